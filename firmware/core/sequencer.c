/* See sequencer.h. */
#include "sequencer.h"

#include <string.h>

#include "dw1000_regs.h"
#include "radio.h"

static struct dw_event s_ev; /* one event buffer for this module (no reentrancy) */

/* ---- plan ------------------------------------------------------------------------------ */

bool seq_gain_ok(uint8_t octet) { return (octet >> 5) != 7u; }

uint32_t seq_min_lead_us(const struct dw_config *cfg) {
    uint32_t sym_ps = cfg->prf_mhz == 16 ? 993590u : 1017630u;
    uint32_t sfd = cfg->data_rate == 0 ? 64u : 8u;
    uint64_t shr_ps = (uint64_t)(cfg->preamble_len + sfd) * sym_ps;
    return (uint32_t)((shr_ps + 999999u) / 1000000u) + 10u;
}

uint32_t seq_min_period_us(uint32_t spacing_us, const struct dw_config *cfg) {
    uint64_t p = 2ull * spacing_us + dw_frame_us(cfg, RF_P_LEN) + SEQ_PERIOD_MARGIN_US;
    return p > 0xFFFFFFFFull ? 0xFFFFFFFFu : (uint32_t)p;
}

uint32_t seq_total(const struct seq_plan *plan) { return plan->per_step * plan->nsteps; }

int seq_plan_from_req(const struct proto_seq_start_req *req, const struct dw_config *cfg,
                      struct seq_plan *plan, uint16_t *detail) {
    memset(plan, 0, sizeof *plan);
    uint16_t n = req->gains2_len;
    uint16_t bad = PROTO_DETAIL_NONE;
    if (req->per_step == 0 || (n > 0 && (uint64_t)req->per_step * n > 0xFFFFFFFFull)) bad = 0;
    else if (req->spacing_us < SEQ_SPACING_MIN_US || req->spacing_us > SEQ_SPACING_MAX_US) bad = 1;
    else if (req->period_us < seq_min_period_us(req->spacing_us, cfg)) bad = 2;
    else if (!seq_gain_ok(req->gain13)) bad = 3;
    else if (n == 0 || n > SEQ_MAX_STEPS) bad = 4;
    else {
        for (uint16_t i = 0; i < n; i++)
            if (!seq_gain_ok(req->gains2[i])) bad = 4;
    }
    if (bad != PROTO_DETAIL_NONE) {
        *detail = bad;
        return PROTO_ERR_BAD_VALUE;
    }
    plan->per_step = req->per_step;
    plan->spacing_us = req->spacing_us;
    plan->period_us = req->period_us;
    plan->gain13 = req->gain13;
    plan->nsteps = (uint8_t)n;
    memcpy(plan->gains2, req->gains2, n);
    return 0;
}

/* ---- TX side ---------------------------------------------------------------------------- */

void seq_start(struct seq_tx *s, const struct seq_plan *plan, uint16_t src) {
    memset(s, 0, sizeof *s);
    s->plan = *plan;
    s->src = src;
    s->spacing_u = dw_us_to_units(plan->spacing_us);
    s->period_u = dw_us_to_units(plan->period_us);
    s->st = seq_total(plan) ? SEQ_SCHEDULE : SEQ_DONE;
}

static void next_triplet(struct seq_tx *s) {
    s->triplet++;
    s->idx = 0;
    if (++s->rep >= s->plan.per_step) {
        s->rep = 0;
        s->step++;
    }
    if (s->step >= s->plan.nsteps) {
        s->st = SEQ_DONE;
        return;
    }
    s->t1 += s->period_u;
    s->st = SEQ_SCHEDULE;
}

static uint64_t grid(uint64_t u) { return u & ~(uint64_t)0x1FF; }

static int schedule(struct seq_tx *s, struct meas_counters *c) {
    struct dw_dev *d = &g_radio.dev;
    uint64_t now_u;
    int rc = radio_sys_now(&now_u);
    if (rc != DW_OK) return rc;
    uint64_t lead_min = dw_us_to_units(seq_min_lead_us(&d->cfg));
    uint64_t lead0 = dw_us_to_units(SEQ_LEAD_US);
    if (!s->started || (s->idx == 0 && s->t1 < now_u + lead_min)) {
        /* first triplet, or behind schedule: P1 slips to now + lead (not counted late) */
        s->t1 = grid(now_u + lead0 + 0x1FF);
        s->started = true;
    }
    uint64_t dx = s->t1 + s->idx * s->spacing_u;
    uint64_t ahead_u = dw_us_to_units(SEQ_PROGRAM_AHEAD_US);
    if (dx > now_u + ahead_u) {
        uint64_t wait_u = dx - now_u - ahead_u / 2;
        int r = radio_wait(radio_now_us() + dw_units_to_us(wait_u));
        if (r < 0) return r;
        if (r == 1) return dw_service(d, &s_ev); /* nothing expected: clear it */
        return DW_OK;
    }
    if (dx < now_u + lead_min) {
        c->late++;
        next_triplet(s);
        return DW_OK;
    }
    struct rf_frame f;
    memset(&f, 0, sizeof f);
    f.kind = RF_P;
    f.src = s->src;
    f.dst = RF_BROADCAST;
    f.seq = s->triplet;
    f.idx = s->idx;
    f.gain = s->idx == 1 ? s->plan.gains2[s->step] : s->plan.gain13;
    f.gain13 = s->plan.gain13;
    f.step = (uint16_t)s->step;
    f.ts[0] = s->expect_stamp = dw_tx_stamp_for(dx, d->cfg.tx_antd);
    uint8_t buf[RF_P_LEN];
    size_t n = rf_encode(&f, buf, sizeof buf);
    rc = dw_tx_delayed(d, buf, n, dx & DW_TIME_MASK, f.gain);
    if (rc == DW_ELATE) {
        c->late++;
        next_triplet(s);
        return DW_OK;
    }
    if (rc != DW_OK) return rc;
    s->tx_deadline_us = radio_now_us() + dw_units_to_us(dx - now_u) + dw_frame_us(&d->cfg, n) +
                        SEQ_TX_MARGIN_US;
    s->st = SEQ_WAIT_TX;
    return DW_OK;
}

static int wait_tx(struct seq_tx *s, struct meas_counters *c) {
    struct dw_dev *d = &g_radio.dev;
    int r = radio_wait(s->tx_deadline_us);
    if (r < 0) return r;
    if (r == 1) {
        int rc = dw_service(d, &s_ev);
        if (rc != DW_OK) return rc;
        if (s_ev.kind == DW_EV_TX_DONE) {
            if (s_ev.stamp != s->expect_stamp) c->stamp_mismatch++;
            if (++s->idx == 3) {
                c->sent++;
                next_triplet(s);
            } else {
                s->st = SEQ_SCHEDULE;
            }
        }
        return DW_OK;
    }
    if (radio_now_us() >= s->tx_deadline_us) {
        int rc = dw_trx_off(d);
        c->tx_timeouts++;
        next_triplet(s);
        return rc;
    }
    return DW_OK;
}

int seq_poll(struct seq_tx *s, struct meas_counters *c) {
    int rc = DW_OK;
    switch (s->st) {
    case SEQ_SCHEDULE: rc = schedule(s, c); break;
    case SEQ_WAIT_TX: rc = wait_tx(s, c); break;
    default: return 0;
    }
    if (rc < 0) return rc;
    return s->st == SEQ_DONE ? 0 : 1;
}

/* ---- RX side: triplet assembly ---------------------------------------------------------- */

void meas_q_to_proto(const struct dw_rx_quality *q, struct proto_rx_quality *p) {
    p->cir_pwr = q->cir_pwr;
    p->rxpacc = q->rxpacc;
    p->rxpacc_nosat = q->rxpacc_nosat;
    p->fp_ampl1 = q->fp_ampl1;
    p->fp_ampl2 = q->fp_ampl2;
    p->fp_ampl3 = q->fp_ampl3;
    p->std_noise = q->std_noise;
    p->fp_index = q->fp_index;
    p->car_int = q->car_int;
    p->ttcko = q->ttcko;
    p->ttcki = q->ttcki;
}

void trip_rx_start(struct trip_rx *r, uint16_t peer) {
    memset(r, 0, sizeof *r);
    r->peer = peer;
}

static int on_frame(struct trip_rx *r, struct meas_counters *c, const struct dw_event *ev) {
    struct rf_frame f;
    if (!rf_decode(ev->data, ev->len, &f) || f.kind != RF_P) return DW_OK;
    if (r->peer != RF_BROADCAST && f.src != r->peer) return DW_OK;
    if (f.idx == 0) {
        if (r->have) c->incomplete++;
        memset(&r->rec, 0, sizeof r->rec);
        r->rec.seq = f.seq;
        r->rec.step = f.step;
        r->rec.tx_station = f.src;
        r->rec.gain13 = f.gain13;
        r->src = f.src;
        r->have = true;
    } else if (!r->have || f.src != r->src || f.seq != r->rec.seq || f.idx != r->next_idx) {
        if (r->have || f.idx == 1) c->incomplete++;
        r->have = false;
        return DW_OK;
    }
    if (f.idx == 1) r->rec.gain2 = f.gain;
    r->rec.tx[f.idx] = f.ts[0];
    r->rec.rx[f.idx] = ev->stamp;
    meas_q_to_proto(&ev->q, &r->rec.q[f.idx]);
    r->next_idx = (uint8_t)(f.idx + 1);
    if (f.idx == 2) {
        int rc = radio_temp_cc(&r->rec.temp_cc);
        r->have = false;
        measure_emit_triplet(&r->rec);
        return rc;
    }
    return DW_OK;
}

int trip_rx_poll(struct trip_rx *r, struct meas_counters *c) {
    struct dw_dev *d = &g_radio.dev;
    int rc;
    if (!r->rx_on) {
        rc = dw_rx_enable(d);
        if (rc != DW_OK) return rc;
        r->rx_on = true;
    }
    int w = radio_wait(radio_now_us() + RADIO_SLICE_US);
    if (w < 0) return w;
    if (w == 0) return 1;
    rc = dw_service(d, &s_ev);
    if (rc != DW_OK) return rc;
    if (s_ev.kind == DW_EV_RX_ERROR) {
        c->rx_errors++; /* the driver re-enabled the receiver */
    } else if (s_ev.kind == DW_EV_RX_GOOD) {
        r->rx_on = false; /* the receiver stops after a good frame */
        rc = on_frame(r, c, &s_ev);
        if (rc != DW_OK) return rc;
    }
    return 1;
}
