/* The hash encoding's interpolation fused for one CPU thread (nerfaug.nerf.hash_cpu builds and
 * loads it). For each level and point: the 8 vertices' rows and trilinear weights, computed as
 * HashEncoding.corners computes them, then the gathered features summed (forward) or the output
 * gradient scattered into the table (backward), without the (levels x 8 x points) intermediate
 * tensors the PyTorch path writes and reads back.
 *
 * Deterministic: one thread, a fixed order (level, then point, then vertex z-y-x), IEEE float32
 * arithmetic (built without -ffast-math and with -ffp-contract=off, so no fused multiply-add and
 * no reordered sums on any x86-64 or ARM machine).
 *
 * Layouts: x (n, 3) float32; table (levels * table_size, F) float32; out / grad (n, levels * F)
 * float32; resolutions (levels,) int32; factors (levels, 3) int32 (dense: row-major strides,
 * hashed: primes masked to the table size).
 */
#include <stdint.h>

typedef struct {
    float weight[8];
    uint32_t row[8];
} corners_t;

/* The rows (in the flat table) and weights of the cell's 8 vertices around point p at one level. */
static inline void cell(const float *p, int32_t res, const int32_t *factor, int dense, uint32_t mask,
                        uint32_t offset, corners_t *c) {
    uint32_t term[3][2];
    float w[3][2];
    for (int a = 0; a < 3; a++) {
        /* Points are clamped into the unit cube: a point outside reads the nearest face's cell
         * (the model clamps before encoding; the clamp keeps every row inside the table). A NaN
         * (a diverging run's sample) reads the origin's cell rather than memory outside the table. */
        float x = p[a];
        x = !(x >= 0.0f) ? 0.0f : (x > 1.0f ? 1.0f : x);
        float scaled = (float)res * x;
        /* scaled >= 0, so truncation is the floor (floorf is a library call without SSE4.1). */
        float floor_ = (float)(int32_t)scaled;
        float frac = scaled - floor_;
        int32_t low = (int32_t)floor_;
        int32_t high = low + 1 < res ? low + 1 : res; /* x == 1 stays on the last cell's far face */
        /* Unsigned products wrap as Instant-NGP's uint32 (the PyTorch path's int32 products have
         * the same low bits). */
        uint32_t f = (uint32_t)factor[a];
        term[a][0] = (uint32_t)low * f;
        term[a][1] = (uint32_t)high * f;
        if (!dense) {
            term[a][0] &= mask;
            term[a][1] &= mask;
        }
        w[a][0] = 1.0f - frac;
        w[a][1] = frac;
    }
    for (int z = 0; z < 2; z++)
        for (int y = 0; y < 2; y++)
            for (int xx = 0; xx < 2; xx++) {
                int k = 4 * z + 2 * y + xx;
                uint32_t row = dense ? term[0][xx] + term[1][y] + term[2][z] : term[0][xx] ^ term[1][y] ^ term[2][z];
                c->row[k] = row + offset;
                c->weight[k] = w[0][xx] * w[1][y] * w[2][z];
            }
}

/* F features a row, F known at compile time where the call passes a literal (2 in every preset). */
static inline void forward_level(const float *x, int64_t n, const float *table, int F, int levels, int level,
                                 int32_t res, const int32_t *factor, int dense, uint32_t mask, uint32_t offset,
                                 float *out) {
    corners_t c;
    for (int64_t i = 0; i < n; i++) {
        cell(x + 3 * i, res, factor, dense, mask, offset, &c);
        float *o = out + i * (int64_t)levels * F + (int64_t)level * F;
        for (int f = 0; f < F; f++) {
            float sum = 0.0f;
            for (int k = 0; k < 8; k++) sum += c.weight[k] * table[(int64_t)c.row[k] * F + f];
            o[f] = sum;
        }
    }
}

static inline void backward_level(const float *x, int64_t n, const float *grad, int F, int levels, int level,
                                  int32_t res, const int32_t *factor, int dense, uint32_t mask, uint32_t offset,
                                  float *grad_table) {
    corners_t c;
    for (int64_t i = 0; i < n; i++) {
        cell(x + 3 * i, res, factor, dense, mask, offset, &c);
        const float *g = grad + i * (int64_t)levels * F + (int64_t)level * F;
        for (int k = 0; k < 8; k++) {
            float *t = grad_table + (int64_t)c.row[k] * F;
            for (int f = 0; f < F; f++) t[f] += c.weight[k] * g[f];
        }
    }
}

void hash_forward(const float *x, int64_t n, const float *table, int features, int levels,
                  const int32_t *resolutions, const int32_t *factors, int dense_levels, int64_t table_size,
                  float *out) {
    uint32_t mask = (uint32_t)(table_size - 1);
    for (int l = 0; l < levels; l++) {
        uint32_t offset = (uint32_t)(l * table_size);
        int dense = l < dense_levels;
        if (features == 2)
            forward_level(x, n, table, 2, levels, l, resolutions[l], factors + 3 * l, dense, mask, offset, out);
        else
            forward_level(x, n, table, features, levels, l, resolutions[l], factors + 3 * l, dense, mask, offset,
                          out);
    }
}

/* grad_table must be zero on entry (or hold what the gradients are added to). */
void hash_backward(const float *x, int64_t n, const float *grad, int features, int levels,
                   const int32_t *resolutions, const int32_t *factors, int dense_levels, int64_t table_size,
                   float *grad_table) {
    uint32_t mask = (uint32_t)(table_size - 1);
    for (int l = 0; l < levels; l++) {
        uint32_t offset = (uint32_t)(l * table_size);
        int dense = l < dense_levels;
        if (features == 2)
            backward_level(x, n, grad, 2, levels, l, resolutions[l], factors + 3 * l, dense, mask, offset,
                           grad_table);
        else
            backward_level(x, n, grad, features, levels, l, resolutions[l], factors + 3 * l, dense, mask, offset,
                           grad_table);
    }
}
