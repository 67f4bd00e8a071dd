/* Native board: SIGTERM / SIGINT end a station process cleanly (native_should_exit()), and a
 * closed peer never kills it with SIGPIPE. Shared by the native station and the host-side
 * USB station (firmware/boards/evk1000/usb/hosted/hosted_board.c). */
#define _XOPEN_SOURCE 700
#include <signal.h>
#include <string.h>

#include "native.h"

static volatile sig_atomic_t exit_requested;

static void on_signal(int sig)
{
    (void)sig;
    exit_requested = 1;
}

void native_catch_exit_signals(void)
{
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
}

bool native_should_exit(void) { return exit_requested != 0; }
