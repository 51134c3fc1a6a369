/*
 * bench.c: `nacre bench`: parses the options and runs the benchmarks of bench/ (bench/bench.h).
 * Benchmarks report medians over repeated runs, as text tables or, with --json, one JSON object
 * per line. Speed targets are checked there, never in unit tests.
 *
 * `nacre bench raster` = the lucy_1600k G-buffer benchmark followed by the built-in demo scene
 * rendered with phong at 1280x720, per stage (bench/bench_raster.c). `nacre bench voxelize`:
 * bench/bench_voxelize.c.
 */
#include "cli.h"
#include "bench.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

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
    "           (default 1)\n"
    "usage: nacre bench load [--json] [--runs N] [--mesh PLY] [--glb GLB]\n"
    "  load     lucy_1600k.ply as a scene, and the same triangles from a .glb (nacre_scene_load_gltf;\n"
    "           make it with scripts/ply_to_glb.py), medians and their ratio (target <= 1.5)\n"
    "usage: nacre bench layered [--json] [--runs N] [--scene FILE] [--only fish|head] [--steps N]\n"
    "  layered  the seed's table 2 layout: 800x600, 10/50/100 samples and 2/4/8 analytic steps (and\n"
    "           the default 16 at half resolution) while the light moves, fps and error to 200\n"
    "           samples, on UV spheres of 2.8k and 73k triangles in FILE (default\n"
    "           examples/layered.json) in place of its translucent object;\n"
    "           --only: the meshes whose name contains it; --steps N: only the rows of N samples/steps\n"
    "usage: nacre bench particles [--json] [--runs N] [--only smoke10k|smoke100k|dust10k|iso]\n"
    "  particles  the smoke plume of examples/particles.json with 10k and 100k particles:\n"
    "           simulate, splat into 128^3, commit, the billboards and sprites passes and the\n"
    "           voxelized frame (froxel march) at 1280x720, median ms per stage\n"
    "           --only: the cases whose name contains it\n"
    "usage: nacre bench volumetrics [--json] [--runs N] [--raymarch] [--only froxel] [--froxels WxHxD]\n"
    "  volumetrics  froxel stages (fill, light, integrate, apply at 160x90x64) and the analytic\n"
    "           fog pass over the demo at 1280x720 with a shadowed sun, four point lights, height\n"
    "           fog and a 128^3 cloud; frames where the camera turns, the sun turns, nothing moves\n"
    "           (bench/bench_volumetrics.c)\n"
    "  --raymarch  also one frame of the per-pixel march (64 steps; tens of seconds)\n"
    "  --only froxel  only the froxel stages of the frames where the camera turns\n"
    "  --froxels WxHxD  the froxel grid (default 160x90x64): its cost against its size\n";





int nc_cli_bench(int argc, char **argv)
{
    int code;
    if (argc < 1)
        return nc_tool_usage("bench", "needs a benchmark name (raster, voxelize)");
    if (nc_tool_common_flag("bench", argv[0], bench_help, &code))
        return code;
    bool voxelize = strcmp(argv[0], "voxelize") == 0, diffusion = strcmp(argv[0], "diffusion") == 0;
    bool pathtrace = strcmp(argv[0], "pathtrace") == 0, layered = strcmp(argv[0], "layered") == 0;
    bool load = strcmp(argv[0], "load") == 0, particles = strcmp(argv[0], "particles") == 0;
    bool volumetrics = strcmp(argv[0], "volumetrics") == 0;
    const char *load_ply = NULL, *load_glb = NULL;
    const char *layered_scene = "examples/layered.json";
    if (strcmp(argv[0], "raster") != 0 && !voxelize && !diffusion && !pathtrace && !load && !layered && !particles &&
        !volumetrics)
        return nc_tool_usage("bench",
                             "unknown benchmark '%s' (raster, voxelize, diffusion, pathtrace, load, layered, particles, "
                             "volumetrics)",
                             argv[0]);
    bool json = false;
    long runs = pathtrace ? 1 : 15, res_only = 0;
    nc_bench_filter filter = {NULL, 0};
    bool repaint = false, raymarch = false;
    long froxels[3] = {160, 90, 64};
    for (int i = 1; i < argc; i++) {
        if (nc_tool_common_flag("bench", argv[i], bench_help, &code))
            return code;
        if (strcmp(argv[i], "--json") == 0)
            json = true;
        else if (strcmp(argv[i], "--runs") == 0 && i + 1 < argc && nc_tool_parse_int(argv[i + 1], 1, 10000, &runs))
            i++;
        else if ((voxelize || diffusion || layered || particles || volumetrics) && strcmp(argv[i], "--only") == 0 &&
                 i + 1 < argc)
            filter.only = argv[++i];
        else if ((voxelize || diffusion) && strcmp(argv[i], "--res") == 0 && i + 1 < argc &&
                 nc_tool_parse_int(argv[i + 1], 1, 4096, &res_only))
            filter.res = (uint32_t)res_only, i++;
        else if (diffusion && strcmp(argv[i], "--repaint") == 0)
            repaint = true;
        else if (volumetrics && strcmp(argv[i], "--raymarch") == 0)
            raymarch = true;
        else if (volumetrics && strcmp(argv[i], "--froxels") == 0 && i + 1 < argc) {
            /* W, H, D: integers in 1..4096 between two x's (the renderer checks the rest) */
            const char *v = argv[++i], *x1 = strchr(v, 'x'), *x2 = x1 ? strchr(x1 + 1, 'x') : NULL;
            char part[3][16] = {{0}};
            bool ok = x1 && x2 && x1 - v < 16 && x2 - x1 - 1 < 16 && strlen(x2 + 1) < 16;
            if (ok) {
                memcpy(part[0], v, (size_t)(x1 - v));
                memcpy(part[1], x1 + 1, (size_t)(x2 - x1 - 1));
                memcpy(part[2], x2 + 1, strlen(x2 + 1));
            }
            for (int k = 0; ok && k < 3; k++)
                ok = nc_tool_parse_int(part[k], 1, 4096, &froxels[k]);
            if (!ok)
                return nc_tool_usage("bench", "--froxels '%s': expected WxHxD, integers in 1..4096, e.g. 160x90x64", v);
        }
        else if (load && strcmp(argv[i], "--mesh") == 0 && i + 1 < argc)
            load_ply = argv[++i];
        else if (load && strcmp(argv[i], "--glb") == 0 && i + 1 < argc)
            load_glb = argv[++i];
        else if (layered && strcmp(argv[i], "--steps") == 0 && i + 1 < argc &&
                 nc_tool_parse_int(argv[i + 1], 1, 4096, &res_only))
            filter.res = (uint32_t)res_only, i++;
        else if (layered && strcmp(argv[i], "--scene") == 0 && i + 1 < argc)
            layered_scene = argv[++i];
        else if (!voxelize && strcmp(argv[i], "--mesh") == 0 && i + 1 < argc)
            i++; /* read by nc_bench_raster */
        else
            return nc_tool_usage("bench", "unknown or incomplete option '%s'", argv[i]);
    }
    if (voxelize)
        return nc_bench_voxelize(json, (int)runs, &filter);
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
    if (load)
        return nc_bench_load(json, (int)runs, load_ply, load_glb);
    if (layered)
        return nc_bench_layered(json, (int)runs, layered_scene, &filter);
    if (particles) {
        if (filter.only && !strstr("smoke10k smoke100k dust10k iso", filter.only))
            return nc_tool_usage("bench", "--only '%s': no particles case (smoke10k, smoke100k, dust10k, iso)",
                                 filter.only);
        return nc_bench_particles(json, (int)runs, filter.only);
    }
    if (volumetrics) {
        if (filter.only && strcmp(filter.only, "froxel") != 0)
            return nc_tool_usage("bench", "--only '%s': volumetrics has one case, froxel", filter.only);
        const uint32_t grid[3] = {(uint32_t)froxels[0], (uint32_t)froxels[1], (uint32_t)froxels[2]};
        return nc_bench_volumetrics(json, (int)runs, raymarch, filter.only != NULL, grid);
    }
    int rc = nc_bench_raster(argc - 1, argv + 1);
    if (rc != 0)
        return rc;
    return nc_bench_demo(json, (int)runs);
}
