/*
 * test_golden.c: every example scene (examples/<name>.json) rendered small and compared with its
 * reviewed reference image in tests/golden/<name>.exr (32-bit float).
 *
 * Tolerance: the renders are deterministic, but optimisation levels and sanitizer builds may
 * move a few silhouette or shadow-edge pixels by one step, so a test passes when at most 0.5% of
 * the values differ by more than 2% (relative, with a 1e-3 floor) and the RMSE stays below 1% of
 * the reference's mean. A broken shader, camera, light or loader changes far more than that.
 *
 * NACRE_UPDATE_GOLDEN=1 rewrites the references (after looking at them: tests/golden/README.md).
 */
#include "test_util.h"

#include <nacre/nacre.h>

#include <dirent.h>
#include <stdlib.h>
#include <string.h>

static int cmp_names(const void *a, const void *b) { return strcmp(*(char *const *)a, *(char *const *)b); }

static void check_scene(nacre_context *ctx, const char *name, bool update)
{
    char path[2048], golden[2048];
    snprintf(path, sizeof(path), "%s/examples/%s", NACRE_SOURCE_DIR, name);
    size_t n = strlen(name);
    snprintf(golden, sizeof(golden), "%s/tests/golden/%.*s.exr", NACRE_SOURCE_DIR, (int)(n - 5), name);
    nacre_scene *scene = NULL;
    nacre_render_settings rs;
    nacre_image img = {0}, ref = {0};
    if (nacre_scene_load_file(ctx, path, &scene, &rs) != NACRE_OK) {
        printf("%s: %s\n", name, nacre_context_last_error(ctx));
        CHECK(!"example scene loads");
        return;
    }
    rs.height = (int32_t)((160.0 * rs.height) / rs.width + 0.5);
    rs.width = 160;
    if (rs.height < 1)
        rs.height = 1;
    rs.method = NACRE_METHOD_PHONG;
    rs.shadow_map_size = 1024;
    bool ok = nacre_scene_commit(scene, rs.time) == NACRE_OK && nacre_render(scene, &rs, &img, NULL) == NACRE_OK;
    if (!ok)
        printf("%s: %s\n", name, nacre_context_last_error(ctx));
    CHECK(ok);
    if (ok && update) {
        CHECK(nacre_image_write_exr(ctx, &img, golden, NACRE_EXR_FLOAT) == NACRE_OK);
        printf("updated %s\n", golden);
    } else if (ok) {
        if (nacre_image_read(ctx, golden, &ref) != NACRE_OK) {
            printf("%s: no reference image (%s)\n", name, nacre_context_last_error(ctx));
            CHECK(!"reference image exists");
        } else if (ref.width != img.width || ref.height != img.height) {
            CHECK(!"reference image has the render's size");
        } else {
            size_t bad = 0, count = 0;
            double se = 0, sum = 0;
            for (int y = 0; y < img.height; y++)
                for (int x = 0; x < img.width; x++)
                    for (int c = 0; c < 3; c++) {
                        double a = img.pixels[(size_t)y * img.stride + 3 * (size_t)x + c];
                        double b = ref.pixels[(size_t)y * ref.stride + (size_t)ref.channels * (size_t)x + c];
                        double d = fabs(a - b);
                        bad += d > 0.02 * fmax(fabs(b), 1e-3 / 0.02);
                        se += d * d;
                        sum += b;
                        count++;
                    }
            double rmse = sqrt(se / (double)count), mean = sum / (double)count;
            double bad_fraction = (double)bad / (double)count;
            printf("%-28s bad values %.4f%%  rmse/mean %.5f\n", name, 100 * bad_fraction, rmse / mean);
            CHECK(bad_fraction <= 0.005);
            CHECK(rmse <= 0.01 * mean);
        }
    }
    nacre_image_free(ctx, &img);
    nacre_image_free(ctx, &ref);
    nacre_scene_destroy(scene);
}

int main(void)
{
    const char *env = getenv("NACRE_UPDATE_GOLDEN");
    bool update = env && strcmp(env, "1") == 0;
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    char dir[2048];
    snprintf(dir, sizeof(dir), "%s/examples", NACRE_SOURCE_DIR);
    DIR *d = opendir(dir);
    CHECK(d != NULL);
    char *names[256];
    int count = 0;
    struct dirent *e;
    while (d && (e = readdir(d)) && count < 256) {
        size_t n = strlen(e->d_name);
        if (n > 5 && strcmp(e->d_name + n - 5, ".json") == 0)
            names[count++] = strdup(e->d_name);
    }
    if (d)
        closedir(d);
    qsort(names, (size_t)count, sizeof(char *), cmp_names);
    CHECK(count >= 5); /* the demo plus one scene per feature */
    for (int i = 0; i < count; i++) {
        check_scene(ctx, names[i], update);
        free(names[i]);
    }
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
