/* COBS: every COBS vector both ways, seeded random round trips, bounds, and that decoding
 * arbitrary bytes never writes past the output buffer (ASan watches). */
#include "check.h"
#include "cobs.h"
#include "vectors_gen.h"

static uint8_t enc[4096], dec[4096], src[3000];

int main(void)
{
    for (size_t i = 0; i < N_COBS_VECTORS; i++) {
        const struct cobs_vector *v = &cobs_vectors[i];
        check_context("cobs vector '%s'", v->name);
        size_t n = cobs_encode(v->decoded, v->decoded_len, enc, sizeof enc);
        CHECK_MEM(enc, n, v->encoded, v->encoded_len);
        size_t m = 0, off = 0;
        CHECK_EQ(cobs_decode(v->encoded, v->encoded_len, dec, sizeof dec, &m, &off), COBS_OK);
        CHECK_MEM(dec, m, v->decoded, v->decoded_len);
        CHECK(n <= COBS_ENCODED_MAX(v->decoded_len));
        /* an output buffer one byte short is refused, never overrun */
        if (v->encoded_len > 0) CHECK_EQ(cobs_encode(v->decoded, v->decoded_len, enc, v->encoded_len - 1), 0);
        if (v->decoded_len > 0)
            CHECK_EQ(cobs_decode(v->encoded, v->encoded_len, dec, v->decoded_len - 1, &m, &off), COBS_ETOOLONG);
    }
    uint32_t rng = 2024;
    for (int round = 0; round < 3000; round++) {
        size_t len = check_rand(&rng) % sizeof src;
        unsigned zero_pct = check_rand(&rng) % 101; /* from no zeros to all zeros */
        for (size_t i = 0; i < len; i++)
            src[i] = (check_rand(&rng) % 100 < zero_pct) ? 0 : (uint8_t)(1 + check_rand(&rng) % 255);
        check_context("round trip %d, %zu bytes", round, len);
        size_t n = cobs_encode(src, len, enc, sizeof enc);
        CHECK(n >= 1 && n <= COBS_ENCODED_MAX(len));
        CHECK(memchr(enc, 0, n) == NULL);
        size_t m = 0;
        CHECK_EQ(cobs_decode(enc, n, dec, sizeof dec, &m, NULL), COBS_OK);
        CHECK_MEM(dec, m, src, len);
        /* the incremental encoder, fed in random pieces, gives the same bytes */
        static uint8_t enc2[4096];
        struct cobs_encoder e;
        cobs_encoder_init(&e, enc2, sizeof enc2);
        for (size_t i = 0; i < len;) {
            size_t k = 1 + check_rand(&rng) % 300;
            if (k > len - i) k = len - i;
            cobs_encoder_push(&e, src + i, k);
            i += k;
        }
        size_t n2 = cobs_encoder_finish(&e);
        CHECK_MEM(enc2, n2, enc, n);
        /* and refuses a buffer one byte short */
        cobs_encoder_init(&e, enc2, n - 1);
        cobs_encoder_push(&e, src, len);
        CHECK_EQ(cobs_encoder_finish(&e), 0);
    }
    /* Arbitrary input: decode into a tight buffer; a result is either an error or fits. */
    for (int round = 0; round < 20000; round++) {
        size_t len = check_rand(&rng) % 700;
        for (size_t i = 0; i < len; i++) src[i] = (uint8_t)check_rand(&rng);
        size_t cap = check_rand(&rng) % 600;
        static uint8_t tight[600];
        size_t m = 0, off = 0;
        int rc = cobs_decode(src, len, tight, cap, &m, &off);
        if (rc == COBS_OK) CHECK(m <= cap);
        else if (rc == COBS_EBAD) CHECK(off < len);
        else CHECK_EQ(rc, COBS_ETOOLONG);
    }
    /* An error offset points at the byte named in the vectors' bad_cobs case. */
    static const uint8_t bad[] = {0x05, 0x01, 0x02};
    size_t m = 0, off = 99;
    check_context("bad code byte");
    CHECK_EQ(cobs_decode(bad, sizeof bad, dec, sizeof dec, &m, &off), COBS_EBAD);
    CHECK_EQ(off, 0);
    static const uint8_t zero_inside[] = {0x03, 0x01, 0x00};
    CHECK_EQ(cobs_decode(zero_inside, sizeof zero_inside, dec, sizeof dec, &m, &off), COBS_EBAD);
    CHECK_EQ(off, 2);
    return check_summary();
}
