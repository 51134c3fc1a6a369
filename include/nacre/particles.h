/*
 * particles.h: particle systems as participating media (Hubert 2020, seed 003 chapter 3). A
 * particle is a blob of medium: a centre, a radius R and a peak density d0, with the density
 * profile
 *   d(p) = d0 * exp(-4.5 |p - c|^2 / R^2)   where |p - c| <= R along each axis, 0 outside,
 * a Gaussian of standard deviation R / 3 cut at the cube of half-edge R (separable: the splat
 * costs one product per cell). Its mass (integrated density, scene units^3) is
 *   m = d0 * (K R)^3,  K = sqrt(2 pi) / 3 * erf(3 / sqrt(2)) ~ 0.8333.
 * A system's medium is sigma_a = D(p) * sigma_a, sigma_s = D(p) * sigma_s (per scene unit), with
 * D the sum of its particles' densities and one Henyey-Greenstein g per system.
 *
 * Systems are emitters (particles born at a steady rate from a point, box or sphere, moving
 * under gravity and linear drag, dying after `lifetime`) or static lists. The state at time T
 * is a function of (desc, T) alone: particle k is born at k / rate with random numbers hashed
 * from (seed, k), and moves by the closed-form solution of dv/dt = gravity - drag * v, so any
 * T renders directly and the result does not depend on thread count or on earlier commits.
 *
 * At nacre_scene_commit(scene, T) each system is simulated to T and splatted into a density grid
 * (seed 003 §3.2) that becomes a BOX fog with a VOLUME pattern, so the path tracer renders it
 * exactly and every fog pass reads it. Part of nacre's public API; the conventions (units,
 * ownership, memory, threading, errors) are in the opening comment of nacre.h.
 */
#ifndef NACRE_PUBLIC_PARTICLES_H
#define NACRE_PUBLIC_PARTICLES_H

#include <nacre/core.h>
#include <nacre/scene.h>

#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* At most this many particles alive at once in one system (emitters: rate * lifetime rounded
 * up; lists: count). 2^22 particles take 80 MiB of state. */
#define NACRE_PARTICLES_MAX (1u << 22)
/* Density grid resolution (samples per axis): default and bounds. */
#define NACRE_PARTICLES_GRID_DEFAULT 128u
#define NACRE_PARTICLES_GRID_MIN 8u
#define NACRE_PARTICLES_GRID_MAX 512u

typedef struct { uint32_t id; } nacre_particles;

typedef enum nacre_particles_type {
    NACRE_PARTICLES_EMITTER = 0, /* born at `rate` from the emitter shape */
    NACRE_PARTICLES_LIST         /* `count` fixed particles */
} nacre_particles_type;

typedef enum nacre_emitter_shape {
    NACRE_EMITTER_POINT = 0, /* at `center` */
    NACRE_EMITTER_BOX,       /* uniform in the axis-aligned box `center`, `size` */
    NACRE_EMITTER_SPHERE     /* uniform in the ball `center`, `emit_radius` */
} nacre_emitter_shape;

typedef struct nacre_particles_desc {
    nacre_particles_type type;
    /* EMITTER */
    nacre_emitter_shape shape;
    float center[3];      /* scene units */
    float size[3];        /* BOX: edge lengths, >= 0 */
    float emit_radius;    /* SPHERE: >= 0 */
    float rate;           /* particles per second, > 0; rate * lifetime particles live at once */
    float lifetime;       /* seconds, > 0 */
    float velocity[3];    /* initial velocity, scene units per second */
    float spread;         /* half-angle of the cone of initial directions around `velocity`,
                             degrees in [0, 180] (uniform over the cone's solid angle) */
    float speed_jitter;   /* initial speed |velocity| * (1 + speed_jitter * u), u in [-1, 1];
                             in [0, 1] */
    float gravity[3];     /* acceleration, scene units per second^2 */
    float drag;           /* linear drag, per second, >= 0: dv/dt = gravity - drag * v */
    float radius;         /* R at birth, scene units, > 0 */
    float radius_jitter;  /* R at birth * (1 + radius_jitter * u), u in [-1, 1]; in [0, 1) */
    float radius_rate;    /* growth of R, scene units per second, >= 0 */
    float density;        /* d0 at birth, >= 0 */
    float fade;           /* d0 at age a: density * (1 - fade * a / lifetime); in [0, 1] */
    uint32_t seed;
    /* LIST (arrays copied by nacre_scene_add_particles) */
    uint32_t count;          /* 1 .. NACRE_PARTICLES_MAX */
    const float *positions;  /* 3 per particle, scene units */
    const float *radii;      /* R per particle, > 0 (NULL: `radius` for all) */
    const float *densities;  /* d0 per particle, >= 0 (NULL: `density` for all) */
    /* The medium, per scene unit at density 1 */
    float sigma_a[3], sigma_s[3]; /* >= 0 */
    float g;                      /* Henyey-Greenstein anisotropy, in (-1, 1) */
    uint32_t grid_resolution;     /* density grid samples per axis over the particles' bounds,
                                     NACRE_PARTICLES_GRID_MIN..MAX (0: the default, 128) */
    /* Optional isosurface (seed 003 §3.2.2-3.2.3, figure 3.15): a smooth dielectric boundary
     * where the system's trilinear density D crosses `density`, drawn by the ray-march fog pass
     * when particles are drawn as voxels (see nacre_particles_draw). */
    struct {
        float density;   /* D at the surface, >= 0; 0: no surface */
        float ior;       /* index of refraction of the inside, in [1, 4] (Fresnel, refraction) */
        float roughness; /* GGX alpha of the lights' highlights, in [0, 1]; 0: none */
    } isosurface;
} nacre_particles_desc;

/* How the raster methods (phong, diffusion) draw particles (nacre_render_settings.particles);
 * the path tracer always renders the density field exactly.
 *   BILLBOARDS (default): screen-space volumetric billboards (seed 003 §3.1): one pass sums each
 *     pixel's optical depth through its particles with the nearest and farthest distances, a
 *     second reconstructs sigma_t along the ray with the remapping r(x) and ray marches it,
 *     lit by directional lights through the same reconstruction and by the environment;
 *   SPRITES: sorted alpha-blended billboards with soft-particle depth fade (§2.2.1), each
 *     particle lit once without shadowing, the baseline the seed compares against;
 *   VOXEL: the density grid as a fog, drawn by the scene's fog passes (seed 003 §3.2: the
 *     ray-marched fog pass renders its shape; the analytic fog pass only its mean). A system
 *     with an isosurface makes the ray-march pass draw all fogs whatever the volumetrics mode
 *     (froxels cannot hold a surface); billboards, sprites and the path tracer draw such a
 *     system's medium without its surface. */
typedef enum nacre_particles_draw {
    NACRE_PARTICLES_DRAW_BILLBOARDS = 0,
    NACRE_PARTICLES_DRAW_SPRITES,
    NACRE_PARTICLES_DRAW_VOXEL
} nacre_particles_draw;

/* "billboards", "sprites", "voxel"; "unknown" otherwise. */
NACRE_API const char *nacre_particles_draw_name(nacre_particles_draw draw);
/* false if the name is unknown. */
NACRE_API bool nacre_particles_draw_from_name(const char *name, nacre_particles_draw *out);

/* Defaults: a point emitter at the origin, 100 particles per second living 2 s, velocity
 * (0, 1, 0), spread 15 degrees, no gravity or drag, radius 0.2, density 1, no fade; grey smoke
 * sigma_s 1, sigma_a 0.1 per unit, g 0; grid 128^3; no isosurface (ior 1.33, roughness 0.2). */
NACRE_API nacre_particles_desc nacre_particles_desc_defaults(nacre_particles_type type);
/* Add a particle system (desc and list arrays copied, validated: a bad field fails with
 * INVALID_ARGUMENT naming it). A scene's particle systems and fogs together are at most
 * NACRE_MAX_FOGS (each system becomes one fog at commit). */
NACRE_API nacre_result nacre_scene_add_particles(nacre_scene *scene, const nacre_particles_desc *desc,
                                                 nacre_particles *out);
NACRE_API nacre_result nacre_scene_set_particles(nacre_scene *scene, nacre_particles particles,
                                                 const nacre_particles_desc *desc);
/* Read back a system's desc; list arrays are borrowed until it is set again or the scene
 * destroyed. */
NACRE_API nacre_result nacre_scene_get_particles(const nacre_scene *scene, nacre_particles particles,
                                                 nacre_particles_desc *out);
NACRE_API uint32_t nacre_scene_particles_count(const nacre_scene *scene);
/* The particles alive at the last commit's time in system `particles` (0 before a commit). */
NACRE_API uint32_t nacre_scene_particles_alive(const nacre_scene *scene, nacre_particles particles);

#ifdef __cplusplus
}
#endif

#endif /* NACRE_PUBLIC_PARTICLES_H */
