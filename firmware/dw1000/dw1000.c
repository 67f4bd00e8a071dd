/* DW1000 driver: see dw1000.h and REGISTERS.md (the register subset and sequences). */
#include "dw1000.h"

#include <string.h>

#include "dw1000_facts.h"
#include "dw1000_regs.h"

/* ---- SPI ---------------------------------------------------------------------------- */

size_t dw_spi_header(uint8_t hdr[3], bool write, uint8_t reg, uint16_t off) {
    if (reg > 0x3F || off > 0x7FFF) return 0;
    uint8_t b0 = (uint8_t)((write ? 0x80u : 0u) | reg);
    if (off == 0) {
        hdr[0] = b0;
        return 1;
    }
    hdr[0] = (uint8_t)(b0 | 0x40u);
    if (off <= 0x7F) {
        hdr[1] = (uint8_t)off;
        return 2;
    }
    hdr[1] = (uint8_t)(0x80u | (off & 0x7Fu));
    hdr[2] = (uint8_t)(off >> 7);
    return 3;
}

static int xfer(struct dw_dev *d, bool write, uint8_t reg, uint16_t off, const uint8_t *tx,
                uint8_t *rx, size_t len) {
    uint8_t hdr[3];
    size_t hl = dw_spi_header(hdr, write, reg, off);
    if (hl == 0 || d->ops == NULL || d->ops->spi_transfer == NULL) return DW_EARG;
    if (d->ops->spi_transfer(d->ops->ctx, hdr, hl, tx, rx, len) < 0) {
        d->spi_errors++;
        return DW_ESPI;
    }
    return DW_OK;
}

/* A batch of reads, each described by (reg, off, buf, len): one ops->spi_batch call when the
 * board has it (the tunnel pipelines it), else one spi_transfer each. */
struct dw_rd {
    uint8_t reg;
    uint16_t off;
    uint8_t *buf;
    size_t len;
};

static int read_batch(struct dw_dev *d, const struct dw_rd *r, size_t n) {
    uint8_t hdr[8][3];
    struct dw_spi_xfer x[8];
    if (n > 8 || d->ops == NULL) return DW_EARG;
    if (d->ops->spi_batch == NULL) {
        for (size_t i = 0; i < n; i++) {
            int rc = xfer(d, false, r[i].reg, r[i].off, NULL, r[i].buf, r[i].len);
            if (rc != DW_OK) return rc;
        }
        return DW_OK;
    }
    for (size_t i = 0; i < n; i++) {
        x[i].hdr = hdr[i];
        x[i].hdr_len = dw_spi_header(hdr[i], false, r[i].reg, r[i].off);
        if (x[i].hdr_len == 0) return DW_EARG;
        x[i].tx = NULL;
        x[i].rx = r[i].buf;
        x[i].len = r[i].len;
    }
    if (d->ops->spi_batch(d->ops->ctx, x, n) < 0) {
        d->spi_errors++;
        return DW_ESPI;
    }
    return DW_OK;
}

int dw_read(struct dw_dev *d, uint8_t reg, uint16_t off, uint8_t *buf, size_t len) {
    return xfer(d, false, reg, off, NULL, buf, len);
}

int dw_write(struct dw_dev *d, uint8_t reg, uint16_t off, const uint8_t *buf, size_t len) {
    return xfer(d, true, reg, off, buf, NULL, len);
}

static void put_le(uint8_t *b, uint64_t v, size_t n) {
    for (size_t i = 0; i < n; i++) b[i] = (uint8_t)(v >> (8 * i));
}

static uint64_t get_le(const uint8_t *b, size_t n) {
    uint64_t v = 0;
    for (size_t i = 0; i < n; i++) v |= (uint64_t)b[i] << (8 * i);
    return v;
}

int dw_read32(struct dw_dev *d, uint8_t reg, uint16_t off, uint32_t *v) {
    uint8_t b[4];
    int rc = dw_read(d, reg, off, b, 4);
    *v = rc == DW_OK ? (uint32_t)get_le(b, 4) : 0;
    return rc;
}

int dw_read40(struct dw_dev *d, uint8_t reg, uint16_t off, uint64_t *v) {
    uint8_t b[5];
    int rc = dw_read(d, reg, off, b, 5);
    *v = rc == DW_OK ? get_le(b, 5) : 0;
    return rc;
}

int dw_write32(struct dw_dev *d, uint8_t reg, uint16_t off, uint32_t v) {
    uint8_t b[4];
    put_le(b, v, 4);
    return dw_write(d, reg, off, b, 4);
}

int dw_write40(struct dw_dev *d, uint8_t reg, uint16_t off, uint64_t v) {
    uint8_t b[5];
    put_le(b, v, 5);
    return dw_write(d, reg, off, b, 5);
}

int dw_write16(struct dw_dev *d, uint8_t reg, uint16_t off, uint16_t v) {
    uint8_t b[2];
    put_le(b, v, 2);
    return dw_write(d, reg, off, b, 2);
}

int dw_write8(struct dw_dev *d, uint8_t reg, uint16_t off, uint8_t v) {
    return dw_write(d, reg, off, &v, 1);
}

/* ---- time ----------------------------------------------------------------------------- */

int64_t dw_time_diff(uint64_t a, uint64_t b) {
    uint64_t u = dw_time_sub(a, b);
    return u >= DW_TIME_HALF ? (int64_t)u - (int64_t)(DW_TIME_MASK + 1) : (int64_t)u;
}

uint64_t dw_us_to_units(uint64_t us) { return us * DW_UNITS_PER_US_NUM / DW_UNITS_PER_US_DEN; }

uint64_t dw_units_to_us(uint64_t units) {
    return (units * DW_UNITS_PER_US_DEN + DW_UNITS_PER_US_NUM - 1) / DW_UNITS_PER_US_NUM;
}

uint64_t dw_tx_stamp_for(uint64_t dx, uint16_t tx_antd) {
    return dw_time_add(dx & DW_TIME_MASK & ~DW_DX_GRID_MASK, tx_antd);
}

/* ---- configuration tables (user manual tables, as in Decawave's driver) --------------- */

static int chan_index(uint8_t ch) {
    switch (ch) {
    case 1: return 0;
    case 2: return 1;
    case 3: return 2;
    case 4: return 3;
    case 5: return 4;
    case 7: return 5;
    default: return -1;
    }
}

static const uint32_t k_rf_txctrl[6] = {0x00005C40, 0x00045CA0, 0x00086CC0,
                                        0x00045C80, 0x001E3FE0, 0x001E7DE0};
static const uint8_t k_pgdelay[6] = {0xC9, 0xC2, 0xC5, 0x95, 0xC0, 0x93};
static const uint32_t k_pllcfg[6] = {0x09000407, 0x08400508, 0x08401009,
                                     0x08400508, 0x0800041D, 0x0800041D};
static const uint8_t k_plltune[6] = {0x1E, 0x26, 0x56, 0x26, 0xBE, 0xBE};
static const uint8_t k_code16[6] = {1, 3, 5, 7, 3, 7};
static const uint8_t k_code64[6] = {9, 9, 9, 17, 9, 17};
static const uint16_t k_lde_repc[24] = {
    0x5998, 0x5998, 0x51EA, 0x428E, 0x451E, 0x2E14, 0x8000, 0x51EA, 0x28F4, 0x3332, 0x3AE0, 0x3D70,
    0x3AE0, 0x35C2, 0x2B84, 0x35C2, 0x3332, 0x35C2, 0x35C2, 0x47AE, 0x3AE0, 0x3850, 0x30A2, 0x3850};

/* TX_FCTRL TXPSR|PE<<2 (4 bits at bit 18) for a preamble length; 0 if invalid. */
static uint32_t psr_pe(uint16_t plen) {
    switch (plen) {
    case 64: return 0x1;
    case 128: return 0x5;
    case 256: return 0x9;
    case 512: return 0xD;
    case 1024: return 0x2;
    case 1536: return 0x6;
    case 2048: return 0xA;
    case 4096: return 0x3;
    default: return 0;
    }
}

void dw_config_default(struct dw_config *cfg) {
    cfg->channel = 2;
    cfg->prf_mhz = 64;
    cfg->preamble_len = 128;
    cfg->data_rate = 2;
    cfg->preamble_code = 0;
    cfg->tx_antd = 0;
    cfg->rx_antd = 0;
}

static uint8_t effective_code(const struct dw_config *cfg) {
    int ci = chan_index(cfg->channel);
    if (cfg->preamble_code != 0 || ci < 0) return cfg->preamble_code;
    return cfg->prf_mhz == 16 ? k_code16[ci] : k_code64[ci];
}

int dw_config_check(const struct dw_config *cfg, unsigned *bad_field) {
    unsigned bad = 0xFFFF;
    int ci = chan_index(cfg->channel);
    if (ci < 0) bad = 0;
    else if (cfg->prf_mhz != 16 && cfg->prf_mhz != 64) bad = 1;
    else if (psr_pe(cfg->preamble_len) == 0) bad = 2;
    else if (cfg->data_rate > 2) bad = 3;
    else if (cfg->preamble_code != 0) {
        uint8_t c = cfg->preamble_code;
        bool ok = cfg->prf_mhz == 16 ? (c >= 1 && c <= 8) : (c >= 9 && c <= 24);
        if (!ok) bad = 4;
    }
    if (bad_field) *bad_field = bad;
    return bad == 0xFFFF ? DW_OK : DW_EARG;
}

/* ---- init and configure -------------------------------------------------------------- */

#define TRY(x)                          \
    do {                                \
        int rc_ = (x);                  \
        if (rc_ != DW_OK) return rc_;   \
    } while (0)

int dw_init(struct dw_dev *d, const struct dw_ops *ops) {
    memset(d, 0, sizeof *d);
    d->ops = ops;
    if (ops == NULL || ops->spi_transfer == NULL || ops->wait_irq == NULL) return DW_EARG;
    if (ops->spi_speed) ops->spi_speed(ops->ctx, 0);
    if (ops->reset && ops->reset(ops->ctx) < 0) return DW_ERESET;
    TRY(dw_read32(d, DW_REG_DEV_ID, 0, &d->dev_id));
    if (d->dev_id != DW1000_DEV_ID_VALUE) return DW_ENODEV;
    TRY(dw_write32(d, DW_REG_SYS_STATUS, 0, 0xFFFFFFFFu));
    /* OTP address 0x009: temperature and voltage readings at calibration */
    uint32_t otp = 0;
    TRY(dw_write16(d, DW_REG_OTP_IF, DW_OTP_ADDR, 0x0009));
    TRY(dw_write16(d, DW_REG_OTP_IF, DW_OTP_CTRL, 0x0003));
    TRY(dw_write16(d, DW_REG_OTP_IF, DW_OTP_CTRL, 0x0000));
    TRY(dw_read32(d, DW_REG_OTP_IF, DW_OTP_RDAT, &otp));
    d->t23 = (uint8_t)(otp >> 8);
    /* LDE microcode load */
    TRY(dw_write16(d, DW_REG_PMSC, DW_PMSC_CTRL0, 0x0301));
    TRY(dw_write16(d, DW_REG_OTP_IF, DW_OTP_CTRL, 0x8000));
    if (ops->delay_us) ops->delay_us(ops->ctx, 150);
    TRY(dw_write16(d, DW_REG_PMSC, DW_PMSC_CTRL0, 0x0200));
    if (ops->spi_speed) ops->spi_speed(ops->ctx, 1);
    TRY(dw_write32(d, DW_REG_SYS_CTRL, 0, DW_SYS_CTRL_TRXOFF));
    return DW_OK;
}

int dw_configure(struct dw_dev *d, const struct dw_config *cfg) {
    unsigned bad;
    if (d->ops == NULL || d->dev_id != DW1000_DEV_ID_VALUE) return DW_ENOTREADY;
    if (dw_config_check(cfg, &bad) != DW_OK) return DW_EARG;
    d->ready = false;
    int ci = chan_index(cfg->channel);
    bool p64 = cfg->prf_mhz == 64;
    uint32_t prf = p64 ? 2u : 1u;
    uint32_t code = effective_code(cfg);
    uint16_t plen = cfg->preamble_len;
    uint8_t rate = cfg->data_rate;

    TRY(dw_write32(d, DW_REG_SYS_CTRL, 0, DW_SYS_CTRL_TRXOFF));
    uint32_t syscfg = DW_SYS_CFG_HIRQ_POL | DW_SYS_CFG_DIS_DRXB | DW_SYS_CFG_DIS_STXP |
                      (rate == 0 ? DW_SYS_CFG_RXM110K : 0u);
    TRY(dw_write32(d, DW_REG_SYS_CFG, 0, syscfg));
    uint32_t chan = (uint32_t)cfg->channel | ((uint32_t)cfg->channel << 4) | (prf << 18) |
                    (code << 22) | (code << 27);
    TRY(dw_write32(d, DW_REG_CHAN_CTRL, 0, chan));
    d->tx_fctrl = ((uint32_t)rate << 13) | DW_TX_FCTRL_TR | (prf << 16) | (psr_pe(plen) << 18);
    d->tx_len = 0;
    TRY(dw_write40(d, DW_REG_TX_FCTRL, 0, d->tx_fctrl | 2u));

    TRY(dw_write16(d, DW_REG_AGC_CTRL, DW_AGC_TUNE1, p64 ? 0x889B : 0x8870));
    TRY(dw_write32(d, DW_REG_AGC_CTRL, DW_AGC_TUNE2, 0x2502A907));
    TRY(dw_write16(d, DW_REG_AGC_CTRL, DW_AGC_TUNE3, 0x0035));
    TRY(dw_write16(d, DW_REG_DRX_CONF, DW_DRX_TUNE0B, rate == 0 ? 0x000A : 0x0001));
    TRY(dw_write16(d, DW_REG_DRX_CONF, DW_DRX_TUNE1A, p64 ? 0x008D : 0x0087));
    uint16_t t1b = rate == 0 ? 0x0064 : (plen == 64 ? 0x0010 : 0x0020);
    TRY(dw_write16(d, DW_REG_DRX_CONF, DW_DRX_TUNE1B, t1b));
    uint32_t tune2;
    if (plen <= 128) tune2 = p64 ? 0x313B006B : 0x311A002D;
    else if (plen <= 512) tune2 = p64 ? 0x333B00BE : 0x331A0052;
    else if (plen <= 1024) tune2 = p64 ? 0x353B015E : 0x351A009A;
    else tune2 = p64 ? 0x373B0296 : 0x371A011D;
    TRY(dw_write32(d, DW_REG_DRX_CONF, DW_DRX_TUNE2, tune2));
    TRY(dw_write16(d, DW_REG_DRX_CONF, DW_DRX_SFDTOC, (uint16_t)(plen + 1 + (rate == 0 ? 64 : 8))));
    TRY(dw_write16(d, DW_REG_DRX_CONF, DW_DRX_TUNE4H, plen == 64 ? 0x0010 : 0x0028));
    TRY(dw_write8(d, DW_REG_RF_CONF, DW_RF_RXCTRLH,
                  (cfg->channel == 4 || cfg->channel == 7) ? 0xBC : 0xD8));
    TRY(dw_write32(d, DW_REG_RF_CONF, DW_RF_TXCTRL, k_rf_txctrl[ci]));
    TRY(dw_write8(d, DW_REG_TX_CAL, DW_TC_PGDELAY, k_pgdelay[ci]));
    TRY(dw_write32(d, DW_REG_FS_CTRL, DW_FS_PLLCFG, k_pllcfg[ci]));
    TRY(dw_write8(d, DW_REG_FS_CTRL, DW_FS_PLLTUNE, k_plltune[ci]));
    TRY(dw_write8(d, DW_REG_LDE_IF, DW_LDE_CFG1, 0x6D));
    TRY(dw_write16(d, DW_REG_LDE_IF, DW_LDE_CFG2, p64 ? 0x0607 : 0x1607));
    uint16_t repc = k_lde_repc[code - 1];
    TRY(dw_write16(d, DW_REG_LDE_IF, DW_LDE_REPC, rate == 0 ? (uint16_t)(repc >> 3) : repc));

    TRY(dw_write16(d, DW_REG_TX_ANTD, 0, cfg->tx_antd));
    TRY(dw_write16(d, DW_REG_LDE_IF, DW_LDE_RXANTD, cfg->rx_antd));
    d->gain_valid = false;
    TRY(dw_set_gain(d, 0x67));
    TRY(dw_write32(d, DW_REG_SYS_MASK, 0, DW_IRQ_MASK));
    TRY(dw_write32(d, DW_REG_SYS_STATUS, 0, 0xFFFFFFFFu));
    TRY(dw_read32(d, DW_REG_DEV_ID, 0, &d->dev_id));
    if (d->dev_id != DW1000_DEV_ID_VALUE) return DW_ENODEV;
    d->cfg = *cfg;
    d->ready = true;
    return DW_OK;
}

/* ---- TX/RX ----------------------------------------------------------------------------- */

int dw_read_sys_time(struct dw_dev *d, uint64_t *t) { return dw_read40(d, DW_REG_SYS_TIME, 0, t); }

int dw_set_gain(struct dw_dev *d, uint8_t octet) {
    if (d->gain_valid && d->gain == octet) return DW_OK;
    TRY(dw_write32(d, DW_REG_TX_POWER, 0, dw_tx_power_word(octet)));
    d->gain = octet;
    d->gain_valid = true;
    return DW_OK;
}

static int tx_load(struct dw_dev *d, const uint8_t *payload, size_t n, uint8_t gain) {
    if (!d->ready) return DW_ENOTREADY;
    if (n == 0 || n > DW_MAX_PAYLOAD) return DW_EARG;
    TRY(dw_set_gain(d, gain));
    if (d->tx_len != n + 2) {
        d->tx_len = 0;
        TRY(dw_write40(d, DW_REG_TX_FCTRL, 0, d->tx_fctrl | (uint32_t)(n + 2)));
        d->tx_len = (uint8_t)(n + 2);
    }
    return dw_write(d, DW_REG_TX_BUFFER, 0, payload, n);
}

int dw_tx_delayed(struct dw_dev *d, const uint8_t *payload, size_t n, uint64_t dx, uint8_t gain) {
    TRY(tx_load(d, payload, n, gain));
    TRY(dw_write40(d, DW_REG_DX_TIME, 0, dx & DW_TIME_MASK));
    TRY(dw_write32(d, DW_REG_SYS_CTRL, 0, DW_SYS_CTRL_TXSTRT | DW_SYS_CTRL_TXDLYS));
    uint32_t st;
    TRY(dw_read32(d, DW_REG_SYS_STATUS, 0, &st));
    if (st & DW_ST_HPDWARN) {
        TRY(dw_write32(d, DW_REG_SYS_CTRL, 0, DW_SYS_CTRL_TRXOFF));
        TRY(dw_write32(d, DW_REG_SYS_STATUS, 0, DW_ST_HPDWARN | DW_TX_DONE_CLR));
        return DW_ELATE;
    }
    return DW_OK;
}

int dw_tx_now(struct dw_dev *d, const uint8_t *payload, size_t n, uint8_t gain) {
    TRY(tx_load(d, payload, n, gain));
    return dw_write32(d, DW_REG_SYS_CTRL, 0, DW_SYS_CTRL_TXSTRT);
}

int dw_rx_enable(struct dw_dev *d) {
    if (!d->ready) return DW_ENOTREADY;
    return dw_write32(d, DW_REG_SYS_CTRL, 0, DW_SYS_CTRL_RXENAB);
}

int dw_trx_off(struct dw_dev *d) {
    TRY(dw_write32(d, DW_REG_SYS_CTRL, 0, DW_SYS_CTRL_TRXOFF));
    return dw_write32(d, DW_REG_SYS_STATUS, 0, 0xFFFFFFFFu);
}

int dw_wait_irq(struct dw_dev *d, uint64_t deadline_us) {
    if (d->ops == NULL || d->ops->wait_irq == NULL) return DW_EARG;
    int r = d->ops->wait_irq(d->ops->ctx, deadline_us);
    return r < 0 ? DW_EIRQ : r;
}

static int32_t sext(uint32_t v, unsigned bits) {
    uint32_t m = 1u << (bits - 1);
    v &= (1u << bits) - 1u;
    return (int32_t)(v ^ m) - (int32_t)m;
}

static int rx_read(struct dw_dev *d, struct dw_event *ev) {
    uint8_t finfo[4], tm[14], fq[8], nosat[2], car[3], tki[4], tko[4];
    /* every register of the frame but the buffer, in one batch (REGISTERS.md 5.4) */
    const struct dw_rd rd[7] = {
        {DW_REG_RX_FINFO, 0, finfo, 4},          {DW_REG_RX_TIME, 0, tm, 14},
        {DW_REG_RX_FQUAL, 0, fq, 8},             {DW_REG_DRX_CONF, DW_DRX_RXPACC_NOSAT, nosat, 2},
        {DW_REG_DRX_CONF, DW_DRX_CAR_INT, car, 3}, {DW_REG_RX_TTCKI, 0, tki, 4},
        {DW_REG_RX_TTCKO, 0, tko, 4},
    };
    TRY(read_batch(d, rd, 7));
    uint32_t fi = (uint32_t)get_le(finfo, 4);
    size_t flen = fi & 0x7Fu;
    ev->len = flen >= 2 ? (uint8_t)(flen - 2) : 0;
    if (ev->len) TRY(dw_read(d, DW_REG_RX_BUFFER, 0, ev->data, ev->len));
    ev->q.rxpacc = (uint16_t)(fi >> 20);
    ev->stamp = get_le(tm, 5);
    ev->q.fp_index = (uint16_t)get_le(tm + 5, 2);
    ev->q.fp_ampl1 = (uint16_t)get_le(tm + 7, 2);
    ev->q.std_noise = (uint16_t)get_le(fq, 2);
    ev->q.fp_ampl2 = (uint16_t)get_le(fq + 2, 2);
    ev->q.fp_ampl3 = (uint16_t)get_le(fq + 4, 2);
    ev->q.cir_pwr = (uint16_t)get_le(fq + 6, 2);
    ev->q.rxpacc_nosat = (uint16_t)get_le(nosat, 2);
    ev->q.car_int = sext((uint32_t)get_le(car, 3), 21);
    ev->q.ttcki = (uint32_t)get_le(tki, 4);
    ev->q.ttcko = sext((uint32_t)get_le(tko, 4), 19);
    return dw_write32(d, DW_REG_SYS_STATUS, 0, DW_RX_GOOD_CLR);
}

static int rx_recover(struct dw_dev *d) {
    TRY(dw_write32(d, DW_REG_SYS_CTRL, 0, DW_SYS_CTRL_TRXOFF));
    TRY(dw_write32(d, DW_REG_SYS_STATUS, 0, DW_RX_ERR_CLR));
    TRY(dw_write8(d, DW_REG_PMSC, DW_PMSC_SOFTRESET, 0xE0));
    TRY(dw_write8(d, DW_REG_PMSC, DW_PMSC_SOFTRESET, 0xF0));
    return dw_write32(d, DW_REG_SYS_CTRL, 0, DW_SYS_CTRL_RXENAB);
}

int dw_service(struct dw_dev *d, struct dw_event *ev) {
    ev->kind = DW_EV_NONE;
    ev->len = 0;
    uint8_t stb[4], txt[5];
    bool have_txt = d->ops != NULL && d->ops->spi_batch != NULL;
    if (have_txt) {
        /* one round trip on a pipelining board: TX_TIME is read along (no side effect) */
        const struct dw_rd rd[2] = {{DW_REG_SYS_STATUS, 0, stb, 4}, {DW_REG_TX_TIME, 0, txt, 5}};
        TRY(read_batch(d, rd, 2));
    } else {
        TRY(dw_read(d, DW_REG_SYS_STATUS, 0, stb, 4));
    }
    ev->status = (uint32_t)get_le(stb, 4);
    uint32_t st = ev->status;
    if (st & DW_ST_TXFRS) {
        if (have_txt) ev->stamp = get_le(txt, 5);
        else TRY(dw_read40(d, DW_REG_TX_TIME, 0, &ev->stamp));
        TRY(dw_write32(d, DW_REG_SYS_STATUS, 0, DW_TX_DONE_CLR));
        ev->kind = DW_EV_TX_DONE;
        return DW_OK;
    }
    if (st & DW_ST_RXFCG) {
        memset(&ev->q, 0, sizeof ev->q);
        TRY(rx_read(d, ev));
        ev->kind = DW_EV_RX_GOOD;
        return DW_OK;
    }
    if (st & DW_ST_RX_ERR) {
        TRY(rx_recover(d));
        ev->kind = DW_EV_RX_ERROR;
        return DW_OK;
    }
    return DW_OK;
}

int dw_read_temp(struct dw_dev *d, int16_t *temp_cc) {
    uint8_t sar[2];
    *temp_cc = INT16_MIN;
    TRY(dw_write8(d, DW_REG_RF_CONF, DW_RF_TEMP1, 0x80));
    TRY(dw_write8(d, DW_REG_RF_CONF, DW_RF_TEMP2, 0x0A));
    TRY(dw_write8(d, DW_REG_RF_CONF, DW_RF_TEMP2, 0x0F));
    TRY(dw_write8(d, DW_REG_TX_CAL, DW_TC_SARC, 0x00));
    TRY(dw_write8(d, DW_REG_TX_CAL, DW_TC_SARC, 0x01));
    if (d->ops->delay_us) d->ops->delay_us(d->ops->ctx, 10);
    TRY(dw_read(d, DW_REG_TX_CAL, DW_TC_SARL, sar, 2));
    TRY(dw_write8(d, DW_REG_TX_CAL, DW_TC_SARC, 0x00));
    if (d->t23 == 0 || d->t23 == 0xFF) return DW_OK;
    /* UM 6.4: T = (SAR_LTEMP - OTP Vtemp@23C) x 1.14 + 23 degC, here in centi-degC (folded
     * to integers at compile time: 114 per LSB, 2300 at the reference) */
    const int cc_per_lsb = (int)(DW1000_SAR_TEMP_DEGC_PER_LSB * 100.0 + 0.5);
    const int ref_cc = (int)(DW1000_SAR_TEMP_REF_DEGC * 100.0 + 0.5);
    *temp_cc = (int16_t)(cc_per_lsb * ((int)sar[1] - (int)d->t23) + ref_cc);
    return DW_OK;
}

uint32_t dw_frame_us(const struct dw_config *cfg, size_t payload_len) {
    /* symbol 1017.63 ns (PRF64) / 993.59 ns (PRF16); PHR 21 bits; Reed-Solomon 48 per 330 */
    uint32_t sym_ps = cfg->prf_mhz == 16 ? 993590u : 1017630u;
    uint32_t sfd = cfg->data_rate == 0 ? 64u : 8u;
    uint64_t shr_ps = (uint64_t)(cfg->preamble_len + sfd) * sym_ps;
    static const uint32_t bit_ps[3] = {8205130u, 1025640u, 128210u};
    static const uint32_t phr_ps[3] = {8205130u, 1025640u, 1025640u};
    uint8_t r = cfg->data_rate <= 2 ? cfg->data_rate : 2;
    uint64_t bits = 8u * (payload_len + 2u);
    uint64_t rs = 48u * ((bits + 329u) / 330u);
    uint64_t tail_ps = 21u * (uint64_t)phr_ps[r] + (bits + rs) * bit_ps[r];
    return (uint32_t)((shr_ps + tail_ps + 999999u) / 1000000u);
}
