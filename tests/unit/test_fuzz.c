/*
 * test_fuzz.c: a small deterministic mutation fuzzer over the two file parsers, run as a plain
 * test (meant for the ASan/UBSan build). Seeds are the example scenes and a few small meshes
 * (OBJ, ASCII PLY, a binary PLY written here); mutations are byte flips, insertions of
 * JSON-significant characters, deletions, truncations, numbers replaced by huge or NaN-like
 * tokens, duplicated keys, strings swapped for format keywords and splices between seeds.
 *
 * Checked for every input: no crash (the sanitizers abort), a failure leaves the output empty
 * and a non-empty one-line message, a success gives a scene that commits and destroys (or mesh
 * data that validates and frees), and the context's allocations return to their baseline.
 *
 * Deterministic: one fixed-seed xorshift generator passed around, no global RNG. The iteration
 * counts fit a few tens of seconds under ASan; NACRE_FUZZ_SCALE=k in the environment runs k
 * times as many (each phase also stops at a time budget, reported when hit) and
 * NACRE_FUZZ_ONLY=scene|mesh|nrrd runs one phase. A crash leaves its
 * input behind: NACRE_TEST_TMP/fuzz_scene.json or fuzz_mesh.{obj,ply}.
 *
 * NRRD volumes (src/io/nrrd.c) get their own phase: seeds are the example density volume, a
 * voxelizer export and headers written here (4D big-endian floats, spacings, byte skip); on top
 * of the byte-level mutations, header values are swapped for tokens aimed at the reader (sizes
 * that overflow, negative sizes, wrong encodings and types, malformed vectors). A volume that
 * loads must hold finite non-negative samples, go into a scene and answer density lookups.
 * A crash leaves NACRE_TEST_TMP/fuzz_volume.nrrd behind.
 */
#include "io/nrrd.h"
#include "scene/medium.h"
#include "scene/scene.h"
#include "test_util.h"

#include <dirent.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#define EXAMPLES NACRE_SOURCE_DIR "/examples"
#define TMP NACRE_TEST_TMP
#define SCENE_ITERATIONS 8000
#define MESH_ITERATIONS 1000
#define NRRD_ITERATIONS 600
#define PHASE_BUDGET_S 30.0
#define MAX_SEEDS 32

/* assimp 5.2 leaks the meshes it has built when its parsers throw on a bad file (e.g. an ASCII
 * PLY with "0x10" where a number belongs); nothing nacre can free. Leaks through libassimp are
 * therefore ignored here; nacre's own allocations are checked exactly by the counting
 * allocator below. LeakSanitizer calls this hook when the test is built with ASan. */
const char *__lsan_default_suppressions(void);
const char *__lsan_default_suppressions(void) { return "leak:libassimp.so\n"; }

typedef struct rng {
    uint64_t s;
} rng;

static uint64_t rng_next(rng *r)
{
    /* xorshift64* */
    r->s ^= r->s >> 12;
    r->s ^= r->s << 25;
    r->s ^= r->s >> 27;
    return r->s * 0x2545F4914F6CDD1DULL;
}

static size_t below(rng *r, size_t n) { return n ? (size_t)(rng_next(r) % n) : 0; }

typedef struct buf {
    char *data;
    size_t len, cap;
} buf;

static void buf_reserve(buf *b, size_t n)
{
    if (n + 1 <= b->cap)
        return;
    size_t cap = b->cap ? b->cap : 64;
    while (cap < n + 1)
        cap *= 2;
    char *p = realloc(b->data, cap);
    if (!p)
        abort();
    b->data = p;
    b->cap = cap;
}

static void buf_set(buf *b, const char *data, size_t len)
{
    buf_reserve(b, len);
    memcpy(b->data, data, len);
    b->len = len;
    b->data[len] = '\0';
}

static void buf_insert(buf *b, size_t at, const char *data, size_t len)
{
    if (at > b->len)
        at = b->len;
    buf_reserve(b, b->len + len);
    memmove(b->data + at + len, b->data + at, b->len - at);
    memcpy(b->data + at, data, len);
    b->len += len;
    b->data[b->len] = '\0';
}

static void buf_erase(buf *b, size_t at, size_t len)
{
    if (at >= b->len)
        return;
    if (len > b->len - at)
        len = b->len - at;
    memmove(b->data + at, b->data + at + len, b->len - at - len);
    b->len -= len;
    b->data[b->len] = '\0';
}

static void buf_replace(buf *b, size_t at, size_t len, const char *data)
{
    buf_erase(b, at, len);
    buf_insert(b, at, data, strlen(data));
}

/* ------------------------------------------------------------------------------------------ */
/* Mutations                                                                                  */
/* ------------------------------------------------------------------------------------------ */

static const char *const number_tokens[] = {
    "1e999", "-1e999", "0", "-0", "-1", "1e-320", "NaN", "nan", "Infinity", "-inf", "99999999999",
    "4294967296", "4294967295", "2147483648", "-2147483649", "1e38", "3.5e38", "1e-45",
    "0.0000001", "16384", "16385", "4096", "65", "5", "1.5", "-0.5", "true", "null", "\"\"", "[]",
    "{}", "[0,0,0]", "[1e999,0,0]", "0x10", "1.", ".5", "1e", "--1", "00012"};

static const char *const words[] = {
    "units", "render", "camera", "environment", "materials", "lights", "objects", "method",
    "width", "height", "exposure", "shadow_map_size", "pcf_radius", "shadow_bias", "spp", "seed",
    "time", "type", "position", "target", "up", "fov", "near", "far", "perspective",
    "orthographic", "opaque", "translucent", "preset", "diffuse", "specular", "shininess",
    "sigma_a", "sigma_s", "g", "eta", "directional", "point", "spot", "direction", "irradiance",
    "intensity", "strength", "angular_radius", "radius", "inner_angle", "outer_angle", "shadows",
    "falloff", "smooth", "cycles", "gltf",
    "name", "mesh", "shape", "material", "transform", "translate", "rotate", "scale", "deformers",
    "twist", "bend", "axis", "angle", "angle_rate", "length", "center", "scale_rate",
    "double_sided", "sphere", "box", "plane", "torus", "size", "segments", "rings",
    "minor_radius", "x", "y", "z", "mm", "cm", "m", "marble", "jade", "skin1", "chicken", "phong",
    "pathtrace", "meshes/suzanne.ply", "meshes/none.ply", "meshes", ".", "/dev/null",
    "../examples/meshes/suzanne.ply", "", "_c", "\\u0000", "\\n", "\\\"", "\\ud800",
    "pattern", "random_mix", "checker", "noise", "volume", "preset2", "sigma_a2", "sigma_s2",
    "cell_size", "fraction", "octaves", "channel", "density_scale", "hetero_density.nrrd",
    "meshes/suzanne.ply.nrrd", "voxel_resolution", "tsm_size", "solver", "source", "tolerance",
    "seed_iterations", "time_limit", "max_scatter", "multigrid", "face", "ketchup"};

static const char significant[] = "{}[]\",:-.eE0123456789 \n\t\\tfn";

/* Position of a number token at or after `from` (wrapping), or SIZE_MAX. */
static size_t find_number(const buf *b, size_t from, size_t *len)
{
    for (size_t k = 0; k < b->len; k++) {
        size_t i = (from + k) % b->len;
        char c = b->data[i];
        if ((c >= '0' && c <= '9') || (c == '-' && i + 1 < b->len && b->data[i + 1] >= '0' &&
                                       b->data[i + 1] <= '9')) {
            size_t start = i;
            while (start > 0 && strchr("0123456789.eE+-", b->data[start - 1]))
                start--;
            size_t end = i;
            while (end < b->len && strchr("0123456789.eE+-", b->data[end]))
                end++;
            *len = end - start;
            return start;
        }
    }
    return SIZE_MAX;
}

/* A quoted string at or after `from`: [start, start + len) includes the quotes. */
static size_t find_string(const buf *b, size_t from, size_t *len)
{
    for (size_t k = 0; k < b->len; k++) {
        size_t i = (from + k) % b->len;
        if (b->data[i] != '"')
            continue;
        size_t j = i + 1;
        while (j < b->len && b->data[j] != '"' && b->data[j] != '\n')
            j++;
        if (j < b->len && b->data[j] == '"') {
            *len = j + 1 - i;
            return i;
        }
    }
    return SIZE_MAX;
}

/* Copy `"key": value` (up to the next ',' '}' or ']' at the same depth) in front of itself,
 * so the object gets the key twice. */
static void duplicate_key(buf *b, rng *r)
{
    size_t len;
    size_t at = find_string(b, below(r, b->len), &len);
    if (at == SIZE_MAX)
        return;
    size_t j = at + len;
    while (j < b->len && (b->data[j] == ' ' || b->data[j] == '\t'))
        j++;
    if (j >= b->len || b->data[j] != ':')
        return;
    int depth = 0;
    size_t end = j + 1;
    for (; end < b->len; end++) {
        char c = b->data[end];
        if (c == '{' || c == '[')
            depth++;
        else if ((c == '}' || c == ']') && depth-- == 0)
            break;
        else if (c == ',' && depth == 0)
            break;
    }
    size_t n = end - at;
    char *copy = malloc(n + 2);
    if (!copy)
        abort();
    memcpy(copy, b->data + at, n);
    copy[n] = ',';
    buf_insert(b, at, copy, n + 1);
    free(copy);
}

static void mutate_once(buf *b, rng *r, const buf *seeds, int seed_count, bool binary)
{
    size_t pos = below(r, b->len + 1);
    char tmp[64];
    /* Half the mutations keep the JSON well-formed (numbers, keywords, duplicate keys) so that
     * the checks behind the parser get exercised too, not just its syntax errors. */
    static const int semantic[] = {4, 5, 6, 7};
    int op = !binary && below(r, 2) ? semantic[below(r, 4)] : (int)below(r, binary ? 12 : 11);
    switch (op) {
    case 0: /* flip a bit */
        if (b->len)
            b->data[pos % b->len] ^= (char)(1u << below(r, 8));
        break;
    case 1: /* insert JSON-significant characters */
        for (size_t n = 1 + below(r, 3), i = 0; i < n; i++) {
            char c = significant[below(r, sizeof(significant) - 1)];
            buf_insert(b, pos, &c, 1);
        }
        break;
    case 2: /* delete a few bytes */
        buf_erase(b, pos, 1 + below(r, 16));
        break;
    case 3: /* truncate */
        if (below(r, 3) == 0)
            buf_erase(b, pos, b->len);
        else
            buf_erase(b, pos, 1);
        break;
    case 4:
    case 5: { /* replace a number */
        size_t len;
        size_t at = b->len ? find_number(b, pos, &len) : SIZE_MAX;
        if (at != SIZE_MAX)
            buf_replace(b, at, len, number_tokens[below(r, sizeof(number_tokens) / sizeof(number_tokens[0]))]);
        break;
    }
    case 6: /* duplicate a key */
        if (b->len)
            duplicate_key(b, r);
        break;
    case 7: { /* swap a string for a keyword */
        size_t len;
        size_t at = b->len ? find_string(b, pos, &len) : SIZE_MAX;
        if (at != SIZE_MAX) {
            snprintf(tmp, sizeof(tmp), "\"%s\"", words[below(r, sizeof(words) / sizeof(words[0]))]);
            buf_replace(b, at, len, tmp);
        }
        break;
    }
    case 8: { /* splice a chunk of another seed */
        const buf *o = &seeds[below(r, (size_t)seed_count)];
        if (o->len) {
            size_t from = below(r, o->len), n = 1 + below(r, 64);
            if (n > o->len - from)
                n = o->len - from;
            buf_insert(b, pos, o->data + from, n);
        }
        break;
    }
    case 9: { /* repeat a chunk of this input */
        if (b->len) {
            size_t from = below(r, b->len), n = 1 + below(r, 32);
            if (n > b->len - from)
                n = b->len - from;
            char *copy = malloc(n);
            if (!copy)
                abort();
            memcpy(copy, b->data + from, n);
            buf_insert(b, pos, copy, n);
            free(copy);
        }
        break;
    }
    case 10: /* a random byte */
        if (b->len)
            b->data[pos % b->len] = (char)below(r, 256);
        break;
    case 11: { /* binary: overwrite 4 bytes with an interesting integer or float */
        static const uint32_t values[] = {0u, 1u, 3u, 0xffffffffu, 0x7fffffffu, 0x80000000u,
                                          0x7fc00000u /* NaN */, 0x7f800000u /* inf */,
                                          0xff800000u, 0x00000001u /* denormal */, 1000000u,
                                          0x0000ffffu, 0x00ff00ffu};
        uint32_t v = values[below(r, sizeof(values) / sizeof(values[0]))];
        if (b->len >= 4) {
            size_t at = below(r, b->len - 3);
            memcpy(b->data + at, &v, 4);
        }
        break;
    }
    }
}

/* ------------------------------------------------------------------------------------------ */
/* Seeds                                                                                      */
/* ------------------------------------------------------------------------------------------ */

static bool read_file(const char *path, buf *out)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return false;
    char chunk[4096];
    size_t n;
    out->len = 0;
    buf_reserve(out, 0);
    while ((n = fread(chunk, 1, sizeof(chunk), f)) > 0)
        buf_insert(out, out->len, chunk, n);
    fclose(f);
    return true;
}

static bool write_file(const char *path, const buf *b)
{
    FILE *f = fopen(path, "wb");
    if (!f)
        return false;
    bool ok = fwrite(b->data, 1, b->len, f) == b->len;
    return fclose(f) == 0 && ok;
}

static int compare_strings(const void *a, const void *b)
{
    return strcmp(*(char *const *)a, *(char *const *)b);
}

/* Example scenes in name order (readdir order is not), then a few small inline scenes. */
static int load_scene_seeds(buf *seeds)
{
    static const char *const inline_seeds[] = {
        "{}",
        "{\"units\": 25.4, \"environment\": 0.1, \"materials\": {\"a\": {\"preset\": \"chicken\", \"g\": 0.1}},"
        " \"lights\": [{\"type\": \"point\", \"position\": [0, 4, 0], \"strength\": 40}],"
        " \"objects\": [{\"shape\": {\"type\": \"box\", \"size\": 2, \"segments\": 3}, \"material\": \"a\","
        " \"deformers\": [{\"type\": \"bend\", \"axis\": \"y\", \"direction\": [1, 0, 1], \"angle\": 30,"
        " \"angle_rate\": 5, \"length\": 2}, {\"type\": \"scale\", \"scale\": 2, \"scale_rate\": [0, 1, 0]}]}]}",
        "{\"camera\": {\"type\": \"orthographic\", \"height\": 4, \"near\": 1, \"far\": 9},"
        " \"materials\": {\"o\": {\"type\": \"opaque\"}, \"t\": {\"type\": \"translucent\"}},"
        " \"objects\": [{\"shape\": {\"type\": \"plane\", \"size\": [3, 4]}, \"material\": \"o\"},"
        " {\"shape\": {\"type\": \"torus\", \"segments\": 8, \"rings\": 4}, \"material\": \"t\","
        " \"deformers\": [{\"type\": \"twist\", \"axis\": [1, 1, 0], \"angle\": 720}]}]}",
    };
    int count = 0;
    DIR *dir = opendir(EXAMPLES);
    if (dir) {
        char *names[MAX_SEEDS];
        int n = 0;
        struct dirent *e;
        while ((e = readdir(dir)) && n < MAX_SEEDS - 4) {
            size_t len = strlen(e->d_name);
            if (len > 5 && strcmp(e->d_name + len - 5, ".json") == 0)
                names[n++] = strdup(e->d_name);
        }
        closedir(dir);
        qsort(names, (size_t)n, sizeof(names[0]), compare_strings);
        for (int i = 0; i < n; i++) {
            char path[1024];
            snprintf(path, sizeof(path), "%s/%s", EXAMPLES, names[i]);
            memset(&seeds[count], 0, sizeof(seeds[count]));
            if (read_file(path, &seeds[count]))
                count++;
            free(names[i]);
        }
    }
    for (size_t i = 0; i < sizeof(inline_seeds) / sizeof(inline_seeds[0]); i++) {
        memset(&seeds[count], 0, sizeof(seeds[count]));
        buf_set(&seeds[count], inline_seeds[i], strlen(inline_seeds[i]));
        count++;
    }
    return count;
}

typedef struct mesh_seed {
    buf data;
    const char *ext;
    bool binary;
} mesh_seed;

static void put_u32(buf *b, uint32_t v) { buf_insert(b, b->len, (const char *)&v, 4); }
static void put_f32(buf *b, float v) { buf_insert(b, b->len, (const char *)&v, 4); }

static int load_mesh_seeds(mesh_seed *seeds)
{
    static const char obj[] =
        "# cube with uvs and normals, quads, negative indices\n"
        "o cube\n"
        "v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "vn 0 0 -1\nvn 0 0 1\nvn 0 -1 0\nvn 0 1 0\nvn -1 0 0\nvn 1 0 0\n"
        "g sides\n"
        "f 1/1/1 4/4/1 3/3/1 2/2/1\n"
        "f 5/1/2 6/2/2 7/3/2 8/4/2\n"
        "f 1/1/3 2/2/3 6/3/3 5/4/3\n"
        "f -5/1/4 -1/2/4 -2/3/4 -6/4/4\n"
        "f 1//5 5//5 8//5\nf 1//5 8//5 4//5\n"
        "f 2 3 7\nf 2 7 6\n";
    static const char ply[] =
        "ply\nformat ascii 1.0\ncomment tetrahedron\n"
        "element vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
        "property float nx\nproperty float ny\nproperty float nz\nproperty float s\nproperty float t\n"
        "element face 4\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0 -1 -1 -1 0 0\n1 0 0 1 0 0 1 0\n0 1 0 0 1 0 0 1\n0 0 1 0 0 1 1 1\n"
        "3 0 2 1\n3 0 1 3\n3 0 3 2\n4 1 2 3 1\n";
    int n = 0;
    memset(seeds, 0, 4 * sizeof(*seeds));
    buf_set(&seeds[n].data, obj, sizeof(obj) - 1);
    seeds[n++].ext = "obj";
    buf_set(&seeds[n].data, ply, sizeof(ply) - 1);
    seeds[n++].ext = "ply";

    /* Binary little-endian PLY: an octahedron, float xyz, uchar/int faces. */
    static const char header[] =
        "ply\nformat binary_little_endian 1.0\nelement vertex 6\nproperty float x\n"
        "property float y\nproperty float z\nelement face 8\n"
        "property list uchar int vertex_indices\nend_header\n";
    static const float v[6][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
    static const uint32_t f[8][3] = {{0, 2, 4}, {2, 1, 4}, {1, 3, 4}, {3, 0, 4},
                                     {2, 0, 5}, {1, 2, 5}, {3, 1, 5}, {0, 3, 5}};
    buf *b = &seeds[n].data;
    buf_set(b, header, sizeof(header) - 1);
    for (int i = 0; i < 6; i++)
        for (int k = 0; k < 3; k++)
            put_f32(b, v[i][k]);
    for (int i = 0; i < 8; i++) {
        char three = 3;
        buf_insert(b, b->len, &three, 1);
        for (int k = 0; k < 3; k++)
            put_u32(b, f[i][k]);
    }
    seeds[n].ext = "ply";
    seeds[n++].binary = true;

    if (read_file(EXAMPLES "/meshes/suzanne.ply", &seeds[n].data)) {
        seeds[n].ext = "ply";
        seeds[n++].binary = true;
    }
    return n;
}

/* ------------------------------------------------------------------------------------------ */
/* Harness                                                                                    */
/* ------------------------------------------------------------------------------------------ */

typedef struct counter {
    long live;
} counter;

static void *count_alloc(size_t size, void *user)
{
    void *p = malloc(size);
    if (p)
        ((counter *)user)->live++;
    return p;
}

static void count_free(void *ptr, void *user)
{
    if (ptr) {
        ((counter *)user)->live--;
        free(ptr);
    }
}

typedef struct stats {
    int runs, ok, failed, bad;
} stats;

static double seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

static int fuzz_scale(void)
{
    const char *s = getenv("NACRE_FUZZ_SCALE");
    int k = s ? atoi(s) : 1;
    return k < 1 ? 1 : k;
}

static bool message_ok(nacre_context *ctx)
{
    const char *msg = nacre_context_last_error(ctx);
    return msg[0] != '\0' && !strchr(msg, '\n');
}

static uint64_t committed_vertex_budget(const nacre_scene *s)
{
    uint64_t total = 0;
    for (uint32_t i = 0; i < s->object_count; i++) {
        const nacre_mesh_data *m = nacre_scene_mesh_data(s, s->objects[i].desc.mesh);
        total += m ? m->vertex_count : 0;
    }
    /* Particle systems are simulated and splatted at commit: count their grids' cells. */
    for (uint32_t i = 0; i < nacre_scene_particles_count(s); i++) {
        nacre_particles_desc d;
        if (nacre_scene_get_particles(s, (nacre_particles){i + 1}, &d) == NACRE_OK)
            total += (uint64_t)d.grid_resolution * d.grid_resolution * d.grid_resolution / 4 +
                     (d.type == NACRE_PARTICLES_LIST ? d.count : (uint64_t)(d.rate * d.lifetime));
    }
    return total;
}

static void fuzz_scenes(nacre_context *ctx, counter *c, rng *r, int iterations)
{
    buf seeds[MAX_SEEDS];
    int count = load_scene_seeds(seeds);
    CHECK(count >= 4);
    buf input = {0};
    stats st = {0};
    long baseline = c->live;
    double start = seconds();
    for (int it = 0; it < iterations; it++) {
        if (seconds() - start > PHASE_BUDGET_S) {
            printf("scene fuzz: time budget reached after %d iterations\n", it);
            break;
        }
        const buf *seed = &seeds[below(r, (size_t)count)];
        buf_set(&input, seed->data, seed->len);
        for (size_t m = 1 + below(r, 4); m > 0; m--)
            mutate_once(&input, r, seeds, count, false);
        write_file(TMP "/fuzz_scene.json", &input); /* left behind if this input crashes */
        nacre_scene *s = NULL;
        nacre_scene_file_settings rs;
        nacre_result res = nacre_scene_load_json(ctx, input.data, input.len, "fuzz.json", EXAMPLES,
                                                 &s, &rs);
        st.runs++;
        bool good;
        if (res == NACRE_OK) {
            st.ok++;
            good = s != NULL;
            /* Commit what is cheap to commit: deformers and transforms see the odd values. */
            if (s && committed_vertex_budget(s) < 300000) {
                nacre_result cr = nacre_scene_commit(s, (double)below(r, 3));
                good = good && (cr == NACRE_OK || message_ok(ctx));
            }
            nacre_scene_destroy(s);
        } else {
            st.failed++;
            good = s == NULL && message_ok(ctx) && strncmp(nacre_context_last_error(ctx), "fuzz.json", 9) == 0;
        }
        good = good && c->live == baseline;
        if (!good) {
            st.bad++;
            if (st.bad <= 5)
                printf("scene fuzz iteration %d: result %d, message \"%s\", live %ld vs %ld\n  input: %.*s\n",
                       it, (int)res, nacre_context_last_error(ctx), c->live, baseline,
                       (int)(input.len < 400 ? input.len : 400), input.data);
        }
    }
    printf("scene fuzz: %d inputs, %d loaded, %d rejected, %d bad (%.1f s)\n", st.runs, st.ok,
           st.failed, st.bad, seconds() - start);
    CHECK(st.bad == 0);
    CHECK(st.ok > 0 && st.failed > 0);
    free(input.data);
    for (int i = 0; i < count; i++)
        free(seeds[i].data);
}

static void fuzz_meshes(nacre_context *ctx, counter *c, rng *r, int iterations)
{
    mesh_seed seeds[4];
    int count = load_mesh_seeds(seeds);
    CHECK(count >= 3);
    buf plain[4];
    for (int i = 0; i < count; i++)
        plain[i] = seeds[i].data;

    /* The unmutated seeds load. */
    for (int i = 0; i < count; i++) {
        char path[512];
        snprintf(path, sizeof(path), "%s/fuzz_seed_%d.%s", TMP, i, seeds[i].ext);
        CHECK(write_file(path, &seeds[i].data));
        nacre_mesh_data m = {0};
        nacre_result res = nacre_mesh_load(ctx, path, &m);
        CHECK(res == NACRE_OK);
        if (res != NACRE_OK)
            printf("mesh seed %d: %s\n", i, nacre_context_last_error(ctx));
        nacre_mesh_data_free(ctx, &m);
    }

    buf input = {0};
    stats st = {0};
    long baseline = c->live;
    double start = seconds();
    for (int it = 0; it < iterations; it++) {
        if (seconds() - start > PHASE_BUDGET_S) {
            printf("mesh fuzz: time budget reached after %d iterations\n", it);
            break;
        }
        const mesh_seed *seed = &seeds[below(r, (size_t)count)];
        buf_set(&input, seed->data.data, seed->data.len);
        for (size_t m = 1 + below(r, 3); m > 0; m--)
            mutate_once(&input, r, plain, count, seed->binary);
        /* Now and then the extension lies about the contents. */
        const char *ext = below(r, 16) == 0 ? (strcmp(seed->ext, "obj") == 0 ? "ply" : "obj") : seed->ext;
        char path[512];
        snprintf(path, sizeof(path), "%s/fuzz_mesh.%s", TMP, ext);
        if (!write_file(path, &input)) {
            CHECK(false);
            break;
        }
        nacre_mesh_data m = {0};
        nacre_result res = nacre_mesh_load(ctx, path, &m);
        st.runs++;
        bool good;
        if (res == NACRE_OK) {
            st.ok++;
            good = nacre_mesh_validate(ctx, &m, "fuzz") == NACRE_OK;
        } else {
            st.failed++;
            good = m.positions == NULL && m.indices == NULL && message_ok(ctx);
        }
        nacre_mesh_data_free(ctx, &m);
        good = good && c->live == baseline;
        if (!good) {
            st.bad++;
            if (st.bad <= 5)
                printf("mesh fuzz iteration %d (%s): result %d, message \"%s\", live %ld vs %ld\n", it,
                       ext, (int)res, nacre_context_last_error(ctx), c->live, baseline);
        }
    }
    printf("mesh fuzz: %d inputs, %d loaded, %d rejected, %d bad (%.1f s)\n", st.runs, st.ok,
           st.failed, st.bad, seconds() - start);
    CHECK(st.bad == 0);
    CHECK(st.ok > 0 && st.failed > 0);
    free(input.data);
    for (int i = 0; i < count; i++)
        free(seeds[i].data.data);
}

/* ------------------------------------------------------------------------------------------ */
/* NRRD volumes                                                                               */
/* ------------------------------------------------------------------------------------------ */

static const char *const nrrd_tokens[] = {
    "-1", "0", "1", "2", "3", "4", "5", "2147483648", "4294967296", "18446744073709551616",
    "99999999999999999999999", "2 2", "2 2 2 2 2", "65536 65536 65536", "2147483648 2147483648 2",
    "-2 2 2", "1 1 1", "nan", "inf", "1e999", "-0", "", " ", "gzip", "ascii", "hex", "raw", "bzip2",
    "little", "big", "middle", "uint8", "int8", "uint16", "short", "int", "uint32", "float",
    "double", "int64", "block", "none", "(1,0,0) (0,1,0) (0,0,1)", "(1,0,0) (0,1,0)",
    "none (1,0,0) (0,1,0) (0,0,1)", "(0,1,0) (1,0,0) (0,0,1)", "(-1,0,0) (0,1,0) (0,0,1)",
    "(nan,0,0) (0,1,0) (0,0,1)", "(1e999,0,0) (0,1,0) (0,0,1)", "(1,2,3)", "(1,2)", "(1,2,3",
    "((1,2,3)", "1 nan 1", "nan 1 1 1", "0 1 1", "x.raw", "right-anterior-superior"};

static const char *const nrrd_fields[] = {
    "type", "dimension", "sizes", "encoding", "endian", "space dimension", "space", "space origin",
    "space directions", "spacings", "byte skip", "line skip", "data file", "kinds", "content",
    "block size", "frobnicate", "centers"};

/* Replace the value of a random header line, rename its field, or add a field line. */
static void mutate_nrrd_header(buf *b, rng *r)
{
    size_t end = 0;
    for (size_t i = 0; i + 1 < b->len; i++)
        if (b->data[i] == '\n' && b->data[i + 1] == '\n') {
            end = i + 1;
            break;
        }
    if (end == 0)
        end = b->len;
    /* Pick a line start inside the header (not the magic line, most of the time). */
    size_t starts[64], n = 0;
    for (size_t i = 0; i < end && n < 64; i++)
        if (i == 0 || b->data[i - 1] == '\n')
            starts[n++] = i;
    if (n == 0)
        return;
    size_t line = starts[below(r, n)];
    size_t line_end = line;
    while (line_end < end && b->data[line_end] != '\n')
        line_end++;
    char tmp[128];
    switch (below(r, 3)) {
    case 0: { /* new value */
        size_t colon = line;
        while (colon + 1 < line_end && !(b->data[colon] == ':' && b->data[colon + 1] == ' '))
            colon++;
        if (colon + 1 < line_end)
            buf_replace(b, colon + 2, line_end - colon - 2, nrrd_tokens[below(r, sizeof(nrrd_tokens) / sizeof(nrrd_tokens[0]))]);
        break;
    }
    case 1: /* a whole new field line */
        snprintf(tmp, sizeof(tmp), "%s: %s\n", nrrd_fields[below(r, sizeof(nrrd_fields) / sizeof(nrrd_fields[0]))],
                 nrrd_tokens[below(r, sizeof(nrrd_tokens) / sizeof(nrrd_tokens[0]))]);
        buf_insert(b, line, tmp, strlen(tmp));
        break;
    default: /* drop the line */
        buf_erase(b, line, line_end - line + (line_end < b->len ? 1 : 0));
        break;
    }
}

static int load_nrrd_seeds(nacre_context *ctx, buf *seeds)
{
    int n = 0;
    if (read_file(EXAMPLES "/hetero_density.nrrd", &seeds[n]))
        n++;
    /* A voxelizer export (2 channels, uint8). */
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
    sd.segments = 12;
    sd.rings = 6;
    nacre_mesh_data mesh = {0};
    nacre_voxel_grid *grid = NULL;
    nacre_voxel_settings vs = nacre_voxel_settings_defaults();
    vs.resolution = 6;
    if (nacre_mesh_make_shape(ctx, &sd, &mesh) == NACRE_OK && nacre_voxelize(ctx, &mesh, &vs, &grid, NULL) == NACRE_OK &&
        nacre_voxel_grid_write_nrrd(grid, 0, TMP "/fuzz_seed_voxels.nrrd") == NACRE_OK &&
        read_file(TMP "/fuzz_seed_voxels.nrrd", &seeds[n]))
        n++;
    nacre_voxel_grid_destroy(grid);
    nacre_mesh_data_free(ctx, &mesh);
    /* 4D big-endian floats with directions; 3D uint16 with spacings and a byte skip. */
    static const char f4[] = "NRRD0005\ntype: float\ndimension: 4\nsizes: 2 3 2 2\nencoding: raw\nendian: big\n"
                             "space dimension: 3\nspace origin: (1,2,3)\n"
                             "space directions: none (0.5,0,0) (0,0.5,0) (0,0,2)\n\n";
    buf_set(&seeds[n], f4, sizeof(f4) - 1);
    for (int i = 0; i < 24; i++) {
        float v = 0.25f * (float)i;
        uint32_t u;
        memcpy(&u, &v, 4);
        char be[4] = {(char)(u >> 24), (char)(u >> 16), (char)(u >> 8), (char)u};
        buf_insert(&seeds[n], seeds[n].len, be, 4);
    }
    n++;
    static const char u16[] = "NRRD0004\n# spacings\ntype: unsigned short\ndimension: 3\nsizes: 3 2 2\n"
                              "encoding: raw\nendian: little\nspacings: 1 2 3\nbyte skip: 4\n\nskip";
    buf_set(&seeds[n], u16, sizeof(u16) - 1);
    for (int i = 0; i < 12; i++) {
        char le[2] = {(char)(i * 100), (char)((i * 100) >> 8)};
        buf_insert(&seeds[n], seeds[n].len, le, 2);
    }
    n++;
    return n;
}

static void fuzz_nrrd(nacre_context *ctx, counter *c, rng *r, int iterations)
{
    buf seeds[4];
    memset(seeds, 0, sizeof(seeds));
    int count = load_nrrd_seeds(ctx, seeds);
    CHECK(count == 4);
    long baseline = c->live;
    /* The unmutated seeds load. */
    for (int i = 0; i < count; i++) {
        nacre_volume_data v;
        nacre_result res = nc_nrrd_parse(ctx, "seed.nrrd", (const uint8_t *)seeds[i].data, seeds[i].len, 0, &v);
        CHECK(res == NACRE_OK);
        if (res != NACRE_OK)
            printf("nrrd seed %d: %s\n", i, nacre_context_last_error(ctx));
        nacre_volume_data_free(ctx, &v);
    }
    nacre_scene *scene = NULL;
    CHECK(nacre_scene_create(ctx, &scene) == NACRE_OK);
    if (!scene)
        return;
    baseline = c->live;
    buf input = {0};
    stats st = {0};
    double start = seconds();
    for (int it = 0; it < iterations; it++) {
        if (seconds() - start > PHASE_BUDGET_S) {
            printf("nrrd fuzz: time budget reached after %d iterations\n", it);
            break;
        }
        const buf *seed = &seeds[below(r, (size_t)count)];
        buf_set(&input, seed->data, seed->len);
        for (size_t m = 1 + below(r, 3); m > 0; m--) {
            if (below(r, 2))
                mutate_nrrd_header(&input, r);
            else
                mutate_once(&input, r, seeds, count, true);
        }
        write_file(TMP "/fuzz_volume.nrrd", &input); /* left behind if this input crashes */
        uint32_t channel = (uint32_t)below(r, 3) == 0 ? 1u : 0u;
        nacre_volume_data v;
        memset(&v, 0x5a, sizeof(v));
        /* Mostly in memory; now and then through the file loader. */
        nacre_result res = below(r, 8) == 0
            ? nacre_volume_load_nrrd(ctx, TMP "/fuzz_volume.nrrd", channel, &v)
            : nc_nrrd_parse(ctx, "fuzz.nrrd", (const uint8_t *)input.data, input.len, channel, &v);
        st.runs++;
        bool good;
        if (res == NACRE_OK) {
            st.ok++;
            size_t n = (size_t)v.dims[0] * v.dims[1] * v.dims[2];
            good = v.data != NULL && n >= 1;
            for (size_t i = 0; good && i < n; i++)
                good = isfinite(v.data[i]) && v.data[i] >= 0;
            nacre_volume h = {0};
            good = good && nacre_scene_add_volume(scene, &v, &h) == NACRE_OK;
            const nc_volume_rec *rec = good ? nc_scene_volume(scene, h) : NULL;
            for (int k = 0; rec && k < 16; k++) {
                float p[3] = {(float)below(r, 41) - 20.0f, (float)below(r, 41) - 20.0f, (float)below(r, 41) - 20.0f};
                float d = nc_volume_density(rec, p);
                good = good && d >= rec->min_value && d <= rec->max_value;
            }
        } else {
            st.failed++;
            const char *msg = nacre_context_last_error(ctx);
            good = v.data == NULL && v.dims[0] == 0 && message_ok(ctx) &&
                   (strncmp(msg, "fuzz.nrrd: ", 11) == 0 || strstr(msg, "fuzz_volume.nrrd: ") == msg ||
                    strstr(msg, "/fuzz_volume.nrrd: ") != NULL);
        }
        nacre_volume_data_free(ctx, &v);
        /* The scene keeps the volumes it accepted; everything else is returned. */
        if (res != NACRE_OK)
            good = good && c->live == baseline;
        baseline = c->live;
        if (!good) {
            st.bad++;
            if (st.bad <= 5)
                printf("nrrd fuzz iteration %d: result %d, message \"%s\"\n", it, (int)res,
                       nacre_context_last_error(ctx));
        }
    }
    printf("nrrd fuzz: %d inputs, %d loaded, %d rejected, %d bad (%.1f s)\n", st.runs, st.ok, st.failed, st.bad,
           seconds() - start);
    CHECK(st.bad == 0);
    CHECK(st.ok > 0 && st.failed > 0);
    nacre_scene_destroy(scene);
    free(input.data);
    for (int i = 0; i < count; i++)
        free(seeds[i].data);
}

int main(void)
{
    counter c = {0};
    nacre_context_desc desc = {{count_alloc, count_free, &c}, 1, NULL, NULL, 0};
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(&desc, &ctx) == NACRE_OK);
    if (!ctx)
        return TEST_MAIN_END();
    mkdir(TMP, 0755);
    int scale = fuzz_scale();
    rng r = {0x9E3779B97F4A7C15ULL};
    /* NACRE_FUZZ_ONLY=scene|mesh|nrrd runs one phase (for long runs of one parser). */
    const char *only = getenv("NACRE_FUZZ_ONLY");
    if (!only || strcmp(only, "scene") == 0)
        fuzz_scenes(ctx, &c, &r, SCENE_ITERATIONS * scale);
    if (!only || strcmp(only, "mesh") == 0)
        fuzz_meshes(ctx, &c, &r, MESH_ITERATIONS * scale);
    if (!only || strcmp(only, "nrrd") == 0)
        fuzz_nrrd(ctx, &c, &r, NRRD_ITERATIONS * scale);
    nacre_context_destroy(ctx);
    CHECK(c.live == 0);
    return TEST_MAIN_END();
}
