/*
 * method_layered.c: `--method layered`, real-time single scattering in layered translucent
 * materials after Francois, Pattanaik, Bouatouch and Breton 2006, "Subsurface texture mapping"
 * (seed 001), over the shared raster frame.
 *
 * Stages: the raster frame (G-buffer with position, normal, uv and triangle per pixel; shadow
 * maps), then per translucent object the least-squares planes and uv gradients (layered/planes.c,
 * stage "planes", cached against the scene's geometry and materials versions and epsilon), then
 * per translucent pixel the ray march (layered/march.c, stage "march"), and last the phong pass
 * with the march's radiance in place of the Lambert term: ambient and the Blinn-Phong glossy
 * layer stay on top, as the seed's surface layer (section 3). A translucent material without
 * layers is one layer, the core, so every scene renders. The material's pattern is not read:
 * the core is its first medium.
 *
 * What no light changes is kept across frames: each marched pixel's view ray, cut into pieces at
 * the layer boundaries, with the depth map's bottoms along it (nc_march_ray, one slot per
 * translucent pixel, made the first time the pixel is marched), from the second frame with the
 * same G-buffer (camera, geometry, size), materials and march settings on. A frame where only
 * lights move then evaluates the lights, the shadow lookups and the closed forms; the image is
 * the same as marching from scratch.
 *
 * Multiple scattering (material option multiple_scattering = DIFFUSION): the seed's march is
 * single scattering only, which leaves thick, high-albedo layers too dark. For such objects the
 * diffusion method's pipeline (seed 000, Blanchard 2012; diffusion/pipeline.c, stages voxelize,
 * medium, tsm, inject, propagate, each cached as in that method) solves the object's voxels with
 * each voxel's own layer or core coefficients (averaged over the cell), and its exitance, read
 * as that method reads it (Fresnel transmission once, at the surface), is added to the march's
 * radiance. As in Jensen et al. 2001's split of subsurface reflectance into a single-scattering
 * term and a diffusion term, the diffusion solution stands for the multiply scattered light
 * only: its sources are those of light scattered a second time (pipeline.c, multiple_medium),
 * since the march already gives the first order; the solution of the first scattering's sources
 * would count that order twice (docs/accuracy.md measures both against the path tracer).
 */
#include "diffusion/pipeline.h"
#include "layered/march.h"
#include "layered/planes.h"
#include "render/method.h"

#include <math.h>
#include <string.h>

typedef struct layered_object {
    bool valid;
    uint64_t scene_uid, geometry, materials;
    float epsilon;
    nc_layer_planes planes;
} layered_object;

/* What the kept rays were made for: the G-buffer's inputs, the materials, the march settings. */
typedef struct ray_key {
    uint64_t scene_uid, geometry, camera, materials;
    int32_t width, height;
    uint32_t samples, cap, layers;
    int32_t integration;
    float epsilon;
} ray_key;

typedef struct layered_state {
    nacre_context *ctx;
    layered_object *objects;
    uint32_t object_capacity;
    nc_layer_medium *media; /* per material (translucent ones used) */
    uint32_t media_capacity;
    uint8_t *subsurface;    /* per object: rendered by the march */
    uint8_t *multiple;      /* per object: multiple scattering from the diffusion pipeline */
    nc_diff_state *diff;    /* that pipeline's state (created on first use) */
    float *radiance;        /* 3 per pixel of the G-buffer, translucent pixels only */
    size_t radiance_pixels;
    /* The kept view rays: slot ray_index[pixel] (UINT32_MAX: none) of ray_bytes bytes, made when
     * ray_made[slot]; valid for ray_key while rays_on (rays_tried: set up for it, or found not
     * possible). */
    ray_key ray_key;
    bool rays_on, rays_tried;
    uint8_t *rays, *ray_made;
    uint32_t *ray_index;
    size_t rays_capacity, made_capacity, index_capacity, ray_bytes;
    uint32_t ray_cap, ray_layers;
} layered_state;

static nacre_result layered_check(nacre_context *ctx, const nacre_render_settings *s)
{
    if (s->layered.samples < 1 || s->layered.samples > 4096)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: layered_samples: %u is not in 1..4096",
                       s->layered.samples);
    if (!(s->layered.epsilon > 0.0f && s->layered.epsilon < 1.0f))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: layered_epsilon: %g is not in (0, 1)",
                       (double)s->layered.epsilon);
    if (!(s->layered.half_res >= 0.0f && s->layered.half_res < 1.0f))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: layered_half_res: %g is not in [0, 1)",
                       (double)s->layered.half_res);
    if (s->layered.integration != NACRE_LAYERED_ANALYTIC && s->layered.integration != NACRE_LAYERED_SAMPLES)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: layered_integration: unknown (%d)",
                       (int)s->layered.integration);
    return NACRE_OK;
}

static nacre_result layered_create(nacre_context *ctx, void **state)
{
    layered_state *st = nc_calloc(ctx, 1, sizeof(*st));
    *state = st;
    if (!st)
        return NACRE_ERROR_OUT_OF_MEMORY;
    st->ctx = ctx;
    return NACRE_OK;
}

static void layered_destroy(nacre_context *ctx, void *state)
{
    layered_state *st = state;
    if (!st)
        return;
    for (uint32_t i = 0; i < st->object_capacity; i++)
        nc_layer_planes_free(ctx, &st->objects[i].planes);
    nc_free(ctx, st->objects);
    nc_free(ctx, st->media);
    nc_free(ctx, st->subsurface);
    nc_free(ctx, st->multiple);
    nc_diff_state_destroy(st->diff);
    nc_free(ctx, st->radiance);
    nc_free(ctx, st->rays);
    nc_free(ctx, st->ray_made);
    nc_free(ctx, st->ray_index);
    nc_free(ctx, st);
}

static nacre_result ensure_capacity(layered_state *st, const nacre_scene *s, size_t pixels)
{
    nacre_context *ctx = st->ctx;
    if (s->object_count > st->object_capacity) {
        layered_object *o = nc_calloc(ctx, s->object_count, sizeof(*o));
        uint8_t *sub = nc_calloc(ctx, s->object_count, 1), *mult = nc_calloc(ctx, s->object_count, 1);
        if (!o || !sub || !mult) {
            nc_free(ctx, o);
            nc_free(ctx, sub);
            nc_free(ctx, mult);
            return NACRE_ERROR_OUT_OF_MEMORY;
        }
        if (st->objects)
            memcpy(o, st->objects, st->object_capacity * sizeof(*o));
        nc_free(ctx, st->objects);
        nc_free(ctx, st->subsurface);
        nc_free(ctx, st->multiple);
        st->objects = o;
        st->subsurface = sub;
        st->multiple = mult;
        st->object_capacity = s->object_count;
    }
    if (s->material_count > st->media_capacity) {
        nc_free(ctx, st->media);
        st->media_capacity = 0;
        if (!(st->media = nc_calloc(ctx, s->material_count, sizeof(*st->media))))
            return NACRE_ERROR_OUT_OF_MEMORY;
        st->media_capacity = s->material_count;
    }
    if (pixels != st->radiance_pixels) {
        nc_free(ctx, st->radiance);
        st->radiance_pixels = 0;
        if (!(st->radiance = nc_alloc(ctx, pixels * 3 * sizeof(float))))
            return NACRE_ERROR_OUT_OF_MEMORY;
        st->radiance_pixels = pixels;
    }
    return NACRE_OK;
}

/* The planes of each translucent object, rebuilt when its geometry, the materials or epsilon
 * changed. */
static nacre_result update_planes(layered_state *st, const nacre_scene *s, float epsilon, nacre_render_stats *stats)
{
    uint64_t t0 = nc_now_us();
    uint32_t runs = 0;
    for (uint32_t i = 0; i < s->object_count; i++) {
        if (!st->subsurface[i])
            continue;
        const nc_object_rec *o = &s->objects[i];
        layered_object *lo = &st->objects[i];
        if (lo->valid && lo->scene_uid == s->uid && lo->geometry == s->versions.geometry &&
            lo->materials == s->versions.materials && lo->epsilon == epsilon)
            continue;
        lo->valid = false;
        const nacre_mesh_data *mesh = &s->meshes[o->desc.mesh.id - 1].data;
        const nc_layer_medium *med = &st->media[o->desc.material.id - 1];
        /* Eq. 8; capped at half the object's size, beyond which a plane fits nothing */
        float ext = 0;
        for (int k = 0; k < 3; k++)
            ext = fmaxf(ext, o->bounds_max[k] - o->bounds_min[k]);
        float st_first = nc_layer_medium_first_sigma_t(med);
        float radius = st_first > 0 ? -logf(epsilon) / st_first : INFINITY;
        radius = fminf(radius, 0.5f * fmaxf(ext, 1e-6f));
        nacre_result res = nc_layer_planes_build(st->ctx, o->world_positions, o->world_normals, mesh->uvs,
                                                 mesh->indices, mesh->vertex_count, mesh->triangle_count, radius,
                                                 &lo->planes);
        if (res != NACRE_OK)
            return res;
        lo->valid = true;
        lo->scene_uid = s->uid;
        lo->geometry = s->versions.geometry;
        lo->materials = s->versions.materials;
        lo->epsilon = epsilon;
        runs++;
    }
    stats->stage_us[NACRE_STAGE_PLANES] += nc_now_us() - t0;
    stats->stage_ran[NACRE_STAGE_PLANES] = runs > 0;
    stats->stage_runs[NACRE_STAGE_PLANES] = runs;
    return NACRE_OK;
}

/* The march point of G-buffer pixel i (an object with planes). */
static void march_point(const nacre_scene *s, const nc_gbuffer *gb, const layered_object *lo, size_t i,
                        const nc_shade_params *sp, nc_march_point *pt)
{
    const nc_object_rec *o = &s->objects[gb->object[i]];
    const nacre_mesh_data *mesh = &s->meshes[o->desc.mesh.id - 1].data;
    const uint32_t tri = gb->triangle[i];
    memcpy(pt->p, gb->position + 3 * i, sizeof(pt->p));
    memcpy(pt->n, gb->normal + 3 * i, sizeof(pt->n));
    memcpy(pt->uv, gb->uv + 2 * i, sizeof(pt->uv));
    if (sp->orthographic) {
        pt->v[0] = -sp->view_dir.x, pt->v[1] = -sp->view_dir.y, pt->v[2] = -sp->view_dir.z;
    } else {
        float d[3] = {sp->eye.x - pt->p[0], sp->eye.y - pt->p[1], sp->eye.z - pt->p[2]};
        float l = sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        for (int k = 0; k < 3; k++)
            pt->v[k] = l > 0 ? d[k] / l : pt->n[k];
    }
    const uint32_t *t = mesh->indices + 3 * (size_t)tri;
    const float *a = o->world_positions + 3 * (size_t)t[0], *b = o->world_positions + 3 * (size_t)t[1],
                *c = o->world_positions + 3 * (size_t)t[2];
    /* Barycentrics of P: the fitted planes are interpolated as the seed's vertex attributes. */
    float e0[3], e1[3], e2[3];
    for (int k = 0; k < 3; k++)
        e0[k] = b[k] - a[k], e1[k] = c[k] - a[k], e2[k] = pt->p[k] - a[k];
    float d00 = e0[0] * e0[0] + e0[1] * e0[1] + e0[2] * e0[2], d01 = e0[0] * e1[0] + e0[1] * e1[1] + e0[2] * e1[2];
    float d11 = e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2], d20 = e2[0] * e0[0] + e2[1] * e0[1] + e2[2] * e0[2];
    float d21 = e2[0] * e1[0] + e2[1] * e1[1] + e2[2] * e1[2];
    float den = d00 * d11 - d01 * d01;
    float w1 = den != 0 ? (d11 * d20 - d01 * d21) / den : 0, w2 = den != 0 ? (d00 * d21 - d01 * d20) / den : 0;
    float w[3] = {1 - w1 - w2, w1, w2};
    float ns[3] = {0, 0, 0}, ps[3] = {0, 0, 0};
    for (int v = 0; v < 3; v++)
        for (int k = 0; k < 3; k++) {
            ns[k] += w[v] * lo->planes.plane_n[3 * (size_t)t[v] + k];
            ps[k] += w[v] * lo->planes.plane_p[3 * (size_t)t[v] + k];
        }
    float nn = sqrtf(ns[0] * ns[0] + ns[1] * ns[1] + ns[2] * ns[2]);
    float along = nn > 0 ? (ns[0] * pt->n[0] + ns[1] * pt->n[1] + ns[2] * pt->n[2]) / nn : 0;
    if (along > 0.2f) {
        for (int k = 0; k < 3; k++)
            pt->ns[k] = ns[k] / nn, pt->ps[k] = ps[k];
    } else { /* seen from the back side, or a fold: the tangent plane */
        memcpy(pt->ns, pt->n, sizeof(pt->ns));
        memcpy(pt->ps, pt->p, sizeof(pt->ps));
    }
    if (lo->planes.grad_uv) {
        memcpy(pt->gu, lo->planes.grad_uv + 6 * (size_t)tri, sizeof(pt->gu));
        memcpy(pt->gv, lo->planes.grad_uv + 6 * (size_t)tri + 3, sizeof(pt->gv));
    } else {
        memset(pt->gu, 0, sizeof(pt->gu));
        memset(pt->gv, 0, sizeof(pt->gv));
    }
}

/* Kept rays waiting to be lit together (nc_march_rays_radiance), per thread. */
typedef struct ray_queue {
    uint32_t n;
    const nc_layer_medium *media[NC_MARCH_CHUNK];
    const void *rays[NC_MARCH_CHUNK];
    float *rgb[NC_MARCH_CHUNK];
} ray_queue;

static void flush_rays(const nacre_scene *s, const nc_raster_frame *rf, const nc_march_params *prm, ray_queue *q)
{
    if (q->n)
        nc_march_rays_radiance(q->media, q->rays, q->n, rf->shade_lights, s->light_count, prm, q->rgb);
    q->n = 0;
}

/* March G-buffer pixel i if it shows a translucent object; false if it does not. With kept rays,
 * the pixel's ray is made on its first march (a pixel is marched by one thread per frame, so its
 * slot has one writer) and queued in q to be lit with others; its radiance is written when q is
 * flushed. */
static inline bool march_pixel(const layered_state *st, const nacre_scene *s, const nc_raster_frame *rf,
                               const nc_shade_params *sp, const nc_march_params *prm, size_t i, ray_queue *q)
{
    const nc_gbuffer *gb = &rf->gbuffer;
    uint32_t o = gb->object[i];
    if (o == NC_NO_OBJECT || !st->subsurface[o])
        return false;
    const nc_layer_medium *m = &st->media[s->objects[o].desc.material.id - 1];
    float *rgb = st->radiance + 3 * i;
    const uint32_t slot = st->rays_on ? st->ray_index[i] : UINT32_MAX;
    if (slot == UINT32_MAX) {
        nc_march_point pt;
        march_point(s, gb, &st->objects[o], i, sp, &pt);
        nc_layered_radiance(m, &pt, rf->shade_lights, s->light_count, prm, rgb);
        return true;
    }
    void *ray = st->rays + (size_t)slot * st->ray_bytes;
    if (!st->ray_made[slot]) {
        nc_march_point pt;
        march_point(s, gb, &st->objects[o], i, sp, &pt);
        nc_march_ray_make(m, &pt, prm, st->ray_cap, st->ray_layers, ray);
        st->ray_made[slot] = 1;
    }
    const nc_march_ray *r = ray;
    if (r->kind == NC_MARCH_RAY_LONG) {
        nc_layered_radiance(m, &r->pt, rf->shade_lights, s->light_count, prm, rgb);
        return true;
    }
    /* The slot is read when the queue is lit: fetch it now, behind the other pixels' work. */
    for (size_t b = 0; b < st->ray_bytes; b += 64)
        __builtin_prefetch((const char *)ray + b);
    q->media[q->n] = m;
    q->rays[q->n] = ray;
    q->rgb[q->n] = rgb;
    if (++q->n == NC_MARCH_CHUNK)
        flush_rays(s, rf, prm, q);
    return true;
}

/* The kept rays for this frame: slots for the translucent pixels, all unmade, once the G-buffer,
 * the materials and the march settings are those of the previous frame. A frame after a change
 * marches from scratch: while the camera moves every frame, rays would be made and never lit
 * again (writing them made such frames slower). Without room under the memory limit (or for rays
 * too long to keep), every pixel is marched from scratch. */
static nacre_result update_rays(layered_state *st, const nacre_scene *s, const nc_gbuffer *gb,
                                const nacre_render_settings *settings, const nc_march_params *prm)
{
    const uint32_t cap = nc_march_ray_cap(prm);
    uint32_t layers = 0;
    for (uint32_t i = 0; i < s->material_count; i++)
        if (s->materials[i].type == NACRE_MATERIAL_TRANSLUCENT && st->media[i].count > layers)
            layers = st->media[i].count;
    ray_key key;
    memset(&key, 0, sizeof(key)); /* the padding too: keys are compared as bytes */
    key.scene_uid = s->uid;
    key.geometry = s->versions.geometry;
    key.camera = s->versions.camera;
    key.materials = s->versions.materials;
    key.width = gb->width;
    key.height = gb->height;
    key.samples = prm->samples;
    key.cap = cap;
    key.layers = layers;
    key.integration = (int32_t)settings->layered.integration;
    key.epsilon = settings->layered.epsilon;
    if (memcmp(&key, &st->ray_key, sizeof(key)) != 0) {
        st->ray_key = key;
        st->rays_on = st->rays_tried = false;
        return NACRE_OK;
    }
    if (st->rays_tried)
        return NACRE_OK;
    st->rays_tried = true;
    if (cap == 0)
        return NACRE_OK;
    nacre_context *ctx = st->ctx;
    const size_t pixels = (size_t)gb->width * (size_t)gb->height;
    if (!nc_reserve(ctx, &st->ray_index, &st->index_capacity, pixels, sizeof(uint32_t)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    size_t count = 0;
    for (int32_t y = 0; y < gb->height; y++) {
        uint32_t *row = st->ray_index + (size_t)y * (size_t)gb->width;
        for (int32_t x = 0; x < gb->width; x++)
            row[x] = UINT32_MAX;
        const int32_t x0 = gb->row_span ? gb->row_span[2 * y] : 0;
        const int32_t x1 = gb->row_span ? gb->row_span[2 * y + 1] : gb->width;
        for (int32_t x = x0; x < x1 && count < UINT32_MAX; x++) {
            const uint32_t o = gb->object[(size_t)y * (size_t)gb->width + (size_t)x];
            if (o != NC_NO_OBJECT && st->subsurface[o])
                row[x] = (uint32_t)count++;
        }
    }
    const size_t bytes = nc_march_ray_bytes(cap, layers);
    if (count == 0)
        return NACRE_OK;
    /* The rays are a speed-up: without room for them under the limit, march from scratch. */
    size_t total;
    const uint64_t used = atomic_load_explicit(&ctx->memory_used, memory_order_relaxed);
    if (!nc_mul_size_ok(count, bytes, &total) ||
        (total > st->rays_capacity && (total > ctx->memory_limit || used > ctx->memory_limit - total)))
        return NACRE_OK;
    if (!nc_reserve(ctx, &st->rays, &st->rays_capacity, total, 1) ||
        !nc_reserve(ctx, &st->ray_made, &st->made_capacity, count, 1))
        return NACRE_ERROR_OUT_OF_MEMORY;
    memset(st->ray_made, 0, count);
    st->rays_on = true;
    st->ray_bytes = bytes;
    st->ray_cap = cap;
    st->ray_layers = layers;
    return NACRE_OK;
}

/* Half resolution (settings.layered.half_res > 0): pixel i between marched pixels a and b (and c,
 * d when it is between four) takes their mean where they show the same object at depths and
 * normals close to its own and their radiances agree within the tolerance; else it is marched. */
static bool interpolate_pixel(const layered_state *st, const nc_gbuffer *gb, size_t i, const size_t *nb, int count,
                              float tol)
{
    const uint32_t o = gb->object[i];
    const float z = gb->view_depth[i];
    const float *n = gb->normal + 3 * i;
    float mean[3] = {0, 0, 0}, lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {0, 0, 0};
    for (int k = 0; k < count; k++) {
        const size_t q = nb[k];
        const float *nq = gb->normal + 3 * q;
        if (gb->object[q] != o || fabsf(gb->view_depth[q] - z) > 0.01f * z ||
            n[0] * nq[0] + n[1] * nq[1] + n[2] * nq[2] < 0.98f)
            return false;
        for (int c = 0; c < 3; c++) {
            const float v = st->radiance[3 * q + c];
            mean[c] += v / (float)count;
            lo[c] = v < lo[c] ? v : lo[c]; /* not fminf / fmaxf: library calls here */
            hi[c] = v > hi[c] ? v : hi[c];
        }
    }
    for (int c = 0; c < 3; c++)
        if (!(hi[c] - lo[c] <= tol * mean[c]))
            return false;
    memcpy(st->radiance + 3 * i, mean, sizeof(mean));
    return true;
}

static nacre_result march(layered_state *st, const nacre_scene *s, const nc_raster_frame *rf,
                          const nacre_render_settings *settings, const nc_shade_params *sp, nacre_render_stats *stats)
{
    uint64_t t0 = nc_now_us();
    const nc_gbuffer *gb = &rf->gbuffer;
    const nc_march_params prm = {.samples = settings->layered.samples,
                                 .analytic = settings->layered.integration == NACRE_LAYERED_ANALYTIC,
                                 .pcf_radius = settings->shadow.pcf_radius,
                                 .shadow_bias = settings->shadow.bias};
    nacre_result res = update_rays(st, s, gb, settings, &prm);
    if (res != NACRE_OK)
        return res;
    const int32_t w = gb->width, h = gb->height;
    const float tol = settings->layered.half_res;
    /* Every pixel, or (half resolution) those of even x and y first. */
    const int32_t stride = tol > 0 ? 2 : 1;
#pragma omp parallel for schedule(dynamic, 2) num_threads(nc_threads(st->ctx))
    for (int32_t y = 0; y < h; y += stride) {
        int32_t x0 = gb->row_span ? gb->row_span[2 * y] : 0, x1 = gb->row_span ? gb->row_span[2 * y + 1] : w;
        ray_queue q = {.n = 0};
        for (int32_t x = x0 + (x0 % stride); x < x1; x += stride)
            march_pixel(st, s, rf, sp, &prm, (size_t)y * (size_t)w + (size_t)x, &q);
        flush_rays(s, rf, &prm, &q);
    }
    if (stride > 1) {
#pragma omp parallel for schedule(dynamic, 4) num_threads(nc_threads(st->ctx))
        for (int32_t y = 0; y < h; y++) {
            int32_t x0 = gb->row_span ? gb->row_span[2 * y] : 0, x1 = gb->row_span ? gb->row_span[2 * y + 1] : w;
            ray_queue q = {.n = 0};
            for (int32_t x = x0; x < x1; x++) {
                const bool ox = x & 1, oy = y & 1;
                const size_t i = (size_t)y * (size_t)w + (size_t)x;
                const uint32_t o = gb->object[i];
                if (!(ox || oy) || o == NC_NO_OBJECT || !st->subsurface[o])
                    continue;
                /* The marched pixels around: 2 along a row or column, 4 at the centre of a cell. */
                size_t nb[4];
                int count = 0;
                const bool in = (!ox || x + 1 < w) && (!oy || y + 1 < h);
                if (in) {
                    const int32_t xa = x - ox, ya = y - oy, xb = x + ox, yb = y + oy;
                    nb[count++] = (size_t)ya * (size_t)w + (size_t)xa;
                    nb[count++] = (size_t)yb * (size_t)w + (size_t)xb;
                    if (ox && oy) {
                        nb[count++] = (size_t)ya * (size_t)w + (size_t)xb;
                        nb[count++] = (size_t)yb * (size_t)w + (size_t)xa;
                    }
                }
                if (!in || !interpolate_pixel(st, gb, i, nb, count, tol))
                    march_pixel(st, s, rf, sp, &prm, i, &q);
            }
            flush_rays(s, rf, &prm, &q);
        }
    }
    stats->stage_us[NACRE_STAGE_MARCH] += nc_now_us() - t0;
    stats->stage_ran[NACRE_STAGE_MARCH] = true;
    stats->stage_runs[NACRE_STAGE_MARCH] = 1;
    return NACRE_OK;
}

/* The shading pass's hook: the march's radiance in place of Lambert, plus the diffusion
 * solution's for objects with multiple scattering. */
static void layered_subsurface(const void *user, uint32_t object, const nc_shade_batch *b,
                               float out[3][NC_SHADE_BATCH])
{
    const layered_state *st = user;
    const float *r = st->radiance + 3 * b->first;
    const uint32_t padded = (b->count + 7u) & ~7u;
    for (uint32_t i = 0; i < padded; i++)
        for (int c = 0; c < 3; c++)
            out[c][i] = i < b->count ? r[3 * i + c] : 0.0f;
    if (st->diff && st->multiple[object] && st->diff->subsurface[object]) {
        float ms[3][NC_SHADE_BATCH];
        nc_diff_subsurface_radiance(st->diff, object, b, ms);
        for (uint32_t i = 0; i < b->count; i++)
            for (int c = 0; c < 3; c++)
                out[c][i] += ms[c][i];
    }
}

/* The diffusion pipeline for the objects whose material asks for multiple scattering. */
static nacre_result update_multiple(layered_state *st, nc_frame *f)
{
    const nacre_scene *s = f->scene;
    bool any = false;
    for (uint32_t i = 0; i < s->object_count; i++) {
        const nacre_material_desc *m = nc_scene_material(s, s->objects[i].desc.material);
        st->multiple[i] = st->subsurface[i] && m->layering.multiple_scattering == NACRE_MULTIPLE_SCATTERING_DIFFUSION;
        any = any || st->multiple[i];
    }
    if (!any)
        return NACRE_OK;
    nacre_result res = nc_method_diffusion.check(f->ctx, f->settings);
    if (res == NACRE_OK && f->settings->diffusion.source != NACRE_SOURCE_VOLUME)
        return nc_fail(f->ctx, NACRE_ERROR_UNSUPPORTED,
                       "render: source: face sources are not implemented for the layered method's multiple "
                       "scattering (use volume)");
    if (res == NACRE_OK && !st->diff && (res = nc_diff_state_create(f->ctx, &st->diff)) == NACRE_OK)
        st->diff->multiple_only = true;
    if (res == NACRE_OK)
        res = nc_diffusion_frame_objects(st->diff, s, f->settings, f->raster->shade_lights, s->light_count,
                                         st->multiple, f->stats);
    return res;
}

static nacre_result layered_render(void *state, nc_frame *f)
{
    layered_state *st = state;
    const nacre_scene *s = f->scene;
    nacre_result res;
    for (uint32_t i = 0; i < s->object_count; i++) {
        const nacre_material_desc *m = nc_scene_material(s, s->objects[i].desc.material);
        const nacre_mesh_data *mesh = &s->meshes[s->objects[i].desc.mesh.id - 1].data;
        if (m && m->type == NACRE_MATERIAL_TRANSLUCENT && m->layering.count > 0 && !mesh->uvs)
            return nc_fail(f->ctx, NACRE_ERROR_INVALID_ARGUMENT,
                           "render: object '%s' has a layered material but its mesh has no texture coordinates "
                           "(the layered method needs uvs for its tangent frames)",
                           s->objects[i].name ? s->objects[i].name : "(unnamed)");
    }
    if ((res = nc_raster_frame_prepare(f->raster, s, f->settings, f->stats)) != NACRE_OK)
        return res;
    const nc_gbuffer *gb = &f->raster->gbuffer;
    if ((res = ensure_capacity(st, s, (size_t)gb->width * (size_t)gb->height)) != NACRE_OK)
        return res;
    for (uint32_t i = 0; i < s->material_count; i++)
        if (s->materials[i].type == NACRE_MATERIAL_TRANSLUCENT)
            nc_layer_medium_init(s, &s->materials[i], f->settings->layered.epsilon, &st->media[i]);
    for (uint32_t i = 0; i < s->object_count; i++) {
        const nacre_material_desc *m = nc_scene_material(s, s->objects[i].desc.material);
        st->subsurface[i] = m && m->type == NACRE_MATERIAL_TRANSLUCENT;
    }
    if ((res = update_planes(st, s, f->settings->layered.epsilon, f->stats)) != NACRE_OK)
        return res;
    if ((res = update_multiple(st, f)) != NACRE_OK)
        return res;
    nc_shade_params params;
    nc_raster_frame_shade_params(f->raster, f->settings, &params);
    if ((res = march(st, s, f->raster, f->settings, &params, f->stats)) != NACRE_OK)
        return res;
    params.subsurface_object = st->subsurface;
    params.subsurface = layered_subsurface;
    params.subsurface_user = st;
    if ((res = nc_raster_frame_shade(f->raster, s, &params, f->out, f->reuse, f->stats)) != NACRE_OK)
        return res;
    f->depth = gb->view_depth;
    return NACRE_OK;
}

const nc_method nc_method_layered = {
    .name = "layered",
    .id = NACRE_METHOD_LAYERED,
    .needs_objects = true,
    .uses_raster = true,
    .stages = NC_RASTER_STAGES | (1u << NACRE_STAGE_PLANES) | (1u << NACRE_STAGE_MARCH) |
              (1u << NACRE_STAGE_VOXELIZE) | (1u << NACRE_STAGE_MEDIUM) | (1u << NACRE_STAGE_TSM) |
              (1u << NACRE_STAGE_INJECT) | (1u << NACRE_STAGE_PROPAGATE),
    .check = layered_check,
    .create = layered_create,
    .render = layered_render,
    .destroy = layered_destroy,
};
