/*
 * bench_voxelize.c: `nacre bench voxelize`: nacre_voxelize_update (per-frame path, grid reused) on
 * the stand-ins of the seed's meshes at 4^3 .. 256^3, beside the seed's GPU voxelization times
 * (seed 000, tables 5.1-5.3, "Voxélisation" column, at 4^3, 12^3 and 28^3 only) scaled by our
 * triangle count over the seed's. Closedness is decided once per mesh (nacre_mesh_analyze, not
 * timed: topology does not change between frames) and the solid rule is passed explicitly, as a
 * per-frame caller would.
 */
#include "bench.h"

#include <nacre/voxel.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

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

int nc_bench_voxelize(bool json, int runs, const nc_bench_filter *filter)
{
    nacre_context *ctx = nc_tool_context(0);
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
        if (!nc_tool_find_mesh(vox_meshes[m].file, path, sizeof(path))) {
            fprintf(stderr, "nacre bench voxelize: %s not found, skipped\n", vox_meshes[m].file);
            continue;
        }
        nacre_mesh_data mesh = {0};
        nacre_mesh_info info;
        if (nacre_mesh_load(ctx, path, &mesh) != NACRE_OK || nacre_mesh_analyze(ctx, &mesh, &info) != NACRE_OK) {
            nacre_mesh_data_free(ctx, &mesh);
            rc = nc_tool_fail(ctx);
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
                uint64_t t0 = nc_tool_now_us();
                res = nacre_voxelize_update(grid, &mesh, &vs, &rep);
                uint64_t t1 = nc_tool_now_us();
                if (run >= 0)
                    samples[run] = (t1 - t0) / 1000.0;
            }
            nacre_voxel_grid_destroy(grid);
            if (res != NACRE_OK) {
                nacre_mesh_data_free(ctx, &mesh);
                rc = nc_tool_fail(ctx);
                goto out;
            }
            double ms = nc_tool_median(samples, runs);
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
