#include "cobs.h"

static void open_block(struct cobs_encoder *e)
{
    if (e->o >= e->cap) {
        e->overflow = 1;
        return;
    }
    e->code_at = e->o++;
    e->code = 1;
    e->open = 1;
}

void cobs_encoder_init(struct cobs_encoder *e, uint8_t *out, size_t cap)
{
    e->out = out;
    e->cap = cap;
    e->o = 0;
    e->open = 0;
    e->overflow = 0;
    open_block(e);
}

void cobs_encoder_push(struct cobs_encoder *e, const uint8_t *in, size_t len)
{
    for (size_t i = 0; i < len && !e->overflow; i++) {
        if (!e->open) open_block(e); /* the previous block was full (254 data bytes) */
        if (e->overflow) return;
        if (in[i] == 0) {
            e->out[e->code_at] = e->code;
            open_block(e); /* a zero always starts a new block, even at the end */
            continue;
        }
        if (e->o >= e->cap) {
            e->overflow = 1;
            return;
        }
        e->out[e->o++] = in[i];
        if (++e->code == 0xFF) {
            /* Full block: no implicit zero. The next block opens only if more input comes,
             * so a full block at the very end needs no further code byte. */
            e->out[e->code_at] = e->code;
            e->open = 0;
        }
    }
}

size_t cobs_encoder_finish(struct cobs_encoder *e)
{
    if (e->overflow) return 0;
    if (e->open) e->out[e->code_at] = e->code;
    e->open = 0;
    return e->o;
}

size_t cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t cap)
{
    struct cobs_encoder e;
    cobs_encoder_init(&e, out, cap);
    cobs_encoder_push(&e, in, len);
    return cobs_encoder_finish(&e);
}

int cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t cap, size_t *out_len,
                size_t *err_offset)
{
    /* Pass 1: structure and decoded length. */
    size_t need = 0;
    size_t i = 0;
    while (i < len) {
        uint8_t code = in[i];
        if (code == 0 || i + code > len) {
            if (err_offset) *err_offset = i;
            return COBS_EBAD;
        }
        for (size_t k = 1; k < code; k++) {
            if (in[i + k] == 0) {
                if (err_offset) *err_offset = i + k;
                return COBS_EBAD;
            }
        }
        need += (size_t)code - 1u;
        i += code;
        if (code != 0xFF && i < len) need++;
    }
    if (need > cap) return COBS_ETOOLONG;
    /* Pass 2: copy. */
    size_t o = 0;
    i = 0;
    while (i < len) {
        uint8_t code = in[i];
        for (size_t k = 1; k < code; k++) out[o++] = in[i + k];
        i += code;
        if (code != 0xFF && i < len) out[o++] = 0;
    }
    *out_len = o;
    return COBS_OK;
}
