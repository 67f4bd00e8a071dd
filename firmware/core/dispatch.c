#include "dispatch.h"

#include <stdbool.h>

#include "crc32.h"

/* The last request that passed the header checks and the answer it got. A response payload
 * stays in resp[] (written only by the handler of a new request, which replaces this memory
 * first), so one answer costs no second frame buffer. */
struct last_request {
    bool valid;
    uint8_t type;
    uint16_t seq;
    uint16_t len;    /* request payload length, bytes */
    uint32_t crc;    /* CRC-32/ISO-HDLC of the request's header | payload */
    int rc;          /* 0: the response in resp[0..resp_len); else the ERROR code */
    uint16_t detail; /* ERROR detail */
    uint16_t resp_len;
};

static uint8_t resp[PROTO_MAX_PAYLOAD];
static struct last_request last;
static uint32_t replayed;

void dispatch_forget(void) { last.valid = false; }

uint32_t dispatch_replayed(void) { return replayed; }

size_t dispatch_error_frame(uint16_t seq, uint8_t code, uint8_t request_type, uint16_t detail,
                            uint8_t *out, size_t cap)
{
    struct proto_error_resp e = {.code = code, .request_type = request_type, .detail = detail};
    uint8_t payload[PROTO_ERROR_RESP_FIXED_SIZE];
    size_t n = 0;
    if (proto_error_resp_encode(&e, payload, sizeof payload, &n) != 0) return 0;
    struct proto_header h = {
        .version = PROTO_VERSION, .type = PROTO_T_ERROR, .flags = PROTO_FLAG_RESPONSE, .seq = seq};
    return frame_encode(&h, payload, n, out, cap);
}

/* The remembered answer as wire bytes (the same bytes as the first time: encoding is
 * deterministic). */
static size_t answer(uint8_t *out, size_t cap)
{
    if (last.rc != 0) return dispatch_error_frame(last.seq, (uint8_t)last.rc, last.type, last.detail, out, cap);
    struct proto_header r = {
        .version = PROTO_VERSION, .type = last.type, .flags = PROTO_FLAG_RESPONSE, .seq = last.seq};
    return frame_encode(&r, resp, last.resp_len, out, cap);
}

size_t dispatch_event(const struct frame_event *ev, uint8_t *out, size_t cap)
{
    if (ev->kind == FRAME_EV_ERROR) return dispatch_error_frame(0, ev->error, 0, ev->detail, out, cap);
    if (ev->kind != FRAME_EV_FRAME) return 0;
    const struct proto_header *h = &ev->hdr;
    if (h->version != PROTO_VERSION)
        return dispatch_error_frame(h->seq, PROTO_ERR_BAD_VERSION, h->type, h->version, out, cap);
    if (h->flags != 0) return dispatch_error_frame(h->seq, PROTO_ERR_BAD_FLAGS, h->type, h->flags, out, cap);

    uint8_t hdr[PROTO_HEADER_SIZE];
    proto_header_encode(h, hdr);
    uint32_t crc = crc32_update(crc32_update(0, hdr, sizeof hdr), ev->payload, ev->payload_len);
    if (last.valid && last.seq == h->seq && last.type == h->type && last.len == ev->payload_len &&
        last.crc == crc) {
        replayed++;
        return answer(out, cap);
    }

    last.valid = false; /* resp[] is about to be overwritten */
    size_t n = 0;
    uint16_t detail = PROTO_DETAIL_NONE;
    int rc = proto_dispatch(h->type, ev->payload, ev->payload_len, resp, sizeof resp, &n, &detail);
    last.type = h->type;
    last.seq = h->seq;
    last.len = (uint16_t)ev->payload_len;
    last.crc = crc;
    last.rc = rc;
    last.detail = rc != 0 ? detail : PROTO_DETAIL_NONE;
    last.resp_len = rc != 0 ? 0u : (uint16_t)n;
    last.valid = true;
    return answer(out, cap);
}
