/* The native board's DW1000 ops over the medium tunnel (firmware/boards/native/radio_tunnel.c)
 * against a scripted medium in a child process: hello, posted SPI writes kept in order before
 * the next read, reads, waits (IRQ / deadline / ignore-IRQ delay / idle), reset, sequence
 * numbers, virtual time, the wait snapshot (reads answered locally until a write), and
 * detaching when the medium goes away. */
#define _GNU_SOURCE
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include "check.h"
#include "dw1000_ops.h"
#include "frame.h"
#include "boards/native/native.h"
#include "proto_gen.h"
#include "tmp_path.h"

static char sock_path[96], log_path[96];

static void reply(int fd, const struct proto_header *rq, const uint8_t *pl, size_t n) {
    struct proto_header h = {.version = PROTO_VERSION, .type = rq->type, .flags = PROTO_FLAG_RESPONSE, .seq = rq->seq};
    uint8_t out[FRAME_TX_MAX];
    size_t len = frame_encode(&h, pl, n, out, sizeof out);
    if (write(fd, out, len) != (ssize_t)len) _exit(3);
}

/* The scripted medium: one station, log one line per frame. */
static void medium(int lfd) {
    int fd = accept(lfd, NULL, NULL);
    if (fd < 0) _exit(2);
    FILE *log = fopen(log_path, "w");
    if (!log) _exit(2);
    static struct frame_decoder dec;
    frame_decoder_init(&dec);
    uint8_t buf[4096];
    ssize_t r;
    while ((r = read(fd, buf, sizeof buf)) > 0) {
        for (ssize_t i = 0; i < r; i++) {
            struct frame_event ev;
            if (frame_decoder_push(&dec, buf[i], &ev) != FRAME_EV_FRAME) continue;
            fprintf(log, "%02X %u %02X", ev.hdr.type, ev.hdr.seq, ev.hdr.flags);
            for (size_t k = 0; k < ev.payload_len; k++) fprintf(log, "%s%02X", k ? "" : " ", ev.payload[k]);
            fprintf(log, "\n");
            fflush(log);
            uint8_t pl[600];
            size_t n = 0;
            switch (ev.hdr.type) {
            case PROTO_T_TUN_HELLO: {
                struct proto_tun_hello_resp h = {.now_us = 1000};
                proto_tun_hello_resp_encode(&h, pl, sizeof pl, &n);
                reply(fd, &ev.hdr, pl, n);
                break;
            }
            case PROTO_T_TUN_SPI_READ: {
                struct proto_tun_spi_read_req q;
                static struct proto_tun_spi_read_resp a;
                proto_tun_spi_read_req_decode(ev.payload, ev.payload_len, &q);
                a.data_len = q.len;
                for (unsigned k = 0; k < q.len; k++) a.data[k] = (uint8_t)(0xA0 + k);

                proto_tun_spi_read_resp_encode(&a, pl, sizeof pl, &n);
                reply(fd, &ev.hdr, pl, n);
                break;
            }
            case PROTO_T_TUN_WAIT: {
                struct proto_tun_wait_req q;
                proto_tun_wait_req_decode(ev.payload, ev.payload_len, &q);
                static struct proto_tun_wait_resp a;
                memset(&a, 0, sizeof a);
                a.now_us = q.deadline_us;
                if ((q.mode & 3) == 0 && q.deadline_us > 50000 && q.deadline_us < 70000) {
                    a.now_us = 50000; /* the IRQ rises at 50000 */
                    a.irq = 1;
                }
                if ((q.mode & 4) && q.deadline_us == 70000) {
                    /* snapshot: SYS_TIME[0:5] = 11.., SYS_STATUS[0:5] = 21.., RX_BUFFER[2:5] = 31.. */
                    static const uint8_t snap[] = {0x06, 0, 0, 5, 11, 12, 13, 14, 15,
                                                   0x0F, 0, 0, 5, 21, 22, 23, 24, 25,
                                                   0x11, 2, 0, 3, 31, 32, 33};
                    memcpy(a.snap, snap, sizeof snap);
                    a.snap_len = sizeof snap;
                }
                proto_tun_wait_resp_encode(&a, pl, sizeof pl, &n);
                reply(fd, &ev.hdr, pl, n);
                break;
            }
            case PROTO_T_TUN_RESET:
                reply(fd, &ev.hdr, NULL, 0);
                break;
            default: break; /* posted */
            }
        }
    }
    fclose(log);
    _exit(0);
}

static int read_log(char lines[][600], int max) {
    FILE *f = fopen(log_path, "r");
    int n = 0;
    if (!f) return 0;
    while (n < max && fgets(lines[n], 600, f)) {
        lines[n][strcspn(lines[n], "\n")] = 0;
        n++;
    }
    fclose(f);
    return n;
}

int main(void) {
    tmp_path(sock_path, sizeof sock_path, "tuntest", ".sock");
    tmp_path(log_path, sizeof log_path, "tuntest", ".log");
    unlink(sock_path);
    int lfd = socket(AF_UNIX, SOCK_STREAM, 0);
    struct sockaddr_un sa = {.sun_family = AF_UNIX};
    strcpy(sa.sun_path, sock_path);
    CHECK(lfd >= 0 && bind(lfd, (struct sockaddr *)&sa, sizeof sa) == 0 && listen(lfd, 1) == 0);
    pid_t child = fork();
    if (child == 0) medium(lfd);
    close(lfd);

    CHECK(native_radio_ops() == NULL);
    uint64_t now = 0;
    CHECK(native_radio_time_us(&now) != 0);
    uint8_t uid[12] = {1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12};
    CHECK(native_radio_attach(sock_path, 7, uid) == 0);
    const struct dw_ops *ops = native_radio_ops();
    CHECK(ops != NULL);
    CHECK(native_radio_time_us(&now) == 0 && now == 1000);
    if (ops == NULL) return check_summary();

    uint8_t h1[1] = {0x89}, d1[3] = {1, 2, 3};
    uint8_t h3[3] = {0xEE, 0x84, 0x30}, d3[2] = {0x10, 0x40};
    CHECK(ops->spi_transfer(ops->ctx, h1, 1, d1, NULL, 3) == 0);
    CHECK(ops->spi_transfer(ops->ctx, h3, 3, d3, NULL, 2) == 0);
    uint8_t rh[2] = {0x4F, 0x03}, rx[5] = {0};
    CHECK(ops->spi_transfer(ops->ctx, rh, 2, NULL, rx, 5) == 0);
    CHECK(rx[0] == 0xA0 && rx[4] == 0xA4);
    CHECK(ops->spi_transfer(ops->ctx, rh, 4, NULL, rx, 5) < 0); /* a 4-byte header is refused */
    CHECK(ops->wait_irq(ops->ctx, 2000) == 0 && native_radio_time_us(&now) == 0 && now == 2000);
    CHECK(ops->wait_irq(ops->ctx, 60000) == 1 && native_radio_time_us(&now) == 0 && now == 50000);
    ops->delay_us(ops->ctx, 100);
    CHECK(native_radio_time_us(&now) == 0 && now == 50100);
    CHECK(ops->reset(ops->ctx) == 0);
    native_radio_idle(0); /* nothing sent */
    native_radio_idle(400);
    CHECK(native_radio_time_us(&now) == 0 && now == 50500);
    /* a batch: write, read, read, write, read; the reads are pipelined */
    CHECK(ops->spi_batch != NULL);
    uint8_t b1[3] = {0}, b2[7] = {0}, b3[2] = {0};
    uint8_t bh_w[1] = {0x8D}, bw[4] = {0x40, 0, 0, 0}, bh_r1[1] = {0x10}, bh_r2[1] = {0x15}, bh_r3[2] = {0x67, 0x2C};
    struct dw_spi_xfer xs[5] = {
        {bh_w, 1, bw, NULL, 4}, {bh_r1, 1, NULL, b1, 3}, {bh_r2, 1, NULL, b2, 7},
        {bh_w, 1, bw, NULL, 4}, {bh_r3, 2, NULL, b3, 2},
    };
    if (ops->spi_batch) CHECK(ops->spi_batch(ops->ctx, xs, 5) == 0);
    CHECK(b1[0] == 0xA0 && b1[2] == 0xA2 && b2[6] == 0xA6 && b3[1] == 0xA1);
    CHECK(ops->spi_transfer(ops->ctx, rh, 1, NULL, rx, 1) == 0); /* sync: everything before is logged */

    char lines[32][600];
    int n = read_log(lines, 32);
    CHECK(n == 15);
    CHECK(n > 0 && strcmp(lines[0], "40 1 00 07000102030405060708090A0B0C") == 0);
    CHECK(n > 1 && strcmp(lines[1], "41 2 00 0189010203") == 0);      /* hdr_len 1, hdr, data */
    CHECK(n > 2 && strcmp(lines[2], "41 3 00 03EE84301040") == 0);    /* 3-byte header */
    CHECK(n > 3 && strcmp(lines[3], "42 4 00 05004F03") == 0);        /* read: len 5, hdr */
    /* every wait asks for the snapshot (mode bit 2); SYS_TIME in it (bit 3) until a wait after
     * which the driver did not read the clock */
    CHECK(n > 4 && strcmp(lines[4], "43 5 00 D0070000000000000C") == 0); /* wait 2000, mode 0 */
    CHECK(n > 5 && strcmp(lines[5], "43 6 00 60EA00000000000004") == 0); /* wait 60000 */
    CHECK(n > 6 && strcmp(lines[6], "43 7 00 B4C300000000000006") == 0); /* delay: 50100, ignore IRQ */
    CHECK(n > 7 && strcmp(lines[7], "44 8 00") == 0);
    CHECK(n > 8 && strcmp(lines[8], "43 9 00 44C500000000000005") == 0); /* idle: 50500, mode idle */
    CHECK(n > 9 && strcmp(lines[9], "41 10 00 018D40000000") == 0);
    CHECK(n > 10 && strcmp(lines[10], "42 11 00 030010") == 0);
    CHECK(n > 11 && strcmp(lines[11], "42 12 00 070015") == 0);
    CHECK(n > 12 && strcmp(lines[12], "41 13 00 018D40000000") == 0);
    CHECK(n > 13 && strcmp(lines[13], "42 14 00 0200672C") == 0);
    CHECK(n > 14 && strncmp(lines[14], "42 15 00 ", 9) == 0);

    /* the snapshot of a wait answers reads inside its blocks without a frame; a write drops
     * it, but SYS_TIME; the next wait (without a snapshot) drops SYS_TIME too */
    CHECK(ops->wait_irq(ops->ctx, 70000) == 0);
    uint8_t st4[4] = {0}, stm[5] = {0}, rb[2] = {0}, rb_far[2] = {0};
    uint8_t hst[1] = {0x0F}, htm[1] = {0x06}, hrb[2] = {0x51, 0x03}, hrb_far[2] = {0x51, 0x04};
    CHECK(ops->spi_transfer(ops->ctx, hst, 1, NULL, st4, 4) == 0 && st4[0] == 21 && st4[3] == 24);
    struct dw_spi_xfer ys[2] = {{htm, 1, NULL, stm, 5}, {hrb, 2, NULL, rb, 2}};
    if (ops->spi_batch) CHECK(ops->spi_batch(ops->ctx, ys, 2) == 0); /* no frame at all */
    CHECK(stm[0] == 11 && stm[4] == 15 && rb[0] == 32 && rb[1] == 33);
    CHECK(ops->spi_transfer(ops->ctx, hrb_far, 2, NULL, rb_far, 2) == 0); /* past the block: asked */
    CHECK(rb_far[0] == 0xA0 && rb_far[1] == 0xA1);
    CHECK(ops->spi_transfer(ops->ctx, bh_w, 1, bw, NULL, 4) == 0); /* a write */
    memset(stm, 0, sizeof stm);
    CHECK(ops->spi_transfer(ops->ctx, htm, 1, NULL, stm, 5) == 0 && stm[0] == 11); /* SYS_TIME kept */
    CHECK(ops->spi_transfer(ops->ctx, hst, 1, NULL, st4, 4) == 0 && st4[0] == 0xA0); /* asked */
    CHECK(ops->wait_irq(ops->ctx, 71000) == 0);
    CHECK(ops->spi_transfer(ops->ctx, htm, 1, NULL, stm, 5) == 0 && stm[0] == 0xA0); /* asked */
    n = read_log(lines, 32);
    CHECK(n == 21);
    CHECK(n > 15 && strcmp(lines[15], "43 16 00 701101000000000004") == 0);
    CHECK(n > 16 && strcmp(lines[16], "42 17 00 02005104") == 0);
    CHECK(n > 17 && strcmp(lines[17], "41 18 00 018D40000000") == 0);
    CHECK(n > 18 && strcmp(lines[18], "42 19 00 04000F") == 0);
    CHECK(n > 19 && strcmp(lines[19], "43 20 00 58150100000000000C") == 0); /* SYS_TIME was read */
    CHECK(n > 20 && strcmp(lines[20], "42 21 00 050006") == 0);

    /* the medium goes away: the tunnel detaches, time falls back to the process clock */
    kill(child, SIGTERM);
    int status = 0;
    waitpid(child, &status, 0);
    CHECK(ops->spi_transfer(ops->ctx, rh, 1, NULL, rx, 1) < 0);
    CHECK(native_radio_ops() == NULL && native_radio_time_us(&now) != 0);
    CHECK(ops->wait_irq(ops->ctx, 1) < 0);
    unlink(sock_path);
    unlink(log_path);
    return check_summary();
}
