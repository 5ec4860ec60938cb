/* Premultiplied RGBA between scene-linear and display sRGB: addon/core/colour.py's
 * display_from_linear and linear_from_display for float32 pixels, on the thread pool.
 *
 * Images are views with any strides (sc_rgba_view), so that F12 converts the render where it
 * lies: the channels of the EXR Blender wrote, read in place (planar, one row of each channel
 * after the other), and the composite written straight into the bottom-to-top rows a render
 * pass is filled from; no interleaving or flipping copies.
 *
 * The transfer is the extended sRGB of colour.py (mirrored for negatives, the linear segment at
 * and below the cut, HDR above 1), applied to the straight colour `rgb / a` and multiplied back
 * by `a` (a pixel whose alpha is not > 0, NaN included, converts as if its alpha were 1; alpha
 * itself passes through). Each value is computed in double and rounded to float once, so the
 * result is within about half a float32 ulp of the float64 formula.
 *
 * The power is the costly part, and libm's pow is slower than NumPy's vectorised one, so it is
 * split: v = m 2^e with m in [1, 2), v^p = (2^e)^p * c^p * (m / c)^p, where c is the centre of
 * the sixteenth of [1, 2) that m lies in; the first two factors come from tables and the last
 * is the binomial series of (1 + d)^p, |d| <= 1/32, to degree 5 (truncation below 1e-11
 * relative). Values outside the tables' exponents (never reached from float32 input, except
 * NaN and infinity) take libm's pow. Every value is independent of the others, so results are
 * the same for any thread count. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

enum { EXP_MIN = -64, EXP_MAX = 320, EXP_COUNT = EXP_MAX - EXP_MIN + 1, SUBDIV = 16, DEGREE = 5 };

static const double LINEAR_CUT = 0.0031308, ENCODED_CUT = 0.04045;

typedef struct {
    double both[EXP_COUNT * SUBDIV]; /* (2^e)^p c^p: one lookup per value */
    double inverse[SUBDIV];     /* 1 / c */
    double series[DEGREE + 1];  /* binomial coefficients of (1 + d)^p */
    double p;
} power_table;

typedef struct {
    sc_rgba_view src, dst;
    int decode, zero_non_finite;
    power_table table;
} job;

static void power_table_init(power_table *t, double p) {
    t->p = p;
    double exponent[EXP_COUNT], centre[SUBDIV]; /* (2^e)^p and c^p */
    for (int e = EXP_MIN; e <= EXP_MAX; ++e) exponent[e - EXP_MIN] = exp2((double)e * p);
    for (int i = 0; i < SUBDIV; ++i) {
        const double c = 1.0 + (i + 0.5) / SUBDIV;
        centre[i] = pow(c, p);
        t->inverse[i] = 1.0 / c;
    }
    for (int e = 0; e < EXP_COUNT; ++e)
        for (int i = 0; i < SUBDIV; ++i) t->both[e * SUBDIV + i] = exponent[e] * centre[i];
    double coefficient = 1.0;
    for (int k = 0; k <= DEGREE; ++k) {
        t->series[k] = coefficient;
        coefficient *= (p - k) / (k + 1);
    }
}

/* v^p for every v, branch-free so that the loop vectorises; v outside the tables' exponents
 * (0, denormals, NaN, infinity) gives a wrong value and sets *outside. */
static SC_ALWAYS_INLINE double power_table_only(const power_table *t, double v, int *outside) {
    uint64_t bits;
    memcpy(&bits, &v, sizeof bits);
    const int64_t biased = (int64_t)((bits >> 52) & 0x7ff) - 1023 - EXP_MIN;
    *outside = biased < 0 || biased >= EXP_COUNT;
    const int64_t e = biased < 0 ? 0 : biased >= EXP_COUNT ? EXP_COUNT - 1 : biased;
    const int64_t i = (int64_t)((bits >> (52 - 4)) & (SUBDIV - 1));
    const uint64_t mantissa_bits = (bits & 0x000fffffffffffffULL) | 0x3ff0000000000000ULL;
    double m;
    memcpy(&m, &mantissa_bits, sizeof m);
    const double d = m * t->inverse[i] - 1.0;
    const double *s = t->series;
    const double series = s[0] + d * (s[1] + d * (s[2] + d * (s[3] + d * (s[4] + d * s[5]))));
    return t->both[e * SUBDIV + i] * series;
}

/* v^p for v > 0 (NaN and infinity too, through pow). */
static SC_ALWAYS_INLINE double power(const power_table *t, double v) {
    int outside;
    const double tabled = power_table_only(t, v, &outside);
    return outside ? pow(v, t->p) : tabled;
}

/* The extended transfer of one straight value. */
static SC_ALWAYS_INLINE double transfer(const power_table *t, int decode, double v) {
    const double a = fabs(v);
    double out;
    if (decode)
        out = a <= ENCODED_CUT ? a / 12.92 : power(t, (a + 0.055) / 1.055);
    else
        out = a <= LINEAR_CUT ? 12.92 * a : 1.055 * power(t, a) - 0.055;
    return v < 0 ? -out : out;
}

enum { CHUNK = 256 }; /* pixels per vectorised pass */

/* `count` straight values through the branch-free transfer, times their scales, into
 * `converted`; the rare values outside the tables again through `transfer`. */
static SC_ALWAYS_INLINE void transfer_values(const power_table *t, const double *straight,
                                             const double *scale, double *converted,
                                             int64_t count, const int decode) {
    const double cut = decode ? ENCODED_CUT : LINEAR_CUT;
    int any_outside = 0;
    for (int64_t k = 0; k < count; ++k) {
        const double v = straight[k];
        const double a = fabs(v);
        const double x = decode ? (a + 0.055) * (1.0 / 1.055) : a;
        int off;
        const double curve = power_table_only(t, x, &off);
        const double bent = decode ? curve : 1.055 * curve - 0.055;
        const double linear = decode ? a * (1.0 / 12.92) : 12.92 * a;
        const int small = a <= cut;
        const double r = small ? linear : bent;
        any_outside |= off & !small;
        converted[k] = (v < 0 ? -r : r) * scale[k];
    }
    if (any_outside)
        for (int64_t k = 0; k < count; ++k) {
            const double a = fabs(straight[k]);
            const double x = decode ? (a + 0.055) * (1.0 / 1.055) : a;
            int off;
            (void)power_table_only(t, x, &off);
            if (off && !(a <= cut)) converted[k] = transfer(t, decode, straight[k]) * scale[k];
        }
}

/* A pixel of a view, and its channel c (views may have any strides, even unaligned ones). */
static SC_ALWAYS_INLINE const char *pixel_at(const sc_rgba_view *v, int64_t y, int64_t x) {
    return v->data + y * v->row + x * v->pixel;
}
static SC_ALWAYS_INLINE float load(const char *pixel, int64_t channel_stride, int c) {
    float value;
    memcpy(&value, pixel + c * channel_stride, sizeof value);
    return value;
}
static SC_ALWAYS_INLINE void store(char *pixel, int64_t channel_stride, int c, float value) {
    memcpy(pixel + c * channel_stride, &value, sizeof value);
}

/* The straight colour of one premultiplied pixel, and its scale, into slot `k` (3 values). */
static SC_ALWAYS_INLINE void straighten(const float *rgb, float alpha, double *straight,
                                        double *scale, int64_t k) {
    const double s = alpha > 0 ? (double)alpha : 1.0, inverse = 1.0 / s;
    for (int c = 0; c < 3; ++c) {
        scale[3 * k + c] = s;
        straight[3 * k + c] = (double)rgb[c] * inverse;
    }
}

/* Pixels [begin, end) (row-major over the view) in chunks within a row: the straight colour
 * values (alpha apart) through the transfer, then written back premultiplied, alpha as it was.
 * A pixel bit-identical to the one before it (a flat world or a transparent film is one colour
 * over most of a frame) takes that pixel's result instead of converting again: the same bits. */
static SC_ALWAYS_INLINE int convert_body(const job *j, int64_t begin, int64_t end,
                                         const int decode) {
    const power_table *t = &j->table;
    /* Locals, not j's fields: stores through the views' char pointers could alias j. */
    const sc_rgba_view src = j->src, dst = j->dst;
    const int zero_non_finite = j->zero_non_finite;
    double straight[CHUNK * 3], scale[CHUNK * 3], converted[CHUNK * 3];
    int32_t slot[CHUNK]; /* the distinct pixel whose result each pixel takes (-1: `last`) */
    float pixel[CHUNK][4], last[4] = {0}, last_rgb[3] = {0};
    int have_last = 0;
    for (int64_t first = begin; first < end;) {
        const int64_t y = first / src.width, x0 = first % src.width;
        int64_t count = end - first < CHUNK ? end - first : CHUNK;
        if (count > src.width - x0) count = src.width - x0;
        const char *in = pixel_at(&src, y, x0);
        int32_t n = 0;
        for (int64_t p = 0; p < count; ++p, in += src.pixel) {
            for (int c = 0; c < 4; ++c) pixel[p][c] = load(in, src.channel, c);
            if (have_last && memcmp(pixel[p], last, sizeof last) == 0) {
                slot[p] = n - 1;
                continue;
            }
            straighten(pixel[p], pixel[p][3], straight, scale, n);
            slot[p] = n++;
            memcpy(last, pixel[p], sizeof last);
            have_last = 1;
        }
        transfer_values(t, straight, scale, converted, 3 * (int64_t)n, decode);
        /* dst may be src itself: every pixel of the chunk was read above. */
        char *out = (char *)pixel_at(&dst, y, x0);
        for (int64_t p = 0; p < count; ++p, out += dst.pixel) {
            float value[4];
            for (int c = 0; c < 3; ++c)
                value[c] = slot[p] < 0 ? last_rgb[c] : (float)converted[3 * slot[p] + c];
            value[3] = pixel[p][3];
            for (int c = 0; c < 4; ++c) {
                if (zero_non_finite && !isfinite(value[c])) value[c] = 0.0f;
                store(out, dst.channel, c, value[c]);
            }
        }
        if (n > 0)
            for (int c = 0; c < 3; ++c) last_rgb[c] = (float)converted[3 * (n - 1) + c];
        first += count;
    }
    return 0;
}

/* compose's way back: per pixel, the composite (rgb, alpha) in display sRGB against the display
 * layer it was composed over (`layer`): where the colour's bits or the alpha (by more than 1e-6,
 * the compositor's 1 - (1 - a) rounding) differ, the composite decoded to scene-linear; elsewhere
 * the scene-linear mesh pixel itself, bit for bit; into `out` (which may be `layer`). */
typedef struct {
    const float *rgb, *alpha, *layer;
    sc_rgba_view mesh, out;
    power_table table;
} changed_job;

static SC_ALWAYS_INLINE int changed_body(const changed_job *j, int64_t begin, int64_t end) {
    double straight[CHUNK * 3], scale[CHUNK * 3], converted[CHUNK * 3];
    int64_t index[CHUNK];
    /* Locals, not j's fields: stores through the views' char pointers could alias j. */
    const float *const rgb = j->rgb, *const alpha = j->alpha, *const layer = j->layer;
    const sc_rgba_view mesh = j->mesh, out = j->out;
    const int64_t width = out.width;
    for (int64_t first = begin; first < end;) {
        const int64_t y = first / width, x0 = first % width;
        int64_t count = end - first < CHUNK ? end - first : CHUNK;
        if (count > width - x0) count = width - x0;
        int64_t n = 0;
        for (int64_t x = x0; x < x0 + count; ++x) {
            const int64_t p = y * width + x;
            uint32_t a[3], b[3];
            memcpy(a, rgb + 3 * p, sizeof a);
            memcpy(b, layer + 4 * p, sizeof b);
            const int changed = a[0] != b[0] || a[1] != b[1] || a[2] != b[2] ||
                                fabsf(alpha[p] - layer[4 * p + 3]) > 1e-6f;
            if (changed) {
                straighten(rgb + 3 * p, alpha[p], straight, scale, n);
                index[n++] = x;
            } else {
                /* layer (when it is out) is read above, before this pixel is written */
                const char *from = pixel_at(&mesh, y, x);
                char *to = (char *)pixel_at(&out, y, x);
                for (int c = 0; c < 4; ++c) store(to, out.channel, c, load(from, mesh.channel, c));
            }
        }
        transfer_values(&j->table, straight, scale, converted, 3 * n, 1);
        for (int64_t i = 0; i < n; ++i) {
            char *to = (char *)pixel_at(&out, y, index[i]);
            for (int c = 0; c < 3; ++c) store(to, out.channel, c, (float)converted[3 * i + c]);
            store(to, out.channel, 3, alpha[y * width + index[i]]);
        }
        first += count;
    }
    return 0;
}

/* One kernel per direction, so that each loop holds only its own transfer. */
SC_MULTIVERSION(int, encode_isa, (const job *j, int64_t begin, int64_t end), (j, begin, end),
                convert_body(j, begin, end, 0))
SC_MULTIVERSION(int, decode_isa, (const job *j, int64_t begin, int64_t end), (j, begin, end),
                convert_body(j, begin, end, 1))

SC_MULTIVERSION(int, changed_isa, (const changed_job *j, int64_t begin, int64_t end),
                (j, begin, end), changed_body(j, begin, end))

static void changed_pixels(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    changed_isa(ctx, begin, end);
}

static void convert_pixels(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const job *j = ctx;
    if (j->decode)
        decode_isa(j, begin, end);
    else
        encode_isa(j, begin, end);
}

void sc_srgb_view(const sc_rgba_view *src, const sc_rgba_view *dst, int decode,
                  int zero_non_finite, int threads) {
    job j = {.src = *src, .dst = *dst, .decode = decode, .zero_non_finite = zero_non_finite};
    power_table_init(&j.table, decode ? 2.4 : 1.0 / 2.4);
    sc_parallel_for(threads, src->height * src->width, 1 << 14, convert_pixels, &j);
}

void sc_srgb_premultiplied(const float *src, float *dst, int64_t pixels, int decode,
                           int threads) {
    const sc_rgba_view in = {(const char *)src, 1, pixels, 0, 16, 4};
    const sc_rgba_view out = {(const char *)dst, 1, pixels, 0, 16, 4};
    sc_srgb_view(&in, &out, decode, 0, threads);
}

void sc_srgb_decode_changed(const float *rgb, const float *alpha, const sc_rgba_view *mesh,
                            const float *layer, const sc_rgba_view *out, int threads) {
    changed_job j = {.rgb = rgb, .alpha = alpha, .layer = layer, .mesh = *mesh, .out = *out};
    power_table_init(&j.table, 2.4);
    sc_parallel_for(threads, out->height * out->width, 1 << 14, changed_pixels, &j);
}

/* ---------------------------------------------------------------- a rectangle at a time
 * compose.c converts only the tiles some Gaussian reaches, inside its tile pass: the same
 * conversions as sc_srgb_view (encode, zero_non_finite) and sc_srgb_decode_changed, over the
 * rows of one rectangle, with tables made once per frame. */
struct sc_srgb_tiles {
    job encode;
    changed_job decode;
};

sc_srgb_tiles *sc_srgb_tiles_new(const sc_rgba_view *mesh, const sc_rgba_view *layer_view,
                                 const float *layer, const float *rgb, const float *alpha,
                                 const sc_rgba_view *out) {
    sc_srgb_tiles *t = malloc(sizeof *t);
    if (!t) return NULL;
    t->encode = (job){.src = *mesh, .dst = *layer_view, .decode = 0, .zero_non_finite = 1};
    power_table_init(&t->encode.table, 1.0 / 2.4);
    t->decode = (changed_job){.rgb = rgb, .alpha = alpha, .layer = layer, .mesh = *mesh,
                              .out = *out};
    power_table_init(&t->decode.table, 2.4);
    return t;
}

void sc_srgb_tiles_free(sc_srgb_tiles *t) { free(t); }

void sc_srgb_tiles_encode(const sc_srgb_tiles *t, int64_t x0, int64_t y0, int64_t w, int64_t h) {
    const int64_t width = t->encode.src.width;
    for (int64_t y = y0; y < y0 + h; ++y) encode_isa(&t->encode, y * width + x0, y * width + x0 + w);
}

void sc_srgb_tiles_decode(const sc_srgb_tiles *t, int64_t x0, int64_t y0, int64_t w, int64_t h) {
    const int64_t width = t->decode.out.width;
    for (int64_t y = y0; y < y0 + h; ++y) changed_isa(&t->decode, y * width + x0, y * width + x0 + w);
}
