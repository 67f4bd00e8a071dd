/* STM32F1 embedded flash driver for the calibration-table region (board.h board_flash_*).
 * Sequences from PM0075 (STM32F10xxx flash programming manual) 2.3 and RM0008 3.3.3:
 *  - unlock: FLASH_KEYR <- 0x45670123, then 0xCDEF89AB;
 *  - page erase: CR.PER, AR <- page address, CR.STRT, wait SR.BSY, check SR.EOP, PGERR,
 *    WRPRTERR; clear PER;
 *  - program: CR.PG, one 16-bit write per half-word, wait BSY after each, check flags;
 *  - verify every byte by reading it back; lock with CR.LOCK.
 * The region is the last BOARD_TABLE_PAGES 2 KB pages of the flash (0x0803F000..0x0803FFFF
 * on the 256 KB STM32F105RC); the linker script keeps the image out of it. Anything outside
 * the region, or misaligned, is rejected with BOARD_EARG before the flash is touched.
 *
 * While an erase (20..40 ms) or a program runs, any code fetch from flash stalls, interrupt
 * handlers included (the vector table and handlers are in flash): USART bytes arriving
 * meanwhile can overrun. The host does not send while it waits for a table response.
 * HSI must be on for flash programming: clock.c never turns it off.
 */
#include <stddef.h>
#include <stdint.h>

#include "board.h"
#include "evk1000.h"
#include "stm32f105.h"

#define FLASH_SIZE_BYTES (EVK_FLASH_SIZE_KB * 1024u)
#define TABLE_BYTES (BOARD_TABLE_PAGES * EVK_FLASH_PAGE_SIZE)
#define TABLE_BASE (FLASH_MEM_BASE + FLASH_SIZE_BYTES - TABLE_BYTES)

_Static_assert(EVK_FLASH_PAGE_SIZE == 2048u, "connectivity line: 2 KB pages");
_Static_assert(TABLE_BASE % EVK_FLASH_PAGE_SIZE == 0u, "table region is page aligned");

/* Datasheet DS6014: page erase <= 40 ms, half-word program <= 70 us. While BSY the flash
 * stalls instruction fetch, so the poll loop barely runs; the bounds are a backstop. */
#define ERASE_TIMEOUT_US 100000u
#define PROGRAM_TIMEOUT_US 1000u
#define BSY_MAX_LOOPS 4000000u

uint32_t board_flash_page_size(void) { return EVK_FLASH_PAGE_SIZE; }
uint32_t board_flash_table_base(void) { return TABLE_BASE; }

static int in_region(uint32_t addr, size_t len)
{
    if (addr < TABLE_BASE || addr > TABLE_BASE + TABLE_BYTES)
        return 0;
    return len <= (size_t)(TABLE_BASE + TABLE_BYTES - addr);
}

static void flash_unlock(void)
{
    if (FLASH_CR & FLASH_CR_LOCK) {
        FLASH_KEYR = FLASH_KEY1;
        FLASH_KEYR = FLASH_KEY2;
    }
}

static void flash_lock(void) { FLASH_CR |= FLASH_CR_LOCK; }

/* Wait for BSY to clear, then map the status flags to a BOARD_E* code; clears them. */
static int flash_wait(uint32_t timeout_us)
{
    uint64_t deadline = board_time_us() + timeout_us;
    uint32_t loops = 0;
    while (FLASH_SR & FLASH_SR_BSY) {
        if (++loops > BSY_MAX_LOOPS || board_time_us() >= deadline)
            return BOARD_ETIMEOUT;
    }
    uint32_t sr = FLASH_SR;
    FLASH_SR = FLASH_SR_EOP | FLASH_SR_PGERR | FLASH_SR_WRPRTERR; /* write 1 to clear */
    if (sr & (FLASH_SR_PGERR | FLASH_SR_WRPRTERR))
        return BOARD_EFLASH;
    if (!(sr & FLASH_SR_EOP))
        return BOARD_EFLASH; /* the operation did not report its end */
    return BOARD_EOK;
}

int board_flash_erase_page(uint32_t addr)
{
    if (addr % EVK_FLASH_PAGE_SIZE != 0u || !in_region(addr, EVK_FLASH_PAGE_SIZE))
        return BOARD_EARG;
    flash_unlock();
    if (FLASH_CR & FLASH_CR_LOCK)
        return BOARD_EFLASH; /* wrong key sequence locks the flash until the next reset */
    int rc = flash_wait(PROGRAM_TIMEOUT_US); /* a previous operation still running? */
    if (rc == BOARD_ETIMEOUT) {
        flash_lock();
        return rc;
    }
    FLASH_CR |= FLASH_CR_PER;
    FLASH_AR = addr;
    FLASH_CR |= FLASH_CR_STRT;
    rc = flash_wait(ERASE_TIMEOUT_US);
    FLASH_CR &= ~FLASH_CR_PER;
    flash_lock();
    if (rc != BOARD_EOK)
        return rc;
    const volatile uint32_t *p = (const volatile uint32_t *)(uintptr_t)addr;
    for (uint32_t i = 0; i < EVK_FLASH_PAGE_SIZE / 4u; i++) {
        if (p[i] != 0xFFFFFFFFu)
            return BOARD_EFLASH;
    }
    return BOARD_EOK;
}

int board_flash_program(uint32_t addr, const uint8_t *data, size_t len)
{
    if ((addr & 1u) != 0u || (len & 1u) != 0u || (len > 0u && data == NULL)
        || !in_region(addr, len))
        return BOARD_EARG;
    if (len == 0u)
        return BOARD_EOK;
    /* Each half-word at most once between erases (board.h): refuse before writing. */
    for (size_t i = 0; i < len; i += 2u) {
        if (*(const volatile uint16_t *)(uintptr_t)(addr + i) != 0xFFFFu)
            return BOARD_EFLASH;
    }
    flash_unlock();
    if (FLASH_CR & FLASH_CR_LOCK)
        return BOARD_EFLASH;
    int rc = BOARD_EOK;
    FLASH_CR |= FLASH_CR_PG;
    for (size_t i = 0; i < len && rc == BOARD_EOK; i += 2u) {
        uint16_t hw = (uint16_t)(data[i] | ((uint16_t)data[i + 1u] << 8)); /* little endian */
        *(volatile uint16_t *)(uintptr_t)(addr + i) = hw;
        rc = flash_wait(PROGRAM_TIMEOUT_US);
    }
    FLASH_CR &= ~FLASH_CR_PG;
    flash_lock();
    if (rc != BOARD_EOK)
        return rc;
    for (size_t i = 0; i < len; i++) {
        if (*(const volatile uint8_t *)(uintptr_t)(addr + i) != data[i])
            return BOARD_EFLASH;
    }
    return BOARD_EOK;
}

int board_flash_read(uint32_t addr, uint8_t *data, size_t len)
{
    if ((len > 0u && data == NULL) || !in_region(addr, len))
        return BOARD_EARG;
    for (size_t i = 0; i < len; i++)
        data[i] = *(const volatile uint8_t *)(uintptr_t)(addr + i);
    return BOARD_EOK;
}
