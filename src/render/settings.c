/*
 * settings.c: render settings defaults and the names of their enumerations (solver, source,
 * stage). Method names live with the method table (methods.c).
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

static const char *const solver_names[] = {"multigrid", "seed"};
static const char *const source_names[] = {"volume", "face"};
static const char *const volumetrics_names[] = {"off", "froxel", "raymarch"};
static const char *const single_names[] = {"off", "on", "auto"};

const char *nacre_solver_name(nacre_diffusion_solver solver)
{
    return (unsigned)solver < 2 ? solver_names[solver] : "unknown";
}

const char *nacre_source_name(nacre_diffusion_source source)
{
    return (unsigned)source < 2 ? source_names[source] : "unknown";
}

static int name_index(const char *name, const char *const *names, int count)
{
    for (int i = 0; name && i < count; i++)
        if (strcmp(name, names[i]) == 0)
            return i;
    return -1;
}

bool nacre_solver_from_name(const char *name, nacre_diffusion_solver *out)
{
    int i = name_index(name, solver_names, 2);
    if (i >= 0)
        *out = (nacre_diffusion_solver)i;
    return i >= 0;
}

bool nacre_source_from_name(const char *name, nacre_diffusion_source *out)
{
    int i = name_index(name, source_names, 2);
    if (i >= 0)
        *out = (nacre_diffusion_source)i;
    return i >= 0;
}

static const char *const integration_names[] = {"analytic", "samples"};

const char *nacre_layered_integration_name(nacre_layered_integration integration)
{
    return (unsigned)integration < 2 ? integration_names[integration] : "unknown";
}

bool nacre_layered_integration_from_name(const char *name, nacre_layered_integration *out)
{
    int i = name_index(name, integration_names, 2);
    if (i >= 0)
        *out = (nacre_layered_integration)i;
    return i >= 0;
}

const char *nacre_volumetrics_name(nacre_volumetrics_mode mode)
{
    return (unsigned)mode < 3 ? volumetrics_names[mode] : "unknown";
}

bool nacre_volumetrics_from_name(const char *name, nacre_volumetrics_mode *out)
{
    int i = name_index(name, volumetrics_names, 3);
    if (i >= 0)
        *out = (nacre_volumetrics_mode)i;
    return i >= 0;
}

const char *nacre_single_scattering_name(nacre_single_scattering mode)
{
    return (unsigned)mode < 3 ? single_names[mode] : "unknown";
}

bool nacre_single_scattering_from_name(const char *name, nacre_single_scattering *out)
{
    int i = name_index(name, single_names, 3);
    if (i >= 0)
        *out = (nacre_single_scattering)i;
    return i >= 0;
}

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
