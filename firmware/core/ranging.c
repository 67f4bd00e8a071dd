/* See ranging.h. */
#include "ranging.h"

#include <string.h>

#include "caltable.h"
#include "dw1000_regs.h"
#include "radio.h"
#include "sequencer.h"

static struct dw_event s_ev;

static uint64_t grid(uint64_t u) { return u & ~(uint64_t)0x1FF; }

uint32_t rng_min_period_us(uint8_t method, uint32_t reply_us, const struct dw_config *cfg) {
    uint64_t replies = method == PROTO_RANGE_METHOD_SS ? 2u : 3u;
    uint64_t p = replies * reply_us + dw_frame_us(cfg, RF_REPORT_LEN) + 500u;
    return p > 0xFFFFFFFFull ? 0xFFFFFFFFu : (uint32_t)p;
}

int rng_ref_check(const struct proto_range_start_req *req, const struct dw_config *cfg, uint16_t *detail) {
    uint16_t bad = PROTO_DETAIL_NONE;
    if (req->method > PROTO_RANGE_METHOD_DS) bad = 0;
    else if (req->tag == RF_BROADCAST) bad = 1;
    else if (req->count == 0) bad = 2;
    else if (req->reply_us < RNG_REPLY_MIN_US || req->reply_us > RNG_REPLY_MAX_US) bad = 4;
    else if (req->period_us < rng_min_period_us(req->method, req->reply_us, cfg)) bad = 3;
    else if (!seq_gain_ok(req->gain)) bad = 5;
    if (bad == PROTO_DETAIL_NONE) return 0;
    *detail = bad;
    return PROTO_ERR_BAD_VALUE;
}

int32_t rng_station_range_mm(const struct proto_range_record *rec, bool tag_valid, float e1_ps, float z_ps) {
    return caltable_ref_range_mm(rec->t, rec->q_r2.cir_pwr, rec->q_r2.rxpacc, rec->q_r2.rxpacc_nosat, tag_valid,
                                 e1_ps, z_ps);
}

/* Program a delayed TX of frame f at dx (unwrapped device time); the frame's stamp slot is
 * filled first. now_u: SYS_TIME just read (unwrapped). Returns DW_OK, DW_ELATE (counted by
 * the caller) or an error. */
static int send_at_ext(struct rf_frame *f, uint64_t now_u, uint64_t dx, uint64_t *stamp_slot,
                       uint64_t *deadline_us) {
    struct dw_dev *d = &g_radio.dev;
    if (dx < now_u + dw_us_to_units(seq_min_lead_us(&d->cfg))) return DW_ELATE;
    *stamp_slot = dw_tx_stamp_for(dx, d->cfg.tx_antd);
    uint8_t buf[RF_REPORT_LEN];
    size_t n = rf_encode(f, buf, sizeof buf);
    if (n == 0) return DW_EARG;
    int rc = dw_tx_delayed(d, buf, n, dx & DW_TIME_MASK, f->gain);
    if (rc != DW_OK) return rc;
    *deadline_us = radio_now_us() + dw_units_to_us(dx - now_u) + dw_frame_us(&d->cfg, n) + RNG_MARGIN_US;
    return DW_OK;
}

/* The same at a 40-bit stamp (a reception, or our own TX stamp) + offset: SYS_TIME is read
 * first, so the stamp unwraps against the present however long the station listened. */
static int send_after(struct rf_frame *f, uint64_t stamp40, uint64_t offset_u, uint64_t *stamp_slot,
                      uint64_t *deadline_us) {
    uint64_t now_u;
    int rc = radio_sys_now(&now_u);
    if (rc != DW_OK) return rc;
    return send_at_ext(f, now_u, radio_unwrap(stamp40) + offset_u, stamp_slot, deadline_us);
}

/* ---- reference ---------------------------------------------------------------------------- */

void rng_ref_start(struct rng_ref *r, const struct proto_range_start_req *req, uint16_t src) {
    memset(r, 0, sizeof *r);
    r->method = req->method;
    r->gain = req->gain;
    r->tag = req->tag;
    r->src = src;
    r->count = req->count;
    r->reply_us = req->reply_us;
    r->period_u = dw_us_to_units(req->period_us);
    r->reply_u = dw_us_to_units(req->reply_us);
    r->st = RREF_SCHED_M1;
}

static void ref_next(struct rng_ref *r) {
    if (++r->k >= r->count) {
        r->st = RREF_DONE;
        return;
    }
    r->t1 += r->period_u;
    r->st = RREF_SCHED_M1;
}

static void ref_fail(struct rng_ref *r, struct meas_counters *c) {
    c->incomplete++;
    (void)dw_trx_off(&g_radio.dev);
    ref_next(r);
}

static void frame_init(struct rf_frame *f, uint8_t kind, uint16_t src, uint16_t dst, uint32_t seq,
                       uint8_t gain, uint8_t method) {
    memset(f, 0, sizeof *f);
    f->kind = kind;
    f->src = src;
    f->dst = dst;
    f->seq = seq;
    f->gain = gain;
    f->idx = method;
}

static int ref_sched_m1(struct rng_ref *r, struct meas_counters *c) {
    struct dw_dev *d = &g_radio.dev;
    uint64_t now_u;
    int rc = radio_sys_now(&now_u);
    if (rc != DW_OK) return rc;
    uint64_t lead_min = dw_us_to_units(seq_min_lead_us(&d->cfg));
    if (!r->started || r->t1 < now_u + lead_min) {
        r->t1 = grid(now_u + dw_us_to_units(RNG_LEAD_US) + 0x1FF);
        r->started = true;
    }
    uint64_t ahead_u = dw_us_to_units(RNG_PROGRAM_AHEAD_US);
    if (r->t1 > now_u + ahead_u) {
        int w = radio_wait(radio_now_us() + dw_units_to_us(r->t1 - now_u - ahead_u / 2));
        if (w < 0) return w;
        return w == 1 ? dw_service(d, &s_ev) : DW_OK;
    }
    memset(&r->rec, 0, sizeof r->rec);
    r->rec.seq = r->k;
    r->rec.method = r->method;
    r->rec.gain = r->gain;
    r->rec.tag_station = r->tag;
    struct rf_frame f;
    frame_init(&f, RF_M1, r->src, r->tag, r->k, r->gain, r->method);
    rc = send_at_ext(&f, now_u, r->t1, &f.ts[0], &r->deadline_us);
    r->expect_stamp = f.ts[0];
    if (rc == DW_ELATE) {
        c->late++;
        ref_next(r);
        return DW_OK;
    }
    if (rc != DW_OK) return rc;
    r->st = RREF_WAIT_M1_TX;
    return DW_OK;
}

/* Wait for the next event of this exchange; returns 1 with s_ev filled, 0 nothing yet,
 * 2 deadline passed, <0 error. RX errors are counted and waited through. */
static int ref_event(struct rng_ref *r, struct meas_counters *c) {
    int w = radio_wait(r->deadline_us);
    if (w < 0) return w;
    if (w == 0) return radio_now_us() >= r->deadline_us ? 2 : 0;
    int rc = dw_service(&g_radio.dev, &s_ev);
    if (rc != DW_OK) return rc;
    if (s_ev.kind == DW_EV_RX_ERROR) {
        c->rx_errors++;
        return 0;
    }
    return s_ev.kind == DW_EV_NONE ? 0 : 1;
}

static bool from_tag(const struct rng_ref *r, const struct rf_frame *f, uint8_t kind) {
    return f->kind == kind && f->src == r->tag && f->dst == r->src && f->seq == r->k;
}

static int ref_rx_on(struct rng_ref *r, uint32_t wait_us) {
    r->deadline_us = radio_now_us() + wait_us;
    return dw_rx_enable(&g_radio.dev);
}

static int ref_poll_wait(struct rng_ref *r, struct meas_counters *c) {
    struct dw_dev *d = &g_radio.dev;
    int e = ref_event(r, c);
    if (e < 0) return e;
    if (e == 2) {
        if (r->st == RREF_WAIT_M2 || r->st == RREF_WAIT_REPORT) c->rx_errors++;
        else c->tx_timeouts++;
        ref_fail(r, c);
        return DW_OK;
    }
    if (e == 0) return DW_OK;
    uint32_t rx_wait = r->reply_us + dw_frame_us(&d->cfg, RF_REPORT_LEN) + RNG_MARGIN_US;
    if (s_ev.kind == DW_EV_TX_DONE) {
        if (r->st == RREF_WAIT_M1_TX) {
            r->rec.t[0] = s_ev.stamp;
            c->sent++;
            r->st = RREF_WAIT_M2;
            return ref_rx_on(r, rx_wait);
        }
        if (r->st == RREF_WAIT_M3_TX) {
            r->rec.t[4] = s_ev.stamp;
            c->sent++;
            r->st = RREF_WAIT_REPORT;
            return ref_rx_on(r, rx_wait);
        }
        return DW_OK;
    }
    /* DW_EV_RX_GOOD: the receiver is off now */
    struct rf_frame f;
    bool ok = rf_decode(s_ev.data, s_ev.len, &f);
    if (r->st == RREF_WAIT_M2 && ok && from_tag(r, &f, RF_M2)) {
        r->rec.t[3] = s_ev.stamp;
        r->rec.t[1] = f.ts[0];
        r->rec.t[2] = f.ts[1];
        meas_q_to_proto(&s_ev.q, &r->rec.q_r2);
        if (r->method == PROTO_RANGE_METHOD_SS) {
            r->st = RREF_WAIT_REPORT;
            return ref_rx_on(r, rx_wait);
        }
        struct rf_frame m3;
        frame_init(&m3, RF_M3, r->src, r->tag, r->k, r->gain, r->method);
        m3.ts[0] = s_ev.stamp;
        int rc = send_after(&m3, s_ev.stamp, r->reply_u, &m3.ts[1], &r->deadline_us);
        if (rc == DW_ELATE) {
            c->late++;
            ref_fail(r, c);
            return DW_OK;
        }
        if (rc != DW_OK) return rc;
        r->st = RREF_WAIT_M3_TX;
        return DW_OK;
    }
    if (r->st == RREF_WAIT_REPORT && ok && from_tag(r, &f, RF_REPORT)) {
        r->rec.t[1] = f.ts[0];
        r->rec.t[2] = f.ts[1];
        r->rec.t[5] = r->method == PROTO_RANGE_METHOD_SS ? 0 : f.ts[2];
        meas_q_to_proto(&f.q[0], &r->rec.q_t1);
        if (r->method != 1) meas_q_to_proto(&f.q[1], &r->rec.q_t3);
        int rc = radio_temp_cc(&r->rec.temp_cc);
        if (rc != DW_OK) return rc;
        r->rec.range_mm = rng_station_range_mm(&r->rec, f.tag_valid != 0, f.e1_ps, f.z_ps);
        measure_emit_range(&r->rec);
        ref_next(r);
        return DW_OK;
    }
    /* someone else's frame: keep listening until the deadline */
    if (r->st == RREF_WAIT_M2 || r->st == RREF_WAIT_REPORT) return dw_rx_enable(d);
    return DW_OK;
}

int rng_ref_poll(struct rng_ref *r, struct meas_counters *c) {
    int rc;
    switch (r->st) {
    case RREF_SCHED_M1: rc = ref_sched_m1(r, c); break;
    case RREF_WAIT_M1_TX:
    case RREF_WAIT_M2:
    case RREF_WAIT_M3_TX:
    case RREF_WAIT_REPORT: rc = ref_poll_wait(r, c); break;
    default: return 0;
    }
    if (rc < 0) return rc;
    return r->st == RREF_DONE ? 0 : 1;
}

/* ---- tag ------------------------------------------------------------------------------------ */

void rng_tag_start(struct rng_tag *t, uint16_t peer, uint32_t reply_us, uint16_t src) {
    memset(t, 0, sizeof *t);
    t->peer = peer;
    t->src = src;
    t->reply_us = reply_us;
    t->reply_u = dw_us_to_units(reply_us);
    t->st = RTAG_LISTEN;
}

static int tag_listen(struct rng_tag *t) {
    t->st = RTAG_LISTEN;
    t->rx_on = true;
    return dw_rx_enable(&g_radio.dev);
}

static int tag_report(struct rng_tag *t, struct meas_counters *c, uint64_t after_stamp) {
    struct rf_frame f;
    frame_init(&f, RF_REPORT, t->src, t->ref, t->seq, t->gain, t->method);
    f.ts[0] = t->t1t;
    f.ts[1] = t->t2t;
    f.ts[2] = t->t3t;
    f.q[0] = t->q1;
    f.q[1] = t->q3;
    float e1 = 0.0f, z = 0.0f;
    bool valid = caltable_rx_error_ps(t->q1.cir_pwr, t->q1.rxpacc, t->q1.rxpacc_nosat, &e1) && caltable_own_z_ps(&z);
    f.tag_valid = valid ? 1u : 0u;
    f.e1_ps = valid ? e1 : 0.0f;
    f.z_ps = valid ? z : 0.0f;
    uint64_t unused;
    int rc = send_after(&f, after_stamp, t->reply_u, &unused, &t->deadline_us);
    if (rc == DW_ELATE) {
        c->late++;
        c->incomplete++;
        return tag_listen(t);
    }
    if (rc != DW_OK) return rc;
    t->st = RTAG_WAIT_REP_TX;
    return DW_OK;
}

static int tag_on_m1(struct rng_tag *t, struct meas_counters *c, const struct rf_frame *f) {
    t->ref = f->src;
    t->seq = f->seq;
    t->method = f->idx;
    t->gain = f->gain;
    t->t1t = s_ev.stamp;
    t->t2t = t->t3t = 0;
    t->q1 = s_ev.q;
    memset(&t->q3, 0, sizeof t->q3);
    struct rf_frame m2;
    frame_init(&m2, RF_M2, t->src, t->ref, t->seq, t->gain, t->method);
    m2.ts[0] = t->t1t;
    int rc = send_after(&m2, t->t1t, t->reply_u, &m2.ts[1], &t->deadline_us);
    t->t2t = m2.ts[1];
    if (rc == DW_ELATE) {
        c->late++;
        c->incomplete++;
        return tag_listen(t);
    }
    if (rc != DW_OK) return rc;
    t->rx_on = false;
    t->st = RTAG_WAIT_M2_TX;
    return DW_OK;
}

int rng_tag_poll(struct rng_tag *t, struct meas_counters *c) {
    struct dw_dev *d = &g_radio.dev;
    int rc;
    if (t->st == RTAG_LISTEN && !t->rx_on) {
        rc = tag_listen(t);
        if (rc != DW_OK) return rc;
    }
    uint64_t deadline = t->st == RTAG_LISTEN ? radio_now_us() + RADIO_SLICE_US : t->deadline_us;
    int w = radio_wait(deadline);
    if (w < 0) return w;
    if (w == 0) {
        if (t->st != RTAG_LISTEN && radio_now_us() >= t->deadline_us) {
            if (t->st == RTAG_WAIT_M3) c->rx_errors++;
            else c->tx_timeouts++;
            c->incomplete++;
            (void)dw_trx_off(d);
            rc = tag_listen(t);
            if (rc != DW_OK) return rc;
        }
        return 1;
    }
    rc = dw_service(d, &s_ev);
    if (rc != DW_OK) return rc;
    switch (s_ev.kind) {
    case DW_EV_RX_ERROR: c->rx_errors++; return 1; /* receiver re-enabled by the driver */
    case DW_EV_TX_DONE:
        c->sent++;
        if (t->st == RTAG_WAIT_M2_TX) {
            if (t->method == PROTO_RANGE_METHOD_SS) rc = tag_report(t, c, t->t2t);
            else {
                t->st = RTAG_WAIT_M3;
                t->deadline_us = radio_now_us() + t->reply_us + dw_frame_us(&d->cfg, RF_M3_LEN) + RNG_MARGIN_US;
                rc = dw_rx_enable(d);
            }
        } else if (t->st == RTAG_WAIT_REP_TX) {
            rc = tag_listen(t);
        }
        return rc < 0 ? rc : 1;
    case DW_EV_RX_GOOD: break;
    default: return 1;
    }
    t->rx_on = false;
    struct rf_frame f;
    bool ok = rf_decode(s_ev.data, s_ev.len, &f);
    bool for_me = ok && (f.dst == t->src || f.dst == RF_BROADCAST);
    bool peer_ok = t->peer == RF_BROADCAST || (ok && f.src == t->peer);
    if (for_me && peer_ok && f.kind == RF_M1 && (t->st == RTAG_LISTEN || t->st == RTAG_WAIT_M3)) {
        if (t->st == RTAG_WAIT_M3) c->incomplete++;
        rc = tag_on_m1(t, c, &f);
    } else if (for_me && t->st == RTAG_WAIT_M3 && f.kind == RF_M3 && f.src == t->ref && f.seq == t->seq) {
        t->t3t = s_ev.stamp;
        t->q3 = s_ev.q;
        rc = tag_report(t, c, t->t3t);
    } else if (t->st == RTAG_LISTEN || t->st == RTAG_WAIT_M3) {
        rc = dw_rx_enable(d);
        if (t->st == RTAG_LISTEN) t->rx_on = true;
    } else {
        rc = DW_OK;
    }
    return rc < 0 ? rc : 1;
}
