/*
 * scene_json_internal.h: what the JSON scene loader's files share (scene_json.c and the section
 * files json_*.c): the loader state with its sticky error and field path, the value ranges the
 * readers check, the generic readers of json_read.c and each section's parser. Private to the
 * library; the format is docs/scene-format.md.
 */
#ifndef NACRE_SCENE_JSON_INTERNAL_H
#define NACRE_SCENE_JSON_INTERNAL_H

#include "core/core.h"
#include "scene/scene.h"

#include <cjson/cJSON.h>

#include <math.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#define PATH_MAX_CHARS 256
#define NAME_SHOWN_MAX 64 /* longer keys and names are cut in messages */

#define COUNT_OF(a) (sizeof(a) / sizeof((a)[0]))

typedef struct range {
    double lo, hi;
    bool lo_open, hi_open;
} range;

static const range R_FINITE = {-INFINITY, INFINITY, true, true};
static const range R_NONNEG = {0.0, INFINITY, false, true};
static const range R_POSITIVE = {0.0, INFINITY, true, true};
static const range R_UNIT = {0.0, 1.0, false, false};
static const range R_ETA = {NACRE_ETA_MIN, NACRE_ETA_MAX, false, false};

typedef struct material_entry {
    const char *name; /* borrowed from the cJSON tree */
    nacre_material handle;
} material_entry;

typedef struct mesh_entry {
    char *path; /* resolved; owned. NULL for a shape */
    nacre_shape_desc shape;
    nacre_mesh handle;
} mesh_entry;

typedef struct loader {
    nacre_context *ctx;
    size_t nul_escapes;   /* \u0000 escapes in the text, turned into byte 1 (mark_nul_escapes) */
    const char *name;     /* shown in messages */
    const char *base_dir; /* relative mesh paths start here; NULL: the working directory */
    nacre_scene *scene;
    nacre_result err;     /* sticky: first failure */
    char path[PATH_MAX_CHARS];
    size_t path_len;
    float unit_mm;
    nacre_scene_file_settings settings;
    material_entry *materials; /* sorted by name */
    uint32_t material_count;
    mesh_entry *meshes;
    uint32_t mesh_count, mesh_capacity;
    material_entry *imported;  /* materials of an "import"ed glTF, names owned; unsorted */
    uint32_t imported_count;
} loader;

/* json_read.c: messages and field paths. nc_json_fail records the first failure only, prefixed
 * with the scene's name and the current field path. */
const char *nc_json_shown(const char *s, char *buf, size_t size);
void nc_json_fail(loader *ld, nacre_result code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
void nc_json_fail_inner(loader *ld, nacre_result code);
size_t nc_json_push_key(loader *ld, const char *key);
size_t nc_json_push_index(loader *ld, int index);
void nc_json_pop(loader *ld, size_t mark);
const char *nc_json_type_name(const cJSON *item);
const char *nc_json_join_names(const char *const *names, size_t count, char *buf, size_t size);
void nc_json_check_duplicates(loader *ld, const cJSON *item);
bool nc_json_expect_object(loader *ld, const cJSON *item);
bool nc_json_check_keys(loader *ld, const cJSON *obj, const char *const *valid, size_t count);
const cJSON *nc_json_member(const cJSON *obj, const char *key);
bool nc_json_require(loader *ld, const cJSON *obj, const char *key);
bool nc_json_read_number(loader *ld, const cJSON *item, range r, double *out);
bool nc_json_read_floats(loader *ld, const cJSON *item, int n, range r, bool allow_scalar,
                         float *out);
bool nc_json_nonzero3(const float v[3]);
double nc_json_sin_between(const float a[3], const float b[3]);
bool nc_json_get_number(loader *ld, const cJSON *obj, const char *key, range r, float *out);
bool nc_json_get_double(loader *ld, const cJSON *obj, const char *key, range r, double *out);
bool nc_json_get_integer(loader *ld, const cJSON *obj, const char *key, int64_t lo, int64_t hi,
                         int64_t *out);
bool nc_json_get_floats(loader *ld, const cJSON *obj, const char *key, int n, range r,
                        bool allow_scalar, float *out);
bool nc_json_get_direction(loader *ld, const cJSON *obj, const char *key, bool allow_name,
                           float out[3]);
bool nc_json_get_bool(loader *ld, const cJSON *obj, const char *key, bool *out);
const char *nc_json_get_string(loader *ld, const cJSON *obj, const char *key);
int nc_json_get_choice(loader *ld, const cJSON *obj, const char *key, const char *what,
                       const char *const *names, size_t count);
void nc_json_parse_array(loader *ld, const cJSON *arr, const char *key,
                         void (*parse_element)(loader *, const cJSON *));
char *nc_json_resolve_path(loader *ld, const char *rel);
/* `path` made absolute with symbolic links resolved (realpath), allocated through the context;
 * the path as given when it does not exist. NULL when out of memory. Shared by the loader (the
 * sources it records) and the writer (scene_write.c). */
char *nc_absolute_path(nacre_context *ctx, const char *path);

/* Section parsers, one file per section of the format; scene_json.c calls them in order. */
void nc_json_parse_units(loader *ld, const cJSON *item);
void nc_json_parse_render(loader *ld, const cJSON *obj);
void nc_json_parse_environment(loader *ld, const cJSON *item);
void nc_json_parse_camera(loader *ld, const cJSON *obj);
void nc_json_parse_light(loader *ld, const cJSON *obj);
/* A pattern object under `key`; medium2_optional: medium 2 may be left out (an emission pattern,
 * whose medium 2 does not emit). */
void nc_json_parse_pattern(loader *ld, const cJSON *obj, const char *key, bool medium2_optional,
                           nacre_medium_pattern *p);
void nc_json_parse_materials(loader *ld, const cJSON *obj);
bool nc_json_find_material(const loader *ld, const char *name, nacre_material *out);
void nc_json_parse_object(loader *ld, const cJSON *obj);
void nc_json_parse_fog(loader *ld, const cJSON *obj);
/* json_import.c: "import" (a glTF file), before camera, materials and lights. */
void nc_json_parse_import(loader *ld, const cJSON *root, bool has_units);
const material_entry *nc_json_find_imported(const loader *ld, const char *name);
void nc_json_parse_particles(loader *ld, const cJSON *obj);

#endif
