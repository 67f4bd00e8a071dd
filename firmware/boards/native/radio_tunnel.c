/* The native station's DW1000 ops table over the tunnel to the simulated medium
 * (protocol/messages/tunnel.toml; the medium side is host/uwbcal/medium/server.py).
 *
 * Transport: one AF_UNIX SOCK_STREAM connection (path from --medium), frames exactly as on
 * the host link: COBS(header | payload | CRC-32) 0x00, header = version 1, type, flags 0,
 * seq. seq counts every frame this station sends (posted ones included), 1..65535, never 0.
 * The medium sends only responses (flags.response, same seq, same type, or ERROR), one per
 * non-posted request, in request order (an ERROR reply, or any other surprise, detaches).
 *
 * Handshake, exactly:
 *   attach:        -> tun_hello{station_id, uid}          <- tun_hello{now_us}
 *   SPI write:     -> tun_spi_write{hdr_len, hdr|data}     (posted: buffered locally, no reply)
 *   SPI read:      -> tun_spi_read{len, hdr}               <- tun_spi_read{data[len]}
 *   SPI batch:     every request of the batch in one write (reads not waited for one by
 *                  one), then the read replies collected in order: one round trip.
 *   (mode: PROTO_TUN_WAIT_MODE_* bits, the tun_wait_mode enum of tunnel.toml)
 *   wait_irq(d):   -> tun_wait{d, snapshot}                <- tun_wait{now_us, irq, snap}
 *   delay_us(us):  -> tun_wait{now+us, ignore_irq|snapshot} <- tun_wait{now_us, irq, snap}
 *   reset:         -> tun_reset{}                          <- tun_reset{}
 *   idle(max_us):  -> tun_wait{now+max_us, idle|snapshot}  <- tun_wait{now_us, irq, snap}
 *                  (max_us == 0: return at once, nothing sent)
 *   Snapshot (mode snapshot): every wait reply carries the registers a driver reads on waking
 *   as tun_snap_block records (SYS_STATUS, TX_TIME, the frame's registers and RX_BUFFER after
 *   a reception, and with mode snapshot_time SYS_TIME, asked for when the driver read SYS_TIME
 *   since the previous wait: tunnel.toml). A read inside a snapshot block is answered from it, no frame
 *   sent: exact, because while this station is not waiting its register model changes only
 *   through its own writes. So every posted write and every reset drops the snapshot (but
 *   SYS_TIME, which depends on virtual time only), and the next wait replaces it.
 *   While a wait_irq or idle tun_wait is pending the station poll()s the socket and the host
 *   pty together. Reply first: done. Pty input first: -> tun_cancel{} (posted), then read the
 *   one tun_wait reply, which the medium sends at once. (delays, mode ignore_irq, are not cancelled.)
 * Posted writes are kept in an output buffer and sent, in order, before the next request
 * that needs a reply (or when the buffer fills): the medium sees them in the same order and
 * before the read/wait that follows, so nothing changes but the number of syscalls.
 * board_time_us() is the now_us of the last tun_hello / tun_wait reply (SPI takes no
 * virtual time). If the medium goes away, the tunnel detaches: ops fail with -1 and board
 * time falls back to the process clock (so the host link keeps working).
 */
#define _GNU_SOURCE
#include <errno.h>
#include <poll.h>
#include <stdio.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include "board.h"
#include "dw1000_facts.h"
#include "dw1000_ops.h"
#include "frame.h"
#include "native.h"
#include "proto_gen.h"

#define TUN_OUT_CAP 8192u
#define TUN_REPLY_TIMEOUT_MS 30000 /* real time a non-wait reply may take */
#define TUN_SNAP_MAX 16u           /* snapshot blocks kept from a wait reply */

struct tunnel {
    int fd;
    bool attached;
    uint16_t station_id;
    uint16_t seq;
    uint64_t now_us;
    uint8_t out[TUN_OUT_CAP];
    size_t out_len;
    struct frame_decoder dec;
    uint8_t reply[PROTO_MAX_PAYLOAD];
    size_t reply_len;
    uint8_t in[4096];      /* bytes received, not yet decoded (pipelined replies) */
    size_t in_pos, in_len;
    uint32_t frames_out, replies, snap_hits;
    /* the last wait reply's snapshot: blocks (reg, off, n) and their bytes in snap_data */
    struct snap_block {
        uint8_t reg;
        uint16_t off;
        uint8_t len;
        uint16_t at;   /* index into snap_data */
        bool valid;
    } snap[TUN_SNAP_MAX];
    size_t snap_n;
    bool time_read; /* SYS_TIME read since the last wait: ask for it in the next snapshot */
    uint8_t snap_data[PROTO_MAX_PAYLOAD];
};

static struct tunnel tun = {.fd = -1};

static void detach(const char *why) {
    if (tun.attached) fprintf(stderr, "uwbcal-station %u: radio tunnel lost: %s\n", tun.station_id, why);
    tun.attached = false;
    if (tun.fd >= 0) close(tun.fd);
    tun.fd = -1;
}

static int send_all(const uint8_t *b, size_t n) {
    while (n > 0) {
        ssize_t w = send(tun.fd, b, n, MSG_NOSIGNAL);
        if (w < 0) {
            if (errno == EINTR) continue;
            detach(strerror(errno));
            return -1;
        }
        b += w;
        n -= (size_t)w;
    }
    return 0;
}

static int flush_out(void) {
    if (tun.out_len == 0) return 0;
    int rc = send_all(tun.out, tun.out_len);
    tun.out_len = 0;
    return rc;
}

/* Queue one request frame; returns its seq, 0 on failure. */
static uint16_t queue_frame(uint8_t type, const uint8_t *payload, size_t len) {
    if (tun.fd < 0) return 0;
    if (++tun.seq == 0) tun.seq = 1;
    struct proto_header h = {.version = PROTO_VERSION, .type = type, .flags = 0, .seq = tun.seq};
    if (TUN_OUT_CAP - tun.out_len < FRAME_TX_MAX && flush_out() != 0) return 0;
    size_t n = frame_encode(&h, payload, len, tun.out + tun.out_len, TUN_OUT_CAP - tun.out_len);
    if (n == 0) return 0;
    tun.out_len += n;
    tun.frames_out++;
    return tun.seq;
}

/* Decode buffered bytes, receiving more as needed, until one whole frame arrives; it must
 * answer (seq, type). Bytes after it stay buffered (replies to pipelined reads). timeout_ms
 * < 0: no limit (tun_wait replies: the medium answers at the virtual deadline). */
static int read_reply(uint16_t seq, uint8_t type, int timeout_ms) {
    int waited = 0;
    for (;;) {
        while (tun.in_pos < tun.in_len) {
            struct frame_event ev;
            int k = frame_decoder_push(&tun.dec, tun.in[tun.in_pos++], &ev);
            if (k == FRAME_EV_NONE) continue;
            if (k == FRAME_EV_ERROR) {
                detach("bad frame from the medium");
                return -1;
            }
            if (ev.hdr.seq != seq || !(ev.hdr.flags & PROTO_FLAG_RESPONSE) || ev.hdr.type != type) {
                char msg[96];
                snprintf(msg, sizeof msg, "reply type 0x%02X seq %u, expected type 0x%02X seq %u",
                         ev.hdr.type, ev.hdr.seq, type, seq);
                detach(msg);
                return -1;
            }
            memcpy(tun.reply, ev.payload, ev.payload_len);
            tun.reply_len = ev.payload_len;
            tun.replies++;
            return 0;
        }
        tun.in_pos = tun.in_len = 0;
        struct pollfd p = {.fd = tun.fd, .events = POLLIN};
        int pr = poll(&p, 1, 1000);
        if (pr < 0 && errno != EINTR) {
            detach(strerror(errno));
            return -1;
        }
        if (pr <= 0) {
            if (native_should_exit()) return -1;
            waited += 1000;
            if (timeout_ms >= 0 && waited >= timeout_ms) {
                detach("no reply from the medium");
                return -1;
            }
            continue;
        }
        ssize_t r = recv(tun.fd, tun.in, sizeof tun.in, 0);
        if (r < 0 && errno == EINTR) continue;
        if (r <= 0) {
            detach(r == 0 ? "the medium closed the connection" : strerror(errno));
            return -1;
        }
        tun.in_len = (size_t)r;
    }
}

/* Send a request that has a reply, flush everything, wait for it. */
static int transact(uint8_t type, const uint8_t *payload, size_t len, int timeout_ms) {
    uint16_t seq = queue_frame(type, payload, len);
    if (seq == 0 || flush_out() != 0) return -1;
    return read_reply(seq, type, timeout_ms);
}

/* ---- snapshot ------------------------------------------------------------------------------ */

/* A write or reset: only SYS_TIME (virtual time only) stays valid. */
static void snap_written(void) {
    for (size_t i = 0; i < tun.snap_n; i++)
        if (tun.snap[i].reg != DW_REG_SYS_TIME) tun.snap[i].valid = false;
}

/* Keep the snapshot of a wait reply (the bytes after now_us, irq). Malformed: ignored. */
static void snap_load(const uint8_t *b, size_t n) {
    size_t o = 0, at = 0;
    tun.snap_n = 0;
    while (o + PROTO_TUN_SNAP_BLOCK_WIRE_SIZE <= n && tun.snap_n < TUN_SNAP_MAX) {
        struct proto_tun_snap_block h;
        proto_tun_snap_block_decode(b + o, &h);
        o += PROTO_TUN_SNAP_BLOCK_WIRE_SIZE;
        if (o + h.n > n || at + h.n > sizeof tun.snap_data) break;
        struct snap_block *s = &tun.snap[tun.snap_n++];
        s->reg = h.reg;
        s->off = h.off;
        s->len = h.n;
        s->at = (uint16_t)at;
        s->valid = true;
        memcpy(tun.snap_data + at, b + o, h.n);
        at += h.n;
        o += h.n;
    }
}

/* A read of len bytes with this SPI header answered from the snapshot: 1, else 0. */
static int snap_read(const uint8_t *hdr, size_t hdr_len, uint8_t *rx, size_t len) {
    uint8_t reg = hdr[0] & 0x3Fu;
    uint16_t off = 0;
    if (reg == DW_REG_SYS_TIME) tun.time_read = true;
    if ((hdr[0] & 0x40u) && hdr_len > 1) {
        off = hdr[1] & 0x7Fu;
        if ((hdr[1] & 0x80u) && hdr_len > 2) off = (uint16_t)(off | (hdr[2] << 7));
    }
    for (size_t i = 0; i < tun.snap_n; i++) {
        const struct snap_block *s = &tun.snap[i];
        if (s->valid && s->reg == reg && off >= s->off && off + len <= (size_t)s->off + s->len) {
            memcpy(rx, tun.snap_data + s->at + (off - s->off), len);
            tun.snap_hits++;
            return 1;
        }
    }
    return 0;
}

/* ---- ops ----------------------------------------------------------------------------------- */

/* Queue one transaction: a posted write, or a read request (its seq in *seq). */
static int queue_spi(const uint8_t *hdr, size_t hdr_len, const uint8_t *tx, size_t len, uint16_t *seq) {
    static union {
        struct proto_tun_spi_write_req w;
        struct proto_tun_spi_read_req r;
    } m;
    uint8_t pl[PROTO_MAX_PAYLOAD];
    size_t n = 0;
    if (!tun.attached || hdr_len < 1 || hdr_len > 3) return -1;
    if (tx != NULL) {
        if (hdr_len + len > sizeof m.w.bytes) return -1;
        m.w.hdr_len = (uint8_t)hdr_len;
        memcpy(m.w.bytes, hdr, hdr_len);
        memcpy(m.w.bytes + hdr_len, tx, len);
        m.w.bytes_len = (uint16_t)(hdr_len + len);
        if (proto_tun_spi_write_req_encode(&m.w, pl, sizeof pl, &n) != 0) return -1;
        snap_written();
        *seq = 0;
        return queue_frame(PROTO_T_TUN_SPI_WRITE, pl, n) != 0 ? 0 : -1;
    }
    if (len > PROTO_TUN_SPI_READ_RESP_DATA_MAX) return -1;
    m.r.len = (uint16_t)len;
    memcpy(m.r.hdr, hdr, hdr_len);
    m.r.hdr_len = (uint16_t)hdr_len;
    if (proto_tun_spi_read_req_encode(&m.r, pl, sizeof pl, &n) != 0) return -1;
    *seq = queue_frame(PROTO_T_TUN_SPI_READ, pl, n);
    return *seq != 0 ? 0 : -1;
}

/* Collect the reply of a queued read into rx[0..len). */
static int collect_read(uint16_t seq, uint8_t *rx, size_t len) {
    static struct proto_tun_spi_read_resp rs;
    if (read_reply(seq, PROTO_T_TUN_SPI_READ, TUN_REPLY_TIMEOUT_MS) != 0) return -1;
    if (proto_tun_spi_read_resp_decode(tun.reply, tun.reply_len, &rs) != 0 || rs.data_len != len) {
        detach("tun_spi_read reply of the wrong length");
        return -1;
    }
    memcpy(rx, rs.data, len);
    return 0;
}

static int op_spi(void *ctx, const uint8_t *hdr, size_t hdr_len, const uint8_t *tx, uint8_t *rx, size_t len) {
    (void)ctx;
    uint16_t seq = 0;
    if (tx == NULL && rx == NULL) return -1;
    if (tx == NULL && tun.attached && hdr_len >= 1 && snap_read(hdr, hdr_len, rx, len)) return 0;
    if (queue_spi(hdr, hdr_len, tx, len, &seq) != 0) return -1;
    if (tx != NULL) return 0; /* posted */
    if (flush_out() != 0) return -1;
    return collect_read(seq, rx, len);
}

/* Every request of the batch goes out in one write; then the replies are collected in order.
 * Reads the snapshot answers (in order: after a write of the batch, it no longer does) send
 * nothing; if none is left, no round trip at all. */
static int op_spi_batch(void *ctx, const struct dw_spi_xfer *x, size_t n) {
    (void)ctx;
    uint16_t seqs[16];
    bool asked = false;
    if (n > 16) return -1;
    for (size_t i = 0; i < n; i++) {
        seqs[i] = 0;
        if (x[i].tx == NULL && x[i].rx == NULL) return -1;
        if (x[i].tx == NULL && tun.attached && x[i].hdr_len >= 1 &&
            snap_read(x[i].hdr, x[i].hdr_len, x[i].rx, x[i].len))
            continue;
        if (queue_spi(x[i].hdr, x[i].hdr_len, x[i].tx, x[i].len, &seqs[i]) != 0) return -1;
        if (x[i].tx == NULL) asked = true;
    }
    if (!asked) return 0; /* writes stay posted */
    if (flush_out() != 0) return -1;
    for (size_t i = 0; i < n; i++)
        if (x[i].tx == NULL && seqs[i] != 0 && collect_read(seqs[i], x[i].rx, x[i].len) != 0) return -1;
    return 0;
}

/* One tun_wait; returns irq (0/1) or -1. Unless the mode ignores the IRQ (a delay), the host
 * pty is watched while the medium holds the wait: host input sends tun_cancel, and the one
 * reply then comes at once (irq 0 or 1 as the line is; a 0 before the deadline is an early
 * wake, which every caller of wait_irq tolerates). So a station answers its host even
 * while another station holds virtual time still. */
static int tun_wait(uint64_t deadline_us, uint8_t mode) {
    struct proto_tun_wait_req rq = {.deadline_us = deadline_us, .mode = mode};
    struct proto_tun_wait_resp rs;
    uint8_t pl[16];
    size_t n = 0;
    if (!tun.attached) return -1;
    rq.mode = (uint8_t)(mode | PROTO_TUN_WAIT_MODE_SNAPSHOT
                         | (tun.time_read ? PROTO_TUN_WAIT_MODE_SNAPSHOT_TIME : 0u));
    tun.snap_n = 0; /* the wait ends the old one, SYS_TIME included */
    tun.time_read = false;
    if (proto_tun_wait_req_encode(&rq, pl, sizeof pl, &n) != 0) return -1;
    uint16_t seq = queue_frame(PROTO_T_TUN_WAIT, pl, n);
    if (seq == 0 || flush_out() != 0) return -1;
    if (!(mode & PROTO_TUN_WAIT_MODE_IGNORE_IRQ)) {
        int link = native_link_fd();
        for (;;) {
            struct pollfd p[2] = {{.fd = tun.fd, .events = POLLIN}, {.fd = link, .events = POLLIN}};
            int pr = poll(p, link >= 0 ? 2 : 1, 1000);
            if (pr < 0 && errno != EINTR) break;
            if (native_should_exit()) return -1;
            if (pr <= 0) continue;
            if (p[0].revents) break; /* the reply (or EOF) */
            if (p[1].revents) {
                if (queue_frame(PROTO_T_TUN_CANCEL, NULL, 0) == 0 || flush_out() != 0) return -1;
                break;
            }
        }
    }
    if (read_reply(seq, PROTO_T_TUN_WAIT, -1) != 0) return -1;
    if (proto_tun_wait_resp_decode(tun.reply, tun.reply_len, &rs) != 0) {
        detach("bad tun_wait reply");
        return -1;
    }
    snap_load(rs.snap, rs.snap_len);
    if (rs.now_us > tun.now_us) tun.now_us = rs.now_us;
    return rs.irq ? 1 : 0;
}

static int op_wait_irq(void *ctx, uint64_t deadline_us) {
    (void)ctx;
    return tun_wait(deadline_us, 0);
}

static void op_delay(void *ctx, uint32_t us) {
    (void)ctx;
    (void)tun_wait(tun.now_us + us, PROTO_TUN_WAIT_MODE_IGNORE_IRQ);
}

static int op_reset(void *ctx) {
    (void)ctx;
    if (!tun.attached) return -1;
    snap_written();
    if (transact(PROTO_T_TUN_RESET, NULL, 0, TUN_REPLY_TIMEOUT_MS) != 0) return -1;
    return tun.reply_len == 0 ? 0 : -1;
}

static void op_speed(void *ctx, int fast) {
    (void)ctx;
    (void)fast;
}

static const struct dw_ops tun_ops = {
    .ctx = NULL,
    .spi_transfer = op_spi,
    .wait_irq = op_wait_irq,
    .reset = op_reset,
    .delay_us = op_delay,
    .spi_speed = op_speed,
    .spi_batch = op_spi_batch,
};

/* ---- native.h hooks ------------------------------------------------------------------------ */

int native_radio_attach(const char *socket_path, uint16_t station_id, const uint8_t uid[12]) {
    struct sockaddr_un sa;
    memset(&sa, 0, sizeof sa);
    sa.sun_family = AF_UNIX;
    if (strlen(socket_path) >= sizeof sa.sun_path) {
        fprintf(stderr, "uwbcal-station %u: --medium %s: path too long\n", station_id, socket_path);
        return -1;
    }
    strcpy(sa.sun_path, socket_path);
    int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0 || connect(fd, (struct sockaddr *)&sa, sizeof sa) != 0) {
        fprintf(stderr, "uwbcal-station %u: --medium %s: %s\n", station_id, socket_path, strerror(errno));
        if (fd >= 0) close(fd);
        return -1;
    }
    tun.fd = fd;
    tun.station_id = station_id;
    tun.seq = 0;
    tun.snap_n = 0;
    tun.time_read = true;
    tun.out_len = 0;
    tun.in_pos = tun.in_len = 0;
    frame_decoder_init(&tun.dec);
    tun.attached = true;
    struct proto_tun_hello_req rq;
    struct proto_tun_hello_resp rs;
    rq.station_id = station_id;
    memcpy(rq.uid, uid, 12);
    uint8_t pl[32];
    size_t n = 0;
    if (proto_tun_hello_req_encode(&rq, pl, sizeof pl, &n) != 0 ||
        transact(PROTO_T_TUN_HELLO, pl, n, -1) != 0 ||
        proto_tun_hello_resp_decode(tun.reply, tun.reply_len, &rs) != 0) {
        fprintf(stderr, "uwbcal-station %u: --medium %s: no tun_hello reply\n", station_id, socket_path);
        detach("hello failed");
        return -1;
    }
    tun.now_us = rs.now_us;
    return 0;
}

const struct dw_ops *native_radio_ops(void) { return tun.attached ? &tun_ops : NULL; }

int native_radio_time_us(uint64_t *now) {
    if (!tun.attached) return -1;
    *now = tun.now_us;
    return 0;
}

void native_radio_idle(uint32_t max_us) {
    if (!tun.attached) {
        native_wait_input(-1, max_us);
        return;
    }
    if (max_us == 0) return;
    (void)tun_wait(tun.now_us + max_us, PROTO_TUN_WAIT_MODE_IDLE);
}

/* The station id in radio frames is the scenario's --id. */
uint16_t radio_board_station_id(void);
uint16_t radio_board_station_id(void) { return native_station_id(); }
