/*
 * test_accuracy.c: the diffusion method against the path tracer on issue 28's two scenes
 * (examples/accuracy_sphere.json, examples/accuracy_checker.json), at the default 32^3 and a
 * coarse image and sample count: the rows of docs/accuracy.md's table (made at full size by
 * scripts/accuracy_table.sh) with bounds that the method failed before its fixes of the light's
 * entry, the exitance lookup, the pattern sampling and the boundary cells' depth:
 *   sphere:  mean ratio per channel in [0.95, 1.06] (issue 28's 5%, with the path tracer's noise;
 *            1.165, 1.138, 1.106 before the light's entry and the lookup, 1.084, 1.068, 1.048
 *            before the boundary cells' depth, 1.041, 1.039, 1.034 now), darkest quarter at most
 *            1.25 (issue 28's target; was 1.44, 1.35, 1.24, then 1.269, 1.189, 1.091, now 1.212,
 *            1.156, 1.080);
 *   checker: mean ratio in [0.95, 1.08], the G - B checker signal correlated with the truth's at
 *            0.3 or more (0.12 when voxels sampled the pattern at the nearest surface point),
 *            darkest quarter at most 1.45, and its contrast over the whole object (check_contrast)
 *            and per visible face, with the faces' means (check_faces, issue 28's targets).
 * Both at the default settings: single scattering per pixel is then off on the homogeneous sphere
 * and on for the patterned checker (check_auto).
 * The measures are nacre_image_compare's lit-pixel ones. The path tracer's noise at this sample
 * count moves the ratios by well under 1%.
 */
#include "core/math.h"
#include "test_util.h"

#include <nacre/nacre.h>

#include <string.h>

#define SIZE 48
#define SPP 48

static bool render_sized(nacre_context *ctx, const char *name, nacre_method method, nacre_single_scattering single,
                         uint32_t seed, int size, uint32_t spp, nacre_image *out)
{
    char path[2048];
    snprintf(path, sizeof(path), "%s/examples/%s", NACRE_SOURCE_DIR, name);
    nacre_scene *scene = NULL;
    nacre_scene_file_settings fs;
    if (nacre_scene_load_file(ctx, path, &scene, &fs) != NACRE_OK) {
        printf("%s: %s\n", name, nacre_context_last_error(ctx));
        return false;
    }
    nacre_render_settings rs = fs.render;
    rs.method = method;
    rs.width = rs.height = size;
    rs.diffusion.voxel_resolution = 32;
    rs.pathtrace.spp = spp;
    rs.pathtrace.seed = seed;
    rs.diffusion.single_scattering = single;
    bool ok = nacre_scene_commit(scene, fs.time) == NACRE_OK && nacre_render(scene, &rs, out, NULL) == NACRE_OK;
    if (!ok)
        printf("%s: %s\n", name, nacre_context_last_error(ctx));
    nacre_scene_destroy(scene);
    return ok;
}

static bool render_with(nacre_context *ctx, const char *name, nacre_method method, nacre_single_scattering single,
                        uint32_t seed, nacre_image *out)
{
    return render_sized(ctx, name, method, single, seed, SIZE, SPP, out);
}

static bool render(nacre_context *ctx, const char *name, nacre_method method, nacre_image *out)
{
    return render_with(ctx, name, method, NACRE_SINGLE_SCATTERING_AUTO, 11, out);
}

/* The G - B signal of a 2x2 block at (x, y) (the reference's per-pixel noise would otherwise
 * dominate the checker at this sample count); false if a pixel of the block is not lit in ref. */
static bool block_signal(const nacre_image *img, const nacre_image *ref, int x, int y, double *out)
{
    double g = 0.0;
    for (int k = 0; k < 4; k++) {
        const float *p = img->pixels + (size_t)(y + (k >> 1)) * img->stride + 3 * (size_t)(x + (k & 1));
        const float *r = ref->pixels + (size_t)(y + (k >> 1)) * ref->stride + 3 * (size_t)(x + (k & 1));
        if (!(r[0] + r[1] + r[2] > 0.0f))
            return false;
        g += p[1] - p[2];
    }
    *out = g;
    return true;
}

/* Covariance over the blocks lit in ref of the G - B signals of a and b. */
static double signal_cov(const nacre_image *a, const nacre_image *b, const nacre_image *ref)
{
    double sa = 0, sb = 0, sab = 0;
    int n = 0;
    for (int y = 0; y + 1 < ref->height; y += 2)
        for (int x = 0; x + 1 < ref->width; x += 2) {
            double ga, gb;
            if (!block_signal(a, ref, x, y, &ga) || !block_signal(b, ref, x, y, &gb))
                continue;
            sa += ga;
            sb += gb;
            sab += ga * gb;
            n++;
        }
    return n > 1 ? sab / n - (sa / n) * (sb / n) : 0.0;
}

/* Correlation over the reference's lit pixels of the G - B signal of two images, on 2x2 blocks
 * (the reference's per-pixel noise would otherwise dominate the checker at this sample count). */
static double checker_correlation(const nacre_image *a, const nacre_image *b)
{
    double sa = 0, sb = 0, saa = 0, sbb = 0, sab = 0;
    int n = 0;
    for (int y = 0; y + 1 < b->height; y += 2)
        for (int x = 0; x + 1 < b->width; x += 2) {
            double ga = 0, gb = 0;
            bool lit = true;
            for (int k = 0; k < 4; k++) {
                const float *pa = a->pixels + (size_t)(y + (k >> 1)) * a->stride + 3 * (size_t)(x + (k & 1));
                const float *pb = b->pixels + (size_t)(y + (k >> 1)) * b->stride + 3 * (size_t)(x + (k & 1));
                lit = lit && pb[0] + pb[1] + pb[2] > 0.0f;
                ga += pa[1] - pa[2];
                gb += pb[1] - pb[2];
            }
            if (!lit)
                continue;
            sa += ga;
            sb += gb;
            saa += ga * ga;
            sbb += gb * gb;
            sab += ga * gb;
            n++;
        }
    if (n < 2)
        return 0.0;
    double cov = sab / n - (sa / n) * (sb / n), va = saa / n - (sa / n) * (sa / n), vb = sbb / n - (sb / n) * (sb / n);
    return va > 0 && vb > 0 ? cov / sqrt(va * vb) : 0.0;
}

static void check_scene(nacre_context *ctx, const char *name, double lo, double hi, double dark_max,
                        double corr_min)
{
    nacre_image d = {0}, p = {0};
    bool ok = render(ctx, name, NACRE_METHOD_DIFFUSION, &d) && render(ctx, name, NACRE_METHOD_PATHTRACE, &p);
    CHECK(ok);
    if (ok) {
        nacre_image_metrics m;
        CHECK(nacre_image_compare(ctx, &d, &p, &m) == NACRE_OK);
        printf("%s at 32^3, %dx%d, %d spp: mean ratio %.3f %.3f %.3f, darkest quarter %.3f %.3f %.3f, "
               "rel. error median %.3f p90 %.3f (%llu lit pixels)\n",
               name, SIZE, SIZE, SPP, m.lit_ratio[0], m.lit_ratio[1], m.lit_ratio[2], m.dark_ratio[0], m.dark_ratio[1],
               m.dark_ratio[2], m.lit_rel_err_median, m.lit_rel_err_p90, (unsigned long long)m.lit_pixels);
        CHECK(m.lit_pixels > SIZE * SIZE / 8);
        for (int c = 0; c < 3; c++) {
            CHECK(m.lit_ratio[c] >= lo && m.lit_ratio[c] <= hi);
            CHECK(m.dark_ratio[c] <= dark_max);
        }
        if (corr_min > -1.0) {
            double r = checker_correlation(&d, &p);
            printf("%s: G - B correlation with the path tracer %.3f\n", name, r);
            CHECK(r >= corr_min);
        }
    }
    nacre_image_free(ctx, &d);
    nacre_image_free(ctx, &p);
}

/* The lit-pixel measures on images whose answers are known: a test image 1.1x the reference
 * on a lit disc (on black), and 1.5x on the disc's darker half. */
static void check_metrics(nacre_context *ctx)
{
    nacre_image t = {0}, r = {0};
    CHECK(nacre_image_alloc(ctx, 40, 40, 3, &t) == NACRE_OK && nacre_image_alloc(ctx, 40, 40, 3, &r) == NACRE_OK);
    int lit = 0;
    for (int y = 0; y < 40; y++)
        for (int x = 0; x < 40; x++) {
            if ((x - 20) * (x - 20) + (y - 20) * (y - 20) > 15 * 15)
                continue;
            float v = x < 20 ? 0.1f : 1.0f, k = 1.1f;
            for (int c = 0; c < 3; c++) {
                r.pixels[(size_t)y * r.stride + 3 * (size_t)x + (size_t)c] = v * (float)(c + 1);
                t.pixels[(size_t)y * t.stride + 3 * (size_t)x + (size_t)c] = k * v * (float)(c + 1);
            }
            lit++;
        }
    nacre_image_metrics m;
    CHECK(nacre_image_compare(ctx, &t, &r, &m) == NACRE_OK);
    CHECK(m.lit_pixels == (uint64_t)lit);
    for (int c = 0; c < 3; c++) {
        CHECK_NEAR(m.lit_ratio[c], 1.1, 1e-6);
        CHECK_NEAR(m.dark_ratio[c], 1.1, 1e-6);
    }
    CHECK_NEAR(m.lit_rel_err_median, 0.1, 1e-6);
    CHECK_NEAR(m.lit_rel_err_p90, 0.1, 1e-6);
    /* Only the dark half (x < 20, a quarter and more of the disc) off: the darkest quarter sees it. */
    for (int y = 0; y < 40; y++)
        for (int x = 0; x < 20; x++)
            for (int c = 0; c < 3; c++)
                t.pixels[(size_t)y * t.stride + 3 * (size_t)x + (size_t)c] *= 1.5f / 1.1f;
    CHECK(nacre_image_compare(ctx, &t, &r, &m) == NACRE_OK);
    printf("metrics: lit ratio %.4f, darkest quarter %.4f\n", m.lit_ratio[0], m.dark_ratio[0]);
    CHECK_NEAR(m.dark_ratio[0], 1.5, 1e-6);
    CHECK(m.lit_ratio[0] > 1.1 && m.lit_ratio[0] < 1.5);
    nacre_image_free(ctx, &t);
    nacre_image_free(ctx, &r);
}

/* Whether two renders are the same to the bit. */
static bool same_pixels(const nacre_image *a, const nacre_image *b)
{
    if (a->width != b->width || a->height != b->height)
        return false;
    for (int y = 0; y < a->height; y++)
        if (memcmp(a->pixels + (size_t)y * a->stride, b->pixels + (size_t)y * b->stride,
                   3 * sizeof(float) * (size_t)a->width) != 0)
            return false;
    return true;
}

/* The default (single_scattering AUTO) is OFF on the homogeneous sphere and ON on the patterned
 * checker, to the bit. */
static void check_auto(nacre_context *ctx)
{
    nacre_image a = {0}, b = {0};
    CHECK(render_with(ctx, "accuracy_sphere.json", NACRE_METHOD_DIFFUSION, NACRE_SINGLE_SCATTERING_AUTO, 11, &a) &&
          render_with(ctx, "accuracy_sphere.json", NACRE_METHOD_DIFFUSION, NACRE_SINGLE_SCATTERING_OFF, 11, &b));
    CHECK(same_pixels(&a, &b));
    nacre_image_free(ctx, &a);
    nacre_image_free(ctx, &b);
    CHECK(render_with(ctx, "accuracy_checker.json", NACRE_METHOD_DIFFUSION, NACRE_SINGLE_SCATTERING_AUTO, 11, &a) &&
          render_with(ctx, "accuracy_checker.json", NACRE_METHOD_DIFFUSION, NACRE_SINGLE_SCATTERING_ON, 11, &b));
    CHECK(same_pixels(&a, &b));
    nacre_image_free(ctx, &a);
    nacre_image_free(ctx, &b);
}

/* The visible face of the checker cube ([-0.5, 0.5]^3) under pixel (x, y) of a w x h image from
 * examples/accuracy_checker.json's camera (position (2.4, -3.2, 2), target the origin, z up, 30
 * degrees): 0 +X, 1 -Y, 2 +Z, -1 for a miss or a point within 0.03 of an edge (as
 * scripts/face_stats.c). */
static int checker_face(int x, int y, int w, int h)
{
    const double pos[3] = {2.4, -3.2, 2.0}, dist = sqrt(2.4 * 2.4 + 3.2 * 3.2 + 2.0 * 2.0);
    const double f[3] = {-pos[0] / dist, -pos[1] / dist, -pos[2] / dist};
    double r[3] = {f[1], -f[0], 0.0}; /* f x up, up = z */
    const double rl = sqrt(r[0] * r[0] + r[1] * r[1]);
    r[0] /= rl, r[1] /= rl;
    const double u[3] = {r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0]};
    const double tf = tan(15.0 * 3.14159265358979323846 / 180.0);
    const double sx = (2.0 * (x + 0.5) / w - 1.0) * tf * w / h, sy = (1.0 - 2.0 * (y + 0.5) / h) * tf;
    float o[3], d[3];
    for (int k = 0; k < 3; k++) {
        o[k] = (float)pos[k];
        d[k] = (float)(f[k] + sx * r[k] + sy * u[k]);
    }
    const float lo[3] = {-0.5f, -0.5f, -0.5f}, hi[3] = {0.5f, 0.5f, 0.5f};
    float t0 = -INFINITY, t1 = INFINITY;
    int axis = -1;
    if (!nc_ray_box(o, d, lo, hi, &t0, &t1, &axis) || !(t0 < t1) || axis < 0)
        return -1;
    for (int k = 0; k < 3; k++)
        if (k != axis && fabsf(o[k] + t0 * d[k]) > 0.47f)
            return -1;
    return axis; /* +X, -Y, +Z are the faces this camera sees: axis 0, 1, 2 */
}

/* Per visible face of the checker: the noise-free G - B contrast sqrt(var(d) / cov(p1, p2)) and
 * correlation cov(d, p1) / sqrt(var(d) cov(p1, p2)) over the face's pixels. */
static void face_contrast(const nacre_image *d, const nacre_image *p1, const nacre_image *p2, double contrast[3],
                          double corr[3], double ratio[3][3])
{
    double s[3][3] = {{0}}, sdd[3] = {0}, sd1[3] = {0}, s12[3] = {0}, md[3][3] = {{0}}, mp[3][3] = {{0}};
    long n[3] = {0};
    for (int y = 0; y < d->height; y++)
        for (int x = 0; x < d->width; x++) {
            const int k = checker_face(x, y, d->width, d->height);
            if (k < 0)
                continue;
            const float *a = d->pixels + (size_t)y * d->stride + 3 * (size_t)x;
            const float *b = p1->pixels + (size_t)y * p1->stride + 3 * (size_t)x;
            const float *c = p2->pixels + (size_t)y * p2->stride + 3 * (size_t)x;
            const double ga = a[1] - a[2], gb = b[1] - b[2], gc = c[1] - c[2];
            s[k][0] += ga, s[k][1] += gb, s[k][2] += gc;
            sdd[k] += ga * ga, sd1[k] += ga * gb, s12[k] += gb * gc;
            for (int c2 = 0; c2 < 3; c2++)
                md[k][c2] += a[c2], mp[k][c2] += 0.5 * ((double)b[c2] + c[c2]);
            n[k]++;
        }
    for (int k = 0; k < 3; k++) {
        const double N = n[k] > 1 ? (double)n[k] : 1.0, ma = s[k][0] / N, mb = s[k][1] / N, mc = s[k][2] / N;
        const double vd = sdd[k] / N - ma * ma, c1 = sd1[k] / N - ma * mb, truth = s12[k] / N - mb * mc;
        contrast[k] = truth > 0.0 && vd >= 0.0 ? sqrt(vd / truth) : 0.0;
        corr[k] = truth > 0.0 && vd > 0.0 ? c1 / sqrt(vd * truth) : 0.0;
        for (int c2 = 0; c2 < 3; c2++)
            ratio[k][c2] = mp[k][c2] > 0.0 ? md[k][c2] / mp[k][c2] : 0.0;
    }
}

/* The checker's contrast by default (single scattering per pixel, AUTO on a patterned medium):
 * the noise-free forms of scripts/face_stats.c over the whole object, the truth's signal variance
 * being the covariance of two path-traced references of independent seeds (their noise is
 * independent): contrast sqrt(var(d) / cov(p1, p2)), correlation cov(d, p1) / sqrt(var(d)
 * cov(p1, p2)). Over the whole object at this size (edges included, 2x2 blocks) the measure reads
 * higher than docs/accuracy.md's per-face one (0.92-1.03 with the first order, 0.52-0.57 without,
 * at 128^2): 1.16 with it and 0.60 without here (the estimate of cov(p1, p2) at 48 spp is noisy,
 * and scales both alike). CONTRAST_MIN lies between: the check fails with single scattering off. */
#define CONTRAST_MIN 0.85
static void check_contrast(nacre_context *ctx)
{
    nacre_image d = {0}, off = {0}, p1 = {0}, p2 = {0};
    const char *name = "accuracy_checker.json";
    bool ok = render_with(ctx, name, NACRE_METHOD_DIFFUSION, NACRE_SINGLE_SCATTERING_AUTO, 11, &d) &&
              render_with(ctx, name, NACRE_METHOD_DIFFUSION, NACRE_SINGLE_SCATTERING_OFF, 11, &off) &&
              render_with(ctx, name, NACRE_METHOD_PATHTRACE, NACRE_SINGLE_SCATTERING_AUTO, 11, &p1) &&
              render_with(ctx, name, NACRE_METHOD_PATHTRACE, NACRE_SINGLE_SCATTERING_AUTO, 12, &p2);
    CHECK(ok);
    if (ok) {
        const double truth = signal_cov(&p1, &p2, &p1);
        CHECK(truth > 0.0);
        const double c_on = sqrt(signal_cov(&d, &d, &p1) / truth), c_off = sqrt(signal_cov(&off, &off, &p1) / truth);
        const double r_on = signal_cov(&d, &p1, &p1) / sqrt(signal_cov(&d, &d, &p1) * truth);
        const double r_off = signal_cov(&off, &p1, &p1) / sqrt(signal_cov(&off, &off, &p1) * truth);
        printf("checker by default: G - B contrast %.3f (single scattering off: %.3f), correlation %.3f (off: "
               "%.3f), noise-free\n",
               c_on, c_off, r_on, r_off);
        CHECK(c_on >= CONTRAST_MIN && c_on <= 1.6);
        CHECK(r_on >= 0.6);
    }
    nacre_image_free(ctx, &d);
    nacre_image_free(ctx, &off);
    nacre_image_free(ctx, &p1);
    nacre_image_free(ctx, &p2);
}

/* Issue 28's checker targets per visible face, by default: the noise-free contrast at least
 * FACE_CONTRAST_MIN (it measures 0.96-1.03; 0.55-0.58 with single scattering off, so the check
 * fails without it; the issue asks 0.5), the right way round (correlation at least 0.6: 0.82-0.87)
 * and the face's mean within 10% of the truth's (the mean of the two references) per channel. At
 * 96^2 and 192 spp the per-face estimates agree with docs/accuracy.md's at 128^2 and 600 spp
 * within 0.07; at 48 spp they scattered by 0.5. */
#define FACE_SIZE 96
#define FACE_SPP 192
#define FACE_CONTRAST_MIN 0.75
static void check_faces(nacre_context *ctx)
{
    nacre_image d = {0}, off = {0}, p1 = {0}, p2 = {0};
    const char *name = "accuracy_checker.json";
    bool ok = render_sized(ctx, name, NACRE_METHOD_DIFFUSION, NACRE_SINGLE_SCATTERING_AUTO, 11, FACE_SIZE, FACE_SPP, &d) &&
              render_sized(ctx, name, NACRE_METHOD_DIFFUSION, NACRE_SINGLE_SCATTERING_OFF, 11, FACE_SIZE, FACE_SPP, &off) &&
              render_sized(ctx, name, NACRE_METHOD_PATHTRACE, NACRE_SINGLE_SCATTERING_AUTO, 11, FACE_SIZE, FACE_SPP, &p1) &&
              render_sized(ctx, name, NACRE_METHOD_PATHTRACE, NACRE_SINGLE_SCATTERING_AUTO, 12, FACE_SIZE, FACE_SPP, &p2);
    CHECK(ok);
    if (ok) {
        double fc[3], fr[3], oc[3], orr[3], m[3][3], mo[3][3];
        face_contrast(&d, &p1, &p2, fc, fr, m);
        face_contrast(&off, &p1, &p2, oc, orr, mo);
        for (int k = 0; k < 3; k++) {
            printf("checker face %s at %d^2, %d spp: G - B contrast %.3f (off %.3f), correlation %.3f (off %.3f), "
                   "noise-free; mean ratio %.3f %.3f %.3f\n",
                   k == 0 ? "+X" : k == 1 ? "-Y" : "+Z", FACE_SIZE, FACE_SPP, fc[k], oc[k], fr[k], orr[k], m[k][0],
                   m[k][1], m[k][2]);
            CHECK(fc[k] >= FACE_CONTRAST_MIN && fc[k] <= 1.5);
            CHECK(fr[k] >= 0.6);
            for (int c = 0; c < 3; c++)
                CHECK(m[k][c] >= 0.9 && m[k][c] <= 1.1);
        }
    }
    nacre_image_free(ctx, &d);
    nacre_image_free(ctx, &off);
    nacre_image_free(ctx, &p1);
    nacre_image_free(ctx, &p2);
}

int main(void)
{
    nacre_context *ctx = NULL;
    nacre_context_desc cd = {0};
    CHECK(nacre_context_create(&cd, &ctx) == NACRE_OK);
    check_metrics(ctx);
    if (!nacre_method_available(NACRE_METHOD_PATHTRACE)) {
        printf("path tracer not built: skipped\n");
        nacre_context_destroy(ctx);
        return TEST_MAIN_END();
    }
    check_scene(ctx, "accuracy_sphere.json", 0.95, 1.06, 1.25, -2.0);
    check_scene(ctx, "accuracy_checker.json", 0.95, 1.08, 1.45, 0.3);
    check_auto(ctx);
    check_contrast(ctx);
    check_faces(ctx);
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
