/* The EVK1000's CDC-ACM function (firmware/boards/evk1000/usb/cdc_acm.c) under ASan and UBSan,
 * with the OTG FS driver below it replaced by a scripted fake (the driver itself is tested
 * against the Python OTG FS model in tests/hil/test_usb_link.py): descriptors, class requests,
 * the RX ring's flow control, and the TX ring's accounting across completed transfers, transfers
 * cut by a bus reset, a full ring and a missing host. The file is included with its host-link
 * functions renamed, because this test binary also links the native board's pty link.
 */
#define OTG_HOSTED 1
#define board_link_read cdc_link_read
#define board_link_write cdc_link_write
#include "../../firmware/boards/evk1000/usb/cdc_acm.c"
#undef board_link_read
#undef board_link_write

#include "check.h"

/* ---- the fake driver ------------------------------------------------------------------------- */
static enum usbd_state fake_state = USBD_CONFIGURED;
static bool fake_busy;
static const uint8_t *fake_data;
static size_t fake_len;
static unsigned fake_arms, fake_starts;
static uint8_t host_got[16384];
static size_t host_n;
static int host_reads = 1; /* the host acknowledges each transfer while the writer waits */

enum usbd_state usbd_state(void) { return fake_state; }
bool usbd_suspended(void) { return false; }
uint32_t usbd_irq_save(void) { return 0u; }
void usbd_irq_restore(uint32_t primask) { (void)primask; }
bool usbd_in_busy(uint8_t ep) { return ep == USBD_EP_DATA && fake_busy; }
void usbd_out_arm(uint8_t ep) { (void)ep; fake_arms++; }
int usbd_init(void) { return 0; }
bool usbd_in_start(uint8_t ep, const uint8_t *data, size_t len)
{
    if (ep != USBD_EP_DATA)
        return true; /* the notification */
    if (fake_busy || fake_state != USBD_CONFIGURED || len > USBD_DATA_TX_MAX)
        return false;
    fake_busy = true;
    fake_data = data;
    fake_len = len;
    fake_starts++;
    return true;
}

/* The host takes `sent` bytes of the transfer on the endpoint (all of it: a completion). */
static void host_takes(size_t sent)
{
    if (!fake_busy)
        return;
    memcpy(host_got + host_n, fake_data, sent);
    host_n += sent;
    fake_busy = false;
    usbd_class_in_done(USBD_EP_DATA, sent);
}

void otg_hosted_wait(void)
{
    if (host_reads)
        host_takes(fake_len);
}
uint32_t otg_hosted_read(uint32_t offset) { (void)offset; return 0u; }
void otg_hosted_write(uint32_t offset, uint32_t value) { (void)offset; (void)value; }

static void test_descriptors(void)
{
    uint16_t n = 0;
    const uint8_t *d = usbd_class_descriptor(1, 0, &n);
    CHECK_EQ(n, 18);
    CHECK_EQ(d[8] | d[9] << 8, PROTO_USB_VID);
    CHECK_EQ(d[10] | d[11] << 8, PROTO_USB_PID);
    const uint8_t *c = usbd_class_descriptor(2, 0, &n);
    CHECK_EQ(c[2] | c[3] << 8, n);
    size_t walked = 0, descs = 0;
    while (walked < n && c[walked] >= 2) {
        walked += c[walked];
        descs++;
    }
    CHECK_EQ(walked, n); /* the descriptors tile wTotalLength exactly */
    CHECK_EQ(descs, 11);
    CHECK(usbd_class_descriptor(2, 1, &n) == NULL);
    CHECK(usbd_class_descriptor(6, 0, &n) == NULL); /* DEVICE_QUALIFIER: full speed only */
    CHECK(usbd_class_descriptor(3, 9, &n) == NULL);
    /* serial number: the UID as 24 hex digits in UTF-16LE */
    uint8_t uid[12];
    board_uid(uid);
    const uint8_t *s = usbd_class_descriptor(3, 3, &n);
    CHECK_EQ(n, 2 + 2 * 24);
    CHECK_EQ(s[1], 3);
    static const char hex[] = "0123456789ABCDEF";
    int ok = 1;
    for (unsigned i = 0; i < 12; i++)
        ok &= s[2 + 4 * i] == hex[uid[i] >> 4] && s[4 + 4 * i] == hex[uid[i] & 15] && s[3 + 4 * i] == 0;
    CHECK(ok);
    s = usbd_class_descriptor(3, 2, &n);
    CHECK_EQ(n, 2 + 2 * strlen(PROTO_USB_PRODUCT));
}

static void test_class_requests(void)
{
    const uint8_t *reply = NULL;
    uint16_t len = 0;
    struct usbd_setup set_lc = {0x21, 0x20, 0, 0, 7};
    CHECK_EQ(usbd_class_setup(&set_lc, &reply, &len), 0);
    static const uint8_t lc[7] = {0x00, 0x10, 0x0E, 0x00, 0, 0, 8}; /* 921600 8N1 */
    usbd_class_out_data(&set_lc, lc, 7);
    struct usbd_setup get_lc = {0xA1, 0x21, 0, 0, 7};
    CHECK_EQ(usbd_class_setup(&get_lc, &reply, &len), 0);
    CHECK_MEM(reply, len, lc, 7);
    struct usbd_setup bad_len = {0x21, 0x20, 0, 0, 6};
    CHECK_EQ(usbd_class_setup(&bad_len, &reply, &len), -1);
    struct usbd_setup data_if = {0x21, 0x22, 3, 1, 0};
    CHECK_EQ(usbd_class_setup(&data_if, &reply, &len), -1);
    struct usbd_setup vendor = {0x40, 0x22, 3, 0, 0};
    CHECK_EQ(usbd_class_setup(&vendor, &reply, &len), -1);
    struct usbd_setup encaps = {0xA1, 0x01, 0, 0, 64};
    CHECK_EQ(usbd_class_setup(&encaps, &reply, &len), -1);
    struct usbd_setup dtr = {0x21, 0x22, 3, 0, 0};
    CHECK_EQ(usbd_class_setup(&dtr, &reply, &len), 0);
    CHECK_EQ(cdc_line_state(), 3);
    usbd_class_configured(false);
    CHECK_EQ(cdc_line_state(), 0);
    usbd_class_configured(true);
}

static void test_rx_flow_control(void)
{
    uint8_t pkt[64], out[CDC_RX_RING_SIZE];
    for (unsigned i = 0; i < 64; i++)
        pkt[i] = (uint8_t)i;
    unsigned fits = 0;
    while (usbd_class_rx(pkt, 64))
        fits++;
    /* it says "no room for another packet" before the ring overflows: nothing is dropped */
    CHECK_EQ(fits + 1, CDC_RX_RING_SIZE / 64);
    unsigned arms = fake_arms;
    size_t got = cdc_link_read(out, sizeof out);
    CHECK_EQ(got, CDC_RX_RING_SIZE);
    CHECK(fake_arms > arms); /* the paused endpoint is armed again */
    CHECK_EQ(out[65], 1);
    CHECK(!evk_link_rx_pending());
}

static void test_tx_ring(void)
{
    uint8_t msg[5000];
    uint32_t rng = 11;
    for (size_t i = 0; i < sizeof msg; i++)
        msg[i] = (uint8_t)check_rand(&rng);
    /* 1. a host that reads: everything arrives in order, in transfers of <= 512 bytes */
    host_n = 0;
    CHECK(cdc_link_write(msg, 3000));
    while (fake_busy)
        host_takes(fake_len);
    CHECK_MEM(host_got, host_n, msg, 3000);
    /* 2. a bus reset cuts a transfer after 128 acknowledged bytes: the rest follows once the
     * host configures the device again, with no gap and no repeat */
    host_n = 0;
    host_reads = 0;
    CHECK(cdc_link_write(msg, 1500));
    CHECK(fake_busy);
    fake_state = USBD_DEFAULT;       /* bus reset: the driver reports the cut transfer... */
    host_takes(128);                 /* ...after 128 of its bytes reached the host */
    usbd_class_configured(false);
    CHECK(!fake_busy);               /* nothing starts without a configuration */
    fake_state = USBD_CONFIGURED;
    usbd_class_configured(true);     /* SET_CONFIGURATION: the ring goes on */
    while (fake_busy)
        host_takes(fake_len);
    CHECK_MEM(host_got, host_n, msg, 1500);
    /* 3. a host that never reads: the ring fills, the write gives up (bounded), counts it */
    host_n = 0;
    uint32_t dropped = cdc_tx_dropped();
    CHECK(!cdc_link_write(msg, sizeof msg));
    CHECK_EQ(cdc_tx_dropped() - dropped, sizeof msg - CDC_TX_RING_SIZE);
    CHECK_EQ(cdc_tx_queued(), CDC_TX_RING_SIZE);
    host_reads = 1;
    while (fake_busy)
        host_takes(fake_len);
    CHECK_MEM(host_got, host_n, msg, CDC_TX_RING_SIZE); /* what fitted went out whole */
    /* 4. no host configured: a full ring fails at once, without waiting */
    host_reads = 0;
    fake_state = USBD_DEFAULT;
    usbd_class_configured(false);
    CHECK(cdc_link_write(msg, CDC_TX_RING_SIZE));
    CHECK(!cdc_link_write(msg, 1));
    CHECK_EQ(cdc_tx_queued(), CDC_TX_RING_SIZE);
}

int main(void)
{
    evk_link_init();
    usbd_class_configured(true);
    test_descriptors();
    test_class_requests();
    test_rx_flow_control();
    test_tx_ring();
    return check_summary();
}
