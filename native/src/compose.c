/* F12's composite in display sRGB, tile by tile (sc_compose_prepare and sc_compose_srgb,
 * splatcore.h).
 *
 * The same pixels as converting the whole mesh layer to display sRGB, rendering over it and
 * converting the changed pixels back (composite.py did that in three frame-wide passes), but in
 * one pass over the tiles after binning: a tile no Gaussian reaches is the mesh render itself
 * (there the old passes changed nothing: the composite over T = 1 is the layer, bit for bit,
 * and the way back copied the mesh's own pixel), so it is copied and nothing converted; a tile
 * with Gaussians is converted, composited (sc_composite_tile) and converted back on its own,
 * while it is in cache. An F12 of a small object leaves most tiles empty: the colour work and
 * the compositor's per-pixel set-up and write-out follow the splats, not the frame. The empty
 * tiles are copied first, row by row (copy_empty_rows), then the others are composed. */
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

enum { MAX_THREADS = 256, PAD = 8 }; /* PAD: one counter per cache line */

typedef struct {
    const sc_frame *frame;
    const sc_camera *cam;
    sc_rgba_view mesh, out;
    sc_plane_view depth_in;
    float *clean_depth, *out_depth, far;
    int want_depth; /* out_depth is the caller's (else scratch: only tiles with Gaussians) */
    sc_image image; /* the display layer, clean depth and scratch rgb/alpha: full-frame */
    const sc_srgb_tiles *colour;
    int exhaustive;
    int64_t evaluations[MAX_THREADS * PAD];
    double colour_ms[MAX_THREADS * PAD];
} compose_job;

/* What compose.py's _finite_depth made of the mesh depth: NaN and +inf far, -inf 0. */
static inline float clean(float z, float far) {
    return isnan(z) ? far : isinf(z) ? (z > 0 ? far : 0.0f) : z;
}

static inline float depth_at(const sc_plane_view *v, int64_t y, int64_t x) {
    float z;
    memcpy(&z, v->data + y * v->row + x * v->pixel, sizeof z);
    return z;
}

/* Pixels no Gaussian reaches: the mesh pixel as it is, and the depth the compositor gives a
 * lone mesh pixel (its depth weighted by its alpha, over that alpha: z itself at alpha 1; the
 * alpha the compositor sees is the display layer's, non-finite as 0). Locals throughout: stores
 * through char pointers could alias the job. */
static void copy_mesh(const compose_job *j, int x0, int y0, int w, int h) {
    const sc_rgba_view m = j->mesh, o = j->out;
    const sc_plane_view dv = j->depth_in;
    const float far = j->far;
    const int64_t width = j->cam->width;
    for (int y = y0; y < y0 + h; ++y) {
        const char *from = m.data + y * m.row + x0 * m.pixel;
        const char *zs = dv.data + y * dv.row + x0 * dv.pixel;
        char *to = (char *)o.data + y * o.row + x0 * o.pixel;
        float *depth = j->want_depth ? j->out_depth + y * width + x0 : NULL;
        for (int i = 0; i < w; ++i, from += m.pixel, to += o.pixel, zs += dv.pixel) {
            float v[4], z;
            for (int c = 0; c < 4; ++c) memcpy(&v[c], from + c * m.channel, sizeof v[c]);
            for (int c = 0; c < 4; ++c) memcpy(to + c * o.channel, &v[c], sizeof v[c]);
            if (!depth) continue;
            memcpy(&z, zs, sizeof z);
            z = clean(z, far);
            const float a = v[3];
            const float d = a == 1.0f ? z : a > 0.0f && a <= FLT_MAX ? (a * z) / a : INFINITY;
            depth[i] = isfinite(d) ? d : far;
        }
    }
}

/* The tiles no Gaussian reaches, a row of pixels at a time: each run of them along a row is
 * copied in one go, so the mesh's planar rows (an EXR's) are read in order, not 16 pixels of
 * each per tile (which a prefetcher cannot follow: about three times slower). */
static void copy_empty_rows(void *ctx, int64_t begin, int64_t end, int thread) {
    compose_job *j = ctx;
    const sc_frame *f = j->frame;
    const int width = j->cam->width;
    const double start = sc_now_ms();
    for (int64_t y = begin; y < end; ++y) {
        const int64_t *offsets = f->offsets + (y / SC_TILE) * f->tiles_x;
        for (int tx = 0; tx < f->tiles_x;) {
            if (offsets[tx + 1] != offsets[tx]) {
                ++tx;
                continue;
            }
            int last = tx;
            while (last + 1 < f->tiles_x && offsets[last + 2] == offsets[last + 1]) ++last;
            const int x0 = tx * SC_TILE, x1 = (last + 1) * SC_TILE < width ? (last + 1) * SC_TILE : width;
            copy_mesh(j, x0, (int)y, x1 - x0, 1);
            tx = last + 1;
        }
    }
    j->colour_ms[thread * PAD] += sc_now_ms() - start;
}

static void compose_tiles(void *ctx, int64_t begin, int64_t end, int thread) {
    compose_job *j = ctx;
    const sc_frame *f = j->frame;
    const int width = j->cam->width, height = j->cam->height;
    for (int64_t t = begin; t < end; ++t) {
        const int tx = (int)(t % f->tiles_x), ty = (int)(t / f->tiles_x);
        const int x0 = tx * SC_TILE, y0 = ty * SC_TILE;
        const int w = width - x0 < SC_TILE ? width - x0 : SC_TILE;
        const int h = height - y0 < SC_TILE ? height - y0 : SC_TILE;
        const int64_t first = f->offsets[t], count = f->offsets[t + 1] - first;
        if (count == 0) continue; /* copy_empty_rows' */
        double start = sc_now_ms();
        sc_srgb_tiles_encode(j->colour, x0, y0, w, h);
        for (int y = y0; y < y0 + h; ++y)
            for (int x = x0; x < x0 + w; ++x)
                j->clean_depth[(int64_t)y * width + x] = clean(depth_at(&j->depth_in, y, x), j->far);
        double done = sc_now_ms();
        j->colour_ms[thread * PAD] += done - start;
        j->evaluations[thread * PAD] += sc_composite_tile(f->splats, f->list + first, count, tx, ty,
                                                          j->cam, &j->image, j->exhaustive);
        start = sc_now_ms();
        sc_srgb_tiles_decode(j->colour, x0, y0, w, h);
        for (int y = y0; y < y0 + h && j->want_depth; ++y)
            for (int x = x0; x < x0 + w; ++x) {
                float *d = j->out_depth + (int64_t)y * width + x;
                if (!isfinite(*d)) *d = j->far;
            }
        j->colour_ms[thread * PAD] += sc_now_ms() - start;
    }
}

/* The Gaussians' half of the frame, and what it was made for. */
struct sc_prepared {
    sc_frame frame;
    sc_camera cam;
    sc_options opt;
    sc_stats stats;
};

sc_status sc_compose_prepare(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                             sc_prepared **prepared, sc_stats *stats) {
    *prepared = NULL;
    sc_prepared *p = calloc(1, sizeof *p);
    if (!p) return SC_ERR_MEMORY;
    const double start = sc_now_ms();
    p->cam = *cam, p->opt = *opt;
    const sc_status status = sc_frame_prepare(g, cam, opt, 0, &p->frame, &p->stats);
    p->stats.ms_total = sc_now_ms() - start;
    *stats = p->stats;
    if (status != SC_OK) {
        free(p);
        return status;
    }
    *prepared = p;
    return SC_OK;
}

void sc_prepared_size(const sc_prepared *p, int *width, int *height) {
    *width = p->cam.width, *height = p->cam.height;
}

void sc_prepared_free(sc_prepared *p) {
    if (!p) return;
    sc_frame_free(&p->frame);
    free(p);
}

sc_status sc_compose_srgb(const sc_prepared *p, const sc_rgba_view *mesh,
                          const sc_plane_view *mesh_depth, const sc_rgba_view *out,
                          float *out_depth, float far, sc_stats *stats, double *colour_ms) {
    const double start = sc_now_ms();
    const sc_camera *cam = &p->cam;
    *stats = p->stats;
    sc_status status = SC_OK;

    /* Full-frame scratch, touched only in the tiles with Gaussians (kept between frames). */
    const size_t pixels = (size_t)cam->width * (size_t)cam->height;
    float *layer = sc_buffer_alloc(sizeof(float) * 4 * pixels);
    float *rgb = sc_buffer_alloc(sizeof(float) * 3 * pixels);
    float *alpha = sc_buffer_alloc(sizeof(float) * pixels);
    float *clean_depth = sc_buffer_alloc(sizeof(float) * pixels);
    float *depth_scratch = out_depth ? NULL : sc_buffer_alloc(sizeof(float) * pixels);
    const sc_rgba_view layer_view = {(const char *)layer, cam->height, cam->width,
                                     (int64_t)sizeof(float) * 4 * cam->width, 16, 4};
    sc_srgb_tiles *colour = layer && rgb && alpha && clean_depth && (out_depth || depth_scratch)
                                ? sc_srgb_tiles_new(mesh, &layer_view, layer, rgb, alpha, out)
                                : NULL;
    compose_job *job = colour ? calloc(1, sizeof *job) : NULL;
    if (!job) {
        status = SC_ERR_MEMORY;
        goto done;
    }
    job->frame = &p->frame, job->cam = cam, job->mesh = *mesh, job->out = *out;
    job->want_depth = out_depth != NULL;
    if (!out_depth) out_depth = depth_scratch;
    job->depth_in = *mesh_depth, job->clean_depth = clean_depth, job->out_depth = out_depth;
    job->far = far, job->colour = colour, job->exhaustive = p->opt.exhaustive;
    job->image = (sc_image){.mesh_rgba = layer, .mesh_depth = clean_depth, .rgb = rgb,
                            .alpha = alpha, .depth = out_depth};
    const int threads = p->opt.threads < MAX_THREADS ? p->opt.threads : MAX_THREADS;
    sc_parallel_for(threads, cam->height, 8, copy_empty_rows, job);
    sc_parallel_for(threads, p->frame.ntiles, 1, compose_tiles, job);

    stats->ms_composite = sc_now_ms() - start;
    stats->ms_total = p->stats.ms_total + stats->ms_composite;
    stats->evaluations = 0;
    *colour_ms = 0.0;
    for (int t = 0; t < MAX_THREADS; ++t) {
        stats->evaluations += job->evaluations[t * PAD];
        *colour_ms += job->colour_ms[t * PAD];
    }
done:
    free(job);
    sc_srgb_tiles_free(colour);
    sc_buffer_free(layer);
    sc_buffer_free(rgb);
    sc_buffer_free(alpha);
    sc_buffer_free(clean_depth);
    sc_buffer_free(depth_scratch);
    return status;
}
