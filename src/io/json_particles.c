/*
 * json_particles.c: the "particles" section of a JSON scene (docs/scene-format.md,
 * "particles"): particle systems, emitters or static lists (nacre/particles.h). Positions in
 * scene units, times in seconds, coefficients per scene unit at density 1.
 */
#include "io/scene_json_internal.h"

#include <nacre/particles.h>

/* An array of `count` numbers (n == 1) or of [x, y, z] (n == 3) into out. */
static void read_list(loader *ld, const cJSON *arr, int n, range r, uint32_t count, float *out)
{
    uint32_t i = 0;
    for (const cJSON *c = arr->child; c && !ld->err && i < count; c = c->next, i++) {
        size_t mark = nc_json_push_index(ld, (int)i);
        if (n == 3) {
            nc_json_read_floats(ld, c, 3, r, false, out + 3 * (size_t)i);
        } else {
            double v;
            if (nc_json_read_number(ld, c, r, &v))
                out[i] = (float)v;
        }
        nc_json_pop(ld, mark);
    }
}

/* The length of array `key` (0 if absent), checked against `want` when nonzero. */
static uint32_t list_length(loader *ld, const cJSON *obj, const char *key, uint32_t want)
{
    const cJSON *arr = nc_json_member(obj, key);
    if (!arr || ld->err)
        return 0;
    size_t mark = nc_json_push_key(ld, key);
    int n = cJSON_IsArray(arr) ? cJSON_GetArraySize(arr) : -1;
    if (n < 0)
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected an array, got %s", nc_json_type_name(arr));
    else if (n < 1 || (uint32_t)n > NACRE_PARTICLES_MAX)
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "must hold 1..%u particles (got %d)", NACRE_PARTICLES_MAX, n);
    else if (want && (uint32_t)n != want)
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected %u elements, one per position, got %d", want, n);
    nc_json_pop(ld, mark);
    return ld->err || n < 0 ? 0 : (uint32_t)n;
}

static void read_array(loader *ld, const cJSON *obj, const char *key, int n, range r, uint32_t count, float *out)
{
    size_t mark = nc_json_push_key(ld, key);
    read_list(ld, nc_json_member(obj, key), n, r, count, out);
    nc_json_pop(ld, mark);
}

/* "particles": one particle system (nacre_particles_desc). */
void nc_json_parse_particles(loader *ld, const cJSON *obj)
{
    static const char *const types[] = {"emitter", "list"};
    static const char *const shapes[] = {"point", "box", "sphere"};
    static const char *const keys[] = {"type", "shape", "center", "size", "emit_radius", "rate", "lifetime",
                                       "velocity", "spread", "speed_jitter", "gravity", "drag", "radius",
                                       "radius_jitter", "radius_rate", "density", "fade", "seed", "positions",
                                       "radii", "densities", "sigma_a", "sigma_s", "g", "grid_resolution",
                                       "isosurface"};
    static const char *const emitter_only[] = {"shape", "center", "size", "emit_radius", "rate", "lifetime",
                                               "velocity", "spread", "speed_jitter", "gravity", "drag",
                                               "radius_jitter", "radius_rate", "fade", "seed"};
    static const char *const list_only[] = {"positions", "radii", "densities"};
    if (!nc_json_expect_object(ld, obj) || !nc_json_check_keys(ld, obj, keys, COUNT_OF(keys)))
        return;
    int type = 0;
    if (nc_json_member(obj, "type"))
        type = nc_json_get_choice(ld, obj, "type", "particles type", types, COUNT_OF(types));
    if (type < 0)
        return;
    nacre_particles_desc d = nacre_particles_desc_defaults(type == 0 ? NACRE_PARTICLES_EMITTER : NACRE_PARTICLES_LIST);
    const char *const *other = type == 0 ? list_only : emitter_only;
    size_t other_count = type == 0 ? COUNT_OF(list_only) : COUNT_OF(emitter_only);
    for (size_t k = 0; k < other_count && !ld->err; k++)
        if (nc_json_member(obj, other[k]))
            nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "\"%s\" applies to %s particles only", other[k],
                         type == 0 ? "list" : "emitter");
    static const range g_range = {-1.0, 1.0, true, true};
    static const range spread_range = {0.0, 180.0, false, false};
    static const range below_one = {0.0, 1.0, false, true};
    if (type == 0) {
        int shape = 0;
        if (nc_json_member(obj, "shape"))
            shape = nc_json_get_choice(ld, obj, "shape", "emitter shape", shapes, COUNT_OF(shapes));
        d.shape = shape == 1 ? NACRE_EMITTER_BOX : shape == 2 ? NACRE_EMITTER_SPHERE : NACRE_EMITTER_POINT;
        nc_json_get_floats(ld, obj, "center", 3, R_FINITE, false, d.center);
        nc_json_get_floats(ld, obj, "size", 3, R_NONNEG, true, d.size);
        nc_json_get_number(ld, obj, "emit_radius", R_NONNEG, &d.emit_radius);
        nc_json_get_number(ld, obj, "rate", R_POSITIVE, &d.rate);
        nc_json_get_number(ld, obj, "lifetime", R_POSITIVE, &d.lifetime);
        nc_json_get_floats(ld, obj, "velocity", 3, R_FINITE, false, d.velocity);
        nc_json_get_number(ld, obj, "spread", spread_range, &d.spread);
        nc_json_get_number(ld, obj, "speed_jitter", R_UNIT, &d.speed_jitter);
        nc_json_get_floats(ld, obj, "gravity", 3, R_FINITE, false, d.gravity);
        nc_json_get_number(ld, obj, "drag", R_NONNEG, &d.drag);
        nc_json_get_number(ld, obj, "radius_jitter", below_one, &d.radius_jitter);
        nc_json_get_number(ld, obj, "radius_rate", R_NONNEG, &d.radius_rate);
        nc_json_get_number(ld, obj, "fade", R_UNIT, &d.fade);
        int64_t seed;
        if (nc_json_get_integer(ld, obj, "seed", 0, UINT32_MAX, &seed))
            d.seed = (uint32_t)seed;
    }
    nc_json_get_number(ld, obj, "radius", R_POSITIVE, &d.radius);
    nc_json_get_number(ld, obj, "density", R_NONNEG, &d.density);
    nc_json_get_floats(ld, obj, "sigma_a", 3, R_NONNEG, true, d.sigma_a);
    nc_json_get_floats(ld, obj, "sigma_s", 3, R_NONNEG, true, d.sigma_s);
    nc_json_get_number(ld, obj, "g", g_range, &d.g);
    int64_t res;
    if (nc_json_get_integer(ld, obj, "grid_resolution", NACRE_PARTICLES_GRID_MIN, NACRE_PARTICLES_GRID_MAX, &res))
        d.grid_resolution = (uint32_t)res;
    const cJSON *iso = nc_json_member(obj, "isosurface");
    if (iso && !ld->err) {
        static const char *const iso_keys[] = {"density", "ior", "roughness"};
        static const range ior_range = {1.0, 4.0, false, false};
        size_t mark = nc_json_push_key(ld, "isosurface");
        if (nc_json_expect_object(ld, iso) && nc_json_check_keys(ld, iso, iso_keys, COUNT_OF(iso_keys)) &&
            nc_json_require(ld, iso, "density")) {
            nc_json_get_number(ld, iso, "density", R_POSITIVE, &d.isosurface.density);
            nc_json_get_number(ld, iso, "ior", ior_range, &d.isosurface.ior);
            nc_json_get_number(ld, iso, "roughness", R_UNIT, &d.isosurface.roughness);
        }
        nc_json_pop(ld, mark);
    }
    float *pos = NULL, *rad = NULL, *den = NULL;
    if (type == 1 && !ld->err && nc_json_require(ld, obj, "positions")) {
        d.count = list_length(ld, obj, "positions", 0);
        uint32_t nr = list_length(ld, obj, "radii", d.count), nd = list_length(ld, obj, "densities", d.count);
        if (!ld->err) {
            pos = nc_alloc(ld->ctx, 3 * sizeof(float) * d.count);
            rad = nr ? nc_alloc(ld->ctx, sizeof(float) * d.count) : NULL;
            den = nd ? nc_alloc(ld->ctx, sizeof(float) * d.count) : NULL;
            if (!pos || (nr && !rad) || (nd && !den))
                nc_json_fail(ld, NACRE_ERROR_OUT_OF_MEMORY, "out of memory for %u particles", d.count);
        }
        if (!ld->err)
            read_array(ld, obj, "positions", 3, R_FINITE, d.count, pos);
        if (!ld->err && rad)
            read_array(ld, obj, "radii", 1, R_POSITIVE, d.count, rad);
        if (!ld->err && den)
            read_array(ld, obj, "densities", 1, R_NONNEG, d.count, den);
        d.positions = pos;
        d.radii = rad;
        d.densities = den;
    }
    if (!ld->err) {
        nacre_particles handle;
        nacre_result r = nacre_scene_add_particles(ld->scene, &d, &handle);
        if (r != NACRE_OK)
            nc_json_fail_inner(ld, r);
    }
    nc_free(ld->ctx, pos);
    nc_free(ld->ctx, rad);
    nc_free(ld->ctx, den);
}
