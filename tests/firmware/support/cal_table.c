/* See cal_table.h. */
#include "cal_table.h"

#include <string.h>

#include "crc32.h"
#include "proto_gen.h"

void test_cal_table(uint8_t *b, const uint8_t uid[12], float z_ps)
{
    static struct proto_cal_table t;
    memset(&t, 0, sizeof t);
    t.format_version = 1;
    memcpy(t.uid, uid, 12);
    t.channel = 2;
    t.prf_mhz = 64;
    t.preamble_len = 128;
    t.data_rate = 2;
    t.n_curve = 4;
    t.n_map = 4;
    t.created_unix = 1763769600u;
    strcpy(t.host_version, "0.1.0");
    t.z_ps = z_ps;
    const float lv[4] = { -100.0f, -90.0f, -80.0f, -70.0f }, e[4] = { 100.0f, 0.0f, -100.0f, -300.0f };
    for (int i = 0; i < 4; i++) {
        t.curve_dbm[i] = lv[i];
        t.curve_ps[i] = e[i];
        t.map_measured_dbm[i] = lv[i];
        t.map_real_dbm[i] = lv[i] + (float)i;
    }
    t.a_dbm = 121.74f;
    proto_cal_table_encode(&t, b);
    t.crc32 = crc32_update(0, b, PROTO_CAL_TABLE_WIRE_SIZE - 4u);
    proto_cal_table_encode(&t, b);
}
