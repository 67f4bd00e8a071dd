/* EP0 of the OTG FS device driver (see otgfs.c): the control-transfer model of USB 2.0 8.5.3 /
 * 9.3 (SETUP, an optional data stage of one packet per transfer, then a zero-length status
 * stage) and the standard requests of USB 2.0 9.4; class requests go to usbd_class_setup.
 */
#include "otgfs_internal.h"

#include "otgfs_regs.h"

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

void otgfs_ep0_out_arm(void)
{
    OTG_WR(DOEPTSIZ(0), TSIZ_STUPCNT_3 | (1u << TSIZ_PKTCNT_SHIFT) | USBD_EP0_MPS);
    OTG_WR(DOEPCTL(0), OTG_RD(DOEPCTL(0)) | EPCTL_EPENA | EPCTL_CNAK);
}

static void ep0_in_packet(const uint8_t *p, uint16_t n)
{
    OTG_WR(DIEPTSIZ(0), (1u << TSIZ_PKTCNT_SHIFT) | n);
    OTG_WR(DIEPCTL(0), (OTG_RD(DIEPCTL(0)) & ~EPCTL_STALL) | EPCTL_EPENA | EPCTL_CNAK);
    otgfs_fifo_write(0, p, n);
}

static void ep0_stall(void)
{
    /* Both directions; the core clears the STALL when the next SETUP arrives (28.17.6). */
    OTG_WR(DIEPCTL(0), OTG_RD(DIEPCTL(0)) | EPCTL_STALL);
    OTG_WR(DOEPCTL(0), OTG_RD(DOEPCTL(0)) | EPCTL_STALL);
    otg.stage = EP0_IDLE;
    otgfs_ep0_out_arm();
}

static void ep0_status_in(void)
{
    otg.stage = EP0_STATUS_IN;
    ep0_in_packet(NULL, 0);
}

static void ep0_send(const uint8_t *p, uint16_t len)
{
    uint16_t want = otg.req.wLength;
    if (len > want)
        len = want;
    otg.in_ptr = p;
    otg.in_left = len;
    /* A short answer that ends on a full packet is ended by a zero-length packet (USB 2.0
     * 5.5.3), else the host waits for more. */
    otg.in_zlp = len < want && len % USBD_EP0_MPS == 0u;
    otg.stage = EP0_DATA_IN;
    uint16_t n = len < USBD_EP0_MPS ? len : (uint16_t)USBD_EP0_MPS;
    ep0_in_packet(p, n);
    otg.in_ptr += n;
    otg.in_left = (uint16_t)(otg.in_left - n);
    if (n == USBD_EP0_MPS || otg.in_left > 0u)
        return;
    otg.in_zlp = false; /* a short first packet already ends the transfer */
}

static void ep_halt(uint8_t addr, bool halt)
{
    uint8_t ep = addr & 0x0Fu;
    if (addr & 0x80u) {
        uint32_t c = OTG_RD(DIEPCTL(ep));
        OTG_WR(DIEPCTL(ep), halt ? (c | EPCTL_STALL) : ((c & ~EPCTL_STALL) | EPCTL_SD0PID));
        otg.halted_in[ep] = halt;
    } else {
        uint32_t c = OTG_RD(DOEPCTL(ep));
        OTG_WR(DOEPCTL(ep), halt ? (c | EPCTL_STALL) : ((c & ~EPCTL_STALL) | EPCTL_SD0PID));
        otg.halted_out[ep] = halt;
    }
}

static bool ep_valid(uint8_t addr)
{
    uint8_t ep = addr & 0x0Fu;
    if (ep == 0u)
        return (addr & 0x70u) == 0u;
    if (otg.state != USBD_CONFIGURED || (addr & 0x70u) != 0u)
        return false;
    return (addr & 0x80u) ? (ep == USBD_EP_DATA || ep == USBD_EP_NOTIFY) : ep == USBD_EP_DATA;
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
            || otg.state == USBD_CONFIGURED)
            return false;
        /* The core answers the status stage at the old address (28.17.5 "device
         * initialization": DAD is written on the SETUP, before the status stage). */
        OTG_WR(DCFG, (OTG_RD(DCFG) & ~DCFG_DAD_MASK) | ((uint32_t)s->wValue << DCFG_DAD_SHIFT));
        otg.state = s->wValue ? USBD_ADDRESSED : USBD_DEFAULT;
        ep0_status_in();
        return true;
    case GET_CONFIGURATION:
        if (!in || recip != RECIP_DEVICE || s->wLength != 1u)
            return false;
        otg.reply[0] = otg.config;
        ep0_send(otg.reply, 1);
        return true;
    case SET_CONFIGURATION:
        if (in || recip != RECIP_DEVICE || s->wValue > 1u || otg.state < USBD_ADDRESSED)
            return false;
        otg.config = (uint8_t)s->wValue;
        otg.state = otg.config ? USBD_CONFIGURED : USBD_ADDRESSED;
        otgfs_endpoints_open(otg.config != 0u);
        usbd_class_configured(otg.config != 0u);
        ep0_status_in();
        return true;
    case GET_STATUS:
        if (!in || s->wLength != 2u)
            return false;
        otg.reply[0] = otg.reply[1] = 0u; /* bus powered, no remote wakeup */
        if (recip == RECIP_INTERFACE) {
            if (otg.state != USBD_CONFIGURED || s->wIndex >= N_INTERFACES)
                return false;
        } else if (recip == RECIP_ENDPOINT) {
            uint8_t a = (uint8_t)s->wIndex;
            if (!ep_valid(a))
                return false;
            otg.reply[0] = (a & 0x80u) ? otg.halted_in[a & 0xFu] : otg.halted_out[a & 0xFu];
        } else if (recip != RECIP_DEVICE) {
            return false;
        }
        ep0_send(otg.reply, 2);
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
        if (!in || recip != RECIP_INTERFACE || otg.state != USBD_CONFIGURED
            || s->wIndex >= N_INTERFACES || s->wLength != 1u)
            return false;
        otg.reply[0] = 0u;
        ep0_send(otg.reply, 1);
        return true;
    case SET_INTERFACE:
        if (in || recip != RECIP_INTERFACE || otg.state != USBD_CONFIGURED
            || s->wIndex >= N_INTERFACES || s->wValue != 0u)
            return false;
        ep0_status_in();
        return true;
    default:
        return false;
    }
}

void otgfs_ep0_setup(void)
{
    uint32_t w0 = otg.setup_words[0], w1 = otg.setup_words[1];
    struct usbd_setup *s = &otg.req;
    s->bmRequestType = (uint8_t)w0;
    s->bRequest = (uint8_t)(w0 >> 8);
    s->wValue = (uint16_t)(w0 >> 16);
    s->wIndex = (uint16_t)w1;
    s->wLength = (uint16_t)(w1 >> 16);
    otg.stage = EP0_IDLE;
    otg.in_left = 0;
    otg.in_zlp = false;
    if (OTG_RD(DIEPCTL(0)) & EPCTL_EPENA) {
        /* The host gave up a data stage (a new SETUP always wins, USB 2.0 8.5.3): drop what
         * is still queued for EP0 IN so the new answer does not follow stale bytes. */
        OTG_WR(DIEPCTL(0), OTG_RD(DIEPCTL(0)) | EPCTL_EPDIS | EPCTL_SNAK);
        OTG_WR(GRSTCTL, GRSTCTL_TXFFLSH); /* TXFNUM 0: the EP0 TX FIFO */
        (void)otgfs_wait_bits(GRSTCTL, GRSTCTL_TXFFLSH, 0u);
        OTG_WR(DIEPINT(0), EPINT_EPDISD);
    }
    otgfs_ep0_out_arm();

    if ((s->bmRequestType & REQ_TYPE_MASK) == REQ_TYPE_STANDARD) {
        if (!standard_request(s))
            ep0_stall();
        return;
    }
    const uint8_t *reply = NULL;
    uint16_t len = 0;
    if (otg.state != USBD_CONFIGURED || usbd_class_setup(s, &reply, &len) != 0) {
        ep0_stall();
        return;
    }
    if (s->bmRequestType & REQ_DIR_IN) {
        ep0_send(reply, len);
    } else if (s->wLength > 0u) {
        if (s->wLength > sizeof otg.out_buf) {
            ep0_stall();
            return;
        }
        otg.out_len = 0;
        otg.stage = EP0_DATA_OUT;
    } else {
        ep0_status_in();
    }
}

void otgfs_ep0_in_done(void)
{
    if (otg.stage == EP0_DATA_IN) {
        if (otg.in_left > 0u) {
            uint16_t n = otg.in_left < USBD_EP0_MPS ? otg.in_left : (uint16_t)USBD_EP0_MPS;
            ep0_in_packet(otg.in_ptr, n);
            otg.in_ptr += n;
            otg.in_left = (uint16_t)(otg.in_left - n);
            if (otg.in_left == 0u && n < USBD_EP0_MPS)
                otg.in_zlp = false;
            return;
        }
        if (otg.in_zlp) {
            otg.in_zlp = false;
            ep0_in_packet(NULL, 0);
            return;
        }
        otg.stage = EP0_STATUS_OUT; /* the host's zero-length OUT comes next */
        return;
    }
    otg.stage = EP0_IDLE; /* status IN sent */
}

void otgfs_ep0_out_done(void)
{
    if (otg.stage == EP0_DATA_OUT && otg.out_len >= otg.req.wLength) {
        usbd_class_out_data(&otg.req, otg.out_buf, otg.out_len);
        ep0_status_in();
    } else if (otg.stage == EP0_STATUS_OUT) {
        otg.stage = EP0_IDLE;
    }
    otgfs_ep0_out_arm();
}

