/*
 * raster_frame.h: the part of a frame that every rasterizing method shares, and its caches
 * (private API of src/render).
 *
 * setup (draw lists) -> raster (visibility buffer) -> gbuffer (attribute resolve) -> shadow (one
 * depth map per light) -> the method's own stages -> shade (phong, with the method's subsurface
 * hook). The raster frame remembers the inputs each stage last saw (scene identity, version
 * counters, light descs, sizes) and skips a stage whose inputs are unchanged: a camera move
 * redraws the G-buffer but keeps the shadow maps, a light edit redraws that light's map only,
 * a material edit only re-shades.
 *
 * Camera conventions: core/math.h (right-handed, looking down -z, NDC z in [0, 1]). When the
 * scene leaves near/far at 0 they are fitted to the committed scene bounds.
 */
#ifndef NACRE_RENDER_RASTER_FRAME_H
#define NACRE_RENDER_RASTER_FRAME_H

#include "raster/raster.h"
#include "scene/scene.h"
#include "shade/shade.h"

/* The stages of the raster frame, for nc_method.stages. */
#define NC_RASTER_STAGES                                                                                              \
    ((1u << NACRE_STAGE_SETUP) | (1u << NACRE_STAGE_RASTER) | (1u << NACRE_STAGE_GBUFFER) |                          \
     (1u << NACRE_STAGE_SHADOW) | (1u << NACRE_STAGE_SHADE))

typedef struct nc_shadow_slot {
    nc_shadow_map map;
    bool valid;
    uint64_t scene_uid, geometry_version;
    int32_t size;
    nacre_light_desc light; /* the desc the map was drawn for */
} nc_shadow_slot;

typedef struct nc_raster_frame {
    nacre_context *ctx;
    nc_rasterizer *rasterizer;
    nc_vis_buffer vis;
    nc_gbuffer gbuffer;
    /* G-buffer cache key */
    bool gbuffer_valid;
    uint64_t gb_scene_uid, gb_geometry, gb_camera;
    int32_t gb_width, gb_height;
    nc_raster_view view;
    nc_shadow_slot *shadows;
    uint32_t shadow_capacity;
    /* Draw lists, grown to the object count */
    nc_raster_mesh *draws;
    nc_gbuffer_source *sources;
    nc_shade_light *shade_lights; /* one per scene light after nc_raster_frame_prepare */
    uint32_t draw_capacity, light_capacity;
    /* The last shaded frame's image (settings.reuse_output): where it was written, with which
     * environment, and the G-buffer's row spans it was shaded with; outside them it holds the
     * environment. image_valid is false until a frame completes. */
    bool image_valid;
    const float *image_pixels;
    int32_t image_width, image_height;
    size_t image_stride;
    float image_env[3];
    int32_t *image_span;
    int32_t image_span_rows;
} nc_raster_frame;

nacre_result nc_raster_frame_init(nacre_context *ctx, nc_raster_frame *rf);
void nc_raster_frame_free(nc_raster_frame *rf);

/* Whether `out` still holds the last frame shaded into it (reuse_output); the answer is taken
 * before anything is written, and the image is forgotten until the next frame completes. */
bool nc_raster_frame_take_reuse(nc_raster_frame *rf, const nacre_scene *s, const nacre_render_settings *settings,
                                const nacre_image *out);
/* Draw lists, camera G-buffer and shadow maps, each only if its inputs changed; fills the
 * SETUP, RASTER, GBUFFER and SHADOW stages of stats. */
nacre_result nc_raster_frame_prepare(nc_raster_frame *rf, const nacre_scene *s, const nacre_render_settings *settings,
                                     nacre_render_stats *stats);
/* The camera G-buffer alone (for depth under a method that does not rasterize). */
nacre_result nc_raster_frame_gbuffer(nc_raster_frame *rf, const nacre_scene *s, int32_t width, int32_t height,
                                     nacre_render_stats *stats);
/* Shading parameters of the prepared frame (eye, view direction, shadow filtering). */
void nc_raster_frame_shade_params(const nc_raster_frame *rf, const nacre_render_settings *settings,
                                  nc_shade_params *params);
/* The phong pass (with the params' subsurface hook) into out; reuse as from take_reuse. Fills
 * the SHADE stage. */
nacre_result nc_raster_frame_shade(nc_raster_frame *rf, const nacre_scene *s, const nc_shade_params *params,
                                   nacre_image *out, bool reuse, nacre_render_stats *stats);

#endif /* NACRE_RENDER_RASTER_FRAME_H */
