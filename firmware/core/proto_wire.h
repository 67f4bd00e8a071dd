/* Little-endian field access for the wire format (protocol/protocol.toml: little-endian, no
 * padding, no bitfields). Hand-written runtime of the generated proto_gen.c, and what the
 * other firmware files use when they pack bytes by hand (the flash slot header, the frame
 * CRC): one definition of byte order. Static inline, so unused helpers cost nothing. */
#ifndef UWBCAL_PROTO_WIRE_H
#define UWBCAL_PROTO_WIRE_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

static inline void wire_put_u8(uint8_t *b, uint8_t v) { b[0] = v; }
static inline void wire_put_u16(uint8_t *b, uint16_t v)
{
    b[0] = (uint8_t)v;
    b[1] = (uint8_t)(v >> 8);
}
static inline void wire_put_u32(uint8_t *b, uint32_t v)
{
    for (int i = 0; i < 4; i++) b[i] = (uint8_t)(v >> (8 * i));
}
static inline void wire_put_u64(uint8_t *b, uint64_t v)
{
    for (int i = 0; i < 8; i++) b[i] = (uint8_t)(v >> (8 * i));
}
static inline uint8_t wire_get_u8(const uint8_t *b) { return b[0]; }
static inline uint16_t wire_get_u16(const uint8_t *b) { return (uint16_t)(b[0] | (b[1] << 8)); }
static inline uint32_t wire_get_u32(const uint8_t *b)
{
    uint32_t v = 0;
    for (int i = 3; i >= 0; i--) v = (v << 8) | b[i];
    return v;
}
static inline uint64_t wire_get_u64(const uint8_t *b)
{
    uint64_t v = 0;
    for (int i = 7; i >= 0; i--) v = (v << 8) | b[i];
    return v;
}
static inline void wire_put_f32(uint8_t *b, float f)
{
    uint32_t v;
    memcpy(&v, &f, 4);
    wire_put_u32(b, v);
}
static inline void wire_put_f64(uint8_t *b, double f)
{
    uint64_t v;
    memcpy(&v, &f, 8);
    wire_put_u64(b, v);
}
static inline float wire_get_f32(const uint8_t *b)
{
    uint32_t v = wire_get_u32(b);
    float f;
    memcpy(&f, &v, 4);
    return f;
}
static inline double wire_get_f64(const uint8_t *b)
{
    uint64_t v = wire_get_u64(b);
    double f;
    memcpy(&f, &v, 8);
    return f;
}
/* str[n] on the wire: the text, NUL-padded to n bytes (not terminated when it fills n). */
static inline void wire_put_str(uint8_t *b, const char *s, size_t n)
{
    size_t i = 0;
    for (; i < n && s[i] != '\0'; i++) b[i] = (uint8_t)s[i];
    for (; i < n; i++) b[i] = 0;
}
/* Into s[n + 1], always terminated. */
static inline void wire_get_str(char *s, const uint8_t *b, size_t n)
{
    size_t i = 0;
    for (; i < n && b[i] != 0; i++) s[i] = (char)b[i];
    for (; i <= n; i++) s[i] = '\0';
}

#endif
