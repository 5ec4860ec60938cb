/* Projection: each Gaussian to a 2D splat (EWA with the guard band, 0.3 px dilation, optional
 * antialiasing compensation), its SH colour, and the exact extent of its alpha >= 1/255 footprint.
 * Per-Gaussian math runs in double: it costs O(N), keeps scenes far from the origin exact, and
 * leaves float32 only for the compositor's per-pixel work. */
#include <float.h>
#include <math.h>
#include <stdatomic.h>
#include <string.h>

#include "internal.h"

typedef struct {
    const sc_gaussians *g;
    const sc_camera *cam;
    const sc_options *opt;
    sc_projection *out;
    double campos[3];
    atomic_llong first_bad; /* smallest index holding a non-finite value, or count */
} job;

static double clampd(double v, double lo, double hi) { return v < lo ? lo : (v > hi ? hi : v); }

/* Rotation matrix (row-major) of a quaternion w,x,y,z; normalises; zero means identity. */
static void quat_to_matrix(const float *q, double r[9]) {
    double w = q[0], x = q[1], y = q[2], z = q[3];
    double n2 = w * w + x * x + y * y + z * z;
    if (n2 > 0.0) {
        double inv = 1.0 / sqrt(n2);
        w *= inv, x *= inv, y *= inv, z *= inv;
    } else {
        w = 1.0, x = y = z = 0.0;
    }
    r[0] = 1 - 2 * (y * y + z * z), r[1] = 2 * (x * y - w * z), r[2] = 2 * (x * z + w * y);
    r[3] = 2 * (x * y + w * z), r[4] = 1 - 2 * (x * x + z * z), r[5] = 2 * (y * z - w * x);
    r[6] = 2 * (x * z - w * y), r[7] = 2 * (y * z + w * x), r[8] = 1 - 2 * (x * x + y * y);
}

/* Pixel-centre index range [lo, hi] covered by the interval [c - r, c + r], clipped to [0, n). */
static void pixel_range(double c, double r, int n, int32_t *lo, int32_t *hi) {
    double a = ceil(clampd(c - r - 0.5, -1.0, (double)n));
    double b = floor(clampd(c + r - 0.5, -1.0, (double)n));
    *lo = (int32_t)(a < 0 ? 0 : a);
    *hi = (int32_t)(b > n - 1 ? n - 1 : b);
}

/* Returns 1 when projected, 0 when culled, -1 on non-finite input. */
static int project_one(const job *j, int64_t i, sc_splat *s, sc_footprint *f) {
    const sc_gaussians *g = j->g;
    const sc_camera *cam = j->cam;
    const float *mean = g->means + 3 * i, *ls = g->log_scales + 3 * i, *q = g->quats + 4 * i;
    const float *sh = g->sh + (int64_t)3 * g->sh_coeffs * i;
    if (!sc_gaussian_finite(g, i)) return -1;

    const double *v = cam->world_to_camera;
    double p[3];
    sc_to_camera(v, mean, p);
    const double z = p[2];
    /* Screen values are float32: a depth beyond its range (a camera translation near 1e38)
     * would be stored as inf, so such a Gaussian is culled, never valid. */
    if (!(z >= j->opt->near) || !(z <= FLT_MAX)) return 0;

    /* EWA Jacobian with x/z and y/z clamped to the guard band (inside J only). */
    const double fx = cam->fx, fy = cam->fy, cx = cam->cx, cy = cam->cy;
    const double tan_x = 0.5 * cam->width / fx, tan_y = 0.5 * cam->height / fy;
    const double tx = clampd(p[0] / z, -(cx / fx) - SC_GUARD * tan_x,
                             (cam->width - cx) / fx + SC_GUARD * tan_x);
    const double ty = clampd(p[1] / z, -(cy / fy) - SC_GUARD * tan_y,
                             (cam->height - cy) / fy + SC_GUARD * tan_y);
    const double j00 = fx / z, j02 = -fx * tx / z, j11 = fy / z, j12 = -fy * ty / z;

    /* Sigma2 = J W R S S^T R^T W^T J^T = A A^T with the 2x3 factor A = J W R S:
     * fewer operations than forming the 3x3 covariances, and symmetric by construction. */
    double r[9], jw[2][3], a_rows[2][3];
    quat_to_matrix(q, r);
    const double scale[3] = {exp((double)ls[0]), exp((double)ls[1]), exp((double)ls[2])};
    for (int k = 0; k < 3; ++k) {
        jw[0][k] = j00 * v[k] + j02 * v[8 + k];
        jw[1][k] = j11 * v[4 + k] + j12 * v[8 + k];
    }
    for (int row = 0; row < 2; ++row)
        for (int k = 0; k < 3; ++k)
            a_rows[row][k] = (jw[row][0] * r[k] + jw[row][1] * r[3 + k] + jw[row][2] * r[6 + k]) *
                             scale[k];
    const double *a0v = a_rows[0], *a1v = a_rows[1];
    const double a0 = a0v[0] * a0v[0] + a0v[1] * a0v[1] + a0v[2] * a0v[2];
    const double b0 = a0v[0] * a1v[0] + a0v[1] * a1v[1] + a0v[2] * a1v[2];
    const double c0 = a1v[0] * a1v[0] + a1v[1] * a1v[1] + a1v[2] * a1v[2];
    const double a = a0 + SC_DILATION, b = b0, c = c0 + SC_DILATION;
    const double det = a * c - b * b;
    if (!(det > 0.0) || !isfinite(det)) return 0;

    double opacity = 1.0 / (1.0 + exp(-(double)g->opacity_logits[i]));
    if (j->opt->antialiased) {
        const double ratio = (a0 * c0 - b0 * b0) / det;
        opacity *= sqrt(ratio > 0.0 ? ratio : 0.0);
    }

    double dir[3], rgb[3];
    for (int k = 0; k < 3; ++k) dir[k] = (double)mean[k] - j->campos[k];
    const double len = sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
    for (int k = 0; k < 3; ++k) dir[k] = len > 0.0 ? dir[k] / len : 0.0;
    sc_sh_colour(j->opt->sh_degree, sh, dir, rgb);

    s->x = (float)(fx * p[0] / z + cx);
    s->y = (float)(fy * p[1] / z + cy);
    if (!isfinite(s->x) || !isfinite(s->y)) return 0; /* beyond float32: off screen, culled */
    s->ca = (float)(c / det);
    s->cb = (float)(-b / det);
    s->cc = (float)(a / det);
    s->opacity = (float)opacity;
    s->r = (float)fmax(rgb[0] + 0.5, 0.0);
    s->g = (float)fmax(rgb[1] + 0.5, 0.0);
    s->b = (float)fmax(rgb[2] + 0.5, 0.0);
    s->depth = (float)z;

    /* The compositor draws where opacity * exp(power) >= 1/255, i.e. inside the ellipse
     * d^T cov^-1 d <= 2 ln(255 opacity). Inflated by 1e-4 so float rounding in the compositor
     * can never put a drawn pixel outside the tiles found here. */
    f->cov_a = a, f->cov_b = b, f->cov_c = c;
    f->tx0 = f->ty0 = f->tx1 = f->ty1 = 0;
    s->row0 = s->col0 = 0, s->row1 = s->col1 = -1;
    if (!(s->opacity >= SC_ALPHA_MIN)) return 1;
    f->k2 = 2.0 * log(255.0 * (double)s->opacity) * (1.0 + 1e-4) + 1e-4;
    int32_t x0, x1, y0, y1;
    pixel_range(s->x, sqrt(f->k2 * a), cam->width, &x0, &x1);
    pixel_range(s->y, sqrt(f->k2 * c), cam->height, &y0, &y1);
    if (x0 > x1 || y0 > y1) return 1;
    s->row0 = y0, s->row1 = y1, s->col0 = x0, s->col1 = x1;
    f->tx0 = x0 / SC_TILE, f->tx1 = x1 / SC_TILE + 1;
    f->ty0 = y0 / SC_TILE, f->ty1 = y1 / SC_TILE + 1;
    return 1;
}

static void project_range(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    job *j = ctx;
    for (int64_t i = begin; i < end; ++i) {
        sc_splat *s = &j->out->splats[i];
        sc_footprint *f = &j->out->footprints[i];
        int result = project_one(j, i, s, f);
        if (result != 1) {
            memset(s, 0, sizeof *s);
            memset(f, 0, sizeof *f);
            s->row1 = s->col1 = -1;
        }
        j->out->valid[i] = (uint8_t)(result == 1);
        if (result < 0) {
            long long seen = atomic_load(&j->first_bad);
            while (i < seen && !atomic_compare_exchange_weak(&j->first_bad, &seen, i)) {
            }
            return;
        }
    }
}

sc_status sc_project(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                     sc_projection *out, sc_stats *stats) {
    job j = {.g = g, .cam = cam, .opt = opt, .out = out};
    atomic_init(&j.first_bad, g->count);
    /* Camera centre in world space: -R^T t. */
    const double *v = cam->world_to_camera;
    for (int k = 0; k < 3; ++k)
        j.campos[k] = -(v[k] * v[3] + v[4 + k] * v[7] + v[8 + k] * v[11]);
    sc_parallel_for(opt->threads, g->count, 4096, project_range, &j);
    long long bad = atomic_load(&j.first_bad);
    if (bad < g->count) {
        stats->error_index = bad;
        return SC_ERR_NONFINITE;
    }
    return SC_OK;
}
