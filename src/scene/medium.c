/*
 * medium.c: absorption and scattering coefficients of translucent materials at rest-pose points
 * (undeformed mesh coordinates, scene units; coefficients per scene unit). Evaluating at rest-pose
 * coordinates makes a heterogeneous pattern follow the object's deformation (Blanchard 2012,
 * section 5.2.3 and figure 5.11: scale and twist).
 *
 * Patterns (nacre_medium_pattern; medium 1 = the material's sigma_a/sigma_s, medium 2 = the
 * pattern's sigma_a2/sigma_s2):
 *   RANDOM_MIX  cubic cells of `cell_size`; a cell is medium 2 when an integer hash of (cell x,
 *               y, z, seed) falls below `fraction` (the seed's figures 5.8/5.9: two materials
 *               mixed at random);
 *   CHECKER     cell (x, y, z) is medium 2 when x + y + z is odd;
 *   NOISE       fractal value noise (`octaves`, feature size `cell_size`) gives w in [0, 1] and
 *               the coefficients blend linearly, (1 - w) * medium 1 + w * medium 2;
 *   VOLUME      a scene volume (trilinear, clamped at its boundary) gives a density d >= 0 and
 *               the coefficients are d * medium 1.
 * A point with a non-finite coordinate gets medium 1 (density 1 for VOLUME).
 *
 * Everything is a pure function of the point, the material and the scene's volumes: no state,
 * no allocation, so any number of threads may call it. Large batches are split over the
 * context's threads unless the caller is already inside a parallel region.
 */
#include "scene/medium.h"
#include "core/simd.h"

#include <math.h>
#include <string.h>

#ifdef _OPENMP
#include <omp.h>
#endif

/* ---------------------------------------------------------------------------------------- */
/* Hashing and noise                                                                        */
/* ---------------------------------------------------------------------------------------- */

/* A 32-bit integer finaliser (xor-shift / multiply rounds, full avalanche): neighbouring cells
 * must look independent, which a plain linear combination of coordinates does not give. */
static inline uint32_t mix32(uint32_t h)
{
    h ^= h >> 16;
    h *= 0x7feb352dU;
    h ^= h >> 15;
    h *= 0x846ca68bU;
    h ^= h >> 16;
    return h;
}

/* Uniform in [0, 1) from the top 24 bits (exact in float). */
static inline float unit24(uint32_t h) { return (float)(h >> 8) * (1.0f / 16777216.0f); }

/* Points are processed 8 at a time: every step below is a short loop over 8 lanes of plain
 * arrays, which the compiler turns into vector instructions (AVX2: 8 floats or 32-bit integers,
 * 4 doubles per register). A single lookup (nc_medium_pattern_weight) runs the same code with
 * one lane filled, so single points and batches agree bit for bit. */
#define LANES 8

/* Up to 8 points as 3 rows of 8 coordinates (unused lanes 0): with a fixed-size block in
 * hand, every later loop reads unconditionally and vectorizes. */
static void gather_block(const float *xyz, size_t n, float p[3][LANES])
{
    for (int l = 0; l < LANES; l++)
        for (int k = 0; k < 3; k++)
            p[k][l] = (size_t)l < n ? xyz[3 * l + k] : 0.0f;
}

/* Integer cell (floor of coordinate * inv) of 8 points, per axis, clamped to +-2^30 so the
 * conversion is always defined (beyond a billion cells the pattern repeats the last cell);
 * non-finite coordinates give a clamped cell (callers give such points medium 1). */
static void cells_block(const float p[3][LANES], double inv, int32_t cell[3][LANES])
{
    for (int k = 0; k < 3; k++) {
        double c[LANES];
        for (int l = 0; l < LANES; l++) {
            c[l] = floor((double)p[k][l] * inv);
            /* Selects rather than fmin/fmax: NaN lands on the lower clamp, no libm calls. */
            c[l] = c[l] > -1073741824.0 ? c[l] : -1073741824.0;
            c[l] = c[l] < 1073741824.0 ? c[l] : 1073741824.0;
        }
        for (int l = 0; l < LANES; l++)
            cell[k][l] = (int32_t)c[l];
    }
}

/* Which of 8 points are finite (1) or not (0). Written as |v| <= FLT_MAX so NaN and
 * infinities fail in one vector compare. */
static void finite_block(const float p[3][LANES], uint32_t ok[LANES])
{
    for (int l = 0; l < LANES; l++)
        ok[l] = (uint32_t)(fabsf(p[0][l]) <= 3.40282347e38f) & (uint32_t)(fabsf(p[1][l]) <= 3.40282347e38f) &
                (uint32_t)(fabsf(p[2][l]) <= 3.40282347e38f);
}

/* CHECKER: medium 2 (1) when the cell coordinates sum to an odd number. */
static void checker_block(const float *xyz, size_t n, const nacre_medium_pattern *pat, uint32_t two[LANES])
{
    float p[3][LANES];
    int32_t cell[3][LANES];
    uint32_t ok[LANES];
    gather_block(xyz, n, p);
    cells_block(p, 1.0 / (double)pat->cell_size, cell);
    finite_block(p, ok);
    for (int l = 0; l < LANES; l++)
        two[l] = ok[l] & (((uint32_t)cell[0][l] + (uint32_t)cell[1][l] + (uint32_t)cell[2][l]) & 1u);
}

/* RANDOM_MIX: medium 2 (1) when the hash of (cell, seed) falls below `fraction`. The hash is
 * chained so that every coordinate passes through a full mix32 (neighbouring cells must look
 * independent; a linear combination of the coordinates would not). */
static void random_mix_block(const float *xyz, size_t n, const nacre_medium_pattern *pat, uint32_t two[LANES])
{
    float p[3][LANES];
    int32_t cell[3][LANES];
    uint32_t ok[LANES];
    gather_block(xyz, n, p);
    cells_block(p, 1.0 / (double)pat->cell_size, cell);
    finite_block(p, ok);
    uint32_t h0 = mix32(pat->seed ^ 0x9e3779b9U);
    float fraction = pat->fraction;
    for (int l = 0; l < LANES; l++) {
        uint32_t h = mix32(h0 ^ (uint32_t)cell[0][l]);
        h = mix32(h ^ (uint32_t)cell[1][l]);
        h = mix32(h ^ (uint32_t)cell[2][l]);
        two[l] = ok[l] & (uint32_t)(unit24(h) < fraction);
    }
}

/* NOISE: fractal value noise, 8 points at a time like the cell patterns.
 *
 * Octave o has frequency 2^o / cell_size, amplitude 2^-o and its own lattice (the seed mixed
 * with o); the sum is normalised by the total amplitude, so w in [0, 1]. Each octave is value
 * noise: the 8 lattice values around the point, mix32(x*A ^ y*B ^ z*C ^ seed) of the wrapped
 * 32-bit cell coordinates (one mix suffices because the interpolation smooths), blended with the
 * quintic fade (C2, so blended coefficients have continuous gradients across cells). Cell
 * coordinates are clamped to +-2^30 so the integer conversion is always defined; the position
 * inside the cell is clamped to [0, 1] for the same reason (absurdly small cells). */
#define NOISE_LANES LANES

static void fractal_noise_block(const float *xyz, size_t n, const nacre_medium_pattern *pat,
                                float w[NOISE_LANES])
{
    const uint32_t A = 0x8da6b343U, B = 0xd8163841U, C = 0xcb1ab31fU;
    float p[3][NOISE_LANES];
    gather_block(xyz, n, p);
    /* Non-finite coordinates read as 0 (the caller gives those points medium 1). */
    for (int k = 0; k < 3; k++)
        for (int l = 0; l < NOISE_LANES; l++)
            p[k][l] = fabsf(p[k][l]) <= 3.40282347e38f ? p[k][l] : 0.0f;
    float sum[NOISE_LANES] = {0};
    double freq = 1.0 / (double)pat->cell_size;
    float amp = 1.0f, norm = 0.0f;
    uint32_t base = mix32(pat->seed ^ 0x51ed270bU);
    for (uint32_t o = 0; o < pat->octaves; o++) {
        uint32_t seed = mix32(base + o);
        float f[3][NOISE_LANES];
        uint32_t h0[3][NOISE_LANES];
        const uint32_t mul[3] = {A, B, C};
        for (int k = 0; k < 3; k++) {
            double x[NOISE_LANES], c[NOISE_LANES];
            int32_t ci[NOISE_LANES];
            for (int l = 0; l < NOISE_LANES; l++) {
                x[l] = (double)p[k][l] * freq;
                c[l] = floor(x[l]);
                c[l] = c[l] > -1073741824.0 ? c[l] : -1073741824.0;
                c[l] = c[l] < 1073741824.0 ? c[l] : 1073741824.0;
                ci[l] = (int32_t)c[l];
            }
            for (int l = 0; l < NOISE_LANES; l++) {
                float t = (float)(x[l] - c[l]);
                float u = t > 0.0f ? (t < 1.0f ? t : 1.0f) : 0.0f;
                f[k][l] = u * u * u * (u * (u * 6.0f - 15.0f) + 10.0f);
                h0[k][l] = (uint32_t)ci[l] * mul[k];
            }
        }
        float v[8][NOISE_LANES];
        for (int corner = 0; corner < 8; corner++)
            for (int l = 0; l < NOISE_LANES; l++) {
                uint32_t h = (h0[0][l] + ((corner & 1) ? A : 0u)) ^ (h0[1][l] + ((corner & 2) ? B : 0u)) ^
                             (h0[2][l] + ((corner & 4) ? C : 0u)) ^ seed;
                v[corner][l] = unit24(mix32(h));
            }
        for (int l = 0; l < NOISE_LANES; l++) {
            float fx = f[0][l], fy = f[1][l], fz = f[2][l];
            float a = v[0][l] + fx * (v[1][l] - v[0][l]), b = v[2][l] + fx * (v[3][l] - v[2][l]);
            float c = v[4][l] + fx * (v[5][l] - v[4][l]), d = v[6][l] + fx * (v[7][l] - v[6][l]);
            float e = a + fy * (b - a), g = c + fy * (d - c);
            sum[l] += amp * (e + fz * (g - e));
        }
        norm += amp;
        amp *= 0.5f;
        freq *= 2.0;
    }
    for (int l = 0; l < NOISE_LANES; l++) {
        float x = sum[l] / norm;
        w[l] = x >= 0.0f ? (x <= 1.0f ? x : 1.0f) : 0.0f;
    }
}

/* One point through the same lanes (lane 0). */
static float fractal_noise(const float p[3], const nacre_medium_pattern *pat)
{
    float w[NOISE_LANES];
    fractal_noise_block(p, 1, pat, w);
    return w[0];
}

/* Weight of medium 2 at p for the patterns defined by two media (0 or 1 for the discrete ones). */
float nc_medium_pattern_weight(const nacre_medium_pattern *pat, const float p[3])
{
    if (!(isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2])))
        return 0.0f;
    uint32_t two[LANES];
    switch (pat->type) {
    case NACRE_PATTERN_RANDOM_MIX:
        random_mix_block(p, 1, pat, two);
        return (float)two[0];
    case NACRE_PATTERN_CHECKER:
        checker_block(p, 1, pat, two);
        return (float)two[0];
    case NACRE_PATTERN_NOISE:
        return fractal_noise(p, pat);
    case NACRE_PATTERN_NONE:
    case NACRE_PATTERN_VOLUME:
        break;
    }
    return 0.0f;
}

/* ---------------------------------------------------------------------------------------- */
/* Volumes                                                                                  */
/* ---------------------------------------------------------------------------------------- */

/* Continuous sample index along one axis, clamped to the grid: lower index and fraction. */
static inline void axis_lookup(float p, float origin, float spacing, uint32_t n, size_t *i0, float *f)
{
    if (n < 2) {
        *i0 = 0;
        *f = 0.0f;
        return;
    }
    float u = (p - origin) / spacing;
    float top = (float)(n - 1);
    u = u > 0.0f ? (u < top ? u : top) : 0.0f;
    size_t i = (size_t)u;
    if (i > n - 2)
        i = n - 2;
    *i0 = i;
    *f = u - (float)i;
}

/* Trilinear density at p (p finite). Clamped to the sample range so rounding in the weights can
 * never push it above the majorant. */
float nc_volume_density(const nc_volume_rec *v, const float p[3])
{
    size_t ix, iy, iz;
    float fx, fy, fz;
    axis_lookup(p[0], v->origin[0], v->spacing[0], v->dims[0], &ix, &fx);
    axis_lookup(p[1], v->origin[1], v->spacing[1], v->dims[1], &iy, &fy);
    axis_lookup(p[2], v->origin[2], v->spacing[2], v->dims[2], &iz, &fz);
    size_t sx = v->dims[0] > 1 ? 1 : 0;
    size_t sy = v->dims[1] > 1 ? (size_t)v->dims[0] : 0;
    size_t sz = v->dims[2] > 1 ? (size_t)v->dims[0] * v->dims[1] : 0;
    const float *d = v->data + ix + (size_t)v->dims[0] * (iy + (size_t)v->dims[1] * iz);
    float a = d[0] + fx * (d[sx] - d[0]);
    float b = d[sy] + fx * (d[sy + sx] - d[sy]);
    float c = d[sz] + fx * (d[sz + sx] - d[sz]);
    float e = d[sz + sy] + fx * (d[sz + sy + sx] - d[sz + sy]);
    float ab = a + fy * (b - a), ce = c + fy * (e - c);
    float r = ab + fz * (ce - ab);
    return r < v->min_value ? v->min_value : (r > v->max_value ? v->max_value : r);
}

/* ---------------------------------------------------------------------------------------- */
/* Evaluation                                                                               */
/* ---------------------------------------------------------------------------------------- */

static void eval_homogeneous(const nacre_material_desc *m, size_t begin, size_t end, float *sa, float *ss)
{
    for (size_t i = begin; i < end; i++)
        for (int c = 0; c < 3; c++) {
            sa[3 * i + c] = m->sigma_a[c];
            ss[3 * i + c] = m->sigma_s[c];
        }
}

/* Discrete patterns: each point gets exactly medium 1 or medium 2 (no blending arithmetic, so
 * the values equal the inputs bit for bit). One loop per pattern, with the pattern test inlined
 * and both media copied to locals (the outputs could alias the desc as far as the compiler
 * knows), keeps the per-point cost to a few dozen operations and lets the loop vectorize. */
typedef struct media_pair {
    float a1[3], s1[3], a2[3], s2[3];
} media_pair;

static media_pair pair_of(const nacre_material_desc *m)
{
    media_pair mp;
    memcpy(mp.a1, m->sigma_a, sizeof(mp.a1));
    memcpy(mp.s1, m->sigma_s, sizeof(mp.s1));
    memcpy(mp.a2, m->pattern.sigma_a2, sizeof(mp.a2));
    memcpy(mp.s2, m->pattern.sigma_s2, sizeof(mp.s2));
    return mp;
}

static inline void store_medium(const media_pair *mp, bool two, size_t i, float *restrict sa, float *restrict ss)
{
    for (int c = 0; c < 3; c++) {
        sa[3 * i + c] = two ? mp->a2[c] : mp->a1[c];
        ss[3 * i + c] = two ? mp->s2[c] : mp->s1[c];
    }
}

static inline bool finite3f(const float *p) { return isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2]); }

/* RANDOM_MIX and CHECKER over a range, 8 points per block. */
static void eval_cells(const nacre_material_desc *m, const float *restrict xyz, size_t begin, size_t end,
                       float *restrict sa, float *restrict ss)
{
    const media_pair mp = pair_of(m);
    bool checker = m->pattern.type == NACRE_PATTERN_CHECKER;
    for (size_t i = begin; i < end; i += LANES) {
        size_t n = end - i < LANES ? end - i : LANES;
        uint32_t two[LANES];
        if (checker)
            checker_block(xyz + 3 * i, n, &m->pattern, two);
        else
            random_mix_block(xyz + 3 * i, n, &m->pattern, two);
        for (size_t l = 0; l < n; l++)
            store_medium(&mp, two[l] != 0, i + l, sa, ss);
    }
}

static void eval_noise(const nacre_material_desc *m, const float *xyz, size_t begin, size_t end,
                       float *sa, float *ss)
{
    const media_pair mp = pair_of(m);
    for (size_t i = begin; i < end; i += NOISE_LANES) {
        size_t n = end - i < NOISE_LANES ? end - i : NOISE_LANES;
        float w[NOISE_LANES];
        fractal_noise_block(xyz + 3 * i, n, &m->pattern, w);
        for (size_t l = 0; l < n; l++) {
            /* Non-finite points: medium 1 (the block saw them as the origin). */
            const float *p = xyz + 3 * (i + l);
            float wl = finite3f(p) ? w[l] : 0.0f;
            for (int c = 0; c < 3; c++) {
                sa[3 * (i + l) + c] = mp.a1[c] + wl * (mp.a2[c] - mp.a1[c]);
                ss[3 * (i + l) + c] = mp.s1[c] + wl * (mp.s2[c] - mp.s1[c]);
            }
        }
    }
}

/* axis_lookup of 8 coordinates (finite) on one axis of n >= 2 samples. */
static inline void axis_lookup8(nc_v8f p, float origin, float spacing, uint32_t n, nc_v8i *i0, nc_v8f *f)
{
    const nc_v8f zero = {0};
    nc_v8f u = (p - origin) / spacing, top = nc_v8_splat((float)(n - 1));
    u = nc_v8_sel(u > zero, nc_v8_sel(u < top, u, top), zero);
    nc_v8i i = __builtin_convertvector(u, nc_v8i); /* u >= 0: truncation is (size_t)u */
    nc_v8i last = (nc_v8i){0} + (int32_t)(n - 2);
    i = nc_v8i_sel(i > last, last, i);
    *i0 = i;
    *f = u - __builtin_convertvector(i, nc_v8f);
}

/* nc_volume_density of 8 finite points (SoA), lane by lane the same operations: a fog's fill
 * and the light grids' marches look up millions of points a frame, and the 8 corners of 8
 * points come by gathers. Volumes of 2^31 samples or more, or with an axis of one sample, take
 * the scalar route. */
static bool volume_density8_ok(const nc_volume_rec *v)
{
    return v->dims[0] > 1 && v->dims[1] > 1 && v->dims[2] > 1 &&
           (uint64_t)v->dims[0] * v->dims[1] * v->dims[2] < ((uint64_t)1 << 31);
}

static nc_v8f volume_density8(const nc_volume_rec *v, nc_v8f x, nc_v8f y, nc_v8f z)
{
    nc_v8i ix, iy, iz;
    nc_v8f fx, fy, fz;
    axis_lookup8(x, v->origin[0], v->spacing[0], v->dims[0], &ix, &fx);
    axis_lookup8(y, v->origin[1], v->spacing[1], v->dims[1], &iy, &fy);
    axis_lookup8(z, v->origin[2], v->spacing[2], v->dims[2], &iz, &fz);
    nc_v8f lo = nc_v8_splat(v->min_value), hi = nc_v8_splat(v->max_value);
    if (v->block_max) {
        /* Lower corners in blocks of 0 around: the lookups read zeros, trilinear gives 0. */
        const int32_t br = (int32_t)v->block_res;
        nc_v8i b = (ix >> 3) + br * ((iy >> 3) + br * (iz >> 3));
        if (nc_v8_bits(nc_v8_gather(v->block_max, b) > 0.0f) == 0) {
            nc_v8f r = {0};
            return nc_v8_sel(r < lo, lo, nc_v8_sel(r > hi, hi, r));
        }
    }
    const int32_t sy = (int32_t)v->dims[0], sz = (int32_t)(v->dims[0] * v->dims[1]);
    nc_v8i base = ix + sy * (iy + (int32_t)v->dims[1] * iz);
    const float *d = v->data;
    nc_v8f d000 = nc_v8_gather(d, base), d100 = nc_v8_gather(d, base + 1);
    nc_v8f d010 = nc_v8_gather(d, base + sy), d110 = nc_v8_gather(d, base + sy + 1);
    nc_v8f d001 = nc_v8_gather(d, base + sz), d101 = nc_v8_gather(d, base + sz + 1);
    nc_v8f d011 = nc_v8_gather(d, base + sz + sy), d111 = nc_v8_gather(d, base + sz + sy + 1);
    nc_v8f a = d000 + fx * (d100 - d000);
    nc_v8f b = d010 + fx * (d110 - d010);
    nc_v8f c = d001 + fx * (d101 - d001);
    nc_v8f e = d011 + fx * (d111 - d011);
    nc_v8f ab = a + fy * (b - a), ce = c + fy * (e - c);
    nc_v8f r = ab + fz * (ce - ab);
    return nc_v8_sel(r < lo, lo, nc_v8_sel(r > hi, hi, r));
}

static void eval_volume(const nacre_material_desc *m, const nc_volume_rec *v, const float *xyz, size_t begin,
                        size_t end, float *sa, float *ss)
{
    if (!m->pattern.blackbody && volume_density8_ok(v)) {
        const float a0 = m->sigma_a[0], a1 = m->sigma_a[1], a2 = m->sigma_a[2];
        const float s0 = m->sigma_s[0], s1 = m->sigma_s[1], s2 = m->sigma_s[2];
        /* The last block takes the points left, its other lanes repeating the last one. */
        for (; begin < end; begin += 8) {
            const float *p = xyz + 3 * begin;
            int n = end - begin < 8 ? (int)(end - begin) : 8;
            nc_v8f x, y, z;
            for (int l = 0; l < 8; l++) {
                int q = l < n ? l : n - 1;
                x[l] = p[3 * q];
                y[l] = p[3 * q + 1];
                z[l] = p[3 * q + 2];
            }
            /* x - x is 0 for finite x, NaN for inf and NaN: non-finite points keep density 1. */
            nc_v8i finite = ((x - x) == 0.0f) & ((y - y) == 0.0f) & ((z - z) == 0.0f);
            if (nc_v8_bits(finite) != 0xffu)
                x = nc_v8_sel(finite, x, (nc_v8f){0}), y = nc_v8_sel(finite, y, (nc_v8f){0}),
                z = nc_v8_sel(finite, z, (nc_v8f){0});
            nc_v8f dv = nc_v8_sel(finite, volume_density8(v, x, y, z), nc_v8_splat(1.0f));
            float *pa = sa + 3 * begin, *ps = ss + 3 * begin;
            for (int l = 0; l < n; l++) {
                float d = dv[l];
                pa[3 * l] = d * a0, pa[3 * l + 1] = d * a1, pa[3 * l + 2] = d * a2;
                ps[3 * l] = d * s0, ps[3 * l + 1] = d * s1, ps[3 * l + 2] = d * s2;
            }
        }
    }
    for (size_t i = begin; i < end; i++) {
        const float *p = xyz + 3 * i;
        float d = 1.0f;
        if (isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2]))
            d = nc_volume_density(v, p);
        if (m->pattern.blackbody) { /* a temperature grid: the emission medium of a fog */
            float b[3];
            nacre_blackbody_rgb((double)m->pattern.kelvin_scale * d, b);
            for (int c = 0; c < 3; c++) {
                sa[3 * i + c] = b[c] * m->sigma_a[c];
                ss[3 * i + c] = b[c] * m->sigma_s[c];
            }
            continue;
        }
        for (int c = 0; c < 3; c++) {
            sa[3 * i + c] = d * m->sigma_a[c];
            ss[3 * i + c] = d * m->sigma_s[c];
        }
    }
}

/* The volume a VOLUME material refers to, or NULL (treated as homogeneous medium 1). */
static const nc_volume_rec *pattern_volume(const nacre_scene *scene, const nacre_material_desc *m)
{
    if (!scene || m->pattern.type != NACRE_PATTERN_VOLUME)
        return NULL;
    return nc_scene_volume(scene, m->pattern.volume);
}

static void eval_range(const nacre_material_desc *m, const nc_volume_rec *vol, const float *xyz, size_t begin,
                       size_t end, float *sa, float *ss)
{
    switch (m->pattern.type) {
    case NACRE_PATTERN_RANDOM_MIX:
    case NACRE_PATTERN_CHECKER:
        eval_cells(m, xyz, begin, end, sa, ss);
        return;
    case NACRE_PATTERN_NOISE:
        eval_noise(m, xyz, begin, end, sa, ss);
        return;
    case NACRE_PATTERN_VOLUME:
        if (vol) {
            eval_volume(m, vol, xyz, begin, end, sa, ss);
            return;
        }
        break;
    case NACRE_PATTERN_NONE:
        break;
    }
    eval_homogeneous(m, begin, end, sa, ss);
}

void nc_medium_eval(const nacre_scene *scene, const nacre_material_desc *m, const float *rest_xyz,
                    size_t count, float *sigma_a, float *sigma_s)
{
    if (count == 0)
        return;
    const nc_volume_rec *vol = pattern_volume(scene, m);
    int threads = scene ? nc_threads(scene->ctx) : 1;
    /* Split large batches over threads, but only from serial code: a caller already running in
     * parallel (per slab, per tile) has its threads busy. Chunks are fixed, so results do not
     * depend on the thread count (each point is computed alone anyway). */
    const size_t chunk = 16384;
    bool split = threads > 1 && count >= 2 * chunk && m->pattern.type != NACRE_PATTERN_NONE;
#ifdef _OPENMP
    split = split && !omp_in_parallel();
#else
    split = false;
#endif
    if (!split) {
        eval_range(m, vol, rest_xyz, 0, count, sigma_a, sigma_s);
        return;
    }
    size_t chunks = (count + chunk - 1) / chunk;
#pragma omp parallel for num_threads(threads) schedule(static)
    for (size_t k = 0; k < chunks; k++) {
        size_t b = k * chunk, e = b + chunk < count ? b + chunk : count;
        eval_range(m, vol, rest_xyz, b, e, sigma_a, sigma_s);
    }
}

void nc_medium_max_sigma_t(const nacre_scene *scene, const nacre_material_desc *m, float out[3])
{
    const nacre_medium_pattern *pat = &m->pattern;
    for (int c = 0; c < 3; c++) {
        float t1 = m->sigma_a[c] + m->sigma_s[c];
        float t2 = pat->sigma_a2[c] + pat->sigma_s2[c];
        float t = t1;
        switch (pat->type) {
        case NACRE_PATTERN_NONE:
            break;
        case NACRE_PATTERN_RANDOM_MIX:
            /* fraction 0 or 1 never (or always) picks medium 2: the bound can be exact. */
            t = pat->fraction <= 0 ? t1 : (pat->fraction >= 1 ? t2 : fmaxf(t1, t2));
            break;
        case NACRE_PATTERN_CHECKER:
            t = fmaxf(t1, t2);
            break;
        case NACRE_PATTERN_NOISE:
            /* Linear blends stay within [t1, t2] up to a few roundings (relative error under
             * 1e-6 of max(t1, t2)), which the margin covers. */
            t = fmaxf(t1, t2) * (1.0f + 2e-6f);
            break;
        case NACRE_PATTERN_VOLUME: {
            const nc_volume_rec *v = pattern_volume(scene, m);
            /* Density 1 covers non-finite points (medium 1) and a missing volume. Products and
             * sums round monotonically, so d <= dmax gives d*a + d*s <= dmax*a + dmax*s. */
            float d = v ? fmaxf(v->max_value, 1.0f) : 1.0f;
            t = d * m->sigma_a[c] + d * m->sigma_s[c];
            break;
        }
        }
        out[c] = t;
    }
}

bool nc_medium_heterogeneous(const nacre_material_desc *m) { return m->pattern.type != NACRE_PATTERN_NONE; }
