/*
 * test_pathtrace_progressive.c: progressive path tracing (nc_pathtrace_render with accumulate).
 *   - accumulating frames of 4 + 4 spp, and of 2 + 2 + 2 + 2, give one frame of 8 spp bit for
 *     bit, variance image included; without accumulation two frames of 4 do not (each is the
 *     4 spp image), and the accumulation continues the random sequence rather than repeating it;
 *   - changing seed, size or max_scatter restarts; changing spp does not;
 *   - editing the camera, a light, a material or the environment of the committed scene between
 *     accumulating frames restarts: the next frame is a fresh render of the edited scene;
 *   - a camera-only edit keeps the built scene (counted through the max_sigma_t hook, which only
 *     the scene setup calls) and still renders what a fresh state renders; other edits rebuild;
 *   - with a time limit pixels may hold different counts: the next frame continues each from
 *     its own, every pixel equals an unlimited render with its count, and the stats add up.
 * A dielectric sphere (guided sun, clearance grid) on an opaque plane, a sun, a sphere light
 * and an environment; 32x24 images so that the whole file runs in seconds under ASan.
 */
#include "test_util.h"

#include "pathtrace/pathtrace.h"

#include <nacre/nacre.h>

#ifdef NACRE_HAVE_EMBREE

/* The state's per-pixel counts (test_time_limit); nc_medium_max_sigma_t (counting_max). */
#include "pathtrace/pt_internal.h"
#include "scene/medium.h"

static nacre_context *ctx;

enum { W = 32, H = 24 };

typedef struct test_scene {
    nacre_scene *s;
    nacre_material glass;
    nacre_light lamp;
    nacre_material_desc glass_desc;
    nacre_light_desc lamp_desc;
    nacre_camera_desc cam;
} test_scene;

static nacre_mesh add_shape(nacre_scene *s, const nacre_shape_desc *sd)
{
    nacre_mesh_data data = {0};
    CHECK(nacre_mesh_make_shape(ctx, sd, &data) == NACRE_OK);
    nacre_mesh mesh = {0};
    CHECK(nacre_scene_add_mesh(s, &data, &mesh) == NACRE_OK);
    nacre_mesh_data_free(ctx, &data);
    return mesh;
}

static void add_object(nacre_scene *s, nacre_mesh mesh, nacre_material mat, float y)
{
    nacre_object_desc od = nacre_object_desc_defaults();
    od.mesh = mesh;
    od.material = mat;
    od.transform.translate[1] = y;
    nacre_object obj;
    CHECK(nacre_scene_add_object(s, &od, &obj) == NACRE_OK);
}

static test_scene make_scene(void)
{
    test_scene t;
    memset(&t, 0, sizeof(t));
    CHECK(nacre_scene_create(ctx, &t.s) == NACRE_OK);
    nacre_shape_desc sphere = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
    sphere.segments = 24;
    sphere.rings = 12;
    nacre_shape_desc plane = nacre_shape_desc_defaults(NACRE_SHAPE_PLANE);
    plane.segments = 1;
    t.glass_desc = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
    for (int c = 0; c < 3; c++) {
        t.glass_desc.sigma_a[c] = 0.2f + 0.1f * (float)c;
        t.glass_desc.sigma_s[c] = 2.0f;
    }
    t.glass_desc.g = 0.3f;
    t.glass_desc.eta = 1.4f;
    CHECK(nacre_scene_add_material(t.s, &t.glass_desc, &t.glass) == NACRE_OK);
    nacre_material_desc ground_desc = nacre_material_desc_defaults(NACRE_MATERIAL_OPAQUE);
    nacre_material ground;
    CHECK(nacre_scene_add_material(t.s, &ground_desc, &ground) == NACRE_OK);
    add_object(t.s, add_shape(t.s, &sphere), t.glass, 0.0f);
    add_object(t.s, add_shape(t.s, &plane), ground, -1.0f);
    nacre_light_desc sun = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
    sun.direction[0] = -0.4f, sun.direction[1] = -1.0f, sun.direction[2] = -0.3f;
    sun.angular_radius = 2.0f;
    nacre_light sun_light;
    CHECK(nacre_scene_add_light(t.s, &sun, &sun_light) == NACRE_OK);
    t.lamp_desc = nacre_light_desc_defaults(NACRE_LIGHT_POINT);
    t.lamp_desc.position[0] = 1.5f, t.lamp_desc.position[1] = 1.5f, t.lamp_desc.position[2] = 1.0f;
    t.lamp_desc.strength[0] = t.lamp_desc.strength[1] = t.lamp_desc.strength[2] = 3.0f;
    t.lamp_desc.radius = 0.2f;
    CHECK(nacre_scene_add_light(t.s, &t.lamp_desc, &t.lamp) == NACRE_OK);
    t.cam = nacre_camera_desc_defaults();
    t.cam.position[0] = 0.5f, t.cam.position[1] = 1.0f, t.cam.position[2] = 4.0f;
    t.cam.target[0] = t.cam.target[1] = t.cam.target[2] = 0.0f;
    t.cam.fov_y = 45;
    CHECK(nacre_scene_set_camera(t.s, &t.cam) == NACRE_OK);
    float env[3] = {0.2f, 0.25f, 0.3f};
    CHECK(nacre_scene_set_environment(t.s, env) == NACRE_OK);
    CHECK(nacre_scene_commit(t.s, 0.0) == NACRE_OK);
    return t;
}

static nacre_render_settings settings(uint32_t spp)
{
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = NACRE_METHOD_PATHTRACE;
    rs.width = W;
    rs.height = H;
    rs.pathtrace.spp = spp;
    rs.pathtrace.seed = 7;
    return rs;
}

/* A frame's image and variance image (free both with free_frame). */
typedef struct frame {
    nacre_image img, var;
    nacre_render_stats st;
} frame;

static frame render(nc_pathtracer **st, const nacre_scene *s, const nacre_render_settings *rs, bool accumulate)
{
    frame f;
    memset(&f, 0, sizeof(f));
    CHECK(nacre_image_alloc(ctx, rs->width, rs->height, 3, &f.img) == NACRE_OK);
    nacre_result r = nc_pathtrace_render(st, ctx, s, rs, accumulate, &f.img, &f.st);
    CHECK(r == NACRE_OK);
    if (r != NACRE_OK)
        printf("  %s\n", nacre_context_last_error(ctx));
    CHECK(nc_pathtrace_variance(*st, ctx, &f.var) == NACRE_OK);
    return f;
}

/* A frame of a state of its own, with the default options. */
static frame render_fresh(const nacre_scene *s, const nacre_render_settings *rs)
{
    nc_pathtracer *st = NULL;
    frame f = render(&st, s, rs, false);
    nc_pathtracer_destroy(ctx, st);
    return f;
}

static void free_frame(frame *f)
{
    nacre_image_free(ctx, &f->img);
    nacre_image_free(ctx, &f->var);
}

static bool same_image(const nacre_image *a, const nacre_image *b)
{
    if (a->width != b->width || a->height != b->height)
        return false;
    for (int32_t y = 0; y < a->height; y++)
        if (memcmp(a->pixels + (size_t)y * a->stride, b->pixels + (size_t)y * b->stride, 3 * sizeof(float) * (size_t)a->width))
            return false;
    return true;
}

static bool same_frame(const frame *a, const frame *b) { return same_image(&a->img, &b->img) && same_image(&a->var, &b->var); }

/* 4 + 4 and 2 + 2 + 2 + 2 accumulated equal 8 at once; 4 and 4 without accumulation do not. */
static void test_split_frames(const test_scene *t)
{
    nacre_render_settings r8 = settings(8), r4 = settings(4), r2 = settings(2);
    frame ref8 = render_fresh(t->s, &r8), ref4 = render_fresh(t->s, &r4);
    CHECK(!same_image(&ref8.img, &ref4.img)); /* the comparisons below can fail */

    nc_pathtracer *st = NULL;
    frame a = render(&st, t->s, &r4, true);
    CHECK(same_frame(&a, &ref4));
    CHECK(nc_pathtrace_frames(st) == 1);
    frame b = render(&st, t->s, &r4, true);
    CHECK(same_frame(&b, &ref8));
    CHECK(!same_image(&b.img, &ref4.img)); /* the sequence went on: repeating it keeps the mean */
    CHECK(b.st.spp_done == 8);
    CHECK(b.st.samples_done == 4u * W * H);
    CHECK(nc_pathtrace_passes(st) == 8);
    CHECK(nc_pathtrace_samples(st) == 8u * W * H);
    CHECK(nc_pathtrace_frames(st) == 2);
    free_frame(&a);
    free_frame(&b);

    /* A state of its own: this one holds 8 samples already and would go on to 16. */
    nc_pathtracer *st2 = NULL;
    for (int k = 0; k < 4; k++) {
        frame c = render(&st2, t->s, &r2, true);
        if (k == 3) {
            CHECK(same_frame(&c, &ref8));
            CHECK(c.st.spp_done == 8 && c.st.samples_done == 2u * W * H);
        }
        free_frame(&c);
    }
    nc_pathtracer_destroy(ctx, st2);
    /* The previous frame held 8 samples: with accumulate = false the state starts over. */
    for (int k = 0; k < 2; k++) {
        frame c = render(&st, t->s, &r4, false);
        CHECK(same_frame(&c, &ref4));
        CHECK(!same_image(&c.img, &ref8.img));
        CHECK(nc_pathtrace_frames(st) == 1 && c.st.spp_done == 4);
        free_frame(&c);
    }
    nc_pathtracer_destroy(ctx, st);
    free_frame(&ref8);
    free_frame(&ref4);
}

/* Settings that decide the samples restart; spp (how many to add) does not. */
static void test_settings_restart(const test_scene *t)
{
    nacre_render_settings r4 = settings(4), r2 = settings(2), r6 = settings(6);
    nc_pathtracer *st = NULL;
    frame f = render(&st, t->s, &r4, true);
    free_frame(&f);
    f = render(&st, t->s, &r2, true);
    frame ref = render_fresh(t->s, &r6);
    CHECK(same_frame(&f, &ref));
    free_frame(&f);
    free_frame(&ref);

    nacre_render_settings seed = r2, size = r2, scatter = r2;
    seed.pathtrace.seed = 8;
    size.width = W - 8;
    scatter.pathtrace.max_scatter = 3;
    const nacre_render_settings *changed[3] = {&seed, &size, &scatter};
    for (int k = 0; k < 3; k++) {
        f = render(&st, t->s, &r4, true); /* back to the first settings: a restart too */
        free_frame(&f);
        f = render(&st, t->s, changed[k], true);
        ref = render_fresh(t->s, changed[k]);
        CHECK(same_frame(&f, &ref));
        CHECK(nc_pathtrace_frames(st) == 1);
        free_frame(&f);
        free_frame(&ref);
    }
    nc_pathtracer_destroy(ctx, st);
}

/* Scene setups counted through the max_sigma_t hook (called once per translucent object by
 * nc_pt_build_scene only). */
static int setups;
static void counting_max(const nacre_scene *scene, const nacre_material_desc *m, float out[3])
{
    setups++;
    nc_medium_max_sigma_t(scene, m, out);
}

enum { EDIT_CAMERA, EDIT_LIGHT, EDIT_MATERIAL, EDIT_ENVIRONMENT, EDIT_COUNT };
static const char *const edit_names[EDIT_COUNT] = {"camera", "light", "material", "environment"};

static void edit(test_scene *t, int what, int round)
{
    float d = 0.1f * (float)(round + 1);
    if (what == EDIT_CAMERA) {
        t->cam.position[0] += d;
        CHECK(nacre_scene_set_camera(t->s, &t->cam) == NACRE_OK);
    } else if (what == EDIT_LIGHT) {
        t->lamp_desc.position[1] += d;
        CHECK(nacre_scene_set_light(t->s, t->lamp, &t->lamp_desc) == NACRE_OK);
    } else if (what == EDIT_MATERIAL) {
        t->glass_desc.sigma_s[1] += d;
        CHECK(nacre_scene_set_material(t->s, t->glass, &t->glass_desc) == NACRE_OK);
    } else {
        float env[3] = {0.2f + d, 0.25f, 0.3f};
        CHECK(nacre_scene_set_environment(t->s, env) == NACRE_OK);
    }
    CHECK(nacre_scene_commit(t->s, 0.0) == NACRE_OK);
}

/* Every kind of edit between accumulating frames restarts: the frame equals a fresh render of
 * the edited scene. A camera edit keeps the built scene, the others rebuild it. */
static void test_edits_restart(void)
{
    test_scene t = make_scene();
    nacre_render_settings r2 = settings(2);
    nc_pathtrace_options opt = nc_pathtrace_options_defaults();
    opt.max_sigma_t = counting_max;
    nc_pathtracer *st = NULL;
    CHECK(nc_pathtracer_create(ctx, &opt, &st) == NACRE_OK);
    for (int round = 0; round < 2; round++)
        for (int what = 0; what < EDIT_COUNT; what++) {
            for (int k = 0; k < 2; k++) {
                frame f = render(&st, t.s, &r2, true);
                free_frame(&f);
            }
            CHECK(nc_pathtrace_frames(st) >= 2);
            setups = 0;
            edit(&t, what, round);
            frame f = render(&st, t.s, &r2, true);
            int rebuilt = setups;
            frame ref = render_fresh(t.s, &r2);
            bool same = same_frame(&f, &ref);
            CHECK(same);
            CHECK(nc_pathtrace_frames(st) == 1 && f.st.spp_done == 2);
            CHECK(rebuilt == (what == EDIT_CAMERA ? 0 : 1)); /* one translucent object */
            if (!same || rebuilt != (what == EDIT_CAMERA ? 0 : 1))
                printf("  edit of the %s (round %d): same %d, scene setups %d\n", edit_names[what], round, same, rebuilt);
            free_frame(&f);
            free_frame(&ref);
        }
    /* Without accumulation a camera-only edit reuses the scene just as well. */
    setups = 0;
    edit(&t, EDIT_CAMERA, 0);
    frame f = render(&st, t.s, &r2, false);
    frame ref = render_fresh(t.s, &r2);
    CHECK(same_frame(&f, &ref));
    CHECK(setups == 0);
    free_frame(&f);
    free_frame(&ref);
    /* An edit not yet committed: neither the built scene nor the accumulators are trusted. */
    t.cam.position[1] += 0.1f;
    CHECK(nacre_scene_set_camera(t.s, &t.cam) == NACRE_OK);
    f = render(&st, t.s, &r2, true);
    CHECK(setups == 1 && nc_pathtrace_frames(st) == 1);
    free_frame(&f);
    CHECK(nacre_scene_commit(t.s, 0.0) == NACRE_OK);
    /* Another scene with the same content restarts and rebuilds (its uid differs). */
    test_scene u = make_scene();
    setups = 0;
    f = render(&st, u.s, &r2, true);
    CHECK(setups == 1 && nc_pathtrace_frames(st) == 1);
    free_frame(&f);
    nc_pathtracer_destroy(ctx, st);
    nacre_scene_destroy(u.s);
    nacre_scene_destroy(t.s);
}

/* A time limit leaves pixels at different counts; the next frame adds spp to each pixel's own
 * count, and each pixel is the pixel of an unlimited render with that many samples. */
static void test_time_limit(const test_scene *t)
{
    nacre_render_settings lim = settings(0), r2 = settings(2);
    lim.pathtrace.time_limit = 0.05;
    nc_pathtracer *st = NULL;
    frame a = render(&st, t->s, &lim, true);
    uint64_t first = a.st.samples_done;
    CHECK(nc_pathtrace_samples(st) == first);
    frame b = render(&st, t->s, &r2, true);
    CHECK(b.st.samples_done == 2u * W * H);
    CHECK(nc_pathtrace_samples(st) == first + 2u * W * H);
    CHECK(nc_pathtrace_frames(st) == 2);
    uint32_t lo = UINT32_MAX, hi = 0;
    for (size_t i = 0; i < (size_t)W * H; i++) {
        lo = st->count[i] < lo ? st->count[i] : lo;
        hi = st->count[i] > hi ? st->count[i] : hi;
    }
    CHECK(lo >= 2 && b.st.spp_done == lo && nc_pathtrace_passes(st) == lo);
    printf("  time limit: %llu paths in the limited frame, counts %u..%u after +2\n", (unsigned long long)first, lo, hi);
    int bad = 0;
    for (uint32_t n = lo; n <= hi; n++) {
        nacre_render_settings rn = settings(n);
        frame ref = render_fresh(t->s, &rn);
        for (int32_t y = 0; y < H; y++)
            for (int32_t x = 0; x < W; x++) {
                if (st->count[(size_t)y * W + (size_t)x] != n)
                    continue;
                size_t o = (size_t)y * b.img.stride + 3 * (size_t)x;
                bad += memcmp(b.img.pixels + o, ref.img.pixels + o, 3 * sizeof(float)) != 0 ||
                       memcmp(b.var.pixels + o, ref.var.pixels + o, 3 * sizeof(float)) != 0;
            }
        free_frame(&ref);
    }
    CHECK(bad == 0);
    free_frame(&a);
    free_frame(&b);
    nc_pathtracer_destroy(ctx, st);
}

int main(void)
{
    nacre_context_desc cd = {0};
    cd.threads = 2;
    CHECK(nacre_context_create(&cd, &ctx) == NACRE_OK);
    test_scene t = make_scene();
    test_split_frames(&t);
    test_settings_restart(&t);
    test_time_limit(&t);
    nacre_scene_destroy(t.s);
    test_edits_restart();
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}

#else /* !NACRE_HAVE_EMBREE */

int main(void)
{
    CHECK(!nc_pathtrace_available());
    printf("path tracer not built (no Embree): skipped\n");
    return TEST_MAIN_END();
}

#endif /* NACRE_HAVE_EMBREE */
