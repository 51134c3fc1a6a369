/*
 * slab.c: `nacre slab`, the slab measurement of nacre_slab_measure on the command line.
 */
#include "cli.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

static const char slab_help[] =
    "usage: nacre slab [options]\n"
    "Measure reflectance R and transmittance T of a plane-parallel slab, infinite in x and y,\n"
    "lit by collimated light (unit power per unit area of the slab's face). R excludes the\n"
    "specular reflection at the top; T includes unscattered light.\n"
    "\n"
    "  --albedo A        single-scattering albedo sigma_s / sigma_t in [0, 1] (default 0.99)\n"
    "  --tau T|inf       optical thickness sigma_t * depth (default inf: semi-infinite)\n"
    "  --g G             Henyey-Greenstein anisotropy in (-1, 1) (default 0)\n"
    "  --incidence DEG   angle of the light to the normal in [0, 89] (default 0)\n"
    "  --eta N           relative index of refraction, air on both sides (default 1)\n"
    "  --method M        diffusion (default) | pathtrace\n"
    "  --json            print {\"R\":..,\"T\":..,...} on one line\n"
    "  --time-limit S    stop after about S seconds (pathtrace: below; diffusion: an error if the\n"
    "                    solve has not converged by then)\n"
    "diffusion:\n"
    "  --cells-per-mfp N grid cells per reduced mean free path (default 8; the column, depth x\n"
    "                    cells per mfp, holds at most 16384 cells)\n"
    "  --solver S        multigrid (default) | seed\n"
    "  --source S        volume (default) | face\n"
    "  --tolerance T     relative residual (default 1e-5)\n"
    "pathtrace:\n"
    "  --samples N       incident paths (default 1000000)\n"
    "  --max-scatter K   scattering events per path (K = 1: single scattering; default unlimited)\n"
    "  --time-limit S    stop after about S seconds: R and T are the means over the paths completed\n"
    "                    by then (reported as samples); paths past 2^20 collisions end and score 0\n"
    "  --seed N          random seed\n"
    "  --threads N       worker threads (default: all cores)\n"
    "  --help, --version\n";

int nc_cli_slab(int argc, char **argv)
{
    nacre_slab_desc d = nacre_slab_desc_defaults();
    bool json = false;
    long threads = 0, v;
    double f;
    int code;
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        if (nc_tool_common_flag("slab", a, slab_help, &code))
            return code;
        bool has = i + 1 < argc;
        if (strcmp(a, "--albedo") == 0) {
            if (!has || !nc_tool_parse_float(argv[++i], &f) || !(f >= 0 && f <= 1))
                return nc_tool_usage("slab", "--albedo needs a number in [0, 1]");
            d.albedo = f;
        } else if (strcmp(a, "--tau") == 0) {
            if (!has)
                return nc_tool_usage("slab", "--tau needs a positive number or inf");
            const char *t = argv[++i];
            if (strcmp(t, "inf") == 0)
                d.tau = INFINITY;
            else if (nc_tool_parse_float(t, &f) && f > 0)
                d.tau = f;
            else
                return nc_tool_usage("slab", "--tau '%s': expected a positive number or inf", t);
        } else if (strcmp(a, "--g") == 0) {
            if (!has || !nc_tool_parse_float(argv[++i], &f) || !(f > -1 && f < 1))
                return nc_tool_usage("slab", "--g needs a number in (-1, 1)");
            d.g = f;
        } else if (strcmp(a, "--incidence") == 0) {
            if (!has || !nc_tool_parse_float(argv[++i], &f) || !(f >= 0 && f <= 89))
                return nc_tool_usage("slab", "--incidence needs an angle in [0, 89] degrees");
            d.incidence = f;
        } else if (strcmp(a, "--eta") == 0) {
            if (!has || !nc_tool_parse_float(argv[++i], &f) || !(f > 0 && f <= 10))
                return nc_tool_usage("slab", "--eta needs a number in (0, 10]");
            d.eta = f;
        } else if (strcmp(a, "--method") == 0) {
            if (!has)
                return nc_tool_usage("slab", "--method needs diffusion or pathtrace");
            const char *m = argv[++i];
            if (strcmp(m, "diffusion") == 0)
                d.method = NACRE_METHOD_DIFFUSION;
            else if (strcmp(m, "pathtrace") == 0)
                d.method = NACRE_METHOD_PATHTRACE;
            else
                return nc_tool_usage("slab", "--method '%s': expected diffusion or pathtrace", m);
        } else if (strcmp(a, "--cells-per-mfp") == 0) {
            if (!has || !nc_tool_parse_int(argv[++i], 1, 1024, &v))
                return nc_tool_usage("slab", "--cells-per-mfp needs an integer in 1..1024");
            d.cells_per_mfp = (uint32_t)v;
        } else if (strcmp(a, "--solver") == 0) {
            if (!has || !nacre_solver_from_name(argv[++i], &d.solver))
                return nc_tool_usage("slab", "--solver needs multigrid or seed");
        } else if (strcmp(a, "--source") == 0) {
            if (!has || !nacre_source_from_name(argv[++i], &d.source))
                return nc_tool_usage("slab", "--source needs volume or face");
        } else if (strcmp(a, "--tolerance") == 0) {
            if (!has || !nc_tool_parse_float(argv[++i], &f) || !(f > 0 && f < 1))
                return nc_tool_usage("slab", "--tolerance needs a number in (0, 1)");
            d.tolerance = (float)f;
        } else if (strcmp(a, "--samples") == 0) {
            if (!has || !nc_tool_parse_int(argv[++i], 1, 4000000000L, &v))
                return nc_tool_usage("slab", "--samples needs an integer in 1..4000000000");
            d.samples = (uint64_t)v;
        } else if (strcmp(a, "--max-scatter") == 0) {
            if (!has || !nc_tool_parse_int(argv[++i], 1, 1000000, &v))
                return nc_tool_usage("slab", "--max-scatter needs an integer in 1..1000000");
            d.max_scatter = (uint32_t)v;
        } else if (strcmp(a, "--time-limit") == 0) {
            if (!has || !nc_tool_parse_float(argv[++i], &f) || !(f > 0 && isfinite(f)))
                return nc_tool_usage("slab", "--time-limit needs a positive number of seconds");
            d.time_limit = f;
        } else if (strcmp(a, "--seed") == 0) {
            if (!has || !nc_tool_parse_int(argv[++i], 0, 4294967295L, &v))
                return nc_tool_usage("slab", "--seed needs an integer in 0..4294967295");
            d.seed = (uint64_t)v;
        } else if (strcmp(a, "--threads") == 0) {
            if (!has || !nc_tool_parse_int(argv[++i], 1, 1024, &threads))
                return nc_tool_usage("slab", "--threads needs an integer in 1..1024");
        } else if (strcmp(a, "--json") == 0) {
            json = true;
        } else {
            return nc_tool_usage("slab", "unknown argument '%s'", a);
        }
    }
    nacre_context *ctx = nc_tool_context((int)threads);
    if (!ctx)
        return 2;
    nacre_slab_result r;
    if (nacre_slab_measure(ctx, &d, &r) != NACRE_OK) {
        int rc = nc_tool_fail(ctx);
        nacre_context_destroy(ctx);
        return rc;
    }
    if (json) {
        printf("{\"method\":\"%s\",\"albedo\":%.9g,\"tau\":", nacre_method_name(d.method), d.albedo);
        if (isinf(d.tau))
            printf("\"inf\"");
        else
            printf("%.9g", d.tau);
        printf(",\"g\":%.9g,\"eta\":%.9g,\"incidence\":%.9g,\"R\":%.6f,\"T\":%.6f", d.g, d.eta, d.incidence, r.R,
               r.T);
        if (d.method == NACRE_METHOD_PATHTRACE)
            printf(",\"R_stderr\":%.6f,\"T_stderr\":%.6f,\"samples\":%llu,\"paths_capped\":%llu", r.R_stderr,
                   r.T_stderr, (unsigned long long)r.samples_done, (unsigned long long)r.paths_capped);
        else
            printf(",\"solver\":\"%s\",\"source\":\"%s\",\"iterations\":%u,\"residual\":%.3g",
                   nacre_solver_name(d.solver), nacre_source_name(d.source),
                   r.iterations, r.residual);
        printf(",\"R_specular\":%.6f,\"ms\":%.3f}\n", r.R_specular, r.ms);
    } else {
        printf("R = %.6f", r.R);
        if (d.method == NACRE_METHOD_PATHTRACE)
            printf(" +- %.6f", r.R_stderr);
        printf("  (specular %.6f excluded)\nT = %.6f", r.R_specular, r.T);
        if (d.method == NACRE_METHOD_PATHTRACE)
            printf(" +- %.6f", r.T_stderr);
        printf("\n%.3f ms\n", r.ms);
        if (d.method == NACRE_METHOD_PATHTRACE && (r.samples_done < d.samples || r.paths_capped))
            printf("%llu of %llu paths (time limit); %llu ended by the collision cap\n",
                   (unsigned long long)r.samples_done, (unsigned long long)d.samples,
                   (unsigned long long)r.paths_capped);
    }
    nacre_context_destroy(ctx);
    return 0;
}
