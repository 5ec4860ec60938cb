/* The colour of real spherical harmonics up to degree 3 (constants and backward: sh_basis.h). */
#include "sh_basis.h"

/* The colour of SH `degree` (0..3) for one Gaussian: coeffs (K,3), dir a unit vector. In float
 * (the constants of sh_basis.h, rounded), as the projection computes it. */
void sc_sh_colour_f(int degree, const float *coeffs, const float dir[3], float rgb[3]) {
    float basis[16];
    sc_sh_basis_f(dir[0], dir[1], dir[2], basis);
    const int k = (degree + 1) * (degree + 1);
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
