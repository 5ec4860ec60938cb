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

/* One Gaussian over the 8 pixels of a half row starting at `first`. */
static SC_ALWAYS_INLINE void back_block(back_state *st, lane_sums *sums, int first, float dy,
                              float power_y, float cb_dy, const sc_columns *c, float ca, float cb,
                              float cc, int32_t entry, const int depth) {
    const int col = first % SC_TILE;
    float *restrict T = st->T + first;
    float *restrict ar = st->acc_r + first, *restrict ag = st->acc_g + first,
                    *restrict ab = st->acc_b + first, *restrict az = st->acc_z + first;
    const float *restrict gr = st->d_r + first, *restrict gg = st->d_g + first,
                          *restrict gb = st->d_b + first, *restrict gz = st->d_z + first,
                          *restrict gt = st->d_t + first;
    const int32_t *restrict last = st->last + first;
    const float *restrict dxs = c->dx + col, *restrict power_x = c->power_x + col;
    const float opacity = c->opacity, cr = c->r, cg = c->g, cbl = c->b, cz = c->depth;
    float *restrict s_x = sums->v[SC_DG_X], *restrict s_y = sums->v[SC_DG_Y];
    float *restrict s_a = sums->v[SC_DG_CA], *restrict s_b = sums->v[SC_DG_CB],
                    *restrict s_c = sums->v[SC_DG_CC], *restrict s_o = sums->v[SC_DG_OPACITY];
    float *restrict s_r = sums->v[SC_DG_R], *restrict s_g = sums->v[SC_DG_G],
                    *restrict s_bl = sums->v[SC_DG_B], *restrict s_z = sums->v[SC_DG_DEPTH];
    float *restrict s_ax = sums->v[SC_DG_ABS_X], *restrict s_ay = sums->v[SC_DG_ABS_Y];
    for (int x = 0; x < BLOCK; ++x) {
        const float dx = dxs[x];
        /* Exactly the forward's expressions, so the same pixels count. */
        const float power = power_x[x] + power_y - cb_dy * dx;
        const float g = sc_fast_exp(power);
        const float raw = opacity * g;
        const float alpha = raw < SC_ALPHA_MAX ? raw : SC_ALPHA_MAX;
        const float mine = entry <= last[x] ? 1.0f : 0.0f;
        const float drawn = alpha >= SC_ALPHA_MIN ? mine : 0.0f;
        const float use = power <= 0.0f ? drawn : 0.0f;

        /* Where the Gaussian was not added, used_alpha is 0, so the division by 1 - 0 and the
         * updates below leave T and the colour behind exactly as they were (no blend needed). */
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

static SC_ALWAYS_INLINE int64_t back_tile_body(back_state *st, const int32_t *block_last, int x0,
                                              int y0, int32_t kmax, const sc_splat *splats,
                                              const uint32_t *list, float *records,
                                              const int depth, const int exhaustive) {
    const float px0 = (float)x0 + 0.5f;
    int64_t evaluations = 0;
    for (int32_t k = kmax - 1; k >= 0; --k) {
        /* The splats are read in list order but lie apart in memory: fetch a few ahead. */
        if (k >= PREFETCH) SC_PREFETCH(&splats[list[k - PREFETCH]]);
        const sc_splat *s = &splats[list[k]];
        float *rec = records + (int64_t)k * NG;
        int j0, j1, i0, i1;
        sc_tile_span(s, x0, y0, &j0, &j1, &i0, &i1);
        /* Only the half rows the forward could have added this Gaussian to: inside its
         * alpha >= 1/255 ellipse (the forward's footprint masks) and with a pixel that had not
         * stopped before it. Every pixel left out adds exactly 0 to the record. */
        sc_half_rows todo = sc_span_half_rows(j0, j1, i0, i1);
        if (!exhaustive) todo &= live_half_rows(block_last, k);
        sc_columns c;
        if (todo) {
            sc_prepare_columns(&c, s, px0);
            if (!exhaustive && sc_popcount(todo) > 3) todo = sc_footprint_half_rows(s, &c, y0, todo);
        }
        if (!todo) {
            memset(rec, 0, sizeof(float) * NG);
            continue;
        }
        evaluations += BLOCK * (int64_t)sc_popcount(todo);
        float dys[SC_TILE], power_y[SC_TILE], cb_dy[SC_TILE]; /* all rows at once (vectorised) */
        for (int j = 0; j < SC_TILE; ++j) {
            dys[j] = c.y - ((float)(y0 + j) + 0.5f);
            power_y[j] = -(c.half_cc * dys[j] * dys[j]), cb_dy[j] = c.cb * dys[j];
        }
        lane_sums sums;
        for (int q = 0; q < NG; ++q) /* a loop, not memset: the sums then live in registers */
            for (int x = 0; x < BLOCK; ++x) sums.v[q][x] = 0.0f;
        while (todo) { /* row by row, left to right: the sums' fixed order */
            const int q = sc_lowest_bit(todo), j = q >> 1;
            todo &= todo - 1;
            back_block(st, &sums, q * BLOCK, dys[j], power_y[j], cb_dy[j], &c, s->ca, s->cb,
                       s->cc, k + 1, depth);
        }
        for (int q = 0; q < NG; ++q) {
            float total = 0.0f;
            for (int x = 0; x < BLOCK; ++x) total += sums.v[q][x];
            rec[q] = total;
        }
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
