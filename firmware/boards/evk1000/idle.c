/* board_idle() of the EVK1000, whichever host link is built (link_usart.c or usb/cdc_acm.c):
 * sleep with WFI until link input, a DW1000 interrupt, or the deadline. */
#include <stdint.h>

#include "board.h"
#include "evk1000.h"
#include "stm32f105.h"

void board_idle(uint32_t max_us)
{
    uint64_t deadline = board_time_us() + max_us;
    for (uint32_t pass = 0; pass <= max_us / 1000u + 2u; pass++) {
        if (evk_link_rx_pending() || evk_dw_irq_pending())
            return;
        uint64_t now = board_time_us();
        if (now >= deadline)
            return;
        if (deadline - now < 1000u) {
            /* Less than a SysTick period left: a WFI could oversleep by up to 1 ms. */
            evk_delay_us((uint32_t)(deadline - now));
            return;
        }
        cpu_irq_disable();
        if (!evk_link_rx_pending() && !evk_dw_irq_pending())
            cpu_wfi(); /* wakes on any pending interrupt, even while masked */
        cpu_irq_enable();
    }
}
