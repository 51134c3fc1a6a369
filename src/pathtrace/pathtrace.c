/*
 * pathtrace.c: placeholder until the reference path tracer lands (issue 5): every entry point
 * reports NACRE_ERROR_UNSUPPORTED.
 */
#include "pathtrace/pathtrace.h"

bool nc_pathtrace_available(void) { return false; }

nacre_result nc_pathtrace_render(nc_pathtracer **state, nacre_context *ctx, const nacre_scene *scene,
                                 const nacre_render_settings *settings, nacre_image *out,
                                 nacre_render_stats *stats)
{
    (void)state, (void)scene, (void)settings, (void)out, (void)stats;
    return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "render: method 'pathtrace' is not implemented yet");
}

nacre_result nc_pathtrace_variance(const nc_pathtracer *state, nacre_context *ctx, nacre_image *out)
{
    (void)state, (void)out;
    return nc_fail(ctx, NACRE_ERROR_INVALID_OPERATION, "variance: the last frame was not path traced");
}

void nc_pathtracer_destroy(nacre_context *ctx, nc_pathtracer *state) { (void)ctx, (void)state; }

nacre_result nc_slab_pathtrace(nacre_context *ctx, const nacre_slab_desc *desc, nacre_slab_result *out)
{
    (void)desc, (void)out;
    return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "slab: method 'pathtrace' is not implemented yet");
}
