/*
 * The planner's MLP costs in one pass per block of rows: every layer of a small MLP for BLOCK rows at once, the
 * activations of a block kept in L1-sized scratch arrays, so no layer's output ever goes to memory (the torch path
 * writes and re-reads every layer's output, and adds the bias and activation in passes of their own).
 *
 * Rows are vectorised: a block's activations are stored feature by feature, BLOCK rows each, and every multiply-add
 * takes one weight against the vector of BLOCK rows. Each row is computed in the same order whatever the block, the
 * column range or the number of threads, so results do not depend on how the work is split.
 *
 * Inputs a roll-out holds at their initial values (the bicycle's height, roll, pitch, ...) need not be read: the
 * caller folds their first-layer terms into a bias per env, and the kernel multiplies only the inputs that move.
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
#define MAX_MEMBERS 16 /* members of an ensemble the kernel takes */

typedef float vector __attribute__((vector_size(LANES * sizeof(float))));
typedef int mask __attribute__((vector_size(LANES * sizeof(int))));

enum { ACTIVATION_NONE = 0, ACTIVATION_RELU = 1, ACTIVATION_LEAKY_RELU = 2, ACTIVATION_TANH = 3 };
/* what each output becomes before it is marked up: itself (LINEAR; a single MLP's last bias is then left to the
 * caller, who adds it to the sum), softplus(y) (SOFTPLUS) or log 2 - softplus(-y) (CAPPED), y the output with its
 * bias: the learned reward forms of sb3_mpail/mppi/reward_forms.py */
enum { FORM_LINEAR = 0, FORM_SOFTPLUS = 1, FORM_CAPPED = 2 };

/* The MLP: layer l maps widths[l] inputs to widths[l + 1] outputs (widths[n_layers] == 1, every width <= MAX_WIDTH)
 * with weights[l], row-major (widths[l], widths[l + 1]), then activations[l] (slopes[l]: a leaky ReLU's). The last
 * layer's bias is left to the caller. */
struct mlp {
    int n_layers;
    const int *widths;
    const float *const *weights;
    const float *const *biases;
    const int *activations;
    const float *slopes;
};

/* The MLP's inputs: x(t, c) = [s(t, c), s(t + 1, c)] when pairs, else s(t, c), for steps t and columns c, feature f of
 * s(t, c) at states[f * feature_stride + t * time_stride + c * column_stride]. Only the n_read inputs read[] are read
 * (read NULL: all of them). The others are constant within each group of group_columns consecutive columns: their
 * first-layer terms are in group_biases, (groups, widths[1]), which replace the first layer's bias (NULL: keep it). */
struct inputs {
    const float *states;
    long feature_stride, time_stride, column_stride;
    int state_dim, pairs, steps;
    long columns;
    int n_read;
    const int *read;
    const float *group_biases;
    long group_columns;
};

/* One layer for a block: outputs h_u = activation(bias_u + sum_k weight[read[k]][u] * input[k]) for u < n_out */
struct layer {
    const float *input;
    int n_in;
    const int *read;       /* the weight rows of the inputs, NULL: 0 .. n_in - 1 */
    const float *weight;   /* row-major (inputs, n_out): a pass's weights for one input are adjacent */
    int n_out;
    const float *bias;     /* (n_out,), NULL: none */
    const float *row_bias; /* (n_out, BLOCK), a bias per row instead of bias, NULL: none */
    int activation;
    float slope;
    float *output;            /* (n_out, BLOCK) */
    const float *next_weight; /* not NULL when the next layer is the single output unit: (n_out,), see dense_units */
};

static inline vector load(const float *source) { return *(const vector *)source; }
static inline void store(float *target, vector value) { *(vector *)target = value; }
static inline vector splat(float value) {
    vector zero = {0};
    return zero + value;
}

static inline vector activate(vector values, int activation, float slope) {
    vector zero = {0};
    mask positive = values > zero;
    if (activation == ACTIVATION_RELU) return (vector)((mask)values & positive);
    if (activation == ACTIVATION_LEAKY_RELU)
        return (vector)(((mask)values & positive) | ((mask)(values * slope) & ~positive));
    if (activation == ACTIVATION_TANH)
        for (int i = 0; i < LANES; i++) values[i] = tanhf(values[i]);
    return values;
}

/*
 * Output units j .. j + count - 1 of a layer for a block, stored in its output, or, when the next layer is the single
 * output unit, never stored: folded into that unit's sum, result += next_weight[u] * h_u. Inlined with a constant
 * count, so the accumulators stay in registers.
 */
static inline __attribute__((always_inline)) void dense_units(const struct layer *layer, int j, int count,
                                                              vector *result) {
    /* locals, so the compiler need not reload them after each store to the output */
    const float *input = layer->input, *weight = layer->weight, *bias = layer->bias, *row_bias = layer->row_bias;
    const float *next_weight = layer->next_weight;
    const int *read = layer->read;
    int n_in = layer->n_in, n_out = layer->n_out, activation = layer->activation;
    float slope = layer->slope, *output = layer->output;
    vector sums[GROUP][VECTORS];
    for (int u = 0; u < count; u++)
        for (int v = 0; v < VECTORS; v++)
            sums[u][v] = row_bias ? load(row_bias + (j + u) * BLOCK + v * LANES) : splat(bias ? bias[j + u] : 0.f);
    for (int k = 0; k < n_in; k++) {
        vector rows[VECTORS];
        for (int v = 0; v < VECTORS; v++) rows[v] = load(input + k * BLOCK + v * LANES);
        const float *weights = weight + (size_t)(read ? read[k] : k) * n_out + j;
        for (int u = 0; u < count; u++) {
            float w = weights[u];
            for (int v = 0; v < VECTORS; v++) sums[u][v] += w * rows[v];
        }
    }
    for (int u = 0; u < count; u++)
        for (int v = 0; v < VECTORS; v++) {
            vector unit = activate(sums[u][v], activation, slope);
            if (next_weight)
                result[v] += next_weight[j + u] * unit;
            else
                store(output + (j + u) * BLOCK + v * LANES, unit);
        }
}

/* a whole layer for a block, GROUP output units per pass over its inputs */
static void dense(const struct layer *layer, vector *result) {
    int j = 0;
    for (; j + GROUP <= layer->n_out; j += GROUP) dense_units(layer, j, GROUP, result);
    for (; j < layer->n_out; j++) dense_units(layer, j, 1, result);
}

int mlp_max_width(void) { return MAX_WIDTH; }

/* first[k * BLOCK + i] = input k read of column block + i at step t, zero past the range's end; offsets[k]: where
 * input k of column 0 at step 0 is */
static void gather_inputs(const struct inputs *in, const long *offsets, int t, long block, int n, float *first) {
    long column_stride = in->column_stride;
    for (int k = 0; k < in->n_read; k++) {
        const float *source = in->states + offsets[k] + t * in->time_stride + block * column_stride;
        float *row = first + k * BLOCK;
        int i = 0;
        if (column_stride == 1)
            for (; i < n; i++) row[i] = source[i];
        else
            for (; i < n; i++) row[i] = source[i * column_stride];
        for (; i < BLOCK; i++) row[i] = 0.f;
    }
}

/* row_bias[u * BLOCK + i] = the group bias of unit u for column block + i (padding rows take the block's first) */
static void gather_group_biases(const struct inputs *in, int width, long block, int n, float *row_bias) {
    for (int i = 0; i < BLOCK; i++) {
        const float *bias = in->group_biases + (block + (i < n ? i : 0)) / in->group_columns * width;
        for (int u = 0; u < width; u++) row_bias[u * BLOCK + i] = bias[u];
    }
}

/* z: the output unit's sum (its last bias left out) of mlp for one block whose first-layer inputs are in inputs;
 * first_row_bias replaces the first layer's bias where not NULL. The hidden layers ping-pong between a and b, so the
 * inputs stay as they are for the next member of an ensemble. */
static void block_output(const struct inputs *in, const struct mlp *mlp, const float *inputs,
                         const float *first_row_bias, float *a, float *b, vector *z) {
    for (int v = 0; v < VECTORS; v++) z[v] = splat(0.f);
    const float *input = inputs;
    float *output = a;
    for (int l = 0; l < mlp->n_layers; l++) {
        int last = l + 1 == mlp->n_layers, last_hidden = l + 2 == mlp->n_layers;
        struct layer layer = {
            .input = input,
            .n_in = l == 0 ? in->n_read : mlp->widths[l],
            .read = l == 0 ? in->read : NULL,
            .weight = mlp->weights[l],
            .n_out = mlp->widths[l + 1],
            .bias = last || (l == 0 && first_row_bias) ? NULL : mlp->biases[l],
            .row_bias = l == 0 ? first_row_bias : NULL,
            .activation = last ? ACTIVATION_NONE : mlp->activations[l],
            .slope = mlp->slopes[l],
            .output = output,
            .next_weight = last_hidden ? mlp->weights[l + 1] : NULL,
        };
        dense(&layer, z);
        if (last) /* a single layer: its output unit was stored, not folded */
            for (int v = 0; v < VECTORS; v++) z[v] = load(output + v * LANES);
        if (last_hidden) break;
        input = output;
        output = output == a ? b : a;
    }
}

/* The cost model of column_range: one MLP's output (with FORM_LINEAR its last bias left to the caller), or, with
 * n_members > 1, an ensemble's mean output less disagreement times the members' standard deviation (biases included),
 * then the form. */
struct members {
    int n_members;
    const struct mlp *mlps;
    const float *output_biases; /* (n_members,), read with n_members > 1 or a form other than FORM_LINEAR */
    float disagreement;
    int form;
};

/* torch's softplus (beta 1, threshold 20): the input itself above the threshold, where log1p(exp(x)) rounds to it */
static inline float softplus(float x) { return x > 20.f ? x : log1pf(expf(x)); }

/* outputs[i] = the form of outputs[i] + bias, for the rows of a block */
static void apply_form(int form, float bias, float *outputs) {
    const float log_2 = 0.693147180559945309f;
    for (int i = 0; i < BLOCK; i++) {
        float y = outputs[i] + bias;
        outputs[i] = form == FORM_SOFTPLUS ? softplus(y) : log_2 - softplus(-y);
    }
}

/* each row's mean - disagreement * std over the members' outputs z[k] (+ their output biases), as torch computes
 * them: the mean of the outputs, then the square root of the mean squared deviation from it */
static void combine_members(const struct members *members, const vector *z, float *combined) {
    int k_count = members->n_members;
    for (int v = 0; v < VECTORS; v++) {
        vector sum = {0};
        for (int k = 0; k < k_count; k++) sum += z[k * VECTORS + v] + members->output_biases[k];
        vector mean = sum / (float)k_count, squares = {0};
        for (int k = 0; k < k_count; k++) {
            vector deviation = z[k * VECTORS + v] + members->output_biases[k] - mean;
            squares += deviation * deviation;
        }
        vector variance = squares / (float)k_count;
        for (int i = 0; i < LANES; i++) combined[v * LANES + i] = mean[i] - members->disagreement * sqrtf(variance[i]);
    }
}

/* out[c] for columns c in [begin, end) of mlp_costs / ensemble_costs; out points at column begin */
static void column_range(const struct inputs *in, const struct members *members, const float *markups, long begin,
                         long end, float *out) {
    float first[MAX_WIDTH * BLOCK] __attribute__((aligned(64)));
    float a[MAX_WIDTH * BLOCK] __attribute__((aligned(64)));
    float b[MAX_WIDTH * BLOCK] __attribute__((aligned(64)));
    float row_bias[MAX_WIDTH * BLOCK] __attribute__((aligned(64)));
    vector z[MAX_MEMBERS * VECTORS];
    float combined[BLOCK] __attribute__((aligned(64)));
    long biased_group = -1; /* the group whose biases row_bias holds for every row, -1: none */
    long offsets[MAX_WIDTH];
    for (int k = 0; k < in->n_read; k++) {
        int input = in->read ? in->read[k] : k; /* feature input % state_dim of state t + input / state_dim */
        offsets[k] = (input % in->state_dim) * in->feature_stride + (input / in->state_dim) * in->time_stride;
    }
    /* time steps outermost: each block's inputs are the next BLOCK floats of every feature, a stream of reads */
    for (int t = 0; t < in->steps; t++) {
        for (long block = begin; block < end; block += BLOCK) {
            int n = end - block < BLOCK ? (int)(end - block) : BLOCK;
            gather_inputs(in, offsets, t, block, n, first);
            const float *first_row_bias = NULL;
            if (in->group_biases) {
                long group = block / in->group_columns, last_group = (block + n - 1) / in->group_columns;
                if (group != last_group || group != biased_group) {
                    gather_group_biases(in, members->mlps[0].widths[1], block, n, row_bias);
                    biased_group = group == last_group ? group : -1;
                }
                first_row_bias = row_bias;
            }
            for (int k = 0; k < members->n_members; k++)
                block_output(in, &members->mlps[k], first, first_row_bias, a, b, z + k * VECTORS);
            const float *outputs = (const float *)z;
            if (members->n_members > 1) {
                combine_members(members, z, combined);
                outputs = combined;
            }
            if (members->form != FORM_LINEAR) {
                if (outputs != combined)
                    for (int v = 0; v < VECTORS; v++) store(combined + v * LANES, z[v]);
                apply_form(members->form, members->n_members > 1 ? 0.f : members->output_biases[0], combined);
                outputs = combined;
            }
            float *totals = out + (block - begin);
            if (t == 0)
                for (int i = 0; i < n; i++) totals[i] = markups[0] * outputs[i];
            else
                for (int i = 0; i < n; i++) totals[i] += markups[t] * outputs[i];
        }
    }
}

/* column_range over columns c < in->columns, split into one contiguous range of whole blocks per thread, at most
 * max_threads (torch's count) */
static void member_costs(const struct inputs *in, const struct members *members, const float *markups, float *out,
                         int max_threads) {
    long threads = in->columns / MIN_COLUMNS_PER_THREAD;
    if (threads > max_threads) threads = max_threads;
    if (threads <= 1) {
        column_range(in, members, markups, 0, in->columns, out);
        return;
    }
    long n_blocks = (in->columns + BLOCK - 1) / BLOCK;
#pragma omp parallel num_threads(threads)
    {
        long count = omp_get_num_threads(), thread = omp_get_thread_num();
        long begin = n_blocks * thread / count * BLOCK, end = n_blocks * (thread + 1) / count * BLOCK;
        if (end > in->columns) end = in->columns;
        column_range(in, members, markups, begin, end, out + begin);
    }
}

/*
 * out[c] = sum_{t < steps} markups[t] * z(t, c) for columns c < in->columns, where z is the MLP's single output on the
 * inputs x(t, c): with FORM_LINEAR the output before the last layer's bias, else the form of the output plus
 * *output_bias.
 */
void mlp_costs(const struct inputs *in, const struct mlp *mlp, int form, const float *output_bias, const float *markups,
               float *out, int max_threads) {
    struct members single = {1, mlp, output_bias, 0.f, form};
    member_costs(in, &single, markups, out, max_threads);
}

int ensemble_max_members(void) { return MAX_MEMBERS; }

/*
 * out[c] = sum_{t < steps} markups[t] * e(t, c), where e is the form of the mean of n_members MLPs' outputs
 * z_k + output_biases[k] on the inputs x(t, c) less disagreement times their standard deviation (2 <= n_members <=
 * MAX_MEMBERS, MLPs of the same input size). Held inputs are not taken: in->read and in->group_biases must be NULL
 * (each member would need its own group biases).
 */
void ensemble_costs(const struct inputs *in, const struct mlp *mlps, int n_members, const float *output_biases,
                    float disagreement, int form, const float *markups, float *out, int max_threads) {
    struct members ensemble = {n_members, mlps, output_biases, disagreement, form};
    member_costs(in, &ensemble, markups, out, max_threads);
}
