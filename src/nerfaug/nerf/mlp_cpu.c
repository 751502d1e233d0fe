/* The fields' small ReLU MLPs (nerfaug.nerf.field.mlp: widths 1-64) forward and backward in one
 * pass over blocks of 64 points, for one CPU core (nerfaug/nerf/mlp_cpu.py says why and when).
 *
 * A block's activations are kept transposed, (width x 64), in buffers that stay in the core's
 * first caches; the forward can keep the hidden ones for the backward (`point_at_hidden`), which
 * otherwise computes them again. Arithmetic is on 8-float vectors (GCC/Clang vector extensions:
 * elementwise, so every lane is its own sum) over 8 points at a time.
 *
 * Determinism on every machine: built without -march, without -ffast-math and with
 * -ffp-contract=off (nerfaug.nerf.hash_cpu._FLAGS); every product-and-add is one fused
 * multiply-add (`fma8`) and every sum runs in an order written here: a layer's output over its
 * inputs in order, from zero, then the bias added; a parameter gradient per lane (points k, k + 8,
 * ... of a block, blocks in order), its 8 lanes added in lane order every BLOCKS_A_FLUSH blocks
 * and those sums added in double. So no result depends on the vector instructions the machine has.
 *
 * Shapes: x (n, dims[0]) row-major; layer l has weight (dims[l+1], dims[l]) row-major and bias
 * (dims[l+1]), a ReLU after every layer but the last; out (n, dims[layers]).
 */
#define _POSIX_C_SOURCE 200112L
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define BLOCK 64
#define LANES 8
#define VECTORS (BLOCK / LANES)
/* Parameter gradients are summed in float lanes over this many blocks, then added in double. */
#define BLOCKS_A_FLUSH 4

/* The entry points are built twice, for AVX2 with fused multiply-adds and for any machine, and
 * the first call picks one (`fast_machine`). Every product-and-add is one fused multiply-add
 * (`fma8`, one rounding) in both: on AVX2 machines the instruction, elsewhere the C library's
 * fmaf, which rounds the same (IEEE 754). So both compute the same bits; -ffp-contract=off keeps
 * the compiler from fusing any other operation. */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && !defined(NERFAUG_ONE_VERSION)
#define TWO_VERSIONS 1
#else
#define TWO_VERSIONS 0
#endif
#define INLINE inline __attribute__((always_inline))

typedef float v8 __attribute__((vector_size(32)));
typedef int32_t v8i __attribute__((vector_size(32)));

/* a * b + c, rounded once, lane by lane. */
static INLINE v8 fma8(v8 a, v8 b, v8 c) {
    v8 r;
    for (int k = 0; k < LANES; k++) r[k] = __builtin_fmaf(a[k], b[k], c[k]);
    return r;
}

static INLINE v8 splat(float value) {
    v8 v = {value, value, value, value, value, value, value, value};
    return v;
}

static INLINE int widest(int layers, const int *dims) {
    int w = 0;
    for (int l = 0; l <= layers; l++) w = dims[l] > w ? dims[l] : w;
    return w;
}

/* rows of x from `start` (zero past n) -> aT (width x BLOCK) */
static INLINE void load_block(const float *x, int64_t n, int64_t start, int width, float *aT) {
    int64_t rows = n - start < BLOCK ? n - start : BLOCK;
    for (int64_t r = 0; r < rows; r++) {
        const float *row = x + (start + r) * width;
        for (int i = 0; i < width; i++) aT[i * BLOCK + r] = row[i];
    }
    for (int64_t r = rows; r < BLOCK; r++)
        for (int i = 0; i < width; i++) aT[i * BLOCK + r] = 0.0f;
}

/* aT (width x BLOCK) -> rows of y from `start`, those below n */
static INLINE void store_block(const float *aT, int64_t n, int64_t start, int width, float *y) {
    int64_t rows = n - start < BLOCK ? n - start : BLOCK;
    for (int64_t r = 0; r < rows; r++) {
        float *row = y + (start + r) * width;
        for (int i = 0; i < width; i++) row[i] = aT[i * BLOCK + r];
    }
}

/* dstT[j] = sum over k in order of M[j * sj + k * sk] * srcT[k] (from zero, each term one fused
 * multiply-add), for j < nj: the products of a layer, forward (M = W, sj = in, sk = 1) or backward
 * (M = W transposed: sj = 1, sk = in). Four outputs and 16 points at a time, so that each vector
 * of srcT loaded serves four multiply-adds; no sum's order depends on that. */
static INLINE void weighted_sums(const float *M, int nj, int nk, int sj, int sk, const float *srcT, float *dstT) {
    const v8 zero = splat(0.0f);
    int j = 0;
    for (; j + 4 <= nj; j += 4) {
        for (int q = 0; q < VECTORS; q += 2) {
            v8 a00 = zero, a01 = zero, a10 = zero, a11 = zero, a20 = zero, a21 = zero, a30 = zero, a31 = zero;
            for (int k = 0; k < nk; k++) {
                const v8 *src = (const v8 *)(srcT + k * BLOCK) + q;
                const v8 s0 = src[0], s1 = src[1];
                const float *m = M + j * sj + k * sk;
                v8 w = splat(m[0]);
                a00 = fma8(w, s0, a00);
                a01 = fma8(w, s1, a01);
                w = splat(m[sj]);
                a10 = fma8(w, s0, a10);
                a11 = fma8(w, s1, a11);
                w = splat(m[2 * sj]);
                a20 = fma8(w, s0, a20);
                a21 = fma8(w, s1, a21);
                w = splat(m[3 * sj]);
                a30 = fma8(w, s0, a30);
                a31 = fma8(w, s1, a31);
            }
            v8 *dst = (v8 *)(dstT + j * BLOCK) + q;
            dst[0] = a00;
            dst[1] = a01;
            dst[VECTORS] = a10;
            dst[VECTORS + 1] = a11;
            dst[2 * VECTORS] = a20;
            dst[2 * VECTORS + 1] = a21;
            dst[3 * VECTORS] = a30;
            dst[3 * VECTORS + 1] = a31;
        }
    }
    for (; j < nj; j++) {
        for (int q = 0; q < VECTORS; q += 2) {
            v8 a0 = zero, a1 = zero;
            for (int k = 0; k < nk; k++) {
                const v8 *src = (const v8 *)(srcT + k * BLOCK) + q;
                const v8 w = splat(M[j * sj + k * sk]);
                a0 = fma8(w, src[0], a0);
                a1 = fma8(w, src[1], a1);
            }
            v8 *dst = (v8 *)(dstT + j * BLOCK) + q;
            dst[0] = a0;
            dst[1] = a1;
        }
    }
}

/* yT[o] = (sum_i W[o][i] aT[i]) + b[o], then ReLU where `relu`. */
static INLINE void layer_forward(const float *W, const float *b, int in, int out, const float *aT, float *yT,
                                 int relu) {
    const v8 zero = splat(0.0f);
    weighted_sums(W, out, in, in, 1, aT, yT);
    for (int o = 0; o < out; o++) {
        const v8 bias = splat(b[o]);
        v8 *y = (v8 *)(yT + o * BLOCK);
        for (int v = 0; v < VECTORS; v++) {
            v8 value = y[v] + bias;
            /* value where not below zero (NaN stays NaN, as torch.relu) */
            y[v] = relu ? (v8)((v8i)value & ~(v8i)(value < zero)) : value;
        }
    }
}

/* gT_in[i] = sum_o W[o][i] gT[o] (o in order), through the ReLU whose outputs are aT (where
 * `through_relu`): zero where aT[i] <= 0, as torch's threshold_backward. */
static INLINE void layer_input_gradient(const float *W, int in, int out, const float *gT, const float *aT,
                                        float *gT_in, int through_relu) {
    const v8 zero = splat(0.0f);
    weighted_sums(W, in, out, 1, in, gT, gT_in);
    if (!through_relu) return;
    for (int i = 0; i < in; i++) {
        v8 *dst = (v8 *)(gT_in + i * BLOCK);
        const v8 *a = (const v8 *)(aT + i * BLOCK);
        for (int v = 0; v < VECTORS; v++) dst[v] = (v8)((v8i)dst[v] & (v8i)(a[v] > zero));
    }
}

/* lanes[o][i] += g[o] * a[i] over the block's 8 vectors (in order), lanes[out][...] likewise of
 * g[o]: the weight's (out x in), then the bias's (out) gradient lanes. Four inputs at a time, so
 * that each vector of g loaded serves four multiply-adds. */
static INLINE void layer_gradient_lanes(const float *gT, const float *aT, int in, int out, v8 *lanes) {
    for (int o = 0; o < out; o++) {
        const v8 *g = (const v8 *)(gT + o * BLOCK);
        v8 *l = lanes + (size_t)o * in;
        int i = 0;
        for (; i + 4 <= in; i += 4) {
            const v8 *a0 = (const v8 *)(aT + i * BLOCK), *a1 = a0 + VECTORS, *a2 = a1 + VECTORS, *a3 = a2 + VECTORS;
            v8 t0 = l[i], t1 = l[i + 1], t2 = l[i + 2], t3 = l[i + 3];
            for (int v = 0; v < VECTORS; v++) {
                const v8 gv = g[v];
                t0 = fma8(gv, a0[v], t0);
                t1 = fma8(gv, a1[v], t1);
                t2 = fma8(gv, a2[v], t2);
                t3 = fma8(gv, a3[v], t3);
            }
            l[i] = t0;
            l[i + 1] = t1;
            l[i + 2] = t2;
            l[i + 3] = t3;
        }
        for (; i < in; i++) {
            const v8 *a = (const v8 *)(aT + i * BLOCK);
            v8 t = l[i];
            for (int v = 0; v < VECTORS; v++) t = fma8(g[v], a[v], t);
            l[i] = t;
        }
        v8 t = lanes[out * in + o];
        for (int v = 0; v < VECTORS; v++) t += g[v];
        lanes[out * in + o] = t;
    }
}

/* sums[p] += lanes[p]'s 8 lanes added in lane order, for p < count; the lanes zeroed. */
static INLINE void flush_lanes(v8 *lanes, double *sums, size_t count) {
    for (size_t p = 0; p < count; p++) {
        float s = lanes[p][0];
        for (int k = 1; k < LANES; k++) s += lanes[p][k];
        sums[p] += (double)s;
        lanes[p] = splat(0.0f);
    }
}

/* All layers of a block: acts[l] (dims[l] x BLOCK) for l = 1..layers from acts[0]. */
static INLINE void block_forward(int layers, const int *dims, const float *const *weights,
                                 const float *const *biases, float **acts) {
    for (int l = 0; l < layers; l++)
        layer_forward(weights[l], biases[l], dims[l], dims[l + 1], acts[l], acts[l + 1], l + 1 < layers);
}

/* acts[0..layers] (activations, width x BLOCK) and two gradient blocks after them, in one
 * 32-byte aligned allocation (*storage, to free); NULL where memory could not be had. */
static float **block_buffers(int layers, const int *dims, float **storage) {
    size_t each = (size_t)widest(layers, dims) * BLOCK;
    float **acts = malloc(sizeof(float *) * (size_t)(layers + 3));
    void *memory = NULL;
    if (acts == NULL || posix_memalign(&memory, 32, sizeof(float) * (size_t)(layers + 3) * each) != 0) {
        free(acts);
        return NULL;
    }
    *storage = memory;
    for (int l = 0; l < layers + 3; l++) acts[l] = *storage + (size_t)l * each;
    return acts;
}

/* Where `hidden` is given (not NULL), a block's hidden activations live there: block b's layer
 * l (1 <= l < layers) at hidden + (b * H + dims[1] + ... + dims[l - 1]) * BLOCK floats, H the sum
 * of the hidden widths. The forward writes them, so that the backward reads them instead of
 * computing them again. */
static INLINE void point_at_hidden(float *hidden, int64_t block, int layers, const int *dims, float **acts) {
    int64_t widths = 0;
    for (int l = 1; l < layers; l++) widths += dims[l];
    float *at = hidden + block * widths * BLOCK;
    for (int l = 1; l < layers; l++) {
        acts[l] = at;
        at += (int64_t)dims[l] * BLOCK;
    }
}

static INLINE int forward_body(const float *x, int64_t n, int layers, const int *dims, const float *const *weights,
                               const float *const *biases, float *out, float *hidden) {
    float *storage;
    float **acts = block_buffers(layers, dims, &storage);
    if (acts == NULL) return 1;
    int64_t block = 0;
    for (int64_t start = 0; start < n; start += BLOCK, block++) {
        load_block(x, n, start, dims[0], acts[0]);
        if (hidden != NULL) point_at_hidden(hidden, block, layers, dims, acts);
        block_forward(layers, dims, weights, biases, acts);
        store_block(acts[layers], n, start, dims[layers], out);
    }
    free(acts);
    free(storage);
    return 0;
}

static INLINE int backward_body(const float *x, int64_t n, int layers, const int *dims, const float *const *weights,
                                const float *const *biases, const float *hidden, const float *grad_out, float *grad_x,
                                float *const *grad_weights, float *const *grad_biases) {
    size_t total = 0;
    for (int l = 0; l < layers; l++) total += (size_t)dims[l + 1] * (size_t)(dims[l] + 1);
    float *storage;
    float **acts = block_buffers(layers, dims, &storage);
    double *sums = calloc(total + 1, sizeof(double));
    void *lane_memory = NULL;
    if (acts == NULL || sums == NULL || posix_memalign(&lane_memory, 32, sizeof(v8) * (total + 1)) != 0) {
        if (acts != NULL) {
            free(acts);
            free(storage);
        }
        free(sums);
        return 1;
    }
    v8 *lanes = lane_memory;
    for (size_t p = 0; p < total; p++) lanes[p] = splat(0.0f);
    float *g = acts[layers + 1], *g_in = acts[layers + 2];
    int64_t block = 0;
    for (int64_t start = 0; start < n; start += BLOCK, block++) {
        load_block(x, n, start, dims[0], acts[0]);
        if (hidden != NULL)
            point_at_hidden((float *)hidden, block, layers, dims, acts);
        else
            block_forward(layers, dims, weights, biases, acts);
        load_block(grad_out, n, start, dims[layers], g);
        v8 *lane = lanes;
        for (int l = layers - 1; l >= 0; l--) {
            const int in = dims[l], out = dims[l + 1];
            layer_gradient_lanes(g, acts[l], in, out, lane);
            lane += (size_t)out * (size_t)(in + 1);
            if (l == 0 && grad_x == NULL) break;
            layer_input_gradient(weights[l], in, out, g, acts[l], g_in, l > 0);
            float *swap = g;
            g = g_in;
            g_in = swap;
        }
        if (grad_x != NULL) store_block(g, n, start, dims[0], grad_x);
        if ((block + 1) % BLOCKS_A_FLUSH == 0 || start + BLOCK >= n) flush_lanes(lanes, sums, total);
    }
    double *s = sums;
    for (int l = layers - 1; l >= 0; l--) {
        const int in = dims[l], out = dims[l + 1];
        for (int k = 0; k < out * in; k++) grad_weights[l][k] = (float)s[k];
        for (int o = 0; o < out; o++) grad_biases[l][o] = (float)s[out * in + o];
        s += (size_t)out * (size_t)(in + 1);
    }
    free(lane_memory);
    free(sums);
    free(acts);
    free(storage);
    return 0;
}

#define FORWARD_ARGS                                                                                    \
    const float *x, int64_t n, int layers, const int *dims, const float *const *weights, const float *const *biases, \
        float *out, float *hidden
#define BACKWARD_ARGS                                                                                   \
    const float *x, int64_t n, int layers, const int *dims, const float *const *weights, const float *const *biases, \
        const float *hidden, const float *grad_out, float *grad_x, float *const *grad_weights, float *const *grad_biases

#if TWO_VERSIONS
__attribute__((target("avx2,fma"))) static int forward_fast(FORWARD_ARGS) {
    return forward_body(x, n, layers, dims, weights, biases, out, hidden);
}
__attribute__((target("avx2,fma"))) static int backward_fast(BACKWARD_ARGS) {
    return backward_body(x, n, layers, dims, weights, biases, hidden, grad_out, grad_x, grad_weights, grad_biases);
}
static int fast_machine(void) {
    static int known = -1;
    if (known < 0) {
        __builtin_cpu_init();
        known = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    }
    return known;
}
#endif

/* out, and the hidden activations into `hidden` where not NULL (`point_at_hidden`). Returns 0, or
 * 1 where memory for the block buffers could not be had (nothing written). */
int mlp_forward(FORWARD_ARGS) {
#if TWO_VERSIONS
    if (fast_machine()) return forward_fast(x, n, layers, dims, weights, biases, out, hidden);
#endif
    return forward_body(x, n, layers, dims, weights, biases, out, hidden);
}

/* Gradients of sum(out * grad_out): grad_x (NULL: not wanted) and every layer's weight and bias
 * gradient (written, not added to); the hidden activations read from `hidden` where the forward
 * kept them, else computed again (the same bits either way). Returns 0, or 1 where memory could not
 * be had (nothing written). */
int mlp_backward(BACKWARD_ARGS) {
#if TWO_VERSIONS
    if (fast_machine()) return backward_fast(x, n, layers, dims, weights, biases, hidden, grad_out, grad_x, grad_weights, grad_biases);
#endif
    return backward_body(x, n, layers, dims, weights, biases, hidden, grad_out, grad_x, grad_weights, grad_biases);
}
