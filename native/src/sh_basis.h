/* Real spherical harmonics up to degree 3: the constants and basis order of the reference 3DGS
 * code (computeColorFromSH), so trained coefficients mean the same thing here, and the backward
 * of the colour. The backward is inline so the projection backward, compiled per instruction-set
 * level (SC_MULTIVERSION), compiles it for its level too. Only src/ files include this. */
#ifndef SC_SH_BASIS_H
#define SC_SH_BASIS_H

#include "internal.h"

static const double SC_SH_C0 = 0.28209479177387814;
static const double SC_SH_C1 = 0.4886025119029199;
static const double SC_SH_C2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                                   -1.0925484305920792, 0.5462742152960396};
static const double SC_SH_C3[7] = {-0.5900435899266435, 2.890611442640554, -0.4570457994644658,
                                   0.3731763325901154,  -0.4570457994644658, 1.445305721320277,
                                   -0.5900435899266435};

/* The 16 basis values of degree 3 at the unit direction (x, y, z), in float (the constants
 * rounded): what sc_sh_colour_f and the projection's 16-lane colour (project.c) sum with. */
static SC_ALWAYS_INLINE void sc_sh_basis_f(float x, float y, float z, float basis[16]) {
    const float xx = x * x, yy = y * y, zz = z * z;
    basis[0] = (float)SC_SH_C0;
    basis[1] = (float)-SC_SH_C1 * y;
    basis[2] = (float)SC_SH_C1 * z;
    basis[3] = (float)-SC_SH_C1 * x;
    basis[4] = (float)SC_SH_C2[0] * x * y;
    basis[5] = (float)SC_SH_C2[1] * y * z;
    basis[6] = (float)SC_SH_C2[2] * (2.0f * zz - xx - yy);
    basis[7] = (float)SC_SH_C2[3] * x * z;
    basis[8] = (float)SC_SH_C2[4] * (xx - yy);
    basis[9] = (float)SC_SH_C3[0] * y * (3.0f * xx - yy);
    basis[10] = (float)SC_SH_C3[1] * x * y * z;
    basis[11] = (float)SC_SH_C3[2] * y * (4.0f * zz - xx - yy);
    basis[12] = (float)SC_SH_C3[3] * z * (2.0f * zz - 3.0f * xx - 3.0f * yy);
    basis[13] = (float)SC_SH_C3[4] * x * (4.0f * zz - xx - yy);
    basis[14] = (float)SC_SH_C3[5] * z * (xx - yy);
    basis[15] = (float)SC_SH_C3[6] * x * (xx - 3.0f * yy);
}

/* The basis values at the direction (x, y, z) for `degree`, and their derivatives in x, y and
 * z (the polynomials of sc_sh_basis_f differentiated, as the reference backward.cu does), into
 * the first (degree+1)^2 entries; the caller zeroes gx, gy and gz. Inline so that the lane loop
 * of the projection backward vectorises it. */
static SC_ALWAYS_INLINE void sc_sh_basis_grad(int degree, double x, double y, double z,
                                              double basis[16], double gx[16], double gy[16],
                                              double gz[16]) {
    basis[0] = SC_SH_C0;
    if (degree >= 1) {
        basis[1] = -SC_SH_C1 * y, gy[1] = -SC_SH_C1;
        basis[2] = SC_SH_C1 * z, gz[2] = SC_SH_C1;
        basis[3] = -SC_SH_C1 * x, gx[3] = -SC_SH_C1;
    }
    if (degree >= 2) {
        const double xx = x * x, yy = y * y, zz = z * z;
        basis[4] = SC_SH_C2[0] * x * y, gx[4] = SC_SH_C2[0] * y, gy[4] = SC_SH_C2[0] * x;
        basis[5] = SC_SH_C2[1] * y * z, gy[5] = SC_SH_C2[1] * z, gz[5] = SC_SH_C2[1] * y;
        basis[6] = SC_SH_C2[2] * (2.0 * zz - xx - yy);
        gx[6] = -2.0 * SC_SH_C2[2] * x, gy[6] = -2.0 * SC_SH_C2[2] * y, gz[6] = 4.0 * SC_SH_C2[2] * z;
        basis[7] = SC_SH_C2[3] * x * z, gx[7] = SC_SH_C2[3] * z, gz[7] = SC_SH_C2[3] * x;
        basis[8] = SC_SH_C2[4] * (xx - yy), gx[8] = 2.0 * SC_SH_C2[4] * x, gy[8] = -2.0 * SC_SH_C2[4] * y;
        if (degree >= 3) {
            basis[9] = SC_SH_C3[0] * y * (3.0 * xx - yy);
            gx[9] = SC_SH_C3[0] * 6.0 * x * y, gy[9] = SC_SH_C3[0] * 3.0 * (xx - yy);
            basis[10] = SC_SH_C3[1] * x * y * z;
            gx[10] = SC_SH_C3[1] * y * z, gy[10] = SC_SH_C3[1] * x * z, gz[10] = SC_SH_C3[1] * x * y;
            basis[11] = SC_SH_C3[2] * y * (4.0 * zz - xx - yy);
            gx[11] = -2.0 * SC_SH_C3[2] * x * y, gy[11] = SC_SH_C3[2] * (4.0 * zz - xx - 3.0 * yy);
            gz[11] = 8.0 * SC_SH_C3[2] * y * z;
            basis[12] = SC_SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
            gx[12] = -6.0 * SC_SH_C3[3] * x * z, gy[12] = -6.0 * SC_SH_C3[3] * y * z;
            gz[12] = SC_SH_C3[3] * (6.0 * zz - 3.0 * xx - 3.0 * yy);
            basis[13] = SC_SH_C3[4] * x * (4.0 * zz - xx - yy);
            gx[13] = SC_SH_C3[4] * (4.0 * zz - 3.0 * xx - yy), gy[13] = -2.0 * SC_SH_C3[4] * x * y;
            gz[13] = 8.0 * SC_SH_C3[4] * x * z;
            basis[14] = SC_SH_C3[5] * z * (xx - yy);
            gx[14] = 2.0 * SC_SH_C3[5] * x * z, gy[14] = -2.0 * SC_SH_C3[5] * y * z, gz[14] = SC_SH_C3[5] * (xx - yy);
            basis[15] = SC_SH_C3[6] * x * (xx - 3.0 * yy);
            gx[15] = SC_SH_C3[6] * 3.0 * (xx - yy), gy[15] = -6.0 * SC_SH_C3[6] * x * y;
        }
    }
}

/* Backward of sc_sh_colour_f: given dL/d(rgb) (before the +0.5 and the clamp), writes dL/dcoeffs
 * for the first (degree+1)^2 coefficients (K,3 layout) and returns dL/d(dir) (dir treated as a
 * free vector; the caller applies the normalisation).
 * The colour is sum_i basis_i(dir) coeffs_i, so dL/dcoeffs_i = basis_i dL/drgb and
 * dL/ddir = sum_i grad(basis_i) (coeffs_i . dL/drgb), with grad(basis_i) the derivatives of
 * the polynomials above in x, y, z (as the reference backward.cu computes them). */
static SC_ALWAYS_INLINE void sc_sh_backward(int degree, const float *coeffs, const double dir[3],
                                           const double d_rgb[3], double *d_coeffs,
                                           double d_dir[3]) {
    double basis[16], gx[16] = {0}, gy[16] = {0}, gz[16] = {0};
    const int k = degree >= 3 ? 16 : (degree + 1) * (degree + 1);
    sc_sh_basis_grad(degree, dir[0], dir[1], dir[2], basis, gx, gy, gz);
    d_dir[0] = d_dir[1] = d_dir[2] = 0.0;
    for (int i = 0; i < k; ++i) {
        const float *c = coeffs + 3 * i;
        const double along = c[0] * d_rgb[0] + c[1] * d_rgb[1] + c[2] * d_rgb[2];
        d_coeffs[3 * i + 0] = basis[i] * d_rgb[0];
        d_coeffs[3 * i + 1] = basis[i] * d_rgb[1];
        d_coeffs[3 * i + 2] = basis[i] * d_rgb[2];
        d_dir[0] += gx[i] * along;
        d_dir[1] += gy[i] * along;
        d_dir[2] += gz[i] * along;
    }
}

#endif
