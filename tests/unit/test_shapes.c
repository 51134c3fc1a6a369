/*
 * test_shapes.c: procedural shapes (src/scene/shapes.c).
 *
 * Every shape is checked for: valid data; watertightness after welding (0 boundary and 0
 * non-manifold edges, Euler characteristic 2 or 0); area and enclosed volume against the exact
 * values of the polyhedron and against the smooth shape within a bound derived below; normals
 * that agree with the winding; unit tangents orthogonal to the normals whose direction and
 * handedness follow the UVs.
 *
 * Exact polyhedra. The sphere and torus are surfaces of revolution tessellated with S segments:
 * a profile polygon (rho_j, y_j) in the meridian half-plane, repeated every 2 pi / S. Each band
 * between two meridians and two profile points is a planar isosceles trapezoid with parallel
 * sides 2 rho sin(pi/S) and height sqrt(cos^2(pi/S) d_rho^2 + d_y^2), so
 *     area   = S sin(pi/S) sum_j (rho_j + rho_j+1) sqrt(cos^2(pi/S) d_rho^2 + d_y^2).
 * A wedge between two meridian planes is {(s, y, t): (s, y) in the profile scaled by cos(pi/S)
 * along rho, |t| <= s tan(pi/S)}, so its volume is 2 tan(pi/S) cos^2(pi/S) int rho dA and
 *     volume = S sin(2 pi/S) int_profile rho dA,  int rho dA = |sum_edges d_y (a^2+ab+b^2)/6|
 * (Green's theorem over the profile polygon, a and b the rho of the edge's ends).
 *
 * Bounds against the smooth shapes. Sphere: the UV sphere is the convex hull of its vertices,
 * all on the sphere; each face's circumscribed cap is empty of other vertices, so its angular
 * radius is at most the covering radius beta <= (pi/R + 2 pi/S) / 2 (half a cell diagonal, walking
 * along the meridian then the parallel). So the hull contains the ball of radius r cos(beta):
 * V0 cos^3(beta) <= V <= V0 and A0 cos^2(beta) <= A <= A0 (area is monotone for convex sets).
 * Torus (S segments, N rings): from the exact formula, V = V0 sinc(2 pi/S) sinc(2 pi/N), so
 * 0 <= 1 - V/V0 <= ((2 pi/S)^2 + (2 pi/N)^2) / 6; and each band height lies between cos(pi/S)
 * and 1 times the profile chord, so 0 <= 1 - A/A0 <= (pi/S)^2 / 6 + (pi/N)^2 / 6 + (pi/S)^2 / 2.
 */
#include "test_util.h"

#include <nacre/nacre.h>

#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define PI 3.14159265358979323846

typedef struct measure {
    double area, volume;
} measure;

static measure measure_mesh(const nacre_mesh_data *m)
{
    measure r = {0, 0};
    for (uint32_t t = 0; t < m->triangle_count; t++) {
        const float *p0 = m->positions + 3 * m->indices[3 * t];
        const float *p1 = m->positions + 3 * m->indices[3 * t + 1];
        const float *p2 = m->positions + 3 * m->indices[3 * t + 2];
        double a[3] = {p0[0], p0[1], p0[2]}, b[3] = {p1[0], p1[1], p1[2]},
               c[3] = {p2[0], p2[1], p2[2]};
        double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
        double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                       e1[0] * e2[1] - e1[1] * e2[0]};
        r.area += 0.5 * sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        /* divergence theorem: sum of signed tetrahedra (origin, triangle) */
        r.volume += (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) +
                     a[2] * (b[0] * c[1] - b[1] * c[0])) / 6.0;
    }
    return r;
}

/* Exact area and volume of a profile polygon (closed) revolved polygonally with S segments. */
static measure revolved(const double *rho, const double *y, int count, int S)
{
    measure r = {0, 0};
    double c = cos(PI / S), s = sin(PI / S);
    double moment = 0;
    for (int j = 0; j < count; j++) {
        int k = (j + 1) % count;
        double dr = rho[k] - rho[j], dy = y[k] - y[j];
        r.area += (rho[j] + rho[k]) * s * sqrt(c * c * dr * dr + dy * dy);
        moment += dy * (rho[j] * rho[j] + rho[j] * rho[k] + rho[k] * rho[k]) / 6.0;
    }
    r.area *= S;
    r.volume = S * sin(2 * PI / S) * fabs(moment);
    return r;
}

static measure sphere_exact(double radius, int S, int R)
{
    double *rho = malloc(sizeof(double) * (size_t)(R + 1));
    double *y = malloc(sizeof(double) * (size_t)(R + 1));
    for (int j = 0; j <= R; j++) {
        rho[j] = radius * sin(PI * j / R);
        y[j] = radius * cos(PI * j / R);
    }
    rho[0] = rho[R] = 0; /* the poles: the closing edge runs along the axis (no area, no moment) */
    measure m = revolved(rho, y, R + 1, S);
    free(rho);
    free(y);
    return m;
}

static measure torus_exact(double major, double minor, int S, int N)
{
    double *rho = malloc(sizeof(double) * (size_t)N), *y = malloc(sizeof(double) * (size_t)N);
    for (int j = 0; j < N; j++) {
        rho[j] = major + minor * cos(2 * PI * j / N);
        y[j] = minor * sin(2 * PI * j / N);
    }
    measure m = revolved(rho, y, N, S);
    free(rho);
    free(y);
    return m;
}

static double dot3(const float *a, const float *b)
{
    return (double)a[0] * b[0] + (double)a[1] * b[1] + (double)a[2] * b[2];
}

/* Normals agree with the winding, tangents are orthonormal to them and follow dP/du, and the
 * handedness matches dP/dv. */
static void check_frames(const nacre_mesh_data *m, const char *what)
{
    int bad_unit = 0, bad_winding = 0, bad_ortho = 0, bad_w = 0, bad_du = 0, bad_dv = 0;
    for (uint32_t v = 0; v < m->vertex_count; v++) {
        const float *n = m->normals + 3 * v, *t = m->tangents + 4 * v;
        if (fabs(dot3(n, n) - 1) > 1e-5 || fabs(dot3(t, t) - 1) > 1e-5)
            bad_unit++;
        if (fabs(dot3(n, t)) > 1e-5)
            bad_ortho++;
        if (t[3] != 1.0f && t[3] != -1.0f)
            bad_w++;
    }
    for (uint32_t tr = 0; tr < m->triangle_count; tr++) {
        const uint32_t *ix = m->indices + 3 * tr;
        const float *p0 = m->positions + 3 * ix[0], *p1 = m->positions + 3 * ix[1],
                    *p2 = m->positions + 3 * ix[2];
        double e1[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]};
        double e2[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
        double g[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                       e1[0] * e2[1] - e1[1] * e2[0]};
        const float *uv0 = m->uvs + 2 * ix[0], *uv1 = m->uvs + 2 * ix[1], *uv2 = m->uvs + 2 * ix[2];
        double du1 = uv1[0] - uv0[0], dv1 = uv1[1] - uv0[1];
        double du2 = uv2[0] - uv0[0], dv2 = uv2[1] - uv0[1];
        double det = du1 * dv2 - du2 * dv1;
        double dpdu[3], dpdv[3];
        for (int k = 0; k < 3; k++) {
            dpdu[k] = (e1[k] * dv2 - e2[k] * dv1) / det;
            dpdv[k] = (e2[k] * du1 - e1[k] * du2) / det;
        }
        for (int c = 0; c < 3; c++) {
            const float *n = m->normals + 3 * ix[c], *t = m->tangents + 4 * ix[c];
            if (g[0] * n[0] + g[1] * n[1] + g[2] * n[2] <= 0)
                bad_winding++;
            if (dpdu[0] * t[0] + dpdu[1] * t[1] + dpdu[2] * t[2] <= 0)
                bad_du++;
            /* bitangent = w (n x t) must point along dP/dv */
            double b[3] = {t[3] * ((double)n[1] * t[2] - (double)n[2] * t[1]),
                           t[3] * ((double)n[2] * t[0] - (double)n[0] * t[2]),
                           t[3] * ((double)n[0] * t[1] - (double)n[1] * t[0])};
            if (b[0] * dpdv[0] + b[1] * dpdv[1] + b[2] * dpdv[2] <= 0)
                bad_dv++;
        }
    }
    if (bad_unit || bad_winding || bad_ortho || bad_w || bad_du || bad_dv)
        printf("%s: frames: %d not unit, %d against winding, %d not orthogonal, %d bad w, "
               "%d against dP/du, %d against dP/dv\n",
               what, bad_unit, bad_winding, bad_ortho, bad_w, bad_du, bad_dv);
    CHECK(bad_unit == 0);
    CHECK(bad_winding == 0);
    CHECK(bad_ortho == 0);
    CHECK(bad_w == 0);
    CHECK(bad_du == 0);
    CHECK(bad_dv == 0);
}

static nacre_mesh_data make(nacre_context *ctx, const nacre_shape_desc *d)
{
    nacre_mesh_data m;
    nacre_result r = nacre_mesh_make_shape(ctx, d, &m);
    CHECK(r == NACRE_OK);
    if (r != NACRE_OK)
        printf("make_shape: %s\n", nacre_context_last_error(ctx));
    CHECK(nacre_mesh_validate(ctx, &m, "shape") == NACRE_OK);
    return m;
}

static void test_sphere(nacre_context *ctx, float radius, uint32_t S, uint32_t R)
{
    nacre_shape_desc d = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
    d.radius = radius;
    d.segments = S;
    d.rings = R;
    nacre_mesh_data m = make(ctx, &d);
    CHECK(m.triangle_count == 2 * S * (R - 1));

    nacre_mesh_info info;
    CHECK(nacre_mesh_analyze(ctx, &m, &info) == NACRE_OK);
    CHECK(info.closed);
    CHECK(info.boundary_edges == 0 && info.nonmanifold_edges == 0);
    CHECK(info.welded_vertex_count == 2 + (R - 1) * S);
    CHECK(info.degenerate_triangles == 0 && info.unreferenced_vertices == 0);
    /* Euler characteristic of a sphere */
    CHECK((int64_t)info.welded_vertex_count - (int64_t)info.edge_count + info.triangle_count == 2);
    CHECK_NEAR(info.bounds_max[1], radius, 0);
    CHECK_NEAR(info.bounds_min[1], -radius, 0);

    measure got = measure_mesh(&m), exact = sphere_exact(radius, (int)S, (int)R);
    CHECK_NEAR(got.area, exact.area, 2e-6 * exact.area);
    CHECK_NEAR(got.volume, exact.volume, 2e-6 * exact.volume);
    CHECK_NEAR(info.surface_area, exact.area, 2e-6 * exact.area);

    double beta = (PI / R + 2 * PI / S) / 2, cb = cos(beta);
    double v0 = 4.0 / 3.0 * PI * pow(radius, 3), a0 = 4 * PI * radius * radius;
    double slack = 4e-6; /* float rounding of the positions */
    CHECK(got.volume <= v0 * (1 + slack) && got.volume >= v0 * cb * cb * cb * (1 - slack));
    CHECK(got.area <= a0 * (1 + slack) && got.area >= a0 * cb * cb * (1 - slack));

    /* Poles exactly on the axis; analytic normals are the unit position. */
    double worst = 0;
    for (uint32_t v = 0; v < m.vertex_count; v++) {
        const float *p = m.positions + 3 * v, *n = m.normals + 3 * v;
        for (int k = 0; k < 3; k++)
            worst = fmax(worst, fabs(p[k] / radius - n[k]));
    }
    CHECK(worst < 1e-6);
    check_frames(&m, "sphere");
    nacre_mesh_data_free(ctx, &m);
}

static void test_torus(nacre_context *ctx, float major, float minor, uint32_t S, uint32_t N)
{
    nacre_shape_desc d = nacre_shape_desc_defaults(NACRE_SHAPE_TORUS);
    d.radius = major;
    d.minor_radius = minor;
    d.segments = S;
    d.rings = N;
    nacre_mesh_data m = make(ctx, &d);
    CHECK(m.triangle_count == 2 * S * N);

    nacre_mesh_info info;
    CHECK(nacre_mesh_analyze(ctx, &m, &info) == NACRE_OK);
    CHECK(info.closed);
    CHECK(info.welded_vertex_count == S * N);
    CHECK((int64_t)info.welded_vertex_count - (int64_t)info.edge_count + info.triangle_count == 0);

    measure got = measure_mesh(&m), exact = torus_exact(major, minor, (int)S, (int)N);
    CHECK_NEAR(got.area, exact.area, 2e-6 * exact.area);
    CHECK_NEAR(got.volume, exact.volume, 2e-6 * exact.volume);

    double v0 = 2 * PI * PI * major * minor * minor, a0 = 4 * PI * PI * major * minor;
    double xs = PI / S, xn = PI / N, slack = 4e-6;
    double vdef = (4 * xs * xs + 4 * xn * xn) / 6, adef = xs * xs / 6 + xn * xn / 6 + xs * xs / 2;
    CHECK(got.volume <= v0 * (1 + slack) && got.volume >= v0 * (1 - vdef - slack));
    CHECK(got.area <= a0 * (1 + slack) && got.area >= a0 * (1 - adef - slack));
    /* With very few segments a cell spans a large turn of the tube, and a face's dP/dv (the
     * chord on its far meridian) can point against the bitangent of its near corner. */
    if (S >= 8)
        check_frames(&m, "torus");
    nacre_mesh_data_free(ctx, &m);
}

static void test_box(nacre_context *ctx, float sx, float sy, float sz, uint32_t N)
{
    nacre_shape_desc d = nacre_shape_desc_defaults(NACRE_SHAPE_BOX);
    d.size[0] = sx;
    d.size[1] = sy;
    d.size[2] = sz;
    d.segments = N;
    nacre_mesh_data m = make(ctx, &d);
    CHECK(m.triangle_count == 12 * N * N);
    CHECK(m.vertex_count == 6 * (N + 1) * (N + 1));

    nacre_mesh_info info;
    CHECK(nacre_mesh_analyze(ctx, &m, &info) == NACRE_OK);
    CHECK(info.closed);
    CHECK(info.welded_vertex_count == 6 * N * N + 2);
    CHECK((int64_t)info.welded_vertex_count - (int64_t)info.edge_count + info.triangle_count == 2);
    CHECK_NEAR(info.bounds_min[0], -0.5 * sx, 0);
    CHECK_NEAR(info.bounds_max[2], 0.5 * sz, 0);

    measure got = measure_mesh(&m);
    double area = 2.0 * ((double)sx * sy + (double)sy * sz + (double)sz * sx);
    double volume = (double)sx * sy * sz;
    CHECK_NEAR(got.area, area, 1e-6 * area);
    CHECK_NEAR(got.volume, volume, 1e-6 * volume);
    check_frames(&m, "box");

    /* Normals are exactly axis-aligned per face. */
    int off_axis = 0;
    for (uint32_t v = 0; v < m.vertex_count; v++) {
        const float *n = m.normals + 3 * v;
        off_axis += fabsf(n[0]) + fabsf(n[1]) + fabsf(n[2]) != 1.0f;
    }
    CHECK(off_axis == 0);
    nacre_mesh_data_free(ctx, &m);
}

static void test_plane(nacre_context *ctx, float sx, float sz, uint32_t N)
{
    nacre_shape_desc d = nacre_shape_desc_defaults(NACRE_SHAPE_PLANE);
    d.size[0] = sx;
    d.size[2] = sz;
    d.segments = N;
    nacre_mesh_data m = make(ctx, &d);
    CHECK(m.triangle_count == 2 * N * N);
    nacre_mesh_info info;
    CHECK(nacre_mesh_analyze(ctx, &m, &info) == NACRE_OK);
    CHECK(!info.closed);
    CHECK(info.boundary_edges == 4 * N);
    CHECK(info.nonmanifold_edges == 0);
    CHECK_NEAR(info.surface_area, (double)sx * sz, 1e-6 * sx * sz);
    CHECK(info.bounds_min[1] == 0.0f && info.bounds_max[1] == 0.0f);
    CHECK_NEAR(info.bounds_min[0], -0.5 * sx, 0);
    CHECK_NEAR(info.bounds_max[2], 0.5 * sz, 0);
    int not_up = 0;
    for (uint32_t v = 0; v < m.vertex_count; v++)
        not_up += !(m.normals[3 * v] == 0 && m.normals[3 * v + 1] == 1 &&
                    m.normals[3 * v + 2] == 0);
    CHECK(not_up == 0);
    check_frames(&m, "plane");
    nacre_mesh_data_free(ctx, &m);
}

/* Recomputed normals and tangents (Lengyel) agree with the analytic ones of the shapes. The
 * box keeps its flat normals: welded by position, recomputed normals would round its edges. */
static void test_recomputed_frames(nacre_context *ctx)
{
    nacre_shape_type types[3] = {NACRE_SHAPE_SPHERE, NACRE_SHAPE_TORUS, NACRE_SHAPE_BOX};
    for (int i = 0; i < 3; i++) {
        bool box = types[i] == NACRE_SHAPE_BOX;
        nacre_shape_desc d = nacre_shape_desc_defaults(types[i]);
        d.segments = box ? 3 : d.segments;
        nacre_mesh_data m = make(ctx, &d);
        nacre_mesh_data c = m; /* shares positions, uvs, indices (and the box's normals) */
        c.tangents = NULL;
        if (!box) {
            c.normals = NULL;
            CHECK(nacre_mesh_compute_normals(ctx, &c) == NACRE_OK);
        }
        CHECK(nacre_mesh_compute_tangents(ctx, &c) == NACRE_OK);
        double worst_n = 1, worst_t = 1;
        int w_mismatch = 0;
        for (uint32_t v = 0; v < m.vertex_count; v++) {
            worst_n = fmin(worst_n, dot3(m.normals + 3 * v, c.normals + 3 * v));
            worst_t = fmin(worst_t, dot3(m.tangents + 4 * v, c.tangents + 4 * v));
            w_mismatch += m.tangents[4 * v + 3] != c.tangents[4 * v + 3];
        }
        CHECK(worst_n > 0.995);
        CHECK(worst_t > (box ? 0.99999 : 0.99));
        CHECK(w_mismatch == 0);
        if (worst_n <= 0.995 || worst_t <= 0.99 || w_mismatch)
            printf("recomputed frames of shape %d: normals %.6f tangents %.6f, %d w differ\n",
                   (int)types[i], worst_n, worst_t, w_mismatch);
        /* c's new arrays came from the context. */
        if (!box)
            nacre_free(ctx, c.normals);
        nacre_free(ctx, c.tangents);
        nacre_mesh_data_free(ctx, &m);
    }
}

static void expect_error(nacre_context *ctx, const nacre_shape_desc *d, const char *needle)
{
    nacre_mesh_data m;
    memset(&m, 0xab, sizeof(m));
    nacre_result r = nacre_mesh_make_shape(ctx, d, &m);
    CHECK(r == NACRE_ERROR_INVALID_ARGUMENT);
    const char *msg = nacre_context_last_error(ctx);
    CHECK(strstr(msg, needle) != NULL);
    if (!strstr(msg, needle))
        printf("expected \"%s\" in \"%s\"\n", needle, msg);
    CHECK(m.positions == NULL && m.indices == NULL && m.vertex_count == 0);
}

static void test_errors(nacre_context *ctx)
{
    nacre_shape_desc d = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
    d.radius = 0;
    expect_error(ctx, &d, "shape: radius: must be positive");
    d.radius = NAN;
    expect_error(ctx, &d, "shape: radius: must be positive");
    d.radius = -1;
    expect_error(ctx, &d, "shape: radius: must be positive");
    d = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
    d.segments = 2;
    expect_error(ctx, &d, "shape: segments: 2 out of range (3..65536)");
    d.segments = 8;
    d.rings = 1;
    expect_error(ctx, &d, "shape: rings: 1 out of range (2..65536)");
    d.segments = 65536;
    d.rings = 65536;
    expect_error(ctx, &d, "shape: segments, rings: too many triangles");
    d = nacre_shape_desc_defaults(NACRE_SHAPE_BOX);
    d.size[1] = INFINITY;
    expect_error(ctx, &d, "shape: size[1]: must be positive");
    d = nacre_shape_desc_defaults(NACRE_SHAPE_BOX);
    d.segments = 0;
    expect_error(ctx, &d, "shape: segments: 0 out of range (1..65536)");
    d = nacre_shape_desc_defaults(NACRE_SHAPE_PLANE);
    d.size[2] = 0;
    expect_error(ctx, &d, "shape: size[2]: must be positive");
    d = nacre_shape_desc_defaults(NACRE_SHAPE_TORUS);
    d.minor_radius = 1.5f;
    expect_error(ctx, &d, "shape: minor_radius: must be smaller than radius");
    d.minor_radius = 0;
    expect_error(ctx, &d, "shape: minor_radius: must be positive");
    d = nacre_shape_desc_defaults(NACRE_SHAPE_TORUS);
    d.rings = 2;
    expect_error(ctx, &d, "shape: rings: 2 out of range (3..65536)");
    d.type = (nacre_shape_type)42;
    expect_error(ctx, &d, "shape: type: unknown (42)");
    CHECK(nacre_mesh_make_shape(ctx, NULL, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(nacre_mesh_make_shape(NULL, &d, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
}

static void test_defaults(void)
{
    nacre_shape_desc s = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
    CHECK(s.type == NACRE_SHAPE_SPHERE && s.radius == 1 && s.segments == 64 && s.rings == 32);
    nacre_shape_desc b = nacre_shape_desc_defaults(NACRE_SHAPE_BOX);
    CHECK(b.type == NACRE_SHAPE_BOX && b.size[0] == 1 && b.size[1] == 1 && b.size[2] == 1);
    nacre_shape_desc p = nacre_shape_desc_defaults(NACRE_SHAPE_PLANE);
    CHECK(p.type == NACRE_SHAPE_PLANE && p.size[0] == 10 && p.size[2] == 10);
    nacre_shape_desc t = nacre_shape_desc_defaults(NACRE_SHAPE_TORUS);
    CHECK(t.type == NACRE_SHAPE_TORUS && t.radius == 1 && t.minor_radius == 0.25f &&
          t.segments == 64 && t.rings == 32);
}

int main(void)
{
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    test_defaults();

    test_sphere(ctx, 1.0f, 64, 32);
    test_sphere(ctx, 2.5f, 3, 2); /* the coarsest: two triangular pyramids */
    test_sphere(ctx, 0.75f, 7, 5);
    test_sphere(ctx, 1.0f, 256, 128);
    test_torus(ctx, 1.0f, 0.25f, 64, 32);
    test_torus(ctx, 3.0f, 1.0f, 3, 4);
    test_torus(ctx, 2.0f, 0.5f, 200, 100);
    test_box(ctx, 1, 1, 1, 1);
    test_box(ctx, 2, 0.5f, 3, 4);
    test_box(ctx, 0.1f, 7, 1.3f, 17);
    test_plane(ctx, 10, 10, 1);
    test_plane(ctx, 3, 0.5f, 9);

    /* Convergence: the error shrinks as the tessellation refines, inside the derived bound. */
    double prev = INFINITY;
    for (uint32_t s = 8; s <= 512; s *= 2) {
        nacre_shape_desc d = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
        d.segments = s;
        d.rings = s / 2;
        nacre_mesh_data m = make(ctx, &d);
        double v0 = 4.0 / 3.0 * PI, cb = cos((PI / d.rings + 2 * PI / s) / 2);
        double err = v0 - measure_mesh(&m).volume;
        CHECK(err < prev);
        CHECK(err >= -4e-6 * v0 && err <= v0 * (1 - cb * cb * cb) + 4e-6 * v0);
        prev = err;
        nacre_mesh_data_free(ctx, &m);
    }

    test_recomputed_frames(ctx);
    test_errors(ctx);
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
