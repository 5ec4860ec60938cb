/* Projection: each Gaussian to a 2D splat (EWA with the guard band, 0.3 px dilation, optional
 * antialiasing compensation), its SH colour, and the exact extent of its alpha >= 1/255 footprint.
 * In float, vectorised (sc_project_fast, below); project_one is the same in double, for the
 * Gaussians whose float values overflow, and the backward pass (project_backward.c) recomputes
 * it in double through the shared sc_ewa_project. */
#include <float.h>
#include <math.h>
#include <stdatomic.h>
#include <string.h>

#include "internal.h"
#include "sh_basis.h"

typedef struct {
    sc_projection_pass p;
    double forward[3];  /* the camera's +z in world space: the view direction of an ORTHO camera */
    atomic_llong first_bad; /* smallest index holding a non-finite value, or count */
} job;

/* Pixel-centre index range [lo, hi] covered by the interval [c - r, c + r], clipped to [0, n).
 * Branch-free, so that it vectorises in project_lanes. */
static SC_ALWAYS_INLINE void pixel_range(double c, double r, int n, int32_t *lo, int32_t *hi) {
    const double a = ceil(sc_clamp(c - r - 0.5, -1.0, (double)n));
    const double b = floor(sc_clamp(c + r - 0.5, -1.0, (double)n));
    *lo = (int32_t)(a < 0.0 ? 0.0 : a);
    *hi = (int32_t)(b > n - 1 ? (double)(n - 1) : b);
}

/* The footprint's k2 from ln(255 opacity): 2 ln(255 opacity), inflated by 1e-4 so that float
 * rounding in the compositor cannot put a drawn pixel outside it. */
static SC_ALWAYS_INLINE float footprint_k2(float log_255_opacity) {
    return 2.0f * log_255_opacity * (1.0f + 1e-4f) + 1e-4f;
}

/* The footprint of splat `s` (all else set): the compositor draws where opacity exp(power) >=
 * 1/255, i.e. inside the ellipse d^T conic d <= 2 ln(255 opacity) (footprint_k2). Its bounding
 * box follows from the covariance that the float conic stands for, inverted in double. */
void sc_footprint(sc_splat *s, const sc_camera *cam) {
    s->row0 = s->col0 = 0, s->row1 = s->col1 = -1;
    s->k2 = 0.0f, s->unused = 0.0f;
    if (!(s->opacity >= SC_ALPHA_MIN)) return;
    s->k2 = footprint_k2((float)log(255.0 * (double)s->opacity));
    const double ca = s->ca, cb = s->cb, cc = s->cc, det = ca * cc - cb * cb;
    /* A conic that float made singular (or zero: a covariance beyond float) is unbounded. */
    const double half_x = det > 0.0 ? sqrt((double)s->k2 * cc / det) : INFINITY;
    /* A band (panorama.c: constant along x, conic 0 0 cc) reaches all columns, some rows. */
    const double half_y = det > 0.0                       ? sqrt((double)s->k2 * ca / det)
                          : ca == 0.0 && cb == 0.0 && cc > 0.0 ? sqrt((double)s->k2 / cc)
                                                                : INFINITY;
    int32_t x0, x1, y0, y1;
    pixel_range(s->x, half_x, cam->width, &x0, &x1);
    pixel_range(s->y, half_y, cam->height, &y0, &y1);
    if (x0 > x1 || y0 > y1) return;
    s->row0 = y0, s->row1 = y1, s->col0 = x0, s->col1 = x1;
}

/* Returns 1 when projected, 0 when culled, -1 on non-finite input. */
static int project_one(const job *j, int64_t i, sc_splat *s) {
    const sc_gaussians *g = j->p.g;
    const sc_camera *cam = j->p.cam;
    if (!sc_gaussian_finite(g, i)) return -1;
    sc_ewa e;
    if (!sc_ewa_project(g, i, cam, j->p.opt->near, &e)) return 0;
    const double a = e.a, b = e.b, c = e.c, det = e.det;

    double opacity = sc_sigmoid(g->opacity_logits[i]);
    if (j->p.opt->antialiased || cam->aperture > 0.0) opacity *= sc_mass_factor(&e, j->p.opt->antialiased);

    double dir[3];
    sc_view_dir(g->means + 3 * i, j->p.campos, dir);
    if (cam->model == SC_ORTHO) memcpy(dir, j->forward, sizeof dir);
    const float dir_f[3] = {(float)dir[0], (float)dir[1], (float)dir[2]};
    float rgb[3];
    sc_sh_colour_f(j->p.opt->sh_degree, g->sh + (int64_t)3 * g->sh_coeffs * i, dir_f, rgb);

    s->x = (float)sc_pixel_x(cam, &e);
    s->y = (float)sc_pixel_y(cam, &e);
    if (!isfinite(s->x) || !isfinite(s->y)) return 0; /* beyond float32: off screen, culled */
    s->ca = (float)(c / det);
    s->cb = (float)(-b / det);
    s->cc = (float)(a / det);
    s->opacity = (float)opacity;
    s->r = fmaxf(rgb[0] + 0.5f, 0.0f);
    s->g = fmaxf(rgb[1] + 0.5f, 0.0f);
    s->b = fmaxf(rgb[2] + 0.5f, 0.0f);
    s->depth = (float)e.p[2];

    sc_footprint(s, cam);
    return 1;
}

/* ---------------------------------------------------------------- the renderer's fast path
 *
 * The same projection in float, LANES Gaussians at a time in loops the compiler vectorises
 * (AVX-512 or AVX2 where the CPU has them, cpu.c). Only the view transform runs in double: the
 * mean in the camera frame, p = R mean + t, and the view direction, mean - camera centre, are
 * small differences of large numbers in a scene far from the origin, so they are formed in
 * double and rounded once; everything after them is relative to the camera and well scaled for
 * float. det(A A^T), the determinant before the dilation, is |row0 x row1|^2 (Lagrange's
 * identity), a sum of squares, so needle-thin splats keep their precision where a c - b^2
 * would cancel. A Gaussian whose float values overflow (scales beyond ~e^40) is projected by
 * the double path instead. Every Gaussian goes through the same vector code (a short batch is
 * padded), so results never depend on which batch or thread a Gaussian falls in.
 *
 * With `cull` (the render), Gaussians that cannot reach the image are dropped before the
 * covariance and SH work, by a bound on the screen radius from the largest scale alone:
 * |A|_2 <= |J|_F max(scale), so the ellipse lies within sqrt(k2 (|J|_F^2 max(scale)^2 + 0.3))
 * pixels of the projected mean, k2 <= 2 ln 255 (inflated as the footprint is). Those with
 * opacity below 1/255 (logit < -5.6) are dropped too: they draw nothing. */

enum { LANES = 16, CHUNK = 1024 };

/* e^x in float for any x (clamped to [-87, 88]). */
static inline float exp_any(float x) {
    return sc_exp_in_range(x < -87.0f ? -87.0f : (x > 88.0f ? 88.0f : x));
}

/* ln x in float for a normal x > 0 (the footprint's 255 opacity): x = m 2^e with m in
 * [0.75, 1.5), ln m from its series in s = (m - 1) / (m + 1) (ln m = 2 (s + s^3/3 + ...),
 * |s| < 0.2: the terms up to s^11 leave a relative error below 1e-7). Vectorisable. */
static inline float log_normal(float x) {
    int32_t bits;
    memcpy(&bits, &x, sizeof bits);
    int32_t e = ((bits >> 23) & 0xff) - 127;
    int32_t mbits = (bits & 0x007fffff) | 0x3f800000; /* m in [1, 2) */
    float m;
    memcpy(&m, &mbits, sizeof m);
    const int big = m >= 1.5f;
    m = big ? 0.5f * m : m;
    e += big;
    const float t = (m - 1.0f) / (m + 1.0f), t2 = t * t;
    float series = 1.0f / 11.0f;
    series = series * t2 + 1.0f / 9.0f;
    series = series * t2 + 1.0f / 7.0f;
    series = series * t2 + 1.0f / 5.0f;
    series = series * t2 + 1.0f / 3.0f;
    series = series * t2 + 1.0f;
    return (float)e * 0.693147180559945309f + 2.0f * t * series;
}

typedef struct {
    job base;                     /* what project_one takes: inputs, output, first_bad */
    float view[9];                /* the camera rotation, in float */
    float lo_x, hi_x, lo_y, hi_y; /* the guard band of x/z and y/z (0 for ORTHO) */
    int cull;
    int ortho;                    /* SC_ORTHO: x, y instead of x/z, y/z; J constant */
    float aperture, inv_focus;    /* depth of field (sc_camera), aperture 0: none */
} fast_job;

/* One batch: lane l holds Gaussian idx[l]. */
typedef struct {
    float dir[3][LANES], depth[LANES];
    float x[LANES], y[LANES], ca[LANES], cb[LANES], cc[LANES], opacity[LANES], k2[LANES];
    float rgb[3][LANES]; /* clamped colour */
    int32_t row0[LANES], row1[LANES], col0[LANES], col1[LANES], ok[LANES];
} batch;

static SC_ALWAYS_INLINE void project_lanes_body(const fast_job *fj, const int64_t *idx, batch *o) {
    const sc_gaussians *g = fj->base.p.g;
    const sc_camera *cam = fj->base.p.cam;
    /* The inputs, copied into contiguous lanes so that the loops below vectorise. */
    float in[14][LANES]; /* mean 3, log scale 3, quaternion 4, opacity logit 1 */
    for (int l = 0; l < LANES; ++l) {
        const int64_t i = idx[l];
        for (int k = 0; k < 3; ++k) in[k][l] = g->means[3 * i + k];
        for (int k = 0; k < 3; ++k) in[3 + k][l] = g->log_scales[3 * i + k];
        for (int k = 0; k < 4; ++k) in[6 + k][l] = g->quats[4 * i + k];
        in[10][l] = g->opacity_logits[i];
    }
    double v[12], campos[3];
    for (int k = 0; k < 12; ++k) v[k] = cam->world_to_camera[k];
    for (int k = 0; k < 3; ++k) campos[k] = fj->base.p.campos[k];
    const double fxd = cam->fx, fyd = cam->fy, cxd = cam->cx, cyd = cam->cy;
    const int ortho = fj->ortho;
    /* An orthographic camera sees every Gaussian along its axis: dir = forward (as campos
     * + forward - campos, so the one expression serves both). */
    const double fwd[3] = {fj->base.forward[0], fj->base.forward[1], fj->base.forward[2]};
    float pf[3][LANES];
    for (int l = 0; l < LANES; ++l) {
        const double m0 = in[0][l], m1 = in[1][l], m2 = in[2][l];
        double p[3];
        for (int k = 0; k < 3; ++k) p[k] = v[4 * k] * m0 + v[4 * k + 1] * m1 + v[4 * k + 2] * m2 + v[4 * k + 3];
        for (int k = 0; k < 3; ++k) pf[k][l] = (float)p[k];
        o->dir[0][l] = (float)(ortho ? fwd[0] : m0 - campos[0]);
        o->dir[1][l] = (float)(ortho ? fwd[1] : m1 - campos[1]);
        o->dir[2][l] = (float)(ortho ? fwd[2] : m2 - campos[2]);
        /* The projected mean too: fx x/z + cx cancels near the image's left edge. */
        const double inv_z = ortho ? 1.0 : 1.0 / p[2];
        o->x[l] = (float)(fxd * (p[0] * inv_z) + cxd);
        o->y[l] = (float)(fyd * (p[1] * inv_z) + cyd);
        o->depth[l] = pf[2][l];
    }
    const float fx = (float)cam->fx, fy = (float)cam->fy;
    float w[9];
    for (int k = 0; k < 9; ++k) w[k] = fj->view[k];
    const float dilation = (float)SC_DILATION;
    const float lo_x = fj->lo_x, hi_x = fj->hi_x, lo_y = fj->lo_y, hi_y = fj->hi_y;
    const float aa = fj->base.p.opt->antialiased ? 1.0f : 0.0f;
    const float aperture = fj->aperture, inv_focus = fj->inv_focus;
    const int keep_mass = fj->base.p.opt->antialiased || aperture > 0.0f; /* sc_mass_factor */
    const int width = cam->width, height = cam->height;
    for (int l = 0; l < LANES; ++l) {
        const float inv_z = ortho ? 1.0f : 1.0f / pf[2][l]; /* ORTHO: the band is 0, so J's */
        const float rx = pf[0][l] * inv_z, ry = pf[1][l] * inv_z; /* z column is too */
        const float tx = rx < lo_x ? lo_x : (rx > hi_x ? hi_x : rx);
        const float ty = ry < lo_y ? lo_y : (ry > hi_y ? hi_y : ry);
        const float j00 = fx * inv_z, j02 = -fx * tx * inv_z;
        const float j11 = fy * inv_z, j12 = -fy * ty * inv_z;
        float jw[2][3];
        for (int k = 0; k < 3; ++k) {
            jw[0][k] = j00 * w[k] + j02 * w[6 + k];
            jw[1][k] = j11 * w[3 + k] + j12 * w[6 + k];
        }
        /* Rotation of the normalised quaternion (all-zero: the identity). */
        const float q0 = in[6][l], q1 = in[7][l], q2 = in[8][l], q3 = in[9][l];
        const float n2 = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3;
        const float inv = n2 > 0.0f ? 1.0f / sqrtf(n2 > 0.0f ? n2 : 1.0f) : 0.0f;
        const float qw = n2 > 0.0f ? q0 * inv : 1.0f;
        const float qx = q1 * inv, qy = q2 * inv, qz = q3 * inv;
        const float r[9] = {1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz),
                            2 * (qx * qz + qw * qy),     2 * (qx * qy + qw * qz),
                            1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx),
                            2 * (qx * qz - qw * qy),     2 * (qy * qz + qw * qx),
                            1 - 2 * (qx * qx + qy * qy)};
        /* A = J W R S; Sigma2 = A A^T + 0.3 I. */
        float u[3], t[3];
        for (int k = 0; k < 3; ++k) {
            const float s = exp_any(in[3 + k][l]);
            u[k] = (jw[0][0] * r[k] + jw[0][1] * r[3 + k] + jw[0][2] * r[6 + k]) * s;
            t[k] = (jw[1][0] * r[k] + jw[1][1] * r[3 + k] + jw[1][2] * r[6 + k]) * s;
        }
        const float a0 = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];
        const float b0 = u[0] * t[0] + u[1] * t[1] + u[2] * t[2];
        const float c0 = t[0] * t[0] + t[1] * t[1] + t[2] * t[2];
        const float e0 = u[1] * t[2] - u[2] * t[1], e1 = u[2] * t[0] - u[0] * t[2];
        const float e2 = u[0] * t[1] - u[1] * t[0];
        const float det0 = e0 * e0 + e1 * e1 + e2 * e2;
        /* The circle of confusion (sc_dof_blur): 0 without depth of field, then a1 = a0 etc.
         * exactly. */
        const float rz = aperture * (ortho ? 1.0f - pf[2][l] * inv_focus : inv_focus - inv_z);
        const float blur = 0.25f * rz * rz, bx = fx * fx * blur, by = fy * fy * blur;
        const float a1 = a0 + bx, c1 = c0 + by, det1 = det0 + bx * c0 + by * a0 + bx * by;
        const float det = det1 + dilation * (a1 + c1) + dilation * dilation;
        const float inv_det = 1.0f / det;
        const float ca = (c1 + dilation) * inv_det, cb = -b0 * inv_det, cc = (a1 + dilation) * inv_det;
        o->ca[l] = ca, o->cb[l] = cb, o->cc[l] = cc;
        const float sigmoid = 1.0f / (1.0f + exp_any(-in[10][l]));
        const float before = aa * det0 + (1.0f - aa) * (det0 + dilation * (a0 + c0) + dilation * dilation);
        const float mass = sqrtf(before * inv_det);
        const float opacity = sigmoid * (keep_mass ? mass : 1.0f);
        o->opacity[l] = opacity;
        /* x * 0 == 0 exactly when x is finite. */
        const float finite = o->x[l] * 0.0f + o->y[l] * 0.0f + det * 0.0f + ca * 0.0f +
                             cb * 0.0f + cc * 0.0f + opacity * 0.0f;
        o->ok[l] = finite == 0.0f && det > 0.0f;

        /* The footprint, as footprint() (with a float log). */
        const int drawn = opacity >= SC_ALPHA_MIN;
        const float k2 = drawn ? footprint_k2(log_normal(255.0f * opacity)) : 0.0f;
        o->k2[l] = k2;
        const double det_c = (double)ca * cc - (double)cb * cb;
        const double half_x = det_c > 0.0 ? sqrt((double)k2 * cc / det_c) : INFINITY;
        const double half_y = det_c > 0.0 ? sqrt((double)k2 * ca / det_c) : INFINITY;
        int32_t x0, x1, y0, y1;
        pixel_range(o->x[l], half_x, width, &x0, &x1);
        pixel_range(o->y[l], half_y, height, &y0, &y1);
        const int reach = drawn && x0 <= x1 && y0 <= y1;
        o->row0[l] = reach ? y0 : 0, o->row1[l] = reach ? y1 : -1;
        o->col0[l] = reach ? x0 : 0, o->col1[l] = reach ? x1 : -1;
    }
}

/* The colour, as sc_sh_colour_f computes it for each lane (the same expressions, summed in the
 * same order), but LANES Gaussians at a time: one Gaussian's sums are chains of 16 dependent
 * additions, which a lane-parallel loop overlaps. The lanes' Gaussians lie within one CHUNK, so
 * their coefficient rows are at 32-bit offsets from the first. */
static SC_ALWAYS_INLINE void colour_lanes(const fast_job *fj, const int64_t *idx, batch *o) {
    const sc_gaussians *g = fj->base.p.g;
    const int degree = fj->base.p.opt->sh_degree;
    const int count = (degree + 1) * (degree + 1);
    const int64_t stride = (int64_t)3 * g->sh_coeffs;
    const float *restrict sh = g->sh + idx[0] * stride;
    int32_t row[LANES];
    for (int l = 0; l < LANES; ++l) row[l] = (int32_t)((idx[l] - idx[0]) * stride);
    float basis[16][LANES];
    for (int l = 0; l < LANES; ++l) {
        const float d0 = o->dir[0][l], d1 = o->dir[1][l], d2 = o->dir[2][l];
        const float len = sqrtf(d0 * d0 + d1 * d1 + d2 * d2);
        const float x = len > 0.0f ? d0 / len : 0.0f, y = len > 0.0f ? d1 / len : 0.0f;
        const float z = len > 0.0f ? d2 / len : 0.0f;
        float one[16];
        sc_sh_basis_f(x, y, z, one);
        for (int i = 0; i < 16; ++i) basis[i][l] = one[i];
    }
    float sum[3][LANES] = {{0.0f}};
    for (int i = 0; i < count; ++i)
        for (int c = 0; c < 3; ++c) {
            const float *restrict coeff = sh + 3 * i + c;
            SC_NO_UNROLL /* a loop over lanes vectorises (gathered loads); unrolled, it would not */
            for (int l = 0; l < LANES; ++l) sum[c][l] += basis[i][l] * coeff[row[l]];
        }
    for (int c = 0; c < 3; ++c)
        for (int l = 0; l < LANES; ++l) {
            const float v = sum[c][l] + 0.5f;
            o->rgb[c][l] = v > 0.0f ? v : 0.0f; /* as fmaxf(v, 0): NaN gives 0 */
        }
}

SC_MULTIVERSION(void, project_lanes, (const fast_job *fj, const int64_t *idx, batch *o),
                (fj, idx, o), (project_lanes_body(fj, idx, o), colour_lanes(fj, idx, o)))

/* keep[i - begin] for Gaussians [begin, end): in front of the near plane (and a depth float32
 * can hold, as sc_ewa_project), and with `cull` possibly reaching the image (see above). */
static SC_ALWAYS_INLINE void select_body(const fast_job *fj, int64_t begin, int64_t end,
                                         uint8_t *restrict keep) {
    const sc_gaussians *g = fj->base.p.g;
    const sc_camera *cam = fj->base.p.cam;
    const float *restrict means = g->means + 3 * begin, *restrict scales = g->log_scales + 3 * begin;
    const float *restrict logits = g->opacity_logits + begin;
    double v[12];
    for (int k = 0; k < 12; ++k) v[k] = cam->world_to_camera[k];
    const double near = fj->base.p.opt->near, far = sc_far(cam), fx = cam->fx, fy = cam->fy;
    const double cx = cam->cx, cy = cam->cy;
    const int ortho = fj->ortho;
    const double aperture = cam->aperture > 0.0 ? cam->aperture : 0.0;
    const double inv_focus = aperture > 0.0 ? 1.0 / cam->focus : 0.0;
    const double f2 = fx > fy ? fx * fx : fy * fy;
    const double lo_x = fj->lo_x, hi_x = fj->hi_x, lo_y = fj->lo_y, hi_y = fj->hi_y;
    const double width = cam->width, height = cam->height;
    const int cull = fj->cull;
    const int64_t n = end - begin;
    for (int64_t i = 0; i < n; ++i) {
        const double m0 = means[3 * i], m1 = means[3 * i + 1], m2 = means[3 * i + 2];
        const double x_cam = v[0] * m0 + v[1] * m1 + v[2] * m2 + v[3];
        const double y_cam = v[4] * m0 + v[5] * m1 + v[6] * m2 + v[7];
        const double z = v[8] * m0 + v[9] * m1 + v[10] * m2 + v[11];
        const int in_front = (z >= near) & (z <= far) & (z >= -FLT_MAX);
        const double inv_z = ortho ? 1.0 : 1.0 / z;
        const double rx = x_cam * inv_z, ry = y_cam * inv_z;
        const double tx = sc_clamp(rx, lo_x, hi_x), ty = sc_clamp(ry, lo_y, hi_y);
        const double j2 = (fx * fx * (1.0 + tx * tx) + fy * fy * (1.0 + ty * ty)) * (inv_z * inv_z);
        /* Not fmaxf, a library call that stops vectorisation (the inputs are finite here). */
        const float s0 = scales[3 * i], s1 = scales[3 * i + 1], s2 = scales[3 * i + 2];
        const float s12 = s1 > s2 ? s1 : s2, largest = s0 > s12 ? s0 : s12;
        const double rz = aperture * (ortho ? 1.0 - z * inv_focus : inv_focus - inv_z);
        const double blur = 0.25 * rz * rz * f2; /* the circle of confusion, pixels^2 */
        const double radius =
            sqrt(11.1 * (j2 * (double)exp_any(2.0f * largest) + SC_DILATION + blur)) * 1.001 + 1.0;
        const double x = fx * rx + cx, y = fy * ry + cy;
        /* NaN or inf in the bound keeps the Gaussian (the full path decides). */
        const int outside = (x + radius < 0.0) | (x - radius > width) | (y + radius < 0.0) |
                            (y - radius > height);
        const int faint = logits[i] < -5.6f; /* sigmoid < 1/271 */
        const int reach = (!faint) & ((largest > 40.0f) /* beyond exp_any */ | (!outside));
        keep[i] = (uint8_t)(in_front & ((!cull) | reach)); /* & and |: no branches, vectorises */
    }
}

SC_MULTIVERSION(void, select_chunk, (const fast_job *fj, int64_t begin, int64_t end, uint8_t *keep),
                (fj, begin, end, keep), select_body(fj, begin, end, keep))

/* The sort key of splat i, if the caller asked for keys. */
static void set_key(const sc_projection *out, int64_t i) {
    const sc_splat *s = &out->splats[i];
    if (out->keys) out->keys[i] = s->row1 >= s->row0 && s->col1 >= s->col0 ? s->depth : INFINITY;
}

/* The float values of lane l into the splat of Gaussian i. */
static void finish_lane(const fast_job *fj, const batch *o, int l, int64_t i) {
    sc_splat *s = &fj->base.p.out->splats[i];
    *s = (sc_splat){.x = o->x[l], .y = o->y[l], .ca = o->ca[l], .cb = o->cb[l], .cc = o->cc[l],
                    .opacity = o->opacity[l], .r = o->rgb[0][l], .g = o->rgb[1][l],
                    .b = o->rgb[2][l], .depth = o->depth[l], .row0 = o->row0[l],
                    .row1 = o->row1[l], .col0 = o->col0[l], .col1 = o->col1[l], .k2 = o->k2[l]};
    fj->base.p.out->valid[i] = 1;
    set_key(fj->base.p.out, i);
}

static void clear(const fast_job *fj, int64_t i) {
    sc_splat *s = &fj->base.p.out->splats[i];
    *s = (sc_splat){.row1 = -1, .col1 = -1};
    fj->base.p.out->valid[i] = 0;
    set_key(fj->base.p.out, i);
}

/* Whether every input value of Gaussians [begin, end) is finite: one pass over each array,
 * testing the exponent bits (an integer compare and OR, which vectorise; a float sum would not).
 * At 1M SH3 Gaussians that is 236 MB a frame, so it is compiled per instruction-set level. */
static SC_ALWAYS_INLINE int all_finite_body(const sc_gaussians *g, int64_t begin, int64_t end) {
    const float *rows[5] = {g->means, g->log_scales, g->quats, g->opacity_logits, g->sh};
    const int64_t widths[5] = {3, 3, 4, 1, (int64_t)3 * g->sh_coeffs};
    uint32_t bad = 0;
    for (int r = 0; r < 5; ++r) {
        const uint32_t *restrict bits = (const uint32_t *)(const void *)rows[r];
        for (int64_t k = begin * widths[r]; k < end * widths[r]; ++k)
            bad |= (bits[k] & 0x7f800000u) == 0x7f800000u; /* an all-ones exponent: inf or NaN */
    }
    return !bad;
}

SC_MULTIVERSION(int, all_finite, (const sc_gaussians *g, int64_t begin, int64_t end),
                (g, begin, end), all_finite_body(g, begin, end))

/* Gaussians [begin, end), at most CHUNK of them. */
static void project_fast_chunk(fast_job *fj, int64_t begin, int64_t end) {
    job *j = &fj->base;
    const sc_gaussians *g = j->p.g;
    if (!all_finite(g, begin, end)) {
        for (int64_t i = begin; i < end; ++i)
            if (!sc_gaussian_finite(g, i)) {
                long long seen = atomic_load(&j->first_bad);
                while (i < seen && !atomic_compare_exchange_weak(&j->first_bad, &seen, i)) {
                }
                return;
            }
    }
    uint8_t keep[CHUNK];
    select_chunk(fj, begin, end, keep);
    int64_t idx[CHUNK + LANES];
    int count = 0;
    for (int64_t i = begin; i < end; ++i) {
        if (keep[i - begin])
            idx[count++] = i;
        else
            clear(fj, i);
    }
    for (int at = 0; at < count; at += LANES) {
        const int n = count - at < LANES ? count - at : LANES;
        for (int l = n; l < LANES; ++l) idx[at + l] = idx[at + n - 1]; /* pad: same code path */
        batch o;
        project_lanes(fj, idx + at, &o);
        for (int l = 0; l < n; ++l) {
            const int64_t i = idx[at + l];
            if (o.ok[l])
                finish_lane(fj, &o, l, i);
            else if (project_one(j, i, &j->p.out->splats[i]) == 1) { /* overflow: in double */
                j->p.out->valid[i] = 1;
                set_key(j->p.out, i);
            } else {
                clear(fj, i);
            }
        }
    }
}

static void project_fast_range(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    for (int64_t at = begin; at < end; at += CHUNK) /* one thread runs the whole range */
        project_fast_chunk(ctx, at, end - at < CHUNK ? end : at + CHUNK);
}

sc_status sc_project_fast(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                          int cull, sc_projection *out, sc_stats *stats) {
    if (cam->model >= SC_EQUIRECTANGULAR) return sc_project_panorama(g, cam, opt, cull, out, stats);
    fast_job fj = {.base = {.p = {.g = g, .cam = cam, .opt = opt, .out = out}}, .cull = cull,
                   .ortho = cam->model == SC_ORTHO};
    atomic_init(&fj.base.first_bad, g->count);
    sc_camera_centre(cam->world_to_camera, fj.base.p.campos);
    for (int k = 0; k < 3; ++k) fj.base.forward[k] = cam->world_to_camera[8 + k];
    for (int r = 0; r < 3; ++r)
        for (int k = 0; k < 3; ++k) fj.view[3 * r + k] = (float)cam->world_to_camera[4 * r + k];
    const double tan_x = 0.5 * cam->width / cam->fx, tan_y = 0.5 * cam->height / cam->fy;
    fj.lo_x = (float)(-(cam->cx / cam->fx) - SC_GUARD * tan_x);
    fj.hi_x = (float)((cam->width - cam->cx) / cam->fx + SC_GUARD * tan_x);
    fj.lo_y = (float)(-(cam->cy / cam->fy) - SC_GUARD * tan_y);
    fj.hi_y = (float)((cam->height - cam->cy) / cam->fy + SC_GUARD * tan_y);
    if (fj.ortho) fj.lo_x = fj.hi_x = fj.lo_y = fj.hi_y = 0.0f; /* no clamp: J is constant */
    fj.aperture = cam->aperture > 0.0 ? (float)cam->aperture : 0.0f;
    fj.inv_focus = cam->aperture > 0.0 ? (float)(1.0 / cam->focus) : 0.0f;
    sc_parallel_for(opt->threads, g->count, CHUNK, project_fast_range, &fj);
    long long bad = atomic_load(&fj.base.first_bad);
    if (bad < g->count) {
        stats->error_index = bad;
        return SC_ERR_NONFINITE;
    }
    return SC_OK;
}

sc_status sc_project(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                     sc_projection *out, sc_stats *stats) {
    return sc_project_fast(g, cam, opt, 0, out, stats);
}
