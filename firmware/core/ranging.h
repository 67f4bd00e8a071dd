/* Two-way ranging: the reference role (range_start) and the tag role (listen role 1).
 *
 * Exchange k (REGISTERS.md section 6 has the frame layouts):
 *   ref  M1 at t1r (delayed, on the period grid)            -> tag receives at t1t
 *   tag  M2 at t2t = grid(t1t + reply) + TX_ANTD, carries t1t, t2t -> ref receives at t2r
 *   ref  M3 at t3r = grid(t2r + reply) + TX_ANTD, carries t2r, t3r -> tag receives at t3t
 *   tag  REPORT at t3t + reply: t1t t2t t3t, RX quality of M1 and M3, its E1 and Z share
 * Method 0 (paper) and 2 (asymmetric DS-TWR) use the same four frames; method 1
 * (single-sided) stops after M2, and the tag reports at t2t + reply with t3t = 0.
 * The reference streams one range_record per completed exchange with
 * t = {t1r, t1t, t2t, t2r, t3r, t3t}. A late TX or a missed frame abandons the exchange
 * (counted: late, rx_errors for a reception that never came, incomplete).
 */
#ifndef UWBCAL_RANGING_H
#define UWBCAL_RANGING_H

#include <stdbool.h>
#include <stdint.h>

#include "dw1000.h"
#include "measure.h"
#include "proto_gen.h"

#define RNG_REPLY_MIN_US 200u
#define RNG_REPLY_MAX_US 1000000u
#define RNG_LEAD_US 1000u
#define RNG_PROGRAM_AHEAD_US 3000u
#define RNG_MARGIN_US 2000u

enum rng_ref_state { RREF_OFF = 0, RREF_SCHED_M1, RREF_WAIT_M1_TX, RREF_WAIT_M2, RREF_WAIT_M3_TX, RREF_WAIT_REPORT, RREF_DONE };

struct rng_ref {
    enum rng_ref_state st;
    uint8_t method, gain;
    uint16_t tag, src;
    uint32_t count, k;
    uint64_t period_u, reply_u;
    uint32_t reply_us;
    bool started;
    uint64_t t1;            /* unwrapped device time of this exchange's M1 */
    uint64_t deadline_us;
    uint64_t expect_stamp;
    struct proto_range_record rec;
};

enum rng_tag_state { RTAG_OFF = 0, RTAG_LISTEN, RTAG_WAIT_M2_TX, RTAG_WAIT_M3, RTAG_WAIT_REP_TX };

struct rng_tag {
    enum rng_tag_state st;
    uint16_t peer, src;
    uint16_t ref;           /* source of the exchange in progress */
    uint32_t reply_us;
    uint64_t reply_u;
    bool rx_on;
    uint32_t seq;
    uint8_t method, gain;
    uint64_t t1t, t2t, t3t;
    struct dw_rx_quality q1, q3;
    uint64_t deadline_us;
};

/* Validate range_start: 0 or PROTO_ERR_BAD_VALUE with *detail = field index
 * (method 0, tag 1, count 2, period_us 3, reply_us 4, gain 5). */
int rng_ref_check(const struct proto_range_start_req *req, const struct dw_config *cfg, uint16_t *detail);
uint32_t rng_min_period_us(uint8_t method, uint32_t reply_us, const struct dw_config *cfg);
void rng_ref_start(struct rng_ref *r, const struct proto_range_start_req *req, uint16_t src);
/* 1 running, 0 finished, <0 DW_E*. */
int rng_ref_poll(struct rng_ref *r, struct meas_counters *c);

void rng_tag_start(struct rng_tag *t, uint16_t peer, uint32_t reply_us, uint16_t src);
/* 1 running, <0 DW_E*. */
int rng_tag_poll(struct rng_tag *t, struct meas_counters *c);

/* The station's corrected range for a record (caltable.h when the station has a table),
 * INT32_MIN otherwise. */
int32_t rng_station_range_mm(const struct proto_range_record *rec, bool tag_valid, float e1_ps, float z_ps);

#endif
