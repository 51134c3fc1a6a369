/*
 * json_read.c: the JSON scene loader's generic readers, shared by every section file: the field
 * path that prefixes messages ("objects[2].transform.scale"), message formatting with the sticky
 * first error, structure checks (objects, unknown and duplicate keys, required keys), typed
 * getters with ranges (numbers, integers, float vectors, directions, booleans, strings, named
 * choices), arrays of sections and paths relative to the scene file. The rules they enforce are
 * described in docs/scene-format.md, "Conventions" and "Strictness and error messages". Values
 * pass through unconverted: units are the caller's business.
 */
#define _XOPEN_SOURCE 700 /* realpath (XSI); the build asks for POSIX 2008 only */
#include "io/scene_json_internal.h"

#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------------------------------------------ */
/* Messages and field paths                                                                   */
/* ------------------------------------------------------------------------------------------ */

/* Keys come from the file and may hold newlines or megabytes: keep messages one short line. */
const char *nc_json_shown(const char *s, char *buf, size_t size)
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

void nc_json_fail(loader *ld, nacre_result code, const char *fmt, ...)
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
void nc_json_fail_inner(loader *ld, nacre_result code)
{
    char inner[NC_ERROR_MAX];
    snprintf(inner, sizeof(inner), "%s", nacre_context_last_error(ld->ctx));
    if (code == NACRE_OK)
        code = NACRE_ERROR_INVALID_ARGUMENT;
    nc_json_fail(ld, code, "%s", inner[0] ? inner : nacre_result_string(code));
}

size_t nc_json_push_key(loader *ld, const char *key)
{
    size_t mark = ld->path_len;
    char buf[NAME_SHOWN_MAX + 8];
    size_t room = sizeof(ld->path) - mark;
    int n = snprintf(ld->path + mark, room, "%s%s", mark ? "." : "",
                     nc_json_shown(key, buf, sizeof(buf)));
    ld->path_len = (n < 0 || (size_t)n >= room) ? sizeof(ld->path) - 1 : mark + (size_t)n;
    return mark;
}

size_t nc_json_push_index(loader *ld, int index)
{
    size_t mark = ld->path_len;
    size_t room = sizeof(ld->path) - mark;
    int n = snprintf(ld->path + mark, room, "[%d]", index);
    ld->path_len = (n < 0 || (size_t)n >= room) ? sizeof(ld->path) - 1 : mark + (size_t)n;
    return mark;
}

void nc_json_pop(loader *ld, size_t mark)
{
    ld->path_len = mark;
    ld->path[mark] = '\0';
}

const char *nc_json_type_name(const cJSON *item)
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
const char *nc_json_join_names(const char *const *names, size_t count, char *buf, size_t size)
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
    nc_json_fail(ld, NACRE_ERROR_PARSE, "duplicate key \"%s\"",
                 nc_json_shown(key, buf, sizeof(buf)));
}

/* cJSON keeps every copy of a repeated key and lookups return the first; JSON says the result
 * is undefined, so refuse rather than guess which one the author meant. Small objects compare
 * pairwise; large ones (a long "materials" list) sort a copy of their keys. */
void nc_json_check_duplicates(loader *ld, const cJSON *item)
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
                nc_json_fail_inner(ld, NACRE_ERROR_OUT_OF_MEMORY);
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
        size_t mark =
            cJSON_IsObject(item) ? nc_json_push_key(ld, c->string) : nc_json_push_index(ld, index);
        nc_json_check_duplicates(ld, c);
        nc_json_pop(ld, mark);
    }
}

bool nc_json_expect_object(loader *ld, const cJSON *item)
{
    if (ld->err)
        return false;
    if (!cJSON_IsObject(item)) {
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected an object, got %s",
                     nc_json_type_name(item));
        return false;
    }
    return true;
}

/* Unknown keys are errors so that a typo ("sigma_s " or "colour") cannot silently fall back
 * to a default. Keys starting with '_' are comments. */
bool nc_json_check_keys(loader *ld, const cJSON *obj, const char *const *valid, size_t count)
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
            nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "unknown key \"%s\" (valid keys: %s)",
                         nc_json_shown(c->string, key, sizeof(key)),
                         nc_json_join_names(valid, count, list, sizeof(list)));
            return false;
        }
    }
    return true;
}

const cJSON *nc_json_member(const cJSON *obj, const char *key)
{
    return cJSON_GetObjectItemCaseSensitive(obj, key);
}

bool nc_json_require(loader *ld, const cJSON *obj, const char *key)
{
    if (ld->err)
        return false;
    if (!nc_json_member(obj, key)) {
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "missing required key \"%s\"", key);
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
    nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "%s (got %g)", what, v);
}

bool nc_json_read_number(loader *ld, const cJSON *item, range r, double *out)
{
    if (ld->err)
        return false;
    if (!cJSON_IsNumber(item)) {
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected a number, got %s",
                     nc_json_type_name(item));
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
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected an integer, got %s",
                     nc_json_type_name(item));
        return false;
    }
    double v = item->valuedouble;
    if (!isfinite(v) || v != floor(v) || v < (double)lo || v > (double)hi) {
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "must be an integer in %lld..%lld (got %g)",
                     (long long)lo, (long long)hi, v);
        return false;
    }
    *out = (int64_t)v;
    return true;
}

/* n numbers; a single number fills all n when allow_scalar (grey colours, uniform scales). */
bool nc_json_read_floats(loader *ld, const cJSON *item, int n, range r, bool allow_scalar,
                         float *out)
{
    if (ld->err)
        return false;
    double v;
    if (allow_scalar && cJSON_IsNumber(item)) {
        if (!nc_json_read_number(ld, item, r, &v))
            return false;
        for (int i = 0; i < n; i++)
            out[i] = (float)v;
        return true;
    }
    if (!cJSON_IsArray(item)) {
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected an array of %d numbers%s, got %s",
                     n, allow_scalar ? " or a number" : "", nc_json_type_name(item));
        return false;
    }
    int count = cJSON_GetArraySize(item);
    if (count != n) {
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                     "expected an array of %d numbers, got %d element%s", n, count,
                     count == 1 ? "" : "s");
        return false;
    }
    float tmp[4];
    int i = 0;
    for (const cJSON *c = item->child; c && i < n; c = c->next, i++) {
        size_t mark = nc_json_push_index(ld, i);
        bool ok = nc_json_read_number(ld, c, r, &v);
        nc_json_pop(ld, mark);
        if (!ok)
            return false;
        tmp[i] = (float)v;
    }
    memcpy(out, tmp, (size_t)n * sizeof(float));
    return true;
}

bool nc_json_nonzero3(const float v[3])
{
    /* Squares of tiny components underflow; compare the largest magnitude instead. */
    return fmaxf(fabsf(v[0]), fmaxf(fabsf(v[1]), fabsf(v[2]))) > 1e-20f;
}

static double length3(const float v[3])
{
    return sqrt((double)v[0] * v[0] + (double)v[1] * v[1] + (double)v[2] * v[2]);
}

/* |a x b| / (|a| |b|): 0 for parallel vectors. Both must be nonzero. */
double nc_json_sin_between(const float a[3], const float b[3])
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
            nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                         "unknown axis \"%s\" (valid: \"x\", \"y\", \"z\" or [x, y, z])",
                         nc_json_shown(s, buf, sizeof(buf)));
            return false;
        }
        out[0] = out[1] = out[2] = 0.0f;
        out[axis] = 1.0f;
        return true;
    }
    float v[3];
    if (!cJSON_IsArray(item) && allow_name) {
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT,
                     "expected an array of 3 numbers or \"x\", \"y\", \"z\", got %s",
                     nc_json_type_name(item));
        return false;
    }
    if (!nc_json_read_floats(ld, item, 3, R_FINITE, false, v))
        return false;
    if (!nc_json_nonzero3(v)) {
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "must not be the zero vector");
        return false;
    }
    memcpy(out, v, sizeof(v));
    return true;
}

/* Keyed readers: do nothing (false) when the key is absent, so defaults stay. */

bool nc_json_get_number(loader *ld, const cJSON *obj, const char *key, range r, float *out)
{
    const cJSON *item = nc_json_member(obj, key);
    if (!item || ld->err)
        return false;
    size_t mark = nc_json_push_key(ld, key);
    double v;
    bool ok = nc_json_read_number(ld, item, r, &v);
    nc_json_pop(ld, mark);
    if (ok)
        *out = (float)v;
    return ok;
}

bool nc_json_get_double(loader *ld, const cJSON *obj, const char *key, range r, double *out)
{
    const cJSON *item = nc_json_member(obj, key);
    if (!item || ld->err)
        return false;
    size_t mark = nc_json_push_key(ld, key);
    bool ok = nc_json_read_number(ld, item, r, out);
    nc_json_pop(ld, mark);
    return ok;
}

bool nc_json_get_integer(loader *ld, const cJSON *obj, const char *key, int64_t lo, int64_t hi,
                         int64_t *out)
{
    const cJSON *item = nc_json_member(obj, key);
    if (!item || ld->err)
        return false;
    size_t mark = nc_json_push_key(ld, key);
    bool ok = read_integer(ld, item, lo, hi, out);
    nc_json_pop(ld, mark);
    return ok;
}

bool nc_json_get_floats(loader *ld, const cJSON *obj, const char *key, int n, range r,
                        bool allow_scalar, float *out)
{
    const cJSON *item = nc_json_member(obj, key);
    if (!item || ld->err)
        return false;
    size_t mark = nc_json_push_key(ld, key);
    bool ok = nc_json_read_floats(ld, item, n, r, allow_scalar, out);
    nc_json_pop(ld, mark);
    return ok;
}

bool nc_json_get_direction(loader *ld, const cJSON *obj, const char *key, bool allow_name,
                           float out[3])
{
    const cJSON *item = nc_json_member(obj, key);
    if (!item || ld->err)
        return false;
    size_t mark = nc_json_push_key(ld, key);
    bool ok = read_direction(ld, item, allow_name, out);
    nc_json_pop(ld, mark);
    return ok;
}

bool nc_json_get_bool(loader *ld, const cJSON *obj, const char *key, bool *out)
{
    const cJSON *item = nc_json_member(obj, key);
    if (!item || ld->err)
        return false;
    if (!cJSON_IsBool(item)) {
        size_t mark = nc_json_push_key(ld, key);
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected true or false, got %s",
                     nc_json_type_name(item));
        nc_json_pop(ld, mark);
        return false;
    }
    *out = cJSON_IsTrue(item);
    return true;
}

/* A non-empty string, or NULL (absent or error). */
const char *nc_json_get_string(loader *ld, const cJSON *obj, const char *key)
{
    const cJSON *item = nc_json_member(obj, key);
    if (!item || ld->err)
        return NULL;
    size_t mark = nc_json_push_key(ld, key);
    const char *s = NULL;
    if (!cJSON_IsString(item) || !item->valuestring)
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected a string, got %s",
                     nc_json_type_name(item));
    else if (ld->nul_escapes && strchr(item->valuestring, '\x01'))
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "contains \\u0000 (a NUL character, which no path or name can hold)");
    else if (item->valuestring[0] == '\0')
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "must not be empty");
    else
        s = item->valuestring;
    nc_json_pop(ld, mark);
    return s;
}

/* Index of `s` in names[], or -1 after reporting an error that lists the valid names. */
int nc_json_get_choice(loader *ld, const cJSON *obj, const char *key, const char *what,
                       const char *const *names, size_t count)
{
    const char *s = nc_json_get_string(ld, obj, key);
    if (!s)
        return -1;
    for (size_t i = 0; i < count; i++)
        if (strcmp(s, names[i]) == 0)
            return (int)i;
    char buf[NAME_SHOWN_MAX + 8], list[512];
    size_t mark = nc_json_push_key(ld, key);
    nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "unknown %s \"%s\" (valid: %s)", what,
                 nc_json_shown(s, buf, sizeof(buf)),
                 nc_json_join_names(names, count, list, sizeof(list)));
    nc_json_pop(ld, mark);
    return -1;
}
/* Walk a JSON array whose elements are parsed by `parse_element`, with the key and index on the
 * field path for messages ("lights[2].type"). */
void nc_json_parse_array(loader *ld, const cJSON *arr, const char *key,
                         void (*parse_element)(loader *, const cJSON *))
{
    size_t mark = nc_json_push_key(ld, key);
    if (!cJSON_IsArray(arr)) {
        nc_json_fail(ld, NACRE_ERROR_INVALID_ARGUMENT, "expected an array, got %s",
                     nc_json_type_name(arr));
    } else {
        int i = 0;
        for (const cJSON *c = arr->child; c && !ld->err; c = c->next, i++) {
            size_t m2 = nc_json_push_index(ld, i);
            parse_element(ld, c);
            nc_json_pop(ld, m2);
        }
    }
    nc_json_pop(ld, mark);
}
char *nc_json_resolve_path(loader *ld, const char *rel)
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

char *nc_absolute_path(nacre_context *ctx, const char *path)
{
    /* realpath allocates with malloc; the copy goes through the context like everything else. */
    char *real = realpath(path, NULL);
    char *copy = nc_strdup(ctx, real ? real : path);
    free(real);
    return copy;
}
