/* Elementary functions for lane loops (a value per Gaussian side by side, compiled per
 * instruction-set level: project_backward.c, deform_apply.c): no table, no branch and no library
 * call, so the loops that use them vectorise; in double, about 1 ulp from libm. Only src/ files
 * include this. */
#ifndef SC_LANE_MATH_H
#define SC_LANE_MATH_H

#include <stdint.h>
#include <string.h>

#include "internal.h"

/* e^x in double for |x| <= 700 (the caller checks): 2^n e^r, |r| <= ln(2)/2, e^r by its Taylor
 * series to r^13 (truncation below 1e-17 relative), ln 2 split in two so that r is exact to
 * the last bits. */
static SC_ALWAYS_INLINE double sc_exp_lane(double x) {
    /* n = round(x / ln 2), also as an integer: 1.5 2^52 + n holds n in its low mantissa bits
     * (integer operations only: AVX2 has no double-to-int64 conversion). */
    const double shifted = x * 1.4426950408889634 + 6755399441055744.0;
    const double n = shifted - 6755399441055744.0;
    int64_t n_bits;
    memcpy(&n_bits, &shifted, sizeof n_bits);
    const double r = (x - n * 0.6931471803691238) - n * 1.9082149292705877e-10;
    double p = 1.0 / 6227020800.0;
    p = p * r + 1.0 / 479001600.0;
    p = p * r + 1.0 / 39916800.0;
    p = p * r + 1.0 / 3628800.0;
    p = p * r + 1.0 / 362880.0;
    p = p * r + 1.0 / 40320.0;
    p = p * r + 1.0 / 5040.0;
    p = p * r + 1.0 / 720.0;
    p = p * r + 1.0 / 120.0;
    p = p * r + 1.0 / 24.0;
    p = p * r + 1.0 / 6.0;
    p = p * r + 0.5;
    p = p * r + 1.0;
    p = p * r + 1.0;
    /* 2^n from its exponent bits: n + 1023 in [3, 2033]. */
    const int64_t bits = (n_bits - 0x4338000000000000LL + 1023) << 52;
    double scale;
    memcpy(&scale, &bits, sizeof scale);
    return p * scale;
}

/* ln x in double for a normal positive finite x (the caller makes sure): x = 2^e m with m in
 * [sqrt(1/2), sqrt(2)), ln m = 2 atanh(s), s = (m - 1) / (m + 1), |s| < 0.172, by its series to
 * s^21 (truncation below 1e-18), ln 2 split in two. */
static SC_ALWAYS_INLINE double sc_log_lane(double x) {
    uint64_t bits;
    memcpy(&bits, &x, sizeof bits);
    /* the biased exponent as a double through the same 2^52 trick as sc_exp_lane */
    const uint64_t exponent_bits = (bits >> 52) | 0x4330000000000000ULL;
    double biased;
    memcpy(&biased, &exponent_bits, sizeof biased);
    const uint64_t mantissa_bits = (bits & 0x000fffffffffffffULL) | 0x3ff0000000000000ULL;
    double m;
    memcpy(&m, &mantissa_bits, sizeof m);
    const int high = m > 1.4142135623730951;
    m = high ? 0.5 * m : m;
    const double e = (biased - 4503599627370496.0) - 1023.0 + (high ? 1.0 : 0.0);
    const double s = (m - 1.0) / (m + 1.0), z = s * s;
    double p = 1.0 / 21.0;
    p = p * z + 1.0 / 19.0;
    p = p * z + 1.0 / 17.0;
    p = p * z + 1.0 / 15.0;
    p = p * z + 1.0 / 13.0;
    p = p * z + 1.0 / 11.0;
    p = p * z + 1.0 / 9.0;
    p = p * z + 1.0 / 7.0;
    p = p * z + 1.0 / 5.0;
    p = p * z + 1.0 / 3.0;
    const double tail = 2.0 * s * z * p; /* ln m - 2 s */
    return e * 0.6931471803691238 + ((2.0 * s + (tail + e * 1.9082149292705877e-10)));
}

/* The larger of two non-NaN values (not fmax, a library call that stops vectorisation). */
static SC_ALWAYS_INLINE double sc_fmax_lane(double a, double b) { return a > b ? a : b; }

#endif
