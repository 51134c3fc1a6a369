/*
 * solver_internal.h: what the diffusion solver's files share (private to src/diffusion/solver*.c,
 * multigrid.c and seed_solver.c; callers use diffusion.h): the level and solver structures, the
 * conductance scales of the coarse levels, and the per-cell kernels that more than one file
 * runs, kept `static inline` so every kernel loop still inlines them.
 *
 * Layout: the three channels are solved together, each cell holding a 4-float vector (R, G, B,
 * unused), so one pass over the grid serves all channels and the arithmetic is one SIMD
 * operation per cell; the conjugate-gradient scalars are per-channel vectors too (three
 * independent solves in lockstep). Each level has one layer of padding cells (outside the
 * domain: zero conductances, zero values) so kernels need no bounds tests. Units: see
 * diffusion.h (lengths in scene units, cell side h; conductances and diagonals in h^3 / length^2
 * per cell as the finite-volume sums of solver_setup.c give them).
 *
 * Memory traffic (the solver is bandwidth-bound): kernels visit each row only from its first to
 * its last solid cell (a sphere fills about half of its bounding box); cells outside these spans
 * are never written and stay zero, and a new setup clears only the cells that left them.
 * Reductions are summed per z slab and the slabs added in order, so results do not depend on
 * the number of threads; the slabs are shared out by active cells, not planes (level.zb).
 */
#ifndef NACRE_DIFFUSION_SOLVER_INTERNAL_H
#define NACRE_DIFFUSION_SOLVER_INTERNAL_H

#include "diffusion/diffusion.h"

#include <math.h>
#include <string.h>
#include <stdlib.h>

#define MAX_LEVELS 16
#define MAX_PARTS 256
/* The z slabs of level l in the balanced split, as one loop the OpenMP pragma before it shares
 * out: thread t takes part t (schedule(static, 1) and parts <= threads). */
#define FOR_SLABS(l, z)                                                                                                \
    for (int t_ = 0; t_ < (l)->parts; t_++)                                                                            \
        for (uint32_t z = (l)->zb[t_]; z < (l)->zb[t_ + 1]; z++)

/* One cell: R, G, B and an unused lane. aligned(4) so any allocator's memory will do. */
typedef float v4 __attribute__((vector_size(16), aligned(4)));
typedef double v4d __attribute__((vector_size(32), aligned(8)));

typedef struct level {
    uint32_t n[3]; /* interior cells per axis */
    uint32_t r[3]; /* coarsening factor from the finer level per axis: 1 or 2 */
    size_t cells;  /* padded: (n + 2) per axis */
    size_t sy, sz; /* strides */
    uint8_t *solid;
    /* Active span of each padded row r = y + (ny + 2) z: padded x in [ext[2 r], ext[2 r + 1]),
     * from its first to its last solid cell (1, 1 when none). Kernels visit these spans only; cells
     * outside them are never written and read as zero (see zero_outside). */
    const uint32_t *ext;
    /* The z slabs [zb[t], zb[t + 1]) of the parallel kernels, one per thread, with equal numbers
     * of active cells: an even split of the planes gave one thread 2.3 times the other's cells
     * on Armadillo (most of its volume is in the upper half), and every kernel waited for it.
     * Results do not depend on the split (per-slab reductions, red-black sweeps). */
    int parts;
    uint32_t zb[MAX_PARTS + 1];
    size_t active; /* cells in the active spans (level_spans) */
    v4 *g[3];      /* conductance to the +x, +y, +z neighbour (0 when either cell is outside) */
    v4 *diag;      /* diagonal (1 outside the domain) */
    v4 *x, *b, *res; /* multigrid cycle work */
    /* Homogeneous fast path (level 0 of a medium with constant coefficients): the kernels read a
     * byte per cell instead of 80 bytes of coefficients. k = solid neighbours (0..6), 7 outside;
     * every coefficient is a function of k (the neighbours outside hold zero values). */
    uint8_t *k;
    /* Level 0, per solve: cells without a warm-start value (fresh[i]), then one flag per padded
     * row (fresh + cells) telling whether the row has any (see nc_diff_warm_fill). */
    uint8_t *fresh;
    float *bw;    /* boundary weight sum per cell: sum of w_f over its exposed faces */
    bool homogeneous_level;
    v4 kbase[8];  /* absorption + k G (k = 7: 1, outside) */
    v4 kg[8];     /* G (k = 7: 0) */
    v4 kb;        /* B per unit boundary weight */
} level;

struct nc_diff_solver {
    nacre_context *ctx;
    uint32_t dims[3];   /* the caller's grid */
    uint32_t off[3];    /* the solver works on the solid cells' bounding box, from here */
    float h;
    uint32_t level_count;
    level lv[MAX_LEVELS];
    size_t capacity[MAX_LEVELS]; /* padded cells allocated per level */
    /* level 0 extras */
    v4 *bnd;     /* boundary conductance sum per cell (escape); not written on the fast path (robin_bnd) */
    v4 *absorb;  /* sigma_a h^3 per cell (not written on the homogeneous fast path: aconst) */
    v4 *pr, *pz, *pp, *pq, *px; /* conjugate-gradient vectors */
    v4 *pp2;     /* the other buffer of the direction p (apply_dot_dir) */
    /* Row spans per level (level.ext points into span), the previous setup's spans, and
     * whether the work arrays are zero outside them (then a new setup only clears the cells
     * that left the spans). */
    uint32_t *span[MAX_LEVELS], *span_old[MAX_LEVELS];
    size_t span_capacity[MAX_LEVELS];
    uint32_t span_n[MAX_LEVELS][3];
    bool span_valid[MAX_LEVELS];
    /* Coarse levels: solid, diag and g are zero outside the spans span[li] of a level of shape
     * op_n[li] (op_clean; diag is 1 at the cells inside them that are not solid), so the next
     * build clears those spans only (build_coarse). */
    bool op_clean[MAX_LEVELS];
    uint32_t op_n[MAX_LEVELS][3];
    v4d *part;   /* per-slab partial sums of the reductions, 3 (nz + 2) */
    size_t part_capacity;
    size_t *hot; /* warm start: the cells that hold most of the residual (hot_relax), per slab */
    size_t hot_capacity;
    /* hot_relax's residual update: the cells whose residual it changes (touched), and a flag per
     * level-0 cell (mark, all 0 between calls) so that each is counted once */
    uint32_t *touched;
    size_t touched_capacity;
    uint8_t *mark;
    size_t mark_capacity;
    /* The last output (nc_diff_solve_rgb): per row (y, z) of the caller's grid, the x range
     * [lo, hi) it wrote from the domain; phi was 0 elsewhere. Valid for out_phi, out_dims. */
    uint32_t *out_span;
    size_t out_span_capacity;
    bool out_valid;
    float *out_phi[3];
    uint32_t out_dims[3];
    float *d_user[3]; /* D per cell in the caller's layout */
    size_t user_capacity;
    /* d_user is 0 outside the box (d_dims grid, d_off, d_n) of the setup that wrote it last
     * (d_valid): a new setup clears only what it does not overwrite. */
    bool d_valid;
    uint32_t d_dims[3], d_off[3], d_n[3];
    bool homogeneous; /* level 0 uses the fast path */
    v4 aconst;        /* the fast path's absorption sigma_a h^3 (absorb is not written then) */
    v4 dconst;        /* ... and its D (d_user is not written then) */
    v4 bden;          /* ... and h + 4 A D, for its Robin terms (robin_bnd; bnd is not written then) */
    float coarse_scale; /* the conductance scale the coarse levels were built with */
    /* The coarsest level (at most 2 cells per axis) solved exactly: the inverse of its operator
     * per channel over its solid cells (padded indices cidx), or coarse_direct false (a pivot
     * that is not positive): symmetric Gauss-Seidel sweeps then. */
    bool coarse_direct;
    uint32_t coarse_count;
    size_t cidx[8];
    double cinv[3][8][8];
};

/* Conductance scale per coarsened axis. Re-discretizing a homogeneous medium on the coarse
 * cells gives 1/2 (four fine faces of conductance h D make one of 2 h D); that makes the coarse
 * correction exact for the smoothest error but too large for the intermediate frequencies
 * that piecewise-constant prolongation represents badly (it overshoots in energy). A slightly
 * stiffer coarse operator (over-correction 1/0.6 ~ 1.7 instead of 2, as in the aggregation
 * multigrid literature: Braess 1995, Vanek et al.) converges faster: on the marble sphere of
 * bench_diffusion_solver.c, PCG to 1e-4 takes 6, 6, 7, 7 iterations at 32..256^3 (W-cycle)
 * against 6, 7, 7, 8 with 1/2; 0.55-0.7 behave alike. */
#define COARSE_G_SCALE 0.6f
/* The seed's cascade (nc_diff_solve_seed) starts each level from the coarser level's solution, which
 * must approximate the fine one: it keeps the re-discretization's 1/2. */
#define SEED_G_SCALE 0.5f

static const v4 V4_ZERO = {0, 0, 0, 0};
static const v4 V4_ONE = {1, 1, 1, 1};

/* Padded index of interior cell (x, y, z). */
static inline size_t pidx(const level *l, uint32_t x, uint32_t y, uint32_t z)
{
    return (size_t)(x + 1) + l->sy * (y + 1) + l->sz * (z + 1);
}

/* The active cells [*a, *e) (padded indices) of interior row (y, z), 1-based padded y and z;
 * an empty row gives a == e. */
static inline void row_span(const level *l, uint32_t y, uint32_t z, size_t *a, size_t *e)
{
    const uint32_t *x = l->ext + 2 * ((size_t)y + ((size_t)l->n[1] + 2) * z);
    size_t row = l->sy * y + l->sz * z;
    *a = row + x[0];
    *e = row + x[1];
}

/* ---------------------------------------------------------------------------------------- */
/* Kernels                                                                                  */
/* ---------------------------------------------------------------------------------------- */

/* The operator at padded cell i: M v = diag * v - offdiag(v). The homogeneous fast path reads
 * a byte and a float per cell (every coefficient a function of the solid-neighbour count k),
 * the general path the stored conductances. Cells outside the domain have zero conductances,
 * a unit diagonal and zero b and v, so every kernel leaves them at 0 without a test. */
static inline v4 cell_diag(const level *l, size_t i)
{
    if (l->homogeneous_level)
        return l->kbase[l->k[i]] + l->bw[i] * l->kb;
    return l->diag[i];
}

static inline v4 cell_offdiag(const level *l, const v4 *v, size_t i)
{
    const size_t sy = l->sy, sz = l->sz;
    if (l->homogeneous_level)
        return l->kg[l->k[i]] * (v[i + 1] + v[i - 1] + v[i + sy] + v[i - sy] + v[i + sz] + v[i - sz]);
    const v4 *const *g = (const v4 *const *)l->g;
    return g[0][i] * v[i + 1] + g[0][i - 1] * v[i - 1] + g[1][i] * v[i + sy] + g[1][i - sy] * v[i - sy] +
           g[2][i] * v[i + sz] + g[2][i - sz] * v[i - sz];
}

static inline v4d widen(v4 a) { return __builtin_convertvector(a, v4d); }

/* The Robin conductance of a cell with boundary weight w, D dv and den = h + 4 A dv per channel:
 * w h^2 2 D / (h + 4 A D). The fast path stores no per-cell copy (bnd): its readers (the coarse
 * level's diagonal, the energy sums) form it from bw with these same operations. */
static inline v4 robin_bnd(float w, v4 dv, v4 den, float h)
{
    v4 bv = {0.0f, 0.0f, 0.0f, 0.0f};
    if (w > 0)
        for (int c = 0; c < 3; c++)
            bv[c] = w * h * h * 2.0f * dv[c] / den[c];
    return bv;
}

/* Per-slab partial sums of the reductions, added in slab order: the result does not depend on
 * the number of threads or the schedule. */
static inline v4d sum_slabs(const v4d *part, uint32_t nz)
{
    v4d r = {0.0, 0.0, 0.0, 0.0};
    for (uint32_t z = 1; z <= nz; z++)
        r += part[z];
    return r;
}

/* solver_setup.c */
void nc_diff_level_free(nacre_context *ctx, level *l);
void nc_diff_extras_free(nc_diff_solver *s);
nacre_result nc_diff_build_coarse_levels(nc_diff_solver *s, float scale, bool spans, int threads);

/* multigrid.c */
void nc_diff_restrict_rows(const level *f, const level *l, const v4 *v, const v4 *b, v4 *coarse, int threads);
v4d nc_diff_residual_exact(const level *l, const v4 *v, const v4 *b, v4 *out, v4d *bb, bool exact, v4d *part,
                           int threads);
void nc_diff_warm_fill(const level *l, v4 *x, const v4 *b, int threads);
void nc_diff_solve_pcg(nc_diff_solver *s, const v4 *b, v4 *x, const nc_diff_solve_opts *o,
                       nc_diff_solve_report rep[3]);

/* seed_solver.c */
void nc_diff_solve_seed(nc_diff_solver *s, const v4 *b, v4 *x, const nc_diff_solve_opts *o,
                        nc_diff_solve_report rep[3]);

#endif /* NACRE_DIFFUSION_SOLVER_INTERNAL_H */
