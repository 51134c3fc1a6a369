/*
 * solver.c: steady-state diffusion of light inside a voxelized object (Blanchard 2012 section
 * 2.4 and 4.5), per RGB channel:  div(D grad phi) - sigma_a phi + S = 0  on the solid cells,
 * with the Robin boundary condition of Arbree et al. (seed eq. 4.7) on every exposed face.
 * Units: see diffusion.h (sources in W per cell, phi fluence, lengths in scene units).
 *
 * This file holds the entry points of diffusion.h: create / destroy, the coefficient queries,
 * and nc_diff_solve_rgb, which moves the sources into the solver's padded layout, runs one of
 * the two solvers, reports the energy balance (injected = absorbed + escaped at convergence)
 * and writes phi back to the caller's grid. The rest of the solver:
 *   solver_setup.c     the discretization and its operators (nc_diff_setup): fine level, Robin
 *                      boundary, coarse levels (Galerkin), the coarsest level's inverse;
 *   multigrid.c        MULTIGRID (default): PCG with a multigrid W-cycle, warm start;
 *   seed_solver.c      SEED: the seed's Jacobi cascade, for reproducing its numbers;
 *   solver_internal.h  the shared structures and per-cell kernels.
 */
#include "diffusion/solver_internal.h"

nacre_result nc_diff_solver_create(nacre_context *ctx, nc_diff_solver **out)
{
    if (!ctx || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    *out = nc_calloc(ctx, 1, sizeof(**out));
    if (!*out)
        return NACRE_ERROR_OUT_OF_MEMORY;
    (*out)->ctx = ctx;
    return NACRE_OK;
}

void nc_diff_solver_destroy(nc_diff_solver *s)
{
    if (!s)
        return;
    for (int i = 0; i < MAX_LEVELS; i++) {
        nc_diff_level_free(s->ctx, &s->lv[i]);
        nc_free(s->ctx, s->span[i]);
        nc_free(s->ctx, s->span_old[i]);
    }
    nc_free(s->ctx, s->part);
    nc_free(s->ctx, s->hot);
    nc_free(s->ctx, s->touched);
    nc_free(s->ctx, s->mark);
    nc_free(s->ctx, s->out_span);
    nc_diff_extras_free(s);
    for (int c = 0; c < 3; c++)
        nc_free(s->ctx, s->d_user[c]);
    nc_free(s->ctx, s);
}

const float *nc_diff_coefficient_d(const nc_diff_solver *s, int channel, float *uniform)
{
    if (!s || channel < 0 || channel > 2)
        return NULL;
    if (s->homogeneous) {
        *uniform = s->dconst[channel];
        return NULL;
    }
    return s->d_user[channel];
}

double nc_diff_boundary_area(const nc_diff_solver *s)
{
    if (!s || s->level_count == 0)
        return 0.0;
    const level *l = &s->lv[0];
    double sum = 0.0;
    for (size_t i = 0; i < l->cells; i++)
        sum += l->bw[i];
    return sum * (double)s->h * (double)s->h;
}

/* Energy from the final phi x and the sources b into rep: injected, absorbed and escaped power
 * per channel (injected = absorbed + escaped at convergence). */
static void energy_report(const nc_diff_solver *s, const v4 *b, const v4 *x, nc_diff_solve_report rep[3])
{
    const level *l = &s->lv[0];
    const uint32_t cy = l->n[1], cz = l->n[2];
    const int threads = s->ctx->threads;
    /* Per-slab sums added in slab order (independent of the thread count). */
    v4d *part = s->part, *pabs = s->part + (cz + 2), *pesc = s->part + 2 * ((size_t)cz + 2);
#pragma omp parallel for num_threads(threads) schedule(static, 1) if (l->cells > 32768)
    FOR_SLABS(l, z) {
        v4d si = {0, 0, 0, 0}, sa = {0, 0, 0, 0}, se = {0, 0, 0, 0};
        for (uint32_t y = 1; y <= cy; y++) {
            size_t a, e;
            row_span(l, y, z, &a, &e);
            for (size_t i = a; i < e; i++) {
                v4d xi = widen(x[i]);
                si += widen(b[i]);
                sa += widen(s->homogeneous ? s->aconst : s->absorb[i]) * xi;
                se += widen(s->homogeneous ? robin_bnd(l->bw[i], s->dconst, s->bden, s->h) : s->bnd[i]) * xi;
            }
        }
        part[z] = si;
        pabs[z] = sa;
        pesc[z] = se;
    }
    v4d inj = sum_slabs(part, cz), abs_ = sum_slabs(pabs, cz), esc = sum_slabs(pesc, cz);
    for (int c = 0; c < 3; c++) {
        rep[c].injected = inj[c];
        rep[c].absorbed = abs_[c];
        rep[c].escaped = esc[c];
    }
}

nacre_result nc_diff_solve_rgb(nc_diff_solver *s, const float *const source[3], float *const phi[3],
                               const nc_diff_solve_opts *opts, nc_diff_solve_report report[3])
{
    if (!s || !source || !phi || !opts || s->level_count == 0)
        return NACRE_ERROR_INVALID_ARGUMENT;
    level *l = &s->lv[0];
    const uint32_t nx = s->dims[0], ny = s->dims[1], *off = s->off;
    const uint32_t cy = l->n[1], cz = l->n[2];
    const int threads = s->ctx->threads;
    v4 *b = l->b, *x = s->px;
    /* Into the padded layout, active spans only (x is zero elsewhere, b is not read there);
     * outside cells take no source. A NULL channel solves nothing. */
    int dirty = 0, any_fresh = 0;
    const bool warm = opts->warm_start && opts->solver == NACRE_SOLVER_MULTIGRID;
    uint8_t *fresh = l->fresh, *row_fresh = l->fresh + l->cells;
#pragma omp parallel for num_threads(threads) schedule(static, 1) reduction(| : dirty, any_fresh) if (l->cells > 32768)
    FOR_SLABS(l, z)
        for (uint32_t y = 1; y <= cy; y++) {
            size_t a, e, row = l->sy * y + l->sz * z;
            row_span(l, y, z, &a, &e);
            /* user index of padded cell i: u0 + (i - row) */
            size_t u0 = (size_t)off[0] - 1 + (size_t)nx * ((y - 1 + off[1]) + (size_t)ny * (z - 1 + off[2]));
            int row_any = 0;
            for (size_t i = a; i < e; i++) {
                size_t u = u0 + (i - row);
                v4 bv = V4_ZERO, xv = V4_ZERO;
                if (l->solid[i])
                    for (int c = 0; c < 3; c++) {
                        if (!source[c])
                            continue;
                        float v = source[c][u];
                        dirty |= !isfinite(v);
                        bv[c] = v;
                        if (opts->warm_start && phi[c] && isfinite(phi[c][u]))
                            xv[c] = phi[c][u];
                    }
                b[i] = bv;
                x[i] = xv;
                if (warm) {
                    /* a solid cell that was outside the previous domain comes with 0 */
                    int f = l->solid[i] && xv[0] == 0.0f && xv[1] == 0.0f && xv[2] == 0.0f;
                    fresh[i] = (uint8_t)f;
                    row_any |= f;
                }
            }
            if (warm)
                row_fresh[y + ((size_t)cy + 2) * z] = (uint8_t)row_any;
            any_fresh |= row_any;
        }
    if (dirty)
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "diffusion: non-finite source");
    nc_diff_solve_report rep[3];
    memset(rep, 0, sizeof(rep));
    /* The two solvers want differently scaled coarse operators: rebuild them on a switch (a
     * setup's cost, paid only by callers that alternate). */
    float scale = opts->solver == NACRE_SOLVER_SEED ? SEED_G_SCALE : COARSE_G_SCALE;
    if (s->coarse_scale != scale)
        nc_diff_build_coarse_levels(s, scale, false, threads);
    if (opts->solver == NACRE_SOLVER_SEED) {
        nc_diff_solve_seed(s, b, x, opts, rep);
    } else {
        if (warm && any_fresh)
            nc_diff_warm_fill(l, x, b, threads);
        nc_diff_solve_pcg(s, b, x, opts, rep);
    }
    if (!opts->no_energy)
        energy_report(s, b, x, rep);
    /* Out to the caller's grid, 0 outside the domain (the bounding box included): each cell
     * written once, in parallel (a serial clear of the whole grid first cost as much as a
     * third of a PCG iteration at 128^3). When phi still holds the last output, only the
     * previous spans need zeros where the new ones do not reach: the whole grid was 25 MB of
     * writes per frame at 128^3 for 3 MB of solution. */
    const uint32_t uz = s->dims[2];
    const size_t user_rows = (size_t)ny * uz;
    const bool same = opts->phi_unchanged && s->out_valid && memcmp(s->out_dims, s->dims, sizeof(s->dims)) == 0 &&
                      memcmp(s->out_phi, phi, sizeof(s->out_phi)) == 0;
    s->out_valid = false;
    if (!nc_reserve(s->ctx, &s->out_span, &s->out_span_capacity, user_rows, 2 * sizeof(uint32_t)))
        return nc_fail(s->ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory");
    uint32_t *ospan = s->out_span;
#pragma omp parallel for num_threads(threads) schedule(static) if (l->cells > 32768)
    for (uint32_t zu = 0; zu < uz; zu++)
        for (uint32_t yu = 0; yu < ny; yu++) {
            size_t u0 = (size_t)nx * (yu + (size_t)ny * zu);
            /* padded row of the box, if any; [lo, hi): the user x range of its span */
            uint32_t z = zu - off[2] + 1, y = yu - off[1] + 1;
            size_t a = 0, e = 0, row = 0, lo = 0, hi = 0;
            if (zu >= off[2] && z <= cz && yu >= off[1] && y <= cy) {
                row = l->sy * y + l->sz * z;
                row_span(l, y, z, &a, &e);
                lo = off[0] + (a - row) - 1;
                hi = lo + (e - a);
            }
            /* the zeros: [0, lo) and [hi, nx), or of those only what the last output wrote */
            uint32_t *os = ospan + 2 * (yu + (size_t)ny * zu);
            int64_t zr[4];
            nc_range_minus(same ? os[0] : 0, same ? os[1] : nx, (int64_t)lo, (int64_t)hi, zr);
            os[0] = (uint32_t)lo;
            os[1] = (uint32_t)hi;
            for (int c = 0; c < 3; c++) {
                float *out = phi[c];
                if (!out)
                    continue;
                for (int k = 0; k < 4; k += 2)
                    if (zr[k + 1] > zr[k])
                        memset(out + u0 + zr[k], 0, (size_t)(zr[k + 1] - zr[k]) * sizeof(float));
                for (size_t i = a; i < e; i++)
                    out[u0 + lo + (i - a)] = x[i][c];
            }
        }
    s->out_valid = true;
    memcpy(s->out_dims, s->dims, sizeof(s->dims));
    memcpy(s->out_phi, phi, sizeof(s->out_phi));
    if (report)
        memcpy(report, rep, sizeof(rep));
    return NACRE_OK;
}

nacre_result nc_diff_solve(nc_diff_solver *s, int channel, const float *source, float *phi,
                           const nc_diff_solve_opts *opts, nc_diff_solve_report *report)
{
    if (!s || channel < 0 || channel > 2 || !source || !phi)
        return NACRE_ERROR_INVALID_ARGUMENT;
    const float *src[3] = {NULL, NULL, NULL};
    float *out[3] = {NULL, NULL, NULL};
    src[channel] = source;
    out[channel] = phi;
    nc_diff_solve_report rep[3];
    nacre_result res = nc_diff_solve_rgb(s, src, out, opts, rep);
    if (res == NACRE_OK && report)
        *report = rep[channel];
    return res;
}
