/* Calibration-table store: two flash slots (one page each) with sequence numbers and a
 * commit word written last, so that a power cut at any moment leaves the old table or the
 * new one active, never neither and never a damaged one.
 *
 * Slot layout (little-endian, offsets in the page):
 *   0  magic  u32  TABLE_STORE_MAGIC
 *   4  seq    u32  sequence number, the newest valid slot wins
 *   8  len    u16  table bytes
 *  10  ver    u16  slot layout version (1)
 *  12  crc    u32  CRC-32/ISO-HDLC of bytes 0..11 followed by the table bytes
 *  16  table  len bytes (padded with 0xFF to an even length)
 *  page_size - 4: commit u32 TABLE_STORE_COMMIT, programmed last
 * A write: erase the inactive page, blank-check it, program header and table, read them
 * back and compare, then program the commit word. The store knows nothing of the table's
 * contents (caltable.c does); it keeps bytes.
 */
#ifndef UWBCAL_TABLE_STORE_H
#define UWBCAL_TABLE_STORE_H

#include <stddef.h>
#include <stdint.h>

#include "proto_gen.h"

#define TABLE_STORE_MAGIC 0x54435755u   /* "UWCT" */
#define TABLE_STORE_COMMIT 0x3CA5C35Au
#define TABLE_STORE_LAYOUT 1u
#define TABLE_STORE_HDR 16u
#define TABLE_STORE_SLOTS 2u

/* Slot states, as reported by table_info: PROTO_TABLE_SLOT_STATE_* (the table_slot_state
 * enum of protocol/messages/tables.toml, generated into proto_gen.h). */

struct table_store_info {
    int active;                              /* 0, 1, or -1 when no valid slot */
    uint8_t state[TABLE_STORE_SLOTS];        /* PROTO_TABLE_SLOT_STATE_* */
    uint32_t seq[TABLE_STORE_SLOTS];         /* header sequence, 0 when unreadable */
    uint16_t len[TABLE_STORE_SLOTS];         /* header length, 0 when unreadable */
};

/* Largest table the store holds in one page. */
uint32_t table_store_max_len(void);

/* Scan both slots (at boot, and again after every write or erase). Returns BOARD_EOK or
 * a BOARD_E* code when the flash cannot be read. */
int table_store_init(void);

const struct table_store_info *table_store_get_info(void);

/* Bytes of the active table, 0 when there is none. */
uint16_t table_store_active_len(void);

/* Read from the active table. BOARD_EARG beyond its end or when there is no table. */
int table_store_read(uint32_t offset, uint8_t *buf, size_t len);

/* Write a table to the inactive slot with the next sequence number; on success it becomes
 * the active table. Returns BOARD_EOK or a BOARD_E* code (the old table stays active). */
int table_store_write(const uint8_t *table, size_t len, uint8_t *slot_out, uint32_t *seq_out);

/* Erase both slots, the inactive one first. */
int table_store_erase(void);

#endif
