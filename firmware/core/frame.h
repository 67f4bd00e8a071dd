/* Frames on the host link: COBS(header | payload | crc32) 0x00 (protocol/PROTOCOL.md).
 * The decoder is a byte-at-a-time state machine: garbage resynchronises at the next 0x00,
 * an overlong frame is dropped and reported once as too_long, empty frames are ignored. */
#ifndef UWBCAL_FRAME_H
#define UWBCAL_FRAME_H

#include <stddef.h>
#include <stdint.h>

#include "cobs.h"
#include "proto_gen.h"

/* Longest encoded frame the decoder keeps (delimiter not included). */
#define FRAME_WIRE_MAX COBS_ENCODED_MAX(PROTO_FRAME_MAX)
/* Buffer size that holds any encoded frame plus its delimiter. */
#define FRAME_TX_MAX (FRAME_WIRE_MAX + 1u)

enum frame_event_kind {
    FRAME_EV_NONE = 0,  /* nothing complete yet */
    FRAME_EV_FRAME = 1, /* a frame with a good CRC: hdr, payload, payload_len */
    FRAME_EV_ERROR = 2, /* a frame was rejected: error (PROTO_ERR_*), detail */
};

struct frame_event {
    int kind;
    struct proto_header hdr;
    const uint8_t *payload; /* points into the decoder: valid until the next push */
    size_t payload_len;
    uint8_t error;
    uint16_t detail;
};

struct frame_decoder {
    uint8_t enc[FRAME_WIRE_MAX];
    uint8_t raw[PROTO_FRAME_MAX];
    size_t len;      /* bytes kept in enc */
    uint32_t count;  /* bytes seen since the last delimiter, saturating at 0xFFFF */
};

void frame_decoder_init(struct frame_decoder *d);
/* Feed one byte; returns ev->kind (ev is always written). */
int frame_decoder_push(struct frame_decoder *d, uint8_t byte, struct frame_event *ev);

/* Encode one frame into out[0..cap) including the trailing delimiter. Returns its length, or
 * 0 if payload_len > PROTO_MAX_PAYLOAD or cap is too small. */
size_t frame_encode(const struct proto_header *h, const uint8_t *payload, size_t payload_len,
                    uint8_t *out, size_t cap);

#endif
