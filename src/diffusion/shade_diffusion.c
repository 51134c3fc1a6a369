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
 * Interpolation: trilinear between cell centres over solid cells only (weights renormalized), so
 * empty space never leaks in; with no solid corner, the nearest solid cell within one cell.
 *
 * Radiance towards the viewer:
 *   L = E (1 - F(cos_o, eta)) / (pi (1 - F_diffuse(eta))),
 * whose projected-solid-angle integral is exactly E (2 pi int (1 - F) mu dmu = pi (1 - F_diffuse)).
 * The seed's eq. 4.9 (after Arbree et al. 2011) writes L = Ft / (4 pi) [...] with the fluence
 * terms and omits the 1 / eta^2 compression of radiance crossing into the lower index; here E is
 * already the flux that leaves, and the normalization above distributes it over the outside
 * hemisphere, which accounts for that compression.
 *
 * The shading pass calls nc_diff_subsurface_radiance once per batch of pixels (shade.h): the
 * per-pixel arithmetic runs as vectorized loops over the batch, and only the corner reads of
 * the padded exitance grid and the nearest-cell fallback (with the batch's cells cached) run per
 * pixel; the values are those of nc_diff_exitance_at, bit for bit.
 */
#include "diffusion/pipeline.h"
#include "core/optics.h"

#include <math.h>
#include <string.h>

/* Trilinear interpolation of a per-cell field (3 channels) at p over the solid cells around it
 * (weights renormalized); with no solid corner with weight, the nearest solid cell centre among
 * the 27 around p's cell. For many nearby points (a batch of pixels) the cache keeps the solid
 * corners of the last interpolation cell and the solid cells of the last 27-cell neighbourhood,
 * so that points in the same cells skip the bounds and solid tests; the sums and the search
 * visit the same cells in the same order either way. At coarse grids many pixels take the
 * nearest-cell fallback, and neighbouring pixels share their cells. */
typedef struct field_cache {
    int corner_key[3], near_key[3];
    bool corner_valid, near_valid;
    int corner_n, near_n;
    int corner_k[8];
    size_t corner_i[8], near_i[27];
    float near_x[27], near_y[27], near_z[27];
} field_cache;

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
    if (!isfinite(gx) || !isfinite(gy) || !isfinite(gz))
        return false;
    int x0 = (int)floorf(gx), y0 = (int)floorf(gy), z0 = (int)floorf(gz);
    float fx = gx - (float)x0, fy = gy - (float)y0, fz = gz - (float)z0;
    if (!fc->corner_valid || fc->corner_key[0] != x0 || fc->corner_key[1] != y0 || fc->corner_key[2] != z0) {
        fc->corner_n = 0;
        for (int k = 0; k < 8; k++) {
            int x = x0 + (k & 1), y = y0 + ((k >> 1) & 1), z = z0 + ((k >> 2) & 1);
            if (x < 0 || y < 0 || z < 0 || x >= nx || y >= ny || z >= nz)
                continue;
            size_t i = (size_t)x + (size_t)nx * ((size_t)y + (size_t)ny * (size_t)z);
            if (!o->solid[i])
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
    int cx = (int)floorf(gx + 0.5f), cy = (int)floorf(gy + 0.5f), cz = (int)floorf(gz + 0.5f);
    if (!fc->near_valid || fc->near_key[0] != cx || fc->near_key[1] != cy || fc->near_key[2] != cz) {
        fc->near_n = 0;
        for (int dz = -1; dz <= 1; dz++)
            for (int dy = -1; dy <= 1; dy++)
                for (int dx = -1; dx <= 1; dx++) {
                    int x = cx + dx, y = cy + dy, z = cz + dz;
                    if (x < 0 || y < 0 || z < 0 || x >= nx || y >= ny || z >= nz)
                        continue;
                    size_t i = (size_t)x + (size_t)nx * ((size_t)y + (size_t)ny * (size_t)z);
                    if (!o->solid[i])
                        continue;
                    fc->near_i[fc->near_n] = i;
                    fc->near_x[fc->near_n] = (float)x;
                    fc->near_y[fc->near_n] = (float)y;
                    fc->near_z[fc->near_n++] = (float)z;
                }
        fc->near_key[0] = cx;
        fc->near_key[1] = cy;
        fc->near_key[2] = cz;
        fc->near_valid = true;
    }
    float best = INFINITY;
    size_t best_i = 0;
    for (int j = 0; j < fc->near_n; j++) {
        float ex = fc->near_x[j] - gx, ey = fc->near_y[j] - gy, ez = fc->near_z[j] - gz;
        float d2 = ex * ex + ey * ey + ez * ez;
        if (d2 < best) {
            best = d2;
            best_i = fc->near_i[j];
        }
    }
    if (!isfinite(best))
        return false;
    for (int c = 0; c < 3; c++)
        out[c] = field[c][best_i];
    return true;
}

/* sample_field_cached for a single point. */
static bool sample_field(const nc_diff_object *o, float *const field[3], nc_vec3 p, float out[3])
{
    field_cache fc = {.corner_valid = false, .near_valid = false};
    return sample_field_cached(o, field, p, &fc, out);
}

/* One pass over the padded grid writes both layouts: o->exitance (the fallback's and
 * nc_diff_exitance_at's) and o->packed (the shading pass's corner reads). */
nacre_result nc_diff_compute_exitance(nc_diff_object *o, const float *const D[3], nacre_diffusion_source mode,
                                      int threads)
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
    if (ny * nz > o->row_live_capacity) {
        nc_free(o->ctx, o->row_live);
        o->row_live_capacity = 0;
        o->exit_valid = false;
        o->row_live = nc_alloc(o->ctx, ny * nz);
        if (!o->row_live)
            return nc_fail(o->ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory for the exitance grid");
        o->row_live_capacity = ny * nz;
    }
    if (memcmp(o->exit_dims, o->dims, sizeof(o->dims)) != 0)
        o->exit_valid = false;
    /* Without a valid record every row is written (and the padding with it) */
    const bool known = o->exit_valid;
    uint8_t *live = o->row_live;
    const uint8_t *solid = o->solid;
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
            const size_t u = nx * ((y - 1) + ny * (z - 1));
            const bool any = memchr(solid + u, 1, nx) != NULL;
            uint8_t *was = &live[(y - 1) + ny * (z - 1)];
            if (known && !any && !*was)
                continue;
            *was = any;
            /* k phi with k = D / (delta + 2 A D): nc_diff_exitance with the distance 2 delta.
             * Outside the domain phi and D are 0 (the solver's contract), so e is 0 there
             * without a test and the loop vectorizes. */
            for (int c = 0; c < 3; c++) {
                const float *restrict pc = phi[c] + u, *restrict dc = D[c] + u;
                float *restrict ec = E[c] + u;
                for (size_t x = 0; x < nx; x++) {
                    float e = nc_diff_exitance(pc[x], dc[x], A, 2.0f * delta);
                    ec[x] = e > 0.0f ? e : 0.0f;
                }
                /* FACE: the lit faces' own term replaces q in place (once per solve), read at
                 * the surface (see the file). Its k uses the face distance h / 2: q is a face
                 * quantity. */
                float *q = face ? o->q[c] : NULL;
                if (q)
                    for (size_t x = 0; x < nx; x++)
                        if (solid[u + x] && q[u + x] != 0.0f) {
                            float kf = 2.0f * dc[x] / (h + 4.0f * A * dc[x]);
                            q[u + x] *= 1.0f - 4.0f * kf * inv_1mfdr;
                        }
            }
            memset(row, 0, 4 * sizeof(float));
            memset(row + 4 * (px - 1), 0, 4 * sizeof(float));
            for (size_t x = 0; x < nx; x++) {
                float *v = row + 4 * (x + 1);
                v[0] = E[0][u + x];
                v[1] = E[1][u + x];
                v[2] = E[2][u + x];
                v[3] = solid[u + x] ? 1.0f : 0.0f;
            }
        }
    memcpy(o->exit_dims, o->dims, sizeof(o->dims));
    o->exit_valid = true;
    return NACRE_OK;
}

/* sample_field over o->packed for the exitance: the same weights and corners, with the solid
 * test folded into the data (exitance is 0 and the 4th value is 0 outside the domain and in
 * the padding, so adding w x 0 leaves the sums unchanged) and no per-corner branch: one
 * 4-wide multiply-add per corner. Points farther than half a cell outside the grid, or with no
 * solid corner with weight, take sample_field (the nearest-cell fallback). */
typedef float v4f __attribute__((vector_size(16)));

/* Grid coordinates of p for padded_sum: relative to the padded grid's cell centres (hence
 * + 1 - 0.5). */
static inline void padded_coords(const nc_diff_object *o, float inv_h, float px, float py, float pz, float *gx,
                                 float *gy, float *gz)
{
    *gx = (px - o->origin[0]) * inv_h + 0.5f;
    *gy = (py - o->origin[1]) * inv_h + 0.5f;
    *gz = (pz - o->origin[2]) * inv_h + 0.5f;
}

/* The trilinear sums (exitance RGB, solid weight) at padded coordinates inside the padded grid. */
static inline v4f padded_sum(const nc_diff_object *o, float gx, float gy, float gz)
{
    int x0 = (int)gx, y0 = (int)gy, z0 = (int)gz; /* non-negative: truncation is floor */
    float fx = gx - (float)x0, fy = gy - (float)y0, fz = gz - (float)z0;
    const size_t sy = 4 * ((size_t)o->dims[0] + 2), sz = sy * ((size_t)o->dims[1] + 2);
    const float *base = o->packed + 4 * (size_t)x0 + sy * (size_t)y0 + sz * (size_t)z0;
    v4f c[8];
    for (int k = 0; k < 8; k++)
        memcpy(&c[k], base + 4 * (size_t)(k & 1) + sy * (size_t)((k >> 1) & 1) + sz * (size_t)((k >> 2) & 1),
               sizeof(v4f));
    /* Trilinear as three lerps: the same weights as the per-corner products of sample_field. */
    const float gx0 = 1.0f - fx, gy0 = 1.0f - fy, gz0 = 1.0f - fz;
    v4f c00 = c[0] * gx0 + c[1] * fx, c10 = c[2] * gx0 + c[3] * fx;
    v4f c01 = c[4] * gx0 + c[5] * fx, c11 = c[6] * gx0 + c[7] * fx;
    return (c00 * gy0 + c10 * fy) * gz0 + (c01 * gy0 + c11 * fy) * fz;
}

static inline bool padded_inside(const nc_diff_object *o, float gx, float gy, float gz)
{
    return gx >= 0.0f && gy >= 0.0f && gz >= 0.0f && gx < (float)(o->dims[0] + 1) &&
           gy < (float)(o->dims[1] + 1) && gz < (float)(o->dims[2] + 1);
}

static bool sample_exitance(const nc_diff_object *o, nc_vec3 p, float out[3])
{
    if (!o->solid || o->solid_count == 0 || !o->packed)
        return sample_field(o, o->exitance, p, out);
    float gx, gy, gz;
    padded_coords(o, 1.0f / o->h, p.x, p.y, p.z, &gx, &gy, &gz);
    if (!padded_inside(o, gx, gy, gz))
        return sample_field(o, o->exitance, p, out);
    v4f acc = padded_sum(o, gx, gy, gz);
    if (!(acc[3] > 1e-6f))
        return sample_field(o, o->exitance, p, out);
    float inv = 1.0f / acc[3];
    for (int k = 0; k < 3; k++)
        out[k] = acc[k] * inv;
    return true;
}

bool nc_diff_exitance_at(const nc_diff_object *o, nc_vec3 p, nc_vec3 n, bool face_mode, float out[3])
{
    if (!sample_exitance(o, nc_sub(p, nc_scale(n, NC_DIFF_SAMPLE_DEPTH * o->h)), out))
        return false;
    float qt[3];
    if (face_mode && o->q[0] && sample_field(o, o->q, p, qt))
        for (int c = 0; c < 3; c++)
            out[c] = fmaxf(out[c] + qt[c], 0.0f);
    return true;
}

void nc_diff_subsurface_radiance(const void *user, uint32_t object, const nc_shade_batch *b,
                                 float out[3][NC_SHADE_BATCH])
{
    const nc_diff_state *st = user;
    const nc_diff_object *o = &st->objects[object];
    const uint32_t count = b->count;
    /* nc_diff_exitance_at and the view factor for the whole batch, split into loops: the
     * arithmetic per lane vectorizes, and only the corner reads (padded_sum) and the rare
     * fallbacks (sample_field) run per pixel. The values are the scalar functions' exactly. */
    float k[NC_SHADE_BATCH], gx[NC_SHADE_BATCH], gy[NC_SHADE_BATCH], gz[NC_SHADE_BATCH];
    float E[4][NC_SHADE_BATCH];
    int32_t inside[NC_SHADE_BATCH], valid[NC_SHADE_BATCH];
    /* (1 - F) / (pi (1 - F_diffuse)) with nc_fresnel_dielectric_f's total-reflection branch as a
     * select (nc_shade_sel; the discarded lanes may hold NaN). */
    const float eta = o->eta, inv_eta2 = o->inv_eta2, radiance_k = o->radiance_k;
    for (uint32_t i = 0; i < count; i++) {
        float cos_o = b->nx[i] * b->vx[i] + b->ny[i] * b->vy[i] + b->nz[i] * b->vz[i];
        cos_o = nc_shade_sel(cos_o < 0.0f, 0.0f, nc_shade_sel(cos_o > 1.0f, 1.0f, cos_o));
        float sin2_t = (1.0f - cos_o * cos_o) * inv_eta2;
        float t = 1.0f - sin2_t;
        float cos_t = sqrtf(nc_shade_sel(t > 0.0f, t, 0.0f));
        float rs = (cos_o - eta * cos_t) / (cos_o + eta * cos_t);
        float rp = (eta * cos_o - cos_t) / (eta * cos_o + cos_t);
        float f = nc_shade_sel(sin2_t >= 1.0f, 1.0f, 0.5f * (rs * rs + rp * rp));
        k[i] = (1.0f - f) * radiance_k;
    }
    /* The sample point NC_DIFF_SAMPLE_DEPTH cells below the surface, in padded grid coordinates */
    const bool packed = o->solid && o->solid_count != 0 && o->packed;
    const float depth = NC_DIFF_SAMPLE_DEPTH * o->h, inv_h = 1.0f / o->h;
    const float lim_x = (float)(o->dims[0] + 1), lim_y = (float)(o->dims[1] + 1), lim_z = (float)(o->dims[2] + 1);
    for (uint32_t i = 0; i < count; i++) {
        padded_coords(o, inv_h, b->px[i] - b->nx[i] * depth, b->py[i] - b->ny[i] * depth,
                      b->pz[i] - b->nz[i] * depth, &gx[i], &gy[i], &gz[i]);
        inside[i] = packed & (gx[i] >= 0.0f) & (gy[i] >= 0.0f) & (gz[i] >= 0.0f) & (gx[i] < lim_x) &
                    (gy[i] < lim_y) & (gz[i] < lim_z);
    }
    for (uint32_t i = 0; i < count; i++) {
        v4f acc = {0.0f, 0.0f, 0.0f, 0.0f};
        if (inside[i])
            acc = padded_sum(o, gx[i], gy[i], gz[i]);
        for (int c = 0; c < 4; c++)
            E[c][i] = acc[c];
    }
    for (uint32_t i = 0; i < count; i++) {
        valid[i] = E[3][i] > 1e-6f;
        float inv = 1.0f / E[3][i];
        for (int c = 0; c < 3; c++)
            E[c][i] = nc_shade_sel(valid[i], E[c][i] * inv, E[c][i]);
    }
    /* One cache per field: the exitance is read below the surface and q at it, in other cells */
    field_cache fc_e = {.corner_valid = false, .near_valid = false}, fc_q = fc_e;
    for (uint32_t i = 0; i < count; i++) {
        nc_vec3 p = nc_v3(b->px[i], b->py[i], b->pz[i]);
        if (!valid[i]) {
            /* Outside the padded grid or no solid corner: sample_exitance's fallback */
            float e[3];
            nc_vec3 n = nc_v3(b->nx[i], b->ny[i], b->nz[i]);
            valid[i] = sample_field_cached(o, o->exitance, nc_sub(p, nc_scale(n, depth)), &fc_e, e);
            for (int c = 0; c < 3; c++)
                E[c][i] = e[c];
        }
        float qt[3];
        if (valid[i] && o->face_mode && o->q[0] && sample_field_cached(o, o->q, p, &fc_q, qt))
            for (int c = 0; c < 3; c++)
                E[c][i] = fmaxf(E[c][i] + qt[c], 0.0f);
    }
    for (int c = 0; c < 3; c++)
        for (uint32_t i = 0; i < count; i++)
            out[c][i] = nc_shade_sel(valid[i], E[c][i] * k[i], 0.0f);
}
