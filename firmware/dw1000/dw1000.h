/* Register-level DW1000 driver. Reaches the chip only through struct dw_ops; every wait is
 * bounded by a deadline. The exact register subset is in REGISTERS.md.
 *
 * Non-blocking use: start a TX (dw_tx_delayed / dw_tx_now) or enable RX (dw_rx_enable),
 * then call dw_wait_irq(deadline) and dw_service() until it reports the event.
 */
#ifndef UWBCAL_DW1000_H
#define UWBCAL_DW1000_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "dw1000_ops.h"
#include "dw1000_regs.h"

/* error codes (negative), also sent to the host as ERROR radio's detail (negated) */
#define DW_OK 0
#define DW_ESPI (-1)     /* an ops->spi_transfer failed */
#define DW_ENODEV (-2)   /* DEV_ID is not 0xDECA0130 */
#define DW_ETIMEOUT (-3) /* a bounded wait ran out */
#define DW_ELATE (-4)    /* delayed TX refused: HPDWARN (the time was already past) */
#define DW_EARG (-5)     /* bad argument (length, configuration) */
#define DW_ERESET (-6)   /* ops->reset failed */
#define DW_ENOTREADY (-7) /* dw_init/dw_configure not done */
#define DW_EIRQ (-8)     /* ops->wait_irq failed */

#define DW_MAX_FRAME 127u                 /* TFLEN/RXFLEN limit of a standard frame */
#define DW_MAX_PAYLOAD (DW_MAX_FRAME - 2u) /* without the 2-byte FCS */

/* 40-bit device time: 1 unit = 1/(128 * 499.2 MHz) = 15.65 ps; 1 us = 63897.6 units */
#define DW_UNITS_PER_US_NUM 319488u /* units = us * 319488 / 5 */
#define DW_UNITS_PER_US_DEN 5u

struct dw_config {
    uint8_t channel;       /* 1, 2, 3, 4, 5, 7 */
    uint8_t prf_mhz;       /* 16 or 64 */
    uint16_t preamble_len; /* 64 .. 4096 */
    uint8_t data_rate;     /* 0 110k, 1 850k, 2 6.81M */
    uint8_t preamble_code; /* 0 = default for channel and PRF */
    uint16_t tx_antd;      /* device units */
    uint16_t rx_antd;      /* device units */
};

/* The paper's configuration: channel 2, PRF 64, preamble 128, 6.81 Mb/s. */
void dw_config_default(struct dw_config *cfg);
/* 0 if valid; otherwise DW_EARG and *bad_field = index of the offending field in
 * struct dw_config order (channel 0, prf 1, preamble_len 2, data_rate 3, code 4). */
int dw_config_check(const struct dw_config *cfg, unsigned *bad_field);

struct dw_rx_quality {
    uint16_t cir_pwr, rxpacc, rxpacc_nosat, fp_ampl1, fp_ampl2, fp_ampl3, std_noise, fp_index;
    int32_t car_int; /* DRX_CAR_INT, sign-extended from 21 bits */
    int32_t ttcko;   /* RX_TTCKO.RXTOFS, sign-extended from 19 bits */
    uint32_t ttcki;  /* RX_TTCKI */
};

enum dw_event_kind { DW_EV_NONE = 0, DW_EV_TX_DONE, DW_EV_RX_GOOD, DW_EV_RX_ERROR };

struct dw_event {
    enum dw_event_kind kind;
    uint32_t status;        /* SYS_STATUS as read */
    uint64_t stamp;         /* TX_STAMP (TX_DONE) or RX_STAMP (RX_GOOD), 40 bits */
    struct dw_rx_quality q; /* RX_GOOD only */
    uint8_t len;            /* RX_GOOD: payload bytes in data (FCS excluded) */
    uint8_t data[DW_MAX_PAYLOAD];
};

struct dw_dev {
    const struct dw_ops *ops;
    struct dw_config cfg;
    bool ready;          /* init and configure done */
    bool gain_valid;
    uint8_t gain;        /* last TX_POWER octet written */
    uint8_t t23;         /* OTP 0x009 byte 1: LTEMP at 23 degC (0/0xFF: uncalibrated) */
    uint32_t dev_id;
    uint32_t tx_fctrl;   /* TX_FCTRL low 32 bits without TFLEN */
    uint8_t tx_len;      /* TFLEN last written (0: unknown); TX_FCTRL is rewritten on change */
    uint32_t spi_errors; /* failed transactions */
};

/* ---- SPI header and raw register access ------------------------------------------- */
/* Encode the 1..3-byte header for register file reg (0..0x3F), sub-address off
 * (0..0x7FFF); returns the header length, 0 if reg/off is out of range. */
size_t dw_spi_header(uint8_t hdr[3], bool write, uint8_t reg, uint16_t off);
int dw_read(struct dw_dev *d, uint8_t reg, uint16_t off, uint8_t *buf, size_t len);
int dw_write(struct dw_dev *d, uint8_t reg, uint16_t off, const uint8_t *buf, size_t len);
int dw_read32(struct dw_dev *d, uint8_t reg, uint16_t off, uint32_t *v);
int dw_write32(struct dw_dev *d, uint8_t reg, uint16_t off, uint32_t v);
int dw_write16(struct dw_dev *d, uint8_t reg, uint16_t off, uint16_t v);
int dw_write8(struct dw_dev *d, uint8_t reg, uint16_t off, uint8_t v);
int dw_read40(struct dw_dev *d, uint8_t reg, uint16_t off, uint64_t *v);
int dw_write40(struct dw_dev *d, uint8_t reg, uint16_t off, uint64_t v);

/* ---- 40-bit time arithmetic -------------------------------------------------------- */
static inline uint64_t dw_time_add(uint64_t a, uint64_t b) { return (a + b) & DW_TIME_MASK; }
/* (a - b) mod 2^40, in 0 .. 2^40-1 */
static inline uint64_t dw_time_sub(uint64_t a, uint64_t b) { return (a - b) & DW_TIME_MASK; }
/* (a - b) as a signed value in -2^39 .. 2^39-1 */
int64_t dw_time_diff(uint64_t a, uint64_t b);
uint64_t dw_us_to_units(uint64_t us);  /* exact rounding down */
uint64_t dw_units_to_us(uint64_t units); /* rounded up */
/* The TX_STAMP a delayed TX programmed at dx will report: (dx & ~0x1FF) + TX_ANTD, mod 2^40. */
uint64_t dw_tx_stamp_for(uint64_t dx, uint16_t tx_antd);

/* TX_POWER octet helpers: coarse 0 (highest) .. 6 (lowest), 7 off; fine 0..31 (0.5 dB). */
static inline uint8_t dw_gain_octet(unsigned coarse, unsigned fine) {
    return (uint8_t)(((coarse & 7u) << 5) | (fine & 31u));
}
static inline uint32_t dw_tx_power_word(uint8_t octet) { return 0x01010101u * octet; }

/* ---- chip control ---------------------------------------------------------------- */
int dw_init(struct dw_dev *d, const struct dw_ops *ops);
int dw_configure(struct dw_dev *d, const struct dw_config *cfg);
int dw_read_sys_time(struct dw_dev *d, uint64_t *t);
int dw_set_gain(struct dw_dev *d, uint8_t octet);
/* Program a delayed TX: payload n bytes at dx (low 9 bits ignored by the chip). Returns 0
 * (TX pending: wait for DW_EV_TX_DONE), DW_ELATE (HPDWARN: aborted with TRXOFF, nothing
 * sent), or another error. */
int dw_tx_delayed(struct dw_dev *d, const uint8_t *payload, size_t n, uint64_t dx, uint8_t gain);
int dw_tx_now(struct dw_dev *d, const uint8_t *payload, size_t n, uint8_t gain);
int dw_rx_enable(struct dw_dev *d);
int dw_trx_off(struct dw_dev *d);         /* TRXOFF and clear every status bit */
/* Bounded wait for the IRQ line: 1 IRQ, 0 deadline, DW_EIRQ. */
int dw_wait_irq(struct dw_dev *d, uint64_t deadline_us);
/* Read SYS_STATUS and handle what is pending: a finished TX (reads TX_TIME), a good frame
 * (reads the frame and every quality register), or an RX error (recovers: TRXOFF, clear,
 * RX reset, RX re-enabled). ev->kind = DW_EV_NONE when nothing is pending. */
int dw_service(struct dw_dev *d, struct dw_event *ev);
/* Temperature in 0.01 degC; INT16_MIN when the chip has no OTP calibration. */
int dw_read_temp(struct dw_dev *d, int16_t *temp_cc);
/* Frame air time after the RMARKER plus before it (preamble+SFD), us, rounded up. */
uint32_t dw_frame_us(const struct dw_config *cfg, size_t payload_len);

#endif
