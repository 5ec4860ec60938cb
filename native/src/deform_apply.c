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
 * Opacity is not touched (as transform.py).
 *
 * Gaussians go through in batches of SC_SHAPE_LANES side by side (sc_shapes_batch, below):
 * one Gaussian's chain (three exp, an acos and two cosines, three logs, square roots and
 * divisions, each waiting for the one before) costs about as much as eight in vector
 * registers. shape_one is the scalar covariance, for the lanes the closed form does not suit. */
#include <float.h>

#include "deform.h"
#include "lane_math.h"
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

/* ---------------------------------------------------------------- one Gaussian at a time */

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

/* ---------------------------------------------------------------- SC_SHAPE_LANES at a time */

enum { LANES = SC_SHAPE_LANES };

typedef struct {
    double J[9][LANES], Q[9][LANES];
    double ls[3][LANES], quat[4][LANES];
    double sh[48][LANES]; /* (K, 3) order */
    /* the covariance scaled to its largest entry (00, 01, 02, 11, 12, 22), that entry, and the
     * closed form's mean eigenvalue q, spread p and cos(3 angle) (sc_sym3_eigen's names) */
    double a[6][LANES], scale[LANES], q[LANES], p[LANES], half[LANES];
    float out_ls[3][LANES], out_quat[4][LANES], out_sh[48][LANES];
    int64_t scalar[LANES]; /* 1: the lane's shape is left to shape_one */
} lanes;

/* Coefficients of asin(x) = x + x z Q(z), z = x^2, |x| <= 1/2: a degree-11 polynomial Q
 * fitted (Chebyshev, mpmath) to asin(x) / x^3 - 1 / x^2 on that range, 1.2 ulp at worst. */
static const double ASIN_Q[12] = {
    0.03187962140081284,  -0.016187392271599134, 0.019513468251252167, 0.0065293020047365695,
    0.012170138592391726, 0.01388484282640208,   0.01735977964134998,  0.022371749733164054,
    0.03038195969768514,  0.044642856805998936,  0.07500000000385201,  0.16666666666664942};

/* acos(h), h in [-1, 1]: pi/2 - asin(h) for |h| <= 1/2, else through asin(sqrt((1 - |h|)/2)). */
static SC_ALWAYS_INLINE double acos_lane(double h) {
    const double magnitude = fabs(h);
    const int far = magnitude > 0.5;
    const double x = far ? sqrt(0.5 * (1.0 - magnitude)) : magnitude, z = x * x;
    double poly = ASIN_Q[0];
    for (int c = 1; c < 12; ++c) poly = poly * z + ASIN_Q[c];
    const double asin_x = x + x * (z * poly);
    const double near_value = 1.5707963267948966 - (h < 0.0 ? -asin_x : asin_x);
    const double far_value = h > 0.0 ? 2.0 * asin_x : 3.141592653589793 - 2.0 * asin_x;
    return far ? far_value : near_value;
}

/* cos t and sin t for t in [0, pi/3] by their Taylor series to t^20 and t^21 (below 1e-17). */
static SC_ALWAYS_INLINE void sincos_lane(double t, double *c_out, double *s_out) {
    const double z = t * t;
    double c = 1.0 / 2432902008176640000.0, s = 1.0 / 51090942171709440000.0;
    static const double COS[10] = {-1.0 / 6402373705728000.0, 1.0 / 20922789888000.0,
                                   -1.0 / 87178291200.0,      1.0 / 479001600.0,
                                   -1.0 / 3628800.0,          1.0 / 40320.0,
                                   -1.0 / 720.0,              1.0 / 24.0,
                                   -0.5,                      1.0};
    static const double SIN[10] = {-1.0 / 121645100408832000.0, 1.0 / 355687428096000.0,
                                   -1.0 / 1307674368000.0,      1.0 / 6227020800.0,
                                   -1.0 / 39916800.0,           1.0 / 362880.0,
                                   -1.0 / 5040.0,               1.0 / 120.0,
                                   -1.0 / 6.0,                  1.0};
    for (int k = 0; k < 10; ++k) c = c * z + COS[k], s = s * z + SIN[k];
    *c_out = c, *s_out = s * t;
}

static SC_ALWAYS_INLINE void cross_lane(const double a[3], const double b[3], double out[3]) {
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

/* sc_sym3_vector with selects: the longest cross product of two rows of a - value I. */
static SC_ALWAYS_INLINE void vector_lane(const double a[6], double value, double out[3]) {
    const double r0[3] = {a[0] - value, a[1], a[2]}, r1[3] = {a[1], a[3] - value, a[4]},
                 r2[3] = {a[2], a[4], a[5] - value};
    double c0[3], c1[3], c2[3];
    cross_lane(r0, r1, c0);
    cross_lane(r0, r2, c1);
    cross_lane(r1, r2, c2);
    const double d0 = c0[0] * c0[0] + c0[1] * c0[1] + c0[2] * c0[2];
    const double d1 = c1[0] * c1[0] + c1[1] * c1[1] + c1[2] * c1[2];
    const double d2 = c2[0] * c2[0] + c2[1] * c2[1] + c2[2] * c2[2];
    const int one = d1 > d0;
    const double d01 = one ? d1 : d0;
    const int two = d2 > d01;
    const double longest = two ? d2 : d01;
    const double inv = 1.0 / sqrt(longest);
    for (int i = 0; i < 3; ++i) out[i] = (two ? c2[i] : one ? c1[i] : c0[i]) * inv;
}

/* sc_sym3_vector_in_plane with selects: the unit eigenvector for `value` orthogonal to w. */
static SC_ALWAYS_INLINE void vector_in_plane_lane(const double a[6], const double w[3],
                                                  double value, double out[3]) {
    const int x_first = fabs(w[0]) > fabs(w[1]);
    const double inv = 1.0 / sqrt(x_first ? w[0] * w[0] + w[2] * w[2] : w[1] * w[1] + w[2] * w[2]);
    const double u[3] = {x_first ? -w[2] * inv : 0.0, x_first ? 0.0 : w[2] * inv,
                         x_first ? w[0] * inv : -w[1] * inv};
    double v[3];
    cross_lane(w, u, v);
    const double au[3] = {a[0] * u[0] + a[1] * u[1] + a[2] * u[2],
                          a[1] * u[0] + a[3] * u[1] + a[4] * u[2],
                          a[2] * u[0] + a[4] * u[1] + a[5] * u[2]};
    const double av[3] = {a[0] * v[0] + a[1] * v[1] + a[2] * v[2],
                          a[1] * v[0] + a[3] * v[1] + a[4] * v[2],
                          a[2] * v[0] + a[4] * v[1] + a[5] * v[2]};
    const double m00 = u[0] * au[0] + u[1] * au[1] + u[2] * au[2] - value;
    const double m01 = u[0] * av[0] + u[1] * av[1] + u[2] * av[2];
    const double m11 = v[0] * av[0] + v[1] * av[1] + v[2] * av[2] - value;
    const double a00 = fabs(m00), a01 = fabs(m01), a11 = fabs(m11);
    /* first: the row (m00, m01) is the larger; second: (m11, m01); neither: any will do (u) */
    const int first = a00 >= a11 && sc_fmax_lane(a00, a01) > 0.0;
    const int second = a11 > a00 && sc_fmax_lane(a11, a01) > 0.0;
    const double diagonal = first ? m00 : m11;
    const int by_diagonal = fabs(diagonal) >= a01;
    const double num = by_diagonal ? m01 : diagonal;
    const double den = first || second ? (by_diagonal ? diagonal : m01) : 1.0;
    const double t = num / den, r = 1.0 / sqrt(1.0 + t * t);
    const double along_diagonal = by_diagonal ? r : t * r, along_off = by_diagonal ? t * r : r;
    const double cu = first ? along_off : second ? along_diagonal : 1.0;
    const double cv = first ? -along_diagonal : second ? -along_off : 0.0;
    for (int i = 0; i < 3; ++i) out[i] = cu * u[i] + cv * v[i];
}

/* The covariance L L^T (L = J R(q) diag(exp(ls))) scaled to its largest entry, and the closed
 * form's q, p and cos(3 angle), as sc_sym3_eigen; `scalar` where sc_sym3_eigen would use Jacobi
 * for want of off-diagonal entries, or an input exp_lane does not take. */
static SC_ALWAYS_INLINE void covariance_lanes(lanes *restrict L) {
    for (int l = 0; l < LANES; ++l) {
        double w = L->quat[0][l], x = L->quat[1][l], y = L->quat[2][l], z = L->quat[3][l];
        const double n2 = w * w + x * x + y * y + z * z;
        const int has_q = n2 > 0.0;
        const double inv = 1.0 / sqrt(has_q ? n2 : 1.0);
        w = has_q ? w * inv : 1.0, x = has_q ? x * inv : 0.0;
        y = has_q ? y * inv : 0.0, z = has_q ? z * inv : 0.0;
        const double r[9] = {1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                             2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                             2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)};
        const double ls0 = L->ls[0][l], ls1 = L->ls[1][l], ls2 = L->ls[2][l];
        const int in_range = sc_fmax_lane(sc_fmax_lane(fabs(ls0), fabs(ls1)), fabs(ls2)) <= 700.0;
        const double s[3] = {sc_exp_lane(in_range ? ls0 : 0.0), sc_exp_lane(in_range ? ls1 : 0.0),
                             sc_exp_lane(in_range ? ls2 : 0.0)};
        double m[9];
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b)
                m[3 * a + b] = (L->J[3 * a][l] * r[b] + L->J[3 * a + 1][l] * r[3 + b] +
                                L->J[3 * a + 2][l] * r[6 + b]) * s[b];
        static const int ROW[6] = {0, 0, 0, 1, 1, 2}, COL[6] = {0, 1, 2, 1, 2, 2};
        double c[6], scale = 0.0;
        for (int e = 0; e < 6; ++e) {
            const int a = ROW[e], b = COL[e];
            c[e] = m[3 * a] * m[3 * b] + m[3 * a + 1] * m[3 * b + 1] + m[3 * a + 2] * m[3 * b + 2];
            scale = sc_fmax_lane(scale, fabs(c[e]));
        }
        const double off = c[1] * c[1] + c[2] * c[2] + c[4] * c[4];
        const int usable = in_range && scale > 0.0 && scale <= DBL_MAX && off > 0.0;
        const double safe = usable ? scale : 1.0;
        double a[6];
        for (int e = 0; e < 6; ++e) a[e] = c[e] / safe;
        const double norm = off / (safe * safe);
        const double q = (a[0] + a[3] + a[5]) / 3.0;
        const double b00 = a[0] - q, b11 = a[3] - q, b22 = a[5] - q;
        const double p = sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * norm) / 6.0);
        const double c00 = b11 * b22 - a[4] * a[4], c01 = a[1] * b22 - a[4] * a[2],
                     c02 = a[1] * a[4] - b11 * a[2];
        const double half = 0.5 * ((b00 * c00 - a[1] * c01 + a[2] * c02) / (p * p * p));
        for (int e = 0; e < 6; ++e) L->a[e][l] = a[e];
        L->scale[l] = safe, L->q[l] = q, L->p[l] = usable ? p : 1.0;
        L->half[l] = usable ? (half < -1.0 ? -1.0 : half > 1.0 ? 1.0 : half) : 0.0;
        L->scalar[l] = !usable;
    }
}

/* The eigenvalues and vectors from q, p and cos(3 angle) (sc_sym3_eigen's closed form), then
 * the log-scales and quaternion (shape_one's). */
static SC_ALWAYS_INLINE void decompose_lanes(lanes *restrict L) {
    for (int l = 0; l < LANES; ++l) {
        const double half = L->half[l], q = L->q[l], p = L->p[l], scale = L->scale[l];
        double a[6];
        for (int e = 0; e < 6; ++e) a[e] = L->a[e][l];
        double cos_t, sin_t;
        sincos_lane(acos_lane(half) / 3.0, &cos_t, &sin_t);
        const double beta2 = 2.0 * cos_t, beta0 = -cos_t - 1.7320508075688772 * sin_t;
        const double beta1 = -(beta0 + beta2);
        const double value[3] = {q + p * beta0, q + p * beta1, q + p * beta2};
        const double top = sc_fmax_lane(fabs(value[0]), fabs(value[2]));
        const int graded = fabs(value[0]) > GRADED * top && value[1] - value[0] > 0.0 &&
                           value[2] - value[1] > 0.0;
        /* the most separated eigenvalue's vector first: the largest's when half >= 0 */
        const int largest_first = half >= 0.0;
        double w[3], middle[3], other[3];
        vector_lane(a, largest_first ? value[2] : value[0], w);
        vector_in_plane_lane(a, w, value[1], middle);
        double m_x_w[3], w_x_m[3];
        cross_lane(middle, w, m_x_w);
        cross_lane(w, middle, w_x_m);
        for (int i = 0; i < 3; ++i) other[i] = largest_first ? m_x_w[i] : w_x_m[i];
        double v[3][3]; /* v[i]: the eigenvector of value[i] */
        for (int i = 0; i < 3; ++i) {
            v[0][i] = largest_first ? other[i] : w[i];
            v[1][i] = middle[i];
            v[2][i] = largest_first ? w[i] : other[i];
        }
        double check = 0.0; /* NaN if a cross product underflowed to 0 (sc_sym3_eigen) */
        for (int i = 0; i < 3; ++i) check += v[i][0] + v[i][1] + v[i][2];
        L->scalar[l] |= !graded || !(check - check == 0.0);
        const double values[3] = {value[0] * scale, value[1] * scale, value[2] * scale};
        const double floor = sc_fmax_lane(values[2] * 1e-24, 1e-36);
        double m[9]; /* the vectors as columns, made right-handed */
        const double det = v[0][0] * (v[1][1] * v[2][2] - v[1][2] * v[2][1]) -
                           v[1][0] * (v[0][1] * v[2][2] - v[0][2] * v[2][1]) +
                           v[2][0] * (v[0][1] * v[1][2] - v[0][2] * v[1][1]);
        const double flip = det < 0.0 ? -1.0 : 1.0;
        for (int k = 0; k < 3; ++k) m[3 * k] = flip * v[0][k], m[3 * k + 1] = v[1][k], m[3 * k + 2] = v[2][k];
        /* sc_rotation_quat: Shepperd's four cases as selects */
        const double trace = m[0] + m[4] + m[8];
        const int by_w = trace >= m[0] && trace >= m[4] && trace >= m[8];
        const int by_x = !by_w && m[0] >= m[4] && m[0] >= m[8];
        const int by_y = !by_w && !by_x && m[4] >= m[8];
        const double pivot = by_w ? 1.0 + trace : by_x ? 1.0 + m[0] - m[4] - m[8]
                             : by_y ? 1.0 - m[0] + m[4] - m[8] : 1.0 - m[0] - m[4] + m[8];
        const double s = 2.0 * sqrt(sc_fmax_lane(pivot, 0.0)), quarter = 0.25 * s;
        const double wx = (m[7] - m[5]) / s, wy = (m[2] - m[6]) / s, wz = (m[3] - m[1]) / s;
        const double xy = (m[1] + m[3]) / s, xz = (m[2] + m[6]) / s, yz = (m[5] + m[7]) / s;
        double quat[4];
        quat[0] = by_w ? quarter : by_x ? wx : by_y ? wy : wz;
        quat[1] = by_w ? wx : by_x ? quarter : by_y ? xy : xz;
        quat[2] = by_w ? wy : by_x ? xy : by_y ? quarter : yz;
        quat[3] = by_w ? wz : by_x ? xz : by_y ? yz : quarter;
        const double norm = sqrt(quat[0] * quat[0] + quat[1] * quat[1] + quat[2] * quat[2] +
                                 quat[3] * quat[3]);
        const double sign = (quat[0] < 0.0 ? -1.0 : 1.0) / norm;
        for (int i = 0; i < 4; ++i) L->out_quat[i][l] = (float)(quat[i] * sign);
        for (int i = 0; i < 3; ++i)
            L->out_ls[i][l] = (float)(0.5 * sc_log_lane(sc_fmax_lane(values[i], floor)));
    }
}

/* The 16 SH basis values at (x, y, z) (sc_sh_basis_grad's, without the derivatives). */
static SC_ALWAYS_INLINE void basis_lane(double x, double y, double z, double b[16]) {
    const double xx = x * x, yy = y * y, zz = z * z;
    b[1] = -SC_SH_C1 * y, b[2] = SC_SH_C1 * z, b[3] = -SC_SH_C1 * x;
    b[4] = SC_SH_C2[0] * x * y, b[5] = SC_SH_C2[1] * y * z;
    b[6] = SC_SH_C2[2] * (2.0 * zz - xx - yy), b[7] = SC_SH_C2[3] * x * z;
    b[8] = SC_SH_C2[4] * (xx - yy);
    b[9] = SC_SH_C3[0] * y * (3.0 * xx - yy), b[10] = SC_SH_C3[1] * x * y * z;
    b[11] = SC_SH_C3[2] * y * (4.0 * zz - xx - yy);
    b[12] = SC_SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
    b[13] = SC_SH_C3[4] * x * (4.0 * zz - xx - yy), b[14] = SC_SH_C3[5] * z * (xx - yy);
    b[15] = SC_SH_C3[6] * x * (xx - 3.0 * yy);
}

/* Each lane's SH bands 1..degree (a constant at each use) rotated by its Q: the file's
 * comment. */
static SC_ALWAYS_INLINE void colour_lanes(lanes *restrict L, const sc_shapes *s, const int degree) {
    static const int BAND[4] = {1, 4, 9, 16};
    const int used = BAND[degree];
    double out[48][LANES];
    for (int t = 3; t < 3 * used; ++t)
        for (int l = 0; l < LANES; ++l) out[t][l] = 0.0;
    for (int k = 0; k < DIRECTIONS; ++k) {
        const double d0 = s->fixed[k][0], d1 = s->fixed[k][1], d2 = s->fixed[k][2];
        double basis[16][LANES];
        for (int l = 0; l < LANES; ++l) { /* at Q^T d */
            const double x = L->Q[0][l] * d0 + L->Q[3][l] * d1 + L->Q[6][l] * d2;
            const double y = L->Q[1][l] * d0 + L->Q[4][l] * d1 + L->Q[7][l] * d2;
            const double z = L->Q[2][l] * d0 + L->Q[5][l] * d1 + L->Q[8][l] * d2;
            double b[16];
            basis_lane(x, y, z, b);
            for (int t = 1; t < used; ++t) basis[t][l] = b[t];
        }
        for (int band = 0; band < degree; ++band)
            for (int ch = 0; ch < 3; ++ch) {
                double value[LANES];
                for (int l = 0; l < LANES; ++l) value[l] = 0.0;
                for (int t = BAND[band]; t < BAND[band + 1]; ++t)
                    for (int l = 0; l < LANES; ++l) value[l] += basis[t][l] * L->sh[3 * t + ch][l];
                for (int t = BAND[band]; t < BAND[band + 1]; ++t) {
                    const double weight = s->project[t][k];
                    for (int l = 0; l < LANES; ++l) out[3 * t + ch][l] += weight * value[l];
                }
            }
    }
    for (int t = 3; t < 3 * used; ++t)
        for (int l = 0; l < LANES; ++l) L->out_sh[t][l] = (float)out[t][l];
}

static SC_ALWAYS_INLINE void lanes_body(lanes *restrict L, const sc_shapes *s, const int degree) {
    covariance_lanes(L);
    decompose_lanes(L);
    if (degree > 0) colour_lanes(L, s, degree);
}

#define SC_SHAPE_LANES_DEGREE(d)                                                                   \
    SC_MULTIVERSION(void, lanes_degree##d, (lanes * L, const sc_shapes *s), (L, s),               \
                    lanes_body(L, s, d))
SC_SHAPE_LANES_DEGREE(0)
SC_SHAPE_LANES_DEGREE(1)
SC_SHAPE_LANES_DEGREE(2)
SC_SHAPE_LANES_DEGREE(3)

void sc_shapes_batch(const sc_shapes *s, const sc_shape_batch *b) {
    lanes L;
    const int coeffs = s->coeffs, used = 3 * coeffs;
    for (int l = 0; l < LANES; ++l) { /* a short batch repeats its last Gaussian */
        const int from = l < b->count ? l : b->count - 1;
        const int64_t i = b->index[from];
        for (int e = 0; e < 9; ++e) L.J[e][l] = b->jac[from][e], L.Q[e][l] = b->rot[from][e];
        for (int e = 0; e < 3; ++e) L.ls[e][l] = s->log_scales[3 * i + e];
        for (int e = 0; e < 4; ++e) L.quat[e][l] = s->quats[4 * i + e];
        const float *sh = s->sh + (int64_t)used * i;
        for (int t = 0; t < used; ++t) L.sh[t][l] = sh[t];
    }
    switch (coeffs) {
    case 1: lanes_degree0(&L, s); break;
    case 4: lanes_degree1(&L, s); break;
    case 9: lanes_degree2(&L, s); break;
    default: lanes_degree3(&L, s); break;
    }
    for (int l = 0; l < b->count; ++l) {
        const int64_t i = b->index[l];
        float *sh = s->out_sh + (int64_t)used * i;
        sh[0] = (float)L.sh[0][l], sh[1] = (float)L.sh[1][l], sh[2] = (float)L.sh[2][l];
        for (int t = 3; t < used; ++t) sh[t] = L.out_sh[t][l];
        if (L.scalar[l]) {
            shape_one(s, i, b->jac[l]);
            continue;
        }
        for (int e = 0; e < 3; ++e) s->out_log_scales[3 * i + e] = L.out_ls[e][l];
        for (int e = 0; e < 4; ++e) s->out_quats[4 * i + e] = L.out_quat[e][l];
    }
}

static void deform_rows(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const job *j = ctx;
    sc_shape_batch b;
    for (int64_t start = begin; start < end; start += LANES) {
        b.count = end - start < LANES ? (int)(end - start) : LANES;
        for (int l = 0; l < b.count; ++l) {
            const int64_t i = start + l;
            b.index[l] = i;
            memcpy(b.jac[l], j->jacobians + 9 * i, sizeof b.jac[l]);
            memcpy(b.rot[l], j->rotations + 9 * i, sizeof b.rot[l]);
        }
        sc_shapes_batch(&j->shapes, &b);
    }
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
