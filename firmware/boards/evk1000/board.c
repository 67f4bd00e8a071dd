/* Identity and reset of the EVK1000 board (board.h). */
#include <stdint.h>

#include "board.h"
#include "evk1000.h"
#include "stm32f105.h"

/* The name GET_INFO reports. If the 12 MHz crystal or a PLL did not start, the board runs on
 * the 8 MHz HSI (clock.c) and says so here, where `uwbcal info` shows it: DW1000 timing is
 * unaffected (its own crystal), but the host link and every MCU timing run on a +-1 % RC. */
const char *board_name(void)
{
    return evk_clock_source() == EVK_CLOCK_HSI ? "evk1000/hsi" : "evk1000";
}

void board_uid(uint8_t uid[12])
{
    /* RM0008 30.2: 96-bit unique device ID at 0x1FFFF7E8, read as bytes (little endian,
     * the same byte order ST's tools print). */
    const volatile uint8_t *p = (const volatile uint8_t *)(uintptr_t)UID_BASE;
    for (unsigned i = 0; i < 12u; i++)
        uid[i] = p[i];
}

void board_reset(void)
{
    /* PM0056 4.4.4: AIRCR.SYSRESETREQ with the VECTKEY. Let the last bytes of the link
     * leave first (bounded). */
    evk_link_flush();
    cpu_dsb();
    SCB_AIRCR = SCB_AIRCR_VECTKEY | SCB_AIRCR_SYSRESETREQ;
    cpu_dsb();
    for (;;)
        cpu_nop();
}
