/*
 * pipeline.h: the frame pipeline of `--method diffusion` (Blanchard 2012 chapter 4) as the
 * renderer drives it (private interface; the solver itself is diffusion.h).
 *
 * Per translucent object and frame: voxelize the committed world-space mesh (seed 4.2), evaluate
 * the medium per voxel at rest-pose points, render a translucent shadow map per light (seed 4.3,
 * tsm.c), turn its texels into per-cell sources (seed 4.4, tsm.c), solve the diffusion equation
 * per RGB channel (seed 4.5, solver.c) and keep the exitance per cell for the deferred shading
 * pass (seed 4.6, shade_diffusion.c).
 *
 * UNITS AND CONVENTIONS
 *   - Everything is in world space (the grid is built from the committed world positions);
 *     lengths in scene units, cell side h. Cell (x, y, z) has its centre at
 *     origin + (x + 0.5, y + 0.5, z + 0.5) h; index i = x + nx (y + ny z).
 *   - "Grid coordinates" are (p - origin) / h: cell (x, y, z) covers [x, x + 1) etc.
 *   - A light's strength is irradiance (directional) or intensity (point, spot) per scene unit^2
 *     as in phong.c; fluxes are strength x area (or x solid angle), per RGB channel.
 *   - Sources are power per cell (W), phi is fluence, exitance is outgoing flux per unit area
 *     (diffusion.h).
 *   - Face ids follow the seed's table 4.1: z- = 0, z+ = 1, x- = 2, x+ = 3, y- = 4, y+ = 5.
 */
#ifndef NACRE_DIFFUSION_PIPELINE_H
#define NACRE_DIFFUSION_PIPELINE_H

#include "diffusion/diffusion.h"
#include "shade/shade.h"

enum { NC_FACE_ZN = 0, NC_FACE_ZP, NC_FACE_XN, NC_FACE_XP, NC_FACE_YN, NC_FACE_YP };

/* The light's entry into an object as one view of its translucent shadow map saw it, kept for
 * the single-scattering term (single.c): per texel NC_DIFF_LMAP_FLOATS floats, the distance along
 * the texel's ray to where it enters the object (grid units; INFINITY: no light enters there), the
 * part of the light's strength that enters per unit irradiance (Fresnel transmittance, spot
 * profile and other objects' shadow) and the unit surface normal there (facing the light). */
#define NC_DIFF_LMAP_FLOATS 5
typedef struct nc_diff_lmap {
    uint32_t light;                  /* index into the frame's lights */
    bool ortho;
    float origin[3], f[3], r[3], u[3]; /* tsm.c's view, grid units (ortho) or tangents (perspective) */
    float a0, a1, b0, b1;
    int32_t size;
    float *texel;                    /* size^2 x NC_DIFF_LMAP_FLOATS */
    size_t capacity;                 /* texels allocated */
} nc_diff_lmap;

/* The state of one translucent object, kept by the renderer across frames. Arrays hold
 * `cells` floats (or 3 * cells for xyz triples) and are reused while the grid does not grow. */
typedef struct nc_diff_object {
    nacre_context *ctx;
    /* Voxelization (level 0 of the grid is the domain) */
    uint32_t index;                  /* the scene object voxelized */
    nacre_voxel_grid *grid;
    bool rule_known;                 /* the solid rule was decided by AUTO on the first frame */
    nacre_voxel_solid_rule rule;
    uint32_t rule_mesh;              /* mesh id the rule was decided for */
    uint32_t dims[3];
    float origin[3];
    float h;                         /* cell side, scene units */
    size_t cells, capacity;          /* nx*ny*nz; floats allocated per array */
    uint8_t *solid;                  /* cells: 1 = in the domain */
    float *depth;                    /* cells: a boundary cell's centre's distance to the mesh
                                      * (its depth below the true surface); NAN elsewhere and
                                      * where the mesh is not within a cell (pipeline.c) */
    float *bscale;                   /* cells: a boundary cell's Robin factor for that depth
                                      * (object_setup), the solver's and the exitance's */
    uint64_t solid_count;
    uint32_t lo[3], hi[3];           /* bounding box of the solid cells, [lo, hi) */
    /* Medium */
    bool multiple_only;              /* the solution stands for orders >= 2 (nc_diff_state) */
    float *ms_keep[3];               /* cells each, when multiple_only: the part of the first
                                      * scattering's source that scatters again (pipeline.c) */
    bool heterogeneous;
    float eta, fdr, robin_a, fresnel_diffuse;
    float inv_eta2, radiance_k;      /* shading constants: 1 / eta^2, 1 / (pi (1 - fresnel_diffuse)) */
    float sigma_a_const[3], sigma_sp_const[3];
    float *rest;                     /* 3 * cells: rest-pose point of each voxel (heterogeneous) */
    float *eval_a, *eval_s;          /* 3 * cells: interleaved nc_medium_eval output (heterogeneous) */
    float *sigma_a[3], *sigma_sp[3]; /* cells each (used when heterogeneous; else the constants) */
    /* Light and solution */
    nc_diff_solver *solver;
    float *source[3];                /* W per cell */
    float *q[3];                     /* FACE mode: lit face flux per unit area, summed per cell */
    int64_t *acc;                    /* 3 * cells: injection scratch, fixed-point power per cell,
                                      * channels interleaved (tsm.c); all 0 between injections
                                      * unless acc_dirty */
    bool acc_dirty;
    /* Per row (y, z) of the grid, the x range [lo, hi) from its first to its last solid cell
     * (inj_span, 2 per row; valid for the current voxels when inj_valid). Deposits go to solid
     * cells only, so the injection reads and clears its accumulators and writes the sources in
     * these ranges only; source (and q) are 0 outside them when src_clean. */
    /* The exposed faces that face a directional light (tsm.c list_faces): cell index * 8 + face
     * id. They depend only on the voxels and on the signs of the light's direction, so they are
     * listed again only when one of those changes (faces_valid, for face_steps). */
    uint32_t *faces;
    size_t face_count, face_capacity;
    int8_t face_steps[3];
    bool faces_valid;
    uint32_t *inj_span;
    size_t inj_span_capacity;        /* rows */
    bool inj_valid, src_clean;
    float *phi[3];                   /* fluence, kept for the next frame's warm start */
    float *exitance[3];              /* outgoing flux per unit area */
    float *packed;                   /* exitance RGB and solid (1/0) per cell, 4 floats each, the
                                      * shading pass's copy (one 16-byte read per interpolation
                                      * corner) on the grid padded by one empty cell per side,
                                      * (nx + 2) (ny + 2) (nz + 2) cells, so that every point within
                                      * half a cell of the grid interpolates without bounds tests */
    size_t packed_capacity;          /* padded cells allocated in packed */
    /* Per row (y, z) of the grid, the x range [lo, hi) from its first to its last solid cell at
     * the last exitance pass (exit_span, 2 per row), for the grid exit_dims, when exit_valid:
     * packed is 0 outside those ranges, so a pass writes the new ranges and clears what is left
     * of the old ones. */
    uint32_t *exit_span;
    size_t exit_span_capacity;       /* rows */
    float *packed_ghost;             /* when ghosts: the fallback's record of every padded cell
                                      * (shade_diffusion.c), 4 floats each, packed's layout; then
                                      * as much scratch */
    size_t ghost_capacity;           /* padded cells allocated in packed_ghost */
    bool ghosts;
    uint32_t exit_dims[3];
    bool exit_valid;
    bool phi_valid;
    uint32_t phi_dims[3];
    bool lit;                        /* exitance holds this frame's result */
    bool face_mode;                  /* ... computed with FACE sources (q holds the face term) */
    /* Cache keys: voxels and medium, then the light-dependent part */
    bool vox_valid, medium_valid, light_valid;
    uint64_t key_uid, key_geometry, key_materials, key_lights;
    uint32_t key_res;
    nacre_render_settings key_settings;
    /* Single scattering (single.c): when `single`, the maps of the last injection (lmap_count
     * views of up to 64 lights x 6), the sources reduced to orders >= 2 (multiple_only) */
    bool single;
    nc_diff_lmap *lmap;
    uint32_t lmap_count, lmap_capacity;
    float sigma_t_min;               /* smallest sigma_a + sigma_s over the object's voxels */
    /* Report of the last frame */
    double tsm_flux[3];              /* W: sum over texels of the flux transmitted into the object */
    double injected[3];              /* W: sum of the sources */
    uint32_t iterations;
    double residual;
} nc_diff_object;

/* Scratch of the translucent shadow map (one band of rows at a time), shared by all objects. */
typedef struct nc_tsm_band {
    size_t capacity;                 /* texels */
    uint32_t *cell;                  /* UINT32_MAX: the texel's ray misses the domain */
    uint8_t *face;
    float *weight;                   /* flux per unit light strength (area or solid angle x Ft x ...) */
    float *pos;                      /* 3: entry point, grid coordinates */
    float *dir;                      /* 3: unit direction of travel */
    int64_t *scratch;                /* per-thread injection accumulators (tsm.c); all 0
                                      * between injections unless scratch_dirty */
    bool scratch_dirty;
    size_t scratch_bytes;
    /* Orthographic maps are rasterized from the exposed faces (tsm.c): */
    float *depth;                    /* per band texel: distance along the light to the nearest face */
    uint32_t *hit;                   /* per band texel: index into faces, UINT32_MAX: none */
    size_t raster_capacity;          /* texels of depth and hit */
    int32_t *fbox;                   /* per listed face: its texel bounds i0, i1, j0, j1 */
    int32_t *tbox;                   /* per mesh triangle: the same (mesh_band) */
    size_t tbox_capacity;            /* triangles */
    size_t fbox_capacity;            /* faces */
    /* The object's true surface along each band texel's ray (tsm.c mesh_band): */
    float *mesh_t;                   /* per band texel: distance to the mesh (grid units), INFINITY: misses */
    float *mesh_n;                   /* 3 per band texel: unit mesh normal there, facing the light */
    uint64_t *mesh_key;              /* per band texel: scratch of mesh_band */
    size_t mesh_capacity;            /* texels of mesh_t and mesh_n */
    float *vproj;                    /* 3 per mesh vertex: map coordinates a, b and 1 if in front */
    size_t vproj_capacity;           /* vertices */
} nc_tsm_band;

/* Everything the diffusion method keeps in a renderer. */
typedef struct nc_diff_state {
    nacre_context *ctx;
    nc_diff_object *objects;         /* one per scene object (used for translucent ones) */
    uint32_t object_capacity;
    uint64_t scene_uid;
    nc_tsm_band band;
    uint8_t *subsurface;             /* per object: 1 = shaded from the diffusion solution */
    /* Set by the layered method, whose march gives the single scattering: the objects' media come
     * from their layers and core, and the sources are those of light scattered twice or more
     * (pipeline.c, multiple_medium). Volume sources only. */
    bool multiple_only;
    /* The frame the shading pass reads for the single-scattering term (single.c) */
    const nacre_scene *scene;
    const nc_shade_light *lights;
    uint32_t light_count;
    uint32_t ss_steps;               /* steps along each view ray */
} nc_diff_state;

nacre_result nc_diff_state_create(nacre_context *ctx, nc_diff_state **out);
void nc_diff_state_destroy(nc_diff_state *st);

/* Run voxelize / TSM / inject / propagate for every translucent object of a committed scene
 * (stages skipped when their inputs did not change), filling the diffusion fields and stage
 * timings of `stats`. `lights` are the renderer's lights with their shadow maps (light_count of
 * them), used to let other objects occlude the translucent shadow maps. */
nacre_result nc_diffusion_frame(nc_diff_state *st, const nacre_scene *scene,
                                const nacre_render_settings *settings, const nc_shade_light *lights,
                                uint32_t light_count, nacre_render_stats *stats);

/* The same for the objects i with only[i] != 0 (only: one entry per scene object; NULL: every
 * translucent object). The others are left alone and not shaded from the solution. */
nacre_result nc_diffusion_frame_objects(nc_diff_state *st, const nacre_scene *scene,
                                        const nacre_render_settings *settings, const nc_shade_light *lights,
                                        uint32_t light_count, const uint8_t *only, nacre_render_stats *stats);

/* Whether an object of material m gets the per-pixel first order (single.c) under settings d. */
bool nc_diff_single_for(const nacre_diffusion_settings *d, const nacre_material_desc *m);

/* Fill the subsurface hook of the phong pass (shade.h) from the state of the last frame. */
void nc_diffusion_shade_params(const nc_diff_state *st, const nacre_scene *scene,
                               nc_shade_params *params);

/* ---- Per-object steps (pipeline.c), exposed for tests ---- */

void nc_diff_object_free(nc_diff_object *o);
/* Voxelize object `index` of the scene at `resolution` and evaluate its medium. */
nacre_result nc_diff_object_voxelize(nc_diff_object *o, const nacre_scene *scene, uint32_t index,
                                     uint32_t resolution);
/* Evaluate the medium of object `index` per voxel (after nc_diff_object_voxelize); face_mode
 * also allocates the per-cell q of FACE injection. */
nacre_result nc_diff_object_medium(nc_diff_object *o, const nacre_scene *scene, uint32_t index, bool face_mode);
/* Coefficients of cell i, channel c. */
static inline void nc_diff_object_coeffs(const nc_diff_object *o, size_t i, int c, float *sigma_a,
                                         float *sigma_sp)
{
    *sigma_a = o->heterogeneous ? o->sigma_a[c][i] : o->sigma_a_const[c];
    *sigma_sp = o->heterogeneous ? o->sigma_sp[c][i] : o->sigma_sp_const[c];
}

/* ---- Translucent shadow maps and injection (tsm.c) ---- */

/* Zero the sources (and q), then render the TSM of each light for object `o` and inject it.
 * `shadows[li]` may be NULL; `others_cast` says whether any other object casts shadows (only then
 * are the shadow maps consulted). Adds to o->tsm_flux and o->injected. Timings (us) are added to
 * *tsm_us and *inject_us. */
nacre_result nc_diff_inject_lights(nc_diff_object *o, nc_tsm_band *band, const nacre_scene *scene,
                                   const nc_shade_light *lights, uint32_t light_count,
                                   bool others_cast, const nacre_render_settings *settings,
                                   uint64_t *tsm_us, uint64_t *inject_us);
void nc_tsm_band_free(nacre_context *ctx, nc_tsm_band *band);
/* The light of map m at grid point x: false if none enters towards x; else the distance from
 * the entry point to x (grid units, >= 0), the map's transmitted part and the entry normal,
 * interpolated bilinearly over the texels that have an entry, and the unit direction the
 * light travels at x (dir). */
bool nc_diff_lmap_lookup(const nc_diff_lmap *m, const float x[3], float *dist, float *trans, float n[3], float dir[3]);

/* ---- Single scattering (single.c) ---- */

/* Add to out[c][i] the radiance of light scattered once below each pixel of the batch
 * (object `object` of the frame st->scene, with o->single). */
void nc_diff_single_radiance(const nc_diff_state *st, uint32_t object, const nc_shade_batch *batch,
                             float out[3][NC_SHADE_BATCH]);

/* ---- Exitance and shading (shade_diffusion.c) ---- */

/* Depth below the surface, in cells, at which the shading pass reads the solution. */
#define NC_DIFF_SAMPLE_DEPTH 0.5f
/* Padded grids up to this many cells (18^3 voxels) keep every cell's fallback record
 * (o->packed_ghost): 15 us at 12^3, where 7.5% of Suzanne's pixels need one; at 28^3 it would
 * take 0.14 ms per frame for almost none. */
#define NC_DIFF_GHOST_GRID_CELLS 8192u

/* After the solve: per cell and channel, the exitance a surface NC_DIFF_SAMPLE_DEPTH cells away
 * would have (FACE mode adds the lit faces' own term, see the file), into o->exitance and
 * o->packed (padded, see nc_diff_object; grown if needed). D[c]: diffusion coefficient per cell,
 * or NULL for d_uniform[c] in every solid cell (nc_diff_coefficient_d). */
nacre_result nc_diff_compute_exitance(nc_diff_object *o, const float *const D[3], const float d_uniform[3],
                                      nacre_diffusion_source mode, int threads);
/* The subsurface hook of the phong pass: radiance towards the viewer at a batch of pixels of a
 * translucent object, into out[channel][pixel]. user = the nc_diff_state. */
void nc_diff_subsurface_radiance(const void *user, uint32_t object, const nc_shade_batch *batch,
                                 float out[3][NC_SHADE_BATCH]);

#endif /* NACRE_DIFFUSION_PIPELINE_H */
