/* Calibration tables on the station: validation, the table_* message handlers, and the
 * application of the table to a ranging exchange (the paper's TWR with E1, E2 and Z).
 *
 * The table format is the cal_table struct of protocol/messages/tables.toml (generated into
 * proto_gen.h); the bytes are kept by table_store.c. docs/TABLES.md is the prose.
 *
 * Who applies what. E1 is the tag's RX timestamp error of M1 and belongs to the tag's curve;
 * E2 is the reference's RX error of M2 and belongs to the reference's curve; each station
 * holds only its own table. So each station computes its own share from its own table:
 *   - the tag, on receiving M1: e1_ps = caltable_rx_error_ps(M1's CIR_PWR, RXPACC, NOSAT) and its
 *     z share caltable_own_z_ps(), and sends both in its report to the reference;
 *   - the reference: caltable_ref_range_mm(t, M2's registers, tag's e1_ps and z_ps), which
 *     adds its own E2 and z share. Z = z_ref + z_tag (each table holds the station's half).
 * When either side has no usable table the station range is PROTO_NO_RANGE_MM (INT32_MIN),
 * never a half-corrected number; the host recomputes from raw timestamps in any case
 * (host/uwbcal/tables.py, same vectors: tests/firmware/test_table_vectors.json).
 */
#ifndef UWBCAL_CALTABLE_H
#define UWBCAL_CALTABLE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "proto_gen.h"

/* The format version, the limits (PROTO_TABLE_*: points, bounds, allowed radio settings, read
 * chunk, the detail bit of table_commit) and the slot states are constants of
 * protocol/messages/tables.toml, generated into proto_gen.h and the host's proto_gen.py. */
#define CALTABLE_OK (-1)   /* caltable_validate: no bad field */
_Static_assert(PROTO_TABLE_READ_MAX <= PROTO_TABLE_READ_RESP_DATA_MAX, "a read chunk fits a response");

/* Decode a serialised table (no checks beyond the length). false if len is wrong. */
bool caltable_decode(const uint8_t *buf, size_t len, struct proto_cal_table *out);

/* Check a serialised table: CRC, format, radio settings, NaN, bounds, monotonic axes.
 * uid: the station's uid, or NULL to skip the uid check. Returns CALTABLE_OK or the index of
 * the first bad field of cal_table. */
int caltable_validate(const uint8_t *buf, size_t len, const uint8_t uid[12]);

/* Timestamp error at a measured RX level, ps (measured minus true), from a decoded table:
 * linear interpolation in curve_dbm, clamped at the ends (as numpy.interp). */
double caltable_error_at_dbm(const struct proto_cal_table *t, double level_dbm);

/* N of the RX level estimate: RXPACC, less the SFD symbols it counts when it equals
 * RXPACC_NOSAT (user manual, RXPACC_NOSAT; standard SFD: DW1000_RXPACC_SFD_CORR*), floored at 0.
 * data_rate is cal_table's code (0 = 110 kb/s). The host's uwbcal.dw1000.rxpacc_n is the same. */
uint16_t caltable_rxpacc_n(uint16_t rxpacc, uint16_t rxpacc_nosat, uint8_t data_rate);

/* Measured RX level, dBm: 10 log10(C 2^17 / N^2) - A (user manual 4.7.2). false when C or N
 * is 0. a_dbm = 121.74 at PRF 64. */
bool caltable_rx_level_dbm(uint16_t cir_pwr, uint16_t rxpacc, double a_dbm, double *level_dbm);

/* E of one reception from a decoded table: level from the registers (N corrected for the SFD
 * at the table's data rate) with the table's A, then the curve. false when the registers give
 * no level. */
bool caltable_table_error_ps(const struct proto_cal_table *t, uint16_t cir_pwr, uint16_t rxpacc,
                             uint16_t rxpacc_nosat, double *e_ps);

/* The paper's corrected range, mm, from t[6] = t1r t1t t2t t2r t3r t3t (40-bit device
 * units, wrap-safe), E1, E2 and Z (ps). PROTO_NO_RANGE_MM if dT13 at the tag is 0 or the
 * result does not fit. */
int32_t caltable_range_mm(const uint64_t t[6], double e1_ps, double e2_ps, double z_ps);
/* The same, time of flight in device units without Z (for tests against the host). */
double caltable_tof_units(const uint64_t t[6], double e1_units, double e2_units);

/* ---- the station's own active table ---------------------------------------------------- */
/* At boot: scan the flash slots and load the active table if it validates. Optional: the
 * first table request or caltable_active() does it when nobody did. */
void caltable_init(void);
/* Back to the power-on state: nothing loaded, nothing staged (tests restart this way). */
void caltable_reset_state(void);
/* The station's active, validated table, or NULL. */
const struct proto_cal_table *caltable_active(void);
/* E of one reception of this station, ps, from its active table. */
bool caltable_rx_error_ps(uint16_t cir_pwr, uint16_t rxpacc, uint16_t rxpacc_nosat, float *e_ps);
/* This station's share of Z, ps. false without a table. */
bool caltable_own_z_ps(float *z_ps);
/* Reference side: corrected range with its own E2 and z share plus the tag's reported share.
 * PROTO_NO_RANGE_MM when this station or the tag (tag_valid false) has no table. */
int32_t caltable_ref_range_mm(const uint64_t t[6], uint16_t cir_pwr_r2, uint16_t rxpacc_r2,
                              uint16_t rxpacc_nosat_r2, bool tag_valid, float tag_e1_ps, float tag_z_ps);

#endif
