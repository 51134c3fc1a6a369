/*
 * voxel.h: voxelization of triangle meshes (part of the nacre public API; included by nacre.h,
 * whose opening comment has the general conventions). It needs core.h for nacre_context and
 * nacre_result and mesh.h for nacre_mesh_data, and includes them.
 *
 * UNITS AND CONVENTIONS
 *   - Voxels are cubes of side `voxel_size` in mesh units. Voxel (x, y, z) of level 0 covers
 *     [origin + (x, y, z) * voxel_size, origin + (x + 1, y + 1, z + 1) * voxel_size].
 *   - Fitting: the bounds are those of the finite vertices (unreferenced ones included); their
 *     longest axis spans `resolution` voxels. By default the grid
 *     is resolution^3 with the mesh centred in it; with `anisotropic` the other axes get
 *     max(1, ceil(extent / voxel_size)) voxels, the mesh centred on each.
 *   - Surface set: conservative; a voxel is set when its closed box touches a triangle (Schwarz
 *     and Seidel 2010 triangle/box overlap). Solid set: a voxel is set when its centre is inside
 *     the mesh. The solid set does not include the surface set (use both for "occupied").
 *   - Level L has dims ceil(dims(L-1) / 2); a coarse voxel is set when any of its (up to 8)
 *     children is. Levels stop when the next one would have fewer than 4 voxels on its shortest
 *     side (a grid already under 4 has one level).
 *   - Triangles with a non-finite vertex or zero area are skipped and counted in the report.
 *
 * COST: one pass over the vertices (bounds) and one over the triangles (surface and z parity, both
 * with atomic bit operations when threads share the grid, plain ones on a thread's own copy),
 * then a prefix XOR per column; ROBUST adds the x and y parities (in the same triangle pass), a
 * running XOR along x and y and a vote, all word-wise (64 voxels per operation). SOLID_AUTO also
 * runs nacre_mesh_analyze (welding, edge sort), which costs more than the voxelization on large
 * meshes: per-frame callers should decide the rule once (topology does
 * not change under deformation), pass PARITY or ROBUST and use nacre_voxelize_update on a grid
 * kept across frames.
 *
 * THREADING: voxelization uses OpenMP with the context's thread count; the result does not
 * depend on it. With several threads, a grid whose level-0 sets (surface and solid, plus the
 * ROBUST parities) total at most 2 MiB and 4 words (256 voxels) per triangle also keeps a private
 * copy of them per extra thread (scratch like the ROBUST parities: reused by
 * nacre_voxelize_update, freed with the grid). A finished grid may be queried from several
 * threads at once.
 */
#ifndef NACRE_PUBLIC_VOXEL_H
#define NACRE_PUBLIC_VOXEL_H

#include <nacre/core.h>
#include <nacre/mesh.h>

#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* How the solid set is found. */
typedef enum nacre_voxel_solid_rule {
    NACRE_VOXEL_SOLID_AUTO = 0, /* PARITY for meshes closed after welding, ROBUST otherwise */
    NACRE_VOXEL_SOLID_PARITY,   /* crossings of z lines through voxel centres (closed meshes) */
    NACRE_VOXEL_SOLID_ROBUST    /* majority vote of the x, y and z parities (holes, flips) */
} nacre_voxel_solid_rule;

typedef struct nacre_voxel_settings {
    uint32_t resolution;               /* voxels along the longest axis, 1..4096; 0: 32 */
    bool anisotropic;                  /* false: resolution^3 grid; true: fitted to the bounds */
    nacre_voxel_solid_rule solid_rule; /* AUTO runs nacre_mesh_analyze (welding) to decide */
} nacre_voxel_settings;

typedef enum nacre_voxel_set { NACRE_VOXEL_SURFACE = 0, NACRE_VOXEL_SOLID } nacre_voxel_set;

typedef struct nacre_voxel_report {
    uint32_t dims[3];                  /* level 0 */
    float voxel_size;                  /* mesh units */
    float origin[3];                   /* minimum corner of voxel (0, 0, 0) */
    uint64_t surface_voxels, solid_voxels; /* level 0 */
    bool closed;                       /* AUTO: closed after welding; else: rule == PARITY */
    nacre_voxel_solid_rule rule_used;  /* PARITY or ROBUST */
    uint32_t levels;
    uint32_t skipped_degenerate;       /* zero-area triangles */
    uint32_t skipped_nonfinite;        /* triangles with a NaN or infinite vertex */
    double ms;                         /* wall time of nacre_voxelize */
} nacre_voxel_report;

typedef struct nacre_voxel_grid nacre_voxel_grid;

/* Defaults: resolution 32, cubic, AUTO. */
NACRE_API nacre_voxel_settings nacre_voxel_settings_defaults(void);
/* Voxelize `mesh` (read only, not kept). settings may be NULL (defaults); report may be NULL.
 * Fails with INVALID_ARGUMENT on out-of-range indices, on empty meshes and when no triangle is
 * left after skipping; OUT_OF_MEMORY past the allocator. Free with nacre_voxel_grid_destroy. */
NACRE_API nacre_result nacre_voxelize(nacre_context *ctx, const nacre_mesh_data *mesh,
                                      const nacre_voxel_settings *settings,
                                      nacre_voxel_grid **out, nacre_voxel_report *report);
/* Per-frame path: re-voxelize `mesh` into an existing `grid` (from nacre_voxelize, same context),
 * with the same results as a fresh nacre_voxelize bit for bit. The grid's level arrays and its
 * scratch (the ROBUST x and y parity sets, kept in the grid) are reused when the new sizes fit
 * and reallocated otherwise, so a caller voxelizing every frame (as the seed does) allocates
 * nothing after the first frame; create the grid once, update it each frame, destroy it at the
 * end. Settings may change between calls (resolution, anisotropic, rule); report->ms is the wall
 * time of this call. Argument errors detected before any work (NULL or empty mesh, bad settings)
 * leave the grid unchanged; a later failure (bad index, no usable triangle, out of memory)
 * leaves it with 0 levels (queries return false / 0) until the next successful update. */
NACRE_API nacre_result nacre_voxelize_update(nacre_voxel_grid *grid, const nacre_mesh_data *mesh,
                                             const nacre_voxel_settings *settings,
                                             nacre_voxel_report *report);
NACRE_API void nacre_voxel_grid_destroy(nacre_voxel_grid *grid);
/* Number of levels (>= 1). */
NACRE_API uint32_t nacre_voxel_grid_levels(const nacre_voxel_grid *grid);
/* Dims of `level`; false (dims zeroed) when the level does not exist. */
NACRE_API bool nacre_voxel_grid_dims(const nacre_voxel_grid *grid, uint32_t level,
                                     uint32_t dims[3]);
/* Whether voxel (x, y, z) of `level` is in `set`; false outside the grid. */
NACRE_API bool nacre_voxel_grid_get(const nacre_voxel_grid *grid, nacre_voxel_set set,
                                    uint32_t level, uint32_t x, uint32_t y, uint32_t z);
/* The whole of `set` at `level` as bytes (1 set, 0 not), out[x + nx * (y + ny * z)], out holding
 * nx * ny * nz bytes; much faster than a nacre_voxel_grid_get per voxel. False (out untouched)
 * when the level does not exist. */
NACRE_API bool nacre_voxel_grid_unpack(const nacre_voxel_grid *grid, nacre_voxel_set set, uint32_t level,
                                       uint8_t *out);
/* Voxels set in `set` at `level`. */
NACRE_API uint64_t nacre_voxel_grid_count(const nacre_voxel_grid *grid, nacre_voxel_set set,
                                          uint32_t level);
/* Write `level` as NRRD (uint8, raw): sizes 2 x y z, channel 0 = solid, 1 = surface (0 or 1),
 * with space directions in mesh units and "space origin" the centre of voxel (0, 0, 0) (NRRD
 * places samples at cell centres). Written to a temporary file then renamed. */
NACRE_API nacre_result nacre_voxel_grid_write_nrrd(const nacre_voxel_grid *grid, uint32_t level,
                                                   const char *path);
/* Rest-pose coordinates. The grid must come from `deformed`; `rest` has the same vertex count
 * and indices (undeformed positions). Fills out[3 * (x + nx * (y + ny * z))] for every level-0
 * voxel (out holds 3 * nx * ny * nz floats): NaN for voxels in neither set; otherwise the rest
 * point of the voxel's CENTRE. A surface voxel takes the closest point q on the closest deformed
 * triangle touching it, and maps its centre c to rest(q) + A (c - q), A the triangle's local
 * deformed-to-rest map (its edges in the plane; along the normal, the rest normal scaled by
 * sqrt(rest area / deformed area)). A solid voxel not on the surface follows the nearest
 * surface voxel in 6-connected steps (breadth-first, first reached wins, in a fixed order) the
 * same way: rest(c_surface) + A (c - c_surface). Exact for translations, rotations and uniform
 * scales, first order for smooth deformations. Serial. */
NACRE_API nacre_result nacre_voxel_grid_rest_positions(const nacre_voxel_grid *grid,
                                                       const nacre_mesh_data *rest,
                                                       const nacre_mesh_data *deformed,
                                                       float *out);

#ifdef __cplusplus
}
#endif

#endif /* NACRE_PUBLIC_VOXEL_H */
