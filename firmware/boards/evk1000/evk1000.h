/* Board-private interface of the EVK1000 port (STM32F105RC). Not used by core/ or dw1000/:
 * they see only board.h and the ops table. */
#ifndef EVK1000_EVK1000_H
#define EVK1000_EVK1000_H

#include <stdbool.h>
#include <stdint.h>

/* Flash geometry (RM0008 3.3.3: connectivity line, 2 KB pages); -DEVK_FLASH_SIZE_KB=N for a
 * part with less flash. */
#ifndef EVK_FLASH_SIZE_KB
#define EVK_FLASH_SIZE_KB 256u
#endif
#define EVK_FLASH_PAGE_SIZE 2048u

/* Host link speed (USART1, 8N1). */
#ifndef EVK_LINK_BAUD
#define EVK_LINK_BAUD 115200u
#endif

/* ---- clocks (clock.c) ---------------------------------------------------------------- */
enum evk_clock_source {
    EVK_CLOCK_PLL_HSE = 0, /* 12 MHz HSE -> PLL2 -> PREDIV1 -> PLL -> 72 MHz */
    EVK_CLOCK_HSI = 1,     /* fallback: 8 MHz internal RC, every bus at 8 MHz */
};
/* Why the HSE/PLL bring-up failed, if it did (0 = it did not). */
enum evk_clock_fault {
    EVK_CLOCK_OK = 0,
    EVK_CLOCK_HSE_TIMEOUT = 1,
    EVK_CLOCK_PLL2_TIMEOUT = 2,
    EVK_CLOCK_PLL_TIMEOUT = 3,
    EVK_CLOCK_SWITCH_TIMEOUT = 4,
};
void evk_clock_init(void);                       /* also starts SysTick at 1 kHz */
enum evk_clock_source evk_clock_source(void);
enum evk_clock_fault evk_clock_fault(void);
uint32_t evk_sysclk_hz(void);
uint32_t evk_pclk2_hz(void);                      /* SPI1 and USART1 clock */

/* ---- host link (usb/cdc_acm.c, or link_usart.c with `make firmware LINK=usart`) -------- */
void evk_link_init(void);
void evk_link_flush(void);                        /* let the last bytes leave (bounded) */
bool evk_link_rx_pending(void);                   /* bytes waiting in the RX ring */
uint32_t evk_link_rx_overruns(void);              /* bytes lost: ring full or USART ORE */

/* ---- DW1000 wiring (dw_spi.c) -------------------------------------------------------- */
void evk_dw_init(void);
bool evk_dw_irq_pending(void);                    /* IRQ line high or an edge latched */

/* ---- startup (startup.c) ------------------------------------------------------------- */
/* Vector number of the last unexpected exception (HardFault = 3, ...) that made the board
 * reset, or 0; kept in .noinit RAM across the reset. Readable with a debugger. */
uint32_t evk_last_fault(void);

/* Busy-wait on board_time_us(), bounded also by a loop count. */
void evk_delay_us(uint32_t us);

#endif
