/* DW1000 driver against the transaction-recording fake: SPI headers, 40-bit time, the TX
 * grid, gain octets, init/config writes, delayed TX, late TX (HPDWARN), RX with quality
 * registers, RX error recovery, temperature, bounded waits, SPI failures. */
#include <stdio.h>
#include <string.h>

#include "check.h"
#include "dw1000.h"
#include "dw1000_regs.h"
#include "fake_spi.c"

static struct fake_spi F;
static struct dw_dev D;

static void setup(void) {
    fake_init(&F);
    CHECK(dw_init(&D, &F.ops) == DW_OK);
    struct dw_config cfg;
    dw_config_default(&cfg);
    cfg.tx_antd = 16436;
    cfg.rx_antd = 16400;
    CHECK(dw_configure(&D, &cfg) == DW_OK);
    fake_clear_log(&F);
}

static void test_header(void) {
    uint8_t h[3];
    CHECK(dw_spi_header(h, false, 0x00, 0) == 1 && h[0] == 0x00);
    CHECK(dw_spi_header(h, true, 0x09, 0) == 1 && h[0] == 0x89);
    CHECK(dw_spi_header(h, false, 0x27, 0x28) == 2 && h[0] == 0x67 && h[1] == 0x28);
    CHECK(dw_spi_header(h, true, 0x2D, 0x06) == 2 && h[0] == 0xED && h[1] == 0x06);
    CHECK(dw_spi_header(h, true, 0x27, 0x7F) == 2 && h[1] == 0x7F);
    CHECK(dw_spi_header(h, true, 0x2E, 0x1804) == 3 && h[0] == 0xEE && h[1] == 0x84 && h[2] == 0x30);
    CHECK(dw_spi_header(h, false, 0x2E, 0x0080) == 3 && h[0] == 0x6E && h[1] == 0x80 && h[2] == 0x01);
    CHECK(dw_spi_header(h, false, 0x3F, 0x7FFF) == 3 && h[1] == 0xFF && h[2] == 0xFF);
    CHECK(dw_spi_header(h, false, 0x40, 0) == 0);
    CHECK(dw_spi_header(h, false, 0x00, 0x8000) == 0);
}

static void test_time(void) {
    CHECK(dw_time_add(0xFFFFFFFFFFull, 1) == 0);
    CHECK(dw_time_sub(5, 10) == 0xFFFFFFFFFBull);
    CHECK(dw_time_diff(5, 10) == -5);
    CHECK(dw_time_diff(10, 0xFFFFFFFFF0ull) == 26);
    CHECK(dw_time_diff(0x7FFFFFFFFFull, 0) == 0x7FFFFFFFFFll);
    CHECK(dw_time_diff(0x8000000000ull, 0) == -0x8000000000ll);
    CHECK(dw_us_to_units(5) == 319488u);
    CHECK(dw_us_to_units(1) == 63897u);
    CHECK(dw_us_to_units(1000000) == 63897600000ull);
    CHECK(dw_units_to_us(319488) == 5 && dw_units_to_us(319489) == 6 && dw_units_to_us(0) == 0);
    /* grid and antenna delay, with wrap */
    CHECK(dw_tx_stamp_for(0x12345678FFull, 0) == 0x1234567800ull);
    CHECK(dw_tx_stamp_for(0x12345679FFull, 100) == 0x1234567800ull + 100);
    CHECK(dw_tx_stamp_for(0xFFFFFFFFFFull, 0x300) == 0x100ull);
    CHECK(dw_tx_stamp_for(0x1FFFFFFFFFFull, 0) == 0xFFFFFFFE00ull); /* bits above 40 ignored */
}

static void test_gain(void) {
    CHECK(dw_gain_octet(0, 31) == 0x1F);
    CHECK(dw_gain_octet(6, 0) == 0xC0);
    CHECK(dw_gain_octet(3, 5) == 0x65);
    CHECK(dw_gain_octet(7, 0) == 0xE0);
    CHECK(dw_tx_power_word(0x67) == 0x67676767u);
    setup();
    uint8_t p[4] = {1, 2, 3, 4};
    uint64_t dx = fake_sys_time(&F) + dw_us_to_units(2000);
    CHECK(dw_tx_delayed(&D, p, 4, dx, 0x45) == DW_OK);
    const struct fake_txn *w = fake_last_write(&F, DW_REG_TX_POWER, 0);
    CHECK(w && w->len == 4 && w->data[0] == 0x45 && w->data[1] == 0x45 && w->data[2] == 0x45 && w->data[3] == 0x45);
    CHECK(dw_wait_irq(&D, F.now_us + 5000) == 1);
    struct dw_event ev;
    CHECK(dw_service(&D, &ev) == DW_OK && ev.kind == DW_EV_TX_DONE);
    CHECK(F.txlog[0].gain == 0x45);
    dx = fake_sys_time(&F) + dw_us_to_units(2000);
    CHECK(dw_tx_delayed(&D, p, 4, dx, 0x45) == DW_OK);
    CHECK(fake_count_writes(&F, DW_REG_TX_POWER, 0) == 1); /* unchanged gain: no rewrite */
    CHECK(dw_trx_off(&D) == DW_OK);
    CHECK(dw_tx_delayed(&D, p, 4, fake_sys_time(&F) + dw_us_to_units(2000), 0xC3) == DW_OK);
    CHECK(fake_count_writes(&F, DW_REG_TX_POWER, 0) == 2);
}

static void test_init_config(void) {
    fake_init(&F);
    F.dev_id = 0xDECA0131u;
    F.regs[0][0] = 0x31;
    CHECK(dw_init(&D, &F.ops) == DW_ENODEV);
    fake_init(&F);
    CHECK(dw_init(&D, &F.ops) == DW_OK);
    CHECK(F.resets == 1);
    CHECK(F.log[0].reg == DW_REG_DEV_ID && !F.log[0].write && F.log[0].len == 4);
    CHECK(D.t23 == 0x80);
    CHECK(fake_count_writes(&F, DW_REG_OTP_IF, DW_OTP_CTRL) == 3); /* OTP read, LDE load */
    struct dw_config cfg;
    dw_config_default(&cfg);
    CHECK(cfg.channel == 2 && cfg.prf_mhz == 64 && cfg.preamble_len == 128 && cfg.data_rate == 2);
    cfg.tx_antd = 0x4034;
    cfg.rx_antd = 0x4010;
    CHECK(dw_configure(&D, &cfg) == DW_OK && D.ready);
    CHECK(fake_get_reg(&F, DW_REG_SYS_CFG, 0, 4) == 0x00041200u);
    uint32_t chan = 2u | (2u << 4) | (2u << 18) | (9u << 22) | (9u << 27);
    CHECK(fake_get_reg(&F, DW_REG_CHAN_CTRL, 0, 4) == chan);
    CHECK(fake_get_reg(&F, DW_REG_SYS_MASK, 0, 4) == 0x2427D080u);
    CHECK((fake_get_reg(&F, DW_REG_TX_FCTRL, 0, 5) & ~0x7Full) == ((2u << 13) | (1u << 15) | (2u << 16) | (5u << 18)));
    CHECK(fake_get_reg(&F, DW_REG_TX_ANTD, 0, 2) == 0x4034);
    CHECK(fake_get_reg(&F, DW_REG_LDE_IF, DW_LDE_RXANTD, 2) == 0x4010);
    CHECK(fake_get_reg(&F, DW_REG_DRX_CONF, DW_DRX_TUNE2, 4) == 0x313B006Bu);
    CHECK(fake_get_reg(&F, DW_REG_LDE_IF, DW_LDE_REPC, 2) == 0x28F4); /* code 9 */
    CHECK(fake_get_reg(&F, DW_REG_FS_CTRL, DW_FS_PLLCFG, 4) == 0x08400508u);
    CHECK(fake_get_reg(&F, DW_REG_DRX_CONF, DW_DRX_SFDTOC, 2) == 128 + 1 + 8);
    /* 110 kb/s, PRF 16, channel 5, 1024 */
    cfg.channel = 5;
    cfg.prf_mhz = 16;
    cfg.preamble_len = 1024;
    cfg.data_rate = 0;
    CHECK(dw_configure(&D, &cfg) == DW_OK);
    CHECK(fake_get_reg(&F, DW_REG_SYS_CFG, 0, 4) == (0x00041200u | (1u << 22)));
    CHECK(fake_get_reg(&F, DW_REG_CHAN_CTRL, 0, 4) == (5u | (5u << 4) | (1u << 18) | (3u << 22) | (3u << 27)));
    CHECK(fake_get_reg(&F, DW_REG_LDE_IF, DW_LDE_REPC, 2) == (0x51EA >> 3));
    CHECK(fake_get_reg(&F, DW_REG_DRX_CONF, DW_DRX_TUNE2, 4) == 0x351A009Au);
    /* validation with the offending field index */
    unsigned bad = 99;
    dw_config_default(&cfg);
    CHECK(dw_config_check(&cfg, &bad) == DW_OK && bad == 0xFFFF);
    cfg.channel = 6;
    CHECK(dw_config_check(&cfg, &bad) == DW_EARG && bad == 0);
    dw_config_default(&cfg);
    cfg.prf_mhz = 32;
    CHECK(dw_config_check(&cfg, &bad) == DW_EARG && bad == 1);
    dw_config_default(&cfg);
    cfg.preamble_len = 100;
    CHECK(dw_config_check(&cfg, &bad) == DW_EARG && bad == 2);
    dw_config_default(&cfg);
    cfg.data_rate = 3;
    CHECK(dw_config_check(&cfg, &bad) == DW_EARG && bad == 3);
    dw_config_default(&cfg);
    cfg.preamble_code = 5; /* a PRF16 code at PRF 64 */
    CHECK(dw_config_check(&cfg, &bad) == DW_EARG && bad == 4);
    CHECK(dw_configure(&D, &cfg) == DW_EARG);
}

static void test_delayed_tx(void) {
    setup();
    uint8_t p[20];
    for (int i = 0; i < 20; i++) p[i] = (uint8_t)i;
    uint64_t dx = (fake_sys_time(&F) + dw_us_to_units(1500)) | 0x155; /* low bits ignored */
    uint64_t expect = dw_tx_stamp_for(dx, 16436);
    CHECK(dw_tx_delayed(&D, p, 20, dx, 0x67) == DW_OK);
    CHECK((fake_get_reg(&F, DW_REG_TX_FCTRL, 0, 1) & 0x7F) == 22);
    CHECK(memcmp(F.regs[DW_REG_TX_BUFFER], p, 20) == 0);
    CHECK(fake_get_reg(&F, DW_REG_DX_TIME, 0, 5) == dx);
    const struct fake_txn *c = fake_last_write(&F, DW_REG_SYS_CTRL, 0);
    CHECK(c && c->len == 4 && c->data[0] == 0x06);
    struct dw_event ev;
    CHECK(dw_service(&D, &ev) == DW_OK && ev.kind == DW_EV_NONE); /* not yet */
    uint64_t t0 = F.now_us;
    CHECK(dw_wait_irq(&D, t0 + 10000) == 1);
    CHECK(F.now_us >= t0 + 1499 + F.tx_tail_us && F.now_us <= t0 + 1501 + F.tx_tail_us); /* TXFRS at the frame end */
    CHECK(dw_service(&D, &ev) == DW_OK && ev.kind == DW_EV_TX_DONE && ev.stamp == expect);
    CHECK((fake_status(&F) & DW_ST_TXFRS) == 0); /* cleared */
    CHECK(dw_wait_irq(&D, F.now_us + 100) == 0);
    /* with spi_batch: SYS_STATUS and TX_TIME in one batch, same event */
    fake_enable_batch(&F);
    dx = fake_sys_time(&F) + dw_us_to_units(1500);
    CHECK(dw_tx_delayed(&D, p, 20, dx, 0x67) == DW_OK && dw_wait_irq(&D, F.now_us + 10000) == 1);
    unsigned nb = F.nbatch;
    CHECK(dw_service(&D, &ev) == DW_OK && ev.kind == DW_EV_TX_DONE && ev.stamp == dw_tx_stamp_for(dx, 16436));
    CHECK(F.nbatch == nb + 1);
    F.ops.spi_batch = NULL;
    /* same length again: TX_FCTRL is not rewritten; another length: it is */
    size_t nf = fake_count_writes(&F, DW_REG_TX_FCTRL, 0);
    CHECK(dw_tx_delayed(&D, p, 20, fake_sys_time(&F) + dw_us_to_units(1000), 0x67) == DW_OK);
    CHECK(fake_count_writes(&F, DW_REG_TX_FCTRL, 0) == nf);
    CHECK(dw_trx_off(&D) == DW_OK);
    CHECK(dw_tx_delayed(&D, p, 7, fake_sys_time(&F) + dw_us_to_units(1000), 0x67) == DW_OK);
    CHECK(fake_count_writes(&F, DW_REG_TX_FCTRL, 0) == nf + 1 && (fake_get_reg(&F, DW_REG_TX_FCTRL, 0, 1) & 0x7F) == 9);
    CHECK(dw_trx_off(&D) == DW_OK);
    /* oversize payload refused before touching the chip */
    size_t before = F.ntxn;
    uint8_t big[DW_MAX_PAYLOAD + 1] = {0};
    CHECK(dw_tx_delayed(&D, big, sizeof big, dx, 0x67) == DW_EARG && F.ntxn == before);
}

static void test_late_tx(void) {
    setup();
    uint8_t p[4] = {9, 9, 9, 9};
    uint64_t dx = fake_sys_time(&F) - dw_us_to_units(10); /* already past */
    CHECK(dw_tx_delayed(&D, p, 4, dx, 0x67) == DW_ELATE);
    const struct fake_txn *c = fake_last_write(&F, DW_REG_SYS_CTRL, 0);
    CHECK(c && c->data[0] == DW_SYS_CTRL_TRXOFF);
    CHECK((fake_status(&F) & DW_ST_HPDWARN) == 0);
    CHECK(!F.tx_pending);
    CHECK(dw_wait_irq(&D, F.now_us + 20000) == 0 && F.ntx == 0); /* nothing is ever sent */
    /* too close for the chip (fake's minimum lead): refused the same way */
    F.late_lead_units = dw_us_to_units(200);
    dx = fake_sys_time(&F) + dw_us_to_units(100);
    CHECK(dw_tx_delayed(&D, p, 4, dx, 0x67) == DW_ELATE);
    /* and the next good one works */
    dx = fake_sys_time(&F) + dw_us_to_units(1000);
    CHECK(dw_tx_delayed(&D, p, 4, dx, 0x67) == DW_OK);
    CHECK(dw_wait_irq(&D, F.now_us + 5000) == 1 && F.ntx == 1);
}

static void test_rx(void) {
    setup();
    uint8_t p[10] = {0xC5, 1, 2, 3, 4, 5, 6, 7, 8, 9};
    struct fake_rx *r = fake_add_rx(&F, F.now_us + 300, p, 10, 0xFFFFFFFF00ull);
    r->cir_pwr = 0x1234;
    r->rxpacc = 0x7AB; /* 12 bits */
    r->rxpacc_nosat = 0x7AC;
    r->fp_ampl1 = 1111;
    r->fp_ampl2 = 2222;
    r->fp_ampl3 = 3333;
    r->std_noise = 44;
    r->fp_index = 0x2F40;
    r->car_int_raw = 0x1FFFFF; /* -1 in 21 bits */
    r->ttcko_raw = 0xFFF40000; /* RXTOFS = -262144 (bit 18 set), upper bits ignored */
    r->ttcki = 0x01F00000;
    CHECK(dw_rx_enable(&D) == DW_OK && F.rx_on);
    CHECK(dw_wait_irq(&D, F.now_us + 1000) == 1);
    struct dw_event ev;
    CHECK(dw_service(&D, &ev) == DW_OK && ev.kind == DW_EV_RX_GOOD);
    CHECK(ev.len == 10 && memcmp(ev.data, p, 10) == 0);
    CHECK(ev.stamp == 0xFFFFFFFF00ull);
    CHECK(ev.q.cir_pwr == 0x1234 && ev.q.rxpacc == 0x7AB && ev.q.rxpacc_nosat == 0x7AC);
    CHECK(ev.q.fp_ampl1 == 1111 && ev.q.fp_ampl2 == 2222 && ev.q.fp_ampl3 == 3333);
    CHECK(ev.q.std_noise == 44 && ev.q.fp_index == 0x2F40);
    CHECK(ev.q.car_int == -1 && ev.q.ttcko == -262144 && ev.q.ttcki == 0x01F00000u);
    CHECK((fake_status(&F) & DW_RX_GOOD_CLR) == 0);
    r = fake_add_rx(&F, F.now_us + 300, p, 10, 5);
    r->car_int_raw = 0x0FFFFF; /* largest positive */
    r->ttcko_raw = 0x3FFFF;
    CHECK(dw_rx_enable(&D) == DW_OK && dw_wait_irq(&D, F.now_us + 1000) == 1);
    CHECK(dw_service(&D, &ev) == DW_OK && ev.kind == DW_EV_RX_GOOD);
    CHECK(ev.q.car_int == 0x0FFFFF && ev.q.ttcko == 0x3FFFF);
    /* the same through a board that offers spi_batch: one batch per frame, same values */
    fake_enable_batch(&F);
    r = fake_add_rx(&F, F.now_us + 300, p, 10, 77);
    r->car_int_raw = 0x100000; /* most negative */
    r->fp_ampl3 = 4444;
    CHECK(dw_rx_enable(&D) == DW_OK && dw_wait_irq(&D, F.now_us + 1000) == 1);
    CHECK(dw_service(&D, &ev) == DW_OK && ev.kind == DW_EV_RX_GOOD && F.nbatch == 2); /* status, then the frame */
    CHECK(ev.len == 10 && memcmp(ev.data, p, 10) == 0 && ev.stamp == 77);
    CHECK(ev.q.car_int == -1048576 && ev.q.fp_ampl3 == 4444 && ev.q.rxpacc == 120 && ev.q.cir_pwr == 1000);
    F.ops.spi_batch = NULL;
    /* a frame while the receiver is off is not seen */
    fake_add_rx(&F, F.now_us + 100, p, 10, 6);
    CHECK(dw_wait_irq(&D, F.now_us + 1000) == 0 && F.rx_missed == 1);
}

static void test_rx_error(void) {
    setup();
    fake_add_rx_error(&F, F.now_us + 100);
    CHECK(dw_rx_enable(&D) == DW_OK);
    CHECK(dw_wait_irq(&D, F.now_us + 1000) == 1);
    fake_clear_log(&F);
    struct dw_event ev;
    CHECK(dw_service(&D, &ev) == DW_OK && ev.kind == DW_EV_RX_ERROR);
    /* SYS_STATUS read, TRXOFF, clear, RX reset 0xE0/0xF0, RXENAB */
    CHECK(F.nlog == 6);
    CHECK(F.log[1].reg == DW_REG_SYS_CTRL && F.log[1].data[0] == DW_SYS_CTRL_TRXOFF);
    CHECK(F.log[2].reg == DW_REG_SYS_STATUS && fake_get_reg(&F, 0, 0, 0) == 0);
    uint32_t clr = (uint32_t)F.log[2].data[0] | ((uint32_t)F.log[2].data[1] << 8) |
                   ((uint32_t)F.log[2].data[2] << 16) | ((uint32_t)F.log[2].data[3] << 24);
    CHECK(clr == 0x2437FF00u);
    CHECK(F.log[3].reg == DW_REG_PMSC && F.log[3].off == 3 && F.log[3].data[0] == 0xE0);
    CHECK(F.log[4].reg == DW_REG_PMSC && F.log[4].off == 3 && F.log[4].data[0] == 0xF0);
    CHECK(F.log[5].reg == DW_REG_SYS_CTRL && F.log[5].data[0] == 0x00 && F.log[5].data[1] == 0x01);
    CHECK(F.rx_on && (fake_status(&F) & DW_ST_RX_ERR) == 0);
}

static void test_temp_and_wait(void) {
    setup();
    F.regs[DW_REG_TX_CAL][DW_TC_SARL + 1] = 0x85;
    int16_t t = 0;
    /* The user manual's own numbers (6.4, Measuring IC temperature and voltage), not the shared
     * constant: T = (SAR_LTEMP - OTP Vtemp@23C) x 1.14 + 23 degC. t23 = 0x80 here. */
    CHECK(dw_read_temp(&D, &t) == DW_OK && t == 2870); /* +5 LSB: 23 + 5.70 degC */
    F.regs[DW_REG_TX_CAL][DW_TC_SARL + 1] = 0x7E;
    CHECK(dw_read_temp(&D, &t) == DW_OK && t == 2072); /* -2 LSB: 23 - 2.28 degC */
    CHECK(fake_get_reg(&F, DW_REG_TX_CAL, DW_TC_SARC, 1) == 0); /* SAR left off */
    D.t23 = 0; /* uncalibrated chip */
    CHECK(dw_read_temp(&D, &t) == DW_OK && t == INT16_MIN);
    uint64_t t0 = F.now_us;
    CHECK(dw_wait_irq(&D, t0 + 777) == 0 && F.now_us == t0 + 777);
    CHECK(dw_wait_irq(&D, t0) == 0 && F.now_us == t0 + 777); /* a past deadline returns at once */
}

static void test_spi_fail(void) {
    setup();
    F.fail_at = (long)F.ntxn + 2;
    uint8_t p[4] = {0};
    CHECK(dw_tx_delayed(&D, p, 4, fake_sys_time(&F) + dw_us_to_units(1000), 0x11) == DW_ESPI);
    CHECK(D.spi_errors == 1);
    struct dw_dev none;
    CHECK(dw_init(&none, NULL) == DW_EARG);
    struct dw_dev fresh;
    memset(&fresh, 0, sizeof fresh);
    fresh.ops = &F.ops;
    CHECK(dw_rx_enable(&fresh) == DW_ENOTREADY);
}

static void test_frame_time(void) {
    struct dw_config cfg;
    dw_config_default(&cfg);
    uint32_t us = dw_frame_us(&cfg, 20);
    /* 136 symbols of 1017.63 ns + PHR 21.5 us + (176 + 48) bits of 128.21 ns: about 189 us */
    CHECK(us >= 185 && us <= 192);
    cfg.data_rate = 0;
    cfg.preamble_len = 1024;
    CHECK(dw_frame_us(&cfg, 20) > 2500);
}

int main(void) {
    test_header();
    test_time();
    test_gain();
    test_init_config();
    test_delayed_tx();
    test_late_tx();
    test_rx();
    test_rx_error();
    test_temp_and_wait();
    test_spi_fail();
    test_frame_time();
    return check_summary();
}
