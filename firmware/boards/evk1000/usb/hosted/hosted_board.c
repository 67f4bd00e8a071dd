/* HOST-ONLY: the EVK1000's USB link (usb/otgfs.c, usb/cdc_acm.c) and the station core built
 * as a shared library for the host (build/usbhosted/libevkusb.so, `make usbhosted`), so the
 * real driver code runs against the Python OTG FS model (host/uwbcal/evk1000/otgfs.py)
 * without a CPU emulator. host/uwbcal/evk1000/usbhosted.py loads it with ctypes.
 *
 * Compiled with -DOTG_HOSTED: every OTG register access is a call to the model (the
 * callbacks below); a driver wait calls the wait callback, in which the harness lets the
 * USB host run and delivers the interrupt, as the NVIC would on the chip. Time is a virtual
 * microsecond counter the harness advances, or, attached to the simulated medium, the
 * medium's virtual time. Flash is the native board's simulated flash (boards/native/flash.c,
 * in a file with --flash). Radio: the native board's tunnel to the medium
 * (boards/native/radio_tunnel.c) when attached, else none (board_dw_ops() is NULL).
 *
 * What this cannot show: anything of the ARM image itself (startup, clocks, the NVIC, the
 * real interrupt timing and preemption points, the 72 MHz cycle budget); that needs the
 * emulated EVK1000 of issue 10.
 */
#define _XOPEN_SOURCE 700
#include <poll.h>
#include <setjmp.h>
#include <stdlib.h>
#include <string.h>
#include <stddef.h>
#include <stdint.h>

#include "app.h"
#include "board.h"
#include "cdc_acm.h"
#include "dw1000_ops.h"
#include "evk1000.h"
#include "native.h"
#include "otgfs.h"
#include "otgfs_regs.h"

typedef uint32_t (*hosted_read_fn)(uint32_t offset);
typedef void (*hosted_write_fn)(uint32_t offset, uint32_t value);
typedef void (*hosted_wait_fn)(void);

/* A radio wait is cut into slices of this much virtual time (one full-speed frame); between
 * slices the USB host and the OTG interrupt run, as on the chip, where the USB interrupt
 * preempts a wait for the DW1000 and the host controller polls the device whatever its CPU
 * does. (250 us slices cost 11 ms of wall time per triplet, 1 ms slices 5 ms.) */
#define HOSTED_RADIO_SLICE_US 1000u

static hosted_read_fn rd_cb;
static hosted_write_fn wr_cb;
static hosted_wait_fn wait_cb;
static hosted_wait_fn bus_cb;
static uint64_t now_us;
static uint8_t uid_bytes[12] = {0x55, 0x57, 0x42, 0x43, 0x48, 0x4F, 0x53, 0x54, 0, 0, 0, 1};
static jmp_buf reset_jmp;
static int in_step;
static uint16_t station_id = 1;
static int link_fd = -1;
static int medium_attached;

/* ---- the harness API (ctypes) ---- */
void hosted_set_callbacks(hosted_read_fn r, hosted_write_fn w, hosted_wait_fn wt);
void hosted_set_bus_callback(hosted_wait_fn bus);
void hosted_set_uid(const uint8_t uid[12]);
void hosted_set_time_us(uint64_t t);
void hosted_init(void);
int hosted_poll(void);
void hosted_irq(void);
uint32_t hosted_tx_failures(void);
int hosted_attach(uint16_t id, const char *flash_path, const char *medium_socket);
void hosted_set_link_fd(int fd);
void hosted_idle(uint32_t max_us);
int hosted_should_exit(void);
uint64_t hosted_time_us(void);

void hosted_set_callbacks(hosted_read_fn r, hosted_write_fn w, hosted_wait_fn wt)
{
    rd_cb = r;
    wr_cb = w;
    wait_cb = wt;
}

/* Called between the slices of a radio wait: the USB host and the interrupt, no time. */
void hosted_set_bus_callback(hosted_wait_fn bus) { bus_cb = bus; }

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

/* A station process (host/uwbcal/evk1000/usbstation.py): its id, its flash file (NULL: RAM),
 * the medium's socket (NULL: no radio), and SIGTERM/SIGINT handling as the native board's.
 * Before hosted_init(). Returns 0, or -1 if the medium does not answer. */
int hosted_attach(uint16_t id, const char *flash_path, const char *medium_socket)
{
    station_id = id;
    native_catch_exit_signals();
    (void)native_flash_open(flash_path);
    if (medium_socket != NULL) {
        if (native_radio_attach(medium_socket, id, uid_bytes) != 0)
            return -1;
        medium_attached = 1;
    }
    return 0;
}

/* The fd whose input ends an idle early (the pty the USB bridge serves). */
void hosted_set_link_fd(int fd) { link_fd = fd; }

/* Nothing to do for max_us: with the medium, wait in virtual time (the medium advances it);
 * without, the harness advances its own clock. */
void hosted_idle(uint32_t max_us)
{
    if (medium_attached)
        native_radio_idle(max_us);
    else
        now_us += max_us;
}

int hosted_should_exit(void) { return native_should_exit() ? 1 : 0; }
uint64_t hosted_time_us(void) { return board_time_us(); }

/* ---- the native board hooks radio_tunnel.c and flash.c use (native.h) ---- */
uint16_t native_station_id(void) { return station_id; }
int native_link_fd(void) { return link_fd; }
void native_wait_input(int extra_fd, uint32_t max_us)
{
    struct pollfd p[2] = {{.fd = link_fd, .events = POLLIN}, {.fd = extra_fd, .events = POLLIN}};
    if (!native_should_exit())
        (void)poll(p, 2, (int)((max_us + 999u) / 1000u));
}
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
uint64_t board_time_us(void)
{
    uint64_t t;
    return native_radio_time_us(&t) == 0 ? t : now_us;
}
void board_idle(uint32_t max_us) { hosted_idle(max_us); }
static const struct dw_ops *radio_inner;
static struct dw_ops radio_sliced;

static int sliced_wait_irq(void *ctx, uint64_t deadline_us)
{
    for (unsigned i = 0; i < 1000000u; i++) {
        uint64_t step = board_time_us() + HOSTED_RADIO_SLICE_US;
        if (step >= deadline_us || bus_cb == NULL)
            return radio_inner->wait_irq(ctx, deadline_us);
        int r = radio_inner->wait_irq(ctx, step);
        if (r != 0)
            return r; /* the IRQ, or an error */
        bus_cb();
    }
    return 0; /* an early wake: every caller of wait_irq tolerates one */
}

const struct dw_ops *board_dw_ops(void)
{
    const struct dw_ops *ops = native_radio_ops();
    if (ops == NULL)
        return NULL;
    if (radio_inner != ops) {
        radio_inner = ops;
        radio_sliced = *ops;
        radio_sliced.wait_irq = sliced_wait_irq;
    }
    return &radio_sliced;
}
void board_reset(void)
{
    if (in_step)
        longjmp(reset_jmp, 1);
    abort(); /* a reset outside a main-loop pass: a harness bug */
}
void evk_delay_us(uint32_t us) { now_us += us; }
