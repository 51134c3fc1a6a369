/*
 * test_layered_method.c: `--method layered` (seed 001) on a flat slab, where the seed's planar
 * approximations are exact: the rendered radiance against a fine midpoint quadrature (in double)
 * of the single-scattering integral through two layers and a core, with Fresnel at entry and
 * exit, for both integrations; one layer of constant thickness against its closed form; the
 * seed's point sampling converging as N grows (10 .. 200) and the analytic pieces reaching the
 * 200-sample image with few steps on a slab with the vein depth map; the planes stage cached
 * across light and camera edits; half resolution against the full image; the view rays kept
 * across frames against new renderers after light, camera, material and settings edits; bad input (a layered mesh without uvs, samples and epsilon out
 * of range) refused with messages naming the object or the field.
 */
#include "test_util.h"

#include <nacre/nacre.h>

static nacre_context *ctx;

/* The slab: a box whose top face (y = 20) the orthographic camera sees, lit by a directional
 * light; no environment and no specular, so the image is the single scattering alone. */
static const char *sun_radius = "0"; /* degrees; the path tracer needs a sun of some size */

static const char *slab_json(char *buf, size_t size, const char *layers, const char *extra_material)
{
    snprintf(buf, size,
             "{\"units\": \"mm\","
             " \"camera\": {\"type\": \"orthographic\", \"position\": [0, 80, 30], \"target\": [0, 20, 0],"
             "   \"height\": 8},"
             " \"environment\": [0, 0, 0],"
             " \"materials\": {\"m\": {\"type\": \"translucent\", \"sigma_a\": [0.02, 0.1, 0.3],"
             "   \"sigma_s\": [1.0, 0.8, 0.6], \"g\": 0.3, \"eta\": 1.4, \"specular\": 0, %s"
             "   \"layers\": %s}},"
             " \"lights\": [{\"type\": \"directional\", \"direction\": [-0.4, -1, -0.3], \"irradiance\": [2, 2, 2],"
             "   \"angular_radius\": %s}],"
             " \"objects\": [{\"name\": \"slab\", \"shape\": {\"type\": \"box\", \"size\": [80, 40, 80]},"
             "   \"material\": \"m\"}]}",
             extra_material, layers, sun_radius);
    return buf;
}

typedef struct medium1 {
    double st[3], ss[3], g;
} medium1;

static double hg(double c, double g)
{
    double d = 1 + g * g - 2 * g * c;
    return (1 - g * g) / (4 * 3.14159265358979323846 * d * sqrt(d));
}

static double fresnel(double ci, double eta)
{
    double s2 = (1 - ci * ci) / (eta * eta);
    if (s2 >= 1)
        return 1;
    double ct = sqrt(1 - s2);
    double rs = (ci - eta * ct) / (ci + eta * ct), rp = (eta * ci - ct) / (eta * ci + ct);
    return 0.5 * (rs * rs + rp * rp);
}

static void normalize(double v[3])
{
    double l = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    for (int k = 0; k < 3; k++)
        v[k] /= l;
}

/* Geometry of the slab scene: cosines of the refracted view and light, the scattering cosine
 * inside, and the factors outside the integral. */
typedef struct slab_geo {
    double cv, cl, cs, fac;
} slab_geo;

static slab_geo slab_geometry(double eta, double irradiance)
{
    double v[3] = {0, 60, 30}, w[3] = {0.4, 1, 0.3}; /* towards the eye, towards the light */
    normalize(v);
    normalize(w);
    double co = v[1], ci = w[1];
    double cv = sqrt(1 - (1 - co * co) / (eta * eta)), cl = sqrt(1 - (1 - ci * ci) / (eta * eta));
    /* refracted directions (n = +y): inward view ray d, towards-light inside wt */
    double d[3], wt[3];
    for (int k = 0; k < 3; k++) {
        double nk = k == 1 ? 1 : 0;
        d[k] = -v[k] / eta + (co / eta - cv) * nk;
        wt[k] = (w[k] - ci * nk) / eta + cl * nk;
    }
    slab_geo g = {cv, cl, d[0] * wt[0] + d[1] * wt[1] + d[2] * wt[2], 0};
    g.fac = (1 - fresnel(co, eta)) / (eta * eta) * irradiance * (1 - fresnel(ci, eta)) * ci / cl;
    return g;
}

/* Midpoint quadrature in depth of the single scattering through layers of thickness thick[]
 * over a core (media[count]), channel c. */
static double slab_quadrature(const medium1 *media, const double *thick, int count, int c, slab_geo g)
{
    double sum = 0, tau = 0, z = 0;
    const double dz = 1e-4;
    int j = 0;
    double bottom = count > 0 ? thick[0] : INFINITY;
    while (tau < 40) {
        double zm = z + 0.5 * dz;
        while (j < count && zm >= bottom) {
            j++;
            bottom = j < count ? bottom + thick[j] : INFINITY;
        }
        const medium1 *m = &media[j];
        double k = m->st[c] * (1 / g.cl + 1 / g.cv);
        sum += m->ss[c] * hg(g.cs, m->g) * exp(-(tau + 0.5 * k * dz)) * dz / g.cv;
        tau += k * dz;
        z += dz;
    }
    return g.fac * sum;
}

/* Render and return the mean of the central 16 x 16 pixels (all on the flat top) per channel. */
static bool render_center(nacre_scene *s, nacre_render_settings rs, double out[3])
{
    nacre_image img = {0};
    nacre_result r = nacre_render(s, &rs, &img, NULL);
    if (r != NACRE_OK) {
        printf("render: %s\n", nacre_context_last_error(ctx));
        return false;
    }
    out[0] = out[1] = out[2] = 0;
    for (int y = rs.height / 2 - 8; y < rs.height / 2 + 8; y++)
        for (int x = rs.width / 2 - 8; x < rs.width / 2 + 8; x++)
            for (int c = 0; c < 3; c++)
                out[c] += img.pixels[img.stride * (size_t)y + 3 * (size_t)x + (size_t)c] / 256.0;
    nacre_image_free(ctx, &img);
    return true;
}

static nacre_scene *load(const char *json)
{
    nacre_scene *s = NULL;
    if (nacre_scene_load_json(ctx, json, strlen(json), "slab.json", NACRE_SOURCE_DIR "/examples", &s, NULL) !=
        NACRE_OK) {
        printf("load: %s\n", nacre_context_last_error(ctx));
        return NULL;
    }
    if (nacre_scene_commit(s, 0) != NACRE_OK) {
        nacre_scene_destroy(s);
        return NULL;
    }
    return s;
}

static nacre_render_settings settings(uint32_t samples, nacre_layered_integration integ)
{
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = NACRE_METHOD_LAYERED;
    rs.width = rs.height = 48;
    rs.layered.samples = samples;
    rs.layered.integration = integ;
    rs.layered.epsilon = 1e-3f; /* Depth_max where the omitted tail is ~1e-6 of the sum */
    return rs;
}

/* Two flat layers over a core against the quadrature. */
static void test_flat_layers(void)
{
    char buf[2048];
    const char *layers = "[{\"sigma_a\": [0.05, 0.2, 0.4], \"sigma_s\": [3, 2.5, 2], \"g\": 0.8, \"depth\": 0.3},"
                         " {\"sigma_a\": [0.6, 0.1, 0.05], \"sigma_s\": [1, 1.5, 2], \"g\": -0.2, \"depth\": 0.9}]";
    nacre_scene *s = load(slab_json(buf, sizeof(buf), layers, ""));
    CHECK(s != NULL);
    if (!s)
        return;
    const medium1 media[3] = {{{3.05, 2.7, 2.4}, {3, 2.5, 2}, 0.8},
                              {{1.6, 1.6, 2.05}, {1, 1.5, 2}, -0.2},
                              {{1.02, 0.9, 0.9}, {1.0, 0.8, 0.6}, 0.3}};
    const double thick[2] = {0.3, 0.6};
    slab_geo g = slab_geometry(1.4, 2.0);
    double want[3];
    for (int c = 0; c < 3; c++)
        want[c] = slab_quadrature(media, thick, 2, c, g);
    double got[3];
    /* Analytic pieces: exact on flat layers whatever the number of steps. */
    const uint32_t steps[] = {1, 4, 16};
    for (int i = 0; i < 3; i++) {
        CHECK(render_center(s, settings(steps[i], NACRE_LAYERED_ANALYTIC), got));
        for (int c = 0; c < 3; c++)
            CHECK_NEAR(got[c] / want[c], 1.0, 0.005);
    }
    printf("flat layers: quadrature %.6g %.6g %.6g, analytic(4) %.6g %.6g %.6g\n", want[0], want[1], want[2],
           got[0], got[1], got[2]);
    /* The seed's point samples: within 1% at 200 samples. */
    CHECK(render_center(s, settings(200, NACRE_LAYERED_SAMPLES), got));
    for (int c = 0; c < 3; c++)
        CHECK_NEAR(got[c] / want[c], 1.0, 0.01);
    /* Shadows on (the default) must not darken the lit top; the same without the shadow map. */
    nacre_render_settings ns = settings(8, NACRE_LAYERED_ANALYTIC);
    ns.shadow.map_size = 0;
    double unshadowed[3];
    CHECK(render_center(s, ns, unshadowed));
    CHECK(render_center(s, settings(8, NACRE_LAYERED_ANALYTIC), got));
    for (int c = 0; c < 3; c++)
        CHECK_NEAR(got[c] / unshadowed[c], 1.0, 1e-3);
    nacre_scene_destroy(s);
}

/* The same slab against the path tracer with one scattering event (the sun of angular radius
 * 0.27 degrees, which the path tracer samples through the dielectric): image means agree within
 * 1% plus 3 standard deviations of the reference's mean. */
static void test_flat_layers_pathtrace(void)
{
#ifdef NACRE_HAVE_EMBREE
    char buf[2048];
    const char *layers = "[{\"sigma_a\": [0.05, 0.2, 0.4], \"sigma_s\": [3, 2.5, 2], \"g\": 0.8, \"depth\": 0.3},"
                         " {\"sigma_a\": [0.6, 0.1, 0.05], \"sigma_s\": [1, 1.5, 2], \"g\": -0.2, \"depth\": 0.9}]";
    sun_radius = "0.27";
    nacre_scene *s = load(slab_json(buf, sizeof(buf), layers, ""));
    sun_radius = "0";
    CHECK(s != NULL);
    if (!s)
        return;
    nacre_renderer *r = NULL;
    CHECK(nacre_renderer_create(ctx, &r) == NACRE_OK);
    nacre_render_settings rs = settings(4, NACRE_LAYERED_ANALYTIC);
    rs.width = rs.height = 16;
    nacre_image lay = {0}, pt = {0}, var = {0};
    CHECK(nacre_renderer_render(r, s, &rs, &lay, NULL) == NACRE_OK);
    rs.method = NACRE_METHOD_PATHTRACE;
    rs.pathtrace.max_scatter = 1;
    rs.pathtrace.spp = 1024;
    CHECK(nacre_renderer_render(r, s, &rs, &pt, NULL) == NACRE_OK);
    CHECK(nacre_renderer_variance(r, &var) == NACRE_OK);
    if (lay.pixels && pt.pixels && var.pixels) {
        for (int c = 0; c < 3; c++) {
            double ml = 0, mp = 0, v = 0;
            const double n = 16.0 * 16.0;
            for (int y = 0; y < 16; y++)
                for (int x = 0; x < 16; x++) {
                    ml += lay.pixels[lay.stride * (size_t)y + 3 * (size_t)x + (size_t)c] / n;
                    mp += pt.pixels[pt.stride * (size_t)y + 3 * (size_t)x + (size_t)c] / n;
                    v += var.pixels[var.stride * (size_t)y + 3 * (size_t)x + (size_t)c] / (n * n);
                }
            printf("slab vs path tracer (max_scatter 1), channel %d: layered %.6g, path tracer %.6g +- %.2g\n", c, ml,
                   mp, sqrt(v));
            CHECK_NEAR(ml, mp, 0.01 * mp + 3 * sqrt(v));
        }
    }
    nacre_image_free(ctx, &lay);
    nacre_image_free(ctx, &pt);
    nacre_image_free(ctx, &var);
    nacre_renderer_destroy(r);
    nacre_scene_destroy(s);
#endif
}

/* One layer of constant thickness over the core: the closed form. */
static void test_one_layer_closed_form(void)
{
    char buf[2048];
    const char *layers = "[{\"sigma_a\": [0.3, 0.3, 0.3], \"sigma_s\": [4, 2, 1], \"g\": 0.5, \"depth\": 0.4}]";
    nacre_scene *s = load(slab_json(buf, sizeof(buf), layers, ""));
    CHECK(s != NULL);
    if (!s)
        return;
    const double st1[3] = {4.3, 2.3, 1.3}, ss1[3] = {4, 2, 1}, g1 = 0.5, d1 = 0.4;
    const double st2[3] = {1.02, 0.9, 0.9}, ss2[3] = {1.0, 0.8, 0.6}, g2 = 0.3;
    slab_geo g = slab_geometry(1.4, 2.0);
    double got[3];
    CHECK(render_center(s, settings(3, NACRE_LAYERED_ANALYTIC), got));
    for (int c = 0; c < 3; c++) {
        double k1 = st1[c] * (1 / g.cl + 1 / g.cv), k2 = st2[c] * (1 / g.cl + 1 / g.cv);
        double want = g.fac / g.cv *
                      (ss1[c] * hg(g.cs, g1) * (1 - exp(-k1 * d1)) / k1 + exp(-k1 * d1) * ss2[c] * hg(g.cs, g2) / k2);
        CHECK_NEAR(got[c] / want, 1.0, 0.005);
    }
    nacre_scene_destroy(s);
}

/* Mean relative error of a over b over the pixels where b > 0. */
static double image_error(const nacre_image *a, const nacre_image *b)
{
    double sum = 0;
    size_t n = 0;
    for (int32_t y = 0; y < a->height; y++)
        for (int32_t x = 0; x < 3 * a->width; x++) {
            double r = b->pixels[b->stride * (size_t)y + (size_t)x], t = a->pixels[a->stride * (size_t)y + (size_t)x];
            if (r > 1e-6) {
                sum += fabs(t - r) / r;
                n++;
            }
        }
    return n ? sum / (double)n : INFINITY;
}

/* With the vein map the layers vary: the seed's sampling converges as N grows, and the analytic
 * pieces get close to the 200-sample image with few steps. */
static void test_convergence(void)
{
    char buf[2048];
    const char *layers = "[{\"sigma_a\": [0.05, 0.12, 0.3], \"sigma_s\": [4, 4, 4], \"g\": 0.8, \"depth\": 0.15},"
                         " {\"sigma_a\": [0.3, 1.5, 1.2], \"sigma_s\": [1.5, 1.5, 1.5], \"g\": 0.9, \"depth\": 1.2},"
                         " {\"sigma_a\": [0.03, 0.06, 0.1], \"sigma_s\": [0.8, 0.9, 1.0], \"g\": 0, \"depth\": 3}]";
    nacre_scene *s = load(slab_json(buf, sizeof(buf), layers, "\"depth_map\": \"layered_depth.png\","));
    CHECK(s != NULL);
    if (!s)
        return;
    nacre_renderer *r = NULL;
    CHECK(nacre_renderer_create(ctx, &r) == NACRE_OK);
    nacre_image ref = {0}, img = {0};
    /* The reference: analytic pieces at 256 steps (converged: 64 steps give the same image to
     * 1e-4). Point samples converge as 1 / N only, from the steps that straddle a boundary. */
    nacre_render_settings rs = settings(256, NACRE_LAYERED_ANALYTIC);
    rs.width = rs.height = 40;
    rs.shadow.map_size = 0;
    CHECK(nacre_renderer_render(r, s, &rs, &ref, NULL) == NACRE_OK);
    rs.layered.samples = 64;
    CHECK(nacre_renderer_render(r, s, &rs, &img, NULL) == NACRE_OK);
    CHECK(image_error(&img, &ref) < 1e-3);
    rs.layered.integration = NACRE_LAYERED_SAMPLES;
    const uint32_t n[] = {10, 20, 50, 100, 200};
    double err[5];
    nacre_image i200 = {0};
    for (int i = 0; i < 5; i++) {
        rs.layered.samples = n[i];
        CHECK(nacre_renderer_render(r, s, &rs, i == 4 ? &i200 : &img, NULL) == NACRE_OK);
        err[i] = image_error(i == 4 ? &i200 : &img, &ref);
        printf("samples %u: mean relative error to the converged image %.5f\n", n[i], err[i]);
    }
    CHECK(err[2] < err[0] && err[4] < 0.1 * err[1] && err[4] < 0.03);
    rs.layered.integration = NACRE_LAYERED_ANALYTIC;
    const uint32_t na[] = {1, 2, 4, 8, 16};
    double e4 = INFINITY;
    for (int i = 0; i < 5; i++) {
        rs.layered.samples = na[i];
        CHECK(nacre_renderer_render(r, s, &rs, &img, NULL) == NACRE_OK);
        double e200 = image_error(&img, &i200), eref = image_error(&img, &ref);
        printf("analytic %u steps: mean relative error to 200 samples %.5f, to the converged image %.5f\n", na[i],
               e200, eref);
        if (na[i] == 4)
            e4 = eref;
    }
    /* 4 analytic steps are closer to the converged image than 200 point samples */
    CHECK(e4 < err[4]);
    nacre_image_free(ctx, &ref);
    nacre_image_free(ctx, &img);
    nacre_image_free(ctx, &i200);
    nacre_renderer_destroy(r);
    nacre_scene_destroy(s);
}

/* The planes stage runs once per geometry: light, material-free and camera edits keep it. */
static void test_planes_cached(void)
{
    char buf[2048];
    nacre_scene *s = load(slab_json(buf, sizeof(buf), "[]", ""));
    CHECK(s != NULL);
    if (!s)
        return;
    nacre_renderer *r = NULL;
    CHECK(nacre_renderer_create(ctx, &r) == NACRE_OK);
    nacre_render_settings rs = settings(4, NACRE_LAYERED_ANALYTIC);
    nacre_render_stats st;
    nacre_image img = {0};
    CHECK(nacre_renderer_render(r, s, &rs, &img, &st) == NACRE_OK);
    CHECK(st.stage_runs[NACRE_STAGE_PLANES] == 1 && st.stage_runs[NACRE_STAGE_MARCH] == 1);
    nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
    ld.direction[0] = 0.3f, ld.direction[1] = -1, ld.direction[2] = 0;
    CHECK(nacre_scene_set_light(s, (nacre_light){1}, &ld) == NACRE_OK);
    CHECK(nacre_scene_commit(s, 0) == NACRE_OK);
    CHECK(nacre_renderer_render(r, s, &rs, &img, &st) == NACRE_OK);
    CHECK(st.stage_runs[NACRE_STAGE_PLANES] == 0 && st.stage_runs[NACRE_STAGE_MARCH] == 1);
    rs.layered.epsilon = 0.05f; /* a new radius */
    CHECK(nacre_renderer_render(r, s, &rs, &img, &st) == NACRE_OK);
    CHECK(st.stage_runs[NACRE_STAGE_PLANES] == 1);
    nacre_image_free(ctx, &img);
    nacre_renderer_destroy(r);
    nacre_scene_destroy(s);
}

static void test_bad_input(void)
{
    /* A layered material on a mesh without uvs: the error names the object. */
    nacre_scene *s = NULL;
    CHECK(nacre_scene_create(ctx, &s) == NACRE_OK);
    float pos[9] = {0, 0, 0, 1, 0, 0, 0, 0, -1};
    uint32_t idx[3] = {0, 1, 2};
    nacre_mesh_data md = {0};
    md.vertex_count = 3;
    md.triangle_count = 1;
    md.positions = pos;
    md.indices = idx;
    nacre_mesh mesh = {0};
    CHECK(nacre_scene_add_mesh(s, &md, &mesh) == NACRE_OK);
    nacre_material_desc m = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
    m.layering.count = 1;
    m.layering.layers[0] = (nacre_layer){{0.1f, 0.1f, 0.1f}, {1, 1, 1}, 0, 0.5f};
    nacre_material mat = {0};
    CHECK(nacre_scene_add_material(s, &m, &mat) == NACRE_OK);
    nacre_object_desc od = nacre_object_desc_defaults();
    od.mesh = mesh;
    od.material = mat;
    od.name = "no-uv thing";
    nacre_object obj = {0};
    CHECK(nacre_scene_add_object(s, &od, &obj) == NACRE_OK);
    CHECK(nacre_scene_commit(s, 0) == NACRE_OK);
    nacre_render_settings rs = settings(4, NACRE_LAYERED_ANALYTIC);
    nacre_image img = {0};
    CHECK(nacre_render(s, &rs, &img, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "no-uv thing") != NULL);
    CHECK(strstr(nacre_context_last_error(ctx), "texture coordinates") != NULL);
    /* Settings out of range name the field. */
    rs.layered.samples = 0;
    CHECK(nacre_render(s, &rs, &img, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "layered_samples") != NULL);
    rs.layered.samples = 100000;
    CHECK(nacre_render(s, &rs, &img, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
    rs.layered.samples = 8;
    rs.layered.epsilon = 1.0f;
    CHECK(nacre_render(s, &rs, &img, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "layered_epsilon") != NULL);
    CHECK(img.pixels == NULL);
    nacre_scene_destroy(s);
    /* Scene files: the render block's keys, read and range-checked with the field named. */
    const char *good = "{\"render\": {\"method\": \"layered\", \"layered_samples\": 7, \"layered_epsilon\": 0.05,"
                       " \"layered_integration\": \"samples\", \"layered_half_res\": 0.05}, \"objects\": []}";
    nacre_scene_file_settings fs;
    s = NULL;
    CHECK(nacre_scene_load_json(ctx, good, strlen(good), "g.json", NULL, &s, &fs) == NACRE_OK);
    CHECK(fs.render.method == NACRE_METHOD_LAYERED && fs.render.layered.samples == 7 &&
          fabsf(fs.render.layered.epsilon - 0.05f) < 1e-7f && fs.render.layered.integration == NACRE_LAYERED_SAMPLES &&
          fabsf(fs.render.layered.half_res - 0.05f) < 1e-7f);
    nacre_scene_destroy(s);
    const char *bad[] = {"{\"render\": {\"layered_samples\": 0}}", "{\"render\": {\"layered_samples\": 5000}}",
                         "{\"render\": {\"layered_epsilon\": 1}}", "{\"render\": {\"layered_integration\": \"simpson\"}}",
                         "{\"render\": {\"layered_half_res\": 1}}"};
    const char *field[] = {"layered_samples", "layered_samples", "layered_epsilon", "layered_integration",
                           "layered_half_res"};
    for (int i = 0; i < 5; i++) {
        s = NULL;
        CHECK(nacre_scene_load_json(ctx, bad[i], strlen(bad[i]), "b.json", NULL, &s, &fs) != NACRE_OK);
        CHECK(s == NULL && strstr(nacre_context_last_error(ctx), field[i]) != NULL);
    }
}

/* Procedural depth maps: values in [0, 1], the fixed channels at 1, veins covering some but not
 * most of the map, the same seed giving the same map and another seed another; a data PNG
 * reads back to the values; the fish preset is the seed's table 1. */
static void test_maps_and_fish(void)
{
    nacre_image a = {0}, b = {0}, c = {0};
    CHECK(nacre_layer_map_generate(ctx, NACRE_LAYER_MAP_VEINS, 128, 7, &a) == NACRE_OK);
    CHECK(nacre_layer_map_generate(ctx, NACRE_LAYER_MAP_VEINS, 128, 7, &b) == NACRE_OK);
    CHECK(nacre_layer_map_generate(ctx, NACRE_LAYER_MAP_VEINS, 128, 8, &c) == NACRE_OK);
    CHECK(a.channels == 4 && a.width == 128 && a.height == 128);
    size_t n = (size_t)a.width * (size_t)a.height * 4, vein = 0, fixed_ok = 0, diff = 0;
    for (size_t i = 0; i < n; i++) {
        CHECK(a.pixels[i] >= 0.0f && a.pixels[i] <= 1.0f);
        if (i % 4 == 1)
            vein += a.pixels[i] > 0.5f;
        else
            fixed_ok += a.pixels[i] == 1.0f;
        diff += a.pixels[i] != c.pixels[i];
    }
    CHECK(memcmp(a.pixels, b.pixels, n * sizeof(float)) == 0);
    CHECK(diff > 0);
    CHECK(fixed_ok == 3 * n / 4);
    CHECK(vein > n / 4 / 100 && vein < n / 4 / 2);
    CHECK(nacre_image_write_data(ctx, &a, NACRE_TEST_TMP "/veins.png") == NACRE_OK);
    nacre_image back = {0};
    CHECK(nacre_image_read_data(ctx, NACRE_TEST_TMP "/veins.png", &back) == NACRE_OK);
    double worst = 0;
    for (int32_t y = 0; back.pixels && y < 128; y++)
        for (int32_t x = 0; x < 4 * 128; x++)
            worst = fmax(worst, fabs(back.pixels[back.stride * (size_t)y + (size_t)x] - a.pixels[a.stride * (size_t)y + (size_t)x]));
    CHECK(back.channels == 4 && worst <= 0.5 / 255 + 1e-6);
    nacre_image_free(ctx, &back);
    nacre_image_free(ctx, &a);
    nacre_image_free(ctx, &b);
    nacre_image_free(ctx, &c);
    CHECK(nacre_layer_map_generate(ctx, NACRE_LAYER_MAP_CONSTANT, 16, 1, &a) == NACRE_OK);
    for (size_t i = 0; a.pixels && i < 16 * 16 * 4; i++)
        CHECK(a.pixels[i] == 1.0f);
    nacre_image_free(ctx, &a);
    CHECK(nacre_layer_map_generate(ctx, NACRE_LAYER_MAP_SPOTS, 4, 1, &a) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "size") != NULL && a.pixels == NULL);
    nacre_material_desc fish;
    CHECK(nacre_material_preset("fish", &fish) && fish.layering.count == 2);
    CHECK_NEAR(fish.layering.layers[1].sigma_a[0] + fish.layering.layers[1].sigma_s[0], 6.6, 1e-5);
    CHECK_NEAR(fish.sigma_a[2] + fish.sigma_s[2], 2.5, 1e-5);
    CHECK_NEAR(fish.layering.layers[0].g, 0.25, 1e-6);
}

/* examples/layered.json, loaded and committed at time 0 (NULL on failure, which is checked). */
static nacre_scene *load_layered_example(nacre_scene_file_settings *fs)
{
    nacre_scene *s = NULL;
    CHECK(nacre_scene_load_file(ctx, NACRE_SOURCE_DIR "/examples/layered.json", &s, fs) == NACRE_OK);
    if (s)
        CHECK(nacre_scene_commit(s, 0) == NACRE_OK);
    return s;
}

/* Half resolution: a pixel is interpolated only where its marched neighbours agree within the
 * tolerance, so the image stays close to the full one: on the layered sphere of the example (vein
 * map, curved surface, silhouettes), the interpolated pixels' mean relative error stays below the
 * tolerance and the whole object's below a tenth of it; 0 gives the full image. */
static void test_half_res(void)
{
    nacre_scene_file_settings fs;
    nacre_scene *s = load_layered_example(&fs);
    if (!s)
        return;
    nacre_render_settings rs = fs.render;
    rs.method = NACRE_METHOD_LAYERED;
    rs.width = 200;
    rs.height = 150;
    rs.layered.samples = 4;
    rs.layered.integration = NACRE_LAYERED_ANALYTIC;
    CHECK(rs.layered.half_res == 0.05f); /* the default */
    rs.layered.half_res = 0;
    nacre_image full = {0}, half = {0}, phong = {0};
    CHECK(nacre_render(s, &rs, &full, NULL) == NACRE_OK);
    /* The sphere's pixels: the others are phong's */
    nacre_render_settings ps = rs;
    ps.method = NACRE_METHOD_PHONG;
    CHECK(nacre_render(s, &ps, &phong, NULL) == NACRE_OK);
    const float tol[] = {0.02f, 0.05f};
    for (int t = 0; t < 2; t++) {
        rs.layered.half_res = tol[t];
        CHECK(nacre_render(s, &rs, &half, NULL) == NACRE_OK);
        if (!full.pixels || !half.pixels || !phong.pixels)
            break;
        double sum_i = 0, sum_all = 0;
        size_t n_i = 0, n_all = 0;
        for (int32_t y = 0; y < full.height; y++)
            for (int32_t x = 0; x < full.width; x++) {
                const float *a = half.pixels + half.stride * (size_t)y + 3 * (size_t)x;
                const float *b = full.pixels + full.stride * (size_t)y + 3 * (size_t)x;
                const float *f = phong.pixels + phong.stride * (size_t)y + 3 * (size_t)x;
                const bool interpolated = a[0] != b[0] || a[1] != b[1] || a[2] != b[2];
                const bool object = f[0] != b[0] || f[1] != b[1] || f[2] != b[2];
                for (int c = 0; c < 3; c++) {
                    if (!(b[c] > 1e-6f))
                        continue;
                    const double e = fabs((double)a[c] - (double)b[c]) / (double)b[c];
                    if (interpolated) {
                        sum_i += e;
                        n_i++;
                    }
                    if (object) {
                        sum_all += e;
                        n_all++;
                    }
                }
            }
        const double ei = n_i ? sum_i / (double)n_i : 0, ea = n_all ? sum_all / (double)n_all : 0;
        printf("half_res %.2f: %zu interpolated channel values of %zu on the object, mean relative error %.5f "
               "there, %.5f over the object\n",
               (double)tol[t], n_i, n_all, ei, ea);
        CHECK(n_i > n_all / 10); /* the setting does something */
        CHECK(ei < tol[t]);
        CHECK(ea < 0.1 * tol[t]);
    }
    rs.layered.half_res = 0;
    CHECK(nacre_render(s, &rs, &half, NULL) == NACRE_OK);
    CHECK(half.pixels && full.pixels &&
          memcmp(half.pixels, full.pixels, sizeof(float) * full.stride * (size_t)full.height) == 0);
    rs.layered.half_res = 1.0f;
    CHECK(nacre_render(s, &rs, &half, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "layered_half_res") != NULL);
    nacre_image_free(ctx, &full);
    nacre_image_free(ctx, &half);
    nacre_image_free(ctx, &phong);
    nacre_scene_destroy(s);
}

/* Kept view rays: a renderer keeps each pixel's ray (pieces and layer bottoms) while only lights
 * move (made on the second frame after a change, lit again from the third), and drops them after
 * a camera, material or settings change; every frame must be bit for bit the image of a new
 * renderer, which marches from scratch. */
static void test_rays_kept(void)
{
    nacre_scene_file_settings fs;
    nacre_scene *s = load_layered_example(&fs);
    if (!s)
        return;
    nacre_renderer *r = NULL;
    CHECK(nacre_renderer_create(ctx, &r) == NACRE_OK);
    nacre_render_settings rs = fs.render;
    rs.method = NACRE_METHOD_LAYERED;
    rs.width = 160;
    rs.height = 120;
    rs.layered.samples = 2;
    rs.layered.integration = NACRE_LAYERED_ANALYTIC;
    nacre_light_desc ld0, ld;
    CHECK(nacre_scene_get_light(s, (nacre_light){1}, &ld0) == NACRE_OK);
    /* The layered object's material */
    nacre_material layered = {0};
    nacre_material_desc md;
    for (uint32_t i = 1; i <= nacre_scene_object_count(s); i++) {
        nacre_object_desc od;
        if (nacre_scene_get_object(s, (nacre_object){i}, &od) == NACRE_OK &&
            nacre_scene_get_material(s, od.material, &md) == NACRE_OK && md.layering.count > 0)
            layered = od.material;
    }
    CHECK(layered.id != 0);
    nacre_image kept = {0}, fresh = {0};
    size_t differ = 0, checked = 0;
    for (int frame = 0; frame < 15; frame++) {
        /* The light moves every frame; 3: the camera; 6: the layers' depths; 9: 16 steps; 12: 10
         * point samples */
        const float a = 0.05f * (float)frame;
        ld = ld0;
        ld.direction[0] = ld0.direction[0] * cosf(a) - ld0.direction[2] * sinf(a);
        ld.direction[2] = ld0.direction[0] * sinf(a) + ld0.direction[2] * cosf(a);
        CHECK(nacre_scene_set_light(s, (nacre_light){1}, &ld) == NACRE_OK);
        if (frame == 3) {
            nacre_camera_desc cd;
            CHECK(nacre_scene_get_camera(s, &cd) == NACRE_OK);
            cd.position[0] += 3.0f;
            CHECK(nacre_scene_set_camera(s, &cd) == NACRE_OK);
        }
        if (frame == 6 && nacre_scene_get_material(s, layered, &md) == NACRE_OK) {
            md.layering.layers[0].depth *= 1.5f;
            CHECK(nacre_scene_set_material(s, layered, &md) == NACRE_OK);
        }
        if (frame == 9)
            rs.layered.samples = 16;
        if (frame == 12) {
            rs.layered.samples = 10;
            rs.layered.integration = NACRE_LAYERED_SAMPLES;
        }
        CHECK(nacre_scene_commit(s, 0) == NACRE_OK);
        CHECK(nacre_renderer_render(r, s, &rs, &kept, NULL) == NACRE_OK);
        CHECK(nacre_render(s, &rs, &fresh, NULL) == NACRE_OK);
        if (!kept.pixels || !fresh.pixels)
            break;
        for (int32_t y = 0; y < kept.height; y++)
            for (int32_t x = 0; x < 3 * kept.width; x++) {
                differ += kept.pixels[kept.stride * (size_t)y + (size_t)x] != fresh.pixels[fresh.stride * (size_t)y + (size_t)x];
                checked++;
            }
    }
    printf("kept rays: %zu of %zu values differ from new renderers' over 15 frames\n", differ, checked);
    CHECK(checked > 0 && differ == 0);
    nacre_image_free(ctx, &kept);
    nacre_image_free(ctx, &fresh);
    nacre_renderer_destroy(r);
    nacre_scene_destroy(s);
}

int main(void)
{
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    test_flat_layers();
    test_flat_layers_pathtrace();
    test_one_layer_closed_form();
    test_convergence();
    test_planes_cached();
    test_bad_input();
    test_maps_and_fish();
    test_half_res();
    test_rays_kept();
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
