/* The proposal sampler's per-ray arithmetic fused for one CPU thread (nerfaug.nerf.sampler_cpu
 * builds and loads it): volume-rendering weights and their gradient, the inverse-CDF resampling
 * of a histogram, and the interlevel and distortion losses with their gradients. Each replaces a
 * chain of 10-30 small PyTorch operations on (rays x samples) tensors by one pass over each ray.
 *
 * Deterministic: one thread, a fixed order (ray by ray, sample by sample), IEEE float32
 * elementwise arithmetic, running sums in double as PyTorch's CPU cumsum keeps them; built without
 * -ffast-math and with -ffp-contract=off, so the same operations on every x86-64 or ARM machine
 * (no result depends on a vector unit's width).
 *
 * Layouts: every array row-major and contiguous, one row per ray: edges (R, n + 1), per-sample
 * arrays (R, n), per-ray arrays (R,).
 */
#include <math.h>
#include <stdint.h>

#define MAX_OPTICAL_DEPTH 80.0f

/* w_i = T_i alpha_i with T_i = exp(-sum_{j<i} sigma_j delta_j), alpha_i = 1 - exp(-sigma_i
 * delta_i); optical depths clamped at 80 and the transmittance beyond it 0, as
 * nerfaug.nerf.volrend.render_weights. decay (R, n) keeps exp(-sigma_i delta_i) for the backward. */
void weights_forward(const float *sigma, const float *delta, int64_t rays, int64_t n, float *weights,
                     float *transmittance, float *decay) {
    for (int64_t r = 0; r < rays; r++) {
        const float *s = sigma + r * n, *d = delta + r * n;
        float *w = weights + r * n, *t = transmittance + r * n, *e = decay + r * n;
        double accumulated = 0.0;
        for (int64_t i = 0; i < n; i++) {
            float exclusive = (float)accumulated;
            float optical = s[i] * d[i];
            accumulated += optical;
            float trans = exclusive > MAX_OPTICAL_DEPTH ? 0.0f : expf(-exclusive);
            e[i] = expf(-(optical > MAX_OPTICAL_DEPTH ? MAX_OPTICAL_DEPTH : optical));
            t[i] = trans;
            w[i] = trans * (1.0f - e[i]);
        }
    }
}

/* The gradient of the weights (and transmittance, grad_transmittance may be NULL) with respect
 * to sigma, from the forward's transmittance and decay: d optical_k = gw_k T_k decay_k -
 * sum_{i>k} (gw_i alpha_i + gT_i) T_i, times delta_k (no gradient through a clamped optical
 * depth). */
void weights_backward(const float *sigma, const float *delta, int64_t rays, int64_t n, const float *transmittance,
                      const float *decay, const float *grad_weights, const float *grad_transmittance,
                      float *grad_sigma) {
    for (int64_t r = 0; r < rays; r++) {
        const float *s = sigma + r * n, *d = delta + r * n, *gw = grad_weights + r * n;
        const float *t = transmittance + r * n, *e = decay + r * n;
        const float *gt = grad_transmittance ? grad_transmittance + r * n : 0;
        float *gs = grad_sigma + r * n;
        double behind = 0.0; /* sum_{i>k} (gw_i alpha_i + gT_i) T_i */
        for (int64_t k = n - 1; k >= 0; k--) {
            float trans = t[k], alpha = 1.0f - e[k];
            float own = s[k] * d[k] > MAX_OPTICAL_DEPTH ? 0.0f : gw[k] * trans * e[k];
            gs[k] = (float)((double)own - behind) * d[k];
            behind += (double)((gw[k] * alpha + (gt ? gt[k] : 0.0f)) * trans);
        }
    }
}

/* Count of sorted[0..size) <= value (searchsorted side="right" on a nondecreasing row; a NaN
 * value counts none). Without branches on the data (the conditional is a select), so a search
 * costs no mispredicted jumps: the rows are short and the searches many. */
static inline int64_t upper_bound(const float *sorted, int64_t size, float value) {
    if (size <= 0) return 0;
    const float *base = sorted;
    int64_t n = size;
    while (n > 1) {
        int64_t half = n / 2;
        base = base[half] <= value ? base + half : base;
        n -= half;
    }
    return (base - sorted) + (*base <= value);
}

/* Edges (R, samples) placed by inverting the CDF of each ray's histogram (edges (R, bins + 1),
 * weights (R, bins), `padding` added to every bin) at the positions u (R, samples) in [0, 1],
 * as nerfaug.nerf.sampling.sample_pdf. cdf is scratch of bins + 1 floats. */
void pdf_sample(const float *edges, const float *weights, int64_t rays, int64_t bins, const float *u, int64_t samples,
                float padding, float *cdf, float *out) {
    for (int64_t r = 0; r < rays; r++) {
        const float *e = edges + r * (bins + 1), *w = weights + r * bins, *ur = u + r * samples;
        float *o = out + r * samples;
        double total = 0.0;
        for (int64_t j = 0; j < bins; j++) total += (double)(w[j] + padding);
        float sum = (float)total;
        double running = 0.0;
        cdf[0] = 0.0f;
        for (int64_t j = 0; j < bins; j++) {
            running += (double)((w[j] + padding) / sum);
            float c = (float)running;
            cdf[j + 1] = c > 1.0f ? 1.0f : c;
        }
        for (int64_t k = 0; k < samples; k++) {
            float value = ur[k];
            int64_t above = upper_bound(cdf, bins + 1, value);
            int64_t below = above - 1 < 0 ? 0 : above - 1;
            if (above > bins) above = bins;
            float fraction = (value - cdf[below]) / (cdf[above] - cdf[below]);
            /* nan_to_num(., 0) then clamp(0, 1): 0/0 -> 0, +inf -> 1, -inf -> 0. */
            fraction = isnan(fraction) ? 0.0f : (fraction < 0.0f ? 0.0f : (fraction > 1.0f ? 1.0f : fraction));
            o[k] = e[below] + fraction * (e[above] - e[below]);
        }
    }
}

/* Count of sorted[0..size) <= value, searched upwards from the count `from` of an earlier,
 * smaller value (a ray's edges increase, so each search continues the last: O(n + m) a ray);
 * where values decrease it searches afresh, so any order gives searchsorted's answer. */
static inline int64_t count_from(const float *sorted, int64_t size, float value, float previous, int64_t from) {
    if (!(value >= previous)) return upper_bound(sorted, size, value);
    while (from < size && sorted[from] <= value) from++;
    return from;
}

/* For each final sample of a ray (edges e[0..n]), the proposal bins its interval overlaps: low
 * (the last bin starting at or before its start) and high (the first bin ending after its end),
 * clamped to [0, m - 1], as nerfaug.nerf.proposal.outer_measure. */
static inline void overlaps(const float *e, int64_t n, const float *pe, int64_t m, int64_t *low, int64_t *high) {
    int64_t starts = 0, ends = 0;
    for (int64_t i = 0; i < n; i++) {
        starts = count_from(pe, m, e[i], i ? e[i - 1] : -INFINITY, starts);         /* bins' starts pe[0..m) */
        ends = count_from(pe + 1, m, e[i + 1], i ? e[i] : -INFINITY, ends);          /* bins' ends pe[1..m] */
        int64_t lo = starts - 1;
        low[i] = lo < 0 ? 0 : (lo > m - 1 ? m - 1 : lo);
        high[i] = ends > m - 1 ? m - 1 : ends;
    }
}

/* The proposal's cumulative weights [0, cumsum(pw)] of one ray into c (m + 1 floats). */
static inline void cumulative(const float *pw, int64_t m, float *c) {
    double running = 0.0;
    c[0] = 0.0f;
    for (int64_t j = 0; j < m; j++) {
        running += pw[j];
        c[j + 1] = (float)running;
    }
}

/* Per final sample the interlevel penalty max(w - bound, 0)^2 / (w + eps), bound the proposal's
 * outer measure over the sample's interval: terms (R, n). c is scratch of m + 1 floats, bins of
 * 2 n int64. */
void interlevel_forward(const float *edges, const float *weights, int64_t rays, int64_t n, const float *p_edges,
                        const float *p_weights, int64_t m, float eps, float *c, int64_t *bins, float *terms) {
    for (int64_t r = 0; r < rays; r++) {
        const float *e = edges + r * (n + 1), *w = weights + r * n, *pe = p_edges + r * (m + 1);
        cumulative(p_weights + r * m, m, c);
        overlaps(e, n, pe, m, bins, bins + n);
        for (int64_t i = 0; i < n; i++) {
            int64_t low = bins[i], high = bins[n + i];
            float excess = w[i] - (c[high + 1] - c[low]);
            excess = excess > 0.0f ? excess : 0.0f;
            terms[r * n + i] = excess * excess / (w[i] + eps);
        }
    }
}

/* The gradient of the terms (grad (R, n)) with respect to the proposal weights (R, m): a bound
 * is c[high + 1] - c[low], and c[k] sums the weights before k. Scratch as the forward's, and
 * accumulated of m + 1 doubles. */
void interlevel_backward(const float *edges, const float *weights, int64_t rays, int64_t n, const float *p_edges,
                         const float *p_weights, int64_t m, float eps, const float *grad, float *c, int64_t *bins,
                         double *accumulated, float *grad_p_weights) {
    for (int64_t r = 0; r < rays; r++) {
        const float *e = edges + r * (n + 1), *w = weights + r * n, *pe = p_edges + r * (m + 1);
        cumulative(p_weights + r * m, m, c);
        for (int64_t k = 0; k <= m; k++) accumulated[k] = 0.0;
        overlaps(e, n, pe, m, bins, bins + n);
        for (int64_t i = 0; i < n; i++) {
            int64_t low = bins[i], high = bins[n + i];
            float excess = w[i] - (c[high + 1] - c[low]);
            if (!(excess > 0.0f)) continue;
            float grad_bound = -(grad[r * n + i] * (2.0f * excess) / (w[i] + eps));
            accumulated[high + 1] += grad_bound;
            accumulated[low] -= grad_bound;
        }
        double behind = 0.0; /* d loss / d pw_j = sum over k > j of d loss / d c[k] */
        for (int64_t j = m - 1; j >= 0; j--) {
            behind += accumulated[j + 1];
            grad_p_weights[r * m + j] = (float)behind;
        }
    }
}

/* The ray's distances normalised to [0, 1] over its span: mids and widths (n floats each). */
static inline void normalised(const float *e, int64_t n, float eps, float *mids, float *widths) {
    float span = e[n] - e[0];
    span = span > eps ? span : eps;
    for (int64_t i = 0; i < n; i++) {
        float a = (e[i] - e[0]) / span, b = (e[i + 1] - e[0]) / span;
        mids[i] = 0.5f * (b + a);
        widths[i] = b - a;
    }
}

/* sum_j w_j |m - mids_j| in four running sums (j mod 4) added at the end: a fixed order, and
 * four independent chains of additions instead of one. */
static inline float row_sum(const float *w, const float *mids, int64_t n, float m) {
    float part[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    int64_t j = 0;
    for (; j + 4 <= n; j += 4)
        for (int q = 0; q < 4; q++) part[q] += w[j + q] * fabsf(m - mids[j + q]);
    for (; j < n; j++) part[j & 3] += w[j] * fabsf(m - mids[j]);
    return (part[0] + part[1]) + (part[2] + part[3]);
}

/* mip-NeRF 360's distortion of each ray, sum_ij w_i w_j |m_i - m_j| + sum_i w_i^2 width_i / 3 on
 * distances normalised per ray: out (R,). scratch holds 2 n floats. */
void distortion_forward(const float *edges, const float *weights, int64_t rays, int64_t n, float eps, float *scratch,
                        float *out) {
    float *mids = scratch, *widths = scratch + n;
    for (int64_t r = 0; r < rays; r++) {
        const float *w = weights + r * n;
        normalised(edges + r * (n + 1), n, eps, mids, widths);
        double pairwise = 0.0, own = 0.0;
        for (int64_t i = 0; i < n; i++) {
            pairwise += (double)(w[i] * row_sum(w, mids, n, mids[i]));
            own += (double)(w[i] * w[i] * widths[i]);
        }
        out[r] = (float)pairwise + (float)own / 3.0f;
    }
}

/* The gradient of each ray's distortion (grad (R,)) with respect to its weights (R, n):
 * 2 sum_j w_j |m_k - m_j| + 2 w_k width_k / 3. */
void distortion_backward(const float *edges, const float *weights, int64_t rays, int64_t n, float eps,
                         const float *grad, float *scratch, float *grad_weights) {
    float *mids = scratch, *widths = scratch + n;
    for (int64_t r = 0; r < rays; r++) {
        const float *w = weights + r * n;
        normalised(edges + r * (n + 1), n, eps, mids, widths);
        for (int64_t k = 0; k < n; k++) {
            float d = 2.0f * row_sum(w, mids, n, mids[k]) + 2.0f * w[k] * widths[k] / 3.0f;
            grad_weights[r * n + k] = grad[r] * d;
        }
    }
}
