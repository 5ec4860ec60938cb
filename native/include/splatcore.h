/*
 * splatcore: a CPU renderer for 3D Gaussian splats that reproduces the reference 3DGS
 * rasterizer (Kerbl et al. 2023) up to float rounding, with its training backward pass.
 *
 * This is the public C API: everything a caller (module.c, the Python binding, or a C program
 * such as native/tests/render_driver.c) needs. The stage-to-stage declarations live in
 * src/internal.h, which only the library's own files include.
 *
 * Plain C11, no Python. Arrays are caller-owned, C-contiguous, float32 unless noted; nothing
 * here keeps a pointer after a call returns. Every result is identical for any thread count.
 *
 * Pipeline (one stage per file in src/):
 *   project.c    per Gaussian: EWA projection, SH colour, opacity, screen footprint (float,
 *                vectorised, with frustum culling before the covariance work); pinhole and
 *                orthographic cameras, with an optional thin-lens depth of field
 *   panorama.c   the same through panoramic cameras (equirectangular, fisheyes, mirror ball):
 *                the local Jacobian of the mapping at each mean, the seam's copies, in double
 *   sh.c         spherical harmonics degree 0..3 (the reference constants)
 *   sort.c       stable radix sort of Gaussians by view depth
 *   binning.c    Gaussian -> 16x16 tile lists, depth-ordered, exact ellipse/tile overlap
 *   composite.c  per tile, front to back, with an optional mesh layer (colour + depth); and the
 *                training variant that records what the backward pass needs
 *   render.c     the pipeline above, with timings
 *   threadpool.c a small persistent pool (POSIX threads, or Win32 threads on Windows)
 *   buffers.c    large working buffers, kept for the next frame
 *   cpu.c        the instruction set the compositor kernels run with, picked once at run time
 *
 * F12's composite and its helpers:
 *   compose.c    the composite in display sRGB, tile by tile (prepare, then the tile pass)
 *   colour.c     premultiplied RGBA between scene-linear and display sRGB, any strides
 *   checksum.c   a checksum of raw memory (whether a splat object's attributes changed)
 *
 * Training (backward passes, loss and optimizer):
 *   composite_backward.c  per tile, back to front: gradients of the projected Gaussians
 *   project_backward.c    per Gaussian: projected-Gaussian gradients -> parameter gradients
 *   sh.c                  (also) the SH backward
 *   train.c               the training forward (keeps an sc_train_state) and the backward
 *   loss.c                L1 + SSIM loss and its gradient
 *   adam.c                the Adam update
 *   position_noise.c      3DGS-MCMC's noise on the positions of nearly transparent Gaussians
 *
 * Deformation (modifiers, armatures, shape keys bending Gaussians, not only their centres):
 *   neighbours.c    k nearest neighbours of every point (a k-d tree)
 *   deform_fit.c    each Gaussian's deformation Jacobian from its neighbours' rest and
 *                   deformed positions, and its polar rotation; the rest positions' half of
 *                   that fit, computed once per rest shape
 *   deform_apply.c  covariances J Sigma J^T and SH rotated, a matrix per Gaussian
 *
 * The Python binding, module.c, is no stage: it checks every argument (a table per entry point)
 * and calls the functions declared here.
 */
#ifndef SPLATCORE_H
#define SPLATCORE_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

enum { SC_TILE = 16 }; /* tiles are SC_TILE x SC_TILE pixels (sc_frame) */

typedef enum {
    SC_OK = 0,
    SC_ERR_NONFINITE, /* a Gaussian holds NaN or Inf; error_index says which */
    SC_ERR_MEMORY,    /* an allocation failed */
    SC_ERR_TOO_LARGE, /* more tile/Gaussian pairs than fit the index type */
    SC_ERR_STALE,     /* backward: the Gaussians differ from those the state was rendered from;
                         error_index says which */
} sc_status;

/* N Gaussians in the design's struct-of-arrays layout. */
typedef struct {
    const float *means;          /* (N,3) */
    const float *log_scales;     /* (N,3) */
    const float *quats;          /* (N,4) w,x,y,z, normalised on use; all-zero = identity */
    const float *opacity_logits; /* (N,) */
    const float *sh;             /* (N,K,3), K = sh_coeffs */
    int64_t count;
    int sh_coeffs; /* 1, 4, 9 or 16 */
} sc_gaussians;

/* Projection models (docs/conventions.md, "Cameras beyond the pinhole"). */
typedef enum {
    SC_PINHOLE = 0,             /* (fx x/z + cx, fy y/z + cy), depth z */
    SC_ORTHO = 1,               /* (fx x + cx, fy y + cy), fx, fy in pixels per unit; depth z;
                                   every Gaussian seen along +z (its SH direction) */
    /* Panoramas: the direction p/|p| to Cycles' normalised (u, v), v up, then pixels
     * (fx u + cx, cy - fy v); depth |p|. Each Gaussian with the local Jacobian at its mean. */
    SC_EQUIRECTANGULAR = 2,     /* params: longitude min, max, latitude min, max (radians) */
    SC_FISHEYE_EQUIDISTANT = 3, /* params: field of view (radians) */
    SC_FISHEYE_EQUISOLID = 4,   /* params: lens (mm), field of view, sensor width, height (mm) */
    SC_MIRRORBALL = 5,
    SC_FISHEYE_POLYNOMIAL = 6,  /* params: k0..k4 (theta = -(k0 + k1 r + ... + k4 r^4), r in mm
                                   on the sensor), field of view, sensor width, height */
    SC_EQUIANGULAR_CUBEMAP_FACE = 7, /* one 90-degree face: u, v linear in atan2(x, z), atan2(-y, z) */
    SC_CENTRAL_CYLINDRICAL = 8, /* params: longitude min, max (radians), height min, max on a
                                   cylinder of radius 1 (-y / |(x, z)|) */
    SC_MODEL_COUNT
} sc_model;
enum { SC_MODEL_PARAMS = 10 };

/* A camera, OpenCV convention: x right, y down, z forward; pixel centres at i + 0.5. A zeroed
 * model, far and params is the pinhole of the first fields. */
typedef struct {
    double world_to_camera[16]; /* row-major 4x4, rigid */
    double fx, fy, cx, cy;
    int width, height;
    int model;                  /* sc_model */
    double far;                 /* Gaussians deeper than this are culled; <= 0: no limit */
    double params[SC_MODEL_PARAMS];
    /* Depth of field (PINHOLE and ORTHO; 0: none): a thin lens of this aperture radius (world
     * units) focused at depth `focus`. Each Gaussian's screen covariance gains the covariance
     * of its circle of confusion, (r/2)^2 diag(fx^2, fy^2) with r = aperture |1/focus - 1/z|
     * (ORTHO: aperture |1 - z/focus|), and its opacity falls so that its drawn mass stays. */
    double aperture, focus;
} sc_camera;

typedef struct {
    int sh_degree;   /* bands to evaluate, <= the data's degree */
    double near;     /* Gaussians with view z below this are culled */
    int antialiased; /* Mip-Splatting opacity compensation */
    int threads;     /* worker threads, >= 1 */
    int exhaustive;  /* evaluate each Gaussian over its tile's whole bounding span instead of the
                        half rows its alpha >= 1/255 ellipse reaches: the slow twin of those
                        masks, for tests; the image is the same bit for bit. In training, also
                        the backward's slow twins (its compositor likewise, its projection
                        backward one Gaussian at a time) */
} sc_options;

/* A projected Gaussian as binning and the compositor read it: one 64-byte record (a cache line). */
typedef struct {
    float x, y;          /* projected mean, pixels */
    float ca, cb, cc;    /* conic: inverse of the dilated 2D covariance [[ca, cb], [cb, cc]] */
    float opacity;       /* after the antialiasing compensation, if on */
    float r, g, b;       /* SH colour + 0.5, clamped at 0 */
    float depth;         /* view-space z of the mean */
    int32_t row0, row1;  /* pixel rows its alpha >= 1/255 footprint can reach, inclusive */
    int32_t col0, col1;  /* pixel columns likewise; row1 < row0 when it reaches none */
    float k2;            /* the footprint: alpha >= 1/255 only where d^T conic d <= k2 =
                            2 ln(255 opacity), inflated slightly to stay conservative */
    float unused;        /* pads the record to 64 bytes */
} sc_splat;

/* Per-Gaussian results of projection; `valid` is 0 for culled Gaussians (rows then zero). */
typedef struct {
    sc_splat *splats; /* (N) */
    uint8_t *valid;   /* (N) */
    float *keys;      /* optional (N): the depth where the splat reaches a pixel, else +inf */
    int wrap_rows;    /* render only: the arrays have 2N rows, and row N + i holds Gaussian i's
                         copy one period over (across the equirectangular seam) */
} sc_projection;

/* The image outputs; mesh and background inputs are optional (NULL). */
typedef struct {
    const float *background; /* (3) RGB behind everything, or NULL for black */
    const float *mesh_rgba;  /* (H,W,4) premultiplied, or NULL */
    const float *mesh_depth; /* (H,W) planar depth; used where mesh alpha > 0 */
    float *rgb;              /* (H,W,3) premultiplied */
    float *alpha;            /* (H,W) 1 - final transmittance */
    float *depth;            /* (H,W) expected depth, +inf where nothing was hit */
} sc_image;

typedef struct {
    double ms_project, ms_sort, ms_bin, ms_composite, ms_total;
    /* While the pool is profiled (sc_pool_profile), the part of each stage spent in parallel
     * sections (the rest ran on the calling thread alone); 0 otherwise. */
    double ms_pool_project, ms_pool_sort, ms_pool_bin, ms_pool_composite;
    int64_t visible;     /* Gaussians with a non-empty footprint */
    int64_t tile_pairs;  /* Gaussian/tile pairs composited */
    int64_t evaluations; /* Gaussian/pixel evaluations actually made */
    int64_t peak_bytes;  /* the most working memory the pipeline held at once (not the images) */
    int64_t error_index; /* with SC_ERR_NONFINITE: the offending Gaussian */
} sc_stats;

/* Project every Gaussian (threads over Gaussians), in float with the view transform in double
 * (project.c says why that is exact enough, and tests/ hold it against float64). Returns
 * SC_ERR_NONFINITE with stats->error_index set if any input value is NaN or Inf. */
sc_status sc_project(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                     sc_projection *out, sc_stats *stats);

/* The whole pipeline: project, sort, bin, composite. */
sc_status sc_render(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                    const sc_image *image, sc_stats *stats);

/* The renderer's depth sort on its own (for tests): order[k] = the index of the k-th smallest of
 * `count` (< 2^31) keys, stable (equal keys keep index order), +inf last, -0 before +0, on
 * `threads` threads (the same result for any number). *finite: how many keys are not +inf. A NaN
 * key gives SC_ERR_NONFINITE with stats->error_index the first; SC_ERR_MEMORY, SC_OK. */
sc_status sc_sort_keys(const float *keys, int64_t count, int threads, int32_t *order,
                       int64_t *finite, sc_stats *stats);

/* Time `iterations` passes of the composite inner loop over one in-cache tile of `count`
 * Gaussians that all cover it (no early stop): the kernel's arithmetic limit. Returns seconds. */
double sc_composite_microbench(int count, int iterations);

/* Frames keep their large working buffers (the last frame's, at most 8 blocks) for the next
 * frame, which saves the page faults of fresh memory; this frees them. */
void sc_release_buffers(void);

/* Memory for a caller's image (a render's outputs) from those kept buffers, so that frame after
 * frame the same pages are written again rather than fresh ones faulted in; NULL when out of
 * memory. sc_image_free gives it back, to be kept for the next frame. */
void *sc_image_alloc(size_t bytes);
void sc_image_free(void *p);

/* Cores this process may use (the default for `threads`). */
int sc_cpu_count(void);

/* The viewport's image of a render (H = height, W = width): rgb (H,W,3), alpha and planar depth
 * (H,W) into premultiplied RGBA (H,W,4) and depth-buffer values (H,W), rows bottom to top;
 * projection = P22, P23, P32, P33 of the view's OpenGL projection (viewport.c says how). */
void sc_viewport_image(const float *rgb, const float *alpha, const float *depth, int width,
                       int height, const double projection[4], float *rgba, float *window,
                       int threads);

/* 8-bit photo pixels (height, width, channels >= 3), C-contiguous, to float32 RGB (height,
 * width, 3) in [0, 1]: each value times float32(1 / 255) (photo.c). */
void sc_photo_rgb(const uint8_t *pixels, int width, int height, int channels, float *rgb,
                  int threads);

/* The index of the first NaN or Inf among `n` float32 values, or -1; on `threads` threads (the
 * same answer on any count). */
int64_t sc_first_non_finite(const float *values, int64_t n, int threads);

/* What the thread pool did while profiling (benchmarks/bench_scaling.py): process-wide sums over
 * every parallel section (one pass of a stage over Gaussians, tiles or rows), whatever called it. */
typedef struct {
    int64_t jobs;      /* parallel sections run */
    double inside_ms;  /* their callers' wall time inside them; the rest of a call is serial */
    double busy_ms;    /* the time their threads spent working, summed over the threads */
    double offered_ms; /* each section's wall time times the threads it ran on: offered - busy is
                        * the threads' waiting (waking up, the last chunk's tail) */
} sc_pool_counters;

/* Takes (returns and zeroes) the counters and profiles from now on as `mode` says. Profiling
 * is off by default and then costs nothing; on, it reads the clock twice per section and
 * thread, and the stages' stats fill their ms_pool_* fields. SC_PROFILE_CPU times the stages
 * and the sections by the calling thread's CPU clock instead of the wall clock: steady on a
 * busy machine, and exact for one thread, where all the work runs on the calling thread (with
 * more, the sections' times are then only the calling thread's share). */
enum { SC_PROFILE_OFF, SC_PROFILE_WALL, SC_PROFILE_CPU };
void sc_pool_profile(int mode, sc_pool_counters *taken);

/* The instruction set the compositor kernels run with on this CPU: "avx512", "avx2" or "sse2"
 * on x86-64 (picked once; SPLATCORE_ISA=sse2|avx2|avx512 caps it), "neon" on arm64. */
const char *sc_cpu_isa_name(void);

/* ================================================================ training
 *
 * Per step: sc_render_train (the forward, keeping an sc_train_state), the caller's loss on the
 * image (sc_l1_ssim, or anything else giving dL/d(rgb, alpha, depth)), sc_backward (parameter
 * gradients), sc_adam on each parameter array. Every result is identical for any thread count.
 *
 * Gradients are those of the forward exactly as defined ("Rendering semantics"), a piecewise
 * smooth function; where a piece ends the one-sided pieces are used, as follows:
 *  - a Gaussian skipped at a pixel (alpha < 1/255), stopped (transmittance) or culled gets no
 *    gradient from that pixel; alpha clamped at 0.99 passes no gradient to opacity or shape;
 *  - an SH colour channel clamped at 0 passes no gradient;
 *  - in the EWA Jacobian, x/z (y/z) clamped to the guard band is a constant: the clamped ratio
 *    gets no gradient, and J's remaining dependence on z is differentiated exactly (the
 *    reference CUDA code instead treats the clamped x, not x/z, as the constant);
 *  - the quaternion is normalised on use: its gradient is orthogonal to it and scaled by
 *    1/|q|; an all-zero quaternion (the identity) gets gradient 0;
 *  - the view direction's dependence on the mean is included (SH degree >= 1), as in 3DGS;
 *  - antialiased mode: d sqrt(r)/dr uses max(sqrt(r), 1e-6) in the denominator (r = det ratio).
 * The compositor recovers each Gaussian's transmittance back to front by division by 1 - alpha,
 * which is >= 0.01 since alpha <= 0.99. */

/* The front half of a frame: the drawn Gaussians in depth order and their tile lists. */
typedef struct {
    sc_splat *splats;       /* (drawn) projected Gaussians, front to back */
    uint32_t *order;        /* (drawn) index of each in the input Gaussians */
    int64_t drawn;
    int64_t *offsets;       /* (ntiles + 1): tile t's entries are list[offsets[t] .. offsets[t+1]) */
    uint32_t *list;         /* (pairs) indices into splats */
    int64_t *pair_offsets;  /* optional (drawn + 1): splat k's entries in `list` are at */
    uint32_t *pairs;        /* positions pairs[pair_offsets[k] .. pair_offsets[k+1]), tile order */
    int tiles_x;
    int64_t ntiles;
} sc_frame;

/* Everything the backward pass needs from a training forward. Owns its arrays. */
typedef struct {
    sc_frame frame;       /* with the pair index */
    sc_camera camera;
    sc_options options;   /* options.threads is the forward's; sc_backward takes its own */
    int64_t count;        /* Gaussians rendered */
    int sh_coeffs;        /* K of the Gaussians' sh array */
    int has_background;
    float background[3];
    float *final_t;       /* (H,W) transmittance after the Gaussians */
    int32_t *n_contrib;   /* (H,W) tile-list entries up to the last Gaussian added */
    float *depth;         /* (H,W) the expected depth as rendered (inf where nothing was hit) */
} sc_train_state;

/* The forward for training: sc_render without a mesh layer (image->mesh_* must be NULL),
 * returning the same images bit for bit, and filling *state (free it with
 * sc_train_state_free, also after a failure). */
sc_status sc_render_train(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                          const sc_image *image, sc_train_state *state, sc_stats *stats);
void sc_train_state_free(sc_train_state *state);

/* Parameter gradients, in the Gaussians' layout (caller-owned, overwritten). */
typedef struct {
    float *means;          /* (N,3) */
    float *log_scales;     /* (N,3) */
    float *quats;          /* (N,4) */
    float *opacity_logits; /* (N,) */
    float *sh;             /* (N,K,3); bands above the rendered degree get 0 */
    float *xy;             /* (N,2) dL/d projected mean in pixels, summed over pixels (the
                            * compositor's part; 3DGS's viewspace gradient is xy * (W/2, H/2)) */
    float *xy_abs;         /* (N,2) sums over pixels of |per-pixel dL/dx|, |dL/dy|
                            * (gsplat's "absgrad") */
} sc_gaussian_grads;

typedef struct {
    double ms_composite, ms_project, ms_total;
    double ms_pool_composite, ms_pool_project; /* as sc_stats's, while profiling */
    int64_t evaluations;
    int64_t flushed;     /* non-finite gradient values written as 0 (expected: 0) */
    int64_t error_index; /* with SC_ERR_NONFINITE or SC_ERR_STALE */
} sc_backward_stats;

/* Gradients of a loss w.r.t. every Gaussian parameter, given dL/d(rgb) (H,W,3) and optionally
 * dL/d(alpha) and dL/d(expected depth) (H,W) of the forward that filled `state` (which also
 * supplies final_t, n_contrib, depth and background). `g` must hold the same Gaussians as that
 * forward: a drawn Gaussian whose projection changed gives SC_ERR_STALE (SH changes are not
 * detected), a non-finite one SC_ERR_NONFINITE, with stats->error_index; the outputs then hold
 * partial results. Rows of Gaussians that were not drawn are 0. Deterministic: per tile, one
 * record per tile-list entry; per Gaussian, its records summed in the fixed order of the pair
 * index. Memory, during the call: 12 floats per tile pair + ~110 bytes per Gaussian. */
sc_status sc_backward(const sc_train_state *state, const sc_gaussians *g, const float *d_rgb,
                      const float *d_alpha, const float *d_depth, int threads,
                      sc_gaussian_grads *out, sc_backward_stats *stats);

/* The 3DGS photometric loss on (H,W,3) images in [0,1]:
 *   loss = (1 - lambda) L1 + lambda (1 - SSIM),
 * L1 the mean absolute difference, SSIM the mean of the SSIM map with an 11x11 Gaussian window
 * (sigma 1.5), C1 = 0.01^2, C2 = 0.03^2, each channel filtered separately with zero padding of
 * 5 pixels (the 3DGS training code's conv2d(padding = 5)), the map the same size as the image.
 * Writes dL/d(image) (H,W,3) into grad when non-NULL (d|x|/dx at 0 is 0). Float32 arithmetic (as the
 * 3DGS training code), the means summed in double.
 * With mse non-NULL, also the mean squared error of the image clamped to [0, 1] (what PSNR
 * measures), in double.
 * Returns SC_ERR_MEMORY or SC_OK. */
sc_status sc_l1_ssim(const float *image, const float *target, int width, int height,
                     double lambda, int threads, float *grad, double *loss, double *l1,
                     double *ssim, double *mse);

typedef struct {
    double lr, beta1, beta2, eps;
    int64_t step; /* 1 on the first update (bias correction) */
} sc_adam_options;

/* One Adam step over n float32 values in place, exactly torch.optim.Adam's (non-amsgrad,
 * no weight decay) formula: m = b1 m + (1-b1) g; v = b2 v + (1-b2) g^2;
 * p -= lr / (1 - b1^t) * m / (sqrt(v) / sqrt(1 - b2^t) + eps). */
void sc_adam(float *param, const float *grad, float *m, float *v, int64_t n,
             const sc_adam_options *o, int threads);

/* sc_adam over the rows of (rows, width) arrays, with the rows where mask[r] is 0 left exactly
 * as they are, moments included (mask NULL: every row; a step's visible Gaussians as gsplat's
 * visible_adam), the first `lead` values of each row at the rate lead_lr instead of o->lr
 * (the SH DC coefficients; lead 0: none), and only the first `used` values of each row updated
 * (the rest left as they are; `width` or more, or negative: all). */
void sc_adam_rows(float *param, const float *grad, float *m, float *v, int64_t rows,
                  int64_t width, const uint8_t *mask, int64_t lead, double lead_lr, int64_t used,
                  const sc_adam_options *o, int threads);

/* 3DGS-MCMC's position noise, in place: each of `count` means moves by R diag(s^2) R^T z
 * times sigmoid(100 ((1 - o) - 0.995)) times `scale`, o = sigmoid(opacity logit), s = exp(log
 * scales), R the normalised quaternion's rotation, z = noise (count, 3) float64 (the caller's
 * standard normal draw); computed in double; a gate at or below 1e-12 leaves a mean exactly as
 * it is. Identical for any thread count. */
void sc_position_noise(float *means, const float *log_scales, const float *quats,
                       const float *opacity_logits, const double *noise, int64_t count,
                       double scale, int threads);

/* An (height, width, 4) float32 image anywhere in memory: the byte strides of a row, a pixel
 * and a channel, of any sign (NumPy views: an EXR's planar channels, a row-reversed buffer). */
typedef struct {
    const char *data;
    int64_t height, width;
    int64_t row, pixel, channel;
} sc_rgba_view;

/* Premultiplied float32 RGBA from scene-linear to display sRGB (decode 0) or back (decode 1),
 * the extended sRGB transfer of addon/core/colour.py on rgb / alpha (alpha not > 0: as if 1),
 * alpha passed through; with zero_non_finite, non-finite results (alpha too) become 0. src and
 * dst have one shape; dst is written, and may be src itself (not otherwise overlapping).
 * Identical for any thread count. */
void sc_srgb_view(const sc_rgba_view *src, const sc_rgba_view *dst, int decode,
                  int zero_non_finite, int threads);

/* sc_srgb_view over `pixels` C-contiguous RGBA pixels (4 floats each). */
void sc_srgb_premultiplied(const float *src, float *dst, int64_t pixels, int decode,
                           int threads);

/* The composite back to scene-linear where it differs from the display layer it was composed
 * over: rgb (H, W, 3) and alpha (H, W) in display sRGB; layer (H, W, 4) the display layer. Per
 * pixel of out (H, W, 4, written; may be layer itself, not otherwise overlapping the others):
 * where rgb's bits or alpha (by more than 1e-6) differ from layer's, rgb/alpha decoded as
 * sc_srgb_view does; elsewhere mesh's pixel (scene-linear) bit for bit. rgb, alpha and layer
 * C-contiguous. Identical for any thread count. */
void sc_srgb_decode_changed(const float *rgb, const float *alpha, const sc_rgba_view *mesh,
                            const float *layer, const sc_rgba_view *out, int threads);

/* An (height, width) float32 plane anywhere in memory: byte strides of a row and a pixel. */
typedef struct {
    const char *data;
    int64_t height, width;
    int64_t row, pixel;
} sc_plane_view;

/* F12's composite (addon/core/render/composite.py, compose): the Gaussians composed with a mesh
 * render, in display sRGB, back in scene-linear; in two steps, so that the Gaussians' half
 * (project, sort, bin: no mesh needed) can run while Blender writes the mesh render out.
 *
 * sc_compose_prepare: that half for `cam` (its stats: project, sort and bin times, visible,
 * tile_pairs, peak_bytes; error_index with SC_ERR_NONFINITE). Free with sc_prepared_free.
 *
 * sc_compose_srgb: mesh is premultiplied scene-linear RGBA, mesh_depth its planar depth (NaN
 * and +inf: nothing there, -inf: 0), both cam's size, any strides. Per 16x16 tile, in one pass
 * on the thread pool: a tile no Gaussian reaches is the mesh itself (out = mesh bit for bit;
 * out_depth its depth where its alpha > 0); any other is what sc_srgb_view (encode,
 * zero_non_finite), sc_render with that display layer and sc_srgb_decode_changed give, bit
 * for bit. out (H, W, 4), any strides, overlapping no input; out_depth (H, W) C-contiguous,
 * `far` where nothing was hit, or NULL for no depth (nothing is then read from mesh_depth in
 * tiles no Gaussian reaches). stats: the prepared ones, with the tile pass as ms_composite and
 * both in ms_total; *colour_ms: the time the conversions and the mesh's copy took, summed over
 * threads. */
typedef struct sc_prepared sc_prepared;
sc_status sc_compose_prepare(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                             sc_prepared **prepared, sc_stats *stats);
sc_status sc_compose_srgb(const sc_prepared *prepared, const sc_rgba_view *mesh,
                          const sc_plane_view *mesh_depth, const sc_rgba_view *out,
                          float *out_depth, float far, sc_stats *stats, double *colour_ms);
void sc_prepared_size(const sc_prepared *prepared, int *width, int *height);
void sc_prepared_free(sc_prepared *prepared);

/* A 256-bit checksum of `bytes` bytes of memory (four 64-bit lanes; checksum.c says what it
 * always detects): for telling whether data changed. */
void sc_checksum(const void *data, int64_t bytes, uint64_t out[4]);

enum { SC_MAX_NEIGHBOURS = 64 };

/* The k (1..SC_MAX_NEIGHBOURS) nearest of `n` points (n, 3) to each point, itself left out, by
 * squared distance in double, ties to the lower index: out (n, k), nearest first, -1 where
 * fewer than k others exist. Returns 0, -1 for a bad k, -2 when memory runs out. */
int sc_neighbours(const float *points, int64_t n, int k, int32_t *out, int threads);

/* Per point, the deformation Jacobian mapping rest offsets to its neighbours to their deformed
 * offsets (deform_fit.c: weighted least squares; directions the neighbours span less than
 * `undetermined` (a variance ratio to the widest) follow a rotation, those above `determined`
 * are fitted, a ramp between) into jacobians (n, 3, 3) row-major, and its polar rotation into
 * rotations (n, 3, 3). neighbours (n, k) indices into the points, -1 for none. */
void sc_deformation_jacobians(const float *rest, const float *deformed, int64_t n,
                              const int32_t *neighbours, int k, double undetermined,
                              double determined, double *jacobians, double *rotations,
                              int threads);

/* n Gaussians' log-scales and quaternions for the covariances J Sigma J^T (jacobians (n, 3, 3))
 * and their SH (n, sh_coeffs, 3) rotated by the orthogonal rotations (n, 3, 3), into the out
 * arrays (deform_apply.c). */
void sc_deform_shapes(const float *log_scales, const float *quats, const float *sh, int64_t n,
                      int sh_coeffs, const double *jacobians, const double *rotations,
                      float *out_log_scales, float *out_quats, float *out_sh, int threads);

/* The rest half of each point's fit (deform_fit.c): what sc_deformation_jacobians computes
 * from the rest centres (n, 3) and neighbours (n, k) alone, SC_FIT_FIELDS + k doubles per point,
 * into fit (n, SC_FIT_FIELDS + k): a deformation's frames share it. */
enum { SC_FIT_FIELDS = 11 };
void sc_deform_rest(const float *rest, int64_t n, const int32_t *neighbours, int k,
                    double undetermined, double determined, double *fit, int threads);

/* sc_deformation_jacobians and sc_deform_shapes for n Gaussians in one pass (deform_frame.c):
 * rest (n, 3) the rest centres in the rows of a spatial order, order (n,) the Gaussian in each
 * row (a permutation), neighbours (n, k) each row's neighbours as rows (-1 none), fit
 * (n, SC_FIT_FIELDS + k) their sc_deform_rest; deformed (n, 3) and the shapes, SH and outputs
 * by Gaussian. The same numbers as sc_deformation_jacobians (in Gaussian order, with fit's
 * thresholds) then sc_deform_shapes. linear and linear_rotation (3, 3) row-major, both or NULL:
 * a map after the deformation (an object's matrix): the shapes go through linear J, the SH
 * through linear_rotation Q. Returns 0, or -2 when memory runs out. */
int sc_deform_frame(const float *rest, const float *deformed, int64_t n,
                    const int32_t *neighbours, int k, const int32_t *order, const double *fit,
                    const double *linear, const double *linear_rotation,
                    const float *log_scales, const float *quats, const float *sh, int sh_coeffs,
                    float *out_log_scales, float *out_quats, float *out_sh, int threads);

#ifdef __cplusplus
}
#endif
#endif
