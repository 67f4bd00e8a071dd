/* Calibration tables on the station against the host: the shared vectors
 * (test_table_vectors.json, also read by tests/unit/test_table_vectors.py) give the same
 * validation verdict (which field) and the same corrected range (mm, exactly). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "board.h"
#include "boards/native/flash_sim.h"
#include "caltable.h"
#include "check.h"
#include "proto_gen.h"
#include "table_store.h"

/* ---- a minimal JSON reader: enough for the vector file (objects, arrays, strings without
 * escapes, numbers, null). Tokens in document order with parent links. ---- */
enum { J_OBJ, J_ARR, J_STR, J_NUM, J_NULL, J_BOOL };
struct tok { int type, start, end, parent, size; };
#define MAXTOK 20000
static struct tok toks[MAXTOK];
static int ntok;
static char *js;

static int parse_json(char *s)
{
    js = s;
    ntok = 0;
    int parent = -1;
    for (int i = 0; s[i]; i++) {
        char c = s[i];
        if (c == ' ' || c == '\n' || c == '\t' || c == '\r' || c == ',' || c == ':') {
            continue;
        }
        if (ntok >= MAXTOK) {
            return -1;
        }
        if (c == '{' || c == '[') {
            toks[ntok] = (struct tok){ c == '{' ? J_OBJ : J_ARR, i, -1, parent, 0 };
            if (parent >= 0) toks[parent].size++;
            parent = ntok++;
        } else if (c == '}' || c == ']') {
            if (parent < 0) return -1;
            toks[parent].end = i + 1;
            parent = toks[parent].parent;
        } else if (c == '"') {
            int j = i + 1;
            while (s[j] && s[j] != '"') j++;
            if (!s[j]) return -1;
            toks[ntok] = (struct tok){ J_STR, i + 1, j, parent, 0 };
            if (parent >= 0) toks[parent].size++;
            ntok++;
            i = j;
        } else {
            int j = i;
            while (s[j] && !strchr(",]} \n\r\t", s[j])) j++;
            int type = s[i] == 'n' ? J_NULL : (s[i] == 't' || s[i] == 'f') ? J_BOOL : J_NUM;
            toks[ntok] = (struct tok){ type, i, j, parent, 0 };
            if (parent >= 0) toks[parent].size++;
            ntok++;
            i = j - 1;
        }
    }
    return parent == -1 ? 0 : -1;
}

static bool tok_is(int t, const char *str)
{
    return toks[t].type == J_STR && (int)strlen(str) == toks[t].end - toks[t].start
           && strncmp(js + toks[t].start, str, strlen(str)) == 0;
}

/* The value token of key in object obj, or -1. */
static int get(int obj, const char *key)
{
    int child = 0;
    for (int t = obj + 1; t < ntok && toks[t].start < toks[obj].end; t++) {
        if (toks[t].parent != obj) {
            continue;
        }
        if (child++ % 2 == 0 && tok_is(t, key)) {   /* keys are the even children */
            return t + 1;
        }
    }
    return -1;
}

/* The k-th child of an array. */
static int nth(int arr, int k)
{
    int n = 0;
    for (int t = arr + 1; t < ntok && toks[t].start < toks[arr].end; t++) {
        if (toks[t].parent == arr && n++ == k) {
            return t;
        }
    }
    return -1;
}

static double num(int t)
{
    return strtod(js + toks[t].start, NULL);
}

static unsigned long long unum(int t)
{
    return strtoull(js + toks[t].start, NULL, 10);
}

static size_t hex(int t, uint8_t *out, size_t cap)
{
    size_t n = (size_t)(toks[t].end - toks[t].start) / 2;
    if (n > cap) return 0;
    for (size_t i = 0; i < n; i++) {
        unsigned v;
        if (sscanf(js + toks[t].start + 2 * i, "%2x", &v) != 1) return 0;
        out[i] = (uint8_t)v;
    }
    return n;
}

static char *read_file(const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    static char buf[1 << 20];
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    buf[n] = 0;
    return n ? buf : NULL;
}

/* ---- the tests ---- */

static uint8_t tag_bytes[PROTO_CAL_TABLE_WIRE_SIZE], ref_bytes[PROTO_CAL_TABLE_WIRE_SIZE];
static struct proto_cal_table tag, ref;

static void test_tables(int root)
{
    int tabs = get(root, "tables");
    CHECK(tabs >= 0 && toks[tabs].size == 2);
    CHECK((unsigned)num(get(root, "table_size")) == PROTO_CAL_TABLE_WIRE_SIZE);
    uint8_t uid[12];
    for (int k = 0; k < 2; k++) {
        int o = nth(tabs, k);
        uint8_t *b = k == 0 ? tag_bytes : ref_bytes;
        CHECK(hex(get(o, "hex"), b, PROTO_CAL_TABLE_WIRE_SIZE) == PROTO_CAL_TABLE_WIRE_SIZE);
        CHECK(hex(get(o, "uid"), uid, 12) == 12);
        CHECK(caltable_validate(b, PROTO_CAL_TABLE_WIRE_SIZE, uid) == CALTABLE_OK);
        CHECK(caltable_validate(b, PROTO_CAL_TABLE_WIRE_SIZE, NULL) == CALTABLE_OK);
        CHECK(caltable_validate(b, PROTO_CAL_TABLE_WIRE_SIZE - 1, NULL) == 0);
    }
    CHECK(caltable_decode(tag_bytes, sizeof tag_bytes, &tag));
    CHECK(caltable_decode(ref_bytes, sizeof ref_bytes, &ref));
}

static void test_invalid(int root)
{
    int inv = get(root, "invalid");
    CHECK(inv >= 0 && toks[inv].size >= 25);
    static uint8_t b[PROTO_CAL_TABLE_WIRE_SIZE];
    for (int k = 0; k < toks[inv].size; k++) {
        int o = nth(inv, k);
        CHECK(hex(get(o, "hex"), b, sizeof b) == sizeof b);
        uint8_t uid[12];
        int u = get(o, "uid");
        bool has_uid = toks[u].type == J_STR;
        if (has_uid) CHECK(hex(u, uid, 12) == 12);
        int want = (int)num(get(o, "field"));
        int got = caltable_validate(b, sizeof b, has_uid ? uid : NULL);
        if (got != want) {
            int nm = get(o, "name");
            fprintf(stderr, "invalid vector %.*s: firmware says field %d, host says %d\n",
                    toks[nm].end - toks[nm].start, js + toks[nm].start, got, want);
        }
        CHECK(got == want);
    }
}

static void test_ranges(int root)
{
    int rs = get(root, "ranges");
    CHECK(rs >= 0 && toks[rs].size >= 6);
    /* the reference station's own table in its flash, as on a station */
    native_flash_reset();
    CHECK(native_flash_open(NULL) == 0);
    CHECK(table_store_init() == BOARD_EOK);
    CHECK(table_store_write(ref_bytes, sizeof ref_bytes, NULL, NULL) == BOARD_EOK);
    caltable_init();
    CHECK(caltable_active() != NULL);
    int with_range = 0;
    for (int k = 0; k < toks[rs].size; k++) {
        int o = nth(rs, k);
        uint64_t t[6];
        int ta = get(o, "t");
        for (int i = 0; i < 6; i++) t[i] = (uint64_t)unum(nth(ta, i));
        int q1 = get(o, "q_t1"), q2 = get(o, "q_r2");
        uint16_t c1 = (uint16_t)unum(nth(q1, 0)), n1 = (uint16_t)unum(nth(q1, 1));
        uint16_t c2 = (uint16_t)unum(nth(q2, 0)), n2 = (uint16_t)unum(nth(q2, 1));
        int ev1 = get(o, "e1_ps"), ev2 = get(o, "e2_ps"), er = get(o, "range_mm");
        double e1 = 0, e2 = 0;
        /* RXPACC_NOSAT 0: never equal to RXPACC, N as read (the vectors' registers) */
        bool ok1 = caltable_table_error_ps(&tag, c1, n1, 0, &e1);
        bool ok2 = caltable_table_error_ps(&ref, c2, n2, 0, &e2);
        CHECK(ok1 == (toks[ev1].type == J_NUM));
        CHECK(ok2 == (toks[ev2].type == J_NUM));
        if (ok1) CHECK(fabs(e1 - num(ev1)) < 1e-9);
        if (ok2) CHECK(fabs(e2 - num(ev2)) < 1e-9);
        /* the station path: the tag's share (f32, as sent over the air) and the reference's
         * own table from flash */
        float e1f = (float)e1;
        int32_t mm = caltable_ref_range_mm(t, c2, n2, 0, ok1, e1f, tag.z_ps);
        if (toks[er].type == J_NULL) {
            CHECK(mm == PROTO_NO_RANGE_MM);
        } else {
            int32_t want = (int32_t)num(er);
            if (mm != want) fprintf(stderr, "range vector %d: station %d mm, host %d mm\n", k, mm, want);
            CHECK(mm == want);
            CHECK(mm == caltable_range_mm(t, (double)e1f, e2, (double)ref.z_ps + (double)tag.z_ps));
            with_range++;
        }
    }
    CHECK(with_range >= 6);
    /* no tag share: no range, never a half-corrected one */
    uint64_t t0[6] = { 0, 100, 200000, 200400, 400000, 400100 };
    CHECK(caltable_ref_range_mm(t0, 1000, 1000, 0, false, 0.0f, 0.0f) == PROTO_NO_RANGE_MM);
    CHECK(caltable_ref_range_mm(t0, 1000, 1000, 0, true, NAN, 0.0f) == PROTO_NO_RANGE_MM);
    /* and none without an own table */
    CHECK(table_store_erase() == BOARD_EOK);
    caltable_init();
    CHECK(caltable_active() == NULL);
    CHECK(caltable_ref_range_mm(t0, 1000, 1000, 0, true, 0.0f, 0.0f) == PROTO_NO_RANGE_MM);
    float e;
    CHECK(!caltable_rx_error_ps(1000, 1000, 0, &e) && !caltable_own_z_ps(&e));
}

static void test_math(void)
{
    /* the RX level formula at one point: C = 2^17 / ... chosen so that the level is -A + 0 */
    double lv = 0;
    CHECK(caltable_rx_level_dbm(1024, 1024, 121.74, &lv));
    CHECK(fabs(lv - (10.0 * log10(1024.0 * 131072.0 / (1024.0 * 1024.0)) - 121.74)) < 1e-12);
    CHECK(fabs(lv - (-100.6688)) < 1e-3);   /* 10 log10(128) - 121.74 */
    CHECK(!caltable_rx_level_dbm(0, 1024, 121.74, &lv));
    CHECK(!caltable_rx_level_dbm(1024, 0, 121.74, &lv));
    /* RXPACC == RXPACC_NOSAT: N less the standard SFD, the user manual's numbers (5 symbols at
     * 850 kb/s and 6.8 Mb/s, 64 at 110 kb/s), written here, not taken from dw1000_facts.h */
    CHECK(caltable_rxpacc_n(100, 100, 2) == 95 && caltable_rxpacc_n(100, 100, 1) == 95);
    CHECK(caltable_rxpacc_n(100, 100, 0) == 36);
    CHECK(caltable_rxpacc_n(100, 108, 2) == 100 && caltable_rxpacc_n(3, 3, 2) == 0);
    double es = 0, ec = 0;
    CHECK(caltable_table_error_ps(&tag, 3000, 100, 100, &es) == caltable_table_error_ps(&tag, 3000, 95, 0, &ec));
    CHECK(es == ec);
    /* interpolation: clamped at both ends, linear inside */
    CHECK(caltable_error_at_dbm(&tag, -200.0) == (double)tag.curve_ps[0]);
    CHECK(caltable_error_at_dbm(&tag, 0.0) == (double)tag.curve_ps[tag.n_curve - 1]);
    double mid = 0.5 * ((double)tag.curve_dbm[1] + (double)tag.curve_dbm[2]);
    CHECK(fabs(caltable_error_at_dbm(&tag, mid) - 0.5 * ((double)tag.curve_ps[1] + (double)tag.curve_ps[2])) < 1e-9);
    CHECK(caltable_error_at_dbm(&tag, (double)tag.curve_dbm[3]) == (double)tag.curve_ps[3]);
    /* TOF: a symmetric exchange with no drift and 1000 units of flight; 40-bit wrap inside */
    uint64_t m = (UINT64_C(1) << 40) - 1;
    uint64_t base = (UINT64_C(1) << 40) - 50000;
    uint64_t t[6] = { base & m, (base + 1000 + 7) & m, (base + 300000 + 7) & m,
                      (base + 301000) & m, (base + 600000) & m, (base + 601000 + 7) & m };
    CHECK(fabs(caltable_tof_units(t, 0.0, 0.0) - 1000.0) < 1e-9);
    CHECK(fabs(caltable_tof_units(t, 10.0, 20.0) - (1000.0 - 15.0)) < 1e-6);
    uint64_t bad[6] = { 0, 5, 10, 20, 30, 5 };   /* dT13 at the tag = 0 */
    CHECK(caltable_range_mm(bad, 0, 0, 0) == PROTO_NO_RANGE_MM);
}

int main(void)
{
    char *s = read_file("test_table_vectors.json");
    CHECK(s != NULL);
    if (s == NULL || parse_json(s) != 0 || ntok == 0) {
        fprintf(stderr, "cannot read test_table_vectors.json (run from tests/firmware)\n");
        check_record(0, __FILE__, __LINE__, "test_table_vectors.json read and parsed", NULL);
        return check_summary();
    }
    test_tables(0);
    test_invalid(0);
    test_ranges(0);
    test_math();
    native_flash_reset();
    return check_summary();
}
