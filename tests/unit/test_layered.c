/*
 * test_layered.c: point location in layered materials (src/layered): bilinear, repeating depth
 * map lookups against hand-computed texel blends; the layer found at a depth against the
 * running-maximum definition, and the conservative depth-range test (nc_layers_touching) against
 * the layers actually found; nearest surface points (Embree point queries) against closed forms
 * on a box (distance to the nearest face; a search radius short of it finds nothing), a plane (distance and affine uv) and a sphere (R - |p|
 * within the tessellation's sagitta); scene validation of layers and textures with one-line
 * errors naming the field.
 */
#include "test_util.h"

#include "layered/layers.h"

#include <nacre/nacre.h>

static nacre_context *ctx;

static uint64_t rng_state = 0x9e3779b97f4a7c15ull;
static double urand(void)
{
    rng_state = rng_state * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(rng_state >> 11) * (1.0 / 9007199254740992.0);
}

/* A 3 x 2 texture of 2 channels with distinct values. */
static nacre_texture small_texture(nacre_scene *s, const nc_texture_rec **rec)
{
    float px[3 * 2 * 2];
    for (int i = 0; i < 12; i++)
        px[i] = (float)(i * i % 7) + 0.25f * (float)i;
    nacre_image img = {3, 2, 2, 6, px};
    nacre_texture t = {0};
    CHECK(nacre_scene_add_texture(s, &img, &t) == NACRE_OK);
    *rec = nc_scene_texture(s, t);
    CHECK(*rec != NULL);
    return t;
}

static float texel(const nc_texture_rec *t, int x, int y, int c)
{
    x = ((x % t->width) + t->width) % t->width;
    y = ((y % t->height) + t->height) % t->height;
    return t->data[(size_t)t->channels * ((size_t)x + (size_t)t->width * (size_t)y) + (size_t)c];
}

static void test_texture_sampling(void)
{
    nacre_scene *s = NULL;
    CHECK(nacre_scene_create(ctx, &s) == NACRE_OK);
    const nc_texture_rec *t = NULL;
    small_texture(s, &t);
    /* Texel centres give the texel exactly; v grows upwards (row 0 is v near 1). */
    for (int y = 0; y < 2; y++)
        for (int x = 0; x < 3; x++)
            for (int c = 0; c < 2; c++) {
                float u = (x + 0.5f) / 3, v = 1 - (y + 0.5f) / 2;
                CHECK_NEAR(nc_texture_sample(t, c, u, v), texel(t, x, y, c), 1e-5);
                /* One period away is the same point. */
                CHECK_NEAR(nc_texture_sample(t, c, u + 2, v - 3), texel(t, x, y, c), 1e-4);
            }
    /* Halfway between texels 2 and 0 of a row (across the seam): their average. */
    float v0 = 1 - 0.5f / 2;
    CHECK_NEAR(nc_texture_sample(t, 1, 1.0f, v0), 0.5 * (texel(t, 2, 0, 1) + texel(t, 0, 0, 1)), 1e-5);
    /* A general point: the bilinear blend of its four texels. */
    for (int k = 0; k < 50; k++) {
        float u = (float)(urand() * 4 - 2), v = (float)(urand() * 4 - 2);
        double fx = (u - floor(u)) * 3 - 0.5, fy = (1 - (v - floor(v))) * 2 - 0.5;
        int x0 = (int)floor(fx), y0 = (int)floor(fy);
        double ax = fx - x0, ay = fy - y0;
        double want = (1 - ay) * ((1 - ax) * texel(t, x0, y0, 0) + ax * texel(t, x0 + 1, y0, 0)) +
                      ay * ((1 - ax) * texel(t, x0, y0 + 1, 0) + ax * texel(t, x0 + 1, y0 + 1, 0));
        CHECK_NEAR(nc_texture_sample(t, 0, u, v), want, 1e-4);
    }
    /* Non-finite uv reads a texel, never out of bounds. */
    CHECK(isfinite(nc_texture_sample(t, 0, NAN, INFINITY)));
    nacre_scene_destroy(s);
}

static nacre_layering layering(uint32_t count, const float *depths)
{
    nacre_layering l;
    memset(&l, 0, sizeof(l));
    l.count = count;
    for (uint32_t j = 0; j < count; j++) {
        for (int c = 0; c < 3; c++) {
            l.layers[j].sigma_a[c] = 0.1f * (float)(j + 1);
            l.layers[j].sigma_s[c] = 1.0f;
        }
        l.layers[j].depth = depths[j];
    }
    return l;
}

static void test_find_and_touching(void)
{
    nacre_scene *s = NULL;
    CHECK(nacre_scene_create(ctx, &s) == NACRE_OK);
    /* Constant layers: boundaries belong to the deeper layer. */
    const float d3[3] = {0.5f, 1.0f, 2.5f};
    nacre_layering l = layering(3, d3);
    nc_layer_stack st;
    nc_layers_init(s, &l, &st);
    CHECK(nc_layers_find(&st, 0.0f, 0, 0) == 0);
    CHECK(nc_layers_find(&st, 0.49f, 0, 0) == 0);
    CHECK(nc_layers_find(&st, 0.5f, 0, 0) == 1);
    CHECK(nc_layers_find(&st, 2.4f, 0, 0) == 2);
    CHECK(nc_layers_find(&st, 2.5f, 0, 0) == 3); /* the core */
    CHECK(nc_layers_find(&st, 100.0f, 0, 0) == 3);
    CHECK(nc_layers_touching(&st, 0.6f, 0.9f) == 2u);
    CHECK(nc_layers_touching(&st, 0.4f, 1.1f) == 7u);
    CHECK(nc_layers_touching(&st, 3.0f, 4.0f) == 8u);

    /* With a map: bottom(j) = max_k<=j depth_k * map_k(uv). */
    const nc_texture_rec *t = NULL;
    float dm[2] = {0.3f, 0.2f};
    l = layering(2, dm);
    l.depth_map = small_texture(s, &t);
    nc_layers_init(s, &l, &st);
    for (int k = 0; k < 2000; k++) {
        float u = (float)urand(), v = (float)urand(), d = (float)(urand() * 3.5);
        float b0 = 0.3f * nc_texture_sample(t, 0, u, v);
        float b1 = fmaxf(b0, 0.2f * nc_texture_sample(t, 1, u, v));
        uint32_t want = d < b0 ? 0u : d < b1 ? 1u : 2u;
        uint32_t got = nc_layers_find(&st, d, u, v);
        CHECK(got == want);
        /* Every layer a depth range can reach is reported (conservative). */
        float r = (float)(urand() * 0.3);
        CHECK((nc_layers_touching(&st, d - r, d + r) >> got) & 1u);
    }
    nacre_scene_destroy(s);
}

static nacre_mesh_data shape(nacre_shape_type type, float a, uint32_t segments, uint32_t rings)
{
    nacre_shape_desc sd = nacre_shape_desc_defaults(type);
    if (type == NACRE_SHAPE_SPHERE) {
        sd.radius = a;
        sd.rings = rings;
    } else {
        sd.size[0] = sd.size[1] = sd.size[2] = a;
    }
    sd.segments = segments;
    nacre_mesh_data m = {0};
    CHECK(nacre_mesh_make_shape(ctx, &sd, &m) == NACRE_OK);
    return m;
}

static void test_locator(void)
{
#ifdef NACRE_HAVE_EMBREE
    RTCDevice dev = rtcNewDevice("threads=1");
    CHECK(dev != NULL);

    /* Box of side 2: the depth of an inside point is its distance to the nearest face. */
    nacre_mesh_data box = shape(NACRE_SHAPE_BOX, 2.0f, 3, 0);
    nc_surface_locator *loc = NULL;
    CHECK(nc_locator_create(ctx, dev, &box, &loc) == NACRE_OK);
    double worst = 0;
    for (int k = 0; k < 500; k++) {
        float p[3], uv[2];
        double want = INFINITY;
        for (int a = 0; a < 3; a++) {
            p[a] = (float)(urand() * 1.98 - 0.99);
            want = fmin(want, 1.0 - fabs(p[a]));
        }
        worst = fmax(worst, fabs(nc_locator_nearest(loc, p, INFINITY, NULL, uv) - want));
        /* A search radius short of the depth finds nothing; one past it finds the same. */
        CHECK(nc_locator_nearest(loc, p, (float)want * 0.99f, NULL, uv) == INFINITY);
        CHECK_NEAR(nc_locator_nearest(loc, p, (float)want * 1.01f + 1e-6f, NULL, uv), want, 1e-5);
    }
    printf("  box: worst depth error %.2e\n", worst);
    CHECK(worst < 1e-5);
    nc_locator_destroy(ctx, loc);
    nacre_mesh_data_free(ctx, &box);

    /* Plane (y = 0, 2 x 2): distance |y| above it, and uv the affine function the mesh's own
     * vertices define, at the foot of the perpendicular. */
    nacre_shape_desc pd = nacre_shape_desc_defaults(NACRE_SHAPE_PLANE);
    pd.size[0] = pd.size[2] = 2.0f;
    pd.segments = 4;
    nacre_mesh_data plane = {0};
    CHECK(nacre_mesh_make_shape(ctx, &pd, &plane) == NACRE_OK);
    CHECK(nc_locator_create(ctx, dev, &plane, &loc) == NACRE_OK);
    /* The affine map from the first triangle. */
    const uint32_t *tri = plane.indices;
    const float *P[3], *T[3];
    for (int i = 0; i < 3; i++) {
        P[i] = plane.positions + 3 * tri[i];
        T[i] = plane.uvs + 2 * tri[i];
    }
    double e1x = P[1][0] - P[0][0], e1z = P[1][2] - P[0][2], e2x = P[2][0] - P[0][0], e2z = P[2][2] - P[0][2];
    double det = e1x * e2z - e2x * e1z;
    worst = 0;
    double worst_uv = 0;
    for (int k = 0; k < 300; k++) {
        float p[3] = {(float)(urand() * 1.9 - 0.95), (float)(urand() * 0.8 + 0.05), (float)(urand() * 1.9 - 0.95)};
        float uv[2];
        worst = fmax(worst, fabs(nc_locator_nearest(loc, p, INFINITY, NULL, uv) - p[1]));
        double dx = p[0] - P[0][0], dz = p[2] - P[0][2];
        double b1 = (dx * e2z - e2x * dz) / det, b2 = (e1x * dz - dx * e1z) / det;
        for (int c = 0; c < 2; c++) {
            double want = T[0][c] + b1 * (T[1][c] - T[0][c]) + b2 * (T[2][c] - T[0][c]);
            worst_uv = fmax(worst_uv, fabs(uv[c] - want));
        }
    }
    printf("  plane: worst depth error %.2e, uv error %.2e\n", worst, worst_uv);
    CHECK(worst < 1e-5);
    CHECK(worst_uv < 1e-5);
    nc_locator_destroy(ctx, loc);
    nacre_mesh_data_free(ctx, &plane);

    /* Sphere of radius 1, 128 x 64: the mesh lies between R cos(pi/64)-ish and R, so the depth
     * is R - |p| within the sagitta (1 - cos(pi / 64) < 1.3e-3). */
    nacre_mesh_data sph = shape(NACRE_SHAPE_SPHERE, 1.0f, 128, 64);
    CHECK(nc_locator_create(ctx, dev, &sph, &loc) == NACRE_OK);
    worst = 0;
    for (int k = 0; k < 300; k++) {
        float p[3], uv[2];
        double r2;
        do {
            for (int a = 0; a < 3; a++)
                p[a] = (float)(urand() * 2 - 1);
            r2 = (double)p[0] * p[0] + (double)p[1] * p[1] + (double)p[2] * p[2];
        } while (r2 > 0.95 * 0.95);
        worst = fmax(worst, fabs(nc_locator_nearest(loc, p, INFINITY, NULL, uv) - (1.0 - sqrt(r2))));
    }
    printf("  sphere: worst |depth - (R - |p|)| %.2e\n", worst);
    CHECK(worst < 1.3e-3);
    nc_locator_destroy(ctx, loc);
    nacre_mesh_data_free(ctx, &sph);
    rtcReleaseDevice(dev);
#else
    printf("  locator: skipped (built without Embree)\n");
#endif
}

static void expect_error(nacre_scene *s, const nacre_material_desc *md, const char *needle)
{
    nacre_material m;
    nacre_result r = nacre_scene_add_material(s, md, &m);
    const char *msg = nacre_context_last_error(ctx);
    CHECK(r == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(msg, needle) != NULL);
    if (!strstr(msg, needle))
        printf("  got \"%s\", want \"%s\"\n", msg, needle);
}

static void test_validation(void)
{
    nacre_scene *s = NULL;
    CHECK(nacre_scene_create(ctx, &s) == NACRE_OK);
    const float d2[2] = {0.5f, 1.0f};
    nacre_material_desc md = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
    md.layering = layering(2, d2);
    nacre_material ok;
    CHECK(nacre_scene_add_material(s, &md, &ok) == NACRE_OK);

    nacre_material_desc bad = md;
    bad.layering.count = 5;
    expect_error(s, &bad, "material: layers: at most 4");
    bad = md;
    bad.layering.layers[1].depth = -1;
    expect_error(s, &bad, "material: layers[1].depth");
    bad = md;
    bad.layering.layers[0].sigma_s[2] = NAN;
    expect_error(s, &bad, "material: layers[0].sigma_s");
    bad = md;
    bad.layering.layers[0].sigma_a[1] = 0, bad.layering.layers[0].sigma_s[1] = 0;
    expect_error(s, &bad, "material: layers[0].sigma_a + sigma_s");
    bad = md;
    bad.layering.layers[1].g = 1.0f;
    expect_error(s, &bad, "material: layers[1].g");
    bad = md;
    bad.layering.depth_map.id = 9;
    expect_error(s, &bad, "material: depth_map: invalid handle 9");
    /* One channel for two layers. */
    float px[4] = {1, 2, 3, 4};
    nacre_image grey = {2, 2, 1, 2, px};
    nacre_texture t;
    CHECK(nacre_scene_add_texture(s, &grey, &t) == NACRE_OK);
    bad = md;
    bad.layering.depth_map = t;
    expect_error(s, &bad, "material: depth_map: 1 channel(s) for 2 layers");

    /* Textures: shape and values. */
    px[2] = -1;
    CHECK(nacre_scene_add_texture(s, &grey, &t) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "texture: pixel (0, 1) channel 0") != NULL);
    px[2] = 3;
    nacre_image wide = {2, 2, 5, 10, px};
    CHECK(nacre_scene_add_texture(s, &wide, &t) == NACRE_ERROR_INVALID_ARGUMENT);
    nacre_image short_stride = {2, 2, 1, 1, px};
    CHECK(nacre_scene_add_texture(s, &short_stride, &t) == NACRE_ERROR_INVALID_ARGUMENT);
    nacre_scene_destroy(s);
}

int main(void)
{
    nacre_context_desc cd = {0};
    cd.threads = 2;
    CHECK(nacre_context_create(&cd, &ctx) == NACRE_OK);
    test_texture_sampling();
    test_find_and_touching();
    test_locator();
    test_validation();
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
