/* Gaussians' shapes and view-dependent colour through per-Gaussian linear maps
 * (sc_deform_shapes, splatcore.h): covariance J Sigma J^T re-decomposed, SH bands 1-3 rotated
 * by the orthogonal Q beside J. What addon/core/transform.py does for one matrix (a
 * non-uniform object scale: `_reshape_covariances`; `rotate_sh`), here for a matrix per
 * Gaussian, at memory speed, in double:
 *
 *   - covariance: L = J R diag(exp(s)), C = L L^T; eigenvalues (ascending) floored at 1e-24 of
 *     the largest and 1e-36; eigenvectors made right-handed (the first one flipped) become the
 *     quaternion (w >= 0), half the logs of the eigenvalues the log-scales.
 *   - SH: the colour shown along Q d must be the one shown along d: for each band l,
 *     c'_l = P_l Y_l(Q^T d_k) c_l over nine fixed well-spread directions d_k, P_l the
 *     least-squares inverse of the band's basis at them (exact: each band is invariant under
 *     O(3), as transform.py's sh_rotation_matrices solves it). Band 0 is copied bit for bit.
 * Opacity is not touched (as transform.py). */
#include "deform.h"
#include "mat3.h"
#include "sh_basis.h"

enum { GRAIN = 2048, DIRECTIONS = SC_SH_DIRECTIONS };

/* The covariance's eigen-decomposition in closed form unless its smallest variance is below
 * this of the largest (a Gaussian flatter than 1:30000): there the closed form's rounding,
 * 1e-16 of the largest, would reach 1e-7 of the smallest, and Jacobi keeps it relative.
 * Close eigenvalues need no fallback here: only the covariance they make back is kept. */
static const double GRADED = 1e-9;

typedef struct {
    sc_shapes shapes;
    const double *jacobians, *rotations;
} job;

/* Nine directions of a Fibonacci sphere, and P_l = (Y_l^T Y_l)^-1 Y_l^T per band. */
void sc_shapes_prepare(sc_shapes *j) {
    double basis[DIRECTIONS][16];
    for (int k = 0; k < DIRECTIONS; ++k) {
        const double z = 1.0 - 2.0 * (k + 0.5) / DIRECTIONS, r = sqrt(1.0 - z * z);
        const double phi = 3.14159265358979323846 * (1.0 + sqrt(5.0)) * (k + 0.5);
        j->fixed[k][0] = r * cos(phi), j->fixed[k][1] = r * sin(phi), j->fixed[k][2] = z;
        double gx[16] = {0}, gy[16] = {0}, gz[16] = {0};
        sc_sh_basis_grad(3, j->fixed[k][0], j->fixed[k][1], j->fixed[k][2], basis[k], gx, gy, gz);
    }
    static const int BAND[4] = {1, 4, 9, 16};
    for (int band = 0; band < 3; ++band) {
        const int lo = BAND[band], width = BAND[band + 1] - lo;
        double m[7][7 + DIRECTIONS]; /* [Y^T Y | Y^T], Gauss-Jordan with partial pivots */
        for (int a = 0; a < width; ++a) {
            for (int b = 0; b < width; ++b) {
                double s = 0.0;
                for (int k = 0; k < DIRECTIONS; ++k) s += basis[k][lo + a] * basis[k][lo + b];
                m[a][b] = s;
            }
            for (int k = 0; k < DIRECTIONS; ++k) m[a][width + k] = basis[k][lo + a];
        }
        for (int col = 0; col < width; ++col) {
            int pivot = col;
            for (int r = col + 1; r < width; ++r)
                if (fabs(m[r][col]) > fabs(m[pivot][col])) pivot = r;
            for (int c = 0; c < width + DIRECTIONS; ++c) {
                const double t = m[col][c];
                m[col][c] = m[pivot][c], m[pivot][c] = t;
            }
            const double inv = 1.0 / m[col][col];
            for (int c = 0; c < width + DIRECTIONS; ++c) m[col][c] *= inv;
            for (int r = 0; r < width; ++r) {
                if (r == col || m[r][col] == 0.0) continue;
                const double factor = m[r][col];
                for (int c = 0; c < width + DIRECTIONS; ++c) m[r][c] -= factor * m[col][c];
            }
        }
        for (int a = 0; a < width; ++a)
            for (int k = 0; k < DIRECTIONS; ++k) j->project[lo + a][k] = m[a][width + k];
    }
}

static void shape_one(const sc_shapes *j, int64_t i, const double J[9]) {
    double unit_q[4], r[9], s[3];
    sc_quat_rotation(j->quats + 4 * i, unit_q, r);
    for (int a = 0; a < 3; ++a) s[a] = exp((double)j->log_scales[3 * i + a]);
    double L[9], C[9];
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b)
            L[3 * a + b] = (J[3 * a] * r[b] + J[3 * a + 1] * r[3 + b] + J[3 * a + 2] * r[6 + b]) * s[b];
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b)
            C[3 * a + b] = L[3 * a] * L[3 * b] + L[3 * a + 1] * L[3 * b + 1] + L[3 * a + 2] * L[3 * b + 2];
    double values[3], vectors[9], q[4];
    sc_sym3_eigen(C, values, vectors, GRADED, 0.0);
    const double floor = fmax(values[2] * 1e-24, 1e-36);
    if (sc_m3_det(vectors) < 0.0)
        for (int a = 0; a < 3; ++a) vectors[3 * a] = -vectors[3 * a];
    sc_rotation_quat(vectors, q);
    for (int a = 0; a < 4; ++a) j->out_quats[4 * i + a] = (float)q[a];
    for (int a = 0; a < 3; ++a) j->out_log_scales[3 * i + a] = (float)(0.5 * log(fmax(values[a], floor)));
}

static void colour_one(const sc_shapes *j, int64_t i, const double Q[9]) {
    const int coeffs = j->coeffs;
    const float *sh = j->sh + (int64_t)3 * coeffs * i;
    float *out = j->out_sh + (int64_t)3 * coeffs * i;
    out[0] = sh[0], out[1] = sh[1], out[2] = sh[2];
    if (coeffs == 1) return;
    const int degree = coeffs == 4 ? 1 : coeffs == 9 ? 2 : 3;
    static const int BAND[4] = {1, 4, 9, 16};
    double values[DIRECTIONS][3][3] = {{{0}}}; /* [direction][band][channel] */
    for (int k = 0; k < DIRECTIONS; ++k) {
        const double *d = j->fixed[k];
        const double x = Q[0] * d[0] + Q[3] * d[1] + Q[6] * d[2], y = Q[1] * d[0] + Q[4] * d[1] + Q[7] * d[2],
                     z = Q[2] * d[0] + Q[5] * d[1] + Q[8] * d[2]; /* Q^T d */
        double basis[16], gx[16] = {0}, gy[16] = {0}, gz[16] = {0};
        sc_sh_basis_grad(degree, x, y, z, basis, gx, gy, gz);
        for (int band = 0; band < degree; ++band)
            for (int t = BAND[band]; t < BAND[band + 1]; ++t)
                for (int ch = 0; ch < 3; ++ch) values[k][band][ch] += basis[t] * sh[3 * t + ch];
    }
    for (int band = 0; band < degree; ++band)
        for (int t = BAND[band]; t < BAND[band + 1]; ++t)
            for (int ch = 0; ch < 3; ++ch) {
                double v = 0.0;
                for (int k = 0; k < DIRECTIONS; ++k) v += j->project[t][k] * values[k][band][ch];
                out[3 * t + ch] = (float)v;
            }
}

void sc_shapes_point(const sc_shapes *s, int64_t i, const double J[9], const double Q[9]) {
    shape_one(s, i, J);
    colour_one(s, i, Q);
}

static void deform_rows(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const job *j = ctx;
    for (int64_t i = begin; i < end; ++i)
        sc_shapes_point(&j->shapes, i, j->jacobians + 9 * i, j->rotations + 9 * i);
}

void sc_deform_shapes(const float *log_scales, const float *quats, const float *sh, int64_t n,
                      int sh_coeffs, const double *jacobians, const double *rotations,
                      float *out_log_scales, float *out_quats, float *out_sh, int threads) {
    job j = {.shapes = {.log_scales = log_scales, .quats = quats, .sh = sh, .coeffs = sh_coeffs,
                        .out_log_scales = out_log_scales, .out_quats = out_quats,
                        .out_sh = out_sh},
             .jacobians = jacobians, .rotations = rotations};
    sc_shapes_prepare(&j.shapes);
    sc_parallel_for(threads < 1 ? 1 : threads, n, GRAIN, deform_rows, &j);
}
