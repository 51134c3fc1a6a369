/*
 * render.h: rendering: the methods, the diffusion solver and source, nacre_render_settings, the
 * timed stages and nacre_render_stats, the renderer (nacre_renderer_render, nacre_render,
 * nacre_renderer_variance); and the loading and saving of scene files (nacre_scene_load_file,
 * nacre_scene_load_json, nacre_scene_save_file, nacre_scene_save_json), here because they read
 * and write nacre_render_settings as the file's "render" block. Part of nacre's public API; the
 * conventions (units, ownership, memory, threading, errors) are in the opening comment of nacre.h.
 */
#ifndef NACRE_PUBLIC_RENDER_H
#define NACRE_PUBLIC_RENDER_H

#include <nacre/core.h>
#include <nacre/image.h>
#include <nacre/scene.h>
#include <nacre/particles.h>

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
    NACRE_METHOD_LAYERED,   /* Francois et al. 2006 subsurface texture mapping: single scattering */
    NACRE_METHOD_PATHTRACE, /* reference volumetric path tracer (Embree; see nacre render --help) */
    NACRE_METHOD_COUNT
} nacre_method;

/* "phong", "diffusion", "layered", "pathtrace". */
NACRE_API const char *nacre_method_name(nacre_method method);
/* Parse a method name; false if unknown. */
NACRE_API bool nacre_method_from_name(const char *name, nacre_method *out);
/* Whether this build implements the method. */
NACRE_API bool nacre_method_available(nacre_method method);

/* What a method is and does, for front ends that list methods or adapt their panels. */
typedef struct nacre_method_info {
    const char *name;       /* as nacre_method_name */
    bool available;         /* as nacre_method_available */
    bool needs_objects;     /* false: a scene of fog alone renders (the path tracer) */
    bool stochastic;        /* reads nacre_render_settings.pathtrace (samples, seed, variance) */
    bool renders_fog;       /* the scene's fog is part of its image; other methods ignore fog */
    uint32_t stages;        /* bit (1u << stage) for each nacre_stage the method may run */
} nacre_method_info;

/* Fill *out for a method; false (and *out untouched) for an unknown one. */
NACRE_API bool nacre_method_info_get(nacre_method method, nacre_method_info *out);

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

/* Shadow maps of the rasterizing methods (phong, diffusion). */
typedef struct nacre_shadow_settings {
    int32_t map_size;         /* texels per side, default 2048; 0 disables shadows */
    float pcf_radius;         /* PCF kernel radius in shadow texels, default 1.5 */
    float bias;               /* depth bias in shadow texels, default 1.5 */
} nacre_shadow_settings;

/* The diffusion method's first order at pixel resolution (docs/accuracy.md, "Single scattering
 * per pixel"): ON marches each pixel's refracted view ray for the light scattered once and solves
 * the diffusion from the sources of orders >= 2; OFF lets the diffusion stand for every order;
 * AUTO (the default) is ON for objects whose medium varies in space (a pattern: the first orders
 * carry detail finer than the diffusion length) and OFF for homogeneous ones (the march adds no
 * detail there and costs about 1.6x the frame). OFF and ON keep the values of the former bool. */
typedef enum nacre_single_scattering {
    NACRE_SINGLE_SCATTERING_OFF = 0,
    NACRE_SINGLE_SCATTERING_ON = 1,
    NACRE_SINGLE_SCATTERING_AUTO = 2
} nacre_single_scattering;

/* "off", "on", "auto"; false if unknown. */
NACRE_API const char *nacre_single_scattering_name(nacre_single_scattering mode);
NACRE_API bool nacre_single_scattering_from_name(const char *name, nacre_single_scattering *out);

/* The diffusion method (Blanchard 2012). */
typedef struct nacre_diffusion_settings {
    uint32_t voxel_resolution;       /* voxels along the longest axis of each translucent object, default 32 */
    int32_t tsm_size;                /* translucent shadow map: most texels per side, default 512; each map
                                        uses 4 texels per voxel side of the object's voxels (fewer on
                                        coarse grids), at most tsm_size */
    nacre_diffusion_solver solver;   /* default MULTIGRID */
    nacre_diffusion_source source;   /* default VOLUME */
    float tolerance;                 /* MULTIGRID: relative residual, default 1e-4 */
    uint32_t seed_iterations;        /* SEED: Jacobi sweeps per level, 0 = the seed's table 5.6 count */
    nacre_single_scattering single_scattering; /* default AUTO; ON needs volume sources (AUTO
                                        is OFF with face sources) */
} nacre_diffusion_settings;

/* How the layered method integrates single scattering along each refracted view ray. */
typedef enum nacre_layered_integration {
    NACRE_LAYERED_ANALYTIC = 0, /* samples steps, each cut at the layer boundaries it crosses; each
                                   piece of constant coefficients integrated in closed form */
    NACRE_LAYERED_SAMPLES       /* the seed's ray marching: one point sample per step */
} nacre_layered_integration;

/* "analytic", "samples"; false if unknown. */
NACRE_API const char *nacre_layered_integration_name(nacre_layered_integration integration);
NACRE_API bool nacre_layered_integration_from_name(const char *name, nacre_layered_integration *out);

/* The layered method (Francois et al. 2006). */
typedef struct nacre_layered_settings {
    uint32_t samples;                      /* steps along each view ray, 1..4096, default 16 */
    float epsilon;                         /* negligible attenuation, in (0, 1), default 0.01: the
                                              radius -log(eps) / sigma_t of the fitted planes and
                                              the depth where marching stops */
    nacre_layered_integration integration; /* default ANALYTIC */
    float half_res;                        /* 0: every pixel is marched; in (0, 1) (default 0.05):
                                              pixels of even x and y are, and a pixel between them
                                              takes their mean where they show its object at a close
                                              depth and normal and their radiances differ by at most
                                              half_res times the mean (else it is marched too) */
} nacre_layered_settings;

/* The path tracer. */
typedef struct nacre_pathtrace_settings {
    uint32_t spp;                    /* samples per pixel this frame adds, default 64 */
    uint32_t seed;                   /* same seed, same image; default 1 */
    double time_limit;               /* seconds from the start of the render call; 0 = none.
                                        Stops within a pass, see nacre_render_stats */
    uint32_t max_scatter;            /* scattering events per path in media; 0 = unlimited */
    /* Progressive rendering (a viewer): true adds this frame's spp samples to those of the
     * renderer's previous path-traced frames, as long as nothing changed since: the same scene,
     * no edit committed, the same size, seed and max_scatter. Anything else starts again from
     * zero. N frames of k spp give exactly the image of one frame of N k spp. Default false:
     * every frame starts from zero. */
    bool accumulate;
} nacre_pathtrace_settings;

/* Volumetric fog over the rasterizing methods (phong, diffusion; Hubert 2020, seed 003 §2.3).
 * The path tracer renders fog itself and ignores these. docs/scene-format.md "Volumetrics". */
typedef enum nacre_volumetrics_mode {
    NACRE_VOLUMETRICS_OFF = 0, /* the analytic fog pass (§2.1): directional lights and ambient,
                                  unshadowed, patterns by their mean (the default) */
    NACRE_VOLUMETRICS_FROXEL,  /* a frustum-aligned grid (§2.3.2): every fog per froxel, every light
                                  with shadow maps and the fog's own shadow, integrated per column */
    NACRE_VOLUMETRICS_RAYMARCH /* the same lighting marched along each pixel's ray (§2.3.1) */
} nacre_volumetrics_mode;

/* "off", "froxel", "raymarch"; from_name returns false if unknown. */
NACRE_API const char *nacre_volumetrics_name(nacre_volumetrics_mode mode);
NACRE_API bool nacre_volumetrics_from_name(const char *name, nacre_volumetrics_mode *out);

typedef struct nacre_volumetrics_settings {
    nacre_volumetrics_mode mode; /* default OFF */
    uint32_t froxel_width;       /* froxel columns across the image, default 160 (1..1024) */
    uint32_t froxel_height;      /* froxel rows, default 90 (1..1024) */
    uint32_t froxel_slices;      /* depth slices, exponentially spaced, default 64 (1..1024) */
    uint32_t raymarch_steps;     /* RAYMARCH: steps along each pixel's ray, default 64 (1..4096) */
    uint32_t shadow_steps;       /* steps of the march towards a light through patterned fog
                                    (homogeneous and height fog are integrated in closed form),
                                    default 8 (1..256) */
    float temporal;              /* FROXEL: temporal reprojection, the previous frame's weight in
                                    [0, 1) (0, the default: off; 0.9 typical for a viewer). Each
                                    frame samples the slices at a jittered depth and blends the
                                    lit froxels with the previous frame's, reprojected through
                                    the previous camera (docs/scene-format.md "Volumetrics") */
} nacre_volumetrics_settings;

typedef struct nacre_render_settings {
    nacre_method method;
    int32_t width, height;    /* default 640 x 480; 1..16384 each, at most 2^26 pixels */
    nacre_shadow_settings shadow;       /* phong, diffusion */
    nacre_diffusion_settings diffusion; /* diffusion */
    nacre_pathtrace_settings pathtrace; /* pathtrace */
    nacre_layered_settings layered;     /* layered */
    /* Raster methods (phong, diffusion): true promises that `out` holds, unchanged, the image this
     * renderer wrote in its previous frame (same pixels, size and stride), as in a viewer that
     * shows each frame and passes the buffer back. Pixels that were background then and still are
     * hold the environment already and are not rewritten (on a 1280x720 frame mostly background,
     * ~0.6 ms of memory writes); the image is identical to a full repaint. The renderer repaints
     * everything when the buffer, its size, the environment or the method differ from its last
     * frame. Default false. */
    bool reuse_output;
    nacre_particles_draw particles; /* phong, diffusion: how particles are drawn (particles.h) */
    nacre_volumetrics_settings volumetrics; /* phong, diffusion: how fog is drawn */
} nacre_render_settings;

NACRE_API nacre_render_settings nacre_render_settings_defaults(void);

/* Stages of a frame, in the order they run. A stage that did not run (its inputs unchanged
 * since the renderer's previous frame, or not part of the method) reports 0 us, ran = false and
 * 0 runs. What invalidates what:
 *   setup      every frame (draw lists of the committed scene)
 *   raster, gbuffer   camera, geometry (meshes, objects, transforms, deformer time), image size
 *   shadow     per light: that light, geometry, shadow settings
 *   voxelize   per translucent object: geometry, voxel_resolution
 *   medium     per translucent object: voxelize, materials (coefficients per voxel)
 *   tsm, inject   per translucent object: medium, lights, diffusion and shadow settings
 *   propagate  per translucent object: inject (the solve; also its setup after medium)
 *   shade      every frame
 *   fog        every frame of a raster method when the scene has fog (the post pass over the
 *              image and depth: distance and height fog, see docs/scene-format.md "fog")
 *   planes     layered, per translucent object: geometry, materials, layered.epsilon (the
 *              least-squares planes and uv gradients of seed 001 section 2.2)
 *   march      layered: every frame (single scattering along each translucent pixel's view ray;
 *              runs before shade, which adds the surface layer)
 *   particles  every frame of a raster method with particles alive, drawn as billboards or
 *              sprites (the post pass of nacre_render_settings.particles)
 *   froxel_fill, froxel_light, froxel_integrate, froxel_apply   instead of fog with
 *              volumetrics FROXEL: fogs sampled per froxel, lit, integrated per column, applied
 *   raymarch   instead of fog with volumetrics RAYMARCH: the per-pixel march
 * The path tracer runs none of these; its frames restart or accumulate (pathtrace.accumulate). */
#define NACRE_STAGE_LIST(X)                                                                    \
    X(NACRE_STAGE_SETUP, "setup")                                                              \
    X(NACRE_STAGE_RASTER, "raster")                                                            \
    X(NACRE_STAGE_GBUFFER, "gbuffer")                                                          \
    X(NACRE_STAGE_SHADOW, "shadow")                                                            \
    X(NACRE_STAGE_VOXELIZE, "voxelize")                                                        \
    X(NACRE_STAGE_MEDIUM, "medium")                                                            \
    X(NACRE_STAGE_TSM, "tsm")                                                                  \
    X(NACRE_STAGE_INJECT, "inject")                                                            \
    X(NACRE_STAGE_PROPAGATE, "propagate")                                                      \
    X(NACRE_STAGE_SHADE, "shade")                                                              \
    X(NACRE_STAGE_FOG, "fog")                                                                  \
    X(NACRE_STAGE_PLANES, "planes")                                                            \
    X(NACRE_STAGE_MARCH, "march")                                                              \
    X(NACRE_STAGE_PARTICLES, "particles")                                                      \
    X(NACRE_STAGE_FROXEL_FILL, "froxel_fill")                                                  \
    X(NACRE_STAGE_FROXEL_LIGHT, "froxel_light")                                                \
    X(NACRE_STAGE_FROXEL_INTEGRATE, "froxel_integrate")                                        \
    X(NACRE_STAGE_FROXEL_APPLY, "froxel_apply")                                                \
    X(NACRE_STAGE_RAYMARCH, "raymarch")

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
    /* How many times each stage ran this frame: shadow maps drawn, objects voxelized, ... (1 for
     * the per-frame stages that ran). */
    uint32_t stage_runs[NACRE_STAGE_COUNT];
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
    uint32_t spp_done;           /* samples per pixel in the image, every pixel (the minimum);
                                    with accumulate, over the frames accumulated */
    double samples_per_second;   /* camera paths per second this frame */
    uint64_t samples_done;       /* camera paths completed this frame, over all pixels (with a time
                                    limit, pixel counts may differ; each pixel is the mean of its own) */
    uint64_t paths_capped;       /* paths ended by the path-length or collision cap (README) */
    uint32_t pixels_unsampled;   /* time limit reached within the first pass: pixels without a
                                    sample, filled with their 8x8 block's mean (0 if none) */
    bool accumulated;            /* this frame added to the previous frames' samples */
    /* fog post pass (methods that do not render fog themselves; docs/scene-format.md "fog") */
    uint32_t fog_lights_ignored; /* lights that add no light to the fog: with volumetrics OFF the
                                    point and spot lights; with FROXEL or RAYMARCH none (0) */
    uint32_t fog_patterns_averaged; /* patterned fogs drawn with their mean coefficients */
} nacre_render_stats;

/* A renderer lives across frames: it keeps each stage's results and recomputes only the stages
 * whose inputs changed since its last frame of the same scene (see NACRE_STAGE_LIST): a camera
 * move re-rasterizes and re-shades; a light edit redraws that light's shadow map and reruns the
 * diffusion's translucent shadow maps, injection and propagation; a material edit reruns the
 * diffusion from its medium stage; geometry or a new commit time reruns everything. The stats
 * say which stages ran. One renderer per thread; the scene is the caller's and may change
 * between frames (commit before each frame). */
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

/* The depth of the last frame (1 channel): per pixel, the distance from the camera along its
 * viewing axis to the nearest surface at the pixel's centre, in scene units; +infinity where no
 * surface is. This is the depth the post passes compose with. Rasterizing methods always have
 * it; after a path-traced frame it exists only when a post pass asked for it (else
 * INVALID_OPERATION, as before any frame). Same allocation rule as nacre_renderer_render. */
NACRE_API nacre_result nacre_renderer_depth(const nacre_renderer *renderer, nacre_image *out);

/* Which object covers pixel (x, y) (0,0 = top left) of the renderer's last frame, from the
 * rasterizing methods' G-buffer (the object at the pixel's centre): *object_index is the object's
 * index (its nacre_object id - 1), or UINT32_MAX where no object is (background). INVALID_OPERATION
 * when the last frame was not rasterized (none yet, or path traced); INVALID_ARGUMENT outside
 * the frame. For a viewer's click-to-select. */
NACRE_API nacre_result nacre_renderer_pick(const nacre_renderer *renderer, int32_t x, int32_t y,
                                           uint32_t *object_index);

/* ------------------------------------------------------------------------------------------ */
/* Scene files (JSON; format in docs/scene-format.md)                                         */
/* ------------------------------------------------------------------------------------------ */

/* What a scene file's "render" block says besides the scene: the render settings, and two
 * values for the caller, who commits the scene and writes the image. */
typedef struct nacre_scene_file_settings {
    nacre_render_settings render;
    double time;              /* "time": seconds to commit the scene at (deformers), default 0 */
    float exposure;           /* "exposure": EV stops for PNG output (nacre_image_write_options) */
} nacre_scene_file_settings;

/* Load a scene file: builds the scene (not yet committed) and fills `settings` from its "render"
 * block (defaults otherwise); settings may be NULL. Paths inside are relative to the file.
 * Errors name the file and the field path, or line and column for malformed JSON. */
NACRE_API nacre_result nacre_scene_load_file(nacre_context *ctx, const char *path,
                                             nacre_scene **out, nacre_scene_file_settings *settings);
/* Same, from a string; `name` is used in messages and `base_dir` resolves relative paths. */
NACRE_API nacre_result nacre_scene_load_json(nacre_context *ctx, const char *json, size_t length,
                                             const char *name, const char *base_dir,
                                             nacre_scene **out, nacre_scene_file_settings *settings);

/* Save a scene's current state (edits included) as a scene file that nacre_scene_load_file reads
 * back to the same descs, bit for bit: units, the "render" block from `settings` (NULL: the
 * defaults, time 0, exposure 0; accumulate and reuse_output are not part of the format), camera,
 * environment, every material, lights, objects and fogs. Meshes, depth and diffuse maps and
 * volumes loaded from files are referred to by path (relative to the scene file's folder when
 * they lie in it or below, else absolute), shapes by their desc; those built from raw arrays
 * through this API are written beside the scene file as <name>_mesh<id>.ply,
 * <name>_depth<id>.exr, <name>_texture<id>.exr (diffuse maps) and <name>_volume<id>.nrrd
 * (lossless). Materials keep the names of their scene file; others are
 * named "material<id>". Every file is written under a temporary name and renamed; on failure no
 * file of this save is left behind. Refuses to write over a file the scene reads
 * (nacre_scene_input_path, and the sources above), and values the format cannot express (a
 * negative object scale, an opaque colour above 1: scene files take [0, 1]) with a message naming
 * the field. Details: docs/scene-format.md, "Saving a scene". */
NACRE_API nacre_result nacre_scene_save_file(const nacre_scene *scene,
                                             const nacre_scene_file_settings *settings,
                                             const char *path);
/* Same, into a string: *json_out is allocated through the scene's context (free with nacre_free),
 * *length_out (may be NULL) is its length without the terminating NUL. Paths are relative to
 * `base_dir` (NULL: the working directory), where generated files are written, named
 * scene_mesh<id>.ply and so on. */
NACRE_API nacre_result nacre_scene_save_json(const nacre_scene *scene,
                                             const nacre_scene_file_settings *settings,
                                             const char *base_dir, char **json_out,
                                             size_t *length_out);

/* ------------------------------------------------------------------------------------------ */
/* glTF 2.0 scenes (.gltf, .glb; the mapping is in docs/scene-format.md, "glTF 2.0 scenes")   */
/* ------------------------------------------------------------------------------------------ */

#define NACRE_GLTF_REPORT_MAX 64 /* names kept per list of nacre_gltf_report */
#define NACRE_GLTF_NAME_MAX 64   /* bytes per name, NUL included; longer names are cut */

typedef struct nacre_gltf_options {
    const char *camera;  /* camera to use, by the name of its camera or its node; NULL: the first */
    float unit_mm;       /* millimetres per scene unit to import into; 0: metres (glTF's own) */
    bool skip_lights;    /* add none of the file's lights */
    bool skip_camera;    /* leave the scene's camera alone */
    bool thickness_layer; /* a translucent material's KHR_materials_volume thickness texture
                             becomes a one-layer depth map (docs/scene-format.md); default: not
                             read, the medium fills the mesh as glTF defines it */
} nacre_gltf_options;

/* What an import mapped. Extension names are those the file lists in extensionsUsed. */
typedef struct nacre_gltf_report {
    uint32_t meshes, primitives;     /* in the file */
    uint32_t objects;                /* added: one per mesh instance (node x primitive) */
    uint32_t lights, cameras;        /* lights added; cameras in the file */
    uint32_t material_count;         /* materials added (the file's, plus a default if needed) */
    uint32_t first_material;         /* id of the first of them in the scene */
    char materials[NACRE_GLTF_REPORT_MAX][NACRE_GLTF_NAME_MAX];
    bool translucent[NACRE_GLTF_REPORT_MAX];
    uint32_t mapped_count, ignored_count;
    char mapped[NACRE_GLTF_REPORT_MAX][NACRE_GLTF_NAME_MAX];
    char ignored[NACRE_GLTF_REPORT_MAX][NACRE_GLTF_NAME_MAX];
} nacre_gltf_report;

/* Load a glTF 2.0 file (.gltf with its buffers, or .glb) as a scene in metres (or
 * options->unit_mm): meshes through assimp with their node transforms applied, materials,
 * KHR_lights_punctual lights, the chosen camera. settings get the defaults. options and report
 * may be NULL. An extension the file requires (extensionsRequired) that nacre does not map fails
 * with UNSUPPORTED; used but unknown ones are listed in report->ignored (the caller warns).
 * nacre_scene_load_file calls this for paths ending in .gltf or .glb. */
NACRE_API nacre_result nacre_scene_load_gltf(nacre_context *ctx, const char *path,
                                             const nacre_gltf_options *options, nacre_scene **out,
                                             nacre_scene_file_settings *settings,
                                             nacre_gltf_report *report);

#ifdef __cplusplus
}
#endif

#endif /* NACRE_PUBLIC_RENDER_H */
