/* CDC-ACM function on the OTG FS driver (otgfs.h) and the host link of board.h over it.
 *
 * Descriptors: USB 2.0 chapter 9, the Interface Association ECN, CDC 1.2 (PSTN subclass for
 * the ACM functional descriptors). Identity (VID/PID, strings) from protocol/protocol.toml
 * [usb] through proto_gen.h; the serial number string is the chip UID in hex (board_uid).
 * Class requests: SET/GET_LINE_CODING, SET_CONTROL_LINE_STATE, SEND_BREAK (PSTN 6.3).
 *
 * Data: bulk OUT bytes go into a ring buffer; when it has no room for another 64-byte
 * packet, the endpoint stays NAKing (the host holds the data) until board_link_read frees
 * space, so no received byte is ever dropped. Bulk IN: board_link_write appends to a TX ring
 * buffer and returns; transfers of up to 512 bytes are started from the ring whenever the
 * endpoint is free (from the main loop or the interrupt handler). The ring's tail moves only
 * over bytes the host acknowledged: a bus reset cuts a transfer, the unsent rest stays in the
 * ring and goes out once the host has configured the device again. A host that stops reading
 * fills the ring: a write then waits (bounded) and, if the host still does not read, drops
 * what does not fit and says so (false, counted).
 */
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "board.h"
#include "cdc_acm.h"
#include "evk1000.h"
#include "otgfs.h"
#include "otgfs_regs.h"
#include "proto_gen.h"

#ifndef CDC_RX_RING_SIZE
#define CDC_RX_RING_SIZE 512u /* power of two, >= 2 packets */
#endif
_Static_assert((CDC_RX_RING_SIZE & (CDC_RX_RING_SIZE - 1u)) == 0u, "ring: a power of two");
_Static_assert(CDC_RX_RING_SIZE >= 2u * USBD_DATA_MPS, "ring: two packets at least");
#ifndef CDC_TX_RING_SIZE
#define CDC_TX_RING_SIZE 2048u /* power of two, a multiple of 64: ~13 full TRIPLETS frames */
#endif
_Static_assert((CDC_TX_RING_SIZE & (CDC_TX_RING_SIZE - 1u)) == 0u && CDC_TX_RING_SIZE % 64u == 0u,
               "TX ring: a power of two, whole packets");
/* A write waits at most this long for room in the TX ring (us). A host whose port is open
 * reads continuously (cdc_acm keeps bulk IN requests queued); one that closed the port or
 * stopped for longer loses what cannot be sent, and the station goes on. */
#ifndef CDC_TX_TIMEOUT_US
#define CDC_TX_TIMEOUT_US 50000u
#endif

/* ---- descriptors ------------------------------------------------------------------------ */
#define LO(x) (uint8_t)((x) & 0xFFu)
#define HI(x) (uint8_t)(((x) >> 8) & 0xFFu)
enum { STR_LANGID = 0, STR_MANUFACTURER = 1, STR_PRODUCT = 2, STR_SERIAL = 3, STR_COUNT };

static const uint8_t device_desc[18] = {
    18, 1,               /* bLength, DEVICE */
    0x00, 0x02,          /* bcdUSB 2.00 */
    0xEF, 0x02, 0x01,    /* Miscellaneous / Common / IAD: the function is described by its IAD */
    USBD_EP0_MPS,
    LO(PROTO_USB_VID), HI(PROTO_USB_VID), LO(PROTO_USB_PID), HI(PROTO_USB_PID),
    LO(PROTO_USB_BCD_DEVICE), HI(PROTO_USB_BCD_DEVICE),
    STR_MANUFACTURER, STR_PRODUCT, STR_SERIAL,
    1,                   /* bNumConfigurations */
};

#define CONFIG_TOTAL 75u
static const uint8_t config_desc[CONFIG_TOTAL] = {
    9, 2, LO(CONFIG_TOTAL), HI(CONFIG_TOTAL), 2, 1, 0,
    0x80,                /* bus powered, no remote wakeup */
    125,                 /* 250 mA (units of 2 mA) */
    /* Interface Association: interfaces 0-1, CDC / ACM */
    8, 11, 0, 2, 0x02, 0x02, 0x00, 0,
    /* Interface 0: Communications, ACM, no AT-command protocol, 1 endpoint */
    9, 4, 0, 0, 1, 0x02, 0x02, 0x00, 0,
    5, 0x24, 0x00, 0x20, 0x01,  /* Header, bcdCDC 1.20 */
    5, 0x24, 0x01, 0x00, 1,     /* Call Management: none over data, data interface 1 */
    4, 0x24, 0x02, 0x02,        /* ACM: line coding + control line state + SERIAL_STATE */
    5, 0x24, 0x06, 0, 1,        /* Union: control 0, subordinate 1 */
    7, 5, 0x80 | USBD_EP_NOTIFY, 0x03, USBD_NOTIFY_MPS, 0, 16, /* interrupt IN, 16 ms */
    /* Interface 1: CDC Data, 2 bulk endpoints */
    9, 4, 1, 0, 2, 0x0A, 0x00, 0x00, 0,
    7, 5, USBD_EP_DATA, 0x02, LO(USBD_DATA_MPS), HI(USBD_DATA_MPS), 0,          /* bulk OUT */
    7, 5, 0x80 | USBD_EP_DATA, 0x02, LO(USBD_DATA_MPS), HI(USBD_DATA_MPS), 0,   /* bulk IN */
};

static const uint8_t langid_desc[4] = {4, 3, 0x09, 0x04}; /* English (United States) */
/* Longest string: the product name; the serial is 24 hex digits. */
#define STR_MAX_CHARS 32u
static uint8_t string_buf[2u + 2u * STR_MAX_CHARS];

static const uint8_t *string_desc(const char *s, uint16_t *len)
{
    size_t n = 0;
    for (; s[n] != '\0' && n < STR_MAX_CHARS; n++) {
        string_buf[2u + 2u * n] = (uint8_t)s[n]; /* ASCII -> UTF-16LE */
        string_buf[3u + 2u * n] = 0u;
    }
    string_buf[0] = (uint8_t)(2u + 2u * n);
    string_buf[1] = 3u;
    *len = string_buf[0];
    return string_buf;
}

const uint8_t *usbd_class_descriptor(uint8_t type, uint8_t index, uint16_t *len)
{
    switch (type) {
    case 1:
        *len = sizeof device_desc;
        return index == 0u ? device_desc : NULL;
    case 2:
        *len = sizeof config_desc;
        return index == 0u ? config_desc : NULL;
    case 3:
        if (index == STR_LANGID) {
            *len = sizeof langid_desc;
            return langid_desc;
        }
        if (index == STR_MANUFACTURER)
            return string_desc(PROTO_USB_MANUFACTURER, len);
        if (index == STR_PRODUCT)
            return string_desc(PROTO_USB_PRODUCT, len);
        if (index == STR_SERIAL) {
            static const char hex[] = "0123456789ABCDEF";
            char s[25];
            uint8_t uid[12];
            board_uid(uid);
            for (unsigned i = 0; i < 12u; i++) {
                s[2u * i] = hex[uid[i] >> 4];
                s[2u * i + 1u] = hex[uid[i] & 0xFu];
            }
            s[24] = '\0';
            return string_desc(s, len);
        }
        return NULL;
    default:
        return NULL; /* DEVICE_QUALIFIER, OTHER_SPEED...: full-speed only, STALL */
    }
}

/* ---- class requests (CDC PSTN 1.2, 6.3) ------------------------------------------------- */
enum { SEND_ENCAPSULATED = 0x00, GET_ENCAPSULATED = 0x01, SET_LINE_CODING = 0x20,
       GET_LINE_CODING = 0x21, SET_CONTROL_LINE_STATE = 0x22, SEND_BREAK = 0x23 };

static struct {
    uint8_t line_coding[7]; /* dwDTERate LE, bCharFormat, bParityType, bDataBits */
    uint16_t line_state;    /* bit 0 DTR, bit 1 RTS */
    bool configured;
    bool notify_pending;
    uint8_t notify[10];
    uint8_t rx_ring[CDC_RX_RING_SIZE];
    volatile uint32_t rx_head, rx_tail;
    uint8_t tx_ring[CDC_TX_RING_SIZE];
    volatile uint32_t tx_head;     /* written by board_link_write */
    volatile uint32_t tx_tail;     /* bytes the host acknowledged; moved by the handler */
    volatile uint32_t tx_inflight; /* bytes of the transfer on the endpoint, 0 if none */
    uint32_t tx_dropped;
} cdc = {.line_coding = {0x00, 0xC2, 0x01, 0x00, 0, 0, 8}}; /* 115200 8N1 */

int usbd_class_setup(const struct usbd_setup *s, const uint8_t **reply, uint16_t *len)
{
    if ((s->bmRequestType & 0x7Fu) != 0x21u || s->wIndex != 0u)
        return -1; /* only class requests to interface 0 */
    switch (s->bRequest) {
    case SET_LINE_CODING:
        return s->wLength == 7u ? 0 : -1;
    case GET_LINE_CODING: /* a shorter wLength gets the first bytes (USB 2.0 9.3.5) */
        *reply = cdc.line_coding;
        *len = sizeof cdc.line_coding;
        return 0;
    case SET_CONTROL_LINE_STATE:
        if (s->wLength != 0u)
            return -1;
        cdc.line_state = s->wValue & 3u;
        cdc.notify_pending = (cdc.line_state & 1u) != 0u;
        return 0;
    case SEND_BREAK:
        return s->wLength == 0u ? 0 : -1;
    default:
        return -1;
    }
}

void usbd_class_out_data(const struct usbd_setup *s, const uint8_t *data, uint16_t len)
{
    if (s->bRequest == SET_LINE_CODING && len >= 7u) {
        for (unsigned i = 0; i < 7u; i++)
            cdc.line_coding[i] = data[i];
    }
}

static void tx_kick(void);

void usbd_class_configured(bool on)
{
    cdc.configured = on;
    if (!on)
        cdc.line_state = 0;
    else
        tx_kick(); /* what a bus reset cut off goes out now */
}

/* Start the next transfer from the ring if the endpoint is free (interrupt safe). */
static void tx_kick(void)
{
    uint32_t pm = usbd_irq_save();
    uint32_t tail = cdc.tx_tail, queued = cdc.tx_head - tail;
    if (cdc.configured && cdc.tx_inflight == 0u && queued > 0u) {
        uint32_t at = tail % CDC_TX_RING_SIZE;
        uint32_t n = CDC_TX_RING_SIZE - at; /* contiguous up to the end of the ring */
        if (n > queued)
            n = queued;
        if (n > USBD_DATA_TX_MAX)
            n = USBD_DATA_TX_MAX;
        if (usbd_in_start(USBD_EP_DATA, &cdc.tx_ring[at], n))
            cdc.tx_inflight = n;
    }
    usbd_irq_restore(pm);
}

void usbd_class_in_done(uint8_t ep, size_t sent)
{
    (void)ep;
    if (sent > cdc.tx_inflight)
        sent = cdc.tx_inflight;
    cdc.tx_tail += (uint32_t)sent;
    cdc.tx_inflight = 0;
    tx_kick();
}

static uint32_t rx_free(void) { return CDC_RX_RING_SIZE - (cdc.rx_head - cdc.rx_tail); }

bool usbd_class_rx(const uint8_t *data, size_t len)
{
    uint32_t head = cdc.rx_head;
    for (size_t i = 0; i < len && head - cdc.rx_tail < CDC_RX_RING_SIZE; i++)
        cdc.rx_ring[head++ % CDC_RX_RING_SIZE] = data[i];
    cdc.rx_head = head;
    return rx_free() >= USBD_DATA_MPS;
}

/* ---- the host link (board.h) ------------------------------------------------------------- */

bool evk_link_rx_pending(void) { return cdc.rx_head != cdc.rx_tail; }
uint32_t evk_link_rx_overruns(void) { return 0u; /* OUT flow control: never */ }
uint32_t cdc_tx_dropped(void) { return cdc.tx_dropped; }
uint32_t cdc_tx_queued(void) { return cdc.tx_head - cdc.tx_tail; }
uint16_t cdc_line_state(void) { return cdc.line_state; }

static void notify_serial_state(void)
{
    /* SERIAL_STATE (PSTN 6.5.4): DCD and DSR up once the host raised DTR. */
    static const uint8_t n[10] = {0xA1, 0x20, 0, 0, 0, 0, 2, 0, 0x03, 0x00};
    for (unsigned i = 0; i < sizeof n; i++)
        cdc.notify[i] = n[i];
    if (usbd_in_start(USBD_EP_NOTIFY, cdc.notify, sizeof cdc.notify))
        cdc.notify_pending = false;
}

size_t board_link_read(uint8_t *buf, size_t max)
{
    if (cdc.notify_pending)
        notify_serial_state();
    size_t n = 0;
    uint32_t tail = cdc.rx_tail;
    uint32_t head = cdc.rx_head;
    while (n < max && tail != head)
        buf[n++] = cdc.rx_ring[tail++ % CDC_RX_RING_SIZE];
    cdc.rx_tail = tail;
    if (n > 0u && rx_free() >= USBD_DATA_MPS)
        usbd_out_arm(USBD_EP_DATA); /* no-op unless the endpoint was left NAKing */
    return n;
}

bool board_link_write(const uint8_t *buf, size_t len)
{
    size_t done = 0;
    uint64_t deadline = board_time_us() + CDC_TX_TIMEOUT_US;
    for (uint32_t loops = 0; done < len; loops++) {
        uint32_t room = CDC_TX_RING_SIZE - (cdc.tx_head - cdc.tx_tail);
        if (room == 0u) {
            /* Wait for the host only while it is there to read; bounded either way. */
            bool host = usbd_state() == USBD_CONFIGURED && !usbd_suspended();
            if (!host || board_time_us() >= deadline || loops > 4000000u) {
                cdc.tx_dropped += (uint32_t)(len - done);
                tx_kick();
                return false;
            }
            tx_kick();
            OTG_WAIT_HOOK();
            continue;
        }
        uint32_t head = cdc.tx_head;
        while (room > 0u && done < len) {
            cdc.tx_ring[head++ % CDC_TX_RING_SIZE] = buf[done++];
            room--;
        }
        cdc.tx_head = head;
        tx_kick();
    }
    return true;
}

void evk_link_init(void)
{
    cdc.rx_head = cdc.rx_tail = 0;
    cdc.tx_head = cdc.tx_tail = cdc.tx_inflight = 0;
    cdc.configured = false;
#ifndef OTG_HOSTED
    /* The OTG FS core needs 48 MHz from the PLL and an AHB clock above 14.2 MHz (RM0008
     * 28.3, 8.2): on the 8 MHz HSI fallback there is no USB; the D+ pull-up stays off, so the
     * host sees no device rather than one that fails to enumerate (docs/EVK1000.md). */
    if (evk_clock_source() != EVK_CLOCK_PLL_HSE)
        return;
#endif
    (void)usbd_init(); /* a core that does not come out of reset leaves the link down */
}

void evk_link_flush(void)
{
    /* Let the ring empty before a reset (bounded: 20 ms, or at once without a host). */
    uint64_t deadline = board_time_us() + 20000u;
    for (uint32_t i = 0; i < 1000000u && cdc.tx_head != cdc.tx_tail && usbd_state() == USBD_CONFIGURED
                         && board_time_us() < deadline; i++) {
        tx_kick();
        OTG_WAIT_HOOK();
    }
}
