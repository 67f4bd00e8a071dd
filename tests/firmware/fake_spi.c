/* See fake_spi.h. */
#include "fake_spi.h"

#include <string.h>

#include "dw1000_regs.h"

static struct fake_spi *g_clock_fake;

void fake_use_clock(struct fake_spi *f) { g_clock_fake = f; }
uint64_t fake_clock_us(void) { return g_clock_fake ? g_clock_fake->now_us : 0; }

uint64_t fake_units_at(const struct fake_spi *f, uint64_t t_us) {
    return (f->sys_offset + t_us * 319488u / 5u) & DW_TIME_MASK;
}

uint64_t fake_sys_time(const struct fake_spi *f) { return fake_units_at(f, f->now_us) & ~(uint64_t)0x1FF; }

void fake_set_reg(struct fake_spi *f, uint8_t reg, uint16_t off, uint64_t v, size_t n) {
    for (size_t i = 0; i < n; i++) f->regs[reg][off + i] = (uint8_t)(v >> (8 * i));
}

uint64_t fake_get_reg(const struct fake_spi *f, uint8_t reg, uint16_t off, size_t n) {
    uint64_t v = 0;
    for (size_t i = 0; i < n; i++) v |= (uint64_t)f->regs[reg][off + i] << (8 * i);
    return v;
}

uint32_t fake_status(const struct fake_spi *f) { return (uint32_t)fake_get_reg(f, DW_REG_SYS_STATUS, 0, 4); }

static void set_status(struct fake_spi *f, uint32_t bits) {
    fake_set_reg(f, DW_REG_SYS_STATUS, 0, fake_status(f) | bits, 4);
}

static bool irq(const struct fake_spi *f) {
    return (fake_status(f) & (uint32_t)fake_get_reg(f, DW_REG_SYS_MASK, 0, 4)) != 0;
}

static void chip_reset(struct fake_spi *f) {
    memset(f->regs, 0, sizeof f->regs);
    fake_set_reg(f, DW_REG_DEV_ID, 0, f->dev_id, 4);
    f->regs[DW_REG_OTP_IF][DW_OTP_RDAT + 1] = f->otp_t23;
    f->tx_pending = false;
    f->rx_on = false;
}

static uint64_t us_after_units(uint64_t units) { return (units * 5u + 319487u) / 319488u; }

static void sys_ctrl(struct fake_spi *f, uint32_t v) {
    if (v & DW_SYS_CTRL_TRXOFF) {
        f->tx_pending = false;
        f->rx_on = false;
    }
    if (v & DW_SYS_CTRL_TXSTRT) {
        struct fake_tx *t = &f->cur;
        memset(t, 0, sizeof *t);
        size_t flen = fake_get_reg(f, DW_REG_TX_FCTRL, 0, 1) & 0x7F;
        t->len = (uint8_t)(flen >= 2 ? flen - 2 : 0);
        memcpy(t->data, f->regs[DW_REG_TX_BUFFER], t->len);
        t->gain = f->regs[DW_REG_TX_POWER][2];
        uint16_t antd = (uint16_t)fake_get_reg(f, DW_REG_TX_ANTD, 0, 2);
        if (v & DW_SYS_CTRL_TXDLYS) {
            uint64_t dx = fake_get_reg(f, DW_REG_DX_TIME, 0, 5) & ~(uint64_t)0x1FF;
            uint64_t delta = (dx - fake_sys_time(f)) & DW_TIME_MASK;
            bool refused = f->refuse_tx >= 0 && (size_t)f->refuse_tx == f->ndelayed;
            f->ndelayed++;
            if (delta >= DW_TIME_HALF || delta < f->late_lead_units || refused) {
                set_status(f, DW_ST_HPDWARN);
                return; /* pending forever until TRXOFF: never sent */
            }
            t->at_us = f->now_us + us_after_units(delta);
            t->stamp = (dx + antd) & DW_TIME_MASK;
        } else {
            t->at_us = f->now_us + 200;
            t->stamp = ((fake_units_at(f, t->at_us) & ~(uint64_t)0x1FF) + antd) & DW_TIME_MASK;
        }
        f->tx_pending = true;
    }
    if (v & DW_SYS_CTRL_RXENAB) f->rx_on = true;
}

static int op_spi(void *ctx, const uint8_t *hdr, size_t hdr_len, const uint8_t *tx, uint8_t *rx, size_t len) {
    struct fake_spi *f = ctx;
    long n = (long)f->ntxn++;
    if (hdr_len < 1 || hdr_len > 3 || len > 128) return -1;
    bool write = (hdr[0] & 0x80) != 0;
    uint8_t reg = hdr[0] & 0x3F;
    uint16_t off = 0;
    size_t want = 1;
    if (hdr[0] & 0x40) {
        if (hdr_len < 2) return -1;
        if (hdr[1] & 0x80) {
            if (hdr_len < 3) return -1;
            off = (uint16_t)((hdr[1] & 0x7F) | (hdr[2] << 7));
            want = 3;
        } else {
            off = hdr[1];
            want = 2;
        }
    }
    if (want != hdr_len || write != (tx != NULL) || (!write && rx == NULL)) return -1;
    if (off + len > FAKE_REG_BYTES) return -1;
    if (f->nlog < FAKE_LOG_CAP) {
        struct fake_txn *l = &f->log[f->nlog++];
        l->write = write;
        l->reg = reg;
        l->off = off;
        memcpy(l->hdr, hdr, hdr_len);
        l->hdr_len = hdr_len;
        l->len = len;
        if (write) memcpy(l->data, tx, len);
    }
    if (f->fail_at >= 0 && n == f->fail_at) return -1;
    if (!write) {
        if (reg == DW_REG_SYS_TIME) fake_set_reg(f, DW_REG_SYS_TIME, 0, fake_sys_time(f), 5);
        memcpy(rx, &f->regs[reg][off], len);
        if (reg == DW_REG_SYS_CTRL) memset(rx, 0, len);
        return 0;
    }
    if (reg == DW_REG_SYS_STATUS) {
        for (size_t i = 0; i < len; i++) f->regs[reg][off + i] &= (uint8_t)~tx[i];
        return 0;
    }
    if (reg == DW_REG_SYS_CTRL) {
        uint32_t v = 0;
        for (size_t i = 0; i < len && i < 4; i++) v |= (uint32_t)tx[i] << (8 * (off + i));
        sys_ctrl(f, v);
        return 0;
    }
    memcpy(&f->regs[reg][off], tx, len);
    return 0;
}

static void apply_tx(struct fake_spi *f) {
    f->tx_pending = false;
    set_status(f, DW_TX_DONE_CLR);
    fake_set_reg(f, DW_REG_TX_TIME, 0, (f->cur.stamp + f->tx_time_skew) & DW_TIME_MASK, 5);
    if (f->ntx < FAKE_TXLOG_CAP) f->txlog[f->ntx] = f->cur;
    f->ntx++;
    if (f->on_tx) f->on_tx(f, &f->cur);
}

static void apply_rx(struct fake_spi *f) {
    struct fake_rx *r = &f->rxq[f->rx_head++];
    if (!f->rx_on) {
        f->rx_missed++;
        return;
    }
    f->rx_on = false;
    if (r->error) {
        set_status(f, DW_ST_RXPHE);
        return;
    }
    fake_set_reg(f, DW_REG_RX_FINFO, 0, (uint32_t)(r->len + 2) | ((uint32_t)r->rxpacc << 20), 4);
    memcpy(f->regs[DW_REG_RX_BUFFER], r->data, r->len);
    fake_set_reg(f, DW_REG_RX_TIME, 0, r->stamp, 5);
    fake_set_reg(f, DW_REG_RX_TIME, 5, r->fp_index, 2);
    fake_set_reg(f, DW_REG_RX_TIME, 7, r->fp_ampl1, 2);
    fake_set_reg(f, DW_REG_RX_FQUAL, 0, r->std_noise, 2);
    fake_set_reg(f, DW_REG_RX_FQUAL, 2, r->fp_ampl2, 2);
    fake_set_reg(f, DW_REG_RX_FQUAL, 4, r->fp_ampl3, 2);
    fake_set_reg(f, DW_REG_RX_FQUAL, 6, r->cir_pwr, 2);
    fake_set_reg(f, DW_REG_DRX_CONF, DW_DRX_RXPACC_NOSAT, r->rxpacc_nosat, 2);
    fake_set_reg(f, DW_REG_DRX_CONF, DW_DRX_CAR_INT, r->car_int_raw, 3);
    fake_set_reg(f, DW_REG_RX_TTCKI, 0, r->ttcki, 4);
    fake_set_reg(f, DW_REG_RX_TTCKO, 0, r->ttcko_raw, 4);
    set_status(f, DW_RX_GOOD_CLR);
}

/* Earliest pending event time; false when none. */
static bool next_event(const struct fake_spi *f, uint64_t *t, int *which) {
    bool any = false;
    if (f->tx_pending) {
        *t = f->cur.at_us + f->tx_tail_us;
        *which = 0;
        any = true;
    }
    if (f->rx_head < f->nrx && (!any || f->rxq[f->rx_head].at_us < *t)) {
        *t = f->rxq[f->rx_head].at_us;
        *which = 1;
        any = true;
    }
    return any;
}

static void advance_to(struct fake_spi *f, uint64_t t) {
    if (t > f->now_us) {
        if (t - f->now_us > f->max_wait_step_us) f->max_wait_step_us = t - f->now_us;
        f->now_us = t;
    }
}

static void run_until(struct fake_spi *f, uint64_t deadline, bool stop_on_irq) {
    uint64_t t;
    int which;
    while (!(stop_on_irq && irq(f)) && next_event(f, &t, &which) && t <= deadline) {
        advance_to(f, t);
        if (which == 0) apply_tx(f);
        else apply_rx(f);
    }
}

static int op_wait_irq(void *ctx, uint64_t deadline_us) {
    struct fake_spi *f = ctx;
    run_until(f, deadline_us, true);
    if (irq(f)) return 1;
    advance_to(f, deadline_us);
    return 0;
}

static int op_reset(void *ctx) {
    struct fake_spi *f = ctx;
    f->resets++;
    chip_reset(f);
    return 0;
}

static void op_delay(void *ctx, uint32_t us) {
    struct fake_spi *f = ctx;
    run_until(f, f->now_us + us, false);
    advance_to(f, f->now_us + us);
}

static void op_speed(void *ctx, int fast) {
    (void)ctx;
    (void)fast;
}

static int op_batch(void *ctx, const struct dw_spi_xfer *x, size_t n) {
    struct fake_spi *f = ctx;
    f->nbatch++;
    for (size_t i = 0; i < n; i++)
        if (op_spi(ctx, x[i].hdr, x[i].hdr_len, x[i].tx, x[i].rx, x[i].len) < 0) return -1;
    return 0;
}

void fake_enable_batch(struct fake_spi *f) { f->ops.spi_batch = op_batch; }

void fake_init(struct fake_spi *f) {
    memset(f, 0, sizeof *f);
    f->ops.ctx = f;
    f->ops.spi_transfer = op_spi;
    f->ops.wait_irq = op_wait_irq;
    f->ops.reset = op_reset;
    f->ops.delay_us = op_delay;
    f->ops.spi_speed = op_speed;
    f->dev_id = DW1000_DEV_ID_VALUE;
    f->fail_at = -1;
    f->refuse_tx = -1;
    f->now_us = 1000;
    f->otp_t23 = 0x80;
    f->tx_tail_us = 50;
    chip_reset(f);
}

struct fake_rx *fake_add_rx(struct fake_spi *f, uint64_t at_us, const uint8_t *data, size_t len, uint64_t stamp) {
    if (f->nrx >= FAKE_RXQ_CAP) return NULL;
    struct fake_rx *r = &f->rxq[f->nrx++];
    memset(r, 0, sizeof *r);
    r->at_us = at_us;
    memcpy(r->data, data, len);
    r->len = (uint8_t)len;
    r->stamp = stamp & DW_TIME_MASK;
    r->rxpacc = 120;
    r->rxpacc_nosat = 120;
    r->cir_pwr = 1000;
    return r;
}

void fake_add_rx_error(struct fake_spi *f, uint64_t at_us) {
    if (f->nrx >= FAKE_RXQ_CAP) return;
    struct fake_rx *r = &f->rxq[f->nrx++];
    memset(r, 0, sizeof *r);
    r->at_us = at_us;
    r->error = true;
}

const struct fake_txn *fake_last_write(const struct fake_spi *f, uint8_t reg, uint16_t off) {
    for (size_t i = f->nlog; i-- > 0;)
        if (f->log[i].write && f->log[i].reg == reg && f->log[i].off == off) return &f->log[i];
    return NULL;
}

size_t fake_count_writes(const struct fake_spi *f, uint8_t reg, uint16_t off) {
    size_t n = 0;
    for (size_t i = 0; i < f->nlog; i++)
        if (f->log[i].write && f->log[i].reg == reg && f->log[i].off == off) n++;
    return n;
}

void fake_clear_log(struct fake_spi *f) { f->nlog = 0; }
