/* Compositing backward: one 16x16 tile, back to front, as the reference CUDA rasterizer's
 * renderCUDA backward, with this renderer's per-pixel rules (the same exp(), the same
 * power <= 0 and alpha >= 1/255 decisions, recomputed from the same floats as the forward).
 *
 * Per pixel the forward kept only the final transmittance T_N and n_contrib; walking back from
 * the last Gaussian added, each Gaussian's transmittance is recovered as T_i = T_{i+1}/(1 - a_i)
 * (1 - a_i >= 0.01 since a_i <= 0.99), and the colour accumulated behind it as
 * acc_{i} = a_{i+1} c_{i+1} + (1 - a_{i+1}) acc_{i+1}. With C = sum_i c_i a_i T_i + T_N bg,
 * alpha = 1 - T_N and the expected depth D = S / (1 - T_N), S = sum_i z_i a_i T_i:
 *   dL/dc_i = a_i T_i dL/dC,        dL/dz_i = a_i T_i dL/dD / (1 - T_N)
 *   dL/da_i = T_i (c_i - acc_i) . (dL/dC, dL/dS) + T_N / (1 - a_i) (dL/dalpha' - bg . dL/dC)
 * where depth is a fourth colour channel (c = z, dL/dS = dL/dD / (1 - T_N)) and
 * dL/dalpha' = dL/dalpha - dL/dD D / (1 - T_N). Then a = min(0.99, o G), G = exp(power):
 * unclamped, dL/do = G dL/da and dL/dpower = a dL/da; clamped, both 0.
 *
 * Like the forward, the work runs Gaussian by Gaussian over 8-pixel half rows with 0/1 masks
 * so that it vectorises; each Gaussian's sums over the tile's pixels land in its record at its
 * position in the tile list, so no two threads ever write the same memory and the sums' order
 * is fixed (per-lane partial sums, then the lanes in order). */
#include <math.h>
#include <string.h>

#include "internal.h"

enum { PIXELS = SC_PIXELS, BLOCK = SC_BLOCK, NG = SC_DG_COUNT, PREFETCH = 4 };

typedef struct {
    float T[PIXELS];                           /* transmittance in front of the current Gaussian */
    float acc_r[PIXELS], acc_g[PIXELS], acc_b[PIXELS], acc_z[PIXELS]; /* colour behind it */
    float d_r[PIXELS], d_g[PIXELS], d_b[PIXELS], d_z[PIXELS]; /* dL/dC per channel, dL/dS */
    float d_t[PIXELS];                         /* T_N (dL/dalpha' - bg . dL/dC) */
    int32_t last[PIXELS];                      /* n_contrib */
} back_state;

typedef struct {
    float v[NG][BLOCK]; /* per-lane partial sums of one Gaussian's gradient record */
} lane_sums;

/* As the forward (composite.c), a tile's Gaussians go in batches of up to BATCH, in three
 * passes: each Gaussian's set-up, then exp() over each half row it is evaluated at (an item),
 * then the items in order through the running state (back to front) into each Gaussian's lane
 * sums. The first two have no dependence from one Gaussian to the next, so they overlap freely.
 * Per pixel and per lane everything happens in the same order with the same expressions as one
 * Gaussian at a time (each value that went through memory still does, so no multiply-add is
 * fused differently): the same bits. */
enum { BATCH = 16, MAX_ITEMS = BATCH * PIXELS / BLOCK };

typedef struct {
    float g[BLOCK];   /* exp(power) where the forward added the Gaussian, else 0 */
    int32_t first;    /* the half row's first pixel */
    int32_t gaussian; /* its Gaussian's place in the batch */
} work_item;

typedef struct {
    float ca, cb, cc, opacity, r, g, b, depth;
} item_splat;

/* The second pass for one half row: exp(power), 0 where this Gaussian was not added (those
 * pixels then change nothing: see back_block). Exactly the forward's expressions, so the same
 * pixels count. */
static SC_ALWAYS_INLINE void exp_block(const back_state *st, work_item *item, float power_y,
                                       float cb_dy, const sc_columns *c, int32_t entry) {
    const int first = item->first, col = first % SC_TILE;
    const int32_t *restrict last = st->last + first;
    const float *restrict dxs = c->dx + col, *restrict power_x = c->power_x + col;
    const float opacity = c->opacity;
    float *restrict out = item->g;
    for (int x = 0; x < BLOCK; ++x) {
        const float power = power_x[x] + power_y - cb_dy * dxs[x];
        const float g = sc_fast_exp(power);
        const float raw = opacity * g;
        const float alpha = raw < SC_ALPHA_MAX ? raw : SC_ALPHA_MAX;
        const float mine = entry <= last[x] ? g : 0.0f;
        const float drawn = alpha >= SC_ALPHA_MIN ? mine : 0.0f;
        out[x] = power <= 0.0f ? drawn : 0.0f;
    }
}

/* The third pass for one item: its Gaussian over the 8 pixels of a half row. */
static SC_ALWAYS_INLINE void back_block(back_state *st, lane_sums *sums, const work_item *item,
                                        float dy, const float *dxs, const item_splat *sp,
                                        const int depth) {
    const int first = item->first;
    float *restrict T = st->T + first;
    float *restrict ar = st->acc_r + first, *restrict ag = st->acc_g + first,
                    *restrict ab = st->acc_b + first, *restrict az = st->acc_z + first;
    const float *restrict gr = st->d_r + first, *restrict gg = st->d_g + first,
                          *restrict gb = st->d_b + first, *restrict gz = st->d_z + first,
                          *restrict gt = st->d_t + first;
    const float *restrict gs = item->g;
    const float opacity = sp->opacity, cr = sp->r, cg = sp->g, cbl = sp->b, cz = sp->depth;
    const float ca = sp->ca, cb = sp->cb, cc = sp->cc;
    float *restrict s_x = sums->v[SC_DG_X], *restrict s_y = sums->v[SC_DG_Y];
    float *restrict s_a = sums->v[SC_DG_CA], *restrict s_b = sums->v[SC_DG_CB],
                    *restrict s_c = sums->v[SC_DG_CC], *restrict s_o = sums->v[SC_DG_OPACITY];
    float *restrict s_r = sums->v[SC_DG_R], *restrict s_g = sums->v[SC_DG_G],
                    *restrict s_bl = sums->v[SC_DG_B], *restrict s_z = sums->v[SC_DG_DEPTH];
    float *restrict s_ax = sums->v[SC_DG_ABS_X], *restrict s_ay = sums->v[SC_DG_ABS_Y];
    for (int x = 0; x < BLOCK; ++x) {
        const float dx = dxs[x];
        const float g = gs[x]; /* > 0 exactly where the Gaussian was added (alpha >= 1/255) */
        const float raw = opacity * g;
        const float alpha = raw < SC_ALPHA_MAX ? raw : SC_ALPHA_MAX;
        const float use = g > 0.0f ? 1.0f : 0.0f;

        /* Where the Gaussian was not added, used_alpha is 0, so the division by 1 - 0 and the
         * updates below leave T and the colour behind exactly as they were (no blend needed),
         * and every term of the sums is 0. */
        const float used_alpha = use * alpha;
        const float inv = 1.0f / (1.0f - used_alpha);
        const float t = T[x] * inv; /* T_i */
        const float w = used_alpha * t;
        s_r[x] += w * gr[x];
        s_g[x] += w * gg[x];
        s_bl[x] += w * gb[x];
        if (depth) s_z[x] += w * gz[x];
        const float d_alpha = t * ((cr - ar[x]) * gr[x] + (cg - ag[x]) * gg[x] +
                                   (cbl - ab[x]) * gb[x] + (depth ? (cz - az[x]) * gz[x] : 0.0f)) +
                              gt[x] * inv;
        const float free_alpha = raw < SC_ALPHA_MAX ? use : 0.0f; /* not clamped */
        const float d_power = free_alpha * d_alpha * alpha;
        s_o[x] += free_alpha * d_alpha * g;
        /* power = -0.5 (A dx^2 + C dy^2) - B dx dy, dx, dy = mean - pixel centre. */
        const float gx = -(ca * dx + cb * dy) * d_power;
        const float gy = -(cc * dy + cb * dx) * d_power;
        s_x[x] += gx;
        s_y[x] += gy;
        s_ax[x] += fabsf(gx);
        s_ay[x] += fabsf(gy);
        s_a[x] += -0.5f * dx * dx * d_power;
        s_b[x] += -dx * dy * d_power;
        s_c[x] += -0.5f * dy * dy * d_power;

        /* acc_i = a_i c_i + (1 - a_i) acc_{i+1} = acc_{i+1} + a_i (c_i - acc_{i+1}). */
        ar[x] += used_alpha * (cr - ar[x]);
        ag[x] += used_alpha * (cg - ag[x]);
        ab[x] += used_alpha * (cbl - ab[x]);
        if (depth) az[x] += used_alpha * (cz - az[x]);
        T[x] = t;
    }
}

/* The half rows with a pixel whose n_contrib reaches past entry k (those where entry k may have
 * been added), for every k at once: bit q of live[k] for k < block_last[q]. */
static SC_ALWAYS_INLINE sc_half_rows live_half_rows(const int32_t *block_last, int32_t k) {
    sc_half_rows live = 0;
    for (int q = 0; q < PIXELS / BLOCK; ++q) live |= (sc_half_rows)(k < block_last[q]) << q;
    return live;
}

/* A Gaussian's record: each quantity's 8 lane sums added in lane order, 0 + v0 + v1 + ... + v7
 * (the order is part of the result). With vector extensions the 12 x 8 sums are transposed
 * (shuffles), so that 8 quantities are added at once in that order: a column at a time, the
 * compiler built each from 8 scalar loads. */
#if defined(__clang__) || (defined(__GNUC__) && __GNUC__ >= 12)
typedef float lane_vector __attribute__((vector_size(BLOCK * sizeof(float))));
#define SHUFFLE __builtin_shufflevector

static SC_ALWAYS_INLINE void reduce_lanes(const lane_sums *sums, float *rec) {
    _Static_assert(NG == 12 && BLOCK == 8, "the transposes below are for 12 x 8 sums");
    lane_vector r[12], t[12], u[12];
    memcpy(r, sums->v, sizeof r);
    /* Per 128-bit half: interleave pairs of rows, then pairs of pairs: u[4a + i] holds, for
     * rows 4a..4a+3, column i in its low half and column i + 4 in its high half. */
    for (int a = 0; a < 3; ++a) {
        const lane_vector *ra = r + 4 * a;
        lane_vector *ta = t + 4 * a, *ua = u + 4 * a;
        ta[0] = SHUFFLE(ra[0], ra[1], 0, 8, 1, 9, 4, 12, 5, 13);
        ta[1] = SHUFFLE(ra[0], ra[1], 2, 10, 3, 11, 6, 14, 7, 15);
        ta[2] = SHUFFLE(ra[2], ra[3], 0, 8, 1, 9, 4, 12, 5, 13);
        ta[3] = SHUFFLE(ra[2], ra[3], 2, 10, 3, 11, 6, 14, 7, 15);
        ua[0] = SHUFFLE(ta[0], ta[2], 0, 1, 8, 9, 4, 5, 12, 13);
        ua[1] = SHUFFLE(ta[0], ta[2], 2, 3, 10, 11, 6, 7, 14, 15);
        ua[2] = SHUFFLE(ta[1], ta[3], 0, 1, 8, 9, 4, 5, 12, 13);
        ua[3] = SHUFFLE(ta[1], ta[3], 2, 3, 10, 11, 6, 7, 14, 15);
    }
    /* Quantities 0..7: column x as one vector (rows 0..3 from u[0..3], 4..7 from u[4..7]). */
    lane_vector total = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
    for (int x = 0; x < 4; ++x) total += SHUFFLE(u[x], u[4 + x], 0, 1, 2, 3, 8, 9, 10, 11);
    for (int x = 0; x < 4; ++x) total += SHUFFLE(u[x], u[4 + x], 4, 5, 6, 7, 12, 13, 14, 15);
    memcpy(rec, &total, sizeof total);
    /* Quantities 8..11: columns 0..3 in u[8..11]'s low halves, then 4..7 from the high halves. */
    lane_vector rest = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
    for (int x = 0; x < 4; ++x) rest += u[8 + x];
    for (int x = 0; x < 4; ++x) rest += SHUFFLE(u[8 + x], u[8 + x], 4, 5, 6, 7, 4, 5, 6, 7);
    memcpy(rec + 8, &rest, 4 * sizeof(float));
}
#undef SHUFFLE
#else
static SC_ALWAYS_INLINE void reduce_lanes(const lane_sums *sums, float *rec) {
    for (int q = 0; q < NG; ++q) {
        float total = 0.0f;
        for (int x = 0; x < BLOCK; ++x) total += sums->v[q][x];
        rec[q] = total;
    }
}
#endif

static SC_ALWAYS_INLINE int64_t back_tile_body(back_state *st, const int32_t *block_last, int x0,
                                              int y0, int32_t kmax, const sc_splat *splats,
                                              const uint32_t *list, float *records,
                                              const int depth, const int exhaustive) {
    const float px0 = (float)x0 + 0.5f;
    int64_t evaluations = 0;
    sc_columns columns[BATCH];
    float dys[BATCH][SC_TILE], power_y[BATCH][SC_TILE], cb_dy[BATCH][SC_TILE];
    sc_half_rows todos[BATCH];
    int32_t entries[BATCH];
    item_splat sp[BATCH];
    lane_sums sums[BATCH];
    work_item items[MAX_ITEMS];
    for (int32_t k = kmax - 1; k >= 0;) {
        int n = 0; /* Gaussians of the batch with half rows to evaluate */
        for (const int32_t stop = k >= BATCH ? k - BATCH : -1; k > stop; --k) {
            /* The splats are read in list order but lie apart in memory: fetch a few ahead. */
            if (k >= PREFETCH) SC_PREFETCH(&splats[list[k - PREFETCH]]);
            const sc_splat *s = &splats[list[k]];
            int j0, j1, i0, i1;
            sc_tile_span(s, x0, y0, &j0, &j1, &i0, &i1);
            /* Only the half rows the forward could have added this Gaussian to: inside its
             * alpha >= 1/255 ellipse (the forward's footprint masks) and with a pixel that had
             * not stopped before it. Every pixel left out adds exactly 0 to the record. */
            sc_half_rows todo = sc_span_half_rows(j0, j1, i0, i1);
            if (!exhaustive) todo &= live_half_rows(block_last, k);
            sc_columns *c = &columns[n];
            if (todo) {
                sc_prepare_columns(c, s, px0);
                if (!exhaustive && sc_popcount(todo) > 3) todo = sc_footprint_half_rows(s, c, y0, todo);
            }
            if (!todo) {
                memset(records + (int64_t)k * NG, 0, sizeof(float) * NG);
                continue;
            }
            evaluations += BLOCK * (int64_t)sc_popcount(todo);
            for (int j = 0; j < SC_TILE; ++j) { /* all rows at once (vectorised) */
                dys[n][j] = c->y - ((float)(y0 + j) + 0.5f);
                power_y[n][j] = -(c->half_cc * dys[n][j] * dys[n][j]), cb_dy[n][j] = c->cb * dys[n][j];
            }
            for (int q = 0; q < NG; ++q)
                for (int x = 0; x < BLOCK; ++x) sums[n].v[q][x] = 0.0f;
            sp[n] = (item_splat){s->ca, s->cb, s->cc, c->opacity, c->r, c->g, c->b, c->depth};
            todos[n] = todo;
            entries[n++] = k;
        }
        int items_n = 0;
        for (int b = 0; b < n; ++b) /* row by row, left to right: the sums' fixed order */
            for (sc_half_rows todo = todos[b]; todo; todo &= todo - 1) {
                const int q = sc_lowest_bit(todo);
                work_item *item = &items[items_n++];
                item->first = q * BLOCK, item->gaussian = b;
                exp_block(st, item, power_y[b][q >> 1], cb_dy[b][q >> 1], &columns[b],
                          entries[b] + 1);
            }
        for (int i = 0; i < items_n; ++i) {
            const work_item *item = &items[i];
            const int b = item->gaussian, q = item->first / BLOCK;
            back_block(st, &sums[b], item, dys[b][q >> 1], columns[b].dx + item->first % SC_TILE,
                       &sp[b], depth);
        }
        for (int b = 0; b < n; ++b) reduce_lanes(&sums[b], records + (int64_t)entries[b] * NG);
    }
    return evaluations;
}

/* Two builds of the tile loop: with the expected-depth gradient, and without (training on
 * colour alone; its terms are all zero then), `depth` a constant in each. */
SC_MULTIVERSION(int64_t, back_tile,
                (back_state *st, const int32_t *block_last, int x0, int y0, int32_t kmax,
                 const sc_splat *splats, const uint32_t *list, float *records),
                (st, block_last, x0, y0, kmax, splats, list, records),
                back_tile_body(st, block_last, x0, y0, kmax, splats, list, records, 0, 0))

SC_MULTIVERSION(int64_t, back_tile_depth,
                (back_state *st, const int32_t *block_last, int x0, int y0, int32_t kmax,
                 const sc_splat *splats, const uint32_t *list, float *records),
                (st, block_last, x0, y0, kmax, splats, list, records),
                back_tile_body(st, block_last, x0, y0, kmax, splats, list, records, 1, 0))

/* The slow twin: every Gaussian over its whole span, at the same instruction-set level (so the
 * same roundings) as the fast builds. */
SC_MULTIVERSION(int64_t, back_tile_exhaustive,
                (back_state *st, const int32_t *block_last, int x0, int y0, int32_t kmax,
                 const sc_splat *splats, const uint32_t *list, float *records, int depth),
                (st, block_last, x0, y0, kmax, splats, list, records, depth),
                depth ? back_tile_body(st, block_last, x0, y0, kmax, splats, list, records, 1, 1)
                      : back_tile_body(st, block_last, x0, y0, kmax, splats, list, records, 0, 1))

int64_t sc_composite_tile_backward(const sc_splat *splats, const uint32_t *list, int64_t count,
                                   int tile_x, int tile_y, const sc_camera *cam,
                                   const sc_image_grads *im, float *records, int exhaustive) {
    back_state st;
    const int x0 = tile_x * SC_TILE, y0 = tile_y * SC_TILE;
    const int w = cam->width - x0 < SC_TILE ? cam->width - x0 : SC_TILE;
    const int h = cam->height - y0 < SC_TILE ? cam->height - y0 : SC_TILE;
    const float *bg = im->background;
    int32_t kmax = 0, block_last[PIXELS / BLOCK] = {0}; /* max n_contrib per half row */
    for (int p = 0; p < PIXELS; ++p) {
        const int i = p % SC_TILE, j = p / SC_TILE;
        st.acc_r[p] = st.acc_g[p] = st.acc_b[p] = st.acc_z[p] = 0.0f;
        st.T[p] = 1.0f;
        st.d_r[p] = st.d_g[p] = st.d_b[p] = st.d_z[p] = st.d_t[p] = 0.0f;
        st.last[p] = 0;
        if (i >= w || j >= h) continue;
        const int64_t pix = (int64_t)(y0 + j) * cam->width + x0 + i;
        const float t_final = im->final_t[pix];
        const float *d = im->d_rgb + 3 * pix;
        float d_alpha = im->d_alpha ? im->d_alpha[pix] : 0.0f;
        const float covered = 1.0f - t_final; /* = the sum of the weights */
        if (im->d_depth && im->n_contrib[pix] > 0 && covered > 0.0f && isfinite(im->depth[pix])) {
            const float d_s = im->d_depth[pix] / covered;
            st.d_z[p] = d_s;
            d_alpha -= d_s * im->depth[pix];
        }
        st.T[p] = t_final;
        st.d_r[p] = d[0], st.d_g[p] = d[1], st.d_b[p] = d[2];
        st.d_t[p] = t_final * (d_alpha - (bg ? bg[0] * d[0] + bg[1] * d[1] + bg[2] * d[2] : 0.0f));
        st.last[p] = im->n_contrib[pix];
        if (st.last[p] > block_last[p / BLOCK]) block_last[p / BLOCK] = st.last[p];
        if (st.last[p] > kmax) kmax = st.last[p];
    }
    if (kmax > count) kmax = (int32_t)count; /* cannot happen with a matching state */
    memset(records + (int64_t)kmax * NG, 0, sizeof(float) * (size_t)((count - kmax) * NG));
    if (exhaustive)
        return back_tile_exhaustive(&st, block_last, x0, y0, kmax, splats, list, records,
                                    im->d_depth != NULL);
    return im->d_depth ? back_tile_depth(&st, block_last, x0, y0, kmax, splats, list, records)
                       : back_tile(&st, block_last, x0, y0, kmax, splats, list, records);
}
