/* See measure.h. The measurement handlers of protocol/messages/measurement.toml. */
#include "measure.h"

#include <string.h>

#include "app.h"
#include "board.h"
#include "radio.h"
#include "ranging.h"
#include "sequencer.h"

static enum meas_mode s_mode;
static bool s_done;
static int s_fail; /* last radio failure that stopped an activity (DW_E*), 0 none */
static struct meas_counters s_cnt;

static struct seq_tx s_seq;
static struct trip_rx s_trip;
static struct rng_ref s_ref;
static struct rng_tag s_tag;

/* ---- record queue ------------------------------------------------------------------------- */

struct qslot {
    uint32_t index;
    uint64_t t_us;
    union {
        struct proto_triplet_record t;
        struct proto_range_record r;
    } u;
};

static struct qslot s_q[MEAS_QUEUE_CAP];
static unsigned s_qhead, s_qcount;
static uint8_t s_qtype;       /* PROTO_T_TRIPLETS or PROTO_T_RANGES */
static uint32_t s_next_index; /* running record index of this activity */
static uint8_t s_payload[PROTO_MAX_PAYLOAD];

static void queue_reset(uint8_t type) {
    s_qhead = s_qcount = 0;
    s_qtype = type;
    s_next_index = 0;
}

static struct qslot *queue_push(void) {
    uint32_t index = s_next_index++;
    s_cnt.records++;
    if (s_qcount >= MEAS_QUEUE_CAP) {
        s_cnt.dropped++;
        return NULL;
    }
    struct qslot *q = &s_q[(s_qhead + s_qcount) % MEAS_QUEUE_CAP];
    s_qcount++;
    q->index = index;
    q->t_us = radio_now_us();
    return q;
}

void measure_emit_triplet(const struct proto_triplet_record *r) {
    struct qslot *q = queue_push();
    if (q) q->u.t = *r;
}

void measure_emit_range(const struct proto_range_record *r) {
    struct qslot *q = queue_push();
    if (q) q->u.r = *r;
}

unsigned measure_queued(void) { return s_qcount; }

bool measure_peek(unsigned i, uint32_t *index, struct proto_triplet_record *t, struct proto_range_record *r) {
    if (i >= s_qcount) return false;
    const struct qslot *q = &s_q[(s_qhead + i) % MEAS_QUEUE_CAP];
    if (index) *index = q->index;
    if (t && s_qtype == PROTO_T_TRIPLETS) *t = q->u.t;
    if (r && s_qtype == PROTO_T_RANGES) *r = q->u.r;
    return true;
}

/* Send one batch of consecutive indices from the head of the queue. */
static void send_batch(void) {
    if (s_qcount == 0) return;
    static union {
        struct proto_triplets_resp t;
        struct proto_ranges_resp r;
    } m;
    unsigned max = s_qtype == PROTO_T_TRIPLETS ? PROTO_TRIPLETS_RESP_RECORDS_MAX : PROTO_RANGES_RESP_RECORDS_MAX;
    uint32_t first = s_q[s_qhead].index;
    unsigned n = 0;
    while (n < max && n < s_qcount) {
        const struct qslot *q = &s_q[(s_qhead + n) % MEAS_QUEUE_CAP];
        if (q->index != first + n) break;
        if (s_qtype == PROTO_T_TRIPLETS) m.t.records[n] = q->u.t;
        else m.r.records[n] = q->u.r;
        n++;
    }
    size_t len = 0;
    int rc;
    if (s_qtype == PROTO_T_TRIPLETS) {
        m.t.first_index = first;
        m.t.records_count = (uint16_t)n;
        rc = proto_triplets_resp_encode(&m.t, s_payload, sizeof s_payload, &len);
    } else {
        m.r.first_index = first;
        m.r.records_count = (uint16_t)n;
        rc = proto_ranges_resp_encode(&m.r, s_payload, sizeof s_payload, &len);
    }
    s_qhead = (s_qhead + n) % MEAS_QUEUE_CAP;
    s_qcount -= n;
    if (rc != 0 || app_send_stream(s_qtype, s_payload, len) != 0) s_cnt.dropped += n;
}

void measure_flush(void) {
    while (s_qcount > 0) send_batch();
}

static void maybe_flush(void) {
    unsigned max = s_qtype == PROTO_T_TRIPLETS ? PROTO_TRIPLETS_RESP_RECORDS_MAX : PROTO_RANGES_RESP_RECORDS_MAX;
    while (s_qcount >= max) send_batch();
    if (s_qcount > 0 && (s_mode == MEAS_IDLE || s_done ||
                         radio_now_us() - s_q[s_qhead].t_us >= MEAS_FLUSH_US))
        send_batch();
}

/* ---- activity control --------------------------------------------------------------------- */

enum meas_mode measure_mode(void) { return s_mode; }
const struct meas_counters *measure_counters(void) { return &s_cnt; }
struct meas_counters *measure_counters_mut(void) { return &s_cnt; }
bool measure_busy(void) { return s_mode != MEAS_IDLE && !s_done; }

static void begin(enum meas_mode m, uint8_t qtype) {
    memset(&s_cnt, 0, sizeof s_cnt);
    queue_reset(qtype);
    s_mode = m;
    s_done = false;
    s_fail = 0;
}

static void halt(void) {
    if (s_mode != MEAS_IDLE && radio_ready()) (void)dw_trx_off(&g_radio.dev);
    s_mode = MEAS_IDLE;
}

void measure_init(void) {
    s_mode = MEAS_IDLE;
    s_done = false;
    memset(&s_cnt, 0, sizeof s_cnt);
    queue_reset(PROTO_T_TRIPLETS);
    (void)radio_attach(board_dw_ops());
}

void measure_poll(void) {
    int rc = 0;
    if (s_mode != MEAS_IDLE && !s_done) {
        switch (s_mode) {
        case MEAS_SEQUENCER: rc = seq_poll(&s_seq, &s_cnt); break;
        case MEAS_LISTEN: rc = trip_rx_poll(&s_trip, &s_cnt); break;
        case MEAS_RANGE_REF: rc = rng_ref_poll(&s_ref, &s_cnt); break;
        case MEAS_RANGE_TAG: rc = rng_tag_poll(&s_tag, &s_cnt); break;
        default: rc = 0; break;
        }
        if (rc <= 0) {
            s_done = true; /* finished (0) or failed (<0): the radio is left off */
            if (rc < 0) {
                s_fail = rc;
                g_radio.last_err = rc;
            }
            if (radio_ready()) (void)dw_trx_off(&g_radio.dev);
        }
    }
    maybe_flush();
}

uint32_t measure_idle_us(void) { return measure_busy() || s_qcount > 0 ? 0u : APP_IDLE_MAX_US; }

/* ---- handlers ------------------------------------------------------------------------------ */

static int radio_error(uint16_t *detail, int rc) {
    *detail = (uint16_t)(rc < 0 ? -rc : rc);
    return PROTO_ERR_RADIO;
}

static int need_radio(uint16_t *detail) {
    if (measure_busy()) {
        *detail = PROTO_DETAIL_NONE;
        return PROTO_ERR_BUSY;
    }
    if (!radio_ready()) {
        int rc = g_radio.present ? DW_ENOTREADY : radio_attach(board_dw_ops());
        if (!radio_ready()) return radio_error(detail, rc == DW_OK ? DW_ENOTREADY : rc);
    }
    /* a finished or failed activity is cleared by the next start */
    measure_flush();
    halt();
    return 0;
}

int handle_radio_config(const struct proto_radio_config_req *req, struct proto_radio_config_resp *resp,
                        uint16_t *detail) {
    struct dw_config cfg = {
        .channel = req->channel,
        .prf_mhz = req->prf_mhz,
        .preamble_len = req->preamble_len,
        .data_rate = req->data_rate,
        .preamble_code = req->preamble_code,
        .tx_antd = req->tx_antd,
        .rx_antd = req->rx_antd,
    };
    unsigned bad;
    if (dw_config_check(&cfg, &bad) != DW_OK) {
        *detail = (uint16_t)bad;
        return PROTO_ERR_BAD_VALUE;
    }
    if (measure_busy()) {
        *detail = PROTO_DETAIL_NONE;
        return PROTO_ERR_BUSY;
    }
    if (!g_radio.present) {
        int rc = radio_attach(board_dw_ops());
        if (!g_radio.present) return radio_error(detail, rc);
    }
    measure_flush();
    halt();
    int rc = dw_configure(&g_radio.dev, &cfg);
    g_radio.last_err = rc;
    if (rc != DW_OK) return radio_error(detail, rc);
    resp->dev_id = g_radio.dev.dev_id;
    resp->station_id = radio_station_id();
    return 0;
}

int handle_seq_start(const struct proto_seq_start_req *req, struct proto_seq_start_resp *resp, uint16_t *detail) {
    struct seq_plan plan;
    int rc = seq_plan_from_req(req, &g_radio.dev.cfg, &plan, detail);
    if (rc != 0) return rc;
    rc = need_radio(detail);
    if (rc != 0) return rc;
    begin(MEAS_SEQUENCER, PROTO_T_TRIPLETS);
    seq_start(&s_seq, &plan, radio_station_id());
    resp->total = seq_total(&plan);
    return 0;
}

int handle_listen(const struct proto_listen_req *req, struct proto_listen_resp *resp, uint16_t *detail) {
    (void)resp;
    if (req->role > 1) {
        *detail = 0;
        return PROTO_ERR_BAD_VALUE;
    }
    if (req->role == 1 && (req->reply_us < RNG_REPLY_MIN_US || req->reply_us > RNG_REPLY_MAX_US)) {
        *detail = 2;
        return PROTO_ERR_BAD_VALUE;
    }
    int rc = need_radio(detail);
    if (rc != 0) return rc;
    if (req->role == 0) {
        begin(MEAS_LISTEN, PROTO_T_TRIPLETS);
        trip_rx_start(&s_trip, req->peer);
    } else {
        begin(MEAS_RANGE_TAG, PROTO_T_RANGES);
        rng_tag_start(&s_tag, req->peer, req->reply_us, radio_station_id());
    }
    return 0;
}

int handle_range_start(const struct proto_range_start_req *req, struct proto_range_start_resp *resp,
                       uint16_t *detail) {
    (void)resp;
    int rc = rng_ref_check(req, &g_radio.dev.cfg, detail);
    if (rc != 0) return rc;
    rc = need_radio(detail);
    if (rc != 0) return rc;
    begin(MEAS_RANGE_REF, PROTO_T_RANGES);
    rng_ref_start(&s_ref, req, radio_station_id());
    return 0;
}

int handle_stop(const struct proto_stop_req *req, struct proto_stop_resp *resp, uint16_t *detail) {
    (void)req;
    (void)detail;
    halt();
    measure_flush(); /* every record goes out before the response */
    resp->sent = s_cnt.sent;
    resp->records = s_cnt.records;
    resp->dropped = s_cnt.dropped;
    resp->late = s_cnt.late;
    resp->rx_errors = s_cnt.rx_errors;
    resp->stamp_mismatch = s_cnt.stamp_mismatch;
    s_done = false;
    return 0;
}

int handle_status(const struct proto_status_req *req, struct proto_status_resp *resp, uint16_t *detail) {
    (void)req;
    (void)detail;
    resp->state = (uint8_t)s_mode;
    resp->sent = s_cnt.sent;
    resp->records = s_cnt.records;
    resp->dropped = s_cnt.dropped;
    resp->late = s_cnt.late;
    resp->rx_errors = s_cnt.rx_errors;
    resp->done = s_done ? 1u : 0u;
    resp->incomplete = s_cnt.incomplete;
    resp->tx_timeouts = s_cnt.tx_timeouts;
    resp->radio_error = (uint16_t)(s_fail < 0 ? -s_fail : 0);
    resp->stamp_mismatch = s_cnt.stamp_mismatch;
    return 0;
}

int measure_last_failure(void) { return s_fail; }
