/*
 * methods.c: the table of render methods, looked up by id or by name. A new method is one row
 * here and one file implementing nc_method (method.h); nothing else in the library, the CLI or
 * the bench names methods.
 */
#include "render/method.h"

#include <string.h>

static const nc_method *const methods[NACRE_METHOD_COUNT] = {
    [NACRE_METHOD_PHONG] = &nc_method_phong,
    [NACRE_METHOD_DIFFUSION] = &nc_method_diffusion,
    [NACRE_METHOD_LAYERED] = &nc_method_layered,
    [NACRE_METHOD_PATHTRACE] = &nc_method_pathtrace,
};

const nc_method *nc_method_get(nacre_method id)
{
    return (unsigned)id < NACRE_METHOD_COUNT ? methods[id] : NULL;
}

const nc_method *nc_method_find(const char *name)
{
    for (int i = 0; name && i < NACRE_METHOD_COUNT; i++)
        if (strcmp(name, methods[i]->name) == 0)
            return methods[i];
    return NULL;
}

const char *nacre_method_name(nacre_method method)
{
    const nc_method *m = nc_method_get(method);
    return m ? m->name : "unknown";
}

bool nacre_method_from_name(const char *name, nacre_method *out)
{
    const nc_method *m = nc_method_find(name);
    if (m)
        *out = m->id;
    return m != NULL;
}

bool nacre_method_available(nacre_method method)
{
    const nc_method *m = nc_method_get(method);
    return m && m->render && (!m->available || m->available());
}

bool nacre_method_info_get(nacre_method method, nacre_method_info *out)
{
    const nc_method *m = nc_method_get(method);
    if (!m || !out)
        return false;
    *out = (nacre_method_info){.name = m->name,
                               .available = nacre_method_available(method),
                               .needs_objects = m->needs_objects,
                               .stochastic = m->stochastic,
                               .renders_fog = m->renders_fog,
                               .stages = m->stages};
    return true;
}
