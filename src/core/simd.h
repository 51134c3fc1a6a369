/*
 * simd.h: 8-lane float and int32 vectors for the per-pixel kernels of the shading passes (GCC and
 * Clang vector extensions: +, *, /, comparisons work lane-wise and compile to AVX with
 * -march=x86-64-v3, to plain code elsewhere).
 *
 * Why explicit vectors: a batch of pixels written as one loop per step keeps every intermediate
 * in a stack array, and the loads and stores between the steps were a large part of the
 * shading pass. Written per group of 8 lanes, the intermediates stay in registers.
 *
 * Conventions: comparisons give masks of -1 (true) or 0 per lane (nc_v8i); nc_v8_sel picks by
 * such a mask. Loads and stores are unaligned (memcpy). The operations are the scalar ones lane by
 * lane, in the same order, so a kernel written with them rounds exactly as its scalar form.
 */
#ifndef NACRE_SIMD_H
#define NACRE_SIMD_H

#include <math.h>
#include <stdint.h>
#include <string.h>
#ifdef __AVX__
#include <immintrin.h>
#endif

typedef float nc_v8f __attribute__((vector_size(32)));
typedef int32_t nc_v8i __attribute__((vector_size(32)));

static inline nc_v8f nc_v8_load(const float *p)
{
    nc_v8f v;
    memcpy(&v, p, sizeof(v));
    return v;
}

static inline void nc_v8_store(float *p, nc_v8f v) { memcpy(p, &v, sizeof(v)); }

/* Lanes 0-3 from lo, 4-7 from hi (two rows of a 2D array) */
static inline nc_v8f nc_v8_load2(const float *lo, const float *hi)
{
#ifdef __AVX__
    return (nc_v8f)_mm256_loadu2_m128(hi, lo);
#else
    float t[8];
    memcpy(t, lo, 4 * sizeof(float));
    memcpy(t + 4, hi, 4 * sizeof(float));
    return nc_v8_load(t);
#endif
}

static inline nc_v8i nc_v8i_load(const int32_t *p)
{
    nc_v8i v;
    memcpy(&v, p, sizeof(v));
    return v;
}

static inline void nc_v8i_store(int32_t *p, nc_v8i v) { memcpy(p, &v, sizeof(v)); }

static inline nc_v8f nc_v8_splat(float x) { return (nc_v8f){0} + x; }

/* m ? a : b per lane (m: -1 or 0) */
static inline nc_v8f nc_v8_sel(nc_v8i m, nc_v8f a, nc_v8f b)
{
#ifdef __AVX__
    return (nc_v8f)_mm256_blendv_ps((__m256)b, (__m256)a, (__m256)m); /* by the sign bit: same for -1 / 0 */
#else
    return (nc_v8f)((m & (nc_v8i)a) | (~m & (nc_v8i)b));
#endif
}

static inline nc_v8i nc_v8i_sel(nc_v8i m, nc_v8i a, nc_v8i b) { return (m & a) | (~m & b); }

/* Lanes 0 .. n - 1 set (n <= 8) */
static inline nc_v8i nc_v8_first(uint32_t n)
{
    const nc_v8i iota = {0, 1, 2, 3, 4, 5, 6, 7};
    return iota < (int32_t)n;
}

/* Bit l set where lane l of m is set */
/* base[idx] per lane. */
static inline nc_v8f nc_v8_gather(const float *base, nc_v8i idx)
{
#ifdef __AVX2__
    return (nc_v8f)_mm256_i32gather_ps(base, (__m256i)idx, 4);
#else
    nc_v8f r;
    for (int l = 0; l < 8; l++)
        r[l] = base[idx[l]];
    return r;
#endif
}

/* Round to the nearest integer (ties to even, as lrintf). */
static inline nc_v8i nc_v8_rint(nc_v8f x)
{
#ifdef __AVX__
    return (nc_v8i)_mm256_cvtps_epi32((__m256)x);
#else
    nc_v8i r;
    for (int l = 0; l < 8; l++)
        r[l] = (int32_t)lrintf(x[l]);
    return r;
#endif
}

static inline uint32_t nc_v8_bits(nc_v8i m)
{
#ifdef __AVX__
    return (uint32_t)_mm256_movemask_ps((__m256)m);
#else
    uint32_t bits = 0;
    for (int l = 0; l < 8; l++)
        bits |= m[l] ? 1u << l : 0u;
    return bits;
#endif
}

static inline nc_v8f nc_v8_floor(nc_v8f x)
{
#ifdef __AVX__
    return (nc_v8f)_mm256_floor_ps((__m256)x);
#else
    for (int l = 0; l < 8; l++)
        x[l] = floorf(x[l]);
    return x;
#endif
}

static inline nc_v8f nc_v8_sqrt(nc_v8f x)
{
#ifdef __AVX__
    return (nc_v8f)_mm256_sqrt_ps((__m256)x);
#else
    for (int l = 0; l < 8; l++)
        x[l] = sqrtf(x[l]);
    return x;
#endif
}

/* 1 / sqrt(x) for x > 0: the processor's estimate refined by one Newton step (relative error
 * about 2^-22), where a square root and a division would queue on the one divider; exact without
 * AVX. The estimate is the processor's own, so the last bits may differ between processors: for
 * kernels whose result is not compared bit for bit with a scalar form. */
static inline nc_v8f nc_v8_rsqrt(nc_v8f x)
{
#ifdef __AVX__
    nc_v8f r = (nc_v8f)_mm256_rsqrt_ps((__m256)x);
    return r * (1.5f - 0.5f * x * r * r);
#else
    return 1.0f / nc_v8_sqrt(x);
#endif
}

/* 1 / x for finite x != 0, as nc_v8_rsqrt: the estimate and one Newton step. */
static inline nc_v8f nc_v8_rcp(nc_v8f x)
{
#ifdef __AVX__
    nc_v8f r = (nc_v8f)_mm256_rcp_ps((__m256)x);
    return r * (2.0f - x * r);
#else
    return 1.0f / x;
#endif
}

/* 8 consecutive triples (x0 y0 z0 x1 ... z7, 24 words in a, b, c) as three 8-lane vectors x, y,
 * z (bit patterns: int32 or float words). With AVX2, two blends and one lane permutation each. */
static inline void nc_v8_deinterleave3(nc_v8i a, nc_v8i b, nc_v8i c, nc_v8i *x, nc_v8i *y, nc_v8i *z)
{
#ifdef __AVX2__
    const __m256i va = (__m256i)a, vb = (__m256i)b, vc = (__m256i)c;
    /* x_k sits in a at lanes 0 3 6, in b at 1 4 7, in c at 2 5 (y and z likewise, shifted) */
    *x = (nc_v8i)_mm256_permutevar8x32_epi32(_mm256_blend_epi32(_mm256_blend_epi32(va, vb, 0x92), vc, 0x24),
                                             _mm256_setr_epi32(0, 3, 6, 1, 4, 7, 2, 5));
    *y = (nc_v8i)_mm256_permutevar8x32_epi32(_mm256_blend_epi32(_mm256_blend_epi32(va, vb, 0x24), vc, 0x49),
                                             _mm256_setr_epi32(1, 4, 7, 2, 5, 0, 3, 6));
    *z = (nc_v8i)_mm256_permutevar8x32_epi32(_mm256_blend_epi32(_mm256_blend_epi32(va, vb, 0x49), vc, 0x92),
                                             _mm256_setr_epi32(2, 5, 0, 3, 6, 1, 4, 7));
#else
    int32_t w[24], t[3][8];
    memcpy(w, &a, 32);
    memcpy(w + 8, &b, 32);
    memcpy(w + 16, &c, 32);
    for (int k = 0; k < 8; k++)
        for (int q = 0; q < 3; q++)
            t[q][k] = w[3 * k + q];
    *x = nc_v8i_load(t[0]);
    *y = nc_v8i_load(t[1]);
    *z = nc_v8i_load(t[2]);
#endif
}

/* nc_v8_deinterleave3 undone: three 8-lane vectors x, y, z as 8 consecutive triples in a, b, c. */
static inline void nc_v8_interleave3(nc_v8i x, nc_v8i y, nc_v8i z, nc_v8i *a, nc_v8i *b, nc_v8i *c)
{
#ifdef __AVX2__
    const __m256i vx = (__m256i)x, vy = (__m256i)y, vz = (__m256i)z;
    /* a = x0 y0 z0 x1 y1 z1 x2 y2, b = z2 x3 y3 z3 x4 y4 z4 x5, c = y5 z5 x6 y6 z6 x7 y7 z7 */
    __m256i px = _mm256_permutevar8x32_epi32(vx, _mm256_setr_epi32(0, 3, 6, 1, 4, 7, 2, 5));
    __m256i py = _mm256_permutevar8x32_epi32(vy, _mm256_setr_epi32(5, 0, 3, 6, 1, 4, 7, 2));
    __m256i pz = _mm256_permutevar8x32_epi32(vz, _mm256_setr_epi32(2, 5, 0, 3, 6, 1, 4, 7));
    *a = (nc_v8i)_mm256_blend_epi32(_mm256_blend_epi32(px, py, 0x92), pz, 0x24);
    *b = (nc_v8i)_mm256_blend_epi32(_mm256_blend_epi32(px, py, 0x24), pz, 0x49);
    *c = (nc_v8i)_mm256_blend_epi32(_mm256_blend_epi32(px, py, 0x49), pz, 0x92);
#else
    int32_t w[24];
    for (int k = 0; k < 8; k++) {
        w[3 * k] = x[k];
        w[3 * k + 1] = y[k];
        w[3 * k + 2] = z[k];
    }
    *a = nc_v8i_load(w);
    *b = nc_v8i_load(w + 8);
    *c = nc_v8i_load(w + 16);
#endif
}

/* The sum of the 8 lanes, in a fixed order: ((0 + 4) + (1 + 5)) + ((2 + 6) + (3 + 7)) */
static inline float nc_v8_sum(nc_v8f x) { return ((x[0] + x[4]) + (x[1] + x[5])) + ((x[2] + x[6]) + (x[3] + x[7])); }

#endif /* NACRE_SIMD_H */
