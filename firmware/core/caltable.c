/* Calibration tables on the station: validation, table_* handlers, and the corrected range.
 * See caltable.h for who applies which correction, docs/TABLES.md for the format. */
#include "caltable.h"

#include <math.h>
#include <string.h>

#include "board.h"
#include "crc32.h"
#include "dw1000_facts.h"
#include "table_store.h"

#define TSIZE PROTO_CAL_TABLE_WIRE_SIZE

/* Field indices of cal_table (protocol/messages/tables.toml), for bad_value's detail. */
enum {
    F_FORMAT_VERSION, F_UID, F_CHANNEL, F_PRF_MHZ, F_PREAMBLE_LEN, F_DATA_RATE, F_N_CURVE, F_N_MAP,
    F_CREATED_UNIX, F_HOST_VERSION, F_TX_ANTD, F_RX_ANTD, F_Z_PS, F_CURVE_DBM, F_CURVE_PS,
    F_MAP_MEASURED_DBM, F_MAP_REAL_DBM, F_RESERVED, F_A_DBM, F_FLAGS, F_CRC32, F_COUNT
};

/* DW1000 time base: one device unit = 1 / (128 * 499.2 MHz). The numbers are chip facts of
 * protocol/dw1000.toml (dw1000_facts.h); the host's uwbcal.dw1000 builds the same expressions
 * on the same generated values and the shared vectors check the agreement. */
#define TIME_UNIT_S (1.0 / DW1000_TICK_HZ)
#define METRES_PER_UNIT (DW1000_C_LIGHT * TIME_UNIT_S)
#define TS_MASK ((UINT64_C(1) << DW1000_TIMESTAMP_BITS) - 1u)

static uint8_t staging[TSIZE];
static uint16_t staged;

static bool loaded;
static bool active_ok;
static struct proto_cal_table active;

bool caltable_decode(const uint8_t *buf, size_t len, struct proto_cal_table *out)
{
    if (buf == NULL || out == NULL || len != TSIZE) {
        return false;
    }
    proto_cal_table_decode(buf, out);
    return true;
}

static bool in_range(float v, float lo, float hi)
{
    return isfinite(v) && v >= lo && v <= hi;   /* NaN fails every comparison */
}

/* n used points of x: finite, in [lo, hi], strictly increasing (or non-decreasing); the
 * unused points are 0 so that a table has exactly one byte form. */
static bool axis_ok(const float *x, unsigned n, float lo, float hi, bool strict)
{
    for (unsigned i = 0; i < PROTO_TABLE_MAX_POINTS; i++) {
        if (i >= n) {
            if (x[i] != 0.0f) {
                return false;
            }
            continue;
        }
        if (!in_range(x[i], lo, hi)) {
            return false;
        }
        if (i > 0 && (strict ? !(x[i] > x[i - 1]) : !(x[i] >= x[i - 1]))) {
            return false;
        }
    }
    return true;
}

/* v is one of the n values of `ok` (a PROTO_TABLE_*_VALUES list) */
static bool one_of(unsigned v, const uint16_t *ok, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        if (ok[i] == v) {
            return true;
        }
    }
    return false;
}

/* the radio settings a table may name: the chip's (protocol/dw1000.toml) */
static const uint16_t channels_ok[DW1000_CHANNELS_COUNT] = DW1000_CHANNELS_VALUES;
static const uint16_t prfs_ok[DW1000_PRFS_COUNT] = DW1000_PRFS_VALUES;
static const uint16_t preambles_ok[DW1000_PREAMBLE_LENGTHS_COUNT] = DW1000_PREAMBLE_LENGTHS_VALUES;

int caltable_validate(const uint8_t *buf, size_t len, const uint8_t uid[12])
{
    static struct proto_cal_table t;
    static uint8_t again[TSIZE];
    if (!caltable_decode(buf, len, &t)) {
        return F_FORMAT_VERSION;
    }
    if (crc32_update(0, buf, TSIZE - 4u) != t.crc32) {
        return F_CRC32;
    }
    if (t.format_version != PROTO_TABLE_FORMAT_VERSION) {
        return F_FORMAT_VERSION;
    }
    if (uid != NULL && memcmp(uid, t.uid, sizeof t.uid) != 0) {
        return F_UID;
    }
    if (!one_of(t.channel, channels_ok, DW1000_CHANNELS_COUNT)) {
        return F_CHANNEL;
    }
    if (!one_of(t.prf_mhz, prfs_ok, DW1000_PRFS_COUNT)) {
        return F_PRF_MHZ;
    }
    if (!one_of(t.preamble_len, preambles_ok, DW1000_PREAMBLE_LENGTHS_COUNT)) {
        return F_PREAMBLE_LEN;
    }
    if (t.data_rate > 2) {
        return F_DATA_RATE;
    }
    if (t.n_curve < 2 || t.n_curve > PROTO_TABLE_MAX_POINTS) {
        return F_N_CURVE;
    }
    if (t.n_map == 1 || t.n_map > PROTO_TABLE_MAX_POINTS) {
        return F_N_MAP;
    }
    /* host_version: printable ASCII, NUL-padded (re-encoding gives the same bytes only then) */
    for (size_t i = 0; t.host_version[i] != '\0'; i++) {
        if (t.host_version[i] < 0x20 || t.host_version[i] > 0x7E) {
            return F_HOST_VERSION;
        }
    }
    proto_cal_table_encode(&t, again);
    if (memcmp(again, buf, TSIZE) != 0) {
        return F_HOST_VERSION;
    }
    if (!in_range(t.z_ps, -PROTO_TABLE_Z_PS_MAX, PROTO_TABLE_Z_PS_MAX)) {
        return F_Z_PS;
    }
    if (!axis_ok(t.curve_dbm, t.n_curve, PROTO_TABLE_DBM_MIN, PROTO_TABLE_DBM_MAX, true)) {
        return F_CURVE_DBM;
    }
    for (unsigned i = 0; i < PROTO_TABLE_MAX_POINTS; i++) {
        if (i < t.n_curve ? !in_range(t.curve_ps[i], -PROTO_TABLE_ERR_PS_MAX, PROTO_TABLE_ERR_PS_MAX)
                          : t.curve_ps[i] != 0.0f) {
            return F_CURVE_PS;
        }
    }
    if (!axis_ok(t.map_measured_dbm, t.n_map, PROTO_TABLE_DBM_MIN, PROTO_TABLE_DBM_MAX, true)) {
        return F_MAP_MEASURED_DBM;
    }
    if (!axis_ok(t.map_real_dbm, t.n_map, PROTO_TABLE_DBM_MIN, PROTO_TABLE_DBM_MAX, false)) {
        return F_MAP_REAL_DBM;
    }
    for (size_t i = 0; i < sizeof t.reserved; i++) {
        if (t.reserved[i] != 0) {
            return F_RESERVED;
        }
    }
    if (!in_range(t.a_dbm, PROTO_TABLE_A_MIN, PROTO_TABLE_A_MAX)) {
        return F_A_DBM;
    }
    if (t.flags != 0) {
        return F_FLAGS;
    }
    return CALTABLE_OK;
}

/* ---- the corrections ------------------------------------------------------------------ */

double caltable_error_at_dbm(const struct proto_cal_table *t, double x)
{
    unsigned n = t->n_curve;
    const float *xp = t->curve_dbm, *fp = t->curve_ps;
    if (n == 0) {
        return 0.0;
    }
    if (!(x > (double)xp[0])) {   /* also NaN and -inf: numpy.interp clamps -inf to fp[0] */
        return (double)fp[0];
    }
    if (x >= (double)xp[n - 1]) {
        return (double)fp[n - 1];
    }
    unsigned j = 0;
    while (j + 1 < n && (double)xp[j + 1] <= x) {
        j++;
    }
    /* numpy.interp's arithmetic, so that host and station agree to the last bit */
    double slope = ((double)fp[j + 1] - (double)fp[j]) / ((double)xp[j + 1] - (double)xp[j]);
    return slope * (x - (double)xp[j]) + (double)fp[j];
}

uint16_t caltable_rxpacc_n(uint16_t rxpacc, uint16_t rxpacc_nosat, uint8_t data_rate)
{
    unsigned corr = data_rate == 0 ? DW1000_RXPACC_SFD_CORR_110K : DW1000_RXPACC_SFD_CORR;
    if (rxpacc != rxpacc_nosat) {
        return rxpacc;
    }
    return rxpacc > corr ? (uint16_t)(rxpacc - corr) : 0u;
}

bool caltable_rx_level_dbm(uint16_t cir_pwr, uint16_t rxpacc, double a_dbm, double *level_dbm)
{
    if (cir_pwr == 0 || rxpacc == 0) {
        return false;
    }
    double n = (double)rxpacc;
    *level_dbm = 10.0 * log10((double)cir_pwr * 131072.0 / (n * n)) - a_dbm;
    return true;
}

bool caltable_table_error_ps(const struct proto_cal_table *t, uint16_t cir_pwr, uint16_t rxpacc,
                             uint16_t rxpacc_nosat, double *e_ps)
{
    double level;
    uint16_t n = caltable_rxpacc_n(rxpacc, rxpacc_nosat, t->data_rate);
    if (!caltable_rx_level_dbm(cir_pwr, n, (double)t->a_dbm, &level)) {
        return false;
    }
    *e_ps = caltable_error_at_dbm(t, level);
    return true;
}

static double wrap_diff(uint64_t later, uint64_t earlier)
{
    uint64_t d = (later - earlier) & TS_MASK;
    int64_t s = d >= (UINT64_C(1) << (DW1000_TIMESTAMP_BITS - 1u)) ? (int64_t)d - (INT64_C(1) << DW1000_TIMESTAMP_BITS)
                                                                    : (int64_t)d;
    return (double)s;
}

double caltable_tof_units(const uint64_t t[6], double e1, double e2)
{
    /* t1r t1t t2t t2r t3r t3t; same order of operations as uwbcal.corrections.twr */
    double r12 = wrap_diff(t[3], t[0]);
    double t12 = wrap_diff(t[2], t[1]);
    double bracket = r12 - t12 - e2 - e1;
    double r13 = wrap_diff(t[4], t[0]);
    double t13 = wrap_diff(t[5], t[1]);
    if (t13 == 0.0) {
        return NAN;
    }
    bracket = bracket - (r13 - t13) / t13 * (t12 + e1);
    return 0.5 * bracket;
}

static double ps_to_units(double ps)
{
    return ps * 1e-12 / TIME_UNIT_S;
}

int32_t caltable_range_mm(const uint64_t t[6], double e1_ps, double e2_ps, double z_ps)
{
    double tof = caltable_tof_units(t, ps_to_units(e1_ps), ps_to_units(e2_ps));
    double mm = floor((tof + ps_to_units(z_ps)) * METRES_PER_UNIT * 1000.0 + 0.5);
    if (!isfinite(mm) || mm <= (double)INT32_MIN || mm > (double)INT32_MAX) {
        return PROTO_NO_RANGE_MM;
    }
    return (int32_t)mm;
}

/* ---- the station's own table ---------------------------------------------------------- */

/* Load the active table from flash (through the staging buffer, to save RAM: a boot, a
 * commit or an erase discards any staged upload). */
static void load_active(void)
{
    active_ok = false;
    staged = 0;
    uint16_t n = table_store_active_len();
    if (n == TSIZE && table_store_read(0, staging, TSIZE) == BOARD_EOK
        && caltable_validate(staging, TSIZE, NULL) == CALTABLE_OK) {
        /* the uid is not checked here: a table pushed with --force is used as pushed */
        active_ok = caltable_decode(staging, TSIZE, &active);
    }
}

void caltable_init(void)
{
    (void)table_store_init();   /* a read failure leaves the slots reported corrupt */
    load_active();
    loaded = true;
}

void caltable_reset_state(void)
{
    loaded = false;
    active_ok = false;
    staged = 0;
}

static void ensure_loaded(void)
{
    if (!loaded) {
        caltable_init();
    }
}

const struct proto_cal_table *caltable_active(void)
{
    ensure_loaded();
    return active_ok ? &active : NULL;
}

bool caltable_rx_error_ps(uint16_t cir_pwr, uint16_t rxpacc, uint16_t rxpacc_nosat, float *e_ps)
{
    const struct proto_cal_table *t = caltable_active();
    double e;
    if (t == NULL || !caltable_table_error_ps(t, cir_pwr, rxpacc, rxpacc_nosat, &e)) {
        return false;
    }
    *e_ps = (float)e;
    return true;
}

bool caltable_own_z_ps(float *z_ps)
{
    const struct proto_cal_table *t = caltable_active();
    if (t == NULL) {
        return false;
    }
    *z_ps = t->z_ps;
    return true;
}

int32_t caltable_ref_range_mm(const uint64_t t[6], uint16_t cir_pwr_r2, uint16_t rxpacc_r2,
                              uint16_t rxpacc_nosat_r2, bool tag_valid, float tag_e1_ps, float tag_z_ps)
{
    const struct proto_cal_table *own = caltable_active();
    double e2;
    if (!tag_valid || own == NULL || !caltable_table_error_ps(own, cir_pwr_r2, rxpacc_r2, rxpacc_nosat_r2, &e2)
        || !isfinite(tag_e1_ps) || !isfinite(tag_z_ps)) {
        return PROTO_NO_RANGE_MM;
    }
    return caltable_range_mm(t, (double)tag_e1_ps, e2, (double)own->z_ps + (double)tag_z_ps);
}

/* ---- handlers (override the weak defaults of proto_gen.c) ----------------------------- */

int handle_table_write(const struct proto_table_write_req *req, struct proto_table_write_resp *resp,
                       uint16_t *detail)
{
    ensure_loaded();   /* before staging: loading the active table goes through the buffer */
    if (req->offset == 0) {
        staged = 0;   /* a new table */
    }
    if (req->offset > staged) {
        *detail = 0;   /* a gap: chunks come in order (a repeated chunk is fine) */
        return PROTO_ERR_BAD_VALUE;
    }
    if (req->data_len == 0 || (size_t)req->offset + req->data_len > TSIZE) {
        *detail = 1;
        return PROTO_ERR_BAD_VALUE;
    }
    memcpy(staging + req->offset, req->data, req->data_len);
    if (req->offset + req->data_len > staged) {
        staged = (uint16_t)(req->offset + req->data_len);
    }
    resp->staged = staged;
    return 0;
}

int handle_table_commit(const struct proto_table_commit_req *req, struct proto_table_commit_resp *resp,
                        uint16_t *detail)
{
    ensure_loaded();
    if (req->length != TSIZE || staged != TSIZE) {
        *detail = PROTO_TABLE_DETAIL_REQUEST | 0u;
        return PROTO_ERR_BAD_VALUE;
    }
    if (req->crc32 != crc32_update(0, staging, TSIZE - 4u)) {
        *detail = PROTO_TABLE_DETAIL_REQUEST | 1u;
        return PROTO_ERR_BAD_VALUE;
    }
    uint8_t uid[12];
    board_uid(uid);
    int bad = caltable_validate(staging, TSIZE, (req->force & 1u) ? NULL : uid);
    if (bad != CALTABLE_OK) {
        *detail = (uint16_t)bad;
        return PROTO_ERR_BAD_VALUE;
    }
    uint8_t slot = 0;
    uint32_t seq = 0;
    int r = table_store_write(staging, TSIZE, &slot, &seq);
    load_active();
    if (r != BOARD_EOK) {
        *detail = (uint16_t)(-r);
        return PROTO_ERR_FLASH;
    }
    staged = 0;
    resp->slot = slot;
    resp->sequence = seq;
    return 0;
}

int handle_table_read(const struct proto_table_read_req *req, struct proto_table_read_resp *resp,
                      uint16_t *detail)
{
    ensure_loaded();
    uint16_t total = table_store_active_len();
    if (total == 0) {
        *detail = PROTO_DETAIL_NONE;
        return PROTO_ERR_NOT_FOUND;
    }
    if (req->offset >= total) {
        *detail = 0;
        return PROTO_ERR_BAD_VALUE;
    }
    if (req->length == 0 || req->length > PROTO_TABLE_READ_MAX) {
        *detail = 1;
        return PROTO_ERR_BAD_VALUE;
    }
    uint16_t n = (uint16_t)(total - req->offset < req->length ? total - req->offset : req->length);
    int r = table_store_read(req->offset, resp->data, n);
    if (r != BOARD_EOK) {
        *detail = (uint16_t)(-r);
        return PROTO_ERR_FLASH;
    }
    resp->total = total;
    resp->data_len = n;
    return 0;
}

int handle_table_info(const struct proto_table_info_req *req, struct proto_table_info_resp *resp,
                      uint16_t *detail)
{
    (void)req;
    (void)detail;
    ensure_loaded();
    const struct table_store_info *in = table_store_get_info();
    resp->active = in->active < 0 ? 0xFFu : (uint8_t)in->active;
    resp->slot0_state = in->state[0];
    resp->slot0_sequence = in->seq[0];
    resp->slot1_state = in->state[1];
    resp->slot1_sequence = in->seq[1];
    resp->table_size = (uint16_t)TSIZE;
    resp->table_crc32 = 0;
    uint16_t n = table_store_active_len();
    uint8_t c[4];
    if (n >= 4 && table_store_read(n - 4u, c, 4) == BOARD_EOK) {
        resp->table_crc32 = (uint32_t)c[0] | ((uint32_t)c[1] << 8) | ((uint32_t)c[2] << 16) | ((uint32_t)c[3] << 24);
    }
    resp->applied = active_ok ? 1u : 0u;
    return 0;
}

int handle_table_erase(const struct proto_table_erase_req *req, struct proto_table_erase_resp *resp,
                       uint16_t *detail)
{
    (void)req;
    (void)resp;
    ensure_loaded();
    int r = table_store_erase();
    load_active();
    if (r != BOARD_EOK) {
        *detail = (uint16_t)(-r);
        return PROTO_ERR_FLASH;
    }
    return 0;
}
