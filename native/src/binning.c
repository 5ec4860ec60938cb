/* Binning: every drawn Gaussian into the 16x16 tiles its alpha >= 1/255 ellipse reaches, with
 * each tile's list in depth order. The input is already sorted front to back, and a counting
 * sort over tiles keeps that order: count per (chunk, tile), prefix sums, scatter. No per-pair
 * sort is needed, and the input is read sequentially.
 *
 * The tiles are exact for the ellipse, not its bounding box: for each tile row the ellipse's
 * x-extent over that row's pixel centres is computed in closed form, which removes the empty
 * corner tiles of elongated, rotated splats.
 *
 * Every pass runs on the thread pool, the prefix sums too (sc_prefix_by_column), which at 4K
 * with 16 threads had been 2M strided reads and writes on one thread. Per (chunk, tile) there is one
 * 32-bit count, turned into that chunk's write cursor in place, and the chunks are capped so
 * that these take at most COUNTS_BYTES beyond one row per thread: at 8K on 16 threads 33 MB,
 * where counts and 64-bit cursors had taken 100 MB. */
#include <math.h>
#include <stdlib.h>

#include "internal.h"

/* A splat's tiles: its bounding box's tile rectangle [tx0, tx1) x [ty0, ty1) (empty: ty1 = ty0)
 * and, when that spans several tile rows and columns, its ellipse d^T conic d <= k2, with the
 * covariance the float conic stands for inverted in double, set up for row_tiles. */
typedef struct {
    int32_t tx0, tx1, ty0, ty1, row0, row1;
    int exact;                        /* whether row_tiles trims the rectangle's rows */
    double x, y, k2, ry, slope, s_cond, d_right, inv_c;
} shape;

static SC_ALWAYS_INLINE void shape_of(const sc_splat *s, shape *sh) {
    const int reaches = s->row1 >= s->row0 && s->col1 >= s->col0;
    sh->tx0 = s->col0 / SC_TILE, sh->tx1 = reaches ? s->col1 / SC_TILE + 1 : sh->tx0;
    sh->ty0 = s->row0 / SC_TILE, sh->ty1 = reaches ? s->row1 / SC_TILE + 1 : sh->ty0;
    sh->row0 = s->row0, sh->row1 = s->row1;
    const double ca = s->ca, cb = s->cb, cc = s->cc, det = ca * cc - cb * cb;
    /* One tile row or column: the rectangle is already exact (or a harmless superset). So is
     * it for a conic that float made singular (the footprint is then unbounded). */
    sh->exact = sh->tx1 - sh->tx0 > 1 && sh->ty1 - sh->ty0 > 1 && det > 0.0;
    if (!sh->exact) return;
    /* The covariance [a b; b c] = conic^-1, with three divisions rather than seven (each a long
     * latency; the 1e-3 px margin of row_tiles dwarfs the difference in rounding). */
    const double inv_det = 1.0 / det, inv_ca = 1.0 / ca, k2 = s->k2;
    const double b = -cb * inv_det, c = ca * inv_det;
    /* Points of the ellipse (dx - (b/c) dy)^2 / s + dy^2 / c <= k2 with s = det(cov) / c. */
    sh->x = s->x, sh->y = s->y, sh->k2 = k2;
    sh->ry = sqrt(k2 * c), sh->slope = -cb * inv_ca, sh->s_cond = inv_ca, sh->inv_c = det * inv_ca;
    /* The ellipse's rightmost point is at dy = b k / sqrt(a), a = cc / det. */
    sh->d_right = b * sqrt(k2 * det / cc);
}

/* Tile columns [*t0, *t1) that the splat reaches within tile row `ty` (over that row's pixel
 * centres): the x-extent of the ellipse is concave in dy, so its maximum over the row's dy
 * range is at the clamped dy of the rightmost point, its minimum likewise at the leftmost. */
static SC_ALWAYS_INLINE void row_tiles(const shape *sh, int ty, int width, int32_t *t0,
                                      int32_t *t1) {
    if (!sh->exact) {
        *t0 = sh->tx0, *t1 = sh->tx1;
        return;
    }
    *t0 = *t1 = 0;
    int32_t j_lo = ty * SC_TILE > sh->row0 ? ty * SC_TILE : sh->row0;
    int32_t j_hi = ty * SC_TILE + SC_TILE - 1 < sh->row1 ? ty * SC_TILE + SC_TILE - 1 : sh->row1;
    if (j_lo > j_hi) return;
    double lo = j_lo + 0.5 - sh->y, hi = j_hi + 0.5 - sh->y;
    if (lo < -sh->ry) lo = -sh->ry;
    if (hi > sh->ry) hi = sh->ry;
    if (lo > hi) return;
    const double d1 = sh->d_right < lo ? lo : (sh->d_right > hi ? hi : sh->d_right);
    const double d2 = -sh->d_right < lo ? lo : (-sh->d_right > hi ? hi : -sh->d_right);
    const double h1 = sh->s_cond * (sh->k2 - d1 * d1 * sh->inv_c);
    const double h2 = sh->s_cond * (sh->k2 - d2 * d2 * sh->inv_c);
    const double margin = 1e-3; /* pixels; the compositor works in float */
    double x_max = sh->x + sh->slope * d1 + sqrt(h1 > 0 ? h1 : 0) + margin;
    double x_min = sh->x + sh->slope * d2 - sqrt(h2 > 0 ? h2 : 0) - margin;
    double i0 = ceil(x_min - 0.5), i1 = floor(x_max - 0.5);
    if (i0 < 0) i0 = 0;
    if (i1 > width - 1) i1 = width - 1;
    if (i0 > i1) return;
    *t0 = (int32_t)i0 / SC_TILE;
    *t1 = (int32_t)i1 / SC_TILE + 1;
    if (*t0 < sh->tx0) *t0 = sh->tx0;
    if (*t1 > sh->tx1) *t1 = sh->tx1;
    if (*t1 < *t0) *t1 = *t0;
}

typedef struct {
    const sc_splat *splats;
    const sc_camera *cam;
    int64_t count, chunk_size;
    int tiles_x;
    int64_t ntiles;
    uint32_t *counts;  /* (chunks, ntiles): pairs, then in place each chunk's write cursor */
    int64_t *offsets;  /* (ntiles + 1) each tile's first list entry */
    uint32_t *list;
    int64_t pairs_total; /* entries of `list` */
    uint64_t *codes;       /* (count) each splat's tiles, from the count pass to the scatter */
    int64_t *pair_offsets; /* optional (count + 1): each Gaussian's pairs, counted then summed */
    int64_t *chunk_pairs;  /* optional (chunks): pairs per chunk, then each chunk's first */
    uint32_t *pairs;       /* optional: list positions of each Gaussian's pairs, tile order */
} job;

/* The per-(chunk, tile) counts may take this much beyond a chunk per thread. */
static const int64_t COUNTS_BYTES = (int64_t)32 << 20;

/* The passes are written once, with a constant `inverse` flag that the compiler folds, so the
 * plain render pays nothing for the optional Gaussian -> pairs index. */
/* The count pass remembers each splat's tiles for the scatter pass, which then reads neither
 * the splat (64 bytes) nor solves its ellipse again: up to 4 tile rows of up to 14 tile columns
 * as one 64-bit code, a byte per row holding [t0, t1) relative to the rectangle's first column
 * (t0 low nibble, t1 high nibble), then the rectangle's corner and its number of rows. Larger
 * footprints (rare) are solved again. */
enum { CODE_ROWS = 4, CODE_COLUMNS = 14, CODE_TX = 32, CODE_TY = 48, CODE_NROWS = 61 };
static const uint64_t RECOMPUTE = ~(uint64_t)0; /* a code holds at most 4 rows, never 7 */

static SC_ALWAYS_INLINE void count_pass(job *j, int64_t begin, int64_t end, const int inverse) {
    for (int64_t chunk = begin; chunk < end; ++chunk) {
        uint32_t *counts = j->counts + chunk * j->ntiles;
        memset(counts, 0, sizeof(uint32_t) * (size_t)j->ntiles);
        int64_t lo = chunk * j->chunk_size, hi = lo + j->chunk_size;
        if (hi > j->count) hi = j->count;
        int64_t chunk_pairs = 0;
        for (int64_t k = lo; k < hi; ++k) {
            shape sh = {0}; /* (what row_tiles reads is set whenever it reads it) */
            shape_of(&j->splats[k], &sh);
            const int coded = sh.ty1 - sh.ty0 <= CODE_ROWS && sh.tx1 - sh.tx0 <= CODE_COLUMNS &&
                              sh.tx0 < (1 << (CODE_TY - CODE_TX)) && sh.ty0 < (1 << (CODE_NROWS - CODE_TY));
            uint64_t code = 0;
            int64_t pairs = 0;
            for (int ty = sh.ty0; ty < sh.ty1; ++ty) {
                int32_t t0, t1;
                row_tiles(&sh, ty, j->cam->width, &t0, &t1);
                for (int tx = t0; tx < t1; ++tx) counts[(int64_t)ty * j->tiles_x + tx]++;
                pairs += t1 - t0;
                if (coded && t1 > t0) /* an empty row stays 0 */
                    code |= (uint64_t)((t0 - sh.tx0) | (t1 - sh.tx0) << 4) << 8 * (ty - sh.ty0);
            }
            code |= (uint64_t)sh.tx0 << CODE_TX | (uint64_t)sh.ty0 << CODE_TY |
                    (uint64_t)(sh.ty1 - sh.ty0) << CODE_NROWS;
            j->codes[k] = coded ? code : RECOMPUTE;
            if (inverse) j->pair_offsets[k] = pairs;
            chunk_pairs += pairs;
        }
        if (inverse) j->chunk_pairs[chunk] = chunk_pairs;
    }
}

static SC_ALWAYS_INLINE void scatter_pass(job *j, int64_t begin, int64_t end,
                                         const int inverse) {
    for (int64_t chunk = begin; chunk < end; ++chunk) {
        uint32_t *cursor = j->counts + chunk * j->ntiles;
        int64_t lo = chunk * j->chunk_size, hi = lo + j->chunk_size;
        if (hi > j->count) hi = j->count;
        if (inverse) { /* this chunk's per-Gaussian pair counts -> offsets */
            int64_t sum = j->chunk_pairs[chunk];
            for (int64_t k = lo; k < hi; ++k) {
                const int64_t c = j->pair_offsets[k];
                j->pair_offsets[k] = sum;
                sum += c;
            }
        }
        for (int64_t k = lo; k < hi; ++k) {
            const uint64_t code = j->codes[k];
            shape sh = {0}; /* (what row_tiles reads is set whenever it reads it) */
            if (code == RECOMPUTE) {
                shape_of(&j->splats[k], &sh);
            } else { /* only the rectangle's corner is needed */
                sh.tx0 = (int32_t)(code >> CODE_TX & ((1u << (CODE_TY - CODE_TX)) - 1));
                sh.ty0 = (int32_t)(code >> CODE_TY & ((1u << (CODE_NROWS - CODE_TY)) - 1));
                sh.ty1 = sh.ty0 + (int32_t)(code >> CODE_NROWS);
            }
            uint32_t *mine = inverse ? j->pairs + j->pair_offsets[k] : NULL;
            for (int ty = sh.ty0; ty < sh.ty1; ++ty) {
                int32_t t0, t1;
                if (code == RECOMPUTE) {
                    row_tiles(&sh, ty, j->cam->width, &t0, &t1);
                } else {
                    const uint32_t row = (uint32_t)(code >> 8 * (ty - sh.ty0));
                    t0 = sh.tx0 + (int32_t)(row & 15), t1 = sh.tx0 + (int32_t)(row >> 4 & 15);
                }
                for (int tx = t0; tx < t1; ++tx) {
                    const int64_t at = cursor[(int64_t)ty * j->tiles_x + tx]++;
                    /* Thousands of tiles fill their lists at once, too many streams for the
                     * hardware prefetcher: ask for each tile's next cache line ahead of time. */
                    if (at + 16 < j->pairs_total) SC_PREFETCH_WRITE(&j->list[at + 16]);
                    j->list[at] = (uint32_t)k;
                    if (inverse) *mine++ = (uint32_t)at;
                }
            }
        }
    }
}

/* The count pass solves the ellipses (divisions, square roots, ceil and floor in double): it is
 * compiled per instruction-set level too, for SSE4.1's rounding and AVX's encodings. */
SC_MULTIVERSION(void, count_chunk, (void *ctx, int64_t begin, int64_t end, int thread),
                (ctx, begin, end, thread), ((void)thread, count_pass(ctx, begin, end, 0)))

SC_MULTIVERSION(void, count_chunk_inverse, (void *ctx, int64_t begin, int64_t end, int thread),
                (ctx, begin, end, thread), ((void)thread, count_pass(ctx, begin, end, 1)))

static void scatter_chunk(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    scatter_pass(ctx, begin, end, 0);
}

static void scatter_chunk_inverse(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    scatter_pass(ctx, begin, end, 1);
}

/* At most this many Gaussian/tile pairs (4 GiB of list). */
static const int64_t MAX_PAIRS = (int64_t)1 << 30;

sc_status sc_bin(const sc_splat *splats, int64_t count, const sc_camera *cam, int threads,
                 int64_t **offsets_out, uint32_t **list_out, int64_t **pair_offsets_out,
                 uint32_t **pairs_out, int64_t *peak_bytes) {
    job j = {.splats = splats, .cam = cam, .count = count};
    const int inverse = pair_offsets_out != NULL;
    j.tiles_x = (cam->width + SC_TILE - 1) / SC_TILE;
    const int tiles_y = (cam->height + SC_TILE - 1) / SC_TILE;
    j.ntiles = (int64_t)j.tiles_x * tiles_y;
    /* A few chunks per thread balance the load; the result does not depend on the split. Big
     * frames keep the counts to COUNTS_BYTES, or one row per thread. */
    if (threads < 1) threads = 1;
    int64_t chunks = (int64_t)threads * 4;
    const int64_t affordable = COUNTS_BYTES / (int64_t)(sizeof(uint32_t) * (size_t)j.ntiles);
    if (chunks > affordable) chunks = affordable > threads ? affordable : threads;
    if (chunks > (count + 1023) / 1024) chunks = (count + 1023) / 1024;
    if (chunks < 1) chunks = 1;
    j.chunk_size = (count + chunks - 1) / chunks;
    if (j.chunk_size < 1) j.chunk_size = 1;
    chunks = (count + j.chunk_size - 1) / j.chunk_size;
    if (chunks < 1) chunks = 1;

    j.offsets = sc_buffer_alloc(sizeof(int64_t) * (size_t)(j.ntiles + 1));
    j.counts = sc_buffer_alloc(sizeof(uint32_t) * (size_t)(chunks * j.ntiles));
    j.codes = sc_buffer_alloc(sizeof(uint64_t) * (size_t)(count ? count : 1));
    if (inverse) {
        j.pair_offsets = sc_buffer_alloc(sizeof(int64_t) * (size_t)(count + 1));
        j.chunk_pairs = sc_buffer_alloc(sizeof(int64_t) * (size_t)chunks);
    }
    if (!j.offsets || !j.counts || !j.codes || (inverse && (!j.pair_offsets || !j.chunk_pairs)))
        goto out_of_memory;

    sc_parallel_for(threads, chunks, 1, inverse ? count_chunk_inverse : count_chunk, &j);
    /* The counts become each chunk's cursor in each tile's list, offsets each list's start. */
    const int64_t total = sc_prefix_by_column(j.counts, chunks, j.ntiles, j.offsets, MAX_PAIRS,
                                              threads);
    if (total < 0) goto out_of_memory;
    j.pairs_total = total;
    if (total > MAX_PAIRS) {
        sc_buffer_free(j.offsets);
        sc_buffer_free(j.counts);
        sc_buffer_free(j.codes);
        sc_buffer_free(j.pair_offsets);
        sc_buffer_free(j.chunk_pairs);
        return SC_ERR_TOO_LARGE;
    }
    if (inverse) { /* the chunks' first pairs; each chunk sums its Gaussians' in the scatter */
        int64_t sum = 0;
        for (int64_t c = 0; c < chunks; ++c) {
            const int64_t n = j.chunk_pairs[c];
            j.chunk_pairs[c] = sum;
            sum += n;
        }
        j.pair_offsets[count] = sum; /* = total */
        j.pairs = sc_buffer_alloc(sizeof(uint32_t) * (size_t)(total ? total : 1));
        if (!j.pairs) goto out_of_memory;
    }
    j.list = sc_buffer_alloc(sizeof(uint32_t) * (size_t)(total ? total : 1));
    if (!j.list) goto out_of_memory;
    /* The most held at once: during the scatter. */
    *peak_bytes = (int64_t)(sizeof(int64_t) * (size_t)(j.ntiles + 1) +
                            sizeof(uint32_t) * (size_t)(chunks * j.ntiles) +
                            sizeof(uint32_t) * (size_t)total * (inverse ? 2 : 1) +
                            sizeof(uint64_t) * (size_t)count +
                            (inverse ? sizeof(int64_t) * (size_t)(count + 1 + chunks) : 0));
    sc_parallel_for(threads, chunks, 1, inverse ? scatter_chunk_inverse : scatter_chunk, &j);
    sc_buffer_free(j.counts);
    sc_buffer_free(j.codes);
    sc_buffer_free(j.chunk_pairs);
    *offsets_out = j.offsets;
    *list_out = j.list;
    if (inverse) {
        *pair_offsets_out = j.pair_offsets;
        *pairs_out = j.pairs;
    }
    return SC_OK;

out_of_memory:
    sc_buffer_free(j.offsets);
    sc_buffer_free(j.counts);
    sc_buffer_free(j.codes);
    sc_buffer_free(j.pair_offsets);
    sc_buffer_free(j.chunk_pairs);
    sc_buffer_free(j.pairs);
    sc_buffer_free(j.list);
    return SC_ERR_MEMORY;
}
