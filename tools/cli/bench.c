/*
 * bench.c: `nacre bench`: benchmarks report medians over repeated runs, as text tables or, with
 * --json, one JSON object per line. Speed targets are checked here, never in unit tests.
 *
 * `nacre bench raster` = the lucy_1600k G-buffer benchmark (bench/bench_raster.c) followed by
 * the built-in demo scene rendered with phong at 1280x720, per stage.
 */
#include "cli.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "demo_scene.h"

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

double nc_cli_median(double *v, int n)
{
    if (n <= 0)
        return 0;
    qsort(v, (size_t)n, sizeof(double), cmp_double);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

static const char bench_help[] =
    "usage: nacre bench raster [--json] [--runs N] [--mesh PATH]\n"
    "  raster   G-buffer of lucy_1600k.ply at 1280x720 (mesh from $NACRE_MESH_DIR or\n"
    "           ../shared/meshes), then the demo scene with phong at 1280x720, per stage\n"
    "  --json   one JSON object per line\n"
    "  --runs N timed runs after one warm-up (default 15); medians are reported\n";

/* Demo scene: every stage timed with caches cold (a fresh renderer per run). */
static int bench_demo(bool json, int runs)
{
    nacre_context *ctx = nc_cli_context(0);
    if (!ctx)
        return 2;
    nacre_scene *scene = NULL;
    nacre_render_settings rs;
    int rc = 2;
    double *samples = calloc((size_t)(runs * (NACRE_STAGE_COUNT + 1)), sizeof(double));
    nacre_image img = {0};
    if (!samples)
        goto out;
    if (nacre_scene_load_json(ctx, (const char *)nacre_demo_scene_json, strlen((const char *)nacre_demo_scene_json),
                              "<built-in demo>", ".", &scene, &rs) != NACRE_OK ||
        nacre_scene_commit(scene, 0.0) != NACRE_OK) {
        rc = nc_cli_fail(ctx);
        goto out;
    }
    rs.width = 1280;
    rs.height = 720;
    rs.method = NACRE_METHOD_PHONG;
    for (int run = -1; run < runs; run++) {
        nacre_render_stats st;
        if (nacre_render(scene, &rs, &img, &st) != NACRE_OK) {
            rc = nc_cli_fail(ctx);
            goto out;
        }
        if (run < 0)
            continue;
        for (int s = 0; s < NACRE_STAGE_COUNT; s++)
            samples[s * runs + run] = st.stage_us[s] / 1000.0;
        samples[NACRE_STAGE_COUNT * runs + run] = st.total_us / 1000.0;
    }
    if (json) {
        printf("{\"bench\":\"raster\",\"scene\":\"demo\",\"method\":\"phong\",\"width\":1280,\"height\":720,"
               "\"threads\":%d,\"runs\":%d", nacre_context_threads(ctx), runs);
        for (int s = 0; s < NACRE_STAGE_COUNT; s++)
            printf(",\"%s_ms\":%.3f", nacre_stage_name((nacre_stage)s), nc_cli_median(samples + s * runs, runs));
        printf(",\"total_ms\":%.3f}\n", nc_cli_median(samples + NACRE_STAGE_COUNT * runs, runs));
    } else {
        printf("demo scene, phong, 1280x720, %d threads, median of %d runs (ms):\n", nacre_context_threads(ctx), runs);
        for (int s = 0; s < NACRE_STAGE_COUNT; s++)
            printf("  %-8s %8.3f\n", nacre_stage_name((nacre_stage)s), nc_cli_median(samples + s * runs, runs));
        printf("  %-8s %8.3f\n", "total", nc_cli_median(samples + NACRE_STAGE_COUNT * runs, runs));
    }
    rc = 0;
out:
    free(samples);
    nacre_image_free(ctx, &img);
    nacre_scene_destroy(scene);
    nacre_context_destroy(ctx);
    return rc;
}

int nc_cli_bench(int argc, char **argv)
{
    int code;
    if (argc < 1)
        return nc_cli_usage("bench", "needs a benchmark name (raster)");
    if (nc_cli_common_flag("bench", argv[0], bench_help, &code))
        return code;
    if (strcmp(argv[0], "raster") != 0)
        return nc_cli_usage("bench", "unknown benchmark '%s' (raster)", argv[0]);
    bool json = false;
    long runs = 15;
    for (int i = 1; i < argc; i++) {
        if (nc_cli_common_flag("bench", argv[i], bench_help, &code))
            return code;
        if (strcmp(argv[i], "--json") == 0)
            json = true;
        else if (strcmp(argv[i], "--runs") == 0 && i + 1 < argc && nc_cli_parse_int(argv[i + 1], 1, 10000, &runs))
            i++;
        else if (strcmp(argv[i], "--mesh") == 0 && i + 1 < argc)
            i++; /* read by nc_bench_raster */
        else
            return nc_cli_usage("bench", "unknown or incomplete option '%s'", argv[i]);
    }
    int rc = nc_bench_raster(argc - 1, argv + 1);
    if (rc != 0)
        return rc;
    return bench_demo(json, (int)runs);
}
