/*
 * rng.h: the path tracer's random numbers: PCG32 (O'Neill 2014, "PCG: a family of simple fast
 * space-efficient statistically good algorithms for random number generation"), XSH-RR output,
 * 64-bit LCG state. Every independent unit of work (a slab chunk, a pixel in one pass) gets its
 * own stream, chosen by hashing its coordinates, so results never depend on which thread ran it.
 */
#ifndef NACRE_PATHTRACE_RNG_H
#define NACRE_PATHTRACE_RNG_H

#include <stdint.h>

typedef struct nc_rng {
    uint64_t state, inc;
} nc_rng;

/* splitmix64 finaliser: decorrelates consecutive seeds before they reach the LCG. */
static inline uint64_t nc_hash64(uint64_t x)
{
    x += 0x9e3779b97f4a7c15ull;
    x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
    x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
    return x ^ (x >> 31);
}

static inline uint32_t nc_rng_u32(nc_rng *r)
{
    uint64_t old = r->state;
    r->state = old * 6364136223846793005ull + r->inc;
    uint32_t xorshifted = (uint32_t)(((old >> 18u) ^ old) >> 27u);
    uint32_t rot = (uint32_t)(old >> 59u);
    return (xorshifted >> rot) | (xorshifted << ((-rot) & 31u));
}

/* Stream `stream` of generator `seed`: distinct streams use distinct LCG increments. */
static inline nc_rng nc_rng_make(uint64_t seed, uint64_t stream)
{
    nc_rng r;
    r.state = 0;
    r.inc = (nc_hash64(stream ^ 0x5851f42d4c957f2dull) << 1u) | 1u;
    nc_rng_u32(&r);
    r.state += nc_hash64(seed);
    nc_rng_u32(&r);
    return r;
}

/* Uniform in [0, 1) with 24 bits (never rounds up to 1.0f). */
static inline float nc_rng_float(nc_rng *r) { return (float)(nc_rng_u32(r) >> 8) * 0x1p-24f; }

/* Uniform in [0, 1) with 53 bits. */
static inline double nc_rng_double(nc_rng *r)
{
    uint64_t hi = nc_rng_u32(r), lo = nc_rng_u32(r);
    return (double)(((hi << 32) | lo) >> 11) * 0x1p-53;
}

#endif /* NACRE_PATHTRACE_RNG_H */
