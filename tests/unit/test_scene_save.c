/*
 * test_scene_save.c: nacre_scene_save_file / nacre_scene_save_json (src/io/scene_write.c). Every
 * example scene loaded, saved, loaded again gives the same descs bit for bit and the same phong
 * and diffusion images; so does a scene edited through the C API, and one built from raw arrays
 * (its mesh written as PLY, its depth map as EXR, its volume as NRRD). A save that cannot be
 * written fails with one line and leaves no file; a save over a file the scene reads is refused.
 * Renders are small (64x48, voxel resolution 8, 256-texel shadow maps) to stay quick under ASan.
 */
#include "scene/scene.h"
#include "test_util.h"

#include <dirent.h>
#include <nacre/nacre.h>
#include <stddef.h>
#include <sys/stat.h>
#include <unistd.h>

#define TMP NACRE_TEST_TMP "/scene_save"

static bool exists(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0;
}

/* Field-by-field where a struct has padding or pointers, memcmp where it has neither. */
static bool same_light(const nacre_light_desc *a, const nacre_light_desc *b)
{
    return memcmp(a, b, offsetof(nacre_light_desc, cast_shadows)) == 0 &&
           a->cast_shadows == b->cast_shadows;
}

static bool same_object(const nacre_object_desc *a, const nacre_object_desc *b)
{
    bool names = (!a->name && !b->name) || (a->name && b->name && strcmp(a->name, b->name) == 0);
    return names && a->mesh.id == b->mesh.id && a->material.id == b->material.id &&
           memcmp(&a->transform, &b->transform, sizeof(a->transform)) == 0 &&
           a->deformer_count == b->deformer_count &&
           memcmp(a->deformers, b->deformers, a->deformer_count * sizeof(a->deformers[0])) == 0 &&
           a->cast_shadows == b->cast_shadows && a->double_sided == b->double_sided;
}

static bool same_floats(const float *a, const float *b, size_t n)
{
    return (!a && !b) || (a && b && memcmp(a, b, n * sizeof(float)) == 0);
}

static bool same_mesh(const nacre_mesh_data *a, const nacre_mesh_data *b)
{
    size_t nv = a->vertex_count;
    return a->vertex_count == b->vertex_count && a->triangle_count == b->triangle_count &&
           same_floats(a->positions, b->positions, nv * 3) &&
           same_floats(a->normals, b->normals, nv * 3) && same_floats(a->uvs, b->uvs, nv * 2) &&
           same_floats(a->tangents, b->tangents, nv * 4) &&
           memcmp(a->indices, b->indices, (size_t)a->triangle_count * 3 * sizeof(uint32_t)) == 0;
}

static bool same_settings(const nacre_scene_file_settings *a, const nacre_scene_file_settings *b)
{
    const nacre_render_settings *x = &a->render, *y = &b->render;
    return x->method == y->method && x->width == y->width && x->height == y->height &&
           memcmp(&x->shadow, &y->shadow, sizeof(x->shadow)) == 0 &&
           memcmp(&x->diffusion, &y->diffusion, sizeof(x->diffusion)) == 0 &&
           x->pathtrace.spp == y->pathtrace.spp && x->pathtrace.seed == y->pathtrace.seed &&
           x->pathtrace.time_limit == y->pathtrace.time_limit &&
           x->pathtrace.max_scatter == y->pathtrace.max_scatter && a->time == b->time &&
           a->exposure == b->exposure;
}

/* Every desc of the two scenes, the data of every mesh, texture and volume. Returns the number of
 * differences (0: identical), printing the first kind found. */
static int compare_scenes(const nacre_scene *a, const nacre_scene *b, const char *what)
{
    int diffs = 0;
#define DIFF(cond, kind)                                                                           \
    do {                                                                                           \
        if (!(cond)) {                                                                             \
            if (diffs++ == 0)                                                                      \
                printf("%s: %s differ\n", what, kind);                                             \
        }                                                                                          \
    } while (0)
    DIFF(a->unit_mm == b->unit_mm, "units");
    DIFF(memcmp(a->environment, b->environment, sizeof(a->environment)) == 0, "environments");
    DIFF(memcmp(&a->camera, &b->camera, sizeof(a->camera)) == 0, "cameras");
    DIFF(a->material_count == b->material_count, "material counts");
    for (uint32_t i = 0; i < a->material_count && i < b->material_count; i++)
        DIFF(memcmp(&a->materials[i], &b->materials[i], sizeof(a->materials[i])) == 0, "materials");
    DIFF(a->light_count == b->light_count, "light counts");
    for (uint32_t i = 0; i < a->light_count && i < b->light_count; i++)
        DIFF(same_light(&a->lights[i].desc, &b->lights[i].desc), "lights");
    DIFF(a->object_count == b->object_count, "object counts");
    for (uint32_t i = 0; i < a->object_count && i < b->object_count; i++) {
        DIFF(same_object(&a->objects[i].desc, &b->objects[i].desc), "objects");
        const nc_mesh_rec *ma = nc_scene_mesh(a, a->objects[i].desc.mesh),
                          *mb = nc_scene_mesh(b, b->objects[i].desc.mesh);
        DIFF(ma && mb && same_mesh(&ma->data, &mb->data), "meshes");
    }
    DIFF(a->fog_count == b->fog_count, "fog counts");
    for (uint32_t i = 0; i < a->fog_count && i < b->fog_count; i++)
        DIFF(memcmp(&a->fogs[i].desc, &b->fogs[i].desc, sizeof(a->fogs[i].desc)) == 0, "fogs");
    DIFF(a->texture_count == b->texture_count, "texture counts");
    for (uint32_t i = 0; i < a->texture_count && i < b->texture_count; i++) {
        const nc_texture_rec *x = &a->textures[i], *y = &b->textures[i];
        /* An EXR written for a 1- or 2-channel texture reads back with 3 channels. */
        bool ok = x->width == y->width && x->height == y->height && y->channels >= x->channels;
        for (size_t p = 0; ok && p < (size_t)x->width * (size_t)x->height; p++)
            ok = memcmp(x->data + p * (size_t)x->channels, y->data + p * (size_t)y->channels,
                        (size_t)x->channels * sizeof(float)) == 0;
        DIFF(ok, "textures");
    }
    DIFF(a->volume_count == b->volume_count, "volume counts");
    for (uint32_t i = 0; i < a->volume_count && i < b->volume_count; i++) {
        const nc_volume_rec *x = &a->volumes[i], *y = &b->volumes[i];
        bool ok = memcmp(x->dims, y->dims, sizeof(x->dims)) == 0 &&
                  memcmp(x->origin, y->origin, sizeof(x->origin)) == 0 &&
                  memcmp(x->spacing, y->spacing, sizeof(x->spacing)) == 0 &&
                  same_floats(x->data, y->data, (size_t)x->dims[0] * x->dims[1] * x->dims[2]);
        DIFF(ok, "volumes");
    }
#undef DIFF
    return diffs;
}

/* Render a committed scene; the result code, and the image in *img when it succeeds. */
static nacre_result render(nacre_scene *scene, double time, nacre_method method, nacre_image *img)
{
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = method;
    rs.width = 64;
    rs.height = 48;
    rs.shadow.map_size = 256;
    rs.diffusion.voxel_resolution = 8;
    if (nacre_scene_commit(scene, time) != NACRE_OK)
        return NACRE_ERROR_INVALID_ARGUMENT;
    return nacre_render(scene, &rs, img, NULL);
}

/* Phong and diffusion images of the two scenes are bit-identical (or both methods fail alike). */
static void check_same_images(nacre_context *ctx, nacre_scene *a, double ta, nacre_scene *b,
                              double tb, const char *what)
{
    const nacre_method methods[] = {NACRE_METHOD_PHONG, NACRE_METHOD_DIFFUSION};
    for (int m = 0; m < 2; m++) {
        nacre_image ia = {0}, ib = {0};
        nacre_result ra = render(a, ta, methods[m], &ia), rb = render(b, tb, methods[m], &ib);
        CHECK(ra == rb);
        if (ra == NACRE_OK && rb == NACRE_OK) {
            bool same = ia.width == ib.width && ia.height == ib.height &&
                        memcmp(ia.pixels, ib.pixels,
                               (size_t)ia.width * (size_t)ia.height * 3 * sizeof(float)) == 0;
            if (!same)
                printf("%s: %s images differ\n", what, nacre_method_name(methods[m]));
            CHECK(same);
        }
        nacre_image_free(ctx, &ia);
        nacre_image_free(ctx, &ib);
    }
}

/* Save `scene` to `path`, load it back; checks descs and images. Returns the reloaded scene. */
static nacre_scene *round_trip(nacre_context *ctx, nacre_scene *scene,
                               const nacre_scene_file_settings *fs, const char *path)
{
    nacre_result r = nacre_scene_save_file(scene, fs, path);
    if (r != NACRE_OK)
        printf("%s: save: %s\n", path, nacre_context_last_error(ctx));
    CHECK(r == NACRE_OK);
    nacre_scene *back = NULL;
    nacre_scene_file_settings fs2;
    r = nacre_scene_load_file(ctx, path, &back, &fs2);
    if (r != NACRE_OK)
        printf("%s: reload: %s\n", path, nacre_context_last_error(ctx));
    CHECK(r == NACRE_OK);
    if (!back)
        return NULL;
    CHECK(same_settings(fs, &fs2));
    CHECK(compare_scenes(scene, back, path) == 0);
    check_same_images(ctx, scene, fs->time, back, fs2.time, path);
    return back;
}

static void test_examples(nacre_context *ctx)
{
    char dir[1024];
    snprintf(dir, sizeof(dir), "%s/examples", NACRE_SOURCE_DIR);
    DIR *d = opendir(dir);
    CHECK(d != NULL);
    int count = 0;
    for (struct dirent *e; d && (e = readdir(d));) {
        size_t n = strlen(e->d_name);
        if (n < 6 || strcmp(e->d_name + n - 5, ".json") != 0)
            continue;
        char in[2048], out[2048];
        snprintf(in, sizeof(in), "%s/%s", dir, e->d_name);
        snprintf(out, sizeof(out), "%s/%s", TMP, e->d_name);
        nacre_scene *scene = NULL;
        nacre_scene_file_settings fs;
        CHECK(nacre_scene_load_file(ctx, in, &scene, &fs) == NACRE_OK);
        if (!scene)
            continue;
        nacre_scene_destroy(round_trip(ctx, scene, &fs, out));
        nacre_scene_destroy(scene);
        count++;
    }
    if (d)
        closedir(d);
    CHECK(count >= 10);
}

/* Edits through the C API (a material's absorption, a light's position, the camera, the time)
 * are what the saved file holds. */
static void test_edited(nacre_context *ctx)
{
    char in[1024];
    snprintf(in, sizeof(in), "%s/examples/point_light.json", NACRE_SOURCE_DIR);
    nacre_scene *scene = NULL;
    nacre_scene_file_settings fs;
    CHECK(nacre_scene_load_file(ctx, in, &scene, &fs) == NACRE_OK);
    if (!scene)
        return;
    nacre_material_desc md = scene->materials[0]; /* "marble", translucent */
    CHECK(md.type == NACRE_MATERIAL_TRANSLUCENT);
    md.sigma_a[0] = 0.0123456789f;
    md.sigma_s[2] = 1.0f / 3.0f;
    CHECK(nacre_scene_set_material(scene, (nacre_material){1}, &md) == NACRE_OK);
    nacre_light_desc ld = scene->lights[0].given;
    ld.position[0] += 7.1f;
    ld.position[1] *= 0.9f;
    CHECK(nacre_scene_set_light(scene, (nacre_light){1}, &ld) == NACRE_OK);
    nacre_camera_desc cam = scene->camera;
    cam.position[0] += 13.3f;
    cam.fov_y = 33.3f;
    CHECK(nacre_scene_set_camera(scene, &cam) == NACRE_OK);
    fs.time = 1.0 / 3.0;
    char out[1024];
    snprintf(out, sizeof(out), "%s/edited.json", TMP);
    nacre_scene *back = round_trip(ctx, scene, &fs, out);
    if (back) {
        CHECK(back->materials[0].sigma_a[0] == 0.0123456789f);
        CHECK(back->camera.fov_y == 33.3f);
    }
    nacre_scene_destroy(back);
    nacre_scene_destroy(scene);
}

/* A scene made only through the C API from raw arrays: a bumpy grid mesh with normals and uvs,
 * a translucent material with a raw volume pattern, a layered one with a raw 2-channel depth map,
 * an opaque one; the saved scene's PLY, EXR and NRRD reload bit for bit. */
static nacre_scene *make_raw_scene(nacre_context *ctx)
{
    enum { N = 9 };
    float pos[N * N * 3], nrm[N * N * 3], uv[N * N * 2];
    uint32_t idx[(N - 1) * (N - 1) * 6];
    for (int j = 0; j < N; j++)
        for (int i = 0; i < N; i++) {
            int v = j * N + i;
            float x = (float)i / (N - 1) * 2 - 1, z = (float)j / (N - 1) * 2 - 1;
            pos[3 * v] = x;
            pos[3 * v + 1] = 0.2f * sinf(3 * x) * cosf(2 * z);
            pos[3 * v + 2] = z;
            float nx = -0.6f * cosf(3 * x) * cosf(2 * z), nz = 0.4f * sinf(3 * x) * sinf(2 * z);
            float len = sqrtf(nx * nx + 1 + nz * nz);
            nrm[3 * v] = nx / len;
            nrm[3 * v + 1] = 1 / len;
            nrm[3 * v + 2] = nz / len;
            uv[2 * v] = (float)i / (N - 1);
            uv[2 * v + 1] = (float)j / (N - 1);
        }
    int t = 0;
    for (int j = 0; j + 1 < N; j++)
        for (int i = 0; i + 1 < N; i++) {
            uint32_t a = (uint32_t)(j * N + i), b = a + 1, c = a + N, dd = c + 1;
            uint32_t tri[6] = {a, c, b, b, c, dd};
            memcpy(idx + 6 * t++, tri, sizeof(tri));
        }
    nacre_mesh_data md = {N * N, (N - 1) * (N - 1) * 2, pos, nrm, uv, NULL, idx};
    nacre_scene *s = NULL;
    CHECK(nacre_scene_create(ctx, &s) == NACRE_OK);
    CHECK(nacre_scene_set_unit_mm(s, 2.5f) == NACRE_OK);
    nacre_mesh mesh;
    CHECK(nacre_scene_add_mesh(s, &md, &mesh) == NACRE_OK);

    float density[4 * 3 * 2];
    for (int i = 0; i < 24; i++)
        density[i] = 0.1f + (float)i / 7.0f;
    nacre_volume_data vd = {{4, 3, 2}, {-1.1f, -0.3f, -1.05f}, {0.7f, 0.3f, 2.1f}, density};
    nacre_volume vol;
    CHECK(nacre_scene_add_volume(s, &vd, &vol) == NACRE_OK);
    float texels[5 * 3 * 2];
    for (int i = 0; i < 30; i++)
        texels[i] = (float)(i % 7) / 6.0f + 1e-3f * (float)i;
    nacre_image tex = {5, 3, 2, 10, texels};
    nacre_texture tx;
    CHECK(nacre_scene_add_texture(s, &tex, &tx) == NACRE_OK);

    nacre_material_desc cloudy = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
    cloudy.sigma_s[1] = 0.7777777f;
    cloudy.pattern.type = NACRE_PATTERN_VOLUME;
    cloudy.pattern.fraction = 0.5f; /* as the loader leaves the fields a volume pattern ignores */
    cloudy.pattern.octaves = 4;
    cloudy.pattern.volume = vol;
    nacre_material_desc layered = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
    layered.layering.count = 2;
    layered.layering.layers[0] = (nacre_layer){{0.05f, 0.1f, 0.3f}, {4, 4, 4}, 0.8f, 0.15f};
    layered.layering.layers[1] = (nacre_layer){{0.3f, 1.5f, 1.2f}, {1.5f, 1.5f, 1.5f}, 0.9f, 0.3f};
    layered.layering.depth_map = tx;
    nacre_material_desc ground = nacre_material_desc_defaults(NACRE_MATERIAL_OPAQUE);
    ground.diffuse[2] = 0.123456f;
    nacre_material m_cloudy, m_layered, m_ground;
    CHECK(nacre_scene_add_material(s, &cloudy, &m_cloudy) == NACRE_OK);
    CHECK(nacre_scene_add_material(s, &layered, &m_layered) == NACRE_OK);
    CHECK(nacre_scene_add_material(s, &ground, &m_ground) == NACRE_OK);

    nacre_object_desc od = nacre_object_desc_defaults();
    od.mesh = mesh;
    od.material = m_cloudy;
    od.transform.rotate[1] = 17.5f;
    od.deformers[0] = nacre_deformer_defaults(NACRE_DEFORM_TWIST);
    od.deformers[0].angle = 40.0f;
    od.deformers[0].angle_rate = 3.0f;
    od.deformer_count = 1;
    nacre_object obj;
    CHECK(nacre_scene_add_object(s, &od, &obj) == NACRE_OK);
    od = nacre_object_desc_defaults();
    od.mesh = mesh;
    od.material = m_layered;
    od.name = "second";
    od.transform.translate[0] = 2.2f;
    od.transform.scale[1] = 1.7f;
    od.double_sided = true;
    CHECK(nacre_scene_add_object(s, &od, &obj) == NACRE_OK);
    od.material = m_ground;
    od.name = NULL;
    od.transform.translate[1] = -0.5f;
    od.transform.scale[0] = od.transform.scale[2] = 6.0f;
    od.cast_shadows = false;
    CHECK(nacre_scene_add_object(s, &od, &obj) == NACRE_OK);

    nacre_light_desc sun = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
    sun.direction[0] = 0.3f; /* not unit: the file keeps it as given */
    nacre_light light;
    CHECK(nacre_scene_add_light(s, &sun, &light) == NACRE_OK);
    nacre_light_desc spot = nacre_light_desc_defaults(NACRE_LIGHT_SPOT);
    spot.position[0] = 1.0f;
    spot.position[1] = 3.0f;
    spot.direction[0] = -0.2f;
    spot.falloff = NACRE_SPOT_FALLOFF_GLTF; /* not the default: the file must keep it */
    CHECK(nacre_scene_add_light(s, &spot, &light) == NACRE_OK);
    nacre_camera_desc cam = nacre_camera_desc_defaults();
    cam.position[1] = 2.5f;
    CHECK(nacre_scene_set_camera(s, &cam) == NACRE_OK);
    float env[3] = {0.1f, 0.2f, 0.3f};
    CHECK(nacre_scene_set_environment(s, env) == NACRE_OK);
    return s;
}

static void test_raw_scene(nacre_context *ctx)
{
    nacre_scene *s = make_raw_scene(ctx);
    nacre_scene_file_settings fs = {
        .render = nacre_render_settings_defaults(), .time = 0.25, .exposure = -1.5f};
    char out[1024], ply[1024];
    snprintf(out, sizeof(out), "%s/raw.json", TMP);
    snprintf(ply, sizeof(ply), "%s/raw_mesh1.ply", TMP);
    remove(ply);
    nacre_scene *back = round_trip(ctx, s, &fs, out);
    CHECK(exists(ply));
    char path[1024];
    snprintf(path, sizeof(path), "%s/raw_depth1.exr", TMP);
    CHECK(exists(path));
    snprintf(path, sizeof(path), "%s/raw_volume1.nrrd", TMP);
    CHECK(exists(path));
    /* Saving the reloaded scene refers to those files instead of writing them again, by paths
     * relative to its folder. */
    char *json = NULL;
    size_t length = 0;
    CHECK(back && nacre_scene_save_json(back, NULL, TMP, &json, &length) == NACRE_OK);
    CHECK(json && length == strlen(json));
    CHECK(json && strstr(json, "\"raw_mesh1.ply\"") && strstr(json, "\"raw_volume1.nrrd\"") &&
          strstr(json, "\"material1\""));
    nacre_scene *again = NULL;
    CHECK(json && nacre_scene_load_json(ctx, json, length, "again", TMP, &again, NULL) == NACRE_OK);
    CHECK(again && compare_scenes(back, again, "save_json") == 0);
    nacre_free(ctx, json);
    nacre_scene_destroy(again);
    nacre_scene_destroy(back);

    /* Values the format cannot hold are refused by name, and nothing is written. */
    nacre_object_desc od = s->objects[0].desc;
    od.transform.scale[2] = -1.0f;
    CHECK(nacre_scene_set_object(s, (nacre_object){1}, &od) == NACRE_OK);
    snprintf(out, sizeof(out), "%s/mirrored.json", TMP);
    CHECK(nacre_scene_save_file(s, &fs, out) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "objects[0].transform.scale") != NULL);
    CHECK(!exists(out));
    snprintf(path, sizeof(path), "%s/mirrored_mesh1.ply", TMP);
    CHECK(!exists(path));
    nacre_scene_destroy(s);
}

/* Entries of TMP whose names start with `prefix` (temporary files included). */
static int count_files(const char *prefix)
{
    DIR *d = opendir(TMP);
    int n = 0;
    for (struct dirent *e; d && (e = readdir(d));)
        n += strncmp(e->d_name, prefix, strlen(prefix)) == 0;
    if (d)
        closedir(d);
    return n;
}

static void test_failures(nacre_context *ctx)
{
    nacre_scene *s = make_raw_scene(ctx);
    /* A folder that does not exist: one line naming the path. */
    nacre_result r = nacre_scene_save_file(s, NULL, TMP "/no/such/folder/x.json");
    CHECK(r == NACRE_ERROR_IO);
    const char *msg = nacre_context_last_error(ctx);
    CHECK(strstr(msg, "no/such/folder") != NULL && strchr(msg, '\n') == NULL);
    /* The scene path is a folder: the PLY, EXR and NRRD are written first, then the scene file
     * cannot be; everything this save wrote is removed again. */
    char dir[1024];
    snprintf(dir, sizeof(dir), "%s/blocked.json", TMP);
    mkdir(dir, 0755);
    r = nacre_scene_save_file(s, NULL, dir);
    CHECK(r == NACRE_ERROR_IO);
    msg = nacre_context_last_error(ctx);
    CHECK(strstr(msg, "blocked.json") != NULL && strchr(msg, '\n') == NULL);
    CHECK(count_files("blocked") == 1); /* the folder itself */
    rmdir(dir);
    nacre_scene_destroy(s);

    /* A save over a file the scene reads (its mesh) is refused and leaves it as it was. */
    char mesh[1024], scene_path[1024], cmd[4096];
    snprintf(mesh, sizeof(mesh), "%s/input.ply", TMP);
    snprintf(cmd, sizeof(cmd), "cp %s/examples/meshes/suzanne.ply %s", NACRE_SOURCE_DIR, mesh);
    CHECK(system(cmd) == 0);
    snprintf(scene_path, sizeof(scene_path), "%s/input.json", TMP);
    FILE *f = fopen(scene_path, "wb");
    CHECK(f != NULL);
    if (f) {
        fputs("{\"materials\": {\"m\": {\"type\": \"opaque\"}},\n"
              " \"objects\": [{\"mesh\": \"input.ply\", \"material\": \"m\"}]}\n",
              f);
        fclose(f);
    }
    struct stat before, after;
    CHECK(stat(mesh, &before) == 0);
    s = NULL;
    CHECK(nacre_scene_load_file(ctx, scene_path, &s, NULL) == NACRE_OK);
    char spelled[1024];
    snprintf(spelled, sizeof(spelled), "%s/../scene_save/./input.ply", TMP);
    CHECK(s && nacre_scene_save_file(s, NULL, spelled) == NACRE_ERROR_INVALID_ARGUMENT);
    msg = nacre_context_last_error(ctx);
    CHECK(strstr(msg, "which the scene reads") != NULL && strstr(msg, "input.ply") != NULL);
    CHECK(stat(mesh, &after) == 0 && after.st_size == before.st_size &&
          after.st_mtime == before.st_mtime);
    CHECK(count_files("input") == 2); /* no temporary file either */
    /* Saving over the scene's own file is allowed (File > Save): it refers to its mesh. */
    CHECK(s && nacre_scene_save_file(s, NULL, scene_path) == NACRE_OK);
    nacre_scene *back = NULL;
    CHECK(nacre_scene_load_file(ctx, scene_path, &back, NULL) == NACRE_OK);
    CHECK(back && compare_scenes(s, back, "input.json") == 0);
    nacre_scene_destroy(back);
    nacre_scene_destroy(s);
}

int main(void)
{
    mkdir(NACRE_TEST_TMP, 0755);
    mkdir(TMP, 0755);
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    test_examples(ctx);
    test_edited(ctx);
    test_raw_scene(ctx);
    test_failures(ctx);
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
