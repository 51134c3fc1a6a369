/*
 * test_fog_pass.c: the shared volume core (src/volume/volume.h) and the distance / height fog
 * post pass (src/render/post_fog.c), against closed forms, quadrature and the path tracer:
 *   - height-fog optical depth against Simpson quadrature (relative 1e-5): oblique, exactly
 *     horizontal, exactly vertical (up and down) rays, huge and tiny falloffs, segments that
 *     cross the exponent cap, rays rising to infinity, and the divergent cases; its 8-lane
 *     float form (the fog pass's) against it in each case (relative 1e-5);
 *   - transmittance in [0, 1] (single segments and products of steps); the segment integral of
 *     in-scattering and emission against fine numerical integration, its sigma_t -> 0 limit and
 *     infinite segments; front-to-back marching independent of the number of steps;
 *   - the pass on phong frames: homogeneous global fog, one directional light, a black plane far
 *     away and a black background, against sigma_s / sigma_t p E (1 - e^(-sigma_t t)) per pixel
 *     (relative 1e-4); ambient light from the environment; c T + L over a lit surface (against
 *     the same scene rendered without fog); thread count; reuse_output; which methods run it;
 *   - the pass with every kind of fog at once (global height fog over rising, descending and
 *     surface rays, a box with a falloff, an emitting ellipsoid, a channel that emits without
 *     extinction) against the same formula evaluated per pixel in double (relative 1e-4);
 *   - the pass against the path tracer with max_scatter 1 (single scattering) on a thin slab of
 *     box fog lit by a delta sun, per band of rows (its noise plus 2%).
 */
#include "media_util.h"

#include "volume/volume.h"

#include <nacre/nacre.h>

static nacre_context *ctx;

static const double PI = 3.14159265358979323846;

/* ---- the core ----------------------------------------------------------------------------- */

static double height_density(const nc_vol_height *h, double y)
{
    double e = -h->falloff * (y - h->base);
    return exp(e < h->cap ? e : h->cap);
}

/* Simpson's rule over [t0, t1] with n (even) intervals, of the height factor along the ray. */
static double height_quadrature(const nc_vol_height *h, double y0, double dir_y, double t0, double t1, int n)
{
    double step = (t1 - t0) / n, sum = 0.0;
    for (int i = 0; i <= n; i++) {
        double w = (i == 0 || i == n) ? 1.0 : (i % 2) ? 4.0 : 2.0;
        sum += w * height_density(h, y0 + dir_y * (t0 + i * step));
    }
    return sum * step / 3.0;
}

/* nc_vol_height_integral8 (float, 8 lanes) with the same ray in every lane: lane 0, the others
 * checked equal to it. */
static double height8(const nc_vol_height *h, double y0, double dir_y, double t0, double t1)
{
    nc_vol_height8 hf = nc_vol_height8_make(h);
    const nc_v8f zero = {0};
    nc_v8f G = nc_vol_height_integral8(&hf, zero + (float)y0, zero + (float)dir_y, zero + (float)t0, zero + (float)t1);
    bool same = true;
    for (int l = 1; l < 8; l++)
        same = same && memcmp(&G[l], &G[0], sizeof(float)) == 0;
    CHECK(same);
    return G[0];
}

static void check_height(const char *what, nc_vol_height h, double y0, double dir_y, double t0, double t1)
{
    double exact = nc_vol_height_integral(&h, y0, dir_y, t0, t1);
    double quad = height_quadrature(&h, y0, dir_y, t0, t1, 400000);
    double rel = fabs(exact - quad) / fabs(quad);
    if (!(rel <= 1e-5))
        printf("  height integral %s: %.12g vs quadrature %.12g (rel %.3g)\n", what, exact, quad, rel);
    CHECK(rel <= 1e-5);
    /* The fog pass's float form: within 1e-5 of the double one. */
    double rel8 = fabs(height8(&h, y0, dir_y, t0, t1) - exact) / fabs(exact);
    if (!(rel8 <= 1e-5))
        printf("  height integral %s, 8 lanes in float: rel %.3g\n", what, rel8);
    CHECK(rel8 <= 1e-5);
}

static void height_integral(void)
{
    nc_vol_height h = {.falloff = 0.3, .base = 1.0, .cap = 60.0};
    double s = 1 / sqrt(2.0);
    check_height("oblique up", h, 0.5, s, 0.0, 12.0);
    check_height("oblique down", h, 4.0, -s, 1.0, 9.0);
    check_height("horizontal", h, 2.5, 0.0, 0.0, 30.0);
    check_height("horizontal below base", h, -3.0, 0.0, 2.0, 7.0);
    check_height("nearly horizontal", h, 2.5, 1e-9, 0.0, 30.0);
    check_height("nearly horizontal down", h, 2.5, -1e-13, 0.0, 30.0);
    check_height("vertical up", h, -1.0, 1.0, 0.0, 25.0);
    check_height("vertical down", h, 10.0, -1.0, 0.0, 12.0);
    /* Huge falloff: the density changes by e^-1 over a thousandth of a unit. */
    nc_vol_height steep = {.falloff = 1000.0, .base = 0.0, .cap = 60.0};
    check_height("huge falloff, vertical up", steep, 0.001, 1.0, 0.0, 0.05);
    check_height("huge falloff, oblique", steep, 0.002, 0.6, 0.0, 0.05);
    check_height("huge falloff, horizontal", steep, 0.003, 0.0, 0.0, 2.0);
    /* Tiny falloff: the closed form's (1 - e^(-k dh)) / (k dh) is 1 - 5e-6: the series. */
    nc_vol_height flat = {.falloff = 1e-6, .base = 0.0, .cap = 60.0};
    check_height("tiny falloff, oblique", flat, 3.0, 0.8, 0.0, 10.0);
    check_height("tiny falloff, vertical down", flat, 3.0, -1.0, 0.0, 10.0);
    check_height("tiny falloff, horizontal", flat, 3.0, 0.0, 0.0, 10.0);
    /* Through the cap: below y = base - 60 / k the density is e^60. */
    nc_vol_height capped = {.falloff = 2.0, .base = 0.0, .cap = 60.0};
    check_height("across the cap, down", capped, -25.0, -0.9, 0.0, 10.0);
    check_height("across the cap, up", capped, -40.0, 0.7, 0.0, 25.0);
    check_height("under the cap, horizontal", capped, -40.0, 0.0, 0.0, 3.0);
    nc_vol_height lowcap = {.falloff = 0.5, .base = 0.0, .cap = 3.0};
    check_height("low cap, vertical up", lowcap, -10.0, 1.0, 0.0, 20.0);
    /* No falloff: the constant factor e^min(cap, 0). */
    nc_vol_height none = {.falloff = 0.0, .base = 0.0, .cap = 0.0};
    CHECK_NEAR(nc_vol_height_integral(&none, 5.0, 0.3, 1.0, 4.0), 3.0, 1e-15);
    nc_vol_height dense = {.falloff = 0.0, .base = 0.0, .cap = -2.0};
    CHECK_NEAR(nc_vol_height_integral(&dense, 5.0, 0.3, 1.0, 4.0), 3.0 * exp(-2.0), 1e-15);
    /* To infinity: rising converges to the quadrature of a long stretch; level and falling
     * rays diverge. */
    double inf_up = nc_vol_height_integral(&h, 0.5, 0.6, 0.0, INFINITY);
    double long_up = height_quadrature(&h, 0.5, 0.6, 0.0, 200.0, 400000); /* e^-36 left */
    CHECK_NEAR(inf_up / long_up, 1.0, 1e-5);
    double inf_capped = nc_vol_height_integral(&capped, -50.0, 0.5, 0.0, INFINITY);
    double long_capped = height_quadrature(&capped, -50.0, 0.5, 0.0, 120.0, 400000);
    CHECK_NEAR(inf_capped / long_capped, 1.0, 1e-5);
    CHECK(isinf(nc_vol_height_integral(&h, 0.5, 0.0, 0.0, INFINITY)));
    CHECK(isinf(nc_vol_height_integral(&h, 0.5, -0.1, 0.0, INFINITY)));
    CHECK(isinf(nc_vol_height_integral(&none, 0.5, 0.6, 0.0, INFINITY)));
    CHECK(nc_vol_height_integral(&h, 0.5, 0.6, 3.0, 3.0) == 0.0);
    CHECK_NEAR(height8(&h, 0.5, 0.6, 0.0, INFINITY) / inf_up, 1.0, 1e-5);
    CHECK_NEAR(height8(&capped, -50.0, 0.5, 0.0, INFINITY) / inf_capped, 1.0, 1e-5);
    CHECK(isinf(height8(&h, 0.5, 0.0, 0.0, INFINITY)) && isinf(height8(&h, 0.5, -0.1, 0.0, INFINITY)) &&
          isinf(height8(&none, 0.5, 0.6, 0.0, INFINITY)));
    CHECK_NEAR(height8(&dense, 5.0, 0.3, 1.0, 4.0), 3.0 * exp(-2.0), 1e-6);
    /* The float factor the path tracer tracks agrees with the double profile. */
    CHECK_NEAR(nc_vol_height_factor(true, 0.3f, 1.0f, 60.0f, 4.0f), height_density(&h, 4.0), 1e-6);
    CHECK(nc_vol_height_exp_cap(true, 1e-20f) == 60.0f);
    CHECK_NEAR(nc_vol_height_exp_cap(true, 1.0f), log(1e12), 1e-5); /* the density cap */
    CHECK(nc_vol_height_exp_cap(false, 1.0f) == 0.0f);
    CHECK_NEAR(nc_vol_height_exp_cap(true, 1e10f), log(100.0), 1e-5);
}

static void transmittance(void)
{
    /* In [0, 1] for every sigma_t >= 0 and length >= 0, infinite ones included. */
    const float st[] = {0.0f, 1e-30f, 1e-6f, 0.5f, 3.0f, 1e6f, 1e12f, INFINITY};
    const float len[] = {0.0f, 1e-20f, 1e-3f, 1.0f, 40.0f, 1e9f, INFINITY};
    bool in_range = true;
    for (size_t i = 0; i < sizeof(st) / sizeof(st[0]); i++)
        for (size_t j = 0; j < sizeof(len) / sizeof(len[0]); j++) {
            if (st[i] == 0.0f && isinf(len[j]))
                continue; /* 0 x inf: no medium over an infinite length is not a case */
            if (isinf(st[i]) && len[j] == 0.0f)
                continue;
            float t = nc_vol_transmittance(st[i], len[j]);
            in_range &= t >= 0.0f && t <= 1.0f;
        }
    CHECK(in_range);
    CHECK(nc_vol_transmittance(0.0f, 5.0f) == 1.0f);
    CHECK_NEAR(nc_vol_transmittance(0.5f, 3.0f), exp(-1.5), 1e-7);
    /* The product over steps equals the product of the steps' transmittances. */
    const float sig[4] = {0.2f, 0.0f, 1.5f, 0.05f}, dl[4] = {1.0f, 7.0f, 0.3f, 11.0f};
    double prod = 1.0;
    for (int i = 0; i < 4; i++)
        prod *= exp(-(double)sig[i] * dl[i]);
    double steps = nc_vol_transmittance_steps(4, sig, dl);
    CHECK_NEAR(steps, prod, 1e-15);
    CHECK(steps >= 0.0 && steps <= 1.0);
    CHECK(nc_vol_transmittance_steps(0, sig, dl) == 1.0);
}

/* integral_0^d S e^(-sigma_t t) dt by the midpoint rule with n steps. */
static double segment_numeric(double sigma_t, double source, double d, int n)
{
    double sum = 0.0, h = d / n;
    for (int i = 0; i < n; i++)
        sum += source * exp(-sigma_t * (i + 0.5) * h);
    return sum * h;
}

static void segment_integral(void)
{
    const double cases[][2] = {{0.7, 3.0}, {2.5, 0.01}, {1e-3, 20.0}, {40.0, 2.0}, {1e-9, 5.0}};
    for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
        double st = cases[i][0], d = cases[i][1];
        double exact = nc_vol_inscatter_segment(0.6 * st, st, 2.0, d);
        double num = segment_numeric(st, 0.6 * st * 2.0, d, 200000);
        CHECK_NEAR(exact / num, 1.0, 1e-8);
        /* Energy: never more than albedo x (1 - T) x L. */
        CHECK(exact <= 0.6 * 2.0 * -expm1(-st * d) * (1.0 + 1e-12));
        CHECK_NEAR(nc_vol_emission_segment(0.25, st, d) / segment_numeric(st, 0.25, d, 200000), 1.0, 1e-8);
    }
    /* sigma_t -> 0: S d, continuously. */
    CHECK(nc_vol_segment_weight(0.0, 3.0) == 3.0);
    CHECK_NEAR(nc_vol_segment_weight(1e-12, 3.0), 3.0, 1e-11);
    CHECK_NEAR(nc_vol_segment_weight(1e-5, 3.0), -expm1(-3e-5) / 1e-5, 1e-14);
    /* (1 - e^-x) / x against expm1 from 1e-8 to 100, across the series' switch point. */
    double worst = 0;
    for (double x = 1e-8; x < 100; x *= 1.01)
        worst = fmax(worst, fabs(nc_vol_exp_ratio(x) / (-expm1(-x) / x) - 1));
    printf("  (1 - e^-x) / x: max rel diff from expm1 %.2g\n", worst);
    CHECK(worst <= 1e-14);
    CHECK(nc_vol_exp_ratio(0.0) == 1.0);
    CHECK(nc_vol_exp_ratio(INFINITY) == 0.0);
    /* Infinite segments: 1 / sigma_t; nothing scattered by a non-scattering medium. */
    CHECK_NEAR(nc_vol_segment_weight(0.5, INFINITY), 2.0, 1e-15);
    CHECK_NEAR(nc_vol_inscatter_segment(0.3, 0.5, 2.0, INFINITY), 0.3 * 2.0 / 0.5, 1e-15);
    CHECK(nc_vol_inscatter_segment(0.0, 0.0, 2.0, INFINITY) == 0.0);
    /* Front to back: a homogeneous run gives the same light and transmittance in 1, 7 or 1000
     * steps, and a two-medium run matches its closed form. */
    double L[3], T[3];
    const int counts[3] = {1, 7, 1000};
    for (int k = 0; k < 3; k++) {
        nc_vol_march m = nc_vol_march_begin();
        for (int i = 0; i < counts[k]; i++)
            nc_vol_march_step(&m, 0.8, 0.3, 5.0 / counts[k]);
        L[k] = m.radiance;
        T[k] = m.transmittance;
    }
    CHECK_NEAR(L[1], L[0], 1e-14);
    CHECK_NEAR(L[2], L[0], 1e-13);
    CHECK_NEAR(T[2], T[0], 1e-14);
    CHECK_NEAR(L[0], 0.3 * (1 - exp(-4.0)) / 0.8, 1e-15);
    nc_vol_march m = nc_vol_march_begin();
    nc_vol_march_step(&m, 0.8, 0.3, 2.0);
    nc_vol_march_step(&m, 0.1, 0.05, 3.0);
    double two = 0.3 * (1 - exp(-1.6)) / 0.8 + exp(-1.6) * 0.05 * (1 - exp(-0.3)) / 0.1;
    CHECK_NEAR(m.radiance, two, 1e-15);
    CHECK_NEAR(m.transmittance, exp(-1.9), 1e-15);
}

/* ---- the pass ----------------------------------------------------------------------------- */

static bool render_json(nacre_context *c, const char *json, nacre_method method, int32_t w, int32_t h,
                        nacre_image *img, nacre_render_stats *st)
{
    nacre_scene *s = media_load(c, json, NULL);
    if (!s)
        return false;
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = method;
    rs.width = w;
    rs.height = h;
    nacre_result res = nacre_render(s, &rs, img, st);
    CHECK(res == NACRE_OK);
    if (res != NACRE_OK)
        printf("  %s\n", nacre_context_last_error(c));
    nacre_scene_destroy(s);
    return res == NACRE_OK;
}

static float px(const nacre_image *img, int x, int y, int c)
{
    return img->pixels[(size_t)y * img->stride + 3 * (size_t)x + (size_t)c];
}

static double hg(double cos_theta, double g)
{
    double d = 1 + g * g - 2 * g * cos_theta;
    return (1 - g * g) / (4 * PI * d * sqrt(d));
}

/* The scene of the closed-form checks: camera at (0, 1, 5) looking at the origin (fov 50), a
 * 400 x 400 plane at y = -30 (black unless PLANE_DIFFUSE says otherwise), a global homogeneous
 * fog, and the light and environment given. */
#define W 64
#define H 48
static const double SA = 0.002, SS[3] = {0.008, 0.006, 0.004}, G = 0.4;
static const double LDIR[3] = {0.3, -1.0, -0.4}, E[3] = {1.0, 0.8, 0.6};

static void scene_json(char *buf, size_t n, bool light, double env, double diffuse, bool fog)
{
    snprintf(buf, n,
             "{\"camera\": {\"position\": [0, 1, 5], \"target\": [0, 0, 0], \"fov\": 50},"
             "\"environment\": %g,"
             "\"materials\": {\"m\": {\"type\": \"opaque\", \"diffuse\": %g, \"specular\": 0}},"
             "\"lights\": [%s],"
             "\"objects\": [{\"shape\": {\"type\": \"plane\", \"size\": [400, 400]}, \"material\": \"m\","
             " \"transform\": {\"translate\": [0, -30, 0]}}]"
             "%s}",
             env, diffuse,
             light ? "{\"type\": \"directional\", \"direction\": [0.3, -1, -0.4], \"irradiance\": [1, 0.8, 0.6]}" : "",
             fog ? ",\"fog\": [{\"shape\": \"global\", \"sigma_a\": 0.002, \"sigma_s\": [0.008, 0.006, 0.004], \"g\": 0.4}]"
                 : "");
}

/* The camera ray of pixel (x, y) of that scene, and the distance to the plane (inf: background;
 * -1: too close to the plane's edge to say which). */
static double scene_ray(int x, int y, double d[3])
{
    double o[3] = {0, 1, 5}, f[3] = {0, -1, -5}, up[3] = {0, 1, 0}, r[3], u[3];
    double fl = sqrt(26.0);
    for (int k = 0; k < 3; k++)
        f[k] /= fl;
    r[0] = f[1] * up[2] - f[2] * up[1], r[1] = f[2] * up[0] - f[0] * up[2], r[2] = f[0] * up[1] - f[1] * up[0];
    double rl = sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]);
    for (int k = 0; k < 3; k++)
        r[k] /= rl;
    u[0] = r[1] * f[2] - r[2] * f[1], u[1] = r[2] * f[0] - r[0] * f[2], u[2] = r[0] * f[1] - r[1] * f[0];
    double th = tan(0.5 * 50 * PI / 180), nx = (x + 0.5) * 2.0 / W - 1, ny = 1 - (y + 0.5) * 2.0 / H;
    double len = 0;
    for (int k = 0; k < 3; k++) {
        d[k] = f[k] + nx * th * W / H * r[k] + ny * th * u[k];
        len += d[k] * d[k];
    }
    for (int k = 0; k < 3; k++)
        d[k] /= sqrt(len);
    if (d[1] >= 0)
        return INFINITY;
    double t = (-30 - o[1]) / d[1], px_ = o[0] + t * d[0], pz = o[2] + t * d[2];
    double edge = fmax(fabs(px_), fabs(pz));
    if (fabs(edge - 200) < 4)
        return -1;
    return edge < 200 ? t : INFINITY;
}

/* sigma_s / sigma_t p E (1 - T) + env sigma_s / sigma_t (1 - T), per channel. */
static double closed_form(const double d[3], double t, int c, bool light, double env)
{
    double ln = sqrt(LDIR[0] * LDIR[0] + LDIR[1] * LDIR[1] + LDIR[2] * LDIR[2]);
    double cos_t = -(d[0] * LDIR[0] + d[1] * LDIR[1] + d[2] * LDIR[2]) / ln;
    double st = SA + SS[c], one_minus_t = isinf(t) ? 1.0 : 1 - exp(-st * t);
    return SS[c] / st * ((light ? E[c] * hg(cos_t, G) : 0.0) + env) * one_minus_t;
}

static void pass_closed_form(void)
{
    char json[2048];
    scene_json(json, sizeof(json), true, 0.0, 0.0, true);
    nacre_image img = {0};
    nacre_render_stats st;
    if (!render_json(ctx, json, NACRE_METHOD_PHONG, W, H, &img, &st))
        return;
    CHECK(st.stage_runs[NACRE_STAGE_FOG] == 1 && st.stage_ran[NACRE_STAGE_FOG]);
    CHECK(st.fog_lights_ignored == 0 && st.fog_patterns_averaged == 0);
    double worst = 0;
    int plane = 0, background = 0;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            double d[3], t = scene_ray(x, y, d);
            if (t < 0)
                continue;
            plane += isfinite(t);
            background += isinf(t);
            for (int c = 0; c < 3; c++) {
                double expect = closed_form(d, t, c, true, 0.0);
                worst = fmax(worst, fabs(px(&img, x, y, c) - expect) / expect);
            }
        }
    printf("  closed form, directional light: %d plane and %d background pixels, max rel err %.2g\n", plane,
           background, worst);
    CHECK(plane > 300 && background > 300);
    CHECK(worst <= 1e-4);
    nacre_image_free(ctx, &img);

    /* Environment alone: isotropic ambient, sigma_s / sigma_t L_env (1 - T). */
    scene_json(json, sizeof(json), false, 0.5, 0.0, true);
    if (!render_json(ctx, json, NACRE_METHOD_PHONG, W, H, &img, NULL))
        return;
    worst = 0;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            double d[3], t = scene_ray(x, y, d);
            if (t < 0)
                continue;
            for (int c = 0; c < 3; c++) {
                double expect = closed_form(d, t, c, false, 0.5);
                worst = fmax(worst, fabs(px(&img, x, y, c) - expect) / expect);
            }
        }
    printf("  closed form, ambient: max rel err %.2g\n", worst);
    CHECK(worst <= 1e-4);
    nacre_image_free(ctx, &img);
}

/* A lit grey plane: the fog frame is the fogless frame times T plus the fog's light. */
/* Every kind of fog at once: a global height fog (rays that rise to infinity, reach the plane or
 * descend past it forever), an axis-aligned box with its own falloff and a sphere (ellipsoid)
 * that emits in red and, without extinction, in blue, under the light, over a black plane and the environment's background. The
 * pass (8 pixels at a time in float) against the module's formula evaluated per pixel in double
 * here: nc_vol_shape_segment, nc_vol_height_integral, exp. */
#define MIXED_FOGS                                                                                      \
    ",\"fog\": [{\"shape\": \"global\", \"sigma_a\": 0.002, \"sigma_s\": [0.008, 0.006, 0.004], \"g\": 0.4," \
    "\"height_falloff\": 0.3, \"height_base\": 0},"                                                     \
    "{\"shape\": \"box\", \"center\": [0.5, 0, -1], \"size\": [2, 1.5, 2], \"sigma_s\": [0.3, 0.2, 0.1],"   \
    "\"sigma_a\": 0.05, \"height_falloff\": 0.5, \"height_base\": -0.5},"                              \
    "{\"shape\": \"sphere\", \"center\": [-1, 0.3, -0.5], \"size\": [2, 1.6, 2.4],"                    \
    "\"sigma_s\": [0.5, 0.5, 0], \"g\": -0.3, \"emission\": [0.02, 0, 0.03]}]}"

static void pass_mixed_fogs(void)
{
    char json[4096];
    const double env = 0.1;
    scene_json(json, sizeof(json), true, env, 0.0, false);
    json[strlen(json) - 1] = '\0'; /* the closing brace: the fogs follow */
    strncat(json, MIXED_FOGS, sizeof(json) - strlen(json) - 1);
    nacre_image img = {0};
    if (!render_json(ctx, json, NACRE_METHOD_PHONG, W, H, &img, NULL))
        return;
    const double c_box[3] = {0.5, 0, -1}, h_box[3] = {1, 0.75, 1}, c_sph[3] = {-1, 0.3, -0.5},
                 h_sph[3] = {1, 0.8, 1.2};
    const double ss_box[3] = {0.3, 0.2, 0.1}, cap = nc_vol_height_exp_cap(true, 0.35f);
    double worst = 0;
    int rising = 0, falling = 0, plane = 0, in_box = 0, in_sphere = 0;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            const double o[3] = {0, 1, 5};
            double d[3], t = scene_ray(x, y, d);
            if (t < 0)
                continue;
            double tau[3] = {0, 0, 0}, acc[3] = {0, 0, 0}, tau_inf[3] = {0, 0, 0}, acc_inf[3] = {0, 0, 0};
            for (int i = 0; i < 3; i++) {
                double t0 = 0, t1 = t, ol[3], sa, ss[3], g, em[3] = {0, 0, 0};
                nc_vol_height h = {0};
                const double *c = i == 1 ? c_box : c_sph, *half = i == 1 ? h_box : h_sph;
                for (int k = 0; k < 3; k++)
                    ol[k] = o[k] - c[k];
                if (i > 0 && !nc_vol_shape_segment(i == 2, half, ol, d, &t0, &t1))
                    continue;
                if (i == 0) {
                    h = (nc_vol_height){.falloff = 0.3, .base = 0, .cap = nc_vol_height_exp_cap(true, 0.01f)};
                    sa = 0.002, g = 0.4;
                    memcpy(ss, SS, sizeof(ss));
                } else if (i == 1) {
                    h = (nc_vol_height){.falloff = 0.5, .base = -0.5, .cap = cap};
                    sa = 0.05, g = 0;
                    memcpy(ss, ss_box, sizeof(ss));
                    in_box++;
                } else {
                    h = (nc_vol_height){.falloff = 0, .cap = nc_vol_height_exp_cap(false, 0.5f)};
                    sa = 0, g = -0.3, em[0] = 0.02, em[2] = 0.03;
                    ss[0] = ss[1] = 0.5, ss[2] = 0; /* blue: emission without extinction */
                    in_sphere++;
                }
                double Gi = nc_vol_height_integral(&h, o[1], d[1], t0, t1);
                if (!(Gi > 0))
                    continue;
                double ln = sqrt(LDIR[0] * LDIR[0] + LDIR[1] * LDIR[1] + LDIR[2] * LDIR[2]);
                double p = hg(-(d[0] * LDIR[0] + d[1] * LDIR[1] + d[2] * LDIR[2]) / ln, g);
                for (int ch = 0; ch < 3; ch++) {
                    double st = sa + ss[ch], src = ss[ch] * (env + E[ch] * p) + em[ch];
                    if (isinf(Gi)) {
                        tau_inf[ch] += st;
                        acc_inf[ch] += src;
                    } else {
                        tau[ch] += st * Gi;
                        acc[ch] += src * Gi;
                    }
                }
            }
            rising += isinf(t) && d[1] > 0;
            falling += isinf(t) && d[1] < 0;
            plane += isfinite(t);
            for (int ch = 0; ch < 3; ch++) {
                double T = tau_inf[ch] > 0 ? 0.0 : exp(-tau[ch]);
                double L = tau_inf[ch] > 0 ? acc_inf[ch] / tau_inf[ch]
                                           : (tau[ch] > 0 ? acc[ch] * -expm1(-tau[ch]) / tau[ch] : acc[ch]);
                double expect = (isinf(t) ? env : 0.0) * T + L;
                worst = fmax(worst, fabs(px(&img, x, y, ch) - expect) / expect);
            }
        }
    printf("  every kind of fog: %d rising, %d descending background pixels, %d plane; %d through the box, "
           "%d the sphere; max rel err %.2g\n",
           rising, falling, plane, in_box, in_sphere, worst);
    CHECK(rising > 100 && falling > 10 && plane > 300 && in_box > 100 && in_sphere > 100);
    CHECK(worst <= 1e-4);
    nacre_image_free(ctx, &img);
}

static void pass_attenuates_surfaces(void)
{
    char json[2048];
    nacre_image fog = {0}, clear = {0};
    scene_json(json, sizeof(json), true, 0.1, 0.6, true);
    bool ok = render_json(ctx, json, NACRE_METHOD_PHONG, W, H, &fog, NULL);
    scene_json(json, sizeof(json), true, 0.1, 0.6, false);
    ok = render_json(ctx, json, NACRE_METHOD_PHONG, W, H, &clear, NULL) && ok;
    if (!ok)
        return;
    double worst = 0;
    int n = 0;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            double d[3], t = scene_ray(x, y, d);
            if (t < 0)
                continue;
            for (int c = 0; c < 3; c++) {
                double T = isinf(t) ? 0.0 : exp(-(SA + SS[c]) * t);
                double expect = px(&clear, x, y, c) * T + closed_form(d, t, c, true, 0.1);
                worst = fmax(worst, fabs(px(&fog, x, y, c) - expect) / expect);
                n += isfinite(t) && px(&clear, x, y, c) > 0.05f;
            }
        }
    printf("  c T + L over a lit plane: max rel err %.2g (%d lit values)\n", worst, n);
    CHECK(n > 300);
    CHECK(worst <= 1e-4);
    nacre_image_free(ctx, &fog);
    nacre_image_free(ctx, &clear);
}

/* The same frame from 1 and 2 threads, and from a renderer reusing its output buffer. */
static void pass_threads_and_reuse(void)
{
    char json[2048];
    scene_json(json, sizeof(json), true, 0.1, 0.6, true);
    nacre_image img[2] = {{0}, {0}};
    for (int k = 0; k < 2; k++) {
        nacre_context_desc cd = {0};
        cd.threads = k + 1;
        nacre_context *c = NULL;
        CHECK(nacre_context_create(&cd, &c) == NACRE_OK);
        if (!c)
            return;
        nacre_image tmp = {0};
        if (render_json(c, json, NACRE_METHOD_PHONG, W, H, &tmp, NULL)) {
            CHECK(nacre_image_alloc(ctx, W, H, 3, &img[k]) == NACRE_OK);
            memcpy(img[k].pixels, tmp.pixels, (size_t)W * H * 3 * sizeof(float));
            nacre_image_free(c, &tmp);
        }
        nacre_context_destroy(c);
    }
    CHECK(img[0].pixels && img[1].pixels &&
          memcmp(img[0].pixels, img[1].pixels, (size_t)W * H * 3 * sizeof(float)) == 0);

    /* reuse_output: background pixels keep the environment from frame to frame, so a pass that
     * changes them must not be applied twice. The background must be seen through finite fog
     * (behind an infinite one it is the fog's colour whatever was there): a box of height fog. */
    const char *box = "{\"camera\": {\"position\": [0, 1, 5], \"target\": [0, 0, 0]}, \"environment\": 0.3,"
                      "\"materials\": {\"m\": {\"type\": \"opaque\"}},"
                      "\"objects\": [{\"shape\": {\"type\": \"sphere\"}, \"material\": \"m\"}],"
                      "\"fog\": [{\"shape\": \"box\", \"size\": 30, \"sigma_a\": 0.02, \"sigma_s\": 0.05,"
                      " \"height_falloff\": 0.1}]}";
    nacre_image fresh = {0};
    render_json(ctx, box, NACRE_METHOD_PHONG, W, H, &fresh, NULL);
    nacre_scene *s = media_load(ctx, box, NULL);
    if (s) {
        nacre_render_settings rs = nacre_render_settings_defaults();
        rs.width = W;
        rs.height = H;
        rs.reuse_output = true;
        nacre_renderer *r = NULL;
        CHECK(nacre_renderer_create(ctx, &r) == NACRE_OK);
        nacre_image out = {0};
        CHECK(nacre_renderer_render(r, s, &rs, &out, NULL) == NACRE_OK);
        CHECK(nacre_renderer_render(r, s, &rs, &out, NULL) == NACRE_OK);
        CHECK(out.pixels && fresh.pixels && memcmp(out.pixels, fresh.pixels, (size_t)W * H * 3 * sizeof(float)) == 0);
        nacre_image_free(ctx, &out);
        nacre_renderer_destroy(r);
        nacre_scene_destroy(s);
    }
    nacre_image_free(ctx, &fresh);
    nacre_image_free(ctx, &img[0]);
    nacre_image_free(ctx, &img[1]);
}

/* Which frames get the pass: raster methods with fog; not the path tracer, not fogless scenes. */
static void pass_wanted(void)
{
    char json[2048];
    scene_json(json, sizeof(json), true, 0.1, 0.6, false);
    nacre_image img = {0};
    nacre_render_stats st;
    if (render_json(ctx, json, NACRE_METHOD_PHONG, 16, 12, &img, &st))
        CHECK(st.stage_runs[NACRE_STAGE_FOG] == 0);
    nacre_image_free(ctx, &img);
    nacre_method_info info;
    CHECK(nacre_method_info_get(NACRE_METHOD_PATHTRACE, &info) && info.renders_fog);
    CHECK(nacre_method_info_get(NACRE_METHOD_PHONG, &info) && !info.renders_fog);
    CHECK(nacre_method_info_get(NACRE_METHOD_DIFFUSION, &info) && !info.renders_fog);
    if (!nacre_method_available(NACRE_METHOD_PATHTRACE))
        return;
    scene_json(json, sizeof(json), true, 0.1, 0.6, true);
    if (render_json(ctx, json, NACRE_METHOD_PATHTRACE, 16, 12, &img, &st))
        CHECK(st.stage_runs[NACRE_STAGE_FOG] == 0);
    nacre_image_free(ctx, &img);
    /* A point light lights no fog in the pass: the stats say so. */
    const char *pt = "{\"camera\": {\"position\": [0, 1, 5], \"target\": [0, 0, 0]},"
                     "\"materials\": {\"m\": {\"type\": \"opaque\"}},"
                     "\"lights\": [{\"type\": \"point\", \"position\": [0, 3, 0], \"intensity\": 5}],"
                     "\"objects\": [{\"shape\": {\"type\": \"plane\"}, \"material\": \"m\"}],"
                     "\"fog\": [{\"shape\": \"global\", \"sigma_s\": 0.01}]}";
    if (render_json(ctx, pt, NACRE_METHOD_PHONG, 16, 12, &img, &st))
        CHECK(st.stage_runs[NACRE_STAGE_FOG] == 1 && st.fog_lights_ignored == 1);
    nacre_image_free(ctx, &img);
}

/* ---- against the path tracer -------------------------------------------------------------- */

/* A slab of box fog, y in [0, 1] and 10^4 wide, over a black plane at y = 0; the camera inside
 * at y = 0.5 looks along the horizon (fov 10: rows from 5 degrees up to 5 down, optical depths
 * from ~0.06 to ~50 along the view); a delta sun from above and to the side, no environment.
 * The pass lights every point fully; in the path tracer the sun crosses up to 1 / 0.9 units of
 * fog (optical depth <= 0.011, ~0.5% on average): a bias inside the 2% allowed. */
#define PW 48
#define PH 36
static const char *SLAB =
    "{\"camera\": {\"position\": [0, 0.5, 0], \"target\": [0, 0.5, -10], \"fov\": 10},"
    "\"environment\": 0,"
    "\"materials\": {\"black\": {\"type\": \"opaque\", \"diffuse\": 0, \"specular\": 0}},"
    "\"lights\": [{\"type\": \"directional\", \"direction\": [0.4, -1, 0.2], \"irradiance\": [1, 0.9, 0.8],"
    " \"angular_radius\": 0}],"
    "\"objects\": [{\"shape\": {\"type\": \"plane\", \"size\": 10000}, \"material\": \"black\"}],"
    "\"fog\": [{\"shape\": \"box\", \"center\": [0, 0.5, 0], \"size\": [10000, 1, 10000], \"sigma_a\": 0.001,"
    " \"sigma_s\": [0.009, 0.008, 0.007], \"g\": 0.3}]}";

static void pass_against_path_tracer(void)
{
    if (!nacre_method_available(NACRE_METHOD_PATHTRACE)) {
        printf("  no path tracer in this build: comparison skipped\n");
        return;
    }
    nacre_image pass = {0}, ref = {0}, var = {0};
    if (!render_json(ctx, SLAB, NACRE_METHOD_PHONG, PW, PH, &pass, NULL))
        return;
    nacre_scene *s = media_load(ctx, SLAB, NULL);
    if (!s)
        return;
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = NACRE_METHOD_PATHTRACE;
    rs.width = PW;
    rs.height = PH;
    rs.pathtrace.spp = 512;
    rs.pathtrace.seed = 7;
    rs.pathtrace.max_scatter = 1;
    nacre_renderer *r = NULL;
    CHECK(nacre_renderer_create(ctx, &r) == NACRE_OK);
    nacre_result res = nacre_renderer_render(r, s, &rs, &ref, NULL);
    CHECK(res == NACRE_OK);
    CHECK(res != NACRE_OK || nacre_renderer_variance(r, &var) == NACRE_OK);
    nacre_renderer_destroy(r);
    nacre_scene_destroy(s);
    if (res != NACRE_OK || !var.pixels) {
        nacre_image_free(ctx, &pass);
        nacre_image_free(ctx, &ref);
        return;
    }
    /* Bands of 6 rows: the mean of the pass against the path tracer's, its standard error. */
    double worst = 0;
    for (int b = 0; b < PH / 6; b++)
        for (int c = 0; c < 3; c++) {
            double mp = 0, mr = 0, v = 0;
            for (int y = 6 * b; y < 6 * b + 6; y++)
                for (int x = 0; x < PW; x++) {
                    mp += px(&pass, x, y, c);
                    mr += px(&ref, x, y, c);
                    v += px(&var, x, y, c);
                }
            int n = 6 * PW;
            mp /= n, mr /= n;
            double se = sqrt(v) / n, rel = (mp - mr) / mr;
            worst = fmax(worst, fabs(rel));
            if (c == 1)
                printf("  slab vs path tracer, rows %2d-%2d: pass %.5f, path tracer %.5f +- %.5f (%+.2f%%)\n", 6 * b,
                       6 * b + 5, mp, mr, se, 100 * rel);
            CHECK(fabs(mp - mr) <= 3 * se + 0.02 * mr);
        }
    printf("  slab vs path tracer: largest band difference %.2f%%\n", 100 * worst);
    nacre_image_free(ctx, &pass);
    nacre_image_free(ctx, &ref);
    nacre_image_free(ctx, &var);
}

int main(void)
{
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    height_integral();
    transmittance();
    segment_integral();
    pass_closed_form();
    pass_mixed_fogs();
    pass_attenuates_surfaces();
    pass_threads_and_reuse();
    pass_wanted();
    pass_against_path_tracer();
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
