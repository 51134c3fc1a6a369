/*
 * test_incremental.c: the renderer across frames (nacre_renderer, NACRE_STAGE_LIST). For each
 * kind of scene edit (none, camera, light, material, geometry, commit time) the number of times
 * each stage runs in the next diffusion frame, and the image against a fresh renderer's: equal
 * bit for bit where the edit leaves the solution alone, within the solver's tolerance where the
 * warm-started solve reruns. Also the method table (nacre_method_info_get), the depth every
 * rasterizing frame keeps (against the analytic distance to a plane), and a post pass installed
 * through the method interface that reads image and depth of phong, diffusion and pathtrace.
 */
#include "render/method.h"
#include "scene/scene.h"
#include "test_util.h"

typedef struct fixture {
    nacre_context *ctx;
    nacre_scene *scene;
    nacre_object a, b, ground;
    nacre_object_desc a_desc;
    nacre_material jade;
    nacre_material_desc jade_desc;
    nacre_light key, fill;
    nacre_light_desc key_desc;
    nacre_camera_desc cam;
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

/* Two translucent objects (a sphere with a twist deformer, a cube) over an opaque ground, lit
 * by a directional and a point light: every stage of the diffusion method has work. */
static void make_scene(fixture *f)
{
    memset(f, 0, sizeof(*f));
    CHECK(nacre_context_create(NULL, &f->ctx) == NACRE_OK);
    CHECK(nacre_scene_create(f->ctx, &f->scene) == NACRE_OK);
    nacre_shape_desc sphere = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
    sphere.radius = 10;
    nacre_shape_desc cube = nacre_shape_desc_defaults(NACRE_SHAPE_BOX);
    cube.size[0] = cube.size[1] = cube.size[2] = 14;
    nacre_shape_desc plane = nacre_shape_desc_defaults(NACRE_SHAPE_PLANE);
    plane.size[0] = plane.size[2] = 120;
    nacre_mesh ms = add_shape(f, sphere), mc = add_shape(f, cube), mp = add_shape(f, plane);
    f->jade_desc = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
    CHECK(nacre_scene_add_material(f->scene, &f->jade_desc, &f->jade) == NACRE_OK);
    nacre_material_desc grey = nacre_material_desc_defaults(NACRE_MATERIAL_OPAQUE);
    nacre_material ground_mat;
    CHECK(nacre_scene_add_material(f->scene, &grey, &ground_mat) == NACRE_OK);
    f->a_desc = nacre_object_desc_defaults();
    f->a_desc.mesh = ms;
    f->a_desc.material = f->jade;
    f->a_desc.transform.translate[0] = -14;
    f->a_desc.transform.translate[1] = 10;
    f->a_desc.deformers[0] = nacre_deformer_defaults(NACRE_DEFORM_TWIST);
    f->a_desc.deformers[0].angle = 20;
    f->a_desc.deformers[0].angle_rate = 60;
    f->a_desc.deformers[0].length = 20;
    f->a_desc.deformer_count = 1;
    CHECK(nacre_scene_add_object(f->scene, &f->a_desc, &f->a) == NACRE_OK);
    nacre_object_desc od = nacre_object_desc_defaults();
    od.mesh = mc;
    od.material = f->jade;
    od.transform.translate[0] = 14;
    od.transform.translate[1] = 7;
    CHECK(nacre_scene_add_object(f->scene, &od, &f->b) == NACRE_OK);
    od = nacre_object_desc_defaults();
    od.mesh = mp;
    od.material = ground_mat;
    CHECK(nacre_scene_add_object(f->scene, &od, &f->ground) == NACRE_OK);
    f->key_desc = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
    f->key_desc.direction[0] = 0.4f;
    f->key_desc.direction[1] = -1;
    f->key_desc.direction[2] = -0.3f;
    CHECK(nacre_scene_add_light(f->scene, &f->key_desc, &f->key) == NACRE_OK);
    nacre_light_desc fill = nacre_light_desc_defaults(NACRE_LIGHT_POINT);
    fill.position[0] = -30;
    fill.position[1] = 40;
    fill.position[2] = 30;
    fill.strength[0] = fill.strength[1] = fill.strength[2] = 800;
    CHECK(nacre_scene_add_light(f->scene, &fill, &f->fill) == NACRE_OK);
    f->cam = nacre_camera_desc_defaults();
    f->cam.position[0] = 0;
    f->cam.position[1] = 40;
    f->cam.position[2] = 90;
    f->cam.target[1] = 8;
    CHECK(nacre_scene_set_camera(f->scene, &f->cam) == NACRE_OK);
    CHECK(nacre_scene_commit(f->scene, 0.0) == NACRE_OK);
}

static nacre_render_settings diffusion_settings(void)
{
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = NACRE_METHOD_DIFFUSION;
    rs.width = 96;
    rs.height = 64;
    rs.shadow.map_size = 256;
    rs.diffusion.voxel_resolution = 12;
    rs.diffusion.tsm_size = 64;
    return rs;
}

/* The stage runs a frame must show: one count per stage, -1 for "don't care". */
typedef struct expect {
    const char *edit;
    int runs[NACRE_STAGE_COUNT];
} expect;

static void check_runs(const expect *e, const nacre_render_stats *st)
{
    for (int i = 0; i < NACRE_STAGE_COUNT; i++) {
        bool ok = e->runs[i] < 0 || st->stage_runs[i] == (uint32_t)e->runs[i];
        ok = ok && st->stage_ran[i] == (st->stage_runs[i] > 0);
        if (!ok)
            printf("  %s: stage %s ran %u times, expected %d\n", e->edit, nacre_stage_name((nacre_stage)i),
                   st->stage_runs[i], e->runs[i]);
        CHECK(ok);
    }
}

/* Largest |a - b| relative to the largest value of b. */
static double max_rel_diff(const nacre_image *a, const nacre_image *b)
{
    double peak = 0, diff = 0;
    for (size_t i = 0; i < (size_t)a->width * a->height * 3; i++) {
        peak = fmax(peak, fabs(b->pixels[i]));
        diff = fmax(diff, fabs(a->pixels[i] - b->pixels[i]));
    }
    return peak > 0 ? diff / peak : diff;
}

/* The incremental frame against a fresh renderer's frame of the same committed scene. */
static void check_against_fresh(fixture *f, const nacre_render_settings *rs, const nacre_image *img, bool exact,
                                const char *edit)
{
    nacre_image fresh = {0};
    CHECK(nacre_render(f->scene, rs, &fresh, NULL) == NACRE_OK);
    if (!fresh.pixels)
        return;
    size_t bytes = (size_t)img->width * img->height * 3 * sizeof(float);
    double d = max_rel_diff(img, &fresh);
    if (exact) {
        bool same = memcmp(img->pixels, fresh.pixels, bytes) == 0;
        if (!same)
            printf("  %s: differs from a fresh render (max rel %.3g)\n", edit, d);
        CHECK(same);
    } else {
        /* Warm-started solves stop at the same relative residual from another start. */
        if (d > 2e-3)
            printf("  %s: max rel diff %.3g from a fresh render\n", edit, d);
        CHECK(d <= 2e-3);
    }
    nacre_image_free(f->ctx, &fresh);
}

enum { S, RA, GB, SH, VX, ME, TS, IN, PR, SD };

static void test_diffusion_edits(void)
{
    fixture f;
    make_scene(&f);
    nacre_render_settings rs = diffusion_settings();
    nacre_renderer *r = NULL;
    CHECK(nacre_renderer_create(f.ctx, &r) == NACRE_OK);
    nacre_image img = {0};
    nacre_render_stats st;
    /* Stage order of the expectations: setup raster gbuffer shadow voxelize medium tsm inject
     * propagate shade (NACRE_STAGE_LIST). */
    CHECK((int)NACRE_STAGE_SHADE == SD && (int)NACRE_STAGE_MEDIUM == ME);
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    check_runs(&(expect){"first frame", {1, 1, 1, 2, 2, 2, 2, 2, 2, 1}}, &st);
    check_against_fresh(&f, &rs, &img, true, "first frame");

    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    check_runs(&(expect){"no edit", {1, 0, 0, 0, 0, 0, 0, 0, 0, 1}}, &st);
    check_against_fresh(&f, &rs, &img, true, "no edit");

    f.cam.position[0] = 20;
    CHECK(nacre_scene_set_camera(f.scene, &f.cam) == NACRE_OK);
    CHECK(nacre_scene_commit(f.scene, 0.0) == NACRE_OK);
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    check_runs(&(expect){"camera", {1, 1, 1, 0, 0, 0, 0, 0, 0, 1}}, &st);
    check_against_fresh(&f, &rs, &img, true, "camera");

    f.key_desc.direction[0] = -0.2f;
    CHECK(nacre_scene_set_light(f.scene, f.key, &f.key_desc) == NACRE_OK);
    CHECK(nacre_scene_commit(f.scene, 0.0) == NACRE_OK);
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    check_runs(&(expect){"light", {1, 0, 0, 1, 0, 0, 2, 2, 2, 1}}, &st);
    check_against_fresh(&f, &rs, &img, false, "light");

    f.jade_desc.sigma_a[1] *= 2;
    CHECK(nacre_scene_set_material(f.scene, f.jade, &f.jade_desc) == NACRE_OK);
    CHECK(nacre_scene_commit(f.scene, 0.0) == NACRE_OK);
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    check_runs(&(expect){"material", {1, 0, 0, 0, 0, 2, 2, 2, 2, 1}}, &st);
    check_against_fresh(&f, &rs, &img, false, "material");

    f.a_desc.transform.translate[2] = 5;
    CHECK(nacre_scene_set_object(f.scene, f.a, &f.a_desc) == NACRE_OK);
    CHECK(nacre_scene_commit(f.scene, 0.0) == NACRE_OK);
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    check_runs(&(expect){"geometry", {1, 1, 1, 2, 2, 2, 2, 2, 2, 1}}, &st);
    check_against_fresh(&f, &rs, &img, false, "geometry");

    /* A new commit time moves the twist: everything reruns. */
    CHECK(nacre_scene_commit(f.scene, 0.5) == NACRE_OK);
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    check_runs(&(expect){"time", {1, 1, 1, 2, 2, 2, 2, 2, 2, 1}}, &st);
    check_against_fresh(&f, &rs, &img, false, "time");

    /* A diffusion setting that only the solve reads: no voxelization, no raster. */
    rs.diffusion.tolerance = 1e-5f;
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    check_runs(&(expect){"tolerance", {1, 0, 0, 0, 0, 0, 2, 2, 2, 1}}, &st);
    /* The voxel resolution: voxelize onward, the G-buffer and shadow maps kept. */
    rs.diffusion.voxel_resolution = 10;
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    check_runs(&(expect){"voxel_resolution", {1, 0, 0, 0, 2, 2, 2, 2, 2, 1}}, &st);

    /* Switching to phong and back keeps the diffusion's caches. */
    rs.method = NACRE_METHOD_PHONG;
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    check_runs(&(expect){"to phong", {1, 0, 0, 0, 0, 0, 0, 0, 0, 1}}, &st);
    rs.method = NACRE_METHOD_DIFFUSION;
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    check_runs(&(expect){"back to diffusion", {1, 0, 0, 0, 0, 0, 0, 0, 0, 1}}, &st);
    check_against_fresh(&f, &rs, &img, false, "back to diffusion");

    nacre_image_free(f.ctx, &img);
    nacre_renderer_destroy(r);
    nacre_scene_destroy(f.scene);
    nacre_context_destroy(f.ctx);
}

static void test_method_table(void)
{
    nacre_method_info info;
    for (int m = 0; m < NACRE_METHOD_COUNT; m++) {
        CHECK(nacre_method_info_get((nacre_method)m, &info));
        nacre_method back;
        CHECK(nacre_method_from_name(info.name, &back) && back == (nacre_method)m);
        CHECK(strcmp(info.name, nacre_method_name((nacre_method)m)) == 0);
        CHECK(info.available == nacre_method_available((nacre_method)m));
        CHECK(nc_method_find(info.name) == nc_method_get((nacre_method)m));
    }
    CHECK(!nacre_method_info_get(NACRE_METHOD_COUNT, &info));
    CHECK(nc_method_find("froxel") == NULL && nc_method_get((nacre_method)-1) == NULL);
    CHECK(nacre_method_info_get(NACRE_METHOD_DIFFUSION, &info) && (info.stages & (1u << NACRE_STAGE_MEDIUM)));
    CHECK(nacre_method_info_get(NACRE_METHOD_PHONG, &info) && !(info.stages & (1u << NACRE_STAGE_VOXELIZE)));
    CHECK(nacre_method_info_get(NACRE_METHOD_PATHTRACE, &info) && info.stochastic && info.renders_fog &&
          !info.needs_objects);
    CHECK(nacre_method_info_get(NACRE_METHOD_LAYERED, &info) && info.available && (info.stages & (1u << NACRE_STAGE_PLANES)));
}

/* A post pass for the test: records what it was given and darkens every pixel by its depth, so
 * the test can see it ran on the final image. */
typedef struct probe {
    int applied;
    double depth_sum;
    uint64_t finite, infinite;
} probe;

static probe probe_seen;

static bool probe_wanted(const nacre_scene *s, const nacre_render_settings *rs)
{
    (void)s;
    return rs->width == 80;
}

static nacre_result probe_create(nacre_context *ctx, void **state)
{
    (void)ctx;
    *state = &probe_seen;
    return NACRE_OK;
}

static nacre_result probe_apply(void *state, const nc_post_input *in, nacre_image *image, nacre_render_stats *st)
{
    (void)st;
    probe *p = state;
    p->applied++;
    p->depth_sum = 0;
    p->finite = p->infinite = 0;
    for (int32_t y = 0; y < image->height; y++)
        for (int32_t x = 0; x < image->width; x++) {
            float d = in->depth[(size_t)y * (size_t)image->width + (size_t)x];
            float *px = image->pixels + (size_t)y * image->stride + 3 * (size_t)x;
            if (isfinite(d)) {
                p->finite++;
                p->depth_sum += d;
                for (int c = 0; c < 3; c++)
                    px[c] *= expf(-0.01f * d);
            } else {
                p->infinite++;
            }
        }
    return NACRE_OK;
}

static void probe_destroy(nacre_context *ctx, void *state)
{
    (void)ctx;
    (void)state;
}

static const nc_post_pass probe_pass = {"probe", probe_wanted, probe_create, probe_apply, probe_destroy};

/* An orthographic camera straight down on a plane at y = 0 from y = 50: every pixel on the plane
 * has depth 50; the pass must see that under every method. */
static void test_depth_and_post_pass(void)
{
    nacre_context *ctx = NULL;
    nacre_scene *s = NULL;
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    CHECK(nacre_scene_create(ctx, &s) == NACRE_OK);
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_PLANE);
    sd.size[0] = sd.size[2] = 60;
    nacre_mesh_data md = {0};
    nacre_mesh mesh;
    CHECK(nacre_mesh_make_shape(ctx, &sd, &md) == NACRE_OK);
    CHECK(nacre_scene_add_mesh(s, &md, &mesh) == NACRE_OK);
    nacre_mesh_data_free(ctx, &md);
    nacre_material_desc mdsc = nacre_material_desc_defaults(NACRE_MATERIAL_OPAQUE);
    nacre_material mat;
    CHECK(nacre_scene_add_material(s, &mdsc, &mat) == NACRE_OK);
    nacre_object_desc od = nacre_object_desc_defaults();
    od.mesh = mesh;
    od.material = mat;
    nacre_object obj;
    CHECK(nacre_scene_add_object(s, &od, &obj) == NACRE_OK);
    nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
    nacre_light light;
    CHECK(nacre_scene_add_light(s, &ld, &light) == NACRE_OK);
    nacre_camera_desc cam = nacre_camera_desc_defaults();
    cam.projection = NACRE_ORTHOGRAPHIC;
    cam.position[0] = 0, cam.position[1] = 50, cam.position[2] = 0;
    cam.target[0] = cam.target[1] = cam.target[2] = 0;
    cam.up[0] = 0, cam.up[1] = 0, cam.up[2] = -1;
    cam.ortho_height = 100; /* the plane fills the middle 60% of each axis */
    CHECK(nacre_scene_set_camera(s, &cam) == NACRE_OK);
    CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);

    nacre_renderer *r = NULL;
    CHECK(nacre_renderer_create(ctx, &r) == NACRE_OK);
    nacre_image depth = {0};
    CHECK(nacre_renderer_depth(r, &depth) == NACRE_ERROR_INVALID_OPERATION); /* no frame yet */
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.width = rs.height = 40;
    nacre_image img = {0};
    CHECK(nacre_renderer_render(r, s, &rs, &img, NULL) == NACRE_OK);
    CHECK(nacre_renderer_depth(r, &depth) == NACRE_OK);
    uint64_t on = 0, off = 0;
    bool exact = true;
    for (int i = 0; depth.pixels && i < 40 * 40; i++) {
        if (isfinite(depth.pixels[i])) {
            on++;
            exact = exact && fabsf(depth.pixels[i] - 50.0f) < 1e-3f;
        } else {
            off++;
        }
    }
    CHECK(depth.channels == 1 && exact);
    CHECK(on == 24 * 24 && off == 40 * 40 - 24 * 24); /* 60 of 100 units: 24 of 40 pixels a side */
    nacre_image_free(ctx, &depth);
    nacre_image_free(ctx, &img);

    /* The pass, installed through the interface, under each method. */
    const nc_post_pass *const passes[] = {&probe_pass};
    CHECK(nc_renderer_set_post_passes(r, passes, 1) == NACRE_OK);
    const nacre_method methods[] = {NACRE_METHOD_PHONG, NACRE_METHOD_DIFFUSION, NACRE_METHOD_PATHTRACE};
    rs.width = 80;
    rs.height = 80;
    rs.pathtrace.spp = 1;
    for (int m = 0; m < 3; m++) {
        if (!nacre_method_available(methods[m]))
            continue;
        rs.method = methods[m];
        memset(&probe_seen, 0, sizeof(probe_seen));
        nacre_image with = {0}, without = {0};
        CHECK(nacre_renderer_render(r, s, &rs, &with, NULL) == NACRE_OK);
        CHECK(probe_seen.applied == 1);
        CHECK(probe_seen.finite == 48 * 48 && probe_seen.infinite == 80 * 80 - 48 * 48);
        CHECK_NEAR(probe_seen.depth_sum / (double)probe_seen.finite, 50.0, 1e-3);
        /* Its effect is in the returned image: a fresh render without the pass is brighter
         * by exp(0.5) on the plane. */
        CHECK(nacre_render(s, &rs, &without, NULL) == NACRE_OK);
        if (with.pixels && without.pixels) {
            size_t centre = (size_t)40 * with.stride + 3 * 40;
            CHECK_NEAR(with.pixels[centre] * expf(0.5f), without.pixels[centre], 1e-4 * without.pixels[centre] + 1e-7);
        }
        nacre_image_free(ctx, &with);
        nacre_image_free(ctx, &without);
    }
    /* Not wanted (another width): not applied. */
    memset(&probe_seen, 0, sizeof(probe_seen));
    rs.method = NACRE_METHOD_PHONG;
    rs.width = 81;
    CHECK(nacre_renderer_render(r, s, &rs, &img, NULL) == NACRE_OK);
    CHECK(probe_seen.applied == 0);
    nacre_image_free(ctx, &img);
    nacre_renderer_destroy(r);
    nacre_scene_destroy(s);
    nacre_context_destroy(ctx);
}

/* Progressive path tracing through the public API: two accumulating frames of 4 spp are one
 * frame of 8; a camera edit starts again. */
static void test_progressive(void)
{
    if (!nacre_method_available(NACRE_METHOD_PATHTRACE))
        return;
    fixture f;
    make_scene(&f);
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = NACRE_METHOD_PATHTRACE;
    rs.width = 24;
    rs.height = 16;
    rs.pathtrace.spp = 4;
    rs.pathtrace.accumulate = true;
    nacre_renderer *r = NULL;
    CHECK(nacre_renderer_create(f.ctx, &r) == NACRE_OK);
    nacre_image img = {0}, once = {0};
    nacre_render_stats st;
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    CHECK(!st.accumulated && st.spp_done == 4);
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    CHECK(st.accumulated && st.spp_done == 8 && st.samples_done == 4u * 24 * 16);
    nacre_render_settings eight = rs;
    eight.pathtrace.spp = 8;
    eight.pathtrace.accumulate = false;
    CHECK(nacre_render(f.scene, &eight, &once, NULL) == NACRE_OK);
    CHECK(img.pixels && once.pixels && memcmp(img.pixels, once.pixels, 24 * 16 * 3 * sizeof(float)) == 0);
    f.cam.position[0] = 5;
    CHECK(nacre_scene_set_camera(f.scene, &f.cam) == NACRE_OK);
    CHECK(nacre_scene_commit(f.scene, 0.0) == NACRE_OK);
    CHECK(nacre_renderer_render(r, f.scene, &rs, &img, &st) == NACRE_OK);
    CHECK(!st.accumulated && st.spp_done == 4);
    nacre_image_free(f.ctx, &img);
    nacre_image_free(f.ctx, &once);
    nacre_renderer_destroy(r);
    nacre_scene_destroy(f.scene);
    nacre_context_destroy(f.ctx);
}

int main(void)
{
    test_progressive();
    test_method_table();
    test_diffusion_edits();
    test_depth_and_post_pass();
    return TEST_MAIN_END();
}
