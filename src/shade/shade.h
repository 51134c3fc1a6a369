/*
 * shade.h: deferred shading passes that turn a G-buffer into radiance (private API).
 * Every render method shares the G-buffer of src/raster; each method adds its own pass here.
 */
#ifndef NACRE_SHADE_H
#define NACRE_SHADE_H

#include "raster/raster.h"
#include "scene/scene.h"

/* Lights resolved for shading: one per scene light, with its shadow map (NULL = unshadowed). */
typedef struct nc_shade_light {
    const nacre_light_desc *desc;
    const nc_shadow_map *shadow;
} nc_shade_light;

/* Pixels shaded together: a run of one row's pixels with the same object and material, at
 * most NC_SHADE_BATCH long, held as SoA arrays so that the per-pixel arithmetic vectorizes.
 * Lanes from count up to the next multiple of 8 hold finite values (position and normal 0), so
 * that kernels working on groups of 8 lanes read no garbage there; their results are unused. */
#define NC_SHADE_BATCH 64

typedef struct nc_shade_batch {
    uint32_t count;                     /* pixels in use, 1..NC_SHADE_BATCH */
    size_t first;                       /* G-buffer index of lane 0 (lanes are consecutive pixels) */
    float px[NC_SHADE_BATCH], py[NC_SHADE_BATCH], pz[NC_SHADE_BATCH]; /* world position */
    float nx[NC_SHADE_BATCH], ny[NC_SHADE_BATCH], nz[NC_SHADE_BATCH]; /* unit shading normal */
    float vx[NC_SHADE_BATCH], vy[NC_SHADE_BATCH], vz[NC_SHADE_BATCH]; /* unit direction to the eye */
} nc_shade_batch;

typedef struct nc_shade_params {
    nc_vec3 eye;             /* camera position (perspective) */
    nc_vec3 view_dir;        /* camera forward direction (orthographic: every view ray) */
    bool orthographic;
    float pcf_radius, shadow_bias;
    /* Optional hook of the diffusion method: pixels of objects with subsurface_object[object]
     * nonzero get subsurface() (the radiance leaving the medium towards v) instead of the
     * Lambert direct term; ambient and specular stay as for any object. NULL: plain phong.
     * It shades one batch of pixels of `object` into out[channel][pixel]. Called from several
     * threads at once (read only). */
    const uint8_t *subsurface_object;
    void (*subsurface)(const void *user, uint32_t object, const nc_shade_batch *batch,
                       float out[3][NC_SHADE_BATCH]);
    const void *subsurface_user;
} nc_shade_params;

/* Effective Lambert albedo the phong method uses for a material: the diffuse colour of an
 * opaque material; for a translucent one, its total diffuse reflectance from the classical
 * diffusion dipole (Jensen et al. 2001, eq. for Rd), per channel. */
void nc_material_albedo(const nacre_material_desc *m, float out[3]);

/* Ambient + Lambert + normalized Blinn-Phong with shadow maps, into rgb (width*height*3, row
 * stride `stride` floats). Empty pixels get the environment radiance, except that with
 * prev_span (2 per row, the G-buffer's row_span of the frame rgb already holds, whose other
 * pixels are the same environment) the empty pixels outside the previous frame's span are left
 * as they are. prev_span NULL: every pixel is written. */
void nc_shade_phong(const nacre_scene *scene, const nc_gbuffer *gb, const nc_shade_light *lights,
                    uint32_t light_count, const nc_shade_params *params, float *rgb, size_t stride,
                    const int32_t *prev_span, int threads);

#endif /* NACRE_SHADE_H */
