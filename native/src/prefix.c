/* Prefix sums over a table of counts, column by column, in parallel: the counting sorts' middle
 * step (sort.c: chunks x digits; binning.c: chunks x tiles). Row r of column c counts what chunk
 * r puts in bucket c; each becomes that chunk's first position in the output, buckets in order
 * and chunks in order within a bucket (so a stable counting sort stays stable).
 *
 * Three passes over ranges of RANGE columns: each range's column totals (reading the table row
 * by row, sequentially), the ranges' starts (serial, one value per range), then each range's
 * positions. One thread walked the whole table before, column-major across rows (a cache miss
 * per count): at 4K with 16 threads, 2M of them per frame. The order of the additions is fixed,
 * so the result is the same on any thread count. */
#include "internal.h"

enum { RANGE = 64 };
/* Below this many counts, the passes run on the calling thread (the pool's wake-up would cost
 * more than the work). */
static const int64_t PARALLEL_FROM = 1 << 15;

typedef struct {
    uint32_t *counts;
    int64_t rows, columns;
    int64_t *starts;       /* (columns + 1) */
    int64_t *range_starts; /* (ranges) */
} prefix_job;

static int64_t range_end(const prefix_job *j, int64_t r) {
    return (r + 1) * RANGE < j->columns ? (r + 1) * RANGE : j->columns;
}

static void column_totals(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    prefix_job *j = ctx;
    for (int64_t r = begin; r < end; ++r) {
        const int64_t c0 = r * RANGE, n = range_end(j, r) - c0;
        int64_t *totals = j->starts + c0;
        for (int64_t c = 0; c < n; ++c) totals[c] = 0;
        for (int64_t row = 0; row < j->rows; ++row) {
            const uint32_t *counts = j->counts + row * j->columns + c0;
            for (int64_t c = 0; c < n; ++c) totals[c] += counts[c];
        }
        int64_t sum = 0;
        for (int64_t c = 0; c < n; ++c) sum += totals[c];
        j->range_starts[r] = sum;
    }
}

static void positions(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    prefix_job *j = ctx;
    uint32_t at[RANGE];
    for (int64_t r = begin; r < end; ++r) {
        const int64_t c0 = r * RANGE, n = range_end(j, r) - c0;
        int64_t sum = j->range_starts[r];
        for (int64_t c = 0; c < n; ++c) {
            const int64_t total = j->starts[c0 + c];
            j->starts[c0 + c] = sum;
            at[c] = (uint32_t)sum;
            sum += total;
        }
        for (int64_t row = 0; row < j->rows; ++row) {
            uint32_t *counts = j->counts + row * j->columns + c0;
            for (int64_t c = 0; c < n; ++c) {
                const uint32_t count = counts[c];
                counts[c] = at[c];
                at[c] += count;
            }
        }
    }
}

int64_t sc_prefix_by_column(uint32_t *counts, int64_t rows, int64_t columns, int64_t *starts,
                            int64_t limit, int threads) {
    const int64_t ranges = (columns + RANGE - 1) / RANGE;
    int64_t *scratch = starts ? NULL : sc_buffer_alloc(sizeof(int64_t) * (size_t)(columns + 1));
    int64_t *range_starts = sc_buffer_alloc(sizeof(int64_t) * (size_t)(ranges ? ranges : 1));
    if ((!starts && !scratch) || !range_starts) {
        sc_buffer_free(scratch);
        sc_buffer_free(range_starts);
        return -1;
    }
    prefix_job j = {.counts = counts, .rows = rows, .columns = columns,
                    .starts = starts ? starts : scratch, .range_starts = range_starts};
    if (rows * columns < PARALLEL_FROM) threads = 1;
    sc_parallel_for(threads, ranges, 1, column_totals, &j);
    int64_t total = 0;
    for (int64_t r = 0; r < ranges; ++r) {
        const int64_t sum = range_starts[r];
        range_starts[r] = total;
        total += sum;
    }
    j.starts[columns] = total;
    if (total <= limit) sc_parallel_for(threads, ranges, 1, positions, &j);
    sc_buffer_free(scratch);
    sc_buffer_free(range_starts);
    return total;
}
