/*
 * The planner's MLP costs in one pass per block of rows: every layer of a small MLP for BLOCK rows at once, the
 * activations of a block kept in two L1-sized scratch arrays, so no layer's output ever goes to memory (the torch path
 * writes and re-reads every layer's output, and adds the bias and activation in passes of their own).
 *
 * Rows are vectorised: a block's activations are stored feature by feature, BLOCK rows each, and every multiply-add
 * takes one weight against the vector of BLOCK rows. Each row is computed in the same order whatever the block, the
 * column range or the number of threads, so results do not depend on how the work is split.
 *
 * Built at run time by sb3_mpail/mppi/native.py with the machine's C compiler; plain C with GCC/Clang vector
 * extensions and OpenMP, linked to the OpenMP runtime torch has loaded so that the kernel runs on torch's own threads
 * (a second pool would compete with torch's, whose threads spin for a while after each parallel operator).
 */
#include <math.h>
#include <omp.h>
#include <stddef.h>

/* LANES: floats per vector register. GROUP: output units per pass over a layer's inputs, so GROUP * VECTORS
 * independent accumulators: 16 of AVX-512's 32 registers (10% faster than 8 on a Xeon), 8 of AVX2's 16 */
#ifdef __AVX512F__
#define LANES 16
#define GROUP 8
#else
#define LANES 8
#define GROUP 4
#endif
#define VECTORS 2
#define BLOCK (LANES * VECTORS)
#define MAX_WIDTH 256
#define MIN_COLUMNS_PER_THREAD 256 /* below this, another thread costs more than it saves */

typedef float vector __attribute__((vector_size(LANES * sizeof(float))));

enum { ACTIVATION_NONE = 0, ACTIVATION_RELU = 1, ACTIVATION_LEAKY_RELU = 2, ACTIVATION_TANH = 3 };

static inline vector load(const float *source) { return *(const vector *)source; }
static inline void store(float *target, vector value) { *(vector *)target = value; }
static inline vector splat(float value) {
    vector zero = {0};
    return zero + value;
}

/* output[j] = bias[j] + sum_k weight[j][k] * input[k] for a block; weight row-major (n_out, n_in), bias may be NULL */
static void dense(const float *input, int n_in, float *output, int n_out, const float *weight, const float *bias) {
    int j = 0;
    for (; j + GROUP <= n_out; j += GROUP) {
        vector sums[GROUP][VECTORS];
        for (int u = 0; u < GROUP; u++)
            for (int v = 0; v < VECTORS; v++) sums[u][v] = splat(bias ? bias[j + u] : 0.f);
        for (int k = 0; k < n_in; k++) {
            vector rows[VECTORS];
            for (int v = 0; v < VECTORS; v++) rows[v] = load(input + k * BLOCK + v * LANES);
            for (int u = 0; u < GROUP; u++) {
                float w = weight[(size_t)(j + u) * n_in + k];
                for (int v = 0; v < VECTORS; v++) sums[u][v] += w * rows[v];
            }
        }
        for (int u = 0; u < GROUP; u++)
            for (int v = 0; v < VECTORS; v++) store(output + (j + u) * BLOCK + v * LANES, sums[u][v]);
    }
    for (; j < n_out; j++) {
        vector sums[VECTORS];
        for (int v = 0; v < VECTORS; v++) sums[v] = splat(bias ? bias[j] : 0.f);
        for (int k = 0; k < n_in; k++) {
            float w = weight[(size_t)j * n_in + k];
            for (int v = 0; v < VECTORS; v++) sums[v] += w * load(input + k * BLOCK + v * LANES);
        }
        for (int v = 0; v < VECTORS; v++) store(output + j * BLOCK + v * LANES, sums[v]);
    }
}

static void activate(float *values, int width, int activation, float slope) {
    int count = width * BLOCK;
    if (activation == ACTIVATION_RELU) {
        for (int i = 0; i < count; i++) values[i] = values[i] > 0.f ? values[i] : 0.f;
    } else if (activation == ACTIVATION_LEAKY_RELU) {
        for (int i = 0; i < count; i++) values[i] = values[i] > 0.f ? values[i] : values[i] * slope;
    } else if (activation == ACTIVATION_TANH) {
        for (int i = 0; i < count; i++) values[i] = tanhf(values[i]);
    }
}

int mlp_max_width(void) { return MAX_WIDTH; }

/* out[c] for columns c in [begin, end) of mlp_costs; out points at column begin */
static void column_range(const float *states, long feature_stride, long time_stride, long column_stride, int state_dim,
                         int pairs, int steps, long begin, long end, int n_layers, const int *widths,
                         const float *const *weights, const float *const *biases, const int *activations,
                         const float *slopes, const float *markups, float *out) {
    float first[MAX_WIDTH * BLOCK] __attribute__((aligned(64)));
    float second[MAX_WIDTH * BLOCK] __attribute__((aligned(64)));
    int n_inputs = pairs ? 2 * state_dim : state_dim;
    /* time steps outermost: each block's inputs are the next BLOCK floats of every feature, a stream of reads */
    for (int t = 0; t < steps; t++) {
        for (long block = begin; block < end; block += BLOCK) {
            int n = end - block < BLOCK ? (int)(end - block) : BLOCK;
            for (int k = 0; k < n_inputs; k++) {
                const float *source = states + (k % state_dim) * feature_stride
                                      + (t + k / state_dim) * time_stride + block * column_stride;
                float *row = first + k * BLOCK;
                int i = 0;
                if (column_stride == 1)
                    for (; i < n; i++) row[i] = source[i];
                else
                    for (; i < n; i++) row[i] = source[i * column_stride];
                for (; i < BLOCK; i++) row[i] = 0.f;
            }
            float *input = first, *output = second;
            for (int layer = 0; layer < n_layers; layer++) {
                dense(input, widths[layer], output, widths[layer + 1], weights[layer], biases[layer]);
                activate(output, widths[layer + 1], activations[layer], slopes[layer]);
                float *swap = input;
                input = output;
                output = swap;
            }
            float *totals = out + (block - begin);
            if (t == 0)
                for (int i = 0; i < n; i++) totals[i] = markups[0] * input[i];
            else
                for (int i = 0; i < n; i++) totals[i] += markups[t] * input[i];
        }
    }
}

/*
 * out[c] = sum_{t < steps} markups[t] * z(t, c) for columns c < columns, where z is the MLP's single output (its last
 * layer's bias left out) on the input x(t, c) = [s(t, c), s(t + 1, c)] when pairs, else s(t, c), and feature f of
 * s(t, c) is states[f * feature_stride + t * time_stride + c * column_stride].
 * Layer l maps widths[l] inputs to widths[l + 1] outputs (widths[n_layers] == 1), every width <= MAX_WIDTH.
 * The columns are split into one contiguous range of whole blocks per thread, at most max_threads (torch's count).
 */
void mlp_costs(const float *states, long feature_stride, long time_stride, long column_stride, int state_dim,
               int pairs, int steps, long columns, int n_layers, const int *widths, const float *const *weights,
               const float *const *biases, const int *activations, const float *slopes, const float *markups,
               float *out, int max_threads) {
    long threads = columns / MIN_COLUMNS_PER_THREAD;
    if (threads > max_threads) threads = max_threads;
    if (threads <= 1) {
        column_range(states, feature_stride, time_stride, column_stride, state_dim, pairs, steps, 0, columns, n_layers,
                     widths, weights, biases, activations, slopes, markups, out);
        return;
    }
    long n_blocks = (columns + BLOCK - 1) / BLOCK;
#pragma omp parallel num_threads(threads)
    {
        long count = omp_get_num_threads(), thread = omp_get_thread_num();
        long begin = n_blocks * thread / count * BLOCK, end = n_blocks * (thread + 1) / count * BLOCK;
        if (end > columns) end = columns;
        column_range(states, feature_stride, time_stride, column_stride, state_dim, pairs, steps, begin, end, n_layers,
                     widths, weights, biases, activations, slopes, markups, out + begin);
    }
}
