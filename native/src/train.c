/* Training: the forward that keeps what the backward needs, and the backward pipeline.
 *
 * Forward: sc_frame_prepare (project, sort, bin with the Gaussian-major pair index) and the
 * training compositor per tile; the state keeps the frame and, per pixel, the final
 * transmittance, n_contrib and the expected depth.
 *
 * Backward, deterministic for any thread count:
 *  1. per tile (in parallel), back to front: a gradient record per tile-list entry, written at
 *     that entry's position (sc_composite_tile_backward); no two tiles share memory;
 *  2. per drawn Gaussian, in depth order (in parallel): its records summed in double in a
 *     fixed order (its pairs in tile order, from the pair index), stored at its input index;
 *  3. per Gaussian, in input order (in parallel): the projection backward
 *     (sc_project_backward_gaussian) into its rows of the outputs, or zeros if not drawn.
 * Memory, for the duration of the call: SC_DG_COUNT floats per tile pair, ~110 bytes per
 * Gaussian. */
#include <math.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

enum { MAX_THREADS = 256, PAD = 8, GATHER_AHEAD = 16 };

void sc_train_state_free(sc_train_state *state) {
    sc_frame_free(&state->frame);
    free(state->final_t);
    free(state->n_contrib);
    free(state->depth);
    state->final_t = NULL, state->n_contrib = NULL, state->depth = NULL;
}

static int clamp_threads(int threads) {
    return threads < 1 ? 1 : threads > MAX_THREADS ? MAX_THREADS : threads;
}

sc_status sc_render_train(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                          const sc_image *image, sc_train_state *state, sc_stats *stats) {
    const double start = sc_now_ms();
    memset(state, 0, sizeof *state);
    state->camera = *cam;
    state->options = *opt;
    state->count = g->count;
    state->sh_coeffs = g->sh_coeffs;
    if (image->background) {
        state->has_background = 1;
        memcpy(state->background, image->background, sizeof state->background);
    }
    const size_t pixels = (size_t)cam->width * (size_t)cam->height;
    state->final_t = malloc(sizeof(float) * pixels);
    state->n_contrib = malloc(sizeof(int32_t) * pixels);
    state->depth = malloc(sizeof(float) * pixels);
    if (!state->final_t || !state->n_contrib || !state->depth) return SC_ERR_MEMORY;
    sc_status status = sc_frame_prepare(g, cam, opt, 1, &state->frame, stats);
    if (status != SC_OK) return status;
    const double binned = sc_now_ms(), pool_binned = sc_pool_inside_ms();

    stats->evaluations = sc_composite_frame(&state->frame, cam, image, state->final_t,
                                            state->n_contrib, opt->exhaustive,
                                            clamp_threads(opt->threads));
    memcpy(state->depth, image->depth, sizeof(float) * pixels);
    const double composited = sc_now_ms();
    stats->ms_composite = composited - binned;
    stats->ms_pool_composite = sc_pool_inside_ms() - pool_binned;
    stats->ms_total = composited - start;
    return SC_OK;
}

/* ---------------------------------------------------------------- backward */

/* A drawn Gaussian's summed gradient and its projection, gathered into input order. */
typedef struct {
    float d[SC_DG_COUNT];
    sc_splat splat;
} gathered;

typedef struct {
    const sc_train_state *state;
    const sc_gaussians *g;
    const sc_image_grads *grads;
    sc_gaussian_grads *out;
    float *records;     /* (pairs, SC_DG_COUNT), tile-list order */
    gathered *by_input; /* (N) valid where drawn[i] */
    uint8_t *drawn;     /* (N) */
    double campos[3];
    atomic_llong first_bad; /* smallest Gaussian index with a problem, or count */
    int64_t evaluations[MAX_THREADS * PAD];
    int64_t flushed[MAX_THREADS * PAD];
} backward_job;

static void backward_tiles(void *ctx, int64_t begin, int64_t end, int thread) {
    backward_job *j = ctx;
    const sc_frame *f = &j->state->frame;
    for (int64_t t = begin; t < end; ++t) {
        const int64_t first = f->offsets[t], count = f->offsets[t + 1] - first;
        j->evaluations[thread * PAD] += sc_composite_tile_backward(
            f->splats, f->list + first, count, (int)(t % f->tiles_x), (int)(t / f->tiles_x),
            &j->state->camera, j->grads, j->records + first * SC_DG_COUNT,
            j->state->options.exhaustive);
    }
}

/* Phase A, depth order: the pair index and the splats are read sequentially and the record
 * loads are independent of each other, so cache misses overlap. Sums in double, in the fixed
 * order of the pair index (tile order). */
static void gather_gradients(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    backward_job *j = ctx;
    const sc_frame *f = &j->state->frame;
    const int64_t last_pair = f->pair_offsets[end];
    for (int64_t k = begin; k < end; ++k) {
        double d[SC_DG_COUNT] = {0};
        for (int64_t p = f->pair_offsets[k]; p < f->pair_offsets[k + 1]; ++p) {
            if (p + GATHER_AHEAD < last_pair) { /* the records lie apart: fetch ahead */
                const float *ahead = j->records + (int64_t)f->pairs[p + GATHER_AHEAD] * SC_DG_COUNT;
                SC_PREFETCH(ahead);
                SC_PREFETCH(ahead + SC_DG_COUNT - 1);
            }
            const float *rec = j->records + (int64_t)f->pairs[p] * SC_DG_COUNT;
            for (int q = 0; q < SC_DG_COUNT; ++q) d[q] += rec[q];
        }
        const int64_t i = f->order[k];
        gathered *out = &j->by_input[i];
        for (int q = 0; q < SC_DG_COUNT; ++q) out->d[q] = (float)d[q];
        out->splat = f->splats[k];
        j->drawn[i] = 1;
    }
}

/* Zero the gradient rows of Gaussians [begin, end) (not drawn). */
static void zero_rows(const backward_job *j, int64_t begin, int64_t end) {
    const int64_t n = end - begin, k3 = 3 * (int64_t)j->g->sh_coeffs;
    sc_gaussian_grads *o = j->out;
    memset(o->means + 3 * begin, 0, sizeof(float) * (size_t)(3 * n));
    memset(o->log_scales + 3 * begin, 0, sizeof(float) * (size_t)(3 * n));
    memset(o->quats + 4 * begin, 0, sizeof(float) * (size_t)(4 * n));
    memset(o->opacity_logits + begin, 0, sizeof(float) * (size_t)n);
    memset(o->sh + k3 * begin, 0, sizeof(float) * (size_t)(k3 * n));
    memset(o->xy + 2 * begin, 0, sizeof(float) * (size_t)(2 * n));
    memset(o->xy_abs + 2 * begin, 0, sizeof(float) * (size_t)(2 * n));
}

static void note_bad(backward_job *j, int64_t i) {
    long long seen = atomic_load(&j->first_bad);
    while (i < seen && !atomic_compare_exchange_weak(&j->first_bad, &seen, i)) {
    }
}

static int row_finite(const float *v, int64_t n) {
    for (int64_t i = 0; i < n; ++i)
        if (!isfinite(v[i])) return 0;
    return 1;
}

/* Drawn Gaussians index[0 .. n) through the projection backward, SC_BW_LANES at a time (or
 * one by one, the slow twin, when the state was rendered `exhaustive`). */
static void project_back(backward_job *j, const int64_t *index, int n, int thread) {
    int64_t *flushed = &j->flushed[thread * PAD];
    if (j->state->options.exhaustive) {
        for (int l = 0; l < n; ++l) {
            const gathered *gi = &j->by_input[index[l]];
            double d[SC_DG_COUNT];
            for (int q = 0; q < SC_DG_COUNT; ++q) d[q] = gi->d[q];
            if (sc_project_backward_gaussian(j->g, &j->state->camera, &j->state->options,
                                             j->campos, index[l], &gi->splat, d, j->out,
                                             flushed) != 0)
                note_bad(j, index[l]);
        }
        return;
    }
    const sc_splat *splats[SC_BW_LANES];
    const float *d[SC_BW_LANES];
    int results[SC_BW_LANES];
    for (int l = 0; l < n; ++l) {
        splats[l] = &j->by_input[index[l]].splat;
        d[l] = j->by_input[index[l]].d;
    }
    if (sc_project_backward_lanes(j->g, &j->state->camera, &j->state->options, j->campos, n,
                                  index, splats, d, j->out, flushed, results))
        for (int l = 0; l < n; ++l)
            if (results[l] != 0) note_bad(j, index[l]);
}

/* Phase B, input order: parameters and gradients are read and written sequentially. */
static void backward_gaussians(void *ctx, int64_t begin, int64_t end, int thread) {
    backward_job *j = ctx;
    int64_t batch[SC_BW_LANES];
    int n = 0;
    for (int64_t i = begin; i < end; ++i) {
        if (!j->drawn[i]) {
            int64_t run = i + 1; /* zero a whole run of undrawn Gaussians at once */
            while (run < end && !j->drawn[run]) ++run;
            zero_rows(j, i, run);
            i = run - 1;
            continue;
        }
        batch[n++] = i;
        if (n == SC_BW_LANES) {
            project_back(j, batch, n, thread);
            n = 0;
        }
    }
    if (n) project_back(j, batch, n, thread);
}

sc_status sc_backward(const sc_train_state *state, const sc_gaussians *g, const float *d_rgb,
                      const float *d_alpha, const float *d_depth, int threads,
                      sc_gaussian_grads *out, sc_backward_stats *stats) {
    const double start = sc_now_ms(), pool_start = sc_pool_inside_ms();
    const sc_frame *f = &state->frame;
    threads = clamp_threads(threads);
    memset(stats, 0, sizeof *stats);
    const int64_t pairs = f->offsets[f->ntiles];
    const size_t n = (size_t)(g->count ? g->count : 1);
    float *records = malloc(sizeof(float) * (size_t)(pairs ? pairs : 1) * SC_DG_COUNT);
    gathered *by_input = malloc(sizeof(gathered) * n);
    uint8_t *drawn = calloc(n, 1);
    backward_job *j = calloc(1, sizeof *j);
    if (!records || !by_input || !drawn || !j) {
        free(records);
        free(by_input);
        free(drawn);
        free(j);
        return SC_ERR_MEMORY;
    }
    j->by_input = by_input, j->drawn = drawn;
    const sc_image_grads grads = {.d_rgb = d_rgb, .d_alpha = d_alpha, .d_depth = d_depth,
                                  .final_t = state->final_t, .n_contrib = state->n_contrib,
                                  .depth = state->depth,
                                  .background = state->has_background ? state->background : NULL};
    j->state = state, j->g = g, j->grads = &grads, j->out = out, j->records = records;
    atomic_init(&j->first_bad, g->count);
    sc_camera_centre(state->camera.world_to_camera, j->campos);

    sc_parallel_for(threads, f->ntiles, 1, backward_tiles, j);
    const double composited = sc_now_ms(), pool_composited = sc_pool_inside_ms();
    sc_parallel_for(threads, f->drawn, sc_grain(f->drawn, 16, threads), gather_gradients, j);
    sc_parallel_for(threads, g->count, 1024, backward_gaussians, j);
    const double done = sc_now_ms();
    stats->ms_pool_composite = pool_composited - pool_start;
    stats->ms_pool_project = sc_pool_inside_ms() - pool_composited;

    stats->ms_composite = composited - start;
    stats->ms_project = done - composited;
    stats->ms_total = done - start;
    for (int t = 0; t < MAX_THREADS; ++t) {
        stats->evaluations += j->evaluations[t * PAD];
        stats->flushed += j->flushed[t * PAD];
    }
    const long long bad = atomic_load(&j->first_bad);
    free(records);
    free(by_input);
    free(drawn);
    free(j);
    if (bad < g->count) {
        stats->error_index = bad;
        const int finite = row_finite(g->means + 3 * bad, 3) &&
                           row_finite(g->log_scales + 3 * bad, 3) &&
                           row_finite(g->quats + 4 * bad, 4) &&
                           row_finite(g->opacity_logits + bad, 1) &&
                           row_finite(g->sh + 3 * (int64_t)g->sh_coeffs * bad, 3 * g->sh_coeffs);
        return finite ? SC_ERR_STALE : SC_ERR_NONFINITE;
    }
    return SC_OK;
}
