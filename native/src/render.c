/* The forward pipeline: project -> sort by depth -> bin into tiles -> composite each tile.
 * Working memory is O(Gaussians + tile pairs + tiles): at most 132 bytes per Gaussian (the
 * projected and the depth-sorted splats side by side during the gather), 4 per Gaussian/tile
 * pair (12 more for training's pair index) and 4 per tile and binning chunk (at most 32 MiB of
 * these beyond one chunk per thread: binning.c); nothing is kept
 * per pixel beyond the caller's images. The front half (project, sort, bin) is shared with the training forward
 * (train.c), which keeps it for the backward pass. */
#include <math.h>
#include <stdlib.h>

#include "internal.h"

enum { MAX_THREADS = 256, PAD = 8 }; /* PAD: one counter per cache line */

/* Copies the drawn Gaussians into depth order, so that binning and compositing read them
 * sequentially (and a tile's list touches memory in ascending order). */
typedef struct {
    const sc_splat *projected;
    const uint32_t *order;
    sc_splat *splats;
} gather_job;

static void gather_sorted(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    gather_job *j = ctx;
    enum { AHEAD = 16 }; /* scattered reads: fetch a few records ahead */
    for (int64_t k = begin; k < end; ++k) {
        if (k + AHEAD < end) SC_PREFETCH(&j->projected[j->order[k + AHEAD]]);
        j->splats[k] = j->projected[j->order[k]];
    }
}

void sc_frame_free(sc_frame *f) {
    sc_buffer_free(f->splats);
    sc_buffer_free(f->order);
    sc_buffer_free(f->offsets);
    sc_buffer_free(f->list);
    sc_buffer_free(f->pair_offsets);
    sc_buffer_free(f->pairs);
    *f = (sc_frame){0};
}

/* Working memory: each buffer is freed as soon as the next stage no longer needs it, and the
 * largest moment is counted in stats->peak_bytes (besides what sc_bin allocates, counted there). */
sc_status sc_frame_prepare(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                           int with_pairs, sc_frame *frame, sc_stats *stats) {
    const double start = sc_now_ms(), pool_start = sc_pool_inside_ms();
    const int wrap = sc_wraps(cam); /* twice the rows: each Gaussian's seam copy */
    *frame = (sc_frame){0};
    if (wrap && g->count > (1LL << 30)) return SC_ERR_TOO_LARGE;
    const int64_t n = wrap ? 2 * g->count : g->count;
    const size_t rows = (size_t)(n ? n : 1);
    sc_status status = SC_ERR_MEMORY;
    float *keys = NULL;
    *frame = (sc_frame){0};
    frame->tiles_x = (cam->width + SC_TILE - 1) / SC_TILE;
    frame->ntiles = (int64_t)frame->tiles_x * ((cam->height + SC_TILE - 1) / SC_TILE);
    sc_projection proj = {sc_buffer_alloc(sizeof(sc_splat) * rows), sc_buffer_alloc(rows),
                          sc_buffer_alloc(sizeof(float) * rows), wrap};
    keys = proj.keys;
    if (!proj.splats || !proj.valid || !keys) goto done;
    if ((status = sc_project_fast(g, cam, opt, 1, &proj, stats)) != SC_OK) goto done;
    sc_buffer_free(proj.valid);
    proj.valid = NULL;
    const double projected = sc_now_ms(), pool_projected = sc_pool_inside_ms();

    /* Only Gaussians that reach a pixel take part (the projection keyed the others +inf, which
     * sort last), front to back. */
    status = SC_ERR_MEMORY;
    frame->order = sc_buffer_alloc(sizeof(uint32_t) * rows);
    if (!frame->order) goto done;
    int64_t sort_bytes;
    const int64_t drawn = sc_sort_by_depth(keys, n, NULL, opt->threads, frame->order, &sort_bytes);
    if (drawn < 0) goto done;
    int64_t peak = (int64_t)((sizeof(sc_splat) + sizeof(uint32_t) + sizeof(float)) * rows) +
                   sort_bytes;
    sc_buffer_free(keys);
    keys = NULL;
    frame->splats = sc_buffer_alloc(sizeof(sc_splat) * (size_t)(drawn ? drawn : 1));
    if (!frame->splats) goto done;
    gather_job gather = {proj.splats, frame->order, frame->splats};
    /* (A 64-byte record: 16 values.) */
    sc_parallel_for(opt->threads, drawn, sc_grain(drawn, 16, opt->threads), gather_sorted, &gather);
    const int64_t gathered = (int64_t)(sizeof(sc_splat) * (rows + (size_t)drawn) +
                                       sizeof(uint32_t) * rows);
    peak = gathered > peak ? gathered : peak;
    sc_buffer_free(proj.splats);
    proj.splats = NULL;
    frame->drawn = drawn;
    const double sorted_ms = sc_now_ms(), pool_sorted = sc_pool_inside_ms();

    int64_t bin_bytes = 0;
    if ((status = sc_bin(frame->splats, drawn, cam, opt->threads, &frame->offsets, &frame->list,
                         with_pairs ? &frame->pair_offsets : NULL,
                         with_pairs ? &frame->pairs : NULL, &bin_bytes)) != SC_OK)
        goto done;
    bin_bytes += (int64_t)((sizeof(sc_splat) + sizeof(uint32_t)) * (size_t)drawn);
    stats->peak_bytes = bin_bytes > peak ? bin_bytes : peak;
    stats->ms_project = projected - start;
    stats->ms_sort = sorted_ms - projected;
    stats->ms_bin = sc_now_ms() - sorted_ms;
    stats->ms_pool_project = pool_projected - pool_start;
    stats->ms_pool_sort = pool_sorted - pool_projected;
    stats->ms_pool_bin = sc_pool_inside_ms() - pool_sorted;
    stats->visible = drawn;
    stats->tile_pairs = frame->offsets[frame->ntiles];
    status = SC_OK;

done:
    sc_buffer_free(proj.splats);
    sc_buffer_free(proj.valid);
    sc_buffer_free(keys);
    if (status != SC_OK) sc_frame_free(frame);
    return status;
}

typedef struct {
    const sc_frame *frame;
    const sc_camera *cam;
    const sc_image *image;
    float *final_t;      /* the training forward's: what its backward needs (else NULL) */
    int32_t *n_contrib;
    int exhaustive;
    int64_t evaluations[MAX_THREADS * PAD];
} composite_job;

static void composite_tiles(void *ctx, int64_t begin, int64_t end, int thread) {
    composite_job *j = ctx;
    const sc_frame *f = j->frame;
    for (int64_t t = begin; t < end; ++t) {
        const int64_t first = f->offsets[t], count = f->offsets[t + 1] - first;
        const int tx = (int)(t % f->tiles_x), ty = (int)(t / f->tiles_x);
        j->evaluations[thread * PAD] +=
            j->final_t ? sc_composite_tile_train(f->splats, f->list + first, count, tx, ty, j->cam,
                                                 j->image, j->final_t, j->n_contrib, j->exhaustive)
                       : sc_composite_tile(f->splats, f->list + first, count, tx, ty, j->cam,
                                           j->image, j->exhaustive);
    }
}

int64_t sc_composite_frame(const sc_frame *frame, const sc_camera *cam, const sc_image *image,
                           float *final_t, int32_t *n_contrib, int exhaustive, int threads) {
    composite_job job = {.frame = frame, .cam = cam, .image = image, .final_t = final_t,
                         .n_contrib = n_contrib, .exhaustive = exhaustive};
    sc_parallel_for(threads, frame->ntiles, 1, composite_tiles, &job);
    int64_t evaluations = 0;
    for (int t = 0; t < MAX_THREADS; ++t) evaluations += job.evaluations[t * PAD];
    return evaluations;
}

sc_status sc_render(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                    const sc_image *image, sc_stats *stats) {
    const double start = sc_now_ms();
    sc_frame frame;
    sc_status status = sc_frame_prepare(g, cam, opt, 0, &frame, stats);
    if (status != SC_OK) return status;
    const double binned = sc_now_ms(), pool_binned = sc_pool_inside_ms();

    stats->evaluations = sc_composite_frame(&frame, cam, image, NULL, NULL, opt->exhaustive,
                                            opt->threads < MAX_THREADS ? opt->threads : MAX_THREADS);
    const double composited = sc_now_ms();

    stats->ms_composite = composited - binned;
    stats->ms_pool_composite = sc_pool_inside_ms() - pool_binned;
    stats->ms_total = composited - start;
    sc_frame_free(&frame);
    return SC_OK;
}
