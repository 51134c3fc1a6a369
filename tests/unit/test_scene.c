/*
 * test_scene.c: math helpers, object transforms, deformers (against closed forms), scene
 * validation messages and change tracking, and the last error kept per thread.
 */
#include "core/math.h"
#include "scene/scene.h"
#include "test_util.h"

#include <pthread.h>
#include <string.h>

static void test_math(void)
{
    nacre_transform t = {{1, 2, 3}, {30, -45, 60}, {2, 0.5f, 3}};
    nc_mat4 m = nc_transform_matrix(&t), inv, id;
    CHECK(nc_mat4_inverse(m, &inv));
    id = nc_mat4_mul(m, inv);
    double err = 0;
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++)
            err = fmax(err, fabs(id.m[i][j] - (i == j ? 1.0 : 0.0)));
    CHECK(err < 1e-5);
    nc_mat4 singular = nc_mat4_scale(nc_v3(1, 0, 1));
    CHECK(!nc_mat4_inverse(singular, &inv));

    /* Rotation order: x first, then y. Rotating +y by 90 about x gives +z; then 90 about y
     * takes +z to +x. */
    nacre_transform r = {{0, 0, 0}, {90, 90, 0}, {1, 1, 1}};
    nc_mat4 mr = nc_transform_matrix(&r);
    nc_vec3 p = nc_mat4_point(&mr, nc_v3(0, 1, 0));
    CHECK_NEAR(p.x, 1, 1e-6);
    CHECK_NEAR(p.y, 0, 1e-6);
    CHECK_NEAR(p.z, 0, 1e-6);
    /* Scale happens before rotation and translation. */
    nacre_transform s = {{5, 0, 0}, {0, 0, 90}, {2, 1, 1}};
    nc_mat4 ms = nc_transform_matrix(&s);
    p = nc_mat4_point(&ms, nc_v3(1, 0, 0)); /* scaled to (2,0,0), rotated to (0,2,0), moved */
    CHECK_NEAR(p.x, 5, 1e-6);
    CHECK_NEAR(p.y, 2, 1e-6);

    /* look_at + perspective: the target projects to the centre, near -> z 0, far -> z 1 */
    nc_mat4 v = nc_mat4_look_at(nc_v3(0, 0, 10), nc_v3(0, 0, 0), nc_v3(0, 1, 0));
    nc_mat4 pr = nc_mat4_perspective(60 * NC_DEG2RAD, 1.5f, 1, 100);
    nc_mat4 vp = nc_mat4_mul(pr, v);
    nc_vec4 c = nc_mat4_apply(&vp, (nc_vec4){0, 0, 0, 1});
    CHECK_NEAR(c.x / c.w, 0, 1e-6);
    CHECK_NEAR(c.y / c.w, 0, 1e-6);
    c = nc_mat4_apply(&vp, (nc_vec4){0, 0, 9, 1});
    CHECK_NEAR(c.z / c.w, 0, 1e-6);
    c = nc_mat4_apply(&vp, (nc_vec4){0, 0, -90, 1});
    CHECK_NEAR(c.z / c.w, 1, 1e-5);
    /* top edge of the frustum at distance 10: y = 10 tan(30 deg) -> NDC y = 1 */
    c = nc_mat4_apply(&vp, (nc_vec4){0, 10 * tanf(30 * NC_DEG2RAD), 0, 1});
    CHECK_NEAR(c.y / c.w, 1, 1e-5);
}

static void test_deformers(void)
{
    /* Twist: a point at height s rotates by angle * s / length about the axis. */
    nacre_deformer tw = nacre_deformer_defaults(NACRE_DEFORM_TWIST);
    tw.angle = 90;
    tw.length = 2;
    nc_vec3 p = nc_deform_point(&tw, 1, 0.0, nc_v3(1, 2, 0)); /* s = 2 -> 90 deg about +y */
    CHECK_NEAR(p.x, 0, 1e-6);
    CHECK_NEAR(p.y, 2, 1e-6);
    CHECK_NEAR(p.z, -1, 1e-6);
    p = nc_deform_point(&tw, 1, 0.0, nc_v3(1, 0, 0)); /* s = 0: unchanged */
    CHECK_NEAR(p.x, 1, 1e-7);
    /* angle_rate animates: at t = 1 s with rate -90 deg/s the twist cancels. */
    tw.angle_rate = -90;
    p = nc_deform_point(&tw, 1, 1.0, nc_v3(1, 2, 0));
    CHECK_NEAR(p.x, 1, 1e-6);
    CHECK_NEAR(p.z, 0, 1e-6);

    /* Scale about a centre. */
    nacre_deformer sc = nacre_deformer_defaults(NACRE_DEFORM_SCALE);
    sc.scale[0] = 2;
    sc.scale[1] = 0.5f;
    sc.center[0] = 1;
    p = nc_deform_point(&sc, 1, 0.0, nc_v3(2, 2, 3));
    CHECK_NEAR(p.x, 3, 1e-6);
    CHECK_NEAR(p.y, 1, 1e-6);
    CHECK_NEAR(p.z, 3, 1e-6);

    /* Bend by 90 degrees over length L: the axis end lands at (L/k)(sin, 1 - cos) with
     * k = (pi/2)/L, i.e. at (2L/pi, 2L/pi) in (axis, direction) coordinates, and the axis
     * keeps its length (arc length preserved). */
    nacre_deformer bd = nacre_deformer_defaults(NACRE_DEFORM_BEND);
    bd.angle = 90;
    bd.length = 3;
    p = nc_deform_point(&bd, 1, 0.0, nc_v3(0, 3, 0));
    CHECK_NEAR(p.y, 6 / NC_PI, 1e-5);
    CHECK_NEAR(p.x, 6 / NC_PI, 1e-5);
    double arc = 0;
    nc_vec3 prev = nc_deform_point(&bd, 1, 0.0, nc_v3(0, 0, 0));
    for (int i = 1; i <= 1000; i++) {
        nc_vec3 q = nc_deform_point(&bd, 1, 0.0, nc_v3(0, 3.0f * i / 1000, 0));
        arc += nc_length(nc_sub(q, prev));
        prev = q;
    }
    CHECK_NEAR(arc, 3, 1e-3);
    /* Beyond the arc the material continues straight along the end tangent (+x here). */
    p = nc_deform_point(&bd, 1, 0.0, nc_v3(0, 4, 0));
    CHECK_NEAR(p.x, 6 / NC_PI + 1, 1e-5);
    CHECK_NEAR(p.y, 6 / NC_PI, 1e-5);
    /* Below the centre: untouched. */
    p = nc_deform_point(&bd, 1, 0.0, nc_v3(0.3f, -1, 0.2f));
    CHECK_NEAR(p.x, 0.3, 1e-7);
    CHECK_NEAR(p.y, -1, 1e-7);
}

static nacre_mesh add_unit_box(nacre_scene *scene, nacre_context *ctx, uint32_t segments)
{
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_BOX);
    sd.segments = segments;
    nacre_mesh_data md = {0};
    nacre_mesh mesh = {0};
    CHECK(nacre_mesh_make_shape(ctx, &sd, &md) == NACRE_OK);
    CHECK(nacre_scene_add_mesh(scene, &md, &mesh) == NACRE_OK);
    nacre_mesh_data_free(ctx, &md);
    return mesh;
}

static void test_scene_commit(void)
{
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    nacre_scene *scene = NULL;
    CHECK(nacre_scene_create(ctx, &scene) == NACRE_OK);
    nacre_mesh mesh = add_unit_box(scene, ctx, 8);
    nacre_material_desc md = nacre_material_desc_defaults(NACRE_MATERIAL_OPAQUE);
    nacre_material mat;
    CHECK(nacre_scene_add_material(scene, &md, &mat) == NACRE_OK);
    nacre_object_desc od = nacre_object_desc_defaults();
    od.mesh = mesh;
    od.material = mat;
    od.transform.translate[0] = 10;
    od.deformer_count = 1;
    od.deformers[0] = nacre_deformer_defaults(NACRE_DEFORM_TWIST);
    od.deformers[0].angle = 90;
    od.deformers[0].length = 1;
    nacre_object obj;
    CHECK(nacre_scene_add_object(scene, &od, &obj) == NACRE_OK);
    CHECK(nacre_scene_commit(scene, 0.0) == NACRE_OK);
    const nc_object_rec *o = &scene->objects[obj.id - 1];
    const nacre_mesh_data *rest = nacre_scene_mesh_data(scene, mesh);
    CHECK(rest != NULL);
    /* Every world vertex is the deformed rest vertex, translated; normals stay unit and
     * perpendicular to the deformed surface (checked against a finite-difference tangent). */
    double worst = 0, worst_n = 0;
    for (uint32_t v = 0; v < rest->vertex_count; v++) {
        nc_vec3 q = nc_deform_point(od.deformers, 1, 0.0, nc_v3a(rest->positions + 3 * v));
        q.x += 10;
        worst = fmax(worst, nc_length(nc_sub(q, nc_v3a(o->world_positions + 3 * v))));
        worst_n = fmax(worst_n, fabs(nc_length(nc_v3a(o->world_normals + 3 * v)) - 1));
    }
    CHECK(worst < 1e-5);
    CHECK(worst_n < 1e-5);
    /* Normal of the deformed +x face at its centre: the twist rotates it by 90 * 0 deg there
     * (s = 0), so it stays +x. */
    for (uint32_t v = 0; v < rest->vertex_count; v++) {
        const float *rp = rest->positions + 3 * v;
        if (rp[0] == 0.5f && fabsf(rp[1]) < 1e-6f && fabsf(rp[2]) < 1e-6f) {
            CHECK_NEAR(o->world_normals[3 * v], 1, 1e-4);
        }
    }
    float bmin[3], bmax[3];
    CHECK(nacre_scene_bounds(scene, bmin, bmax) == NACRE_OK);
    CHECK(bmin[0] > 9 && bmax[0] < 11);

    /* Change tracking: an edit invalidates the commit; a material edit bumps only materials. */
    nc_versions before = scene->versions;
    md.diffuse[0] = 0.1f;
    CHECK(nacre_scene_set_material(scene, mat, &md) == NACRE_OK);
    CHECK(scene->versions.materials == before.materials + 1);
    CHECK(scene->versions.geometry == before.geometry);
    CHECK(memcmp(&scene->versions, &scene->committed, sizeof(nc_versions)) != 0);

    /* Validation names the field. */
    md.sigma_a[0] = -1;
    md.type = NACRE_MATERIAL_TRANSLUCENT;
    CHECK(nacre_scene_add_material(scene, &md, &mat) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "sigma_a") != NULL);
    /* Issue 29 item 6: eta outside [NACRE_ETA_MIN, NACRE_ETA_MAX] made diffusion images NaN. */
    {
        nacre_material_desc te = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
        const float bad_eta[] = {1e-6f, 0.29f, 3.01f, 1e9f, NAN, INFINITY};
        for (int i = 0; i < 6; i++) {
            te.eta = bad_eta[i];
            CHECK(nacre_scene_add_material(scene, &te, &mat) == NACRE_ERROR_INVALID_ARGUMENT);
            CHECK(strstr(nacre_context_last_error(ctx), "material: eta: must be in [0.3, 3]") != NULL);
        }
        const float good_eta[] = {(float)NACRE_ETA_MIN, 1.0f, (float)NACRE_ETA_MAX};
        for (int i = 0; i < 3; i++) {
            te.eta = good_eta[i];
            CHECK(nacre_scene_add_material(scene, &te, &mat) == NACRE_OK);
        }
    }
    nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_SPOT);
    ld.outer_angle = 10;
    ld.inner_angle = 20;
    nacre_light light;
    CHECK(nacre_scene_add_light(scene, &ld, &light) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "inner_angle") != NULL);
    nacre_camera_desc cam = nacre_camera_desc_defaults();
    cam.fov_y = 180;
    CHECK(nacre_scene_set_camera(scene, &cam) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "fov") != NULL);
    od.transform.scale[1] = 0;
    CHECK(nacre_scene_add_object(scene, &od, &obj) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "scale") != NULL);
    od.transform.scale[1] = 1;
    od.material.id = 99;
    CHECK(nacre_scene_add_object(scene, &od, &obj) == NACRE_ERROR_INVALID_ARGUMENT);

    /* Mesh validation: out-of-range index and NaN position. */
    float pos[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    uint32_t idx[3] = {0, 1, 3};
    nacre_mesh_data bad = {.vertex_count = 3, .triangle_count = 1, .positions = pos, .indices = idx};
    nacre_mesh m2;
    CHECK(nacre_scene_add_mesh(scene, &bad, &m2) != NACRE_OK);
    idx[2] = 2;
    pos[4] = NAN;
    CHECK(nacre_scene_add_mesh(scene, &bad, &m2) != NACRE_OK);
    pos[4] = 0;
    CHECK(nacre_scene_add_mesh(scene, &bad, &m2) == NACRE_OK);

    /* Presets: Jensen's marble and the alias "chicken". */
    nacre_material_desc pm;
    CHECK(nacre_material_preset("marble", &pm));
    CHECK_NEAR(pm.sigma_s[0], 2.19, 1e-6);
    CHECK_NEAR(pm.sigma_a[2], 0.0071, 1e-7);
    CHECK_NEAR(pm.eta, 1.3, 1e-6);
    CHECK(nacre_material_preset("chicken", &pm));
    CHECK(!nacre_material_preset("unobtainium", &pm));

    nacre_scene_destroy(scene);
    nacre_context_destroy(ctx);
}

/* Names of methods, solvers and sources round-trip; unknown names are refused. */
static void test_names(void)
{
    for (int m = 0; m < NACRE_METHOD_COUNT; m++) {
        nacre_method back = NACRE_METHOD_COUNT;
        CHECK(nacre_method_from_name(nacre_method_name((nacre_method)m), &back) && back == (nacre_method)m);
    }
    nacre_diffusion_solver sv;
    CHECK(nacre_solver_from_name("seed", &sv) && sv == NACRE_SOLVER_SEED);
    CHECK(strcmp(nacre_solver_name(NACRE_SOLVER_MULTIGRID), "multigrid") == 0);
    CHECK(!nacre_solver_from_name("jacobi", &sv) && !nacre_solver_from_name(NULL, &sv));
    nacre_diffusion_source so;
    CHECK(nacre_source_from_name("face", &so) && so == NACRE_SOURCE_FACE);
    CHECK(strcmp(nacre_source_name(NACRE_SOURCE_VOLUME), "volume") == 0);
    CHECK(!nacre_source_from_name("Face", &so));
    nacre_method me;
    CHECK(!nacre_method_from_name("raytrace", &me));
}

/* One thread's failure on a shared context, read back after the other threads failed too. */
typedef struct error_job {
    nacre_context *ctx;
    pthread_barrier_t *barrier;
    int index;
    bool own_message;
} error_job;

static void *fail_then_read(void *arg)
{
    error_job *job = arg;
    nacre_material_desc md = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
    md.eta = 10.0f + (float)job->index; /* out of range: the message names the value */
    nacre_scene *s = NULL;
    nacre_material m;
    bool failed = nacre_scene_create(job->ctx, &s) == NACRE_OK && nacre_scene_add_material(s, &md, &m) != NACRE_OK;
    pthread_barrier_wait(job->barrier); /* every thread has failed before any reads */
    char want[32];
    snprintf(want, sizeof(want), "%d", 10 + job->index);
    job->own_message = failed && strstr(nacre_context_last_error(job->ctx), want) != NULL &&
                       nacre_context_last_result(job->ctx) == NACRE_ERROR_INVALID_ARGUMENT;
    pthread_barrier_wait(job->barrier);
    nacre_scene_destroy(s);
    return NULL;
}

static void test_errors_per_thread(void)
{
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    enum { N = 8 };
    pthread_t threads[N];
    error_job jobs[N];
    pthread_barrier_t barrier;
    pthread_barrier_init(&barrier, NULL, N);
    for (int i = 0; i < N; i++) {
        jobs[i] = (error_job){ctx, &barrier, i, false};
        CHECK(pthread_create(&threads[i], NULL, fail_then_read, &jobs[i]) == 0);
    }
    for (int i = 0; i < N; i++) {
        pthread_join(threads[i], NULL);
        CHECK(jobs[i].own_message);
    }
    pthread_barrier_destroy(&barrier);
    /* This thread has not failed: its message is empty whatever the others did. */
    CHECK(strcmp(nacre_context_last_error(ctx), "") == 0 && nacre_context_last_result(ctx) == NACRE_OK);
    nacre_scene *s = NULL;
    CHECK(nacre_scene_create(ctx, &s) == NACRE_OK);
    nacre_material_desc md = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
    md.eta = 7.5f;
    nacre_material m;
    CHECK(nacre_scene_add_material(s, &md, &m) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "7.5") != NULL);
    nacre_context_clear_error(ctx);
    CHECK(strcmp(nacre_context_last_error(ctx), "") == 0 && nacre_context_last_result(ctx) == NACRE_OK);
    nacre_scene_destroy(s);
    nacre_context_destroy(ctx);
}

int main(void)
{
    test_errors_per_thread();
    test_math();
    test_names();
    test_deformers();
    test_scene_commit();
    return TEST_MAIN_END();
}
