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
 * correlation is the same correlation). Everything in double: s1 = e11 - mu1^2 cancels badly
 * in float. Rows run in parallel; every sum has a fixed order, so results do not depend on the
 * thread count. */
#include <math.h>
#include <stdlib.h>

#include "internal.h"

enum { RADIUS = 5, TAPS = 2 * RADIUS + 1, MAPS = 5 };
static const double SIGMA = 1.5, C1 = 0.01 * 0.01, C2 = 0.03 * 0.03;

typedef struct {
    const float *image, *target;
    float *grad;
    int width, height, channel;
    double window[TAPS];
    double lambda, inv_count;
    double *h[MAPS]; /* horizontal passes, then reused */
    double *s[3];    /* dS/dmu1, dS/de11, dS/de12 per pixel */
    double *row_ssim, *row_l1; /* per (channel, row) */
} job;

/* Horizontal pass of the five products x, y, x^2, y^2, xy of one channel. */
static void horizontal_products(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    job *j = ctx;
    const int w = j->width, c = j->channel;
    for (int64_t y = begin; y < end; ++y) {
        const float *xr = j->image + 3 * y * w, *yr = j->target + 3 * y * w;
        for (int x = 0; x < w; ++x) {
            double sums[MAPS] = {0};
            const int lo = x - RADIUS < 0 ? RADIUS - x : 0;
            const int hi = x + RADIUS > w - 1 ? RADIUS + (w - 1 - x) : TAPS - 1;
            for (int t = lo; t <= hi; ++t) {
                const double a = xr[3 * (x + t - RADIUS) + c], b = yr[3 * (x + t - RADIUS) + c];
                const double wt = j->window[t];
                sums[0] += wt * a, sums[1] += wt * b;
                sums[2] += wt * a * a, sums[3] += wt * b * b, sums[4] += wt * a * b;
            }
            for (int m = 0; m < MAPS; ++m) j->h[m][y * w + x] = sums[m];
        }
    }
}

/* Vertical pass: the SSIM map, its partial derivatives, and the row sums. */
static void vertical_ssim(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    job *j = ctx;
    const int w = j->width, h = j->height, c = j->channel;
    for (int64_t y = begin; y < end; ++y) {
        const int lo = y - RADIUS < 0 ? RADIUS - (int)y : 0;
        const int hi = y + RADIUS > h - 1 ? RADIUS + (h - 1 - (int)y) : TAPS - 1;
        double ssim_sum = 0.0, l1_sum = 0.0;
        for (int x = 0; x < w; ++x) {
            double v[MAPS] = {0};
            for (int t = lo; t <= hi; ++t) {
                const int64_t at = (y + t - RADIUS) * w + x;
                for (int m = 0; m < MAPS; ++m) v[m] += j->window[t] * j->h[m][at];
            }
            const double mu1 = v[0], mu2 = v[1];
            const double s1 = v[2] - mu1 * mu1, s2 = v[3] - mu2 * mu2, s12 = v[4] - mu1 * mu2;
            const double a1 = 2.0 * mu1 * mu2 + C1, a2 = 2.0 * s12 + C2;
            const double b1 = mu1 * mu1 + mu2 * mu2 + C1, b2 = s1 + s2 + C2;
            const double inv = 1.0 / (b1 * b2);
            const double s = a1 * a2 * inv;
            ssim_sum += s;
            const int64_t at = y * w + x;
            j->s[0][at] = 2.0 * mu2 * (a2 - a1) * inv - 2.0 * mu1 * s * (1.0 / b1 - 1.0 / b2);
            j->s[1][at] = -s / b2;
            j->s[2][at] = 2.0 * a1 * inv;
            l1_sum += fabs((double)j->image[3 * at + c] - (double)j->target[3 * at + c]);
        }
        j->row_ssim[(int64_t)c * h + y] = ssim_sum;
        j->row_l1[(int64_t)c * h + y] = l1_sum;
    }
}

/* Horizontal pass of the three partial-derivative maps (into h[0..2]). */
static void horizontal_partials(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    job *j = ctx;
    const int w = j->width;
    for (int64_t y = begin; y < end; ++y)
        for (int x = 0; x < w; ++x) {
            double sums[3] = {0};
            const int lo = x - RADIUS < 0 ? RADIUS - x : 0;
            const int hi = x + RADIUS > w - 1 ? RADIUS + (w - 1 - x) : TAPS - 1;
            for (int t = lo; t <= hi; ++t) {
                const int64_t at = y * w + x + t - RADIUS;
                for (int m = 0; m < 3; ++m) sums[m] += j->window[t] * j->s[m][at];
            }
            for (int m = 0; m < 3; ++m) j->h[m][y * w + x] = sums[m];
        }
}

/* Vertical pass of the partials, and the gradient of the whole loss for this channel. */
static void vertical_gradient(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    job *j = ctx;
    const int w = j->width, h = j->height, c = j->channel;
    const double l1_scale = (1.0 - j->lambda) * j->inv_count, ssim_scale = -j->lambda * j->inv_count;
    for (int64_t y = begin; y < end; ++y) {
        const int lo = y - RADIUS < 0 ? RADIUS - (int)y : 0;
        const int hi = y + RADIUS > h - 1 ? RADIUS + (h - 1 - (int)y) : TAPS - 1;
        for (int x = 0; x < w; ++x) {
            double v[3] = {0};
            for (int t = lo; t <= hi; ++t) {
                const int64_t at = (y + t - RADIUS) * w + x;
                for (int m = 0; m < 3; ++m) v[m] += j->window[t] * j->h[m][at];
            }
            const int64_t at = 3 * (y * w + x) + c;
            const double a = j->image[at], b = j->target[at];
            const double sign = a > b ? 1.0 : (a < b ? -1.0 : 0.0);
            j->grad[at] = (float)(l1_scale * sign + ssim_scale * (v[0] + 2.0 * a * v[1] + b * v[2]));
        }
    }
}

sc_status sc_l1_ssim(const float *image, const float *target, int width, int height,
                     double lambda, int threads, float *grad, double *loss, double *l1,
                     double *ssim) {
    const int64_t pixels = (int64_t)width * height;
    job j = {.image = image, .target = target, .grad = grad, .width = width, .height = height,
             .lambda = lambda, .inv_count = 1.0 / (3.0 * (double)pixels)};
    double total = 0.0;
    for (int t = 0; t < TAPS; ++t) {
        j.window[t] = exp(-(double)((t - RADIUS) * (t - RADIUS)) / (2.0 * SIGMA * SIGMA));
        total += j.window[t];
    }
    for (int t = 0; t < TAPS; ++t) j.window[t] /= total;

    sc_status status = SC_ERR_MEMORY;
    double *block = malloc(sizeof(double) * (size_t)(pixels * (MAPS + 3) + 6 * (int64_t)height));
    if (!block) return status;
    for (int m = 0; m < MAPS; ++m) j.h[m] = block + m * pixels;
    for (int m = 0; m < 3; ++m) j.s[m] = block + (MAPS + m) * pixels;
    j.row_ssim = block + (MAPS + 3) * pixels;
    j.row_l1 = j.row_ssim + 3 * (int64_t)height;

    const int64_t grain = 4;
    for (int c = 0; c < 3; ++c) {
        j.channel = c;
        sc_parallel_for(threads, height, grain, horizontal_products, &j);
        sc_parallel_for(threads, height, grain, vertical_ssim, &j);
        if (grad) {
            sc_parallel_for(threads, height, grain, horizontal_partials, &j);
            sc_parallel_for(threads, height, grain, vertical_gradient, &j);
        }
    }
    double ssim_sum = 0.0, l1_sum = 0.0;
    for (int64_t r = 0; r < 3 * (int64_t)height; ++r) {
        ssim_sum += j.row_ssim[r];
        l1_sum += j.row_l1[r];
    }
    *ssim = ssim_sum * j.inv_count;
    *l1 = l1_sum * j.inv_count;
    *loss = (1.0 - lambda) * *l1 + lambda * (1.0 - *ssim);
    status = SC_OK;
    free(block);
    return status;
}
