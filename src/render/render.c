/*
 * render.c: the frame pipeline shared by the render methods, and its caches.
 *
 * A frame is: setup (camera matrices, draw lists) -> raster (visibility buffer) -> gbuffer
 * (attribute resolve) -> shadow (one depth map per light) -> shade (the method's pass). The
 * renderer remembers the inputs each stage last saw (scene identity, version counters, light
 * descs, sizes) and skips a stage whose inputs are unchanged, which is what the interactive
 * viewer relies on: a material edit only re-shades, a light edit redraws that light's shadow
 * map, a camera move redraws the G-buffer but keeps the shadow maps.
 *
 * The diffusion method (src/diffusion/pipeline.c) runs between the shadow and shade stages:
 * voxelize, translucent shadow maps, inject and propagate per translucent object, with its own
 * per-object caches; its result enters the phong pass through the subsurface hook (shade.h).
 *
 * Camera conventions: core/math.h (right-handed, looking down -z, NDC z in [0, 1]). When the
 * scene leaves near/far at 0 they are fitted to the committed scene bounds.
 */
#include "diffusion/pipeline.h"
#include "pathtrace/pathtrace.h"
#include "raster/raster.h"
#include "scene/scene.h"
#include "shade/shade.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

typedef struct shadow_slot {
    nc_shadow_map map;
    bool valid;
    uint64_t scene_uid, geometry_version;
    int32_t size;
    nacre_light_desc light; /* the desc the map was drawn for */
} shadow_slot;

struct nacre_renderer {
    nacre_context *ctx;
    nc_rasterizer *rasterizer;
    nc_vis_buffer vis;
    nc_gbuffer gbuffer;
    /* G-buffer cache key */
    bool gbuffer_valid;
    uint64_t gb_scene_uid, gb_geometry, gb_camera;
    int32_t gb_width, gb_height;
    nc_raster_view view;
    shadow_slot *shadows;
    uint32_t shadow_capacity;
    /* Draw lists, grown to the object count */
    nc_raster_mesh *draws;
    nc_gbuffer_source *sources;
    nc_shade_light *shade_lights;
    uint32_t draw_capacity, light_capacity;
    /* The last raster frame's image (settings.reuse_output): where it was written, with which
     * environment, and the G-buffer's row spans it was shaded with; outside them it holds the
     * environment. image_valid is false until a frame completes. */
    bool image_valid;
    const float *image_pixels;
    int32_t image_width, image_height;
    size_t image_stride;
    float image_env[3];
    int32_t *image_span;
    int32_t image_span_rows;
    nc_pathtracer *pathtracer; /* created by the first path-traced frame */
    nc_diff_state *diffusion;  /* created by the first diffusion frame */
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
    nacre_result res = nc_rasterizer_create(ctx, &r->rasterizer);
    if (res != NACRE_OK) {
        nc_free(ctx, r);
        return res;
    }
    *out = r;
    return NACRE_OK;
}

void nacre_renderer_destroy(nacre_renderer *r)
{
    if (!r)
        return;
    nacre_context *ctx = r->ctx;
    nc_rasterizer_destroy(r->rasterizer);
    nc_vis_buffer_free(ctx, &r->vis);
    nc_gbuffer_free(ctx, &r->gbuffer);
    for (uint32_t i = 0; i < r->shadow_capacity; i++)
        nc_shadow_free(ctx, &r->shadows[i].map);
    nc_free(ctx, r->shadows);
    nc_free(ctx, r->draws);
    nc_free(ctx, r->sources);
    nc_free(ctx, r->shade_lights);
    nc_free(ctx, r->image_span);
    nc_pathtracer_destroy(ctx, r->pathtracer);
    nc_diff_state_destroy(r->diffusion);
    nc_free(ctx, r);
}

static nacre_result check_settings(nacre_context *ctx, const nacre_render_settings *s)
{
    if ((unsigned)s->method >= NACRE_METHOD_COUNT)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: method: unknown (%d)", (int)s->method);
    if (!nacre_method_available(s->method))
        return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "render: method '%s' is not implemented yet",
                       nacre_method_name(s->method));
    if (s->width < 1 || s->width > 16384 || s->height < 1 || s->height > 16384)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: size %dx%d: width and height must be 1..16384",
                       s->width, s->height);
    /* ~100 bytes of buffers per pixel: 2^26 pixels (8192 x 8192) is ~7 GB, the most that fits
     * the machines we target; larger requests fail here rather than in the kernel's OOM killer. */
    if ((int64_t)s->width * s->height > ((int64_t)1 << 26))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: size %dx%d: at most 67108864 pixels (8192x8192)",
                       s->width, s->height);
    if (s->shadow_map_size < 0 || s->shadow_map_size > 16384)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: shadow_map_size: must be 0..16384");
    if (!(isfinite(s->pcf_radius) && s->pcf_radius >= 0 && s->pcf_radius <= 64))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: pcf_radius: must be in [0, 64]");
    if (!(isfinite(s->shadow_bias) && s->shadow_bias >= 0))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: shadow_bias: must be finite and >= 0");
    if (!isfinite(s->exposure))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: exposure: must be finite");
    if (s->method == NACRE_METHOD_DIFFUSION) {
        /* Only the diffusion method reads these; other methods accept any value. */
        if (s->voxel_resolution < 1 || s->voxel_resolution > 1024)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: voxel_resolution: %u is not in 1..1024",
                           s->voxel_resolution);
        if (s->tsm_size < 16 || s->tsm_size > 8192)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: tsm_size: %d is not in 16..8192",
                           (int)s->tsm_size);
        if (!(s->tolerance > 0.0f && s->tolerance < 1.0f))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: tolerance: %g is not in (0, 1)",
                           (double)s->tolerance);
        if (s->solver != NACRE_SOLVER_MULTIGRID && s->solver != NACRE_SOLVER_SEED)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: solver: unknown (%d)", (int)s->solver);
        if (s->source != NACRE_SOURCE_VOLUME && s->source != NACRE_SOURCE_FACE)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: source: unknown (%d)", (int)s->source);
        if (s->seed_iterations > 100000)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: seed_iterations: %u is not in 0..100000",
                           s->seed_iterations);
    }
    return NACRE_OK;
}

/* Camera matrices; near/far fitted to the scene bounds when the camera leaves them at 0. */
static void camera_view(const nacre_scene *s, int32_t width, int32_t height, nc_raster_view *v)
{
    const nacre_camera_desc *c = &s->camera;
    nc_vec3 eye = nc_v3a(c->position);
    v->view = nc_mat4_look_at(eye, nc_v3a(c->target), nc_v3a(c->up));
    v->width = width;
    v->height = height;
    v->orthographic = c->projection == NACRE_ORTHOGRAPHIC;
    /* Depth range of the bounds' corners along the view axis. */
    float dmin = INFINITY, dmax = -INFINITY;
    for (int k = 0; k < 8; k++) {
        nc_vec3 p = nc_v3((k & 1) ? s->bounds_max[0] : s->bounds_min[0], (k & 2) ? s->bounds_max[1] : s->bounds_min[1],
                          (k & 4) ? s->bounds_max[2] : s->bounds_min[2]);
        float d = -nc_mat4_point(&v->view, p).z;
        dmin = fminf(dmin, d);
        dmax = fmaxf(dmax, d);
    }
    if (!isfinite(dmin) || !isfinite(dmax)) {
        dmin = 0.01f;
        dmax = 100.0f;
    }
    float span = fmaxf(dmax - dmin, 1e-6f);
    float zfar = c->far_clip > 0 ? c->far_clip : dmax + 0.01f * span;
    float aspect = (float)width / (float)height;
    if (v->orthographic) {
        float znear = c->near_clip > 0 ? c->near_clip : dmin - 0.01f * span;
        if (zfar <= znear)
            zfar = znear + 1.0f;
        float hh = 0.5f * c->ortho_height, hw = hh * aspect;
        v->proj = nc_mat4_ortho(-hw, hw, -hh, hh, znear, zfar);
    } else {
        /* Keep far/near <= 1e5 so float NDC depth still separates nearby surfaces. */
        float znear = c->near_clip > 0 ? c->near_clip : fmaxf(dmin * 0.99f, zfar * 1e-5f);
        if (zfar <= znear)
            zfar = znear * 2.0f;
        v->proj = nc_mat4_perspective(c->fov_y * NC_DEG2RAD, aspect, znear, zfar);
    }
}

static nacre_result ensure_lists(nacre_renderer *r, uint32_t objects, uint32_t lights)
{
    nacre_context *ctx = r->ctx;
    if (objects > r->draw_capacity) {
        nc_free(ctx, r->draws);
        nc_free(ctx, r->sources);
        r->draws = nc_calloc(ctx, objects, sizeof(*r->draws));
        r->sources = nc_calloc(ctx, objects, sizeof(*r->sources));
        r->draw_capacity = r->draws && r->sources ? objects : 0;
        if (!r->draw_capacity)
            return NACRE_ERROR_OUT_OF_MEMORY;
    }
    if (lights > r->light_capacity) {
        shadow_slot *slots = nc_realloc(ctx, r->shadows, r->shadow_capacity * sizeof(*slots), lights * sizeof(*slots));
        if (!slots)
            return NACRE_ERROR_OUT_OF_MEMORY;
        memset(slots + r->shadow_capacity, 0, (lights - r->shadow_capacity) * sizeof(*slots));
        r->shadows = slots;
        r->shadow_capacity = lights;
        nc_free(ctx, r->shade_lights);
        r->shade_lights = nc_calloc(ctx, lights, sizeof(*r->shade_lights));
        r->light_capacity = r->shade_lights ? lights : 0;
        if (!r->shade_lights)
            return NACRE_ERROR_OUT_OF_MEMORY;
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
    uint64_t t_start = nc_now_us(), t0 = t_start;
    nacre_result res = check_settings(ctx, settings);
    if (res != NACRE_OK)
        return res;
    if (!s->committed_valid || memcmp(&s->committed, &s->versions, sizeof(s->versions)) != 0)
        return nc_fail(ctx, NACRE_ERROR_INVALID_OPERATION, "render: scene changed since the last nacre_scene_commit");
    /* Fog alone is a scene for the path tracer; the raster methods need geometry for their
     * camera planes and ignore fog anyway. */
    if (s->object_count == 0 && !(settings->method == NACRE_METHOD_PATHTRACE && s->fog_count > 0))
        return nc_fail(ctx, NACRE_ERROR_INVALID_OPERATION, "render: scene has no objects");
    int32_t w = settings->width, h = settings->height;
    /* Whether out still holds the last raster frame (reuse_output); decided before anything is
     * written, and forgotten until this frame completes. */
    const bool reuse = settings->reuse_output && r->image_valid && out->pixels &&
                       out->pixels == r->image_pixels && out->width == r->image_width &&
                       out->height == r->image_height && out->stride == r->image_stride &&
                       out->channels == 3 && settings->method != NACRE_METHOD_PATHTRACE &&
                       memcmp(r->image_env, s->environment, sizeof(r->image_env)) == 0;
    r->image_valid = false;
    bool allocated = false;
    if (out->pixels) {
        if (out->width != w || out->height != h || out->channels != 3 || out->stride < (size_t)w * 3)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: output image must be %dx%d with 3 channels", w, h);
    } else {
        if ((res = nacre_image_alloc(ctx, w, h, 3, out)) != NACRE_OK)
            return res;
        allocated = true;
    }
    if (settings->method == NACRE_METHOD_PATHTRACE) {
        /* The path tracer shares nothing with the raster pipeline. */
        if ((res = nc_pathtrace_render(&r->pathtracer, ctx, s, settings, false, out, &st)) != NACRE_OK)
            goto fail;
        st.total_us = nc_now_us() - t_start;
        if (stats)
            *stats = st;
        return NACRE_OK;
    }
    if ((res = ensure_lists(r, s->object_count, s->light_count)) != NACRE_OK)
        goto fail;

    for (uint32_t i = 0; i < s->object_count; i++) {
        const nc_object_rec *o = &s->objects[i];
        const nacre_mesh_data *m = &s->meshes[o->desc.mesh.id - 1].data;
        r->draws[i] = (nc_raster_mesh){.positions = o->world_positions, .indices = m->indices,
                                       .vertex_count = m->vertex_count, .triangle_count = m->triangle_count,
                                       .object_index = i, .double_sided = o->desc.double_sided};
        r->sources[i] = (nc_gbuffer_source){.positions = o->world_positions, .normals = o->world_normals,
                                            .tangents = o->world_tangents, .uvs = m->uvs, .indices = m->indices,
                                            .material_index = o->desc.material.id - 1};
        st.triangles += m->triangle_count;
    }
    st.stage_us[NACRE_STAGE_SETUP] = nc_now_us() - t0;
    st.stage_ran[NACRE_STAGE_SETUP] = true;

    /* Camera G-buffer */
    bool gb_fresh = r->gbuffer_valid && r->gb_scene_uid == s->uid && r->gb_geometry == s->versions.geometry &&
                    r->gb_camera == s->versions.camera && r->gb_width == w && r->gb_height == h;
    if (!gb_fresh) {
        r->gbuffer_valid = false;
        camera_view(s, w, h, &r->view);
        t0 = nc_now_us();
        nc_raster_counts counts = {0, 0};
        if ((res = nc_vis_buffer_resize(ctx, &r->vis, w, h)) != NACRE_OK ||
            (res = nc_raster_visibility(r->rasterizer, &r->view, r->draws, s->object_count, &r->vis, &counts)) != NACRE_OK)
            goto fail;
        st.triangles_drawn = counts.triangles_drawn;
        st.stage_us[NACRE_STAGE_RASTER] = nc_now_us() - t0;
        st.stage_ran[NACRE_STAGE_RASTER] = true;
        t0 = nc_now_us();
        if ((res = nc_gbuffer_resize(ctx, &r->gbuffer, w, h)) != NACRE_OK ||
            (res = nc_gbuffer_resolve(ctx, &r->view, &r->vis, r->sources, s->object_count, &r->gbuffer)) != NACRE_OK)
            goto fail;
        st.stage_us[NACRE_STAGE_GBUFFER] = nc_now_us() - t0;
        st.stage_ran[NACRE_STAGE_GBUFFER] = true;
        r->gbuffer_valid = true;
        r->gb_scene_uid = s->uid;
        r->gb_geometry = s->versions.geometry;
        r->gb_camera = s->versions.camera;
        r->gb_width = w;
        r->gb_height = h;
    }

    /* Shadow maps: casters are the objects that cast shadows. */
    t0 = nc_now_us();
    uint32_t casters = 0;
    for (uint32_t i = 0; i < s->object_count; i++)
        if (s->objects[i].desc.cast_shadows)
            r->draws[casters++] = r->draws[i];
    if (settings->shadow_map_size > 0 && casters > 0) {
        /* The estimate before any map is made: every shadowing light's depth map (six faces for
         * a point light) that is not allocated at its size yet. */
        uint64_t need = 0, texels = (uint64_t)settings->shadow_map_size * (uint64_t)settings->shadow_map_size;
        uint32_t maps = 0;
        for (uint32_t li = 0; li < s->light_count; li++) {
            const nacre_light_desc *ld = &s->lights[li].desc;
            uint64_t faces = (uint64_t)nc_shadow_face_count(ld->type);
            const nc_shadow_map *m = &r->shadows[li].map;
            if (!ld->cast_shadows || (m->depth && m->size == settings->shadow_map_size && (uint64_t)m->face_count == faces))
                continue;
            need += faces * texels * sizeof(float);
            maps++;
        }
        if (need) {
            char what[96];
            snprintf(what, sizeof(what), "%u shadow map%s of %d^2 texels (lights, shadow_map_size)", maps,
                     maps == 1 ? "" : "s", settings->shadow_map_size);
            if ((res = nc_memory_check(ctx, need, what)) != NACRE_OK)
                goto fail;
        }
    }
    for (uint32_t li = 0; li < s->light_count; li++) {
        const nacre_light_desc *ld = &s->lights[li].desc;
        shadow_slot *slot = &r->shadows[li];
        r->shade_lights[li].desc = ld;
        r->shade_lights[li].shadow = NULL;
        if (!ld->cast_shadows || settings->shadow_map_size == 0 || casters == 0)
            continue;
        bool fresh = slot->valid && slot->scene_uid == s->uid && slot->geometry_version == s->versions.geometry &&
                     slot->size == settings->shadow_map_size && memcmp(&slot->light, ld, sizeof(*ld)) == 0;
        if (!fresh) {
            slot->valid = false;
            if ((res = nc_shadow_render(r->rasterizer, ctx, ld, s->bounds_min, s->bounds_max, settings->shadow_map_size,
                                        r->draws, casters, &slot->map)) != NACRE_OK)
                goto fail;
            slot->valid = true;
            slot->scene_uid = s->uid;
            slot->geometry_version = s->versions.geometry;
            slot->size = settings->shadow_map_size;
            slot->light = *ld;
            st.shadow_maps++;
        }
        r->shade_lights[li].shadow = &slot->map;
    }
    st.stage_us[NACRE_STAGE_SHADOW] = nc_now_us() - t0;
    st.stage_ran[NACRE_STAGE_SHADOW] = st.shadow_maps > 0;

    /* Diffusion: voxelize, translucent shadow maps, inject, propagate (timed inside). */
    if (settings->method == NACRE_METHOD_DIFFUSION) {
        for (uint32_t i = 0; i < s->object_count; i++) {
            const nacre_material_desc *m = nc_scene_material(s, s->objects[i].desc.material);
            if (m && m->type == NACRE_MATERIAL_TRANSLUCENT && m->layering.count > 0) {
                res = nc_fail(ctx, NACRE_ERROR_UNSUPPORTED,
                              "render: object '%s' has a layered material: layers are not implemented in the "
                              "diffusion method (use --method pathtrace)",
                              s->objects[i].name ? s->objects[i].name : "(unnamed)");
                goto fail;
            }
        }
        if (!r->diffusion && (res = nc_diff_state_create(ctx, &r->diffusion)) != NACRE_OK)
            goto fail;
        if ((res = nc_diffusion_frame(r->diffusion, s, settings, r->shade_lights, s->light_count, &st)) != NACRE_OK)
            goto fail;
    }

    /* Shade */
    t0 = nc_now_us();
    nc_mat4 inv_view;
    nc_mat4_inverse(r->view.view, &inv_view);
    nc_shade_params params = {
        .eye = nc_mat4_point(&inv_view, nc_v3(0, 0, 0)),
        .view_dir = nc_normalize(nc_mat4_dir(&inv_view, nc_v3(0, 0, -1))),
        .orthographic = r->view.orthographic,
        .pcf_radius = settings->pcf_radius,
        .shadow_bias = settings->shadow_bias,
    };
    if (settings->method == NACRE_METHOD_DIFFUSION)
        nc_diffusion_shade_params(r->diffusion, s, &params);
    if (r->image_span_rows != h) {
        nc_free(ctx, r->image_span);
        r->image_span_rows = 0;
        if (!(r->image_span = nc_alloc(ctx, 2 * (size_t)h * sizeof(int32_t)))) {
            res = NACRE_ERROR_OUT_OF_MEMORY;
            goto fail;
        }
        r->image_span_rows = h;
    }
    nc_shade_phong(s, &r->gbuffer, r->shade_lights, s->light_count, &params, out->pixels, out->stride,
                   reuse ? r->image_span : NULL, ctx->threads);
    if (r->gbuffer.row_span) {
        memcpy(r->image_span, r->gbuffer.row_span, 2 * (size_t)h * sizeof(int32_t));
        r->image_valid = true;
        r->image_pixels = out->pixels;
        r->image_width = w;
        r->image_height = h;
        r->image_stride = out->stride;
        memcpy(r->image_env, s->environment, sizeof(r->image_env));
    }
    st.stage_us[NACRE_STAGE_SHADE] = nc_now_us() - t0;
    st.stage_ran[NACRE_STAGE_SHADE] = true;
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
    return nc_pathtrace_variance(r->pathtracer, r->ctx, out);
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
