/* Premultiplied RGBA between scene-linear and display sRGB: addon/core/colour.py's
 * display_from_linear and linear_from_display for float32 pixels, on the thread pool.
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
    const float *src;
    float *dst;
    int decode;
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

/* The straight colour of one premultiplied pixel, and its scale, into slot `k` (3 values). */
static SC_ALWAYS_INLINE void straighten(const float *rgb, float alpha, double *straight,
                                        double *scale, int64_t k) {
    const double s = alpha > 0 ? (double)alpha : 1.0, inverse = 1.0 / s;
    for (int c = 0; c < 3; ++c) {
        scale[3 * k + c] = s;
        straight[3 * k + c] = (double)rgb[c] * inverse;
    }
}

/* Pixels [begin, end) in chunks: the straight colour values (alpha apart) through the
 * transfer, then written back premultiplied, alpha as it was. */
static SC_ALWAYS_INLINE int convert_body(const job *j, int64_t begin, int64_t end,
                                         const int decode) {
    const power_table *t = &j->table;
    double straight[CHUNK * 3], scale[CHUNK * 3], converted[CHUNK * 3];
    for (int64_t first = begin; first < end; first += CHUNK) {
        const int64_t count = end - first < CHUNK ? end - first : CHUNK;
        const float *in = j->src + 4 * first;
        float *out = j->dst + 4 * first;
        for (int64_t p = 0; p < count; ++p) straighten(in + 4 * p, in[4 * p + 3], straight, scale, p);
        transfer_values(t, straight, scale, converted, 3 * count, decode);
        /* out may be the input itself: each pixel is read (its alpha) before it is written. */
        for (int64_t p = 0; p < count; ++p) {
            const float alpha = in[4 * p + 3];
            for (int c = 0; c < 3; ++c) out[4 * p + c] = (float)converted[3 * p + c];
            out[4 * p + 3] = alpha;
        }
    }
    return 0;
}

/* compose's way back: per pixel, the composite (rgb, alpha) in display sRGB against the display
 * layer it was composed over (`layer`, overwritten with the result): where the colour's bits or
 * the alpha (by more than 1e-6, the compositor's 1 - (1 - a) rounding) differ, the composite
 * decoded to scene-linear; elsewhere the scene-linear mesh pixel itself, bit for bit. */
typedef struct {
    const float *rgb, *alpha, *mesh;
    float *layer;
    power_table table;
} changed_job;

static SC_ALWAYS_INLINE int changed_body(const changed_job *j, int64_t begin, int64_t end) {
    double straight[CHUNK * 3], scale[CHUNK * 3], converted[CHUNK * 3];
    int64_t index[CHUNK];
    for (int64_t first = begin; first < end; first += CHUNK) {
        const int64_t count = end - first < CHUNK ? end - first : CHUNK;
        int64_t n = 0;
        for (int64_t p = first; p < first + count; ++p) {
            const float *rgb = j->rgb + 3 * p;
            float *layer = j->layer + 4 * p;
            uint32_t a[3], b[3];
            memcpy(a, rgb, sizeof a);
            memcpy(b, layer, sizeof b);
            const int changed = a[0] != b[0] || a[1] != b[1] || a[2] != b[2] ||
                                fabsf(j->alpha[p] - layer[3]) > 1e-6f;
            if (changed) {
                straighten(rgb, j->alpha[p], straight, scale, n);
                index[n++] = p;
            } else {
                memcpy(layer, j->mesh + 4 * p, 4 * sizeof *layer);
            }
        }
        transfer_values(&j->table, straight, scale, converted, 3 * n, 1);
        for (int64_t i = 0; i < n; ++i) {
            float *layer = j->layer + 4 * index[i];
            for (int c = 0; c < 3; ++c) layer[c] = (float)converted[3 * i + c];
            layer[3] = j->alpha[index[i]];
        }
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

void sc_srgb_premultiplied(const float *src, float *dst, int64_t pixels, int decode,
                           int threads) {
    job j = {.src = src, .dst = dst, .decode = decode};
    power_table_init(&j.table, decode ? 2.4 : 1.0 / 2.4);
    sc_parallel_for(threads, pixels, 1 << 14, convert_pixels, &j);
}

void sc_srgb_decode_changed(const float *rgb, const float *alpha, const float *mesh, float *layer,
                            int64_t pixels, int threads) {
    changed_job j = {.rgb = rgb, .alpha = alpha, .mesh = mesh, .layer = layer};
    power_table_init(&j.table, 2.4);
    sc_parallel_for(threads, pixels, 1 << 14, changed_pixels, &j);
}
