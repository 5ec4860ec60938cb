/* Real spherical harmonics up to degree 3, with the constants and basis order of the reference
 * 3DGS code (computeColorFromSH), so trained coefficients mean the same thing here. */
#include "splatcore.h"

static const double C0 = 0.28209479177387814;
static const double C1 = 0.4886025119029199;
static const double C2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                             -1.0925484305920792, 0.5462742152960396};
static const double C3[7] = {-0.5900435899266435, 2.890611442640554, -0.4570457994644658,
                             0.3731763325901154,  -0.4570457994644658, 1.445305721320277,
                             -0.5900435899266435};

void sc_sh_colour(int degree, const float *coeffs, const double dir[3], double rgb[3]) {
    double basis[16];
    const double x = dir[0], y = dir[1], z = dir[2];
    int k = 1;
    basis[0] = C0;
    if (degree >= 1) {
        basis[1] = -C1 * y;
        basis[2] = C1 * z;
        basis[3] = -C1 * x;
        k = 4;
    }
    if (degree >= 2) {
        const double xx = x * x, yy = y * y, zz = z * z;
        basis[4] = C2[0] * x * y;
        basis[5] = C2[1] * y * z;
        basis[6] = C2[2] * (2.0 * zz - xx - yy);
        basis[7] = C2[3] * x * z;
        basis[8] = C2[4] * (xx - yy);
        k = 9;
        if (degree >= 3) {
            basis[9] = C3[0] * y * (3.0 * xx - yy);
            basis[10] = C3[1] * x * y * z;
            basis[11] = C3[2] * y * (4.0 * zz - xx - yy);
            basis[12] = C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
            basis[13] = C3[4] * x * (4.0 * zz - xx - yy);
            basis[14] = C3[5] * z * (xx - yy);
            basis[15] = C3[6] * x * (xx - 3.0 * yy);
            k = 16;
        }
    }
    double r = 0.0, g = 0.0, b = 0.0;
    for (int i = 0; i < k; ++i) {
        r += basis[i] * coeffs[3 * i + 0];
        g += basis[i] * coeffs[3 * i + 1];
        b += basis[i] * coeffs[3 * i + 2];
    }
    rgb[0] = r;
    rgb[1] = g;
    rgb[2] = b;
}
