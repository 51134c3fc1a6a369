/*
 * optics.c: see optics.h. Formulas: Fresnel equations for unpolarized light (Born and Wolf);
 * Jensen, Marschner, Levoy, Hanrahan 2001 for Fdr and Rd; Henyey and Greenstein 1941.
 */
#include "core/optics.h"

#include <math.h>

double nc_fresnel_dielectric(double cos_i, double eta)
{
    if (cos_i < 0.0)
        cos_i = 0.0;
    if (cos_i > 1.0)
        cos_i = 1.0;
    double sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if (sin2_t >= 1.0)
        return 1.0;
    double cos_t = sqrt(1.0 - sin2_t);
    double rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    double rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

double nc_fresnel_diffuse(double eta)
{
    /* Composite Simpson in mu; the integrand has a kink at the critical angle, so enough panels
     * that the error stays below 1e-7 there too. */
    const int n = 4096;
    double sum = 0.0;
    for (int i = 0; i <= n; i++) {
        double mu = (double)i / n;
        double w = (i == 0 || i == n) ? 1.0 : (i & 1) ? 4.0 : 2.0;
        sum += w * nc_fresnel_dielectric(mu, eta) * mu;
    }
    return 2.0 * sum / (3.0 * n);
}

double nc_fresnel_fdr(double eta)
{
    /* Valid for eta near 1 to 2; below 1 the second branch of the same source applies. */
    if (eta >= 1.0)
        return -1.440 / (eta * eta) + 0.710 / eta + 0.668 + 0.0636 * eta;
    return -0.4399 + 0.7099 / eta - 0.3319 / (eta * eta) + 0.0636 / (eta * eta * eta);
}

double nc_dipole_rd(double alpha_p, double eta)
{
    double fdr = nc_fresnel_fdr(eta);
    double A = (1.0 + fdr) / (1.0 - fdr);
    double s = sqrt(3.0 * (1.0 - alpha_p));
    return 0.5 * alpha_p * (1.0 + exp(-4.0 / 3.0 * A * s)) * exp(-s);
}

double nc_hg_phase(double cos_theta, double g)
{
    double d = 1.0 + g * g - 2.0 * g * cos_theta;
    return (1.0 - g * g) / (4.0 * 3.14159265358979323846 * d * sqrt(d));
}

double nc_hg_sample_cos(double g, double u)
{
    /* Near g = 0 the inverse divides by g; the isotropic limit is exact enough there. */
    if (fabs(g) < 1e-3)
        return 1.0 - 2.0 * u;
    double s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u);
    double c = (1.0 + g * g - s * s) / (2.0 * g);
    return c < -1.0 ? -1.0 : c > 1.0 ? 1.0 : c;
}

bool nc_refract(const float d[3], const float n[3], double eta, float out[3])
{
    double cos_i = -((double)d[0] * n[0] + (double)d[1] * n[1] + (double)d[2] * n[2]);
    double sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if (sin2_t >= 1.0)
        return false;
    double cos_t = sqrt(1.0 - sin2_t);
    /* Snell in vector form: the tangential part scales by 1/eta, the normal part becomes cos_t. */
    for (int k = 0; k < 3; k++)
        out[k] = (float)(d[k] / eta + (cos_i / eta - cos_t) * n[k]);
    return true;
}
