/* Ranging roles against the fake DW1000 with a scripted peer: the reference's M1/M3 timing
 * and its range_record (all six timestamps, qualities), single-sided, a lost reply; the tag's
 * M2 and report (timestamps carried, grid, gain from M1), single-sided, M3 timeout. */
#include <stdio.h>
#include <string.h>

#include "check.h"
#include "dw1000_regs.h"
#include "fake_spi.c"
#include "measure.h"
#include "radio.h"
#include "ranging.h"
#include "sequencer.h"

static struct fake_spi F;
#define ANTD 16436u
#define TAG 9u
#define REPLY_US 600u
#define TOF_U 2000u /* about 9.4 m */

static void attach(void) {
    fake_init(&F);
    fake_use_clock(&F);
    radio_set_clock(fake_clock_us);
    CHECK(radio_attach(&F.ops) == DW_OK);
    struct dw_config cfg;
    dw_config_default(&cfg);
    cfg.tx_antd = ANTD;
    CHECK(dw_configure(&g_radio.dev, &cfg) == DW_OK);
    struct proto_stop_req sr;
    struct proto_stop_resp sp;
    uint16_t det;
    handle_stop(&sr, &sp, &det);
}

/* ---- scripted tag ------------------------------------------------------------------------- */
static bool tag_answers_m1 = true;
static uint64_t tag_clock = 0x0123456789ull; /* the tag's stamps: its own clock */
static uint64_t last_t1t, last_t2t, last_t3t, last_t2r;

static struct fake_rx *inject(uint64_t at, const struct rf_frame *f, uint64_t stamp) {
    uint8_t b[RF_REPORT_LEN];
    size_t n = rf_encode(f, b, sizeof b);
    CHECK(n > 0);
    return fake_add_rx(&F, at, b, n, stamp);
}

static void tag_script(struct fake_spi *f, const struct fake_tx *tx) {
    struct rf_frame m;
    CHECK(rf_decode(tx->data, tx->len, &m));
    uint64_t reply_u = dw_us_to_units(REPLY_US);
    struct rf_frame a;
    memset(&a, 0, sizeof a);
    a.src = TAG;
    a.dst = m.src;
    a.seq = m.seq;
    a.gain = m.gain;
    a.idx = m.idx;
    uint64_t at = tx->at_us + REPLY_US;
    if (m.kind == RF_M1) {
        if (!tag_answers_m1) return;
        last_t1t = (tag_clock + m.seq * 1000000ull) & DW_TIME_MASK;
        last_t2t = ((last_t1t + reply_u) & ~0x1FFull) + ANTD;
        last_t2r = (m.ts[0] + 2 * TOF_U + (last_t2t - last_t1t)) & DW_TIME_MASK;
        a.kind = RF_M2;
        a.ts[0] = last_t1t;
        a.ts[1] = last_t2t;
        struct fake_rx *r = inject(at, &a, last_t2r);
        r->cir_pwr = 222;
        if (m.idx == 1) { /* single-sided: the report follows M2 */
            a.kind = RF_REPORT;
            a.ts[2] = 0;
            a.q[0].cir_pwr = 111;
            inject(at + REPLY_US, &a, 0);
        }
    } else if (m.kind == RF_M3) {
        CHECK(m.ts[0] == last_t2r && m.ts[1] == tx->stamp);
        last_t3t = (last_t2t + (m.ts[1] - last_t2r) + 2 * TOF_U) & DW_TIME_MASK;
        a.kind = RF_REPORT;
        a.ts[0] = last_t1t;
        a.ts[1] = last_t2t;
        a.ts[2] = last_t3t;
        a.q[0].cir_pwr = 111;
        a.q[1].cir_pwr = 333;
        a.q[1].car_int = -77;
        inject(at, &a, 0);
    }
    (void)f;
}

static struct proto_range_start_req rreq(uint8_t method, uint32_t count, uint32_t period) {
    struct proto_range_start_req r;
    memset(&r, 0, sizeof r);
    r.method = method;
    r.tag = TAG;
    r.count = count;
    r.period_us = period;
    r.reply_us = REPLY_US;
    r.gain = 0x2A;
    return r;
}

static void run_ref(struct rng_ref *r, struct meas_counters *c) {
    for (int i = 0; i < 100000; i++) {
        int rc = rng_ref_poll(r, c);
        if (rc <= 0) {
            CHECK(rc == 0);
            return;
        }
    }
    CHECK(!"reference did not finish");
}

static void test_ref_validation(void) {
    attach();
    struct proto_range_start_req r = rreq(3, 1, 10000);
    struct proto_range_start_resp rs;
    uint16_t det = 0;
    CHECK(handle_range_start(&r, &rs, &det) == PROTO_ERR_BAD_VALUE && det == 0);
    r = rreq(0, 1, 10000);
    r.tag = 0xFFFF;
    CHECK(handle_range_start(&r, &rs, &det) == PROTO_ERR_BAD_VALUE && det == 1);
    r = rreq(0, 0, 10000);
    CHECK(handle_range_start(&r, &rs, &det) == PROTO_ERR_BAD_VALUE && det == 2);
    r = rreq(0, 1, 3 * REPLY_US);
    CHECK(handle_range_start(&r, &rs, &det) == PROTO_ERR_BAD_VALUE && det == 3);
    r = rreq(0, 1, 10000);
    r.reply_us = 100;
    CHECK(handle_range_start(&r, &rs, &det) == PROTO_ERR_BAD_VALUE && det == 4);
    r = rreq(0, 1, 10000);
    r.gain = 0xE0;
    CHECK(handle_range_start(&r, &rs, &det) == PROTO_ERR_BAD_VALUE && det == 5);
    struct proto_listen_req lq = {.role = 1, .peer = 1, .reply_us = 50};
    struct proto_listen_resp lr;
    CHECK(handle_listen(&lq, &lr, &det) == PROTO_ERR_BAD_VALUE && det == 2);
    lq.role = 2;
    CHECK(handle_listen(&lq, &lr, &det) == PROTO_ERR_BAD_VALUE && det == 0);
    CHECK(measure_mode() == MEAS_IDLE);
}

static void test_ref_paper(void) {
    attach();
    F.on_tx = tag_script;
    tag_answers_m1 = true;
    struct proto_range_start_req q = rreq(0, 3, 10000);
    struct proto_range_start_resp rs;
    uint16_t det;
    CHECK(handle_range_start(&q, &rs, &det) == 0); /* sets up the ranges queue */
    struct meas_counters *c = measure_counters_mut();
    struct rng_ref r;
    rng_ref_start(&r, &q, 4);
    run_ref(&r, c);
    CHECK(F.ntx == 6 && c->sent == 6 && c->records == 3 && c->late == 0 && c->incomplete == 0);
    CHECK(measure_queued() == 3);
    struct proto_range_record rec;
    uint32_t idx;
    CHECK(measure_peek(2, &idx, NULL, &rec) && idx == 2);
    const struct fake_tx *m1 = &F.txlog[4], *m3 = &F.txlog[5];
    struct rf_frame f1, f3;
    CHECK(rf_decode(m1->data, m1->len, &f1) && f1.kind == RF_M1 && f1.seq == 2 && f1.dst == TAG && f1.src == 4);
    CHECK(f1.ts[0] == m1->stamp && m1->gain == 0x2A && f1.idx == 0);
    CHECK(rf_decode(m3->data, m3->len, &f3) && f3.kind == RF_M3);
    CHECK(rec.seq == 2 && rec.method == 0 && rec.gain == 0x2A && rec.tag_station == TAG);
    CHECK(rec.t[0] == m1->stamp);
    CHECK(rec.t[1] == last_t1t && rec.t[2] == last_t2t);
    CHECK(rec.t[3] == last_t2r);
    CHECK(rec.t[4] == m3->stamp && rec.t[4] == (((last_t2r + dw_us_to_units(REPLY_US)) & ~0x1FFull) + ANTD));
    CHECK(rec.t[5] == last_t3t);
    CHECK(rec.q_r2.cir_pwr == 222 && rec.q_t1.cir_pwr == 111 && rec.q_t3.cir_pwr == 333 && rec.q_t3.car_int == -77);
    CHECK(rec.temp_cc != 0 && rec.range_mm == INT32_MIN); /* no calibration tables here */
    /* M1s are on the period grid */
    uint64_t dp = F.txlog[4].at_us - F.txlog[2].at_us;
    CHECK(dp >= 9999 && dp <= 10001);
    /* the tag's times are consistent: ToF from the record = TOF_U */
    double ra = (double)dw_time_sub(rec.t[3], rec.t[0]), db = (double)dw_time_sub(rec.t[2], rec.t[1]);
    CHECK((ra - db) / 2 == TOF_U);
}

static void test_ref_ss_and_loss(void) {
    attach();
    F.on_tx = tag_script;
    tag_answers_m1 = true;
    struct proto_range_start_req q = rreq(1, 2, 5000);
    struct proto_range_start_resp rs;
    uint16_t det;
    CHECK(handle_range_start(&q, &rs, &det) == 0);
    struct meas_counters *c = measure_counters_mut();
    struct rng_ref r;
    rng_ref_start(&r, &q, 4);
    run_ref(&r, c);
    CHECK(F.ntx == 2 && c->records == 2);
    struct proto_range_record rec;
    CHECK(measure_peek(1, NULL, NULL, &rec));
    CHECK(rec.method == 1 && rec.t[4] == 0 && rec.t[5] == 0 && rec.t[1] == last_t1t && rec.t[3] == last_t2r);
    /* the tag never answers: each exchange times out and the next one still runs */
    attach();
    F.on_tx = tag_script;
    tag_answers_m1 = false;
    q = rreq(0, 3, 8000);
    CHECK(handle_range_start(&q, &rs, &det) == 0);
    c = measure_counters_mut();
    rng_ref_start(&r, &q, 4);
    run_ref(&r, c);
    CHECK(F.ntx == 3 && c->records == 0 && c->rx_errors == 3 && c->incomplete == 3);
    CHECK(F.max_wait_step_us <= RADIO_SLICE_US);
    tag_answers_m1 = true;
    F.on_tx = NULL;
}

static void run_tag(struct rng_tag *t, struct meas_counters *c, uint64_t until) {
    while (F.now_us < until) CHECK(rng_tag_poll(t, c) == 1);
}

static void test_tag(void) {
    attach();
    struct proto_listen_req lq = {.role = 1, .peer = 5, .reply_us = REPLY_US};
    struct proto_listen_resp lr;
    uint16_t det;
    CHECK(handle_listen(&lq, &lr, &det) == 0 && measure_mode() == MEAS_RANGE_TAG);
    struct meas_counters *c = measure_counters_mut();
    struct rng_tag t;
    uint16_t me = radio_station_id();
    rng_tag_start(&t, 5, REPLY_US, me);
    struct rf_frame m;
    memset(&m, 0, sizeof m);
    m.kind = RF_M1;
    m.src = 6; /* not the peer: ignored */
    m.dst = me;
    m.seq = 41;
    m.gain = 0x21;
    uint64_t t0 = F.now_us + 1000;
    inject(t0, &m, 100);
    m.src = 5;
    m.seq = 42;
    /* RX stamps follow the chip's clock; the counter wraps between M1 and M2 */
    F.sys_offset = (DW_TIME_MASK + 1 - (t0 + 2000) * 319488u / 5u - 4096u) & DW_TIME_MASK;
    uint64_t t1t = fake_units_at(&F, t0 + 2000);
    CHECK(t1t == DW_TIME_MASK + 1 - 4096u);
    struct fake_rx *x = inject(t0 + 2000, &m, t1t);
    x->cir_pwr = 4321;
    /* the reference's M3 comes REPLY_US after M2 (scripted before the tag runs: the tag's
     * bounded waits would otherwise run the fake clock past its M3 deadline) */
    struct rf_frame m3;
    memset(&m3, 0, sizeof m3);
    m3.kind = RF_M3;
    m3.src = 5;
    m3.dst = me;
    m3.seq = 42;
    m3.gain = 0x21;
    uint64_t at3 = t0 + 2000 + 2 * REPLY_US;
    uint64_t t3t = fake_units_at(&F, at3);
    x = inject(at3, &m3, t3t);
    x->cir_pwr = 999;
    run_tag(&t, c, t0 + 2000 + REPLY_US + 200);
    CHECK(F.ntx == 1);
    struct rf_frame m2;
    CHECK(rf_decode(F.txlog[0].data, F.txlog[0].len, &m2) && m2.kind == RF_M2 && m2.dst == 5 && m2.seq == 42);
    uint64_t t2t = ((t1t + dw_us_to_units(REPLY_US)) & ~0x1FFull & DW_TIME_MASK) + ANTD;
    CHECK(m2.ts[0] == t1t && m2.ts[1] == F.txlog[0].stamp && m2.ts[1] == t2t && F.txlog[0].gain == 0x21);
    CHECK(F.txlog[0].at_us == t0 + 2000 + REPLY_US);
    /* M3 -> report at t3t + reply */
    run_tag(&t, c, F.now_us + 3 * REPLY_US);
    CHECK(F.ntx == 2);
    struct rf_frame rep;
    CHECK(rf_decode(F.txlog[1].data, F.txlog[1].len, &rep) && rep.kind == RF_REPORT && rep.seq == 42 && rep.dst == 5);
    CHECK(rep.ts[0] == t1t && rep.ts[1] == t2t && rep.ts[2] == t3t);
    CHECK(rep.q[0].cir_pwr == 4321 && rep.q[1].cir_pwr == 999 && rep.tag_valid == 0);
    CHECK(F.txlog[1].stamp == ((((t3t + dw_us_to_units(REPLY_US)) & ~0x1FFull) + ANTD) & DW_TIME_MASK));
    CHECK(c->sent == 2 && c->incomplete == 0);
    /* single-sided: M2 then the report, no M3 */
    m.seq = 43;
    m.idx = 1;
    inject(F.now_us + 500, &m, fake_units_at(&F, F.now_us + 500));
    run_tag(&t, c, F.now_us + 500 + 3 * REPLY_US);
    CHECK(F.ntx == 4);
    CHECK(rf_decode(F.txlog[3].data, F.txlog[3].len, &rep) && rep.kind == RF_REPORT && rep.seq == 43 && rep.ts[2] == 0);
    /* M3 never comes: the tag gives up and listens again */
    m.seq = 44;
    m.idx = 0;
    inject(F.now_us + 500, &m, fake_units_at(&F, F.now_us + 500));
    run_tag(&t, c, F.now_us + 20000);
    CHECK(F.ntx == 5 && c->rx_errors == 1 && c->incomplete == 1 && t.st == RTAG_LISTEN);
    m.seq = 45;
    inject(F.now_us + 500, &m, fake_units_at(&F, F.now_us + 500));
    run_tag(&t, c, F.now_us + 500 + REPLY_US + 200);
    CHECK(F.ntx == 6);
    /* a reply that cannot be made in time is refused as late, not sent late */
    F.late_lead_units = dw_us_to_units(REPLY_US + 100);
    m.seq = 46;
    size_t before = F.ntx;
    uint32_t late0 = c->late;
    run_tag(&t, c, F.now_us + 20000); /* let the exchange 45 time out first */
    inject(F.now_us + 500, &m, fake_units_at(&F, F.now_us + 500));
    run_tag(&t, c, F.now_us + 3000);
    CHECK(F.ntx == before && c->late == late0 + 1);
}

static void test_frames(void) {
    struct rf_frame f, g;
    uint8_t b[RF_REPORT_LEN + 4];
    memset(&f, 0, sizeof f);
    f.kind = RF_REPORT;
    f.src = 0x1234;
    f.dst = 0xFFFF;
    f.seq = 0xA1B2C3D4u;
    f.gain = 0x5F;
    f.idx = 2;
    f.ts[0] = 0xFFFFFFFFFFull;
    f.ts[1] = 1;
    f.ts[2] = 0x8000000000ull;
    f.q[0].cir_pwr = 65535;
    f.q[0].car_int = -1048576;
    f.q[1].ttcko = -5;
    f.q[1].ttcki = 0xDEADBEEFu;
    f.tag_valid = 1;
    f.e1_ps = -123.5f;
    f.z_ps = 4567.25f;
    CHECK(rf_encode(&f, b, RF_REPORT_LEN - 1) == 0); /* buffer too small */
    CHECK(rf_encode(&f, b, sizeof b) == RF_REPORT_LEN);
    CHECK(b[0] == RF_MAGIC && b[1] == RF_REPORT && b[2] == 0x34 && b[3] == 0x12 && b[6] == 0xD4);
    CHECK(b[12] == 0xFF && b[16] == 0xFF && b[17] == 0x01); /* 40-bit little-endian stamps */
    CHECK(rf_decode(b, RF_REPORT_LEN, &g));
    CHECK(g.kind == f.kind && g.src == f.src && g.dst == f.dst && g.seq == f.seq && g.gain == f.gain && g.idx == 2);
    CHECK(g.ts[0] == f.ts[0] && g.ts[1] == 1 && g.ts[2] == f.ts[2]);
    CHECK(g.q[0].cir_pwr == 65535 && g.q[0].car_int == -1048576 && g.q[1].ttcko == -5 && g.q[1].ttcki == 0xDEADBEEFu);
    CHECK(g.tag_valid == 1 && g.e1_ps == -123.5f && g.z_ps == 4567.25f);
    CHECK(!rf_decode(b, RF_REPORT_LEN - 1, &g)); /* wrong length for the kind */
    b[0] ^= 1;
    CHECK(!rf_decode(b, RF_REPORT_LEN, &g));
    memset(&f, 0, sizeof f);
    f.kind = RF_P;
    f.idx = 2;
    f.step = 63;
    f.gain13 = 0x11;
    f.ts[0] = 0x123456789Aull;
    CHECK(rf_encode(&f, b, sizeof b) == RF_P_LEN);
    CHECK(rf_decode(b, RF_P_LEN, &g) && g.step == 63 && g.gain13 == 0x11 && g.ts[0] == 0x123456789Aull);
    b[11] = 3; /* P index out of range */
    CHECK(!rf_decode(b, RF_P_LEN, &g));
    f.kind = 9;
    CHECK(rf_encode(&f, b, sizeof b) == 0);
    CHECK(RF_P_LEN + 2 <= DW_MAX_FRAME && RF_REPORT_LEN + 2 <= DW_MAX_FRAME);
}

/* A tag that listened longer than half the 40-bit period (8.6 s) without reading SYS_TIME
 * still places its reply right: the M1 stamp is unwrapped against a fresh SYS_TIME. */
static void test_tag_long_listen(void) {
    attach();
    struct proto_listen_req lq = {.role = 1, .peer = 0xFFFF, .reply_us = REPLY_US};
    struct proto_listen_resp lr;
    uint16_t det;
    CHECK(handle_listen(&lq, &lr, &det) == 0);
    struct meas_counters *c = measure_counters_mut();
    struct rng_tag t;
    rng_tag_start(&t, 0xFFFF, REPLY_US, radio_station_id());
    uint64_t now_u;
    CHECK(radio_sys_now(&now_u) == DW_OK);
    F.now_us += 12000000; /* 12 s of listening */
    struct rf_frame m;
    memset(&m, 0, sizeof m);
    m.kind = RF_M1;
    m.src = 3;
    m.dst = RF_BROADCAST;
    m.seq = 1;
    m.gain = 0x10;
    uint64_t at = F.now_us + 500;
    inject(at, &m, fake_units_at(&F, at));
    run_tag(&t, c, at + REPLY_US + 200);
    CHECK(F.ntx == 1 && c->late == 0);
    CHECK(F.ntx == 1 && F.txlog[0].at_us == at + REPLY_US);
}

int main(void) {
    test_tag_long_listen();
    test_frames();
    test_ref_validation();
    test_ref_paper();
    test_ref_ss_and_loss();
    test_tag();
    return check_summary();
}
