/*
 * test_particles_iso.c: the isosurface of voxelized particles (seed 003 §3.2.2, figure 3.15).
 * One particle's density is d0 exp(-4.5 r^2 / R^2), so the level L is crossed on the sphere of
 * radius R sqrt(ln(d0 / L) / 4.5): the traced hits and normals against that sphere, the surface
 * shading of the ray-march pass against the analytic shading of the sphere (no medium: Fresnel
 * reflection of the environment, GGX highlight of the sun, the rest of the scene behind; an
 * absorbing medium: the analytic transmittances along the same rays, the refracted ones
 * included), the option off (or never reached) giving the image without it bit for bit, one
 * thread the same image as two, the froxel and analytic fog settings routed to the march, bad
 * values failing with one line naming the field, and the scene file round trip.
 */
#include "test_util.h"

#include "core/optics.h"
#include "particles/particles.h"
#include "scene/scene.h"

#include <nacre/nacre.h>

#define PI_D 3.14159265358979323846
#define R0 1.0f
#define D0 10.0f
#define LEVEL 1.0f

static const float CENTRE[3] = {0.3f, -0.2f, 0.1f};

static nacre_context *make_ctx(int threads)
{
    nacre_context_desc cd;
    memset(&cd, 0, sizeof(cd));
    cd.threads = threads;
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(&cd, &ctx) == NACRE_OK);
    return ctx;
}

static double iso_radius(void) { return R0 * sqrt(log((double)D0 / LEVEL) / 4.5); }

/* Ray (o, unit d) against the sphere (CENTRE, r): the nearer hit, false if none. */
static bool sphere_hit(const float o[3], const float d[3], double r, double *t)
{
    double v[3] = {o[0] - CENTRE[0], o[1] - CENTRE[1], o[2] - CENTRE[2]};
    double b = v[0] * d[0] + v[1] * d[1] + v[2] * d[2], c = v[0] * v[0] + v[1] * v[1] + v[2] * v[2] - r * r;
    double disc = b * b - c;
    if (disc < 0.0)
        return false;
    *t = -b - sqrt(disc);
    return *t > 0.0;
}

/* Hits and normals of rays from one eye through a 61 x 61 fan against the analytic sphere. */
static void test_geometry(void)
{
    nacre_context *ctx = make_ctx(0);
    nacre_scene *scene = NULL;
    CHECK(nacre_scene_create(ctx, &scene) == NACRE_OK);
    nacre_particles_desc d = nacre_particles_desc_defaults(NACRE_PARTICLES_LIST);
    d.count = 1;
    d.positions = CENTRE;
    d.radius = R0;
    d.density = D0;
    d.grid_resolution = 64;
    d.isosurface.density = LEVEL;
    nacre_particles h;
    CHECK(nacre_scene_add_particles(scene, &d, &h) == NACRE_OK);
    CHECK(nacre_scene_commit(scene, 0.0) == NACRE_OK);
    const nc_particle_grid *g = nc_scene_particle_grid(scene, 0, NULL);
    CHECK(g != NULL);
    if (!g) {
        nacre_scene_destroy(scene);
        nacre_context_destroy(ctx);
        return;
    }
    const double r = iso_radius(), vox = g->spacing[0];
    const float eye[3] = {CENTRE[0] + 0.9f, CENTRE[1] + 1.7f, CENTRE[2] + 4.0f};
    double worst_t = 0.0, worst_deg = 0.0, sum_t = 0.0;
    int n_t = 0, hits = 0, bad_miss = 0, bad_hit = 0;
    for (int j = 0; j < 61; j++)
        for (int i = 0; i < 61; i++) {
            float target[3] = {CENTRE[0] + (i - 30) * 0.03f, CENTRE[1] + (j - 30) * 0.03f, CENTRE[2]};
            float dir[3] = {target[0] - eye[0], target[1] - eye[1], target[2] - eye[2]};
            float len = sqrtf(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
            for (int c = 0; c < 3; c++)
                dir[c] /= len;
            double ta, tb;
            bool want = sphere_hit(eye, dir, r, &ta), got = nc_particle_iso_hit(g, LEVEL, eye, dir, 0.0, 100.0, &tb);
            /* Far from the silhouette (a voxel), hit and miss must agree. */
            double inner, outer;
            bool in_inner = sphere_hit(eye, dir, r - vox, &inner), in_outer = sphere_hit(eye, dir, r + vox, &outer);
            if (in_inner && !got)
                bad_miss++;
            if (!in_outer && got)
                bad_hit++;
            if (!(want && got && in_inner))
                continue;
            hits++;
            double qa[3] = {eye[0] + ta * dir[0] - CENTRE[0], eye[1] + ta * dir[1] - CENTRE[1],
                            eye[2] + ta * dir[2] - CENTRE[2]};
            /* Depth errors grow as 1 / cos towards the silhouette: held where cos >= 0.3. The
             * trilinear field itself is off the Gaussian by up to ~h^2 / 8 |D''| per axis, which
             * moves the level by ~0.02 voxel per axis at this radius: the bound is 0.05 voxel. */
            if (-(qa[0] * dir[0] + qa[1] * dir[1] + qa[2] * dir[2]) / r >= 0.3) {
                worst_t = fmax(worst_t, fabs(tb - ta));
                sum_t += fabs(tb - ta);
                n_t++;
            }
            float p[3] = {eye[0] + (float)tb * dir[0], eye[1] + (float)tb * dir[1], eye[2] + (float)tb * dir[2]}, n[3];
            CHECK(nc_particle_iso_normal(g, p, n));
            double q[3] = {eye[0] + ta * dir[0] - CENTRE[0], eye[1] + ta * dir[1] - CENTRE[1],
                           eye[2] + ta * dir[2] - CENTRE[2]};
            double ql = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
            double cs = (n[0] * q[0] + n[1] * q[1] + n[2] * q[2]) / ql;
            worst_deg = fmax(worst_deg, acos(fmin(cs, 1.0)) * 180.0 / PI_D);
        }
    printf("iso geometry: %d hits (%d at cos >= 0.3), depth error mean %.3g, worst %.3g voxel (%.3g); worst "
           "normal error %.3g deg\n", hits, n_t, sum_t / (n_t > 0 ? n_t : 1) / vox, worst_t / vox, worst_t, worst_deg);
    CHECK(hits > 1000);
    CHECK(bad_miss == 0 && bad_hit == 0);
    CHECK(n_t > 1000 && worst_t < 0.05 * vox);
    CHECK(worst_deg < 0.5);
    /* A ray starting inside finds no surface to enter; a level above the peak is never met. */
    float inside[3] = {CENTRE[0], CENTRE[1], CENTRE[2]}, up[3] = {0, 1, 0};
    double t;
    CHECK(!nc_particle_iso_hit(g, LEVEL, inside, up, 0.0, 100.0, &t));
    CHECK(!nc_particle_iso_hit(g, 2.0f * g->max_value, eye, (float[3]){-0.2f, -0.4f, -0.9f}, 0.0, 100.0, &t));
    nacre_scene_destroy(scene);
    nacre_context_destroy(ctx);
}

/* The blob in front of a perspective camera with a sun; medium coefficients zero so that only
 * the surface shows. */
static const char shading_scene[] =
    "{\"camera\": {\"type\": \"perspective\", \"position\": [0, 0, 10], \"target\": [0, 0, 0], \"up\": [0, 1, 0],"
    " \"fov\": 17},"
    " \"environment\": [0.2, 0.25, 0.3],"
    " \"lights\": [{\"type\": \"directional\", \"direction\": [-0.3, -0.5, -0.8], \"irradiance\": [2, 1.8, 1.6]}],"
    " \"materials\": {\"g\": {\"type\": \"opaque\", \"diffuse\": 0.5}},"
    " \"objects\": [{\"shape\": {\"type\": \"plane\", \"size\": [4, 4]}, \"material\": \"g\","
    "   \"transform\": {\"translate\": [0, 0, -3], \"rotate\": [90, 0, 0]}}],"
    " \"particles\": [{\"type\": \"list\", \"positions\": [[0.3, -0.2, 0.1]], \"radius\": 1, \"density\": 10,"
    "   \"sigma_s\": 0, \"grid_resolution\": 64, \"sigma_a\": %s%s}]}";

static nacre_scene *load_absorbing(nacre_context *ctx, const char *sigma_a, const char *iso)
{
    char text[2048];
    snprintf(text, sizeof(text), shading_scene, sigma_a, iso);
    nacre_scene *s = NULL;
    if (nacre_scene_load_json(ctx, text, strlen(text), "iso.json", NULL, &s, NULL) != NACRE_OK) {
        printf("load: %s\n", nacre_context_last_error(ctx));
        return NULL;
    }
    CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
    return s;
}

/* The surface of the shading checks: level 1, eta 1.5, GGX alpha 0.3. */
static const char ISO[] = ", \"isosurface\": {\"density\": 1, \"ior\": 1.5, \"roughness\": 0.3}";

static nacre_scene *load(nacre_context *ctx, const char *iso) { return load_absorbing(ctx, "0", iso); }

static bool same_image(const nacre_image *a, const nacre_image *b)
{
    bool same = a->width == b->width && a->height == b->height;
    for (int32_t y = 0; same && y < a->height; y++)
        same = memcmp(a->pixels + (size_t)y * a->stride, b->pixels + (size_t)y * b->stride,
                      (size_t)a->width * 3 * sizeof(float)) == 0;
    return same;
}


/* The GGX highlight of a light of unit irradiance from l on the sphere's point of normal nrm seen
 * from v (cs = nrm . v), Fresnel weighted, times cos_l: written from the formulas, apart from the
 * pass's code. */
static double ggx(const double nrm[3], const double v[3], const double l[3], double cs, double alpha, double eta)
{
    double hv[3] = {l[0] + v[0], l[1] + v[1], l[2] + v[2]};
    double hl = sqrt(hv[0] * hv[0] + hv[1] * hv[1] + hv[2] * hv[2]);
    double nh = (nrm[0] * hv[0] + nrm[1] * hv[1] + nrm[2] * hv[2]) / hl;
    double lh = (l[0] * hv[0] + l[1] * hv[1] + l[2] * hv[2]) / hl;
    double nl = nrm[0] * l[0] + nrm[1] * l[1] + nrm[2] * l[2];
    if (!(nl > 0.0))
        return 0.0;
    double a2 = alpha * alpha, q = nh * nh * (a2 - 1.0) + 1.0, D = a2 / (PI_D * q * q);
    double g1l = 2.0 * nl / (nl + sqrt(a2 + (1.0 - a2) * nl * nl));
    double g1v = 2.0 * cs / (cs + sqrt(a2 + (1.0 - a2) * cs * cs));
    return D * g1l * g1v * nc_fresnel_dielectric(lh, eta) / (4.0 * cs);
}
static void test_shading(void)
{
    nacre_context *ctx = make_ctx(2);
    nacre_scene *off = load(ctx, ""), *on = load(ctx, ISO);
    nacre_scene *high = load(ctx, ", \"isosurface\": {\"density\": 50}");
    CHECK(off && on && high);
    if (!off || !on || !high)
        return;
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = NACRE_METHOD_PHONG;
    rs.width = 120;
    rs.height = 90;
    rs.particles = NACRE_PARTICLES_DRAW_VOXEL;
    rs.volumetrics.mode = NACRE_VOLUMETRICS_RAYMARCH;
    nacre_image base = {0}, img = {0}, never = {0}, fro = {0}, ana = {0};
    nacre_render_stats st;
    CHECK(nacre_render(off, &rs, &base, NULL) == NACRE_OK);
    CHECK(nacre_render(on, &rs, &img, &st) == NACRE_OK && st.stage_ran[NACRE_STAGE_RAYMARCH]);
    CHECK(nacre_render(high, &rs, &never, NULL) == NACRE_OK);
    /* A level above the grid's peak: no surface, the image without it bit for bit. */
    CHECK(same_image(&base, &never));
    /* Froxels and the analytic pass cannot draw a surface: the march does, the same image. */
    rs.volumetrics.mode = NACRE_VOLUMETRICS_FROXEL;
    CHECK(nacre_render(on, &rs, &fro, &st) == NACRE_OK && st.stage_ran[NACRE_STAGE_RAYMARCH] &&
          !st.stage_ran[NACRE_STAGE_FROXEL_FILL]);
    CHECK(same_image(&img, &fro));
    rs.volumetrics.mode = NACRE_VOLUMETRICS_OFF;
    CHECK(nacre_render(on, &rs, &ana, &st) == NACRE_OK && st.stage_ran[NACRE_STAGE_RAYMARCH]);
    CHECK(same_image(&img, &ana));

    /* Analytic shading of the sphere per pixel. */
    const double r = iso_radius(), eta = 1.5, alpha = 0.3, env[3] = {0.2, 0.25, 0.3}, E[3] = {2, 1.8, 1.6};
    double ldir[3] = {-0.3, -0.5, -0.8}, ll = sqrt(0.09 + 0.25 + 0.64);
    double l[3] = {-ldir[0] / ll, -ldir[1] / ll, -ldir[2] / ll};
    const double half_h = tan(17.0 * PI_D / 360.0), half_w = half_h * 120.0 / 90.0;
    double worst = 0.0, sum = 0.0;
    int n = 0, outside_changed = 0;
    for (int32_t y = 0; y < 90; y++)
        for (int32_t x = 0; x < 120; x++) {
            const float o[3] = {0, 0, 10};
            double dd[3] = {((x + 0.5) * 2.0 / 120 - 1.0) * half_w, (1.0 - (y + 0.5) * 2.0 / 90) * half_h, -1.0};
            double dl = sqrt(dd[0] * dd[0] + dd[1] * dd[1] + 1.0);
            const float d[3] = {(float)(dd[0] / dl), (float)(dd[1] / dl), (float)(dd[2] / dl)};
            double t;
            const float *a = img.pixels + (size_t)y * img.stride + 3 * (size_t)x;
            const float *b = base.pixels + (size_t)y * base.stride + 3 * (size_t)x;
            double ex = 0.03; /* a voxel is 2 R / 60 = 0.033 */
            if (!sphere_hit(o, d, r + ex, &t)) {
                outside_changed += memcmp(a, b, 3 * sizeof(float)) != 0;
                continue;
            }
            if (!sphere_hit(o, d, r, &t))
                continue;
            double nrm[3], v[3] = {-d[0], -d[1], -d[2]};
            for (int c = 0; c < 3; c++)
                nrm[c] = (o[c] + t * d[c] - CENTRE[c]) / r;
            double cs = nrm[0] * v[0] + nrm[1] * v[1] + nrm[2] * v[2];
            if (cs < 0.3)
                continue;
            double F = nc_fresnel_dielectric(cs, eta);
            double spec = ggx(nrm, v, l, cs, alpha, eta);
            for (int c = 0; c < 3; c++) {
                double want = F * env[c] + spec * E[c] + (1.0 - F) * b[c];
                double err = fabs(a[c] - want) / want;
                if (c == 0 && getenv("ISO_DUMP") && (x % 6 == 0) && (y % 6 == 0))
                    printf("%d %d cs %.3f F %.4f spec %.4f b %.4f got %.4f want %.4f\n", x, y, cs, F, spec, b[c], a[c],
                           want);
                worst = fmax(worst, err);
                sum += err;
                n++;
            }
        }
    printf("iso shading: %d channel values, mean relative error %.3g, worst %.3g; %d pixels off the sphere "
           "changed\n", n, n ? sum / n : 0.0, worst, outside_changed);
    CHECK(n > 3 * 1000);
    CHECK(outside_changed == 0);
    CHECK(sum / n < 1e-3);
    CHECK(worst < 5e-3);
    /* One thread gives the same image as two. */
    nacre_context *ctx1 = make_ctx(1);
    nacre_scene *on1 = load(ctx1, ISO);
    nacre_image one = {0};
    rs.volumetrics.mode = NACRE_VOLUMETRICS_RAYMARCH;
    CHECK(on1 && nacre_render(on1, &rs, &one, NULL) == NACRE_OK && same_image(&img, &one));
    nacre_image_free(ctx1, &one);
    nacre_scene_destroy(on1);
    nacre_context_destroy(ctx1);
    nacre_image *all[] = {&base, &img, &never, &fro, &ana};
    for (size_t i = 0; i < 5; i++)
        nacre_image_free(ctx, all[i]);
    nacre_scene_destroy(off);
    nacre_scene_destroy(on);
    nacre_scene_destroy(high);
    nacre_context_destroy(ctx);
}

/* The particle's density as splatted: the Gaussian cut at the cube of half-edge R. */
static double kernel_at(const double p[3])
{
    double r2 = 0.0;
    for (int a = 0; a < 3; a++) {
        double v = p[a] - CENTRE[a];
        if (fabs(v) > R0)
            return 0.0;
        r2 += v * v;
    }
    return D0 * exp(-4.5 * r2 / (R0 * R0));
}

/* Integral of the density along p + s w, s in [0, len], by 4000 midpoints. */
static double column(const double p[3], const double w[3], double len)
{
    double sum = 0.0, ds = len / 4000.0;
    for (int k = 0; k < 4000; k++) {
        double s = (k + 0.5) * ds, q[3] = {p[0] + s * w[0], p[1] + s * w[1], p[2] + s * w[2]};
        sum += kernel_at(q);
    }
    return sum * ds;
}

/* An absorbing blob (sigma_s 0): the pixel is T_front (F L_env + f_GGX E Tr + (1 - F) T_in c)
 * with every transmittance the analytic density's along the same rays, the refracted one
 * included: the check of the part that carries the medium behind the surface. */
static void test_absorbing(void)
{
    nacre_context *ctx = make_ctx(0);
    nacre_scene *plain = load(ctx, "");
    nacre_scene *on = load_absorbing(ctx, "[0.05, 0.1, 0.2]", ISO);
    CHECK(plain && on);
    if (!plain || !on)
        return;
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = NACRE_METHOD_PHONG;
    rs.width = 120;
    rs.height = 90;
    rs.particles = NACRE_PARTICLES_DRAW_VOXEL;
    rs.volumetrics.mode = NACRE_VOLUMETRICS_RAYMARCH;
    nacre_image base = {0}, img = {0};
    CHECK(nacre_render(plain, &rs, &base, NULL) == NACRE_OK && nacre_render(on, &rs, &img, NULL) == NACRE_OK);
    const double r = iso_radius(), eta = 1.5, alpha = 0.3, env[3] = {0.2, 0.25, 0.3}, E[3] = {2, 1.8, 1.6};
    const double sa[3] = {0.05, 0.1, 0.2};
    double ll = sqrt(0.09 + 0.25 + 0.64), l[3] = {0.3 / ll, 0.5 / ll, 0.8 / ll};
    const double half_h = tan(17.0 * PI_D / 360.0), half_w = half_h * 120.0 / 90.0;
    double worst = 0.0, sum = 0.0, min_tin = 1.0;
    int n = 0;
    for (int32_t y = 0; y < 90; y += 2)
        for (int32_t x = 0; x < 120; x += 2) {
            const float o[3] = {0, 0, 10};
            double dd[3] = {((x + 0.5) * 2.0 / 120 - 1.0) * half_w, (1.0 - (y + 0.5) * 2.0 / 90) * half_h, -1.0};
            double dl = sqrt(dd[0] * dd[0] + dd[1] * dd[1] + 1.0);
            const float d[3] = {(float)(dd[0] / dl), (float)(dd[1] / dl), (float)(dd[2] / dl)};
            double t;
            if (!sphere_hit(o, d, r, &t))
                continue;
            double nrm[3], v[3] = {-d[0], -d[1], -d[2]}, hp[3], od[3] = {o[0], o[1], o[2]}, dv[3] = {d[0], d[1], d[2]};
            for (int c = 0; c < 3; c++) {
                hp[c] = o[c] + t * d[c];
                nrm[c] = (hp[c] - CENTRE[c]) / r;
            }
            double cs = nrm[0] * v[0] + nrm[1] * v[1] + nrm[2] * v[2];
            if (cs < 0.3)
                continue;
            double F = nc_fresnel_dielectric(cs, eta);
            double spec = ggx(nrm, v, l, cs, alpha, eta);
            float nf[3] = {(float)nrm[0], (float)nrm[1], (float)nrm[2]}, rf[3];
            CHECK(nc_refract(d, nf, eta, rf));
            double rd[3] = {rf[0], rf[1], rf[2]};
            double front = column(od, dv, t), inside = column(hp, rd, 4.0 * R0), to_light = column(hp, l, 4.0 * R0);
            const float *a = img.pixels + (size_t)y * img.stride + 3 * (size_t)x;
            const float *b = base.pixels + (size_t)y * base.stride + 3 * (size_t)x;
            for (int c = 0; c < 3; c++) {
                double tin = exp(-sa[c] * inside);
                min_tin = fmin(min_tin, tin);
                double want = exp(-sa[c] * front) *
                              (F * env[c] + spec * E[c] * exp(-sa[c] * to_light) + (1.0 - F) * tin * b[c]);
                double err = fabs(a[c] - want) / want;
                worst = fmax(worst, err);
                sum += err;
                n++;
            }
        }
    printf("iso absorbing: %d channel values, mean relative error %.3g, worst %.3g (inside transmittance down to "
           "%.3g)\n", n, n ? sum / n : 0.0, worst, min_tin);
    CHECK(n > 3 * 250);
    CHECK(min_tin < 0.3); /* the medium inside matters */
    CHECK(sum / n < 0.005);
    CHECK(worst < 0.02);
    nacre_image_free(ctx, &base);
    nacre_image_free(ctx, &img);
    nacre_scene_destroy(plain);
    nacre_scene_destroy(on);
    nacre_context_destroy(ctx);
}

static void test_bad_input_and_round_trip(void)
{
    nacre_context *ctx = make_ctx(0);
    nacre_scene *scene = NULL;
    CHECK(nacre_scene_create(ctx, &scene) == NACRE_OK);
    nacre_particles_desc d = nacre_particles_desc_defaults(NACRE_PARTICLES_EMITTER);
    nacre_particles h;
    d.isosurface.density = -1.0f;
    CHECK(nacre_scene_add_particles(scene, &d, &h) == NACRE_ERROR_INVALID_ARGUMENT &&
          test_error_names(ctx, "isosurface.density"));
    d.isosurface.density = NAN;
    CHECK(nacre_scene_add_particles(scene, &d, &h) == NACRE_ERROR_INVALID_ARGUMENT &&
          test_error_names(ctx, "isosurface.density"));
    d.isosurface.density = 2.0f;
    d.isosurface.ior = 0.5f;
    CHECK(nacre_scene_add_particles(scene, &d, &h) == NACRE_ERROR_INVALID_ARGUMENT &&
          test_error_names(ctx, "isosurface.ior"));
    d.isosurface.ior = 1.4f;
    d.isosurface.roughness = 1.5f;
    CHECK(nacre_scene_add_particles(scene, &d, &h) == NACRE_ERROR_INVALID_ARGUMENT &&
          test_error_names(ctx, "isosurface.roughness"));
    CHECK(nacre_scene_particles_count(scene) == 0);
    static const char *const bad[][2] = {
        {"{\"particles\": [{\"isosurface\": {\"density\": -1}}]}", "particles[0].isosurface.density"},
        {"{\"particles\": [{\"isosurface\": {\"density\": 0}}]}", "particles[0].isosurface.density"},
        {"{\"particles\": [{\"isosurface\": {\"density\": 1, \"ior\": 7}}]}", "particles[0].isosurface.ior"},
        {"{\"particles\": [{\"isosurface\": {\"density\": 1, \"roughness\": -0.1}}]}", "isosurface.roughness"},
        {"{\"particles\": [{\"isosurface\": {\"ior\": 1.3}}]}", "density"},
        {"{\"particles\": [{\"isosurface\": {\"density\": 1, \"eta\": 1.3}}]}", "eta"},
        {"{\"particles\": [{\"isosurface\": 3}]}", "isosurface"},
    };
    for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
        nacre_scene *s2 = NULL;
        CHECK(nacre_scene_load_json(ctx, bad[i][0], strlen(bad[i][0]), "bad.json", NULL, &s2, NULL) ==
              NACRE_ERROR_INVALID_ARGUMENT);
        CHECK(s2 == NULL && test_error_names(ctx, bad[i][1]));
    }
    /* Round trip: the surface's fields come back bit for bit; without one, none is written. */
    d.isosurface.density = 0.3f;
    d.isosurface.ior = 1.1f;
    d.isosurface.roughness = 0.07f;
    CHECK(nacre_scene_add_particles(scene, &d, &h) == NACRE_OK);
    nacre_particles_desc plain = nacre_particles_desc_defaults(NACRE_PARTICLES_EMITTER);
    CHECK(nacre_scene_add_particles(scene, &plain, &h) == NACRE_OK);
    char *json = NULL;
    size_t len = 0;
    CHECK(nacre_scene_save_json(scene, NULL, NACRE_TEST_TMP, &json, &len) == NACRE_OK);
    const char *first = json ? strstr(json, "isosurface") : NULL;
    CHECK(first && !strstr(first + 1, "isosurface"));
    nacre_scene *s2 = NULL;
    CHECK(json && nacre_scene_load_json(ctx, json, len, "saved.json", NACRE_TEST_TMP, &s2, NULL) == NACRE_OK);
    nacre_free(ctx, json);
    if (s2) {
        nacre_particles_desc back;
        CHECK(nacre_scene_get_particles(s2, (nacre_particles){1}, &back) == NACRE_OK);
        CHECK(back.isosurface.density == 0.3f && back.isosurface.ior == 1.1f && back.isosurface.roughness == 0.07f);
        CHECK(nacre_scene_get_particles(s2, (nacre_particles){2}, &back) == NACRE_OK);
        CHECK(back.isosurface.density == 0.0f);
        nacre_scene_destroy(s2);
    }
    nacre_scene_destroy(scene);
    nacre_context_destroy(ctx);
}

int main(void)
{
    test_geometry();
    test_shading();
    test_absorbing();
    test_bad_input_and_round_trip();
    return TEST_MAIN_END();
}
