/* 3DGS-MCMC's position noise (Kheradmand et al. 2024; addon/core/train/strategies/mcmc.py), per
 * Gaussian in double, as the reference computes it in float64:
 *   o = sigmoid(opacity logit),  gate = sigmoid(100 ((1 - o) - 0.995)),
 *   mean += float32(R diag(s^2) R^T z gate scale),  s = exp(log scales),
 * R the rotation of the normalised quaternion (identity for a zero one), z the caller's standard
 * normal draw (so the random stream stays the caller's). A gate at or below 1e-12 (opacity above
 * about 0.27) moves a mean by less than float32 resolves: such means are left exactly as they
 * are. Each Gaussian is independent: identical for any thread count. */
#include <math.h>

#include "internal.h"

enum { GRAIN = 4096 };
static const double MIN_GATE = 1e-12;

typedef struct {
    float *means;
    const float *log_scales, *quats, *opacity_logits;
    const double *noise;
    double scale;
} job;

static void noise_rows(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const job *j = ctx;
    for (int64_t i = begin; i < end; ++i) {
        const double o = 1.0 / (1.0 + exp(-(double)j->opacity_logits[i]));
        const double gate = 1.0 / (1.0 + exp(-100.0 * ((1.0 - o) - 0.995)));
        if (!(gate > MIN_GATE)) continue;
        double unit[4], r[9];
        sc_quat_rotation(j->quats + 4 * i, unit, r);
        const double f = gate * j->scale, *n = j->noise + 3 * i;
        const double z[3] = {n[0] * f, n[1] * f, n[2] * f};
        double u[3]; /* diag(s^2) R^T z */
        for (int k = 0; k < 3; ++k) {
            const double variance = exp(2.0 * (double)j->log_scales[3 * i + k]);
            u[k] = variance * (r[k] * z[0] + r[3 + k] * z[1] + r[6 + k] * z[2]);
        }
        float *mean = j->means + 3 * i;
        for (int k = 0; k < 3; ++k)
            mean[k] += (float)(r[3 * k] * u[0] + r[3 * k + 1] * u[1] + r[3 * k + 2] * u[2]);
    }
}

void sc_position_noise(float *means, const float *log_scales, const float *quats,
                       const float *opacity_logits, const double *noise, int64_t count,
                       double scale, int threads) {
    job j = {.means = means, .log_scales = log_scales, .quats = quats,
             .opacity_logits = opacity_logits, .noise = noise, .scale = scale};
    sc_parallel_for(threads < 1 ? 1 : threads, count, GRAIN, noise_rows, &j);
}
