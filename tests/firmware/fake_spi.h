/* A transaction-recording fake of the DW1000 behind struct dw_ops, for driver and state
 * machine unit tests. Not a radio model: registers are plain bytes, plus the few chip rules
 * the driver's control flow depends on (SYS_STATUS write-1-to-clear, SYS_CTRL actions,
 * delayed TX at DX_TIME on the 512 grid with TX_ANTD, HPDWARN when DX_TIME is in the past,
 * IRQ = status & mask), a fake clock, and scripted receptions. Include fake_spi.c once in
 * the test file (only tests/firmware/test_*.c and support/ are compiled by make ctest). */
#ifndef UWBCAL_FAKE_SPI_H
#define UWBCAL_FAKE_SPI_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "dw1000.h"

#define FAKE_REG_BYTES 0x2900u
#define FAKE_LOG_CAP 4096u
#define FAKE_RXQ_CAP 64u
#define FAKE_TXLOG_CAP 256u

struct fake_txn {
    bool write;
    uint8_t reg;
    uint16_t off;
    uint8_t hdr[3];
    size_t hdr_len;
    uint8_t data[128];
    size_t len;
};

struct fake_rx {
    uint64_t at_us;   /* when the frame (or error) completes */
    bool error;       /* an RX error (RXPHE) instead of a frame */
    uint8_t data[DW_MAX_PAYLOAD];
    uint8_t len;
    uint64_t stamp;   /* RX_STAMP to report */
    uint16_t cir_pwr, rxpacc, rxpacc_nosat, fp_ampl1, fp_ampl2, fp_ampl3, std_noise, fp_index;
    uint32_t car_int_raw; /* 21 bits as in the register */
    uint32_t ttcko_raw;   /* 19 bits */
    uint32_t ttcki;
};

struct fake_tx {
    uint64_t at_us;   /* fake time of the RMARKER (TXFRS comes tx_tail_us later) */
    uint64_t stamp;   /* TX_STAMP reported */
    uint8_t data[DW_MAX_PAYLOAD];
    uint8_t len;
    uint8_t gain;     /* TX_POWER octet 2 at the time */
};

struct fake_spi {
    struct dw_ops ops;
    uint64_t now_us;
    uint64_t sys_offset;        /* device units at now_us = 0 */
    uint32_t dev_id;
    uint8_t otp_t23;            /* OTP 0x009 byte 1 (survives reset) */
    uint8_t regs[0x40][FAKE_REG_BYTES];
    struct fake_txn log[FAKE_LOG_CAP];
    size_t nlog;                /* entries in log (stops at FAKE_LOG_CAP) */
    size_t ntxn;                /* every transaction */
    long fail_at;               /* transaction number that fails (-1 never) */
    unsigned resets;
    unsigned nbatch;            /* spi_batch calls (fake_enable_batch) */
    /* TX */
    bool tx_pending;
    struct fake_tx cur;
    struct fake_tx txlog[FAKE_TXLOG_CAP];
    size_t ntx;
    uint32_t tx_tail_us;        /* TXFRS this long after the RMARKER (PHR+data), default 50 */
    uint64_t late_lead_units;   /* HPDWARN also when DX_TIME is closer than this */
    long refuse_tx;             /* delayed TX number (0-based) answered with HPDWARN, -1 none */
    uint64_t tx_time_skew;      /* added to TX_TIME as read (0: the chip's own stamp) */
    size_t ndelayed;
    /* RX */
    bool rx_on;
    struct fake_rx rxq[FAKE_RXQ_CAP];
    size_t nrx, rx_head;
    unsigned rx_missed;         /* scripted frames that found the receiver off */
    uint64_t max_wait_step_us;  /* longest single wait_irq advance seen */
    void (*on_tx)(struct fake_spi *f, const struct fake_tx *tx);
};

void fake_init(struct fake_spi *f);
/* Offer ops->spi_batch (a loop over the transactions that counts the calls). */
void fake_enable_batch(struct fake_spi *f);
uint64_t fake_sys_time(const struct fake_spi *f);     /* SYS_TIME now (40 bits, grid) */
uint64_t fake_units_at(const struct fake_spi *f, uint64_t t_us);
void fake_set_reg(struct fake_spi *f, uint8_t reg, uint16_t off, uint64_t v, size_t n);
uint64_t fake_get_reg(const struct fake_spi *f, uint8_t reg, uint16_t off, size_t n);
uint32_t fake_status(const struct fake_spi *f);
struct fake_rx *fake_add_rx(struct fake_spi *f, uint64_t at_us, const uint8_t *data, size_t len, uint64_t stamp);
void fake_add_rx_error(struct fake_spi *f, uint64_t at_us);
/* Last logged transaction writing reg:off, or NULL. */
const struct fake_txn *fake_last_write(const struct fake_spi *f, uint8_t reg, uint16_t off);
size_t fake_count_writes(const struct fake_spi *f, uint8_t reg, uint16_t off);
void fake_clear_log(struct fake_spi *f);
/* Clock for radio_set_clock(): the time of the fake set by fake_use_clock. */
void fake_use_clock(struct fake_spi *f);
uint64_t fake_clock_us(void);

#endif
