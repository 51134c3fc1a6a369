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
 *   MULTIGRID (default): conjugate gradients preconditioned by one multigrid V-cycle. Coarse
 *     levels aggregate 2x2x2 cells (a coarse cell is in the domain when any child is, as the
 *     voxel pyramid of seed 4.2.2); their operator is the Galerkin sum of the fine one with the
 *     face conductances scaled by 1/2 per coarsened axis, which is what re-discretizing on the
 *     coarse cells gives for a homogeneous medium (piecewise-constant transfer alone would make
 *     the coarse operator twice too stiff). Smoother: red-black Gauss-Seidel, red then black
 *     before and black then red after the coarse correction, so the V-cycle is a symmetric
 *     operator as conjugate gradients needs. Stops at ||S - M phi|| <= tol * ||S||.
 *   SEED: the seed's scheme for reproducing its numbers: Jacobi sweeps with fixed counts on the
 *     levels from 4 cells up (tables 4.3 and 5.6), each level started from the coarser one.
 *
 * Sources are restricted to the coarse levels by summation (power is additive), which is the
 * seed's "inject on every level" (section 4.4) done once.
 */
#include "diffusion/diffusion.h"
#include "core/optics.h"

#include <math.h>
#include <string.h>

#define MAX_LEVELS 16

/* Each level is stored with one layer of padding cells around it (outside the domain, zero
 * conductances), so the stencil kernels need no bounds tests. Periodic axes must have one cell
 * (the slab): a face that joins a cell to itself carries no flux, so they need no storage. */
typedef struct level {
    uint32_t n[3];    /* interior cells per axis */
    uint32_t p[3];    /* padded: n + 2 */
    uint32_t r[3];    /* coarsening factor from the previous (finer) level per axis: 1 or 2 */
    size_t cells;     /* padded cell count */
    size_t sy, sz;    /* strides */
    uint8_t *solid;
    /* per channel: conductance to the +x, +y, +z neighbour (0 when either cell is outside),
     * diagonal and its inverse (1 outside the domain) */
    float *g[3][3];
    float *diag[3], *inv_diag[3];
    float *x, *b, *res; /* V-cycle work */
} level;

struct nc_diff_solver {
    nacre_context *ctx;
    float h;
    uint32_t dims[3];
    uint32_t level_count;
    level lv[MAX_LEVELS];
    size_t capacity[MAX_LEVELS]; /* cells allocated per level */
    /* level 0 extras (padded layout) */
    float *d[3];      /* D per cell; also handed out in the caller's layout (d_user) */
    float *d_user[3];
    float *bnd[3];    /* boundary conductance sum per cell (escape) */
    float *absorb[3]; /* sigma_a h^3 per cell */
    float *pr, *pz, *pp, *pq, *px; /* PCG vectors */
    size_t user_capacity;
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
    for (int c = 0; c < 3; c++) {
        for (int a = 0; a < 3; a++)
            nc_free(ctx, l->g[c][a]);
        nc_free(ctx, l->diag[c]);
        nc_free(ctx, l->inv_diag[c]);
    }
    nc_free(ctx, l->x);
    nc_free(ctx, l->b);
    nc_free(ctx, l->res);
    memset(l, 0, sizeof(*l));
}

static void extras_free(nc_diff_solver *s)
{
    nacre_context *ctx = s->ctx;
    for (int c = 0; c < 3; c++) {
        nc_free(ctx, s->d[c]);
        nc_free(ctx, s->d_user[c]);
        nc_free(ctx, s->bnd[c]);
        nc_free(ctx, s->absorb[c]);
        s->d[c] = s->d_user[c] = s->bnd[c] = s->absorb[c] = NULL;
    }
    nc_free(ctx, s->pr);
    nc_free(ctx, s->pz);
    nc_free(ctx, s->pp);
    nc_free(ctx, s->pq);
    nc_free(ctx, s->px);
    s->pr = s->pz = s->pp = s->pq = s->px = NULL;
}

void nc_diff_solver_destroy(nc_diff_solver *s)
{
    if (!s)
        return;
    for (int i = 0; i < MAX_LEVELS; i++)
        level_free(s->ctx, &s->lv[i]);
    extras_free(s);
    nc_free(s->ctx, s);
}

const float *nc_diff_coefficient_d(const nc_diff_solver *s, int channel)
{
    return (s && channel >= 0 && channel < 3) ? s->d_user[channel] : NULL;
}

/* (Re)allocate a level's arrays when its padded size grows; level 0 also gets the extras. */
static nacre_result level_alloc(nc_diff_solver *s, int li, size_t user_cells)
{
    nacre_context *ctx = s->ctx;
    level *l = &s->lv[li];
    size_t cells = l->cells;
    bool ok = true;
    if (s->capacity[li] < cells || !l->solid) {
        level keep = *l;
        level_free(ctx, l);
        memcpy(l->n, keep.n, sizeof(keep.n));
        memcpy(l->p, keep.p, sizeof(keep.p));
        memcpy(l->r, keep.r, sizeof(keep.r));
        l->cells = keep.cells;
        l->sy = keep.sy;
        l->sz = keep.sz;
        s->capacity[li] = 0;
        size_t fb = cells * sizeof(float);
        ok = (l->solid = nc_alloc(ctx, cells)) != NULL;
        for (int c = 0; c < 3 && ok; c++) {
            for (int a = 0; a < 3 && ok; a++)
                ok = (l->g[c][a] = nc_alloc(ctx, fb)) != NULL;
            ok = ok && (l->diag[c] = nc_alloc(ctx, fb)) != NULL && (l->inv_diag[c] = nc_alloc(ctx, fb)) != NULL;
        }
        ok = ok && (l->x = nc_alloc(ctx, fb)) && (l->b = nc_alloc(ctx, fb)) && (l->res = nc_alloc(ctx, fb));
        if (ok && li == 0) {
            extras_free(s);
            for (int c = 0; c < 3; c++) {
                s->d[c] = nc_alloc(ctx, fb);
                s->bnd[c] = nc_alloc(ctx, fb);
                s->absorb[c] = nc_alloc(ctx, fb);
                ok = ok && s->d[c] && s->bnd[c] && s->absorb[c];
            }
            s->pr = nc_alloc(ctx, fb);
            s->pz = nc_alloc(ctx, fb);
            s->pp = nc_alloc(ctx, fb);
            s->pq = nc_alloc(ctx, fb);
            s->px = nc_alloc(ctx, fb);
            ok = ok && s->pr && s->pz && s->pp && s->pq && s->px;
        }
        if (ok)
            s->capacity[li] = cells;
    }
    if (ok && li == 0 && s->user_capacity < user_cells) {
        for (int c = 0; c < 3; c++) {
            nc_free(ctx, s->d_user[c]);
            s->d_user[c] = nc_alloc(ctx, user_cells * sizeof(float));
            ok = ok && s->d_user[c];
        }
        s->user_capacity = ok ? user_cells : 0;
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

static void finish_diag(level *l, int c)
{
    for (size_t i = 0; i < l->cells; i++) {
        if (!l->solid[i]) {
            l->diag[c][i] = 1.0f;
            l->inv_diag[c][i] = 1.0f;
        } else {
            l->inv_diag[c][i] = l->diag[c][i] > 0 ? 1.0f / l->diag[c][i] : 0.0f;
        }
    }
}

/* diag += the conductances of the six faces (diag holds boundary + absorption on entry). */
static void add_conductances(level *l, int c)
{
    const size_t st[3] = {1, l->sy, l->sz};
    for (size_t i = 0; i < l->cells; i++)
        for (int a = 0; a < 3; a++) {
            float g = l->g[c][a][i];
            if (g != 0.0f) {
                l->diag[c][i] += g;
                l->diag[c][i + st[a]] += g;
            }
        }
}

static nacre_result build_fine(nc_diff_solver *s, const nc_diff_medium *m)
{
    level *l = &s->lv[0];
    const float h = m->h;
    const float A = (float)nc_diff_robin_a(m->eta);
    const uint32_t nx = m->dims[0], ny = m->dims[1];
    const size_t st[3] = {1, l->sy, l->sz};
    memset(l->solid, 0, l->cells);
    for (uint32_t z = 0; z < l->n[2]; z++)
        for (uint32_t y = 0; y < l->n[1]; y++)
            for (uint32_t x = 0; x < l->n[0]; x++)
                l->solid[pidx(l, x, y, z)] = m->solid[x + (size_t)nx * (y + (size_t)ny * z)] != 0;
    for (int c = 0; c < 3; c++) {
        float *d = s->d[c];
        memset(d, 0, l->cells * sizeof(float));
        memset(s->absorb[c], 0, l->cells * sizeof(float));
        memset(s->bnd[c], 0, l->cells * sizeof(float));
        for (uint32_t z = 0; z < l->n[2]; z++)
            for (uint32_t y = 0; y < l->n[1]; y++)
                for (uint32_t x = 0; x < l->n[0]; x++) {
                    size_t u = x + (size_t)nx * (y + (size_t)ny * z), i = pidx(l, x, y, z);
                    float du = 0.0f;
                    if (l->solid[i]) {
                        float sa = m->sigma_a[c] ? m->sigma_a[c][u] : m->sigma_a_const[c];
                        float sp = m->sigma_sp[c] ? m->sigma_sp[c][u] : m->sigma_sp_const[c];
                        float sum = sa + sp;
                        du = sum > 0 ? 1.0f / (3.0f * sum) : 0.0f;
                        s->absorb[c][i] = sa * h * h * h;
                    }
                    d[i] = du;
                    s->d_user[c][u] = du;
                }
        for (size_t i = 0; i < l->cells; i++) {
            for (int a = 0; a < 3; a++) {
                size_t j = i + st[a];
                float g = 0.0f;
                if (j < l->cells && l->solid[i] && l->solid[j] && d[i] > 0 && d[j] > 0)
                    g = h * 2.0f * d[i] * d[j] / (d[i] + d[j]);
                l->g[c][a][i] = g;
            }
        }
        for (uint32_t z = 0; z < l->n[2]; z++)
            for (uint32_t y = 0; y < l->n[1]; y++)
                for (uint32_t x = 0; x < l->n[0]; x++) {
                    size_t i = pidx(l, x, y, z);
                    if (!l->solid[i])
                        continue;
                    /* Robin condition on each face whose neighbour is outside the domain; the
                     * faces of a one-cell periodic axis join the cell to itself: no boundary. */
                    float bface = h * h * 2.0f * d[i] / (h + 4.0f * A * d[i]);
                    float bsum = 0.0f;
                    for (int a = 0; a < 3; a++) {
                        if (m->periodic[a])
                            continue;
                        bsum += (l->solid[i - st[a]] ? 0.0f : bface) + (l->solid[i + st[a]] ? 0.0f : bface);
                    }
                    s->bnd[c][i] = bsum;
                }
        for (size_t i = 0; i < l->cells; i++)
            l->diag[c][i] = l->solid[i] ? s->bnd[c][i] + s->absorb[c][i] : 0.0f;
        add_conductances(l, c);
        finish_diag(l, c);
    }
    return NACRE_OK;
}

/* Coarse level li from li - 1: Galerkin sums with conductances scaled by 1 / r per axis. */
static void build_coarse(nc_diff_solver *s, int li)
{
    level *f = &s->lv[li - 1], *l = &s->lv[li];
    (void)s;
    memset(l->solid, 0, l->cells);
    for (int c = 0; c < 3; c++) {
        memset(l->diag[c], 0, l->cells * sizeof(float));
        for (int a = 0; a < 3; a++)
            memset(l->g[c][a], 0, l->cells * sizeof(float));
    }
    const size_t fst[3] = {1, f->sy, f->sz};
    for (uint32_t z = 0; z < f->n[2]; z++)
        for (uint32_t y = 0; y < f->n[1]; y++)
            for (uint32_t x = 0; x < f->n[0]; x++) {
                size_t i = pidx(f, x, y, z);
                if (!f->solid[i])
                    continue;
                uint32_t p[3] = {x, y, z};
                uint32_t cp[3] = {x / l->r[0], y / l->r[1], z / l->r[2]};
                size_t I = pidx(l, cp[0], cp[1], cp[2]);
                l->solid[I] = 1;
                for (int c = 0; c < 3; c++) {
                    /* diag minus the six conductances = boundary + absorption of the fine cell */
                    float nonc = f->diag[c][i];
                    for (int a = 0; a < 3; a++)
                        nonc -= f->g[c][a][i] + f->g[c][a][i - fst[a]];
                    l->diag[c][I] += nonc > 0 ? nonc : 0.0f;
                    for (int a = 0; a < 3; a++) {
                        float g = f->g[c][a][i];
                        if (g == 0.0f || (p[a] + 1) / l->r[a] == cp[a])
                            continue; /* none, or inside the aggregate (cancels in the sum) */
                        l->g[c][a][I] += g / (float)l->r[a];
                    }
                }
            }
    for (int c = 0; c < 3; c++) {
        add_conductances(l, c);
        finish_diag(l, c);
    }
}

static void level_shape(level *l, const uint32_t n[3])
{
    for (int a = 0; a < 3; a++) {
        l->n[a] = n[a];
        l->p[a] = n[a] + 2;
    }
    l->sy = l->p[0];
    l->sz = (size_t)l->p[0] * l->p[1];
    l->cells = l->sz * l->p[2];
}

nacre_result nc_diff_setup(nc_diff_solver *s, const nc_diff_medium *m)
{
    if (!s || !m || !m->solid)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_context *ctx = s->ctx;
    if (m->dims[0] == 0 || m->dims[1] == 0 || m->dims[2] == 0 || !(m->h > 0) || !isfinite(m->h))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "diffusion: empty grid or bad cell size");
    if (!(m->eta > 0) || !isfinite(m->eta))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "diffusion: eta must be finite and > 0");
    for (int a = 0; a < 3; a++)
        if (m->periodic[a] && m->dims[a] != 1)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "diffusion: a periodic axis must have one cell");
    size_t cells;
    if (m->dims[0] > (1u << 16) || m->dims[1] > (1u << 16) || m->dims[2] > (1u << 24) ||
        !nc_mul_size_ok((size_t)m->dims[0] + 2, (size_t)m->dims[1] + 2, &cells) ||
        !nc_mul_size_ok(cells, (size_t)m->dims[2] + 2, &cells) || cells > ((size_t)1 << 31))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "diffusion: grid %ux%ux%u too large", m->dims[0], m->dims[1],
                       m->dims[2]);
    s->h = m->h;
    memcpy(s->dims, m->dims, sizeof(s->dims));
    size_t user_cells = (size_t)m->dims[0] * m->dims[1] * m->dims[2];
    /* Level sizes: coarsen each axis longer than 2 cells, down to at most 2 per axis. */
    uint32_t n[3] = {m->dims[0], m->dims[1], m->dims[2]};
    uint32_t count = 0;
    for (;;) {
        level *l = &s->lv[count];
        level_shape(l, n);
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
    /* Kernels write interior cells only: the padding of every work array must read as zero,
     * whatever a previous, differently shaped grid left there. */
    for (uint32_t li = 0; li < count; li++) {
        level *l = &s->lv[li];
        memset(l->x, 0, l->cells * sizeof(float));
        memset(l->b, 0, l->cells * sizeof(float));
        memset(l->res, 0, l->cells * sizeof(float));
    }
    float *work[5] = {s->pr, s->pz, s->pp, s->pq, s->px};
    for (int k = 0; k < 5; k++)
        memset(work[k], 0, s->lv[0].cells * sizeof(float));
    nacre_result res = build_fine(s, m);
    if (res != NACRE_OK)
        return res;
    for (uint32_t li = 1; li < count; li++)
        build_coarse(s, (int)li);
    return NACRE_OK;
}

/* ---------------------------------------------------------------------------------------- */
/* Kernels                                                                                  */
/* ---------------------------------------------------------------------------------------- */

/* Sum of g * v over the six neighbours of padded cell i. */
#define NEIGHBOURS(g, v, i, sy, sz)                                                                        \
    ((g)[0][i] * (v)[(i) + 1] + (g)[0][(i) - 1] * (v)[(i) - 1] + (g)[1][i] * (v)[(i) + (sy)] +           \
     (g)[1][(i) - (sy)] * (v)[(i) - (sy)] + (g)[2][i] * (v)[(i) + (sz)] + (g)[2][(i) - (sz)] * (v)[(i) - (sz)])

/* out = b - M v, or M v when b is NULL. Cells outside the domain have zero conductances, unit
 * diagonal and zero b and v, so they come out 0 without a test. */
static void apply(const level *l, int c, const float *v, const float *b, float *out, int threads)
{
    const uint32_t nx = l->n[0], ny = l->n[1], nz = l->n[2];
    const size_t sy = l->sy, sz = l->sz;
    const float *g[3] = {l->g[c][0], l->g[c][1], l->g[c][2]};
    const float *diag = l->diag[c];
#pragma omp parallel for num_threads(threads) schedule(static) if (l->cells > 32768)
    for (uint32_t z = 1; z <= nz; z++)
        for (uint32_t y = 1; y <= ny; y++) {
            size_t row = sy * y + sz * z;
            if (b) {
                for (size_t i = row + 1; i <= row + nx; i++)
                    out[i] = b[i] - (diag[i] * v[i] - NEIGHBOURS(g, v, i, sy, sz));
            } else {
                for (size_t i = row + 1; i <= row + nx; i++)
                    out[i] = diag[i] * v[i] - NEIGHBOURS(g, v, i, sy, sz);
            }
        }
}

/* out = b - M v with the products summed in double: near convergence b and M v agree to many
 * digits (high albedo makes the diagonal almost equal the neighbour sum), so a float sum would
 * put a floor of ~1e-5 under the relative residual. */
static void residual_exact(const level *l, int c, const float *v, const float *b, float *out, int threads)
{
    const uint32_t nx = l->n[0], ny = l->n[1], nz = l->n[2];
    const size_t sy = l->sy, sz = l->sz;
    const float *g[3] = {l->g[c][0], l->g[c][1], l->g[c][2]};
    const float *diag = l->diag[c];
#pragma omp parallel for num_threads(threads) schedule(static) if (l->cells > 32768)
    for (uint32_t z = 1; z <= nz; z++)
        for (uint32_t y = 1; y <= ny; y++) {
            size_t row = sy * y + sz * z;
            for (size_t i = row + 1; i <= row + nx; i++) {
                double acc = (double)b[i] - (double)diag[i] * v[i];
                acc += (double)g[0][i] * v[i + 1] + (double)g[0][i - 1] * v[i - 1];
                acc += (double)g[1][i] * v[i + sy] + (double)g[1][i - sy] * v[i - sy];
                acc += (double)g[2][i] * v[i + sz] + (double)g[2][i - sz] * v[i - sz];
                out[i] = (float)acc;
            }
        }
}

/* One red-black Gauss-Seidel half sweep over the cells with (x + y + z) % 2 == color. */
static void gs_color(const level *l, int c, float *v, const float *b, int color, int threads)
{
    const uint32_t nx = l->n[0], ny = l->n[1], nz = l->n[2];
    const size_t sy = l->sy, sz = l->sz;
    const float *g[3] = {l->g[c][0], l->g[c][1], l->g[c][2]};
    const float *inv = l->inv_diag[c];
#pragma omp parallel for num_threads(threads) schedule(static) if (l->cells > 32768)
    for (uint32_t z = 1; z <= nz; z++)
        for (uint32_t y = 1; y <= ny; y++) {
            size_t row = sy * y + sz * z;
            for (size_t i = row + 1 + ((color + y + z + 1) & 1); i <= row + nx; i += 2)
                v[i] = inv[i] * (b[i] + NEIGHBOURS(g, v, i, sy, sz));
        }
}

/* Coarse b = sum of the fine values of its children. */
static void restrict_sum(const level *f, const level *l, const float *fine, float *coarse)
{
    memset(coarse, 0, l->cells * sizeof(float));
    for (uint32_t z = 0; z < f->n[2]; z++)
        for (uint32_t y = 0; y < f->n[1]; y++) {
            size_t row = pidx(f, 0, y, z), crow = pidx(l, 0, y / l->r[1], z / l->r[2]);
            if (l->r[0] == 2) {
                for (uint32_t x = 0; x < f->n[0]; x++)
                    coarse[crow + (x >> 1)] += fine[row + x];
            } else {
                for (uint32_t x = 0; x < f->n[0]; x++)
                    coarse[crow + x] += fine[row + x];
            }
        }
}

/* fine += the coarse value of the parent (piecewise constant), inside the domain only. */
static void prolong_add(const level *f, const level *l, const float *coarse, float *fine)
{
    for (uint32_t z = 0; z < f->n[2]; z++)
        for (uint32_t y = 0; y < f->n[1]; y++) {
            size_t row = pidx(f, 0, y, z), crow = pidx(l, 0, y / l->r[1], z / l->r[2]);
            const uint32_t sh = l->r[0] == 2 ? 1 : 0;
            for (uint32_t x = 0; x < f->n[0]; x++)
                fine[row + x] += f->solid[row + x] ? coarse[crow + (x >> sh)] : 0.0f;
        }
}

/* Symmetric V-cycle: x = V(b) with x starting at zero (a fixed linear operator of b). */
static void vcycle(nc_diff_solver *s, uint32_t li, int c, const float *b, float *x, int threads)
{
    level *l = &s->lv[li];
    memset(x, 0, l->cells * sizeof(float));
    if (li + 1 == s->level_count) {
        /* Coarsest (at most 2 cells per axis, or what could not be coarsened): enough symmetric
         * sweeps to solve it, the count fixed so the cycle stays linear. */
        uint32_t sweeps = 4 + 2 * (l->n[0] + l->n[1] + l->n[2]);
        for (uint32_t k = 0; k < sweeps; k++) {
            gs_color(l, c, x, b, 0, threads);
            gs_color(l, c, x, b, 1, threads);
            gs_color(l, c, x, b, 1, threads);
            gs_color(l, c, x, b, 0, threads);
        }
        return;
    }
    level *lc = &s->lv[li + 1];
    gs_color(l, c, x, b, 0, threads);
    gs_color(l, c, x, b, 1, threads);
    apply(l, c, x, b, l->res, threads);
    restrict_sum(l, lc, l->res, lc->b);
    vcycle(s, li + 1, c, lc->b, lc->x, threads);
    prolong_add(l, lc, lc->x, x);
    gs_color(l, c, x, b, 1, threads);
    gs_color(l, c, x, b, 0, threads);
}

static double dot(const float *a, const float *b, size_t n, int threads)
{
    double sum = 0.0;
#pragma omp parallel for num_threads(threads) reduction(+ : sum) schedule(static) if (n > 65536)
    for (size_t i = 0; i < n; i++)
        sum += (double)a[i] * b[i];
    return sum;
}

static void energy(const nc_diff_solver *s, int c, const float *b, const float *x, nc_diff_solve_report *rep)
{
    const level *l = &s->lv[0];
    double inj = 0, abs_ = 0, esc = 0;
    for (size_t i = 0; i < l->cells; i++) {
        inj += b[i];
        abs_ += (double)s->absorb[c][i] * x[i];
        esc += (double)s->bnd[c][i] * x[i];
    }
    rep->injected = inj;
    rep->absorbed = abs_;
    rep->escaped = esc;
}

static void solve_pcg(nc_diff_solver *s, int c, const float *b, float *x, const nc_diff_solve_opts *o,
                      nc_diff_solve_report *rep)
{
    level *l = &s->lv[0];
    const size_t n = l->cells;
    const int threads = s->ctx->threads;
    float *r = s->pr, *z = s->pz, *p = s->pp, *q = s->pq;
    double bnorm = sqrt(dot(b, b, n, threads));
    if (bnorm == 0.0) {
        memset(x, 0, n * sizeof(float));
        rep->iterations = 0;
        rep->residual = 0.0;
        return;
    }
    double tol = o->tolerance > 0 ? o->tolerance : 1e-4;
    uint32_t max_it = o->max_iterations ? o->max_iterations : 200;
    uint32_t it = 0;
    /* Restarted from the exact residual whenever the recursively updated one (float) claims
     * a convergence that the exact one does not confirm. */
    for (int restart = 0; restart < 8 && it < max_it; restart++) {
        residual_exact(l, c, x, b, r, threads);
        double rnorm = sqrt(dot(r, r, n, threads));
        if (rnorm <= tol * bnorm)
            break;
        vcycle(s, 0, c, r, z, threads);
        memcpy(p, z, n * sizeof(float));
        double rz = dot(r, z, n, threads);
        while (it < max_it) {
            apply(l, c, p, NULL, q, threads);
            double pq = dot(p, q, n, threads);
            if (!(pq > 0))
                break;
            float af = (float)(rz / pq);
#pragma omp parallel for num_threads(threads) schedule(static) if (n > 65536)
            for (size_t i = 0; i < n; i++) {
                x[i] += af * p[i];
                r[i] -= af * q[i];
            }
            it++;
            rnorm = sqrt(dot(r, r, n, threads));
            if (rnorm <= tol * bnorm)
                break;
            vcycle(s, 0, c, r, z, threads);
            double rz_new = dot(r, z, n, threads);
            float beta = (float)(rz_new / rz);
            rz = rz_new;
#pragma omp parallel for num_threads(threads) schedule(static) if (n > 65536)
            for (size_t i = 0; i < n; i++)
                p[i] = z[i] + beta * p[i];
        }
    }
    /* Report the true residual, not the recursively updated one. */
    residual_exact(l, c, x, b, r, threads);
    rep->iterations = it;
    rep->residual = sqrt(dot(r, r, n, threads)) / bnorm;
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

/* The seed's scheme: x starts from the coarser level's result, then plain Jacobi sweeps. */
static void solve_seed(nc_diff_solver *s, int c, const float *b, float *x, const nc_diff_solve_opts *o,
                       nc_diff_solve_report *rep)
{
    const int threads = s->ctx->threads;
    uint32_t top = 0; /* the coarsest level with a side of at least 4 cells (the seed's smallest) */
    for (uint32_t li = 1; li < s->level_count && !o->seed_single_grid; li++) {
        if (max_dim(&s->lv[li]) < 4)
            break;
        top = li;
    }
    for (uint32_t li = 1; li <= top; li++)
        restrict_sum(&s->lv[li - 1], &s->lv[li], li == 1 ? b : s->lv[li - 1].b, s->lv[li].b);
    uint32_t total = 0;
    for (int li = (int)top; li >= 0; li--) {
        level *l = &s->lv[li];
        float *xl = li == 0 ? x : l->x;
        const float *bl = li == 0 ? b : l->b;
        if (li < (int)top) {
            memset(xl, 0, l->cells * sizeof(float));
            prolong_add(l, &s->lv[li + 1], s->lv[li + 1].x, xl);
        } else if (!(li == 0 && o->warm_start)) {
            memset(xl, 0, l->cells * sizeof(float));
        }
        uint32_t sweeps = (li == 0 && o->seed_iterations) ? o->seed_iterations : seed_sweeps(max_dim(l));
        for (uint32_t k = 0; k < sweeps; k++) {
            apply(l, c, xl, bl, l->res, threads);
            for (size_t i = 0; i < l->cells; i++)
                xl[i] += l->inv_diag[c][i] * l->res[i];
        }
        total += sweeps;
    }
    level *l0 = &s->lv[0];
    residual_exact(l0, c, x, b, l0->res, threads);
    double bn = sqrt(dot(b, b, l0->cells, threads));
    rep->iterations = total;
    rep->residual = bn > 0 ? sqrt(dot(l0->res, l0->res, l0->cells, threads)) / bn : 0.0;
}

nacre_result nc_diff_solve(nc_diff_solver *s, int channel, const float *source, float *phi,
                           const nc_diff_solve_opts *opts, nc_diff_solve_report *report)
{
    if (!s || channel < 0 || channel > 2 || !source || !phi || !opts || s->level_count == 0)
        return NACRE_ERROR_INVALID_ARGUMENT;
    level *l = &s->lv[0];
    const uint32_t nx = s->dims[0], ny = s->dims[1], nz = s->dims[2];
    /* Into the padded layout; outside cells take no source. */
    float *b = l->b, *x = s->px;
    memset(b, 0, l->cells * sizeof(float));
    memset(x, 0, l->cells * sizeof(float));
    bool clean = true;
    for (uint32_t z = 0; z < nz; z++)
        for (uint32_t y = 0; y < ny; y++) {
            size_t u = (size_t)nx * (y + (size_t)ny * z), i = pidx(l, 0, y, z);
            for (uint32_t xx = 0; xx < nx; xx++) {
                if (!l->solid[i + xx])
                    continue;
                float v = source[u + xx];
                clean &= isfinite(v) != 0;
                b[i + xx] = v;
                if (opts->warm_start)
                    x[i + xx] = isfinite(phi[u + xx]) ? phi[u + xx] : 0.0f;
            }
        }
    if (!clean)
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "diffusion: non-finite source");
    nc_diff_solve_report rep;
    memset(&rep, 0, sizeof(rep));
    if (opts->solver == NACRE_SOLVER_SEED)
        solve_seed(s, channel, b, x, opts, &rep);
    else
        solve_pcg(s, channel, b, x, opts, &rep);
    energy(s, channel, b, x, &rep);
    for (uint32_t z = 0; z < nz; z++)
        for (uint32_t y = 0; y < ny; y++)
            memcpy(phi + (size_t)nx * (y + (size_t)ny * z), x + pidx(l, 0, y, z), nx * sizeof(float));
    if (report)
        *report = rep;
    return NACRE_OK;
}
