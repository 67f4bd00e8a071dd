/* Scratch file paths for the C unit tests (flash images, sockets, logs). */
#ifndef UWBCAL_TMP_PATH_H
#define UWBCAL_TMP_PATH_H

#include <stddef.h>

/* Write "/tmp/uwbcal-<name>-<pid><ext>" into buf (cap bytes) and return buf: distinct per
 * test process, so tests may run in parallel. Nothing is created or removed. */
char *tmp_path(char *buf, size_t cap, const char *name, const char *ext);

#endif
