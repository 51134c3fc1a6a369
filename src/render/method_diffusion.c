/*
 * method_diffusion.c: `--method diffusion`, Blanchard 2012 (seed 000) over the shared raster
 * frame: after the shadow maps, per translucent object voxelize, translucent shadow maps,
 * inject and propagate (src/diffusion/pipeline.c, with its own per-object caches), then the
 * phong pass with the subsurface hook reading the fluence (seed 4.6).
 */
#include "diffusion/pipeline.h"
#include "render/method.h"

static nacre_result diffusion_check(nacre_context *ctx, const nacre_render_settings *s)
{
    if (s->diffusion.voxel_resolution < 1 || s->diffusion.voxel_resolution > 1024)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: voxel_resolution: %u is not in 1..1024",
                       s->diffusion.voxel_resolution);
    if (s->diffusion.tsm_size < 16 || s->diffusion.tsm_size > 8192)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: tsm_size: %d is not in 16..8192", (int)s->diffusion.tsm_size);
    if (!(s->diffusion.tolerance > 0.0f && s->diffusion.tolerance < 1.0f))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: tolerance: %g is not in (0, 1)",
                       (double)s->diffusion.tolerance);
    if (s->diffusion.solver != NACRE_SOLVER_MULTIGRID && s->diffusion.solver != NACRE_SOLVER_SEED)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: solver: unknown (%d)", (int)s->diffusion.solver);
    if (s->diffusion.source != NACRE_SOURCE_VOLUME && s->diffusion.source != NACRE_SOURCE_FACE)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: source: unknown (%d)", (int)s->diffusion.source);
    if ((unsigned)s->diffusion.single_scattering > NACRE_SINGLE_SCATTERING_AUTO)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: single_scattering: unknown (%d)",
                       (int)s->diffusion.single_scattering);
    if (s->diffusion.single_scattering == NACRE_SINGLE_SCATTERING_ON && s->diffusion.source != NACRE_SOURCE_VOLUME)
        return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED,
                       "render: single_scattering: not implemented with face sources (use source volume)");
    if (s->diffusion.seed_iterations > 100000)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: seed_iterations: %u is not in 0..100000",
                       s->diffusion.seed_iterations);
    return NACRE_OK;
}

static nacre_result diffusion_create(nacre_context *ctx, void **state)
{
    nc_diff_state *st = NULL;
    nacre_result res = nc_diff_state_create(ctx, &st);
    *state = st;
    return res;
}

static nacre_result diffusion_render(void *state, nc_frame *f)
{
    const nacre_scene *s = f->scene;
    nacre_result res = nc_raster_frame_prepare(f->raster, s, f->settings, f->stats);
    if (res != NACRE_OK)
        return res;
    if ((res = nc_diffusion_frame(state, s, f->settings, f->raster->shade_lights, s->light_count, f->stats)) !=
        NACRE_OK)
        return res;
    nc_shade_params params;
    nc_raster_frame_shade_params(f->raster, f->settings, &params);
    nc_diffusion_shade_params(state, s, &params);
    if ((res = nc_raster_frame_shade(f->raster, s, &params, f->out, f->reuse, f->stats)) != NACRE_OK)
        return res;
    f->depth = f->raster->gbuffer.view_depth;
    return NACRE_OK;
}

static void diffusion_destroy(nacre_context *ctx, void *state)
{
    (void)ctx;
    nc_diff_state_destroy(state);
}

const nc_method nc_method_diffusion = {
    .name = "diffusion",
    .id = NACRE_METHOD_DIFFUSION,
    .needs_objects = true,
    .uses_raster = true,
    .stages = NC_RASTER_STAGES | (1u << NACRE_STAGE_VOXELIZE) | (1u << NACRE_STAGE_MEDIUM) | (1u << NACRE_STAGE_TSM) |
              (1u << NACRE_STAGE_INJECT) | (1u << NACRE_STAGE_PROPAGATE),
    .check = diffusion_check,
    .create = diffusion_create,
    .render = diffusion_render,
    .destroy = diffusion_destroy,
};
