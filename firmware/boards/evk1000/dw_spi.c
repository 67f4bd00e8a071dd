/* The DW1000 as wired on the EVK1000: SPI1 (PA4 software CS, PA5 SCK, PA6 MISO, PA7 MOSI),
 * IRQ on PB5 (EXTI5, rising edge, EXTI9_5 interrupt), RSTn on PA0 (open drain).
 * Filled into the struct dw_ops the driver in dw1000/ uses; nothing else touches the chip.
 * SPI mode 0 (CPOL 0, CPHA 0), MSB first, 8-bit frames (DW1000 user manual 2.3.1).
 */
#include <stddef.h>
#include <stdint.h>

#include "board.h"
#include "dw1000_ops.h"
#include "evk1000.h"
#include "stm32f105.h"

void EXTI9_5_IRQHandler(void);

#define PIN_RSTN 0u  /* PA0 */
#define PIN_CS 4u    /* PA4 */
#define PIN_IRQ 5u   /* PB5 */

#define SPI_SLOW_MAX_HZ 3000000u   /* before the DW1000 is initialised (its PLL not locked) */
#define SPI_FAST_MAX_HZ 18000000u  /* DW1000 limit is 20 MHz; 72 MHz / 4 = 18 MHz */
/* One SPI byte at the slowest clock used (2 MHz on HSI) takes 4 us = 32 cycles at 8 MHz,
 * 288 at 72 MHz; a poll pass is >= 4 cycles. 20000 passes is generous and still bounded. */
#define SPI_WAIT_LOOPS 20000u
#define RSTN_LOW_US 100u           /* DW1000 datasheet: >= 10 ns */
#define RSTN_RISE_TIMEOUT_US 10000u /* the chip holds RSTn low until its crystal runs (~ms) */

static volatile uint32_t irq_latched;
static uint32_t spi_cr1_base;
static uint32_t spi_br_slow;
static uint32_t spi_br_fast;

static void gpio_config(uint32_t port, uint32_t pin, uint32_t nibble)
{
    if (pin < 8u) {
        uint32_t shift = pin * 4u;
        GPIO_CRL(port) = (GPIO_CRL(port) & ~(0xFu << shift)) | (nibble << shift);
    } else {
        uint32_t shift = (pin - 8u) * 4u;
        GPIO_CRH(port) = (GPIO_CRH(port) & ~(0xFu << shift)) | (nibble << shift);
    }
}

/* Smallest SPI prescaler 2^(BR+1) giving at most max_hz from PCLK2. */
static uint32_t spi_br_for(uint32_t max_hz)
{
    uint32_t pclk = evk_pclk2_hz();
    for (uint32_t br = 0; br < 7u; br++) {
        if ((pclk >> (br + 1u)) <= max_hz)
            return br;
    }
    return 7u;
}

static void cs_low(void) { GPIO_BRR(GPIOA_BASE) = 1u << PIN_CS; }
static void cs_high(void) { GPIO_BSRR(GPIOA_BASE) = 1u << PIN_CS; }

static int spi_wait(uint32_t mask, uint32_t value)
{
    for (uint32_t i = 0; i < SPI_WAIT_LOOPS; i++) {
        if ((SPI_SR(SPI1_BASE) & mask) == value)
            return 0;
    }
    return -1;
}

static int spi_byte(uint8_t out, uint8_t *in)
{
    if (spi_wait(SPI_SR_TXE, SPI_SR_TXE) != 0)
        return -1;
    SPI_DR(SPI1_BASE) = out;
    if (spi_wait(SPI_SR_RXNE, SPI_SR_RXNE) != 0)
        return -1;
    uint8_t b = (uint8_t)SPI_DR(SPI1_BASE);
    if (in)
        *in = b;
    return 0;
}

static int evk_spi_transfer(void *ctx, const uint8_t *hdr, size_t hdr_len, const uint8_t *tx,
                            uint8_t *rx, size_t len)
{
    (void)ctx;
    if (hdr == NULL || hdr_len < 1u || hdr_len > 3u || (tx != NULL && rx != NULL)
        || (len > 0u && tx == NULL && rx == NULL))
        return -2;
    /* Drop a stale received byte and an overrun flag (read DR, then SR: RM0008 25.3.10). */
    (void)SPI_DR(SPI1_BASE);
    (void)SPI_SR(SPI1_BASE);

    int rc = 0;
    cs_low();
    for (size_t i = 0; i < hdr_len && rc == 0; i++)
        rc = spi_byte(hdr[i], NULL);
    for (size_t i = 0; i < len && rc == 0; i++)
        rc = tx ? spi_byte(tx[i], NULL) : spi_byte(0u, &rx[i]);
    if (spi_wait(SPI_SR_BSY, 0u) != 0)
        rc = -1;
    cs_high();
    return rc;
}

static void evk_spi_speed(void *ctx, int fast)
{
    (void)ctx;
    (void)spi_wait(SPI_SR_BSY, 0u);
    /* BR must not change while the SPI is enabled and busy (RM0008 25.5.1). */
    SPI_CR1(SPI1_BASE) = spi_cr1_base;
    SPI_CR1(SPI1_BASE) = spi_cr1_base | ((fast ? spi_br_fast : spi_br_slow) << SPI_CR1_BR_SHIFT)
                       | SPI_CR1_SPE;
}

static int irq_line_high(void) { return (GPIO_IDR(GPIOB_BASE) >> PIN_IRQ) & 1u; }

bool evk_dw_irq_pending(void) { return irq_latched != 0u || irq_line_high(); }

void EXTI9_5_IRQHandler(void)
{
    uint32_t pr = EXTI_PR & (0x1Fu << 5); /* lines 5..9 share this vector */
    if (pr & (1u << PIN_IRQ))
        irq_latched = 1u;
    EXTI_PR = pr; /* write 1 to clear */
}

static int evk_wait_irq(void *ctx, uint64_t deadline_us)
{
    (void)ctx;
    uint64_t now = board_time_us();
    /* Backstop in case time stopped: a pass lasts >= 0.5 us (busy) or ~1 ms (WFI). */
    uint64_t remaining = deadline_us > now ? deadline_us - now : 0u;
    uint64_t max_passes = remaining < (UINT64_MAX / 4u) ? remaining * 2u + 1000u : UINT64_MAX;
    for (uint64_t pass = 0; pass < max_passes; pass++) {
        if (evk_dw_irq_pending()) {
            irq_latched = 0u;
            return 1;
        }
        now = board_time_us();
        if (now >= deadline_us)
            return 0;
        if (deadline_us - now > 1500u) {
            /* Sleep until the next interrupt (SysTick wakes us every 1 ms at the latest).
             * Interrupts masked around the check, so an edge between check and WFI still
             * wakes the core (PM0056 2.5.2: WFI wakes on a pending interrupt). */
            cpu_irq_disable();
            if (!evk_dw_irq_pending())
                cpu_wfi();
            cpu_irq_enable();
        }
        /* Closer than 1.5 ms to the deadline: poll, so the deadline is met to ~1 us. */
    }
    return -1; /* time did not advance: report it rather than wait forever */
}

static int evk_dw_reset(void *ctx)
{
    (void)ctx;
    /* Drive RSTn low (open drain), then release it: input floating, never driven high
     * (DW1000 datasheet: RSTn must not be driven high by the host). */
    GPIO_BRR(GPIOA_BASE) = 1u << PIN_RSTN;
    gpio_config(GPIOA_BASE, PIN_RSTN, GPIO_OUT_OD_50);
    evk_delay_us(RSTN_LOW_US);
    gpio_config(GPIOA_BASE, PIN_RSTN, GPIO_IN_FLOAT);
    uint64_t deadline = board_time_us() + RSTN_RISE_TIMEOUT_US;
    for (uint32_t i = 0; i < 1000000u; i++) {
        if ((GPIO_IDR(GPIOA_BASE) >> PIN_RSTN) & 1u) {
            evk_delay_us(10u);
            return 0;
        }
        if (board_time_us() >= deadline)
            break;
    }
    return -1;
}

static void evk_dw_delay_us(void *ctx, uint32_t us)
{
    (void)ctx;
    evk_delay_us(us);
}

static const struct dw_ops evk_dw_ops = {
    .ctx = NULL,
    .spi_transfer = evk_spi_transfer,
    .wait_irq = evk_wait_irq,
    .reset = evk_dw_reset,
    .delay_us = evk_dw_delay_us,
    .spi_speed = evk_spi_speed,
};

const struct dw_ops *board_dw_ops(void) { return &evk_dw_ops; }

void evk_dw_init(void)
{
    RCC_APB2ENR |= RCC_APB2ENR_AFIOEN | RCC_APB2ENR_IOPAEN | RCC_APB2ENR_IOPBEN
                 | RCC_APB2ENR_SPI1EN;
    (void)RCC_APB2ENR; /* read back: the clock is on before the first register access */

    cs_high();
    gpio_config(GPIOA_BASE, PIN_CS, GPIO_OUT_PP_50);
    gpio_config(GPIOA_BASE, 5u, GPIO_AF_PP_50);  /* SCK */
    gpio_config(GPIOA_BASE, 6u, GPIO_IN_FLOAT);  /* MISO */
    gpio_config(GPIOA_BASE, 7u, GPIO_AF_PP_50);  /* MOSI */
    gpio_config(GPIOA_BASE, PIN_RSTN, GPIO_IN_FLOAT); /* released; the chip pulls it */

    spi_br_slow = spi_br_for(SPI_SLOW_MAX_HZ);
    spi_br_fast = spi_br_for(SPI_FAST_MAX_HZ);
    spi_cr1_base = SPI_CR1_MSTR | SPI_CR1_SSM | SPI_CR1_SSI; /* mode 0, MSB first, 8 bit */
    SPI_CR2(SPI1_BASE) = 0u;
    evk_spi_speed(NULL, 0);

    /* PB5: input with pull-down (the DW1000 IRQ output is active high). */
    GPIO_BRR(GPIOB_BASE) = 1u << PIN_IRQ;
    gpio_config(GPIOB_BASE, PIN_IRQ, GPIO_IN_PULL);
    AFIO_EXTICR2 = (AFIO_EXTICR2 & ~(0xFu << 4)) | (1u << 4); /* EXTI5 <- port B */
    EXTI_RTSR |= 1u << PIN_IRQ;
    EXTI_FTSR &= ~(1u << PIN_IRQ);
    EXTI_PR = 1u << PIN_IRQ;
    EXTI_IMR |= 1u << PIN_IRQ;
    nvic_enable(IRQN_EXTI9_5, 2u);
}
