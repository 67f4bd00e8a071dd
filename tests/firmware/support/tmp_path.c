#include "tmp_path.h"

#include <stdio.h>
#include <unistd.h>

char *tmp_path(char *buf, size_t cap, const char *name, const char *ext)
{
    snprintf(buf, cap, "/tmp/uwbcal-%s-%ld%s", name, (long)getpid(), ext);
    return buf;
}
