/*
 * raster.h: the tiled, multithreaded software rasterizer (private API).
 *
 * Stage 1 (nc_raster_visibility): world-space triangles -> a visibility buffer (per pixel: depth
 * and the id of the nearest triangle). Fixed-point edge functions with the top-left rule, so a
 * pixel centre on an edge shared by two triangles is drawn exactly once. Near-plane clipping.
 * Stage 2 (nc_gbuffer_resolve): per pixel, the camera ray is intersected with the visible
 * triangle's plane, which gives perspective-correct barycentrics independent of clipping; they
 * interpolate position, normal and UV.
 * Depth-only rendering (nc_raster_depth) serves shadow maps (src/raster/shadow.c).
 *
 * Conventions: pixel (x, y) has its centre at (x + 0.5, y + 0.5); row 0 is the top of the image.
 * Matrices follow core/math.h (NDC z in [0, 1], y up). Front faces wind counter-clockwise on
 * screen.
 */
#ifndef NACRE_RASTER_H
#define NACRE_RASTER_H

#include "core/core.h"
#include "core/math.h"

#define NC_NO_OBJECT UINT32_MAX

/* One draw: an object's world-space triangles (borrowed for the call). */
typedef struct nc_raster_mesh {
    const float *positions;   /* world space, 3 floats per vertex */
    const uint32_t *indices;  /* 3 per triangle */
    uint32_t vertex_count, triangle_count;
    uint32_t object_index;    /* written to the visibility buffer */
    bool double_sided;        /* false: back faces are culled */
} nc_raster_mesh;

typedef struct nc_raster_view {
    nc_mat4 view;        /* world -> view */
    nc_mat4 proj;        /* view -> clip */
    int32_t width, height;
    bool orthographic;
} nc_raster_view;

/* Per pixel: depth = NDC z of the nearest surface (1 where empty, i.e. cleared to far), object =
 * object_index (NC_NO_OBJECT where empty), triangle = triangle index within the object
 * (NC_NO_OBJECT where empty). */
typedef struct nc_vis_buffer {
    int32_t width, height;
    float *depth;
    uint32_t *object;
    uint32_t *triangle;
} nc_vis_buffer;

typedef struct nc_raster_counts {
    uint64_t triangles;       /* submitted */
    uint64_t triangles_drawn; /* survived culling and covered at least one pixel centre bbox
                                 (bounding boxes of up to 2x2 centres: covered a centre) */
} nc_raster_counts;

/* Scratch memory (bins, clip buffers) kept between frames. */
typedef struct nc_rasterizer nc_rasterizer;

nacre_result nc_rasterizer_create(nacre_context *ctx, nc_rasterizer **out);
void nc_rasterizer_destroy(nc_rasterizer *r);

/* Allocate or resize a visibility buffer (owned by the caller, freed with nc_vis_buffer_free). */
nacre_result nc_vis_buffer_resize(nacre_context *ctx, nc_vis_buffer *vb, int32_t width, int32_t height);
void nc_vis_buffer_free(nacre_context *ctx, nc_vis_buffer *vb);

/* Clear and draw all meshes. Deterministic: the result does not depend on the thread count
 * (equal depths resolve to the earlier draw / lower triangle index). */
nacre_result nc_raster_visibility(nc_rasterizer *r, const nc_raster_view *view,
                                  const nc_raster_mesh *meshes, uint32_t mesh_count,
                                  nc_vis_buffer *out, nc_raster_counts *counts);

/* Depth only, into depth[width*height] (cleared to 1). cull_back_faces as for the camera: when
 * true, back faces of meshes that are not double_sided are culled; when false, none are. */
nacre_result nc_raster_depth(nc_rasterizer *r, const nc_raster_view *view,
                             const nc_raster_mesh *meshes, uint32_t mesh_count,
                             bool cull_back_faces, float *depth);

/* Attributes of one object for the G-buffer resolve (borrowed). */
typedef struct nc_gbuffer_source {
    const float *positions; /* world, 3 per vertex */
    const float *normals;   /* world, 3 per vertex (NULL: the geometric normal) */
    const float *uvs;       /* 2 per vertex, or NULL */
    const uint32_t *indices;
    uint32_t material_index;
} nc_gbuffer_source;

/* The G-buffer: one flat array per attribute, pixel-major, interleaved components. Pixels with
 * object == NC_NO_OBJECT hold zeros (and view_depth = +inf). Normals face the camera side the
 * triangle was seen from (flipped for back faces of double-sided objects). */
typedef struct nc_gbuffer {
    int32_t width, height;
    float *position;   /* 3: world position */
    float *normal;     /* 3: unit world shading normal (interpolated) */
    float *geo_normal; /* 3: unit world geometric (face) normal, same side as `normal` */
    float *uv;         /* 2 */
    float *view_depth; /* 1: distance along the view axis (scene units) */
    uint32_t *object;  /* object index or NC_NO_OBJECT */
    uint32_t *material;/* material index */
    uint32_t *triangle;/* triangle index in the object */
    /* Per row, the pixel range [first, end) the last resolve may have left non-empty (written
     * by gbuffer.c only). Pixels outside it are known to hold the empty values: the resolve does
     * not rewrite them (so the arrays above must not be written by anyone but
     * nc_gbuffer_resolve) and the shading pass does not read their ids. */
    int32_t *row_span;
} nc_gbuffer;

nacre_result nc_gbuffer_resize(nacre_context *ctx, nc_gbuffer *gb, int32_t width, int32_t height);
void nc_gbuffer_free(nacre_context *ctx, nc_gbuffer *gb);
/* Fill the G-buffer from a visibility buffer. sources[object_index] describes each object. */
nacre_result nc_gbuffer_resolve(nacre_context *ctx, const nc_raster_view *view, const nc_vis_buffer *vis,
                                const nc_gbuffer_source *sources, uint32_t source_count,
                                nc_gbuffer *out);

/* ---- Shadow maps (shadow.c) ---- */

typedef enum nc_shadow_kind { NC_SHADOW_ORTHO = 0, NC_SHADOW_PERSPECTIVE, NC_SHADOW_CUBE } nc_shadow_kind;

/* A depth map from a light: directional -> one orthographic map fitted to the bounds of the
 * shadow casters and receivers; spot -> one perspective map covering the cone; point -> a cube
 * of six 90-degree perspective faces. */
typedef struct nc_shadow_map {
    nc_shadow_kind kind;
    int32_t size;               /* texels per side (per face for cubes) */
    int32_t face_count;         /* 1 or 6 */
    nc_raster_view views[6];
    nc_mat4 world_to_clip[6];
    float *depth;               /* face_count * size * size, NDC z */
    float texel_world[6];       /* approximate world size of one texel at unit distance (persp.) or absolute (ortho) */
    float light_pos[3];         /* point/spot */
    float light_dir[3];         /* directional/spot: direction of travel */
    /* Set anew by every nc_shadow_render, from a counter of the context (unique within it, so
     * that a map re-rendered, or another map at the same address, is told apart); 0: none */
    uint64_t generation;
} nc_shadow_map;

/* Build (allocate if needed) and render the shadow map of one light. Scene bounds are the world
 * bounds of all objects (casters and receivers). */
nacre_result nc_shadow_render(nc_rasterizer *r, nacre_context *ctx, const nacre_light_desc *light,
                              const float bounds_min[3], const float bounds_max[3], int32_t size,
                              const nc_raster_mesh *casters, uint32_t caster_count,
                              nc_shadow_map *sm);
void nc_shadow_free(nacre_context *ctx, nc_shadow_map *sm);
/* Depth maps a light's shadow needs: 6 (a cube) for a point light, else 1. */
static inline int nc_shadow_face_count(nacre_light_type type) { return type == NACRE_LIGHT_POINT ? 6 : 1; }
/* Fraction of light reaching world point p (1 = lit) with PCF over a disc of `pcf_radius`
 * texels; `bias` in texels, scaled by the slope between the normal n and the light.
 * Implementation notes (shadow.c): the PCF kernel is a box of half-width pcf_radius (clamped to
 * [0.5, 8]) with texels weighted by overlap area; each texel compares against the depth of the
 * plane through p with normal n along that texel's ray (receiver-plane bias), so n should be the
 * surface normal at p (either side). Points outside the map (or its depth range) are lit.
 * Perspective maps keep far/near <= 1000: casters closer to a point or spot light than
 * far/1000 do not shadow. Thread-safe (reads only). */
float nc_shadow_lookup(const nc_shadow_map *sm, nc_vec3 p, nc_vec3 n, float pcf_radius, float bias);
/* Fraction of light reaching a point in the air (fog): no surface, so no receiver plane; a
 * 2 x 2 bilinear depth comparison with `bias` texels (pcf_radius unused), a quarter of
 * nc_shadow_lookup's cost. Points beyond the map's far plane (behind every caster) are shadowed
 * where the map holds a caster, where surfaces beyond the scene bounds count as lit. */
float nc_shadow_lookup_volume(const nc_shadow_map *sm, nc_vec3 p, float pcf_radius, float bias);
/* nc_shadow_lookup_volume for 8 points (px, py, pz: 8 floats each) into out[0 .. 8): the set-up
 * and the comparisons 8 lanes at a time (core/simd.h), the texels read lane by lane; equal to it
 * up to float rounding of the set-up and, for an orthographic map, of the comparison, made on
 * the stored depths (cube maps: the same calls). */
void nc_shadow_lookup_volume8(const nc_shadow_map *sm, const float *px, const float *py, const float *pz, float bias,
                              float *out);
/* Least and greatest stored depth (NDC) around the texels of a single-face shadow map, for
 * nc_shadow_lookup_volume_n: block (bx, by) covers texels bx 2^shift - 1 .. (bx + 1) 2^shift - 1
 * by the same rows (those in the map), so that the 2 x 2 texels of a lookup whose first texel is
 * (x0, y0) all lie in block ((x0 + 1) >> shift, (y0 + 1) >> shift). (min, max) pairs row by row
 * (NaN, NaN where the block holds a NaN or an infinite depth; max +inf on the table's border).
 * Owned by the caller: zero-initialise, then nc_shadow_minmax_update before the lookups. */
typedef struct nc_shadow_minmax {
    uint64_t generation; /* the map's when made; 0: not made */
    int32_t size;        /* the map's */
    int32_t shift;       /* blocks of 2^shift texels (plus one), the least with dim <= NC_SHADOW_MM_DIM */
    int32_t dim;         /* blocks a side: (size >> shift) + 1 */
    float *data;
    size_t capacity;
} nc_shadow_minmax;
/* 257^2 pairs: 516 KiB a map, 8 x 8 texel blocks for the default 2048^2 */
#define NC_SHADOW_MM_DIM 257

/* Make mm the table of sm unless it already is (the same generation: a map that is not
 * re-rendered costs a comparison). Cube maps get none (their lookups do not use it). `threads`
 * make it (OpenMP), reading the map once. */
nacre_result nc_shadow_minmax_update(nacre_context *ctx, const nc_shadow_map *sm, nc_shadow_minmax *mm, int threads);
void nc_shadow_minmax_free(nacre_context *ctx, nc_shadow_minmax *mm);
/* nc_shadow_lookup_volume8 for n points (n a multiple of 8) with the same values, bit for bit,
 * deciding points from the table mm (NULL, or not made for sm's generation: none decided): a
 * point whose block lies wholly on the lit side of its comparison depth (or holds only cleared
 * texels) has all 4 taps lit, and its value is the sum of its bilinear weights as the taps sum
 * them; one whose block lies wholly behind has none, 0. Only the others read their texels,
 * fetched for a column's worth of points at once (they are few, scattered over the map and
 * seldom in the cache). Returns how many points read texels. */
uint32_t nc_shadow_lookup_volume_n(const nc_shadow_map *sm, const nc_shadow_minmax *mm, uint32_t n, const float *px,
                                   const float *py, const float *pz, float bias, float *out);
/* nc_shadow_lookup for n points (positions p, normals n as SoA arrays) into out[0 .. n), with the
 * next lookups' texels prefetched. An orthographic map (directional light) does the per-point
 * set-up of many points at once in vectorized loops; the values are nc_shadow_lookup's up to
 * float rounding of that set-up. */
void nc_shadow_lookup_n(const nc_shadow_map *sm, uint32_t n, const float *px, const float *py, const float *pz,
                        const float *nx, const float *ny, const float *nz, float pcf_radius, float bias, float *out);

#endif /* NACRE_RASTER_H */
