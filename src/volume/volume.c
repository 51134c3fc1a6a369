/*
 * volume.c: the closed forms of volume.h (Hubert 2020, seed 003 §1.2.7, §1.2.10, §2.1.2):
 * transmittance over homogeneous steps, the segment integral of in-scattered and emitted
 * light, and the optical depth of exponential height fog along a ray. Double precision: these
 * are evaluated a few times per pixel or per froxel, and the height-fog integral is checked to
 * 1e-5 against quadrature at exponents up to the cap of 60.
 *
 * Units: scene units along unit directions; coefficients per scene unit.
 */
#include "volume/volume.h"

/* fmin without the libm call (these run per pixel); no NaNs reach them. */
static inline double min_d(double a, double b) { return a < b ? a : b; }

double nc_vol_transmittance_steps(size_t n, const float *sigma_t, const float *length)
{
    double tau = 0.0;
    for (size_t i = 0; i < n; i++)
        tau += (double)sigma_t[i] * (double)length[i];
    return exp(-tau);
}

double nc_vol_exp_ratio(double x)
{
    return nc_vol_exp_ratio_t(x, x < NC_VOL_SERIES_MAX ? 1.0 : exp(-x));
}

double nc_vol_segment_weight(double sigma_t, double d)
{
    if (!(sigma_t > 0.0))
        return d;
    double x = sigma_t * d;
    /* e^(-40) is below double resolution against 1: the infinite segment's 1 / sigma_t, which
     * also covers d = +inf (x * ratio would give inf * 0). */
    if (x > 40.0)
        return 1.0 / sigma_t;
    return d * nc_vol_exp_ratio(x);
}

double nc_vol_inscatter_segment(double sigma_s, double sigma_t, double l_s, double d)
{
    if (sigma_s == 0.0 || l_s == 0.0)
        return 0.0; /* not 0 x inf for an infinite segment of a non-scattering medium */
    return sigma_s * l_s * nc_vol_segment_weight(sigma_t, d);
}

double nc_vol_emission_segment(double emission, double sigma_t, double d)
{
    if (emission == 0.0)
        return 0.0;
    return emission * nc_vol_segment_weight(sigma_t, d);
}

void nc_vol_march_step(nc_vol_march *m, double sigma_t, double source, double d)
{
    if (source != 0.0 && m->transmittance > 0.0)
        m->radiance += m->transmittance * source * nc_vol_segment_weight(sigma_t, d);
    m->transmittance *= exp(-sigma_t * d);
}

double nc_vol_height_integral(const nc_vol_height *h, double y0, double dir_y, double t0, double t1)
{
    if (!(t1 > t0))
        return 0.0;
    double len = t1 - t0; /* may be +inf */
    if (!(h->falloff > 0.0))
        return h->cap >= 0.0 ? len : len * exp(h->cap);
    double k = h->falloff, s = fabs(dir_y);
    /* Lengths come from ray parameters and heights from the lower end: a nearly horizontal ray
     * never divides a tiny height difference by a tiny slope. */
    if (isinf(len) && dir_y < 0.0)
        return INFINITY; /* descends into the capped density forever */
    double y_lo = dir_y >= 0.0 ? y0 + dir_y * t0 : y0 + dir_y * t1;
    double f_lo = exp(min_d(h->cap, -k * (y_lo - h->base)));
    if (s == 0.0)
        return f_lo > 0.0 ? len * f_lo : 0.0; /* level: constant density (0 x inf is 0 here) */
    /* Below the cap's height yc the density is the constant e^cap. */
    double yc = h->base - h->cap / k, capped = 0.0;
    if (y_lo < yc) {
        capped = min_d(len, (yc - y_lo) / s);
        f_lo = exp(h->cap);
    }
    double rest = len - capped, total = capped * f_lo;
    if (rest > 0.0) {
        if (isinf(rest))
            total += f_lo / (k * s); /* rising forever: integral of e^(-k s t) */
        else
            total += rest * f_lo * nc_vol_exp_ratio(k * s * rest);
    }
    return total;
}
