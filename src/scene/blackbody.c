/*
 * blackbody.c: nacre_blackbody_rgb, the radiance of a black body at a temperature in linear
 * Rec.709 RGB, W / (m^2 sr) per channel (Planck's law against the CIE 1931 colour matching
 * functions; see blackbody.h and scripts/make_blackbody_table.py). Fog emission from temperature
 * grids reads it per point (scene/medium.c), so it interpolates a table in ln-ln (exact at the
 * nodes; the table's neighbours differ by under 1% in T) rather than integrating the spectrum.
 * Above the table's last temperature it extrapolates the last segment (the Rayleigh-Jeans limit
 * grows as T); below the first, and for NaN, it gives 0 (under 1e-16 of a body at 1000 K).
 */
#include "scene/blackbody.h"

#include <nacre/scene.h>

#include <math.h>

void nacre_blackbody_rgb(double kelvin, float rgb[3])
{
    rgb[0] = rgb[1] = rgb[2] = 0.0f;
    if (!(kelvin >= NC_BLACKBODY_T_MIN))
        return;
    double u = log(kelvin / NC_BLACKBODY_T_MIN) / log(NC_BLACKBODY_T_MAX / NC_BLACKBODY_T_MIN) *
               (NC_BLACKBODY_COUNT - 1);
    int i = u >= NC_BLACKBODY_COUNT - 2 ? NC_BLACKBODY_COUNT - 2 : (int)u;
    double f = u - i;
    for (int c = 0; c < 3; c++) {
        double a = nc_blackbody_ln_rgb[i][c], b = nc_blackbody_ln_rgb[i + 1][c];
        /* A clipped channel (ln 1e-30) at either node stays 0 there: no ramp into the gamut. */
        if (a < -60.0 || b < -60.0)
            continue;
        rgb[c] = (float)exp(a + f * (b - a));
    }
}
