/*
 * bench.c: `nacre bench`: benchmarks report medians over repeated runs, as text tables or, with
 * --json, one JSON object per line. Speed targets are checked here, never in unit tests.
 *
 * `nacre bench raster` = the lucy_1600k G-buffer benchmark (bench/bench_raster.c) followed by
 * the built-in demo scene rendered with phong at 1280x720, per stage.
 *
 * `nacre bench voxelize` = nacre_voxelize_update (per-frame path, grid reused) on the stand-ins of the seed's meshes at 4^3 .. 256^3,
 * beside the seed's GPU voxelization times (seed 000, tables 5.1-5.3, "Voxélisation" column, at
 * 4^3, 12^3 and 28^3 only) scaled by our triangle count over the seed's. Closedness is decided
 * once per mesh (nacre_mesh_analyze, not timed: topology does not change between frames) and the
 * solid rule is passed explicitly, as a per-frame caller would.
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
    "  --runs N timed runs after one warm-up (default 15); medians are reported\n"
    "usage: nacre bench voxelize [--json] [--runs N] [--only MESH] [--res N]\n"
    "  voxelize suzanne_subdiv2, armadillo_400k, dragon, lucy_1600k (missing ones skipped) at\n"
    "           4,12,28,64,128,256 voxels per side, beside the seed's tables 5.1-5.3\n"
    "usage: nacre bench diffusion [--json] [--runs N] [--only MESH] [--res N] [--repaint]\n"
    "  diffusion  the seed's tables 5.1-5.3 layout (per-stage us, fps) for its meshes' stand-ins\n"
    "           at 4..128 voxels (bench/bench_diffusion.c), then iterations to converge (seed\n"
    "           table 4.3) and converged propagation at 32^3..256^3 (bench/bench_diffusion_solver.c)\n"
    "  --only MESH  only the meshes whose file name contains MESH; --res N  only that resolution\n"
    "           (either filter skips the solver tables of `bench diffusion`)\n"
    "  --repaint  every frame writes every pixel; by default frames reuse the previous frame's\n"
    "           background, as a viewer does (nacre_render_settings.reuse_output)\n"
    "usage: nacre bench pathtrace [--json] [--runs N]\n"
    "  pathtrace  samples/s and extrapolated time to relative MSE 1e-3 at 512x512: translucent\n"
    "           sphere (index matched, dielectric, layered skin) and the demo scene, N x 30 s each\n"
    "           (default 1)\n";

/* bench/bench_pathtrace.c */
int nc_bench_pathtrace(bool json, double seconds);

/* Seed meshes: our stand-in file, the seed's triangle count and its voxelization time in
 * microseconds at 4^3, 12^3, 28^3 (tables 5.1, 5.2, 5.3). */
static const struct {
    const char *file;
    const char *seed_name;
    double seed_tris;
    double seed_us[3];
} vox_meshes[] = {
    {"suzanne_subdiv2.ply", "Suzanne", 15e3, {266, 257, 286}},
    {"armadillo_400k.ply", "Armadillo", 346e3, {4906, 5046, 5208}},
    {"dragon.ply", "Statue", 800e3, {9700, 8789, 8627}},
    {"lucy_1600k.ply", "Lucy", 2027e3, {26401, 24822, 23705}},
};
static const uint32_t vox_res[] = {4, 12, 28, 64, 128, 256};

bool nc_cli_find_mesh(const char *file, char *path, size_t size)
{
    const char *dirs[3] = {getenv("NACRE_MESH_DIR"), "../shared/meshes", "/work/shared/meshes"};
    for (int d = 0; d < 3; d++) {
        if (!dirs[d] || !dirs[d][0])
            continue;
        snprintf(path, size, "%s/%s", dirs[d], file);
        FILE *f = fopen(path, "rb");
        if (f) {
            fclose(f);
            return true;
        }
    }
    return false;
}

bool nc_bench_filter_mesh(const nc_bench_filter *f, const char *file)
{
    return !f->only || strstr(file, f->only) != NULL;
}

static int bench_voxelize(bool json, int runs, const nc_bench_filter *filter)
{
    nacre_context *ctx = nc_cli_context(0);
    if (!ctx)
        return 2;
    double *samples = calloc((size_t)runs, sizeof(double));
    int rc = 2;
    if (!samples)
        goto out;
    if (!json)
        printf("voxelize (per-frame path: nacre_voxelize_update into a reused grid), %d threads, median of %d runs (ms); seed = GPU time of tables 5.1-5.3 x tris ratio\n"
               "%-22s %9s %5s %6s %10s %10s %10s %8s\n",
               nacre_context_threads(ctx), runs, "mesh", "tris", "res", "rule", "surface", "solid", "ms", "seed_ms");
    for (size_t m = 0; m < sizeof(vox_meshes) / sizeof(vox_meshes[0]); m++) {
        char path[4096];
        if (!nc_bench_filter_mesh(filter, vox_meshes[m].file))
            continue;
        if (!nc_cli_find_mesh(vox_meshes[m].file, path, sizeof(path))) {
            fprintf(stderr, "nacre bench voxelize: %s not found, skipped\n", vox_meshes[m].file);
            continue;
        }
        nacre_mesh_data mesh = {0};
        nacre_mesh_info info;
        if (nacre_mesh_load(ctx, path, &mesh) != NACRE_OK || nacre_mesh_analyze(ctx, &mesh, &info) != NACRE_OK) {
            nacre_mesh_data_free(ctx, &mesh);
            rc = nc_cli_fail(ctx);
            goto out;
        }
        double ratio = mesh.triangle_count / vox_meshes[m].seed_tris;
        for (size_t r = 0; r < sizeof(vox_res) / sizeof(vox_res[0]); r++) {
            if (filter->res && filter->res != vox_res[r])
                continue;
            nacre_voxel_settings vs = nacre_voxel_settings_defaults();
            vs.resolution = vox_res[r];
            vs.solid_rule = info.closed ? NACRE_VOXEL_SOLID_PARITY : NACRE_VOXEL_SOLID_ROBUST;
            nacre_voxel_report rep;
            /* Per-frame path: the grid is created once (untimed), each run re-voxelizes into it. */
            nacre_voxel_grid *grid = NULL;
            nacre_result res = nacre_voxelize(ctx, &mesh, &vs, &grid, &rep);
            for (int run = -1; res == NACRE_OK && run < runs; run++) {
                uint64_t t0 = nc_cli_now_us();
                res = nacre_voxelize_update(grid, &mesh, &vs, &rep);
                uint64_t t1 = nc_cli_now_us();
                if (run >= 0)
                    samples[run] = (t1 - t0) / 1000.0;
            }
            nacre_voxel_grid_destroy(grid);
            if (res != NACRE_OK) {
                nacre_mesh_data_free(ctx, &mesh);
                rc = nc_cli_fail(ctx);
                goto out;
            }
            double ms = nc_cli_median(samples, runs);
            double seed_ms = r < 3 ? vox_meshes[m].seed_us[r] / 1000.0 * ratio : -1;
            const char *rule = info.closed ? "parity" : "robust";
            if (json) {
                printf("{\"bench\":\"voxelize\",\"mesh\":\"%s\",\"triangles\":%u,\"res\":%u,\"rule\":\"%s\","
                       "\"threads\":%d,\"runs\":%d,\"surface_voxels\":%llu,\"solid_voxels\":%llu,\"ms\":%.3f",
                       vox_meshes[m].file, mesh.triangle_count, vox_res[r], rule, nacre_context_threads(ctx), runs,
                       (unsigned long long)rep.surface_voxels, (unsigned long long)rep.solid_voxels, ms);
                if (seed_ms >= 0)
                    printf(",\"seed_ms\":%.3f", seed_ms);
                printf("}\n");
            } else {
                printf("%-22s %9u %5u %6s %10llu %10llu %10.3f ", vox_meshes[m].file, mesh.triangle_count,
                       vox_res[r], rule, (unsigned long long)rep.surface_voxels,
                       (unsigned long long)rep.solid_voxels, ms);
                if (seed_ms >= 0)
                    printf("%8.3f\n", seed_ms);
                else
                    printf("%8s\n", "-");
            }
            fflush(stdout);
        }
        nacre_mesh_data_free(ctx, &mesh);
    }
    rc = 0;
out:
    free(samples);
    nacre_context_destroy(ctx);
    return rc;
}

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
        return nc_cli_usage("bench", "needs a benchmark name (raster, voxelize)");
    if (nc_cli_common_flag("bench", argv[0], bench_help, &code))
        return code;
    bool voxelize = strcmp(argv[0], "voxelize") == 0, diffusion = strcmp(argv[0], "diffusion") == 0;
    bool pathtrace = strcmp(argv[0], "pathtrace") == 0;
    if (strcmp(argv[0], "raster") != 0 && !voxelize && !diffusion && !pathtrace)
        return nc_cli_usage("bench", "unknown benchmark '%s' (raster, voxelize, diffusion, pathtrace)", argv[0]);
    bool json = false;
    long runs = pathtrace ? 1 : 15, res_only = 0;
    nc_bench_filter filter = {NULL, 0};
    bool repaint = false;
    for (int i = 1; i < argc; i++) {
        if (nc_cli_common_flag("bench", argv[i], bench_help, &code))
            return code;
        if (strcmp(argv[i], "--json") == 0)
            json = true;
        else if (strcmp(argv[i], "--runs") == 0 && i + 1 < argc && nc_cli_parse_int(argv[i + 1], 1, 10000, &runs))
            i++;
        else if ((voxelize || diffusion) && strcmp(argv[i], "--only") == 0 && i + 1 < argc)
            filter.only = argv[++i];
        else if ((voxelize || diffusion) && strcmp(argv[i], "--res") == 0 && i + 1 < argc &&
                 nc_cli_parse_int(argv[i + 1], 1, 4096, &res_only))
            filter.res = (uint32_t)res_only, i++;
        else if (diffusion && strcmp(argv[i], "--repaint") == 0)
            repaint = true;
        else if (!voxelize && strcmp(argv[i], "--mesh") == 0 && i + 1 < argc)
            i++; /* read by nc_bench_raster */
        else
            return nc_cli_usage("bench", "unknown or incomplete option '%s'", argv[i]);
    }
    if (voxelize)
        return bench_voxelize(json, (int)runs, &filter);
    if (diffusion) {
        int rc = nc_bench_diffusion_pipeline(json, (int)runs, &filter, repaint);
        if (rc != 0 || filter.only || filter.res)
            return rc;
        if (!json)
            printf("\n");
        return nc_bench_diffusion_solver(json, (int)runs);
    }
    if (pathtrace)
        return nc_bench_pathtrace(json, 30.0 * (double)runs);
    int rc = nc_bench_raster(argc - 1, argv + 1);
    if (rc != 0)
        return rc;
    return bench_demo(json, (int)runs);
}
