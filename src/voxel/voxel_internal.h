/*
 * voxel_internal.h: what the voxelizer's files share (private to src/voxel/): the bit-packed set
 * and grid structures, the triangle source and destination of the triangle pass, and the small
 * helpers more than one file uses (`static inline`).
 *
 * Layout: a set is nx * ny columns along z, each `words` 64-bit words; bit k of word w of
 * column (x, y) is voxel z = 64 w + k; column index x + nx * y. Everything is computed in grid
 * coordinates g = (p - origin) / voxel_size (doubles, so voxel (i, j, k) is the unit box at
 * (i, j, k)); a vertex shared by two triangles maps to the same doubles in both. Every file of
 * src/voxel/ is compiled with -ffp-contract=off (CMakeLists.txt): the edge functions must give
 * exactly opposite values for a shared edge and the same bits on the vector and scalar paths.
 */
#ifndef NACRE_VOXEL_INTERNAL_H
#define NACRE_VOXEL_INTERNAL_H

#include "core/core.h"

#include <math.h>
#if defined(__AVX2__) || defined(__BMI2__)
#include <immintrin.h>
#endif
#include <string.h>

#define VOXEL_MAX_RES 4096u
#define VOXEL_MAX_LEVELS 16
#define VOXEL_PARALLEL_MIN 4096
#define VOXEL_CHUNK 1024 /* triangles (vertices) per scheduling unit of the triangle (bounds) pass */
#define VOXEL_BOUNDS_PARALLEL 65536
#define VOXEL_PRIVATE_WORDS 4        /* per-thread copies of the level-0 sets: at most this many words per triangle */
#define VOXEL_PRIVATE_MAX (1u << 18) /* and at most this many words (2 MiB) per thread */
#define VOXEL_PREFETCH_MIN 16384 /* vertices (192 KiB) below which the triangle pass does not prefetch */
#define VOXEL_PRE_RATE_MIN 46 /* of 64: the prefilter pays when about 70% of the triangles pass it */
#define VOXEL_MERGE_PARALLEL 32768 /* words of copies merged by all threads rather than one */

/* Branch-free min/max without libm's NaN rules (inputs are finite here): the libm calls cost
 * more than the rest of the per-triangle work. */
static inline double dmin(double a, double b) { return a < b ? a : b; }
static inline double dmax(double a, double b) { return a > b ? a : b; }
static inline float fmn(float a, float b) { return a < b ? a : b; }
static inline float fmx(float a, float b) { return a > b ? a : b; }

typedef struct bitset {
    uint32_t dims[3];
    uint32_t words; /* per column */
    uint64_t *surface, *solid;
    bool shared; /* other threads write the same words: atomic read-modify-writes */
} bitset;

struct nacre_voxel_grid {
    nacre_context *ctx;
    float origin[3];
    float voxel_size;
    uint32_t levels;
    bitset level[VOXEL_MAX_LEVELS];
    size_t cap[VOXEL_MAX_LEVELS]; /* words allocated for each of surface and solid, per level */
    uint64_t *px, *py;            /* ROBUST scratch: x and y parities (level-0 layout), kept across updates */
    size_t cap_px, cap_py;        /* words allocated in px, py */
    uint64_t *priv;               /* per-thread level-0 sets of a small grid (nc_voxel_triangle_pass), kept */
    size_t cap_priv;
};

/* Set bits m of *w; a locked RMW only when other threads write the same set. */
static inline void bits_or(bool shared, uint64_t *w, uint64_t m)
{
    if (!shared) {
        *w |= m;
        return;
    }
    /* Reading first skips the locked RMW when the bits are already there (common on dense meshes). */
    if ((__atomic_load_n(w, __ATOMIC_RELAXED) & m) != m)
        __atomic_fetch_or(w, m, __ATOMIC_RELAXED);
}

static inline void bits_xor(bool shared, uint64_t *w, uint64_t m)
{
    if (shared)
        __atomic_fetch_xor(w, m, __ATOMIC_RELAXED);
    else
        *w ^= m;
}

typedef struct tri_source {
    const float *pos;
    const uint32_t *idx;
    double origin[3], inv_h;
    bool all_finite; /* no vertex is NaN or infinite: skip the per-corner checks */
    float margin;    /* of the float prefilter (prefilter8), grid units; 0: no prefilter */
} tri_source;

/* Grid coordinates of triangle t and its normal (e1 x e2); 1 if a vertex is not finite, 2 if
 * the area is zero, else 0. */
static inline int load_triangle(const tri_source *s, size_t t, double v[3][3], double n[3])
{
    for (int k = 0; k < 3; k++) {
        const float *p = s->pos + 3 * (size_t)s->idx[3 * t + (size_t)k];
        if (!s->all_finite && (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2])))
            return 1;
        for (int a = 0; a < 3; a++)
            v[k][a] = ((double)p[a] - s->origin[a]) * s->inv_h;
    }
    double e1[3], e2[3];
    for (int a = 0; a < 3; a++) {
        e1[a] = v[1][a] - v[0][a];
        e2[a] = v[2][a] - v[0][a];
    }
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
    return n[0] == 0 && n[1] == 0 && n[2] == 0 ? 2 : 0;
}

/* Where a triangle's bits go: level 0 and, for ROBUST, the x and y toggle sets (NULL otherwise),
 * laid out like the solid set; filled in the same triangle pass as the surface and z parity (the
 * XOR toggles commute, so the result is the same as in passes of their own). */
typedef struct tri_out {
    const bitset *b;
    uint64_t *px, *py;
} tri_out;

typedef struct tri_counts {
    uint32_t degenerate, nonfinite, bad_index;
} tri_counts;

static inline size_t bitset_words(const bitset *b)
{
    return (size_t)b->dims[0] * b->dims[1] * b->words;
}

/* voxel.c */
nacre_result nc_voxel_bitset_alloc(nacre_context *ctx, nacre_voxel_grid *g, uint32_t l, const uint32_t dims[3]);

/* surface.c: the triangle pass over the whole mesh into level 0 (surface bits and parity
 * toggles); fills *total. Fails only when out of memory. */
nacre_result nc_voxel_triangle_pass(nacre_context *ctx, nacre_voxel_grid *g, const tri_out *dst,
                                    const tri_source *src, size_t nt, uint32_t nv, int threads, tri_counts *total);

/* solid.c */
void nc_voxel_parity_triangle(uint64_t *flip, const bitset *bs, const double v[3][3], const double n[3], int a,
                              int b, int c);
void nc_voxel_prefix_xor(uint64_t *flip, size_t columns, uint32_t nc, uint32_t words, int threads);
void nc_voxel_robust_solid(uint64_t *px, uint64_t *py, bitset *b, int threads);

/* pyramid.c */
nacre_result nc_voxel_pyramid(nacre_context *ctx, nacre_voxel_grid *g, int threads);

#endif /* NACRE_VOXEL_INTERNAL_H */
