/*
 * test_mesh.c: mesh validation, normals, tangents and analysis (src/scene/mesh.c) and the
 * loader (src/io/mesh_load.c).
 *
 * Loader round trips write small files into NACRE_TEST_TMP from procedural shapes (OBJ, ASCII
 * PLY, binary PLY, GLB) or read the tiny hand-written files in tests/data/ (a quad cube OBJ, a
 * glTF with node transforms). Bad files must fail with the file name in the message and no
 * crash or leak under the sanitizers. The checks against the shared scans (NACRE_MESH_DIR, or
 * shared/meshes beside the source tree) are skipped with a note when they are absent.
 */
#include "test_util.h"

#include <nacre/nacre.h>

#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#define TMP NACRE_TEST_TMP
#define PI 3.14159265358979323846
#define DATA NACRE_SOURCE_DIR "/tests/data"

static nacre_context *ctx1, *ctx2; /* one thread, two threads */

static const char *tmp_path(const char *name)
{
    static char buf[8][1024];
    static int next;
    char *p = buf[next++ % 8];
    snprintf(p, sizeof(buf[0]), "%s/%s", TMP, name);
    return p;
}

static void write_bytes(const char *path, const void *data, size_t n)
{
    FILE *f = fopen(path, "wb");
    CHECK(f != NULL);
    if (!f)
        return;
    CHECK(fwrite(data, 1, n, f) == n);
    fclose(f);
}

static void write_text(const char *path, const char *text)
{
    write_bytes(path, text, strlen(text));
}

static bool contains(const char *hay, const char *needle) { return strstr(hay, needle) != NULL; }

static double signed_volume(const nacre_mesh_data *m)
{
    double v = 0;
    for (uint32_t t = 0; t < m->triangle_count; t++) {
        const float *a = m->positions + 3 * m->indices[3 * t];
        const float *b = m->positions + 3 * m->indices[3 * t + 1];
        const float *c = m->positions + 3 * m->indices[3 * t + 2];
        v += ((double)a[0] * ((double)b[1] * c[2] - (double)b[2] * c[1]) -
              (double)a[1] * ((double)b[0] * c[2] - (double)b[2] * c[0]) +
              (double)a[2] * ((double)b[0] * c[1] - (double)b[1] * c[0])) / 6.0;
    }
    return v;
}

static nacre_mesh_data shape(nacre_shape_type type, uint32_t segments, uint32_t rings)
{
    nacre_shape_desc d = nacre_shape_desc_defaults(type);
    if (segments)
        d.segments = segments;
    if (rings)
        d.rings = rings;
    nacre_mesh_data m;
    CHECK(nacre_mesh_make_shape(ctx1, &d, &m) == NACRE_OK);
    return m;
}

static nacre_mesh_info analyze(const nacre_mesh_data *m)
{
    nacre_mesh_info info;
    nacre_result r = nacre_mesh_analyze(ctx2, m, &info);
    CHECK(r == NACRE_OK);
    if (r != NACRE_OK)
        printf("analyze: %s\n", nacre_context_last_error(ctx2));
    return info;
}

/* ------------------------------------------------------------------------------------------ */
/* Validation                                                                                 */
/* ------------------------------------------------------------------------------------------ */

static float quad_pos[] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
static uint32_t quad_idx[] = {0, 1, 2, 0, 2, 3};

static void expect_invalid(const nacre_mesh_data *m, const char *message)
{
    CHECK(nacre_mesh_validate(ctx1, m, "quad") == NACRE_ERROR_INVALID_ARGUMENT);
    const char *msg = nacre_context_last_error(ctx1);
    CHECK(strcmp(msg, message) == 0);
    if (strcmp(msg, message) != 0)
        printf("expected \"%s\", got \"%s\"\n", message, msg);
}

static void test_validate(void)
{
    nacre_mesh_data m = {4, 2, quad_pos, NULL, NULL, NULL, quad_idx};
    CHECK(nacre_mesh_validate(ctx1, &m, "quad") == NACRE_OK);

    uint32_t bad_idx[] = {0, 1, 2, 0, 99, 3};
    nacre_mesh_data b = m;
    b.indices = bad_idx;
    expect_invalid(&b, "quad: triangle 1: index 99 out of range (vertex_count 4)");

    float nan_pos[12];
    memcpy(nan_pos, quad_pos, sizeof(nan_pos));
    nan_pos[7] = NAN;
    b = m;
    b.positions = nan_pos;
    expect_invalid(&b, "quad: vertex 2: non-finite position");

    b = m;
    b.triangle_count = 0;
    expect_invalid(&b, "quad: mesh has no triangles");
    b = m;
    b.vertex_count = 0;
    expect_invalid(&b, "quad: mesh has no vertices");
    b = m;
    b.positions = NULL;
    expect_invalid(&b, "quad: positions: NULL");
    b = m;
    b.indices = NULL;
    expect_invalid(&b, "quad: indices: NULL");

    float normals[12] = {0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 0, INFINITY};
    b = m;
    b.normals = normals;
    expect_invalid(&b, "quad: vertex 3: non-finite normal");
    float uvs[8] = {0, 0, 1, 0, NAN, 1, 0, 1};
    b = m;
    b.uvs = uvs;
    expect_invalid(&b, "quad: vertex 2: non-finite uv");
    float tangents[16] = {1, 0, 0, 1, 1, 0, 0, 1, 1, 0, 0, 1, 1, 0, 0, 1};
    tangents[1] = NAN;
    b = m;
    b.tangents = tangents;
    expect_invalid(&b, "quad: vertex 0: non-finite tangent");

    CHECK(nacre_mesh_validate(ctx1, NULL, "x") == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(nacre_mesh_validate(NULL, &m, "x") == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(nacre_mesh_validate(ctx1, &m, NULL) == NACRE_OK);

    /* Freeing zeroes the struct and accepts NULL fields. */
    nacre_mesh_data empty = {0};
    nacre_mesh_data_free(ctx1, &empty);
    nacre_mesh_data_free(ctx1, NULL);
    nacre_mesh_data s = shape(NACRE_SHAPE_BOX, 1, 0);
    nacre_mesh_data_free(ctx1, &s);
    CHECK(s.positions == NULL && s.vertex_count == 0 && s.indices == NULL);
}

/* ------------------------------------------------------------------------------------------ */
/* Normals and tangents                                                                       */
/* ------------------------------------------------------------------------------------------ */

/* A unit cube with 8 shared corners, counter-clockwise seen from outside. */
static float cube_pos[] = {-1, -1, -1, 1, -1, -1, 1, 1, -1, -1, 1, -1,
                           -1, -1, 1,  1, -1, 1,  1, 1, 1,  -1, 1, 1};
static uint32_t cube_idx[] = {0, 3, 2, 0, 2, 1, 4, 5, 6, 4, 6, 7, 0, 4, 7, 0, 7, 3,
                              1, 2, 6, 1, 6, 5, 0, 1, 5, 0, 5, 4, 3, 7, 6, 3, 6, 2};

static bool is_corner_normal(const float *p, const float *n)
{
    const double k = 1.0 / sqrt(3.0);
    for (int i = 0; i < 3; i++)
        if (fabs(n[i] - copysign(k, p[i])) > 1e-6)
            return false;
    return true;
}

static void test_normals(void)
{
    /* Shared corners: by symmetry (and since each face adds the same angle x area at every
     * corner, however it is split), every normal is the corner's diagonal. */
    nacre_mesh_data m = {8, 12, cube_pos, NULL, NULL, NULL, cube_idx};
    CHECK(nacre_mesh_compute_normals(ctx1, &m) == NACRE_OK);
    CHECK(m.normals != NULL);
    int bad = 0;
    for (int v = 0; v < 8; v++)
        bad += !is_corner_normal(cube_pos + 3 * v, m.normals + 3 * v);
    CHECK(bad == 0);
    /* Recomputing overwrites the existing array in place. */
    float *same = m.normals;
    m.normals[0] = 42;
    CHECK(nacre_mesh_compute_normals(ctx1, &m) == NACRE_OK);
    CHECK(m.normals == same && is_corner_normal(cube_pos, m.normals));
    nacre_free(ctx1, m.normals); /* allocated through the context */

    /* Unshared corners (the box shape has three copies of each corner, one per face):
     * welding by position must give the same smooth result. */
    nacre_mesh_data box = shape(NACRE_SHAPE_BOX, 1, 0);
    float *flat = box.normals;
    box.normals = NULL;
    CHECK(nacre_mesh_compute_normals(ctx2, &box) == NACRE_OK);
    bad = 0;
    for (uint32_t v = 0; v < box.vertex_count; v++)
        bad += !is_corner_normal(box.positions + 3 * v, box.normals + 3 * v);
    CHECK(bad == 0);
    nacre_free(ctx1, flat);
    nacre_free(ctx2, box.normals); /* each array goes back to the context that made it */
    box.normals = NULL;
    nacre_mesh_data_free(ctx1, &box);

    /* Degenerate triangles add nothing; a vertex with no usable triangle gets +y. */
    float pos[] = {0, 0, 0, 1, 0, 0, 0, 0, -1, 5, 5, 5, 2, 0, 0, 0, 0, 0};
    uint32_t idx[] = {0, 2, 1, /* normal -y */ 0, 1, 4, /* collinear */ 0, 5, 1 /* 5 is at 0 */};
    nacre_mesh_data d = {6, 3, pos, NULL, NULL, NULL, idx};
    CHECK(nacre_mesh_compute_normals(ctx1, &d) == NACRE_OK);
    for (int v = 0; v < 6; v++) {
        float want = (v == 3 || v == 4) ? 1.0f : -1.0f; /* 3: unused; 4: only the collinear one */
        CHECK_NEAR(d.normals[3 * v], 0, 1e-7);
        CHECK_NEAR(d.normals[3 * v + 1], want, 1e-7);
        CHECK_NEAR(d.normals[3 * v + 2], 0, 1e-7);
    }
    nacre_free(ctx1, d.normals);

    /* Bad input fails cleanly. */
    uint32_t oob[] = {0, 1, 7};
    nacre_mesh_data o = {3, 1, quad_pos, NULL, NULL, NULL, oob};
    CHECK(nacre_mesh_compute_normals(ctx1, &o) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(contains(nacre_context_last_error(ctx1), "index 7 out of range"));
    CHECK(o.normals == NULL);
}

static void test_tangents(void)
{
    /* No UVs: any unit tangent perpendicular to the normal, w = +1. */
    nacre_mesh_data m = {8, 12, cube_pos, NULL, NULL, NULL, cube_idx};
    CHECK(nacre_mesh_compute_tangents(ctx1, &m) == NACRE_OK); /* computes normals too */
    CHECK(m.normals && m.tangents);
    int bad = 0;
    for (int v = 0; v < 8; v++) {
        const float *n = m.normals + 3 * v, *t = m.tangents + 4 * v;
        bad += fabsf(n[0] * t[0] + n[1] * t[1] + n[2] * t[2]) > 1e-6f;
        bad += fabsf(t[0] * t[0] + t[1] * t[1] + t[2] * t[2] - 1) > 1e-6f;
        bad += t[3] != 1.0f;
    }
    CHECK(bad == 0);
    nacre_free(ctx1, m.normals);
    nacre_free(ctx1, m.tangents);

    /* A quad in the xy plane facing +z with u along +x, v along +y: t = +x, w = +1. Mirroring u
     * flips the tangent and the handedness. */
    float normals[12] = {0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 0, 1};
    float uv[8] = {0, 0, 1, 0, 1, 1, 0, 1};
    float uv_mirror[8] = {1, 0, 0, 0, 0, 1, 1, 1};
    float uv_flat[8] = {0.5f, 0.5f, 0.5f, 0.5f, 0.5f, 0.5f, 0.5f, 0.5f};
    for (int c = 0; c < 3; c++) {
        nacre_mesh_data q = {4, 2, quad_pos, normals, c == 0 ? uv : c == 1 ? uv_mirror : uv_flat,
                             NULL, quad_idx};
        CHECK(nacre_mesh_compute_tangents(ctx2, &q) == NACRE_OK);
        for (int v = 0; v < 4; v++) {
            const float *t = q.tangents + 4 * v;
            if (c == 0) {
                CHECK(fabsf(t[0] - 1) < 1e-6f && fabsf(t[1]) < 1e-6f && fabsf(t[2]) < 1e-6f);
                CHECK(t[3] == 1.0f);
            } else if (c == 1) {
                CHECK(fabsf(t[0] + 1) < 1e-6f && fabsf(t[1]) < 1e-6f && fabsf(t[2]) < 1e-6f);
                CHECK(t[3] == -1.0f);
            } else {
                /* degenerate UVs: some frame perpendicular to +z */
                CHECK(fabsf(t[2]) < 1e-6f && fabsf(t[0] * t[0] + t[1] * t[1] - 1) < 1e-6f);
                CHECK(t[3] == 1.0f || t[3] == -1.0f);
            }
        }
        nacre_free(ctx2, q.tangents);
    }
}

/* Results must not depend on the thread count. */
static void test_determinism(void)
{
    nacre_mesh_data a = shape(NACRE_SHAPE_TORUS, 300, 150);
    nacre_mesh_data b = shape(NACRE_SHAPE_TORUS, 300, 150);
    size_t nv = a.vertex_count;
    nacre_free(ctx1, a.normals);
    nacre_free(ctx1, a.tangents);
    nacre_free(ctx1, b.normals);
    nacre_free(ctx1, b.tangents);
    a.normals = a.tangents = b.normals = b.tangents = NULL;
    CHECK(nacre_mesh_compute_tangents(ctx1, &a) == NACRE_OK);
    CHECK(nacre_mesh_compute_tangents(ctx2, &b) == NACRE_OK);
    CHECK(memcmp(a.normals, b.normals, nv * 3 * sizeof(float)) == 0);
    CHECK(memcmp(a.tangents, b.tangents, nv * 4 * sizeof(float)) == 0);
    nacre_mesh_info i1, i2;
    CHECK(nacre_mesh_analyze(ctx1, &a, &i1) == NACRE_OK);
    CHECK(nacre_mesh_analyze(ctx2, &a, &i2) == NACRE_OK);
    CHECK(memcmp(&i1, &i2, sizeof(i1)) == 0);
    CHECK(i1.closed);
    nacre_mesh_data_free(ctx1, &a);
    nacre_mesh_data_free(ctx1, &b);
}

/* ------------------------------------------------------------------------------------------ */
/* Analysis                                                                                   */
/* ------------------------------------------------------------------------------------------ */

/* A copy of `m`'s triangles without those for which drop(t) is true (positions shared). */
static nacre_mesh_data without(const nacre_mesh_data *m, uint32_t first, uint32_t count)
{
    nacre_mesh_data r = *m;
    r.indices = malloc(sizeof(uint32_t) * 3 * m->triangle_count);
    r.triangle_count = 0;
    for (uint32_t t = 0; t < m->triangle_count; t++)
        if (t < first || t >= first + count) {
            memcpy(r.indices + 3 * r.triangle_count, m->indices + 3 * t, 3 * sizeof(uint32_t));
            r.triangle_count++;
        }
    return r;
}

static void test_analyze(void)
{
    const uint32_t S = 24, R = 12;
    nacre_mesh_data sphere = shape(NACRE_SHAPE_SPHERE, S, R);
    nacre_mesh_info info = analyze(&sphere);
    CHECK(info.closed && info.edge_count == 3ull * info.triangle_count / 2);
    CHECK(info.vertex_count == sphere.vertex_count && info.triangle_count == sphere.triangle_count);
    /* 2 S pole copies collapse to 2 poles, and R - 1 seam copies to the rings' first vertex */
    CHECK(info.welded_vertex_count == sphere.vertex_count - 2 * (S - 1) - (R - 1));

    /* The first S triangles are the north pole fan: removing it opens an S-edge hole. */
    nacre_mesh_data hole = without(&sphere, 0, S);
    info = analyze(&hole);
    CHECK(!info.closed && info.boundary_edges == S && info.nonmanifold_edges == 0);
    CHECK(info.unreferenced_vertices == S); /* the pole copies */
    CHECK(info.welded_vertex_count == 1 + (R - 1) * S);
    free(hole.indices);

    /* Two triangles of one quad: a 4-edge hole. Then one triangle: 3 edges. */
    hole = without(&sphere, S + 10, 2);
    info = analyze(&hole);
    CHECK(info.boundary_edges == 4 && info.nonmanifold_edges == 0);
    CHECK(info.unreferenced_vertices == 0);
    free(hole.indices);
    hole = without(&sphere, S + 10, 1);
    info = analyze(&hole);
    CHECK(info.boundary_edges == 3);
    free(hole.indices);

    /* A duplicated triangle makes its three edges non-manifold (used by three faces). */
    nacre_mesh_data dup = sphere;
    dup.indices = malloc(sizeof(uint32_t) * 3 * (sphere.triangle_count + 1));
    memcpy(dup.indices, sphere.indices, sizeof(uint32_t) * 3 * sphere.triangle_count);
    memcpy(dup.indices + 3 * sphere.triangle_count, sphere.indices + 3 * 40, 3 * sizeof(uint32_t));
    dup.triangle_count++;
    info = analyze(&dup);
    CHECK(!info.closed && info.nonmanifold_edges == 3 && info.boundary_edges == 0);

    /* A triangle through both seam copies of one ring vertex (distinct indices, one position)
     * collapses after welding: degenerate, and it adds no edges. Ring 1 starts at vertex S. */
    dup.indices[3 * sphere.triangle_count] = S;
    dup.indices[3 * sphere.triangle_count + 1] = S + S;
    dup.indices[3 * sphere.triangle_count + 2] = S + S + 1;
    info = analyze(&dup);
    CHECK(info.closed && info.degenerate_triangles == 1);
    CHECK(info.edge_count == 3ull * sphere.triangle_count / 2);
    free(dup.indices);

    /* Unreferenced vertices: extra positions no triangle uses. */
    nacre_mesh_data extra = sphere;
    extra.vertex_count += 5;
    extra.positions = malloc(sizeof(float) * 3 * extra.vertex_count);
    memcpy(extra.positions, sphere.positions, sizeof(float) * 3 * sphere.vertex_count);
    for (int i = 0; i < 15; i++)
        extra.positions[3 * sphere.vertex_count + (uint32_t)i] = 100.0f + (float)i;
    extra.normals = extra.uvs = extra.tangents = NULL;
    info = analyze(&extra);
    CHECK(info.closed && info.unreferenced_vertices == 5);
    CHECK(info.welded_vertex_count == sphere.vertex_count - 2 * (S - 1) - (R - 1));
    CHECK(info.bounds_max[0] == 112.0f); /* bounds cover every vertex record */
    free(extra.positions);
    nacre_mesh_data_free(ctx1, &sphere);

    /* Zero-area (collinear) triangle with distinct corners: degenerate, edges still counted. */
    float pos[] = {0, 0, 0, 1, 0, 0, 2, 0, 0, 0, 1, 0};
    uint32_t idx[] = {0, 1, 3, 0, 1, 2};
    nacre_mesh_data z = {4, 2, pos, NULL, NULL, NULL, idx};
    info = analyze(&z);
    CHECK(info.degenerate_triangles == 1 && info.edge_count == 5);
    CHECK(info.boundary_edges == 4 && info.nonmanifold_edges == 0);
    CHECK_NEAR(info.surface_area, 0.5, 1e-12);
    CHECK(info.bounds_min[0] == 0 && info.bounds_max[0] == 2 && info.bounds_max[1] == 1);

    /* -0.0 and +0.0 weld. */
    float pz[] = {0, 0, 0, 1, 0, 0, 0, 1, 0, -0.0f, -0.0f, -0.0f, 0, 0, 1};
    uint32_t iz[] = {0, 2, 1, 3, 1, 4};
    nacre_mesh_data w = {5, 2, pz, NULL, NULL, NULL, iz};
    info = analyze(&w);
    CHECK(info.welded_vertex_count == 4 && info.edge_count == 5);

    nacre_mesh_info dummy;
    CHECK(nacre_mesh_analyze(ctx1, &w, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
    uint32_t oob[] = {0, 1, 9};
    nacre_mesh_data o = {5, 1, pz, NULL, NULL, NULL, oob};
    CHECK(nacre_mesh_analyze(ctx1, &o, &dummy) == NACRE_ERROR_INVALID_ARGUMENT);
}

/* ------------------------------------------------------------------------------------------ */
/* Loader round trips                                                                         */
/* ------------------------------------------------------------------------------------------ */

static nacre_mesh_data load_ok(const char *path)
{
    nacre_mesh_data m;
    nacre_result r = nacre_mesh_load(ctx2, path, &m);
    CHECK(r == NACRE_OK);
    if (r != NACRE_OK) {
        printf("load %s: %s\n", path, nacre_context_last_error(ctx2));
        memset(&m, 0, sizeof(m));
        return m;
    }
    CHECK(nacre_mesh_validate(ctx2, &m, path) == NACRE_OK);
    CHECK(m.normals != NULL && m.tangents != NULL);
    return m;
}

static bool same_floats(const float *a, const float *b, size_t n)
{
    return memcmp(a, b, n * sizeof(float)) == 0;
}

/* Text formats: assimp's fast_atof is not correctly rounded, so "%.9g" may come back an ulp or
 * two off. */
static bool near_floats(const float *a, const float *b, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (!(fabsf(a[i] - b[i]) <= 1e-6f * fmaxf(1.0f, fabsf(b[i]))))
            return false;
    return true;
}

static void test_load_obj(void)
{
    nacre_mesh_data src = shape(NACRE_SHAPE_SPHERE, 12, 6);
    const char *path = tmp_path("sphere.obj");
    FILE *f = fopen(path, "w");
    CHECK(f != NULL);
    if (!f)
        return;
    fprintf(f, "# written by test_mesh\no sphere\n");
    for (uint32_t v = 0; v < src.vertex_count; v++) {
        const float *p = src.positions + 3 * v, *n = src.normals + 3 * v, *t = src.uvs + 2 * v;
        fprintf(f, "v %.9g %.9g %.9g\nvn %.9g %.9g %.9g\nvt %.9g %.9g\n", p[0], p[1], p[2], n[0],
                n[1], n[2], t[0], t[1]);
    }
    for (uint32_t t = 0; t < src.triangle_count; t++) {
        const uint32_t *i = src.indices + 3 * t;
        fprintf(f, "f %u/%u/%u %u/%u/%u %u/%u/%u\n", i[0] + 1, i[0] + 1, i[0] + 1, i[1] + 1,
                i[1] + 1, i[1] + 1, i[2] + 1, i[2] + 1, i[2] + 1);
    }
    fclose(f);

    nacre_mesh_data m = load_ok(path);
    CHECK(m.triangle_count == src.triangle_count);
    CHECK(m.uvs != NULL);
    int bad = 0;
    for (uint32_t t = 0; m.indices && t < m.triangle_count; t++)
        for (int k = 0; k < 3; k++) {
            uint32_t a = m.indices[3 * t + (uint32_t)k], b = src.indices[3 * t + (uint32_t)k];
            bad += !near_floats(m.positions + 3 * a, src.positions + 3 * b, 3);
            bad += !near_floats(m.uvs + 2 * a, src.uvs + 2 * b, 2);
            for (int c = 0; c < 3; c++)
                bad += fabsf(m.normals[3 * a + (uint32_t)c] - src.normals[3 * b + (uint32_t)c]) >
                       1e-6f;
        }
    CHECK(bad == 0);
    nacre_mesh_info info = analyze(&m);
    CHECK(info.closed && info.welded_vertex_count == 2 + 5 * 12);
    nacre_mesh_data_free(ctx2, &m);
    nacre_mesh_data_free(ctx1, &src);

    /* Quads are triangulated; the file's normals and UVs are kept, tangents derived. */
    m = load_ok(DATA "/quad_cube.obj");
    CHECK(m.triangle_count == 12 && m.vertex_count == 24);
    info = analyze(&m);
    CHECK(info.closed && info.welded_vertex_count == 8);
    CHECK_NEAR(info.surface_area, 6, 1e-9);
    CHECK_NEAR(signed_volume(&m), 1, 1e-9);
    bad = 0;
    for (uint32_t t = 0; t < m.triangle_count; t++) {
        const uint32_t *ix = m.indices + 3 * t;
        const float *p0 = m.positions + 3 * ix[0], *p1 = m.positions + 3 * ix[1],
                    *p2 = m.positions + 3 * ix[2];
        float e1[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]};
        float e2[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
        float g[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                      e1[0] * e2[1] - e1[1] * e2[0]};
        for (int k = 0; k < 3; k++) {
            const float *n = m.normals + 3 * ix[k], *tg = m.tangents + 4 * ix[k];
            /* flat file normals: exactly the face's axis */
            bad += g[0] * n[0] + g[1] * n[1] + g[2] * n[2] <= 0;
            bad += fabsf(n[0]) + fabsf(n[1]) + fabsf(n[2]) != 1.0f;
            bad += fabsf(n[0] * tg[0] + n[1] * tg[1] + n[2] * tg[2]) > 1e-6f;
            bad += tg[3] != 1.0f;
        }
    }
    CHECK(bad == 0);
    nacre_mesh_data_free(ctx2, &m);
}

static void write_ply_header(FILE *f, const char *format, uint32_t nv, uint32_t nt, bool normals)
{
    fprintf(f, "ply\nformat %s 1.0\ncomment test_mesh\nelement vertex %u\n", format, nv);
    fprintf(f, "property float x\nproperty float y\nproperty float z\n");
    if (normals)
        fprintf(f, "property float nx\nproperty float ny\nproperty float nz\n");
    fprintf(f, "element face %u\nproperty list uchar int vertex_indices\nend_header\n", nt);
}

/* Binary little-endian PLY of m (x86 is little-endian, as the test machine is). */
static void write_binary_ply(const char *path, const nacre_mesh_data *m, bool normals,
                             long truncate_by)
{
    FILE *f = fopen(path, "wb");
    CHECK(f != NULL);
    if (!f)
        return;
    write_ply_header(f, "binary_little_endian", m->vertex_count, m->triangle_count, normals);
    for (uint32_t v = 0; v < m->vertex_count; v++) {
        fwrite(m->positions + 3 * v, sizeof(float), 3, f);
        if (normals)
            fwrite(m->normals + 3 * v, sizeof(float), 3, f);
    }
    for (uint32_t t = 0; t < m->triangle_count; t++) {
        unsigned char three = 3;
        int32_t ix[3] = {(int32_t)m->indices[3 * t], (int32_t)m->indices[3 * t + 1],
                         (int32_t)m->indices[3 * t + 2]};
        fwrite(&three, 1, 1, f);
        fwrite(ix, sizeof(int32_t), 3, f);
    }
    long size = ftell(f);
    fclose(f);
    if (truncate_by > 0)
        CHECK(truncate(path, size - truncate_by) == 0);
}

static void test_load_ply(void)
{
    nacre_mesh_data src = shape(NACRE_SHAPE_TORUS, 20, 10);

    const char *ascii = tmp_path("torus_ascii.ply");
    FILE *f = fopen(ascii, "w");
    CHECK(f != NULL);
    if (!f)
        return;
    write_ply_header(f, "ascii", src.vertex_count, src.triangle_count, false);
    for (uint32_t v = 0; v < src.vertex_count; v++)
        fprintf(f, "%.9g %.9g %.9g\n", src.positions[3 * v], src.positions[3 * v + 1],
                src.positions[3 * v + 2]);
    for (uint32_t t = 0; t < src.triangle_count; t++)
        fprintf(f, "3 %u %u %u\n", src.indices[3 * t], src.indices[3 * t + 1],
                src.indices[3 * t + 2]);
    fclose(f);
    nacre_mesh_data m = load_ok(ascii);
    CHECK(m.vertex_count == src.vertex_count && m.triangle_count == src.triangle_count);
    if (m.positions) {
        CHECK(near_floats(m.positions, src.positions, 3 * (size_t)src.vertex_count));
        CHECK(memcmp(m.indices, src.indices, 12 * (size_t)src.triangle_count) == 0);
        CHECK(m.uvs == NULL);
        nacre_mesh_info info = analyze(&m);
        CHECK(info.closed && info.welded_vertex_count == 200);
        /* computed normals are close to the analytic ones of the torus */
        double worst = 1;
        for (uint32_t v = 0; v < m.vertex_count; v++) {
            const float *a = m.normals + 3 * v, *b = src.normals + 3 * v;
            worst = fmin(worst, (double)a[0] * b[0] + (double)a[1] * b[1] + (double)a[2] * b[2]);
        }
        CHECK(worst > 0.95);
    }
    nacre_mesh_data_free(ctx2, &m);

    const char *binary = tmp_path("torus_binary.ply");
    write_binary_ply(binary, &src, true, 0);
    m = load_ok(binary);
    CHECK(m.vertex_count == src.vertex_count && m.triangle_count == src.triangle_count);
    if (m.positions) {
        CHECK(same_floats(m.positions, src.positions, 3 * (size_t)src.vertex_count));
        CHECK(memcmp(m.indices, src.indices, 12 * (size_t)src.triangle_count) == 0);
        int bad = 0;
        for (size_t i = 0; i < 3 * (size_t)src.vertex_count; i++)
            bad += fabsf(m.normals[i] - src.normals[i]) > 1e-6f;
        CHECK(bad == 0);
    }
    nacre_mesh_data_free(ctx2, &m);
    nacre_mesh_data_free(ctx1, &src);
}

static void test_load_gltf(void)
{
    /* Three instances of a tetrahedron: translated, under a scaled parent, and mirrored (whose
     * winding must be flipped back to stay outward). */
    nacre_mesh_data m = load_ok(DATA "/tetra_nodes.gltf");
    CHECK(m.vertex_count == 12 && m.triangle_count == 12);
    if (!m.positions)
        return;
    nacre_mesh_info info = analyze(&m);
    CHECK(info.closed && info.welded_vertex_count == 12);
    CHECK(info.bounds_min[0] == -11 && info.bounds_min[1] == 0 && info.bounds_min[2] == 0);
    CHECK(info.bounds_max[0] == 11 && info.bounds_max[1] == 12 && info.bounds_max[2] == 2);
    CHECK_NEAR(signed_volume(&m), 1.0 / 6 + 8.0 / 6 + 1.0 / 6, 1e-6);
    CHECK(m.uvs != NULL);
    /* The first instance's vertices are the file's, moved by +10 in x; glTF's v runs down the
     * image, nacre's up, so v comes back as 1 - v. */
    const float expect_p[4][3] = {{10, 0, 0}, {11, 0, 0}, {10, 1, 0}, {10, 0, 1}};
    const float expect_uv[4][2] = {{0, 1}, {1, 1}, {0, 0}, {0.5f, 0.5f}};
    for (int v = 0; v < 4; v++) {
        CHECK(same_floats(m.positions + 3 * v, expect_p[v], 3));
        CHECK(same_floats(m.uvs + 2 * v, expect_uv[v], 2));
    }
    nacre_mesh_data_free(ctx2, &m);

    /* GLB: the same tetrahedron rotated 90 degrees about +y (x -> -z, z -> x). */
    float pos[12] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1};
    uint16_t idx[12] = {0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3};
    unsigned char bin[72];
    memcpy(bin, pos, 48);
    memcpy(bin + 48, idx, 24);
    char json[1024];
    int jn = snprintf(json, sizeof(json),
        "{\"asset\":{\"version\":\"2.0\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
        "\"nodes\":[{\"mesh\":0,\"rotation\":[0,0.70710678,0,0.70710678]}],"
        "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":0},\"indices\":1}]}],"
        "\"accessors\":[{\"bufferView\":0,\"componentType\":5126,\"count\":4,\"type\":\"VEC3\","
        "\"min\":[0,0,0],\"max\":[1,1,1]},"
        "{\"bufferView\":1,\"componentType\":5123,\"count\":12,\"type\":\"SCALAR\"}],"
        "\"bufferViews\":[{\"buffer\":0,\"byteOffset\":0,\"byteLength\":48},"
        "{\"buffer\":0,\"byteOffset\":48,\"byteLength\":24}],"
        "\"buffers\":[{\"byteLength\":72}]}");
    while (jn % 4)
        json[jn++] = ' ';
    uint32_t header[3] = {0x46546C67u, 2, (uint32_t)(12 + 8 + jn + 8 + 72)};
    uint32_t jchunk[2] = {(uint32_t)jn, 0x4E4F534Au}, bchunk[2] = {72, 0x004E4942u};
    const char *glb = tmp_path("tetra.glb");
    FILE *f = fopen(glb, "wb");
    CHECK(f != NULL);
    if (!f)
        return;
    fwrite(header, 4, 3, f);
    fwrite(jchunk, 4, 2, f);
    fwrite(json, 1, (size_t)jn, f);
    fwrite(bchunk, 4, 2, f);
    fwrite(bin, 1, 72, f);
    fclose(f);
    m = load_ok(glb);
    CHECK(m.vertex_count == 4 && m.triangle_count == 4);
    if (!m.positions)
        return;
    const float rotated[4][3] = {{0, 0, 0}, {0, 0, -1}, {0, 1, 0}, {1, 0, 0}};
    for (int v = 0; v < 4; v++)
        for (int k = 0; k < 3; k++)
            CHECK_NEAR(m.positions[3 * v + k], rotated[v][k], 1e-6);
    CHECK_NEAR(signed_volume(&m), 1.0 / 6, 1e-6);
    CHECK(m.uvs == NULL);
    nacre_mesh_data_free(ctx2, &m);
}

/* ------------------------------------------------------------------------------------------ */
/* Loader errors                                                                              */
/* ------------------------------------------------------------------------------------------ */

static void expect_load_error(const char *path, nacre_result code, const char *needle)
{
    nacre_mesh_data m;
    memset(&m, 0x5a, sizeof(m));
    nacre_result r = nacre_mesh_load(ctx2, path, &m);
    const char *msg = nacre_context_last_error(ctx2);
    CHECK(r == code);
    CHECK(strncmp(msg, path, strlen(path)) == 0); /* names the file first */
    CHECK(needle == NULL || contains(msg, needle));
    CHECK(strchr(msg, '\n') == NULL);
    if (r != code || (needle && !contains(msg, needle)) || strncmp(msg, path, strlen(path)))
        printf("load %s: result %d, message \"%s\" (wanted %d, \"%s\")\n", path, (int)r, msg,
               (int)code, needle ? needle : "");
    CHECK(m.positions == NULL && m.indices == NULL && m.vertex_count == 0);
}

static void test_load_errors(void)
{
    char missing[1024];
    snprintf(missing, sizeof(missing), "%s", tmp_path("does_not_exist.obj"));
    remove(missing);
    nacre_mesh_data m;
    CHECK(nacre_mesh_load(ctx2, missing, &m) == NACRE_ERROR_IO);
    char want[1200];
    snprintf(want, sizeof(want), "%s: cannot open: No such file or directory", missing);
    CHECK(strcmp(nacre_context_last_error(ctx2), want) == 0);

    const char *empty = tmp_path("empty.obj");
    write_text(empty, "");
    expect_load_error(empty, NACRE_ERROR_PARSE, "empty file");

    /* Deterministic garbage under every extension the loader knows. */
    unsigned char junk[4096];
    uint32_t state = 12345;
    for (size_t i = 0; i < sizeof(junk); i++) {
        state = state * 1664525u + 1013904223u;
        junk[i] = (unsigned char)(state >> 24);
    }
    const char *names[] = {"garbage.obj", "garbage.ply", "garbage.gltf", "garbage.glb",
                           "garbage.bin"};
    for (int i = 0; i < 5; i++) {
        const char *p = tmp_path(names[i]);
        write_bytes(p, junk, sizeof(junk));
        expect_load_error(p, NACRE_ERROR_PARSE, NULL);
    }
    /* Unknown property types: the body's size cannot be checked against the counts, and assimp
     * would size its arrays from them (tens of GB from a few hundred bytes). */
    const char *odd_ply = tmp_path("unknown_type.ply");
    write_text(odd_ply, "ply\nformat binary_little_endian 1.0\nelement vertex 2000000000\n"
                        "property float x\nproperty float y\nproperty float z\nproperty quad w\n"
                        "element face 1\nproperty list uchar int vertex_indices\nend_header\n0123456789");
    expect_load_error(odd_ply, NACRE_ERROR_PARSE, "unknown PLY property type 'quad'");
    write_text(odd_ply, "ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
                        "property float x\nproperty float y\nproperty float z\n"
                        "element face 1000000000\nproperty list uchar huge vertex_indices\nend_header\n0123");
    expect_load_error(odd_ply, NACRE_ERROR_PARSE, "unknown PLY list type 'uchar huge'");
    /* A PLY header followed by garbage */
    const char *junk_ply = tmp_path("garbage_body.ply");
    char body[4096 + 256];
    int hn = snprintf(body, 256, "ply\nformat binary_little_endian 1.0\nelement vertex 100\n"
                      "property float x\nproperty float y\nproperty float z\nelement face 50\n"
                      "property list uchar int vertex_indices\nend_header\n");
    memcpy(body + hn, junk, sizeof(junk));
    write_bytes(junk_ply, body, (size_t)hn + sizeof(junk));
    expect_load_error(junk_ply, NACRE_ERROR_PARSE, NULL);

    /* A PLY header cut short (assimp 5.2 would loop forever looking for its end). */
    const char *no_end = tmp_path("no_end_header.ply");
    write_text(no_end, "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_he");
    expect_load_error(no_end, NACRE_ERROR_PARSE, "PLY header has no end_header line");

    /* A count no file this small can hold (assimp would reserve memory for it first). */
    const char *huge = tmp_path("huge_count.ply");
    write_text(huge, "ply\nformat ascii 1.0\nelement vertex 99999999999\nproperty float x\n"
                     "property float y\nproperty float z\nelement face 1\n"
                     "property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
                     "3 0 1 2\n");
    expect_load_error(huge, NACRE_ERROR_PARSE, "truncated ASCII PLY");

    /* A malformed number (assimp would throw and leak): named with its line. */
    const char *nan_ply = tmp_path("bad_number.ply");
    write_text(nan_ply, "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                        "property float y\nproperty float z\nelement face 1\n"
                        "property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 x10\n"
                        "0 1 0\n3 0 1 2\n");
    expect_load_error(nan_ply, NACRE_ERROR_PARSE, "bad_number.ply:11: not a number: \"x10\"");

    /* A list count no file could hold (assimp would allocate for it first). */
    const char *big_list = tmp_path("big_list.ply");
    write_text(big_list, "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                         "property float y\nproperty float z\nelement face 2\n"
                         "property list uchar int vertex_indices\nend_header\n0 0 0\n\n1 0 0\n"
                         "0 1 0\n3 0 1 2\n4294967295 0 1 2\n");
    expect_load_error(big_list, NACRE_ERROR_PARSE,
                      "big_list.ply:15: a list of 4294967295 items cannot fit in the file");

    /* Truncated binary PLY: detected from the size the header promises. */
    nacre_mesh_data box = shape(NACRE_SHAPE_BOX, 2, 0);
    const char *trunc = tmp_path("truncated.ply");
    write_binary_ply(trunc, &box, false, 7);
    expect_load_error(trunc, NACRE_ERROR_PARSE, "truncated binary PLY");
    write_binary_ply(trunc, &box, false, 1000);
    expect_load_error(trunc, NACRE_ERROR_PARSE, "truncated binary PLY");
    nacre_mesh_data_free(ctx1, &box);

    const char *oor = tmp_path("out_of_range.ply");
    write_text(oor, "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                    "property float z\nelement face 2\nproperty list uchar int vertex_indices\n"
                    "end_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 99 3\n");
    expect_load_error(oor, NACRE_ERROR_PARSE, "face 1: index 99 out of range (vertex_count 4)");
    /* A polygon with a bad index: must be caught before assimp triangulates it. */
    write_text(oor, "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                    "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                    "end_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n5 0 1 2 3 123456789\n");
    expect_load_error(oor, NACRE_ERROR_PARSE, "index 123456789 out of range");

    const char *nan_obj = tmp_path("nan.obj");
    write_text(nan_obj, "v 0 0 0\nv 1 0 0\nv 0 nan 0\nf 1 2 3\n");
    expect_load_error(nan_obj, NACRE_ERROR_PARSE, "vertex 2: non-finite position");
    write_text(nan_obj, "v 0 0 0\nv 1 0 0\nv 0 1 0\nv inf 0 0\nf 1 2 3\nf 1 3 4\n");
    expect_load_error(nan_obj, NACRE_ERROR_PARSE, "non-finite position");

    const char *lines = tmp_path("lines.obj");
    write_text(lines, "v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2\nl 2 3\n");
    expect_load_error(lines, NACRE_ERROR_PARSE, "mesh has no triangles");

    const char *bad_face = tmp_path("bad_face.obj");
    write_text(bad_face, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n");
    expect_load_error(bad_face, NACRE_ERROR_PARSE, "bad_face.obj:4: index 7 out of range (3 vertices)");
    /* A bad index in a later group (assimp would leak the meshes built before it). */
    write_text(bad_face, "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\ng a\nf 1//1 2//1 3//1\ng b\n"
                         "f 3//1 2//1 1//2\n");
    expect_load_error(bad_face, NACRE_ERROR_PARSE, "bad_face.obj:8: index 2 out of range (1 normals)");
    write_text(bad_face, "v 0 0 0\nv 1 0 0\nf -1 -2 -3\nv 0 1 0\n");
    expect_load_error(bad_face, NACRE_ERROR_PARSE, "bad_face.obj:3: index -3 reaches before");

    CHECK(nacre_mesh_load(ctx2, NULL, &m) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(nacre_mesh_load(ctx2, empty, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(nacre_mesh_load(NULL, empty, &m) == NACRE_ERROR_INVALID_ARGUMENT);
}

/* ------------------------------------------------------------------------------------------ */
/* Shared scans (optional)                                                                    */
/* ------------------------------------------------------------------------------------------ */

typedef struct scan_expect {
    const char *file;
    uint32_t triangles, vertices, welded, unreferenced, degenerate;
    uint64_t boundary, nonmanifold;
} scan_expect;

static void test_shared_meshes(void)
{
    const char *dir = getenv("NACRE_MESH_DIR");
    char fallback[1024];
    if (!dir || !*dir) {
        snprintf(fallback, sizeof(fallback), "%s/../shared/meshes", NACRE_SOURCE_DIR);
        dir = fallback;
    }
    char probe[1200];
    snprintf(probe, sizeof(probe), "%s/bunny.ply", dir);
    FILE *f = fopen(probe, "rb");
    if (!f) {
        printf("note: %s not found; skipping the shared-mesh checks (set NACRE_MESH_DIR)\n", probe);
        return;
    }
    fclose(f);
    /* From shared/meshes/README.md: raw counts, then the welded figures it states. */
    const scan_expect table[] = {
        {"suzanne.ply", 968, 507, 0, 0, 0, 42, 0},
        {"suzanne.obj", 968, 0, 0, 0, 0, 42, 0},
        {"bunny.ply", 69451, 35947, 0, 1113, 0, 223, 0},
        {"buddha_100k.ply", 100000, 49950, 0, 0, 0, 0, 50},
        {"buddha_54k.ply", 54384, 26986, 26986 - 32, 0, 62, 0, 9},
        {"armadillo_100k.ply", 99976, 49990, 49990, 0, 0, 0, 0},
        {"lucy_100k.ply", 99970, 49987, 49987, 0, 0, 0, 0},
        {"dragon.ply", 871414, 437645, 435545, 0, 108, 0, 0},
    };
    for (size_t i = 0; i < sizeof(table) / sizeof(table[0]); i++) {
        const scan_expect *e = &table[i];
        char path[1200];
        snprintf(path, sizeof(path), "%s/%s", dir, e->file);
        nacre_mesh_data m = load_ok(path);
        if (!m.positions)
            continue;
        nacre_mesh_info info = analyze(&m);
        bool ok = info.triangle_count == e->triangles && info.boundary_edges == e->boundary &&
                  info.nonmanifold_edges == e->nonmanifold &&
                  info.unreferenced_vertices == e->unreferenced &&
                  info.degenerate_triangles == e->degenerate &&
                  (!e->vertices || info.vertex_count == e->vertices) &&
                  (!e->welded || info.welded_vertex_count == e->welded);
        CHECK(ok);
        printf("%s %s: %u tris, %u verts, %u welded, %u unreferenced, %u degenerate, "
               "%llu edges, %llu boundary, %llu non-manifold\n",
               ok ? "ok" : "MISMATCH", e->file, info.triangle_count, info.vertex_count,
               info.welded_vertex_count, info.unreferenced_vertices, info.degenerate_triangles,
               (unsigned long long)info.edge_count, (unsigned long long)info.boundary_edges,
               (unsigned long long)info.nonmanifold_edges);
        /* the scans wind counter-clockwise seen from outside */
        if (info.closed)
            CHECK(signed_volume(&m) > 0);
        nacre_mesh_data_free(ctx2, &m);
    }
}

/* Issue 29 item 12: a folder is not an "empty file"; an ASCII PLY face with one or two indices is
 * named as such, not called truncated. */
static void test_load_messages(void)
{
    const char *dir = tmp_path("folder.obj");
    mkdir(dir, 0755);
    expect_load_error(dir, NACRE_ERROR_IO, "is a directory");
    static const char *const head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                                    "property float z\nelement face %d\nproperty list uchar int vertex_indices\n"
                                    "end_header\n0 0 0\n1 0 0\n0 1 0\n%s";
    char text[1024];
    const char *p = tmp_path("short_face.ply");
    snprintf(text, sizeof(text), head, 2, "3 0 1 2\n1 0\n");
    write_text(p, text);
    expect_load_error(p, NACRE_ERROR_PARSE, "short_face.ply:14: face 1 has 1 index (need at least 3)");
    snprintf(text, sizeof(text), head, 1, "2 0 1\n");
    write_text(p, text);
    expect_load_error(p, NACRE_ERROR_PARSE, "short_face.ply:13: face 0 has 2 indices (need at least 3)");
    /* A real truncation is still called one. */
    snprintf(text, sizeof(text), head, 3, "3 0 1 2\n");
    write_text(p, text);
    expect_load_error(p, NACRE_ERROR_PARSE, "truncated ASCII PLY");
}

/* Issue 29 item 8: a polygon with many corners loads in time linear in its corners (assimp's
 * ear clipper took 38.6 s on 200,000 and lost a third of a 20,000-corner disc's area). */
static double mesh_area(const nacre_mesh_data *m)
{
    double area = 0;
    for (uint32_t t = 0; t < m->triangle_count; t++) {
        const float *a = m->positions + 3 * m->indices[3 * t];
        const float *b = m->positions + 3 * m->indices[3 * t + 1];
        const float *c = m->positions + 3 * m->indices[3 * t + 2];
        double u[3], v[3];
        for (int k = 0; k < 3; k++) {
            u[k] = (double)b[k] - a[k];
            v[k] = (double)c[k] - a[k];
        }
        double x = u[1] * v[2] - u[2] * v[1], y = u[2] * v[0] - u[0] * v[2], z = u[0] * v[1] - u[1] * v[0];
        area += 0.5 * sqrt(x * x + y * y + z * z);
    }
    return area;
}

static void write_polygon_obj(const char *path, int n, double r_even, double r_odd, const char *extra)
{
    FILE *f = fopen(path, "wb");
    CHECK(f != NULL);
    if (!f)
        return;
    for (int i = 0; i < n; i++) {
        double a = 2 * PI * i / n, r = i % 2 ? r_odd : r_even;
        fprintf(f, "v %.6f %.6f 0\n", r * cos(a), r * sin(a));
    }
    fputs("f", f);
    for (int i = 0; i < n; i++)
        fprintf(f, " %d", i + 1);
    fprintf(f, "\n%s", extra);
    fclose(f);
}

static void test_long_polygons(void)
{
    /* A disc of 100,000 corners (coordinates rounded to 6 digits, as exporters write them). */
    const int n = 100000;
    const char *p = tmp_path("disc.obj");
    write_polygon_obj(p, n, 1.0, 1.0, "");
    nacre_mesh_data m = {0};
    uint64_t t0 = 0;
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    t0 = (uint64_t)ts.tv_sec * 1000 + (uint64_t)ts.tv_nsec / 1000000;
    nacre_result r = nacre_mesh_load(ctx2, p, &m);
    clock_gettime(CLOCK_MONOTONIC, &ts);
    uint64_t ms = (uint64_t)ts.tv_sec * 1000 + (uint64_t)ts.tv_nsec / 1000000 - t0;
    printf("disc of %d corners: %llu ms\n", n, (unsigned long long)ms);
    CHECK(r == NACRE_OK);
    CHECK(m.triangle_count == (uint32_t)n - 2);
    CHECK_NEAR(mesh_area(&m), PI, 1e-4);
    CHECK(ms < 15000); /* quadratic: minutes under the sanitizers */
    /* Counter-clockwise seen from +z: normals point up. */
    CHECK(m.normals && m.normals[2] > 0.99f);
    nacre_mesh_data_free(ctx2, &m);

    /* A star (non-convex) of 200 corners is ear-clipped; the quad in the same file is cut too. */
    p = tmp_path("star.obj");
    write_polygon_obj(p, 200, 1.0, 0.5, "v 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\nf 201 202 203 204\n");
    r = nacre_mesh_load(ctx2, p, &m);
    CHECK(r == NACRE_OK);
    CHECK(m.triangle_count == 198 + 2);
    double star = 200 * 0.5 * 1.0 * 0.5 * sin(2 * PI / 200);
    CHECK_NEAR(mesh_area(&m), star + 1.0, 1e-4);
    nacre_mesh_data_free(ctx2, &m);

    /* A non-convex polygon too long to clip is refused by name. */
    p = tmp_path("star_long.obj");
    write_polygon_obj(p, 2000, 1.0, 0.5, "");
    expect_load_error(p, NACRE_ERROR_UNSUPPORTED, "face 0: a non-convex polygon of 2000 corners");
}

int main(void)
{
    nacre_context_desc d1 = {0}, d2 = {0};
    d1.threads = 1;
    d2.threads = 2;
    CHECK(nacre_context_create(&d1, &ctx1) == NACRE_OK);
    CHECK(nacre_context_create(&d2, &ctx2) == NACRE_OK);

    test_validate();
    test_normals();
    test_tangents();
    test_determinism();
    test_analyze();
    test_load_obj();
    test_load_ply();
    test_load_gltf();
    test_load_errors();
    test_load_messages();
    test_long_polygons();
    test_shared_meshes();

    nacre_context_destroy(ctx1);
    nacre_context_destroy(ctx2);
    return TEST_MAIN_END();
}
