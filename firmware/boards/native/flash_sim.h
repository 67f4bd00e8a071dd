/* Test hooks of the native board's file-backed flash (flash.c): reset the simulated flash,
 * count its operations, and cut the power during one of them with a chosen tear mode.
 *
 * Native-only: included by flash.c and by the C tests (tests/firmware/), never by the EVK1000
 * build. native_flash_open() itself stays in native.h (main.c opens the flash file through it).
 *
 * Every page erase and every half-word program is one "flash operation"; reads are not.
 * See flash.c for the STM32F1 rules enforced and for what each tear mode leaves behind.
 */
#ifndef UWBCAL_NATIVE_FLASH_SIM_H
#define UWBCAL_NATIVE_FLASH_SIM_H

#include <stdbool.h>
#include <stdint.h>

#include "native.h"

/* What the operation interrupted by the power cut leaves behind. */
enum {
    NATIVE_TEAR_NONE = 0,     /* it had not started: nothing changed */
    NATIVE_TEAR_PARTIAL = 1,  /* a seeded random part of it happened (the default) */
    NATIVE_TEAR_FULL = 2,     /* it completed, the power went just after it */
};

/* Close the file and forget the RAM image (all 0xFF); clears the counter and any cut.
 * Reset then native_flash_open(path) is a station restart. */
void native_flash_reset(void);
/* Cut the power during operation n (counting from 0, from now; -1: never). Restarts the
 * operation counter and powers on. */
void native_flash_cut_at(long n);
/* Tear mode (NATIVE_TEAR_*) and PRNG seed (0: the default seed) for the next cut. */
void native_flash_tear(int mode, uint32_t seed);
/* Power back on after a cut: operations work again; no cut pending, counter at 0. */
void native_flash_power_on(void);
/* Flash operations counted since the last reset, cut_at or power-on. */
long native_flash_ops(void);
/* False from the cut until native_flash_power_on(): every operation fails. */
bool native_flash_powered(void);
/* Close the flash file (the RAM image stays). */
void native_flash_close(void);

#endif
