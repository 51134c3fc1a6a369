/*
 * bench_load.c: `nacre bench load`: the time to load a mesh as a scene from a binary PLY
 * (nacre_mesh_load, then one object in a new scene, as a scene file referring to it does) and
 * from a glTF binary of the same triangles (nacre_scene_load_gltf: JSON, structure checks, assimp,
 * materials, scene), medians over the runs, and their ratio. The target for the
 * 1.6M-triangle Lucy is glb / ply <= 1.5. The .glb is not shipped: make it with
 * `python3 scripts/ply_to_glb.py lucy_1600k.ply lucy_1600k.glb` (found like the meshes, or --glb).
 */
#include "bench.h"

#include <stdio.h>
#include <stdlib.h>

static nacre_result load_ply_scene(nacre_context *ctx, const char *path)
{
    nacre_mesh_data m = {0};
    nacre_scene *scene = NULL;
    nacre_result r = nacre_mesh_load(ctx, path, &m);
    if (r == NACRE_OK)
        r = nacre_scene_create(ctx, &scene);
    nacre_object_desc d = nacre_object_desc_defaults();
    nacre_material_desc md = nacre_material_desc_defaults(NACRE_MATERIAL_OPAQUE);
    nacre_object obj;
    if (r == NACRE_OK)
        r = nacre_scene_add_material(scene, &md, &d.material);
    if (r == NACRE_OK)
        r = nacre_scene_add_mesh(scene, &m, &d.mesh);
    if (r == NACRE_OK)
        r = nacre_scene_add_object(scene, &d, &obj);
    nacre_mesh_data_free(ctx, &m);
    nacre_scene_destroy(scene);
    return r;
}

static nacre_result load_glb_scene(nacre_context *ctx, const char *path)
{
    nacre_scene *scene = NULL;
    nacre_result r = nacre_scene_load_gltf(ctx, path, NULL, &scene, NULL, NULL);
    nacre_scene_destroy(scene);
    return r;
}

int nc_bench_load(bool json, int runs, const char *ply_arg, const char *glb_arg)
{
    char ply[1024], glb[1024];
    if (ply_arg)
        snprintf(ply, sizeof(ply), "%s", ply_arg);
    else if (!nc_tool_find_mesh("lucy_1600k.ply", ply, sizeof(ply)))
        return nc_tool_error("bench load: lucy_1600k.ply not found (set NACRE_MESH_DIR or give --mesh)");
    if (glb_arg)
        snprintf(glb, sizeof(glb), "%s", glb_arg);
    else if (!nc_tool_find_mesh("lucy_1600k.glb", glb, sizeof(glb)))
        return nc_tool_error("bench load: lucy_1600k.glb not found: make it with python3 scripts/ply_to_glb.py "
                             "%s lucy_1600k.glb and give --glb", ply);
    nacre_context *ctx = nc_tool_context(0);
    if (!ctx)
        return 2;
    double *t = malloc(sizeof(double) * 2 * (size_t)runs);
    int rc = 2;
    if (!t)
        goto out;
    /* One warm-up of each (page cache), then alternate so that load changes hit both alike. */
    if (load_ply_scene(ctx, ply) != NACRE_OK || load_glb_scene(ctx, glb) != NACRE_OK) {
        nc_tool_fail(ctx);
        goto out;
    }
    for (int i = 0; i < runs; i++) {
        uint64_t t0 = nc_tool_now_us();
        if (load_ply_scene(ctx, ply) != NACRE_OK)
            goto fail;
        uint64_t t1 = nc_tool_now_us();
        if (load_glb_scene(ctx, glb) != NACRE_OK)
            goto fail;
        t[i] = (double)(t1 - t0) / 1000.0;
        t[runs + i] = (double)(nc_tool_now_us() - t1) / 1000.0;
    }
    double ply_ms = nc_tool_median(t, runs), glb_ms = nc_tool_median(t + runs, runs);
    if (json)
        printf("{\"bench\":\"load\",\"ply\":\"%s\",\"glb\":\"%s\",\"runs\":%d,\"ply_ms\":%.3f,\"glb_ms\":%.3f,"
               "\"ratio\":%.3f,\"target_ratio\":1.5}\n",
               ply, glb, runs, ply_ms, glb_ms, glb_ms / ply_ms);
    else
        printf("load as a scene (median of %d)\n  %-40s %9.1f ms\n  %-40s %9.1f ms\n  glb / ply %.2f (target <= 1.5)\n",
               runs, ply, ply_ms, glb, glb_ms, glb_ms / ply_ms);
    rc = 0;
    goto out;
fail:
    nc_tool_fail(ctx);
out:
    free(t);
    nacre_context_destroy(ctx);
    return rc;
}
