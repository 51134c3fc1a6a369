/*
 * optics.h: the optics every light-transport module shares: Fresnel reflectance of a smooth
 * dielectric boundary, its hemispherical (diffuse) averages, the classical dipole diffuse
 * reflectance, Henyey-Greenstein phase function. One place, so the diffusion solver, the
 * shading passes and the path tracer agree on the same numbers.
 *
 * Conventions: `eta` is the relative index n_transmitted / n_incident (1.3 for light entering
 * skin from air; 1 / 1.3 for light leaving it). Angles are given by cosines measured from the
 * boundary normal on the incident side, in [0, 1].
 */
#ifndef NACRE_OPTICS_H
#define NACRE_OPTICS_H

#include <math.h>

#include <stdbool.h>

/* Unpolarized Fresnel reflectance for light arriving at cos_i (>= 0) on a boundary of relative
 * index eta; 1 under total internal reflection. */
double nc_fresnel_dielectric(double cos_i, double eta);
/* The same in float for per-pixel use, with 1 / eta^2 precomputed by the caller; cos_i in
 * [0, 1]. Relative difference from the double version ~1e-7. */
static inline float nc_fresnel_dielectric_f(float cos_i, float eta, float inv_eta2)
{
    float sin2_t = (1.0f - cos_i * cos_i) * inv_eta2;
    if (sin2_t >= 1.0f)
        return 1.0f;
    float cos_t = sqrtf(1.0f - sin2_t);
    float rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    float rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    return 0.5f * (rs * rs + rp * rp);
}

/* Hemispherical average 2 * integral_0^1 F(mu, eta) mu dmu (numerical, 1e-7): the fraction of
 * diffuse (Lambertian) light arriving from the incident side that is reflected. */
double nc_fresnel_diffuse(double eta);
/* The polynomial fit of the diffuse Fresnel reflectance used by Jensen et al. 2001 for light
 * inside a medium of relative index eta (Egan and Hilgeman 1973). */
double nc_fresnel_fdr(double eta);
/* Total diffuse reflectance Rd of a semi-infinite medium of reduced albedo alpha_p and relative
 * index eta, per unit power entering (Jensen et al. 2001, dipole, A = (1 + Fdr) / (1 - Fdr)). */
double nc_dipole_rd(double alpha_p, double eta);
/* Henyey-Greenstein phase function value (per steradian) for cos_theta between the directions. */
double nc_hg_phase(double cos_theta, double g);
/* The same in float without pow, for the per-point loops of the real-time passes (froxels, the
 * layered march, diffusion's single scattering), where pow was a tenth of the lighting. */
static inline float nc_hg_phasef(float cos_theta, float g)
{
    float x = 1.0f + g * g - 2.0f * g * cos_theta;
    return (1.0f - g * g) / (4.0f * 3.14159265358979323846f * x * sqrtf(x));
}
/* Sample the cosine of the Henyey-Greenstein scattering angle from u uniform in [0, 1) by
 * inverting its CDF; the density of the result is 2 pi nc_hg_phase. */
double nc_hg_sample_cos(double g, double u);
/* Refract unit direction d (pointing towards the boundary) through the surface with unit normal
 * n (on the incident side, dot(d, n) < 0) for relative index eta; false under total internal
 * reflection. */
bool nc_refract(const float d[3], const float n[3], double eta, float out[3]);

#endif /* NACRE_OPTICS_H */
