/*
 * scene.c: building a scene from code (meshes, materials, objects, lights, camera), the desc
 * defaults, the measured-material presets, deformers, and the commit that turns rest-pose
 * meshes into world-space geometry for the render stages.
 *
 * Deformers (twist, bend, non-uniform scale) act on the mesh's own coordinates before the
 * object transform; the seed (Blanchard 2012, section 5.2.3) deforms meshes every frame and
 * looks materials up in rest-pose coordinates, which the commit keeps available (the mesh data).
 * Normals follow the deformation through the cofactor of its Jacobian (estimated by central
 * differences), so any deformer chain is handled by one mechanism.
 *
 * Units: scene units (millimetres by default); angles in degrees at the API, radians inside.
 */
#include "scene/scene.h"

#include <math.h>
#include <string.h>

/* ---------------------------------------------------------------------------------------- */
/* Desc defaults and names                                                                  */
/* ---------------------------------------------------------------------------------------- */

nacre_material_desc nacre_material_desc_defaults(nacre_material_type type)
{
    nacre_material_desc d;
    memset(&d, 0, sizeof(d));
    if (type == NACRE_MATERIAL_TRANSLUCENT) {
        nacre_material_preset("jade", &d);
        return d;
    }
    d.type = NACRE_MATERIAL_OPAQUE;
    for (int i = 0; i < 3; i++) {
        d.diffuse[i] = 0.8f;
        d.specular[i] = 0.04f;
    }
    d.shininess = 64.0f;
    d.g = 0.0f;
    d.eta = 1.5f;
    return d;
}

/* Jensen, Marschner, Levoy, Hanrahan 2001, "A Practical Model for Subsurface Light Transport",
 * figure 5: reduced scattering sigma_s' and absorption sigma_a in mm^-1 (R, G, B), eta = 1.3.
 * With g = 0, sigma_s = sigma_s'. Jade and aquamarine follow Blanchard 2012 section 5.2.1,
 * whose RGB triplets name the colour the gem lets through ((0.1, 1, 0.1) for jade); we turn
 * them into absorption 0.1 mm^-1 * (1 - 0.9 * colour) so the named colour is the one that
 * survives, with a scattering coefficient that makes a few-millimetre mean free path. */
typedef struct preset {
    const char *name;
    float sigma_s[3];
    float sigma_a[3];
    float eta;
} preset;

static const preset presets[] = {
    {"apple", {2.29f, 2.39f, 1.97f}, {0.0030f, 0.0034f, 0.046f}, 1.3f},
    {"chicken1", {0.15f, 0.21f, 0.38f}, {0.015f, 0.077f, 0.19f}, 1.3f},
    {"chicken2", {0.19f, 0.25f, 0.32f}, {0.018f, 0.088f, 0.20f}, 1.3f},
    {"cream", {7.38f, 5.47f, 3.15f}, {0.0002f, 0.0028f, 0.0163f}, 1.3f},
    {"ketchup", {0.18f, 0.07f, 0.03f}, {0.061f, 0.97f, 1.45f}, 1.3f},
    {"marble", {2.19f, 2.62f, 3.00f}, {0.0021f, 0.0041f, 0.0071f}, 1.3f},
    {"potato", {0.68f, 0.70f, 0.55f}, {0.0024f, 0.0090f, 0.12f}, 1.3f},
    {"skimmilk", {0.70f, 1.22f, 1.90f}, {0.0014f, 0.0025f, 0.0142f}, 1.3f},
    {"skin1", {0.74f, 0.88f, 1.01f}, {0.032f, 0.17f, 0.48f}, 1.3f},
    {"skin2", {1.09f, 1.59f, 1.79f}, {0.013f, 0.070f, 0.145f}, 1.3f},
    {"wholemilk", {2.55f, 3.21f, 3.77f}, {0.0011f, 0.0024f, 0.014f}, 1.3f},
    {"jade", {1.0f, 1.0f, 1.0f}, {0.091f, 0.010f, 0.091f}, 1.6f},
    {"aquamarine", {0.5f, 0.5f, 0.5f}, {0.1f, 0.01f, 0.01f}, 1.57f},
};

bool nacre_material_preset(const char *name, nacre_material_desc *out)
{
    if (!name || !out)
        return false;
    const char *lookup = strcmp(name, "chicken") == 0 ? "chicken1" : name;
    for (size_t i = 0; i < sizeof(presets) / sizeof(presets[0]); i++) {
        if (strcmp(presets[i].name, lookup) != 0)
            continue;
        memset(out, 0, sizeof(*out));
        out->type = NACRE_MATERIAL_TRANSLUCENT;
        for (int c = 0; c < 3; c++) {
            out->sigma_s[c] = presets[i].sigma_s[c];
            out->sigma_a[c] = presets[i].sigma_a[c];
            out->specular[c] = 0.04f;
            out->diffuse[c] = 0.8f;
        }
        out->shininess = 128.0f;
        out->g = 0.0f;
        out->eta = presets[i].eta;
        return true;
    }
    if (strcmp(name, "fish") == 0) {
        /* Francois et al. 2006 (seed 001), table 1, sigma in mm^-1 (R, G, B): dermis and blood
         * layers over the organs (the core); sigma_a = sigma_t - sigma_s. The seed gives the
         * layers' depths only as its hand-painted texture: 0.5 mm of dermis and blood down to
         * 1.5 mm here, meant to be scaled by a depth map (`nacre layers --kind veins`). */
        static const float ss[3][3] = {{2.0f, 1.0f, 1.0f}, {6.0f, 3.0f, 2.0f}, {1.0f, 1.0f, 2.0f}};
        static const float st[3][3] = {{2.6f, 1.6f, 1.6f}, {6.6f, 3.6f, 2.6f}, {1.5f, 1.5f, 2.5f}};
        static const float g[3] = {0.25f, 0.40f, 0.80f}, depth[2] = {0.5f, 1.5f};
        memset(out, 0, sizeof(*out));
        out->type = NACRE_MATERIAL_TRANSLUCENT;
        for (int c = 0; c < 3; c++) {
            out->sigma_s[c] = ss[2][c];
            out->sigma_a[c] = st[2][c] - ss[2][c];
            out->specular[c] = 0.04f;
            out->diffuse[c] = 0.8f;
            for (int j = 0; j < 2; j++) {
                out->layering.layers[j].sigma_s[c] = ss[j][c];
                out->layering.layers[j].sigma_a[c] = st[j][c] - ss[j][c];
            }
        }
        for (int j = 0; j < 2; j++) {
            out->layering.layers[j].g = g[j];
            out->layering.layers[j].depth = depth[j];
        }
        out->layering.count = 2;
        out->shininess = 128.0f;
        out->g = g[2];
        out->eta = 1.33f;
        return true;
    }
    return false;
}

nacre_deformer nacre_deformer_defaults(nacre_deformer_type type)
{
    nacre_deformer d;
    memset(&d, 0, sizeof(d));
    d.type = type;
    d.axis[1] = 1.0f;
    d.direction[0] = 1.0f;
    d.length = 1.0f;
    d.scale[0] = d.scale[1] = d.scale[2] = 1.0f;
    return d;
}

nacre_object_desc nacre_object_desc_defaults(void)
{
    nacre_object_desc d;
    memset(&d, 0, sizeof(d));
    d.transform.scale[0] = d.transform.scale[1] = d.transform.scale[2] = 1.0f;
    d.cast_shadows = true;
    d.double_sided = false;
    return d;
}

nacre_light_desc nacre_light_desc_defaults(nacre_light_type type)
{
    nacre_light_desc d;
    memset(&d, 0, sizeof(d));
    d.type = type;
    d.direction[0] = -0.3f;
    d.direction[1] = -1.0f;
    d.direction[2] = -0.4f;
    d.position[1] = 5.0f;
    for (int i = 0; i < 3; i++)
        d.strength[i] = type == NACRE_LIGHT_DIRECTIONAL ? 3.0f : 50.0f;
    d.inner_angle = 20.0f;
    d.outer_angle = 30.0f;
    d.angular_radius = 0.27f;
    d.cast_shadows = true;
    return d;
}

nacre_camera_desc nacre_camera_desc_defaults(void)
{
    nacre_camera_desc d;
    memset(&d, 0, sizeof(d));
    d.projection = NACRE_PERSPECTIVE;
    d.position[1] = 1.0f;
    d.position[2] = 5.0f;
    d.up[1] = 1.0f;
    d.fov_y = 40.0f;
    d.ortho_height = 2.0f;
    return d;
}


/* ---------------------------------------------------------------------------------------- */
/* Validation helpers                                                                       */
/* ---------------------------------------------------------------------------------------- */

static bool finite3(const float *v) { return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]); }
static bool nonneg3(const float *v) { return finite3(v) && v[0] >= 0 && v[1] >= 0 && v[2] >= 0; }
static bool nonzero3(const float *v) { return finite3(v) && (v[0] != 0 || v[1] != 0 || v[2] != 0); }

/* Medium 2 and the pattern's parameters (translucent materials and fogs read them). `what` names
 * the owner in messages. A fog's medium 2 may be empty (clear air, `clear_ok`); a material's must
 * extinguish in every channel (the diffusion solver divides by sigma_t). */
static nacre_result check_pattern(const nacre_scene *s, const nacre_medium_pattern *p, const char *what,
                                  bool clear_ok, bool temperature_ok)
{
    nacre_context *ctx = s->ctx;
    if (p->blackbody && !(temperature_ok && p->type == NACRE_PATTERN_VOLUME))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "%s: pattern.blackbody: only for a volume as a fog's emission_pattern", what);
    if (p->blackbody && !(isfinite(p->kelvin_scale) && p->kelvin_scale > 0))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: pattern.kelvin_scale: must be finite and > 0", what);
    if (p->type < NACRE_PATTERN_NONE || p->type > NACRE_PATTERN_VOLUME)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: pattern.type: unknown (%d)", what, (int)p->type);
    if (p->type == NACRE_PATTERN_NONE)
        return NACRE_OK;
    if (p->type != NACRE_PATTERN_VOLUME) {
        if (!nonneg3(p->sigma_a2))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: pattern.sigma_a2: must be finite and >= 0", what);
        if (!nonneg3(p->sigma_s2))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: pattern.sigma_s2: must be finite and >= 0", what);
        for (int c = 0; c < 3 && !clear_ok; c++)
            if (p->sigma_a2[c] + p->sigma_s2[c] <= 0)
                return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                               "%s: pattern.sigma_a2 + sigma_s2: must be positive in every channel", what);
        /* Cells far below float resolution of typical coordinates make no sense either. */
        if (!(isfinite(p->cell_size) && p->cell_size > 0))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: pattern.cell_size: must be finite and > 0", what);
    }
    if (p->type == NACRE_PATTERN_RANDOM_MIX && !(p->fraction >= 0 && p->fraction <= 1))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: pattern.fraction: must be in [0, 1]", what);
    if (p->type == NACRE_PATTERN_NOISE && (p->octaves < 1 || p->octaves > 12))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: pattern.octaves: must be in 1..12", what);
    if (p->type == NACRE_PATTERN_VOLUME && !nc_scene_volume(s, p->volume))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: pattern.volume: invalid handle %u", what, p->volume.id);
    return NACRE_OK;
}

/* Layers above a translucent core (nacre_layering). */
static nacre_result check_layering(const nacre_scene *s, const nacre_layering *l)
{
    nacre_context *ctx = s->ctx;
    if (l->count > NACRE_MAX_LAYERS)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: layers: at most %d (got %u)",
                       NACRE_MAX_LAYERS, l->count);
    if (l->multiple_scattering != NACRE_MULTIPLE_SCATTERING_NONE &&
        l->multiple_scattering != NACRE_MULTIPLE_SCATTERING_DIFFUSION)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: multiple_scattering: unknown (%d)",
                       (int)l->multiple_scattering);
    if (l->count == 0)
        return NACRE_OK;
    for (uint32_t j = 0; j < l->count; j++) {
        const nacre_layer *y = &l->layers[j];
        if (!nonneg3(y->sigma_a))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: layers[%u].sigma_a: must be finite and >= 0", j);
        if (!nonneg3(y->sigma_s))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: layers[%u].sigma_s: must be finite and >= 0", j);
        for (int c = 0; c < 3; c++)
            if (y->sigma_a[c] + y->sigma_s[c] <= 0)
                return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                               "material: layers[%u].sigma_a + sigma_s: must be positive in every channel", j);
        if (!(isfinite(y->g) && y->g > -1 && y->g < 1))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: layers[%u].g: must be in (-1, 1)", j);
        if (!(isfinite(y->depth) && y->depth >= 0))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: layers[%u].depth: must be finite and >= 0", j);
    }
    if (l->depth_map.id != 0) {
        const nc_texture_rec *t = nc_scene_texture(s, l->depth_map);
        if (!t)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: depth_map: invalid handle %u", l->depth_map.id);
        if ((uint32_t)t->channels < l->count)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                           "material: depth_map: %d channel(s) for %u layers (one channel per layer)",
                           t->channels, l->count);
    }
    return NACRE_OK;
}

static nacre_result check_material(const nacre_scene *s, const nacre_material_desc *d)
{
    nacre_context *ctx = s->ctx;
    if (d->type != NACRE_MATERIAL_OPAQUE && d->type != NACRE_MATERIAL_TRANSLUCENT)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: type: unknown (%d)", (int)d->type);
    if (!nonneg3(d->diffuse))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: diffuse: must be finite and >= 0");
    if (!nonneg3(d->specular))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: specular: must be finite and >= 0");
    if (!(isfinite(d->shininess) && d->shininess >= 0))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: shininess: must be finite and >= 0");
    if (d->diffuse_map.id != 0) {
        if (d->type != NACRE_MATERIAL_OPAQUE)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                           "material: diffuse_map: only opaque materials have a diffuse colour");
        if (!nc_scene_texture(s, d->diffuse_map))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: diffuse_map: invalid handle %u",
                           d->diffuse_map.id);
    }
    if (d->type == NACRE_MATERIAL_TRANSLUCENT) {
        if (!nonneg3(d->sigma_a))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: sigma_a: must be finite and >= 0");
        if (!nonneg3(d->sigma_s))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: sigma_s: must be finite and >= 0");
        for (int c = 0; c < 3; c++)
            if (d->sigma_a[c] + d->sigma_s[c] <= 0)
                return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                               "material: sigma_a + sigma_s: must be positive in every channel");
        if (!(isfinite(d->g) && d->g > -1 && d->g < 1))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: g: must be in (-1, 1)");
        if (!(d->eta >= NACRE_ETA_MIN && d->eta <= NACRE_ETA_MAX))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: eta: must be in [%g, %g] (got %g)",
                           NACRE_ETA_MIN, NACRE_ETA_MAX, d->eta);
        nacre_result r = check_pattern(s, &d->pattern, "material", false, false);
        if (r == NACRE_OK)
            r = check_layering(s, &d->layering);
        if (r != NACRE_OK)
            return r;
    }
    return NACRE_OK;
}

static nacre_result check_deformer(nacre_context *ctx, const nacre_deformer *d, uint32_t i)
{
    if (d->type < NACRE_DEFORM_NONE || d->type > NACRE_DEFORM_BEND)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "object: deformers[%u]: unknown type", i);
    if (!finite3(d->center) || !finite3(d->scale) || !finite3(d->scale_rate))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "object: deformers[%u]: non-finite value", i);
    if (!isfinite(d->angle) || !isfinite(d->angle_rate))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "object: deformers[%u]: angle: must be finite", i);
    if (d->type == NACRE_DEFORM_TWIST || d->type == NACRE_DEFORM_BEND) {
        if (!nonzero3(d->axis))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "object: deformers[%u]: axis: must be a non-zero vector", i);
        if (!(isfinite(d->length) && d->length > 0))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "object: deformers[%u]: length: must be positive", i);
    }
    if (d->type == NACRE_DEFORM_BEND) {
        nc_vec3 a = nc_normalize(nc_v3a(d->axis));
        nc_vec3 b = nc_v3a(d->direction);
        if (!finite3(d->direction) || nc_length(nc_sub(b, nc_scale(a, nc_dot(a, b)))) < 1e-6f)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                           "object: deformers[%u]: direction: must not be parallel to the axis", i);
    }
    return NACRE_OK;
}

static nacre_result check_light(nacre_context *ctx, const nacre_light_desc *d)
{
    if (d->type < NACRE_LIGHT_DIRECTIONAL || d->type > NACRE_LIGHT_SPOT)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "light: type: unknown (%d)", (int)d->type);
    if (!nonneg3(d->strength))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "light: strength: must be finite and >= 0");
    if (d->type != NACRE_LIGHT_POINT && !nonzero3(d->direction))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "light: direction: must be a non-zero vector");
    if (d->type != NACRE_LIGHT_DIRECTIONAL && !finite3(d->position))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "light: position: must be finite");
    if (d->type == NACRE_LIGHT_SPOT) {
        if (!(isfinite(d->outer_angle) && d->outer_angle > 0 && d->outer_angle < 90))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "light: outer_angle: must be in (0, 90) degrees");
        if (!(isfinite(d->inner_angle) && d->inner_angle >= 0 && d->inner_angle <= d->outer_angle))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "light: inner_angle: must be in [0, outer_angle]");
        if (d->falloff < NACRE_SPOT_FALLOFF_SMOOTH || d->falloff > NACRE_SPOT_FALLOFF_GLTF)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "light: falloff: unknown (%d)", (int)d->falloff);
    }
    if (!(isfinite(d->radius) && d->radius >= 0))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "light: radius: must be finite and >= 0");
    if (!(isfinite(d->angular_radius) && d->angular_radius >= 0 && d->angular_radius < 90))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "light: angular_radius: must be in [0, 90) degrees");
    return NACRE_OK;
}

static nacre_result check_camera(nacre_context *ctx, const nacre_camera_desc *d)
{
    if (d->projection != NACRE_PERSPECTIVE && d->projection != NACRE_ORTHOGRAPHIC)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "camera: type: unknown (%d)", (int)d->projection);
    if (!finite3(d->position) || !finite3(d->target))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "camera: position/target: must be finite");
    if (nc_length(nc_sub(nc_v3a(d->target), nc_v3a(d->position))) <= 0)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "camera: target: must differ from position");
    if (!nonzero3(d->up))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "camera: up: must be a non-zero vector");
    if (d->projection == NACRE_PERSPECTIVE && !(isfinite(d->fov_y) && d->fov_y > 0 && d->fov_y < 180))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "camera: fov: must be in (0, 180) degrees");
    if (d->projection == NACRE_ORTHOGRAPHIC && !(isfinite(d->ortho_height) && d->ortho_height > 0))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "camera: height: must be positive");
    if (!(isfinite(d->near_clip) && d->near_clip >= 0) || !(isfinite(d->far_clip) && d->far_clip >= 0))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "camera: near/far: must be finite and >= 0");
    if (d->near_clip > 0 && d->far_clip > 0 && d->far_clip <= d->near_clip)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "camera: far: must exceed near");
    return NACRE_OK;
}

/* Grow a handle array by one slot; returns the new slot or NULL. */
static void *grow(nacre_context *ctx, void **array, uint32_t *count, uint32_t *capacity, size_t elem)
{
    if (*count == UINT32_MAX - 1) {
        nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "scene: too many elements");
        return NULL;
    }
    if (*count == *capacity) {
        uint32_t cap = *capacity ? *capacity * 2 : 8;
        void *p = nc_realloc(ctx, *array, (size_t)*capacity * elem, (size_t)cap * elem);
        if (!p)
            return NULL;
        *array = p;
        *capacity = cap;
    }
    char *slot = (char *)*array + (size_t)*count * elem;
    memset(slot, 0, elem);
    return slot;
}

/* ---------------------------------------------------------------------------------------- */
/* Scene lifetime and edits                                                                 */
/* ---------------------------------------------------------------------------------------- */

nacre_result nacre_scene_create(nacre_context *ctx, nacre_scene **out)
{
    if (!ctx || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    *out = NULL;
    nacre_scene *s = nc_calloc(ctx, 1, sizeof(*s));
    if (!s)
        return NACRE_ERROR_OUT_OF_MEMORY;
    s->ctx = ctx;
    pthread_mutex_lock(&ctx->lock);
    s->uid = ++ctx->scene_serial;
    pthread_mutex_unlock(&ctx->lock);
    s->camera = nacre_camera_desc_defaults();
    s->environment[0] = s->environment[1] = s->environment[2] = 0.05f;
    s->unit_mm = 1.0f;
    s->versions.geometry = 1;
    *out = s;
    return NACRE_OK;
}

void nacre_scene_destroy(nacre_scene *s)
{
    if (!s)
        return;
    nacre_context *ctx = s->ctx;
    for (uint32_t i = 0; i < s->mesh_count; i++) {
        nacre_mesh_data_free(ctx, &s->meshes[i].data);
        nc_free(ctx, s->meshes[i].source_path);
    }
    for (uint32_t i = 0; i < s->object_count; i++) {
        nc_object_rec *o = &s->objects[i];
        nc_free(ctx, o->name);
        nc_free(ctx, o->world_positions);
        nc_free(ctx, o->world_normals);
    }
    nc_free(ctx, s->meshes);
    nc_free(ctx, s->materials);
    for (uint32_t i = 0; i < s->material_name_capacity; i++)
        nc_free(ctx, s->material_names[i]);
    nc_free(ctx, s->material_names);
    nc_free(ctx, s->objects);
    nc_free(ctx, s->lights);
    for (uint32_t i = 0; i < s->volume_count; i++) {
        nc_free(ctx, s->volumes[i].data);
        nc_free(ctx, s->volumes[i].source_path);
        nc_free(ctx, s->volumes[i].source_grid);
    }
    nc_free(ctx, s->volumes);
    for (uint32_t i = 0; i < s->texture_count; i++) {
        nc_free(ctx, s->textures[i].data);
        nc_free(ctx, s->textures[i].source_path);
    }
    nc_free(ctx, s->textures);
    nc_scene_free_particles(s);
    for (uint32_t i = 0; i < s->input_count; i++)
        nc_free(ctx, s->inputs[i]);
    nc_free(ctx, s->inputs);
    nc_free(ctx, s);
}

nacre_result nc_scene_note_input(nacre_scene *s, const char *path)
{
    for (uint32_t i = 0; i < s->input_count; i++)
        if (strcmp(s->inputs[i], path) == 0)
            return NACRE_OK;
    if (s->input_count == s->input_capacity) {
        uint32_t cap = s->input_capacity ? 2 * s->input_capacity : 8;
        char **grown = nc_realloc(s->ctx, s->inputs, s->input_capacity * sizeof(char *), cap * sizeof(char *));
        if (!grown)
            return NACRE_ERROR_OUT_OF_MEMORY;
        s->inputs = grown;
        s->input_capacity = cap;
    }
    char *copy = nc_strdup(s->ctx, path);
    if (!copy)
        return NACRE_ERROR_OUT_OF_MEMORY;
    s->inputs[s->input_count++] = copy;
    return NACRE_OK;
}

/* Replace an owned string by a copy of `value` (NULL clears it). */
static nacre_result set_string(nacre_context *ctx, char **slot, const char *value)
{
    char *copy = NULL;
    if (value && !(copy = nc_strdup(ctx, value)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    nc_free(ctx, *slot);
    *slot = copy;
    return NACRE_OK;
}

nacre_result nc_scene_set_mesh_source(nacre_scene *s, nacre_mesh mesh, const char *path,
                                      const nacre_shape_desc *shape)
{
    if (!nc_scene_mesh(s, mesh))
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "mesh: invalid handle %u", mesh.id);
    nc_mesh_rec *m = &s->meshes[mesh.id - 1];
    nacre_result r = set_string(s->ctx, &m->source_path, path);
    if (r != NACRE_OK)
        return r;
    m->from_shape = shape != NULL;
    if (shape)
        m->shape = *shape;
    return NACRE_OK;
}

nacre_result nc_scene_set_volume_source(nacre_scene *s, nacre_volume volume, const char *path,
                                        uint32_t channel, float density_scale)
{
    if (!nc_scene_volume(s, volume))
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "volume: invalid handle %u", volume.id);
    nc_volume_rec *v = &s->volumes[volume.id - 1];
    v->source_channel = channel;
    v->source_scale = density_scale;
    return set_string(s->ctx, &v->source_path, path);
}

nacre_result nc_scene_set_volume_grid(nacre_scene *s, nacre_volume volume, const char *grid)
{
    if (!nc_scene_volume(s, volume))
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "volume: invalid handle %u", volume.id);
    return set_string(s->ctx, &s->volumes[volume.id - 1].source_grid, grid);
}

nacre_result nc_scene_set_texture_source(nacre_scene *s, nacre_texture texture, const char *path)
{
    if (!nc_scene_texture(s, texture))
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "texture: invalid handle %u", texture.id);
    return set_string(s->ctx, &s->textures[texture.id - 1].source_path, path);
}

nacre_result nc_scene_set_material_name(nacre_scene *s, nacre_material material, const char *name)
{
    if (!nc_scene_material(s, material))
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: invalid handle %u", material.id);
    /* Names are rare (scene files only): the array is made on first use, as large as the
     * materials' and zeroed past the count. */
    if (s->material_name_capacity < s->material_capacity) {
        char **grown = nc_realloc(s->ctx, s->material_names, s->material_name_capacity * sizeof(char *),
                                  s->material_capacity * sizeof(char *));
        if (!grown)
            return NACRE_ERROR_OUT_OF_MEMORY;
        memset(grown + s->material_name_capacity, 0,
               (s->material_capacity - s->material_name_capacity) * sizeof(char *));
        s->material_names = grown;
        s->material_name_capacity = s->material_capacity;
    }
    return set_string(s->ctx, &s->material_names[material.id - 1], name);
}

const char *nc_scene_material_name(const nacre_scene *s, nacre_material material)
{
    if (!nc_scene_material(s, material) || material.id > s->material_name_capacity)
        return NULL;
    return s->material_names[material.id - 1];
}

uint32_t nacre_scene_input_count(const nacre_scene *s) { return s ? s->input_count : 0; }

const char *nacre_scene_input_path(const nacre_scene *s, uint32_t index)
{
    return s && index < s->input_count ? s->inputs[index] : NULL;
}

nacre_context *nacre_scene_context(const nacre_scene *s) { return s ? s->ctx : NULL; }
uint32_t nacre_scene_object_count(const nacre_scene *s) { return s ? s->object_count : 0; }
uint32_t nacre_scene_light_count(const nacre_scene *s) { return s ? s->light_count : 0; }

const nc_mesh_rec *nc_scene_mesh(const nacre_scene *s, nacre_mesh m)
{
    return (m.id >= 1 && m.id <= s->mesh_count) ? &s->meshes[m.id - 1] : NULL;
}

const nacre_material_desc *nc_scene_material(const nacre_scene *s, nacre_material m)
{
    return (m.id >= 1 && m.id <= s->material_count) ? &s->materials[m.id - 1] : NULL;
}

const nc_volume_rec *nc_scene_volume(const nacre_scene *s, nacre_volume v)
{
    if (v.id & NC_PARTICLE_VOLUME_BIT)
        return nc_scene_particle_volume(s, v.id & ~NC_PARTICLE_VOLUME_BIT);
    return (v.id >= 1 && v.id <= s->volume_count) ? &s->volumes[v.id - 1] : NULL;
}

const nc_texture_rec *nc_scene_texture(const nacre_scene *s, nacre_texture t)
{
    return (t.id >= 1 && t.id <= s->texture_count) ? &s->textures[t.id - 1] : NULL;
}

const nacre_mesh_data *nacre_scene_mesh_data(const nacre_scene *s, nacre_mesh m)
{
    const nc_mesh_rec *r = s ? nc_scene_mesh(s, m) : NULL;
    return r ? &r->data : NULL;
}

static float *copy_floats(nacre_context *ctx, const float *src, size_t count, bool *failed)
{
    if (!src)
        return NULL;
    float *p = nc_calloc(ctx, count, sizeof(float));
    if (!p)
        *failed = true;
    else
        memcpy(p, src, count * sizeof(float));
    return p;
}

nacre_result nacre_scene_add_mesh(nacre_scene *s, const nacre_mesh_data *data, nacre_mesh *out)
{
    if (!s || !data || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_context *ctx = s->ctx;
    out->id = 0;
    nacre_result r = nacre_mesh_validate(ctx, data, "mesh");
    if (r != NACRE_OK)
        return r;
    nacre_mesh_data m;
    memset(&m, 0, sizeof(m));
    m.vertex_count = data->vertex_count;
    m.triangle_count = data->triangle_count;
    size_t nv = data->vertex_count;
    bool failed = false;
    m.positions = copy_floats(ctx, data->positions, nv * 3, &failed);
    m.normals = copy_floats(ctx, data->normals, nv * 3, &failed);
    m.uvs = copy_floats(ctx, data->uvs, nv * 2, &failed);
    m.tangents = copy_floats(ctx, data->tangents, nv * 4, &failed);
    m.indices = nc_calloc(ctx, (size_t)data->triangle_count * 3, sizeof(uint32_t));
    if (!m.indices || failed) {
        nacre_mesh_data_free(ctx, &m);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    memcpy(m.indices, data->indices, (size_t)data->triangle_count * 3 * sizeof(uint32_t));
    if (!m.normals && (r = nacre_mesh_compute_normals(ctx, &m)) != NACRE_OK)
        goto fail;
    if (!m.tangents && (r = nacre_mesh_compute_tangents(ctx, &m)) != NACRE_OK)
        goto fail;
    nc_mesh_rec *rec = grow(ctx, (void **)&s->meshes, &s->mesh_count, &s->mesh_capacity, sizeof(*rec));
    if (!rec) {
        r = NACRE_ERROR_OUT_OF_MEMORY;
        goto fail;
    }
    rec->data = m;
    out->id = ++s->mesh_count;
    s->versions.geometry++;
    return NACRE_OK;
fail:
    nacre_mesh_data_free(ctx, &m);
    return r;
}

nacre_result nacre_scene_add_material(nacre_scene *s, const nacre_material_desc *desc, nacre_material *out)
{
    if (!s || !desc || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    out->id = 0;
    nacre_result r = check_material(s, desc);
    if (r != NACRE_OK)
        return r;
    nacre_material_desc *slot =
        grow(s->ctx, (void **)&s->materials, &s->material_count, &s->material_capacity, sizeof(*slot));
    if (!slot)
        return NACRE_ERROR_OUT_OF_MEMORY;
    *slot = *desc;
    out->id = ++s->material_count;
    s->versions.materials++;
    return NACRE_OK;
}

nacre_result nacre_scene_set_material(nacre_scene *s, nacre_material m, const nacre_material_desc *desc)
{
    if (!s || !desc)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!nc_scene_material(s, m))
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "material: invalid handle %u", m.id);
    nacre_result r = check_material(s, desc);
    if (r != NACRE_OK)
        return r;
    s->materials[m.id - 1] = *desc;
    s->versions.materials++;
    return NACRE_OK;
}

/* Density volumes (NACRE_PATTERN_VOLUME). Values are checked here once so that the medium's
 * lookups never meet a NaN and its majorant (max_value) is exact. */
nacre_result nacre_scene_add_volume(nacre_scene *s, const nacre_volume_data *data, nacre_volume *out)
{
    if (!s || !data || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_context *ctx = s->ctx;
    out->id = 0;
    size_t n = 1;
    for (int k = 0; k < 3; k++) {
        if (data->dims[k] < 1 || !nc_mul_size_ok(n, data->dims[k], &n) || n > ((size_t)1 << 31))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                           "volume: dims: each must be >= 1, at most 2^31 samples in all");
        if (!(isfinite(data->spacing[k]) && data->spacing[k] > 0))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "volume: spacing[%d]: must be finite and > 0", k);
    }
    if (!finite3(data->origin))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "volume: origin: must be finite");
    if (!data->data)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "volume: data: missing");
    float lo = INFINITY, hi = -INFINITY;
    for (size_t i = 0; i < n; i++) {
        float v = data->data[i];
        if (!(isfinite(v) && v >= 0))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                           "volume: data[%zu]: must be finite and >= 0 (got %g)", i, (double)v);
        lo = fminf(lo, v);
        hi = fmaxf(hi, v);
    }
    float *copy = nc_alloc(ctx, n * sizeof(float));
    if (!copy)
        return NACRE_ERROR_OUT_OF_MEMORY;
    memcpy(copy, data->data, n * sizeof(float));
    nc_volume_rec *rec = grow(ctx, (void **)&s->volumes, &s->volume_count, &s->volume_capacity, sizeof(*rec));
    if (!rec) {
        nc_free(ctx, copy);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    memcpy(rec->dims, data->dims, sizeof(rec->dims));
    memcpy(rec->origin, data->origin, sizeof(rec->origin));
    memcpy(rec->spacing, data->spacing, sizeof(rec->spacing));
    rec->data = copy;
    rec->min_value = lo;
    rec->max_value = hi;
    out->id = ++s->volume_count;
    s->versions.materials++;
    return NACRE_OK;
}

/* Textures are validated once so that lookups never meet a NaN and per-channel bounds are exact
 * (bilinear weights are convex). */
nacre_result nacre_scene_add_texture(nacre_scene *s, const nacre_image *image, nacre_texture *out)
{
    if (!s || !image || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_context *ctx = s->ctx;
    out->id = 0;
    int32_t w = image->width, h = image->height, c = image->channels;
    if (w < 1 || h < 1 || c < 1 || c > 4 || !image->pixels || image->stride < (size_t)w * (size_t)c)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "texture: need width, height >= 1, 1..4 channels, pixels and stride >= width * channels");
    size_t row = (size_t)w * (size_t)c, n;
    if (!nc_mul_size_ok(row, (size_t)h, &n) || n > ((size_t)1 << 31))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "texture: at most 2^31 values");
    float lo[4] = {INFINITY, INFINITY, INFINITY, INFINITY}, hi[4] = {-INFINITY, -INFINITY, -INFINITY, -INFINITY};
    for (int32_t y = 0; y < h; y++)
        for (size_t i = 0; i < row; i++) {
            float v = image->pixels[(size_t)y * image->stride + i];
            if (!(isfinite(v) && v >= 0))
                return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                               "texture: pixel (%zu, %d) channel %zu: must be finite and >= 0 (got %g)",
                               i / (size_t)c, (int)y, i % (size_t)c, (double)v);
            lo[i % (size_t)c] = fminf(lo[i % (size_t)c], v);
            hi[i % (size_t)c] = fmaxf(hi[i % (size_t)c], v);
        }
    float *copy = nc_alloc(ctx, n * sizeof(float));
    if (!copy)
        return NACRE_ERROR_OUT_OF_MEMORY;
    for (int32_t y = 0; y < h; y++)
        memcpy(copy + (size_t)y * row, image->pixels + (size_t)y * image->stride, row * sizeof(float));
    nc_texture_rec *rec = grow(ctx, (void **)&s->textures, &s->texture_count, &s->texture_capacity, sizeof(*rec));
    if (!rec) {
        nc_free(ctx, copy);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    rec->width = w, rec->height = h, rec->channels = c;
    rec->data = copy;
    memcpy(rec->min_value, lo, sizeof(lo));
    memcpy(rec->max_value, hi, sizeof(hi));
    out->id = ++s->texture_count;
    s->versions.materials++;
    return NACRE_OK;
}

void nacre_volume_data_free(nacre_context *ctx, nacre_volume_data *v)
{
    if (!v)
        return;
    if (ctx)
        nc_free(ctx, v->data);
    memset(v, 0, sizeof(*v));
}

static nacre_result check_object(nacre_scene *s, const nacre_object_desc *d)
{
    nacre_context *ctx = s->ctx;
    if (!nc_scene_mesh(s, d->mesh))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "object: mesh: invalid handle %u", d->mesh.id);
    if (!nc_scene_material(s, d->material))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "object: material: invalid handle %u", d->material.id);
    const nacre_transform *t = &d->transform;
    if (!finite3(t->translate) || !finite3(t->rotate))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "object: transform: non-finite value");
    for (int i = 0; i < 3; i++)
        if (!(isfinite(t->scale[i]) && t->scale[i] != 0))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "object: transform.scale[%d]: must be finite and non-zero", i);
    if (d->deformer_count > NACRE_MAX_DEFORMERS)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "object: deformers: at most %d", NACRE_MAX_DEFORMERS);
    for (uint32_t i = 0; i < d->deformer_count; i++) {
        nacre_result r = check_deformer(ctx, &d->deformers[i], i);
        if (r != NACRE_OK)
            return r;
    }
    return NACRE_OK;
}

static nacre_result store_object(nacre_scene *s, nc_object_rec *o, const nacre_object_desc *d)
{
    char *name = NULL;
    if (d->name && !(name = nc_strdup(s->ctx, d->name)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    nc_free(s->ctx, o->name);
    o->name = name;
    o->desc = *d;
    o->desc.name = name;
    s->versions.geometry++;
    return NACRE_OK;
}

nacre_result nacre_scene_add_object(nacre_scene *s, const nacre_object_desc *desc, nacre_object *out)
{
    if (!s || !desc || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    out->id = 0;
    nacre_result r = check_object(s, desc);
    if (r != NACRE_OK)
        return r;
    nc_object_rec *o = grow(s->ctx, (void **)&s->objects, &s->object_count, &s->object_capacity, sizeof(*o));
    if (!o)
        return NACRE_ERROR_OUT_OF_MEMORY;
    if ((r = store_object(s, o, desc)) != NACRE_OK)
        return r;
    out->id = ++s->object_count;
    return NACRE_OK;
}

nacre_result nacre_scene_set_object(nacre_scene *s, nacre_object obj, const nacre_object_desc *desc)
{
    if (!s || !desc)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (obj.id < 1 || obj.id > s->object_count)
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "object: invalid handle %u", obj.id);
    nacre_result r = check_object(s, desc);
    if (r != NACRE_OK)
        return r;
    return store_object(s, &s->objects[obj.id - 1], desc);
}

static void store_light(nc_light_rec *rec, const nacre_light_desc *d)
{
    rec->given = *d;
    rec->desc = *d;
    if (d->type != NACRE_LIGHT_POINT)
        nc_v3store(nc_normalize(nc_v3a(d->direction)), rec->desc.direction);
}

nacre_result nacre_scene_add_light(nacre_scene *s, const nacre_light_desc *desc, nacre_light *out)
{
    if (!s || !desc || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    out->id = 0;
    nacre_result r = check_light(s->ctx, desc);
    if (r != NACRE_OK)
        return r;
    nc_light_rec *rec = grow(s->ctx, (void **)&s->lights, &s->light_count, &s->light_capacity, sizeof(*rec));
    if (!rec)
        return NACRE_ERROR_OUT_OF_MEMORY;
    store_light(rec, desc);
    out->id = ++s->light_count;
    s->versions.lights++;
    return NACRE_OK;
}

nacre_result nacre_scene_set_light(nacre_scene *s, nacre_light light, const nacre_light_desc *desc)
{
    if (!s || !desc)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (light.id < 1 || light.id > s->light_count)
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "light: invalid handle %u", light.id);
    nacre_result r = check_light(s->ctx, desc);
    if (r != NACRE_OK)
        return r;
    store_light(&s->lights[light.id - 1], desc);
    s->versions.lights++;
    return NACRE_OK;
}

nacre_result nacre_scene_set_camera(nacre_scene *s, const nacre_camera_desc *desc)
{
    if (!s || !desc)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_result r = check_camera(s->ctx, desc);
    if (r != NACRE_OK)
        return r;
    s->camera = *desc;
    s->has_camera = true;
    s->versions.camera++;
    return NACRE_OK;
}

nacre_result nacre_scene_set_environment(nacre_scene *s, const float radiance[3])
{
    if (!s || !radiance)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!nonneg3(radiance))
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "environment: must be finite and >= 0");
    memcpy(s->environment, radiance, sizeof(s->environment));
    s->versions.environment++;
    return NACRE_OK;
}

nacre_fog_desc nacre_fog_desc_defaults(nacre_fog_shape shape)
{
    nacre_fog_desc d;
    memset(&d, 0, sizeof(d));
    d.shape = shape;
    d.size[0] = d.size[1] = d.size[2] = 1.0f;
    d.sigma_s[0] = d.sigma_s[1] = d.sigma_s[2] = 0.001f;
    return d;
}

static nacre_result check_fog(const nacre_scene *s, const nacre_fog_desc *d)
{
    nacre_context *ctx = s->ctx;
    if (d->shape != NACRE_FOG_GLOBAL && d->shape != NACRE_FOG_BOX && d->shape != NACRE_FOG_SPHERE)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "fog: shape: unknown (%d)", (int)d->shape);
    if (!finite3(d->center))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "fog: center: must be finite");
    if (!finite3(d->rotate))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "fog: rotate: must be finite");
    if (d->shape != NACRE_FOG_GLOBAL && !(nonneg3(d->size) && d->size[0] > 0 && d->size[1] > 0 && d->size[2] > 0))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "fog: size: must be finite and > 0");
    if (!nonneg3(d->sigma_a))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "fog: sigma_a: must be finite and >= 0");
    if (!nonneg3(d->sigma_s))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "fog: sigma_s: must be finite and >= 0");
    if (!nonneg3(d->emission))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "fog: emission: must be finite and >= 0");
    for (int c = 0; d->shape == NACRE_FOG_GLOBAL && c < 3; c++)
        if (d->emission[c] > 0 && !(d->sigma_a[c] + d->sigma_s[c] > 0))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                           "fog: emission: a global fog that emits must absorb or scatter in that channel "
                           "(sigma_a + sigma_s > 0), or its light is infinite");
    if (!(isfinite(d->g) && d->g > -1 && d->g < 1))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "fog: g: must be in (-1, 1)");
    if (!(isfinite(d->height_falloff) && d->height_falloff >= 0))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "fog: height_falloff: must be finite and >= 0");
    if (!isfinite(d->height_base))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "fog: height_base: must be finite");
    nacre_result r = check_pattern(s, &d->pattern, "fog", true, false);
    return r != NACRE_OK ? r : check_pattern(s, &d->emission_pattern, "fog: emission_pattern", true, true);
}

void nc_scene_store_fog(nc_fog_rec *rec, const nacre_fog_desc *d)
{
    rec->desc = *d;
    nacre_material_desc m = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
    memcpy(m.sigma_a, d->sigma_a, sizeof(m.sigma_a));
    memcpy(m.sigma_s, d->sigma_s, sizeof(m.sigma_s));
    m.g = d->g;
    m.eta = 1.0f;
    m.pattern = d->pattern;
    rec->medium = m;
    /* Emission as the absorption of a medium whose medium 2 is clear: nc_medium_eval then
     * scales it by the pattern exactly as it scales sigma (x (1 - w), x density). */
    m.sigma_s[0] = m.sigma_s[1] = m.sigma_s[2] = 0.0f;
    memcpy(m.sigma_a, d->emission, sizeof(m.sigma_a));
    if (d->emission_pattern.type != NACRE_PATTERN_NONE)
        m.pattern = d->emission_pattern;
    memset(m.pattern.sigma_a2, 0, sizeof(m.pattern.sigma_a2));
    memset(m.pattern.sigma_s2, 0, sizeof(m.pattern.sigma_s2));
    rec->emission = m;
    rec->emissive = d->emission[0] > 0.0f || d->emission[1] > 0.0f || d->emission[2] > 0.0f;
    rec->emission_patterned = rec->emission.pattern.type != NACRE_PATTERN_NONE;
    nacre_transform t;
    memset(&t, 0, sizeof(t));
    memcpy(t.translate, d->center, sizeof(t.translate));
    memcpy(t.rotate, d->rotate, sizeof(t.rotate));
    t.scale[0] = t.scale[1] = t.scale[2] = 1.0f;
    nc_mat4_inverse(nc_transform_matrix(&t), &rec->world_to_local);
}

nacre_result nacre_scene_add_fog(nacre_scene *s, const nacre_fog_desc *desc, nacre_fog *out)
{
    if (!s || !desc || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    out->id = 0;
    if (nc_scene_user_fogs(s) >= NACRE_MAX_FOGS)
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "fog: at most %d fogs per scene", NACRE_MAX_FOGS);
    nacre_result r = check_fog(s, desc);
    if (r != NACRE_OK)
        return r;
    nc_scene_drop_particle_fogs(s); /* made again at the next commit, after the new fog */
    if (s->fog_count + s->particles_count >= NACRE_MAX_FOGS)
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "fog: at most %d fogs and particle systems per scene", NACRE_MAX_FOGS);
    nc_scene_store_fog(&s->fogs[s->fog_count], desc);
    out->id = ++s->fog_count;
    s->versions.environment++;
    return NACRE_OK;
}

nacre_result nacre_scene_set_fog(nacre_scene *s, nacre_fog fog, const nacre_fog_desc *desc)
{
    if (!s || !desc)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (fog.id < 1 || fog.id > nc_scene_user_fogs(s))
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "fog: invalid handle %u", fog.id);
    nacre_result r = check_fog(s, desc);
    if (r != NACRE_OK)
        return r;
    nc_scene_store_fog(&s->fogs[fog.id - 1], desc);
    s->versions.environment++;
    return NACRE_OK;
}

uint32_t nacre_scene_fog_count(const nacre_scene *s) { return s ? nc_scene_user_fogs(s) : 0; }

nacre_result nacre_scene_set_unit_mm(nacre_scene *s, float unit_mm)
{
    if (!s)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!(isfinite(unit_mm) && unit_mm > 0))
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "units: must be a positive number of millimetres");
    s->unit_mm = unit_mm;
    s->versions.materials++;
    return NACRE_OK;
}

/* ---------------------------------------------------------------------------------------- */
/* Transforms and deformers                                                                 */
/* ---------------------------------------------------------------------------------------- */

nc_mat4 nc_transform_matrix(const nacre_transform *t)
{
    nc_mat4 rx = nc_mat4_rotate(nc_v3(1, 0, 0), t->rotate[0] * NC_DEG2RAD);
    nc_mat4 ry = nc_mat4_rotate(nc_v3(0, 1, 0), t->rotate[1] * NC_DEG2RAD);
    nc_mat4 rz = nc_mat4_rotate(nc_v3(0, 0, 1), t->rotate[2] * NC_DEG2RAD);
    nc_mat4 r = nc_mat4_mul(rz, nc_mat4_mul(ry, rx)); /* x first, then y, then z */
    nc_mat4 m = nc_mat4_mul(r, nc_mat4_scale(nc_v3a(t->scale)));
    return nc_mat4_mul(nc_mat4_translate(nc_v3a(t->translate)), m);
}

/* Rotate v about unit axis a by angle (Rodrigues). */
static nc_vec3 rotate_about(nc_vec3 v, nc_vec3 a, float angle)
{
    float c = cosf(angle), s = sinf(angle);
    return nc_add(nc_add(nc_scale(v, c), nc_scale(nc_cross(a, v), s)), nc_scale(a, nc_dot(a, v) * (1 - c)));
}

static nc_vec3 deform_one(const nacre_deformer *d, double time, nc_vec3 p)
{
    nc_vec3 c = nc_v3a(d->center);
    float angle = (float)((double)d->angle + (double)d->angle_rate * time) * NC_DEG2RAD;
    switch (d->type) {
    case NACRE_DEFORM_NONE:
        return p;
    case NACRE_DEFORM_SCALE: {
        nc_vec3 s = nc_v3((float)(d->scale[0] + d->scale_rate[0] * time), (float)(d->scale[1] + d->scale_rate[1] * time),
                          (float)(d->scale[2] + d->scale_rate[2] * time));
        return nc_add(c, nc_mul(nc_sub(p, c), s));
    }
    case NACRE_DEFORM_TWIST: {
        nc_vec3 a = nc_normalize(nc_v3a(d->axis));
        nc_vec3 rel = nc_sub(p, c);
        float s = nc_dot(rel, a);
        return nc_add(c, rotate_about(rel, a, angle * s / d->length));
    }
    case NACRE_DEFORM_BEND: {
        /* The axis line bends into a circular arc in the (axis, direction) plane; material
         * beyond the arc's end continues straight along its tangent, material before the
         * centre is untouched. */
        nc_vec3 a = nc_normalize(nc_v3a(d->axis));
        nc_vec3 b = nc_v3a(d->direction);
        b = nc_normalize(nc_sub(b, nc_scale(a, nc_dot(a, b))));
        nc_vec3 rel = nc_sub(p, c);
        float s = nc_dot(rel, a), x = nc_dot(rel, b);
        nc_vec3 rest = nc_sub(rel, nc_add(nc_scale(a, s), nc_scale(b, x))); /* off-plane part */
        if (s <= 0 || angle == 0)
            return p;
        float k = angle / d->length; /* curvature */
        float sa = fminf(s, d->length);
        float phi = k * sa;
        /* Arc point for the axis at arc length sa, and the local frame there. */
        nc_vec3 tangent = nc_add(nc_scale(a, cosf(phi)), nc_scale(b, sinf(phi)));
        nc_vec3 normal = nc_sub(nc_scale(b, cosf(phi)), nc_scale(a, sinf(phi)));
        nc_vec3 arc = nc_add(nc_scale(a, sinf(phi) / k), nc_scale(b, (1 - cosf(phi)) / k));
        nc_vec3 q = nc_add(arc, nc_add(nc_scale(normal, x), nc_scale(tangent, s - sa)));
        return nc_add(c, nc_add(q, rest));
    }
    }
    return p;
}

nc_vec3 nc_deform_point(const nacre_deformer *deformers, uint32_t count, double time, nc_vec3 p)
{
    for (uint32_t i = 0; i < count; i++)
        p = deform_one(&deformers[i], time, p);
    return p;
}

/* Cofactor matrix of the 3x3 matrix with columns c0, c1, c2: maps normals the way the
 * matrix maps surfaces (det(J) J^-T), well defined even when J is singular. */
static void cofactor_columns(nc_vec3 c0, nc_vec3 c1, nc_vec3 c2, nc_vec3 out[3])
{
    out[0] = nc_cross(c1, c2);
    out[1] = nc_cross(c2, c0);
    out[2] = nc_cross(c0, c1);
}

static nc_vec3 apply_columns(const nc_vec3 cols[3], nc_vec3 v)
{
    return nc_add(nc_add(nc_scale(cols[0], v.x), nc_scale(cols[1], v.y)), nc_scale(cols[2], v.z));
}

static nacre_result commit_object(nacre_scene *s, nc_object_rec *o, double time)
{
    nacre_context *ctx = s->ctx;
    const nacre_mesh_data *m = &s->meshes[o->desc.mesh.id - 1].data;
    uint32_t nv = m->vertex_count;
    if (o->world_capacity < nv) {
        nc_free(ctx, o->world_positions);
        nc_free(ctx, o->world_normals);
        o->world_positions = nc_calloc(ctx, (size_t)nv * 3, sizeof(float));
        o->world_normals = nc_calloc(ctx, (size_t)nv * 3, sizeof(float));
        o->world_capacity = nv;
        if (!o->world_positions || !o->world_normals) {
            o->world_capacity = 0;
            return NACRE_ERROR_OUT_OF_MEMORY;
        }
    }
    nc_mat4 M = nc_transform_matrix(&o->desc.transform);
    o->object_to_world = M;
    nc_vec3 mc[3] = {nc_v3(M.m[0][0], M.m[1][0], M.m[2][0]), nc_v3(M.m[0][1], M.m[1][1], M.m[2][1]),
                     nc_v3(M.m[0][2], M.m[1][2], M.m[2][2])};
    nc_vec3 mcof[3];
    cofactor_columns(mc[0], mc[1], mc[2], mcof);

    /* Finite-difference step: small against the mesh but far above float resolution. */
    float extent = 0;
    for (uint32_t i = 0; i < nv * 3; i++)
        extent = fmaxf(extent, fabsf(m->positions[i]));
    float h = fmaxf(extent, 1e-6f) * 1e-3f;

    const nacre_deformer *defs = o->desc.deformers;
    uint32_t ndef = o->desc.deformer_count;
    float *wp = o->world_positions, *wn = o->world_normals;
    float bmin[3] = {INFINITY, INFINITY, INFINITY}, bmax[3] = {-INFINITY, -INFINITY, -INFINITY};

#pragma omp parallel num_threads(ctx->threads)
    {
        float lmin[3] = {INFINITY, INFINITY, INFINITY}, lmax[3] = {-INFINITY, -INFINITY, -INFINITY};
#pragma omp for schedule(static)
        for (uint32_t v = 0; v < nv; v++) {
            nc_vec3 p = nc_v3a(m->positions + 3 * (size_t)v);
            nc_vec3 n = nc_v3a(m->normals + 3 * (size_t)v);
            nc_vec3 q = p;
            if (ndef) {
                q = nc_deform_point(defs, ndef, time, p);
                nc_vec3 J[3];
                for (int axis = 0; axis < 3; axis++) {
                    nc_vec3 e = nc_v3(axis == 0 ? h : 0, axis == 1 ? h : 0, axis == 2 ? h : 0);
                    nc_vec3 fp = nc_deform_point(defs, ndef, time, nc_add(p, e));
                    nc_vec3 fm = nc_deform_point(defs, ndef, time, nc_sub(p, e));
                    J[axis] = nc_scale(nc_sub(fp, fm), 0.5f / h);
                }
                nc_vec3 cof[3];
                cofactor_columns(J[0], J[1], J[2], cof);
                n = apply_columns(cof, n);
            }
            nc_vec3 w = nc_mat4_point(&M, q);
            n = nc_normalize(apply_columns(mcof, n));
            nc_v3store(w, wp + 3 * (size_t)v);
            nc_v3store(n, wn + 3 * (size_t)v);
            lmin[0] = fminf(lmin[0], w.x); lmin[1] = fminf(lmin[1], w.y); lmin[2] = fminf(lmin[2], w.z);
            lmax[0] = fmaxf(lmax[0], w.x); lmax[1] = fmaxf(lmax[1], w.y); lmax[2] = fmaxf(lmax[2], w.z);
        }
#pragma omp critical
        for (int k = 0; k < 3; k++) {
            bmin[k] = fminf(bmin[k], lmin[k]);
            bmax[k] = fmaxf(bmax[k], lmax[k]);
        }
    }
    for (int k = 0; k < 3; k++) {
        if (!isfinite(bmin[k]) || !isfinite(bmax[k]))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                           "object '%s': deformed geometry is not finite", o->name ? o->name : "?");
        o->bounds_min[k] = bmin[k];
        o->bounds_max[k] = bmax[k];
    }
    return NACRE_OK;
}

nacre_result nacre_scene_commit(nacre_scene *s, double time)
{
    if (!s)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!isfinite(time))
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "commit: time must be finite");
    s->committed_valid = false;
    /* A diffuse map is read at the surface's uvs: a mesh without them would show one texel. */
    for (uint32_t i = 0; i < s->object_count; i++) {
        const nc_object_rec *o = &s->objects[i];
        uint32_t mi = o->desc.material.id, me = o->desc.mesh.id;
        if (mi == 0 || mi > s->material_count || me == 0 || me > s->mesh_count)
            continue;
        if (s->materials[mi - 1].diffuse_map.id != 0 && !s->meshes[me - 1].data.uvs)
            return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT,
                           "object '%s': its material has a diffuse_map but its mesh has no uvs",
                           o->name ? o->name : "(unnamed)");
    }
    /* Geometry is recomputed only when it or the deformation time changed. */
    bool animated = false;
    for (uint32_t i = 0; i < s->object_count; i++) {
        const nacre_object_desc *d = &s->objects[i].desc;
        for (uint32_t k = 0; k < d->deformer_count; k++)
            animated |= d->deformers[k].angle_rate != 0 || d->deformers[k].scale_rate[0] != 0 ||
                        d->deformers[k].scale_rate[1] != 0 || d->deformers[k].scale_rate[2] != 0;
    }
    bool geometry_stale = s->committed.geometry != s->versions.geometry || (animated && time != s->time);
    if (geometry_stale) {
        if (animated && time != s->time)
            s->versions.geometry++;
        float bmin[3] = {INFINITY, INFINITY, INFINITY}, bmax[3] = {-INFINITY, -INFINITY, -INFINITY};
        for (uint32_t i = 0; i < s->object_count; i++) {
            nacre_result r = commit_object(s, &s->objects[i], time);
            if (r != NACRE_OK)
                return r;
            for (int k = 0; k < 3; k++) {
                bmin[k] = fminf(bmin[k], s->objects[i].bounds_min[k]);
                bmax[k] = fmaxf(bmax[k], s->objects[i].bounds_max[k]);
            }
        }
        memcpy(s->bounds_min, bmin, sizeof(bmin));
        memcpy(s->bounds_max, bmax, sizeof(bmax));
    }
    nacre_result pr = nc_scene_commit_particles(s, time);
    if (pr != NACRE_OK)
        return pr;
    s->time = time;
    s->committed = s->versions;
    s->committed_valid = true;
    return NACRE_OK;
}

nacre_result nacre_scene_bounds(const nacre_scene *s, float min[3], float max[3])
{
    if (!s || !min || !max)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!s->committed_valid || s->object_count == 0)
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_OPERATION, "scene: not committed or empty");
    memcpy(min, s->bounds_min, sizeof(s->bounds_min));
    memcpy(max, s->bounds_max, sizeof(s->bounds_max));
    return NACRE_OK;
}

void nc_scene_view_depth_range(const nacre_scene *s, const nc_mat4 *view, float *dmin_out, float *dmax_out)
{
    float dmin = INFINITY, dmax = -INFINITY;
    for (int k = 0; k < 8; k++) {
        nc_vec3 p = nc_v3((k & 1) ? s->bounds_max[0] : s->bounds_min[0], (k & 2) ? s->bounds_max[1] : s->bounds_min[1],
                          (k & 4) ? s->bounds_max[2] : s->bounds_min[2]);
        float d = -nc_mat4_point(view, p).z;
        dmin = fminf(dmin, d);
        dmax = fmaxf(dmax, d);
    }
    if (!isfinite(dmin) || !isfinite(dmax)) {
        dmin = 0.01f;
        dmax = 100.0f;
    }
    *dmin_out = dmin;
    *dmax_out = dmax;
}
