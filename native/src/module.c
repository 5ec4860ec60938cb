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

/* ---------------------------------------------------------------- arguments as data
 * Each entry point declares its arguments once, in one table (a signature: per argument its
 * name, kind, and for an array its dtype, shape and flags; see bindings.h). That table is the
 * only statement of the arguments' order: begin() parses a call by it (positional or by
 * keyword, numbers converted), check() validates the arrays in it the same way for every entry
 * point (the buffer protocol, writability, dtype, C-contiguity unless STRIDED, shape,
 * finiteness where asked; a named size is bound by the first argument that has it), finish()
 * and fail() release what a call holds; `splatcore.signature(name)` hands the table to Python,
 * whose door (addon/core/native.py) passes every argument by name. */

/* A dimension of a shape: a size (>= 0), ANY, or a named size (N Gaussians, at most
 * MAX_GAUSSIANS; K SH coefficients per colour channel, 1, 4, 9 or 16; H and W an image's rows
 * and columns; ROWS any other length). */
enum { ANY = -1, DIM_N = -2, DIM_K = -3, DIM_H = -4, DIM_W = -5, DIM_ROWS = -6 };
enum { NAMED_DIMS = 5, MAX_RANK = 8 };
static const char DIM_LETTER[NAMED_DIMS] = {'N', 'K', 'H', 'W', 'N'};

enum {
    WRITABLE = 1, /* an output: the array must be writable */
    OPTIONAL = 2, /* None is allowed (its view is NULL) */
    FINITE = 4,   /* values (float32 or float64) that must all be finite */
    STRIDED = 8,  /* any strides (otherwise C-contiguous) */
    ANY_RANK = 16, /* any shape (ndim and shape unused): later LIKE arguments must have it */
    LIKE = 32,    /* the shape of the ANY_RANK argument before it (ndim and shape unused) */
    DEFAULTED = 64, /* may be left out: an array or object is then None, a number `fallback` */
};

/* What an argument is: an array (the table's dtype and shape) or a scalar. */
typedef enum {
    ARRAY,   /* buffer protocol, checked by check() */
    INT,     /* a Python int that fits a C int */
    LONG,    /* a Python int that fits a long long */
    REAL,    /* a float (or int) */
    FLAG,    /* anything, by its truth */
    THREADS, /* an int in 0..MAX_THREADS (parse_threads) */
    OBJECT,  /* any object (a capsule), checked by its entry point */
} arg_kind;

typedef struct {
    const char *name; /* its keyword, and how messages name it */
    char type;        /* arrays: 'f' float32, 'd' float64, 'B' uint8, 'i' int32 */
    int ndim;
    Py_ssize_t shape[3]; /* sizes, ANY or DIM_* */
    int flags;
    arg_kind kind;   /* ARRAY unless a scalar */
    double fallback; /* a DEFAULTED number's value when left out */
} arg_spec;

/* A scalar argument of the tables: its name and kind (and, DEFAULTED, its value left out). */
#define SCALAR(name, kind) {name, 0, 0, {0}, 0, kind, 0}
#define SCALAR_OR(name, kind, fallback) {name, 0, 0, {0}, DEFAULTED, kind, fallback}

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

static int check_finite(const Py_buffer *view, const char *name, int threads);

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
                      PyObject *const *objs, const Py_buffer **views, int threads) {
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
        if ((s->flags & FINITE) && check_finite(view, s->name, threads) != 0) return -1;
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

/* The size a call bound to a named dimension. */
#define SIZE(d, dim) ((d)->size[-2 - (dim)])

#include "bindings.h"

enum { MAX_PARAMS = 32 };

/* An entry point: its name and its table (bindings.h). */
typedef struct {
    const char *name;
    const arg_spec *params;
    int count;
} signature;

/* One call of an entry point: its arguments by the table's index (objects as given, NULL when
 * left out; numbers converted), the views check() took, and the buffers to release. */
typedef struct {
    const signature *sig;
    PyObject *objs[MAX_PARAMS];
    long long ints[MAX_PARAMS];
    double reals[MAX_PARAMS];
    const Py_buffer *views[MAX_PARAMS];
    buffers b;
    arg_dims d;
} call;

/* The table index of `name`; a name no table has is a bug in this file: fatal. */
static int index_of(const signature *sig, const char *name) {
    for (int i = 0; i < sig->count; ++i)
        if (strcmp(sig->params[i].name, name) == 0) return i;
    Py_FatalError("splatcore: an entry point uses an argument its table lacks");
    return -1;
}

/* One scalar argument, converted as its kind says. */
static int convert(call *c, int i, PyObject *obj) {
    const arg_spec *s = &c->sig->params[i];
    switch (s->kind) {
    case INT:
    case LONG: {
        const long long value = PyLong_AsLongLong(obj);
        if (value == -1 && PyErr_Occurred()) return -1;
        if (s->kind == INT && (value < -2147483647LL - 1 || value > 2147483647LL)) {
            PyErr_Format(PyExc_OverflowError, "%s does not fit a C int, got %lld", s->name, value);
            return -1;
        }
        c->ints[i] = value;
        return 0;
    }
    case REAL:
        c->reals[i] = PyFloat_AsDouble(obj);
        return c->reals[i] == -1.0 && PyErr_Occurred() ? -1 : 0;
    case FLAG: {
        const int truth = PyObject_IsTrue(obj);
        c->ints[i] = truth;
        return truth < 0 ? -1 : 0;
    }
    case THREADS: {
        int threads = 0;
        if (!parse_threads(obj, &threads)) return -1;
        c->ints[i] = threads;
        return 0;
    }
    default:
        return 0;
    }
}

/* Parse a call by its table: positional arguments in the table's order, the rest by keyword;
 * every argument not DEFAULTED is required. Numbers are converted here; arrays wait for
 * check(). On failure the exception is set and nothing is held. */
static int begin(call *c, const signature *sig, PyObject *args, PyObject *kwargs) {
    c->sig = sig;
    c->b.count = 0;
    c->d = (arg_dims)ARG_DIMS_INIT;
    const Py_ssize_t given = PyTuple_Size(args);
    if (given < 0) return -1;
    if (given > sig->count) {
        PyErr_Format(PyExc_TypeError, "%s() takes at most %d arguments (%zd given)", sig->name,
                     sig->count, given);
        return -1;
    }
    Py_ssize_t by_keyword = kwargs ? PyDict_Size(kwargs) : 0;
    for (int i = 0; i < sig->count; ++i) {
        const arg_spec *s = &sig->params[i];
        PyObject *obj = i < given ? PyTuple_GetItem(args, i) : NULL;
        PyObject *named = kwargs ? PyDict_GetItemString(kwargs, s->name) : NULL;
        if (obj && named) {
            PyErr_Format(PyExc_TypeError, "%s() got multiple values for argument '%s'", sig->name,
                         s->name);
            return -1;
        }
        if (named) obj = named, --by_keyword;
        c->objs[i] = obj;
        c->views[i] = NULL;
        c->ints[i] = (long long)s->fallback;
        c->reals[i] = s->fallback;
        if (!obj && !(s->flags & DEFAULTED)) {
            PyErr_Format(PyExc_TypeError, "%s() missing required argument '%s' (pos %d)",
                         sig->name, s->name, i + 1);
            return -1;
        }
        if (obj && convert(c, i, obj) != 0) return -1;
    }
    if (by_keyword > 0) {
        PyErr_Format(PyExc_TypeError, "%s() got an unexpected keyword argument (its arguments: "
                     "splatcore.signature('%s'))", sig->name, sig->name);
        return -1;
    }
    return 0;
}

/* Check the arrays from `first` to `last` (names, inclusive) in the table's order; each view
 * is held until finish() or fail(). A left-out or None OPTIONAL array has no view. */
static int check(call *c, const char *first, const char *last) {
    const int from = index_of(c->sig, first), to = index_of(c->sig, last);
    int threads = 1; /* the call's own, for the FINITE scans (threads 0: every core) */
    for (int i = 0; i < c->sig->count; ++i)
        if (c->sig->params[i].kind == THREADS)
            threads = c->ints[i] ? (int)c->ints[i] : sc_cpu_count();
    for (int i = from; i <= to; ++i) {
        const arg_spec *s = &c->sig->params[i];
        if (s->kind != ARRAY) continue;
        PyObject *obj = c->objs[i] ? c->objs[i] : Py_None;
        if (check_args(&c->b, &c->d, s, 1, &obj, &c->views[i], threads) != 0) return -1;
    }
    return 0;
}

/* A call's end: what it holds released, `result` (NULL: the exception set) returned. */
static PyObject *finish(call *c, PyObject *result) {
    release_all(&c->b);
    return result;
}

static PyObject *fail(call *c) { return finish(c, NULL); }

/* A call's arguments by name: an array's view or data (NULL for None), a number, an object
 * (NULL when left out). */
static const Py_buffer *view_of(const call *c, const char *name) { return c->views[index_of(c->sig, name)]; }
static void *data_of(const call *c, const char *name) { return data(view_of(c, name)); }
static long long int_of(const call *c, const char *name) { return c->ints[index_of(c->sig, name)]; }
static double real_of(const call *c, const char *name) { return c->reals[index_of(c->sig, name)]; }
static PyObject *object_of(const call *c, const char *name) { return c->objs[index_of(c->sig, name)]; }

/* The Gaussians' five arrays of a call (checked; shapes consistent, K in 1, 4, 9, 16). */
static int parse_gaussians(call *c, sc_gaussians *g) {
    if (check(c, "means", "sh") != 0) return -1;
    g->means = data_of(c, "means"), g->log_scales = data_of(c, "log_scales");
    g->quats = data_of(c, "quats"), g->opacity_logits = data_of(c, "opacity_logits");
    g->sh = data_of(c, "sh");
    g->count = SIZE(&c->d, DIM_N);
    g->sh_coeffs = (int)SIZE(&c->d, DIM_K);
    return 0;
}

/* The arguments project(), render(), render_train() and compose_prepare() share (FRAME_PARAMS):
 * Gaussians, camera, options; the call's H and W are bound to the image size. */
static int parse_common(call *c, sc_gaussians *g, sc_camera *cam, sc_options *opt) {
    if (parse_gaussians(c, g) != 0) return -1;
    const int sh_degree = (int)int_of(c, "sh_degree"), width = (int)int_of(c, "width"),
              height = (int)int_of(c, "height"), threads = (int)int_of(c, "threads");
    const double near = real_of(c, "near");
    const int data_degree = g->sh_coeffs == 1 ? 0 : g->sh_coeffs == 4 ? 1 : g->sh_coeffs == 9 ? 2 : 3;
    if (sh_degree < 0 || sh_degree > data_degree) {
        PyErr_Format(PyExc_ValueError, "sh_degree must be in 0..%d for this data, got %d",
                     data_degree, sh_degree);
        return -1;
    }
    if (check(c, "world_to_camera", "intrinsics") != 0) return -1;
    const double *viewmat = data_of(c, "world_to_camera"), *intr = data_of(c, "intrinsics");
    /* intrinsics: fx fy cx cy (a pinhole), or those, the model, far, aperture, focus and
     * SC_MODEL_PARAMS (sc_camera). */
    const Py_ssize_t n_intr = view_of(c, "intrinsics")->shape[0], n_long = 8 + SC_MODEL_PARAMS;
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
        for (int k = 0; k < 3; ++k) {
            double dot = 0;
            for (int j = 0; j < 3; ++j) dot += viewmat[4 * r + j] * viewmat[4 * k + j];
            worst = fmax(worst, fabs(dot - (r == k)));
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
    memcpy(cam->world_to_camera, viewmat, sizeof cam->world_to_camera);
    cam->fx = intr[0], cam->fy = intr[1], cam->cx = intr[2], cam->cy = intr[3];
    cam->width = width, cam->height = height;
    cam->model = (int)model, cam->far = far, cam->aperture = aperture, cam->focus = focus;
    for (int k = 0; k < SC_MODEL_PARAMS; ++k) cam->params[k] = pinhole_only ? 0.0 : intr[8 + k];
    SIZE(&c->d, DIM_H) = height, SIZE(&c->d, DIM_W) = width;
    opt->sh_degree = sh_degree;
    opt->near = near;
    opt->antialiased = (int)int_of(c, "antialiased");
    opt->threads = threads ? threads : sc_cpu_count();
    opt->exhaustive = 0;
    return 0;
}

/* A call's `threads` as the kernels take it (0: every core). */
static int threads_of(const call *c) {
    const int threads = (int)int_of(c, "threads");
    return threads ? threads : sc_cpu_count();
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
        set_number(d, "ms_pool_project", PyFloat_FromDouble(s->ms_pool_project)) ||
        set_number(d, "ms_pool_sort", PyFloat_FromDouble(s->ms_pool_sort)) ||
        set_number(d, "ms_pool_bin", PyFloat_FromDouble(s->ms_pool_bin)) ||
        set_number(d, "ms_pool_composite", PyFloat_FromDouble(s->ms_pool_composite)) ||
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

static int non_finite_at(const char *name, int64_t i) {
    PyErr_Format(PyExc_ValueError, "%s has a non-finite value (NaN or Inf) at flat index %lld",
                 name, (long long)i);
    return -1;
}

/* A FINITE argument's values, float32 or float64 as its spec says (itemsize). float32 ones are
 * whole images and gradients, checked at every training step: on the call's threads, without
 * the GIL when there are many (sc_first_non_finite). */
static int check_finite(const Py_buffer *view, const char *name, int threads) {
    const int64_t n = (int64_t)(view->len / view->itemsize);
    if (view->itemsize == (Py_ssize_t)sizeof(float)) {
        int64_t bad;
        if (n < ((int64_t)1 << 16)) {
            bad = sc_first_non_finite(view->buf, n, 1);
        } else {
            Py_BEGIN_ALLOW_THREADS
            bad = sc_first_non_finite(view->buf, n, threads);
            Py_END_ALLOW_THREADS
        }
        return bad < 0 ? 0 : non_finite_at(name, bad);
    }
    const double *v = view->buf;
    uint64_t bad = 0; /* branch-free first, as check_finite_array */
    for (int64_t i = 0; i < n; ++i) {
        uint64_t bits;
        memcpy(&bits, v + i, sizeof bits);
        bad |= (bits & 0x7ff0000000000000u) == 0x7ff0000000000000u;
    }
    if (!bad) return 0;
    for (int64_t i = 0; i < n; ++i)
        if (!isfinite(v[i])) return non_finite_at(name, i);
    return 0;
}


static PyObject *py_project(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_render(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_compose_prepare(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_compose_srgb(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_sort_keys(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_render_train(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_backward(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_l1_ssim(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_adam(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_position_noise(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_neighbours(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_deformation_jacobians(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_deform_shapes(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_deform_rest(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_deform_frame(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_srgb_premultiplied(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_srgb_view(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_srgb_decode_changed(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_composite_microbench(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_pool_profile(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_viewport_image(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_photo_rgb(PyObject *self, PyObject *args, PyObject *kwargs);
static PyObject *py_image_memory(PyObject *self, PyObject *args, PyObject *kwargs);

/* Every entry point with its table (METH_NOARGS ones have none), for begin() and for
 * `splatcore.signature`. */
#define ENTRY(name, table) {name, table, COUNT(table)}
static const signature SIGNATURES[] = {
    ENTRY("project", PROJECT),
    ENTRY("render", RENDER),
    ENTRY("compose_prepare", COMPOSE_PREPARE),
    ENTRY("compose_srgb", COMPOSE_SRGB),
    ENTRY("checksum", CHECKSUM),
    ENTRY("sort_keys", SORT_KEYS),
    ENTRY("render_train", RENDER_TRAIN),
    ENTRY("train_state_info", TRAIN_STATE_INFO),
    ENTRY("backward", BACKWARD),
    ENTRY("l1_ssim", L1_SSIM),
    ENTRY("adam", ADAM),
    ENTRY("position_noise", POSITION_NOISE),
    ENTRY("neighbours", NEIGHBOURS),
    ENTRY("deformation_jacobians", DEFORMATION_JACOBIANS),
    ENTRY("deform_shapes", DEFORM_SHAPES),
    ENTRY("deform_rest", DEFORM_REST),
    ENTRY("deform_frame", DEFORM_FRAME),
    ENTRY("srgb_premultiplied", SRGB_PREMULTIPLIED),
    ENTRY("srgb_view", SRGB_VIEW),
    ENTRY("srgb_decode_changed", SRGB_DECODE_CHANGED),
    ENTRY("composite_microbench", COMPOSITE_MICROBENCH),
    ENTRY("pool_profile", POOL_PROFILE),
    ENTRY("viewport_image", VIEWPORT_IMAGE),
    ENTRY("photo_rgb", PHOTO_RGB),
    ENTRY("image_memory", IMAGE_MEMORY),
};

static const signature *signature_of(const char *name) {
    for (int i = 0; i < COUNT(SIGNATURES); ++i)
        if (strcmp(SIGNATURES[i].name, name) == 0) return &SIGNATURES[i];
    Py_FatalError("splatcore: an entry point without a table");
    return NULL;
}

/* An entry point's opening: its call parsed by its table, or NULL returned. */
#define BEGIN(c, name)                                                              \
    (void)self;                                                                     \
    call c;                                                                         \
    if (begin(&c, signature_of(name), args, kwargs) != 0) return NULL

/* ---------------------------------------------------------------- rendering */

static PyObject *py_project(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "project");
    sc_gaussians g;
    sc_camera cam;
    sc_options opt;
    if (parse_common(&c, &g, &cam, &opt) != 0 || check(&c, "out_xy", "out_valid") != 0)
        return fail(&c);
    const Py_ssize_t n = (Py_ssize_t)g.count;
    float *xy = data_of(&c, "out_xy"), *conic = data_of(&c, "out_conic"),
          *depth = data_of(&c, "out_depth"), *opacity = data_of(&c, "out_opacity"),
          *rgb = data_of(&c, "out_rgb");
    uint8_t *valid = data_of(&c, "out_valid");
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
    return finish(&c, status == SC_OK ? Py_NewRef(Py_None) : raise_status(status, &g, &stats));
}

/* The background and the three images of render() and render_train() (BACKGROUND_PARAM,
 * IMAGE_PARAMS). */
static int parse_image(call *c, sc_image *image) {
    if (check(c, "background", "background") != 0 || check(c, "out_rgb", "out_depth") != 0)
        return -1;
    image->background = data_of(c, "background");
    image->rgb = data_of(c, "out_rgb"), image->alpha = data_of(c, "out_alpha");
    image->depth = data_of(c, "out_depth");
    return 0;
}

static PyObject *py_render(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "render");
    sc_gaussians g;
    sc_camera cam;
    sc_options opt;
    sc_image image = {0};
    if (parse_common(&c, &g, &cam, &opt) != 0 || parse_image(&c, &image) != 0) return fail(&c);
    opt.exhaustive = (int)int_of(&c, "exhaustive");
    const PyObject *mesh_rgba = object_of(&c, "mesh_rgba"), *mesh_depth = object_of(&c, "mesh_depth");
    if ((mesh_rgba == Py_None) != (mesh_depth == Py_None)) {
        PyErr_SetString(PyExc_ValueError, "mesh_rgba and mesh_depth must be given together");
        return fail(&c);
    }
    if (check(&c, "mesh_rgba", "mesh_depth") != 0) return fail(&c);
    image.mesh_rgba = data_of(&c, "mesh_rgba"), image.mesh_depth = data_of(&c, "mesh_depth");
    if (image.mesh_rgba &&
        check_mesh(image.mesh_rgba, image.mesh_depth, (int64_t)cam.width * cam.height) != 0)
        return fail(&c);
    sc_stats stats = {0};
    sc_status status;
    Py_BEGIN_ALLOW_THREADS
    status = sc_render(&g, &cam, &opt, &image, &stats);
    Py_END_ALLOW_THREADS
    return finish(&c, status == SC_OK ? stats_dict(&stats) : raise_status(status, &g, &stats));
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

static PyObject *py_render_train(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "render_train");
    sc_gaussians g;
    sc_camera cam;
    sc_options opt;
    sc_image image = {0};
    if (parse_common(&c, &g, &cam, &opt) != 0) return fail(&c);
    opt.exhaustive = (int)int_of(&c, "exhaustive");
    if (cam.model != SC_PINHOLE || cam.aperture > 0) {
        PyErr_SetString(PyExc_ValueError, "training renders through pinhole cameras only (no "
                                          "depth of field)");
        return fail(&c);
    }
    if (parse_image(&c, &image) != 0 || check(&c, "out_final_t", "out_visible") != 0)
        return fail(&c);
    float *out_t = data_of(&c, "out_final_t");
    int32_t *out_n = data_of(&c, "out_n_contrib");
    uint8_t *out_visible = data_of(&c, "out_visible");

    sc_train_state *state = calloc(1, sizeof *state);
    if (!state) return PyErr_NoMemory(), fail(&c);
    sc_stats stats = {0};
    sc_status status;
    const size_t pixels = (size_t)cam.width * (size_t)cam.height;
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
        return fail(&c);
    }
    finish(&c, NULL);
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

static PyObject *py_backward(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "backward");
    const sc_train_state *state = get_state(object_of(&c, "state"));
    if (!state) return NULL;
    sc_gaussians g;
    if (parse_gaussians(&c, &g) != 0) return fail(&c);
    if (g.count != state->count || g.sh_coeffs != state->sh_coeffs) {
        PyErr_Format(PyExc_ValueError,
                     "the Gaussians (N=%lld, K=%d) are not those render_train drew (N=%lld, K=%d)",
                     (long long)g.count, g.sh_coeffs, (long long)state->count, state->sh_coeffs);
        return fail(&c);
    }
    SIZE(&c.d, DIM_H) = state->camera.height, SIZE(&c.d, DIM_W) = state->camera.width;
    if (check(&c, "d_rgb", "out_xy_abs") != 0) return fail(&c);
    const float *d_rgb = data_of(&c, "d_rgb"), *d_alpha = data_of(&c, "d_alpha"),
                *d_depth = data_of(&c, "d_depth");
    sc_gaussian_grads out = {data_of(&c, "out_means"), data_of(&c, "out_log_scales"),
                             data_of(&c, "out_quats"), data_of(&c, "out_opacity_logits"),
                             data_of(&c, "out_sh"), data_of(&c, "out_xy"),
                             data_of(&c, "out_xy_abs")};
    const int threads = threads_of(&c);
    sc_backward_stats stats = {0};
    sc_status status;
    Py_BEGIN_ALLOW_THREADS
    status = sc_backward(state, &g, d_rgb, d_alpha, d_depth, threads, &out, &stats);
    Py_END_ALLOW_THREADS
    if (status != SC_OK) {
        sc_stats s = {.error_index = stats.error_index};
        raise_status(status, &g, &s);
        return fail(&c);
    }
    return finish(&c, Py_BuildValue("{s:d,s:d,s:d,s:d,s:d,s:L,s:L}", "ms_composite",
                                    stats.ms_composite, "ms_project", stats.ms_project,
                                    "ms_total", stats.ms_total, "ms_pool_composite",
                                    stats.ms_pool_composite, "ms_pool_project",
                                    stats.ms_pool_project, "evaluations",
                                    (long long)stats.evaluations, "flushed",
                                    (long long)stats.flushed));
}

static PyObject *py_l1_ssim(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "l1_ssim");
    const double lambda = real_of(&c, "lambda_dssim");
    if (!(lambda >= 0.0 && lambda <= 1.0))
        return value_error("lambda_dssim must be in [0, 1], got %g", lambda), NULL;
    if (check(&c, "image", "image") != 0) return fail(&c);
    const Py_ssize_t height = SIZE(&c.d, DIM_H), width = SIZE(&c.d, DIM_W);
    if (height < 1 || width < 1 || height > MAX_SIDE || width > MAX_SIDE ||
        (long long)width * height > MAX_PIXELS) {
        PyErr_Format(PyExc_ValueError,
                     "image size %zdx%zd is invalid: sides must be 1..%d and at most %lld pixels",
                     width, height, (int)MAX_SIDE, MAX_PIXELS);
        return fail(&c);
    }
    if (check(&c, "target", "out_grad") != 0) return fail(&c);
    const float *image = data_of(&c, "image"), *target = data_of(&c, "target");
    float *grad = data_of(&c, "out_grad");
    const int threads = threads_of(&c);
    double loss = 0, l1 = 0, ssim = 0, mse = 0;
    sc_status status;
    Py_BEGIN_ALLOW_THREADS
    status = sc_l1_ssim(image, target, (int)width, (int)height, lambda, threads, grad, &loss, &l1,
                        &ssim, &mse);
    Py_END_ALLOW_THREADS
    if (status != SC_OK) return PyErr_NoMemory(), fail(&c);
    return finish(&c, Py_BuildValue("(dddd)", loss, l1, ssim, mse));
}

static PyObject *py_adam(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "adam");
    sc_adam_options o = {.lr = real_of(&c, "lr"), .beta1 = real_of(&c, "beta1"),
                         .beta2 = real_of(&c, "beta2"), .eps = real_of(&c, "eps"),
                         .step = int_of(&c, "step")};
    const double lead_lr = isnan(real_of(&c, "lead_lr")) ? o.lr : real_of(&c, "lead_lr");
    long long used = int_of(&c, "used");
    const long long lead = int_of(&c, "lead");
    if (!isfinite(o.lr) || o.lr < 0) return value_error("lr must be finite and >= 0, got %g", o.lr), NULL;
    if (!isfinite(lead_lr) || lead_lr < 0)
        return value_error("lead_lr must be finite and >= 0, got %g", lead_lr), NULL;
    if (!(o.beta1 >= 0 && o.beta1 < 1) || !(o.beta2 >= 0 && o.beta2 < 1))
        return value_error("beta1 and beta2 must be in [0, 1), got %g, %g", o.beta1, o.beta2), NULL;
    if (!(o.eps > 0) || !isfinite(o.eps))
        return value_error("eps must be finite and > 0, got %g", o.eps), NULL;
    if (o.step < 1)
        return PyErr_Format(PyExc_ValueError, "step must be >= 1 (the first update is 1), got %lld",
                            (long long)o.step);
    if (check(&c, "param", "exp_avg_sq") != 0) return fail(&c);
    const Py_buffer *like = view_of(&c, "param");
    const int64_t n = (int64_t)(like->len / 4);
    /* Rows along the first axis (a 0-d array is one row). */
    const int64_t rows = like->ndim > 0 ? (int64_t)like->shape[0] : 1;
    const int64_t width = rows > 0 ? n / rows : 0;
    SIZE(&c.d, DIM_ROWS) = (Py_ssize_t)rows;
    if (check(&c, "rows", "rows") != 0) return fail(&c);
    float *param = data_of(&c, "param"), *m = data_of(&c, "exp_avg"), *v = data_of(&c, "exp_avg_sq");
    const float *grad = data_of(&c, "grad");
    const uint8_t *mask = data_of(&c, "rows");
    if (used < 0) used = width;
    if (used > width) {
        PyErr_Format(PyExc_ValueError, "used must be in 0..%lld (the values in a row), got %lld",
                     (long long)width, used);
        return fail(&c);
    }
    if (lead < 0 || lead > used) {
        PyErr_Format(PyExc_ValueError, "lead must be in 0..%lld (the values in a row updated), "
                     "got %lld", (long long)used, lead);
        return fail(&c);
    }
    const int threads = threads_of(&c);
    Py_BEGIN_ALLOW_THREADS
    sc_adam_rows(param, grad, m, v, rows, width, mask, lead, lead_lr, used, &o, threads);
    Py_END_ALLOW_THREADS
    return finish(&c, Py_NewRef(Py_None));
}

static PyObject *py_position_noise(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "position_noise");
    const double scale = real_of(&c, "scale");
    if (!isfinite(scale)) return value_error("scale must be finite, got %g", scale), NULL;
    if (check(&c, "means", "noise") != 0) return fail(&c);
    const Py_ssize_t n = SIZE(&c.d, DIM_N);
    float *means = data_of(&c, "means");
    const float *log_scales = data_of(&c, "log_scales"), *quats = data_of(&c, "quats"),
                *logits = data_of(&c, "opacity_logits");
    const double *noise = data_of(&c, "noise");
    const int threads = threads_of(&c);
    Py_BEGIN_ALLOW_THREADS
    sc_position_noise(means, log_scales, quats, logits, noise, n, scale, threads);
    Py_END_ALLOW_THREADS
    return finish(&c, Py_NewRef(Py_None));
}

/* ---------------------------------------------------------------- deformation */

static PyObject *py_neighbours(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "neighbours");
    if (check(&c, "points", "out") != 0) return fail(&c);
    const Py_ssize_t n = SIZE(&c.d, DIM_N), k = view_of(&c, "out")->shape[1];
    if (k < 1 || k > SC_MAX_NEIGHBOURS) {
        PyErr_Format(PyExc_ValueError, "out must have shape (N, k) with k in 1..%d, got k=%zd",
                     (int)SC_MAX_NEIGHBOURS, k);
        return fail(&c);
    }
    const float *points = data_of(&c, "points");
    int32_t *out = data_of(&c, "out");
    const int threads = threads_of(&c);
    int status;
    Py_BEGIN_ALLOW_THREADS
    status = sc_neighbours(points, n, (int)k, out, threads);
    Py_END_ALLOW_THREADS
    if (status != 0) return fail(&c), PyErr_NoMemory();
    return finish(&c, Py_NewRef(Py_None));
}

/* The neighbour lists (n, k): k in 1..SC_MAX_NEIGHBOURS, each entry a row or -1. */
static int check_neighbours(const call *c, Py_ssize_t n, Py_ssize_t k) {
    if (k < 1 || k > SC_MAX_NEIGHBOURS) {
        PyErr_Format(PyExc_ValueError, "neighbours must have shape (N, k) with k in 1..%d, got "
                     "k=%zd", (int)SC_MAX_NEIGHBOURS, k);
        return -1;
    }
    const int32_t *neighbours = data_of(c, "neighbours");
    for (Py_ssize_t i = 0; i < n * k; ++i)
        if (neighbours[i] < -1 || neighbours[i] >= n) {
            PyErr_Format(PyExc_ValueError, "neighbours[%zd, %zd] is %d, not a point's index (0..%zd) "
                         "or -1", i / k, i % k, (int)neighbours[i], n - 1);
            return -1;
        }
    return 0;
}

static PyObject *py_deformation_jacobians(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "deformation_jacobians");
    const double lo = real_of(&c, "undetermined"), hi = real_of(&c, "determined");
    if (!(lo >= 0.0 && lo <= hi && hi <= 1.0))
        return value_error("need 0 <= undetermined <= determined <= 1, got %g and %g", lo, hi), NULL;
    if (check(&c, "rest", "neighbours") != 0 || check(&c, "out_jacobians", "out_rotations") != 0)
        return fail(&c);
    const Py_ssize_t n = SIZE(&c.d, DIM_N), k = view_of(&c, "neighbours")->shape[1];
    if (check_neighbours(&c, n, k) != 0) return fail(&c);
    const int32_t *neighbours = data_of(&c, "neighbours");
    const float *rest = data_of(&c, "rest"), *deformed = data_of(&c, "deformed");
    double *jacobians = data_of(&c, "out_jacobians"), *rotations = data_of(&c, "out_rotations");
    const int threads = threads_of(&c);
    Py_BEGIN_ALLOW_THREADS
    sc_deformation_jacobians(rest, deformed, n, neighbours, (int)k, lo, hi, jacobians, rotations,
                             threads);
    Py_END_ALLOW_THREADS
    return finish(&c, Py_NewRef(Py_None));
}

static PyObject *py_deform_shapes(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "deform_shapes");
    if (check(&c, "log_scales", "rotations") != 0 || check(&c, "out_log_scales", "out_sh") != 0)
        return fail(&c);
    const Py_ssize_t n = SIZE(&c.d, DIM_N);
    const double *jacobians = data_of(&c, "jacobians"), *rotations = data_of(&c, "rotations");
    for (Py_ssize_t i = 0; i < n; ++i) {
        const double *q = rotations + 9 * i;
        if (!all_finite_d(jacobians + 9 * i, 9) || !all_finite_d(q, 9)) {
            value_error("Gaussian %zd: its Jacobian or rotation is not finite", i);
            return fail(&c);
        }
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) {
                const double dot = q[3 * a] * q[3 * b] + q[3 * a + 1] * q[3 * b + 1] + q[3 * a + 2] * q[3 * b + 2];
                if (fabs(dot - (a == b)) > 1e-6) {
                    value_error("rotations[%zd] is not orthogonal (row %d . row %d = %g)", i, a, b, dot);
                    return fail(&c);
                }
            }
    }
    const float *log_scales = data_of(&c, "log_scales"), *quats = data_of(&c, "quats"),
                *sh = data_of(&c, "sh");
    float *out_log_scales = data_of(&c, "out_log_scales"), *out_quats = data_of(&c, "out_quats"),
          *out_sh = data_of(&c, "out_sh");
    const int coeffs = (int)SIZE(&c.d, DIM_K), threads = threads_of(&c);
    Py_BEGIN_ALLOW_THREADS
    sc_deform_shapes(log_scales, quats, sh, n, coeffs, jacobians, rotations, out_log_scales,
                     out_quats, out_sh, threads);
    Py_END_ALLOW_THREADS
    return finish(&c, Py_NewRef(Py_None));
}

/* A fit (N, SC_FIT_FIELDS + k) for neighbours (N, k). */
static int check_fit_width(const call *c, const char *name, Py_ssize_t k) {
    const Py_ssize_t width = view_of(c, name)->shape[1];
    if (width != SC_FIT_FIELDS + k) {
        PyErr_Format(PyExc_ValueError, "%s must have shape (N, %d + k) = (N, %zd) for k=%zd "
                     "neighbours, got (N, %zd)", name, (int)SC_FIT_FIELDS, SC_FIT_FIELDS + k, k,
                     width);
        return -1;
    }
    return 0;
}

static PyObject *py_deform_rest(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "deform_rest");
    const double lo = real_of(&c, "undetermined"), hi = real_of(&c, "determined");
    if (!(lo >= 0.0 && lo <= hi && hi <= 1.0)) {
        value_error("need 0 <= undetermined <= determined <= 1, got %g and %g", lo, hi);
        return fail(&c);
    }
    if (check(&c, "rest", "neighbours") != 0 || check(&c, "out_fit", "out_fit") != 0)
        return fail(&c);
    const Py_ssize_t n = SIZE(&c.d, DIM_N), k = view_of(&c, "neighbours")->shape[1];
    if (check_neighbours(&c, n, k) != 0 || check_fit_width(&c, "out_fit", k) != 0)
        return fail(&c);
    const float *rest = data_of(&c, "rest");
    const int32_t *neighbours = data_of(&c, "neighbours");
    double *fit = data_of(&c, "out_fit");
    const int threads = threads_of(&c);
    Py_BEGIN_ALLOW_THREADS
    sc_deform_rest(rest, n, neighbours, (int)k, lo, hi, fit, threads);
    Py_END_ALLOW_THREADS
    return finish(&c, Py_NewRef(Py_None));
}

static PyObject *py_deform_frame(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "deform_frame");
    if (check(&c, "rest", "sh") != 0 || check(&c, "out_log_scales", "out_sh") != 0)
        return fail(&c);
    const Py_ssize_t n = SIZE(&c.d, DIM_N), k = view_of(&c, "neighbours")->shape[1];
    if (check_neighbours(&c, n, k) != 0 || check_fit_width(&c, "fit", k) != 0) return fail(&c);
    const int32_t *order = data_of(&c, "order");
    uint8_t *seen = calloc((size_t)(n > 0 ? n : 1), 1);
    if (seen == NULL) return fail(&c), PyErr_NoMemory();
    for (Py_ssize_t row = 0; row < n; ++row) {
        const int32_t i = order[row];
        if (i < 0 || i >= n || seen[i]) {
            free(seen);
            value_error("order must be a permutation of 0..%zd: order[%zd] is %d%s", n - 1, row,
                        (int)i, i >= 0 && i < n ? ", again" : "");
            return fail(&c);
        }
        seen[i] = 1;
    }
    free(seen);
    const double *linear = data_of(&c, "linear"), *linear_rotation = data_of(&c, "linear_rotation");
    if ((linear == NULL) != (linear_rotation == NULL)) {
        value_error("linear and linear_rotation go together: give both or neither");
        return fail(&c);
    }
    for (int a = 0; linear_rotation != NULL && a < 3; ++a)
        for (int b = 0; b < 3; ++b) {
            const double *q = linear_rotation;
            const double dot = q[3 * a] * q[3 * b] + q[3 * a + 1] * q[3 * b + 1] + q[3 * a + 2] * q[3 * b + 2];
            if (fabs(dot - (a == b)) > 1e-6) {
                value_error("linear_rotation is not orthogonal (row %d . row %d = %g)", a, b, dot);
                return fail(&c);
            }
        }
    const float *rest = data_of(&c, "rest"), *deformed = data_of(&c, "deformed"),
                *log_scales = data_of(&c, "log_scales"), *quats = data_of(&c, "quats"),
                *sh = data_of(&c, "sh");
    float *out_log_scales = data_of(&c, "out_log_scales"), *out_quats = data_of(&c, "out_quats"),
          *out_sh = data_of(&c, "out_sh");
    const int32_t *neighbours = data_of(&c, "neighbours");
    const int coeffs = (int)SIZE(&c.d, DIM_K), threads = threads_of(&c);
    int status;
    Py_BEGIN_ALLOW_THREADS
    status = sc_deform_frame(rest, deformed, n, neighbours, (int)k, order, data_of(&c, "fit"),
                             linear, linear_rotation, log_scales, quats, sh, coeffs,
                             out_log_scales, out_quats, out_sh, threads);
    Py_END_ALLOW_THREADS
    if (status != 0) return fail(&c), PyErr_NoMemory();
    return finish(&c, Py_NewRef(Py_None));
}

/* ---------------------------------------------------------------- colour */

static PyObject *py_srgb_premultiplied(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "srgb_premultiplied");
    if (check(&c, "rgba", "rgba") != 0) return fail(&c);
    const Py_buffer *like = view_of(&c, "rgba");
    const int64_t n = (int64_t)(like->len / 4);
    if (like->ndim < 1 || like->shape[like->ndim - 1] != 4) {
        PyErr_Format(PyExc_ValueError, "rgba must have shape (..., 4), got %d dimensions ending in %zd",
                     like->ndim, like->ndim ? like->shape[like->ndim - 1] : (Py_ssize_t)0);
        return fail(&c);
    }
    if (check(&c, "out", "out") != 0) return fail(&c);
    const float *src = data_of(&c, "rgba");
    float *dst = data_of(&c, "out");
    const char *a = (const char *)src, *d = (const char *)dst;
    if (a != d && a < d + 4 * n && d < a + 4 * n) {
        PyErr_SetString(PyExc_ValueError, "out must be rgba itself or not overlap it");
        return fail(&c);
    }
    const int decode = (int)int_of(&c, "decode"), threads = threads_of(&c);
    Py_BEGIN_ALLOW_THREADS
    sc_srgb_premultiplied(src, dst, n / 4, decode, threads);
    Py_END_ALLOW_THREADS
    return finish(&c, Py_NewRef(Py_None));
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

static PyObject *py_viewport_image(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "viewport_image");
    if (check(&c, "rgb", "out_depth") != 0) return fail(&c);
    const char *names[] = {"rgb", "alpha", "depth", "out_rgba", "out_depth"};
    for (int a = 3; a < 5; ++a)
        for (int b = 0; b < 5; ++b)
            if (b != a && overlap(view_of(&c, names[a]), view_of(&c, names[b]))) {
                PyErr_Format(PyExc_ValueError, "%s must not overlap %s", names[a], names[b]);
                return fail(&c);
            }
    const int width = (int)SIZE(&c.d, DIM_W), height = (int)SIZE(&c.d, DIM_H);
    const float *rgb = data_of(&c, "rgb"), *alpha = data_of(&c, "alpha");
    const float *depth = data_of(&c, "depth");
    const double *projection = data_of(&c, "projection");
    float *rgba = data_of(&c, "out_rgba"), *window = data_of(&c, "out_depth");
    const int threads = threads_of(&c);
    Py_BEGIN_ALLOW_THREADS
    sc_viewport_image(rgb, alpha, depth, width, height, projection, rgba, window, threads);
    Py_END_ALLOW_THREADS
    return finish(&c, Py_NewRef(Py_None));
}

static PyObject *py_photo_rgb(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "photo_rgb");
    if (check(&c, "pixels", "out") != 0) return fail(&c);
    const Py_buffer *pixels = view_of(&c, "pixels"), *out = view_of(&c, "out");
    const Py_ssize_t channels = pixels->shape[2];
    if (channels < 3) {
        PyErr_Format(PyExc_ValueError, "pixels must have 3 or more channels, got %zd", channels);
        return fail(&c);
    }
    if (overlap(pixels, out)) {
        PyErr_SetString(PyExc_ValueError, "out must not overlap pixels");
        return fail(&c);
    }
    const int width = (int)SIZE(&c.d, DIM_W), height = (int)SIZE(&c.d, DIM_H);
    const uint8_t *in = data_of(&c, "pixels");
    float *rgb = data_of(&c, "out");
    const int threads = threads_of(&c);
    Py_BEGIN_ALLOW_THREADS
    sc_photo_rgb(in, width, height, (int)channels, rgb, threads);
    Py_END_ALLOW_THREADS
    return finish(&c, Py_NewRef(Py_None));
}

static PyObject *py_srgb_view(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "srgb_view");
    if (check(&c, "rgba", "out") != 0) return fail(&c);
    const Py_buffer *src_view = view_of(&c, "rgba"), *dst_view = view_of(&c, "out");
    if (!same_view(src_view, dst_view) && overlap(src_view, dst_view)) {
        PyErr_SetString(PyExc_ValueError, "out must be rgba itself or not overlap it");
        return fail(&c);
    }
    const sc_rgba_view src = rgba_view(src_view), dst = rgba_view(dst_view);
    const int decode = (int)int_of(&c, "decode"), zero = (int)int_of(&c, "zero_non_finite");
    const int threads = threads_of(&c);
    Py_BEGIN_ALLOW_THREADS
    sc_srgb_view(&src, &dst, decode, zero, threads);
    Py_END_ALLOW_THREADS
    return finish(&c, Py_NewRef(Py_None));
}

static PyObject *py_srgb_decode_changed(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "srgb_decode_changed");
    const int out_at = index_of(c.sig, "out"), layer_at = index_of(c.sig, "layer");
    const int in_place = c.objs[out_at] == NULL || c.objs[out_at] == Py_None;
    if (check(&c, "rgb", "mesh") != 0) return fail(&c);
    if (in_place) {
        /* layer is checked twice: C-contiguous and writable (read), then as the output view. */
        arg_spec layer = c.sig->params[layer_at], out = c.sig->params[out_at];
        layer.flags |= WRITABLE;
        out.name = "layer";
        out.flags &= ~(OPTIONAL | DEFAULTED);
        PyObject *obj = c.objs[layer_at];
        if (check_args(&c.b, &c.d, &layer, 1, &obj, &c.views[layer_at], 1) != 0 ||
            check_args(&c.b, &c.d, &out, 1, &obj, &c.views[out_at], 1) != 0)
            return fail(&c);
    } else if (check(&c, "layer", "out") != 0) {
        return fail(&c);
    }
    const Py_buffer *out_view = c.views[out_at];
    const char *const inputs[] = {"rgb", "alpha", "mesh"};
    for (int i = 0; i < 3; ++i)
        if (overlap(out_view, view_of(&c, inputs[i]))) {
            PyErr_Format(PyExc_ValueError, "%s must not overlap rgb, alpha or mesh",
                         in_place ? "layer" : "out");
            return fail(&c);
        }
    if (!same_view(out_view, c.views[layer_at]) && overlap(out_view, c.views[layer_at])) {
        PyErr_SetString(PyExc_ValueError, "out must be layer itself or not overlap it");
        return fail(&c);
    }
    const float *rgb = data_of(&c, "rgb"), *alpha = data_of(&c, "alpha");
    const float *layer = data(c.views[layer_at]);
    const sc_rgba_view mesh = rgba_view(view_of(&c, "mesh")), out = rgba_view(out_view);
    const int threads = threads_of(&c);
    Py_BEGIN_ALLOW_THREADS
    sc_srgb_decode_changed(rgb, alpha, &mesh, layer, &out, threads);
    Py_END_ALLOW_THREADS
    return finish(&c, Py_NewRef(Py_None));
}

/* ---------------------------------------------------------------- F12's composite */

static const char PREPARED_NAME[] = "splatcore.Prepared";

static void prepared_destructor(PyObject *capsule) {
    sc_prepared *p = PyCapsule_GetPointer(capsule, PREPARED_NAME);
    if (!p) {
        PyErr_Clear();
        return;
    }
    sc_prepared_free(p);
}

/* compose_prepare -> (prepared, stats): see sc_compose_prepare. The Gaussians' arrays are not
 * kept (the prepared frame holds its own copies). */
static PyObject *py_compose_prepare(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "compose_prepare");
    sc_gaussians g;
    sc_camera cam;
    sc_options opt;
    if (parse_common(&c, &g, &cam, &opt) != 0) return fail(&c);
    opt.exhaustive = (int)int_of(&c, "exhaustive");
    sc_stats stats = {0};
    sc_prepared *prepared = NULL;
    sc_status status;
    Py_BEGIN_ALLOW_THREADS
    status = sc_compose_prepare(&g, &cam, &opt, &prepared, &stats);
    Py_END_ALLOW_THREADS
    if (status != SC_OK) return finish(&c, raise_status(status, &g, &stats));
    finish(&c, NULL);
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

/* compose_srgb -> stats: see sc_compose_srgb (the arrays: COMPOSE_SRGB in bindings.h). */
static PyObject *py_compose_srgb(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "compose_srgb");
    PyObject *capsule = object_of(&c, "prepared");
    if (!PyCapsule_IsValid(capsule, PREPARED_NAME)) {
        PyErr_SetString(PyExc_TypeError, "prepared must be what compose_prepare returned");
        return NULL;
    }
    const sc_prepared *prepared = PyCapsule_GetPointer(capsule, PREPARED_NAME);
    int width, height;
    sc_prepared_size(prepared, &width, &height);
    SIZE(&c.d, DIM_H) = height, SIZE(&c.d, DIM_W) = width;
    if (check(&c, "mesh_rgba", "out_depth") != 0) return fail(&c);
    const sc_rgba_view mesh = rgba_view(view_of(&c, "mesh_rgba")), out = rgba_view(view_of(&c, "out"));
    const sc_plane_view mesh_depth = plane_view(view_of(&c, "mesh_depth"));
    float *out_depth = data_of(&c, "out_depth");
    for (int i = 0; i < c.b.count; ++i)
        for (int k = i + 1; k < c.b.count; ++k)
            if (i != 0 || k != 1) /* the two inputs may share a buffer */
                if (overlap(&c.b.views[i], &c.b.views[k])) {
                    PyErr_SetString(PyExc_ValueError,
                                    "out and out_depth must overlap neither each other nor the "
                                    "mesh layers");
                    return fail(&c);
                }
    const double far = real_of(&c, "far");
    if (!isfinite(far)) {
        PyErr_SetString(PyExc_ValueError, "far must be finite");
        return fail(&c);
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
    return finish(&c, result);
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

static PyObject *py_composite_microbench(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "composite_microbench");
    const int count = (int)int_of(&c, "count"), iterations = (int)int_of(&c, "iterations");
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

/* sort_keys -> count of keys not +inf: see sc_sort_keys. */
static PyObject *py_sort_keys(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "sort_keys");
    if (check(&c, "keys", "keys") != 0) return fail(&c);
    const Py_ssize_t n = SIZE(&c.d, DIM_ROWS);
    if (n > MAX_GAUSSIANS) {
        PyErr_Format(PyExc_ValueError, "at most %lld keys, got %zd", MAX_GAUSSIANS, n);
        return fail(&c);
    }
    if (check(&c, "out_order", "out_order") != 0) return fail(&c);
    const float *keys = data_of(&c, "keys");
    int32_t *order = data_of(&c, "out_order");
    const int threads = threads_of(&c);
    sc_stats stats = {0};
    int64_t finite = 0;
    sc_status status;
    Py_BEGIN_ALLOW_THREADS
    status = sc_sort_keys(keys, n, threads, order, &finite, &stats);
    Py_END_ALLOW_THREADS
    if (status == SC_ERR_NONFINITE) {
        PyErr_Format(PyExc_ValueError, "key %lld is NaN", (long long)stats.error_index);
        return fail(&c);
    }
    if (status != SC_OK) return PyErr_NoMemory(), fail(&c);
    return finish(&c, PyLong_FromLongLong(finite));
}

/* ---------------------------------------------------------------- kept image memory
 * Memory for a render's images from the buffers frames keep (buffers.c), as a writable buffer
 * object: NumPy views it, and when the last view is gone the block goes back to be kept for
 * the next frame. Fresh memory is faulted in page by page, zeroed by the kernel: at 3840x2160 a
 * render's three images (166 MB) took about as long as its composite, on one thread's time. */

typedef struct {
    PyObject_HEAD
    void *data;
    Py_ssize_t bytes;
} image_memory;

static int image_memory_getbuffer(PyObject *self, Py_buffer *view, int flags) {
    image_memory *m = (image_memory *)self;
    return PyBuffer_FillInfo(view, self, m->data, m->bytes, 0, flags);
}

static void image_memory_dealloc(PyObject *self) {
    PyTypeObject *type = Py_TYPE(self);
    sc_image_free(((image_memory *)self)->data);
    freefunc free_self = (freefunc)PyType_GetSlot(type, Py_tp_free);
    free_self(self);
    Py_DECREF(type);
}

static PyType_Slot image_memory_slots[] = {
    {Py_bf_getbuffer, (void *)image_memory_getbuffer},
    {Py_tp_dealloc, (void *)image_memory_dealloc},
    {Py_tp_doc, (void *)"Kept memory for a render's image (image_memory(bytes))."},
    {0, NULL},
};

static PyType_Spec image_memory_spec = {"splatcore.ImageMemory", sizeof(image_memory), 0,
                                        Py_TPFLAGS_DEFAULT, image_memory_slots};

static PyObject *image_memory_type; /* made at import */

static PyObject *py_image_memory(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "image_memory");
    const long long bytes = int_of(&c, "bytes");
    if (bytes < 0 || bytes > (long long)MAX_PIXELS * 64) {
        PyErr_Format(PyExc_ValueError, "bytes must be in 0..%lld, got %lld",
                     (long long)MAX_PIXELS * 64, bytes);
        return fail(&c);
    }
    finish(&c, NULL);
    void *data = sc_image_alloc((size_t)bytes);
    if (!data) return PyErr_NoMemory();
    allocfunc alloc = (allocfunc)PyType_GetSlot((PyTypeObject *)image_memory_type, Py_tp_alloc);
    image_memory *m = (image_memory *)alloc((PyTypeObject *)image_memory_type, 0);
    if (!m) {
        sc_image_free(data);
        return NULL;
    }
    m->data = data, m->bytes = (Py_ssize_t)bytes;
    return (PyObject *)m;
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

static PyObject *py_pool_profile(PyObject *self, PyObject *args, PyObject *kwargs) {
    BEGIN(c, "pool_profile");
    sc_pool_counters taken;
    sc_pool_profile(!int_of(&c, "enable")     ? SC_PROFILE_OFF
                    : int_of(&c, "cpu_clock") ? SC_PROFILE_CPU
                                              : SC_PROFILE_WALL,
                    &taken);
    return finish(&c, Py_BuildValue("{s:L,s:d,s:d,s:d}", "jobs", (long long)taken.jobs,
                                    "inside_ms", taken.inside_ms, "busy_ms", taken.busy_ms,
                                    "offered_ms", taken.offered_ms));
}

/* What an argument is, in words: "float32 array (N, 3)", "int", "threads", ... */
static PyObject *describe(const arg_spec *s) {
    static const char *const kinds[] = {"array", "int", "int", "float", "bool", "threads", "object"};
    if (s->kind != ARRAY) return PyUnicode_FromString(kinds[s->kind]);
    char shape[64] = "";
    if (s->flags & (ANY_RANK | LIKE)) {
        snprintf(shape, sizeof shape, "%s", s->flags & LIKE ? "(like the array before)" : "(any)");
    } else {
        for (int k = 0; k < s->ndim; ++k) {
            const size_t at = strlen(shape);
            const Py_ssize_t want = s->shape[k];
            if (want >= 0) snprintf(shape + at, sizeof shape - at, "%s%zd", k ? ", " : "(", want);
            else if (want == ANY) snprintf(shape + at, sizeof shape - at, "%s*", k ? ", " : "(");
            else snprintf(shape + at, sizeof shape - at, "%s%c", k ? ", " : "(", DIM_LETTER[-2 - want]);
        }
        strncat(shape, s->ndim == 1 ? ",)" : ")", sizeof shape - strlen(shape) - 1);
    }
    return PyUnicode_FromFormat("%s array %s%s%s", type_name(s->type), shape,
                                s->flags & WRITABLE ? ", written" : "",
                                s->flags & OPTIONAL ? ", or None" : "");
}

/* signature(name) -> ((argument, what it is, may be left out), ...) in call order. */
static PyObject *py_signature(PyObject *self, PyObject *arg) {
    (void)self;
    const char *name = PyUnicode_AsUTF8AndSize(arg, NULL);
    if (!name) return NULL;
    for (int i = 0; i < COUNT(SIGNATURES); ++i) {
        if (strcmp(SIGNATURES[i].name, name) != 0) continue;
        const signature *sig = &SIGNATURES[i];
        PyObject *result = PyTuple_New(sig->count);
        for (int k = 0; result && k < sig->count; ++k) {
            const arg_spec *s = &sig->params[k];
            PyObject *item = Py_BuildValue("(sNO)", s->name, describe(s),
                                           s->flags & DEFAULTED ? Py_True : Py_False);
            if (!item || PyTuple_SetItem(result, k, item) != 0) Py_CLEAR(result);
        }
        return result;
    }
    return PyErr_Format(PyExc_ValueError, "splatcore has no entry point %R", arg);
}

/* The methods: METH_VARARGS | METH_KEYWORDS ones take their arguments by their table. */
#define WITH_KEYWORDS(function) (PyCFunction)(void (*)(void))(function), METH_VARARGS | METH_KEYWORDS

/* Each docstring says what the entry point does; its arguments are its table's
 * (`splatcore.signature(name)`, bindings.h), by position or by name. */
static PyMethodDef methods[] = {
    {"project", WITH_KEYWORDS(py_project),
     "project(...) -> None\n\nProject every Gaussian; fills the out_* arrays."},
    {"render", WITH_KEYWORDS(py_render),
     "render(...) -> stats\n\nRender into the out_* arrays over the optional mesh layer and "
     "background; returns timings (ms) and counts. exhaustive: evaluate each Gaussian over its "
     "tiles' whole bounding spans (the same image, for tests)."},
    {"compose_prepare", WITH_KEYWORDS(py_compose_prepare),
     "compose_prepare(...) -> (prepared, stats)\n\nF12's composite, the Gaussians' half "
     "(sc_compose_prepare): projected, sorted and binned for the camera; no mesh needed yet."},
    {"compose_srgb", WITH_KEYWORDS(py_compose_srgb),
     "compose_srgb(...) -> stats\n\nF12's composite (sc_compose_srgb): the prepared Gaussians "
     "over a scene-linear mesh render, composed in display sRGB, into out (scene-linear) and "
     "out_depth (None: no depth); tiles no Gaussian reaches keep the mesh's pixels."},
    {"checksum", py_checksum, METH_O,
     "checksum(buffer) -> tuple of four ints\n\nA 256-bit checksum of a C-contiguous buffer's "
     "bytes (sc_checksum): any change within 193 consecutive bits changes it."},
    {"sort_keys", WITH_KEYWORDS(py_sort_keys),
     "sort_keys(...) -> int\n\nThe renderer's depth sort on its own (for tests): out_order gets "
     "the stable ascending order of keys (+inf last, -0 before +0, no NaN); returns how many "
     "keys are not +inf."},
    {"release_buffers", py_release_buffers, METH_NOARGS,
     "release_buffers()\n\nFree the working buffers renders keep for the next frame."},
    {"render_train", WITH_KEYWORDS(py_render_train),
     "render_train(...) -> (stats, state)\n\nThe training forward: render (no mesh layer) into "
     "the out_* arrays, bit-identical to render(); out_final_t and out_n_contrib get the "
     "per-pixel final transmittance and n_contrib; out_visible 1 for each Gaussian drawn (its "
     "footprint reaches a pixel). `state` is an opaque handle holding what backward() needs. "
     "exhaustive: this forward and its backward run their slow twins (each Gaussian over its "
     "tiles' whole spans; the projection backward one Gaussian at a time)."},
    {"train_state_info", py_train_state_info, METH_O,
     "train_state_info(state) -> dict: the image size, Gaussian count, options and counts of a "
     "training state."},
    {"backward", WITH_KEYWORDS(py_backward),
     "backward(...) -> stats\n\nGradients of a loss with dL/d(rgb), dL/d(alpha) and dL/d(depth) "
     "(None: no such term) w.r.t. the Gaussians render_train drew (the same arrays, unchanged), "
     "into the out_* arrays (overwritten)."},
    {"l1_ssim", WITH_KEYWORDS(py_l1_ssim),
     "l1_ssim(...) -> (loss, l1, ssim, mse)\n\n(1 - lambda) L1 + lambda (1 - SSIM) of two "
     "images; dL/d(image) into out_grad when it is not None; mse: of the image clamped to "
     "[0, 1] (PSNR's)."},
    {"adam", WITH_KEYWORDS(py_adam),
     "adam(...) -> None\n\nOne Adam step in place (torch.optim.Adam's formula). rows: rows "
     "where it is 0 are left as they are (moments too). The first `lead` values of each row "
     "(along the first axis) step at lead_lr; only the first `used` values of each row are "
     "updated (negative: all)."},
    {"position_noise", WITH_KEYWORDS(py_position_noise),
     "position_noise(...) -> None\n\n3DGS-MCMC's noise on the means in place "
     "(sc_position_noise), noise standard normal."},
    {"neighbours", WITH_KEYWORDS(py_neighbours),
     "neighbours(...) -> None\n\nThe k nearest other points of each point into out (N, k), "
     "nearest first, ties to the lower index, -1 where fewer exist (sc_neighbours)."},
    {"deformation_jacobians", WITH_KEYWORDS(py_deformation_jacobians),
     "deformation_jacobians(...) -> None\n\nEach point's deformation Jacobian from its "
     "neighbours' rest and deformed positions, and its polar rotation "
     "(sc_deformation_jacobians)."},
    {"deform_shapes", WITH_KEYWORDS(py_deform_shapes),
     "deform_shapes(...) -> None\n\nLog-scales and quaternions of J Sigma J^T and SH rotated, "
     "a Jacobian and a rotation per Gaussian (sc_deform_shapes)."},
    {"deform_rest", WITH_KEYWORDS(py_deform_rest),
     "deform_rest(...) -> None\n\nThe rest positions' half of each point's deformation fit, "
     "shared by a deformation's frames (sc_deform_rest)."},
    {"deform_frame", WITH_KEYWORDS(py_deform_frame),
     "deform_frame(...) -> None\n\nThe deformation Jacobians fitted and the Gaussians' shapes "
     "and SH through them, in one pass over rows in a spatial order (sc_deform_frame)."},
    {"srgb_premultiplied", WITH_KEYWORDS(py_srgb_premultiplied),
     "srgb_premultiplied(...) -> None\n\nPremultiplied RGBA (..., 4) scene-linear -> display "
     "sRGB (decode False) or back (True), into out (rgba itself, or an array of its shape)."},
    {"srgb_view", WITH_KEYWORDS(py_srgb_view),
     "srgb_view(...) -> None\n\nsrgb_premultiplied for (H, W, 4) arrays with any strides; "
     "with zero_non_finite, non-finite results become 0."},
    {"srgb_decode_changed", WITH_KEYWORDS(py_srgb_decode_changed),
     "srgb_decode_changed(...) -> None\n\ncompose's way back: out (left out: layer, the display "
     "layer) gets the scene-linear result: the composite (rgb, alpha) decoded where it differs "
     "from layer, mesh's pixel elsewhere."},
    {"composite_microbench", WITH_KEYWORDS(py_composite_microbench),
     "composite_microbench(...) -> seconds for the compositor's inner loop over one in-cache "
     "tile covered by `count` Gaussians, `iterations` times."},
    {"cpu_count", py_cpu_count, METH_NOARGS, "Cores this process may use."},
    {"viewport_image", WITH_KEYWORDS(py_viewport_image),
     "viewport_image(...) -> None\n\nA render's rgb, alpha and depth into the viewport's "
     "premultiplied RGBA and depth-buffer values, rows bottom to top (sc_viewport_image)."},
    {"photo_rgb", WITH_KEYWORDS(py_photo_rgb),
     "photo_rgb(...) -> None\n\n8-bit photo pixels (H, W, C >= 3) into float32 RGB in [0, 1] "
     "(sc_photo_rgb), as NumPy's astype(float32) * float32(1 / 255)."},
    {"image_memory", WITH_KEYWORDS(py_image_memory),
     "image_memory(...) -> ImageMemory\n\n`bytes` of memory for a render's image, from the "
     "buffers frames keep (a writable buffer; back to be kept when the last view of it is "
     "gone)."},
    {"pool_profile", WITH_KEYWORDS(py_pool_profile),
     "pool_profile(...) -> dict\n\nThe thread pool's counters since the last call (jobs, "
     "inside_ms, busy_ms, offered_ms; see sc_pool_counters), zeroed; profiles from now on if "
     "`enable` (the stages' stats then fill their ms_pool_* fields), by the calling thread's "
     "CPU clock with `cpu_clock` (for one thread)."},
    {"signature", py_signature, METH_O,
     "signature(name) -> ((argument, what it is, may be left out), ...)\n\nThe arguments of "
     "entry point `name` in call order, from the one table module.c parses them by."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "splatcore",
    "Native 3D Gaussian splatting renderer (see native/include/splatcore.h).", -1, methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit_splatcore(void) {
    PyObject *m = PyModule_Create(&module);
    if (!m) return NULL;
    image_memory_type = PyType_FromSpec(&image_memory_spec); /* kept for the module's life */
    if (!image_memory_type) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
