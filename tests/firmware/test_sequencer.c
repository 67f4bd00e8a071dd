/* Sequencer and triplet receiver against the fake DW1000 and its fake clock: plan
 * validation (bad_value with the field index), triplet timing in both clocks, the 40-bit
 * wrap at 10 s spacing, bounded waits, late TX recovery, stop during a plan, triplet
 * assembly with losses, RX errors, the record queue and its dropped counter. */
#include <stdio.h>
#include <string.h>

#include "app.h"
#include "check.h"
#include "dw1000_regs.h"
#include "fake_spi.c"
#include "measure.h"
#include "radio.h"
#include "sequencer.h"

static struct fake_spi F;

static void attach(void) {
    fake_init(&F);
    fake_use_clock(&F);
    radio_set_clock(fake_clock_us);
    CHECK(radio_attach(&F.ops) == DW_OK);
    g_radio.dev.cfg.tx_antd = 0; /* set below through a configure */
    struct dw_config cfg;
    dw_config_default(&cfg);
    cfg.tx_antd = 16436;
    CHECK(dw_configure(&g_radio.dev, &cfg) == DW_OK);
    struct proto_stop_req sr;
    struct proto_stop_resp sp;
    uint16_t det;
    handle_stop(&sr, &sp, &det); /* idle, counters of the previous test gone at next start */
}

static struct proto_seq_start_req req(uint32_t per_step, uint32_t spacing, uint32_t period, uint8_t g13,
                                      const uint8_t *g2, uint16_t n) {
    struct proto_seq_start_req r;
    memset(&r, 0, sizeof r);
    r.per_step = per_step;
    r.spacing_us = spacing;
    r.period_us = period;
    r.gain13 = g13;
    memcpy(r.gains2, g2, n);
    r.gains2_len = n;
    return r;
}

static void test_plan_validation(void) {
    attach();
    struct dw_config cfg;
    dw_config_default(&cfg);
    uint8_t g[65];
    memset(g, 0x10, sizeof g);
    struct seq_plan plan;
    uint16_t det = 0;
    struct proto_seq_start_req r = req(10, 2000, 5000, 0x0F, g, 3);
    CHECK(seq_plan_from_req(&r, &cfg, &plan, &det) == 0 && seq_total(&plan) == 30 && plan.nsteps == 3);
    r = req(0, 2000, 5000, 0x0F, g, 3);
    CHECK(seq_plan_from_req(&r, &cfg, &plan, &det) == PROTO_ERR_BAD_VALUE && det == 0);
    r = req(0x08000000u, 2000, 5000, 0x0F, g, 64); /* total does not fit u32 */
    CHECK(seq_plan_from_req(&r, &cfg, &plan, &det) == PROTO_ERR_BAD_VALUE && det == 0);
    r = req(1, 149, 5000, 0x0F, g, 3);
    CHECK(seq_plan_from_req(&r, &cfg, &plan, &det) == PROTO_ERR_BAD_VALUE && det == 1);
    r = req(1, 10000001, 30000000, 0x0F, g, 3);
    CHECK(seq_plan_from_req(&r, &cfg, &plan, &det) == PROTO_ERR_BAD_VALUE && det == 1);
    r = req(1, 150, 400, 0x0F, g, 3); /* 2 x 150 + ~189 us frame + margin > 400 */
    CHECK(seq_plan_from_req(&r, &cfg, &plan, &det) == PROTO_ERR_BAD_VALUE && det == 2);
    uint32_t minp = seq_min_period_us(150, &cfg);
    CHECK(minp > 300 + 180 && minp < 300 + 300);
    r = req(1, 150, minp, 0x0F, g, 3);
    CHECK(seq_plan_from_req(&r, &cfg, &plan, &det) == 0);
    r = req(1, 10000000, 20000000, 0x0F, g, 1);
    CHECK(seq_plan_from_req(&r, &cfg, &plan, &det) == PROTO_ERR_BAD_VALUE && det == 2);
    r = req(1, 2000, 5000, 0xE3, g, 3); /* coarse 7 = output off */
    CHECK(seq_plan_from_req(&r, &cfg, &plan, &det) == PROTO_ERR_BAD_VALUE && det == 3);
    r = req(1, 2000, 5000, 0x0F, g, 0);
    CHECK(seq_plan_from_req(&r, &cfg, &plan, &det) == PROTO_ERR_BAD_VALUE && det == 4);
    r = req(1, 2000, 5000, 0x0F, g, 65);
    CHECK(seq_plan_from_req(&r, &cfg, &plan, &det) == PROTO_ERR_BAD_VALUE && det == 4);
    g[2] = 0xFF;
    r = req(1, 2000, 5000, 0x0F, g, 3);
    CHECK(seq_plan_from_req(&r, &cfg, &plan, &det) == PROTO_ERR_BAD_VALUE && det == 4);
    /* the same through the handler; nothing starts */
    struct proto_seq_start_resp resp;
    det = 0;
    CHECK(handle_seq_start(&r, &resp, &det) == PROTO_ERR_BAD_VALUE && det == 4);
    CHECK(measure_mode() == MEAS_IDLE && F.ntx == 0);
}

/* Run seq_poll to the end; returns polls used (bounded). */
static unsigned run_seq(struct seq_tx *s, struct meas_counters *c, unsigned max_polls) {
    unsigned n = 0;
    while (n < max_polls) {
        n++;
        int r = seq_poll(s, c);
        if (r <= 0) {
            CHECK(r == 0);
            break;
        }
    }
    return n;
}

static const uint8_t timing_g2[2] = {0x0E, 0x0D};

/* The plan of test_timing (2 steps x 2 triplets, P2 gains timing_g2) run to its end on a fresh chip whose
 * TX_TIME reads tx_time_skew more than the stamp; returns the polls taken. */
static unsigned run_timing_plan(uint64_t tx_time_skew, struct meas_counters *c) {
    attach();
    F.tx_time_skew = tx_time_skew;
    struct proto_seq_start_req r = req(2, 2000, 10000, 0x0F, timing_g2, 2);
    struct seq_plan plan;
    uint16_t det;
    CHECK(seq_plan_from_req(&r, &g_radio.dev.cfg, &plan, &det) == 0);
    struct seq_tx s;
    memset(c, 0, sizeof *c);
    seq_start(&s, &plan, 7);
    return run_seq(&s, c, 100000);
}

/* A chip whose TX_TIME disagrees with the stamp the frame announced: each one is counted
 * (the host reads the counter in stop and status). */
static void test_stamp_mismatch(void) {
    struct meas_counters c;
    CHECK(run_timing_plan(512, &c) < 100000);
    CHECK(c.sent == 4 && c.stamp_mismatch == 12);
}

static void test_timing(void) {
    struct meas_counters c;
    unsigned polls = run_timing_plan(0, &c);
    CHECK(polls < 100000);
    CHECK(c.sent == 4 && c.late == 0 && c.tx_timeouts == 0 && c.stamp_mismatch == 0);
    CHECK(F.ntx == 12);
    uint64_t sp_u = dw_us_to_units(2000), per_u = dw_us_to_units(10000);
    for (size_t i = 0; i < F.ntx && i < 12; i++) {
        struct rf_frame f;
        CHECK(rf_decode(F.txlog[i].data, F.txlog[i].len, &f));
        CHECK(f.kind == RF_P && f.src == 7 && f.dst == RF_BROADCAST);
        CHECK(f.idx == i % 3 && f.seq == i / 3 && f.step == (i / 3) / 2);
        uint8_t want_gain = f.idx == 1 ? timing_g2[f.step] : 0x0F;
        CHECK(f.gain == want_gain && F.txlog[i].gain == want_gain && f.gain13 == 0x0F);
        CHECK(f.ts[0] == F.txlog[i].stamp); /* the frame carries its own TX_STAMP */
        CHECK(((F.txlog[i].stamp - 16436) & 0x1FF) == 0); /* on the grid, + TX_ANTD */
        if (i % 3 != 0) {
            uint64_t d = dw_time_sub(F.txlog[i].stamp, F.txlog[i - 1].stamp);
            CHECK(d + 512 > sp_u && d < sp_u + 512);
            uint64_t dt = F.txlog[i].at_us - F.txlog[i - 1].at_us;
            CHECK(dt >= 1999 && dt <= 2001);
        } else if (i > 0) {
            uint64_t d = dw_time_sub(F.txlog[i].stamp, F.txlog[i - 3].stamp);
            CHECK(d + 512 > per_u && d < per_u + 512);
            uint64_t dt = F.txlog[i].at_us - F.txlog[i - 3].at_us;
            CHECK(dt >= 9999 && dt <= 10001);
        }
    }
    CHECK(F.max_wait_step_us <= RADIO_SLICE_US);
}

static void test_long_spacing_wrap(void) {
    attach();
    F.sys_offset = 0xFFF0000000ull; /* SYS_TIME wraps during the triplet */
    uint8_t g2[1] = {0x20};
    struct dw_config *cfg = &g_radio.dev.cfg;
    uint32_t per = seq_min_period_us(10000000u, cfg);
    struct proto_seq_start_req r = req(1, 10000000u, per, 0x0F, g2, 1);
    struct seq_plan plan;
    uint16_t det;
    CHECK(seq_plan_from_req(&r, cfg, &plan, &det) == 0);
    struct seq_tx s;
    struct meas_counters c;
    memset(&c, 0, sizeof c);
    seq_start(&s, &plan, 1);
    unsigned polls = run_seq(&s, &c, 100000);
    CHECK(c.sent == 1 && c.late == 0 && F.ntx == 3);
    CHECK(polls >= 20000000u / RADIO_SLICE_US); /* the waits were sliced */
    CHECK(F.max_wait_step_us <= RADIO_SLICE_US);
    uint64_t sp_u = dw_us_to_units(10000000u);
    uint64_t d12 = dw_time_sub(F.txlog[1].stamp, F.txlog[0].stamp);
    uint64_t d13 = dw_time_sub(F.txlog[2].stamp, F.txlog[0].stamp); /* 20 s > 2^40 units */
    CHECK(d12 + 512 > sp_u && d12 < sp_u + 512);
    CHECK(d13 + 1024 > ((2 * sp_u) & DW_TIME_MASK) && d13 < ((2 * sp_u) & DW_TIME_MASK) + 1024);
    CHECK(F.txlog[2].stamp < F.txlog[0].stamp); /* it did wrap */
    CHECK(F.txlog[1].at_us - F.txlog[0].at_us >= 9999999 && F.txlog[1].at_us - F.txlog[0].at_us <= 10000001);
}

static void test_late(void) {
    attach();
    F.refuse_tx = 4; /* the 5th delayed TX: P2 of triplet 1 */
    uint8_t g2[1] = {0x11};
    struct proto_seq_start_req r = req(4, 2000, 8000, 0x0F, g2, 1);
    struct seq_plan plan;
    uint16_t det;
    CHECK(seq_plan_from_req(&r, &g_radio.dev.cfg, &plan, &det) == 0);
    struct seq_tx s;
    struct meas_counters c;
    memset(&c, 0, sizeof c);
    seq_start(&s, &plan, 3);
    run_seq(&s, &c, 100000);
    CHECK(c.late == 1 && c.sent == 3);
    CHECK(F.ntx == 3 + 1 + 3 + 3); /* triplet 1 stopped after P1 */
    struct rf_frame f;
    CHECK(rf_decode(F.txlog[4].data, F.txlog[4].len, &f) && f.seq == 2 && f.idx == 0);
    CHECK((fake_status(&F) & DW_ST_HPDWARN) == 0);
    /* a plan the chip cannot keep up with: 150 us spacing at preamble 128 (the frame is longer) */
    attach();
    struct dw_config *cfg = &g_radio.dev.cfg;
    r = req(3, 150, seq_min_period_us(150, cfg), 0x0F, g2, 1);
    CHECK(seq_plan_from_req(&r, cfg, &plan, &det) == 0);
    memset(&c, 0, sizeof c);
    seq_start(&s, &plan, 3);
    run_seq(&s, &c, 100000);
    CHECK(c.late == 3 && c.sent == 0 && F.ntx == 3); /* each P1 goes, each P2 is refused */
    /* with preamble 64 the same spacing is possible */
    attach();
    struct dw_config c64;
    dw_config_default(&c64);
    c64.preamble_len = 64;
    CHECK(dw_configure(&g_radio.dev, &c64) == DW_OK);
    r = req(3, 150, seq_min_period_us(150, &c64) + 200, 0x0F, g2, 1);
    CHECK(seq_plan_from_req(&r, &c64, &plan, &det) == 0);
    memset(&c, 0, sizeof c);
    seq_start(&s, &plan, 3);
    run_seq(&s, &c, 100000);
    CHECK(c.late == 0 && c.sent == 3 && F.ntx == 9);
}

static void test_stop_during_plan(void) {
    attach();
    uint8_t g2[3] = {0x10, 0x11, 0x12};
    struct proto_seq_start_req r = req(1000, 2000, 6000, 0x0F, g2, 3);
    struct proto_seq_start_resp resp;
    uint16_t det = 0;
    CHECK(handle_seq_start(&r, &resp, &det) == 0 && resp.total == 3000);
    CHECK(measure_mode() == MEAS_SEQUENCER && measure_busy() && measure_idle_us() == 0);
    CHECK(handle_seq_start(&r, &resp, &det) == PROTO_ERR_BUSY);
    uint64_t t0 = F.now_us;
    while (F.now_us < t0 + 60000) {
        uint64_t before = F.now_us;
        measure_poll();
        CHECK(F.now_us - before <= RADIO_SLICE_US); /* the host link is served often */
    }
    size_t sent_frames = F.ntx;
    CHECK(sent_frames >= 27 && sent_frames <= 33);
    struct proto_status_req sq;
    struct proto_status_resp st;
    CHECK(handle_status(&sq, &st, &det) == 0 && st.state == 1 && st.done == 0 && st.sent >= 9);
    struct proto_stop_req q;
    struct proto_stop_resp sp;
    CHECK(handle_stop(&q, &sp, &det) == 0);
    CHECK(sp.sent == sent_frames / 3 && sp.late == 0);
    CHECK(measure_mode() == MEAS_IDLE && !measure_busy());
    for (int i = 0; i < 50; i++) measure_poll();
    F.now_us += 100000;
    measure_poll();
    CHECK(F.ntx == sent_frames); /* nothing more goes out */
    /* a plan that finishes reports done */
    r = req(2, 2000, 6000, 0x0F, g2, 1);
    CHECK(handle_seq_start(&r, &resp, &det) == 0 && resp.total == 2);
    for (int i = 0; i < 1000 && measure_busy(); i++) measure_poll();
    CHECK(handle_status(&sq, &st, &det) == 0 && st.state == 1 && st.done == 1 && st.sent == 2);
}

static size_t p_frame(uint8_t *buf, uint16_t src, uint32_t seq, uint8_t idx, uint16_t step, uint8_t gain,
                      uint64_t ts) {
    struct rf_frame f;
    memset(&f, 0, sizeof f);
    f.kind = RF_P;
    f.src = src;
    f.dst = RF_BROADCAST;
    f.seq = seq;
    f.idx = idx;
    f.step = step;
    f.gain = gain;
    f.gain13 = 0x0F;
    f.ts[0] = ts;
    return rf_encode(&f, buf, RF_P_LEN);
}

static void test_triplet_rx(void) {
    attach();
    struct proto_listen_req lq = {.role = 0, .peer = 7, .reply_us = 0};
    struct proto_listen_resp lr;
    uint16_t det;
    CHECK(handle_listen(&lq, &lr, &det) == 0 && measure_mode() == MEAS_LISTEN);
    uint8_t b[RF_P_LEN];
    uint64_t t = F.now_us + 1000;
    uint64_t base = 0xFFFFF00000ull; /* RX stamps wrap inside the first triplet */
    /* A: complete */
    for (uint8_t i = 0; i < 3; i++) {
        struct fake_rx *x = fake_add_rx(&F, t + 2000u * i, b, p_frame(b, 7, 0, i, 0, i == 1 ? 0x33 : 0x0F, 1000u + i), base + 128000u * i);
        x->cir_pwr = (uint16_t)(100 + i);
        x->car_int_raw = 0x1FFFFE;
    }
    t += 10000;
    /* B: P1 P2, then C starts: B is incomplete */
    fake_add_rx(&F, t, b, p_frame(b, 7, 1, 0, 0, 0x0F, 2000), 1);
    fake_add_rx(&F, t + 2000, b, p_frame(b, 7, 1, 1, 0, 0x33, 2001), 2);
    t += 10000;
    /* a frame of another station in between is ignored */
    fake_add_rx(&F, t - 100, b, p_frame(b, 9, 2, 1, 0, 0x33, 5), 5);
    /* C complete, with an RX error before P3 */
    fake_add_rx(&F, t, b, p_frame(b, 7, 2, 0, 1, 0x0F, 3000), 10);
    fake_add_rx(&F, t + 2000, b, p_frame(b, 7, 2, 1, 1, 0x34, 3001), 11);
    fake_add_rx_error(&F, t + 3000);
    fake_add_rx(&F, t + 4000, b, p_frame(b, 7, 2, 2, 1, 0x0F, 3002), 12);
    t += 10000;
    /* D: P1 lost: orphan P2 and P3 */
    fake_add_rx(&F, t + 2000, b, p_frame(b, 7, 3, 1, 1, 0x34, 4001), 21);
    fake_add_rx(&F, t + 4000, b, p_frame(b, 7, 3, 2, 1, 0x0F, 4002), 22);
    /* E: P3 before P2 (out of order) */
    t += 10000;
    fake_add_rx(&F, t, b, p_frame(b, 7, 4, 0, 1, 0x0F, 1), 31);
    fake_add_rx(&F, t + 2000, b, p_frame(b, 7, 4, 2, 1, 0x0F, 3), 32);
    F.regs[DW_REG_TX_CAL][DW_TC_SARL + 1] = 0x82;
    /* drive a receiver directly (measure_poll would stream the records out) */
    struct meas_counters *c = measure_counters_mut();
    struct trip_rx rx;
    trip_rx_start(&rx, 7);
    while (F.now_us < t + 10000) CHECK(trip_rx_poll(&rx, c) == 1);
    CHECK(F.rx_missed == 0);
    CHECK(c->records == 2 && c->rx_errors == 1);
    CHECK(c->incomplete == 3); /* B abandoned, D's orphan P2, E out of order */
    CHECK(measure_queued() == 2);
    struct proto_triplet_record a, cc;
    uint32_t ia = 99, ic = 99;
    CHECK(measure_peek(0, &ia, &a, NULL) && measure_peek(1, &ic, &cc, NULL) && !measure_peek(2, NULL, NULL, NULL));
    CHECK(ia == 0 && ic == 1);
    CHECK(a.seq == 0 && a.step == 0 && a.tx_station == 7 && a.gain13 == 0x0F && a.gain2 == 0x33);
    CHECK(a.tx[0] == 1000 && a.tx[1] == 1001 && a.tx[2] == 1002);
    CHECK(a.rx[0] == base && a.rx[1] == ((base + 128000u) & DW_TIME_MASK) && a.rx[2] == ((base + 256000u) & DW_TIME_MASK));
    CHECK(a.q[0].cir_pwr == 100 && a.q[1].cir_pwr == 101 && a.q[2].cir_pwr == 102);
    CHECK(a.q[2].car_int == -2 && a.q[0].rxpacc == 120);
    CHECK(a.temp_cc == 2 * 114 + 2300); /* UM 6.4: 1.14 degC per LSB */
    CHECK(cc.seq == 2 && cc.step == 1 && cc.gain2 == 0x34 && cc.rx[2] == 12 && cc.tx[2] == 3002);
    /* ring full of unsent records: the oldest are overwritten and counted as dropped, indices
     * keep running */
    for (int i = 0; i < 38; i++) measure_emit_triplet(&a);
    CHECK(measure_queued() == MEAS_RING_CAP && c->records == 40 && c->dropped == 40 - MEAS_RING_CAP);
    uint32_t first = 0, last = 0;
    CHECK(measure_peek(0, &first, NULL, NULL) && first == 40 - MEAS_RING_CAP);
    CHECK(measure_peek(MEAS_RING_CAP - 1, &last, NULL, NULL) && last == 39);
    /* no host link in this test: streaming fails and the loss is counted */
    measure_flush();
    CHECK(measure_queued() == 0 && c->dropped == 40);
    struct proto_stop_req q;
    struct proto_stop_resp sp;
    CHECK(handle_stop(&q, &sp, &det) == 0 && sp.records == 40 && sp.dropped == 40 && sp.rx_errors == 1);
    /* after stop the ring still answers fetches: the newest MEAS_RING_CAP records */
    struct proto_triplets_fetch_req fq = {.first_index = 39, .count = 5};
    struct proto_triplets_fetch_resp fr;
    CHECK(handle_triplets_fetch(&fq, &fr, &det) == 0 && fr.oldest == 40 - MEAS_RING_CAP && fr.next == 40);
    CHECK(fr.first_index == 39 && fr.records_count == 1 && fr.records[0].seq == a.seq);
    fq.first_index = 40 - MEAS_RING_CAP;
    CHECK(handle_triplets_fetch(&fq, &fr, &det) == 0 && fr.records_count == PROTO_TRIPLETS_FETCH_RESP_RECORDS_MAX);
    fq.first_index = 40 - MEAS_RING_CAP - 1; /* overwritten: nothing, and oldest says why */
    CHECK(handle_triplets_fetch(&fq, &fr, &det) == 0 && fr.records_count == 0 && fr.oldest > fq.first_index);
    fq.first_index = 40; /* not produced yet */
    CHECK(handle_triplets_fetch(&fq, &fr, &det) == 0 && fr.records_count == 0);
    fq.count = 0;
    CHECK(handle_triplets_fetch(&fq, &fr, &det) == PROTO_ERR_BAD_VALUE && det == 1);
    struct proto_ranges_fetch_req rq = {.first_index = 0, .count = 1};
    struct proto_ranges_fetch_resp rr;
    CHECK(handle_ranges_fetch(&rq, &rr, &det) == PROTO_ERR_NOT_FOUND); /* the ring holds triplets */
}

static size_t sar_reads(void) {
    size_t n = 0;
    for (size_t i = 0; i < F.nlog; i++)
        if (!F.log[i].write && F.log[i].reg == DW_REG_TX_CAL && F.log[i].off == DW_TC_SARL) n++;
    return n;
}

static void test_temp_cache(void) {
    attach();
    fake_clear_log(&F);
    F.regs[DW_REG_TX_CAL][DW_TC_SARL + 1] = 0x81;
    int16_t t = 0;
    int rc = radio_temp_cc(&t);
    CHECK(rc == DW_OK && t == 2414 && sar_reads() == 1);
    F.regs[DW_REG_TX_CAL][DW_TC_SARL + 1] = 0x83;
    F.now_us += RADIO_TEMP_PERIOD_US - 100; /* the SAR read itself took 10 us */
    CHECK(radio_temp_cc(&t) == DW_OK && t == 2414 && sar_reads() == 1); /* cached */
    F.now_us += 100;
    CHECK(radio_temp_cc(&t) == DW_OK && t == 2642 && sar_reads() == 2);
}

int main(void) {
    test_temp_cache();
    test_plan_validation();
    test_timing();
    test_stamp_mismatch();
    test_long_spacing_wrap();
    test_late();
    test_stop_during_plan();
    test_triplet_rx();
    return check_summary();
}
