/* uwbcal-station: the station firmware as a host process.
 *   uwbcal-station --id N [--flash PATH] [--medium SOCKET]
 * Prints "PTY <path>" on stdout, then serves the host link until SIGTERM or SIGINT. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app.h"
#include "board.h"
#include "native.h"

static int usage(void)
{
    fprintf(stderr, "usage: uwbcal-station --id N [--flash PATH] [--medium SOCKET]\n"
                    "  N: station id 1..65535 (also fixes the station's UID)\n");
    return 2;
}

int main(int argc, char **argv)
{
    long id = -1;
    const char *flash = NULL, *medium = NULL;
    for (int i = 1; i < argc; i++) {
        if (i + 1 < argc && strcmp(argv[i], "--id") == 0) {
            char *end = NULL;
            id = strtol(argv[++i], &end, 10);
            if (end == NULL || *end != '\0') id = -1;
        } else if (i + 1 < argc && strcmp(argv[i], "--flash") == 0) {
            flash = argv[++i];
        } else if (i + 1 < argc && strcmp(argv[i], "--medium") == 0) {
            medium = argv[++i];
        } else {
            return usage();
        }
    }
    if (id < 1 || id > 65535) return usage();
    native_board_init((uint16_t)id, argv);
    if (native_flash_open(flash) != 0)
        fprintf(stderr, "uwbcal-station %ld: flash %s unavailable; flash operations will fail\n", id,
                flash ? flash : "(RAM)");
    if (medium != NULL) {
        uint8_t uid[12];
        board_uid(uid);
        if (native_radio_attach(medium, (uint16_t)id, uid) != 0) return 1;
    }
    int inherited = getenv("UWBCAL_STATION_PTY") != NULL;
    if (native_link_open() != 0) return 1;
    if (!inherited) {
        printf("PTY %s\n", native_link_path());
        fflush(stdout);
    }
    app_init();
    while (!native_should_exit()) {
        if (!app_poll()) board_idle(app_idle_us());
    }
    return 0;
}
