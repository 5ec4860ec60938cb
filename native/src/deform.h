/* The per-point steps of the deformation stages, shared by the stage-by-stage entry points
 * (deform_fit.c: each point's Jacobian and polar rotation; deform_apply.c: Gaussians through
 * given maps) and the one-pass frame (deform_frame.c: both per Gaussian, nothing in between
 * kept). Only src/ files include this. */
#ifndef SC_DEFORM_H
#define SC_DEFORM_H

#include "internal.h"

/* Rows of rest and deformed centres (n, 3), each row's neighbours (n, k) as rows (-1 none),
 * the fit's thresholds (variance ratios). */
typedef struct {
    const float *rest, *deformed;
    const int32_t *neighbours;
    int k;
    double undetermined, determined;
} sc_fit_input;

/* Row `row`'s deformation Jacobian and its polar rotation (deform_fit.c's comment). */
void sc_fit_point(const sc_fit_input *in, int64_t row, double jac[9], double rot[9]);

enum { SC_SH_DIRECTIONS = 9 };

/* Gaussians' shapes and SH in, their deformed ones out (by Gaussian), and what
 * sc_shapes_prepare fills: the fixed directions and each SH band's least-squares inverse. */
typedef struct {
    const float *log_scales, *quats, *sh;
    int coeffs;
    float *out_log_scales, *out_quats, *out_sh;
    double fixed[SC_SH_DIRECTIONS][3];
    double project[16][SC_SH_DIRECTIONS]; /* rows 1..15: each band's least-squares inverse */
} sc_shapes;

void sc_shapes_prepare(sc_shapes *s);

/* Gaussian i's covariance through J and its SH through the orthogonal Q, into the outputs
 * (deform_apply.c's comment). */
void sc_shapes_point(const sc_shapes *s, int64_t i, const double J[9], const double Q[9]);

#endif
