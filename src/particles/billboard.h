/*
 * billboard.h (private): the per-ray pieces of screen-space volumetric billboards (seed 003
 * §3.1), shared by the post pass (src/render/post_particles.c) and its tests.
 *
 * A particle seen along a ray that passes at distance rho from its centre covers the chord
 * [t* - h, t* + h], h = sqrt(R^2 - rho^2), t* the ray parameter closest to the centre. Its
 * column density along the ray is that of the kernel (nacre/particles.h),
 *   D(rho) = d0 K R exp(-4.5 rho^2 / R^2),
 * so the billboard's transmittance is exp(-sigma_t D): the seed's billboard texture, here from
 * the analytic kernel instead of an artist's texture. The pixel keeps the sum of the optical
 * depths (the product of transmittances) and the smallest t* - h and largest t* + h: the seed's
 * "displacement" of the fragment's depth, which it takes from the texture value, is here the
 * half-chord of the sphere.
 *
 * Reconstruction (figure 3.5): over [near, far], sigma_t = tau / (far - near) (Beer-Lambert
 * solved for sigma_t), shaped by the remapping r (figure 3.7)
 *   f(x) = min(x / T, 1) / (1 - T / 2),   r(x) = f(1 - 2 |x - 0.5|),
 * which vanishes at both ends and integrates to 1 over [0, 1] for any T in (0, 1], so the
 * reconstructed profile keeps the pixel's optical depth while its density ramps in and out.
 * T = 1 (a tent, the closest of the family to a Gaussian's bell) is what the pass uses.
 */
#ifndef NACRE_PARTICLES_BILLBOARD_H
#define NACRE_PARTICLES_BILLBOARD_H

#include "core/math.h"
#include "core/simd.h"

#include <math.h>
#include <stdbool.h>
#include <stdint.h>

#define NC_BILLBOARD_REMAP_T 1.0f

static inline float nc_billboard_remap(float x, float T)
{
    if (!(x > 0.0f && x < 1.0f))
        return 0.0f;
    float y = 1.0f - 2.0f * fabsf(x - 0.5f);
    return fminf(y / T, 1.0f) / (1.0f - 0.5f * T);
}

/* One particle (view-space centre offset v = c - ray origin, radius R) against a ray of unit
 * direction d: false if it misses; else the column weight exp(-4.5 rho^2 / R^2) (multiply by
 * d0 K R for the column density), the closest parameter t* and the half-chord h. */
static inline bool nc_billboard_hit(const float v[3], const float d[3], float R, float *weight, float *tmid,
                                    float *half)
{
    float t = v[0] * d[0] + v[1] * d[1] + v[2] * d[2];
    float rho2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2] - t * t;
    float R2 = R * R;
    if (!(rho2 < R2))
        return false;
    rho2 = fmaxf(rho2, 0.0f);
    *weight = nc_fast_exp(-4.5f * rho2 / R2);
    *tmid = t;
    *half = sqrtf(R2 - rho2);
    return true;
}

/* nc_fast_exp on 8 lanes: the same steps lane by lane (0 below 2^-126, capped at 2^126). */
static inline nc_v8f nc_billboard_exp8(nc_v8f x)
{
    nc_v8f y = x * 1.44269504f;
    const nc_v8i live = y > -126.0f;
    y = nc_v8_sel(live, nc_v8_sel(y < 126.0f, y, nc_v8_splat(126.0f)), nc_v8_splat(0.0f));
    const nc_v8f n = nc_v8_floor(y), f = y - n;
    nc_v8f p = nc_v8_splat(1.8775767e-3f);
    p = p * f + 8.9893397e-3f;
    p = p * f + 5.5826318e-2f;
    p = p * f + 2.4015361e-1f;
    p = p * f + 6.9315308e-1f;
    p = p * f + 9.9999994e-1f;
    const nc_v8i bits = (__builtin_convertvector(n, nc_v8i) + 127) << 23;
    return nc_v8_sel(live, p * (nc_v8f)bits, nc_v8_splat(0.0f));
}

#endif /* NACRE_PARTICLES_BILLBOARD_H */
