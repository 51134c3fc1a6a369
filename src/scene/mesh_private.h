/*
 * mesh_private.h: helpers shared by the mesh files (src/scene/mesh.c, src/scene/shapes.c,
 * src/io/mesh_load.c). Private to the library (prefix nc_).
 */
#ifndef NACRE_MESH_PRIVATE_H
#define NACRE_MESH_PRIVATE_H

#include "core/core.h"

/* Below this many elements a loop runs serially: an OpenMP team costs more than it saves. */
#define NC_MESH_PARALLEL_MIN 8192

/* The largest triangle count the mesh code accepts, so that 3 * triangle_count (corner ids)
 * fits in a uint32_t. */
#define NC_MESH_MAX_TRIANGLES (UINT32_MAX / 3u)

/* Weld vertices whose attributes are bit-identical (with -0.0 == +0.0): rep[i] is the smallest
 * index j whose positions (and normals, uvs when not NULL) equal those of i. rep[i] == i for the
 * first vertex of each group. Deterministic; rep must hold n entries. */
nacre_result nc_mesh_weld(nacre_context *ctx, uint32_t n, const float *positions,
                          const float *normals, const float *uvs, uint32_t *rep);

/* Validate counts, pointers, indices, finite positions and (when the pointer is non-NULL)
 * finite uvs; normals and tangents are not looked at. Messages start with `name`; failures
 * return `code` (the loader reports bad file contents as NACRE_ERROR_PARSE). */
nacre_result nc_mesh_check_geometry(nacre_context *ctx, const nacre_mesh_data *mesh,
                                    const char *name, nacre_result code);

/* One mesh instance of a file's node tree (src/io/mesh_load.c): the instance's triangles with
 * its node's global transform applied, where it sits in assimp's node tree, and assimp's
 * material index (assimp numbers materials in the order it first met them, not the file's). */
typedef struct nc_mesh_part {
    nacre_mesh_data data;
    uint32_t material;
    uint32_t mesh; /* assimp mesh index (one per glTF primitive) */
    uint32_t node; /* preorder number of the node in assimp's tree (root 0, children in order) */
    uint32_t slot; /* index in that node's mesh list (for glTF: the primitive) */
} nc_mesh_part;

/* Load a mesh file as one part per mesh instance (checks and completion as nacre_mesh_load).
 * *parts is allocated through the context; free with nc_mesh_parts_free. */
nacre_result nc_mesh_load_parts(nacre_context *ctx, const char *path, nc_mesh_part **parts,
                                uint32_t *count);
void nc_mesh_parts_free(nacre_context *ctx, nc_mesh_part *parts, uint32_t count);

#endif /* NACRE_MESH_PRIVATE_H */
