/* Native board: the calibration-table flash region as a file, with the STM32F1 rules and a
 * power-cut simulator (MCUboot's simulator is the model).
 *
 * Rules enforced (as on the STM32F105): erased bytes read 0xFF; programming is by 16-bit
 * half-words at even addresses; a half-word can be programmed only while it reads 0xFFFF
 * (otherwise the operation fails with PGERR and nothing changes, BOARD_EFLASH here); a page
 * is erased as a whole. The image lives in RAM and every change is written through to the
 * file at once, so it survives a restart (or a kill) of the station process.
 *
 * Power cut: every page erase and every half-word program is one "flash operation" and is
 * counted. native_flash_cut_at(n) (or UWBCAL_FLASH_CUT_AT=n in the environment) makes
 * operation n (counting from 0) the one during which the power goes: that operation is torn
 * according to the tear mode, and every later operation fails (the MCU is dead). A station
 * process started with UWBCAL_FLASH_CUT_AT exits at the cut (exit code 86), as a board
 * would stop; a C test instead calls native_flash_power_on() and re-runs its boot code.
 *
 * Tear modes (what the interrupted operation leaves behind):
 *   NATIVE_TEAR_NONE    the operation had not started: nothing changed
 *   NATIVE_TEAR_PARTIAL program: a seeded random subset of the bits that were to go 1->0
 *                       went; erase: a seeded random subset of the page's bytes erased to
 *                       0xFF, and random bits of the rest set to 1 (the erase pulse is
 *                       what sets bits; it may have reached some cells only partly)
 *   NATIVE_TEAR_FULL    the operation completed, the power went just after it
 */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "board.h"
#include "flash_sim.h"   /* the test hooks defined below */
#include "native.h"

#define PAGE_SIZE 2048u
#define REGION_SIZE (PAGE_SIZE * BOARD_TABLE_PAGES)
/* The same addresses as on the EVK1000: the last two pages of the STM32F105RC's 256 KB. */
#define REGION_BASE 0x0803F000u
#define CUT_EXIT_CODE 86

static uint8_t image[REGION_SIZE];
static bool image_ready;
static int fd = -1;
static long op_count;
static long cut_at = -1;
static int tear_mode = NATIVE_TEAR_PARTIAL;
static uint32_t tear_rng = 0x2545F491u;
static bool dead;
static bool exit_on_cut;

static uint32_t rng_next(void)
{
    /* xorshift32: deterministic for a seed, good enough to pick bits */
    uint32_t x = tear_rng;
    x ^= x << 13;
    x ^= x >> 17;
    x ^= x << 5;
    tear_rng = x ? x : 0x2545F491u;
    return tear_rng;
}

static void image_init(void)
{
    if (!image_ready) {
        memset(image, 0xFF, sizeof image);
        image_ready = true;
    }
}

/* Write [off, off+len) of the image through to the file; false on an I/O error. */
static bool persist(uint32_t off, size_t len)
{
    if (fd < 0) {
        return true;
    }
    size_t done = 0;
    while (done < len) {
        ssize_t n = pwrite(fd, image + off + done, len - done, (off_t)(off + done));
        if (n < 0) {
            if (errno == EINTR) {
                continue;
            }
            return false;
        }
        done += (size_t)n;
    }
    return true;
}

static void read_env_hooks(void)
{
    const char *s = getenv("UWBCAL_FLASH_CUT_AT");
    if (s && *s) {
        cut_at = strtol(s, NULL, 10);
        exit_on_cut = true;
    }
    const char *t = getenv("UWBCAL_FLASH_TEAR");
    if (t && *t) {
        if (strcmp(t, "none") == 0) {
            tear_mode = NATIVE_TEAR_NONE;
        } else if (strcmp(t, "full") == 0) {
            tear_mode = NATIVE_TEAR_FULL;
        } else {
            tear_mode = NATIVE_TEAR_PARTIAL;
        }
    }
    const char *seed = getenv("UWBCAL_FLASH_SEED");
    if (seed && *seed) {
        tear_rng = (uint32_t)strtoul(seed, NULL, 0);
        if (tear_rng == 0) {
            tear_rng = 0x2545F491u;
        }
    }
}

int native_flash_open(const char *path)
{
    image_init();
    read_env_hooks();
    if (fd >= 0) {
        close(fd);
        fd = -1;
    }
    if (path == NULL) {
        return 0;   /* RAM only */
    }
    fd = open(path, O_RDWR | O_CREAT | O_CLOEXEC, 0644); /* not inherited across a RESET (exec) */
    if (fd < 0) {
        fprintf(stderr, "flash: cannot open %s: %s\n", path, strerror(errno));
        return -1;
    }
    ssize_t n = pread(fd, image, sizeof image, 0);
    if (n < 0) {
        fprintf(stderr, "flash: cannot read %s: %s\n", path, strerror(errno));
        close(fd);
        fd = -1;
        return -1;
    }
    if ((size_t)n < sizeof image) {
        /* new or short file: the missing part is erased flash */
        memset(image + n, 0xFF, sizeof image - (size_t)n);
        if (!persist((uint32_t)n, sizeof image - (size_t)n)) {
            fprintf(stderr, "flash: cannot write %s: %s\n", path, strerror(errno));
            close(fd);
            fd = -1;
            return -1;
        }
    }
    return 0;
}

void native_flash_close(void)
{
    if (fd >= 0) {
        close(fd);
        fd = -1;
    }
}

void native_flash_reset(void)
{
    native_flash_close();
    memset(image, 0xFF, sizeof image);
    image_ready = true;
    op_count = 0;
    cut_at = -1;
    dead = false;
    exit_on_cut = false;
}

void native_flash_cut_at(long n)
{
    cut_at = n;
    op_count = 0;
    dead = false;
}

void native_flash_tear(int mode, uint32_t seed)
{
    tear_mode = mode;
    tear_rng = seed ? seed : 0x2545F491u;
}

void native_flash_power_on(void)
{
    dead = false;
    cut_at = -1;
    op_count = 0;
}

long native_flash_ops(void)
{
    return op_count;
}

bool native_flash_powered(void)
{
    return !dead;
}

/* Count one operation. Returns 0 to perform it normally, 1 if this is the cut (tear it),
 * -1 if the power is already gone (do nothing). */
static int op_begin(void)
{
    if (dead) {
        return -1;
    }
    long n = op_count++;
    if (cut_at >= 0 && n == cut_at) {
        dead = true;
        return 1;
    }
    return 0;
}

static void op_cut_done(void)
{
    if (exit_on_cut) {
        fprintf(stderr, "flash: power cut at operation %ld\n", cut_at);
        _exit(CUT_EXIT_CODE);
    }
}

uint32_t board_flash_page_size(void)
{
    return PAGE_SIZE;
}

uint32_t board_flash_table_base(void)
{
    return REGION_BASE;
}

static bool in_region(uint32_t addr, size_t len)
{
    return addr >= REGION_BASE && len <= REGION_SIZE && addr - REGION_BASE <= REGION_SIZE - len;
}

int board_flash_erase_page(uint32_t addr)
{
    image_init();
    if (!in_region(addr, PAGE_SIZE) || (addr - REGION_BASE) % PAGE_SIZE != 0) {
        return BOARD_EARG;
    }
    uint32_t off = addr - REGION_BASE;
    int r = op_begin();
    if (r < 0) {
        return BOARD_EFLASH;
    }
    if (r == 0 || tear_mode == NATIVE_TEAR_FULL) {
        memset(image + off, 0xFF, PAGE_SIZE);
    } else if (tear_mode == NATIVE_TEAR_PARTIAL) {
        /* the erase reached a random share of the cells: some bytes fully erased, the
         * others with random bits raised (an erase only ever sets bits) */
        uint32_t share = rng_next() % 101u;   /* percent of bytes fully erased */
        for (uint32_t i = 0; i < PAGE_SIZE; i++) {
            if (rng_next() % 100u < share) {
                image[off + i] = 0xFF;
            } else {
                image[off + i] |= (uint8_t)(rng_next() & rng_next());
            }
        }
    }
    bool ok = persist(off, PAGE_SIZE);
    if (r == 1) {
        op_cut_done();
        return BOARD_EFLASH;
    }
    return ok ? BOARD_EOK : BOARD_EFLASH;
}

int board_flash_program(uint32_t addr, const uint8_t *data, size_t len)
{
    image_init();
    if (data == NULL || len == 0 || len % 2 != 0 || addr % 2 != 0 || !in_region(addr, len)) {
        return BOARD_EARG;
    }
    uint32_t off = addr - REGION_BASE;
    for (size_t i = 0; i < len; i += 2) {
        int r = op_begin();
        if (r < 0) {
            return BOARD_EFLASH;
        }
        uint8_t *cell = image + off + i;
        if (cell[0] != 0xFF || cell[1] != 0xFF) {
            /* PGERR: the half-word is not erased; the STM32F1 leaves it unchanged */
            if (r == 1) {
                op_cut_done();
            }
            return BOARD_EFLASH;
        }
        if (r == 0 || tear_mode == NATIVE_TEAR_FULL) {
            cell[0] = data[i];
            cell[1] = data[i + 1];
        } else if (tear_mode == NATIVE_TEAR_PARTIAL) {
            /* only some of the bits that were to be cleared got cleared */
            uint16_t want = (uint16_t)(data[i] | (data[i + 1] << 8));
            uint16_t keep = (uint16_t)rng_next();   /* 1 = this bit's cell was not reached */
            uint16_t got = (uint16_t)(want | (uint16_t)(~want & keep));
            cell[0] = (uint8_t)(got & 0xFF);
            cell[1] = (uint8_t)(got >> 8);
        }
        bool ok = persist(off + (uint32_t)i, 2);
        if (r == 1) {
            op_cut_done();
            return BOARD_EFLASH;
        }
        if (!ok) {
            return BOARD_EFLASH;
        }
    }
    return BOARD_EOK;
}

int board_flash_read(uint32_t addr, uint8_t *data, size_t len)
{
    image_init();
    if (data == NULL || !in_region(addr, len)) {
        return BOARD_EARG;
    }
    memcpy(data, image + (addr - REGION_BASE), len);
    return BOARD_EOK;
}
