/*
 * view.h: the state of `nacre view` and the edits every input goes through. The mouse, the keys,
 * the panel (panel.cpp, Dear ImGui) and the headless script (script.c) all call the nc_view_*
 * functions below, so a scripted run exercises the same code as a person at the window. The
 * viewer keeps one scene and one renderer for its whole life: an edit changes a desc in the
 * scene and marks it for commit; the library's renderer decides which stages rerun.
 *
 * C interface on purpose: panel.cpp (the only C++) includes it.
 */
#ifndef NACRE_VIEW_H
#define NACRE_VIEW_H

#include <nacre/nacre.h>

#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* What the window shows. */
typedef enum nc_view_mode {
    NC_VIEW_NORMAL = 0, /* the current method */
    NC_VIEW_WIPE,       /* left of the wipe line: the current method; right: the path tracer */
    NC_VIEW_ERROR       /* false-colour relative error of the current method against the path tracer */
} nc_view_mode;

/* Per material: the desc before the scales (as loaded or as the chosen preset). */
typedef struct nc_view_material {
    nacre_material_desc base;
    float sigma_a_scale, sigma_s_scale;
    int preset; /* index in nc_view_presets, -1: as loaded */
    float layer_depth_loaded[NACRE_MAX_LAYERS]; /* as loaded or as the preset: the panel's range */
} nc_view_material;

typedef struct nc_view {
    nacre_context *ctx;
    nacre_scene *scene;
    nacre_renderer *renderer;     /* the current method; lives as long as the viewer */
    nacre_renderer *truth;        /* the progressive path tracer of the wipe and error views */
    nacre_scene_file_settings fs; /* render settings (fs.render is the current ones), time, exposure */
    nacre_image frame, truth_frame;
    bool frame_valid, truth_valid;
    nacre_render_stats stats, truth_stats;
    uint32_t pathtrace_spp;       /* samples per pixel each path-traced frame adds */

    /* Camera: orbit about the target, kept as angles so that orbiting does not drift. */
    nacre_camera_desc camera, camera_home;
    float yaw, pitch, distance; /* degrees, degrees, scene units */

    nc_view_material *materials;
    uint32_t material_count;
    uint32_t light, material, object; /* selected (indices; object UINT32_MAX: none) */

    double time_max;
    bool playing;
    double fixed_step;       /* > 0: seconds the timeline advances per frame (headless runs) */

    nc_view_mode mode;
    float wipe;              /* wipe line, fraction of the width from the left */
    double mean_rel_err;     /* of the current method against the truth; < 0: not known */

    /* Interactive light edits (on unless --exact): a frame in which a light moved solves the
     * diffusion only to a relative residual of NC_VIEW_LIGHT_TOLERANCE (when the scene asks for
     * less); once no light has moved for NC_VIEW_REFINE_FRAMES frames, or before an image is
     * saved, the frame is rendered again at the scene's settings (README, `nacre view`). */
    bool interactive;
    bool light_moved;        /* a light edit since the last frame */
    bool refine_due;         /* the last frame was rendered with the interactive tolerance */
    uint32_t still_frames;   /* frames since the last light edit */

    bool dirty;              /* an edit since the last commit */
    bool need_render;        /* something changed since the last frame (edit, size, method, view) */
    char message[256];       /* the last problem or note, shown in the panel */

    /* Accounting for the headless JSON line and the panel. */
    uint64_t frames, rendered;
    uint64_t stage_us[NACRE_STAGE_COUNT];
    uint64_t stage_runs[NACRE_STAGE_COUNT];
    double fps;              /* smoothed, of rendered frames */
} nc_view;

/* The interactive light edits' solver tolerance, and the frames without a light edit after
 * which the frame is refined (see nc_view.interactive). */
#define NC_VIEW_LIGHT_TOLERANCE 1e-3f
#define NC_VIEW_REFINE_FRAMES 2

/* Material presets offered by the panel and the script, NULL-terminated. */
extern const char *const nc_view_presets[];

/* Set up from a loaded scene (ownership of scene moves to the view) with its file settings;
 * false with v->message set on failure. */
bool nc_view_init(nc_view *v, nacre_context *ctx, nacre_scene *scene, const nacre_scene_file_settings *fs);
void nc_view_free(nc_view *v);

/* Edits. Each returns false and sets v->message when the edit is refused (the state is kept).
 * With check_only the edit is only validated (script checking before the window opens). */
void nc_view_orbit(nc_view *v, float dyaw, float dpitch);
void nc_view_pan(nc_view *v, float dx_pixels, float dy_pixels);
void nc_view_zoom(nc_view *v, float factor);
void nc_view_camera_home(nc_view *v);
bool nc_view_set_method(nc_view *v, nacre_method method, bool check_only);
bool nc_view_light_direction(nc_view *v, uint32_t light, const float d[3], bool check_only);
bool nc_view_light_position(nc_view *v, uint32_t light, const float p[3], bool check_only);
bool nc_view_light_strength(nc_view *v, uint32_t light, const float s[3], bool check_only);
/* Turn the selected light: directional and spot lights rotate about the world y axis (yaw) and
 * tilt (pitch), in degrees; point lights move around the scene centre the same way. */
bool nc_view_light_turn(nc_view *v, float dyaw, float dpitch);
bool nc_view_material_preset(nc_view *v, uint32_t material, const char *preset, bool check_only);
/* field: "sigma_a_scale", "sigma_s_scale", "g", "eta". */
bool nc_view_material_field(nc_view *v, uint32_t material, const char *field, float value, bool check_only);
bool nc_view_voxel_resolution(nc_view *v, uint32_t res, bool check_only);
bool nc_view_solver(nc_view *v, nacre_diffusion_solver solver);
/* Render settings of the layered method, the volumetric fog and the particles, by the names of
 * the scene file's render block (docs/scene-format.md): layered_samples, layered_epsilon,
 * layered_integration, volumetrics, froxel_width, froxel_height, froxel_slices, raymarch_steps,
 * shadow_steps, froxel_temporal, particles. `value` is the text as in a script ("froxel", "8", "0.01"); the same
 * ranges as the scene loader. */
bool nc_view_render_setting(nc_view *v, const char *name, const char *value, bool check_only);
void nc_view_set_time(nc_view *v, double time);
void nc_view_set_mode(nc_view *v, nc_view_mode mode);
bool nc_view_resize(nc_view *v, int32_t width, int32_t height, bool check_only);
/* Select the light whose handle is at pixel (x, y), else the object under it (and its
 * material); false if the frame was not rasterized. */
bool nc_view_pick(nc_view *v, int32_t x, int32_t y);
/* Light handles (the gizmo): a point or spot light's handle is its position; a directional
 * light's is the point 0.25 x the camera distance from the target towards where the light comes
 * from, so dragging it swings the light about the target. nc_view_light_handle_pixel gives the
 * handle's frame pixel (false if it is behind the camera); nc_view_light_at the light whose
 * handle is within NC_VIEW_HANDLE_PX of (x, y), or UINT32_MAX; nc_view_light_drag moves light
 * `light`'s handle to pixel (x, y), keeping its distance from the camera plane. */
#define NC_VIEW_HANDLE_PX 8.0f
bool nc_view_light_handle_pixel(const nc_view *v, uint32_t light, float *x, float *y);
uint32_t nc_view_light_at(const nc_view *v, float x, float y);
bool nc_view_light_drag(nc_view *v, uint32_t light, float x, float y);
/* A left drag in the frame from (x0, y0) to (x1, y1) pixels, as the mouse does it: from a light's
 * handle it moves that light, elsewhere it orbits the camera. */
void nc_view_drag(nc_view *v, float x0, float y0, float x1, float y1);
/* A key as pressed in the window ("1".."4", "p", "t", "e", "n", "left", "right", "up", "down",
 * "[", "]", "r", "space"); false if the key means nothing. */
bool nc_view_key(nc_view *v, const char *key, bool check_only);

/* Advance the timeline by dt seconds if playing (fixed_step instead when set), commit the edits,
 * render what the view needs. false with v->message on a library error (the window stays). */
bool nc_view_frame(nc_view *v, double dt);
/* If the last frame was rendered with the interactive tolerance, render it again at the
 * scene's settings (before an image is saved). */
bool nc_view_refine(nc_view *v);
/* The frame for display: RGBA 8-bit sRGB, width x height of the settings, with the view mode
 * applied; `rgba` has room for width * height * 4 bytes. */
void nc_view_display(nc_view *v, uint8_t *rgba);
/* Write the current method's last frame (not the panel): PNG with the exposure, or EXR. */
bool nc_view_save_image(nc_view *v, const char *path);
/* Write the edited scene, with the current settings and time, as a scene file that
 * `nacre render` reproduces (nacre_scene_save_file). */
bool nc_view_save_scene(nc_view *v, const char *path);

#ifdef __cplusplus
}
#endif

#endif /* NACRE_VIEW_H */
