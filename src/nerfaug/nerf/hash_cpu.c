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
 *
 * Eight points at a time (`cells8`), their vertices' rows and weights computed on 8-lane vectors
 * (GCC/Clang vector extensions, lane by lane the same operations as `cell`), the features summed
 * (forward) per point in vertex order and the gradients scattered point by point in the order of
 * the one-point loop: the same bits as the one-point loop (`hash_forward_reference`, tested), built
 * for AVX2 and for any machine, the first call choosing (`fast_machine`).
 */
#include <stdint.h>

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && !defined(NERFAUG_ONE_VERSION)
#define TWO_VERSIONS 1
#else
#define TWO_VERSIONS 0
#endif
#define INLINE inline __attribute__((always_inline))
#define LANES 8

typedef float v8f __attribute__((vector_size(32)));
typedef int32_t v8i __attribute__((vector_size(32)));
typedef uint32_t v8u __attribute__((vector_size(32)));

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

/* The rows and weights of the 8 vertices (k = 4z + 2y + x) of 8 points' cells at one level,
 * rows[k][lane] and weights[k][lane]: lane by lane `cell`'s operations in `cell`'s order. */
static INLINE void cells8(const float *p, int32_t res, const int32_t *factor, int dense, uint32_t mask,
                          uint32_t offset, uint32_t rows[8][LANES], float weights[8][LANES]) {
    const v8f zero = {0, 0, 0, 0, 0, 0, 0, 0}, one = zero + 1.0f;
    const v8i ones = {1, 1, 1, 1, 1, 1, 1, 1};
    v8u term[3][2];
    v8f w[3][2];
    for (int a = 0; a < 3; a++) {
        v8f x;
        for (int lane = 0; lane < LANES; lane++) x[lane] = p[3 * lane + a];
        /* clamped into [0, 1], NaN to 0: `!(x >= 0) ? 0 : (x > 1 ? 1 : x)` */
        x = (v8f)((v8i)x & (v8i)(x >= zero));
        v8i above = (v8i)(x > one);
        x = (v8f)(((v8i)x & ~above) | ((v8i)one & above));
        v8f scaled = x * (float)res;
        v8i low = __builtin_convertvector(scaled, v8i); /* truncation, as the (int32_t) cast */
        v8f frac = scaled - __builtin_convertvector(low, v8f);
        v8i next = low + ones, last = low - low + res;
        v8i inside = next < last;
        v8i high = (next & inside) | (last & ~inside);
        uint32_t f = (uint32_t)factor[a];
        term[a][0] = (v8u)low * f;
        term[a][1] = (v8u)high * f;
        if (!dense) {
            term[a][0] &= mask;
            term[a][1] &= mask;
        }
        w[a][0] = one - frac;
        w[a][1] = frac;
    }
    for (int z = 0; z < 2; z++)
        for (int y = 0; y < 2; y++)
            for (int xx = 0; xx < 2; xx++) {
                int k = 4 * z + 2 * y + xx;
                v8u row = dense ? term[0][xx] + term[1][y] + term[2][z] : term[0][xx] ^ term[1][y] ^ term[2][z];
                row += offset;
                v8f weight = w[0][xx] * w[1][y] * w[2][z];
                for (int lane = 0; lane < LANES; lane++) {
                    rows[k][lane] = row[lane];
                    weights[k][lane] = weight[lane];
                }
            }
}

static INLINE void forward_level8(const float *x, int64_t n, const float *table, int F, int levels, int level,
                                  int32_t res, const int32_t *factor, int dense, uint32_t mask, uint32_t offset,
                                  float *out) {
    uint32_t rows[8][LANES];
    float weights[8][LANES];
    int64_t whole = n - n % LANES;
    for (int64_t i = 0; i < whole; i += LANES) {
        cells8(x + 3 * i, res, factor, dense, mask, offset, rows, weights);
        for (int f = 0; f < F; f++) {
            v8f sum = {0, 0, 0, 0, 0, 0, 0, 0};
            for (int k = 0; k < 8; k++) {
                v8f value, weight;
                for (int lane = 0; lane < LANES; lane++) {
                    value[lane] = table[(int64_t)rows[k][lane] * F + f];
                    weight[lane] = weights[k][lane];
                }
                sum += weight * value;
            }
            for (int lane = 0; lane < LANES; lane++) out[(i + lane) * (int64_t)levels * F + (int64_t)level * F + f] = sum[lane];
        }
    }
    /* the last n % 8 points one at a time */
    forward_level(x + 3 * whole, n - whole, table, F, levels, level, res, factor, dense, mask, offset,
                  out + whole * (int64_t)levels * F);
}

static INLINE void backward_level8(const float *x, int64_t n, const float *grad, int F, int levels, int level,
                                   int32_t res, const int32_t *factor, int dense, uint32_t mask, uint32_t offset,
                                   float *grad_table) {
    uint32_t rows[8][LANES];
    float weights[8][LANES];
    int64_t whole = n - n % LANES;
    for (int64_t i = 0; i < whole; i += LANES) {
        cells8(x + 3 * i, res, factor, dense, mask, offset, rows, weights);
        /* point by point, vertex by vertex: the one-point loop's order of additions */
        for (int lane = 0; lane < LANES; lane++) {
            const float *g = grad + (i + lane) * (int64_t)levels * F + (int64_t)level * F;
            for (int k = 0; k < 8; k++) {
                float *t = grad_table + (int64_t)rows[k][lane] * F;
                for (int f = 0; f < F; f++) t[f] += weights[k][lane] * g[f];
            }
        }
    }
    backward_level(x + 3 * whole, n - whole, grad + whole * (int64_t)levels * F, F, levels, level, res, factor,
                   dense, mask, offset, grad_table);
}

#define HASH_ARGS                                                                                              \
    const float *x, int64_t n, const float *tensor, int features, int levels, const int32_t *resolutions,      \
        const int32_t *factors, int dense_levels, int64_t table_size, float *result
#define PASS_ARGS x, n, tensor, features, levels, resolutions, factors, dense_levels, table_size, result

/* One level of the n points: the eight-point loop where `eight`, else the one-point loop (the
 * reference it is tested against). */
static INLINE void level_pass(HASH_ARGS, int F, int l, int backward, int eight) {
    (void)features; /* F is it (a literal where it is 2) */
    uint32_t mask = (uint32_t)(table_size - 1), offset = (uint32_t)(l * table_size);
    int dense = l < dense_levels;
    const int32_t *factor = factors + 3 * l;
    if (backward && eight)
        backward_level8(x, n, tensor, F, levels, l, resolutions[l], factor, dense, mask, offset, result);
    else if (backward)
        backward_level(x, n, tensor, F, levels, l, resolutions[l], factor, dense, mask, offset, result);
    else if (eight)
        forward_level8(x, n, tensor, F, levels, l, resolutions[l], factor, dense, mask, offset, result);
    else
        forward_level(x, n, tensor, F, levels, l, resolutions[l], factor, dense, mask, offset, result);
}

/* Every level; F = 2 (every preset's) passed as a literal, so that the compiler specialises it. */
static INLINE void levels_pass(HASH_ARGS, int backward, int eight) {
    for (int l = 0; l < levels; l++) {
        if (features == 2)
            level_pass(PASS_ARGS, 2, l, backward, eight);
        else
            level_pass(PASS_ARGS, features, l, backward, eight);
    }
}

#if TWO_VERSIONS
/* AVX2 without fused multiply-adds (-ffp-contract=off): the same operations as the plain build. */
__attribute__((target("avx2"))) static void eight_point_pass_avx2(HASH_ARGS, int backward) {
    levels_pass(PASS_ARGS, backward, 1);
}
static int fast_machine(void) {
    static int known = -1;
    if (known < 0) {
        __builtin_cpu_init();
        known = __builtin_cpu_supports("avx2");
    }
    return known;
}
#endif

static void eight_point_pass(HASH_ARGS, int backward) {
#if TWO_VERSIONS
    if (fast_machine()) {
        eight_point_pass_avx2(PASS_ARGS, backward);
        return;
    }
#endif
    levels_pass(PASS_ARGS, backward, 1);
}

/* out (n, levels * features) from table. */
void hash_forward(HASH_ARGS) { eight_point_pass(PASS_ARGS, 0); }

/* grad (n, levels * features) scattered into grad_table (zero on entry, or holding what the
 * gradients are added to). */
void hash_backward(HASH_ARGS) { eight_point_pass(PASS_ARGS, 1); }

/* The one-point loops: the reference the eight-point loops are tested against (the same bits). */
void hash_forward_reference(HASH_ARGS) { levels_pass(PASS_ARGS, 0, 0); }

void hash_backward_reference(HASH_ARGS) { levels_pass(PASS_ARGS, 1, 0); }
