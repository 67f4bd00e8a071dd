/* See radio.h. */
#include "radio.h"

#include <string.h>

#include "board.h"
#include "dw1000_regs.h"
#include "proto_gen.h"

/* The driver knows nothing of the protocol; its "no temperature" is the records' one. */
_Static_assert(PROTO_NO_TEMP_CC == INT16_MIN, "dw_read_temp's INT16_MIN is temp_cc's no_temp_cc");

struct radio g_radio;

int radio_attach(const struct dw_ops *ops) {
    uint64_t (*clk)(void) = g_radio.clock_us;
    memset(&g_radio, 0, sizeof g_radio);
    g_radio.clock_us = clk;
    if (ops == NULL) {
        g_radio.last_err = DW_ENODEV;
        return DW_ENODEV;
    }
    g_radio.attached = true;
    int rc = dw_init(&g_radio.dev, ops);
    if (rc == DW_OK) {
        struct dw_config cfg;
        dw_config_default(&cfg);
        rc = dw_configure(&g_radio.dev, &cfg);
    }
    g_radio.present = rc == DW_OK;
    g_radio.last_err = rc;
    return rc;
}

void radio_set_clock(uint64_t (*clock_us)(void)) { g_radio.clock_us = clock_us; }

uint64_t radio_now_us(void) { return g_radio.clock_us ? g_radio.clock_us() : board_time_us(); }

bool radio_ready(void) { return g_radio.present && g_radio.dev.ready; }

uint16_t radio_uid_station_id(const uint8_t uid[12]) {
    uint16_t id = 0;
    for (int i = 0; i < 12; i += 2) id ^= (uint16_t)(uid[i] | (uid[i + 1] << 8));
    return id;
}

/* Boards that know their scenario id (the native board attached to a medium) override it. */
__attribute__((weak)) uint16_t radio_board_station_id(void);
__attribute__((weak)) uint16_t radio_board_station_id(void) {
    uint8_t uid[12];
    board_uid(uid);
    return radio_uid_station_id(uid);
}

uint16_t radio_station_id(void) { return radio_board_station_id(); }

uint64_t radio_unwrap(uint64_t raw40) {
    if (!g_radio.ext_valid) {
        g_radio.ext_valid = true;
        g_radio.ext_last = raw40 & DW_TIME_MASK;
        return g_radio.ext_last;
    }
    int64_t d = dw_time_diff(raw40, g_radio.ext_last & DW_TIME_MASK);
    return (uint64_t)((int64_t)g_radio.ext_last + d);
}

int radio_sys_now(uint64_t *ext) {
    uint64_t raw;
    int rc = dw_read_sys_time(&g_radio.dev, &raw);
    if (rc != DW_OK) return rc;
    uint64_t e = radio_unwrap(raw);
    if (e > g_radio.ext_last) g_radio.ext_last = e;
    *ext = e;
    return DW_OK;
}

int radio_wait(uint64_t deadline_us) {
    uint64_t now = radio_now_us();
    uint64_t lim = now + RADIO_SLICE_US;
    if (deadline_us < lim) lim = deadline_us;
    return dw_wait_irq(&g_radio.dev, lim);
}

int radio_temp_cc(int16_t *temp_cc) {
    uint64_t now = radio_now_us();
    if (!g_radio.temp_valid || now - g_radio.temp_us >= RADIO_TEMP_PERIOD_US) {
        int rc = dw_read_temp(&g_radio.dev, &g_radio.temp_cc);
        if (rc != DW_OK) return rc;
        g_radio.temp_valid = true;
        g_radio.temp_us = now;
    }
    *temp_cc = g_radio.temp_cc;
    return DW_OK;
}

/* ---- frames -------------------------------------------------------------------------- */

static void put16(uint8_t *b, uint16_t v) {
    b[0] = (uint8_t)v;
    b[1] = (uint8_t)(v >> 8);
}
static void put32(uint8_t *b, uint32_t v) {
    for (int i = 0; i < 4; i++) b[i] = (uint8_t)(v >> (8 * i));
}
static void put40(uint8_t *b, uint64_t v) {
    for (int i = 0; i < 5; i++) b[i] = (uint8_t)(v >> (8 * i));
}
static uint16_t get16(const uint8_t *b) { return (uint16_t)(b[0] | (b[1] << 8)); }
static uint32_t get32(const uint8_t *b) {
    return (uint32_t)b[0] | ((uint32_t)b[1] << 8) | ((uint32_t)b[2] << 16) | ((uint32_t)b[3] << 24);
}
static uint64_t get40(const uint8_t *b) {
    uint64_t v = 0;
    for (int i = 0; i < 5; i++) v |= (uint64_t)b[i] << (8 * i);
    return v;
}
static void putf(uint8_t *b, float f) {
    uint32_t u;
    memcpy(&u, &f, 4);
    put32(b, u);
}
static float getf(const uint8_t *b) {
    uint32_t u = get32(b);
    float f;
    memcpy(&f, &u, 4);
    return f;
}

static void put_q(uint8_t *b, const struct dw_rx_quality *q) {
    put16(b + 0, q->cir_pwr);
    put16(b + 2, q->rxpacc);
    put16(b + 4, q->rxpacc_nosat);
    put16(b + 6, q->fp_ampl1);
    put16(b + 8, q->fp_ampl2);
    put16(b + 10, q->fp_ampl3);
    put16(b + 12, q->std_noise);
    put16(b + 14, q->fp_index);
    put32(b + 16, (uint32_t)q->car_int);
    put32(b + 20, (uint32_t)q->ttcko);
    put32(b + 24, q->ttcki);
}

static void get_q(const uint8_t *b, struct dw_rx_quality *q) {
    q->cir_pwr = get16(b + 0);
    q->rxpacc = get16(b + 2);
    q->rxpacc_nosat = get16(b + 4);
    q->fp_ampl1 = get16(b + 6);
    q->fp_ampl2 = get16(b + 8);
    q->fp_ampl3 = get16(b + 10);
    q->std_noise = get16(b + 12);
    q->fp_index = get16(b + 14);
    q->car_int = (int32_t)get32(b + 16);
    q->ttcko = (int32_t)get32(b + 20);
    q->ttcki = get32(b + 24);
}

static size_t rf_len(uint8_t kind) {
    switch (kind) {
    case RF_P: return RF_P_LEN;
    case RF_M1: return RF_M1_LEN;
    case RF_M2: return RF_M2_LEN;
    case RF_M3: return RF_M3_LEN;
    case RF_REPORT: return RF_REPORT_LEN;
    default: return 0;
    }
}

size_t rf_encode(const struct rf_frame *f, uint8_t *b, size_t cap) {
    size_t n = rf_len(f->kind);
    if (n == 0 || cap < n) return 0;
    memset(b, 0, n);
    b[0] = RF_MAGIC;
    b[1] = f->kind;
    put16(b + 2, f->src);
    put16(b + 4, f->dst);
    put32(b + 6, f->seq);
    b[10] = f->gain;
    b[11] = f->idx;
    uint8_t *p = b + RF_HDR_LEN;
    switch (f->kind) {
    case RF_P:
        put16(p, f->step);
        p[2] = f->gain13;
        put40(p + 3, f->ts[0]);
        break;
    case RF_M1: put40(p, f->ts[0]); break;
    case RF_M2:
    case RF_M3:
        put40(p, f->ts[0]);
        put40(p + 5, f->ts[1]);
        break;
    case RF_REPORT:
        put40(p, f->ts[0]);
        put40(p + 5, f->ts[1]);
        put40(p + 10, f->ts[2]);
        put_q(p + 15, &f->q[0]);
        put_q(p + 15 + RF_Q_LEN, &f->q[1]);
        p[71] = f->tag_valid;
        putf(p + 72, f->e1_ps);
        putf(p + 76, f->z_ps);
        break;
    default: return 0;
    }
    return n;
}

bool rf_decode(const uint8_t *b, size_t len, struct rf_frame *f) {
    if (len < RF_HDR_LEN || b[0] != RF_MAGIC) return false;
    size_t n = rf_len(b[1]);
    if (n == 0 || len != n) return false;
    memset(f, 0, sizeof *f);
    f->kind = b[1];
    f->src = get16(b + 2);
    f->dst = get16(b + 4);
    f->seq = get32(b + 6);
    f->gain = b[10];
    f->idx = b[11];
    const uint8_t *p = b + RF_HDR_LEN;
    switch (f->kind) {
    case RF_P:
        if (f->idx > 2) return false;
        f->step = get16(p);
        f->gain13 = p[2];
        f->ts[0] = get40(p + 3);
        break;
    case RF_M1: f->ts[0] = get40(p); break;
    case RF_M2:
    case RF_M3:
        f->ts[0] = get40(p);
        f->ts[1] = get40(p + 5);
        break;
    default: /* RF_REPORT */
        f->ts[0] = get40(p);
        f->ts[1] = get40(p + 5);
        f->ts[2] = get40(p + 10);
        get_q(p + 15, &f->q[0]);
        get_q(p + 15 + RF_Q_LEN, &f->q[1]);
        f->tag_valid = p[71];
        f->e1_ps = getf(p + 72);
        f->z_ps = getf(p + 76);
        break;
    }
    return true;
}
