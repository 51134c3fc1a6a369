/*
 * pipeline.c: `--method diffusion`, the per-object frame pipeline of Blanchard 2012 chapter 4:
 * voxelize (seed 4.2) -> medium per voxel (heterogeneous media following deformation, seed
 * chapter 5, figures 5.8-5.11) ->
 * translucent shadow maps and injection (seed 4.3, 4.4; tsm.c) -> propagation (seed 4.5;
 * solver.c) -> exitance per cell for the shading pass (seed 4.6; shade_diffusion.c).
 *
 * The voxelization is of the committed world-space mesh, a cubic grid of `voxel_resolution`
 * cells along the longest axis (the seed's constant, mesh-dependent volume); the domain is the
 * solid set of level 0 (cells whose centre is inside). The solid rule is decided once by AUTO
 * (which welds and analyses the mesh) and reused, since deformation does not change topology.
 * Heterogeneous media are evaluated at each voxel centre's rest-pose point, so the pattern moves
 * with the surface (seed figure 5.11): the inverse object transform for an undeformed object
 * (exact), nacre_voxel_grid_rest_positions for a deformed one (first order). sigma_s' = sigma_s (1 - g).
 *
 * Caches, per object: the grid and medium while the scene geometry, the material list and the
 * resolution are unchanged; the solution while the lights and diffusion settings are unchanged
 * too (a camera move only re-shades). The fluence of the previous frame warm-starts the solver
 * whenever the grid has the same dims.
 *
 * Layered materials (nacre_layering): the medium step gives each voxel the mean of its layers'
 * and core's coefficients over its cell (layered_medium). For the layered method's multiple
 * scattering (nc_diff_state.multiple_only, issue 23 item 5) it also gives the part of the first
 * scattering's source that scatters again, by which the sources are scaled after injection, so
 * that the solution is the light of scattering orders 2 and up (the march gives order 1). The
 * diffusion method's single-scattering option (settings.diffusion.single_scattering, single.c)
 * does the same for any translucent material, its first order marched per pixel.
 *
 * Units: world space, scene units (pipeline.h). Timings go to the VOXELIZE, MEDIUM (coefficients
 * per voxel), TSM, INJECT and PROPAGATE (solver setup and solves, exitance) stages; each counts
 * the objects it ran for in stage_runs.
 */
#include "diffusion/pipeline.h"
#include "core/math.h"
#include "core/optics.h"
#include "layered/layers.h"
#include "scene/medium.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

/* ------------------------------------------------------------------------------------------ */
/* Object state                                                                               */
/* ------------------------------------------------------------------------------------------ */

static void free_arrays(nc_diff_object *o)
{
    nacre_context *ctx = o->ctx;
    nc_free(ctx, o->solid);
    nc_free(ctx, o->depth);
    nc_free(ctx, o->bscale);
    o->depth = o->bscale = NULL;
    nc_free(ctx, o->rest);
    nc_free(ctx, o->eval_a);
    nc_free(ctx, o->eval_s);
    nc_free(ctx, o->packed);
    nc_free(ctx, o->acc);
    nc_free(ctx, o->exit_span);
    nc_free(ctx, o->inj_span);
    nc_free(ctx, o->faces);
    o->faces = NULL;
    o->face_capacity = o->face_count = 0;
    o->faces_valid = false;
    o->inj_span = NULL;
    o->inj_span_capacity = 0;
    o->inj_valid = o->src_clean = o->acc_dirty = false;
    nc_free(ctx, o->packed_ghost);
    o->packed_ghost = NULL;
    o->ghost_capacity = 0;
    o->ghosts = false;
    o->packed = NULL;
    o->packed_capacity = 0;
    o->exit_span = NULL;
    o->exit_span_capacity = 0;
    o->exit_valid = false;
    o->acc = NULL;
    o->solid = NULL;
    o->rest = o->eval_a = o->eval_s = NULL;
    for (int c = 0; c < 3; c++) {
        nc_free(ctx, o->sigma_a[c]);
        nc_free(ctx, o->sigma_sp[c]);
        nc_free(ctx, o->source[c]);
        nc_free(ctx, o->q[c]);
        nc_free(ctx, o->phi[c]);
        nc_free(ctx, o->exitance[c]);
        nc_free(ctx, o->ms_keep[c]);
        o->sigma_a[c] = o->sigma_sp[c] = o->source[c] = o->q[c] = o->phi[c] = o->exitance[c] = o->ms_keep[c] = NULL;
    }
    o->capacity = 0;
    o->phi_valid = false;
}

void nc_diff_object_free(nc_diff_object *o)
{
    if (!o || !o->ctx)
        return;
    free_arrays(o);
    for (uint32_t k = 0; k < o->lmap_capacity; k++)
        nc_free(o->ctx, o->lmap[k].texel);
    nc_free(o->ctx, o->lmap);
    nacre_voxel_grid_destroy(o->grid);
    nc_diff_solver_destroy(o->solver);
    memset(o, 0, sizeof(*o));
}

/* The per-cell arrays for `cells` cells: the always-needed ones now, the heterogeneous and
 * face-mode ones on first use. Contents are not preserved when the grid grows. */
static nacre_result ensure_arrays(nc_diff_object *o, size_t cells)
{
    if (cells <= o->capacity)
        return NACRE_OK;
    free_arrays(o);
    size_t bytes;
    if (!nc_mul_size_ok(cells, 3 * sizeof(float), &bytes))
        return nc_fail(o->ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: voxel grid too large");
    o->solid = nc_calloc(o->ctx, cells, 1);
    o->acc = nc_calloc(o->ctx, cells, 3 * sizeof(int64_t));
    o->depth = nc_alloc(o->ctx, cells * sizeof(float));
    o->bscale = nc_alloc(o->ctx, cells * sizeof(float));
    bool ok = o->solid != NULL && o->acc != NULL && o->depth != NULL && o->bscale != NULL;
    for (int c = 0; c < 3 && ok; c++) {
        o->source[c] = nc_calloc(o->ctx, cells, sizeof(float));
        o->phi[c] = nc_calloc(o->ctx, cells, sizeof(float));
        o->exitance[c] = nc_calloc(o->ctx, cells, sizeof(float));
        ok = o->source[c] && o->phi[c] && o->exitance[c];
    }
    if (!ok) {
        free_arrays(o);
        return nc_fail(o->ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory for a %zu-cell grid", cells);
    }
    o->capacity = cells;
    return NACRE_OK;
}

static nacre_result ensure_optional(nc_diff_object *o, bool hetero, bool face)
{
    bool ok = true;
    if (hetero && !o->rest) {
        o->rest = nc_alloc(o->ctx, o->capacity * 3 * sizeof(float));
        o->eval_a = nc_alloc(o->ctx, o->capacity * 3 * sizeof(float));
        o->eval_s = nc_alloc(o->ctx, o->capacity * 3 * sizeof(float));
        for (int c = 0; c < 3; c++) {
            o->sigma_a[c] = nc_calloc(o->ctx, o->capacity, sizeof(float));
            o->sigma_sp[c] = nc_calloc(o->ctx, o->capacity, sizeof(float));
            ok = ok && o->sigma_a[c] && o->sigma_sp[c];
        }
        ok = ok && o->rest && o->eval_a && o->eval_s;
    }
    if (hetero && o->multiple_only && !o->ms_keep[0])
        for (int c = 0; c < 3; c++) {
            o->ms_keep[c] = nc_calloc(o->ctx, o->capacity, sizeof(float));
            ok = ok && o->ms_keep[c];
        }
    if (face && !o->q[0])
        for (int c = 0; c < 3; c++) {
            o->q[c] = nc_calloc(o->ctx, o->capacity, sizeof(float));
            ok = ok && o->q[c];
        }
    if (!ok) {
        free_arrays(o);
        return nc_fail(o->ctx, NACRE_ERROR_OUT_OF_MEMORY, "diffusion: out of memory for the medium");
    }
    return NACRE_OK;
}

/* World-space copy of the object's mesh description (positions borrowed from the commit). */
static nacre_mesh_data world_mesh(const nacre_scene *s, const nc_object_rec *obj)
{
    nacre_mesh_data m = s->meshes[obj->desc.mesh.id - 1].data;
    m.positions = obj->world_positions;
    m.normals = NULL;
    m.tangents = NULL;
    m.uvs = NULL;
    return m;
}

/* o->depth: for each boundary cell (solid with an exposed face, the cells whose Robin terms let
 * light out), the distance from its centre to the nearest triangle of the mesh. Solid cells have
 * their centres inside the mesh (the voxelizer's parity rule), so this is the centre's depth
 * below the true surface, between 0 and about a cell: the face a cell centre's flux crosses
 * (the staircase, h / 2 away) is not where the surface is, and object_setup corrects the
 * boundary condition for it. The mesh crosses the segment from a boundary cell's centre to its
 * empty neighbour's, so only triangles within a cell of a centre matter: each triangle visits
 * the cells of its bounding box grown by one cell, about 27 distance tests for a triangle
 * smaller than a cell. A mesh of more than NC_DIFF_DEPTH_TRIANGLES triangles per boundary cell
 * keeps the staircase's depth (NAN everywhere): its triangles are smaller than the cells, the
 * pass would cost more than the rest of the voxelization (Suzanne's 15.7k triangles at 28^3:
 * a few ms against 0.45 ms), and the staircase of such a grid is no rougher than its mesh's
 * detail. Threads take slabs of z and every triangle that reaches them, so each cell's minimum is
 * over the same triangles whatever the thread count. */
#define NC_DIFF_DEPTH_TRIANGLES 4
static void boundary_depths(nc_diff_object *o, const nacre_mesh_data *dm)
{
    const uint32_t nx = o->dims[0], ny = o->dims[1], nz = o->dims[2];
    const size_t sy = nx, sz = (size_t)nx * ny;
    const uint8_t *solid = o->solid;
    float *depth = o->depth;
    size_t boundary = 0;
    for (size_t i = 0; i < o->cells; i++)
        depth[i] = NAN;
    for (uint32_t z = o->lo[2]; z < o->hi[2]; z++)
        for (uint32_t y = o->lo[1]; y < o->hi[1]; y++)
            for (uint32_t x = o->lo[0]; x < o->hi[0]; x++) {
                const size_t i = x + sy * y + sz * z;
                if (!solid[i])
                    continue;
                const bool b = x == 0 || y == 0 || z == 0 || x == nx - 1 || y == ny - 1 || z == nz - 1 ||
                               !solid[i - 1] || !solid[i + 1] || !solid[i - sy] || !solid[i + sy] ||
                               !solid[i - sz] || !solid[i + sz];
                if (b) {
                    depth[i] = INFINITY;
                    boundary++;
                }
            }
    if ((double)dm->triangle_count > (double)NC_DIFF_DEPTH_TRIANGLES * (double)boundary) {
        for (size_t i = 0; i < o->cells; i++)
            depth[i] = NAN;
        return;
    }
    const float h = o->h, inv_h = 1.0f / h;
    const uint32_t dims[3] = {nx, ny, nz};
    const int threads = nc_threads(o->ctx), slabs = threads > 1 && o->cells > 32768 ? threads : 1;
#pragma omp parallel for schedule(static, 1) num_threads(slabs)
    for (int slab = 0; slab < slabs; slab++) {
        const int z0 = (int)((uint64_t)nz * (uint64_t)slab / (uint64_t)slabs),
                  z1 = (int)((uint64_t)nz * (uint64_t)(slab + 1) / (uint64_t)slabs) - 1;
        for (size_t t = 0; t < dm->triangle_count; t++) {
            const uint32_t *ti = dm->indices + 3 * t;
            if (ti[0] >= dm->vertex_count || ti[1] >= dm->vertex_count || ti[2] >= dm->vertex_count)
                continue;
            const float *v[3] = {dm->positions + 3 * (size_t)ti[0], dm->positions + 3 * (size_t)ti[1],
                                 dm->positions + 3 * (size_t)ti[2]};
            int lo[3], hi[3];
            bool empty = false;
            for (int a = 0; a < 3 && !empty; a++) {
                const float mn = fminf(v[0][a], fminf(v[1][a], v[2][a])),
                            mx = fmaxf(v[0][a], fmaxf(v[1][a], v[2][a]));
                /* cells whose centre (k + 1/2) h + origin is within h of [mn, mx] */
                const float gl = (mn - o->origin[a]) * inv_h - 1.5f, gh = (mx - o->origin[a]) * inv_h + 0.5f;
                if (!(gl < 1e6f && gh > -1e6f)) { /* also NaN */
                    empty = true;
                    break;
                }
                lo[a] = gl < 0.0f ? 0 : (int)ceilf(gl);
                hi[a] = gh >= (float)dims[a] ? (int)dims[a] - 1 : (int)floorf(gh);
                empty = lo[a] > hi[a];
            }
            if (empty)
                continue;
            /* unit normal: the distance to the plane bounds the distance to the triangle from
             * below, which skips most tests once a cell has a near triangle (0: degenerate) */
            float n[3];
            nc_v3store(nc_normalize(nc_cross(nc_sub(nc_v3a(v[1]), nc_v3a(v[0])), nc_sub(nc_v3a(v[2]), nc_v3a(v[0])))), n);
            lo[2] = lo[2] > z0 ? lo[2] : z0;
            hi[2] = hi[2] < z1 ? hi[2] : z1;
            for (int z = lo[2]; z <= hi[2]; z++)
                for (int y = lo[1]; y <= hi[1]; y++)
                    for (int x = lo[0]; x <= hi[0]; x++) {
                        const size_t i = (size_t)x + sy * (size_t)y + sz * (size_t)z;
                        if (!(depth[i] > 0.0f)) /* NaN: not a boundary cell; 0: on the surface */
                            continue;
                        const float p[3] = {o->origin[0] + ((float)x + 0.5f) * h,
                                            o->origin[1] + ((float)y + 0.5f) * h,
                                            o->origin[2] + ((float)z + 0.5f) * h};
                        const float dp = (p[0] - v[0][0]) * n[0] + (p[1] - v[0][1]) * n[1] + (p[2] - v[0][2]) * n[2];
                        if (dp * dp >= depth[i])
                            continue;
                        float wb, wc;
                        const float d2 = nc_closest_on_triangle(p, v[0], v[1], v[2], &wb, &wc);
                        depth[i] = d2 < depth[i] ? d2 : depth[i];
                    }
        }
    }
    /* squared distances to distances; a boundary cell with no triangle within a cell (a mesh
     * that is not closed, a thin sliver) keeps the staircase's depth */
    const float reach2 = 2.0f * h * h;
    for (size_t i = 0; i < o->cells; i++)
        if (depth[i] >= 0.0f)
            depth[i] = depth[i] <= reach2 ? sqrtf(depth[i]) : NAN;
}

nacre_result nc_diff_object_voxelize(nc_diff_object *o, const nacre_scene *s, uint32_t index, uint32_t resolution)
{
    nacre_context *ctx = o->ctx;
    const nc_object_rec *obj = &s->objects[index];
    nacre_mesh_data dm = world_mesh(s, obj);
    o->index = index;
    nacre_voxel_settings vs = nacre_voxel_settings_defaults();
    vs.resolution = resolution;
    vs.anisotropic = false;
    /* A different mesh may have a different topology: decide the rule again. */
    if (o->rule_mesh != obj->desc.mesh.id)
        o->rule_known = false;
    vs.solid_rule = o->rule_known ? o->rule : NACRE_VOXEL_SOLID_AUTO;
    /* The estimate before anything is made: the pipeline's per-cell arrays, the solver's levels
     * and the voxel sets come to about 390 bytes per cell of the res^3 grid (measured peaks at
     * 64^3 and 128^3); only a grid larger than the one held counts. */
    uint64_t cells = (uint64_t)resolution * resolution * resolution;
    if (cells > o->capacity) {
        char what[96];
        if (obj->name)
            snprintf(what, sizeof(what), "diffusion grid %u^3 of object '%.40s' (voxel resolution)", resolution,
                     obj->name);
        else
            snprintf(what, sizeof(what), "diffusion grid %u^3 of object %u (voxel resolution)", resolution, index);
        nacre_result mr = nc_memory_check(ctx, (cells - o->capacity) * 384u, what);
        if (mr != NACRE_OK)
            return mr;
    }
    nacre_voxel_report rep;
    nacre_result res = o->grid ? nacre_voxelize_update(o->grid, &dm, &vs, &rep)
                               : nacre_voxelize(ctx, &dm, &vs, &o->grid, &rep);
    o->vox_valid = o->medium_valid = o->light_valid = o->lit = false;
    o->inj_valid = o->faces_valid = false; /* new solid cells: new injection spans and faces */
    if (res != NACRE_OK)
        return res;
    o->rule_known = true;
    o->rule = rep.rule_used;
    o->rule_mesh = obj->desc.mesh.id;
    memcpy(o->dims, rep.dims, sizeof(o->dims));
    memcpy(o->origin, rep.origin, sizeof(o->origin));
    o->h = rep.voxel_size;
    o->cells = (size_t)o->dims[0] * o->dims[1] * o->dims[2];
    if ((res = ensure_arrays(o, o->cells)) != NACRE_OK)
        return res;
    const uint32_t nx = o->dims[0], ny = o->dims[1], nz = o->dims[2];
    uint8_t *solid = o->solid;
    const nacre_voxel_grid *grid = o->grid;
    uint64_t count = 0;
    uint32_t lo[3] = {UINT32_MAX, UINT32_MAX, UINT32_MAX}, hi[3] = {0, 0, 0};
    nacre_voxel_grid_unpack(grid, NACRE_VOXEL_SOLID, 0, solid);
    /* Per-slab bounds reduced after the loop; slabs are independent. */
#pragma omp parallel num_threads(nc_threads(ctx)) if (o->cells > 32768)
    {
        uint32_t tlo[3] = {UINT32_MAX, UINT32_MAX, UINT32_MAX}, thi[3] = {0, 0, 0};
        uint64_t tcount = 0;
#pragma omp for schedule(static)
        for (uint32_t z = 0; z < nz; z++)
            for (uint32_t y = 0; y < ny; y++)
                for (uint32_t x = 0; x < nx; x++) {
                    if (!solid[x + (size_t)nx * (y + (size_t)ny * z)])
                        continue;
                    tcount++;
                    uint32_t p[3] = {x, y, z};
                    for (int k = 0; k < 3; k++) {
                        tlo[k] = p[k] < tlo[k] ? p[k] : tlo[k];
                        thi[k] = p[k] + 1 > thi[k] ? p[k] + 1 : thi[k];
                    }
                }
#pragma omp critical
        {
            count += tcount;
            for (int k = 0; k < 3; k++) {
                lo[k] = tlo[k] < lo[k] ? tlo[k] : lo[k];
                hi[k] = thi[k] > hi[k] ? thi[k] : hi[k];
            }
        }
    }
    o->solid_count = count;
    for (int k = 0; k < 3; k++) {
        o->lo[k] = count ? lo[k] : 0;
        o->hi[k] = count ? hi[k] : 0;
    }
    boundary_depths(o, &dm);
    o->vox_valid = true;
    return NACRE_OK;
}

/* Subsamples per axis of a voxel when it averages the layers' coefficients (LAYER_SUB^3 points). */
#define LAYER_SUB 2
/* Optical depths of the escape table (escape_table) and its entries: beyond ESC_TAU_MAX the
 * escape fraction is below 2e-5. */
#define ESC_TAU_MAX 8.0f
#define ESC_N 256

/* Fraction of the light scattered isotropically at optical depth tau below a plane boundary that
 * leaves through it before interacting again: (1/2) int_0^1 T(mu) exp(-tau / mu) dmu, T the
 * Fresnel transmittance from inside (relative index 1 / eta), tabulated on [0, ESC_TAU_MAX]. */
static void escape_table(float eta, float table[ESC_N + 1])
{
    enum { MU_N = 256 };
    for (int t = 0; t <= ESC_N; t++) {
        double tau = (double)t * ESC_TAU_MAX / ESC_N, sum = 0.0;
        for (int k = 0; k < MU_N; k++) {
            double mu = (k + 0.5) / MU_N;
            sum += (1.0 - nc_fresnel_dielectric(mu, 1.0 / eta)) * exp(-tau / mu);
        }
        table[t] = (float)(0.5 * sum / MU_N);
    }
}

static inline float escape_at(const float table[ESC_N + 1], float tau)
{
    if (!(tau < ESC_TAU_MAX))
        return 0.0f;
    float x = fmaxf(tau, 0.0f) * (ESC_N / ESC_TAU_MAX);
    int i = (int)x;
    i = i < ESC_N ? i : ESC_N - 1;
    float f = x - (float)i;
    return table[i] + f * (table[i + 1] - table[i]);
}

/* Quadrature points of second_order's cosines, and Fresnel reflectance from inside at each. */
#define SECOND_MU 24

/* Where light scattered at reduced optical depth tau below a plane boundary interacts again,
 * weighted by the diffusion's response there relative to tau's: the exitance of a planar source
 * at depth z in a half-space is exp(-sigma_tr (z + z_b)) (the diffusion's Green's function with
 * the extrapolated boundary), so a second event at tau2 lets out exp(-k (tau2 - tau)) times what
 * one at tau would, k = sigma_tr / sigma_t' = sqrt(3 (1 - alpha')) in reduced units. Over the
 * isotropic directions mu of the flight and its exponential length t:
 *   M(tau) = 1/2 int_0^1 [ 1 / (1 + k mu)                                    (downwards)
 *                        + (1 - exp(-(1 - k mu) tau / mu)) / (1 - k mu)       (upwards, short of the surface)
 *                        + F(mu) exp(-tau / mu) exp(k tau) / (1 + k mu) ] dmu (reflected back down),
 * F the Fresnel reflectance from inside. At k = 0 this is 1 - escape(tau); deep down it tends to
 * M_inf = ln((1 + k) / (1 - k)) / (2 k), which the diffusion's own transport already stands for,
 * so the factor is M(tau) / M_inf: 1 in the bulk, and below 1 - escape(tau) near the surface,
 * where the light that does not escape is mostly the part that went down. Placing the second
 * event at the first (the factor 1 - escape(tau)) made the multiply scattered light 15-20% too
 * bright on issue 28's checker cube. k is capped at 0.95 (albedo above 0.7). */
static float second_order(float tau, float k, const float fin[SECOND_MU])
{
    k = fminf(fmaxf(k, 0.0f), 0.95f);
    const float ek = expf(k * tau);
    float sum = 0.0f;
    for (int q = 0; q < SECOND_MU; q++) {
        const float mu = ((float)q + 0.5f) / SECOND_MU, km = k * mu;
        const float reach = expf(-tau / mu);
        sum += 1.0f / (1.0f + km) + (1.0f - expf(-(1.0f - km) * tau / mu)) / (1.0f - km) +
               fin[q] * reach * ek / (1.0f + km);
    }
    const float m = 0.5f * sum / SECOND_MU;
    const float m_inf = k > 1e-4f ? logf((1.0f + k) / (1.0f - k)) / (2.0f * k) : 1.0f;
    return fminf(m / m_inf, 1.0f);
}

/* The medium of an object with a layered material, after nc_medium_eval put the core's
 * coefficients in eval_a and eval_s at the n rest points; `keep` (NULL unless the solution
 * stands for multiple scattering only, o->multiple_only) gets the sources' factor below.
 *
 * Coefficients: each voxel takes the mean of the reduced coefficients sigma_a and
 * sigma_s (1 - g) over LAYER_SUB^3 points of its cell, each point those of the layer it lies in
 * (nacre_layering: depth below the rest-pose mesh, the depth map read at the nearest point's uv)
 * or of the core. The mean keeps the optical depth of layers thinner than a voxel, which a centre
 * sample would drop or inflate to a whole cell. Voxels whose centre lies deeper than the deepest
 * bottom plus the cell's half diagonal are all core.
 *
 * Sources of order 2 and up: the volume injection deposits where light scatters for the first
 * time (in similarity-reduced terms), and a diffusion solution from those sources is the light
 * of every order; the first order is the layered march's. Of the light scattered once at
 * reduced optical depth tau below the surface, escape(tau) leaves without interacting again
 * (escape_table, isotropic in the reduced medium, the surface locally a plane) and the rest
 * interacts again, scattering with probability alpha' = sigma_s' / sigma_t'. So the source of
 * the multiply scattered light is S alpha' (1 - escape(tau)) (the second event placed at the
 * first), and ms_keep holds that factor per cell and channel, tau the optical depth of the
 * straight path to the surface through the layers at the point's uv (mean over the subsamples
 * near the surface, the centre deeper down). For the diffusion method's own single scattering
 * (o->single, single.c) the factor is alpha' M(tau) / M_inf instead (second_order): the second
 * event's depth weighted by the diffusion's response there. `to_rest`: the linear map of world offsets into
 * rest space (NULL for deformed objects: the centre only, the rest map being known there). */
static nacre_result layered_medium(nc_diff_object *o, const nacre_scene *s, const nc_object_rec *obj,
                                    const nacre_material_desc *m, size_t n, const nc_mat4 *to_rest, float *keep)
{
#ifdef NACRE_HAVE_EMBREE
    nc_layer_stack stack;
    nc_layers_init(s, &m->layering, &stack);
    float deepest = 0.0f, st_min = INFINITY;
    for (uint32_t j = 0; j < stack.count; j++)
        deepest = fmaxf(deepest, stack.hi[j]);
    const float core_g = 1.0f - m->g;
    for (size_t k = 0; k < n; k++)
        for (int c = 0; c < 3; c++)
            st_min = fminf(st_min, o->eval_a[3 * k + c] + o->eval_s[3 * k + c] * core_g);
    /* Half diagonal of a cell in rest units, bounded through the Frobenius norm of the map. */
    float stretch = 1.0f;
    if (to_rest) {
        float f2 = 0.0f;
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++)
                f2 += to_rest->m[r][c] * to_rest->m[r][c];
        stretch = sqrtf(f2);
    }
    const float half_diag = 0.5f * sqrtf(3.0f) * o->h * stretch;
    /* Deeper than this no layer and no escape matter (the core's escape is under 2e-5). */
    const float reach = fmaxf(deepest, st_min > 0.0f ? ESC_TAU_MAX / st_min : 0.0f) + half_diag;
    float esc[ESC_N + 1], fin[SECOND_MU];
    escape_table(m->eta, esc);
    for (int q = 0; q < SECOND_MU; q++)
        fin[q] = (float)nc_fresnel_dielectric(((double)q + 0.5) / SECOND_MU, 1.0 / m->eta);
    const bool deepen = o->single;
    RTCDevice device = rtcNewDevice("threads=1");
    if (!device)
        return nc_fail(o->ctx, NACRE_ERROR_UNSUPPORTED, "diffusion: Embree device creation failed");
    nc_surface_locator *loc = NULL;
    nacre_result res = nc_locator_create(o->ctx, device, &s->meshes[obj->desc.mesh.id - 1].data, &loc);
    if (res == NACRE_OK) {
        const float sub = (float)LAYER_SUB;
        nc_vec3 off[LAYER_SUB * LAYER_SUB * LAYER_SUB];
        int nsub = 0;
        for (int z = 0; z < LAYER_SUB; z++)
            for (int y = 0; y < LAYER_SUB; y++)
                for (int x = 0; x < LAYER_SUB; x++) {
                    nc_vec3 w = nc_v3((((float)x + 0.5f) / sub - 0.5f) * o->h, (((float)y + 0.5f) / sub - 0.5f) * o->h,
                                      (((float)z + 0.5f) / sub - 0.5f) * o->h);
                    off[nsub++] = to_rest ? nc_mat4_dir(to_rest, w) : nc_v3(0, 0, 0);
                }
        const nacre_layer *layers = m->layering.layers;
#pragma omp parallel for schedule(dynamic, 256) num_threads(nc_threads(o->ctx))
        for (size_t k = 0; k < n; k++) {
            const float *p = o->rest + 3 * k;
            float core_a[3], core_sp[3];
            for (int c = 0; c < 3; c++) {
                core_a[c] = o->eval_a[3 * k + c];
                core_sp[c] = o->eval_s[3 * k + c] * core_g;
            }
            float uv[2];
            uint32_t hint = UINT32_MAX;
            float d = nc_locator_nearest(loc, p, reach, &hint, uv);
            /* The centre alone where the cell cannot reach a layer (or the map is unknown). */
            const int points = (to_rest && d <= deepest + half_diag) ? nsub : 1;
            float sa[3] = {0, 0, 0}, ssp[3] = {0, 0, 0}, e[3] = {0, 0, 0};
            for (int q = 0; q < points; q++) {
                float dq = d;
                if (points > 1) {
                    float pq[3] = {p[0] + off[q].x, p[1] + off[q].y, p[2] + off[q].z};
                    dq = nc_locator_nearest(loc, pq, reach + 2.0f * half_diag, &hint, uv);
                }
                uint32_t j = isfinite(dq) ? nc_layers_find(&stack, dq, uv[0], uv[1]) : stack.count;
                float bottom[NACRE_MAX_LAYERS];
                if (isfinite(dq))
                    nc_layers_bottoms(&stack, uv[0], uv[1], bottom);
                for (int c = 0; c < 3; c++) {
                    sa[c] += j < stack.count ? layers[j].sigma_a[c] : core_a[c];
                    ssp[c] += j < stack.count ? layers[j].sigma_s[c] * (1.0f - layers[j].g) : core_sp[c];
                    if (!isfinite(dq) || !keep)
                        continue;
                    /* Reduced optical depth of the straight path up to the surface. */
                    float tau = 0.0f, top = 0.0f;
                    for (uint32_t l = 0; l < stack.count && top < dq; l++) {
                        float b = fminf(bottom[l], dq);
                        if (b > top)
                            tau += (b - top) * (layers[l].sigma_a[c] + layers[l].sigma_s[c] * (1.0f - layers[l].g));
                        top = fmaxf(top, bottom[l]);
                    }
                    if (dq > top)
                        tau += (dq - top) * (core_a[c] + core_sp[c]);
                    if (deepen) {
                        const float pa = j < stack.count ? layers[j].sigma_a[c] : core_a[c];
                        const float pt = pa + (j < stack.count ? layers[j].sigma_s[c] * (1.0f - layers[j].g) : core_sp[c]);
                        const float kk = pt > 0.0f ? sqrtf(3.0f * pa / pt) : 0.0f;
                        e[c] += tau < ESC_TAU_MAX + 4.0f ? 1.0f - second_order(tau, kk, fin) : 0.0f;
                    } else {
                        e[c] += escape_at(esc, tau);
                    }
                }
            }
            for (int c = 0; c < 3; c++) {
                float a = sa[c] / (float)points, sp = ssp[c] / (float)points;
                o->eval_a[3 * k + c] = a;
                /* eval_s holds sigma_s with the core's g: the caller applies (1 - g) */
                o->eval_s[3 * k + c] = sp / core_g;
                if (keep)
                    keep[3 * k + c] = (a + sp > 0.0f ? sp / (a + sp) : 0.0f) * (1.0f - e[c] / (float)points);
            }
        }
        nc_locator_destroy(o->ctx, loc);
    }
    rtcReleaseDevice(device);
    return res;
#else
    (void)s, (void)obj, (void)m, (void)n, (void)to_rest, (void)keep;
    return nc_fail(o->ctx, NACRE_ERROR_UNSUPPORTED,
                   "diffusion: layered materials are not implemented without Embree (it finds each voxel's "
                   "depth below the surface)");
#endif
}

/* Medium per voxel: constants for homogeneous materials; rest-pose evaluation otherwise; a
 * layered material per voxel from its layers and core (layered_medium). */
nacre_result nc_diff_object_medium(nc_diff_object *o, const nacre_scene *s, uint32_t index, bool face_mode)
{
    const nc_object_rec *obj = &s->objects[index];
    const nacre_material_desc *m = &s->materials[obj->desc.material.id - 1];
    const bool multiple = o->multiple_only;
    const bool layered = multiple || m->layering.count > 0;
    o->medium_valid = o->light_valid = o->lit = false;
    o->heterogeneous = nc_medium_heterogeneous(m) || layered;
    if (o->eta != m->eta || o->fresnel_diffuse == 0.0f) {
        o->eta = m->eta;
        o->fdr = (float)nc_fresnel_fdr(m->eta);
        o->robin_a = (float)nc_diff_robin_a(m->eta);
        o->fresnel_diffuse = (float)nc_fresnel_diffuse(m->eta);
        o->inv_eta2 = 1.0f / (o->eta * o->eta);
        o->radiance_k = 1.0f / (NC_PI * (1.0f - o->fresnel_diffuse));
    }
    for (int c = 0; c < 3; c++) {
        o->sigma_a_const[c] = m->sigma_a[c];
        o->sigma_sp_const[c] = m->sigma_s[c] * (1.0f - m->g);
    }
    nacre_result res = ensure_optional(o, o->heterogeneous, face_mode);
    if (res != NACRE_OK)
        return res;
    if (o->heterogeneous) {
        /* The rest points of the solid cells only, packed in cell order (evaluated, then
         * scattered back below). */
        size_t n = 0;
        nc_mat4 to_rest;
        if (obj->desc.deformer_count == 0) {
            /* Undeformed: the rest point of a voxel centre is exactly its inverse transform. */
            nc_mat4_inverse(obj->object_to_world, &to_rest);
            for (uint32_t z = 0; z < o->dims[2]; z++)
                for (uint32_t y = 0; y < o->dims[1]; y++)
                    for (uint32_t x = 0; x < o->dims[0]; x++) {
                        if (!o->solid[x + o->dims[0] * (y + (size_t)o->dims[1] * z)])
                            continue;
                        nc_vec3 c = nc_v3(o->origin[0] + ((float)x + 0.5f) * o->h,
                                          o->origin[1] + ((float)y + 0.5f) * o->h,
                                          o->origin[2] + ((float)z + 0.5f) * o->h);
                        nc_v3store(nc_mat4_point(&to_rest, c), o->rest + 3 * n++);
                    }
        } else {
            const nacre_mesh_data *rest = &s->meshes[obj->desc.mesh.id - 1].data;
            nacre_mesh_data dm = world_mesh(s, obj);
            if ((res = nacre_voxel_grid_rest_positions(o->grid, rest, &dm, o->rest)) != NACRE_OK)
                return res;
            /* Compact in place: the write index never passes the read index. */
            for (size_t i = 0; i < o->cells; i++)
                if (o->solid[i]) {
                    memmove(o->rest + 3 * n, o->rest + 3 * i, 3 * sizeof(float));
                    n++;
                }
        }
        nc_medium_eval(s, m, o->rest, n, o->eval_a, o->eval_s);
        float *keep = NULL;
        if (layered) {
            /* keep: per rest point, then per cell into ms_keep (multiple scattering only) */
            if (multiple && !(keep = nc_alloc(o->ctx, (n > 0 ? n : 1) * 3 * sizeof(float))))
                return NACRE_ERROR_OUT_OF_MEMORY;
            res = layered_medium(o, s, obj, m, n, obj->desc.deformer_count == 0 ? &to_rest : NULL, keep);
            if (res != NACRE_OK) {
                nc_free(o->ctx, keep);
                return res;
            }
        }
        size_t k = 0;
        for (size_t i = 0; i < o->cells; i++) {
            for (int c = 0; c < 3; c++) {
                o->sigma_a[c][i] = o->solid[i] ? o->eval_a[3 * k + c] : 0.0f;
                o->sigma_sp[c][i] = o->solid[i] ? o->eval_s[3 * k + c] * (1.0f - m->g) : 0.0f;
                if (keep)
                    o->ms_keep[c][i] = o->solid[i] ? keep[3 * k + c] : 0.0f;
            }
            k += o->solid[i] ? 1 : 0;
        }
        nc_free(o->ctx, keep);
    }
    o->medium_valid = true;
    return NACRE_OK;
}

/* Build the solver's operators for the current grid and medium. */
static nacre_result object_setup(nc_diff_object *o)
{
    nacre_result res;
    if (!o->solver && (res = nc_diff_solver_create(o->ctx, &o->solver)) != NACRE_OK)
        return res;
    nc_diff_medium m;
    memset(&m, 0, sizeof(m));
    memcpy(m.dims, o->dims, sizeof(m.dims));
    m.h = o->h;
    m.solid = o->solid;
    for (int c = 0; c < 3; c++) {
        m.sigma_a[c] = o->heterogeneous ? o->sigma_a[c] : NULL;
        m.sigma_sp[c] = o->heterogeneous ? o->sigma_sp[c] : NULL;
        m.sigma_a_const[c] = o->sigma_a_const[c];
        m.sigma_sp_const[c] = o->sigma_sp_const[c];
    }
    m.eta = o->eta;
    /* Boundary cells at their true depth. The solver's Robin term lets a boundary cell's flux
     * out through its exposed faces as if the surface were there, h / 2 from the centre
     * (J = D phi / (h / 2 + 2 A D)); the surface is at the centre's depth d below it (o->depth),
     * from about 0 to a cell: with d the flux is D phi / (d + 2 A D), the factor
     * f = (h / 2 + 2 A D) / (d + 2 A D) on the cell's boundary weight (one per cell: D is the
     * mean over the channels, within a few percent of each channel's factor for the materials
     * here). The shading pass reads phi at h / 2 below the true surface as D phi / (d + 2 A D)
     * with d the interpolated depth of the cells it reads (nc_diff_compute_exitance). That
     * linear profile holds where a cell is within a transport mean free path 1 / sigma_t'
     * (issue 28's sphere: 0.69 at 32^3); below a lit surface phi follows the sources over the
     * first mean free path, and on coarser cells the factor drew the grid's terraces as bands
     * (the jade torus at 32^3: 2.1 mean free paths per cell) and blotches (marble at 32^3:
     * 4.6). So f fades to 1 between one and two mean free paths per cell (docs/accuracy.md). */
    const float A = o->robin_a, half = 0.5f * o->h;
    for (size_t i = 0; i < o->cells; i++) {
        float f = 1.0f;
        if (o->solid[i] && o->depth[i] >= 0.0f) {
            float dm = 0.0f;
            for (int c = 0; c < 3; c++) {
                const float sa = o->heterogeneous ? o->sigma_a[c][i] : o->sigma_a_const[c];
                const float sp = o->heterogeneous ? o->sigma_sp[c][i] : o->sigma_sp_const[c];
                dm += sa + sp > 0.0f ? 1.0f / (3.0f * (sa + sp)) : 0.0f;
            }
            dm *= 1.0f / 3.0f;
            if (dm > 0.0f) {
                const float ext = 2.0f * A * dm, mfp_cells = o->h / (3.0f * dm);
                const float w = fminf(fmaxf(2.0f - mfp_cells, 0.0f), 1.0f);
                f = 1.0f + w * ((half + ext) / (o->depth[i] + ext) - 1.0f);
            }
        }
        o->bscale[i] = f;
    }
    m.boundary_scale = o->bscale;
    return nc_diff_setup(o->solver, &m);
}

/* Solve the three channels and derive the exitance. */
static nacre_result object_solve(nc_diff_object *o, const nacre_render_settings *settings)
{
    const int threads = nc_threads(o->ctx);
    bool warm = o->phi_valid && memcmp(o->phi_dims, o->dims, sizeof(o->dims)) == 0;
    nc_diff_solve_opts opts;
    memset(&opts, 0, sizeof(opts));
    opts.solver = settings->diffusion.solver;
    opts.tolerance = settings->diffusion.tolerance;
    opts.seed_iterations = settings->diffusion.seed_iterations;
    opts.warm_start = warm;
    opts.phi_unchanged = warm; /* phi is written by the solver only */
    opts.no_energy = true;
    o->iterations = 0;
    o->residual = 0.0;
    /* No clearing of phi: the solver reads it at the current domain's cells only, and only for a
     * warm start, where the previous solve left 0 outside the previous domain (a cell that has
     * just entered comes with 0 and is filled by warm_fill); it then writes every cell. */
    /* The three channels in one solve: one pass over the grid serves all three. */
    nc_diff_solve_report rep[3];
    memset(rep, 0, sizeof(rep));
    const float *src[3] = {o->source[0], o->source[1], o->source[2]};
    float *phis[3] = {o->phi[0], o->phi[1], o->phi[2]};
    nacre_result res = nc_diff_solve_rgb(o->solver, src, phis, &opts, rep);
    if (res != NACRE_OK) {
        o->phi_valid = false;
        return res;
    }
    const float *D[3];
    float d_uniform[3] = {0.0f, 0.0f, 0.0f};
    for (int c = 0; c < 3; c++) {
        o->iterations = rep[c].iterations > o->iterations ? rep[c].iterations : o->iterations;
        o->residual = rep[c].residual > o->residual ? rep[c].residual : o->residual;
        D[c] = nc_diff_coefficient_d(o->solver, c, &d_uniform[c]);
    }
    o->phi_valid = true;
    memcpy(o->phi_dims, o->dims, sizeof(o->dims));
    if ((res = nc_diff_compute_exitance(o, D, d_uniform, settings->diffusion.source, threads)) != NACRE_OK)
        return res;
    o->face_mode = settings->diffusion.source == NACRE_SOURCE_FACE;
    o->lit = true;
    return NACRE_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* Renderer state and frame                                                                   */
/* ------------------------------------------------------------------------------------------ */

nacre_result nc_diff_state_create(nacre_context *ctx, nc_diff_state **out)
{
    *out = NULL;
    nc_diff_state *st = nc_calloc(ctx, 1, sizeof(*st));
    if (!st)
        return NACRE_ERROR_OUT_OF_MEMORY;
    st->ctx = ctx;
    *out = st;
    return NACRE_OK;
}

void nc_diff_state_destroy(nc_diff_state *st)
{
    if (!st)
        return;
    nacre_context *ctx = st->ctx;
    for (uint32_t i = 0; i < st->object_capacity; i++)
        nc_diff_object_free(&st->objects[i]);
    nc_free(ctx, st->objects);
    nc_free(ctx, st->subsurface);
    nc_tsm_band_free(ctx, &st->band);
    nc_free(ctx, st);
}

static nacre_result ensure_objects(nc_diff_state *st, uint32_t count)
{
    if (count <= st->object_capacity)
        return NACRE_OK;
    nacre_context *ctx = st->ctx;
    nc_diff_object *objs = nc_realloc(ctx, st->objects, st->object_capacity * sizeof(*objs), count * sizeof(*objs));
    if (!objs)
        return NACRE_ERROR_OUT_OF_MEMORY;
    memset(objs + st->object_capacity, 0, (count - st->object_capacity) * sizeof(*objs));
    st->objects = objs;
    uint8_t *sub = nc_realloc(ctx, st->subsurface, st->object_capacity, count);
    if (!sub)
        return NACRE_ERROR_OUT_OF_MEMORY;
    st->subsurface = sub;
    st->object_capacity = count;
    return NACRE_OK;
}

/* Whether an object of material m gets the per-pixel first order (nacre_single_scattering:
 * AUTO for media that vary in space, and only with volume sources, which ON requires). Layered
 * materials are left to the layered method's own march. */
bool nc_diff_single_for(const nacre_diffusion_settings *d, const nacre_material_desc *m)
{
    if (d->single_scattering == NACRE_SINGLE_SCATTERING_AUTO)
        return d->source == NACRE_SOURCE_VOLUME && nc_medium_heterogeneous(m) && m->layering.count == 0;
    return d->single_scattering == NACRE_SINGLE_SCATTERING_ON;
}

/* Whether the light-dependent settings are those the cached solution was computed with. */
static bool same_light_settings(const nacre_render_settings *a, const nacre_render_settings *b)
{
    return a->diffusion.tsm_size == b->diffusion.tsm_size && a->diffusion.single_scattering == b->diffusion.single_scattering && a->diffusion.solver == b->diffusion.solver && a->diffusion.source == b->diffusion.source &&
           a->diffusion.tolerance == b->diffusion.tolerance && a->diffusion.seed_iterations == b->diffusion.seed_iterations &&
           a->shadow.map_size == b->shadow.map_size && a->shadow.pcf_radius == b->shadow.pcf_radius &&
           a->shadow.bias == b->shadow.bias;
}

nacre_result nc_diffusion_frame(nc_diff_state *st, const nacre_scene *s, const nacre_render_settings *settings,
                                const nc_shade_light *lights, uint32_t light_count, nacre_render_stats *stats)
{
    return nc_diffusion_frame_objects(st, s, settings, lights, light_count, NULL, stats);
}

/* The smallest sigma_a + sigma_s over the object's solid voxels (the single-scattering march's
 * length), sigma_s from the reduced sigma_s' with the material's g. */
static float sigma_t_min(const nc_diff_object *o, const nacre_material_desc *m)
{
    const float inv_1mg = m->g < 1.0f ? 1.0f / (1.0f - m->g) : 0.0f;
    float lo = INFINITY;
    if (!o->heterogeneous) {
        for (int c = 0; c < 3; c++)
            lo = fminf(lo, o->sigma_a_const[c] + o->sigma_sp_const[c] * inv_1mg);
        return lo;
    }
    for (size_t i = 0; i < o->cells; i++)
        if (o->solid[i])
            for (int c = 0; c < 3; c++)
                lo = fminf(lo, o->sigma_a[c][i] + o->sigma_sp[c][i] * inv_1mg);
    return lo < INFINITY ? lo : 0.0f;
}

nacre_result nc_diffusion_frame_objects(nc_diff_state *st, const nacre_scene *s, const nacre_render_settings *settings,
                                        const nc_shade_light *lights, uint32_t light_count, const uint8_t *only,
                                        nacre_render_stats *stats)
{
    nacre_result res = ensure_objects(st, s->object_count);
    if (res != NACRE_OK)
        return res;
    if (st->scene_uid != s->uid) {
        /* Another scene: forget every cache (memory is kept, the solid rule is decided again). */
        for (uint32_t i = 0; i < st->object_capacity; i++) {
            nc_diff_object *o = &st->objects[i];
            o->vox_valid = o->medium_valid = o->light_valid = o->lit = o->phi_valid = false;
            o->rule_known = false;
        }
        st->scene_uid = s->uid;
    }
    memset(st->subsurface, 0, st->object_capacity);
    st->scene = s;
    st->lights = lights;
    st->light_count = light_count;
    stats->solver = settings->diffusion.solver;
    uint32_t casters = 0;
    for (uint32_t i = 0; i < s->object_count; i++)
        casters += s->objects[i].desc.cast_shadows ? 1 : 0;
    uint64_t best_cells = 0;
    for (uint32_t i = 0; i < s->object_count; i++) {
        const nc_object_rec *obj = &s->objects[i];
        const nacre_material_desc *m = &s->materials[obj->desc.material.id - 1];
        if (m->type != NACRE_MATERIAL_TRANSLUCENT || (only && !only[i]))
            continue;
        nc_diff_object *o = &st->objects[i];
        o->ctx = st->ctx;
        /* Single scattering per pixel (single.c): the solution stands for orders >= 2 */
        const bool single = !st->multiple_only && nc_diff_single_for(&settings->diffusion, m);
        if (o->single != single || o->multiple_only != (st->multiple_only || single))
            o->medium_valid = false;
        o->single = single;
        o->multiple_only = st->multiple_only || single;
        bool face_mode = settings->diffusion.source == NACRE_SOURCE_FACE;
        if (!o->vox_valid || o->key_uid != s->uid || o->key_geometry != s->versions.geometry ||
            o->key_res != settings->diffusion.voxel_resolution) {
            uint64_t t0 = nc_now_us();
            if ((res = nc_diff_object_voxelize(o, s, i, settings->diffusion.voxel_resolution)) != NACRE_OK)
                return res;
            stats->stage_us[NACRE_STAGE_VOXELIZE] += nc_now_us() - t0;
            stats->stage_ran[NACRE_STAGE_VOXELIZE] = true;
            stats->stage_runs[NACRE_STAGE_VOXELIZE]++;
            o->key_uid = s->uid;
            o->key_geometry = s->versions.geometry;
            o->key_res = settings->diffusion.voxel_resolution;
        }
        if (!o->medium_valid || o->key_materials != s->versions.materials) {
            uint64_t t0 = nc_now_us();
            if ((res = nc_diff_object_medium(o, s, i, face_mode)) != NACRE_OK)
                return res;
            uint64_t t1 = nc_now_us();
            stats->stage_us[NACRE_STAGE_MEDIUM] += t1 - t0;
            stats->stage_ran[NACRE_STAGE_MEDIUM] = true;
            stats->stage_runs[NACRE_STAGE_MEDIUM]++;
            /* The solver's setup depends on the medium only; it is timed with the solve that
             * always follows it (the medium invalidates the light-dependent state). */
            if (o->solid_count > 0 && (res = object_setup(o)) != NACRE_OK) {
                o->medium_valid = false;
                return res;
            }
            stats->stage_us[NACRE_STAGE_PROPAGATE] += nc_now_us() - t1;
            o->key_materials = s->versions.materials;
            o->sigma_t_min = sigma_t_min(o, m);
        }
        if (!o->light_valid || o->key_lights != s->versions.lights ||
            !same_light_settings(&o->key_settings, settings)) {
            o->light_valid = o->lit = false;
            if ((res = ensure_optional(o, o->heterogeneous, face_mode)) != NACRE_OK)
                return res;
            bool others_cast = casters > (obj->desc.cast_shadows ? 1u : 0u);
            uint64_t tsm_us = 0, inject_us = 0;
            if ((res = nc_diff_inject_lights(o, &st->band, s, lights, light_count, others_cast, settings, &tsm_us,
                                             &inject_us)) != NACRE_OK)
                return res;
            stats->stage_us[NACRE_STAGE_TSM] += tsm_us;
            stats->stage_us[NACRE_STAGE_INJECT] += inject_us;
            stats->stage_ran[NACRE_STAGE_TSM] = stats->stage_ran[NACRE_STAGE_INJECT] = true;
            stats->stage_runs[NACRE_STAGE_TSM]++;
            stats->stage_runs[NACRE_STAGE_INJECT]++;
            if (o->multiple_only && o->ms_keep[0]) {
                uint64_t t0 = nc_now_us();
                for (int c = 0; c < 3; c++)
                    for (size_t k = 0; k < o->cells; k++)
                        o->source[c][k] *= o->ms_keep[c][k];
                stats->stage_us[NACRE_STAGE_INJECT] += nc_now_us() - t0;
            }
            if (o->solid_count > 0) {
                uint64_t t0 = nc_now_us();
                if ((res = object_solve(o, settings)) != NACRE_OK)
                    return res;
                stats->stage_us[NACRE_STAGE_PROPAGATE] += nc_now_us() - t0;
                stats->stage_ran[NACRE_STAGE_PROPAGATE] = true;
                stats->stage_runs[NACRE_STAGE_PROPAGATE]++;
            }
            o->light_valid = true;
            o->key_lights = s->versions.lights;
            o->key_settings = *settings;
        }
        /* Objects too thin for any solid voxel keep the phong shading. */
        st->subsurface[i] = o->lit && o->solid_count > 0;
        if (o->cells > best_cells) {
            best_cells = o->cells;
            memcpy(stats->voxel_dims, o->dims, sizeof(o->dims));
        }
        if (o->lit) {
            stats->iterations = o->iterations > stats->iterations ? o->iterations : stats->iterations;
            stats->residual = o->residual > stats->residual ? o->residual : stats->residual;
        }
    }
    return NACRE_OK;
}

void nc_diffusion_shade_params(const nc_diff_state *st, const nacre_scene *s, nc_shade_params *params)
{
    (void)s;
    params->subsurface_object = st->subsurface;
    params->subsurface = nc_diff_subsurface_radiance;
    params->subsurface_user = st;
}
