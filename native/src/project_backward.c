/* Projection backward: one Gaussian's summed splat gradient (projected mean, conic, opacity,
 * colour, depth) back to its parameters, in double, through exactly the forward's chain
 * (project.c): conic = inverse of Sigma2 = A A^T + 0.3 I with the 2x3 factor A = J W R S,
 * the guard-band clamp inside J, the quaternion normalisation, exp of the log scales, the
 * opacity sigmoid (and the antialiasing compensation), the SH colour with its clamp and its
 * view direction. The forward's intermediate values are recomputed here (O(1) per Gaussian),
 * which also checks that the Gaussian still projects to what the forward drew.
 * Scalar double code, compiled per instruction-set level (SC_MULTIVERSION): FMA and three-operand
 * forms make it about 15% faster where the CPU has them. */
#include <float.h>
#include <math.h>

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
