/* The Python binding: validates every argument, then runs the C pipeline with the GIL released.
 * Arrays cross through the buffer protocol (numpy arrays in, caller-allocated numpy arrays out),
 * so there is no numpy C dependency, and the limited API 3.11 keeps one binary (abi3) for
 * every Blender from 4.2 on. Nothing here may crash the host: any bad argument is a TypeError
 * or ValueError that says what is wrong. */
#define Py_LIMITED_API 0x030B0000
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "splatcore.h"

enum { MAX_SIDE = 32768 };
static const long long MAX_PIXELS = 1LL << 27;
static const long long MAX_GAUSSIANS = 0x7fffffffLL;

/* Which arrays a call holds, so every exit path can release them. */
typedef struct {
    Py_buffer views[16];
    int count;
} buffers;

static void release_all(buffers *b) {
    for (int i = 0; i < b->count; ++i) PyBuffer_Release(&b->views[i]);
    b->count = 0;
}

static int format_is(const char *format, char type) {
    if (!format) return type == 'B';
    if (*format == '@' || *format == '=' || *format == '<') format++;
    return format[0] == type && format[1] == '\0';
}

static const char *type_name(char type) {
    return type == 'f' ? "float32" : type == 'd' ? "float64" : "uint8";
}

/* Get a C-contiguous buffer of `type` with shape `shape` (-1: any size) or raise. */
static const void *get_array(buffers *b, PyObject *obj, const char *name, char type, int ndim,
                             const Py_ssize_t *shape, int writable) {
    Py_buffer *view = &b->views[b->count];
    int flags = PyBUF_FORMAT | PyBUF_STRIDES | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) != 0) {
        PyErr_Clear();
        if (writable && PyObject_GetBuffer(obj, view, PyBUF_FORMAT | PyBUF_STRIDES) == 0) {
            PyBuffer_Release(view);
            PyErr_Format(PyExc_ValueError, "%s must be a writable array", name);
        } else {
            PyObject *type_obj = PyType_GetName(Py_TYPE(obj));
            PyErr_Format(PyExc_TypeError, "%s must be a %s array (buffer protocol), got %S", name,
                         type_name(type), type_obj ? type_obj : Py_None);
            Py_XDECREF(type_obj);
        }
        return NULL;
    }
    b->count++;
    if (!format_is(view->format, type) || view->itemsize != (type == 'd' ? 8 : type == 'f' ? 4 : 1)) {
        PyErr_Format(PyExc_TypeError, "%s must have dtype %s, got format '%s'", name,
                     type_name(type), view->format ? view->format : "B");
        return NULL;
    }
    if (!PyBuffer_IsContiguous(view, 'C')) {
        PyErr_Format(PyExc_ValueError, "%s must be C-contiguous (use numpy.ascontiguousarray)", name);
        return NULL;
    }
    int shape_ok = view->ndim == ndim;
    for (int i = 0; shape_ok && i < ndim; ++i) shape_ok = shape[i] < 0 || view->shape[i] == shape[i];
    if (!shape_ok) {
        char want[96] = "(", got[96] = "(";
        for (int i = 0; i < ndim; ++i) {
            size_t at = strlen(want);
            if (shape[i] < 0) snprintf(want + at, sizeof want - at, "%s%s", i ? ", " : "", "N");
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
    return view->buf;
}

static int all_finite_d(const double *v, int n) {
    for (int i = 0; i < n; ++i)
        if (!isfinite(v[i])) return 0;
    return 1;
}

/* Parse the arguments project() and render() share: Gaussians, camera, options. */
static int parse_common(buffers *b, PyObject *const *objs, int sh_degree, int width, int height,
                        double near, int antialiased, int threads, sc_gaussians *g, sc_camera *cam,
                        sc_options *opt) {
    const Py_ssize_t n3[] = {-1, 3}, n4[] = {-1, 4}, n1[] = {-1}, m44[] = {4, 4}, v4[] = {4};
    if (!(g->means = get_array(b, objs[0], "means", 'f', 2, n3, 0))) return -1;
    const Py_ssize_t n = b->views[b->count - 1].shape[0];
    if (n > MAX_GAUSSIANS) {
        PyErr_Format(PyExc_ValueError, "too many Gaussians (%zd); at most %lld", n, MAX_GAUSSIANS);
        return -1;
    }
    const Py_ssize_t rows3[] = {n, 3}, rows4[] = {n, 4}, rows1[] = {n}, sh_shape[] = {n, -1, 3};
    (void)n4, (void)n1;
    if (!(g->log_scales = get_array(b, objs[1], "log_scales", 'f', 2, rows3, 0))) return -1;
    if (!(g->quats = get_array(b, objs[2], "quats", 'f', 2, rows4, 0))) return -1;
    if (!(g->opacity_logits = get_array(b, objs[3], "opacity_logits", 'f', 1, rows1, 0))) return -1;
    if (!(g->sh = get_array(b, objs[4], "sh", 'f', 3, sh_shape, 0))) return -1;
    g->count = n;
    g->sh_coeffs = (int)b->views[b->count - 1].shape[1];
    int data_degree = g->sh_coeffs == 1 ? 0 : g->sh_coeffs == 4 ? 1 : g->sh_coeffs == 9 ? 2
                    : g->sh_coeffs == 16 ? 3 : -1;
    if (data_degree < 0) {
        PyErr_Format(PyExc_ValueError, "sh must have shape (N, K, 3) with K in 1, 4, 9, 16; got K=%d",
                     g->sh_coeffs);
        return -1;
    }
    if (sh_degree < 0 || sh_degree > data_degree) {
        PyErr_Format(PyExc_ValueError, "sh_degree must be in 0..%d for this data, got %d",
                     data_degree, sh_degree);
        return -1;
    }

    const double *viewmat = get_array(b, objs[5], "world_to_camera", 'd', 2, m44, 0);
    if (!viewmat) return -1;
    const double *intr = get_array(b, objs[6], "intrinsics", 'd', 1, v4, 0);
    if (!intr) return -1;
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
        PyErr_Format(PyExc_ValueError,
                     "world_to_camera must be rigid (orthonormal rotation, last row 0 0 0 1); "
                     "it is off by %g", worst);
        return -1;
    }
    if (!(intr[0] > 0) || !(intr[1] > 0)) {
        PyErr_Format(PyExc_ValueError, "focal lengths must be positive, got fx=%g fy=%g", intr[0],
                     intr[1]);
        return -1;
    }
    if (width <= 0 || height <= 0 || width > MAX_SIDE || height > MAX_SIDE ||
        (long long)width * height > MAX_PIXELS) {
        PyErr_Format(PyExc_ValueError,
                     "image size %dx%d is invalid: sides must be 1..%d and at most %lld pixels",
                     width, height, (int)MAX_SIDE, MAX_PIXELS);
        return -1;
    }
    if (!(near >= 0) || !isfinite(near)) {
        PyErr_Format(PyExc_ValueError, "near must be finite and >= 0, got %g", near);
        return -1;
    }
    if (threads < 0) {
        PyErr_Format(PyExc_ValueError, "threads must be >= 0 (0 = all cores), got %d", threads);
        return -1;
    }
    memcpy(cam->world_to_camera, viewmat, sizeof cam->world_to_camera);
    cam->fx = intr[0], cam->fy = intr[1], cam->cx = intr[2], cam->cy = intr[3];
    cam->width = width, cam->height = height;
    opt->sh_degree = sh_degree;
    opt->near = near;
    opt->antialiased = antialiased;
    opt->threads = threads ? threads : sc_cpu_count();
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
    if (status == SC_ERR_TOO_LARGE)
        return PyErr_Format(PyExc_MemoryError,
                            "too many Gaussian/tile overlaps to render this image; "
                            "use a smaller image or fewer, smaller Gaussians");
    return PyErr_NoMemory();
}

static PyObject *py_project(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *objs[7], *outs[6];
    int sh_degree, width, height, antialiased, threads;
    double near;
    if (!PyArg_ParseTuple(args, "OOOOOiOOiidpiOOOOOO:project", &objs[0], &objs[1], &objs[2],
                          &objs[3], &objs[4], &sh_degree, &objs[5], &objs[6], &width, &height,
                          &near, &antialiased, &threads, &outs[0], &outs[1], &outs[2], &outs[3],
                          &outs[4], &outs[5]))
        return NULL;
    buffers b = {.count = 0};
    sc_gaussians g;
    sc_camera cam;
    sc_options opt;
    if (parse_common(&b, objs, sh_degree, width, height, near, antialiased, threads, &g, &cam,
                     &opt) != 0) {
        release_all(&b);
        return NULL;
    }
    const Py_ssize_t n = (Py_ssize_t)g.count, n2[] = {n, 2}, n3[] = {n, 3}, n1[] = {n};
    float *xy = (float *)get_array(&b, outs[0], "out_xy", 'f', 2, n2, 1);
    float *conic = xy ? (float *)get_array(&b, outs[1], "out_conic", 'f', 2, n3, 1) : NULL;
    float *depth = conic ? (float *)get_array(&b, outs[2], "out_depth", 'f', 1, n1, 1) : NULL;
    float *opacity = depth ? (float *)get_array(&b, outs[3], "out_opacity", 'f', 1, n1, 1) : NULL;
    float *rgb = opacity ? (float *)get_array(&b, outs[4], "out_rgb", 'f', 2, n3, 1) : NULL;
    uint8_t *valid = rgb ? (uint8_t *)get_array(&b, outs[5], "out_valid", 'B', 1, n1, 1) : NULL;
    if (!valid) {
        release_all(&b);
        return NULL;
    }
    sc_projection proj = {malloc(sizeof(sc_splat) * (size_t)(n ? n : 1)),
                          malloc(sizeof(sc_footprint) * (size_t)(n ? n : 1)), valid};
    sc_stats stats = {0};
    sc_status status = SC_ERR_MEMORY;
    if (proj.splats && proj.footprints) {
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
    free(proj.footprints);
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
        set_number(d, "evaluations", PyLong_FromLongLong(s->evaluations))) {
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

static PyObject *py_render(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *objs[7], *background, *mesh_rgba, *mesh_depth, *outs[3];
    int sh_degree, width, height, antialiased, threads;
    double near;
    if (!PyArg_ParseTuple(args, "OOOOOiOOiidpiOOOOOO:render", &objs[0], &objs[1], &objs[2],
                          &objs[3], &objs[4], &sh_degree, &objs[5], &objs[6], &width, &height,
                          &near, &antialiased, &threads, &background, &mesh_rgba, &mesh_depth,
                          &outs[0], &outs[1], &outs[2]))
        return NULL;
    buffers b = {.count = 0};
    sc_gaussians g;
    sc_camera cam;
    sc_options opt;
    sc_image image = {0};
    if (parse_common(&b, objs, sh_degree, width, height, near, antialiased, threads, &g, &cam,
                     &opt) != 0)
        goto fail;
    const Py_ssize_t img3[] = {height, width, 3}, img4[] = {height, width, 4}, img1[] = {height, width},
                     rgb3[] = {3};
    if (background != Py_None) {
        if (!(image.background = get_array(&b, background, "background", 'f', 1, rgb3, 0))) goto fail;
        if (!isfinite(image.background[0]) || !isfinite(image.background[1]) ||
            !isfinite(image.background[2])) {
            PyErr_SetString(PyExc_ValueError, "background colour is non-finite");
            goto fail;
        }
    }
    if ((mesh_rgba == Py_None) != (mesh_depth == Py_None)) {
        PyErr_SetString(PyExc_ValueError, "mesh_rgba and mesh_depth must be given together");
        goto fail;
    }
    if (mesh_rgba != Py_None) {
        if (!(image.mesh_rgba = get_array(&b, mesh_rgba, "mesh_rgba", 'f', 3, img4, 0))) goto fail;
        if (!(image.mesh_depth = get_array(&b, mesh_depth, "mesh_depth", 'f', 2, img1, 0))) goto fail;
        if (check_mesh(image.mesh_rgba, image.mesh_depth, (int64_t)width * height) != 0) goto fail;
    }
    if (!(image.rgb = (float *)get_array(&b, outs[0], "out_rgb", 'f', 3, img3, 1))) goto fail;
    if (!(image.alpha = (float *)get_array(&b, outs[1], "out_alpha", 'f', 2, img1, 1))) goto fail;
    if (!(image.depth = (float *)get_array(&b, outs[2], "out_depth", 'f', 2, img1, 1))) goto fail;

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
     "out_rgb, out_alpha, out_depth) -> stats\n\nRender into the out_* arrays; returns timings "
     "(ms) and counts."},
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
