/* Two-slot calibration-table store; see table_store.h for the layout and the write order. */
#include "table_store.h"

#include <string.h>

#include "board.h"
#include "crc32.h"
#include "proto_wire.h"

#define CHUNK 64u

static struct table_store_info info = { .active = -1, .state = { 0, 0 }, .seq = { 0, 0 }, .len = { 0, 0 } };

static uint32_t slot_addr(unsigned slot)
{
    return board_flash_table_base() + slot * board_flash_page_size();
}

uint32_t table_store_max_len(void)
{
    return board_flash_page_size() - TABLE_STORE_HDR - 4u;
}

/* True when the whole page reads 0xFF; *err set on a read failure. */
static int page_blank(uint32_t addr, bool *blank)
{
    uint8_t buf[CHUNK];
    *blank = true;
    for (uint32_t off = 0; off < board_flash_page_size(); off += CHUNK) {
        int r = board_flash_read(addr + off, buf, CHUNK);
        if (r != BOARD_EOK) {
            return r;
        }
        for (unsigned i = 0; i < CHUNK; i++) {
            if (buf[i] != 0xFF) {
                *blank = false;
                return BOARD_EOK;
            }
        }
    }
    return BOARD_EOK;
}

static int scan_slot(unsigned slot)
{
    uint32_t base = slot_addr(slot);
    uint8_t hdr[TABLE_STORE_HDR];
    uint8_t cw[4];
    info.state[slot] = PROTO_TABLE_SLOT_STATE_CORRUPT;
    info.seq[slot] = 0;
    info.len[slot] = 0;
    int r = board_flash_read(base, hdr, sizeof hdr);
    if (r == BOARD_EOK) {
        r = board_flash_read(base + board_flash_page_size() - 4u, cw, sizeof cw);
    }
    if (r != BOARD_EOK) {
        return r;
    }
    uint32_t commit = wire_get_u32(cw);
    bool header_ok = wire_get_u32(hdr) == TABLE_STORE_MAGIC && wire_get_u16(hdr + 10) == TABLE_STORE_LAYOUT
                     && wire_get_u16(hdr + 8) >= 1u && wire_get_u16(hdr + 8) <= table_store_max_len();
    if (header_ok) {
        info.seq[slot] = wire_get_u32(hdr + 4);
        info.len[slot] = wire_get_u16(hdr + 8);
    }
    if (commit != TABLE_STORE_COMMIT) {
        bool blank;
        r = page_blank(base, &blank);
        if (r != BOARD_EOK) {
            return r;
        }
        /* an all-0xFF page is empty; anything else without a full commit word is a write
         * that did not finish (or an erase that did not: equally unusable) */
        info.state[slot] = blank ? PROTO_TABLE_SLOT_STATE_EMPTY : PROTO_TABLE_SLOT_STATE_TORN;
        return BOARD_EOK;
    }
    if (!header_ok) {
        return BOARD_EOK;   /* corrupt */
    }
    uint32_t crc = crc32_update(0, hdr, 12);
    uint8_t buf[CHUNK];
    uint32_t len = info.len[slot];
    for (uint32_t off = 0; off < len; off += CHUNK) {
        uint32_t n = len - off < CHUNK ? len - off : CHUNK;
        r = board_flash_read(base + TABLE_STORE_HDR + off, buf, n);
        if (r != BOARD_EOK) {
            return r;
        }
        crc = crc32_update(crc, buf, n);
    }
    if (crc == wire_get_u32(hdr + 12)) {
        info.state[slot] = PROTO_TABLE_SLOT_STATE_VALID;
    }
    return BOARD_EOK;
}

int table_store_init(void)
{
    info.active = -1;
    int result = BOARD_EOK;
    for (unsigned s = 0; s < TABLE_STORE_SLOTS; s++) {
        int r = scan_slot(s);
        if (r != BOARD_EOK) {
            info.state[s] = PROTO_TABLE_SLOT_STATE_CORRUPT;
            result = r;
        }
    }
    for (unsigned s = 0; s < TABLE_STORE_SLOTS; s++) {
        if (info.state[s] != PROTO_TABLE_SLOT_STATE_VALID) {
            continue;
        }
        /* the newest wins; sequence numbers compare by serial-number arithmetic so that
         * the 2^32 wrap does not matter; equal sequences (never written so) keep slot 0 */
        if (info.active < 0 || (int32_t)(info.seq[s] - info.seq[info.active]) > 0) {
            info.active = (int)s;
        }
    }
    return result;
}

const struct table_store_info *table_store_get_info(void)
{
    return &info;
}

uint16_t table_store_active_len(void)
{
    return info.active < 0 ? 0 : info.len[info.active];
}

int table_store_read(uint32_t offset, uint8_t *buf, size_t len)
{
    if (info.active < 0 || offset > info.len[info.active] || len > info.len[info.active] - offset) {
        return BOARD_EARG;
    }
    if (len == 0) {
        return BOARD_EOK;
    }
    return board_flash_read(slot_addr((unsigned)info.active) + TABLE_STORE_HDR + offset, buf, len);
}

/* Program len bytes (len may be odd: the last half-word is padded with 0xFF). */
static int program_bytes(uint32_t addr, const uint8_t *data, size_t len)
{
    size_t even = len & ~(size_t)1;
    if (even) {
        int r = board_flash_program(addr, data, even);
        if (r != BOARD_EOK) {
            return r;
        }
    }
    if (len & 1u) {
        uint8_t last[2] = { data[len - 1], 0xFF };
        return board_flash_program(addr + (uint32_t)even, last, 2);
    }
    return BOARD_EOK;
}

static int verify_bytes(uint32_t addr, const uint8_t *data, size_t len)
{
    uint8_t buf[CHUNK];
    for (size_t off = 0; off < len; off += CHUNK) {
        size_t n = len - off < CHUNK ? len - off : CHUNK;
        int r = board_flash_read(addr + (uint32_t)off, buf, n);
        if (r != BOARD_EOK) {
            return r;
        }
        if (memcmp(buf, data + off, n) != 0) {
            return BOARD_EFLASH;
        }
    }
    return BOARD_EOK;
}

int table_store_write(const uint8_t *table, size_t len, uint8_t *slot_out, uint32_t *seq_out)
{
    if (table == NULL || len == 0 || len > table_store_max_len()) {
        return BOARD_EARG;
    }
    unsigned slot = info.active == 0 ? 1u : 0u;
    uint32_t seq = info.active < 0 ? 1u : info.seq[info.active] + 1u;
    if (seq == 0) {
        seq = 1;
    }
    uint32_t base = slot_addr(slot);
    uint8_t hdr[TABLE_STORE_HDR];
    wire_put_u32(hdr, TABLE_STORE_MAGIC);
    wire_put_u32(hdr + 4, seq);
    hdr[8] = (uint8_t)len;
    hdr[9] = (uint8_t)(len >> 8);
    hdr[10] = (uint8_t)TABLE_STORE_LAYOUT;
    hdr[11] = 0;
    wire_put_u32(hdr + 12, crc32_update(crc32_update(0, hdr, 12), table, len));

    int r = board_flash_erase_page(base);
    bool blank = false;
    if (r == BOARD_EOK) {
        r = page_blank(base, &blank);
        if (r == BOARD_EOK && !blank) {
            r = BOARD_EFLASH;
        }
    }
    if (r == BOARD_EOK) {
        r = program_bytes(base, hdr, sizeof hdr);
    }
    if (r == BOARD_EOK) {
        r = program_bytes(base + TABLE_STORE_HDR, table, len);
    }
    if (r == BOARD_EOK) {
        r = verify_bytes(base, hdr, sizeof hdr);
    }
    if (r == BOARD_EOK) {
        r = verify_bytes(base + TABLE_STORE_HDR, table, len);
    }
    if (r == BOARD_EOK) {
        uint8_t cw[4];
        wire_put_u32(cw, TABLE_STORE_COMMIT);
        r = board_flash_program(base + board_flash_page_size() - 4u, cw, sizeof cw);
    }
    /* rescan in every case: the slot states reported afterwards are what the flash holds */
    int r2 = table_store_init();
    if (r == BOARD_EOK && r2 != BOARD_EOK) {
        r = r2;
    }
    if (r == BOARD_EOK && info.active != (int)slot) {
        r = BOARD_EFLASH;   /* the commit word did not take */
    }
    if (r == BOARD_EOK) {
        if (slot_out) {
            *slot_out = (uint8_t)slot;
        }
        if (seq_out) {
            *seq_out = seq;
        }
    }
    return r;
}

int table_store_erase(void)
{
    unsigned first = info.active == 0 ? 1u : 0u;
    int r = board_flash_erase_page(slot_addr(first));
    if (r == BOARD_EOK) {
        r = board_flash_erase_page(slot_addr(1u - first));
    }
    int r2 = table_store_init();
    return r != BOARD_EOK ? r : r2;
}
