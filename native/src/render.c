/* The forward pipeline: project -> sort by depth -> bin into tiles -> composite each tile.
 * Working memory is O(Gaussians + tile pairs + tiles); nothing is kept per pixel beyond the
 * caller's images. The front half (project, sort, bin) is shared with the training forward
 * (train.c), which keeps it for the backward pass. */
#include <math.h>
#include <stdlib.h>

#include "internal.h"

enum { MAX_THREADS = 256, PAD = 8 }; /* PAD: one counter per cache line */

/* Copies the drawn Gaussians into depth order, so that binning and compositing read them
 * sequentially (and a tile's list touches memory in ascending order). */
typedef struct {
    const sc_projection *proj;
    const uint32_t *order;
    sc_splat *splats;
    sc_footprint *footprints;
} gather_job;

static void gather_sorted(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    gather_job *j = ctx;
    for (int64_t k = begin; k < end; ++k) {
        j->splats[k] = j->proj->splats[j->order[k]];
        j->footprints[k] = j->proj->footprints[j->order[k]];
    }
}

void sc_frame_free(sc_frame *f) {
    free(f->splats);
    free(f->order);
    free(f->offsets);
    free(f->list);
    free(f->pair_offsets);
    free(f->pairs);
    *f = (sc_frame){0};
}

sc_status sc_frame_prepare(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                           int with_pairs, sc_frame *frame, sc_stats *stats) {
    const double start = sc_now_ms();
    const int64_t n = g->count;
    sc_status status = SC_ERR_MEMORY;
    uint32_t *scratch = NULL;
    float *keys = NULL;
    sc_footprint *sorted_fp = NULL;
    *frame = (sc_frame){0};
    frame->tiles_x = (cam->width + SC_TILE - 1) / SC_TILE;
    frame->ntiles = (int64_t)frame->tiles_x * ((cam->height + SC_TILE - 1) / SC_TILE);
    sc_projection proj = {malloc(sizeof(sc_splat) * (size_t)(n ? n : 1)),
                          malloc(sizeof(sc_footprint) * (size_t)(n ? n : 1)),
                          malloc((size_t)(n ? n : 1))};
    if (!proj.splats || !proj.footprints || !proj.valid) goto done;
    if ((status = sc_project(g, cam, opt, &proj, stats)) != SC_OK) goto done;
    const double projected = sc_now_ms();

    /* Only Gaussians that reach a pixel take part, sorted front to back. */
    status = SC_ERR_MEMORY;
    frame->order = malloc(sizeof(uint32_t) * (size_t)(n ? n : 1));
    keys = malloc(sizeof(float) * (size_t)(n ? n : 1));
    if (!frame->order || !keys) goto done;
    int64_t drawn = 0;
    for (int64_t i = 0; i < n; ++i) {
        const sc_footprint *f = &proj.footprints[i];
        if (f->tx1 > f->tx0 && f->ty1 > f->ty0) {
            frame->order[drawn] = (uint32_t)i;
            keys[drawn++] = proj.splats[i].depth;
        }
    }
    scratch = malloc(sizeof(uint32_t) * (size_t)(3 * drawn + 1));
    if (!scratch) goto done;
    sc_sort_by_depth(keys, drawn, frame->order, scratch);
    frame->splats = malloc(sizeof(sc_splat) * (size_t)(drawn ? drawn : 1));
    sorted_fp = malloc(sizeof(sc_footprint) * (size_t)(drawn ? drawn : 1));
    if (!frame->splats || !sorted_fp) goto done;
    gather_job gather = {&proj, frame->order, frame->splats, sorted_fp};
    sc_parallel_for(opt->threads, drawn, 8192, gather_sorted, &gather);
    frame->drawn = drawn;
    const double sorted_ms = sc_now_ms();

    if ((status = sc_bin(sorted_fp, frame->splats, drawn, cam, opt->threads, &frame->offsets,
                         &frame->list, with_pairs ? &frame->pair_offsets : NULL,
                         with_pairs ? &frame->pairs : NULL)) != SC_OK)
        goto done;
    stats->ms_project = projected - start;
    stats->ms_sort = sorted_ms - projected;
    stats->ms_bin = sc_now_ms() - sorted_ms;
    stats->visible = drawn;
    stats->tile_pairs = frame->offsets[frame->ntiles];
    status = SC_OK;

done:
    free(proj.splats);
    free(proj.footprints);
    free(proj.valid);
    free(keys);
    free(scratch);
    free(sorted_fp);
    if (status != SC_OK) sc_frame_free(frame);
    return status;
}

typedef struct {
    const sc_frame *frame;
    const sc_camera *cam;
    const sc_image *image;
    int64_t evaluations[MAX_THREADS * PAD];
} composite_job;

static void composite_tiles(void *ctx, int64_t begin, int64_t end, int thread) {
    composite_job *j = ctx;
    const sc_frame *f = j->frame;
    for (int64_t t = begin; t < end; ++t) {
        const int64_t first = f->offsets[t], count = f->offsets[t + 1] - first;
        j->evaluations[thread * PAD] +=
            sc_composite_tile(f->splats, f->list + first, count, (int)(t % f->tiles_x),
                              (int)(t / f->tiles_x), j->cam, j->image);
    }
}

sc_status sc_render(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                    const sc_image *image, sc_stats *stats) {
    const double start = sc_now_ms();
    sc_frame frame;
    sc_status status = sc_frame_prepare(g, cam, opt, 0, &frame, stats);
    if (status != SC_OK) return status;
    const double binned = sc_now_ms();

    composite_job job = {.frame = &frame, .cam = cam, .image = image};
    sc_parallel_for(opt->threads < MAX_THREADS ? opt->threads : MAX_THREADS, frame.ntiles, 1,
                    composite_tiles, &job);
    const double composited = sc_now_ms();

    stats->ms_composite = composited - binned;
    stats->ms_total = composited - start;
    stats->evaluations = 0;
    for (int t = 0; t < MAX_THREADS; ++t) stats->evaluations += job.evaluations[t * PAD];
    sc_frame_free(&frame);
    return SC_OK;
}
