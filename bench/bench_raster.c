/*
 * bench_raster.c: `nacre bench raster`, first part: the G-buffer of lucy_1600k.ply (1.6 M
 * triangles) at 1280x720, i.e. nc_raster_visibility followed by nc_gbuffer_resolve, timed
 * separately over --runs runs after one warm-up run. Reports median, min and max in ms.
 *
 * The mesh comes from --mesh PATH, else $NACRE_MESH_DIR, ../shared/meshes or /work/shared/meshes.
 * The camera looks down -z at the centre of the mesh bounds (40 degree vertical fov) from the
 * distance at which the bounds fill 90% of the image height or width, whichever is tighter.
 * Target (2 cores, release build): under 40 ms median for raster + resolve.
 */
#include "bench.h"

#include "demo_scene.h"
#include "raster/raster.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MESH_NAME "lucy_1600k.ply"
#define WIDTH 1280
#define HEIGHT 720

static const char usage_cmd[] = "bench raster";

typedef struct stat3 {
    double median, min, max;
} stat3;

static stat3 stats(double *v, int n)
{
    stat3 s = {0, 0, 0};
    if (n <= 0)
        return s;
    s.min = s.max = v[0];
    for (int i = 1; i < n; i++) {
        s.min = v[i] < s.min ? v[i] : s.min;
        s.max = v[i] > s.max ? v[i] : s.max;
    }
    s.median = nc_tool_median(v, n); /* sorts */
    return s;
}

int nc_bench_raster(int argc, char **argv)
{
    bool json = false;
    long runs = 15;
    const char *mesh_path = NULL;
    for (int i = 0; i < argc; i++) {
        if (strcmp(argv[i], "--json") == 0)
            json = true;
        else if (strcmp(argv[i], "--runs") == 0 && i + 1 < argc &&
                 nc_tool_parse_int(argv[i + 1], 1, 10000, &runs))
            i++;
        else if (strcmp(argv[i], "--mesh") == 0 && i + 1 < argc)
            mesh_path = argv[++i];
        else
            return nc_tool_usage(usage_cmd, "unknown or incomplete option '%s'", argv[i]);
    }
    char found[4096];
    if (!mesh_path) {
        if (!nc_tool_find_mesh(MESH_NAME, found, sizeof(found))) {
            fprintf(stderr,
                    "nacre bench raster: %s not found in $NACRE_MESH_DIR, ../shared/meshes "
                    "or /work/shared/meshes (use --mesh PATH)\n",
                    MESH_NAME);
            return 2;
        }
        mesh_path = found;
    }

    nacre_context *ctx = nc_tool_context(0);
    if (!ctx)
        return 2;
    int rc = 2;
    nacre_mesh_data mesh = {0};
    nc_rasterizer *rz = NULL;
    nc_vis_buffer vis = {0};
    nc_gbuffer gb = {0};
    double *samples = calloc((size_t)runs * 3, sizeof(double));
    if (!samples) {
        fprintf(stderr, "nacre bench raster: out of memory\n");
        goto out;
    }
    uint64_t t_load = nc_tool_now_us();
    if (nacre_mesh_load(ctx, mesh_path, &mesh) != NACRE_OK) {
        rc = nc_tool_fail(ctx);
        goto out;
    }
    double load_ms = (nc_tool_now_us() - t_load) / 1000.0;
    if (nc_rasterizer_create(ctx, &rz) != NACRE_OK ||
        nc_vis_buffer_resize(ctx, &vis, WIDTH, HEIGHT) != NACRE_OK ||
        nc_gbuffer_resize(ctx, &gb, WIDTH, HEIGHT) != NACRE_OK) {
        rc = nc_tool_fail(ctx);
        goto out;
    }

    /* Frame the bounds. */
    nc_vec3 lo = nc_v3a(mesh.positions), hi = lo;
    for (uint32_t v = 1; v < mesh.vertex_count; v++) {
        nc_vec3 p = nc_v3a(mesh.positions + 3 * (size_t)v);
        lo = nc_vmin(lo, p);
        hi = nc_vmax(hi, p);
    }
    nc_vec3 centre = nc_scale(nc_add(lo, hi), 0.5f), ext = nc_sub(hi, lo);
    float fov = 40.0f * NC_DEG2RAD, aspect = (float)WIDTH / HEIGHT, t = tanf(0.5f * fov);
    float fit_h = 0.5f * ext.y / (0.9f * t), fit_w = 0.5f * ext.x / (0.9f * t * aspect);
    float dist = (fit_h > fit_w ? fit_h : fit_w) + 0.5f * ext.z;
    float radius = 0.5f * nc_length(ext);
    nc_raster_view view;
    memset(&view, 0, sizeof(view));
    view.view = nc_mat4_look_at(nc_add(centre, nc_v3(0, 0, dist)), centre, nc_v3(0, 1, 0));
    float znear = dist - radius > 1e-3f * dist ? dist - radius : 1e-3f * dist;
    view.proj = nc_mat4_perspective(fov, aspect, 0.5f * znear, dist + radius);
    view.width = WIDTH;
    view.height = HEIGHT;
    nc_raster_mesh rm = {mesh.positions, mesh.indices, mesh.vertex_count, mesh.triangle_count, 0,
                         false};
    nc_gbuffer_source src = {mesh.positions, mesh.normals, mesh.uvs, mesh.indices, 0};

    nc_raster_counts counts = {0, 0};
    for (long run = -1; run < runs; run++) {
        uint64_t t0 = nc_tool_now_us();
        if (nc_raster_visibility(rz, &view, &rm, 1, &vis, &counts) != NACRE_OK) {
            rc = nc_tool_fail(ctx);
            goto out;
        }
        uint64_t t1 = nc_tool_now_us();
        if (nc_gbuffer_resolve(ctx, &view, &vis, &src, 1, &gb) != NACRE_OK) {
            rc = nc_tool_fail(ctx);
            goto out;
        }
        uint64_t t2 = nc_tool_now_us();
        if (run < 0)
            continue;
        samples[run] = (t1 - t0) / 1000.0;
        samples[runs + run] = (t2 - t1) / 1000.0;
        samples[2 * runs + run] = (t2 - t0) / 1000.0;
    }
    size_t covered = 0;
    for (size_t p = 0; p < (size_t)WIDTH * HEIGHT; p++)
        covered += vis.object[p] != NC_NO_OBJECT;
    int n = (int)runs;
    stat3 sr = stats(samples, n), sg = stats(samples + n, n), st = stats(samples + 2 * n, n);
    int threads = nacre_context_threads(ctx);
    if (json) {
        printf("{\"bench\":\"raster\",\"scene\":\"lucy_1600k\",\"width\":%d,\"height\":%d,"
               "\"threads\":%d,"
               "\"runs\":%d,\"triangles\":%llu,\"triangles_drawn\":%llu,\"pixels_covered\":%zu,"
               "\"raster_ms\":%.3f,\"raster_min_ms\":%.3f,\"raster_max_ms\":%.3f,"
               "\"resolve_ms\":%.3f,\"resolve_min_ms\":%.3f,\"resolve_max_ms\":%.3f,"
               "\"total_ms\":%.3f,\"total_min_ms\":%.3f,\"total_max_ms\":%.3f}\n",
               WIDTH, HEIGHT, threads, n, (unsigned long long)counts.triangles,
               (unsigned long long)counts.triangles_drawn, covered, sr.median, sr.min, sr.max,
               sg.median, sg.min, sg.max, st.median, st.min, st.max);
    } else {
        printf("%s: %llu triangles (%llu drawn, %zu pixels covered), loaded in %.0f ms\n",
               mesh_path, (unsigned long long)counts.triangles,
               (unsigned long long)counts.triangles_drawn, covered, load_ms);
        printf("G-buffer %dx%d, %d threads, %d runs (ms):   median      min      max\n", WIDTH,
               HEIGHT, threads, n);
        printf("  %-8s %37.3f %8.3f %8.3f\n", "raster", sr.median, sr.min, sr.max);
        printf("  %-8s %37.3f %8.3f %8.3f\n", "resolve", sg.median, sg.min, sg.max);
        printf("  %-8s %37.3f %8.3f %8.3f\n", "total", st.median, st.min, st.max);
    }
    fflush(stdout);
    rc = 0;
out:
    free(samples);
    nc_gbuffer_free(ctx, &gb);
    nc_vis_buffer_free(ctx, &vis);
    nc_rasterizer_destroy(rz);
    nacre_mesh_data_free(ctx, &mesh);
    nacre_context_destroy(ctx);
    return rc;
}

/* Demo scene: every stage timed with caches cold (a fresh renderer per run). */
int nc_bench_demo(bool json, int runs)
{
    nacre_context *ctx = nc_tool_context(0);
    if (!ctx)
        return 2;
    nacre_scene *scene = NULL;
    nacre_scene_file_settings fs;
    nacre_render_settings rs;
    int rc = 2;
    double *samples = calloc((size_t)(runs * (NACRE_STAGE_COUNT + 1)), sizeof(double));
    nacre_image img = {0};
    if (!samples)
        goto out;
    if (nacre_scene_load_json(ctx, (const char *)nacre_demo_scene_json, strlen((const char *)nacre_demo_scene_json),
                              "<built-in demo>", ".", &scene, &fs) != NACRE_OK ||
        nacre_scene_commit(scene, 0.0) != NACRE_OK) {
        rc = nc_tool_fail(ctx);
        goto out;
    }
    rs = fs.render;
    rs.width = 1280;
    rs.height = 720;
    rs.method = NACRE_METHOD_PHONG;
    for (int run = -1; run < runs; run++) {
        nacre_render_stats st;
        if (nacre_render(scene, &rs, &img, &st) != NACRE_OK) {
            rc = nc_tool_fail(ctx);
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
            printf(",\"%s_ms\":%.3f", nacre_stage_name((nacre_stage)s), nc_tool_median(samples + s * runs, runs));
        printf(",\"total_ms\":%.3f}\n", nc_tool_median(samples + NACRE_STAGE_COUNT * runs, runs));
    } else {
        printf("demo scene, phong, 1280x720, %d threads, median of %d runs (ms):\n", nacre_context_threads(ctx), runs);
        for (int s = 0; s < NACRE_STAGE_COUNT; s++)
            printf("  %-8s %8.3f\n", nacre_stage_name((nacre_stage)s), nc_tool_median(samples + s * runs, runs));
        printf("  %-8s %8.3f\n", "total", nc_tool_median(samples + NACRE_STAGE_COUNT * runs, runs));
    }
    rc = 0;
out:
    free(samples);
    nacre_image_free(ctx, &img);
    nacre_scene_destroy(scene);
    nacre_context_destroy(ctx);
    return rc;
}

