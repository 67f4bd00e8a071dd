/* libFuzzer harness: the station's whole request path on arbitrary host-link bytes.
 *
 * Every input is a byte stream from the host: it goes through frame_decoder_push (COBS, CRC,
 * lengths), dispatch_event (header checks, the retry memory, every request handler: radio,
 * sequencer, ranging, record ring fetches, calibration tables) and, after each frame, one
 * measure_poll (a started plan runs and streams into a link nobody reads). The DW1000 is the
 * transaction-recording fake (tests/firmware/fake_spi.c, its clock advances on every wait, so
 * nothing waits in real time); the flash is the native board's RAM image. Each answer must
 * be one well-formed frame (checked by decoding it again). Built by `make fuzz` with
 * clang -fsanitize=fuzzer,address,undefined; the seed corpus is protocol/vectors.json
 * (tools/fuzz_corpus.py). What this cannot see: timing (the fake clock), the real chip, the
 * EVK1000's USART and flash drivers. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app.h"
#include "boards/native/native.h"
#include "dispatch.h"
#include "fake_spi.c"
#include "frame.h"
#include "measure.h"
#include "radio.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static struct fake_spi F;
static struct frame_decoder dec, check_dec;
static uint8_t out[FRAME_TX_MAX];
static bool ready;

static void setup(void)
{
    fake_init(&F);
    fake_use_clock(&F);
    radio_set_clock(fake_clock_us);
    if (native_flash_open(NULL) != 0) abort(); /* RAM image: fast, no file */
    if (radio_attach(&F.ops) != DW_OK) abort();
    ready = true;
}

/* An answer must decode as exactly one frame with flags.response. */
static void check_answer(const uint8_t *p, size_t n)
{
    struct frame_event ev;
    int frames = 0;
    frame_decoder_init(&check_dec);
    for (size_t i = 0; i < n; i++) {
        int k = frame_decoder_push(&check_dec, p[i], &ev);
        if (k == FRAME_EV_NONE) continue;
        if (k != FRAME_EV_FRAME || ev.hdr.flags != PROTO_FLAG_RESPONSE) abort();
        frames++;
    }
    if (frames != 1) abort();
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (!ready) setup();
    /* a fresh station for every input (what a RESET gives), with the same fake radio */
    frame_decoder_init(&dec);
    dispatch_forget();
    struct proto_stop_req sr;
    struct proto_stop_resp sp;
    uint16_t det;
    (void)handle_stop(&sr, &sp, &det);
    F.nlog = 0; /* the fake's transaction log is for tests: keep it from filling */
    for (size_t i = 0; i < size; i++) {
        struct frame_event ev;
        if (frame_decoder_push(&dec, data[i], &ev) == FRAME_EV_NONE) continue;
        size_t n = dispatch_event(&ev, out, sizeof out);
        if (ev.kind == FRAME_EV_FRAME || ev.kind == FRAME_EV_ERROR) {
            if (n == 0) abort(); /* every frame gets an answer */
            check_answer(out, n);
        }
        measure_poll();
        F.nlog = 0;
    }
    for (int k = 0; k < 4; k++) measure_poll(); /* let a started plan run a little */
    return 0;
}
