/* A training step's photo: 8-bit pixels (H, W, C), C >= 3 (RGB, RGBA, ...), to float32 RGB in
 * [0, 1] as addon/core/images/files.py's to_float makes it (each value times float32(1 / 255),
 * one rounding: the same bits). NumPy's two serial passes (the conversion, then the scale) over
 * a fresh array were a training step's photo time, on one thread; here rows on the pool. */
#include "internal.h"

typedef struct {
    const uint8_t *pixels;
    int64_t width, channels;
    float *rgb;
} job;

static SC_ALWAYS_INLINE void rows_body(const job *j, int64_t begin, int64_t end) {
    const float scale = (float)(1.0 / 255.0);
    for (int64_t r = begin; r < end; ++r) {
        const uint8_t *restrict in = j->pixels + r * j->width * j->channels;
        float *restrict out = j->rgb + r * j->width * 3;
        if (j->channels == 3) { /* RGB: one flat run, which vectorises */
            for (int64_t i = 0; i < 3 * j->width; ++i) out[i] = (float)in[i] * scale;
            continue;
        }
        for (int64_t x = 0; x < j->width; ++x)
            for (int c = 0; c < 3; ++c) out[3 * x + c] = (float)in[j->channels * x + c] * scale;
    }
}

SC_MULTIVERSION(int, rows_isa, (const job *j, int64_t begin, int64_t end), (j, begin, end),
                (rows_body(j, begin, end), 0))

static void rows(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    rows_isa(ctx, begin, end);
}

void sc_photo_rgb(const uint8_t *pixels, int width, int height, int channels, float *rgb,
                  int threads) {
    const job j = {.pixels = pixels, .width = width, .channels = channels, .rgb = rgb};
    sc_parallel_for(threads, height, sc_grain(height, (int64_t)width * 3, threads), rows,
                    (void *)&j);
}
