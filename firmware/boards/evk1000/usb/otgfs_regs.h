/* The USB OTG FS core of the STM32F105/107 ("connectivity line") in device mode: the
 * registers and bits this driver uses, from RM0008 chapter 28 ("USB on-the-go full-speed",
 * 28.16 "OTG_FS registers"). Offsets are from OTG_FS_BASE (RM0008 3.3 memory map). Only what
 * is used; no vendor header.
 *
 * Register access goes through OTG_RD / OTG_WR / OTG_FIFO_*. On the chip they are plain
 * volatile accesses. With -DOTG_HOSTED (the host-side test harness, tests/usb/) they call
 * functions the harness provides, which forward to the Python OTG FS model; OTG_WAIT_HOOK()
 * lets that model run while the driver waits (on the chip an interrupt does).
 */
#ifndef EVK1000_USB_OTGFS_REGS_H
#define EVK1000_USB_OTGFS_REGS_H

#include <stdint.h>

#define OTG_FS_BASE 0x50000000u
#define OTG_FS_IRQN 67u /* RM0008 table 62: OTG_FS global interrupt, position 67 */
#define RCC_AHBENR_OTGFSEN (1u << 12) /* RM0008 8.3.14 (connectivity line AHBENR) */

#ifdef OTG_HOSTED
uint32_t otg_hosted_read(uint32_t offset);
void otg_hosted_write(uint32_t offset, uint32_t value);
void otg_hosted_wait(void);
#define OTG_RD(off) otg_hosted_read(off)
#define OTG_WR(off, v) otg_hosted_write((off), (v))
#define OTG_WAIT_HOOK() otg_hosted_wait()
#else
#define OTG_RD(off) (*(volatile uint32_t *)(uintptr_t)(OTG_FS_BASE + (off)))
#define OTG_WR(off, v) (*(volatile uint32_t *)(uintptr_t)(OTG_FS_BASE + (off)) = (v))
#define OTG_WAIT_HOOK() ((void)0)
#endif
/* Data FIFO of endpoint n: push (IN) or pop (OUT / RX FIFO) one 32-bit word (28.16.1 "CSR
 * memory map": 4 KB per FIFO from offset 0x1000). */
#define OTG_FIFO(n) (0x1000u * ((n) + 1u))

/* ---- core global registers (28.16.2) ------------------------------------------------- */
#define GOTGCTL 0x000u
#define GAHBCFG 0x008u
#define GAHBCFG_GINTMSK (1u << 0)
#define GAHBCFG_TXFELVL (1u << 7) /* TXFE interrupt when the TX FIFO is completely empty */
#define GUSBCFG 0x00Cu
#define GUSBCFG_PHYSEL (1u << 6)  /* always 1: full-speed serial transceiver */
#define GUSBCFG_TRDT_SHIFT 10u    /* USB turnaround time, in PHY clocks */
#define GUSBCFG_TRDT_MASK (0xFu << 10)
#define GUSBCFG_FDMOD (1u << 30)  /* force device mode */
#define GRSTCTL 0x010u
#define GRSTCTL_CSRST (1u << 0)
#define GRSTCTL_RXFFLSH (1u << 4)
#define GRSTCTL_TXFFLSH (1u << 5)
#define GRSTCTL_TXFNUM_ALL (0x10u << 6)
#define GRSTCTL_AHBIDL (1u << 31)
#define GINTSTS 0x014u
#define GINTMSK 0x018u
#define GINT_MMIS (1u << 1)
#define GINT_OTGINT (1u << 2)
#define GINT_SOF (1u << 3)
#define GINT_RXFLVL (1u << 4)
#define GINT_USBSUSP (1u << 11)
#define GINT_USBRST (1u << 12)
#define GINT_ENUMDNE (1u << 13)
#define GINT_IEPINT (1u << 18)
#define GINT_OEPINT (1u << 19)
#define GINT_SRQINT (1u << 30)
#define GINT_WKUPINT (1u << 31)
#define GRXSTSP 0x020u                  /* pop: EPNUM 3:0, BCNT 14:4, DPID 16:15, PKTSTS 20:17 */
#define GRXSTS_EPNUM(v) ((v) & 0xFu)
#define GRXSTS_BCNT(v) (((v) >> 4) & 0x7FFu)
#define GRXSTS_PKTSTS(v) (((v) >> 17) & 0xFu)
#define PKTSTS_OUT_DATA 2u
#define PKTSTS_OUT_DONE 3u
#define PKTSTS_SETUP_DONE 4u
#define PKTSTS_SETUP_DATA 6u
#define GRXFSIZ 0x024u                  /* RX FIFO depth, words */
#define DIEPTXF0 0x028u                 /* EP0 TX FIFO: depth 31:16, start 15:0 (words) */
#define GCCFG 0x038u
#define GCCFG_PWRDWN (1u << 16)         /* 1: transceiver active */
#define GCCFG_VBUSBSEN (1u << 19)       /* VBUS sensing "B" device (PA9) */
#define CID 0x03Cu
#define DIEPTXF(n) (0x104u + 4u * ((n) - 1u)) /* n = 1..3 */

/* ---- device-mode registers (28.16.4) ------------------------------------------------- */
#define DCFG 0x800u
#define DCFG_DSPD_FS 3u                 /* full speed, internal PHY */
#define DCFG_DAD_SHIFT 4u
#define DCFG_DAD_MASK (0x7Fu << 4)
#define DCTL 0x804u
#define DCTL_RWUSIG (1u << 0)
#define DCTL_SDIS (1u << 1)             /* soft disconnect: pull-up off */
#define DCTL_CGINAK (1u << 8)
#define DCTL_CGONAK (1u << 10)
#define DSTS 0x808u
#define DSTS_SUSPSTS (1u << 0)
#define DIEPMSK 0x810u
#define DOEPMSK 0x814u
#define DAINT 0x818u
#define DAINTMSK 0x81Cu
#define DIEPCTL(n) (0x900u + 0x20u * (n))
#define DIEPINT(n) (0x908u + 0x20u * (n))
#define DIEPTSIZ(n) (0x910u + 0x20u * (n))
#define DTXFSTS(n) (0x918u + 0x20u * (n))
#define DOEPCTL(n) (0xB00u + 0x20u * (n))
#define DOEPINT(n) (0xB08u + 0x20u * (n))
#define DOEPTSIZ(n) (0xB10u + 0x20u * (n))
#define PCGCCTL 0xE00u
/* DIEPCTLx / DOEPCTLx */
#define EPCTL_MPSIZ_MASK 0x7FFu         /* EP0: 2 bits, 0 = 64 bytes */
#define EPCTL_USBAEP (1u << 15)
#define EPCTL_NAKSTS (1u << 17)
#define EPCTL_EPTYP_BULK (2u << 18)
#define EPCTL_EPTYP_INTR (3u << 18)
#define EPCTL_STALL (1u << 21)
#define EPCTL_TXFNUM(n) ((uint32_t)(n) << 22)
#define EPCTL_CNAK (1u << 26)
#define EPCTL_SNAK (1u << 27)
#define EPCTL_SD0PID (1u << 28)
#define EPCTL_EPDIS (1u << 30)
#define EPCTL_EPENA (1u << 31)
/* DIEPINTx / DOEPINTx */
#define EPINT_XFRC (1u << 0)
#define EPINT_EPDISD (1u << 1)
#define EPINT_STUP (1u << 3)            /* OUT: SETUP phase done */
#define EPINT_TOC (1u << 3)             /* IN: timeout (control IN) */
/* DIEPTSIZx / DOEPTSIZx */
#define TSIZ_PKTCNT_SHIFT 19u
#define TSIZ_STUPCNT_3 (3u << 29)       /* DOEPTSIZ0: accept up to 3 back-to-back SETUPs */

#endif
