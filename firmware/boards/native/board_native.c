/* Native board: identity, time, idle, reset, and weak fallbacks for the flash (flash.c) and
 * radio tunnel (radio_tunnel.c) hooks declared in native.h. */
#define _XOPEN_SOURCE 700
#include <errno.h>
#include <poll.h>
#include <stdio.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "board.h"
#include "native.h"

static uint16_t station_id;
static char **saved_argv;
static uint64_t t0_us;
static int t0_set;

static uint64_t raw_monotonic_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000u + (uint64_t)ts.tv_nsec / 1000u;
}

uint64_t native_monotonic_us(void)
{
    uint64_t now = raw_monotonic_us();
    if (!t0_set) {
        t0_us = now;
        t0_set = 1;
    }
    return now - t0_us;
}

void native_board_init(uint16_t id, char **argv)
{
    station_id = id;
    saved_argv = argv;
    (void)native_monotonic_us();
    native_catch_exit_signals();
}


uint16_t native_station_id(void) { return station_id; }

static uint64_t splitmix64(uint64_t x)
{
    x += 0x9E3779B97F4A7C15ull;
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
    return x ^ (x >> 31);
}

void native_uid_for_id(uint16_t id, uint8_t uid[12])
{
    /* splitmix64 is a bijection of 64-bit words: distinct ids give distinct first 8 bytes. */
    uint64_t a = splitmix64((uint64_t)id);
    uint64_t b = splitmix64(a ^ 0x55574243414C0000ull); /* "UWBCAL" */
    for (int i = 0; i < 8; i++) uid[i] = (uint8_t)(a >> (8 * i));
    for (int i = 0; i < 4; i++) uid[8 + i] = (uint8_t)(b >> (8 * i));
}

/* ---- board.h ---- */

const char *board_name(void) { return "native"; }

void board_uid(uint8_t uid[12]) { native_uid_for_id(station_id, uid); }

uint64_t board_time_us(void)
{
    uint64_t now;
    if (native_radio_time_us(&now) == 0) return now;
    return native_monotonic_us();
}

void board_idle(uint32_t max_us) { native_radio_idle(max_us); }

void board_reset(void)
{
    fflush(stdout);
    fflush(stderr);
    if (saved_argv != NULL) {
        native_link_prepare_exec();
        execv("/proc/self/exe", saved_argv);
        fprintf(stderr, "uwbcal-station: reset: exec failed: %s\n", strerror(errno));
    }
    _exit(1);
}

const struct dw_ops *board_dw_ops(void) { return native_radio_ops(); }

void native_wait_input(int extra_fd, uint32_t max_us)
{
    /* native_link_fd() is -1 while no host has the pty open: then this only sleeps. */
    struct pollfd p[2] = {{.fd = native_link_fd(), .events = POLLIN}, {.fd = extra_fd, .events = POLLIN}};
    int ms = (int)((max_us + 999u) / 1000u);
    if (native_should_exit()) return;
    poll(p, 2, ms);
}

/* ---- weak fallbacks: flash (the tables module's flash.c overrides them) ---- */

__attribute__((weak)) int native_flash_open(const char *path)
{
    (void)path;
    return -1;
}
__attribute__((weak)) uint32_t board_flash_page_size(void) { return 2048u; }
__attribute__((weak)) uint32_t board_flash_table_base(void) { return 0x0803F000u; }
__attribute__((weak)) int board_flash_erase_page(uint32_t addr)
{
    (void)addr;
    return BOARD_EFLASH;
}
__attribute__((weak)) int board_flash_program(uint32_t addr, const uint8_t *data, size_t len)
{
    (void)addr;
    (void)data;
    (void)len;
    return BOARD_EFLASH;
}
__attribute__((weak)) int board_flash_read(uint32_t addr, uint8_t *data, size_t len)
{
    (void)addr;
    (void)data;
    (void)len;
    return BOARD_EFLASH;
}

/* ---- weak fallbacks: radio (the measurement module's radio_tunnel.c overrides them) ---- */

__attribute__((weak)) int native_radio_attach(const char *socket_path, uint16_t id, const uint8_t uid[12])
{
    (void)id;
    (void)uid;
    fprintf(stderr, "uwbcal-station: --medium %s: this build has no radio tunnel (radio_tunnel.c)\n",
            socket_path);
    return -1;
}
__attribute__((weak)) const struct dw_ops *native_radio_ops(void) { return NULL; }
__attribute__((weak)) int native_radio_time_us(uint64_t *now)
{
    (void)now;
    return -1;
}
__attribute__((weak)) void native_radio_idle(uint32_t max_us) { native_wait_input(-1, max_us); }
