/* HOST-ONLY: the EVK1000's USB link (usb/otgfs.c, usb/cdc_acm.c) and the station core built
 * as a shared library for the host (build/usbhosted/libevkusb.so, `make usbhosted`), so the
 * real driver code runs against the Python OTG FS model (host/uwbcal/evk1000/otgfs.py)
 * without a CPU emulator. host/uwbcal/evk1000/usbhosted.py loads it with ctypes.
 *
 * Compiled with -DOTG_HOSTED: every OTG register access is a call to the model (the
 * callbacks below); a driver wait calls the wait callback, in which the harness lets the
 * USB host run and delivers the interrupt, as the NVIC would on the chip. Time is a virtual
 * microsecond counter the harness advances. Flash is the native board's simulated flash
 * (boards/native/flash.c, RAM only here). No radio: board_dw_ops() is NULL.
 *
 * What this cannot show: anything of the ARM image itself (startup, clocks, the NVIC, the
 * real interrupt timing and preemption points, the 72 MHz cycle budget); that needs the
 * emulated EVK1000 of issue 10.
 */
#include <setjmp.h>
#include <stdlib.h>
#include <stddef.h>
#include <stdint.h>

#include "app.h"
#include "board.h"
#include "cdc_acm.h"
#include "evk1000.h"
#include "otgfs.h"
#include "otgfs_regs.h"

typedef uint32_t (*hosted_read_fn)(uint32_t offset);
typedef void (*hosted_write_fn)(uint32_t offset, uint32_t value);
typedef void (*hosted_wait_fn)(void);

static hosted_read_fn rd_cb;
static hosted_write_fn wr_cb;
static hosted_wait_fn wait_cb;
static uint64_t now_us;
static uint8_t uid_bytes[12] = {0x55, 0x57, 0x42, 0x43, 0x48, 0x4F, 0x53, 0x54, 0, 0, 0, 1};
static jmp_buf reset_jmp;
static int in_step;

/* ---- the harness API (ctypes) ---- */
void hosted_set_callbacks(hosted_read_fn r, hosted_write_fn w, hosted_wait_fn wt);
void hosted_set_uid(const uint8_t uid[12]);
void hosted_set_time_us(uint64_t t);
void hosted_init(void);
int hosted_poll(void);
void hosted_irq(void);
uint32_t hosted_tx_failures(void);

void hosted_set_callbacks(hosted_read_fn r, hosted_write_fn w, hosted_wait_fn wt)
{
    rd_cb = r;
    wr_cb = w;
    wait_cb = wt;
}

void hosted_set_uid(const uint8_t uid[12])
{
    for (unsigned i = 0; i < 12u; i++)
        uid_bytes[i] = uid[i];
}

void hosted_set_time_us(uint64_t t) { now_us = t; }

/* Boot: the link (USB core init and connect) then the station core, as main.c does. */
void hosted_init(void)
{
    evk_link_init();
    app_init();
}

/* One pass of the main loop: 1 if it did work, 0 if idle, 2 if the station reset itself. */
int hosted_poll(void)
{
    if (setjmp(reset_jmp) != 0) {
        in_step = 0;
        return 2;
    }
    in_step = 1;
    int r = app_poll() ? 1 : 0;
    in_step = 0;
    return r;
}

void hosted_irq(void) { usbd_irq(); }
uint32_t hosted_tx_failures(void) { return app_stats()->tx_failures; }

/* ---- the register hooks of otgfs_regs.h ---- */
uint32_t otg_hosted_read(uint32_t offset) { return rd_cb ? rd_cb(offset) : 0u; }
void otg_hosted_write(uint32_t offset, uint32_t value)
{
    if (wr_cb)
        wr_cb(offset, value);
}
void otg_hosted_wait(void)
{
    if (wait_cb)
        wait_cb();
}

/* ---- board.h ---- */
const char *board_name(void) { return "evk1000/hosted"; }
void board_uid(uint8_t uid[12])
{
    for (unsigned i = 0; i < 12u; i++)
        uid[i] = uid_bytes[i];
}
uint64_t board_time_us(void) { return now_us; }
void board_idle(uint32_t max_us) { (void)max_us; }
const struct dw_ops *board_dw_ops(void) { return NULL; }
void board_reset(void)
{
    if (in_step)
        longjmp(reset_jmp, 1);
    abort(); /* a reset outside a main-loop pass: a harness bug */
}
void evk_delay_us(uint32_t us) { now_us += us; }
