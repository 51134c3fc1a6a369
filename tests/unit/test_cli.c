/*
 * test_cli.c: the `nacre` command end to end: exit statuses, one-line errors naming the file,
 * no output left behind on failure, --stats / --json output that parses, help and version.
 */
#include "test_util.h"

#include <cjson/cJSON.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#define TMP NACRE_TEST_TMP "/cli"

/* Run `nacre ARGS`, capturing stdout and stderr; returns the exit status. */
static int run(const char *args, char *out, size_t out_cap, char *err, size_t err_cap)
{
    char cmd[4096];
    snprintf(cmd, sizeof(cmd), "%s %s >%s/stdout.txt 2>%s/stderr.txt", NACRE_CLI, args, TMP, TMP);
    int st = system(cmd);
    int code = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
    const char *names[2] = {"stdout.txt", "stderr.txt"};
    char *bufs[2] = {out, err};
    size_t caps[2] = {out_cap, err_cap};
    for (int i = 0; i < 2; i++) {
        if (!bufs[i])
            continue;
        char path[1024];
        snprintf(path, sizeof(path), "%s/%s", TMP, names[i]);
        FILE *f = fopen(path, "rb");
        size_t n = f ? fread(bufs[i], 1, caps[i] - 1, f) : 0;
        bufs[i][n] = '\0';
        if (f)
            fclose(f);
    }
    return code;
}

static bool exists(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0;
}

static void write_file(const char *path, const char *text)
{
    FILE *f = fopen(path, "wb");
    CHECK(f != NULL);
    if (f) {
        fputs(text, f);
        fclose(f);
    }
}

/* Only the final file (if any) in TMP: no *.tmp* leftovers. */
static int count_temp_files(void)
{
    char cmd[1024];
    snprintf(cmd, sizeof(cmd), "ls -a %s | grep -c tmp > %s/count.txt", TMP, NACRE_TEST_TMP);
    if (system(cmd) < 0)
        return -1;
    char path[1024];
    snprintf(path, sizeof(path), "%s/count.txt", NACRE_TEST_TMP);
    FILE *f = fopen(path, "r");
    int n = -1;
    if (f) {
        if (fscanf(f, "%d", &n) != 1)
            n = -1;
        fclose(f);
    }
    return n;
}

static char out[1 << 16], err[1 << 16];

static void test_help_version(void)
{
    CHECK(run("--version", out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(strstr(out, "nacre") != NULL);
    const char *cmds[] = {"render", "info", "compare", "bench"};
    for (int i = 0; i < 4; i++) {
        char a[64];
        snprintf(a, sizeof(a), "%s --help", cmds[i]);
        CHECK(run(a, out, sizeof(out), err, sizeof(err)) == 0);
        CHECK(strstr(out, "usage") != NULL);
        snprintf(a, sizeof(a), "%s --version", cmds[i]);
        CHECK(run(a, out, sizeof(out), err, sizeof(err)) == 0);
    }
    CHECK(run("frobnicate", out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(run("", out, sizeof(out), err, sizeof(err)) == 2);
}

static void test_render_errors(void)
{
    char args[8192], outpng[1024];
    snprintf(outpng, sizeof(outpng), "%s/out.png", TMP);
    /* Unknown flag, unknown method, bad size, bad output extension. */
    snprintf(args, sizeof(args), "render --frobnicate -o %s", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "--frobnicate") != NULL);
    snprintf(args, sizeof(args), "render --method magic -o %s", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "magic") != NULL);
    snprintf(args, sizeof(args), "render --size 0x10 -o %s", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    snprintf(args, sizeof(args), "render --size 100000x10 -o %s", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    snprintf(args, sizeof(args), "render --size 16384x16384 -o %s", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "pixels") != NULL);
    snprintf(args, sizeof(args), "render -o %s/out.bmp", TMP);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    /* Known but not implemented method: a clear error, not a fake image. */
    snprintf(args, sizeof(args), "render --method layered -o %s", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "not implemented") != NULL);
    CHECK(!exists(outpng));
    /* A layered material under a method that has no layers yet: the same. */
    snprintf(args, sizeof(args), "render %s/examples/layered.json --method diffusion -o %s", NACRE_SOURCE_DIR, outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) != 0);
    CHECK(strstr(err, "object 'layered sphere' has a layered material") != NULL);
    CHECK(!exists(outpng));
    /* Path tracing with its variance image; --variance needs the path tracer. */
    char varexr[600];
    snprintf(varexr, sizeof(varexr), "%s/var.exr", TMP);
    snprintf(args, sizeof(args), "render --method pathtrace --size 32x24 --spp 2 --variance %s -o %s --stats", varexr,
             outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(exists(outpng) && exists(varexr));
    CHECK(strstr(out, "\"spp\":2") != NULL);
    remove(outpng);
    snprintf(args, sizeof(args), "render --method phong --variance %s -o %s", varexr, outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(!exists(outpng));
    /* Slab measurement: JSON with R and T; bad values are usage errors. */
    snprintf(args, sizeof(args), "slab --albedo 0.99 --json");
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(strstr(out, "\"R\":0.75") != NULL);
    snprintf(args, sizeof(args), "slab --albedo 0.9 --tau 1 --method pathtrace --samples 20000 --json");
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(strstr(out, "\"R_stderr\"") != NULL);
    snprintf(args, sizeof(args), "slab --albedo 1.5");
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "albedo") != NULL);
    snprintf(args, sizeof(args), "slab --tau -1");
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);

    /* Missing scene, malformed scene (line:col), unknown key: one line naming the file. */
    snprintf(args, sizeof(args), "render %s/missing.json -o %s", TMP, outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "missing.json") != NULL);
    char bad[1024];
    snprintf(bad, sizeof(bad), "%s/bad.json", TMP);
    write_file(bad, "{\n  \"camera\": {\"fov\": 40,\n  }\n");
    snprintf(args, sizeof(args), "render %s -o %s", bad, outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "bad.json:") != NULL);
    CHECK(strchr(err, '\n') == err + strlen(err) - 1); /* exactly one line */
    write_file(bad, "{\"camera\": {\"fov\": 40, \"zoom\": 2}, \"objects\": []}");
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "zoom") != NULL);
    CHECK(!exists(outpng));
    /* Unwritable output: error, no file, no temp file left. */
    snprintf(args, sizeof(args), "render --size 32x24 -o %s/no/such/dir/out.png", TMP);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "out.png") != NULL);
    CHECK(count_temp_files() == 0);
}

static void test_render_ok_and_stats(void)
{
    char args[8192], outpng[1024], outexr[1024];
    snprintf(outpng, sizeof(outpng), "%s/demo.png", TMP);
    snprintf(outexr, sizeof(outexr), "%s/demo.exr", TMP);
    snprintf(args, sizeof(args), "render --size 96x54 -o %s --stats", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(exists(outpng));
    cJSON *j = cJSON_Parse(out);
    CHECK(j != NULL);
    /* The built-in demo shows the best real-time method: diffusion, with the stat keys. */
    const char *keys[] = {"load_us",    "commit_us", "raster_us",    "gbuffer_us", "shadow_us",  "voxelize_us",
                          "tsm_us",     "inject_us", "propagate_us", "shade_us",   "write_us",   "total_us",
                          "iterations", "residual"};
    for (int i = 0; j && i < (int)(sizeof(keys) / sizeof(keys[0])); i++)
        CHECK(cJSON_IsNumber(cJSON_GetObjectItemCaseSensitive(j, keys[i])));
    cJSON *m = j ? cJSON_GetObjectItemCaseSensitive(j, "method") : NULL;
    CHECK(cJSON_IsString(m) && strcmp(m->valuestring, "diffusion") == 0);
    cJSON *sv = j ? cJSON_GetObjectItemCaseSensitive(j, "solver") : NULL;
    CHECK(cJSON_IsString(sv) && strcmp(sv->valuestring, "multigrid") == 0);
    cJSON *dims = j ? cJSON_GetObjectItemCaseSensitive(j, "voxel_dims") : NULL;
    CHECK(cJSON_IsArray(dims) && cJSON_GetArraySize(dims) == 3);
    cJSON *res = j ? cJSON_GetObjectItemCaseSensitive(j, "residual") : NULL;
    CHECK(cJSON_IsNumber(res) && res->valuedouble <= 1e-4);
    cJSON_Delete(j);
    /* The seed's solver and face source run too. */
    snprintf(args, sizeof(args), "render --size 64x36 --solver seed --source face --voxel-res 12 -o %s --stats", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(strstr(out, "\"solver\":\"seed\"") != NULL);
    snprintf(args, sizeof(args), "render --method phong --size 64x36 -o %s --stats", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    CHECK(strstr(out, "\"method\":\"phong\"") != NULL);
    snprintf(args, sizeof(args), "render --voxel-res 0 -o %s", outpng);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    snprintf(args, sizeof(args), "render %s/examples/demo.json --size 96x54 -o %s", NACRE_SOURCE_DIR, outexr);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    /* compare: an image against itself is exact. */
    snprintf(args, sizeof(args), "compare %s %s --json", outexr, outexr);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    j = cJSON_Parse(out);
    CHECK(j != NULL);
    cJSON *rmse = j ? cJSON_GetObjectItemCaseSensitive(j, "rmse") : NULL;
    CHECK(cJSON_IsNumber(rmse) && rmse->valuedouble == 0);
    cJSON_Delete(j);
    /* compare: size mismatch is an error. */
    char small[1024];
    snprintf(small, sizeof(small), "%s/small.exr", TMP);
    snprintf(args, sizeof(args), "render --size 48x27 -o %s", small);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    snprintf(args, sizeof(args), "compare %s %s", small, outexr);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    snprintf(args, sizeof(args), "compare %s %s/nothing.exr", small, TMP);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "nothing.exr") != NULL);
}

static void test_info(void)
{
    char args[8192];
    snprintf(args, sizeof(args), "info %s/examples/meshes/suzanne.ply --json", NACRE_SOURCE_DIR);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 0);
    cJSON *j = cJSON_Parse(out);
    CHECK(j != NULL);
    if (j) {
        /* Counts from ../shared/meshes/README.md: 968 triangles, 507 vertices, 42 / 0. */
        CHECK(cJSON_GetObjectItemCaseSensitive(j, "triangles")->valuedouble == 968);
        CHECK(cJSON_GetObjectItemCaseSensitive(j, "vertices")->valuedouble == 507);
        CHECK(cJSON_GetObjectItemCaseSensitive(j, "boundary_edges")->valuedouble == 42);
        CHECK(cJSON_GetObjectItemCaseSensitive(j, "nonmanifold_edges")->valuedouble == 0);
        CHECK(cJSON_IsFalse(cJSON_GetObjectItemCaseSensitive(j, "closed")));
    }
    cJSON_Delete(j);
    snprintf(args, sizeof(args), "info %s/none.ply", TMP);
    CHECK(run(args, out, sizeof(out), err, sizeof(err)) == 2);
    CHECK(strstr(err, "none.ply") != NULL);
    CHECK(run("info", out, sizeof(out), err, sizeof(err)) == 2);
}

int main(void)
{
    mkdir(NACRE_TEST_TMP, 0755);
    mkdir(TMP, 0755);
    test_help_version();
    test_render_errors();
    test_render_ok_and_stats();
    test_info();
    return TEST_MAIN_END();
}
