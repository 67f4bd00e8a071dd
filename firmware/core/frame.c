#include "frame.h"

#include <string.h>

#include "crc32.h"
#include "proto_wire.h"

void frame_decoder_init(struct frame_decoder *d)
{
    d->len = 0;
    d->count = 0;
}

static int error_event(struct frame_event *ev, uint8_t code, size_t detail)
{
    ev->kind = FRAME_EV_ERROR;
    ev->error = code;
    ev->detail = (uint16_t)(detail > 0xFFFFu ? 0xFFFFu : detail);
    return ev->kind;
}

int frame_decoder_push(struct frame_decoder *d, uint8_t byte, struct frame_event *ev)
{
    memset(ev, 0, sizeof *ev);
    ev->kind = FRAME_EV_NONE;
    if (byte != PROTO_DELIMITER) {
        if (d->count < 0xFFFFu) d->count++;
        if (d->len < FRAME_WIRE_MAX) d->enc[d->len] = byte;
        if (d->len <= FRAME_WIRE_MAX) d->len++; /* len == FRAME_WIRE_MAX + 1 marks overflow */
        return ev->kind;
    }
    /* End of a frame. */
    size_t len = d->len;
    uint32_t count = d->count;
    d->len = 0;
    d->count = 0;
    if (len == 0) return ev->kind; /* empty frame: a resync delimiter */
    if (len > FRAME_WIRE_MAX) return error_event(ev, PROTO_ERR_TOO_LONG, count);
    size_t n = 0, off = 0;
    int rc = cobs_decode(d->enc, len, d->raw, sizeof d->raw, &n, &off);
    if (rc == COBS_EBAD) return error_event(ev, PROTO_ERR_BAD_COBS, off);
    if (rc != COBS_OK) return error_event(ev, PROTO_ERR_TOO_LONG, count);
    if (n < PROTO_HEADER_SIZE + PROTO_CRC_SIZE) return error_event(ev, PROTO_ERR_TOO_SHORT, n);
    size_t body = n - PROTO_CRC_SIZE;
    if (crc32_iso_hdlc(d->raw, body) != wire_get_u32(d->raw + body))
        return error_event(ev, PROTO_ERR_BAD_CRC, PROTO_DETAIL_NONE);
    proto_header_decode(d->raw, &ev->hdr);
    ev->payload = d->raw + PROTO_HEADER_SIZE;
    ev->payload_len = body - PROTO_HEADER_SIZE;
    ev->kind = FRAME_EV_FRAME;
    return ev->kind;
}

size_t frame_encode(const struct proto_header *h, const uint8_t *payload, size_t payload_len,
                    uint8_t *out, size_t cap)
{
    if (payload_len > PROTO_MAX_PAYLOAD || cap < 2) return 0;
    uint8_t hdr[PROTO_HEADER_SIZE], crc_le[PROTO_CRC_SIZE];
    proto_header_encode(h, hdr);
    uint32_t crc = crc32_update(crc32_update(0, hdr, sizeof hdr), payload, payload_len);
    for (unsigned i = 0; i < PROTO_CRC_SIZE; i++) crc_le[i] = (uint8_t)(crc >> (8 * i));
    /* COBS straight from the pieces: no copy of the frame. */
    struct cobs_encoder e;
    cobs_encoder_init(&e, out, cap - 1);
    cobs_encoder_push(&e, hdr, sizeof hdr);
    if (payload_len > 0) cobs_encoder_push(&e, payload, payload_len);
    cobs_encoder_push(&e, crc_le, sizeof crc_le);
    size_t n = cobs_encoder_finish(&e);
    if (n == 0) return 0;
    out[n] = PROTO_DELIMITER;
    return n + 1;
}
