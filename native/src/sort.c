/* Stable least-significant-digit radix sort of float keys (3 passes of 11 bits). Stability is
 * what makes equal depths keep index order, as the reference rasterizer's sort does. */
#include <string.h>

#include "internal.h"

/* Map float bits to unsigned integers that sort in the same order as the floats. */
static uint32_t sortable(float f) {
    uint32_t bits;
    memcpy(&bits, &f, sizeof bits);
    return bits ^ ((uint32_t)-(int32_t)(bits >> 31) | 0x80000000u);
}

void sc_sort_by_depth(const float *keys, int64_t count, uint32_t *order, uint32_t *scratch) {
    enum { BITS = 11, BUCKETS = 1 << BITS };
    uint32_t *key_a = scratch, *key_b = scratch + count;
    uint32_t *idx_a = order, *idx_b = scratch + 2 * count;
    for (int64_t i = 0; i < count; ++i) key_a[i] = sortable(keys[i]);
    for (int shift = 0; shift < 32; shift += BITS) {
        int64_t histogram[BUCKETS] = {0};
        for (int64_t i = 0; i < count; ++i) histogram[(key_a[i] >> shift) & (BUCKETS - 1)]++;
        int64_t sum = 0;
        for (int b = 0; b < BUCKETS; ++b) {
            int64_t c = histogram[b];
            histogram[b] = sum;
            sum += c;
        }
        for (int64_t i = 0; i < count; ++i) {
            int64_t dst = histogram[(key_a[i] >> shift) & (BUCKETS - 1)]++;
            key_b[dst] = key_a[i];
            idx_b[dst] = idx_a[i];
        }
        uint32_t *t = key_a; key_a = key_b; key_b = t;
        t = idx_a; idx_a = idx_b; idx_b = t;
    }
    /* An odd number of passes leaves the result in the scratch buffer. */
    if (idx_a != order) memcpy(order, idx_a, sizeof(uint32_t) * (size_t)count);
}
