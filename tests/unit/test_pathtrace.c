/*
 * test_pathtrace.c: the scene path tracer. White furnaces (a non-absorbing medium under a uniform
 * environment must give back the environment radiance: index matched, homogeneous, chromatic and
 * heterogeneous; inside a smooth dielectric of eta 1.5, where a wrong eta^2 factor shows), the
 * majorant grid against one global majorant, convergence as 1/sqrt(spp), determinism across
 * thread counts, a lit Lambert plane against its closed form, and clean errors for bad settings.
 * Speed-ups checked against their absence: clearance grids (same image bit for bit where they
 * only skip queries; same within noise where they also thin out guided sun samples), and
 * cast_shadows = false on an opaque occluder against the closed form of the unshadowed plane.
 * Procedural shapes only; small images so every case stays within seconds under ASan.
 */
#include "test_util.h"

#include "pathtrace/pathtrace.h"
#include "scene/scene.h"

#include <nacre/nacre.h>

static nacre_context *ctx;

/* A sphere of radius 1 at the origin (segments x rings, with or without uvs) with a translucent
 * material, camera looking at it. */
static nacre_scene *sphere_scene_mesh(nacre_context *c, const nacre_material_desc *md, float env, uint32_t segments,
                                      uint32_t rings, bool uvs)
{
    nacre_scene *s = NULL;
    CHECK(nacre_scene_create(c, &s) == NACRE_OK);
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
    sd.segments = segments;
    sd.rings = rings;
    nacre_mesh_data data = {0};
    CHECK(nacre_mesh_make_shape(c, &sd, &data) == NACRE_OK);
    nacre_mesh mesh;
    nacre_mesh_data added = data;
    if (!uvs)
        added.uvs = added.tangents = NULL;
    CHECK(nacre_scene_add_mesh(s, &added, &mesh) == NACRE_OK);
    nacre_mesh_data_free(c, &data);
    nacre_material mat;
    CHECK(nacre_scene_add_material(s, md, &mat) == NACRE_OK);
    nacre_object_desc od = nacre_object_desc_defaults();
    od.mesh = mesh;
    od.material = mat;
    nacre_object obj;
    CHECK(nacre_scene_add_object(s, &od, &obj) == NACRE_OK);
    nacre_camera_desc cam = nacre_camera_desc_defaults();
    cam.position[0] = 0, cam.position[1] = 0, cam.position[2] = 4;
    cam.target[0] = 0, cam.target[1] = 0, cam.target[2] = 0;
    cam.up[0] = 0, cam.up[1] = 1, cam.up[2] = 0;
    cam.fov_y = 30;
    CHECK(nacre_scene_set_camera(s, &cam) == NACRE_OK);
    float e[3] = {env, env, env};
    CHECK(nacre_scene_set_environment(s, e) == NACRE_OK);
    CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
    return s;
}

static nacre_scene *sphere_scene_res(nacre_context *c, const nacre_material_desc *md, float env, uint32_t segments,
                                     uint32_t rings)
{
    return sphere_scene_mesh(c, md, env, segments, rings, true);
}

static nacre_scene *sphere_scene(nacre_context *c, const nacre_material_desc *md, float env)
{
    return sphere_scene_res(c, md, env, 32, 16);
}

static nacre_material_desc medium(float sa, float ss, float g, float eta)
{
    nacre_material_desc md = nacre_material_desc_defaults(NACRE_MATERIAL_TRANSLUCENT);
    for (int c = 0; c < 3; c++) {
        md.sigma_a[c] = sa;
        md.sigma_s[c] = ss;
    }
    md.g = g;
    md.eta = eta;
    return md;
}

static nacre_render_settings pt_settings(int32_t size, uint32_t spp)
{
    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.method = NACRE_METHOD_PATHTRACE;
    rs.width = size;
    rs.height = size;
    rs.pathtrace.spp = spp;
    rs.pathtrace.seed = 3;
    return rs;
}

/* Render through an explicit state (options) into a freshly allocated image. */
static nacre_image render_with(nacre_context *c, const nacre_scene *s, const nacre_render_settings *rs,
                               const nc_pathtrace_options *opt, nacre_image *variance)
{
    nacre_image img = {0};
    CHECK(nacre_image_alloc(c, rs->width, rs->height, 3, &img) == NACRE_OK);
    nc_pathtracer *st = NULL;
    CHECK(nc_pathtracer_create(c, opt, &st) == NACRE_OK);
    nacre_render_stats stats;
    memset(&stats, 0, sizeof(stats));
    nacre_result r = nc_pathtrace_render(&st, c, s, rs, false, &img, &stats);
    CHECK(r == NACRE_OK);
    if (r != NACRE_OK)
        printf("  %s\n", nacre_context_last_error(c));
    CHECK(stats.spp_done == rs->pathtrace.spp);
    if (variance)
        CHECK(nc_pathtrace_variance(st, c, variance) == NACRE_OK);
    nc_pathtracer_destroy(c, st);
    return img;
}

/* Mean over pixels inside the sphere's silhouette (radius `frac` of the half-image), per channel,
 * with the standard error from the variance image. */
static void disk_mean(const nacre_image *img, const nacre_image *var, float frac, double mean[3], double se[3])
{
    double sum[3] = {0, 0, 0}, vs[3] = {0, 0, 0};
    int n = 0;
    for (int y = 0; y < img->height; y++)
        for (int x = 0; x < img->width; x++) {
            double dx = (x + 0.5) / img->width * 2 - 1, dy = (y + 0.5) / img->height * 2 - 1;
            if (dx * dx + dy * dy > frac * frac)
                continue;
            for (int c = 0; c < 3; c++) {
                sum[c] += img->pixels[(size_t)y * img->stride + 3 * (size_t)x + (size_t)c];
                vs[c] += var->pixels[(size_t)y * var->stride + 3 * (size_t)x + (size_t)c];
            }
            n++;
        }
    for (int c = 0; c < 3; c++) {
        mean[c] = sum[c] / n;
        se[c] = sqrt(vs[c]) / n; /* pixels are independent */
    }
}

/* Two renders of `s` (options a with seed 3, options b with seed_b, so the noise is independent)
 * whose means over the sphere must agree within 4 standard errors (+1e-3). */
static void same_within_noise(const char *what, const nacre_scene *s, int32_t size, uint32_t spp,
                              const nc_pathtrace_options *a, const nc_pathtrace_options *b, uint64_t seed_b)
{
    nacre_render_settings rs = pt_settings(size, spp);
    nacre_image va = {0}, vb = {0};
    nacre_image ia = render_with(ctx, s, &rs, a, &va);
    rs.pathtrace.seed = seed_b;
    nacre_image ib = render_with(ctx, s, &rs, b, &vb);
    double ma[3], sa[3], mb[3], sb[3];
    disk_mean(&ia, &va, 0.8f, ma, sa);
    disk_mean(&ib, &vb, 0.8f, mb, sb);
    printf("  %s: %.4f %.4f %.4f  vs %.4f %.4f %.4f (stderr %.4f)\n", what, ma[0], ma[1], ma[2], mb[0], mb[1], mb[2],
           sa[0]);
    for (int c = 0; c < 3; c++)
        CHECK_NEAR(ma[c], mb[c], 4 * sqrt(sa[c] * sa[c] + sb[c] * sb[c]) + 1e-3);
    nacre_image_free(ctx, &ia);
    nacre_image_free(ctx, &ib);
    nacre_image_free(ctx, &va);
    nacre_image_free(ctx, &vb);
}

/* A directional light of equal RGB strength, then commit. */
static void add_sun(nacre_scene *s, float dx, float dy, float dz, float strength)
{
    nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
    ld.direction[0] = dx, ld.direction[1] = dy, ld.direction[2] = dz;
    ld.strength[0] = ld.strength[1] = ld.strength[2] = strength;
    nacre_light l;
    CHECK(nacre_scene_add_light(s, &ld, &l) == NACRE_OK);
    CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
}

/* The furnace check on a sphere scene under environment 0.7 (destroys the scene). */
static void furnace_scene(const char *name, nacre_scene *s, const nc_pathtrace_options *opt, uint32_t spp)
{
    nacre_render_settings rs = pt_settings(24, spp);
    nacre_image var = {0};
    nacre_image img = render_with(ctx, s, &rs, opt, &var);
    double m[3], se[3];
    /* The sphere of radius 1 seen from distance 4 with fov 30 spans ~0.97 of the half-image. */
    disk_mean(&img, &var, 0.8f, m, se);
    printf("  furnace %-28s: %.4f %.4f %.4f (stderr %.4f) expect 0.7\n", name, m[0], m[1], m[2], se[0]);
    for (int c = 0; c < 3; c++)
        CHECK_NEAR(m[c], 0.7, 4 * se[c] + 0.005);
    /* And the rim, where paths graze the boundary, is no different from the centre. */
    double rim = 0;
    int nr = 0;
    for (int y = 0; y < 24; y++)
        for (int x = 0; x < 24; x++) {
            double dx = (x + 0.5) / 12 - 1, dy = (y + 0.5) / 12 - 1, r2 = dx * dx + dy * dy;
            if (r2 > 0.55 * 0.55 && r2 < 0.9 * 0.9) {
                rim += img.pixels[3 * (24 * y + x) + 1];
                nr++;
            }
        }
    CHECK_NEAR(rim / nr, 0.7, 0.05);
    nacre_image_free(ctx, &img);
    nacre_image_free(ctx, &var);
    nacre_scene_destroy(s);
}

static void furnace(const char *name, const nacre_material_desc *md, const nc_pathtrace_options *opt, uint32_t spp)
{
    furnace_scene(name, sphere_scene(ctx, md, 0.7f), opt, spp);
}

/* Test-only heterogeneous medium: a 3D checker of cell 0.3 alternating sigma_s 2 and 12
 * (non-absorbing) in rest-pose coordinates, chromatic in the dense cells. */
static void checker_eval(const nacre_scene *scene, const nacre_material_desc *m, const float *xyz, size_t count,
                         float *sa, float *ss)
{
    (void)scene, (void)m;
    for (size_t i = 0; i < count; i++) {
        int k = (int)floorf(xyz[3 * i] / 0.3f) + (int)floorf(xyz[3 * i + 1] / 0.3f) + (int)floorf(xyz[3 * i + 2] / 0.3f);
        bool dense = (k & 1) != 0;
        for (int c = 0; c < 3; c++) {
            sa[3 * i + c] = 0;
            ss[3 * i + c] = dense ? 12.0f - 3.0f * (float)c : 2.0f;
        }
    }
}
static void checker_max(const nacre_scene *scene, const nacre_material_desc *m, float out[3])
{
    (void)scene, (void)m;
    out[0] = 12, out[1] = 9, out[2] = 6;
}
/* Same checker but absorbing, for the grid-vs-global comparison (non-trivial image). */
static void checker_absorb_eval(const nacre_scene *scene, const nacre_material_desc *m, const float *xyz,
                                size_t count, float *sa, float *ss)
{
    checker_eval(scene, m, xyz, count, sa, ss);
    for (size_t i = 0; i < count; i++)
        for (int c = 0; c < 3; c++) {
            sa[3 * i + c] = 0.3f * ss[3 * i + c];
            ss[3 * i + c] *= 0.7f;
        }
}

static double rms_diff(const nacre_image *a, const nacre_image *b)
{
    double s = 0;
    size_t n = (size_t)a->width * a->height * 3;
    for (size_t i = 0; i < n; i++)
        s += (a->pixels[i] - b->pixels[i]) * (double)(a->pixels[i] - b->pixels[i]);
    return sqrt(s / n);
}

/* Test-only analytic counterpart of the layered sphere below: a shell |p| > 0.7 of sigma_a 0.6,
 * sigma_s 3 around a core of sigma_a 0.05, sigma_s 1.5 (blue absorbs more in the core). */
static void shell_eval(const nacre_scene *scene, const nacre_material_desc *m, const float *xyz, size_t count,
                       float *sa, float *ss)
{
    (void)scene, (void)m;
    for (size_t i = 0; i < count; i++) {
        const float *p = xyz + 3 * i;
        bool shell = p[0] * p[0] + p[1] * p[1] + p[2] * p[2] > 0.7f * 0.7f;
        for (int c = 0; c < 3; c++) {
            sa[3 * i + c] = shell ? 0.6f : (c == 2 ? 0.4f : 0.05f);
            ss[3 * i + c] = shell ? 3.0f : 1.5f;
        }
    }
}
static void shell_max(const nacre_scene *scene, const nacre_material_desc *m, float out[3])
{
    (void)scene, (void)m;
    out[0] = out[1] = out[2] = 3.6f;
}

/* The same shell as a layered material: one layer 0.3 deep over the core. */
static nacre_material_desc shell_layered(void)
{
    nacre_material_desc md = medium(0.05f, 1.5f, 0.0f, 1.0f);
    md.sigma_a[2] = 0.4f;
    md.layering.count = 1;
    for (int c = 0; c < 3; c++) {
        md.layering.layers[0].sigma_a[c] = 0.6f;
        md.layering.layers[0].sigma_s[c] = 3.0f;
    }
    md.layering.layers[0].depth = 0.3f;
    return md;
}

/* Mean over the sphere of a render with options opt (seed), with its standard error. */
static void render_mean(const nacre_scene *s, int32_t size, uint32_t spp, uint64_t seed, const nc_pathtrace_options *opt,
                        double m[3], double se[3])
{
    nacre_render_settings rs = pt_settings(size, spp);
    rs.pathtrace.seed = seed;
    nacre_image var = {0};
    nacre_image img = render_with(ctx, s, &rs, opt, &var);
    disk_mean(&img, &var, 0.8f, m, se);
    nacre_image_free(ctx, &img);
    nacre_image_free(ctx, &var);
}

/* Layered materials (Francois et al. 2006 layers, located by the depth below the rest-pose
 * surface): white furnaces with chromatic, anisotropic layers (index matched and dielectric,
 * with constant depths and with a depth map); a one-layer sphere against the same shell given
 * analytically (|p| > 0.7) through the test medium hook, which must agree within noise while the
 * core alone must not; the majorant grid against one global majorant; and a layer's own g
 * (a layer deeper than the sphere with g 0.8 over a g 0 core against a homogeneous g 0.8). */
static void test_layered(const nc_pathtrace_options *def)
{
    nacre_material_desc md = medium(0.0f, 1.0f, 0.0f, 1.0f);
    md.layering.count = 2;
    const float ls[2][3] = {{4.0f, 3.0f, 2.0f}, {8.0f, 8.0f, 8.0f}};
    for (int j = 0; j < 2; j++)
        for (int c = 0; c < 3; c++)
            md.layering.layers[j].sigma_s[c] = ls[j][c];
    md.layering.layers[0].g = 0.7f, md.layering.layers[0].depth = 0.15f;
    md.layering.layers[1].g = -0.3f, md.layering.layers[1].depth = 0.4f;
    furnace("matched layered", &md, def, 16);
    md.eta = 1.5f;
    furnace("dielectric layered eta=1.5", &md, def, 32);
    md.eta = 1.0f;
    {
        /* A depth map: a 4 x 2 RGBA texture whose channels swing each layer's depth by 2x. */
        float px[4 * 2 * 4];
        for (int i = 0; i < 8; i++)
            for (int c = 0; c < 4; c++)
                px[4 * i + c] = (i + c) % 2 ? 1.0f : 0.5f;
        nacre_scene *s = sphere_scene(ctx, &md, 0.7f);
        nacre_image img = {4, 2, 4, 16, px};
        nacre_material_desc mm = md;
        CHECK(nacre_scene_add_texture(s, &img, &mm.layering.depth_map) == NACRE_OK);
        nacre_material first = {1};
        CHECK(nacre_scene_set_material(s, first, &mm) == NACRE_OK);
        CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
        furnace_scene("matched layered depth map", s, def, 16);
    }

    /* Layered shell vs the analytic shell (fine mesh: depth is R - |p| within 1.2e-3). */
    nacre_material_desc lm = shell_layered();
    nacre_scene *sl = sphere_scene_res(ctx, &lm, 0.2f, 128, 64);
    add_sun(sl, 0.0f, -0.6f, -0.8f, 2.0f);
    nacre_material_desc hm = medium(0.05f, 1.5f, 0.0f, 1.0f);
    hm.sigma_a[2] = 0.4f;
    nacre_scene *sh = sphere_scene_res(ctx, &hm, 0.2f, 128, 64);
    add_sun(sh, 0.0f, -0.6f, -0.8f, 2.0f);
    nc_pathtrace_options an = *def;
    an.eval = shell_eval;
    an.max_sigma_t = shell_max;
    an.force_heterogeneous = true;
    double ml[3], el[3], ma[3], ea[3], mc[3], ec[3];
    render_mean(sl, 16, 128, 5, def, ml, el);
    render_mean(sh, 16, 128, 6, &an, ma, ea);
    render_mean(sh, 16, 32, 7, def, mc, ec);
    printf("  layered shell %.4f %.4f %.4f  analytic shell %.4f %.4f %.4f  core only %.4f %.4f %.4f (stderr %.4f)\n",
           ml[0], ml[1], ml[2], ma[0], ma[1], ma[2], mc[0], mc[1], mc[2], el[0]);
    double far = 0;
    for (int c = 0; c < 3; c++) {
        CHECK_NEAR(ml[c], ma[c], 4 * sqrt(el[c] * el[c] + ea[c] * ea[c]) + 1e-3);
        far = fmax(far, fabs(ml[c] - mc[c]) / sqrt(el[c] * el[c] + ec[c] * ec[c]));
    }
    CHECK(far > 8); /* the layer matters: the comparison above can fail */

    /* Deformed (stretched 1.6x along x): layers are located at rest-pose points, so the layered
     * sphere still matches the analytic shell evaluated at the same rest points. */
    nacre_object_desc od = nacre_object_desc_defaults();
    od.mesh.id = 1;
    od.material.id = 1;
    od.deformer_count = 1;
    od.deformers[0] = nacre_deformer_defaults(NACRE_DEFORM_SCALE);
    od.deformers[0].scale[0] = 1.6f;
    od.deformers[0].scale[1] = od.deformers[0].scale[2] = 1.0f;
    nacre_object first = {1};
    CHECK(nacre_scene_set_object(sl, first, &od) == NACRE_OK && nacre_scene_set_object(sh, first, &od) == NACRE_OK);
    CHECK(nacre_scene_commit(sl, 0.0) == NACRE_OK && nacre_scene_commit(sh, 0.0) == NACRE_OK);
    render_mean(sl, 16, 64, 8, def, ml, el);
    render_mean(sh, 16, 64, 9, &an, ma, ea);
    printf("  deformed: layered shell %.4f %.4f %.4f  analytic shell %.4f %.4f %.4f (stderr %.4f)\n", ml[0], ml[1],
           ml[2], ma[0], ma[1], ma[2], el[0]);
    for (int c = 0; c < 3; c++)
        CHECK_NEAR(ml[c], ma[c], 4 * sqrt(el[c] * el[c] + ea[c] * ea[c]) + 1e-3);
    nacre_scene_destroy(sh);
    /* Back to the undeformed sphere for the majorant comparison. */
    od.deformer_count = 0;
    CHECK(nacre_scene_set_object(sl, first, &od) == NACRE_OK && nacre_scene_commit(sl, 0.0) == NACRE_OK);

    /* Majorant grid (depth bounds per cell) vs one global majorant. */
    nc_pathtrace_options glob = *def;
    glob.majorant_res = 0;
    same_within_noise("layered: majorant grid vs global", sl, 16, 24, def, &glob, 4321);
    nacre_scene_destroy(sl);

    /* A layer's own g: a layer deeper than the sphere (g 0.8) over a g 0 core is a homogeneous
     * g 0.8 medium; isotropic scattering gives a visibly different image. */
    nacre_material_desc gl = medium(0.1f, 2.0f, 0.0f, 1.0f);
    gl.layering.count = 1;
    for (int c = 0; c < 3; c++) {
        gl.layering.layers[0].sigma_a[c] = 0.1f;
        gl.layering.layers[0].sigma_s[c] = 2.0f;
    }
    gl.layering.layers[0].g = 0.8f;
    gl.layering.layers[0].depth = 5.0f;
    nacre_material_desc g8 = medium(0.1f, 2.0f, 0.8f, 1.0f), g0 = medium(0.1f, 2.0f, 0.0f, 1.0f);
    nacre_scene *s1 = sphere_scene(ctx, &gl, 0.0f), *s2 = sphere_scene(ctx, &g8, 0.0f), *s3 = sphere_scene(ctx, &g0, 0.0f);
    add_sun(s1, 0.0f, 0.0f, 1.0f, 2.0f); /* from behind the sphere: forward scattering shows */
    add_sun(s2, 0.0f, 0.0f, 1.0f, 2.0f);
    add_sun(s3, 0.0f, 0.0f, 1.0f, 2.0f);
    double m1[3], e1[3], m2[3], e2[3], m3[3], e3[3];
    render_mean(s1, 16, 32, 11, def, m1, e1);
    render_mean(s2, 16, 32, 12, def, m2, e2);
    render_mean(s3, 16, 32, 13, def, m3, e3);
    printf("  layer g 0.8: %.4f  homogeneous g 0.8: %.4f  g 0: %.4f (stderr %.4f)\n", m1[1], m2[1], m3[1], e1[1]);
    for (int c = 0; c < 3; c++)
        CHECK_NEAR(m1[c], m2[c], 4 * sqrt(e1[c] * e1[c] + e2[c] * e2[c]) + 1e-3);
    CHECK(fabs(m1[1] - m3[1]) > 8 * sqrt(e1[1] * e1[1] + e3[1] * e3[1]));
    nacre_scene_destroy(s1);
    nacre_scene_destroy(s2);
    nacre_scene_destroy(s3);

    /* A depth map on a mesh without uvs: a one-line error naming the object, no image. */
    {
        nacre_material_desc mm = shell_layered();
        nacre_scene *s = sphere_scene_mesh(ctx, &mm, 0.0f, 16, 8, false);
        float px[4] = {1, 1, 1, 1};
        nacre_image one = {1, 1, 4, 4, px};
        CHECK(nacre_scene_add_texture(s, &one, &mm.layering.depth_map) == NACRE_OK);
        nacre_material first = {1};
        CHECK(nacre_scene_set_material(s, first, &mm) == NACRE_OK);
        nacre_object_desc od = nacre_object_desc_defaults();
        od.mesh.id = od.material.id = 1;
        od.name = "bare";
        nacre_object obj = {1};
        CHECK(nacre_scene_set_object(s, obj, &od) == NACRE_OK);
        CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
        nacre_render_settings rs = pt_settings(8, 1);
        nacre_image img = {0};
        CHECK(nacre_render(s, &rs, &img, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
        CHECK(img.pixels == NULL);
        CHECK(strstr(nacre_context_last_error(ctx), "object 'bare': its layered material has a depth_map but its "
                                                    "mesh has no uvs") != NULL);
        nacre_scene_destroy(s);
    }
}

int main(void)
{
    nacre_context_desc cd = {0};
    cd.threads = 2;
    CHECK(nacre_context_create(&cd, &ctx) == NACRE_OK);
    if (!nacre_method_available(NACRE_METHOD_PATHTRACE)) {
        /* Built without Embree: the scene path tracer must say so cleanly. */
        nacre_material_desc om = nacre_material_desc_defaults(NACRE_MATERIAL_OPAQUE);
        nacre_scene *s = sphere_scene(ctx, &om, 1.0f);
        nacre_render_settings rs = pt_settings(8, 1);
        nacre_image img = {0};
        CHECK(nacre_render(s, &rs, &img, NULL) == NACRE_ERROR_UNSUPPORTED);
        nacre_scene_destroy(s);
        nacre_context_destroy(ctx);
        printf("  skipped: built without Embree\n");
        return TEST_MAIN_END();
    }
    nc_pathtrace_options def = nc_pathtrace_options_defaults();

    /* White furnaces. */
    nacre_material_desc md = medium(0.0f, 2.0f, 0.0f, 1.0f);
    furnace("matched homogeneous", &md, &def, 16);
    md = medium(0.0f, 3.0f, 0.6f, 1.0f);
    md.sigma_s[1] = 1.0f;
    md.sigma_s[2] = 0.3f;
    furnace("matched chromatic g=0.6", &md, &def, 16);
    {
        nc_pathtrace_options het = def;
        het.eval = checker_eval;
        het.max_sigma_t = checker_max;
        het.force_heterogeneous = true;
        md = medium(0.0f, 1.0f, 0.3f, 1.0f);
        furnace("matched heterogeneous grid", &md, &het, 16);
        het.majorant_res = 0;
        furnace("matched heterogeneous global", &md, &het, 16);
    }
    /* Heterogeneous through the scene's own patterns (nc_medium_eval): a non-absorbing checker. */
    md = medium(0.0f, 1.0f, 0.0f, 1.0f);
    md.pattern.type = NACRE_PATTERN_CHECKER;
    md.pattern.cell_size = 0.4f;
    md.pattern.sigma_s2[0] = 8.0f, md.pattern.sigma_s2[1] = 5.0f, md.pattern.sigma_s2[2] = 3.0f;
    furnace("matched checker pattern", &md, &def, 16);
    md = medium(0.0f, 2.0f, 0.0f, 1.5f);
    furnace("dielectric eta=1.5", &md, &def, 32);
    md = medium(0.0f, 1e-3f, 0.0f, 1.5f);
    furnace("dielectric eta=1.5 nearly empty", &md, &def, 16);

    /* Majorant grid vs one global majorant on an absorbing heterogeneous medium lit by a sun. */
    {
        nc_pathtrace_options a = def, b = def;
        a.eval = b.eval = checker_absorb_eval;
        a.max_sigma_t = b.max_sigma_t = checker_max;
        a.force_heterogeneous = b.force_heterogeneous = true;
        b.majorant_res = 0;
        md = medium(0.0f, 1.0f, 0.0f, 1.0f);
        nacre_scene *s = sphere_scene(ctx, &md, 0.2f);
        add_sun(s, 0.0f, -0.6f, -0.8f, 2.0f);
        same_within_noise("majorant grid vs global", s, 16, 24, &a, &b, 1234);
        nacre_scene_destroy(s);
    }

    /* Sun through a dielectric boundary: the guided technique (MIS with phase sampling) against
     * phase sampling alone, which is unbiased but slow; a 4-degree sun keeps it measurable. */
    {
        md = medium(0.02f, 3.0f, 0.2f, 1.4f);
        md.sigma_a[2] = 0.3f;
        nacre_scene *s = sphere_scene(ctx, &md, 0.0f);
        nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
        ld.direction[0] = -0.5f, ld.direction[1] = -0.5f, ld.direction[2] = -0.7071f;
        ld.strength[0] = ld.strength[1] = ld.strength[2] = 1.0f;
        ld.angular_radius = 4.0f;
        nacre_light l;
        CHECK(nacre_scene_add_light(s, &ld, &l) == NACRE_OK);
        CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
        nc_pathtrace_options plain = def;
        plain.no_sun_guiding = true;
        nacre_render_settings rs = pt_settings(16, 64);
        nacre_image vg = {0}, vp = {0};
        nacre_image ig = render_with(ctx, s, &rs, &def, &vg);
        rs.pathtrace.seed = 77;
        rs.pathtrace.spp = 256;
        nacre_image ip = render_with(ctx, s, &rs, &plain, &vp);
        double mg[3], sg[3], mp[3], sp[3];
        disk_mean(&ig, &vg, 0.8f, mg, sg);
        disk_mean(&ip, &vp, 0.8f, mp, sp);
        printf("  sun through eta=1.4: guided %.4f %.4f %.4f (stderr %.4f)  phase only %.4f %.4f %.4f (stderr %.4f)\n",
               mg[0], mg[1], mg[2], sg[0], mp[0], mp[1], mp[2], sp[0]);
        for (int c = 0; c < 3; c++)
            CHECK_NEAR(mg[c], mp[c], 4 * sqrt(sg[c] * sg[c] + sp[c] * sp[c]) + 1e-3);
        CHECK(sg[0] < sp[0]); /* and it is the better estimator, with 4x fewer samples */
        nacre_image_free(ctx, &ig);
        nacre_image_free(ctx, &ip);
        nacre_image_free(ctx, &vg);
        nacre_image_free(ctx, &vp);
        nacre_scene_destroy(s);
    }

    /* Clearance grids skip boundary queries for flights that provably end inside the medium:
     * with nothing else depending on them (a dielectric without sun guiding) the image is the
     * same bit for bit, which also shows the bound is never wrong (a missed boundary would change
     * the path). Deep vertices also run NEE (index matched) or the guided sun technique
     * (dielectric) with probability q < 1: the same image within noise. Dense media, so most
     * flights are short. */
    {
        nc_pathtrace_options off = def;
        off.no_clearance = true;
        const float etas[2] = {1.0f, 1.3f};
        for (int k = 0; k < 2; k++) {
            md = medium(0.05f, 20.0f, 0.3f, etas[k]);
            md.sigma_s[2] = 8.0f;
            nacre_scene *s = sphere_scene(ctx, &md, 0.2f);
            add_sun(s, -0.3f, -0.6f, -0.74f, 2.0f);
            if (k == 1) {
                nacre_render_settings rs = pt_settings(12, 4);
                nacre_image a, b;
                nc_pathtrace_options on = def, off2 = off;
                on.no_sun_guiding = off2.no_sun_guiding = true;
                a = render_with(ctx, s, &rs, &on, NULL);
                b = render_with(ctx, s, &rs, &off2, NULL);
                CHECK(memcmp(a.pixels, b.pixels, sizeof(float) * 12 * 12 * 3) == 0);
                nacre_image_free(ctx, &a);
                nacre_image_free(ctx, &b);
            }
            same_within_noise(k ? "clearance on vs off (eta 1.3)" : "clearance on vs off (eta 1)", s, 12, 24, &def,
                              &off, 4321);
            nacre_scene_destroy(s);
        }
        /* The guided sun technique thinned by the optical depth of the way out (found by the
         * walk over the mesh from the previous vertex's facet, or the clearance) against running
         * it at every vertex: the same image within noise. A dense dielectric sphere, so most
         * vertices are deep and thinned; the sun is small, so the phase-sampled paths into it
         * need the lazily remade guide and probability to match the vertex's for MIS. */
        {
            md = medium(0.05f, 20.0f, 0.3f, 1.3f);
            md.sigma_s[2] = 8.0f;
            nacre_scene *s = sphere_scene(ctx, &md, 0.2f);
            add_sun(s, -0.3f, -0.6f, -0.74f, 2.0f);
            nc_pathtrace_options always = def;
            always.guide_always = true;
            same_within_noise("guided sun thinned vs always", s, 12, 64, &def, &always, 2468);
            nacre_scene_destroy(s);
        }
        /* Heterogeneous media track up to the bound, then on from it: same within noise. */
        nc_pathtrace_options het = def;
        het.eval = checker_absorb_eval;
        het.max_sigma_t = checker_max;
        het.force_heterogeneous = true;
        nc_pathtrace_options het_off = het;
        het_off.no_clearance = true;
        md = medium(0.0f, 1.0f, 0.0f, 1.0f);
        nacre_scene *s = sphere_scene(ctx, &md, 0.5f);
        same_within_noise("heterogeneous clearance on vs off", s, 12, 24, &het, &het_off, 555);
        nacre_scene_destroy(s);
    }

    /* A Lambert plane under a delta sun and a black sky: L = kd E cos / pi exactly. */
    {
        nacre_scene *s = NULL;
        CHECK(nacre_scene_create(ctx, &s) == NACRE_OK);
        nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_PLANE);
        nacre_mesh_data data = {0};
        CHECK(nacre_mesh_make_shape(ctx, &sd, &data) == NACRE_OK);
        nacre_mesh mesh;
        CHECK(nacre_scene_add_mesh(s, &data, &mesh) == NACRE_OK);
        nacre_mesh_data_free(ctx, &data);
        nacre_material_desc om = nacre_material_desc_defaults(NACRE_MATERIAL_OPAQUE);
        om.specular[0] = om.specular[1] = om.specular[2] = 0;
        nacre_material mat;
        CHECK(nacre_scene_add_material(s, &om, &mat) == NACRE_OK);
        nacre_object_desc od = nacre_object_desc_defaults();
        od.mesh = mesh;
        od.material = mat;
        nacre_object obj;
        CHECK(nacre_scene_add_object(s, &od, &obj) == NACRE_OK);
        nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
        ld.direction[0] = 0.6f, ld.direction[1] = -0.8f, ld.direction[2] = 0;
        ld.strength[0] = ld.strength[1] = ld.strength[2] = 3.0f;
        ld.angular_radius = 0;
        nacre_light l;
        CHECK(nacre_scene_add_light(s, &ld, &l) == NACRE_OK);
        nacre_camera_desc cam = nacre_camera_desc_defaults();
        cam.position[0] = 0, cam.position[1] = 3, cam.position[2] = 0.01f;
        cam.target[0] = 0, cam.target[1] = 0, cam.target[2] = 0;
        cam.up[0] = 0, cam.up[1] = 0, cam.up[2] = -1;
        cam.fov_y = 20;
        CHECK(nacre_scene_set_camera(s, &cam) == NACRE_OK);
        const float black[3] = {0, 0, 0};
        CHECK(nacre_scene_set_environment(s, black) == NACRE_OK);
        CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
        nacre_render_settings rs = pt_settings(8, 2);
        nacre_image img = render_with(ctx, s, &rs, &def, NULL);
        double expect = 0.8 * 3.0 * 0.8 / 3.14159265358979;
        CHECK_NEAR(img.pixels[3 * (4 * 8 + 4)], expect, 1e-3 * expect);
        printf("  lambert plane %.5f expect %.5f\n", img.pixels[3 * (4 * 8 + 4)], expect);
        /* Same scene through the public API: phong sees the same value (no ambient, no spec). */
        nacre_render_settings ph = nacre_render_settings_defaults();
        ph.width = ph.height = 8;
        ph.shadow.map_size = 0;
        nacre_image pimg = {0};
        CHECK(nacre_render(s, &ph, &pimg, NULL) == NACRE_OK);
        CHECK_NEAR(pimg.pixels[3 * (4 * 8 + 4)], img.pixels[3 * (4 * 8 + 4)], 2e-3 * expect);
        nacre_image_free(ctx, &pimg);
        nacre_image_free(ctx, &img);
        /* A point light (intensity, W/sr) and a sphere light of the same intensity: a uniform
         * sphere above the horizon gives exactly I cos / d^2, like the point. Small pixels, so the
         * path tracer's average over a pixel matches phong's value at its centre. */
        ld = nacre_light_desc_defaults(NACRE_LIGHT_POINT);
        ld.position[0] = 1.0f, ld.position[1] = 2.0f, ld.position[2] = 0.0f;
        ld.strength[0] = ld.strength[1] = ld.strength[2] = 5.0f;
        CHECK(nacre_scene_set_light(s, l, &ld) == NACRE_OK);
        CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
        rs.width = rs.height = ph.width = ph.height = 32;
        const size_t mid = 3 * (16 * 32 + 16);
        img = render_with(ctx, s, &rs, &def, NULL);
        CHECK(nacre_render(s, &ph, &pimg, NULL) == NACRE_OK);
        double centre = img.pixels[mid];
        printf("  point light: pathtrace %.5f phong %.5f\n", centre, pimg.pixels[mid]);
        CHECK_NEAR(centre, pimg.pixels[mid], 2e-3 * centre);
        nacre_image_free(ctx, &img);
        nacre_image_free(ctx, &pimg);
        /* A spot aimed past the centre, so the centre sits in the smooth falloff: same as phong. */
        ld.type = NACRE_LIGHT_SPOT;
        ld.direction[0] = -0.3f, ld.direction[1] = -0.95394f, ld.direction[2] = 0.0f;
        ld.inner_angle = 2.0f;
        ld.outer_angle = 14.0f;
        CHECK(nacre_scene_set_light(s, l, &ld) == NACRE_OK);
        CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
        img = render_with(ctx, s, &rs, &def, NULL);
        CHECK(nacre_render(s, &ph, &pimg, NULL) == NACRE_OK);
        printf("  spot light: pathtrace %.5f phong %.5f (point %.5f)\n", img.pixels[mid], pimg.pixels[mid], centre);
        /* The falloff changes ~20% per pixel here, so phong's G-buffer point (rasterizer sub-pixel
         * precision, a few hundredths of a pixel) and the pixel average differ by up to ~1%. */
        CHECK_NEAR(img.pixels[mid], pimg.pixels[mid], 1.5e-2 * pimg.pixels[mid]);
        CHECK(pimg.pixels[mid] < 0.95 * centre && pimg.pixels[mid] > 0.05 * centre);
        nacre_image_free(ctx, &img);
        ld.type = NACRE_LIGHT_POINT;
        ld.radius = 0.3f;
        CHECK(nacre_scene_set_light(s, l, &ld) == NACRE_OK);
        CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
        rs.pathtrace.spp = 64;
        img = render_with(ctx, s, &rs, &def, NULL);
        printf("  sphere light r=0.3: pathtrace %.5f (point %.5f)\n", img.pixels[mid], centre);
        CHECK_NEAR(img.pixels[mid], centre, 0.01 * centre);
        nacre_image_free(ctx, &pimg);
        nacre_image_free(ctx, &img);
        /* An opaque sphere between the centre and the sun (out of view) shadows the centre;
         * with cast_shadows = false the centre is lit as if it were not there: exactly for a
         * delta sun, and within noise for a 2-degree sun (direct light by NEE alone then). */
        {
            nacre_shape_desc bd = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
            nacre_mesh_data bdata = {0};
            CHECK(nacre_mesh_make_shape(ctx, &bd, &bdata) == NACRE_OK);
            nacre_mesh bmesh;
            CHECK(nacre_scene_add_mesh(s, &bdata, &bmesh) == NACRE_OK);
            nacre_mesh_data_free(ctx, &bdata);
            /* Black, so that it adds no indirect light to the centre either. */
            nacre_material_desc black_m = nacre_material_desc_defaults(NACRE_MATERIAL_OPAQUE);
            for (int c = 0; c < 3; c++)
                black_m.diffuse[c] = black_m.specular[c] = 0;
            nacre_material bmat;
            CHECK(nacre_scene_add_material(s, &black_m, &bmat) == NACRE_OK);
            nacre_object_desc bo = nacre_object_desc_defaults();
            bo.mesh = bmesh;
            bo.material = bmat;
            bo.transform.translate[0] = -1.2f, bo.transform.translate[1] = 1.6f;
            bo.transform.scale[0] = bo.transform.scale[1] = bo.transform.scale[2] = 0.3f;
            nacre_object blocker;
            ld = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
            ld.direction[0] = 0.6f, ld.direction[1] = -0.8f, ld.direction[2] = 0;
            ld.strength[0] = ld.strength[1] = ld.strength[2] = 3.0f;
            ld.angular_radius = 0;
            CHECK(nacre_scene_set_light(s, l, &ld) == NACRE_OK);
            rs = pt_settings(8, 2);
            CHECK(nacre_scene_add_object(s, &bo, &blocker) == NACRE_OK);
            CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
            const size_t cpix = 3 * (4 * 8 + 4);
            double lit = 0.8 * 3.0 * 0.8 / 3.14159265358979;
            img = render_with(ctx, s, &rs, &def, NULL);
            CHECK(img.pixels[cpix] == 0.0f);
            nacre_image_free(ctx, &img);
            bo.cast_shadows = false;
            CHECK(nacre_scene_set_object(s, blocker, &bo) == NACRE_OK);
            CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
            img = render_with(ctx, s, &rs, &def, NULL);
            printf("  cast_shadows=false: %.5f expect %.5f\n", img.pixels[cpix], lit);
            CHECK_NEAR(img.pixels[cpix], lit, 1e-3 * lit);
            nacre_image_free(ctx, &img);
            ld.angular_radius = 2.0f;
            CHECK(nacre_scene_set_light(s, l, &ld) == NACRE_OK);
            CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
            nacre_render_settings rs2 = pt_settings(8, 64);
            nacre_image vimg = {0};
            img = render_with(ctx, s, &rs2, &def, &vimg);
            double se = sqrt(vimg.pixels[cpix]);
            printf("  cast_shadows=false, 2-degree sun: %.5f (stderr %.5f) expect %.5f\n", img.pixels[cpix], se, lit);
            CHECK_NEAR(img.pixels[cpix], lit, 4 * se + 5e-3 * lit);
            nacre_image_free(ctx, &img);
            nacre_image_free(ctx, &vimg);
        }
        nacre_scene_destroy(s);
    }

    /* A deformed heterogeneous object: the pattern follows the deformation. A sphere stretched
     * 1.6x along x by a SCALE deformer must look like the same sphere stretched by its transform
     * (a checker of cell 0.6 in rest coordinates; looked up at deformed coordinates it would
     * come out squeezed). Compared pixel by pixel: chi^2 per pixel of the difference over the
     * summed variances is ~1 for equal expectations. */
    {
        nacre_material_desc hm = medium(0.02f, 1.0f, 0.0f, 1.0f);
        hm.pattern.type = NACRE_PATTERN_CHECKER;
        hm.pattern.cell_size = 0.6f;
        for (int c = 0; c < 3; c++) {
            hm.pattern.sigma_a2[c] = 6.0f;
            hm.pattern.sigma_s2[c] = 1.0f;
        }
        nacre_image img[2], var[2];
        for (int variant = 0; variant < 2; variant++) {
            nacre_scene *s = sphere_scene(ctx, &hm, 1.0f);
            nacre_object_desc od = s->objects[0].desc;
            nacre_object obj = {1};
            if (variant == 0) {
                od.deformer_count = 1;
                od.deformers[0] = nacre_deformer_defaults(NACRE_DEFORM_SCALE);
                od.deformers[0].scale[0] = 1.6f;
                od.deformers[0].scale[1] = od.deformers[0].scale[2] = 1.0f;
            } else {
                od.transform.scale[0] = 1.6f;
            }
            CHECK(nacre_scene_set_object(s, obj, &od) == NACRE_OK);
            CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
            nacre_render_settings rs = pt_settings(24, 32);
            rs.pathtrace.seed = 11 + 100 * (uint32_t)variant; /* independent noise in the two images */
            var[variant] = (nacre_image){0};
            img[variant] = render_with(ctx, s, &rs, &def, &var[variant]);
            nacre_scene_destroy(s);
        }
        double chi2 = 0;
        int n = 0;
        for (int i = 0; i < 24 * 24 * 3; i++) {
            double v = var[0].pixels[i] + var[1].pixels[i], d = img[0].pixels[i] - img[1].pixels[i];
            if (v > 0) {
                chi2 += d * d / v;
                n++;
            }
        }
        chi2 /= n > 0 ? n : 1;
        printf("  deformed pattern vs transformed: chi^2 per value %.3f over %d values (1 expected)\n", chi2, n);
        CHECK(n > 500 && chi2 < 1.6);
        for (int v = 0; v < 2; v++) {
            nacre_image_free(ctx, &img[v]);
            nacre_image_free(ctx, &var[v]);
        }
    }

    /* The image lines up with phong: a black opaque sphere against a white sky, pixel by pixel
     * (pixels the path tracer sees fully covered or fully empty must agree; edges are mixed). */
    {
        nacre_material_desc bm = nacre_material_desc_defaults(NACRE_MATERIAL_OPAQUE);
        for (int c = 0; c < 3; c++)
            bm.diffuse[c] = bm.specular[c] = 0;
        nacre_scene *s = sphere_scene(ctx, &bm, 1.0f);
        nacre_render_settings rs = pt_settings(40, 16);
        rs.height = 30;
        nacre_image img = render_with(ctx, s, &rs, &def, NULL), pimg = {0};
        nacre_render_settings ph = nacre_render_settings_defaults();
        ph.width = 40;
        ph.height = 30;
        CHECK(nacre_render(s, &ph, &pimg, NULL) == NACRE_OK);
        int mismatched = 0, covered = 0, mixed = 0;
        for (int i = 0; i < 40 * 30; i++) {
            float a = img.pixels[3 * i], b = pimg.pixels[3 * i];
            if (a == 0.0f) {
                covered++;
                mismatched += b != 0.0f;
            } else if (a == 1.0f) {
                mismatched += b != 1.0f;
            } else {
                mixed++;
            }
        }
        printf("  alignment: %d covered, %d edge pixels, %d mismatched\n", covered, mixed, mismatched);
        CHECK(covered > 200 && mismatched == 0);
        nacre_image_free(ctx, &img);
        nacre_image_free(ctx, &pimg);
        nacre_scene_destroy(s);
    }

    /* Convergence and determinism on a lit translucent sphere (dielectric, chromatic). */
    {
        /* Index matched, so NEE reaches the sphere light from inside: no caustic fireflies, whose
         * heavy tail would make a 3-seed error estimate too noisy to measure a slope. */
        md = medium(0.05f, 1.5f, 0.3f, 1.0f);
        md.sigma_a[2] = 0.4f;
        nacre_scene *s = sphere_scene(ctx, &md, 0.3f);
        nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_POINT);
        ld.position[0] = 2, ld.position[1] = 2, ld.position[2] = 2;
        ld.strength[0] = ld.strength[1] = ld.strength[2] = 10.0f;
        ld.radius = 0.5f;
        nacre_light l;
        CHECK(nacre_scene_add_light(s, &ld, &l) == NACRE_OK);
        CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
        nacre_render_settings rs = pt_settings(12, 256);
        rs.pathtrace.seed = 99;
        nacre_image ref = render_with(ctx, s, &rs, &def, NULL);
        double err[3];
        const uint32_t spps[3] = {4, 16, 64};
        for (int i = 0; i < 3; i++) {
            double e = 0;
            /* Average the error over a few seeds: one render's error is itself noisy. */
            for (uint32_t seed = 1; seed <= 3; seed++) {
                nacre_render_settings r2 = pt_settings(12, spps[i]);
                r2.pathtrace.seed = seed;
                nacre_image img = render_with(ctx, s, &r2, &def, NULL);
                e += rms_diff(&img, &ref) / 3;
                nacre_image_free(ctx, &img);
            }
            /* Remove the reference's own noise (it is 1/64 .. 1/4 of the test's variance). */
            err[i] = e;
        }
        double slope1 = log(err[0] / err[1]) / log(4.0), slope2 = log(err[1] / err[2]) / log(4.0);
        printf("  convergence rms %.4g %.4g %.4g at 4/16/64 spp: slopes %.2f %.2f (0.5 expected)\n", err[0], err[1],
               err[2], slope1, slope2);
        CHECK(slope1 > 0.35 && slope1 < 0.65);
        CHECK(slope2 > 0.3 && slope2 < 0.65);

        /* Same seed, same image with 1 and 2 threads. */
        nacre_context *c1 = NULL;
        nacre_context_desc d1 = {0};
        d1.threads = 1;
        CHECK(nacre_context_create(&d1, &c1) == NACRE_OK);
        nacre_scene *s1 = sphere_scene(c1, &md, 0.3f);
        CHECK(nacre_scene_add_light(s1, &ld, &l) == NACRE_OK);
        CHECK(nacre_scene_commit(s1, 0.0) == NACRE_OK);
        nacre_render_settings r3 = pt_settings(12, 4);
        nacre_image a = {0}, b = {0}, va = {0};
        nacre_renderer *r = NULL;
        CHECK(nacre_renderer_create(c1, &r) == NACRE_OK);
        nacre_render_stats st;
        CHECK(nacre_renderer_render(r, s1, &r3, &a, &st) == NACRE_OK);
        CHECK(st.spp_done == 4 && st.samples_per_second > 0);
        CHECK(nacre_renderer_variance(r, &va) == NACRE_OK);
        CHECK(va.width == 12 && va.pixels != NULL);
        nacre_renderer_destroy(r);
        CHECK(nacre_render(s, &r3, &b, NULL) == NACRE_OK);
        CHECK(memcmp(a.pixels, b.pixels, sizeof(float) * 12 * 12 * 3) == 0);
        nacre_image_free(c1, &a);
        nacre_image_free(c1, &va);
        nacre_image_free(ctx, &b);
        nacre_scene_destroy(s1);
        nacre_context_destroy(c1);

        /* Bad settings fail cleanly; a time limit stops at whole passes. */
        nacre_render_settings bad = pt_settings(12, 0);
        nacre_image img = {0};
        CHECK(nacre_render(s, &bad, &img, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
        CHECK(img.pixels == NULL);
        bad.pathtrace.time_limit = -1;
        bad.pathtrace.spp = 1;
        CHECK(nacre_render(s, &bad, &img, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
        bad.pathtrace.time_limit = NAN;
        CHECK(nacre_render(s, &bad, &img, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
        nacre_render_settings tl = pt_settings(12, 0);
        tl.pathtrace.time_limit = 0.05;
        CHECK(nacre_render(s, &tl, &img, &st) == NACRE_OK);
        CHECK(st.spp_done >= 1);
        nacre_image_free(ctx, &img);
        nacre_renderer *r4 = NULL;
        CHECK(nacre_renderer_create(ctx, &r4) == NACRE_OK);
        nacre_image v4 = {0};
        CHECK(nacre_renderer_variance(r4, &v4) == NACRE_ERROR_INVALID_OPERATION);
        nacre_renderer_destroy(r4);
        nacre_image_free(ctx, &ref);
        nacre_scene_destroy(s);
    }

    test_layered(&def);

    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
