/* The native flash file obeys the STM32F1 rules, persists across a restart, and its power
 * cut tears exactly the operation it is told to. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "board.h"
#include "boards/native/flash_sim.h"
#include "check.h"

static uint32_t base(void) { return board_flash_table_base(); }

static bool all_ff(uint32_t addr, size_t len)
{
    uint8_t b[2048];
    if (len > sizeof b || board_flash_read(addr, b, len) != BOARD_EOK) {
        return false;
    }
    for (size_t i = 0; i < len; i++) {
        if (b[i] != 0xFF) {
            return false;
        }
    }
    return true;
}

static void test_rules(void)
{
    native_flash_reset();
    CHECK(native_flash_open(NULL) == 0);
    uint32_t ps = board_flash_page_size();
    CHECK(ps == 2048);
    CHECK(all_ff(base(), ps));
    CHECK(all_ff(base() + ps, ps));
    const uint8_t d[4] = { 0x12, 0x34, 0x00, 0xFF };
    CHECK(board_flash_program(base(), d, 4) == BOARD_EOK);
    uint8_t r[4];
    CHECK(board_flash_read(base(), r, 4) == BOARD_EOK && memcmp(r, d, 4) == 0);
    /* a programmed half-word cannot be programmed again, not even to clear more bits */
    const uint8_t z[2] = { 0x00, 0x00 };
    CHECK(board_flash_program(base(), z, 2) == BOARD_EFLASH);
    CHECK(board_flash_read(base(), r, 2) == BOARD_EOK && r[0] == 0x12 && r[1] == 0x34);
    /* 0x00FF was programmed as a value: the half-word is no longer 0xFFFF */
    CHECK(board_flash_program(base() + 2, z, 2) == BOARD_EFLASH);
    /* 16-bit programming only, inside the region only */
    CHECK(board_flash_program(base() + 5, z, 2) == BOARD_EARG);
    CHECK(board_flash_program(base() + 8, d, 3) == BOARD_EARG);
    CHECK(board_flash_program(base() - 2, z, 2) == BOARD_EARG);
    CHECK(board_flash_program(base() + 2 * ps - 2, d, 4) == BOARD_EARG);
    CHECK(board_flash_read(base() + 2 * ps - 1, r, 2) == BOARD_EARG);
    CHECK(board_flash_erase_page(base() + 2) == BOARD_EARG);
    CHECK(board_flash_erase_page(base() + 2 * ps) == BOARD_EARG);
    /* erase makes the page 0xFF and programmable again; the other page is untouched */
    CHECK(board_flash_program(base() + ps, d, 2) == BOARD_EOK);
    CHECK(board_flash_erase_page(base()) == BOARD_EOK);
    CHECK(all_ff(base(), ps));
    CHECK(board_flash_read(base() + ps, r, 2) == BOARD_EOK && r[0] == 0x12);
    CHECK(board_flash_program(base(), z, 2) == BOARD_EOK);
}

static void test_counter_and_cut(void)
{
    native_flash_reset();
    CHECK(native_flash_open(NULL) == 0);
    native_flash_cut_at(-1);
    uint8_t d[8] = { 0, 0, 0, 0, 0, 0, 0, 0 };
    CHECK(board_flash_erase_page(base()) == BOARD_EOK);
    CHECK(board_flash_program(base(), d, 8) == BOARD_EOK);
    CHECK(native_flash_ops() == 5);   /* one erase, four half-words */
    uint8_t r[8];
    CHECK(board_flash_read(base(), r, 8) == BOARD_EOK);   /* reads are not operations */
    CHECK(native_flash_ops() == 5);

    /* cut at the third half-word of a program, no tearing: two done, the rest not */
    CHECK(board_flash_erase_page(base()) == BOARD_EOK);
    native_flash_cut_at(2);
    native_flash_tear(NATIVE_TEAR_NONE, 1);
    CHECK(board_flash_program(base(), d, 8) == BOARD_EFLASH);
    CHECK(!native_flash_powered());
    CHECK(board_flash_erase_page(base()) == BOARD_EFLASH);   /* dead until power-on */
    native_flash_power_on();
    CHECK(board_flash_read(base(), r, 8) == BOARD_EOK);
    CHECK(r[0] == 0 && r[3] == 0 && r[4] == 0xFF && r[7] == 0xFF);

    /* full tear: the cut operation completed */
    CHECK(board_flash_erase_page(base()) == BOARD_EOK);
    native_flash_cut_at(2);
    native_flash_tear(NATIVE_TEAR_FULL, 1);
    CHECK(board_flash_program(base(), d, 8) == BOARD_EFLASH);
    native_flash_power_on();
    CHECK(board_flash_read(base(), r, 8) == BOARD_EOK);
    CHECK(r[4] == 0 && r[5] == 0 && r[6] == 0xFF);

    /* partial program: only 1->0 transitions, a subset of the wanted ones; over seeds
     * both "some but not all" and the extremes occur */
    int partial_seen = 0;
    for (uint32_t seed = 1; seed <= 64; seed++) {
        CHECK(board_flash_erase_page(base()) == BOARD_EOK);
        native_flash_cut_at(0);
        native_flash_tear(NATIVE_TEAR_PARTIAL, seed);
        const uint8_t w[2] = { 0x0F, 0x30 };
        CHECK(board_flash_program(base(), w, 2) == BOARD_EFLASH);
        native_flash_power_on();
        CHECK(board_flash_read(base(), r, 2) == BOARD_EOK);
        uint16_t got = (uint16_t)(r[0] | (r[1] << 8)), want = 0x300F;
        CHECK((got & want) == want);   /* no wanted 1 became 0 */
        if (got != want && got != 0xFFFF) {
            partial_seen++;
        }
        /* and the torn half-word cannot be finished by programming it again */
        if (got != 0xFFFF) {
            CHECK(board_flash_program(base(), w, 2) == BOARD_EFLASH);
        }
    }
    CHECK(partial_seen > 10);

    /* partial erase: bits only go up; some bytes 0xFF, some not */
    int mixed = 0;
    for (uint32_t seed = 1; seed <= 16; seed++) {
        native_flash_cut_at(-1);
        CHECK(board_flash_erase_page(base()) == BOARD_EOK);
        static uint8_t page[2048];
        for (size_t i = 0; i < sizeof page; i++) {
            page[i] = (uint8_t)(i * 7u);
        }
        page[0] = 0x00;
        CHECK(board_flash_program(base(), page, sizeof page) == BOARD_EOK);
        native_flash_cut_at(0);
        native_flash_tear(NATIVE_TEAR_PARTIAL, seed);
        CHECK(board_flash_erase_page(base()) == BOARD_EFLASH);
        native_flash_power_on();
        static uint8_t after[2048];
        CHECK(board_flash_read(base(), after, sizeof after) == BOARD_EOK);
        int ff = 0, bad = 0;
        for (size_t i = 0; i < sizeof after; i++) {
            ff += after[i] == 0xFF;
            bad += (after[i] & page[i]) != page[i];
        }
        CHECK(bad == 0);
        if (ff > 8 && ff < 2040) {
            mixed++;
        }
    }
    CHECK(mixed > 4);
}

static void test_persistence(void)
{
    char path[] = "/tmp/uwbcal-flash-test-XXXXXX";
    int tfd = mkstemp(path);
    CHECK(tfd >= 0);
    if (tfd < 0) {
        return;
    }
    close(tfd);
    native_flash_reset();
    CHECK(native_flash_open(path) == 0);
    CHECK(all_ff(base(), 2048));   /* an empty file is erased flash */
    const uint8_t d[4] = { 1, 2, 3, 4 };
    CHECK(board_flash_program(base() + 2048 + 100, d, 4) == BOARD_EOK);
    /* "restart": forget the RAM image, reload from the file */
    native_flash_reset();
    CHECK(all_ff(base() + 2048 + 100, 4));
    CHECK(native_flash_open(path) == 0);
    uint8_t r[4];
    CHECK(board_flash_read(base() + 2048 + 100, r, 4) == BOARD_EOK && memcmp(r, d, 4) == 0);
    CHECK(board_flash_program(base() + 2048 + 100, d, 2) == BOARD_EFLASH);   /* still programmed */
    FILE *f = fopen(path, "rb");
    CHECK(f != NULL);
    if (f) {
        CHECK(fseek(f, 0, SEEK_END) == 0 && ftell(f) == 4096);
        fclose(f);
    }
    native_flash_reset();
    unlink(path);
}

int main(void)
{
    test_rules();
    test_counter_and_cut();
    test_persistence();
    return check_summary();
}
