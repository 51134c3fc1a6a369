/*
 * shade_diffusion.c: exitance and shading of the diffusion method (Blanchard 2012 section 4.6).
 *
 * Exitance. The Robin condition phi + 2 A D dphi/dn = 4 q / (1 - Fdr) (seed eq. 4.7), written
 * between the surface and a point a distance delta inside it (dphi/dn = (phi_s - phi) / delta),
 * gives the net outward flux per unit area
 *     J = k (phi - 4 q / (1 - Fdr)),  k = D / (delta + 2 A D);
 * with delta = h / 2 (a cell centre and its face) this is nc_diff_exitance, the boundary term of
 * the solver. The light that leaves is J + q (net = leaving - incoming), so
 *   VOLUME sources (q = 0 on the boundary): E = k phi;
 *   FACE sources: E = k phi + q (1 - 4 k / (1 - Fdr)), q the lit faces' incoming flux per unit
 *     area in that cell, summed when a cell has several (a simplification: the shading point does
 *     not know which face it is nearest to). The q term is a property of the boundary faces, so
 *     it uses the faces' own k (delta = h / 2) and is read at the surface point, while k phi is
 *     read below it (next paragraph); reading q below the surface mixed lit boundary cells with
 *     interior ones (q = 0) and drew rings on spheres.
 * Negative values (round-off of an unconverged solve, or a strongly lit face whose net flux is
 * inward) are clamped to 0: the light leaving cannot be negative.
 *
 * Where to sample. The domain's boundary is a staircase of voxel faces, and the boundary cells'
 * fluence follows it: a cell with three exposed faces escapes more than one with one. Reading
 * the field at the surface point itself (corners half solid, half empty) shows that staircase as
 * terraces and rings on smooth objects. We read it NC_DIFF_SAMPLE_DEPTH = 1/2 cell below the
 * surface, at p - n h / 2 with the G-buffer's shading normal n, which is about where the first
 * layer of cell centres lies, and use delta = h / 2: then the per-cell E is exactly the solver's
 * boundary flux nc_diff_exitance, so the picture carries the energy the solver lets escape.
 * Reading one cell deep (delta = h) is smoother still but darker at coarse grids, because phi
 * falls off over the first cells below a lit surface: the red exitance at the lit pole of a
 * jade sphere (r = 20 mm) at 16 / 32 / 64 / 128 cells is 0.24 / 0.43 / 0.57 / 0.63 one cell deep
 * against 0.46 / 0.60 / 0.65 / 0.66 half a cell deep. Per cell we store E with the cell's own D,
 * so heterogeneous media need no separate D interpolation.
 *
 * True depth. A boundary cell's centre is 0 to about a cell below the true surface, not h / 2
 * (o->depth); the solver scales its Robin term by f = (h / 2 + 2 A D) / (d + 2 A D)
 * (pipeline.c, object_setup, where f also fades to 1 on cells wider than a mean free path).
 * The sample point p - n h / 2 is h / 2 below the true surface, and phi interpolated there from
 * cells at depths d_i stands for phi at their mean depth: the exitance is
 * D phi / (d + 2 A D) = sum w k phi / sum w g with g = 1 / f, so each cell's record is
 * (k phi, g) instead of (k phi, 1), and the shading pass's renormalized sums do the rest
 * (g = 1 where f = 1: the staircase's exitance as before). The fallbacks (o->exitance: ghost
 * records of larger grids, points outside the grid, rare) keep k phi with weight 1.
 *
 * Interpolation: trilinear between cell centres over the boundary cells only (solid cells with an
 * exposed face; weights renormalized), so that neither empty space nor the interior leaks in. An
 * interior cell's k phi is no exitance: below a lit surface phi grows over the first mean free
 * path, and on the wide terraces of a surface nearly aligned with a grid axis the sample point
 * half a cell down falls between a boundary cell and the interior one under it. Mixing those in
 * made a sphere 11-14% too bright at 32^3-64^3 (docs/accuracy.md); over boundary cells only,
 * 5-8%. Where no solid corner has weight (thin parts at coarse grids: a
 * fifth of Suzanne's pixels at 4^3, half of the statue's, 1% at 128^3), the corners take ghost
 * values: an empty cell next to the domain (26-neighbourhood) holds the weighted mean of its
 * solid neighbours, and the point interpolates the corners that have one (ghost_record; small
 * grids keep every cell's record, ghost_grid). A point with none has no solid cell within one
 * cell and gets no subsurface light. This replaced the nearest solid cell, which drew the solid
 * cells' Voronoi edges on thin parts and searched 27 cells per pixel (a third of the shading pass
 * at 4^3); against the 64^3 image, Suzanne's and the statue's 640x360 pictures at 4^3 came
 * closer (rmse 0.0332 -> 0.0315, 0.0486 -> 0.0412).
 *
 * Radiance towards the viewer:
 *   L = E (1 - F(cos_o, eta)) / (pi (1 - F_diffuse(eta))),
 * whose projected-solid-angle integral is exactly E (2 pi int (1 - F) mu dmu = pi (1 - F_diffuse)).
 * The seed's eq. 4.9 (after Arbree et al. 2011) writes L = Ft / (4 pi) [...] with the fluence
 * terms and omits the 1 / eta^2 compression of radiance crossing into the lower index; here E is
 * already the flux that leaves, and the normalization above distributes it over the outside
 * hemisphere, which accounts for that compression.
 *
 * The shading pass calls nc_diff_subsurface_radiance once per batch of pixels (shade.h), which
 * takes them 8 lanes at a time from the G-buffer values to the radiance in vector registers
 * (core/simd.h): the corner reads broadcast each cell's records once for the lanes in it
 * (group_sums), and only the per-point ghost records of larger grids, the points outside the grid
 * and FACE mode's q run per lane. Against one 4-wide trilinear read per pixel, the 8-lane corner
 * reads took the subsurface part of Suzanne's 4^3 pass from 15 to 7.5 million instructions per
 * frame (callgrind), and the 8-lane groups from there to 6.1 million, with bit-identical images
 * (before FMA contraction was turned on).
 */
#include "diffusion/pipeline.h"
#include "core/optics.h"
#include "core/simd.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Trilinear interpolation of a per-cell field (3 channels) at p over the boundary cells around it
 * (weights renormalized); where no solid corner has weight, over the corners' ghost values
 * (ghost_record). For many nearby points (a batch of pixels) the cache keeps the solid corners of
 * the last interpolation cell and the corner values of the last ghost interpolation, so that
 * points in the same cells skip the bounds and solid tests and the ghosts' sums; the result is
 * the same either way. At coarse grids many pixels take the ghost path, and neighbouring pixels
 * share their cells. */
typedef float v4f __attribute__((vector_size(16)));

typedef struct field_cache {
    int corner_key[3], ghost_key[3];
    bool corner_valid, ghost_valid;
    int corner_n;
    int corner_k[8];
    size_t corner_i[8];
    v4f ghost[8];
} field_cache;

/* Trilinear interpolation of 8 corner records (corner k at +x if k & 1, +y if k & 2, +z if k & 4)
 * as three lerps: the weights of the per-corner products (1 - fx or fx) (1 - fy or fy) ... */
static inline v4f lerp8(const v4f c[8], float fx, float fy, float fz)
{
    const float gx0 = 1.0f - fx, gy0 = 1.0f - fy, gz0 = 1.0f - fz;
    v4f c00 = c[0] * gx0 + c[1] * fx, c10 = c[2] * gx0 + c[3] * fx;
    v4f c01 = c[4] * gx0 + c[5] * fx, c11 = c[6] * gx0 + c[7] * fx;
    return (c00 * gy0 + c10 * fy) * gz0 + (c01 * gy0 + c11 * fy) * fz;
}

/* Whether grid cell (x, y, z) (inside the grid) is a boundary cell: solid with an exposed face. */
static inline bool boundary_cell(const nc_diff_object *o, int x, int y, int z)
{
    const int nx = (int)o->dims[0], ny = (int)o->dims[1], nz = (int)o->dims[2];
    const size_t i = (size_t)x + (size_t)nx * ((size_t)y + (size_t)ny * (size_t)z), sy = (size_t)nx,
                 sz = (size_t)nx * (size_t)ny;
    if (!o->solid[i])
        return false;
    return x == 0 || y == 0 || z == 0 || x == nx - 1 || y == ny - 1 || z == nz - 1 || !o->solid[i - 1] ||
           !o->solid[i + 1] || !o->solid[i - sy] || !o->solid[i + sy] || !o->solid[i - sz] || !o->solid[i + sz];
}

/* The fallback's record of grid cell (x, y, z), possibly outside the grid: (value, 1) with its own
 * value if a boundary cell, else with the weighted mean of the boundary cells among its 26
 * neighbours (weight 2^-(|dx|+|dy|+|dz|): face 1/2, edge 1/4, corner 1/8); zero if it has none.
 * The same records as ghost_grid makes from the packed grid. */
static v4f ghost_record(const nc_diff_object *o, float *const field[3], int x, int y, int z)
{
    const int nx = (int)o->dims[0], ny = (int)o->dims[1], nz = (int)o->dims[2];
    static const float weight[4] = {1.0f, 0.5f, 0.25f, 0.125f};
    if (x >= 0 && y >= 0 && z >= 0 && x < nx && y < ny && z < nz) {
        size_t i = (size_t)x + (size_t)nx * ((size_t)y + (size_t)ny * (size_t)z);
        if (boundary_cell(o, x, y, z))
            return (v4f){field[0][i], field[1][i], field[2][i], 1.0f};
    }
    float a[3] = {0.0f, 0.0f, 0.0f}, ws = 0.0f;
    for (int dz = -1; dz <= 1; dz++)
        for (int dy = -1; dy <= 1; dy++)
            for (int dx = -1; dx <= 1; dx++) {
                int cx = x + dx, cy = y + dy, cz = z + dz;
                if (cx < 0 || cy < 0 || cz < 0 || cx >= nx || cy >= ny || cz >= nz)
                    continue;
                size_t i = (size_t)cx + (size_t)nx * ((size_t)cy + (size_t)ny * (size_t)cz);
                if (!boundary_cell(o, cx, cy, cz))
                    continue;
                float w = weight[abs(dx) + abs(dy) + abs(dz)];
                for (int c = 0; c < 3; c++)
                    a[c] += w * field[c][i];
                ws += w;
            }
    if (!(ws > 0.0f))
        return (v4f){0.0f, 0.0f, 0.0f, 0.0f};
    return (v4f){a[0] / ws, a[1] / ws, a[2] / ws, 1.0f};
}

/* The value of a ghost interpolation (the trilinear sums of ghost records); false if no corner
 * with weight has a record. */
static bool ghost_result(v4f acc, float out[3])
{
    out[0] = out[1] = out[2] = 0.0f;
    if (!(acc[3] > 0.0f))
        return false;
    for (int c = 0; c < 3; c++)
        out[c] = acc[c] / acc[3];
    return true;
}

/* The trilinear sums of the ghost records of the corners of grid cell (x0, y0, z0) at fractions
 * (fx, fy, fz), the records computed (ghost_record) and kept in fc for the next point. */
static v4f ghost_sum(const nc_diff_object *o, float *const field[3], int x0, int y0, int z0, float fx, float fy,
                     float fz, field_cache *fc)
{
    if (!fc->ghost_valid || fc->ghost_key[0] != x0 || fc->ghost_key[1] != y0 || fc->ghost_key[2] != z0) {
        for (int k = 0; k < 8; k++)
            fc->ghost[k] = ghost_record(o, field, x0 + (k & 1), y0 + ((k >> 1) & 1), z0 + ((k >> 2) & 1));
        fc->ghost_key[0] = x0;
        fc->ghost_key[1] = y0;
        fc->ghost_key[2] = z0;
        fc->ghost_valid = true;
    }
    return lerp8(fc->ghost, fx, fy, fz);
}

static bool sample_field_cached(const nc_diff_object *o, float *const field[3], nc_vec3 p, field_cache *fc,
                                float out[3])
{
    out[0] = out[1] = out[2] = 0.0f;
    if (!o->solid || o->solid_count == 0)
        return false;
    const int nx = (int)o->dims[0], ny = (int)o->dims[1], nz = (int)o->dims[2];
    const float inv_h = 1.0f / o->h;
    float gx = (p.x - o->origin[0]) * inv_h - 0.5f, gy = (p.y - o->origin[1]) * inv_h - 0.5f,
          gz = (p.z - o->origin[2]) * inv_h - 0.5f;
    if (!(fabsf(gx) < 1e6f && fabsf(gy) < 1e6f && fabsf(gz) < 1e6f))
        return false; /* also NaN; keeps the cell indices in range of int */
    int x0 = (int)floorf(gx), y0 = (int)floorf(gy), z0 = (int)floorf(gz);
    float fx = gx - (float)x0, fy = gy - (float)y0, fz = gz - (float)z0;
    if (!fc->corner_valid || fc->corner_key[0] != x0 || fc->corner_key[1] != y0 || fc->corner_key[2] != z0) {
        fc->corner_n = 0;
        for (int k = 0; k < 8; k++) {
            int x = x0 + (k & 1), y = y0 + ((k >> 1) & 1), z = z0 + ((k >> 2) & 1);
            if (x < 0 || y < 0 || z < 0 || x >= nx || y >= ny || z >= nz)
                continue;
            size_t i = (size_t)x + (size_t)nx * ((size_t)y + (size_t)ny * (size_t)z);
            if (!boundary_cell(o, x, y, z))
                continue;
            fc->corner_k[fc->corner_n] = k;
            fc->corner_i[fc->corner_n++] = i;
        }
        fc->corner_key[0] = x0;
        fc->corner_key[1] = y0;
        fc->corner_key[2] = z0;
        fc->corner_valid = true;
    }
    float acc[3] = {0, 0, 0}, wsum = 0.0f;
    for (int j = 0; j < fc->corner_n; j++) {
        int k = fc->corner_k[j];
        size_t i = fc->corner_i[j];
        float w = ((k & 1) ? fx : 1.0f - fx) * ((k & 2) ? fy : 1.0f - fy) * ((k & 4) ? fz : 1.0f - fz);
        wsum += w;
        for (int c = 0; c < 3; c++)
            acc[c] += w * field[c][i];
    }
    if (wsum > 1e-6f) {
        for (int c = 0; c < 3; c++)
            out[c] = acc[c] / wsum;
        return true;
    }
    return ghost_result(ghost_sum(o, field, x0, y0, z0, fx, fy, fz, fc), out);
}

/* One axis of the ghost weights: out[i] = in[i - d] / 2 + in[i] + in[i + d] / 2 along an axis of
 * n cells with stride d (cells beyond the padded grid are empty), for every line of a grid of
 * `cells` cells; the lines start at multiples of n d plus 0 .. d - 1. */
static void blur_axis(const v4f *restrict in, v4f *restrict out, size_t cells, size_t n, size_t d)
{
    for (size_t base = 0; base < cells; base += n * d)
        for (size_t a = 0; a < n; a++) {
            const v4f *c = in + base + a * d;
            const v4f *lo = a > 0 ? c - d : NULL, *hi = a + 1 < n ? c + d : NULL;
            v4f *o = out + base + a * d;
            for (size_t k = 0; k < d; k++) {
                v4f v = c[k];
                if (lo)
                    v += 0.5f * lo[k];
                if (hi)
                    v += 0.5f * hi[k];
                o[k] = v;
            }
        }
}

/* Every padded cell's ghost record (ghost_record) from the packed records (E, 1 if a boundary
 * cell, 0 else): the neighbours' weighted sums 2^-(|dx|+|dy|+|dz|) are a separable 3x3x3 filter of
 * them, three passes over the grid. ghost and scratch hold px py pz records each. */
static void ghost_grid(const float *packed, v4f *ghost, v4f *scratch, size_t px, size_t py, size_t pz)
{
    const v4f *rec = (const v4f *)(const void *)packed;
    const size_t cells = px * py * pz;
    blur_axis(rec, ghost, cells, px, 1);
    blur_axis(ghost, scratch, cells, py, px);
    blur_axis(scratch, ghost, cells, pz, px * py);
    for (size_t i = 0; i < cells; i++) {
        v4f g = ghost[i];
        if (rec[i][3] > 0.0f)
            ghost[i] = rec[i];
        else if (g[3] > 0.0f)
            ghost[i] = (v4f){g[0] / g[3], g[1] / g[3], g[2] / g[3], 1.0f};
        else
            ghost[i] = (v4f){0.0f, 0.0f, 0.0f, 0.0f};
    }
}

/* One pass over the padded grid writes both layouts: o->exitance (the fallback's) and o->packed
 * (the shading pass's corner reads). */
nacre_result nc_diff_compute_exitance(nc_diff_object *o, const float *const D[3], const float d_uniform[3],
                                      nacre_diffusion_source mode, int threads)
{
    const size_t nx = o->dims[0], ny = o->dims[1], nz = o->dims[2];
    const size_t px = nx + 2, py = ny + 2, pz = nz + 2;
    size_t padded, bytes;
    if (!nc_mul_size_ok(px, py, &padded) || !nc_mul_size_ok(padded, pz, &padded) ||
        !nc_mul_size_ok(padded, 4 * sizeof(float), &bytes))
        return nc_fail(o->ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: voxel grid too large");
    if (padded > o->packed_capacity) {
        nc_free(o->ctx, o->packed);
        o->packed_capacity = 0;
        o->exit_valid = false;
        o->packed = nc_alloc(o->ctx, bytes);
        if (!o->packed)
            return nc_fail(o->ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory for the exitance grid");
        o->packed_capacity = padded;
    }
    if (ny * nz > o->exit_span_capacity) {
        nc_free(o->ctx, o->exit_span);
        o->exit_span_capacity = 0;
        o->exit_valid = false;
        o->exit_span = nc_alloc(o->ctx, 2 * ny * nz * sizeof(uint32_t));
        if (!o->exit_span)
            return nc_fail(o->ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory for the exitance grid");
        o->exit_span_capacity = ny * nz;
    }
    if (memcmp(o->exit_dims, o->dims, sizeof(o->dims)) != 0)
        o->exit_valid = false;
    /* Without a valid record every row is written (and the padding with it) */
    const bool known = o->exit_valid;
    o->exit_valid = false;
    uint32_t *spans = o->exit_span;
    const uint8_t *solid = o->solid;
    const float *bscale = o->bscale;
    const float h = o->h, delta = NC_DIFF_SAMPLE_DEPTH * h, A = o->robin_a, inv_1mfdr = 1.0f / (1.0f - o->fdr);
    const bool face = mode == NACRE_SOURCE_FACE;
    float *pk = o->packed;
    const float *phi[3] = {o->phi[0], o->phi[1], o->phi[2]};
    float *E[3] = {o->exitance[0], o->exitance[1], o->exitance[2]};
#pragma omp parallel for schedule(static) num_threads(threads) if (padded > 65536)
    for (size_t z = 0; z < pz; z++)
        for (size_t y = 0; y < py; y++) {
            float *row = pk + 4 * px * (y + py * z);
            if (z == 0 || y == 0 || z == pz - 1 || y == py - 1) {
                if (!known)
                    memset(row, 0, 4 * px * sizeof(float));
                continue;
            }
            /* Only the row's first to last solid cell: exitance is read at solid cells only
             * (ghost_record, sample_field_cached), and packed is 0 elsewhere. At 128^3 these
             * spans hold a quarter of the rows' cells. */
            const size_t u = nx * ((y - 1) + ny * (z - 1));
            size_t lo = nc_first_nonzero(solid + u, nx), hi = lo;
            if (lo < nx)
                hi = nc_last_nonzero(solid + u, nx) + 1;
            else
                lo = hi = 0;
            uint32_t *sp = spans + 2 * ((y - 1) + ny * (z - 1));
            if (!known) {
                memset(row, 0, 4 * px * sizeof(float));
            } else {
                /* what is left of the old range (packed x = grid x + 1) */
                int64_t r[4];
                nc_range_minus(sp[0], sp[1], (int64_t)lo, (int64_t)hi, r);
                for (int k = 0; k < 4; k += 2)
                    if (r[k + 1] > r[k])
                        memset(row + 4 * (r[k] + 1), 0, 4 * (size_t)(r[k + 1] - r[k]) * sizeof(float));
            }
            sp[0] = (uint32_t)lo;
            sp[1] = (uint32_t)hi;
            /* k phi with k = D / (delta + 2 A D): nc_diff_exitance with the distance 2 delta.
             * Outside the domain phi is 0 (the solver's contract) and D finite (0, or the
             * uniform D), so e is 0 there without a test and the loop vectorizes. */
            for (int c = 0; c < 3; c++) {
                const float *restrict pc = phi[c] + u, *restrict dc = D[c] ? D[c] + u : NULL;
                const float du = dc ? 0.0f : d_uniform[c];
                float *restrict ec = E[c] + u;
                for (size_t x = lo; x < hi; x++) { /* -O3 unswitches the test of dc */
                    float e = nc_diff_exitance(pc[x], dc ? dc[x] : du, A, 2.0f * delta);
                    ec[x] = e > 0.0f ? e : 0.0f;
                }
                /* FACE: the lit faces' own term replaces q in place (once per solve), read at
                 * the surface (see the file). Its k uses the face distance h / 2: q is a face
                 * quantity. */
                float *q = face ? o->q[c] : NULL;
                if (q)
                    for (size_t x = lo; x < hi; x++)
                        if (solid[u + x] && q[u + x] != 0.0f) {
                            const float d = dc ? dc[x] : du, kf = 2.0f * d / (h + 4.0f * A * d);
                            q[u + x] *= 1.0f - 4.0f * kf * inv_1mfdr;
                        }
            }
            const size_t yy = y - 1, zz = z - 1;
            for (size_t x = lo; x < hi; x++) {
                float *v = row + 4 * (x + 1);
                const size_t i = u + x;
                const bool b = solid[i] && (x == 0 || x == nx - 1 || yy == 0 || yy == ny - 1 || zz == 0 ||
                                            zz == nz - 1 || !solid[i - 1] || !solid[i + 1] || !solid[i - nx] ||
                                            !solid[i + nx] || !solid[i - nx * ny] || !solid[i + nx * ny]);
                /* (k phi, g): the shading pass's sums give sum w k phi / sum w g (see above) */
                const float f = bscale ? bscale[i] : 1.0f;
                v[0] = b ? E[0][i] : 0.0f;
                v[1] = b ? E[1][i] : 0.0f;
                v[2] = b ? E[2][i] : 0.0f;
                v[3] = b ? 1.0f / f : 0.0f;
            }
        }
    memcpy(o->exit_dims, o->dims, sizeof(o->dims));
    o->exit_valid = true;
    /* Small grids: every padded cell's ghost record, so that the shading pass's many fallbacks
     * (a fifth to half of the pixels at 4^3) are one more corner read. Larger grids have few and
     * compute them per pixel (ghost_record), with the same records up to float rounding. */
    o->ghosts = false;
    if (padded <= NC_DIFF_GHOST_GRID_CELLS) {
        if (padded > o->ghost_capacity) {
            nc_free(o->ctx, o->packed_ghost);
            o->ghost_capacity = 0;
            o->packed_ghost = nc_alloc(o->ctx, 2 * bytes);
            if (!o->packed_ghost)
                return nc_fail(o->ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory for the exitance grid");
            o->ghost_capacity = padded;
        }
        ghost_grid(o->packed, (v4f *)(void *)o->packed_ghost, (v4f *)(void *)o->packed_ghost + padded, px, py, pz);
        o->ghosts = true;
    }
    return NACRE_OK;
}

/* The shading pass evaluates a padded record grid for 8 lanes of a batch at a time: lanes are
 * neighbouring pixels of one row and mostly share their cell (a cell spans about 20 pixels at
 * 28^3, 100 at 4^3), so a cell's 8 records are broadcast once (group_cache) and the trilinear
 * sums run 8 lanes wide with lerp8's operations per channel (the same formula; FMA contraction
 * may round the two differently in the last bit). */
typedef struct group_cache {
    int32_t cell;    /* offset of the cached cell's first record in the grid; -1: none */
    nc_v8f c[4][8];  /* corner k's value of channel c on every lane */
} group_cache;

static void group_cache_load(group_cache *gc, const float *grid, int32_t cell, size_t sy, size_t sz)
{
    const float *base = grid + cell;
    for (int k = 0; k < 8; k++) {
        const float *r = base + 4 * (size_t)(k & 1) + sy * (size_t)((k >> 1) & 1) + sz * (size_t)((k >> 2) & 1);
        for (int ch = 0; ch < 4; ch++)
            gc->c[ch][k] = nc_v8_splat(r[ch]);
    }
    gc->cell = cell;
}

/* lerp8 of one channel's corners c on 8 lanes */
static inline nc_v8f lerp8_v8(const nc_v8f c[8], nc_v8f fx, nc_v8f fy, nc_v8f fz, nc_v8f gx0, nc_v8f gy0,
                              nc_v8f gz0)
{
    nc_v8f c00 = c[0] * gx0 + c[1] * fx, c10 = c[2] * gx0 + c[3] * fx;
    nc_v8f c01 = c[4] * gx0 + c[5] * fx, c11 = c[6] * gx0 + c[7] * fx;
    return (c00 * gy0 + c10 * fy) * gz0 + (c01 * gy0 + c11 * fy) * fz;
}

/* The trilinear sums over grid (o->packed or o->packed_ghost) of 8 lanes: lane l at fractions
 * (x, y, z)[l] of the padded cell whose first record is at grid + cell[l], or 0 where
 * cell[l] < 0; into out[channel]. */
static void group_sums(const float *grid, size_t sy, size_t sz, nc_v8i cell, nc_v8f x, nc_v8f y, nc_v8f z,
                       group_cache *gc, nc_v8f out[4])
{
    const nc_v8f one = nc_v8_splat(1.0f);
    const nc_v8f gx0 = one - x, gy0 = one - y, gz0 = one - z;
    const int32_t c0 = cell[0];
    uint32_t done = nc_v8_bits(cell == c0);
    if (done == 0xffu) { /* the usual case: one cell */
        if (c0 >= 0 && gc->cell != c0)
            group_cache_load(gc, grid, c0, sy, sz);
        for (int ch = 0; ch < 4; ch++)
            out[ch] = c0 >= 0 ? lerp8_v8(gc->c[ch], x, y, z, gx0, gy0, gz0) : (nc_v8f){0};
        return;
    }
    /* Each distinct cell once; lanes take their cell's sums */
    for (int ch = 0; ch < 4; ch++)
        out[ch] = (nc_v8f){0};
    for (int l = 0; l < 8; l++) {
        const int32_t c = cell[l];
        const nc_v8i m = cell == c;
        if (l > 0) {
            if (done & (1u << l))
                continue;
            done |= nc_v8_bits(m);
        }
        if (c < 0)
            continue; /* out is 0 there already */
        if (gc->cell != c)
            group_cache_load(gc, grid, c, sy, sz);
        for (int ch = 0; ch < 4; ch++)
            out[ch] = nc_v8_sel(m, lerp8_v8(gc->c[ch], x, y, z, gx0, gy0, gz0), out[ch]);
    }
}

/* Lanes of the batch are processed 8 at a time from the G-buffer values to the radiance, with
 * the per-lane fallbacks (ghosts of larger grids, points outside the grid, FACE mode's q) run
 * per lane in the groups that need them. */
void nc_diff_subsurface_radiance(const void *user, uint32_t object, const nc_shade_batch *b,
                                 float out[3][NC_SHADE_BATCH])
{
    const nc_diff_state *st = user;
    const nc_diff_object *o = &st->objects[object];
    const uint32_t count = b->count;
    const float eta = o->eta, inv_eta2 = o->inv_eta2, radiance_k = o->radiance_k;
    /* The sample point NC_DIFF_SAMPLE_DEPTH cells below the surface, in padded grid coordinates:
     * the cell (its first record's offset in o->packed, -1 outside) and the fractions */
    const nc_v8i packed = (nc_v8i){0} - (int32_t)(o->solid && o->solid_count != 0 && o->packed);
    const float depth = NC_DIFF_SAMPLE_DEPTH * o->h, inv_h = 1.0f / o->h;
    const float ox = o->origin[0], oy = o->origin[1], oz = o->origin[2];
    const float lim_x = (float)(o->dims[0] + 1), lim_y = (float)(o->dims[1] + 1), lim_z = (float)(o->dims[2] + 1);
    const int32_t sy = 4 * ((int32_t)o->dims[0] + 2), sz = sy * ((int32_t)o->dims[1] + 2);
    const bool face_q = o->face_mode && o->q[0];
    group_cache gc_e, gc_g; /* not zeroed: 1 KB each, filled on first use */
    gc_e.cell = gc_g.cell = -1;
    /* One cache per field: the exitance is read below the surface and q at it, in other cells */
    field_cache fc_e = {.corner_valid = false, .ghost_valid = false}, fc_q = fc_e;
    for (uint32_t g = 0; g < count; g += 8) {
        const uint32_t n = count - g < 8 ? count - g : 8;
        const nc_v8f px = nc_v8_load(b->px + g), py = nc_v8_load(b->py + g), pz = nc_v8_load(b->pz + g);
        const nc_v8f nx = nc_v8_load(b->nx + g), ny = nc_v8_load(b->ny + g), nz = nc_v8_load(b->nz + g);
        const nc_v8f vx = nc_v8_load(b->vx + g), vy = nc_v8_load(b->vy + g), vz = nc_v8_load(b->vz + g);
        const nc_v8f zero = {0}, one = nc_v8_splat(1.0f);
        /* View factor (1 - F) / (pi (1 - F_diffuse)), nc_fresnel_dielectric_f with its
         * total-reflection branch as a select (the discarded lanes may hold NaN) */
        nc_v8f cos_o = nx * vx + ny * vy + nz * vz;
        cos_o = nc_v8_sel(cos_o < 0.0f, zero, nc_v8_sel(cos_o > 1.0f, one, cos_o));
        const nc_v8f sin2_t = (1.0f - cos_o * cos_o) * inv_eta2;
        const nc_v8f t = 1.0f - sin2_t;
        const nc_v8f cos_t = nc_v8_sqrt(nc_v8_sel(t > 0.0f, t, zero));
        const nc_v8f rs = (cos_o - eta * cos_t) / (cos_o + eta * cos_t);
        const nc_v8f rp = (eta * cos_o - cos_t) / (eta * cos_o + cos_t);
        const nc_v8f f = nc_v8_sel(sin2_t >= 1.0f, one, 0.5f * (rs * rs + rp * rp));
        const nc_v8f k = (1.0f - f) * radiance_k;
        /* Padded grid coordinates: relative to the padded grid's cell centres (hence + 1 - 0.5).
         * o->packed holds exitance RGB and solid weight, 0 outside the domain and in the
         * padding, so the solid test is folded into the data (a corner outside adds w x 0);
         * o->packed_ghost is read at the same coordinates, with sample_field_cached's weights
         * and corners. Lanes outside compute garbage here and are masked (gx may be NaN). */
        const nc_v8f gx = (px - nx * depth - ox) * inv_h + 0.5f, gy = (py - ny * depth - oy) * inv_h + 0.5f,
                     gz = (pz - nz * depth - oz) * inv_h + 0.5f;
        const nc_v8i live = nc_v8_first(n);
        const nc_v8i inside = packed & live & (gx >= 0.0f) & (gy >= 0.0f) & (gz >= 0.0f) & (gx < lim_x) &
                              (gy < lim_y) & (gz < lim_z);
        const nc_v8f x = nc_v8_sel(inside, gx, zero), y = nc_v8_sel(inside, gy, zero), z = nc_v8_sel(inside, gz, zero);
        /* non-negative: truncation is floor */
        const nc_v8i x0 = __builtin_convertvector(x, nc_v8i), y0 = __builtin_convertvector(y, nc_v8i),
                     z0 = __builtin_convertvector(z, nc_v8i);
        const nc_v8f fx = x - __builtin_convertvector(x0, nc_v8f), fy = y - __builtin_convertvector(y0, nc_v8f),
                     fz = z - __builtin_convertvector(z0, nc_v8f);
        const nc_v8i cell = nc_v8i_sel(inside, 4 * x0 + sy * y0 + sz * z0, (nc_v8i){0} - 1);
        nc_v8f E[4];
        group_sums(o->packed, (size_t)sy, (size_t)sz, cell, fx, fy, fz, &gc_e, E);
        nc_v8i valid = E[3] > 1e-6f;
        const nc_v8f inv = 1.0f / E[3];
        for (int c = 0; c < 3; c++)
            E[c] = nc_v8_sel(valid, E[c] * inv, E[c]);
        /* No solid corner with weight: the ghost fallback, its records read from o->packed_ghost
         * when it holds this frame's (small grids), else computed per lane */
        const nc_v8i need_ghost = inside & ~valid;
        const bool ghosts = nc_v8_bits(need_ghost) != 0;
        if (ghosts && o->ghosts) {
            nc_v8f G[4];
            group_sums(o->packed_ghost, (size_t)sy, (size_t)sz, cell, fx, fy, fz, &gc_g, G);
            /* ghost_result: the records' mean where a corner with weight has one, else none */
            const nc_v8i has = G[3] > 0.0f;
            for (int c = 0; c < 3; c++)
                E[c] = nc_v8_sel(need_ghost, nc_v8_sel(has, G[c] / G[3], zero), E[c]);
            valid = nc_v8i_sel(need_ghost, has, valid);
        }
        /* The rare per-lane paths */
        const bool outside = nc_v8_bits(live & ~inside) != 0;
        if ((ghosts && !o->ghosts) || outside || face_q) {
            float e8[3][8];
            int32_t v8[8];
            for (int c = 0; c < 3; c++)
                nc_v8_store(e8[c], E[c]);
            nc_v8i_store(v8, valid);
            for (uint32_t l = 0; l < n; l++) {
                const uint32_t i = g + l;
                float e[3];
                if (inside[l] && !v8[l] && !o->ghosts) {
                    int xi = (int)gx[l], yi = (int)gy[l], zi = (int)gz[l]; /* padded: cell xi - 1 */
                    v4f acc = ghost_sum(o, o->exitance, xi - 1, yi - 1, zi - 1, gx[l] - (float)xi,
                                        gy[l] - (float)yi, gz[l] - (float)zi, &fc_e);
                    v8[l] = ghost_result(acc, e) ? -1 : 0;
                    for (int c = 0; c < 3; c++)
                        e8[c][l] = e[c];
                }
                nc_vec3 p = nc_v3(b->px[i], b->py[i], b->pz[i]);
                if (!inside[l]) {
                    nc_vec3 nn = nc_v3(b->nx[i], b->ny[i], b->nz[i]);
                    v8[l] = sample_field_cached(o, o->exitance, nc_sub(p, nc_scale(nn, depth)), &fc_e, e) ? -1 : 0;
                    for (int c = 0; c < 3; c++)
                        e8[c][l] = e[c];
                }
                float qt[3];
                if (v8[l] && face_q && sample_field_cached(o, o->q, p, &fc_q, qt))
                    for (int c = 0; c < 3; c++)
                        e8[c][l] = fmaxf(e8[c][l] + qt[c], 0.0f);
            }
            for (int c = 0; c < 3; c++)
                E[c] = nc_v8_load(e8[c]);
            valid = nc_v8i_load(v8);
        }
        for (int c = 0; c < 3; c++)
            nc_v8_store(out[c] + g, nc_v8_sel(valid, E[c] * k, zero));
    }
    if (o->single)
        nc_diff_single_radiance(st, object, b, out);
}
