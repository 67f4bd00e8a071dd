/* CRC-32/ISO-HDLC (the zlib/Ethernet CRC): poly 0x04C11DB7 reflected, init and xorout
 * 0xFFFFFFFF. Check value of "123456789": 0xCBF43926. 16-entry table (64 bytes). */
#ifndef UWBCAL_CRC32_H
#define UWBCAL_CRC32_H

#include <stddef.h>
#include <stdint.h>

/* Continue a CRC: pass 0 to start; crc32_update(crc32_update(0, a), b) == CRC of a|b. */
uint32_t crc32_update(uint32_t crc, const uint8_t *data, size_t len);

static inline uint32_t crc32_iso_hdlc(const uint8_t *data, size_t len)
{
    return crc32_update(0, data, len);
}

#endif
