/*
 * multigrid.c: the default solver (NACRE_SOLVER_MULTIGRID) of the diffusion equation set up by
 * solver_setup.c: conjugate gradients preconditioned by one multigrid W-cycle, the red-black
 * Gauss-Seidel smoother, and the warm start of a moving object (nc_diff_warm_fill, hot_relax). It
 * replaces the seed's Jacobi cascade (Blanchard 2012 section 4.5, seed_solver.c) for speed;
 * units as in diffusion.h (sources in W per cell, phi fluence).
 *
 * Smoother: red-black Gauss-Seidel, red then black before and black then red after the coarse
 * correction, and each coarse problem gets two cycles of its own level (W), so the cycle is a
 * symmetric operator as conjugate gradients needs; the coarsest level (at most 2x2x2) is solved
 * exactly with the inverse formed at setup. The PCG iteration count stays at 6-7 from 32^3 to
 * 256^3 (a V-cycle: 7 to 11). Stops at ||S - M phi|| <= tol * ||S|| per channel.
 *
 * Passes are fused where the data dependencies allow it without changing the arithmetic: the
 * residual is restricted as it is formed (never stored; at color-0 cells only, the color-1 half
 * sweep before it leaves the others at zero), the CG update of x and r carries the next cycle's
 * first half sweep, the prolongation is read inside the color-1 half sweep after it
 * (gs_prolong), the last half sweep carries r . z, and the new direction p is formed inside the
 * operator pass (double-buffered).
 *
 * Warm start: a moving object is voxelized again every frame, and the cells that enter the
 * domain come with phi = 0; they are filled from their neighbours first (nc_diff_warm_fill), which
 * takes a frame of a rotating mesh from 5-6 PCG iterations to 4. The residual that is left sits
 * in a few boundary cells, which are relaxed locally before the first iteration (hot_relax):
 * 3-3.4 iterations on average at 128^3.
 */
#include "diffusion/solver_internal.h"

/* The same off-diagonal sum with every product in double (nc_diff_residual_exact). */
static inline v4d cell_offdiag_d(const level *l, const v4 *v, size_t i)
{
    const size_t sy = l->sy, sz = l->sz;
    if (l->homogeneous_level)
        return widen(l->kg[l->k[i]]) * (widen(v[i + 1]) + widen(v[i - 1]) + widen(v[i + sy]) + widen(v[i - sy]) +
                                        widen(v[i + sz]) + widen(v[i - sz]));
    const v4 *const *g = (const v4 *const *)l->g;
    return widen(g[0][i]) * widen(v[i + 1]) + widen(g[0][i - 1]) * widen(v[i - 1]) + widen(g[1][i]) * widen(v[i + sy]) +
           widen(g[1][i - sy]) * widen(v[i - sy]) + widen(g[2][i]) * widen(v[i + sz]) +
           widen(g[2][i - sz]) * widen(v[i - sz]);
}

/* First cell of `color` ((x + y + z) % 2, padded coordinates) at or after padded index a of row
 * (y, z) whose first padded cell is `row`. */
static inline size_t color_start(size_t a, size_t row, uint32_t y, uint32_t z, int color)
{
    return a + (((size_t)color + (a - row) + y + z) & 1);
}

/* Conjugate-gradient direction and its image in one pass: p_new = z + beta p_old (p_old not
 * read when first: p_new = z) and q = M p_new, with the per-channel p_new . q. q needs p_new at
 * the six neighbours, which are formed on the fly from z and p_old (double buffer: p_old is
 * not overwritten while neighbours still read it); this saves the separate pass that updated p
 * in place and the re-read of p by the operator. */
static v4d apply_dot_dir(const level *l, const v4 *z, const v4 *p_old, v4 *p_new, v4 *q, v4 beta, bool first,
                         v4d *part, int threads)
{
    const uint32_t ny = l->n[1], nz = l->n[2];
    const size_t sy = l->sy, sz = l->sz;
#pragma omp parallel for num_threads(threads) schedule(static, 1) if (l->cells > 32768)
    FOR_SLABS(l, zz) {
        v4d slab = {0.0, 0.0, 0.0, 0.0};
        for (uint32_t y = 1; y <= ny; y++) {
            size_t a, e;
            row_span(l, y, zz, &a, &e);
            v4 acc = V4_ZERO;
            if (first) {
                for (size_t i = a; i < e; i++) {
                    v4 pi = z[i];
                    v4 mv = cell_diag(l, i) * pi - cell_offdiag(l, z, i);
                    p_new[i] = pi;
                    q[i] = mv;
                    acc += pi * mv;
                }
            } else {
#define DIR(j) (z[j] + beta * p_old[j])
                for (size_t i = a; i < e; i++) {
                    v4 pi = DIR(i), off;
                    if (l->homogeneous_level) {
                        off = l->kg[l->k[i]] *
                              (DIR(i + 1) + DIR(i - 1) + DIR(i + sy) + DIR(i - sy) + DIR(i + sz) + DIR(i - sz));
                    } else {
                        const v4 *const *g = (const v4 *const *)l->g;
                        off = g[0][i] * DIR(i + 1) + g[0][i - 1] * DIR(i - 1) + g[1][i] * DIR(i + sy) +
                              g[1][i - sy] * DIR(i - sy) + g[2][i] * DIR(i + sz) + g[2][i - sz] * DIR(i - sz);
                    }
#undef DIR
                    v4 mv = cell_diag(l, i) * pi - off;
                    p_new[i] = pi;
                    q[i] = mv;
                    acc += pi * mv;
                }
            }
            slab += widen(acc);
        }
        part[zz] = slab;
    }
    return sum_slabs(part, nz);
}

/* x += alpha p, r -= alpha q and the per-channel r . r, and the first Gauss-Seidel half sweep
 * of the next cycle on r (z = r / diag on color-0 cells, see gs_first), in one pass: the
 * half sweep reads only r and the diagonal of the cell, so it needs no neighbour of this pass. */
static v4d update_xr_first(const level *l, v4 *x, v4 *r, const v4 *p, const v4 *q, v4 alpha, v4 *zv, v4d *part,
                           int threads)
{
    const uint32_t ny = l->n[1], nz = l->n[2];
#pragma omp parallel for num_threads(threads) schedule(static, 1) if (l->cells > 32768)
    FOR_SLABS(l, z) {
        v4d slab = {0.0, 0.0, 0.0, 0.0};
        for (uint32_t y = 1; y <= ny; y++) {
            size_t a, e, row = l->sy * y + l->sz * z;
            row_span(l, y, z, &a, &e);
            v4 acc = V4_ZERO;
            for (size_t i = a; i < e; i++) {
                x[i] += alpha * p[i];
                v4 ri = r[i] - alpha * q[i];
                r[i] = ri;
                acc += ri * ri;
            }
            for (size_t i = color_start(a, row, y, z, 0); i < e; i += 2)
                zv[i] = r[i] / cell_diag(l, i);
            slab += widen(acc);
        }
        part[z] = slab;
    }
    return sum_slabs(part, nz);
}

/* out = b - M v with the products summed in double (exact true): near convergence b and M v
 * agree to many digits (high albedo makes the diagonal almost equal the neighbour sum), so a
 * float sum would put a floor of ~1e-5 under the relative residual. exact false: in float, for
 * a residual far from the tolerance (half the cost: the double products are most of it).
 * Returns the per-channel out . out; with bb, also b . b (the pass reads b anyway: saves the
 * separate pass of the first residual). part holds 2 (nz + 2) slabs. */
v4d nc_diff_residual_exact(const level *l, const v4 *v, const v4 *b, v4 *out, v4d *bb, bool exact, v4d *part,
                          int threads)
{
    const uint32_t ny = l->n[1], nz = l->n[2];
    v4d *pb = part + nz + 2;
#pragma omp parallel for num_threads(threads) schedule(static, 1) if (l->cells > 32768)
    FOR_SLABS(l, z) {
        v4d slab = {0.0, 0.0, 0.0, 0.0}, slab_b = slab;
        for (uint32_t y = 1; y <= ny; y++) {
            size_t a, e;
            row_span(l, y, z, &a, &e);
            v4 acc = V4_ZERO, acc_b = V4_ZERO;
            if (exact)
                for (size_t i = a; i < e; i++) {
                    v4 bi = b[i];
                    v4d d = widen(bi) - widen(cell_diag(l, i)) * widen(v[i]) + cell_offdiag_d(l, v, i);
                    v4 o = __builtin_convertvector(d, v4);
                    out[i] = o;
                    acc += o * o;
                    acc_b += bi * bi;
                }
            else
                for (size_t i = a; i < e; i++) {
                    v4 bi = b[i];
                    v4 o = bi - (cell_diag(l, i) * v[i] - cell_offdiag(l, v, i));
                    out[i] = o;
                    acc += o * o;
                    acc_b += bi * bi;
                }
            slab += widen(acc);
            slab_b += widen(acc_b);
        }
        part[z] = slab;
        pb[z] = slab_b;
    }
    if (bb)
        *bb = sum_slabs(pb, nz);
    return sum_slabs(part, nz);
}

/* One red-black Gauss-Seidel half sweep over the cells with (x + y + z) % 2 == color. With
 * `part`, also the per-channel b . v over all active cells after the sweep (the last sweep of a
 * cycle gives the conjugate-gradient r . z this way: the row's cells are in cache). */
static v4d gs_color(const level *l, v4 *v, const v4 *b, int color, v4d *part, int threads)
{
    const uint32_t ny = l->n[1], nz = l->n[2];
#pragma omp parallel for num_threads(threads) schedule(static, 1) if (l->cells > 32768)
    FOR_SLABS(l, z) {
        v4d slab = {0.0, 0.0, 0.0, 0.0};
        for (uint32_t y = 1; y <= ny; y++) {
            size_t a, e, row = l->sy * y + l->sz * z;
            row_span(l, y, z, &a, &e);
            for (size_t i = color_start(a, row, y, z, color); i < e; i += 2)
                v[i] = (b[i] + cell_offdiag(l, v, i)) / cell_diag(l, i);
            if (part) {
                v4 acc = V4_ZERO;
                for (size_t i = a; i < e; i++)
                    acc += b[i] * v[i];
                slab += widen(acc);
            }
        }
        if (part)
            part[z] = slab;
    }
    if (!part) {
        v4d zero = {0.0, 0.0, 0.0, 0.0};
        return zero;
    }
    return sum_slabs(part, nz);
}

/* The first half sweep (color 0) from v = 0, without clearing v first: color-0 cells get
 * b / diag (their neighbours, all of color 1, are 0), exactly what gs_color gives after a
 * clear. Color-1 cells keep whatever they hold: the color-1 half sweep that must follow reads
 * only color-0 neighbours and overwrites every color-1 cell. Saves a pass over v and the
 * neighbour reads. */
static void gs_first(const level *l, v4 *v, const v4 *b, int threads)
{
    const uint32_t ny = l->n[1];
#pragma omp parallel for num_threads(threads) schedule(static, 1) if (l->cells > 32768)
    FOR_SLABS(l, z)
        for (uint32_t y = 1; y <= ny; y++) {
            size_t a, e, row = l->sy * y + l->sz * z;
            row_span(l, y, z, &a, &e);
            for (size_t i = color_start(a, row, y, z, 0); i < e; i += 2)
                v[i] = b[i] / cell_diag(l, i);
        }
}

/* Coarse b = sum over the children of the fine residual b - M v (v non-NULL) or of the fine b
 * itself (v NULL). The residual is formed row by row and summed at once, never stored. v comes
 * from a color-1 half sweep, which leaves every color-1 cell satisfying its equation exactly:
 * its residual is zero (up to rounding), so only color-0 cells are summed. Each
 * coarse slab gathers its own children in a fixed order, so slabs run in parallel and the sums
 * do not depend on the thread count. Coarse cells outside the coarse rows' spans are not
 * written (they stay 0); every fine active cell lies inside its parent's span. */
void nc_diff_restrict_rows(const level *f, const level *l, const v4 *v, const v4 *b, v4 *coarse, int threads)
{
    const uint32_t sh = l->r[0] == 2 ? 1 : 0;
#pragma omp parallel for num_threads(threads) schedule(static, 1) if (f->cells > 32768)
    FOR_SLABS(l, Z) {
        for (uint32_t Y = 1; Y <= l->n[1]; Y++) {
            size_t a, e;
            row_span(l, Y, Z, &a, &e);
            for (size_t i = a; i < e; i++)
                coarse[i] = V4_ZERO;
        }
        for (uint32_t z = (Z - 1) * l->r[2] + 1; z <= Z * l->r[2] && z <= f->n[2]; z++)
            for (uint32_t y = 1; y <= f->n[1]; y++) {
                size_t a, e, row = f->sy * y + f->sz * z;
                row_span(f, y, z, &a, &e);
                /* padded fine x -> padded coarse X: (x - 1) / r + 1 */
                size_t crow = l->sy * ((y - 1) / l->r[1] + 1) + l->sz * Z + 1;
                if (v)
                    for (size_t i = color_start(a, row, y, z, 0); i < e; i += 2)
                        coarse[crow + ((i - row - 1) >> sh)] += b[i] - (cell_diag(f, i) * v[i] - cell_offdiag(f, v, i));
                else
                    for (size_t i = a; i < e; i++)
                        coarse[crow + ((i - row - 1) >> sh)] += b[i];
            }
    }
}

/* Coarse padded coordinate of fine padded coordinate k on an axis coarsened by 2^sh: the
 * interior maps as (k - 1) / r + 1 and the padding layer 0 to the coarse padding. */
static inline size_t parent_coord(size_t k, uint32_t sh)
{
    return (k + (1u << sh) - 1) >> sh;
}

/* The color-1 half sweep of the coarse-correction step, on v + P coarse (P: piecewise constant
 * prolongation inside the domain) without storing the sum: a color-1 update reads only its
 * color-0 neighbours, so they take their parent's value on the fly, and the color-0 half sweep
 * that must follow overwrites every color-0 cell without reading it. The same result as adding
 * the prolongation to the color-0 cells first, one pass over the level fewer. */
static void gs_prolong(const level *l, const level *lc, v4 *v, const v4 *b, const v4 *coarse, int threads)
{
    const uint32_t ny = l->n[1];
    const uint32_t sx = lc->r[0] == 2, shy = lc->r[1] == 2, shz = lc->r[2] == 2;
    const size_t sy = l->sy, sz = l->sz, csy = lc->sy, csz = lc->sz;
    const uint8_t *solid = l->solid;
#pragma omp parallel for num_threads(threads) schedule(static, 1) if (l->cells > 32768)
    FOR_SLABS(l, z)
        for (uint32_t y = 1; y <= ny; y++) {
            size_t a, e, row = sy * y + sz * z;
            row_span(l, y, z, &a, &e);
            /* parent rows of this row and of its four neighbour rows (padding rows map to the
             * coarse padding, which holds zero; their cells are outside and masked anyway) */
            const size_t py = parent_coord(y, shy), pz = parent_coord(z, shz);
            const v4 *c0 = coarse + csy * py + csz * pz;
            const v4 *cym = coarse + csy * parent_coord(y - 1, shy) + csz * pz;
            const v4 *cyp = coarse + csy * parent_coord(y + 1, shy) + csz * pz;
            const v4 *czm = coarse + csy * py + csz * parent_coord(z - 1, shz);
            const v4 *czp = coarse + csy * py + csz * parent_coord(z + 1, shz);
#define NB(j, cp) (v[j] + (float)solid[j] * (cp))
            for (size_t i = color_start(a, row, y, z, 1); i < e; i += 2) {
                const size_t x = i - row, px = parent_coord(x, sx);
                v4 xp = NB(i + 1, c0[parent_coord(x + 1, sx)]), xm = NB(i - 1, c0[parent_coord(x - 1, sx)]);
                v4 yp = NB(i + sy, cyp[px]), ym = NB(i - sy, cym[px]);
                v4 zp = NB(i + sz, czp[px]), zm = NB(i - sz, czm[px]);
                v4 off;
                if (l->homogeneous_level) {
                    off = l->kg[l->k[i]] * (xp + xm + yp + ym + zp + zm);
                } else {
                    const v4 *const *g = (const v4 *const *)l->g;
                    off = g[0][i] * xp + g[0][i - 1] * xm + g[1][i] * yp + g[1][i - sy] * ym + g[2][i] * zp +
                          g[2][i - sz] * zm;
                }
                v[i] = (b[i] + off) / cell_diag(l, i);
            }
#undef NB
        }
}

/* How a cycle finds x on entry: zero (its contents ignored), zero with the first half sweep
 * already done by the caller (update_xr_first), or a guess to improve. */
enum cycle_start { START_ZERO, START_FIRST_DONE, START_GUESS };

/* Symmetric W-cycle: x = W(b), a fixed linear operator of b when x starts at zero; from a guess,
 * x + W(b - M x). The coarse problem is solved by two cycles of the coarser level (the second
 * from the first's result), which is symmetric too: its error propagator is E^2 with E the
 * coarse cycle's (A-self-adjoint) one. One V-cycle per coarse level let the PCG count grow with
 * the number of levels (7, 8, 9, 11 at 32, 64, 128, 256^3) because piecewise-constant
 * aggregation solves the smooth error of each level only partly; in 3D a level has 1/8 of the
 * cells and is visited twice as often, so the extra work is a quarter of a level per level.
 * With bz, the last half sweep also returns b . x there. */
static void cycle(nc_diff_solver *s, uint32_t li, const v4 *b, v4 *x, enum cycle_start start, v4d *bz, int threads)
{
    level *l = &s->lv[li];
    v4d *part = s->part;
    if (li + 1 == s->level_count && s->coarse_direct) {
        /* Coarsest: exact, whatever x holds (at most 8 cells) */
        memset(x, 0, l->cells * sizeof(v4));
        v4d sum = {0.0, 0.0, 0.0, 0.0};
        for (uint32_t i = 0; i < s->coarse_count; i++) {
            v4 xi = V4_ZERO;
            for (int c = 0; c < 3; c++) {
                double acc = 0.0;
                for (uint32_t j = 0; j < s->coarse_count; j++)
                    acc += s->cinv[c][i][j] * b[s->cidx[j]][c];
                xi[c] = (float)acc;
            }
            x[s->cidx[i]] = xi;
            sum += widen(b[s->cidx[i]] * xi);
        }
        if (bz)
            *bz = sum;
        return;
    }
    if (li + 1 == s->level_count) {
        if (start != START_GUESS)
            memset(x, 0, l->cells * sizeof(v4));
        /* Coarsest without an inverse: enough symmetric sweeps to solve it, the count fixed so
         * the cycle stays linear. */
        uint32_t sweeps = 4 + 2 * (l->n[0] + l->n[1] + l->n[2]);
        for (uint32_t k = 0; k < sweeps; k++) {
            gs_color(l, x, b, 0, NULL, threads);
            gs_color(l, x, b, 1, NULL, threads);
            gs_color(l, x, b, 1, NULL, threads);
            v4d d = gs_color(l, x, b, 0, bz && k + 1 == sweeps ? part : NULL, threads);
            if (bz && k + 1 == sweeps)
                *bz = d;
        }
        return;
    }
    level *lc = &s->lv[li + 1];
    if (start == START_ZERO)
        gs_first(l, x, b, threads); /* x starts at zero (the padding is zero already) */
    else if (start == START_GUESS)
        gs_color(l, x, b, 0, NULL, threads);
    gs_color(l, x, b, 1, NULL, threads);
    nc_diff_restrict_rows(l, lc, x, b, lc->b, threads);
    cycle(s, li + 1, lc->b, lc->x, START_ZERO, NULL, threads);
    if (!(li + 2 == s->level_count && s->coarse_direct)) /* a second exact solve changes nothing */
        cycle(s, li + 1, lc->b, lc->x, START_GUESS, NULL, threads);
    gs_prolong(l, lc, x, b, lc->x, threads);
    v4d d = gs_color(l, x, b, 0, bz ? part : NULL, threads);
    if (bz)
        *bz = d;
}

/* Warm start on a domain that moved (a rotating or deforming object is voxelized again every
 * frame): the cells that have just entered the domain come with phi = 0 next to neighbours at
 * their full value, and a hundred such cells on the lit surface make a residual as large as the
 * source itself (relative residual ~1 where the rest of the field is within 1e-4), which costs
 * the solve one to two iterations of its five or six. One Gauss-Seidel update of those cells
 * from their neighbours (0.01 degree of rotation at 128^3: residual 0.7 -> 0.05) removes that.
 * By color, so the result does not depend on the order or the thread count; rows without such
 * cells are skipped. */
void nc_diff_warm_fill(const level *l, v4 *x, const v4 *b, int threads)
{
    const uint32_t ny = l->n[1];
    const uint8_t *fresh = l->fresh, *row_fresh = l->fresh + l->cells;
    for (int color = 0; color < 2; color++) {
#pragma omp parallel for num_threads(threads) schedule(static, 1) if (l->cells > 32768)
        FOR_SLABS(l, z)
            for (uint32_t y = 1; y <= ny; y++) {
                if (!row_fresh[y + ((size_t)ny + 2) * z])
                    continue;
                size_t a, e, row = l->sy * y + l->sz * z;
                row_span(l, y, z, &a, &e);
                for (size_t i = color_start(a, row, y, z, color); i < e; i += 2)
                    if (fresh[i])
                        x[i] = (b[i] + cell_offdiag(l, x, i)) / cell_diag(l, i);
            }
    }
}

/* Residual hot spots of a warm start. A turning or deforming object is voxelized again every
 * frame, and the previous solution misses the new frame's sources mostly in a few boundary
 * cells: those that entered or left the domain, or whose injected power jumped with the new
 * voxelization (Suzanne at 128^3 turning by 0.01 degree: 90% of r . r in 70-400 of 220k cells,
 * the relative residual 0.05-0.1). Gauss-Seidel sweeps over those cells and the cells within
 * HOT_RADIUS steps of them remove that part of the residual for the cost of a few ten thousand
 * cell updates (0.2-1.1 ms at 128^3), where a conjugate-gradient iteration costs a pass over
 * the whole domain (about 10 ms). Mean PCG iterations per frame of the four benchmark meshes
 * turning at 128^3 (bench_diffusion.c): 4.0-4.1 without, 3.1-3.9 with radius 1 and 3 sweeps,
 * 3.0-3.4 with radius 2 and 2 sweeps (chosen), 3.0-3.2 with radius 3 (relaxation twice as
 * long). The cells are those with r_c^2 > HOT_RATIO times the mean r_c^2 over the active cells
 * in some channel c; when more than one in HOT_MAX_SHARE of the active cells qualifies, the
 * residual is not concentrated and nothing is done. The search runs per slab in parallel and
 * the sweeps serially in index order, so the result does not depend on the thread count.
 * The residual r (float, as nc_diff_residual_exact computes it) and r . r are then updated at the cells
 * within HOT_RADIUS + 1 steps, the only ones whose residual the sweeps change, instead of a pass
 * over the domain (1-1.5 ms at 128^3). Returns whether x changed; *rr is the new r . r then. */
#define HOT_RATIO 4.0
#define HOT_MAX_SHARE 64
#define HOT_SWEEPS 2
#define HOT_RADIUS 2
static bool hot_relax(nc_diff_solver *s, const v4 *b, v4 *x, v4 *r, v4d *rr, int threads)
{
    level *l = &s->lv[0];
    const uint32_t ny = l->n[1];
    const size_t active = l->active;
    if (active == 0)
        return false;
    const size_t cap = active / HOT_MAX_SHARE, parts = (size_t)l->parts;
    /* each slab fills its own cap entries; the touched cells are solid, at most active */
    if (s->hot_capacity < cap * parts || s->touched_capacity < active || s->mark_capacity < l->cells) {
        nc_free(s->ctx, s->hot);
        nc_free(s->ctx, s->touched);
        nc_free(s->ctx, s->mark);
        s->hot = nc_alloc(s->ctx, cap * parts * sizeof(size_t));
        s->touched = nc_alloc(s->ctx, active * sizeof(uint32_t));
        s->mark = nc_calloc(s->ctx, l->cells, 1);
        const bool ok = s->hot && s->touched && s->mark;
        s->hot_capacity = ok ? cap * parts : 0;
        s->touched_capacity = ok ? active : 0;
        s->mark_capacity = ok ? l->cells : 0;
        if (!ok)
            return false; /* an optimization only: the solve does without */
    }
    v4 th;
    for (int c = 0; c < 3; c++)
        th[c] = (float)(HOT_RATIO * (*rr)[c] / (double)active);
    th[3] = INFINITY;
    size_t found[MAX_PARTS];
#pragma omp parallel for num_threads(threads) schedule(static, 1) if (l->cells > 32768)
    for (int t = 0; t < l->parts; t++) {
        size_t n = 0, *hot = s->hot + cap * (size_t)t;
        for (uint32_t z = l->zb[t]; z < l->zb[t + 1] && n <= cap; z++)
            for (uint32_t y = 1; y <= ny && n <= cap; y++) {
                size_t a, e;
                row_span(l, y, z, &a, &e);
                for (size_t i = a; i < e; i++) {
                    v4 r2 = r[i] * r[i];
                    if (r2[0] > th[0] || r2[1] > th[1] || r2[2] > th[2]) {
                        if (n == cap) { /* more than the whole limit in one slab */
                            n = cap + 1;
                            break;
                        }
                        hot[n++] = i;
                    }
                }
            }
        found[t] = n;
    }
    size_t n = 0;
    for (size_t t = 0; t < parts; t++) {
        if (found[t] > cap || n + found[t] > cap)
            return false;
        memmove(s->hot + n, s->hot + cap * t, found[t] * sizeof(size_t));
        n += found[t];
    }
    if (n == 0)
        return false;
    /* The offsets within HOT_RADIUS + 1 steps (Manhattan distance), those within HOT_RADIUS
     * first. Near a row's ends they may reach a cell of the next row (the padding is one cell
     * wide): relaxing that cell is as valid an update as any, and the index test keeps every read
     * inside the level. */
    enum { SIDE = 2 * HOT_RADIUS + 3 };
    ptrdiff_t nb[SIDE * SIDE * SIDE];
    int nnb = 0, nrelax = 0; /* nb[0, nrelax): within HOT_RADIUS */
    for (int ring = 0; ring < 2; ring++) {
        for (int dz = -HOT_RADIUS - 1; dz <= HOT_RADIUS + 1; dz++)
            for (int dy = -HOT_RADIUS - 1; dy <= HOT_RADIUS + 1; dy++)
                for (int dx = -HOT_RADIUS - 1; dx <= HOT_RADIUS + 1; dx++) {
                    const int d = abs(dx) + abs(dy) + abs(dz);
                    if (ring == 0 ? d <= HOT_RADIUS : d == HOT_RADIUS + 1)
                        nb[nnb++] = dx + dy * (ptrdiff_t)l->sy + dz * (ptrdiff_t)l->sz;
                }
        if (ring == 0)
            nrelax = nnb;
    }
    /* The solid cells whose residual can change, each once, with their share of r . r */
    size_t m = 0;
    v4d old = {0.0, 0.0, 0.0, 0.0};
    for (size_t k = 0; k < n; k++)
        for (int j = 0; j < nnb; j++) {
            size_t i = (size_t)((ptrdiff_t)s->hot[k] + nb[j]);
            if (i < l->cells && l->solid[i] && !s->mark[i]) {
                s->mark[i] = 1;
                s->touched[m++] = (uint32_t)i;
                old += widen(r[i] * r[i]);
            }
        }
    for (int sweep = 0; sweep < HOT_SWEEPS; sweep++)
        for (size_t k = 0; k < n; k++)
            for (int j = 0; j < nrelax; j++) {
                size_t i = (size_t)((ptrdiff_t)s->hot[k] + nb[j]);
                if (i < l->cells && l->solid[i])
                    x[i] = (b[i] + cell_offdiag(l, x, i)) / cell_diag(l, i);
            }
    v4d now = {0.0, 0.0, 0.0, 0.0};
    for (size_t k = 0; k < m; k++) {
        const size_t i = s->touched[k];
        const v4 o = b[i] - (cell_diag(l, i) * x[i] - cell_offdiag(l, x, i));
        r[i] = o;
        now += widen(o * o);
        s->mark[i] = 0;
    }
    v4d sum = *rr - old;
    for (int c = 0; c < 4; c++)
        sum[c] = sum[c] > 0.0 ? sum[c] : 0.0; /* round-off when the hot cells held it all */
    *rr = sum + now;
    return true;
}

/* Whether the solve's deadline (opts.deadline_us, 0: none) has passed. */
static bool past_deadline(const nc_diff_solve_opts *o) { return o->deadline_us && nc_now_us() >= o->deadline_us; }

void nc_diff_solve_pcg(nc_diff_solver *s, const v4 *b, v4 *x, const nc_diff_solve_opts *o, nc_diff_solve_report rep[3])
{
    level *l = &s->lv[0];
    const int threads = s->ctx->threads;
    v4 *r = s->pr, *z = s->pz, *p = s->pp, *p2 = s->pp2, *q = s->pq;
    v4d *part = s->part;
    const double tol = o->tolerance > 0 ? o->tolerance : 1e-4;
    const uint32_t max_it = o->max_iterations ? o->max_iterations : 200;
    v4d bb;
    /* rr: the exact residual of the current x (exact true) or not. The first one in float: a
     * start far from the tolerance (cold, or warm on a new frame) needs no more, and one within
     * 2 tol of it is computed again exactly. */
    v4d rr = nc_diff_residual_exact(l, x, b, r, &bb, false, part, threads);
    if (o->warm_start && !o->no_local_relax)
        hot_relax(s, b, x, r, &rr, threads);
    bool exact = false, near = false;
    double bnorm[3];
    for (int c = 0; c < 3; c++) {
        bnorm[c] = sqrt(bb[c]);
        near |= bnorm[c] > 0 && sqrt(rr[c]) <= 2.0 * tol * bnorm[c];
    }
    if (near) {
        rr = nc_diff_residual_exact(l, x, b, r, NULL, true, part, threads);
        exact = true;
    }
    uint32_t it = 0;
    /* Three solves in lockstep; a channel that has converged gets step 0 from then on. Restarted
     * from the exact residual whenever the recursively updated one (float) claims a convergence
     * that the exact one does not confirm. */
    rep[0].timed_out = false;
    for (int restart = 0; restart < 8 && it < max_it && !rep[0].timed_out; restart++) {
        /* the first pass starts from the residual above, the float one when far from the
         * tolerance */
        if (!exact && restart > 0)
            rr = nc_diff_residual_exact(l, x, b, r, NULL, true, part, threads);
        exact = true;
        bool active[3], any = false;
        for (int c = 0; c < 3; c++) {
            active[c] = sqrt(rr[c]) > tol * bnorm[c];
            any |= active[c];
        }
        if (!any || (rep[0].timed_out = past_deadline(o)))
            break;
        v4d rz;
        cycle(s, 0, r, z, START_ZERO, &rz, threads);
        v4 beta = V4_ZERO;
        bool first = true; /* p = z */
        while (it < max_it && !(rep[0].timed_out = past_deadline(o))) {
            v4d pq = apply_dot_dir(l, z, p, p2, q, beta, first, part, threads);
            v4 *t = p; /* p2 holds the new direction */
            p = p2;
            p2 = t;
            first = false;
            v4 alpha = V4_ZERO;
            bool stalled = true;
            for (int c = 0; c < 3; c++)
                if (active[c] && pq[c] > 0) {
                    alpha[c] = (float)(rz[c] / pq[c]);
                    stalled = false;
                }
            if (stalled)
                break;
            rr = update_xr_first(l, x, r, p, q, alpha, z, part, threads);
            exact = false;
            it++;
            any = false;
            for (int c = 0; c < 3; c++) {
                if (active[c] && sqrt(rr[c]) <= tol * bnorm[c])
                    active[c] = false;
                any |= active[c];
            }
            if (!any)
                break;
            v4d rz_new;
            cycle(s, 0, r, z, START_FIRST_DONE, &rz_new, threads);
            for (int c = 0; c < 3; c++)
                beta[c] = active[c] && rz[c] != 0 ? (float)(rz_new[c] / rz[c]) : 0.0f;
            rz = rz_new;
        }
    }
    /* Keep the buffers' roles for the next solve (both directions stay zero outside the spans). */
    s->pp = p;
    s->pp2 = p2;
    /* Report the true residual, not the recursively updated one (the loop usually ends on the
     * exact check, whose value is reused). */
    if (!exact)
        rr = nc_diff_residual_exact(l, x, b, r, NULL, true, part, threads);
    for (int c = 0; c < 3; c++) {
        rep[c].iterations = it;
        rep[c].residual = bnorm[c] > 0 ? sqrt(rr[c]) / bnorm[c] : 0.0;
        rep[c].timed_out = rep[0].timed_out;
    }
}
