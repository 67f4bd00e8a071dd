/* A valid calibration table for the C unit tests that store or push one. */
#ifndef UWBCAL_TEST_CAL_TABLE_H
#define UWBCAL_TEST_CAL_TABLE_H

#include <stdint.h>

/* Encode into b (PROTO_CAL_TABLE_WIRE_SIZE bytes) a valid, sealed table for uid (12 bytes):
 * channel 2, PRF 64, preamble 128, 6.8 Mb/s, a 4-point curve (dBm -> ps) and map, z offset
 * z_ps (ps). */
void test_cal_table(uint8_t *b, const uint8_t uid[12], float z_ps);

#endif
