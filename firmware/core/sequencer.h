/* P1/P2/P3 sequencer (the TX side of the paper's drift and power calibration) and the
 * triplet receiver (listen role 0). Both are non-blocking state machines: each *_poll()
 * call does at most one bounded wait (RADIO_SLICE_US) and returns.
 *
 * Timing is in the DW1000's own clock: P1 of triplet k is programmed for
 * T1(k) = T1(0) + k * period (T1(0) = SYS_TIME at start + SEQ_LEAD_US), P2 and P3 at
 * T1 + spacing and T1 + 2 spacing (delayed TX, 512-unit grid), each frame carrying its own
 * TX timestamp (dx & ~0x1FF) + TX_ANTD. A TX is programmed only when its time is less than
 * SEQ_PROGRAM_AHEAD_US away (the chip accepts at most 2^39 units = 8.6 s), so spacings
 * up to 10 s work. A TX refused as late (HPDWARN, or closer than the frame's preamble)
 * abandons that triplet (counted late; its seq number is skipped, so the receiver sees it).
 */
#ifndef UWBCAL_SEQUENCER_H
#define UWBCAL_SEQUENCER_H

#include <stdbool.h>
#include <stdint.h>

#include "dw1000.h"
#include "measure.h"
#include "proto_gen.h"

#define SEQ_MAX_STEPS 64u
#define SEQ_SPACING_MIN_US 150u
#define SEQ_SPACING_MAX_US 10000000u
#define SEQ_LEAD_US 1000u          /* first P1 this far after the start */
#define SEQ_PROGRAM_AHEAD_US 3000u /* program a delayed TX when it is this close */
#define SEQ_TX_MARGIN_US 2000u     /* TXFRS deadline margin after the frame's end */
#define SEQ_PERIOD_MARGIN_US 100u  /* period >= 2 spacing + P3 air time + this */

struct seq_plan {
    uint32_t per_step, spacing_us, period_us;
    uint8_t gain13;
    uint8_t nsteps;
    uint8_t gains2[SEQ_MAX_STEPS];
};

/* Validate a seq_start request against the radio configuration; fills plan. Returns 0, or
 * PROTO_ERR_BAD_VALUE with *detail = index of the bad field (per_step 0, spacing_us 1,
 * period_us 2, gain13 3, gains2 4). */
int seq_plan_from_req(const struct proto_seq_start_req *req, const struct dw_config *cfg,
                      struct seq_plan *plan, uint16_t *detail);
/* Smallest period for a spacing: 2 spacing + P frame air time + SEQ_PERIOD_MARGIN_US. */
uint32_t seq_min_period_us(uint32_t spacing_us, const struct dw_config *cfg);
/* Shortest lead (us) a delayed TX needs: the preamble and SFD go out before the RMARKER. */
uint32_t seq_min_lead_us(const struct dw_config *cfg);
/* A gain octet with coarse gain 7 (output off) is refused. */
bool seq_gain_ok(uint8_t octet);

enum seq_state { SEQ_OFF = 0, SEQ_SCHEDULE, SEQ_WAIT_TX, SEQ_DONE };

struct seq_tx {
    struct seq_plan plan;
    enum seq_state st;
    uint16_t src;
    uint32_t step, rep, triplet; /* triplet = seq number sent in the frames */
    uint8_t idx;                 /* 0..2: P1..P3 */
    bool started;
    uint64_t t1;                 /* unwrapped device time of the current P1 */
    uint64_t spacing_u, period_u;
    uint64_t tx_deadline_us;
    uint64_t expect_stamp;       /* TX_STAMP announced in the frame (a mismatch is counted in
                                    meas_counters.stamp_mismatch, reported by stop and status) */
};

void seq_start(struct seq_tx *s, const struct seq_plan *plan, uint16_t src);
/* 1 running, 0 finished, <0 DW_E* radio failure (the activity must stop). */
int seq_poll(struct seq_tx *s, struct meas_counters *c);
uint32_t seq_total(const struct seq_plan *plan);

/* ---- triplet receiver (listen role 0) ------------------------------------------------ */
struct trip_rx {
    uint16_t peer; /* 0xFFFF: any */
    bool rx_on;
    bool have;     /* a partial triplet is being assembled */
    uint8_t next_idx;
    uint16_t src;
    struct proto_triplet_record rec;
};

void trip_rx_start(struct trip_rx *r, uint16_t peer);
/* 1 running, <0 DW_E*. Emits records through measure_emit_triplet. */
int trip_rx_poll(struct trip_rx *r, struct meas_counters *c);
void meas_q_to_proto(const struct dw_rx_quality *q, struct proto_rx_quality *p);

#endif
