/*
 * test_fog_emission.c: fog emission ("emission" of a fog: radiance per unit length, seed 003
 * §1.2.11) in every technique that renders fog, against closed forms and the path tracer:
 *   - an emitting, absorbing, non-scattering fog box (edge 2) seen head-on through an
 *     orthographic camera in front of an environment of 0.5: per pixel inside the box,
 *     L = eps / sigma_t (1 - e^(-2 sigma_t)) + 0.5 e^(-2 sigma_t), one channel with sigma_t = 0
 *     (the limit eps d); the analytic fog pass to 1e-5 (every pixel, the box edges included),
 *     froxels and the ray march to 2%, and the same with 8 slices or steps as with 64 (the
 *     box faces on slice boundaries: the segment integral is exact for homogeneous media), and
 *     the path tracer per band of rows within 4 standard errors of its mean (from its variance
 *     image);
 *   - a global emitting fog in the analytic pass to 1e-5: over the background (infinite depth)
 *     eps / sigma_t, on a black cube's flat face eps / sigma_t (1 - e^(-sigma_t d));
 *   - a heterogeneous (noise) emitting, absorbing fog: the ray march (512 steps) and the path
 *     tracer agree per band of rows within 4 standard errors plus 1%;
 *   - "emission_pattern", emission from a grid of its own: the box above with constant volumes
 *     as density and emission grids against the same closed forms (fog pass 1e-5, froxels and
 *     march 2%, path tracer 4 standard errors); saved and reloaded; a .vdb grid renders as the
 *     same samples from NRRD; bad patterns name the field;
 *   - the black body (nacre_blackbody_rgb) against published numbers: 6.0e5 cd/m^2 at 2042 K (the
 *     1948 candela) within 2%, illuminant A's chromaticity at 2856 K within 0.003; a box whose
 *     emission grid holds temperatures ("blackbody") against the closed form as above;
 *   - scene files: "emission" loads, saves and reloads to the same bits; negative, wrong-sized
 *     and non-numeric values, and a global fog that emits without extinction, give one-line
 *     errors naming the field; the API rejects NaN.
 */
#include "io/vdb.h"
#include "media_util.h"

#include <nacre/nacre.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static nacre_context *ctx;

/* ---- an emitting box seen head-on ------------------------------------------------------------ */

/* Orthographic camera at z = 5 looking down -z over [-2, 2]^2, near 1 and far 9: rays start at
 * z = 4 and cross the box (|z| <= 1) over d = 2; 8, 16 or 64 equal slices put boundaries on its
 * faces. A black sphere behind the camera is the object the raster methods need. */
#define BOX_SCENE(FOG)                                                                              \
    "{\"camera\": {\"type\": \"orthographic\", \"position\": [0, 0, 5], \"target\": [0, 0, 0], "    \
    "\"height\": 4, \"near\": 1, \"far\": 9}, \"environment\": 0.5,"                                \
    "\"materials\": {\"black\": {\"type\": \"opaque\", \"diffuse\": 0, \"specular\": 0}},"          \
    "\"objects\": [{\"shape\": {\"type\": \"sphere\", \"radius\": 0.1}, \"material\": \"black\","   \
    "\"transform\": {\"translate\": [0, 0, 20]}, \"shadows\": false}],"                             \
    "\"fog\": [" FOG "]}"

#define EMIT_BOX BOX_SCENE("{\"shape\": \"box\", \"size\": 2, \"sigma_a\": [0.5, 1.5, 0], \"sigma_s\": 0, " \
                           "\"emission\": [0.3, 0.6, 0.9]}")

static const double BOX_SA[3] = {0.5, 1.5, 0.0}, BOX_EM[3] = {0.3, 0.6, 0.9};

/* The closed form at pixel (x, y) of a 32 x 32 image (8 pixels per unit). */
static double box_exact_of(int x, int y, int c, const double *sa, const double *em)
{
    double xx = (x + 0.5) / 8 - 2, yy = 2 - (y + 0.5) / 8;
    if (fabs(xx) > 1 || fabs(yy) > 1)
        return 0.5;
    const double d = 2.0, st = sa[c];
    double T = exp(-st * d), w = st > 0 ? (1 - T) / st : d;
    return em[c] * w + 0.5 * T;
}

static double box_exact(int x, int y, int c) { return box_exact_of(x, y, c, BOX_SA, BOX_EM); }

static double worst_box_error_of(const nacre_image *img, bool inner, const double *sa, const double *em)
{
    double worst = 0;
    for (int y = 0; y < 32; y++)
        for (int x = 0; x < 32; x++) {
            double xx = (x + 0.5) / 8 - 2, yy = 2 - (y + 0.5) / 8;
            if (inner && (fabs(xx) > 0.9 || fabs(yy) > 0.9))
                continue;
            for (int c = 0; c < 3; c++) {
                double e = box_exact_of(x, y, c, sa, em), err = fabs(media_px(img, x, y, c) - e) / e;
                worst = err > worst ? err : worst;
            }
        }
    return worst;
}

static double worst_box_error(const nacre_image *img, bool inner) { return worst_box_error_of(img, inner, BOX_SA, BOX_EM); }

static double max_rel_diff(const nacre_image *a, const nacre_image *b)
{
    double worst = 0;
    for (int y = 0; y < a->height; y++)
        for (int x = 0; x < a->width; x++)
            for (int c = 0; c < 3; c++) {
                double u = media_px(a, x, y, c), v = media_px(b, x, y, c), d = fabs(u - v) / fmax(fabs(v), 1e-6);
                worst = d > worst ? d : worst;
            }
    return worst;
}

static void emitting_box(void)
{
    const int W = 32, H = 32;
    nacre_image fog = {0}, fx = {0}, fx8 = {0}, rm = {0}, rm8 = {0};
    nacre_render_settings rs = media_settings(NACRE_METHOD_PHONG, NACRE_VOLUMETRICS_OFF, W, H);
    bool ok = media_render(ctx, EMIT_BOX, &rs, &fog, NULL);
    rs.volumetrics.mode = NACRE_VOLUMETRICS_FROXEL;
    rs.volumetrics.froxel_width = W;
    rs.volumetrics.froxel_height = H;
    rs.volumetrics.froxel_slices = 64;
    ok = ok && media_render(ctx, EMIT_BOX, &rs, &fx, NULL);
    rs.volumetrics.froxel_slices = 8;
    ok = ok && media_render(ctx, EMIT_BOX, &rs, &fx8, NULL);
    rs.volumetrics.mode = NACRE_VOLUMETRICS_RAYMARCH;
    rs.volumetrics.raymarch_steps = 64;
    ok = ok && media_render(ctx, EMIT_BOX, &rs, &rm, NULL);
    rs.volumetrics.raymarch_steps = 8;
    ok = ok && media_render(ctx, EMIT_BOX, &rs, &rm8, NULL);
    if (ok) {
        double e_fog = worst_box_error(&fog, false), e_fx = worst_box_error(&fx, true),
               e_rm = worst_box_error(&rm, true);
        double s_fx = max_rel_diff(&fx8, &fx), s_rm = max_rel_diff(&rm8, &rm);
        printf("  emitting box: largest relative error fog pass %.2e (all pixels), froxel %.2e, raymarch %.2e;\n"
               "  8 vs 64 slices %.2e, 8 vs 64 steps %.2e\n",
               e_fog, e_fx, e_rm, s_fx, s_rm);
        CHECK(e_fog < 1e-5);
        CHECK(e_fx < 0.02);
        CHECK(e_rm < 0.02);
        CHECK(s_fx < 1e-4);
        CHECK(s_rm < 1e-4);
        /* The sigma_t = 0 channel is eps d + background, exactly. */
        CHECK_NEAR(media_px(&fog, 16, 16, 2), BOX_EM[2] * 2 + 0.5, 1e-5);
        CHECK_NEAR(media_px(&rm, 16, 16, 2), BOX_EM[2] * 2 + 0.5, 1e-4);
        CHECK_NEAR(media_px(&fx, 16, 16, 2), BOX_EM[2] * 2 + 0.5, 2e-3);
    }
    nacre_image_free(ctx, &fog);
    nacre_image_free(ctx, &fx);
    nacre_image_free(ctx, &fx8);
    nacre_image_free(ctx, &rm);
    nacre_image_free(ctx, &rm8);

    /* The path tracer, per band of 4 rows over the inner 14 columns. */
    nacre_render_settings pr = media_settings(NACRE_METHOD_PATHTRACE, NACRE_VOLUMETRICS_OFF, W, H);
    pr.pathtrace.spp = 128;
    pr.pathtrace.seed = 5;
    nacre_image ref = {0}, var = {0};
    if (media_render(ctx, EMIT_BOX, &pr, &ref, &var)) {
        double worst_sigma = 0;
        for (int y0 = 9; y0 + 4 <= 23; y0 += 4) {
            double m[3], se[3], e[3];
            media_region(&ref, &var, 9, 23, y0, y0 + 4, m, se);
            for (int c = 0; c < 3; c++) {
                e[c] = box_exact(16, y0, c);
                CHECK_NEAR(m[c], e[c], 4 * se[c]);
                double z = fabs(m[c] - e[c]) / se[c];
                worst_sigma = z > worst_sigma ? z : worst_sigma;
            }
            printf("  rows %2d-%2d: path tracer %.5f %.5f %.5f (se %.5f %.5f %.5f), exact %.5f %.5f %.5f\n", y0,
                   y0 + 3, m[0], m[1], m[2], se[0], se[1], se[2], e[0], e[1], e[2]);
        }
        printf("  path tracer: largest deviation %.2f standard errors (tolerance 4)\n", worst_sigma);
        /* Outside the box only the environment. */
        CHECK_NEAR(media_px(&ref, 2, 2, 0), 0.5, 1e-6);
    }
    nacre_image_free(ctx, &ref);
    nacre_image_free(ctx, &var);
}

/* ---- a global emitting fog in the analytic pass ------------------------------------------------ */

static void global_fog_pass(void)
{
    /* A black cube of edge 2 at the origin: its front face at z = 1, d = 4 - 1 = 3 from the rays'
     * start on the near plane. */
    const char *json =
        "{\"camera\": {\"type\": \"orthographic\", \"position\": [0, 0, 5], \"target\": [0, 0, 0], "
        "\"height\": 4, \"near\": 1, \"far\": 9}, \"environment\": 0.5,"
        "\"materials\": {\"black\": {\"type\": \"opaque\", \"diffuse\": 0, \"specular\": 0}},"
        "\"objects\": [{\"shape\": {\"type\": \"box\", \"size\": [2, 2, 2]}, \"material\": \"black\"}],"
        "\"fog\": [{\"shape\": \"global\", \"sigma_a\": [0.2, 0.1, 0.05], \"sigma_s\": 0,"
        "\"emission\": [0.1, 0.2, 0.3]}]}";
    const double sa[3] = {0.2, 0.1, 0.05}, em[3] = {0.1, 0.2, 0.3};
    nacre_render_settings rs = media_settings(NACRE_METHOD_PHONG, NACRE_VOLUMETRICS_OFF, 32, 32);
    nacre_image img = {0};
    if (media_render(ctx, json, &rs, &img, NULL)) {
        double worst_bg = 0, worst_face = 0;
        for (int c = 0; c < 3; c++) {
            double bg = em[c] / sa[c], face = em[c] / sa[c] * (1 - exp(-3 * sa[c]));
            worst_bg = fmax(worst_bg, fabs(media_px(&img, 1, 1, c) - bg) / bg);
            worst_face = fmax(worst_face, fabs(media_px(&img, 16, 16, c) - face) / face);
        }
        printf("  global emitting fog, fog pass: relative error background %.2e, cube face %.2e\n", worst_bg,
               worst_face);
        CHECK(worst_bg < 1e-5);
        CHECK(worst_face < 1e-5);
    }
    nacre_image_free(ctx, &img);
}

/* ---- heterogeneous emission: the march against the path tracer -------------------------------- */

#define NOISE_BOX BOX_SCENE("{\"shape\": \"box\", \"size\": 2, \"sigma_a\": [0.6, 0.3, 0.1], \"sigma_s\": 0, " \
                            "\"emission\": [1, 0.8, 0.5], \"pattern\": {\"type\": \"noise\", \"cell_size\": 1, " \
                            "\"octaves\": 2, \"sigma_a2\": 0, \"sigma_s2\": 0}}")

/* json by the techniques that take part (a NULL image skips one) on a 32 x 32 image: the fog
 * pass, froxels of `slices` slices, the march of `steps` steps, the path tracer at `spp` with
 * its variance. */
static bool render_techniques(const char *json, int slices, int steps, int spp, uint32_t seed, nacre_image *fp,
                              nacre_image *fx, nacre_image *rm, nacre_image *pt, nacre_image *var)
{
    const int W = 32, H = 32;
    nacre_render_settings rs = media_settings(NACRE_METHOD_PHONG, NACRE_VOLUMETRICS_OFF, W, H);
    bool ok = !fp || media_render(ctx, json, &rs, fp, NULL);
    rs.volumetrics.mode = NACRE_VOLUMETRICS_FROXEL;
    rs.volumetrics.froxel_width = W;
    rs.volumetrics.froxel_height = H;
    rs.volumetrics.froxel_slices = slices;
    ok = ok && (!fx || media_render(ctx, json, &rs, fx, NULL));
    rs.volumetrics.mode = NACRE_VOLUMETRICS_RAYMARCH;
    rs.volumetrics.raymarch_steps = steps;
    ok = ok && (!rm || media_render(ctx, json, &rs, rm, NULL));
    nacre_render_settings pr = media_settings(NACRE_METHOD_PATHTRACE, NACRE_VOLUMETRICS_OFF, W, H);
    pr.pathtrace.spp = spp;
    pr.pathtrace.seed = seed;
    return ok && (!pt || media_render(ctx, json, &pr, pt, var));
}

static void noise_box(void)
{
    nacre_image rm = {0}, pt = {0}, var = {0}, fx = {0};
    bool ok = render_techniques(NOISE_BOX, 128, 512, 512, 9, NULL, &fx, &rm, &pt, &var);
    if (ok) {
        double worst = 0, worst_fx = 0, lo = INFINITY, hi = 0, se_max = 0;
        for (int y0 = 9; y0 + 2 <= 23; y0 += 2)
            for (int x0 = 9; x0 + 7 <= 23; x0 += 7) {
                double m[3], se[3], r[3], f[3], dummy[3];
                media_region(&pt, &var, x0, x0 + 7, y0, y0 + 2, m, se);
                media_region(&rm, NULL, x0, x0 + 7, y0, y0 + 2, r, dummy);
                media_region(&fx, NULL, x0, x0 + 7, y0, y0 + 2, f, dummy);
                lo = fmin(lo, r[0]);
                hi = fmax(hi, r[0]);
                se_max = fmax(se_max, se[0]);
                for (int c = 0; c < 3; c++) {
                    CHECK_NEAR(r[c], m[c], 4 * se[c] + 0.01 * m[c]);
                    CHECK_NEAR(f[c], m[c], 4 * se[c] + 0.02 * m[c]);
                    worst = fmax(worst, fabs(r[c] - m[c]) / se[c]);
                    worst_fx = fmax(worst_fx, fabs(f[c] - m[c]) / m[c]);
                }
            }
        printf("  noise emitting box: march vs path tracer at most %.2f standard errors; froxels (128 slices) "
               "vs path tracer at most %.2f%%\n",
               worst, 100 * worst_fx);
        /* The pattern matters: the blocks differ by far more than the tolerance. */
        printf("  blocks of the march (red): %.4f .. %.4f, path tracer's largest se %.4f\n", lo, hi, se_max);
        CHECK(hi - lo > 8 * se_max);
    }
    nacre_image_free(ctx, &rm);
    nacre_image_free(ctx, &fx);
    nacre_image_free(ctx, &pt);
    nacre_image_free(ctx, &var);
}

/* ---- scene files and the API ---------------------------------------------------------------- */

static void expect_error(const char *fog, const char *needle) { media_expect_fog_error(ctx, fog, needle); }

/* s saved to JSON (which must hold `needle`) and loaded back; NULL on failure. */
static nacre_scene *reloaded(nacre_scene *s, const char *needle)
{
    char *json = NULL;
    CHECK(nacre_scene_save_json(s, NULL, NACRE_TEST_TMP, &json, NULL) == NACRE_OK);
    CHECK(json && strstr(json, needle));
    nacre_scene *t = NULL;
    nacre_scene_file_settings fs;
    if (json)
        CHECK(nacre_scene_load_json(ctx, json, strlen(json), "saved.json", NACRE_TEST_TMP, &t, &fs) == NACRE_OK);
    nacre_free(ctx, json);
    return t;
}

static void files_and_api(void)
{
    nacre_scene *s = media_load(ctx, NOISE_BOX, NULL);
    if (s) {
        nacre_scene *t = reloaded(s, "\"emission\"");
        if (t) {
            nacre_fog_desc a, b;
            CHECK(nacre_scene_get_fog(s, (nacre_fog){1}, &a) == NACRE_OK);
            CHECK(nacre_scene_get_fog(t, (nacre_fog){1}, &b) == NACRE_OK);
            CHECK(memcmp(a.emission, b.emission, sizeof(a.emission)) == 0);
            CHECK(a.emission[0] == 1.0f && a.emission[1] == 0.8f && a.emission[2] == 0.5f);
            nacre_scene_destroy(t);
        }
        /* The API: NaN and negative values name the field. */
        nacre_fog_desc d = nacre_fog_desc_defaults(NACRE_FOG_BOX);
        nacre_fog h;
        d.emission[1] = NAN;
        CHECK(nacre_scene_add_fog(s, &d, &h) == NACRE_ERROR_INVALID_ARGUMENT);
        CHECK(strstr(nacre_context_last_error(ctx), "emission") != NULL);
        d.emission[1] = -1.0f;
        CHECK(nacre_scene_add_fog(s, &d, &h) == NACRE_ERROR_INVALID_ARGUMENT);
        d.emission[1] = 1.0f;
        CHECK(nacre_scene_add_fog(s, &d, &h) == NACRE_OK);
        nacre_scene_destroy(s);
    }
    /* Without emission nothing is written (files stay as they were). */
    nacre_scene *plain = media_load(ctx, BOX_SCENE("{\"shape\": \"box\", \"size\": 2, \"sigma_a\": 1, \"sigma_s\": 0}"), NULL);
    if (plain) {
        char *json = NULL;
        CHECK(nacre_scene_save_json(plain, NULL, NACRE_TEST_TMP, &json, NULL) == NACRE_OK);
        CHECK(json && !strstr(json, "emission"));
        nacre_free(ctx, json);
        nacre_scene_destroy(plain);
    }
    expect_error("{\"shape\": \"box\", \"size\": 1, \"emission\": [1, -0.5, 0]}", "emission");
    expect_error("{\"shape\": \"box\", \"size\": 1, \"emission\": [1, 2]}", "emission");
    expect_error("{\"shape\": \"box\", \"size\": 1, \"emission\": \"bright\"}", "emission");
    expect_error("{\"shape\": \"global\", \"sigma_a\": 0, \"sigma_s\": [0.1, 0, 0.1], \"emission\": 1}", "emission");
}

/* ---- an emission grid of its own: "emission_pattern" ------------------------------------------- */

/* A 2 x 2 x 2 NRRD volume of one value: constant everywhere (volumes clamp outside). */
static bool write_constant_nrrd(const char *path, float value)
{
    FILE *f = fopen(path, "wb");
    if (!f)
        return false;
    fprintf(f, "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 2 2\nspacings: 1 1 1\nencoding: raw\n"
               "endian: little\n\n");
    float v[8];
    for (int i = 0; i < 8; i++)
        v[i] = value;
    bool ok = fwrite(v, sizeof(v), 1, f) == 1;
    return fclose(f) == 0 && ok;
}

/* json's box against the closed form of absorption sa and emission em: the fog pass to 1e-5,
 * froxels and the march to 2%, the path tracer per band of rows within 4 standard errors. */
static void check_emitting_box(const char *json, const double *sa, const double *em, uint32_t seed, const char *what)
{
    nacre_image fp = {0}, fx = {0}, rm = {0}, pt = {0}, var = {0};
    if (render_techniques(json, 64, 64, 64, seed, &fp, &fx, &rm, &pt, &var)) {
        double e_fp = worst_box_error_of(&fp, false, sa, em), e_fx = worst_box_error_of(&fx, true, sa, em),
               e_rm = worst_box_error_of(&rm, true, sa, em), worst_sigma = 0;
        for (int y0 = 9; y0 + 4 <= 23; y0 += 4) {
            double m[3], se[3];
            media_region(&pt, &var, 9, 23, y0, y0 + 4, m, se);
            for (int c = 0; c < 3; c++) {
                double x = box_exact_of(16, y0, c, sa, em);
                CHECK_NEAR(m[c], x, 4 * se[c]);
                worst_sigma = fmax(worst_sigma, fabs(m[c] - x) / se[c]);
            }
        }
        printf("  %s: largest relative error fog pass %.2e, froxel %.2e, raymarch %.2e; path tracer within %.2f "
               "standard errors\n",
               what, e_fp, e_fx, e_rm, worst_sigma);
        CHECK(e_fp < 1e-5);
        CHECK(e_fx < 0.02);
        CHECK(e_rm < 0.02);
    }
    nacre_image_free(ctx, &fp);
    nacre_image_free(ctx, &fx);
    nacre_image_free(ctx, &rm);
    nacre_image_free(ctx, &pt);
    nacre_image_free(ctx, &var);
}

/* The box of EMIT_BOX with a density volume of `dens` (0: none) and an emission volume of
 * `scale` (0: none), against its closed form: sigma = dens sigma_a (the density scales medium
 * 1), emission = scale eps with an emission pattern, else dens eps (the density's rule). */
static void emission_pattern_case(const char *dens_path, double dens, const char *em_path, double scale)
{
    char fog[1024], json[4096], pat[512] = "", em_pat[512] = "";
    if (dens > 0)
        snprintf(pat, sizeof(pat), ", \"pattern\": {\"type\": \"volume\", \"volume\": \"%s\"}", dens_path);
    if (scale > 0)
        snprintf(em_pat, sizeof(em_pat), ", \"emission_pattern\": {\"type\": \"volume\", \"volume\": \"%s\"}", em_path);
    snprintf(fog, sizeof(fog),
             "{\"shape\": \"box\", \"size\": 2, \"sigma_a\": [0.5, 1.5, 0], \"sigma_s\": 0, "
             "\"emission\": [0.3, 0.6, 0.9]%s%s}",
             pat, em_pat);
    snprintf(json, sizeof(json), BOX_SCENE("%s"), fog);
    double d = dens > 0 ? dens : 1.0, e = scale > 0 ? scale : d, sa[3], em[3];
    for (int c = 0; c < 3; c++) {
        sa[c] = d * BOX_SA[c];
        em[c] = e * BOX_EM[c];
    }
    char what[128];
    snprintf(what, sizeof(what), "density %.1f, emission pattern %.1f", dens, scale);
    check_emitting_box(json, sa, em, 3, what);
}

static void emission_pattern(void)
{
    const char *dens = NACRE_TEST_TMP "/emission_density.nrrd", *em = NACRE_TEST_TMP "/emission_grid.nrrd";
    CHECK(write_constant_nrrd(dens, 0.5f));
    CHECK(write_constant_nrrd(em, 3.0f));
    emission_pattern_case(dens, 0.0, em, 3.0); /* homogeneous fog, emission from its own grid */
    emission_pattern_case(dens, 0.5, em, 3.0); /* each follows its own grid */
    emission_pattern_case(dens, 0.5, em, 0.0); /* no emission grid: emission follows the density */

    /* Saved and reloaded: the same two volumes, and an emission pattern of another type. */
    char json[4096];
    snprintf(json, sizeof(json),
             BOX_SCENE("{\"shape\": \"box\", \"size\": 2, \"sigma_a\": 1, \"sigma_s\": 0, \"emission\": 1, "
                       "\"pattern\": {\"type\": \"volume\", \"volume\": \"%s\"}, \"emission_pattern\": "
                       "{\"type\": \"volume\", \"volume\": \"%s\"}}, {\"shape\": \"sphere\", \"size\": 1, "
                       "\"emission\": [1, 2, 3], \"emission_pattern\": {\"type\": \"checker\", \"cell_size\": 0.25}}"),
             dens, em);
    nacre_scene *s = media_load(ctx, json, NULL);
    if (s) {
        nacre_scene *t = reloaded(s, "\"emission_pattern\"");
        if (t) {
            nacre_fog_desc a, b;
            CHECK(nacre_scene_get_fog(t, (nacre_fog){1}, &a) == NACRE_OK);
            CHECK(a.pattern.type == NACRE_PATTERN_VOLUME && a.emission_pattern.type == NACRE_PATTERN_VOLUME);
            CHECK(a.pattern.volume.id != a.emission_pattern.volume.id);
            CHECK(nacre_scene_get_fog(t, (nacre_fog){2}, &b) == NACRE_OK);
            CHECK(b.pattern.type == NACRE_PATTERN_NONE && b.emission_pattern.type == NACRE_PATTERN_CHECKER);
            CHECK(b.emission_pattern.cell_size == 0.25f);
            nacre_scene_destroy(t);
        }
        nacre_scene_destroy(s);
    }
    /* From an OpenVDB file: the cloud's grid as the emission of a homogeneous box renders as
     * the same samples read from NRRD. */
    if (nc_vdb_available()) {
        nacre_image a = {0}, b = {0};
        nacre_render_settings rs = media_settings(NACRE_METHOD_PHONG, NACRE_VOLUMETRICS_RAYMARCH, 32, 32);
        rs.volumetrics.raymarch_steps = 64;
        const char *fmt = BOX_SCENE("{\"shape\": \"box\", \"size\": 2, \"sigma_a\": 0.2, \"sigma_s\": 0, "
                                    "\"emission\": 1, \"emission_pattern\": {\"type\": \"volume\", \"volume\": "
                                    "\"%s\"%s}}");
        char j1[4096], j2[4096];
        snprintf(j1, sizeof(j1), fmt, NACRE_SOURCE_DIR "/tests/data/vdb_cloud.vdb", ", \"grid\": \"density\"");
        snprintf(j2, sizeof(j2), fmt, NACRE_SOURCE_DIR "/tests/data/vdb_cloud.nrrd", "");
        if (media_render(ctx, j1, &rs, &a, NULL) && media_render(ctx, j2, &rs, &b, NULL)) {
            double diff = max_rel_diff(&a, &b), lo = INFINITY, hi = 0;
            for (int y = 0; y < 32; y++)
                for (int x = 0; x < 32; x++) {
                    lo = fmin(lo, media_px(&a, x, y, 0));
                    hi = fmax(hi, media_px(&a, x, y, 0));
                }
            printf("  emission grid from .vdb against .nrrd: largest relative difference %.2e; red %.4f .. %.4f\n",
                   diff, lo, hi);
            CHECK(diff < 1e-6);
            CHECK(hi > lo + 0.05); /* the cloud glows over the background */
        }
        nacre_image_free(ctx, &a);
        nacre_image_free(ctx, &b);
    }
    expect_error("{\"shape\": \"box\", \"size\": 1, \"emission\": 1, \"emission_pattern\": {\"type\": \"swirl\"}}",
                 "emission_pattern");
    expect_error("{\"shape\": \"box\", \"size\": 1, \"emission\": 1, \"emission_pattern\": {\"type\": \"checker\"}}",
                 "emission_pattern");
    expect_error("{\"shape\": \"box\", \"size\": 1, \"emission\": 1, \"emission_pattern\": 3}", "emission_pattern");
}

/* ---- emission from a temperature grid: the black body ---------------------------------------- */

static void blackbody(void)
{
    /* Published reference numbers: the candela of 1948 was 1/60 of the luminance of a square
     * centimetre of a black body at the freezing point of platinum (2042 K), so 683 lm/W times
     * Y is 6.0e5 cd/m^2 there; CIE illuminant A (2856 K) has chromaticity (0.44757, 0.40745). */
    float c[3];
    nacre_blackbody_rgb(2042.0, c);
    double Y = 0.2126729 * c[0] + 0.7151522 * c[1] + 0.0721750 * c[2];
    printf("  black body at 2042 K: %.4g cd/m^2 (6.0e5 by the 1948 candela)\n", 683.0 * Y);
    CHECK(fabs(683.0 * Y / 6.0e5 - 1.0) < 0.02);
    nacre_blackbody_rgb(2856.0, c);
    double X = 0.4124564 * c[0] + 0.3575761 * c[1] + 0.1804375 * c[2];
    Y = 0.2126729 * c[0] + 0.7151522 * c[1] + 0.0721750 * c[2];
    double Z = 0.0193339 * c[0] + 0.1191920 * c[1] + 0.9503041 * c[2], sum = X + Y + Z;
    printf("  black body at 2856 K: chromaticity (%.5f, %.5f), illuminant A (0.44757, 0.40745)\n", X / sum, Y / sum);
    CHECK(fabs(X / sum - 0.44757) < 0.003 && fabs(Y / sum - 0.40745) < 0.003);
    /* Hotter is brighter in every channel and bluer; out of range and NaN give 0. */
    float prev[3] = {0, 0, 0};
    int bad = 0;
    for (double t = 1000.0; t < 60000.0; t *= 1.013) {
        nacre_blackbody_rgb(t, c);
        for (int k = 0; k < 3; k++)
            bad += !(c[k] >= prev[k]) || !isfinite(c[k]);
        bad += t > 2500.0 && !(c[2] / c[0] > prev[2] / prev[0]);
        memcpy(prev, c, sizeof(prev));
    }
    CHECK(bad == 0);
    nacre_blackbody_rgb(300.0, c);
    CHECK(c[0] == 0.0f && c[1] == 0.0f && c[2] == 0.0f);
    nacre_blackbody_rgb(NAN, c);
    CHECK(c[0] == 0.0f && c[1] == 0.0f && c[2] == 0.0f);

    /* A box whose emission grid holds 2000 (K): emission x the black body's radiance. */
    const char *grid = NACRE_TEST_TMP "/temperature_2000.nrrd";
    CHECK(write_constant_nrrd(grid, 2000.0f));
    char fog[1024], json[4096];
    snprintf(fog, sizeof(fog),
             "{\"shape\": \"box\", \"size\": 2, \"sigma_a\": [0.5, 1.5, 0], \"sigma_s\": 0, \"emission\": [1e-3, 2e-3, "
             "0.1], \"emission_pattern\": {\"type\": \"volume\", \"volume\": \"%s\", \"blackbody\": true, "
             "\"kelvin_scale\": 2}}",
             grid);
    snprintf(json, sizeof(json), BOX_SCENE("%s"), fog);
    const double emission[3] = {1e-3, 2e-3, 0.1};
    double em[3];
    nacre_blackbody_rgb(4000.0, c); /* 2000 x kelvin_scale 2 */
    for (int k = 0; k < 3; k++)
        em[k] = emission[k] * c[k];
    check_emitting_box(json, BOX_SA, em, 4, "black-body box (4000 K)");
    /* Saved and reloaded with its scale; refused elsewhere. */
    nacre_scene *sc = media_load(ctx, json, NULL);
    if (sc) {
        nacre_scene *t = reloaded(sc, "\"blackbody\"");
        if (t) {
            nacre_fog_desc a;
            CHECK(nacre_scene_get_fog(t, (nacre_fog){1}, &a) == NACRE_OK);
            CHECK(a.emission_pattern.blackbody && a.emission_pattern.kelvin_scale == 2.0f);
            nacre_scene_destroy(t);
        }
        nacre_fog_desc d = nacre_fog_desc_defaults(NACRE_FOG_BOX);
        nacre_fog h;
        d.emission_pattern.type = NACRE_PATTERN_CHECKER;
        d.emission_pattern.cell_size = 1.0f;
        d.emission_pattern.blackbody = true;
        d.emission_pattern.kelvin_scale = 1.0f;
        CHECK(nacre_scene_add_fog(sc, &d, &h) == NACRE_ERROR_INVALID_ARGUMENT);
        CHECK(strstr(nacre_context_last_error(ctx), "blackbody") != NULL);
        nacre_scene_destroy(sc);
    }
    char bad_fog[1024];
    snprintf(bad_fog, sizeof(bad_fog),
             "{\"shape\": \"box\", \"size\": 1, \"pattern\": {\"type\": \"volume\", \"volume\": \"%s\", \"blackbody\": "
             "true}}",
             grid);
    expect_error(bad_fog, "blackbody");
    snprintf(bad_fog, sizeof(bad_fog),
             "{\"shape\": \"box\", \"size\": 1, \"emission\": 1, \"emission_pattern\": {\"type\": \"volume\", "
             "\"volume\": \"%s\", \"blackbody\": true, \"kelvin_scale\": 0}}",
             grid);
    expect_error(bad_fog, "kelvin_scale");
    snprintf(bad_fog, sizeof(bad_fog),
             "{\"shape\": \"box\", \"size\": 1, \"emission\": 1, \"emission_pattern\": {\"type\": \"volume\", "
             "\"volume\": \"%s\", \"kelvin_scale\": 2}}",
             grid);
    expect_error(bad_fog, "kelvin_scale");
}

int main(void)
{
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    files_and_api();
    global_fog_pass();
    emitting_box();
    noise_box();
    emission_pattern();
    blackbody();
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
