/*
 * planes.h: what the layered method precomputes per translucent object when its geometry
 * changes (seed 001, Francois et al. 2006, section 2.2 and eq. 14): per vertex the least-squares
 * plane of the vertices within r = -log(eps) / sigma_t, and per triangle the world gradients of
 * the texture coordinates (the tangent frame T / |dP/du|, B / |dP/dv| that maps a displacement
 * below the surface to a displacement in the depth map). See planes.c.
 */
#ifndef NACRE_LAYERED_PLANES_H
#define NACRE_LAYERED_PLANES_H

#include "core/core.h"

/* One object's planes and uv gradients, in world space (scene units). */
typedef struct nc_layer_planes {
    uint32_t vertex_count, triangle_count;
    float *plane_n; /* 3 per vertex: unit normal of the fitted plane, on the side of the vertex normal */
    float *plane_p; /* 3 per vertex: the point of the plane on the vertex's normal line (eq. 14) */
    float *grad_uv; /* 6 per triangle: grad u then grad v (per scene unit, in the triangle's plane);
                       NULL when the mesh has no uvs */
} nc_layer_planes;

/* Build (or rebuild into the same arrays) the planes of a mesh: world positions and unit normals
 * (3 per vertex), uvs (2 per vertex, or NULL), triangles. radius > 0: the neighbourhood radius
 * (eq. 8). Neighbours are found through a uniform hash grid of cell `radius`. */
nacre_result nc_layer_planes_build(nacre_context *ctx, const float *positions, const float *normals,
                                   const float *uvs, const uint32_t *indices, uint32_t vertex_count,
                                   uint32_t triangle_count, float radius, nc_layer_planes *out);
void nc_layer_planes_free(nacre_context *ctx, nc_layer_planes *p);

#endif /* NACRE_LAYERED_PLANES_H */
