/* Measurement runtime: owns the station's one running activity (sequencer, triplet
 * listener, ranging reference or tag), its counters and the record ring that streams
 * triplet_record / range_record batches to the host.
 *
 * app.c calls measure_init() once and measure_poll() every main-loop iteration; the
 * measurement handlers (radio_config, listen, seq_start, range_start, stop, status) are the
 * strong definitions of the generated weak handle_* functions. measure_poll() never blocks
 * longer than RADIO_SLICE_US, so host requests (stop) are served while a plan runs.
 */
#ifndef UWBCAL_MEASURE_H
#define UWBCAL_MEASURE_H

#include <stdbool.h>
#include <stdint.h>

#include "proto_gen.h"

enum meas_mode {
    MEAS_IDLE = 0,
    MEAS_SEQUENCER = 1,
    MEAS_LISTEN = 2,
    MEAS_RANGE_REF = 3,
    MEAS_RANGE_TAG = 4,
};

struct meas_counters {
    uint32_t sent;        /* triplets (sequencer) or frames (ranging) sent */
    uint32_t records;     /* records produced (streamed or dropped) */
    uint32_t dropped;     /* records not streamed: overwritten in the ring before they went out, or the host link write
                           failed (the host can still fetch those the ring holds) */
    uint32_t late;        /* delayed TX refused (HPDWARN or below the minimum lead) */
    uint32_t rx_errors;   /* RX error events (and RX timeouts of a ranging exchange) */
    uint32_t tx_timeouts; /* TX that never reported TXFRS by its deadline */
    uint32_t incomplete;  /* triplets / exchanges abandoned part way */
    uint32_t stamp_mismatch; /* sequencer: TX_TIME differed from the stamp announced in the frame */
};

/* Record ring capacity (records, 152 bytes each): the most recent records of an activity,
 * kept until the next one begins so that the host can fetch what it missed. Sized to the
 * EVK1000's RAM budget (16 KB with the rest of the image; `make firmware` prints it); a build
 * for a smaller target may shrink it with -DMEAS_RING_CAP=N. */
#ifndef MEAS_RING_CAP
#define MEAS_RING_CAP 32u
#endif

void measure_init(void);
void measure_poll(void);
/* True while an activity runs (the main loop must not idle-wait then). */
bool measure_busy(void);

enum meas_mode measure_mode(void);
const struct meas_counters *measure_counters(void);
struct meas_counters *measure_counters_mut(void);

/* Producers (sequencer.c, ranging.c): put one record in the ring; counts records, and dropped
 * when the oldest unsent record had to be overwritten. */
void measure_emit_triplet(const struct proto_triplet_record *r);
void measure_emit_range(const struct proto_range_record *r);
/* Stream every unsent record now (used by stop and at the end of a plan). */
void measure_flush(void);
/* Records in the ring not streamed yet. */
unsigned measure_queued(void);
/* Diagnostics and tests: the i-th unsent record (0 = oldest) and its running index; t or r
 * (whichever matches the ring's type) may be NULL. false when i >= measure_queued(). */
bool measure_peek(unsigned i, uint32_t *index, struct proto_triplet_record *t, struct proto_range_record *r);
/* The DW_E* code that stopped the last activity, 0 when none. */
int measure_last_failure(void);

#endif
