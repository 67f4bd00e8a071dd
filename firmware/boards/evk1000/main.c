/* EVK1000 entry point. startup.c has already copied .data, zeroed .bss and set up the
 * clocks (72 MHz, or HSI 8 MHz if the crystal/PLL failed) and SysTick. Here: the host link,
 * the DW1000 wiring, then the shared station loop of core/app.h. */
#include "app.h"
#include "board.h"
#include "evk1000.h"

int main(void)
{
    evk_link_init();
    evk_dw_init();
    app_init();
    for (;;) {
        if (!app_poll())
            board_idle(app_idle_us());
    }
}
