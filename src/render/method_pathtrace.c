/*
 * method_pathtrace.c: `--method pathtrace`, the reference volumetric path tracer
 * (src/pathtrace). It shares nothing with the raster pipeline; its state holds the Embree scene
 * and the per-pixel accumulators (and the variance image, nacre_renderer_variance).
 */
#include "pathtrace/pathtrace.h"
#include "render/method.h"

static nacre_result pathtrace_create(nacre_context *ctx, void **state)
{
    nc_pathtracer *pt = NULL;
    nacre_result res = nc_pathtracer_create(ctx, NULL, &pt);
    *state = pt;
    return res;
}

static nacre_result pathtrace_render(void *state, nc_frame *f)
{
    nc_pathtracer *pt = state;
    return nc_pathtrace_render(&pt, f->ctx, f->scene, f->settings, f->out, f->stats);
}

static void pathtrace_destroy(nacre_context *ctx, void *state)
{
    nc_pathtracer_destroy(ctx, state);
}

const nc_method nc_method_pathtrace = {
    .name = "pathtrace",
    .id = NACRE_METHOD_PATHTRACE,
    .available = nc_pathtrace_available,
    .needs_objects = false,
    .uses_raster = false,
    .stochastic = true,
    .renders_fog = true,
    .create = pathtrace_create,
    .render = pathtrace_render,
    .destroy = pathtrace_destroy,
};
