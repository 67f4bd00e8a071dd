/* Clocks (RM0008 8.2 "Connectivity line devices: clocks") and time (SysTick, PM0056 4.4).
 *
 *   HSE 12 MHz -> PREDIV2 /3 = 4 MHz -> PLL2MUL x10 = PLL2CLK 40 MHz
 *   PLL2CLK -> PREDIV1 /5 = 8 MHz (PREDIV1SRC = PLL2) -> PLLMUL x9 = PLLCLK 72 MHz = SYSCLK
 *   AHB /1 = 72 MHz, APB1 /2 = 36 MHz (max 36), APB2 /1 = 72 MHz, ADC /6 = 12 MHz,
 *   USB OTG FS = PLLVCO (2 x PLLCLK = 144 MHz) / 3 = 48 MHz (OTGFSPRE = 0).
 * Limits checked (RM0008 8.2, datasheet DS6014): PLL2 input 3..5 MHz (4), PLL2 output
 * 40..74 MHz (40), PLL input 3..12 MHz (8), PLL output 18..72 MHz (72). Flash: 2 wait
 * states above 48 MHz (RM0008 3.3.3), prefetch on.
 *
 * Every ready-wait is a bounded loop. If HSE, PLL2, PLL or the switch does not become
 * ready, the board runs on HSI (8 MHz) and remembers why: evk_clock_source() and
 * evk_clock_fault() report it (and GET_INFO-level code can expose it); nothing is hidden.
 * HSI stays on in every case: the flash interface needs it to program and erase (RM0008
 * 3.3.3 / PM0075 2.3).
 */
#include <stdint.h>

#include "board.h"
#include "evk1000.h"
#include "stm32f105.h"

void SysTick_Handler(void);

/* Upper bounds of the ready-wait loops. At 8 MHz HSI a loop pass is >= 4 cycles, so
 * 400000 passes last >= 200 ms: far beyond the HSE start-up time (datasheet: 2 ms typ.)
 * and the PLL lock time (~200 us), and still short enough for a board without crystal. */
#define READY_LOOPS 400000u

static enum evk_clock_source clock_source = EVK_CLOCK_HSI;
static enum evk_clock_fault clock_fault = EVK_CLOCK_OK;
static uint32_t sysclk_hz = 8000000u;
static uint32_t pclk2_hz = 8000000u;
static uint32_t cycles_per_us = 8u;
static uint32_t systick_reload = 8000u - 1u;
static volatile uint64_t ms_count;

static int wait_set(volatile uint32_t *reg, uint32_t mask, uint32_t value)
{
    for (uint32_t i = 0; i < READY_LOOPS; i++) {
        if ((*reg & mask) == value)
            return 0;
    }
    return -1;
}

static void fall_back_to_hsi(enum evk_clock_fault why)
{
    RCC_CR |= RCC_CR_HSION;
    (void)wait_set(&RCC_CR, RCC_CR_HSIRDY, RCC_CR_HSIRDY);
    RCC_CFGR = (RCC_CFGR & ~RCC_CFGR_SW_MASK) | RCC_CFGR_SW_HSI;
    (void)wait_set(&RCC_CFGR, RCC_CFGR_SWS_MASK, RCC_CFGR_SWS_HSI);
    RCC_CR &= ~(RCC_CR_PLLON | RCC_CR_PLL2ON | RCC_CR_HSEON);
    RCC_CFGR = RCC_CFGR_SW_HSI; /* every prescaler /1: all buses at 8 MHz */
    FLASH_ACR = FLASH_ACR_PRFTBE; /* 0 wait states up to 24 MHz */
    clock_source = EVK_CLOCK_HSI;
    clock_fault = why;
    sysclk_hz = 8000000u;
    pclk2_hz = 8000000u;
}

static void clock_tree_init(void)
{
    RCC_CR |= RCC_CR_HSION;
    (void)wait_set(&RCC_CR, RCC_CR_HSIRDY, RCC_CR_HSIRDY);
    RCC_CFGR = RCC_CFGR_SW_HSI;
    (void)wait_set(&RCC_CFGR, RCC_CFGR_SWS_MASK, RCC_CFGR_SWS_HSI);
    RCC_CR &= ~(RCC_CR_PLLON | RCC_CR_PLL2ON);
    RCC_CIR = 0x00FF0000u; /* clear ready flags, no clock interrupts */

    RCC_CR = (RCC_CR & ~RCC_CR_HSEBYP) | RCC_CR_HSEON;
    if (wait_set(&RCC_CR, RCC_CR_HSERDY, RCC_CR_HSERDY) != 0) {
        fall_back_to_hsi(EVK_CLOCK_HSE_TIMEOUT);
        return;
    }
    /* Wait states before the clock goes up (RM0008 3.3.3). */
    FLASH_ACR = (FLASH_ACR & ~FLASH_ACR_LATENCY_MASK) | FLASH_ACR_LATENCY_2 | FLASH_ACR_PRFTBE;

    /* CFGR2 may only change while PLL2 and PLL are off (RM0008 8.3.12). */
    RCC_CFGR2 = (4u << RCC_CFGR2_PREDIV1_SHIFT)      /* PREDIV1 /5 */
              | (2u << RCC_CFGR2_PREDIV2_SHIFT)      /* PREDIV2 /3 */
              | (8u << RCC_CFGR2_PLL2MUL_SHIFT)      /* PLL2 x10 */
              | RCC_CFGR2_PREDIV1SRC_PLL2;
    RCC_CR |= RCC_CR_PLL2ON;
    if (wait_set(&RCC_CR, RCC_CR_PLL2RDY, RCC_CR_PLL2RDY) != 0) {
        fall_back_to_hsi(EVK_CLOCK_PLL2_TIMEOUT);
        return;
    }

    RCC_CFGR = RCC_CFGR_SW_HSI | RCC_CFGR_HPRE_DIV1 | RCC_CFGR_PPRE1_DIV2 | RCC_CFGR_PPRE2_DIV1
             | RCC_CFGR_ADCPRE_DIV6 | RCC_CFGR_PLLSRC_PREDIV1
             | (7u << RCC_CFGR_PLLMUL_SHIFT); /* 0111: x9; OTGFSPRE = 0: USB = VCO/3 */
    RCC_CR |= RCC_CR_PLLON;
    if (wait_set(&RCC_CR, RCC_CR_PLLRDY, RCC_CR_PLLRDY) != 0) {
        fall_back_to_hsi(EVK_CLOCK_PLL_TIMEOUT);
        return;
    }
    RCC_CFGR = (RCC_CFGR & ~RCC_CFGR_SW_MASK) | RCC_CFGR_SW_PLL;
    if (wait_set(&RCC_CFGR, RCC_CFGR_SWS_MASK, RCC_CFGR_SWS_PLL) != 0) {
        fall_back_to_hsi(EVK_CLOCK_SWITCH_TIMEOUT);
        return;
    }
    clock_source = EVK_CLOCK_PLL_HSE;
    clock_fault = EVK_CLOCK_OK;
    sysclk_hz = 72000000u;
    pclk2_hz = 72000000u;
}

void evk_clock_init(void)
{
    clock_tree_init();
    cycles_per_us = sysclk_hz / 1000000u;
    systick_reload = sysclk_hz / 1000u - 1u;
    SYST_CSR = 0u;
    SYST_RVR = systick_reload;
    SYST_CVR = 0u;
    SYST_CSR = SYST_CSR_CLKSOURCE | SYST_CSR_TICKINT | SYST_CSR_ENABLE;
}

enum evk_clock_source evk_clock_source(void) { return clock_source; }
enum evk_clock_fault evk_clock_fault(void) { return clock_fault; }
uint32_t evk_sysclk_hz(void) { return sysclk_hz; }
uint32_t evk_pclk2_hz(void) { return pclk2_hz; }

void SysTick_Handler(void) { ms_count++; }

uint64_t board_time_us(void)
{
    /* Milliseconds from the SysTick interrupt, microseconds from the SysTick counter.
     * If the counter wrapped before we read it but the interrupt has not run yet (we are
     * inside a higher-priority handler or interrupts are masked), PENDSTSET is set and the
     * counter is high: count that millisecond. */
    for (unsigned tries = 0;; tries++) {
        uint64_t ms = ms_count;
        uint32_t val = SYST_CVR;
        uint32_t pending = SCB_ICSR & SCB_ICSR_PENDSTSET;
        if (ms != ms_count && tries < 4u)
            continue; /* the interrupt ran in between: read again (bounded) */
        if (pending && val > systick_reload / 2u)
            ms++;
        uint32_t us = (systick_reload - val) / cycles_per_us;
        if (us > 999u)
            us = 999u;
        return ms * 1000u + us;
    }
}

void evk_delay_us(uint32_t us)
{
    uint64_t deadline = board_time_us() + us;
    /* Backstop if SysTick ever stopped: a pass costs well over 10 cycles. */
    uint64_t max_loops = (uint64_t)us * (cycles_per_us / 8u + 1u) + 100u;
    for (uint64_t i = 0; i < max_loops && board_time_us() < deadline; i++) {
    }
}
