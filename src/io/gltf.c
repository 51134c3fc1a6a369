/*
 * gltf.c: glTF 2.0 scenes (Khronos glTF 2.0 specification; KHR_lights_punctual and the
 * KHR_materials_* extensions named below). Meshes come through assimp (nc_mesh_load_parts: one
 * part per node x primitive, node transform applied); what assimp does not expose reliably
 * (materials with their extensions, punctual lights in glTF's photometric units, cameras by
 * name, extensionsRequired) is read from the file's own JSON with cJSON, for a .glb from the
 * JSON chunk of its container. Nothing here reads vertex data; the PNG images of base colour
 * textures are read here (from a file, a data: URI or a buffer view) and decoded by io/.
 *
 * Before assimp sees the file, its structure is checked against the JSON: the GLB header and
 * chunk lengths against the file size, every buffer against its byteLength (GLB chunk, external
 * file or data: URI), every buffer view against its buffer and every accessor against its view,
 * node indices, and the node graph (a forest: no node has two parents). assimp 5.2 trusts some of
 * these and reads out of bounds on a broken file.
 *
 * Conventions: glTF lengths are metres, +y up, a camera and a light look down their node's -z.
 * The scene is in metres unless options->unit_mm says otherwise, in which case positions,
 * lengths and coefficients are converted. Photometric units become radiometric ones at the
 * luminous efficacy 683 lm/W: directional lux -> irradiance W/m^2 = lux / 683; point and spot
 * candela -> intensity W/sr = cd / 683 (the colour multiplies both). The material mapping is
 * documented in docs/scene-format.md ("glTF 2.0 scenes").
 */
#include "io/gltf.h"
#include "io/image_private.h"
#include "io/scene_json_internal.h"

#include "core/math.h"
#include "scene/mesh_private.h"
#include "scene/scene.h"

#include <cjson/cJSON.h>

#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#define GLB_MAGIC 0x46546C67u      /* "glTF" */
#define GLB_CHUNK_JSON 0x4E4F534Au /* "JSON" */
#define GLB_CHUNK_BIN 0x004E4942u  /* "BIN\0" */
#define GLTF_JSON_MAX (256u << 20) /* a .gltf with its data: URIs, or a GLB's JSON chunk */
#define GLTF_MAX_NODE_DEPTH 1024
#define LUMENS_PER_WATT 683.0f
#define GLTF_PI 3.14159265358979f
/* glTF has no scattering coefficient; the default for translucent materials, per millimetre
 * (the order of the measured materials of nacre's presets, which have sigma_s' 0.5..2.7/mm). */
#define GLTF_SIGMA_S_PER_MM 1.0f
/* With options->thickness_layer, the scattering left in the core under the thickness layer, as a
 * part of the layer's: a positive extinction that the diffusion method can still solve for. */
#define GLTF_CORE_SCATTERING 0.01f

/* Extensions nacre maps; a file may require any of these. */
static const char *const mapped_extensions[] = {
    "KHR_lights_punctual",        "KHR_materials_volume",   "KHR_materials_transmission",
    "KHR_materials_ior",          "KHR_materials_diffuse_transmission", "KHR_materials_specular",
};

typedef struct gltf_state {
    nacre_context *ctx;
    nacre_scene *scene;
    const char *path;
    const nacre_gltf_options *opt;
    nacre_gltf_report *report;
    cJSON *root;
    float scale;        /* scene units per metre */
    bool glb;
    uint64_t bin_length; /* GLB BIN chunk, 0 if none */
    uint64_t bin_offset; /* where its bytes start in the file */
    nacre_texture *image_textures; /* per glTF image: its scene texture once read (id 0: not yet) */
    int image_count;
    int node_count;
    nc_mat4 *world;     /* per node; valid where `reached` */
    bool *reached;
    /* Nodes in assimp's preorder (its root first, children in order): -1 for the root assimp
     * makes when the scene has several root nodes. Maps nc_mesh_part.node to a glTF node. */
    int *order;
    int order_count;
} gltf_state;

bool nc_gltf_is_path(const char *path)
{
    size_t n = path ? strlen(path) : 0;
    const char *exts[] = {".gltf", ".glb"};
    for (int k = 0; k < 2; k++) {
        size_t e = strlen(exts[k]);
        if (n < e)
            continue;
        bool same = true;
        for (size_t i = 0; i < e && same; i++)
            same = (path[n - e + i] | 0x20) == exts[k][i];
        if (same)
            return true;
    }
    return false;
}

/* ------------------------------------------------------------------------------------------ */
/* Reading the JSON                                                                           */
/* ------------------------------------------------------------------------------------------ */

static uint32_t le32(const unsigned char *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static nacre_result read_bytes(gltf_state *g, FILE *f, void *dst, size_t n)
{
    if (fread(dst, 1, n, f) != n)
        return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: cannot read %zu bytes (truncated file?)", g->path, n);
    return NACRE_OK;
}

/* The JSON text: the whole .gltf, or a GLB's JSON chunk after the container is checked. */
static nacre_result read_json(gltf_state *g, char **text_out, size_t *len_out)
{
    FILE *f = fopen(g->path, "rb");
    if (!f)
        return nc_fail(g->ctx, NACRE_ERROR_IO, "%s: cannot open: %s", g->path, strerror(errno));
    struct stat st;
    if (fstat(fileno(f), &st) != 0 || S_ISDIR(st.st_mode)) {
        fclose(f);
        return nc_fail(g->ctx, NACRE_ERROR_IO, "%s: not a regular file", g->path);
    }
    uint64_t size = (uint64_t)st.st_size;
    unsigned char head[20];
    size_t got = fread(head, 1, sizeof(head), f);
    nacre_result r = NACRE_OK;
    uint64_t offset = 0, length = size;
    g->glb = got >= 4 && le32(head) == GLB_MAGIC;
    if (g->glb) {
        if (got < 20) {
            r = nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: truncated GLB: %llu bytes, the header needs 20", g->path,
                        (unsigned long long)size);
        } else if (le32(head + 4) != 2) {
            r = nc_fail(g->ctx, NACRE_ERROR_UNSUPPORTED, "%s: GLB version %u (nacre reads version 2)", g->path,
                        le32(head + 4));
        } else if (le32(head + 8) != size) {
            r = nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: %s GLB: the header says %u bytes, the file has %llu",
                        g->path, le32(head + 8) > size ? "truncated" : "malformed", le32(head + 8),
                        (unsigned long long)size);
        } else if (le32(head + 16) != GLB_CHUNK_JSON) {
            r = nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: GLB: the first chunk is not JSON", g->path);
        } else if ((uint64_t)le32(head + 12) + 20 > size) {
            r = nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: truncated GLB: the JSON chunk of %u bytes ends past the file",
                        g->path, le32(head + 12));
        } else {
            offset = 20;
            length = le32(head + 12);
            uint64_t next = (offset + length + 3) & ~(uint64_t)3;
            if (next + 8 <= size) {
                unsigned char ch[8];
                if (fseek(f, (long)next, SEEK_SET) != 0 || (r = read_bytes(g, f, ch, 8)) != NACRE_OK) {
                    if (r == NACRE_OK)
                        r = nc_fail(g->ctx, NACRE_ERROR_IO, "%s: cannot seek", g->path);
                } else if (le32(ch + 4) == GLB_CHUNK_BIN) {
                    if (next + 8 + le32(ch) > size)
                        r = nc_fail(g->ctx, NACRE_ERROR_PARSE,
                                    "%s: truncated GLB: the BIN chunk of %u bytes ends past the file", g->path,
                                    le32(ch));
                    g->bin_length = le32(ch);
                    g->bin_offset = next + 8;
                }
            } else if (next < size && next + 8 > size) {
                r = nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: truncated GLB: a partial chunk header at its end",
                            g->path);
            }
        }
    }
    if (r == NACRE_OK && length > GLTF_JSON_MAX)
        r = nc_fail(g->ctx, NACRE_ERROR_UNSUPPORTED, "%s: JSON of %llu bytes (at most %u MiB)", g->path,
                    (unsigned long long)length, GLTF_JSON_MAX >> 20);
    if (r == NACRE_OK && length == 0)
        r = nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: empty file", g->path);
    char *text = NULL;
    if (r == NACRE_OK) {
        text = nc_alloc(g->ctx, (size_t)length + 1);
        if (!text)
            r = NACRE_ERROR_OUT_OF_MEMORY;
        else if (fseek(f, (long)offset, SEEK_SET) != 0)
            r = nc_fail(g->ctx, NACRE_ERROR_IO, "%s: cannot seek", g->path);
        else
            r = read_bytes(g, f, text, (size_t)length);
    }
    fclose(f);
    if (r != NACRE_OK) {
        nc_free(g->ctx, text);
        return r;
    }
    text[length] = '\0';
    *text_out = text;
    *len_out = (size_t)length;
    return NACRE_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* Structure checks                                                                           */
/* ------------------------------------------------------------------------------------------ */

static const cJSON *get(const cJSON *obj, const char *key)
{
    return cJSON_IsObject(obj) ? cJSON_GetObjectItemCaseSensitive(obj, key) : NULL;
}

static int array_size(const cJSON *a) { return cJSON_IsArray(a) ? cJSON_GetArraySize(a) : 0; }

/* An integer member in [lo, hi]; *out = def when absent. False (after an error naming
 * what.key) when present but not such an integer. */
static bool get_index(gltf_state *g, const cJSON *obj, const char *key, double lo, double hi, double def,
                      const char *what, int where, double *out)
{
    const cJSON *v = get(obj, key);
    *out = def;
    if (!v)
        return true;
    if (!cJSON_IsNumber(v) || v->valuedouble != floor(v->valuedouble) || v->valuedouble < lo ||
        v->valuedouble > hi) {
        char buf[64];
        if (cJSON_IsNumber(v))
            snprintf(buf, sizeof(buf), "%.17g", v->valuedouble);
        else
            snprintf(buf, sizeof(buf), "not a number");
        nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: %s[%d].%s: %s is out of range (%.0f..%.0f)", g->path, what, where,
                key, buf, lo, hi);
        return false;
    }
    *out = v->valuedouble;
    return true;
}

static nacre_result fail_r(gltf_state *g) { return nacre_context_last_result(g->ctx); }

static bool nonempty_string(const cJSON *v) { return cJSON_IsString(v) && v->valuestring && v->valuestring[0]; }

/* Decoded size of a base64 data: URI, or -1 when the URI is not base64. */
static long long data_uri_size(const char *uri)
{
    const char *comma = strchr(uri, ',');
    if (!comma || comma - uri < 7 || memcmp(comma - 7, ";base64", 7) != 0)
        return -1;
    size_t n = strlen(comma + 1);
    size_t pad = 0;
    while (pad < 2 && n > pad && comma[1 + n - 1 - pad] == '=')
        pad++;
    return (long long)(n / 4 * 3 + (n % 4 ? n % 4 - 1 : 0)) - (long long)(n % 4 ? 0 : pad);
}

static nacre_result check_buffers(gltf_state *g, double **lengths_out, int *count_out)
{
    const cJSON *buffers = get(g->root, "buffers");
    int nb = array_size(buffers);
    double *len = nc_calloc(g->ctx, (size_t)(nb > 0 ? nb : 1), sizeof(double));
    if (!len)
        return NACRE_ERROR_OUT_OF_MEMORY;
    *lengths_out = len;
    *count_out = nb;
    char *dir = NULL;
    const char *slash = strrchr(g->path, '/');
    size_t dir_len = slash ? (size_t)(slash - g->path) + 1 : 0;
    for (int i = 0; i < nb; i++) {
        const cJSON *b = cJSON_GetArrayItem(buffers, i);
        double bl;
        if (!get(b, "byteLength"))
            return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: buffers[%d]: missing byteLength", g->path, i);
        if (!get_index(g, b, "byteLength", 1, 9007199254740992.0, 0, "buffers", i, &bl))
            return fail_r(g);
        len[i] = bl;
        const cJSON *uri = get(b, "uri");
        if (!uri) {
            if (!g->glb || i != 0)
                return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: buffers[%d]: no uri (only a GLB's first buffer may omit it)",
                               g->path, i);
            if (g->bin_length < bl)
                return nc_fail(g->ctx, NACRE_ERROR_PARSE,
                               "%s: buffers[0]: byteLength %.0f, but the GLB's BIN chunk has %llu bytes", g->path, bl,
                               (unsigned long long)g->bin_length);
            continue;
        }
        if (!nonempty_string(uri))
            return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: buffers[%d].uri: not a string", g->path, i);
        const char *u = uri->valuestring;
        if (strncmp(u, "data:", 5) == 0) {
            long long n = data_uri_size(u);
            if (n < 0)
                return nc_fail(g->ctx, NACRE_ERROR_UNSUPPORTED, "%s: buffers[%d].uri: a data: URI that is not base64",
                               g->path, i);
            if ((double)n < bl)
                return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: buffers[%d]: byteLength %.0f, but its data: URI holds %lld bytes",
                               g->path, i, bl, n);
            continue;
        }
        if (strstr(u, "://") || strchr(u, '%'))
            return nc_fail(g->ctx, NACRE_ERROR_UNSUPPORTED, "%s: buffers[%d].uri: \"%.64s\": only relative file names are read",
                           g->path, i, u);
        size_t n = strlen(u);
        dir = nc_alloc(g->ctx, dir_len + n + 1);
        if (!dir)
            return NACRE_ERROR_OUT_OF_MEMORY;
        memcpy(dir, g->path, dir_len);
        memcpy(dir + dir_len, u, n + 1);
        struct stat st;
        int e = stat(dir, &st) == 0 ? 0 : errno;
        nc_free(g->ctx, dir);
        if (e != 0)
            return nc_fail(g->ctx, NACRE_ERROR_IO, "%s: buffers[%d]: cannot open \"%.64s\": %s", g->path, i, u,
                           strerror(e));
        if ((double)st.st_size < bl)
            return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: buffers[%d]: byteLength %.0f, but \"%.64s\" has %lld bytes",
                           g->path, i, bl, u, (long long)st.st_size);
    }
    return NACRE_OK;
}

static int component_size(int type)
{
    switch (type) {
    case 5120: case 5121: return 1;
    case 5122: case 5123: return 2;
    case 5125: case 5126: return 4;
    default: return 0;
    }
}

static int type_components(const char *t)
{
    static const struct { const char *name; int n; } types[] = {
        {"SCALAR", 1}, {"VEC2", 2}, {"VEC3", 3}, {"VEC4", 4}, {"MAT2", 4}, {"MAT3", 9}, {"MAT4", 16}};
    for (size_t i = 0; t && i < sizeof(types) / sizeof(types[0]); i++)
        if (strcmp(t, types[i].name) == 0)
            return types[i].n;
    return 0;
}

static nacre_result check_views_accessors(gltf_state *g, const double *buffer_len, int nb)
{
    const cJSON *views = get(g->root, "bufferViews");
    int nv = array_size(views);
    for (int i = 0; i < nv; i++) {
        const cJSON *v = cJSON_GetArrayItem(views, i);
        double buf, off, len, stride;
        if (!get(v, "buffer") || !get(v, "byteLength"))
            return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: bufferViews[%d]: missing %s", g->path, i,
                           get(v, "buffer") ? "byteLength" : "buffer");
        if (!get_index(g, v, "buffer", 0, nb - 1, 0, "bufferViews", i, &buf) ||
            !get_index(g, v, "byteOffset", 0, 9007199254740992.0, 0, "bufferViews", i, &off) ||
            !get_index(g, v, "byteLength", 1, 9007199254740992.0, 0, "bufferViews", i, &len) ||
            !get_index(g, v, "byteStride", 4, 252, 0, "bufferViews", i, &stride))
            return fail_r(g);
        if (off + len > buffer_len[(int)buf])
            return nc_fail(g->ctx, NACRE_ERROR_PARSE,
                           "%s: bufferViews[%d]: bytes %.0f..%.0f out of range (buffers[%d] has %.0f)", g->path, i, off,
                           off + len, (int)buf, buffer_len[(int)buf]);
    }
    const cJSON *accessors = get(g->root, "accessors");
    int na = array_size(accessors);
    for (int i = 0; i < na; i++) {
        const cJSON *a = cJSON_GetArrayItem(accessors, i);
        double view, off, count, ctype;
        const cJSON *type = get(a, "type");
        if (!get(a, "count") || !get(a, "componentType") || !cJSON_IsString(type))
            return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: accessors[%d]: missing count, componentType or type",
                           g->path, i);
        if (!get_index(g, a, "bufferView", 0, nv - 1, -1, "accessors", i, &view) ||
            !get_index(g, a, "byteOffset", 0, 9007199254740992.0, 0, "accessors", i, &off) ||
            !get_index(g, a, "count", 1, 4294967295.0, 0, "accessors", i, &count) ||
            !get_index(g, a, "componentType", 5120, 5126, 0, "accessors", i, &ctype))
            return fail_r(g);
        int cs = component_size((int)ctype), nc = type_components(type->valuestring);
        if (cs == 0 || nc == 0)
            return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: accessors[%d]: unknown %s", g->path, i,
                           cs == 0 ? "componentType" : "type");
        if (get(a, "sparse"))
            return nc_fail(g->ctx, NACRE_ERROR_UNSUPPORTED, "%s: accessors[%d]: sparse accessors are not supported",
                           g->path, i);
        if (view < 0)
            continue; /* all zeros */
        const cJSON *v = cJSON_GetArrayItem(views, (int)view);
        double vlen = get(v, "byteLength")->valuedouble, stride = 0;
        get_index(g, v, "byteStride", 4, 252, 0, "bufferViews", (int)view, &stride);
        double elem = (double)cs * nc;
        if (stride == 0)
            stride = elem;
        double need = off + (count - 1) * stride + elem;
        if (need > vlen)
            return nc_fail(g->ctx, NACRE_ERROR_PARSE,
                           "%s: accessors[%d]: %.0f elements need %.0f bytes of bufferViews[%d], which has %.0f",
                           g->path, i, count, need, (int)view, vlen);
    }
    /* Primitives: attribute and index accessors, materials. */
    const cJSON *meshes = get(g->root, "meshes");
    int nm = array_size(meshes), nmat = array_size(get(g->root, "materials"));
    for (int i = 0; i < nm; i++) {
        const cJSON *prims = get(cJSON_GetArrayItem(meshes, i), "primitives");
        int np = array_size(prims);
        if (np == 0)
            return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: meshes[%d]: no primitives", g->path, i);
        g->report->primitives += (uint32_t)np;
        for (int k = 0; k < np; k++) {
            const cJSON *p = cJSON_GetArrayItem(prims, k);
            const cJSON *attrs = get(p, "attributes");
            char what[96];
            snprintf(what, sizeof(what), "meshes[%d].primitives", i);
            double idx;
            if (!get(attrs, "POSITION"))
                return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: %s[%d]: no POSITION attribute", g->path, what, k);
            if (!get_index(g, p, "indices", 0, na - 1, 0, what, k, &idx) ||
                !get_index(g, p, "material", 0, nmat - 1, 0, what, k, &idx))
                return fail_r(g);
            for (const cJSON *at = attrs->child; at; at = at->next) {
                snprintf(what, sizeof(what), "meshes[%d].primitives[%d].attributes", i, k);
                if (!cJSON_IsNumber(at) || at->valuedouble != floor(at->valuedouble) || at->valuedouble < 0 ||
                    at->valuedouble >= na)
                    return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: %s.%s: accessor %.17g out of range (%d accessors)",
                                   g->path, what, at->string ? at->string : "?",
                                   cJSON_IsNumber(at) ? at->valuedouble : -1.0, na);
            }
        }
    }
    return NACRE_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* Nodes                                                                                      */
/* ------------------------------------------------------------------------------------------ */

static bool read_floats(const cJSON *a, int n, float *out)
{
    if (array_size(a) != n)
        return false;
    int i = 0;
    for (const cJSON *c = a->child; c; c = c->next, i++) {
        if (!cJSON_IsNumber(c) || !isfinite(c->valuedouble))
            return false;
        out[i] = (float)c->valuedouble;
    }
    return true;
}

/* A node's local matrix: "matrix" (column-major) or translation * rotation * scale. */
static bool local_matrix(const cJSON *node, nc_mat4 *out)
{
    nc_mat4 m = nc_mat4_identity();
    const cJSON *mat = get(node, "matrix");
    if (mat) {
        float v[16];
        if (!read_floats(mat, 16, v))
            return false;
        for (int c = 0; c < 4; c++)
            for (int r = 0; r < 4; r++)
                m.m[r][c] = v[c * 4 + r];
        *out = m;
        return true;
    }
    float t[3] = {0, 0, 0}, q[4] = {0, 0, 0, 1}, s[3] = {1, 1, 1};
    if ((get(node, "translation") && !read_floats(get(node, "translation"), 3, t)) ||
        (get(node, "rotation") && !read_floats(get(node, "rotation"), 4, q)) ||
        (get(node, "scale") && !read_floats(get(node, "scale"), 3, s)))
        return false;
    float len = sqrtf(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (!(len > 0.0f))
        return false;
    float x = q[0] / len, y = q[1] / len, z = q[2] / len, w = q[3] / len;
    float r[3][3] = {{1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)},
                     {2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)},
                     {2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)}};
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++)
            m.m[i][j] = r[i][j] * s[j];
        m.m[i][3] = t[i];
    }
    *out = m;
    return true;
}

static nacre_result walk_nodes(gltf_state *g, int index, nc_mat4 parent, int depth)
{
    const cJSON *nodes = get(g->root, "nodes");
    if (depth > GLTF_MAX_NODE_DEPTH)
        return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: node hierarchy deeper than %d", g->path, GLTF_MAX_NODE_DEPTH);
    if (g->reached[index])
        return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: nodes[%d] is reached twice (the nodes must form a tree)",
                       g->path, index);
    const cJSON *node = cJSON_GetArrayItem(nodes, index);
    nc_mat4 local;
    if (!local_matrix(node, &local))
        return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: nodes[%d]: malformed matrix, translation, rotation or scale",
                       g->path, index);
    g->world[index] = nc_mat4_mul(parent, local);
    g->reached[index] = true;
    g->order[g->order_count++] = index;
    const cJSON *children = get(node, "children");
    int i = 0;
    for (const cJSON *c = children ? children->child : NULL; c; c = c->next, i++) {
        double ci;
        char what[40];
        snprintf(what, sizeof(what), "nodes[%d].children", index);
        if (!cJSON_IsNumber(c) || c->valuedouble != floor(c->valuedouble) || c->valuedouble < 0 ||
            c->valuedouble >= g->node_count)
            return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: %s[%d]: node out of range (%d nodes)", g->path, what, i,
                           g->node_count);
        ci = c->valuedouble;
        nacre_result r = walk_nodes(g, (int)ci, g->world[index], depth + 1);
        if (r != NACRE_OK)
            return r;
    }
    return NACRE_OK;
}

/* World matrices of the nodes of the default scene (or the first, or every root node). */
static nacre_result compute_world(gltf_state *g)
{
    const cJSON *nodes = get(g->root, "nodes");
    g->node_count = array_size(nodes);
    if (g->node_count == 0)
        return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: no nodes", g->path);
    g->world = nc_calloc(g->ctx, (size_t)g->node_count, sizeof(*g->world));
    g->reached = nc_calloc(g->ctx, (size_t)g->node_count, sizeof(*g->reached));
    g->order = nc_calloc(g->ctx, (size_t)g->node_count + 1, sizeof(*g->order));
    if (!g->world || !g->reached || !g->order)
        return NACRE_ERROR_OUT_OF_MEMORY;
    int nmesh = array_size(get(g->root, "meshes")), ncam = array_size(get(g->root, "cameras"));
    for (int i = 0; i < g->node_count; i++) {
        const cJSON *n = cJSON_GetArrayItem(nodes, i);
        double v;
        if (!get_index(g, n, "mesh", 0, nmesh - 1, 0, "nodes", i, &v) ||
            !get_index(g, n, "camera", 0, ncam - 1, 0, "nodes", i, &v))
            return fail_r(g);
    }
    const cJSON *scenes = get(g->root, "scenes");
    double si = 0;
    if (!get_index(g, g->root, "scene", 0, array_size(scenes) - 1, 0, "", 0, &si))
        return fail_r(g);
    const cJSON *roots = get(cJSON_GetArrayItem(scenes, (int)si), "nodes");
    if (array_size(roots) != 1)
        g->order[g->order_count++] = -1;
    int i = 0;
    for (const cJSON *c = roots ? roots->child : NULL; c; c = c->next, i++) {
        if (!cJSON_IsNumber(c) || c->valuedouble != floor(c->valuedouble) || c->valuedouble < 0 ||
            c->valuedouble >= g->node_count)
            return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: scenes[%d].nodes[%d]: node out of range (%d nodes)",
                           g->path, (int)si, i, g->node_count);
        nacre_result r = walk_nodes(g, (int)c->valuedouble, nc_mat4_identity(), 0);
        if (r != NACRE_OK)
            return r;
    }
    return NACRE_OK;
}

static nc_vec3 node_position(const gltf_state *g, int node)
{
    return nc_scale(nc_mat4_point(&g->world[node], nc_v3(0, 0, 0)), g->scale);
}

static nc_vec3 node_axis(const gltf_state *g, int node, nc_vec3 local)
{
    return nc_normalize(nc_mat4_dir(&g->world[node], local));
}

/* ------------------------------------------------------------------------------------------ */
/* Extensions, materials, lights, camera                                                      */
/* ------------------------------------------------------------------------------------------ */

static bool is_mapped(const char *name)
{
    for (size_t i = 0; i < sizeof(mapped_extensions) / sizeof(mapped_extensions[0]); i++)
        if (strcmp(name, mapped_extensions[i]) == 0)
            return true;
    return false;
}

static void copy_name(char dst[NACRE_GLTF_NAME_MAX], const char *src)
{
    snprintf(dst, NACRE_GLTF_NAME_MAX, "%s", src);
}

static nacre_result check_extensions(gltf_state *g)
{
    nacre_gltf_report *rep = g->report;
    const cJSON *req = get(g->root, "extensionsRequired");
    for (const cJSON *c = req ? req->child : NULL; c; c = c->next)
        if (!cJSON_IsString(c) || !is_mapped(c->valuestring))
            return nc_fail(g->ctx, NACRE_ERROR_UNSUPPORTED,
                           "%s: extensionsRequired: \"%.64s\" is not supported (nacre maps KHR_lights_punctual, "
                           "KHR_materials_volume, _transmission, _ior, _diffuse_transmission, _specular)",
                           g->path, cJSON_IsString(c) ? c->valuestring : "?");
    const cJSON *used = get(g->root, "extensionsUsed");
    for (const cJSON *c = used ? used->child : NULL; c; c = c->next) {
        if (!cJSON_IsString(c))
            continue;
        if (is_mapped(c->valuestring)) {
            if (rep->mapped_count < NACRE_GLTF_REPORT_MAX)
                copy_name(rep->mapped[rep->mapped_count++], c->valuestring);
        } else {
            if (rep->ignored_count < NACRE_GLTF_REPORT_MAX)
                copy_name(rep->ignored[rep->ignored_count++], c->valuestring);
            nc_warn(g->ctx, "%s: extension %s is not supported and was ignored", g->path, c->valuestring);
        }
    }
    return NACRE_OK;
}

static float num(const cJSON *obj, const char *key, float def)
{
    const cJSON *v = get(obj, key);
    return cJSON_IsNumber(v) && isfinite(v->valuedouble) ? (float)v->valuedouble : def;
}

static void floats_or(const cJSON *obj, const char *key, int n, float *out)
{
    float v[4];
    if (read_floats(get(obj, key), n, v))
        memcpy(out, v, (size_t)n * sizeof(float));
}

static float clampf(float v, float lo, float hi) { return v < lo ? lo : v > hi ? hi : v; }

/* One glTF material as a nacre desc (docs/scene-format.md, "glTF 2.0 scenes"). */
static nacre_material_desc map_material(const gltf_state *g, const cJSON *m, bool *translucent)
{
    const cJSON *pbr = get(m, "pbrMetallicRoughness");
    const cJSON *ext = get(m, "extensions");
    const cJSON *vol = get(ext, "KHR_materials_volume"), *tr = get(ext, "KHR_materials_transmission");
    const cJSON *dt = get(ext, "KHR_materials_diffuse_transmission"), *sp = get(ext, "KHR_materials_specular");
    const cJSON *ior_ext = get(ext, "KHR_materials_ior");
    float base[4] = {1, 1, 1, 1};
    floats_or(pbr, "baseColorFactor", 4, base);
    float metallic = clampf(num(pbr, "metallicFactor", 1.0f), 0, 1);
    float rough = clampf(num(pbr, "roughnessFactor", 1.0f), 0, 1);
    float ior = num(ior_ext, "ior", 1.5f);
    float eta = clampf(ior, (float)NACRE_ETA_MIN, (float)NACRE_ETA_MAX);
    float f0 = (eta - 1.0f) / (eta + 1.0f);
    f0 *= f0;
    float spec_color[3] = {1, 1, 1};
    floats_or(sp, "specularColorFactor", 3, spec_color);
    float spec_factor = clampf(num(sp, "specularFactor", 1.0f), 0, 1);
    float transmission = clampf(num(tr, "transmissionFactor", 0.0f), 0, 1);
    float diffuse_tr = clampf(num(dt, "diffuseTransmissionFactor", 0.0f), 0, 1);
    float thickness = num(vol, "thicknessFactor", 0.0f);
    *translucent = vol && (thickness > 0.0f || get(vol, "thicknessTexture")) &&
                   (transmission > 0.0f || diffuse_tr > 0.0f);

    nacre_material_desc d = nacre_material_desc_defaults(*translucent ? NACRE_MATERIAL_TRANSLUCENT
                                                                      : NACRE_MATERIAL_OPAQUE);
    /* Blinn-Phong exponent of the same width as GGX of alpha = roughness^2 (2 / alpha^2 - 2). */
    float alpha = rough * rough;
    d.shininess = alpha * alpha > 2.0f / 10002.0f ? 2.0f / (alpha * alpha) - 2.0f : 10000.0f;
    for (int c = 0; c < 3; c++) {
        float b = clampf(base[c], 0, 1);
        float dielectric = fminf(f0 * clampf(spec_color[c], 0, FLT_MAX), 1.0f) * spec_factor;
        d.diffuse[c] = b * (1.0f - metallic);
        d.specular[c] = clampf(dielectric * (1.0f - metallic) + b * metallic, 0, 1);
    }
    if (!*translucent)
        return d;
    float color[3] = {1, 1, 1};
    floats_or(vol, "attenuationColor", 3, color);
    float dist = num(vol, "attenuationDistance", INFINITY) * g->scale; /* scene units */
    for (int c = 0; c < 3; c++) {
        float a = clampf(color[c], 1e-6f, 1.0f);
        d.sigma_a[c] = isfinite(dist) && dist > 0.0f ? -logf(a) / dist : 0.0f;
        d.sigma_s[c] = GLTF_SIGMA_S_PER_MM * (1000.0f / g->scale); /* per mm -> per scene unit */
    }
    d.g = 0.0f;
    d.eta = eta;
    return d;
}

/* ------------------------------------------------------------------------------------------ */
/* Base colour textures                                                                       */
/* ------------------------------------------------------------------------------------------ */

static int base64_value(char c)
{
    if (c >= 'A' && c <= 'Z')
        return c - 'A';
    if (c >= 'a' && c <= 'z')
        return c - 'a' + 26;
    if (c >= '0' && c <= '9')
        return c - '0' + 52;
    return c == '+' ? 62 : c == '/' ? 63 : -1;
}

/* The bytes of a base64 data: URI (checked by data_uri_size for buffers; images are checked
 * here), allocated; NULL with *size 0 if it is not base64. */
static unsigned char *data_uri_bytes(gltf_state *g, const char *uri, size_t *size)
{
    *size = 0;
    const char *comma = strchr(uri, ',');
    if (!comma || comma - uri < 7 || memcmp(comma - 7, ";base64", 7) != 0)
        return NULL;
    const char *p = comma + 1;
    size_t n = strlen(p);
    unsigned char *out = nc_alloc(g->ctx, n / 4 * 3 + 3);
    if (!out)
        return NULL;
    uint32_t acc = 0;
    int bits = 0;
    for (size_t i = 0; i < n && p[i] != '='; i++) {
        int v = base64_value(p[i]);
        if (v < 0) {
            nc_free(g->ctx, out);
            return NULL;
        }
        acc = (acc << 6) | (uint32_t)v;
        bits += 6;
        if (bits >= 8) {
            bits -= 8;
            out[(*size)++] = (unsigned char)(acc >> bits);
        }
    }
    return out;
}

/* Bytes [offset, offset + len) of a file, allocated. */
static unsigned char *file_bytes(gltf_state *g, const char *path, uint64_t offset, uint64_t len)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        nc_fail(g->ctx, NACRE_ERROR_IO, "%s: cannot open: %s", path, strerror(errno));
        return NULL;
    }
    unsigned char *b = len > 0 && len < ((uint64_t)1 << 31) ? nc_alloc(g->ctx, (size_t)len) : NULL;
    if (b && (fseek(f, (long)offset, SEEK_SET) != 0 || fread(b, 1, (size_t)len, f) != (size_t)len)) {
        nc_fail(g->ctx, NACRE_ERROR_IO, "%s: cannot read %llu bytes at %llu", path, (unsigned long long)len,
                (unsigned long long)offset);
        nc_free(g->ctx, b);
        b = NULL;
    }
    fclose(f);
    return b;
}

/* A file name relative to the glTF's folder, allocated. */
static char *sibling_path(gltf_state *g, const char *name)
{
    const char *slash = strrchr(g->path, '/');
    size_t dir_len = slash ? (size_t)(slash - g->path) + 1 : 0, n = strlen(name);
    char *p = nc_alloc(g->ctx, dir_len + n + 1);
    if (p) {
        memcpy(p, g->path, dir_len);
        memcpy(p + dir_len, name, n + 1);
    }
    return p;
}

/* The bytes of images[i]: its file (a relative uri), data: URI, or buffer view (whose buffer the
 * structure checks have validated: the GLB's BIN chunk, a file or a data: URI). *path gets the
 * image's own file when it has one (allocated), for the scene to refer to when saved. NULL on
 * failure (the context holds the message). */
static unsigned char *image_bytes(gltf_state *g, int i, size_t *size, char **path)
{
    const cJSON *img = cJSON_GetArrayItem(get(g->root, "images"), i);
    const cJSON *uri = get(img, "uri"), *view = get(img, "bufferView");
    *size = 0;
    *path = NULL;
    if (nonempty_string(uri)) {
        const char *u = uri->valuestring;
        if (strncmp(u, "data:", 5) == 0) {
            unsigned char *b = data_uri_bytes(g, u, size);
            if (!b)
                nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: images[%d].uri: a data: URI that is not base64", g->path, i);
            return b;
        }
        if (strstr(u, "://") || strchr(u, '%')) {
            nc_fail(g->ctx, NACRE_ERROR_UNSUPPORTED, "%s: images[%d].uri: \"%.64s\": only relative file names are read",
                    g->path, i, u);
            return NULL;
        }
        *path = sibling_path(g, u);
        struct stat st;
        if (!*path || stat(*path, &st) != 0) {
            if (*path)
                nc_fail(g->ctx, NACRE_ERROR_IO, "%s: images[%d]: cannot open \"%.64s\": %s", g->path, i, u,
                        strerror(errno));
            return NULL;
        }
        *size = (size_t)st.st_size;
        return file_bytes(g, *path, 0, (uint64_t)st.st_size);
    }
    const cJSON *views = get(g->root, "bufferViews");
    if (!cJSON_IsNumber(view) || view->valuedouble < 0 || view->valuedouble >= array_size(views) ||
        view->valuedouble != floor(view->valuedouble)) {
        nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: images[%d]: neither a uri nor a valid bufferView", g->path, i);
        return NULL;
    }
    const cJSON *v = cJSON_GetArrayItem(views, (int)view->valuedouble);
    int bi = (int)get(v, "buffer")->valuedouble;
    uint64_t off = (uint64_t)num(v, "byteOffset", 0), len = (uint64_t)get(v, "byteLength")->valuedouble;
    const cJSON *buf_uri = get(cJSON_GetArrayItem(get(g->root, "buffers"), bi), "uri");
    unsigned char *b = NULL;
    if (!buf_uri) { /* the GLB's BIN chunk */
        b = file_bytes(g, g->path, g->bin_offset + off, len);
    } else if (strncmp(buf_uri->valuestring, "data:", 5) == 0) {
        size_t n = 0;
        unsigned char *all = data_uri_bytes(g, buf_uri->valuestring, &n);
        if (all && off + len <= n && (b = nc_alloc(g->ctx, (size_t)len)))
            memcpy(b, all + off, (size_t)len);
        nc_free(g->ctx, all);
    } else {
        char *bp = sibling_path(g, buf_uri->valuestring);
        b = bp ? file_bytes(g, bp, off, len) : NULL;
        nc_free(g->ctx, bp);
    }
    if (b)
        *size = (size_t)len;
    else if (nacre_context_last_result(g->ctx) == NACRE_OK)
        nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: images[%d]: cannot read its bufferView", g->path, i);
    return b;
}

/* The glTF image behind a material's texture reference `info` (`what`: its key, for messages):
 * *ii its index, -1 when the reference cannot be used here (texCoord other than 0: nacre keeps
 * TEXCOORD_0 only; a texture without a source), which is warned about. */
static nacre_result texture_source(gltf_state *g, const cJSON *info, int mi, const char *what, int *ii)
{
    *ii = -1;
    const cJSON *tex_index = get(info, "index");
    const cJSON *textures = get(g->root, "textures");
    if (!cJSON_IsNumber(tex_index) || tex_index->valuedouble < 0 || tex_index->valuedouble >= array_size(textures) ||
        tex_index->valuedouble != floor(tex_index->valuedouble))
        return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: materials[%d].%s.index: out of range (%d textures)", g->path,
                       mi, what, array_size(textures));
    if (num(info, "texCoord", 0) != 0) {
        nc_warn(g->ctx, "%s: materials[%d]: %s uses TEXCOORD_%g; nacre keeps TEXCOORD_0 only, the texture was ignored",
                g->path, mi, what, (double)num(info, "texCoord", 0));
        return NACRE_OK;
    }
    int ti = (int)tex_index->valuedouble;
    const cJSON *source = get(cJSON_GetArrayItem(textures, ti), "source");
    if (!cJSON_IsNumber(source)) {
        nc_warn(g->ctx, "%s: textures[%d]: no source image nacre can read (only PNG and JPEG are decoded); the %s of "
                        "materials[%d] was ignored", g->path, ti, what, mi);
        return NACRE_OK;
    }
    if (source->valuedouble < 0 || source->valuedouble >= g->image_count ||
        source->valuedouble != floor(source->valuedouble))
        return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: textures[%d].source: out of range (%d images)", g->path, ti,
                       g->image_count);
    *ii = (int)source->valuedouble;
    return NACRE_OK;
}

/* Image `ii` decoded (PNG or JPEG; sRGB to linear when `srgb`, else as data) into *img, and the
 * absolute path of its file in *path (NULL when it is embedded). Another format leaves *img
 * empty with a warning. */
static nacre_result decode_image(gltf_state *g, int ii, int mi, const char *what, bool srgb, nacre_image *img,
                                 char **path)
{
    *img = (nacre_image){0};
    *path = NULL;
    size_t size = 0;
    char *file = NULL;
    unsigned char *bytes = image_bytes(g, ii, &size, &file);
    if (!bytes) {
        nc_free(g->ctx, file);
        nacre_result r = nacre_context_last_result(g->ctx);
        return r != NACRE_OK ? r : NACRE_ERROR_OUT_OF_MEMORY;
    }
    static const unsigned char png_sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
    nacre_result r = NACRE_OK;
    bool png = size >= 8 && memcmp(bytes, png_sig, 8) == 0;
    bool jpeg = size >= 3 && bytes[0] == 0xFF && bytes[1] == 0xD8 && bytes[2] == 0xFF;
    if (!png && !jpeg) {
        nc_warn(g->ctx, "%s: images[%d]: neither PNG nor JPEG; the %s of materials[%d] was ignored", g->path, ii, what,
                mi);
    } else {
        char name[600];
        snprintf(name, sizeof(name), "%s: images[%d]", g->path, ii);
        r = png ? nc_image_read_png_memory(g->ctx, name, bytes, size, srgb, img)
                : nc_image_read_jpeg_memory(g->ctx, name, bytes, size, srgb, img);
        if (r == NACRE_OK && file && !(*path = nc_absolute_path(g->ctx, file)))
            r = NACRE_ERROR_OUT_OF_MEMORY;
        if (r != NACRE_OK)
            nacre_image_free(g->ctx, img);
    }
    nc_free(g->ctx, bytes);
    nc_free(g->ctx, file);
    return r;
}

/* The scene texture of material `mi`'s pbrMetallicRoughness.baseColorTexture (sRGB PNG or JPEG
 * decoded to linear), in *out; id 0 when it has none or it cannot be used here (warned). */
static nacre_result base_color_texture(gltf_state *g, const cJSON *m, int mi, nacre_texture *out)
{
    out->id = 0;
    const char *what = "pbrMetallicRoughness.baseColorTexture";
    const cJSON *info = get(get(m, "pbrMetallicRoughness"), "baseColorTexture");
    int ii = -1;
    nacre_result r = info ? texture_source(g, info, mi, what, &ii) : NACRE_OK;
    if (r != NACRE_OK || ii < 0)
        return r;
    if (g->image_textures[ii].id != 0) {
        *out = g->image_textures[ii];
        return NACRE_OK;
    }
    nacre_image img = {0};
    char *path = NULL;
    r = decode_image(g, ii, mi, what, true, &img, &path);
    if (r == NACRE_OK && img.pixels) {
        r = nacre_scene_add_texture(g->scene, &img, out);
        if (r == NACRE_OK && path)
            r = nc_scene_set_texture_source(g->scene, *out, path);
        if (r == NACRE_OK)
            g->image_textures[ii] = *out;
    }
    nacre_image_free(g->ctx, &img);
    nc_free(g->ctx, path);
    return r;
}

/* With options->thickness_layer, a translucent material's KHR_materials_volume.thicknessTexture
 * becomes a one-layer depth map (docs/scene-format.md, "glTF 2.0 scenes"): the layer is the
 * material's medium, `thicknessFactor` deep where the texture's G is 1; under it the core keeps
 * the attenuation and a hundredth of the scattering. The map is read as data and its G channel
 * (glTF's thickness) copied into R (the first layer's channel); not shared with base colours,
 * which are sRGB-decoded. */
static nacre_result thickness_layer(gltf_state *g, const cJSON *m, int mi, nacre_material_desc *d)
{
    const char *what = "extensions.KHR_materials_volume.thicknessTexture";
    const cJSON *info = get(get(get(m, "extensions"), "KHR_materials_volume"), "thicknessTexture");
    int ii = -1;
    nacre_result r = info ? texture_source(g, info, mi, what, &ii) : NACRE_OK;
    if (r != NACRE_OK || ii < 0)
        return r;
    nacre_image img = {0};
    char *path = NULL;
    r = decode_image(g, ii, mi, what, false, &img, &path);
    if (r == NACRE_OK && img.pixels) {
        if (img.channels >= 2)
            for (int32_t y = 0; y < img.height; y++)
                for (int32_t x = 0; x < img.width; x++) {
                    float *p = img.pixels + img.stride * (size_t)y + (size_t)img.channels * (size_t)x;
                    p[0] = p[1];
                }
        nacre_layer *layer = &d->layering.layers[0];
        *layer = (nacre_layer){.g = d->g, .depth = num(get(get(m, "extensions"), "KHR_materials_volume"),
                                                       "thicknessFactor", 0.0f) * g->scale};
        for (int c = 0; c < 3; c++) {
            layer->sigma_a[c] = d->sigma_a[c];
            layer->sigma_s[c] = d->sigma_s[c];
            d->sigma_s[c] *= GLTF_CORE_SCATTERING;
        }
        d->layering.count = 1;
        /* No source file: the map is not the file's image (G moved to R), so a saved scene
         * writes it out. */
        r = nacre_scene_add_texture(g->scene, &img, &d->layering.depth_map);
    }
    nacre_image_free(g->ctx, &img);
    nc_free(g->ctx, path);
    return r;
}

static nacre_result add_materials(gltf_state *g, nacre_material **handles_out, int *count_out)
{
    const cJSON *mats = get(g->root, "materials");
    int n = array_size(mats);
    /* One more for primitives without a material (assimp appends its default last). */
    nacre_material *h = nc_calloc(g->ctx, (size_t)n + 1, sizeof(*h));
    if (!h)
        return NACRE_ERROR_OUT_OF_MEMORY;
    *handles_out = h;
    *count_out = n;
    g->image_count = array_size(get(g->root, "images"));
    g->image_textures = nc_calloc(g->ctx, (size_t)(g->image_count > 0 ? g->image_count : 1), sizeof(nacre_texture));
    if (!g->image_textures)
        return NACRE_ERROR_OUT_OF_MEMORY;
    nacre_gltf_report *rep = g->report;
    for (int i = 0; i < n; i++) {
        const cJSON *m = cJSON_GetArrayItem(mats, i);
        bool translucent = false;
        nacre_material_desc d = map_material(g, m, &translucent);
        /* The base colour texture multiplies the opaque diffuse colour; a translucent material
         * has none (its colour is its medium's) */
        nacre_result r = translucent ? NACRE_OK : base_color_texture(g, m, i, &d.diffuse_map);
        if (r == NACRE_OK && translucent && g->opt && g->opt->thickness_layer)
            r = thickness_layer(g, m, i, &d);
        if (r == NACRE_OK)
            r = nacre_scene_add_material(g->scene, &d, &h[i]);
        if (r != NACRE_OK)
            return r;
        char name[NACRE_GLTF_NAME_MAX];
        const cJSON *nm = get(m, "name");
        if (nonempty_string(nm))
            copy_name(name, nm->valuestring);
        else
            snprintf(name, sizeof(name), "material%d", i);
        /* Names are how a scene file overrides materials: keep them unique. */
        for (int j = 0; j < i; j++)
            if (strcmp(nc_scene_material_name(g->scene, h[j]) ? nc_scene_material_name(g->scene, h[j]) : "",
                       name) == 0) {
                snprintf(name, sizeof(name), "material%d", i);
                break;
            }
        if ((r = nc_scene_set_material_name(g->scene, h[i], name)) != NACRE_OK)
            return r;
        if (i == 0)
            rep->first_material = h[i].id;
        if (rep->material_count < NACRE_GLTF_REPORT_MAX) {
            copy_name(rep->materials[rep->material_count], name);
            rep->translucent[rep->material_count] = translucent;
        }
        rep->material_count++;
    }
    return NACRE_OK;
}

static nacre_result add_lights(gltf_state *g)
{
    const cJSON *lights = get(get(get(g->root, "extensions"), "KHR_lights_punctual"), "lights");
    int nl = array_size(lights);
    const cJSON *nodes = get(g->root, "nodes");
    for (int i = 0; i < g->node_count; i++) {
        const cJSON *ln = get(get(get(cJSON_GetArrayItem(nodes, i), "extensions"), "KHR_lights_punctual"), "light");
        if (!ln || !g->reached[i])
            continue;
        if (!cJSON_IsNumber(ln) || ln->valuedouble != floor(ln->valuedouble) || ln->valuedouble < 0 ||
            ln->valuedouble >= nl)
            return nc_fail(g->ctx, NACRE_ERROR_PARSE,
                           "%s: nodes[%d].extensions.KHR_lights_punctual.light: out of range (%d lights)", g->path, i,
                           nl);
        int li = (int)ln->valuedouble;
        const cJSON *l = cJSON_GetArrayItem(lights, li);
        const cJSON *type = get(l, "type");
        const char *t = cJSON_IsString(type) ? type->valuestring : "";
        nacre_light_type kind;
        if (strcmp(t, "directional") == 0)
            kind = NACRE_LIGHT_DIRECTIONAL;
        else if (strcmp(t, "point") == 0)
            kind = NACRE_LIGHT_POINT;
        else if (strcmp(t, "spot") == 0)
            kind = NACRE_LIGHT_SPOT;
        else
            return nc_fail(g->ctx, NACRE_ERROR_PARSE,
                           "%s: extensions.KHR_lights_punctual.lights[%d].type: \"%.32s\" (expected directional, point or spot)",
                           g->path, li, t);
        nacre_light_desc d = nacre_light_desc_defaults(kind);
        float color[3] = {1, 1, 1};
        floats_or(l, "color", 3, color);
        float intensity = num(l, "intensity", 1.0f);
        if (!(intensity >= 0.0f))
            return nc_fail(g->ctx, NACRE_ERROR_PARSE,
                           "%s: extensions.KHR_lights_punctual.lights[%d].intensity: must be >= 0", g->path, li);
        for (int c = 0; c < 3; c++)
            d.strength[c] = clampf(color[c], 0, FLT_MAX) * intensity / LUMENS_PER_WATT;
        nc_vec3 dir = node_axis(g, i, nc_v3(0, 0, -1)), pos = node_position(g, i);
        if (kind != NACRE_LIGHT_POINT && !(nc_length(dir) > 0.5f))
            return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: nodes[%d]: a light's node has a degenerate transform",
                           g->path, i);
        nc_v3store(dir, d.direction);
        nc_v3store(pos, d.position);
        if (kind == NACRE_LIGHT_SPOT) {
            const cJSON *spot = get(l, "spot");
            const float deg = 180.0f / GLTF_PI;
            d.outer_angle = clampf(num(spot, "outerConeAngle", GLTF_PI / 4.0f) * deg, 0.01f, 89.9f);
            d.inner_angle = clampf(num(spot, "innerConeAngle", 0.0f) * deg, 0.0f, d.outer_angle);
            d.falloff = NACRE_SPOT_FALLOFF_GLTF;
        }
        nacre_light h;
        nacre_result r = nacre_scene_add_light(g->scene, &d, &h);
        if (r != NACRE_OK)
            return r;
        g->report->lights++;
    }
    return NACRE_OK;
}

static nacre_result set_camera(gltf_state *g, const float bmin[3], const float bmax[3])
{
    const cJSON *nodes = get(g->root, "nodes"), *cams = get(g->root, "cameras");
    const char *want = g->opt ? g->opt->camera : NULL;
    int node = -1;
    for (int i = 0; i < g->node_count && node < 0; i++) {
        const cJSON *n = cJSON_GetArrayItem(nodes, i);
        const cJSON *ci = get(n, "camera");
        if (!ci || !g->reached[i])
            continue;
        if (!want) {
            node = i;
            break;
        }
        const cJSON *nn = get(n, "name"), *cn = get(cJSON_GetArrayItem(cams, (int)ci->valuedouble), "name");
        if ((cJSON_IsString(nn) && strcmp(nn->valuestring, want) == 0) ||
            (cJSON_IsString(cn) && strcmp(cn->valuestring, want) == 0))
            node = i;
    }
    if (want && node < 0)
        return nc_fail(g->ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: no camera named \"%.64s\" (%u camera%s in the file)",
                       g->path, want, g->report->cameras, g->report->cameras == 1 ? "" : "s");
    nc_vec3 lo = nc_v3(bmin[0], bmin[1], bmin[2]), hi = nc_v3(bmax[0], bmax[1], bmax[2]);
    nc_vec3 center = nc_scale(nc_add(lo, hi), 0.5f);
    nacre_camera_desc d = nacre_camera_desc_defaults();
    if (node < 0) {
        /* No camera: look at the bounds from +z, far enough for the bounding sphere at 40 deg. */
        float radius = 0.5f * nc_length(nc_sub(hi, lo));
        float dist = radius / sinf(0.5f * d.fov_y * GLTF_PI / 180.0f);
        nc_v3store(center, d.target);
        nc_v3store(nc_add(center, nc_v3(0, 0, dist > 0 ? dist : 1.0f)), d.position);
        return nacre_scene_set_camera(g->scene, &d);
    }
    const cJSON *cam = cJSON_GetArrayItem(cams, (int)get(cJSON_GetArrayItem(nodes, node), "camera")->valuedouble);
    const cJSON *type = get(cam, "type");
    bool ortho = cJSON_IsString(type) && strcmp(type->valuestring, "orthographic") == 0;
    const cJSON *p = get(cam, ortho ? "orthographic" : "perspective");
    nc_vec3 pos = node_position(g, node), fwd = node_axis(g, node, nc_v3(0, 0, -1));
    nc_vec3 up = node_axis(g, node, nc_v3(0, 1, 0));
    if (!(nc_length(fwd) > 0.5f) || !(nc_length(up) > 0.5f))
        return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: nodes[%d]: the camera's node has a degenerate transform",
                       g->path, node);
    /* The target (the viewer orbits about it) is the bounds' centre projected on the view axis. */
    float along = nc_dot(nc_sub(center, pos), fwd);
    if (!(along > 0.0f))
        along = 1.0f;
    nc_v3store(pos, d.position);
    nc_v3store(nc_add(pos, nc_scale(fwd, along)), d.target);
    nc_v3store(up, d.up);
    if (ortho) {
        d.projection = NACRE_ORTHOGRAPHIC;
        float ymag = num(p, "ymag", 1.0f);
        d.ortho_height = 2.0f * fabsf(ymag) * g->scale;
    } else {
        float yfov = num(p, "yfov", 0.8f) * 180.0f / GLTF_PI;
        d.fov_y = clampf(yfov, 0.1f, 179.0f);
    }
    float znear = num(p, "znear", 0.0f), zfar = num(p, "zfar", 0.0f);
    d.near_clip = znear > 0.0f ? znear * g->scale : 0.0f;
    d.far_clip = zfar > znear && d.near_clip > 0.0f ? zfar * g->scale : 0.0f;
    return nacre_scene_set_camera(g->scene, &d);
}

/* ------------------------------------------------------------------------------------------ */
/* Meshes and the entry points                                                                */
/* ------------------------------------------------------------------------------------------ */

/* The glTF material of a part, found through its node and primitive (assimp renumbers
 * materials); -1: none (the default material). */
static int part_material(const gltf_state *g, const nc_mesh_part *part)
{
    if (part->node >= (uint32_t)g->order_count || g->order[part->node] < 0)
        return -1;
    const cJSON *node = cJSON_GetArrayItem(get(g->root, "nodes"), g->order[part->node]);
    const cJSON *mesh = get(node, "mesh");
    if (!cJSON_IsNumber(mesh))
        return -1;
    const cJSON *prims = get(cJSON_GetArrayItem(get(g->root, "meshes"), (int)mesh->valuedouble), "primitives");
    const cJSON *mat = get(cJSON_GetArrayItem(prims, (int)part->slot), "material");
    return cJSON_IsNumber(mat) ? (int)mat->valuedouble : -1;
}

static nacre_result add_objects(gltf_state *g, const nacre_material *materials, int material_count,
                                float bmin[3], float bmax[3])
{
    nc_mesh_part *parts = NULL;
    uint32_t count = 0;
    nacre_result r = nc_mesh_load_parts(g->ctx, g->path, &parts, &count);
    if (r != NACRE_OK)
        return r;
    const cJSON *mats = get(g->root, "materials");
    nacre_material fallback = {0};
    for (int c = 0; c < 3; c++) {
        bmin[c] = FLT_MAX;
        bmax[c] = -FLT_MAX;
    }
    for (uint32_t i = 0; i < count && r == NACRE_OK; i++) {
        nacre_mesh_data *m = &parts[i].data;
        for (size_t v = 0; v < (size_t)m->vertex_count * 3; v++) {
            m->positions[v] *= g->scale;
            bmin[v % 3] = fminf(bmin[v % 3], m->positions[v]);
            bmax[v % 3] = fmaxf(bmax[v % 3], m->positions[v]);
        }
        nacre_object_desc d = nacre_object_desc_defaults();
        int mi = part_material(g, &parts[i]);
        if (mi >= 0 && mi < material_count) {
            d.material = materials[mi];
            const cJSON *ds = get(cJSON_GetArrayItem(mats, mi), "doubleSided");
            d.double_sided = cJSON_IsTrue(ds);
        } else {
            if (fallback.id == 0) {
                nacre_material_desc def = nacre_material_desc_defaults(NACRE_MATERIAL_OPAQUE);
                if ((r = nacre_scene_add_material(g->scene, &def, &fallback)) != NACRE_OK ||
                    (r = nc_scene_set_material_name(g->scene, fallback, "default")) != NACRE_OK)
                    break;
                if (g->report->material_count < NACRE_GLTF_REPORT_MAX)
                    copy_name(g->report->materials[g->report->material_count], "default");
                if (g->report->material_count++ == 0)
                    g->report->first_material = fallback.id;
            }
            d.material = fallback;
        }
        char name[32];
        snprintf(name, sizeof(name), "mesh%u", parts[i].mesh);
        d.name = name;
        if ((r = nacre_scene_add_mesh(g->scene, m, &d.mesh)) != NACRE_OK)
            break;
        nacre_object h;
        if ((r = nacre_scene_add_object(g->scene, &d, &h)) != NACRE_OK)
            break;
        g->report->objects++;
    }
    nc_mesh_parts_free(g->ctx, parts, count);
    return r;
}

/* The file's JSON (a .glb's JSON chunk), parsed into g->root; *text holds it (free it). */
static nacre_result parse_json(gltf_state *g, char **text, size_t *len)
{
    nacre_result r = read_json(g, text, len);
    if (r != NACRE_OK)
        return r;
    const char *end = NULL;
    g->root = cJSON_ParseWithLengthOpts(*text, *len, &end, 0);
    if (!g->root || !cJSON_IsObject(g->root)) {
        size_t off = end && end >= *text ? (size_t)(end - *text) : 0;
        return nc_fail(g->ctx, NACRE_ERROR_PARSE, "%s: malformed glTF JSON (at byte %zu of the JSON)", g->path, off);
    }
    return NACRE_OK;
}

/* What must hold before assimp reads the file: buffers, views, accessors, the node tree. */
static nacre_result check_structure(gltf_state *g, double **buffer_len, int *nb)
{
    nacre_result r = check_buffers(g, buffer_len, nb);
    if (r == NACRE_OK)
        r = check_views_accessors(g, *buffer_len, *nb);
    if (r == NACRE_OK)
        r = compute_world(g);
    return r;
}

nacre_result nc_gltf_import(nacre_scene *scene, const char *path, const nacre_gltf_options *options,
                            nacre_gltf_report *report)
{
    nacre_context *ctx = nacre_scene_context(scene);
    memset(report, 0, sizeof(*report));
    gltf_state g = {0};
    g.ctx = ctx;
    g.scene = scene;
    g.path = path;
    g.opt = options;
    g.report = report;
    float unit_mm = options && options->unit_mm > 0.0f ? options->unit_mm : 1000.0f;
    g.scale = 1000.0f / unit_mm;
    char *text = NULL;
    size_t len = 0;
    double *buffer_len = NULL;
    int nb = 0;
    nacre_material *materials = NULL;
    int material_count = 0;
    nacre_result r = parse_json(&g, &text, &len);
    if (r != NACRE_OK)
        goto out;
    const cJSON *version = get(get(g.root, "asset"), "version");
    if (!cJSON_IsString(version) || version->valuestring[0] != '2') {
        r = nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "%s: asset.version: %s (nacre reads glTF 2.0)", path,
                    cJSON_IsString(version) ? version->valuestring : "missing");
        goto out;
    }
    report->meshes = (uint32_t)array_size(get(g.root, "meshes"));
    report->cameras = (uint32_t)array_size(get(g.root, "cameras"));
    if ((r = check_extensions(&g)) != NACRE_OK || (r = check_structure(&g, &buffer_len, &nb)) != NACRE_OK)
        goto out;
    if ((r = add_materials(&g, &materials, &material_count)) != NACRE_OK)
        goto out;
    float bmin[3], bmax[3];
    if ((r = add_objects(&g, materials, material_count, bmin, bmax)) != NACRE_OK)
        goto out;
    if (!(options && options->skip_lights) && (r = add_lights(&g)) != NACRE_OK)
        goto out;
    if (!(options && options->skip_camera) && (r = set_camera(&g, bmin, bmax)) != NACRE_OK)
        goto out;
    char *absolute = nc_absolute_path(ctx, path);
    r = absolute ? nc_scene_note_input(scene, absolute) : NACRE_ERROR_OUT_OF_MEMORY;
    nc_free(ctx, absolute);
out:
    cJSON_Delete(g.root);
    nc_free(ctx, text);
    nc_free(ctx, buffer_len);
    nc_free(ctx, materials);
    nc_free(ctx, g.world);
    nc_free(ctx, g.reached);
    nc_free(ctx, g.order);
    nc_free(ctx, g.image_textures);
    return r;
}

nacre_result nc_gltf_check(nacre_context *ctx, const char *path)
{
    nacre_gltf_report report;
    memset(&report, 0, sizeof(report));
    gltf_state g = {0};
    g.ctx = ctx;
    g.path = path;
    g.report = &report;
    char *text = NULL;
    size_t len = 0;
    double *buffer_len = NULL;
    int nb = 0;
    nacre_result r = parse_json(&g, &text, &len);
    if (r == NACRE_OK)
        r = check_structure(&g, &buffer_len, &nb);
    cJSON_Delete(g.root);
    nc_free(ctx, text);
    nc_free(ctx, buffer_len);
    nc_free(ctx, g.world);
    nc_free(ctx, g.reached);
    nc_free(ctx, g.order);
    return r;
}

nacre_result nacre_scene_load_gltf(nacre_context *ctx, const char *path, const nacre_gltf_options *options,
                                   nacre_scene **out, nacre_scene_file_settings *settings,
                                   nacre_gltf_report *report)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (out)
        *out = NULL;
    if (!out || !path)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "nacre_scene_load_gltf: %s is NULL", out ? "path" : "out");
    nacre_gltf_report *rep = report;
    if (!rep && !(rep = nc_alloc(ctx, sizeof(*rep))))
        return NACRE_ERROR_OUT_OF_MEMORY;
    nacre_scene *scene = NULL;
    nacre_result r = nacre_scene_create(ctx, &scene);
    float unit_mm = options && options->unit_mm > 0.0f ? options->unit_mm : 1000.0f;
    if (r == NACRE_OK)
        r = nacre_scene_set_unit_mm(scene, unit_mm);
    if (r == NACRE_OK)
        r = nc_gltf_import(scene, path, options, rep);
    if (rep != report)
        nc_free(ctx, rep);
    if (r != NACRE_OK) {
        nacre_scene_destroy(scene);
        return r;
    }
    *out = scene;
    if (settings)
        *settings = (nacre_scene_file_settings){.render = nacre_render_settings_defaults()};
    return NACRE_OK;
}
