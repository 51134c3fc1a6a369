/*
 * bench_diffusion_solver.c: `nacre bench diffusion`, solver part. The propagation step alone
 * (src/diffusion/solver.c) on a sphere inscribed in an N^3 grid, a marble-like medium (sigma_a
 * 0.0021, sigma_s' 2.19 per mm, eta 1.3: Jensen et al. 2001) of 20 mm diameter, lit on its top
 * cap (the source a directional light from +z leaves, deposited over the first reduced mean free
 * path):
 *   - the seed's table 4.3 (iterations to converge: single grid vs multi-resolution) beside
 *     ours: Jacobi sweeps on the single grid and on the resolution cascade (the finest level's
 *     count; coarser levels run the seed's counts first) to reach a relative residual of 1e-2, and
 *     multigrid-preconditioned CG iterations to 1e-2 and 1e-4;
 *   - time of one converged propagation (1e-4, cold and warm-started after the light moved)
 *     at 32^3 .. 256^3, median of --runs: one channel (nc_diff_solve) and all three at once
 *     (nc_diff_solve_rgb, what the renderer runs).
 */
#include "bench.h"
#include "diffusion/diffusion.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct sphere {
    uint32_t n;
    uint8_t *solid;
    float *src, *src2, *phi, *phi2, *phi3;
} sphere;

/* Source of a light from direction (0, sin t, cos t): cells within one reduced mean free path
 * of the lit surface, weighted by the cosine. */
static void sphere_source(const sphere *s, float *src, double tilt)
{
    uint32_t n = s->n;
    double c = 0.5 * n, r = 0.5 * n - 0.5, h = 20.0 / n, l = 1.0 / 2.19;
    double dir[3] = {0.0, sin(tilt), cos(tilt)};
    for (uint32_t z = 0; z < n; z++)
        for (uint32_t y = 0; y < n; y++)
            for (uint32_t x = 0; x < n; x++) {
                size_t i = x + (size_t)n * (y + (size_t)n * z);
                src[i] = 0.0f;
                if (!s->solid[i])
                    continue;
                double p[3] = {x + 0.5 - c, y + 0.5 - c, z + 0.5 - c};
                double d = sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
                double cosn = d > 0 ? (p[0] * dir[0] + p[1] * dir[1] + p[2] * dir[2]) / d : 0;
                double depth = (r - d) * h;
                if (cosn > 0 && depth < l)
                    src[i] = (float)(cosn * h * h * h);
            }
}

static bool sphere_make(sphere *s, uint32_t n)
{
    size_t cells = (size_t)n * n * n;
    s->n = n;
    s->solid = calloc(cells, 1);
    s->src = calloc(cells, sizeof(float));
    s->src2 = calloc(cells, sizeof(float));
    s->phi = calloc(cells, sizeof(float));
    s->phi2 = calloc(cells, sizeof(float));
    s->phi3 = calloc(cells, sizeof(float));
    if (!s->solid || !s->src || !s->src2 || !s->phi || !s->phi2 || !s->phi3)
        return false;
    double c = 0.5 * n, r = 0.5 * n - 0.5;
    for (uint32_t z = 0; z < n; z++)
        for (uint32_t y = 0; y < n; y++)
            for (uint32_t x = 0; x < n; x++) {
                double p[3] = {x + 0.5 - c, y + 0.5 - c, z + 0.5 - c};
                s->solid[x + (size_t)n * (y + (size_t)n * z)] = p[0] * p[0] + p[1] * p[1] + p[2] * p[2] <= r * r;
            }
    sphere_source(s, s->src, 0.0);
    sphere_source(s, s->src2, 0.15); /* the light moved by ~9 degrees */
    return true;
}

static void sphere_free(sphere *s)
{
    free(s->solid);
    free(s->src);
    free(s->src2);
    free(s->phi);
    free(s->phi2);
    free(s->phi3);
}

static nacre_result setup(nc_diff_solver *solver, const sphere *s)
{
    nc_diff_medium m = {.dims = {s->n, s->n, s->n}, .h = 20.0f / s->n, .solid = s->solid, .eta = 1.3f,
                        .sigma_a_const = {0.0021f, 0.0041f, 0.0071f}, .sigma_sp_const = {2.19f, 2.62f, 3.00f}};
    return nc_diff_setup(solver, &m);
}

/* Smallest finest-level Jacobi sweep count reaching `tol` (doubling, then bisection); 0 if
 * more than `cap` are needed. */
static uint32_t seed_sweeps_to(nc_diff_solver *solver, sphere *s, double tol, bool single_grid, uint32_t cap)
{
    uint32_t lo = 0, hi = 1;
    nc_diff_solve_report rep;
    nc_diff_solve_opts o = {.solver = NACRE_SOLVER_SEED, .seed_single_grid = single_grid};
    for (;;) {
        o.seed_iterations = hi;
        if (nc_diff_solve(solver, 0, s->src, s->phi, &o, &rep) != NACRE_OK)
            return 0;
        if (rep.residual <= tol)
            break;
        lo = hi;
        hi *= 2;
        if (hi > cap)
            return 0;
    }
    while (hi - lo > 1) {
        o.seed_iterations = lo + (hi - lo) / 2;
        if (nc_diff_solve(solver, 0, s->src, s->phi, &o, &rep) != NACRE_OK)
            return 0;
        if (rep.residual <= tol)
            hi = o.seed_iterations;
        else
            lo = o.seed_iterations;
    }
    return hi;
}

int nc_bench_diffusion_solver(bool json, int runs)
{
    nacre_context *ctx = nc_tool_context(0);
    if (!ctx)
        return 2;
    int rc = 2;
    double *samples = calloc((size_t)runs * 3, sizeof(double));
    nc_diff_solver *solver = NULL;
    if (!samples || nc_diff_solver_create(ctx, &solver) != NACRE_OK)
        goto out;

    /* Table 4.3 */
    static const struct { uint32_t n; int single, multi; } t43[] = {{8, 34, 20}, {16, 72, 38}, {32, 142, 66}};
    if (!json)
        printf("iterations to converge (seed table 4.3 beside ours; sphere, marble, red channel)\n"
               "%-6s %12s %12s | %16s %16s %12s %12s\n", "res", "seed_single", "seed_multi", "jacobi_1e-2",
               "cascade_1e-2", "mgcg_1e-2", "mgcg_1e-4");
    for (size_t k = 0; k < sizeof(t43) / sizeof(t43[0]); k++) {
        sphere s;
        if (!sphere_make(&s, t43[k].n) || setup(solver, &s) != NACRE_OK) {
            sphere_free(&s);
            rc = nc_tool_fail(ctx);
            goto out;
        }
        uint32_t single = seed_sweeps_to(solver, &s, 1e-2, true, 1u << 16);
        uint32_t cascade = seed_sweeps_to(solver, &s, 1e-2, false, 1u << 16);
        nc_diff_solve_report rep;
        nc_diff_solve_opts o = {.solver = NACRE_SOLVER_MULTIGRID, .tolerance = 1e-2f};
        nc_diff_solve(solver, 0, s.src, s.phi, &o, &rep);
        uint32_t mg2 = rep.iterations;
        o.tolerance = 1e-4f;
        nc_diff_solve(solver, 0, s.src, s.phi, &o, &rep);
        uint32_t mg4 = rep.iterations;
        if (json)
            printf("{\"bench\":\"diffusion_iterations\",\"res\":%u,\"seed_single\":%d,\"seed_multi\":%d,"
                   "\"jacobi_sweeps_1e-2\":%u,\"cascade_sweeps_1e-2\":%u,\"mgcg_1e-2\":%u,\"mgcg_1e-4\":%u}\n",
                   t43[k].n, t43[k].single, t43[k].multi, single, cascade, mg2, mg4);
        else
            printf("%-6u %12d %12d | %16u %16u %12u %12u\n", t43[k].n, t43[k].single, t43[k].multi, single, cascade,
                   mg2, mg4);
        sphere_free(&s);
    }

    /* Propagation time */
    static const uint32_t sizes[] = {32, 64, 128, 256};
    if (!json)
        printf("\nconverged propagation (1e-4), %d threads, median of %d runs (ms)\n%-6s %10s %8s %10s %8s %12s\n",
               nacre_context_threads(ctx), runs, "res", "cold_1ch", "iters", "warm_1ch", "iters", "cold_3ch");
    for (size_t k = 0; k < sizeof(sizes) / sizeof(sizes[0]); k++) {
        sphere s;
        if (!sphere_make(&s, sizes[k]) || setup(solver, &s) != NACRE_OK) {
            sphere_free(&s);
            rc = nc_tool_fail(ctx);
            goto out;
        }
        size_t cells = (size_t)s.n * s.n * s.n;
        uint32_t it_cold = 0, it_warm = 0;
        double res_cold = 0;
        for (int run = -1; run < runs; run++) {
            nc_diff_solve_report rep;
            nc_diff_solve_opts o = {.solver = NACRE_SOLVER_MULTIGRID, .tolerance = 1e-4f};
            memset(s.phi, 0, cells * sizeof(float));
            uint64_t t0 = nc_tool_now_us();
            nc_diff_solve(solver, 0, s.src, s.phi, &o, &rep);
            uint64_t t1 = nc_tool_now_us();
            it_cold = rep.iterations;
            res_cold = rep.residual;
            o.warm_start = true;
            uint64_t t2 = nc_tool_now_us();
            nc_diff_solve(solver, 0, s.src2, s.phi, &o, &rep);
            uint64_t t3 = nc_tool_now_us();
            it_warm = rep.iterations;
            uint64_t t4 = nc_tool_now_us();
            o.warm_start = false;
            const float *src3[3] = {s.src, s.src, s.src};
            float *phi3[3] = {s.phi, s.phi2, s.phi3};
            nc_diff_solve_rgb(solver, src3, phi3, &o, NULL);
            uint64_t t5 = nc_tool_now_us();
            if (run >= 0) {
                samples[run] = (t1 - t0) / 1000.0;
                samples[runs + run] = (t3 - t2) / 1000.0;
                samples[2 * runs + run] = (t5 - t4) / 1000.0;
            }
        }
        double cold = nc_tool_median(samples, runs), warm = nc_tool_median(samples + runs, runs),
               cold3 = nc_tool_median(samples + 2 * runs, runs);
        if (json)
            printf("{\"bench\":\"diffusion_propagate\",\"res\":%u,\"threads\":%d,\"runs\":%d,\"cold_ms\":%.3f,"
                   "\"cold_iterations\":%u,\"residual\":%.3g,\"warm_ms\":%.3f,\"warm_iterations\":%u,\"cold_3ch_ms\":%.3f}\n",
                   s.n, nacre_context_threads(ctx), runs, cold, it_cold, res_cold, warm, it_warm, cold3);
        else
            printf("%-6u %10.3f %8u %10.3f %8u %12.3f\n", s.n, cold, it_cold, warm, it_warm, cold3);
        fflush(stdout);
        sphere_free(&s);
    }
    rc = 0;
out:
    nc_diff_solver_destroy(solver);
    free(samples);
    nacre_context_destroy(ctx);
    return rc;
}
