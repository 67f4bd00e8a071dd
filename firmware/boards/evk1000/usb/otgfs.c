/* USB OTG FS device-mode driver (RM0008 chapter 28, 28.17 "OTG_FS programming model"), see
 * otgfs.h. EP0 follows the control-transfer model of USB 2.0 8.5.3 / 9.3: SETUP, an optional
 * data stage of one packet per transfer, then a zero-length status stage. Every wait is a
 * bounded loop; a bus reset may arrive at any moment and puts everything back to DEFAULT.
 */
#include "otgfs.h"

#include "otgfs_regs.h"

#ifndef OTG_HOSTED
#include "evk1000.h"
#include "stm32f105.h"
#endif

/* Critical sections that nest: PRIMASK saved and restored (PM0056 2.1.3). */
uint32_t usbd_irq_save(void)
{
#ifndef OTG_HOSTED
    uint32_t primask;
    __asm__ volatile("mrs %0, primask" : "=r"(primask));
    cpu_irq_disable();
    return primask;
#else
    return 0u;
#endif
}

void usbd_irq_restore(uint32_t primask)
{
#ifndef OTG_HOSTED
    if ((primask & 1u) == 0u)
        cpu_irq_enable();
#else
    (void)primask;
#endif
}

/* FIFO RAM: 1.25 KB = 320 words on the connectivity line (RM0008 28.4, 28.11). RX FIFO per
 * 28.11.1: 10 words for SETUP/status + 2 * (largest packet / 4 + 1) + 1, with room. */
#define FIFO_RX_WORDS 64u
#define FIFO_TX0_WORDS 16u                     /* one 64-byte EP0 packet */
#define FIFO_TX1_WORDS (USBD_DATA_TX_MAX / 4u) /* one whole bulk transfer (8 packets) */
#define FIFO_TX2_WORDS 16u
_Static_assert(FIFO_RX_WORDS + FIFO_TX0_WORDS + FIFO_TX1_WORDS + FIFO_TX2_WORDS <= 320u,
               "OTG FS FIFO RAM is 320 words");
#define WAIT_LOOPS 100000u /* bounded register waits: >1 ms at 72 MHz, far above the core's */

/* USB 2.0 table 9-4 standard request codes, 9-5 descriptor types, 9-6 feature selectors. */
enum { GET_STATUS = 0, CLEAR_FEATURE = 1, SET_FEATURE = 3, SET_ADDRESS = 5, GET_DESCRIPTOR = 6,
       GET_CONFIGURATION = 8, SET_CONFIGURATION = 9, GET_INTERFACE = 10, SET_INTERFACE = 11 };
#define FEATURE_ENDPOINT_HALT 0u
#define REQ_DIR_IN 0x80u
#define REQ_TYPE_MASK 0x60u
#define REQ_TYPE_STANDARD 0x00u
#define REQ_RECIP_MASK 0x1Fu
enum { RECIP_DEVICE = 0, RECIP_INTERFACE = 1, RECIP_ENDPOINT = 2 };
#define N_INTERFACES 2u

enum ep0_stage { EP0_IDLE = 0, EP0_DATA_IN, EP0_DATA_OUT, EP0_STATUS_IN, EP0_STATUS_OUT };

static struct {
    enum usbd_state state;
    bool suspended;
    uint8_t config;
    uint32_t bus_resets;
    /* EP0 */
    uint32_t setup_words[2];
    struct usbd_setup req;
    enum ep0_stage stage;
    const uint8_t *in_ptr;
    uint16_t in_left;
    bool in_zlp;
    uint8_t out_buf[USBD_EP0_MPS];
    uint16_t out_len;
    uint8_t reply[2];
    /* IN endpoints 1 and 2 */
    volatile bool in_busy[3];
    volatile bool in_zlp_after[3];
    uint16_t in_len[3];
    bool halted_in[3], halted_out[3];
    bool out_paused;
} usb;

enum usbd_state usbd_state(void) { return usb.state; }
bool usbd_suspended(void) { return usb.suspended; }
uint32_t usbd_bus_resets(void) { return usb.bus_resets; }

static bool wait_bits(uint32_t reg, uint32_t mask, uint32_t value)
{
    for (uint32_t i = 0; i < WAIT_LOOPS; i++) {
        if ((OTG_RD(reg) & mask) == value)
            return true;
        OTG_WAIT_HOOK();
    }
    return false;
}

static void fifo_write(uint8_t ep, const uint8_t *p, size_t len)
{
    for (size_t i = 0; i < len; i += 4u) {
        uint32_t w = 0;
        for (size_t k = 0; k < 4u && i + k < len; k++)
            w |= (uint32_t)p[i + k] << (8u * k);
        OTG_WR(OTG_FIFO(ep), w);
    }
}

static void fifo_read(uint8_t *p, size_t len, size_t keep)
{
    /* Pops ceil(len / 4) words; stores the first `keep` bytes, drops the rest. */
    for (size_t i = 0; i < len; i += 4u) {
        uint32_t w = OTG_RD(OTG_FIFO(0));
        for (size_t k = 0; k < 4u && i + k < len; k++) {
            if (i + k < keep)
                p[i + k] = (uint8_t)(w >> (8u * k));
        }
    }
}

static void flush_fifos(void)
{
    OTG_WR(GRSTCTL, GRSTCTL_TXFFLSH | GRSTCTL_TXFNUM_ALL);
    (void)wait_bits(GRSTCTL, GRSTCTL_TXFFLSH, 0u);
    OTG_WR(GRSTCTL, GRSTCTL_RXFFLSH);
    (void)wait_bits(GRSTCTL, GRSTCTL_RXFFLSH, 0u);
}

/* ---- EP0 ------------------------------------------------------------------------------ */

static void ep0_out_arm(void)
{
    OTG_WR(DOEPTSIZ(0), TSIZ_STUPCNT_3 | (1u << TSIZ_PKTCNT_SHIFT) | USBD_EP0_MPS);
    OTG_WR(DOEPCTL(0), OTG_RD(DOEPCTL(0)) | EPCTL_EPENA | EPCTL_CNAK);
}

static void ep0_in_packet(const uint8_t *p, uint16_t n)
{
    OTG_WR(DIEPTSIZ(0), (1u << TSIZ_PKTCNT_SHIFT) | n);
    OTG_WR(DIEPCTL(0), (OTG_RD(DIEPCTL(0)) & ~EPCTL_STALL) | EPCTL_EPENA | EPCTL_CNAK);
    fifo_write(0, p, n);
}

static void ep0_stall(void)
{
    /* Both directions; the core clears the STALL when the next SETUP arrives (28.17.6). */
    OTG_WR(DIEPCTL(0), OTG_RD(DIEPCTL(0)) | EPCTL_STALL);
    OTG_WR(DOEPCTL(0), OTG_RD(DOEPCTL(0)) | EPCTL_STALL);
    usb.stage = EP0_IDLE;
    ep0_out_arm();
}

static void ep0_status_in(void)
{
    usb.stage = EP0_STATUS_IN;
    ep0_in_packet(NULL, 0);
}

static void ep0_send(const uint8_t *p, uint16_t len)
{
    uint16_t want = usb.req.wLength;
    if (len > want)
        len = want;
    usb.in_ptr = p;
    usb.in_left = len;
    /* A short answer that ends on a full packet is ended by a zero-length packet (USB 2.0
     * 5.5.3), else the host waits for more. */
    usb.in_zlp = len < want && len % USBD_EP0_MPS == 0u;
    usb.stage = EP0_DATA_IN;
    uint16_t n = len < USBD_EP0_MPS ? len : (uint16_t)USBD_EP0_MPS;
    ep0_in_packet(p, n);
    usb.in_ptr += n;
    usb.in_left = (uint16_t)(usb.in_left - n);
    if (n == USBD_EP0_MPS || usb.in_left > 0u)
        return;
    usb.in_zlp = false; /* a short first packet already ends the transfer */
}

static void ep_halt(uint8_t addr, bool halt)
{
    uint8_t ep = addr & 0x0Fu;
    if (addr & 0x80u) {
        uint32_t c = OTG_RD(DIEPCTL(ep));
        OTG_WR(DIEPCTL(ep), halt ? (c | EPCTL_STALL) : ((c & ~EPCTL_STALL) | EPCTL_SD0PID));
        usb.halted_in[ep] = halt;
    } else {
        uint32_t c = OTG_RD(DOEPCTL(ep));
        OTG_WR(DOEPCTL(ep), halt ? (c | EPCTL_STALL) : ((c & ~EPCTL_STALL) | EPCTL_SD0PID));
        usb.halted_out[ep] = halt;
    }
}

static bool ep_valid(uint8_t addr)
{
    uint8_t ep = addr & 0x0Fu;
    if (ep == 0u)
        return (addr & 0x70u) == 0u;
    if (usb.state != USBD_CONFIGURED || (addr & 0x70u) != 0u)
        return false;
    return (addr & 0x80u) ? (ep == USBD_EP_DATA || ep == USBD_EP_NOTIFY) : ep == USBD_EP_DATA;
}

static void endpoints_open(bool on)
{
    if (usb.in_busy[USBD_EP_DATA]) {
        /* XFRSIZ counts down as the host acknowledges packets (28.16.4 DIEPTSIZx). */
        uint32_t left = OTG_RD(DIEPTSIZ(USBD_EP_DATA)) & 0x7FFFFu;
        uint16_t len = usb.in_len[USBD_EP_DATA];
        usb.in_busy[USBD_EP_DATA] = false;
        usbd_class_in_done(USBD_EP_DATA, left < len ? len - left : 0u);
    }
    for (uint8_t ep = 1; ep <= 2u; ep++) {
        usb.in_busy[ep] = false;
        usb.in_zlp_after[ep] = false;
        usb.halted_in[ep] = usb.halted_out[ep] = false;
        if (OTG_RD(DIEPCTL(ep)) & EPCTL_EPENA)
            OTG_WR(DIEPCTL(ep), EPCTL_EPDIS | EPCTL_SNAK);
        if (OTG_RD(DOEPCTL(ep)) & EPCTL_EPENA)
            OTG_WR(DOEPCTL(ep), EPCTL_EPDIS | EPCTL_SNAK);
        OTG_WR(DIEPCTL(ep), 0u);
        OTG_WR(DOEPCTL(ep), 0u);
    }
    if (!on) {
        OTG_WR(DAINTMSK, 1u | (1u << 16));
        return;
    }
    OTG_WR(DIEPCTL(USBD_EP_DATA), USBD_DATA_MPS | EPCTL_USBAEP | EPCTL_EPTYP_BULK
                                      | EPCTL_TXFNUM(USBD_EP_DATA) | EPCTL_SD0PID | EPCTL_SNAK);
    OTG_WR(DIEPCTL(USBD_EP_NOTIFY), USBD_NOTIFY_MPS | EPCTL_USBAEP | EPCTL_EPTYP_INTR
                                        | EPCTL_TXFNUM(USBD_EP_NOTIFY) | EPCTL_SD0PID | EPCTL_SNAK);
    OTG_WR(DOEPCTL(USBD_EP_DATA), USBD_DATA_MPS | EPCTL_USBAEP | EPCTL_EPTYP_BULK | EPCTL_SD0PID);
    OTG_WR(DAINTMSK, 1u | (1u << USBD_EP_DATA) | (1u << USBD_EP_NOTIFY) | (1u << 16)
                         | (1u << (16u + USBD_EP_DATA)));
    usb.out_paused = false;
    usbd_out_arm(USBD_EP_DATA);
}

/* USB 2.0 9.4: the standard requests. Returns false to STALL. */
static bool standard_request(const struct usbd_setup *s)
{
    uint8_t recip = s->bmRequestType & REQ_RECIP_MASK;
    bool in = (s->bmRequestType & REQ_DIR_IN) != 0u;
    switch (s->bRequest) {
    case GET_DESCRIPTOR: {
        if (!in || recip != RECIP_DEVICE)
            return false;
        uint16_t len = 0;
        const uint8_t *d = usbd_class_descriptor((uint8_t)(s->wValue >> 8), (uint8_t)s->wValue, &len);
        if (d == NULL)
            return false; /* e.g. DEVICE_QUALIFIER: a full-speed-only device STALLs (9.6.2) */
        ep0_send(d, len);
        return true;
    }
    case SET_ADDRESS:
        if (in || recip != RECIP_DEVICE || s->wValue > 127u || s->wIndex || s->wLength
            || usb.state == USBD_CONFIGURED)
            return false;
        /* The core answers the status stage at the old address (28.17.5 "device
         * initialization": DAD is written on the SETUP, before the status stage). */
        OTG_WR(DCFG, (OTG_RD(DCFG) & ~DCFG_DAD_MASK) | ((uint32_t)s->wValue << DCFG_DAD_SHIFT));
        usb.state = s->wValue ? USBD_ADDRESSED : USBD_DEFAULT;
        ep0_status_in();
        return true;
    case GET_CONFIGURATION:
        if (!in || recip != RECIP_DEVICE || s->wLength != 1u)
            return false;
        usb.reply[0] = usb.config;
        ep0_send(usb.reply, 1);
        return true;
    case SET_CONFIGURATION:
        if (in || recip != RECIP_DEVICE || s->wValue > 1u || usb.state < USBD_ADDRESSED)
            return false;
        usb.config = (uint8_t)s->wValue;
        usb.state = usb.config ? USBD_CONFIGURED : USBD_ADDRESSED;
        endpoints_open(usb.config != 0u);
        usbd_class_configured(usb.config != 0u);
        ep0_status_in();
        return true;
    case GET_STATUS:
        if (!in || s->wLength != 2u)
            return false;
        usb.reply[0] = usb.reply[1] = 0u; /* bus powered, no remote wakeup */
        if (recip == RECIP_INTERFACE) {
            if (usb.state != USBD_CONFIGURED || s->wIndex >= N_INTERFACES)
                return false;
        } else if (recip == RECIP_ENDPOINT) {
            uint8_t a = (uint8_t)s->wIndex;
            if (!ep_valid(a))
                return false;
            usb.reply[0] = (a & 0x80u) ? usb.halted_in[a & 0xFu] : usb.halted_out[a & 0xFu];
        } else if (recip != RECIP_DEVICE) {
            return false;
        }
        ep0_send(usb.reply, 2);
        return true;
    case CLEAR_FEATURE:
    case SET_FEATURE:
        /* Only ENDPOINT_HALT: no remote wakeup is offered and TEST_MODE is high speed only. */
        if (in || recip != RECIP_ENDPOINT || s->wValue != FEATURE_ENDPOINT_HALT
            || !ep_valid((uint8_t)s->wIndex) || (s->wIndex & 0x0Fu) == 0u)
            return false;
        ep_halt((uint8_t)s->wIndex, s->bRequest == SET_FEATURE);
        ep0_status_in();
        return true;
    case GET_INTERFACE:
        if (!in || recip != RECIP_INTERFACE || usb.state != USBD_CONFIGURED
            || s->wIndex >= N_INTERFACES || s->wLength != 1u)
            return false;
        usb.reply[0] = 0u;
        ep0_send(usb.reply, 1);
        return true;
    case SET_INTERFACE:
        if (in || recip != RECIP_INTERFACE || usb.state != USBD_CONFIGURED
            || s->wIndex >= N_INTERFACES || s->wValue != 0u)
            return false;
        ep0_status_in();
        return true;
    default:
        return false;
    }
}

static void ep0_setup(void)
{
    uint32_t w0 = usb.setup_words[0], w1 = usb.setup_words[1];
    struct usbd_setup *s = &usb.req;
    s->bmRequestType = (uint8_t)w0;
    s->bRequest = (uint8_t)(w0 >> 8);
    s->wValue = (uint16_t)(w0 >> 16);
    s->wIndex = (uint16_t)w1;
    s->wLength = (uint16_t)(w1 >> 16);
    usb.stage = EP0_IDLE;
    usb.in_left = 0;
    usb.in_zlp = false;
    if (OTG_RD(DIEPCTL(0)) & EPCTL_EPENA) {
        /* The host gave up a data stage (a new SETUP always wins, USB 2.0 8.5.3): drop what
         * is still queued for EP0 IN so the new answer does not follow stale bytes. */
        OTG_WR(DIEPCTL(0), OTG_RD(DIEPCTL(0)) | EPCTL_EPDIS | EPCTL_SNAK);
        OTG_WR(GRSTCTL, GRSTCTL_TXFFLSH); /* TXFNUM 0: the EP0 TX FIFO */
        (void)wait_bits(GRSTCTL, GRSTCTL_TXFFLSH, 0u);
        OTG_WR(DIEPINT(0), EPINT_EPDISD);
    }
    ep0_out_arm();

    if ((s->bmRequestType & REQ_TYPE_MASK) == REQ_TYPE_STANDARD) {
        if (!standard_request(s))
            ep0_stall();
        return;
    }
    const uint8_t *reply = NULL;
    uint16_t len = 0;
    if (usb.state != USBD_CONFIGURED || usbd_class_setup(s, &reply, &len) != 0) {
        ep0_stall();
        return;
    }
    if (s->bmRequestType & REQ_DIR_IN) {
        ep0_send(reply, len);
    } else if (s->wLength > 0u) {
        if (s->wLength > sizeof usb.out_buf) {
            ep0_stall();
            return;
        }
        usb.out_len = 0;
        usb.stage = EP0_DATA_OUT;
    } else {
        ep0_status_in();
    }
}

static void ep0_in_done(void)
{
    if (usb.stage == EP0_DATA_IN) {
        if (usb.in_left > 0u) {
            uint16_t n = usb.in_left < USBD_EP0_MPS ? usb.in_left : (uint16_t)USBD_EP0_MPS;
            ep0_in_packet(usb.in_ptr, n);
            usb.in_ptr += n;
            usb.in_left = (uint16_t)(usb.in_left - n);
            if (usb.in_left == 0u && n < USBD_EP0_MPS)
                usb.in_zlp = false;
            return;
        }
        if (usb.in_zlp) {
            usb.in_zlp = false;
            ep0_in_packet(NULL, 0);
            return;
        }
        usb.stage = EP0_STATUS_OUT; /* the host's zero-length OUT comes next */
        return;
    }
    usb.stage = EP0_IDLE; /* status IN sent */
}

static void ep0_out_done(void)
{
    if (usb.stage == EP0_DATA_OUT && usb.out_len >= usb.req.wLength) {
        usbd_class_out_data(&usb.req, usb.out_buf, usb.out_len);
        ep0_status_in();
    } else if (usb.stage == EP0_STATUS_OUT) {
        usb.stage = EP0_IDLE;
    }
    ep0_out_arm();
}

/* ---- bus events --------------------------------------------------------------------------- */

static void bus_reset(void)
{
    usb.bus_resets++;
    usb.state = USBD_DEFAULT;
    usb.suspended = false;
    usb.config = 0;
    usb.stage = EP0_IDLE;
    OTG_WR(DCTL, OTG_RD(DCTL) & ~DCTL_RWUSIG);
    endpoints_open(false);
    flush_fifos();
    for (uint8_t ep = 0; ep < 4u; ep++) {
        OTG_WR(DIEPINT(ep), 0xFFu);
        OTG_WR(DOEPINT(ep), 0xFFu);
    }
    OTG_WR(DOEPMSK, EPINT_XFRC | EPINT_STUP);
    OTG_WR(DIEPMSK, EPINT_XFRC | EPINT_TOC);
    OTG_WR(DCFG, OTG_RD(DCFG) & ~DCFG_DAD_MASK);
    ep0_out_arm();
    usbd_class_configured(false);
}

static void rx_fifo_pop(void)
{
    uint32_t st = OTG_RD(GRXSTSP);
    uint8_t ep = (uint8_t)GRXSTS_EPNUM(st);
    uint16_t n = (uint16_t)GRXSTS_BCNT(st);
    switch (GRXSTS_PKTSTS(st)) {
    case PKTSTS_SETUP_DATA:
        fifo_read((uint8_t *)usb.setup_words, n, sizeof usb.setup_words);
        break;
    case PKTSTS_OUT_DATA:
        if (ep == 0u) {
            size_t room = sizeof usb.out_buf - usb.out_len;
            fifo_read(usb.out_buf + usb.out_len, n, room);
            usb.out_len = (uint16_t)(usb.out_len + (n < room ? n : room));
        } else {
            uint8_t pkt[USBD_DATA_MPS];
            fifo_read(pkt, n, sizeof pkt);
            if (!usbd_class_rx(pkt, n < sizeof pkt ? n : sizeof pkt))
                usb.out_paused = true;
        }
        break;
    default: /* SETUP done, OUT done, global OUT NAK: no data */
        break;
    }
}

void usbd_irq(void)
{
    uint32_t st = OTG_RD(GINTSTS) & OTG_RD(GINTMSK);
    if (st & GINT_USBRST) {
        OTG_WR(GINTSTS, GINT_USBRST);
        bus_reset();
    }
    if (st & GINT_ENUMDNE) {
        OTG_WR(GINTSTS, GINT_ENUMDNE);
        OTG_WR(DIEPCTL(0), OTG_RD(DIEPCTL(0)) & ~EPCTL_MPSIZ_MASK); /* 0: 64 bytes */
        OTG_WR(DCTL, OTG_RD(DCTL) | DCTL_CGINAK);
    }
    for (unsigned i = 0; i < 16u && (OTG_RD(GINTSTS) & GINT_RXFLVL); i++)
        rx_fifo_pop();
    if (st & GINT_OEPINT) {
        uint32_t eps = OTG_RD(DAINT) >> 16;
        for (uint8_t ep = 0; ep <= USBD_EP_DATA; ep++) {
            if (!(eps & (1u << ep)))
                continue;
            uint32_t f = OTG_RD(DOEPINT(ep)) & OTG_RD(DOEPMSK);
            OTG_WR(DOEPINT(ep), f);
            if (ep == 0u && (f & EPINT_STUP)) {
                ep0_setup();
            } else if (ep == 0u && (f & EPINT_XFRC)) {
                ep0_out_done();
            } else if (f & EPINT_XFRC) {
                if (!usb.out_paused)
                    usbd_out_arm(ep);
            }
        }
    }
    if (st & GINT_IEPINT) {
        uint32_t eps = OTG_RD(DAINT) & 0xFFFFu;
        for (uint8_t ep = 0; ep <= USBD_EP_NOTIFY; ep++) {
            if (!(eps & (1u << ep)))
                continue;
            uint32_t f = OTG_RD(DIEPINT(ep)) & OTG_RD(DIEPMSK);
            OTG_WR(DIEPINT(ep), f);
            if (!(f & EPINT_XFRC))
                continue;
            if (ep == 0u) {
                ep0_in_done();
            } else if (usb.in_zlp_after[ep]) {
                usb.in_zlp_after[ep] = false;
                OTG_WR(DIEPTSIZ(ep), 1u << TSIZ_PKTCNT_SHIFT);
                OTG_WR(DIEPCTL(ep), OTG_RD(DIEPCTL(ep)) | EPCTL_EPENA | EPCTL_CNAK);
            } else {
                usb.in_busy[ep] = false;
                if (ep == USBD_EP_DATA)
                    usbd_class_in_done(ep, usb.in_len[ep]);
            }
        }
    }
    if (st & GINT_USBSUSP) {
        OTG_WR(GINTSTS, GINT_USBSUSP);
        if (OTG_RD(DSTS) & DSTS_SUSPSTS)
            usb.suspended = true;
    }
    if (st & GINT_WKUPINT) {
        OTG_WR(GINTSTS, GINT_WKUPINT);
        usb.suspended = false;
    }
    if (st & (GINT_SRQINT | GINT_MMIS))
        OTG_WR(GINTSTS, st & (GINT_SRQINT | GINT_MMIS));
    if (st & GINT_OTGINT)
        OTG_WR(GOTGCTL + 4u, OTG_RD(GOTGCTL + 4u)); /* GOTGINT: write 1 to clear */
}

/* ---- data endpoints ------------------------------------------------------------------------ */

bool usbd_in_busy(uint8_t ep) { return ep < 3u && usb.in_busy[ep]; }

bool usbd_in_start(uint8_t ep, const uint8_t *data, size_t len)
{
    if (ep == 0u || ep > USBD_EP_NOTIFY || len > USBD_DATA_TX_MAX || usb.state != USBD_CONFIGURED)
        return false;
    uint32_t pm = usbd_irq_save();
    bool ok = !usb.in_busy[ep] && !usb.halted_in[ep] && usb.state == USBD_CONFIGURED;
    if (ok) {
        uint32_t mps = ep == USBD_EP_DATA ? USBD_DATA_MPS : USBD_NOTIFY_MPS;
        uint32_t pkts = len == 0u ? 1u : (uint32_t)((len + mps - 1u) / mps);
        usb.in_busy[ep] = true;
        usb.in_len[ep] = (uint16_t)len;
        usb.in_zlp_after[ep] = ep == USBD_EP_DATA && len > 0u && len % mps == 0u;
        OTG_WR(DIEPTSIZ(ep), (pkts << TSIZ_PKTCNT_SHIFT) | (uint32_t)len);
        OTG_WR(DIEPCTL(ep), OTG_RD(DIEPCTL(ep)) | EPCTL_EPENA | EPCTL_CNAK);
        fifo_write(ep, data, len);
    }
    usbd_irq_restore(pm);
    return ok;
}

void usbd_out_arm(uint8_t ep)
{
    uint32_t pm = usbd_irq_save();
    if (usb.state == USBD_CONFIGURED && !usb.halted_out[ep]) {
        usb.out_paused = false;
        OTG_WR(DOEPTSIZ(ep), (1u << TSIZ_PKTCNT_SHIFT) | USBD_DATA_MPS);
        OTG_WR(DOEPCTL(ep), OTG_RD(DOEPCTL(ep)) | EPCTL_EPENA | EPCTL_CNAK);
    }
    usbd_irq_restore(pm);
}

/* ---- init (RM0008 28.17.1 core initialization, 28.17.3 device initialization) ------------ */

int usbd_init(void)
{
    usb.state = USBD_DETACHED;
#ifndef OTG_HOSTED
    /* 48 MHz from PLLVCO / 3 (clock.c leaves OTGFSPRE = 0); PA11/PA12 are taken by the core
     * when it is powered, with no GPIO setup (RM0008 9.1.11 table 29 note); PA9 = VBUS. */
    RCC_AHBENR |= RCC_AHBENR_OTGFSEN;
    (void)RCC_AHBENR;
#endif
    OTG_WR(GAHBCFG, 0u);
    if (!wait_bits(GRSTCTL, GRSTCTL_AHBIDL, GRSTCTL_AHBIDL))
        return -1;
    OTG_WR(GRSTCTL, GRSTCTL_CSRST);
    if (!wait_bits(GRSTCTL, GRSTCTL_CSRST, 0u))
        return -1;
    OTG_WR(GUSBCFG, GUSBCFG_PHYSEL | GUSBCFG_FDMOD | (6u << GUSBCFG_TRDT_SHIFT));
    /* Forcing device mode takes effect after at least 25 ms (28.16.2 GUSBCFG.FDMOD). */
#ifndef OTG_HOSTED
    evk_delay_us(25000u);
#endif
    OTG_WR(GCCFG, GCCFG_PWRDWN | GCCFG_VBUSBSEN);
    OTG_WR(PCGCCTL, 0u);
    OTG_WR(DCFG, DCFG_DSPD_FS);
    OTG_WR(DCTL, DCTL_SDIS); /* stay disconnected until everything is set up */

    OTG_WR(GRXFSIZ, FIFO_RX_WORDS);
    OTG_WR(DIEPTXF0, (FIFO_TX0_WORDS << 16) | FIFO_RX_WORDS);
    OTG_WR(DIEPTXF(1), (FIFO_TX1_WORDS << 16) | (FIFO_RX_WORDS + FIFO_TX0_WORDS));
    OTG_WR(DIEPTXF(2), (FIFO_TX2_WORDS << 16) | (FIFO_RX_WORDS + FIFO_TX0_WORDS + FIFO_TX1_WORDS));
    flush_fifos();

    OTG_WR(GINTSTS, 0xFFFFFFFFu);
    OTG_WR(GINTMSK, GINT_USBRST | GINT_ENUMDNE | GINT_RXFLVL | GINT_IEPINT | GINT_OEPINT
                        | GINT_USBSUSP | GINT_WKUPINT | GINT_OTGINT | GINT_SRQINT | GINT_MMIS);
    OTG_WR(GAHBCFG, GAHBCFG_GINTMSK);
#ifndef OTG_HOSTED
    nvic_enable(OTG_FS_IRQN, 2u);
#endif
    OTG_WR(DCTL, OTG_RD(DCTL) & ~DCTL_SDIS); /* D+ pull-up on: the host sees the device */
    return 0;
}

#ifndef OTG_HOSTED
void OTG_FS_IRQHandler(void);
void OTG_FS_IRQHandler(void) { usbd_irq(); }
#endif
