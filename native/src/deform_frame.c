/* A frame of a deformation in one pass (sc_deform_frame, splatcore.h): per Gaussian, the
 * Jacobian and its polar rotation fitted from its neighbours (sc_fit_batch, deform_fit.c,
 * from the rest half of the fit its row keeps: sc_deform_rest, once per rest shape) and the
 * Gaussian's shape and SH through them (sc_shapes_batch, deform_apply.c: SC_SHAPE_LANES rows'
 * Gaussians at a time), the two maps kept on the stack rather than written to and read back
 * from two (n, 3, 3) double arrays.
 *
 * The fit reads every neighbour's rest and deformed centre: in the Gaussians' own order (a
 * capture's, a random cloud's) those are scattered over memory, a cache miss each, about a
 * third of the fit. So the rest centres come in the rows of a spatial order (`order[row]` is
 * the Gaussian in that row; the neighbours given as rows), the deformed centres are permuted
 * into those rows first, and the rows are walked in that order: a row's neighbours lie a few
 * rows away and were mostly read for the rows before it; those a Morton jump away are asked
 * for AHEAD rows early. Each Gaussian's own parameters are then scattered (read and written
 * whole: a few cache lines each), asked for AHEAD rows early too.
 * Every Gaussian's result is computed by the same code from the same numbers whichever thread
 * takes its row, so it is the same for every thread count, and bit for bit what the two
 * stages give one after the other. The outputs may be the inputs (sc_shapes_batch reads its
 * Gaussians' shapes and SH whole before writing theirs). An object's matrix may follow the
 * deformation (linear, and its polar rotation for the SH): the gather then turns each SH once,
 * not once here and again for the object. */
#include <stdlib.h>
#include <string.h>

#include "deform.h"

enum { GRAIN = 4096, AHEAD = 16 };

typedef struct {
    const float *deformed; /* by Gaussian */
    const int32_t *order;
    float *rows;           /* the deformed centres by row */
} permute_job;

static void permute(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const permute_job *j = ctx;
    for (int64_t row = begin; row < end; ++row) {
        const float *from = j->deformed + 3 * (int64_t)j->order[row];
        float *to = j->rows + 3 * row;
        to[0] = from[0], to[1] = from[1], to[2] = from[2];
    }
}

typedef struct {
    sc_fit_input fit;
    const double *rest_fit; /* by row: sc_fit_rest's halves */
    sc_shapes shapes;
    const int32_t *order;
    const double *linear, *linear_rotation; /* both or NULL */
} frame_job;

static void then(const double l[9], double m[9]) { /* m <- l m */
    double out[9];
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
            out[3 * r + c] = l[3 * r] * m[c] + l[3 * r + 1] * m[3 + c] + l[3 * r + 2] * m[6 + c];
    memcpy(m, out, sizeof out);
}

static void prefetch(const frame_job *j, int64_t i) {
    const int64_t coeffs = 3 * (int64_t)j->shapes.coeffs;
    SC_PREFETCH(j->shapes.log_scales + 3 * i);
    SC_PREFETCH(j->shapes.quats + 4 * i);
    SC_PREFETCH_WRITE(j->shapes.out_log_scales + 3 * i);
    SC_PREFETCH_WRITE(j->shapes.out_quats + 4 * i);
    for (int64_t c = 0; c < coeffs; c += 16) {
        SC_PREFETCH(j->shapes.sh + coeffs * i + c);
        SC_PREFETCH_WRITE(j->shapes.out_sh + coeffs * i + c);
    }
}

/* Row `row`'s neighbours' rest and deformed centres (a neighbour a Morton jump away is a miss). */
static void prefetch_neighbours(const frame_job *j, int64_t row) {
    const int32_t *nb = j->fit.neighbours + (int64_t)j->fit.k * row;
    for (int m = 0; m < j->fit.k; ++m) {
        if (nb[m] < 0) continue;
        SC_PREFETCH(j->fit.rest + 3 * (int64_t)nb[m]);
        SC_PREFETCH(j->fit.deformed + 3 * (int64_t)nb[m]);
    }
}

static void frame_rows(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const frame_job *j = ctx;
    const int64_t stride = SC_FIT_FIELDS + j->fit.k;
    for (int64_t row = begin; row < end && row < begin + AHEAD; ++row) prefetch(j, j->order[row]);
    sc_shape_batch b;
    for (int64_t start = begin; start < end; start += SC_SHAPE_LANES) {
        b.count = end - start < SC_SHAPE_LANES ? (int)(end - start) : SC_SHAPE_LANES;
        for (int l = 0; l < b.count; ++l)
            if (start + l + AHEAD < end) {
                prefetch(j, j->order[start + l + AHEAD]);
                prefetch_neighbours(j, start + l + AHEAD);
            }
        sc_fit_batch(&j->fit, start, b.count, j->rest_fit + stride * start, b.jac, b.rot);
        for (int l = 0; l < b.count; ++l) {
            if (j->linear) then(j->linear, b.jac[l]), then(j->linear_rotation, b.rot[l]);
            b.index[l] = j->order[start + l];
        }
        sc_shapes_batch(&j->shapes, &b);
    }
}

int sc_deform_frame(const float *rest, const float *deformed, int64_t n,
                    const int32_t *neighbours, int k, const int32_t *order, const double *fit,
                    const double *linear, const double *linear_rotation,
                    const float *log_scales, const float *quats, const float *sh, int sh_coeffs,
                    float *out_log_scales, float *out_quats, float *out_sh, int threads) {
    threads = threads < 1 ? 1 : threads;
    float *rows = malloc(sizeof(float) * 3 * (size_t)(n > 0 ? n : 1));
    if (rows == NULL) return -2;
    permute_job p = {.deformed = deformed, .order = order, .rows = rows};
    sc_parallel_for(threads, n, 65536, permute, &p);
    frame_job j = {.fit = {.rest = rest, .deformed = rows, .neighbours = neighbours, .k = k},
                   .rest_fit = fit,
                   .shapes = {.log_scales = log_scales, .quats = quats, .sh = sh,
                              .coeffs = sh_coeffs, .out_log_scales = out_log_scales,
                              .out_quats = out_quats, .out_sh = out_sh},
                   .order = order, .linear = linear, .linear_rotation = linear_rotation};
    sc_shapes_prepare(&j.shapes);
    sc_parallel_for(threads, n, GRAIN, frame_rows, &j);
    free(rows);
    return 0;
}
