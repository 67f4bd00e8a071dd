/* Dispatch: every request vector gets its expected response, every malformed vector its
 * expected ERROR frame byte for byte, GET_INFO reports this board, and seeded random and
 * mutated input always gets exactly one well-formed answer per frame. Then the main loop
 * (app.c) over a real pty: a PING answered, stream frames numbered per type. */
#define _XOPEN_SOURCE 700
#include <fcntl.h>
#include <poll.h>
#include <stdlib.h>
#include <termios.h>
#include <unistd.h>

#include "app.h"
#include "board.h"
#include "check.h"
#include "dispatch.h"
#include "boards/native/native.h"
#include "vectors_gen.h"

static struct frame_decoder d;
static uint8_t out[FRAME_TX_MAX];

/* Feed bytes through decoder + dispatcher; collect the answers in acc. Returns the number of
 * answers; every non-empty frame must give exactly one (checked by the caller). */
static int run_bytes(const uint8_t *p, size_t n, uint8_t *acc, size_t cap, size_t *acc_len, int *events)
{
    int answers = 0;
    struct frame_event ev;
    *acc_len = 0;
    *events = 0;
    for (size_t i = 0; i < n; i++) {
        if (frame_decoder_push(&d, p[i], &ev) == FRAME_EV_NONE) continue;
        (*events)++;
        size_t k = dispatch_event(&ev, out, sizeof out);
        if (k == 0) continue;
        answers++;
        if (*acc_len + k <= cap) {
            memcpy(acc + *acc_len, out, k);
            *acc_len += k;
        }
    }
    return answers;
}

/* Check that buf holds well-formed answer frames only (good CRC, our version,
 * flags.response). Returns how many. */
static int check_answers(const uint8_t *buf, size_t n)
{
    static struct frame_decoder d2;
    frame_decoder_init(&d2);
    struct frame_event ev;
    int frames = 0;
    for (size_t i = 0; i < n; i++) {
        int k = frame_decoder_push(&d2, buf[i], &ev);
        if (k == FRAME_EV_NONE) continue;
        frames++;
        CHECK_EQ(k, FRAME_EV_FRAME);
        CHECK_EQ(ev.hdr.version, PROTO_VERSION);
        CHECK_EQ(ev.hdr.flags, PROTO_FLAG_RESPONSE);
    }
    return frames;
}

static void test_vectors(void)
{
    static uint8_t acc[8 * FRAME_TX_MAX];
    size_t n = 0;
    int events = 0;
    for (size_t i = 0; i < N_FRAME_VECTORS; i++) {
        const struct frame_vector *v = &frame_vectors[i];
        if (v->response < 0) continue;
        const struct frame_vector *r = &frame_vectors[v->response];
        check_context("request vector '%s'", v->name);
        CHECK_EQ(run_bytes(v->wire, v->wire_len, acc, sizeof acc, &n, &events), 1);
        CHECK_MEM(acc, n, r->wire, r->wire_len);
    }
    for (size_t i = 0; i < N_MALFORMED_VECTORS; i++) {
        const struct malformed_vector *v = &malformed_vectors[i];
        check_context("malformed vector '%s'", v->name);
        CHECK_EQ(run_bytes(v->wire, v->wire_len, acc, sizeof acc, &n, &events), 1);
        CHECK_MEM(acc, n, v->response, v->response_len);
    }
}

static void test_get_info(void)
{
    struct proto_header h = {PROTO_VERSION, PROTO_T_GET_INFO, 0, 77};
    static uint8_t req[64], acc[FRAME_TX_MAX];
    size_t n = frame_encode(&h, NULL, 0, req, sizeof req), an = 0;
    int events = 0;
    check_context("get_info");
    CHECK_EQ(run_bytes(req, n, acc, sizeof acc, &an, &events), 1);
    struct frame_decoder d2;
    frame_decoder_init(&d2);
    struct frame_event ev = {0};
    for (size_t i = 0; i < an; i++) frame_decoder_push(&d2, acc[i], &ev);
    CHECK_EQ(ev.kind, FRAME_EV_FRAME);
    CHECK_EQ(ev.hdr.type, PROTO_T_GET_INFO);
    CHECK_EQ(ev.hdr.seq, 77);
    struct proto_get_info_resp r;
    CHECK_EQ(proto_get_info_resp_decode(ev.payload, ev.payload_len, &r), 0);
    CHECK_EQ(r.protocol_version, PROTO_VERSION);
    CHECK_EQ(r.max_payload, PROTO_MAX_PAYLOAD);
    CHECK(strcmp(r.board, board_name()) == 0);
    char ver[32];
    snprintf(ver, sizeof ver, "%u.%u.%u", r.fw_major, r.fw_minor, r.fw_patch);
    CHECK(strcmp(ver, UWBCAL_FW_VERSION) == 0);
    CHECK(strncmp(r.git_hash, UWBCAL_GIT_HASH, 12) == 0);
    uint8_t uid[12];
    board_uid(uid);
    CHECK_MEM(r.uid, 12, uid, 12);
    if (board_dw_ops() == NULL) CHECK_EQ(r.dev_id, 0);
    /* UIDs: stable and distinct per station id. */
    uint8_t a[12], b[12];
    int distinct = 1;
    for (unsigned id = 1; id < 2000; id++) {
        native_uid_for_id((uint16_t)id, a);
        native_uid_for_id((uint16_t)(id + 1), b);
        distinct &= memcmp(a, b, 12) != 0;
        native_uid_for_id((uint16_t)id, b);
        distinct &= memcmp(a, b, 12) == 0;
    }
    CHECK(distinct);
}

static void test_lengths(void)
{
    /* Core requests with a wrong payload length: bad_length with the length as detail. */
    static const uint8_t types[] = {PROTO_T_GET_INFO, PROTO_T_RESET};
    static uint8_t payload[PROTO_MAX_PAYLOAD], req[FRAME_TX_MAX], acc[FRAME_TX_MAX];
    for (size_t t = 0; t < sizeof types; t++) {
        for (size_t len = 1; len <= PROTO_MAX_PAYLOAD; len += 37) {
            struct proto_header h = {PROTO_VERSION, types[t], 0, (uint16_t)len};
            size_t n = frame_encode(&h, payload, len, req, sizeof req), an = 0;
            int events = 0;
            check_context("type %u length %zu", types[t], len);
            CHECK_EQ(run_bytes(req, n, acc, sizeof acc, &an, &events), 1);
            uint8_t want[FRAME_TX_MAX];
            size_t wn = dispatch_error_frame((uint16_t)len, PROTO_ERR_BAD_LENGTH, types[t], (uint16_t)len,
                                             want, sizeof want);
            CHECK_MEM(acc, an, want, wn);
        }
    }
}

static void test_fuzz(void)
{
    static uint8_t buf[1 << 16], acc[64 * FRAME_TX_MAX];
    uint32_t rng = 99;
    long total_events = 0, total_answers = 0;
    for (int round = 0; round < 400; round++) {
        size_t n = 0;
        /* a mix of random bytes and mutated (>= 1 byte changed) copies of the vectors */
        while (n < sizeof buf - 2 * FRAME_TX_MAX) {
            uint32_t what = check_rand(&rng) % 4;
            if (what == 0) {
                size_t k = check_rand(&rng) % 200;
                for (size_t i = 0; i < k; i++) buf[n++] = (uint8_t)check_rand(&rng);
            } else {
                const uint8_t *w;
                size_t wl;
                if (what == 1) {
                    const struct malformed_vector *v = &malformed_vectors[check_rand(&rng) % N_MALFORMED_VECTORS];
                    w = v->wire;
                    wl = v->wire_len;
                } else {
                    const struct frame_vector *v = &frame_vectors[check_rand(&rng) % N_FRAME_VECTORS];
                    w = v->wire;
                    wl = v->wire_len;
                }
                memcpy(buf + n, w, wl);
                size_t flips = 1 + check_rand(&rng) % 3;
                for (size_t f = 0; f < flips; f++) buf[n + check_rand(&rng) % wl] ^= (uint8_t)(1 + check_rand(&rng) % 255);
                n += wl;
            }
            if (check_rand(&rng) % 16 == 0) break;
        }
        buf[n++] = 0;
        size_t an = 0;
        int events = 0;
        check_context("fuzz round %d", round);
        int answers = run_bytes(buf, n, acc, sizeof acc, &an, &events);
        CHECK_EQ(answers, events); /* exactly one answer per frame */
        if (an < sizeof acc) CHECK_EQ(check_answers(acc, an), answers);
        total_events += events;
        total_answers += answers;
    }
    printf("fuzz: %ld frames, %ld answers\n", total_events, total_answers);
}

/* Read one frame (up to and including 0x00) from fd, waiting at most ~2 s in total. */
static size_t read_frame_fd(int fd, uint8_t *buf, size_t cap)
{
    size_t n = 0;
    for (int tries = 0; tries < 200 && n < cap; tries++) {
        app_poll();
        struct pollfd p = {.fd = fd, .events = POLLIN};
        if (poll(&p, 1, 10) <= 0) continue;
        while (n < cap && read(fd, buf + n, 1) == 1) {
            if (buf[n++] == 0) return n;
        }
    }
    return n;
}

static void test_app_pty(void)
{
    check_context("app over a pty");
    CHECK_EQ(native_link_open(), 0);
    int s = open(native_link_path(), O_RDWR | O_NOCTTY | O_NONBLOCK);
    CHECK(s >= 0);
    if (s < 0) return;
    struct termios t;
    tcgetattr(s, &t);
    cfmakeraw(&t);
    tcsetattr(s, TCSANOW, &t);
    app_init();
    const struct frame_vector *ping = &frame_vectors[2], *pong = &frame_vectors[3];
    static uint8_t buf[FRAME_TX_MAX * 2];
    CHECK_EQ(write(s, "\0", 1), 1);
    CHECK_EQ(write(s, ping->wire, ping->wire_len), (long)ping->wire_len);
    size_t n = read_frame_fd(s, buf, sizeof buf);
    CHECK_MEM(buf, n, pong->wire, pong->wire_len);
    const uint8_t rec[4] = {1, 2, 3, 4};
    for (unsigned k = 0; k < 3; k++) {
        CHECK_EQ(app_send_stream(PROTO_T_TRIPLETS, rec, sizeof rec), 0);
        n = read_frame_fd(s, buf, sizeof buf);
        struct frame_decoder d2;
        frame_decoder_init(&d2);
        struct frame_event ev = {0};
        for (size_t i = 0; i < n; i++) frame_decoder_push(&d2, buf[i], &ev);
        CHECK_EQ(ev.kind, FRAME_EV_FRAME);
        CHECK_EQ(ev.hdr.flags, PROTO_FLAG_STREAM);
        CHECK_EQ(ev.hdr.type, PROTO_T_TRIPLETS);
        CHECK_EQ(ev.hdr.seq, k);
        CHECK_MEM(ev.payload, ev.payload_len, rec, sizeof rec);
    }
    CHECK_EQ(app_send_stream(PROTO_T_PING, rec, sizeof rec), -1);
    CHECK_EQ(app_send_stream(PROTO_T_TRIPLETS, rec, PROTO_MAX_PAYLOAD + 1), -1);
    close(s);
}

int main(void)
{
    frame_decoder_init(&d);
    test_vectors();
    test_get_info();
    test_lengths();
    test_fuzz();
    test_app_pty();
    return check_summary();
}
