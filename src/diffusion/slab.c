/*
 * slab.c: nacre_slab_measure (placeholder until the diffusion slab lands).
 */
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
    d.tolerance = 1e-6f;
    d.samples = 1000000;
    d.seed = 1;
    return d;
}

nacre_result nacre_slab_measure(nacre_context *ctx, const nacre_slab_desc *desc, nacre_slab_result *out)
{
    if (!ctx || !desc || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (desc->method == NACRE_METHOD_PATHTRACE)
        return nc_slab_pathtrace(ctx, desc, out);
    return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "slab: method '%s' is not implemented yet", nacre_method_name(desc->method));
}
