/* Host link backend: USART1 (PA9 TX, PA10 RX), EVK_LINK_BAUD 8N1, RX by interrupt into a
 * ring buffer, TX polled with bounded waits.
 *
 * For boards wired that way: the EVK1000's PC link is the USB OTG FS virtual COM port (PA11/PA12).
 * USART1 is not brought out on the EVK1000 and PA9 is wired as USB VBUS sense there (PA10
 * as USB ID). On a real EVK1000 this backend talks to nothing unless a USB-to-UART adapter
 * is wired to PA9/PA10 (and the VBUS sense connection is dealt with). The USB CDC backend
 * is usb/cdc_acm.c, the default (`make firmware`; this file: `make firmware LINK=usart`). The
 * emulated EVK1000 (host/uwbcal/evk1000) bridges USART1 to a pty.
 */
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "board.h"
#include "evk1000.h"
#include "stm32f105.h"

void USART1_IRQHandler(void);

#ifndef EVK_RX_RING_SIZE
#define EVK_RX_RING_SIZE 1024u /* power of two; > one maximum frame plus margin */
#endif
#define RX_RING_SIZE EVK_RX_RING_SIZE
_Static_assert((RX_RING_SIZE & (RX_RING_SIZE - 1u)) == 0u, "ring size: a power of two");
#define TX_BYTE_TIMEOUT_US 5000u /* one byte at 115200 takes 87 us */

static uint8_t rx_ring[RX_RING_SIZE];
static volatile uint32_t rx_head; /* written by the ISR */
static volatile uint32_t rx_tail; /* written by board_link_read */
static volatile uint32_t rx_lost;

void USART1_IRQHandler(void)
{
    uint32_t sr = USART_SR(USART1_BASE);
    if (sr & (USART_SR_RXNE | USART_SR_ORE)) {
        /* Reading DR after SR clears RXNE and ORE (RM0008 27.6.1). */
        uint8_t b = (uint8_t)USART_DR(USART1_BASE);
        if (sr & USART_SR_ORE)
            rx_lost++;
        uint32_t head = rx_head;
        if (head - rx_tail < RX_RING_SIZE) {
            rx_ring[head % RX_RING_SIZE] = b;
            rx_head = head + 1u;
        } else {
            rx_lost++;
        }
    }
}

/* Bytes that followed a RESET (in the same read, and still in the ring): kept across the
 * SYSRESETREQ in .noinit (neither copied nor zeroed at boot) and put back into the ring by
 * evk_link_init, so the restarted station answers them. A power cycle loses them (the magic
 * no longer matches): the host's retry covers that. */
#define KEEP_MAX 256u
#define KEEP_MAGIC 0x4B454550u /* "KEEP" */
__attribute__((section(".noinit"))) static volatile uint32_t keep_magic;
__attribute__((section(".noinit"))) static volatile uint32_t keep_len;
__attribute__((section(".noinit"))) static volatile uint8_t keep_buf[KEEP_MAX];

void board_link_keep(const uint8_t *buf, size_t len)
{
    uint32_t n = 0;
    for (size_t i = 0; i < len && n < KEEP_MAX; i++) keep_buf[n++] = buf[i];
    cpu_irq_disable();
    for (uint32_t t = rx_tail; t != rx_head && n < KEEP_MAX; t++) keep_buf[n++] = rx_ring[t % RX_RING_SIZE];
    keep_len = n;
    keep_magic = KEEP_MAGIC ^ n;
    cpu_irq_enable();
}

bool evk_link_rx_pending(void) { return rx_head != rx_tail; }
uint32_t evk_link_rx_overruns(void) { return rx_lost; }

size_t board_link_read(uint8_t *buf, size_t max)
{
    size_t n = 0;
    uint32_t tail = rx_tail;
    uint32_t head = rx_head;
    while (n < max && tail != head) {
        buf[n++] = rx_ring[tail % RX_RING_SIZE];
        tail++;
    }
    rx_tail = tail;
    return n;
}

bool board_link_write(const uint8_t *buf, size_t len)
{
    for (size_t i = 0; i < len; i++) {
        uint64_t deadline = board_time_us() + TX_BYTE_TIMEOUT_US;
        uint32_t loops = 0;
        while (!(USART_SR(USART1_BASE) & USART_SR_TXE)) {
            if (board_time_us() >= deadline || ++loops > 1000000u)
                return false;
        }
        USART_DR(USART1_BASE) = buf[i];
    }
    return true;
}

void evk_link_flush(void)
{
    /* Let the last byte leave the USART (bounded). */
    for (uint32_t i = 0; i < 200000u && !(USART_SR(USART1_BASE) & USART_SR_TC); i++) {
    }
}

void evk_link_init(void)
{
    RCC_APB2ENR |= RCC_APB2ENR_IOPAEN | RCC_APB2ENR_USART1EN | RCC_APB2ENR_AFIOEN;
    (void)RCC_APB2ENR;
    /* PA9 TX: alternate function push-pull; PA10 RX: input with pull-up (RM0008 9.1.11). */
    GPIO_CRH(GPIOA_BASE) = (GPIO_CRH(GPIOA_BASE) & ~(0xFFu << 4))
                         | (GPIO_AF_PP_50 << 4) | (GPIO_IN_PULL << 8);
    GPIO_BSRR(GPIOA_BASE) = 1u << 10;

    USART_CR1(USART1_BASE) = 0u;
    USART_CR2(USART1_BASE) = 0u; /* 1 stop bit */
    USART_CR3(USART1_BASE) = 0u; /* no flow control */
    /* BRR = f_PCLK2 / baud, rounded (RM0008 27.3.4: mantissa.fraction in 1/16). */
    USART_BRR(USART1_BASE) = (evk_pclk2_hz() + EVK_LINK_BAUD / 2u) / EVK_LINK_BAUD;
    uint32_t kept = keep_len;
    if (keep_magic == (KEEP_MAGIC ^ kept) && kept <= KEEP_MAX) { /* input that followed a RESET */
        for (uint32_t i = 0; i < kept; i++) rx_ring[i] = keep_buf[i];
        rx_tail = 0u;
        rx_head = kept;
    }
    keep_magic = 0u;
    USART_CR1(USART1_BASE) = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE;
    nvic_enable(IRQN_USART1, 1u);
}
