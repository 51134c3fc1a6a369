/*
 * tsm.c: translucent shadow maps and injection (Blanchard 2012 sections 4.3 and 4.4).
 *
 * Translucent shadow map: for each light, the solid voxels of an object are seen from the light
 * and each texel keeps the flux that the light sends through it into the material, with the cell
 * and the face (seed table 4.1) it enters by. The seed rasterizes the exposed voxel faces with a
 * depth test, which we do for directional lights (raster_band: half-open faces, so no cracks
 * or double coverage at shared edges); for point and spot lights we cast one ray per texel
 * centre through the grid instead (Amanatides-Woo traversal), which needs no face list. Both
 * keep, per texel, the nearest exposed face that faces the light: the first solid cell a ray
 * reaches is entered through a face whose neighbour is not solid, and a ray enters a face only
 * from its front. The map's side follows the voxel size (adapt_size), capped by tsm_size.
 *   - Directional light: an orthographic map over the bounding box of the solid cells, seen along
 *     the light; texel flux = E x texel area (perpendicular to the light) x Ft.
 *   - Point and spot lights: a perspective map from the light around that box (any frustum, so
 *     asymmetric), or a cube map (six 90-degree faces) when the light is inside or too close to
 *     the box; texel flux = I x solid angle of the texel x Ft (= I / d^2 x perpendicular area),
 *     with the spot profile of scene/lights.h (as phong.c).
 *   - Ft = 1 - F(cos, eta), F the Fresnel reflectance at the angle to the voxel face normal.
 *   - Occlusion by other objects: the renderer's shadow map of the light is looked up where the
 *     texel's ray enters the object's box (grown by one cell). The object itself lies beyond that
 *     point, so it cannot shadow itself there (its own occlusion is the traversal's depth test);
 *     another object intersecting the box does not shadow the part inside the box.
 * The map is produced and consumed in bands of rows, so memory stays bounded at 8192^2 texels.
 * For the single-scattering option (o->single) each view also keeps, whole, what single.c needs
 * of its texels (nc_diff_lmap: the entry's distance along the texel's ray, the transmitted part
 * per unit strength, the entry normal), 20 bytes a texel (a 32^3 grid: maps of ~200^2 texels).
 *
 * Injection (seed 4.4): each hit texel adds its flux to the per-cell source (W per cell) in one
 * of two ways (settings->diffusion.source):
 *   - FACE (the seed): the flux enters through the Robin condition of the lit face, see
 *     inject_face() for the derivation of S_i += flux 8 D / ((h + 4 A D) (1 - Fdr)).
 *   - VOLUME (default): the refracted ray (Snell at the voxel face) is marched through the solid
 *     cells and each cell receives the scattered part of the reduced intensity it attenuates,
 *     flux alpha' (exp(-tau_0) - exp(-tau_1)), optical depth accumulated cell by cell, until the
 *     remaining fraction is below 1e-4 or the ray leaves the domain (the rest passes through;
 *     notches of the voxel staircase up to two cells wide do not count as leaving, see
 *     inject_volume).
 * Injection runs in parallel over texels; deposits are summed in 64-bit fixed point (integer
 * addition is associative), so sources do not depend on the thread count. The coarse
 * levels of the solver get their sources by restriction inside the solver (the seed injects on
 * every level of its pyramid; diffusion.h restricts S itself).
 */
#include "diffusion/pipeline.h"
#include "core/optics.h"
#include "scene/lights.h"
#include "volume/volume.h"

#include <math.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif

/* Texels per band of the map (see the file comment). */
#define BAND_TEXELS (1u << 20)
/* Volume injection stops when every channel's remaining reduced intensity is below this. */
#define VOLUME_CUTOFF 1e-4f
/* PCF radius (texels) of the renderer's shadow maps when they occlude a TSM texel: the TSM is
 * usually finer than the shadow map, so a small kernel suffices and keeps lookups cheap. */
#define TSM_PCF_RADIUS 0.5f
/* Largest total size of the per-thread injection accumulators before threads share one set
 * with atomic adds instead. */
#define PRIVATE_BYTES ((size_t)64 << 20)
/* Longest run of non-solid cells (path length in cells) the volume march crosses as medium. */
#define MAX_GAP 2.0f
/* A perspective map is used while every corner of the box is within this tangent of its axis. */
#define MAX_FRUSTUM_TAN 3.0f
/* Texels per voxel side the map needs (see adapt_size): the map only has to resolve the exposed
 * voxel faces, so its resolution follows the grid, with settings->diffusion.tsm_size as the maximum. */
#define TEXELS_PER_CELL 4.0f
/* Most mesh triangles per map texel for which the map takes the light's entry from the mesh
 * (mesh_band); finer meshes keep the voxel staircase's entry. */
#define MESH_PER_TEXEL 4.0
/* Texels per batch of occlusion lookups (raster_band). */
#define SHADOW_BATCH 64
/* Smallest adapted map side. */
#define MIN_TSM_SIZE 16
/* Volume injection from a rasterized (orthographic, parallel-ray) map marches one refracted ray
 * per 2x2 block of texels when the four land on the same voxel face: the block's flux from its
 * flux-weighted mean entry point. The rays of a block share their direction, and the entry
 * points differ by under half a texel (1/8 of a cell at 4 texels per cell), so the deposits
 * differ from four separate marches only at that sub-cell scale, while the marches (the
 * injection's cost) fall by about 4. Blocks that straddle faces march each texel. The map's
 * flux (o->tsm_flux) is still summed per texel. */

typedef struct tsm_view {
    bool ortho;
    nc_vec3 origin;           /* ortho: ray origin for (a, b) = (0, 0); persp: light position (grid) */
    nc_vec3 f, r, u;          /* axis of travel and the map's two in-plane directions */
    float a0, a1, b0, b1;     /* extents along r, u: grid units (ortho) or tangents (persp) */
    int32_t size;
    float ortho_area;         /* ortho: world area of one texel */
} tsm_view;

typedef struct tsm_light {
    const nacre_light_desc *desc;
    const nc_shadow_map *shadow; /* NULL: not consulted */
    float pcf_radius, bias;
} tsm_light;

static void texels_free(nacre_context *ctx, nc_tsm_band *b)
{
    nc_free(ctx, b->cell);
    nc_free(ctx, b->face);
    nc_free(ctx, b->weight);
    nc_free(ctx, b->pos);
    nc_free(ctx, b->dir);
    b->cell = NULL;
    b->face = NULL;
    b->weight = b->pos = b->dir = NULL;
    b->capacity = 0;
}

void nc_tsm_band_free(nacre_context *ctx, nc_tsm_band *b)
{
    texels_free(ctx, b);
    nc_free(ctx, b->scratch);
    nc_free(ctx, b->depth);
    nc_free(ctx, b->fbox);
    nc_free(ctx, b->tbox);
    nc_free(ctx, b->hit);
    nc_free(ctx, b->mesh_t);
    nc_free(ctx, b->mesh_n);
    nc_free(ctx, b->mesh_key);
    nc_free(ctx, b->vproj);
    memset(b, 0, sizeof(*b));
}

static nacre_result band_reserve(nacre_context *ctx, nc_tsm_band *b, size_t texels)
{
    if (b->capacity >= texels)
        return NACRE_OK;
    texels_free(ctx, b);
    b->cell = nc_alloc(ctx, texels * sizeof(*b->cell));
    b->face = nc_alloc(ctx, texels * sizeof(*b->face));
    b->weight = nc_alloc(ctx, texels * sizeof(*b->weight));
    b->pos = nc_alloc(ctx, 3 * texels * sizeof(*b->pos));
    b->dir = nc_alloc(ctx, 3 * texels * sizeof(*b->dir));
    if (!b->cell || !b->face || !b->weight || !b->pos || !b->dir) {
        texels_free(ctx, b);
        return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory for a translucent shadow map");
    }
    b->capacity = texels;
    return NACRE_OK;
}

/* The spot's profile (scene/lights.h) in direction dir from the light, as phong.c. */
static float spot_falloff(const nacre_light_desc *l, nc_vec3 dir)
{
    float c = nc_dot(nc_normalize(nc_v3a(l->direction)), dir);
    return nc_spot_falloff(l->falloff, c, cosf(l->outer_angle * NC_DEG2RAD), cosf(l->inner_angle * NC_DEG2RAD));
}

/* The face a ray enters when it steps along `axis` in direction `step` (table 4.1). */
static inline uint8_t entry_face(int axis, int step)
{
    static const uint8_t base[3] = {NC_FACE_XN, NC_FACE_YN, NC_FACE_ZN};
    return (uint8_t)(base[axis] + (step < 0 ? 1 : 0));
}

/* Slab test of ray (o, d) against box [lo, hi]: entry and exit parameters and the entry axis. */
static bool ray_box(const float o[3], const float d[3], const float lo[3], const float hi[3], float *tin,
                    float *tout, int *axis)
{
    float t0 = -INFINITY, t1 = INFINITY;
    if (!nc_ray_box(o, d, lo, hi, &t0, &t1, axis) || !(t1 >= t0) || t1 <= 0.0f)
        return false;
    *tin = t0;
    *tout = t1;
    return true;
}

/* First solid cell along the ray (grid coordinates, unit d) and the face it is entered by. False
 * when the ray misses the solid cells or starts inside one (a light inside the object). */
static bool cast_ray(const nc_diff_object *o, const float org[3], const float d[3], uint32_t *cell_out,
                     uint8_t *face_out, float entry[3])
{
    float lo[3], hi[3];
    for (int k = 0; k < 3; k++) {
        lo[k] = (float)o->lo[k];
        hi[k] = (float)o->hi[k];
    }
    float tin, tout;
    int axis;
    if (!ray_box(org, d, lo, hi, &tin, &tout, &axis))
        return false;
    int c[3], step[3], ilo[3], ihi[3];
    float tmax[3], tdelta[3], t;
    for (int k = 0; k < 3; k++) {
        ilo[k] = (int)o->lo[k];
        ihi[k] = (int)o->hi[k] - 1;
    }
    int entered = -1; /* axis of the last step, -1: none (the ray starts inside the box) */
    if (tin > 0.0f) {
        t = tin;
        for (int k = 0; k < 3; k++) {
            int v = (int)floorf(org[k] + d[k] * t);
            c[k] = v < ilo[k] ? ilo[k] : (v > ihi[k] ? ihi[k] : v);
        }
        c[axis] = d[axis] > 0.0f ? ilo[axis] : ihi[axis];
        entered = axis;
    } else {
        t = 0.0f;
        for (int k = 0; k < 3; k++) {
            int v = (int)floorf(org[k]);
            c[k] = v < ilo[k] ? ilo[k] : (v > ihi[k] ? ihi[k] : v);
        }
    }
    for (int k = 0; k < 3; k++) {
        if (d[k] > 0.0f) {
            step[k] = 1;
            tmax[k] = ((float)c[k] + 1.0f - org[k]) / d[k];
            tdelta[k] = 1.0f / d[k];
        } else if (d[k] < 0.0f) {
            step[k] = -1;
            tmax[k] = ((float)c[k] - org[k]) / d[k];
            tdelta[k] = -1.0f / d[k];
        } else {
            step[k] = 0;
            tmax[k] = tdelta[k] = INFINITY;
        }
    }
    const size_t nx = o->dims[0], ny = o->dims[1];
    for (;;) {
        size_t idx = (size_t)c[0] + nx * ((size_t)c[1] + ny * (size_t)c[2]);
        if (o->solid[idx]) {
            if (entered < 0)
                return false;
            *cell_out = (uint32_t)idx;
            *face_out = entry_face(entered, step[entered]);
            for (int k = 0; k < 3; k++)
                entry[k] = org[k] + d[k] * t;
            /* On the face plane exactly, so the volume march starts inside the right cell. */
            entry[entered] = (float)(step[entered] > 0 ? c[entered] : c[entered] + 1);
            return true;
        }
        int k = tmax[0] < tmax[1] ? (tmax[0] < tmax[2] ? 0 : 2) : (tmax[1] < tmax[2] ? 1 : 2);
        if (!isfinite(tmax[k]))
            return false;
        t = tmax[k];
        tmax[k] += tdelta[k];
        c[k] += step[k];
        entered = k;
        if (c[k] < ilo[k] || c[k] > ihi[k])
            return false;
    }
}

/* The views of one light: 1 (orthographic or frustum) or 6 (cube). */
static int light_views(const nc_diff_object *o, const nacre_light_desc *l, int32_t size, tsm_view v[6])
{
    nc_vec3 lo = nc_v3((float)o->lo[0], (float)o->lo[1], (float)o->lo[2]);
    nc_vec3 hi = nc_v3((float)o->hi[0], (float)o->hi[1], (float)o->hi[2]);
    nc_vec3 centre = nc_scale(nc_add(lo, hi), 0.5f);
    float diag = nc_length(nc_sub(hi, lo));
    nc_vec3 corner[8];
    for (int k = 0; k < 8; k++)
        corner[k] = nc_v3((k & 1) ? hi.x : lo.x, (k & 2) ? hi.y : lo.y, (k & 4) ? hi.z : lo.z);
    if (l->type == NACRE_LIGHT_DIRECTIONAL) {
        tsm_view *w = &v[0];
        w->ortho = true;
        w->size = size;
        w->f = nc_normalize(nc_v3a(l->direction));
        nc_basis(w->f, &w->r, &w->u);
        w->a0 = w->b0 = INFINITY;
        w->a1 = w->b1 = -INFINITY;
        for (int k = 0; k < 8; k++) {
            float a = nc_dot(corner[k], w->r), b = nc_dot(corner[k], w->u);
            w->a0 = fminf(w->a0, a);
            w->a1 = fmaxf(w->a1, a);
            w->b0 = fminf(w->b0, b);
            w->b1 = fmaxf(w->b1, b);
        }
        /* Ray origins on a plane in front of the box: origin + r a + u b, a and b absolute. */
        w->origin = nc_sub(nc_sub(nc_sub(centre, nc_scale(w->r, nc_dot(centre, w->r))),
                                  nc_scale(w->u, nc_dot(centre, w->u))),
                           nc_scale(w->f, diag + 1.0f));
        float h = o->h;
        w->ortho_area = (w->a1 - w->a0) * (w->b1 - w->b0) / ((float)size * (float)size) * h * h;
        return 1;
    }
    nc_vec3 pos = nc_scale(nc_sub(nc_v3a(l->position), nc_v3a(o->origin)), 1.0f / o->h);
    nc_vec3 to_c = nc_sub(centre, pos);
    bool inside = pos.x >= lo.x - 1 && pos.y >= lo.y - 1 && pos.z >= lo.z - 1 && pos.x <= hi.x + 1 &&
                  pos.y <= hi.y + 1 && pos.z <= hi.z + 1;
    if (!inside && nc_length(to_c) > 0.0f) {
        tsm_view *w = &v[0];
        w->ortho = false;
        w->size = size;
        w->origin = pos;
        w->f = nc_normalize(to_c);
        nc_basis(w->f, &w->r, &w->u);
        w->a0 = w->b0 = INFINITY;
        w->a1 = w->b1 = -INFINITY;
        bool ok = true;
        for (int k = 0; k < 8 && ok; k++) {
            nc_vec3 d = nc_sub(corner[k], pos);
            float z = nc_dot(d, w->f);
            if (!(z > 1e-3f * diag)) {
                ok = false;
                break;
            }
            float a = nc_dot(d, w->r) / z, b = nc_dot(d, w->u) / z;
            w->a0 = fminf(w->a0, a);
            w->a1 = fmaxf(w->a1, a);
            w->b0 = fminf(w->b0, b);
            w->b1 = fmaxf(w->b1, b);
        }
        if (ok && fmaxf(fmaxf(-w->a0, w->a1), fmaxf(-w->b0, w->b1)) <= MAX_FRUSTUM_TAN)
            return 1;
    }
    /* Cube map: the six faces partition the directions exactly. */
    static const float axes[6][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
    for (int f = 0; f < 6; f++) {
        tsm_view *w = &v[f];
        w->ortho = false;
        w->size = size;
        w->origin = pos;
        w->f = nc_v3a(axes[f]);
        nc_basis(w->f, &w->r, &w->u);
        w->a0 = w->b0 = -1.0f;
        w->a1 = w->b1 = 1.0f;
    }
    return 6;
}

/* The side of view w's map: TEXELS_PER_CELL texels per voxel side where the voxels are
 * largest on the map (ortho: everywhere; perspective: at the box corner farthest along the
 * axis, since a texel's footprint grows with distance), at least MIN_TSM_SIZE, at most max_size
 * (settings->diffusion.tsm_size). The seed renders a fixed-size map; what the flux estimate needs is
 * enough texels on each exposed face (16 per face here), and a 28^3 grid seen whole needs ~40
 * cells x 4 texels, not 512. Measured against tests/unit/test_diffusion_pipeline.c's references
 * (brute-force rays, quadrature): the transmitted flux is within 0.07% (sphere, directional),
 * 0.16% (point, spot) at 4 texels per cell, 0.01-0.05% at 8; both are far below the voxelization's
 * own error (the staircase of a voxelized sphere lets through ~20% more than the smooth one),
 * and 8 costs 4 times the texels in both the map and the injection. The ortho texel area is
 * rescaled for the new size; view_power_bound does not depend on the size. */
static void adapt_size(const nc_diff_object *o, tsm_view *w, int32_t max_size)
{
    float cells;
    if (w->ortho) {
        cells = fmaxf(w->a1 - w->a0, w->b1 - w->b0);
    } else {
        float zmax = 0.0f;
        for (int k = 0; k < 8; k++) {
            nc_vec3 c = nc_v3((float)((k & 1) ? o->hi[0] : o->lo[0]), (float)((k & 2) ? o->hi[1] : o->lo[1]),
                              (float)((k & 4) ? o->hi[2] : o->lo[2]));
            zmax = fmaxf(zmax, nc_dot(nc_sub(c, w->origin), w->f));
        }
        cells = fmaxf(w->a1 - w->a0, w->b1 - w->b0) * zmax;
    }
    float want = ceilf(TEXELS_PER_CELL * cells);
    int32_t size = max_size;
    if (isfinite(want) && want < (float)max_size)
        size = want < (float)MIN_TSM_SIZE ? MIN_TSM_SIZE : (int32_t)want;
    if (size > max_size)
        size = max_size;
    if (w->ortho)
        w->ortho_area *= ((float)w->size * (float)w->size) / ((float)size * (float)size);
    w->size = size;
}

/* Render rows [j0, j1) of view `w` into the band: per texel, cell, face, weight, entry point and
 * direction. */
static void render_band(const nc_diff_object *o, const tsm_view *w, const tsm_light *tl, bool shadowed,
                        int32_t j0, int32_t j1, nc_tsm_band *b, bool use_mesh, int threads)
{
    const int32_t size = w->size;
    const float da = (w->a1 - w->a0) / (float)size, db = (w->b1 - w->b0) / (float)size;
    const float lo_g[3] = {(float)o->lo[0] - 1, (float)o->lo[1] - 1, (float)o->lo[2] - 1};
    const float hi_g[3] = {(float)o->hi[0] + 1, (float)o->hi[1] + 1, (float)o->hi[2] + 1};
    const bool spot = tl->desc->type == NACRE_LIGHT_SPOT;
    const double eta = o->eta;
    const int64_t count = (int64_t)(j1 - j0) * size;
#pragma omp parallel for schedule(dynamic, 256) num_threads(threads) if (count > 4096)
    for (int64_t t = 0; t < count; t++) {
        int32_t j = j0 + (int32_t)(t / size), i = (int32_t)(t % size);
        float a = w->a0 + ((float)i + 0.5f) * da, bb = w->b0 + ((float)j + 0.5f) * db;
        nc_vec3 org, dir;
        float geom;
        if (w->ortho) {
            org = nc_add(w->origin, nc_add(nc_scale(w->r, a), nc_scale(w->u, bb)));
            dir = w->f;
            geom = w->ortho_area;
        } else {
            nc_vec3 ray = nc_add(w->f, nc_add(nc_scale(w->r, a), nc_scale(w->u, bb)));
            float len = nc_length(ray);
            org = w->origin;
            dir = nc_scale(ray, 1.0f / len);
            /* Solid angle of the texel: its area on the plane at unit distance x cos^3. */
            geom = da * db / (len * len * len);
        }
        float o3[3] = {org.x, org.y, org.z}, d3[3] = {dir.x, dir.y, dir.z}, entry[3];
        uint32_t cell;
        uint8_t face;
        b->cell[t] = UINT32_MAX;
        b->weight[t] = 0.0f;
        if (!cast_ray(o, o3, d3, &cell, &face, entry))
            continue;
        float cos_f = fabsf(d3[face / 2 == 0 ? 2 : (face / 2 == 1 ? 0 : 1)]);
        if (use_mesh) {
            if (!(b->mesh_t[t] < INFINITY))
                continue;
            cos_f = fabsf(d3[0] * b->mesh_n[3 * t] + d3[1] * b->mesh_n[3 * t + 1] + d3[2] * b->mesh_n[3 * t + 2]);
            for (int k = 0; k < 3; k++)
                entry[k] = o3[k] + d3[k] * b->mesh_t[t];
        }
        float wgt = geom * (float)(1.0 - nc_fresnel_dielectric(cos_f, eta));
        if (spot)
            wgt *= spot_falloff(tl->desc, dir);
        if (shadowed && wgt > 0.0f) {
            float tin, tout;
            int ax;
            if (ray_box(o3, d3, lo_g, hi_g, &tin, &tout, &ax) && tin > 0.0f) {
                nc_vec3 pw = nc_add(nc_v3a(o->origin), nc_scale(nc_add(org, nc_scale(dir, tin)), o->h));
                wgt *= nc_shadow_lookup(tl->shadow, pw, nc_scale(dir, -1.0f), tl->pcf_radius, tl->bias);
            }
        }
        b->cell[t] = cell;
        b->face[t] = face;
        b->weight[t] = wgt;
        b->pos[3 * t + 0] = entry[0];
        b->pos[3 * t + 1] = entry[1];
        b->pos[3 * t + 2] = entry[2];
        b->dir[3 * t + 0] = d3[0];
        b->dir[3 * t + 1] = d3[1];
        b->dir[3 * t + 2] = d3[2];
    }
}

/*
 * The true surface. The voxel staircase seen from a light has a larger silhouette than the
 * object (a sphere's, at 32 cells across and a light along no axis: 6.5% larger; 3.4% at 64)
 * and faces at the wrong angles, so a map of the staircase alone lets in too much light, at the
 * wrong Fresnel factor, from points up to a cell off the surface. Each texel therefore also
 * finds where its ray meets the object's mesh: texels whose ray misses the mesh carry no flux,
 * the Fresnel factor and the refraction take the mesh's normal there, and the volume source
 * starts at that point. The staircase still says which cell the light enters (the face source
 * and the march's first cell). Triangles are scanned like the faces of raster_band, in the
 * map's plane (perspective maps: the plane at unit distance, where triangles stay triangles
 * while in front of the light), and the distance along each texel's ray is exact (ray and
 * triangle plane). Cube maps (a light inside or next to the object's box) and meshes of more
 * than MESH_PER_TEXEL triangles per texel of the map the grid asks for (the pass's cost) keep
 * the staircase.
 */

/* Map coordinates of every vertex (grid units or tangents), and whether it is in front. */
static void project_vertices(const nc_diff_object *o, const tsm_view *w, const float *pos, uint32_t n, float *vp,
                             int threads)
{
    const float inv_h = 1.0f / o->h;
#pragma omp parallel for schedule(static) num_threads(threads) if (n > 16384)
    for (int64_t v = 0; v < (int64_t)n; v++) {
        nc_vec3 p = nc_scale(nc_sub(nc_v3a(pos + 3 * v), nc_v3a(o->origin)), inv_h);
        float *out = vp + 3 * v;
        if (w->ortho) {
            out[0] = nc_dot(p, w->r);
            out[1] = nc_dot(p, w->u);
            out[2] = 1.0f;
            continue;
        }
        nc_vec3 q = nc_sub(p, w->origin);
        float z = nc_dot(q, w->f);
        out[2] = z > 1e-6f ? 1.0f : 0.0f;
        out[0] = z > 1e-6f ? nc_dot(q, w->r) / z : 0.0f;
        out[1] = z > 1e-6f ? nc_dot(q, w->u) / z : 0.0f;
    }
}

/* The texel's ray as render_band and raster_band build it (grid units; dir unit length). */
static inline void texel_ray(const tsm_view *w, float a, float bb, nc_vec3 *org, nc_vec3 *dir)
{
    if (w->ortho) {
        *org = nc_add(w->origin, nc_add(nc_scale(w->r, a), nc_scale(w->u, bb)));
        *dir = w->f;
    } else {
        *org = w->origin;
        *dir = nc_normalize(nc_add(w->f, nc_add(nc_scale(w->r, a), nc_scale(w->u, bb))));
    }
}

/* Per texel of rows [j0, j1): the distance to the nearest triangle along its ray (mesh_t,
 * INFINITY when it misses) and that triangle's unit normal turned towards the light (mesh_n).
 * Each covered texel keeps the smallest key (distance bits, then triangle index), so the result
 * does not depend on the order or the thread count; a pass over the texels then turns keys into
 * distances and normals. */
static void mesh_band(const nc_diff_object *o, const tsm_view *w, const float *pos, const uint32_t *idx,
                      uint32_t tri_count, const float *vp, int32_t j0, int32_t j1, nc_tsm_band *b, int threads)
{
    const int32_t size = w->size;
    const float da = (w->a1 - w->a0) / (float)size, db = (w->b1 - w->b0) / (float)size;
    const float inv_da = 1.0f / da, inv_db = 1.0f / db, inv_h = 1.0f / o->h;
    const int64_t count = (int64_t)(j1 - j0) * size;
    uint64_t *key = b->mesh_key;
#pragma omp parallel for schedule(static) num_threads(threads) if (count > 4096)
    for (int64_t t = 0; t < count; t++)
        key[t] = UINT64_MAX;
    const float rb0 = w->b0 + (float)j0 * db, rb1 = w->b0 + (float)j1 * db;
    /* Each triangle's texel bounds first (first row > last row when it holds no texel centre
     * of the band); then chunks of rows, each drawing the triangles that reach its rows. A texel
     * belongs to one chunk, so its minimum needs no atomic compare-and-swap. */
    int32_t *tbox = b->tbox;
#pragma omp parallel for schedule(static, 4096) num_threads(threads) if (tri_count > 4096)
    for (int64_t tri = 0; tri < (int64_t)tri_count; tri++) {
        int32_t *tb = tbox + 4 * tri;
        tb[2] = 1;
        tb[3] = 0;
        const float *p0 = vp + 3 * (size_t)idx[3 * tri], *p1 = vp + 3 * (size_t)idx[3 * tri + 1];
        const float *p2 = vp + 3 * (size_t)idx[3 * tri + 2];
        if (p0[2] == 0.0f || p1[2] == 0.0f || p2[2] == 0.0f)
            continue;
        float bmin = fminf(p0[1], fminf(p1[1], p2[1])), bmax = fmaxf(p0[1], fmaxf(p1[1], p2[1]));
        if (bmax < rb0 || bmin > rb1)
            continue;
        float amin = fminf(p0[0], fminf(p1[0], p2[0])), amax = fmaxf(p0[0], fmaxf(p1[0], p2[0]));
        /* Texel centres within the bounds: most triangles of a fine mesh hold none. */
        int32_t ia = (int32_t)ceilf((amin - w->a0) * inv_da - 0.5f), ib = (int32_t)floorf((amax - w->a0) * inv_da - 0.5f);
        int32_t ja = (int32_t)ceilf((bmin - w->b0) * inv_db - 0.5f), jb = (int32_t)floorf((bmax - w->b0) * inv_db - 0.5f);
        ia = ia < 0 ? 0 : ia;
        ib = ib > size - 1 ? size - 1 : ib;
        ja = ja < j0 ? j0 : ja;
        jb = jb > j1 - 1 ? j1 - 1 : jb;
        if (ia > ib || ja > jb)
            continue;
        float area = (p1[0] - p0[0]) * (p2[1] - p0[1]) - (p2[0] - p0[0]) * (p1[1] - p0[1]);
        if (area == 0.0f)
            continue;
        tb[0] = ia;
        tb[1] = ib;
        tb[2] = ja;
        tb[3] = jb;
    }
    const int32_t nrows = j1 - j0;
    const int chunks = threads > 1 ? 4 * threads : 1;
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads) if (count > 4096 && tri_count > 256)
    for (int ch = 0; ch < chunks; ch++) {
        const int32_t r0 = j0 + (int32_t)((int64_t)nrows * ch / chunks);
        const int32_t r1 = j0 + (int32_t)((int64_t)nrows * (ch + 1) / chunks);
        for (int64_t tri = 0; r0 < r1 && tri < (int64_t)tri_count; tri++) {
            const int32_t *tb = tbox + 4 * tri;
            if (tb[2] > r1 - 1 || tb[3] < r0 || tb[2] > tb[3])
                continue;
            const int32_t ia = tb[0], ib = tb[1], ja = tb[2] < r0 ? r0 : tb[2], jb = tb[3] > r1 - 1 ? r1 - 1 : tb[3];
            const float *p0 = vp + 3 * (size_t)idx[3 * tri], *p1 = vp + 3 * (size_t)idx[3 * tri + 1];
            const float *p2 = vp + 3 * (size_t)idx[3 * tri + 2];
            float area = (p1[0] - p0[0]) * (p2[1] - p0[1]) - (p2[0] - p0[0]) * (p1[1] - p0[1]);
            const float sgn = area > 0.0f ? 1.0f : -1.0f;
            nc_vec3 v0 = nc_scale(nc_sub(nc_v3a(pos + 3 * (size_t)idx[3 * tri]), nc_v3a(o->origin)), inv_h);
            nc_vec3 v1 = nc_scale(nc_sub(nc_v3a(pos + 3 * (size_t)idx[3 * tri + 1]), nc_v3a(o->origin)), inv_h);
            nc_vec3 v2 = nc_scale(nc_sub(nc_v3a(pos + 3 * (size_t)idx[3 * tri + 2]), nc_v3a(o->origin)), inv_h);
            nc_vec3 n = nc_cross(nc_sub(v1, v0), nc_sub(v2, v0));
            for (int32_t j = ja; j <= jb; j++) {
                float bb = w->b0 + ((float)j + 0.5f) * db;
                for (int32_t i = ia; i <= ib; i++) {
                    float a = w->a0 + ((float)i + 0.5f) * da;
                    /* Inside, edges inclusive: a texel on a shared edge takes the smaller key. */
                    float e0 = ((p1[0] - p0[0]) * (bb - p0[1]) - (p1[1] - p0[1]) * (a - p0[0])) * sgn;
                    float e1 = ((p2[0] - p1[0]) * (bb - p1[1]) - (p2[1] - p1[1]) * (a - p1[0])) * sgn;
                    float e2 = ((p0[0] - p2[0]) * (bb - p2[1]) - (p0[1] - p2[1]) * (a - p2[0])) * sgn;
                    if (e0 < 0.0f || e1 < 0.0f || e2 < 0.0f)
                        continue;
                    nc_vec3 org, dir;
                    texel_ray(w, a, bb, &org, &dir);
                    float dn = nc_dot(dir, n);
                    if (dn == 0.0f)
                        continue;
                    float dist = nc_dot(nc_sub(v0, org), n) / dn;
                    dist = dist > 0.0f ? dist : 0.0f;
                    uint32_t bits;
                    memcpy(&bits, &dist, sizeof(bits)); /* non-negative floats order as their bits */
                    uint64_t k = ((uint64_t)bits << 32) | (uint64_t)tri;
                    uint64_t *slot = &key[(int64_t)(j - j0) * size + i];
                    if (k < *slot)
                        *slot = k;
                }
            }
        }
    }
#pragma omp parallel for schedule(static) num_threads(threads) if (count > 4096)
    for (int64_t t = 0; t < count; t++) {
        if (key[t] == UINT64_MAX) {
            b->mesh_t[t] = INFINITY;
            continue;
        }
        uint32_t tri = (uint32_t)(key[t] & 0xffffffffu), bits = (uint32_t)(key[t] >> 32);
        memcpy(&b->mesh_t[t], &bits, sizeof(bits));
        nc_vec3 v0 = nc_v3a(pos + 3 * (size_t)idx[3 * tri]), v1 = nc_v3a(pos + 3 * (size_t)idx[3 * tri + 1]);
        nc_vec3 v2 = nc_v3a(pos + 3 * (size_t)idx[3 * tri + 2]);
        nc_vec3 n = nc_normalize(nc_cross(nc_sub(v1, v0), nc_sub(v2, v0)));
        int32_t j = j0 + (int32_t)(t / size), i = (int32_t)(t % size);
        nc_vec3 org, dir;
        texel_ray(w, w->a0 + ((float)i + 0.5f) * da, w->b0 + ((float)j + 0.5f) * db, &org, &dir);
        if (nc_dot(dir, n) > 0.0f)
            n = nc_scale(n, -1.0f);
        b->mesh_n[3 * t + 0] = n.x;
        b->mesh_n[3 * t + 1] = n.y;
        b->mesh_n[3 * t + 2] = n.z;
    }
}

/*
 * Orthographic maps by rasterization (the seed's method). A directional light sees, per axis,
 * only the faces whose outward normal points against its direction; a ray through a texel
 * reaches a solid cell first through such a face whose neighbour is empty, and no such face can
 * lie in front of that one (the ray would have entered a solid cell there). So the nearest
 * exposed light-facing face along each texel's ray is exactly what cast_ray() finds, and
 * drawing those faces with a depth test gives the same map for a fraction of the work: the
 * traversal walked the empty part of the box for every texel, the faces are few and each
 * covers a handful of texels. Ties (a texel centre exactly on the edge between two faces) go
 * half-open within a face plane and to the first face in list order across planes, so the map
 * does not depend on the thread count either.
 */

/* Coordinate `axis` of cell index `cell`. */
static inline uint32_t cell_coord(uint32_t cell, int axis, uint32_t nx, uint32_t ny)
{
    return axis == 0 ? cell % nx : (axis == 1 ? (cell / nx) % ny : cell / (nx * ny));
}

/* Entry step along each axis for direction d: +1, -1 or 0 (the face id a ray enters by is
 * entry_face(axis, step)). */
static void face_steps(const float d[3], int step[3])
{
    for (int k = 0; k < 3; k++)
        step[k] = d[k] > 0.0f ? 1 : (d[k] < 0.0f ? -1 : 0);
}

/* List the exposed faces that face direction d: cell * 8 + face id, ordered by cell then axis.
 * Two passes over z-slabs (count, then fill at the slab's prefix offset), so the order does not
 * depend on the thread count. Returns the face count, or SIZE_MAX when out of memory. */
static size_t list_faces(nc_diff_object *o, const float d[3], int threads)
{
    int step[3];
    face_steps(d, step);
    const uint32_t nx = o->dims[0], ny = o->dims[1], nz = o->dims[2];
    const size_t sx = 1, sy = nx, sz = (size_t)nx * ny;
    const size_t stride[3] = {sx, sy, sz};
    const uint32_t lo[3] = {o->lo[0], o->lo[1], o->lo[2]}, hi[3] = {o->hi[0], o->hi[1], o->hi[2]};
    const uint32_t dims[3] = {nx, ny, nz};
    const uint8_t *solid = o->solid;
    const int32_t zn = (int32_t)(hi[2] - lo[2]);
    /* Per-slab counts (then offsets) on the stack: the caller guarantees at most 1024 slabs. */
    size_t counts[1025];
    uint32_t *faces = o->faces;
    for (int pass = 0; pass < 2; pass++) {
#pragma omp parallel for schedule(static) num_threads(threads) if (o->cells > 32768)
        for (int32_t zi = 0; zi < zn; zi++) {
            uint32_t z = lo[2] + (uint32_t)zi;
            size_t n = pass == 0 ? 0 : counts[zi];
            for (uint32_t y = lo[1]; y < hi[1]; y++)
                for (uint32_t x = lo[0]; x < hi[0]; x++) {
                    size_t i = x + sy * y + sz * z;
                    if (!solid[i])
                        continue;
                    const uint32_t c[3] = {x, y, z};
                    for (int k = 0; k < 3; k++) {
                        if (!step[k])
                            continue;
                        /* The neighbour the light comes from: against the direction of travel. */
                        bool open = step[k] > 0 ? c[k] == 0 : c[k] + 1 >= dims[k];
                        if (!open)
                            open = !solid[step[k] > 0 ? i - stride[k] : i + stride[k]];
                        if (!open)
                            continue;
                        if (pass == 1)
                            faces[n] = (uint32_t)(i * 8 + entry_face(k, step[k]));
                        n++;
                    }
                }
            if (pass == 0)
                counts[zi] = n;
        }
        if (pass == 0) {
            size_t total = 0;
            for (int32_t zi = 0; zi < zn; zi++) {
                size_t cnt = counts[zi];
                counts[zi] = total;
                total += cnt;
            }
            if (total > o->face_capacity) {
                nc_free(o->ctx, o->faces);
                o->faces = nc_alloc(o->ctx, total * sizeof(*o->faces));
                o->face_capacity = o->faces ? total : 0;
                if (!o->faces)
                    return SIZE_MAX;
            }
            faces = o->faces;
            counts[zn] = total;
        }
    }
    return counts[zn];
}

/* Rasterize the listed faces into rows [j0, j1) of orthographic view w, then fill the band as
 * render_band does. */
static void raster_band(const nc_diff_object *o, const tsm_view *w, const tsm_light *tl, bool shadowed, int32_t j0,
                        int32_t j1, nc_tsm_band *b, size_t nfaces, const float ft[3], bool use_mesh, int threads)
{
    const int32_t size = w->size;
    const float da = (w->a1 - w->a0) / (float)size, db = (w->b1 - w->b0) / (float)size;
    const float inv_da = 1.0f / da, inv_db = 1.0f / db;
    const float d3[3] = {w->f.x, w->f.y, w->f.z};
    const float rr[3] = {w->r.x, w->r.y, w->r.z}, uu[3] = {w->u.x, w->u.y, w->u.z};
    const float oo[3] = {w->origin.x, w->origin.y, w->origin.z};
    const uint32_t nx = o->dims[0], ny = o->dims[1];
    const int64_t count = (int64_t)(j1 - j0) * size;
    float *depth = b->depth;
    uint32_t *hit = b->hit;
    const uint32_t *faces = o->faces;
    /* Each face's texel bounds first (i clamped to the map; j as computed), then chunks of rows,
     * each scanning the bounds for the faces that reach its rows, so that no chunk projects
     * every face's corners again. */
    int32_t *fbox = b->fbox;
#pragma omp parallel for schedule(static) num_threads(threads) if (nfaces > 4096)
    for (int64_t fi = 0; fi < (int64_t)nfaces; fi++) {
        uint32_t cell = faces[fi] >> 3, face = faces[fi] & 7;
        int axis = face / 2 == 0 ? 2 : (face / 2 == 1 ? 0 : 1);
        int k1 = (axis + 1) % 3, k2 = (axis + 2) % 3;
        const float c[3] = {(float)(cell % nx), (float)((cell / nx) % ny), (float)(cell / ((size_t)nx * ny))};
        float plane = (face & 1) ? c[axis] + 1.0f : c[axis];
        /* Projected bounds of the square: its 4 corners on the map. */
        float amin = INFINITY, amax = -INFINITY, bmin = INFINITY, bmax = -INFINITY;
        for (int q = 0; q < 4; q++) {
            float p[3];
            p[axis] = plane;
            p[k1] = c[k1] + (float)(q & 1);
            p[k2] = c[k2] + (float)(q >> 1);
            float a = p[0] * rr[0] + p[1] * rr[1] + p[2] * rr[2], bb = p[0] * uu[0] + p[1] * uu[1] + p[2] * uu[2];
            amin = a < amin ? a : amin;
            amax = a > amax ? a : amax;
            bmin = bb < bmin ? bb : bmin;
            bmax = bb > bmax ? bb : bmax;
        }
        /* Texel centres a0 + (i + 0.5) da within [amin, amax], rounded outwards as slack
         * for round-off (the exact test below decides). */
        int32_t i0 = (int32_t)floorf((amin - w->a0) * inv_da - 0.5f);
        int32_t i1 = (int32_t)ceilf((amax - w->a0) * inv_da - 0.5f);
        fbox[4 * fi + 0] = i0 < 0 ? 0 : i0;
        fbox[4 * fi + 1] = i1 > size - 1 ? size - 1 : i1;
        fbox[4 * fi + 2] = (int32_t)floorf((bmin - w->b0) * inv_db - 0.5f);
        fbox[4 * fi + 3] = (int32_t)ceilf((bmax - w->b0) * inv_db - 0.5f);
    }
    const int32_t nrows = j1 - j0;
    const int chunks = threads > 1 ? 4 * threads : 1;
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads) if (count > 4096 && nfaces > 256)
    for (int ch = 0; ch < chunks; ch++) {
        int32_t r0 = j0 + (int32_t)((int64_t)nrows * ch / chunks), r1 = j0 + (int32_t)((int64_t)nrows * (ch + 1) / chunks);
        if (r0 >= r1)
            continue;
        for (int64_t t = (int64_t)(r0 - j0) * size; t < (int64_t)(r1 - j0) * size; t++) {
            depth[t] = INFINITY;
            hit[t] = UINT32_MAX;
        }
        for (size_t fi = 0; fi < nfaces; fi++) {
            const int32_t *fb = fbox + 4 * fi;
            if (fb[2] > r1 - 1 || fb[3] < r0 || fb[0] > fb[1])
                continue;
            const int32_t i0 = fb[0], i1 = fb[1], jj0 = fb[2] < r0 ? r0 : fb[2], jj1 = fb[3] > r1 - 1 ? r1 - 1 : fb[3];
            uint32_t cell = faces[fi] >> 3, face = faces[fi] & 7;
            int axis = face / 2 == 0 ? 2 : (face / 2 == 1 ? 0 : 1);
            int k1 = (axis + 1) % 3, k2 = (axis + 2) % 3;
            const float c[3] = {(float)(cell % nx), (float)((cell / nx) % ny), (float)(cell / ((size_t)nx * ny))};
            float plane = (face & 1) ? c[axis] + 1.0f : c[axis];
            const float inv_dk = 1.0f / d3[axis];
            for (int32_t j = jj0; j <= jj1; j++) {
                float bb = w->b0 + ((float)j + 0.5f) * db;
                for (int32_t i = i0; i <= i1; i++) {
                    float a = w->a0 + ((float)i + 0.5f) * da;
                    /* The texel's ray, as render_band builds it, against the face plane. */
                    float org[3];
                    for (int k = 0; k < 3; k++)
                        org[k] = oo[k] + (rr[k] * a + uu[k] * bb);
                    float t = (plane - org[axis]) * inv_dk;
                    float x1 = org[k1] + d3[k1] * t, x2 = org[k2] + d3[k2] * t;
                    if (!(x1 >= c[k1] && x1 < c[k1] + 1.0f && x2 >= c[k2] && x2 < c[k2] + 1.0f))
                        continue;
                    int64_t tx = (int64_t)(j - j0) * size + i;
                    if (t < depth[tx]) {
                        depth[tx] = t;
                        hit[tx] = (uint32_t)fi;
                    }
                }
            }
        }
    }
    const float lo_g[3] = {(float)o->lo[0] - 1, (float)o->lo[1] - 1, (float)o->lo[2] - 1};
    const float hi_g[3] = {(float)o->hi[0] + 1, (float)o->hi[1] + 1, (float)o->hi[2] + 1};
    /* Texels in chunks of SHADOW_BATCH: the occlusion by other objects is looked up for a chunk's
     * lit texels in one nc_shadow_lookup_n call, whose set-up is vectorized across the points. */
    const int64_t nchunks = (count + SHADOW_BATCH - 1) / SHADOW_BATCH;
#pragma omp parallel for schedule(static) num_threads(threads) if (count > 4096)
    for (int64_t ch = 0; ch < nchunks; ch++) {
        float qx[SHADOW_BATCH], qy[SHADOW_BATCH], qz[SHADOW_BATCH], vis[SHADOW_BATCH];
        float nx_[SHADOW_BATCH], ny_[SHADOW_BATCH], nz_[SHADOW_BATCH];
        int64_t qt[SHADOW_BATCH];
        uint32_t nq = 0;
        const int64_t t_end = (ch + 1) * SHADOW_BATCH < count ? (ch + 1) * SHADOW_BATCH : count;
        for (int64_t t = ch * SHADOW_BATCH; t < t_end; t++) {
            b->cell[t] = UINT32_MAX;
            b->weight[t] = 0.0f;
            if (hit[t] == UINT32_MAX)
                continue;
            int32_t j = j0 + (int32_t)(t / size), i = (int32_t)(t % size);
            float a = w->a0 + ((float)i + 0.5f) * da, bb = w->b0 + ((float)j + 0.5f) * db;
            uint32_t cell = faces[hit[t]] >> 3;
            uint8_t face = (uint8_t)(faces[hit[t]] & 7);
            int axis = face / 2 == 0 ? 2 : (face / 2 == 1 ? 0 : 1);
            float org[3];
            for (int k = 0; k < 3; k++)
                org[k] = oo[k] + (rr[k] * a + uu[k] * bb);
            float wgt = w->ortho_area * ft[axis];
            if (use_mesh) {
                if (!(b->mesh_t[t] < INFINITY))
                    continue;
                float cos_n = -(d3[0] * b->mesh_n[3 * t] + d3[1] * b->mesh_n[3 * t + 1] + d3[2] * b->mesh_n[3 * t + 2]);
                wgt = w->ortho_area * (float)(1.0 - nc_fresnel_dielectric(fabs((double)cos_n), o->eta));
            }
            if (shadowed && wgt > 0.0f) {
                float tin, tout;
                int ax;
                if (ray_box(org, d3, lo_g, hi_g, &tin, &tout, &ax) && tin > 0.0f) {
                    nc_vec3 pw = nc_add(nc_v3a(o->origin), nc_scale(nc_add(nc_v3a(org), nc_scale(w->f, tin)), o->h));
                    qx[nq] = pw.x;
                    qy[nq] = pw.y;
                    qz[nq] = pw.z;
                    nx_[nq] = -w->f.x;
                    ny_[nq] = -w->f.y;
                    nz_[nq] = -w->f.z;
                    qt[nq++] = t;
                }
            }
            b->cell[t] = cell;
            b->face[t] = face;
            b->weight[t] = wgt;
            for (int k = 0; k < 3; k++) {
                b->pos[3 * t + k] = org[k] + d3[k] * depth[t];
                b->dir[3 * t + k] = d3[k];
            }
            const float plane =
                (float)((face & 1) ? (cell_coord(cell, axis, nx, ny) + 1) : cell_coord(cell, axis, nx, ny));
            b->pos[3 * t + axis] = plane;
            if (use_mesh)
                for (int k = 0; k < 3; k++)
                    b->pos[3 * t + k] = org[k] + d3[k] * b->mesh_t[t];
        }
        if (nq > 0) {
            nc_shadow_lookup_n(tl->shadow, nq, qx, qy, qz, nx_, ny_, nz_, tl->pcf_radius, tl->bias, vis);
            for (uint32_t k = 0; k < nq; k++)
                b->weight[qt[k]] *= vis[k];
        }
    }
}

/* Add `value` W to a fixed-point accumulator (see nc_diff_inject_lights). Integer addition is
 * associative, so the sums do not depend on the order threads add in. */
static inline void accumulate(int64_t *acc, double value, double scale, bool atomic)
{
    int64_t v = llrint(value * scale);
    if (v == 0)
        return;
    if (atomic) {
#pragma omp atomic
        *acc += v;
    } else {
        *acc += v;
    }
}

/*
 * FACE injection. The seed's boundary condition (eq. 4.7, Arbree et al. 2011) on a lit face,
 * with n the outward normal and q the transmitted incident flux per unit area:
 *     phi_s + 2 A D dphi/dn = 4 q / (1 - Fdr).
 * The face is half a cell from the centre, so dphi/dn = (phi_s - phi_i) / (h / 2), which gives
 *     phi_s = (4 h q / (1 - Fdr) + 4 A D phi_i) / (h + 4 A D).
 * The outward flux per unit area (Fick) is J = -D dphi/dn = 2 D (phi_i - phi_s) / h
 *     = 2 D (phi_i - 4 q / (1 - Fdr)) / (h + 4 A D),
 * and over the face area h^2 this is B_f phi_i - B_f 4 q / (1 - Fdr) with
 * B_f = h^2 2 D / (h + 4 A D), the boundary term of diffusion.h. Moving the constant to the right
 * of the cell balance: S_i += B_f 4 q / (1 - Fdr) = flux 8 D / ((h + 4 A D) (1 - Fdr)), flux = q h^2.
 * (This S is not the net power entering: the same face also loses the diffuse part reflected back,
 * which the B_f phi_i term carries; see nc_diff_compute_exitance.)
 */
/* The per-cell factor of FACE injection: S_i = k_i x (flux into cell i). */
static float face_factor(const nc_diff_object *o, size_t cell, int c)
{
    float sa, ssp;
    nc_diff_object_coeffs(o, cell, c, &sa, &ssp);
    float st = sa + ssp;
    /* D -> infinity (no interaction) has the finite limit 2 / (A (1 - Fdr)). */
    if (!(st > 0.0f))
        return 2.0f / (o->robin_a * (1.0f - o->fdr));
    float D = 1.0f / (3.0f * st);
    return 8.0f * D / ((o->h + 4.0f * o->robin_a * D) * (1.0f - o->fdr));
}

/* VOLUME injection: march the refracted ray from the entry point through solid cells. */
static void inject_volume(const nc_diff_object *o, int64_t *acc, bool atomic, double scale, uint32_t cell,
                          uint8_t face, const float pos[3], const float din[3], const float *nrm, const float flux[3])
{
    /* Outward normal at the entry (the mesh's when given, else the entry face's), then Snell
     * (relative index eta) into the medium. */
    float n[3] = {0, 0, 0};
    int axis = face / 2 == 0 ? 2 : (face / 2 == 1 ? 0 : 1);
    n[axis] = (face & 1) ? 1.0f : -1.0f;
    if (nrm)
        for (int i = 0; i < 3; i++)
            n[i] = nrm[i];
    float cos_i = -(din[0] * n[0] + din[1] * n[1] + din[2] * n[2]);
    float eta = o->eta;
    float sin2_t = (1.0f - cos_i * cos_i) / (eta * eta);
    if (!(cos_i > 0.0f) || sin2_t >= 1.0f)
        return;
    float k = cos_i / eta - sqrtf(1.0f - sin2_t);
    float d[3];
    for (int i = 0; i < 3; i++)
        d[i] = din[i] / eta + k * n[i];
    float len = sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    for (int i = 0; i < 3; i++)
        d[i] /= len;

    const uint32_t nx = o->dims[0], ny = o->dims[1];
    int c[3] = {(int)(cell % nx), (int)((cell / nx) % ny), (int)(cell / ((size_t)nx * ny))};
    /* From the mesh, the march starts in the cell of the surface point: the cells of the
     * staircase in front of the surface hold no medium the light crosses. */
    if (nrm)
        for (int i = 0; i < 3; i++) {
            int ci = (int)floorf(pos[i]);
            c[i] = ci < 0 ? 0 : (ci >= (int)o->dims[i] ? (int)o->dims[i] - 1 : ci);
        }
    int step[3];
    float tmax[3], tdelta[3];
    for (int i = 0; i < 3; i++) {
        if (d[i] > 0.0f) {
            step[i] = 1;
            tmax[i] = fmaxf(((float)c[i] + 1.0f - pos[i]) / d[i], 0.0f);
            tdelta[i] = 1.0f / d[i];
        } else if (d[i] < 0.0f) {
            step[i] = -1;
            tmax[i] = fmaxf(((float)c[i] - pos[i]) / d[i], 0.0f);
            tdelta[i] = -1.0f / d[i];
        } else {
            step[i] = 0;
            tmax[i] = tdelta[i] = INFINITY;
        }
    }
    float remain[3] = {1.0f, 1.0f, 1.0f}, s = 0.0f;
    /* Per-channel sigma_t' and flux x albedo x scale of the cell being deposited into, updated
     * only when that cell changes (homogeneous media: never), which keeps the division out of
     * the step loop. */
    float st_c[3] = {0, 0, 0};
    double dep_c[3] = {0, 0, 0};
    size_t coef_cell = SIZE_MAX;
    /* The voxelized boundary is a staircase: a refracted ray entering a face near its edge
     * often crosses the notch of the next step, a non-solid cell that the smooth surface
     * mostly covers. Runs of empty cells up to MAX_GAP cells of path are crossed as medium,
     * depositing in the last solid cell; a longer run means the ray has left the object.
     * Without this, a voxelized sphere (test_diffusion_pipeline) loses 4% of its volume source,
     * at any resolution since the staircase is scale invariant; with 1 cell 2%, with 2 cells
     * 0.4%. The price: objects thinner than 2 cells keep up to 2 cells' worth of attenuation. */
    size_t idx = (size_t)c[0] + nx * ((size_t)c[1] + (size_t)ny * (size_t)c[2]), last_solid = cell;
    float gap = 0.0f;
    /* Homogeneous media: the remaining fraction after the crossing at path length t is
     * exp(-sigma_t' h t), and the crossings of axis a are at tmax[a] + k tdelta[a], so each
     * axis' next remaining fraction is a geometric sequence: ea[a] (the value at tmax[a]) times
     * ma[a] per crossing. Eighteen exponentials per ray replace one or two per
     * step; the repeated products drift by ~1e-7 per step, far below the 1e-4 cutoff. */
    const bool geometric = !o->heterogeneous;
    float ea[3][3], ma[3][3];
    if (geometric) {
        /* The 18 exponentials as three 8-lane vectors (nc_vol_exp_fast8, expf's accuracy): 18
         * expf calls would be a fifth of the injection. An argument of -inf gives 0. */
        float in[24], out[24]; /* ea then ma, [channel][axis]; 6 lanes of padding */
        for (int ch = 0; ch < 3; ch++) {
            float st = o->sigma_a_const[ch] + o->sigma_sp_const[ch];
            for (int i = 0; i < 3; i++) {
                in[3 * ch + i] = st > 0.0f && tmax[i] < INFINITY ? -st * o->h * tmax[i] : -INFINITY;
                in[9 + 3 * ch + i] = st > 0.0f && tdelta[i] < INFINITY ? -st * o->h * tdelta[i] : -INFINITY;
            }
        }
        for (int k = 18; k < 24; k++)
            in[k] = -INFINITY;
        for (int k = 0; k < 24; k += 8)
            nc_v8_store(out + k, nc_vol_exp_fast8(nc_v8_load(in + k)));
        memcpy(ea, out, sizeof(ea));
        memcpy(ma, out + 9, sizeof(ma));
    }
    uint32_t max_steps = o->dims[0] + o->dims[1] + o->dims[2] + 3;
    for (uint32_t it = 0; it < max_steps; it++) {
        int a = tmax[0] < tmax[1] ? (tmax[0] < tmax[2] ? 0 : 2) : (tmax[1] < tmax[2] ? 1 : 2);
        float s1 = tmax[a];
        if (o->solid[idx]) {
            last_solid = idx;
            gap = 0.0f;
        } else {
            gap += s1 - s;
            if (gap > MAX_GAP)
                break;
        }
        float seg = (s1 - s) * o->h;
        float most = 0.0f;
        if (coef_cell != last_solid && (o->heterogeneous || coef_cell == SIZE_MAX)) {
            for (int ch = 0; ch < 3; ch++) {
                float sa, ssp;
                nc_diff_object_coeffs(o, last_solid, ch, &sa, &ssp);
                st_c[ch] = sa + ssp;
                dep_c[ch] = st_c[ch] > 0.0f ? (double)flux[ch] * (double)(ssp / st_c[ch]) * scale : 0.0;
            }
            coef_cell = last_solid;
        }
        float att[3] = {0.0f, 0.0f, 0.0f};
        for (int ch = 0; ch < 3; ch++) {
            /* A channel already below the cutoff has deposited all it will. */
            if (remain[ch] < VOLUME_CUTOFF)
                continue;
            float st = st_c[ch];
            if (!(st > 0.0f))
                continue;
            if (geometric) {
                float r1 = ea[ch][a] < remain[ch] ? ea[ch][a] : remain[ch];
                accumulate(&acc[3 * last_solid + (size_t)ch], dep_c[ch] * (double)(remain[ch] - r1), 1.0, atomic);
                remain[ch] = r1;
                most = r1 > most ? r1 : most;
                continue;
            }
            /* Channels with the same sigma_t' (jade's red and blue, grey media) share the
             * segment's attenuation, one expf fewer per step. An earlier channel still above
             * the cutoff has computed its att this step (remain only decreases). */
            if (ch > 0 && st == st_c[ch - 1] && remain[ch - 1] >= VOLUME_CUTOFF)
                att[ch] = att[ch - 1];
            else if (ch > 1 && st == st_c[0] && remain[0] >= VOLUME_CUTOFF)
                att[ch] = att[0];
            else
                att[ch] = expf(-st * seg);
            float r1 = remain[ch] * att[ch];
            accumulate(&acc[3 * last_solid + (size_t)ch], dep_c[ch] * (double)(remain[ch] - r1), 1.0, atomic);
            remain[ch] = r1;
            most = r1 > most ? r1 : most;
        }
        if (most < VOLUME_CUTOFF)
            break;
        s = s1;
        c[a] += step[a];
        tmax[a] += tdelta[a];
        if (geometric)
            for (int ch = 0; ch < 3; ch++)
                ea[ch][a] *= ma[ch][a];
        if (c[a] < 0 || c[a] >= (int)o->dims[a])
            break;
        idx = (size_t)c[0] + nx * ((size_t)c[1] + (size_t)ny * (size_t)c[2]);
    }
}

/* Upper bound of the power one view can deliver: strength x (map area or tangent-plane area,
 * which bounds the solid angle). */
/* The maps kept for single scattering (nc_diff_lmap): one per view, its texels allocated. */
static nacre_result lmaps_reserve(nc_diff_object *o, uint32_t nl, tsm_view views[][6], const int *nviews)
{
    uint32_t count = 0;
    for (uint32_t li = 0; li < nl; li++)
        count += (uint32_t)nviews[li];
    if (count > o->lmap_capacity) {
        nc_diff_lmap *m = nc_realloc(o->ctx, o->lmap, o->lmap_capacity * sizeof(*m), count * sizeof(*m));
        if (!m)
            return nc_fail(o->ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory for the light maps");
        memset(m + o->lmap_capacity, 0, (count - o->lmap_capacity) * sizeof(*m));
        o->lmap = m;
        o->lmap_capacity = count;
    }
    uint32_t k = 0;
    for (uint32_t li = 0; li < nl; li++)
        for (int vi = 0; vi < nviews[li]; vi++, k++) {
            const tsm_view *w = &views[li][vi];
            nc_diff_lmap *m = &o->lmap[k];
            const size_t texels = (size_t)w->size * (size_t)w->size;
            if (texels > m->capacity) {
                nc_free(o->ctx, m->texel);
                m->capacity = 0;
                if (!(m->texel = nc_alloc(o->ctx, texels * NC_DIFF_LMAP_FLOATS * sizeof(float))))
                    return nc_fail(o->ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory for the light maps");
                m->capacity = texels;
            }
            m->light = li;
            m->ortho = w->ortho;
            nc_v3store(w->origin, m->origin);
            nc_v3store(w->f, m->f);
            nc_v3store(w->r, m->r);
            nc_v3store(w->u, m->u);
            m->a0 = w->a0, m->a1 = w->a1, m->b0 = w->b0, m->b1 = w->b1;
            m->size = w->size;
        }
    o->lmap_count = count;
    return NACRE_OK;
}

/* Rows [j0, j1) of map m from the band's texels (render_band or raster_band): the entry's
 * distance along the texel's ray, the weight per unit of the texel's area or solid angle, the
 * normal (the mesh's, or the staircase face's). */
static void lmap_band(const tsm_view *w, nc_diff_lmap *m, int32_t j0, int32_t j1, const nc_tsm_band *b,
                      bool use_mesh, int threads)
{
    const int32_t size = w->size;
    const float da = (w->a1 - w->a0) / (float)size, db = (w->b1 - w->b0) / (float)size;
    const int64_t count = (int64_t)(j1 - j0) * size;
    float *out = m->texel + (size_t)j0 * (size_t)size * NC_DIFF_LMAP_FLOATS;
#pragma omp parallel for schedule(static) num_threads(threads) if (count > 16384)
    for (int64_t t = 0; t < count; t++) {
        float *e = out + (size_t)t * NC_DIFF_LMAP_FLOATS;
        e[0] = INFINITY;
        e[1] = e[2] = e[3] = e[4] = 0.0f;
        if (b->cell[t] == UINT32_MAX || !(b->weight[t] > 0.0f))
            continue;
        int32_t j = j0 + (int32_t)(t / size), i = (int32_t)(t % size);
        float a = w->a0 + ((float)i + 0.5f) * da, bb = w->b0 + ((float)j + 0.5f) * db;
        nc_vec3 org, dir;
        texel_ray(w, a, bb, &org, &dir);
        nc_vec3 p = nc_v3a(b->pos + 3 * t);
        float geom = w->ortho ? w->ortho_area : da * db / powf(1.0f + a * a + bb * bb, 1.5f);
        e[0] = nc_dot(nc_sub(p, org), dir);
        e[1] = b->weight[t] / geom;
        if (use_mesh) {
            e[2] = b->mesh_n[3 * t], e[3] = b->mesh_n[3 * t + 1], e[4] = b->mesh_n[3 * t + 2];
        } else {
            const uint8_t face = b->face[t];
            const int axis = face / 2 == 0 ? 2 : (face / 2 == 1 ? 0 : 1);
            e[2 + axis] = (face & 1) ? 1.0f : -1.0f;
        }
    }
}

bool nc_diff_lmap_lookup(const nc_diff_lmap *m, const float x[3], float *dist, float *trans, float n[3], float dir[3])
{
    float a, bb, along;
    const float q[3] = {x[0] - m->origin[0], x[1] - m->origin[1], x[2] - m->origin[2]};
    const float z = q[0] * m->f[0] + q[1] * m->f[1] + q[2] * m->f[2];
    if (m->ortho) {
        a = x[0] * m->r[0] + x[1] * m->r[1] + x[2] * m->r[2];
        bb = x[0] * m->u[0] + x[1] * m->u[1] + x[2] * m->u[2];
        along = z;
        for (int k = 0; k < 3; k++)
            dir[k] = m->f[k];
    } else {
        if (!(z > 0.0f))
            return false;
        a = (q[0] * m->r[0] + q[1] * m->r[1] + q[2] * m->r[2]) / z;
        bb = (q[0] * m->u[0] + q[1] * m->u[1] + q[2] * m->u[2]) / z;
        along = sqrtf(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
        for (int k = 0; k < 3; k++)
            dir[k] = along > 0.0f ? q[k] / along : m->f[k];
    }
    if (!(a >= m->a0 && a <= m->a1 && bb >= m->b0 && bb <= m->b1))
        return false;
    /* Texel-centre coordinates; bilinear over the corners with an entry (weights renormalized) */
    const float gx = (a - m->a0) / (m->a1 - m->a0) * (float)m->size - 0.5f;
    const float gy = (bb - m->b0) / (m->b1 - m->b0) * (float)m->size - 0.5f;
    const int32_t i0 = (int32_t)floorf(gx), j0 = (int32_t)floorf(gy);
    const float fx = gx - (float)i0, fy = gy - (float)j0;
    float sw = 0.0f, t = 0.0f, tr = 0.0f, nn[3] = {0.0f, 0.0f, 0.0f};
    for (int k = 0; k < 4; k++) {
        const int32_t i = i0 + (k & 1), j = j0 + (k >> 1);
        if (i < 0 || j < 0 || i >= m->size || j >= m->size)
            continue;
        const float *e = m->texel + ((size_t)j * (size_t)m->size + (size_t)i) * NC_DIFF_LMAP_FLOATS;
        if (!(e[0] < INFINITY))
            continue;
        const float wk = ((k & 1) ? fx : 1.0f - fx) * ((k >> 1) ? fy : 1.0f - fy) + 1e-6f;
        sw += wk;
        t += wk * e[0];
        tr += wk * e[1];
        for (int c = 0; c < 3; c++)
            nn[c] += wk * e[2 + c];
    }
    if (!(sw > 0.0f))
        return false;
    *dist = fmaxf(along - t / sw, 0.0f);
    *trans = tr / sw;
    const float len = sqrtf(nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2]);
    for (int c = 0; c < 3; c++)
        n[c] = len > 0.0f ? nn[c] / len : -dir[c];
    return true;
}

static double view_power_bound(const nacre_light_desc *l, const tsm_view *w)
{
    double smax = fmax(fmax(fabs(l->strength[0]), fabs(l->strength[1])), fabs(l->strength[2]));
    if (w->ortho)
        return smax * (double)w->ortho_area * (double)w->size * (double)w->size;
    return smax * (double)(w->a1 - w->a0) * (double)(w->b1 - w->b0);
}

/* The solid rows' x spans (inj_span), once per voxelization; a new set of spans leaves the
 * sources to be cleared whole (src_clean false). */
static nacre_result injection_spans(nc_diff_object *o, int threads)
{
    if (o->inj_valid)
        return NACRE_OK;
    const uint32_t nx = o->dims[0], ny = o->dims[1], nz = o->dims[2];
    const size_t rows = (size_t)ny * nz;
    if (!nc_reserve(o->ctx, &o->inj_span, &o->inj_span_capacity, rows, 2 * sizeof(uint32_t)))
        return nc_fail(o->ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory for the injection spans");
#pragma omp parallel for schedule(static) num_threads(threads) if (o->cells > 32768)
    for (int64_t r = 0; r < (int64_t)rows; r++) {
        const uint8_t *row = o->solid + (size_t)r * nx;
        uint32_t a = 0, e = nx;
        while (a < nx && !row[a])
            a++;
        while (e > a && !row[e - 1])
            e--;
        o->inj_span[2 * r] = a;
        o->inj_span[2 * r + 1] = e;
    }
    o->inj_valid = true;
    o->src_clean = false;
    return NACRE_OK;
}

/* Sources (and q) all 0: a frame that injects nothing. */
static void clear_sources(nc_diff_object *o, int threads)
{
    (void)threads;
    for (int c = 0; c < 3; c++) {
        memset(o->source[c], 0, o->cells * sizeof(float));
        if (o->q[c])
            memset(o->q[c], 0, o->cells * sizeof(float));
    }
    o->src_clean = true;
}

nacre_result nc_diff_inject_lights(nc_diff_object *o, nc_tsm_band *band, const nacre_scene *scene,
                                   const nc_shade_light *lights, uint32_t light_count, bool others_cast,
                                   const nacre_render_settings *settings, uint64_t *tsm_us, uint64_t *inject_us)
{
    nacre_context *ctx = o->ctx;
    /* Clearing the per-frame arrays is part of the injection's cost: timed with it. */
    const uint64_t t_clear = nc_now_us();
    const int threads = nc_threads(ctx);
    nacre_result res = injection_spans(o, threads);
    if (res != NACRE_OK)
        return res;
    for (int c = 0; c < 3; c++) {
        o->tsm_flux[c] = 0.0;
        o->injected[c] = 0.0;
    }
    o->lmap_count = 0;
    if (o->solid_count == 0 || light_count == 0) {
        clear_sources(o, threads);
        *inject_us += nc_now_us() - t_clear;
        return NACRE_OK;
    }
    const bool face_mode = settings->diffusion.source == NACRE_SOURCE_FACE;
    if (face_mode && !o->q[0])
        return nc_fail(ctx, NACRE_ERROR_INVALID_OPERATION, "diffusion: face injection without its buffers");
    const int32_t max_size = settings->diffusion.tsm_size;
    const int64_t cells = (int64_t)o->cells;

    /* Deposits are summed in 64-bit fixed point so that the parallel injection gives the same
     * sources for any thread count and schedule. The unit is chosen so that everything all the
     * lights can deliver stays below 2^61: no overflow, and a resolution of 2^-61 of the total
     * (far below float precision). */
    tsm_view views[64][6];
    int nviews[64];
    double bound = 0.0;
    uint32_t nl = light_count < 64 ? light_count : 64;
    if (light_count > 64)
        return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "diffusion: at most 64 lights (%u)", light_count);
    size_t band_texels = 0;
    for (uint32_t li = 0; li < nl; li++) {
        nviews[li] = light_views(o, lights[li].desc, max_size, views[li]);
        for (int vi = 0; vi < nviews[li]; vi++) {
            tsm_view *w = &views[li][vi];
            bound += view_power_bound(lights[li].desc, w);
            adapt_size(o, w, max_size);
            size_t rows = BAND_TEXELS / (uint32_t)w->size;
            rows = rows < 1 ? 1 : (rows > (size_t)w->size ? (size_t)w->size : rows);
            band_texels = rows * (size_t)w->size > band_texels ? rows * (size_t)w->size : band_texels;
        }
    }
    if (!(bound > 0.0) || !isfinite(bound)) {
        clear_sources(o, threads);
        *inject_us += nc_now_us() - t_clear;
        return NACRE_OK;
    }
    *inject_us += nc_now_us() - t_clear;
    res = band_reserve(ctx, band, band_texels);
    if (res != NACRE_OK)
        return res;
    if (band->raster_capacity < band_texels) {
        nc_free(ctx, band->depth);
        nc_free(ctx, band->hit);
        band->depth = nc_alloc(ctx, band_texels * sizeof(*band->depth));
        band->hit = nc_alloc(ctx, band_texels * sizeof(*band->hit));
        band->raster_capacity = band->depth && band->hit ? band_texels : 0;
        if (!band->raster_capacity)
            return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory for a translucent shadow map");
    }
    /* The object's mesh in its committed (deformed) pose, for the true surface (mesh_band).
     * The pass reads every triangle (~25 ns each); past MESH_PER_TEXEL triangles per texel of
     * the map the grid asks for (TEXELS_PER_CELL per cell of its longest side, whatever the
     * tsm_size cap) it would cost more than the rest of the map and the injection together
     * (Suzanne's 15.7k triangles at a 4^3 grid: 0.4 ms against 0.02 ms), so such meshes keep
     * the staircase at such grids. */
    const nc_object_rec *obj = &scene->objects[o->index];
    const nacre_mesh_data *mesh = &scene->meshes[obj->desc.mesh.id - 1].data;
    const bool have_mesh = mesh->triangle_count > 0 && obj->world_positions;
    const uint32_t longest = o->dims[0] > o->dims[1] ? (o->dims[0] > o->dims[2] ? o->dims[0] : o->dims[2])
                                                     : (o->dims[1] > o->dims[2] ? o->dims[1] : o->dims[2]);
    const double mesh_side = TEXELS_PER_CELL * (double)longest;
    const double mesh_budget = MESH_PER_TEXEL * mesh_side * mesh_side;
    if (have_mesh && band->mesh_capacity < band_texels) {
        nc_free(ctx, band->mesh_t);
        nc_free(ctx, band->mesh_n);
        nc_free(ctx, band->mesh_key);
        band->mesh_t = nc_alloc(ctx, band_texels * sizeof(float));
        band->mesh_n = nc_alloc(ctx, 3 * band_texels * sizeof(float));
        band->mesh_key = nc_alloc(ctx, band_texels * sizeof(uint64_t));
        band->mesh_capacity = band->mesh_t && band->mesh_n && band->mesh_key ? band_texels : 0;
        if (!band->mesh_capacity)
            return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory for a translucent shadow map");
    }
    /* Per triangle its texel box (4 ints), per vertex its projection (3 floats). */
    if (have_mesh && (!nc_reserve(ctx, &band->tbox, &band->tbox_capacity, mesh->triangle_count, 4 * sizeof(int32_t)) ||
                      !nc_reserve(ctx, &band->vproj, &band->vproj_capacity, mesh->vertex_count, 3 * sizeof(float))))
        return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory for a translucent shadow map");
    if (o->single && (res = lmaps_reserve(o, nl, views, nviews)) != NACRE_OK)
        return res;
    const double scale = ldexp(1.0, 61) / bound, inv_scale = 1.0 / scale;
    /* Deposits only go to solid cells, so the accumulators are read and cleared only in the
     * solid rows' spans (inj_span), by the pass that turns them into sources: they are all 0
     * when an injection starts, unless one stopped half-way (an error). */
    const uint64_t t_acc = nc_now_us();
    const size_t slab = (size_t)o->dims[0] * o->dims[1];
    const size_t c_lo = (size_t)o->lo[2] * slab, c_hi = (size_t)o->hi[2] * slab;
    /* Interleaved RGB per cell: a deposit touches one cache line for its three channels. */
    int64_t *acc = o->acc;
    if (o->acc_dirty)
        memset(acc, 0, 3 * o->cells * sizeof(int64_t));
    o->acc_dirty = true;
    int64_t total[3] = {0, 0, 0};
    /* Each extra thread adds into its own copy (plain adds; the copies are summed at the end,
     * still exactly); past PRIVATE_BYTES of copies, threads share the arrays with atomic adds. */
    int extra = threads > 1 ? threads - 1 : 0;
    size_t private_bytes = (size_t)extra * 3 * o->cells * sizeof(int64_t);
    bool private_acc = extra > 0 && private_bytes <= PRIVATE_BYTES;
    if (private_acc) {
        if (band->scratch_bytes < private_bytes) {
            nc_free(ctx, band->scratch);
            band->scratch = nc_calloc(ctx, 1, private_bytes);
            band->scratch_bytes = band->scratch ? private_bytes : 0;
            band->scratch_dirty = false;
            if (!band->scratch)
                return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory for injection");
        }
        if (band->scratch_dirty)
            memset(band->scratch, 0, band->scratch_bytes);
        band->scratch_dirty = true;
    }
    *inject_us += nc_now_us() - t_acc;
    const bool atomic = extra > 0 && !private_acc;

    uint32_t map_index = 0;
    for (uint32_t li = 0; li < nl; li++) {
        const nacre_light_desc *ld = lights[li].desc;
        tsm_light tl = {.desc = ld, .shadow = lights[li].shadow, .pcf_radius = TSM_PCF_RADIUS,
                        .bias = settings->shadow.bias};
        bool shadowed = others_cast && tl.shadow != NULL;
        const float strength[3] = {ld->strength[0], ld->strength[1], ld->strength[2]};
        for (int vi = 0; vi < nviews[li]; vi++) {
            const tsm_view *w = &views[li][vi];
            nc_diff_lmap *lm = o->single ? &o->lmap[map_index++] : NULL;
            const int32_t size = w->size;
            const int32_t rows = (int32_t)(band_texels / (size_t)size);
            /* Orthographic maps are rasterized from the face list (see raster_band); the face
             * encoding needs cells * 8 < 2^32 and list_faces at most 1024 slabs. */
            uint64_t tf = nc_now_us();
            bool raster = w->ortho && o->cells < ((size_t)1 << 29) && o->hi[2] - o->lo[2] <= 1024;
            size_t nfaces = 0;
            float ft[3] = {0, 0, 0};
            if (raster) {
                const float d3[3] = {w->f.x, w->f.y, w->f.z};
                int step[3];
                face_steps(d3, step);
                if (!o->faces_valid || step[0] != o->face_steps[0] || step[1] != o->face_steps[1] ||
                    step[2] != o->face_steps[2]) {
                    o->faces_valid = false;
                    size_t n = list_faces(o, d3, threads);
                    if (n == SIZE_MAX)
                        return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY,
                                       "diffusion: out of memory for a translucent shadow map");
                    o->face_count = n;
                    for (int k = 0; k < 3; k++)
                        o->face_steps[k] = (int8_t)step[k];
                    o->faces_valid = true;
                }
                nfaces = o->face_count;
                if (band->fbox_capacity < nfaces) {
                    nc_free(ctx, band->fbox);
                    band->fbox = nc_alloc(ctx, 4 * nfaces * sizeof(int32_t));
                    band->fbox_capacity = band->fbox ? nfaces : 0;
                    if (!band->fbox)
                        return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY,
                                       "diffusion: out of memory for a translucent shadow map");
                }
                for (int k = 0; k < 3; k++)
                    ft[k] = (float)(1.0 - nc_fresnel_dielectric(fabs((double)d3[k]), o->eta));
            }

            const bool use_mesh = have_mesh && nviews[li] == 1 && (double)mesh->triangle_count <= mesh_budget;
            if (use_mesh)
                project_vertices(o, w, obj->world_positions, mesh->vertex_count, band->vproj, threads);
            *tsm_us += nc_now_us() - tf;
            for (int32_t j0 = 0; j0 < size; j0 += rows) {
                int32_t j1 = j0 + rows < size ? j0 + rows : size;
                uint64_t t0 = nc_now_us();
                if (use_mesh)
                    mesh_band(o, w, obj->world_positions, mesh->indices, mesh->triangle_count, band->vproj, j0, j1,
                              band, threads);
                if (raster)
                    raster_band(o, w, &tl, shadowed, j0, j1, band, nfaces, ft, use_mesh, threads);
                else
                    render_band(o, w, &tl, shadowed, j0, j1, band, use_mesh, threads);
                if (lm)
                    lmap_band(w, lm, j0, j1, band, use_mesh, threads);
                uint64_t t1 = nc_now_us();
                *tsm_us += t1 - t0;
                const int64_t count = (int64_t)(j1 - j0) * size;
                int64_t t_r = 0, t_g = 0, t_b = 0;
#pragma omp parallel num_threads(threads) reduction(+ : t_r, t_g, t_b) if (count > 4096)
                {
                int tid = 0;
#ifdef _OPENMP
                tid = omp_get_thread_num();
#endif
                int64_t *mine = private_acc && tid > 0 ? band->scratch + (size_t)(tid - 1) * 3 * o->cells : acc;
                /* Units of work: single texels, or in rasterized (parallel-ray) volume mode 2x2
                 * blocks of texels (see the comment at MIN_TSM_SIZE). */
                const bool merge = raster && !face_mode;
                const int64_t bw = merge ? (size + 1) / 2 : size;
                const int64_t units = merge ? (int64_t)((j1 - j0 + 1) / 2) * bw : count;
#pragma omp for schedule(dynamic, 256) /* hit texels cluster: balance the threads */
                for (int64_t u = 0; u < units; u++) {
                    int64_t tex[4];
                    int nt = 0;
                    if (merge) {
                        int64_t br = u / bw, bc = u % bw;
                        for (int k = 0; k < 4; k++) {
                            int64_t r = 2 * br + (k >> 1), cc = 2 * bc + (k & 1);
                            if (r < j1 - j0 && cc < size)
                                tex[nt++] = r * size + cc;
                        }
                    } else {
                        tex[nt++] = u;
                    }
                    float sum_flux[3] = {0, 0, 0}, sum_w = 0.0f, sum_pos[3] = {0, 0, 0}, sum_n[3] = {0, 0, 0};
                    int nhit = 0, first = -1;
                    bool same = true;
                    for (int k = 0; k < nt; k++) {
                        int64_t t = tex[k];
                        if (band->cell[t] == UINT32_MAX || !(band->weight[t] > 0.0f))
                            continue;
                        float flux[3];
                        int64_t q[3];
                        for (int c = 0; c < 3; c++) {
                            flux[c] = strength[c] * band->weight[t];
                            q[c] = llrint((double)flux[c] * scale);
                        }
                        t_r += q[0];
                        t_g += q[1];
                        t_b += q[2];
                        if (face_mode) {
                            for (int c = 0; c < 3; c++)
                                accumulate(&mine[3 * (size_t)band->cell[t] + (size_t)c], (double)flux[c], scale, atomic);
                            continue;
                        }
                        if (first < 0)
                            first = k;
                        else if (band->cell[t] != band->cell[tex[first]] || band->face[t] != band->face[tex[first]])
                            same = false;
                        nhit++;
                        for (int c = 0; c < 3; c++) {
                            sum_flux[c] += flux[c];
                            sum_pos[c] += band->weight[t] * band->pos[3 * t + c];
                            if (use_mesh)
                                sum_n[c] += band->weight[t] * band->mesh_n[3 * t + c];
                        }
                        sum_w += band->weight[t];
                    }
                    if (face_mode || nhit == 0)
                        continue;
                    if (same) {
                        /* One ray for the block: its flux, from the flux-weighted mean entry point
                         * (on the same face; the direction is shared). */
                        int64_t t = tex[first];
                        float pos[3], nrm[3];
                        for (int c = 0; c < 3; c++)
                            pos[c] = nhit == 1 ? band->pos[3 * t + c] : sum_pos[c] / sum_w;
                        if (use_mesh) {
                            float len = sqrtf(sum_n[0] * sum_n[0] + sum_n[1] * sum_n[1] + sum_n[2] * sum_n[2]);
                            for (int c = 0; c < 3; c++)
                                nrm[c] = len > 0.0f ? sum_n[c] / len : band->mesh_n[3 * t + c];
                        }
                        inject_volume(o, mine, atomic, scale, band->cell[t], band->face[t], pos, band->dir + 3 * t,
                                      use_mesh ? nrm : NULL, sum_flux);
                        continue;
                    }
                    for (int k = 0; k < nt; k++) {
                        int64_t t = tex[k];
                        if (band->cell[t] == UINT32_MAX || !(band->weight[t] > 0.0f))
                            continue;
                        float flux[3];
                        for (int c = 0; c < 3; c++)
                            flux[c] = strength[c] * band->weight[t];
                        inject_volume(o, mine, atomic, scale, band->cell[t], band->face[t], band->pos + 3 * t,
                                      band->dir + 3 * t, use_mesh ? band->mesh_n + 3 * t : NULL, flux);
                    }
                }
                }
                total[0] += t_r;
                total[1] += t_g;
                total[2] += t_b;
                *inject_us += nc_now_us() - t1;
            }
        }
    }

    uint64_t t0 = nc_now_us();
    const float inv_h2 = 1.0f / (o->h * o->h);
    /* One pass for the three channels (the accumulators interleave them), with the injected
     * power summed per z slab and the slabs added in order: neither depends on the thread
     * count. */
    const int copies = private_acc ? extra : 0;
    const size_t z_lo = o->lo[2], z_hi = o->hi[2];
    double slab_sum[3][1024 + 1];
    const bool per_slab = z_hi - z_lo <= 1024;
    const bool clean = o->src_clean;
    const uint32_t ny = o->dims[1];
#pragma omp parallel for schedule(static) num_threads(threads) if (c_hi - c_lo > 65536)
    for (size_t zz = z_lo; zz < z_hi; zz++) {
        double sum[3] = {0.0, 0.0, 0.0};
        if (!clean)
            for (int c = 0; c < 3; c++) {
                memset(o->source[c] + zz * slab, 0, slab * sizeof(float));
                if (o->q[c])
                    memset(o->q[c] + zz * slab, 0, slab * sizeof(float));
            }
        for (uint32_t y = o->lo[1]; y < o->hi[1]; y++) {
            const uint32_t *sp = o->inj_span + 2 * (y + (size_t)ny * zz);
            const size_t row = zz * slab + (size_t)y * o->dims[0];
            for (size_t i = row + sp[0]; i < row + sp[1]; i++) {
                for (int c = 0; c < 3; c++) {
                    int64_t v = acc[3 * i + (size_t)c];
                    acc[3 * i + (size_t)c] = 0;
                    for (int k = 0; k < copies; k++) {
                        int64_t *sc = &band->scratch[3 * ((size_t)k * (size_t)cells + i) + (size_t)c];
                        v += *sc;
                        *sc = 0;
                    }
                    float sv = 0.0f;
                    if (v) {
                        double flux = (double)v * inv_scale;
                        if (face_mode)
                            sv = (float)(flux * face_factor(o, i, c));
                        else
                            sv = (float)flux;
                        sum[c] += sv;
                    }
                    o->source[c][i] = sv;
                    if (face_mode)
                        o->q[c][i] = v ? (float)((double)v * inv_scale) * inv_h2 : 0.0f;
                }
            }
        }
        if (per_slab)
            for (int c = 0; c < 3; c++)
                slab_sum[c][zz - z_lo] = sum[c];
    }
    /* the slabs outside [lo.z, hi.z) hold no solid cell and no source */
    if (!clean)
        for (int c = 0; c < 3; c++) {
            memset(o->source[c], 0, c_lo * sizeof(float));
            memset(o->source[c] + c_hi, 0, (o->cells - c_hi) * sizeof(float));
            if (o->q[c]) {
                memset(o->q[c], 0, c_lo * sizeof(float));
                memset(o->q[c] + c_hi, 0, (o->cells - c_hi) * sizeof(float));
            }
        }
    o->src_clean = true;
    o->acc_dirty = false;
    if (private_acc)
        band->scratch_dirty = false;
    for (int c = 0; c < 3; c++) {
        double sum = 0.0;
        if (per_slab) {
            for (size_t zz = z_lo; zz < z_hi; zz++)
                sum += slab_sum[c][zz - z_lo];
        } else {
            for (size_t i = c_lo; i < c_hi; i++)
                sum += o->source[c][i];
        }
        o->injected[c] = sum;
        o->tsm_flux[c] = (double)total[c] * inv_scale;
    }
    *inject_us += nc_now_us() - t0;
    return NACRE_OK;
}
