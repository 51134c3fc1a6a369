/*
 * test_render.c: the phong method against closed-form radiance, shadows through the whole
 * pipeline, the renderer's stage caches, thread-count independence, reuse of the previous frame's
 * background (reuse_output) and render errors.
 */
#include "scene/scene.h"
#include "shade/shade.h"
#include "core/optics.h"
#include "test_util.h"

#include <string.h>

typedef struct fixture {
    nacre_context *ctx;
    nacre_scene *scene;
    nacre_material ground_mat;
    nacre_object ground;
    nacre_light light;
    nacre_material_desc ground_desc;
} fixture;

static nacre_mesh add_shape(fixture *f, nacre_shape_desc sd)
{
    nacre_mesh_data md = {0};
    nacre_mesh mesh = {0};
    CHECK(nacre_mesh_make_shape(f->ctx, &sd, &md) == NACRE_OK);
    CHECK(nacre_scene_add_mesh(f->scene, &md, &mesh) == NACRE_OK);
    nacre_mesh_data_free(f->ctx, &md);
    return mesh;
}

/* A 100x100 plane at y = 0, seen from straight above by an orthographic camera. */
static void make_plane_scene(fixture *f, int threads, float light_angle_deg)
{
    nacre_context_desc cd = {0};
    cd.threads = threads;
    CHECK(nacre_context_create(&cd, &f->ctx) == NACRE_OK);
    CHECK(nacre_scene_create(f->ctx, &f->scene) == NACRE_OK);
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_PLANE);
    sd.size[0] = sd.size[2] = 100;
    nacre_mesh plane = add_shape(f, sd);
    f->ground_desc = nacre_material_desc_defaults(NACRE_MATERIAL_OPAQUE);
    f->ground_desc.diffuse[0] = 0.5f;
    f->ground_desc.diffuse[1] = 0.25f;
    f->ground_desc.diffuse[2] = 0.75f;
    f->ground_desc.specular[0] = f->ground_desc.specular[1] = f->ground_desc.specular[2] = 0.1f;
    f->ground_desc.shininess = 20;
    CHECK(nacre_scene_add_material(f->scene, &f->ground_desc, &f->ground_mat) == NACRE_OK);
    nacre_object_desc od = nacre_object_desc_defaults();
    od.mesh = plane;
    od.material = f->ground_mat;
    CHECK(nacre_scene_add_object(f->scene, &od, &f->ground) == NACRE_OK);
    nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
    float a = light_angle_deg * NC_DEG2RAD;
    ld.direction[0] = sinf(a);
    ld.direction[1] = -cosf(a);
    ld.direction[2] = 0;
    ld.strength[0] = ld.strength[1] = ld.strength[2] = 2.0f;
    CHECK(nacre_scene_add_light(f->scene, &ld, &f->light) == NACRE_OK);
    nacre_camera_desc cam = nacre_camera_desc_defaults();
    cam.projection = NACRE_ORTHOGRAPHIC;
    cam.position[0] = 0; cam.position[1] = 50; cam.position[2] = 0;
    cam.target[0] = 0; cam.target[1] = 0; cam.target[2] = 0;
    cam.up[0] = 0; cam.up[1] = 0; cam.up[2] = -1;
    cam.ortho_height = 60;
    CHECK(nacre_scene_set_camera(f->scene, &cam) == NACRE_OK);
    float env[3] = {0.1f, 0.2f, 0.3f};
    CHECK(nacre_scene_set_environment(f->scene, env) == NACRE_OK);
}

static void free_fixture(fixture *f)
{
    nacre_scene_destroy(f->scene);
    nacre_context_destroy(f->ctx);
}

static void test_phong_closed_form(float angle_deg)
{
    fixture f;
    make_plane_scene(&f, 0, angle_deg);
    CHECK(nacre_scene_commit(f.scene, 0) == NACRE_OK);
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.width = 64;
    rs.height = 48;
    nacre_image img = {0};
    CHECK(nacre_render(f.scene, &rs, &img, NULL) == NACRE_OK);
    /* L = E cos(t) (kd/pi + ks (s+8)/(8 pi) cos^s(t/2)) + kd L_env: view and normal are +y,
     * the half vector sits at t/2 from the normal. */
    float t = angle_deg * NC_DEG2RAD, s = f.ground_desc.shininess;
    const float env[3] = {0.1f, 0.2f, 0.3f};
    double worst = 0;
    for (int c = 0; c < 3; c++) {
        double kd = f.ground_desc.diffuse[c], ks = f.ground_desc.specular[c];
        double expect = 2.0 * cos(t) * (kd / NC_PI + ks * (s + 8) / (8 * NC_PI) * pow(cos(t / 2), s)) + kd * env[c];
        for (int y = 0; y < img.height; y++)
            for (int x = 0; x < img.width; x++)
                worst = fmax(worst, fabs(img.pixels[(size_t)y * img.stride + 3 * (size_t)x + c] - expect) / expect);
    }
    CHECK(worst < 1e-4);
    nacre_image_free(f.ctx, &img);
    free_fixture(&f);
}

/* A box floating above the plane casts a shadow where the analytic projection says. */
static void test_shadow_and_caches(void)
{
    fixture f;
    make_plane_scene(&f, 0, 0);
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_BOX);
    sd.size[0] = sd.size[1] = sd.size[2] = 10;
    nacre_mesh box = add_shape(&f, sd);
    nacre_object_desc od = nacre_object_desc_defaults();
    od.mesh = box;
    od.material = f.ground_mat;
    od.transform.translate[1] = 20;
    nacre_object obj;
    CHECK(nacre_scene_add_object(f.scene, &od, &obj) == NACRE_OK);
    /* Render fails until committed. */
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.width = 120;
    rs.height = 120;
    nacre_image img = {0};
    CHECK(nacre_render(f.scene, &rs, &img, NULL) == NACRE_ERROR_INVALID_OPERATION);
    CHECK(img.pixels == NULL);
    CHECK(nacre_scene_commit(f.scene, 0) == NACRE_OK);
    /* The camera sees 60 units over 120 pixels: 0.5 units per pixel. Look along the row
     * through the centre, away from the box itself (which is seen from above at x,z in
     * [-5, 5]): with the light straight down the shadow coincides with the box's footprint,
     * so tilt the light by 45 degrees: the shadow moves by 20 units along +x. */
    nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
    ld.direction[0] = 1;
    ld.direction[1] = -1;
    ld.direction[2] = 0;
    ld.strength[0] = ld.strength[1] = ld.strength[2] = 2.0f;
    CHECK(nacre_scene_set_light(f.scene, f.light, &ld) == NACRE_OK);
    CHECK(nacre_scene_commit(f.scene, 0) == NACRE_OK);
    nacre_renderer *r = NULL;
    CHECK(nacre_renderer_create(f.ctx, &r) == NACRE_OK);
    nacre_render_stats st;
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    CHECK(st.stage_ran[NACRE_STAGE_RASTER] && st.shadow_maps == 1);
    /* The box's bottom face (y = 15) projects to x in [15-5+... ]: points on the ground at
     * x in [5+15, 5+25]... precisely: the box spans x in [-5,5], y in [15,25]; light travels
     * (+1,-1): its shadow on y = 0 covers x in [-5+15, 5+25] = [10, 30], z in [-5, 5]. */
    int row = 60; /* z = 0 */
    int shadowed = 0, lit = 0;
    for (int x = 0; x < 120; x++) {
        float wx = (x + 0.5f) * 0.5f - 30.0f;
        float v = img.pixels[(size_t)row * img.stride + 3 * (size_t)x + 0];
        bool in_box_view = fabsf(wx) < 5.5f;
        if (in_box_view)
            continue;
        bool expect_shadow = wx > 10.5f && wx < 29.5f;
        bool expect_lit = wx < 9.0f || wx > 31.0f;
        float ambient = f.ground_desc.diffuse[0] * 0.1f;
        if (expect_shadow)
            shadowed += fabsf(v - ambient) < 1e-4f;
        if (expect_lit)
            lit += v > ambient + 0.1f;
        if (expect_shadow && fabsf(v - ambient) >= 1e-4f)
            printf("pixel %d (x=%.2f) not shadowed: %g\n", x, wx, v);
    }
    CHECK(shadowed == 38);  /* x in (10.5, 29.5): 38 pixel centres */
    CHECK(lit >= 40);

    /* Caches: nothing changed -> nothing but shading reruns. */
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    CHECK(!st.stage_ran[NACRE_STAGE_RASTER] && !st.stage_ran[NACRE_STAGE_GBUFFER] && st.shadow_maps == 0);
    /* Material edit: still no raster, no shadow map. */
    f.ground_desc.diffuse[0] = 0.9f;
    CHECK(nacre_scene_set_material(f.scene, f.ground_mat, &f.ground_desc) == NACRE_OK);
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_ERROR_INVALID_OPERATION);
    CHECK(nacre_scene_commit(f.scene, 0) == NACRE_OK);
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    CHECK(!st.stage_ran[NACRE_STAGE_RASTER] && st.shadow_maps == 0);
    /* Light edit: the shadow map is redrawn, the G-buffer kept. */
    ld.direction[0] = 0.5f;
    CHECK(nacre_scene_set_light(f.scene, f.light, &ld) == NACRE_OK);
    CHECK(nacre_scene_commit(f.scene, 0) == NACRE_OK);
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    CHECK(!st.stage_ran[NACRE_STAGE_RASTER] && st.shadow_maps == 1);
    /* Camera edit: G-buffer redrawn, shadow map kept. */
    nacre_camera_desc cam = f.scene->camera;
    cam.ortho_height = 70;
    CHECK(nacre_scene_set_camera(f.scene, &cam) == NACRE_OK);
    CHECK(nacre_scene_commit(f.scene, 0) == NACRE_OK);
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    CHECK(st.stage_ran[NACRE_STAGE_RASTER] && st.shadow_maps == 0);
    /* Geometry edit: everything. */
    od.transform.translate[1] = 21;
    CHECK(nacre_scene_set_object(f.scene, obj, &od) == NACRE_OK);
    CHECK(nacre_scene_commit(f.scene, 0) == NACRE_OK);
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    CHECK(st.stage_ran[NACRE_STAGE_RASTER] && st.shadow_maps == 1);

    /* Invalid settings. */
    rs.method = NACRE_METHOD_LAYERED;
    rs.layered.samples = 0;
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(f.ctx), "layered_samples") != NULL);
    rs.layered.samples = 16;
    rs.method = NACRE_METHOD_PHONG;
    rs.width = 0;
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_ERROR_INVALID_ARGUMENT);
    nacre_renderer_destroy(r);
    nacre_image_free(f.ctx, &img);
    free_fixture(&f);
}

/* Same image with 1 and 2 threads. */
static void test_thread_independence(void)
{
    nacre_image imgs[2] = {{0}, {0}};
    nacre_context *ctxs[2];
    for (int i = 0; i < 2; i++) {
        fixture f;
        make_plane_scene(&f, i + 1, 30);
        nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_TORUS);
        sd.radius = 15;
        sd.minor_radius = 5;
        nacre_mesh torus = add_shape(&f, sd);
        nacre_object_desc od = nacre_object_desc_defaults();
        od.mesh = torus;
        od.material = f.ground_mat;
        od.transform.translate[1] = 10;
        od.transform.rotate[0] = 60;
        nacre_object obj;
        CHECK(nacre_scene_add_object(f.scene, &od, &obj) == NACRE_OK);
        CHECK(nacre_scene_commit(f.scene, 0) == NACRE_OK);
        nacre_render_settings rs = nacre_render_settings_defaults();
        rs.width = 97;
        rs.height = 71;
        CHECK(nacre_render(f.scene, &rs, &imgs[i], NULL) == NACRE_OK);
        nacre_scene_destroy(f.scene);
        ctxs[i] = f.ctx;
    }
    CHECK(memcmp(imgs[0].pixels, imgs[1].pixels, sizeof(float) * 97 * 71 * 3) == 0);
    for (int i = 0; i < 2; i++) {
        nacre_image_free(ctxs[i], &imgs[i]);
        nacre_context_destroy(ctxs[i]);
    }
}

/* reuse_output: a renderer that writes only what changed into the image it wrote last must give
 * the same images as one that repaints every frame, while the object moves (pixels it leaves are
 * background again), the environment changes, and the caller switches buffers. */
static void test_reuse_output(nacre_method method, int threads)
{
    nacre_context_desc cd = {0};
    cd.threads = threads;
    nacre_context *ctx = NULL;
    nacre_scene *scene = NULL;
    CHECK(nacre_context_create(&cd, &ctx) == NACRE_OK);
    CHECK(nacre_scene_create(ctx, &scene) == NACRE_OK);
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_TORUS);
    sd.radius = 10;
    sd.minor_radius = 4;
    nacre_mesh_data md = {0};
    nacre_mesh mesh;
    CHECK(nacre_mesh_make_shape(ctx, &sd, &md) == NACRE_OK);
    CHECK(nacre_scene_add_mesh(scene, &md, &mesh) == NACRE_OK);
    nacre_mesh_data_free(ctx, &md);
    nacre_material_desc jade;
    CHECK(nacre_material_preset("jade", &jade));
    nacre_material mat;
    CHECK(nacre_scene_add_material(scene, &jade, &mat) == NACRE_OK);
    nacre_object_desc od = nacre_object_desc_defaults();
    od.mesh = mesh;
    od.material = mat;
    od.transform.rotate[0] = 70; /* the hole shows: background inside the object's row spans */
    nacre_object obj;
    CHECK(nacre_scene_add_object(scene, &od, &obj) == NACRE_OK);
    nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
    ld.direction[0] = -0.5f;
    ld.direction[1] = -0.7f;
    ld.direction[2] = -0.5f;
    ld.strength[0] = ld.strength[1] = ld.strength[2] = 3.0f;
    nacre_light light;
    CHECK(nacre_scene_add_light(scene, &ld, &light) == NACRE_OK);
    nacre_camera_desc cam = nacre_camera_desc_defaults();
    cam.position[0] = 0; cam.position[1] = 0; cam.position[2] = 70;
    cam.target[0] = 0; cam.target[1] = 0; cam.target[2] = 0;
    cam.fov_y = 40;
    CHECK(nacre_scene_set_camera(scene, &cam) == NACRE_OK);
    float env[3] = {0.1f, 0.2f, 0.3f};
    CHECK(nacre_scene_set_environment(scene, env) == NACRE_OK);

    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = method;
    rs.width = 96;
    rs.height = 64;
    rs.diffusion.voxel_resolution = 8;
    nacre_render_settings full = rs;
    rs.reuse_output = true;
    nacre_renderer *r = NULL, *ref = NULL;
    CHECK(nacre_renderer_create(ctx, &r) == NACRE_OK);
    CHECK(nacre_renderer_create(ctx, &ref) == NACRE_OK);
    nacre_image img = {0}, other = {0}, want = {0};
    CHECK(nacre_image_alloc(ctx, rs.width, rs.height, 3, &other) == NACRE_OK);
    const size_t bytes = sizeof(float) * (size_t)rs.width * (size_t)rs.height * 3;
    /* Frames: the torus moves right, then up-left (uncovering pixels of earlier frames), stays,
     * the environment changes, and the last frame goes to another buffer. */
    const float xs[] = {-12, 0, 14, -8, -8, -8, -8}, ys[] = {0, 3, -4, 8, 8, 8, 8};
    for (int frame = 0; frame < 7; frame++) {
        od.transform.translate[0] = xs[frame];
        od.transform.translate[1] = ys[frame];
        CHECK(nacre_scene_set_object(scene, obj, &od) == NACRE_OK);
        if (frame == 5) {
            env[0] = 0.4f;
            CHECK(nacre_scene_set_environment(scene, env) == NACRE_OK);
        }
        CHECK(nacre_scene_commit(scene, 0) == NACRE_OK);
        nacre_image *out = &img;
        if (frame == 6) {
            for (size_t i = 0; i < bytes / sizeof(float); i++)
                other.pixels[i] = 7.0f; /* not the environment */
            out = &other;
        }
        CHECK(nacre_renderer_render(r, scene, &rs, out, NULL) == NACRE_OK);
        CHECK(nacre_renderer_render(ref, scene, &full, &want, NULL) == NACRE_OK);
        size_t background = 0;
        for (size_t i = 0; i < bytes / sizeof(float); i += 3)
            background += want.pixels[i] == env[0] && want.pixels[i + 1] == env[1] && want.pixels[i + 2] == env[2];
        CHECK(background > 1000 && background < (size_t)rs.width * (size_t)rs.height - 500);
        if (memcmp(out->pixels, want.pixels, bytes) != 0) {
            fprintf(stderr, "test_reuse_output: %s, %d threads: frame %d differs from a full repaint\n",
                    nacre_method_name(method), threads, frame);
            CHECK(false);
        }
    }
    nacre_image_free(ctx, &img);
    nacre_image_free(ctx, &other);
    nacre_image_free(ctx, &want);
    nacre_renderer_destroy(r);
    nacre_renderer_destroy(ref);
    nacre_scene_destroy(scene);
    nacre_context_destroy(ctx);
}

static void test_dipole(void)
{
    /* Jensen et al. 2001: Rd for alpha' = 0.99 with eta = 1 is about 0.77; eta = 1.3 lowers it.
     * Fdr at eta = 1 is ~0 (the fit gives 0.0016). */
    CHECK_NEAR(nc_fresnel_fdr(1.0), 0.0016, 1e-4);
    double rd = nc_dipole_rd(0.99, 1.0);
    double A = (1 + nc_fresnel_fdr(1.0)) / (1 - nc_fresnel_fdr(1.0));
    double s = sqrt(3 * 0.01);
    CHECK_NEAR(rd, 0.495 * (1 + exp(-4.0 / 3.0 * A * s)) * exp(-s), 1e-12);
    CHECK(nc_dipole_rd(0.99, 1.3) < rd);
    CHECK(nc_dipole_rd(0.5, 1.3) < nc_dipole_rd(0.9, 1.3));
}

/* The same scene in mm, cm and m (lengths divided by 1, 10, 1000; a directional light and the
 * environment, whose radiance does not depend on the unit) renders the same image with the
 * diffusion method: the translucent default and the presets are per millimetre and must be
 * converted. A "translucent" material without coefficients kept jade's per-mm values in cm and m
 * scenes (ten and a thousand times too clear). */
static void test_units(void)
{
    static const char *const names[] = {"mm", "cm", "m"};
    const double mm[] = {1.0, 10.0, 1000.0};
    nacre_image img[3];
    memset(img, 0, sizeof(img));
    nacre_context *ctx = NULL;
    nacre_context_desc cd = {0};
    cd.threads = 2;
    CHECK(nacre_context_create(&cd, &ctx) == NACRE_OK);
    for (int u = 0; u < 3; u++) {
        double k = 1.0 / mm[u];
        char json[2048];
        snprintf(json, sizeof(json),
                 "{\"units\": \"%s\", \"render\": {\"width\": 48, \"height\": 32, \"voxel_resolution\": 16},\n"
                 " \"camera\": {\"position\": [0, %.9g, %.9g], \"target\": [0, 0, 0], \"fov\": 40},\n"
                 " \"environment\": [0.1, 0.1, 0.1],\n"
                 " \"materials\": {\"plain\": {\"type\": \"translucent\"}, \"milk\": {\"preset\": \"wholemilk\"},\n"
                 "   \"set\": {\"type\": \"translucent\", \"sigma_a\": [%.9g, %.9g, %.9g], \"sigma_s\": [%.9g, %.9g, %.9g]}},\n"
                 " \"lights\": [{\"type\": \"directional\", \"direction\": [0.3, -1, -0.4], \"irradiance\": [2, 2, 2]}],\n"
                 " \"objects\": [\n"
                 "  {\"shape\": {\"type\": \"sphere\", \"radius\": %.9g}, \"material\": \"plain\",\n"
                 "   \"transform\": {\"translate\": [%.9g, 0, 0]}},\n"
                 "  {\"shape\": {\"type\": \"sphere\", \"radius\": %.9g}, \"material\": \"milk\"},\n"
                 "  {\"shape\": {\"type\": \"sphere\", \"radius\": %.9g}, \"material\": \"set\",\n"
                 "   \"transform\": {\"translate\": [%.9g, 0, 0]}}]}\n",
                 names[u], 5 * k, 40 * k, 0.02 * mm[u], 0.05 * mm[u], 0.1 * mm[u], 1.0 * mm[u], 1.2 * mm[u],
                 1.5 * mm[u], 4 * k, -9 * k, 4 * k, 4 * k, 9 * k);
        nacre_scene *scene = NULL;
        nacre_scene_file_settings fs;
        nacre_result r = nacre_scene_load_json(ctx, json, strlen(json), "units.json", ".", &scene, &fs);
        nacre_render_settings rs = fs.render;
        CHECK(r == NACRE_OK);
        if (r != NACRE_OK) {
            printf("units %s: %s\n", names[u], nacre_context_last_error(ctx));
            continue;
        }
        CHECK(nacre_scene_commit(scene, 0.0) == NACRE_OK);
        rs.method = NACRE_METHOD_DIFFUSION;
        CHECK(nacre_render(scene, &rs, &img[u], NULL) == NACRE_OK);
        nacre_scene_destroy(scene);
    }
    for (int u = 1; u < 3; u++) {
        if (!img[0].pixels || !img[u].pixels)
            continue;
        double worst = 0, sum = 0, diff = 0;
        size_t n = (size_t)img[0].width * (size_t)img[0].height * 3;
        for (size_t i = 0; i < n; i++) {
            double d = fabs((double)img[u].pixels[i] - img[0].pixels[i]);
            worst = d > worst ? d : worst;
            diff += d;
            sum += fabs((double)img[0].pixels[i]);
        }
        /* Float rounding of the scaled geometry moves a few silhouette and voxel-boundary pixels. */
        CHECK(diff / sum < 2e-3);
        if (!(diff / sum < 2e-3))
            printf("units %s vs mm: mean relative difference %.3g, max %.3g\n", names[u], diff / sum, worst);
    }
    for (int u = 0; u < 3; u++)
        nacre_image_free(ctx, &img[u]);

    /* The C API: presets and the default are per millimetre; per_unit converts core and layers. */
    nacre_material_desc d, e;
    CHECK(nacre_material_preset("marble", &d));
    e = d;
    e.layering.count = 1;
    e.layering.layers[0].sigma_a[0] = 0.5f;
    e.layering.layers[0].sigma_s[1] = 2.0f;
    e.layering.layers[0].depth = 0.25f;
    float cm = 0;
    CHECK(nacre_units_mm("cm", &cm) && cm == 10.0f);
    CHECK(!nacre_units_mm("inch", &cm));
    nacre_material_desc_per_unit(&e, 10.0f);
    CHECK(e.sigma_a[0] == d.sigma_a[0] * 10.0f && e.sigma_s[2] == d.sigma_s[2] * 10.0f);
    CHECK(e.layering.layers[0].sigma_a[0] == 5.0f && e.layering.layers[0].sigma_s[1] == 20.0f);
    CHECK(e.layering.layers[0].depth == 0.25f);
    nacre_context_destroy(ctx);
}

int main(void)
{
    test_phong_closed_form(0);
    test_phong_closed_form(40);
    test_shadow_and_caches();
    test_thread_independence();
    test_reuse_output(NACRE_METHOD_PHONG, 2);
    test_reuse_output(NACRE_METHOD_DIFFUSION, 1);
    test_dipole();
    test_units();
    return TEST_MAIN_END();
}
