/* At-most-once requests (dispatch.c): a request frame identical to the last one answered
 * (same seq, same bytes) gets the same answer byte for byte and its handler does not run again;
 * the same seq with other bytes, another seq, or a forgotten memory runs the handler. Fed
 * through the real decoder and dispatcher, as the main loop does. The non-idempotent request
 * used is table_commit (it consumes the staged upload and bumps the slot sequence), on the
 * native board's RAM-only flash (no file). */
#include <stdlib.h>

#include "board.h"
#include "cal_table.h"
#include "check.h"
#include "crc32.h"
#include "dispatch.h"
#include "frame.h"
#include "proto_gen.h"
#include "table_store.h"

#define TS PROTO_CAL_TABLE_WIRE_SIZE
#define CHUNK 256u

static struct frame_decoder dec;

/* An answer as it went on the wire. */
struct answer {
    uint8_t wire[FRAME_TX_MAX];
    size_t len;
};

/* Wire bytes of a request frame (with delimiter). */
static size_t request_wire(uint8_t type, uint16_t seq, uint8_t flags, const uint8_t *p, size_t n,
                           uint8_t *out, size_t cap)
{
    struct proto_header h = {.version = PROTO_VERSION, .type = type, .flags = flags, .seq = seq};
    return frame_encode(&h, p, n, out, cap);
}

/* Feed wire bytes; returns how many answers came back, the last one in *a. */
static int feed(const uint8_t *w, size_t n, struct answer *a)
{
    static uint8_t out[FRAME_TX_MAX];
    int answers = 0;
    a->len = 0;
    for (size_t i = 0; i < n; i++) {
        struct frame_event ev;
        if (frame_decoder_push(&dec, w[i], &ev) == FRAME_EV_NONE) continue;
        size_t k = dispatch_event(&ev, out, sizeof out);
        if (k == 0) continue;
        answers++;
        memcpy(a->wire, out, k);
        a->len = k;
    }
    return answers;
}

/* Send one request frame, expect exactly one answer. */
static struct answer send_req(uint8_t type, uint16_t seq, const uint8_t *p, size_t n)
{
    static uint8_t w[FRAME_TX_MAX];
    struct answer a;
    size_t wn = request_wire(type, seq, 0, p, n, w, sizeof w);
    CHECK(wn > 0);
    CHECK_EQ(feed(w, wn, &a), 1);
    return a;
}

/* Decode an answer frame: returns its header; payload copied to p (cap bytes), length in *n. */
static struct proto_header decode_answer(const struct answer *a, uint8_t *p, size_t cap, size_t *n)
{
    struct frame_decoder d2;
    frame_decoder_init(&d2);
    struct frame_event ev = {0};
    struct proto_header h = {0};
    *n = 0;
    for (size_t i = 0; i < a->len; i++) {
        if (frame_decoder_push(&d2, a->wire[i], &ev) != FRAME_EV_FRAME) continue;
        h = ev.hdr;
        *n = ev.payload_len < cap ? ev.payload_len : cap;
        memcpy(p, ev.payload, *n);
    }
    CHECK_EQ(ev.kind, FRAME_EV_FRAME);
    return h;
}

/* The ERROR code of an answer, 0 if it is a response of request type `type`. */
static int answer_code(const struct answer *a, uint8_t type, uint16_t seq)
{
    uint8_t p[PROTO_MAX_PAYLOAD];
    size_t n;
    struct proto_header h = decode_answer(a, p, sizeof p, &n);
    CHECK_EQ(h.seq, seq);
    CHECK_EQ(h.flags, PROTO_FLAG_RESPONSE);
    if (h.type == type) return 0;
    CHECK_EQ(h.type, PROTO_T_ERROR);
    struct proto_error_resp e;
    CHECK_EQ(proto_error_resp_decode(p, n, &e), 0);
    CHECK_EQ(e.request_type, type);
    return e.code;
}

/* A valid table (forced on commit, so the uid does not matter), sealed. */
static void make_table(uint8_t *b)
{
    uint8_t uid[12];
    board_uid(uid);
    test_cal_table(b, uid, -500.0f);
}

/* Stage a table with table_write requests, seqs from *seq on. */
static void stage(const uint8_t *t, uint16_t *seq)
{
    for (size_t off = 0; off < TS; off += CHUNK) {
        size_t n = TS - off < CHUNK ? TS - off : CHUNK;
        uint8_t p[2 + CHUNK];
        p[0] = (uint8_t)off;
        p[1] = (uint8_t)(off >> 8);
        memcpy(p + 2, t + off, n);
        struct answer a = send_req(PROTO_T_TABLE_WRITE, (*seq)++, p, n + 2);
        CHECK_EQ(answer_code(&a, PROTO_T_TABLE_WRITE, (uint16_t)(*seq - 1)), 0);
    }
}

static size_t commit_payload(const uint8_t *t, uint8_t *p, size_t cap)
{
    struct proto_table_commit_req r = {.length = TS, .crc32 = crc32_update(0, t, TS - 4u), .force = 1};
    size_t n = 0;
    CHECK_EQ(proto_table_commit_req_encode(&r, p, cap, &n), 0);
    return n;
}

static struct proto_table_info_resp table_info(uint16_t seq)
{
    struct answer a = send_req(PROTO_T_TABLE_INFO, seq, NULL, 0);
    uint8_t p[PROTO_MAX_PAYLOAD];
    size_t n;
    struct proto_table_info_resp r;
    memset(&r, 0, sizeof r);
    decode_answer(&a, p, sizeof p, &n);
    CHECK_EQ(proto_table_info_resp_decode(p, n, &r), 0);
    return r;
}

static void test_ping(void)
{
    check_context("ping");
    const uint8_t abc[3] = {'a', 'b', 'c'}, abd[3] = {'a', 'b', 'd'};
    static uint8_t want[FRAME_TX_MAX];
    struct proto_header rh = {.version = PROTO_VERSION, .type = PROTO_T_PING, .flags = PROTO_FLAG_RESPONSE,
                              .seq = 10};
    size_t wn = frame_encode(&rh, abc, sizeof abc, want, sizeof want);
    uint32_t r0 = dispatch_replayed();

    struct answer a1 = send_req(PROTO_T_PING, 10, abc, sizeof abc);
    struct answer a2 = send_req(PROTO_T_PING, 10, abc, sizeof abc);
    CHECK_MEM(a1.wire, a1.len, want, wn);
    CHECK_MEM(a2.wire, a2.len, a1.wire, a1.len);
    CHECK_EQ(dispatch_replayed(), r0 + 1);

    /* same seq, same type and length, other bytes: a new request, echoed anew */
    struct answer a3 = send_req(PROTO_T_PING, 10, abd, sizeof abd);
    uint8_t p[8];
    size_t n;
    decode_answer(&a3, p, sizeof p, &n);
    CHECK_MEM(p, n, abd, sizeof abd);
    CHECK_EQ(dispatch_replayed(), r0 + 1);

    /* a frame the decoder rejects (bad CRC: seq 0 ERROR) between attempts changes nothing */
    static uint8_t w[FRAME_TX_MAX];
    size_t k = request_wire(PROTO_T_PING, 10, 0, abd, sizeof abd, w, sizeof w);
    uint8_t *pa = memchr(w, 'a', k); /* a payload byte, unchanged by COBS: 'z' keeps it valid COBS */
    CHECK(pa != NULL);
    if (pa != NULL) *pa = 'z';
    struct answer bad;
    CHECK_EQ(feed(w, k, &bad), 1);
    CHECK_EQ(answer_code(&bad, 0, 0), PROTO_ERR_BAD_CRC);
    struct answer a4 = send_req(PROTO_T_PING, 10, abd, sizeof abd);
    CHECK_MEM(a4.wire, a4.len, a3.wire, a3.len);
    CHECK_EQ(dispatch_replayed(), r0 + 2);
}

static void test_commit_once(void)
{
    check_context("table_commit");
    static uint8_t t[TS];
    make_table(t);
    uint16_t seq = 100;
    uint8_t cp[16];
    size_t cn = commit_payload(t, cp, sizeof cp);

    struct proto_table_info_resp i0 = table_info(seq++);
    CHECK_EQ(i0.active, 0xFF);

    /* commit, then the host's retry of the same frame (its answer was lost) */
    stage(t, &seq);
    uint16_t cseq = seq++;
    struct answer c1 = send_req(PROTO_T_TABLE_COMMIT, cseq, cp, cn);
    struct answer c2 = send_req(PROTO_T_TABLE_COMMIT, cseq, cp, cn);
    CHECK_EQ(answer_code(&c1, PROTO_T_TABLE_COMMIT, cseq), 0);
    CHECK_MEM(c2.wire, c2.len, c1.wire, c1.len);
    uint8_t p[16];
    size_t n;
    decode_answer(&c1, p, sizeof p, &n);
    struct proto_table_commit_resp r;
    CHECK_EQ(proto_table_commit_resp_decode(p, n, &r), 0);
    CHECK_EQ(r.slot, 0);
    CHECK_EQ(r.sequence, 1);
    /* the handler ran once: one slot written, the second still empty */
    struct proto_table_info_resp i1 = table_info(seq++);
    CHECK_EQ(i1.active, 0);
    CHECK_EQ(i1.slot0_sequence, 1);
    CHECK_EQ(i1.slot1_state, PROTO_TABLE_SLOT_STATE_EMPTY);

    /* the same commit bytes under another seq are a new request: the handler runs and finds
     * the upload consumed */
    uint16_t dseq = seq++;
    struct answer d = send_req(PROTO_T_TABLE_COMMIT, dseq, cp, cn);
    CHECK_EQ(answer_code(&d, PROTO_T_TABLE_COMMIT, dseq), PROTO_ERR_BAD_VALUE);
    /* only the last request is remembered: the first commit's frame is now new again */
    struct answer c3 = send_req(PROTO_T_TABLE_COMMIT, cseq, cp, cn);
    CHECK_EQ(answer_code(&c3, PROTO_T_TABLE_COMMIT, cseq), PROTO_ERR_BAD_VALUE);

    /* staged again, two commits with different seqs and the same bytes both run */
    stage(t, &seq);
    uint16_t e1 = seq++;
    struct answer e = send_req(PROTO_T_TABLE_COMMIT, e1, cp, cn);
    CHECK_EQ(answer_code(&e, PROTO_T_TABLE_COMMIT, e1), 0);
    stage(t, &seq);
    uint16_t e2 = seq++;
    e = send_req(PROTO_T_TABLE_COMMIT, e2, cp, cn);
    CHECK_EQ(answer_code(&e, PROTO_T_TABLE_COMMIT, e2), 0);
    struct proto_table_info_resp i2 = table_info(seq++);
    CHECK_EQ(i2.slot1_sequence, 2);
    CHECK_EQ(i2.slot0_sequence, 3);
    CHECK_EQ(i2.active, 0);

    /* an ERROR answer is remembered too: the retry gets the same ERROR frame */
    uint8_t short_len[16];
    struct proto_table_commit_req bad = {.length = TS - 1u, .crc32 = 0, .force = 1};
    size_t bn = 0;
    CHECK_EQ(proto_table_commit_req_encode(&bad, short_len, sizeof short_len, &bn), 0);
    uint16_t fseq = seq++;
    uint32_t r0 = dispatch_replayed();
    struct answer f1 = send_req(PROTO_T_TABLE_COMMIT, fseq, short_len, bn);
    struct answer f2 = send_req(PROTO_T_TABLE_COMMIT, fseq, short_len, bn);
    CHECK_EQ(answer_code(&f1, PROTO_T_TABLE_COMMIT, fseq), PROTO_ERR_BAD_VALUE);
    CHECK_MEM(f2.wire, f2.len, f1.wire, f1.len);
    CHECK_EQ(dispatch_replayed(), r0 + 1);

    /* forgotten (a restart): the same frame runs its handler again */
    stage(t, &seq);
    uint16_t gseq = seq++;
    struct answer g1 = send_req(PROTO_T_TABLE_COMMIT, gseq, cp, cn);
    CHECK_EQ(answer_code(&g1, PROTO_T_TABLE_COMMIT, gseq), 0);
    dispatch_forget();
    struct answer g2 = send_req(PROTO_T_TABLE_COMMIT, gseq, cp, cn);
    CHECK_EQ(answer_code(&g2, PROTO_T_TABLE_COMMIT, gseq), PROTO_ERR_BAD_VALUE);
    CHECK_EQ(table_info(seq++).slot1_sequence, 4);
}

int main(void)
{
    frame_decoder_init(&dec);
    dispatch_forget();
    test_ping();
    test_commit_once();
    return check_summary();
}
