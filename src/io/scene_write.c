/*
 * scene_write.c: nacre_scene_save_file and nacre_scene_save_json write a scene's current state
 * (after any edits through the C API) as a scene file in the format nacre_scene_load_file reads
 * (docs/scene-format.md, "Saving a scene"), so that loading it gives the same descs bit for bit.
 *
 * Conventions. The JSON is built with cJSON, numbers inserted as raw text: each float with the
 * fewest digits (6 to 9, as "%.9g" at most) and each double with 15 to 17 ("%.17g") that read
 * back (strtod, then the loader's cast to float) as the same value. Every value is written
 * explicitly (no presets, no defaults left to the loader), except fields that the element's type
 * ignores and the format has no key for. Elements keep their order, so handles keep their ids on
 * reload: materials in id order (all of them), lights, objects, fogs. Meshes, textures and volumes
 * are referred to where they came from (nc_mesh_rec's source: a file, relative to the scene file's
 * folder when it lies in it or below, else absolute; or a shape desc); those made from raw arrays
 * are written beside the scene file as <stem>_mesh<id>.ply (binary, assimp's exporter),
 * <stem>_depth<id>.exr (float) and <stem>_volume<id>.nrrd (float), all lossless. Values the C API
 * accepts but the format does not (a mirroring scale, a colour above 1) are refused with one
 * message naming the field.
 *
 * Every file is written under a temporary name and renamed; a failed save removes the files it
 * generated and leaves nothing at the scene path. No file is written over one the scene reads
 * (its inputs and sources), compared by device and inode.
 */
#define _XOPEN_SOURCE 700 /* realpath (XSI); the build asks for POSIX 2008 only */
#include "io/nrrd.h"
#include "io/scene_json_internal.h"
#include "io/tmpfile.h"
#include <nacre/particles.h>

#include <assimp/cexport.h>
#include <assimp/material.h>
#include <assimp/scene.h>

#include <errno.h>
#include <float.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define IMAGE_SIZE_MAX 16384 /* the loader's range for width, height, shadow_map_size */

typedef struct writer {
    nacre_context *ctx;
    const nacre_scene *scene;
    const char *label; /* in messages: the scene file's path, or "<json>" */
    char *dir;         /* absolute folder of the scene file; generated files go there */
    const char *stem;  /* generated files are <stem>_<kind><id>.<ext> */
    char **names;      /* one per material: unique, non-empty */
    char **mesh_refs, **texture_refs, **volume_refs; /* per handle, once written or resolved */
    char **written; /* generated files, removed if the save fails */
    uint32_t written_count;
    nacre_result err; /* first failure (sticky) */
} writer;

/* ------------------------------------------------------------------------------------------ */
/* Failures and values                                                                        */
/* ------------------------------------------------------------------------------------------ */

static void fail(writer *w, nacre_result code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

static void fail(writer *w, nacre_result code, const char *fmt, ...)
{
    if (w->err != NACRE_OK)
        return;
    char msg[NC_ERROR_MAX];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof(msg), fmt, ap);
    va_end(ap);
    w->err = nc_fail(w->ctx, code, "%s: %s", w->label, msg);
}

/* A lower layer recorded its message (which names its file): keep it. */
static void fail_inner(writer *w, nacre_result code)
{
    if (w->err == NACRE_OK)
        w->err = code != NACRE_OK ? code : NACRE_ERROR_INVALID_ARGUMENT;
}

static void add(writer *w, cJSON *obj, const char *key, cJSON *item)
{
    if (w->err == NACRE_OK && item &&
        (key ? cJSON_AddItemToObject(obj, key, item) : cJSON_AddItemToArray(obj, item)))
        return;
    cJSON_Delete(item);
    if (w->err == NACRE_OK)
        fail(w, NACRE_ERROR_OUT_OF_MEMORY, "out of memory building the JSON");
}

/* Numbers go in as raw text so that their precision is ours: the fewest significant digits (at
 * least 6, at most 9 for a float and 17 for a double, which always suffice) whose decimal reads
 * back as the same value the way the loader reads it (cJSON's strtod, then a cast for floats).
 * 0.1f is written 0.1, not 0.100000001. */
static cJSON *raw_float(float v)
{
    char buf[48];
    for (int digits = 6; digits <= 9; digits++) {
        snprintf(buf, sizeof(buf), "%.*g", digits, (double)v);
        if ((float)strtod(buf, NULL) == v)
            break;
    }
    return cJSON_CreateRaw(buf);
}

static cJSON *raw_double(double v)
{
    char buf[48];
    for (int digits = 15; digits <= 17; digits++) {
        snprintf(buf, sizeof(buf), "%.*g", digits, v);
        if (strtod(buf, NULL) == v)
            break;
    }
    return cJSON_CreateRaw(buf);
}

static void add_float(writer *w, cJSON *obj, const char *key, float v)
{
    add(w, obj, key, raw_float(v));
}

static void add_double(writer *w, cJSON *obj, const char *key, double v)
{
    add(w, obj, key, raw_double(v));
}

static void add_uint(writer *w, cJSON *obj, const char *key, uint64_t v)
{
    char buf[32];
    snprintf(buf, sizeof(buf), "%llu", (unsigned long long)v);
    add(w, obj, key, cJSON_CreateRaw(buf));
}

static void add_floats(writer *w, cJSON *obj, const char *key, const float *v, int n)
{
    cJSON *arr = cJSON_CreateArray();
    for (int i = 0; i < n && arr; i++)
        add(w, arr, NULL, raw_float(v[i]));
    add(w, obj, key, arr);
}

static void add_string(writer *w, cJSON *obj, const char *key, const char *s)
{
    add(w, obj, key, cJSON_CreateString(s));
}

static void add_bool(writer *w, cJSON *obj, const char *key, bool b)
{
    add(w, obj, key, cJSON_CreateBool(b));
}

static bool in_unit(const float *v, int n)
{
    for (int i = 0; i < n; i++)
        if (!(v[i] >= 0.0f && v[i] <= 1.0f))
            return false;
    return true;
}

/* ------------------------------------------------------------------------------------------ */
/* Files: paths, the input check, generated files                                             */
/* ------------------------------------------------------------------------------------------ */

static bool same_existing_file(const char *a, const char *b)
{
    struct stat sa, sb;
    return stat(a, &sa) == 0 && stat(b, &sb) == 0 && sa.st_dev == sb.st_dev &&
           sa.st_ino == sb.st_ino;
}

/* Refuse to write `path` over a file the scene reads (its inputs and the sources it refers to):
 * the saved scene would refer to itself, or an input would be lost. */
static bool check_not_input(writer *w, const char *path)
{
    const nacre_scene *s = w->scene;
    const char *hit = NULL;
    for (uint32_t i = 0; i < s->input_count && !hit; i++)
        if (same_existing_file(path, s->inputs[i]))
            hit = s->inputs[i];
    for (uint32_t i = 0; i < s->mesh_count && !hit; i++)
        if (s->meshes[i].source_path && same_existing_file(path, s->meshes[i].source_path))
            hit = s->meshes[i].source_path;
    for (uint32_t i = 0; i < s->texture_count && !hit; i++)
        if (s->textures[i].source_path && same_existing_file(path, s->textures[i].source_path))
            hit = s->textures[i].source_path;
    for (uint32_t i = 0; i < s->volume_count && !hit; i++)
        if (s->volumes[i].source_path && same_existing_file(path, s->volumes[i].source_path))
            hit = s->volumes[i].source_path;
    if (hit)
        fail(w, NACRE_ERROR_INVALID_ARGUMENT,
             "refusing to write '%s': it is the same file as '%s', which the scene reads", path,
             hit);
    return !hit;
}

/* How the scene file refers to `absolute`: relative to its folder when the file lies in it or
 * below (the two move together), else absolute. Allocated. */
static char *reference_to(writer *w, const char *absolute)
{
    size_t n = strlen(w->dir);
    bool root = n == 1; /* "/" */
    const char *rel = absolute;
    if (strncmp(absolute, w->dir, n) == 0 && (root || absolute[n] == '/'))
        rel = absolute + (root ? 1 : n + 1);
    char *copy = nc_strdup(w->ctx, rel);
    if (!copy)
        fail(w, NACRE_ERROR_OUT_OF_MEMORY, "out of memory");
    return copy;
}

/* The path of a generated file, "<dir>/<stem>_<kind><id>.<ext>", checked against the inputs;
 * its reference (the name alone) goes to *ref. NULL after a failure. */
static char *generated_path(writer *w, const char *kind, uint32_t id, const char *ext, char **ref)
{
    char name[512];
    int n = snprintf(name, sizeof(name), "%s_%s%u.%s", w->stem, kind, id, ext);
    if (n < 0 || (size_t)n >= sizeof(name)) {
        fail(w, NACRE_ERROR_INVALID_ARGUMENT, "file name '%s' too long", w->stem);
        return NULL;
    }
    size_t len = strlen(w->dir) + 1 + (size_t)n + 1;
    char *path = nc_alloc(w->ctx, len);
    *ref = nc_strdup(w->ctx, name);
    if (path)
        snprintf(path, len, "%s%s%s", w->dir, strcmp(w->dir, "/") == 0 ? "" : "/", name);
    if (!path || !*ref || !check_not_input(w, path)) {
        if (!path || !*ref)
            fail(w, NACRE_ERROR_OUT_OF_MEMORY, "out of memory");
        nc_free(w->ctx, path);
        nc_free(w->ctx, *ref);
        *ref = NULL;
        return NULL;
    }
    return path;
}

/* After a generated file is written (r == NACRE_OK): keep its path, to remove the file if the
 * save fails later; takes `path` either way. */
static void generated_done(writer *w, char *path, nacre_result r)
{
    char **grown = r == NACRE_OK ? nc_realloc(w->ctx, w->written, w->written_count * sizeof(char *),
                                              (w->written_count + 1) * sizeof(char *))
                                 : NULL;
    if (grown) {
        w->written = grown;
        w->written[w->written_count++] = path;
        return;
    }
    if (r == NACRE_OK) { /* cannot keep track of it: remove it now and fail */
        unlink(path);
        r = NACRE_ERROR_OUT_OF_MEMORY;
    }
    nc_free(w->ctx, path);
    fail_inner(w, r);
}

/* A binary PLY through assimp's exporter: positions, normals and uvs as 32-bit floats (lossless),
 * triangles in order. Tangents are left out: nacre_mesh_load recomputes them from the same
 * positions, normals and uvs, as nacre_scene_add_mesh did. The aiScene is built here in C and
 * points at the mesh's own arrays where the layouts agree; the exporter copies it. */
static nacre_result write_ply(writer *w, const nacre_mesh_data *m, const char *path)
{
    nacre_result r = NACRE_OK;
    _Static_assert(sizeof(struct aiVector3D) == 3 * sizeof(float), "aiVector3D holds 3 floats");
    _Static_assert(sizeof(unsigned int) == sizeof(uint32_t), "assimp indices are 32-bit");
    struct aiVector3D *uvs = NULL;
    struct aiFace *faces = nc_calloc(w->ctx, m->triangle_count, sizeof(*faces));
    if (faces && m->uvs && (uvs = nc_calloc(w->ctx, m->vertex_count, sizeof(*uvs)))) {
        for (uint32_t v = 0; v < m->vertex_count; v++) {
            uvs[v].x = m->uvs[2 * (size_t)v];
            uvs[v].y = m->uvs[2 * (size_t)v + 1];
        }
    }
    if (!faces || (m->uvs && !uvs)) {
        r = nc_fail(w->ctx, NACRE_ERROR_OUT_OF_MEMORY, "%s: out of memory", path);
        goto out;
    }
    for (uint32_t t = 0; t < m->triangle_count; t++) {
        faces[t].mNumIndices = 3;
        faces[t].mIndices = m->indices + 3 * (size_t)t;
    }
    struct aiMesh mesh;
    struct aiNode root;
    struct aiMaterial material; /* the exporter wants one; empty is enough for PLY */
    struct aiScene scene;
    memset(&mesh, 0, sizeof(mesh));
    memset(&root, 0, sizeof(root));
    memset(&material, 0, sizeof(material));
    memset(&scene, 0, sizeof(scene));
    mesh.mPrimitiveTypes = aiPrimitiveType_TRIANGLE;
    mesh.mNumVertices = m->vertex_count;
    mesh.mNumFaces = m->triangle_count;
    mesh.mVertices = (struct aiVector3D *)(void *)m->positions;
    mesh.mNormals = (struct aiVector3D *)(void *)m->normals;
    mesh.mTextureCoords[0] = uvs;
    mesh.mNumUVComponents[0] = uvs ? 2 : 0;
    mesh.mFaces = faces;
    unsigned int mesh_index = 0;
    root.mTransformation.a1 = root.mTransformation.b2 = root.mTransformation.c3 =
        root.mTransformation.d4 = 1.0f;
    root.mNumMeshes = 1;
    root.mMeshes = &mesh_index;
    struct aiMesh *meshes[1] = {&mesh};
    struct aiMaterial *materials[1] = {&material};
    scene.mRootNode = &root;
    scene.mNumMeshes = 1;
    scene.mMeshes = meshes;
    scene.mNumMaterials = 1;
    scene.mMaterials = materials;
    const struct aiExportDataBlob *blob = aiExportSceneToBlob(&scene, "plyb", 0);
    if (!blob) {
        r = nc_fail(w->ctx, NACRE_ERROR_IO, "%s: assimp could not export the mesh as PLY", path);
        goto out;
    }
    nc_tmpfile tmp;
    r = nc_tmpfile_open(w->ctx, path, &tmp);
    if (r == NACRE_OK && (r = nc_tmpfile_write(w->ctx, &tmp, blob->data, blob->size)) != NACRE_OK)
        nc_tmpfile_abort(w->ctx, &tmp);
    else if (r == NACRE_OK)
        r = nc_tmpfile_commit(w->ctx, &tmp);
    aiReleaseExportBlob(blob);
out:
    nc_free(w->ctx, uvs);
    nc_free(w->ctx, faces);
    return r;
}

/* A source file still there to refer to (a vanished one is written out instead). */
static bool source_usable(const char *path)
{
    return path && access(path, R_OK) == 0;
}

static const char *mesh_reference(writer *w, nacre_mesh handle)
{
    const nc_mesh_rec *m = nc_scene_mesh(w->scene, handle);
    char **ref = &w->mesh_refs[handle.id - 1];
    if (!*ref && w->err == NACRE_OK) {
        if (source_usable(m->source_path)) {
            *ref = reference_to(w, m->source_path);
        } else {
            char *path = generated_path(w, "mesh", handle.id, "ply", ref);
            if (path)
                generated_done(w, path, write_ply(w, &m->data, path));
        }
    }
    return w->err == NACRE_OK ? *ref : NULL;
}

/* Textures without a file become float EXRs with 3 or 4 channels (the EXR reader gives 3 or 4:
 * a 1- or 2-channel depth map is padded with zero channels, so the channels layers read keep
 * their values; a 1- or 2-channel colour map, `kind` "texture", repeats its grey channel 0). */
static const char *texture_reference(writer *w, nacre_texture handle, const char *kind)
{
    const nc_texture_rec *t = nc_scene_texture(w->scene, handle);
    char **ref = &w->texture_refs[handle.id - 1];
    if (*ref || w->err != NACRE_OK)
        return w->err == NACRE_OK ? *ref : NULL;
    if (source_usable(t->source_path)) {
        *ref = reference_to(w, t->source_path);
        return *ref;
    }
    char *path = generated_path(w, kind, handle.id, "exr", ref);
    if (!path)
        return NULL;
    nacre_image img = {0};
    int32_t channels = t->channels < 3 ? 3 : t->channels;
    const bool colour = strcmp(kind, "texture") == 0;
    nacre_result r = nacre_image_alloc(w->ctx, t->width, t->height, channels, &img);
    if (r == NACRE_OK) {
        size_t pixels = (size_t)t->width * (size_t)t->height;
        for (size_t i = 0; i < pixels; i++)
            for (int32_t c = 0; c < channels; c++) {
                /* A grey colour map stays grey; a depth map's missing layers are 0 */
                int32_t from = c < t->channels ? c : colour ? 0 : -1;
                img.pixels[i * (size_t)channels + (size_t)c] =
                    from < 0 ? 0.0f : t->data[i * (size_t)t->channels + (size_t)from];
            }
        nacre_image_write_options opt = {.exr_type = NACRE_EXR_FLOAT};
        r = nacre_image_write(w->ctx, &img, path, &opt);
    }
    nacre_image_free(w->ctx, &img);
    generated_done(w, path, r);
    return w->err == NACRE_OK ? *ref : NULL;
}

/* Adds "volume" (and "channel" or "grid", "density_scale" for a source file) to a pattern object. */
static void add_volume_reference(writer *w, cJSON *obj, nacre_volume handle)
{
    const nc_volume_rec *v = nc_scene_volume(w->scene, handle);
    char **ref = &w->volume_refs[handle.id - 1];
    bool from_file = source_usable(v->source_path);
    if (!*ref && w->err == NACRE_OK) {
        if (from_file) {
            *ref = reference_to(w, v->source_path);
        } else {
            char *path = generated_path(w, "volume", handle.id, "nrrd", ref);
            if (path)
                generated_done(w, path,
                               nc_nrrd_write_f32(w->ctx, path, "written by nacre_scene_save_file",
                                                 v->dims, v->spacing, v->origin, v->data));
        }
    }
    if (w->err != NACRE_OK)
        return;
    add_string(w, obj, "volume", *ref);
    if (from_file && v->source_grid)
        add_string(w, obj, "grid", v->source_grid);
    else if (from_file && v->source_channel) /* 0 is the default, and .vdb files take none */
        add_uint(w, obj, "channel", v->source_channel);
    if (from_file)
        add_float(w, obj, "density_scale", v->source_scale);
}

/* ------------------------------------------------------------------------------------------ */
/* Sections                                                                                   */
/* ------------------------------------------------------------------------------------------ */

static cJSON *render_section(writer *w, const nacre_scene_file_settings *fs)
{
    const nacre_render_settings *s = &fs->render;
    /* The loader's ranges (json_render.c): a setting outside them would make an unloadable file. */
    const struct {
        bool ok;
        const char *key;
    } checks[] = {
        {(int)s->method >= 0 && s->method < NACRE_METHOD_COUNT, "method"},
        {s->width >= 1 && s->width <= IMAGE_SIZE_MAX, "width"},
        {s->height >= 1 && s->height <= IMAGE_SIZE_MAX, "height"},
        {isfinite(fs->exposure), "exposure"},
        {isfinite(fs->time), "time"},
        {s->shadow.map_size >= 0 && s->shadow.map_size <= IMAGE_SIZE_MAX, "shadow_map_size"},
        {s->shadow.pcf_radius >= 0 && s->shadow.pcf_radius <= FLT_MAX, "pcf_radius"},
        {s->shadow.bias >= 0 && s->shadow.bias <= FLT_MAX, "shadow_bias"},
        {s->pathtrace.spp >= 1 && s->pathtrace.spp <= (1u << 24), "spp"},
        {s->diffusion.voxel_resolution >= 1 && s->diffusion.voxel_resolution <= 1024,
         "voxel_resolution"},
        {s->diffusion.tsm_size >= 16 && s->diffusion.tsm_size <= 8192, "tsm_size"},
        {s->diffusion.solver == NACRE_SOLVER_MULTIGRID || s->diffusion.solver == NACRE_SOLVER_SEED,
         "solver"},
        {s->diffusion.source == NACRE_SOURCE_VOLUME || s->diffusion.source == NACRE_SOURCE_FACE,
         "source"},
        {s->diffusion.tolerance > 0 && s->diffusion.tolerance < 1, "tolerance"},
        {s->diffusion.seed_iterations <= 1000000, "seed_iterations"},
        {(unsigned)s->diffusion.single_scattering <= NACRE_SINGLE_SCATTERING_AUTO, "single_scattering"},
        {s->pathtrace.time_limit >= 0 && s->pathtrace.time_limit <= FLT_MAX, "time_limit"},
        {s->layered.samples >= 1 && s->layered.samples <= 4096, "layered_samples"},
        {s->layered.epsilon > 0 && s->layered.epsilon < 1, "layered_epsilon"},
        {s->layered.half_res >= 0 && s->layered.half_res < 1, "layered_half_res"},
        {s->layered.integration == NACRE_LAYERED_ANALYTIC || s->layered.integration == NACRE_LAYERED_SAMPLES,
         "layered_integration"},
        {(unsigned)s->particles <= NACRE_PARTICLES_DRAW_VOXEL, "particles"},
        {(unsigned)s->volumetrics.mode <= NACRE_VOLUMETRICS_RAYMARCH, "volumetrics"},
        {s->volumetrics.froxel_width >= 1 && s->volumetrics.froxel_width <= 1024, "froxel_width"},
        {s->volumetrics.froxel_height >= 1 && s->volumetrics.froxel_height <= 1024, "froxel_height"},
        {s->volumetrics.froxel_slices >= 1 && s->volumetrics.froxel_slices <= 1024, "froxel_slices"},
        {s->volumetrics.raymarch_steps >= 1 && s->volumetrics.raymarch_steps <= 4096, "raymarch_steps"},
        {s->volumetrics.shadow_steps >= 1 && s->volumetrics.shadow_steps <= 256, "shadow_steps"},
        {s->volumetrics.temporal >= 0.0f && s->volumetrics.temporal < 1.0f, "froxel_temporal"},
    };
    for (size_t i = 0; i < COUNT_OF(checks); i++)
        if (!checks[i].ok) {
            fail(w, NACRE_ERROR_INVALID_ARGUMENT,
                 "render.%s: outside the range scene files accept (docs/scene-format.md, "
                 "\"render\")",
                 checks[i].key);
            return NULL;
        }
    cJSON *o = cJSON_CreateObject();
    if (!o)
        return NULL;
    add_string(w, o, "method", nacre_method_name(s->method));
    add_uint(w, o, "width", (uint64_t)s->width);
    add_uint(w, o, "height", (uint64_t)s->height);
    add_float(w, o, "exposure", fs->exposure);
    add_double(w, o, "time", fs->time);
    add_uint(w, o, "shadow_map_size", (uint64_t)s->shadow.map_size);
    add_float(w, o, "pcf_radius", s->shadow.pcf_radius);
    add_float(w, o, "shadow_bias", s->shadow.bias);
    add_uint(w, o, "voxel_resolution", s->diffusion.voxel_resolution);
    add_uint(w, o, "tsm_size", (uint64_t)s->diffusion.tsm_size);
    add_string(w, o, "solver", nacre_solver_name(s->diffusion.solver));
    add_string(w, o, "source", nacre_source_name(s->diffusion.source));
    add_float(w, o, "tolerance", s->diffusion.tolerance);
    add_uint(w, o, "seed_iterations", s->diffusion.seed_iterations);
    add_string(w, o, "single_scattering", nacre_single_scattering_name(s->diffusion.single_scattering));
    add_uint(w, o, "spp", s->pathtrace.spp);
    add_uint(w, o, "seed", s->pathtrace.seed);
    add_double(w, o, "time_limit", s->pathtrace.time_limit);
    add_uint(w, o, "max_scatter", s->pathtrace.max_scatter);
    add_uint(w, o, "layered_samples", s->layered.samples);
    add_float(w, o, "layered_epsilon", s->layered.epsilon);
    add_float(w, o, "layered_half_res", s->layered.half_res);
    add_string(w, o, "layered_integration", nacre_layered_integration_name(s->layered.integration));
    add_string(w, o, "particles", nacre_particles_draw_name(s->particles));
    add_string(w, o, "volumetrics", nacre_volumetrics_name(s->volumetrics.mode));
    add_uint(w, o, "froxel_width", s->volumetrics.froxel_width);
    add_uint(w, o, "froxel_height", s->volumetrics.froxel_height);
    add_uint(w, o, "froxel_slices", s->volumetrics.froxel_slices);
    add_uint(w, o, "raymarch_steps", s->volumetrics.raymarch_steps);
    add_uint(w, o, "shadow_steps", s->volumetrics.shadow_steps);
    if (s->volumetrics.temporal != 0.0f)
        add_float(w, o, "froxel_temporal", s->volumetrics.temporal);
    return o;
}

static cJSON *camera_section(writer *w)
{
    const nacre_camera_desc *c = &w->scene->camera;
    float view[3] = {c->target[0] - c->position[0], c->target[1] - c->position[1],
                     c->target[2] - c->position[2]};
    if (!nc_json_nonzero3(view) || !nc_json_nonzero3(c->up) ||
        nc_json_sin_between(view, c->up) < 1e-6) {
        fail(w, NACRE_ERROR_INVALID_ARGUMENT,
             "camera: up is parallel to the view direction (or a vector is zero), which scene "
             "files refuse");
        return NULL;
    }
    cJSON *o = cJSON_CreateObject();
    if (!o)
        return NULL;
    add_string(w, o, "type", c->projection == NACRE_ORTHOGRAPHIC ? "orthographic" : "perspective");
    add_floats(w, o, "position", c->position, 3);
    add_floats(w, o, "target", c->target, 3);
    add_floats(w, o, "up", c->up, 3);
    /* The projection not in use may hold anything the C API let through; the file has a range. */
    if (c->fov_y > 0 && c->fov_y < 180)
        add_float(w, o, "fov", c->fov_y);
    if (c->ortho_height > 0 && c->ortho_height <= FLT_MAX)
        add_float(w, o, "height", c->ortho_height);
    add_float(w, o, "near", c->near_clip);
    add_float(w, o, "far", c->far_clip);
    return o;
}

static void add_pattern(writer *w, cJSON *parent, const char *key, const nacre_medium_pattern *p)
{
    static const char *const types[] = {"none", "random_mix", "checker", "noise", "volume"};
    if (p->type == NACRE_PATTERN_NONE || w->err != NACRE_OK)
        return;
    cJSON *o = cJSON_CreateObject();
    add(w, parent, key, o);
    if (w->err != NACRE_OK)
        return;
    add_string(w, o, "type", types[p->type]);
    if (p->type == NACRE_PATTERN_VOLUME) {
        add_volume_reference(w, o, p->volume);
        if (p->blackbody) {
            add_bool(w, o, "blackbody", true);
            add_float(w, o, "kelvin_scale", p->kelvin_scale);
        }
        return;
    }
    add_floats(w, o, "sigma_a2", p->sigma_a2, 3);
    add_floats(w, o, "sigma_s2", p->sigma_s2, 3);
    add_float(w, o, "cell_size", p->cell_size);
    if (p->type == NACRE_PATTERN_RANDOM_MIX)
        add_float(w, o, "fraction", p->fraction);
    if (p->type == NACRE_PATTERN_RANDOM_MIX || p->type == NACRE_PATTERN_NOISE)
        add_uint(w, o, "seed", p->seed);
    if (p->type == NACRE_PATTERN_NOISE)
        add_uint(w, o, "octaves", p->octaves);
}

static void add_layering(writer *w, cJSON *o, const nacre_layering *l)
{
    if (l->multiple_scattering != NACRE_MULTIPLE_SCATTERING_NONE)
        add_string(w, o, "multiple_scattering", nacre_multiple_scattering_name(l->multiple_scattering));
    if (l->count == 0)
        return;
    cJSON *arr = cJSON_CreateArray();
    add(w, o, "layers", arr);
    for (uint32_t j = 0; j < l->count && w->err == NACRE_OK; j++) {
        cJSON *y = cJSON_CreateObject();
        add(w, arr, NULL, y);
        if (w->err != NACRE_OK)
            return;
        add_floats(w, y, "sigma_a", l->layers[j].sigma_a, 3);
        add_floats(w, y, "sigma_s", l->layers[j].sigma_s, 3);
        add_float(w, y, "g", l->layers[j].g);
        add_float(w, y, "depth", l->layers[j].depth);
    }
    if (l->depth_map.id != 0) {
        const char *ref = texture_reference(w, l->depth_map, "depth");
        if (ref)
            add_string(w, o, "depth_map", ref);
    }
}

/* Translucent materials write everything they use; "diffuse" is the opaque type's only (the
 * loader keeps a translucent material's at its default). */
static cJSON *material_object(writer *w, uint32_t i, const nacre_material_desc *d)
{
    bool opaque = d->type == NACRE_MATERIAL_OPAQUE;
    if ((opaque && !in_unit(d->diffuse, 3)) || !in_unit(d->specular, 3)) {
        fail(w, NACRE_ERROR_INVALID_ARGUMENT,
             "materials[\"%s\"].%s: above 1, which scene files refuse", w->names[i],
             opaque && !in_unit(d->diffuse, 3) ? "diffuse" : "specular");
        return NULL;
    }
    cJSON *o = cJSON_CreateObject();
    if (!o)
        return NULL;
    add_string(w, o, "type", opaque ? "opaque" : "translucent");
    if (opaque)
        add_floats(w, o, "diffuse", d->diffuse, 3);
    add_floats(w, o, "specular", d->specular, 3);
    add_float(w, o, "shininess", d->shininess);
    if (opaque && d->diffuse_map.id != 0) {
        const char *ref = texture_reference(w, d->diffuse_map, "texture");
        if (ref)
            add_string(w, o, "diffuse_map", ref);
    }
    if (opaque)
        return o;
    add_floats(w, o, "sigma_a", d->sigma_a, 3);
    add_floats(w, o, "sigma_s", d->sigma_s, 3);
    add_float(w, o, "g", d->g);
    add_float(w, o, "eta", d->eta);
    add_pattern(w, o, "pattern", &d->pattern);
    add_layering(w, o, &d->layering);
    return o;
}

static cJSON *light_object(writer *w, const nc_light_rec *rec)
{
    static const char *const types[] = {"directional", "point", "spot"};
    /* The direction as given reproduces the stored (normalised) one exactly; one the loader would
     * call zero falls back to the normalised one. */
    const nacre_light_desc *d = &rec->given;
    const float *direction = nc_json_nonzero3(d->direction) ? d->direction : rec->desc.direction;
    cJSON *o = cJSON_CreateObject();
    if (!o)
        return NULL;
    add_string(w, o, "type", types[d->type]);
    if (d->type != NACRE_LIGHT_POINT)
        add_floats(w, o, "direction", direction, 3);
    if (d->type != NACRE_LIGHT_DIRECTIONAL)
        add_floats(w, o, "position", d->position, 3);
    add_floats(w, o, d->type == NACRE_LIGHT_DIRECTIONAL ? "irradiance" : "intensity", d->strength,
               3);
    if (d->type == NACRE_LIGHT_DIRECTIONAL)
        add_float(w, o, "angular_radius", d->angular_radius);
    if (d->type == NACRE_LIGHT_SPOT) {
        add_float(w, o, "inner_angle", d->inner_angle);
        add_float(w, o, "outer_angle", d->outer_angle);
        static const char *const falloffs[] = {"smooth", "cycles", "gltf"};
        add_string(w, o, "falloff", falloffs[d->falloff]);
    }
    if (d->type != NACRE_LIGHT_DIRECTIONAL)
        add_float(w, o, "radius", d->radius);
    add_bool(w, o, "shadows", d->cast_shadows);
    return o;
}

static cJSON *shape_object(writer *w, const nacre_shape_desc *d)
{
    static const char *const types[] = {"sphere", "box", "plane", "torus"};
    cJSON *o = cJSON_CreateObject();
    if (!o)
        return NULL;
    add_string(w, o, "type", types[d->type]);
    if (d->type == NACRE_SHAPE_SPHERE || d->type == NACRE_SHAPE_TORUS)
        add_float(w, o, "radius", d->radius);
    if (d->type == NACRE_SHAPE_TORUS)
        add_float(w, o, "minor_radius", d->minor_radius);
    if (d->type == NACRE_SHAPE_BOX)
        add_floats(w, o, "size", d->size, 3);
    if (d->type == NACRE_SHAPE_PLANE)
        add_floats(w, o, "size", (const float[2]){d->size[0], d->size[2]}, 2);
    add_uint(w, o, "segments", d->segments);
    if (d->type == NACRE_SHAPE_SPHERE || d->type == NACRE_SHAPE_TORUS)
        add_uint(w, o, "rings", d->rings);
    return o;
}

/* NONE deformers do nothing and have no name in the format: they are left out. */
static void add_deformers(writer *w, cJSON *o, uint32_t index, const nacre_object_desc *d)
{
    static const char *const types[] = {"none", "scale", "twist", "bend"};
    cJSON *arr = NULL;
    for (uint32_t i = 0; i < d->deformer_count && w->err == NACRE_OK; i++) {
        const nacre_deformer *f = &d->deformers[i];
        if (f->type == NACRE_DEFORM_NONE)
            continue;
        bool bad_scale = f->type == NACRE_DEFORM_SCALE &&
                         !(f->scale[0] > 0 && f->scale[1] > 0 && f->scale[2] > 0);
        bool bad_axis = f->type != NACRE_DEFORM_SCALE && !nc_json_nonzero3(f->axis);
        bool bad_bend =
            f->type == NACRE_DEFORM_BEND && !bad_axis &&
            (!nc_json_nonzero3(f->direction) || nc_json_sin_between(f->axis, f->direction) < 1e-3);
        if (bad_scale || bad_axis || bad_bend) {
            fail(w, NACRE_ERROR_INVALID_ARGUMENT,
                 "objects[%u].deformers[%u].%s: %s, which scene files refuse", index, i,
                 bad_scale  ? "scale"
                 : bad_axis ? "axis"
                            : "direction",
                 bad_scale  ? "not positive"
                 : bad_axis ? "nearly zero"
                            : "nearly parallel to the axis");
            return;
        }
        if (!arr) {
            arr = cJSON_CreateArray();
            add(w, o, "deformers", arr);
            if (w->err != NACRE_OK)
                return;
        }
        cJSON *e = cJSON_CreateObject();
        add(w, arr, NULL, e);
        if (w->err != NACRE_OK)
            return;
        add_string(w, e, "type", types[f->type]);
        add_floats(w, e, "center", f->center, 3);
        if (f->type == NACRE_DEFORM_SCALE) {
            add_floats(w, e, "scale", f->scale, 3);
            add_floats(w, e, "scale_rate", f->scale_rate, 3);
            continue;
        }
        add_floats(w, e, "axis", f->axis, 3);
        if (f->type == NACRE_DEFORM_BEND)
            add_floats(w, e, "direction", f->direction, 3);
        add_float(w, e, "angle", f->angle);
        add_float(w, e, "angle_rate", f->angle_rate);
        add_float(w, e, "length", f->length);
    }
}

static cJSON *object_object(writer *w, uint32_t index, const nc_object_rec *rec)
{
    const nacre_object_desc *d = &rec->desc;
    const nacre_transform *t = &d->transform;
    if (!(t->scale[0] > 0 && t->scale[1] > 0 && t->scale[2] > 0)) {
        fail(w, NACRE_ERROR_INVALID_ARGUMENT,
             "objects[%u].transform.scale: a negative (mirroring) scale, which scene files refuse",
             index);
        return NULL;
    }
    cJSON *o = cJSON_CreateObject();
    if (!o)
        return NULL;
    if (d->name && d->name[0])
        add_string(w, o, "name", d->name);
    const nc_mesh_rec *m = nc_scene_mesh(w->scene, d->mesh);
    if (m->from_shape) {
        add(w, o, "shape", shape_object(w, &m->shape));
    } else {
        const char *ref = mesh_reference(w, d->mesh);
        if (ref)
            add_string(w, o, "mesh", ref);
    }
    add_string(w, o, "material", w->names[d->material.id - 1]);
    cJSON *tr = cJSON_CreateObject();
    add(w, o, "transform", tr);
    if (w->err == NACRE_OK) {
        add_floats(w, tr, "translate", t->translate, 3);
        add_floats(w, tr, "rotate", t->rotate, 3);
        add_floats(w, tr, "scale", t->scale, 3);
    }
    add_deformers(w, o, index, d);
    add_bool(w, o, "shadows", d->cast_shadows);
    add_bool(w, o, "double_sided", d->double_sided);
    return o;
}

static cJSON *fog_object(writer *w, const nacre_fog_desc *d)
{
    cJSON *o = cJSON_CreateObject();
    if (!o)
        return NULL;
    add_string(w, o, "shape", d->shape == NACRE_FOG_BOX ? "box" : d->shape == NACRE_FOG_SPHERE ? "sphere" : "global");
    add_floats(w, o, "center", d->center, 3);
    if (d->shape != NACRE_FOG_GLOBAL)
        add_floats(w, o, "size", d->size, 3);
    add_floats(w, o, "rotate", d->rotate, 3);
    add_floats(w, o, "sigma_a", d->sigma_a, 3);
    add_floats(w, o, "sigma_s", d->sigma_s, 3);
    add_float(w, o, "g", d->g);
    add_float(w, o, "height_falloff", d->height_falloff);
    add_float(w, o, "height_base", d->height_base);
    if (d->emission[0] != 0.0f || d->emission[1] != 0.0f || d->emission[2] != 0.0f)
        add_floats(w, o, "emission", d->emission, 3);
    add_pattern(w, o, "pattern", &d->pattern);
    add_pattern(w, o, "emission_pattern", &d->emission_pattern);
    return o;
}

/* One particle system (json_particles.c reads it back). */
static cJSON *particles_object(writer *w, const nacre_particles_desc *d)
{
    static const char *const shapes[] = {"point", "box", "sphere"};
    cJSON *o = cJSON_CreateObject();
    if (!o)
        return NULL;
    bool list = d->type == NACRE_PARTICLES_LIST;
    add_string(w, o, "type", list ? "list" : "emitter");
    if (!list) {
        add_string(w, o, "shape", shapes[d->shape]);
        add_floats(w, o, "center", d->center, 3);
        add_floats(w, o, "size", d->size, 3);
        add_float(w, o, "emit_radius", d->emit_radius);
        add_float(w, o, "rate", d->rate);
        add_float(w, o, "lifetime", d->lifetime);
        add_floats(w, o, "velocity", d->velocity, 3);
        add_float(w, o, "spread", d->spread);
        add_float(w, o, "speed_jitter", d->speed_jitter);
        add_floats(w, o, "gravity", d->gravity, 3);
        add_float(w, o, "drag", d->drag);
        add_float(w, o, "radius_jitter", d->radius_jitter);
        add_float(w, o, "radius_rate", d->radius_rate);
        add_float(w, o, "fade", d->fade);
        add_uint(w, o, "seed", d->seed);
    }
    add_float(w, o, "radius", d->radius);
    add_float(w, o, "density", d->density);
    if (list) {
        cJSON *pos = cJSON_CreateArray();
        for (uint32_t i = 0; i < d->count && pos && w->err == NACRE_OK; i++) {
            cJSON *p = cJSON_CreateArray();
            for (int c = 0; c < 3 && p; c++)
                add(w, p, NULL, raw_float(d->positions[3 * (size_t)i + c]));
            add(w, pos, NULL, p);
        }
        add(w, o, "positions", pos);
        const float *arrays[2] = {d->radii, d->densities};
        const char *names[2] = {"radii", "densities"};
        for (int k = 0; k < 2; k++) {
            if (!arrays[k])
                continue;
            cJSON *a = cJSON_CreateArray();
            for (uint32_t i = 0; i < d->count && a && w->err == NACRE_OK; i++)
                add(w, a, NULL, raw_float(arrays[k][i]));
            add(w, o, names[k], a);
        }
    }
    add_floats(w, o, "sigma_a", d->sigma_a, 3);
    add_floats(w, o, "sigma_s", d->sigma_s, 3);
    add_float(w, o, "g", d->g);
    add_uint(w, o, "grid_resolution", d->grid_resolution);
    if (d->isosurface.density > 0.0f) {
        cJSON *iso = cJSON_CreateObject();
        add_float(w, iso, "density", d->isosurface.density);
        add_float(w, iso, "ior", d->isosurface.ior);
        add_float(w, iso, "roughness", d->isosurface.roughness);
        add(w, o, "isosurface", iso);
    }
    return o;
}

/* The whole file, in the loader's order of dependencies. */
static cJSON *scene_object(writer *w, const nacre_scene_file_settings *fs)
{
    const nacre_scene *s = w->scene;
    cJSON *root = cJSON_CreateObject();
    if (!root) {
        fail(w, NACRE_ERROR_OUT_OF_MEMORY, "out of memory building the JSON");
        return NULL;
    }
    add(w, root, "_comment", cJSON_CreateString("written by nacre_scene_save_file"));
    add(w, root, "units", raw_float(s->unit_mm));
    add(w, root, "render", render_section(w, fs));
    add(w, root, "camera", camera_section(w));
    add_floats(w, root, "environment", s->environment, 3);
    cJSON *materials = cJSON_CreateObject();
    add(w, root, "materials", materials);
    for (uint32_t i = 0; i < s->material_count && w->err == NACRE_OK; i++)
        add(w, materials, w->names[i], material_object(w, i, &s->materials[i]));
    cJSON *lights = cJSON_CreateArray();
    add(w, root, "lights", lights);
    for (uint32_t i = 0; i < s->light_count && w->err == NACRE_OK; i++)
        add(w, lights, NULL, light_object(w, &s->lights[i]));
    cJSON *objects = cJSON_CreateArray();
    add(w, root, "objects", objects);
    for (uint32_t i = 0; i < s->object_count && w->err == NACRE_OK; i++)
        add(w, objects, NULL, object_object(w, i, &s->objects[i]));
    cJSON *fogs = cJSON_CreateArray();
    add(w, root, "fog", fogs);
    for (uint32_t i = 0; i < nc_scene_user_fogs(s) && w->err == NACRE_OK; i++)
        add(w, fogs, NULL, fog_object(w, &s->fogs[i].desc));
    if (nacre_scene_particles_count(s) > 0) {
        cJSON *systems = cJSON_CreateArray();
        add(w, root, "particles", systems);
        for (uint32_t i = 0; i < nacre_scene_particles_count(s) && w->err == NACRE_OK; i++) {
            nacre_particles_desc d;
            if (nacre_scene_get_particles(s, (nacre_particles){i + 1}, &d) == NACRE_OK)
                add(w, systems, NULL, particles_object(w, &d));
        }
    }
    if (w->err != NACRE_OK) {
        cJSON_Delete(root);
        return NULL;
    }
    return root;
}

/* ------------------------------------------------------------------------------------------ */
/* Names, set-up and entry points                                                             */
/* ------------------------------------------------------------------------------------------ */

static bool name_taken(char *const *names, uint32_t count, const char *name)
{
    for (uint32_t i = 0; i < count; i++)
        if (names[i] && strcmp(names[i], name) == 0)
            return true;
    return false;
}

/* Each material's name from its scene file; "material<id>" for those made by the C API (with
 * "_2", "_3", ... if a file already used that name). */
static void name_materials(writer *w)
{
    const nacre_scene *s = w->scene;
    for (uint32_t i = 0; i < s->material_count && w->err == NACRE_OK; i++) {
        const char *name = nc_scene_material_name(s, (nacre_material){i + 1});
        if (name && !(w->names[i] = nc_strdup(w->ctx, name)))
            fail(w, NACRE_ERROR_OUT_OF_MEMORY, "out of memory");
    }
    for (uint32_t i = 0; i < s->material_count && w->err == NACRE_OK; i++) {
        if (w->names[i])
            continue;
        char name[64];
        snprintf(name, sizeof(name), "material%u", i + 1);
        for (uint32_t k = 2; name_taken(w->names, s->material_count, name); k++)
            snprintf(name, sizeof(name), "material%u_%u", i + 1, k);
        if (!(w->names[i] = nc_strdup(w->ctx, name)))
            fail(w, NACRE_ERROR_OUT_OF_MEMORY, "out of memory");
    }
}

static void free_refs(nacre_context *ctx, char **refs, uint32_t count)
{
    for (uint32_t i = 0; refs && i < count; i++)
        nc_free(ctx, refs[i]);
    nc_free(ctx, refs);
}

static void writer_free(writer *w)
{
    const nacre_scene *s = w->scene;
    free_refs(w->ctx, w->names, s->material_count);
    free_refs(w->ctx, w->mesh_refs, s->mesh_count);
    free_refs(w->ctx, w->texture_refs, s->texture_count);
    free_refs(w->ctx, w->volume_refs, s->volume_count);
    for (uint32_t i = 0; i < w->written_count; i++) {
        if (w->err != NACRE_OK)
            unlink(w->written[i]);
        nc_free(w->ctx, w->written[i]);
    }
    nc_free(w->ctx, w->written);
    nc_free(w->ctx, w->dir);
}

/* Builds the text of the scene file; generated files go to `dir`. Returns cJSON's string (malloc)
 * or NULL after a failure recorded in w->err. */
static char *build_text(writer *w, const char *dir, const nacre_scene_file_settings *settings)
{
    nacre_scene_file_settings defaults = {.render = nacre_render_settings_defaults()};
    const nacre_scene *s = w->scene;
    char *real = realpath(dir, NULL);
    if (!real) {
        fail(w, NACRE_ERROR_IO, "cannot create file: folder '%s': %s", dir, strerror(errno));
        return NULL;
    }
    w->dir = nc_strdup(w->ctx, real);
    free(real);
    w->names = nc_calloc(w->ctx, s->material_count + 1, sizeof(char *));
    w->mesh_refs = nc_calloc(w->ctx, s->mesh_count + 1, sizeof(char *));
    w->texture_refs = nc_calloc(w->ctx, s->texture_count + 1, sizeof(char *));
    w->volume_refs = nc_calloc(w->ctx, s->volume_count + 1, sizeof(char *));
    if (!w->dir || !w->names || !w->mesh_refs || !w->texture_refs || !w->volume_refs) {
        fail(w, NACRE_ERROR_OUT_OF_MEMORY, "out of memory");
        return NULL;
    }
    name_materials(w);
    cJSON *root = w->err == NACRE_OK ? scene_object(w, settings ? settings : &defaults) : NULL;
    if (!root)
        return NULL;
    char *text = cJSON_Print(root);
    cJSON_Delete(root);
    if (!text)
        fail(w, NACRE_ERROR_OUT_OF_MEMORY, "out of memory printing the JSON");
    return text;
}

static nacre_result check_args(const nacre_scene *scene, const char *what, bool ok)
{
    if (!scene)
        return NACRE_ERROR_INVALID_ARGUMENT;
    return ok ? NACRE_OK
              : nc_fail(scene->ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: an argument is NULL", what);
}

nacre_result nacre_scene_save_file(const nacre_scene *scene,
                                   const nacre_scene_file_settings *settings, const char *path)
{
    nacre_result r = check_args(scene, "nacre_scene_save_file", path && path[0]);
    if (r != NACRE_OK)
        return r;
    writer w = {.ctx = scene->ctx, .scene = scene, .label = path};
    /* Generated files are named after the scene file: "a/b.json" -> "a/b_mesh1.ply". */
    const char *slash = strrchr(path, '/');
    const char *base = slash ? slash + 1 : path;
    size_t dir_len = slash ? (slash == path ? 1 : (size_t)(slash - path)) : 0;
    size_t base_len = strlen(base);
    if (base_len > 5 && strcmp(base + base_len - 5, ".json") == 0)
        base_len -= 5;
    char *dir = nc_alloc(w.ctx, dir_len + 2), *stem = nc_alloc(w.ctx, base_len + 1);
    if (!dir || !stem) {
        nc_free(w.ctx, dir);
        nc_free(w.ctx, stem);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    memcpy(dir, slash ? path : ".", slash ? dir_len : 1);
    dir[slash ? dir_len : 1] = '\0';
    memcpy(stem, base, base_len);
    stem[base_len] = '\0';
    w.stem = stem[0] ? stem : "scene";
    char *text = NULL;
    if (check_not_input(&w, path))
        text = build_text(&w, dir, settings);
    if (text) {
        nc_tmpfile tmp;
        r = nc_tmpfile_open(w.ctx, path, &tmp);
        if (r == NACRE_OK && (r = nc_tmpfile_write(w.ctx, &tmp, text, strlen(text))) == NACRE_OK)
            r = nc_tmpfile_write(w.ctx, &tmp, "\n", 1);
        if (r == NACRE_OK)
            r = nc_tmpfile_commit(w.ctx, &tmp);
        else if (tmp.tmp_path)
            nc_tmpfile_abort(w.ctx, &tmp);
        if (r != NACRE_OK)
            fail_inner(&w, r);
    }
    cJSON_free(text);
    r = w.err;
    writer_free(&w);
    nc_free(w.ctx, dir);
    nc_free(w.ctx, stem);
    return r;
}

nacre_result nacre_scene_save_json(const nacre_scene *scene,
                                   const nacre_scene_file_settings *settings, const char *base_dir,
                                   char **json_out, size_t *length_out)
{
    nacre_result r = check_args(scene, "nacre_scene_save_json", json_out != NULL);
    if (r != NACRE_OK)
        return r;
    *json_out = NULL;
    if (length_out)
        *length_out = 0;
    writer w = {.ctx = scene->ctx, .scene = scene, .label = "<json>", .stem = "scene"};
    char *text = build_text(&w, base_dir && base_dir[0] ? base_dir : ".", settings);
    if (text) {
        size_t n = strlen(text);
        char *copy = nc_alloc(w.ctx, n + 2);
        if (copy) {
            memcpy(copy, text, n);
            memcpy(copy + n, "\n", 2);
            *json_out = copy;
            if (length_out)
                *length_out = n + 1;
        } else {
            fail(&w, NACRE_ERROR_OUT_OF_MEMORY, "out of memory");
        }
    }
    cJSON_free(text);
    r = w.err;
    writer_free(&w);
    return r;
}
