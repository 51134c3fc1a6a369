/*
 * particles.h (private): the particle state at one time (flat SoA arrays) and its splat into a
 * density grid (seed 003 §3.2.1). The kernel and the units are those of nacre/particles.h.
 */
#ifndef NACRE_PARTICLES_H
#define NACRE_PARTICLES_H

#include "core/core.h"

#include <nacre/particles.h>

/* Particles alive at one time. Arrays are owned and grow; capacity never shrinks, so a system
 * re-simulated every frame allocates only when it grows. */
typedef struct nc_particle_set {
    uint32_t count, capacity;
    float *x, *y, *z; /* centres, scene units */
    float *radius;    /* R, scene units, > 0 */
    float *density;   /* d0, >= 0 */
} nc_particle_set;

/* A density grid: sample (i, j, k) at origin + (i, j, k) * spacing, x fastest. The two outer
 * layers of samples on every face are 0, so the trilinear field (clamped outside) integrates to
 * exactly sum(data) * spacing^3 (each sample's tent integrates to one cell). */
typedef struct nc_particle_grid {
    uint32_t dims[3];
    float origin[3], spacing[3]; /* world, scene units */
    float *data;                 /* owned, dims product floats */
    size_t capacity;             /* floats allocated */
    float max_value;
    /* Scratch of the splat, kept so that a system splatted every frame reuses it. */
    int32_t *range;              /* per particle: first and last sample per axis (6) */
    float *scale;                /* per particle: mass / (kernel sum on the grid * cell volume) */
    uint32_t *bin_start, *bins;  /* per brick (fine, then each coarse level), its particles in index order */
    float *weights;              /* per particle from woff[i]: x (padded to 8), y, z kernel weights */
    size_t *woff;                /* n + 1 offsets into weights */
    uint8_t *level;              /* per particle: 0 the grid, l its coarse level l (spacing 2^l) */
    uint8_t *fallback;           /* per particle: bit a set where axis a takes the linear fallback */
    uint32_t *bin_count;         /* per thread and brick: the binning's counts, then its places */
    float *coarse[2];            /* coarse levels 1 and 2: (n - 1) / 2 + 1 samples per axis of the one below */
    uint8_t *dirty;              /* per brick of the grid: not all 0 after the last splat */
    /* Per block of 8^3 samples (block_res per axis, x fastest; 0: not made), the largest sample
     * of the block and of the blocks around it: 0 means that every trilinear lookup whose lower
     * corner lies in the block reads zeros (the volume lookups skip such blocks). */
    float *block_max, *block_raw; /* block_raw: the blocks' own maxima (scratch) */
    uint32_t block_res;
    uint32_t dirty_res;          /* the res `dirty` describes; 0: unknown (every brick dirty) */
    size_t range_capacity, scale_capacity, bin_start_capacity, bin_capacity, weight_capacity, woff_capacity;
    size_t level_capacity, coarse_capacity[2], dirty_capacity, fallback_capacity, bin_count_capacity;
    size_t block_max_capacity, block_raw_capacity;
    bool fine_only;              /* set by the caller: every particle on the grid itself (tests) */
} nc_particle_grid;

/* K of the mass formula m = d0 (K R)^3 (nacre/particles.h). */
#define NC_PARTICLE_KERNEL_K 0.83328696f
/* The kernel's exponent: exp(-NC_PARTICLE_KERNEL_A t^2), t = offset / R in [-1, 1]. */
#define NC_PARTICLE_KERNEL_A 4.5f

/* Check a desc (the message names the field). */
nacre_result nc_particles_check(nacre_context *ctx, const nacre_particles_desc *desc);
/* The particles of `desc` alive at `time` (seconds) into `set`. Deterministic; parallel. */
nacre_result nc_particles_simulate(nacre_context *ctx, const nacre_particles_desc *desc, double time,
                                   nc_particle_set *set);
void nc_particle_set_free(nacre_context *ctx, nc_particle_set *set);
/* Splat `set` into `grid` (res samples per axis over the particles' bounds plus two empty
 * layers): parallel over bricks, each cell summing its particles in index order, so the grid is
 * bit for bit the same for any thread count. An empty set gives dims 0. */
nacre_result nc_particles_splat(nacre_context *ctx, const nc_particle_set *set, uint32_t res,
                                nc_particle_grid *grid);
void nc_particle_grid_free(nacre_context *ctx, nc_particle_grid *grid);
/* The state of particle system `index` (0-based) at the scene's last commit, with its desc;
 * NULL if the scene has no committed particles or no such system. */
struct nacre_scene;
const nc_particle_set *nc_scene_particle_set(const struct nacre_scene *scene, uint32_t index,
                                             const nacre_particles_desc **desc);

/* Isosurface (isosurface.c): the trilinear density at world point p (0 outside the samples). */
float nc_particle_grid_density(const nc_particle_grid *grid, const float p[3]);
/* The first t in [t0, t1] where the density along o + t d rises through `level`; false if the
 * ray misses, never reaches it, or starts at or above it. */
bool nc_particle_iso_hit(const nc_particle_grid *grid, float level, const float o[3], const float d[3], double t0,
                         double t1, double *t_hit);
/* The outward unit normal (minus the density's gradient) at p; false where it vanishes. */
bool nc_particle_iso_normal(const nc_particle_grid *grid, const float p[3], float n[3]);
/* Distance along d from p (inside) to where the ray leaves the grid's samples; 0 if outside. */
double nc_particle_grid_exit(const nc_particle_grid *grid, const float p[3], const float d[3]);
/* The density grid of system `index` at the last commit with its desc; NULL if none. */
const nc_particle_grid *nc_scene_particle_grid(const struct nacre_scene *scene, uint32_t index,
                                               const nacre_particles_desc **desc);
/* Whether particles drawn as voxels (settings) include a system with an isosurface, which
 * makes the ray-march fog pass draw the fogs whatever the volumetrics mode. */
struct nacre_render_settings;
bool nc_scene_particles_iso_drawn(const struct nacre_scene *scene, const struct nacre_render_settings *settings);

/* Sum of the particles' masses, d0 (K R)^3, in double. */
double nc_particles_mass(const nc_particle_set *set);

#endif /* NACRE_PARTICLES_H */
