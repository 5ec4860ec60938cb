/*
 * splatcore: a CPU renderer for 3D Gaussian splats that reproduces the reference 3DGS
 * rasterizer (Kerbl et al. 2023) up to float rounding.
 *
 * Plain C11, no Python: the binding lives in module.c alone. Arrays are caller-owned, C-contiguous,
 * float32 unless noted; nothing here keeps a pointer after a call returns.
 *
 * Pipeline (one stage per file):
 *   project.c    per Gaussian: EWA projection, SH colour, opacity, screen footprint
 *   sh.c         spherical harmonics degree 0..3 (the reference constants)
 *   sort.c       stable radix sort of Gaussians by view depth
 *   binning.c    Gaussian -> 16x16 tile lists, depth-ordered, exact ellipse/tile overlap
 *   composite.c  per tile, front to back, with an optional mesh layer (colour + depth)
 *   render.c     the pipeline above, with timings
 *   threadpool.c a small persistent pool; output never depends on the thread count
 */
#ifndef SPLATCORE_H
#define SPLATCORE_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

enum { SC_TILE = 16 };

/* The reference constants (DESIGN.md, "Rendering semantics"). */
#define SC_ALPHA_MIN (1.0f / 255.0f) /* a Gaussian is skipped at a pixel below this alpha */
#define SC_ALPHA_MAX 0.99f           /* alpha is clamped to this */
#define SC_T_MIN 1e-4f               /* stop before transmittance would fall below this */
#define SC_DILATION 0.3              /* low-pass filter added to the 2D covariance */
#define SC_GUARD 0.3                 /* guard band: fraction of the half field of view */

typedef enum {
    SC_OK = 0,
    SC_ERR_NONFINITE, /* a Gaussian holds NaN or Inf; error_index says which */
    SC_ERR_MEMORY,    /* an allocation failed */
    SC_ERR_TOO_LARGE, /* more tile/Gaussian pairs than fit the index type */
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

/* A pinhole camera, OpenCV convention: x right, y down, z forward; pixel centres at i + 0.5. */
typedef struct {
    double world_to_camera[16]; /* row-major 4x4, rigid */
    double fx, fy, cx, cy;
    int width, height;
} sc_camera;

typedef struct {
    int sh_degree;   /* bands to evaluate, <= the data's degree */
    double near;     /* Gaussians with view z below this are culled */
    int antialiased; /* Mip-Splatting opacity compensation */
    int threads;     /* worker threads, >= 1 */
} sc_options;

/* A projected Gaussian as the compositor reads it (one cache-friendly record). */
typedef struct {
    float x, y;          /* projected mean, pixels */
    float ca, cb, cc;    /* conic: inverse of the dilated 2D covariance [[ca, cb], [cb, cc]] */
    float opacity;       /* after the antialiasing compensation, if on */
    float r, g, b;       /* SH colour + 0.5, clamped at 0 */
    float depth;         /* view-space z of the mean */
    int32_t row0, row1;  /* pixel rows its alpha >= 1/255 footprint can reach, inclusive */
    int32_t col0, col1;  /* pixel columns likewise */
} sc_splat;

/* Where a projected Gaussian reaches: the ellipse alpha >= 1/255, i.e. d^T cov^-1 d <= k2. */
typedef struct {
    double cov_a, cov_b, cov_c; /* dilated 2D covariance [[a, b], [b, c]] */
    double k2;                  /* 2 ln(255 opacity), slightly inflated to stay conservative */
    int32_t tx0, ty0, tx1, ty1; /* tile rectangle [tx0, tx1) x [ty0, ty1); empty if not drawn */
} sc_footprint;

/* Per-Gaussian results of projection; `valid` is 0 for culled Gaussians (rows then zero). */
typedef struct {
    sc_splat *splats;         /* (N) */
    sc_footprint *footprints; /* (N) */
    uint8_t *valid;           /* (N) */
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
    int64_t visible;     /* Gaussians with a non-empty footprint */
    int64_t tile_pairs;  /* Gaussian/tile pairs composited */
    int64_t evaluations; /* Gaussian/pixel evaluations actually made */
    int64_t error_index; /* with SC_ERR_NONFINITE: the offending Gaussian */
} sc_stats;

/* Project every Gaussian (threads over Gaussians). Returns SC_ERR_NONFINITE with
 * stats->error_index set if any input value is NaN or Inf. */
sc_status sc_project(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                     sc_projection *out, sc_stats *stats);

/* Evaluate SH of `degree` (0..3) for one Gaussian: coeffs (K,3), dir a unit vector. */
void sc_sh_colour(int degree, const float *coeffs, const double dir[3], double rgb[3]);

/* The whole pipeline: project, sort, bin, composite. */
sc_status sc_render(const sc_gaussians *g, const sc_camera *cam, const sc_options *opt,
                    const sc_image *image, sc_stats *stats);

/* Stable ascending sort of `count` float keys, carrying a payload: on entry order[i] is the
 * payload of keys[i], on return the payloads are in key order. `scratch` holds 3*count values. */
void sc_sort_by_depth(const float *keys, int64_t count, uint32_t *order, uint32_t *scratch);

/* Tile lists for `count` splats already in front-to-back order: for each tile t,
 * list[offsets[t] .. offsets[t+1]) are indices into `splats`, ascending (so front to back).
 * Allocates *offsets and *list (free with free()). */
sc_status sc_bin(const sc_footprint *fp, const sc_splat *splats, int64_t count,
                 const sc_camera *cam, int threads, int64_t **offsets, uint32_t **list);

/* Composite one tile front to back. Returns the number of Gaussian/pixel evaluations made. */
int64_t sc_composite_tile(const sc_splat *splats, const uint32_t *list, int64_t count,
                          int tile_x, int tile_y, const sc_camera *cam, const sc_image *image);

/* Time `iterations` passes of the composite inner loop over one in-cache tile of `count`
 * Gaussians that all cover it (no early stop): the kernel's arithmetic limit. Returns seconds. */
double sc_composite_microbench(int count, int iterations);

/* Thread pool: run fn(ctx, begin, end, thread) over [0, n) in chunks of `grain` on `threads`
 * threads (the caller is thread 0). Which thread runs a chunk must not change results. */
typedef void (*sc_task)(void *ctx, int64_t begin, int64_t end, int thread);
void sc_parallel_for(int threads, int64_t n, int64_t grain, sc_task fn, void *ctx);
int sc_cpu_count(void);

double sc_now_ms(void);

#ifdef __cplusplus
}
#endif
#endif
