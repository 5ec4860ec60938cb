/* The forward pipeline: project -> sort by depth -> bin into tiles -> composite each tile.
 * Working memory is O(Gaussians + tile pairs + tiles); nothing is kept per pixel beyond the
 * caller's images. */
#include <math.h>
#include <stdlib.h>

#include "splatcore.h"

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

typedef struct {
    const sc_splat *splats;
    const int64_t *offsets;
    const uint32_t *list;
    const sc_camera *cam;
    const sc_image *image;
    int tiles_x;
    int64_t evaluations[MAX_THREADS * PAD];
} composite_job;

static void composite_tiles(void *ctx, int64_t begin, int64_t end, int thread) {
    composite_job *j = ctx;
    for (int64_t t = begin; t < end; ++t) {
        const int64_t first = j->offsets[t], count = j->offsets[t + 1] - first;
        j->evaluations[thread * PAD] +=
            sc_composite_tile(j->splats, j->list + first, count, (int)(t % j->tiles_x),
                              (int)(t / j->tiles_x), j->cam, j->image);
    }
}

sc_status sc_render(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                    const sc_image *image, sc_stats *stats) {
    const double start = sc_now_ms();
    const int64_t n = g->count;
    sc_status status = SC_ERR_MEMORY;
    int64_t *offsets = NULL;
    uint32_t *list = NULL, *order = NULL, *scratch = NULL;
    float *keys = NULL;
    sc_splat *sorted = NULL;
    sc_footprint *sorted_fp = NULL;
    sc_projection proj = {malloc(sizeof(sc_splat) * (size_t)(n ? n : 1)),
                          malloc(sizeof(sc_footprint) * (size_t)(n ? n : 1)),
                          malloc((size_t)(n ? n : 1))};
    if (!proj.splats || !proj.footprints || !proj.valid) goto done;
    if ((status = sc_project(g, cam, opt, &proj, stats)) != SC_OK) goto done;
    const double projected = sc_now_ms();

    /* Only Gaussians that reach a pixel take part, sorted front to back. */
    status = SC_ERR_MEMORY;
    order = malloc(sizeof(uint32_t) * (size_t)(n ? n : 1));
    keys = malloc(sizeof(float) * (size_t)(n ? n : 1));
    if (!order || !keys) goto done;
    int64_t drawn = 0;
    for (int64_t i = 0; i < n; ++i) {
        const sc_footprint *f = &proj.footprints[i];
        if (f->tx1 > f->tx0 && f->ty1 > f->ty0) {
            order[drawn] = (uint32_t)i;
            keys[drawn++] = proj.splats[i].depth;
        }
    }
    scratch = malloc(sizeof(uint32_t) * (size_t)(3 * drawn + 1));
    if (!scratch) goto done;
    sc_sort_by_depth(keys, drawn, order, scratch);
    sorted = malloc(sizeof(sc_splat) * (size_t)(drawn ? drawn : 1));
    sorted_fp = malloc(sizeof(sc_footprint) * (size_t)(drawn ? drawn : 1));
    if (!sorted || !sorted_fp) goto done;
    gather_job gather = {&proj, order, sorted, sorted_fp};
    sc_parallel_for(opt->threads, drawn, 8192, gather_sorted, &gather);
    const double sorted_ms = sc_now_ms();

    if ((status = sc_bin(sorted_fp, sorted, drawn, cam, opt->threads, &offsets, &list)) != SC_OK)
        goto done;
    const double binned = sc_now_ms();

    composite_job job = {.splats = sorted, .offsets = offsets, .list = list, .cam = cam,
                         .image = image, .tiles_x = (cam->width + SC_TILE - 1) / SC_TILE};
    const int64_t ntiles = (int64_t)job.tiles_x * ((cam->height + SC_TILE - 1) / SC_TILE);
    sc_parallel_for(opt->threads < MAX_THREADS ? opt->threads : MAX_THREADS, ntiles, 1,
                    composite_tiles, &job);
    const double composited = sc_now_ms();

    stats->ms_project = projected - start;
    stats->ms_sort = sorted_ms - projected;
    stats->ms_bin = binned - sorted_ms;
    stats->ms_composite = composited - binned;
    stats->ms_total = composited - start;
    stats->visible = drawn;
    stats->tile_pairs = offsets[ntiles];
    stats->evaluations = 0;
    for (int t = 0; t < MAX_THREADS; ++t) stats->evaluations += job.evaluations[t * PAD];
    status = SC_OK;

done:
    free(proj.splats);
    free(proj.footprints);
    free(proj.valid);
    free(order);
    free(keys);
    free(scratch);
    free(sorted);
    free(sorted_fp);
    free(offsets);
    free(list);
    return status;
}
