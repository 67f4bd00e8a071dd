/* USB OTG FS device-mode driver (RM0008 chapter 28, 28.17 "OTG_FS programming model"), see
 * otgfs.h: core init, FIFOs, bus events, the interrupt handler and the data endpoints. EP0 and
 * the standard requests are in otgfs_ep0.c. Every wait is a bounded loop; a bus reset may
 * arrive at any moment and puts everything back to DEFAULT.
 */
#include "otgfs_internal.h"

#include "otgfs_regs.h"

#ifndef OTG_HOSTED
#include "evk1000.h"
#include "stm32f105.h"
#endif

/* Critical sections that nest: PRIMASK saved and restored (PM0056 2.1.3). */
uint32_t usbd_irq_save(void)
{
#ifndef OTG_HOSTED
    uint32_t primask;
    __asm__ volatile("mrs %0, primask" : "=r"(primask));
    cpu_irq_disable();
    return primask;
#else
    return 0u;
#endif
}

void usbd_irq_restore(uint32_t primask)
{
#ifndef OTG_HOSTED
    if ((primask & 1u) == 0u)
        cpu_irq_enable();
#else
    (void)primask;
#endif
}

/* FIFO RAM: 1.25 KB = 320 words on the connectivity line (RM0008 28.4, 28.11). RX FIFO per
 * 28.11.1: 10 words for SETUP/status + 2 * (largest packet / 4 + 1) + 1, with room. */
#define FIFO_RX_WORDS 64u
#define FIFO_TX0_WORDS 16u                     /* one 64-byte EP0 packet */
#define FIFO_TX1_WORDS (USBD_DATA_TX_MAX / 4u) /* one whole bulk transfer (8 packets) */
#define FIFO_TX2_WORDS 16u
_Static_assert(FIFO_RX_WORDS + FIFO_TX0_WORDS + FIFO_TX1_WORDS + FIFO_TX2_WORDS <= 320u,
               "OTG FS FIFO RAM is 320 words");
#define WAIT_LOOPS 100000u /* bounded register waits: >1 ms at 72 MHz, far above the core's */

struct otgfs_state otg;

enum usbd_state usbd_state(void) { return otg.state; }
bool usbd_suspended(void) { return otg.suspended; }
uint32_t usbd_bus_resets(void) { return otg.bus_resets; }

bool otgfs_wait_bits(uint32_t reg, uint32_t mask, uint32_t value)
{
    for (uint32_t i = 0; i < WAIT_LOOPS; i++) {
        if ((OTG_RD(reg) & mask) == value)
            return true;
        OTG_WAIT_HOOK();
    }
    return false;
}

void otgfs_fifo_write(uint8_t ep, const uint8_t *p, size_t len)
{
    for (size_t i = 0; i < len; i += 4u) {
        uint32_t w = 0;
        for (size_t k = 0; k < 4u && i + k < len; k++)
            w |= (uint32_t)p[i + k] << (8u * k);
        OTG_WR(OTG_FIFO(ep), w);
    }
}

static void fifo_read(uint8_t *p, size_t len, size_t keep)
{
    /* Pops ceil(len / 4) words; stores the first `keep` bytes, drops the rest. */
    for (size_t i = 0; i < len; i += 4u) {
        uint32_t w = OTG_RD(OTG_FIFO(0));
        for (size_t k = 0; k < 4u && i + k < len; k++) {
            if (i + k < keep)
                p[i + k] = (uint8_t)(w >> (8u * k));
        }
    }
}

static void flush_fifos(void)
{
    OTG_WR(GRSTCTL, GRSTCTL_TXFFLSH | GRSTCTL_TXFNUM_ALL);
    (void)otgfs_wait_bits(GRSTCTL, GRSTCTL_TXFFLSH, 0u);
    OTG_WR(GRSTCTL, GRSTCTL_RXFFLSH);
    (void)otgfs_wait_bits(GRSTCTL, GRSTCTL_RXFFLSH, 0u);
}

void otgfs_endpoints_open(bool on)
{
    if (otg.in_busy[USBD_EP_DATA]) {
        /* XFRSIZ counts down as the host acknowledges packets (28.16.4 DIEPTSIZx). */
        uint32_t left = OTG_RD(DIEPTSIZ(USBD_EP_DATA)) & 0x7FFFFu;
        uint16_t len = otg.in_len[USBD_EP_DATA];
        otg.in_busy[USBD_EP_DATA] = false;
        usbd_class_in_done(USBD_EP_DATA, left < len ? len - left : 0u);
    }
    for (uint8_t ep = 1; ep <= 2u; ep++) {
        otg.in_busy[ep] = false;
        otg.in_zlp_after[ep] = false;
        otg.halted_in[ep] = otg.halted_out[ep] = false;
        if (OTG_RD(DIEPCTL(ep)) & EPCTL_EPENA)
            OTG_WR(DIEPCTL(ep), EPCTL_EPDIS | EPCTL_SNAK);
        if (OTG_RD(DOEPCTL(ep)) & EPCTL_EPENA)
            OTG_WR(DOEPCTL(ep), EPCTL_EPDIS | EPCTL_SNAK);
        OTG_WR(DIEPCTL(ep), 0u);
        OTG_WR(DOEPCTL(ep), 0u);
    }
    if (!on) {
        OTG_WR(DAINTMSK, 1u | (1u << 16));
        return;
    }
    OTG_WR(DIEPCTL(USBD_EP_DATA), USBD_DATA_MPS | EPCTL_USBAEP | EPCTL_EPTYP_BULK
                                      | EPCTL_TXFNUM(USBD_EP_DATA) | EPCTL_SD0PID | EPCTL_SNAK);
    OTG_WR(DIEPCTL(USBD_EP_NOTIFY), USBD_NOTIFY_MPS | EPCTL_USBAEP | EPCTL_EPTYP_INTR
                                        | EPCTL_TXFNUM(USBD_EP_NOTIFY) | EPCTL_SD0PID | EPCTL_SNAK);
    OTG_WR(DOEPCTL(USBD_EP_DATA), USBD_DATA_MPS | EPCTL_USBAEP | EPCTL_EPTYP_BULK | EPCTL_SD0PID);
    OTG_WR(DAINTMSK, 1u | (1u << USBD_EP_DATA) | (1u << USBD_EP_NOTIFY) | (1u << 16)
                         | (1u << (16u + USBD_EP_DATA)));
    otg.out_paused = false;
    usbd_out_arm(USBD_EP_DATA);
}

/* ---- bus events --------------------------------------------------------------------------- */

static void bus_reset(void)
{
    otg.bus_resets++;
    otg.state = USBD_DEFAULT;
    otg.suspended = false;
    otg.config = 0;
    otg.stage = EP0_IDLE;
    OTG_WR(DCTL, OTG_RD(DCTL) & ~DCTL_RWUSIG);
    otgfs_endpoints_open(false);
    flush_fifos();
    for (uint8_t ep = 0; ep < 4u; ep++) {
        OTG_WR(DIEPINT(ep), 0xFFu);
        OTG_WR(DOEPINT(ep), 0xFFu);
    }
    OTG_WR(DOEPMSK, EPINT_XFRC | EPINT_STUP);
    OTG_WR(DIEPMSK, EPINT_XFRC | EPINT_TOC);
    OTG_WR(DCFG, OTG_RD(DCFG) & ~DCFG_DAD_MASK);
    otgfs_ep0_out_arm();
    usbd_class_configured(false);
}

static void rx_fifo_pop(void)
{
    uint32_t st = OTG_RD(GRXSTSP);
    uint8_t ep = (uint8_t)GRXSTS_EPNUM(st);
    uint16_t n = (uint16_t)GRXSTS_BCNT(st);
    switch (GRXSTS_PKTSTS(st)) {
    case PKTSTS_SETUP_DATA:
        fifo_read((uint8_t *)otg.setup_words, n, sizeof otg.setup_words);
        break;
    case PKTSTS_OUT_DATA:
        if (ep == 0u) {
            size_t room = sizeof otg.out_buf - otg.out_len;
            fifo_read(otg.out_buf + otg.out_len, n, room);
            otg.out_len = (uint16_t)(otg.out_len + (n < room ? n : room));
        } else {
            uint8_t pkt[USBD_DATA_MPS];
            fifo_read(pkt, n, sizeof pkt);
            if (!usbd_class_rx(pkt, n < sizeof pkt ? n : sizeof pkt))
                otg.out_paused = true;
        }
        break;
    default: /* SETUP done, OUT done, global OUT NAK: no data */
        break;
    }
}

void usbd_irq(void)
{
    uint32_t st = OTG_RD(GINTSTS) & OTG_RD(GINTMSK);
    if (st & GINT_USBRST) {
        OTG_WR(GINTSTS, GINT_USBRST);
        bus_reset();
    }
    if (st & GINT_ENUMDNE) {
        OTG_WR(GINTSTS, GINT_ENUMDNE);
        OTG_WR(DIEPCTL(0), OTG_RD(DIEPCTL(0)) & ~EPCTL_MPSIZ_MASK); /* 0: 64 bytes */
        OTG_WR(DCTL, OTG_RD(DCTL) | DCTL_CGINAK);
    }
    for (unsigned i = 0; i < 16u && (OTG_RD(GINTSTS) & GINT_RXFLVL); i++)
        rx_fifo_pop();
    if (st & GINT_OEPINT) {
        uint32_t eps = OTG_RD(DAINT) >> 16;
        for (uint8_t ep = 0; ep <= USBD_EP_DATA; ep++) {
            if (!(eps & (1u << ep)))
                continue;
            uint32_t f = OTG_RD(DOEPINT(ep)) & OTG_RD(DOEPMSK);
            OTG_WR(DOEPINT(ep), f);
            if (ep == 0u && (f & EPINT_STUP)) {
                otgfs_ep0_setup();
            } else if (ep == 0u && (f & EPINT_XFRC)) {
                otgfs_ep0_out_done();
            } else if (f & EPINT_XFRC) {
                if (!otg.out_paused)
                    usbd_out_arm(ep);
            }
        }
    }
    if (st & GINT_IEPINT) {
        uint32_t eps = OTG_RD(DAINT) & 0xFFFFu;
        for (uint8_t ep = 0; ep <= USBD_EP_NOTIFY; ep++) {
            if (!(eps & (1u << ep)))
                continue;
            uint32_t f = OTG_RD(DIEPINT(ep)) & OTG_RD(DIEPMSK);
            OTG_WR(DIEPINT(ep), f);
            if (!(f & EPINT_XFRC))
                continue;
            if (ep == 0u) {
                otgfs_ep0_in_done();
            } else if (otg.in_zlp_after[ep]) {
                otg.in_zlp_after[ep] = false;
                OTG_WR(DIEPTSIZ(ep), 1u << TSIZ_PKTCNT_SHIFT);
                OTG_WR(DIEPCTL(ep), OTG_RD(DIEPCTL(ep)) | EPCTL_EPENA | EPCTL_CNAK);
            } else {
                otg.in_busy[ep] = false;
                if (ep == USBD_EP_DATA)
                    usbd_class_in_done(ep, otg.in_len[ep]);
            }
        }
    }
    if (st & GINT_USBSUSP) {
        OTG_WR(GINTSTS, GINT_USBSUSP);
        if (OTG_RD(DSTS) & DSTS_SUSPSTS)
            otg.suspended = true;
    }
    if (st & GINT_WKUPINT) {
        OTG_WR(GINTSTS, GINT_WKUPINT);
        otg.suspended = false;
    }
    if (st & (GINT_SRQINT | GINT_MMIS))
        OTG_WR(GINTSTS, st & (GINT_SRQINT | GINT_MMIS));
    if (st & GINT_OTGINT)
        OTG_WR(GOTGCTL + 4u, OTG_RD(GOTGCTL + 4u)); /* GOTGINT: write 1 to clear */
}

/* ---- data endpoints ------------------------------------------------------------------------ */

bool usbd_in_busy(uint8_t ep) { return ep < 3u && otg.in_busy[ep]; }

bool usbd_in_start(uint8_t ep, const uint8_t *data, size_t len)
{
    if (ep == 0u || ep > USBD_EP_NOTIFY || len > USBD_DATA_TX_MAX || otg.state != USBD_CONFIGURED)
        return false;
    uint32_t pm = usbd_irq_save();
    bool ok = !otg.in_busy[ep] && !otg.halted_in[ep] && otg.state == USBD_CONFIGURED;
    if (ok) {
        uint32_t mps = ep == USBD_EP_DATA ? USBD_DATA_MPS : USBD_NOTIFY_MPS;
        uint32_t pkts = len == 0u ? 1u : (uint32_t)((len + mps - 1u) / mps);
        otg.in_busy[ep] = true;
        otg.in_len[ep] = (uint16_t)len;
        otg.in_zlp_after[ep] = ep == USBD_EP_DATA && len > 0u && len % mps == 0u;
        OTG_WR(DIEPTSIZ(ep), (pkts << TSIZ_PKTCNT_SHIFT) | (uint32_t)len);
        OTG_WR(DIEPCTL(ep), OTG_RD(DIEPCTL(ep)) | EPCTL_EPENA | EPCTL_CNAK);
        otgfs_fifo_write(ep, data, len);
    }
    usbd_irq_restore(pm);
    return ok;
}

void usbd_out_arm(uint8_t ep)
{
    uint32_t pm = usbd_irq_save();
    if (otg.state == USBD_CONFIGURED && !otg.halted_out[ep]) {
        otg.out_paused = false;
        OTG_WR(DOEPTSIZ(ep), (1u << TSIZ_PKTCNT_SHIFT) | USBD_DATA_MPS);
        OTG_WR(DOEPCTL(ep), OTG_RD(DOEPCTL(ep)) | EPCTL_EPENA | EPCTL_CNAK);
    }
    usbd_irq_restore(pm);
}

/* ---- init (RM0008 28.17.1 core initialization, 28.17.3 device initialization) ------------ */

int usbd_init(void)
{
    otg.state = USBD_DETACHED;
#ifndef OTG_HOSTED
    /* 48 MHz from PLLVCO / 3 (clock.c leaves OTGFSPRE = 0); PA11/PA12 are taken by the core
     * when it is powered, with no GPIO setup (RM0008 9.1.11 table 29 note); PA9 = VBUS. */
    RCC_AHBENR |= RCC_AHBENR_OTGFSEN;
    (void)RCC_AHBENR;
#endif
    OTG_WR(GAHBCFG, 0u);
    if (!otgfs_wait_bits(GRSTCTL, GRSTCTL_AHBIDL, GRSTCTL_AHBIDL))
        return -1;
    OTG_WR(GRSTCTL, GRSTCTL_CSRST);
    if (!otgfs_wait_bits(GRSTCTL, GRSTCTL_CSRST, 0u))
        return -1;
    OTG_WR(GUSBCFG, GUSBCFG_PHYSEL | GUSBCFG_FDMOD | (6u << GUSBCFG_TRDT_SHIFT));
    /* Forcing device mode takes effect after at least 25 ms (28.16.2 GUSBCFG.FDMOD). */
#ifndef OTG_HOSTED
    evk_delay_us(25000u);
#endif
    OTG_WR(GCCFG, GCCFG_PWRDWN | GCCFG_VBUSBSEN);
    OTG_WR(PCGCCTL, 0u);
    OTG_WR(DCFG, DCFG_DSPD_FS);
    OTG_WR(DCTL, DCTL_SDIS); /* stay disconnected until everything is set up */

    OTG_WR(GRXFSIZ, FIFO_RX_WORDS);
    OTG_WR(DIEPTXF0, (FIFO_TX0_WORDS << 16) | FIFO_RX_WORDS);
    OTG_WR(DIEPTXF(1), (FIFO_TX1_WORDS << 16) | (FIFO_RX_WORDS + FIFO_TX0_WORDS));
    OTG_WR(DIEPTXF(2), (FIFO_TX2_WORDS << 16) | (FIFO_RX_WORDS + FIFO_TX0_WORDS + FIFO_TX1_WORDS));
    flush_fifos();

    OTG_WR(GINTSTS, 0xFFFFFFFFu);
    OTG_WR(GINTMSK, GINT_USBRST | GINT_ENUMDNE | GINT_RXFLVL | GINT_IEPINT | GINT_OEPINT
                        | GINT_USBSUSP | GINT_WKUPINT | GINT_OTGINT | GINT_SRQINT | GINT_MMIS);
    OTG_WR(GAHBCFG, GAHBCFG_GINTMSK);
#ifndef OTG_HOSTED
    nvic_enable(OTG_FS_IRQN, 2u);
#endif
    OTG_WR(DCTL, OTG_RD(DCTL) & ~DCTL_SDIS); /* D+ pull-up on: the host sees the device */
    return 0;
}

#ifndef OTG_HOSTED
void OTG_FS_IRQHandler(void);
void OTG_FS_IRQHandler(void) { usbd_irq(); }
#endif
