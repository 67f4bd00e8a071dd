/* DW1000 register files, sub-addresses and bits used by the driver (DW1000 User Manual).
 * Exactly the subset documented in REGISTERS.md; keep the two in step. */
#ifndef UWBCAL_DW1000_REGS_H
#define UWBCAL_DW1000_REGS_H

#include <stdint.h>

#include "dw1000_facts.h"

#define DW_DEV_ID_VALUE 0xDECA0130u

/* register file IDs */
#define DW_REG_DEV_ID 0x00
#define DW_REG_SYS_CFG 0x04
#define DW_REG_SYS_TIME 0x06
#define DW_REG_TX_FCTRL 0x08
#define DW_REG_TX_BUFFER 0x09
#define DW_REG_DX_TIME 0x0A
#define DW_REG_SYS_CTRL 0x0D
#define DW_REG_SYS_MASK 0x0E
#define DW_REG_SYS_STATUS 0x0F
#define DW_REG_RX_FINFO 0x10
#define DW_REG_RX_BUFFER 0x11
#define DW_REG_RX_FQUAL 0x12
#define DW_REG_RX_TTCKI 0x13
#define DW_REG_RX_TTCKO 0x14
#define DW_REG_RX_TIME 0x15
#define DW_REG_TX_TIME 0x17
#define DW_REG_TX_ANTD 0x18
#define DW_REG_TX_POWER 0x1E
#define DW_REG_CHAN_CTRL 0x1F
#define DW_REG_AGC_CTRL 0x23
#define DW_REG_DRX_CONF 0x27
#define DW_REG_RF_CONF 0x28
#define DW_REG_TX_CAL 0x2A
#define DW_REG_FS_CTRL 0x2B
#define DW_REG_OTP_IF 0x2D
#define DW_REG_LDE_IF 0x2E
#define DW_REG_PMSC 0x36

/* sub-addresses */
#define DW_AGC_TUNE1 0x04
#define DW_AGC_TUNE2 0x0C
#define DW_AGC_TUNE3 0x12
#define DW_DRX_TUNE0B 0x02
#define DW_DRX_TUNE1A 0x04
#define DW_DRX_TUNE1B 0x06
#define DW_DRX_TUNE2 0x08
#define DW_DRX_SFDTOC 0x20
#define DW_DRX_TUNE4H 0x26
#define DW_DRX_CAR_INT 0x28
#define DW_RXPACC_NOSAT 0x2C
#define DW_RF_RXCTRLH 0x0B
#define DW_RF_TXCTRL 0x0C
#define DW_RF_TEMP1 0x11
#define DW_RF_TEMP2 0x12
#define DW_TC_SARC 0x00
#define DW_TC_SARL 0x03
#define DW_TC_PGDELAY 0x0B
#define DW_FS_PLLCFG 0x07
#define DW_FS_PLLTUNE 0x0B
#define DW_OTP_ADDR 0x04
#define DW_OTP_CTRL 0x06
#define DW_OTP_RDAT 0x0A
#define DW_LDE_CFG1 0x0806
#define DW_LDE_RXANTD 0x1804
#define DW_LDE_CFG2 0x1806
#define DW_LDE_REPC 0x2804
#define DW_PMSC_CTRL0 0x00
#define DW_PMSC_SOFTRESET 0x03

/* SYS_CFG */
#define DW_SYS_CFG_HIRQ_POL (1u << 9)
#define DW_SYS_CFG_DIS_DRXB (1u << 12)
#define DW_SYS_CFG_DIS_STXP (1u << 18)
#define DW_SYS_CFG_RXM110K (1u << 22)

/* SYS_CTRL */
#define DW_SYS_CTRL_TXSTRT (1u << 1)
#define DW_SYS_CTRL_TXDLYS (1u << 2)
#define DW_SYS_CTRL_TRXOFF (1u << 6)
#define DW_SYS_CTRL_RXENAB (1u << 8)

/* SYS_STATUS (and SYS_MASK, same positions) */
#define DW_ST_TXFRB (1u << 4)
#define DW_ST_TXPRS (1u << 5)
#define DW_ST_TXPHS (1u << 6)
#define DW_ST_TXFRS (1u << 7)
#define DW_ST_RXPRD (1u << 8)
#define DW_ST_RXSFDD (1u << 9)
#define DW_ST_LDEDONE (1u << 10)
#define DW_ST_RXPHD (1u << 11)
#define DW_ST_RXPHE (1u << 12)
#define DW_ST_RXDFR (1u << 13)
#define DW_ST_RXFCG (1u << 14)
#define DW_ST_RXFCE (1u << 15)
#define DW_ST_RXRFSL (1u << 16)
#define DW_ST_RXRFTO (1u << 17)
#define DW_ST_LDEERR (1u << 18)
#define DW_ST_RXOVRF (1u << 20)
#define DW_ST_RXPTO (1u << 21)
#define DW_ST_RXSFDTO (1u << 26)
#define DW_ST_HPDWARN (1u << 27)
#define DW_ST_AFFREJ (1u << 29)

#define DW_ST_RX_ERR                                                                      \
    (DW_ST_RXPHE | DW_ST_RXFCE | DW_ST_RXRFSL | DW_ST_RXRFTO | DW_ST_LDEERR | DW_ST_RXPTO | \
     DW_ST_RXSFDTO | DW_ST_AFFREJ)
#define DW_IRQ_MASK (DW_ST_TXFRS | DW_ST_RXFCG | DW_ST_RX_ERR)           /* 0x2427D080 */
#define DW_TX_DONE_CLR (DW_ST_TXFRB | DW_ST_TXPRS | DW_ST_TXPHS | DW_ST_TXFRS) /* 0xF0 */
#define DW_RX_GOOD_CLR                                                                   \
    (DW_ST_RXPRD | DW_ST_RXSFDD | DW_ST_LDEDONE | DW_ST_RXPHD | DW_ST_RXDFR | DW_ST_RXFCG) /* 0x6F00 */
#define DW_RX_ERR_CLR (DW_ST_RX_ERR | DW_ST_RXOVRF | DW_RX_GOOD_CLR) /* 0x2437FF00 */

/* TX_FCTRL */
#define DW_TX_FCTRL_TR (1u << 15)

/* time base */
#define DW_TIME_MASK ((UINT64_C(1) << DW1000_TIMESTAMP_BITS) - 1u) /* 40 bits */
#define DW_TIME_HALF 0x8000000000ull /* 2^39 */
#define DW_DX_GRID_MASK 0x1FFull     /* low 9 bits ignored by DX_TIME */

#endif
