/*
 * test_shadow.c: shadow maps against analytic shadows.
 *
 * A small horizontal square over a ground plane casts a shadow whose outline is the square
 * projected along the light (parallel for directional lights, central for spot and point
 * lights). Points well inside it must read 0, points well outside 1, and the 50% crossing of the
 * PCF result must lie within 2 texels of the analytic edge. A tessellated sphere checks for
 * self-shadowing acne: every point facing the light (n.l > 0.2) must be fully lit.
 */
#include "raster/raster.h"
#include "test_util.h"

#include <stdlib.h>
#include <string.h>

#define PCF 1.5f
#define BIAS 1.5f

typedef struct geo {
    float *pos;
    float *nrm;
    uint32_t *idx;
    uint32_t nv, nt;
} geo;

static void geo_free(geo *g)
{
    free(g->pos);
    free(g->nrm);
    free(g->idx);
    memset(g, 0, sizeof(*g));
}

/* Horizontal square (normal +y) centred at (cx, h, cz), `cells` x `cells` quads. */
/* The end of a test: its map, its n meshes, the rasterizer and the context. */
static void finish(nacre_context *ctx, nc_rasterizer *r, nc_shadow_map *sm, geo *g, int n)
{
    nc_shadow_free(ctx, sm);
    for (int i = 0; i < n; i++)
        geo_free(&g[i]);
    nc_rasterizer_destroy(r);
    nacre_context_destroy(ctx);
}

static geo make_square(double cx, double h, double cz, double half, int cells)
{
    geo g;
    g.nv = (uint32_t)((cells + 1) * (cells + 1));
    g.nt = (uint32_t)(2 * cells * cells);
    g.pos = malloc(sizeof(float) * 3 * g.nv);
    g.nrm = malloc(sizeof(float) * 3 * g.nv);
    g.idx = malloc(sizeof(uint32_t) * 3 * g.nt);
    for (int j = 0; j <= cells; j++)
        for (int i = 0; i <= cells; i++) {
            uint32_t v = (uint32_t)(j * (cells + 1) + i);
            g.pos[3 * v] = (float)(cx - half + 2 * half * i / cells);
            g.pos[3 * v + 1] = (float)h;
            g.pos[3 * v + 2] = (float)(cz - half + 2 * half * j / cells);
            g.nrm[3 * v] = 0.0f;
            g.nrm[3 * v + 1] = 1.0f;
            g.nrm[3 * v + 2] = 0.0f;
        }
    uint32_t t = 0;
    for (int j = 0; j < cells; j++)
        for (int i = 0; i < cells; i++) {
            uint32_t a = (uint32_t)(j * (cells + 1) + i), b = a + 1, c = a + (uint32_t)cells + 1,
                     d = c + 1;
            /* Counter-clockwise seen from +y: a (x-, z-), c (x-, z+), d, b. */
            uint32_t q[6] = {a, c, d, a, d, b};
            memcpy(g.idx + 3 * t, q, sizeof(q));
            t += 2;
        }
    return g;
}

static geo make_sphere(double cx, double cy, double cz, double r, int seg, int rings)
{
    geo g;
    g.nv = (uint32_t)((seg + 1) * (rings + 1));
    g.nt = (uint32_t)(2 * seg * rings);
    g.pos = malloc(sizeof(float) * 3 * g.nv);
    g.nrm = malloc(sizeof(float) * 3 * g.nv);
    g.idx = malloc(sizeof(uint32_t) * 3 * g.nt);
    const double pi = 3.14159265358979323846;
    for (int j = 0; j <= rings; j++)
        for (int i = 0; i <= seg; i++) {
            double th = pi * j / rings, ph = 2 * pi * (i % seg) / seg;
            double n[3] = {sin(th) * cos(ph), cos(th), -sin(th) * sin(ph)};
            uint32_t v = (uint32_t)(j * (seg + 1) + i);
            for (int k = 0; k < 3; k++)
                g.nrm[3 * v + k] = (float)n[k];
            g.pos[3 * v] = (float)(cx + r * n[0]);
            g.pos[3 * v + 1] = (float)(cy + r * n[1]);
            g.pos[3 * v + 2] = (float)(cz + r * n[2]);
        }
    uint32_t t = 0;
    for (int j = 0; j < rings; j++)
        for (int i = 0; i < seg; i++) {
            uint32_t a = (uint32_t)(j * (seg + 1) + i), b = a + 1, c = a + (uint32_t)seg + 1,
                     d = c + 1;
            uint32_t q[6] = {a, c, d, a, d, b};
            memcpy(g.idx + 3 * t, q, sizeof(q));
            t += 2;
        }
    return g;
}

/* Axis-aligned box [x0, x1] x [y0, y1] x [z0, z1], faces wound counter-clockwise outside. */
static geo make_box(double x0, double y0, double z0, double x1, double y1, double z1)
{
    geo g;
    g.nv = 8;
    g.nt = 12;
    g.pos = malloc(sizeof(float) * 3 * 8);
    g.nrm = calloc(3 * 8, sizeof(float)); /* unused */
    g.idx = malloc(sizeof(uint32_t) * 3 * 12);
    for (int i = 0; i < 8; i++) {
        g.pos[3 * i] = (float)((i & 1) ? x1 : x0);
        g.pos[3 * i + 1] = (float)((i & 2) ? y1 : y0);
        g.pos[3 * i + 2] = (float)((i & 4) ? z1 : z0);
    }
    static const uint32_t q[12][3] = {{0, 4, 6}, {0, 6, 2}, {1, 3, 7}, {1, 7, 5},  /* -x, +x */
                                      {0, 1, 5}, {0, 5, 4}, {2, 6, 7}, {2, 7, 3},  /* -y, +y */
                                      {0, 2, 3}, {0, 3, 1}, {4, 5, 7}, {4, 7, 6}}; /* -z, +z */
    memcpy(g.idx, q, sizeof(q));
    return g;
}

static nc_raster_mesh as_mesh(const geo *g, uint32_t object)
{
    nc_raster_mesh m = {g->pos, g->idx, g->nv, g->nt, object, false};
    return m;
}

static void bounds_of(const geo *gs, int n, float lo[3], float hi[3])
{
    for (int k = 0; k < 3; k++) {
        lo[k] = INFINITY;
        hi[k] = -INFINITY;
    }
    for (int i = 0; i < n; i++)
        for (uint32_t v = 0; v < gs[i].nv; v++)
            for (int k = 0; k < 3; k++) {
                lo[k] = fminf(lo[k], gs[i].pos[3 * v + k]);
                hi[k] = fmaxf(hi[k], gs[i].pos[3 * v + k]);
            }
}

static nacre_context *make_ctx(int threads)
{
    nacre_context *ctx = NULL;
    nacre_context_desc cd = {0};
    cd.threads = threads;
    CHECK(nacre_context_create(&cd, &ctx) == NACRE_OK);
    return ctx;
}

typedef struct tally {
    int inside, outside, inside_bad, outside_bad, edge_bad, samples;
} tally;

/* Classify one ground sample: `dist` is the signed distance (scene units, negative in shadow)
 * to the analytic shadow outline and `texel` the size of one shadow texel on the ground. */
static void judge(tally *t, double dist, double texel, float v)
{
    t->samples++;
    double margin = (PCF + 2.0) * texel;
    if (dist < -margin) {
        t->inside++;
        t->inside_bad += v != 0.0f;
    } else if (dist > margin) {
        t->outside++;
        t->outside_bad += v != 1.0f;
    }
    if (dist < -2.0 * texel)
        t->edge_bad += v > 0.5f;
    else if (dist > 2.0 * texel)
        t->edge_bad += v < 0.5f;
}

static void check_tally(const tally *t)
{
    CHECK(t->inside > 200);
    CHECK(t->outside > 200);
    CHECK(t->inside_bad == 0);
    CHECK(t->outside_bad == 0);
    CHECK(t->edge_bad == 0);
    if (t->inside_bad || t->outside_bad || t->edge_bad)
        printf("  inside %d (bad %d) outside %d (bad %d) edge bad %d\n", t->inside, t->inside_bad,
               t->outside, t->outside_bad, t->edge_bad);
}

/* Signed box distance of (x, z) to the square |x - cx| <= half, |z - cz| <= half. */
static double box_dist(double x, double z, double cx, double cz, double half)
{
    return fmax(fabs(x - cx) - half, fabs(z - cz) - half);
}

/* nc_shadow_lookup_n gives nc_shadow_lookup's values (to the rounding of its vectorized set-up)
 * for points over the ground, the occluders and outside the map, with tilted normals, in batches
 * of uneven size; enough of them partly lit that the PCF taps are compared too. */
static void check_batch(const nc_shadow_map *sm, double extent, double top)
{
    enum { N = 3000 };
    static float px[N], py[N], pz[N], nx[N], ny[N], nz[N], got[N];
    uint32_t state = 12345u;
    for (int i = 0; i < N; i++) {
        float r[6];
        for (int k = 0; k < 6; k++) {
            state = state * 1664525u + 1013904223u;
            r[k] = (float)(state >> 8) / 16777216.0f;
        }
        /* every other point near the middle, where the occluders' shadow edges are */
        double e = i % 2 ? 2.5 : extent * 1.2;
        px[i] = (float)((2.0 * r[0] - 1.0) * e);
        pz[i] = (float)((2.0 * r[1] - 1.0) * e);
        py[i] = r[2] < 0.7f ? 0.0f : (float)(r[2] * top);
        nx[i] = 0.6f * (r[3] - 0.5f);
        ny[i] = r[4] < 0.1f ? -1.0f : 1.0f;
        nz[i] = 0.6f * (r[5] - 0.5f);
        if (i % 4 == 3) {
            /* Grazing receivers, slope (tangent against the map's axis) 4 to 16: across the
             * limit where the per-tap depth clamp starts to act (MAX_SLOPE 10), which decides
             * between the batch's affine taps and the exact ones */
            const nc_mat4 *v = &sm->views[0].view;
            double f[3] = {-v->m[2][0], -v->m[2][1], -v->m[2][2]};
            double a[3] = {v->m[0][0], v->m[0][1], v->m[0][2]}, b[3] = {v->m[1][0], v->m[1][1], v->m[1][2]};
            double ang = 6.283185307179586 * r[3], t = 4.0 + 12.0 * r[5];
            for (int k = 0; k < 3; k++) {
                double w = cos(ang) * a[k] + sin(ang) * b[k] - f[k] / t;
                (k == 0 ? nx : k == 1 ? ny : nz)[i] = (float)w;
            }
        }
    }
    int bad = 0, partial = 0;
    for (int i = 0, n = 1; i < N; i += n, n = n % 97 + 13) {
        int m = i + n <= N ? n : N - i;
        nc_shadow_lookup_n(sm, (uint32_t)m, px + i, py + i, pz + i, nx + i, ny + i, nz + i, PCF, BIAS, got + i);
    }
    for (int i = 0; i < N; i++) {
        float want = nc_shadow_lookup(sm, nc_v3(px[i], py[i], pz[i]), nc_v3(nx[i], ny[i], nz[i]), PCF, BIAS);
        bad += !(fabsf(got[i] - want) <= 1e-5f);
        partial += want > 0.0f && want < 1.0f;
    }
    CHECK(bad == 0);
    CHECK(partial > 10);
    if (bad || partial <= 10)
        printf("  batch lookups: %d of %d differ, %d partly lit\n", bad, N, partial);
}

static void test_directional(void)
{
    nacre_context *ctx = make_ctx(2);
    nc_rasterizer *r = NULL;
    CHECK(nc_rasterizer_create(ctx, &r) == NACRE_OK);
    /* A square floating over the ground, a box standing on it and a thin plate just above it
     * (contact shadows). */
    geo g[4] = {make_square(0, 0, 0, 10, 8), make_square(0.5, 2, -0.4, 1, 1),
                make_box(-5.5, 0, 4.5, -4.5, 1, 5.5), make_square(4, 0.1, 5, 0.5, 1)};
    nc_raster_mesh m[4] = {as_mesh(&g[0], 0), as_mesh(&g[1], 1), as_mesh(&g[2], 2),
                           as_mesh(&g[3], 3)};
    float lo[3], hi[3];
    bounds_of(g, 4, lo, hi);
    nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
    double dir[3] = {0.3, -1.0, 0.2}, dl = sqrt(0.09 + 1 + 0.04);
    for (int k = 0; k < 3; k++)
        ld.direction[k] = (float)(dir[k] / dl);
    nc_shadow_map sm;
    memset(&sm, 0, sizeof(sm));
    CHECK(nc_shadow_render(r, ctx, &ld, lo, hi, 1024, m, 4, &sm) == NACRE_OK);
    CHECK(sm.kind == NC_SHADOW_ORTHO && sm.face_count == 1 && sm.size == 1024);
    /* The map fits the bounds: a texel is about the scene's diagonal extent / size. */
    CHECK(sm.texel_world[0] > 20.0f / 1024 && sm.texel_world[0] < 30.0f / 1024);
    double ly = -ld.direction[1];
    double texel = sm.texel_world[0] / ly;
    double s = 2.0 / ly; /* ground -> occluder along the light */
    tally t = {0};
    for (double z = -9.7; z <= 9.7; z += 0.043)
        for (double x = -9.7; x <= 9.7; x += 0.043) {
            double qx = x - s * ld.direction[0], qz = z - s * ld.direction[2];
            if ((x < -3.5 || x > 3.0) && z > 3.5)
                continue; /* the box and the plate, checked below */
            float v =
                nc_shadow_lookup(&sm, nc_v3((float)x, 0, (float)z), nc_v3(0, 1, 0), PCF, BIAS);
            judge(&t, box_dist(qx, qz, 0.5, -0.4, 1.0), texel, v);
        }
    check_tally(&t);
    /* The box's shadow starts at its base: the ground just beside the lit-away side is dark
     * (a large depth bias would light it: peter-panning), the ground on the light's side lit. */
    int contact_bad = 0, front_bad = 0;
    for (double z = 4.8; z <= 5.3; z += 0.02) {
        for (double x = -4.45; x <= -4.3; x += 0.01)
            contact_bad += nc_shadow_lookup(&sm, nc_v3((float)x, 0, (float)z), nc_v3(0, 1, 0), PCF,
                                            BIAS) != 0.0f;
        for (double x = -5.8; x <= -5.6; x += 0.01)
            front_bad += nc_shadow_lookup(&sm, nc_v3((float)x, 0, (float)z), nc_v3(0, 1, 0), PCF,
                                          BIAS) != 1.0f;
    }
    /* The plate 0.1 above the ground: a depth bias of a few texels too many would lose it. */
    double sp = 0.1 / ly;
    tally tp = {0};
    for (double z = 4.2; z <= 5.8; z += 0.011)
        for (double x = 3.2; x <= 4.8; x += 0.011) {
            float v =
                nc_shadow_lookup(&sm, nc_v3((float)x, 0, (float)z), nc_v3(0, 1, 0), PCF, BIAS);
            judge(&tp, box_dist(x - sp * ld.direction[0], z - sp * ld.direction[2], 4, 5, 0.5),
                  texel, v);
        }
    CHECK(tp.inside > 200 && tp.inside_bad == 0 && tp.edge_bad == 0);
    CHECK(contact_bad == 0);
    CHECK(front_bad == 0);
    /* The occluder's own lit face, and points beyond the map. */
    int acne = 0;
    for (double z = -0.9; z <= 0.5; z += 0.05)
        for (double x = -0.4; x <= 1.4; x += 0.05)
            acne += nc_shadow_lookup(&sm, nc_v3((float)x, 2, (float)z), nc_v3(0, 1, 0), PCF,
                                     BIAS) != 1.0f;
    CHECK(acne == 0);
    CHECK(nc_shadow_lookup(&sm, nc_v3(50, 0, 50), nc_v3(0, 1, 0), PCF, BIAS) == 1.0f);
    check_batch(&sm, 10.0, 2.5);
    /* Rendering again into the same map reuses it and gives the same texels. */
    float *copy = malloc(sizeof(float) * 1024 * 1024);
    memcpy(copy, sm.depth, sizeof(float) * 1024 * 1024);
    CHECK(nc_shadow_render(r, ctx, &ld, lo, hi, 1024, m, 4, &sm) == NACRE_OK);
    CHECK(memcmp(copy, sm.depth, sizeof(float) * 1024 * 1024) == 0);
    free(copy);
    /* A zero direction is an error. */
    nacre_light_desc bad = ld;
    bad.direction[0] = bad.direction[1] = bad.direction[2] = 0.0f;
    CHECK(nc_shadow_render(r, ctx, &bad, lo, hi, 64, m, 2, &sm) == NACRE_ERROR_INVALID_ARGUMENT);
    nc_shadow_free(ctx, &sm);
    CHECK(sm.depth == NULL);
    for (int i = 0; i < 4; i++)
        geo_free(&g[i]);
    nc_rasterizer_destroy(r);
    nacre_context_destroy(ctx);
}

/* Central projection from L of a ground point onto the occluder plane y = h; returns the signed
 * ground distance to the shadow outline of square (cx, cz, half). */
static double central_dist(const double L[3], double x, double z, double h, double cx, double cz,
                           double half)
{
    double s = (L[1] - h) / L[1]; /* fraction of the way from L to the ground */
    double qx = L[0] + (x - L[0]) * s, qz = L[2] + (z - L[2]) * s;
    return box_dist(qx, qz, cx, cz, half) / s;
}

static void test_spot(void)
{
    nacre_context *ctx = make_ctx(2);
    nc_rasterizer *r = NULL;
    CHECK(nc_rasterizer_create(ctx, &r) == NACRE_OK);
    geo g[2] = {make_square(0, 0, 0, 10, 8), make_square(0, 2, 0, 1, 1)};
    nc_raster_mesh m[2] = {as_mesh(&g[0], 0), as_mesh(&g[1], 1)};
    float lo[3], hi[3];
    bounds_of(g, 2, lo, hi);
    nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_SPOT);
    double L[3] = {0.4, 6.0, -0.3}, dir[3] = {0.05, -1.0, 0.03};
    double dl = sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
    for (int k = 0; k < 3; k++) {
        ld.position[k] = (float)L[k];
        ld.direction[k] = (float)(dir[k] / dl);
    }
    ld.outer_angle = 50.0f;
    ld.inner_angle = 40.0f;
    nc_shadow_map sm;
    memset(&sm, 0, sizeof(sm));
    CHECK(nc_shadow_render(r, ctx, &ld, lo, hi, 1024, m, 2, &sm) == NACRE_OK);
    CHECK(sm.kind == NC_SHADOW_PERSPECTIVE && sm.face_count == 1);
    tally t = {0};
    double cos_lim = cos(45.0 * 3.14159265358979 / 180.0);
    for (double z = -9.7; z <= 9.7; z += 0.043)
        for (double x = -9.7; x <= 9.7; x += 0.043) {
            double d[3] = {x - L[0], -L[1], z - L[2]};
            double dist = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            double along =
                (d[0] * ld.direction[0] + d[1] * ld.direction[1] + d[2] * ld.direction[2]);
            if (along / dist < cos_lim)
                continue; /* outside the cone: unlit anyway */
            double cos_inc = L[1] / dist;
            double texel = sm.texel_world[0] * along / cos_inc;
            float v =
                nc_shadow_lookup(&sm, nc_v3((float)x, 0, (float)z), nc_v3(0, 1, 0), PCF, BIAS);
            judge(&t, central_dist(L, x, z, 2.0, 0, 0, 1), texel, v);
        }
    check_tally(&t);
    int acne = 0;
    for (double z = -0.9; z <= 0.9; z += 0.05)
        for (double x = -0.9; x <= 0.9; x += 0.05)
            acne += nc_shadow_lookup(&sm, nc_v3((float)x, 2, (float)z), nc_v3(0, 1, 0), PCF,
                                     BIAS) != 1.0f;
    CHECK(acne == 0);
    /* Behind the light: outside the map, lit. */
    CHECK(nc_shadow_lookup(&sm, nc_v3(0.4f, 8, -0.3f), nc_v3(0, 1, 0), PCF, BIAS) == 1.0f);
    check_batch(&sm, 10.0, 2.5);
    finish(ctx, r, &sm, g, 2);
}

static void test_point(void)
{
    nacre_context *ctx = make_ctx(2);
    nc_rasterizer *r = NULL;
    CHECK(nc_rasterizer_create(ctx, &r) == NACRE_OK);
    /* Occluders below the light (the -y face) and off to three sides (+x, -x, -z faces). */
    static const double occ[4][4] = {
        {0, 2, 0, 1}, {6, 1, 0, 0.5}, {-5.5, 1, 0.5, 0.5}, {-0.5, 1, -6, 0.5}};
    geo g[5];
    g[0] = make_square(0, 0, 0, 10, 8);
    nc_raster_mesh m[5];
    m[0] = as_mesh(&g[0], 0);
    for (int i = 0; i < 4; i++) {
        g[i + 1] = make_square(occ[i][0], occ[i][1], occ[i][2], occ[i][3], 1);
        m[i + 1] = as_mesh(&g[i + 1], (uint32_t)i + 1);
    }
    float lo[3], hi[3];
    bounds_of(g, 5, lo, hi);
    nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_POINT);
    double L[3] = {0.3, 5.0, 0.2};
    for (int k = 0; k < 3; k++)
        ld.position[k] = (float)L[k];
    nc_shadow_map sm;
    memset(&sm, 0, sizeof(sm));
    CHECK(nc_shadow_render(r, ctx, &ld, lo, hi, 512, m, 5, &sm) == NACRE_OK);
    CHECK(sm.kind == NC_SHADOW_CUBE && sm.face_count == 6 && sm.size == 512);
    tally t = {0};
    int faces_seen[6] = {0}, shadow_faces[6] = {0};
    for (double z = -9.7; z <= 9.7; z += 0.043)
        for (double x = -9.7; x <= 9.7; x += 0.043) {
            double d[3] = {x - L[0], -L[1], z - L[2]};
            double ax = fabs(d[0]), ay = fabs(d[1]), az = fabs(d[2]);
            int face = ax >= ay && ax >= az ? (d[0] >= 0 ? 0 : 1)
                       : ay >= az           ? (d[1] >= 0 ? 2 : 3)
                                            : (d[2] >= 0 ? 4 : 5);
            double major = fmax(ax, fmax(ay, az));
            double dist = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            double texel = sm.texel_world[face] * major * (dist / major) / (L[1] / dist);
            float v =
                nc_shadow_lookup(&sm, nc_v3((float)x, 0, (float)z), nc_v3(0, 1, 0), PCF, BIAS);
            double sd = INFINITY; /* signed distance to the union of the shadows */
            for (int i = 0; i < 4; i++)
                sd = fmin(sd, central_dist(L, x, z, occ[i][1], occ[i][0], occ[i][2], occ[i][3]));
            faces_seen[face]++;
            shadow_faces[face] += sd < -(PCF + 2.0) * texel;
            judge(&t, sd, texel, v);
        }
    check_tally(&t);
    CHECK(faces_seen[0] > 0 && faces_seen[1] > 0 && faces_seen[3] > 0 && faces_seen[4] > 0 &&
          faces_seen[5] > 0);
    CHECK(shadow_faces[0] > 50 && shadow_faces[1] > 50 && shadow_faces[3] > 50 &&
          shadow_faces[5] > 50);
    check_batch(&sm, 10.0, 4.0);
    finish(ctx, r, &sm, g, 5);
}

/* Points on the facets of a sphere lit by `ld`: everything facing the light must be lit. */
static void acne_case(nc_rasterizer *r, nacre_context *ctx, const nacre_light_desc *ld, int size,
                      const char *name)
{
    geo g[2] = {make_square(0, 0, 0, 6, 4), make_sphere(0.2, 1.3, -0.1, 1.0, 64, 32)};
    nc_raster_mesh m[2] = {as_mesh(&g[0], 0), as_mesh(&g[1], 1)};
    float lo[3], hi[3];
    bounds_of(g, 2, lo, hi);
    nc_shadow_map sm;
    memset(&sm, 0, sizeof(sm));
    CHECK(nc_shadow_render(r, ctx, ld, lo, hi, size, m, 2, &sm) == NACRE_OK);
    int facing = 0, acne = 0, back = 0, back_lit = 0;
    static const double bary[4][3] = {
        {1.0 / 3, 1.0 / 3, 1.0 / 3}, {0.7, 0.2, 0.1}, {0.1, 0.7, 0.2}, {0.2, 0.1, 0.7}};
    for (uint32_t t = 0; t < g[1].nt; t++)
        for (int s = 0; s < 4; s++) {
            double p[3] = {0, 0, 0}, n[3] = {0, 0, 0};
            for (int k = 0; k < 3; k++) {
                uint32_t v = g[1].idx[3 * t + k];
                for (int c = 0; c < 3; c++) {
                    p[c] += bary[s][k] * g[1].pos[3 * v + c];
                    n[c] += bary[s][k] * g[1].nrm[3 * v + c];
                }
            }
            double nl = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
            double l[3];
            if (ld->type == NACRE_LIGHT_DIRECTIONAL) {
                for (int c = 0; c < 3; c++)
                    l[c] = -ld->direction[c];
            } else {
                for (int c = 0; c < 3; c++)
                    l[c] = ld->position[c] - p[c];
            }
            double ll = sqrt(l[0] * l[0] + l[1] * l[1] + l[2] * l[2]);
            double ndl = (n[0] * l[0] + n[1] * l[1] + n[2] * l[2]) / (nl * ll);
            float v = nc_shadow_lookup(
                &sm, nc_v3((float)p[0], (float)p[1], (float)p[2]),
                nc_v3((float)(n[0] / nl), (float)(n[1] / nl), (float)(n[2] / nl)), PCF, BIAS);
            if (ndl > 0.2) {
                facing++;
                acne += v < 0.999f;
            } else if (ndl < -0.5) {
                back++;
                back_lit += v > 0.001f; /* the sphere shadows its own far side */
            }
        }
    CHECK(facing > 3000);
    CHECK(acne == 0);
    CHECK(back > 3000);
    CHECK(back_lit == 0);
    if (acne || back_lit)
        printf("  %s: %d of %d facing points shadowed, %d of %d back points lit\n", name, acne,
               facing, back_lit, back);
    nc_shadow_free(ctx, &sm);
    geo_free(&g[0]);
    geo_free(&g[1]);
}

/* A sun along (0.4, -1, 0.3), normalised: oblique to the test squares. */
static nacre_light_desc tilted_sun(void)
{
    nacre_light_desc dl = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
    double d[3] = {0.4, -1.0, 0.3}, n = sqrt(0.16 + 1 + 0.09);
    for (int k = 0; k < 3; k++)
        dl.direction[k] = (float)(d[k] / n);
    return dl;
}

static void test_acne(void)
{
    nacre_context *ctx = make_ctx(2);
    nc_rasterizer *r = NULL;
    CHECK(nc_rasterizer_create(ctx, &r) == NACRE_OK);
    nacre_light_desc dl = tilted_sun();
    acne_case(r, ctx, &dl, 1024, "directional");
    nacre_light_desc sl = nacre_light_desc_defaults(NACRE_LIGHT_SPOT);
    float sp[3] = {3.0f, 5.0f, 2.0f}, st[3] = {0.2f, 1.3f, -0.1f};
    double sd[3], sn = 0.0;
    for (int k = 0; k < 3; k++) {
        sl.position[k] = sp[k];
        sd[k] = st[k] - sp[k];
        sn += sd[k] * sd[k];
    }
    for (int k = 0; k < 3; k++)
        sl.direction[k] = (float)(sd[k] / sqrt(sn));
    sl.outer_angle = 30.0f;
    sl.inner_angle = 20.0f;
    acne_case(r, ctx, &sl, 1024, "spot");
    nacre_light_desc pl = nacre_light_desc_defaults(NACRE_LIGHT_POINT);
    pl.position[0] = -2.5f;
    pl.position[1] = 3.0f;
    pl.position[2] = 1.5f;
    acne_case(r, ctx, &pl, 512, "point");
    nc_rasterizer_destroy(r);
    nacre_context_destroy(ctx);
}

/* ---- fog lookups with the min-max table (nc_shadow_lookup_volume_n) ---------------------- */

static float rnd01(uint32_t *state)
{
    *state = *state * 1664525u + 1013904223u;
    return (float)(*state >> 8) / 16777216.0f;
}

/* What a scene for the table's tests holds: the casters' bounds, the light, and a caster's
 * square outline (centre cx, cz at height h, half-width half) for points across its shadow. */
typedef struct vol_scene {
    float lo[3], hi[3];
    const nacre_light_desc *ld;
    double cx, h, cz, half;
} vol_scene;

/* The way light travels to p (unit). */
static void light_way(const vol_scene *vs, const double p[3], double w[3])
{
    double l = 0.0;
    for (int k = 0; k < 3; k++) {
        w[k] = vs->ld->type == NACRE_LIGHT_DIRECTIONAL ? vs->ld->direction[k] : p[k] - vs->ld->position[k];
        l += w[k] * w[k];
    }
    for (int k = 0; k < 3; k++)
        w[k] /= sqrt(l);
}

/* 8 points of one kind into px, py, pz (8 each): 0, anywhere in and around the bounds (some
 * outside the map, in front of the near plane or behind the light); 1, a froxel column's run
 * from an eye outside the bounds, at depths growing by a factor per lane, near the eye or far;
 * 2, across the shadow of the square's outline, beside the light's rays through its edge;
 * 3, a cluster within about a texel (the same few texels). */
static void vol_points(const vol_scene *vs, int kind, double texel, uint32_t *st, float *px, float *py, float *pz)
{
    double ext[3], mid[3];
    for (int k = 0; k < 3; k++) {
        ext[k] = vs->hi[k] - vs->lo[k] + 1.0;
        mid[k] = 0.5 * (vs->hi[k] + vs->lo[k]);
    }
    double p[3], d[3];
    if (kind == 0) {
        for (int l = 0; l < 8; l++) {
            px[l] = (float)(mid[0] + (rnd01(st) - 0.5) * 1.8 * ext[0]);
            py[l] = (float)(mid[1] + (rnd01(st) - 0.5) * 1.8 * ext[1]);
            pz[l] = (float)(mid[2] + (rnd01(st) - 0.5) * 1.8 * ext[2]);
        }
        return;
    }
    if (kind == 1) {
        double ang = 6.283185307179586 * rnd01(st), r = 0.6 * (ext[0] + ext[2]);
        double eye[3] = {mid[0] + r * cos(ang), vs->lo[1] + (0.2 + 2.0 * rnd01(st)) * ext[1], mid[2] + r * sin(ang)};
        double tgt[3] = {mid[0] + (rnd01(st) - 0.5) * ext[0], vs->lo[1], mid[2] + (rnd01(st) - 0.5) * ext[2]};
        double dl = 0.0;
        for (int k = 0; k < 3; k++) {
            d[k] = tgt[k] - eye[k];
            dl += d[k] * d[k];
        }
        dl = sqrt(dl);
        double t = rnd01(st) < 0.5 ? 0.05 * dl * (1.0 + rnd01(st)) : dl * (0.3 + rnd01(st));
        double q = 1.02 + 0.3 * rnd01(st);
        for (int l = 0; l < 8; l++, t *= q) {
            px[l] = (float)(eye[0] + t * d[0] / dl);
            py[l] = (float)(eye[1] + t * d[1] / dl);
            pz[l] = (float)(eye[2] + t * d[2] / dl);
        }
        return;
    }
    /* A point on the outline (or, for clusters, anywhere over the ground) */
    double e = 2.0 * rnd01(st) - 1.0;
    int side = (int)(4.0f * rnd01(st)) & 3;
    p[0] = vs->cx + (side < 2 ? (side ? 1 : -1) * vs->half : e * vs->half);
    p[1] = vs->h;
    p[2] = vs->cz + (side >= 2 ? (side & 1 ? 1 : -1) * vs->half : e * vs->half);
    if (kind == 3)
        for (int k = 0; k < 3; k++)
            p[k] = mid[k] + (rnd01(st) - 0.5) * ext[k];
    light_way(vs, p, d);
    double along = kind == 2 ? (0.2 + 0.75 * rnd01(st)) * vs->h / -d[1] : 0.0;
    for (int l = 0; l < 8; l++) {
        double s = kind == 2 ? along * (0.7 + 0.6 * rnd01(st)) : 0.0, j = kind == 2 ? 3.0 : 0.7;
        px[l] = (float)(p[0] + s * d[0] + (rnd01(st) - 0.5) * j * texel);
        py[l] = (float)(p[1] + s * d[1] + (rnd01(st) - 0.5) * j * texel);
        pz[l] = (float)(p[2] + s * d[2] + (rnd01(st) - 0.5) * j * texel);
    }
}

typedef struct vol_stats {
    int groups, bad, live, read, dark, lit, partial;
} vol_stats;

/* Groups of every kind, looked up in batches of 1 to 12 groups with the table and compared bit
 * for bit with nc_shadow_lookup_volume8, one group at a time. */
static void vol_compare(const nc_shadow_map *sm, const nc_shadow_minmax *mm, const vol_scene *vs, float bias,
                        int groups, uint32_t seed, vol_stats *t)
{
    enum { MAXG = 12 };
    float px[8 * MAXG], py[8 * MAXG], pz[8 * MAXG], got[8 * MAXG], want[8];
    double texel = (vs->hi[0] - vs->lo[0] + vs->hi[2] - vs->lo[2]) / sm->size;
    uint32_t st = seed;
    for (int done = 0; done < groups;) {
        int ng = 1 + (int)(rnd01(&st) * MAXG) % MAXG;
        for (int q = 0; q < ng; q++)
            vol_points(vs, (done + q) % 4, texel, &st, px + 8 * q, py + 8 * q, pz + 8 * q);
        t->read += (int)nc_shadow_lookup_volume_n(sm, mm, 8u * (uint32_t)ng, px, py, pz, bias, got);
        for (int q = 0; q < ng; q++) {
            nc_shadow_lookup_volume8(sm, px + 8 * q, py + 8 * q, pz + 8 * q, bias, want);
            t->bad += memcmp(want, got + 8 * q, sizeof(want)) != 0;
            for (int l = 0; l < 8; l++) {
                /* live: what the plain lookup did not leave at 1 for being outside (approx.) */
                float w = want[l];
                t->dark += w == 0.0f;
                t->lit += w >= 0.999f;
                t->partial += w > 0.0f && w < 0.999f;
            }
        }
        t->groups += ng;
        done += ng;
    }
}

/* A batch whose every point the table must decide (read nothing) and whose values are `want`
 * (0: deep shadow, 1: well lit), bit for bit the plain lookups'. */
static void vol_decided(const nc_shadow_map *sm, const nc_shadow_minmax *mm, const float *px, const float *py,
                        const float *pz, uint32_t n, float want)
{
    float got[64], ref[8];
    CHECK(n <= 64 && n % 8 == 0);
    CHECK(nc_shadow_lookup_volume_n(sm, mm, n, px, py, pz, BIAS, got) == 0);
    int bad = 0, off = 0;
    for (uint32_t i = 0; i < n; i += 8) {
        nc_shadow_lookup_volume8(sm, px + i, py + i, pz + i, BIAS, ref);
        bad += memcmp(ref, got + i, sizeof(ref)) != 0;
        for (int l = 0; l < 8; l++)
            off += !(fabsf(got[i + l] - want) <= 1e-6f);
    }
    CHECK(bad == 0);
    CHECK(off == 0);
}

/* Points straight under (or over) the square's middle, between fractions a and b of the way
 * from the ground to it along the light (b > 1: above it, towards the light). */
static void vol_column(const vol_scene *vs, double a, double b, float *px, float *py, float *pz, uint32_t n)
{
    double p[3] = {vs->cx, vs->h, vs->cz}, d[3];
    light_way(vs, p, d);
    double full = vs->h / -d[1];
    for (uint32_t i = 0; i < n; i++) {
        double s = full * (1.0 - (a + (b - a) * (i + 0.5) / n));
        double j = 0.3 * vs->half * ((i * 7 % 5) / 4.0 - 0.5);
        px[i] = (float)(p[0] + s * d[0] + j);
        py[i] = (float)(p[1] + s * d[1]);
        pz[i] = (float)(p[2] + s * d[2] - j);
    }
}

static void vol_case(nc_rasterizer *r, nacre_context *ctx, const nacre_light_desc *ld, int size, const char *name)
{
    /* Ground, the square over it, a box and a sphere standing on it */
    geo g[4] = {make_square(0, 0, 0, 10, 8), make_square(0.5, 2, -0.4, 1.5, 2), make_box(-5.5, 0, 4.5, -4.5, 1, 5.5),
                make_sphere(4.0, 1.0, -4.0, 1.0, 32, 16)};
    nc_raster_mesh m[4] = {as_mesh(&g[0], 0), as_mesh(&g[1], 1), as_mesh(&g[2], 2), as_mesh(&g[3], 3)};
    vol_scene vs = {.ld = ld, .cx = 0.5, .h = 2.0, .cz = -0.4, .half = 1.5};
    bounds_of(g, 4, vs.lo, vs.hi);
    nc_shadow_map sm;
    memset(&sm, 0, sizeof(sm));
    CHECK(nc_shadow_render(r, ctx, ld, vs.lo, vs.hi, size, m, 4, &sm) == NACRE_OK);
    nc_shadow_minmax mm;
    memset(&mm, 0, sizeof(mm));
    CHECK(nc_shadow_minmax_update(ctx, &sm, &mm, 2) == NACRE_OK);
    CHECK(mm.generation == sm.generation && mm.generation != 0);
    CHECK(mm.dim == (size >> mm.shift) + 1 && mm.dim <= NC_SHADOW_MM_DIM);

    vol_stats t = {0};
    vol_compare(&sm, &mm, &vs, BIAS, 6000, 777u + (uint32_t)size, &t);
    vol_compare(&sm, &mm, &vs, 0.0f, 1000, 31u, &t);
    vol_compare(&sm, &mm, &vs, 50.0f, 1000, 32u, &t);
    vol_compare(&sm, &mm, &vs, INFINITY, 200, 33u, &t);
    CHECK(t.bad == 0);
    CHECK(t.dark > 2000 && t.lit > 2000 && t.partial > 300);
    /* Most points are decided by the table, not all (the edges' are read) */
    int lanes = 8 * t.groups;
    CHECK(t.read > 0 && t.read < lanes / 2);
    if (t.bad || !(t.read > 0 && t.read < lanes / 2) || t.dark <= 2000 || t.partial <= 300)
        printf("  %s: %d of %d groups differ; %d of %d points read texels; %d dark, %d lit, %d partial\n", name,
               t.bad, t.groups, t.read, lanes, t.dark, t.lit, t.partial);

    /* Deep in the square's shadow, and between it and the light */
    float px[64], py[64], pz[64];
    vol_column(&vs, 0.3, 0.8, px, py, pz, 64);
    vol_decided(&sm, &mm, px, py, pz, 64, 0.0f);
    vol_column(&vs, 1.15, 1.6, px, py, pz, 64);
    vol_decided(&sm, &mm, px, py, pz, 64, 1.0f);

    /* Depths that no comparison decides (NaN) or that are infinite, in patches of a copy of the
     * map (a new generation: the table is made again) */
    nc_shadow_map bad = sm;
    size_t texels = (size_t)size * (size_t)size;
    bad.depth = malloc(texels * sizeof(float));
    memcpy(bad.depth, sm.depth, texels * sizeof(float));
    bad.generation = sm.generation + 1000000u;
    const float odd[4] = {NAN, INFINITY, -INFINITY, -0.5f};
    for (int pch = 0; pch < 12; pch++) {
        int x0 = (int)((pch % 4) * size / 4 + size / 16), y0 = (int)((pch / 4) * size / 3 + size / 12);
        for (int y = y0; y < y0 + size / 10 && y < size; y++)
            for (int x = x0; x < x0 + size / 10 && x < size; x++)
                if ((x + y) % 3 == 0)
                    bad.depth[(size_t)y * (size_t)size + (size_t)x] = odd[pch % 4];
    }
    /* ... and one texel, at a texel's spacing from the last row and column */
    bad.depth[(size_t)(size - 1) * (size_t)size + (size_t)(size / 2)] = NAN;
    bad.depth[(size_t)(size / 2) * (size_t)size + (size_t)(size - 1)] = NAN;
    CHECK(nc_shadow_minmax_update(ctx, &bad, &mm, 2) == NACRE_OK);
    CHECK(mm.generation == bad.generation);
    vol_stats tb = {0};
    vol_compare(&bad, &mm, &vs, BIAS, 3000, 99u, &tb);
    vol_compare(&bad, &mm, &vs, INFINITY, 300, 98u, &tb);
    vol_compare(&bad, &mm, &vs, -INFINITY, 300, 97u, &tb);
    CHECK(tb.bad == 0);
    if (tb.bad)
        printf("  %s, odd depths: %d of %d groups differ\n", name, tb.bad, tb.groups);
    free(bad.depth);

    nc_shadow_minmax_free(ctx, &mm);
    nc_shadow_free(ctx, &sm);
    for (int i = 0; i < 4; i++)
        geo_free(&g[i]);
}

static void test_volume_table(void)
{
    nacre_context *ctx = make_ctx(2);
    nc_rasterizer *r = NULL;
    CHECK(nc_rasterizer_create(ctx, &r) == NACRE_OK);
    nacre_light_desc dl = tilted_sun();
    /* Sizes: blocks of 1 texel (dim = size + 1), of 2 and 8 (the default map), sizes that are
     * not powers of two (clipped blocks at the far border) */
    vol_case(r, ctx, &dl, 200, "directional 200");
    vol_case(r, ctx, &dl, 300, "directional 300");
    vol_case(r, ctx, &dl, 2048, "directional 2048");
    nacre_light_desc sl = nacre_light_desc_defaults(NACRE_LIGHT_SPOT);
    double L[3] = {1.5, 7.0, -1.0}, sd[3] = {-0.1, -1.0, 0.08}, sn = sqrt(0.01 + 1 + 0.0064);
    for (int k = 0; k < 3; k++) {
        sl.position[k] = (float)L[k];
        sl.direction[k] = (float)(sd[k] / sn);
    }
    sl.outer_angle = 55.0f;
    sl.inner_angle = 45.0f;
    vol_case(r, ctx, &sl, 257, "spot 257");
    vol_case(r, ctx, &sl, 700, "spot 700");

    /* A cube map gets no table: the lookups are the plain ones, every point reading texels */
    nacre_light_desc pl = nacre_light_desc_defaults(NACRE_LIGHT_POINT);
    pl.position[0] = 0.3f, pl.position[1] = 5.0f, pl.position[2] = 0.2f;
    geo g[2] = {make_square(0, 0, 0, 10, 8), make_square(0.5, 2, -0.4, 1.5, 2)};
    nc_raster_mesh m[2] = {as_mesh(&g[0], 0), as_mesh(&g[1], 1)};
    vol_scene vs = {.ld = &pl, .cx = 0.5, .h = 2.0, .cz = -0.4, .half = 1.5};
    bounds_of(g, 2, vs.lo, vs.hi);
    nc_shadow_map sm;
    memset(&sm, 0, sizeof(sm));
    CHECK(nc_shadow_render(r, ctx, &pl, vs.lo, vs.hi, 64, m, 2, &sm) == NACRE_OK);
    nc_shadow_minmax mm;
    memset(&mm, 0, sizeof(mm));
    CHECK(nc_shadow_minmax_update(ctx, &sm, &mm, 2) == NACRE_OK);
    CHECK(mm.generation == 0);
    vol_stats t = {0};
    vol_compare(&sm, &mm, &vs, BIAS, 300, 5u, &t);
    CHECK(t.bad == 0 && t.read == 8 * t.groups);
    nc_shadow_minmax_free(ctx, &mm);
    finish(ctx, r, &sm, g, 2);
}

/* The table is made again when its map is re-rendered (the light moved), and only then; a table
 * left from before the map changed decides nothing. */
static void test_volume_table_update(void)
{
    nacre_context *ctx = make_ctx(2);
    nc_rasterizer *r = NULL;
    CHECK(nc_rasterizer_create(ctx, &r) == NACRE_OK);
    geo g[2] = {make_square(0, 0, 0, 10, 8), make_square(0.5, 2, -0.4, 1.5, 2)};
    nc_raster_mesh m[2] = {as_mesh(&g[0], 0), as_mesh(&g[1], 1)};
    nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
    ld.direction[0] = 0.0f, ld.direction[1] = -1.0f, ld.direction[2] = 0.0f;
    vol_scene vs = {.ld = &ld, .cx = 0.5, .h = 2.0, .cz = -0.4, .half = 1.5};
    bounds_of(g, 2, vs.lo, vs.hi);
    nc_shadow_map sm, other;
    memset(&sm, 0, sizeof(sm));
    memset(&other, 0, sizeof(other));
    CHECK(nc_shadow_render(r, ctx, &ld, vs.lo, vs.hi, 512, m, 2, &sm) == NACRE_OK);
    CHECK(nc_shadow_render(r, ctx, &ld, vs.lo, vs.hi, 512, m, 2, &other) == NACRE_OK);
    CHECK(sm.generation != 0 && other.generation != 0 && sm.generation != other.generation);
    nc_shadow_minmax mm;
    memset(&mm, 0, sizeof(mm));
    CHECK(nc_shadow_minmax_update(ctx, &sm, &mm, 2) == NACRE_OK);
    uint64_t first = mm.generation;
    CHECK(first == sm.generation);
    /* Not re-rendered: kept (a mark in the table survives) */
    const float mark = 12345.0f;
    float saved = mm.data[0];
    mm.data[0] = mark;
    CHECK(nc_shadow_minmax_update(ctx, &sm, &mm, 2) == NACRE_OK);
    CHECK(mm.generation == first && mm.data[0] == mark);
    mm.data[0] = saved;
    /* Another map of the same size: made for it */
    mm.data[0] = mark;
    CHECK(nc_shadow_minmax_update(ctx, &other, &mm, 2) == NACRE_OK);
    CHECK(mm.generation == other.generation && mm.data[0] != mark);
    CHECK(nc_shadow_minmax_update(ctx, &sm, &mm, 2) == NACRE_OK);
    CHECK(mm.generation == sm.generation);

    /* The light turns: the map is re-rendered, the table is stale until updated */
    float px[64], py[64], pz[64], got[64], want[8];
    vol_column(&vs, 0.3, 0.8, px, py, pz, 64);
    CHECK(nc_shadow_lookup_volume_n(&sm, &mm, 64, px, py, pz, BIAS, got) == 0);
    ld.direction[0] = 0.6f, ld.direction[1] = -0.8f;
    CHECK(nc_shadow_render(r, ctx, &ld, vs.lo, vs.hi, 512, m, 2, &sm) == NACRE_OK);
    CHECK(sm.generation != first && sm.generation != other.generation);
    CHECK(mm.generation == first);
    uint32_t read = nc_shadow_lookup_volume_n(&sm, &mm, 64, px, py, pz, BIAS, got);
    int bad = 0, live = 0;
    for (int i = 0; i < 64; i += 8) {
        nc_shadow_lookup_volume8(&sm, px + i, py + i, pz + i, BIAS, want);
        bad += memcmp(want, got + i, sizeof(want)) != 0;
    }
    for (int i = 0; i < 64; i++)
        live += got[i] != 1.0f; /* inside the map and shadowed at least in part */
    CHECK(bad == 0);
    CHECK((int)read >= live && live > 0);
    mm.data[0] = mark;
    CHECK(nc_shadow_minmax_update(ctx, &sm, &mm, 2) == NACRE_OK);
    CHECK(mm.generation == sm.generation && mm.data[0] != mark);
    vol_stats t = {0};
    vol_compare(&sm, &mm, &vs, BIAS, 2000, 4242u, &t);
    CHECK(t.bad == 0 && t.read < 8 * t.groups / 2);
    /* A map freed and made again at the same address gets a new generation */
    nc_shadow_free(ctx, &sm);
    CHECK(nc_shadow_render(r, ctx, &ld, vs.lo, vs.hi, 512, m, 2, &sm) == NACRE_OK);
    CHECK(sm.generation != mm.generation);
    nc_shadow_minmax_free(ctx, &mm);
    nc_shadow_free(ctx, &sm);
    finish(ctx, r, &other, g, 2);
}

int main(void)
{
    test_directional();
    test_spot();
    test_point();
    test_acne();
    test_volume_table();
    test_volume_table_update();
    return TEST_MAIN_END();
}
