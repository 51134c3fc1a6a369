/*
 * raster_frame.c: draw lists, camera G-buffer, shadow maps and the phong pass that the
 * rasterizing methods share, each cached against the inputs it last saw (raster_frame.h).
 */
#include "render/raster_frame.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

nacre_result nc_raster_frame_init(nacre_context *ctx, nc_raster_frame *rf)
{
    memset(rf, 0, sizeof(*rf));
    rf->ctx = ctx;
    return nc_rasterizer_create(ctx, &rf->rasterizer);
}

void nc_raster_frame_free(nc_raster_frame *rf)
{
    nacre_context *ctx = rf->ctx;
    if (!ctx)
        return;
    nc_rasterizer_destroy(rf->rasterizer);
    nc_vis_buffer_free(ctx, &rf->vis);
    nc_gbuffer_free(ctx, &rf->gbuffer);
    for (uint32_t i = 0; i < rf->shadow_capacity; i++)
        nc_shadow_free(ctx, &rf->shadows[i].map);
    nc_free(ctx, rf->shadows);
    nc_free(ctx, rf->draws);
    nc_free(ctx, rf->sources);
    nc_free(ctx, rf->shade_lights);
    nc_free(ctx, rf->image_span);
    memset(rf, 0, sizeof(*rf));
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
    float dmin, dmax;
    nc_scene_view_depth_range(s, &v->view, &dmin, &dmax);
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

static nacre_result ensure_lists(nc_raster_frame *r, uint32_t objects, uint32_t lights)
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
        nc_shadow_slot *slots = nc_realloc(ctx, r->shadows, r->shadow_capacity * sizeof(*slots), lights * sizeof(*slots));
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

bool nc_raster_frame_take_reuse(nc_raster_frame *rf, const nacre_scene *s, const nacre_render_settings *settings,
                                const nacre_image *out)
{
    const bool reuse = settings->reuse_output && rf->image_valid && out->pixels && out->pixels == rf->image_pixels &&
                       out->width == rf->image_width && out->height == rf->image_height &&
                       out->stride == rf->image_stride && out->channels == 3 &&
                       memcmp(rf->image_env, s->environment, sizeof(rf->image_env)) == 0;
    rf->image_valid = false;
    return reuse;
}

/* Fill the draw lists from the committed scene (every frame: they only hold pointers). */
static nacre_result setup_lists(nc_raster_frame *r, const nacre_scene *s, nacre_render_stats *st)
{
    uint64_t t0 = nc_now_us();
    nacre_result res = ensure_lists(r, s->object_count, s->light_count);
    if (res != NACRE_OK)
        return res;
    for (uint32_t i = 0; i < s->object_count; i++) {
        const nc_object_rec *o = &s->objects[i];
        const nacre_mesh_data *m = &s->meshes[o->desc.mesh.id - 1].data;
        r->draws[i] = (nc_raster_mesh){.positions = o->world_positions, .indices = m->indices,
                                       .vertex_count = m->vertex_count, .triangle_count = m->triangle_count,
                                       .object_index = i, .double_sided = o->desc.double_sided};
        r->sources[i] = (nc_gbuffer_source){.positions = o->world_positions, .normals = o->world_normals,
                                            .uvs = m->uvs, .indices = m->indices,
                                            .material_index = o->desc.material.id - 1};
        st->triangles += m->triangle_count;
    }
    st->stage_us[NACRE_STAGE_SETUP] += nc_now_us() - t0;
    st->stage_ran[NACRE_STAGE_SETUP] = true;
    st->stage_runs[NACRE_STAGE_SETUP] = 1;
    return NACRE_OK;
}

/* The camera G-buffer, redrawn when the scene's geometry, the camera or the size changed. */
static nacre_result camera_gbuffer(nc_raster_frame *r, const nacre_scene *s, int32_t w, int32_t h,
                                   nacre_render_stats *st)
{
    nacre_context *ctx = r->ctx;
    if (r->gbuffer_valid && r->gb_scene_uid == s->uid && r->gb_geometry == s->versions.geometry &&
        r->gb_camera == s->versions.camera && r->gb_width == w && r->gb_height == h)
        return NACRE_OK;
    r->gbuffer_valid = false;
    camera_view(s, w, h, &r->view);
    uint64_t t0 = nc_now_us();
    nc_raster_counts counts = {0, 0};
    nacre_result res;
    if ((res = nc_vis_buffer_resize(ctx, &r->vis, w, h)) != NACRE_OK ||
        (res = nc_raster_visibility(r->rasterizer, &r->view, r->draws, s->object_count, &r->vis, &counts)) != NACRE_OK)
        return res;
    st->triangles_drawn = counts.triangles_drawn;
    st->stage_us[NACRE_STAGE_RASTER] += nc_now_us() - t0;
    st->stage_ran[NACRE_STAGE_RASTER] = true;
    st->stage_runs[NACRE_STAGE_RASTER] = 1;
    t0 = nc_now_us();
    if ((res = nc_gbuffer_resize(ctx, &r->gbuffer, w, h)) != NACRE_OK ||
        (res = nc_gbuffer_resolve(ctx, &r->view, &r->vis, r->sources, s->object_count, &r->gbuffer)) != NACRE_OK)
        return res;
    st->stage_us[NACRE_STAGE_GBUFFER] += nc_now_us() - t0;
    st->stage_ran[NACRE_STAGE_GBUFFER] = true;
    st->stage_runs[NACRE_STAGE_GBUFFER] = 1;
    r->gbuffer_valid = true;
    r->gb_scene_uid = s->uid;
    r->gb_geometry = s->versions.geometry;
    r->gb_camera = s->versions.camera;
    r->gb_width = w;
    r->gb_height = h;
    return NACRE_OK;
}

nacre_result nc_raster_frame_gbuffer(nc_raster_frame *rf, const nacre_scene *s, int32_t width, int32_t height,
                                     nacre_render_stats *stats)
{
    nacre_result res = setup_lists(rf, s, stats);
    return res != NACRE_OK ? res : camera_gbuffer(rf, s, width, height, stats);
}

/* Shadow maps of the lights that cast shadows, from the objects that cast them; a map is
 * redrawn when its light, the geometry or the map size changed. */
static nacre_result shadow_maps(nc_raster_frame *r, const nacre_scene *s, const nacre_render_settings *settings,
                                nacre_render_stats *st)
{
    nacre_context *ctx = r->ctx;
    nacre_result res;
    uint64_t t0 = nc_now_us();
    uint32_t casters = 0;
    for (uint32_t i = 0; i < s->object_count; i++)
        if (s->objects[i].desc.cast_shadows)
            r->draws[casters++] = r->draws[i];
    if (settings->shadow.map_size > 0 && casters > 0) {
        /* The estimate before any map is made: every shadowing light's depth map (six faces for
         * a point light) that is not allocated at its size yet. */
        uint64_t need = 0, texels = (uint64_t)settings->shadow.map_size * (uint64_t)settings->shadow.map_size;
        uint32_t maps = 0;
        for (uint32_t li = 0; li < s->light_count; li++) {
            const nacre_light_desc *ld = &s->lights[li].desc;
            uint64_t faces = (uint64_t)nc_shadow_face_count(ld->type);
            const nc_shadow_map *m = &r->shadows[li].map;
            if (!ld->cast_shadows || (m->depth && m->size == settings->shadow.map_size && (uint64_t)m->face_count == faces))
                continue;
            need += faces * texels * sizeof(float);
            maps++;
        }
        if (need) {
            char what[96];
            snprintf(what, sizeof(what), "%u shadow map%s of %d^2 texels (lights, shadow_map_size)", maps,
                     maps == 1 ? "" : "s", settings->shadow.map_size);
            if ((res = nc_memory_check(ctx, need, what)) != NACRE_OK)
                return res;
        }
    }
    for (uint32_t li = 0; li < s->light_count; li++) {
        const nacre_light_desc *ld = &s->lights[li].desc;
        nc_shadow_slot *slot = &r->shadows[li];
        r->shade_lights[li].desc = ld;
        r->shade_lights[li].shadow = NULL;
        if (!ld->cast_shadows || settings->shadow.map_size == 0 || casters == 0)
            continue;
        bool fresh = slot->valid && slot->scene_uid == s->uid && slot->geometry_version == s->versions.geometry &&
                     slot->size == settings->shadow.map_size && memcmp(&slot->light, ld, sizeof(*ld)) == 0;
        if (!fresh) {
            slot->valid = false;
            if ((res = nc_shadow_render(r->rasterizer, ctx, ld, s->bounds_min, s->bounds_max, settings->shadow.map_size,
                                        r->draws, casters, &slot->map)) != NACRE_OK)
                return res;
            slot->valid = true;
            slot->scene_uid = s->uid;
            slot->geometry_version = s->versions.geometry;
            slot->size = settings->shadow.map_size;
            slot->light = *ld;
            st->shadow_maps++;
        }
        r->shade_lights[li].shadow = &slot->map;
    }
    st->stage_us[NACRE_STAGE_SHADOW] = nc_now_us() - t0;
    st->stage_ran[NACRE_STAGE_SHADOW] = st->shadow_maps > 0;
    st->stage_runs[NACRE_STAGE_SHADOW] = st->shadow_maps;
    return NACRE_OK;
}

nacre_result nc_raster_frame_prepare(nc_raster_frame *rf, const nacre_scene *s, const nacre_render_settings *settings,
                                     nacre_render_stats *stats)
{
    nacre_result res = nc_raster_frame_gbuffer(rf, s, settings->width, settings->height, stats);
    return res != NACRE_OK ? res : shadow_maps(rf, s, settings, stats);
}

void nc_raster_frame_shade_params(const nc_raster_frame *rf, const nacre_render_settings *settings,
                                  nc_shade_params *params)
{
    nc_mat4 inv_view;
    nc_mat4_inverse(rf->view.view, &inv_view);
    *params = (nc_shade_params){
        .eye = nc_mat4_point(&inv_view, nc_v3(0, 0, 0)),
        .view_dir = nc_normalize(nc_mat4_dir(&inv_view, nc_v3(0, 0, -1))),
        .orthographic = rf->view.orthographic,
        .pcf_radius = settings->shadow.pcf_radius,
        .shadow_bias = settings->shadow.bias,
    };
}

nacre_result nc_raster_frame_shade(nc_raster_frame *r, const nacre_scene *s, const nc_shade_params *params,
                                   nacre_image *out, bool reuse, nacre_render_stats *st)
{
    nacre_context *ctx = r->ctx;
    uint64_t t0 = nc_now_us();
    int32_t w = out->width, h = out->height;
    if (r->image_span_rows != h) {
        nc_free(ctx, r->image_span);
        r->image_span_rows = 0;
        if (!(r->image_span = nc_alloc(ctx, 2 * (size_t)h * sizeof(int32_t))))
            return NACRE_ERROR_OUT_OF_MEMORY;
        r->image_span_rows = h;
    }
    nc_shade_phong(s, &r->gbuffer, r->shade_lights, s->light_count, params, out->pixels, out->stride,
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
    st->stage_us[NACRE_STAGE_SHADE] = nc_now_us() - t0;
    st->stage_ran[NACRE_STAGE_SHADE] = true;
    st->stage_runs[NACRE_STAGE_SHADE] = 1;
    return NACRE_OK;
}
