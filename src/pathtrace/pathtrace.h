/*
 * pathtrace.h: the reference volumetric path tracer (private interface used by render.c and the
 * slab measurement). See pathtrace.c for the method and its conventions.
 */
#ifndef NACRE_PATHTRACE_H
#define NACRE_PATHTRACE_H

#include "core/core.h"

/* Per-renderer state of the path tracer (accumulation and variance images). Created lazily by
 * nc_pathtrace_render, destroyed with the renderer. */
typedef struct nc_pathtracer nc_pathtracer;

/* Whether this build has the path tracer. */
bool nc_pathtrace_available(void);
/* Render a committed scene into `out` (already width x height x 3); fills the pathtrace fields
 * of `stats` (spp_done, samples_per_second). *state is created on first use. */
nacre_result nc_pathtrace_render(nc_pathtracer **state, nacre_context *ctx, const nacre_scene *scene,
                                 const nacre_render_settings *settings, nacre_image *out,
                                 nacre_render_stats *stats);
/* The variance image of the last render (see nacre_renderer_variance). */
nacre_result nc_pathtrace_variance(const nc_pathtracer *state, nacre_context *ctx, nacre_image *out);
void nc_pathtracer_destroy(nacre_context *ctx, nc_pathtracer *state);

/* Monte Carlo measurement of the analytic slab (nacre_slab_measure with method PATHTRACE). */
nacre_result nc_slab_pathtrace(nacre_context *ctx, const nacre_slab_desc *desc, nacre_slab_result *out);

#endif /* NACRE_PATHTRACE_H */
