/* Two-slot table store, and the MCUboot-style power-cut test: cut the power at every flash
 * operation of a table write (with three ways of tearing the interrupted operation), restart
 * from the flash file, and require exactly the old table or the new one to be active. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "board.h"
#include "boards/native/flash_sim.h"
#include "check.h"
#include "table_store.h"
#include "tmp_path.h"

#define TLEN 581u   /* the size of a cal_table (odd: exercises the padded last half-word) */

static char path[64];

static void fill(uint8_t *t, size_t n, uint32_t seed)
{
    for (size_t i = 0; i < n; i++) {
        seed = seed * 1664525u + 1013904223u;
        t[i] = (uint8_t)(seed >> 24);
    }
}

/* Power off and on: forget RAM, reload the flash file, run the boot scan. */
static void restart(void)
{
    native_flash_reset();
    CHECK(native_flash_open(path) == 0);
    CHECK(table_store_init() == BOARD_EOK);
}

static void fresh(void)
{
    native_flash_reset();
    unlink(path);
    CHECK(native_flash_open(path) == 0);
    CHECK(table_store_init() == BOARD_EOK);
}

static bool active_is(const uint8_t *t, size_t n)
{
    static uint8_t buf[2048];
    if (table_store_active_len() != n) {
        return false;
    }
    if (table_store_read(0, buf, n) != BOARD_EOK) {
        return false;
    }
    return memcmp(buf, t, n) == 0;
}

static void test_basic(void)
{
    static uint8_t a[TLEN], b[TLEN], c[TLEN];
    fill(a, TLEN, 1);
    fill(b, TLEN, 2);
    fill(c, TLEN, 3);
    fresh();
    const struct table_store_info *in = table_store_get_info();
    CHECK(in->active == -1);
    CHECK(in->state[0] == PROTO_TABLE_SLOT_STATE_EMPTY && in->state[1] == PROTO_TABLE_SLOT_STATE_EMPTY);
    CHECK(table_store_active_len() == 0);
    uint8_t x;
    CHECK(table_store_read(0, &x, 1) == BOARD_EARG);

    uint8_t slot = 9;
    uint32_t seq = 0;
    CHECK(table_store_write(a, TLEN, &slot, &seq) == BOARD_EOK);
    CHECK(slot == 0 && seq == 1 && active_is(a, TLEN));
    CHECK(table_store_write(b, TLEN, &slot, &seq) == BOARD_EOK);
    CHECK(slot == 1 && seq == 2 && active_is(b, TLEN));
    CHECK(in->state[0] == PROTO_TABLE_SLOT_STATE_VALID && in->state[1] == PROTO_TABLE_SLOT_STATE_VALID);
    CHECK(table_store_write(c, TLEN, &slot, &seq) == BOARD_EOK);
    CHECK(slot == 0 && seq == 3 && active_is(c, TLEN));
    restart();
    CHECK(active_is(c, TLEN));
    CHECK(in->active == 0 && in->seq[0] == 3 && in->seq[1] == 2);
    /* reads are bounded by the table */
    CHECK(table_store_read(TLEN - 1, &x, 1) == BOARD_EOK && x == c[TLEN - 1]);
    CHECK(table_store_read(TLEN, &x, 1) == BOARD_EARG);
    /* size limits */
    CHECK(table_store_write(a, 0, NULL, NULL) == BOARD_EARG);
    CHECK(table_store_write(a, table_store_max_len() + 1, NULL, NULL) == BOARD_EARG);
    static uint8_t big[2048];
    fill(big, sizeof big, 4);
    CHECK(table_store_write(big, table_store_max_len(), NULL, NULL) == BOARD_EOK);
    CHECK(active_is(big, table_store_max_len()));
    CHECK(table_store_write(a, 2, NULL, NULL) == BOARD_EOK && active_is(a, 2));
    CHECK(table_store_write(a, 1, NULL, NULL) == BOARD_EOK && active_is(a, 1));
    restart();
    CHECK(active_is(a, 1));

    CHECK(table_store_erase() == BOARD_EOK);
    CHECK(in->active == -1 && in->state[0] == PROTO_TABLE_SLOT_STATE_EMPTY && in->state[1] == PROTO_TABLE_SLOT_STATE_EMPTY);
    restart();
    CHECK(in->active == -1);
}

/* Damage a byte of the flash file directly (a bit flip no flash operation could make). */
static void poke_file(uint32_t off, uint8_t xor_mask)
{
    FILE *f = fopen(path, "r+b");
    CHECK(f != NULL);
    if (!f) {
        return;
    }
    CHECK(fseek(f, (long)off, SEEK_SET) == 0);
    int c = fgetc(f);
    CHECK(c != EOF);
    CHECK(fseek(f, (long)off, SEEK_SET) == 0);
    fputc(c ^ xor_mask, f);
    fclose(f);
}

static void test_corrupt_reported(void)
{
    static uint8_t a[TLEN], b[TLEN];
    fill(a, TLEN, 11);
    fill(b, TLEN, 12);
    const struct table_store_info *in = table_store_get_info();
    /* a flipped bit in the newer table: it is reported corrupt and the older one is used */
    fresh();
    CHECK(table_store_write(a, TLEN, NULL, NULL) == BOARD_EOK);
    CHECK(table_store_write(b, TLEN, NULL, NULL) == BOARD_EOK);
    poke_file(2048 + TABLE_STORE_HDR + 100, 0x04);
    restart();
    CHECK(in->state[1] == PROTO_TABLE_SLOT_STATE_CORRUPT && in->state[0] == PROTO_TABLE_SLOT_STATE_VALID);
    CHECK(in->active == 0 && active_is(a, TLEN));
    /* a damaged sequence number is caught too (the header is under the CRC) */
    fresh();
    CHECK(table_store_write(a, TLEN, NULL, NULL) == BOARD_EOK);
    CHECK(table_store_write(b, TLEN, NULL, NULL) == BOARD_EOK);
    poke_file(4, 0x10);   /* slot 0 (older) claims seq 17 */
    restart();
    CHECK(in->state[0] == PROTO_TABLE_SLOT_STATE_CORRUPT && in->active == 1 && active_is(b, TLEN));
    /* a header without a commit word is torn, never used */
    fresh();
    CHECK(table_store_write(a, TLEN, NULL, NULL) == BOARD_EOK);
    poke_file(2048 - 4, 0x01);   /* commit word of slot 0 no longer matches */
    restart();
    CHECK(in->state[0] == PROTO_TABLE_SLOT_STATE_TORN && in->active == -1 && table_store_active_len() == 0);
    /* and the next write goes over it */
    CHECK(table_store_write(b, TLEN, NULL, NULL) == BOARD_EOK && active_is(b, TLEN));
    restart();
    CHECK(active_is(b, TLEN));
}

struct cut_stats {
    long cases, old_wins, new_wins, torn_reported, corrupt_reported;
};

/* One power-cut run. Before: t0 in slot 0 (seq 1) and old in slot 1 (seq 2) if two_slots,
 * else only old in slot 0. The write of neu is cut at operation n. */
static void cut_case(bool two_slots, long n, int mode, uint32_t seed, long total_ops,
                     const uint8_t *t0, const uint8_t *old, const uint8_t *neu, struct cut_stats *st)
{
    fresh();
    if (two_slots) {
        CHECK(table_store_write(t0, TLEN, NULL, NULL) == BOARD_EOK);
    }
    CHECK(table_store_write(old, TLEN, NULL, NULL) == BOARD_EOK);
    native_flash_cut_at(n);
    native_flash_tear(mode, seed);
    int r = table_store_write(neu, TLEN, NULL, NULL);
    CHECK(r != BOARD_EOK);   /* the power went during the write: it cannot report success */
    restart();
    bool is_old = active_is(old, TLEN), is_new = active_is(neu, TLEN);
    st->cases++;
    if (!(is_old || is_new)) {
        fprintf(stderr, "cut at op %ld/%ld mode %d seed %u two_slots %d: neither table active\n",
                n, total_ops, mode, seed, two_slots);
    }
    CHECK(is_old || is_new);
    st->old_wins += is_old;
    st->new_wins += is_new;
    const struct table_store_info *in = table_store_get_info();
    for (unsigned s = 0; s < 2; s++) {
        st->torn_reported += in->state[s] == PROTO_TABLE_SLOT_STATE_TORN;
        st->corrupt_reported += in->state[s] == PROTO_TABLE_SLOT_STATE_CORRUPT;
    }
    /* the slot being written (slot 0 over t0 when two_slots, else slot 1) shows what the cut
     * left: once its erase is done, only a torn slot (commit word not whole) or the new
     * table; a "corrupt" one would mean a commit word programmed before the data */
    unsigned target = two_slots ? 0u : 1u;
    if (n > 0 && !is_new) {
        CHECK(in->state[target] == PROTO_TABLE_SLOT_STATE_TORN || in->state[target] == PROTO_TABLE_SLOT_STATE_EMPTY);
    }
    /* what we know for certain: the new table can only win once its commit word is whole */
    if (n < total_ops - 1 || mode == NATIVE_TEAR_NONE) {
        CHECK(is_old);
    }
    if (n == total_ops - 1 && mode == NATIVE_TEAR_FULL) {
        CHECK(is_new);
    }
    /* after the restart the store works: a further write succeeds and survives a restart */
    static uint8_t more[TLEN];
    fill(more, TLEN, (uint32_t)n + 1000u);
    CHECK(table_store_write(more, TLEN, NULL, NULL) == BOARD_EOK);
    restart();
    CHECK(active_is(more, TLEN));
}

static void test_power_cut(void)
{
    static uint8_t t0[TLEN], old[TLEN], neu[TLEN];
    fill(t0, TLEN, 21);
    fill(old, TLEN, 22);
    fill(neu, TLEN, 23);
    /* count the operations of one uninterrupted write */
    fresh();
    CHECK(table_store_write(old, TLEN, NULL, NULL) == BOARD_EOK);
    native_flash_cut_at(-1);
    CHECK(table_store_write(neu, TLEN, NULL, NULL) == BOARD_EOK);
    long total = native_flash_ops();
    /* 1 erase + 8 header half-words + ceil(581 / 2) table half-words + 2 commit half-words */
    CHECK(total == 1 + 8 + (TLEN + 1) / 2 + 2);
    struct cut_stats st = { 0, 0, 0, 0, 0 };
    for (int two = 0; two <= 1; two++) {
        for (long n = 0; n < total; n++) {
            cut_case(two, n, NATIVE_TEAR_NONE, 1, total, t0, old, neu, &st);
            cut_case(two, n, NATIVE_TEAR_FULL, 1, total, t0, old, neu, &st);
            for (uint32_t seed = 1; seed <= 4; seed++) {
                cut_case(two, n, NATIVE_TEAR_PARTIAL, seed * 2654435761u + (uint32_t)n, total, t0, old,
                         neu, &st);
            }
        }
    }
    printf("power cut: %ld flash operations per write, %ld cases: old table %ld, new table %ld, "
           "torn slots reported %ld, corrupt slots reported %ld\n",
           total, st.cases, st.old_wins, st.new_wins, st.torn_reported, st.corrupt_reported);
    CHECK(st.cases == 2 * total * 6);
    CHECK(st.old_wins + st.new_wins == st.cases);
    CHECK(st.new_wins >= 2);   /* the FULL tear of the last operation, in both layouts */
    CHECK(st.torn_reported > 0);   /* interrupted writes are reported, not hidden */
}

int main(void)
{
    tmp_path(path, sizeof path, "store-test", ".bin");
    test_basic();
    test_corrupt_reported();
    test_power_cut();
    native_flash_reset();
    unlink(path);
    return check_summary();
}
