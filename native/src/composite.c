/* Compositing: one 16x16 tile, front to back, exactly the reference rasterizer's per-pixel rules
 * (skip power > 0 and alpha < 1/255, clamp alpha at 0.99, stop before T < 1e-4), with an
 * optional mesh layer slotted in at each pixel's mesh depth; and the training variant (no mesh)
 * that also records each pixel's final transmittance and n_contrib for the backward pass.
 *
 * Speed comes from these, none of which changes a result:
 *  - only the 8-pixel half rows that a Gaussian's alpha >= 1/255 ellipse reaches are evaluated
 *    (sc_footprint_half_rows, internal.h), and none whose pixels have all stopped (live_half_rows);
 *  - each half row is branch-free, so the compiler vectorises it (AVX2/AVX-512 builds
 *    where the CPU has them, chosen once at run time by cpu.c; SSE2 otherwise; NEON on arm64);
 *  - exp() is a polynomial (sc_fast_exp, internal.h) with relative error below 4e-7, far
 *    inside the 1e-4 tolerance and the threshold margins the tests allow (checked against
 *    float64 in tests), floored where a pixel cannot be drawn so that no result is subnormal;
 *  - the Gaussians go in batches, set-up and exp() apart from the blending (work_item). */
#include <math.h>
#include <string.h>

#include "internal.h"

enum { PIXELS = SC_PIXELS, BLOCK = SC_BLOCK };

typedef struct {
    float T[PIXELS], r[PIXELS], g[PIXELS], b[PIXELS], depth[PIXELS], weight[PIXELS];
    float live[PIXELS]; /* 1 while the pixel takes Gaussians, 0 once stopped (or off-image) */
} tile_state;

/* A tile's Gaussians go in batches of up to BATCH, in three passes: each Gaussian's set-up (its
 * half rows, columns and rows), then its alpha over each half row it is evaluated at (an item),
 * then the items in order, blended into the running state. The first two have no dependence
 * from one Gaussian to the next, so they overlap freely; the third is only the short chain
 * through each pixel's transmittance. One Gaussian at a time, its set-up and exp() sat between
 * dependent blends, and a few half rows per Gaussian left the processor little to overlap.
 * Per pixel the Gaussians are blended in list order as before, with the same expressions (each
 * value that went through memory still does, so no multiply-add is fused differently): the
 * same bits. */
enum { BATCH = 16, MAX_ITEMS = BATCH * PIXELS / BLOCK };

typedef struct {
    float alpha[BLOCK]; /* the clamped alpha where power <= 0 and alpha >= 1/255, else 0 */
    int32_t first;      /* the half row's first pixel */
    int32_t gaussian;   /* its Gaussian's place in the batch */
} work_item;

typedef struct {
    float r, g, b, depth;
    int32_t entry; /* its tile-list entry + 1 (n_contrib) */
} item_colour;

/* The first pass for one half row: alpha = min(0.99, o exp(power)), 0 where not drawn. */
static SC_ALWAYS_INLINE void alpha_block(work_item *item, int first, float power_y, float cb_dy,
                                         const sc_columns *c) {
    const int col = first % SC_TILE;
    const float *restrict dx = c->dx + col, *restrict power_x = c->power_x + col;
    const float opacity = c->opacity;
    float *restrict out = item->alpha;
    for (int x = 0; x < BLOCK; ++x) {
        const float power = power_x[x] + power_y - cb_dy * dx[x];
        float alpha = opacity * sc_fast_exp(power);
        alpha = alpha < SC_ALPHA_MAX ? alpha : SC_ALPHA_MAX;
        const float drawn = alpha >= SC_ALPHA_MIN ? alpha : 0.0f;
        out[x] = power <= 0.0f ? drawn : 0.0f;
    }
}

/* The second pass for one item. The decisions are 0/1 float masks rather than branches so
 * that the loop vectorises. Where alpha is 0 (not drawn) nothing changes: w = 0. With `record`
 * (a constant at every call, so the compiler drops the branch) it also notes the entry as the
 * last Gaussian added at each pixel it was added to, for the backward pass. */
static SC_ALWAYS_INLINE void blend_block(tile_state *st, const work_item *item,
                                         const item_colour *colour, const int record,
                                         int32_t *restrict last_all) {
    const int first = item->first;
    float *restrict T = st->T + first, *restrict live = st->live + first;
    float *restrict r = st->r + first, *restrict g = st->g + first, *restrict b = st->b + first,
                    *restrict depth = st->depth + first, *restrict weight = st->weight + first;
    int32_t *restrict last = record ? last_all + first : NULL;
    const float *restrict alphas = item->alpha;
    const float cr = colour->r, cg = colour->g, cbl = colour->b, cz = colour->depth;
    const int32_t entry = colour->entry;
    for (int x = 0; x < BLOCK; ++x) {
        const float alpha = alphas[x];
        const float t = T[x];
        const float next_t = t * (1.0f - alpha);
        const float visible = alpha > 0.0f ? live[x] : 0.0f;
        const float stop = next_t < SC_T_MIN ? visible : 0.0f;
        const float added = visible - stop;
        const float w = added * alpha * t; /* alpha T when added, else 0 */
        r[x] += w * cr;
        g[x] += w * cg;
        b[x] += w * cbl;
        depth[x] += w * cz;
        weight[x] += w;
        T[x] = t - w; /* = t (1 - alpha) when added, up to rounding */
        live[x] -= stop;
        if (record) last[x] = added != 0.0f ? entry : last[x];
    }
}

/* The half rows that still have a pixel taking Gaussians. */
static SC_ALWAYS_INLINE sc_half_rows live_half_rows(const tile_state *st) {
    sc_half_rows alive = 0;
    for (int q = 0; q < PIXELS / BLOCK; ++q) {
        float sum = 0.0f;
        for (int x = 0; x < BLOCK; ++x) sum += st->live[q * BLOCK + x];
        alive |= (sc_half_rows)(sum != 0.0f) << q;
    }
    return alive;
}

/* Blend the mesh layer into pixel p with the transmittance left. A pixel left with T < SC_T_MIN
 * takes nothing more (the next Gaussian it would draw stops it, adding 0), so it stops here. */
static void blend_mesh(tile_state *st, int p, const float *rgba, float z) {
    const float t = st->T[p], a = rgba[3];
    st->r[p] += t * rgba[0];
    st->g[p] += t * rgba[1];
    st->b[p] += t * rgba[2];
    if (a > 0.0f && isfinite(z)) {
        st->depth[p] += t * a * z;
        st->weight[p] += t * a;
    }
    st->T[p] = t * (1.0f - a);
    if (st->T[p] < SC_T_MIN) st->live[p] = 0.0f;
}

typedef struct {
    int x0, y0, w, h;        /* tile origin and its size inside the image */
    float mesh_z[PIXELS];    /* +inf where no mesh is pending */
    float next_mesh_z;       /* the smallest pending mesh depth */
} mesh_state;

/* Blend every pending mesh pixel that lies in front of `depth`. */
static void flush_mesh(tile_state *st, mesh_state *ms, const sc_camera *cam, const sc_image *im,
                       float depth) {
    float next = INFINITY;
    for (int j = 0; j < ms->h; ++j)
        for (int i = 0; i < ms->w; ++i) {
            const int p = j * SC_TILE + i;
            const float z = ms->mesh_z[p];
            if (z <= depth) {
                const int64_t pix = (int64_t)(ms->y0 + j) * cam->width + ms->x0 + i;
                blend_mesh(st, p, im->mesh_rgba + 4 * pix, z);
                ms->mesh_z[p] = NAN; /* done: compares false with everything */
            } else if (z < next) {
                next = z;
            }
        }
    ms->next_mesh_z = next;
}

/* Every Gaussian of the tile's list, front to back. `record` as in blend_block; `exhaustive`
 * evaluates each splat's whole sc_tile_span (the slow twin of the footprint masks). */
static SC_ALWAYS_INLINE int64_t composite(tile_state *st, mesh_state *ms,
                                          const sc_splat *splats, const uint32_t *list,
                                          int64_t count, const sc_camera *cam,
                                          const sc_image *im, const int record, int32_t *last,
                                          const int exhaustive) {
    const int has_mesh = im->mesh_rgba != NULL;
    const float px0 = (float)ms->x0 + 0.5f;
    int64_t evaluations = 0;
    sc_columns columns[BATCH];
    float power_y[BATCH][SC_TILE], cb_dy[BATCH][SC_TILE];
    sc_half_rows todos[BATCH];
    item_colour colours[BATCH];
    work_item items[MAX_ITEMS];
    sc_half_rows alive = live_half_rows(st);
    int64_t k = 0;
    while (k < count) {
        /* Now and then (before every 16th entry), which half rows still take Gaussians: the
         * others are skipped (their pixels would add exactly 0), and a tile whose pixels have
         * all stopped is finished. A batch ends there, or before a Gaussian behind pending
         * mesh pixels (blended first), so `alive` is fixed within a batch. */
        if ((k & 15) == 15 && !(alive = live_half_rows(st))) break;
        if (has_mesh && splats[list[k]].depth >= ms->next_mesh_z) {
            flush_mesh(st, ms, cam, im, splats[list[k]].depth);
            if (!(alive = live_half_rows(st))) break; /* e.g. all behind an opaque mesh */
        }
        const int64_t end = (k | 15) + ((k & 15) == 15 ? 16 : 0), stop = end < count ? end : count;
        int n = 0; /* Gaussians of the batch with half rows to evaluate */
        for (const int64_t k0 = k; k < stop; ++k) {
            const sc_splat *s = &splats[list[k]];
            if (k + 8 < count) SC_PREFETCH(&splats[list[k + 8]]); /* the list jumps about */
            if (k > k0 && has_mesh && s->depth >= ms->next_mesh_z) break;
            int j0, j1, i0, i1;
            sc_tile_span(s, ms->x0, ms->y0, &j0, &j1, &i0, &i1);
            sc_half_rows todo = sc_span_half_rows(j0, j1, i0, i1);
            if (!todo) continue;
            sc_columns *c = &columns[n];
            sc_prepare_columns(c, s, px0);
            /* A span of a few half rows has little to skip: not worth the masks' set-up. */
            if (!exhaustive && sc_popcount(todo) > 3)
                todo = sc_footprint_half_rows(s, c, ms->y0, todo);
            if (!exhaustive) todo &= alive;
            evaluations += BLOCK * (int64_t)sc_popcount(todo);
            /* Each row's terms, for all 16 rows at once (vectorised; the same bits as one by one). */
            for (int j = 0; j < SC_TILE; ++j) {
                const float dy = c->y - ((float)(ms->y0 + j) + 0.5f);
                power_y[n][j] = -(c->half_cc * dy * dy), cb_dy[n][j] = c->cb * dy;
            }
            todos[n] = todo;
            colours[n++] = (item_colour){c->r, c->g, c->b, c->depth, (int32_t)(k + 1)};
        }
        int items_n = 0;
        for (int b = 0; b < n; ++b)
            for (sc_half_rows todo = todos[b]; todo; todo &= todo - 1) {
                const int q = sc_lowest_bit(todo);
                work_item *item = &items[items_n++];
                item->first = q * BLOCK, item->gaussian = b;
                alpha_block(item, q * BLOCK, power_y[b][q >> 1], cb_dy[b][q >> 1], &columns[b]);
            }
        for (int i = 0; i < items_n; ++i)
            blend_block(st, &items[i], &colours[items[i].gaussian], record, last);
    }
    return evaluations;
}

SC_MULTIVERSION(int64_t, composite_render,
                (tile_state *st, mesh_state *ms, const sc_splat *splats, const uint32_t *list,
                 int64_t count, const sc_camera *cam, const sc_image *im),
                (st, ms, splats, list, count, cam, im),
                composite(st, ms, splats, list, count, cam, im, 0, NULL, 0))

SC_MULTIVERSION(int64_t, composite_exhaustive,
                (tile_state *st, mesh_state *ms, const sc_splat *splats, const uint32_t *list,
                 int64_t count, const sc_camera *cam, const sc_image *im),
                (st, ms, splats, list, count, cam, im),
                composite(st, ms, splats, list, count, cam, im, 0, NULL, 1))

SC_MULTIVERSION(int64_t, composite_record,
                (tile_state *st, mesh_state *ms, const sc_splat *splats, const uint32_t *list,
                 int64_t count, const sc_camera *cam, const sc_image *im, int32_t *last),
                (st, ms, splats, list, count, cam, im, last),
                composite(st, ms, splats, list, count, cam, im, 1, last, 0))

SC_MULTIVERSION(int64_t, composite_record_exhaustive,
                (tile_state *st, mesh_state *ms, const sc_splat *splats, const uint32_t *list,
                 int64_t count, const sc_camera *cam, const sc_image *im, int32_t *last),
                (st, ms, splats, list, count, cam, im, last),
                composite(st, ms, splats, list, count, cam, im, 1, last, 1))

/* One tile: set up, composite, write out; with `final_t` and `n_contrib` the training record. */
static int64_t composite_tile(const sc_splat *splats, const uint32_t *list, int64_t count,
                              int tile_x, int tile_y, const sc_camera *cam, const sc_image *im,
                              float *final_t, int32_t *n_contrib, int exhaustive) {
    tile_state st;
    mesh_state ms;
    int32_t last[PIXELS];
    ms.x0 = tile_x * SC_TILE;
    ms.y0 = tile_y * SC_TILE;
    ms.w = cam->width - ms.x0 < SC_TILE ? cam->width - ms.x0 : SC_TILE;
    ms.h = cam->height - ms.y0 < SC_TILE ? cam->height - ms.y0 : SC_TILE;
    ms.next_mesh_z = INFINITY;
    for (int p = 0; p < PIXELS; ++p) {
        const int in_image = (p % SC_TILE) < ms.w && (p / SC_TILE) < ms.h;
        st.T[p] = 1.0f;
        st.r[p] = st.g[p] = st.b[p] = st.depth[p] = st.weight[p] = 0.0f;
        st.live[p] = in_image ? 1.0f : 0.0f;
        ms.mesh_z[p] = NAN;
        last[p] = 0;
    }
    if (im->mesh_rgba) {
        for (int j = 0; j < ms.h; ++j)
            for (int i = 0; i < ms.w; ++i) {
                const float z = im->mesh_depth[(int64_t)(ms.y0 + j) * cam->width + ms.x0 + i];
                ms.mesh_z[j * SC_TILE + i] = z;
                if (z < ms.next_mesh_z) ms.next_mesh_z = z;
            }
    }

    const int64_t evaluations =
        final_t ? (exhaustive ? composite_record_exhaustive(&st, &ms, splats, list, count, cam, im, last)
                              : composite_record(&st, &ms, splats, list, count, cam, im, last))
        : exhaustive ? composite_exhaustive(&st, &ms, splats, list, count, cam, im)
                     : composite_render(&st, &ms, splats, list, count, cam, im);
    if (im->mesh_rgba) flush_mesh(&st, &ms, cam, im, INFINITY);

    const float *bg = im->background;
    for (int j = 0; j < ms.h; ++j)
        for (int i = 0; i < ms.w; ++i) {
            const int p = j * SC_TILE + i;
            const int64_t pix = (int64_t)(ms.y0 + j) * cam->width + ms.x0 + i;
            const float t = st.T[p];
            im->rgb[3 * pix + 0] = st.r[p] + (bg ? t * bg[0] : 0.0f);
            im->rgb[3 * pix + 1] = st.g[p] + (bg ? t * bg[1] : 0.0f);
            im->rgb[3 * pix + 2] = st.b[p] + (bg ? t * bg[2] : 0.0f);
            im->alpha[pix] = 1.0f - t;
            im->depth[pix] = st.weight[p] > 0.0f ? st.depth[p] / st.weight[p] : INFINITY;
            if (final_t) {
                final_t[pix] = t;
                n_contrib[pix] = last[p];
            }
        }
    return evaluations;
}

int64_t sc_composite_tile(const sc_splat *splats, const uint32_t *list, int64_t count,
                          int tile_x, int tile_y, const sc_camera *cam, const sc_image *im,
                          int exhaustive) {
    return composite_tile(splats, list, count, tile_x, tile_y, cam, im, NULL, NULL, exhaustive);
}

/* The training variant records, per pixel, the final transmittance and the number of tile-list
 * entries up to and including the last Gaussian added (the reference CUDA code's n_contrib).
 * Training renders have no mesh layer; the images are bit-identical to sc_composite_tile's. */
int64_t sc_composite_tile_train(const sc_splat *splats, const uint32_t *list, int64_t count,
                                int tile_x, int tile_y, const sc_camera *cam, const sc_image *im,
                                float *final_t, int32_t *n_contrib, int exhaustive) {
    sc_image plain = *im;
    plain.mesh_rgba = NULL, plain.mesh_depth = NULL;
    return composite_tile(splats, list, count, tile_x, tile_y, cam, &plain, final_t, n_contrib,
                          exhaustive);
}

double sc_composite_microbench(int count, int iterations) {
    /* A 16x16 image whose single tile is covered by `count` broad, faint Gaussians: every
     * Gaussian is evaluated at all 256 pixels and none stops a pixel. */
    enum { MAX_COUNT = 4096 };
    static sc_splat splats[MAX_COUNT];
    static uint32_t list[MAX_COUNT];
    static float rgb[PIXELS * 3], alpha[PIXELS], depth[PIXELS];
    if (count > MAX_COUNT) count = MAX_COUNT;
    for (int i = 0; i < count; ++i) {
        const float u = (float)((i * 37) % 97) / 97.0f, v = (float)((i * 53) % 89) / 89.0f;
        splats[i] = (sc_splat){.x = 4.0f + 8.0f * u, .y = 4.0f + 8.0f * v, .ca = 0.01f,
                               .cb = 0.002f, .cc = 0.012f, .opacity = 2.0f / (float)(count + 1),
                               .r = u, .g = v, .b = 0.5f, .depth = 1.0f + (float)i,
                               .row0 = 0, .row1 = SC_TILE - 1, .col0 = 0, .col1 = SC_TILE - 1,
                               .k2 = 100.0f};
        list[i] = (uint32_t)i;
    }
    const sc_camera cam = {.width = SC_TILE, .height = SC_TILE, .fx = 1, .fy = 1};
    const sc_image im = {.rgb = rgb, .alpha = alpha, .depth = depth};
    const double start = sc_now_ms();
    for (int it = 0; it < iterations; ++it) sc_composite_tile(splats, list, count, 0, 0, &cam, &im, 1);
    return (sc_now_ms() - start) / 1000.0;
}
