/* The native board: the station firmware as a host process (Zephyr native_sim style).
 *
 *   uwbcal-station --id N [--flash PATH] [--medium SOCKET]
 *
 * Host link: a pty (link_pty.c); the process prints one line "PTY <path>" on stdout.
 * Flash: a file (flash.c, the tables module). Radio: a tunnel to the simulated medium
 * (radio_tunnel.c, the measurement module). board_native.c has __attribute__((weak))
 * fallbacks for every hook below, so the board builds and runs without those modules.
 */
#ifndef UWBCAL_NATIVE_H
#define UWBCAL_NATIVE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

struct dw_ops;

/* ---- station identity (board_native.c) ---- */
uint16_t native_station_id(void);            /* --id */
/* The UID of a station id: stable, distinct for distinct ids (splitmix64 of the id). */
void native_uid_for_id(uint16_t id, uint8_t uid[12]);

/* ---- host link (link_pty.c) ---- */
/* Open a new pty (raw mode) or adopt inherited fds after board_reset(). 0 or -1. */
int native_link_open(void);
const char *native_link_path(void);          /* the slave path, e.g. "/dev/pts/7" */
/* The master fd to poll for host input, or -1 while no host has the pty open (a closed pty
 * reports POLLHUP without end: polling it would spin). Poll for POLLIN only. */
int native_link_fd(void);
/* Keep the fds open across exec (board_reset) and name them in the environment. */
void native_link_prepare_exec(void);

/* ---- process control (board_native.c) ---- */
/* Called first by main(): station id, argv for board_reset(), signal handlers. */
void native_board_init(uint16_t id, char **argv);
bool native_should_exit(void);               /* SIGTERM or SIGINT seen (signals.c) */
void native_catch_exit_signals(void);        /* install that handler, ignore SIGPIPE */
/* poll() the link fd (and extra_fd if >= 0) for input, at most max_us; returns at once
 * when input is pending or a signal arrives. Helper for native_radio_idle implementations. */
void native_wait_input(int extra_fd, uint32_t max_us);
uint64_t native_monotonic_us(void);          /* CLOCK_MONOTONIC since process start, us */

/* ---- flash file (flash.c; weak fallback: -1, board_flash_* return BOARD_EFLASH) ---- */
/* Open or create the flash image file; path NULL: RAM only. 0 or -1. */
int native_flash_open(const char *path);

/* ---- radio tunnel to the medium (radio_tunnel.c; weak fallbacks in board_native.c) ---- */
/* Connect to the medium's unix socket and say hello. 0 or -1 (message on stderr). */
int native_radio_attach(const char *socket_path, uint16_t station_id, const uint8_t uid[12]);
/* The DW1000 ops over the tunnel, NULL when not attached. */
const struct dw_ops *native_radio_ops(void);
/* Virtual time when attached: returns 0 and sets *now; else non-zero. */
int native_radio_time_us(uint64_t *now);
/* Idle at most max_us (virtual time when attached), waking on host link input. */
void native_radio_idle(uint32_t max_us);

#endif
