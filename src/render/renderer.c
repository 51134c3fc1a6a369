/*
 * renderer.c: nacre_renderer, the object that lives across frames. It checks the settings every
 * method shares, owns the shared raster frame and one state per method it has rendered with
 * (made on first use), runs the method named by the settings (methods.c), then the post passes
 * that want the frame (post.c) over its image and depth. What each stage caches, and so which
 * scene edits rerun which stages, is said where the stage lives: raster_frame.h for the shared
 * raster stages, each method's file for its own.
 */
#include "pathtrace/pathtrace.h"
#include "render/method.h"

#include <math.h>
#include <string.h>

struct nacre_renderer {
    nacre_context *ctx;
    nc_raster_frame raster;
    void *state[NACRE_METHOD_COUNT];
    bool created[NACRE_METHOD_COUNT];
    const nc_post_pass *const *post;
    uint32_t post_count;
    void **post_state; /* post_count entries, made on a pass's first use */
    const float *depth; /* the last frame's depth (borrowed from a method or the raster frame) */
    int32_t depth_width, depth_height;
    nacre_method last_method;
    bool last_valid;
};

nacre_result nacre_renderer_create(nacre_context *ctx, nacre_renderer **out)
{
    if (!ctx || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    *out = NULL;
    nacre_renderer *r = nc_calloc(ctx, 1, sizeof(*r));
    if (!r)
        return NACRE_ERROR_OUT_OF_MEMORY;
    r->ctx = ctx;
    nacre_result res = nc_raster_frame_init(ctx, &r->raster);
    if (res == NACRE_OK)
        res = nc_renderer_set_post_passes(r, nc_post_passes, nc_post_pass_count);
    if (res != NACRE_OK) {
        nacre_renderer_destroy(r);
        return res;
    }
    *out = r;
    return NACRE_OK;
}

static void free_post_states(nacre_renderer *r)
{
    for (uint32_t i = 0; r->post_state && i < r->post_count; i++)
        if (r->post_state[i])
            r->post[i]->destroy(r->ctx, r->post_state[i]);
    nc_free(r->ctx, r->post_state);
    r->post_state = NULL;
}

nacre_result nc_renderer_set_post_passes(nacre_renderer *r, const nc_post_pass *const *passes, uint32_t count)
{
    free_post_states(r);
    r->post = passes;
    r->post_count = count;
    if (count && !(r->post_state = nc_calloc(r->ctx, count, sizeof(*r->post_state)))) {
        r->post_count = 0;
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    return NACRE_OK;
}

void nacre_renderer_destroy(nacre_renderer *r)
{
    if (!r)
        return;
    nacre_context *ctx = r->ctx;
    for (int m = 0; m < NACRE_METHOD_COUNT; m++)
        if (r->created[m])
            nc_method_get((nacre_method)m)->destroy(ctx, r->state[m]);
    free_post_states(r);
    nc_raster_frame_free(&r->raster);
    nc_free(ctx, r);
}

/* Checks of the settings every method reads; each method checks its own (nc_method.check). */
static nacre_result check_settings(nacre_context *ctx, const nacre_render_settings *s, const nc_method **out)
{
    const nc_method *m = nc_method_get(s->method);
    if (!m)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: method: unknown (%d)", (int)s->method);
    if (!nacre_method_available(s->method))
        return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "render: method '%s' is not implemented yet", m->name);
    if (s->width < 1 || s->width > 16384 || s->height < 1 || s->height > 16384)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: size %dx%d: width and height must be 1..16384",
                       s->width, s->height);
    /* ~100 bytes of buffers per pixel: 2^26 pixels (8192 x 8192) is ~7 GB, the most that fits
     * the machines we target; larger requests fail here rather than in the kernel's OOM killer. */
    if ((int64_t)s->width * s->height > ((int64_t)1 << 26))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: size %dx%d: at most 67108864 pixels (8192x8192)",
                       s->width, s->height);
    if (s->shadow.map_size < 0 || s->shadow.map_size > 16384)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: shadow_map_size: must be 0..16384");
    if (!(isfinite(s->shadow.pcf_radius) && s->shadow.pcf_radius >= 0 && s->shadow.pcf_radius <= 64))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: pcf_radius: must be in [0, 64]");
    if (!(isfinite(s->shadow.bias) && s->shadow.bias >= 0))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: shadow_bias: must be finite and >= 0");
    const nacre_volumetrics_settings *v = &s->volumetrics;
    if ((unsigned)v->mode > NACRE_VOLUMETRICS_RAYMARCH)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: volumetrics: must be off, froxel or raymarch");
    if (v->froxel_width < 1 || v->froxel_width > 1024)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: froxel_width: must be 1..1024");
    if (v->froxel_height < 1 || v->froxel_height > 1024)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: froxel_height: must be 1..1024");
    if (v->froxel_slices < 1 || v->froxel_slices > 1024)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: froxel_slices: must be 1..1024");
    if ((uint64_t)v->froxel_width * v->froxel_height * v->froxel_slices > (1u << 24))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "render: froxel_width: froxel_width x froxel_height x froxel_slices must be at most 2^24");
    if (v->raymarch_steps < 1 || v->raymarch_steps > 4096)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: raymarch_steps: must be 1..4096");
    if (v->shadow_steps < 1 || v->shadow_steps > 256)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: shadow_steps: must be 1..256");
    if (!(v->temporal >= 0.0f && v->temporal < 1.0f))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: froxel_temporal: must be in [0, 1)");
    *out = m;
    return m->check ? m->check(ctx, s) : NACRE_OK;
}

/* The post passes that want this frame, over its image and depth. A method without depth of
 * its own (the path tracer) gets the raster frame's G-buffer depth, made only when a pass
 * needs it. */
static nacre_result post_passes(nacre_renderer *r, nc_frame *f)
{
    for (uint32_t i = 0; i < r->post_count; i++) {
        const nc_post_pass *p = r->post[i];
        if (!p->wanted(f->scene, f->settings))
            continue;
        nacre_result res;
        if (!f->depth) {
            if ((res = nc_raster_frame_gbuffer(&r->raster, f->scene, f->settings->width, f->settings->height,
                                               f->stats)) != NACRE_OK)
                return res;
            f->depth = r->raster.gbuffer.view_depth;
        }
        if (!r->post_state[i] && (res = p->create(r->ctx, &r->post_state[i])) != NACRE_OK)
            return res;
        nc_post_input in = {.ctx = r->ctx, .scene = f->scene, .settings = f->settings, .view = &r->raster.view,
                            .depth = f->depth};
        const nc_method *m = nc_method_get(f->settings->method);
        if (m && m->uses_raster) {
            in.lights = r->raster.shade_lights;
            in.light_count = f->scene->light_count;
        }
        if ((res = p->apply(r->post_state[i], &in, f->out, f->stats)) != NACRE_OK)
            return res;
        /* The pass changed background pixels too: the next frame cannot keep them
         * (reuse_output), or it would apply the pass to them twice. */
        r->raster.image_valid = false;
    }
    return NACRE_OK;
}

nacre_result nacre_renderer_render(nacre_renderer *r, const nacre_scene *s, const nacre_render_settings *settings,
                                   nacre_image *out, nacre_render_stats *stats)
{
    if (!r || !s || !settings || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_context *ctx = r->ctx;
    if (s->ctx != ctx)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: the scene belongs to another context");
    nacre_render_stats st;
    memset(&st, 0, sizeof(st));
    st.threads = ctx->threads;
    uint64_t t_start = nc_now_us();
    const nc_method *m = NULL;
    nacre_result res = check_settings(ctx, settings, &m);
    if (res != NACRE_OK)
        return res;
    if (!s->committed_valid || memcmp(&s->committed, &s->versions, sizeof(s->versions)) != 0)
        return nc_fail(ctx, NACRE_ERROR_INVALID_OPERATION, "render: scene changed since the last nacre_scene_commit");
    /* Fog alone is a scene for the path tracer; the raster methods need geometry for their
     * camera planes. */
    if (s->object_count == 0 && (m->needs_objects || s->fog_count == 0))
        return nc_fail(ctx, NACRE_ERROR_INVALID_OPERATION, "render: scene has no objects");
    int32_t w = settings->width, h = settings->height;
    /* Decided before anything is written; the raster frame forgets its image until a raster
     * frame completes. */
    bool reuse = nc_raster_frame_take_reuse(&r->raster, s, settings, out) && m->uses_raster;
    r->last_valid = false;
    r->depth = NULL;
    bool allocated = false;
    if (out->pixels) {
        if (out->width != w || out->height != h || out->channels != 3 || out->stride < (size_t)w * 3)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: output image must be %dx%d with 3 channels", w, h);
    } else {
        if ((res = nacre_image_alloc(ctx, w, h, 3, out)) != NACRE_OK)
            return res;
        allocated = true;
    }
    if (!r->created[m->id]) {
        if ((res = m->create(ctx, &r->state[m->id])) != NACRE_OK)
            goto fail;
        r->created[m->id] = true;
    }
    nc_frame f = {.ctx = ctx, .scene = s, .settings = settings, .out = out, .stats = &st, .raster = &r->raster,
                  .reuse = reuse};
    if ((res = m->render(r->state[m->id], &f)) != NACRE_OK || (res = post_passes(r, &f)) != NACRE_OK)
        goto fail;
    r->depth = f.depth;
    r->depth_width = w;
    r->depth_height = h;
    r->last_method = m->id;
    r->last_valid = true;
    st.total_us = nc_now_us() - t_start;
    if (stats)
        *stats = st;
    return NACRE_OK;
fail:
    if (allocated)
        nacre_image_free(ctx, out);
    return res;
}

nacre_result nacre_renderer_variance(const nacre_renderer *r, nacre_image *out)
{
    if (!r || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!r->last_valid || r->last_method != NACRE_METHOD_PATHTRACE)
        return nc_fail(r->ctx, NACRE_ERROR_INVALID_OPERATION, "variance: the last frame was not path traced");
    return nc_pathtrace_variance(r->state[NACRE_METHOD_PATHTRACE], r->ctx, out);
}

nacre_result nacre_renderer_depth(const nacre_renderer *r, nacre_image *out)
{
    if (!r || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!r->last_valid || !r->depth)
        return nc_fail(r->ctx, NACRE_ERROR_INVALID_OPERATION,
                       "depth: the renderer's last frame kept no depth (none yet, or path traced without a post pass)");
    int32_t w = r->depth_width, h = r->depth_height;
    if (out->pixels) {
        if (out->width != w || out->height != h || out->channels != 1 || out->stride < (size_t)w)
            return nc_fail(r->ctx, NACRE_ERROR_INVALID_ARGUMENT, "depth: output image must be %dx%d with 1 channel", w, h);
    } else {
        nacre_result res = nacre_image_alloc(r->ctx, w, h, 1, out);
        if (res != NACRE_OK)
            return res;
    }
    for (int32_t y = 0; y < h; y++)
        memcpy(out->pixels + (size_t)y * out->stride, r->depth + (size_t)y * (size_t)w, (size_t)w * sizeof(float));
    return NACRE_OK;
}

nacre_result nacre_render(const nacre_scene *s, const nacre_render_settings *settings, nacre_image *out,
                          nacre_render_stats *stats)
{
    if (!s)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_renderer *r = NULL;
    nacre_result res = nacre_renderer_create(s->ctx, &r);
    if (res != NACRE_OK)
        return res;
    res = nacre_renderer_render(r, s, settings, out, stats);
    nacre_renderer_destroy(r);
    return res;
}

nacre_result nacre_renderer_pick(const nacre_renderer *r, int32_t x, int32_t y, uint32_t *object_index)
{
    if (!r || !object_index)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_method_info info;
    /* Only a rasterized frame's G-buffer is the frame on screen: after a path-traced frame it
     * may be an older camera's. */
    if (!r->last_valid || !nacre_method_info_get(r->last_method, &info) || !(info.stages & (1u << NACRE_STAGE_RASTER)) ||
        !r->raster.gbuffer_valid)
        return nc_fail(r->ctx, NACRE_ERROR_INVALID_OPERATION,
                       "pick: the renderer's last frame was not rasterized (none yet, or path traced)");
    const nc_gbuffer *gb = &r->raster.gbuffer;
    if (x < 0 || y < 0 || x >= gb->width || y >= gb->height)
        return nc_fail(r->ctx, NACRE_ERROR_INVALID_ARGUMENT, "pick: pixel (%d, %d) is outside the %dx%d frame",
                       (int)x, (int)y, (int)gb->width, (int)gb->height);
    uint32_t id = gb->object[(size_t)y * (size_t)gb->width + (size_t)x];
    *object_index = id == NC_NO_OBJECT ? UINT32_MAX : id;
    return NACRE_OK;
}
