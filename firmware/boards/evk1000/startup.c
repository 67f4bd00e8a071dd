/* Reset handler, vector table and default handlers of the STM32F105RC (connectivity line,
 * RM0008 10.1.2 table 62: 16 Cortex-M3 system vectors + 68 peripheral vectors).
 * No vendor startup code: .data is copied from flash, .bss zeroed, then clocks, then main().
 */
#include <stdint.h>

#include "evk1000.h"
#include "stm32f105.h"

/* Symbols of the linker script (evk1000_sections.ld). */
extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;

int main(void);
void Reset_Handler(void);
void Default_Handler(void);

/* The handlers this port implements; every other vector is Default_Handler. */
void NMI_Handler(void) __attribute__((weak, alias("Default_Handler")));
void HardFault_Handler(void) __attribute__((weak, alias("Default_Handler")));
void MemManage_Handler(void) __attribute__((weak, alias("Default_Handler")));
void BusFault_Handler(void) __attribute__((weak, alias("Default_Handler")));
void UsageFault_Handler(void) __attribute__((weak, alias("Default_Handler")));
void SVC_Handler(void) __attribute__((weak, alias("Default_Handler")));
void DebugMon_Handler(void) __attribute__((weak, alias("Default_Handler")));
void PendSV_Handler(void) __attribute__((weak, alias("Default_Handler")));
void SysTick_Handler(void) __attribute__((weak, alias("Default_Handler")));
void EXTI9_5_IRQHandler(void) __attribute__((weak, alias("Default_Handler")));
void USART1_IRQHandler(void) __attribute__((weak, alias("Default_Handler")));
void OTG_FS_IRQHandler(void) __attribute__((weak, alias("Default_Handler")));

typedef void (*evk_vector)(void);

#define EVK_VECTORS (16u + IRQN_COUNT)

/* The range designator fills every peripheral vector, then three are overridden. */
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Woverride-init"
__attribute__((section(".isr_vector"), used))
const evk_vector evk_vector_table[EVK_VECTORS] = {
    [0] = (evk_vector)(uintptr_t)&_estack, /* initial main stack pointer */
    [1] = Reset_Handler,
    [2] = NMI_Handler,
    [3] = HardFault_Handler,
    [4] = MemManage_Handler,
    [5] = BusFault_Handler,
    [6] = UsageFault_Handler,
    [7] = Default_Handler, [8] = Default_Handler, [9] = Default_Handler, [10] = Default_Handler,
    [11] = SVC_Handler,
    [12] = DebugMon_Handler,
    [13] = Default_Handler,
    [14] = PendSV_Handler,
    [15] = SysTick_Handler,
    [16 ... (EVK_VECTORS - 1)] = Default_Handler,
    [16 + IRQN_EXTI9_5] = EXTI9_5_IRQHandler,
    [16 + IRQN_USART1] = USART1_IRQHandler,
    [16 + IRQN_OTG_FS] = OTG_FS_IRQHandler,
};
#pragma GCC diagnostic pop

/* Survives a SYSRESETREQ (not a power cycle): .noinit is neither copied nor zeroed. */
#define EVK_FAULT_MAGIC 0xFA017EC7u
__attribute__((section(".noinit"))) static volatile uint32_t fault_magic;
__attribute__((section(".noinit"))) static volatile uint32_t fault_vector;
static uint32_t last_fault;

uint32_t evk_last_fault(void) { return last_fault; }

/* Kept as plain word loops (GCC would otherwise turn them into memcpy/memset calls). */
__attribute__((optimize("no-tree-loop-distribute-patterns")))
void Reset_Handler(void)
{
    const uint32_t *src = &_sidata;
    for (uint32_t *dst = &_sdata; dst < &_edata;)
        *dst++ = *src++;
    for (uint32_t *dst = &_sbss; dst < &_ebss;)
        *dst++ = 0u;

    last_fault = (fault_magic == EVK_FAULT_MAGIC) ? fault_vector : 0u;
    fault_magic = 0u;

    SCB_VTOR = (uint32_t)(uintptr_t)evk_vector_table;
    evk_clock_init();
    (void)main();
    /* main() does not return; if it does, start again rather than hang. */
    SCB_AIRCR = SCB_AIRCR_VECTKEY | SCB_AIRCR_SYSRESETREQ;
    for (;;)
        cpu_nop();
}

/* Any unexpected exception or interrupt: remember which, then reset the MCU. A hang would
 * leave the host with a dead station; a reset gives it a station that answers again. */
void Default_Handler(void)
{
    uint32_t ipsr;
    __asm__ volatile("mrs %0, ipsr" : "=r"(ipsr));
    fault_vector = ipsr & 0x1FFu;
    fault_magic = EVK_FAULT_MAGIC;
    cpu_dsb();
    SCB_AIRCR = SCB_AIRCR_VECTKEY | SCB_AIRCR_SYSRESETREQ;
    cpu_dsb();
    for (;;)
        cpu_nop();
}
