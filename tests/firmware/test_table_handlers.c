/* table_* requests through the generated dispatcher, as the host sends them: chunked write,
 * commit (uid check, force, CRC, validation naming the field), chunked read, info, erase;
 * and the active table survives a restart from the flash file. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "board.h"
#include "cal_table.h"
#include "boards/native/flash_sim.h"
#include "caltable.h"
#include "check.h"
#include "crc32.h"
#include "proto_gen.h"
#include "table_store.h"
#include "tmp_path.h"

#define TS PROTO_CAL_TABLE_WIRE_SIZE
static uint8_t out[PROTO_MAX_PAYLOAD];
static size_t out_len;
static uint16_t detail;

static int req(uint8_t type, const uint8_t *p, size_t n)
{
    detail = 0xABCD;
    return proto_dispatch(type, p, n, out, sizeof out, &out_len, &detail);
}

static int write_chunk(uint16_t off, const uint8_t *d, size_t n)
{
    uint8_t p[PROTO_MAX_PAYLOAD];
    p[0] = (uint8_t)off;
    p[1] = (uint8_t)(off >> 8);
    memcpy(p + 2, d, n);
    return req(PROTO_T_TABLE_WRITE, p, n + 2);
}

static int commit(uint16_t len, uint32_t crc, uint8_t force)
{
    struct proto_table_commit_req r = { .length = len, .crc32 = crc, .force = force };
    uint8_t p[16];
    size_t n;
    CHECK(proto_table_commit_req_encode(&r, p, sizeof p, &n) == 0);
    return req(PROTO_T_TABLE_COMMIT, p, n);
}

static uint32_t crc_of(const uint8_t *t)
{
    return crc32_update(0, t, TS - 4u);
}

/* Stage a whole table in chunks of `chunk` bytes and commit it. */
static int push(const uint8_t *t, size_t chunk, uint8_t force)
{
    for (size_t off = 0; off < TS; off += chunk) {
        size_t n = TS - off < chunk ? TS - off : chunk;
        int r = write_chunk((uint16_t)off, t + off, n);
        if (r != 0) return -100 - r;
        struct proto_table_write_resp w;
        CHECK(proto_table_write_resp_decode(out, out_len, &w) == 0 && w.staged == off + n);
    }
    return commit(TS, crc_of(t), force);
}

static bool pull(uint8_t *t, size_t chunk)
{
    size_t got = 0;
    for (;;) {
        uint8_t p[4] = { (uint8_t)got, (uint8_t)(got >> 8), (uint8_t)chunk, (uint8_t)(chunk >> 8) };
        if (req(PROTO_T_TABLE_READ, p, 4) != 0) return false;
        struct proto_table_read_resp r;
        if (proto_table_read_resp_decode(out, out_len, &r) != 0 || r.total != TS) return false;
        memcpy(t + got, r.data, r.data_len);
        got += r.data_len;
        if (got >= TS) return got == TS;
        if (r.data_len == 0) return false;
    }
}

static struct proto_table_info_resp info(void)
{
    struct proto_table_info_resp i;
    memset(&i, 0, sizeof i);
    CHECK(req(PROTO_T_TABLE_INFO, NULL, 0) == 0);
    CHECK(proto_table_info_resp_decode(out, out_len, &i) == 0);
    return i;
}

static void reseal(uint8_t *b)
{
    uint32_t c = crc32_update(0, b, TS - 4u);
    for (int i = 0; i < 4; i++) b[TS - 4 + i] = (uint8_t)(c >> (8 * i));
}

int main(void)
{
    char path[64];
    tmp_path(path, sizeof path, "handlers", ".bin");
    unlink(path);
    native_flash_reset();
    CHECK(native_flash_open(path) == 0);
    /* no caltable_init(): the first request loads the store (lazily, as on a station) */

    uint8_t uid[12], other[12];
    board_uid(uid);
    memcpy(other, uid, 12);
    other[11] ^= 0x5A;
    static uint8_t mine[TS], theirs[TS], back[TS], bad[TS];
    test_cal_table(mine, uid, -500.0f);
    test_cal_table(theirs, other, 250.0f);
    CHECK(caltable_validate(mine, TS, uid) == CALTABLE_OK);

    /* empty station */
    struct proto_table_info_resp i = info();
    CHECK(i.active == 0xFF && i.slot0_state == PROTO_TABLE_SLOT_STATE_EMPTY && i.slot1_state == PROTO_TABLE_SLOT_STATE_EMPTY);
    CHECK(i.table_size == TS && i.applied == 0);
    uint8_t rp[4] = { 0, 0, 64, 0 };
    CHECK(req(PROTO_T_TABLE_READ, rp, 4) == PROTO_ERR_NOT_FOUND);

    /* push in 256-byte chunks, read back in 100-byte chunks */
    CHECK(push(mine, 256, 0) == 0);
    struct proto_table_commit_resp c;
    CHECK(proto_table_commit_resp_decode(out, out_len, &c) == 0 && c.slot == 0 && c.sequence == 1);
    CHECK(pull(back, 100) && memcmp(back, mine, TS) == 0);
    i = info();
    CHECK(i.active == 0 && i.slot0_state == PROTO_TABLE_SLOT_STATE_VALID && i.slot0_sequence == 1 && i.applied == 1);
    CHECK(i.table_crc32 == crc_of(mine));
    CHECK(caltable_active() != NULL && caltable_active()->z_ps == -500.0f);

    /* another station's table: refused naming the uid field, unless forced */
    CHECK(push(theirs, 200, 0) == PROTO_ERR_BAD_VALUE && detail == 1);
    CHECK(pull(back, 500) && memcmp(back, mine, TS) == 0);   /* nothing changed */
    CHECK(push(theirs, 200, 1) == 0);
    CHECK(proto_table_commit_resp_decode(out, out_len, &c) == 0 && c.slot == 1 && c.sequence == 2);
    CHECK(pull(back, 500) && memcmp(back, theirs, TS) == 0);
    CHECK(caltable_active() != NULL && caltable_active()->z_ps == 250.0f);   /* used as forced */

    /* restart: reload from the file, the newest table wins */
    native_flash_reset();
    CHECK(native_flash_open(path) == 0);
    caltable_init();
    CHECK(pull(back, 256) && memcmp(back, theirs, TS) == 0);
    i = info();
    CHECK(i.active == 1 && i.slot0_sequence == 1 && i.slot1_sequence == 2);

    /* after a restart the first request may be a table_write: the lazy load of the active
     * table (through the staging buffer) must not eat the upload */
    native_flash_reset();
    CHECK(native_flash_open(path) == 0);
    caltable_reset_state();
    CHECK(push(theirs, 256, 1) == 0);
    CHECK(proto_table_commit_resp_decode(out, out_len, &c) == 0 && c.slot == 0 && c.sequence == 3);
    CHECK(push(theirs, 256, 1) == 0);   /* back to slot 1, sequence 4 */
    CHECK(proto_table_commit_resp_decode(out, out_len, &c) == 0 && c.slot == 1 && c.sequence == 4);

    /* validation: the field index comes back, nothing is written */
    memcpy(bad, mine, TS);
    static struct proto_cal_table t;
    proto_cal_table_decode(bad, &t);
    t.curve_dbm[2] = t.curve_dbm[1];   /* not increasing: field 13 */
    proto_cal_table_encode(&t, bad);
    reseal(bad);
    CHECK(push(bad, 256, 0) == PROTO_ERR_BAD_VALUE && detail == 13);
    t.curve_dbm[2] = -80.0f;
    t.curve_ps[1] = 5001.0f;   /* field 14 */
    proto_cal_table_encode(&t, bad);
    reseal(bad);
    CHECK(push(bad, 256, 1) == PROTO_ERR_BAD_VALUE && detail == 14);
    CHECK(info().slot1_sequence == 4 && info().active == 1);

    /* request-level errors */
    CHECK(write_chunk(0, mine, 100) == 0);
    CHECK(write_chunk(200, mine + 200, 10) == PROTO_ERR_BAD_VALUE && detail == 0);   /* gap */
    CHECK(write_chunk(100, mine + 100, 10) == 0);
    CHECK(write_chunk(100, mine + 100, 10) == 0);   /* a repeated chunk is fine */
    CHECK(write_chunk(100, mine, 490) == PROTO_ERR_BAD_VALUE && detail == 1);       /* past the end */
    CHECK(commit(TS, crc_of(mine), 0) == PROTO_ERR_BAD_VALUE && detail == (PROTO_TABLE_DETAIL_REQUEST | 0));
    for (size_t off = 0; off < TS; off += 300) {
        CHECK(write_chunk((uint16_t)off, mine + off, TS - off < 300 ? TS - off : 300) == 0);
    }
    CHECK(commit(TS - 1, crc_of(mine), 0) == PROTO_ERR_BAD_VALUE && detail == (PROTO_TABLE_DETAIL_REQUEST | 0));
    CHECK(commit(TS, crc_of(mine) ^ 1u, 0) == PROTO_ERR_BAD_VALUE && detail == (PROTO_TABLE_DETAIL_REQUEST | 1));
    CHECK(commit(TS, crc_of(mine), 0) == 0);
    CHECK(proto_table_commit_resp_decode(out, out_len, &c) == 0 && c.slot == 0 && c.sequence == 5);
    CHECK(commit(TS, crc_of(mine), 0) == PROTO_ERR_BAD_VALUE);   /* staging is consumed */
    uint8_t rp2[4] = { (uint8_t)TS, (uint8_t)(TS >> 8), 10, 0 };
    CHECK(req(PROTO_T_TABLE_READ, rp2, 4) == PROTO_ERR_BAD_VALUE && detail == 0);
    uint8_t rp3[4] = { 0, 0, 0, 0 };
    CHECK(req(PROTO_T_TABLE_READ, rp3, 4) == PROTO_ERR_BAD_VALUE && detail == 1);
    CHECK(req(PROTO_T_TABLE_READ, rp3, 3) == PROTO_ERR_BAD_LENGTH);
    uint8_t rp4[4] = { 0, 0, 501 & 0xFF, 501 >> 8 };
    CHECK(req(PROTO_T_TABLE_READ, rp4, 4) == PROTO_ERR_BAD_VALUE && detail == 1);
    rp4[2] = 500 & 0xFF;
    CHECK(req(PROTO_T_TABLE_READ, rp4, 4) == 0 && out_len == 2 + 500);

    /* a torn slot is reported and not used */
    FILE *f = fopen(path, "r+b");
    CHECK(f != NULL);
    if (f) {
        fseek(f, 2048 - 4, SEEK_SET);   /* slot 0's commit word */
        fputc(0xFF, f);
        fclose(f);
    }
    native_flash_reset();
    CHECK(native_flash_open(path) == 0);
    caltable_init();
    i = info();
    CHECK(i.slot0_state == PROTO_TABLE_SLOT_STATE_TORN && i.active == 1 && i.applied == 1);
    CHECK(pull(back, 256) && memcmp(back, theirs, TS) == 0);

    /* erase */
    CHECK(req(PROTO_T_TABLE_ERASE, NULL, 0) == 0);
    i = info();
    CHECK(i.active == 0xFF && i.slot0_state == PROTO_TABLE_SLOT_STATE_EMPTY && i.slot1_state == PROTO_TABLE_SLOT_STATE_EMPTY && i.applied == 0);
    CHECK(req(PROTO_T_TABLE_READ, rp, 4) == PROTO_ERR_NOT_FOUND);
    CHECK(caltable_active() == NULL);

    native_flash_reset();
    unlink(path);
    return check_summary();
}
