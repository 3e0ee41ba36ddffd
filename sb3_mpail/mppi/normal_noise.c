/*
 * torch.randn's CPU float32 draws, bit for bit, in a fraction of the time. torch draws a Mersenne Twister uniform per
 * element through a function call, on one thread (1.9 of the 2.2 ms of 655k normals, the sampling noise of one
 * planning iteration at 64 envs), then turns every block of 16 uniforms into normals by Box-Muller on 8-float
 * vectors. Here the twist and the tempering are plain loops the compiler vectorises, and the blocks of 16 are split
 * between torch's OpenMP threads.
 *
 * The stream is the generator's own: its state (torch.Generator.get_state()) comes in and goes back advanced exactly
 * as torch.randn leaves it. Box-Muller follows torch's AVX2 kernel (normal_fill_AVX2 in aten/src/ATen/native/cpu, with
 * Cephes' log and sincos polynomials as in Pommier's sse_mathfun and Garberoglio's avx_mathfun): the same operations
 * in the same order, with fused multiply-adds exactly where torch's build contracts them. This file is therefore
 * compiled with -ffp-contract=off, so that the compiler adds no others. native.py compares the draws with torch's
 * before first use and keeps torch.randn if they differ.
 */
#include <omp.h>
#include <stdint.h>
#include <string.h>

#define STATE_WORDS 624
#define SHIFT 397
#define BOX_MULLER_BLOCK 16
#define MIN_BLOCKS_PER_THREAD 1024 /* 16k floats: below this, another thread costs more than it saves */

/* The head of torch's CPU generator state (CPUGeneratorImplStateLegacy): the twister's words, widened to 64 bits, and
 * its position. left counts the draws until the next twist, plus one; next indexes the next word. */
struct torch_generator_state {
    uint64_t seed;
    int32_t left, seeded;
    uint64_t next;
    uint64_t words[STATE_WORDS];
};

struct twister {
    uint32_t words[STATE_WORDS];
    long left, next;
};

static inline uint32_t twisted(uint32_t word, uint32_t next_word) {
    uint32_t joined = (word & 0x80000000u) | (next_word & 0x7fffffffu);
    return (joined >> 1) ^ ((next_word & 1u) ? 0x9908b0dfu : 0u);
}

static void twist(uint32_t *words) {
    int i;
    for (i = 0; i < STATE_WORDS - SHIFT; i++)
        words[i] = words[i + SHIFT] ^ twisted(words[i], words[i + 1]);
    for (; i < STATE_WORDS - 1; i++)
        words[i] = words[i + SHIFT - STATE_WORDS] ^ twisted(words[i], words[i + 1]);
    words[STATE_WORDS - 1] = words[SHIFT - 1] ^ twisted(words[STATE_WORDS - 1], words[0]);
}

/* count uniforms in [0, 1) as torch draws them for floats: the tempered word's low 24 bits times 2^-24 */
static void draw_uniforms(struct twister *twister, float *out, long count) {
    while (count > 0) {
        if (twister->left == 1) {
            twist(twister->words);
            twister->left = STATE_WORDS + 1;
            twister->next = 0;
        }
        long drawn = twister->left - 1 < count ? twister->left - 1 : count;
        const uint32_t *words = twister->words + twister->next;
        for (long i = 0; i < drawn; i++) {
            uint32_t word = words[i];
            word ^= word >> 11;
            word ^= (word << 7) & 0x9d2c5680u;
            word ^= (word << 15) & 0xefc60000u;
            word ^= word >> 18;
            out[i] = (float)(word & 0xffffffu) * (1.0f / 16777216.0f);
        }
        twister->next += drawn;
        twister->left -= drawn;
        out += drawn;
        count -= drawn;
    }
}

#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>

static inline __m256 splat(float value) { return _mm256_set1_ps(value); }

static inline __m256 splat_bits(int bits) { return _mm256_castsi256_ps(_mm256_set1_epi32(bits)); }

/* natural logarithm of x in [2^-24, 1] (Cephes' logf; torch's also clamps subnormals and gives NaN below 0, which
 * these inputs never are) */
static inline __m256 cephes_log(__m256 x) {
    const __m256 one = splat(1.0f);
    __m256i exponent = _mm256_sub_epi32(_mm256_srli_epi32(_mm256_castps_si256(x), 23), _mm256_set1_epi32(0x7f));
    x = _mm256_or_ps(_mm256_and_ps(x, splat_bits(~0x7f800000)), splat(0.5f)); /* the mantissa, in [0.5, 1) */
    __m256 e = _mm256_add_ps(_mm256_cvtepi32_ps(exponent), one);
    /* below sqrt(1/2): e - 1 and 2x - 1, else x - 1 */
    __m256 below = _mm256_cmp_ps(x, splat(0.707106781186547524f), _CMP_LT_OS);
    __m256 doubled = _mm256_and_ps(x, below);
    x = _mm256_sub_ps(x, one);
    e = _mm256_sub_ps(e, _mm256_and_ps(one, below));
    x = _mm256_add_ps(x, doubled);
    __m256 squared = _mm256_mul_ps(x, x);
    __m256 y = splat(7.0376836292E-2f);
    y = _mm256_fmadd_ps(y, x, splat(-1.1514610310E-1f));
    y = _mm256_fmadd_ps(y, x, splat(1.1676998740E-1f));
    y = _mm256_fmadd_ps(y, x, splat(-1.2420140846E-1f));
    y = _mm256_fmadd_ps(y, x, splat(1.4249322787E-1f));
    y = _mm256_fmadd_ps(y, x, splat(-1.6668057665E-1f));
    y = _mm256_fmadd_ps(y, x, splat(2.0000714765E-1f));
    y = _mm256_fmadd_ps(y, x, splat(-2.4999993993E-1f));
    y = _mm256_fmadd_ps(y, x, splat(3.3333331174E-1f));
    y = _mm256_mul_ps(y, x);
    y = _mm256_fmadd_ps(y, squared, _mm256_mul_ps(e, splat(-2.12194440e-4f)));
    y = _mm256_fnmadd_ps(squared, splat(0.5f), y);
    return _mm256_fmadd_ps(e, splat(0.693359375f), _mm256_add_ps(x, y));
}

/* sine and cosine of x in [0, 2 pi) (Cephes' sinf and cosf: reduced to [-pi/4, pi/4] by octant, then one of two
 * polynomials; torch's also takes negative x, by its absolute value and sign) */
static inline void cephes_sincos(__m256 x, __m256 *sine, __m256 *cosine) {
    __m256i octant = _mm256_cvttps_epi32(_mm256_mul_ps(x, splat(1.27323954473516f))); /* x * 4 / pi */
    octant = _mm256_and_si256(_mm256_add_epi32(octant, _mm256_set1_epi32(1)), _mm256_set1_epi32(~1));
    __m256 y = _mm256_cvtepi32_ps(octant);
    __m256i sine_flip = _mm256_slli_epi32(_mm256_and_si256(octant, _mm256_set1_epi32(4)), 29);
    __m256i cosine_flip = _mm256_slli_epi32(
        _mm256_andnot_si256(_mm256_sub_epi32(octant, _mm256_set1_epi32(2)), _mm256_set1_epi32(4)), 29);
    __m256 sine_is_cosine_polynomial = _mm256_castsi256_ps(
        _mm256_cmpeq_epi32(_mm256_and_si256(octant, _mm256_set1_epi32(2)), _mm256_setzero_si256()));
    /* x - y pi / 4 in three parts, for the precision of the reduction */
    x = _mm256_fmadd_ps(y, splat(-0.78515625f), x);
    x = _mm256_fmadd_ps(y, splat(-2.4187564849853515625e-4f), x);
    x = _mm256_fmadd_ps(y, splat(-3.77489497744594108e-8f), x);
    __m256 squared = _mm256_mul_ps(x, x);
    __m256 cosine_polynomial = splat(2.443315711809948E-005f);
    cosine_polynomial = _mm256_fmadd_ps(cosine_polynomial, squared, splat(-1.388731625493765E-003f));
    cosine_polynomial = _mm256_fmadd_ps(cosine_polynomial, squared, splat(4.166664568298827E-002f));
    cosine_polynomial = _mm256_mul_ps(cosine_polynomial, squared);
    cosine_polynomial = _mm256_fmsub_ps(cosine_polynomial, squared, _mm256_mul_ps(squared, splat(0.5f)));
    cosine_polynomial = _mm256_add_ps(cosine_polynomial, splat(1.0f));
    __m256 sine_polynomial = splat(-1.9515295891E-4f);
    sine_polynomial = _mm256_fmadd_ps(sine_polynomial, squared, splat(8.3321608736E-3f));
    sine_polynomial = _mm256_fmadd_ps(sine_polynomial, squared, splat(-1.6666654611E-1f));
    sine_polynomial = _mm256_mul_ps(sine_polynomial, squared);
    sine_polynomial = _mm256_fmadd_ps(sine_polynomial, x, x);
    /* each polynomial goes to the sine or the cosine, by octant; torch selects by masking, subtracting and adding */
    __m256 sine_part = _mm256_and_ps(sine_is_cosine_polynomial, sine_polynomial);
    __m256 cosine_part = _mm256_andnot_ps(sine_is_cosine_polynomial, cosine_polynomial);
    sine_polynomial = _mm256_sub_ps(sine_polynomial, sine_part);
    cosine_polynomial = _mm256_sub_ps(cosine_polynomial, cosine_part);
    *sine = _mm256_xor_ps(_mm256_add_ps(cosine_part, sine_part), _mm256_castsi256_ps(sine_flip));
    *cosine = _mm256_xor_ps(_mm256_add_ps(cosine_polynomial, sine_polynomial), _mm256_castsi256_ps(cosine_flip));
}

/* uniforms u (j) and v (j + 8) -> sqrt(-2 log(1 - u)) cos(2 pi v) and ... sin(2 pi v), in place; torch's last step,
 * a multiply-add by the standard deviation 1 and mean 0, is kept: it turns -0 into +0 */
static inline void box_muller(float *block) {
    __m256 u = _mm256_sub_ps(splat(1.0f), _mm256_loadu_ps(block));
    __m256 angle = _mm256_mul_ps(splat((float)(2.0 * 3.14159265358979323846)), _mm256_loadu_ps(block + 8));
    __m256 radius = _mm256_sqrt_ps(_mm256_mul_ps(splat(-2.0f), cephes_log(u)));
    __m256 sine, cosine;
    cephes_sincos(angle, &sine, &cosine);
    _mm256_storeu_ps(block, _mm256_fmadd_ps(_mm256_mul_ps(radius, cosine), splat(1.0f), splat(0.0f)));
    _mm256_storeu_ps(block + 8, _mm256_fmadd_ps(_mm256_mul_ps(radius, sine), splat(1.0f), splat(0.0f)));
}

/* out[0:size] = torch.randn(size, generator) for size >= 16, advancing state as torch does: size uniforms, Box-Muller
 * on each whole block of 16, then, if size is not a multiple of 16, 16 more uniforms for the last 16 values */
void standard_normal_fill(struct torch_generator_state *state, float *out, long size, int max_threads) {
    struct twister twister = {.left = state->left, .next = (long)state->next};
    for (int i = 0; i < STATE_WORDS; i++)
        twister.words[i] = (uint32_t)state->words[i];
    float tail[BOX_MULLER_BLOCK];
    draw_uniforms(&twister, out, size);
    if (size % BOX_MULLER_BLOCK != 0)
        draw_uniforms(&twister, tail, BOX_MULLER_BLOCK);
    long blocks = size / BOX_MULLER_BLOCK;
    long threads = blocks / MIN_BLOCKS_PER_THREAD;
    threads = threads < 1 ? 1 : threads > max_threads ? max_threads : threads;
#pragma omp parallel for num_threads((int)threads) schedule(static)
    for (long block = 0; block < blocks; block++)
        box_muller(out + block * BOX_MULLER_BLOCK);
    if (size % BOX_MULLER_BLOCK != 0) {
        box_muller(tail);
        memcpy(out + size - BOX_MULLER_BLOCK, tail, sizeof tail);
    }
    for (int i = 0; i < STATE_WORDS; i++)
        state->words[i] = twister.words[i];
    state->left = (int32_t)twister.left;
    state->next = (uint64_t)twister.next;
}
#endif
