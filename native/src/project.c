/* Projection: each Gaussian to a 2D splat (EWA with the guard band, 0.3 px dilation, optional
 * antialiasing compensation), its SH colour, and the exact extent of its alpha >= 1/255 footprint.
 * Per-Gaussian math runs in double: it costs O(N), keeps scenes far from the origin exact, and
 * leaves float32 only for the compositor's per-pixel work. */
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

/* Pixel-centre index range [lo, hi] covered by the interval [c - r, c + r], clipped to [0, n). */
static void pixel_range(double c, double r, int n, int32_t *lo, int32_t *hi) {
    double a = ceil(sc_clamp(c - r - 0.5, -1.0, (double)n));
    double b = floor(sc_clamp(c + r - 0.5, -1.0, (double)n));
    *lo = (int32_t)(a < 0 ? 0 : a);
    *hi = (int32_t)(b > n - 1 ? n - 1 : b);
}

/* Returns 1 when projected, 0 when culled, -1 on non-finite input. */
static int project_one(const job *j, int64_t i, sc_splat *s, sc_footprint *f) {
    const sc_gaussians *g = j->g;
    const sc_camera *cam = j->cam;
    if (!sc_gaussian_finite(g, i)) return -1;
    sc_ewa e;
    if (!sc_ewa_project(g, i, cam, j->opt->near, &e)) return 0;
    const double a = e.a, b = e.b, c = e.c, det = e.det;

    double opacity = sc_sigmoid(g->opacity_logits[i]);
    if (j->opt->antialiased) {
        const double ratio = (e.a0 * e.c0 - e.b0 * e.b0) / det;
        opacity *= sqrt(ratio > 0.0 ? ratio : 0.0);
    }

    double dir[3], rgb[3];
    sc_view_dir(g->means + 3 * i, j->campos, dir);
    sc_sh_colour(j->opt->sh_degree, g->sh + (int64_t)3 * g->sh_coeffs * i, dir, rgb);

    s->x = (float)sc_pixel_x(cam, &e);
    s->y = (float)sc_pixel_y(cam, &e);
    s->ca = (float)(c / det);
    s->cb = (float)(-b / det);
    s->cc = (float)(a / det);
    s->opacity = (float)opacity;
    s->r = (float)fmax(rgb[0] + 0.5, 0.0);
    s->g = (float)fmax(rgb[1] + 0.5, 0.0);
    s->b = (float)fmax(rgb[2] + 0.5, 0.0);
    s->depth = (float)e.p[2];

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
    sc_camera_centre(cam->world_to_camera, j.campos);
    sc_parallel_for(opt->threads, g->count, 4096, project_range, &j);
    long long bad = atomic_load(&j.first_bad);
    if (bad < g->count) {
        stats->error_index = bad;
        return SC_ERR_NONFINITE;
    }
    return SC_OK;
}
