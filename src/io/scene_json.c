/*
 * scene_json.c: loads JSON scene files (format in docs/scene-format.md) by calling the public
 * scene-building functions, so a file can express nothing the C API cannot.
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
#include "core/core.h"
#include "scene/scene.h"

#include <cjson/cJSON.h>

#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define PATH_MAX_CHARS 256
#define NAME_SHOWN_MAX 64           /* longer keys and names are cut in messages */
#define SCENE_FILE_MAX (64u << 20)  /* a scene file is text; anything bigger is a mistake */
#define IMAGE_SIZE_MAX 16384
#define SHAPE_VERTICES_MAX (1u << 22)
#define SHAPE_SEGMENTS_MAX 4096u

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
    nacre_render_settings settings;
    material_entry *materials; /* sorted by name */
    uint32_t material_count;
    mesh_entry *meshes;
    uint32_t mesh_count, mesh_capacity;
} loader;

/* ------------------------------------------------------------------------------------------ */
/* Messages and field paths                                                                   */
/* ------------------------------------------------------------------------------------------ */

/* Keys come from the file and may hold newlines or megabytes: keep messages one short line. */
static const char *shown(const char *s, char *buf, size_t size)
{
    size_t n = 0;
    for (; s[n] && n + 4 < size && n < NAME_SHOWN_MAX; n++) {
        unsigned char c = (unsigned char)s[n];
        buf[n] = (c < 0x20 || c == 0x7f) ? '?' : (char)c;
    }
    if (s[n]) {
        memcpy(buf + n, "...", 3);
        n += 3;
    }
    buf[n] = '\0';
    return buf;
}

static void fail(loader *ld, nacre_result code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

static void fail(loader *ld, nacre_result code, const char *fmt, ...)
{
    if (ld->err != NACRE_OK)
        return;
    char msg[NC_ERROR_MAX];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof(msg), fmt, ap);
    va_end(ap);
    /* Paths from the file and third-party messages (assimp) may hold newlines; ours are one
     * line. */
    for (char *c = msg; *c; c++)
        if ((unsigned char)*c < 0x20)
            *c = ' ';
    if (ld->path_len > 0)
        ld->err = nc_fail(ld->ctx, code, "%s: %s: %s", ld->name, ld->path, msg);
    else
        ld->err = nc_fail(ld->ctx, code, "%s: %s", ld->name, msg);
}

/* A lower layer already recorded a message: keep its code, put the field path in front. */
static void fail_inner(loader *ld, nacre_result code)
{
    char inner[NC_ERROR_MAX];
    snprintf(inner, sizeof(inner), "%s", nacre_context_last_error(ld->ctx));
    if (code == NACRE_OK)
        code = NACRE_ERROR_INVALID_ARGUMENT;
    fail(ld, code, "%s", inner[0] ? inner : nacre_result_string(code));
}

static size_t push_key(loader *ld, const char *key)
{
    size_t mark = ld->path_len;
    char buf[NAME_SHOWN_MAX + 8];
    size_t room = sizeof(ld->path) - mark;
    int n = snprintf(ld->path + mark, room, "%s%s", mark ? "." : "", shown(key, buf, sizeof(buf)));
    ld->path_len = (n < 0 || (size_t)n >= room) ? sizeof(ld->path) - 1 : mark + (size_t)n;
    return mark;
}

static size_t push_index(loader *ld, int index)
{
    size_t mark = ld->path_len;
    size_t room = sizeof(ld->path) - mark;
    int n = snprintf(ld->path + mark, room, "[%d]", index);
    ld->path_len = (n < 0 || (size_t)n >= room) ? sizeof(ld->path) - 1 : mark + (size_t)n;
    return mark;
}

static void pop(loader *ld, size_t mark)
{
    ld->path_len = mark;
    ld->path[mark] = '\0';
}

static const char *type_name(const cJSON *item)
{
    if (cJSON_IsNumber(item))
        return "a number";
    if (cJSON_IsString(item))
        return "a string";
    if (cJSON_IsBool(item))
        return "a boolean";
    if (cJSON_IsNull(item))
        return "null";
    if (cJSON_IsArray(item))
        return "an array";
    if (cJSON_IsObject(item))
        return "an object";
    return "an invalid value";
}

/* "a, b, c" into buf, cut short (with "...") when it does not fit. */
static const char *join_names(const char *const *names, size_t count, char *buf, size_t size)
{
    size_t len = 0;
    buf[0] = '\0';
    for (size_t i = 0; i < count; i++) {
        int n = snprintf(buf + len, size - len, "%s%s", i ? ", " : "", names[i]);
        if (n < 0 || (size_t)n >= size - len) {
            if (size >= 4)
                memcpy(buf + size - 4, "...", 4);
            break;
        }
        len += (size_t)n;
    }
    return buf;
}

/* ------------------------------------------------------------------------------------------ */
/* Structure checks                                                                           */
/* ------------------------------------------------------------------------------------------ */

static int compare_names(const void *a, const void *b)
{
    return strcmp(*(const char *const *)a, *(const char *const *)b);
}

static void duplicate_key(loader *ld, const char *key)
{
    char buf[NAME_SHOWN_MAX + 8];
    fail(ld, NACRE_ERROR_PARSE, "duplicate key \"%s\"", shown(key, buf, sizeof(buf)));
}

/* cJSON keeps every copy of a repeated key and lookups return the first; JSON says the result
 * is undefined, so refuse rather than guess which one the author meant. Small objects compare
 * pairwise; large ones (a long "materials" list) sort a copy of their keys. */
static void check_duplicates(loader *ld, const cJSON *item)
{
    if (ld->err || (!cJSON_IsObject(item) && !cJSON_IsArray(item)))
        return;
    int count = cJSON_GetArraySize(item);
    if (cJSON_IsObject(item) && count > 1) {
        if (count <= 16) {
            for (const cJSON *a = item->child; a && !ld->err; a = a->next)
                for (const cJSON *b = a->next; b; b = b->next)
                    if (strcmp(a->string, b->string) == 0) {
                        duplicate_key(ld, a->string);
                        break;
                    }
        } else {
            const char **keys = nc_calloc(ld->ctx, (size_t)count, sizeof(*keys));
            if (!keys) {
                fail_inner(ld, NACRE_ERROR_OUT_OF_MEMORY);
                return;
            }
            int n = 0;
            for (const cJSON *c = item->child; c && n < count; c = c->next)
                keys[n++] = c->string;
            qsort(keys, (size_t)n, sizeof(*keys), compare_names);
            for (int i = 1; i < n; i++)
                if (strcmp(keys[i - 1], keys[i]) == 0) {
                    duplicate_key(ld, keys[i]);
                    break;
                }
            nc_free(ld->ctx, keys);
        }
    }
    int index = 0;
    for (const cJSON *c = item->child; c && !ld->err; c = c->next, index++) {
        size_t mark = cJSON_IsObject(item) ? push_key(ld, c->string) : push_index(ld, index);
        check_duplicates(ld, c);
        pop(ld, mark);
    }
}

static bool expect_object(loader *ld, const cJSON *item)
{
    if (ld->err)
        return false;
    if (!cJSON_IsObject(item)) {
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected an object, got %s", type_name(item));
        return false;
    }
    return true;
}

#define COUNT_OF(a) (sizeof(a) / sizeof((a)[0]))

/* Unknown keys are errors so that a typo ("sigma_s " or "colour") cannot silently fall back
 * to a default. Keys starting with '_' are comments. */
static bool check_keys(loader *ld, const cJSON *obj, const char *const *valid, size_t count)
{
    if (ld->err)
        return false;
    for (const cJSON *c = obj->child; c; c = c->next) {
        if (c->string[0] == '_')
            continue;
        bool known = false;
        for (size_t i = 0; i < count && !known; i++)
            known = strcmp(c->string, valid[i]) == 0;
        if (!known) {
            char key[NAME_SHOWN_MAX + 8], list[512];
            fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "unknown key \"%s\" (valid keys: %s)",
                 shown(c->string, key, sizeof(key)), join_names(valid, count, list, sizeof(list)));
            return false;
        }
    }
    return true;
}

static const cJSON *member(const cJSON *obj, const char *key)
{
    return cJSON_GetObjectItemCaseSensitive(obj, key);
}

static bool require(loader *ld, const cJSON *obj, const char *key)
{
    if (ld->err)
        return false;
    if (!member(obj, key)) {
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "missing required key \"%s\"", key);
        return false;
    }
    return true;
}

/* ------------------------------------------------------------------------------------------ */
/* Values (the path already names the value)                                                  */
/* ------------------------------------------------------------------------------------------ */

static bool in_range(double v, range r)
{
    if (r.lo_open ? !(v > r.lo) : !(v >= r.lo))
        return false;
    return r.hi_open ? v < r.hi : v <= r.hi;
}

static void range_problem(loader *ld, double v, range r)
{
    const char *what;
    char buf[96];
    if (isinf(r.lo) && isinf(r.hi))
        what = "must be finite";
    else if (isinf(r.hi) && r.lo == 0.0)
        what = r.lo_open ? "must be positive and finite" : "must be non-negative and finite";
    else {
        snprintf(buf, sizeof(buf), "must be in %c%g, %g%c", r.lo_open ? '(' : '[', r.lo, r.hi,
                 r.hi_open ? ')' : ']');
        what = buf;
    }
    fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "%s (got %g)", what, v);
}

static bool read_number(loader *ld, const cJSON *item, range r, double *out)
{
    if (ld->err)
        return false;
    if (!cJSON_IsNumber(item)) {
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected a number, got %s", type_name(item));
        return false;
    }
    double v = item->valuedouble;
    /* cJSON turns 1e999 into inf; floats overflow earlier still. */
    if (!isfinite(v) || fabs(v) > FLT_MAX || !in_range(v, r)) {
        range_problem(ld, v, r);
        return false;
    }
    *out = v;
    return true;
}

static bool read_integer(loader *ld, const cJSON *item, int64_t lo, int64_t hi, int64_t *out)
{
    if (ld->err)
        return false;
    if (!cJSON_IsNumber(item)) {
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected an integer, got %s", type_name(item));
        return false;
    }
    double v = item->valuedouble;
    if (!isfinite(v) || v != floor(v) || v < (double)lo || v > (double)hi) {
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "must be an integer in %lld..%lld (got %g)",
             (long long)lo, (long long)hi, v);
        return false;
    }
    *out = (int64_t)v;
    return true;
}

/* n numbers; a single number fills all n when allow_scalar (grey colours, uniform scales). */
static bool read_floats(loader *ld, const cJSON *item, int n, range r, bool allow_scalar,
                        float *out)
{
    if (ld->err)
        return false;
    double v;
    if (allow_scalar && cJSON_IsNumber(item)) {
        if (!read_number(ld, item, r, &v))
            return false;
        for (int i = 0; i < n; i++)
            out[i] = (float)v;
        return true;
    }
    if (!cJSON_IsArray(item)) {
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected an array of %d numbers%s, got %s", n,
             allow_scalar ? " or a number" : "", type_name(item));
        return false;
    }
    int count = cJSON_GetArraySize(item);
    if (count != n) {
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected an array of %d numbers, got %d element%s",
             n, count, count == 1 ? "" : "s");
        return false;
    }
    float tmp[4];
    int i = 0;
    for (const cJSON *c = item->child; c && i < n; c = c->next, i++) {
        size_t mark = push_index(ld, i);
        bool ok = read_number(ld, c, r, &v);
        pop(ld, mark);
        if (!ok)
            return false;
        tmp[i] = (float)v;
    }
    memcpy(out, tmp, (size_t)n * sizeof(float));
    return true;
}

static bool nonzero3(const float v[3])
{
    /* Squares of tiny components underflow; compare the largest magnitude instead. */
    return fmaxf(fabsf(v[0]), fmaxf(fabsf(v[1]), fabsf(v[2]))) > 1e-20f;
}

static double length3(const float v[3])
{
    return sqrt((double)v[0] * v[0] + (double)v[1] * v[1] + (double)v[2] * v[2]);
}

/* |a x b| / (|a| |b|): 0 for parallel vectors. Both must be nonzero. */
static double sin_between(const float a[3], const float b[3])
{
    double c[3] = {(double)a[1] * b[2] - (double)a[2] * b[1], (double)a[2] * b[0] - (double)a[0] * b[2],
                   (double)a[0] * b[1] - (double)a[1] * b[0]};
    double cl = sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
    return cl / (length3(a) * length3(b));
}

/* A direction: three numbers, not all zero; axes may also be named "x", "y" or "z". */
static bool read_direction(loader *ld, const cJSON *item, bool allow_name, float out[3])
{
    if (ld->err)
        return false;
    if (allow_name && cJSON_IsString(item)) {
        const char *s = item->valuestring;
        int axis = strcmp(s, "x") == 0 ? 0 : strcmp(s, "y") == 0 ? 1 : strcmp(s, "z") == 0 ? 2 : -1;
        if (axis < 0) {
            char buf[NAME_SHOWN_MAX + 8];
            fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                 "unknown axis \"%s\" (valid: \"x\", \"y\", \"z\" or [x, y, z])",
                 shown(s, buf, sizeof(buf)));
            return false;
        }
        out[0] = out[1] = out[2] = 0.0f;
        out[axis] = 1.0f;
        return true;
    }
    float v[3];
    if (!cJSON_IsArray(item) && allow_name) {
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
             "expected an array of 3 numbers or \"x\", \"y\", \"z\", got %s", type_name(item));
        return false;
    }
    if (!read_floats(ld, item, 3, R_FINITE, false, v))
        return false;
    if (!nonzero3(v)) {
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "must not be the zero vector");
        return false;
    }
    memcpy(out, v, sizeof(v));
    return true;
}

/* Keyed readers: do nothing (false) when the key is absent, so defaults stay. */

static bool get_number(loader *ld, const cJSON *obj, const char *key, range r, float *out)
{
    const cJSON *item = member(obj, key);
    if (!item || ld->err)
        return false;
    size_t mark = push_key(ld, key);
    double v;
    bool ok = read_number(ld, item, r, &v);
    pop(ld, mark);
    if (ok)
        *out = (float)v;
    return ok;
}

static bool get_double(loader *ld, const cJSON *obj, const char *key, range r, double *out)
{
    const cJSON *item = member(obj, key);
    if (!item || ld->err)
        return false;
    size_t mark = push_key(ld, key);
    bool ok = read_number(ld, item, r, out);
    pop(ld, mark);
    return ok;
}

static bool get_integer(loader *ld, const cJSON *obj, const char *key, int64_t lo, int64_t hi,
                        int64_t *out)
{
    const cJSON *item = member(obj, key);
    if (!item || ld->err)
        return false;
    size_t mark = push_key(ld, key);
    bool ok = read_integer(ld, item, lo, hi, out);
    pop(ld, mark);
    return ok;
}

static bool get_floats(loader *ld, const cJSON *obj, const char *key, int n, range r,
                       bool allow_scalar, float *out)
{
    const cJSON *item = member(obj, key);
    if (!item || ld->err)
        return false;
    size_t mark = push_key(ld, key);
    bool ok = read_floats(ld, item, n, r, allow_scalar, out);
    pop(ld, mark);
    return ok;
}

static bool get_direction(loader *ld, const cJSON *obj, const char *key, bool allow_name,
                          float out[3])
{
    const cJSON *item = member(obj, key);
    if (!item || ld->err)
        return false;
    size_t mark = push_key(ld, key);
    bool ok = read_direction(ld, item, allow_name, out);
    pop(ld, mark);
    return ok;
}

static bool get_bool(loader *ld, const cJSON *obj, const char *key, bool *out)
{
    const cJSON *item = member(obj, key);
    if (!item || ld->err)
        return false;
    if (!cJSON_IsBool(item)) {
        size_t mark = push_key(ld, key);
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected true or false, got %s", type_name(item));
        pop(ld, mark);
        return false;
    }
    *out = cJSON_IsTrue(item);
    return true;
}

/* A non-empty string, or NULL (absent or error). */
static const char *get_string(loader *ld, const cJSON *obj, const char *key)
{
    const cJSON *item = member(obj, key);
    if (!item || ld->err)
        return NULL;
    size_t mark = push_key(ld, key);
    const char *s = NULL;
    if (!cJSON_IsString(item) || !item->valuestring)
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected a string, got %s", type_name(item));
    else if (ld->nul_escapes && strchr(item->valuestring, '\x01'))
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "contains \\u0000 (a NUL character, which no path or name can hold)");
    else if (item->valuestring[0] == '\0')
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "must not be empty");
    else
        s = item->valuestring;
    pop(ld, mark);
    return s;
}

/* Index of `s` in names[], or -1 after reporting an error that lists the valid names. */
static int get_choice(loader *ld, const cJSON *obj, const char *key, const char *what,
                      const char *const *names, size_t count)
{
    const char *s = get_string(ld, obj, key);
    if (!s)
        return -1;
    for (size_t i = 0; i < count; i++)
        if (strcmp(s, names[i]) == 0)
            return (int)i;
    char buf[NAME_SHOWN_MAX + 8], list[512];
    size_t mark = push_key(ld, key);
    fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "unknown %s \"%s\" (valid: %s)", what,
         shown(s, buf, sizeof(buf)), join_names(names, count, list, sizeof(list)));
    pop(ld, mark);
    return -1;
}

/* ------------------------------------------------------------------------------------------ */
/* Sections                                                                                   */
/* ------------------------------------------------------------------------------------------ */

static void parse_units(loader *ld, const cJSON *item)
{
    size_t mark = push_key(ld, "units");
    if (cJSON_IsString(item)) {
        if (!nacre_units_mm(item->valuestring, &ld->unit_mm)) {
            char buf[NAME_SHOWN_MAX + 8];
            fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                 "unknown unit \"%s\" (valid: \"mm\", \"cm\", \"m\" or millimetres per unit)",
                 shown(item->valuestring, buf, sizeof(buf)));
        }
    } else if (cJSON_IsNumber(item)) {
        double v;
        if (read_number(ld, item, R_POSITIVE, &v))
            ld->unit_mm = (float)v;
    } else {
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
             "expected \"mm\", \"cm\", \"m\" or a number of millimetres, got %s", type_name(item));
    }
    pop(ld, mark);
    if (ld->err)
        return;
    nacre_result r = nacre_scene_set_unit_mm(ld->scene, ld->unit_mm);
    if (r != NACRE_OK) {
        mark = push_key(ld, "units");
        fail_inner(ld, r);
        pop(ld, mark);
    }
}

static void parse_render(loader *ld, const cJSON *obj)
{
    static const char *const keys[] = {"method", "width", "height", "exposure", "shadow_map_size",
                                       "pcf_radius", "shadow_bias", "spp", "seed", "time",
                                       "voxel_resolution", "tsm_size", "solver", "source",
                                       "tolerance", "seed_iterations", "time_limit", "max_scatter"};
    /* indexed by the enums' values */
    const char *const solvers[] = {nacre_solver_name(NACRE_SOLVER_MULTIGRID), nacre_solver_name(NACRE_SOLVER_SEED)};
    const char *const sources[] = {nacre_source_name(NACRE_SOURCE_VOLUME), nacre_source_name(NACRE_SOURCE_FACE)};
    size_t mark = push_key(ld, "render");
    if (!expect_object(ld, obj) || !check_keys(ld, obj, keys, COUNT_OF(keys))) {
        pop(ld, mark);
        return;
    }
    nacre_render_settings *s = &ld->settings;
    const char *method = get_string(ld, obj, "method");
    if (method && !nacre_method_from_name(method, &s->method)) {
        const char *names[NACRE_METHOD_COUNT];
        for (int i = 0; i < NACRE_METHOD_COUNT; i++)
            names[i] = nacre_method_name((nacre_method)i);
        char buf[NAME_SHOWN_MAX + 8], list[256];
        size_t m2 = push_key(ld, "method");
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "unknown render method \"%s\" (valid: %s)",
             shown(method, buf, sizeof(buf)), join_names(names, NACRE_METHOD_COUNT, list, sizeof(list)));
        pop(ld, m2);
    }
    int64_t v;
    if (get_integer(ld, obj, "width", 1, IMAGE_SIZE_MAX, &v))
        s->width = (int32_t)v;
    if (get_integer(ld, obj, "height", 1, IMAGE_SIZE_MAX, &v))
        s->height = (int32_t)v;
    get_number(ld, obj, "exposure", R_FINITE, &s->exposure);
    if (get_integer(ld, obj, "shadow_map_size", 0, IMAGE_SIZE_MAX, &v))
        s->shadow_map_size = (int32_t)v;
    get_number(ld, obj, "pcf_radius", R_NONNEG, &s->pcf_radius);
    get_number(ld, obj, "shadow_bias", R_NONNEG, &s->shadow_bias);
    if (get_integer(ld, obj, "spp", 1, 1 << 24, &v))
        s->spp = (uint32_t)v;
    if (get_integer(ld, obj, "seed", 0, UINT32_MAX, &v))
        s->seed = (uint32_t)v;
    get_double(ld, obj, "time", R_FINITE, &s->time);
    /* Diffusion and path-tracer settings (nacre_render_settings); ranges match what the
     * renderers accept, so a file cannot ask for a grid or map the library would refuse. */
    if (get_integer(ld, obj, "voxel_resolution", 1, 1024, &v))
        s->voxel_resolution = (uint32_t)v;
    if (get_integer(ld, obj, "tsm_size", 16, 8192, &v))
        s->tsm_size = (int32_t)v;
    int choice = get_choice(ld, obj, "solver", "solver", solvers, COUNT_OF(solvers));
    if (choice >= 0)
        s->solver = (nacre_diffusion_solver)choice;
    choice = get_choice(ld, obj, "source", "source", sources, COUNT_OF(sources));
    if (choice >= 0)
        s->source = (nacre_diffusion_source)choice;
    static const range tolerance_range = {0.0, 1.0, true, true};
    get_number(ld, obj, "tolerance", tolerance_range, &s->tolerance);
    if (get_integer(ld, obj, "seed_iterations", 0, 1000000, &v))
        s->seed_iterations = (uint32_t)v;
    get_double(ld, obj, "time_limit", R_NONNEG, &s->time_limit);
    if (get_integer(ld, obj, "max_scatter", 0, UINT32_MAX, &v))
        s->max_scatter = (uint32_t)v;
    pop(ld, mark);
}

static void parse_environment(loader *ld, const cJSON *item)
{
    size_t mark = push_key(ld, "environment");
    float radiance[3];
    if (read_floats(ld, item, 3, R_NONNEG, true, radiance)) {
        nacre_result r = nacre_scene_set_environment(ld->scene, radiance);
        if (r != NACRE_OK)
            fail_inner(ld, r);
    }
    pop(ld, mark);
}

static void parse_camera(loader *ld, const cJSON *obj)
{
    static const char *const keys[] = {"type", "position", "target", "up", "fov", "height",
                                       "near", "far"};
    static const char *const types[] = {"perspective", "orthographic"};
    size_t mark = push_key(ld, "camera");
    if (!expect_object(ld, obj) || !check_keys(ld, obj, keys, COUNT_OF(keys))) {
        pop(ld, mark);
        return;
    }
    nacre_camera_desc d = nacre_camera_desc_defaults();
    int type = get_choice(ld, obj, "type", "camera type", types, COUNT_OF(types));
    if (type >= 0)
        d.projection = type == 0 ? NACRE_PERSPECTIVE : NACRE_ORTHOGRAPHIC;
    get_floats(ld, obj, "position", 3, R_FINITE, false, d.position);
    get_floats(ld, obj, "target", 3, R_FINITE, false, d.target);
    get_direction(ld, obj, "up", false, d.up);
    static const range fov_range = {0.0, 180.0, true, true};
    get_number(ld, obj, "fov", fov_range, &d.fov_y);
    get_number(ld, obj, "height", R_POSITIVE, &d.ortho_height);
    get_number(ld, obj, "near", R_NONNEG, &d.near_clip);
    get_number(ld, obj, "far", R_NONNEG, &d.far_clip);
    if (!ld->err) {
        float view[3] = {d.target[0] - d.position[0], d.target[1] - d.position[1],
                         d.target[2] - d.position[2]};
        if (!nonzero3(view)) {
            size_t m2 = push_key(ld, "target");
            fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "must differ from camera.position");
            pop(ld, m2);
        } else if (nonzero3(d.up) && sin_between(view, d.up) < 1e-6) {
            size_t m2 = push_key(ld, "up");
            fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "must not be parallel to the view direction");
            pop(ld, m2);
        } else if (d.far_clip > 0.0f && d.far_clip <= d.near_clip) {
            size_t m2 = push_key(ld, "far");
            fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "must be greater than near (or 0: automatic)");
            pop(ld, m2);
        }
    }
    if (!ld->err) {
        nacre_result r = nacre_scene_set_camera(ld->scene, &d);
        if (r != NACRE_OK)
            fail_inner(ld, r);
    }
    pop(ld, mark);
}

/* Names accepted by nacre_material_preset (listed in nacre.h); used for the error message. */
static const char *const preset_names[] = {"apple", "chicken1", "chicken2", "cream", "ketchup",
                                           "marble", "potato", "skimmilk", "skin1", "skin2",
                                           "wholemilk", "jade", "aquamarine"};

static char *resolve_path(loader *ld, const char *rel);

/* A preset's coefficients per scene unit, or false after an error listing the valid names. */
static bool preset_per_unit(loader *ld, const char *key, const char *name, nacre_material_desc *d)
{
    if (!nacre_material_preset(name, d)) {
        const char *valid[COUNT_OF(preset_names)];
        size_t n = 0;
        nacre_material_desc probe;
        for (size_t i = 0; i < COUNT_OF(preset_names); i++)
            if (nacre_material_preset(preset_names[i], &probe))
                valid[n++] = preset_names[i];
        char buf[NAME_SHOWN_MAX + 8], list[512];
        size_t mark = push_key(ld, key);
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "unknown preset \"%s\" (valid: %s)",
             shown(name, buf, sizeof(buf)), join_names(valid, n, list, sizeof(list)));
        pop(ld, mark);
        return false;
    }
    nacre_material_desc_per_unit(d, ld->unit_mm);
    return true;
}

/* "volume": an NRRD file (relative to the scene file) scaled by "density_scale", added to the
 * scene; the handle goes into the pattern. */
static void load_volume(loader *ld, const cJSON *obj, nacre_medium_pattern *p)
{
    const char *rel = get_string(ld, obj, "volume");
    int64_t channel = 0;
    get_integer(ld, obj, "channel", 0, 255, &channel);
    float scale = 1.0f;
    get_number(ld, obj, "density_scale", R_NONNEG, &scale);
    if (ld->err || !rel)
        return;
    size_t mark = push_key(ld, "volume");
    char *path = resolve_path(ld, rel);
    nacre_volume_data vol = {0};
    nacre_result r = path ? nacre_volume_load_nrrd(ld->ctx, path, (uint32_t)channel, &vol)
                          : NACRE_ERROR_OUT_OF_MEMORY;
    if (r == NACRE_OK) {
        size_t n = (size_t)vol.dims[0] * vol.dims[1] * vol.dims[2];
        for (size_t i = 0; i < n; i++)
            vol.data[i] *= scale;
        r = nacre_scene_add_volume(ld->scene, &vol, &p->volume);
    }
    if (r != NACRE_OK)
        fail_inner(ld, r);
    nacre_volume_data_free(ld->ctx, &vol);
    nc_free(ld->ctx, path);
    pop(ld, mark);
}

/* "pattern": heterogeneity of a translucent material (nacre_medium_pattern). Medium 2 comes
 * from "preset2" and/or "sigma_a2" + "sigma_s2" (explicit values override the preset's). */
static void parse_pattern(loader *ld, const cJSON *obj, nacre_medium_pattern *p)
{
    static const char *const types[] = {"random_mix", "checker", "noise", "volume"};
    static const char *const mix_keys[] = {"type", "preset2", "sigma_a2", "sigma_s2", "cell_size",
                                           "fraction", "seed"};
    static const char *const checker_keys[] = {"type", "preset2", "sigma_a2", "sigma_s2", "cell_size"};
    static const char *const noise_keys[] = {"type", "preset2", "sigma_a2", "sigma_s2", "cell_size",
                                             "seed", "octaves"};
    static const char *const volume_keys[] = {"type", "volume", "channel", "density_scale"};
    size_t mark = push_key(ld, "pattern");
    if (!expect_object(ld, obj) || !require(ld, obj, "type")) {
        pop(ld, mark);
        return;
    }
    int type = get_choice(ld, obj, "type", "pattern type", types, COUNT_OF(types));
    if (type < 0) {
        pop(ld, mark);
        return;
    }
    memset(p, 0, sizeof(*p));
    p->type = (nacre_pattern_type)(NACRE_PATTERN_RANDOM_MIX + type);
    p->fraction = 0.5f;
    p->octaves = 4;
    switch (p->type) {
    case NACRE_PATTERN_RANDOM_MIX: check_keys(ld, obj, mix_keys, COUNT_OF(mix_keys)); break;
    case NACRE_PATTERN_CHECKER: check_keys(ld, obj, checker_keys, COUNT_OF(checker_keys)); break;
    case NACRE_PATTERN_NOISE: check_keys(ld, obj, noise_keys, COUNT_OF(noise_keys)); break;
    default: check_keys(ld, obj, volume_keys, COUNT_OF(volume_keys)); break;
    }
    if (p->type == NACRE_PATTERN_VOLUME) {
        if (require(ld, obj, "volume"))
            load_volume(ld, obj, p);
        pop(ld, mark);
        return;
    }
    const char *preset2 = get_string(ld, obj, "preset2");
    if (preset2) {
        nacre_material_desc m2;
        if (preset_per_unit(ld, "preset2", preset2, &m2)) {
            memcpy(p->sigma_a2, m2.sigma_a, sizeof(p->sigma_a2));
            memcpy(p->sigma_s2, m2.sigma_s, sizeof(p->sigma_s2));
        }
    } else if (!ld->err && (!member(obj, "sigma_a2") || !member(obj, "sigma_s2"))) {
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
             "medium 2 needs \"preset2\" or both \"sigma_a2\" and \"sigma_s2\"");
    }
    get_floats(ld, obj, "sigma_a2", 3, R_NONNEG, true, p->sigma_a2);
    get_floats(ld, obj, "sigma_s2", 3, R_NONNEG, true, p->sigma_s2);
    if (require(ld, obj, "cell_size"))
        get_number(ld, obj, "cell_size", R_POSITIVE, &p->cell_size);
    get_number(ld, obj, "fraction", R_UNIT, &p->fraction);
    int64_t v;
    if (get_integer(ld, obj, "seed", 0, UINT32_MAX, &v))
        p->seed = (uint32_t)v;
    if (get_integer(ld, obj, "octaves", 1, 12, &v))
        p->octaves = (uint32_t)v;
    pop(ld, mark);
}

/* One entry of "layers": coefficients from "preset" and/or "sigma_a" + "sigma_s" (explicit
 * values override the preset's), "g", and the required "depth" (scene units). */
static void parse_layer(loader *ld, const cJSON *obj, nacre_layer *y)
{
    static const char *const keys[] = {"preset", "sigma_a", "sigma_s", "g", "depth"};
    if (!expect_object(ld, obj) || !require(ld, obj, "depth"))
        return;
    check_keys(ld, obj, keys, COUNT_OF(keys));
    const char *preset = get_string(ld, obj, "preset");
    if (!preset && !ld->err && (!member(obj, "sigma_a") || !member(obj, "sigma_s")))
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "a layer needs \"preset\" or both \"sigma_a\" and \"sigma_s\"");
    if (ld->err)
        return;
    nacre_material_desc d = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
    d.g = 0.0f;
    if (preset && !preset_per_unit(ld, "preset", preset, &d))
        return;
    static const range g_range = {-1.0, 1.0, true, true};
    get_floats(ld, obj, "sigma_a", 3, R_NONNEG, true, d.sigma_a);
    get_floats(ld, obj, "sigma_s", 3, R_NONNEG, true, d.sigma_s);
    get_number(ld, obj, "g", g_range, &d.g);
    get_number(ld, obj, "depth", R_NONNEG, &y->depth);
    memcpy(y->sigma_a, d.sigma_a, sizeof(y->sigma_a));
    memcpy(y->sigma_s, d.sigma_s, sizeof(y->sigma_s));
    y->g = d.g;
}

/* "layers" (array, surface first) and "depth_map" (an image file relative to the scene file,
 * read as data: channel j scales layer j's depth) of a translucent material. */
static void parse_layering(loader *ld, const cJSON *obj, nacre_layering *l)
{
    const cJSON *arr = member(obj, "layers");
    if (arr) {
        size_t mark = push_key(ld, "layers");
        if (!cJSON_IsArray(arr)) {
            fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected an array, got %s", type_name(arr));
        } else if (cJSON_GetArraySize(arr) > NACRE_MAX_LAYERS) {
            fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "at most %d layers (got %d)", NACRE_MAX_LAYERS,
                 cJSON_GetArraySize(arr));
        } else {
            int i = 0;
            for (const cJSON *c = arr->child; c && !ld->err; c = c->next, i++) {
                size_t m2 = push_index(ld, i);
                parse_layer(ld, c, &l->layers[i]);
                pop(ld, m2);
            }
            l->count = (uint32_t)i;
        }
        pop(ld, mark);
    }
    const char *rel = get_string(ld, obj, "depth_map");
    if (ld->err || !rel)
        return;
    size_t mark = push_key(ld, "depth_map");
    if (l->count == 0) {
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "a depth map needs \"layers\"");
        pop(ld, mark);
        return;
    }
    char *path = resolve_path(ld, rel);
    nacre_image img = {0};
    nacre_result r = path ? nacre_image_read_data(ld->ctx, path, &img) : NACRE_ERROR_OUT_OF_MEMORY;
    if (r == NACRE_OK)
        r = nacre_scene_add_texture(ld->scene, &img, &l->depth_map);
    if (r != NACRE_OK)
        fail_inner(ld, r);
    nacre_image_free(ld->ctx, &img);
    nc_free(ld->ctx, path);
    pop(ld, mark);
}

static void parse_material(loader *ld, const cJSON *obj, nacre_material *out)
{
    static const char *const opaque_keys[] = {"type", "diffuse", "specular", "shininess"};
    static const char *const translucent_keys[] = {"type", "preset", "sigma_a", "sigma_s", "g",
                                                   "eta", "specular", "shininess", "pattern",
                                                   "layers", "depth_map"};
    static const char *const types[] = {"opaque", "translucent"};
    if (!expect_object(ld, obj))
        return;
    nacre_material_desc d = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
    const char *preset = get_string(ld, obj, "preset");
    int type = -1;
    if (member(obj, "type"))
        type = get_choice(ld, obj, "type", "material type", types, COUNT_OF(types));
    else if (!preset && !ld->err)
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "missing required key \"type\" (or \"preset\")");
    if (ld->err)
        return;
    if (preset) {
        if (type == 0) {
            size_t mark = push_key(ld, "type");
            fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "presets are translucent materials");
            pop(ld, mark);
            return;
        }
        type = 1;
        if (!preset_per_unit(ld, "preset", preset, &d))
            return;
    } else {
        d = nacre_material_desc_defaults(type == 0 ? NACRE_MATERIAL_OPAQUE : NACRE_MATERIAL_TRANSLUCENT);
        /* The translucent default (jade) is per millimetre like the presets. */
        nacre_material_desc_per_unit(&d, ld->unit_mm);
    }
    if (type == 0)
        check_keys(ld, obj, opaque_keys, COUNT_OF(opaque_keys));
    else
        check_keys(ld, obj, translucent_keys, COUNT_OF(translucent_keys));
    static const range g_range = {-1.0, 1.0, true, true};
    get_floats(ld, obj, "diffuse", 3, R_UNIT, true, d.diffuse);
    get_floats(ld, obj, "specular", 3, R_UNIT, true, d.specular);
    get_number(ld, obj, "shininess", R_NONNEG, &d.shininess);
    get_floats(ld, obj, "sigma_a", 3, R_NONNEG, true, d.sigma_a);
    get_floats(ld, obj, "sigma_s", 3, R_NONNEG, true, d.sigma_s);
    get_number(ld, obj, "g", g_range, &d.g);
    get_number(ld, obj, "eta", R_ETA, &d.eta);
    const cJSON *pattern = member(obj, "pattern");
    if (pattern && type == 1 && !ld->err)
        parse_pattern(ld, pattern, &d.pattern);
    if (type == 1 && !ld->err)
        parse_layering(ld, obj, &d.layering);
    if (ld->err)
        return;
    nacre_result r = nacre_scene_add_material(ld->scene, &d, out);
    if (r != NACRE_OK)
        fail_inner(ld, r);
}

static int compare_material_entries(const void *a, const void *b)
{
    return strcmp(((const material_entry *)a)->name, ((const material_entry *)b)->name);
}

static void parse_materials(loader *ld, const cJSON *obj)
{
    size_t mark = push_key(ld, "materials");
    if (!expect_object(ld, obj)) {
        pop(ld, mark);
        return;
    }
    int count = cJSON_GetArraySize(obj);
    if (count > 0) {
        ld->materials = nc_calloc(ld->ctx, (size_t)count, sizeof(*ld->materials));
        if (!ld->materials)
            fail_inner(ld, NACRE_ERROR_OUT_OF_MEMORY);
    }
    for (const cJSON *c = obj->child; c && !ld->err && ld->material_count < (uint32_t)count;
         c = c->next) {
        size_t m2 = push_key(ld, c->string);
        if (c->string[0] == '\0')
            fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "material names must not be empty");
        material_entry *e = &ld->materials[ld->material_count];
        parse_material(ld, c, &e->handle);
        if (!ld->err) {
            e->name = c->string;
            ld->material_count++;
        }
        pop(ld, m2);
    }
    if (!ld->err && ld->material_count > 1)
        qsort(ld->materials, ld->material_count, sizeof(*ld->materials), compare_material_entries);
    pop(ld, mark);
}

static bool find_material(const loader *ld, const char *name, nacre_material *out)
{
    material_entry key = {name, {0}};
    const material_entry *e = ld->material_count == 0 ? NULL
        : bsearch(&key, ld->materials, ld->material_count, sizeof(*ld->materials),
                  compare_material_entries);
    if (e)
        *out = e->handle;
    return e != NULL;
}

static void parse_light(loader *ld, const cJSON *obj)
{
    static const char *const types[] = {"directional", "point", "spot"};
    static const char *const directional_keys[] = {"type", "direction", "irradiance", "strength",
                                                   "angular_radius", "shadows"};
    static const char *const point_keys[] = {"type", "position", "intensity", "strength", "radius",
                                             "shadows"};
    static const char *const spot_keys[] = {"type", "position", "direction", "intensity",
                                            "strength", "inner_angle", "outer_angle", "radius",
                                            "shadows"};
    if (!expect_object(ld, obj) || !require(ld, obj, "type"))
        return;
    int type = get_choice(ld, obj, "type", "light type", types, COUNT_OF(types));
    if (type < 0)
        return;
    static const nacre_light_type kinds[] = {NACRE_LIGHT_DIRECTIONAL, NACRE_LIGHT_POINT,
                                             NACRE_LIGHT_SPOT};
    nacre_light_desc d = nacre_light_desc_defaults(kinds[type]);
    const char *strength_key = type == 0 ? "irradiance" : "intensity";
    if (type == 0)
        check_keys(ld, obj, directional_keys, COUNT_OF(directional_keys));
    else if (type == 1)
        check_keys(ld, obj, point_keys, COUNT_OF(point_keys));
    else
        check_keys(ld, obj, spot_keys, COUNT_OF(spot_keys));
    if (type != 1)
        require(ld, obj, "direction");
    if (type != 0)
        require(ld, obj, "position");
    if (!ld->err && member(obj, strength_key) && member(obj, "strength"))
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "give \"%s\" or \"strength\", not both", strength_key);
    get_direction(ld, obj, "direction", false, d.direction);
    get_floats(ld, obj, "position", 3, R_FINITE, false, d.position);
    get_floats(ld, obj, strength_key, 3, R_NONNEG, true, d.strength);
    get_floats(ld, obj, "strength", 3, R_NONNEG, true, d.strength);
    static const range angular_range = {0.0, 90.0, false, true};
    get_number(ld, obj, "angular_radius", angular_range, &d.angular_radius);
    get_number(ld, obj, "radius", R_NONNEG, &d.radius);
    /* Half-angles: a cone of 90 degrees or more has no well-defined shadow frustum. */
    static const range inner_range = {0.0, 90.0, false, true};
    static const range outer_range = {0.0, 90.0, true, true};
    get_number(ld, obj, "inner_angle", inner_range, &d.inner_angle);
    get_number(ld, obj, "outer_angle", outer_range, &d.outer_angle);
    get_bool(ld, obj, "shadows", &d.cast_shadows);
    if (!ld->err && type == 2 && d.inner_angle > d.outer_angle)
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "inner_angle (%g) must not exceed outer_angle (%g)",
             d.inner_angle, d.outer_angle);
    if (ld->err)
        return;
    nacre_light handle;
    nacre_result r = nacre_scene_add_light(ld->scene, &d, &handle);
    if (r != NACRE_OK)
        fail_inner(ld, r);
}

/* Walk a JSON array whose elements are parsed by `parse_element`, with the key and index on the
 * field path for messages ("lights[2].type"). */
static void parse_array(loader *ld, const cJSON *arr, const char *key,
                        void (*parse_element)(loader *, const cJSON *))
{
    size_t mark = push_key(ld, key);
    if (!cJSON_IsArray(arr)) {
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected an array, got %s", type_name(arr));
    } else {
        int i = 0;
        for (const cJSON *c = arr->child; c && !ld->err; c = c->next, i++) {
            size_t m2 = push_index(ld, i);
            parse_element(ld, c);
            pop(ld, m2);
        }
    }
    pop(ld, mark);
}

/* ------------------------------------------------------------------------------------------ */
/* Objects: meshes, shapes, transforms, deformers                                             */
/* ------------------------------------------------------------------------------------------ */

static mesh_entry *new_mesh_entry(loader *ld)
{
    if (ld->mesh_count == ld->mesh_capacity) {
        uint32_t cap = ld->mesh_capacity ? ld->mesh_capacity * 2 : 8;
        mesh_entry *grown = nc_realloc(ld->ctx, ld->meshes, ld->mesh_count * sizeof(*grown),
                                       cap * sizeof(*grown));
        if (!grown) {
            fail_inner(ld, NACRE_ERROR_OUT_OF_MEMORY);
            return NULL;
        }
        ld->meshes = grown;
        ld->mesh_capacity = cap;
    }
    mesh_entry *e = &ld->meshes[ld->mesh_count];
    memset(e, 0, sizeof(*e));
    return e;
}

/* Hand generated or loaded data to the scene (which copies it) and free ours. */
static bool add_mesh_data(loader *ld, nacre_mesh_data *data, nacre_mesh *out)
{
    nacre_result r = nacre_scene_add_mesh(ld->scene, data, out);
    nacre_mesh_data_free(ld->ctx, data);
    if (r != NACRE_OK)
        fail_inner(ld, r);
    return r == NACRE_OK;
}

static char *resolve_path(loader *ld, const char *rel)
{
    bool relative = rel[0] != '/' && ld->base_dir && ld->base_dir[0];
    size_t base_len = relative ? strlen(ld->base_dir) : 0;
    bool slash = relative && ld->base_dir[base_len - 1] != '/';
    size_t rel_len = strlen(rel);
    char *p = nc_alloc(ld->ctx, base_len + (slash ? 1 : 0) + rel_len + 1);
    if (!p)
        return NULL;
    if (relative)
        memcpy(p, ld->base_dir, base_len);
    if (slash)
        p[base_len++] = '/';
    memcpy(p + base_len, rel, rel_len + 1);
    if (nc_scene_note_input(ld->scene, p) != NACRE_OK) {
        nc_free(ld->ctx, p);
        return NULL;
    }
    return p;
}

/* The same file named twice (after resolving against the scene's folder) is loaded once. */
static bool load_mesh(loader *ld, const char *rel, nacre_mesh *out)
{
    size_t mark = push_key(ld, "mesh");
    char *path = resolve_path(ld, rel);
    bool ok = false;
    if (!path) {
        fail_inner(ld, NACRE_ERROR_OUT_OF_MEMORY);
        goto out;
    }
    for (uint32_t i = 0; i < ld->mesh_count; i++)
        if (ld->meshes[i].path && strcmp(ld->meshes[i].path, path) == 0) {
            *out = ld->meshes[i].handle;
            ok = true;
            goto out_free_path;
        }
    /* Check first so that the message names the scene field and the path as written. */
    FILE *f = fopen(path, "rb");
    if (!f) {
        char reason[128] = "cannot open";
        int e = errno;
        if (strerror_r(e, reason, sizeof(reason)) != 0)
            snprintf(reason, sizeof(reason), "error %d", e);
        char buf[NAME_SHOWN_MAX + 8];
        if (strcmp(rel, path) == 0)
            fail(ld, NACRE_ERROR_IO, "cannot open mesh file \"%s\": %s", shown(rel, buf, sizeof(buf)),
                 reason);
        else
            fail(ld, NACRE_ERROR_IO, "cannot open mesh file \"%s\" (%s): %s",
                 shown(rel, buf, sizeof(buf)), path, reason);
        goto out_free_path;
    }
    fclose(f);
    nacre_mesh_data data = {0};
    nacre_result r = nacre_mesh_load(ld->ctx, path, &data);
    if (r != NACRE_OK) {
        nacre_mesh_data_free(ld->ctx, &data);
        fail_inner(ld, r);
        goto out_free_path;
    }
    mesh_entry *e = new_mesh_entry(ld);
    if (!e) {
        nacre_mesh_data_free(ld->ctx, &data);
        goto out_free_path;
    }
    if (!add_mesh_data(ld, &data, out))
        goto out_free_path;
    e->path = path;
    e->handle = *out;
    ld->mesh_count++;
    ok = true;
    goto out;
out_free_path:
    nc_free(ld->ctx, path);
out:
    pop(ld, mark);
    return ok;
}

static bool same_shape(const nacre_shape_desc *a, const nacre_shape_desc *b)
{
    return a->type == b->type && a->radius == b->radius && a->minor_radius == b->minor_radius &&
           a->size[0] == b->size[0] && a->size[1] == b->size[1] && a->size[2] == b->size[2] &&
           a->segments == b->segments && a->rings == b->rings;
}

static void parse_plane_size(loader *ld, const cJSON *obj, nacre_shape_desc *d)
{
    const cJSON *item = member(obj, "size");
    if (!item || ld->err)
        return;
    size_t mark = push_key(ld, "size");
    float v[3];
    if (cJSON_IsArray(item) && cJSON_GetArraySize(item) == 2) {
        if (read_floats(ld, item, 2, R_POSITIVE, false, v)) {
            d->size[0] = v[0];
            d->size[2] = v[1];
        }
    } else if (cJSON_IsArray(item) && cJSON_GetArraySize(item) == 3) {
        /* Allow the middle entry so a box size can be reused; a plane has no height. */
        if (read_floats(ld, item, 3, R_NONNEG, false, v)) {
            int bad = v[0] <= 0.0f ? 0 : v[1] != 0.0f ? 1 : v[2] <= 0.0f ? 2 : -1;
            if (bad >= 0) {
                size_t m2 = push_index(ld, bad);
                fail(ld, NACRE_ERROR_INVALID_ARGUMENT, bad == 1 ? "must be 0 (a plane is flat)"
                     : "must be positive and finite (got 0)");
                pop(ld, m2);
            } else {
                d->size[0] = v[0];
                d->size[2] = v[2];
            }
        }
    } else if (cJSON_IsNumber(item)) {
        if (read_floats(ld, item, 1, R_POSITIVE, true, v))
            d->size[0] = d->size[2] = v[0];
    } else if (cJSON_IsArray(item)) {
        int n = cJSON_GetArraySize(item);
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
             "expected [width, depth] or [width, 0, depth], got %d element%s", n, n == 1 ? "" : "s");
    } else {
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
             "expected [width, depth], [width, 0, depth] or a number, got %s", type_name(item));
    }
    pop(ld, mark);
}

static bool make_shape(loader *ld, const cJSON *obj, nacre_mesh *out)
{
    static const char *const types[] = {"sphere", "box", "plane", "torus"};
    static const char *const sphere_keys[] = {"type", "radius", "segments", "rings"};
    static const char *const box_keys[] = {"type", "size", "segments"};
    static const char *const torus_keys[] = {"type", "radius", "minor_radius", "segments", "rings"};
    static const nacre_shape_type kinds[] = {NACRE_SHAPE_SPHERE, NACRE_SHAPE_BOX, NACRE_SHAPE_PLANE,
                                             NACRE_SHAPE_TORUS};
    size_t mark = push_key(ld, "shape");
    bool ok = false;
    if (!expect_object(ld, obj) || !require(ld, obj, "type"))
        goto out;
    int type = get_choice(ld, obj, "type", "shape type", types, COUNT_OF(types));
    if (type < 0)
        goto out;
    nacre_shape_desc d = nacre_shape_desc_defaults(kinds[type]);
    int64_t v;
    uint32_t min_segments = 1, min_rings = 2;
    switch (kinds[type]) {
    case NACRE_SHAPE_SPHERE:
        check_keys(ld, obj, sphere_keys, COUNT_OF(sphere_keys));
        get_number(ld, obj, "radius", R_POSITIVE, &d.radius);
        min_segments = 3;
        break;
    case NACRE_SHAPE_BOX:
        check_keys(ld, obj, box_keys, COUNT_OF(box_keys));
        get_floats(ld, obj, "size", 3, R_POSITIVE, true, d.size);
        break;
    case NACRE_SHAPE_PLANE:
        check_keys(ld, obj, box_keys, COUNT_OF(box_keys));
        parse_plane_size(ld, obj, &d);
        break;
    case NACRE_SHAPE_TORUS:
        check_keys(ld, obj, torus_keys, COUNT_OF(torus_keys));
        get_number(ld, obj, "radius", R_POSITIVE, &d.radius);
        get_number(ld, obj, "minor_radius", R_POSITIVE, &d.minor_radius);
        min_segments = 3;
        min_rings = 3;
        if (!ld->err && d.minor_radius >= d.radius) {
            size_t m2 = push_key(ld, "minor_radius");
            fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                 "must be smaller than radius (%g), or the torus intersects itself", d.radius);
            pop(ld, m2);
        }
        break;
    }
    if (get_integer(ld, obj, "segments", min_segments, SHAPE_SEGMENTS_MAX, &v))
        d.segments = (uint32_t)v;
    if (get_integer(ld, obj, "rings", min_rings, SHAPE_SEGMENTS_MAX, &v))
        d.rings = (uint32_t)v;
    if (ld->err)
        goto out;
    /* Bound the memory a few typed digits can ask for. */
    uint64_t s = d.segments + 1u, rg = d.rings + 1u;
    uint64_t vertices = kinds[type] == NACRE_SHAPE_BOX ? 6 * s * s
                        : kinds[type] == NACRE_SHAPE_PLANE ? s * s : s * rg;
    if (vertices > SHAPE_VERTICES_MAX) {
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
             "too finely subdivided (about %llu vertices; at most %u)",
             (unsigned long long)vertices, SHAPE_VERTICES_MAX);
        goto out;
    }
    for (uint32_t i = 0; i < ld->mesh_count; i++)
        if (!ld->meshes[i].path && same_shape(&ld->meshes[i].shape, &d)) {
            *out = ld->meshes[i].handle;
            ok = true;
            goto out;
        }
    mesh_entry *e = new_mesh_entry(ld);
    if (!e)
        goto out;
    nacre_mesh_data data = {0};
    nacre_result r = nacre_mesh_make_shape(ld->ctx, &d, &data);
    if (r != NACRE_OK) {
        nacre_mesh_data_free(ld->ctx, &data);
        fail_inner(ld, r);
        goto out;
    }
    if (!add_mesh_data(ld, &data, out))
        goto out;
    e->shape = d;
    e->handle = *out;
    ld->mesh_count++;
    ok = true;
out:
    pop(ld, mark);
    return ok;
}

static void parse_transform(loader *ld, const cJSON *obj, nacre_transform *t)
{
    static const char *const keys[] = {"translate", "rotate", "scale"};
    size_t mark = push_key(ld, "transform");
    if (expect_object(ld, obj) && check_keys(ld, obj, keys, COUNT_OF(keys))) {
        get_floats(ld, obj, "translate", 3, R_FINITE, false, t->translate);
        get_floats(ld, obj, "rotate", 3, R_FINITE, false, t->rotate);
        get_floats(ld, obj, "scale", 3, R_POSITIVE, true, t->scale);
    }
    pop(ld, mark);
}

static void parse_deformer(loader *ld, const cJSON *obj, nacre_deformer *out)
{
    static const char *const types[] = {"scale", "twist", "bend"};
    static const nacre_deformer_type kinds[] = {NACRE_DEFORM_SCALE, NACRE_DEFORM_TWIST,
                                                NACRE_DEFORM_BEND};
    static const char *const scale_keys[] = {"type", "scale", "scale_rate", "center"};
    static const char *const twist_keys[] = {"type", "axis", "angle", "angle_rate", "length",
                                             "center"};
    static const char *const bend_keys[] = {"type", "axis", "direction", "angle", "angle_rate",
                                            "length", "center"};
    if (!expect_object(ld, obj) || !require(ld, obj, "type"))
        return;
    int type = get_choice(ld, obj, "type", "deformer type", types, COUNT_OF(types));
    if (type < 0)
        return;
    nacre_deformer d = nacre_deformer_defaults(kinds[type]);
    if (type == 0)
        check_keys(ld, obj, scale_keys, COUNT_OF(scale_keys));
    else if (type == 1)
        check_keys(ld, obj, twist_keys, COUNT_OF(twist_keys));
    else
        check_keys(ld, obj, bend_keys, COUNT_OF(bend_keys));
    get_floats(ld, obj, "center", 3, R_FINITE, false, d.center);
    get_floats(ld, obj, "scale", 3, R_POSITIVE, true, d.scale);
    get_floats(ld, obj, "scale_rate", 3, R_FINITE, true, d.scale_rate);
    get_direction(ld, obj, "axis", true, d.axis);
    get_direction(ld, obj, "direction", true, d.direction);
    get_number(ld, obj, "angle", R_FINITE, &d.angle);
    get_number(ld, obj, "angle_rate", R_FINITE, &d.angle_rate);
    get_number(ld, obj, "length", R_POSITIVE, &d.length);
    if (!ld->err && type == 2 && sin_between(d.axis, d.direction) < 1e-3) {
        size_t mark = push_key(ld, "direction");
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "must not be parallel to axis");
        pop(ld, mark);
    }
    *out = d;
}

static void parse_deformers(loader *ld, const cJSON *arr, nacre_object_desc *d)
{
    size_t mark = push_key(ld, "deformers");
    if (!cJSON_IsArray(arr)) {
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected an array, got %s", type_name(arr));
    } else if (cJSON_GetArraySize(arr) > NACRE_MAX_DEFORMERS) {
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "at most %d deformers per object (got %d)",
             NACRE_MAX_DEFORMERS, cJSON_GetArraySize(arr));
    } else {
        int i = 0;
        for (const cJSON *c = arr->child; c && !ld->err; c = c->next, i++) {
            size_t m2 = push_index(ld, i);
            parse_deformer(ld, c, &d->deformers[i]);
            pop(ld, m2);
        }
        d->deformer_count = (uint32_t)i;
    }
    pop(ld, mark);
}

static void parse_object(loader *ld, const cJSON *obj)
{
    static const char *const keys[] = {"name", "mesh", "shape", "material", "transform",
                                       "deformers", "shadows", "double_sided"};
    if (!expect_object(ld, obj) || !check_keys(ld, obj, keys, COUNT_OF(keys)))
        return;
    nacre_object_desc d = nacre_object_desc_defaults();
    const char *name = get_string(ld, obj, "name");
    const cJSON *mesh = member(obj, "mesh");
    const cJSON *shape = member(obj, "shape");
    if (!ld->err && mesh && shape)
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "give \"mesh\" or \"shape\", not both");
    else if (!ld->err && !mesh && !shape)
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "missing required key \"mesh\" or \"shape\"");
    const char *mesh_path = mesh ? get_string(ld, obj, "mesh") : NULL;
    require(ld, obj, "material");
    const char *material = get_string(ld, obj, "material");
    if (material && !find_material(ld, material, &d.material)) {
        const char *names[8];
        uint32_t n = ld->material_count < 8 ? ld->material_count : 8;
        for (uint32_t i = 0; i < n; i++)
            names[i] = ld->materials[i].name;
        char buf[NAME_SHOWN_MAX + 8], list[512];
        size_t mark = push_key(ld, "material");
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "unknown material \"%s\" (defined: %s%s)",
             shown(material, buf, sizeof(buf)), n ? join_names(names, n, list, sizeof(list)) : "none",
             ld->material_count > n ? ", ..." : "");
        pop(ld, mark);
    }
    const cJSON *transform = member(obj, "transform");
    if (transform)
        parse_transform(ld, transform, &d.transform);
    const cJSON *deformers = member(obj, "deformers");
    if (deformers)
        parse_deformers(ld, deformers, &d);
    get_bool(ld, obj, "shadows", &d.cast_shadows);
    get_bool(ld, obj, "double_sided", &d.double_sided);
    /* Geometry last: every cheap check has passed before a file is read. */
    if (ld->err)
        return;
    if (mesh_path ? !load_mesh(ld, mesh_path, &d.mesh) : !make_shape(ld, shape, &d.mesh))
        return;
    d.name = name;
    nacre_object handle;
    nacre_result r = nacre_scene_add_object(ld->scene, &d, &handle);
    if (r != NACRE_OK)
        fail_inner(ld, r);
}

/* "fog": participating media in open space (nacre_fog_desc). */
static void parse_fog(loader *ld, const cJSON *obj)
{
    static const char *const shapes[] = {"global", "box"};
    static const char *const keys[] = {"shape", "center", "size", "rotate", "sigma_a", "sigma_s", "g",
                                       "height_falloff", "height_base", "pattern"};
    if (!expect_object(ld, obj) || !require(ld, obj, "shape"))
        return;
    int shape = get_choice(ld, obj, "shape", "fog shape", shapes, COUNT_OF(shapes));
    if (shape < 0)
        return;
    nacre_fog_desc d = nacre_fog_desc_defaults(shape == 0 ? NACRE_FOG_GLOBAL : NACRE_FOG_BOX);
    check_keys(ld, obj, keys, COUNT_OF(keys));
    if (shape == 1)
        require(ld, obj, "size");
    if (!ld->err && shape == 0 && member(obj, "size"))
        fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "\"size\" applies to box fogs only");
    static const range g_range = {-1.0, 1.0, true, true};
    get_floats(ld, obj, "center", 3, R_FINITE, false, d.center);
    get_floats(ld, obj, "size", 3, R_POSITIVE, true, d.size);
    get_floats(ld, obj, "rotate", 3, R_FINITE, false, d.rotate);
    get_floats(ld, obj, "sigma_a", 3, R_NONNEG, true, d.sigma_a);
    get_floats(ld, obj, "sigma_s", 3, R_NONNEG, true, d.sigma_s);
    get_number(ld, obj, "g", g_range, &d.g);
    get_number(ld, obj, "height_falloff", R_NONNEG, &d.height_falloff);
    get_number(ld, obj, "height_base", R_FINITE, &d.height_base);
    const cJSON *pattern = member(obj, "pattern");
    if (pattern && !ld->err)
        parse_pattern(ld, pattern, &d.pattern);
    if (ld->err)
        return;
    nacre_fog handle;
    nacre_result r = nacre_scene_add_fog(ld->scene, &d, &handle);
    if (r != NACRE_OK)
        fail_inner(ld, r);
}


/* Sections in dependency order, whatever their order in the file: units scale the presets,
 * materials must exist before objects name them. */
static void parse_scene(loader *ld, const cJSON *root)
{
    static const char *const keys[] = {"units", "render", "camera", "environment", "materials",
                                       "lights", "objects", "fog"};
    if (!cJSON_IsObject(root)) {
        fail(ld, NACRE_ERROR_PARSE, "the top level must be an object, got %s", type_name(root));
        return;
    }
    check_duplicates(ld, root);
    if (!check_keys(ld, root, keys, COUNT_OF(keys)))
        return;
    const cJSON *item;
    if ((item = member(root, "units")))
        parse_units(ld, item);
    if ((item = member(root, "render")))
        parse_render(ld, item);
    if ((item = member(root, "environment")) && !ld->err)
        parse_environment(ld, item);
    if ((item = member(root, "camera")) && !ld->err)
        parse_camera(ld, item);
    if ((item = member(root, "materials")) && !ld->err)
        parse_materials(ld, item);
    if ((item = member(root, "lights")) && !ld->err)
        parse_array(ld, item, "lights", parse_light);
    if ((item = member(root, "objects")) && !ld->err)
        parse_array(ld, item, "objects", parse_object);
    if ((item = member(root, "fog")) && !ld->err)
        parse_array(ld, item, "fog", parse_fog);
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
 * file has reason to hold), so get_string can refuse the string and name its field. Returns the
 * number of escapes changed. */
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
                              nacre_render_settings *settings)
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
    ld.settings = nacre_render_settings_defaults();
    nacre_result r = nacre_scene_create(ctx, &ld.scene);
    if (r != NACRE_OK)
        fail_inner(&ld, r);
    else
        parse_scene(&ld, root);

    for (uint32_t i = 0; i < ld.mesh_count; i++)
        nc_free(ctx, ld.meshes[i].path);
    nc_free(ctx, ld.meshes);
    nc_free(ctx, ld.materials);
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
                                   nacre_render_settings *settings)
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

static nacre_result read_whole_file(nacre_context *ctx, const char *path, char **out, size_t *size)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        int e = errno;
        char reason[128];
        if (strerror_r(e, reason, sizeof(reason)) != 0)
            snprintf(reason, sizeof(reason), "error %d", e);
        return nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot open: %s", path, reason);
    }
    size_t cap = 0, len = 0;
    char *buf = NULL;
    nacre_result r = NACRE_OK;
    for (;;) {
        if (len == cap) {
            size_t grown = cap ? cap * 2 : 16384;
            if (cap >= SCENE_FILE_MAX) {
                r = nc_fail(ctx, NACRE_ERROR_IO, "%s: larger than %u MiB, not a scene file", path,
                            SCENE_FILE_MAX >> 20);
                break;
            }
            char *p = nc_realloc(ctx, buf, len, grown);
            if (!p) {
                r = NACRE_ERROR_OUT_OF_MEMORY;
                break;
            }
            buf = p;
            cap = grown;
        }
        size_t n = fread(buf + len, 1, cap - len, f);
        len += n;
        if (n == 0) {
            if (ferror(f)) {
                int e = errno;
                char reason[128];
                if (strerror_r(e, reason, sizeof(reason)) != 0)
                    snprintf(reason, sizeof(reason), "error %d", e);
                r = nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot read: %s", path, reason);
            }
            break;
        }
    }
    fclose(f);
    if (r != NACRE_OK) {
        nc_free(ctx, buf);
        return r;
    }
    *out = buf;
    *size = len;
    return NACRE_OK;
}

nacre_result nacre_scene_load_file(nacre_context *ctx, const char *path, nacre_scene **out,
                                   nacre_render_settings *settings)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (out)
        *out = NULL;
    if (!out || !path)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "nacre_scene_load_file: %s is NULL",
                       out ? "path" : "out");
    char *text = NULL;
    size_t size = 0;
    nacre_result r = read_whole_file(ctx, path, &text, &size);
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
