/*
 * method.h: the interface every render method implements, and the post passes that compose
 * with any method's image and depth (private API of src/render).
 *
 * A method is a row of the table in methods.c: its name (what scene files, the CLI, the bench
 * and the viewer say), how to make and destroy its per-renderer state, and how to render one
 * frame. The renderer (renderer.c) owns one state per method it has used, so switching methods
 * back and forth keeps each method's caches; each method decides from the scene's version
 * counters which of its stages to rerun (see nacre_renderer in render.h).
 *
 * Methods that draw the scene with the rasterizer (phong, diffusion, and the coming layered
 * method) share one raster frame (raster_frame.h) held by the renderer: camera visibility,
 * G-buffer and shadow maps are made once for whichever of them runs.
 *
 * Depth: every frame ends with a per-pixel view-axis depth in scene units (distance from the
 * eye along the camera's forward axis; INFINITY where no surface is), which post passes read.
 * A method that draws no G-buffer leaves frame->depth NULL and the renderer asks the raster
 * frame for one when something needs it.
 */
#ifndef NACRE_RENDER_METHOD_H
#define NACRE_RENDER_METHOD_H

#include "render/raster_frame.h"

/* One frame as a method sees it. */
typedef struct nc_frame {
    nacre_context *ctx;
    const nacre_scene *scene;
    const nacre_render_settings *settings;
    nacre_image *out;          /* width x height x 3, allocated by the renderer */
    nacre_render_stats *stats; /* zeroed by the renderer; the method fills its stages */
    nc_raster_frame *raster;   /* the renderer's shared raster frame */
    bool reuse;                /* out holds the renderer's previous raster frame (reuse_output) */
    const float *depth;        /* set by the method: view-axis depth per pixel, or NULL */
} nc_frame;

typedef struct nc_method {
    const char *name;          /* "phong", "diffusion", ... */
    nacre_method id;
    bool (*available)(void);   /* NULL: always */
    bool needs_objects;        /* false: a scene of fog alone is something to render */
    bool uses_raster;          /* draws through the shared raster frame */
    bool stochastic;           /* reads settings->pathtrace */
    bool renders_fog;          /* the scene's fog is in its image (post passes leave fog alone) */
    uint32_t stages;           /* bit (1u << stage) for each stage it may run */
    /* Checks of the settings only this method reads (NULL: none); messages name the field. */
    nacre_result (*check)(nacre_context *ctx, const nacre_render_settings *settings);
    nacre_result (*create)(nacre_context *ctx, void **state);
    nacre_result (*render)(void *state, nc_frame *frame);
    void (*destroy)(nacre_context *ctx, void *state);
} nc_method;

/* The method of that id or name, NULL if unknown. */
const nc_method *nc_method_get(nacre_method id);
const nc_method *nc_method_find(const char *name);

/* The methods of the table (methods.c). */
extern const nc_method nc_method_phong, nc_method_diffusion, nc_method_layered, nc_method_pathtrace;

/* What a post pass reads: the finished image of any method with its depth and camera. */
typedef struct nc_post_input {
    nacre_context *ctx;
    const nacre_scene *scene;
    const nacre_render_settings *settings;
    const nc_raster_view *view; /* camera matrices the depth was made with */
    const float *depth;         /* width * height view-axis depths, INFINITY: background */
    /* The frame's lights with their shadow maps (a rasterizing method's; NULL otherwise). */
    const nc_shade_light *lights;
    uint32_t light_count;
} nc_post_input;

/* A pass over a finished frame (the fog and froxel volumetrics of seed 003 are such passes). */
typedef struct nc_post_pass {
    const char *name;
    /* Whether the pass has anything to do for this scene and these settings. */
    bool (*wanted)(const nacre_scene *scene, const nacre_render_settings *settings);
    nacre_result (*create)(nacre_context *ctx, void **state);
    /* Read and change `image` (width x height x 3, radiance) in place. */
    nacre_result (*apply)(void *state, const nc_post_input *in, nacre_image *image,
                          nacre_render_stats *stats);
    void (*destroy)(nacre_context *ctx, void *state);
} nc_post_pass;

/* Distance and exponential height fog over a finished frame (post_fog.c). */
extern const nc_post_pass nc_post_fog;
/* Particles as volumetric billboards or sprites (post_particles.c). */
extern const nc_post_pass nc_post_particles;
/* Volumetric fog: froxels and the per-pixel march (post_volumetrics.c). */
extern const nc_post_pass nc_post_froxel, nc_post_raymarch;

/* How many of the scene's fogs the fog passes draw: the user's, and the particle systems' density
 * grids only when particles are drawn as voxels (otherwise the particles pass draws them). */
static inline uint32_t nc_post_fogs_drawn(const nacre_scene *scene, const nacre_render_settings *settings)
{
    return settings->particles == NACRE_PARTICLES_DRAW_VOXEL ? scene->fog_count : nc_scene_user_fogs(scene);
}

/* The built-in post passes, in the order they apply (post.c). */
extern const nc_post_pass *const nc_post_passes[];
extern const uint32_t nc_post_pass_count;

/* Replace the renderer's list of post passes (tests install their own); the list is borrowed.
 * States of the previous list are destroyed. */
nacre_result nc_renderer_set_post_passes(nacre_renderer *r, const nc_post_pass *const *passes, uint32_t count);

#endif /* NACRE_RENDER_METHOD_H */
