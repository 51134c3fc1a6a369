/*
 * method_phong.c: `--method phong`, ambient + Lambert + normalized Blinn-Phong with shadow maps
 * and PCF (shade/phong.c) over the shared raster frame. Translucent materials shade with their
 * dipole diffuse reflectance (nc_material_albedo), so phong is the quick preview of any scene.
 */
#include "render/method.h"

static nacre_result phong_create(nacre_context *ctx, void **state)
{
    (void)ctx;
    *state = NULL; /* everything it keeps is in the shared raster frame */
    return NACRE_OK;
}

static nacre_result phong_render(void *state, nc_frame *f)
{
    (void)state;
    nacre_result res = nc_raster_frame_prepare(f->raster, f->scene, f->settings, f->stats);
    if (res != NACRE_OK)
        return res;
    nc_shade_params params;
    nc_raster_frame_shade_params(f->raster, f->settings, &params);
    if ((res = nc_raster_frame_shade(f->raster, f->scene, &params, f->out, f->reuse, f->stats)) != NACRE_OK)
        return res;
    f->depth = f->raster->gbuffer.view_depth;
    return NACRE_OK;
}

static void phong_destroy(nacre_context *ctx, void *state)
{
    (void)ctx;
    (void)state;
}

const nc_method nc_method_phong = {
    .name = "phong",
    .id = NACRE_METHOD_PHONG,
    .needs_objects = true,
    .uses_raster = true,
    .stages = NC_RASTER_STAGES,
    .create = phong_create,
    .render = phong_render,
    .destroy = phong_destroy,
};
