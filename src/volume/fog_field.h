/*
 * fog_field.h: the scene's fogs as a field sampled at world points, for the volumetric passes
 * (render/post_volumetrics.c: froxels and the per-pixel march; Hubert 2020, seed 003 §2.3).
 * Every fog is evaluated where it is (global or box, height falloff, pattern at the point: not
 * its mean), and the optical depth from a point towards a light is integrated through every fog
 * (§2.2.3, the fog's shadow on itself): in closed form for fogs without pattern (Beer-Lambert
 * times the height-fog integral of volume.h, over the part of the segment inside the box), by a
 * march of `shadow_steps` steps through patterned fogs (each step's pattern at its midpoint times
 * the closed-form height integral over the step, so a constant pattern is exact at any count).
 *
 * Emission (radiance per unit length) is a separate field (nc_fog_field_emission): the source
 * term added to sigma_s L in each step's segment integral (§1.2.11).
 *
 * The coefficients are those the path tracer tracks (same density cap). Translucent objects do
 * not displace the fog here (the path tracer's fog stops inside them).
 *
 * Units: world scene units, unit directions; coefficients per scene unit, per channel.
 */
#ifndef NACRE_VOLUME_FOG_FIELD_H
#define NACRE_VOLUME_FOG_FIELD_H

#include "scene/scene.h"
#include "volume/volume.h"

typedef struct nc_fog_one {
    bool box, patterned;                 /* box: bounded (a box, or an ellipsoid if `ellipsoid`) */
    bool ellipsoid;
    float w2l[3][4];                     /* world -> local (rotation, translation) */
    float half[3];                       /* box: half edges (ellipsoid: semi-axes) */
    nc_vol_height h;                     /* height profile (double, closed forms) */
    float hf_falloff, hf_base, hf_cap;   /* the same in float, for point factors */
    bool height;
    float sigma_a[3], sigma_s[3];        /* where the height factor is 1 (pattern: medium 1) */
    float g;
    const nacre_material_desc *medium;   /* pattern source (the scene's, borrowed) */
    bool emissive, emission_patterned;
    float emission[3];                   /* where the height factor is 1 (pattern: medium 1) */
    const nacre_material_desc *emission_medium; /* emission as sigma_a (nc_fog_rec.emission) */
} nc_fog_one;

typedef struct nc_fog_field {
    const nacre_scene *scene;
    uint32_t count;
    nc_fog_one fogs[NACRE_MAX_FOGS];
    float bounds_min[3], bounds_max[3]; /* committed scene bounds: a global pattern is marched in them */
    uint32_t shadow_steps;
    bool emissive; /* some fog emits */
} nc_fog_field;

/* Floats of scratch that nc_fog_field_eval needs for n points (arrays of n rounded up to 8,
 * nc_fog_field_eval's), and nc_fog_field_optical_depth. */
#define NC_FOG_EVAL_SCRATCH(n) (20u * (((size_t)(n) + 7) & ~(size_t)7))
#define NC_FOG_TAU_SCRATCH(steps) (9u * (size_t)(steps))

/* The scene's first `count` fogs (nc_post_fogs_drawn: particle grids may be left out). */
void nc_fog_field_init(nc_fog_field *f, const nacre_scene *s, uint32_t count, uint32_t shadow_steps);

/* sigma_t and sigma_s (3 per point) and the sigma_s-weighted Henyey-Greenstein g (1 per point)
 * of all fogs at n world points (3 floats each). */
void nc_fog_field_eval(const nc_fog_field *f, uint32_t n, const float *p, float *sigma_t, float *sigma_s, float *g,
                       float *scratch);

/* Emission (radiance per unit length, 3 per point) of all fogs at n world points, as the
 * scene format defines it (height factor, pattern with a clear medium 2); zeros when no fog
 * emits. Scratch: NC_FOG_EVAL_SCRATCH(n). */
void nc_fog_field_emission(const nc_fog_field *f, uint32_t n, const float *p, float *emission, float *scratch);

/* One fog's emission at world point p where its height factor is 1 (its pattern at p; p is not
 * tested against its shape), for closed-form tails that integrate the height factor. */
void nc_fog_one_emission(const nc_fog_field *f, const nc_fog_one *o, const float p[3], float emission[3]);

/* Which fogs nc_fog_field_optical_depth integrates. */
#define NC_FOG_ANALYTIC 1u  /* fogs without pattern (closed form) */
#define NC_FOG_PATTERNED 2u /* patterned fogs (marched) */
#define NC_FOG_ALL 3u
#define NC_FOG_BOXES 4u /* with the above: only the box-shaped ones of those */

/* Optical depth per channel of the fogs of `which` along p + t w, t in [0, tmax] (tmax may be
 * INFINITY; the result may be INFINITY: a global fog without falloff towards a directional
 * light). */
void nc_fog_field_optical_depth(const nc_fog_field *f, const float p[3], const float w[3], float tmax, unsigned which,
                                double tau[3], float *scratch);
/* Fog o's optical depth along p + t w, t in [0, tmax], added to tau (nc_fog_field_optical_depth's
 * term of one fog). */
void nc_fog_one_optical_depth(const nc_fog_field *f, const nc_fog_one *o, const float p[3], const float w[3],
                              float tmax, double tau[3], float *scratch);
/* Whether any fog has a pattern. */
bool nc_fog_field_patterned(const nc_fog_field *f);

/* Ray [t0, t1] inside fog i's box or ellipsoid (global: [t0, t1] itself); false if empty. */
bool nc_fog_field_segment(const nc_fog_one *fog, const float o[3], const float d[3], double *t0, double *t1);

#endif /* NACRE_VOLUME_FOG_FIELD_H */
