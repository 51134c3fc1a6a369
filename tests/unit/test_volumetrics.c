/*
 * test_volumetrics.c: the volumetric fog passes (src/render/post_volumetrics.c, froxels and the
 * per-pixel march; src/volume/fog_field.c) against closed forms and the path tracer:
 *   - a box of homogeneous fog under a delta sun from straight above, seen sideways through an
 *     orthographic camera, no occluders: every pixel against the closed-form single scattering
 *     sigma_s p(90) E e^(-sigma_t (1 - y)) (1 - e^(-2 sigma_t)) / sigma_t (within 2%; the froxel
 *     grid coarser than the image, so the columns are interpolated), and against the path tracer
 *     with max_scatter 1 per band of rows (its noise plus 2%);
 *   - a global homogeneous fog lit by the environment alone (a constant source): froxels, the
 *     march and the analytic pass agree (0.5%) on objects and background; the march does not
 *     depend on its step count nor the froxels' background on the slice count (segment
 *     integral); 1 and 2 threads give the same bits; transmittance stays in [0, 1] (fog_field);
 *   - a global height fog lit by a sun (a slab above the view casts a shaft), point lights below
 *     and above the view and a spot, seen
 *     through an orthographic camera whose pixels are the froxel columns and whose march steps
 *     are the slices: froxels (the optical depth towards the lights in float closed form, a fast
 *     exponential) against the march (every optical depth integrated in double) within 0.1%,
 *     and a row of the sun alone against its closed form (2%);
 *   - volumetric shadows: a black box under a spot light in fog casts a shaft; its contrast
 *     (1 - shaft / lit beside it) by froxels and by the march against the path tracer
 *     (max_scatter 1) within 5% of the contrast;
 *   - the fast exponential of volume.h against exp (relative 1e-7) and its segment ratio;
 *   - temporal reprojection of the froxels: on a static camera with 6 slices straddling the
 *     box's faces the jittered, blended frames converge (RMS error under half of the single
 *     frame's); a first frame equals a frame with the setting off; with a moving camera and
 *     aligned slices (exact without history) the reprojected frames stay within 3% (ghosting);
 *   - the optical-depth grids towards each light through a patterned box (light_volume.h): their
 *     transmittance against a direct march from points in and around the box (a sun's
 *     light-aligned grid against a 256-step march, a point light's grid against the same 8-step
 *     march its nodes use): largest |dT| under 0.1 (sun) and 0.03 (point), RMS under 0.008 and
 *     0.006, and the same checks failing on a grid of 4 nodes an axis; where their lookups may be
 *     other than 0 (nc_light_volume_reach8) contains every point whose lookup is not (a lattice
 *     and points nudged across the edges of the box's shadow) and leaves out over a quarter of it
 *     for the sun and the point light outside; a gray fog's grids (one
 *     channel stored) equal its three-channel grids bit for bit, and only gray fogs are found gray;
 *   - bounded patterned fogs alone (the coarse optical depths 8 lanes at a time) give the frame
 *     that the general path (a global patterned fog of zero density added) gives, bit for bit,
 *     and a colored box with its channels reversed swaps the frame's red and blue;
 *   - frames kept between renders (froxel grid, its fill, each light's coarse optical depths and
 *     grids; the analytic pass's per-pixel T and L): a renderer's second, unchanged frame and its frames
 *     after moving a sun, a spot, the camera or editing the fog equal a new renderer's frame of
 *     the same scene bit for bit;
 *   - settings: bad values give errors naming the field; scene-file keys load and save.
 */
#include "media_util.h"

#include "volume/fog_field.h"
#include "volume/light_volume.h"

#include <nacre/nacre.h>

#include <math.h>
#include <stdio.h>
#include <string.h>

static nacre_context *ctx;
static const double PI = 3.14159265358979323846;

/* ---- a box of fog under a sun, no occluders ------------------------------------------------ */

/* Orthographic camera at z = 5 looking down -z over [-2, 2]^2; near 1 and far 9, so that 64
 * equal slices (or march steps) of 1/8 put boundaries on the box's faces at depths 4 and 6. A
 * black sphere behind the camera, casting no shadow, is the object the raster methods need. */
#define SUN_SCENE                                                                                   \
    "{\"camera\": {\"type\": \"orthographic\", \"position\": [0, 0, 5], \"target\": [0, 0, 0], "    \
    "\"height\": 4, \"near\": 1, \"far\": 9}, \"environment\": 0,"                                  \
    "\"materials\": {\"black\": {\"type\": \"opaque\", \"diffuse\": 0, \"specular\": 0}},"          \
    "\"objects\": [{\"shape\": {\"type\": \"sphere\", \"radius\": 0.1}, \"material\": \"black\","   \
    "\"transform\": {\"translate\": [0, 0, 20]}, \"shadows\": false}],"                             \
    "\"lights\": [{\"type\": \"directional\", \"direction\": [0, -1, 0], \"irradiance\": 2, "      \
    "\"angular_radius\": 0}],"                                                                      \
    "\"fog\": [{\"shape\": \"box\", \"size\": 2, \"sigma_a\": 0.3, \"sigma_s\": [0.9, 0.6, 0.3], \"g\": 0.4}]}"

static double sun_exact(double y, int c)
{
    const double g = 0.4, ss[3] = {0.9, 0.6, 0.3};
    double p90 = (1 - g * g) / (4 * PI * pow(1 + g * g, 1.5)), st = 0.3 + ss[c];
    if (fabs(y) >= 1)
        return 0;
    return ss[c] * p90 * 2 * exp(-st * (1 - y)) * (1 - exp(-2 * st)) / st;
}

static void sun_closed_form(void)
{
    const int W = 32, H = 32;
    nacre_image img[2] = {{0}, {0}};
    for (int k = 0; k < 2; k++) {
        nacre_render_settings rs =
            media_settings(NACRE_METHOD_PHONG, k ? NACRE_VOLUMETRICS_RAYMARCH : NACRE_VOLUMETRICS_FROXEL, W, H);
        rs.volumetrics.froxel_width = 16; /* half the image: pixels between column centres */
        rs.volumetrics.froxel_height = 16;
        if (!media_render(ctx, SUN_SCENE, &rs, &img[k], NULL))
            return;
    }
    double worst[2] = {0, 0};
    /* Rows and columns well inside the box (|x|, |y| < 0.9), where the closed form is smooth;
     * the box's top and bottom edges fall between froxel rows. */
    for (int y = 2; y < 30; y++)
        for (int x = 2; x < 30; x++)
            for (int c = 0; c < 3; c++) {
                double yy = 2 - (y + 0.5) / 8, xx = (x + 0.5) / 8 - 2;
                if (fabs(yy) > 0.85 || fabs(xx) > 0.85)
                    continue;
                double e = sun_exact(yy, c);
                for (int k = 0; k < 2; k++) {
                    double err = fabs(media_px(&img[k], x, y, c) - e) / e;
                    worst[k] = err > worst[k] ? err : worst[k];
                }
            }
    printf("  sun over a fog box: largest relative error froxel %.4f, raymarch %.4f\n", worst[0], worst[1]);
    CHECK(worst[0] < 0.02);
    CHECK(worst[1] < 0.02);

    /* The path tracer (single scattering) on the same scene, per band of 4 rows. */
    nacre_render_settings rs = media_settings(NACRE_METHOD_PATHTRACE, NACRE_VOLUMETRICS_OFF, W, H);
    rs.pathtrace.spp = 256;
    rs.pathtrace.seed = 3;
    rs.pathtrace.max_scatter = 1;
    nacre_image ref = {0}, var = {0};
    if (media_render(ctx, SUN_SCENE, &rs, &ref, &var)) {
        for (int y0 = 2; y0 < 30; y0 += 4) {
            double m[3], se[3], f[3], r[3], dummy[3];
            media_region(&ref, &var, 4, 28, y0, y0 + 4, m, se);
            media_region(&img[0], NULL, 4, 28, y0, y0 + 4, f, dummy);
            media_region(&img[1], NULL, 4, 28, y0, y0 + 4, r, dummy);
            printf("  rows %2d-%2d: path tracer %.5f +- %.5f, froxel %.5f, raymarch %.5f\n", y0, y0 + 3, m[0], se[0],
                   f[0], r[0]);
            for (int c = 0; c < 3; c++) {
                CHECK_NEAR(f[c], m[c], 4 * se[c] + 0.02 * m[c]);
                CHECK_NEAR(r[c], m[c], 4 * se[c] + 0.02 * m[c]);
            }
        }
    }
    nacre_image_free(ctx, &ref);
    nacre_image_free(ctx, &var);
    nacre_image_free(ctx, &img[0]);
    nacre_image_free(ctx, &img[1]);
}

/* ---- temporal reprojection ------------------------------------------------------------------ */

/* Relative error of an image of SUN_SCENE against its closed form, over the box's inner pixels
 * (32 x 32 image of [-2, 2]^2 shifted by (cx, cy) world units): RMS and largest. */
static void sun_errors(const nacre_image *img, double cx, double cy, double *rms, double *worst)
{
    double s = 0;
    int n = 0;
    *worst = 0;
    for (int y = 0; y < 32; y++)
        for (int x = 0; x < 32; x++) {
            double yy = cy + 2 - (y + 0.5) / 8, xx = cx + (x + 0.5) / 8 - 2;
            if (fabs(yy) > 0.85 || fabs(xx) > 0.85)
                continue;
            for (int c = 0; c < 3; c++) {
                double e = sun_exact(yy, c), err = (media_px(img, x, y, c) - e) / e;
                s += err * err;
                n++;
                *worst = fmax(*worst, fabs(err));
            }
        }
    *rms = n ? sqrt(s / n) : 0;
}

/* Frames of SUN_SCENE by one renderer with the camera at (cx(f), cy(f), 5), f = 0 .. frames - 1;
 * the last frame's errors, and the largest RMS over the frames from `from` on. */
static bool temporal_run(float temporal, uint32_t slices, int frames, double move, double *rms_last,
                         double *worst_last, double *rms_max, int from)
{
    nacre_render_settings rs;
    nacre_scene *s = media_load(ctx, SUN_SCENE, &rs);
    if (!s)
        return false;
    rs.method = NACRE_METHOD_PHONG;
    rs.width = rs.height = 32;
    rs.volumetrics.mode = NACRE_VOLUMETRICS_FROXEL;
    rs.volumetrics.froxel_width = rs.volumetrics.froxel_height = 32;
    rs.volumetrics.froxel_slices = slices;
    rs.volumetrics.temporal = temporal;
    nacre_renderer *r = NULL;
    CHECK(nacre_renderer_create(ctx, &r) == NACRE_OK);
    nacre_camera_desc cam;
    CHECK(nacre_scene_get_camera(s, &cam) == NACRE_OK);
    nacre_image img = {0};
    bool ok = true;
    *rms_max = 0;
    for (int f = 0; f < frames && ok; f++) {
        /* Along a diagonal, so that the sun's gradient (in y) moves across the pixels. */
        double cx = move * f, cy = 0.5 * move * f;
        cam.position[0] = cam.target[0] = (float)cx;
        cam.position[1] = cam.target[1] = (float)cy;
        ok = nacre_scene_set_camera(s, &cam) == NACRE_OK && nacre_scene_commit(s, 0.0) == NACRE_OK &&
             nacre_renderer_render(r, s, &rs, &img, NULL) == NACRE_OK;
        CHECK(ok);
        double rms, worst;
        if (ok) {
            sun_errors(&img, cx, cy, &rms, &worst);
            if (f >= from)
                *rms_max = fmax(*rms_max, rms);
            *rms_last = rms;
            *worst_last = worst;
        }
    }
    nacre_image_free(ctx, &img);
    nacre_renderer_destroy(r);
    nacre_scene_destroy(s);
    return ok;
}

static void temporal(void)
{
    /* Static camera, 6 slices over depths 1 .. 9 (the box's faces at 4 and 6 inside slices 2 and
     * 3, whose centres both fall in the box): the jitter spreads the samples over the slices. */
    double off_rms, off_worst, tmp_rms, tmp_worst, mx;
    if (!temporal_run(0.0f, 6, 1, 0.0, &off_rms, &off_worst, &mx, 0) ||
        !temporal_run(0.9f, 6, 48, 0.0, &tmp_rms, &tmp_worst, &mx, 0))
        return;
    printf("  temporal, static camera, 6 slices: RMS relative error off %.4f (largest %.4f), temporal 0.9 after "
           "48 frames %.4f (largest %.4f)\n",
           off_rms, off_worst, tmp_rms, tmp_worst);
    CHECK(tmp_rms < 0.5 * off_rms);
    /* A frame with the setting off equals the first temporal frame (jitter 0.5, no history). */
    double first_rms, first_worst;
    CHECK(temporal_run(0.9f, 6, 1, 0.0, &first_rms, &first_worst, &mx, 0));
    CHECK(first_rms == off_rms && first_worst == off_worst);

    /* Moving camera, 64 slices aligned with the box (exact without history): the history's
     * resampling and the lag behind the camera (ghosting) are the only errors. */
    double move_off, mo_worst, move_tmp, mt_worst, off_max, tmp_max;
    if (!temporal_run(0.0f, 64, 24, 0.04, &move_off, &mo_worst, &off_max, 1) ||
        !temporal_run(0.9f, 64, 24, 0.04, &move_tmp, &mt_worst, &tmp_max, 1))
        return;
    printf("  temporal, camera moving 0.04 + 0.02 units (0.36 pixels) per frame, 64 aligned slices: RMS relative "
           "error off %.4f (largest over frames %.4f), temporal 0.9 %.4f (largest over frames %.4f; largest pixel "
           "%.4f)\n",
           move_off, off_max, move_tmp, tmp_max, mt_worst);
    /* Without following the camera the history would lag ~10 frames, 0.2 units up the sun's
     * gradient (e^(0.2 sigma_t): up to 27%); measured 2.3% at most (resampling the history across
     * the box's faces and the gradient). */
    CHECK(tmp_max < 0.03);
    CHECK(move_tmp < 0.02);
}

/* ---- a constant source: environment light in a global fog ---------------------------------- */

#define AMBIENT_SCENE                                                                               \
    "{\"camera\": {\"position\": [0, 1, 6], \"target\": [0, 0, 0], \"fov\": 50}, \"environment\": 0.5," \
    "\"materials\": {\"m\": {\"type\": \"opaque\", \"diffuse\": [0.8, 0.5, 0.2]}},"                 \
    "\"objects\": [{\"shape\": {\"type\": \"sphere\"}, \"material\": \"m\"},"                       \
    "{\"shape\": {\"type\": \"plane\", \"size\": [6, 6]}, \"material\": \"m\","                     \
    "\"transform\": {\"translate\": [0, -1, -2]}}],"                                                \
    "\"fog\": [{\"shape\": \"global\", \"sigma_a\": [0.02, 0.05, 0.1], \"sigma_s\": [0.2, 0.1, 0.05]}]}"

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

static void constant_source(void)
{
    const int W = 48, H = 36;
    nacre_image off = {0}, fx = {0}, rm = {0}, rm4 = {0}, fx8 = {0};
    nacre_render_settings rs = media_settings(NACRE_METHOD_PHONG, NACRE_VOLUMETRICS_OFF, W, H);
    bool ok = media_render(ctx, AMBIENT_SCENE, &rs, &off, NULL);
    rs.volumetrics.mode = NACRE_VOLUMETRICS_FROXEL;
    ok = ok && media_render(ctx, AMBIENT_SCENE, &rs, &fx, NULL);
    rs.volumetrics.froxel_slices = 8;
    ok = ok && media_render(ctx, AMBIENT_SCENE, &rs, &fx8, NULL);
    rs.volumetrics.mode = NACRE_VOLUMETRICS_RAYMARCH;
    ok = ok && media_render(ctx, AMBIENT_SCENE, &rs, &rm, NULL);
    rs.volumetrics.raymarch_steps = 4;
    ok = ok && media_render(ctx, AMBIENT_SCENE, &rs, &rm4, NULL);
    if (ok) {
        double d_fx = max_rel_diff(&fx, &off), d_rm = max_rel_diff(&rm, &off), d_rm4 = max_rel_diff(&rm4, &rm);
        printf("  ambient in global fog vs the analytic pass: froxel %.2e, raymarch %.2e; 4 vs 64 steps %.2e\n",
               d_fx, d_rm, d_rm4);
        CHECK(d_fx < 0.005);
        CHECK(d_rm < 0.005);
        CHECK(d_rm4 < 1e-4);
        /* Background (the top row sees only sky through the fog): any slice count. */
        double bg = 0;
        for (int x = 0; x < W; x++)
            for (int c = 0; c < 3; c++)
                bg = fmax(bg, fabs(media_px(&fx8, x, 0, c) - media_px(&fx, x, 0, c)) / media_px(&fx, x, 0, c));
        printf("  background with 8 vs 64 slices: %.2e\n", bg);
        CHECK(bg < 1e-4);
    }
    nacre_image_free(ctx, &off);
    nacre_image_free(ctx, &fx);
    nacre_image_free(ctx, &fx8);
    nacre_image_free(ctx, &rm);
    nacre_image_free(ctx, &rm4);
}

/* A sphere on a plane under a spot light and a sun, in a box of noise-patterned height fog, and
 * MORE_FOG (",{...}" or ""). */
#define SPOT_SUN_SCENE(MORE_FOG)                                                                    \
    "{\"camera\": {\"position\": [0, 3, 6], \"target\": [0, 0, 0]}, \"environment\": 0.1,"              \
    "\"materials\": {\"m\": {\"type\": \"opaque\"}},"                                                 \
    "\"objects\": [{\"shape\": {\"type\": \"sphere\"}, \"material\": \"m\"},"                          \
    "{\"shape\": {\"type\": \"plane\", \"size\": [8, 8]}, \"material\": \"m\","                      \
    "\"transform\": {\"translate\": [0, -1, 0]}}],"                                                   \
    "\"lights\": [{\"type\": \"spot\", \"position\": [0, 3, 0], \"direction\": [0, -1, 0],"            \
    "\"intensity\": 20, \"outer_angle\": 30, \"inner_angle\": 20},"                                  \
    "{\"type\": \"directional\", \"direction\": [1, -1, 0], \"irradiance\": 1}],"                    \
    "\"fog\": [{\"shape\": \"box\", \"size\": [6, 4, 6], \"sigma_s\": 0.2, \"height_falloff\": 0.3,"   \
    "\"pattern\": {\"type\": \"noise\", \"cell_size\": 0.5, \"sigma_a2\": 0, \"sigma_s2\": 0}}" MORE_FOG "]}"

/* The same froxel and march frames from 1 and 2 threads. */
static void thread_count(void)
{
    const char *json = SPOT_SUN_SCENE("");
    for (int mode = NACRE_VOLUMETRICS_FROXEL; mode <= NACRE_VOLUMETRICS_RAYMARCH; mode++) {
        nacre_image img[2] = {{0}, {0}};
        for (int k = 0; k < 2; k++) {
            nacre_context_desc cd = {0};
            cd.threads = k + 1;
            nacre_context *c = NULL;
            CHECK(nacre_context_create(&cd, &c) == NACRE_OK);
            if (!c)
                return;
            nacre_render_settings rs = media_settings(NACRE_METHOD_PHONG, (nacre_volumetrics_mode)mode, 40, 30);
            rs.volumetrics.froxel_width = 20;
            rs.volumetrics.froxel_height = 15;
            rs.volumetrics.raymarch_steps = 16;
            nacre_image tmp = {0};
            if (media_render(c, json, &rs, &tmp, NULL)) {
                CHECK(nacre_image_alloc(ctx, 40, 30, 3, &img[k]) == NACRE_OK);
                memcpy(img[k].pixels, tmp.pixels, 40 * 30 * 3 * sizeof(float));
                nacre_image_free(c, &tmp);
            }
            nacre_context_destroy(c);
        }
        CHECK(img[0].pixels && img[1].pixels &&
              memcmp(img[0].pixels, img[1].pixels, 40 * 30 * 3 * sizeof(float)) == 0);
        bool finite = img[0].pixels != NULL;
        for (size_t i = 0; finite && i < 40 * 30 * 3; i++)
            finite = isfinite(img[0].pixels[i]) && img[0].pixels[i] >= 0;
        CHECK(finite);
        nacre_image_free(ctx, &img[0]);
        nacre_image_free(ctx, &img[1]);
    }
}

/* Bounded patterned fogs only (a colored box, a gray ellipsoid) under a spot whose cone edge
 * crosses them, a sun and a point light inside the box: the froxels' coarse optical depths come
 * from box_tau8 (8 lanes, which lanes each light reaches in vector form); with a global patterned
 * fog of zero density added they come from the general path (marched and summed point by point).
 * Both frames are equal bit for bit. */
#define BOXES_SCENE(SIGMA_S, MORE_FOG)                                                                     \
    "{\"camera\": {\"position\": [0, 3, 6], \"target\": [0, 0, 0]}, \"environment\": 0.1,"              \
    "\"materials\": {\"m\": {\"type\": \"opaque\"}},"                                                 \
    "\"objects\": [{\"shape\": {\"type\": \"sphere\"}, \"material\": \"m\"},"                          \
    "{\"shape\": {\"type\": \"plane\", \"size\": [8, 8]}, \"material\": \"m\","                      \
    "\"transform\": {\"translate\": [0, -1, 0]}}],"                                                   \
    "\"lights\": [{\"type\": \"spot\", \"position\": [0.5, 3, 0], \"direction\": [-0.2, -1, 0.1],"      \
    "\"intensity\": 20, \"outer_angle\": 30, \"inner_angle\": 20},"                                  \
    "{\"type\": \"directional\", \"direction\": [1, -1, 0], \"irradiance\": 1},"                     \
    "{\"type\": \"point\", \"position\": [2, 0.5, 1], \"intensity\": 10}],"                          \
    "\"fog\": [{\"shape\": \"box\", \"size\": [6, 4, 6], \"rotate\": [0, 20, 0],"                     \
    "\"sigma_s\": " SIGMA_S ", \"height_falloff\": 0.3,"                                        \
    "\"pattern\": {\"type\": \"noise\", \"cell_size\": 0.5, \"sigma_a2\": 0, \"sigma_s2\": 0}},"      \
    "{\"shape\": \"sphere\", \"center\": [-1, 0.5, 0], \"size\": [2, 2, 3], \"sigma_a\": 0.2,"        \
    "\"sigma_s\": 1.5, \"pattern\": {\"type\": \"checker\", \"cell_size\": 0.4, \"sigma_a2\": 0,"      \
    "\"sigma_s2\": 0.5}}" MORE_FOG "]}"

/* The lanes whose light box_tau8 leaves to light_at: an orthographic camera (SUN_SCENE's) whose
 * nodes of one slice lie in the plane of a spot pointing along x with a 45 degree cone, so that
 * the nodes on the diagonal of the odd-sized grid (x = y) lie on the cone's edge. */
#define CONE_EDGE_SCENE(MORE_FOG)                                                                   \
    "{\"camera\": {\"type\": \"orthographic\", \"position\": [0, 0, 5], \"target\": [0, 0, 0], "    \
    "\"height\": 4, \"near\": 1, \"far\": 9}, \"environment\": 0,"                                  \
    "\"materials\": {\"black\": {\"type\": \"opaque\", \"diffuse\": 0, \"specular\": 0}},"          \
    "\"objects\": [{\"shape\": {\"type\": \"sphere\", \"radius\": 0.1}, \"material\": \"black\","    \
    "\"transform\": {\"translate\": [0, 0, 20]}, \"shadows\": false}],"                             \
    "\"lights\": [{\"type\": \"spot\", \"position\": [0, 0, 2.875], \"direction\": [1, 0, 0],"       \
    "\"intensity\": 20, \"outer_angle\": 45, \"inner_angle\": 30}],"                                \
    "\"fog\": [{\"shape\": \"box\", \"center\": [1, 0, 2], \"size\": [2.5, 4, 4], \"sigma_s\": 2,"     \
    "\"pattern\": {\"type\": \"noise\", \"cell_size\": 0.3, \"sigma_a2\": 0, \"sigma_s2\": 0}}" MORE_FOG "]}"

#define ZERO_GLOBAL_FOG                                                                             \
    ",{\"shape\": \"global\", \"sigma_s\": 0, \"pattern\": {\"type\": \"noise\", \"cell_size\": 1,"   \
    "\"sigma_a2\": 0, \"sigma_s2\": 0}}"

static void box_fogs(void)
{
    const char *json[2][2] = {{BOXES_SCENE("[0.3, 0.5, 0.7]", ""), BOXES_SCENE("[0.3, 0.5, 0.7]", ZERO_GLOBAL_FOG)},
                              {CONE_EDGE_SCENE(""), CONE_EDGE_SCENE(ZERO_GLOBAL_FOG)}};
    for (int q = 0; q < 2; q++) {
        nacre_image img[2] = {{0}, {0}};
        int w = q ? 66 : 96, h = q ? 66 : 72;
        nacre_render_settings rs = media_settings(NACRE_METHOD_PHONG, NACRE_VOLUMETRICS_FROXEL, w, h);
        rs.volumetrics.froxel_width = w / 2;
        rs.volumetrics.froxel_height = h / 2;
        rs.volumetrics.froxel_slices = 32;
        for (int k = 0; k < 2; k++)
            CHECK(media_render(ctx, json[q][k], &rs, &img[k], NULL));
        CHECK(img[0].pixels && img[1].pixels &&
              memcmp(img[0].pixels, img[1].pixels, (size_t)w * h * 3 * sizeof(float)) == 0);
        nacre_image_free(ctx, &img[0]);
        nacre_image_free(ctx, &img[1]);
    }
    /* The colored box's channels reversed (everything else in the scene is gray): the frame's red
     * and blue swap. Its coarse optical depths differ by channel (not gray, three channels
     * interpolated); one channel's depths taken for all three would break the swap. */
    nacre_image img[2] = {{0}, {0}};
    nacre_render_settings rs = media_settings(NACRE_METHOD_PHONG, NACRE_VOLUMETRICS_FROXEL, 96, 72);
    rs.volumetrics.froxel_width = 48;
    rs.volumetrics.froxel_height = 36;
    rs.volumetrics.froxel_slices = 32;
    CHECK(media_render(ctx, BOXES_SCENE("[0.3, 0.5, 0.7]", ""), &rs, &img[0], NULL));
    CHECK(media_render(ctx, BOXES_SCENE("[0.7, 0.5, 0.3]", ""), &rs, &img[1], NULL));
    double worst = 0, top = 0;
    for (int y = 0; img[0].pixels && img[1].pixels && y < 72; y++)
        for (int x = 0; x < 96; x++)
            for (int c = 0; c < 3; c++) {
                double a = media_px(&img[0], x, y, c), b = media_px(&img[1], x, y, 2 - c);
                top = fmax(top, a);
                worst = fmax(worst, fabs(a - b));
            }
    printf("  colored patterned box, channels reversed: largest difference %.2e of %.3f\n", worst, top);
    CHECK(top > 0 && worst <= 1e-6 * top);
    nacre_image_free(ctx, &img[0]);
    nacre_image_free(ctx, &img[1]);
}

/* ---- frames kept between renders ------------------------------------------------------------ */

/* A frame of s by renderer r, then by a new renderer: equal bit for bit. */
static void reuse_check(nacre_renderer *r, nacre_scene *s, const nacre_render_settings *rs, const char *what)
{
    nacre_image kept = {0}, fresh = {0};
    nacre_renderer *n = NULL;
    CHECK(nacre_renderer_create(ctx, &n) == NACRE_OK);
    bool ok = n && nacre_renderer_render(r, s, rs, &kept, NULL) == NACRE_OK &&
              nacre_renderer_render(n, s, rs, &fresh, NULL) == NACRE_OK;
    CHECK(ok);
    bool same = ok && memcmp(kept.pixels, fresh.pixels, (size_t)rs->width * rs->height * 3 * sizeof(float)) == 0;
    if (!same)
        printf("  frame reuse: %s (%s) differs from a new renderer's frame\n", what,
               rs->volumetrics.mode == NACRE_VOLUMETRICS_FROXEL ? "froxel" : "analytic");
    CHECK(same);
    nacre_image_free(ctx, &kept);
    nacre_image_free(ctx, &fresh);
    nacre_renderer_destroy(n);
}

static void frame_reuse(void)
{
    const char *json = SPOT_SUN_SCENE(",{\"shape\": \"global\", \"sigma_s\": 0.02, \"height_falloff\": 0.5}");
    /* Twice for the froxels: 2 pixels a column, and 8 (froxel_apply_pixels' 8-pixel path, whose
     * result the second frame's per-pixel path must match bit for bit). */
    for (int pass = 0; pass < 3; pass++) {
        int mode = pass < 2 ? pass + NACRE_VOLUMETRICS_OFF : NACRE_VOLUMETRICS_FROXEL, wide = pass == 2 ? 4 : 1;
        nacre_scene *s = media_load(ctx, json, NULL);
        if (!s)
            return;
        nacre_render_settings rs = media_settings(NACRE_METHOD_PHONG, (nacre_volumetrics_mode)mode, 40 * wide, 30);
        rs.volumetrics.froxel_width = 20;
        rs.volumetrics.froxel_height = 15;
        rs.volumetrics.froxel_slices = 24;
        nacre_renderer *r = NULL;
        CHECK(nacre_renderer_create(ctx, &r) == NACRE_OK);
        nacre_image first = {0};
        CHECK(nacre_renderer_render(r, s, &rs, &first, NULL) == NACRE_OK);
        reuse_check(r, s, &rs, "an unchanged frame");
        reuse_check(r, s, &rs, "a third unchanged frame");
        nacre_light_desc ld;
        CHECK(nacre_scene_get_light(s, (nacre_light){2}, &ld) == NACRE_OK);
        ld.direction[2] = 0.3f;
        CHECK(nacre_scene_set_light(s, (nacre_light){2}, &ld) == NACRE_OK && nacre_scene_commit(s, 0.0) == NACRE_OK);
        reuse_check(r, s, &rs, "the sun turned");
        reuse_check(r, s, &rs, "unchanged after the sun turned");
        CHECK(nacre_scene_get_light(s, (nacre_light){1}, &ld) == NACRE_OK);
        ld.position[0] = 0.5f;
        CHECK(nacre_scene_set_light(s, (nacre_light){1}, &ld) == NACRE_OK && nacre_scene_commit(s, 0.0) == NACRE_OK);
        reuse_check(r, s, &rs, "the spot moved");
        nacre_fog_desc fd;
        CHECK(nacre_scene_get_fog(s, (nacre_fog){1}, &fd) == NACRE_OK);
        fd.sigma_s[1] = 0.4f;
        CHECK(nacre_scene_set_fog(s, (nacre_fog){1}, &fd) == NACRE_OK && nacre_scene_commit(s, 0.0) == NACRE_OK);
        reuse_check(r, s, &rs, "the fog changed");
        nacre_camera_desc cam;
        CHECK(nacre_scene_get_camera(s, &cam) == NACRE_OK);
        cam.position[0] = 0.3f;
        CHECK(nacre_scene_set_camera(s, &cam) == NACRE_OK && nacre_scene_commit(s, 0.0) == NACRE_OK);
        reuse_check(r, s, &rs, "the camera moved");
        rs.volumetrics.froxel_slices = 20;
        reuse_check(r, s, &rs, "fewer slices");
        nacre_image_free(ctx, &first);
        nacre_renderer_destroy(r);
        nacre_scene_destroy(s);
    }
}

/* A box of fog in the middle of the view (a sphere and a plane around it, the environment
 * behind): the columns that hold no medium are skipped (vol_state.col_clear). The frame must
 * equal the first frame with temporal reprojection on, which skips nothing (the history could
 * bring medium anywhere) and otherwise computes the same grid; the pixels that read only clear
 * columns keep the image without fog exactly; the box's pixels do not; kept frames equal fresh
 * ones. Without the identity boundaries of clear columns beside the box, or with a clear column
 * that holds medium, the first check fails. */
static void clear_columns(void)
{
    const char *fog = "{\"camera\": {\"position\": [0, 1, 6], \"target\": [0, 0, 0], \"fov\": 50}, \"environment\": 0.5,"
                      "\"materials\": {\"m\": {\"type\": \"opaque\", \"diffuse\": [0.8, 0.5, 0.2]}},"
                      "\"objects\": [{\"shape\": {\"type\": \"sphere\", \"radius\": 0.5}, \"material\": \"m\","
                      "\"transform\": {\"translate\": [1.5, 0, 0]}},"
                      "{\"shape\": {\"type\": \"plane\", \"size\": [6, 6]}, \"material\": \"m\","
                      "\"transform\": {\"translate\": [0, -1, -2]}}],"
                      "\"lights\": [{\"type\": \"directional\", \"direction\": [-0.3, -1, -0.2], \"irradiance\": 2}],"
                      "\"fog\": [{\"shape\": \"box\", \"size\": [1, 1.5, 1], \"center\": [-0.3, 0.2, 0], "
                      "\"sigma_a\": 0.1, \"sigma_s\": [0.9, 0.6, 0.3]}]}";
    nacre_scene *s = media_load(ctx, fog, NULL);
    if (!s)
        return;
    enum { W = 64, H = 48 };
    nacre_render_settings rs = media_settings(NACRE_METHOD_PHONG, NACRE_VOLUMETRICS_FROXEL, W, H);
    rs.volumetrics.froxel_width = 32;
    rs.volumetrics.froxel_height = 24;
    rs.volumetrics.froxel_slices = 32;
    nacre_render_settings rt = rs, off = rs;
    rt.volumetrics.temporal = 0.5f;
    off.volumetrics.mode = NACRE_VOLUMETRICS_OFF;
    nacre_image skip = {0}, full = {0}, base = {0};
    nacre_renderer *r = NULL, *t = NULL, *b = NULL;
    CHECK(nacre_renderer_create(ctx, &r) == NACRE_OK && nacre_renderer_create(ctx, &t) == NACRE_OK &&
          nacre_renderer_create(ctx, &b) == NACRE_OK);
    bool ok = r && t && b && nacre_renderer_render(r, s, &rs, &skip, NULL) == NACRE_OK &&
              nacre_renderer_render(t, s, &rt, &full, NULL) == NACRE_OK;
    /* The image without fog: the same scene, its fog removed. */
    nacre_fog_desc fd;
    ok = ok && nacre_scene_get_fog(s, (nacre_fog){1}, &fd) == NACRE_OK;
    nacre_fog_desc none = fd;
    memset(none.sigma_a, 0, sizeof(none.sigma_a));
    memset(none.sigma_s, 0, sizeof(none.sigma_s));
    ok = ok && nacre_scene_set_fog(s, (nacre_fog){1}, &none) == NACRE_OK && nacre_scene_commit(s, 0.0) == NACRE_OK &&
         nacre_renderer_render(b, s, &off, &base, NULL) == NACRE_OK;
    CHECK(ok);
    if (ok) {
        size_t n = (size_t)W * H * 3;
        CHECK(memcmp(skip.pixels, full.pixels, n * sizeof(float)) == 0);
        size_t kept = 0, changed = 0;
        for (size_t k = 0; k < n; k++) {
            kept += skip.pixels[k] == base.pixels[k];
            changed += skip.pixels[k] != base.pixels[k];
        }
        printf("  clear columns: %zu of %zu values as without fog, %zu changed by the box; equal to the frame "
               "that skips nothing: %s\n",
               kept, n, changed, memcmp(skip.pixels, full.pixels, n * sizeof(float)) == 0 ? "yes" : "no");
        /* The box covers 6% of the values (576 of 9216): the rest keep the fogless image. */
        CHECK(kept > n / 2);
        CHECK(changed > n / 25);
        /* Kept frames (the second builds the per-pixel L and T, the third applies them). */
        ok = nacre_scene_set_fog(s, (nacre_fog){1}, &fd) == NACRE_OK && nacre_scene_commit(s, 0.0) == NACRE_OK;
        CHECK(ok);
        if (ok) {
            reuse_check(r, s, &rs, "a box fog: an unchanged frame");
            reuse_check(r, s, &rs, "a box fog: a third unchanged frame");
        }
    }
    nacre_image_free(ctx, &skip);
    nacre_image_free(ctx, &full);
    nacre_image_free(ctx, &base);
    nacre_renderer_destroy(r);
    nacre_renderer_destroy(t);
    nacre_renderer_destroy(b);
    nacre_scene_destroy(s);
}

/* The scene of json and the fog field of its first `count` fogs (0: all) with shadow_steps
 * steps; NULL (f not set) if the scene does not load. */
static nacre_scene *load_field(const char *json, uint32_t count, uint32_t steps, nc_fog_field *f)
{
    nacre_scene *s = media_load(ctx, json, NULL);
    if (s)
        nc_fog_field_init(f, s, count ? count : s->fog_count, steps);
    return s;
}

/* Transmittance towards lights from the fog field: in [0, 1], and the closed form for a
 * homogeneous box and for height fog (against the march through the same fog as a pattern). */
static void field_transmittance(void)
{
    const char *json = "{\"materials\": {\"m\": {\"type\": \"opaque\"}},"
                       "\"objects\": [{\"shape\": {\"type\": \"sphere\"}, \"material\": \"m\"}],"
                       "\"fog\": [{\"shape\": \"box\", \"size\": [4, 2, 4], \"sigma_a\": 0.1, \"sigma_s\": [0.5, 1, 2],"
                       "\"height_falloff\": 0.7, \"height_base\": -1},"
                       "{\"shape\": \"global\", \"sigma_s\": 0.01, \"height_falloff\": 2}]}";
    nc_fog_field f;
    nacre_scene *s = load_field(json, 0, 8, &f);
    if (!s)
        return;
    float scratch[NC_FOG_TAU_SCRATCH(8)];
    bool in_range = true;
    for (int i = 0; i < 200; i++) {
        float p[3] = {(float)(i % 7) - 3.0f, (float)(i % 5) * 0.6f - 1.5f, (float)(i % 3) - 1.0f};
        float a = (float)i * 0.37f, b = (float)i * 0.11f;
        float w[3] = {cosf(a) * sinf(b), cosf(b), sinf(a) * sinf(b)};
        double tau[3];
        nc_fog_field_optical_depth(&f, p, w, i % 2 ? INFINITY : 3.0f, NC_FOG_ALL, tau, scratch);
        for (int c = 0; c < 3; c++) {
            double T = exp(-tau[c]);
            in_range = in_range && tau[c] >= 0 && T >= 0 && T <= 1;
        }
    }
    CHECK(in_range);
    /* Straight up from (0, -1, 0) to the box top at y = 1: sigma_t integral e^(-0.7 (y + 1)) dy
     * + the global fog's 0.01 integral_-1^inf e^(-2 y) dy. */
    float p[3] = {0, -1, 0}, up[3] = {0, 1, 0};
    double tau[3];
    nc_fog_field_optical_depth(&f, p, up, INFINITY, NC_FOG_ALL, tau, scratch);
    const double ss[3] = {0.5, 1, 2};
    for (int c = 0; c < 3; c++) {
        double expect = (0.1 + ss[c]) * (1 - exp(-1.4)) / 0.7 + 0.01 * exp(2.0) / 2;
        CHECK_NEAR(tau[c], expect, 1e-5 * expect);
    }
    nacre_scene_destroy(s);
}

/* Largest |T_grid - T_march| (T = e^-tau, any channel) of light volume v over points on a
 * lattice around its (rotated) box, its margin included, and (rms) its root mean square; ref:
 * the march's field, towards the light along dir (directional) or to pos. */
static double light_volume_error(const nc_fog_field *ref, const nc_light_volume *v, const float dir[3],
                                 const float pos[3], float *scratch, double *rms)
{
    double worst = 0, sum2 = 0;
    int count = 0;
    for (int i = 0; i < 11; i++)
        for (int j = 0; j < 9; j++)
            for (int k = 0; k < 10; k++) {
                float x[3] = {-3.1f + 0.62f * i, -1.4f + 0.35f * j, -2.35f + 0.52f * k}, w[3];
                float dist = INFINITY;
                if (v->directional) {
                    for (int c = 0; c < 3; c++)
                        w[c] = -dir[c];
                } else {
                    for (int c = 0; c < 3; c++)
                        w[c] = pos[c] - x[c];
                    dist = sqrtf(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
                    for (int c = 0; c < 3; c++)
                        w[c] /= dist;
                }
                double tr[3] = {0, 0, 0};
                nc_fog_one_optical_depth(ref, &ref->fogs[0], x, w, dist, tr, scratch);
                float tv[3];
                nc_light_volume_lookup(v, x, tv);
                for (int c = 0; c < 3; c++) {
                    double e = fabs(exp(-(double)tv[c]) - exp(-tr[c]));
                    worst = fmax(worst, e);
                    sum2 += e * e;
                    count++;
                }
            }
    *rms = sqrt(sum2 / count);
    return worst;
}

/* nc_light_volume_reach8 on v: at points of a lattice around the box and at points just inside
 * and outside the edges of the box's shadow (along rays from the light past each corner of the
 * box, nudged by 1e-3 .. 1e-6 of a unit), every point it excludes has lookups 0 (scalar and 8
 * lanes, every channel; *sound); *culled of *total lattice points are excluded. */
static void reach_check(const nc_light_volume *v, const nc_fog_one *o, const float dir[3], const float pos[3],
                        bool *sound, int *culled, int *total)
{
    enum { MAXP = 11 * 9 * 10 + 8 * 6 * 8 * 6 };
    static float P[3][MAXP + 8];
    int n = 0;
    for (int i = 0; i < 11; i++)
        for (int j = 0; j < 9; j++)
            for (int k = 0; k < 10; k++, n++) {
                P[0][n] = -4.1f + 0.82f * i;
                P[1][n] = -3.4f + 0.85f * j;
                P[2][n] = -3.85f + 0.85f * k;
            }
    int lattice = n;
    const float nudge[6] = {1e-3f, -1e-3f, 1e-5f, -1e-5f, 1e-6f, -1e-6f};
    for (int c = 0; c < 8; c++) {
        /* the corner in the world (w2l is a rotation and a translation) */
        float q[3] = {c & 1 ? o->half[0] : -o->half[0], c & 2 ? o->half[1] : -o->half[1],
                      c & 4 ? o->half[2] : -o->half[2]},
              b[3];
        for (int a = 0; a < 3; a++)
            b[a] = o->w2l[0][a] * (q[0] - o->w2l[0][3]) + o->w2l[1][a] * (q[1] - o->w2l[1][3]) +
                   o->w2l[2][a] * (q[2] - o->w2l[2][3]);
        const float far[6] = {0.0f, 0.01f, 0.5f, 1.0f, 3.0f, 10.0f};
        for (int e = 0; e < 6; e++)
            for (int a = 0; a < 8; a++)
                for (int f = 0; f < 6; f++, n++) {
                    float bb[3] = {b[0] + (a & 1 ? nudge[e] : -nudge[e]), b[1] + (a & 2 ? nudge[e] : -nudge[e]),
                                   b[2] + (a & 4 ? nudge[e] : -nudge[e])};
                    for (int m = 0; m < 3; m++)
                        P[m][n] = v->directional ? bb[m] + far[f] * dir[m] : bb[m] + far[f] * (bb[m] - pos[m]);
                }
    }
    for (int m = 0; m < 3; m++)
        for (int k = n; k < MAXP + 8; k++)
            P[m][k] = P[m][n - 1];
    *culled = 0;
    *total = lattice;
    for (int b = 0; b < n; b += 8) {
        float t8[24];
        uint32_t bits = nc_light_volume_reach8(v, P[0] + b, P[1] + b, P[2] + b);
        nc_light_volume_lookup8(v, P[0] + b, P[1] + b, P[2] + b, t8);
        for (int l = 0; l < 8 && b + l < n; l++) {
            if (bits >> l & 1)
                continue;
            float x[3] = {P[0][b + l], P[1][b + l], P[2][b + l]}, t1[3];
            nc_light_volume_lookup(v, x, t1);
            for (int c = 0; c < 3; c++)
                *sound = *sound && t1[c] == 0.0f && t8[8 * c + l] == 0.0f;
            *culled += b + l < lattice;
        }
    }
}

/* The optical-depth grids towards a light through a bounded patterned fog (light_volume.h)
 * against a direct march from each point: a sun's light-aligned grid against a march of 256
 * steps, a point light's grid (nodes marched with the renderer's 8 steps) against the same
 * 8-step march, for a point light outside the box and one inside it. The largest differences
 * are next to the box's walls that lie nearly along the light (the optical depth jumps there
 * within a node's spacing); at 4 nodes an axis the same checks fail. */
static void light_volume(void)
{
    const char *json = "{\"materials\": {\"m\": {\"type\": \"opaque\"}},"
                       "\"objects\": [{\"shape\": {\"type\": \"sphere\"}, \"material\": \"m\"}],"
                       "\"fog\": [{\"shape\": \"box\", \"center\": [0.2, 0.1, -0.1], \"size\": [4, 2, 3],"
                       "\"rotate\": [10, 35, 0], \"sigma_a\": 0.1, \"sigma_s\": [0.4, 0.8, 1.2],"
                       "\"height_falloff\": 0.5, \"pattern\": {\"type\": \"noise\", \"cell_size\": 0.5,"
                       "\"sigma_a2\": 0, \"sigma_s2\": 0}}]}";
    nc_fog_field f8, f256;
    nacre_scene *s = load_field(json, 1, 8, &f8);
    if (!s)
        return;
    nc_fog_field_init(&f256, s, 1, 256);
    static float scratch[NC_FOG_TAU_SCRATCH(256)];
    float dir[3] = {0.3f, -1.0f, 0.2f}, out[3] = {1.5f, 2.5f, 0.5f}, in[3] = {0.3f, 0.0f, 0.1f};
    float l = sqrtf(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
    for (int c = 0; c < 3; c++)
        dir[c] /= l;
    const double tol_max[3] = {0.1, 0.03, 0.03};
    const double tol_rms[3] = {0.008, 0.006, 0.006};
    const char *what[3] = {"sun (64^3, vs 256 steps)", "point light outside (24^3)", "point light inside (24^3)"};
    for (int q = 0; q < 3; q++) {
        for (int coarse = 0; coarse < 2; coarse++) {
            nc_light_volume v;
            uint32_t res = coarse ? 4u : q == 0 ? NC_LIGHT_VOLUME_DIR_RES : NC_LIGHT_VOLUME_POINT_RES;
            const float *pos = q == 1 ? out : in;
            nc_light_volume_setup(&v, &f8.fogs[0], q == 0, dir, pos, res);
            v.tau = malloc(3 * nc_light_volume_nodes(&v) * sizeof(float));
            CHECK(v.tau != NULL);
            if (!v.tau)
                break;
            nc_light_volume_build(&f8, &v, 2);
            /* The 8-lane lookup equals the scalar one bit for bit, inside, beside and beyond. */
            bool same = true;
            for (int b = 0; b < 64; b++) {
                float X[8], Y[8], Z[8], t8[24];
                for (int q8 = 0; q8 < 8; q8++) {
                    int m = 8 * b + q8;
                    X[q8] = -3.0f + 6.0f * (float)((m * 37) % 101) / 100.0f;
                    Y[q8] = -2.5f + 5.0f * (float)((m * 53) % 97) / 96.0f;
                    Z[q8] = -3.0f + 6.0f * (float)((m * 71) % 89) / 88.0f;
                }
                nc_light_volume_lookup8(&v, X, Y, Z, t8);
                for (int q8 = 0; q8 < 8; q8++) {
                    float x[3] = {X[q8], Y[q8], Z[q8]}, t1[3];
                    nc_light_volume_lookup(&v, x, t1);
                    for (int c = 0; c < 3; c++)
                        same = same && memcmp(&t1[c], &t8[8 * c + q8], sizeof(float)) == 0;
                }
            }
            CHECK(same);
            double rms, e = light_volume_error(q == 0 ? &f256 : &f8, &v, dir, pos, scratch, &rms);
            printf("  light volume, %s%s: |dT| largest %.4f, RMS %.4f (tolerances %.3f, %.4f)\n", what[q],
                   coarse ? ", 4 nodes an axis" : "", e, rms, tol_max[q], tol_rms[q]);
            CHECK(coarse ? e > tol_max[q] && rms > tol_rms[q] : e < tol_max[q] && rms < tol_rms[q]);
            /* Where the lookups may be other than 0: never a point whose lookup is not 0, and
             * away from the grid's shadow (none for the light inside the box) most points. */
            bool sound = true;
            int culled, total;
            reach_check(&v, &f8.fogs[0], dir, pos, &sound, &culled, &total);
            printf("  light volume, %s%s: %d of %d lattice points outside its reach\n", what[q],
                   coarse ? ", 4 nodes an axis" : "", culled, total);
            CHECK(sound);
            CHECK(q == 2 ? culled == 0 : culled > total / 4);
            free(v.tau);
        }
    }
    nacre_scene_destroy(s);
}

/* Gray fogs' grids (light_volume.h): one channel stored, copied to the others. Which fogs are
 * gray (equal coefficients in every channel, medium 2's too where the pattern uses it); a gray
 * fog's grids, for a sun and for point lights outside and inside it, equal the three-channel
 * grids of the same fog bit for bit in every channel, by both lookups, at points inside, beside
 * and beyond the box (a gray grid read with the wrong stride or channel fails). */
static void light_volume_gray(void)
{
    const char *json = "{\"materials\": {\"m\": {\"type\": \"opaque\"}},"
                       "\"objects\": [{\"shape\": {\"type\": \"sphere\"}, \"material\": \"m\"}],"
                       "\"fog\": [{\"shape\": \"box\", \"center\": [0.2, 0.1, -0.1], \"size\": [4, 2, 3],"
                       "\"rotate\": [10, 35, 0], \"sigma_a\": 0.1, \"sigma_s\": 0.9, \"height_falloff\": 0.5,"
                       "\"pattern\": {\"type\": \"noise\", \"cell_size\": 0.5, \"sigma_a2\": 0, \"sigma_s2\": 0}},"
                       "{\"shape\": \"box\", \"size\": [1, 1, 1], \"sigma_s\": [0.4, 0.8, 1.2],"
                       "\"pattern\": {\"type\": \"noise\", \"cell_size\": 0.5, \"sigma_a2\": 0, \"sigma_s2\": 0}},"
                       "{\"shape\": \"box\", \"size\": [1, 1, 1], \"sigma_s\": 0.5,"
                       "\"pattern\": {\"type\": \"checker\", \"cell_size\": 0.5, \"sigma_a2\": 0,"
                       "\"sigma_s2\": [0.1, 0.2, 0.3]}},"
                       "{\"shape\": \"sphere\", \"size\": [1, 1, 1], \"sigma_a\": [0.1, 0.1, 0.2], \"sigma_s\": 0.5}]}";
    nc_fog_field f;
    nacre_scene *s = load_field(json, 4, 8, &f);
    if (!s)
        return;
    CHECK(nc_light_volume_fog_gray(&f.fogs[0]));
    CHECK(!nc_light_volume_fog_gray(&f.fogs[1]));
    CHECK(!nc_light_volume_fog_gray(&f.fogs[2]));
    CHECK(!nc_light_volume_fog_gray(&f.fogs[3]));
    float dir[3] = {0.3f, -1.0f, 0.2f}, out[3] = {1.5f, 2.5f, 0.5f}, in[3] = {0.3f, 0.0f, 0.1f};
    float l = sqrtf(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
    for (int c = 0; c < 3; c++)
        dir[c] /= l;
    for (int q = 0; q < 3; q++) {
        const float *pos = q == 1 ? out : in;
        uint32_t res = q == 0 ? 16u : 12u;
        nc_light_volume gray, rgb;
        nc_light_volume_setup(&gray, &f.fogs[0], q == 0, dir, pos, res);
        nc_light_volume_setup(&rgb, &f.fogs[0], q == 0, dir, pos, res);
        CHECK(gray.gray);
        rgb.gray = false;
        CHECK(nc_light_volume_floats(&gray) == nc_light_volume_nodes(&gray) &&
              nc_light_volume_floats(&rgb) == 3 * nc_light_volume_nodes(&rgb));
        gray.tau = malloc(nc_light_volume_floats(&gray) * sizeof(float));
        rgb.tau = malloc(nc_light_volume_floats(&rgb) * sizeof(float));
        CHECK(gray.tau && rgb.tau);
        if (gray.tau && rgb.tau) {
            nc_light_volume_build(&f, &gray, 2);
            nc_light_volume_build(&f, &rgb, 2);
            bool same = true, shaded = false;
            for (int b = 0; b < 64; b++) {
                float X[8], Y[8], Z[8], t8[24], r8[24];
                for (int q8 = 0; q8 < 8; q8++) {
                    int m = 8 * b + q8;
                    X[q8] = -3.0f + 6.0f * (float)((m * 37) % 101) / 100.0f;
                    Y[q8] = -2.5f + 5.0f * (float)((m * 53) % 97) / 96.0f;
                    Z[q8] = -3.0f + 6.0f * (float)((m * 71) % 89) / 88.0f;
                }
                nc_light_volume_lookup8(&gray, X, Y, Z, t8);
                nc_light_volume_lookup8(&rgb, X, Y, Z, r8);
                same = same && memcmp(t8, r8, sizeof(t8)) == 0;
                for (int q8 = 0; q8 < 8; q8++) {
                    float x[3] = {X[q8], Y[q8], Z[q8]}, t1[3], r1[3];
                    nc_light_volume_lookup(&gray, x, t1);
                    nc_light_volume_lookup(&rgb, x, r1);
                    same = same && memcmp(t1, r1, sizeof(t1)) == 0;
                    shaded = shaded || r1[0] > 0.1f;
                }
            }
            CHECK(same && shaded);
        }
        free(gray.tau);
        free(rgb.tau);
    }
    nacre_scene_destroy(s);
}

/* volume.h's fast exponential against exp over its range. */
static void fast_exp(void)
{
    double worst = 0;
    for (double x = -86.99; x <= 88.0; x += 1e-3) {
        double e = exp((double)(float)x);
        worst = fmax(worst, fabs(nc_vol_exp_fast((float)x) - e) / e);
    }
    printf("  nc_vol_exp_fast: largest relative error %.2e\n", worst);
    CHECK(worst < 1e-7);
    CHECK(nc_vol_exp_fast(-INFINITY) == 0.0f && nc_vol_exp_fast(-90.0f) == 0.0f && nc_vol_exp_fast(0.0f) == 1.0f);
    double r = 0;
    for (double x = 0; x < 30; x += 1e-3)
        r = fmax(r, fabs(nc_vol_exp_ratio_fast((float)x) - nc_vol_exp_ratio((float)x)) / nc_vol_exp_ratio((float)x));
    printf("  nc_vol_exp_ratio_fast: largest relative error %.2e\n", r);
    CHECK(r < 2e-6);
    /* The froxels' transmittance: e^-tau over [0, 87.3] 8 at a time, and e^-87.3 (never
     * 0, never more) beyond. */
    double tw = 0;
    for (double t0 = 0; t0 + 8e-3 <= 87.3; t0 += 8e-3) {
        nc_v8f tau, e;
        for (int l = 0; l < 8; l++)
            tau[l] = (float)(t0 + l * 1e-3);
        e = nc_vol_transmittance8(tau);
        for (int l = 0; l < 8; l++) {
            double x = exp(-(double)tau[l]);
            tw = fmax(tw, fabs(e[l] - x) / x);
        }
    }
    printf("  nc_vol_transmittance8: largest relative error %.2e\n", tw);
    CHECK(tw < 1e-7);
    nc_v8f far = {87.3f, 88.0f, 100.0f, 1e30f, INFINITY, 0.0f, 1e-30f, 80.0f}, ef = nc_vol_transmittance8(far);
    for (int l = 0; l < 5; l++)
        CHECK(ef[l] > 0.0f && ef[l] <= 1.3e-38f);
    CHECK(ef[5] == 1.0f && ef[6] == 1.0f && fabs(ef[7] / exp(-80.0) - 1) < 1e-7);
    /* nc_v8_rsqrt and nc_v8_rcp: relative 2^-21 over many octaves */
    double rs = 0, rc = 0;
    for (double x = 1e-20; x < 1e20; x *= 1.37) {
        nc_v8f v, a, b;
        for (int l = 0; l < 8; l++)
            v[l] = (float)(x * (1 + 0.11 * l));
        a = nc_v8_rsqrt(v);
        b = nc_v8_rcp(v);
        for (int l = 0; l < 8; l++) {
            rs = fmax(rs, fabs(a[l] * sqrt((double)v[l]) - 1));
            rc = fmax(rc, fabs(b[l] * (double)v[l] - 1));
        }
    }
    printf("  nc_v8_rsqrt, nc_v8_rcp: largest relative errors %.2e, %.2e\n", rs, rc);
    CHECK(rs < 5e-7 && rc < 5e-7);
}

/* ---- a global height fog, lit ------------------------------------------------------------- */

/* SUN_SCENE's camera (64 slices or steps of 1/8 from depth 1 to 9; the sphere behind the camera
 * leaves every pixel to the background) in a global fog thinning upwards. */
#define HEIGHT_FOG_CAMERA                                                                           \
    "{\"camera\": {\"type\": \"orthographic\", \"position\": [0, 0, 5], \"target\": [0, 0, 0], "    \
    "\"height\": 4, \"near\": 1, \"far\": 9}, \"environment\": 0,"                                  \
    "\"materials\": {\"black\": {\"type\": \"opaque\", \"diffuse\": 0, \"specular\": 0}},"          \
    "\"fog\": [{\"shape\": \"global\", \"sigma_a\": 0.05, \"sigma_s\": [0.4, 0.25, 0.1], \"g\": 0.3,"  \
    "\"height_falloff\": 0.6, \"height_base\": -1}],"

#define HEIGHT_FOG_LIGHTS(slab_x)                                                                        \
    HEIGHT_FOG_CAMERA                                                                               \
    "\"objects\": [{\"shape\": {\"type\": \"sphere\", \"radius\": 0.1}, \"material\": \"black\","   \
    "\"transform\": {\"translate\": [0, 0, 20]}, \"shadows\": false},"                              \
    "{\"shape\": {\"type\": \"box\", \"size\": [1.2, 0.1, 1]}, \"material\": \"black\","              \
    "\"transform\": {\"translate\": [" slab_x ", 2.6, 0]}}],"                                         \
    "\"lights\": [{\"type\": \"directional\", \"direction\": [0.3, -1, 0.2], \"irradiance\": 2},"       \
    "{\"type\": \"point\", \"position\": [1, 1.5, 0.3], \"intensity\": 3},"                            \
    "{\"type\": \"point\", \"position\": [-1.5, -3, 2], \"intensity\": 20},"                          \
    "{\"type\": \"spot\", \"position\": [-1, 3, 1], \"direction\": [0.2, -1, -0.3], \"intensity\": 15,"  \
    "\"outer_angle\": 40, \"inner_angle\": 25}]}"

#define HEIGHT_FOG_SUN                                                                              \
    HEIGHT_FOG_CAMERA                                                                               \
    "\"objects\": [{\"shape\": {\"type\": \"sphere\", \"radius\": 0.1}, \"material\": \"black\","   \
    "\"transform\": {\"translate\": [0, 0, 20]}, \"shadows\": false}],"                             \
    "\"lights\": [{\"type\": \"directional\", \"direction\": [0, -1, 0], \"irradiance\": 2, "          \
    "\"angular_radius\": 0}]}"

/* Along a level ray at height y through the fog under a sun from straight above, to infinity:
 * sigma_s(y) p(90) E e^(-tau_up(y)) / sigma_t(y), tau_up = sigma_t(y) / falloff. */
static double height_sun_exact(double y, int c)
{
    const double g = 0.3, ss[3] = {0.4, 0.25, 0.1}, k = 0.6, base = -1;
    double p90 = (1 - g * g) / (4 * PI * pow(1 + g * g, 1.5)), f = exp(-k * (y - base));
    double st = (0.05 + ss[c]) * f;
    return ss[c] * f * p90 * 2 * exp(-st / k) / st;
}

static void height_fog_lights(void)
{
    const int W = 16, H = 16;
    nacre_image img[2] = {{0}, {0}};
    for (int k = 0; k < 2; k++) {
        nacre_render_settings rs =
            media_settings(NACRE_METHOD_PHONG, k ? NACRE_VOLUMETRICS_RAYMARCH : NACRE_VOLUMETRICS_FROXEL, W, H);
        rs.volumetrics.froxel_width = W; /* a column per pixel, through its centre */
        rs.volumetrics.froxel_height = H;
        if (!media_render(ctx, HEIGHT_FOG_LIGHTS("0.3"), &rs, &img[k], NULL))
            goto out;
    }
    double worst = 0, top = 0;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++)
            for (int c = 0; c < 3; c++)
                top = fmax(top, media_px(&img[1], x, y, c));
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++)
            for (int c = 0; c < 3; c++) {
                double r = media_px(&img[1], x, y, c), err = fabs(media_px(&img[0], x, y, c) - r) / fmax(r, 1e-3 * top);
                worst = fmax(worst, err);
            }
    printf("  height fog, sun + 2 points + spot: froxel vs march largest relative difference %.2e\n", worst);
    CHECK(worst < 1e-3);
    /* The slab's shadow is in the image: moved out of the sun's way, the froxels change by far
     * more than that. */
    nacre_image_free(ctx, &img[1]);
    memset(&img[1], 0, sizeof(img[1]));
    nacre_render_settings rs = media_settings(NACRE_METHOD_PHONG, NACRE_VOLUMETRICS_FROXEL, W, H);
    rs.volumetrics.froxel_width = W;
    rs.volumetrics.froxel_height = H;
    if (!media_render(ctx, HEIGHT_FOG_LIGHTS("30"), &rs, &img[1], NULL))
        goto out;
    double shaft = 0;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++)
            shaft = fmax(shaft, 1 - media_px(&img[0], x, y, 1) / media_px(&img[1], x, y, 1));
    printf("  the slab's shaft: darker by up to %.3f\n", shaft);
    CHECK(shaft > 0.01);
    nacre_image_free(ctx, &img[0]);
    nacre_image_free(ctx, &img[1]);
    memset(img, 0, sizeof(img));

    if (!media_render(ctx, HEIGHT_FOG_SUN, &rs, &img[0], NULL))
        goto out;
    worst = 0;
    for (int y = 0; y < H; y++)
        for (int c = 0; c < 3; c++) {
            double e = height_sun_exact(2 - (y + 0.5) / 4, c);
            worst = fmax(worst, fabs(media_px(&img[0], W / 2, y, c) - e) / e);
        }
    printf("  height fog under a sun: largest relative error froxel %.4f\n", worst);
    CHECK(worst < 0.02);
out:
    nacre_image_free(ctx, &img[0]);
    nacre_image_free(ctx, &img[1]);
}

/* ---- volumetric shadows ------------------------------------------------------------------- */

/* A spot light straight down into a box of fog; a thin black slab beside its axis (x in
 * [0.1, 0.7], |z| < 0.25) casts a shaft into the cone below it. The camera looks at it from the
 * side, so the rays through the shaft also cross lit fog in front of and behind it. */
#define SHAFT_SCENE                                                                                 \
    "{\"camera\": {\"position\": [0, 0, 7], \"target\": [0, 0, 0], \"fov\": 45}, \"environment\": 0," \
    "\"materials\": {\"black\": {\"type\": \"opaque\", \"diffuse\": 0, \"specular\": 0}},"          \
    "\"objects\": [{\"shape\": {\"type\": \"box\", \"size\": [0.6, 0.05, 0.5]}, \"material\": \"black\"," \
    "\"transform\": {\"translate\": [0.4, 1.2, 0]}}],"                                             \
    "\"lights\": [{\"type\": \"spot\", \"position\": [0, 2, 0], \"direction\": [0, -1, 0],"         \
    "\"intensity\": 30, \"outer_angle\": 35, \"inner_angle\": 30}],"                                \
    "\"fog\": [{\"shape\": \"box\", \"size\": [5, 5, 5], \"sigma_a\": 0.05, \"sigma_s\": 0.25, \"g\": 0.2}]}"

/* Shaft and lit regions (pixel boxes on a 64 x 48 image): below the slab on the right (x > 0)
 * and their mirror image on the left. */
static void shaft_regions(const nacre_image *img, const nacre_image *var, double *shaft, double *lit, double *se)
{
    double m[3], s[3], m2[3], s2[3];
    media_region(img, var, 35, 42, 24, 36, m, s);
    media_region(img, var, 22, 29, 24, 36, m2, s2);
    *shaft = m[1];
    *lit = m2[1];
    *se = var ? sqrt(s[1] * s[1] + s2[1] * s2[1]) : 0;
}

static void volumetric_shadow(void)
{
    const int W = 64, H = 48;
    nacre_image fx = {0}, rm = {0}, ref = {0}, var = {0};
    nacre_render_settings rs = media_settings(NACRE_METHOD_PHONG, NACRE_VOLUMETRICS_FROXEL, W, H);
    bool ok = media_render(ctx, SHAFT_SCENE, &rs, &fx, NULL);
    rs.volumetrics.mode = NACRE_VOLUMETRICS_RAYMARCH;
    ok = ok && media_render(ctx, SHAFT_SCENE, &rs, &rm, NULL);
    rs = media_settings(NACRE_METHOD_PATHTRACE, NACRE_VOLUMETRICS_OFF, W, H);
    rs.pathtrace.spp = 512;
    rs.pathtrace.seed = 5;
    rs.pathtrace.max_scatter = 1;
    ok = ok && media_render(ctx, SHAFT_SCENE, &rs, &ref, &var);
    if (ok) {
        double s_pt, l_pt, se, s_fx, l_fx, s_rm, l_rm, dummy;
        shaft_regions(&ref, &var, &s_pt, &l_pt, &se);
        shaft_regions(&fx, NULL, &s_fx, &l_fx, &dummy);
        shaft_regions(&rm, NULL, &s_rm, &l_rm, &dummy);
        double c_pt = 1 - s_pt / l_pt, c_fx = 1 - s_fx / l_fx, c_rm = 1 - s_rm / l_rm;
        printf("  shaft: path tracer shaft %.5f lit %.5f (se %.5f) contrast %.4f; froxel %.5f %.5f contrast %.4f; "
               "raymarch %.5f %.5f contrast %.4f\n",
               s_pt, l_pt, se, c_pt, s_fx, l_fx, c_fx, s_rm, l_rm, c_rm);
        CHECK(c_pt > 0.2 && c_pt < 0.9); /* a shaft, seen through lit fog */
        CHECK_NEAR(c_fx, c_pt, 0.05 * c_pt);
        CHECK_NEAR(c_rm, c_pt, 0.05 * c_pt);
        /* The lit fog itself: the path tracer's noise plus 3%. */
        CHECK_NEAR(l_fx, l_pt, 4 * se + 0.03 * l_pt);
        CHECK_NEAR(l_rm, l_pt, 4 * se + 0.03 * l_pt);
    }
    nacre_image_free(ctx, &fx);
    nacre_image_free(ctx, &rm);
    nacre_image_free(ctx, &ref);
    nacre_image_free(ctx, &var);
}

/* ---- settings ---------------------------------------------------------------------------- */

static void bad_settings(void)
{
    nacre_scene *s = media_load(ctx, AMBIENT_SCENE, NULL);
    if (!s)
        return;
    nacre_renderer *r = NULL;
    CHECK(nacre_renderer_create(ctx, &r) == NACRE_OK);
    const char *fields[] = {"froxel_slices", "froxel_slices", "froxel_width", "raymarch_steps", "shadow_steps",
                            "froxel_temporal", "froxel_temporal", "volumetrics"};
    for (int k = 0; k < 8; k++) {
        nacre_render_settings rs = media_settings(NACRE_METHOD_PHONG, NACRE_VOLUMETRICS_FROXEL, 16, 16);
        switch (k) {
        case 0: rs.volumetrics.froxel_slices = 0; break;
        case 1: rs.volumetrics.froxel_slices = 100000; break;
        case 2: rs.volumetrics.froxel_width = 0; break;
        case 3: rs.volumetrics.raymarch_steps = 0; break;
        case 4: rs.volumetrics.shadow_steps = 1000; break;
        case 5: rs.volumetrics.temporal = 1.0f; break;
        case 6: rs.volumetrics.temporal = NAN; break;
        default: rs.volumetrics.mode = (nacre_volumetrics_mode)7; break;
        }
        nacre_image img = {0};
        CHECK(nacre_renderer_render(r, s, &rs, &img, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
        CHECK(img.pixels == NULL);
        CHECK(strstr(nacre_context_last_error(ctx), fields[k]) != NULL);
    }
    nacre_renderer_destroy(r);
    nacre_scene_destroy(s);

    /* Scene-file keys: read, range-checked, saved and read back. */
    const char *json = "{\"render\": {\"volumetrics\": \"raymarch\", \"froxel_width\": 80, \"froxel_height\": 45,"
                       "\"froxel_slices\": 32, \"raymarch_steps\": 100, \"shadow_steps\": 4, \"froxel_temporal\": 0.85}}";
    nacre_scene_file_settings fs;
    s = NULL;
    CHECK(nacre_scene_load_json(ctx, json, strlen(json), "v.json", ".", &s, &fs) == NACRE_OK);
    const nacre_volumetrics_settings *v = &fs.render.volumetrics;
    CHECK(v->mode == NACRE_VOLUMETRICS_RAYMARCH && v->froxel_width == 80 && v->froxel_height == 45 &&
          v->froxel_slices == 32 && v->raymarch_steps == 100 && v->shadow_steps == 4 && v->temporal == 0.85f);
    char *text = NULL;
    if (s && nacre_scene_save_json(s, &fs, NULL, &text, NULL) == NACRE_OK) {
        nacre_scene *s2 = NULL;
        nacre_scene_file_settings fs2;
        CHECK(nacre_scene_load_json(ctx, text, strlen(text), "v2.json", ".", &s2, &fs2) == NACRE_OK);
        CHECK(memcmp(&fs2.render.volumetrics, v, sizeof(*v)) == 0);
        nacre_scene_destroy(s2);
        nacre_free(ctx, text);
    } else {
        CHECK(false);
    }
    nacre_scene_destroy(s);
    const char *bad[] = {"{\"render\": {\"volumetrics\": \"voxels\"}}", "{\"render\": {\"froxel_slices\": 0}}",
                         "{\"render\": {\"froxel_slices\": 100000}}", "{\"render\": {\"froxel_temporal\": 1}}",
                         "{\"render\": {\"froxel_temporal\": -0.1}}"};
    const char *named[] = {"render.volumetrics", "render.froxel_slices", "render.froxel_slices",
                           "render.froxel_temporal", "render.froxel_temporal"};
    for (int k = 0; k < 5; k++) {
        s = NULL;
        CHECK(nacre_scene_load_json(ctx, bad[k], strlen(bad[k]), "v.json", ".", &s, &fs) ==
              NACRE_ERROR_INVALID_ARGUMENT);
        CHECK(strstr(nacre_context_last_error(ctx), named[k]) != NULL);
        nacre_scene_destroy(s);
    }
}

int main(void)
{
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    field_transmittance();
    light_volume();
    light_volume_gray();
    fast_exp();
    bad_settings();
    constant_source();
    thread_count();
    box_fogs();
    frame_reuse();
    clear_columns();
    sun_closed_form();
    height_fog_lights();
    volumetric_shadow();
    temporal();
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
