/* Adam, as torch.optim.Adam computes it for float32 tensors (amsgrad off, no weight decay):
 *   m = m + (1 - b1) (g - m)        (torch's lerp, = b1 m + (1 - b1) g)
 *   v = b2 v + (1 - b2) g^2
 *   p = p - lr / (1 - b1^t) * m / (sqrt(v) / sqrt(1 - b2^t) + eps)
 * elementwise in float32, the scalar factors in double. Each element is independent, so any
 * thread count gives the same result. */
#include <math.h>

#include "internal.h"

typedef struct {
    float *param, *m, *v;
    const float *grad;
    float b1, b2, one_minus_b1, one_minus_b2, step_size, inv_bc2_sqrt, eps;
} job;

static void adam_range(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const job *j = ctx;
    float *restrict p = j->param, *restrict m = j->m, *restrict v = j->v;
    const float *restrict g = j->grad;
    for (int64_t i = begin; i < end; ++i) {
        const float gi = g[i];
        const float mi = m[i] + j->one_minus_b1 * (gi - m[i]);
        const float vi = j->b2 * v[i] + j->one_minus_b2 * gi * gi;
        m[i] = mi;
        v[i] = vi;
        p[i] -= j->step_size * mi / (sqrtf(vi) * j->inv_bc2_sqrt + j->eps);
    }
}

void sc_adam(float *param, const float *grad, float *m, float *v, int64_t n,
             const sc_adam_options *o, int threads) {
    const double bc1 = 1.0 - pow(o->beta1, (double)o->step);
    const double bc2 = 1.0 - pow(o->beta2, (double)o->step);
    job j = {.param = param, .m = m, .v = v, .grad = grad, .b1 = (float)o->beta1,
             .b2 = (float)o->beta2, .one_minus_b1 = (float)(1.0 - o->beta1),
             .one_minus_b2 = (float)(1.0 - o->beta2), .step_size = (float)(o->lr / bc1),
             .inv_bc2_sqrt = (float)(1.0 / sqrt(bc2)), .eps = (float)o->eps};
    sc_parallel_for(threads, n, 1 << 16, adam_range, &j);
}
