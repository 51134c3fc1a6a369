/*
 * bench.h: the benchmarks' entry points, called by `nacre bench` (tools/cli/bench.c). Each prints
 * medians as a text table or, with json, one JSON object per line, and returns the exit status.
 * Speed targets are checked here, never in unit tests.
 */
#ifndef NACRE_BENCH_H
#define NACRE_BENCH_H

#include "common.h"

#include <string.h>

/* Optional row filter of `nacre bench voxelize|diffusion`: mesh file names containing `only`
 * (NULL: all) and one resolution (0: all). */
typedef struct nc_bench_filter {
    const char *only;
    uint32_t res;
} nc_bench_filter;

static inline bool nc_bench_filter_mesh(const nc_bench_filter *f, const char *file)
{
    return !f->only || strstr(file, f->only) != NULL;
}

/* lucy_1600k G-buffer (bench/bench_raster.c); reads --mesh PATH from argv. */
int nc_bench_raster(int argc, char **argv);
/* The built-in demo with phong at 1280x720, every stage cold (bench/bench_raster.c). */
int nc_bench_demo(bool json, int runs);
/* Per-frame voxelization beside the seed's tables 5.1-5.3 (bench/bench_voxelize.c). */
int nc_bench_voxelize(bool json, int runs, const nc_bench_filter *filter);
/* The seed's tables 5.1-5.3 layout for the diffusion pipeline (bench/bench_diffusion.c); repaint:
 * every frame writes every pixel (no reuse_output). */
int nc_bench_diffusion_pipeline(bool json, int runs, const nc_bench_filter *filter, bool repaint);
/* Iterations to converge (table 4.3) and converged propagation (bench/bench_diffusion_solver.c). */
int nc_bench_diffusion_solver(bool json, int runs);
/* Samples/s and time to relative MSE 1e-3 (bench/bench_pathtrace.c). */
int nc_bench_pathtrace(bool json, double seconds);
/* Loading a mesh as a scene from PLY and from the same triangles as GLB (bench/bench_load.c);
 * NULL paths: lucy_1600k.ply / .glb from the mesh folders. */
int nc_bench_load(bool json, int runs, const char *ply, const char *glb);
/* The layered method at 640x480 on a scene file, cold and while the light moves (bench/bench_layered.c). */
int nc_bench_layered(bool json, int runs, const char *scene_path, const nc_bench_filter *filter);
/* Particles: simulate, splat, billboards and sprites passes (bench/bench_particles.c). */
int nc_bench_particles(bool json, int runs, const char *only);
/* The froxel stages, the per-pixel march and the analytic fog pass (bench/bench_volumetrics.c);
 * froxel_only: the froxel stages of the camera-turning frames alone. */
int nc_bench_volumetrics(bool json, int runs, bool raymarch, bool froxel_only, const uint32_t froxels[3]);

#endif /* NACRE_BENCH_H */
