/* The streaming frame decoder and encoder against every frame and malformed vector, garbage
 * resynchronisation, overlong input, and seeded random bytes. */
#include "check.h"
#include "frame.h"
#include "vectors_gen.h"

static struct frame_decoder d;

/* Push bytes; return the number of events, keep the last one in *last. */
static int feed(const uint8_t *p, size_t n, struct frame_event *last)
{
    int events = 0;
    struct frame_event ev;
    for (size_t i = 0; i < n; i++) {
        if (frame_decoder_push(&d, p[i], &ev) != FRAME_EV_NONE) {
            events++;
            *last = ev;
        }
    }
    return events;
}

static int is_frame_level(uint8_t code)
{
    return code == PROTO_ERR_BAD_COBS || code == PROTO_ERR_BAD_CRC || code == PROTO_ERR_TOO_LONG ||
           code == PROTO_ERR_TOO_SHORT;
}

int main(void)
{
    static uint8_t out[FRAME_TX_MAX];
    struct frame_event ev;
    frame_decoder_init(&d);
    for (size_t i = 0; i < N_FRAME_VECTORS; i++) {
        const struct frame_vector *v = &frame_vectors[i];
        check_context("frame vector '%s'", v->name);
        CHECK_EQ(feed(v->wire, v->wire_len, &ev), 1);
        CHECK_EQ(ev.kind, FRAME_EV_FRAME);
        CHECK_EQ(ev.hdr.version, v->version);
        CHECK_EQ(ev.hdr.type, v->type);
        CHECK_EQ(ev.hdr.flags, v->flags);
        CHECK_EQ(ev.hdr.seq, v->seq);
        CHECK_MEM(ev.payload, ev.payload_len, v->payload, v->payload_len);
        CHECK_EQ(v->check_fields(v->payload, v->payload_len), 0);
        const uint8_t *c = v->raw + v->raw_len - 4;
        CHECK_EQ((uint32_t)c[0] | ((uint32_t)c[1] << 8) | ((uint32_t)c[2] << 16) | ((uint32_t)c[3] << 24), v->crc);
        CHECK_MEM(v->raw + PROTO_HEADER_SIZE, v->raw_len - PROTO_HEADER_SIZE - 4, v->payload, v->payload_len);
        struct proto_header h = {v->version, v->type, v->flags, v->seq};
        size_t n = frame_encode(&h, v->payload, v->payload_len, out, sizeof out);
        CHECK_MEM(out, n, v->wire, v->wire_len);
        CHECK(n <= FRAME_TX_MAX);
    }
    for (size_t i = 0; i < N_MALFORMED_VECTORS; i++) {
        const struct malformed_vector *v = &malformed_vectors[i];
        check_context("malformed vector '%s'", v->name);
        CHECK_EQ(feed(v->wire, v->wire_len, &ev), 1);
        if (is_frame_level(v->code)) {
            CHECK_EQ(ev.kind, FRAME_EV_ERROR);
            CHECK_EQ(ev.error, v->code);
            CHECK_EQ(ev.detail, v->detail);
        } else {
            CHECK_EQ(ev.kind, FRAME_EV_FRAME); /* the dispatcher rejects it (test_dispatch) */
        }
    }
    /* Garbage then a frame: the garbage is reported (at most once per delimiter) and the frame
     * right after the next delimiter decodes. */
    uint32_t rng = 7;
    const struct frame_vector *ping = &frame_vectors[2];
    for (int round = 0; round < 500; round++) {
        uint8_t junk[300];
        size_t n = check_rand(&rng) % sizeof junk;
        for (size_t i = 0; i < n; i++) junk[i] = (uint8_t)check_rand(&rng);
        check_context("garbage round %d", round);
        int events = feed(junk, n, &ev);
        events += feed((const uint8_t *)"\0", 1, &ev);
        size_t zeros = 0;
        for (size_t i = 0; i < n; i++) zeros += junk[i] == 0;
        CHECK(events <= (int)zeros + 1);
        CHECK_EQ(feed(ping->wire, ping->wire_len, &ev), 1);
        CHECK_EQ(ev.kind, FRAME_EV_FRAME);
        CHECK_EQ(ev.hdr.seq, ping->seq);
    }
    /* Overlong: one too_long per overlong frame, detail saturated at 0xFFFF. */
    check_context("overlong");
    static uint8_t big[70000];
    memset(big, 0x41, sizeof big);
    CHECK_EQ(feed(big, sizeof big, &ev), 0);
    CHECK_EQ(feed((const uint8_t *)"\0", 1, &ev), 1);
    CHECK_EQ(ev.kind, FRAME_EV_ERROR);
    CHECK_EQ(ev.error, PROTO_ERR_TOO_LONG);
    CHECK_EQ(ev.detail, 0xFFFFu);
    CHECK_EQ(feed(big, FRAME_WIRE_MAX + 1, &ev), 0);
    CHECK_EQ(feed((const uint8_t *)"\0", 1, &ev), 1);
    CHECK_EQ(ev.detail, FRAME_WIRE_MAX + 1);
    /* Empty frames (runs of delimiters) produce nothing. */
    static const uint8_t zeros[16] = {0};
    CHECK_EQ(feed(zeros, sizeof zeros, &ev), 0);
    /* Encoder limits. */
    CHECK_EQ(frame_encode(&(struct proto_header){1, 1, 0, 1}, big, PROTO_MAX_PAYLOAD + 1, out, sizeof out), 0);
    CHECK_EQ(frame_encode(&(struct proto_header){1, 1, 0, 1}, big, 10, out, 12), 0);
    /* Random bytes: every reported frame has a consistent length and a good CRC. */
    check_context("random bytes");
    int frames = 0, errors = 0;
    for (int i = 0; i < 400000; i++) {
        uint32_t r = check_rand(&rng);
        uint8_t b = (r & 0x300) == 0 ? 0 : (uint8_t)r; /* about one byte in four is 0x00 */
        int k = frame_decoder_push(&d, b, &ev);
        if (k == FRAME_EV_FRAME) {
            frames++;
            CHECK(ev.payload_len <= PROTO_MAX_PAYLOAD);
        } else if (k == FRAME_EV_ERROR) {
            errors++;
            CHECK(is_frame_level(ev.error));
        }
    }
    CHECK(errors > 0);
    printf("random bytes: %d frames with a good CRC, %d rejected\n", frames, errors);
    return check_summary();
}
