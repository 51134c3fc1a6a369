/*
 * mesh.h: triangle meshes as plain arrays (nacre_mesh_data), mesh analysis (nacre_mesh_info), the
 * built-in shapes, loading (OBJ, PLY, glTF), validation, and normals and tangents. Part of nacre's
 * public API; the conventions (units, ownership, memory, threading, errors) are in the opening
 * comment of nacre.h.
 */
#ifndef NACRE_PUBLIC_MESH_H
#define NACRE_PUBLIC_MESH_H

#include <nacre/core.h>

#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ------------------------------------------------------------------------------------------ */
/* Mesh data: plain arrays, owned by whoever allocated them                                   */
/* ------------------------------------------------------------------------------------------ */

typedef struct nacre_mesh_data {
    uint32_t vertex_count;
    uint32_t triangle_count;
    float *positions; /* 3 floats per vertex */
    float *normals;   /* 3 per vertex, unit length, or NULL */
    float *uvs;       /* 2 per vertex, or NULL */
    float *tangents;  /* 4 per vertex: unit xyz + handedness w = +-1 (bitangent = w n x t), or NULL */
    uint32_t *indices; /* 3 per triangle, counter-clockwise seen from outside */
} nacre_mesh_data;

/* What mesh analysis reports. Edges are counted after welding exactly coincident positions. */
typedef struct nacre_mesh_info {
    uint32_t vertex_count, triangle_count;
    uint32_t welded_vertex_count;     /* distinct positions among referenced vertices */
    uint32_t unreferenced_vertices;   /* vertices no triangle uses */
    uint32_t degenerate_triangles;    /* zero area after welding (repeated vertex or collinear) */
    uint64_t edge_count;              /* undirected edges after welding */
    uint64_t boundary_edges;          /* used by one triangle */
    uint64_t nonmanifold_edges;       /* used by three or more triangles */
    bool closed;                      /* no boundary and no non-manifold edges */
    float bounds_min[3], bounds_max[3];
    double surface_area;
} nacre_mesh_info;

typedef enum nacre_shape_type {
    NACRE_SHAPE_SPHERE = 0, /* radius, segments (around) x rings */
    NACRE_SHAPE_BOX,        /* size[3], centred at the origin, per-face UVs */
    NACRE_SHAPE_PLANE,      /* size[0] x size[2] in the xz plane, normal +y */
    NACRE_SHAPE_TORUS       /* radius (major), minor_radius, in the xz plane */
} nacre_shape_type;

typedef struct nacre_shape_desc {
    nacre_shape_type type;
    float radius;        /* sphere radius; torus major radius */
    float minor_radius;  /* torus tube radius */
    float size[3];       /* box extents; plane uses size[0] and size[2] */
    uint32_t segments;   /* subdivisions around (sphere, torus) or per side (box, plane) */
    uint32_t rings;      /* subdivisions from pole to pole (sphere) or around the tube (torus) */
} nacre_shape_desc;

/* Defaults: sphere r=1 64x32, box 1x1x1, plane 10x10, torus 1/0.25 64x32. */
NACRE_API nacre_shape_desc nacre_shape_desc_defaults(nacre_shape_type type);
/* Build a shape with positions, normals, UVs and tangents. Closed shapes are watertight (shared
 * vertices along seams are exactly coincident). */
NACRE_API nacre_result nacre_mesh_make_shape(nacre_context *ctx, const nacre_shape_desc *desc,
                                             nacre_mesh_data *out);
/* Load OBJ, PLY (ASCII/binary) or glTF 2.0 (.gltf/.glb); all meshes in the file are merged,
 * with node transforms applied. Polygons are triangulated: by assimp when none has more than 64
 * corners, otherwise by nacre, in time linear in the corners for convex polygons (and those
 * star-shaped around their first corner, which become fans) and by ear clipping for others of
 * up to 512 corners; a longer polygon of that kind fails with UNSUPPORTED naming the face.
 * Normals and tangents are computed when missing (tangents need UVs; without UVs a tangent is
 * chosen perpendicular to the normal). Fails on empty meshes, non-finite positions and
 * out-of-range indices. */
NACRE_API nacre_result nacre_mesh_load(nacre_context *ctx, const char *path, nacre_mesh_data *out);
/* Free arrays allocated by the library and zero the struct. */
NACRE_API void nacre_mesh_data_free(nacre_context *ctx, nacre_mesh_data *mesh);
/* Check sizes, indices and finiteness; names the first problem. */
NACRE_API nacre_result nacre_mesh_validate(nacre_context *ctx, const nacre_mesh_data *mesh,
                                           const char *name);
/* (Re)compute area- and angle-weighted smooth normals across exactly coincident positions.
 * This and nacre_mesh_compute_tangents allocate a missing array through the context: free it
 * with nacre_mesh_data_free along with the rest, or alone with nacre_free. */
NACRE_API nacre_result nacre_mesh_compute_normals(nacre_context *ctx, nacre_mesh_data *mesh);
/* (Re)compute tangents from UVs (MikkTSpace-like per-vertex accumulation), orthogonalised
 * against the normals; needs normals. Without UVs, an arbitrary perpendicular frame. */
NACRE_API nacre_result nacre_mesh_compute_tangents(nacre_context *ctx, nacre_mesh_data *mesh);
/* Topology and size report. */
NACRE_API nacre_result nacre_mesh_analyze(nacre_context *ctx, const nacre_mesh_data *mesh,
                                          nacre_mesh_info *out);

#ifdef __cplusplus
}
#endif

#endif /* NACRE_PUBLIC_MESH_H */
