/* The viewport's image of a render (addon/blender/viewport.py, render_view): premultiplied RGBA
 * and each pixel's depth-buffer value, rows bottom to top (OpenGL's texture order), in one pass
 * over rows on the pool. In NumPy the same took a serial chain of float64 temporaries and
 * copies (RGBA interleaved, the depth mapped, clipped and converted, both flipped): at 3840x2160
 * 585 ms of one thread's time a frame, more than the render itself.
 *
 * The depth-buffer value of planar depth z (+inf: nothing) under the view's projection P
 * (default depth range [0, 1]): ndc = (P22 (-z) + P23) / (P32 (-z) + P33), 0.5 ndc + 0.5
 * clipped to [0, 1], 1 where ndc is not finite; in double, rounded to float once (tests hold it
 * against the float64 formula). Each pixel is independent: any thread count, the same bits. */
#include "internal.h"

typedef struct {
    const float *rgb, *alpha, *depth;
    int64_t width, height;
    double p22, p23, p32, p33;
    float *rgba, *window;
} job;

static void rows(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const job *j = ctx;
    const int64_t w = j->width;
    for (int64_t r = begin; r < end; ++r) {
        const int64_t from = (j->height - 1 - r) * w, to = r * w;
        const float *restrict rgb = j->rgb + 3 * from, *restrict alpha = j->alpha + from;
        const float *restrict depth = j->depth + from;
        float *restrict rgba = j->rgba + 4 * to, *restrict window = j->window + to;
        for (int64_t x = 0; x < w; ++x) {
            rgba[4 * x] = rgb[3 * x];
            rgba[4 * x + 1] = rgb[3 * x + 1];
            rgba[4 * x + 2] = rgb[3 * x + 2];
            rgba[4 * x + 3] = alpha[x];
        }
        for (int64_t x = 0; x < w; ++x) {
            const double z = -(double)depth[x];
            const double ndc = (j->p22 * z + j->p23) / (j->p32 * z + j->p33);
            double v = isfinite(ndc) ? 0.5 * ndc + 0.5 : 1.0;
            v = v < 0.0 ? 0.0 : v > 1.0 ? 1.0 : v;
            window[x] = (float)v;
        }
    }
}

void sc_viewport_image(const float *rgb, const float *alpha, const float *depth, int width,
                       int height, const double projection[4], float *rgba, float *window,
                       int threads) {
    const job j = {.rgb = rgb, .alpha = alpha, .depth = depth, .width = width, .height = height,
                   .p22 = projection[0], .p23 = projection[1], .p32 = projection[2],
                   .p33 = projection[3], .rgba = rgba, .window = window};
    sc_parallel_for(threads, height, sc_grain(height, (int64_t)width * 8, threads), rows,
                    (void *)&j);
}
