/*
 * test_raster.c: the rasterizer and the G-buffer resolve against independent references.
 *
 * Coverage is checked pixel by pixel against a brute-force evaluation of the top-left rule in
 * double precision; shared edges and vertices against an overdraw count; clipping, huge
 * triangles and perspective-correct attributes against exact ray intersections; determinism by
 * comparing thread counts and the vector paths against the scalar ones.
 */
#include "raster/raster.h"
#include "test_util.h"

#include <stdlib.h>
#include <string.h>

/* ---- helpers ---- */

#define PI_D 3.14159265358979323846

static uint64_t rng_state = 0x9e3779b97f4a7c15ull;
static double rnd(void) /* uniform [0, 1) */
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return (double)(rng_state >> 11) * (1.0 / 9007199254740992.0);
}
static double rnd_range(double a, double b) { return a + (b - a) * rnd(); }

typedef struct rig {
    nacre_context *ctx;
    nc_rasterizer *r;
    nc_vis_buffer vb;
} rig;

static rig rig_make(int threads, int w, int h)
{
    rig g;
    memset(&g, 0, sizeof(g));
    nacre_context_desc cd = {0};
    cd.threads = threads;
    CHECK(nacre_context_create(&cd, &g.ctx) == NACRE_OK);
    CHECK(nc_rasterizer_create(g.ctx, &g.r) == NACRE_OK);
    CHECK(nc_vis_buffer_resize(g.ctx, &g.vb, w, h) == NACRE_OK);
    return g;
}

static void rig_free(rig *g)
{
    nc_vis_buffer_free(g->ctx, &g->vb);
    nc_rasterizer_destroy(g->r);
    nacre_context_destroy(g->ctx);
}

/* Identity view and projection: world x, y are NDC, world z is depth. */
static nc_raster_view screen_view(int w, int h)
{
    nc_raster_view v;
    memset(&v, 0, sizeof(v));
    v.view = nc_mat4_identity();
    v.proj = nc_mat4_identity();
    v.width = w;
    v.height = h;
    v.orthographic = true;
    return v;
}

/* Screen position (pixels, y down) -> world point of screen_view; exact for multiples of 1/256
 * when the size is a power of two. */
static void screen_to_world(int w, int h, double sx, double sy, double z, float out[3])
{
    out[0] = (float)(sx * 2.0 / w - 1.0);
    out[1] = (float)(1.0 - sy * 2.0 / h);
    out[2] = (float)z;
}

static double q256(double v) { return floor(v * 256.0 + 0.5) / 256.0; }

/* Top-left rule, independently: inside strictly, or on an edge whose inward normal points
 * right (a left edge) or straight down on screen (a top edge). Screen coordinates, y down. */
static bool ref_covered(const double x[3], const double y[3], double px, double py)
{
    double area = (x[1] - x[0]) * (y[2] - y[0]) - (x[2] - x[0]) * (y[1] - y[0]);
    if (area == 0.0)
        return false;
    double s = area > 0.0 ? 1.0 : -1.0;
    for (int k = 0; k < 3; k++) {
        int k2 = (k + 1) % 3;
        double ex = x[k2] - x[k], ey = y[k2] - y[k];
        double d = s * (ex * (py - y[k]) - ey * (px - x[k]));
        double nx = -s * ey, ny = s * ex; /* inward normal */
        if (d > 0.0)
            continue;
        if (d == 0.0 && (nx > 0.0 || (nx == 0.0 && ny > 0.0)))
            continue;
        return false;
    }
    return true;
}

static size_t count_covered(const nc_vis_buffer *vb)
{
    size_t n = 0;
    for (size_t i = 0; i < (size_t)vb->width * (size_t)vb->height; i++)
        n += vb->object[i] != NC_NO_OBJECT;
    return n;
}

/* ---- coverage of single triangles ---- */

static void test_single_triangles(void)
{
    const int W = 64, H = 64;
    rig g = rig_make(1, W, H);
    nc_raster_view view = screen_view(W, H);
    int exact_ok = 0, bound_ok = 0, n = 600;
    double sum_count = 0.0, sum_area = 0.0;
    for (int t = 0; t < n; t++) {
        double x[3], y[3];
        for (int k = 0; k < 3; k++) {
            if (t % 3 == 0) { /* on pixel centres: many centres exactly on edges */
                x[k] = floor(rnd_range(-4, 68)) + 0.5;
                y[k] = floor(rnd_range(-4, 68)) + 0.5;
            } else if (t % 3 == 1) { /* small, sub-pixel */
                x[k] = q256(rnd_range(20, 26));
                y[k] = q256(rnd_range(20, 26));
            } else {
                x[k] = q256(rnd_range(-8, 72));
                y[k] = q256(rnd_range(-8, 72));
            }
        }
        if (t == 7) { /* degenerate */
            x[2] = x[1];
            y[2] = y[1];
        }
        float pos[9];
        for (int k = 0; k < 3; k++)
            screen_to_world(W, H, x[k], y[k], 0.5, pos + 3 * k);
        uint32_t idx[3] = {0, 1, 2};
        nc_raster_mesh m = {pos, idx, 3, 1, 0, true};
        CHECK(nc_raster_visibility(g.r, &view, &m, 1, &g.vb, NULL) == NACRE_OK);
        bool same = true;
        int count = 0;
        for (int j = 0; j < H; j++)
            for (int i = 0; i < W; i++) {
                bool want = ref_covered(x, y, i + 0.5, j + 0.5);
                bool got = g.vb.object[j * W + i] == 0;
                same &= want == got;
                count += got;
            }
        exact_ok += same;
        /* Lattice points of a convex region (Nosarzewska): A - P/2 < N <= A + P/2 + 1, for
         * the part of the triangle inside the viewport; use triangles fully inside. */
        bool inside = true;
        for (int k = 0; k < 3; k++)
            inside &= x[k] >= 0 && x[k] <= W && y[k] >= 0 && y[k] <= H;
        double area = 0.5 * fabs((x[1] - x[0]) * (y[2] - y[0]) - (x[2] - x[0]) * (y[1] - y[0]));
        double per = 0.0;
        for (int k = 0; k < 3; k++)
            per += hypot(x[(k + 1) % 3] - x[k], y[(k + 1) % 3] - y[k]);
        if (inside) {
            bound_ok += count > area - per / 2 - 1e-9 && count <= area + per / 2 + 1 + 1e-9;
            sum_count += count;
            sum_area += area;
        } else {
            bound_ok++;
        }
    }
    CHECK(exact_ok == n);
    CHECK(bound_ok == n);
    CHECK(sum_area > 1000.0);
    CHECK_NEAR(sum_count / sum_area, 1.0, 0.01);
    rig_free(&g);
}

/* ---- shared edges and vertices: a jittered grid and a fan ---- */

static void test_shared_edges(void)
{
    const int W = 64, H = 64, N = 9; /* N x N vertices */
    rig g = rig_make(2, W, H);
    nc_raster_view view = screen_view(W, H);
    double x0 = 2.3, x1 = 61.7, y0 = 3.1, y1 = 60.6;
    double gx[N][N], gy[N][N];
    for (int j = 0; j < N; j++)
        for (int i = 0; i < N; i++) {
            double x = x0 + (x1 - x0) * i / (N - 1), y = y0 + (y1 - y0) * j / (N - 1);
            bool bx = i == 0 || i == N - 1, by = j == 0 || j == N - 1;
            /* Up to 2 px per vertex with the snap below: no triangle folds over. */
            if (!bx)
                x += rnd_range(-1.5, 1.5);
            if (!by)
                y += rnd_range(-1.5, 1.5);
            if (!bx && !by && (i + j) % 2 == 0) { /* vertex exactly on a pixel centre */
                x = floor(x) + 0.5;
                y = floor(y) + 0.5;
            }
            gx[j][i] = q256(x);
            gy[j][i] = q256(y);
        }
    float pos[N * N * 3];
    for (int j = 0; j < N; j++)
        for (int i = 0; i < N; i++)
            screen_to_world(W, H, gx[j][i], gy[j][i], 0.5, pos + 3 * (j * N + i));
    uint32_t idx[(N - 1) * (N - 1) * 6];
    int nt = 0;
    for (int j = 0; j + 1 < N; j++)
        for (int i = 0; i + 1 < N; i++) {
            uint32_t a = (uint32_t)(j * N + i), b = a + 1, c = a + (uint32_t)N, d = c + 1;
            /* Counter-clockwise in NDC (y up): screen rows grow downwards. */
            uint32_t t[6];
            if (rnd() < 0.5) {
                uint32_t q[6] = {a, c, d, a, d, b};
                memcpy(t, q, sizeof(q));
            } else {
                uint32_t q[6] = {a, c, b, b, c, d};
                memcpy(t, q, sizeof(q));
            }
            memcpy(idx + 3 * nt, t, sizeof(t));
            nt += 2;
        }
    /* Each triangle alone, counting draws per pixel. */
    int hits[64 * 64] = {0};
    for (int t = 0; t < nt; t++) {
        nc_raster_mesh m = {pos, idx + 3 * t, N * N, 1, 0, false};
        CHECK(nc_raster_visibility(g.r, &view, &m, 1, &g.vb, NULL) == NACRE_OK);
        for (int p = 0; p < W * H; p++)
            hits[p] += g.vb.object[p] == 0;
    }
    int once = 0, inside = 0, wrong = 0;
    for (int j = 0; j < H; j++)
        for (int i = 0; i < W; i++) {
            bool in = i + 0.5 > x0 && i + 0.5 < x1 && j + 0.5 > y0 && j + 0.5 < y1;
            inside += in;
            once += in && hits[j * W + i] == 1;
            wrong += in ? hits[j * W + i] != 1 : hits[j * W + i] != 0;
        }
    CHECK(wrong == 0);
    CHECK(once == inside);
    CHECK(inside == 60 * 58);
    /* The whole mesh at once covers the same pixels, front faces only. */
    nc_raster_mesh all = {pos, idx, N * N, (uint32_t)nt, 0, false};
    nc_raster_counts counts;
    CHECK(nc_raster_visibility(g.r, &view, &all, 1, &g.vb, &counts) == NACRE_OK);
    CHECK(count_covered(&g.vb) == (size_t)inside);
    CHECK(counts.triangles == (uint64_t)nt);
    CHECK(counts.triangles_drawn == (uint64_t)nt);
    /* Reversed winding: all back faces, culled. */
    for (int t = 0; t < nt; t++) {
        uint32_t s = idx[3 * t + 1];
        idx[3 * t + 1] = idx[3 * t + 2];
        idx[3 * t + 2] = s;
    }
    CHECK(nc_raster_visibility(g.r, &view, &all, 1, &g.vb, &counts) == NACRE_OK);
    CHECK(count_covered(&g.vb) == 0);
    CHECK(counts.triangles_drawn == 0);

    /* A fine grid (cells of 1.5 px, vertices on multiples of 1/4 px, many pixel centres on
     * edges and vertices): triangles this small go through the vectorised rejection of the
     * setup pass when drawn as one mesh, and through the scalar path when drawn one by one. */
    {
        const int M = 27; /* vertices per side */
        float *fp = malloc(sizeof(float) * 3 * M * M);
        uint32_t *fi = malloc(sizeof(uint32_t) * 6 * (M - 1) * (M - 1));
        for (int j = 0; j < M; j++)
            for (int i = 0; i < M; i++) {
                double x = 4.5 + 1.5 * i, y = 4.5 + 1.5 * j;
                if (i > 0 && i < M - 1)
                    x += 0.25 * (double)((int)(rnd() * 3) - 1);
                if (j > 0 && j < M - 1)
                    y += 0.25 * (double)((int)(rnd() * 3) - 1);
                screen_to_world(W, H, x, y, 0.5, fp + 3 * (j * M + i));
            }
        int fn = 0;
        for (int j = 0; j + 1 < M; j++)
            for (int i = 0; i + 1 < M; i++) {
                uint32_t a = (uint32_t)(j * M + i), b = a + 1, c = a + (uint32_t)M, d = c + 1;
                uint32_t q[6] = {a, c, d, a, d, b};
                memcpy(fi + 3 * fn, q, sizeof(q));
                fn += 2;
            }
        nc_raster_mesh fm = {fp, fi, (uint32_t)(M * M), (uint32_t)fn, 0, false};
        CHECK(nc_raster_visibility(g.r, &view, &fm, 1, &g.vb, NULL) == NACRE_OK);
        int fine_bad = 0;
        for (int j = 0; j < H; j++)
            for (int i = 0; i < W; i++) {
                /* Left and top edges of the square own their centres, right and bottom not. */
                bool want = i >= 4 && i < 43 && j >= 4 && j < 43;
                fine_bad += want != (g.vb.object[j * W + i] == 0);
            }
        CHECK(fine_bad == 0);
        int single_hits[64 * 64] = {0};
        for (int t = 0; t < fn; t++) {
            nc_raster_mesh m1 = {fp, fi + 3 * t, (uint32_t)(M * M), 1, 0, false};
            CHECK(nc_raster_visibility(g.r, &view, &m1, 1, &g.vb, NULL) == NACRE_OK);
            for (int p = 0; p < W * H; p++)
                single_hits[p] += g.vb.object[p] == 0;
        }
        int single_bad = 0;
        for (int j = 0; j < H; j++)
            for (int i = 0; i < W; i++)
                single_bad += single_hits[j * W + i] != (i >= 4 && i < 43 && j >= 4 && j < 43);
        CHECK(single_bad == 0);
        free(fp);
        free(fi);
    }

    /* A fan of 16 triangles around a pixel centre, outer vertices on pixel centres too. */
    const int F = 16;
    float fp[(16 + 1) * 3];
    screen_to_world(W, H, 32.5, 32.5, 0.5, fp);
    static const int ring[16][2] = {{12, 0},  {11, 5},  {9, 9},   {5, 11},   {0, 12},  {-5, 11},
                                    {-9, 9},  {-11, 5}, {-12, 0}, {-11, -5}, {-9, -9}, {-5, -11},
                                    {0, -12}, {5, -11}, {9, -9},  {11, -5}};
    for (int k = 0; k < F; k++)
        screen_to_world(W, H, 32.5 + ring[k][0], 32.5 + ring[k][1], 0.5, fp + 3 * (k + 1));
    int fan_hits[64 * 64] = {0};
    for (int k = 0; k < F; k++) {
        uint32_t tri[3] = {0, (uint32_t)(k + 1), (uint32_t)((k + 1) % F + 1)};
        nc_raster_mesh m = {fp, tri, F + 1, 1, 0, true};
        CHECK(nc_raster_visibility(g.r, &view, &m, 1, &g.vb, NULL) == NACRE_OK);
        for (int p = 0; p < W * H; p++)
            fan_hits[p] += g.vb.object[p] == 0;
    }
    int over = 0, holes = 0;
    for (int j = 0; j < H; j++)
        for (int i = 0; i < W; i++) {
            over += fan_hits[j * W + i] > 1;
            double dx = i - 32.0, dy = j - 32.0;
            holes += dx * dx + dy * dy < 9.0 * 9.0 && fan_hits[j * W + i] != 1;
        }
    CHECK(over == 0);
    CHECK(holes == 0);
    CHECK(fan_hits[32 * W + 32] == 1); /* the shared centre vertex itself */
    rig_free(&g);
}

/* ---- depth order ---- */

static void test_depth_order(void)
{
    const int W = 32, H = 32;
    rig g = rig_make(2, W, H);
    nc_raster_view view = screen_view(W, H);
    float pos[18];
    double tri_a[3][2] = {{2, 2}, {2, 30}, {30, 16}}, tri_b[3][2] = {{30, 2}, {4, 16}, {30, 30}};
    for (int pass = 0; pass < 2; pass++) {
        double za = pass == 0 ? 0.3 : 0.5, zb = pass == 0 ? 0.6 : 0.5;
        for (int order = 0; order < 2; order++) {
            double(*first)[2] = order == 0 ? tri_a : tri_b,
            (*second)[2] = order == 0 ? tri_b : tri_a;
            double zf = order == 0 ? za : zb, zs = order == 0 ? zb : za;
            for (int k = 0; k < 3; k++) {
                screen_to_world(W, H, first[k][0], first[k][1], zf, pos + 3 * k);
                screen_to_world(W, H, second[k][0], second[k][1], zs, pos + 9 + 3 * k);
            }
            uint32_t idx[6] = {0, 1, 2, 3, 4, 5};
            nc_raster_mesh m = {pos, idx, 6, 2, 7, true};
            CHECK(nc_raster_visibility(g.r, &view, &m, 1, &g.vb, NULL) == NACRE_OK);
            size_t p = 16 * W + 20; /* inside both */
            CHECK(g.vb.object[p] == 7);
            uint32_t want =
                pass == 0 ? (order == 0 ? 0u : 1u) : 0u; /* nearer, or earlier on ties */
            CHECK(g.vb.triangle[p] == want);
            CHECK_NEAR(g.vb.depth[p], pass == 0 ? 0.3 : 0.5, 1e-6);
            /* The same across two meshes: ties keep the earlier draw. */
            nc_raster_mesh two[2] = {{pos, idx, 6, 1, 3, true}, {pos, idx + 3, 6, 1, 4, true}};
            CHECK(nc_raster_visibility(g.r, &view, two, 2, &g.vb, NULL) == NACRE_OK);
            CHECK(g.vb.object[p] == (want == 0 ? 3u : 4u));
            CHECK(g.vb.triangle[p] == 0);
        }
    }
    rig_free(&g);
}

/* ---- perspective camera helpers ---- */

typedef struct cam {
    double eye[3], fwd[3], right[3], up[3];
    double tan_half, aspect;
    int w, h;
    nc_raster_view view;
} cam;

static void norm3(double v[3])
{
    double l = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    v[0] /= l;
    v[1] /= l;
    v[2] /= l;
}
static void cross3(const double a[3], const double b[3], double r[3])
{
    r[0] = a[1] * b[2] - a[2] * b[1];
    r[1] = a[2] * b[0] - a[0] * b[2];
    r[2] = a[0] * b[1] - a[1] * b[0];
}
static double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static cam cam_make(const double eye[3], const double target[3], double fov_deg, int w, int h,
                    double znear, double zfar)
{
    cam c;
    memset(&c, 0, sizeof(c));
    for (int i = 0; i < 3; i++) {
        c.eye[i] = eye[i];
        c.fwd[i] = target[i] - eye[i];
    }
    norm3(c.fwd);
    double up0[3] = {0, 1, 0};
    cross3(c.fwd, up0, c.right);
    norm3(c.right);
    cross3(c.right, c.fwd, c.up);
    c.tan_half = tan(0.5 * fov_deg * PI_D / 180.0);
    c.aspect = (double)w / h;
    c.w = w;
    c.h = h;
    c.view.view = nc_mat4_look_at(nc_v3((float)eye[0], (float)eye[1], (float)eye[2]),
                                  nc_v3((float)target[0], (float)target[1], (float)target[2]),
                                  nc_v3(0, 1, 0));
    c.view.proj = nc_mat4_perspective((float)(fov_deg * PI_D / 180.0), (float)c.aspect,
                                      (float)znear, (float)zfar);
    c.view.width = w;
    c.view.height = h;
    return c;
}

/* Ray direction through pixel centre (i, j), built from the camera frame (not the matrices). */
static void cam_ray(const cam *c, int i, int j, double d[3])
{
    double nx = ((i + 0.5) / c->w * 2.0 - 1.0) * c->tan_half * c->aspect;
    double ny = (1.0 - (j + 0.5) / c->h * 2.0) * c->tan_half;
    for (int k = 0; k < 3; k++)
        d[k] = c->fwd[k] + nx * c->right[k] + ny * c->up[k];
}

/* Ray / triangle: t and barycentrics (b1, b2), or false if parallel. */
static bool ray_tri(const double o[3], const double d[3], const double p0[3], const double p1[3],
                    const double p2[3], double *t, double *b1, double *b2)
{
    double e1[3], e2[3], s[3], pv[3], qv[3];
    for (int k = 0; k < 3; k++) {
        e1[k] = p1[k] - p0[k];
        e2[k] = p2[k] - p0[k];
        s[k] = o[k] - p0[k];
    }
    cross3(d, e2, pv);
    double det = dot3(e1, pv);
    if (det == 0.0)
        return false;
    cross3(s, e1, qv);
    *b1 = dot3(s, pv) / det;
    *b2 = dot3(d, qv) / det;
    *t = dot3(e2, qv) / det;
    return true;
}

/* ---- perspective-correct resolve on a slanted textured quad ---- */

static void test_perspective_resolve(void)
{
    const int W = 160, H = 120;
    rig g = rig_make(2, W, H);
    double eye[3] = {0.3, 1.2, 3.0}, target[3] = {0, 0, 0};
    cam c = cam_make(eye, target, 50.0, W, H, 0.1, 100.0);
    /* Parallelogram O + u Eu + v Ev, strongly slanted away from the camera. */
    double O[3] = {-1.2, -0.6, 1.0}, Eu[3] = {2.4, 0.2, -0.3}, Ev[3] = {0.3, 0.9, -4.0};
    float pos[12], nrm[12], uvs[8];
    double N[3];
    cross3(Eu, Ev, N);
    norm3(N);
    for (int k = 0; k < 4; k++) {
        double u = (k == 1 || k == 2) ? 1 : 0, v = k >= 2 ? 1 : 0;
        for (int a = 0; a < 3; a++) {
            pos[3 * k + a] = (float)(O[a] + u * Eu[a] + v * Ev[a]);
            nrm[3 * k + a] = (float)N[a];
        }
        uvs[2 * k] = (float)u;
        uvs[2 * k + 1] = (float)v;
    }
    uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    nc_raster_mesh m = {pos, idx, 4, 2, 0, false};
    CHECK(nc_raster_visibility(g.r, &c.view, &m, 1, &g.vb, NULL) == NACRE_OK);
    nc_gbuffer gb;
    memset(&gb, 0, sizeof(gb));
    CHECK(nc_gbuffer_resize(g.ctx, &gb, W, H) == NACRE_OK);
    nc_gbuffer_source src = {pos, nrm, uvs, idx, 5};
    CHECK(nc_gbuffer_resolve(g.ctx, &c.view, &g.vb, &src, 1, &gb) == NACRE_OK);
    if (N[0] * (eye[0] - O[0]) + N[1] * (eye[1] - O[1]) + N[2] * (eye[2] - O[2]) < 0)
        for (int a = 0; a < 3; a++)
            N[a] = -N[a]; /* (the quad is wound to face the camera; keep N on its side) */
    int covered = 0, pos_bad = 0, uv_bad = 0, attr_bad = 0, cov_bad = 0, empty_bad = 0;
    double max_rel = 0.0;
    for (int j = 0; j < H; j++)
        for (int i = 0; i < W; i++) {
            size_t p = (size_t)j * W + i;
            double d[3];
            cam_ray(&c, i, j, d);
            double t = (dot3(O, N) - dot3(eye, N)) / dot3(d, N), hit[3], rel[3];
            for (int a = 0; a < 3; a++) {
                hit[a] = eye[a] + t * d[a];
                rel[a] = hit[a] - O[a];
            }
            /* rel = u Eu + v Ev: least squares via the Gram matrix. */
            double a11 = dot3(Eu, Eu), a12 = dot3(Eu, Ev), a22 = dot3(Ev, Ev);
            double r1 = dot3(rel, Eu), r2 = dot3(rel, Ev), det = a11 * a22 - a12 * a12;
            double u = (r1 * a22 - r2 * a12) / det, v = (a11 * r2 - a12 * r1) / det;
            bool in = u > 0.002 && u < 0.998 && v > 0.002 && v < 0.998;
            bool out = u < -0.002 || u > 1.002 || v < -0.002 || v > 1.002;
            bool got = g.vb.object[p] == 0;
            if ((in && !got) || (out && got))
                cov_bad++;
            if (!got) {
                empty_bad += gb.object[p] != NC_NO_OBJECT || !isinf(gb.view_depth[p]) ||
                             gb.position[3 * p] != 0.0f || gb.normal[3 * p + 1] != 0.0f;
                continue;
            }
            covered++;
            double dist =
                sqrt((hit[0] - eye[0]) * (hit[0] - eye[0]) + (hit[1] - eye[1]) * (hit[1] - eye[1]) +
                     (hit[2] - eye[2]) * (hit[2] - eye[2]));
            double err = 0.0;
            for (int a = 0; a < 3; a++)
                err = fmax(err, fabs(gb.position[3 * p + a] - hit[a]));
            max_rel = fmax(max_rel, err / dist);
            pos_bad += err > 1e-4 * dist;
            uv_bad += fabs(gb.uv[2 * p] - u) > 1e-4 || fabs(gb.uv[2 * p + 1] - v) > 1e-4;
            double depth = 0.0;
            for (int a = 0; a < 3; a++)
                depth += (hit[a] - eye[a]) * c.fwd[a];
            attr_bad += fabs(gb.view_depth[p] - depth) > 1e-4 * depth;
            for (int a = 0; a < 3; a++) {
                attr_bad += fabs(gb.normal[3 * p + a] - N[a]) > 1e-5;
                attr_bad += fabs(gb.geo_normal[3 * p + a] - N[a]) > 1e-5;
            }
            attr_bad +=
                gb.material[p] != 5 || gb.object[p] != 0 || gb.triangle[p] != g.vb.triangle[p];
        }
    CHECK(covered > 2000);
    CHECK(cov_bad == 0);
    CHECK(pos_bad == 0);
    CHECK(max_rel < 1e-4);
    CHECK(uv_bad == 0);
    CHECK(attr_bad == 0);
    CHECK(empty_bad == 0);
    /* Frames with less coverage leave no stale pixels behind (the resolve skips rewriting
     * pixels it knows to be empty). */
    for (int frame = 0; frame < 2; frame++) {
        nc_raster_mesh half = {pos, idx, 4, frame == 0 ? 1u : 0u, 0, false};
        CHECK(nc_raster_visibility(g.r, &c.view, &half, 1, &g.vb, NULL) == NACRE_OK);
        CHECK(nc_gbuffer_resolve(g.ctx, &c.view, &g.vb, &src, 1, &gb) == NACRE_OK);
        int stale = 0, drawn = 0;
        for (size_t p = 0; p < (size_t)W * H; p++) {
            if (g.vb.object[p] == 0) {
                drawn++;
                stale += gb.object[p] != 0;
                continue;
            }
            stale +=
                gb.object[p] != NC_NO_OBJECT || !isinf(gb.view_depth[p]) || gb.material[p] != 0;
            for (int a = 0; a < 3; a++)
                stale += gb.position[3 * p + a] != 0.0f || gb.normal[3 * p + a] != 0.0f ||
                         gb.geo_normal[3 * p + a] != 0.0f;
            stale += gb.uv[2 * p] != 0.0f || gb.uv[2 * p + 1] != 0.0f;
        }
        CHECK(stale == 0);
        CHECK(frame == 0 ? drawn > 500 : drawn == 0);
    }
    nc_gbuffer_free(g.ctx, &gb);
    rig_free(&g);
}

/* Compare coverage and depth of one triangle against exact ray casting; returns mismatches. */
static int compare_with_rays(const rig *g, const cam *c, const double tri[3][3], double znear,
                             double zfar, int *covered, int *depth_bad)
{
    int bad = 0;
    *covered = 0;
    *depth_bad = 0;
    const nc_mat4 *P = &c->view.proj;
    for (int j = 0; j < c->h; j++)
        for (int i = 0; i < c->w; i++) {
            double d[3], t, b1, b2;
            cam_ray(c, i, j, d);
            bool want = false;
            double depth = 0.0;
            if (ray_tri(c->eye, d, tri[0], tri[1], tri[2], &t, &b1, &b2) && t > 0 && b1 >= 0 &&
                b2 >= 0 && b1 + b2 <= 1) {
                depth = t * dot3(d, c->fwd); /* d has unit forward component */
                want = depth >= znear && depth <= zfar;
            }
            size_t p = (size_t)j * c->w + i;
            bool got = g->vb.object[p] != NC_NO_OBJECT;
            bad += want != got;
            *covered += got;
            if (got && want) {
                double zndc = (P->m[2][2] * -depth + P->m[2][3]) / depth;
                *depth_bad += fabs(g->vb.depth[p] - zndc) > 1e-4;
            }
        }
    return bad;
}

/* ---- near-plane clipping and huge triangles ---- */

static void test_clipping(void)
{
    const int W = 200, H = 150;
    rig g = rig_make(2, W, H);
    double eye[3] = {0, 0, 0}, target[3] = {0, 0, -1};
    cam c = cam_make(eye, target, 60.0, W, H, 0.5, 100.0);
    /* One vertex behind the camera, one beside it: crosses the near plane and the frustum. */
    double tri[3][3] = {{-2.0, -1.0, -4.0}, {2.5, -0.8, -6.0}, {0.4, -0.9, 3.0}};
    float pos[9];
    for (int k = 0; k < 9; k++)
        pos[k] = (float)tri[k / 3][k % 3];
    uint32_t idx[3] = {0, 1, 2};
    nc_raster_mesh m = {pos, idx, 3, 1, 0, true};
    CHECK(nc_raster_visibility(g.r, &c.view, &m, 1, &g.vb, NULL) == NACRE_OK);
    int covered, depth_bad;
    int bad = compare_with_rays(&g, &c, tri, 0.5, 100.0, &covered, &depth_bad);
    CHECK(covered > 3000);
    CHECK(bad <= 2); /* only centres within float noise of an edge may differ */
    CHECK(depth_bad == 0);

    /* Crossing the near plane in the middle of the view, where the cut is visible. */
    double tri2[3][3] = {{-1.0, -0.3, -3.0}, {1.0, -0.2, -3.0}, {0.1, 0.3, 2.0}};
    for (int k = 0; k < 9; k++)
        pos[k] = (float)tri2[k / 3][k % 3];
    CHECK(nc_raster_visibility(g.r, &c.view, &m, 1, &g.vb, NULL) == NACRE_OK);
    bad = compare_with_rays(&g, &c, tri2, 0.5, 100.0, &covered, &depth_bad);
    CHECK(covered > 1000);
    CHECK(bad <= 2);
    CHECK(depth_bad == 0);
    int near_cut = 0; /* rays that hit the triangle closer than the near plane */
    for (int j = 0; j < H; j++)
        for (int i = 0; i < W; i++) {
            double d[3], t, b1, b2;
            cam_ray(&c, i, j, d);
            near_cut += ray_tri(c.eye, d, tri2[0], tri2[1], tri2[2], &t, &b1, &b2) && t > 0 &&
                        t < 0.5 && b1 >= 0 && b2 >= 0 && b1 + b2 <= 1;
        }
    CHECK(near_cut > 100);

    /* Entirely behind the camera: nothing. */
    float behind[9] = {-1, -1, 2, 1, -1, 2, 0, 1, 3};
    nc_raster_mesh mb = {behind, idx, 3, 1, 0, true};
    nc_raster_counts counts;
    CHECK(nc_raster_visibility(g.r, &c.view, &mb, 1, &g.vb, &counts) == NACRE_OK);
    CHECK(count_covered(&g.vb) == 0);
    CHECK(counts.triangles == 1 && counts.triangles_drawn == 0);

    /* A 10 km ground plane seen from eye height, horizon near the middle of the image. */
    double eye2[3] = {0.0, 1.7, 0.0}, target2[3] = {0.0, 1.2, -10.0};
    cam c2 = cam_make(eye2, target2, 70.0, W, H, 0.05, 20000.0);
    double quad[4][3] = {{-5000, 0, -5000}, {-5000, 0, 5000}, {5000, 0, 5000}, {5000, 0, -5000}};
    float qp[12];
    for (int k = 0; k < 12; k++)
        qp[k] = (float)quad[k / 3][k % 3];
    uint32_t qi[6] = {0, 1, 2, 0, 2, 3};
    nc_raster_mesh mq = {qp, qi, 4, 2, 0, false};
    CHECK(nc_raster_visibility(g.r, &c2.view, &mq, 1, &g.vb, NULL) == NACRE_OK);
    int bad2 = 0, cov2 = 0, db2 = 0;
    const nc_mat4 *P = &c2.view.proj;
    for (int j = 0; j < H; j++)
        for (int i = 0; i < W; i++) {
            double d[3];
            cam_ray(&c2, i, j, d);
            bool want = false;
            double depth = 0.0;
            if (d[1] < 0) {
                double t = -eye2[1] / d[1];
                double hx = eye2[0] + t * d[0], hz = eye2[2] + t * d[2];
                depth = t * dot3(d, c2.fwd);
                want = fabs(hx) <= 5000 && fabs(hz) <= 5000 && depth <= 20000.0;
            }
            size_t p = (size_t)j * W + i;
            bool got = g.vb.object[p] == 0;
            bad2 += want != got;
            cov2 += got;
            if (got && want && depth < 1000.0) {
                double zndc = (P->m[2][2] * -depth + P->m[2][3]) / depth;
                db2 += fabs(g.vb.depth[p] - zndc) > 1e-5;
            }
        }
    CHECK(cov2 > W * H / 3);
    CHECK(bad2 <= W / 20); /* the far edge 5 km away lies on the horizon row */
    CHECK(db2 == 0);
    rig_free(&g);
}

/* ---- back faces: culled, or drawn with flipped normals ---- */

static void test_back_faces(void)
{
    const int W = 64, H = 48;
    rig g = rig_make(1, W, H);
    double eye[3] = {0, 0, 3}, target[3] = {0, 0, 0};
    cam c = cam_make(eye, target, 45.0, W, H, 0.1, 10.0);
    /* Clockwise seen from the camera: its normal points away (-z). */
    float pos[9] = {-1, -1, 0, 0, 1, 0, 1, -1, 0};
    float nrm[9] = {0, 0, -1, 0, 0, -1, 0, 0, -1};
    float uvs[6] = {0, 0, 0.5f, 1, 1, 0};
    uint32_t idx[3] = {0, 1, 2};
    nc_raster_mesh m = {pos, idx, 3, 1, 0, false};
    CHECK(nc_raster_visibility(g.r, &c.view, &m, 1, &g.vb, NULL) == NACRE_OK);
    CHECK(count_covered(&g.vb) == 0);
    m.double_sided = true;
    CHECK(nc_raster_visibility(g.r, &c.view, &m, 1, &g.vb, NULL) == NACRE_OK);
    size_t n = count_covered(&g.vb);
    CHECK(n > 300);
    nc_gbuffer gb;
    memset(&gb, 0, sizeof(gb));
    CHECK(nc_gbuffer_resize(g.ctx, &gb, W, H) == NACRE_OK);
    nc_gbuffer_source src = {pos, nrm, uvs, idx, 0};
    CHECK(nc_gbuffer_resolve(g.ctx, &c.view, &g.vb, &src, 1, &gb) == NACRE_OK);
    int bad = 0;
    for (size_t p = 0; p < (size_t)W * H; p++) {
        if (gb.object[p] != 0)
            continue;
        bad += fabs(gb.normal[3 * p + 2] - 1.0f) > 1e-6 ||
               fabs(gb.geo_normal[3 * p + 2] - 1.0f) > 1e-6;
    }
    CHECK(bad == 0);
    /* The same triangle wound to face the camera keeps its normals. */
    uint32_t idx2[3] = {0, 2, 1};
    float nrm2[9] = {0, 0, 1, 0, 0, 1, 0, 0, 1};
    nc_raster_mesh m2 = {pos, idx2, 3, 1, 0, false};
    CHECK(nc_raster_visibility(g.r, &c.view, &m2, 1, &g.vb, NULL) == NACRE_OK);
    CHECK(count_covered(&g.vb) == n);
    nc_gbuffer_source src2 = {pos, nrm2, uvs, idx2, 0};
    CHECK(nc_gbuffer_resolve(g.ctx, &c.view, &g.vb, &src2, 1, &gb) == NACRE_OK);
    bad = 0;
    for (size_t p = 0; p < (size_t)W * H; p++) {
        if (gb.object[p] != 0)
            continue;
        bad += fabs(gb.normal[3 * p + 2] - 1.0f) > 1e-6 ||
               fabs(gb.geo_normal[3 * p + 2] - 1.0f) > 1e-6;
    }
    CHECK(bad == 0);
    nc_gbuffer_free(g.ctx, &gb);
    rig_free(&g);
}

/* ---- determinism: thread counts, and vector paths against scalar ones ---- */

static void test_determinism(void)
{
    const int W = 333, H = 211, NT = 4000;
    double eye[3] = {0.5, 0.8, 4.0}, target[3] = {0, 0, 0};
    float *pos = malloc(sizeof(float) * 9 * NT);
    uint32_t *idx = malloc(sizeof(uint32_t) * 3 * NT);
    for (int t = 0; t < NT; t++) {
        double cx = rnd_range(-3, 3), cy = rnd_range(-2, 2), cz = rnd_range(-6, 4.5);
        double s = t % 10 == 0 ? 3.0 : rnd_range(0.005, 0.3);
        for (int k = 0; k < 3; k++) {
            pos[9 * t + 3 * k] = (float)(cx + rnd_range(-s, s));
            pos[9 * t + 3 * k + 1] = (float)(cy + rnd_range(-s, s));
            pos[9 * t + 3 * k + 2] = (float)(cz + rnd_range(-s, s));
            idx[3 * t + k] = (uint32_t)(3 * t + k);
        }
        if (t % 7 == 3) /* coplanar duplicate of the previous triangle: a depth tie */
            memcpy(pos + 9 * t, pos + 9 * (t - 1), 9 * sizeof(float));
    }
    cam c = cam_make(eye, target, 60.0, W, H, 0.3, 50.0);
    /* Two meshes, the second double-sided. */
    nc_raster_mesh ms[2] = {{pos, idx, 3 * NT / 2, NT / 2, 0, false},
                            {pos + 9 * (NT / 2), idx, 3 * NT / 2, NT / 2, 1, true}};
    rig g1 = rig_make(1, W, H), g2 = rig_make(2, W, H), g3 = rig_make(3, W, H);
    nc_raster_counts k1, k2, k3;
    CHECK(nc_raster_visibility(g1.r, &c.view, ms, 2, &g1.vb, &k1) == NACRE_OK);
    CHECK(nc_raster_visibility(g2.r, &c.view, ms, 2, &g2.vb, &k2) == NACRE_OK);
    CHECK(nc_raster_visibility(g3.r, &c.view, ms, 2, &g3.vb, &k3) == NACRE_OK);
    size_t n = (size_t)W * H;
    CHECK(memcmp(g1.vb.depth, g2.vb.depth, n * sizeof(float)) == 0);
    CHECK(memcmp(g1.vb.object, g2.vb.object, n * sizeof(uint32_t)) == 0);
    CHECK(memcmp(g1.vb.triangle, g2.vb.triangle, n * sizeof(uint32_t)) == 0);
    CHECK(memcmp(g1.vb.depth, g3.vb.depth, n * sizeof(float)) == 0);
    CHECK(memcmp(g1.vb.triangle, g3.vb.triangle, n * sizeof(uint32_t)) == 0);
    CHECK(k1.triangles == (uint64_t)NT && k1.triangles_drawn == k2.triangles_drawn &&
          k1.triangles_drawn == k3.triangles_drawn);
    CHECK(k1.triangles_drawn > (uint64_t)NT / 4 && k1.triangles_drawn < (uint64_t)NT);
    size_t cov = count_covered(&g1.vb);
    CHECK(cov > n / 3);
    /* Repeating a frame on the same rasterizer gives the same result. */
    CHECK(nc_raster_visibility(g2.r, &c.view, ms, 2, &g2.vb, NULL) == NACRE_OK);
    CHECK(memcmp(g1.vb.depth, g2.vb.depth, n * sizeof(float)) == 0);

    /* One mesh per triangle (3 vertices each: only the scalar paths run) against the big
     * meshes (vector paths): the same pixels, depths and triangles. */
    nc_raster_mesh *single = malloc(sizeof(nc_raster_mesh) * NT);
    static const uint32_t tri012[3] = {0, 1, 2};
    for (int t = 0; t < NT; t++) {
        nc_raster_mesh s = {pos + 9 * t, tri012, 3, 1, (uint32_t)t, t >= NT / 2};
        single[t] = s;
    }
    CHECK(nc_raster_visibility(g2.r, &c.view, single, NT, &g2.vb, NULL) == NACRE_OK);
    CHECK(memcmp(g1.vb.depth, g2.vb.depth, n * sizeof(float)) == 0);
    int id_bad = 0;
    for (size_t p = 0; p < n; p++) {
        uint32_t want = g1.vb.object[p] == NC_NO_OBJECT
                            ? NC_NO_OBJECT
                            : g1.vb.object[p] * (NT / 2) + g1.vb.triangle[p];
        id_bad += g2.vb.object[p] != want || (want != NC_NO_OBJECT && g2.vb.triangle[p] != 0);
    }
    CHECK(id_bad == 0);

    /* The resolve is deterministic too. */
    nc_gbuffer a, b;
    memset(&a, 0, sizeof(a));
    memset(&b, 0, sizeof(b));
    float *nrm = calloc((size_t)9 * NT, sizeof(float));
    for (int v = 0; v < 3 * NT; v++)
        nrm[3 * v + 1] = 1.0f;
    nc_gbuffer_source srcs[2] = {{pos, nrm, NULL, idx, 0},
                                 {pos + 9 * (NT / 2), nrm, NULL, idx, 1}};
    CHECK(nc_gbuffer_resize(g1.ctx, &a, W, H) == NACRE_OK);
    CHECK(nc_gbuffer_resize(g2.ctx, &b, W, H) == NACRE_OK);
    CHECK(nc_raster_visibility(g2.r, &c.view, ms, 2, &g2.vb, NULL) == NACRE_OK);
    CHECK(nc_gbuffer_resolve(g1.ctx, &c.view, &g1.vb, srcs, 2, &a) == NACRE_OK);
    CHECK(nc_gbuffer_resolve(g2.ctx, &c.view, &g2.vb, srcs, 2, &b) == NACRE_OK);
    CHECK(memcmp(a.position, b.position, n * 3 * sizeof(float)) == 0);
    CHECK(memcmp(a.normal, b.normal, n * 3 * sizeof(float)) == 0);
    CHECK(memcmp(a.uv, b.uv, n * 2 * sizeof(float)) == 0);
    CHECK(memcmp(a.material, b.material, n * sizeof(uint32_t)) == 0);
    /* A source list too short for the visibility buffer is an error, not a crash. */
    CHECK(nc_gbuffer_resolve(g1.ctx, &c.view, &g1.vb, srcs, 1, &a) == NACRE_ERROR_INVALID_ARGUMENT);
    nc_gbuffer_free(g1.ctx, &a);
    nc_gbuffer_free(g2.ctx, &b);
    free(nrm);
    free(single);
    free(pos);
    free(idx);
    rig_free(&g1);
    rig_free(&g2);
    rig_free(&g3);
}

/* ---- orthographic camera ---- */

static void test_orthographic(void)
{
    const int W = 80, H = 60;
    rig g = rig_make(2, W, H);
    nc_raster_view v;
    memset(&v, 0, sizeof(v));
    /* Camera at z = 5 looking down -z; the view spans x in [-2, 2], y in [-1.5, 1.5]. */
    v.view = nc_mat4_look_at(nc_v3(0, 0, 5), nc_v3(0, 0, 0), nc_v3(0, 1, 0));
    v.proj = nc_mat4_ortho(-2.0f, 2.0f, -1.5f, 1.5f, 0.5f, 20.0f);
    v.width = W;
    v.height = H;
    v.orthographic = true;
    /* A square tilted about x: orthographic coverage is its projected rectangle. */
    double x0 = -0.73, x1 = 1.11, y0 = -0.52, y1 = 0.87, z0 = -1.0, z1 = 1.0;
    float pos[12] = {(float)x0, (float)y0, (float)z0, (float)x1, (float)y0, (float)z0,
                     (float)x1, (float)y1, (float)z1, (float)x0, (float)y1, (float)z1};
    float nrm[12];
    double ny = -(z1 - z0), nz = (y1 - y0), nl = sqrt(ny * ny + nz * nz);
    for (int k = 0; k < 4; k++) {
        nrm[3 * k] = 0.0f;
        nrm[3 * k + 1] = (float)(ny / nl);
        nrm[3 * k + 2] = (float)(nz / nl);
    }
    uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    nc_raster_mesh m = {pos, idx, 4, 2, 0, false};
    CHECK(nc_raster_visibility(g.r, &v, &m, 1, &g.vb, NULL) == NACRE_OK);
    int bad = 0, want_n = 0;
    for (int j = 0; j < H; j++)
        for (int i = 0; i < W; i++) {
            double wx = -2.0 + (i + 0.5) * 4.0 / W, wy = 1.5 - (j + 0.5) * 3.0 / H;
            bool want = wx > x0 && wx < x1 && wy > y0 && wy < y1;
            want_n += want;
            bad += want != (g.vb.object[(size_t)j * W + i] == 0);
        }
    CHECK(want_n > 500);
    CHECK(bad == 0);
    nc_gbuffer gb;
    memset(&gb, 0, sizeof(gb));
    CHECK(nc_gbuffer_resize(g.ctx, &gb, W, H) == NACRE_OK);
    nc_gbuffer_source src = {pos, nrm, NULL, idx, 0};
    CHECK(nc_gbuffer_resolve(g.ctx, &v, &g.vb, &src, 1, &gb) == NACRE_OK);
    int pbad = 0;
    for (int j = 0; j < H; j++)
        for (int i = 0; i < W; i++) {
            size_t p = (size_t)j * W + i;
            if (gb.object[p] != 0)
                continue;
            double wx = -2.0 + (i + 0.5) * 4.0 / W, wy = 1.5 - (j + 0.5) * 3.0 / H;
            double wz = z0 + (wy - y0) / (y1 - y0) * (z1 - z0);
            pbad += fabs(gb.position[3 * p] - wx) > 1e-5 ||
                    fabs(gb.position[3 * p + 1] - wy) > 1e-5 ||
                    fabs(gb.position[3 * p + 2] - wz) > 1e-5;
            pbad += fabs(gb.view_depth[p] - (5.0 - wz)) > 1e-5;
            pbad += fabs(gb.normal[3 * p + 2] - nz / nl) > 1e-5;
        }
    CHECK(pbad == 0);
    nc_gbuffer_free(g.ctx, &gb);
    rig_free(&g);
}

/* ---- argument errors ---- */

static void test_errors(void)
{
    rig g = rig_make(1, 16, 16);
    nc_raster_view view = screen_view(16, 16);
    float pos[9] = {0, 0, 0.5f, 1, 0, 0.5f, 0, 1, 0.5f};
    uint32_t idx[3] = {0, 1, 3};
    nc_raster_mesh m = {pos, idx, 3, 1, 0, true};
    CHECK(nc_raster_visibility(g.r, &view, &m, 1, &g.vb, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(g.ctx), "index") != NULL);
    idx[2] = 2;
    nc_raster_view big = screen_view(17, 16);
    CHECK(nc_raster_visibility(g.r, &big, &m, 1, &g.vb, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(nc_raster_visibility(g.r, &view, &m, 1, &g.vb, NULL) == NACRE_OK);
    CHECK(nc_raster_visibility(g.r, &view, NULL, 0, &g.vb, NULL) == NACRE_OK);
    CHECK(count_covered(&g.vb) == 0);
    CHECK(g.vb.depth[0] == 1.0f);
    float depth[16 * 16];
    CHECK(nc_raster_depth(g.r, &view, &m, 1, true, depth) == NACRE_OK);
    CHECK(depth[15 * 16 + 12] == 1.0f && depth[5 * 16 + 10] == 0.5f);
    CHECK(nc_vis_buffer_resize(g.ctx, &g.vb, 0, 5) == NACRE_ERROR_INVALID_ARGUMENT);
    rig_free(&g);
}

/* Vertices near the float range under a perspective view: clip-space x or w overflow to inf,
 * which the vertex pass once snapped to INT32_MIN (then the edge setup overflowed int32 under
 * UBSan). Every vertex set must rasterize without undefined behaviour, and the visible cases
 * still cover pixels. */
static void test_huge_vertices(void)
{
    const int W = 64, H = 48;
    rig g = rig_make(2, W, H);
    nc_raster_view view;
    memset(&view, 0, sizeof(view));
    view.view = nc_mat4_identity();
    /* Infinite far plane with z_ndc = near / w: no vertex in front of the camera is beyond far. */
    view.proj = nc_mat4_perspective(1.2f, (float)W / H, 0.1f, 100.0f);
    view.proj.m[2][2] = 0.0f;
    view.proj.m[2][3] = 0.1f;
    view.width = W;
    view.height = H;
    const float big[][9] = {
        {-3e38f, -3e38f, -3e38f, 3e38f, -3e38f, -3e38f, 0, 3e38f, -3e38f},
        {-3.4e38f, 0, -1, 3.4e38f, 0, -1, 0, 3.4e38f, -1},
        {-3e38f, -3e38f, -1e30f, 3e38f, -3e38f, -1e30f, 0, 3e38f, -1e30f},
        {0, 0, -3e38f, 3e38f, 0, -3e38f, 0, 3e38f, -3.4e38f},
        {0, 0, -3.2e38f, 3.4e38f, 0, -3.2e38f, 0, 1e38f, -3.2e38f}, /* x = inf, w finite */
        {0, 0, -3.2e38f, 0, 1e38f, -3.2e38f, -3.4e38f, 0, -3.2e38f},
        {-1, -1, -2, 1, -1, -2, 0, 1, -2}, /* an ordinary triangle among them */
    };
    const int n = (int)(sizeof(big) / sizeof(big[0]));
    for (int t = 0; t < n; t++) {
        /* Each alone, and eight copies so that the vector vertex pass sees them too. */
        float pos[9 * 8];
        uint32_t idx[3 * 8];
        for (int c = 0; c < 8; c++) {
            memcpy(pos + 9 * c, big[t], sizeof(big[t]));
            for (int k = 0; k < 3; k++)
                idx[3 * c + k] = (uint32_t)(3 * c + k);
        }
        for (int cull = 0; cull < 2; cull++) {
            nc_raster_mesh m = {pos, idx, 24, 8, 1, cull == 1};
            CHECK(nc_raster_visibility(g.r, &view, &m, 1, &g.vb, NULL) == NACRE_OK);
            if (t == n - 1)
                CHECK(count_covered(&g.vb) > 0);
        }
    }
    rig_free(&g);
}

int main(void)
{
    test_single_triangles();
    test_shared_edges();
    test_depth_order();
    test_perspective_resolve();
    test_clipping();
    test_back_faces();
    test_determinism();
    test_orthographic();
    test_errors();
    test_huge_vertices();
    return TEST_MAIN_END();
}
