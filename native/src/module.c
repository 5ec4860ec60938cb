/* The Python binding: validates every argument, then runs the C pipeline with the GIL released.
 * Arrays cross through the buffer protocol (numpy arrays in, caller-allocated numpy arrays out),
 * so there is no numpy C dependency, and the limited API 3.11 keeps one binary (abi3) for
 * every Blender from 4.2 on. Nothing here may crash the host: any bad argument is a TypeError
 * or ValueError that says what is wrong. */
#define Py_LIMITED_API 0x030B0000
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "splatcore.h"

enum { MAX_SIDE = 32768, MAX_THREADS = 4096 };
static const long long MAX_PIXELS = 1LL << 27;

/* A ValueError whose message may hold floating-point conversions: PyErr_Format knows none
 * (it prints "%g" literally), so the message is formatted by C's vsnprintf first. */
static void value_error(const char *format, ...) {
    char message[512];
    va_list args;
    va_start(args, format);
    PyOS_vsnprintf(message, sizeof message, format, args);
    va_end(args);
    PyErr_SetString(PyExc_ValueError, message);
}

/* "O&" converter for `threads`: any Python int; out of 0..MAX_THREADS is a ValueError (an
 * "i" format would make 2**31 an OverflowError). */
static int parse_threads(PyObject *obj, void *out) {
    int overflow = 0;
    const long long value = PyLong_AsLongLongAndOverflow(obj, &overflow);
    if (value == -1 && PyErr_Occurred()) return 0;
    if (overflow || value < 0 || value > MAX_THREADS) {
        PyErr_Format(PyExc_ValueError, "threads must be >= 0 (0 = all cores) and at most %d, got %R",
                     (int)MAX_THREADS, obj);
        return 0;
    }
    *(int *)out = (int)value;
    return 1;
}
static const long long MAX_GAUSSIANS = 0x7fffffffLL;

/* Which arrays a call holds, so every exit path can release them. */
typedef struct {
    Py_buffer views[24];
    int count;
} buffers;

static void release_all(buffers *b) {
    for (int i = 0; i < b->count; ++i) PyBuffer_Release(&b->views[i]);
    b->count = 0;
}

/* type: 'f' float32, 'd' float64, 'B' uint8, 'i' int32 (any 4-byte signed integer code). */
static int format_is(const char *format, char type) {
    if (!format) return type == 'B';
    if (*format == '@' || *format == '=' || *format == '<') format++;
    if (type == 'i' && (format[0] == 'l' || format[0] == 'i') && format[1] == '\0') return 1;
    return format[0] == type && format[1] == '\0';
}

static const char *type_name(char type) {
    return type == 'f' ? "float32" : type == 'd' ? "float64" : type == 'i' ? "int32" : "uint8";
}

static Py_ssize_t type_size(char type) { return type == 'd' ? 8 : type == 'f' || type == 'i' ? 4 : 1; }

/* ---------------------------------------------------------------- argument checking as data
 * Each entry point names its array arguments in a table (arg_spec: name, dtype, shape, flags)
 * and check_args() validates them in order, so every array gets the same checks and messages:
 * the buffer protocol, writability, dtype, C-contiguity (unless STRIDED), shape, and finiteness
 * where asked. Shapes may use named sizes: the first argument with one binds it, later ones must
 * match it. Scalar arguments are parsed by PyArg_ParseTuple and checked where they are used.
 * A new array argument is a row in its entry point's table (and its object in the
 * PyArg_ParseTuple list, in the table's order); a shared group (GAUSSIAN_ARGS, CAMERA_ARGS,
 * IMAGE_ARGS) is one table that every entry point taking it passes to check_args. */

/* A dimension of a shape: a size (>= 0), ANY, or a named size (N Gaussians, at most
 * MAX_GAUSSIANS; K SH coefficients per colour channel, 1, 4, 9 or 16; H and W an image's rows
 * and columns; ROWS any other length). */
enum { ANY = -1, DIM_N = -2, DIM_K = -3, DIM_H = -4, DIM_W = -5, DIM_ROWS = -6 };
enum { NAMED_DIMS = 5, MAX_RANK = 8 };
static const char DIM_LETTER[NAMED_DIMS] = {'N', 'K', 'H', 'W', 'N'};

enum {
    WRITABLE = 1, /* an output: the array must be writable */
    OPTIONAL = 2, /* None is allowed (its view is NULL) */
    FINITE = 4,   /* float32 values that must all be finite */
    STRIDED = 8,  /* any strides (otherwise C-contiguous) */
    ANY_RANK = 16, /* any shape (ndim and shape unused): later LIKE arguments must have it */
    LIKE = 32,    /* the shape of the ANY_RANK argument before it (ndim and shape unused) */
};

typedef struct {
    const char *name; /* as messages name it */
    char type;        /* 'f' float32, 'd' float64, 'B' uint8, 'i' int32 */
    int ndim;
    Py_ssize_t shape[3]; /* sizes, ANY or DIM_* */
    int flags;
} arg_spec;

/* The named sizes of one call (-1 until bound) and its ANY_RANK argument's view. */
typedef struct {
    Py_ssize_t size[NAMED_DIMS];
    const Py_buffer *like;
} arg_dims;

#define ARG_DIMS_INIT {{-1, -1, -1, -1, -1}, NULL}
#define COUNT(table) ((int)(sizeof(table) / sizeof(table)[0]))

/* Get a buffer of `type` with shape `shape` (-1: any size; `letters` names those in messages),
 * C-contiguous unless STRIDED, writable if WRITABLE, or raise. */
static const Py_buffer *get_array(buffers *b, PyObject *obj, const char *name, char type, int ndim,
                                  const Py_ssize_t *shape, const char *letters, int flags) {
    Py_buffer *view = &b->views[b->count];
    const int writable = flags & WRITABLE;
    if (PyObject_GetBuffer(obj, view, PyBUF_FORMAT | PyBUF_STRIDES | (writable ? PyBUF_WRITABLE : 0))
        != 0) {
        PyErr_Clear();
        if (writable && PyObject_GetBuffer(obj, view, PyBUF_FORMAT | PyBUF_STRIDES) == 0) {
            PyBuffer_Release(view);
            PyErr_Format(PyExc_ValueError, "%s must be a writable array", name);
        } else {
            PyErr_Clear();
            PyObject *type_obj = PyType_GetName(Py_TYPE(obj));
            PyErr_Format(PyExc_TypeError, "%s must be a %s array (buffer protocol), got %S", name,
                         type_name(type), type_obj ? type_obj : Py_None);
            Py_XDECREF(type_obj);
        }
        return NULL;
    }
    b->count++;
    if (!format_is(view->format, type) || view->itemsize != type_size(type)) {
        PyErr_Format(PyExc_TypeError, "%s must have dtype %s, got format '%s'", name,
                     type_name(type), view->format ? view->format : "B");
        return NULL;
    }
    if (!(flags & STRIDED) && !PyBuffer_IsContiguous(view, 'C')) {
        PyErr_Format(PyExc_ValueError, "%s must be C-contiguous (use numpy.ascontiguousarray)", name);
        return NULL;
    }
    int shape_ok = view->ndim == ndim;
    for (int i = 0; shape_ok && i < ndim; ++i) shape_ok = shape[i] < 0 || view->shape[i] == shape[i];
    if (!shape_ok) {
        char want[96] = "(", got[96] = "(";
        for (int i = 0; i < ndim && i < 6; ++i) {
            size_t at = strlen(want);
            if (shape[i] < 0) snprintf(want + at, sizeof want - at, "%s%c", i ? ", " : "", letters[i]);
            else snprintf(want + at, sizeof want - at, "%s%zd", i ? ", " : "", shape[i]);
        }
        for (int i = 0; i < view->ndim && i < 6; ++i) {
            size_t at = strlen(got);
            snprintf(got + at, sizeof got - at, "%s%zd", i ? ", " : "", view->shape[i]);
        }
        strncat(want, ")", sizeof want - strlen(want) - 1);
        strncat(got, ")", sizeof got - strlen(got) - 1);
        PyErr_Format(PyExc_ValueError, "%s must have shape %s, got shape %s", name, want, got);
        return NULL;
    }
    return view;
}

static int check_finite_array(const float *v, int64_t n, const char *name);

/* A named size just bound: N and K have limits of their own. */
static int check_bound(int dim, Py_ssize_t size) {
    if (dim == DIM_N && size > MAX_GAUSSIANS) {
        PyErr_Format(PyExc_ValueError, "too many Gaussians (%zd); at most %lld", size, MAX_GAUSSIANS);
        return -1;
    }
    if (dim == DIM_K && size != 1 && size != 4 && size != 9 && size != 16) {
        PyErr_Format(PyExc_ValueError, "sh must have shape (N, K, 3) with K in 1, 4, 9, 16; got K=%d",
                     (int)size);
        return -1;
    }
    return 0;
}

/* Validate objs[0..count-1] against specs[0..count-1] in order; views[i] gets each array's view
 * (NULL for an OPTIONAL None), held by `b` until release_all. */
static int check_args(buffers *b, arg_dims *d, const arg_spec *specs, int count,
                      PyObject *const *objs, const Py_buffer **views) {
    for (int i = 0; i < count; ++i) {
        const arg_spec *s = &specs[i];
        views[i] = NULL;
        if ((s->flags & OPTIONAL) && objs[i] == Py_None) continue;
        Py_ssize_t shape[MAX_RANK] = {0};
        char letters[MAX_RANK];
        int ndim = s->ndim;
        memset(letters, 'N', sizeof letters);
        if (s->flags & LIKE) {
            ndim = d->like->ndim;
            for (int k = 0; k < ndim; ++k) shape[k] = d->like->shape[k];
        } else if (s->flags & ANY_RANK) {
            /* Learn the shape first, then validate like every other array. */
            Py_buffer probe;
            if (PyObject_GetBuffer(objs[i], &probe, PyBUF_FORMAT | PyBUF_STRIDES) != 0) {
                PyErr_Clear();
                ndim = 1, shape[0] = -1;
            } else {
                ndim = probe.ndim;
                for (int k = 0; k < ndim && k < MAX_RANK; ++k) shape[k] = probe.shape[k];
                PyBuffer_Release(&probe);
            }
            if (ndim > MAX_RANK) {
                PyErr_Format(PyExc_ValueError, "%s has too many dimensions", s->name);
                return -1;
            }
        } else {
            for (int k = 0; k < ndim; ++k) {
                const Py_ssize_t want = s->shape[k];
                shape[k] = want >= ANY ? want : d->size[-2 - want];
                if (want < ANY) letters[k] = DIM_LETTER[-2 - want];
            }
        }
        const Py_buffer *view = get_array(b, objs[i], s->name, s->type, ndim, shape, letters, s->flags);
        if (!view) return -1;
        for (int k = 0; !(s->flags & (LIKE | ANY_RANK)) && k < ndim; ++k) {
            const Py_ssize_t want = s->shape[k];
            if (want < ANY && d->size[-2 - want] < 0) {
                d->size[-2 - want] = view->shape[k];
                if (check_bound((int)want, view->shape[k]) != 0) return -1;
            }
        }
        if (s->flags & ANY_RANK) d->like = view;
        if ((s->flags & FINITE) &&
            check_finite_array(view->buf, (int64_t)(view->len / view->itemsize), s->name) != 0)
            return -1;
        views[i] = view;
    }
    return 0;
}

/* The data of a view check_args returned, or NULL for an OPTIONAL None. */
static void *data(const Py_buffer *view) { return view ? view->buf : NULL; }

static int all_finite_d(const double *v, int n) {
    for (int i = 0; i < n; ++i)
        if (!isfinite(v[i])) return 0;
    return 1;
}

static const arg_spec GAUSSIAN_ARGS[] = {
    {"means", 'f', 2, {DIM_N, 3}, 0},
    {"log_scales", 'f', 2, {DIM_N, 3}, 0},
    {"quats", 'f', 2, {DIM_N, 4}, 0},
    {"opacity_logits", 'f', 1, {DIM_N}, 0},
    {"sh", 'f', 3, {DIM_N, DIM_K, 3}, 0},
};

static const arg_spec CAMERA_ARGS[] = {
    {"world_to_camera", 'd', 2, {4, 4}, 0},
    {"intrinsics", 'd', 1, {ANY}, 0}, /* (4,) or (8 + SC_MODEL_PARAMS,): parse_common */
};

/* The size a call bound to a named dimension. */
#define SIZE(d, dim) ((d)->size[-2 - (dim)])

/* Parse the five Gaussian arrays objs[0..4] (shapes consistent, K in 1, 4, 9, 16). */
static int parse_gaussians(buffers *b, arg_dims *d, PyObject *const *objs, sc_gaussians *g) {
    const Py_buffer *v[COUNT(GAUSSIAN_ARGS)];
    if (check_args(b, d, GAUSSIAN_ARGS, COUNT(GAUSSIAN_ARGS), objs, v) != 0) return -1;
    g->means = data(v[0]), g->log_scales = data(v[1]), g->quats = data(v[2]);
    g->opacity_logits = data(v[3]), g->sh = data(v[4]);
    g->count = SIZE(d, DIM_N);
    g->sh_coeffs = (int)SIZE(d, DIM_K);
    return 0;
}

/* Parse the arguments project(), render() and render_train() share: Gaussians, camera, options;
 * `d` gets N, K, H and W. */
static int parse_common(buffers *b, arg_dims *d, PyObject *const *objs, int sh_degree, int width,
                        int height, double near, int antialiased, int threads, sc_gaussians *g,
                        sc_camera *cam, sc_options *opt) {
    if (parse_gaussians(b, d, objs, g) != 0) return -1;
    const int data_degree = g->sh_coeffs == 1 ? 0 : g->sh_coeffs == 4 ? 1 : g->sh_coeffs == 9 ? 2 : 3;
    if (sh_degree < 0 || sh_degree > data_degree) {
        PyErr_Format(PyExc_ValueError, "sh_degree must be in 0..%d for this data, got %d",
                     data_degree, sh_degree);
        return -1;
    }

    const Py_buffer *v[COUNT(CAMERA_ARGS)];
    if (check_args(b, d, CAMERA_ARGS, COUNT(CAMERA_ARGS), objs + 5, v) != 0) return -1;
    const double *viewmat = data(v[0]), *intr = data(v[1]);
    /* intrinsics: fx fy cx cy (a pinhole), or those, the model, far, aperture, focus and
     * SC_MODEL_PARAMS (sc_camera). */
    const Py_ssize_t n_intr = v[1]->shape[0], n_long = 8 + SC_MODEL_PARAMS;
    if (n_intr != 4 && n_intr != n_long) {
        PyErr_Format(PyExc_ValueError, "intrinsics must have shape (4,) or (%zd,), got (%zd,)",
                     n_long, n_intr);
        return -1;
    }
    const int pinhole_only = n_intr == 4;
    const double model = pinhole_only ? SC_PINHOLE : intr[4], far = pinhole_only ? 0.0 : intr[5];
    const double aperture = pinhole_only ? 0.0 : intr[6], focus = pinhole_only ? 1.0 : intr[7];
    if (!(model >= 0 && model < SC_MODEL_COUNT && model == (int)model) || isnan(far) ||
        !all_finite_d(intr + (pinhole_only ? 0 : 8), pinhole_only ? 0 : SC_MODEL_PARAMS)) {
        PyErr_SetString(PyExc_ValueError, "intrinsics: unknown camera model or non-finite "
                                          "model parameters");
        return -1;
    }
    if (!(aperture >= 0 && isfinite(aperture)) || !(focus > 0 && isfinite(focus)) ||
        (aperture > 0 && model >= SC_EQUIRECTANGULAR)) {
        value_error("depth of field needs a finite aperture >= 0 and focus > 0, and a pinhole or "
                    "orthographic camera; got aperture %g, focus %g", aperture, focus);
        return -1;
    }
    if (!all_finite_d(viewmat, 16) || !all_finite_d(intr, 4)) {
        PyErr_SetString(PyExc_ValueError, "camera has non-finite pose or intrinsics");
        return -1;
    }
    /* A rigid transform: orthonormal rotation, last row 0 0 0 1. */
    double worst = fabs(viewmat[12]) + fabs(viewmat[13]) + fabs(viewmat[14]) + fabs(viewmat[15] - 1);
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) {
            double dot = 0;
            for (int k = 0; k < 3; ++k) dot += viewmat[4 * r + k] * viewmat[4 * c + k];
            worst = fmax(worst, fabs(dot - (r == c)));
        }
    if (worst > 1e-4) {
        value_error("world_to_camera must be rigid (orthonormal rotation, last row 0 0 0 1); "
                    "it is off by %g", worst);
        return -1;
    }
    if (!(intr[0] > 0) || !(intr[1] > 0)) {
        value_error("focal lengths must be positive, got fx=%g fy=%g", intr[0], intr[1]);
        return -1;
    }
    if (width <= 0 || height <= 0 || width > MAX_SIDE || height > MAX_SIDE ||
        (long long)width * height > MAX_PIXELS) {
        PyErr_Format(PyExc_ValueError,
                     "image size %dx%d is invalid: sides must be 1..%d and at most %lld pixels",
                     width, height, (int)MAX_SIDE, MAX_PIXELS);
        return -1;
    }
    /* Orthographic views may clip behind their origin (Blender's viewport does). */
    if (!isfinite(near) || (!(near >= 0) && model != SC_ORTHO)) {
        value_error("near must be finite and >= 0, got %g", near);
        return -1;
    }
    if (threads < 0) {
        PyErr_Format(PyExc_ValueError, "threads must be >= 0 (0 = all cores), got %d", threads);
        return -1;
    }
    memcpy(cam->world_to_camera, viewmat, sizeof cam->world_to_camera);
    cam->fx = intr[0], cam->fy = intr[1], cam->cx = intr[2], cam->cy = intr[3];
    cam->width = width, cam->height = height;
    cam->model = (int)model, cam->far = far, cam->aperture = aperture, cam->focus = focus;
    for (int k = 0; k < SC_MODEL_PARAMS; ++k) cam->params[k] = pinhole_only ? 0.0 : intr[8 + k];
    SIZE(d, DIM_H) = height, SIZE(d, DIM_W) = width;
    opt->sh_degree = sh_degree;
    opt->near = near;
    opt->antialiased = antialiased;
    opt->threads = threads ? threads : sc_cpu_count();
    opt->exhaustive = 0;
    return 0;
}

static int row_finite(const float *v, int64_t n) {
    for (int64_t i = 0; i < n; ++i)
        if (!isfinite(v[i])) return 0;
    return 1;
}

/* Turn a pipeline status into a Python exception naming the culprit. */
static PyObject *raise_status(sc_status status, const sc_gaussians *g, const sc_stats *stats) {
    if (status == SC_ERR_NONFINITE) {
        const int64_t i = stats->error_index;
        const char *what = !row_finite(g->means + 3 * i, 3)            ? "means"
                           : !row_finite(g->log_scales + 3 * i, 3)     ? "log_scales"
                           : !row_finite(g->quats + 4 * i, 4)          ? "quats"
                           : !row_finite(g->opacity_logits + i, 1)     ? "opacity_logits"
                                                                       : "sh";
        return PyErr_Format(PyExc_ValueError,
                            "Gaussian %lld has a non-finite value (NaN or Inf) in %s",
                            (long long)i, what);
    }
    if (status == SC_ERR_STALE)
        return PyErr_Format(PyExc_ValueError,
                            "Gaussian %lld differs from the one render_train drew: the Gaussians "
                            "changed between the forward and the backward pass",
                            (long long)stats->error_index);
    if (status == SC_ERR_TOO_LARGE)
        return PyErr_Format(PyExc_MemoryError,
                            "too many Gaussian/tile overlaps to render this image; "
                            "use a smaller image or fewer, smaller Gaussians");
    return PyErr_NoMemory();
}

static const arg_spec PROJECT_OUTS[] = {
    {"out_xy", 'f', 2, {DIM_N, 2}, WRITABLE},
    {"out_conic", 'f', 2, {DIM_N, 3}, WRITABLE},
    {"out_depth", 'f', 1, {DIM_N}, WRITABLE},
    {"out_opacity", 'f', 1, {DIM_N}, WRITABLE},
    {"out_rgb", 'f', 2, {DIM_N, 3}, WRITABLE},
    {"out_valid", 'B', 1, {DIM_N}, WRITABLE},
};

static PyObject *py_project(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *objs[7], *outs[6];
    int sh_degree, width, height, antialiased, threads;
    double near;
    if (!PyArg_ParseTuple(args, "OOOOOiOOiidpO&OOOOOO:project", &objs[0], &objs[1], &objs[2],
                          &objs[3], &objs[4], &sh_degree, &objs[5], &objs[6], &width, &height,
                          &near, &antialiased, parse_threads, &threads, &outs[0], &outs[1], &outs[2], &outs[3],
                          &outs[4], &outs[5]))
        return NULL;
    buffers b = {.count = 0};
    arg_dims d = ARG_DIMS_INIT;
    sc_gaussians g;
    sc_camera cam;
    sc_options opt;
    const Py_buffer *v[COUNT(PROJECT_OUTS)];
    if (parse_common(&b, &d, objs, sh_degree, width, height, near, antialiased, threads, &g, &cam,
                     &opt) != 0 ||
        check_args(&b, &d, PROJECT_OUTS, COUNT(PROJECT_OUTS), outs, v) != 0) {
        release_all(&b);
        return NULL;
    }
    const Py_ssize_t n = (Py_ssize_t)g.count;
    float *xy = data(v[0]), *conic = data(v[1]), *depth = data(v[2]), *opacity = data(v[3]),
          *rgb = data(v[4]);
    uint8_t *valid = data(v[5]);
    sc_projection proj = {malloc(sizeof(sc_splat) * (size_t)(n ? n : 1)), valid, NULL, 0};
    sc_stats stats = {0};
    sc_status status = SC_ERR_MEMORY;
    if (proj.splats) {
        Py_BEGIN_ALLOW_THREADS
        status = sc_project(&g, &cam, &opt, &proj, &stats);
        for (Py_ssize_t i = 0; status == SC_OK && i < n; ++i) {
            const sc_splat *s = &proj.splats[i];
            xy[2 * i] = s->x, xy[2 * i + 1] = s->y;
            conic[3 * i] = s->ca, conic[3 * i + 1] = s->cb, conic[3 * i + 2] = s->cc;
            depth[i] = s->depth;
            opacity[i] = s->opacity;
            rgb[3 * i] = s->r, rgb[3 * i + 1] = s->g, rgb[3 * i + 2] = s->b;
        }
        Py_END_ALLOW_THREADS
    }
    free(proj.splats);
    PyObject *result = status == SC_OK ? Py_NewRef(Py_None) : raise_status(status, &g, &stats);
    release_all(&b);
    return result;
}

static int set_number(PyObject *dict, const char *key, PyObject *value) {
    if (!value) return -1;
    int rc = PyDict_SetItemString(dict, key, value);
    Py_DECREF(value);
    return rc;
}

static PyObject *stats_dict(const sc_stats *s) {
    PyObject *d = PyDict_New();
    if (!d) return NULL;
    if (set_number(d, "ms_project", PyFloat_FromDouble(s->ms_project)) ||
        set_number(d, "ms_sort", PyFloat_FromDouble(s->ms_sort)) ||
        set_number(d, "ms_bin", PyFloat_FromDouble(s->ms_bin)) ||
        set_number(d, "ms_composite", PyFloat_FromDouble(s->ms_composite)) ||
        set_number(d, "ms_total", PyFloat_FromDouble(s->ms_total)) ||
        set_number(d, "visible", PyLong_FromLongLong(s->visible)) ||
        set_number(d, "tile_pairs", PyLong_FromLongLong(s->tile_pairs)) ||
        set_number(d, "evaluations", PyLong_FromLongLong(s->evaluations)) ||
        set_number(d, "peak_bytes", PyLong_FromLongLong(s->peak_bytes))) {
        Py_DECREF(d);
        return NULL;
    }
    return d;
}

/* Mesh colour must be finite with alpha in [0, 1]; mesh depth must not be NaN (inf is fine). */
static int check_mesh(const float *rgba, const float *depth, int64_t pixels) {
    for (int64_t i = 0; i < pixels; ++i) {
        const float *p = rgba + 4 * i;
        if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2]) || !(p[3] >= 0.0f && p[3] <= 1.0f)) {
            PyErr_Format(PyExc_ValueError,
                         "mesh_rgba pixel %lld is non-finite or has alpha outside [0, 1]", (long long)i);
            return -1;
        }
        if (isnan(depth[i])) {
            PyErr_Format(PyExc_ValueError, "mesh_depth pixel %lld is NaN", (long long)i);
            return -1;
        }
    }
    return 0;
}

static int check_finite_array(const float *v, int64_t n, const char *name) {
    /* One branch-free pass (it vectorises: these arrays are whole images and gradients); the
     * index is looked for only when there is something to report. */
    uint32_t bad = 0;
    for (int64_t i = 0; i < n; ++i) {
        uint32_t bits;
        memcpy(&bits, v + i, sizeof bits);
        bad |= (bits & 0x7f800000u) == 0x7f800000u; /* exponent all ones: Inf or NaN */
    }
    if (!bad) return 0;
    for (int64_t i = 0; i < n; ++i)
        if (!isfinite(v[i])) {
            PyErr_Format(PyExc_ValueError, "%s has a non-finite value (NaN or Inf) at flat index %lld",
                         name, (long long)i);
            return -1;
        }
    return 0;
}

/* The optional background (3) and the three images render() and render_train() write. */
static const arg_spec IMAGE_ARGS[] = {
    {"background", 'f', 1, {3}, OPTIONAL | FINITE},
    {"out_rgb", 'f', 3, {DIM_H, DIM_W, 3}, WRITABLE},
    {"out_alpha", 'f', 2, {DIM_H, DIM_W}, WRITABLE},
    {"out_depth", 'f', 2, {DIM_H, DIM_W}, WRITABLE},
};

/* objs: background, out_rgb, out_alpha, out_depth. */
static int parse_image(buffers *b, arg_dims *d, PyObject *const *objs, sc_image *image) {
    const Py_buffer *v[COUNT(IMAGE_ARGS)];
    if (check_args(b, d, IMAGE_ARGS, COUNT(IMAGE_ARGS), objs, v) != 0) return -1;
    image->background = data(v[0]);
    image->rgb = data(v[1]), image->alpha = data(v[2]), image->depth = data(v[3]);
    return 0;
}

/* render()'s mesh layer: both or neither (checked before). */
static const arg_spec MESH_ARGS[] = {
    {"mesh_rgba", 'f', 3, {DIM_H, DIM_W, 4}, OPTIONAL},
    {"mesh_depth", 'f', 2, {DIM_H, DIM_W}, OPTIONAL},
};

static PyObject *py_render(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *objs[7], *image_objs[4], *mesh_objs[2];
    int sh_degree, width, height, antialiased, threads, exhaustive = 0;
    double near;
    if (!PyArg_ParseTuple(args, "OOOOOiOOiidpO&OOOOOO|p:render", &objs[0], &objs[1], &objs[2],
                          &objs[3], &objs[4], &sh_degree, &objs[5], &objs[6], &width, &height,
                          &near, &antialiased, parse_threads, &threads, &image_objs[0],
                          &mesh_objs[0], &mesh_objs[1], &image_objs[1], &image_objs[2],
                          &image_objs[3], &exhaustive))
        return NULL;
    buffers b = {.count = 0};
    arg_dims d = ARG_DIMS_INIT;
    sc_gaussians g;
    sc_camera cam;
    sc_options opt;
    sc_image image = {0};
    if (parse_common(&b, &d, objs, sh_degree, width, height, near, antialiased, threads, &g, &cam,
                     &opt) != 0)
        goto fail;
    if (parse_image(&b, &d, image_objs, &image) != 0) goto fail;
    opt.exhaustive = exhaustive;
    if ((mesh_objs[0] == Py_None) != (mesh_objs[1] == Py_None)) {
        PyErr_SetString(PyExc_ValueError, "mesh_rgba and mesh_depth must be given together");
        goto fail;
    }
    const Py_buffer *mesh[COUNT(MESH_ARGS)];
    if (check_args(&b, &d, MESH_ARGS, COUNT(MESH_ARGS), mesh_objs, mesh) != 0) goto fail;
    image.mesh_rgba = data(mesh[0]), image.mesh_depth = data(mesh[1]);
    if (image.mesh_rgba &&
        check_mesh(image.mesh_rgba, image.mesh_depth, (int64_t)width * height) != 0)
        goto fail;

    sc_stats stats = {0};
    sc_status status;
    Py_BEGIN_ALLOW_THREADS
    status = sc_render(&g, &cam, &opt, &image, &stats);
    Py_END_ALLOW_THREADS
    PyObject *result = status == SC_OK ? stats_dict(&stats) : raise_status(status, &g, &stats);
    release_all(&b);
    return result;
fail:
    release_all(&b);
    return NULL;
}

/* ---------------------------------------------------------------- training */

static const char STATE_NAME[] = "splatcore.TrainState";

static void state_destructor(PyObject *capsule) {
    sc_train_state *state = PyCapsule_GetPointer(capsule, STATE_NAME);
    if (!state) {
        PyErr_Clear();
        return;
    }
    sc_train_state_free(state);
    free(state);
}

static sc_train_state *get_state(PyObject *obj) {
    if (!PyCapsule_IsValid(obj, STATE_NAME)) {
        PyErr_SetString(PyExc_TypeError,
                        "state must be the training state that render_train returned");
        return NULL;
    }
    return PyCapsule_GetPointer(obj, STATE_NAME);
}

/* render_train()'s optional per-pixel and per-Gaussian outputs. */
static const arg_spec TRAIN_OUTS[] = {
    {"out_final_t", 'f', 2, {DIM_H, DIM_W}, WRITABLE | OPTIONAL},
    {"out_n_contrib", 'i', 2, {DIM_H, DIM_W}, WRITABLE | OPTIONAL},
    {"out_visible", 'B', 1, {DIM_N}, WRITABLE | OPTIONAL},
};

static PyObject *py_render_train(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *objs[7], *image_objs[4], *outs[3];
    int sh_degree, width, height, antialiased, threads, exhaustive = 0;
    double near;
    if (!PyArg_ParseTuple(args, "OOOOOiOOiidpO&OOOOOOO|p:render_train", &objs[0], &objs[1],
                          &objs[2], &objs[3], &objs[4], &sh_degree, &objs[5], &objs[6], &width,
                          &height, &near, &antialiased, parse_threads, &threads, &image_objs[0],
                          &image_objs[1], &image_objs[2], &image_objs[3], &outs[0], &outs[1],
                          &outs[2], &exhaustive))
        return NULL;
    buffers b = {.count = 0};
    arg_dims d = ARG_DIMS_INIT;
    sc_gaussians g;
    sc_camera cam;
    sc_options opt;
    sc_image image = {0};
    const Py_buffer *v[COUNT(TRAIN_OUTS)];
    if (parse_common(&b, &d, objs, sh_degree, width, height, near, antialiased, threads, &g, &cam,
                     &opt) != 0)
        goto fail;
    opt.exhaustive = exhaustive;
    if (cam.model != SC_PINHOLE || cam.aperture > 0) {
        PyErr_SetString(PyExc_ValueError, "training renders through pinhole cameras only (no "
                                          "depth of field)");
        goto fail;
    }
    if (parse_image(&b, &d, image_objs, &image) != 0 ||
        check_args(&b, &d, TRAIN_OUTS, COUNT(TRAIN_OUTS), outs, v) != 0)
        goto fail;
    float *out_t = data(v[0]);
    int32_t *out_n = data(v[1]);
    uint8_t *out_visible = data(v[2]);

    sc_train_state *state = calloc(1, sizeof *state);
    if (!state) {
        PyErr_NoMemory();
        goto fail;
    }
    sc_stats stats = {0};
    sc_status status;
    const size_t pixels = (size_t)width * (size_t)height;
    Py_BEGIN_ALLOW_THREADS
    status = sc_render_train(&g, &cam, &opt, &image, state, &stats);
    if (status == SC_OK && out_t) memcpy(out_t, state->final_t, sizeof(float) * pixels);
    if (status == SC_OK && out_n) memcpy(out_n, state->n_contrib, sizeof(int32_t) * pixels);
    if (status == SC_OK && out_visible) {
        memset(out_visible, 0, (size_t)g.count);
        for (int64_t k = 0; k < state->frame.drawn; ++k) out_visible[state->frame.order[k]] = 1;
    }
    Py_END_ALLOW_THREADS
    if (status != SC_OK) {
        sc_train_state_free(state);
        free(state);
        raise_status(status, &g, &stats);
        goto fail;
    }
    release_all(&b);
    PyObject *capsule = PyCapsule_New(state, STATE_NAME, state_destructor);
    if (!capsule) {
        sc_train_state_free(state);
        free(state);
        return NULL;
    }
    PyObject *stats_obj = stats_dict(&stats);
    if (!stats_obj) {
        Py_DECREF(capsule);
        return NULL;
    }
    PyObject *result = PyTuple_Pack(2, stats_obj, capsule);
    Py_DECREF(stats_obj);
    Py_DECREF(capsule);
    return result;
fail:
    release_all(&b);
    return NULL;
}

static PyObject *py_train_state_info(PyObject *self, PyObject *arg) {
    (void)self;
    const sc_train_state *st = get_state(arg);
    if (!st) return NULL;
    return Py_BuildValue("{s:i,s:i,s:L,s:i,s:i,s:O,s:d,s:L,s:L,s:O}", "width", st->camera.width,
                         "height", st->camera.height, "count", (long long)st->count, "sh_coeffs",
                         st->sh_coeffs, "sh_degree", st->options.sh_degree, "antialiased",
                         st->options.antialiased ? Py_True : Py_False, "near", st->options.near,
                         "drawn", (long long)st->frame.drawn, "tile_pairs",
                         (long long)st->frame.offsets[st->frame.ntiles], "background",
                         st->has_background ? Py_True : Py_False);
}

/* backward()'s loss gradients (in) and the Gaussians' gradients (out). */
static const arg_spec BACKWARD_ARGS[] = {
    {"d_rgb", 'f', 3, {DIM_H, DIM_W, 3}, FINITE},
    {"d_alpha", 'f', 2, {DIM_H, DIM_W}, OPTIONAL | FINITE},
    {"d_depth", 'f', 2, {DIM_H, DIM_W}, OPTIONAL | FINITE},
    {"out_means", 'f', 2, {DIM_N, 3}, WRITABLE},
    {"out_log_scales", 'f', 2, {DIM_N, 3}, WRITABLE},
    {"out_quats", 'f', 2, {DIM_N, 4}, WRITABLE},
    {"out_opacity_logits", 'f', 1, {DIM_N}, WRITABLE},
    {"out_sh", 'f', 3, {DIM_N, DIM_K, 3}, WRITABLE},
    {"out_xy", 'f', 2, {DIM_N, 2}, WRITABLE},
    {"out_xy_abs", 'f', 2, {DIM_N, 2}, WRITABLE},
};

static PyObject *py_backward(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *state_obj, *objs[5], *rest[COUNT(BACKWARD_ARGS)];
    int threads;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOO&OOOOOOO:backward", &state_obj, &objs[0], &objs[1],
                          &objs[2], &objs[3], &objs[4], &rest[0], &rest[1], &rest[2],
                          parse_threads, &threads, &rest[3], &rest[4], &rest[5], &rest[6],
                          &rest[7], &rest[8], &rest[9]))
        return NULL;
    const sc_train_state *state = get_state(state_obj);
    if (!state) return NULL;
    if (threads < 0) {
        PyErr_Format(PyExc_ValueError, "threads must be >= 0 (0 = all cores), got %d", threads);
        return NULL;
    }
    buffers b = {.count = 0};
    arg_dims d = ARG_DIMS_INIT;
    sc_gaussians g;
    if (parse_gaussians(&b, &d, objs, &g) != 0) goto fail;
    if (g.count != state->count || g.sh_coeffs != state->sh_coeffs) {
        PyErr_Format(PyExc_ValueError,
                     "the Gaussians (N=%lld, K=%d) are not those render_train drew (N=%lld, K=%d)",
                     (long long)g.count, g.sh_coeffs, (long long)state->count, state->sh_coeffs);
        goto fail;
    }
    SIZE(&d, DIM_H) = state->camera.height, SIZE(&d, DIM_W) = state->camera.width;
    const Py_buffer *v[COUNT(BACKWARD_ARGS)];
    if (check_args(&b, &d, BACKWARD_ARGS, COUNT(BACKWARD_ARGS), rest, v) != 0) goto fail;
    const float *d_rgb = data(v[0]), *d_alpha = data(v[1]), *d_depth = data(v[2]);
    sc_gaussian_grads out = {data(v[3]), data(v[4]), data(v[5]), data(v[6]), data(v[7]),
                             data(v[8]), data(v[9])};

    sc_backward_stats stats = {0};
    sc_status status;
    Py_BEGIN_ALLOW_THREADS
    status = sc_backward(state, &g, d_rgb, d_alpha, d_depth, threads ? threads : sc_cpu_count(),
                         &out, &stats);
    Py_END_ALLOW_THREADS
    if (status != SC_OK) {
        sc_stats s = {.error_index = stats.error_index};
        raise_status(status, &g, &s);
        goto fail;
    }
    release_all(&b);
    return Py_BuildValue("{s:d,s:d,s:d,s:L,s:L}", "ms_composite", stats.ms_composite,
                         "ms_project", stats.ms_project, "ms_total", stats.ms_total,
                         "evaluations", (long long)stats.evaluations, "flushed",
                         (long long)stats.flushed);
fail:
    release_all(&b);
    return NULL;
}

static const arg_spec L1_SSIM_ARGS[] = {
    {"image", 'f', 3, {DIM_H, DIM_W, 3}, FINITE},
    {"target", 'f', 3, {DIM_H, DIM_W, 3}, FINITE},
    {"out_grad", 'f', 3, {DIM_H, DIM_W, 3}, WRITABLE | OPTIONAL},
};

static PyObject *py_l1_ssim(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *image_obj, *target_obj, *grad_obj;
    double lambda;
    int threads;
    if (!PyArg_ParseTuple(args, "OOdO&O:l1_ssim", &image_obj, &target_obj, &lambda, parse_threads, &threads,
                          &grad_obj))
        return NULL;
    if (!(lambda >= 0.0 && lambda <= 1.0)) {
        value_error("lambda_dssim must be in [0, 1], got %g", lambda);
        return NULL;
    }
    if (threads < 0) {
        PyErr_Format(PyExc_ValueError, "threads must be >= 0 (0 = all cores), got %d", threads);
        return NULL;
    }
    buffers b = {.count = 0};
    arg_dims d = ARG_DIMS_INIT;
    PyObject *objs[] = {image_obj, target_obj, grad_obj};
    const Py_buffer *v[COUNT(L1_SSIM_ARGS)];
    if (check_args(&b, &d, L1_SSIM_ARGS, 1, objs, v) != 0) goto fail;
    const Py_ssize_t height = SIZE(&d, DIM_H), width = SIZE(&d, DIM_W);
    if (height < 1 || width < 1 || height > MAX_SIDE || width > MAX_SIDE ||
        (long long)width * height > MAX_PIXELS) {
        PyErr_Format(PyExc_ValueError,
                     "image size %zdx%zd is invalid: sides must be 1..%d and at most %lld pixels",
                     width, height, (int)MAX_SIDE, MAX_PIXELS);
        goto fail;
    }
    if (check_args(&b, &d, L1_SSIM_ARGS + 1, COUNT(L1_SSIM_ARGS) - 1, objs + 1, v + 1) != 0)
        goto fail;
    const float *image = data(v[0]), *target = data(v[1]);
    float *grad = data(v[2]);
    double loss = 0, l1 = 0, ssim = 0, mse = 0;
    sc_status status;
    Py_BEGIN_ALLOW_THREADS
    status = sc_l1_ssim(image, target, (int)width, (int)height, lambda,
                        threads ? threads : sc_cpu_count(), grad, &loss, &l1, &ssim, &mse);
    Py_END_ALLOW_THREADS
    release_all(&b);
    if (status != SC_OK) return PyErr_NoMemory();
    return Py_BuildValue("(dddd)", loss, l1, ssim, mse);
fail:
    release_all(&b);
    return NULL;
}

/* adam()'s arrays: param of any shape, its gradient and moments of the same, the row mask. Every
 * value of grad is checked, those the update skips too: one flat pass is faster than a pass per
 * row. */
static const arg_spec ADAM_ARGS[] = {
    {"param", 'f', 0, {0}, ANY_RANK | WRITABLE},
    {"grad", 'f', 0, {0}, LIKE | FINITE},
    {"exp_avg", 'f', 0, {0}, LIKE | WRITABLE},
    {"exp_avg_sq", 'f', 0, {0}, LIKE | WRITABLE},
    {"rows", 'B', 1, {DIM_ROWS}, OPTIONAL},
};

static PyObject *py_adam(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *objs[4], *mask_obj = Py_None;
    sc_adam_options o;
    long long step, lead = 0, used = -1;
    double lead_lr = NAN;
    int threads;
    if (!PyArg_ParseTuple(args, "OOOOddddLO&|OLdL:adam", &objs[0], &objs[1], &objs[2], &objs[3],
                          &o.lr, &o.beta1, &o.beta2, &o.eps, &step, parse_threads, &threads,
                          &mask_obj, &lead, &lead_lr, &used))
        return NULL;
    o.step = step;
    if (isnan(lead_lr)) lead_lr = o.lr;
    if (!isfinite(o.lr) || o.lr < 0) return value_error("lr must be finite and >= 0, got %g", o.lr), NULL;
    if (!isfinite(lead_lr) || lead_lr < 0)
        return value_error("lead_lr must be finite and >= 0, got %g", lead_lr), NULL;
    if (!(o.beta1 >= 0 && o.beta1 < 1) || !(o.beta2 >= 0 && o.beta2 < 1))
        return value_error("beta1 and beta2 must be in [0, 1), got %g, %g", o.beta1, o.beta2), NULL;
    if (!(o.eps > 0) || !isfinite(o.eps))
        return value_error("eps must be finite and > 0, got %g", o.eps), NULL;
    if (step < 1) return PyErr_Format(PyExc_ValueError, "step must be >= 1 (the first update is 1), got %lld", step);
    if (threads < 0)
        return PyErr_Format(PyExc_ValueError, "threads must be >= 0 (0 = all cores), got %d", threads);
    buffers b = {.count = 0};
    arg_dims d = ARG_DIMS_INIT;
    const Py_buffer *views[COUNT(ADAM_ARGS)];
    if (check_args(&b, &d, ADAM_ARGS, 4, objs, views) != 0) goto fail;
    const Py_buffer *like = views[0];
    const int64_t n = (int64_t)(like->len / 4);
    /* Rows along the first axis (a 0-d array is one row). */
    const int64_t rows = like->ndim > 0 ? (int64_t)like->shape[0] : 1;
    const int64_t width = rows > 0 ? n / rows : 0;
    SIZE(&d, DIM_ROWS) = (Py_ssize_t)rows;
    if (check_args(&b, &d, ADAM_ARGS + 4, 1, &mask_obj, views + 4) != 0) goto fail;
    float *param = data(views[0]), *m = data(views[2]), *v = data(views[3]);
    const float *grad = data(views[1]);
    const uint8_t *mask = data(views[4]);
    if (used < 0) used = width;
    if (used > width) {
        PyErr_Format(PyExc_ValueError, "used must be in 0..%lld (the values in a row), got %lld",
                     (long long)width, used);
        goto fail;
    }
    if (lead < 0 || lead > used) {
        PyErr_Format(PyExc_ValueError, "lead must be in 0..%lld (the values in a row updated), "
                     "got %lld", (long long)used, lead);
        goto fail;
    }
    Py_BEGIN_ALLOW_THREADS
    sc_adam_rows(param, grad, m, v, rows, width, mask, lead, lead_lr, used, &o,
                 threads ? threads : sc_cpu_count());
    Py_END_ALLOW_THREADS
    release_all(&b);
    Py_RETURN_NONE;
fail:
    release_all(&b);
    return NULL;
}

/* position_noise(means, log_scales, quats, opacity_logits, noise, scale, threads): see
 * sc_position_noise. float32 parameters (means writable) of N rows, noise (N, 3) float64. */
static const arg_spec POSITION_NOISE_ARGS[] = {
    {"means", 'f', 2, {DIM_N, 3}, WRITABLE},
    {"log_scales", 'f', 2, {DIM_N, 3}, 0},
    {"quats", 'f', 2, {DIM_N, 4}, 0},
    {"opacity_logits", 'f', 1, {DIM_N}, 0},
    {"noise", 'd', 2, {DIM_N, 3}, 0},
};

static PyObject *py_position_noise(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *objs[5];
    double scale;
    int threads;
    if (!PyArg_ParseTuple(args, "OOOOOdO&:position_noise", &objs[0], &objs[1], &objs[2],
                          &objs[3], &objs[4], &scale, parse_threads, &threads))
        return NULL;
    if (!isfinite(scale)) return value_error("scale must be finite, got %g", scale), NULL;
    buffers b = {.count = 0};
    arg_dims d = ARG_DIMS_INIT;
    const Py_buffer *v[COUNT(POSITION_NOISE_ARGS)];
    if (check_args(&b, &d, POSITION_NOISE_ARGS, COUNT(POSITION_NOISE_ARGS), objs, v) != 0)
        goto fail;
    const Py_ssize_t n = SIZE(&d, DIM_N);
    float *means = data(v[0]);
    const float *log_scales = data(v[1]), *quats = data(v[2]), *logits = data(v[3]);
    const double *noise = data(v[4]);
    Py_BEGIN_ALLOW_THREADS
    sc_position_noise(means, log_scales, quats, logits, noise, n, scale,
                      threads ? threads : sc_cpu_count());
    Py_END_ALLOW_THREADS
    release_all(&b);
    Py_RETURN_NONE;
fail:
    release_all(&b);
    return NULL;
}

/* srgb_premultiplied(src, dst, decode, threads): see sc_srgb_premultiplied. Both float32,
 * C-contiguous, of one shape (..., 4); dst writable and either src itself or not overlapping it. */
static const arg_spec SRGB_PREMULTIPLIED_ARGS[] = {
    {"rgba", 'f', 0, {0}, ANY_RANK},
    {"out", 'f', 0, {0}, LIKE | WRITABLE},
};

static PyObject *py_srgb_premultiplied(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *src_obj, *dst_obj;
    int decode, threads;
    if (!PyArg_ParseTuple(args, "OOpO&:srgb_premultiplied", &src_obj, &dst_obj, &decode,
                          parse_threads, &threads))
        return NULL;
    buffers b = {.count = 0};
    arg_dims dims = ARG_DIMS_INIT;
    PyObject *objs[] = {src_obj, dst_obj};
    const Py_buffer *v[COUNT(SRGB_PREMULTIPLIED_ARGS)];
    if (check_args(&b, &dims, SRGB_PREMULTIPLIED_ARGS, 1, objs, v) != 0) goto fail;
    const Py_buffer *like = v[0];
    const int64_t n = (int64_t)(like->len / 4);
    if (like->ndim < 1 || like->shape[like->ndim - 1] != 4) {
        PyErr_Format(PyExc_ValueError, "rgba must have shape (..., 4), got %d dimensions ending in %zd",
                     like->ndim, like->ndim ? like->shape[like->ndim - 1] : (Py_ssize_t)0);
        goto fail;
    }
    if (check_args(&b, &dims, SRGB_PREMULTIPLIED_ARGS + 1, 1, objs + 1, v + 1) != 0) goto fail;
    const float *src = data(v[0]);
    float *dst = data(v[1]);
    const char *a = (const char *)src, *d = (const char *)dst;
    if (a != d && a < d + 4 * n && d < a + 4 * n) {
        PyErr_SetString(PyExc_ValueError, "out must be rgba itself or not overlap it");
        goto fail;
    }
    Py_BEGIN_ALLOW_THREADS
    sc_srgb_premultiplied(src, dst, n / 4, decode, threads ? threads : sc_cpu_count());
    Py_END_ALLOW_THREADS
    release_all(&b);
    Py_RETURN_NONE;
fail:
    release_all(&b);
    return NULL;
}

/* A checked (H, W, 4) float32 view with any strides as an sc_rgba_view. */
static sc_rgba_view rgba_view(const Py_buffer *v) {
    return (sc_rgba_view){(const char *)v->buf, v->shape[0], v->shape[1], v->strides[0],
                          v->strides[1], v->strides[2]};
}

/* A checked (H, W) float32 view with any strides as an sc_plane_view. */
static sc_plane_view plane_view(const Py_buffer *v) {
    return (sc_plane_view){(const char *)v->buf, v->shape[0], v->shape[1], v->strides[0],
                           v->strides[1]};
}

/* The bytes a view spans, [*low, *high). */
static void view_extent(const Py_buffer *v, const char **low, const char **high) {
    const char *lo = v->buf, *hi = (const char *)v->buf + v->itemsize;
    for (int i = 0; i < v->ndim; ++i) {
        const Py_ssize_t reach = (v->shape[i] - 1) * (v->strides ? v->strides[i] : 0);
        if (v->shape[i] == 0) return (void)(*low = *high = v->buf);
        if (reach < 0) lo += reach;
        else hi += reach;
    }
    *low = lo, *high = hi;
}

static int overlap(const Py_buffer *a, const Py_buffer *b) {
    const char *a0, *a1, *b0, *b1;
    view_extent(a, &a0, &a1);
    view_extent(b, &b0, &b1);
    return a0 < b1 && b0 < a1;
}

static int same_view(const Py_buffer *a, const Py_buffer *b) {
    if (a->buf != b->buf || a->ndim != b->ndim) return 0;
    for (int i = 0; i < a->ndim; ++i)
        if (a->shape[i] != b->shape[i] || a->strides[i] != b->strides[i]) return 0;
    return 1;
}

/* srgb_view(rgba, out, decode, zero_non_finite, threads): see sc_srgb_view. (H, W, 4) float32
 * arrays of one shape with any strides; out writable, rgba itself or not overlapping it. */
static const arg_spec SRGB_VIEW_ARGS[] = {
    {"rgba", 'f', 3, {DIM_H, DIM_W, 4}, STRIDED},
    {"out", 'f', 3, {DIM_H, DIM_W, 4}, STRIDED | WRITABLE},
};

static PyObject *py_srgb_view(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *src_obj, *dst_obj;
    int decode, zero_non_finite, threads;
    if (!PyArg_ParseTuple(args, "OOppO&:srgb_view", &src_obj, &dst_obj, &decode, &zero_non_finite,
                          parse_threads, &threads))
        return NULL;
    buffers b = {.count = 0};
    arg_dims d = ARG_DIMS_INIT;
    PyObject *objs[] = {src_obj, dst_obj};
    const Py_buffer *v[COUNT(SRGB_VIEW_ARGS)];
    if (check_args(&b, &d, SRGB_VIEW_ARGS, COUNT(SRGB_VIEW_ARGS), objs, v) != 0) goto fail;
    const sc_rgba_view src = rgba_view(v[0]), dst = rgba_view(v[1]);
    if (!same_view(&b.views[0], &b.views[1]) && overlap(&b.views[0], &b.views[1])) {
        PyErr_SetString(PyExc_ValueError, "out must be rgba itself or not overlap it");
        goto fail;
    }
    Py_BEGIN_ALLOW_THREADS
    sc_srgb_view(&src, &dst, decode, zero_non_finite, threads ? threads : sc_cpu_count());
    Py_END_ALLOW_THREADS
    release_all(&b);
    Py_RETURN_NONE;
fail:
    release_all(&b);
    return NULL;
}

/* srgb_decode_changed(rgb, alpha, mesh, layer, threads, out=layer): see sc_srgb_decode_changed.
 * float32 (H, W, 3), (H, W), (H, W, 4), (H, W, 4) C-contiguous but mesh (any strides); out
 * (H, W, 4) writable, any strides, layer itself or not overlapping it, overlapping none of the
 * others. */
static PyObject *py_srgb_decode_changed(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *objs[4], *out_obj = Py_None;
    int threads;
    if (!PyArg_ParseTuple(args, "OOOOO&|O:srgb_decode_changed", &objs[0], &objs[1], &objs[2],
                          &objs[3], parse_threads, &threads, &out_obj))
        return NULL;
    buffers b = {.count = 0};
    arg_dims d = ARG_DIMS_INIT;
    const int in_place = out_obj == Py_None;
    /* In place, layer is checked twice: C-contiguous (read), then as a writable view. */
    const arg_spec specs[] = {
        {"rgb", 'f', 3, {DIM_H, DIM_W, 3}, 0},
        {"alpha", 'f', 2, {DIM_H, DIM_W}, 0},
        {"mesh", 'f', 3, {DIM_H, DIM_W, 4}, STRIDED},
        {"layer", 'f', 3, {DIM_H, DIM_W, 4}, in_place ? WRITABLE : 0},
        {in_place ? "layer" : "out", 'f', 3, {DIM_H, DIM_W, 4}, STRIDED | WRITABLE},
    };
    PyObject *const all[] = {objs[0], objs[1], objs[2], objs[3], in_place ? objs[3] : out_obj};
    const Py_buffer *v[COUNT(specs)];
    if (check_args(&b, &d, specs, COUNT(specs), all, v) != 0) goto fail;
    const float *rgb = data(v[0]), *alpha = data(v[1]), *layer = data(v[3]);
    const sc_rgba_view mesh = rgba_view(v[2]), out = rgba_view(v[4]);
    const Py_buffer *out_view = &b.views[4];
    for (int i = 0; i < 3; ++i)
        if (overlap(out_view, &b.views[i])) {
            PyErr_Format(PyExc_ValueError, "%s must not overlap rgb, alpha or mesh",
                         in_place ? "layer" : "out");
            goto fail;
        }
    if (!same_view(out_view, &b.views[3]) && overlap(out_view, &b.views[3])) {
        PyErr_SetString(PyExc_ValueError, "out must be layer itself or not overlap it");
        goto fail;
    }
    Py_BEGIN_ALLOW_THREADS
    sc_srgb_decode_changed(rgb, alpha, &mesh, layer, &out, threads ? threads : sc_cpu_count());
    Py_END_ALLOW_THREADS
    release_all(&b);
    Py_RETURN_NONE;
fail:
    release_all(&b);
    return NULL;
}

static const char PREPARED_NAME[] = "splatcore.Prepared";

static void prepared_destructor(PyObject *capsule) {
    sc_prepared *p = PyCapsule_GetPointer(capsule, PREPARED_NAME);
    if (!p) {
        PyErr_Clear();
        return;
    }
    sc_prepared_free(p);
}

/* compose_prepare(means, ..., sh_degree, world_to_camera, intrinsics, width, height, near,
 * antialiased, threads[, exhaustive]) -> (prepared, stats): see sc_compose_prepare. The
 * Gaussians' arrays are not kept (the prepared frame holds its own copies). */
static PyObject *py_compose_prepare(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *objs[7];
    int sh_degree, width, height, antialiased, threads, exhaustive = 0;
    double near;
    if (!PyArg_ParseTuple(args, "OOOOOiOOiidpO&|p:compose_prepare", &objs[0], &objs[1], &objs[2],
                          &objs[3], &objs[4], &sh_degree, &objs[5], &objs[6], &width, &height,
                          &near, &antialiased, parse_threads, &threads, &exhaustive))
        return NULL;
    buffers b = {.count = 0};
    arg_dims d = ARG_DIMS_INIT;
    sc_gaussians g;
    sc_camera cam;
    sc_options opt;
    if (parse_common(&b, &d, objs, sh_degree, width, height, near, antialiased, threads, &g, &cam,
                     &opt) != 0) {
        release_all(&b);
        return NULL;
    }
    opt.exhaustive = exhaustive;
    sc_stats stats = {0};
    sc_prepared *prepared = NULL;
    sc_status status;
    Py_BEGIN_ALLOW_THREADS
    status = sc_compose_prepare(&g, &cam, &opt, &prepared, &stats);
    Py_END_ALLOW_THREADS
    if (status != SC_OK) {
        PyObject *error = raise_status(status, &g, &stats);
        release_all(&b);
        return error;
    }
    release_all(&b);
    PyObject *capsule = PyCapsule_New(prepared, PREPARED_NAME, prepared_destructor);
    if (!capsule) {
        sc_prepared_free(prepared);
        return NULL;
    }
    PyObject *dict = stats_dict(&stats);
    if (!dict) {
        Py_DECREF(capsule);
        return NULL;
    }
    return Py_BuildValue("(NN)", capsule, dict);
}

/* compose_srgb(prepared, mesh, mesh_depth, out, out_depth, far) -> stats: see sc_compose_srgb.
 * mesh (H, W, 4) and mesh_depth (H, W) float32, any strides, of the prepared camera's size; out
 * (H, W, 4) writable, any strides, overlapping none of the others; out_depth (H, W) float32
 * C-contiguous, writable, overlapping neither mesh nor mesh_depth, or None (no depth). */
static const arg_spec COMPOSE_SRGB_ARGS[] = {
    {"mesh_rgba", 'f', 3, {DIM_H, DIM_W, 4}, STRIDED},
    {"mesh_depth", 'f', 2, {DIM_H, DIM_W}, STRIDED},
    {"out", 'f', 3, {DIM_H, DIM_W, 4}, STRIDED | WRITABLE},
    {"out_depth", 'f', 2, {DIM_H, DIM_W}, WRITABLE | OPTIONAL},
};

static PyObject *py_compose_srgb(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *capsule, *mesh_obj, *depth_obj, *out_obj, *out_depth_obj;
    double far;
    if (!PyArg_ParseTuple(args, "OOOOOd:compose_srgb", &capsule, &mesh_obj, &depth_obj, &out_obj,
                          &out_depth_obj, &far))
        return NULL;
    if (!PyCapsule_IsValid(capsule, PREPARED_NAME)) {
        PyErr_SetString(PyExc_TypeError, "prepared must be what compose_prepare returned");
        return NULL;
    }
    const sc_prepared *prepared = PyCapsule_GetPointer(capsule, PREPARED_NAME);
    int width, height;
    sc_prepared_size(prepared, &width, &height);
    buffers b = {.count = 0};
    arg_dims d = ARG_DIMS_INIT;
    SIZE(&d, DIM_H) = height, SIZE(&d, DIM_W) = width;
    PyObject *objs[] = {mesh_obj, depth_obj, out_obj, out_depth_obj};
    const Py_buffer *v[COUNT(COMPOSE_SRGB_ARGS)];
    if (check_args(&b, &d, COMPOSE_SRGB_ARGS, COUNT(COMPOSE_SRGB_ARGS), objs, v) != 0) goto fail;
    const sc_rgba_view mesh = rgba_view(v[0]), out = rgba_view(v[2]);
    const sc_plane_view mesh_depth = plane_view(v[1]);
    float *out_depth = data(v[3]);
    for (int i = 0; i < b.count; ++i)
        for (int k = i + 1; k < b.count; ++k)
            if (i != 0 || k != 1) /* the two inputs may share a buffer */
                if (overlap(&b.views[i], &b.views[k])) {
                    PyErr_SetString(PyExc_ValueError,
                                    "out and out_depth must overlap neither each other nor the "
                                    "mesh layers");
                    goto fail;
                }
    if (!isfinite(far)) {
        PyErr_SetString(PyExc_ValueError, "far must be finite");
        goto fail;
    }
    sc_stats stats = {0};
    double colour_ms = 0.0;
    sc_status status;
    Py_BEGIN_ALLOW_THREADS
    status = sc_compose_srgb(prepared, &mesh, &mesh_depth, &out, out_depth, (float)far, &stats,
                             &colour_ms);
    Py_END_ALLOW_THREADS
    PyObject *result = status == SC_OK ? stats_dict(&stats) : raise_status(status, NULL, &stats);
    if (result && set_number(result, "ms_colour_cpu", PyFloat_FromDouble(colour_ms)) != 0)
        Py_CLEAR(result);
    release_all(&b);
    return result;
fail:
    release_all(&b);
    return NULL;
}

/* checksum(buffer) -> (lane0, lane1, lane2, lane3): see sc_checksum. Any C-contiguous buffer. */
static PyObject *py_checksum(PyObject *self, PyObject *arg) {
    (void)self;
    Py_buffer view;
    if (PyObject_GetBuffer(arg, &view, PyBUF_SIMPLE) != 0) {
        PyErr_Clear();
        PyErr_SetString(PyExc_TypeError, "checksum needs a C-contiguous buffer");
        return NULL;
    }
    uint64_t lanes[4];
    Py_BEGIN_ALLOW_THREADS
    sc_checksum(view.buf, (int64_t)view.len, lanes);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&view);
    return Py_BuildValue("(KKKK)", (unsigned long long)lanes[0], (unsigned long long)lanes[1],
                         (unsigned long long)lanes[2], (unsigned long long)lanes[3]);
}

static PyObject *py_composite_microbench(PyObject *self, PyObject *args) {
    (void)self;
    int count, iterations;
    if (!PyArg_ParseTuple(args, "ii:composite_microbench", &count, &iterations)) return NULL;
    if (count < 1 || count > 4096 || iterations < 1) {
        PyErr_SetString(PyExc_ValueError, "count must be 1..4096 and iterations >= 1");
        return NULL;
    }
    double seconds;
    Py_BEGIN_ALLOW_THREADS
    seconds = sc_composite_microbench(count, iterations);
    Py_END_ALLOW_THREADS
    return PyFloat_FromDouble(seconds);
}

/* sort_keys(keys, threads, out_order) -> count of keys not +inf: see sc_sort_keys. keys float32 (N,),
 * out_order int32 (N,) writable. */
static const arg_spec SORT_KEYS_ARGS[] = {
    {"keys", 'f', 1, {DIM_ROWS}, 0},
    {"out_order", 'i', 1, {DIM_ROWS}, WRITABLE},
};

static PyObject *py_sort_keys(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *keys_obj, *order_obj;
    int threads;
    if (!PyArg_ParseTuple(args, "OO&O:sort_keys", &keys_obj, parse_threads, &threads, &order_obj))
        return NULL;
    buffers b = {.count = 0};
    arg_dims d = ARG_DIMS_INIT;
    PyObject *objs[] = {keys_obj, order_obj};
    const Py_buffer *v[COUNT(SORT_KEYS_ARGS)];
    if (check_args(&b, &d, SORT_KEYS_ARGS, 1, objs, v) != 0) goto fail;
    const Py_ssize_t n = SIZE(&d, DIM_ROWS);
    if (n > MAX_GAUSSIANS) {
        PyErr_Format(PyExc_ValueError, "at most %lld keys, got %zd", MAX_GAUSSIANS, n);
        goto fail;
    }
    if (check_args(&b, &d, SORT_KEYS_ARGS + 1, 1, objs + 1, v + 1) != 0) goto fail;
    const float *keys = data(v[0]);
    int32_t *order = data(v[1]);
    sc_stats stats = {0};
    int64_t finite = 0;
    sc_status status;
    Py_BEGIN_ALLOW_THREADS
    status = sc_sort_keys(keys, n, threads ? threads : sc_cpu_count(), order, &finite, &stats);
    Py_END_ALLOW_THREADS
    if (status == SC_ERR_NONFINITE) {
        PyErr_Format(PyExc_ValueError, "key %lld is NaN", (long long)stats.error_index);
        goto fail;
    }
    if (status != SC_OK) {
        PyErr_NoMemory();
        goto fail;
    }
    release_all(&b);
    return PyLong_FromLongLong(finite);
fail:
    release_all(&b);
    return NULL;
}

static PyObject *py_release_buffers(PyObject *self, PyObject *args) {
    (void)self, (void)args;
    sc_release_buffers();
    Py_RETURN_NONE;
}

static PyObject *py_cpu_count(PyObject *self, PyObject *args) {
    (void)self, (void)args;
    return PyLong_FromLong(sc_cpu_count());
}

static PyMethodDef methods[] = {
    {"project", py_project, METH_VARARGS,
     "project(means, log_scales, quats, opacity_logits, sh, sh_degree, world_to_camera, "
     "intrinsics, width, height, near, antialiased, threads, out_xy, out_conic, out_depth, "
     "out_opacity, out_rgb, out_valid)\n\nProject every Gaussian; fills the out_* arrays."},
    {"render", py_render, METH_VARARGS,
     "render(means, log_scales, quats, opacity_logits, sh, sh_degree, world_to_camera, "
     "intrinsics, width, height, near, antialiased, threads, background, mesh_rgba, mesh_depth, "
     "out_rgb, out_alpha, out_depth[, exhaustive]) -> stats\n\nRender into the out_* arrays; "
     "returns timings (ms) and counts. exhaustive: evaluate each Gaussian over its tiles' whole "
     "bounding spans (the same image, for tests)."},
    {"compose_prepare", py_compose_prepare, METH_VARARGS,
     "compose_prepare(means, log_scales, quats, opacity_logits, sh, sh_degree, world_to_camera, "
     "intrinsics, width, height, near, antialiased, threads[, exhaustive]) -> (prepared, stats)"
     "\n\nF12's composite, the Gaussians' half (sc_compose_prepare): projected, sorted and "
     "binned for the camera; no mesh needed yet."},
    {"compose_srgb", py_compose_srgb, METH_VARARGS,
     "compose_srgb(prepared, mesh_rgba, mesh_depth, out, out_depth, far) -> stats\n\n"
     "F12's composite (sc_compose_srgb): the prepared Gaussians over a scene-linear mesh render, "
     "composed in display sRGB, into out (scene-linear) and out_depth (None: no depth); tiles "
     "no Gaussian reaches keep the mesh's pixels."},
    {"checksum", py_checksum, METH_O,
     "checksum(buffer) -> tuple of four ints\n\nA 256-bit checksum of a C-contiguous buffer's "
     "bytes (sc_checksum): any change within 193 consecutive bits changes it."},
    {"sort_keys", py_sort_keys, METH_VARARGS,
     "sort_keys(keys, threads, out_order) -> int\n\nThe renderer's depth sort on its own (for "
     "tests): out_order (int32, N) gets the stable ascending order of keys (float32, N; +inf "
     "last, -0 before +0, no NaN); returns how many keys are not +inf."},
    {"release_buffers", py_release_buffers, METH_NOARGS,
     "release_buffers()\n\nFree the working buffers renders keep for the next frame."},
    {"render_train", py_render_train, METH_VARARGS,
     "render_train(means, log_scales, quats, opacity_logits, sh, sh_degree, world_to_camera, "
     "intrinsics, width, height, near, antialiased, threads, background, out_rgb, out_alpha, "
     "out_depth, out_final_t, out_n_contrib, out_visible[, exhaustive]) -> (stats, state)\n\n"
     "The training forward: render (no mesh layer) into the out_* arrays, bit-identical to "
     "render(); out_final_t (float32) and out_n_contrib (int32), (H, W) or None, get the "
     "per-pixel final transmittance and n_contrib; out_visible (uint8, (N,) or None) 1 for each "
     "Gaussian drawn (its footprint reaches a pixel). `state` is an opaque handle holding what "
     "backward() needs. exhaustive: this forward and its backward run their slow twins (each "
     "Gaussian over its tiles' whole spans; the projection backward one Gaussian at a time)."},
    {"train_state_info", py_train_state_info, METH_O,
     "train_state_info(state) -> dict: the image size, Gaussian count, options and counts of a "
     "training state."},
    {"backward", py_backward, METH_VARARGS,
     "backward(state, means, log_scales, quats, opacity_logits, sh, d_rgb, d_alpha, d_depth, "
     "threads, out_means, out_log_scales, out_quats, out_opacity_logits, out_sh, out_xy, "
     "out_xy_abs) -> stats\n\nGradients of a loss with dL/d(rgb) (H, W, 3), dL/d(alpha) and "
     "dL/d(depth) (H, W) or None, w.r.t. the Gaussians render_train drew (the same arrays, "
     "unchanged), into the out_* arrays (overwritten)."},
    {"l1_ssim", py_l1_ssim, METH_VARARGS,
     "l1_ssim(image, target, lambda_dssim, threads, out_grad) -> (loss, l1, ssim, mse)\n\n"
     "(1 - lambda) L1 + lambda (1 - SSIM) of (H, W, 3) float32 images; dL/d(image) into "
     "out_grad when it is not None; mse: of the image clamped to [0, 1] (PSNR's)."},
    {"adam", py_adam, METH_VARARGS,
     "adam(param, grad, exp_avg, exp_avg_sq, lr, beta1, beta2, eps, step, threads, rows=None, "
     "lead=0, lead_lr=lr, used=-1)\n\n"
     "One Adam step in place (torch.optim.Adam's formula); float32 arrays of one shape. rows: "
     "uint8 (shape[0],) or None: rows where it is 0 are left as they are (moments too). The "
     "first `lead` values of each row (along the first axis) step at lead_lr; only the first "
     "`used` values of each row are updated (negative: all)."},
    {"position_noise", py_position_noise, METH_VARARGS,
     "position_noise(means, log_scales, quats, opacity_logits, noise, scale, threads)\n\n"
     "3DGS-MCMC's noise on the means in place (sc_position_noise): float32 parameters of N "
     "Gaussians (means writable), noise (N, 3) float64 standard normal."},
    {"srgb_premultiplied", py_srgb_premultiplied, METH_VARARGS,
     "srgb_premultiplied(rgba, out, decode, threads)\n\n"
     "Premultiplied float32 RGBA (..., 4) scene-linear -> display sRGB (decode False) or back "
     "(True), into out (rgba itself, or a C-contiguous float32 array of its shape)."},
    {"srgb_view", py_srgb_view, METH_VARARGS,
     "srgb_view(rgba, out, decode, zero_non_finite, threads)\n\n"
     "srgb_premultiplied for (H, W, 4) float32 arrays with any strides; with zero_non_finite, "
     "non-finite results become 0."},
    {"srgb_decode_changed", py_srgb_decode_changed, METH_VARARGS,
     "srgb_decode_changed(rgb, alpha, mesh, layer, threads, out=layer)\n\n"
     "compose's way back: out (H, W, 4; by default layer, the display layer) gets the "
     "scene-linear result: the composite (rgb, alpha) decoded where it differs from layer, "
     "mesh's pixel (any strides) elsewhere."},
    {"composite_microbench", py_composite_microbench, METH_VARARGS,
     "composite_microbench(count, iterations) -> seconds for the compositor's inner loop over "
     "one in-cache tile covered by `count` Gaussians."},
    {"cpu_count", py_cpu_count, METH_NOARGS, "Cores this process may use."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "splatcore",
    "Native 3D Gaussian splatting renderer (see native/include/splatcore.h).", -1, methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit_splatcore(void) { return PyModule_Create(&module); }
