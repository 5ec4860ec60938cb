/* Stable least-significant-digit radix sort of float keys. Stability is what makes equal depths
 * keep index order, as the reference rasterizer's sort does. The keys are first mapped to
 * unsigned integers that sort like the floats and offset by their minimum, so only the bits in
 * which the keys differ are sorted: depths within a factor of 8 of each other span 26 bits, two
 * passes of 13 instead of three of 11. All the passes' histograms are counted in one read of
 * the keys. Fewer than 2^32 keys (Gaussian counts are below 2^31). Keys of +inf stand for
 * Gaussians that are not drawn: they go last, as one past the largest finite key. */
#include <math.h>
#include <string.h>

#include "internal.h"

/* Map float bits to unsigned integers that sort in the same order as the floats. */
static uint32_t sortable(float f) {
    uint32_t bits;
    memcpy(&bits, &f, sizeof bits);
    return bits ^ ((uint32_t)-(int32_t)(bits >> 31) | 0x80000000u);
}


int64_t sc_sort_by_depth(const float *keys, int64_t count, uint32_t *order, uint32_t *scratch) {
    uint32_t *key_a = scratch, *key_b = scratch + count;
    uint32_t *idx_a = order, *idx_b = scratch + 2 * count;
    const uint32_t infinity = sortable(INFINITY);
    uint32_t lo = UINT32_MAX, hi = 0;
    int64_t finite = 0;
    for (int64_t i = 0; i < count; ++i) {
        const uint32_t k = sortable(keys[i]);
        key_a[i] = k;
        const int drawn = k != infinity;
        finite += drawn;
        lo = drawn && k < lo ? k : lo;
        hi = drawn && k > hi ? k : hi;
    }
    if (finite <= 1 || hi == lo) { /* nothing to order but the drawn before the rest */
        int64_t at = 0;
        for (int64_t i = 0; i < count; ++i)
            if (key_a[i] != infinity) key_b[at++] = idx_a[i];
        for (int64_t i = 0; i < count; ++i)
            if (key_a[i] == infinity) key_b[at++] = idx_a[i];
        memcpy(order, key_b, sizeof(uint32_t) * (size_t)count);
        return finite;
    }
    /* +inf sorts as one past the largest finite key. */
    const uint32_t range = hi - lo + 1;
    int bits = 0;
    while (bits < 32 && (range >> bits) != 0) ++bits;
    const int passes = (bits + SC_SORT_BITS - 1) / SC_SORT_BITS;
    const int width = (bits + passes - 1) / passes; /* <= SC_SORT_BITS */
    const uint32_t mask = (1u << width) - 1;

    /* After the keys and payloads in scratch; counts fit in 32 bits, count < 2^32. */
    uint32_t(*histogram)[1 << SC_SORT_BITS] = (uint32_t(*)[1 << SC_SORT_BITS])(scratch + 3 * count);
    memset(histogram, 0, sizeof(uint32_t) * SC_SORT_EXTRA);
    for (int64_t i = 0; i < count; ++i) {
        const uint32_t k = key_a[i] == infinity ? range : key_a[i] - lo;
        key_a[i] = k;
        for (int p = 0; p < passes; ++p) histogram[p][(k >> (p * width)) & mask]++;
    }
    for (int p = 0; p < passes; ++p) {
        uint32_t sum = 0;
        for (uint32_t b = 0; b <= mask; ++b) {
            const uint32_t c = histogram[p][b];
            histogram[p][b] = sum;
            sum += c;
        }
    }
    for (int p = 0; p < passes; ++p) {
        const int shift = p * width;
        uint32_t *cursor = histogram[p];
        for (int64_t i = 0; i < count; ++i) {
            const uint32_t dst = cursor[(key_a[i] >> shift) & mask]++;
            key_b[dst] = key_a[i];
            idx_b[dst] = idx_a[i];
        }
        uint32_t *t = key_a; key_a = key_b; key_b = t;
        t = idx_a; idx_a = idx_b; idx_b = t;
    }
    /* An odd number of passes leaves the result in the scratch buffer. */
    if (idx_a != order) memcpy(order, idx_a, sizeof(uint32_t) * (size_t)count);
    return finite;
}
