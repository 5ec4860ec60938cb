/* Stable least-significant-digit radix sort of float keys. Stability is what makes equal depths
 * keep index order, as the reference rasterizer's sort does. The keys are first mapped to
 * unsigned integers that sort like the floats and offset by their minimum, so only the bits in
 * which the keys differ are sorted: depths within a factor of 2 of each other span 24 bits, two
 * passes of 12 instead of three of 11. All the passes' histograms are counted in one read of
 * the keys. Fewer than 2^32 keys (Gaussian counts are below 2^31). */
#include <string.h>

#include "internal.h"

/* Map float bits to unsigned integers that sort in the same order as the floats. */
static uint32_t sortable(float f) {
    uint32_t bits;
    memcpy(&bits, &f, sizeof bits);
    return bits ^ ((uint32_t)-(int32_t)(bits >> 31) | 0x80000000u);
}

enum { MAX_BITS = 12, MAX_PASSES = 3 }; /* 3 x 12 >= 32 */

void sc_sort_by_depth(const float *keys, int64_t count, uint32_t *order, uint32_t *scratch) {
    if (count <= 1) return;
    uint32_t *key_a = scratch, *key_b = scratch + count;
    uint32_t *idx_a = order, *idx_b = scratch + 2 * count;
    uint32_t lo = UINT32_MAX, hi = 0;
    for (int64_t i = 0; i < count; ++i) {
        const uint32_t k = sortable(keys[i]);
        key_a[i] = k;
        lo = k < lo ? k : lo;
        hi = k > hi ? k : hi;
    }
    const uint32_t range = hi - lo;
    int bits = 0;
    while (bits < 32 && (range >> bits) != 0) ++bits;
    if (bits == 0) return; /* all equal: a stable sort changes nothing */
    const int passes = (bits + MAX_BITS - 1) / MAX_BITS;
    const int width = (bits + passes - 1) / passes; /* <= MAX_BITS */
    const uint32_t mask = (1u << width) - 1;

    uint32_t histogram[MAX_PASSES][1 << MAX_BITS]; /* 48 KiB: counts fit, count < 2^32 */
    memset(histogram, 0, sizeof histogram);
    for (int64_t i = 0; i < count; ++i) {
        const uint32_t k = key_a[i] - lo;
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
}
