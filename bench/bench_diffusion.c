/*
 * bench_diffusion.c: `nacre bench diffusion`, pipeline part: the layout of the seed's tables
 * 5.1-5.3 (Blanchard 2012: per-stage microseconds and frames per second of the diffusion
 * pipeline on a GTX 470) for our stand-ins of its meshes, at 4^3, 12^3, 28^3 (the seed's
 * resolutions), 64^3 and 128^3, shaded at 1280x720, plus Suzanne at 64^3 shaded at 640x480.
 *
 * Each mesh is scaled to 50 mm along its longest axis and given the seed's jade; one directional
 * light from the upper right (the seed's figure 5.6); the camera frames the mesh. Every timed
 * frame rotates the object by 0.01 degree and commits, so every stage runs again as for a
 * deforming mesh (the seed re-voxelizes every frame). The seed's total covers voxelize, shadow
 * maps (PLV), inject, propagate and the diffusion shading pass, not the G-buffer: our `total`
 * is the same sum. Reported beside it and not in it: `raster` (visibility + G-buffer), `shadow`
 * (the lights' mesh shadow maps, which the shading pass reads to shadow the specular term; the
 * seed's tables list no such stage; re-rendered every frame here because the object moves) and
 * `frame` (the whole render call, every stage). Commit (vertex transform) is in none.
 *
 * Frames render into the same image with reuse_output, as a viewer does: background pixels that
 * were background in the previous frame are not rewritten (a GPU clears its frame buffer at
 * almost no cost; we skip the clear where it would change nothing). --repaint writes every pixel
 * of every frame; the JSON rows say which ("reuse_output").
 */
#include "bench.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const struct {
    const char *file;
    const char *seed_name;
    /* seed tables 5.1, 5.2, 5.3: voxelize, PLV, inject, propagate, render, total (us), fps */
    double seed[3][7];
} meshes[] = {
    {"suzanne_subdiv2.ply", "Suzanne (15k)",
     {{266, 83, 1095, 364, 227, 2035, 491}, {257, 424, 1640, 2432, 269, 5022, 199}, {286, 2148, 2004, 7958, 337, 12733, 79}}},
    {"armadillo_400k.ply", "Armadillo (346k)",
     /* table 5.2 prints the total as 1081; the stages sum to 10081 and 99 fps agrees */
     {{4906, 89, 1236, 357, 202, 6790, 147}, {5046, 568, 1780, 2432, 255, 10081, 99}, {5208, 2941, 1932, 8089, 311, 18481, 54}}},
    {"dragon.ply", "Statue (800k)",
     {{9700, 68, 1214, 287, 178, 11447, 87}, {8789, 454, 1693, 2315, 218, 13469, 74}, {8627, 2198, 1914, 6644, 288, 19671, 51}}},
    {"lucy_1600k.ply", "Lucy (2027k)",
     {{26401, 62, 1244, 287, 185, 28179, 35}, {24822, 286, 1770, 2274, 220, 29372, 34}, {23705, 2024, 1932, 6876, 259, 34796, 29}}},
};
static const uint32_t resolutions[] = {4, 12, 28, 64, 128};

enum { COL_VOX, COL_TSM, COL_INJ, COL_PROP, COL_SHADE, COL_TOTAL, COL_RASTER, COL_SHADOW, COL_FRAME, COL_COUNT };

/* Build the scene for one mesh: scaled to 50 mm, jade, a sun from the upper right. */
static nacre_result make_scene(nacre_context *ctx, const nacre_mesh_data *mesh, nacre_scene **out, nacre_object *obj,
                               nacre_object_desc *od)
{
    nacre_scene *scene = NULL;
    nacre_result res = nacre_scene_create(ctx, &scene);
    if (res != NACRE_OK)
        return res;
    float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (uint32_t v = 0; v < mesh->vertex_count; v++)
        for (int a = 0; a < 3; a++) {
            float p = mesh->positions[3 * v + a];
            lo[a] = p < lo[a] ? p : lo[a];
            hi[a] = p > hi[a] ? p : hi[a];
        }
    float ext = fmaxf(hi[0] - lo[0], fmaxf(hi[1] - lo[1], hi[2] - lo[2]));
    float k = ext > 0 ? 50.0f / ext : 1.0f;
    nacre_mesh m;
    nacre_material mat;
    nacre_material_desc md;
    nacre_material_preset("jade", &md);
    *od = nacre_object_desc_defaults();
    if ((res = nacre_scene_add_mesh(scene, mesh, &m)) != NACRE_OK || (res = nacre_scene_add_material(scene, &md, &mat)) != NACRE_OK)
        goto fail;
    od->mesh = m;
    od->material = mat;
    for (int a = 0; a < 3; a++) {
        od->transform.scale[a] = k;
        od->transform.translate[a] = -0.5f * (lo[a] + hi[a]) * k;
    }
    if ((res = nacre_scene_add_object(scene, od, obj)) != NACRE_OK)
        goto fail;
    nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
    float dir[3] = {-0.6f, -0.6f, -0.5f};
    float n = sqrtf(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
    for (int a = 0; a < 3; a++) {
        ld.direction[a] = dir[a] / n;
        ld.strength[a] = 3.0f;
    }
    nacre_light light;
    if ((res = nacre_scene_add_light(scene, &ld, &light)) != NACRE_OK)
        goto fail;
    nacre_camera_desc cd = nacre_camera_desc_defaults();
    cd.position[0] = 0.0f;
    cd.position[1] = 0.0f;
    cd.position[2] = 95.0f;
    cd.fov_y = 40.0f;
    if ((res = nacre_scene_set_camera(scene, &cd)) != NACRE_OK)
        goto fail;
    float env[3] = {0.05f, 0.05f, 0.05f};
    nacre_scene_set_environment(scene, env);
    *out = scene;
    return NACRE_OK;
fail:
    nacre_scene_destroy(scene);
    return res;
}

static int run_case(nacre_context *ctx, nacre_renderer *renderer, nacre_scene *scene, nacre_object obj,
                    nacre_object_desc *od, uint32_t res_n, int width, int height, int runs, double *samples,
                    double med[COL_COUNT], uint32_t *iterations, uint32_t dims[3], bool repaint)
{
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = NACRE_METHOD_DIFFUSION;
    rs.width = width;
    rs.height = height;
    rs.diffusion.voxel_resolution = res_n;
    rs.reuse_output = !repaint;
    nacre_image img = {0};
    int rc = 0;
    for (int run = -1; run < runs; run++) {
        od->transform.rotate[1] += 0.01f;
        nacre_render_stats st;
        if (nacre_scene_set_object(scene, obj, od) != NACRE_OK || nacre_scene_commit(scene, 0.0) != NACRE_OK ||
            nacre_renderer_render(renderer, scene, &rs, &img, &st) != NACRE_OK) {
            rc = nc_tool_fail(ctx);
            break;
        }
        *iterations = st.iterations;
        memcpy(dims, st.voxel_dims, sizeof(st.voxel_dims));
        if (run < 0)
            continue;
        double v[COL_COUNT];
        /* The seed's voxelization writes each voxel's material: our voxelize and medium stages. */
        v[COL_VOX] = (double)(st.stage_us[NACRE_STAGE_VOXELIZE] + st.stage_us[NACRE_STAGE_MEDIUM]);
        v[COL_TSM] = (double)st.stage_us[NACRE_STAGE_TSM];
        v[COL_INJ] = (double)st.stage_us[NACRE_STAGE_INJECT];
        v[COL_PROP] = (double)st.stage_us[NACRE_STAGE_PROPAGATE];
        v[COL_SHADE] = (double)st.stage_us[NACRE_STAGE_SHADE];
        v[COL_TOTAL] = v[COL_VOX] + v[COL_TSM] + v[COL_INJ] + v[COL_PROP] + v[COL_SHADE];
        v[COL_RASTER] = (double)(st.stage_us[NACRE_STAGE_RASTER] + st.stage_us[NACRE_STAGE_GBUFFER]);
        v[COL_SHADOW] = (double)st.stage_us[NACRE_STAGE_SHADOW];
        v[COL_FRAME] = (double)st.total_us;
        for (int c = 0; c < COL_COUNT; c++)
            samples[c * runs + run] = v[c];
    }
    nacre_image_free(ctx, &img);
    if (rc == 0)
        for (int c = 0; c < COL_COUNT; c++)
            med[c] = nc_tool_median(samples + c * runs, runs);
    return rc;
}

static void print_row(bool json, const char *file, uint32_t tris, uint32_t res_n, int w, int h, const double m[COL_COUNT],
                      uint32_t iterations, const uint32_t dims[3], const double *seed, bool repaint)
{
    double fps = m[COL_TOTAL] > 0 ? 1e6 / m[COL_TOTAL] : 0;
    if (json) {
        printf("{\"bench\":\"diffusion\",\"mesh\":\"%s\",\"triangles\":%u,\"res\":%u,\"width\":%d,\"height\":%d,"
               "\"voxel_dims\":[%u,%u,%u],\"voxelize_us\":%.0f,\"tsm_us\":%.0f,\"inject_us\":%.0f,\"propagate_us\":%.0f,"
               "\"shade_us\":%.0f,\"total_us\":%.0f,\"fps\":%.1f,\"raster_us\":%.0f,\"shadow_us\":%.0f,"
               "\"frame_us\":%.0f,\"iterations\":%u,\"reuse_output\":%s",
               file, tris, res_n, w, h, dims[0], dims[1], dims[2], m[COL_VOX], m[COL_TSM], m[COL_INJ], m[COL_PROP],
               m[COL_SHADE], m[COL_TOTAL], fps, m[COL_RASTER], m[COL_SHADOW], m[COL_FRAME], iterations,
               repaint ? "false" : "true");
        if (seed)
            printf(",\"seed_voxelize_us\":%.0f,\"seed_tsm_us\":%.0f,\"seed_inject_us\":%.0f,\"seed_propagate_us\":%.0f,"
                   "\"seed_shade_us\":%.0f,\"seed_total_us\":%.0f,\"seed_fps\":%.0f",
                   seed[0], seed[1], seed[2], seed[3], seed[4], seed[5], seed[6]);
        printf("}\n");
    } else {
        printf("%-20s %5u %4dx%-4d %8.0f %7.0f %7.0f %9.0f %7.0f %8.0f %6.1f %8.0f %7.0f %7.0f %5u", file, res_n, w, h,
               m[COL_VOX], m[COL_TSM], m[COL_INJ], m[COL_PROP], m[COL_SHADE], m[COL_TOTAL], fps, m[COL_RASTER],
               m[COL_SHADOW], m[COL_FRAME], iterations);
        if (seed)
            printf("  | %6.0f %5.0f %5.0f %6.0f %4.0f %6.0f %4.0f", seed[0], seed[1], seed[2], seed[3], seed[4], seed[5],
                   seed[6]);
        printf("\n");
    }
    fflush(stdout);
}

int nc_bench_diffusion_pipeline(bool json, int runs, const nc_bench_filter *filter, bool repaint)
{
    nacre_context *ctx = nc_tool_context(0);
    if (!ctx)
        return 2;
    if (!nacre_method_available(NACRE_METHOD_DIFFUSION)) {
        fprintf(stderr, "nacre bench diffusion: the diffusion method is not implemented in this build\n");
        nacre_context_destroy(ctx);
        return 2;
    }
    int rc = 2;
    double *samples = calloc((size_t)runs * COL_COUNT, sizeof(double));
    nacre_renderer *renderer = NULL;
    if (!samples || nacre_renderer_create(ctx, &renderer) != NACRE_OK)
        goto out;
    if (!json)
        printf("diffusion pipeline (us), %d threads, median of %d runs; total = voxelize+tsm+inject+propagate+shade "
               "(the seed's); beside it, not in it: raster = camera G-buffer, shadow = the lights' shadow maps (the "
               "specular term's shadows), frame = the whole render call; %s\n"
               "%-20s %5s %9s %8s %7s %7s %9s %7s %8s %6s %8s %7s %7s %5s  | seed GTX 470 (tables 5.1-5.3): vox PLV inj "
               "prop rend total fps\n",
               nacre_context_threads(ctx), runs,
               repaint ? "every pixel written every frame" : "frames reuse the previous frame's background", "mesh",
               "res", "image", "voxelize", "tsm", "inject", "propagate", "shade", "total", "fps", "raster", "shadow",
               "frame", "iter");
    for (size_t mi = 0; mi < sizeof(meshes) / sizeof(meshes[0]); mi++) {
        char path[4096];
        if (!nc_bench_filter_mesh(filter, meshes[mi].file))
            continue;
        if (!nc_tool_find_mesh(meshes[mi].file, path, sizeof(path))) {
            fprintf(stderr, "nacre bench diffusion: %s not found, skipped\n", meshes[mi].file);
            continue;
        }
        nacre_mesh_data mesh = {0};
        nacre_scene *scene = NULL;
        nacre_object obj;
        nacre_object_desc od;
        if (nacre_mesh_load(ctx, path, &mesh) != NACRE_OK || make_scene(ctx, &mesh, &scene, &obj, &od) != NACRE_OK) {
            nacre_mesh_data_free(ctx, &mesh);
            rc = nc_tool_fail(ctx);
            goto out;
        }
        uint32_t tris = mesh.triangle_count;
        nacre_mesh_data_free(ctx, &mesh);
        for (size_t r = 0; r < sizeof(resolutions) / sizeof(resolutions[0]); r++) {
            double med[COL_COUNT];
            uint32_t iterations = 0, dims[3] = {0, 0, 0};
            if (filter->res && filter->res != resolutions[r])
                continue;
            if (run_case(ctx, renderer, scene, obj, &od, resolutions[r], 1280, 720, runs, samples, med, &iterations,
                         dims, repaint) != 0) {
                nacre_scene_destroy(scene);
                goto out;
            }
            print_row(json, meshes[mi].file, tris, resolutions[r], 1280, 720, med, iterations, dims,
                      r < 3 ? meshes[mi].seed[r] : NULL, repaint);
        }
        if (mi == 0 && (!filter->res || filter->res == 64)) {
            /* The interactive target: Suzanne at 64^3 shaded at 640x480. */
            double med[COL_COUNT];
            uint32_t iterations = 0, dims[3] = {0, 0, 0};
            if (run_case(ctx, renderer, scene, obj, &od, 64, 640, 480, runs, samples, med, &iterations, dims,
                         repaint) != 0) {
                nacre_scene_destroy(scene);
                goto out;
            }
            print_row(json, meshes[mi].file, tris, 64, 640, 480, med, iterations, dims, NULL, repaint);
        }
        nacre_scene_destroy(scene);
    }
    rc = 0;
out:
    nacre_renderer_destroy(renderer);
    free(samples);
    nacre_context_destroy(ctx);
    return rc;
}
