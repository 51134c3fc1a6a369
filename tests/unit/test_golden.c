/*
 * test_golden.c: every example scene (examples/<name>.json) rendered small by every method and
 * compared with its reviewed reference image in tests/golden/ (tests/golden/README.md):
 *
 *   <name>.exr                    phong, 32-bit float
 *   <name>.diffusion11.exr        diffusion at 11 voxels along each translucent object, half
 *   <name>.diffusion32.exr        diffusion at 32 voxels (the default), half
 *   <name>.pathtrace.exr          path tracer, seed 1, 8 samples per pixel, 32-bit float
 *   <name>.pathtrace.sd.exr       its per-pixel standard deviation of the mean, half
 *
 * all at 160 pixels wide. Diffusion is skipped, with a note, for scenes without a translucent
 * object (it would equal phong) and for layered materials in builds without Embree (the voxels'
 * depths below the surface need it); the path tracer for builds without Embree.
 *
 * Phong and diffusion tolerance: the renders are deterministic, but optimisation levels, FMA
 * contraction (the x86-64-v3 and the portable build) and sanitizer builds may move a few
 * silhouette or shadow-edge pixels by one step, and the multigrid solve stops at a residual, so a
 * test passes when at most 0.5% of the values differ by more than 2% (relative, with a 1e-3
 * floor) and the RMSE stays below 1% of the reference's mean. Half references add at most 0.05%.
 * A broken shader, camera, light, loader or solver changes far more than that. The coarse
 * resolution is odd on purpose: at even ones the centre plane of the symmetric scenes is a voxel
 * face, and spot_light at 12 (and 16) voxels differs between the two builds in a band of the
 * sphere (1% of the values, by up to 6%) while 11 and 13 agree to rounding.
 *
 * Path tracer tolerance: the same build and seed give the same image bit for bit (reported as
 * "exact"), but a build that rounds differently (FMA, another compiler, a reordered sum) sends
 * some paths elsewhere (the portable build keeps 50-75% of the values exact). So the check is
 * statistical, one that a render with ANOTHER seed passes too (NACRE_GOLDEN_SEED=N runs that),
 * with d = new - reference per value and v = var_new + var_ref (variances of the pixel means):
 *   - outliers: at most 1% of the values have |d| > 4 sqrt(v) + 1e-3 |ref| + 1e-5;
 *   - image mean, per channel: |sum d| <= 5 sqrt(sum v), a z-test with independent noise;
 *   - the whole image (t <= 5) and every 16x16 block (t <= 6), per channel, two scale-free
 *     tests: t = |sum d| / sqrt(sum d^2), and the sign test t = |n+ - n-| / sqrt(n+ + n-) over
 *     the values with |d| > 1e-3 |ref| + 1e-6. Pixels have independent random streams, so for
 *     the same scene the d are independent and symmetric about 0; given their magnitudes their
 *     signs are fair coins, and P(t > k) <= 2 exp(-k^2 / 2) (Hoeffding): 4e-6 for 5, 3e-8 for 6,
 *     whatever the noise is and however correlated new and reference are. A changed scene
 *     rendered with the same seed keeps most paths, so d is small but one-signed: these tests
 *     see changes that the noise hides from the z-test (the sum), and changes that one firefly
 *     hides from the sum (the signs).
 *   Floors: the z and sum tests pass when |sum d| <= 0.2% of sum |ref|, the sign test when
 *   |n+ - n-| <= 2% of the region's values. Rounding does not flip branches symmetrically: the
 *   portable build against the x86-64-v3 references shows sign imbalances up to 0.8% (layered,
 *   diffusion_suzanne) and a block of 20 same-signed values, with means within 0.6%; for
 *   layered_ms_fish the mean moves by 1% (t 5.3), so the portable build compares it at seed 2
 *   (same_seed_diverges).
 *
 * NACRE_UPDATE_GOLDEN=1 rewrites the references (after looking at them: tests/golden/README.md).
 * NACRE_GOLDEN_ONLY=SUBSTRING limits the run to the scenes whose file name contains it, and
 * NACRE_GOLDEN_METHODS=LIST (comma-separated method names, e.g. "pathtrace") to those methods:
 * with NACRE_UPDATE_GOLDEN=1 they rewrite only the references an intended change touched.
 */
#include "test_util.h"

#include "io/image_private.h"
#include "scene/scene.h"

#include <nacre/nacre.h>

#include <dirent.h>
#include <stdlib.h>
#include <string.h>

enum { WIDTH = 160, PT_SPP = 8, PT_SEED = 1, BLOCK = 16 };
static const double PT_K_VALUE = 4.0, PT_K_IMAGE = 5.0, PT_K_BLOCK = 6.0;
static const double PT_OUTLIER_FRACTION = 0.01, PT_FLOOR = 0.002, PT_SIGN_FLOOR = 1e-3, PT_SIGN_IMBALANCE = 0.02;

typedef struct variant {
    const char *suffix; /* reference file: <name><suffix>.exr */
    nacre_method method;
    uint32_t voxel_resolution;
    nacre_exr_pixel exr;
} variant;

static const variant VARIANTS[] = {
    {"", NACRE_METHOD_PHONG, 0, NACRE_EXR_FLOAT},
    {".diffusion11", NACRE_METHOD_DIFFUSION, 11, NACRE_EXR_HALF},
    {".diffusion32", NACRE_METHOD_DIFFUSION, 32, NACRE_EXR_HALF},
    {".pathtrace", NACRE_METHOD_PATHTRACE, 0, NACRE_EXR_FLOAT},
};

static struct {
    bool update;
    uint32_t seed;
    const char *methods; /* NULL: all */
    int written, compared, skipped;
    int per_method[NACRE_METHOD_COUNT];
} g;

static int cmp_names(const void *a, const void *b) { return strcmp(*(char *const *)a, *(char *const *)b); }

static bool method_listed(const char *list, nacre_method method)
{
    const char *name = nacre_method_name(method);
    size_t n = strlen(name);
    for (const char *p = list; *p;) {
        size_t len = strcspn(p, ",");
        if (len == n && strncmp(p, name, n) == 0)
            return true;
        p += len + (p[len] == ',');
    }
    return false;
}

static float px(const nacre_image *im, int x, int y, int c)
{
    return im->pixels[(size_t)y * im->stride + (size_t)im->channels * (size_t)x + (size_t)c];
}

/* Layered scenes with a veins map: in the portable build, the paths that rounding sends elsewhere
 * at seed 1 move the fish's mean by -0.8% to -1.2% (t 5.3), while seeds 2 and 3 pass in both
 * builds (t 0.6-1.0): a one-sided divergence of the same stream, not a different result. */
#ifndef __AVX2__
static bool same_seed_diverges(const char *stem) { return strcmp(stem, "layered_ms_fish") == 0; }
#endif

/* Phong and diffusion: deterministic up to rounding (see the top of the file). */
static void compare_raster(const char *label, const nacre_image *img, const nacre_image *ref)
{
    size_t bad = 0, count = 0;
    double se = 0, sum = 0;
    for (int y = 0; y < img->height; y++)
        for (int x = 0; x < img->width; x++)
            for (int c = 0; c < 3; c++) {
                double a = px(img, x, y, c), b = px(ref, x, y, c);
                double d = fabs(a - b);
                bad += !(d <= 0.02 * fmax(fabs(b), 1e-3 / 0.02)); /* NaN counts as bad */
                se += d * d;
                sum += b;
                count++;
            }
    double rmse = sqrt(se / (double)count), mean = sum / (double)count;
    double bad_fraction = (double)bad / (double)count;
    printf("%-30s bad values %.4f%%  rmse/mean %.5f\n", label, 100 * bad_fraction, rmse / mean);
    CHECK(bad_fraction <= 0.005);
    CHECK(rmse <= 0.01 * mean);
}

/* Sums over a region (a block or the whole image) of one channel, for the path tracer. */
typedef struct region {
    double d, d2, ref, v; /* sums of d, d^2, |ref|, var_new + var_ref */
    long pos, neg, n;     /* values with d above / below the sign floor, all values */
} region;

static void region_add(region *r, double d, double b, double v)
{
    r->d += d;
    r->d2 += d * d;
    r->ref += fabs(b);
    r->v += v;
    double floor = PT_SIGN_FLOOR * fabs(b) + 1e-6;
    r->pos += d > floor;
    r->neg += d < -floor;
    r->n++;
}

/* The scale-free statistics (see the top of the file), 0 when the floor excuses the difference. */
static double region_t(const region *r)
{
    return fabs(r->d) > PT_FLOOR * r->ref ? fabs(r->d) / sqrt(r->d2) : 0;
}

static double region_s(const region *r)
{
    if (!(fabs((double)(r->pos - r->neg)) > PT_SIGN_IMBALANCE * (double)r->n))
        return 0;
    return fabs((double)(r->pos - r->neg)) / sqrt((double)(r->pos + r->neg));
}

/* Path tracer: a statistical comparison (see the top of the file). */
static void compare_pathtrace(const char *label, const nacre_image *img, const nacre_image *var,
                              const nacre_image *ref, const nacre_image *ref_sd)
{
    int w = img->width, h = img->height;
    size_t outliers = 0, exact = 0, count = 0;
    double worst_z = 0, worst_t = 0, worst_s = 0, worst_block = 0, diff[3], sign[3];
    int failed_blocks = 0;
    for (int c = 0; c < 3; c++) {
        region all = {0};
        for (int by = 0; by < h; by += BLOCK)
            for (int bx = 0; bx < w; bx += BLOCK) {
                region blk = {0};
                for (int y = by; y < by + BLOCK && y < h; y++)
                    for (int x = bx; x < bx + BLOCK && x < w; x++) {
                        double a = px(img, x, y, c), b = px(ref, x, y, c);
                        double sd = px(ref_sd, x, y, c);
                        double v = (double)px(var, x, y, c) + sd * sd;
                        double d = a - b;
                        /* NaN counts as an outlier (the renderer never writes one). */
                        outliers += !(fabs(d) <= PT_K_VALUE * sqrt(v) + 1e-3 * fabs(b) + 1e-5);
                        exact += a == b;
                        count++;
                        region_add(&blk, d, b, v);
                        region_add(&all, d, b, v);
                    }
                double t = region_t(&blk), sgn = region_s(&blk);
                worst_block = fmax(worst_block, fmax(t, sgn));
                if (!(t <= PT_K_BLOCK && sgn <= PT_K_BLOCK) && failed_blocks++ < 3)
                    printf("  block at (%d, %d) channel %d: sum d %.4g over sum |ref| %.4g, t %.2f, signs +%ld -%ld\n",
                           bx, by, c, blk.d, blk.ref, t, blk.pos, blk.neg);
            }
        diff[c] = all.ref > 0 ? 100 * all.d / all.ref : 0;
        sign[c] = 100.0 * (double)(all.pos - all.neg) / (double)all.n;
        double z = fabs(all.d) > PT_FLOOR * all.ref ? fabs(all.d) / sqrt(all.v) : 0;
        CHECK(z <= PT_K_IMAGE);
        CHECK(region_t(&all) <= PT_K_IMAGE);
        CHECK(region_s(&all) <= PT_K_IMAGE);
        worst_z = fmax(worst_z, z);
        worst_t = fmax(worst_t, region_t(&all));
        worst_s = fmax(worst_s, region_s(&all));
    }
    double outlier_fraction = (double)outliers / (double)count;
    printf("%-30s exact %5.1f%%  outliers %.3f%%  mean %+.2f%% %+.2f%% %+.2f%%  signs %+.1f%% %+.1f%% %+.1f%%  "
           "z %.2f  t %.2f  s %.2f  blocks %.2f\n",
           label, 100.0 * (double)exact / (double)count, 100 * outlier_fraction, diff[0], diff[1], diff[2], sign[0],
           sign[1], sign[2], worst_z, worst_t, worst_s, worst_block);
    CHECK(outlier_fraction <= PT_OUTLIER_FRACTION);
    CHECK(failed_blocks == 0);
}

static bool read_reference(nacre_context *ctx, const char *label, const char *path, const nacre_image *img,
                           nacre_image *out)
{
    if (nacre_image_read(ctx, path, out) != NACRE_OK) {
        printf("%s: no reference image (%s)\n", label, nacre_context_last_error(ctx));
        CHECK(!"reference image exists");
        return false;
    }
    if (out->width != img->width || out->height != img->height) {
        printf("%s: reference is %dx%d, render %dx%d\n", label, out->width, out->height, img->width, img->height);
        CHECK(!"reference image has the render's size");
        return false;
    }
    return true;
}

static bool write_reference(nacre_context *ctx, const nacre_image *img, const char *path, nacre_exr_pixel type)
{
    bool ok = nc_image_write_exr(ctx, img, path, type) == NACRE_OK;
    if (!ok)
        printf("%s: %s\n", path, nacre_context_last_error(ctx));
    CHECK(ok);
    printf("updated %s\n", path);
    return ok;
}

static void check_variant(nacre_context *ctx, nacre_scene *scene, const char *stem, nacre_render_settings rs,
                          const variant *v, bool translucent, bool layered)
{
    char label[512], golden[4096], golden_sd[4096];
    snprintf(label, sizeof(label), "%s%s", stem, v->suffix[0] ? v->suffix : ".phong");
    snprintf(golden, sizeof(golden), "%s/tests/golden/%s%s.exr", NACRE_SOURCE_DIR, stem, v->suffix);
    snprintf(golden_sd, sizeof(golden_sd), "%s/tests/golden/%s%s.sd.exr", NACRE_SOURCE_DIR, stem, v->suffix);
    if (g.methods && !method_listed(g.methods, v->method))
        return;
    if (v->method == NACRE_METHOD_DIFFUSION && !translucent) {
        printf("%-30s skipped: no translucent object (diffusion would equal phong)\n", label);
        g.skipped++;
        return;
    }
    /* At 11^3 a voxel of a layered material is the mean of 8 sub-samples, each in the layer its
     * depth falls in: one sub-sample on the other side of a layer bottom by a rounding (FMA or
     * not) moves a whole coarse cell's coefficients, and the portable build's images differ from
     * the x86-64-v3 ones by 1.4% (rmse/mean). Layered scenes are compared at 32^3 only. */
    if (v->method == NACRE_METHOD_DIFFUSION && layered && v->voxel_resolution < 32) {
        printf("%-30s skipped: layered material at %u^3 (build-sensitive; compared at 32^3)\n", label, v->voxel_resolution);
        g.skipped++;
        return;
    }
    if (!nacre_method_available(v->method)) {
        printf("%-30s skipped: this build has no %s method\n", label, nacre_method_name(v->method));
        g.skipped++;
        return;
    }
    rs.method = v->method;
    if (v->voxel_resolution)
        rs.diffusion.voxel_resolution = v->voxel_resolution;
    if (v->method == NACRE_METHOD_PATHTRACE) {
        rs.pathtrace.seed = g.seed;
        rs.pathtrace.spp = PT_SPP;
        rs.pathtrace.time_limit = 0;
#ifndef __AVX2__
        /* Scenes whose same-seed paths a build without FMA sends elsewhere one-sidedly (see the
         * top of the file) are compared at another seed, where the streams are independent and
         * the tests' assumptions hold. */
        if (!g.update && g.seed == PT_SEED && same_seed_diverges(stem)) {
            rs.pathtrace.seed = PT_SEED + 1;
            printf("%-30s (portable build: seed %u, see same_seed_diverges)\n", label, rs.pathtrace.seed);
        }
#endif
    }
    nacre_renderer *renderer = NULL;
    nacre_image img = {0}, var = {0}, ref = {0}, ref_sd = {0};
    CHECK(nacre_renderer_create(ctx, &renderer) == NACRE_OK);
    nacre_result res = nacre_renderer_render(renderer, scene, &rs, &img, NULL);
    if (res == NACRE_ERROR_UNSUPPORTED && v->method == NACRE_METHOD_DIFFUSION && layered) {
        printf("%-30s skipped: %s\n", label, nacre_context_last_error(ctx));
        g.skipped++;
        goto out;
    }
    if (res != NACRE_OK) {
        printf("%s: %s\n", label, nacre_context_last_error(ctx));
        CHECK(!"render succeeds");
        goto out;
    }
    if (v->method == NACRE_METHOD_PATHTRACE)
        CHECK(nacre_renderer_variance(renderer, &var) == NACRE_OK);
    if (g.update) {
        if (write_reference(ctx, &img, golden, v->exr))
            g.written++;
        if (var.pixels) {
            for (int y = 0; y < var.height; y++) /* stored as the standard deviation of the mean */
                for (int x = 0; x < 3 * var.width; x++) {
                    float *p = &var.pixels[(size_t)y * var.stride + (size_t)x];
                    *p = sqrtf(*p);
                }
            write_reference(ctx, &var, golden_sd, NACRE_EXR_HALF);
        }
        goto out;
    }
    if (!read_reference(ctx, label, golden, &img, &ref))
        goto out;
    g.compared++;
    g.per_method[v->method]++;
    if (v->method != NACRE_METHOD_PATHTRACE) {
        compare_raster(label, &img, &ref);
        goto out;
    }
    if (!read_reference(ctx, label, golden_sd, &img, &ref_sd))
        goto out;
    compare_pathtrace(label, &img, &var, &ref, &ref_sd);
out:
    nacre_image_free(ctx, &img);
    nacre_image_free(ctx, &var);
    nacre_image_free(ctx, &ref);
    nacre_image_free(ctx, &ref_sd);
    nacre_renderer_destroy(renderer);
}

static void check_scene(nacre_context *ctx, const char *name)
{
    char path[2048], stem[256];
    snprintf(path, sizeof(path), "%s/examples/%s", NACRE_SOURCE_DIR, name);
    snprintf(stem, sizeof(stem), "%.*s", (int)(strlen(name) - 5), name);
    nacre_scene *scene = NULL;
    nacre_scene_file_settings fs;
    if (nacre_scene_load_file(ctx, path, &scene, &fs) != NACRE_OK) {
        printf("%s: %s\n", name, nacre_context_last_error(ctx));
        CHECK(!"example scene loads");
        return;
    }
    nacre_render_settings rs = fs.render;
    rs.height = (int32_t)((WIDTH * (double)rs.height) / rs.width + 0.5);
    rs.width = WIDTH;
    if (rs.height < 1)
        rs.height = 1;
    rs.shadow.map_size = 1024;
    bool translucent = false, layered = false;
    for (uint32_t i = 0; i < scene->object_count; i++) {
        const nacre_material_desc *m = nc_scene_material(scene, scene->objects[i].desc.material);
        if (m && m->type == NACRE_MATERIAL_TRANSLUCENT) {
            translucent = true;
            layered = layered || m->layering.count > 0;
        }
    }
    bool ok = nacre_scene_commit(scene, fs.time) == NACRE_OK;
    if (!ok)
        printf("%s: %s\n", name, nacre_context_last_error(ctx));
    CHECK(ok);
    for (size_t i = 0; ok && i < sizeof(VARIANTS) / sizeof(VARIANTS[0]); i++)
        check_variant(ctx, scene, stem, rs, &VARIANTS[i], translucent, layered);
    nacre_scene_destroy(scene);
}

int main(void)
{
    const char *env = getenv("NACRE_UPDATE_GOLDEN");
    g.update = env && strcmp(env, "1") == 0;
    const char *seed = getenv("NACRE_GOLDEN_SEED");
    g.seed = seed ? (uint32_t)strtoul(seed, NULL, 10) : PT_SEED;
    CHECK(!(g.update && g.seed != PT_SEED)); /* references are made with PT_SEED */
    const char *only = getenv("NACRE_GOLDEN_ONLY");
    g.methods = getenv("NACRE_GOLDEN_METHODS");
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
        if (!only || strstr(names[i], only))
            check_scene(ctx, names[i]);
        free(names[i]);
    }
    if (g.update)
        printf("%d references written\n", g.written);
    else
        printf("compared %d references (phong %d, diffusion %d, pathtrace %d), %d skipped\n", g.compared,
               g.per_method[NACRE_METHOD_PHONG], g.per_method[NACRE_METHOD_DIFFUSION],
               g.per_method[NACRE_METHOD_PATHTRACE], g.skipped);
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
