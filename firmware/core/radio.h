/* The measurement side of the radio: the one DW1000 device of the station, its clock, the
 * station id, 64-bit (unwrapped) device time, and the uwbcal radio frame format
 * (firmware/dw1000/REGISTERS.md section 6). Used by sequencer.c, ranging.c and measure.c.
 */
#ifndef UWBCAL_RADIO_H
#define UWBCAL_RADIO_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "dw1000.h"

/* Longest single blocking wait of a poll, us: the host link is read at least this often
 * while something runs (in the station's clock, virtual time on the native board). */
#define RADIO_SLICE_US 5000u

struct radio {
    struct dw_dev dev;
    bool attached;      /* an ops table is known */
    bool present;       /* dw_init succeeded (DEV_ID ok) */
    int last_err;       /* last driver error (DW_E*) */
    uint64_t ext_last;  /* last unwrapped device time seen */
    bool ext_valid;
    uint64_t (*clock_us)(void); /* board_time_us, or a test clock */
    bool temp_valid;
    int16_t temp_cc;    /* last temperature read */
    uint64_t temp_us;   /* when (station clock) */
};

extern struct radio g_radio;

/* Bind the ops table and initialise the chip with the paper's configuration.
 * Returns DW_OK or a DW_E* code (radio absent). ops NULL: no radio. */
int radio_attach(const struct dw_ops *ops);
void radio_set_clock(uint64_t (*clock_us)(void));
uint64_t radio_now_us(void);
bool radio_ready(void);
/* This station's id in frames: the native board's scenario id, else derived from the uid. */
uint16_t radio_station_id(void);
/* The uid fold used when no board gives an id: XOR of the six little-endian u16 words. */
uint16_t radio_uid_station_id(const uint8_t uid[12]);

/* Read SYS_TIME and return it unwrapped (64-bit, monotonic while read at least every 8 s). */
int radio_sys_now(uint64_t *ext);
/* Unwrap a 40-bit stamp that lies within +-8.6 s of the last time seen. */
uint64_t radio_unwrap(uint64_t raw40);
/* Bounded wait for the radio IRQ until min(deadline_us, now + RADIO_SLICE_US):
 * 1 IRQ, 0 no IRQ (check radio_now_us() against your deadline), <0 DW_E*. */
int radio_wait(uint64_t deadline_us);

/* Temperature, 0.01 degC (INT16_MIN: uncalibrated chip), read from the chip at most every
 * RADIO_TEMP_PERIOD_US and cached in between (it changes slowly; each read costs SPI time). */
#define RADIO_TEMP_PERIOD_US 100000u
int radio_temp_cc(int16_t *temp_cc);

/* ---- radio frames ------------------------------------------------------------------ */
#define RF_MAGIC 0xC5u
#define RF_HDR_LEN 12u
#define RF_BROADCAST 0xFFFFu
enum rf_kind { RF_P = 1, RF_M1 = 2, RF_M2 = 3, RF_M3 = 4, RF_REPORT = 5 };
#define RF_P_LEN 20u
#define RF_M1_LEN 17u
#define RF_M2_LEN 22u
#define RF_M3_LEN 22u
#define RF_REPORT_LEN 92u
#define RF_Q_LEN 28u

struct rf_frame {
    uint8_t kind;
    uint16_t src, dst;
    uint32_t seq;
    uint8_t gain;  /* TX_POWER octet of this frame */
    uint8_t idx;   /* P: 0,1,2; M*: method */
    uint16_t step; /* P */
    uint8_t gain13; /* P */
    uint64_t ts[3]; /* P: own tx; M1: t1r; M2: t1t t2t; M3: t2r t3r; REPORT: t1t t2t t3t */
    struct dw_rx_quality q[2]; /* REPORT: q_t1, q_t3 */
    uint8_t tag_valid;         /* REPORT: the tag has a calibration table */
    float e1_ps, z_ps;         /* REPORT: tag's E1 and its share of Z */
};

/* Encode into buf (cap >= frame length); returns the length, 0 on error. */
size_t rf_encode(const struct rf_frame *f, uint8_t *buf, size_t cap);
/* Decode; false when the bytes are not a well-formed uwbcal frame. */
bool rf_decode(const uint8_t *buf, size_t len, struct rf_frame *f);

#endif
