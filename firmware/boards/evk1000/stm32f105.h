/* The STM32F105RC registers this board port uses, written from ST RM0008 (reference manual
 * of the STM32F101/102/103/105/107) and PM0056 (Cortex-M3 programming manual). Only what
 * is used; each block names its RM0008 / PM0056 section. No vendor headers are used.
 */
#ifndef EVK1000_STM32F105_H
#define EVK1000_STM32F105_H

#include <stdint.h>

#define REG32(addr) (*(volatile uint32_t *)(uintptr_t)(addr))

/* ---- memory map (RM0008 3.3 "Memory map") ------------------------------------------ */
#define FLASH_MEM_BASE 0x08000000u
#define SRAM_BASE 0x20000000u
#define UID_BASE 0x1FFFF7E8u   /* RM0008 30.2 "Unique device ID register (96 bits)" */
#define FSIZE_BASE 0x1FFFF7E0u /* RM0008 30.1 "Memory size register" (flash KB) */

/* ---- RCC (RM0008 8.3 "Connectivity line devices: RCC registers") --------------------- */
#define RCC_BASE 0x40021000u
#define RCC_CR REG32(RCC_BASE + 0x00u)       /* 8.3.1 clock control */
#define RCC_CFGR REG32(RCC_BASE + 0x04u)     /* 8.3.2 clock configuration */
#define RCC_CIR REG32(RCC_BASE + 0x08u)      /* 8.3.3 clock interrupt */
#define RCC_AHBENR REG32(RCC_BASE + 0x14u)   /* 8.3.6 AHB peripheral clock enable */
#define RCC_APB2ENR REG32(RCC_BASE + 0x18u)  /* 8.3.7 APB2 peripheral clock enable */
#define RCC_APB1ENR REG32(RCC_BASE + 0x1Cu)  /* 8.3.8 APB1 peripheral clock enable */
#define RCC_CSR REG32(RCC_BASE + 0x24u)      /* 8.3.10 control/status (reset flags) */
#define RCC_CFGR2 REG32(RCC_BASE + 0x2Cu)    /* 8.3.12 clock configuration 2 */

#define RCC_CR_HSION (1u << 0)
#define RCC_CR_HSIRDY (1u << 1)
#define RCC_CR_HSEON (1u << 16)
#define RCC_CR_HSERDY (1u << 17)
#define RCC_CR_HSEBYP (1u << 18)
#define RCC_CR_CSSON (1u << 19)
#define RCC_CR_PLLON (1u << 24)
#define RCC_CR_PLLRDY (1u << 25)
#define RCC_CR_PLL2ON (1u << 26)
#define RCC_CR_PLL2RDY (1u << 27)

#define RCC_CFGR_SW_MASK (3u << 0)
#define RCC_CFGR_SW_HSI (0u << 0)
#define RCC_CFGR_SW_PLL (2u << 0)
#define RCC_CFGR_SWS_MASK (3u << 2)
#define RCC_CFGR_SWS_HSI (0u << 2)
#define RCC_CFGR_SWS_PLL (2u << 2)
#define RCC_CFGR_HPRE_DIV1 (0u << 4)
#define RCC_CFGR_PPRE1_DIV2 (4u << 8)  /* APB1 = HCLK / 2 (APB1 max 36 MHz) */
#define RCC_CFGR_PPRE2_DIV1 (0u << 11) /* APB2 = HCLK */
#define RCC_CFGR_ADCPRE_DIV6 (2u << 14)
#define RCC_CFGR_PLLSRC_PREDIV1 (1u << 16)
#define RCC_CFGR_PLLMUL_SHIFT 18u      /* connectivity line: 0010=x4 ... 0111=x9, 1101=x6.5 */
#define RCC_CFGR_PLLMUL_MASK (0xFu << 18)
#define RCC_CFGR_OTGFSPRE (1u << 22)   /* 0: USB OTG FS clock = PLLVCO / 3 (= 2*PLLCLK/3) */

#define RCC_CFGR2_PREDIV1_SHIFT 0u     /* 0000=/1 ... 1111=/16 */
#define RCC_CFGR2_PREDIV2_SHIFT 4u     /* 0000=/1 ... 1111=/16 */
#define RCC_CFGR2_PLL2MUL_SHIFT 8u     /* 0110=x8 0111=x9 1000=x10 ... 1100=x14 1110=x16 1111=x20 */
#define RCC_CFGR2_PREDIV1SRC_PLL2 (1u << 16)

#define RCC_APB2ENR_AFIOEN (1u << 0)
#define RCC_APB2ENR_IOPAEN (1u << 2)
#define RCC_APB2ENR_IOPBEN (1u << 3)
#define RCC_APB2ENR_IOPCEN (1u << 4)
#define RCC_APB2ENR_SPI1EN (1u << 12)
#define RCC_APB2ENR_USART1EN (1u << 14)

/* ---- FLASH interface (RM0008 3.3.3 "Embedded Flash memory", PM0075 flash programming
 * manual, registers in PM0075 section 4) -------------------------------------------- */
#define FLASH_R_BASE 0x40022000u
#define FLASH_ACR REG32(FLASH_R_BASE + 0x00u)
#define FLASH_KEYR REG32(FLASH_R_BASE + 0x04u)
#define FLASH_SR REG32(FLASH_R_BASE + 0x0Cu)
#define FLASH_CR REG32(FLASH_R_BASE + 0x10u)
#define FLASH_AR REG32(FLASH_R_BASE + 0x14u)

#define FLASH_ACR_LATENCY_MASK (7u << 0)
#define FLASH_ACR_LATENCY_2 (2u << 0) /* 48 MHz < SYSCLK <= 72 MHz */
#define FLASH_ACR_PRFTBE (1u << 4)
#define FLASH_KEY1 0x45670123u
#define FLASH_KEY2 0xCDEF89ABu
#define FLASH_SR_BSY (1u << 0)
#define FLASH_SR_PGERR (1u << 2)
#define FLASH_SR_WRPRTERR (1u << 4)
#define FLASH_SR_EOP (1u << 5)
#define FLASH_CR_PG (1u << 0)
#define FLASH_CR_PER (1u << 1)
#define FLASH_CR_STRT (1u << 6)
#define FLASH_CR_LOCK (1u << 7)

/* ---- GPIO and AFIO (RM0008 9.2 "GPIO registers", 9.4 "AFIO registers") -------------- */
#define GPIOA_BASE 0x40010800u
#define GPIOB_BASE 0x40010C00u
#define GPIOC_BASE 0x40011000u
#define GPIO_CRL(base) REG32((base) + 0x00u)  /* 9.2.1 pins 0..7, 4 bits each */
#define GPIO_CRH(base) REG32((base) + 0x04u)  /* 9.2.2 pins 8..15 */
#define GPIO_IDR(base) REG32((base) + 0x08u)  /* 9.2.3 */
#define GPIO_ODR(base) REG32((base) + 0x0Cu)  /* 9.2.4 */
#define GPIO_BSRR(base) REG32((base) + 0x10u) /* 9.2.5 set: bit n, reset: bit n+16 */
#define GPIO_BRR(base) REG32((base) + 0x14u)  /* 9.2.6 */
/* Pin configuration nibble = CNF[1:0] MODE[1:0] (RM0008 table 20). */
#define GPIO_IN_ANALOG 0x0u
#define GPIO_IN_FLOAT 0x4u
#define GPIO_IN_PULL 0x8u       /* pull-up if ODR bit = 1, pull-down if 0 */
#define GPIO_OUT_PP_50 0x3u
#define GPIO_OUT_OD_50 0x7u
#define GPIO_AF_PP_50 0xBu

#define AFIO_BASE 0x40010000u
#define AFIO_EXTICR2 REG32(AFIO_BASE + 0x0Cu) /* 9.4.4 EXTI4..EXTI7 source port */

/* ---- EXTI (RM0008 10.3 "EXTI registers") -------------------------------------------- */
#define EXTI_BASE 0x40010400u
#define EXTI_IMR REG32(EXTI_BASE + 0x00u)
#define EXTI_EMR REG32(EXTI_BASE + 0x04u)
#define EXTI_RTSR REG32(EXTI_BASE + 0x08u)
#define EXTI_FTSR REG32(EXTI_BASE + 0x0Cu)
#define EXTI_PR REG32(EXTI_BASE + 0x14u)

/* ---- SPI1 (RM0008 25.5 "SPI and I2S registers") ------------------------------------- */
#define SPI1_BASE 0x40013000u
#define SPI_CR1(base) REG32((base) + 0x00u)
#define SPI_CR2(base) REG32((base) + 0x04u)
#define SPI_SR(base) REG32((base) + 0x08u)
#define SPI_DR(base) REG32((base) + 0x0Cu)
#define SPI_CR1_CPHA (1u << 0)
#define SPI_CR1_CPOL (1u << 1)
#define SPI_CR1_MSTR (1u << 2)
#define SPI_CR1_BR_SHIFT 3u      /* f_PCLK / 2^(BR+1) */
#define SPI_CR1_BR_MASK (7u << 3)
#define SPI_CR1_SPE (1u << 6)
#define SPI_CR1_SSI (1u << 8)
#define SPI_CR1_SSM (1u << 9)
#define SPI_SR_RXNE (1u << 0)
#define SPI_SR_TXE (1u << 1)
#define SPI_SR_MODF (1u << 5)
#define SPI_SR_OVR (1u << 6)
#define SPI_SR_BSY (1u << 7)

/* ---- USART1 (RM0008 27.6 "USART registers") ----------------------------------------- */
#define USART1_BASE 0x40013800u
#define USART_SR(base) REG32((base) + 0x00u)
#define USART_DR(base) REG32((base) + 0x04u)
#define USART_BRR(base) REG32((base) + 0x08u)
#define USART_CR1(base) REG32((base) + 0x0Cu)
#define USART_CR2(base) REG32((base) + 0x10u)
#define USART_CR3(base) REG32((base) + 0x14u)
#define USART_SR_ORE (1u << 3)
#define USART_SR_RXNE (1u << 5)
#define USART_SR_TC (1u << 6)
#define USART_SR_TXE (1u << 7)
#define USART_CR1_RE (1u << 2)
#define USART_CR1_TE (1u << 3)
#define USART_CR1_RXNEIE (1u << 5)
#define USART_CR1_UE (1u << 13)

/* ---- Cortex-M3 system control (PM0056 4.3 SCB, 4.4 SysTick, 4.2 NVIC) --------------- */
#define SCB_ICSR REG32(0xE000ED04u)
#define SCB_VTOR REG32(0xE000ED08u)
#define SCB_AIRCR REG32(0xE000ED0Cu)
#define SCB_SCR REG32(0xE000ED10u)
#define SCB_ICSR_PENDSTSET (1u << 26)
#define SCB_AIRCR_VECTKEY (0x05FAu << 16)
#define SCB_AIRCR_SYSRESETREQ (1u << 2)

#define SYST_CSR REG32(0xE000E010u)
#define SYST_RVR REG32(0xE000E014u)
#define SYST_CVR REG32(0xE000E018u)
#define SYST_CSR_ENABLE (1u << 0)
#define SYST_CSR_TICKINT (1u << 1)
#define SYST_CSR_CLKSOURCE (1u << 2) /* 1: processor clock */

#define NVIC_ISER(n) REG32(0xE000E100u + 4u * (n))
#define NVIC_ICER(n) REG32(0xE000E180u + 4u * (n))
#define NVIC_IPR_BYTE(irq) (*(volatile uint8_t *)(uintptr_t)(0xE000E400u + (irq)))

/* Connectivity-line interrupt numbers (RM0008 table 62 "Vector table for connectivity
 * line devices"). */
#define IRQN_EXTI9_5 23u
#define IRQN_USART1 37u
#define IRQN_OTG_FS 67u
#define IRQN_COUNT 68u

static inline void cpu_irq_disable(void) { __asm__ volatile("cpsid i" ::: "memory"); }
static inline void cpu_irq_enable(void) { __asm__ volatile("cpsie i" ::: "memory"); }
static inline void cpu_wfi(void) { __asm__ volatile("wfi" ::: "memory"); }
static inline void cpu_dsb(void) { __asm__ volatile("dsb" ::: "memory"); }
static inline void cpu_isb(void) { __asm__ volatile("isb" ::: "memory"); }
static inline void cpu_nop(void) { __asm__ volatile("nop"); }

static inline void nvic_enable(uint32_t irq, uint8_t prio)
{
    NVIC_IPR_BYTE(irq) = (uint8_t)(prio << 4); /* STM32F1 implements 4 priority bits */
    NVIC_ISER(irq >> 5) = 1u << (irq & 31u);
}

#endif
