/* The only way the DW1000 driver reaches the chip (after Bitcraze libdw1000's ops table).
 * A board fills one of these: boards/evk1000 with SPI1/PB5/PA0, boards/native with the
 * tunnel to the simulated medium, C unit tests with a fake.
 */
#ifndef UWBCAL_DW1000_OPS_H
#define UWBCAL_DW1000_OPS_H

#include <stddef.h>
#include <stdint.h>

/* One transaction of a batch (spi_batch): as the arguments of spi_transfer. */
struct dw_spi_xfer {
    const uint8_t *hdr;
    size_t hdr_len;
    const uint8_t *tx;
    uint8_t *rx;
    size_t len;
};

struct dw_ops {
    void *ctx;
    /* One chip-select-framed SPI transaction: clock out hdr (1 to 3 bytes, the DW1000
     * transaction header), then either clock out tx[0..len) (tx != NULL, a write) or clock
     * in rx[0..len) (rx != NULL, a read). Returns 0, or a negative value on failure. */
    int (*spi_transfer)(void *ctx, const uint8_t *hdr, size_t hdr_len,
                        const uint8_t *tx, uint8_t *rx, size_t len);
    /* Wait until the IRQ line is asserted or board_time_us() reaches deadline_us.
     * Returns 1 for IRQ, 0 for deadline, negative on failure. Never waits past deadline. */
    int (*wait_irq)(void *ctx, uint64_t deadline_us);
    /* Pulse RSTn and wait for the chip to come out of reset (bounded). 0 or negative. */
    int (*reset)(void *ctx);
    /* Busy or virtual delay. */
    void (*delay_us)(void *ctx, uint32_t us);
    /* SPI clock: slow (<= 3 MHz) before the chip is initialised, fast afterwards. */
    void (*spi_speed)(void *ctx, int fast);
    /* Optional, added by the measurement work (NULL: the driver makes n spi_transfer calls).
     * n transactions with exactly the effect of n spi_transfer calls in order; a board may
     * pipeline them (the native tunnel sends every request, then collects the replies, one
     * round trip instead of n). Returns 0, or negative if any transaction failed. */
    int (*spi_batch)(void *ctx, const struct dw_spi_xfer *x, size_t n);
};

#endif
