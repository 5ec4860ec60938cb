/* The 3DGS photometric loss, (1 - lambda) L1 + lambda (1 - SSIM), and its gradient.
 *
 * SSIM as the 3DGS training code computes it (utils/loss_utils.py): per channel, the 11x11
 * Gaussian window (sigma 1.5, normalised) as a 2D correlation with zero padding of 5, giving
 *   mu1 = w * x, mu2 = w * y, s1 = w * x^2 - mu1^2, s2 = w * y^2 - mu2^2, s12 = w * xy - mu1 mu2
 *   S = (2 mu1 mu2 + C1)(2 s12 + C2) / ((mu1^2 + mu2^2 + C1)(s1 + s2 + C2)),
 * and SSIM the mean of S over every pixel and channel. The window is separable: each filter is
 * a horizontal then a vertical 11-tap pass. The gradient: with S a function of mu1, e11 = w*x^2
 * and e12 = w*xy at each pixel p,
 *   dSSIM/dx(q) = (1/M) sum_p w(p - q) [dS/dmu1(p) + 2 x(q) dS/de11(p) + y(q) dS/de12(p)],
 * three more filterings (the window is symmetric and the padding zero, so the transposed
 * correlation is the same correlation).
 *
 * Float32, as the 3DGS training code computes it on the GPU: the filters and the per-pixel
 * formulas run over planar rows (one plane per channel and product, rows zero-padded by the
 * window's radius) in loops the compiler vectorises, compiled per instruction-set level
 * (SC_MULTIVERSION). Only the sums over the image (the loss, L1 and SSIM means) are double.
 * s1 = e11 - mu1^2 cancels in float32, but s1 + s2 + C2 >= C2 = 9e-4 bounds the relative error
 * (tests/core/train/test_train_kernels.py holds the result against the float64 reference).
 *
 * Four passes over rows, each in parallel (every output has a fixed order of operations, so
 * results do not depend on the thread count): horizontal products, vertical products with the
 * SSIM map and its partial derivatives, horizontal partials, vertical partials with the
 * gradient. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

enum {
    RADIUS = 5,
    TAPS = 2 * RADIUS + 1,
    PRODUCTS = 5,     /* x, y, x^2, y^2, xy */
    PARTIALS = 3,     /* dS/dmu1, dS/de11, dS/de12 */
    CHUNK = 256,      /* columns a vertical pass keeps in its accumulators */
    LANES = 8,        /* independent double partial sums (vectorisable, fixed order) */
};
static const double SIGMA = 1.5;
static const float C1 = 0.01f * 0.01f, C2 = 0.03f * 0.03f;

typedef struct {
    const float *image, *target; /* (H,W,3) */
    float *grad;                 /* (H,W,3) or NULL */
    int width, height;
    int64_t stride;              /* a row padded left and right: width + 2 RADIUS */
    float window[TAPS];
    float l1_scale, ssim_scale;  /* dL/d(x) factors: (1 - lambda) / M, -lambda / M */
    float *x, *y;                /* (3, H, stride) image and target planes, padded rows */
    float *s;                    /* (PARTIALS * 3, H, stride) partial-derivative planes, likewise */
    float *h;                    /* (PRODUCTS * 3, H + 2 RADIUS, W) horizontal sums with zero
                                  * rows above and below, reused for the partials */
    double *row_ssim, *row_l1;   /* (H) sums over a row's pixels and channels */
    double *row_se;              /* (H) squared errors of the image clamped to [0, 1] (PSNR) */
    int pass;                    /* the pass running (run_pass) */
} job;

/* Row y of plane `plane` in a horizontally padded array (the row's first padding column). */
static inline float *padded_row(const job *j, float *base, int64_t plane, int64_t y) {
    return base + (plane * j->height + y) * j->stride;
}

/* Row y (-RADIUS .. H - 1 + RADIUS) of plane `plane` of the vertically padded sums. */
static inline float *sums_row(const job *j, int64_t plane, int64_t y) {
    return j->h + (plane * (j->height + 2 * RADIUS) + y + RADIUS) * j->width;
}

/* out[i] = sum_t window[t] in[i + t], i < n, in a padded row: every output one sum in a fixed
 * order, kept in a register (the tap loop unrolls; the column loop vectorises). */
static SC_ALWAYS_INLINE void filter_row(const float *window, const float *restrict in,
                                        float *restrict out, int n) {
    for (int i = 0; i < n; ++i) {
        float sum = 0.0f;
        for (int t = 0; t < TAPS; ++t) sum += window[t] * in[i + t];
        out[i] = sum;
    }
}

/* Pass 1, rows [begin, end): deinterleave into the padded planes, then the horizontal sums of
 * the five products per channel, CHUNK columns at a time. */
static SC_ALWAYS_INLINE int horizontal_products_body(job *j, int64_t begin, int64_t end) {
    const int w = j->width;
    for (int64_t y = begin; y < end; ++y)
        for (int c = 0; c < 3; ++c) {
            float *restrict xr = padded_row(j, j->x, c, y), *restrict yr = padded_row(j, j->y, c, y);
            const float *restrict xi = j->image + 3 * y * w + c, *restrict yi = j->target + 3 * y * w + c;
            for (int i = 0; i < w; ++i) xr[RADIUS + i] = xi[3 * i], yr[RADIUS + i] = yi[3 * i];
            for (int x0 = 0; x0 < w; x0 += CHUNK) {
                const int n = w - x0 < CHUNK ? w - x0 : CHUNK;
                float xx[CHUNK + 2 * RADIUS], yy[CHUNK + 2 * RADIUS], xy[CHUNK + 2 * RADIUS];
                for (int i = 0; i < n + 2 * RADIUS; ++i) {
                    const float a = xr[x0 + i], b = yr[x0 + i];
                    xx[i] = a * a, yy[i] = b * b, xy[i] = a * b;
                }
                filter_row(j->window, xr + x0, sums_row(j, 0 * 3 + c, y) + x0, n);
                filter_row(j->window, yr + x0, sums_row(j, 1 * 3 + c, y) + x0, n);
                filter_row(j->window, xx, sums_row(j, 2 * 3 + c, y) + x0, n);
                filter_row(j->window, yy, sums_row(j, 3 * 3 + c, y) + x0, n);
                filter_row(j->window, xy, sums_row(j, 4 * 3 + c, y) + x0, n);
            }
        }
    return 0;
}

/* v[m][i] = sum_t window[t] (plane m * 3 + c of the sums)[y + t - RADIUS][x0 + i], i < n, for
 * `maps` maps (the zero rows stand for the zero padding). */
static SC_ALWAYS_INLINE void vertical_sums(const job *j, int maps, int c, int64_t y, int x0, int n,
                                           float v[][CHUNK]) {
    for (int m = 0; m < maps; ++m) {
        const float *rows[TAPS];
        for (int t = 0; t < TAPS; ++t) rows[t] = sums_row(j, m * 3 + c, y + t - RADIUS) + x0;
        float *restrict out = v[m];
        for (int i = 0; i < n; ++i) {
            float sum = 0.0f;
            for (int t = 0; t < TAPS; ++t) sum += j->window[t] * rows[t][i];
            out[i] = sum;
        }
    }
}

/* (min(max(x, 0), 1) - y)^2 in double: the error PSNR measures (of the displayable image). */
static SC_ALWAYS_INLINE double clamped_square_error(float x, float y) {
    const double d = (double)(x < 0.0f ? 0.0f : x > 1.0f ? 1.0f : x) - (double)y;
    return d * d;
}

/* Pass 2: the vertical sums, the SSIM map, its partials (into the padded s planes) and the
 * row sums of SSIM and L1. */
static SC_ALWAYS_INLINE int vertical_ssim_body(job *j, int64_t begin, int64_t end) {
    const int w = j->width;
    for (int64_t y = begin; y < end; ++y) {
        double ssim_lanes[LANES] = {0}, l1_lanes[LANES] = {0}, se_lanes[LANES] = {0};
        for (int c = 0; c < 3; ++c)
            for (int x0 = 0; x0 < w; x0 += CHUNK) {
                const int n = w - x0 < CHUNK ? w - x0 : CHUNK;
                float v[PRODUCTS][CHUNK];
                vertical_sums(j, PRODUCTS, c, y, x0, n, v);
                float *restrict d_mu1 = padded_row(j, j->s, 0 * 3 + c, y) + RADIUS + x0;
                float *restrict d_e11 = padded_row(j, j->s, 1 * 3 + c, y) + RADIUS + x0;
                float *restrict d_e12 = padded_row(j, j->s, 2 * 3 + c, y) + RADIUS + x0;
                const float *restrict xr = padded_row(j, j->x, c, y) + RADIUS + x0;
                const float *restrict yr = padded_row(j, j->y, c, y) + RADIUS + x0;
                float s_map[CHUNK];
                for (int i = 0; i < n; ++i) {
                    const float mu1 = v[0][i], mu2 = v[1][i];
                    const float s1 = v[2][i] - mu1 * mu1, s2 = v[3][i] - mu2 * mu2;
                    const float s12 = v[4][i] - mu1 * mu2;
                    const float a1 = 2.0f * mu1 * mu2 + C1, a2 = 2.0f * s12 + C2;
                    const float b1 = mu1 * mu1 + mu2 * mu2 + C1, b2 = s1 + s2 + C2;
                    const float inv_b1 = 1.0f / b1, inv_b2 = 1.0f / b2;
                    const float inv = inv_b1 * inv_b2;
                    const float s = a1 * a2 * inv;
                    d_mu1[i] = 2.0f * mu2 * (a2 - a1) * inv - 2.0f * mu1 * s * (inv_b1 - inv_b2);
                    d_e11[i] = -s * inv_b2;
                    d_e12[i] = 2.0f * a1 * inv;
                    s_map[i] = s;
                }
                /* Sums in double over LANES fixed partial sums (vectorisable, fixed order). */
                int i = 0;
                for (; i + LANES <= n; i += LANES)
                    for (int l = 0; l < LANES; ++l) {
                        ssim_lanes[l] += (double)s_map[i + l];
                        l1_lanes[l] += fabs((double)xr[i + l] - (double)yr[i + l]);
                        se_lanes[l] += clamped_square_error(xr[i + l], yr[i + l]);
                    }
                for (int l = 0; i < n; ++i, ++l) {
                    ssim_lanes[l] += (double)s_map[i];
                    l1_lanes[l] += fabs((double)xr[i] - (double)yr[i]);
                    se_lanes[l] += clamped_square_error(xr[i], yr[i]);
                }
            }
        double ssim_sum = 0.0, l1_sum = 0.0, se_sum = 0.0;
        for (int l = 0; l < LANES; ++l)
            ssim_sum += ssim_lanes[l], l1_sum += l1_lanes[l], se_sum += se_lanes[l];
        j->row_ssim[y] = ssim_sum;
        j->row_l1[y] = l1_sum;
        j->row_se[y] = se_sum;
    }
    return 0;
}

/* Pass 3: horizontal sums of the three partials (into the sums' first planes). */
static SC_ALWAYS_INLINE int horizontal_partials_body(job *j, int64_t begin, int64_t end) {
    for (int64_t y = begin; y < end; ++y)
        for (int p = 0; p < 3 * PARTIALS; ++p)
            for (int x0 = 0; x0 < j->width; x0 += CHUNK) {
                const int n = j->width - x0 < CHUNK ? j->width - x0 : CHUNK;
                float in[CHUNK + 2 * RADIUS]; /* a local copy: provably not the output */
                memcpy(in, padded_row(j, j->s, p, y) + x0, sizeof(float) * (size_t)(n + 2 * RADIUS));
                filter_row(j->window, in, sums_row(j, p, y) + x0, n);
            }
    return 0;
}

/* Pass 4: vertical sums of the partials and the gradient of the whole loss. */
static SC_ALWAYS_INLINE int vertical_gradient_body(job *j, int64_t begin, int64_t end) {
    const int w = j->width;
    for (int64_t y = begin; y < end; ++y)
        for (int c = 0; c < 3; ++c)
            for (int x0 = 0; x0 < w; x0 += CHUNK) {
                const int n = w - x0 < CHUNK ? w - x0 : CHUNK;
                float v[PARTIALS][CHUNK];
                vertical_sums(j, PARTIALS, c, y, x0, n, v);
                const float *restrict xr = padded_row(j, j->x, c, y) + RADIUS + x0;
                const float *restrict yr = padded_row(j, j->y, c, y) + RADIUS + x0;
                float *restrict g = j->grad + 3 * (y * w + x0) + c;
                for (int i = 0; i < n; ++i) {
                    const float a = xr[i], b = yr[i];
                    const float sign = a > b ? 1.0f : (a < b ? -1.0f : 0.0f);
                    g[3 * i] = j->l1_scale * sign +
                               j->ssim_scale * (v[0][i] + 2.0f * a * v[1][i] + b * v[2][i]);
                }
            }
    return 0;
}

/* The four passes, in order; job.pass says which one a parallel_for runs. */
enum { HORIZONTAL_PRODUCTS, VERTICAL_SSIM, HORIZONTAL_PARTIALS, VERTICAL_GRADIENT };

static SC_ALWAYS_INLINE int pass_body(job *j, int64_t begin, int64_t end) {
    switch (j->pass) {
    case HORIZONTAL_PRODUCTS: return horizontal_products_body(j, begin, end);
    case VERTICAL_SSIM: return vertical_ssim_body(j, begin, end);
    case HORIZONTAL_PARTIALS: return horizontal_partials_body(j, begin, end);
    default: return vertical_gradient_body(j, begin, end);
    }
}

SC_MULTIVERSION(int, pass_isa, (job *j, int64_t begin, int64_t end), (j, begin, end),
                pass_body(j, begin, end))

static void run_pass(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    pass_isa(ctx, begin, end);
}

sc_status sc_l1_ssim(const float *image, const float *target, int width, int height,
                     double lambda, int threads, float *grad, double *loss, double *l1,
                     double *ssim, double *mse) {
    const int64_t pixels = (int64_t)width * height, stride = (int64_t)width + 2 * RADIUS;
    const double inv_count = 1.0 / (3.0 * (double)pixels);
    job j = {.image = image, .target = target, .grad = grad, .width = width, .height = height,
             .stride = stride, .l1_scale = (float)((1.0 - lambda) * inv_count),
             .ssim_scale = (float)(-lambda * inv_count)};
    double window[TAPS], total = 0.0;
    for (int t = 0; t < TAPS; ++t) {
        window[t] = exp(-(double)((t - RADIUS) * (t - RADIUS)) / (2.0 * SIGMA * SIGMA));
        total += window[t];
    }
    for (int t = 0; t < TAPS; ++t) j.window[t] = (float)(window[t] / total);

    /* Only the padding is zeroed: every interior value is written before it is read. */
    const int64_t padded = 3 * (int64_t)height * stride, sums = (int64_t)(height + 2 * RADIUS) * width;
    float *planes = malloc(sizeof(float) * (size_t)((2 + PARTIALS) * padded + PRODUCTS * 3 * sums));
    double *rows = malloc(sizeof(double) * 3 * (size_t)height);
    if (!planes || !rows) {
        free(planes);
        free(rows);
        return SC_ERR_MEMORY;
    }
    j.x = planes, j.y = planes + padded, j.s = planes + 2 * padded;
    j.h = planes + (2 + PARTIALS) * padded;
    j.row_ssim = rows, j.row_l1 = rows + height, j.row_se = rows + 2 * (int64_t)height;
    for (int64_t r = 0; r < (2 + PARTIALS) * 3 * (int64_t)height; ++r) {
        float *row = planes + r * stride;
        memset(row, 0, sizeof(float) * RADIUS);
        memset(row + RADIUS + width, 0, sizeof(float) * RADIUS);
    }
    for (int64_t p = 0; p < PRODUCTS * 3; ++p) {
        memset(sums_row(&j, p, -RADIUS), 0, sizeof(float) * RADIUS * (size_t)width);
        memset(sums_row(&j, p, height), 0, sizeof(float) * RADIUS * (size_t)width);
    }

    for (int pass = HORIZONTAL_PRODUCTS; pass <= (grad ? VERTICAL_GRADIENT : VERTICAL_SSIM); ++pass) {
        j.pass = pass;
        sc_parallel_for(threads, height, 4, run_pass, &j);
    }
    double ssim_sum = 0.0, l1_sum = 0.0, se_sum = 0.0;
    for (int64_t r = 0; r < height; ++r) {
        ssim_sum += j.row_ssim[r];
        l1_sum += j.row_l1[r];
        se_sum += j.row_se[r];
    }
    *ssim = ssim_sum * inv_count;
    *l1 = l1_sum * inv_count;
    if (mse) *mse = se_sum * inv_count;
    *loss = (1.0 - lambda) * *l1 + lambda * (1.0 - *ssim);
    free(planes);
    free(rows);
    return SC_OK;
}
