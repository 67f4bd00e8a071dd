#include "check.h"

#include <stdarg.h>
#include <stdio.h>

int check_n_passed;
int check_n_failed;
static char context[160];

void check_context(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(context, sizeof context, fmt, ap);
    va_end(ap);
}

void check_record(int ok, const char *file, int line, const char *expr, const char *ctx)
{
    if (ok) {
        check_n_passed++;
        return;
    }
    check_n_failed++;
    fprintf(stderr, "%s:%d: FAILED %s%s%s\n", file, line, expr, ctx ? ": " : "", ctx ? ctx : "");
    if (context[0]) fprintf(stderr, "    (%s)\n", context);
}

void check_hexdump(const char *label, const uint8_t *p, size_t n)
{
    fprintf(stderr, "    %s (%zu):", label, n);
    for (size_t i = 0; i < n && i < 48; i++) fprintf(stderr, " %02x", p[i]);
    fprintf(stderr, "%s\n", n > 48 ? " ..." : "");
}

int check_summary(void)
{
    printf("%d passed, %d failed\n", check_n_passed, check_n_failed);
    return check_n_failed == 0 && check_n_passed > 0 ? 0 : 1;
}

uint32_t check_rand(uint32_t *state)
{
    uint32_t x = *state ? *state : 0x9E3779B9u;
    x ^= x << 13;
    x ^= x >> 17;
    x ^= x << 5;
    *state = x;
    return x;
}
