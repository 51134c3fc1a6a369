/*
 * scene_setup.c: what the path tracer builds from a committed scene before a frame: the Embree
 * scene, its objects (kind, medium, eta), lights and fogs, and the per-object grids that the
 * path loop reads: majorant grids of heterogeneous media, layer grids of layered materials,
 * rest-pose grids of deformed objects, clearance grids of media (with their lookup,
 * nc_pt_clearance, below), the triangle adjacency and refracted-sun table of dielectric objects
 * (sun_guide.c). Also the geometry of a hit on that scene (nc_pt_surface_at).
 *
 * Rest pose: an object's rest-pose point is the inverse object transform of the world point,
 * exact for objects without deformers. A deformed heterogeneous object gets a 64-voxel (longest
 * axis) grid of its deformed mesh holding each voxel's rest point (nacre_voxel_grid_rest_positions:
 * exact on the surface, first order inside), looked up by nearest voxel: the pattern follows the
 * deformation to within about a voxel.
 *
 * Grids are in world space (scene units), cut into cubic or res^3 cells over the object's
 * padded world bounds.
 *
 * Reuse (nc_pt_prepare_scene): nothing here depends on the camera, so a frame whose scene
 * differs from the built one only in the camera (an interactive viewer orbiting) keeps it. The
 * objects, lights and fogs point into the scene's arrays (materials, world positions, mesh
 * indices, light and fog records); only the edits that bump geometry, materials, lights or
 * environment versions reallocate or rewrite those (nacre_scene_set_camera writes the camera
 * alone, and a commit without a geometry change recomputes nothing), so the pointers stay valid
 * exactly as long as those versions do.
 */
#include "pathtrace/pt_internal.h"

#ifdef NACRE_HAVE_EMBREE

/* World position (barycentric, more precise than o + t d), outward geometric normal from the
 * counter-clockwise winding, and interpolated shading normal. */
void nc_pt_surface_at(const pt_object *o, const pt_hit *h, nc_vec3 *p, nc_vec3 *ng, nc_vec3 *ns)
{
    const uint32_t *tri = o->idx + 3 * (size_t)h->prim;
    nc_vec3 a = nc_v3a(o->pos + 3 * (size_t)tri[0]), b = nc_v3a(o->pos + 3 * (size_t)tri[1]),
            c = nc_v3a(o->pos + 3 * (size_t)tri[2]);
    float w = 1.0f - h->u - h->v;
    *p = nc_add(nc_add(nc_scale(a, w), nc_scale(b, h->u)), nc_scale(c, h->v));
    *ng = nc_normalize(nc_cross(nc_sub(b, a), nc_sub(c, a)));
    nc_vec3 na = nc_v3a(o->nrm + 3 * (size_t)tri[0]), nb = nc_v3a(o->nrm + 3 * (size_t)tri[1]),
            nc = nc_v3a(o->nrm + 3 * (size_t)tri[2]);
    *ns = nc_normalize(nc_add(nc_add(nc_scale(na, w), nc_scale(nb, h->u)), nc_scale(nc, h->v)));
}

const nacre_material_desc *nc_pt_material_at(const pt_scene *ps, const pt_object *o, const pt_hit *h,
                                             nacre_material_desc *tmp)
{
    const nacre_material_desc *m = o->mat;
    if (m->diffuse_map.id == 0 || !o->uv)
        return m;
    const nc_texture_rec *tex = nc_scene_texture(ps->scene, m->diffuse_map);
    if (!tex)
        return m;
    const uint32_t *tri = o->idx + 3 * (size_t)h->prim;
    float w = 1.0f - h->u - h->v;
    float u = w * o->uv[2 * (size_t)tri[0]] + h->u * o->uv[2 * (size_t)tri[1]] + h->v * o->uv[2 * (size_t)tri[2]];
    float v = w * o->uv[2 * (size_t)tri[0] + 1] + h->u * o->uv[2 * (size_t)tri[1] + 1] +
              h->v * o->uv[2 * (size_t)tri[2] + 1];
    float t[3];
    nc_texture_rgb(tex, u, v, t);
    *tmp = *m;
    for (int c = 0; c < 3; c++)
        tmp->diffuse[c] *= t[c];
    return tmp;
}

/* ---- clearance grids ---------------------------------------------------------------------
 *
 * In a dense medium (marble: a mean free path of 0.4 mm in a 60 mm block) a path scatters
 * thousands of times, and each free flight would ask Embree where the boundary is. A clearance
 * grid over each medium object stores per cell the chessboard distance, in cells, to the nearest
 * cell touched by any surface of the scene, by a sphere light or by the outside of the grid
 * (build_clearance). A surface point in a cell k cells away from point p's cell differs from p
 * by at least k - 1 cells along one axis, so (k - 1) cells is a lower bound on the distance from
 * p to any surface: a flight shorter than that needs no query, since the query could not change
 * it. The flight is sampled before the query either way, so the image is the same bit for bit. */
#define CLEARANCE_RES 192    /* at most this many cells along the object's longest axis */
#define CLEARANCE_MIN_RES 32 /* and at least this many */

/* Lower bound on the distance from p to any surface (<= 0: unknown, ask Embree). */
float nc_pt_clearance(const pt_object *o, nc_vec3 p)
{
    if (!o->dist)
        return 0.0f;
    float pv[3] = {p.x, p.y, p.z};
    size_t idx[3];
    for (int a = 0; a < 3; a++) {
        float f = (pv[a] - o->dorigin[a]) * o->dinv;
        if (!(f >= 0.0f) || f >= (float)o->ddims[a])
            return 0.0f;
        idx[a] = (size_t)f;
    }
    uint8_t k = o->dist[idx[0] + o->ddims[0] * (idx[1] + o->ddims[1] * idx[2])];
    return ((float)k - 1.0f) * o->dcell - o->dmargin;
}

void nc_pt_release_scene(nc_pathtracer *pt)
{
    nacre_context *ctx = pt->ctx;
    if (pt->rtc)
        rtcReleaseScene(pt->rtc);
    pt->rtc = NULL;
    for (uint32_t i = 0; i < pt->object_count; i++) {
        nc_free(ctx, pt->objects[i].grid);
        nc_locator_destroy(ctx, pt->objects[i].loc);
        nc_free(ctx, pt->objects[i].lbits);
        nc_free(ctx, pt->objects[i].lhint);
        nc_free(ctx, pt->objects[i].rest);
        nc_free(ctx, pt->objects[i].dist);
        nc_free(ctx, pt->objects[i].adj);
        nc_free(ctx, pt->objects[i].sun_dir);
    }
    nc_free(ctx, pt->objects);
    nc_free(ctx, pt->lights);
    pt->objects = NULL;
    pt->lights = NULL;
    pt->object_count = pt->light_count = 0;
    pt->built_valid = false;
}

/* Deformed heterogeneous objects: voxelize the deformed mesh in object space (the committed world
 * positions through the inverse object transform) and record each voxel's rest-pose point. */
#define REST_RES 64
static nacre_result build_rest_grid(nc_pathtracer *pt, pt_object *o, const nc_object_rec *rec,
                                    const nacre_mesh_data *md)
{
    nacre_context *ctx = pt->ctx;
    float *def = nc_alloc(ctx, (size_t)md->vertex_count * 3 * sizeof(float));
    if (!def)
        return NACRE_ERROR_OUT_OF_MEMORY;
    for (uint32_t v = 0; v < md->vertex_count; v++)
        nc_v3store(nc_mat4_point(&o->world_to_rest, nc_v3a(rec->world_positions + 3 * (size_t)v)), def + 3 * (size_t)v);
    nacre_mesh_data dm = *md;
    dm.positions = def;
    nacre_voxel_settings vs = nacre_voxel_settings_defaults();
    vs.resolution = REST_RES;
    vs.anisotropic = true;
    nacre_voxel_grid *grid = NULL;
    nacre_voxel_report rep;
    nacre_result res = nacre_voxelize(ctx, &dm, &vs, &grid, &rep);
    if (res == NACRE_OK) {
        size_t n = (size_t)rep.dims[0] * rep.dims[1] * rep.dims[2];
        o->rest = nc_alloc(ctx, n * 3 * sizeof(float));
        if (!o->rest)
            res = NACRE_ERROR_OUT_OF_MEMORY;
        else
            res = nacre_voxel_grid_rest_positions(grid, md, &dm, o->rest);
        memcpy(o->rdims, rep.dims, sizeof(o->rdims));
        memcpy(o->rorigin, rep.origin, sizeof(o->rorigin));
        o->rvoxel = rep.voxel_size;
    }
    nacre_voxel_grid_destroy(grid);
    nc_free(ctx, def);
    return res;
}

/* Layers of object o's material: coefficients, the stack's depth ranges and a nearest-point
 * structure over the rest-pose mesh; the global majorant grows to cover every layer. */
static nacre_result setup_layers(nc_pathtracer *pt, const pt_scene *ps, pt_object *o, const nc_object_rec *rec, const nacre_mesh_data *md)
{
    const nacre_layering *l = &o->mat->layering;
    if (l->depth_map.id && !md->uvs)
        return nc_fail(pt->ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "pathtrace: object '%s': its layered material has a depth_map but its mesh has no uvs",
                       rec->name ? rec->name : "(unnamed)");
    nc_layers_init(ps->scene, l, &o->layers);
    for (uint32_t j = 0; j < o->layers.count; j++) {
        for (int c = 0; c < 3; c++) {
            o->layer_sa[j][c] = l->layers[j].sigma_a[c];
            o->layer_ss[j][c] = l->layers[j].sigma_s[c];
            o->maj_global = fmaxf(o->maj_global, o->layer_sa[j][c] + o->layer_ss[j][c]);
        }
        o->layer_g[j] = l->layers[j].g;
    }
    return nc_locator_create(pt->ctx, pt->device, md, &o->loc);
}

/* The world bounds of an object, padded a little, cut into res^3 cells: origin and cell size. */
static void grid_box(const nc_object_rec *rec, float eps, uint32_t res, float origin[3], float cell[3])
{
    for (int a = 0; a < 3; a++) {
        float lo = rec->bounds_min[a], hi = rec->bounds_max[a];
        float pad = 1e-3f * (hi - lo) + eps;
        origin[a] = lo - pad;
        cell[a] = (hi - lo + 2 * pad) / (float)res;
    }
}

/* Layer grid and majorant grid of a layered object. Depth below the rest-pose surface is
 * 1-Lipschitz, so over a cell whose centre maps to rest point q every depth lies within
 * d(q) +- r, r the cell's half diagonal times the largest stretch of the world-to-rest map
 * (bounded by the Frobenius norm of its linear part). The layers such depths can reach at any uv
 * (nc_layers_touching) are the cell's layer bits: a cell with one bit needs no nearest-point
 * query at all (medium_at). The layer grid has LAYER_RES cells a side (rounded to a multiple of
 * the majorant grid's), and a majorant cell bounds sigma_t by the layers of its layer cells, the
 * core counting with its global bound. Deformed objects map to rest space through a voxel lookup
 * without such a bound: no layer grid, and majorant cells keep the global majorant. */
#define LAYER_RES 64
static nacre_result build_grid_layered(nc_pathtracer *pt, const pt_scene *ps, pt_object *o, const nc_object_rec *rec)
{
    uint32_t res = pt->opt.majorant_res;
    size_t n = (size_t)res * res * res;
    if (res) {
        if (!(o->grid = nc_alloc(pt->ctx, n * sizeof(float))))
            return NACRE_ERROR_OUT_OF_MEMORY;
        o->res = res;
    }
    if (o->rest) {
        for (size_t i = 0; i < n; i++)
            o->grid[i] = o->maj_global;
        if (res)
            grid_box(rec, ps->eps, res, o->gmin, o->cell);
        return NACRE_OK;
    }
    uint32_t k = res ? (LAYER_RES / res > 1 ? LAYER_RES / res : 1) : 1;
    uint32_t lres = res ? res * k : LAYER_RES;
    size_t nl = (size_t)lres * lres * lres;
    o->lbits = nc_alloc(pt->ctx, nl);
    o->lhint = nc_alloc(pt->ctx, nl * sizeof(uint32_t));
    if (!o->lbits || !o->lhint)
        return NACRE_ERROR_OUT_OF_MEMORY;
    o->lres = lres;
    float half2 = 0, lcell[3];
    grid_box(rec, ps->eps, lres, o->lmin, lcell);
    for (int a = 0; a < 3; a++) {
        o->linv[a] = 1.0f / lcell[a];
        half2 += 0.25f * lcell[a] * lcell[a];
        if (res) {
            o->gmin[a] = o->lmin[a];
            o->cell[a] = lcell[a] * (float)k;
        }
    }
    float stretch2 = 0;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            stretch2 += o->world_to_rest.m[i][j] * o->world_to_rest.m[i][j];
    /* A little slack for the rounding of the distance query and of the map. */
    float r = sqrtf(half2 * stretch2) * 1.001f + 1e-6f;
#pragma omp parallel for schedule(dynamic, 64) num_threads(nc_threads(pt->ctx))
    for (int64_t ci = 0; ci < (int64_t)nl; ci++) {
        uint32_t cx = (uint32_t)ci % lres, cy = ((uint32_t)ci / lres) % lres, cz = (uint32_t)(ci / ((int64_t)lres * lres));
        nc_vec3 c = nc_v3(o->lmin[0] + lcell[0] * ((float)cx + 0.5f), o->lmin[1] + lcell[1] * ((float)cy + 0.5f),
                          o->lmin[2] + lcell[2] * ((float)cz + 0.5f));
        nc_vec3 q = nc_mat4_point(&o->world_to_rest, c);
        float qv[3] = {q.x, q.y, q.z}, uv[2];
        /* Past the deepest bottom by more than r the cell is core only (d = INFINITY says so). */
        uint32_t near = UINT32_MAX;
        float d = nc_locator_nearest(o->loc, qv, o->layers.hi[o->layers.count - 1] + r, &near, uv);
        o->lbits[ci] = (uint8_t)nc_layers_touching(&o->layers, d - r, d + r);
        o->lhint[ci] = near;
    }
    if (res == 0)
        return NACRE_OK;
    float bound[NACRE_MAX_LAYERS + 1];
    uint32_t count = o->layers.count;
    for (uint32_t j = 0; j < count; j++)
        bound[j] = fmaxf(o->layer_sa[j][0] + o->layer_ss[j][0],
                         fmaxf(o->layer_sa[j][1] + o->layer_ss[j][1], o->layer_sa[j][2] + o->layer_ss[j][2]));
    float core[3];
    nc_pt_medium_max_fn max_fn = pt->opt.max_sigma_t ? pt->opt.max_sigma_t : nc_medium_max_sigma_t;
    max_fn(ps->scene, o->mat, core);
    bound[count] = fmaxf(core[0], fmaxf(core[1], core[2]));
    for (size_t ci = 0; ci < n; ci++) {
        uint32_t cx = (uint32_t)ci % res, cy = ((uint32_t)ci / res) % res, cz = (uint32_t)(ci / ((size_t)res * res));
        uint32_t bits = 0;
        for (uint32_t z = cz * k; z < (cz + 1) * k; z++)
            for (uint32_t y = cy * k; y < (cy + 1) * k; y++)
                for (uint32_t x = cx * k; x < (cx + 1) * k; x++)
                    bits |= o->lbits[x + (size_t)lres * (y + (size_t)lres * z)];
        float m = 0;
        for (uint32_t j = 0; j <= count; j++)
            if (bits & (1u << j))
                m = fmaxf(m, bound[j]);
        o->grid[ci] = fminf(m, o->maj_global);
    }
    return NACRE_OK;
}

/* Majorant grid of a heterogeneous object: world bounds cut into res^3 cells, each bounding
 * sigma_t (max over channels) by the maximum over a 5^3 lattice of samples (cell faces included),
 * capped by the material's global bound. */
static nacre_result build_grid(nc_pathtracer *pt, const pt_scene *ps, pt_object *o, const nc_object_rec *rec)
{
    uint32_t res = pt->opt.majorant_res;
    if (res == 0)
        return NACRE_OK;
    size_t n = (size_t)res * res * res;
    o->grid = nc_alloc(pt->ctx, n * sizeof(float));
    if (!o->grid)
        return NACRE_ERROR_OUT_OF_MEMORY;
    o->res = res;
    grid_box(rec, ps->eps, res, o->gmin, o->cell);
    enum { S = 5 };
#pragma omp parallel for schedule(static) num_threads(nc_threads(pt->ctx))
    for (int64_t ci = 0; ci < (int64_t)n; ci++) {
        uint32_t cx = (uint32_t)ci % res, cy = ((uint32_t)ci / res) % res, cz = (uint32_t)ci / (res * res);
        float xyz[S * S * S * 3], sa[S * S * S * 3], ss[S * S * S * 3];
        int k = 0;
        for (int i = 0; i < S; i++)
            for (int j = 0; j < S; j++)
                for (int l = 0; l < S; l++) {
                    nc_vec3 w = nc_v3(o->gmin[0] + o->cell[0] * ((float)cx + (float)i / (S - 1)),
                                      o->gmin[1] + o->cell[1] * ((float)cy + (float)j / (S - 1)),
                                      o->gmin[2] + o->cell[2] * ((float)cz + (float)l / (S - 1)));
                    nc_pt_rest_point(o, w, xyz + 3 * k);
                    k++;
                }
        ps->eval(ps->scene, o->mat, xyz, (size_t)k, sa, ss);
        float m = 0;
        for (int q = 0; q < 3 * k; q++)
            m = fmaxf(m, sa[q] + ss[q]);
        o->grid[ci] = fminf(m, o->maj_global);
    }
    return NACRE_OK;
}

/* Mark cells overlapped by the box [lo, hi] (world) as surface cells. */
static void mark_box(pt_object *o, const float lo[3], const float hi[3])
{
    uint32_t i0[3], i1[3];
    for (int a = 0; a < 3; a++) {
        float f0 = floorf((lo[a] - o->dmargin - o->dorigin[a]) / o->dcell);
        float f1 = floorf((hi[a] + o->dmargin - o->dorigin[a]) / o->dcell);
        float top = (float)(o->ddims[a] - 1);
        if (!(f1 >= 0.0f) || !(f0 <= top))
            return; /* outside (or NaN): the grid's border already bounds it */
        i0[a] = f0 < 0.0f ? 0u : (uint32_t)f0;
        i1[a] = f1 > top ? o->ddims[a] - 1 : (uint32_t)f1;
    }
    for (uint32_t z = i0[2]; z <= i1[2]; z++)
        for (uint32_t y = i0[1]; y <= i1[1]; y++)
            memset(o->dist + i0[0] + (size_t)o->ddims[0] * (y + (size_t)o->ddims[1] * z), 0, i1[0] - i0[0] + 1);
}

/* One raster pass of the chessboard distance transform: each cell takes the minimum over its
 * 13 neighbours already visited in scan order (dir = +1 forward, -1 backward) plus one. Two
 * passes give the exact chessboard distance (Rosenfeld and Pfaltz 1966). */
static void chamfer_pass(uint8_t *d, const uint32_t dims[3], int dir)
{
    int64_t nx = dims[0], ny = dims[1], nz = dims[2];
    for (int64_t zz = 0; zz < nz; zz++)
        for (int64_t yy = 0; yy < ny; yy++)
            for (int64_t xx = 0; xx < nx; xx++) {
                int64_t x = dir > 0 ? xx : nx - 1 - xx, y = dir > 0 ? yy : ny - 1 - yy, z = dir > 0 ? zz : nz - 1 - zz;
                uint8_t *c = d + x + nx * (y + ny * z);
                int best = *c;
                if (best == 0)
                    continue;
                for (int dz = -1; dz <= 0; dz++)
                    for (int dy = -1; dy <= 1; dy++)
                        for (int dx = -1; dx <= 1; dx++) {
                            if (dz == 0 && (dy > 0 || (dy == 0 && dx >= 0)))
                                continue; /* not yet visited in this scan order */
                            int64_t qx = x + dir * dx, qy = y + dir * dy, qz = z + dir * dz;
                            if (qx < 0 || qy < 0 || qz < 0 || qx >= nx || qy >= ny || qz >= nz)
                                continue;
                            int v = d[qx + nx * (qy + ny * qz)] + 1;
                            best = v < best ? v : best;
                        }
                *c = (uint8_t)best;
            }
}

/* Clearance grid of medium object `o` (see nc_pt_clearance()): cubic cells over its bounds plus one
 * cell of border; cells touched by the bounding box of any triangle of any object, or of any
 * sphere light, are surface cells; cells are also at most their chessboard distance from the
 * outside of the grid, which stands for everything beyond it. The margin absorbs rounding in
 * cell lookups and Embree's hits reported a little before the surface. */
static nacre_result build_clearance(nc_pathtracer *pt, const pt_scene *ps, pt_object *o, const nc_object_rec *rec)
{
    if (pt->opt.no_clearance)
        return NACRE_OK;
    float ext = 0;
    for (int a = 0; a < 3; a++)
        ext = fmaxf(ext, rec->bounds_max[a] - rec->bounds_min[a]);
    if (!(ext > 0) || !isfinite(ext))
        return NACRE_OK;
    /* Cells of about half a mean free path of the densest channel make most flights provably
     * short; at most CLEARANCE_RES cells along the longest axis bound memory and build time. */
    float st = o->heterogeneous ? o->maj_global
                                : fminf(o->sigma_a[0] + o->sigma_s[0],
                                        fminf(o->sigma_a[1] + o->sigma_s[1], o->sigma_a[2] + o->sigma_s[2]));
    o->dcell = ext / (float)CLEARANCE_RES;
    if (st > 0.0f && 0.5f / st > o->dcell)
        o->dcell = fminf(0.5f / st, ext / (float)CLEARANCE_MIN_RES);
    /* Cells below the scene's float resolution (a tiny or degenerate object) would bound
     * nothing, and a zero cell size has no grid at all: no clearance then (Embree is asked). */
    if (!(o->dcell >= ps->eps) || !isfinite(o->dcell))
        return NACRE_OK;
    o->dinv = 1.0f / o->dcell;
    o->dmargin = 0.01f * o->dcell + 4.0f * ps->eps;
    size_t n = 1;
    for (int a = 0; a < 3; a++) {
        o->dorigin[a] = rec->bounds_min[a] - o->dcell;
        float cells = ceilf((rec->bounds_max[a] - rec->bounds_min[a]) / o->dcell) + 2.0f;
        o->ddims[a] = !(cells >= 1.0f) ? 1u : cells > (float)(CLEARANCE_RES + 4) ? CLEARANCE_RES + 4 : (uint32_t)cells;
        n *= o->ddims[a];
    }
    o->dist = nc_alloc(pt->ctx, n);
    if (!o->dist)
        return NACRE_ERROR_OUT_OF_MEMORY;
    for (uint32_t z = 0; z < o->ddims[2]; z++)
        for (uint32_t y = 0; y < o->ddims[1]; y++)
            for (uint32_t x = 0; x < o->ddims[0]; x++) {
                uint32_t c[3] = {x, y, z}, k = 255;
                for (int a = 0; a < 3; a++) {
                    uint32_t e = c[a] + 1 < o->ddims[a] - c[a] ? c[a] + 1 : o->ddims[a] - c[a];
                    k = e < k ? e : k;
                }
                o->dist[x + (size_t)o->ddims[0] * (y + (size_t)o->ddims[1] * z)] = (uint8_t)k;
            }
    for (uint32_t j = 0; j < pt->object_count; j++) {
        const pt_object *q = &pt->objects[j];
        for (uint32_t t = 0; t < q->tri_count; t++) {
            const uint32_t *tri = q->idx + 3 * (size_t)t;
            float lo[3], hi[3];
            for (int a = 0; a < 3; a++) {
                float v0 = q->pos[3 * (size_t)tri[0] + (size_t)a], v1 = q->pos[3 * (size_t)tri[1] + (size_t)a],
                      v2 = q->pos[3 * (size_t)tri[2] + (size_t)a];
                lo[a] = fminf(v0, fminf(v1, v2));
                hi[a] = fmaxf(v0, fmaxf(v1, v2));
            }
            mark_box(o, lo, hi);
        }
    }
    for (uint32_t li = 0; li < pt->light_count; li++) {
        const pt_light *l = &pt->lights[li];
        if (l->type == NACRE_LIGHT_DIRECTIONAL || l->delta)
            continue;
        float lo[3] = {l->pos.x - l->radius, l->pos.y - l->radius, l->pos.z - l->radius};
        float hi[3] = {l->pos.x + l->radius, l->pos.y + l->radius, l->pos.z + l->radius};
        mark_box(o, lo, hi);
    }
    chamfer_pass(o->dist, o->ddims, 1);
    chamfer_pass(o->dist, o->ddims, -1);
    return NACRE_OK;
}

/* Triangle adjacency of a dielectric object for nc_pt_make_guide's walk. Edges are matched by vertex
 * position, not index, so that seams (split normals or texture coordinates) do not stop the walk;
 * an edge shared by more than two triangles links none of them. */
typedef struct adj_edge {
    float a[3], b[3]; /* endpoints, lexicographically ordered */
    uint32_t slot;    /* 3 * triangle + edge */
} adj_edge;

static int cmp_point(const float *p, const float *q)
{
    for (int k = 0; k < 3; k++)
        if (p[k] != q[k])
            return p[k] < q[k] ? -1 : 1;
    return 0;
}

static int cmp_edge(const void *x, const void *y)
{
    const adj_edge *e = x, *f = y;
    int c = cmp_point(e->a, f->a);
    return c ? c : cmp_point(e->b, f->b);
}

static nacre_result build_adjacency(nc_pathtracer *pt, pt_object *o)
{
    size_t n = 3 * (size_t)o->tri_count;
    adj_edge *edges = nc_alloc(pt->ctx, n * sizeof(*edges));
    o->adj = nc_alloc(pt->ctx, n * sizeof(uint32_t));
    if (!edges || !o->adj) {
        nc_free(pt->ctx, edges);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    for (size_t i = 0; i < n; i++) {
        const float *p = o->pos + 3 * (size_t)o->idx[i], *q = o->pos + 3 * (size_t)o->idx[i % 3 == 2 ? i - 2 : i + 1];
        if (cmp_point(p, q) > 0) {
            const float *t = p;
            p = q;
            q = t;
        }
        memcpy(edges[i].a, p, sizeof(edges[i].a));
        memcpy(edges[i].b, q, sizeof(edges[i].b));
        edges[i].slot = (uint32_t)i;
        o->adj[i] = UINT32_MAX;
    }
    qsort(edges, n, sizeof(*edges), cmp_edge);
    for (size_t i = 0; i < n;) {
        size_t j = i + 1;
        while (j < n && cmp_edge(&edges[i], &edges[j]) == 0)
            j++;
        if (j == i + 2) {
            o->adj[edges[i].slot] = edges[i + 1].slot / 3;
            o->adj[edges[i + 1].slot] = edges[i].slot / 3;
        }
        i = j;
    }
    nc_free(pt->ctx, edges);
    return NACRE_OK;
}

/* The scene's lights with non-zero strength, in scene order: directions, cones and radiances
 * (see lights.c for the radiometry). */
static void setup_lights(nc_pathtracer *pt, const nacre_scene *s)
{
    for (uint32_t i = 0; i < s->light_count; i++) {
        const nacre_light_desc *ld = &s->lights[i].desc;
        pt_light *l = &pt->lights[pt->light_count];
        nc_vec3 strength = nc_v3a(ld->strength);
        if (max3(strength) <= 0)
            continue;
        l->type = ld->type;
        l->desc = ld;
        if (ld->type == NACRE_LIGHT_DIRECTIONAL) {
            l->to_light = nc_normalize(nc_scale(nc_v3a(ld->direction), -1.0f));
            float r = ld->angular_radius * NC_DEG2RAD;
            l->delta = !(r > 0);
            if (l->delta) {
                l->value = strength;
            } else {
                float sr = sinf(r);
                l->cos_max = cosf(r);
                float one_minus = sr * sr / (1.0f + l->cos_max);
                l->cone_pdf = 1.0f / (2.0f * PT_PI * one_minus);
                l->value = nc_scale(strength, 1.0f / (PT_PI * sr * sr));
            }
        } else {
            l->pos = nc_v3a(ld->position);
            l->radius = ld->radius;
            l->delta = !(ld->radius > 0);
            l->value = l->delta ? strength : nc_scale(strength, 1.0f / (PT_PI * ld->radius * ld->radius));
        }
        pt->light_count++;
    }
}

/* The scene's fogs: shapes, pattern bounds and height falloff (see "fog" in media.c). */
static void setup_fogs(nc_pathtracer *pt, const nacre_scene *s, nc_pt_medium_max_fn max_fn)
{
    pt->fog_count = s->fog_count;
    pt->fog_mixed_g = false;
    pt->fog_emissive = false;
    for (uint32_t i = 0; i < s->fog_count; i++) {
        const nc_fog_rec *rec = &s->fogs[i];
        pt_fog *f = &pt->fogs[i];
        f->rec = rec;
        f->box = rec->desc.shape == NACRE_FOG_BOX;
        f->ellipsoid = rec->desc.shape == NACRE_FOG_SPHERE;
        for (int a = 0; a < 3; a++)
            f->half[a] = 0.5f * rec->desc.size[a];
        f->patterned = nc_medium_heterogeneous(&rec->medium);
        float mx[3];
        max_fn(s, &rec->medium, mx);
        f->maj = fmaxf(mx[0], fmaxf(mx[1], mx[2]));
        f->height = rec->desc.height_falloff > 0;
        f->hexp = nc_vol_height_exp_cap(f->height, f->maj);
        f->emissive = rec->emissive;
        f->emission_patterned = rec->emission_patterned;
        /* Emission is gathered at tentative collisions (media.c): a bounded fog that emits gets
         * a majorant of at least 2 / (smallest half edge), 4 collisions across that edge on
         * average, even where it barely absorbs (or not at all: its light is then e d). Set
         * after the cap above, which stays the one the other passes use. */
        if (f->emissive && (f->box || f->ellipsoid)) {
            float h = fminf(f->half[0], fminf(f->half[1], f->half[2]));
            f->maj = fmaxf(f->maj, 2.0f / h);
        }
        pt->fog_emissive |= f->emissive;
        f->falloff = rec->desc.height_falloff;
        f->base = rec->desc.height_base;
        f->g = rec->desc.g;
        pt->fog_mixed_g |= f->g != pt->fogs[0].g;
    }
}

/* The path tracer's copy of committed scene s: objects with their grids, the Embree scene,
 * lights and fogs (replacing the previous scene's). The grids sample media through ps->eval. */
nacre_result nc_pt_build_scene(nc_pathtracer *pt, const nacre_scene *s, pt_scene *ps)
{
    nacre_context *ctx = pt->ctx;
    nc_pt_release_scene(pt);
    pt->objects = nc_calloc(ctx, s->object_count, sizeof(*pt->objects));
    pt->lights = nc_calloc(ctx, s->light_count + 1, sizeof(*pt->lights));
    if (!pt->objects || !pt->lights)
        return NACRE_ERROR_OUT_OF_MEMORY;
    pt->object_count = s->object_count;
    pt->any_matched = false;
    pt->any_noncaster = false;
    pt->nee_only = false;
    pt->rtc = rtcNewScene(pt->device);
    rtcSetSceneFlags(pt->rtc, RTC_SCENE_FLAG_ROBUST);
    rtcSetSceneBuildQuality(pt->rtc, RTC_BUILD_QUALITY_HIGH);
    nc_pt_medium_max_fn max_fn = pt->opt.max_sigma_t ? pt->opt.max_sigma_t : nc_medium_max_sigma_t;
    for (uint32_t i = 0; i < s->object_count; i++) {
        const nc_object_rec *rec = &s->objects[i];
        const nacre_mesh_data *md = &s->meshes[rec->desc.mesh.id - 1].data;
        const nacre_material_desc *m = &s->materials[rec->desc.material.id - 1];
        pt_object *o = &pt->objects[i];
        o->mat = m;
        o->pos = rec->world_positions;
        o->nrm = rec->world_normals;
        o->idx = md->indices;
        o->uv = md->uvs;
        o->tri_count = md->triangle_count;
        o->g = m->g;
        o->eta = m->eta;
        if (m->type == NACRE_MATERIAL_OPAQUE) {
            o->kind = PT_OPAQUE;
            o->casts = rec->desc.cast_shadows;
            pt->any_noncaster |= !o->casts;
        } else {
            o->kind = m->eta == 1.0f ? PT_MATCHED : PT_DIELECTRIC;
            o->casts = true;
            pt->any_matched |= o->kind == PT_MATCHED;
            const bool layered = m->layering.count > 0;
            o->heterogeneous = nc_medium_heterogeneous(m) || layered || pt->opt.force_heterogeneous;
            float mx[3];
            max_fn(s, m, mx);
            o->maj_global = fmaxf(mx[0], fmaxf(mx[1], mx[2]));
            if (layered) {
                nacre_result res = setup_layers(pt, ps, o, rec, md);
                if (res != NACRE_OK)
                    return res;
            }
            for (int c = 0; c < 3; c++) {
                o->sigma_a[c] = m->sigma_a[c];
                o->sigma_s[c] = m->sigma_s[c];
            }
            nc_mat4_inverse(rec->object_to_world, &o->world_to_rest);
            if (o->kind == PT_DIELECTRIC) {
                nacre_result res = build_adjacency(pt, o);
                if (res != NACRE_OK)
                    return res;
            }
            if (o->heterogeneous) {
                nacre_result res = rec->desc.deformer_count > 0 ? build_rest_grid(pt, o, rec, md) : NACRE_OK;
                if (res != NACRE_OK)
                    return res;
                res = layered ? build_grid_layered(pt, ps, o, rec) : build_grid(pt, ps, o, rec);
                if (res != NACRE_OK)
                    return res;
            }
        }
        RTCGeometry g = rtcNewGeometry(pt->device, RTC_GEOMETRY_TYPE_TRIANGLE);
        /* Embree reads vertex buffers 16 bytes at a time: its own buffers are padded for that. */
        float *vb = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float),
                                            md->vertex_count);
        unsigned *ib = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned),
                                               md->triangle_count);
        if (!vb || !ib) {
            rtcReleaseGeometry(g);
            return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "pathtrace: Embree buffer allocation failed");
        }
        memcpy(vb, rec->world_positions, (size_t)md->vertex_count * 3 * sizeof(float));
        memcpy(ib, md->indices, (size_t)md->triangle_count * 3 * sizeof(unsigned));
        rtcCommitGeometry(g);
        rtcAttachGeometryByID(pt->rtc, g, i);
        rtcReleaseGeometry(g);
    }
    rtcCommitScene(pt->rtc);
    if (rtcGetDeviceError(pt->device) != RTC_ERROR_NONE)
        return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "pathtrace: Embree scene build failed");

    setup_lights(pt, s);
    setup_fogs(pt, s, max_fn);
    pt->nee_only = pt->any_noncaster;
    for (uint32_t li = 0; li < pt->light_count && !pt->opt.no_sun_guiding; li++) {
        const pt_light *l = &pt->lights[li];
        if (l->type != NACRE_LIGHT_DIRECTIONAL || l->delta)
            continue;
        /* The guided sun (the first one, as trace_path picks it). */
        for (uint32_t i = 0; i < pt->object_count; i++) {
            pt_object *o = &pt->objects[i];
            if (o->kind != PT_DIELECTRIC)
                continue;
            if (!(o->sun_dir = nc_alloc(ctx, 3 * (size_t)o->tri_count * sizeof(float))))
                return NACRE_ERROR_OUT_OF_MEMORY;
            for (uint32_t t = 0; t < o->tri_count; t++) {
                nc_vec3 dir = {NAN, 0, 0};
                nc_pt_refract_sun_facet(o, l, t, &dir);
                memcpy(o->sun_dir + 3 * (size_t)t, &dir, 3 * sizeof(float));
            }
        }
        break;
    }
    /* After every object and light is known: the grids record all of them. */
    for (uint32_t i = 0; i < pt->object_count; i++) {
        if (pt->objects[i].kind == PT_OPAQUE)
            continue;
        nacre_result res = build_clearance(pt, ps, &pt->objects[i], &s->objects[i]);
        if (res != NACRE_OK)
            return res;
    }
    return NACRE_OK;
}

/* Whether s holds what its last commit saw: an uncommitted edit may already have reallocated
 * arrays without the committed versions saying so, so such a scene is never matched to a
 * cache by them. */
bool nc_pt_scene_settled(const nacre_scene *s)
{
    return s->committed_valid && memcmp(&s->committed, &s->versions, sizeof(s->versions)) == 0;
}

/* nc_pt_build_scene unless the built scene is already a copy of s: the same scene (uid, within
 * its context, as uids are per context) with the same committed versions but for the camera. */
nacre_result nc_pt_prepare_scene(nc_pathtracer *pt, const nacre_scene *s, pt_scene *ps)
{
    nc_versions v = s->committed, b = pt->built_versions;
    v.camera = b.camera = 0;
    if (pt->built_valid && s->ctx == pt->ctx && s->uid == pt->built_uid && nc_pt_scene_settled(s) &&
        memcmp(&v, &b, sizeof(v)) == 0)
        return NACRE_OK;
    nacre_result res = nc_pt_build_scene(pt, s, ps);
    if (res != NACRE_OK) {
        nc_pt_release_scene(pt); /* a half-built scene must not be mistaken for a copy */
        return res;
    }
    pt->built_valid = true;
    pt->built_uid = s->uid;
    pt->built_versions = s->committed;
    return NACRE_OK;
}

#endif /* NACRE_HAVE_EMBREE */
