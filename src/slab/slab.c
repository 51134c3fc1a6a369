/*
 * slab.c: nacre_slab_measure, the validation experiment shared by the methods: reflectance R and
 * transmittance T of a plane-parallel slab, infinite in x and y, lit by collimated light of unit
 * power per unit area of its face at a given incidence (normal by default), air on both sides. Lengths are mean free paths
 * (sigma_t = 1). The desc is checked here; the diffusion method measures it on its solver's
 * column (src/diffusion/slab.c, nc_slab_diffusion), the path tracer by Monte Carlo
 * (src/pathtrace/slab.c, nc_slab_pathtrace). This module sits above both.
 */
#include "core/core.h"
#include "diffusion/diffusion.h"
#include "pathtrace/pathtrace.h"

#include <math.h>
#include <string.h>

nacre_slab_desc nacre_slab_desc_defaults(void)
{
    nacre_slab_desc d;
    memset(&d, 0, sizeof(d));
    d.method = NACRE_METHOD_DIFFUSION;
    d.albedo = 0.99;
    d.tau = INFINITY;
    d.eta = 1.0;
    d.cells_per_mfp = 8;
    d.solver = NACRE_SOLVER_MULTIGRID;
    d.source = NACRE_SOURCE_VOLUME;
    d.tolerance = 1e-5f;
    d.samples = 1000000;
    d.seed = 1;
    return d;
}

static nacre_result check_desc(nacre_context *ctx, const nacre_slab_desc *d)
{
    if (d->method != NACRE_METHOD_DIFFUSION && d->method != NACRE_METHOD_PATHTRACE)
        return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "slab: method '%s' has no slab measurement (diffusion, pathtrace)",
                       nacre_method_name(d->method));
    if (!(d->albedo >= 0 && d->albedo <= 1))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "slab: albedo must be in [0, 1]");
    if (!(d->tau > 0))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "slab: tau must be > 0 (or infinite)");
    if (!(d->g > -1 && d->g < 1))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "slab: g must be in (-1, 1)");
    if (!(d->incidence >= 0 && d->incidence <= 89))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "slab: incidence must be in [0, 89] degrees");
    if (!(d->time_limit >= 0) || !isfinite(d->time_limit))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "slab: time_limit: must be finite and >= 0");
    if (!(d->eta > 0) || !isfinite(d->eta))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "slab: eta must be finite and > 0");
    /* The path tracer's Fresnel equations hold for any eta; the diffusion boundary's fit does not. */
    if (d->method == NACRE_METHOD_DIFFUSION && !(d->eta >= NACRE_ETA_MIN && d->eta <= NACRE_ETA_MAX))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "slab: eta must be in [%g, %g] for diffusion (got %g)",
                       NACRE_ETA_MIN, NACRE_ETA_MAX, d->eta);
    return NACRE_OK;
}

nacre_result nacre_slab_measure(nacre_context *ctx, const nacre_slab_desc *desc, nacre_slab_result *out)
{
    if (!ctx || !desc || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    memset(out, 0, sizeof(*out));
    nacre_result res = check_desc(ctx, desc);
    if (res != NACRE_OK)
        return res;
    uint64_t t0 = nc_now_us();
    if (desc->method == NACRE_METHOD_PATHTRACE)
        res = nc_slab_pathtrace(ctx, desc, out);
    else
        res = nc_slab_diffusion(ctx, desc, out);
    out->ms = (double)(nc_now_us() - t0) / 1000.0;
    return res;
}
