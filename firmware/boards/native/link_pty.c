/* Native board host link: the master side of a pty. The host opens the slave path exactly as
 * it opens /dev/ttyACM0. While no host has the slave open the master sees POLLHUP: writes are
 * dropped (as a USB CDC port with no listener drops them) and idling sleeps instead of
 * spinning. The fds survive board_reset() (exec) through UWBCAL_STATION_PTY. */
#define _XOPEN_SOURCE 700
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

#include "board.h"
#include "native.h"

#define ENV_PTY "UWBCAL_STATION_PTY"
/* Bytes that followed a RESET in the same read, handed to the restarted station (hex). */
#define ENV_KEEP "UWBCAL_STATION_KEEP"
#define KEEP_MAX 256
#define WRITE_TIMEOUT_MS 500

static int master_fd = -1;
static char slave_path[256];
static uint8_t keep_buf[KEEP_MAX];
static size_t keep_len, keep_off;

void board_link_keep(const uint8_t *buf, size_t len)
{
    if (len > KEEP_MAX) len = KEEP_MAX;
    if (len > 0) memcpy(keep_buf, buf, len);
    keep_len = len;
    keep_off = 0;
}

static void adopt_kept(void)
{
    const char *hex = getenv(ENV_KEEP);
    keep_len = keep_off = 0;
    if (hex == NULL) return;
    for (size_t i = 0; hex[2 * i] && hex[2 * i + 1] && keep_len < KEEP_MAX; i++) {
        unsigned v;
        if (sscanf(hex + 2 * i, "%2x", &v) != 1) break;
        keep_buf[keep_len++] = (uint8_t)v;
    }
    unsetenv(ENV_KEEP);
}

static int set_cloexec(int fd, int on)
{
    int fl = fcntl(fd, F_GETFD);
    if (fl < 0) return -1;
    return fcntl(fd, F_SETFD, on ? (fl | FD_CLOEXEC) : (fl & ~FD_CLOEXEC));
}

static int adopt_inherited(const char *env)
{
    char path[sizeof slave_path];
    int fd = -1;
    if (sscanf(env, "%d,%255s", &fd, path) != 2 || fd < 0 || fcntl(fd, F_GETFD) < 0) return -1;
    master_fd = fd;
    snprintf(slave_path, sizeof slave_path, "%s", path);
    set_cloexec(master_fd, 1);
    unsetenv(ENV_PTY);
    return 0;
}

int native_link_open(void)
{
    const char *env = getenv(ENV_PTY);
    adopt_kept();
    if (env != NULL && adopt_inherited(env) == 0) return 0;
    int m = posix_openpt(O_RDWR | O_NOCTTY);
    if (m < 0 || grantpt(m) != 0 || unlockpt(m) != 0) {
        fprintf(stderr, "uwbcal-station: cannot open a pty: %s\n", strerror(errno));
        if (m >= 0) close(m);
        return -1;
    }
    const char *name = ptsname(m);
    if (name == NULL) {
        close(m);
        return -1;
    }
    snprintf(slave_path, sizeof slave_path, "%s", name);
    /* Raw mode on the slave side (no echo, no line editing, 8 bits); it persists while the
     * master is open, so set it once through a temporary slave fd. */
    int s = open(slave_path, O_RDWR | O_NOCTTY);
    if (s < 0) {
        fprintf(stderr, "uwbcal-station: cannot open %s: %s\n", slave_path, strerror(errno));
        close(m);
        return -1;
    }
    struct termios t;
    if (tcgetattr(s, &t) == 0) {
        cfmakeraw(&t);
        tcsetattr(s, TCSANOW, &t);
    }
    close(s);
    fcntl(m, F_SETFL, fcntl(m, F_GETFL) | O_NONBLOCK);
    set_cloexec(m, 1);
    master_fd = m;
    return 0;
}

const char *native_link_path(void) { return slave_path; }

int native_link_fd(void)
{
    if (master_fd < 0) return -1;
    /* While no host has the slave open, the master reports POLLHUP without end: hand out -1
     * so that an idle poll() sleeps instead of spinning (poll ignores negative fds). */
    struct pollfd p = {.fd = master_fd, .events = POLLIN};
    if (poll(&p, 1, 0) > 0 && (p.revents & POLLHUP) && !(p.revents & POLLIN)) return -1;
    return master_fd;
}

void native_link_prepare_exec(void)
{
    char buf[sizeof slave_path + 32];
    if (master_fd < 0) return;
    set_cloexec(master_fd, 0);
    snprintf(buf, sizeof buf, "%d,%s", master_fd, slave_path);
    setenv(ENV_PTY, buf, 1);
    char hex[2 * KEEP_MAX + 1];
    for (size_t i = 0; i < keep_len - keep_off; i++) snprintf(hex + 2 * i, 3, "%02x", keep_buf[keep_off + i]);
    hex[2 * (keep_len - keep_off)] = '\0';
    if (keep_len > keep_off) setenv(ENV_KEEP, hex, 1);
}

size_t board_link_read(uint8_t *buf, size_t max)
{
    if (master_fd < 0 || max == 0) return 0;
    if (keep_off < keep_len) { /* input that followed a RESET, before anything newer */
        size_t n = keep_len - keep_off < max ? keep_len - keep_off : max;
        memcpy(buf, keep_buf + keep_off, n);
        keep_off += n;
        return n;
    }
    ssize_t n = read(master_fd, buf, max);
    return n > 0 ? (size_t)n : 0; /* EAGAIN: nothing; EIO: no host has the slave open */
}

bool board_link_write(const uint8_t *buf, size_t len)
{
    if (master_fd < 0) return false;
    uint64_t deadline = native_monotonic_us() + (uint64_t)WRITE_TIMEOUT_MS * 1000u;
    size_t done = 0;
    while (done < len) {
        struct pollfd p = {.fd = master_fd, .events = POLLOUT};
        int rc = poll(&p, 1, 0);
        if (rc > 0 && (p.revents & POLLHUP)) return false; /* nobody listens: drop */
        ssize_t n = write(master_fd, buf + done, len - done);
        if (n > 0) {
            done += (size_t)n;
            continue;
        }
        if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) return false;
        uint64_t now = native_monotonic_us();
        if (now >= deadline || native_should_exit()) return false;
        uint64_t left_ms = (deadline - now + 999u) / 1000u;
        p.revents = 0;
        poll(&p, 1, (int)(left_ms < 10 ? left_ms : 10));
    }
    return true;
}
