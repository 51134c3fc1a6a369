/*
 * json_render.c: the "units" and "render" sections of a JSON scene (docs/scene-format.md,
 * "units" and "render"). "units" sets the scene's millimetres per unit, which the material
 * presets are later scaled by; "render" fills nacre_scene_file_settings (sizes in pixels, times in
 * seconds, lengths in scene units).
 */
#include "io/scene_json_internal.h"

#define IMAGE_SIZE_MAX 16384

/* ------------------------------------------------------------------------------------------ */
/* Sections                                                                                   */
/* ------------------------------------------------------------------------------------------ */

void nc_json_parse_units(loader *ld, const cJSON *item)
{
    size_t mark = nc_json_push_key(ld, "units");
    if (cJSON_IsString(item)) {
        if (!nacre_units_mm(item->valuestring, &ld->unit_mm)) {
            char buf[NAME_SHOWN_MAX + 8];
            nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                         "unknown unit \"%s\" (valid: \"mm\", \"cm\", \"m\" or millimetres per unit)",
                         nc_json_shown(item->valuestring, buf, sizeof(buf)));
        }
    } else if (cJSON_IsNumber(item)) {
        double v;
        if (nc_json_read_number(ld, item, R_POSITIVE, &v))
            ld->unit_mm = (float)v;
    } else {
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                     "expected \"mm\", \"cm\", \"m\" or a number of millimetres, got %s",
                     nc_json_type_name(item));
    }
    nc_json_pop(ld, mark);
    if (ld->err)
        return;
    nacre_result r = nacre_scene_set_unit_mm(ld->scene, ld->unit_mm);
    if (r != NACRE_OK) {
        mark = nc_json_push_key(ld, "units");
        nc_json_fail_inner(ld, r);
        nc_json_pop(ld, mark);
    }
}

void nc_json_parse_render(loader *ld, const cJSON *obj)
{
    static const char *const keys[] = {"method", "width", "height", "exposure", "shadow_map_size",
                                       "pcf_radius", "shadow_bias", "spp", "seed", "time",
                                       "voxel_resolution", "tsm_size", "solver", "source",
                                       "tolerance", "seed_iterations", "single_scattering", "time_limit", "max_scatter",
                                       "layered_samples", "layered_epsilon", "layered_half_res", "layered_integration",
                                       "particles", "volumetrics", "froxel_width", "froxel_height",
                                       "froxel_slices", "raymarch_steps", "shadow_steps", "froxel_temporal"};
    /* indexed by the enums' values */
    const char *const solvers[] = {nacre_solver_name(NACRE_SOLVER_MULTIGRID), nacre_solver_name(NACRE_SOLVER_SEED)};
    const char *const sources[] = {nacre_source_name(NACRE_SOURCE_VOLUME), nacre_source_name(NACRE_SOURCE_FACE)};
    size_t mark = nc_json_push_key(ld, "render");
    if (!nc_json_expect_object(ld, obj) || !nc_json_check_keys(ld, obj, keys, COUNT_OF(keys))) {
        nc_json_pop(ld, mark);
        return;
    }
    nacre_render_settings *s = &ld->settings.render;
    const char *method = nc_json_get_string(ld, obj, "method");
    if (method && !nacre_method_from_name(method, &s->method)) {
        const char *names[NACRE_METHOD_COUNT];
        for (int i = 0; i < NACRE_METHOD_COUNT; i++)
            names[i] = nacre_method_name((nacre_method)i);
        char buf[NAME_SHOWN_MAX + 8], list[256];
        size_t m2 = nc_json_push_key(ld, "method");
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "unknown render method \"%s\" (valid: %s)",
                     nc_json_shown(method, buf, sizeof(buf)), nc_json_join_names(names, NACRE_METHOD_COUNT, list, sizeof(list)));
        nc_json_pop(ld, m2);
    }
    int64_t v;
    if (nc_json_get_integer(ld, obj, "width", 1, IMAGE_SIZE_MAX, &v))
        s->width = (int32_t)v;
    if (nc_json_get_integer(ld, obj, "height", 1, IMAGE_SIZE_MAX, &v))
        s->height = (int32_t)v;
    nc_json_get_number(ld, obj, "exposure", R_FINITE, &ld->settings.exposure);
    if (nc_json_get_integer(ld, obj, "shadow_map_size", 0, IMAGE_SIZE_MAX, &v))
        s->shadow.map_size = (int32_t)v;
    nc_json_get_number(ld, obj, "pcf_radius", R_NONNEG, &s->shadow.pcf_radius);
    nc_json_get_number(ld, obj, "shadow_bias", R_NONNEG, &s->shadow.bias);
    if (nc_json_get_integer(ld, obj, "spp", 1, 1 << 24, &v))
        s->pathtrace.spp = (uint32_t)v;
    if (nc_json_get_integer(ld, obj, "seed", 0, UINT32_MAX, &v))
        s->pathtrace.seed = (uint32_t)v;
    nc_json_get_double(ld, obj, "time", R_FINITE, &ld->settings.time);
    /* Diffusion and path-tracer settings (nacre_render_settings); ranges match what the
     * renderers accept, so a file cannot ask for a grid or map the library would refuse. */
    if (nc_json_get_integer(ld, obj, "voxel_resolution", 1, 1024, &v))
        s->diffusion.voxel_resolution = (uint32_t)v;
    if (nc_json_get_integer(ld, obj, "tsm_size", 16, 8192, &v))
        s->diffusion.tsm_size = (int32_t)v;
    int choice = nc_json_get_choice(ld, obj, "solver", "solver", solvers, COUNT_OF(solvers));
    if (choice >= 0)
        s->diffusion.solver = (nacre_diffusion_solver)choice;
    choice = nc_json_get_choice(ld, obj, "source", "source", sources, COUNT_OF(sources));
    if (choice >= 0)
        s->diffusion.source = (nacre_diffusion_source)choice;
    const char *const draws[] = {nacre_particles_draw_name(NACRE_PARTICLES_DRAW_BILLBOARDS),
                                 nacre_particles_draw_name(NACRE_PARTICLES_DRAW_SPRITES),
                                 nacre_particles_draw_name(NACRE_PARTICLES_DRAW_VOXEL)};
    choice = nc_json_get_choice(ld, obj, "particles", "particles drawing", draws, COUNT_OF(draws));
    if (choice >= 0)
        s->particles = (nacre_particles_draw)choice;
    static const range tolerance_range = {0.0, 1.0, true, true};
    nc_json_get_number(ld, obj, "tolerance", tolerance_range, &s->diffusion.tolerance);
    if (nc_json_get_integer(ld, obj, "seed_iterations", 0, 1000000, &v))
        s->diffusion.seed_iterations = (uint32_t)v;
    /* true and false stay valid (the setting was a bool before "auto") */
    const cJSON *single = nc_json_member(obj, "single_scattering");
    if (single && cJSON_IsBool(single)) {
        s->diffusion.single_scattering = cJSON_IsTrue(single) ? NACRE_SINGLE_SCATTERING_ON : NACRE_SINGLE_SCATTERING_OFF;
    } else if (single) {
        const char *const modes[] = {nacre_single_scattering_name(NACRE_SINGLE_SCATTERING_OFF),
                                     nacre_single_scattering_name(NACRE_SINGLE_SCATTERING_ON),
                                     nacre_single_scattering_name(NACRE_SINGLE_SCATTERING_AUTO)};
        choice = nc_json_get_choice(ld, obj, "single_scattering", "single_scattering mode", modes, COUNT_OF(modes));
        if (choice >= 0)
            s->diffusion.single_scattering = (nacre_single_scattering)choice;
    }
    nc_json_get_double(ld, obj, "time_limit", R_NONNEG, &s->pathtrace.time_limit);
    if (nc_json_get_integer(ld, obj, "max_scatter", 0, UINT32_MAX, &v))
        s->pathtrace.max_scatter = (uint32_t)v;
    /* The layered method (seed 001) */
    if (nc_json_get_integer(ld, obj, "layered_samples", 1, 4096, &v))
        s->layered.samples = (uint32_t)v;
    static const range epsilon_range = {0.0, 1.0, true, true};
    nc_json_get_number(ld, obj, "layered_epsilon", epsilon_range, &s->layered.epsilon);
    static const range half_res_range = {0.0, 1.0, false, true};
    nc_json_get_number(ld, obj, "layered_half_res", half_res_range, &s->layered.half_res);
    const char *const integrations[] = {nacre_layered_integration_name(NACRE_LAYERED_ANALYTIC),
                                        nacre_layered_integration_name(NACRE_LAYERED_SAMPLES)};
    choice = nc_json_get_choice(ld, obj, "layered_integration", "integration", integrations, COUNT_OF(integrations));
    if (choice >= 0)
        s->layered.integration = (nacre_layered_integration)choice;
    const char *const volumetrics[] = {nacre_volumetrics_name(NACRE_VOLUMETRICS_OFF),
                                       nacre_volumetrics_name(NACRE_VOLUMETRICS_FROXEL),
                                       nacre_volumetrics_name(NACRE_VOLUMETRICS_RAYMARCH)};
    choice = nc_json_get_choice(ld, obj, "volumetrics", "volumetrics mode", volumetrics, COUNT_OF(volumetrics));
    if (choice >= 0)
        s->volumetrics.mode = (nacre_volumetrics_mode)choice;
    if (nc_json_get_integer(ld, obj, "froxel_width", 1, 1024, &v))
        s->volumetrics.froxel_width = (uint32_t)v;
    if (nc_json_get_integer(ld, obj, "froxel_height", 1, 1024, &v))
        s->volumetrics.froxel_height = (uint32_t)v;
    if (nc_json_get_integer(ld, obj, "froxel_slices", 1, 1024, &v))
        s->volumetrics.froxel_slices = (uint32_t)v;
    if (nc_json_get_integer(ld, obj, "raymarch_steps", 1, 4096, &v))
        s->volumetrics.raymarch_steps = (uint32_t)v;
    if (nc_json_get_integer(ld, obj, "shadow_steps", 1, 256, &v))
        s->volumetrics.shadow_steps = (uint32_t)v;
    static const range temporal_range = {0.0, 1.0, false, true};
    nc_json_get_number(ld, obj, "froxel_temporal", temporal_range, &s->volumetrics.temporal);
    nc_json_pop(ld, mark);
}
