/*
 * voxel.c: conservative surface and solid voxelization of triangle meshes into bit-packed
 * columns, a level pyramid, NRRD export and rest-pose coordinates (seed 000, section 4.2:
 * Schwarz and Seidel 2010, "Fast parallel surface and solid voxelization on GPUs"). Lengths in
 * mesh units; the grid's origin and voxel size map them to grid coordinates (voxel_internal.h).
 *
 * This file holds the public interface: settings, create (nacre_voxelize) and update, destroy,
 * the queries, NRRD export (io/nrrd) and rest positions, and the driver that runs the stages:
 * bounds and grid fit, solid-rule choice, the triangle pass (surface.c: surface bits and parity
 * toggles), the solid rules (solid.c: prefix XOR, ROBUST vote), the pyramid (pyramid.c).
 */
#include "voxel/voxel_internal.h"
#include "io/nrrd.h"

#include <errno.h>
#include <stdio.h>

nacre_voxel_settings nacre_voxel_settings_defaults(void)
{
    nacre_voxel_settings s;
    memset(&s, 0, sizeof(s));
    s.resolution = 32;
    s.solid_rule = NACRE_VOXEL_SOLID_AUTO;
    return s;
}

/* Zeroed buffer of n words in *buf, reusing it when its capacity *cap suffices (only the n words
 * used are cleared). */
static nacre_result words_prepare(nacre_context *ctx, uint64_t **buf, size_t *cap, size_t n)
{
    if (*buf && n <= *cap) {
        memset(*buf, 0, n * 8);
        return NACRE_OK;
    }
    nc_free(ctx, *buf);
    *cap = 0;
    *buf = nc_calloc(ctx, n ? n : 1, 8);
    if (!*buf)
        return NACRE_ERROR_OUT_OF_MEMORY;
    *cap = n ? n : 1;
    return NACRE_OK;
}

/* Level `l` of g with `dims`, both sets zeroed; allocations are reused when they fit. */
nacre_result nc_voxel_bitset_alloc(nacre_context *ctx, nacre_voxel_grid *g, uint32_t l,
                                   const uint32_t dims[3])
{
    bitset *b = &g->level[l];
    size_t cols, n, bytes;
    memcpy(b->dims, dims, sizeof(b->dims));
    b->words = (dims[2] + 63u) / 64u;
    if (!nc_mul_size_ok((size_t)dims[0], (size_t)dims[1], &cols) ||
        !nc_mul_size_ok(cols, (size_t)b->words, &n) || !nc_mul_size_ok(n, 8, &bytes))
        return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "voxel: grid too large");
    if (b->surface && b->solid && n <= g->cap[l]) {
        memset(b->surface, 0, bytes);
        memset(b->solid, 0, bytes);
        return NACRE_OK;
    }
    nc_free(ctx, b->surface);
    nc_free(ctx, b->solid);
    g->cap[l] = 0;
    b->surface = nc_calloc(ctx, n ? n : 1, 8);
    b->solid = nc_calloc(ctx, n ? n : 1, 8);
    if (!b->surface || !b->solid)
        return NACRE_ERROR_OUT_OF_MEMORY;
    g->cap[l] = n ? n : 1;
    return NACRE_OK;
}

void nacre_voxel_grid_destroy(nacre_voxel_grid *grid)
{
    if (!grid)
        return;
    for (uint32_t l = 0; l < VOXEL_MAX_LEVELS; l++) {
        nc_free(grid->ctx, grid->level[l].surface);
        nc_free(grid->ctx, grid->level[l].solid);
    }
    nc_free(grid->ctx, grid->px);
    nc_free(grid->ctx, grid->py);
    nc_free(grid->ctx, grid->priv);
    nc_free(grid->ctx, grid);
}

static inline bool get_bit(const uint64_t *set, size_t col, uint32_t words, uint32_t k)
{
    return (set[col * words + k / 64] >> (k % 64)) & 1u;
}

static uint64_t popcount_set(const uint64_t *s, size_t n)
{
    uint64_t c = 0;
    for (size_t i = 0; i < n; i++)
        c += (uint64_t)__builtin_popcountll(s[i]);
    return c;
}

/* Extend mn, mx by the finite vertices i0..i1 and count the others. */
static void vertex_bounds(const float *pos, size_t i0, size_t i1, float mn[3], float mx[3], uint32_t *nonfinite)
{
    size_t i = i0;
#ifdef __AVX2__
    /* Eight vertices are three registers of floats whose lanes keep their axis (float j of the
     * group is axis j % 3) from group to group; a group with a NaN or infinity (x - x != 0)
     * goes to the scalar loop below. */
    __m256 lo[3], hi[3];
    for (int r = 0; r < 3; r++) {
        lo[r] = _mm256_set1_ps(INFINITY);
        hi[r] = _mm256_set1_ps(-INFINITY);
    }
    for (; i + 8 <= i1; i += 8) {
        const float *p = pos + 3 * i;
        __m256 r0 = _mm256_loadu_ps(p), r1 = _mm256_loadu_ps(p + 8), r2 = _mm256_loadu_ps(p + 16);
        __m256 z = _mm256_setzero_ps();
        __m256 fin = _mm256_and_ps(_mm256_cmp_ps(_mm256_sub_ps(r0, r0), z, _CMP_EQ_OQ),
                                   _mm256_and_ps(_mm256_cmp_ps(_mm256_sub_ps(r1, r1), z, _CMP_EQ_OQ),
                                                 _mm256_cmp_ps(_mm256_sub_ps(r2, r2), z, _CMP_EQ_OQ)));
        if (_mm256_movemask_ps(fin) != 0xFF)
            break;
        lo[0] = _mm256_min_ps(lo[0], r0), hi[0] = _mm256_max_ps(hi[0], r0);
        lo[1] = _mm256_min_ps(lo[1], r1), hi[1] = _mm256_max_ps(hi[1], r1);
        lo[2] = _mm256_min_ps(lo[2], r2), hi[2] = _mm256_max_ps(hi[2], r2);
    }
    float l[24], h[24];
    for (int r = 0; r < 3; r++) {
        _mm256_storeu_ps(l + 8 * r, lo[r]);
        _mm256_storeu_ps(h + 8 * r, hi[r]);
    }
    for (int j = 0; j < 24; j++) {
        mn[j % 3] = fmn(mn[j % 3], l[j]);
        mx[j % 3] = fmx(mx[j % 3], h[j]);
    }
#endif
    for (; i < i1; i++) {
        const float *p = pos + 3 * i;
        if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2])) {
            (*nonfinite)++;
            continue;
        }
        for (int a = 0; a < 3; a++) {
            mn[a] = fmn(mn[a], p[a]);
            mx[a] = fmx(mx[a], p[a]);
        }
    }
}

/* Bounds over the finite vertices, streamed (a pass over triangles gathers vertices at random
 * and costs several times more on large meshes): extends bmin, bmax and counts the vertices
 * that are not finite. */
static void mesh_bounds(const float *pos, uint32_t nv, int threads, float bmin[3], float bmax[3],
                        uint32_t *nonfinite_vertices)
{
    /* Serial below VOXEL_BOUNDS_PARALLEL: a fork and join would cost more than the pass. */
#pragma omp parallel num_threads(threads) if (nv > VOXEL_BOUNDS_PARALLEL)
    {
        float lmin[3] = {INFINITY, INFINITY, INFINITY}, lmax[3] = {-INFINITY, -INFINITY, -INFINITY};
        uint32_t lnf = 0;
        size_t nblk = ((size_t)nv + VOXEL_CHUNK - 1) / VOXEL_CHUNK;
#pragma omp for schedule(static)
        for (size_t blk = 0; blk < nblk; blk++) {
            size_t i0 = blk * VOXEL_CHUNK, i1 = i0 + VOXEL_CHUNK < nv ? i0 + VOXEL_CHUNK : nv;
            vertex_bounds(pos, i0, i1, lmin, lmax, &lnf);
        }
#pragma omp critical(nacre_voxel_bounds)
        {
            for (int a = 0; a < 3; a++) {
                bmin[a] = fmn(bmin[a], lmin[a]);
                bmax[a] = fmx(bmax[a], lmax[a]);
            }
            *nonfinite_vertices += lnf;
        }
    }
}

/* Fit: longest axis = resolution voxels. A flat or point mesh still gets a positive size.
 * Returns the voxel size; dims and origin (the grid's corner) of the grid. */
static double fit_grid(const nacre_voxel_settings *s, const float bmin[3], const float bmax[3], uint32_t dims[3],
                       double origin[3])
{
    double ext[3], longest = 0;
    for (int a = 0; a < 3; a++) {
        ext[a] = (double)bmax[a] - (double)bmin[a];
        longest = dmax(longest, ext[a]);
    }
    if (!(longest > 0))
        longest = dmax(1e-6, fabs((double)bmax[0]) * 1e-6);
    double h = longest / s->resolution;
    for (int a = 0; a < 3; a++) {
        if (s->anisotropic) {
            double n = ceil(ext[a] / h);
            dims[a] = n < 1 ? 1u : n > s->resolution ? s->resolution : (uint32_t)n;
        } else {
            dims[a] = s->resolution;
        }
        origin[a] = 0.5 * ((double)bmin[a] + (double)bmax[a]) - 0.5 * dims[a] * h;
    }
    return h;
}

/* The float prefilter's margin (tri_source.margin, grid units; 0: no prefilter). Float grid
 * coordinates differ from the doubles by at most 4 * 2^-24 * (|p| + |origin|) / h (see prefilter8);
 * the margin is 16 times that, plus an absolute term for the roundings of small values. A margin
 * of an eighth of a voxel or more would pass almost nothing: no prefilter then. */
static float prefilter_margin(const float bmin[3], const float bmax[3], const float origin[3], double inv_h)
{
    double amax = 0, omax = 0;
    for (int a = 0; a < 3; a++) {
        amax = dmax(amax, dmax(fabs((double)bmin[a]), fabs((double)bmax[a])));
        omax = dmax(omax, fabs((double)origin[a]));
    }
    double m = 64.0 * 0x1p-24 * (amax + omax) * inv_h + 1e-6;
    return m < 0.125 && isfinite((float)inv_h) ? (float)m : 0.0f;
}

/* Voxelize into *out: a fresh grid when *out is NULL (destroyed on failure), else the grid
 * given, whose allocations are reused when they fit (levels set to 0 on a failure after it was
 * touched). */
static nacre_result voxelize_impl(nacre_context *ctx, const nacre_mesh_data *mesh,
                                  const nacre_voxel_settings *settings, nacre_voxel_grid **out,
                                  nacre_voxel_report *report)
{
    uint64_t t_start = nc_now_us();
    if (report)
        memset(report, 0, sizeof(*report));
    nacre_voxel_settings s = settings ? *settings : nacre_voxel_settings_defaults();
    if (s.resolution == 0)
        s.resolution = 32;
    if (s.resolution > VOXEL_MAX_RES)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "voxelize: resolution %u above %u",
                       s.resolution, VOXEL_MAX_RES);
    if ((unsigned)s.solid_rule > NACRE_VOXEL_SOLID_ROBUST)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "voxelize: unknown solid rule %d",
                       (int)s.solid_rule);
    if (!mesh || mesh->triangle_count == 0 || mesh->vertex_count == 0)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "voxelize: mesh is empty");
    if (!mesh->positions || !mesh->indices)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "voxelize: mesh has no positions or indices");
    const size_t nt = mesh->triangle_count;
    const uint32_t nv = mesh->vertex_count;
    const float *pos = mesh->positions;
    const uint32_t *idx = mesh->indices;

    /* Bounds over the finite vertices (unreferenced vertices count too). */
    float bmin[3] = {INFINITY, INFINITY, INFINITY}, bmax[3] = {-INFINITY, -INFINITY, -INFINITY};
    int threads = nc_threads(ctx);
    uint32_t nonfinite_vertices = 0;
    mesh_bounds(pos, nv, threads, bmin, bmax, &nonfinite_vertices);
    if (!(bmin[0] <= bmax[0]))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "voxelize: no finite vertex");

    uint32_t dims[3];
    double origin[3];
    double h = fit_grid(&s, bmin, bmax, dims, origin);

    bool fresh = *out == NULL;
    {
        /* The estimate before anything is made: level 0's two sets, two more parity sets under
         * the robust rule, and the pyramid (under a seventh of level 0). Only what a reused grid
         * does not hold yet counts. */
        uint64_t words = (uint64_t)dims[0] * dims[1] * ((dims[2] + 63u) / 64u);
        uint64_t sets = s.solid_rule == NACRE_VOXEL_SOLID_PARITY ? 2 : 4;
        uint64_t need = words * 8 * sets + words * 8 * 2 / 7;
        if (fresh || words > (*out)->cap[0]) {
            char what[96];
            snprintf(what, sizeof(what), "voxel grid %ux%ux%u (voxel resolution %u)", dims[0], dims[1], dims[2],
                     s.resolution);
            nacre_result mr = nc_memory_check(ctx, need, what);
            if (mr != NACRE_OK)
                return mr;
        }
    }
    nacre_voxel_grid *g = fresh ? nc_calloc(ctx, 1, sizeof(*g)) : *out;
    if (!g)
        return NACRE_ERROR_OUT_OF_MEMORY;
    g->ctx = ctx;
    g->levels = 0;
    g->voxel_size = (float)h;
    for (int a = 0; a < 3; a++)
        g->origin[a] = (float)origin[a];
    nacre_result r = nc_voxel_bitset_alloc(ctx, g, 0, dims);
    if (r != NACRE_OK)
        goto fail;
    /* Use the float-rounded origin and size so queries and exports describe exactly this grid. */
    tri_source src = {pos, idx, {g->origin[0], g->origin[1], g->origin[2]}, 1.0 / (double)g->voxel_size,
                      nonfinite_vertices == 0, 0.0f};
    src.margin = prefilter_margin(bmin, bmax, g->origin, src.inv_h);

    nacre_voxel_solid_rule rule = s.solid_rule;
    bool closed = rule == NACRE_VOXEL_SOLID_PARITY;
    if (rule == NACRE_VOXEL_SOLID_AUTO) {
        closed = false;
        if (nonfinite_vertices == 0) {
            nacre_mesh_info info;
            r = nacre_mesh_analyze(ctx, mesh, &info);
            if (r != NACRE_OK)
                goto fail;
            closed = info.closed;
        }
        rule = closed ? NACRE_VOXEL_SOLID_PARITY : NACRE_VOXEL_SOLID_ROBUST;
    }

    bitset *b = &g->level[0];
    tri_out dst = {b, NULL, NULL};
    if (rule == NACRE_VOXEL_SOLID_ROBUST) {
        /* Same size as a level-0 set, which nc_voxel_bitset_alloc has checked for overflow. */
        r = words_prepare(ctx, &g->px, &g->cap_px, bitset_words(b));
        if (r == NACRE_OK)
            r = words_prepare(ctx, &g->py, &g->cap_py, bitset_words(b));
        if (r != NACRE_OK)
            goto fail;
        dst.px = g->px;
        dst.py = g->py;
    }
    tri_counts total;
    r = nc_voxel_triangle_pass(ctx, g, &dst, &src, nt, nv, threads, &total);
    if (r != NACRE_OK)
        goto fail;
    const uint32_t degenerate = total.degenerate, nonfinite = total.nonfinite, bad_index = total.bad_index;
    if (bad_index) {
        r = nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                    "voxelize: %u triangles have a vertex index >= vertex count %u", bad_index, nv);
        goto fail;
    }
    if (degenerate + nonfinite == nt) {
        r = nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "voxelize: no triangle with a finite, non-zero area");
        goto fail;
    }
    nc_voxel_prefix_xor(b->solid, (size_t)dims[0] * dims[1], dims[2], b->words, threads);
    if (dst.px)
        nc_voxel_robust_solid(dst.px, dst.py, b, threads);

    r = nc_voxel_pyramid(ctx, g, threads);
    if (r != NACRE_OK)
        goto fail;

    if (report) {
        memcpy(report->dims, dims, sizeof(dims));
        report->voxel_size = g->voxel_size;
        memcpy(report->origin, g->origin, sizeof(g->origin));
        report->surface_voxels = popcount_set(b->surface, bitset_words(b));
        report->solid_voxels = popcount_set(b->solid, bitset_words(b));
        report->closed = closed;
        report->rule_used = rule;
        report->levels = g->levels;
        report->skipped_degenerate = degenerate;
        report->skipped_nonfinite = nonfinite;
        report->ms = (double)(nc_now_us() - t_start) / 1000.0;
    }
    *out = g;
    return NACRE_OK;
fail:
    if (fresh) {
        nacre_voxel_grid_destroy(g);
    } else {
        g->levels = 0;
        memset(g->level[0].dims, 0, sizeof(g->level[0].dims));
    }
    return r;
}

nacre_result nacre_voxelize(nacre_context *ctx, const nacre_mesh_data *mesh,
                            const nacre_voxel_settings *settings, nacre_voxel_grid **out,
                            nacre_voxel_report *report)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (report)
        memset(report, 0, sizeof(*report));
    if (!out)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "voxelize: output is NULL");
    *out = NULL;
    return voxelize_impl(ctx, mesh, settings, out, report);
}

nacre_result nacre_voxelize_update(nacre_voxel_grid *grid, const nacre_mesh_data *mesh,
                                   const nacre_voxel_settings *settings, nacre_voxel_report *report)
{
    if (report)
        memset(report, 0, sizeof(*report));
    if (!grid)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_voxel_grid *g = grid;
    return voxelize_impl(grid->ctx, mesh, settings, &g, report);
}

/* ------------------------------------------------------------------------------------------ */
/* Queries and export                                                                         */
/* ------------------------------------------------------------------------------------------ */

uint32_t nacre_voxel_grid_levels(const nacre_voxel_grid *grid)
{
    return grid ? grid->levels : 0;
}

bool nacre_voxel_grid_dims(const nacre_voxel_grid *grid, uint32_t level, uint32_t dims[3])
{
    if (!dims)
        return false;
    if (!grid || level >= grid->levels) {
        dims[0] = dims[1] = dims[2] = 0;
        return false;
    }
    memcpy(dims, grid->level[level].dims, 3 * sizeof(uint32_t));
    return true;
}

bool nacre_voxel_grid_get(const nacre_voxel_grid *grid, nacre_voxel_set set, uint32_t level,
                          uint32_t x, uint32_t y, uint32_t z)
{
    if (!grid || level >= grid->levels)
        return false;
    const bitset *b = &grid->level[level];
    if (x >= b->dims[0] || y >= b->dims[1] || z >= b->dims[2])
        return false;
    const uint64_t *s = set == NACRE_VOXEL_SOLID ? b->solid : b->surface;
    return get_bit(s, (size_t)y * b->dims[0] + x, b->words, z);
}

bool nacre_voxel_grid_unpack(const nacre_voxel_grid *grid, nacre_voxel_set set, uint32_t level, uint8_t *out)
{
    if (!grid || !out || level >= grid->levels)
        return false;
    const bitset *b = &grid->level[level];
    const uint64_t *s = set == NACRE_VOXEL_SOLID ? b->solid : b->surface;
    const size_t nx = b->dims[0], slab = nx * b->dims[1];
    /* Column by column: each 64-bit word holds 64 consecutive z of one (x, y). */
    for (size_t col = 0; col < slab; col++) {
        const uint64_t *w = s + col * b->words;
        for (uint32_t z = 0; z < b->dims[2]; z++)
            out[col + slab * z] = (uint8_t)((w[z / 64] >> (z % 64)) & 1u);
    }
    return true;
}

uint64_t nacre_voxel_grid_count(const nacre_voxel_grid *grid, nacre_voxel_set set, uint32_t level)
{
    if (!grid || level >= grid->levels)
        return 0;
    const bitset *b = &grid->level[level];
    return popcount_set(set == NACRE_VOXEL_SOLID ? b->solid : b->surface, bitset_words(b));
}

typedef struct nrrd_rows {
    const bitset *b;
} nrrd_rows;

/* Channel 0 solid, channel 1 surface. */
static void nrrd_row(void *user, uint32_t y, uint32_t z, uint8_t *row)
{
    const bitset *b = ((const nrrd_rows *)user)->b;
    for (uint32_t x = 0; x < b->dims[0]; x++) {
        size_t col = (size_t)y * b->dims[0] + x;
        row[2 * x] = get_bit(b->solid, col, b->words, z);
        row[2 * x + 1] = get_bit(b->surface, col, b->words, z);
    }
}

nacre_result nacre_voxel_grid_write_nrrd(const nacre_voxel_grid *grid, uint32_t level,
                                         const char *path)
{
    if (!grid)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_context *ctx = grid->ctx;
    if (!path || level >= grid->levels)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "voxel nrrd: no path or level %u missing", level);
    const bitset *b = &grid->level[level];
    double h = (double)grid->voxel_size * (double)(1u << level);
    /* NRRD places samples at their centres: "space origin" is the centre of voxel (0, 0, 0). */
    const double origin[3] = {grid->origin[0] + 0.5 * h, grid->origin[1] + 0.5 * h, grid->origin[2] + 0.5 * h};
    char comment[96];
    snprintf(comment, sizeof(comment), "nacre voxelization level %u: channel 0 solid, channel 1 surface", level);
    nrrd_rows rows = {b};
    return nc_nrrd_write_u8(ctx, path, comment, 2, b->dims, h, origin, nrrd_row, &rows);
}

/* ------------------------------------------------------------------------------------------ */
/* Rest-pose coordinates                                                                      */
/* ------------------------------------------------------------------------------------------ */

/* Closest point of triangle (a, b, c) to p as barycentric weights (Ericson 2005, 5.1.5). */
static void closest_bary(const double p[3], const double a[3], const double b[3], const double c[3],
                         double w[3])
{
    double ab[3], ac[3], ap[3], bp[3], cp[3];
    for (int k = 0; k < 3; k++) {
        ab[k] = b[k] - a[k];
        ac[k] = c[k] - a[k];
        ap[k] = p[k] - a[k];
        bp[k] = p[k] - b[k];
        cp[k] = p[k] - c[k];
    }
#define DOT(u, v) (u[0] * v[0] + u[1] * v[1] + u[2] * v[2])
    double d1 = DOT(ab, ap), d2 = DOT(ac, ap), d3 = DOT(ab, bp), d4 = DOT(ac, bp), d5 = DOT(ab, cp),
           d6 = DOT(ac, cp);
#undef DOT
    double va = d3 * d6 - d5 * d4, vb = d5 * d2 - d1 * d6, vc = d1 * d4 - d3 * d2;
    if (d1 <= 0 && d2 <= 0) {
        w[0] = 1, w[1] = 0, w[2] = 0;
    } else if (d3 >= 0 && d4 <= d3) {
        w[0] = 0, w[1] = 1, w[2] = 0;
    } else if (vc <= 0 && d1 >= 0 && d3 <= 0) {
        double t = d1 / (d1 - d3);
        w[0] = 1 - t, w[1] = t, w[2] = 0;
    } else if (d6 >= 0 && d5 <= d6) {
        w[0] = 0, w[1] = 0, w[2] = 1;
    } else if (vb <= 0 && d2 >= 0 && d6 <= 0) {
        double t = d2 / (d2 - d6);
        w[0] = 1 - t, w[1] = 0, w[2] = t;
    } else if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
        double t = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        w[0] = 0, w[1] = 1 - t, w[2] = t;
    } else {
        double den = 1.0 / (va + vb + vc);
        w[1] = vb * den;
        w[2] = vc * den;
        w[0] = 1 - w[1] - w[2];
    }
}

/* The local map from deformed to rest space that triangle t defines, applied to the world
 * vector dv: the in-plane part through the edges (exact for any affine map of the plane), the
 * normal part along the rest normal scaled by sqrt(rest area / deformed area) (exact for
 * rotations and uniform scales; first order otherwise). A degenerate triangle maps dv to
 * itself (a translation). */
static void rest_vector(const nacre_mesh_data *rest, const nacre_mesh_data *def, size_t t, const double dv[3],
                        double out[3])
{
    const uint32_t *ti = def->indices + 3 * t;
    double e1[3], e2[3], f1[3], f2[3];
    for (int a = 0; a < 3; a++) {
        e1[a] = (double)def->positions[3 * (size_t)ti[1] + (size_t)a] - def->positions[3 * (size_t)ti[0] + (size_t)a];
        e2[a] = (double)def->positions[3 * (size_t)ti[2] + (size_t)a] - def->positions[3 * (size_t)ti[0] + (size_t)a];
        f1[a] = (double)rest->positions[3 * (size_t)ti[1] + (size_t)a] - rest->positions[3 * (size_t)ti[0] + (size_t)a];
        f2[a] = (double)rest->positions[3 * (size_t)ti[2] + (size_t)a] - rest->positions[3 * (size_t)ti[0] + (size_t)a];
    }
    double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
    double m[3] = {f1[1] * f2[2] - f1[2] * f2[1], f1[2] * f2[0] - f1[0] * f2[2], f1[0] * f2[1] - f1[1] * f2[0]};
    double nn = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]), mm = sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
    double g11 = e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2], g22 = e2[0] * e2[0] + e2[1] * e2[1] + e2[2] * e2[2];
    double g12 = e1[0] * e2[0] + e1[1] * e2[1] + e1[2] * e2[2], det = g11 * g22 - g12 * g12;
    if (!(nn > 0) || !(mm > 0) || !(det > 1e-12 * g11 * g22)) {
        memcpy(out, dv, 3 * sizeof(double));
        return;
    }
    double c = (dv[0] * n[0] + dv[1] * n[1] + dv[2] * n[2]) / nn; /* normal component */
    double r1 = dv[0] * e1[0] + dv[1] * e1[1] + dv[2] * e1[2], r2 = dv[0] * e2[0] + dv[1] * e2[1] + dv[2] * e2[2];
    double u = (g22 * r1 - g12 * r2) / det, v = (g11 * r2 - g12 * r1) / det; /* in-plane coordinates */
    double k = c * sqrt(mm / nn) / mm;
    for (int a = 0; a < 3; a++)
        out[a] = u * f1[a] + v * f2[a] + k * m[a];
}

/* Why one function of ~140 lines: the three passes (nearest triangle per surface voxel,
 * breadth-first spread, map through the source's triangle) share the grid walk and the scratch
 * arrays, and read best as one sequence. */
nacre_result nacre_voxel_grid_rest_positions(const nacre_voxel_grid *grid,
                                             const nacre_mesh_data *rest,
                                             const nacre_mesh_data *deformed, float *out)
{
    if (!grid)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_context *ctx = grid->ctx;
    if (!rest || !deformed || !out || !rest->positions || !deformed->positions ||
        !deformed->indices || rest->vertex_count != deformed->vertex_count)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "voxel rest positions: need rest and deformed meshes with the same vertices");
    const bitset *b = &grid->level[0];
    const uint32_t *d = b->dims;
    const size_t nvox = (size_t)d[0] * d[1] * d[2];
    if (nvox > UINT32_MAX) /* the breadth-first queue holds 32-bit voxel ids */
        return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "voxel rest positions: more than 2^32 voxels");
    float *best = nc_alloc(ctx, nvox * sizeof(float));
    uint32_t *queue = nc_alloc(ctx, nvox * sizeof(uint32_t));
    uint32_t *tri = nc_alloc(ctx, nvox * sizeof(uint32_t)); /* surface voxel: its nearest triangle */
    uint32_t *src = nc_alloc(ctx, nvox * sizeof(uint32_t)); /* solid voxel: the surface voxel it follows */
    if (!best || !queue || !tri || !src) {
        nc_free(ctx, best);
        nc_free(ctx, queue);
        nc_free(ctx, tri);
        nc_free(ctx, src);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    for (size_t i = 0; i < nvox; i++) {
        best[i] = INFINITY;
        src[i] = UINT32_MAX;
        out[3 * i] = out[3 * i + 1] = out[3 * i + 2] = NAN;
    }
    tri_source ts = {deformed->positions, deformed->indices,
                     {grid->origin[0], grid->origin[1], grid->origin[2]}, 1.0 / (double)grid->voxel_size, false,
                     0.0f};
    const double h = grid->voxel_size;
    /* Surface voxels: closest deformed triangle among those touching the voxel (bounding box);
     * the rest point of the closest point q on it, then the voxel centre c mapped through the
     * triangle's local map: rest(q) + A (c - q). */
    for (size_t t = 0; t < deformed->triangle_count; t++) {
        const uint32_t *ti = deformed->indices + 3 * t;
        if (ti[0] >= deformed->vertex_count || ti[1] >= deformed->vertex_count ||
            ti[2] >= deformed->vertex_count)
            continue;
        double v[3][3], nrm[3];
        if (load_triangle(&ts, t, v, nrm) != 0)
            continue;
        int lo[3], hi[3];
        bool empty = false;
        for (int a = 0; a < 3; a++) {
            double mn = dmin(v[0][a], dmin(v[1][a], v[2][a])), mx = dmax(v[0][a], dmax(v[1][a], v[2][a]));
            lo[a] = (int)dmax(0.0, ceil(mn) - 1.0);
            hi[a] = (int)dmin((double)d[a] - 1, floor(mx));
            empty = empty || lo[a] > hi[a];
        }
        if (empty)
            continue;
        for (int z = lo[2]; z <= hi[2]; z++)
            for (int y = lo[1]; y <= hi[1]; y++)
                for (int x = lo[0]; x <= hi[0]; x++) {
                    size_t col = (size_t)y * d[0] + (size_t)x;
                    if (!get_bit(b->surface, col, b->words, (uint32_t)z))
                        continue;
                    double p[3] = {x + 0.5, y + 0.5, z + 0.5}, w[3], dv[3], rv[3];
                    closest_bary(p, v[0], v[1], v[2], w);
                    double dist = 0;
                    for (int a = 0; a < 3; a++) {
                        double q = w[0] * v[0][a] + w[1] * v[1][a] + w[2] * v[2][a] - p[a];
                        dv[a] = -q * h; /* c - q, world units */
                        dist += q * q;
                    }
                    size_t vi = col + (size_t)z * d[0] * d[1];
                    if (dist < best[vi]) {
                        best[vi] = (float)dist;
                        tri[vi] = (uint32_t)t;
                        rest_vector(rest, deformed, t, dv, rv);
                        for (int a = 0; a < 3; a++)
                            out[3 * vi + (size_t)a] =
                                (float)(w[0] * rest->positions[3 * (size_t)ti[0] + (size_t)a] +
                                        w[1] * rest->positions[3 * (size_t)ti[1] + (size_t)a] +
                                        w[2] * rest->positions[3 * (size_t)ti[2] + (size_t)a] + rv[a]);
                    }
                }
    }
    /* Spread the surface voxels breadth-first through the solid voxels: each solid voxel
     * follows the nearest surface voxel in 6-connected steps. */
    size_t head = 0, tail = 0;
    for (size_t vi = 0; vi < nvox; vi++)
        if (isfinite(out[3 * vi])) {
            src[vi] = (uint32_t)vi;
            queue[tail++] = (uint32_t)vi;
        }
    while (head < tail) {
        size_t vi = queue[head++];
        long x = (long)(vi % d[0]), y = (long)((vi / d[0]) % d[1]), z = (long)(vi / ((size_t)d[0] * d[1]));
        static const int off[6][3] = {{-1, 0, 0}, {1, 0, 0}, {0, -1, 0}, {0, 1, 0}, {0, 0, -1}, {0, 0, 1}};
        for (int k = 0; k < 6; k++) {
            long nx = x + off[k][0], ny = y + off[k][1], nz = z + off[k][2];
            if (nx < 0 || ny < 0 || nz < 0 || nx >= (long)d[0] || ny >= (long)d[1] || nz >= (long)d[2])
                continue;
            size_t col = (size_t)ny * d[0] + (size_t)nx, ni = col + (size_t)nz * d[0] * d[1];
            if (src[ni] != UINT32_MAX || !get_bit(b->solid, col, b->words, (uint32_t)nz))
                continue;
            src[ni] = src[vi];
            queue[tail++] = (uint32_t)ni;
        }
    }
    /* An interior voxel c' maps through its surface voxel c's triangle: rest(c) + A (c' - c). */
    for (size_t vi = 0; vi < nvox; vi++) {
        size_t si = src[vi];
        if (si == UINT32_MAX || si == vi)
            continue;
        double dv[3], rv[3];
        long ax = (long)(vi % d[0]) - (long)(si % d[0]);
        long ay = (long)((vi / d[0]) % d[1]) - (long)((si / d[0]) % d[1]);
        long az = (long)(vi / ((size_t)d[0] * d[1])) - (long)(si / ((size_t)d[0] * d[1]));
        dv[0] = (double)ax * h, dv[1] = (double)ay * h, dv[2] = (double)az * h;
        rest_vector(rest, deformed, tri[si], dv, rv);
        for (int a = 0; a < 3; a++)
            out[3 * vi + (size_t)a] = (float)(out[3 * si + (size_t)a] + rv[a]);
    }
    nc_free(ctx, best);
    nc_free(ctx, queue);
    nc_free(ctx, tri);
    nc_free(ctx, src);
    return NACRE_OK;
}
