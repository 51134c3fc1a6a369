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

typedef struct level {
    uint32_t n[3];
    uint32_t r[3];    /* coarsening factor from the previous (finer) level per axis: 1 or 2 */
    size_t cells;
    uint8_t *solid;
    /* per channel: conductance to the +x, +y, +z neighbour (0 when either cell is outside or
     * at a non-periodic edge), diagonal and its inverse (1 outside the domain) */
    float *g[3][3];
    float *diag[3], *inv_diag[3];
    float *x, *b, *res; /* V-cycle work */
} level;

struct nc_diff_solver {
    nacre_context *ctx;
    bool periodic[3];
    float h;
    uint32_t level_count;
    level lv[MAX_LEVELS];
    size_t capacity[MAX_LEVELS]; /* cells allocated per level */
    /* level 0 extras */
    float *d[3];      /* D per cell */
    float *bnd[3];    /* boundary conductance sum per cell (escape) */
    float *absorb[3]; /* sigma_a h^3 per cell */
    float *pr, *pz, *pp, *pq; /* PCG vectors */
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

void nc_diff_solver_destroy(nc_diff_solver *s)
{
    if (!s)
        return;
    nacre_context *ctx = s->ctx;
    for (int i = 0; i < MAX_LEVELS; i++)
        level_free(ctx, &s->lv[i]);
    for (int c = 0; c < 3; c++) {
        nc_free(ctx, s->d[c]);
        nc_free(ctx, s->bnd[c]);
        nc_free(ctx, s->absorb[c]);
    }
    nc_free(ctx, s->pr);
    nc_free(ctx, s->pz);
    nc_free(ctx, s->pp);
    nc_free(ctx, s->pq);
    nc_free(ctx, s);
}

const float *nc_diff_coefficient_d(const nc_diff_solver *s, int channel)
{
    return (s && channel >= 0 && channel < 3) ? s->d[channel] : NULL;
}

/* (Re)allocate a level's arrays for `cells` cells; level 0 also gets the extras. */
static nacre_result level_alloc(nc_diff_solver *s, int li, size_t cells)
{
    nacre_context *ctx = s->ctx;
    level *l = &s->lv[li];
    if (s->capacity[li] >= cells && l->solid)
        return NACRE_OK;
    uint32_t n[3] = {l->n[0], l->n[1], l->n[2]}, r[3] = {l->r[0], l->r[1], l->r[2]};
    size_t keep_cells = l->cells;
    level_free(ctx, l);
    memcpy(l->n, n, sizeof(n));
    memcpy(l->r, r, sizeof(r));
    l->cells = keep_cells;
    s->capacity[li] = 0;
    size_t fb = cells * sizeof(float);
    bool ok = (l->solid = nc_alloc(ctx, cells)) != NULL;
    for (int c = 0; c < 3 && ok; c++) {
        for (int a = 0; a < 3 && ok; a++)
            ok = (l->g[c][a] = nc_alloc(ctx, fb)) != NULL;
        ok = ok && (l->diag[c] = nc_alloc(ctx, fb)) != NULL && (l->inv_diag[c] = nc_alloc(ctx, fb)) != NULL;
    }
    ok = ok && (l->x = nc_alloc(ctx, fb)) && (l->b = nc_alloc(ctx, fb)) && (l->res = nc_alloc(ctx, fb));
    if (ok && li == 0) {
        for (int c = 0; c < 3; c++) {
            nc_free(ctx, s->d[c]);
            nc_free(ctx, s->bnd[c]);
            nc_free(ctx, s->absorb[c]);
            s->d[c] = nc_alloc(ctx, fb);
            s->bnd[c] = nc_alloc(ctx, fb);
            s->absorb[c] = nc_alloc(ctx, fb);
            ok = ok && s->d[c] && s->bnd[c] && s->absorb[c];
        }
        nc_free(ctx, s->pr);
        nc_free(ctx, s->pz);
        nc_free(ctx, s->pp);
        nc_free(ctx, s->pq);
        s->pr = nc_alloc(ctx, fb);
        s->pz = nc_alloc(ctx, fb);
        s->pp = nc_alloc(ctx, fb);
        s->pq = nc_alloc(ctx, fb);
        ok = ok && s->pr && s->pz && s->pp && s->pq;
    }
    if (!ok) {
        level_free(ctx, l);
        return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory for a %ux%ux%u grid", n[0], n[1], n[2]);
    }
    s->capacity[li] = cells;
    return NACRE_OK;
}

static inline size_t idx(const level *l, uint32_t x, uint32_t y, uint32_t z)
{
    return (size_t)x + (size_t)l->n[0] * ((size_t)y + (size_t)l->n[1] * z);
}

/* Neighbour of cell (x, y, z) one step towards +axis; SIZE_MAX at a non-periodic edge. */
static inline size_t step_plus(const level *l, const bool *periodic, uint32_t x, uint32_t y, uint32_t z, int axis)
{
    uint32_t p[3] = {x, y, z};
    if (p[axis] + 1 < l->n[axis])
        p[axis]++;
    else if (periodic[axis] && l->n[axis] > 1)
        p[axis] = 0;
    else
        return SIZE_MAX;
    return idx(l, p[0], p[1], p[2]);
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

/* Add the conductances of every level to its diagonal (diag holds the non-conductance part on
 * entry: boundary + absorption). */
static void add_conductances(nc_diff_solver *s, level *l, int c)
{
    for (uint32_t z = 0; z < l->n[2]; z++)
        for (uint32_t y = 0; y < l->n[1]; y++)
            for (uint32_t x = 0; x < l->n[0]; x++) {
                size_t i = idx(l, x, y, z);
                for (int a = 0; a < 3; a++) {
                    float g = l->g[c][a][i];
                    if (g == 0.0f)
                        continue;
                    size_t j = step_plus(l, s->periodic, x, y, z, a);
                    if (j == i) /* a periodic axis of one cell: the face joins the cell to itself */
                        continue;
                    l->diag[c][i] += g;
                    l->diag[c][j] += g;
                }
            }
}

static nacre_result build_fine(nc_diff_solver *s, const nc_diff_medium *m)
{
    level *l = &s->lv[0];
    const float h = m->h;
    const float A = (float)nc_diff_robin_a(m->eta);
    for (size_t i = 0; i < l->cells; i++)
        l->solid[i] = m->solid[i] != 0;
    for (int c = 0; c < 3; c++) {
        float *d = s->d[c];
        for (size_t i = 0; i < l->cells; i++) {
            if (!l->solid[i]) {
                d[i] = 0.0f;
                s->absorb[c][i] = 0.0f;
                continue;
            }
            float sa = m->sigma_a[c] ? m->sigma_a[c][i] : m->sigma_a_const[c];
            float sp = m->sigma_sp[c] ? m->sigma_sp[c][i] : m->sigma_sp_const[c];
            float st = sa + sp;
            d[i] = st > 0 ? 1.0f / (3.0f * st) : 0.0f;
            s->absorb[c][i] = sa * h * h * h;
        }
        for (uint32_t z = 0; z < l->n[2]; z++)
            for (uint32_t y = 0; y < l->n[1]; y++)
                for (uint32_t x = 0; x < l->n[0]; x++) {
                    size_t i = idx(l, x, y, z);
                    float bsum = 0.0f;
                    for (int a = 0; a < 3; a++) {
                        size_t j = step_plus(l, s->periodic, x, y, z, a);
                        bool in_i = l->solid[i], in_j = j != SIZE_MAX && l->solid[j];
                        float g = 0.0f;
                        if (in_i && in_j && d[i] > 0 && d[j] > 0)
                            g = h * 2.0f * d[i] * d[j] / (d[i] + d[j]);
                        l->g[c][a][i] = g;
                    }
                    if (!l->solid[i]) {
                        s->bnd[c][i] = 0.0f;
                        continue;
                    }
                    /* Robin condition on each face whose neighbour is outside the domain. */
                    float bface = h * h * 2.0f * d[i] / (h + 4.0f * A * d[i]);
                    uint32_t p[3] = {x, y, z};
                    for (int a = 0; a < 3; a++)
                        for (int dir = -1; dir <= 1; dir += 2) {
                            int64_t q = (int64_t)p[a] + dir;
                            bool outside;
                            if (q < 0 || q >= (int64_t)l->n[a]) {
                                outside = !s->periodic[a];
                                q = (q + l->n[a]) % l->n[a];
                            } else {
                                outside = false;
                            }
                            if (!outside) {
                                uint32_t pn[3] = {p[0], p[1], p[2]};
                                pn[a] = (uint32_t)q;
                                outside = !l->solid[idx(l, pn[0], pn[1], pn[2])];
                            }
                            if (outside)
                                bsum += bface;
                        }
                    s->bnd[c][i] = bsum;
                }
        for (size_t i = 0; i < l->cells; i++)
            l->diag[c][i] = l->solid[i] ? s->bnd[c][i] + s->absorb[c][i] : 0.0f;
        add_conductances(s, l, c);
        finish_diag(l, c);
    }
    return NACRE_OK;
}

/* Coarse level li from li - 1: Galerkin sums with conductances scaled by 1 / r per axis. */
static void build_coarse(nc_diff_solver *s, int li)
{
    level *f = &s->lv[li - 1], *l = &s->lv[li];
    memset(l->solid, 0, l->cells);
    for (int c = 0; c < 3; c++) {
        memset(l->diag[c], 0, l->cells * sizeof(float));
        for (int a = 0; a < 3; a++)
            memset(l->g[c][a], 0, l->cells * sizeof(float));
    }
    for (uint32_t z = 0; z < f->n[2]; z++)
        for (uint32_t y = 0; y < f->n[1]; y++)
            for (uint32_t x = 0; x < f->n[0]; x++) {
                size_t i = idx(f, x, y, z);
                if (!f->solid[i])
                    continue;
                uint32_t cp[3] = {x / l->r[0], y / l->r[1], z / l->r[2]};
                size_t I = idx(l, cp[0], cp[1], cp[2]);
                l->solid[I] = 1;
                for (int c = 0; c < 3; c++) {
                    /* diag of a fine cell minus its conductances = its boundary + absorption */
                    float nonc = f->diag[c][i];
                    uint32_t p[3] = {x, y, z};
                    for (int a = 0; a < 3; a++) {
                        float g = f->g[c][a][i];
                        size_t j = step_plus(f, s->periodic, x, y, z, a);
                        if (g != 0.0f && j != i)
                            nonc -= g;
                        /* the -axis neighbour's conductance to us */
                        uint32_t pm[3] = {p[0], p[1], p[2]};
                        if (p[a] > 0)
                            pm[a]--;
                        else if (s->periodic[a] && f->n[a] > 1)
                            pm[a] = f->n[a] - 1;
                        else
                            continue;
                        size_t k = idx(f, pm[0], pm[1], pm[2]);
                        if (k != i && f->g[c][a][k] != 0.0f)
                            nonc -= f->g[c][a][k];
                        (void)j;
                    }
                    l->diag[c][I] += nonc > 0 ? nonc : 0.0f;
                    for (int a = 0; a < 3; a++) {
                        float g = f->g[c][a][i];
                        if (g == 0.0f)
                            continue;
                        size_t j = step_plus(f, s->periodic, x, y, z, a);
                        uint32_t pj[3] = {x, y, z};
                        pj[a] = (p[a] + 1 < f->n[a]) ? p[a] + 1 : 0;
                        uint32_t cj = pj[a] / l->r[a];
                        (void)j;
                        if (cj == cp[a])
                            continue; /* inside the aggregate: cancels in the Galerkin sum */
                        l->g[c][a][I] += g / (float)l->r[a];
                    }
                }
            }
    for (int c = 0; c < 3; c++) {
        add_conductances(s, l, c);
        finish_diag(l, c);
    }
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
    size_t cells;
    if (!nc_mul_size_ok(m->dims[0], m->dims[1], &cells) || !nc_mul_size_ok(cells, m->dims[2], &cells))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "diffusion: grid too large");
    memcpy(s->periodic, m->periodic, sizeof(s->periodic));
    s->h = m->h;
    /* Level sizes: coarsen each axis longer than 2 cells, down to at most 2 per axis. */
    uint32_t n[3] = {m->dims[0], m->dims[1], m->dims[2]};
    uint32_t count = 0;
    for (;;) {
        level *l = &s->lv[count];
        memcpy(l->n, n, sizeof(n));
        l->cells = (size_t)n[0] * n[1] * n[2];
        nacre_result res = level_alloc(s, (int)count, l->cells);
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

/* Sum of g * x over the six neighbours of cell (x, y, z). */
static inline float neighbour_sum(const level *l, const bool *periodic, float *const g[3], const float *v,
                                  uint32_t x, uint32_t y, uint32_t z, size_t i)
{
    const uint32_t nx = l->n[0], ny = l->n[1], nz = l->n[2];
    const size_t sy = nx, sz = (size_t)nx * ny;
    float acc = 0.0f;
    /* +x / -x */
    if (x + 1 < nx)
        acc += g[0][i] * v[i + 1];
    else if (periodic[0] && nx > 1)
        acc += g[0][i] * v[i + 1 - nx];
    if (x > 0)
        acc += g[0][i - 1] * v[i - 1];
    else if (periodic[0] && nx > 1)
        acc += g[0][i + nx - 1] * v[i + nx - 1];
    if (y + 1 < ny)
        acc += g[1][i] * v[i + sy];
    else if (periodic[1] && ny > 1)
        acc += g[1][i] * v[i - (size_t)(ny - 1) * sy];
    if (y > 0)
        acc += g[1][i - sy] * v[i - sy];
    else if (periodic[1] && ny > 1)
        acc += g[1][i + (size_t)(ny - 1) * sy] * v[i + (size_t)(ny - 1) * sy];
    if (z + 1 < nz)
        acc += g[2][i] * v[i + sz];
    else if (periodic[2] && nz > 1)
        acc += g[2][i] * v[i - (size_t)(nz - 1) * sz];
    if (z > 0)
        acc += g[2][i - sz] * v[i - sz];
    else if (periodic[2] && nz > 1)
        acc += g[2][i + (size_t)(nz - 1) * sz] * v[i + (size_t)(nz - 1) * sz];
    return acc;
}

/* out = b - M v (or M v when b is NULL); outside cells get 0. */
static void apply(const nc_diff_solver *s, const level *l, int c, const float *v, const float *b, float *out, int threads)
{
    const uint32_t nx = l->n[0], ny = l->n[1], nz = l->n[2];
    float *const *g = l->g[c];
    const float *diag = l->diag[c];
    const uint8_t *solid = l->solid;
#pragma omp parallel for num_threads(threads) schedule(static) if (l->cells > 32768)
    for (uint32_t z = 0; z < nz; z++)
        for (uint32_t y = 0; y < ny; y++) {
            size_t row = (size_t)nx * ((size_t)y + (size_t)ny * z);
            for (uint32_t x = 0; x < nx; x++) {
                size_t i = row + x;
                if (!solid[i]) {
                    out[i] = 0.0f;
                    continue;
                }
                float mv = diag[i] * v[i] - neighbour_sum(l, s->periodic, (float *const *)g, v, x, y, z, i);
                out[i] = b ? b[i] - mv : mv;
            }
        }
}

/* One red-black Gauss-Seidel half sweep over cells of parity `color`. */
/* out = b - M v with the products summed in double: near convergence b and M v agree to many
 * digits (high albedo makes the diagonal almost equal the neighbour sum), so a float sum would
 * put a floor of ~1e-5 under the relative residual. */
static void residual_exact(const nc_diff_solver *s, const level *l, int c, const float *v, const float *b, float *out,
                           int threads)
{
    const uint32_t nx = l->n[0], ny = l->n[1], nz = l->n[2];
    const bool *per = s->periodic;
    float *const *g = l->g[c];
    const float *diag = l->diag[c];
    const size_t sy = nx, sz = (size_t)nx * ny;
#pragma omp parallel for num_threads(threads) schedule(static) if (l->cells > 32768)
    for (uint32_t z = 0; z < nz; z++)
        for (uint32_t y = 0; y < ny; y++) {
            size_t row = (size_t)nx * ((size_t)y + (size_t)ny * z);
            for (uint32_t x = 0; x < nx; x++) {
                size_t i = row + x;
                if (!l->solid[i]) {
                    out[i] = 0.0f;
                    continue;
                }
                double acc = (double)b[i] - (double)diag[i] * v[i];
                size_t j;
                if (x + 1 < nx || (per[0] && nx > 1)) {
                    j = x + 1 < nx ? i + 1 : i + 1 - nx;
                    acc += (double)g[0][i] * v[j];
                }
                if (x > 0 || (per[0] && nx > 1)) {
                    j = x > 0 ? i - 1 : i + nx - 1;
                    acc += (double)g[0][j] * v[j];
                }
                if (y + 1 < ny || (per[1] && ny > 1)) {
                    j = y + 1 < ny ? i + sy : i - (size_t)(ny - 1) * sy;
                    acc += (double)g[1][i] * v[j];
                }
                if (y > 0 || (per[1] && ny > 1)) {
                    j = y > 0 ? i - sy : i + (size_t)(ny - 1) * sy;
                    acc += (double)g[1][j] * v[j];
                }
                if (z + 1 < nz || (per[2] && nz > 1)) {
                    j = z + 1 < nz ? i + sz : i - (size_t)(nz - 1) * sz;
                    acc += (double)g[2][i] * v[j];
                }
                if (z > 0 || (per[2] && nz > 1)) {
                    j = z > 0 ? i - sz : i + (size_t)(nz - 1) * sz;
                    acc += (double)g[2][j] * v[j];
                }
                out[i] = (float)acc;
            }
        }
}

static void gs_color(const nc_diff_solver *s, const level *l, int c, float *v, const float *b, int color, int threads)
{
    const uint32_t nx = l->n[0], ny = l->n[1], nz = l->n[2];
    float *const *g = l->g[c];
    const float *inv = l->inv_diag[c];
    const uint8_t *solid = l->solid;
#pragma omp parallel for num_threads(threads) schedule(static) if (l->cells > 32768)
    for (uint32_t z = 0; z < nz; z++)
        for (uint32_t y = 0; y < ny; y++) {
            size_t row = (size_t)nx * ((size_t)y + (size_t)ny * z);
            for (uint32_t x = (uint32_t)((color + y + z) & 1); x < nx; x += 2) {
                size_t i = row + x;
                if (!solid[i])
                    continue;
                v[i] = inv[i] * (b[i] + neighbour_sum(l, s->periodic, (float *const *)g, v, x, y, z, i));
            }
        }
}

/* Coarse b = sum of the fine residuals of its children. */
static void restrict_sum(const level *f, const level *l, const float *fine, float *coarse)
{
    memset(coarse, 0, l->cells * sizeof(float));
    for (uint32_t z = 0; z < f->n[2]; z++)
        for (uint32_t y = 0; y < f->n[1]; y++) {
            size_t row = (size_t)f->n[0] * ((size_t)y + (size_t)f->n[1] * z);
            size_t crow = idx(l, 0, y / l->r[1], z / l->r[2]);
            for (uint32_t x = 0; x < f->n[0]; x++)
                coarse[crow + x / l->r[0]] += fine[row + x];
        }
}

/* fine += coarse value of the parent (piecewise constant), solid cells only. */
static void prolong_add(const level *f, const level *l, const float *coarse, float *fine)
{
    for (uint32_t z = 0; z < f->n[2]; z++)
        for (uint32_t y = 0; y < f->n[1]; y++) {
            size_t row = (size_t)f->n[0] * ((size_t)y + (size_t)f->n[1] * z);
            size_t crow = idx(l, 0, y / l->r[1], z / l->r[2]);
            for (uint32_t x = 0; x < f->n[0]; x++)
                if (f->solid[row + x])
                    fine[row + x] += coarse[crow + x / l->r[0]];
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
            gs_color(s, l, c, x, b, 0, threads);
            gs_color(s, l, c, x, b, 1, threads);
            gs_color(s, l, c, x, b, 1, threads);
            gs_color(s, l, c, x, b, 0, threads);
        }
        return;
    }
    level *lc = &s->lv[li + 1];
    gs_color(s, l, c, x, b, 0, threads);
    gs_color(s, l, c, x, b, 1, threads);
    apply(s, l, c, x, b, l->res, threads);
    restrict_sum(l, lc, l->res, lc->b);
    vcycle(s, li + 1, c, lc->b, lc->x, threads);
    prolong_add(l, lc, lc->x, x);
    gs_color(s, l, c, x, b, 1, threads);
    gs_color(s, l, c, x, b, 0, threads);
}

static double dot(const float *a, const float *b, size_t n, int threads)
{
    double sum = 0.0;
#pragma omp parallel for num_threads(threads) reduction(+ : sum) schedule(static) if (n > 65536)
    for (size_t i = 0; i < n; i++)
        sum += (double)a[i] * b[i];
    return sum;
}

static void energy(const nc_diff_solver *s, int c, const float *source, const float *phi, nc_diff_solve_report *rep)
{
    const level *l = &s->lv[0];
    double inj = 0, abs_ = 0, esc = 0;
    for (size_t i = 0; i < l->cells; i++) {
        if (!l->solid[i])
            continue;
        inj += source[i];
        abs_ += (double)s->absorb[c][i] * phi[i];
        esc += (double)s->bnd[c][i] * phi[i];
    }
    rep->injected = inj;
    rep->absorbed = abs_;
    rep->escaped = esc;
}

static nacre_result solve_pcg(nc_diff_solver *s, int c, const float *b, float *x, const nc_diff_solve_opts *o,
                              nc_diff_solve_report *rep)
{
    level *l = &s->lv[0];
    const size_t n = l->cells;
    const int threads = s->ctx->threads;
    float *r = s->pr, *z = s->pz, *p = s->pp, *q = s->pq;
    double bnorm = sqrt(dot(b, b, n, threads));
    if (!o->warm_start)
        memset(x, 0, n * sizeof(float));
    if (bnorm == 0.0) {
        memset(x, 0, n * sizeof(float));
        rep->iterations = 0;
        rep->residual = 0.0;
        return NACRE_OK;
    }
    double tol = o->tolerance > 0 ? o->tolerance : 1e-4;
    uint32_t max_it = o->max_iterations ? o->max_iterations : 200;
    uint32_t it = 0;
    /* Restarted from the exact residual whenever the recursively updated one (float) claims
     * convergence that the exact one does not confirm. */
    for (int restart = 0; restart < 8 && it < max_it; restart++) {
        residual_exact(s, l, c, x, b, r, threads);
        double rnorm = sqrt(dot(r, r, n, threads));
        if (rnorm <= tol * bnorm)
            break;
        vcycle(s, 0, c, r, z, threads);
        memcpy(p, z, n * sizeof(float));
        double rz = dot(r, z, n, threads);
        while (it < max_it) {
            apply(s, l, c, p, NULL, q, threads);
            double pq = dot(p, q, n, threads);
            if (!(pq > 0))
                break;
            double alpha = rz / pq;
            float af = (float)alpha;
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
    /* Report the true residual, not the recursively updated one (float drift). */
    residual_exact(s, l, c, x, b, r, threads);
    rep->iterations = it;
    rep->residual = sqrt(dot(r, r, n, threads)) / bnorm;
    return NACRE_OK;
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

static void jacobi_sweeps(nc_diff_solver *s, const level *l, int c, float *x, const float *b, float *tmp, uint32_t sweeps,
                          int threads)
{
    for (uint32_t k = 0; k < sweeps; k++) {
        /* tmp = x + D^-1 (b - M x) */
        apply(s, l, c, x, b, tmp, threads);
        for (size_t i = 0; i < l->cells; i++)
            tmp[i] = l->solid[i] ? x[i] + l->inv_diag[c][i] * tmp[i] : 0.0f;
        memcpy(x, tmp, l->cells * sizeof(float));
    }
}

static nacre_result solve_seed(nc_diff_solver *s, int c, const float *b, float *x, const nc_diff_solve_opts *o,
                               nc_diff_solve_report *rep)
{
    const int threads = s->ctx->threads;
    /* Levels from the coarsest with a side of at least 4 cells (the seed's smallest grid). */
    uint32_t top = 0;
    for (uint32_t li = 1; li < s->level_count; li++) {
        const level *l = &s->lv[li];
        uint32_t m = l->n[0] > l->n[1] ? l->n[0] : l->n[1];
        m = m > l->n[2] ? m : l->n[2];
        if (m < 4)
            break;
        top = li;
    }
    memcpy(s->lv[0].b, b, s->lv[0].cells * sizeof(float));
    for (uint32_t li = 1; li <= top; li++)
        restrict_sum(&s->lv[li - 1], &s->lv[li], s->lv[li - 1].b, s->lv[li].b);
    uint32_t total = 0;
    float *cur = NULL;
    for (int li = (int)top; li >= 0; li--) {
        level *l = &s->lv[li];
        float *xl = li == 0 ? x : l->x;
        if (cur) {
            memset(xl, 0, l->cells * sizeof(float));
            prolong_add(l, &s->lv[li + 1], cur, xl);
        } else if (!(li == 0 && o->warm_start)) {
            memset(xl, 0, l->cells * sizeof(float));
        }
        uint32_t m = l->n[0] > l->n[1] ? l->n[0] : l->n[1];
        m = m > l->n[2] ? m : l->n[2];
        uint32_t sweeps = (li == 0 && o->seed_iterations) ? o->seed_iterations : seed_sweeps(m);
        jacobi_sweeps(s, l, c, xl, l->b, l->res, sweeps, threads);
        total += sweeps;
        cur = xl;
    }
    level *l0 = &s->lv[0];
    residual_exact(s, l0, c, x, b, l0->res, threads);
    double bn = sqrt(dot(b, b, l0->cells, threads));
    rep->iterations = total;
    rep->residual = bn > 0 ? sqrt(dot(l0->res, l0->res, l0->cells, threads)) / bn : 0.0;
    return NACRE_OK;
}

nacre_result nc_diff_solve(nc_diff_solver *s, int channel, const float *source, float *phi,
                           const nc_diff_solve_opts *opts, nc_diff_solve_report *report)
{
    if (!s || channel < 0 || channel > 2 || !source || !phi || !opts || s->level_count == 0)
        return NACRE_ERROR_INVALID_ARGUMENT;
    level *l = &s->lv[0];
    /* Outside cells take no source; keep the caller's array untouched. */
    float *b = l->b;
    bool clean = true;
    for (size_t i = 0; i < l->cells; i++) {
        float v = l->solid[i] ? source[i] : 0.0f;
        if (!isfinite(v))
            clean = false;
        b[i] = v;
    }
    if (!clean)
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "diffusion: non-finite source");
    nc_diff_solve_report rep;
    memset(&rep, 0, sizeof(rep));
    nacre_result res;
    if (opts->solver == NACRE_SOLVER_SEED) {
        /* solve_seed uses lv[0].b as its level-0 source: copy b aside first */
        memcpy(s->pq, b, l->cells * sizeof(float));
        res = solve_seed(s, channel, s->pq, phi, opts, &rep);
        memcpy(b, s->pq, l->cells * sizeof(float));
    } else {
        res = solve_pcg(s, channel, b, phi, opts, &rep);
    }
    if (res != NACRE_OK)
        return res;
    energy(s, channel, b, phi, &rep);
    if (report)
        *report = rep;
    return NACRE_OK;
}
