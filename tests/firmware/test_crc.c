/* CRC-32/ISO-HDLC: every CRC vector of protocol/vectors.json, the catalogue check value, and
 * that a CRC continued over pieces equals the CRC of the whole. */
#include "check.h"
#include "crc32.h"
#include "vectors_gen.h"

int main(void)
{
    for (size_t i = 0; i < N_CRC_VECTORS; i++) {
        const struct crc_vector *v = &crc_vectors[i];
        check_context("crc vector '%s'", v->name);
        CHECK_EQ(crc32_iso_hdlc(v->data, v->len), v->crc);
    }
    check_context("check value");
    CHECK_EQ(crc32_iso_hdlc((const uint8_t *)"123456789", 9), PROTO_CRC_CHECK);
    CHECK_EQ(PROTO_CRC_CHECK, 0xCBF43926u);
    /* Continuation: split every vector at every point (seeded sizes for the long ones). */
    uint32_t rng = 12345;
    for (size_t i = 0; i < N_CRC_VECTORS; i++) {
        const struct crc_vector *v = &crc_vectors[i];
        check_context("split '%s'", v->name);
        for (size_t cut = 0; cut <= v->len; cut += 1 + check_rand(&rng) % 7) {
            uint32_t c = crc32_update(crc32_update(0, v->data, cut), v->data + cut, v->len - cut);
            CHECK_EQ(c, v->crc);
        }
    }
    /* A single flipped bit always changes the CRC (CRC-32 detects every 1-bit error). */
    uint8_t buf[64];
    for (size_t i = 0; i < sizeof buf; i++) buf[i] = (uint8_t)check_rand(&rng);
    uint32_t ref = crc32_iso_hdlc(buf, sizeof buf);
    int changed = 0;
    for (size_t bit = 0; bit < sizeof buf * 8; bit++) {
        buf[bit / 8] ^= (uint8_t)(1u << (bit % 8));
        changed += crc32_iso_hdlc(buf, sizeof buf) != ref;
        buf[bit / 8] ^= (uint8_t)(1u << (bit % 8));
    }
    check_context("bit flips");
    CHECK_EQ(changed, sizeof buf * 8);
    return check_summary();
}
