/* 3x3 matrices in double, row-major (m[3 * row + col]): the symmetric eigen-decomposition, a
 * rotation's quaternion and the smallest rotation between two directions, for the deformation
 * stages (deform_fit.c, deform_apply.c; the polar rotation is deform_fit.c's, in vector lanes).
 * Only src/ files include this. */
#ifndef SC_MAT3_H
#define SC_MAT3_H

#include <math.h>
#include <string.h>

static inline void sc_m3_identity(double m[9]) {
    memset(m, 0, 9 * sizeof(double));
    m[0] = m[4] = m[8] = 1.0;
}

static inline double sc_m3_det(const double m[9]) {
    return m[0] * (m[4] * m[8] - m[5] * m[7]) - m[1] * (m[3] * m[8] - m[5] * m[6]) +
           m[2] * (m[3] * m[7] - m[4] * m[6]);
}

static inline void sc_cross(const double a[3], const double b[3], double out[3]) {
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

/* Eigenvalues (ascending) and unit eigenvectors (the columns of `vectors`) of the symmetric
 * `a`, by cyclic Jacobi rotations: accurate to rounding relative to each eigenvalue's size
 * for the graded matrices thin Gaussians make, where a closed-form cubic is not. */
static inline void sc_sym3_eigen_jacobi(const double a_in[9], double values[3], double vectors[9]) {
    double a[9];
    memcpy(a, a_in, sizeof a);
    sc_m3_identity(vectors);
    static const int PQ[3][3] = {{0, 1, 2}, {0, 2, 1}, {1, 2, 0}}; /* p, q, the third */
    for (int sweep = 0; sweep < 50; ++sweep) {
        const double off = a[1] * a[1] + a[2] * a[2] + a[5] * a[5];
        const double diag = a[0] * a[0] + a[4] * a[4] + a[8] * a[8];
        if (!(off > 1e-36 * diag)) break;
        for (int r = 0; r < 3; ++r) {
            const int p = PQ[r][0], q = PQ[r][1], o = PQ[r][2];
            const double apq = a[3 * p + q];
            if (apq == 0.0) continue;
            const double theta = (a[3 * q + q] - a[3 * p + p]) / (2.0 * apq);
            const double t = (theta >= 0.0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));
            const double c = 1.0 / sqrt(t * t + 1.0), s = t * c;
            a[3 * p + p] -= t * apq;
            a[3 * q + q] += t * apq;
            a[3 * p + q] = a[3 * q + p] = 0.0;
            const double aop = a[3 * o + p], aoq = a[3 * o + q];
            a[3 * o + p] = a[3 * p + o] = c * aop - s * aoq;
            a[3 * o + q] = a[3 * q + o] = s * aop + c * aoq;
            for (int k = 0; k < 3; ++k) {
                const double vp = vectors[3 * k + p], vq = vectors[3 * k + q];
                vectors[3 * k + p] = c * vp - s * vq;
                vectors[3 * k + q] = s * vp + c * vq;
            }
        }
    }
    double d[3] = {a[0], a[4], a[8]};
    int order[3] = {0, 1, 2};
    for (int i = 1; i < 3; ++i) /* insertion sort, ascending */
        for (int j = i; j > 0 && d[order[j]] < d[order[j - 1]]; --j) {
            const int swap = order[j];
            order[j] = order[j - 1], order[j - 1] = swap;
        }
    double v[9];
    memcpy(v, vectors, sizeof v);
    for (int i = 0; i < 3; ++i) {
        values[i] = d[order[i]];
        for (int k = 0; k < 3; ++k) vectors[3 * k + i] = v[3 * k + order[i]];
    }
}

/* A unit eigenvector of the symmetric `a` for its eigenvalue `value`, one of multiplicity 1: the
 * longest cross product of two rows of a - value I (each orthogonal to it). */
static inline void sc_sym3_vector(const double a[9], double value, double out[3]) {
    const double r0[3] = {a[0] - value, a[1], a[2]}, r1[3] = {a[3], a[4] - value, a[5]},
                 r2[3] = {a[6], a[7], a[8] - value};
    double c[3][3];
    sc_cross(r0, r1, c[0]);
    sc_cross(r0, r2, c[1]);
    sc_cross(r1, r2, c[2]);
    int best = 0;
    double longest = 0.0;
    for (int i = 0; i < 3; ++i) {
        const double d = c[i][0] * c[i][0] + c[i][1] * c[i][1] + c[i][2] * c[i][2];
        if (d > longest) longest = d, best = i;
    }
    const double inv = 1.0 / sqrt(longest);
    for (int i = 0; i < 3; ++i) out[i] = c[best][i] * inv;
}

/* A unit eigenvector for `value` orthogonal to the unit eigenvector w: the 2x2 problem in a
 * basis (u, v) of w's complement (Eberly, "A Robust Eigensolver for 3x3 Symmetric
 * Matrices"). */
static inline void sc_sym3_vector_in_plane(const double a[9], const double w[3], double value,
                                           double out[3]) {
    double u[3], v[3];
    if (fabs(w[0]) > fabs(w[1])) {
        const double inv = 1.0 / sqrt(w[0] * w[0] + w[2] * w[2]);
        u[0] = -w[2] * inv, u[1] = 0.0, u[2] = w[0] * inv;
    } else {
        const double inv = 1.0 / sqrt(w[1] * w[1] + w[2] * w[2]);
        u[0] = 0.0, u[1] = w[2] * inv, u[2] = -w[1] * inv;
    }
    sc_cross(w, u, v);
    double au[3], av[3];
    for (int r = 0; r < 3; ++r) {
        au[r] = a[3 * r] * u[0] + a[3 * r + 1] * u[1] + a[3 * r + 2] * u[2];
        av[r] = a[3 * r] * v[0] + a[3 * r + 1] * v[1] + a[3 * r + 2] * v[2];
    }
    double m00 = u[0] * au[0] + u[1] * au[1] + u[2] * au[2] - value;
    double m01 = u[0] * av[0] + u[1] * av[1] + u[2] * av[2];
    double m11 = v[0] * av[0] + v[1] * av[1] + v[2] * av[2] - value;
    const double a00 = fabs(m00), a01 = fabs(m01), a11 = fabs(m11);
    double cu = 1.0, cv = 0.0; /* out = cu u + cv v; u when the 2x2 block is zero (any will do) */
    if (a00 >= a11 && fmax(a00, a01) > 0.0) {
        if (a00 >= a01) {
            m01 /= m00, m00 = 1.0 / sqrt(1.0 + m01 * m01), m01 *= m00;
        } else {
            m00 /= m01, m01 = 1.0 / sqrt(1.0 + m00 * m00), m00 *= m01;
        }
        cu = m01, cv = -m00;
    } else if (a11 > a00 && fmax(a11, a01) > 0.0) {
        if (a11 >= a01) {
            m01 /= m11, m11 = 1.0 / sqrt(1.0 + m01 * m01), m01 *= m11;
        } else {
            m11 /= m01, m01 = 1.0 / sqrt(1.0 + m11 * m11), m11 *= m01;
        }
        cu = m11, cv = -m01;
    }
    for (int i = 0; i < 3; ++i) out[i] = cu * u[i] + cv * v[i];
}

/* Eigenvalues (ascending) and unit eigenvectors (the columns of `vectors`) of the symmetric
 * `a`: in closed form (the characteristic cubic's trigonometric roots of the matrix scaled to
 * its largest entry, the most separated eigenvalue's vector as a cross product of rows, the
 * second in its complement, the third their cross product: Eberly's robust scheme), about
 * three times faster than Jacobi; by Jacobi rotations (sc_sym3_eigen_jacobi) where the closed
 * form is not accurate enough: a diagonal or non-finite a (or vectors that come out
 * non-finite), the smallest eigenvalue's size
 * below `graded` of the largest (the cubic's rounding is absolute, about 1e-16 of the largest:
 * a thin Gaussian's smallest variance would lose its relative accuracy), or two eigenvalues
 * closer than `gap` of the largest (a double root moves by the square root of the rounding,
 * and its vectors by that over the gap). */
static inline void sc_sym3_eigen(const double a_in[9], double values[3], double vectors[9],
                                 double graded, double gap) {
    double scale = 0.0;
    for (int i = 0; i < 9; ++i) scale = fmax(scale, fabs(a_in[i]));
    const double off = a_in[1] * a_in[1] + a_in[2] * a_in[2] + a_in[5] * a_in[5];
    if (!(scale > 0.0) || !isfinite(scale) || !(off > 0.0)) {
        sc_sym3_eigen_jacobi(a_in, values, vectors);
        return;
    }
    double a[9];
    for (int i = 0; i < 9; ++i) a[i] = a_in[i] / scale;
    const double norm = off / (scale * scale);
    const double q = (a[0] + a[4] + a[8]) / 3.0;
    const double b00 = a[0] - q, b11 = a[4] - q, b22 = a[8] - q;
    const double p = sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * norm) / 6.0);
    const double c00 = b11 * b22 - a[5] * a[5], c01 = a[1] * b22 - a[5] * a[2],
                 c02 = a[1] * a[5] - b11 * a[2];
    const double det = (b00 * c00 - a[1] * c01 + a[2] * c02) / (p * p * p);
    const double half = fmin(fmax(0.5 * det, -1.0), 1.0);
    const double angle = acos(half) / 3.0;
    const double beta2 = 2.0 * cos(angle), beta0 = 2.0 * cos(angle + 2.0943951023931957);
    const double beta1 = -(beta0 + beta2);
    const double value[3] = {q + p * beta0, q + p * beta1, q + p * beta2};
    const double top = fmax(fabs(value[0]), fabs(value[2]));
    if (!(fabs(value[0]) > graded * top) || !(value[1] - value[0] > gap * top) ||
        !(value[2] - value[1] > gap * top)) {
        sc_sym3_eigen_jacobi(a_in, values, vectors);
        return;
    }
    double v[3][3];
    if (half >= 0.0) { /* the largest is the most separated */
        sc_sym3_vector(a, value[2], v[2]);
        sc_sym3_vector_in_plane(a, v[2], value[1], v[1]);
        sc_cross(v[1], v[2], v[0]);
    } else {
        sc_sym3_vector(a, value[0], v[0]);
        sc_sym3_vector_in_plane(a, v[0], value[1], v[1]);
        sc_cross(v[0], v[1], v[2]);
    }
    double check = 0.0; /* NaN if a cross product underflowed to 0 (rows at 1e-160 of 1) */
    for (int i = 0; i < 3; ++i) check += v[i][0] + v[i][1] + v[i][2];
    if (!isfinite(check)) {
        sc_sym3_eigen_jacobi(a_in, values, vectors);
        return;
    }
    for (int i = 0; i < 3; ++i) {
        values[i] = value[i] * scale;
        for (int k = 0; k < 3; ++k) vectors[3 * k + i] = v[i][k];
    }
}

/* The unit quaternion (w, x, y, z), w >= 0, of a proper rotation (Shepperd's method: the
 * largest of the four pivots), as addon/core/transform.py's matrix_to_quat. */
static inline void sc_rotation_quat(const double m[9], double q[4]) {
    const double trace = m[0] + m[4] + m[8];
    if (trace >= m[0] && trace >= m[4] && trace >= m[8]) {
        const double s = 2.0 * sqrt(fmax(1.0 + trace, 0.0));
        q[0] = 0.25 * s, q[1] = (m[7] - m[5]) / s, q[2] = (m[2] - m[6]) / s, q[3] = (m[3] - m[1]) / s;
    } else if (m[0] >= m[4] && m[0] >= m[8]) {
        const double s = 2.0 * sqrt(fmax(1.0 + m[0] - m[4] - m[8], 0.0));
        q[0] = (m[7] - m[5]) / s, q[1] = 0.25 * s, q[2] = (m[1] + m[3]) / s, q[3] = (m[2] + m[6]) / s;
    } else if (m[4] >= m[8]) {
        const double s = 2.0 * sqrt(fmax(1.0 - m[0] + m[4] - m[8], 0.0));
        q[0] = (m[2] - m[6]) / s, q[1] = (m[1] + m[3]) / s, q[2] = 0.25 * s, q[3] = (m[5] + m[7]) / s;
    } else {
        const double s = 2.0 * sqrt(fmax(1.0 - m[0] - m[4] + m[8], 0.0));
        q[0] = (m[3] - m[1]) / s, q[1] = (m[2] + m[6]) / s, q[2] = (m[5] + m[7]) / s, q[3] = 0.25 * s;
    }
    const double norm = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    const double sign = q[0] < 0.0 ? -1.0 : 1.0;
    for (int i = 0; i < 4; ++i) q[i] *= sign / norm;
}

/* The smallest rotation taking the unit direction e to the unit direction d (about e x d);
 * for opposite directions, the half turn about an axis perpendicular to e. */
static inline void sc_rotation_between(const double e[3], const double d[3], double r[9]) {
    double v[3];
    sc_cross(e, d, v);
    const double c = e[0] * d[0] + e[1] * d[1] + e[2] * d[2];
    if (c > -1.0 + 1e-12) {
        const double k = 1.0 / (1.0 + c);
        const double vx[9] = {0, -v[2], v[1], v[2], 0, -v[0], -v[1], v[0], 0};
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) {
                double vv = 0.0;
                for (int m = 0; m < 3; ++m) vv += vx[3 * i + m] * vx[3 * m + j];
                r[3 * i + j] = (i == j) + vx[3 * i + j] + k * vv;
            }
        return;
    }
    /* u: e's least component's axis made perpendicular to e */
    const int axis = fabs(e[0]) <= fabs(e[1]) && fabs(e[0]) <= fabs(e[2]) ? 0
                     : fabs(e[1]) <= fabs(e[2])                            ? 1 : 2;
    double u[3] = {-e[axis] * e[0], -e[axis] * e[1], -e[axis] * e[2]};
    u[axis] += 1.0;
    const double n = sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
    for (int i = 0; i < 3; ++i) u[i] /= n;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) r[3 * i + j] = 2.0 * u[i] * u[j] - (i == j);
}

#endif
