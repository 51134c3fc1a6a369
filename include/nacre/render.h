/*
 * render.h: rendering: the methods, the diffusion solver and source, nacre_render_settings, the
 * timed stages and nacre_render_stats, the renderer (nacre_renderer_render, nacre_render,
 * nacre_renderer_variance); and the loading of scene files (nacre_scene_load_file,
 * nacre_scene_load_json), here because they fill nacre_render_settings from the file's "render"
 * block. Part of nacre's public API; the conventions (units, ownership, memory, threading,
 * errors) are in the opening comment of nacre.h.
 */
#ifndef NACRE_PUBLIC_RENDER_H
#define NACRE_PUBLIC_RENDER_H

#include <nacre/core.h>
#include <nacre/image.h>
#include <nacre/scene.h>

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ------------------------------------------------------------------------------------------ */
/* Rendering                                                                                  */
/* ------------------------------------------------------------------------------------------ */

typedef enum nacre_method {
    NACRE_METHOD_PHONG = 0, /* ambient + Lambert + Blinn-Phong, shadow maps with PCF */
    NACRE_METHOD_DIFFUSION, /* Blanchard 2012 voxel diffusion */
    NACRE_METHOD_LAYERED,   /* Francois et al. 2006 subsurface texture mapping (not yet) */
    NACRE_METHOD_PATHTRACE, /* reference volumetric path tracer (Embree; see nacre render --help) */
    NACRE_METHOD_COUNT
} nacre_method;

/* "phong", "diffusion", "layered", "pathtrace". */
NACRE_API const char *nacre_method_name(nacre_method method);
/* Parse a method name; false if unknown. */
NACRE_API bool nacre_method_from_name(const char *name, nacre_method *out);
/* Whether this build implements the method. */
NACRE_API bool nacre_method_available(nacre_method method);

/* Diffusion solver (Blanchard 2012 section 4.5 and our default). */
typedef enum nacre_diffusion_solver {
    NACRE_SOLVER_MULTIGRID = 0, /* multigrid-preconditioned conjugate gradients to `tolerance` */
    NACRE_SOLVER_SEED           /* the seed: Jacobi sweeps over the resolution cascade, fixed counts */
} nacre_diffusion_solver;

/* Where the light transmitted through the surface enters the diffusion solve. */
typedef enum nacre_diffusion_source {
    NACRE_SOURCE_VOLUME = 0, /* reduced intensity deposited along the refracted ray, exp(-sigma_t' d) */
    NACRE_SOURCE_FACE        /* the seed: flux on the exposed voxel faces (Robin boundary source) */
} nacre_diffusion_source;

/* "multigrid", "seed"; "volume", "face". The from_name functions return false if unknown. */
NACRE_API const char *nacre_solver_name(nacre_diffusion_solver solver);
NACRE_API bool nacre_solver_from_name(const char *name, nacre_diffusion_solver *out);
NACRE_API const char *nacre_source_name(nacre_diffusion_source source);
NACRE_API bool nacre_source_from_name(const char *name, nacre_diffusion_source *out);

typedef struct nacre_render_settings {
    nacre_method method;
    int32_t width, height;    /* default 640 x 480; 1..16384 each, at most 2^26 pixels */
    float exposure;           /* EV stops applied when writing PNG (informational here) */
    int32_t shadow_map_size;  /* texels per side, default 2048; 0 disables shadows */
    float pcf_radius;         /* PCF kernel radius in shadow texels, default 1.5 */
    float shadow_bias;        /* depth bias in shadow texels, default 1.5 */
    uint32_t seed;            /* stochastic methods */
    uint32_t spp;             /* stochastic methods: samples per pixel */
    double time;              /* seconds: when the caller should commit the scene (deformers); the
                                 scene file's "render.time". The renderer itself does not read it. */
    /* diffusion */
    uint32_t voxel_resolution;       /* voxels along the longest axis of each translucent object, default 32 */
    int32_t tsm_size;                /* translucent shadow map: most texels per side, default 512; each map
                                        uses 4 texels per voxel side of the object's voxels (fewer on
                                        coarse grids), at most tsm_size */
    nacre_diffusion_solver solver;   /* default MULTIGRID */
    nacre_diffusion_source source;   /* default VOLUME */
    float tolerance;                 /* MULTIGRID: relative residual, default 1e-4 */
    uint32_t seed_iterations;        /* SEED: Jacobi sweeps per level, 0 = the seed's table 5.6 count */
    /* pathtrace */
    double time_limit;               /* seconds from the start of the render call; 0 = none.
                                        Stops within a pass, see nacre_render_stats */
    uint32_t max_scatter;            /* scattering events per path in media; 0 = unlimited */
    /* Raster methods (phong, diffusion): true promises that `out` holds, unchanged, the image this
     * renderer wrote in its previous frame (same pixels, size and stride), as in a viewer that
     * shows each frame and passes the buffer back. Pixels that were background then and still are
     * hold the environment already and are not rewritten (on a 1280x720 frame mostly background,
     * ~0.6 ms of memory writes); the image is identical to a full repaint. The renderer repaints
     * everything when the buffer, its size, the environment or the method differ from its last
     * frame. Default false. */
    bool reuse_output;
} nacre_render_settings;

NACRE_API nacre_render_settings nacre_render_settings_defaults(void);

/* Timed stages. A stage that did not run (cached or not used) reports 0 and ran = false. */
#define NACRE_STAGE_LIST(X)                                                                    \
    X(NACRE_STAGE_SETUP, "setup")                                                              \
    X(NACRE_STAGE_RASTER, "raster")                                                            \
    X(NACRE_STAGE_GBUFFER, "gbuffer")                                                          \
    X(NACRE_STAGE_SHADOW, "shadow")                                                            \
    X(NACRE_STAGE_VOXELIZE, "voxelize")                                                        \
    X(NACRE_STAGE_TSM, "tsm")                                                                  \
    X(NACRE_STAGE_INJECT, "inject")                                                            \
    X(NACRE_STAGE_PROPAGATE, "propagate")                                                      \
    X(NACRE_STAGE_SHADE, "shade")

typedef enum nacre_stage {
#define NACRE_STAGE_ENUM_(name, text) name,
    NACRE_STAGE_LIST(NACRE_STAGE_ENUM_)
#undef NACRE_STAGE_ENUM_
    NACRE_STAGE_COUNT
} nacre_stage;

NACRE_API const char *nacre_stage_name(nacre_stage stage);

typedef struct nacre_render_stats {
    uint64_t stage_us[NACRE_STAGE_COUNT];
    bool stage_ran[NACRE_STAGE_COUNT];
    uint64_t total_us;
    uint64_t triangles;          /* submitted to the camera rasterizer */
    uint64_t triangles_drawn;    /* after culling (back faces, off-screen, no pixel centre) */
    uint32_t shadow_maps;        /* rendered (not cached) this frame */
    int threads;
    /* diffusion (summed over translucent objects; dims of the largest grid) */
    uint32_t voxel_dims[3];
    nacre_diffusion_solver solver;
    uint32_t iterations;         /* MULTIGRID: PCG iterations (max over objects and channels); SEED: sweeps */
    double residual;             /* final relative residual (max over objects and channels) */
    /* pathtrace */
    uint32_t spp_done;           /* samples per pixel completed by every pixel (the minimum) */
    double samples_per_second;   /* camera paths per second */
    uint64_t samples_done;       /* camera paths completed, over all pixels (with a time limit,
                                    pixel counts may differ; each pixel is the mean of its own) */
    uint64_t paths_capped;       /* paths ended by the path-length or collision cap (README) */
    uint32_t pixels_unsampled;   /* time limit reached within the first pass: pixels without a
                                    sample, filled with their 8x8 block's mean (0 if none) */
} nacre_render_stats;

/* A renderer keeps the buffers and results of previous frames (G-buffer, shadow maps) and
 * recomputes only the stages whose inputs changed since its last render of the same scene:
 * changing only a material re-shades; moving only a light redraws its shadow map and re-shades;
 * moving the camera redraws the G-buffer. One renderer per thread. */
typedef struct nacre_renderer nacre_renderer;

NACRE_API nacre_result nacre_renderer_create(nacre_context *ctx, nacre_renderer **out);
NACRE_API void nacre_renderer_destroy(nacre_renderer *renderer);
/* Render a committed scene into `out` (3 channels, radiance). If out->pixels is NULL the image
 * is allocated (free with nacre_image_free); otherwise it must already be width x height x 3.
 * stats may be NULL. */
NACRE_API nacre_result nacre_renderer_render(nacre_renderer *renderer, const nacre_scene *scene,
                                             const nacre_render_settings *settings,
                                             nacre_image *out, nacre_render_stats *stats);
/* One-shot render with a temporary renderer. */
NACRE_API nacre_result nacre_render(const nacre_scene *scene, const nacre_render_settings *settings,
                                    nacre_image *out, nacre_render_stats *stats);

/* The per-pixel variance of the last path-traced image (variance of the pixel mean, 3 channels).
 * INVALID_OPERATION if the renderer's last frame was not path traced. Same allocation rule as
 * nacre_renderer_render. */
NACRE_API nacre_result nacre_renderer_variance(const nacre_renderer *renderer, nacre_image *out);

/* ------------------------------------------------------------------------------------------ */
/* Scene files (JSON; format in docs/scene-format.md)                                         */
/* ------------------------------------------------------------------------------------------ */

/* Load a scene file: builds the scene (not yet committed) and fills `settings` from its "render"
 * block (defaults otherwise); settings may be NULL. Paths inside are relative to the file.
 * Errors name the file and the field path, or line and column for malformed JSON. */
NACRE_API nacre_result nacre_scene_load_file(nacre_context *ctx, const char *path,
                                             nacre_scene **out, nacre_render_settings *settings);
/* Same, from a string; `name` is used in messages and `base_dir` resolves relative paths. */
NACRE_API nacre_result nacre_scene_load_json(nacre_context *ctx, const char *json, size_t length,
                                             const char *name, const char *base_dir,
                                             nacre_scene **out, nacre_render_settings *settings);

#ifdef __cplusplus
}
#endif

#endif /* NACRE_PUBLIC_RENDER_H */
