/*
 * view_state.c: the edits of `nacre view` (camera orbit, pan and zoom, lights, materials,
 * method, diffusion settings, timeline, view modes, picking) and the frame: commit what was
 * edited, render with the one renderer the viewer keeps, and turn the linear radiance into sRGB
 * bytes for the window. Every front end of the viewer (mouse, keys, panel, script) calls these.
 */
#include "view.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

const char *const nc_view_presets[] = {"jade",  "aquamarine", "marble", "skimmilk", "wholemilk", "cream", "ketchup",
                                       "apple", "potato",     "chicken", "skin1",   "skin2",     NULL};

#define DEG (3.14159265358979f / 180.0f)

static void note(nc_view *v, const char *fmt, const char *a)
{
    snprintf(v->message, sizeof(v->message), fmt, a);
}

static void note_error(nc_view *v) { snprintf(v->message, sizeof(v->message), "%s", nacre_context_last_error(v->ctx)); }

static void edited(nc_view *v)
{
    v->dirty = true;
    v->need_render = true;
}

/* ---------------------------------------------------------------------------------------- */
/* Camera                                                                                   */
/* ---------------------------------------------------------------------------------------- */

/* Angles and distance from the camera desc: the orbit keeps these and rebuilds the position. */
static void camera_angles(nc_view *v)
{
    const float *p = v->camera.position, *t = v->camera.target;
    float d[3] = {p[0] - t[0], p[1] - t[1], p[2] - t[2]};
    v->distance = sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    v->yaw = atan2f(d[0], d[2]) / DEG;
    v->pitch = asinf(fmaxf(-1.0f, fminf(1.0f, d[1] / fmaxf(v->distance, 1e-20f)))) / DEG;
}

static void camera_apply(nc_view *v)
{
    float cy = cosf(v->yaw * DEG), sy = sinf(v->yaw * DEG), cp = cosf(v->pitch * DEG), sp = sinf(v->pitch * DEG);
    for (int i = 0; i < 3; i++)
        v->camera.position[i] = v->camera.target[i];
    v->camera.position[0] += v->distance * cp * sy;
    v->camera.position[1] += v->distance * sp;
    v->camera.position[2] += v->distance * cp * cy;
    if (nacre_scene_set_camera(v->scene, &v->camera) != NACRE_OK)
        note_error(v);
    edited(v);
}

void nc_view_orbit(nc_view *v, float dyaw, float dpitch)
{
    v->yaw = fmodf(v->yaw + dyaw, 360.0f);
    /* Short of the poles, where the up vector and the view direction would meet. */
    v->pitch = fmaxf(-89.0f, fminf(89.0f, v->pitch + dpitch));
    camera_apply(v);
}

void nc_view_pan(nc_view *v, float dx, float dy)
{
    /* Scene units per pixel at the target's distance, so the target follows the mouse. */
    float h = (float)v->fs.render.height;
    float upp = v->camera.projection == NACRE_ORTHOGRAPHIC
                    ? v->camera.ortho_height / h
                    : 2.0f * v->distance * tanf(0.5f * v->camera.fov_y * DEG) / h;
    float cy = cosf(v->yaw * DEG), sy = sinf(v->yaw * DEG), cp = cosf(v->pitch * DEG), sp = sinf(v->pitch * DEG);
    float right[3] = {cy, 0.0f, -sy};
    float up[3] = {-sp * sy, cp, -sp * cy};
    for (int i = 0; i < 3; i++)
        v->camera.target[i] += upp * (-dx * right[i] + dy * up[i]);
    camera_apply(v);
}

void nc_view_zoom(nc_view *v, float factor)
{
    if (!(factor > 0.0f) || !isfinite(factor))
        return;
    v->distance = fmaxf(v->distance * factor, 1e-3f);
    if (v->camera.projection == NACRE_ORTHOGRAPHIC)
        v->camera.ortho_height *= factor;
    camera_apply(v);
}

void nc_view_camera_home(nc_view *v)
{
    v->camera = v->camera_home;
    camera_angles(v);
    camera_apply(v);
}

/* ---------------------------------------------------------------------------------------- */
/* Method, settings, lights, materials                                                      */
/* ---------------------------------------------------------------------------------------- */

bool nc_view_set_method(nc_view *v, nacre_method method, bool check_only)
{
    if (!nacre_method_available(method)) {
        note(v, "method '%s' is not implemented yet", nacre_method_name(method));
        return false;
    }
    if (!check_only && v->fs.render.method != method) {
        v->fs.render.method = method;
        v->need_render = true;
    }
    return true;
}

static bool light_index(nc_view *v, uint32_t light)
{
    if (light < nacre_scene_light_count(v->scene))
        return true;
    snprintf(v->message, sizeof(v->message), "light %u: the scene has %u light%s", light,
             nacre_scene_light_count(v->scene), nacre_scene_light_count(v->scene) == 1 ? "" : "s");
    return false;
}

/* Edit one light: read its desc, let `field` change, store it back (the scene validates). */
static bool light_edit(nc_view *v, uint32_t light, int field, const float x[3], bool check_only)
{
    if (!light_index(v, light))
        return false;
    nacre_light_desc d;
    nacre_light handle = {light + 1};
    nacre_scene_get_light(v->scene, handle, &d);
    if (field == 0 && !(x[0] != 0.0f || x[1] != 0.0f || x[2] != 0.0f)) {
        note(v, "light direction: must not be zero%s", "");
        return false;
    }
    float *dst = field == 0 ? d.direction : field == 1 ? d.position : d.strength;
    for (int i = 0; i < 3; i++) {
        if (!isfinite(x[i]) || (field == 2 && x[i] < 0.0f)) {
            note(v, "light: values must be finite%s", field == 2 ? " and >= 0" : "");
            return false;
        }
        dst[i] = x[i];
    }
    if (check_only)
        return true;
    if (nacre_scene_set_light(v->scene, handle, &d) != NACRE_OK) {
        note_error(v);
        return false;
    }
    v->light = light;
    v->light_moved = true;
    edited(v);
    return true;
}

bool nc_view_light_direction(nc_view *v, uint32_t light, const float d[3], bool check_only)
{
    return light_edit(v, light, 0, d, check_only);
}

bool nc_view_light_position(nc_view *v, uint32_t light, const float p[3], bool check_only)
{
    return light_edit(v, light, 1, p, check_only);
}

bool nc_view_light_strength(nc_view *v, uint32_t light, const float s[3], bool check_only)
{
    return light_edit(v, light, 2, s, check_only);
}

/* Rotate a vector about world y by yaw, then tilt it by pitch towards or away from y. */
static void turn(float x[3], float dyaw, float dpitch)
{
    float r = sqrtf(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
    if (!(r > 0.0f))
        return;
    float yaw = atan2f(x[0], x[2]) + dyaw * DEG;
    float pitch = asinf(fmaxf(-1.0f, fminf(1.0f, x[1] / r))) + dpitch * DEG;
    pitch = fmaxf(-89.0f * DEG, fminf(89.0f * DEG, pitch));
    x[0] = r * cosf(pitch) * sinf(yaw);
    x[1] = r * sinf(pitch);
    x[2] = r * cosf(pitch) * cosf(yaw);
}

bool nc_view_light_turn(nc_view *v, float dyaw, float dpitch)
{
    if (!light_index(v, v->light))
        return false;
    nacre_light_desc d;
    nacre_scene_get_light(v->scene, (nacre_light){v->light + 1}, &d);
    if (d.type == NACRE_LIGHT_POINT) {
        float lo[3], hi[3], c[3], p[3];
        nacre_scene_bounds(v->scene, lo, hi);
        for (int i = 0; i < 3; i++) {
            c[i] = 0.5f * (lo[i] + hi[i]);
            p[i] = d.position[i] - c[i];
        }
        turn(p, dyaw, dpitch);
        for (int i = 0; i < 3; i++)
            p[i] += c[i];
        return nc_view_light_position(v, v->light, p, false);
    }
    turn(d.direction, dyaw, dpitch);
    return nc_view_light_direction(v, v->light, d.direction, false);
}

static bool material_index(nc_view *v, uint32_t material)
{
    if (material < v->material_count)
        return true;
    snprintf(v->message, sizeof(v->message), "material %u: the scene has %u material%s", material, v->material_count,
             v->material_count == 1 ? "" : "s");
    return false;
}

/* Base desc times the scales into the scene. */
static bool material_store(nc_view *v, uint32_t material)
{
    nc_view_material *m = &v->materials[material];
    nacre_material_desc d = m->base;
    for (int i = 0; i < 3; i++) {
        d.sigma_a[i] *= m->sigma_a_scale;
        d.sigma_s[i] *= m->sigma_s_scale;
    }
    if (nacre_scene_set_material(v->scene, (nacre_material){material + 1}, &d) != NACRE_OK) {
        note_error(v);
        return false;
    }
    v->material = material;
    edited(v);
    return true;
}

bool nc_view_material_preset(nc_view *v, uint32_t material, const char *preset, bool check_only)
{
    if (!material_index(v, material))
        return false;
    nacre_material_desc d;
    if (!nacre_material_preset(preset, &d)) {
        note(v, "unknown material preset '%s' (jade, marble, skin1, ...)", preset);
        return false;
    }
    if (check_only)
        return true;
    nacre_material_desc_per_unit(&d, nacre_scene_get_unit_mm(v->scene));
    nc_view_material *m = &v->materials[material];
    nacre_material_desc old = m->base;
    m->base = d;
    m->preset = -1;
    for (int i = 0; nc_view_presets[i]; i++)
        if (strcmp(nc_view_presets[i], preset) == 0)
            m->preset = i;
    if (!material_store(v, material)) {
        m->base = old;
        return false;
    }
    for (uint32_t k = 0; k < NACRE_MAX_LAYERS; k++)
        m->layer_depth_loaded[k] = d.layering.layers[k].depth;
    return true;
}

bool nc_view_material_field(nc_view *v, uint32_t material, const char *field, float value, bool check_only)
{
    if (!material_index(v, material))
        return false;
    nc_view_material *m = &v->materials[material];
    nc_view_material old = *m;
    if (strcmp(field, "sigma_a_scale") == 0 || strcmp(field, "sigma_s_scale") == 0) {
        if (!(value >= 0.0f) || !isfinite(value)) {
            note(v, "%s: must be a finite number >= 0", field);
            return false;
        }
        if (field[6] == 'a')
            m->sigma_a_scale = value;
        else
            m->sigma_s_scale = value;
    } else if (strcmp(field, "g") == 0) {
        if (!(value > -1.0f && value < 1.0f)) {
            note(v, "g: must be in (-1, 1)%s", "");
            return false;
        }
        m->base.g = value;
    } else if (strcmp(field, "eta") == 0) {
        if (!(value >= NACRE_ETA_MIN && value <= NACRE_ETA_MAX)) {
            note(v, "eta: must be in [0.3, 3]%s", "");
            return false;
        }
        m->base.eta = value;
    } else if (strncmp(field, "layer", 5) == 0 && field[5] >= '0' && field[5] <= '9' &&
               strcmp(field + 6, "_depth") == 0) {
        uint32_t k = (uint32_t)(field[5] - '0');
        if (k >= m->base.layering.count) {
            snprintf(v->message, sizeof(v->message), "%s: material %u has %u layer(s)", field, material,
                     m->base.layering.count);
            return false;
        }
        if (!(value >= 0.0f) || !isfinite(value)) {
            note(v, "%s: must be a finite depth >= 0 (scene units)", field);
            return false;
        }
        m->base.layering.layers[k].depth = value;
    } else if (strcmp(field, "multiple_scattering") == 0) {
        if (m->base.layering.count == 0) {
            snprintf(v->message, sizeof(v->message), "multiple_scattering: material %u is not layered", material);
            return false;
        }
        if (value != 0.0f && value != 1.0f) {
            note(v, "multiple_scattering: 0 (none) or 1 (diffusion)%s", "");
            return false;
        }
        m->base.layering.multiple_scattering =
            value == 1.0f ? NACRE_MULTIPLE_SCATTERING_DIFFUSION : NACRE_MULTIPLE_SCATTERING_NONE;
    } else {
        note(v, "unknown material field '%s' (sigma_a_scale, sigma_s_scale, g, eta, layerK_depth, "
                "multiple_scattering)", field);
        return false;
    }
    if (check_only) {
        *m = old;
        return true;
    }
    if (!material_store(v, material)) {
        *m = old;
        return false;
    }
    return true;
}

bool nc_view_voxel_resolution(nc_view *v, uint32_t res, bool check_only)
{
    if (res < 2 || res > 512) {
        snprintf(v->message, sizeof(v->message), "voxel resolution %u: must be in 2..512", res);
        return false;
    }
    if (!check_only && v->fs.render.diffusion.voxel_resolution != res) {
        v->fs.render.diffusion.voxel_resolution = res;
        v->need_render = true;
    }
    return true;
}

bool nc_view_solver(nc_view *v, nacre_diffusion_solver solver)
{
    if (v->fs.render.diffusion.solver != solver) {
        v->fs.render.diffusion.solver = solver;
        v->need_render = true;
    }
    return true;
}

/* An integer in lo..hi into *out; false with the reason in v->message. */
static bool setting_uint(nc_view *v, const char *name, const char *text, uint32_t lo, uint32_t hi, uint32_t *out)
{
    char *end = NULL;
    errno = 0;
    long x = strtol(text, &end, 10);
    if (errno || end == text || *end || x < (long)lo || x > (long)hi) {
        snprintf(v->message, sizeof(v->message), "%s '%s': expected an integer in %u..%u", name, text, lo, hi);
        return false;
    }
    *out = (uint32_t)x;
    return true;
}

bool nc_view_render_setting(nc_view *v, const char *name, const char *value, bool check_only)
{
    nacre_render_settings rs = v->fs.render;
    nacre_layered_settings *ly = &rs.layered;
    nacre_volumetrics_settings *vol = &rs.volumetrics;
    bool ok;
    if (strcmp(name, "layered_samples") == 0) {
        ok = setting_uint(v, name, value, 1, 4096, &ly->samples);
    } else if (strcmp(name, "layered_epsilon") == 0) {
        char *end = NULL;
        errno = 0;
        double e = strtod(value, &end);
        ok = !errno && end != value && !*end && e > 0.0 && e < 1.0;
        if (!ok)
            snprintf(v->message, sizeof(v->message), "layered_epsilon '%s': expected a number in (0, 1)", value);
        ly->epsilon = (float)e;
    } else if (strcmp(name, "layered_half_res") == 0) {
        char *end = NULL;
        errno = 0;
        double e = strtod(value, &end);
        ok = !errno && end != value && !*end && e >= 0.0 && e < 1.0;
        if (!ok)
            snprintf(v->message, sizeof(v->message), "layered_half_res '%s': expected a number in [0, 1)", value);
        ly->half_res = (float)e;
    } else if (strcmp(name, "layered_integration") == 0) {
        ok = nacre_layered_integration_from_name(value, &ly->integration);
        if (!ok)
            snprintf(v->message, sizeof(v->message), "layered_integration '%s': expected analytic or samples", value);
    } else if (strcmp(name, "volumetrics") == 0) {
        ok = nacre_volumetrics_from_name(value, &vol->mode);
        if (!ok)
            snprintf(v->message, sizeof(v->message), "volumetrics '%s': expected off, froxel or raymarch", value);
    } else if (strncmp(name, "froxel_", 7) == 0 && (strcmp(name + 7, "width") == 0 ||
                                                     strcmp(name + 7, "height") == 0 || strcmp(name + 7, "slices") == 0)) {
        uint32_t *dst = name[7] == 'w' ? &vol->froxel_width : name[7] == 'h' ? &vol->froxel_height : &vol->froxel_slices;
        ok = setting_uint(v, name, value, 1, 1024, dst);
        /* The renderer's bound on the grid (docs/scene-format.md), checked here so that a
         * script line fails before the window opens rather than at the frame. */
        if (ok && (uint64_t)vol->froxel_width * vol->froxel_height * vol->froxel_slices > (1u << 24)) {
            snprintf(v->message, sizeof(v->message), "%s %s: the froxel grid %ux%ux%u exceeds 2^24 froxels", name, value,
                     vol->froxel_width, vol->froxel_height, vol->froxel_slices);
            ok = false;
        }
    } else if (strcmp(name, "raymarch_steps") == 0) {
        ok = setting_uint(v, name, value, 1, 4096, &vol->raymarch_steps);
    } else if (strcmp(name, "shadow_steps") == 0) {
        ok = setting_uint(v, name, value, 1, 256, &vol->shadow_steps);
    } else if (strcmp(name, "froxel_temporal") == 0) {
        char *end = NULL;
        errno = 0;
        double e = strtod(value, &end);
        ok = !errno && end != value && !*end && e >= 0.0 && e < 1.0;
        if (ok)
            vol->temporal = (float)e;
        else
            snprintf(v->message, sizeof(v->message), "froxel_temporal '%s': expected a number in [0, 1)", value);
    } else if (strcmp(name, "single_scattering") == 0) {
        ok = nacre_single_scattering_from_name(value, &rs.diffusion.single_scattering);
        if (!ok)
            snprintf(v->message, sizeof(v->message), "single_scattering '%s': expected auto, on or off", value);
    } else if (strcmp(name, "particles") == 0) {
        ok = nacre_particles_draw_from_name(value, &rs.particles);
        if (!ok)
            snprintf(v->message, sizeof(v->message), "particles '%s': expected billboards, sprites or voxel", value);
    } else {
        snprintf(v->message, sizeof(v->message),
                 "unknown setting '%s' (layered_samples, layered_epsilon, layered_integration, volumetrics, "
                 "froxel_width, froxel_height, froxel_slices, froxel_temporal, raymarch_steps, shadow_steps, particles, "
                 "single_scattering)",
                 name);
        return false;
    }
    if (!ok || check_only)
        return ok;
    if (memcmp(&rs, &v->fs.render, sizeof(rs)) != 0) {
        v->fs.render = rs;
        v->need_render = true;
    }
    return true;
}

void nc_view_set_time(nc_view *v, double time)
{
    if (!isfinite(time) || time == v->fs.time)
        return;
    v->fs.time = time;
    edited(v);
}

void nc_view_set_mode(nc_view *v, nc_view_mode mode)
{
    if (v->mode != mode) {
        v->mode = mode;
        v->need_render = true;
    }
}

bool nc_view_resize(nc_view *v, int32_t width, int32_t height, bool check_only)
{
    if (width < 1 || height < 1 || width > 16384 || height > 16384) {
        snprintf(v->message, sizeof(v->message), "size %dx%d: width and height must be in 1..16384", (int)width,
                 (int)height);
        return false;
    }
    if (check_only || (width == v->fs.render.width && height == v->fs.render.height))
        return true;
    v->fs.render.width = width;
    v->fs.render.height = height;
    /* New sizes, new images; the renderer sees the size change and redraws everything. */
    nacre_image_free(v->ctx, &v->frame);
    nacre_image_free(v->ctx, &v->truth_frame);
    v->frame_valid = v->truth_valid = false;
    v->need_render = true;
    return true;
}

/* The camera's frame: forward f, right r, up u (from the desc, whatever its up vector). */
static void camera_basis(const nc_view *v, float f[3], float r[3], float u[3])
{
    const nacre_camera_desc *c = &v->camera;
    float n = 0.0f;
    for (int i = 0; i < 3; i++)
        f[i] = c->target[i] - c->position[i], n += f[i] * f[i];
    n = 1.0f / sqrtf(fmaxf(n, 1e-30f));
    for (int i = 0; i < 3; i++)
        f[i] *= n;
    r[0] = f[1] * c->up[2] - f[2] * c->up[1];
    r[1] = f[2] * c->up[0] - f[0] * c->up[2];
    r[2] = f[0] * c->up[1] - f[1] * c->up[0];
    n = 1.0f / sqrtf(fmaxf(r[0] * r[0] + r[1] * r[1] + r[2] * r[2], 1e-30f));
    for (int i = 0; i < 3; i++)
        r[i] *= n;
    u[0] = r[1] * f[2] - r[2] * f[1];
    u[1] = r[2] * f[0] - r[0] * f[2];
    u[2] = r[0] * f[1] - r[1] * f[0];
}

/* Half the view's height at depth z (scene units), and the pixels per unit there. */
static float half_height(const nc_view *v, float z)
{
    return v->camera.projection == NACRE_ORTHOGRAPHIC ? 0.5f * v->camera.ortho_height
                                                      : z * tanf(0.5f * v->camera.fov_y * DEG);
}

static bool project(const nc_view *v, const float p[3], float *x, float *y, float *depth)
{
    float f[3], r[3], u[3], q[3];
    camera_basis(v, f, r, u);
    for (int i = 0; i < 3; i++)
        q[i] = p[i] - v->camera.position[i];
    float z = q[0] * f[0] + q[1] * f[1] + q[2] * f[2];
    if (!(z > 0.0f) && v->camera.projection != NACRE_ORTHOGRAPHIC)
        return false;
    float hh = half_height(v, z), W = (float)v->fs.render.width, H = (float)v->fs.render.height;
    float nx = (q[0] * r[0] + q[1] * r[1] + q[2] * r[2]) / (hh * W / H);
    float ny = (q[0] * u[0] + q[1] * u[1] + q[2] * u[2]) / hh;
    *x = 0.5f * (nx + 1.0f) * W;
    *y = 0.5f * (1.0f - ny) * H;
    *depth = z;
    return isfinite(*x) && isfinite(*y);
}

static void unproject(const nc_view *v, float x, float y, float depth, float p[3])
{
    float f[3], r[3], u[3];
    camera_basis(v, f, r, u);
    float hh = half_height(v, depth), W = (float)v->fs.render.width, H = (float)v->fs.render.height;
    float a = (2.0f * x / W - 1.0f) * hh * W / H, b = (1.0f - 2.0f * y / H) * hh;
    for (int i = 0; i < 3; i++)
        p[i] = v->camera.position[i] + depth * f[i] + a * r[i] + b * u[i];
}

static bool light_handle(const nc_view *v, uint32_t light, nacre_light_desc *d, float p[3])
{
    if (light >= nacre_scene_light_count(v->scene) ||
        nacre_scene_get_light(v->scene, (nacre_light){light + 1}, d) != NACRE_OK)
        return false;
    if (d->type == NACRE_LIGHT_DIRECTIONAL)
        for (int i = 0; i < 3; i++)
            p[i] = v->camera.target[i] - 0.25f * v->distance * d->direction[i];
    else
        memcpy(p, d->position, sizeof(d->position));
    return true;
}

bool nc_view_light_handle_pixel(const nc_view *v, uint32_t light, float *x, float *y)
{
    nacre_light_desc d;
    float p[3], z;
    return light_handle(v, light, &d, p) && project(v, p, x, y, &z);
}

uint32_t nc_view_light_at(const nc_view *v, float x, float y)
{
    uint32_t best = UINT32_MAX;
    float best_d2 = NC_VIEW_HANDLE_PX * NC_VIEW_HANDLE_PX;
    for (uint32_t i = 0; i < nacre_scene_light_count(v->scene); i++) {
        float hx, hy;
        if (!nc_view_light_handle_pixel(v, i, &hx, &hy))
            continue;
        float d2 = (hx - x) * (hx - x) + (hy - y) * (hy - y);
        if (d2 <= best_d2)
            best = i, best_d2 = d2;
    }
    return best;
}

bool nc_view_light_drag(nc_view *v, uint32_t light, float x, float y)
{
    nacre_light_desc d;
    float p[3], hx, hy, z;
    if (!light_handle(v, light, &d, p) || !project(v, p, &hx, &hy, &z))
        return false;
    if (d.type != NACRE_LIGHT_DIRECTIONAL) {
        unproject(v, x, y, z, p);
        return nc_view_light_position(v, light, p, false);
    }
    /* The handle stays on its sphere about the target: the nearer crossing of the pixel's ray
     * with it, or where the ray passes closest when it misses. */
    float o[3], w[3], oc[3], R = 0.25f * v->distance, wn = 0.0f;
    unproject(v, x, y, 0.0f, o);
    unproject(v, x, y, 1.0f, w);
    for (int i = 0; i < 3; i++)
        w[i] -= o[i], wn += w[i] * w[i], oc[i] = o[i] - v->camera.target[i];
    wn = sqrtf(fmaxf(wn, 1e-30f));
    float b = 0.0f, c = -R * R;
    for (int i = 0; i < 3; i++)
        w[i] /= wn, b += oc[i] * w[i], c += oc[i] * oc[i];
    float disc = b * b - c, t = disc >= 0.0f ? -b - sqrtf(disc) : -b;
    for (int i = 0; i < 3; i++)
        p[i] = o[i] + t * w[i];
    float dir[3], n = 0.0f;
    for (int i = 0; i < 3; i++)
        dir[i] = v->camera.target[i] - p[i], n += dir[i] * dir[i];
    if (!(n > 0.0f))
        return false;
    for (int i = 0; i < 3; i++)
        dir[i] /= sqrtf(n);
    return nc_view_light_direction(v, light, dir, false);
}

void nc_view_drag(nc_view *v, float x0, float y0, float x1, float y1)
{
    uint32_t light = nc_view_light_at(v, x0, y0);
    if (light != UINT32_MAX)
        nc_view_light_drag(v, light, x1, y1);
    else
        nc_view_orbit(v, -0.3f * (x1 - x0), 0.3f * (y1 - y0));
}

bool nc_view_pick(nc_view *v, int32_t x, int32_t y)
{
    uint32_t light = nc_view_light_at(v, (float)x + 0.5f, (float)y + 0.5f);
    if (light != UINT32_MAX) {
        v->light = light;
        snprintf(v->message, sizeof(v->message), "picked light %u", light);
        return true;
    }
    uint32_t index = UINT32_MAX;
    if (nacre_renderer_pick(v->renderer, x, y, &index) != NACRE_OK) {
        note_error(v);
        return false;
    }
    v->object = index;
    if (index == UINT32_MAX) { /* background: a valid answer, nothing selected */
        note(v, "no object there%s", "");
        return true;
    }
    nacre_object_desc od;
    if (nacre_scene_get_object(v->scene, (nacre_object){index + 1}, &od) == NACRE_OK && od.material.id >= 1)
        v->material = od.material.id - 1;
    snprintf(v->message, sizeof(v->message), "picked object %u%s%s", index, od.name ? ": " : "", od.name ? od.name : "");
    return true;
}

bool nc_view_key(nc_view *v, const char *key, bool check_only)
{
    static const char *const keys[] = {"1", "2", "3", "4", "p", "space", "t", "e", "n", "left", "right",
                                       "up", "down", "[", "]", "r", NULL};
    int k = -1;
    for (int i = 0; keys[i]; i++)
        if (strcmp(keys[i], key) == 0)
            k = i;
    if (k < 0) {
        note(v, "unknown key '%s' (1-4, p, space, t, e, n, left, right, up, down, [, ], r)", key);
        return false;
    }
    if (k <= 3)
        return nc_view_set_method(v, (nacre_method)k, check_only);
    if (check_only)
        return true;
    uint32_t lights = nacre_scene_light_count(v->scene);
    switch (k) {
    case 4: case 5: v->playing = !v->playing; break;
    case 6: nc_view_set_mode(v, v->mode == NC_VIEW_WIPE ? NC_VIEW_NORMAL : NC_VIEW_WIPE); break;
    case 7: nc_view_set_mode(v, v->mode == NC_VIEW_ERROR ? NC_VIEW_NORMAL : NC_VIEW_ERROR); break;
    case 8: nc_view_set_mode(v, NC_VIEW_NORMAL); break;
    case 9: return nc_view_light_turn(v, -5.0f, 0.0f);
    case 10: return nc_view_light_turn(v, 5.0f, 0.0f);
    case 11: return nc_view_light_turn(v, 0.0f, 5.0f);
    case 12: return nc_view_light_turn(v, 0.0f, -5.0f);
    case 13: if (lights) v->light = (v->light + lights - 1) % lights; break;
    case 14: if (lights) v->light = (v->light + 1) % lights; break;
    case 15: nc_view_camera_home(v); break;
    default: break;
    }
    return true;
}

/* ---------------------------------------------------------------------------------------- */
/* Life and frames                                                                          */
/* ---------------------------------------------------------------------------------------- */

bool nc_view_init(nc_view *v, nacre_context *ctx, nacre_scene *scene, const nacre_scene_file_settings *fs)
{
    memset(v, 0, sizeof(*v));
    v->ctx = ctx;
    v->scene = scene;
    v->fs = *fs;
    v->pathtrace_spp = 1;
    v->time_max = 10.0;
    v->wipe = 0.5f;
    v->mean_rel_err = -1.0;
    v->object = UINT32_MAX;
    v->dirty = v->need_render = true;
    nacre_scene_get_camera(scene, &v->camera);
    v->camera_home = v->camera;
    camera_angles(v);
    v->material_count = nacre_scene_material_count(scene);
    v->materials = calloc(v->material_count ? v->material_count : 1, sizeof(*v->materials));
    if (!v->materials) {
        note(v, "out of memory%s", "");
        return false;
    }
    for (uint32_t i = 0; i < v->material_count; i++) {
        nacre_scene_get_material(scene, (nacre_material){i + 1}, &v->materials[i].base);
        v->materials[i].sigma_a_scale = v->materials[i].sigma_s_scale = 1.0f;
        v->materials[i].preset = -1;
        for (uint32_t k = 0; k < NACRE_MAX_LAYERS; k++)
            v->materials[i].layer_depth_loaded[k] = v->materials[i].base.layering.layers[k].depth;
    }
    if (nacre_renderer_create(ctx, &v->renderer) != NACRE_OK || nacre_renderer_create(ctx, &v->truth) != NACRE_OK) {
        note_error(v);
        return false;
    }
    return true;
}

void nc_view_free(nc_view *v)
{
    nacre_image_free(v->ctx, &v->frame);
    nacre_image_free(v->ctx, &v->truth_frame);
    nacre_renderer_destroy(v->renderer);
    nacre_renderer_destroy(v->truth);
    nacre_scene_destroy(v->scene);
    free(v->materials);
    memset(v, 0, sizeof(*v));
}

static void account(nc_view *v, const nacre_render_stats *st)
{
    for (int i = 0; i < NACRE_STAGE_COUNT; i++) {
        v->stage_us[i] += st->stage_us[i];
        v->stage_runs[i] += st->stage_runs[i];
    }
}

/* Relative error of a value against the path tracer's. The floor keeps the few samples of
 * the first frames, where dark pixels hold tiny non-zero values, from dividing by them: below
 * it the error counts as absolute. The false colour uses the same measure. */
#define REL_FLOOR 0.01f

static inline float rel_err(float a, float t) { return fabsf(a - t) / fmaxf(fabsf(t), REL_FLOOR); }

/* Mean relative error over all pixels and channels (shown in the panel and the JSON line). */
static double mean_rel_err(const nacre_image *a, const nacre_image *t)
{
    double sum = 0.0;
    for (int32_t y = 0; y < a->height; y++) {
        const float *pa = a->pixels + (size_t)y * a->stride, *pt = t->pixels + (size_t)y * t->stride;
        for (int32_t x = 0; x < 3 * a->width; x++)
            sum += rel_err(pa[x], pt[x]);
    }
    return sum / (3.0 * (double)a->width * (double)a->height);
}

/* The progressive path tracer of the same state, for the wipe and error views: one more pass
 * per frame, accumulated while nothing changes (the renderer restarts on any edit). */
static bool render_truth(nc_view *v)
{
    nacre_render_settings ts = v->fs.render;
    ts.method = NACRE_METHOD_PATHTRACE;
    ts.pathtrace.spp = v->pathtrace_spp;
    ts.pathtrace.accumulate = true;
    ts.reuse_output = false;
    if (!nacre_method_available(NACRE_METHOD_PATHTRACE)) {
        note(v, "the path tracer is not in this build (Embree missing)%s", "");
        return false;
    }
    if (nacre_renderer_render(v->truth, v->scene, &ts, &v->truth_frame, &v->truth_stats) != NACRE_OK) {
        note_error(v);
        return false;
    }
    v->truth_valid = true;
    v->mean_rel_err = v->frame_valid ? mean_rel_err(&v->frame, &v->truth_frame) : -1.0;
    return true;
}

static bool render_frame(nc_view *v, bool coarse);

bool nc_view_frame(nc_view *v, double dt)
{
    v->frames++;
    if (v->playing) {
        double step = v->fixed_step > 0 ? v->fixed_step : dt;
        double t = v->fs.time + step;
        nc_view_set_time(v, t > v->time_max ? 0.0 : t);
    }
    nacre_method_info info;
    nacre_method_info_get(v->fs.render.method, &info);
    /* A path tracer that accumulates, or a truth view, improves every frame. */
    bool progressive = info.stochastic || v->mode != NC_VIEW_NORMAL;
    /* Interactive light edits: this frame's settings, and the refinement once the light rests. */
    bool coarse = v->interactive && v->light_moved;
    if (v->light_moved)
        v->still_frames = 0;
    else if (v->still_frames < NC_VIEW_REFINE_FRAMES)
        v->still_frames++;
    v->light_moved = false;
    if (v->refine_due && v->still_frames >= NC_VIEW_REFINE_FRAMES)
        v->need_render = true;
    if (!v->need_render && !progressive)
        return true;
    return render_frame(v, coarse);
}

bool nc_view_refine(nc_view *v)
{
    if (!v->refine_due)
        return true;
    v->need_render = true;
    return render_frame(v, false);
}

static bool render_frame(nc_view *v, bool coarse)
{
    if (v->dirty) {
        if (nacre_scene_commit(v->scene, v->fs.time) != NACRE_OK) {
            note_error(v);
            return false;
        }
        v->dirty = false;
    }
    nacre_render_settings rs = v->fs.render;
    /* Only a tolerance looser than the scene's changes anything: the solve is the one cost a
     * light edit has that a looser stop cuts without moving the image (docs/performance.md:
     * at most 0.04% of a pixel in the demo against the solve to 1e-4). */
    coarse = coarse && rs.method == NACRE_METHOD_DIFFUSION && rs.diffusion.solver == NACRE_SOLVER_MULTIGRID &&
             rs.diffusion.tolerance < NC_VIEW_LIGHT_TOLERANCE;
    if (coarse)
        rs.diffusion.tolerance = NC_VIEW_LIGHT_TOLERANCE;
    v->refine_due = coarse;
    rs.reuse_output = v->frame_valid; /* the viewer never writes into the frame it shows */
    rs.pathtrace.accumulate = true;
    rs.pathtrace.spp = v->pathtrace_spp;
    if (nacre_renderer_render(v->renderer, v->scene, &rs, &v->frame, &v->stats) != NACRE_OK) {
        note_error(v);
        v->need_render = false; /* say it once; the next edit tries again */
        return false;
    }
    v->frame_valid = true;
    v->rendered++;
    account(v, &v->stats);
    v->need_render = false;
    if (v->mode != NC_VIEW_NORMAL && !render_truth(v))
        return false;
    return true;
}

/* Linear radiance to sRGB bytes through a table: a pow() per channel would cost more than the
 * whole shading pass at 640x480. 4096 steps over [0, 1] are finer than 8-bit sRGB's darkest. */
static uint8_t srgb_table[4097];

static void srgb_init(void)
{
    if (srgb_table[4096])
        return;
    for (int i = 0; i <= 4096; i++) {
        double x = i / 4096.0;
        double s = x <= 0.0031308 ? 12.92 * x : 1.055 * pow(x, 1.0 / 2.4) - 0.055;
        srgb_table[i] = (uint8_t)lrint(fmin(fmax(s, 0.0), 1.0) * 255.0);
    }
}

static inline uint8_t to_srgb(float x, float scale)
{
    float y = x * scale;
    if (!(y > 0.0f))
        return 0;
    return y >= 1.0f ? 255 : srgb_table[(int)(y * 4096.0f + 0.5f)];
}

/* Relative error to a colour: black (below 0.1%) through blue, green, yellow to red (100% and
 * more), on a log scale, so both a good and a bad method show structure. */
static void error_colour(float rel, uint8_t *out)
{
    float t = rel > 1e-3f ? fminf(1.0f, log10f(rel / 1e-3f) / 3.0f) : 0.0f;
    static const float stops[5][3] = {{0, 0, 0}, {0, 0, 1}, {0, 1, 0}, {1, 1, 0}, {1, 0, 0}};
    float s = t * 4.0f;
    int i = s >= 4.0f ? 3 : (int)s;
    float f = s - (float)i;
    for (int c = 0; c < 3; c++)
        out[c] = (uint8_t)lrintf(255.0f * (stops[i][c] + f * (stops[i + 1][c] - stops[i][c])));
}

void nc_view_display(nc_view *v, uint8_t *rgba)
{
    srgb_init();
    int32_t w = v->fs.render.width, h = v->fs.render.height;
    float scale = exp2f(v->fs.exposure);
    bool truth = v->mode != NC_VIEW_NORMAL && v->truth_valid;
    int32_t split = v->mode == NC_VIEW_WIPE ? (int32_t)lrintf(v->wipe * (float)w) : w;
    /* Rows in parallel: single-threaded, this was a tenth of a camera-only frame at 640x480. */
#pragma omp parallel for schedule(static)
    for (int32_t y = 0; y < h; y++) {
        const float *a = v->frame_valid ? v->frame.pixels + (size_t)y * v->frame.stride : NULL;
        const float *t = truth ? v->truth_frame.pixels + (size_t)y * v->truth_frame.stride : NULL;
        uint8_t *o = rgba + (size_t)y * (size_t)w * 4;
        for (int32_t x = 0; x < w; x++, o += 4) {
            o[3] = 255;
            if (!a) {
                o[0] = o[1] = o[2] = 0;
            } else if (v->mode == NC_VIEW_ERROR && t) {
                float e = 0.0f;
                for (int c = 0; c < 3; c++)
                    e += rel_err(a[3 * x + c], t[3 * x + c]);
                error_colour(e / 3.0f, o);
            } else {
                const float *src = (t && x >= split) ? t : a;
                for (int c = 0; c < 3; c++)
                    o[c] = to_srgb(src[3 * x + c], scale);
                if (t && x == split) /* the wipe line */
                    o[0] = o[1] = o[2] = 255;
            }
        }
    }
}

bool nc_view_save_image(nc_view *v, const char *path)
{
    if (!nc_view_refine(v))
        return false;
    if (!v->frame_valid) {
        note(v, "no frame to save yet%s", "");
        return false;
    }
    nacre_image_write_options wo = {.exposure = v->fs.exposure, .exr_type = NACRE_EXR_FLOAT};
    if (nacre_image_write(v->ctx, &v->frame, path, &wo) != NACRE_OK) {
        note_error(v);
        return false;
    }
    note(v, "saved %s", path);
    return true;
}

bool nc_view_save_scene(nc_view *v, const char *path)
{
    /* The committed state is what is on screen; fs holds the current settings and time. */
    if (nacre_scene_save_file(v->scene, &v->fs, path) != NACRE_OK) {
        note_error(v);
        return false;
    }
    note(v, "saved %s", path);
    return true;
}
