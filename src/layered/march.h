/*
 * march.h: single scattering below one visible point of a layered translucent material (seed
 * 001, Francois et al. 2006, algorithms 1 and 2), for the layered render method. See march.c.
 */
#ifndef NACRE_LAYERED_MARCH_H
#define NACRE_LAYERED_MARCH_H

#include "layered/layers.h"
#include "shade/shade.h"

/* A material as the march sees it: layers 0..count-1 from the surface in, then the core. */
typedef struct nc_layer_medium {
    uint32_t count;
    float st[NACRE_MAX_LAYERS + 1][3]; /* sigma_t per scene unit */
    float ss[NACRE_MAX_LAYERS + 1][3]; /* sigma_s per scene unit */
    float g[NACRE_MAX_LAYERS + 1];
    float eta;                         /* n inside / n outside */
    float depth_max;                   /* Depth_max of eq. 15: optical depth -log(eps) for every channel */
    nc_layer_stack stack;
} nc_layer_medium;

/* Resolve a translucent material (its pattern is replaced by its first medium). */
void nc_layer_medium_init(const nacre_scene *scene, const nacre_material_desc *m, float epsilon,
                          nc_layer_medium *out);
/* The smallest sigma_t of the first medium below the surface (eq. 7): the planes' radius is
 * -log(eps) over it. */
float nc_layer_medium_first_sigma_t(const nc_layer_medium *m);

/* One visible point: everything in world space. */
typedef struct nc_march_point {
    float p[3];      /* P */
    float n[3];      /* unit shading normal at P, outwards (on the viewer's side) */
    float ns[3];     /* unit normal of the interpolated fitted plane (N_SP) */
    float ps[3];     /* a point of that plane */
    float v[3];      /* unit direction from P to the eye */
    float uv[2];     /* texture coordinates of P */
    float gu[3], gv[3]; /* world gradients of u and v at P (0 without uvs) */
} nc_march_point;

typedef struct nc_march_params {
    uint32_t samples;
    bool analytic;
    float pcf_radius, shadow_bias;
} nc_march_params;

/* Radiance leaving P towards the eye from light scattered once below the surface (Fresnel at
 * entry and exit included), summed over the lights, into rgb[3]. Thread-safe. */
void nc_layered_radiance(const nc_layer_medium *m, const nc_march_point *pt, const nc_shade_light *lights,
                         uint32_t light_count, const nc_march_params *prm, float rgb[3]);

/* The part of nc_layered_radiance that no light changes: the refracted view ray, its pieces of
 * constant layer (the boundary search) and the depth map's layer bottoms at the points where the
 * lights are evaluated. A renderer keeps one per pixel while the camera, the geometry, the
 * materials and the march settings hold, and lights it again each frame
 * (nc_march_ray_radiance), with the same result as nc_layered_radiance. A ray lives in a slot of
 * nc_march_ray_bytes(cap, layers) bytes (16-byte aligned): this header, then cap point
 * positions, `layers` x cap bottoms and cap layer indices. */
typedef struct nc_march_ray {
    nc_march_point pt;
    float d[3], dz, du, dv; /* refracted direction; depth and uv per unit of s along it */
    float len, t_out;       /* |P M_max|; Fresnel transmittance out over eta^2 */
    uint32_t np;            /* pieces */
    uint32_t kind;          /* NC_MARCH_RAY_* */
    uint32_t cap, layers;
} nc_march_ray;

enum {
    NC_MARCH_RAY_DARK = 0, /* no light leaves P towards the eye (seen from behind, total reflection) */
    NC_MARCH_RAY_OK = 1,
    NC_MARCH_RAY_LONG = 2, /* more pieces than the slot holds: use nc_layered_radiance */
};

/* Points a slot needs for these settings (a multiple of 8), 0 when the rays are too long to keep
 * (more than 62 steps). */
uint32_t nc_march_ray_cap(const nc_march_params *prm);
size_t nc_march_ray_bytes(uint32_t cap, uint32_t layers);
/* Make the ray of pt into slot (cap points, layers >= m's layer count); returns its kind. */
uint32_t nc_march_ray_make(const nc_layer_medium *m, const nc_march_point *pt, const nc_march_params *prm,
                           uint32_t cap, uint32_t layers, void *slot);
/* nc_layered_radiance of a ray made by nc_march_ray_make (kind OK or DARK). Thread-safe. */
void nc_march_ray_radiance(const nc_layer_medium *m, const void *slot, const nc_shade_light *lights,
                           uint32_t light_count, const nc_march_params *prm, float rgb[3]);

/* Rays lit together by nc_march_rays_radiance. */
#define NC_MARCH_CHUNK 16
/* nc_march_ray_radiance of n <= NC_MARCH_CHUNK made rays (media[k]: the medium of rays[k]) into
 * rgb[k][0..2], with each light's shadow lookups (2 per ray) made together by nc_shadow_lookup_n:
 * the values are nc_march_ray_radiance's up to that function's float rounding. Thread-safe. */
void nc_march_rays_radiance(const nc_layer_medium *const *media, const void *const *rays, uint32_t n,
                            const nc_shade_light *lights, uint32_t light_count, const nc_march_params *prm,
                            float *const *rgb);

#endif /* NACRE_LAYERED_MARCH_H */
