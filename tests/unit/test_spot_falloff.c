/*
 * test_spot_falloff.c: the spot light profiles of scene/lights.h (smooth, cycles, gltf) against
 * their formulas (docs/scene-format.md, "Spot falloff"), the 8-lane form of the phong pass
 * against the scalar one over the whole range of angles, and a spot-lit plane rendered by
 * phong against the analytic radiance per pixel for each profile.
 */
#include <nacre/nacre.h>

#include "scene/lights.h"
#include "core/math.h"
#include "test_util.h"

static const nacre_spot_falloff profiles[3] = {NACRE_SPOT_FALLOFF_SMOOTH, NACRE_SPOT_FALLOFF_CYCLES,
                                               NACRE_SPOT_FALLOFF_GLTF};

/* The profiles as documented, in double: c = cos of the angle from the axis. */
static double reference(nacre_spot_falloff f, double c, double co, double ci)
{
    if (c <= co)
        return 0.0;
    double t = ci <= co ? 1.0 : (c - co) / (ci - co);
    t = t < 0 ? 0 : t > 1 ? 1 : t;
    double s = t * t * (3 - 2 * t);
    switch (f) {
    case NACRE_SPOT_FALLOFF_CYCLES: /* Cycles 2.8-3.x spot_light_attenuation: cos * smoothstep */
        return c * s;
    case NACRE_SPOT_FALLOFF_GLTF: /* KHR_lights_punctual: clamp(t, 0, 1)^2 */
        return t * t;
    default:
        return s;
    }
}

static void test_formulas(void)
{
    const double cones[3][2] = {{10, 25}, {0, 40}, {30, 30}}; /* inner, outer; the last hard */
    for (int k = 0; k < 3; k++) {
        float ci = cosf((float)cones[k][0] * NC_DEG2RAD), co = cosf((float)cones[k][1] * NC_DEG2RAD);
        for (int p = 0; p < 3; p++) {
            double worst = 0;
            for (int i = 0; i <= 900; i++) { /* 0 to 90 degrees by 0.1 */
                float c = cosf((float)i * 0.1f * NC_DEG2RAD);
                worst = fmax(worst, fabs(nc_spot_falloff(profiles[p], c, co, ci) - reference(profiles[p], c, co, ci)));
            }
            CHECK_NEAR(worst, 0, 1e-6);
        }
        /* Known points: the axis, outside the outer cone. */
        CHECK_NEAR(nc_spot_falloff(NACRE_SPOT_FALLOFF_SMOOTH, 1.0f, co, ci), 1, 0);
        CHECK_NEAR(nc_spot_falloff(NACRE_SPOT_FALLOFF_GLTF, 1.0f, co, ci), 1, 0);
        CHECK_NEAR(nc_spot_falloff(NACRE_SPOT_FALLOFF_CYCLES, 1.0f, co, ci), 1, 0);
        for (int p = 0; p < 3; p++)
            CHECK(nc_spot_falloff(profiles[p], co - 1e-3f, co, ci) == 0.0f);
    }
    /* Halfway in cos between the cones: smooth 1/2, gltf 1/4, cycles c / 2. */
    float co = 0.5f, ci = 0.9f;
    CHECK_NEAR(nc_spot_falloff(NACRE_SPOT_FALLOFF_SMOOTH, 0.7f, co, ci), 0.5, 1e-6);
    CHECK_NEAR(nc_spot_falloff(NACRE_SPOT_FALLOFF_GLTF, 0.7f, co, ci), 0.25, 1e-6);
    CHECK_NEAR(nc_spot_falloff(NACRE_SPOT_FALLOFF_CYCLES, 0.7f, co, ci), 0.35, 1e-6);
}

/* The phong pass's 8-lane form and the scalar one, over cos in [-1, 1] and at the cones. */
static void test_vector_form(void)
{
    const float cones[3][2] = {{10, 25}, {0, 89}, {30, 30}};
    for (int k = 0; k < 3; k++) {
        float ci = cosf(cones[k][0] * NC_DEG2RAD), co = cosf(cones[k][1] * NC_DEG2RAD);
        nc_v8i hard = (nc_v8i){0} - (int32_t)(ci <= co);
        for (int p = 0; p < 3; p++) {
            double worst = 0;
            for (int i = 0; i < 200002; i += 8) {
                float c[8];
                for (int j = 0; j < 8; j++)
                    c[j] = i + j == 200000 ? co : i + j == 200001 ? ci : -1.0f + (float)(i + j) * 1e-5f;
                float out[8];
                nc_v8_store(out, nc_spot_falloff8(profiles[p], nc_v8_load(c), co, ci, hard));
                for (int j = 0; j < 8; j++)
                    worst = fmax(worst, fabs(out[j] - nc_spot_falloff(profiles[p], c[j], co, ci)));
            }
            CHECK_NEAR(worst, 0, 1e-6);
        }
    }
}

/* A spot straight down at height h over a 100 x 100 plane (kd, no specular, black environment),
 * seen from above by an orthographic camera: L = kd / pi * I * f(c) * c / d^2 per pixel, with
 * c = h / d both the spot's cosine and the plane's incidence cosine. */
static void test_phong_plane(nacre_spot_falloff falloff)
{
    nacre_context *ctx = NULL;
    nacre_scene *s = NULL;
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    CHECK(nacre_scene_create(ctx, &s) == NACRE_OK);
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_PLANE);
    sd.size[0] = sd.size[2] = 100;
    nacre_mesh_data md = {0};
    nacre_mesh mesh;
    CHECK(nacre_mesh_make_shape(ctx, &sd, &md) == NACRE_OK);
    CHECK(nacre_scene_add_mesh(s, &md, &mesh) == NACRE_OK);
    nacre_mesh_data_free(ctx, &md);
    nacre_material_desc m = nacre_material_desc_defaults(NACRE_MATERIAL_OPAQUE);
    const float kd = 0.6f;
    m.diffuse[0] = m.diffuse[1] = m.diffuse[2] = kd;
    m.specular[0] = m.specular[1] = m.specular[2] = 0.0f;
    nacre_material mat;
    CHECK(nacre_scene_add_material(s, &m, &mat) == NACRE_OK);
    nacre_object_desc od = nacre_object_desc_defaults();
    od.mesh = mesh;
    od.material = mat;
    nacre_object obj;
    CHECK(nacre_scene_add_object(s, &od, &obj) == NACRE_OK);
    const float h = 40.0f, I = 1000.0f, inner = 15.0f, outer = 35.0f;
    nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_SPOT);
    ld.position[0] = ld.position[2] = 0.0f;
    ld.position[1] = h;
    ld.direction[0] = ld.direction[2] = 0.0f;
    ld.direction[1] = -1.0f;
    ld.strength[0] = ld.strength[1] = ld.strength[2] = I;
    ld.inner_angle = inner;
    ld.outer_angle = outer;
    ld.falloff = falloff;
    ld.cast_shadows = false;
    nacre_light light;
    CHECK(nacre_scene_add_light(s, &ld, &light) == NACRE_OK);
    nacre_camera_desc cam = nacre_camera_desc_defaults();
    cam.projection = NACRE_ORTHOGRAPHIC;
    cam.position[0] = 0; cam.position[1] = 50; cam.position[2] = 0;
    cam.target[0] = 0; cam.target[1] = 0; cam.target[2] = 0;
    cam.up[0] = 0; cam.up[1] = 0; cam.up[2] = -1;
    cam.ortho_height = 80;
    CHECK(nacre_scene_set_camera(s, &cam) == NACRE_OK);
    float env[3] = {0, 0, 0};
    CHECK(nacre_scene_set_environment(s, env) == NACRE_OK);
    CHECK(nacre_scene_commit(s, 0) == NACRE_OK);
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = NACRE_METHOD_PHONG;
    rs.width = rs.height = 80; /* one scene unit per pixel, centred: the plane fills the view */
    nacre_image img = {0};
    CHECK(nacre_render(s, &rs, &img, NULL) == NACRE_OK);
    double co = cos(outer * NC_DEG2RAD), ci = cos(inner * NC_DEG2RAD), peak = kd / NC_PI * I / (h * h);
    double worst = 0;
    int lit = 0, dark = 0;
    for (int y = 0; y < img.height; y++)
        for (int x = 0; x < img.width; x++) {
            /* The profile is symmetric about the axis: the signs of the pixel's axes do not matter. */
            double px = x + 0.5 - 40, pz = y + 0.5 - 40, d = sqrt(px * px + pz * pz + (double)h * h), c = h / d;
            double expect = kd / NC_PI * I * reference(falloff, c, co, ci) * c / (d * d);
            double got = img.pixels[(size_t)y * img.stride + 3 * (size_t)x + 1];
            worst = fmax(worst, fabs(got - expect) / peak);
            lit += expect > 0.5 * peak;
            dark += expect == 0;
        }
    CHECK(lit > 100 && dark > 100); /* the view holds the inside, the edge and the outside */
    CHECK_NEAR(worst, 0, 1e-4);
    nacre_image_free(ctx, &img);
    nacre_scene_destroy(s);
    nacre_context_destroy(ctx);
}

int main(void)
{
    test_formulas();
    test_vector_form();
    for (int p = 0; p < 3; p++)
        test_phong_plane(profiles[p]);
    return TEST_MAIN_END();
}
