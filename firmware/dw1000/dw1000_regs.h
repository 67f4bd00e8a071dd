/* DW1000 register files, sub-addresses and bits used by the driver (DW1000 User Manual).
 * REGISTERS.md documents the subset the driver uses. */
#ifndef UWBCAL_DW1000_REGS_H
#define UWBCAL_DW1000_REGS_H

#include <stdint.h>

#include "dw1000_facts.h"

/* Register file IDs (DW_REG_*), sub-addresses (DW_AGC_*, DW_DRX_*, DW_RF_*, DW_TC_*, DW_FS_*,
 * DW_OTP_*, DW_LDE_*, DW_PMSC_*) and bits (DW_SYS_CFG_*, DW_SYS_CTRL_*, DW_ST_* for SYS_STATUS
 * and SYS_MASK, DW_TX_FCTRL_*) are chip facts of protocol/dw1000.toml, generated into
 * dw1000_facts.h; the medium's register model (host/uwbcal/medium/registers.py) uses the same
 * generated values. Here: what the driver builds from them. */

#define DW_ST_RX_ERR                                                                      \
    (DW_ST_RXPHE | DW_ST_RXFCE | DW_ST_RXRFSL | DW_ST_RXRFTO | DW_ST_LDEERR | DW_ST_RXPTO | \
     DW_ST_RXSFDTO | DW_ST_AFFREJ)
#define DW_IRQ_MASK (DW_ST_TXFRS | DW_ST_RXFCG | DW_ST_RX_ERR)           /* 0x2427D080 */
#define DW_TX_DONE_CLR (DW_ST_TXFRB | DW_ST_TXPRS | DW_ST_TXPHS | DW_ST_TXFRS) /* 0xF0 */
#define DW_RX_GOOD_CLR                                                                   \
    (DW_ST_RXPRD | DW_ST_RXSFDD | DW_ST_LDEDONE | DW_ST_RXPHD | DW_ST_RXDFR | DW_ST_RXFCG) /* 0x6F00 */
#define DW_RX_ERR_CLR (DW_ST_RX_ERR | DW_ST_RXOVRF | DW_RX_GOOD_CLR) /* 0x2437FF00 */

/* time base */
#define DW_TIME_MASK ((UINT64_C(1) << DW1000_TIMESTAMP_BITS) - 1u) /* 40 bits */
#define DW_TIME_HALF (UINT64_C(1) << (DW1000_TIMESTAMP_BITS - 1u)) /* 2^39 */
#define DW_DX_GRID_MASK ((uint64_t)DW1000_DELAYED_TX_GRID - 1u)     /* low 9 bits ignored by DX_TIME */

#endif
