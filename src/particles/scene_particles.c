/*
 * scene_particles.c: particle systems stored in a scene (nacre/particles.h) and turned into fogs
 * at commit. Each system with particles alive at the commit time becomes one BOX fog over its
 * density grid with a VOLUME pattern (seed 003 §3.2: the voxelized particles are a medium like
 * any other), appended after the scene's own fogs; the path tracer renders it exactly and the
 * fog passes read it as they read any patterned fog. The grid's volume record lives here and is
 * named by a volume handle with NC_PARTICLE_VOLUME_BIT, so scene files never see it.
 */
#include "particles/particles.h"

#include "scene/scene.h"

#include <nacre/render.h>

#include <math.h>
#include <string.h>

typedef struct nc_particles_rec {
    nacre_particles_desc desc; /* list arrays point at the owned copies below */
    float *positions, *radii, *densities;
    nc_particle_set set;       /* the state at the last commit */
    nc_particle_grid grid;
    nc_volume_rec volume;      /* the grid in its fog's local frame (data borrowed from grid) */
} nc_particles_rec;

nacre_particles_desc nacre_particles_desc_defaults(nacre_particles_type type)
{
    nacre_particles_desc d;
    memset(&d, 0, sizeof(d));
    d.type = type;
    d.shape = NACRE_EMITTER_POINT;
    d.rate = 100.0f;
    d.lifetime = 2.0f;
    d.velocity[1] = 1.0f;
    d.spread = 15.0f;
    d.radius = 0.2f;
    d.density = 1.0f;
    d.sigma_a[0] = d.sigma_a[1] = d.sigma_a[2] = 0.1f;
    d.sigma_s[0] = d.sigma_s[1] = d.sigma_s[2] = 1.0f;
    d.grid_resolution = NACRE_PARTICLES_GRID_DEFAULT;
    d.isosurface.ior = 1.33f;
    d.isosurface.roughness = 0.2f;
    return d;
}

static void free_lists(nacre_context *ctx, nc_particles_rec *p)
{
    nc_free(ctx, p->positions);
    nc_free(ctx, p->radii);
    nc_free(ctx, p->densities);
    p->positions = p->radii = p->densities = NULL;
}

/* Copy a checked desc into p, with its lists. */
static nacre_result store(nacre_context *ctx, nc_particles_rec *p, const nacre_particles_desc *d)
{
    float *pos = NULL, *rad = NULL, *den = NULL;
    if (d->type == NACRE_PARTICLES_LIST) {
        pos = nc_alloc(ctx, 3 * sizeof(float) * d->count);
        rad = d->radii ? nc_alloc(ctx, sizeof(float) * d->count) : NULL;
        den = d->densities ? nc_alloc(ctx, sizeof(float) * d->count) : NULL;
        if (!pos || (d->radii && !rad) || (d->densities && !den)) {
            nc_free(ctx, pos);
            nc_free(ctx, rad);
            nc_free(ctx, den);
            return NACRE_ERROR_OUT_OF_MEMORY;
        }
        memcpy(pos, d->positions, 3 * sizeof(float) * d->count);
        if (rad)
            memcpy(rad, d->radii, sizeof(float) * d->count);
        if (den)
            memcpy(den, d->densities, sizeof(float) * d->count);
    }
    free_lists(ctx, p);
    p->desc = *d;
    if (p->desc.grid_resolution == 0)
        p->desc.grid_resolution = NACRE_PARTICLES_GRID_DEFAULT;
    p->positions = pos;
    p->radii = rad;
    p->densities = den;
    p->desc.positions = pos;
    p->desc.radii = rad;
    p->desc.densities = den;
    if (d->type != NACRE_PARTICLES_LIST)
        p->desc.count = 0;
    return NACRE_OK;
}

nacre_result nacre_scene_add_particles(nacre_scene *s, const nacre_particles_desc *desc, nacre_particles *out)
{
    if (!s || !desc || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    out->id = 0;
    nacre_context *ctx = s->ctx;
    nacre_result r = nc_particles_check(ctx, desc);
    if (r != NACRE_OK)
        return r;
    if (nc_scene_user_fogs(s) + s->particles_count >= NACRE_MAX_FOGS)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "particles: at most %d fogs and particle systems per scene",
                       NACRE_MAX_FOGS);
    if (s->particles_count == s->particles_capacity) {
        uint32_t cap = s->particles_capacity ? 2 * s->particles_capacity : 4;
        nc_particles_rec *g = nc_realloc(ctx, s->particles, s->particles_capacity * sizeof(*g), cap * sizeof(*g));
        if (!g)
            return NACRE_ERROR_OUT_OF_MEMORY;
        s->particles = g;
        s->particles_capacity = cap;
    }
    nc_particles_rec *p = &s->particles[s->particles_count];
    memset(p, 0, sizeof(*p));
    r = store(ctx, p, desc);
    if (r != NACRE_OK)
        return r;
    out->id = ++s->particles_count;
    s->particles_version++;
    s->versions.environment++; /* as a fog edit: renderers see the scene changed until the commit */
    return NACRE_OK;
}

nacre_result nacre_scene_set_particles(nacre_scene *s, nacre_particles h, const nacre_particles_desc *desc)
{
    if (!s || !desc)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (h.id < 1 || h.id > s->particles_count)
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "particles: invalid handle %u", h.id);
    nacre_result r = nc_particles_check(s->ctx, desc);
    if (r != NACRE_OK)
        return r;
    r = store(s->ctx, &s->particles[h.id - 1], desc);
    if (r == NACRE_OK) {
        s->particles_version++;
        s->versions.environment++;
    }
    return r;
}

nacre_result nacre_scene_get_particles(const nacre_scene *s, nacre_particles h, nacre_particles_desc *out)
{
    if (!s || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (h.id < 1 || h.id > s->particles_count)
        return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "particles: invalid handle %u", h.id);
    *out = s->particles[h.id - 1].desc;
    return NACRE_OK;
}

uint32_t nacre_scene_particles_count(const nacre_scene *s) { return s ? s->particles_count : 0; }

uint32_t nacre_scene_particles_alive(const nacre_scene *s, nacre_particles h)
{
    if (!s || h.id < 1 || h.id > s->particles_count || !s->particles_built)
        return 0;
    return s->particles[h.id - 1].set.count;
}

const nc_volume_rec *nc_scene_particle_volume(const nacre_scene *s, uint32_t index)
{
    if (index >= s->particles_count || !s->particles[index].volume.data)
        return NULL;
    return &s->particles[index].volume;
}

void nc_scene_drop_particle_fogs(nacre_scene *s)
{
    if (s->particle_fog_count) {
        s->fog_count -= s->particle_fog_count;
        s->particle_fog_count = 0;
        s->versions.environment++;
    }
    s->particles_built = 0;
}

void nc_scene_free_particles(nacre_scene *s)
{
    for (uint32_t i = 0; i < s->particles_count; i++) {
        free_lists(s->ctx, &s->particles[i]);
        nc_particle_set_free(s->ctx, &s->particles[i].set);
        nc_particle_grid_free(s->ctx, &s->particles[i].grid);
    }
    nc_free(s->ctx, s->particles);
    s->particles = NULL;
    s->particles_count = s->particles_capacity = 0;
}

nacre_result nc_scene_commit_particles(nacre_scene *s, double time)
{
    if (s->particles_count == 0) {
        nc_scene_drop_particle_fogs(s);
        return NACRE_OK;
    }
    bool moving = false;
    for (uint32_t i = 0; i < s->particles_count; i++)
        moving |= s->particles[i].desc.type == NACRE_PARTICLES_EMITTER;
    if (s->particles_built && s->particles_built == s->particles_version && (!moving || time == s->particles_time))
        return NACRE_OK;
    nc_scene_drop_particle_fogs(s);
    for (uint32_t i = 0; i < s->particles_count; i++) {
        nc_particles_rec *p = &s->particles[i];
        p->volume.data = NULL;
        nacre_result r = nc_particles_simulate(s->ctx, &p->desc, time, &p->set);
        /* The isosurface's depth and normals follow the field's shape closely (0.05 voxel): the
         * coarse level's interpolation would move them by 0.2, so such systems splat finely. */
        p->grid.fine_only = p->desc.isosurface.density > 0.0f;
        if (r == NACRE_OK)
            r = nc_particles_splat(s->ctx, &p->set, p->desc.grid_resolution, &p->grid);
        if (r != NACRE_OK) {
            nc_scene_drop_particle_fogs(s);
            return r;
        }
        if (p->grid.dims[0] == 0)
            continue; /* no particle alive: no fog */
        if (s->fog_count >= NACRE_MAX_FOGS) {
            nc_scene_drop_particle_fogs(s);
            return nc_fail(s->ctx, NACRE_ERROR_INVALID_ARGUMENT, "particles: at most %d fogs and particle systems",
                           NACRE_MAX_FOGS);
        }
        nacre_fog_desc f = nacre_fog_desc_defaults(NACRE_FOG_BOX);
        nc_volume_rec *v = &p->volume;
        memset(v, 0, sizeof(*v));
        for (int a = 0; a < 3; a++) {
            /* The box spans the cells of the samples: half a spacing beyond the outer ones. */
            float h = p->grid.spacing[a], lo = p->grid.origin[a] - 0.5f * h;
            f.size[a] = h * (float)p->grid.dims[a];
            f.center[a] = lo + 0.5f * f.size[a];
            v->dims[a] = p->grid.dims[a];
            v->spacing[a] = h;
            v->origin[a] = p->grid.origin[a] - f.center[a];
        }
        v->data = p->grid.data;
        if (p->grid.block_res == (p->grid.dims[0] + 7) / 8 && p->grid.dims[0] == p->grid.dims[1] &&
            p->grid.dims[0] == p->grid.dims[2]) {
            v->block_max = p->grid.block_max;
            v->block_res = p->grid.block_res;
        }
        v->min_value = 0.0f;
        v->max_value = p->grid.max_value;
        v->source_scale = 1.0f;
        memcpy(f.sigma_a, p->desc.sigma_a, sizeof(f.sigma_a));
        memcpy(f.sigma_s, p->desc.sigma_s, sizeof(f.sigma_s));
        f.g = p->desc.g;
        f.pattern.type = NACRE_PATTERN_VOLUME;
        f.pattern.cell_size = 1.0f;
        f.pattern.volume.id = NC_PARTICLE_VOLUME_BIT | i;
        nc_scene_store_fog(&s->fogs[s->fog_count++], &f);
        s->particle_fog_count++;
    }
    s->versions.environment++;
    s->particles_built = s->particles_version;
    s->particles_time = time;
    return NACRE_OK;
}

const nc_particle_set *nc_scene_particle_set(const nacre_scene *s, uint32_t index, const nacre_particles_desc **desc)
{
    if (!s->particles_built || index >= s->particles_count)
        return NULL;
    if (desc)
        *desc = &s->particles[index].desc;
    return &s->particles[index].set;
}

const nc_particle_grid *nc_scene_particle_grid(const nacre_scene *s, uint32_t index, const nacre_particles_desc **desc)
{
    if (!s->particles_built || index >= s->particles_count || s->particles[index].grid.dims[0] == 0)
        return NULL;
    if (desc)
        *desc = &s->particles[index].desc;
    return &s->particles[index].grid;
}

bool nc_scene_particles_iso_drawn(const nacre_scene *s, const nacre_render_settings *settings)
{
    if (settings->particles != NACRE_PARTICLES_DRAW_VOXEL)
        return false;
    for (uint32_t i = 0; i < s->particles_count; i++)
        if (s->particles[i].desc.isosurface.density > 0.0f)
            return true;
    return false;
}

static const char *const draw_names[] = {"billboards", "sprites", "voxel"};

const char *nacre_particles_draw_name(nacre_particles_draw draw)
{
    return (unsigned)draw < 3 ? draw_names[draw] : "unknown";
}

bool nacre_particles_draw_from_name(const char *name, nacre_particles_draw *out)
{
    for (int i = 0; name && i < 3; i++)
        if (strcmp(name, draw_names[i]) == 0) {
            *out = (nacre_particles_draw)i;
            return true;
        }
    return false;
}
