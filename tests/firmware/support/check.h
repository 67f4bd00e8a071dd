/* A tiny check helper for the C unit tests: CHECK(cond) counts and reports, check_summary()
 * prints "N passed, N failed" and returns the exit code. */
#ifndef UWBCAL_CHECK_H
#define UWBCAL_CHECK_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

extern int check_n_passed;
extern int check_n_failed;

void check_record(int ok, const char *file, int line, const char *expr, const char *ctx);
/* Context printed with the next failures (a vector name, a seed). */
void check_context(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
int check_summary(void);
void check_hexdump(const char *label, const uint8_t *p, size_t n);

/* Deterministic PRNG for the tests (xorshift32); never seeded from time. */
uint32_t check_rand(uint32_t *state);

#define CHECK(cond) check_record(!!(cond), __FILE__, __LINE__, #cond, NULL)
#define CHECK_EQ(a, b)                                                                    \
    do {                                                                                  \
        unsigned long long a_ = (unsigned long long)(a), b_ = (unsigned long long)(b);   \
        char m_[96];                                                                      \
        snprintf(m_, sizeof m_, "%llu (0x%llX) != %llu (0x%llX)", a_, a_, b_, b_);        \
        check_record(a_ == b_, __FILE__, __LINE__, #a " == " #b, m_);                     \
    } while (0)
#define CHECK_MEM(a, an, b, bn)                                                           \
    do {                                                                                  \
        size_t an_ = (an), bn_ = (bn);                                                    \
        int ok_ = an_ == bn_ && (an_ == 0 || memcmp((a), (b), an_) == 0);                 \
        check_record(ok_, __FILE__, __LINE__, #a " == " #b, ok_ ? NULL : "bytes differ"); \
        if (!ok_) {                                                                       \
            check_hexdump("got", (const uint8_t *)(a), an_);                              \
            check_hexdump("want", (const uint8_t *)(b), bn_);                             \
        }                                                                                 \
    } while (0)

#endif
