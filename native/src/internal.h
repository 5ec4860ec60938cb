/* Private helpers shared by the forward and backward passes (not public API).
 * Both passes must make the same per-pixel decisions (power > 0, alpha < 1/255), so they use
 * the same exp() and the same expressions, from here. */
#ifndef SPLATCORE_INTERNAL_H
#define SPLATCORE_INTERNAL_H

#include <math.h>
#include <string.h>

#include "splatcore.h"

#if defined(__GNUC__) && defined(__x86_64__) && !defined(__clang__) && defined(__linux__)
#define SC_CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define SC_CLONES
#endif

/* Inner blocks must be inlined into the SC_CLONES caller to be vectorised for its target. */
#if defined(__GNUC__)
#define SC_ALWAYS_INLINE __attribute__((always_inline)) inline
#else
#define SC_ALWAYS_INLINE inline
#endif

/* Whether every input value of Gaussian i is finite (projection forward and backward). */
static inline int sc_gaussian_finite(const sc_gaussians *g, int64_t i) {
    const float *rows[4] = {g->means + 3 * i, g->log_scales + 3 * i, g->quats + 4 * i,
                            g->sh + (int64_t)3 * g->sh_coeffs * i};
    const int counts[4] = {3, 3, 4, 3 * g->sh_coeffs};
    for (int r = 0; r < 4; ++r)
        for (int k = 0; k < counts[r]; ++k)
            if (!isfinite(rows[r][k])) return 0;
    return isfinite(g->opacity_logits[i]);
}

/* A world point in the camera frame: p = R mean + t, in double. */
static inline void sc_to_camera(const double *world_to_camera, const float *mean, double p[3]) {
    const double *v = world_to_camera;
    for (int k = 0; k < 3; ++k)
        p[k] = v[4 * k] * mean[0] + v[4 * k + 1] * mean[1] + v[4 * k + 2] * mean[2] + v[4 * k + 3];
}

enum { SC_PIXELS = SC_TILE * SC_TILE, SC_BLOCK = 8 /* pixels evaluated together: half a row */ };

/* e^x for x <= 0 (larger x is never drawn): 2^(x log2 e) split into an integer power of two and a
 * degree-6 polynomial on [-0.5, 0.5] (Cephes exp2f coefficients). Branch-free, vectorisable. */
static inline float sc_fast_exp(float x) {
    x = x < -87.0f ? -87.0f : x;
    x = x > 0.0f ? 0.0f : x;
    const float t = x * 1.44269504088896341f;
    const float n = (t + 12582912.0f) - 12582912.0f; /* round to nearest (1.5 * 2^23 trick) */
    const float f = t - n;
    float p = 1.535336188319500e-4f;
    p = p * f + 1.339887440266574e-3f;
    p = p * f + 9.618437357674640e-3f;
    p = p * f + 5.550332471162809e-2f;
    p = p * f + 2.402264791363012e-1f;
    p = p * f + 6.931472028550421e-1f;
    p = p * f + 1.0f;
    const int32_t bits = ((int32_t)n + 127) << 23;
    float scale;
    memcpy(&scale, &bits, sizeof scale);
    return p * scale;
}

/* What one Gaussian contributes along a tile's 16 columns, computed once for all its rows. */
typedef struct {
    float dx[SC_TILE];      /* projected mean minus pixel centre, x */
    float power_x[SC_TILE]; /* -0.5 A dx^2 */
    float half_cc, cb, y, opacity, r, g, b, depth;
} sc_columns;

static inline void sc_prepare_columns(sc_columns *c, const sc_splat *s, float px0) {
    for (int x = 0; x < SC_TILE; ++x) {
        c->dx[x] = s->x - (px0 + (float)x);
        c->power_x[x] = -0.5f * s->ca * c->dx[x] * c->dx[x];
    }
    c->half_cc = 0.5f * s->cc, c->cb = s->cb, c->y = s->y, c->opacity = s->opacity;
    c->r = s->r, c->g = s->g, c->b = s->b, c->depth = s->depth;
}

/* The rows [*j0, *j1] and whole half-row blocks [*i0, *i1) of a tile (origin x0, y0) that a
 * splat's footprint reaches; empty when *j0 > *j1. */
static inline void sc_tile_span(const sc_splat *s, int x0, int y0, int *j0, int *j1, int *i0,
                                int *i1) {
    int a = s->row0 - y0, b = s->row1 - y0, c = s->col0 - x0, d = s->col1 - x0;
    *j0 = a < 0 ? 0 : a;
    *j1 = b > SC_TILE - 1 ? SC_TILE - 1 : b;
    *i0 = c < 0 ? 0 : c / SC_BLOCK * SC_BLOCK;
    *i1 = d > SC_TILE - 1 ? SC_TILE : (d / SC_BLOCK + 1) * SC_BLOCK;
}

#endif
