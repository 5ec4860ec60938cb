/* The per-point steps of the deformation stages, shared by the stage-by-stage entry points
 * (deform_fit.c: each point's Jacobian and polar rotation; deform_apply.c: Gaussians through
 * given maps) and the one-pass frame (deform_frame.c: both per Gaussian, nothing in between
 * kept). Only src/ files include this. */
#ifndef SC_DEFORM_H
#define SC_DEFORM_H

#include "internal.h"

/* How many Gaussians the deformation stages take side by side, in vector lanes. */
enum { SC_SHAPE_LANES = 8 };

/* Rows of rest and deformed centres (n, 3), each row's neighbours (n, k) as rows (-1 none),
 * the fit's thresholds (variance ratios). */
typedef struct {
    const float *rest, *deformed;
    const int32_t *neighbours;
    int k;
    double undetermined, determined;
} sc_fit_input;

/* The rest half of a row's fit, SC_FIT_FIELDS + k doubles (deform_fit.c's comment): what depends
 * on the rest centres and the neighbour lists alone, so a deformation's frames share it. Offsets
 * into it: */
enum {
    SC_FIT_E1 = 0, /* the spread's widest direction e_1 (3) */
    SC_FIT_E2 = 3, /* the second, e_2 (3); e_3 = e_1 x e_2 */
    SC_FIT_L = 6,  /* the spread's eigenvalues l_1 >= l_2 >= l_3 (3); l_1 = 0: no neighbours */
    SC_FIT_C = 9,  /* the ramps c_2, c_3 (2) */
    SC_FIT_W = 11  /* each neighbour's weight (k; 0 where there is none) */
};
_Static_assert((int)SC_FIT_W == (int)SC_FIT_FIELDS, "the weights end the rest half's fixed fields");

/* Row `row`'s rest half (in->deformed is not read) into `half`. */
void sc_fit_rest(const sc_fit_input *in, int64_t row, double *half);

/* Rows row .. row + count - 1's (count 1..SC_SHAPE_LANES) deformation Jacobians and their polar
 * rotations (deform_fit.c's comment) from their rest halves (`halves`, one after the other);
 * the thresholds in `in` are not read (they are in the halves). The same numbers whatever the
 * batch. */
void sc_fit_batch(const sc_fit_input *in, int64_t row, int count, const double *halves,
                  double jac[][9], double rot[][9]);

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

/* Up to SC_SHAPE_LANES Gaussians (their indices) and their maps J and orthogonal Q. */
typedef struct {
    int count; /* 1..SC_SHAPE_LANES */
    int64_t index[SC_SHAPE_LANES];
    double jac[SC_SHAPE_LANES][9], rot[SC_SHAPE_LANES][9];
} sc_shape_batch;

/* Each Gaussian's covariance through its J and its SH through its Q, into the outputs
 * (deform_apply.c's comment); the same numbers whatever the batch. */
void sc_shapes_batch(const sc_shapes *s, const sc_shape_batch *b);

#endif
