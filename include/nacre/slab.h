/*
 * slab.h: slab measurement (nacre_slab_desc, nacre_slab_result, nacre_slab_measure): the diffusion
 * method and the path tracer on a plane-parallel slab, to validate them against exact results.
 * Part of nacre's public API; the conventions (units, ownership, memory, threading, errors) are in
 * the opening comment of nacre.h.
 */
#ifndef NACRE_PUBLIC_SLAB_H
#define NACRE_PUBLIC_SLAB_H

#include <nacre/core.h>
#include <nacre/render.h>

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ------------------------------------------------------------------------------------------ */
/* Slab measurement (validation of diffusion and path tracing against exact results)          */
/* ------------------------------------------------------------------------------------------ */

/* A plane-parallel slab, infinite in x and y, of optical thickness tau (sigma_t * depth; INFINITY
 * for semi-infinite), single-scattering albedo a = sigma_s / sigma_t, Henyey-Greenstein g and
 * relative index eta with air (index 1) on both sides, lit by collimated light at `incidence`
 * degrees from the normal with unit power per unit area of the slab's face. R: light leaving the top after scattering (the
 * specular reflection at the top excluded, reported as R_specular); T: all light leaving the
 * bottom (unscattered included). */
typedef struct nacre_slab_desc {
    nacre_method method;            /* DIFFUSION or PATHTRACE */
    double albedo, tau, g, eta;
    double incidence;               /* angle of the collimated light to the normal, degrees in
                                       [0, 89]; default 0. The power per unit area of the slab's
                                       face stays 1 (irradiance on the face, not on the beam) */
    /* diffusion */
    uint32_t cells_per_mfp;         /* grid cells per reduced mean free path 1/sigma_t', default 8 */
    nacre_diffusion_solver solver;
    nacre_diffusion_source source;
    float tolerance;                /* default 1e-5 */
    /* pathtrace */
    uint64_t samples;               /* incident paths, default 1e6 */
    uint32_t max_scatter;           /* 0 = unlimited */
    uint64_t seed;
    double time_limit;              /* seconds, 0 = none: stop early, the result from the paths
                                       completed by then (samples_done) */
} nacre_slab_desc;

typedef struct nacre_slab_result {
    double R, T;
    double R_stderr, T_stderr;      /* pathtrace: standard errors of the means; diffusion: 0 */
    uint64_t samples_done;          /* pathtrace: paths completed (samples, or fewer at the time limit) */
    uint64_t paths_capped;          /* pathtrace: paths ended by the collision cap (README) */
    double R_specular;              /* Fresnel reflection of the incident light at the top */
    uint32_t iterations;            /* diffusion */
    double residual;                /* diffusion */
    double ms;
} nacre_slab_result;

NACRE_API nacre_slab_desc nacre_slab_desc_defaults(void);
NACRE_API nacre_result nacre_slab_measure(nacre_context *ctx, const nacre_slab_desc *desc,
                                          nacre_slab_result *out);

#ifdef __cplusplus
}
#endif

#endif /* NACRE_PUBLIC_SLAB_H */
