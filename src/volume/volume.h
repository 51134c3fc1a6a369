/*
 * volume.h: the physical core of participating media (Hubert 2020, seed 003 §1.2), shared by
 * the real-time volumetric passes (render/post_fog.c) and the path tracer's fog
 * (pathtrace/media.c), so that both use one set of formulas:
 *   - Beer-Lambert transmittance over a homogeneous segment, e^(-sigma_t d) (§1.2.7.1), and over
 *     a run of homogeneous steps (the product of the steps' transmittances, §1.2.7.1 fig. 1.29);
 *   - the energy-conserving segment integral (§1.2.10): integral_0^d S e^(-sigma_t t) dt
 *     = S (1 - e^(-sigma_t d)) / sigma_t for a source S constant on the segment (in-scattered
 *     light sigma_s L, or emission, §1.2.11), with its sigma_t -> 0 limit S d, and front-to-back
 *     accumulation of such segments;
 *   - the exponential height fog of §2.1.2: density factor e^(-k (y - y0)), its exponent capped
 *     (as the scene format says), and its integral along a ray in closed form, with the
 *     horizontal-ray limit computed without cancellation.
 * The Henyey-Greenstein phase function keeps its one home in core/optics.h (nc_hg_phase,
 * nc_hg_sample_cos), next to the other optics that the diffusion solver also uses; this header
 * includes it so that volume code needs only this header.
 *
 * Units: lengths in scene units along unit directions, coefficients per scene unit, radiance
 * and emission (radiance per unit length) per channel; world y is up for height fog.
 */
#ifndef NACRE_VOLUME_H
#define NACRE_VOLUME_H

#include "core/optics.h"
#include "core/simd.h"

#include <math.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

/* Density cap of any fog, per scene unit: a free path far below float resolution at every
 * scene scale, so that tracking weights (products of two densities) stay finite. */
#define NC_VOL_MAX_DENSITY 1e12f
/* Cap of the height factor's exponent (the density stops growing e^60 times above its base
 * value, far below any scene; nacre_fog_desc). */
#define NC_VOL_HEIGHT_EXP_MAX 60.0f

/* ---- where a bounded fog is ------------------------------------------------------------- */

/* The part [*t0, *t1] (narrowed in place) of the ray o + t d, in the fog's local frame, inside
 * its box (|x_k| <= half[k]; slab test) or, if `ellipsoid`, inside the ellipsoid of semi-axes
 * half[k] (the unit sphere after scaling each axis by 1 / half[k]); false if empty. */
static inline bool nc_vol_shape_segment(bool ellipsoid, const double half[3], const double o[3], const double d[3],
                                        double *t0, double *t1)
{
    double a = *t0, b = *t1;
    if (ellipsoid) {
        double A = 0.0, B = 0.0, C = -1.0;
        for (int k = 0; k < 3; k++) {
            double ok = o[k] / half[k], dk = d[k] / half[k];
            A += dk * dk;
            B += ok * dk;
            C += ok * ok;
        }
        double disc = B * B - A * C;
        if (!(A > 0.0) || !(disc > 0.0))
            return false;
        /* The two roots without cancellation: q = -(B + sign(B) sqrt(disc)). */
        double q = -(B + (B >= 0.0 ? sqrt(disc) : -sqrt(disc)));
        double r0 = q / A, r1 = q != 0.0 ? C / q : -r0;
        double lo = r0 < r1 ? r0 : r1, hi = r0 < r1 ? r1 : r0;
        a = lo > a ? lo : a;
        b = hi < b ? hi : b;
    } else {
        for (int k = 0; k < 3; k++) {
            if (d[k] == 0.0) {
                if (fabs(o[k]) > half[k])
                    return false;
                continue;
            }
            double ta = (-half[k] - o[k]) / d[k], tb = (half[k] - o[k]) / d[k];
            if (ta > tb) { /* ternaries, not fmin/fmax: those are libm calls in hot loops */
                double u = ta;
                ta = tb;
                tb = u;
            }
            a = ta > a ? ta : a;
            b = tb < b ? tb : b;
        }
    }
    *t0 = a;
    *t1 = b;
    return a < b;
}

/* Whether local point q lies in the box or ellipsoid of half extents `half`. */
static inline bool nc_vol_shape_inside(bool ellipsoid, const float half[3], const float q[3])
{
    if (!ellipsoid)
        return fabsf(q[0]) <= half[0] && fabsf(q[1]) <= half[1] && fabsf(q[2]) <= half[2];
    float x = q[0] / half[0], y = q[1] / half[1], z = q[2] / half[2];
    return x * x + y * y + z * z <= 1.0f;
}

/* ---- Beer-Lambert ---------------------------------------------------------------------- */

/* Transmittance of a homogeneous segment of length d. Float, written as the path tracer has
 * always evaluated it, so that sharing it changes no bit of its images. */
static inline float nc_vol_transmittance(float sigma_t, float d) { return expf(-sigma_t * d); }

/* Transmittance through n homogeneous steps (sigma_t[i] over length[i]): the product of the
 * steps' transmittances, evaluated as e^(-sum of optical depths) (one exponential, and no
 * underflow of partial products before a step of zero density). */
double nc_vol_transmittance_steps(size_t n, const float *sigma_t, const float *length);

/* nc_vol_exp_fast's reduction and polynomial (below), for any type with float arithmetic (float
 * there, the froxel pass's 8-lane vectors): r = x - n ln 2 in two parts, and
 * e^r = NC_VOL_EXP_POLY(r) r^2 + r + 1. */
#define NC_VOL_EXP_REDUCE(x, n) ((x) - (n) * 0.693359375f - (n) * -2.12194440e-4f)
#define NC_VOL_EXP_POLY(r)                                                                                 \
    (((((1.9875691500e-4f * (r) + 1.3981999507e-3f) * (r) + 8.3334519073e-3f) * (r) + 4.1665795894e-2f) * (r) + \
      1.6666665459e-1f) * (r) + 5.0000001201e-1f)

/* e^x in float for x <= 88 (x at or below -87, or -inf, gives 0): x = n ln 2 + r with |r| <=
 * ln 2 / 2 (ln 2 in two parts), e^r by Cephes' degree-5 polynomial, 2^n built in the exponent
 * bits; relative error under 1e-7, as expf (test_volumetrics checks it). Written so that loops
 * over froxels vectorize (expf does not), where the volumetric passes take several per froxel
 * and light. */
static inline float nc_vol_exp_fast(float x)
{
    float n = floorf(x * 1.44269504f + 0.5f);
    n = n > -127.0f ? n : -127.0f;
    n = n < 127.0f ? n : 127.0f;
    float r = NC_VOL_EXP_REDUCE(x, n);
    float y = NC_VOL_EXP_POLY(r) * r * r + r + 1.0f;
    int32_t bits = ((int32_t)n + 127) << 23;
    float scale;
    memcpy(&scale, &bits, sizeof(scale));
    return x > -87.0f ? y * scale : 0.0f;
}

/* nc_vol_exp_fast lane by lane (core/simd.h). */
static inline nc_v8f nc_vol_exp_fast8(nc_v8f x)
{
    nc_v8f n = nc_v8_floor(x * 1.44269504f + 0.5f);
    n = nc_v8_sel(n > -127.0f, n, nc_v8_splat(-127.0f));
    n = nc_v8_sel(n < 127.0f, n, nc_v8_splat(127.0f));
    nc_v8f r = NC_VOL_EXP_REDUCE(x, n);
    nc_v8f y = NC_VOL_EXP_POLY(r) * r * r + r + 1.0f;
    nc_v8i bits = (__builtin_convertvector(n, nc_v8i) + 127) << 23;
    return nc_v8_sel(x > -87.0f, y * (nc_v8f)bits, (nc_v8f){0});
}

/* e^(-tau) lane by lane for tau >= 0 (+inf included): a transmittance. nc_vol_exp_fast8's
 * reduction and polynomial without its range checks: tau is clamped to 87.3 (the result, at least
 * 2^-126, stays normal: 1e-38 where exp gives less or 0), and n is rounded by adding 1.5 2^23,
 * which leaves it in the low bits. Relative error under 1e-7 (test_volumetrics); the froxels'
 * lighting takes three per froxel and light. */
static inline nc_v8f nc_vol_transmittance8(nc_v8f tau)
{
    nc_v8f x = -tau;
    x = nc_v8_sel(x > -87.3f, x, nc_v8_splat(-87.3f));
    nc_v8f t = x * 1.44269504f + 12582912.0f;
    nc_v8f n = t - 12582912.0f;
    nc_v8f r = NC_VOL_EXP_REDUCE(x, n);
    nc_v8f y = NC_VOL_EXP_POLY(r) * r * r + r + 1.0f;
    nc_v8i bits = ((nc_v8i)t + 127) << 23; /* t's exponent bits shift out */
    return y * (nc_v8f)bits;
}

/* (1 - e^(-x)) / x in float for x >= 0 (finite), with nc_vol_exp_fast: the series through x^4
 * below 0.1 (next term under 2e-8), the quotient above (cancellation: at most ~1e-6). */
static inline float nc_vol_exp_ratio_fast(float x)
{
    if (x < 0.1f)
        return 1.0f - x * (0.5f - x * (1.0f / 6.0f - x * (1.0f / 24.0f - x * (1.0f / 120.0f))));
    return (1.0f - nc_vol_exp_fast(-x)) / x;
}

/* The series of nc_vol_exp_ratio_fast (x < 0.1) lane by lane. */
static inline nc_v8f nc_vol_exp_ratio_series8(nc_v8f x)
{
    return 1.0f - x * (0.5f - x * (1.0f / 6.0f - x * (1.0f / 24.0f - x * (1.0f / 120.0f))));
}

/* nc_vol_exp_ratio_fast lane by lane given t = e^(-x) (x >= 0; +inf gives 0). */
static inline nc_v8f nc_vol_exp_ratio8(nc_v8f x, nc_v8f t)
{
    nc_v8i small = x < 0.1f;
    return nc_v8_sel(small, nc_vol_exp_ratio_series8(x), (1.0f - t) / nc_v8_sel(small, nc_v8_splat(1.0f), x));
}

/* The Henyey-Greenstein phase lane by lane at cosines cs from the constants of g (pa = 1 + g^2,
 * pb = -2 g, pc = (1 - g^2) / 4 pi, per lane or splat): pc x^-3/2 with x = pa + pb cs >= (1 -
 * |g|)^2 > 0, by nc_v8_rsqrt (relative 2^-21). */
static inline nc_v8f nc_vol_hg_phase8(nc_v8f cs, nc_v8f pa, nc_v8f pb, nc_v8f pc)
{
    nc_v8f r = nc_v8_rsqrt(pa + pb * cs);
    return pc * (r * r * r);
}

/* ---- segment integral (§1.2.10) -------------------------------------------------------- */

/* (1 - e^(-x)) / x for x >= 0 (1 at 0; 0 at +inf), without cancellation for small x: the
 * fraction of a segment's optical depth x that is not transmitted, per unit of x. */
double nc_vol_exp_ratio(double x);

/* Below this x, nc_vol_exp_ratio sums the series sum_n (-x)^n / (n + 1)! through n = 8 (the next
 * term is under 3e-16 relative); above it, (1 - e^(-x)) / x loses at most ~3e-15 to
 * cancellation. This costs one exp where expm1 was twice as slow (measured in the fog pass), and
 * lets a caller that already has e^(-x) skip it. */
#define NC_VOL_SERIES_MAX 0.1

/* nc_vol_exp_ratio(x) given t = e^(-x) (ignored below NC_VOL_SERIES_MAX). */
static inline double nc_vol_exp_ratio_t(double x, double t)
{
    if (x < NC_VOL_SERIES_MAX) {
        double r = 1.0 / 362880.0; /* 1 / 9! */
        const double inv_fact[8] = {1.0 / 40320, 1.0 / 5040, 1.0 / 720, 1.0 / 120, 1.0 / 24, 1.0 / 6, 0.5, 1.0};
        for (int n = 0; n < 8; n++)
            r = inv_fact[n] - x * r;
        return r;
    }
    if (isinf(x))
        return 0.0;
    return (1.0 - t) / x;
}

/* integral_0^d e^(-sigma_t t) dt = (1 - e^(-sigma_t d)) / sigma_t, d when sigma_t = 0; d may be
 * +inf (then 1 / sigma_t, or +inf for sigma_t = 0). */
double nc_vol_segment_weight(double sigma_t, double d);

/* Radiance that a homogeneous segment of length d in-scatters towards its start:
 * sigma_s L_s (1 - e^(-sigma_t d)) / sigma_t, where L_s = integral of phase x incident radiance
 * over directions (seed eq. 1.31 without sigma_s). Energy-conserving for any d: the result never
 * exceeds what the segment removes from a beam of radiance L_s (albedo x (1 - T) x L_s). */
double nc_vol_inscatter_segment(double sigma_s, double sigma_t, double l_s, double d);

/* Radiance that a homogeneous segment of length d emits towards its start, emission being
 * radiance per unit length (§1.2.11: a term added to the source): emission x weight. */
double nc_vol_emission_segment(double emission, double sigma_t, double d);

/* Front-to-back integration of one channel along a ray made of homogeneous steps: radiance
 * gathered so far and transmittance from the ray's start to the current step. */
typedef struct nc_vol_march {
    double radiance, transmittance;
} nc_vol_march;

static inline nc_vol_march nc_vol_march_begin(void) { return (nc_vol_march){0.0, 1.0}; }

/* Add a step of length d with extinction sigma_t and source `source` per unit length
 * (sigma_s L_s + emission): the segment integral, seen through the steps before it. Splitting a
 * homogeneous run into any number of steps gives the same result (up to rounding). */
void nc_vol_march_step(nc_vol_march *m, double sigma_t, double source, double d);

/* ---- exponential height fog (§2.1.2) -------------------------------------------------- */

/* The exponent cap of a fog: NC_VOL_HEIGHT_EXP_MAX with a height falloff (0 without), lowered
 * so that the densest point, maj x e^cap, stays at NC_VOL_MAX_DENSITY; maj bounds the fog's
 * sigma_t where the height factor is 1 (its largest channel). */
static inline float nc_vol_height_exp_cap(bool height, float maj)
{
    float cap = height ? NC_VOL_HEIGHT_EXP_MAX : 0.0f;
    if (maj > 0)
        cap = fminf(cap, logf(NC_VOL_MAX_DENSITY / maj));
    return cap;
}

/* The height factor at world height y: e^(min(cap, -falloff (y - base))) with a falloff,
 * e^cap without (1 unless the density cap lowered it). Float, as the path tracer tracks it. */
static inline float nc_vol_height_factor(bool height, float falloff, float base, float cap, float y)
{
    return expf(height ? fminf(cap, -falloff * (y - base)) : cap);
}

/* A fog's height profile in double, for the closed-form integrals. */
typedef struct nc_vol_height {
    double falloff; /* per scene unit, >= 0; 0: constant factor e^min(cap, 0) */
    double base;    /* world y where the uncapped factor is 1 */
    double cap;     /* exponent cap (nc_vol_height_exp_cap) */
} nc_vol_height;

/* integral_t0^t1 of the height factor along the ray y(t) = y0 + dir_y t (dir_y: the y component
 * of a unit direction), 0 <= t0 <= t1, t1 may be +inf (then +inf unless the ray rises into
 * thinning fog). Closed form (§2.1.2): over a piece that climbs dh from its lower end y_lo,
 * length x e^(-k (y_lo - base)) x (1 - e^(-k dh)) / (k dh), evaluated from the lower end (no
 * overflow) with nc_vol_exp_ratio (no cancellation as dh -> 0: a horizontal ray gets
 * length x factor exactly); the part below the cap's height has constant density e^cap. */
double nc_vol_height_integral(const nc_vol_height *h, double y0, double dir_y, double t0, double t1);

/* A height profile in float for nc_vol_height_integral8, its constants taken once. */
typedef struct nc_vol_height8 {
    float falloff, base, cap;
    float ecap; /* e^cap: the density below yc, and everywhere without a falloff */
    float yc;   /* the height below which the factor is capped (with a falloff) */
} nc_vol_height8;

static inline nc_vol_height8 nc_vol_height8_make(const nc_vol_height *h)
{
    nc_vol_height8 f = {(float)h->falloff, (float)h->base, (float)h->cap, (float)exp(h->cap), 0.0f};
    if (h->falloff > 0.0)
        f.yc = (float)(h->base - h->cap / h->falloff);
    return f;
}

/* nc_vol_height_integral over [t0, t1] for 8 rays in float, the same cases lane by lane: from
 * heights y0, direction y components dy, t1 possibly +inf (lanes with t1 <= t0 are not used).
 * Relative error about 1e-6 (test_fog_pass compares it with the double form). */
static inline nc_v8f nc_vol_height_integral8(const nc_vol_height8 *h, nc_v8f y0, nc_v8f dy, nc_v8f t0, nc_v8f t1)
{
    const nc_v8f zero = {0}, one = zero + 1.0f;
    nc_v8f len = t1 - t0;
    if (!(h->falloff > 0.0f))
        return h->cap >= 0.0f ? len : len * h->ecap;
    nc_v8i up = dy >= 0.0f;
    nc_v8f s = nc_v8_sel(up, dy, -dy);
    /* From the lower end; a descending ray's lower end at t1 = +inf is -inf: handled below. */
    nc_v8f y_lo = y0 + dy * nc_v8_sel(up, t0, t1);
    nc_v8f e = -h->falloff * (y_lo - h->base);
    nc_v8f f_lo = nc_vol_exp_fast8(nc_v8_sel(e < h->cap, e, zero + h->cap));
    nc_v8f level = nc_v8_sel(f_lo > 0.0f, len * f_lo, zero); /* 0 x inf is 0 here */
    nc_v8i below = y_lo < h->yc;
    nc_v8f sh = nc_v8_sel(s > 0.0f, s, one);
    nc_v8f to_cap = (h->yc - y_lo) / sh;
    nc_v8f capped = nc_v8_sel(below, nc_v8_sel(to_cap < len, to_cap, len), zero);
    f_lo = nc_v8_sel(below, zero + h->ecap, f_lo);
    nc_v8f rest = len - capped, ks = h->falloff * sh, x = ks * rest;
    nc_v8f ratio = nc_vol_exp_ratio8(x, nc_vol_exp_fast8(-x));
    nc_v8f more = nc_v8_sel(rest == INFINITY, f_lo / ks, rest * f_lo * ratio); /* rising forever */
    nc_v8f G = capped * f_lo + nc_v8_sel(rest > 0.0f, more, zero);
    G = nc_v8_sel(s == 0.0f, level, G);
    return nc_v8_sel((len == INFINITY) & (dy < 0.0f), zero + INFINITY, G); /* descending forever */
}

#endif /* NACRE_VOLUME_H */
