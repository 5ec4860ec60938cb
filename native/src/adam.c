/* Adam, as torch.optim.Adam computes it for float32 tensors (amsgrad off, no weight decay):
 *   m = m + (1 - b1) (g - m)        (torch's lerp, = b1 m + (1 - b1) g)
 *   v = b2 v + (1 - b2) g^2
 *   p = p - lr / (1 - b1^t) * m / (sqrt(v) / sqrt(1 - b2^t) + eps)
 * elementwise in float32, the scalar factors in double. Each element is independent, so any
 * thread count gives the same result.
 *
 * Over the rows of a (rows, width) array, with two refinements for training:
 *  - a row mask: rows not set are left exactly as they are, moments included (gsplat's
 *    `visible_adam`: Gaussians a step did not see neither decay their moments nor move);
 *  - the first `lead` values of every row may take their own rate (the SH DC coefficients
 *    beside the higher bands, without splitting the array);
 *  - only the first `used` values of every row may be updated (SH bands that have never had a
 *    gradient: with g = m = v = 0 the update leaves them exactly as they are, so skipping them
 *    changes nothing but the time).
 * The loops are compiled per instruction-set level (SC_MULTIVERSION); runs of consecutive
 * selected rows without a lead are one flat loop. */
#include <math.h>

#include "internal.h"

typedef struct {
    float *param, *m, *v;
    const float *grad;
    const uint8_t *mask; /* (rows) or NULL: every row */
    int64_t rows, width, lead, used;
    float b2, one_minus_b1, one_minus_b2, step_size, lead_step_size, inv_bc2_sqrt, eps;
} job;

/* Elements [begin, end) of the flat arrays at one step size. */
static SC_ALWAYS_INLINE void update(const job *j, int64_t begin, int64_t end, float step_size) {
    float *restrict p = j->param, *restrict m = j->m, *restrict v = j->v;
    const float *restrict g = j->grad;
    const float b2 = j->b2, one_minus_b1 = j->one_minus_b1, one_minus_b2 = j->one_minus_b2;
    const float inv_bc2_sqrt = j->inv_bc2_sqrt, eps = j->eps;
    for (int64_t i = begin; i < end; ++i) {
        const float gi = g[i];
        const float mi = m[i] + one_minus_b1 * (gi - m[i]);
        const float vi = b2 * v[i] + one_minus_b2 * gi * gi;
        m[i] = mi;
        v[i] = vi;
        p[i] -= step_size * mi / (sqrtf(vi) * inv_bc2_sqrt + eps);
    }
}

/* Rows [begin, end). */
static SC_ALWAYS_INLINE int rows_body(const job *j, int64_t begin, int64_t end) {
    const int64_t w = j->width;
    for (int64_t r = begin; r < end; ++r) {
        if (j->mask && !j->mask[r]) continue;
        if (j->lead > 0 || j->used < w) {
            update(j, r * w, r * w + j->lead, j->lead_step_size);
            update(j, r * w + j->lead, r * w + j->used, j->step_size);
            continue;
        }
        int64_t run = r + 1; /* the selected rows from r on, as one flat loop */
        while (run < end && (!j->mask || j->mask[run])) ++run;
        update(j, r * w, run * w, j->step_size);
        r = run - 1;
    }
    return 0;
}

SC_MULTIVERSION(int, rows_isa, (const job *j, int64_t begin, int64_t end), (j, begin, end),
                rows_body(j, begin, end))

static void adam_rows(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    rows_isa(ctx, begin, end);
}

void sc_adam_rows(float *param, const float *grad, float *m, float *v, int64_t rows,
                  int64_t width, const uint8_t *mask, int64_t lead, double lead_lr, int64_t used,
                  const sc_adam_options *o, int threads) {
    used = used < 0 || used > width ? width : used;
    const double bc1 = 1.0 - pow(o->beta1, (double)o->step);
    const double bc2 = 1.0 - pow(o->beta2, (double)o->step);
    job j = {.param = param, .m = m, .v = v, .grad = grad, .mask = mask, .rows = rows,
             .width = width, .lead = lead < 0 ? 0 : lead > used ? used : lead, .used = used,
             .b2 = (float)o->beta2,
             .one_minus_b1 = (float)(1.0 - o->beta1), .one_minus_b2 = (float)(1.0 - o->beta2),
             .step_size = (float)(o->lr / bc1), .lead_step_size = (float)(lead_lr / bc1),
             .inv_bc2_sqrt = (float)(1.0 / sqrt(bc2)), .eps = (float)o->eps};
    sc_parallel_for(threads, rows, sc_grain(rows, width, threads), adam_rows, &j);
}

void sc_adam(float *param, const float *grad, float *m, float *v, int64_t n,
             const sc_adam_options *o, int threads) {
    sc_adam_rows(param, grad, m, v, n, 1, NULL, 0, o->lr, 1, o, threads);
}
