/*
 * isosurface.c: the isosurface of a voxelized particle system (seed 003 §3.2.2, figure 3.15:
 * "the ray march also lets us trace an isosurface"), found on the same trilinear density field
 * the renderers march, so that the surface sits where the medium's density equals the level.
 *
 * A ray is clipped to the grid's samples, stepped at half the smallest spacing until the density
 * rises to the level, and the crossing refined by bisection (20 halvings) and a final linear
 * interpolation, so the surface shows no voxel steps. The normal is minus the gradient of the
 * trilinear field by central differences one spacing wide (the trilinear field's own gradient
 * jumps at cell faces; a spacing-wide difference is continuous and, on a blob sampled finely,
 * within a fraction of a degree of the true gradient: tests/unit/test_particles.c).
 * Units: world space, scene units; distances along the ray's direction as given.
 */
#include "particles/particles.h"

#include <math.h>

float nc_particle_grid_density(const nc_particle_grid *g, const float p[3])
{
    int32_t i[3];
    float f[3];
    for (int a = 0; a < 3; a++) {
        float x = (p[a] - g->origin[a]) / g->spacing[a], top = (float)(g->dims[a] - 1);
        if (!(x >= 0.0f && x <= top))
            return 0.0f; /* the outer layers are 0: the field is continuous there */
        int32_t k = (int32_t)x;
        if (k > (int32_t)g->dims[a] - 2)
            k = (int32_t)g->dims[a] - 2;
        i[a] = k;
        f[a] = x - (float)k;
    }
    const size_t nx = g->dims[0], nxy = nx * g->dims[1];
    const float *c = g->data + (size_t)i[2] * nxy + (size_t)i[1] * nx + (size_t)i[0];
    float x00 = c[0] + f[0] * (c[1] - c[0]);
    float x10 = c[nx] + f[0] * (c[nx + 1] - c[nx]);
    float x01 = c[nxy] + f[0] * (c[nxy + 1] - c[nxy]);
    float x11 = c[nxy + nx] + f[0] * (c[nxy + nx + 1] - c[nxy + nx]);
    float y0 = x00 + f[1] * (x10 - x00), y1 = x01 + f[1] * (x11 - x01);
    return y0 + f[2] * (y1 - y0);
}

static float density_at(const nc_particle_grid *g, const float o[3], const float d[3], double t)
{
    const float p[3] = {(float)(o[0] + t * d[0]), (float)(o[1] + t * d[1]), (float)(o[2] + t * d[2])};
    return nc_particle_grid_density(g, p);
}

bool nc_particle_iso_hit(const nc_particle_grid *g, float level, const float o[3], const float d[3], double t0,
                         double t1, double *t_hit)
{
    if (g->dims[0] < 2 || !(level > 0.0f) || !(g->max_value >= level))
        return false;
    double h = INFINITY;
    for (int a = 0; a < 3; a++) {
        double lo = g->origin[a], hi = lo + (double)g->spacing[a] * (g->dims[a] - 1);
        h = fmin(h, 0.5 * g->spacing[a]);
        if (d[a] == 0.0f) {
            if (o[a] < lo || o[a] > hi)
                return false;
            continue;
        }
        double ta = (lo - o[a]) / d[a], tb = (hi - o[a]) / d[a];
        t0 = fmax(t0, fmin(ta, tb));
        t1 = fmin(t1, fmax(ta, tb));
    }
    if (!(t1 > t0))
        return false;
    double len = sqrt((double)d[0] * d[0] + (double)d[1] * d[1] + (double)d[2] * d[2]);
    h /= len;
    double ta = t0;
    float da = density_at(g, o, d, ta);
    if (da >= level)
        return false; /* the ray starts inside: no surface to enter */
    while (ta < t1) {
        double tb = fmin(ta + h, t1);
        float db = density_at(g, o, d, tb);
        if (db >= level) {
            for (int k = 0; k < 20; k++) {
                double tm = 0.5 * (ta + tb);
                float dm = density_at(g, o, d, tm);
                if (dm >= level)
                    tb = tm, db = dm;
                else
                    ta = tm, da = dm;
            }
            double w = db > da ? (double)(level - da) / (double)(db - da) : 1.0;
            *t_hit = ta + fmin(fmax(w, 0.0), 1.0) * (tb - ta);
            return true;
        }
        ta = tb;
        da = db;
    }
    return false;
}

bool nc_particle_iso_normal(const nc_particle_grid *g, const float p[3], float n[3])
{
    float len2 = 0.0f;
    for (int a = 0; a < 3; a++) {
        float e = g->spacing[a], q[3] = {p[0], p[1], p[2]};
        q[a] = p[a] + e;
        float up = nc_particle_grid_density(g, q);
        q[a] = p[a] - e;
        float dn = nc_particle_grid_density(g, q);
        n[a] = -(up - dn) / (2.0f * e);
        len2 += n[a] * n[a];
    }
    if (!(len2 > 0.0f))
        return false;
    float inv = 1.0f / sqrtf(len2);
    for (int a = 0; a < 3; a++)
        n[a] *= inv;
    return true;
}

double nc_particle_grid_exit(const nc_particle_grid *g, const float p[3], const float d[3])
{
    double t = INFINITY;
    for (int a = 0; a < 3; a++) {
        if (d[a] == 0.0f)
            continue;
        double lo = g->origin[a], hi = lo + (double)g->spacing[a] * (g->dims[a] - 1);
        t = fmin(t, ((d[a] > 0.0f ? hi : lo) - p[a]) / d[a]);
    }
    return isfinite(t) && t > 0.0 ? t : 0.0;
}
