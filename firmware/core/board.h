/* The narrow interface between the portable firmware (core/, dw1000/) and a board.
 * Everything that touches hardware, or the host OS on the native board, is behind it.
 * Implemented once per board: boards/evk1000 (STM32F105RC) and boards/native (host process).
 */
#ifndef UWBCAL_BOARD_H
#define UWBCAL_BOARD_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

struct dw_ops;

/* ---- identity ---------------------------------------------------------------------- */
const char *board_name(void);                 /* short name, e.g. "evk1000", "native" */
void board_uid(uint8_t uid[12]);              /* 96-bit unique id, stable across restarts */

/* ---- time -------------------------------------------------------------------------- */
/* Monotonic microseconds since boot. On the native board attached to a medium this is the
 * medium's virtual time, so every timeout in the firmware is in virtual time. */
uint64_t board_time_us(void);

/* ---- host link (a byte stream: USB CDC, USART, or a pty) ---------------------------- */
size_t board_link_read(uint8_t *buf, size_t max);       /* non-blocking; bytes read now */
bool board_link_write(const uint8_t *buf, size_t len);  /* all bytes, or false on timeout */
/* Nothing to do: sleep until link input, a radio IRQ, or at most max_us. */
void board_idle(uint32_t max_us);

/* ---- reset ------------------------------------------------------------------------- */
void board_reset(void);                                 /* does not return */
/* Link bytes already read but not handled when a RESET ran (requests in the same read): a
 * board that can hands them to the restarted station's first board_link_read(). The core's
 * weak default drops them (the host's retry of those requests then reaches the new station). */
void board_link_keep(const uint8_t *buf, size_t len);

/* ---- flash region for calibration tables --------------------------------------------
 * BOARD_TABLE_PAGES pages of board_flash_page_size() bytes each, starting at
 * board_flash_table_base(). STM32F1 rules everywhere: erased bytes read 0xFF, a page must
 * be erased before it is programmed, programming is by 16-bit half-words (len even,
 * addr even), each half-word programmed at most once between erases.
 * Return 0 on success, a negative BOARD_E* code on failure. */
#define BOARD_TABLE_PAGES 2u
#define BOARD_EOK 0
#define BOARD_EFLASH (-1)    /* erase/program failed or verify mismatch */
#define BOARD_EARG (-2)      /* address/length outside the region or misaligned */
#define BOARD_ETIMEOUT (-3)  /* a wait ran out */
uint32_t board_flash_page_size(void);
uint32_t board_flash_table_base(void);
int board_flash_erase_page(uint32_t addr);
int board_flash_program(uint32_t addr, const uint8_t *data, size_t len);
int board_flash_read(uint32_t addr, uint8_t *data, size_t len);

/* ---- radio ------------------------------------------------------------------------- */
/* The DW1000 ops table of this board (see dw1000/dw1000_ops.h), or NULL if the board has
 * no radio attached (the native board run without a medium). */
const struct dw_ops *board_dw_ops(void);

#endif
