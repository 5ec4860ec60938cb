/* Stable least-significant-digit radix sort of float keys, on the thread pool. Stability is what
 * makes equal depths keep index order, as the reference rasterizer's sort does. The keys are
 * mapped to unsigned integers that sort like the floats and offset by their minimum, so only
 * the bits in which the keys differ are sorted: depths within a factor of 8 of each other span
 * 26 bits, two passes of 13 instead of three of 11. Fewer than 2^32 keys (Gaussian counts are
 * below 2^31). Keys of +inf stand for Gaussians that are not drawn: they go last, as one past
 * the largest finite key.
 *
 * In parallel: the keys are cut into chunks; per pass, each chunk counts its digits, the
 * prefix sums over (digit, chunk) give each chunk its first position per digit (in parallel
 * too, sc_prefix_by_column), and each chunk scatters its keys in their order. That is the one
 * stable order, so the result never depends on the chunks or threads. Key and payload travel as one 64-bit value (one write stream per
 * element, not two), and the last pass writes the payload alone. */
#include <math.h>
#include <string.h>

#include "internal.h"

/* Map float bits to unsigned integers that sort in the same order as the floats. */
static inline uint32_t sortable(float f) {
    uint32_t bits;
    memcpy(&bits, &f, sizeof bits);
    return bits ^ ((uint32_t)-(int32_t)(bits >> 31) | 0x80000000u);
}

enum { SORT_BITS = 13, BUCKETS = 1 << SORT_BITS, MIN_CHUNK = 1 << 14, MAX_CHUNKS = 64 };
static const uint32_t INFINITE_KEY = 0xff800000u; /* sortable(INFINITY) */

typedef struct {
    const float *keys;
    const uint32_t *payload; /* NULL: the key's index */
    int64_t count, chunk_size;
    uint32_t lo, range; /* finite key k sorts as k - lo, +inf as range */
    int shift;          /* of this pass's digit */
    uint32_t mask;
    const uint64_t *from; /* this pass's input (NULL in the first pass: keys and payload) */
    uint64_t *to;         /* this pass's output, or NULL in the last: ... */
    uint32_t *order;      /* ... the payloads alone */
    uint32_t *histogram;  /* (chunks, mask + 1): counts, then each chunk's write cursors */
    struct {
        uint32_t lo, hi;
        int64_t finite;
        char pad[48]; /* one chunk per cache line */
    } bounds[MAX_CHUNKS];
} sort_job;

static inline uint32_t rebased(const sort_job *j, int64_t i) {
    const uint32_t k = sortable(j->keys[i]);
    return k == INFINITE_KEY ? j->range : k - j->lo;
}

static void chunk_range(const sort_job *j, int64_t chunk, int64_t *lo, int64_t *hi) {
    *lo = chunk * j->chunk_size;
    *hi = *lo + j->chunk_size < j->count ? *lo + j->chunk_size : j->count;
}

static void find_bounds(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    sort_job *j = ctx;
    for (int64_t c = begin; c < end; ++c) {
        int64_t lo_i, hi_i;
        chunk_range(j, c, &lo_i, &hi_i);
        uint32_t lo = UINT32_MAX, hi = 0;
        int64_t finite = 0;
        for (int64_t i = lo_i; i < hi_i; ++i) {
            const uint32_t k = sortable(j->keys[i]);
            const int drawn = k != INFINITE_KEY;
            finite += drawn;
            lo = drawn && k < lo ? k : lo;
            hi = drawn && k > hi ? k : hi;
        }
        j->bounds[c].lo = lo, j->bounds[c].hi = hi, j->bounds[c].finite = finite;
    }
}

static void count_digits(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    sort_job *j = ctx;
    for (int64_t c = begin; c < end; ++c) {
        uint32_t *h = j->histogram + c * ((int64_t)j->mask + 1);
        memset(h, 0, sizeof(uint32_t) * ((size_t)j->mask + 1));
        int64_t lo, hi;
        chunk_range(j, c, &lo, &hi);
        if (j->from) {
            for (int64_t i = lo; i < hi; ++i) h[(uint32_t)(j->from[i] >> 32 >> j->shift) & j->mask]++;
        } else {
            for (int64_t i = lo; i < hi; ++i) h[(rebased(j, i) >> j->shift) & j->mask]++;
        }
    }
}

static void scatter(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    sort_job *j = ctx;
    for (int64_t c = begin; c < end; ++c) {
        uint32_t *cursor = j->histogram + c * ((int64_t)j->mask + 1);
        int64_t lo, hi;
        chunk_range(j, c, &lo, &hi);
        const int shift = j->shift;
        const uint32_t mask = j->mask;
        for (int64_t i = lo; i < hi; ++i) {
            uint64_t v;
            if (j->from) {
                v = j->from[i];
            } else {
                const uint32_t payload = j->payload ? j->payload[i] : (uint32_t)i;
                v = (uint64_t)rebased(j, i) << 32 | payload;
            }
            const uint32_t dst = cursor[(uint32_t)(v >> 32 >> shift) & mask]++;
            /* Thousands of digits fill their runs at once, too many streams for the hardware
             * prefetcher: ask for each run's next cache line ahead of time. */
            if (j->to) {
                if (dst + 8 < j->count) SC_PREFETCH_WRITE(&j->to[dst + 8]);
                j->to[dst] = v;
            } else {
                if (dst + 16 < j->count) SC_PREFETCH_WRITE(&j->order[dst + 16]);
                j->order[dst] = (uint32_t)v;
            }
        }
    }
}

int64_t sc_sort_by_depth(const float *keys, int64_t count, const uint32_t *payload, int threads,
                         uint32_t *order, int64_t *bytes) {
    *bytes = 0;
    if (count <= 0) return 0;
    sort_job j = {.keys = keys, .payload = payload, .count = count, .order = order};
    int64_t chunks = threads < 1 ? 1 : (int64_t)threads * 2; /* a little balancing */
    if (chunks > (count + MIN_CHUNK - 1) / MIN_CHUNK) chunks = (count + MIN_CHUNK - 1) / MIN_CHUNK;
    if (chunks > MAX_CHUNKS) chunks = MAX_CHUNKS;
    j.chunk_size = (count + chunks - 1) / chunks;
    chunks = (count + j.chunk_size - 1) / j.chunk_size;

    sc_parallel_for(threads, chunks, 1, find_bounds, &j);
    uint32_t lo = UINT32_MAX, hi = 0;
    int64_t finite = 0;
    for (int64_t c = 0; c < chunks; ++c) {
        lo = j.bounds[c].lo < lo ? j.bounds[c].lo : lo;
        hi = j.bounds[c].hi > hi ? j.bounds[c].hi : hi;
        finite += j.bounds[c].finite;
    }
    if (finite <= 1 || hi == lo) { /* nothing to order but the drawn before the rest */
        int64_t at = 0;
        for (int pass = 0; pass < 2; ++pass)
            for (int64_t i = 0; i < count; ++i)
                if ((sortable(keys[i]) == INFINITE_KEY) == pass)
                    order[at++] = payload ? payload[i] : (uint32_t)i;
        return finite;
    }
    j.lo = lo;
    j.range = hi - lo + 1; /* +inf sorts as one past the largest finite key */
    int bits = 0;
    while (bits < 32 && (j.range >> bits) != 0) ++bits;
    const int passes = (bits + SORT_BITS - 1) / SORT_BITS;
    const int width = (bits + passes - 1) / passes; /* <= SORT_BITS */
    j.mask = (1u << width) - 1;

    /* Ping-pong between two arrays of (key, payload); one suffices for up to two passes. */
    const size_t values = (size_t)count * (passes > 2 ? 2 : 1);
    *bytes = (int64_t)(sizeof(uint64_t) * values + sizeof(uint32_t) * (size_t)(chunks * BUCKETS));
    uint64_t *values_a = sc_buffer_alloc(sizeof(uint64_t) * values);
    j.histogram = sc_buffer_alloc(sizeof(uint32_t) * (size_t)(chunks * BUCKETS));
    if (!values_a || !j.histogram) {
        sc_buffer_free(values_a);
        sc_buffer_free(j.histogram);
        return -1;
    }
    uint64_t *buffers[2] = {values_a, passes > 2 ? values_a + count : NULL};
    /* A single pass cannot write the payloads over `payload` while reading it: it goes through
     * the value array, reinterpreted, and is copied out. */
    uint32_t *single = passes == 1 ? (uint32_t *)values_a : NULL;
    for (int p = 0; p < passes; ++p) {
        j.shift = p * width;
        j.from = p == 0 ? NULL : buffers[(p - 1) & 1];
        j.to = p == passes - 1 ? NULL : buffers[p & 1];
        j.order = single ? single : order;
        sc_parallel_for(threads, chunks, 1, count_digits, &j);
        /* The counts become the chunks' write cursors: digit-major, chunk-minor. */
        if (sc_prefix_by_column(j.histogram, chunks, (int64_t)j.mask + 1, NULL, count,
                                threads) < 0) {
            sc_buffer_free(values_a);
            sc_buffer_free(j.histogram);
            return -1;
        }
        sc_parallel_for(threads, chunks, 1, scatter, &j);
    }
    if (single) memcpy(order, single, sizeof(uint32_t) * (size_t)count);
    sc_buffer_free(values_a);
    sc_buffer_free(j.histogram);
    return finite;
}

sc_status sc_sort_keys(const float *keys, int64_t count, int threads, int32_t *order,
                       int64_t *finite, sc_stats *stats) {
    *finite = 0;
    if (count < 0 || count > INT32_MAX) return SC_ERR_TOO_LARGE;
    for (int64_t i = 0; i < count; ++i)
        if (isnan(keys[i])) {
            stats->error_index = i;
            return SC_ERR_NONFINITE;
        }
    int64_t bytes;
    /* int32 and uint32 share their representation for indices below 2^31. */
    *finite = sc_sort_by_depth(keys, count, NULL, threads, (uint32_t *)order, &bytes);
    return *finite < 0 ? SC_ERR_MEMORY : SC_OK;
}
