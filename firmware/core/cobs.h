/* Consistent Overhead Byte Stuffing (Cheshire and Baker): the frame body never contains 0x00,
 * so 0x00 delimits frames on the host link. No allocation, caller's buffers. */
#ifndef UWBCAL_COBS_H
#define UWBCAL_COBS_H

#include <stddef.h>
#include <stdint.h>

/* Upper bound of the encoded size of n bytes (the delimiter not included). */
#define COBS_ENCODED_MAX(n) ((n) + (n) / 254u + 1u)

/* Encode in[0..len) into out[0..cap). Returns the encoded length (>= 1), or 0 if cap is too
 * small. in and out must not overlap. */
size_t cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t cap);

/* Incremental encoder: the input may arrive in pieces (header, payload, CRC) without being
 * copied together first. Same output as cobs_encode of the concatenation. */
struct cobs_encoder {
    uint8_t *out;
    size_t cap;
    size_t o;       /* bytes written */
    size_t code_at; /* where the open block's code byte goes */
    uint8_t code;
    uint8_t open;     /* a block is open */
    uint8_t overflow; /* cap was too small: the result is unusable */
};
void cobs_encoder_init(struct cobs_encoder *e, uint8_t *out, size_t cap);
void cobs_encoder_push(struct cobs_encoder *e, const uint8_t *in, size_t len);
/* Close the last block; returns the encoded length, or 0 on overflow. */
size_t cobs_encoder_finish(struct cobs_encoder *e);

#define COBS_OK 0
#define COBS_EBAD (-1)      /* not valid COBS: *err_offset = offset of the offending byte */
#define COBS_ETOOLONG (-2)  /* valid, but the decoded data needs more than cap bytes */

/* Decode in[0..len) (no delimiter) into out[0..cap). The whole input is validated first, so
 * COBS_EBAD wins over COBS_ETOOLONG. On success *out_len is the decoded length.
 * err_offset may be NULL. */
int cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t cap, size_t *out_len,
                size_t *err_offset);

#endif
