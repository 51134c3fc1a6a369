/*
 * seed_solver.c: the seed's scheme (NACRE_SOLVER_SEED, Blanchard 2012 section 4.5), kept for
 * reproducing its numbers: Jacobi sweeps with fixed counts on the levels from 4 cells up (tables
 * 4.3 and 5.6), each level started from the coarser one's result (piecewise-constant
 * prolongation). Its coarse operators keep the re-discretization's 1/2 conductance scaling
 * (SEED_G_SCALE, solver_setup.c). Units as in diffusion.h.
 *
 * Sources are restricted to the coarse levels by summation (power is additive), which is the
 * seed's "inject on every level" (section 4.4) done once.
 */
#include "diffusion/solver_internal.h"

/* out = b - M v over the active cells (the seed scheme's Jacobi update reads it). */
static void apply(const level *l, const v4 *v, const v4 *b, v4 *out, int threads)
{
    const uint32_t ny = l->n[1], nz = l->n[2];
#pragma omp parallel for num_threads(threads) schedule(static) if (l->cells > 32768)
    for (uint32_t z = 1; z <= nz; z++)
        for (uint32_t y = 1; y <= ny; y++) {
            size_t a, e;
            row_span(l, y, z, &a, &e);
            for (size_t i = a; i < e; i++)
                out[i] = b[i] - (cell_diag(l, i) * v[i] - cell_offdiag(l, v, i));
        }
}

/* fine += the coarse value of the parent (piecewise constant), inside the domain only (the
 * seed's cascade; the multigrid cycle prolongs inside gs_prolong). */
static void prolong_add(const level *f, const level *l, const v4 *coarse, v4 *fine, int threads)
{
    const uint32_t sh = l->r[0] == 2 ? 1 : 0;
#pragma omp parallel for num_threads(threads) schedule(static) if (f->cells > 32768)
    for (uint32_t z = 1; z <= f->n[2]; z++)
        for (uint32_t y = 1; y <= f->n[1]; y++) {
            size_t a, e, row = f->sy * y + f->sz * z;
            row_span(f, y, z, &a, &e);
            size_t crow = l->sy * ((y - 1) / l->r[1] + 1) + l->sz * ((z - 1) / l->r[2] + 1) + 1;
            for (size_t i = a; i < e; i++)
                if (f->solid[i])
                    fine[i] += coarse[crow + ((i - row - 1) >> sh)];
        }
}

/* The seed's iteration counts per level size (tables 5.1 and 5.6), extended linearly in the
 * size past 32 as the counts grow with the number of cells to cross. */
static uint32_t seed_sweeps(uint32_t n)
{
    if (n <= 4)
        return 8;
    if (n <= 8)
        return 16;
    if (n <= 16)
        return 38;
    if (n <= 32)
        return 66;
    return (uint32_t)ceil(66.0 * n / 32.0);
}

static uint32_t max_dim(const level *l)
{
    uint32_t m = l->n[0] > l->n[1] ? l->n[0] : l->n[1];
    return m > l->n[2] ? m : l->n[2];
}

/* The seed's scheme: each level starts from the coarser level's result, then plain Jacobi. */
void nc_diff_solve_seed(nc_diff_solver *s, const v4 *b, v4 *x, const nc_diff_solve_opts *o, nc_diff_solve_report rep[3])
{
    const int threads = s->ctx->threads;
    uint32_t top = 0; /* the coarsest level with a side of at least 4 cells (the seed's smallest) */
    for (uint32_t li = 1; li < s->level_count && !o->seed_single_grid; li++) {
        if (max_dim(&s->lv[li]) < 4)
            break;
        top = li;
    }
    for (uint32_t li = 1; li <= top; li++)
        nc_diff_restrict_rows(&s->lv[li - 1], &s->lv[li], NULL, li == 1 ? b : s->lv[li - 1].b, s->lv[li].b, threads);
    uint32_t total = 0;
    for (int li = (int)top; li >= 0; li--) {
        level *l = &s->lv[li];
        v4 *xl = li == 0 ? x : l->x;
        const v4 *bl = li == 0 ? b : l->b;
        if (li < (int)top) {
            memset(xl, 0, l->cells * sizeof(v4));
            prolong_add(l, &s->lv[li + 1], s->lv[li + 1].x, xl, threads);
        } else if (!(li == 0 && o->warm_start)) {
            memset(xl, 0, l->cells * sizeof(v4));
        }
        uint32_t sweeps = (li == 0 && o->seed_iterations) ? o->seed_iterations : seed_sweeps(max_dim(l));
        for (uint32_t k = 0; k < sweeps; k++) {
            apply(l, xl, bl, l->res, threads);
            for (uint32_t z = 1; z <= l->n[2]; z++)
                for (uint32_t y = 1; y <= l->n[1]; y++) {
                    size_t a, e;
                    row_span(l, y, z, &a, &e);
                    for (size_t i = a; i < e; i++)
                        xl[i] += l->res[i] / cell_diag(l, i);
                }
        }
        total += sweeps;
    }
    level *l0 = &s->lv[0];
    v4d bb;
    v4d rr = nc_diff_residual_exact(l0, x, b, l0->res, &bb, true, s->part, threads);
    for (int c = 0; c < 3; c++) {
        rep[c].iterations = total;
        rep[c].residual = bb[c] > 0 ? sqrt(rr[c] / bb[c]) : 0.0;
    }
}
