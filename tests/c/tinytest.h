/**
 * @file tinytest.h
 * @brief A tiny C test framework: checks with tolerances, a summary line,
 *        non-zero exit on failure. One executable per test file; ctest runs them.
 */
#ifndef TINYTEST_H
#define TINYTEST_H

#include <math.h>
#include <stdint.h>
#include <stdio.h>

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

static int tt_pass_ = 0;
static int tt_fail_ = 0;
static const char *tt_current_ = "";

#define TT_CHECK(cond)                                                          \
  do {                                                                          \
    if (cond) {                                                                 \
      tt_pass_++;                                                               \
    } else {                                                                    \
      tt_fail_++;                                                               \
      printf("FAIL %s:%d [%s] %s\n", __FILE__, __LINE__, tt_current_, #cond);   \
    }                                                                           \
  } while (0)

#define TT_CHECK_NEAR(a, b, tol)                                                \
  do {                                                                          \
    double tt_a_ = (double)(a), tt_b_ = (double)(b), tt_t_ = (double)(tol);      \
    if (fabs(tt_a_ - tt_b_) <= tt_t_) {                                         \
      tt_pass_++;                                                               \
    } else {                                                                    \
      tt_fail_++;                                                               \
      printf("FAIL %s:%d [%s] %s = %.9g, expected %s = %.9g (tol %.3g)\n",      \
             __FILE__, __LINE__, tt_current_, #a, tt_a_, #b, tt_b_, tt_t_);      \
    }                                                                           \
  } while (0)

#define TT_RUN(fn)                                                              \
  do {                                                                          \
    tt_current_ = #fn;                                                          \
    int tt_f0_ = tt_fail_;                                                      \
    fn();                                                                       \
    printf("%s %s\n", tt_fail_ == tt_f0_ ? "ok  " : "FAIL", #fn);               \
  } while (0)

#define TT_SUMMARY()                                                            \
  (printf("%d passed, %d failed\n", tt_pass_, tt_fail_), tt_fail_ == 0 && tt_pass_ > 0 ? 0 : 1)

/* A small deterministic generator for randomized checks (xorshift32; *st != 0). */
static inline uint32_t tt_rng_u32(uint32_t *st) {
  uint32_t x = *st;
  x ^= x << 13;
  x ^= x >> 17;
  x ^= x << 5;
  *st = x;
  return x;
}

/* Uniform in [lo, hi) from tt_rng_u32 (24 bits). */
static inline float tt_rng_f(uint32_t *st, float lo, float hi) {
  return lo + (hi - lo) * (float)(tt_rng_u32(st) >> 8) * (1.0f / 16777216.0f);
}

#endif
