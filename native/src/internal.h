/* The library's internal header: what one stage declares for another, and the inline helpers
 * that two stages must compute identically. Not part of the API (that is include/splatcore.h);
 * only files in src/ include it.
 *
 * The forward and backward passes must make the same decisions (culling, the guard-band clamp,
 * power > 0, alpha < 1/255), so they share the same expressions from here: the projection math
 * of project.c and project_backward.c, the exp() and per-column set-up of composite.c and
 * composite_backward.c. */
#ifndef SPLATCORE_INTERNAL_H
#define SPLATCORE_INTERNAL_H

#include <float.h>
#include <math.h>
#include <string.h>

#include "splatcore.h"

/* The reference constants (docs/conventions.md, "Rendering semantics"). */
#define SC_ALPHA_MIN (1.0f / 255.0f) /* a Gaussian is skipped at a pixel below this alpha */
#define SC_ALPHA_MAX 0.99f           /* alpha is clamped to this */
#define SC_T_MIN 1e-4f               /* stop before transmittance would fall below this */
#define SC_DILATION 0.3              /* low-pass filter added to the 2D covariance */
#define SC_GUARD 0.3                 /* guard band: fraction of the half field of view */

/* Evaluate SH of `degree` (0..3) for one Gaussian: coeffs (K,3), dir a unit vector (float). */
void sc_sh_colour_f(int degree, const float *coeffs, const float dir[3], float rgb[3]);

/* ---------------------------------------------------------------- working memory */

/* Large working buffers, kept for reuse between frames (buffers.c); NULL when out of memory.
 * Every array of an sc_frame comes from here. */
void *sc_buffer_alloc(size_t bytes);
void sc_buffer_free(void *p);

/* ---------------------------------------------------------------- stages */

/* Projection (project.c), in float, vectorised: sc_project with `cull`, which leaves out
 * (valid 0) the Gaussians that cannot reach the image before their covariance and colour are
 * computed. */
sc_status sc_project_fast(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                          int cull, sc_projection *out, sc_stats *stats);

/* The footprint of splat `s` whose other fields are set (project.c): k2 and the pixel rows and
 * columns its alpha >= 1/255 ellipse reaches. */
void sc_footprint(sc_splat *s, const sc_camera *cam);

/* Projection through a panoramic camera (panorama.c), in double, one Gaussian at a time: the
 * local Jacobian of the mapping at each mean (EWA on the sphere); with out->wrap_rows, the
 * copies across the equirectangular seam. sc_project_fast hands panoramas to it. */
sc_status sc_project_panorama(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                              int cull, sc_projection *out, sc_stats *stats);

/* Whether the camera's panorama repeats across its left and right edges (a full 360 degrees of
 * equirectangular or central cylindrical longitude, params[0..1]), so that Gaussians on the seam
 * are drawn on both sides. */
static inline int sc_wraps(const sc_camera *cam) {
    return (cam->model == SC_EQUIRECTANGULAR || cam->model == SC_CENTRAL_CYLINDRICAL) &&
           cam->params[1] - cam->params[0] >= 6.283185307179586 - 1e-6;
}

/* The deepest depth drawn (the camera's far plane, else the largest float). */
static inline double sc_far(const sc_camera *cam) {
    return cam->far > 0.0 && cam->far < FLT_MAX ? cam->far : FLT_MAX;
}

/* Stable ascending sort of `count` float keys (sort.c), on `threads` threads, carrying a payload:
 * on return order[k] is the payload of the k-th smallest key, payload[i] that of keys[i] (NULL:
 * i; it may be `order` itself). Keys of +inf (Gaussians not drawn) go last; -0 sorts before +0;
 * no NaN. Returns how many keys are not +inf, or -1 when out of memory. *bytes: the working memory
 * it held (8 per key for up to two passes, plus the histograms). The result is the same for any
 * thread count. */
int64_t sc_sort_by_depth(const float *keys, int64_t count, const uint32_t *payload, int threads,
                         uint32_t *order, int64_t *bytes);

/* Tile lists for `count` splats already in front-to-back order: for each tile t,
 * list[offsets[t] .. offsets[t+1]) are indices into `splats`, ascending (so front to back).
 * Allocates *offsets and *list (free with sc_buffer_free()). With pair_offsets and pairs non-NULL, also
 * the inverse, Gaussian-major index (for the backward pass's deterministic reduction): splat k's
 * entries in `list` are at positions pairs[pair_offsets[k] .. pair_offsets[k+1]), in tile order;
 * *pair_offsets has count + 1 entries. *peak_bytes: the most it held allocated at once. */
sc_status sc_bin(const sc_splat *splats, int64_t count, const sc_camera *cam, int threads,
                 int64_t **offsets, uint32_t **list, int64_t **pair_offsets, uint32_t **pairs,
                 int64_t *peak_bytes);

/* The counting sorts' prefix sums (prefix.c): counts (rows, columns), row r of column c what
 * chunk r puts in bucket c, become in place each chunk's first position in the output, buckets
 * in order and chunks in order within a bucket; starts (columns + 1, or NULL) gets each
 * bucket's first position and the total. On `threads` threads when the table is large; the
 * same result for any count. Returns the total, or -1 when out of memory; a total above
 * `limit` (at most UINT32_MAX) leaves the counts as they were. */
int64_t sc_prefix_by_column(uint32_t *counts, int64_t rows, int64_t columns, int64_t *starts,
                            int64_t limit, int threads);

/* Composite one tile front to back (`exhaustive` as in sc_options). Returns the number of
 * Gaussian/pixel evaluations made. */
int64_t sc_composite_tile(const sc_splat *splats, const uint32_t *list, int64_t count,
                          int tile_x, int tile_y, const sc_camera *cam, const sc_image *image,
                          int exhaustive);

/* The training variant of sc_composite_tile: no mesh layer (image->mesh_rgba is ignored), the
 * same rgb, alpha and depth bit for bit, and per pixel of the tile, into (H,W) arrays:
 * final_t the transmittance left after the Gaussians (before the background), and n_contrib the
 * number of tile-list entries up to and including the last Gaussian added at that pixel (0 if
 * none), as the reference CUDA rasterizer's n_contrib. */
int64_t sc_composite_tile_train(const sc_splat *splats, const uint32_t *list, int64_t count,
                                int tile_x, int tile_y, const sc_camera *cam, const sc_image *image,
                                float *final_t, int32_t *n_contrib, int exhaustive);

/* Thread pool: run fn(ctx, begin, end, thread) over [0, n) in chunks of `grain` on `threads`
 * threads (the caller is thread 0). Which thread runs a chunk must not change results. */
typedef void (*sc_task)(void *ctx, int64_t begin, int64_t end, int thread);
void sc_parallel_for(int threads, int64_t n, int64_t grain, sc_task fn, void *ctx);

/* Rows per chunk for a pass over `rows` rows of `width` values on `threads` threads: about
 * four chunks per thread, each of 4k to 64k values (smaller ones would cost more to hand out
 * than to run; larger ones left threads idle: Adam over 50k opacities ran as one 64k chunk). */
static inline int64_t sc_grain(int64_t rows, int64_t width, int threads) {
    const int64_t w = width > 0 ? width : 1, per_chunk = rows * w / (4 * (int64_t)(threads > 0 ? threads : 1));
    const int64_t values = per_chunk < 4096 ? 4096 : per_chunk > 65536 ? 65536 : per_chunk;
    const int64_t grain = values / w;
    return grain > 0 ? grain : 1;
}

/* A monotonic clock in milliseconds (the stages' timings). */
double sc_now_ms(void);

/* While the pool is profiled (sc_pool_profile), the wall time callers have spent inside
 * sc_parallel_for so far (a stage's ms_pool_* is the difference across it); else 0. */
double sc_pool_inside_ms(void);

/* Project, sort and bin (the first three stages of sc_render); with_pairs also builds the
 * Gaussian-major pair index. Fills stats' project/sort/bin times, visible, tile_pairs and
 * peak_bytes.
 * On success free with sc_frame_free; on failure nothing is left allocated. */
sc_status sc_frame_prepare(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                           int with_pairs, sc_frame *frame, sc_stats *stats);

void sc_frame_free(sc_frame *frame);

/* Composites every tile of a prepared frame into `image` on `threads` threads: the render's
 * pass, or, given `final_t` and `n_contrib`, the training forward's (which keeps what its
 * backward needs). Returns the Gaussian evaluations made (render.c). */
int64_t sc_composite_frame(const sc_frame *frame, const sc_camera *cam, const sc_image *image,
                           float *final_t, int32_t *n_contrib, int exhaustive, int threads);

/* sRGB conversions a rectangle at a time (colour.c), for sc_compose_srgb's tile pass: encode
 * mesh (scene-linear) into layer_view as sc_srgb_view does with zero_non_finite, and decode as
 * sc_srgb_decode_changed does (rgb, alpha and layer (H, W, ...) C-contiguous, layer_view a view
 * of layer). NULL when out of memory. */
typedef struct sc_srgb_tiles sc_srgb_tiles;
sc_srgb_tiles *sc_srgb_tiles_new(const sc_rgba_view *mesh, const sc_rgba_view *layer_view,
                                 const float *layer, const float *rgb, const float *alpha,
                                 const sc_rgba_view *out);
void sc_srgb_tiles_encode(const sc_srgb_tiles *t, int64_t x0, int64_t y0, int64_t w, int64_t h);
void sc_srgb_tiles_decode(const sc_srgb_tiles *t, int64_t x0, int64_t y0, int64_t w, int64_t h);
void sc_srgb_tiles_free(sc_srgb_tiles *t);

/* ---------------------------------------------------------------- training stages */

/* Gradients of a projected Gaussian (its sc_splat fields), as records of SC_DG_COUNT floats. */
enum {
    SC_DG_X, SC_DG_Y,                      /* projected mean, pixels */
    SC_DG_CA, SC_DG_CB, SC_DG_CC,          /* conic; B counts once (power has -B dx dy) */
    SC_DG_OPACITY,                         /* the opacity the compositor uses */
    SC_DG_R, SC_DG_G, SC_DG_B,             /* clamped SH colour */
    SC_DG_DEPTH,                           /* view-space z, through the expected-depth image */
    SC_DG_ABS_X, SC_DG_ABS_Y,              /* sums over pixels of |per-pixel dL/dx|, |dL/dy| */
    SC_DG_COUNT
};

/* Per-pixel inputs of the compositor's backward pass, all (H,W[,3]) like the images. */
typedef struct {
    const float *d_rgb;      /* dL/d rgb (H,W,3) */
    const float *d_alpha;    /* dL/d alpha (H,W), or NULL */
    const float *d_depth;    /* dL/d expected depth (H,W), or NULL; ignored where depth is inf */
    const float *final_t;    /* from the training forward */
    const int32_t *n_contrib;
    const float *depth;
    const float *background; /* (3), or NULL for black */
} sc_image_grads;

/* Backward of sc_composite_tile_train for one tile, back to front: writes `count` records
 * (count, SC_DG_COUNT), one per tile-list entry (zero for entries no pixel used). Returns the
 * number of Gaussian/pixel evaluations made. `exhaustive`: each Gaussian over its whole span
 * (the slow twin of the masks; the same records bit for bit). */
int64_t sc_composite_tile_backward(const sc_splat *splats, const uint32_t *list, int64_t count,
                                   int tile_x, int tile_y, const sc_camera *cam,
                                   const sc_image_grads *grads, float *records, int exhaustive);

/* Backward of the projection of Gaussian i (drawn as `s` by the forward): from its summed
 * splat gradient `d` (SC_DG_COUNT) to its rows of `out` (xy and xy_abs copied from d). campos
 * is the camera centre in world space; the colour clamp is read from s's colour (0 = clamped).
 * Returns 0, or -1 if an input is non-finite, or -2 if Gaussian i no longer projects to `s` (it
 * changed since the forward). Non-finite results (only in extreme overflow) are written as 0
 * and counted in *flushed. */
int sc_project_backward_gaussian(const sc_gaussians *g, const sc_camera *cam,
                                 const sc_options *opt, const double campos[3], int64_t i,
                                 const sc_splat *s, const double *d, sc_gaussian_grads *out,
                                 int64_t *flushed);

/* The same for `n` (1..SC_BW_LANES) drawn Gaussians index[l] at once, each drawn as *splats[l]
 * with summed gradient d[l] (SC_DG_COUNT floats); results[l] as sc_project_backward_gaussian's
 * return. Vectorised across the Gaussians, in double (project_backward.c); a Gaussian it cannot
 * take (a non-finite input, stale, out of its exp's range) goes to sc_project_backward_gaussian,
 * which decides. Every Gaussian goes through the same code whatever its batch (a short batch
 * is padded), so the results do not depend on how Gaussians are batched. Returns the number of
 * nonzero results. */
enum { SC_BW_LANES = 8 };
int sc_project_backward_lanes(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                              const double campos[3], int n, const int64_t *index,
                              const sc_splat *const *splats, const float *const *d,
                              sc_gaussian_grads *out, int64_t *flushed, int *results);

/* ---------------------------------------------------------------- CPU dispatch
 * The compositor kernels are compiled once per instruction-set level and the best one for this
 * CPU runs (cpu.c). SC_MULTIVERSION(ret, name, params, args, call) defines `static ret
 * name params`, which runs `return call;` compiled for the chosen level; `args` forwards the
 * parameters. Function-level target attributes work with GCC and Clang on every x86-64 OS
 * (unlike target_clones, which needs ELF ifuncs). Elsewhere (arm64: NEON is baseline) there is
 * one build. */
typedef enum { SC_ISA_BASE, SC_ISA_V3 /* AVX2 + FMA */, SC_ISA_V4 /* AVX-512 */ } sc_isa;
sc_isa sc_cpu_isa(void);

#if defined(__GNUC__) && (defined(__x86_64__) || defined(_M_X64))
#define SC_MULTIVERSIONED 1
/* The x86-64-v3 and -v4 psABI levels as feature lists: clang ignores "arch=" in a target
 * attribute when the command line fixes the features (zig cc does), so name them. */
#define SC_TARGET_V3 "avx,avx2,bmi,bmi2,f16c,fma,lzcnt,movbe,xsave"
#define SC_TARGET_V4 SC_TARGET_V3 ",avx512f,avx512bw,avx512cd,avx512dq,avx512vl"
#define SC_MULTIVERSION(ret, name, params, args, call)                                           \
    static ret name##_base params { return call; }                                               \
    __attribute__((target(SC_TARGET_V3))) static ret name##_v3 params { return call; }          \
    __attribute__((target(SC_TARGET_V4))) static ret name##_v4 params { return call; }          \
    static ret name params {                                                                     \
        const sc_isa isa = sc_cpu_isa();                                                         \
        return isa == SC_ISA_V4 ? name##_v4 args : isa == SC_ISA_V3 ? name##_v3 args             \
                                                                    : name##_base args;          \
    }
#else
#define SC_MULTIVERSIONED 0
#define SC_MULTIVERSION(ret, name, params, args, call)                                           \
    static ret name params { return call; }
#endif

/* Inner blocks must be inlined into the SC_MULTIVERSION kernels to be vectorised for their level. */
#if defined(__GNUC__)
#define SC_ALWAYS_INLINE __attribute__((always_inline)) inline
static inline int sc_popcount(uint32_t v) { return __builtin_popcount(v); }
static inline int sc_lowest_bit(uint32_t v) { return __builtin_ctz(v); } /* v != 0 */
#else
static inline int sc_popcount(uint32_t v) {
    int n = 0;
    for (; v; v &= v - 1) ++n;
    return n;
}
static inline int sc_lowest_bit(uint32_t v) { /* v != 0 */
    int n = 0;
    for (; !(v & 1u); v >>= 1) ++n;
    return n;
}
#define SC_ALWAYS_INLINE inline
#endif

/* Keep the next loop a loop (GCC and clang): fully unrolled, a short loop over lanes is no longer
 * vectorised as one. */
#if defined(__GNUC__)
#define SC_NO_UNROLL _Pragma("GCC unroll 1")
#define SC_UNROLL_ALL _Pragma("GCC unroll 64")
#else
#define SC_NO_UNROLL
#define SC_UNROLL_ALL
#endif

/* A hint to fetch memory a loop will read (or write) soon: scattered accesses the hardware
 * cannot guess. */
#if defined(__GNUC__)
#define SC_PREFETCH(address) __builtin_prefetch(address)
#define SC_PREFETCH_WRITE(address) __builtin_prefetch(address, 1)
#else
#define SC_PREFETCH(address) ((void)(address))
#define SC_PREFETCH_WRITE(address) ((void)(address))
#endif

/* Whether every input value of Gaussian i is finite (projection forward and backward).
 * Branch-free (an exponent of all ones is Inf or NaN): the SH row vectorises. */
static inline int sc_gaussian_finite(const sc_gaussians *g, int64_t i) {
    const float *rows[5] = {g->means + 3 * i, g->log_scales + 3 * i, g->quats + 4 * i,
                            g->opacity_logits + i, g->sh + (int64_t)3 * g->sh_coeffs * i};
    const int counts[5] = {3, 3, 4, 1, 3 * g->sh_coeffs};
    uint32_t bad = 0;
    for (int r = 0; r < 5; ++r)
        for (int k = 0; k < counts[r]; ++k) {
            uint32_t bits;
            memcpy(&bits, rows[r] + k, sizeof bits);
            bad |= (bits & 0x7f800000u) == 0x7f800000u;
        }
    return !bad;
}

/* A world point in the camera frame: p = R mean + t, in double. */
static inline void sc_to_camera(const double *world_to_camera, const float *mean, double p[3]) {
    const double *v = world_to_camera;
    for (int k = 0; k < 3; ++k)
        p[k] = v[4 * k] * mean[0] + v[4 * k + 1] * mean[1] + v[4 * k + 2] * mean[2] + v[4 * k + 3];
}

/* ---------------------------------------------------------------- projection math
 * One Gaussian's forward projection, computed in double. project.c draws with it and
 * project_backward.c recomputes it (O(1) per Gaussian) to differentiate it. */

static inline double sc_clamp(double v, double lo, double hi) {
    return v < lo ? lo : (v > hi ? hi : v);
}

/* The camera centre in world space: -R^T t of a rigid world_to_camera. */
static inline void sc_camera_centre(const double *world_to_camera, double centre[3]) {
    const double *v = world_to_camera;
    for (int k = 0; k < 3; ++k) centre[k] = -(v[k] * v[3] + v[4 + k] * v[7] + v[8 + k] * v[11]);
}

/* Unit view direction from the camera centre to a mean; returns the distance (dir 0 at 0). */
static inline double sc_view_dir(const float *mean, const double campos[3], double dir[3]) {
    for (int k = 0; k < 3; ++k) dir[k] = (double)mean[k] - campos[k];
    const double len = sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
    for (int k = 0; k < 3; ++k) dir[k] = len > 0.0 ? dir[k] / len : 0.0;
    return len;
}

static inline double sc_sigmoid(float logit) { return 1.0 / (1.0 + exp(-(double)logit)); }

/* The intermediate values of the EWA projection Sigma2 = A A^T + 0.3 I, A = J W R S. */
typedef struct {
    double p[3];               /* the mean in the camera frame; p[2] is the view depth z */
    double tx, ty;             /* x/z and y/z clamped to the guard band (used inside J only) */
    int clamped_x, clamped_y;  /* whether that clamp acted */
    double j00, j02, j11, j12; /* the EWA Jacobian J (2x3, j01 = j10 = 0) */
    double q[4], q_norm2;      /* the normalised quaternion w,x,y,z and |q|^2 of the input */
    double r[9];               /* its rotation, row-major */
    double scale[3];           /* exp(log_scales) */
    double jw[2][3];           /* J W (W the camera rotation) */
    double a_rows[2][3];       /* A = J W R S */
    double a0, b0, c0;         /* Sigma2 before the dilation: [[a0, b0], [b0, c0]] = A A^T */
    double dof_x, dof_y;       /* the circle of confusion's covariance (diagonal; 0: none) */
    double a, b, c, det;       /* Sigma2 with it, dilated, and its determinant */
} sc_ewa;

/* What a projection pass reads and writes, shared by the pinhole/orthographic pass (project.c)
 * and the panoramic one (panorama.c): each embeds it as `p`. */
typedef struct {
    const sc_gaussians *g;
    const sc_camera *cam;
    const sc_options *opt;
    sc_projection *out;
    double campos[3]; /* the camera's centre in world space */
} sc_projection_pass;

/* The circle of confusion's variance per unit focal length squared at view depth z
 * (sc_camera's aperture and focus): (r/2)^2. */
static inline double sc_dof_blur(const sc_camera *cam, double z) {
    if (!(cam->aperture > 0.0)) return 0.0;
    const double r = cam->aperture * (cam->model == SC_ORTHO ? 1.0 - z / cam->focus
                                                             : 1.0 / cam->focus - 1.0 / z);
    return 0.25 * r * r;
}

/* The opacity factor that keeps a Gaussian's drawn mass through the depth-of-field blur and,
 * if `antialiased`, the dilation: sqrt(det(before) / det), `before` the raw Sigma2 (antialiased)
 * or the dilated one without the blur. 1 exactly without either. */
static inline double sc_mass_factor(const sc_ewa *e, int antialiased) {
    const double before = antialiased ? e->a0 * e->c0 - e->b0 * e->b0
                                      : (e->a0 + SC_DILATION) * (e->c0 + SC_DILATION) - e->b0 * e->b0;
    const double ratio = before / e->det;
    return sqrt(ratio > 0.0 ? ratio : 0.0);
}

/* Rotation matrix (row-major) of a quaternion w,x,y,z; normalises (into unit[4]); zero means
 * identity. Returns |q|^2. */
static inline double sc_quat_rotation(const float *q, double unit[4], double r[9]) {
    double w = q[0], x = q[1], y = q[2], z = q[3];
    const double n2 = w * w + x * x + y * y + z * z;
    if (n2 > 0.0) {
        const double inv = 1.0 / sqrt(n2);
        w *= inv, x *= inv, y *= inv, z *= inv;
    } else {
        w = 1.0, x = y = z = 0.0;
    }
    unit[0] = w, unit[1] = x, unit[2] = y, unit[3] = z;
    r[0] = 1 - 2 * (y * y + z * z), r[1] = 2 * (x * y - w * z), r[2] = 2 * (x * z + w * y);
    r[3] = 2 * (x * y + w * z), r[4] = 1 - 2 * (x * x + z * z), r[5] = 2 * (y * z - w * x);
    r[6] = 2 * (x * z - w * y), r[7] = 2 * (y * z + w * x), r[8] = 1 - 2 * (x * x + y * y);
    return n2;
}

/* The EWA projection of Gaussian i up to its dilated 2D covariance. Returns 1 when it projects,
 * 0 when it is culled (view z below `near`, or a degenerate covariance). The caller checks
 * finiteness first (sc_gaussian_finite). Always inlined: the projection backward, compiled per
 * instruction-set level, then computes it at its level too (FMA, 32 registers). */
static SC_ALWAYS_INLINE int sc_ewa_project(const sc_gaussians *g, int64_t i, const sc_camera *cam,
                                          double near, sc_ewa *e) {
    const float *mean = g->means + 3 * i, *ls = g->log_scales + 3 * i;
    const double *v = cam->world_to_camera;
    sc_to_camera(v, mean, e->p);
    const double z = e->p[2];
    /* Screen values are float32: a depth beyond its range (a camera translation near 1e38)
     * would be stored as inf, so such a Gaussian is culled, never valid. */
    if (!(z >= near) || !(z <= sc_far(cam)) || !(z >= -FLT_MAX)) return 0;

    const double fx = cam->fx, fy = cam->fy, cx = cam->cx, cy = cam->cy;
    if (cam->model == SC_ORTHO) { /* affine: J is exact and constant */
        e->clamped_x = e->clamped_y = 0, e->tx = e->ty = 0.0;
        e->j00 = fx, e->j02 = 0.0, e->j11 = fy, e->j12 = 0.0;
    } else { /* EWA Jacobian with x/z and y/z clamped to the guard band (inside J only). */
        const double tan_x = 0.5 * cam->width / fx, tan_y = 0.5 * cam->height / fy;
        const double lo_x = -(cx / fx) - SC_GUARD * tan_x, hi_x = (cam->width - cx) / fx + SC_GUARD * tan_x;
        const double lo_y = -(cy / fy) - SC_GUARD * tan_y, hi_y = (cam->height - cy) / fy + SC_GUARD * tan_y;
        const double rx = e->p[0] / z, ry = e->p[1] / z;
        e->clamped_x = rx < lo_x || rx > hi_x, e->clamped_y = ry < lo_y || ry > hi_y;
        e->tx = sc_clamp(rx, lo_x, hi_x), e->ty = sc_clamp(ry, lo_y, hi_y);
        e->j00 = fx / z, e->j02 = -fx * e->tx / z, e->j11 = fy / z, e->j12 = -fy * e->ty / z;
    }

    /* Sigma2 = J W R S S^T R^T W^T J^T = A A^T with the 2x3 factor A = J W R S:
     * fewer operations than forming the 3x3 covariances, and symmetric by construction. */
    e->q_norm2 = sc_quat_rotation(g->quats + 4 * i, e->q, e->r);
    for (int k = 0; k < 3; ++k) e->scale[k] = exp((double)ls[k]);
    for (int k = 0; k < 3; ++k) {
        e->jw[0][k] = e->j00 * v[k] + e->j02 * v[8 + k];
        e->jw[1][k] = e->j11 * v[4 + k] + e->j12 * v[8 + k];
    }
    for (int row = 0; row < 2; ++row)
        for (int k = 0; k < 3; ++k)
            e->a_rows[row][k] = (e->jw[row][0] * e->r[k] + e->jw[row][1] * e->r[3 + k] +
                                 e->jw[row][2] * e->r[6 + k]) * e->scale[k];
    const double *a0v = e->a_rows[0], *a1v = e->a_rows[1];
    e->a0 = a0v[0] * a0v[0] + a0v[1] * a0v[1] + a0v[2] * a0v[2];
    e->b0 = a0v[0] * a1v[0] + a0v[1] * a1v[1] + a0v[2] * a1v[2];
    e->c0 = a1v[0] * a1v[0] + a1v[1] * a1v[1] + a1v[2] * a1v[2];
    const double blur = sc_dof_blur(cam, z);
    e->dof_x = fx * fx * blur, e->dof_y = fy * fy * blur;
    e->a = e->a0 + e->dof_x + SC_DILATION, e->b = e->b0, e->c = e->c0 + e->dof_y + SC_DILATION;
    e->det = e->a * e->c - e->b * e->b;
    return e->det > 0.0 && isfinite(e->det);
}

/* The projected mean in pixels. */
static inline double sc_pixel_x(const sc_camera *cam, const sc_ewa *e) {
    return cam->fx * (cam->model == SC_ORTHO ? e->p[0] : e->p[0] / e->p[2]) + cam->cx;
}
static inline double sc_pixel_y(const sc_camera *cam, const sc_ewa *e) {
    return cam->fy * (cam->model == SC_ORTHO ? e->p[1] : e->p[1] / e->p[2]) + cam->cy;
}

/* ---------------------------------------------------------------- compositor helpers */

enum { SC_PIXELS = SC_TILE * SC_TILE, SC_BLOCK = 8 /* pixels evaluated together: half a row */ };

/* e^x for x in [-87, 88]: 2^(x log2 e) split into an integer power of two and a degree-6
 * polynomial on [-0.5, 0.5] (Cephes exp2f coefficients). Branch-free, vectorisable; relative
 * error below 4e-7. */
static inline float sc_exp_in_range(float x) {
    const float t = x * 1.44269504088896341f;
    const float n = (t + 12582912.0f) - 12582912.0f; /* round to nearest (1.5 * 2^23 trick) */
    const float f = t - n;
    float p = 1.535336188319500e-4f;
    p = p * f + 1.339887440266574e-3f;
    p = p * f + 9.618437357674640e-3f;
    p = p * f + 5.550332471162809e-2f;
    p = p * f + 2.402264791363012e-1f;
    p = p * f + 6.931472028550421e-1f;
    p = p * f + 1.0f;
    const int32_t bits = ((int32_t)n + 127) << 23;
    float scale;
    memcpy(&scale, &bits, sizeof scale);
    return p * scale;
}

/* e^x for x <= 0 (larger x is never drawn), the compositor's. Below -40 it returns e^-40: such
 * a pixel's alpha (opacity <= 1 times 4e-18) is far below 1/255, so it is never drawn and adds
 * exactly nothing, forward or backward, whatever the value. The floor keeps alpha = opacity e^x
 * a normal float: near e^-87 it was subnormal, and the processor takes a slow assist on each
 * subnormal result (on this project's AMD EPYC, a third of the forward compositor's time with
 * small, sharp splats, most of whose half-row pixels lie far out). */
static inline float sc_fast_exp(float x) {
    x = x < -40.0f ? -40.0f : x;
    x = x > 0.0f ? 0.0f : x;
    return sc_exp_in_range(x);
}

/* What one Gaussian contributes along a tile's 16 columns, computed once for all its rows. */
typedef struct {
    float dx[SC_TILE];      /* projected mean minus pixel centre, x */
    float power_x[SC_TILE]; /* -0.5 A dx^2 */
    float half_cc, cb, y, opacity, r, g, b, depth;
} sc_columns;

static inline void sc_prepare_columns(sc_columns *c, const sc_splat *s, float px0) {
    for (int x = 0; x < SC_TILE; ++x) {
        c->dx[x] = s->x - (px0 + (float)x);
        c->power_x[x] = -0.5f * s->ca * c->dx[x] * c->dx[x];
    }
    c->half_cc = 0.5f * s->cc, c->cb = s->cb, c->y = s->y, c->opacity = s->opacity;
    c->r = s->r, c->g = s->g, c->b = s->b, c->depth = s->depth;
}

/* The rows [*j0, *j1] and whole half-row blocks [*i0, *i1) of a tile (origin x0, y0) that a
 * splat's footprint reaches; empty when *j0 > *j1. */
static inline void sc_tile_span(const sc_splat *s, int x0, int y0, int *j0, int *j1, int *i0,
                                int *i1) {
    int a = s->row0 - y0, b = s->row1 - y0, c = s->col0 - x0, d = s->col1 - x0;
    *j0 = a < 0 ? 0 : a;
    *j1 = b > SC_TILE - 1 ? SC_TILE - 1 : b;
    *i0 = c < 0 ? 0 : c / SC_BLOCK * SC_BLOCK;
    *i1 = d > SC_TILE - 1 ? SC_TILE : (d / SC_BLOCK + 1) * SC_BLOCK;
}


/* Half-row masks: bit 2j + h stands for columns 8h..8h+7 of tile row j. */
typedef uint32_t sc_half_rows;

/* The half rows of sc_tile_span's span [j0, j1] x [i0, i1). */
static SC_ALWAYS_INLINE sc_half_rows sc_span_half_rows(int j0, int j1, int i0, int i1) {
    if (j0 > j1) return 0;
    const sc_half_rows rows = (j1 == SC_TILE - 1 ? 0u : 1u << 2 * (j1 + 1)) - (1u << 2 * j0);
    const sc_half_rows columns = (i0 < SC_BLOCK ? 0x55555555u : 0u) |
                                 (i1 > SC_BLOCK ? 0xAAAAAAAAu : 0u);
    return rows & columns;
}

/* The half rows of the tile (origin x0, y0) that a splat can draw in, out of `span`. Exact for
 * the ellipse, not its bounding box: a half row is kept when the smallest Q = ca dx^2 +
 * 2 cb dx dy + cc dy^2 over its segment (a convex quadratic in dx: at the clamped minimiser
 * -cb dy / ca) is at most the splat's k2 (>= 2 ln(255 o)), at the very float dx, dy the
 * compositor uses. The bound is widened for the float rounding of Q here and of the power the
 * compositor computes (each below 8 roundings of 2^-24 of the largest term over the tile:
 * 2 x 2e-6 of it) and of exp and alpha (2e-5). A pixel left out therefore has float alpha
 * < 1/255 and adds exactly nothing, forward or backward: skipping it changes no output bit
 * (tests/test_render_masks.py holds it against the span). The forward (composite.c) and the
 * backward (composite_backward.c) must skip the same pixels. */
static SC_ALWAYS_INLINE sc_half_rows sc_footprint_half_rows(const sc_splat *s,
                                                            const sc_columns *c, int y0,
                                                            sc_half_rows span) {
    const float ca = s->ca, cb = s->cb, cc = s->cc;
    /* Larger of two finite magnitudes; not fmaxf, a library call here (its NaN rule). */
    const float dx_a = fabsf(c->dx[0]), dx_b = fabsf(c->dx[SC_TILE - 1]);
    const float dx_max = dx_a > dx_b ? dx_a : dx_b;
    const float dy_a = fabsf(c->y - ((float)y0 + 0.5f));
    const float dy_b = fabsf(c->y - ((float)(y0 + SC_TILE - 1) + 0.5f));
    const float dy_max = dy_a > dy_b ? dy_a : dy_b;
    const float largest = 0.5f * ca * dx_max * dx_max + 0.5f * cc * dy_max * dy_max +
                          fabsf(cb) * dx_max * dy_max;
    const float q_max = s->k2 + 4e-6f * largest + 2e-5f; /* k2 >= 2 ln(255 o) */
    /* A degenerate (underflowed) conic or an overflowing bound: keep the whole span. */
    if (!(ca > 1e-30f && isfinite(largest) && isfinite(q_max))) return span;
    const float neg_cb_over_ca = -cb / ca;
    /* Each half row's segment, as its columns' dx (which decrease along the row). */
    const float left_hi = c->dx[0], left_lo = c->dx[SC_BLOCK - 1];
    const float right_hi = c->dx[SC_BLOCK], right_lo = c->dx[SC_TILE - 1];
    sc_half_rows reach = 0;
    for (int j = 0; j < SC_TILE; ++j) {
        const float dy = c->y - ((float)(y0 + j) + 0.5f); /* as the compositor's */
        const float centre = neg_cb_over_ca * dy, cc_dy2 = cc * dy * dy, cb_dy2 = 2.0f * cb * dy;
        float d = centre < left_lo ? left_lo : centre;
        d = d > left_hi ? left_hi : d;
        const float q_left = ca * d * d + cb_dy2 * d + cc_dy2;
        float e = centre < right_lo ? right_lo : centre;
        e = e > right_hi ? right_hi : e;
        const float q_right = ca * e * e + cb_dy2 * e + cc_dy2;
        reach |= ((sc_half_rows)(q_left <= q_max) | (sc_half_rows)(q_right <= q_max) << 1) << 2 * j;
    }
    return reach & span;
}

#endif
