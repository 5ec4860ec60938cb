/* Each Gaussian's deformation Jacobian from its neighbours (sc_deformation_jacobians,
 * splatcore.h): the J that maps rest offsets to deformed offsets best, in weighted least
 * squares, with the directions the neighbourhood does not span filled in by a rotation.
 *
 * For Gaussian i with rest centre p, deformed centre x and neighbours j: a_j = p_j - p,
 * b_j = x_j - x, w_j = exp(-|a_j|^2 / max |a|^2). A = sum w a a^T (the neighbourhood's spread),
 * B = sum w b a^T. With A's eigenpairs (l_m, e_m), l_1 >= l_2 >= l_3, e_3 = e_1 x e_2, and
 * f_m = B e_m / l_m (where J sends e_m, as far as the data says):
 *
 *   J = sum_m (c_m f_m + (1 - c_m) R e_m) e_m^T,   c_m = ramp(l_m / l_1)
 *
 * c_m is 0 below `undetermined`, 1 above `determined`, linear between: a direction the
 * neighbours span (thick enough against the widest) is fitted, one they do not (a row's
 * sides, a sheet's normal) follows R, and J changes continuously between. R is the rotation
 * the data determines best: d_1 = f_1 / |f_1|; R_1 the smallest rotation taking e_1 to d_1;
 * when the second direction counts (c_2 > 0), d_2 is u_2 = c_2 f_2/|f_2| + (1 - c_2) R_1 e_2
 * made orthogonal to d_1, d_3 = d_1 x d_2, R = sum d_m e_m^T; else R = R_1. So:
 *   - a neighbourhood spanning 3D (every c_m = 1) gives J = B A^-1, exactly the linear part
 *     of an affine deformation;
 *   - a rigid motion gives its rotation exactly (to rounding) whenever the neighbours span at
 *     least a plane (f_m = R e_m), and its smallest rotation for a row (a turn about the row
 *     itself is invisible in it);
 *   - a row's sides and a sheet's normal turn with it rather than keeping their rest
 *     direction (the ladder of dashes an unchanged J draws along a bent row).
 * The rotation written beside J is J's polar rotation (SH follow it), or R where J is
 * singular. No neighbours (or all at the centre): J = R = identity.
 *
 * The weights, A's eigenpairs and the ramps depend on the rest positions alone: sc_fit_rest
 * computes them (the rest half, deform.h's SC_FIT_* layout), sc_fit_batch the rest from a
 * frame's deformed positions, SC_SHAPE_LANES rows at a time (their polar rotations side by
 * side in vector lanes); sc_deform_rest keeps the halves of every point, once per rest shape,
 * for the frames' one pass (deform_frame.c), which then skips the weights' exp and the
 * eigen-decomposition (about a quarter of its time). A neighbourhood spanning 3D needs no R
 * unless J comes out singular; it is only computed then. The numbers are those of computing
 * everything per frame, bit for bit, whatever the batches. */
#include "deform.h"
#include "mat3.h"

enum { GRAIN = 4096 };

typedef struct {
    sc_fit_input in;
    double *jacobians, *rotations;
} job;

/* A spread ratio at rounding level (an exactly flat neighbourhood) says nothing: 0 whatever
 * `lo` is. */
static const double FLAT = 1e-12;

/* The spread's eigen-decomposition in closed form where its eigenvalues are this far apart and
 * from 0 (relative to the largest), by Jacobi elsewhere (a row, a sheet, a lattice's nearly
 * round neighbourhood): f_m divides by l_m, so each l_m and e_m must hold to rounding relative
 * to l_m itself, which the closed form gives only for well-separated eigenvalues (its vectors
 * move by about 1e-16 / separation^2: 1e-10 here). */
static const double SEPARATED = 1e-3;

static double ramp(double ratio, double lo, double hi) {
    return ratio <= lo || ratio <= FLAT ? 0.0 : ratio >= hi ? 1.0 : (ratio - lo) / (hi - lo);
}

static void unit(double v[3]) {
    const double n = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    for (int a = 0; a < 3; ++a) v[a] /= n;
}

void sc_fit_rest(const sc_fit_input *j, int64_t i, double *half) {
    const float *p = j->rest + 3 * i;
    const int32_t *nb = j->neighbours + (int64_t)j->k * i;
    memset(half, 0, sizeof(double) * (size_t)(SC_FIT_W + j->k));
    double reach2 = 0.0;
    for (int m = 0; m < j->k; ++m) {
        if (nb[m] < 0) continue;
        const float *q = j->rest + 3 * (int64_t)nb[m];
        double d2 = 0.0;
        for (int a = 0; a < 3; ++a) d2 += ((double)q[a] - p[a]) * ((double)q[a] - p[a]);
        reach2 = d2 > reach2 ? d2 : reach2;
    }
    if (!(reach2 > 0.0)) return; /* l_1 = 0: J = R = I */
    double A[9] = {0};
    for (int m = 0; m < j->k; ++m) {
        if (nb[m] < 0) continue;
        const float *q = j->rest + 3 * (int64_t)nb[m];
        double a[3], d2 = 0.0;
        for (int c = 0; c < 3; ++c) {
            a[c] = (double)q[c] - p[c];
            d2 += a[c] * a[c];
        }
        const double w = exp(-d2 / reach2);
        half[SC_FIT_W + m] = w;
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) A[3 * r + c] += w * a[r] * a[c];
    }
    double values[3], vectors[9];
    sc_sym3_eigen(A, values, vectors, SEPARATED, SEPARATED);
    double *l = half + SC_FIT_L;
    l[0] = values[2], l[1] = values[1], l[2] = values[0];
    for (int a = 0; a < 3; ++a)
        half[SC_FIT_E1 + a] = vectors[3 * a + 2], half[SC_FIT_E2 + a] = vectors[3 * a + 1];
    for (int m = 1; m < 3; ++m)
        half[SC_FIT_C + m - 1] = ramp(l[m] / l[0], j->undetermined, j->determined);
}

/* R: the rotation the data determines best (the file's comment), from f_1 and f_2. */
static void fit_rotation(const double e[3][3], const double c[3], double f[3][3], double R[9]) {
    sc_m3_identity(R);
    const double f1 = sqrt(f[0][0] * f[0][0] + f[0][1] * f[0][1] + f[0][2] * f[0][2]);
    if (!(f1 > 0.0)) return;
    double d[3][3] = {{f[0][0] / f1, f[0][1] / f1, f[0][2] / f1}};
    sc_rotation_between(e[0], d[0], R);
    if (!(c[1] > 0.0)) return;
    double turned[3], u[3];
    for (int r = 0; r < 3; ++r) turned[r] = R[3 * r] * e[1][0] + R[3 * r + 1] * e[1][1] + R[3 * r + 2] * e[1][2];
    const double f2 = sqrt(f[1][0] * f[1][0] + f[1][1] * f[1][1] + f[1][2] * f[1][2]);
    for (int r = 0; r < 3; ++r) u[r] = (f2 > 0.0 ? c[1] * f[1][r] / f2 : 0.0) + (1.0 - c[1]) * turned[r];
    double along = u[0] * d[0][0] + u[1] * d[0][1] + u[2] * d[0][2];
    for (int r = 0; r < 3; ++r) u[r] -= along * d[0][r];
    if (!(u[0] * u[0] + u[1] * u[1] + u[2] * u[2] > 1e-24)) { /* f_2 along f_1: fold */
        along = turned[0] * d[0][0] + turned[1] * d[0][1] + turned[2] * d[0][2];
        for (int r = 0; r < 3; ++r) u[r] = turned[r] - along * d[0][r];
    }
    unit(u);
    memcpy(d[1], u, sizeof u);
    sc_cross(d[0], d[1], d[2]);
    for (int r = 0; r < 3; ++r)
        for (int s = 0; s < 3; ++s)
            R[3 * r + s] = d[0][r] * e[0][s] + d[1][r] * e[1][s] + d[2][r] * e[2][s];
}

/* What a row's J is made of: e_m, c_m, f_m (the file's comment). */
typedef struct {
    double e[3][3], c[3], f[3][3];
    int fitted; /* every c_m = 1: J = sum f_m e_m^T, R not needed for it */
} fit_parts;

/* Row i's parts from its rest half and the deformed positions; 0 for a row without neighbours
 * (J = R = I). */
static int parts_of(const sc_fit_input *j, int64_t i, const double *half, fit_parts *fp) {
    const double *l = half + SC_FIT_L;
    if (!(l[0] > 0.0)) return 0;
    const float *p = j->rest + 3 * i, *x = j->deformed + 3 * i;
    const int32_t *nb = j->neighbours + (int64_t)j->k * i;
    double B[9] = {0};
    for (int m = 0; m < j->k; ++m) {
        if (nb[m] < 0) continue;
        const float *q = j->rest + 3 * (int64_t)nb[m], *y = j->deformed + 3 * (int64_t)nb[m];
        double a[3], b[3];
        for (int c = 0; c < 3; ++c) a[c] = (double)q[c] - p[c], b[c] = (double)y[c] - x[c];
        const double w = half[SC_FIT_W + m];
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) B[3 * r + c] += w * b[r] * a[c];
    }
    memcpy(fp->e[0], half + SC_FIT_E1, sizeof fp->e[0]);
    memcpy(fp->e[1], half + SC_FIT_E2, sizeof fp->e[1]);
    sc_cross(fp->e[0], fp->e[1], fp->e[2]);
    fp->c[0] = 1.0, fp->c[1] = half[SC_FIT_C], fp->c[2] = half[SC_FIT_C + 1];
    memset(fp->f, 0, sizeof fp->f);
    for (int m = 0; m < 3; ++m) {
        if (fp->c[m] <= 0.0) continue;
        const double *e = fp->e[m];
        for (int r = 0; r < 3; ++r)
            fp->f[m][r] = (B[3 * r] * e[0] + B[3 * r + 1] * e[1] + B[3 * r + 2] * e[2]) / l[m];
    }
    fp->fitted = fp->c[1] >= 1.0 && fp->c[2] >= 1.0;
    return 1;
}

/* J = sum_m (c_m f_m + (1 - c_m) R e_m) e_m^T (R unused, may be NULL, when fitted). */
static void jacobian_of(const fit_parts *fp, const double *R, double jac[9]) {
    for (int r = 0; r < 3; ++r)
        for (int s = 0; s < 3; ++s) {
            double v = 0.0;
            for (int m = 0; m < 3; ++m) {
                const double *e = fp->e[m];
                const double re = fp->fitted ? 0.0 : R[3 * r] * e[0] + R[3 * r + 1] * e[1] + R[3 * r + 2] * e[2];
                v += (fp->c[m] * fp->f[m][r] + (1.0 - fp->c[m]) * re) * e[s];
            }
            jac[3 * r + s] = v;
        }
}

/* ---------------------------------------------------------------- polar rotations in lanes
 * The orthogonal factor Q of the polar decomposition J = Q P (det Q = sign det J) by Higham's
 * scaled Newton iteration Q <- (g Q + Q^-T / g) / 2, for SC_SHAPE_LANES matrices side by side
 * (one matrix's iteration is a chain of divisions and square roots, each waiting for the one
 * before; eight side by side cost about as much). Q^-T = C / det, C the cofactors,
 * and g = (|C| / (|det| |Q|))^(1/2) (Frobenius norms: the optimal scaling's estimate). None
 * (J's R instead) where J is singular to 1e-12 of its size, where Q is not unique, or the
 * iteration is not finite. Each lane stops (keeps its Q) when its own step is under 1e-8, or
 * fails, whatever the others do, so its result does not depend on its batch. */

enum { LANES = SC_SHAPE_LANES, POLAR_STEPS = 60 };

typedef struct {
    double x[9][LANES];
    int64_t state[LANES]; /* 1 iterating, 0 done, -1 singular or non-finite (no rotation) */
} polar_lanes;

static SC_ALWAYS_INLINE void polar_start(polar_lanes *restrict P) {
    for (int l = 0; l < LANES; ++l) {
        double x[9];
        for (int e = 0; e < 9; ++e) x[e] = P->x[e][l];
        double size2 = 0.0;
        for (int e = 0; e < 9; ++e) size2 += x[e] * x[e];
        const double size = sqrt(size2);
        const double det = x[0] * (x[4] * x[8] - x[5] * x[7]) - x[1] * (x[3] * x[8] - x[5] * x[6]) +
                           x[2] * (x[3] * x[7] - x[4] * x[6]);
        P->state[l] = size > 0.0 && fabs(det) > 1e-12 * size * size * size ? 1 : -1;
    }
}

/* One step for every lane still iterating; returns how many still are. */
static SC_ALWAYS_INLINE int polar_step(polar_lanes *restrict P) {
    double iterating = 0.0;
    for (int l = 0; l < LANES; ++l) {
        double x[9];
        for (int e = 0; e < 9; ++e) x[e] = P->x[e][l];
        const double c[9] = {x[4] * x[8] - x[5] * x[7], x[5] * x[6] - x[3] * x[8], x[3] * x[7] - x[4] * x[6],
                             x[2] * x[7] - x[1] * x[8], x[0] * x[8] - x[2] * x[6], x[1] * x[6] - x[0] * x[7],
                             x[1] * x[5] - x[2] * x[4], x[2] * x[3] - x[0] * x[5], x[0] * x[4] - x[1] * x[3]};
        const double det = x[0] * c[0] + x[1] * c[1] + x[2] * c[2];
        double cc = 0.0, xx = 0.0;
        for (int e = 0; e < 9; ++e) cc += c[e] * c[e], xx += x[e] * x[e];
        const double g = sqrt(sqrt(cc / xx) / fabs(det));
        const double by_x = 0.5 * g, by_c = 0.5 / (g * det);
        double change = 0.0, next[9];
        for (int e = 0; e < 9; ++e) {
            next[e] = by_x * x[e] + by_c * c[e];
            change += (next[e] - x[e]) * (next[e] - x[e]);
        }
        const int active = P->state[l] == 1, finite = change - change == 0.0;
        for (int e = 0; e < 9; ++e) P->x[e][l] = active && finite ? next[e] : x[e];
        /* Quadratic convergence: a step of size c leaves x about c^2 / 2 from Q, so after a
         * step under 1e-8 (squared: 1e-16) x is Q to rounding. */
        P->state[l] = !active ? P->state[l] : !finite ? -1 : change <= 1e-16 ? 0 : 1;
        iterating += P->state[l] == 1 ? 1.0 : 0.0;
    }
    return (int)iterating;
}

static SC_ALWAYS_INLINE void polar_body(polar_lanes *restrict P) {
    polar_start(P);
    for (int step = 0; step < POLAR_STEPS && polar_step(P) > 0; ++step) {
    }
}

SC_MULTIVERSION(void, polar_lanes_run, (polar_lanes * P), (P), polar_body(P))

void sc_fit_batch(const sc_fit_input *j, int64_t row, int count, const double *halves,
                  double jac[][9], double rot[][9]) {
    const int64_t stride = SC_FIT_FIELDS + j->k;
    fit_parts parts[LANES];
    int kind[LANES]; /* 0 no neighbours, 1 fitted, 2 with R */
    double R[LANES][9];
    polar_lanes P;
    for (int l = 0; l < LANES; ++l) {
        if (l < count) {
            kind[l] = parts_of(j, row + l, halves + stride * l, &parts[l]);
            if (kind[l] == 0) {
                sc_m3_identity(jac[l]);
            } else {
                kind[l] += !parts[l].fitted;
                if (kind[l] == 2) fit_rotation(parts[l].e, parts[l].c, parts[l].f, R[l]);
                jacobian_of(&parts[l], kind[l] == 2 ? R[l] : NULL, jac[l]);
            }
        }
        const int from = l < count ? l : count - 1; /* a short batch repeats its last row */
        for (int e = 0; e < 9; ++e) P.x[e][l] = jac[from][e];
    }
    polar_lanes_run(&P);
    for (int l = 0; l < count; ++l) {
        if (kind[l] == 0) {
            sc_m3_identity(rot[l]);
        } else if (P.state[l] >= 0) {
            for (int e = 0; e < 9; ++e) rot[l][e] = P.x[e][l];
        } else { /* J singular: R */
            if (kind[l] == 1) fit_rotation(parts[l].e, parts[l].c, parts[l].f, R[l]);
            memcpy(rot[l], R[l], sizeof R[l]);
        }
    }
}

typedef struct {
    sc_fit_input in;
    double *fit;
} rest_job;

static void rest_rows(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const rest_job *j = ctx;
    const int64_t stride = SC_FIT_FIELDS + j->in.k;
    for (int64_t i = begin; i < end; ++i) sc_fit_rest(&j->in, i, j->fit + stride * i);
}

void sc_deform_rest(const float *rest, int64_t n, const int32_t *neighbours, int k,
                    double undetermined, double determined, double *fit, int threads) {
    rest_job j = {.in = {.rest = rest, .neighbours = neighbours, .k = k,
                         .undetermined = undetermined, .determined = determined},
                  .fit = fit};
    sc_parallel_for(threads < 1 ? 1 : threads, n, GRAIN, rest_rows, &j);
}

static void fit_rows(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const job *j = ctx;
    const int64_t stride = SC_FIT_FIELDS + j->in.k;
    double halves[LANES * (SC_FIT_FIELDS + SC_MAX_NEIGHBOURS)];
    for (int64_t start = begin; start < end; start += LANES) {
        const int count = end - start < LANES ? (int)(end - start) : LANES;
        for (int l = 0; l < count; ++l) sc_fit_rest(&j->in, start + l, halves + stride * l);
        sc_fit_batch(&j->in, start, count, halves, (double(*)[9])(j->jacobians + 9 * start),
                     (double(*)[9])(j->rotations + 9 * start));
    }
}

void sc_deformation_jacobians(const float *rest, const float *deformed, int64_t n,
                              const int32_t *neighbours, int k, double undetermined,
                              double determined, double *jacobians, double *rotations,
                              int threads) {
    job j = {.in = {.rest = rest, .deformed = deformed, .neighbours = neighbours, .k = k,
                    .undetermined = undetermined, .determined = determined},
             .jacobians = jacobians, .rotations = rotations};
    sc_parallel_for(threads < 1 ? 1 : threads, n, GRAIN, fit_rows, &j);
}
