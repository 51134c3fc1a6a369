/*
 * solver_setup.c: the diffusion solver's operators (Blanchard 2012 section 2.4 and 4.5), built
 * once per voxelization by nc_diff_setup: the fine level from the medium, the Robin boundary,
 * the coarse levels and the coarsest level's inverse. Units: see diffusion.h (lengths in scene
 * units, cell side h; sigma in 1/length, D in length).
 *
 * Discretization: cell-centred finite volumes of  div(D grad phi) - sigma_a phi + S = 0  on the
 * solid cells, with the Robin boundary condition of Arbree et al. (seed eq. 4.7) on every exposed
 * face. The seed updates a cell from each neighbour's D * phi (its eq. 4.6), which does not
 * conserve energy when D varies; here the flux across a face is G (phi_i - phi_j) with
 * G = h * harmonic mean of the two D, so what leaves one cell enters the other and the matrix is
 * symmetric positive definite.
 *
 * Coarse levels aggregate 2x2x2 cells (a coarse cell is in the domain when any child is, as the
 * voxel pyramid of seed 4.2.2); their operator is the Galerkin sum of the fine one with the face
 * conductances scaled by 0.6 per coarsened axis for multigrid (COARSE_G_SCALE: re-discretizing
 * would give 1/2, the piecewise-constant Galerkin sum alone is twice too stiff) and by 1/2 for
 * the seed's cascade (SEED_G_SCALE; rebuilt when a caller switches solvers). The coarsest level
 * (at most 2x2x2) is solved exactly with an inverse formed here (coarsest_factor).
 *
 * Setup visits the active row spans only where it can (see solver_internal.h), and clears only
 * the cells that left them since the previous setup.
 */
#include "diffusion/solver_internal.h"
#include "core/optics.h"

double nc_diff_robin_a(double eta)
{
    double fdr = nc_fresnel_fdr(eta);
    return (1.0 + fdr) / (1.0 - fdr);
}

void nc_diff_level_free(nacre_context *ctx, level *l)
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

void nc_diff_extras_free(nc_diff_solver *s)
{
    nacre_context *ctx = s->ctx;
    v4 **w[8] = {&s->bnd, &s->absorb, &s->pr, &s->pz, &s->pp, &s->pq, &s->px, &s->pp2};
    for (int k = 0; k < 8; k++) {
        nc_free(ctx, *w[k]);
        *w[k] = NULL;
    }
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
        nc_diff_level_free(ctx, l);
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
            nc_diff_extras_free(s);
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
        nc_diff_level_free(ctx, l);
        s->capacity[li] = 0;
        return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory for a %ux%ux%u grid", l->n[0], l->n[1],
                       l->n[2]);
    }
    return NACRE_OK;
}

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

/* D in the caller's grid (not on the fast path, which keeps D as dconst: see
 * nc_diff_coefficient_d): pass 1 of build_fine (fine_cells) writes every cell of the new box, so
 * only the cells of the previous box outside it need clearing (all of the grid if unknown);
 * clearing the whole grid (12 bytes per cell) was a tenth of a setup at 128^3. s->off and level
 * 0's shape are the new box; s->d_off, d_n still the previous one. */
static void clear_stale_d(nc_diff_solver *s, const nc_diff_medium *m, int threads)
{
    const level *l = &s->lv[0];
    const uint32_t nx = m->dims[0], ny = m->dims[1], nz = l->n[2];
    const uint32_t cx = l->n[0], cy = l->n[1], *off = s->off;
    const size_t user_cells = (size_t)m->dims[0] * m->dims[1] * m->dims[2];
    const bool d_known = s->d_valid && memcmp(s->d_dims, m->dims, sizeof(s->d_dims)) == 0;
    const uint32_t *po = d_known ? s->d_off : NULL, *pn = s->d_n;
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

/* Pass 1 of build_fine: domain, D (into d and the caller's grid) and absorption per cell (the
 * fast path: the domain only). */
static void fine_cells(nc_diff_solver *s, const nc_diff_medium *m, v4 *d, v4 dconst, v4 aconst, bool homogeneous,
                       bool fast, int threads)
{
    level *l = &s->lv[0];
    const float h = m->h;
    const uint32_t nx = m->dims[0], ny = m->dims[1], nz = l->n[2];
    const uint32_t cx = l->n[0], cy = l->n[1], *off = s->off;
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
}

/* Boundary weights of level 0 (build_fine, not staircase_faces): the normal estimate is noisy
 * from cell to cell, and so would be the escape through neighbouring faces (blotches in the
 * image): each cell takes the mean share of true area per exposed face over its 3x3x3
 * neighbourhood, times its own exposed faces. */
static void smooth_weights(nc_diff_solver *s, int threads)
{
    level *l = &s->lv[0];
    const uint32_t nz = l->n[2], cy = l->n[1];
    const size_t sy = l->sy, sz = l->sz;
    /* scratch: the PCG vectors are free during setup (nc_diff_setup clears pr's padding after) */
    float *smooth = (float *)s->pr;
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

/* Level 0 from the medium; also finds its row spans (level_spans). */
static nacre_result build_fine(nc_diff_solver *s, const nc_diff_medium *m, int threads)
{
    level *l = &s->lv[0];
    const float h = m->h;
    const float A = (float)nc_diff_robin_a(m->eta);
    const uint32_t nz = l->n[2], cx = l->n[0], cy = l->n[1], *off = s->off;
    const size_t sy = l->sy, sz = l->sz;
    v4 *d = l->res; /* scratch: level 0's res serves the seed scheme only, which writes it first */
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
    if (!fast)
        clear_stale_d(s, m, threads);
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
    fine_cells(s, m, d, dconst, aconst, homogeneous, fast, threads);
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
    if (!m->staircase_faces)
        smooth_weights(s, threads);
    if (m->boundary_scale) {
        const float *bs = m->boundary_scale;
#pragma omp parallel for num_threads(threads) schedule(static) if (l->cells > 32768)
        for (uint32_t z = 0; z < nz; z++)
            for (uint32_t y = 0; y < cy; y++) {
                const size_t u0 = (size_t)off[0] + (size_t)m->dims[0] * ((y + off[1]) + (size_t)m->dims[1] * (z + off[2]));
                float *bw = l->bw + pidx(l, 0, y, z);
                for (uint32_t x = 0; x < cx; x++)
                    bw[x] *= bs[u0 + x];
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

/* Coarse level li from li - 1: Galerkin sums with conductances scaled by `scale` per coarsened
 * axis (COARSE_G_SCALE for multigrid, SEED_G_SCALE for the seed's cascade). Parallel over coarse
 * z slabs, each gathering its own fine children. Leaves solid, diag and g zero outside the new
 * domain; the caller finds the spans and finishes the diagonal (nc_diff_build_coarse_levels). Only the
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
nacre_result nc_diff_build_coarse_levels(nc_diff_solver *s, float scale, bool spans, int threads)
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
    if ((res = nc_diff_build_coarse_levels(s, COARSE_G_SCALE, true, ctx->threads)) != NACRE_OK)
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
