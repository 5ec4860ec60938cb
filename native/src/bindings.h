/* The arguments of every entry point of `splatcore`, in order: the one place they are declared.
 * module.c parses and checks each call by its table (begin, check), and hands the tables to
 * Python (`splatcore.signature(name)`), whose door, addon/core/native.py, passes every argument
 * by name: a new or reordered argument is a change here (and where it is used), never a second
 * list to keep in step. Included by module.c only (it needs arg_spec and the DIM_* sizes). */

/* The five arrays of N Gaussians (K: SH coefficients per colour channel), in this order
 * wherever a call takes them. */
#define GAUSSIAN_PARAMS                               \
    {"means", 'f', 2, {DIM_N, 3}, 0, ARRAY, 0},       \
    {"log_scales", 'f', 2, {DIM_N, 3}, 0, ARRAY, 0},  \
    {"quats", 'f', 2, {DIM_N, 4}, 0, ARRAY, 0},       \
    {"opacity_logits", 'f', 1, {DIM_N}, 0, ARRAY, 0}, \
    {"sh", 'f', 3, {DIM_N, DIM_K, 3}, 0, ARRAY, 0}

/* The Gaussians, the camera (intrinsics: (4,) or (8 + SC_MODEL_PARAMS,), see parse_common)
 * and the options project, render, render_train and compose_prepare share. */
#define FRAME_PARAMS                                    \
    GAUSSIAN_PARAMS,                                    \
    SCALAR("sh_degree", INT),                           \
    {"world_to_camera", 'd', 2, {4, 4}, 0, ARRAY, 0},   \
    {"intrinsics", 'd', 1, {ANY}, 0, ARRAY, 0},         \
    SCALAR("width", INT), SCALAR("height", INT), SCALAR("near", REAL), \
    SCALAR("antialiased", FLAG), SCALAR("threads", THREADS)

/* The optional background (3), and the three images render and render_train write. */
#define BACKGROUND_PARAM {"background", 'f', 1, {3}, OPTIONAL | FINITE, ARRAY, 0}
#define IMAGE_PARAMS                                                   \
    {"out_rgb", 'f', 3, {DIM_H, DIM_W, 3}, WRITABLE, ARRAY, 0},       \
    {"out_alpha", 'f', 2, {DIM_H, DIM_W}, WRITABLE, ARRAY, 0},        \
    {"out_depth", 'f', 2, {DIM_H, DIM_W}, WRITABLE, ARRAY, 0}

static const arg_spec PROJECT[] = {
    FRAME_PARAMS,
    {"out_xy", 'f', 2, {DIM_N, 2}, WRITABLE, ARRAY, 0},
    {"out_conic", 'f', 2, {DIM_N, 3}, WRITABLE, ARRAY, 0},
    {"out_depth", 'f', 1, {DIM_N}, WRITABLE, ARRAY, 0},
    {"out_opacity", 'f', 1, {DIM_N}, WRITABLE, ARRAY, 0},
    {"out_rgb", 'f', 2, {DIM_N, 3}, WRITABLE, ARRAY, 0},
    {"out_valid", 'B', 1, {DIM_N}, WRITABLE, ARRAY, 0},
};

/* The mesh layer: both or neither (render checks). */
static const arg_spec RENDER[] = {
    FRAME_PARAMS,
    BACKGROUND_PARAM,
    {"mesh_rgba", 'f', 3, {DIM_H, DIM_W, 4}, OPTIONAL, ARRAY, 0},
    {"mesh_depth", 'f', 2, {DIM_H, DIM_W}, OPTIONAL, ARRAY, 0},
    IMAGE_PARAMS,
    SCALAR_OR("exhaustive", FLAG, 0),
};

static const arg_spec COMPOSE_PREPARE[] = {
    FRAME_PARAMS,
    SCALAR_OR("exhaustive", FLAG, 0),
};

/* mesh and mesh_depth of the prepared camera's size (any strides, may share a buffer); out and
 * out_depth (None: no depth) overlapping nothing else. */
static const arg_spec COMPOSE_SRGB[] = {
    SCALAR("prepared", OBJECT),
    {"mesh_rgba", 'f', 3, {DIM_H, DIM_W, 4}, STRIDED, ARRAY, 0},
    {"mesh_depth", 'f', 2, {DIM_H, DIM_W}, STRIDED, ARRAY, 0},
    {"out", 'f', 3, {DIM_H, DIM_W, 4}, STRIDED | WRITABLE, ARRAY, 0},
    {"out_depth", 'f', 2, {DIM_H, DIM_W}, WRITABLE | OPTIONAL, ARRAY, 0},
    SCALAR("far", REAL),
};

static const arg_spec SORT_KEYS[] = {
    {"keys", 'f', 1, {DIM_ROWS}, 0, ARRAY, 0},
    SCALAR("threads", THREADS),
    {"out_order", 'i', 1, {DIM_ROWS}, WRITABLE, ARRAY, 0},
};

/* render_train's optional per-pixel and per-Gaussian outputs follow the images. */
static const arg_spec RENDER_TRAIN[] = {
    FRAME_PARAMS,
    BACKGROUND_PARAM,
    IMAGE_PARAMS,
    {"out_final_t", 'f', 2, {DIM_H, DIM_W}, WRITABLE | OPTIONAL, ARRAY, 0},
    {"out_n_contrib", 'i', 2, {DIM_H, DIM_W}, WRITABLE | OPTIONAL, ARRAY, 0},
    {"out_visible", 'B', 1, {DIM_N}, WRITABLE | OPTIONAL, ARRAY, 0},
    SCALAR_OR("exhaustive", FLAG, 0),
};

/* The loss gradients (in) and the Gaussians' gradients (out), for the Gaussians render_train
 * drew (`state`). */
static const arg_spec BACKWARD[] = {
    SCALAR("state", OBJECT),
    GAUSSIAN_PARAMS,
    {"d_rgb", 'f', 3, {DIM_H, DIM_W, 3}, FINITE, ARRAY, 0},
    {"d_alpha", 'f', 2, {DIM_H, DIM_W}, OPTIONAL | FINITE, ARRAY, 0},
    {"d_depth", 'f', 2, {DIM_H, DIM_W}, OPTIONAL | FINITE, ARRAY, 0},
    SCALAR("threads", THREADS),
    {"out_means", 'f', 2, {DIM_N, 3}, WRITABLE, ARRAY, 0},
    {"out_log_scales", 'f', 2, {DIM_N, 3}, WRITABLE, ARRAY, 0},
    {"out_quats", 'f', 2, {DIM_N, 4}, WRITABLE, ARRAY, 0},
    {"out_opacity_logits", 'f', 1, {DIM_N}, WRITABLE, ARRAY, 0},
    {"out_sh", 'f', 3, {DIM_N, DIM_K, 3}, WRITABLE, ARRAY, 0},
    {"out_xy", 'f', 2, {DIM_N, 2}, WRITABLE, ARRAY, 0},
    {"out_xy_abs", 'f', 2, {DIM_N, 2}, WRITABLE, ARRAY, 0},
};

static const arg_spec L1_SSIM[] = {
    {"image", 'f', 3, {DIM_H, DIM_W, 3}, FINITE, ARRAY, 0},
    {"target", 'f', 3, {DIM_H, DIM_W, 3}, FINITE, ARRAY, 0},
    SCALAR("lambda_dssim", REAL),
    SCALAR("threads", THREADS),
    {"out_grad", 'f', 3, {DIM_H, DIM_W, 3}, WRITABLE | OPTIONAL, ARRAY, 0},
};

/* param of any shape, its gradient and moments of the same, the optional row mask; `lead_lr`
 * left out (NaN) is lr, `used` negative is every value of a row. Every value of grad is
 * checked, those the update skips too: one flat pass is faster than a pass per row. */
static const arg_spec ADAM[] = {
    {"param", 'f', 0, {0}, ANY_RANK | WRITABLE, ARRAY, 0},
    {"grad", 'f', 0, {0}, LIKE | FINITE, ARRAY, 0},
    {"exp_avg", 'f', 0, {0}, LIKE | WRITABLE, ARRAY, 0},
    {"exp_avg_sq", 'f', 0, {0}, LIKE | WRITABLE, ARRAY, 0},
    SCALAR("lr", REAL), SCALAR("beta1", REAL), SCALAR("beta2", REAL), SCALAR("eps", REAL),
    SCALAR("step", LONG),
    SCALAR("threads", THREADS),
    {"rows", 'B', 1, {DIM_ROWS}, OPTIONAL | DEFAULTED, ARRAY, 0},
    SCALAR_OR("lead", LONG, 0),
    SCALAR_OR("lead_lr", REAL, NAN),
    SCALAR_OR("used", LONG, -1),
};

/* float32 parameters (means writable) of N Gaussians, noise (N, 3) float64. */
static const arg_spec POSITION_NOISE[] = {
    {"means", 'f', 2, {DIM_N, 3}, WRITABLE, ARRAY, 0},
    {"log_scales", 'f', 2, {DIM_N, 3}, 0, ARRAY, 0},
    {"quats", 'f', 2, {DIM_N, 4}, 0, ARRAY, 0},
    {"opacity_logits", 'f', 1, {DIM_N}, 0, ARRAY, 0},
    {"noise", 'd', 2, {DIM_N, 3}, 0, ARRAY, 0},
    SCALAR("scale", REAL),
    SCALAR("threads", THREADS),
};

/* Both float32, C-contiguous, of one shape (..., 4); out writable and either rgba itself or not
 * overlapping it. */
static const arg_spec SRGB_PREMULTIPLIED[] = {
    {"rgba", 'f', 0, {0}, ANY_RANK, ARRAY, 0},
    {"out", 'f', 0, {0}, LIKE | WRITABLE, ARRAY, 0},
    SCALAR("decode", FLAG),
    SCALAR("threads", THREADS),
};

/* (H, W, 4) float32 arrays of one shape with any strides; out writable, rgba itself or not
 * overlapping it. */
static const arg_spec SRGB_VIEW[] = {
    {"rgba", 'f', 3, {DIM_H, DIM_W, 4}, STRIDED, ARRAY, 0},
    {"out", 'f', 3, {DIM_H, DIM_W, 4}, STRIDED | WRITABLE, ARRAY, 0},
    SCALAR("decode", FLAG),
    SCALAR("zero_non_finite", FLAG),
    SCALAR("threads", THREADS),
};

/* float32 (H, W, 3), (H, W), (H, W, 4), (H, W, 4), C-contiguous but mesh (any strides); out
 * (left out: layer, in place) (H, W, 4) writable, any strides, layer itself or not overlapping
 * it, overlapping none of the others. */
static const arg_spec SRGB_DECODE_CHANGED[] = {
    {"rgb", 'f', 3, {DIM_H, DIM_W, 3}, 0, ARRAY, 0},
    {"alpha", 'f', 2, {DIM_H, DIM_W}, 0, ARRAY, 0},
    {"mesh", 'f', 3, {DIM_H, DIM_W, 4}, STRIDED, ARRAY, 0},
    {"layer", 'f', 3, {DIM_H, DIM_W, 4}, 0, ARRAY, 0},
    SCALAR("threads", THREADS),
    {"out", 'f', 3, {DIM_H, DIM_W, 4}, STRIDED | WRITABLE | OPTIONAL | DEFAULTED, ARRAY, 0},
};

static const arg_spec COMPOSITE_MICROBENCH[] = {
    SCALAR("count", INT),
    SCALAR("iterations", INT),
};

/* A render's three images into the viewport's two (none overlapping another; module.c checks). */
static const arg_spec VIEWPORT_IMAGE[] = {
    {"rgb", 'f', 3, {DIM_H, DIM_W, 3}, 0, ARRAY, 0},
    {"alpha", 'f', 2, {DIM_H, DIM_W}, 0, ARRAY, 0},
    {"depth", 'f', 2, {DIM_H, DIM_W}, 0, ARRAY, 0},
    {"projection", 'd', 1, {4}, FINITE, ARRAY, 0},
    {"out_rgba", 'f', 3, {DIM_H, DIM_W, 4}, WRITABLE, ARRAY, 0},
    {"out_depth", 'f', 2, {DIM_H, DIM_W}, WRITABLE, ARRAY, 0},
    SCALAR("threads", THREADS),
};

/* 8-bit (H, W, C) pixels, C >= 3 (module.c checks), into float32 (H, W, 3). */
static const arg_spec PHOTO_RGB[] = {
    {"pixels", 'B', 3, {DIM_H, DIM_W, ANY}, 0, ARRAY, 0},
    {"out", 'f', 3, {DIM_H, DIM_W, 3}, WRITABLE, ARRAY, 0},
    SCALAR("threads", THREADS),
};

/* Bytes of kept memory for an image (module.c: a buffer object). */
static const arg_spec IMAGE_MEMORY[] = {
    SCALAR("bytes", LONG),
};

static const arg_spec POOL_PROFILE[] = {
    SCALAR("enable", FLAG),
    SCALAR_OR("cpu_clock", FLAG, 0),
};

/* (N, 3) points; out (N, k), k 1..SC_MAX_NEIGHBOURS. */
static const arg_spec NEIGHBOURS[] = {
    {"points", 'f', 2, {DIM_N, 3}, FINITE, ARRAY, 0},
    SCALAR("threads", THREADS),
    {"out", 'i', 2, {DIM_N, ANY}, WRITABLE, ARRAY, 0},
};

/* Rest and deformed centres, each one's neighbours (N, k) (indices, -1 none); the thresholds
 * are variance ratios, 0 <= undetermined <= determined <= 1. */
static const arg_spec DEFORMATION_JACOBIANS[] = {
    {"rest", 'f', 2, {DIM_N, 3}, FINITE, ARRAY, 0},
    {"deformed", 'f', 2, {DIM_N, 3}, FINITE, ARRAY, 0},
    {"neighbours", 'i', 2, {DIM_N, ANY}, 0, ARRAY, 0},
    SCALAR("undetermined", REAL), SCALAR("determined", REAL),
    SCALAR("threads", THREADS),
    {"out_jacobians", 'd', 3, {DIM_N, 3, 3}, WRITABLE, ARRAY, 0},
    {"out_rotations", 'd', 3, {DIM_N, 3, 3}, WRITABLE, ARRAY, 0},
};

/* The Gaussians' shapes and SH, a finite Jacobian and an orthogonal rotation each. */
static const arg_spec DEFORM_SHAPES[] = {
    {"log_scales", 'f', 2, {DIM_N, 3}, FINITE, ARRAY, 0},
    {"quats", 'f', 2, {DIM_N, 4}, FINITE, ARRAY, 0},
    {"sh", 'f', 3, {DIM_N, DIM_K, 3}, 0, ARRAY, 0},
    {"jacobians", 'd', 3, {DIM_N, 3, 3}, 0, ARRAY, 0},
    {"rotations", 'd', 3, {DIM_N, 3, 3}, 0, ARRAY, 0},
    SCALAR("threads", THREADS),
    {"out_log_scales", 'f', 2, {DIM_N, 3}, WRITABLE, ARRAY, 0},
    {"out_quats", 'f', 2, {DIM_N, 4}, WRITABLE, ARRAY, 0},
    {"out_sh", 'f', 3, {DIM_N, DIM_K, 3}, WRITABLE, ARRAY, 0},
};

/* The rest half of the fit: rest centres and neighbours (indices, -1 none) as for
 * deformation_jacobians, out_fit (N, SC_FIT_FIELDS + k). */
static const arg_spec DEFORM_REST[] = {
    {"rest", 'f', 2, {DIM_N, 3}, FINITE, ARRAY, 0},
    {"neighbours", 'i', 2, {DIM_N, ANY}, 0, ARRAY, 0},
    SCALAR("undetermined", REAL), SCALAR("determined", REAL),
    SCALAR("threads", THREADS),
    {"out_fit", 'd', 2, {DIM_N, ANY}, WRITABLE, ARRAY, 0},
};

/* Both in one pass: the rest centres, each one's neighbours and the rest half of its fit
 * (deform_rest's, by row) in the rows of a spatial order (neighbours as rows), order (N,) the
 * Gaussian in each row (a permutation); the deformed centres, shapes and SH by Gaussian. The
 * outputs may be log_scales, quats and sh themselves (each Gaussian's are read before its own
 * are written). linear and linear_rotation (both or neither; the second orthogonal): a map
 * after the deformation (an object's matrix), applied as L J to the shapes and as
 * linear_rotation Q to the SH. */
static const arg_spec DEFORM_FRAME[] = {
    {"rest", 'f', 2, {DIM_N, 3}, FINITE, ARRAY, 0},
    {"deformed", 'f', 2, {DIM_N, 3}, FINITE, ARRAY, 0},
    {"neighbours", 'i', 2, {DIM_N, ANY}, 0, ARRAY, 0},
    {"order", 'i', 1, {DIM_N}, 0, ARRAY, 0},
    {"fit", 'd', 2, {DIM_N, ANY}, FINITE, ARRAY, 0},
    {"linear", 'd', 2, {3, 3}, OPTIONAL | FINITE, ARRAY, 0},
    {"linear_rotation", 'd', 2, {3, 3}, OPTIONAL | FINITE, ARRAY, 0},
    {"log_scales", 'f', 2, {DIM_N, 3}, FINITE, ARRAY, 0},
    {"quats", 'f', 2, {DIM_N, 4}, FINITE, ARRAY, 0},
    {"sh", 'f', 3, {DIM_N, DIM_K, 3}, 0, ARRAY, 0},
    SCALAR("threads", THREADS),
    {"out_log_scales", 'f', 2, {DIM_N, 3}, WRITABLE, ARRAY, 0},
    {"out_quats", 'f', 2, {DIM_N, 4}, WRITABLE, ARRAY, 0},
    {"out_sh", 'f', 3, {DIM_N, DIM_K, 3}, WRITABLE, ARRAY, 0},
};

/* One object each (METH_O): a C-contiguous buffer; what render_train returned. */
static const arg_spec CHECKSUM[] = {SCALAR("buffer", OBJECT)};
static const arg_spec TRAIN_STATE_INFO[] = {SCALAR("state", OBJECT)};
