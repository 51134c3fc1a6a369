/*
 * solver.c: steady-state diffusion of light inside a voxelized object (Blanchard 2012 section
 * 2.4 and 4.5), per RGB channel:  div(D grad phi) - sigma_a phi + S = 0  on the solid cells,
 * with the Robin boundary condition of Arbree et al. (seed eq. 4.7) on every exposed face.
 *
 * Discretization (see diffusion.h for units): cell-centred finite volumes. The seed updates a
 * cell from each neighbour's D * phi (its eq. 4.6), which does not conserve energy when D
 * varies; here the flux across a face is G (phi_i - phi_j) with G = h * harmonic mean of the two
 * D, so what leaves one cell enters the other and the matrix is symmetric positive definite.
 *
 * Solvers:
 *   MULTIGRID (default): conjugate gradients preconditioned by one multigrid W-cycle. Coarse
 *     levels aggregate 2x2x2 cells (a coarse cell is in the domain when any child is, as the
 *     voxel pyramid of seed 4.2.2); their operator is the Galerkin sum of the fine one with the
 *     face conductances scaled by 0.6 per coarsened axis (see COARSE_G_SCALE: re-discretizing
 *     would give 1/2, the piecewise-constant Galerkin sum alone is twice too stiff). Smoother:
 *     red-black Gauss-Seidel, red then black before and black then red after the coarse
 *     correction, and each coarse problem gets two cycles of its own level (W), so the cycle is a
 *     symmetric operator as conjugate gradients needs; the coarsest level (at most 2x2x2) is
 *     solved exactly with an inverse formed at setup. The PCG iteration count stays at 6-7 from
 *     32^3 to 256^3 (a V-cycle: 7 to 11). Stops at ||S - M phi|| <= tol * ||S|| per channel.
 *   SEED: the seed's scheme for reproducing its numbers: Jacobi sweeps with fixed counts on the
 *     levels from 4 cells up (tables 4.3 and 5.6), each level started from the coarser one. Its
 *     coarse operators keep the 1/2 scaling (rebuilt when a caller switches solvers).
 *
 * Layout: the three channels are solved together, each cell holding a 4-float vector (R, G, B,
 * unused), so one pass over the grid serves all channels and the arithmetic is one SIMD
 * operation per cell; the conjugate-gradient scalars are per-channel vectors too (three
 * independent solves in lockstep). Each level has one layer of padding cells (outside the
 * domain: zero conductances, zero values) so kernels need no bounds tests.
 *
 * Sources are restricted to the coarse levels by summation (power is additive), which is the
 * seed's "inject on every level" (section 4.4) done once.
 *
 * Memory traffic (the solver is bandwidth-bound): kernels visit each row only from its first to
 * its last solid cell (a sphere fills about half of its bounding box); cells outside these spans
 * are never written and stay zero, and a new setup clears only the cells that left them. Passes
 * are fused where the data dependencies allow it without changing the arithmetic: the residual
 * is restricted as it is formed (never stored; at color-0 cells only, the color-1 half sweep
 * before it leaves the others at zero), the CG update of x and r carries the next cycle's first
 * half sweep, the prolongation is read inside the color-1 half sweep after it (gs_prolong), the
 * last half sweep carries r . z, and the new direction p is formed inside the operator pass
 * (double-buffered). Setup also visits the spans only where it can. Reductions are summed per z
 * slab and the slabs added in order, so results do not depend on the number of threads; the
 * slabs are shared out by active cells, not planes (level.zb).
 *
 * Warm start: a moving object is voxelized again every frame, and the cells that enter the
 * domain come with phi = 0; they are filled from their neighbours first (warm_fill), which
 * takes a frame of a rotating mesh from 5-6 PCG iterations to 4. The residual that is left sits
 * in a few boundary cells, which are relaxed locally before the first iteration (hot_relax):
 * 3-3.4 iterations on average at 128^3.
 */
#include "diffusion/diffusion.h"
#include "core/optics.h"

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
     * row (fresh + cells) telling whether the row has any (see warm_fill). */
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

double nc_diff_robin_a(double eta)
{
    double fdr = nc_fresnel_fdr(eta);
    return (1.0 + fdr) / (1.0 - fdr);
}

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

static void level_free(nacre_context *ctx, level *l)
{
    nc_free(ctx, l->solid);
    nc_free(ctx, l->k);
    nc_free(ctx, l->fresh);
    nc_free(ctx, l->bw);
    for (int a = 0; a < 3; a++)
        nc_free(ctx, l->g[a]);
    nc_free(ctx, l->diag);
    nc_free(ctx, l->x);
    nc_free(ctx, l->b);
    nc_free(ctx, l->res);
    memset(l, 0, sizeof(*l));
}

static void extras_free(nc_diff_solver *s)
{
    nacre_context *ctx = s->ctx;
    v4 **w[8] = {&s->bnd, &s->absorb, &s->pr, &s->pz, &s->pp, &s->pq, &s->px, &s->pp2};
    for (int k = 0; k < 8; k++) {
        nc_free(ctx, *w[k]);
        *w[k] = NULL;
    }
}

void nc_diff_solver_destroy(nc_diff_solver *s)
{
    if (!s)
        return;
    for (int i = 0; i < MAX_LEVELS; i++) {
        level_free(s->ctx, &s->lv[i]);
        nc_free(s->ctx, s->span[i]);
        nc_free(s->ctx, s->span_old[i]);
    }
    nc_free(s->ctx, s->part);
    nc_free(s->ctx, s->hot);
    nc_free(s->ctx, s->touched);
    nc_free(s->ctx, s->mark);
    nc_free(s->ctx, s->out_span);
    extras_free(s);
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

static void level_shape(level *l, const uint32_t n[3])
{
    memcpy(l->n, n, sizeof(l->n));
    l->sy = (size_t)n[0] + 2;
    l->sz = l->sy * ((size_t)n[1] + 2);
    l->cells = l->sz * ((size_t)n[2] + 2);
}

/* Grow a level's arrays (and level 0's extras) to its padded size. */
static nacre_result level_alloc(nc_diff_solver *s, int li, size_t user_cells)
{
    nacre_context *ctx = s->ctx;
    level *l = &s->lv[li];
    bool ok = true;
    if (s->capacity[li] < l->cells || !l->solid) {
        level keep = *l;
        level_free(ctx, l);
        s->span_valid[li] = false; /* fresh arrays: nothing known to be zero */
        s->op_clean[li] = false;
        memcpy(l->n, keep.n, sizeof(keep.n));
        memcpy(l->r, keep.r, sizeof(keep.r));
        l->cells = keep.cells;
        l->sy = keep.sy;
        l->sz = keep.sz;
        s->capacity[li] = 0;
        size_t vb = l->cells * sizeof(v4);
        ok = (l->solid = nc_alloc(ctx, l->cells)) != NULL;
        for (int a = 0; a < 3 && ok; a++)
            ok = (l->g[a] = nc_alloc(ctx, vb)) != NULL;
        ok = ok && (l->diag = nc_alloc(ctx, vb)) && (l->x = nc_alloc(ctx, vb)) &&
             (l->b = nc_alloc(ctx, vb)) && (l->res = nc_alloc(ctx, vb));
        ok = ok && (li != 0 || ((l->k = nc_alloc(ctx, l->cells)) != NULL &&
                                (l->fresh = nc_alloc(ctx, 2 * l->cells)) != NULL &&
                                (l->bw = nc_alloc(ctx, l->cells * sizeof(float))) != NULL));
        if (ok && li == 0) {
            extras_free(s);
            v4 **w[8] = {&s->bnd, &s->absorb, &s->pr, &s->pz, &s->pp, &s->pq, &s->px, &s->pp2};
            for (int k = 0; k < 8; k++)
                ok = ok && (*w[k] = nc_alloc(ctx, vb)) != NULL;
        }
        if (ok)
            s->capacity[li] = l->cells;
    }
    if (ok && li == 0 && s->user_capacity < user_cells) {
        for (int c = 0; c < 3; c++) {
            nc_free(ctx, s->d_user[c]);
            s->d_user[c] = nc_alloc(ctx, user_cells * sizeof(float));
            ok = ok && s->d_user[c];
        }
        s->user_capacity = ok ? user_cells : 0;
        s->d_valid = false;
    }
    if (!ok) {
        level_free(ctx, l);
        s->capacity[li] = 0;
        return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory for a %ux%ux%u grid", l->n[0], l->n[1],
                       l->n[2]);
    }
    return NACRE_OK;
}

/* Padded index of interior cell (x, y, z). */
static inline size_t pidx(const level *l, uint32_t x, uint32_t y, uint32_t z)
{
    return (size_t)(x + 1) + l->sy * (y + 1) + l->sz * (z + 1);
}

static const v4 V4_ZERO = {0, 0, 0, 0};
static const v4 V4_ONE = {1, 1, 1, 1};

/* Zero the padding layer of a level's array (the six faces of the padded box). */
static void zero_padding(const level *l, v4 *a)
{
    const size_t sy = l->sy, sz = l->sz, nx = l->n[0], ny = l->n[1], nz = l->n[2];
    memset(a, 0, sz * sizeof(v4));
    memset(a + (nz + 1) * sz, 0, sz * sizeof(v4));
    for (size_t z = 1; z <= nz; z++) {
        v4 *plane = a + z * sz;
        memset(plane, 0, sy * sizeof(v4));
        memset(plane + (ny + 1) * sy, 0, sy * sizeof(v4));
        for (size_t y = 1; y <= ny; y++) {
            plane[y * sy] = V4_ZERO;
            plane[y * sy + nx + 1] = V4_ZERO;
        }
    }
}

static inline void row_span(const level *l, uint32_t y, uint32_t z, size_t *a, size_t *e);

/* diag (holding boundary + absorption on entry) += the six face conductances. Gathered per cell
 * (its own +faces and its neighbours' -faces), so z slabs run in parallel. Lanes that would be
 * 0 (the unused fourth lane, a channel without medium: sigma_t' = 0 decouples the cell) get 1,
 * so the kernels can divide by the diagonal without a test. */
static inline void finish_cell(level *l, size_t i)
{
    if (!l->solid[i]) {
        l->diag[i] = V4_ONE;
        return;
    }
    /* solid cells are interior, so i - sz etc. are in range */
    const size_t sy = l->sy, sz = l->sz;
    v4 d = l->diag[i] + l->g[0][i] + l->g[0][i - 1] + l->g[1][i] + l->g[1][i - sy] + l->g[2][i] + l->g[2][i - sz];
    for (int c = 0; c < 4; c++)
        d[c] = d[c] > 0 ? d[c] : 1.0f;
    l->diag[i] = d;
}

/* Every cell of the level (spans false), or the cells of its row spans (level.ext) only: the
 * kernels read the diagonal nowhere else. */
static void finish_level(level *l, bool spans, int threads)
{
    const size_t sz = l->sz, nz = l->n[2] + 2;
#pragma omp parallel for num_threads(threads) schedule(static) if (l->cells > 32768)
    for (size_t z = 0; z < nz; z++) {
        if (!spans) {
            for (size_t i = z * sz; i < (z + 1) * sz; i++)
                finish_cell(l, i);
            continue;
        }
        if (z == 0 || z == nz - 1) /* padding planes: no spans */
            continue;
        for (uint32_t y = 1; y <= l->n[1]; y++) {
            size_t a, e;
            row_span(l, y, (uint32_t)z, &a, &e);
            for (size_t i = a; i < e; i++)
                finish_cell(l, i);
        }
    }
}

/* Sum over the exposed faces of cell i of their share of true surface area (diffusion.h,
 * staircase_faces). The normal is the gradient of the occupancy over the 3x3x3 neighbourhood
 * (1-2-1 weights across the axis), so a planar staircase gets the plane's normal. A face nearly
 * parallel to the estimate keeps a floor of 0.2 so thin features still let light out. */
static float boundary_weight(const level *l, size_t i, const int open_axes[3], bool staircase)
{
    const size_t st[3] = {1, l->sy, l->sz};
    if (staircase) {
        int open = 0;
        for (int a = 0; a < 3; a++)
            if (open_axes[a])
                open += !l->solid[i - st[a]] + !l->solid[i + st[a]];
        return (float)open;
    }
    /* Integer sums (exact, and the same values as float ones: small integers), with no
     * conversion per neighbour */
    float grad[3] = {0, 0, 0};
    for (int a = 0; a < 3; a++) {
        if (!open_axes[a])
            continue;
        int b = (a + 1) % 3, c = (a + 2) % 3;
        /* the padding layer keeps every index in range for an interior cell, but an axis of
         * one cell has no neighbours across: use the row itself there */
        const ptrdiff_t sb = open_axes[b] ? (ptrdiff_t)st[b] : 0, sc = open_axes[c] ? (ptrdiff_t)st[c] : 0;
        const uint8_t *lo = l->solid + i - st[a], *hi = l->solid + i + st[a];
        int sum = 0;
        for (int ob = -1; ob <= 1; ob++)
            for (int oc = -1; oc <= 1; oc++) {
                const ptrdiff_t off = ob * sb + oc * sc;
                sum += (2 - (ob != 0)) * (2 - (oc != 0)) * ((int)lo[off] - (int)hi[off]);
            }
        grad[a] = (float)sum;
    }
    float len = sqrtf(grad[0] * grad[0] + grad[1] * grad[1] + grad[2] * grad[2]);
    float w = 0.0f;
    for (int a = 0; a < 3; a++) {
        if (!open_axes[a])
            continue;
        float share = len > 0 ? fabsf(grad[a]) / len : 1.0f;
        share = share > 0.2f ? share : 0.2f;
        w += share * (float)(!l->solid[i - st[a]] + !l->solid[i + st[a]]);
    }
    return w;
}

static nacre_result level_spans(nc_diff_solver *s, uint32_t li, int threads);
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

/* Level 0 from the medium; also finds its row spans (level_spans). */
static nacre_result build_fine(nc_diff_solver *s, const nc_diff_medium *m, int threads)
{
    level *l = &s->lv[0];
    const float h = m->h;
    const float A = (float)nc_diff_robin_a(m->eta);
    const uint32_t nx = m->dims[0], ny = m->dims[1], nz = l->n[2];
    const uint32_t cx = l->n[0], cy = l->n[1], *off = s->off;
    const size_t sy = l->sy, sz = l->sz;
    v4 *d = l->res; /* scratch: level 0's res serves the seed scheme only, which writes it first */
    const size_t user_cells = (size_t)m->dims[0] * m->dims[1] * m->dims[2];
    bool homogeneous = true;
    for (int c = 0; c < 3; c++)
        homogeneous &= !m->sigma_a[c] && !m->sigma_sp[c];
    memset(l->solid, 0, l->cells);
    /* d is read at solid cells only (pass 1 writes those, except on the fast path, which reads
     * neither d nor absorb); absorb and bnd are read at interior cells only, which passes 1 and
     * 3 write (no clearing pass over them) */
    v4 dconst = V4_ZERO, aconst = V4_ZERO;
    for (int c = 0; c < 3; c++) {
        float sa = m->sigma_a_const[c], sp = m->sigma_sp_const[c];
        dconst[c] = sa + sp > 0 ? 1.0f / (3.0f * (sa + sp)) : 0.0f;
        aconst[c] = sa * h * h * h;
    }
    /* The homogeneous fast path (below) needs neither the conductances nor the diagonal of
     * this level, nor D and the absorption per cell: every coefficient follows from k and bw and
     * the constants, and build_coarse forms level 1 from those too. A channel with D = 0
     * (sigma_t' = 0: no medium) would make it divide by 0; the general path gives such cells a
     * unit diagonal (finish_level). */
    const bool fast = homogeneous && dconst[0] > 0 && dconst[1] > 0 && dconst[2] > 0;
    /* D in the caller's grid (not on the fast path, which keeps D as dconst: see
     * nc_diff_coefficient_d): pass 1 writes every cell of the new box, so only the cells of the
     * previous box outside it need clearing (all of the grid if unknown); clearing the whole
     * grid (12 bytes per cell) was a tenth of a setup at 128^3. */
    const bool d_known = s->d_valid && memcmp(s->d_dims, m->dims, sizeof(s->d_dims)) == 0;
    const uint32_t *po = d_known ? s->d_off : NULL, *pn = s->d_n;
    if (!fast) {
#pragma omp parallel for num_threads(threads) schedule(static) if (user_cells > 32768)
        for (uint32_t z = 0; z < m->dims[2]; z++) {
            const size_t plane = (size_t)nx * ny;
            if (!po) {
                for (int c = 0; c < 3; c++)
                    memset(s->d_user[c] + plane * z, 0, plane * sizeof(float));
                continue;
            }
            if (z < po[2] || z >= po[2] + pn[2])
                continue;
            for (uint32_t y = po[1]; y < po[1] + pn[1]; y++) {
                /* the old row [x0, x1) minus the new box's [n0, n1) when the row is in the new box */
                size_t row = plane * z + (size_t)nx * y, x0 = po[0], x1 = (size_t)po[0] + pn[0];
                bool inside = z >= off[2] && z < off[2] + nz && y >= off[1] && y < off[1] + cy;
                size_t n0 = inside ? off[0] : x1, n1 = inside ? (size_t)off[0] + cx : x1;
                n0 = n0 > x0 ? n0 : x0;
                n1 = n1 < x1 ? n1 : x1;
                for (int c = 0; c < 3; c++) {
                    float *du = s->d_user[c] + row;
                    if (n0 >= n1) { /* no overlap */
                        memset(du + x0, 0, (x1 - x0) * sizeof(float));
                        continue;
                    }
                    memset(du + x0, 0, (n0 - x0) * sizeof(float));
                    memset(du + n1, 0, (x1 - n1) * sizeof(float));
                }
            }
        }
    }
    memcpy(s->d_dims, m->dims, sizeof(s->d_dims));
    memcpy(s->d_off, off, sizeof(s->d_off));
    s->d_n[0] = cx;
    s->d_n[1] = cy;
    s->d_n[2] = nz;
    s->d_valid = !fast;
    s->aconst = aconst;
    s->dconst = dconst;
    for (int c = 0; c < 3; c++)
        s->bden[c] = h + 4.0f * A * dconst[c];
    s->bden[3] = 1.0f;
    /* Pass 1: domain, D and absorption per cell (the fast path: the domain only). */
#pragma omp parallel for num_threads(threads) schedule(dynamic, 1) if (l->cells > 32768)
    for (uint32_t z = 0; z < nz; z++)
        for (uint32_t y = 0; y < cy; y++) {
            size_t u0 = (size_t)off[0] + (size_t)nx * ((y + off[1]) + (size_t)ny * (z + off[2])), i0 = pidx(l, 0, y, z);
            if (fast) {
                const uint8_t *ms = m->solid + u0;
                uint8_t *ls = l->solid + i0;
                for (uint32_t x = 0; x < cx; x++)
                    ls[x] = ms[x] != 0;
                continue;
            }
            for (uint32_t x = 0; x < cx; x++) {
                size_t u = u0 + x, i = i0 + x;
                bool in = m->solid[u] != 0;
                l->solid[i] = in;
                if (!in) {
                    s->absorb[i] = V4_ZERO;
                    for (int c = 0; c < 3; c++)
                        s->d_user[c][u] = 0.0f;
                    continue;
                }
                v4 dv = dconst, av = aconst;
                if (!homogeneous)
                    for (int c = 0; c < 3; c++) {
                        float sa = m->sigma_a[c] ? m->sigma_a[c][u] : m->sigma_a_const[c];
                        float sp = m->sigma_sp[c] ? m->sigma_sp[c][u] : m->sigma_sp_const[c];
                        dv[c] = sa + sp > 0 ? 1.0f / (3.0f * (sa + sp)) : 0.0f;
                        av[c] = sa * h * h * h;
                    }
                d[i] = dv;
                s->absorb[i] = av;
                for (int c = 0; c < 3; c++)
                    s->d_user[c][u] = dv[c];
            }
        }
    /* Pass 2: face conductances (harmonic mean of D, so the flux is continuous across media)
     * and the Robin boundary of exposed faces. The faces of a one-cell periodic axis join the
     * cell to itself: no flux and no boundary there. */
    int open_axes[3] = {!m->periodic[0], !m->periodic[1], !m->periodic[2]};
    const size_t st[3] = {1, sy, sz};
    /* The rest visits the active spans only (a tenth to a half of the bounding box), except the
     * general path's conductances, which are read across span ends. Outside the spans bw and k
     * stay 0 (k is read at active cells only; bw is summed by nc_diff_boundary_area). */
    nacre_result res = level_spans(s, 0, threads);
    if (res != NACRE_OK)
        return res;
    if (fast) {
        memset(l->k, 0, l->cells);
        memset(l->bw, 0, l->cells * sizeof(float));
    }
    const size_t ry = (size_t)cy + 2;
#pragma omp parallel for num_threads(threads) schedule(dynamic, 1) if (l->cells > 32768)
    for (size_t z = 0; z < (size_t)nz + 2; z++)
        for (size_t y = 0; y < ry; y++) {
            size_t row = y * sy + z * sz, i0 = row, i1 = row + sy;
            if (fast)
                row_span(l, (uint32_t)y, (uint32_t)z, &i0, &i1);
            for (size_t i = i0; i < i1; i++) {
                bool in = l->solid[i];
                int open = 0;
                for (int a = 0; a < 3; a++) {
                    size_t j = i + st[a];
                    v4 g = V4_ZERO;
                    if (!fast && in && j < l->cells && l->solid[j]) {
                        v4 di = d[i], dj = d[j];
                        if (homogeneous)
                            g = h * di;
                        else
                            for (int c = 0; c < 3; c++)
                                g[c] = di[c] > 0 && dj[c] > 0 ? h * 2.0f * di[c] * dj[c] / (di[c] + dj[c]) : 0.0f;
                    }
                    if (!fast)
                        l->g[a][i] = g;
                    if (in && open_axes[a])
                        open += !l->solid[i - st[a]] + !l->solid[i + st[a]];
                }
                l->k[i] = (uint8_t)(in ? open : 0); /* exposed faces, for the smoothing below */
                l->bw[i] = in && open ? boundary_weight(l, i, open_axes, m->staircase_faces) : 0.0f;
            }
        }
    if (!m->staircase_faces) {
        /* The normal estimate is noisy from cell to cell, and so would be the escape through
         * neighbouring faces (blotches in the image): each cell takes the mean share of true
         * area per exposed face over its 3x3x3 neighbourhood, times its own exposed faces. */
        float *smooth = (float *)s->pr; /* scratch: the PCG vectors are free during setup (nc_diff_setup clears pr's padding after) */
#pragma omp parallel for num_threads(threads) schedule(dynamic, 1) if (l->cells > 32768)
        for (size_t z = 1; z <= (size_t)nz; z++)
            for (size_t y = 1; y <= cy; y++) {
                size_t a, e;
                row_span(l, (uint32_t)y, (uint32_t)z, &a, &e);
                for (size_t i = a; i < e; i++) {
                    smooth[i] = l->bw[i];
                    if (l->bw[i] == 0.0f)
                        continue;
                    /* Cells with bw = 0 have k = 0 (not solid, or no exposed face), so summing
                     * them too adds zeros: the same sums, without a branch per neighbour; the
                     * padding keeps every index of an interior cell in range. */
                    float wsum = 0.0f;
                    int osum_i = 0;
                    for (int dz = -1; dz <= 1; dz++)
                        for (int dy = -1; dy <= 1; dy++) {
                            const size_t j =
                                (size_t)((ptrdiff_t)i + (ptrdiff_t)dy * (ptrdiff_t)sy + (ptrdiff_t)dz * (ptrdiff_t)sz);
                            for (int dx = -1; dx <= 1; dx++) {
                                wsum += l->bw[(size_t)((ptrdiff_t)j + dx)];
                                osum_i += l->k[(size_t)((ptrdiff_t)j + dx)];
                            }
                        }
                    const float osum = (float)osum_i;
                    smooth[i] = osum > 0 ? (float)l->k[i] * wsum / osum : l->bw[i];
                }
            }
        /* bw is nonzero at solid cells only, which the spans hold */
#pragma omp parallel for num_threads(threads) schedule(dynamic, 1) if (l->cells > 32768)
        for (size_t z = 1; z <= (size_t)nz; z++)
            for (size_t y = 1; y <= cy; y++) {
                size_t a, e;
                row_span(l, (uint32_t)y, (uint32_t)z, &a, &e);
                memcpy(l->bw + a, smooth + a, (e - a) * sizeof(float));
            }
    }
    /* Pass 3: Robin terms and diagonal (finish_level gives cells outside a unit diagonal). The
     * fast path's k (the exposed faces until here, for the smoothing) becomes the solid
     * neighbour count its kernels read, 7 outside the domain. */
#pragma omp parallel for num_threads(threads) schedule(dynamic, 1) if (l->cells > 32768)
    for (size_t z = 1; z <= (size_t)nz; z++)
        for (size_t y = 1; y <= cy; y++) {
            size_t a, e;
            row_span(l, (uint32_t)y, (uint32_t)z, &a, &e);
            for (size_t i = a; i < e; i++) {
                if (fast) {
                    int k = 7;
                    if (l->solid[i]) {
                        k = 0;
                        for (int ax = 0; ax < 3; ax++)
                            if (open_axes[ax])
                                k += l->solid[i - st[ax]] + l->solid[i + st[ax]];
                    }
                    l->k[i] = (uint8_t)k;
                    continue;
                }
                if (!l->solid[i]) {
                    s->bnd[i] = V4_ZERO;
                    continue;
                }
                const v4 dv = d[i];
                v4 den = V4_ZERO;
                for (int c = 0; c < 3; c++)
                    den[c] = h + 4.0f * A * dv[c];
                const v4 bv = robin_bnd(l->bw[i], dv, den, h);
                s->bnd[i] = bv;
                l->diag[i] = bv + s->absorb[i];
            }
        }
    if (!fast)
        finish_level(l, false, threads);
    homogeneous = fast;
    s->homogeneous = homogeneous;
    l->homogeneous_level = homogeneous;
    if (homogeneous) {
        v4 G = h * dconst, B = V4_ZERO;
        for (int c = 0; c < 3; c++)
            B[c] = h * h * 2.0f * dconst[c] / (h + 4.0f * A * dconst[c]);
        for (int k = 0; k < 7; k++) {
            l->kbase[k] = (float)k * G + aconst;
            l->kbase[k][3] = 1.0f; /* the unused lane: divide by 1, not 0 */
            l->kg[k] = G;
        }
        l->kbase[7] = V4_ONE;
        l->kg[7] = V4_ZERO;
        l->kb = B;
    }
    return NACRE_OK;
}

/* Conductance scale per coarsened axis. Re-discretizing a homogeneous medium on the coarse
 * cells gives 1/2 (four fine faces of conductance h D make one of 2 h D); that makes the coarse
 * correction exact for the smoothest error but too large for the intermediate frequencies
 * that piecewise-constant prolongation represents badly (it overshoots in energy). A slightly
 * stiffer coarse operator (over-correction 1/0.6 ~ 1.7 instead of 2, as in the aggregation
 * multigrid literature: Braess 1995, Vanek et al.) converges faster: on the marble sphere of
 * bench_diffusion_solver.c, PCG to 1e-4 takes 6, 6, 7, 7 iterations at 32..256^3 (W-cycle)
 * against 6, 7, 7, 8 with 1/2; 0.55-0.7 behave alike. */
#define COARSE_G_SCALE 0.6f
/* The seed's cascade (solve_seed) starts each level from the coarser level's solution, which
 * must approximate the fine one: it keeps the re-discretization's 1/2. */
#define SEED_G_SCALE 0.5f

/* Coarse level li from li - 1: Galerkin sums with conductances scaled by `scale` per coarsened
 * axis (COARSE_G_SCALE for multigrid, SEED_G_SCALE for the seed's cascade). Parallel over coarse
 * z slabs, each gathering its own fine children. Leaves solid, diag and g zero outside the new
 * domain; the caller finds the spans and finishes the diagonal (build_coarse_levels). Only the
 * previous build's spans are cleared when they are known (op_clean): at 128^3 level 1's padded
 * box has four times as many cells as its spans (Suzanne: 130k against 31k, 65 bytes each), which
 * saved about 0.3 ms per setup; the shifts below saved another 0.7 ms. */
static void build_coarse(nc_diff_solver *s, int li, float scale, int threads)
{
    level *f = &s->lv[li - 1], *l = &s->lv[li];
    /* A homogeneous fine level stores neither conductances nor diagonal (build_fine): its
     * conductance is G between solid cells, its boundary in bnd, its absorption aconst. */
    const bool hom = f->homogeneous_level;
    const v4 G = f->kg[0];
    const bool known = s->op_clean[li] && memcmp(s->op_n[li], l->n, sizeof(l->n)) == 0;
    s->op_clean[li] = false;
    const uint32_t *old = s->span[li];
    const size_t ry = (size_t)l->n[1] + 2, nzp = (size_t)l->n[2] + 2;
#pragma omp parallel for num_threads(threads) schedule(static) if (l->cells > 32768)
    for (size_t z = 0; z < nzp; z++) {
        if (!known) {
            const size_t p0 = z * l->sz, plane = l->sz;
            memset(l->solid + p0, 0, plane);
            memset(l->diag + p0, 0, plane * sizeof(v4));
            for (int a = 0; a < 3; a++)
                memset(l->g[a] + p0, 0, plane * sizeof(v4));
            continue;
        }
        for (size_t y = 0; y < ry; y++) {
            const size_t r = y + ry * z, a0 = y * l->sy + z * l->sz + old[2 * r], n = old[2 * r + 1] - old[2 * r];
            memset(l->solid + a0, 0, n);
            memset(l->diag + a0, 0, n * sizeof(v4));
            for (int a = 0; a < 3; a++)
                memset(l->g[a] + a0, 0, n * sizeof(v4));
        }
    }
    const size_t fst[3] = {1, f->sy, f->sz};
    float g_scale[3];
    for (int a = 0; a < 3; a++)
        g_scale[a] = l->r[a] == 2 ? scale : 1.0f;
    /* r is 1 or 2 per axis: coarse index = fine index >> (r - 1) (a division by the run-time r
     * per cell and axis was most of this loop's time) */
    const uint32_t shx = l->r[0] - 1, shy = l->r[1] - 1;
    const v4 aconst = s->aconst, dconst = s->dconst, bden = s->bden;
    const float *bw = f->bw, h = s->h;
#pragma omp parallel for num_threads(threads) schedule(dynamic, 1) if (f->cells > 32768)
    for (uint32_t Z = 0; Z < l->n[2]; Z++) {
        for (uint32_t z = Z * l->r[2]; z < (Z + 1) * l->r[2] && z < f->n[2]; z++)
            for (uint32_t y = 0; y < f->n[1]; y++) {
                /* the fine level's spans hold all its solid cells (padded x = interior x + 1) */
                const uint32_t *span = f->ext + 2 * ((size_t)y + 1 + ((size_t)f->n[1] + 2) * (z + 1));
                const uint32_t Y = y >> shy;
                /* faces inside an aggregate cancel: a +y (+z) face counts on the aggregate's
                 * last fine row (plane) only */
                const bool face_y = ((y + 1) >> shy) != Y, face_z = (z + 1) / l->r[2] != Z;
                const size_t frow = pidx(f, 0, y, z) - 1, crow = pidx(l, 0, Y, Z) - 1;
                for (uint32_t px = span[0]; px < span[1]; px++) {
                    const size_t i = frow + px;
                    if (!f->solid[i])
                        continue;
                    const uint32_t x = px - 1, X = x >> shx;
                    const size_t I = crow + 1 + X;
                    l->solid[I] = 1;
                    /* diag minus the six conductances = boundary + absorption of the fine cell */
                    v4 nonc;
                    if (hom) {
                        nonc = robin_bnd(bw[i], dconst, bden, h) + aconst;
                    } else {
                        nonc = f->diag[i];
                        for (int a = 0; a < 3; a++)
                            nonc -= f->g[a][i] + f->g[a][i - fst[a]];
                    }
                    for (int c = 0; c < 4; c++)
                        nonc[c] = nonc[c] > 0 ? nonc[c] : 0.0f;
                    l->diag[I] += nonc;
                    const bool face[3] = {((x + 1) >> shx) != X, face_y, face_z};
                    for (int a = 0; a < 3; a++)
                        if (face[a])
                            l->g[a][I] += (hom ? (f->solid[i + fst[a]] ? G : V4_ZERO) : f->g[a][i]) * g_scale[a];
                }
            }
    }
}

/* The active span of each row of level li (level.ext), from its solid cells; the previous
 * setup's spans move to span_old. */
static nacre_result level_spans(nc_diff_solver *s, uint32_t li, int threads)
{
    level *l = &s->lv[li];
    const size_t ry = (size_t)l->n[1] + 2, rows = ry * ((size_t)l->n[2] + 2);
    if (s->span_capacity[li] < rows) {
        nc_free(s->ctx, s->span[li]);
        nc_free(s->ctx, s->span_old[li]);
        s->span[li] = nc_alloc(s->ctx, 2 * rows * sizeof(uint32_t));
        s->span_old[li] = nc_alloc(s->ctx, 2 * rows * sizeof(uint32_t));
        s->span_valid[li] = false;
        s->span_capacity[li] = s->span[li] && s->span_old[li] ? rows : 0;
        if (!s->span_capacity[li])
            return nc_fail(s->ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory");
    }
    uint32_t *e = s->span_old[li];
    s->span_old[li] = s->span[li];
    s->span[li] = e;
    const uint32_t nx = l->n[0], ny = l->n[1], nz = l->n[2];
#pragma omp parallel for num_threads(threads) schedule(static) if (l->cells > 32768)
    for (uint32_t z = 0; z <= nz + 1; z++)
        for (uint32_t y = 0; y <= ny + 1; y++) {
            uint32_t lo = 1, hi = 1;
            if (z >= 1 && z <= nz && y >= 1 && y <= ny) {
                const uint8_t *row = l->solid + l->sy * y + l->sz * z + 1; /* interior x = 1..nx */
                const size_t first = nc_first_nonzero(row, nx);
                if (first < nx) {
                    lo = (uint32_t)first + 1;
                    hi = (uint32_t)nc_last_nonzero(row, nx) + 2;
                }
            }
            e[2 * (y + ry * z)] = lo;
            e[2 * (y + ry * z) + 1] = hi;
        }
    l->ext = e;
    /* Balanced slabs: active cells plus one per row (the row's own overhead) per plane. */
    int parts = threads < MAX_PARTS ? threads : MAX_PARTS;
    parts = parts < (int)nz ? parts : (int)nz;
    parts = parts > 0 ? parts : 1;
    uint64_t total = 0, cells = 0;
    for (uint32_t z = 1; z <= nz; z++)
        for (uint32_t y = 1; y <= ny; y++) {
            uint64_t len = e[2 * (y + ry * z) + 1] - e[2 * (y + ry * z)];
            cells += len;
            total += 1 + len;
        }
    l->active = (size_t)cells;
    l->parts = parts;
    l->zb[0] = 1;
    uint64_t acc = 0;
    uint32_t z = 1;
    for (int t = 1; t < parts; t++) {
        uint64_t target = total * (uint64_t)t / (uint64_t)parts;
        while (z <= nz && acc < target) {
            for (uint32_t y = 1; y <= ny; y++)
                acc += 1 + e[2 * (y + ry * z) + 1] - e[2 * (y + ry * z)];
            z++;
        }
        l->zb[t] = z;
    }
    l->zb[parts] = nz + 1;
    return NACRE_OK;
}

/* Zero the interior cells of array a outside the current spans of level l: all of them (old
 * NULL), or only those inside the spans `old` (the array is known to be zero outside those). */
static void zero_outside(const level *l, v4 *a, const uint32_t *old, int threads)
{
    const uint32_t nx = l->n[0], ny = l->n[1], nz = l->n[2];
    const size_t ry = (size_t)ny + 2;
#pragma omp parallel for num_threads(threads) schedule(static) if (l->cells > 32768)
    for (uint32_t z = 1; z <= nz; z++)
        for (uint32_t y = 1; y <= ny; y++) {
            size_t r = y + ry * z, row = l->sy * y + l->sz * z;
            uint32_t lo = l->ext[2 * r], hi = l->ext[2 * r + 1];
            uint32_t olo = old ? old[2 * r] : 1, ohi = old ? old[2 * r + 1] : nx + 1;
            if (lo == hi) /* empty: everything of the old range goes */
                lo = hi = ohi;
            for (uint32_t x = olo; x < lo && x < ohi; x++)
                a[row + x] = V4_ZERO;
            for (uint32_t x = hi > olo ? hi : olo; x < ohi; x++)
                a[row + x] = V4_ZERO;
        }
}

static inline v4 cell_diag(const level *l, size_t i);
static inline v4 cell_offdiag(const level *l, const v4 *v, size_t i);

/* Invert the coarsest level's operator per channel (Gauss-Jordan in double; the matrix is
 * symmetric positive definite, so no pivoting is needed and a pivot that is not positive means
 * a singular level: coarse_direct stays false). Its columns come from the operator applied to
 * unit vectors, so the homogeneous fast path needs no special case. */
static void coarsest_factor(nc_diff_solver *s)
{
    level *l = &s->lv[s->level_count - 1];
    s->coarse_direct = false;
    uint32_t n = 0;
    for (size_t i = 0; i < l->cells; i++)
        if (l->solid[i]) {
            if (n == 8)
                return;
            s->cidx[n++] = i;
        }
    s->coarse_count = n;
    v4 *e = l->res; /* scratch: read by the seed scheme only after writing it */
    memset(e, 0, l->cells * sizeof(v4));
    double a[3][8][16];
    for (uint32_t j = 0; j < n; j++) {
        e[s->cidx[j]] = V4_ONE;
        for (uint32_t i = 0; i < n; i++) {
            size_t ci = s->cidx[i];
            v4 col = cell_diag(l, ci) * e[ci] - cell_offdiag(l, e, ci);
            for (int c = 0; c < 3; c++) {
                a[c][i][j] = col[c];
                a[c][i][8 + j] = i == j;
            }
        }
        e[s->cidx[j]] = V4_ZERO;
    }
    for (int c = 0; c < 3; c++)
        for (uint32_t k = 0; k < n; k++) {
            double piv = a[c][k][k];
            if (!(piv > 0) || !isfinite(piv))
                return;
            for (uint32_t j = 0; j < 16; j++)
                a[c][k][j] /= piv;
            for (uint32_t i = 0; i < n; i++) {
                double f = a[c][i][k];
                if (i == k || f == 0.0)
                    continue;
                for (uint32_t j = 0; j < 16; j++)
                    a[c][i][j] -= f * a[c][k][j];
            }
        }
    for (int c = 0; c < 3; c++)
        for (uint32_t i = 0; i < n; i++)
            for (uint32_t j = 0; j < n; j++)
                s->cinv[c][i][j] = a[c][i][8 + j];
    s->coarse_direct = true;
}

/* All coarse levels with conductance scale `scale`, and the coarsest level's inverse. Each
 * level is built from the finer one's spans: with `spans` (a new setup, level 0's spans done),
 * each new level's spans are found as it is built; otherwise they are current. */
static nacre_result build_coarse_levels(nc_diff_solver *s, float scale, bool spans, int threads)
{
    for (uint32_t li = 1; li < s->level_count; li++) {
        build_coarse(s, (int)li, scale, threads);
        nacre_result res;
        if (spans && (res = level_spans(s, li, threads)) != NACRE_OK)
            return res;
        finish_level(&s->lv[li], true, threads);
        s->op_clean[li] = true;
        memcpy(s->op_n[li], s->lv[li].n, sizeof(s->lv[li].n));
    }
    s->coarse_scale = scale;
    coarsest_factor(s);
    return NACRE_OK;
}

nacre_result nc_diff_setup(nc_diff_solver *s, const nc_diff_medium *m)
{
    if (!s || !m || !m->solid)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_context *ctx = s->ctx;
    if (m->dims[0] == 0 || m->dims[1] == 0 || m->dims[2] == 0 || !(m->h > 0) || !isfinite(m->h))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "diffusion: empty grid or bad cell size");
    if (!(m->eta >= NACRE_ETA_MIN && m->eta <= NACRE_ETA_MAX))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "diffusion: eta must be in [%g, %g] (got %g)", NACRE_ETA_MIN,
                       NACRE_ETA_MAX, (double)m->eta);
    for (int a = 0; a < 3; a++)
        if (m->periodic[a] && m->dims[a] != 1)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "diffusion: a periodic axis must have one cell");
    size_t cells;
    if (m->dims[0] > (1u << 16) || m->dims[1] > (1u << 16) || m->dims[2] > (1u << 24) ||
        !nc_mul_size_ok((size_t)m->dims[0] + 2, (size_t)m->dims[1] + 2, &cells) ||
        !nc_mul_size_ok(cells, (size_t)m->dims[2] + 2, &cells) || cells > ((size_t)1 << 30))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "diffusion: grid %ux%ux%u too large", m->dims[0], m->dims[1],
                       m->dims[2]);
    memcpy(s->dims, m->dims, sizeof(s->dims));
    s->h = m->h;
    size_t user_cells = (size_t)m->dims[0] * m->dims[1] * m->dims[2];
    /* Work on the bounding box of the solid cells: a cubic grid around a slender mesh (Lucy
     * fills a third of its 128^3) would otherwise spend most passes on empty cells. */
    /* Row by row: a row's first and last solid cells, found from both ends (most rows are
     * empty or have their solid cells in one run). min / max reductions: exact, so parallel. */
    uint32_t lo0 = m->dims[0], lo1 = m->dims[1], lo2 = m->dims[2], hi0 = 0, hi1 = 0, hi2 = 0;
    const uint32_t dx = m->dims[0];
#pragma omp parallel for num_threads(ctx->threads) schedule(static) reduction(min : lo0, lo1, lo2) \
    reduction(max : hi0, hi1, hi2) if (user_cells > 32768)
    for (uint32_t z = 0; z < m->dims[2]; z++)
        for (uint32_t y = 0; y < m->dims[1]; y++) {
            const uint8_t *row = m->solid + (size_t)dx * (y + (size_t)m->dims[1] * z);
            const uint32_t first = (uint32_t)nc_first_nonzero(row, dx);
            if (first == dx)
                continue;
            const uint32_t last = (uint32_t)nc_last_nonzero(row, dx);
            lo0 = first < lo0 ? first : lo0;
            hi0 = last > hi0 ? last : hi0;
            lo1 = y < lo1 ? y : lo1;
            hi1 = y > hi1 ? y : hi1;
            lo2 = z < lo2 ? z : lo2;
            hi2 = z > hi2 ? z : hi2;
        }
    uint32_t lo[3] = {lo0, lo1, lo2}, hi[3] = {hi0, hi1, hi2};
    if (lo[0] > hi[0]) /* no solid cell: a one-cell empty grid */
        lo[0] = lo[1] = lo[2] = hi[0] = hi[1] = hi[2] = 0;
    memcpy(s->off, lo, sizeof(lo));
    /* Level sizes: coarsen each axis longer than 2 cells, down to at most 2 per axis. */
    uint32_t n[3] = {hi[0] - lo[0] + 1, hi[1] - lo[1] + 1, hi[2] - lo[2] + 1};
    uint32_t count = 0;
    s->lv[0].r[0] = s->lv[0].r[1] = s->lv[0].r[2] = 1;
    for (;;) {
        level_shape(&s->lv[count], n);
        nacre_result res = level_alloc(s, (int)count, user_cells);
        if (res != NACRE_OK)
            return res;
        count++;
        bool any = false;
        uint32_t r[3];
        for (int a = 0; a < 3; a++) {
            r[a] = n[a] > 2 ? 2 : 1;
            any |= r[a] == 2;
        }
        if (!any || count == MAX_LEVELS)
            break;
        for (int a = 0; a < 3; a++) {
            n[a] = (n[a] + r[a] - 1) / r[a];
            s->lv[count].r[a] = r[a];
        }
    }
    s->level_count = count;
    nacre_result res = build_fine(s, m, ctx->threads);
    if (res != NACRE_OK)
        return res;
    zero_padding(&s->lv[0], s->pr); /* pr was scratch (smoothed boundary weights) */
    if ((res = build_coarse_levels(s, COARSE_G_SCALE, true, ctx->threads)) != NACRE_OK)
        return res;
    size_t part = 3 * ((size_t)s->lv[0].n[2] + 2);
    if (s->part_capacity < part) {
        nc_free(ctx, s->part);
        s->part = nc_alloc(ctx, part * sizeof(v4d));
        s->part_capacity = s->part ? part : 0;
        if (!s->part)
            return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory");
    }
    /* Kernels visit the active row spans only. The arrays that neighbour sums read (x of the
     * coarse levels; z, both directions and the solution at level 0) are read at cells outside
     * the spans too, which must hold zero: the padding and every cell outside the spans. The
     * kernels never write there, so when a level keeps its shape from the previous setup only
     * the cells that have left the spans are cleared (clearing whole arrays was a quarter of the
     * propagation stage of a deforming object at 64^3); other arrays are read at active cells
     * only, after being written. */
    for (uint32_t li = 0; li < count; li++) {
        level *l = &s->lv[li];
        bool diff = s->span_valid[li] && memcmp(s->span_n[li], l->n, sizeof(l->n)) == 0;
        v4 *zeroed[4] = {l->x, NULL, NULL, NULL};
        if (li == 0) {
            zeroed[0] = s->pz;
            zeroed[1] = s->pp;
            zeroed[2] = s->pp2;
            zeroed[3] = s->px;
        }
        for (int k = 0; k < 4 && zeroed[k]; k++) {
            if (!diff)
                zero_padding(l, zeroed[k]);
            zero_outside(l, zeroed[k], diff ? s->span_old[li] : NULL, ctx->threads);
        }
        s->span_valid[li] = true;
        memcpy(s->span_n[li], l->n, sizeof(l->n));
    }
    return NACRE_OK;
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

/* The same off-diagonal sum with every product in double (residual_exact). */
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

/* The active cells [*a, *e) (padded indices) of interior row (y, z), 1-based padded y and z;
 * an empty row gives a == e. */
static inline void row_span(const level *l, uint32_t y, uint32_t z, size_t *a, size_t *e)
{
    const uint32_t *x = l->ext + 2 * ((size_t)y + ((size_t)l->n[1] + 2) * z);
    size_t row = l->sy * y + l->sz * z;
    *a = row + x[0];
    *e = row + x[1];
}

/* First cell of `color` ((x + y + z) % 2, padded coordinates) at or after padded index a of row
 * (y, z) whose first padded cell is `row`. */
static inline size_t color_start(size_t a, size_t row, uint32_t y, uint32_t z, int color)
{
    return a + (((size_t)color + (a - row) + y + z) & 1);
}

/* Per-slab partial sums of the reductions, added in slab order: the result does not depend on
 * the number of threads or the schedule. */
static v4d sum_slabs(const v4d *part, uint32_t nz)
{
    v4d r = {0.0, 0.0, 0.0, 0.0};
    for (uint32_t z = 1; z <= nz; z++)
        r += part[z];
    return r;
}

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
static v4d residual_exact(const level *l, const v4 *v, const v4 *b, v4 *out, v4d *bb, bool exact, v4d *part,
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
static void restrict_rows(const level *f, const level *l, const v4 *v, const v4 *b, v4 *coarse, int threads)
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
    restrict_rows(l, lc, x, b, lc->b, threads);
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
static void warm_fill(const level *l, v4 *x, const v4 *b, int threads)
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
 * The residual r (float, as residual_exact computes it) and r . r are then updated at the cells
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

static void solve_pcg(nc_diff_solver *s, const v4 *b, v4 *x, const nc_diff_solve_opts *o, nc_diff_solve_report rep[3])
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
    v4d rr = residual_exact(l, x, b, r, &bb, false, part, threads);
    if (o->warm_start && !o->no_local_relax)
        hot_relax(s, b, x, r, &rr, threads);
    bool exact = false, near = false;
    double bnorm[3];
    for (int c = 0; c < 3; c++) {
        bnorm[c] = sqrt(bb[c]);
        near |= bnorm[c] > 0 && sqrt(rr[c]) <= 2.0 * tol * bnorm[c];
    }
    if (near) {
        rr = residual_exact(l, x, b, r, NULL, true, part, threads);
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
            rr = residual_exact(l, x, b, r, NULL, true, part, threads);
        exact = true;
        bool active[3], any = false;
        for (int c = 0; c < 3; c++) {
            active[c] = sqrt(rr[c]) > tol * bnorm[c];
            any |= active[c];
        }
        if (!any)
            break;
        if (o->deadline_us && nc_now_us() >= o->deadline_us) {
            rep[0].timed_out = true;
            break;
        }
        v4d rz;
        cycle(s, 0, r, z, START_ZERO, &rz, threads);
        v4 beta = V4_ZERO;
        bool first = true; /* p = z */
        while (it < max_it) {
            if (o->deadline_us && nc_now_us() >= o->deadline_us) {
                rep[0].timed_out = true;
                break;
            }
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
        rr = residual_exact(l, x, b, r, NULL, true, part, threads);
    for (int c = 0; c < 3; c++) {
        rep[c].iterations = it;
        rep[c].residual = bnorm[c] > 0 ? sqrt(rr[c]) / bnorm[c] : 0.0;
        rep[c].timed_out = rep[0].timed_out;
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
static void solve_seed(nc_diff_solver *s, const v4 *b, v4 *x, const nc_diff_solve_opts *o, nc_diff_solve_report rep[3])
{
    const int threads = s->ctx->threads;
    uint32_t top = 0; /* the coarsest level with a side of at least 4 cells (the seed's smallest) */
    for (uint32_t li = 1; li < s->level_count && !o->seed_single_grid; li++) {
        if (max_dim(&s->lv[li]) < 4)
            break;
        top = li;
    }
    for (uint32_t li = 1; li <= top; li++)
        restrict_rows(&s->lv[li - 1], &s->lv[li], NULL, li == 1 ? b : s->lv[li - 1].b, s->lv[li].b, threads);
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
    v4d rr = residual_exact(l0, x, b, l0->res, &bb, true, s->part, threads);
    for (int c = 0; c < 3; c++) {
        rep[c].iterations = total;
        rep[c].residual = bb[c] > 0 ? sqrt(rr[c] / bb[c]) : 0.0;
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
        build_coarse_levels(s, scale, false, threads);
    if (opts->solver == NACRE_SOLVER_SEED) {
        solve_seed(s, b, x, opts, rep);
    } else {
        if (warm && any_fresh)
            warm_fill(l, x, b, threads);
        solve_pcg(s, b, x, opts, rep);
    }
    if (!opts->no_energy) {
        /* Energy from the final phi: injected = absorbed + escaped at convergence. Per-slab sums
         * added in slab order (independent of the thread count). */
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
    if (s->out_span_capacity < user_rows) {
        nc_free(s->ctx, s->out_span);
        s->out_span_capacity = 0;
        if (!(s->out_span = nc_alloc(s->ctx, 2 * user_rows * sizeof(uint32_t))))
            return nc_fail(s->ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory");
        s->out_span_capacity = user_rows;
    }
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
