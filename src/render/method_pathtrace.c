/*
 * method_pathtrace.c: `--method pathtrace`, the reference volumetric path tracer
 * (src/pathtrace). It shares nothing with the raster pipeline; its state holds the Embree scene
 * (rebuilt only when something but the camera changed) and the per-pixel accumulators, which
 * progressive frames (settings.pathtrace.accumulate) add to while nothing changes.
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
    nacre_result res = nc_pathtrace_render(&pt, f->ctx, f->scene, f->settings, f->settings->pathtrace.accumulate, f->out,
                                           f->stats);
    if (res == NACRE_OK)
        f->stats->accumulated = nc_pathtrace_frames(pt) > 1;
    return res;
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
