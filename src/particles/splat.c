/*
 * splat.c: voxelized particles (seed 003 §3.2.1). The seed rasterizes each particle into a 3D
 * texture with atomic integer adds; on the CPU the grid is cut into bricks (8 z layers by 64
 * rows), each brick written by one thread, and every brick adds its particles in index order
 * (the lists are built by runs of particles in parallel, each run placed after the runs before
 * it). No two threads write one cell and the order of the additions into a cell is fixed, so
 * the grid is the same bit for bit whatever the thread count, without atomics.
 *
 * Mass: a particle's kernel (nacre/particles.h) is sampled at the cell centres it covers and the
 * samples are scaled so that they sum to its mass m = d0 (K R)^3 divided by the cell volume.
 * Point-sampling alone would gain or lose mass depending on where the particle falls between
 * samples (by tens of percent once R is near a cell); normalised, the grid holds exactly the
 * particles' mass, and with the two empty outer layers the trilinear field the renderers
 * sample integrates to the same number. A particle whose kernel misses every sample centre along
 * an axis (R under half a cell) deposits there by linear weights on the two nearest samples.
 *
 * Large particles: the cost is the cells written (a smoke particle of R = 10 cells writes 10^4).
 * A particle of R >= COARSE_RADIUS cells is splatted instead on a coarse level of twice the
 * spacing (8 times fewer cells), one of R >= 2 COARSE_RADIUS cells on a second coarse level of
 * four times the spacing (64 times fewer), normalised the same way: the kernel's standard
 * deviation is then at least one sample of its level. Each level is added to the one below by
 * trilinear interpolation, which keeps the mass (each coarse sample's tent sums to 8 samples
 * below) and the empty outer layers. The field then differs from the all-fine splat by the
 * interpolation of the coarse samples (docs/accuracy.md); a system with an isosurface is splatted
 * all fine (nc_particle_grid.fine_only).
 *
 * Empty bricks: a brick of the grid that no particle and no coarse sample reaches is left as it
 * is when the last splat left it all 0 (nc_particle_grid.dirty), so a sparse system (dust) pays
 * for the bricks it covers, not for the whole grid's clearing and maximum.
 *
 * Block maxima: the scan for the grid's maximum keeps each 8^3 block's, then each block takes
 * its neighbours' (nc_particle_grid.block_max): the particle fog's volume lookups (medium.c)
 * return 0 without reading the samples where 8 points all fall in blocks of 0.
 */
#include "particles/billboard.h"
#include "particles/particles.h"

#include <math.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif

/* Bricks of SLAB_LAYERS z layers x BRICK_ROWS rows: a brick of the 128^3 grid is 256 kB, in
 * the core's L2 cache with the weights it reads (a slab of 16 whole layers is 1 MB); a
 * particle's weights are computed once, not per brick. Bricks of 4 x 16 (32 kB, in L1) made
 * each particle visit 4 times as many bricks, and the set-up of a visit and of its short runs
 * of rows cost more than the misses the smaller bricks saved (docs/performance.md). The grid
 * does not depend on the brick size: every cell sums its particles in index order whatever the
 * bricks. */
#define SLAB_LAYERS 8u
#define BRICK_ROWS 64u
_Static_assert(SLAB_LAYERS == 8 && BRICK_ROWS % 8 == 0, "the block maxima take a brick as whole 8^3 blocks");
/* Bricks of one level at most (a level's order of bricks is kept on the stack). */
#define MAX_BRICKS                                                                                                     \
    ((NACRE_PARTICLES_GRID_MAX + SLAB_LAYERS - 1) / SLAB_LAYERS *                                                      \
     ((NACRE_PARTICLES_GRID_MAX + BRICK_ROWS - 1) / BRICK_ROWS))
/* Particles of radius at least COARSE_RADIUS cells (the largest spacing) go to coarse level 1,
 * of at least 2 COARSE_RADIUS to level 2: the kernel's standard deviation R / 3 is then at least
 * one sample of the level (error against the all-fine splat: docs/accuracy.md). */
#define COARSE_RADIUS 6.0
#define COARSE2_RADIUS 12.0
#define LEVELS 3
/* Particles from which the bounds are found by all threads: 10k take ~25 us on one thread, as
 * long as a parallel region's start and end with OMP_WAIT_POLICY=passive. */
#define BOUNDS_PARALLEL 50000u

void nc_particle_grid_free(nacre_context *ctx, nc_particle_grid *g)
{
    nc_free(ctx, g->data);
    nc_free(ctx, g->range);
    nc_free(ctx, g->scale);
    nc_free(ctx, g->bin_start);
    nc_free(ctx, g->bins);
    nc_free(ctx, g->weights);
    nc_free(ctx, g->woff);
    nc_free(ctx, g->level);
    nc_free(ctx, g->fallback);
    nc_free(ctx, g->bin_count);
    nc_free(ctx, g->coarse[0]);
    nc_free(ctx, g->coarse[1]);
    nc_free(ctx, g->dirty);
    nc_free(ctx, g->block_max);
    nc_free(ctx, g->block_raw);
    memset(g, 0, sizeof(*g));
}

/* Zeros in front of sample x0's weights: none, unless the particle's whole vectors from x0
 * would leave the row of res samples; then as many as move them back into it. */
static inline int32_t lead(int32_t x0, int32_t nx, int32_t res)
{
    const int32_t e = res - (nx + 7) / 8 * 8;
    return x0 <= e ? 0 : (e > 0 ? x0 - e : x0);
}

/* Kernel samples along one axis around centre c: lo..hi; returns whether the particle takes
 * the fallback: its kernel misses every sample centre (R under half a cell), so it takes the two
 * samples around its centre instead. */
static bool axis_range(double c, double R, double origin, double h, int32_t n, int32_t *lo, int32_t *hi)
{
    double f = (c - origin) / h;
    int32_t a = (int32_t)ceil(f - R / h), b = (int32_t)floor(f + R / h);
    a = a < 0 ? 0 : a;
    b = b > n - 1 ? n - 1 : b;
    const bool fallback = a > b;
    if (fallback) {
        a = (int32_t)floor(f);
        a = a < 0 ? 0 : (a > n - 2 ? n - 2 : a);
        b = a + 1;
    }
    *lo = a;
    *hi = b;
    return fallback;
}

/* Whole 8-lane vectors of weights an axis of m samples takes in the weights array. */
static inline int32_t padded(int32_t m) { return (m + 7) / 8 * 8; }

/* The weights of samples lo..hi (axis_range of the same arguments, which said whether this is
 * the fallback) into w, 0 after them up to padded(hi - lo + 1); returns their sum. inv = 1 / R.
 * Linear weights for the fallback's two samples. */
static float axis_weights(double c, double inv, double origin, double h, bool fallback, int32_t lo, int32_t hi,
                          float *w)
{
    const int32_t m = hi - lo + 1;
    if (fallback) {
        float fr = (float)((c - origin) / h - lo);
        fr = fr < 0.0f ? 0.0f : (fr > 1.0f ? 1.0f : fr);
        memset(w, 0, (size_t)padded(m) * sizeof(float));
        w[0] = 1.0f - fr;
        w[1] = fr;
        return 1.0f;
    }
    /* Each offset (in double, rounded to float) goes from registers into the 8-lane exponential:
     * written to memory as the 4-lane halves the conversion gives and read back as 8 lanes, the
     * load could not take them from the store buffer and waited for both stores. The steps and
     * roundings are those of the scalar form, weight by weight. */
    typedef double v4d __attribute__((vector_size(32)));
    typedef float v4f __attribute__((vector_size(16)));
    const v4d iota = {0.0, 1.0, 2.0, 3.0};
    float sum = 0.0f;
    for (int32_t q = 0; q < m; q += 8) {
        const v4d i0 = (double)(lo + q) + iota, i1 = i0 + 4.0;
        const v4f t0 = __builtin_convertvector((origin + i0 * h - c) * inv, v4f);
        const v4f t1 = __builtin_convertvector((origin + i1 * h - c) * inv, v4f);
        const nc_v8f t = __builtin_shufflevector(t0, t1, 0, 1, 2, 3, 4, 5, 6, 7);
        nc_v8f e = nc_billboard_exp8(nc_v8_splat(-NC_PARTICLE_KERNEL_A) * t * t);
        /* Lanes past the last sample are 0 (the splat's rows read them); the sum adds the
         * samples in index order, so it stays the same bit for bit. */
        const int32_t live = m - q < 8 ? m - q : 8;
        e = nc_v8_sel(nc_v8_first((uint32_t)live), e, nc_v8_splat(0.0f));
        for (int32_t k = 0; k < live; k++)
            sum += e[k];
        nc_v8_store(w + q, e);
    }
    return sum;
}

/* Layers [z0, z1) and rows [y0, y1) of brick b of a grid of res samples per axis. */
static void splat_brick_box(uint32_t res, uint32_t nby, uint32_t b, uint32_t *z0, uint32_t *z1, uint32_t *y0,
                            uint32_t *y1)
{
    *z0 = b / nby * SLAB_LAYERS, *z1 = *z0 + SLAB_LAYERS < res ? *z0 + SLAB_LAYERS : res;
    *y0 = b % nby * BRICK_ROWS, *y1 = *y0 + BRICK_ROWS < res ? *y0 + BRICK_ROWS : res;
}

/* Rows of NV whole vectors (row + fy wx, the generic loop's sum): the x weights stay in registers
 * across the particle's rows, so a short row costs its NV multiply-adds and not a loop's set-up. */
static inline __attribute__((always_inline)) void add_rows(float *restrict p0, size_t nxy, size_t nx, int32_t za,
                                                           int32_t zb, int32_t ya, int32_t yb, const float *wz,
                                                           int32_t oz, const float *wy, int32_t oy, float sc,
                                                           const float *wx, int nv)
{
    nc_v8f w[4];
    for (int v = 0; v < nv; v++)
        w[v] = nc_v8_load(wx + 8 * v);
    for (int32_t z = za; z <= zb; z++) {
        const float fz = sc * wz[z - oz];
        float *restrict pz = p0 + (size_t)z * nxy;
        for (int32_t y = ya; y <= yb; y++) {
            const float fy = fz * wy[y - oy];
            float *restrict row = pz + (size_t)y * nx;
            for (int v = 0; v < nv; v++)
                nc_v8_store(row + 8 * v, nc_v8_load(row + 8 * v) + fy * w[v]);
        }
    }
}

/* Brick b of `data` (res samples per axis) zeroed, then its particles (start, g->bins) added in
 * index order. */
static void splat_brick(const nc_particle_grid *g, float *data, uint32_t res, uint32_t nby, uint32_t b,
                        const uint32_t *start)
{
    const size_t nx = res, nxy = (size_t)res * res;
    uint32_t z0, z1, y0, y1;
    splat_brick_box(res, nby, b, &z0, &z1, &y0, &y1);
    for (uint32_t z = z0; z < z1; z++)
        memset(data + z * nxy + y0 * nx, 0, (y1 - y0) * nx * sizeof(float));
    for (uint32_t e = start[b]; e < start[b + 1]; e++) {
        const uint32_t i = g->bins[e];
        const int32_t *rg = g->range + 6 * (size_t)i;
        const int32_t ld = lead(rg[0], rg[1] - rg[0] + 1, (int32_t)res), x0 = rg[0] - ld, xn = rg[1] - rg[0] + 1 + ld;
        const int32_t px = (xn + 7) / 8 * 8;
        const float *wx = g->weights + g->woff[i], *wy = wx + px, *wz = wy + padded(rg[3] - rg[2] + 1);
        const float sc = g->scale[i];
        const int32_t za = rg[4] > (int32_t)z0 ? rg[4] : (int32_t)z0;
        const int32_t zb = rg[5] < (int32_t)z1 - 1 ? rg[5] : (int32_t)z1 - 1;
        const int32_t ya = rg[2] > (int32_t)y0 ? rg[2] : (int32_t)y0;
        const int32_t yb = rg[3] < (int32_t)y1 - 1 ? rg[3] : (int32_t)y1 - 1;
        /* Whole vectors (the padding adds 0 to the cells around the range, in the same row)
         * unless they would leave the row; then the range alone. */
        const bool vec = x0 >= 0 && x0 + px <= (int32_t)res;
        if (vec && px <= 32) {
            float *p0 = data + (size_t)x0;
            switch (px / 8) {
            case 1: add_rows(p0, nxy, nx, za, zb, ya, yb, wz, rg[4], wy, rg[2], sc, wx, 1); break;
            case 2: add_rows(p0, nxy, nx, za, zb, ya, yb, wz, rg[4], wy, rg[2], sc, wx, 2); break;
            case 3: add_rows(p0, nxy, nx, za, zb, ya, yb, wz, rg[4], wy, rg[2], sc, wx, 3); break;
            default: add_rows(p0, nxy, nx, za, zb, ya, yb, wz, rg[4], wy, rg[2], sc, wx, 4); break;
            }
            continue;
        }
        for (int32_t z = za; z <= zb; z++) {
            const float fz = sc * wz[z - rg[4]];
            for (int32_t y = ya; y <= yb; y++) {
                const float fy = fz * wy[y - rg[2]];
                float *restrict row = data + (size_t)z * nxy + (size_t)y * nx + (size_t)rg[0];
                if (vec) {
                    row -= ld;
                    for (int32_t x = 0; x < px; x += 8)
                        nc_v8_store(row + x, nc_v8_load(row + x) + fy * nc_v8_load(wx + x));
                } else {
                    for (int32_t x = 0; x < xn - ld; x++)
                        row[x] += fy * wx[ld + x];
                }
            }
        }
    }
}

/* Bricks 0 .. nb - 1 in the order to splat them: the most particles first (ties by index), so
 * that with dynamic scheduling the last bricks taken are short ones and the threads end
 * together. The plume's bricks differ by 10 times; in index order a thread was left with one
 * of the largest at the end. The order does not change the grid: each brick is one thread's. */
static void brick_order(const uint32_t *start, uint32_t nb, uint32_t *order)
{
    for (uint32_t b = 0; b < nb; b++) {
        const uint32_t cost = start[b + 1] - start[b];
        uint32_t j = b;
        for (; j > 0 && start[order[j - 1] + 1] - start[order[j - 1]] < cost; j--)
            order[j] = order[j - 1];
        order[j] = b;
    }
}

/* Add to fine layers [z0, z1), rows [y0, y1) the trilinear interpolation of the coarse level
 * (sample I at fine sample 2I), whose samples outside the box cbox (first and last per axis,
 * within c_lo .. c_hi) are 0: an even fine index takes its coarse sample, an odd one the mean
 * of the two around it. */
static void add_coarse(float *data, uint32_t res, const float *coarse, uint32_t rc, const int32_t cbox[6],
                       uint32_t z0, uint32_t z1, uint32_t y0, uint32_t y1)
{
    const size_t nx = res, nxy = (size_t)res * res, cx = rc, cxy = (size_t)rc * rc;
    /* Fine samples the coarse box reaches, per axis. */
    const uint32_t fx1 = 2 * (uint32_t)cbox[1] + 1;
    const uint32_t fy0 = 2 * (uint32_t)cbox[2] - 1, fy1 = 2 * (uint32_t)cbox[3] + 1;
    const uint32_t fz0 = 2 * (uint32_t)cbox[4] - 1, fz1 = 2 * (uint32_t)cbox[5] + 1;
    const uint32_t X0 = (uint32_t)cbox[0], X1 = (uint32_t)cbox[1];
    float row[NACRE_PARTICLES_GRID_MAX / 2 + 16];
    for (uint32_t z = z0 > fz0 ? z0 : fz0; z < z1 && z <= fz1; z++) {
        /* Outside the box the coarse samples are 0: the layer or row there reads as 0. */
        const float *pz0 = coarse + (size_t)(z / 2) * cxy, *pz1 = (z & 1) ? pz0 + cxy : pz0;
        for (uint32_t y = y0 > fy0 ? y0 : fy0; y < y1 && y <= fy1; y++) {
            const size_t o0 = (size_t)(y / 2) * cx, o1 = (y & 1) ? o0 + cx : o0;
            const float *a = pz0 + o0, *b = pz0 + o1, *c = pz1 + o0, *d = pz1 + o1;
            uint32_t X = X0;
            for (; X + 8 <= X1 + 1; X += 8)
                nc_v8_store(row + X, 0.25f * ((nc_v8_load(a + X) + nc_v8_load(b + X)) +
                                              (nc_v8_load(c + X) + nc_v8_load(d + X))));
            for (; X <= X1; X++)
                row[X] = 0.25f * ((a[X] + b[X]) + (c[X] + d[X]));
            /* Zeros around the box's samples: the vectors below read up to 9 past X1. */
            row[X0 - 1] = 0.0f;
            for (uint32_t k = 1; k <= 9; k++)
                row[X1 + k] = 0.0f;
            /* Fine sample 2q takes coarse sample q, 2q + 1 the mean of q and q + 1: 8 coarse
             * samples make 16 fine ones, interleaved in registers and added to the row. Fine
             * sample 2 (X0 - 1) and those past fx1 add 0; the row's end goes sample by sample. */
            float *out = data + (size_t)z * nxy + (size_t)y * nx;
            for (uint32_t q = X0 - 1; q <= X1; q += 8) {
                const nc_v8f r = nc_v8_load(row + q), m = 0.5f * (r + nc_v8_load(row + q + 1));
                const nc_v8f lo = __builtin_shufflevector(r, m, 0, 8, 1, 9, 2, 10, 3, 11);
                const nc_v8f hi = __builtin_shufflevector(r, m, 4, 12, 5, 13, 6, 14, 7, 15);
                float *o = out + 2 * q;
                if (2 * q + 16 <= res) {
                    nc_v8_store(o, nc_v8_load(o) + lo);
                    nc_v8_store(o + 8, nc_v8_load(o + 8) + hi);
                } else {
                    for (uint32_t k = 0; k < 16 && 2 * q + k <= fx1; k++)
                        o[k] += k < 8 ? lo[k] : hi[k - 8];
                }
            }
        }
    }
}

nacre_result nc_particles_splat(nacre_context *ctx, const nc_particle_set *s, uint32_t res, nc_particle_grid *g)
{
    g->dims[0] = g->dims[1] = g->dims[2] = 0;
    g->max_value = 0.0f;
    if (s->count == 0)
        return NACRE_OK;
    if (res < NACRE_PARTICLES_GRID_MIN || res > NACRE_PARTICLES_GRID_MAX)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "particles: grid_resolution: must be %u..%u (got %u)",
                       NACRE_PARTICLES_GRID_MIN, NACRE_PARTICLES_GRID_MAX, res);
    const uint32_t n = s->count;
    float lo0 = INFINITY, lo1 = INFINITY, lo2 = INFINITY, hi0 = -INFINITY, hi1 = -INFINITY, hi2 = -INFINITY;
    int bad = 0;
    /* min and max are exact, so the reduction's order does not matter. Comparisons rather than
     * fminf (a libm call per value here): a NaN, which they would skip, is counted instead.
     * Below BOUNDS_PARALLEL particles one thread does it: waking the others (passive waiting)
     * takes longer than the loop. */
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads(nc_threads(ctx)) if (n >= BOUNDS_PARALLEL) \
    reduction(min : lo0, lo1, lo2) reduction(max : hi0, hi1, hi2) reduction(+ : bad)
#endif
    for (uint32_t i = 0; i < n; i++) {
        const float r = s->radius[i], a0 = s->x[i] - r, a1 = s->y[i] - r, a2 = s->z[i] - r;
        const float b0 = s->x[i] + r, b1 = s->y[i] + r, b2 = s->z[i] + r;
        bad += (a0 != a0) | (a1 != a1) | (a2 != a2) | (b0 != b0) | (b1 != b1) | (b2 != b2);
        lo0 = a0 < lo0 ? a0 : lo0;
        lo1 = a1 < lo1 ? a1 : lo1;
        lo2 = a2 < lo2 ? a2 : lo2;
        hi0 = b0 > hi0 ? b0 : hi0;
        hi1 = b1 > hi1 ? b1 : hi1;
        hi2 = b2 > hi2 ? b2 : hi2;
    }
    const float lo[3] = {lo0, lo1, lo2}, hi[3] = {hi0, hi1, hi2};
    for (int a = 0; a < 3; a++) {
        if (bad || !(isfinite(lo[a]) && isfinite(hi[a])))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "particles: positions: not finite");
        g->dims[a] = res;
        /* Two empty layers of samples outside the bounds on each side. */
        double h = ((double)hi[a] - lo[a]) / (res - 4);
        g->spacing[a] = (float)h;
        g->origin[a] = (float)(lo[a] - 1.5 * h);
    }
    const size_t cells = (size_t)res * res * res;
    const int threads = nc_threads(ctx) > 0 ? nc_threads(ctx) : 1;
    /* Level l's sample I sits at sample 2I of level l - 1, and its samples c_lo .. c_hi[l] spread
     * (by their tents) over samples 3 .. c_hi[l - 1] there only; the grid's samples 2 .. res - 3
     * are inside its two empty outer layers, so those stay empty. */
    const uint32_t c_lo = 2;
    uint32_t res_l[LEVELS], c_hi[LEVELS], nby[LEVELS], bricks[LEVELS], base[LEVELS];
    bool level_ok[LEVELS];
    res_l[0] = res, c_hi[0] = res - 3, level_ok[0] = true;
    for (int l = 1; l < LEVELS; l++) {
        res_l[l] = (res_l[l - 1] - 1) / 2 + 1;
        c_hi[l] = (c_hi[l - 1] - 1) / 2;
        level_ok[l] = level_ok[l - 1] && !g->fine_only && c_hi[l] >= c_lo + 4;
    }
    size_t ccells[LEVELS] = {0}, all_cells = cells;
    uint32_t nb = 0;
    for (int l = 0; l < LEVELS; l++) {
        nby[l] = (res_l[l] + BRICK_ROWS - 1) / BRICK_ROWS;
        bricks[l] = level_ok[l] ? (res_l[l] + SLAB_LAYERS - 1) / SLAB_LAYERS * nby[l] : 0;
        base[l] = nb;
        nb += bricks[l];
        if (l > 0 && level_ok[l])
            all_cells += ccells[l] = (size_t)res_l[l] * res_l[l] * res_l[l];
    }
    nacre_result r = nc_memory_check(ctx, (uint64_t)all_cells * sizeof(float), "particle density grid (grid_resolution)");
    if (r != NACRE_OK)
        return r;
    /* The bricks' state is known only for the same resolution and the same array. */
    const bool known = g->dirty_res == res && cells <= g->capacity && g->data && g->dirty;
    g->dirty_res = 0;
    g->block_res = 0;
    const uint32_t bres = (res + 7) / 8;
    const size_t blocks = (size_t)bres * bres * bres;
    bool ok = nc_reserve(ctx, &g->data, &g->capacity, cells, sizeof(float));
    ok = ok && nc_reserve(ctx, &g->block_max, &g->block_max_capacity, blocks, sizeof(float));
    ok = ok && nc_reserve(ctx, &g->block_raw, &g->block_raw_capacity, blocks, sizeof(float));
    for (int l = 1; l < LEVELS; l++)
        ok = ok && (!level_ok[l] ||
                    nc_reserve(ctx, &g->coarse[l - 1], &g->coarse_capacity[l - 1], ccells[l], sizeof(float)));
    ok = ok && nc_reserve(ctx, &g->dirty, &g->dirty_capacity, bricks[0], sizeof(uint8_t));
    ok = ok && nc_reserve(ctx, &g->range, &g->range_capacity, 6 * (size_t)n, sizeof(int32_t));
    ok = ok && nc_reserve(ctx, &g->scale, &g->scale_capacity, n, sizeof(float));
    ok = ok && nc_reserve(ctx, &g->level, &g->level_capacity, n, sizeof(uint8_t));
    ok = ok && nc_reserve(ctx, &g->fallback, &g->fallback_capacity, n, sizeof(uint8_t));
    ok = ok && nc_reserve(ctx, &g->woff, &g->woff_capacity, (size_t)n + 1, sizeof(size_t));
    ok = ok && nc_reserve(ctx, &g->bin_start, &g->bin_start_capacity, (size_t)nb + 2, sizeof(uint32_t));
    if (!ok)
        return NACRE_ERROR_OUT_OF_MEMORY;
    float *const data_l[LEVELS] = {g->data, level_ok[1] ? g->coarse[0] : NULL, level_ok[2] ? g->coarse[1] : NULL};
    const double hmax = fmax(fmax(g->spacing[0], g->spacing[1]), g->spacing[2]);

    /* Per particle: its level, its sample range per axis there, and where its weights go: x
     * padded with zeros to whole 8-lane vectors (lead zeros first where they would leave the
     * row), then y, then z, each padded to whole vectors (the weights are computed 8 at a time).
     * The vectors start at the particle's first sample, not at 32-byte boundaries of the row: a
     * row of 9 to 16 samples takes 2 vectors, not 2 or 3, and the unaligned loads and stores cost
     * less than the third. Whether an axis takes the fallback is kept for the weights. */
    size_t entries = 0; /* particle-brick pairs: the bins' length */
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads(threads) reduction(+ : entries)
#endif
    for (uint32_t i = 0; i < n; i++) {
        const double c[3] = {s->x[i], s->y[i], s->z[i]};
        int32_t *rg = g->range + 6 * (size_t)i;
        int l = 0;
        const double coarse_r[2] = {COARSE_RADIUS, COARSE2_RADIUS};
        while (l + 1 < LEVELS && level_ok[l + 1] && s->radius[i] >= coarse_r[l] * hmax)
            l++;
        g->level[i] = (uint8_t)l;
        uint8_t fb = 0;
        for (int a = 0; a < 3; a++) {
            fb |= (uint8_t)(axis_range(c[a], s->radius[i], g->origin[a], g->spacing[a] * (double)(1 << l),
                                       (int32_t)res_l[l], &rg[2 * a], &rg[2 * a + 1])
                            << a);
            if (l) {
                rg[2 * a] = rg[2 * a] > (int32_t)c_lo ? rg[2 * a] : (int32_t)c_lo;
                rg[2 * a + 1] = rg[2 * a + 1] < (int32_t)c_hi[l] ? rg[2 * a + 1] : (int32_t)c_hi[l];
            }
        }
        g->fallback[i] = fb;
        g->woff[i + 1] = (size_t)((lead(rg[0], rg[1] - rg[0] + 1, (int32_t)res_l[l]) + rg[1] - rg[0] + 8) / 8 * 8) +
                         (size_t)padded(rg[3] - rg[2] + 1) + (size_t)padded(rg[5] - rg[4] + 1);
        entries += ((uint32_t)rg[5] / SLAB_LAYERS - (uint32_t)rg[4] / SLAB_LAYERS + 1) *
                   ((uint32_t)rg[3] / BRICK_ROWS - (uint32_t)rg[2] / BRICK_ROWS + 1);
    }
    g->woff[0] = 0;
    /* The coarse samples in use (a box per level and axis), so that a coarse pass costs nothing
     * when no particle is large and only its box otherwise. */
    int32_t cbox[LEVELS][6];
    for (int l = 0; l < LEVELS; l++)
        for (int a = 0; a < 3; a++)
            cbox[l][2 * a] = INT32_MAX, cbox[l][2 * a + 1] = -1;
    for (uint32_t i = 0; i < n; i++) {
        g->woff[i + 1] += g->woff[i];
        const int l = g->level[i];
        if (l) {
            const int32_t *rg = g->range + 6 * (size_t)i;
            for (int a = 0; a < 3; a++) {
                cbox[l][2 * a] = rg[2 * a] < cbox[l][2 * a] ? rg[2 * a] : cbox[l][2 * a];
                cbox[l][2 * a + 1] = rg[2 * a + 1] > cbox[l][2 * a + 1] ? rg[2 * a + 1] : cbox[l][2 * a + 1];
            }
        }
    }
    /* Level 2 reaches level 1 over its box's spread: level 1 is in use there too. */
    bool used[LEVELS] = {true, cbox[1][1] >= 0, cbox[2][1] >= 0};
    if (used[2]) {
        for (int a = 0; a < 3; a++) {
            const int32_t s0 = 2 * cbox[2][2 * a] - 1, s1 = 2 * cbox[2][2 * a + 1] + 1;
            cbox[1][2 * a] = s0 < cbox[1][2 * a] ? s0 : cbox[1][2 * a];
            cbox[1][2 * a + 1] = s1 > cbox[1][2 * a + 1] ? s1 : cbox[1][2 * a + 1];
        }
        used[1] = true;
    }
    if ((r = nc_memory_check(ctx, (uint64_t)g->woff[n] * sizeof(float), "particle splat weights")) != NACRE_OK)
        return r;
    if (!nc_reserve(ctx, &g->weights, &g->weight_capacity, g->woff[n], sizeof(float)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    if (!nc_reserve(ctx, &g->bins, &g->bin_capacity, entries + 1, sizeof(uint32_t)) ||
        !nc_reserve(ctx, &g->bin_count, &g->bin_count_capacity, (size_t)threads * nb, sizeof(uint32_t)))
        return NACRE_ERROR_OUT_OF_MEMORY;

    /* The weights, and the factor that makes a particle's samples sum to its mass: on level l
     * each sample spreads over the grid's samples with weights summing to 2^l per axis. Then the
     * particles binned by brick of their level (SLAB_LAYERS z layers x BRICK_ROWS rows), in
     * index order (a counting sort; the fine bricks' lists first, then each coarse level's): each
     * thread counts and then places a run of consecutive particles, its places in a brick's list
     * after those of the runs before it, so the lists do not depend on the thread count. */
    const double V = (double)g->spacing[0] * g->spacing[1] * g->spacing[2];
    uint32_t *start = g->bin_start;
#ifdef _OPENMP
#pragma omp parallel num_threads(threads)
#endif
    {
        int tid = 0, team = 1;
#ifdef _OPENMP
        tid = omp_get_thread_num();
        team = omp_get_num_threads();
#endif
        const uint32_t i0 = (uint32_t)((uint64_t)n * tid / team), i1 = (uint32_t)((uint64_t)n * (tid + 1) / team);
        uint32_t *count = g->bin_count + (size_t)tid * nb;
        memset(count, 0, nb * sizeof(uint32_t));
        for (uint32_t i = i0; i < i1; i++) {
            const double c[3] = {s->x[i], s->y[i], s->z[i]};
            const int32_t *rg = g->range + 6 * (size_t)i;
            const int l = g->level[i];
            const double k = (double)(1 << l), inv = 1.0 / s->radius[i];
            const uint8_t fb = g->fallback[i];
            float *w = g->weights + g->woff[i];
            const int32_t nx = rg[1] - rg[0] + 1, ld = lead(rg[0], nx, (int32_t)res_l[l]), px = (ld + nx + 7) / 8 * 8;
            for (int32_t q = 0; q < ld; q++)
                w[q] = 0.0f;
            /* x's last vector may run past px into y's place, written next. */
            double sum = axis_weights(c[0], inv, g->origin[0], g->spacing[0] * k, fb & 1, rg[0], rg[1], w + ld);
            for (int32_t q = ld + nx; q < px; q++)
                w[q] = 0.0f;
            w += px;
            sum *= axis_weights(c[1], inv, g->origin[1], g->spacing[1] * k, fb & 2, rg[2], rg[3], w);
            w += padded(rg[3] - rg[2] + 1);
            sum *= axis_weights(c[2], inv, g->origin[2], g->spacing[2] * k, fb & 4, rg[4], rg[5], w);
            double kr = (double)NC_PARTICLE_KERNEL_K * s->radius[i];
            double mass = (double)s->density[i] * kr * kr * kr;
            g->scale[i] = (float)(mass / (sum * V * k * k * k));
            for (uint32_t bz = (uint32_t)rg[4] / SLAB_LAYERS; bz <= (uint32_t)rg[5] / SLAB_LAYERS; bz++)
                for (uint32_t by = (uint32_t)rg[2] / BRICK_ROWS; by <= (uint32_t)rg[3] / BRICK_ROWS; by++)
                    count[base[l] + bz * nby[l] + by]++;
        }
#ifdef _OPENMP
#pragma omp barrier
#pragma omp single
#endif
        {
            /* count[t][b] becomes the place of run t's first particle in brick b's list. */
            uint32_t at = 0;
            for (uint32_t b = 0; b < nb; b++) {
                start[b] = at;
                for (int t = 0; t < team; t++) {
                    uint32_t *ct = g->bin_count + (size_t)t * nb + b;
                    const uint32_t c = *ct;
                    *ct = at;
                    at += c;
                }
            }
            start[nb] = at;
        }
        for (uint32_t i = i0; i < i1; i++) {
            const int32_t *rg = g->range + 6 * (size_t)i;
            const int l = g->level[i];
            for (uint32_t bz = (uint32_t)rg[4] / SLAB_LAYERS; bz <= (uint32_t)rg[5] / SLAB_LAYERS; bz++)
                for (uint32_t by = (uint32_t)rg[2] / BRICK_ROWS; by <= (uint32_t)rg[3] / BRICK_ROWS; by++)
                    g->bins[count[base[l] + bz * nby[l] + by]++] = i;
        }
    }

    /* The coarsest level first (its bricks zeroed, then their particles), then level 1 (the
     * same, plus level 2's trilinear values), then each fine brick: zeroed, its particles, level
     * 1's trilinear values added, its maximum. */
    uint32_t order[MAX_BRICKS];
    for (int l = LEVELS - 1; l >= 1; l--) {
        if (!used[l])
            continue;
        const bool add = l + 1 < LEVELS && used[l + 1];
        brick_order(start + base[l], bricks[l], order);
#ifdef _OPENMP
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads)
#endif
        for (uint32_t o = 0; o < bricks[l]; o++) {
            const uint32_t b = order[o];
            splat_brick(g, data_l[l], res_l[l], nby[l], b, start + base[l]);
            if (add) {
                uint32_t z0, z1, y0, y1;
                splat_brick_box(res_l[l], nby[l], b, &z0, &z1, &y0, &y1);
                add_coarse(data_l[l], res_l[l], data_l[l + 1], res_l[l + 1], cbox[l + 1], z0, z1, y0, y1);
            }
        }
    }
    /* Grid samples level 1's box reaches. */
    const int32_t fz0 = used[1] ? 2 * cbox[1][4] - 1 : 0, fz1 = used[1] ? 2 * cbox[1][5] + 1 : -1;
    const int32_t fy0 = used[1] ? 2 * cbox[1][2] - 1 : 0, fy1 = used[1] ? 2 * cbox[1][3] + 1 : -1;
    const size_t nx = res, nxy = (size_t)res * res;
    float gmax = 0.0f;
    brick_order(start, bricks[0], order);
#ifdef _OPENMP
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads) reduction(max : gmax)
#endif
    for (uint32_t o = 0; o < bricks[0]; o++) {
        const uint32_t b = order[o];
        uint32_t z0, z1, y0, y1;
        splat_brick_box(res, nby[0], b, &z0, &z1, &y0, &y1);
        const bool coarse_here = used[1] && (int32_t)z0 <= fz1 && (int32_t)z1 > fz0 && (int32_t)y0 <= fy1 &&
                                 (int32_t)y1 > fy0;
        /* The brick is one block deep (SLAB_LAYERS 8) and BRICK_ROWS / 8 blocks high. */
        float *braw = g->block_raw + ((size_t)(z0 / 8) * bres + y0 / 8) * bres;
        const uint32_t bys = (y1 - y0 + 7) / 8;
        if (start[b] == start[b + 1] && !coarse_here) {
            /* Nothing reaches the brick: it is 0, and its maximum too. */
            if (!known || g->dirty[b])
                for (uint32_t z = z0; z < z1; z++)
                    memset(g->data + z * nxy + y0 * nx, 0, (y1 - y0) * nx * sizeof(float));
            g->dirty[b] = 0;
            memset(braw, 0, (size_t)bys * bres * sizeof(float));
            continue;
        }
        g->dirty[b] = 1;
        splat_brick(g, g->data, res, nby[0], b, start);
        if (coarse_here)
            add_coarse(g->data, res, g->coarse[0], res_l[1], cbox[1], z0, z1, y0, y1);
        /* The maxima of the brick's 8^3 blocks, lane by lane in 8-lane accumulators (a row's
         * 8 samples of a block are one vector), reduced once per block; the grid's maximum is
         * theirs. Maxima are exact, so the order does not matter. */
        nc_v8f acc[BRICK_ROWS / 8][(NACRE_PARTICLES_GRID_MAX + 7) / 8];
        const uint32_t full = res / 8;
        for (uint32_t yb = 0; yb < bys; yb++)
            for (uint32_t xb = 0; xb < bres; xb++)
                acc[yb][xb] = nc_v8_splat(0.0f);
        for (uint32_t z = z0; z < z1; z++)
            for (uint32_t y = y0; y < y1; y++) {
                const float *p = g->data + z * nxy + y * nx;
                nc_v8f *a = acc[(y - y0) / 8];
                for (uint32_t xb = 0; xb < full; xb++) {
                    const nc_v8f v = nc_v8_load(p + 8 * xb);
                    a[xb] = nc_v8_sel(v > a[xb], v, a[xb]);
                }
                for (uint32_t x = 8 * full; x < res; x++)
                    a[full][x - 8 * full] = p[x] > a[full][x - 8 * full] ? p[x] : a[full][x - 8 * full];
            }
        float m = 0.0f;
        for (uint32_t yb = 0; yb < bys; yb++)
            for (uint32_t xb = 0; xb < bres; xb++) {
                float bm = 0.0f;
                for (int k = 0; k < 8; k++)
                    bm = acc[yb][xb][k] > bm ? acc[yb][xb][k] : bm;
                braw[(size_t)yb * bres + xb] = bm;
                m = bm > m ? bm : m;
            }
        gmax = m > gmax ? m : gmax;
    }
    g->max_value = gmax;
    g->dirty_res = res;
    /* Each block's maximum with its neighbours' (a lookup's upper corner may lie in the next
     * block), one axis at a time. */
    float *raw = g->block_raw, *bm = g->block_max;
    for (int axis = 0; axis < 3; axis++) {
        const size_t step = axis == 0 ? 1 : (axis == 1 ? bres : (size_t)bres * bres);
        for (size_t i = 0; i < blocks; i++) {
            const uint32_t c = (uint32_t)(i / step % bres);
            float v = raw[i];
            if (c > 0 && raw[i - step] > v)
                v = raw[i - step];
            if (c + 1 < bres && raw[i + step] > v)
                v = raw[i + step];
            bm[i] = v;
        }
        float *t = raw;
        raw = bm;
        bm = t;
    }
    /* After three swaps the result is in raw's array. */
    if (raw != g->block_max)
        memcpy(g->block_max, raw, blocks * sizeof(float));
    g->block_res = bres;
    return NACRE_OK;
}
