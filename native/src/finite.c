/* The entry points' check of their FINITE arguments (module.c): the first NaN or Inf of an
 * array. Gradients and images checked at every training step add up to millions of values
 * (Adam's gradients alone are 59 per Gaussian); one thread scanning them under the GIL was a
 * tenth of a step's serial time. Chunks of CHUNK values on the pool, each one branch-free pass
 * over the exponent bits (an integer compare and OR, which vectorises), the index looked for
 * only in a chunk that has one. */
#include <stdatomic.h>

#include "internal.h"

enum { CHUNK = 1 << 16 };

typedef struct {
    const float *values;
    int64_t n;
    atomic_llong first; /* the smallest index found, or n */
} job;

static SC_ALWAYS_INLINE int any_non_finite_body(const float *restrict v, int64_t n) {
    uint32_t bad = 0;
    for (int64_t i = 0; i < n; ++i) {
        uint32_t bits;
        memcpy(&bits, v + i, sizeof bits);
        bad |= (bits & 0x7f800000u) == 0x7f800000u; /* exponent all ones: Inf or NaN */
    }
    return bad != 0;
}

SC_MULTIVERSION(int, any_non_finite, (const float *v, int64_t n), (v, n),
                any_non_finite_body(v, n))

static void scan(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    job *j = ctx;
    for (int64_t c = begin; c < end; ++c) {
        const int64_t lo = c * CHUNK, hi = lo + CHUNK < j->n ? lo + CHUNK : j->n;
        if (!any_non_finite(j->values + lo, hi - lo)) continue;
        int64_t i = lo;
        while (isfinite(j->values[i])) ++i;
        long long seen = atomic_load(&j->first);
        while (i < seen && !atomic_compare_exchange_weak(&j->first, &seen, i)) {
        }
        return; /* later chunks cannot hold a smaller index */
    }
}

int64_t sc_first_non_finite(const float *values, int64_t n, int threads) {
    job j = {.values = values, .n = n};
    atomic_init(&j.first, n);
    sc_parallel_for(threads, (n + CHUNK - 1) / CHUNK, 1, scan, &j);
    const long long first = atomic_load(&j.first);
    return first < n ? first : -1;
}
