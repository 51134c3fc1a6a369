/*
 * splat.c: voxelized particles (seed 003 §3.2.1). The seed rasterizes each particle into a 3D
 * texture with atomic integer adds; on the CPU the grid is cut into slabs of z layers,
 * each slab owned by one thread, and every slab adds its particles in index order. No two
 * threads write one cell and the order of the additions into a cell is fixed, so the grid is the
 * same bit for bit whatever the thread count, without atomics.
 *
 * Mass: a particle's kernel (nacre/particles.h) is sampled at the cell centres it covers and the
 * samples are scaled so that they sum to its mass m = d0 (K R)^3 divided by the cell volume.
 * Point-sampling alone would gain or lose mass depending on where the particle falls between
 * samples (by tens of percent once R is near a cell); normalised, the grid holds exactly the
 * particles' mass, and with the two empty outer layers the trilinear field the renderers
 * sample integrates to the same number. A particle whose kernel misses every sample centre along
 * an axis (R under half a cell) deposits there by linear weights on the two nearest samples.
 */
#include "particles/billboard.h"
#include "particles/particles.h"

#include <math.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif

/* z layers per slab: about four slabs per thread (at least 4 layers), enough to balance the
 * threads while a particle's weights are computed once per slab it overlaps. The grid does not
 * depend on the slab size: every cell sums its particles in index order whatever the slabs. */
static uint32_t slab_layers(uint32_t res, int threads)
{
    uint32_t n = (res + 4u * (uint32_t)threads - 1) / (4u * (uint32_t)threads);
    return n < 4u ? 4u : n;
}

void nc_particle_grid_free(nacre_context *ctx, nc_particle_grid *g)
{
    nc_free(ctx, g->data);
    nc_free(ctx, g->range);
    nc_free(ctx, g->scale);
    nc_free(ctx, g->bin_start);
    nc_free(ctx, g->bins);
    nc_free(ctx, g->weights);
    memset(g, 0, sizeof(*g));
}

/* Grow *p (elem bytes each) to hold n; keeps nothing. */
static bool ensure(nacre_context *ctx, void **p, size_t *cap, size_t n, size_t elem)
{
    if (n <= *cap && *p)
        return true;
    nc_free(ctx, *p);
    *p = nc_alloc(ctx, n * elem);
    *cap = *p ? n : 0;
    return *p != NULL;
}

/* Kernel weights along one axis: samples lo..hi (returned) around centre c. */
static float axis_weights(double c, double R, double origin, double h, int32_t n, int32_t *lo, int32_t *hi,
                          float *w)
{
    double f = (c - origin) / h;
    int32_t a = (int32_t)ceil(f - R / h), b = (int32_t)floor(f + R / h);
    if (a < 0)
        a = 0;
    if (b > n - 1)
        b = n - 1;
    float sum = 0.0f;
    for (int32_t i = a; i <= b; i++) {
        float t = (float)((origin + i * h - c) / R);
        w[i - a] = nc_fast_exp(-NC_PARTICLE_KERNEL_A * t * t);
        sum += w[i - a];
    }
    if (!(sum > 0.0f)) {
        a = (int32_t)floor(f);
        if (a < 0)
            a = 0;
        if (a > n - 2)
            a = n - 2;
        float fr = (float)(f - a);
        fr = fr < 0.0f ? 0.0f : (fr > 1.0f ? 1.0f : fr);
        w[0] = 1.0f - fr;
        w[1] = fr;
        b = a + 1;
        sum = 1.0f;
    }
    *lo = a;
    *hi = b;
    return sum;
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
    /* min and max are exact, so the reduction's order does not matter. */
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads(nc_threads(ctx)) \
    reduction(min : lo0, lo1, lo2) reduction(max : hi0, hi1, hi2)
#endif
    for (uint32_t i = 0; i < n; i++) {
        float r = s->radius[i];
        lo0 = fminf(lo0, s->x[i] - r);
        lo1 = fminf(lo1, s->y[i] - r);
        lo2 = fminf(lo2, s->z[i] - r);
        hi0 = fmaxf(hi0, s->x[i] + r);
        hi1 = fmaxf(hi1, s->y[i] + r);
        hi2 = fmaxf(hi2, s->z[i] + r);
    }
    const float lo[3] = {lo0, lo1, lo2}, hi[3] = {hi0, hi1, hi2};
    for (int a = 0; a < 3; a++) {
        if (!(isfinite(lo[a]) && isfinite(hi[a])))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "particles: positions: not finite");
        g->dims[a] = res;
        /* Two empty layers of samples outside the bounds on each side. */
        double h = ((double)hi[a] - lo[a]) / (res - 4);
        g->spacing[a] = (float)h;
        g->origin[a] = (float)(lo[a] - 1.5 * h);
    }
    const size_t cells = (size_t)res * res * res;
    const int threads = nc_threads(ctx) > 0 ? nc_threads(ctx) : 1;
    const uint32_t SLAB = slab_layers(res, threads), slabs = (res + SLAB - 1) / SLAB;
    nacre_result r = nc_memory_check(ctx, (uint64_t)cells * sizeof(float), "particle density grid (grid_resolution)");
    if (r != NACRE_OK)
        return r;
    bool ok = ensure(ctx, (void **)&g->data, &g->capacity, cells, sizeof(float));
    ok = ok && ensure(ctx, (void **)&g->range, &g->range_capacity, 6 * (size_t)n, sizeof(int32_t));
    ok = ok && ensure(ctx, (void **)&g->scale, &g->scale_capacity, n, sizeof(float));
    ok = ok && ensure(ctx, (void **)&g->bin_start, &g->bin_start_capacity, slabs + 1, sizeof(uint32_t));
    ok = ok && ensure(ctx, (void **)&g->weights, &g->weight_capacity, (size_t)threads * 3 * res, sizeof(float));
    if (!ok)
        return NACRE_ERROR_OUT_OF_MEMORY;

    /* Per particle: its sample range and the factor that makes its samples sum to its mass. */
    const double V = (double)g->spacing[0] * g->spacing[1] * g->spacing[2];
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads(threads)
#endif
    for (uint32_t i = 0; i < n; i++) {
        int tid = 0;
#ifdef _OPENMP
        tid = omp_get_thread_num();
#endif
        float *w = g->weights + (size_t)tid * 3 * res;
        const double c[3] = {s->x[i], s->y[i], s->z[i]};
        int32_t *rg = g->range + 6 * (size_t)i;
        double sum = 1.0;
        for (int a = 0; a < 3; a++)
            sum *= axis_weights(c[a], s->radius[i], g->origin[a], g->spacing[a], (int32_t)res, &rg[2 * a],
                                &rg[2 * a + 1], w);
        double kr = (double)NC_PARTICLE_KERNEL_K * s->radius[i];
        double mass = (double)s->density[i] * kr * kr * kr;
        g->scale[i] = (float)(mass / (sum * V));
    }

    /* Bin particles by z slab, in index order (counting sort). */
    memset(g->bin_start, 0, (slabs + 1) * sizeof(uint32_t));
    for (uint32_t i = 0; i < n; i++) {
        const int32_t *rg = g->range + 6 * (size_t)i;
        for (uint32_t b = (uint32_t)rg[4] / SLAB; b <= (uint32_t)rg[5] / SLAB; b++)
            g->bin_start[b + 1]++;
    }
    for (uint32_t b = 0; b < slabs; b++)
        g->bin_start[b + 1] += g->bin_start[b];
    if (!ensure(ctx, (void **)&g->bins, &g->bin_capacity, g->bin_start[slabs] + 1, sizeof(uint32_t)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    {
        /* Fill with a running cursor per slab, kept in the slab's end slot then restored. */
        for (uint32_t i = 0; i < n; i++) {
            const int32_t *rg = g->range + 6 * (size_t)i;
            for (uint32_t b = (uint32_t)rg[4] / SLAB; b <= (uint32_t)rg[5] / SLAB; b++)
                g->bins[g->bin_start[b]++] = i;
        }
        for (uint32_t b = slabs; b > 0; b--)
            g->bin_start[b] = g->bin_start[b - 1];
        g->bin_start[0] = 0;
    }

    const size_t nx = res, nxy = (size_t)res * res;
    float gmax = 0.0f;
#ifdef _OPENMP
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads) reduction(max : gmax)
#endif
    for (uint32_t b = 0; b < slabs; b++) {
        int tid = 0;
#ifdef _OPENMP
        tid = omp_get_thread_num();
#endif
        float *wx = g->weights + (size_t)tid * 3 * res, *wy = wx + res, *wz = wy + res;
        const uint32_t z0 = b * SLAB, z1 = z0 + SLAB < res ? z0 + SLAB : res; /* [z0, z1) */
        float *slab = g->data + z0 * nxy;
        memset(slab, 0, (z1 - z0) * nxy * sizeof(float));
        for (uint32_t e = g->bin_start[b]; e < g->bin_start[b + 1]; e++) {
            const uint32_t i = g->bins[e];
            const int32_t *rg = g->range + 6 * (size_t)i;
            int32_t a0, a1;
            axis_weights(s->x[i], s->radius[i], g->origin[0], g->spacing[0], (int32_t)res, &a0, &a1, wx);
            axis_weights(s->y[i], s->radius[i], g->origin[1], g->spacing[1], (int32_t)res, &a0, &a1, wy);
            axis_weights(s->z[i], s->radius[i], g->origin[2], g->spacing[2], (int32_t)res, &a0, &a1, wz);
            const float sc = g->scale[i];
            const int32_t za = rg[4] > (int32_t)z0 ? rg[4] : (int32_t)z0;
            const int32_t zb = rg[5] < (int32_t)z1 - 1 ? rg[5] : (int32_t)z1 - 1;
            const int32_t x0 = rg[0], xn = rg[1] - rg[0] + 1;
            for (int32_t z = za; z <= zb; z++) {
                const float fz = sc * wz[z - rg[4]];
                for (int32_t y = rg[2]; y <= rg[3]; y++) {
                    const float fy = fz * wy[y - rg[2]];
                    float *restrict row = g->data + (size_t)z * nxy + (size_t)y * nx + (size_t)x0;
                    for (int32_t x = 0; x < xn; x++)
                        row[x] += fy * wx[x];
                }
            }
        }
        /* Eight running maxima in registers: one accumulator in memory (the reduction
         * variable) kept this scan scalar, and it cost most of a sparse splat. */
        float m8[8] = {0};
        const size_t count = (z1 - z0) * nxy;
        size_t c = 0;
        for (; c + 8 <= count; c += 8)
            for (int k = 0; k < 8; k++)
                m8[k] = slab[c + k] > m8[k] ? slab[c + k] : m8[k];
        for (; c < count; c++)
            m8[0] = slab[c] > m8[0] ? slab[c] : m8[0];
        for (int k = 0; k < 8; k++)
            gmax = m8[k] > gmax ? m8[k] : gmax;
    }
    g->max_value = gmax;
    return NACRE_OK;
}
