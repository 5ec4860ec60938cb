/* Projection through panoramic cameras (equirectangular, fisheye equidistant, equisolid and lens
 * polynomial, mirror ball, equiangular cubemap face, central cylindrical): Cycles' mappings from a camera-space direction to its normalised image (u, v),
 * written in this library's camera frame (x right, y down, z forward; docs/conventions.md,
 * "Cameras beyond the pinhole"). Each Gaussian is drawn with the local Jacobian of the mapping
 * at its mean, EWA on the sphere: Sigma2 = J W Sigma W^T J^T + 0.3 I, exact to first order about
 * the mean, as the pinhole's EWA is. Depth is the distance |p| from the camera centre (what
 * Cycles' Depth pass holds for panoramas), so Gaussians are sorted and composed by distance.
 *
 * The seam (equirectangular and central cylindrical): with a full 360 degrees of longitude the
 * image repeats with period
 * P = 2 pi fx / (longitude range) pixels, and a Gaussian whose footprint crosses the left or right
 * edge also gets a copy one period over (row N + i of the projection), so it is drawn on both
 * sides, not cut. Its footprint is at most P/2 wide each side, so no pixel sees both. A Gaussian
 * wider than that (near a pole, where longitude changes fast, or around the camera) is drawn as a
 * band all around: constant along x, its latitude profile the marginal of its covariance.
 *
 * In double, one Gaussian at a time: the transcendental functions dominate, and panoramas are
 * for final renders. */
#include <float.h>
#include <math.h>
#include <stdatomic.h>
#include <string.h>

#include "internal.h"

#define TWO_PI 6.283185307179586
#define PI 3.141592653589793

typedef struct {
    sc_projection_pass p;
    double period; /* pixels, when the image wraps; else 0 */
    int cull;
    atomic_llong first_bad;
} pano_job;

/* A radial mapping (the fisheyes and the mirror ball): the image point is
 * (0.5 + su g(theta) x / rho, 0.5 - sv g(theta) y / rho), theta the angle from the axis, rho the
 * distance from it; g' its derivative. Returns 0 beyond the mapping's field of view. */
static int radial(const sc_camera *cam, double theta, double *g, double *dg, double *su,
                  double *sv) {
    const double *k = cam->params;
    switch (cam->model) {
    case SC_FISHEYE_EQUIDISTANT: /* Cycles' fisheye_to_direction: theta = r fov / 2 */
        *g = 2.0 * theta / k[0], *dg = 2.0 / k[0], *su = *sv = 0.5;
        return theta <= 0.5 * k[0];
    case SC_FISHEYE_EQUISOLID: /* r = 2 lens sin(theta / 2) on a sensor of k[2] x k[3] mm */
        *g = 2.0 * k[0] * sin(0.5 * theta), *dg = k[0] * cos(0.5 * theta);
        *su = 1.0 / k[2], *sv = 1.0 / k[3];
        return theta <= 0.5 * k[1];
    case SC_FISHEYE_POLYNOMIAL: { /* theta = -p(r), p = k0 + k1 r + ... + k4 r^4: r by Newton */
        double r = -(theta + k[0]) / k[1], dp = k[1];
        for (int it = 0; it < 40; ++it) {
            const double p = k[0] + r * (k[1] + r * (k[2] + r * (k[3] + r * k[4]))) + theta;
            dp = k[1] + r * (2.0 * k[2] + r * (3.0 * k[3] + r * 4.0 * k[4]));
            const double step = p / dp;
            r -= step;
            if (!(fabs(step) > 1e-13 * (1.0 + fabs(r)))) break;
        }
        r = r > 0.0 ? r : 0.0; /* within -k0 of the axis: the image centre */
        dp = k[1] + r * (2.0 * k[2] + r * (3.0 * k[3] + r * 4.0 * k[4]));
        *g = r, *dg = -1.0 / dp, *su = 1.0 / k[6], *sv = 1.0 / k[7];
        return theta <= 0.5 * k[5] && isfinite(r) && isfinite(*dg) && *dg > 0.0;
    }
    default: /* SC_MIRRORBALL: the ball's normal bisects the view and the reflected ray. Straight
              * behind (within 1e-3 rad) maps onto the whole rim: not drawn. */
        *g = sin(0.5 * theta), *dg = 0.5 * cos(0.5 * theta), *su = *sv = 0.5;
        return theta < PI - 1e-3;
    }
}

/* The normalised image point (u, v), v up, of camera-space point p, and its Jacobian d(u, v)/dp.
 * Returns 0 where the mapping shows nothing of p. jac[0] may be infinite at an equirectangular
 * pole (its longitude is undefined there). */
static int map_point(const sc_camera *cam, const double p[3], double uv[2], double jac[2][3]) {
    const double x = p[0], y = p[1], z = p[2];
    const double *k = cam->params;
    if (cam->model == SC_EQUIRECTANGULAR) {
        /* longitude atan2(x, z) (0 ahead, positive to the right), latitude asin(-y / r) */
        const double h2 = x * x + z * z, h = sqrt(h2), r2 = h2 + y * y;
        if (!(r2 > 0.0)) return 0;
        const double du = 1.0 / (k[1] - k[0]), dv = 1.0 / (k[3] - k[2]);
        uv[0] = (atan2(x, z) - k[0]) * du;
        uv[1] = (atan2(-y, h) - k[2]) * dv;
        const double inv_h2 = h2 > 0.0 ? 1.0 / h2 : INFINITY;
        jac[0][0] = du * z * inv_h2, jac[0][1] = 0.0, jac[0][2] = -du * x * inv_h2;
        if (h2 == 0.0) jac[0][0] = jac[0][2] = INFINITY;
        const double hs = h > 0.0 ? h : 1e-300, s = dv * y / (hs * r2);
        jac[1][0] = s * x, jac[1][1] = -dv * h / r2, jac[1][2] = s * z;
        return 1;
    }
    if (cam->model == SC_CENTRAL_CYLINDRICAL) {
        /* u: the longitude, as above; v: the height -y / |(x, z)| on the unit cylinder. Straight
         * up or down is infinitely far along it: not drawn. */
        const double h2 = x * x + z * z, h = sqrt(h2);
        if (!(h2 > 0.0)) return 0;
        const double du = 1.0 / (k[1] - k[0]), dv = 1.0 / (k[3] - k[2]), inv_h2 = 1.0 / h2;
        uv[0] = (atan2(x, z) - k[0]) * du;
        uv[1] = (-y / h - k[2]) * dv;
        const double s = dv * y * inv_h2 / h;
        jac[0][0] = du * z * inv_h2, jac[0][1] = 0.0, jac[0][2] = -du * x * inv_h2;
        jac[1][0] = s * x, jac[1][1] = -dv / h, jac[1][2] = s * z;
        return 1;
    }
    if (cam->model == SC_EQUIANGULAR_CUBEMAP_FACE) {
        /* The face ahead, 90 degrees each way: u = 1/2 + atan2(x, z) 2/pi, v = 1/2 +
         * atan2(-y, z) 2/pi. Behind (z <= 0) atan2 jumps and the face shows nothing. */
        if (!(z > 0.0)) return 0;
        const double s = 2.0 / PI, qx = s / (x * x + z * z), qy = s / (y * y + z * z);
        uv[0] = 0.5 + s * atan2(x, z);
        uv[1] = 0.5 + s * atan2(-y, z);
        jac[0][0] = qx * z, jac[0][1] = 0.0, jac[0][2] = -qx * x;
        jac[1][0] = 0.0, jac[1][1] = -qy * z, jac[1][2] = qy * y;
        return 1;
    }
    const double rho2 = x * x + y * y, rho = sqrt(rho2), r2 = rho2 + z * z;
    if (!(r2 > 0.0)) return 0;
    const double theta = atan2(rho, z);
    double g, dg, su, sv;
    if (!radial(cam, theta, &g, &dg, &su, &sv)) return 0;
    if (rho <= 1e-12 * sqrt(r2)) { /* on the axis, ahead: g(theta) / rho -> g'(0) / z */
        uv[0] = uv[1] = 0.5;
        jac[0][0] = su * dg / z, jac[0][1] = jac[0][2] = 0.0;
        jac[1][1] = -sv * dg / z, jac[1][0] = jac[1][2] = 0.0;
        return 1;
    }
    const double ex = x / rho, ey = y / rho, inv_rho = 1.0 / rho;
    uv[0] = 0.5 + su * g * ex;
    uv[1] = 0.5 - sv * g * ey;
    const double dtheta[3] = {z * ex / r2, z * ey / r2, -rho / r2};
    const double dex[3] = {ey * ey * inv_rho, -ex * ey * inv_rho, 0.0};
    const double dey[3] = {-ex * ey * inv_rho, ex * ex * inv_rho, 0.0};
    for (int c = 0; c < 3; ++c) {
        jac[0][c] = su * (dg * ex * dtheta[c] + g * dex[c]);
        jac[1][c] = -sv * (dg * ey * dtheta[c] + g * dey[c]);
    }
    return 1;
}

/* Gaussian i into `s` (and its seam copy into `copy`, row1 < row0 when none). Returns 1 when it
 * projects, 0 when culled. Inputs are finite. */
static int project_gaussian(const pano_job *j, int64_t i, sc_splat *s, sc_splat *copy) {
    const sc_gaussians *g = j->p.g;
    const sc_camera *cam = j->p.cam;
    *copy = (sc_splat){.row1 = -1, .col1 = -1};
    double p[3], uv[2], jac[2][3];
    sc_to_camera(cam->world_to_camera, g->means + 3 * i, p);
    const double depth = sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
    if (!(depth >= j->p.opt->near) || !(depth <= sc_far(cam))) return 0;
    if (!map_point(cam, p, uv, jac)) return 0;
    const double logit = g->opacity_logits[i];
    if (j->cull && logit < -5.6) return 0; /* sigmoid < 1/271: draws nothing */

    /* J in pixels: col = fx u + cx, row = cy - fy v. */
    if (j->period > 0.0) uv[0] -= floor(uv[0]); /* longitude into the image's period */
    double jp[2][3];
    for (int c = 0; c < 3; ++c) jp[0][c] = cam->fx * jac[0][c], jp[1][c] = -cam->fy * jac[1][c];
    /* A = J W R S; Sigma2 = A A^T (+ dilation). */
    const double *v = cam->world_to_camera;
    double q[4], r[9], jw[2][3], a[2][3];
    sc_quat_rotation(g->quats + 4 * i, q, r);
    for (int row = 0; row < 2; ++row)
        for (int c = 0; c < 3; ++c)
            jw[row][c] = jp[row][0] * v[c] + jp[row][1] * v[4 + c] + jp[row][2] * v[8 + c];
    for (int row = 0; row < 2; ++row)
        for (int c = 0; c < 3; ++c)
            a[row][c] = (jw[row][0] * r[c] + jw[row][1] * r[3 + c] + jw[row][2] * r[6 + c]) *
                        exp((double)g->log_scales[3 * i + c]);
    const double c0 = a[1][0] * a[1][0] + a[1][1] * a[1][1] + a[1][2] * a[1][2];
    double a0 = a[0][0] * a[0][0] + a[0][1] * a[0][1] + a[0][2] * a[0][2];
    double b0 = a[0][0] * a[1][0] + a[0][1] * a[1][1] + a[0][2] * a[1][2];
    if (!isfinite(a0) || !isfinite(b0)) a0 = INFINITY, b0 = 0.0;
    double opacity = sc_sigmoid(g->opacity_logits[i]);
    const double k2 = 2.0 * log(255.0 * opacity) * (1.0 + 1e-4) + 1e-4; /* as sc_footprint */
    const double ca_cov = a0 + SC_DILATION, cc_cov = c0 + SC_DILATION;
    const int band = j->period > 0.0 && !(k2 * ca_cov <= 0.25 * j->period * j->period);
    if (!isfinite(cc_cov) || (!band && !isfinite(ca_cov))) return 0;
    double ca, cb, cc, det0, det;
    if (band) { /* all around: constant along x, the latitude marginal along y */
        ca = cb = 0.0, cc = 1.0 / cc_cov, det0 = c0, det = cc_cov;
    } else {
        det = ca_cov * cc_cov - b0 * b0;
        if (!(det > 0.0) || !isfinite(det)) return 0;
        det0 = a0 * c0 - b0 * b0;
        ca = cc_cov / det, cb = -b0 / det, cc = ca_cov / det;
    }
    if (j->p.opt->antialiased) opacity *= sqrt(det0 / det > 0.0 ? det0 / det : 0.0);

    *s = (sc_splat){.x = (float)(cam->fx * uv[0] + cam->cx), .y = (float)(cam->cy - cam->fy * uv[1]),
                    .ca = (float)ca, .cb = (float)cb, .cc = (float)cc, .opacity = (float)opacity,
                    .depth = (float)depth};
    if (!isfinite(s->x) || !isfinite(s->y)) return 0;
    sc_footprint(s, cam);
    if (j->period > 0.0 && !band) {
        *copy = *s;
        copy->x = (float)(s->x + (uv[0] < 0.5 ? j->period : -j->period));
        sc_footprint(copy, cam);
    }
    const int reaches = (s->row1 >= s->row0 && s->col1 >= s->col0) ||
                        (copy->row1 >= copy->row0 && copy->col1 >= copy->col0);
    if (j->cull && !reaches) return 0;

    double dir[3];
    sc_view_dir(g->means + 3 * i, j->p.campos, dir);
    const float dir_f[3] = {(float)dir[0], (float)dir[1], (float)dir[2]};
    float rgb[3];
    sc_sh_colour_f(j->p.opt->sh_degree, g->sh + (int64_t)3 * g->sh_coeffs * i, dir_f, rgb);
    s->r = fmaxf(rgb[0] + 0.5f, 0.0f), s->g = fmaxf(rgb[1] + 0.5f, 0.0f);
    s->b = fmaxf(rgb[2] + 0.5f, 0.0f);
    copy->r = s->r, copy->g = s->g, copy->b = s->b;
    return 1;
}

static void finish(const sc_projection *out, int64_t row, const sc_splat *s, int valid) {
    out->splats[row] = *s;
    if (out->valid) out->valid[row] = (uint8_t)valid;
    if (out->keys)
        out->keys[row] = valid && s->row1 >= s->row0 && s->col1 >= s->col0 ? s->depth : INFINITY;
}

static void project_range(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    pano_job *j = ctx;
    const int64_t n = j->p.g->count;
    for (int64_t i = begin; i < end; ++i) {
        if (!sc_gaussian_finite(j->p.g, i)) {
            long long seen = atomic_load(&j->first_bad);
            while (i < seen && !atomic_compare_exchange_weak(&j->first_bad, &seen, i)) {
            }
            return;
        }
        sc_splat s = {.row1 = -1, .col1 = -1}, copy;
        const int ok = project_gaussian(j, i, &s, &copy);
        if (!ok) s = (sc_splat){.row1 = -1, .col1 = -1}, copy = s;
        finish(j->p.out, i, &s, ok);
        if (j->p.out->wrap_rows) finish(j->p.out, n + i, &copy, ok && copy.row1 >= copy.row0);
    }
}

sc_status sc_project_panorama(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                              int cull, sc_projection *out, sc_stats *stats) {
    pano_job j = {.p = {.g = g, .cam = cam, .opt = opt, .out = out}, .cull = cull};
    atomic_init(&j.first_bad, g->count);
    sc_camera_centre(cam->world_to_camera, j.p.campos);
    if (sc_wraps(cam)) j.period = cam->fx * TWO_PI / (cam->params[1] - cam->params[0]);
    sc_parallel_for(opt->threads, g->count, 1024, project_range, &j);
    const long long bad = atomic_load(&j.first_bad);
    if (bad < g->count) {
        stats->error_index = bad;
        return SC_ERR_NONFINITE;
    }
    return SC_OK;
}
