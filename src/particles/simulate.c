/*
 * simulate.c: particle systems at a time T (seed 003 chapter 3; kernel and units in
 * nacre/particles.h). An emitter's particle k is born at t_k = k / rate; at T the particles
 * with T - lifetime < t_k <= T are alive. Every random number of particle k is a hash of
 * (seed, k, draw), a counter-based generator: a particle's state depends on nothing but its
 * index and T, so the loop runs in parallel and any thread count gives the same bits.
 *
 * Motion: dv/dt = g - k v has the closed form
 *   v(a) = g / k + (v0 - g / k) e^{-k a}
 *   x(a) = x0 + v0 E(a) + g (a - E(a)) / k,   E(a) = (1 - e^{-k a}) / k,
 * (k = 0: x0 + v0 a + g a^2 / 2), which is what fixed steps converge to; it is exact at every T,
 * so a frame at T does not depend on the frames before it or on a step size.
 */
#include "particles/particles.h"

#include "core/math.h"

#include <math.h>
#include <string.h>

#define NC_PI_D 3.14159265358979323846

/* splitmix64 finaliser over (seed, particle, draw): independent uniform numbers per particle. */
static inline uint64_t mix64(uint64_t x)
{
    x += 0x9e3779b97f4a7c15ull;
    x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
    x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
    return x ^ (x >> 31);
}

static inline double uniform(uint64_t seed, uint64_t k, uint32_t draw)
{
    uint64_t h = mix64(mix64(seed ^ 0x243f6a8885a308d3ull) ^ (k * 0x9e3779b97f4a7c15ull + draw));
    return (double)(h >> 11) * (1.0 / 9007199254740992.0); /* [0, 1) */
}

static bool finite3(const float v[3]) { return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]); }
static bool nonneg3(const float v[3]) { return finite3(v) && v[0] >= 0 && v[1] >= 0 && v[2] >= 0; }

nacre_result nc_particles_check(nacre_context *ctx, const nacre_particles_desc *d)
{
    const nacre_result bad = NACRE_ERROR_INVALID_ARGUMENT;
    if (d->type != NACRE_PARTICLES_EMITTER && d->type != NACRE_PARTICLES_LIST)
        return nc_fail(ctx, bad, "particles: type: unknown (%d)", (int)d->type);
    if (!nonneg3(d->sigma_a))
        return nc_fail(ctx, bad, "particles: sigma_a: must be finite and >= 0");
    if (!nonneg3(d->sigma_s))
        return nc_fail(ctx, bad, "particles: sigma_s: must be finite and >= 0");
    if (!(isfinite(d->g) && d->g > -1 && d->g < 1))
        return nc_fail(ctx, bad, "particles: g: must be in (-1, 1)");
    if (d->grid_resolution != 0 &&
        (d->grid_resolution < NACRE_PARTICLES_GRID_MIN || d->grid_resolution > NACRE_PARTICLES_GRID_MAX))
        return nc_fail(ctx, bad, "particles: grid_resolution: must be %u..%u (got %u)", NACRE_PARTICLES_GRID_MIN,
                       NACRE_PARTICLES_GRID_MAX, d->grid_resolution);
    if (!(isfinite(d->isosurface.density) && d->isosurface.density >= 0))
        return nc_fail(ctx, bad, "particles: isosurface.density: must be finite and >= 0 (got %g)",
                       (double)d->isosurface.density);
    if (d->isosurface.density > 0 && !(d->isosurface.ior >= 1 && d->isosurface.ior <= 4))
        return nc_fail(ctx, bad, "particles: isosurface.ior: must be in [1, 4] (got %g)", (double)d->isosurface.ior);
    if (d->isosurface.density > 0 && !(d->isosurface.roughness >= 0 && d->isosurface.roughness <= 1))
        return nc_fail(ctx, bad, "particles: isosurface.roughness: must be in [0, 1] (got %g)",
                       (double)d->isosurface.roughness);
    if (!(isfinite(d->radius) && d->radius > 0))
        return nc_fail(ctx, bad, "particles: radius: must be finite and > 0 (got %g)", (double)d->radius);
    if (!(isfinite(d->density) && d->density >= 0))
        return nc_fail(ctx, bad, "particles: density: must be finite and >= 0 (got %g)", (double)d->density);
    if (d->type == NACRE_PARTICLES_LIST) {
        if (d->count < 1 || d->count > NACRE_PARTICLES_MAX)
            return nc_fail(ctx, bad, "particles: count: must be 1..%u (got %u)", NACRE_PARTICLES_MAX, d->count);
        if (!d->positions)
            return nc_fail(ctx, bad, "particles: positions: missing");
        for (uint32_t i = 0; i < d->count; i++) {
            if (!finite3(d->positions + 3 * (size_t)i))
                return nc_fail(ctx, bad, "particles: positions[%u]: must be finite", i);
            if (d->radii && !(isfinite(d->radii[i]) && d->radii[i] > 0))
                return nc_fail(ctx, bad, "particles: radii[%u]: must be finite and > 0 (got %g)", i,
                               (double)d->radii[i]);
            if (d->densities && !(isfinite(d->densities[i]) && d->densities[i] >= 0))
                return nc_fail(ctx, bad, "particles: densities[%u]: must be finite and >= 0 (got %g)", i,
                               (double)d->densities[i]);
        }
        return NACRE_OK;
    }
    if (d->shape != NACRE_EMITTER_POINT && d->shape != NACRE_EMITTER_BOX && d->shape != NACRE_EMITTER_SPHERE)
        return nc_fail(ctx, bad, "particles: shape: unknown (%d)", (int)d->shape);
    if (!finite3(d->center))
        return nc_fail(ctx, bad, "particles: center: must be finite");
    if (!nonneg3(d->size))
        return nc_fail(ctx, bad, "particles: size: must be finite and >= 0");
    if (!(isfinite(d->emit_radius) && d->emit_radius >= 0))
        return nc_fail(ctx, bad, "particles: emit_radius: must be finite and >= 0");
    if (!(isfinite(d->lifetime) && d->lifetime > 0))
        return nc_fail(ctx, bad, "particles: lifetime: must be finite and > 0 (got %g)", (double)d->lifetime);
    if (!(isfinite(d->rate) && d->rate > 0))
        return nc_fail(ctx, bad, "particles: rate: must be finite and > 0 (got %g)", (double)d->rate);
    double alive = ceil((double)d->rate * (double)d->lifetime) + 1.0;
    if (alive > (double)NACRE_PARTICLES_MAX)
        return nc_fail(ctx, bad,
                       "particles: rate: rate * lifetime = %.4g particles alive at once, over the cap of %u "
                       "(NACRE_PARTICLES_MAX)",
                       (double)d->rate * (double)d->lifetime, NACRE_PARTICLES_MAX);
    if (!finite3(d->velocity))
        return nc_fail(ctx, bad, "particles: velocity: must be finite");
    if (!(isfinite(d->spread) && d->spread >= 0 && d->spread <= 180))
        return nc_fail(ctx, bad, "particles: spread: must be in [0, 180] degrees");
    if (!(isfinite(d->speed_jitter) && d->speed_jitter >= 0 && d->speed_jitter <= 1))
        return nc_fail(ctx, bad, "particles: speed_jitter: must be in [0, 1]");
    if (!finite3(d->gravity))
        return nc_fail(ctx, bad, "particles: gravity: must be finite");
    if (!(isfinite(d->drag) && d->drag >= 0))
        return nc_fail(ctx, bad, "particles: drag: must be finite and >= 0");
    if (!(isfinite(d->radius_jitter) && d->radius_jitter >= 0 && d->radius_jitter < 1))
        return nc_fail(ctx, bad, "particles: radius_jitter: must be in [0, 1)");
    if (!(isfinite(d->radius_rate) && d->radius_rate >= 0))
        return nc_fail(ctx, bad, "particles: radius_rate: must be finite and >= 0");
    if (!(isfinite(d->fade) && d->fade >= 0 && d->fade <= 1))
        return nc_fail(ctx, bad, "particles: fade: must be in [0, 1]");
    return NACRE_OK;
}

void nc_particle_set_free(nacre_context *ctx, nc_particle_set *s)
{
    nc_free(ctx, s->x);
    nc_free(ctx, s->y);
    nc_free(ctx, s->z);
    nc_free(ctx, s->radius);
    nc_free(ctx, s->density);
    memset(s, 0, sizeof(*s));
}

static nacre_result reserve(nacre_context *ctx, nc_particle_set *s, uint32_t n)
{
    if (n <= s->capacity)
        return NACRE_OK;
    nc_particle_set g;
    memset(&g, 0, sizeof(g));
    size_t bytes = (size_t)n * sizeof(float);
    nacre_result r = nc_memory_check(ctx, 5 * (uint64_t)bytes, "particle state (particles: rate * lifetime)");
    if (r != NACRE_OK)
        return r;
    g.x = nc_alloc(ctx, bytes);
    g.y = nc_alloc(ctx, bytes);
    g.z = nc_alloc(ctx, bytes);
    g.radius = nc_alloc(ctx, bytes);
    g.density = nc_alloc(ctx, bytes);
    if (!g.x || !g.y || !g.z || !g.radius || !g.density) {
        nc_particle_set_free(ctx, &g);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    nc_particle_set_free(ctx, s);
    *s = g;
    s->capacity = n;
    return NACRE_OK;
}

/* Two unit vectors perpendicular to unit w. */
static void basis(const double w[3], double u[3], double v[3])
{
    double a[3] = {1, 0, 0};
    if (fabs(w[0]) > 0.9) {
        a[0] = 0;
        a[1] = 1;
    }
    u[0] = a[1] * w[2] - a[2] * w[1];
    u[1] = a[2] * w[0] - a[0] * w[2];
    u[2] = a[0] * w[1] - a[1] * w[0];
    double n = sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
    for (int c = 0; c < 3; c++)
        u[c] /= n;
    v[0] = w[1] * u[2] - w[2] * u[1];
    v[1] = w[2] * u[0] - w[0] * u[2];
    v[2] = w[0] * u[1] - w[1] * u[0];
}

nacre_result nc_particles_simulate(nacre_context *ctx, const nacre_particles_desc *d, double time,
                                   nc_particle_set *s)
{
    if (d->type == NACRE_PARTICLES_LIST) {
        nacre_result r = reserve(ctx, s, d->count);
        if (r != NACRE_OK)
            return r;
        for (uint32_t i = 0; i < d->count; i++) {
            s->x[i] = d->positions[3 * (size_t)i];
            s->y[i] = d->positions[3 * (size_t)i + 1];
            s->z[i] = d->positions[3 * (size_t)i + 2];
            s->radius[i] = d->radii ? d->radii[i] : d->radius;
            s->density[i] = d->densities ? d->densities[i] : d->density;
        }
        s->count = d->count;
        return NACRE_OK;
    }
    s->count = 0;
    const double rate = d->rate, life = d->lifetime;
    if (!(time >= 0))
        return NACRE_OK; /* nothing born before t = 0 */
    /* Alive: k / rate in (T - life, T], k >= 0. */
    double klast = floor(time * rate), kfirst = floor((time - life) * rate) + 1.0;
    if (kfirst < 0)
        kfirst = 0;
    if (klast < kfirst)
        return NACRE_OK;
    if (klast - kfirst + 1.0 > (double)NACRE_PARTICLES_MAX)
        kfirst = klast - (double)NACRE_PARTICLES_MAX + 1.0; /* rounding at the cap's edge */
    if (!(klast < 9.0e15))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "particles: time: %g s at rate %g is past the last "
                       "particle index this generator can number", time, rate);
    uint32_t n = (uint32_t)(klast - kfirst + 1.0);
    nacre_result r = reserve(ctx, s, n);
    if (r != NACRE_OK)
        return r;
    const uint64_t k0 = (uint64_t)kfirst;
    double w[3] = {d->velocity[0], d->velocity[1], d->velocity[2]};
    double speed = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    double eu[3] = {0, 0, 0}, ev[3] = {0, 0, 0};
    if (speed > 0) {
        for (int c = 0; c < 3; c++)
            w[c] /= speed;
        basis(w, eu, ev);
    }
    const double cos_max = cos((double)d->spread * NC_PI_D / 180.0);
    const double drag = d->drag;
    const double grav[3] = {d->gravity[0], d->gravity[1], d->gravity[2]};
    const uint64_t seed = d->seed;
#ifdef _OPENMP
#pragma omp parallel for schedule(static) num_threads(nc_threads(ctx))
#endif
    for (uint32_t i = 0; i < n; i++) {
        uint64_t k = k0 + i;
        double age = time - (double)k / rate;
        if (age < 0)
            age = 0;
        double p[3] = {d->center[0], d->center[1], d->center[2]};
        if (d->shape == NACRE_EMITTER_BOX) {
            for (int c = 0; c < 3; c++)
                p[c] += (uniform(seed, k, (uint32_t)c) - 0.5) * d->size[c];
        } else if (d->shape == NACRE_EMITTER_SPHERE) {
            double z = 2.0 * uniform(seed, k, 0) - 1.0, phi = 2.0 * NC_PI_D * uniform(seed, k, 1);
            double rr = d->emit_radius * cbrt(uniform(seed, k, 2)), sxy = sqrt(fmax(0.0, 1.0 - z * z));
            p[0] += rr * sxy * cos(phi);
            p[1] += rr * sxy * sin(phi);
            p[2] += rr * z;
        }
        double v0[3] = {0, 0, 0};
        if (speed > 0) {
            /* Uniform over the cap's solid angle: cos theta uniform in [cos_max, 1]. */
            double ct = 1.0 - uniform(seed, k, 3) * (1.0 - cos_max), st = sqrt(fmax(0.0, 1.0 - ct * ct));
            double phi = 2.0 * NC_PI_D * uniform(seed, k, 4);
            double sp = speed * (1.0 + d->speed_jitter * (2.0 * uniform(seed, k, 5) - 1.0));
            for (int c = 0; c < 3; c++)
                v0[c] = sp * (ct * w[c] + st * (cos(phi) * eu[c] + sin(phi) * ev[c]));
        }
        /* E(a) = (1 - e^{-k a}) / k and (a - E(a)) / k, by series where k a is small. */
        double ka = drag * age, E, F;
        if (ka < 1e-4) {
            E = age * (1.0 - 0.5 * ka + ka * ka / 6.0);
            F = age * age * (0.5 - ka / 6.0 + ka * ka / 24.0);
        } else {
            E = -expm1(-ka) / drag;
            F = (age - E) / drag;
        }
        s->x[i] = (float)(p[0] + v0[0] * E + grav[0] * F);
        s->y[i] = (float)(p[1] + v0[1] * E + grav[1] * F);
        s->z[i] = (float)(p[2] + v0[2] * E + grav[2] * F);
        double r0 = d->radius * (1.0 + d->radius_jitter * (2.0 * uniform(seed, k, 6) - 1.0));
        s->radius[i] = (float)(r0 + d->radius_rate * age);
        s->density[i] = (float)(d->density * fmax(0.0, 1.0 - d->fade * age / life));
    }
    s->count = n;
    return NACRE_OK;
}

double nc_particles_mass(const nc_particle_set *s)
{
    double m = 0.0;
    for (uint32_t i = 0; i < s->count; i++) {
        double kr = (double)NC_PARTICLE_KERNEL_K * s->radius[i];
        m += (double)s->density[i] * kr * kr * kr;
    }
    return m;
}
