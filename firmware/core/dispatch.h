/* Requests in, exactly one response out: a decoder event becomes either the handler's
 * response (flags.response, same type and seq) or an ERROR frame (code, request_type, detail).
 * Frame-level errors (bad_cobs, bad_crc, too_long, too_short) carry seq 0, request_type 0.
 *
 * At-most-once: the dispatcher remembers the last request that passed the header checks
 * (seq, type, payload length and the CRC-32 of header | payload) and the answer it gave (the
 * response payload, kept in the dispatcher's own response buffer, or the ERROR code and
 * detail). A request identical to that one -- a host retry after a lost answer -- gets the
 * same answer again, byte for byte, without its handler running a second time. Anything else
 * (another seq, or the same seq with other bytes) is handled normally and becomes the one
 * remembered. Static memory: the response buffer dispatch already had, plus a few words. The
 * memory does not survive a restart (RESET, power cycle). */
#ifndef UWBCAL_DISPATCH_H
#define UWBCAL_DISPATCH_H

#include <stddef.h>
#include <stdint.h>

#include "frame.h"

/* Write the answer to ev (wire bytes with delimiter) into out[0..cap); returns its length,
 * 0 when nothing is to be sent (FRAME_EV_NONE) or cap is too small. */
size_t dispatch_event(const struct frame_event *ev, uint8_t *out, size_t cap);

/* An ERROR frame (wire bytes with delimiter); returns its length or 0. */
size_t dispatch_error_frame(uint16_t seq, uint8_t code, uint8_t request_type, uint16_t detail,
                            uint8_t *out, size_t cap);

/* Forget the remembered request (app_init: a fresh station answers every request anew). */
void dispatch_forget(void);

/* Requests answered from memory (retries whose handler did not run again) since boot. */
uint32_t dispatch_replayed(void);

#endif
