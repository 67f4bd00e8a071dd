/* See measure.h. The measurement handlers of protocol/messages/measurement.toml. */
#include "measure.h"

#include <string.h>

#include "app.h"
#include "board.h"
#include "caltable.h"
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

/* ---- record ring ---------------------------------------------------------------------------
 * Every record of the running (or last) activity gets the next running index; the ring keeps
 * the most recent MEAS_RING_CAP of them until the next activity begins. Records at indices
 * s_sent..s_next_index-1 are not streamed yet; a record that is overwritten before it was
 * streamed counts as dropped (its index is skipped in the stream). Streamed or not, the host
 * can fetch any record the ring still holds (triplets_fetch / ranges_fetch). */

union rec {
    struct proto_triplet_record t;
    struct proto_range_record r;
};

static union rec s_ring[MEAS_RING_CAP];
static uint8_t s_qtype;       /* PROTO_T_TRIPLETS or PROTO_T_RANGES */
static uint32_t s_next_index; /* running record index of this activity: records produced */
static uint32_t s_sent;       /* first index not streamed yet */
static uint8_t s_payload[PROTO_MAX_PAYLOAD];

static void ring_reset(uint8_t type) {
    s_qtype = type;
    s_next_index = 0;
    s_sent = 0;
}

static uint32_t ring_oldest(void) { return s_next_index > MEAS_RING_CAP ? s_next_index - MEAS_RING_CAP : 0u; }

static union rec *ring_push(void) {
    uint32_t index = s_next_index++;
    s_cnt.records++;
    if (s_next_index - s_sent > MEAS_RING_CAP) { /* the oldest unsent record is overwritten */
        s_sent++;
        s_cnt.dropped++;
    }
    return &s_ring[index % MEAS_RING_CAP];
}

void measure_emit_triplet(const struct proto_triplet_record *r) { ring_push()->t = *r; }

void measure_emit_range(const struct proto_range_record *r) { ring_push()->r = *r; }

unsigned measure_queued(void) { return (unsigned)(s_next_index - s_sent); }

bool measure_peek(unsigned i, uint32_t *index, struct proto_triplet_record *t, struct proto_range_record *r) {
    if (i >= measure_queued()) return false;
    uint32_t k = s_sent + i;
    const union rec *q = &s_ring[k % MEAS_RING_CAP];
    if (index) *index = k;
    if (t && s_qtype == PROTO_T_TRIPLETS) *t = q->t;
    if (r && s_qtype == PROTO_T_RANGES) *r = q->r;
    return true;
}

/* Copy up to max held records from index first into t[] or r[] (whichever matches the ring's
 * type); returns how many (0 when first is not held). */
static unsigned ring_copy(uint32_t first, unsigned max, struct proto_triplet_record *t,
                          struct proto_range_record *r) {
    if (first < ring_oldest() || first >= s_next_index) return 0;
    uint32_t avail = s_next_index - first;
    unsigned n = avail < max ? (unsigned)avail : max;
    for (unsigned i = 0; i < n; i++) {
        const union rec *q = &s_ring[(first + i) % MEAS_RING_CAP];
        if (t) t[i] = q->t;
        if (r) r[i] = q->r;
    }
    return n;
}

/* Stream one batch: the oldest unsent records, as many as fit in one frame. */
static void send_batch(void) {
    unsigned left = measure_queued();
    if (left == 0) return;
    static union {
        struct proto_triplets_resp t;
        struct proto_ranges_resp r;
    } m;
    bool trip = s_qtype == PROTO_T_TRIPLETS;
    unsigned max = trip ? PROTO_TRIPLETS_RESP_RECORDS_MAX : PROTO_RANGES_RESP_RECORDS_MAX;
    uint32_t first = s_sent;
    unsigned n = ring_copy(first, left < max ? left : max, trip ? m.t.records : NULL, trip ? NULL : m.r.records);
    size_t len = 0;
    int rc;
    if (trip) {
        m.t.first_index = first;
        m.t.records_count = (uint16_t)n;
        rc = proto_triplets_resp_encode(&m.t, s_payload, sizeof s_payload, &len);
    } else {
        m.r.first_index = first;
        m.r.records_count = (uint16_t)n;
        rc = proto_ranges_resp_encode(&m.r, s_payload, sizeof s_payload, &len);
    }
    s_sent += n;
    if (rc != 0 || app_send_stream(s_qtype, s_payload, len) != 0) s_cnt.dropped += n;
}

void measure_flush(void) {
    while (measure_queued() > 0) send_batch();
}

/* Records go out as soon as they exist: one per frame while the link keeps up, batches of up
 * to a frame's worth when it falls behind. */
static void maybe_flush(void) { measure_flush(); }

/* ---- activity control --------------------------------------------------------------------- */

enum meas_mode measure_mode(void) { return s_mode; }
const struct meas_counters *measure_counters(void) { return &s_cnt; }
struct meas_counters *measure_counters_mut(void) { return &s_cnt; }
bool measure_busy(void) { return s_mode != MEAS_IDLE && !s_done; }

static void begin(enum meas_mode m, uint8_t qtype) {
    memset(&s_cnt, 0, sizeof s_cnt);
    ring_reset(qtype);
    s_mode = m;
    s_done = false;
    s_fail = 0;
}

static void halt(void) {
    if (s_mode != MEAS_IDLE && radio_ready()) (void)dw_trx_off(&g_radio.dev);
    s_mode = MEAS_IDLE;
}

/* The active calibration table's antenna delays (TX_ANTD, LDE_RXANTD, device units) replace
 * what a configuration asks for: the table is this station's calibration. A table field of 0
 * means "keep", so the configuration's value stays. */
static void apply_table_antd(struct dw_config *cfg) {
    const struct proto_cal_table *t = caltable_active();
    if (t == NULL) return;
    if (t->tx_antd != 0) cfg->tx_antd = t->tx_antd;
    if (t->rx_antd != 0) cfg->rx_antd = t->rx_antd;
}

void measure_init(void) {
    s_mode = MEAS_IDLE;
    s_done = false;
    memset(&s_cnt, 0, sizeof s_cnt);
    ring_reset(PROTO_T_TRIPLETS);
    (void)radio_attach(board_dw_ops());
    if (radio_ready()) {
        /* at boot the radio gets the table's antenna delays, if the table has any */
        struct dw_config cfg;
        dw_config_default(&cfg);
        apply_table_antd(&cfg);
        if (cfg.tx_antd != 0 || cfg.rx_antd != 0) g_radio.last_err = dw_configure(&g_radio.dev, &cfg);
    }
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

uint32_t measure_idle_us(void) { return measure_busy() || measure_queued() > 0 ? 0u : APP_IDLE_MAX_US; }

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
    apply_table_antd(&cfg);
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

/* triplets_fetch / ranges_fetch: records of the current or last activity, from the ring. */
static int fetch_check(uint8_t type, uint8_t count, uint32_t *oldest, uint32_t *next, uint16_t *detail) {
    if (count == 0) {
        *detail = 1;
        return PROTO_ERR_BAD_VALUE;
    }
    if (s_qtype != type && s_next_index > 0) { /* the ring holds the other kind of record */
        *detail = PROTO_DETAIL_NONE;
        return PROTO_ERR_NOT_FOUND;
    }
    *oldest = ring_oldest();
    *next = s_next_index;
    return 0;
}

int handle_triplets_fetch(const struct proto_triplets_fetch_req *req, struct proto_triplets_fetch_resp *resp,
                          uint16_t *detail) {
    int rc = fetch_check(PROTO_T_TRIPLETS, req->count, &resp->oldest, &resp->next, detail);
    if (rc != 0) return rc;
    unsigned max = req->count < PROTO_TRIPLETS_FETCH_RESP_RECORDS_MAX ? req->count : PROTO_TRIPLETS_FETCH_RESP_RECORDS_MAX;
    resp->first_index = req->first_index;
    resp->records_count = (uint16_t)(s_next_index == 0 ? 0u : ring_copy(req->first_index, max, resp->records, NULL));
    return 0;
}

int handle_ranges_fetch(const struct proto_ranges_fetch_req *req, struct proto_ranges_fetch_resp *resp,
                        uint16_t *detail) {
    int rc = fetch_check(PROTO_T_RANGES, req->count, &resp->oldest, &resp->next, detail);
    if (rc != 0) return rc;
    unsigned max = req->count < PROTO_RANGES_FETCH_RESP_RECORDS_MAX ? req->count : PROTO_RANGES_FETCH_RESP_RECORDS_MAX;
    resp->first_index = req->first_index;
    resp->records_count = (uint16_t)(s_next_index == 0 ? 0u : ring_copy(req->first_index, max, NULL, resp->records));
    return 0;
}

int measure_last_failure(void) { return s_fail; }
