/* Binning: every drawn Gaussian into the 16x16 tiles its alpha >= 1/255 ellipse reaches, with
 * each tile's list in depth order. The input is already sorted front to back, and a counting
 * sort over tiles keeps that order: count per (chunk, tile), prefix sums, scatter. No per-pair
 * sort is needed, and the input is read sequentially.
 *
 * The tiles are exact for the ellipse, not its bounding box: for each tile row the ellipse's
 * x-extent over that row's pixel centres is computed in closed form, which removes the empty
 * corner tiles of elongated, rotated splats. */
#include <math.h>
#include <stdlib.h>

#include "internal.h"

/* Tile columns [*t0, *t1) that Gaussian `s`/`f` reaches within tile row `ty`. */
static void row_tiles(const sc_footprint *f, const sc_splat *s, int ty, const sc_camera *cam,
                      int32_t *t0, int32_t *t1) {
    /* One tile row or column: the rectangle is already exact (or a harmless superset). */
    if (f->tx1 - f->tx0 == 1 || f->ty1 - f->ty0 == 1) {
        *t0 = f->tx0, *t1 = f->tx1;
        return;
    }
    *t0 = *t1 = 0;
    int32_t j_lo = ty * SC_TILE > s->row0 ? ty * SC_TILE : s->row0;
    int32_t j_hi = ty * SC_TILE + SC_TILE - 1 < s->row1 ? ty * SC_TILE + SC_TILE - 1 : s->row1;
    if (j_lo > j_hi) return;
    const double a = f->cov_a, b = f->cov_b, c = f->cov_c, k2 = f->k2;
    /* Points of the ellipse (dx - (b/c) dy)^2 / s + dy^2 / c <= k2 with s = det / c. */
    const double ry = sqrt(k2 * c), slope = b / c, s_cond = (a * c - b * b) / c;
    double lo = j_lo + 0.5 - (double)s->y, hi = j_hi + 0.5 - (double)s->y;
    if (lo < -ry) lo = -ry;
    if (hi > ry) hi = ry;
    if (lo > hi) return;
    /* The x-extent is concave in dy: its maximum over [lo, hi] is at the clamped dy of the
     * ellipse's rightmost point, b k / sqrt(a); its minimum likewise at the leftmost point. */
    const double d_right = b * sqrt(k2 / a);
    const double d1 = d_right < lo ? lo : (d_right > hi ? hi : d_right);
    const double d2 = -d_right < lo ? lo : (-d_right > hi ? hi : -d_right);
    const double h1 = s_cond * (k2 - d1 * d1 / c), h2 = s_cond * (k2 - d2 * d2 / c);
    const double margin = 1e-3; /* pixels; the compositor works in float */
    double x_max = (double)s->x + slope * d1 + sqrt(h1 > 0 ? h1 : 0) + margin;
    double x_min = (double)s->x + slope * d2 - sqrt(h2 > 0 ? h2 : 0) - margin;
    double i0 = ceil(x_min - 0.5), i1 = floor(x_max - 0.5);
    if (i0 < 0) i0 = 0;
    if (i1 > cam->width - 1) i1 = cam->width - 1;
    if (i0 > i1) return;
    *t0 = (int32_t)i0 / SC_TILE;
    *t1 = (int32_t)i1 / SC_TILE + 1;
    if (*t0 < f->tx0) *t0 = f->tx0;
    if (*t1 > f->tx1) *t1 = f->tx1;
    if (*t1 < *t0) *t1 = *t0;
}

typedef struct {
    const sc_footprint *fp;
    const sc_splat *splats;
    const sc_camera *cam;
    int64_t count, chunk_size;
    int tiles_x;
    int64_t ntiles;
    uint32_t *counts;  /* (chunks, ntiles): pairs, then each chunk's write cursor */
    int64_t *cursors;  /* (chunks, ntiles) during the scatter */
    uint32_t *list;
    int64_t *pair_offsets; /* optional (count + 1): each Gaussian's pairs, counted then summed */
    uint32_t *pairs;       /* optional: list positions of each Gaussian's pairs, tile order */
} job;

/* The passes are written once, with a constant `inverse` flag that the compiler folds, so the
 * plain render pays nothing for the optional Gaussian -> pairs index. */
static inline void count_pass(job *j, int64_t begin, int64_t end, const int inverse) {
    for (int64_t chunk = begin; chunk < end; ++chunk) {
        uint32_t *counts = j->counts + chunk * j->ntiles;
        int64_t lo = chunk * j->chunk_size, hi = lo + j->chunk_size;
        if (hi > j->count) hi = j->count;
        for (int64_t k = lo; k < hi; ++k) {
            const sc_footprint *f = &j->fp[k];
            int64_t pairs = 0;
            for (int ty = f->ty0; ty < f->ty1; ++ty) {
                int32_t t0, t1;
                row_tiles(f, &j->splats[k], ty, j->cam, &t0, &t1);
                for (int tx = t0; tx < t1; ++tx) counts[(int64_t)ty * j->tiles_x + tx]++;
                pairs += t1 - t0;
            }
            if (inverse) j->pair_offsets[k] = pairs;
        }
    }
}

static inline void scatter_pass(job *j, int64_t begin, int64_t end, const int inverse) {
    for (int64_t chunk = begin; chunk < end; ++chunk) {
        int64_t *cursor = j->cursors + chunk * j->ntiles;
        int64_t lo = chunk * j->chunk_size, hi = lo + j->chunk_size;
        if (hi > j->count) hi = j->count;
        for (int64_t k = lo; k < hi; ++k) {
            const sc_footprint *f = &j->fp[k];
            uint32_t *mine = inverse ? j->pairs + j->pair_offsets[k] : NULL;
            for (int ty = f->ty0; ty < f->ty1; ++ty) {
                int32_t t0, t1;
                row_tiles(f, &j->splats[k], ty, j->cam, &t0, &t1);
                for (int tx = t0; tx < t1; ++tx) {
                    const int64_t at = cursor[(int64_t)ty * j->tiles_x + tx]++;
                    j->list[at] = (uint32_t)k;
                    if (inverse) *mine++ = (uint32_t)at;
                }
            }
        }
    }
}

static void count_chunk(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    count_pass(ctx, begin, end, 0);
}

static void count_chunk_inverse(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    count_pass(ctx, begin, end, 1);
}

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

sc_status sc_bin(const sc_footprint *fp, const sc_splat *splats, int64_t count,
                 const sc_camera *cam, int threads, int64_t **offsets_out, uint32_t **list_out,
                 int64_t **pair_offsets_out, uint32_t **pairs_out) {
    job j = {.fp = fp, .splats = splats, .cam = cam, .count = count};
    const int inverse = pair_offsets_out != NULL;
    j.tiles_x = (cam->width + SC_TILE - 1) / SC_TILE;
    const int tiles_y = (cam->height + SC_TILE - 1) / SC_TILE;
    j.ntiles = (int64_t)j.tiles_x * tiles_y;
    /* A few chunks per thread balance the load; the result does not depend on the split. */
    int64_t chunks = (int64_t)threads * 4;
    if (chunks > (count + 1023) / 1024) chunks = (count + 1023) / 1024;
    if (chunks < 1) chunks = 1;
    j.chunk_size = (count + chunks - 1) / chunks;
    if (j.chunk_size < 1) j.chunk_size = 1;

    int64_t *offsets = malloc(sizeof(int64_t) * (size_t)(j.ntiles + 1));
    j.counts = calloc((size_t)(chunks * j.ntiles), sizeof(uint32_t));
    j.cursors = malloc(sizeof(int64_t) * (size_t)(chunks * j.ntiles));
    if (inverse) j.pair_offsets = malloc(sizeof(int64_t) * (size_t)(count + 1));
    if (!offsets || !j.counts || !j.cursors || (inverse && !j.pair_offsets)) goto out_of_memory;

    sc_parallel_for(threads, chunks, 1, inverse ? count_chunk_inverse : count_chunk, &j);
    int64_t total = 0;
    for (int64_t t = 0; t < j.ntiles; ++t) {
        offsets[t] = total;
        for (int64_t c = 0; c < chunks; ++c) {
            j.cursors[c * j.ntiles + t] = total;
            total += j.counts[c * j.ntiles + t];
        }
    }
    offsets[j.ntiles] = total;
    free(j.counts);
    j.counts = NULL;
    if (total > MAX_PAIRS) {
        free(offsets);
        free(j.cursors);
        free(j.pair_offsets);
        return SC_ERR_TOO_LARGE;
    }
    if (inverse) { /* per-Gaussian counts -> offsets; they add up to `total` */
        int64_t sum = 0;
        for (int64_t k = 0; k < count; ++k) {
            const int64_t c = j.pair_offsets[k];
            j.pair_offsets[k] = sum;
            sum += c;
        }
        j.pair_offsets[count] = sum;
        j.pairs = malloc(sizeof(uint32_t) * (size_t)(total ? total : 1));
        if (!j.pairs) goto out_of_memory;
    }
    j.list = malloc(sizeof(uint32_t) * (size_t)(total ? total : 1));
    if (!j.list) goto out_of_memory;
    sc_parallel_for(threads, chunks, 1, inverse ? scatter_chunk_inverse : scatter_chunk, &j);
    free(j.cursors);
    *offsets_out = offsets;
    *list_out = j.list;
    if (inverse) {
        *pair_offsets_out = j.pair_offsets;
        *pairs_out = j.pairs;
    }
    return SC_OK;

out_of_memory:
    free(offsets);
    free(j.counts);
    free(j.cursors);
    free(j.pair_offsets);
    free(j.pairs);
    return SC_ERR_MEMORY;
}
