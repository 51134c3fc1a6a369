/*
 * test_particles.c: particle systems (src/particles/): the closed-form motion against a fine
 * numerical integration, the alive count of an emitter, determinism and thread-count
 * independence of simulation and splat, mass conservation of the splat, the optical depth of one
 * particle through its fog against the kernel's analytic integral, bad input, and the scene
 * file round trip.
 */
#include "test_util.h"

#include "particles/billboard.h"
#include "particles/particles.h"
#include "scene/medium.h"
#include "scene/scene.h"

#include <nacre/nacre.h>

static nacre_context *make_ctx(int threads)
{
    nacre_context_desc cd;
    memset(&cd, 0, sizeof(cd));
    cd.threads = threads;
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(&cd, &ctx) == NACRE_OK);
    return ctx;
}

static nacre_particles_desc plume(void)
{
    nacre_particles_desc d = nacre_particles_desc_defaults(NACRE_PARTICLES_EMITTER);
    d.shape = NACRE_EMITTER_SPHERE;
    d.emit_radius = 5.0f;
    d.rate = 2500.0f;
    d.lifetime = 4.0f;
    d.velocity[1] = 45.0f;
    d.spread = 18.0f;
    d.speed_jitter = 0.3f;
    d.gravity[0] = 3.0f;
    d.gravity[1] = 6.0f;
    d.drag = 0.35f;
    d.radius = 4.0f;
    d.radius_jitter = 0.3f;
    d.radius_rate = 3.0f;
    d.fade = 0.9f;
    d.seed = 7;
    return d;
}

/* One particle, no spread: the closed form against RK4 with 1e-4 s steps. */
static void test_motion(void)
{
    nacre_context *ctx = make_ctx(1);
    nacre_particles_desc d = nacre_particles_desc_defaults(NACRE_PARTICLES_EMITTER);
    d.rate = 1.0f; /* particle 0 born at t = 0, particle 1 at t = 1 */
    d.lifetime = 10.0f;
    d.velocity[0] = 20.0f;
    d.velocity[1] = 30.0f;
    d.spread = 0.0f;
    d.gravity[1] = -9.81f;
    d.drag = 0.7f;
    nc_particle_set s;
    memset(&s, 0, sizeof(s));
    const double T = 0.75;
    CHECK(nc_particles_simulate(ctx, &d, T, &s) == NACRE_OK);
    CHECK(s.count == 1);
    double x[2] = {0, 0}, v[2] = {20, 30}, h = 1e-4;
    for (int i = 0; i < (int)(T / h + 0.5); i++) {
        double k[4][4], vs[2];
        for (int st = 0; st < 4; st++) {
            double f = st == 0 ? 0 : (st == 3 ? 1.0 : 0.5);
            for (int c = 0; c < 2; c++) /* the forces do not depend on x */
                vs[c] = v[c] + (st ? f * h * k[st - 1][2 + c] : 0);
            k[st][0] = vs[0];
            k[st][1] = vs[1];
            k[st][2] = -0.7 * vs[0];
            k[st][3] = -9.81 - 0.7 * vs[1];
        }
        for (int c = 0; c < 2; c++) {
            x[c] += h / 6 * (k[0][c] + 2 * k[1][c] + 2 * k[2][c] + k[3][c]);
            v[c] += h / 6 * (k[0][2 + c] + 2 * k[1][2 + c] + 2 * k[2][2 + c] + k[3][2 + c]);
        }
    }
    CHECK_NEAR(s.x[0], x[0], 1e-4 * fabs(x[0]));
    CHECK_NEAR(s.y[0], x[1], 1e-4 * fabs(x[1]));
    CHECK_NEAR(s.z[0], 0.0, 1e-6);
    /* Radius and density at age T. */
    CHECK_NEAR(s.radius[0], d.radius, 1e-6);
    /* Alive count: rate 100, life 2, at T = 5: births in (3, 5] at k / 100. */
    d.rate = 100.0f;
    d.lifetime = 2.0f;
    CHECK(nc_particles_simulate(ctx, &d, 5.0, &s) == NACRE_OK);
    CHECK(s.count == 200);
    CHECK(nc_particles_simulate(ctx, &d, 0.5, &s) == NACRE_OK);
    CHECK(s.count == 51); /* k = 0..50 */
    CHECK(nc_particles_simulate(ctx, &d, -1.0, &s) == NACRE_OK);
    CHECK(s.count == 0);
    nc_particle_set_free(ctx, &s);
    nacre_context_destroy(ctx);
}

/* The same state and grid, bit for bit, with 1 and 2 threads; mass conserved. */
/* The grid's block maxima (nc_particle_grid.block_max): each block's value is the largest sample
 * of the blocks around it (3^3, clipped), exactly. Returns the blocks of 0. */
static uint32_t check_block_max(const nc_particle_grid *g, uint32_t res)
{
    uint32_t br = (res + 7) / 8, zeros = 0;
    CHECK(g->block_res == br);
    if (g->block_res != br)
        return 0;
    bool ok = true;
    for (uint32_t bz = 0; bz < br; bz++)
        for (uint32_t by = 0; by < br; by++)
            for (uint32_t bx = 0; bx < br; bx++) {
                float m = 0.0f;
                for (uint32_t z = bz > 0 ? 8 * bz - 8 : 0; z < 8 * bz + 16 && z < res; z++)
                    for (uint32_t y = by > 0 ? 8 * by - 8 : 0; y < 8 * by + 16 && y < res; y++)
                        for (uint32_t x = bx > 0 ? 8 * bx - 8 : 0; x < 8 * bx + 16 && x < res; x++) {
                            float v = g->data[((size_t)z * res + y) * res + x];
                            m = v > m ? v : m;
                        }
                float b = g->block_max[((size_t)bz * br + by) * br + bx];
                ok = ok && b == m;
                zeros += b == 0.0f;
            }
    CHECK(ok);
    return zeros;
}

static void test_splat(void)
{
    nacre_context *c1 = make_ctx(1), *c2 = make_ctx(2);
    nacre_particles_desc d = plume();
    nc_particle_set s1, s2;
    nc_particle_grid g1, g2;
    memset(&s1, 0, sizeof(s1));
    memset(&s2, 0, sizeof(s2));
    memset(&g1, 0, sizeof(g1));
    memset(&g2, 0, sizeof(g2));
    CHECK(nc_particles_simulate(c1, &d, 5.0, &s1) == NACRE_OK);
    CHECK(nc_particles_simulate(c2, &d, 5.0, &s2) == NACRE_OK);
    CHECK(s1.count == 10000 && s2.count == s1.count);
    CHECK(memcmp(s1.x, s2.x, s1.count * sizeof(float)) == 0 && memcmp(s1.y, s2.y, s1.count * sizeof(float)) == 0 &&
          memcmp(s1.radius, s2.radius, s1.count * sizeof(float)) == 0);
    CHECK(nc_particles_splat(c1, &s1, 64, &g1) == NACRE_OK);
    CHECK(nc_particles_splat(c2, &s2, 64, &g2) == NACRE_OK);
    size_t cells = (size_t)64 * 64 * 64;
    CHECK(memcmp(g1.data, g2.data, cells * sizeof(float)) == 0);
    CHECK(memcmp(g1.origin, g2.origin, sizeof(g1.origin)) == 0);

    /* Mass, and the empty outer layers that make the trilinear field integrate to the sum. */
    for (int pass = 0; pass < 3; pass++) {
        if (pass == 1) { /* particles under half a cell, between samples: the linear fallback */
            for (uint32_t i = 0; i < s1.count; i++)
                s1.radius[i] = i % 2 ? 0.05f : s1.radius[i];
        }
        uint32_t res = pass == 2 ? 128 : 64;
        CHECK(nc_particles_splat(c2, &s1, res, &g1) == NACRE_OK);
        double sum = 0.0, edge = 0.0;
        for (uint32_t z = 0; z < res; z++)
            for (uint32_t y = 0; y < res; y++)
                for (uint32_t x = 0; x < res; x++) {
                    double v = g1.data[((size_t)z * res + y) * res + x];
                    sum += v;
                    bool outer = x == 0 || y == 0 || z == 0 || x == res - 1 || y == res - 1 || z == res - 1;
                    edge += outer ? v : 0.0;
                }
        double V = (double)g1.spacing[0] * g1.spacing[1] * g1.spacing[2], m = nc_particles_mass(&s1);
        printf("splat %u^3 pass %d: grid mass %.9g, particles %.9g, rel %.2e\n", res, pass, sum * V, m,
               fabs(sum * V - m) / m);
        CHECK(fabs(sum * V - m) <= 1e-4 * m);
        CHECK(edge == 0.0);
        uint32_t zeros = check_block_max(&g1, res);
        printf("  block maxima: %u of %u blocks of 0 (with their neighbours)\n", zeros, ((res + 7) / 8) * ((res + 7) / 8) * ((res + 7) / 8));
        CHECK(zeros > 0);
    }
    /* A resolution that is not a multiple of 8 (partial blocks at the far sides). */
    CHECK(nc_particles_splat(c2, &s1, 37, &g1) == NACRE_OK);
    check_block_max(&g1, 37);

    /* Large particles go to the coarse level: the grid is the same with 1 and 2 threads, and
     * against every particle splatted on the grid itself (fine_only) it keeps the mass and
     * stays within a stated error (docs/accuracy.md). */
    for (uint32_t res = 128; res <= 256; res *= 2) {
        /* At 128^3 the plume's particles reach R = 6 cells (level 1), at 256^3 R = 12 (level 2). */
        nc_particle_grid gf, gm, gm1;
        memset(&gf, 0, sizeof(gf));
        memset(&gm, 0, sizeof(gm));
        memset(&gm1, 0, sizeof(gm1));
        gf.fine_only = true;
        CHECK(nc_particles_splat(c2, &s2, res, &gf) == NACRE_OK);
        CHECK(nc_particles_splat(c2, &s2, res, &gm) == NACRE_OK);
        CHECK(nc_particles_splat(c1, &s2, res, &gm1) == NACRE_OK);
        const size_t n3 = (size_t)res * res * res;
        CHECK(memcmp(gm.data, gm1.data, n3 * sizeof(float)) == 0);
        uint32_t coarse = 0, coarse2 = 0;
        for (uint32_t i = 0; i < s2.count; i++) {
            coarse += gm.level[i] > 0;
            coarse2 += gm.level[i] == 2;
        }
        double sf = 0.0, sm = 0.0, l1 = 0.0, worst = 0.0;
        for (size_t c = 0; c < n3; c++) {
            sf += gf.data[c], sm += gm.data[c];
            double d = fabs((double)gm.data[c] - gf.data[c]);
            l1 += d;
            worst = fmax(worst, d);
        }
        printf("%u^3, coarse levels: %u of %u particles (%u on level 2); against the fine splat: mass rel %.2e, "
               "L1 rel %.4f, max %.4f of the maximum %.4g\n", res, coarse, s2.count, coarse2, fabs(sm - sf) / sf,
               l1 / sf, worst / gf.max_value, (double)gf.max_value);
        CHECK(coarse > s2.count / 4); /* the plume's grown particles */
        CHECK(res == 128 ? coarse2 == 0 : coarse2 > s2.count / 4);
        CHECK(fabs(sm - sf) <= 1e-4 * sf);
        CHECK(l1 / sf < 0.02);
        /* At 256^3 level 1 alone already differs by 2.1% of the maximum (docs/accuracy.md). */
        CHECK(worst < (res == 128 ? 0.02 : 0.025) * gf.max_value);
        /* The grid reused for a sparse system after a dense one (bricks left as they were when
         * nothing reaches them) equals a new grid's splat of it, bit for bit. */
        nc_particle_set sp;
        memset(&sp, 0, sizeof(sp));
        CHECK(nc_particles_simulate(c2, &d, 5.0, &sp) == NACRE_OK);
        for (uint32_t i = 0; i < sp.count; i++)
            sp.radius[i] = i % 50 ? 0.05f : 0.5f;
        nc_particle_grid fresh;
        memset(&fresh, 0, sizeof(fresh));
        for (int k = 0; k < 2; k++) {
            CHECK(nc_particles_splat(c2, &sp, res, &gm) == NACRE_OK);
            CHECK(nc_particles_splat(c1, &sp, res, &fresh) == NACRE_OK);
            CHECK(memcmp(gm.data, fresh.data, n3 * sizeof(float)) == 0);
            CHECK(gm.max_value == fresh.max_value && gm.max_value > 0.0f);
            check_block_max(&gm, res);
            CHECK(nc_particles_splat(c2, &s2, res, &gm) == NACRE_OK); /* dense again, then sparse */
            CHECK(memcmp(gm.data, gm1.data, n3 * sizeof(float)) == 0);
        }
        nc_particle_set_free(c2, &sp);
        nc_particle_grid_free(c1, &fresh);
        nc_particle_grid_free(c2, &gf);
        nc_particle_grid_free(c2, &gm);
        nc_particle_grid_free(c1, &gm1);
    }
    nc_particle_set_free(c1, &s1);
    nc_particle_set_free(c2, &s2);
    nc_particle_grid_free(c1, &g1);
    nc_particle_grid_free(c2, &g2);
    nacre_context_destroy(c1);
    nacre_context_destroy(c2);
}

/* One particle in a scene: the optical depth through its centre along x, read through the fog
 * the commit made (placement, volume frame, trilinear lookups), against sigma_t d0 K R. */
static void test_fog_optical_depth(void)
{
    nacre_context *ctx = make_ctx(0);
    nacre_scene *scene = NULL;
    CHECK(nacre_scene_create(ctx, &scene) == NACRE_OK);
    float pos[3] = {10.0f, 20.0f, -5.0f};
    nacre_particles_desc d = nacre_particles_desc_defaults(NACRE_PARTICLES_LIST);
    d.count = 1;
    d.positions = pos;
    d.radius = 8.0f;
    d.density = 2.0f;
    d.grid_resolution = 96;
    d.sigma_a[0] = d.sigma_a[1] = d.sigma_a[2] = 0.05f;
    d.sigma_s[0] = d.sigma_s[1] = d.sigma_s[2] = 0.25f;
    nacre_particles h;
    CHECK(nacre_scene_add_particles(scene, &d, &h) == NACRE_OK);
    CHECK(nacre_scene_commit(scene, 0.0) == NACRE_OK);
    CHECK(scene->fog_count == 1 && nacre_scene_fog_count(scene) == 0);
    CHECK(nacre_scene_particles_alive(scene, h) == 1);
    const nc_fog_rec *f = &scene->fogs[0];
    enum { N = 4000 };
    double tau = 0.0, dx = 24.0 / N;
    for (int i = 0; i < N; i++) {
        nc_vec3 p = nc_v3(pos[0] - 12.0f + (float)((i + 0.5) * dx), pos[1], pos[2]);
        nc_vec3 q = nc_mat4_point(&f->world_to_local, p);
        float qv[3] = {q.x, q.y, q.z}, sa[3], ss[3];
        nc_medium_eval(scene, &f->medium, qv, 1, sa, ss);
        tau += (sa[0] + ss[0]) * dx;
    }
    double expect = 0.3 * 2.0 * NC_PARTICLE_KERNEL_K * 8.0;
    printf("optical depth through one particle: %.6f, analytic %.6f\n", tau, expect);
    CHECK(fabs(tau - expect) <= 0.02 * expect);
    /* Lookups 8 at a time skip the blocks of 0 (the grid's block maxima): two small particles far
     * apart (most blocks of their grid empty), a batch of points half over the whole box and
     * half around the particles equals the scalar lookup (which reads every sample) bit for bit. */
    nacre_scene *two = NULL;
    CHECK(nacre_scene_create(ctx, &two) == NACRE_OK);
    float pos2[6] = {0.0f, 0.0f, 0.0f, 40.0f, 30.0f, -20.0f};
    d.count = 2;
    d.positions = pos2;
    d.radius = 3.0f;
    nacre_particles h2;
    CHECK(nacre_scene_add_particles(two, &d, &h2) == NACRE_OK && nacre_scene_commit(two, 0.0) == NACRE_OK);
    const nc_volume_rec *vr = nc_scene_particle_volume(two, 0);
    CHECK(vr && vr->block_max && vr->block_res == (96 + 7) / 8);
    const nc_fog_rec *f2 = &two->fogs[0];
    enum { NB = 4003 };
    static float bp[3 * NB], ba[3 * NB], bs[3 * NB];
    uint32_t zero = 0, same = 0;
    for (int i = 0; i < NB; i++) {
        float u[3];
        for (int k = 0; k < 3; k++)
            u[k] = (float)(((i * 7919 + k * 104729) % 1000) / 1000.0 - 0.5);
        nc_vec3 w = i % 2 ? nc_v3(-5 + 50 * (u[0] + 0.5f), -5 + 40 * (u[1] + 0.5f), -25 + 30 * (u[2] + 0.5f))
                          : nc_v3(pos2[i % 4 == 0 ? 0 : 3] + 7 * u[0], pos2[i % 4 == 0 ? 1 : 4] + 7 * u[1],
                                  pos2[i % 4 == 0 ? 2 : 5] + 7 * u[2]);
        nc_vec3 q = nc_mat4_point(&f2->world_to_local, w);
        bp[3 * i] = q.x, bp[3 * i + 1] = q.y, bp[3 * i + 2] = q.z;
    }
    nc_medium_eval(two, &f2->medium, bp, NB, ba, bs);
    for (int i = 0; i < NB; i++) {
        float dv = nc_volume_density(vr, bp + 3 * i); /* the scalar lookup: every sample read */
        bool eq = true;
        for (int c = 0; c < 3; c++)
            eq = eq && ba[3 * i + c] == dv * f2->medium.sigma_a[c] && bs[3 * i + c] == dv * f2->medium.sigma_s[c];
        same += eq;
        zero += dv == 0.0f;
    }
    printf("batch lookups over two particles' box: %u of %d equal single lookups, %u of them 0\n", same, NB, zero);
    CHECK(same == NB);
    CHECK(zero > NB / 4 && zero < NB - NB / 4);
    nacre_scene_destroy(two);
    /* A new fog keeps the user's fogs first; the particles' fog comes back at the next commit. */
    nacre_fog_desc fd = nacre_fog_desc_defaults(NACRE_FOG_GLOBAL);
    nacre_fog fh;
    CHECK(nacre_scene_add_fog(scene, &fd, &fh) == NACRE_OK && fh.id == 1);
    CHECK(nacre_scene_commit(scene, 0.0) == NACRE_OK);
    CHECK(scene->fog_count == 2 && nacre_scene_fog_count(scene) == 1 && scene->fogs[1].desc.shape == NACRE_FOG_BOX);
    nacre_scene_destroy(scene);
    nacre_context_destroy(ctx);
}

static void test_bad_input(void)
{
    nacre_context *ctx = make_ctx(0);
    nacre_scene *scene = NULL;
    CHECK(nacre_scene_create(ctx, &scene) == NACRE_OK);
    nacre_particles h;
    nacre_particles_desc d = plume();
    d.radius = -1.0f;
    CHECK(nacre_scene_add_particles(scene, &d, &h) == NACRE_ERROR_INVALID_ARGUMENT && test_error_names(ctx, "radius"));
    d = plume();
    d.density = -0.5f;
    CHECK(nacre_scene_add_particles(scene, &d, &h) == NACRE_ERROR_INVALID_ARGUMENT && test_error_names(ctx, "density"));
    d = plume();
    d.lifetime = 0.0f;
    CHECK(nacre_scene_add_particles(scene, &d, &h) == NACRE_ERROR_INVALID_ARGUMENT && test_error_names(ctx, "lifetime"));
    d = plume();
    d.rate = 1e8f; /* 4e8 alive */
    CHECK(nacre_scene_add_particles(scene, &d, &h) == NACRE_ERROR_INVALID_ARGUMENT && test_error_names(ctx, "rate"));
    d = plume();
    d.grid_resolution = 4;
    CHECK(nacre_scene_add_particles(scene, &d, &h) == NACRE_ERROR_INVALID_ARGUMENT &&
          test_error_names(ctx, "grid_resolution"));
    float pos[6] = {0, 0, 0, 1, NAN, 0}, rad[2] = {1.0f, -2.0f};
    d = nacre_particles_desc_defaults(NACRE_PARTICLES_LIST);
    d.count = 2;
    d.positions = pos;
    CHECK(nacre_scene_add_particles(scene, &d, &h) == NACRE_ERROR_INVALID_ARGUMENT &&
          test_error_names(ctx, "positions[1]"));
    pos[4] = 0.0f;
    d.radii = rad;
    CHECK(nacre_scene_add_particles(scene, &d, &h) == NACRE_ERROR_INVALID_ARGUMENT && test_error_names(ctx, "radii[1]"));
    d.count = 100000000u;
    CHECK(nacre_scene_add_particles(scene, &d, &h) == NACRE_ERROR_INVALID_ARGUMENT && test_error_names(ctx, "count"));
    CHECK(nacre_scene_particles_count(scene) == 0);
    /* Scene files: the field path. */
    static const char bad[] = "{\"particles\": [{\"type\": \"list\", \"positions\": [[0,0,0],[1,2,3]], "
                              "\"radii\": [1, -1]}]}";
    nacre_scene *s2 = NULL;
    CHECK(nacre_scene_load_json(ctx, bad, sizeof(bad) - 1, "bad.json", NULL, &s2, NULL) != NACRE_OK);
    CHECK(test_error_names(ctx, "particles[0].radii[1]"));
    static const char bad2[] = "{\"particles\": [{\"lifetime\": 0}]}";
    CHECK(nacre_scene_load_json(ctx, bad2, sizeof(bad2) - 1, "bad.json", NULL, &s2, NULL) != NACRE_OK);
    CHECK(test_error_names(ctx, "lifetime"));
    static const char bad3[] = "{\"particles\": [{\"rate\": 1e8, \"lifetime\": 1}]}";
    CHECK(nacre_scene_load_json(ctx, bad3, sizeof(bad3) - 1, "bad.json", NULL, &s2, NULL) != NACRE_OK);
    CHECK(test_error_names(ctx, "rate"));
    static const char bad4[] = "{\"particles\": [{\"type\": \"list\", \"positions\": [[0,0,0]], \"rate\": 3}]}";
    CHECK(nacre_scene_load_json(ctx, bad4, sizeof(bad4) - 1, "bad.json", NULL, &s2, NULL) != NACRE_OK);
    CHECK(test_error_names(ctx, "rate"));
    nacre_scene_destroy(scene);
    nacre_context_destroy(ctx);
}

/* Save and load: the same descs, and the same grid at the same time. */
static void test_round_trip(void)
{
    nacre_context *ctx = make_ctx(0);
    nacre_scene *scene = NULL;
    CHECK(nacre_scene_create(ctx, &scene) == NACRE_OK);
    nacre_particles_desc d = plume(), back;
    d.rate = 300.0f;
    d.grid_resolution = 32;
    nacre_particles h;
    CHECK(nacre_scene_add_particles(scene, &d, &h) == NACRE_OK);
    float pos[6] = {0.1f, 0.2f, 0.3f, 1.0f / 3.0f, 2, 3}, den[2] = {0.7f, 1.1f};
    nacre_particles_desc l = nacre_particles_desc_defaults(NACRE_PARTICLES_LIST);
    l.count = 2;
    l.positions = pos;
    l.densities = den;
    CHECK(nacre_scene_add_particles(scene, &l, &h) == NACRE_OK);
    char *json = NULL;
    size_t len = 0;
    CHECK(nacre_scene_save_json(scene, NULL, NACRE_TEST_TMP, &json, &len) == NACRE_OK);
    nacre_scene *s2 = NULL;
    CHECK(json && nacre_scene_load_json(ctx, json, len, "saved.json", NACRE_TEST_TMP, &s2, NULL) == NACRE_OK);
    nacre_free(ctx, json);
    CHECK(s2 && nacre_scene_particles_count(s2) == 2);
    if (s2) {
        CHECK(nacre_scene_get_particles(s2, (nacre_particles){1}, &back) == NACRE_OK);
        CHECK(memcmp(back.velocity, d.velocity, sizeof(d.velocity)) == 0 && back.rate == d.rate &&
              back.drag == d.drag && back.seed == d.seed && back.fade == d.fade && back.grid_resolution == 32);
        CHECK(nacre_scene_get_particles(s2, (nacre_particles){2}, &back) == NACRE_OK);
        CHECK(back.type == NACRE_PARTICLES_LIST && back.count == 2 && back.radii == NULL && back.densities &&
              memcmp(back.positions, pos, sizeof(pos)) == 0 && memcmp(back.densities, den, sizeof(den)) == 0);
        CHECK(nacre_scene_commit(scene, 1.5) == NACRE_OK && nacre_scene_commit(s2, 1.5) == NACRE_OK);
        CHECK(scene->fog_count == 2 && s2->fog_count == 2);
        const nc_volume_rec *a = nc_scene_volume(scene, scene->fogs[0].desc.pattern.volume);
        const nc_volume_rec *b = nc_scene_volume(s2, s2->fogs[0].desc.pattern.volume);
        CHECK(a && b && memcmp(a->data, b->data, 32 * 32 * 32 * sizeof(float)) == 0);
        /* Another time: another state, and the environment version moves for the renderers. */
        uint64_t env = s2->versions.environment;
        CHECK(nacre_scene_commit(s2, 2.0) == NACRE_OK && s2->versions.environment != env);
        env = s2->versions.environment;
        CHECK(nacre_scene_commit(s2, 2.0) == NACRE_OK && s2->versions.environment == env);
        nacre_scene_destroy(s2);
    }
    nacre_scene_destroy(scene);
    nacre_context_destroy(ctx);
}

/* r(x) (seed 003 figures 3.5-3.8): the billboard of one particle seen through its centre,
 * reconstructed over its chord, against the kernel's density along that chord. */
static void test_remap(void)
{
    const float R = 3.0f, d0 = 1.7f, sig = 0.4f;
    float v[3] = {0.0f, 0.0f, -50.0f}, d[3] = {0.0f, 0.0f, -1.0f}, w, tm, h;
    CHECK(nc_billboard_hit(v, d, R, &w, &tm, &h));
    CHECK_NEAR(w, 1.0, 1e-6);
    CHECK_NEAR(tm, 50.0, 1e-4);
    CHECK_NEAR(h, R, 1e-5);
    const double tau = sig * d0 * NC_PARTICLE_KERNEL_K * R * w, near = tm - h, len = 2.0 * h;
    enum { N = 20000 };
    double rec = 0.0, exact = 0.0, l1 = 0.0, l1_flat = 0.0, one = 0.0;
    for (int i = 0; i < N; i++) {
        double t = near + (i + 0.5) * len / N, x = (t - near) / len;
        double s_rec = tau / len * nc_billboard_remap((float)x, NC_BILLBOARD_REMAP_T);
        double u = (t - tm) / R, s_exact = sig * d0 * exp(-4.5 * u * u);
        rec += s_rec * len / N;
        exact += s_exact * len / N;
        l1 += fabs(s_rec - s_exact) * len / N;
        l1_flat += fabs(tau / len - s_exact) * len / N;
        one += nc_billboard_remap((float)x, 0.3f) / N;
    }
    printf("r(x): optical depth reconstructed %.6f, exact %.6f; L1 error %.3f of it (constant sigma_t: %.3f)\n", rec,
           exact, l1 / exact, l1_flat / exact);
    CHECK_NEAR(one, 1.0, 1e-3);      /* r integrates to 1 for any T */
    CHECK_NEAR(rec, exact, 1e-3 * exact); /* the pixel keeps its optical depth */
    CHECK(l1 < 0.28 * exact);         /* the tent follows the bell: 0.265 */
    CHECK(l1 < 0.5 * l1_flat);        /* constant sigma_t over the chord: 0.75 */
    CHECK(nc_billboard_remap(0.0f, 1.0f) == 0.0f && nc_billboard_remap(1.0f, 1.0f) == 0.0f);
    /* A ray passing at R / 2: the column is the kernel's there. */
    v[0] = 0.5f * R;
    CHECK(nc_billboard_hit(v, d, R, &w, &tm, &h));
    CHECK_NEAR(w, exp(-4.5 * 0.25), 1e-5);
    CHECK_NEAR(h, R * sqrt(0.75), 1e-5);
    v[0] = 1.01f * R;
    CHECK(!nc_billboard_hit(v, d, R, &w, &tm, &h));
    double worst = 0.0;
    for (float x = -80.0f; x <= 0.0f; x += 0.01f)
        worst = fmax(worst, fabs(nc_fast_exp(x) / exp(x) - 1.0));
    CHECK(worst < 1e-5);
}

/* The billboard and sprite passes give the same image with 1 and 2 threads. */
static void test_pass_threads(void)
{
    static const char scene_json[] =
        "{\"camera\": {\"position\": [0, 20, 90], \"target\": [0, 15, 0], \"fov\": 40},"
        " \"environment\": [0.2, 0.2, 0.25],"
        " \"materials\": {\"g\": {\"type\": \"opaque\", \"diffuse\": 0.5}},"
        " \"lights\": [{\"type\": \"directional\", \"direction\": [-0.4, -1, -0.3], \"irradiance\": 2}],"
        " \"objects\": [{\"shape\": {\"type\": \"plane\", \"size\": [200, 200]}, \"material\": \"g\"}],"
        " \"particles\": [{\"rate\": 500, \"lifetime\": 2, \"velocity\": [0, 15, 0], \"spread\": 25,"
        " \"radius\": 2, \"radius_rate\": 2, \"sigma_s\": 0.05, \"sigma_a\": 0.01, \"grid_resolution\": 32}]}";
    nacre_image img[2][2];
    nacre_context *ctxs[2];
    nacre_scene *scenes[2];
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = NACRE_METHOD_PHONG;
    rs.width = 160;
    rs.height = 120;
    for (int k = 0; k < 2; k++) {
        ctxs[k] = make_ctx(k + 1);
        scenes[k] = NULL;
        CHECK(nacre_scene_load_json(ctxs[k], scene_json, sizeof(scene_json) - 1, "t.json", NULL, &scenes[k], NULL) ==
              NACRE_OK);
        CHECK(nacre_scene_commit(scenes[k], 3.0) == NACRE_OK);
        for (int p = 0; p < 2; p++) {
            memset(&img[k][p], 0, sizeof(img[k][p]));
            nacre_render_stats st;
            rs.particles = p ? NACRE_PARTICLES_DRAW_SPRITES : NACRE_PARTICLES_DRAW_BILLBOARDS;
            CHECK(nacre_render(scenes[k], &rs, &img[k][p], &st) == NACRE_OK);
            CHECK(st.stage_ran[NACRE_STAGE_PARTICLES]);
        }
    }
    for (int p = 0; p < 2; p++) {
        bool same = true;
        for (int32_t y = 0; y < 120; y++)
            same &= memcmp(img[0][p].pixels + (size_t)y * img[0][p].stride, img[1][p].pixels + (size_t)y * img[1][p].stride,
                           160 * 3 * sizeof(float)) == 0;
        CHECK(same);
    }
    /* The plume is drawn: the image differs from the voxel setting's (the fog pass). */
    nacre_image vox = {0};
    rs.particles = NACRE_PARTICLES_DRAW_VOXEL;
    CHECK(nacre_render(scenes[1], &rs, &vox, NULL) == NACRE_OK);
    double diff = 0.0;
    for (int32_t y = 0; y < 120; y++)
        for (int32_t x = 0; x < 160 * 3; x++)
            diff += fabs(vox.pixels[(size_t)y * vox.stride + x] - img[1][0].pixels[(size_t)y * img[1][0].stride + x]);
    CHECK(diff > 1.0);
    nacre_image_free(ctxs[1], &vox);
    for (int k = 0; k < 2; k++) {
        for (int p = 0; p < 2; p++)
            nacre_image_free(ctxs[k], &img[k][p]);
        nacre_scene_destroy(scenes[k]);
        nacre_context_destroy(ctxs[k]);
    }
}

int main(void)
{
    test_remap();
    test_pass_threads();
    test_motion();
    test_splat();
    test_fog_optical_depth();
    test_bad_input();
    test_round_trip();
    return TEST_MAIN_END();
}
