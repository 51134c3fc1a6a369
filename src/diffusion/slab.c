/*
 * slab.c: the diffusion method's measurement of the slab experiment (src/slab/slab.c: a
 * plane-parallel slab, infinite in x and y, lit by collimated light of unit power per unit area
 * at a given incidence; the desc is checked there).
 *
 * Diffusion: the same finite-volume solver the renderer uses (solver.c) on a column of cells,
 * periodic in x and y (one cell each, so there is no lateral flux), the top face at z = depth
 * and the bottom at z = 0, with Robin boundaries on both. Lengths are in mean free paths
 * (sigma_t = 1): sigma_s = a, sigma_a = 1 - a, sigma_s' = a (1 - g), cells of 1 / cells_per_mfp
 * reduced mean free paths. A semi-infinite slab is cut at 12 diffusion lengths (at least 60
 * reduced mean free paths), where the fluence has fallen by e^-12.
 * Sources: VOLUME deposits the scattered part of the reduced intensity along the refracted
 * ray, alpha' sigma_t' exp(-sigma_t' s) per unit path s = z / mu_t (mu_t the cosine of the
 * refracted direction), integrated exactly over each cell, as the renderer does along each
 * light's refracted rays; FACE puts the transmitted flux on the
 * top face as the boundary source of seed eq. 4.7.
 * R = light escaping through the top (net outward flux plus, for FACE, the incoming flux the
 * Robin condition counts as going in); T = net flux through the bottom plus the unscattered
 * reduced intensity that reaches it (transmitted by the bottom boundary once; its internal
 * reflections, at most R0 ~ 2% of an already small term, are left out).
 */
#include "diffusion/diffusion.h"
#include "core/optics.h"

#include <math.h>
#include <string.h>

nacre_result nc_slab_diffusion(nacre_context *ctx, const nacre_slab_desc *d, nacre_slab_result *out)
{
    const uint64_t t_start = nc_now_us();
    if (d->cells_per_mfp < 1 || d->cells_per_mfp > 1024)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "slab: cells_per_mfp must be in 1..1024");
    if (!(d->tolerance > 0 && d->tolerance < 1))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "slab: tolerance must be in (0, 1)");
    const double a = d->albedo, g = d->g;
    const double sigma_a = 1.0 - a, sigma_sp = a * (1.0 - g), sigma_tp = sigma_a + sigma_sp;
    if (!(sigma_tp > 0))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "slab: the medium neither absorbs nor scatters");
    const double alpha_p = sigma_sp / sigma_tp;
    const double h = 1.0 / (sigma_tp * d->cells_per_mfp);
    double depth = d->tau;
    /* An absorbing slab thicker than the semi-infinite cut is solved to the cut too, as
     * accurately as a semi-infinite one (the fluence there is e^-12 of the top's; R changes by
     * 2e-5 at albedo 0.99), T decaying on as e^(-sigma_tr (tau - cut)): a column of up to 2^22
     * cells took minutes (tau 60000 at albedo 0.5: 75 s). */
    const double sigma_tr = sqrt(3.0 * sigma_a * sigma_tp);
    double cut = 60.0 / sigma_tp;
    if (sigma_tr > 0 && 12.0 / sigma_tr > cut)
        cut = 12.0 / sigma_tr;
    const bool thick = !isinf(depth) && sigma_tr > 0 && depth > cut;
    if (isinf(depth) || thick)
        depth = cut;
    double cells_d = ceil(depth / h - 1e-9);
    if (cells_d < 2)
        cells_d = 2;
    /* The float solver's column: past 2^14 cells the multigrid cycle's many tiny coarse levels
     * make each iteration slow and the float residual stops falling (1024 cells per mfp at
     * albedo 0.999, 224k cells: R = 3.2 after a minute). */
    if (cells_d > 1 << 14)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "slab: the column needs %.0f cells (depth x cells_per_mfp), at most 16384: lower "
                       "cells_per_mfp or tau",
                       cells_d);
    const uint32_t nz = (uint32_t)cells_d;
    /* Keep the cell size exact for a finite slab: the last cell absorbs the rounding. */
    const double hz = isinf(d->tau) ? h : depth / nz;

    nacre_result res = NACRE_OK;
    uint8_t *solid = nc_alloc(ctx, nz);
    float *src = nc_calloc(ctx, nz, sizeof(float));
    float *phi = nc_calloc(ctx, nz, sizeof(float));
    nc_diff_solver *solver = NULL;
    if (!solid || !src || !phi) {
        res = nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "slab: out of memory");
        goto done;
    }
    memset(solid, 1, nz);
    if ((res = nc_diff_solver_create(ctx, &solver)) != NACRE_OK)
        goto done;
    nc_diff_medium m = {
        .dims = {1, 1, nz}, .h = (float)hz, .periodic = {true, true, false}, .solid = solid,
        .sigma_a_const = {(float)sigma_a, (float)sigma_a, (float)sigma_a},
        .sigma_sp_const = {(float)sigma_sp, (float)sigma_sp, (float)sigma_sp}, .eta = (float)d->eta};
    if ((res = nc_diff_setup(solver, &m)) != NACRE_OK)
        goto done;
    const double area = hz * hz;
    const double cos_i = cos(d->incidence * 0.017453292519943295), sin_i = sqrt(fmax(0.0, 1.0 - cos_i * cos_i));
    const double mu_t = sqrt(fmax(0.0, 1.0 - sin_i * sin_i / (d->eta * d->eta)));
    const double r0 = nc_fresnel_dielectric(cos_i, d->eta);
    const double entering = (1.0 - r0) * area; /* power through the top face */
    const double D = 1.0 / (3.0 * sigma_tp), A = nc_diff_robin_a(d->eta), fdr = nc_fresnel_fdr(d->eta);
    const double c = 2.0 * D / (hz + 4.0 * A * D); /* outward flux per area per unit fluence */
    double face_s = 0.0;
    if (d->source == NACRE_SOURCE_FACE) {
        /* q = (1 - R0) per unit area on the top face; s = 4 q / (1 - Fdr) enters as c s A. */
        face_s = 4.0 * (1.0 - r0) / (1.0 - fdr);
        src[nz - 1] = (float)(c * face_s * area);
    } else {
        for (uint32_t k = 0; k < nz; k++) {
            double z0 = (nz - 1 - k) * hz, z1 = z0 + hz; /* depth below the top */
            src[k] = (float)(entering * alpha_p * (exp(-sigma_tp * z0 / mu_t) - exp(-sigma_tp * z1 / mu_t)));
        }
    }
    nc_diff_solve_opts o = {.solver = d->solver, .tolerance = d->tolerance, .max_iterations = 1000};
    if (d->time_limit > 0)
        o.deadline_us = t_start + (uint64_t)(d->time_limit * 1e6);
    nc_diff_solve_report rep;
    if ((res = nc_diff_solve(solver, 0, src, phi, &o, &rep)) != NACRE_OK)
        goto done;
    /* A result the solver did not reach is no measurement: refuse it rather than print it. */
    if (rep.timed_out) {
        res = nc_fail(ctx, NACRE_ERROR_CANCELLED,
                      "slab: time limit of %g s reached before the diffusion solve converged (relative residual "
                      "%.3g after %u iterations)",
                      d->time_limit, rep.residual, rep.iterations);
        goto done;
    }
    if (d->solver == NACRE_SOLVER_MULTIGRID && !(rep.residual <= 1e-2)) {
        res = nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                      "slab: the diffusion solve did not converge (relative residual %.3g after %u iterations): "
                      "lower cells_per_mfp or tau",
                      rep.residual, rep.iterations);
        goto done;
    }
    double top = c * phi[nz - 1] * area, bottom = c * phi[0] * area;
    if (d->source == NACRE_SOURCE_FACE)
        top += (1.0 - r0) * area - c * face_s * area;
    double unscattered = isinf(d->tau) ? 0.0 : (1.0 - r0) * exp(-sigma_tp * d->tau / mu_t) * (1.0 - r0);
    out->R = top / area;
    out->T = bottom / area * (thick ? exp(-sigma_tr * (d->tau - depth)) : 1.0) + unscattered;
    out->R_stderr = out->T_stderr = 0.0;
    out->R_specular = r0;
    out->iterations = rep.iterations;
    out->residual = rep.residual;
done:
    nc_diff_solver_destroy(solver);
    nc_free(ctx, solid);
    nc_free(ctx, src);
    nc_free(ctx, phi);
    return res;
}
