/*
 * layers.h: where a point of a layered translucent material is (which layer), after Francois,
 * Pattanaik, Bouatouh and Breton 2006, "Subsurface texture mapping" (seed 001, section 2.1).
 * See layers.c and nacre_layering for the conventions.
 */
#ifndef NACRE_LAYERS_H
#define NACRE_LAYERS_H

#include "scene/scene.h"

/* A material's layering resolved against its scene once (texture pointer, depth ranges). */
typedef struct nc_layer_stack {
    uint32_t count;                    /* layers; index `count` is the core */
    float depth[NACRE_MAX_LAYERS];     /* per layer: bottom, or the scale of its map channel */
    const nc_texture_rec *map;         /* depth map or NULL */
    float lo[NACRE_MAX_LAYERS];        /* smallest bottom(j) over all uv */
    float hi[NACRE_MAX_LAYERS];        /* largest bottom(j) over all uv */
} nc_layer_stack;

/* `layering` must have passed the scene's validation (its depth map exists). */
void nc_layers_init(const nacre_scene *scene, const nacre_layering *layering, nc_layer_stack *out);
/* The layer holding depth d below the surface point of texture coordinates (u, v): 0..count-1,
 * or count for the core. A point exactly on a boundary belongs to the deeper layer. */
uint32_t nc_layers_find(const nc_layer_stack *stack, float d, float u, float v);
/* The part of a layer lookup that needs no depth map: the first layer j whose largest bottom
 * over every uv lies below depth d; true if that settles it (d is above j's smallest bottom,
 * or in the core), else the caller reads the bottoms at (u, v) and goes on from j with
 * nc_layers_after. nc_layers_find is these two around nc_layers_bottoms. */
static inline bool nc_layers_settled(const nc_layer_stack *s, float d, uint32_t *j)
{
    uint32_t k = 0;
    while (k < s->count && d >= s->hi[k])
        k++;
    *j = k;
    return k == s->count || d < s->lo[k];
}

static inline uint32_t nc_layers_after(const nc_layer_stack *s, float d, uint32_t j,
                                       const float bottom[NACRE_MAX_LAYERS])
{
    while (j < s->count && d >= bottom[j])
        j++;
    return j;
}
/* Bottoms of the layers (running maximum of depth * map) at texture coordinates (u, v). */
void nc_layers_bottoms(const nc_layer_stack *stack, float u, float v, float bottom[NACRE_MAX_LAYERS]);
/* Bit j set when some uv puts some depth of [d0, d1] in layer j (bit count: the core). */
uint32_t nc_layers_touching(const nc_layer_stack *stack, float d0, float d1);
/* Bilinear lookup (repeat) of channel c of a texture at (u, v), see nacre_scene_add_texture. */
float nc_texture_sample(const nc_texture_rec *tex, int c, float u, float v);
/* Channels c .. c + n - 1 of the same lookup at once (n <= the texture's channels - c). */
void nc_texture_sample_n(const nc_texture_rec *tex, int c, int n, float u, float v, float *out);
/* A colour texture (a material's diffuse_map) at (u, v): channels 0-2, or channel 0 as grey for
 * a 1- or 2-channel texture. */
void nc_texture_rgb(const nc_texture_rec *tex, float u, float v, float out[3]);

#ifdef NACRE_HAVE_EMBREE
#include <embree3/rtcore.h>

/* Nearest point of a mesh (Embree point queries, closest point on each candidate triangle):
 * the depth of a point below the surface and the uv it reads the depth map at. */
typedef struct nc_surface_locator nc_surface_locator;

/* The mesh (positions, indices, and uvs if any) is borrowed and must outlive the locator. */
nacre_result nc_locator_create(nacre_context *ctx, RTCDevice device, const nacre_mesh_data *mesh,
                               nc_surface_locator **out);
void nc_locator_destroy(nacre_context *ctx, nc_surface_locator *loc);
/* Distance from p to the mesh and the interpolated uv there ((0, 0) for a mesh without uvs);
 * INFINITY (uv (0, 0)) when no point of the mesh is within max_dist. The search only visits the
 * mesh within the smaller of max_dist and the distance to the triangle *hint (if hint is not NULL
 * and *hint a valid triangle), so callers pass the depth beyond which the answer no longer
 * matters and a triangle that is probably near. *hint receives the nearest triangle
 * (UINT32_MAX when none is within max_dist). Thread-safe. */
float nc_locator_nearest(const nc_surface_locator *loc, const float p[3], float max_dist, uint32_t *hint,
                         float uv[2]);
#endif

#endif /* NACRE_LAYERS_H */
