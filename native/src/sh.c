/* The colour of real spherical harmonics up to degree 3 (constants and backward: sh_basis.h). */
#include "sh_basis.h"

/* The colour of SH `degree` (0..3) for one Gaussian: coeffs (K,3), dir a unit vector. In float
 * (the constants of sh_basis.h, rounded), as the projection computes it. */
void sc_sh_colour_f(int degree, const float *coeffs, const float dir[3], float rgb[3]) {
    float basis[16];
    const float x = dir[0], y = dir[1], z = dir[2];
    int k = 1;
    basis[0] = (float)SC_SH_C0;
    if (degree >= 1) {
        basis[1] = (float)-SC_SH_C1 * y;
        basis[2] = (float)SC_SH_C1 * z;
        basis[3] = (float)-SC_SH_C1 * x;
        k = 4;
    }
    if (degree >= 2) {
        const float xx = x * x, yy = y * y, zz = z * z;
        basis[4] = (float)SC_SH_C2[0] * x * y;
        basis[5] = (float)SC_SH_C2[1] * y * z;
        basis[6] = (float)SC_SH_C2[2] * (2.0f * zz - xx - yy);
        basis[7] = (float)SC_SH_C2[3] * x * z;
        basis[8] = (float)SC_SH_C2[4] * (xx - yy);
        k = 9;
        if (degree >= 3) {
            basis[9] = (float)SC_SH_C3[0] * y * (3.0f * xx - yy);
            basis[10] = (float)SC_SH_C3[1] * x * y * z;
            basis[11] = (float)SC_SH_C3[2] * y * (4.0f * zz - xx - yy);
            basis[12] = (float)SC_SH_C3[3] * z * (2.0f * zz - 3.0f * xx - 3.0f * yy);
            basis[13] = (float)SC_SH_C3[4] * x * (4.0f * zz - xx - yy);
            basis[14] = (float)SC_SH_C3[5] * z * (xx - yy);
            basis[15] = (float)SC_SH_C3[6] * x * (xx - 3.0f * yy);
            k = 16;
        }
    }
    float r = 0.0f, g = 0.0f, b = 0.0f;
    for (int i = 0; i < k; ++i) {
        r += basis[i] * coeffs[3 * i + 0];
        g += basis[i] * coeffs[3 * i + 1];
        b += basis[i] * coeffs[3 * i + 2];
    }
    rgb[0] = r;
    rgb[1] = g;
    rgb[2] = b;
}
