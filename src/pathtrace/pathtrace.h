/*
 * pathtrace.h: the reference volumetric path tracer (private interface used by render.c and the
 * slab measurement). See integrator.c for the method and its conventions, and the list of files.
 */
#ifndef NACRE_PATHTRACE_H
#define NACRE_PATHTRACE_H

#include "core/core.h"

/* Per-renderer state of the path tracer (accumulation and variance images). Created lazily by
 * nc_pathtrace_render, destroyed with the renderer. */
typedef struct nc_pathtracer nc_pathtracer;

/* Options of a path tracer state. The renderer uses the defaults; tests reach in to compare the
 * majorant grid against a single majorant and to substitute a medium. */
typedef void (*nc_pt_medium_eval_fn)(const nacre_scene *scene, const nacre_material_desc *m,
                                     const float *rest_xyz, size_t count, float *sigma_a, float *sigma_s);
typedef void (*nc_pt_medium_max_fn)(const nacre_scene *scene, const nacre_material_desc *m, float out[3]);
typedef struct nc_pathtrace_options {
    uint32_t majorant_res;         /* cells per axis of heterogeneous media's majorant grids; 0: one
                                      global majorant per object. Default 16. */
    nc_pt_medium_eval_fn eval;     /* NULL: nc_medium_eval */
    nc_pt_medium_max_fn max_sigma_t; /* NULL: nc_medium_max_sigma_t */
    bool force_heterogeneous;      /* treat every translucent material as heterogeneous */
    bool no_sun_guiding;           /* disable sampling the sun through dielectric boundaries */
    bool guide_always;             /* run the guided sun technique at every dielectric medium
                                      vertex (no thinning by the optical depth of the way out):
                                      same image within noise, slower */
    bool no_clearance;             /* disable the clearance grids (free flights skip the boundary
                                      query; deep vertices thin out NEE and guided sun samples):
                                      same image within noise, slower */
} nc_pathtrace_options;

nc_pathtrace_options nc_pathtrace_options_defaults(void);
/* Create a state explicitly (nc_pathtrace_render otherwise creates one with the defaults). */
nacre_result nc_pathtracer_create(nacre_context *ctx, const nc_pathtrace_options *options, nc_pathtracer **out);

/* Whether this build has the path tracer. */
bool nc_pathtrace_available(void);
/* Render a committed scene into `out` (already width x height x 3); fills the pathtrace fields
 * of `stats` (spp_done, samples_per_second). *state is created on first use.
 * accumulate: when the state's last frame was of the same scene (uid) with the same committed
 * versions, size, seed and max_scatter, add settings->spp more samples per pixel (or as many as
 * the time limit allows) to it and output the mean of everything accumulated: two frames of 4
 * spp give the image of one frame of 8, bit for bit. Otherwise, or when false, start from zero.
 * spp_done is then the accumulated samples of the pixel with fewest; samples_done and
 * samples_per_second count this frame's paths. */
nacre_result nc_pathtrace_render(nc_pathtracer **state, nacre_context *ctx, const nacre_scene *scene,
                                 const nacre_render_settings *settings, bool accumulate, nacre_image *out,
                                 nacre_render_stats *stats);
/* What the last completed frame's accumulators hold (0 when none): the samples of the pixel with
 * fewest (= spp_done), the camera paths over all pixels, and the frames since the last restart
 * (1: the last frame restarted). */
uint32_t nc_pathtrace_passes(const nc_pathtracer *state);
uint64_t nc_pathtrace_samples(const nc_pathtracer *state);
uint32_t nc_pathtrace_frames(const nc_pathtracer *state);
/* The variance image of the last render, of the mean of everything it accumulated (see
 * nacre_renderer_variance). */
nacre_result nc_pathtrace_variance(const nc_pathtracer *state, nacre_context *ctx, nacre_image *out);
void nc_pathtracer_destroy(nacre_context *ctx, nc_pathtracer *state);

/* Monte Carlo measurement of the analytic slab (nacre_slab_measure with method PATHTRACE). */
nacre_result nc_slab_pathtrace(nacre_context *ctx, const nacre_slab_desc *desc, nacre_slab_result *out);

#endif /* NACRE_PATHTRACE_H */
