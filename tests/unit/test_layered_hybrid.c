/*
 * test_layered_hybrid.c: the layered method's multiple scattering ("multiple_scattering":
 * "diffusion", issue 23 item 5): a small sphere of thin, high-albedo skin layers over a skin core
 * rendered by the path tracer with every scattering order (fixed seed) as the reference, by the
 * layered method alone (single scattering), by the diffusion method on the core material alone,
 * and by the hybrid. The hybrid must come closer to the reference than both parts on two
 * measures: the error of the image's total per channel (what single scattering loses and the
 * layerless core adds) and the mean relative error of 4 x 4 pixel blocks (where the
 * reference's noise averages down). Also: "none" renders exactly the single-scattering image
 * (and turning the option off again gives it back), a camera move reuses the diffusion solve,
 * an unknown value is refused naming the field (scene loader and CLI, exit 2), and the option
 * round-trips through a saved scene.
 */
#include "test_util.h"

#include <nacre/nacre.h>

#include <sys/wait.h>

static nacre_context *ctx;

#define W 40
#define H 32

/* The skin of examples/layered_ms.json (epidermis, veins, dermis over a skin2 core) on a sphere of
 * radius 6 mm; `ms` is the material's multiple_scattering ("" leaves the key out), `layers` false
 * gives the core material alone. */
static const char *scene_json(char *buf, size_t size, const char *ms, bool layers)
{
    char extra[512];
    snprintf(extra, sizeof(extra), "%s%s%s%s", ms[0] ? "\"multiple_scattering\": \"" : "", ms, ms[0] ? "\"," : "",
             layers ? " \"depth_map\": \"layered_depth.png\","
                      " \"layers\": [{\"sigma_a\": [0.05, 0.12, 0.3], \"sigma_s\": [4, 4, 4], \"g\": 0.8, \"depth\": 0.15},"
                      " {\"sigma_a\": [0.3, 1.5, 1.2], \"sigma_s\": [1.5, 1.5, 1.5], \"g\": 0.9, \"depth\": 0.6},"
                      " {\"preset\": \"skin1\", \"depth\": 1.5}],"
                    : "");
    snprintf(buf, size,
             "{\"units\": \"mm\","
             " \"camera\": {\"type\": \"perspective\", \"position\": [0, 11, 33], \"target\": [0, 6, 0], \"fov\": 28},"
             " \"environment\": [0, 0, 0],"
             " \"materials\": {\"skin\": {\"preset\": \"skin2\", \"eta\": 1.4, %s \"specular\": 0}},"
             " \"lights\": [{\"type\": \"directional\", \"direction\": [-0.5, -0.6, -0.62], \"irradiance\": [3, 2.9, 2.7]}],"
             " \"objects\": [{\"name\": \"ball\", \"shape\": {\"type\": \"sphere\", \"radius\": 6, \"segments\": 64,"
             "   \"rings\": 32}, \"material\": \"skin\", \"transform\": {\"translate\": [0, 6, 0]}}]}",
             extra);
    return buf;
}

static nacre_scene *load(const char *json)
{
    nacre_scene *s = NULL;
    if (nacre_scene_load_json(ctx, json, strlen(json), "ball.json", NACRE_SOURCE_DIR "/examples", &s, NULL) !=
        NACRE_OK) {
        printf("load: %s\n", nacre_context_last_error(ctx));
        return NULL;
    }
    if (nacre_scene_commit(s, 0) != NACRE_OK) {
        printf("commit: %s\n", nacre_context_last_error(ctx));
        nacre_scene_destroy(s);
        return NULL;
    }
    return s;
}

static nacre_render_settings settings(nacre_method method)
{
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = method;
    rs.width = W;
    rs.height = H;
    rs.diffusion.voxel_resolution = 32;
    return rs;
}

static double px(const nacre_image *im, int x, int y, int c)
{
    return im->pixels[im->stride * (size_t)y + 3 * (size_t)x + (size_t)c];
}

/* Mean over channels of |sum(test) / sum(ref) - 1|. */
static double total_error(const nacre_image *t, const nacre_image *r)
{
    double e = 0;
    for (int c = 0; c < 3; c++) {
        double st = 0, sr = 0;
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++)
                st += px(t, x, y, c), sr += px(r, x, y, c);
        e += fabs(st / sr - 1) / 3;
    }
    return e;
}

/* Mean relative error of 4 x 4 block sums over the blocks whose reference is above 5% of the
 * brightest block (the lit ball; the silhouette's few samples and the background left out). */
static double block_error(const nacre_image *t, const nacre_image *r)
{
    double bt[H / 4][W / 4][3], br[H / 4][W / 4][3], peak = 0;
    memset(bt, 0, sizeof(bt));
    memset(br, 0, sizeof(br));
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++)
            for (int c = 0; c < 3; c++) {
                bt[y / 4][x / 4][c] += px(t, x, y, c);
                br[y / 4][x / 4][c] += px(r, x, y, c);
            }
    for (int y = 0; y < H / 4; y++)
        for (int x = 0; x < W / 4; x++)
            for (int c = 0; c < 3; c++)
                peak = fmax(peak, br[y][x][c]);
    double sum = 0;
    int n = 0;
    for (int y = 0; y < H / 4; y++)
        for (int x = 0; x < W / 4; x++)
            for (int c = 0; c < 3; c++)
                if (br[y][x][c] > 0.05 * peak) {
                    sum += fabs(bt[y][x][c] - br[y][x][c]) / br[y][x][c];
                    n++;
                }
    return n ? sum / n : INFINITY;
}

static bool render(nacre_renderer *r, const nacre_scene *s, const nacre_render_settings *rs, nacre_image *out,
                   nacre_render_stats *stats)
{
    nacre_image_free(ctx, out);
    if (nacre_renderer_render(r, s, rs, out, stats) != NACRE_OK) {
        printf("render: %s\n", nacre_context_last_error(ctx));
        return false;
    }
    return true;
}

static void test_against_pathtrace(void)
{
#ifdef NACRE_HAVE_EMBREE
    char buf[4096];
    nacre_scene *hybrid = load(scene_json(buf, sizeof(buf), "diffusion", true));
    nacre_scene *single = load(scene_json(buf, sizeof(buf), "none", true));
    nacre_scene *core = load(scene_json(buf, sizeof(buf), "", false));
    nacre_renderer *r = NULL;
    CHECK(nacre_renderer_create(ctx, &r) == NACRE_OK);
    nacre_image ref = {0}, img_single = {0}, img_diff = {0}, img_hybrid = {0}, img = {0};
    bool ok = hybrid && single && core && r;
    nacre_render_settings rs = settings(NACRE_METHOD_PATHTRACE);
    rs.pathtrace.spp = 48;
    rs.pathtrace.seed = 7;
    ok = ok && render(r, single, &rs, &ref, NULL);
    rs = settings(NACRE_METHOD_LAYERED);
    ok = ok && render(r, single, &rs, &img_single, NULL);
    ok = ok && render(r, hybrid, &rs, &img_hybrid, NULL);
    /* A camera move: the diffusion stages are reused, only the frame is drawn again. */
    nacre_render_stats st;
    nacre_camera_desc cam;
    ok = ok && nacre_scene_get_camera(hybrid, &cam) == NACRE_OK;
    cam.position[0] += 0.5f;
    ok = ok && nacre_scene_set_camera(hybrid, &cam) == NACRE_OK && nacre_scene_commit(hybrid, 0) == NACRE_OK;
    ok = ok && render(r, hybrid, &rs, &img, &st);
    CHECK(ok && st.stage_runs[NACRE_STAGE_PROPAGATE] == 0 && st.stage_runs[NACRE_STAGE_MEDIUM] == 0 &&
          st.stage_runs[NACRE_STAGE_MARCH] == 1);
    rs = settings(NACRE_METHOD_DIFFUSION);
    ok = ok && render(r, core, &rs, &img_diff, NULL);
    CHECK(ok);
    if (ok) {
        double te[3] = {total_error(&img_single, &ref), total_error(&img_diff, &ref), total_error(&img_hybrid, &ref)};
        double be[3] = {block_error(&img_single, &ref), block_error(&img_diff, &ref), block_error(&img_hybrid, &ref)};
        printf("against the path tracer: total error single %.3f diffusion %.3f hybrid %.3f; "
               "block error single %.3f diffusion %.3f hybrid %.3f\n",
               te[0], te[1], te[2], be[0], be[1], be[2]);
        /* Margins: the hybrid's error below half the better part's on the totals and below 0.7
         * of it on the blocks (measured: totals 0.05 against single 0.92 and diffusion 1.18;
         * blocks 0.20 against 0.93 and 1.19, mostly the reference's noise at 48 spp: a second
         * seed's reference differs from this one by 0.04 on the totals). */
        CHECK(te[2] < 0.5 * fmin(te[0], te[1]));
        CHECK(be[2] < 0.7 * fmin(be[0], be[1]));
    }
    nacre_image_free(ctx, &ref);
    nacre_image_free(ctx, &img_single);
    nacre_image_free(ctx, &img_diff);
    nacre_image_free(ctx, &img_hybrid);
    nacre_image_free(ctx, &img);
    nacre_renderer_destroy(r);
    nacre_scene_destroy(hybrid);
    nacre_scene_destroy(single);
    nacre_scene_destroy(core);
#endif
}

/* "none" is the layered method's image as it was: no key and "none" render the same pixels, and
 * a renderer that ran the hybrid gives them back when the option is turned off. */
static void test_none_is_single(void)
{
    char buf[4096];
    nacre_scene *plain = load(scene_json(buf, sizeof(buf), "", true));
    nacre_scene *s = load(scene_json(buf, sizeof(buf), "none", true));
    nacre_renderer *r = NULL;
    CHECK(nacre_renderer_create(ctx, &r) == NACRE_OK);
    nacre_image a = {0}, b = {0}, c = {0};
    nacre_render_settings rs = settings(NACRE_METHOD_LAYERED);
    bool ok = plain && s && r && render(r, plain, &rs, &a, NULL) && render(r, s, &rs, &b, NULL);
    CHECK(ok);
    nacre_material_desc m;
    nacre_material mat = {1};
    ok = ok && nacre_scene_get_material(s, mat, &m) == NACRE_OK;
    CHECK(ok && m.layering.multiple_scattering == NACRE_MULTIPLE_SCATTERING_NONE);
#ifdef NACRE_HAVE_EMBREE
    m.layering.multiple_scattering = NACRE_MULTIPLE_SCATTERING_DIFFUSION;
    ok = ok && nacre_scene_set_material(s, mat, &m) == NACRE_OK && nacre_scene_commit(s, 0) == NACRE_OK &&
         render(r, s, &rs, &c, NULL);
    CHECK(ok);
    double sb = 0, sc = 0;
    for (int y = 0; ok && y < H; y++)
        for (int x = 0; x < W; x++)
            sb += px(&b, x, y, 1), sc += px(&c, x, y, 1);
    CHECK(ok && sc > 1.5 * sb); /* the multiply scattered light is most of this skin's */
    m.layering.multiple_scattering = NACRE_MULTIPLE_SCATTERING_NONE;
    ok = ok && nacre_scene_set_material(s, mat, &m) == NACRE_OK && nacre_scene_commit(s, 0) == NACRE_OK &&
         render(r, s, &rs, &c, NULL);
#else
    ok = ok && render(r, s, &rs, &c, NULL);
#endif
    CHECK(ok);
    if (ok)
        for (int y = 0; y < H; y++) {
            CHECK(memcmp(a.pixels + a.stride * (size_t)y, b.pixels + b.stride * (size_t)y, 3 * W * sizeof(float)) == 0);
            CHECK(memcmp(b.pixels + b.stride * (size_t)y, c.pixels + c.stride * (size_t)y, 3 * W * sizeof(float)) == 0);
        }
    nacre_image_free(ctx, &a);
    nacre_image_free(ctx, &b);
    nacre_image_free(ctx, &c);
    nacre_renderer_destroy(r);
    nacre_scene_destroy(plain);
    nacre_scene_destroy(s);
}

/* The diffusion method on a layered material solves on each voxel's mean of its layers' and
 * core's coefficients: a layer equal to the core changes nothing, a layer deeper than the ball
 * is the whole medium, and the skin's thin layers change the image. */
static nacre_scene *two_media(const char *core, const char *layer, double depth)
{
    char layers[256] = "", buf[4096];
    if (layer)
        snprintf(layers, sizeof(layers), "\"layers\": [{\"preset\": \"%s\", \"depth\": %g}],", layer, depth);
    snprintf(buf, sizeof(buf),
             "{\"units\": \"mm\","
             " \"camera\": {\"type\": \"perspective\", \"position\": [0, 11, 33], \"target\": [0, 6, 0], \"fov\": 28},"
             " \"environment\": [0, 0, 0],"
             " \"materials\": {\"skin\": {\"preset\": \"%s\", \"eta\": 1.4, %s \"specular\": 0}},"
             " \"lights\": [{\"type\": \"directional\", \"direction\": [-0.5, -0.6, -0.62], \"irradiance\": [3, 2.9, 2.7]}],"
             " \"objects\": [{\"name\": \"ball\", \"shape\": {\"type\": \"sphere\", \"radius\": 6, \"segments\": 64,"
             "   \"rings\": 32}, \"material\": \"skin\", \"transform\": {\"translate\": [0, 6, 0]}}]}",
             core, layers);
    return load(buf);
}

/* Largest per-pixel difference relative to the brightest value of b. */
static double max_diff(const nacre_image *a, const nacre_image *b)
{
    double peak = 0, d = 0;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++)
            for (int c = 0; c < 3; c++) {
                peak = fmax(peak, px(b, x, y, c));
                d = fmax(d, fabs(px(a, x, y, c) - px(b, x, y, c)));
            }
    return peak > 0 ? d / peak : INFINITY;
}

static void test_diffusion_of_layers(void)
{
#ifdef NACRE_HAVE_EMBREE
    nacre_scene *skin2 = two_media("skin2", NULL, 0), *same = two_media("skin2", "skin2", 1.5);
    nacre_scene *skin1 = two_media("skin1", NULL, 0), *deep = two_media("skin2", "skin1", 20);
    char buf[4096];
    nacre_scene *layered = load(scene_json(buf, sizeof(buf), "", true));
    nacre_renderer *r = NULL;
    CHECK(nacre_renderer_create(ctx, &r) == NACRE_OK);
    nacre_image a = {0}, b = {0}, c = {0}, d = {0}, e = {0};
    nacre_render_settings rs = settings(NACRE_METHOD_DIFFUSION);
    bool ok = skin2 && same && skin1 && deep && layered && r;
    ok = ok && render(r, skin2, &rs, &a, NULL) && render(r, same, &rs, &b, NULL);
    ok = ok && render(r, skin1, &rs, &c, NULL) && render(r, deep, &rs, &d, NULL);
    ok = ok && render(r, layered, &rs, &e, NULL);
    CHECK(ok);
    if (ok) {
        double same_d = max_diff(&b, &a), deep_d = max_diff(&d, &c), thin_d = max_diff(&e, &a);
        printf("diffusion of layers: same as core %.2e, deep layer %.2e, thin skin layers %.3f\n", same_d, deep_d,
               thin_d);
        /* Float rounding of the heterogeneous path against the constant one. */
        CHECK(same_d < 1e-3);
        CHECK(deep_d < 1e-3);
        CHECK(thin_d > 0.05);
    }
    nacre_image_free(ctx, &a);
    nacre_image_free(ctx, &b);
    nacre_image_free(ctx, &c);
    nacre_image_free(ctx, &d);
    nacre_image_free(ctx, &e);
    nacre_renderer_destroy(r);
    nacre_scene_destroy(skin2);
    nacre_scene_destroy(same);
    nacre_scene_destroy(skin1);
    nacre_scene_destroy(deep);
    nacre_scene_destroy(layered);
#endif
}

/* Unknown values name the field; the CLI exits 2 with one line; a saved scene keeps the option. */
static void test_bad_input_and_save(void)
{
    char buf[4096];
    const char *json = scene_json(buf, sizeof(buf), "photon", true);
    nacre_scene *s = NULL;
    CHECK(nacre_scene_load_json(ctx, json, strlen(json), "ball.json", NACRE_SOURCE_DIR "/examples", &s, NULL) ==
          NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(s == NULL && strstr(nacre_context_last_error(ctx), "multiple_scattering") != NULL);
    CHECK(strstr(nacre_context_last_error(ctx), "photon") != NULL);
    /* The C API's value is checked with the rest of the material. */
    s = load(scene_json(buf, sizeof(buf), "diffusion", true));
    CHECK(s != NULL);
    if (s) {
        nacre_material_desc m;
        nacre_material mat = {1};
        CHECK(nacre_scene_get_material(s, mat, &m) == NACRE_OK &&
              m.layering.multiple_scattering == NACRE_MULTIPLE_SCATTERING_DIFFUSION);
        m.layering.multiple_scattering = (nacre_multiple_scattering)7;
        CHECK(nacre_scene_set_material(s, mat, &m) == NACRE_ERROR_INVALID_ARGUMENT);
        CHECK(strstr(nacre_context_last_error(ctx), "multiple_scattering") != NULL);
        /* Round trip through a saved scene. */
        char path[512];
        snprintf(path, sizeof(path), "%s/hybrid_saved.json", NACRE_TEST_TMP);
        CHECK(nacre_scene_save_file(s, NULL, path) == NACRE_OK);
        nacre_scene *t = NULL;
        CHECK(nacre_scene_load_file(ctx, path, &t, NULL) == NACRE_OK);
        if (t) {
            CHECK(nacre_scene_get_material(t, mat, &m) == NACRE_OK &&
                  m.layering.multiple_scattering == NACRE_MULTIPLE_SCATTERING_DIFFUSION && m.layering.count == 3);
            nacre_scene_destroy(t);
        }
        nacre_scene_destroy(s);
    }
    /* The CLI: exit 2 and one line naming the field. */
    char path[512], cmd[2048];
    snprintf(path, sizeof(path), "%s/hybrid_bad.json", NACRE_TEST_TMP);
    FILE *f = fopen(path, "w");
    CHECK(f != NULL);
    if (!f)
        return;
    /* The depth map is relative to the scene file: leave the layers out. */
    fputs(scene_json(buf, sizeof(buf), "photon", false), f);
    fclose(f);
    snprintf(cmd, sizeof(cmd), "%s render %s -o %s/hybrid_bad.png 2>%s/hybrid_bad.txt", NACRE_CLI, path,
             NACRE_TEST_TMP, NACRE_TEST_TMP);
    int st = system(cmd);
    CHECK(WIFEXITED(st) && WEXITSTATUS(st) == 2);
    snprintf(path, sizeof(path), "%s/hybrid_bad.txt", NACRE_TEST_TMP);
    char err[1024] = {0};
    f = fopen(path, "r");
    size_t n = f ? fread(err, 1, sizeof(err) - 1, f) : 0;
    if (f)
        fclose(f);
    err[n] = '\0';
    printf("cli: %s", err);
    CHECK(strstr(err, "multiple_scattering") != NULL);
    CHECK(n > 0 && strchr(err, '\n') == err + n - 1);
}

int main(void)
{
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    test_bad_input_and_save();
    test_none_is_single();
    test_diffusion_of_layers();
    test_against_pathtrace();
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
