#include "dispatch.h"

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

size_t dispatch_event(const struct frame_event *ev, uint8_t *out, size_t cap)
{
    static uint8_t resp[PROTO_MAX_PAYLOAD];
    if (ev->kind == FRAME_EV_ERROR) return dispatch_error_frame(0, ev->error, 0, ev->detail, out, cap);
    if (ev->kind != FRAME_EV_FRAME) return 0;
    const struct proto_header *h = &ev->hdr;
    if (h->version != PROTO_VERSION)
        return dispatch_error_frame(h->seq, PROTO_ERR_BAD_VERSION, h->type, h->version, out, cap);
    if (h->flags != 0) return dispatch_error_frame(h->seq, PROTO_ERR_BAD_FLAGS, h->type, h->flags, out, cap);
    size_t n = 0;
    uint16_t detail = PROTO_DETAIL_NONE;
    int rc = proto_dispatch(h->type, ev->payload, ev->payload_len, resp, sizeof resp, &n, &detail);
    if (rc != 0) return dispatch_error_frame(h->seq, (uint8_t)rc, h->type, detail, out, cap);
    struct proto_header r = {.version = PROTO_VERSION, .type = h->type, .flags = PROTO_FLAG_RESPONSE, .seq = h->seq};
    return frame_encode(&r, resp, n, out, cap);
}
