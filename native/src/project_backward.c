/* Projection backward: one Gaussian's summed splat gradient (projected mean, conic, opacity,
 * colour, depth) back to its parameters, in double, through exactly the forward's chain
 * (project.c): conic = inverse of Sigma2 = A A^T + 0.3 I with the 2x3 factor A = J W R S,
 * the guard-band clamp inside J, the quaternion normalisation, exp of the log scales, the
 * opacity sigmoid (and the antialiasing compensation), the SH colour with its clamp and its
 * view direction. The forward's intermediate values are recomputed here (O(1) per Gaussian),
 * which also checks that the Gaussian still projects to what the forward drew.
 * Scalar double code, compiled per instruction-set level (SC_MULTIVERSION): FMA and three-operand
 * forms make it about 15% faster where the CPU has them.
 *
 * The training backward runs the same chain SC_BW_LANES Gaussians at a time instead
 * (sc_project_backward_lanes, below): one Gaussian's chain is a long dependent sequence with
 * four exp(), two square roots and several divisions, about 250 ns of latency, while eight of
 * them side by side in vector registers cost little more than one. The scalar function is its
 * slow twin (tests/test_backward.py holds the two together). */
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "lane_math.h"
#include "sh_basis.h"

/* Whether a recomputed value still rounds to (about) what the forward stored. */
static inline int same(double value, float stored) {
    return fabs(value - (double)stored) <= 1e-5 * (fabs(value) + 1.0);
}

/* The same for a conic entry: the forward computes the conic in float (project.c), whose
 * relative error grows with the condition number `kappa` of the 2D covariance (about
 * 0.4 FLT_EPSILON kappa measured: 2.6e-5 at kappa 700, a large disc seen edge-on), so the
 * tolerance grows with it too. A Gaussian that really changed (1 % in a scale) still fails
 * unless kappa is above ~1e4. */
static inline int same_conic(double value, float stored, double kappa) {
    const double tolerance = 1e-5 + 8.0 * FLT_EPSILON * kappa;
    return fabs(value - (double)stored) <= tolerance * (fabs(value) + 1.0);
}

static inline float finite_or_zero(double v, int64_t *flushed) {
    const float f = (float)v;
    if (isfinite(f)) return f;
    ++*flushed;
    return 0.0f;
}

static SC_ALWAYS_INLINE int backward_body(const sc_gaussians *g, const sc_camera *cam,
                                         const sc_options *opt, const double campos[3], int64_t i,
                                         const sc_splat *s, const double *d,
                                         sc_gaussian_grads *out, int64_t *flushed) {
    const float *sh = g->sh + (int64_t)3 * g->sh_coeffs * i;
    if (!sc_gaussian_finite(g, i)) return -1;

    /* ---- forward, as project.c */
    sc_ewa e;
    if (!sc_ewa_project(g, i, cam, opt->near, &e)) return -2;
    const double *v = cam->world_to_camera, *p = e.p, *r = e.r, *scale = e.scale;
    const double z = p[2], fx = cam->fx, fy = cam->fy, tx = e.tx, ty = e.ty;
    const double a0 = e.a0, b0 = e.b0, c0 = e.c0, a = e.a, b = e.b, c = e.c, det = e.det;
    const double(*m)[3] = e.jw, (*af)[3] = e.a_rows; /* M = J W, A = M R S */
    const double sig = sc_sigmoid(g->opacity_logits[i]);
    double dir[3];
    const double len = sc_view_dir(g->means + 3 * i, campos, dir);
    const double half_trace = 0.5 * (a + c), spread = 0.5 * (a - c);
    const double largest = half_trace + sqrt(spread * spread + b * b);
    const double inv_det = 1.0 / det;
    const double kappa = largest * largest * inv_det; /* largest / smallest eigenvalue */
    if (!same(sc_pixel_x(cam, &e), s->x) || !same(sc_pixel_y(cam, &e), s->y) ||
        !same(z, s->depth) || !same_conic(c * inv_det, s->ca, kappa) ||
        !same_conic(a * inv_det, s->cc, kappa))
        return -2;

    /* ---- backward */
    /* Conic (c, -b, a) / det -> dilated covariance a, b, c. */
    const double d_ca = d[SC_DG_CA], d_cb = d[SC_DG_CB], d_cc = d[SC_DG_CC];
    const double inv_det2 = inv_det * inv_det;
    double da0 = (-c * c * d_ca + b * c * d_cb - b * b * d_cc) * inv_det2;
    double db0 = (2.0 * b * c * d_ca - (det + 2.0 * b * b) * d_cb + 2.0 * a * b * d_cc) * inv_det2;
    double dc0 = (-b * b * d_ca + a * b * d_cb - a * a * d_cc) * inv_det2;

    /* Opacity: sigmoid, times sqrt(det_raw / det) when antialiased. */
    double d_logit;
    const double d_opacity = d[SC_DG_OPACITY];
    if (opt->antialiased) {
        const double det_raw = a0 * c0 - b0 * b0, ratio = det_raw * inv_det;
        const double comp = sqrt(ratio > 0.0 ? ratio : 0.0);
        d_logit = d_opacity * comp * sig * (1.0 - sig);
        if (ratio > 0.0) {
            const double d_ratio = d_opacity * sig * 0.5 / (comp > 1e-6 ? comp : 1e-6);
            const double d_det_raw = d_ratio * inv_det, d_det = -d_ratio * ratio * inv_det;
            da0 += d_det_raw * c0 + d_det * c;
            dc0 += d_det_raw * a0 + d_det * a;
            db0 += -2.0 * b0 * (d_det_raw + d_det);
        }
    } else {
        d_logit = d_opacity * sig * (1.0 - sig);
    }

    /* Sigma2_raw = A A^T: a0 = |A0|^2, b0 = A0.A1, c0 = |A1|^2. */
    double dA[2][3];
    for (int k = 0; k < 3; ++k) {
        dA[0][k] = 2.0 * da0 * af[0][k] + db0 * af[1][k];
        dA[1][k] = db0 * af[0][k] + 2.0 * dc0 * af[1][k];
    }
    /* A = M R S: dM = dA S R^T, dR = M^T dA S, d log s_k = sum_row dA[row][k] A[row][k]. */
    double dM[2][3] = {{0}}, dR[9] = {0}, d_ls[3];
    for (int k = 0; k < 3; ++k) {
        d_ls[k] = dA[0][k] * af[0][k] + dA[1][k] * af[1][k];
        for (int row = 0; row < 2; ++row) {
            const double ds = dA[row][k] * scale[k];
            for (int n = 0; n < 3; ++n) {
                dM[row][n] += ds * r[3 * n + k];
                dR[3 * n + k] += m[row][n] * ds;
            }
        }
    }
    /* M = J W: rows j00 W0 + j02 W2 and j11 W1 + j12 W2. */
    const double dj00 = dM[0][0] * v[0] + dM[0][1] * v[1] + dM[0][2] * v[2];
    const double dj02 = dM[0][0] * v[8] + dM[0][1] * v[9] + dM[0][2] * v[10];
    const double dj11 = dM[1][0] * v[4] + dM[1][1] * v[5] + dM[1][2] * v[6];
    const double dj12 = dM[1][0] * v[8] + dM[1][1] * v[9] + dM[1][2] * v[10];
    /* Reciprocals once: divisions are the slowest operations of this latency-bound chain. */
    const double inv_z = 1.0 / z, inv_z2 = inv_z * inv_z, inv_z3 = inv_z2 * inv_z;
    const double fx_z2 = fx * inv_z2, fy_z2 = fy * inv_z2;
    double dp[3] = {0.0, 0.0, 0.0};
    dp[2] -= dj00 * fx_z2 + dj11 * fy_z2;
    if (e.clamped_x) {
        dp[2] += dj02 * fx_z2 * tx; /* j02 = -fx tx / z with tx constant */
    } else {
        dp[0] -= dj02 * fx_z2; /* j02 = -fx x / z^2 */
        dp[2] += dj02 * 2.0 * fx * p[0] * inv_z3;
    }
    if (e.clamped_y) {
        dp[2] += dj12 * fy_z2 * ty;
    } else {
        dp[1] -= dj12 * fy_z2;
        dp[2] += dj12 * 2.0 * fy * p[1] * inv_z3;
    }
    /* Projected mean and depth. */
    const double d_x = d[SC_DG_X], d_y = d[SC_DG_Y];
    dp[0] += d_x * fx * inv_z;
    dp[1] += d_y * fy * inv_z;
    dp[2] += -(d_x * fx * p[0] + d_y * fy * p[1]) * inv_z2 + d[SC_DG_DEPTH];
    double d_mean[3];
    for (int k = 0; k < 3; ++k) d_mean[k] = v[k] * dp[0] + v[4 + k] * dp[1] + v[8 + k] * dp[2];

    /* Colour: max(sh + 0.5, 0) (clamped where the forward's colour is 0), then the SH and
     * its view direction. */
    const double d_rgb[3] = {s->r > 0.0f ? d[SC_DG_R] : 0.0, s->g > 0.0f ? d[SC_DG_G] : 0.0,
                             s->b > 0.0f ? d[SC_DG_B] : 0.0};
    double d_sh[48], d_dir[3];
    sc_sh_backward(opt->sh_degree, sh, dir, d_rgb, d_sh, d_dir);
    if (len > 0.0) {
        const double along = d_dir[0] * dir[0] + d_dir[1] * dir[1] + d_dir[2] * dir[2];
        const double inv_len = 1.0 / len;
        for (int k = 0; k < 3; ++k) d_mean[k] += (d_dir[k] - along * dir[k]) * inv_len;
    }

    /* Rotation -> normalised quaternion -> quaternion. */
    double dq[4] = {0.0, 0.0, 0.0, 0.0};
    if (e.q_norm2 > 0.0) {
        const double w = e.q[0], x = e.q[1], y = e.q[2], zq = e.q[3], qnorm = sqrt(e.q_norm2);
        const double dqw = 2.0 * (-zq * dR[1] + y * dR[2] + zq * dR[3] - x * dR[5] - y * dR[6] +
                                  x * dR[7]);
        const double dqx = 2.0 * (y * dR[1] + zq * dR[2] + y * dR[3] - 2.0 * x * dR[4] -
                                  w * dR[5] + zq * dR[6] + w * dR[7] - 2.0 * x * dR[8]);
        const double dqy = 2.0 * (-2.0 * y * dR[0] + x * dR[1] + w * dR[2] + x * dR[3] +
                                  zq * dR[5] - w * dR[6] + zq * dR[7] - 2.0 * y * dR[8]);
        const double dqz = 2.0 * (-2.0 * zq * dR[0] - w * dR[1] + x * dR[2] + w * dR[3] -
                                  2.0 * zq * dR[4] + y * dR[5] + x * dR[6] + y * dR[7]);
        const double along = dqw * w + dqx * x + dqy * y + dqz * zq;
        const double inv_qnorm = 1.0 / qnorm;
        dq[0] = (dqw - along * w) * inv_qnorm;
        dq[1] = (dqx - along * x) * inv_qnorm;
        dq[2] = (dqy - along * y) * inv_qnorm;
        dq[3] = (dqz - along * zq) * inv_qnorm;
    }

    /* ---- write */
    for (int k = 0; k < 3; ++k) {
        out->means[3 * i + k] = finite_or_zero(d_mean[k], flushed);
        out->log_scales[3 * i + k] = finite_or_zero(d_ls[k], flushed);
    }
    for (int k = 0; k < 4; ++k) out->quats[4 * i + k] = finite_or_zero(dq[k], flushed);
    out->opacity_logits[i] = finite_or_zero(d_logit, flushed);
    const int used = 3 * (opt->sh_degree + 1) * (opt->sh_degree + 1);
    float *osh = out->sh + (int64_t)3 * g->sh_coeffs * i;
    int64_t bad = 0;
    for (int k = 0; k < used; ++k) { /* branch-free: this loop streams most of the bytes */
        const float f = (float)d_sh[k];
        const int ok = isfinite(f);
        bad += !ok;
        osh[k] = ok ? f : 0.0f;
    }
    *flushed += bad;
    for (int k = used; k < 3 * g->sh_coeffs; ++k) osh[k] = 0.0f;
    out->xy[2 * i] = finite_or_zero(d_x, flushed);
    out->xy[2 * i + 1] = finite_or_zero(d_y, flushed);
    out->xy_abs[2 * i] = finite_or_zero(d[SC_DG_ABS_X], flushed);
    out->xy_abs[2 * i + 1] = finite_or_zero(d[SC_DG_ABS_Y], flushed);
    return 0;
}

SC_MULTIVERSION(int, backward_isa,
                (const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                 const double campos[3], int64_t i, const sc_splat *s, const double *d,
                 sc_gaussian_grads *out, int64_t *flushed),
                (g, cam, opt, campos, i, s, d, out, flushed),
                backward_body(g, cam, opt, campos, i, s, d, out, flushed))

int sc_project_backward_gaussian(const sc_gaussians *g, const sc_camera *cam,
                                 const sc_options *opt, const double campos[3], int64_t i,
                                 const sc_splat *s, const double *d, sc_gaussian_grads *out,
                                 int64_t *flushed) {
    return backward_isa(g, cam, opt, campos, i, s, d, out, flushed);
}

/* ---------------------------------------------------------------- SC_BW_LANES at a time */

enum { LANES = SC_BW_LANES };

/* The rows of lanes.out: a Gaussian's gradient values in the order the outputs hold them. */
enum { OUT_MEANS = 0, OUT_SCALES = 3, OUT_QUATS = 6, OUT_LOGIT = 10, OUT_SH = 11,
       LANE_OUT = OUT_SH + 48 };

/* The inputs and results of LANES Gaussians, one array per value. */
typedef struct {
    double mean[3][LANES], ls[3][LANES], q[4][LANES], logit[LANES];
    double sx[LANES], sy[LANES], sdepth[LANES], sca[LANES], scc[LANES];
    double keep[3][LANES]; /* 1 where the forward's colour channel is above 0 (not clamped) */
    double d[SC_DG_COUNT][LANES];
    double sh[48][LANES];  /* the rendered coefficients, (K,3) order */
    float out[LANE_OUT][LANES]; /* the parameter gradients, as lane_out orders them */
    int64_t ok[LANES]; /* 0: leave the lane to the scalar code (a non-finite input or result,
                          stale, out of sc_exp_lane's range) */
} lanes;

/* backward_body for every lane, with the branches as selects (so the lane loop vectorises):
 * the same expressions in the same order, exp() by sc_exp_lane. `degree` is a constant at each
 * use (a build per degree), so the SH loops unroll. */
static SC_ALWAYS_INLINE void lanes_body(lanes *restrict L, const sc_camera *cam,
                                        const sc_options *opt, const double campos[3],
                                        const int degree) {
    double v[12];
    for (int k = 0; k < 12; ++k) v[k] = cam->world_to_camera[k];
    const double fx = cam->fx, fy = cam->fy, cx = cam->cx, cy = cam->cy, near = opt->near;
    const double tan_x = 0.5 * cam->width / fx, tan_y = 0.5 * cam->height / fy;
    const double lo_x = -(cx / fx) - SC_GUARD * tan_x, hi_x = (cam->width - cx) / fx + SC_GUARD * tan_x;
    const double lo_y = -(cy / fy) - SC_GUARD * tan_y, hi_y = (cam->height - cy) / fy + SC_GUARD * tan_y;
    const double cp0 = campos[0], cp1 = campos[1], cp2 = campos[2];
    const double aa = opt->antialiased ? 1.0 : 0.0;
    for (int l = 0; l < LANES; ++l) {
        /* ---- forward, as sc_ewa_project */
        const double m0 = L->mean[0][l], m1 = L->mean[1][l], m2 = L->mean[2][l];
        const double p0 = v[0] * m0 + v[1] * m1 + v[2] * m2 + v[3];
        const double p1 = v[4] * m0 + v[5] * m1 + v[6] * m2 + v[7];
        const double z = v[8] * m0 + v[9] * m1 + v[10] * m2 + v[11];
        const double rx = p0 / z, ry = p1 / z;
        const int clamped_x = rx < lo_x || rx > hi_x, clamped_y = ry < lo_y || ry > hi_y;
        const double tx = sc_clamp(rx, lo_x, hi_x), ty = sc_clamp(ry, lo_y, hi_y);
        const double j00 = fx / z, j02 = -fx * tx / z, j11 = fy / z, j12 = -fy * ty / z;
        const double q0 = L->q[0][l], q1 = L->q[1][l], q2 = L->q[2][l], q3 = L->q[3][l];
        const double q_norm2 = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3;
        const int has_q = q_norm2 > 0.0;
        const double q_inv = 1.0 / sqrt(has_q ? q_norm2 : 1.0);
        const double w = has_q ? q0 * q_inv : 1.0, x = has_q ? q1 * q_inv : 0.0;
        const double y = has_q ? q2 * q_inv : 0.0, zq = has_q ? q3 * q_inv : 0.0;
        const double r[9] = {1 - 2 * (y * y + zq * zq), 2 * (x * y - w * zq), 2 * (x * zq + w * y),
                             2 * (x * y + w * zq), 1 - 2 * (x * x + zq * zq), 2 * (y * zq - w * x),
                             2 * (x * zq - w * y), 2 * (y * zq + w * x), 1 - 2 * (x * x + y * y)};
        const double ls0 = L->ls[0][l], ls1 = L->ls[1][l], ls2 = L->ls[2][l];
        const double logit = L->logit[l];
        /* Whether the lane is fine: a count of failed conditions, added up as numbers, since
         * a chain of && (or &) of compares becomes branches, which stop the vectoriser. */
        double failed = (z >= near ? 0.0 : 1.0) + (z <= FLT_MAX ? 0.0 : 1.0);
        const double largest_input = sc_fmax_lane(sc_fmax_lane(fabs(ls0), fabs(ls1)),
                                                  sc_fmax_lane(fabs(ls2), fabs(logit)));
        const int in_range = largest_input <= 700.0;
        failed += in_range ? 0.0 : 1.0;
        /* Out of range (the lane goes to the scalar code): any value sc_exp_lane takes. */
        const double scale[3] = {sc_exp_lane(in_range ? ls0 : 0.0),
                                 sc_exp_lane(in_range ? ls1 : 0.0),
                                 sc_exp_lane(in_range ? ls2 : 0.0)};
        double m[2][3], af[2][3];
        for (int k = 0; k < 3; ++k) {
            m[0][k] = j00 * v[k] + j02 * v[8 + k];
            m[1][k] = j11 * v[4 + k] + j12 * v[8 + k];
        }
        for (int row = 0; row < 2; ++row)
            for (int k = 0; k < 3; ++k)
                af[row][k] = (m[row][0] * r[k] + m[row][1] * r[3 + k] + m[row][2] * r[6 + k]) *
                             scale[k];
        const double a0 = af[0][0] * af[0][0] + af[0][1] * af[0][1] + af[0][2] * af[0][2];
        const double b0 = af[0][0] * af[1][0] + af[0][1] * af[1][1] + af[0][2] * af[1][2];
        const double c0 = af[1][0] * af[1][0] + af[1][1] * af[1][1] + af[1][2] * af[1][2];
        const double a = a0 + SC_DILATION, b = b0, c = c0 + SC_DILATION;
        const double det = a * c - b * b;
        failed += (det > 0.0 ? 0.0 : 1.0) + (det <= DBL_MAX ? 0.0 : 1.0);
        const double sig = 1.0 / (1.0 + sc_exp_lane(in_range ? -logit : 0.0));
        const double e0 = m0 - cp0, e1 = m1 - cp1, e2 = m2 - cp2;
        const double len = sqrt(e0 * e0 + e1 * e1 + e2 * e2);
        const double dir[3] = {len > 0.0 ? e0 / len : 0.0, len > 0.0 ? e1 / len : 0.0,
                               len > 0.0 ? e2 / len : 0.0};
        const double half_trace = 0.5 * (a + c), spread = 0.5 * (a - c);
        const double largest = half_trace + sqrt(spread * spread + b * b);
        const double inv_det = 1.0 / det;
        const double kappa = largest * largest * inv_det;
        const double px = fx * p0 / z + cx, py = fy * p1 / z + cy;
        const double conic_tol = 1e-5 + 8.0 * FLT_EPSILON * kappa;
        const double ca_now = c * inv_det, cc_now = a * inv_det;
        failed += fabs(px - L->sx[l]) <= 1e-5 * (fabs(px) + 1.0) ? 0.0 : 1.0;
        failed += fabs(py - L->sy[l]) <= 1e-5 * (fabs(py) + 1.0) ? 0.0 : 1.0;
        failed += fabs(z - L->sdepth[l]) <= 1e-5 * (fabs(z) + 1.0) ? 0.0 : 1.0;
        failed += fabs(ca_now - L->sca[l]) <= conic_tol * (fabs(ca_now) + 1.0) ? 0.0 : 1.0;
        failed += fabs(cc_now - L->scc[l]) <= conic_tol * (fabs(cc_now) + 1.0) ? 0.0 : 1.0;

        /* ---- backward */
        const double d_ca = L->d[SC_DG_CA][l], d_cb = L->d[SC_DG_CB][l], d_cc = L->d[SC_DG_CC][l];
        const double inv_det2 = inv_det * inv_det;
        double da0 = (-c * c * d_ca + b * c * d_cb - b * b * d_cc) * inv_det2;
        double db0 = (2.0 * b * c * d_ca - (det + 2.0 * b * b) * d_cb + 2.0 * a * b * d_cc) * inv_det2;
        double dc0 = (-b * b * d_ca + a * b * d_cb - a * a * d_cc) * inv_det2;

        const double d_opacity = L->d[SC_DG_OPACITY][l];
        const double det_raw = a0 * c0 - b0 * b0, ratio = det_raw * inv_det;
        const double comp = sqrt(ratio > 0.0 ? ratio : 0.0);
        const double d_ratio = d_opacity * sig * 0.5 / (comp > 1e-6 ? comp : 1e-6);
        const double d_det_raw = d_ratio * inv_det, d_det = -d_ratio * ratio * inv_det;
        const int aa_terms = aa != 0.0 && ratio > 0.0;
        da0 = aa_terms ? da0 + (d_det_raw * c0 + d_det * c) : da0;
        dc0 = aa_terms ? dc0 + (d_det_raw * a0 + d_det * a) : dc0;
        db0 = aa_terms ? db0 + -2.0 * b0 * (d_det_raw + d_det) : db0;
        const double d_logit = aa != 0.0 ? d_opacity * comp * sig * (1.0 - sig)
                                  : d_opacity * sig * (1.0 - sig);

        double dA[2][3];
        for (int k = 0; k < 3; ++k) {
            dA[0][k] = 2.0 * da0 * af[0][k] + db0 * af[1][k];
            dA[1][k] = db0 * af[0][k] + 2.0 * dc0 * af[1][k];
        }
        double dM[2][3] = {{0}}, dR[9] = {0}, d_ls[3];
        for (int k = 0; k < 3; ++k) {
            d_ls[k] = dA[0][k] * af[0][k] + dA[1][k] * af[1][k];
            for (int row = 0; row < 2; ++row) {
                const double ds = dA[row][k] * scale[k];
                for (int n = 0; n < 3; ++n) {
                    dM[row][n] += ds * r[3 * n + k];
                    dR[3 * n + k] += m[row][n] * ds;
                }
            }
        }
        const double dj00 = dM[0][0] * v[0] + dM[0][1] * v[1] + dM[0][2] * v[2];
        const double dj02 = dM[0][0] * v[8] + dM[0][1] * v[9] + dM[0][2] * v[10];
        const double dj11 = dM[1][0] * v[4] + dM[1][1] * v[5] + dM[1][2] * v[6];
        const double dj12 = dM[1][0] * v[8] + dM[1][1] * v[9] + dM[1][2] * v[10];
        const double inv_z = 1.0 / z, inv_z2 = inv_z * inv_z, inv_z3 = inv_z2 * inv_z;
        const double fx_z2 = fx * inv_z2, fy_z2 = fy * inv_z2;
        double dp0 = 0.0, dp1 = 0.0, dp2 = 0.0;
        dp2 -= dj00 * fx_z2 + dj11 * fy_z2;
        dp2 = clamped_x ? dp2 + dj02 * fx_z2 * tx : dp2 + dj02 * 2.0 * fx * p0 * inv_z3;
        dp0 = clamped_x ? dp0 : dp0 - dj02 * fx_z2;
        dp2 = clamped_y ? dp2 + dj12 * fy_z2 * ty : dp2 + dj12 * 2.0 * fy * p1 * inv_z3;
        dp1 = clamped_y ? dp1 : dp1 - dj12 * fy_z2;
        const double d_x = L->d[SC_DG_X][l], d_y = L->d[SC_DG_Y][l];
        dp0 += d_x * fx * inv_z;
        dp1 += d_y * fy * inv_z;
        dp2 += -(d_x * fx * p0 + d_y * fy * p1) * inv_z2 + L->d[SC_DG_DEPTH][l];
        double d_mean[3];
        for (int k = 0; k < 3; ++k) d_mean[k] = v[k] * dp0 + v[4 + k] * dp1 + v[8 + k] * dp2;

        /* Colour: as sc_sh_backward for `degree`. */
        const double d_rgb[3] = {L->keep[0][l] * L->d[SC_DG_R][l], L->keep[1][l] * L->d[SC_DG_G][l],
                                 L->keep[2][l] * L->d[SC_DG_B][l]};
        double basis[16], gx[16] = {0}, gy[16] = {0}, gz[16] = {0};
        sc_sh_basis_grad(degree, dir[0], dir[1], dir[2], basis, gx, gy, gz);
        double d_dir0 = 0.0, d_dir1 = 0.0, d_dir2 = 0.0;
        SC_UNROLL_ALL /* no inner loop may stay: the lane loop would not vectorise */
        for (int i = 0; i < (degree + 1) * (degree + 1); ++i) {
            const double along = L->sh[3 * i][l] * d_rgb[0] + L->sh[3 * i + 1][l] * d_rgb[1] +
                                 L->sh[3 * i + 2][l] * d_rgb[2];
            for (int ch = 0; ch < 3; ++ch) L->out[OUT_SH + 3 * i + ch][l] = (float)(basis[i] * d_rgb[ch]);
            d_dir0 += gx[i] * along;
            d_dir1 += gy[i] * along;
            d_dir2 += gz[i] * along;
        }
        const double along_dir = d_dir0 * dir[0] + d_dir1 * dir[1] + d_dir2 * dir[2];
        const double inv_len = 1.0 / (len > 0.0 ? len : 1.0);
        const int has_len = len > 0.0;
        const double d_dir[3] = {d_dir0, d_dir1, d_dir2};
        for (int k = 0; k < 3; ++k)
            d_mean[k] = has_len ? d_mean[k] + (d_dir[k] - along_dir * dir[k]) * inv_len
                                      : d_mean[k];

        /* Rotation -> normalised quaternion -> quaternion (0 for a zero quaternion). */
        const double dqw = 2.0 * (-zq * dR[1] + y * dR[2] + zq * dR[3] - x * dR[5] - y * dR[6] +
                                  x * dR[7]);
        const double dqx = 2.0 * (y * dR[1] + zq * dR[2] + y * dR[3] - 2.0 * x * dR[4] -
                                  w * dR[5] + zq * dR[6] + w * dR[7] - 2.0 * x * dR[8]);
        const double dqy = 2.0 * (-2.0 * y * dR[0] + x * dR[1] + w * dR[2] + x * dR[3] +
                                  zq * dR[5] - w * dR[6] + zq * dR[7] - 2.0 * y * dR[8]);
        const double dqz = 2.0 * (-2.0 * zq * dR[0] - w * dR[1] + x * dR[2] + w * dR[3] -
                                  2.0 * zq * dR[4] + y * dR[5] + x * dR[6] + y * dR[7]);
        const double along_q = dqw * w + dqx * x + dqy * y + dqz * zq;
        const double inv_qnorm = q_inv; /* 1 / sqrt(|q|^2) */
        const double dq[4] = {has_q ? (dqw - along_q * w) * inv_qnorm : 0.0,
                              has_q ? (dqx - along_q * x) * inv_qnorm : 0.0,
                              has_q ? (dqy - along_q * y) * inv_qnorm : 0.0,
                              has_q ? (dqz - along_q * zq) * inv_qnorm : 0.0};

        /* ---- results, in float; a non-finite one (or input) sends the lane to the scalar
         * code, which flushes and counts it. x * 0 is 0 exactly when x is finite. */
        for (int k = 0; k < 3; ++k) {
            L->out[OUT_MEANS + k][l] = (float)d_mean[k];
            L->out[OUT_SCALES + k][l] = (float)d_ls[k];
        }
        for (int k = 0; k < 4; ++k) L->out[OUT_QUATS + k][l] = (float)dq[k];
        L->out[OUT_LOGIT][l] = (float)d_logit;
        float zero = 0.0f;
        SC_UNROLL_ALL
        for (int k = 0; k < OUT_SH + 3 * (degree + 1) * (degree + 1); ++k) zero += L->out[k][l] * 0.0f;
        double zero_in = (m0 + m1 + m2 + ls0 + ls1 + ls2 + q0 + q1 + q2 + q3 + logit) * 0.0;
        SC_UNROLL_ALL
        for (int k = 0; k < 3 * (degree + 1) * (degree + 1); ++k) zero_in += L->sh[k][l] * 0.0;
        SC_UNROLL_ALL
        for (int q = 0; q < SC_DG_COUNT; ++q) zero_in += L->d[q][l] * 0.0;
        failed += zero == 0.0f && zero_in == 0.0 ? 0.0 : 1.0;
        L->ok[l] = failed == 0.0;
    }
}

#define SC_LANES_DEGREE(d)                                                                         \
    SC_MULTIVERSION(void, lanes_degree##d,                                                         \
                    (lanes * L, const sc_camera *cam, const sc_options *opt,                       \
                     const double campos[3]),                                                      \
                    (L, cam, opt, campos), lanes_body(L, cam, opt, campos, d))
SC_LANES_DEGREE(0)
SC_LANES_DEGREE(1)
SC_LANES_DEGREE(2)
SC_LANES_DEGREE(3)

int sc_project_backward_lanes(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                              const double campos[3], int n, const int64_t *index,
                              const sc_splat *const *splats, const float *const *d,
                              sc_gaussian_grads *out, int64_t *flushed, int *results) {
    lanes L;
    const int degree = opt->sh_degree < 0 ? 0 : opt->sh_degree > 3 ? 3 : opt->sh_degree;
    const int used = 3 * (degree + 1) * (degree + 1);
    for (int l = 0; l < LANES; ++l) { /* a short batch repeats its last Gaussian */
        const int from = l < n ? l : n - 1;
        const int64_t i = index[from];
        const sc_splat *s = splats[from];
        for (int k = 0; k < 3; ++k) {
            L.mean[k][l] = g->means[3 * i + k];
            L.ls[k][l] = g->log_scales[3 * i + k];
        }
        for (int k = 0; k < 4; ++k) L.q[k][l] = g->quats[4 * i + k];
        L.logit[l] = g->opacity_logits[i];
        L.sx[l] = s->x, L.sy[l] = s->y, L.sdepth[l] = s->depth, L.sca[l] = s->ca, L.scc[l] = s->cc;
        L.keep[0][l] = s->r > 0.0f, L.keep[1][l] = s->g > 0.0f, L.keep[2][l] = s->b > 0.0f;
        for (int q = 0; q < SC_DG_COUNT; ++q) L.d[q][l] = d[from][q];
        const float *sh = g->sh + (int64_t)3 * g->sh_coeffs * i;
        for (int k = 0; k < used; ++k) L.sh[k][l] = sh[k];
    }
    switch (degree) {
    case 0: lanes_degree0(&L, cam, opt, campos); break;
    case 1: lanes_degree1(&L, cam, opt, campos); break;
    case 2: lanes_degree2(&L, cam, opt, campos); break;
    default: lanes_degree3(&L, cam, opt, campos); break;
    }
    int problems = 0;
    const int64_t k3 = (int64_t)3 * g->sh_coeffs;
    for (int l = 0; l < n; ++l) {
        const int64_t i = index[l];
        if (!L.ok[l]) { /* the scalar code decides (and reports) */
            double dd[SC_DG_COUNT];
            for (int q = 0; q < SC_DG_COUNT; ++q) dd[q] = d[l][q];
            results[l] = sc_project_backward_gaussian(g, cam, opt, campos, i, splats[l], dd, out,
                                                      flushed);
            problems += results[l] != 0;
            continue;
        }
        results[l] = 0;
        for (int k = 0; k < 3; ++k) {
            out->means[3 * i + k] = L.out[OUT_MEANS + k][l];
            out->log_scales[3 * i + k] = L.out[OUT_SCALES + k][l];
        }
        for (int k = 0; k < 4; ++k) out->quats[4 * i + k] = L.out[OUT_QUATS + k][l];
        out->opacity_logits[i] = L.out[OUT_LOGIT][l];
        float *osh = out->sh + k3 * i;
        for (int k = 0; k < used; ++k) osh[k] = L.out[OUT_SH + k][l];
        memset(osh + used, 0, sizeof(float) * (size_t)(k3 - used));
        const float *dl = d[l]; /* finite: sums of finite records (else the lane is not ok) */
        out->xy[2 * i] = dl[SC_DG_X];
        out->xy[2 * i + 1] = dl[SC_DG_Y];
        out->xy_abs[2 * i] = dl[SC_DG_ABS_X];
        out->xy_abs[2 * i + 1] = dl[SC_DG_ABS_Y];
    }
    return problems;
}
