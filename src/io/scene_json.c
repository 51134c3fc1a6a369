/*
 * scene_json.c: loads JSON scene files (format in docs/scene-format.md) by calling the public
 * scene-building functions, so a file can express nothing the C API cannot. This file holds the
 * entry points, the reading of the text (size, malformed JSON, nesting, \u0000) and the
 * "Top level" object, whose sections it parses in dependency order; each section lives in its
 * own file (json_render.c, json_camera_lights.c, json_materials.c, json_objects.c, json_fog.c,
 * json_particles.c)
 * over the shared readers of json_read.c, declared in scene_json_internal.h.
 *
 * Conventions: the parse is strict. Every object's keys are checked against the keys that
 * object accepts (keys starting with '_' are comments and skipped), duplicate keys are errors,
 * and every number is checked for type, finiteness and range before it reaches the scene. The
 * first problem wins and is reported once as "name: field.path[i]: problem", or
 * "name:line:col: malformed JSON" when cJSON rejects the text. Failures from lower layers (mesh
 * loader, scene validation) keep their code and message, prefixed with the field path.
 *
 * The loader keeps a sticky error (struct loader.err): readers do nothing once it is set, so
 * section parsers read every field in a row and check once at the end. The cJSON tree is
 * allocated by cJSON with malloc: its allocation hooks are process-global, and setting them
 * would be global mutable state. The tree never outlives a call; everything else goes
 * through the context's allocator.
 */
#include "io/scene_json_internal.h"
#include "io/gltf.h"
#include "io/tmpfile.h"

#include <errno.h>
#include <stdio.h>
#include <string.h>

#define SCENE_FILE_MAX (64u << 20)  /* a scene file is text; anything bigger is a mistake */

/* Sections in dependency order, whatever their order in the file: units scale the presets,
 * materials must exist before objects name them. */
static void parse_scene(loader *ld, const cJSON *root)
{
    static const char *const keys[] = {"units", "render", "camera", "environment", "materials",
                                       "lights", "objects", "fog", "import", "particles"};
    if (!cJSON_IsObject(root)) {
        nc_json_fail(ld, NACRE_ERROR_PARSE, "the top level must be an object, got %s",
                     nc_json_type_name(root));
        return;
    }
    nc_json_check_duplicates(ld, root);
    if (!nc_json_check_keys(ld, root, keys, COUNT_OF(keys)))
        return;
    const cJSON *item;
    if ((item = nc_json_member(root, "units")))
        nc_json_parse_units(ld, item);
    if (nc_json_member(root, "import") && !ld->err)
        nc_json_parse_import(ld, root, nc_json_member(root, "units") != NULL);
    if ((item = nc_json_member(root, "render")))
        nc_json_parse_render(ld, item);
    if ((item = nc_json_member(root, "environment")) && !ld->err)
        nc_json_parse_environment(ld, item);
    if ((item = nc_json_member(root, "camera")) && !ld->err)
        nc_json_parse_camera(ld, item);
    if ((item = nc_json_member(root, "materials")) && !ld->err)
        nc_json_parse_materials(ld, item);
    if ((item = nc_json_member(root, "lights")) && !ld->err)
        nc_json_parse_array(ld, item, "lights", nc_json_parse_light);
    if ((item = nc_json_member(root, "objects")) && !ld->err)
        nc_json_parse_array(ld, item, "objects", nc_json_parse_object);
    if ((item = nc_json_member(root, "fog")) && !ld->err)
        nc_json_parse_array(ld, item, "fog", nc_json_parse_fog);
    if ((item = nc_json_member(root, "particles")) && !ld->err)
        nc_json_parse_array(ld, item, "particles", nc_json_parse_particles);
}

/* ------------------------------------------------------------------------------------------ */
/* Entry points                                                                               */
/* ------------------------------------------------------------------------------------------ */

/* 1-based line and byte column of `offset`. */
static void line_column(const char *text, size_t offset, int *line, int *column)
{
    int l = 1;
    size_t start = 0;
    for (size_t i = 0; i < offset; i++)
        if (text[i] == '\n') {
            l++;
            start = i + 1;
        }
    *line = l;
    *column = (int)(offset - start) + 1;
}

/* cJSON decodes \u0000 into a NUL byte, which ends its C string early: "a.obj\u0000x" would
 * load a.obj. Each such escape inside a string becomes \u0001 (byte 1 once decoded, which no
 * file has reason to hold), so nc_json_get_string can refuse the string and name its field.
 * Returns the number of escapes changed. */
static size_t mark_nul_escapes(char *text, size_t length)
{
    size_t count = 0;
    bool in_string = false;
    for (size_t i = 0; i < length; i++) {
        if (!in_string) {
            in_string = text[i] == '"';
        } else if (text[i] == '"') {
            in_string = false;
        } else if (text[i] == '\\' && i + 1 < length) {
            if (i + 5 < length && text[i + 1] == 'u' && memcmp(text + i + 2, "0000", 4) == 0) {
                text[i + 5] = '1';
                count++;
            }
            i++; /* the escaped character; the hex digits that may follow are plain text */
        }
    }
    return count;
}

/* Deepest nesting of arrays and objects in text[0, end] (strings skipped): tells a file cJSON
 * refused for its nesting limit from a malformed one. */
static int nesting_depth(const char *text, size_t end)
{
    int depth = 0, deepest = 0;
    bool in_string = false;
    for (size_t i = 0; i <= end && text[i]; i++) {
        char c = text[i];
        if (in_string) {
            if (c == '\\' && text[i + 1])
                i++;
            else if (c == '"')
                in_string = false;
        } else if (c == '"') {
            in_string = true;
        } else if (c == '[' || c == '{') {
            if (++depth > deepest)
                deepest = depth;
        } else if (c == ']' || c == '}') {
            depth--;
        }
    }
    return deepest;
}

static nacre_result load_text(nacre_context *ctx, const char *json, size_t length,
                              const char *name, const char *base_dir, nacre_scene **out,
                              nacre_scene_file_settings *settings)
{
    /* cJSON stops at a NUL byte, which would hide whatever follows: refuse it. */
    const char *nul = memchr(json, '\0', length);
    if (nul) {
        int line, column;
        line_column(json, (size_t)(nul - json), &line, &column);
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s:%d:%d: malformed JSON (NUL byte)", name, line,
                       column);
    }
    /* A copy with the terminator require_null_terminated looks for inside the length. */
    char *text = nc_alloc(ctx, length + 1);
    if (!text)
        return NACRE_ERROR_OUT_OF_MEMORY;
    memcpy(text, json, length);
    text[length] = '\0';
    size_t nul_escapes = mark_nul_escapes(text, length);
    const char *end = NULL;
    cJSON *root = cJSON_ParseWithLengthOpts(text, length + 1, &end, 1);
    if (!root) {
        size_t offset = end && end >= text && end <= text + length ? (size_t)(end - text) : 0;
        if (nesting_depth(text, offset) > CJSON_NESTING_LIMIT) {
            int line, column;
            line_column(text, offset, &line, &column);
            nacre_result r = nc_fail(ctx, NACRE_ERROR_PARSE,
                                     "%s:%d:%d: arrays and objects nested deeper than %d levels", name, line,
                                     column, CJSON_NESTING_LIMIT);
            nc_free(ctx, text);
            return r;
        }
        /* cJSON reports an unterminated string just after its opening quote: point at the
         * quote. */
        bool unterminated = offset > 0 && offset < length && text[offset - 1] == '"' &&
                            !strchr(text + offset, '"');
        int line, column;
        line_column(text, unterminated ? offset - 1 : offset, &line, &column);
        nacre_result r = nc_fail(ctx, NACRE_ERROR_PARSE, "%s:%d:%d: malformed JSON%s", name, line,
                                 column,
                                 offset >= length ? " (unexpected end of input)"
                                 : unterminated   ? " (unterminated string)"
                                                  : "");
        nc_free(ctx, text);
        return r;
    }

    loader ld = {0};
    ld.ctx = ctx;
    ld.nul_escapes = nul_escapes;
    ld.name = name;
    ld.base_dir = base_dir;
    ld.unit_mm = 1.0f;
    ld.settings = (nacre_scene_file_settings){.render = nacre_render_settings_defaults()};
    nacre_result r = nacre_scene_create(ctx, &ld.scene);
    if (r != NACRE_OK)
        nc_json_fail_inner(&ld, r);
    else
        parse_scene(&ld, root);

    for (uint32_t i = 0; i < ld.mesh_count; i++)
        nc_free(ctx, ld.meshes[i].path);
    nc_free(ctx, ld.meshes);
    nc_free(ctx, ld.materials);
    for (uint32_t i = 0; i < ld.imported_count; i++)
        nc_free(ctx, (char *)ld.imported[i].name);
    nc_free(ctx, ld.imported);
    cJSON_Delete(root);
    nc_free(ctx, text);
    if (ld.err != NACRE_OK) {
        nacre_scene_destroy(ld.scene);
        return ld.err;
    }
    *out = ld.scene;
    if (settings)
        *settings = ld.settings;
    return NACRE_OK;
}

nacre_result nacre_scene_load_json(nacre_context *ctx, const char *json, size_t length,
                                   const char *name, const char *base_dir, nacre_scene **out,
                                   nacre_scene_file_settings *settings)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (out)
        *out = NULL;
    if (!out || (!json && length > 0))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "nacre_scene_load_json: %s is NULL",
                       out ? "json" : "out");
    return load_text(ctx, json ? json : "", length, name ? name : "<json>", base_dir, out,
                     settings);
}

nacre_result nacre_scene_load_file(nacre_context *ctx, const char *path, nacre_scene **out,
                                   nacre_scene_file_settings *settings)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (out)
        *out = NULL;
    if (!out || !path)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "nacre_scene_load_file: %s is NULL",
                       out ? "path" : "out");
    if (nc_gltf_is_path(path))
        return nacre_scene_load_gltf(ctx, path, NULL, out, settings, NULL);
    char *text = NULL;
    size_t size = 0;
    nacre_result r = nc_read_file(ctx, path, SCENE_FILE_MAX, "not a scene file", &text, &size);
    if (r != NACRE_OK)
        return r;
    /* Mesh paths are relative to the scene file's folder. */
    char *base = NULL;
    const char *slash = strrchr(path, '/');
    if (slash) {
        size_t n = slash == path ? 1 : (size_t)(slash - path);
        base = nc_alloc(ctx, n + 1);
        if (!base) {
            nc_free(ctx, text);
            return NACRE_ERROR_OUT_OF_MEMORY;
        }
        memcpy(base, path, n);
        base[n] = '\0';
    }
    r = load_text(ctx, text ? text : "", size, path, base, out, settings);
    nc_free(ctx, base);
    nc_free(ctx, text);
    return r;
}
