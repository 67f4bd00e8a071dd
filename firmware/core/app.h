/* The station's main loop, shared by every board: read the host link, decode frames,
 * dispatch requests, send responses, let the measurement module run.
 *
 * A board's main() calls app_init() once, then app_poll() in a loop and board_idle() when
 * app_poll() returns false:
 *     app_init();
 *     for (;;) if (!app_poll()) board_idle(app_idle_us());
 */
#ifndef UWBCAL_APP_H
#define UWBCAL_APP_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

/* Longest idle when nothing asks for less, us. board_idle() wakes earlier on link input. */
#define APP_IDLE_MAX_US 10000u

void app_init(void);
/* One iteration: returns true if it did work (bytes arrived), false if the caller may idle. */
bool app_poll(void);
/* How long the caller may idle now, us: min(APP_IDLE_MAX_US, measure_idle_us()). */
uint32_t app_idle_us(void);

/* Send a streamed record frame: flags.stream, seq = this type's own frame counter (starting
 * at 0, wrapping at 0xFFFF, counted even when the link write fails so the host sees the
 * loss). type must be in PROTO_STREAM_FIRST..PROTO_STREAM_LAST. Returns 0, or a negative
 * value (-1 bad type or length, -2 link write failed). */
int app_send_stream(uint8_t type, const uint8_t *payload, size_t len);

/* Ask for board_reset() once the current response has been sent (used by RESET). */
void app_request_reset(void);

/* Counters for diagnostics and tests. */
struct app_stats {
    uint32_t frames;      /* requests dispatched (good CRC), retries answered from memory
                           * included (dispatch_replayed() counts those) */
    uint32_t frame_errors; /* frames rejected by the decoder (bad COBS, CRC, length) */
    uint32_t tx_failures; /* link writes that failed */
};
const struct app_stats *app_stats(void);

/* ---- hooks of the measurement module (weak no-op defaults in app.c) ---- */
void measure_init(void);         /* from app_init() */
void measure_poll(void);         /* every app_poll() iteration; must not block long */
uint32_t measure_idle_us(void);  /* longest idle it tolerates now; default APP_IDLE_MAX_US */

#endif
