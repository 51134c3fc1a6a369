/*
 * settings.c: render settings defaults and the names of their enumerations (solver, source,
 * layered integration, volumetrics, single scattering, stage). Method names live with the
 * method table (methods.c).
 */
#include "scene/scene.h"

#include <string.h>

nacre_render_settings nacre_render_settings_defaults(void)
{
    nacre_render_settings s;
    memset(&s, 0, sizeof(s));
    s.method = NACRE_METHOD_PHONG;
    s.width = 640;
    s.height = 480;
    s.shadow.map_size = 2048;
    s.shadow.pcf_radius = 1.5f;
    s.shadow.bias = 1.5f;
    s.pathtrace.seed = 1;
    s.pathtrace.spp = 64;
    s.diffusion.voxel_resolution = 32;
    s.diffusion.tsm_size = 512;
    s.diffusion.solver = NACRE_SOLVER_MULTIGRID;
    s.diffusion.source = NACRE_SOURCE_VOLUME;
    s.diffusion.tolerance = 1e-4f;
    s.diffusion.single_scattering = NACRE_SINGLE_SCATTERING_AUTO;
    s.layered.samples = 16;
    s.layered.epsilon = 0.01f;
    s.layered.integration = NACRE_LAYERED_ANALYTIC;
    s.layered.half_res = 0.05f;
    s.volumetrics.mode = NACRE_VOLUMETRICS_OFF;
    s.volumetrics.froxel_width = 160;
    s.volumetrics.froxel_height = 90;
    s.volumetrics.froxel_slices = 64;
    s.volumetrics.raymarch_steps = 64;
    s.volumetrics.shadow_steps = 8;
    return s;
}

static int name_index(const char *name, const char *const *names, int count)
{
    for (int i = 0; name && i < count; i++)
        if (strcmp(name, names[i]) == 0)
            return i;
    return -1;
}

/* The two functions of one enumeration whose values are 0 .. count - 1, named by `table` (its
 * length gives the count): TYPE's name ("unknown" out of range) and TYPE from a name. */
#define NAMED_ENUM(type, name_fn, from_fn, ...)                                                     \
    static const char *const name_fn##_table[] = {__VA_ARGS__};                                     \
    enum { name_fn##_count = (int)(sizeof(name_fn##_table) / sizeof(name_fn##_table[0])) };          \
    const char *name_fn(type value)                                                                 \
    {                                                                                               \
        return (unsigned)value < (unsigned)name_fn##_count ? name_fn##_table[value] : "unknown";    \
    }                                                                                               \
    bool from_fn(const char *name, type *out)                                                       \
    {                                                                                               \
        int i = name_index(name, name_fn##_table, name_fn##_count);                                 \
        if (i >= 0)                                                                                 \
            *out = (type)i;                                                                         \
        return i >= 0;                                                                              \
    }

NAMED_ENUM(nacre_diffusion_solver, nacre_solver_name, nacre_solver_from_name, "multigrid", "seed")
NAMED_ENUM(nacre_diffusion_source, nacre_source_name, nacre_source_from_name, "volume", "face")
NAMED_ENUM(nacre_layered_integration, nacre_layered_integration_name, nacre_layered_integration_from_name,
           "analytic", "samples")
NAMED_ENUM(nacre_volumetrics_mode, nacre_volumetrics_name, nacre_volumetrics_from_name, "off", "froxel",
           "raymarch")
NAMED_ENUM(nacre_single_scattering, nacre_single_scattering_name, nacre_single_scattering_from_name, "off", "on",
           "auto")

const char *nacre_stage_name(nacre_stage stage)
{
    switch (stage) {
#define NACRE_STAGE_CASE_(name, text) case name: return text;
        NACRE_STAGE_LIST(NACRE_STAGE_CASE_)
#undef NACRE_STAGE_CASE_
    case NACRE_STAGE_COUNT:
        break;
    }
    return "unknown";
}
