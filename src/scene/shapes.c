/*
 * shapes.c: procedural meshes (UV sphere, box, plane, torus) with positions, normals, UVs and
 * tangents.
 *
 * Every shape is a set of (u, v) grids. Along a grid, u follows the tangent T and v the
 * bitangent B with T x B = the outward normal, and each cell splits into two triangles wound
 * counter-clockwise seen from outside, so the tangent handedness w is +1 everywhere. UVs span
 * [0, 1] with v growing upwards (towards +y, or around the tube for the torus).
 *
 * Watertightness: a closed shape duplicates vertices along UV seams (and the sphere at its
 * poles, one pole copy per segment). Those copies come from the very same expressions (angles
 * from the index modulo the count, box coordinates from one per-axis function of the grid
 * index, poles exactly (0, +-r, 0)), so they are bit-identical and weld exactly. Trigonometry is
 * done in double and rounded once to float. Lengths are in scene units.
 */
#include "scene/mesh_private.h"

#include <math.h>
#include <string.h>

#define SHAPE_MAX_SEGMENTS 65536u
#define SHAPE_TWO_PI 6.283185307179586476925

nacre_shape_desc nacre_shape_desc_defaults(nacre_shape_type type)
{
    nacre_shape_desc d;
    memset(&d, 0, sizeof(d));
    d.type = type;
    d.radius = 1.0f;
    d.minor_radius = 0.25f;
    d.size[0] = d.size[1] = d.size[2] = 1.0f;
    d.segments = 64;
    d.rings = 32;
    switch (type) {
    case NACRE_SHAPE_BOX:
        d.segments = 1;
        break;
    case NACRE_SHAPE_PLANE:
        d.size[0] = d.size[2] = 10.0f;
        d.size[1] = 0.0f;
        d.segments = 1;
        break;
    case NACRE_SHAPE_SPHERE:
    case NACRE_SHAPE_TORUS:
        break;
    }
    return d;
}

/* A mesh being filled: vertex and index cursors over arrays sized up front. */
typedef struct builder {
    nacre_mesh_data *m;
    uint32_t nv; /* vertices written */
    size_t ni;   /* indices written */
} builder;

static uint32_t put_vertex(builder *b, const double p[3], const double n[3], double u, double v,
                           const double t[3])
{
    uint32_t i = b->nv++;
    nacre_mesh_data *m = b->m;
    for (int k = 0; k < 3; k++) {
        m->positions[i * 3 + (uint32_t)k] = (float)p[k];
        m->normals[i * 3 + (uint32_t)k] = (float)n[k];
        m->tangents[i * 4 + (uint32_t)k] = (float)t[k];
    }
    m->tangents[i * 4 + 3] = 1.0f;
    m->uvs[i * 2] = (float)u;
    m->uvs[i * 2 + 1] = (float)v;
    return i;
}

static inline void put_triangle(builder *b, uint32_t a, uint32_t c, uint32_t d)
{
    b->m->indices[b->ni++] = a;
    b->m->indices[b->ni++] = c;
    b->m->indices[b->ni++] = d;
}

/* Triangles of a (cols x rows)-cell grid whose vertex (i, j) is base + j * (cols + 1) + i, with
 * i along T and j along B. */
static void put_grid(builder *b, uint32_t base, uint32_t cols, uint32_t rows)
{
    for (uint32_t j = 0; j < rows; j++)
        for (uint32_t i = 0; i < cols; i++) {
            uint32_t v00 = base + j * (cols + 1) + i, v10 = v00 + 1;
            uint32_t v01 = v00 + cols + 1, v11 = v01 + 1;
            put_triangle(b, v00, v10, v11);
            put_triangle(b, v00, v11, v01);
        }
}

static bool positive_finite(float x) { return isfinite(x) && x > 0.0f; }

static nacre_result check_count(nacre_context *ctx, const char *field, uint32_t value,
                                uint32_t min)
{
    if (value < min || value > SHAPE_MAX_SEGMENTS)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "shape: %s: %u out of range (%u..%u)",
                       field, (unsigned)value, (unsigned)min, (unsigned)SHAPE_MAX_SEGMENTS);
    return NACRE_OK;
}

/* Sphere: S segments around y, R rings from the north pole (v = 1) to the south pole (v = 0).
 * Rows j = 1 .. R-1 are rings of S + 1 vertices (the last copies the first at u = 1); each pole
 * has S copies at the segment centres, so every pole triangle gets its own u. */
static void build_sphere(builder *b, double r, uint32_t S, uint32_t R)
{
    const double dphi = SHAPE_TWO_PI / S;
    const double pole_n[2][3] = {{0, 1, 0}, {0, -1, 0}};
    uint32_t top = b->nv;
    for (uint32_t i = 0; i < S; i++) {
        double phi = dphi * (i + 0.5);
        double p[3] = {0, r, 0}, t[3] = {-sin(phi), 0, -cos(phi)};
        put_vertex(b, p, pole_n[0], (i + 0.5) / S, 1.0, t);
    }
    uint32_t rings = b->nv;
    for (uint32_t j = 1; j < R; j++) {
        double theta = SHAPE_TWO_PI * 0.5 * j / R;
        double st = sin(theta), ct = cos(theta);
        for (uint32_t i = 0; i <= S; i++) {
            double phi = dphi * (i % S);
            double sp = sin(phi), cp = cos(phi);
            double n[3] = {st * cp, ct, -st * sp};
            double p[3] = {r * n[0], r * n[1], r * n[2]};
            double t[3] = {-sp, 0, -cp};
            put_vertex(b, p, n, (double)i / S, 1.0 - (double)j / R, t);
        }
    }
    uint32_t bottom = b->nv;
    for (uint32_t i = 0; i < S; i++) {
        double phi = dphi * (i + 0.5);
        double p[3] = {0, -r, 0}, t[3] = {-sin(phi), 0, -cos(phi)};
        put_vertex(b, p, pole_n[1], (i + 0.5) / S, 0.0, t);
    }

    /* Going south (+j) and east (+i): south x east is outward, so (a, south of a, east of a). */
    const uint32_t row = S + 1;
    for (uint32_t i = 0; i < S; i++)
        put_triangle(b, top + i, rings + i, rings + i + 1);
    for (uint32_t j = 1; j + 1 < R; j++)
        for (uint32_t i = 0; i < S; i++) {
            uint32_t a = rings + (j - 1) * row + i, c = a + 1;
            uint32_t s = a + row, sc = s + 1;
            put_triangle(b, a, s, c);
            put_triangle(b, c, s, sc);
        }
    uint32_t last = rings + (R - 2) * row;
    for (uint32_t i = 0; i < S; i++)
        put_triangle(b, last + i, bottom + i, last + i + 1);
}

/* Coordinate of grid index k (0..N) along an axis of extent `size`, centred at 0. Every face
 * that reaches a given edge evaluates the same expression, so edges weld exactly. */
static inline double grid_coord(uint32_t k, uint32_t N, float size)
{
    return ((double)k / N - 0.5) * size;
}

/* One face of a box: outward axis `na` with sign `ns`, u along axis `ua` (sign `us`), v along
 * axis `va` (sign `vs`); the three axes are distinct and (u dir) x (v dir) = normal. */
typedef struct box_face {
    int na, ns, ua, us, va, vs;
} box_face;

static void build_box_faces(builder *b, const box_face *faces, int face_count, const float size[3],
                            uint32_t N)
{
    for (int f = 0; f < face_count; f++) {
        const box_face *F = &faces[f];
        double n[3] = {0, 0, 0}, t[3] = {0, 0, 0};
        n[F->na] = F->ns;
        t[F->ua] = F->us;
        uint32_t base = b->nv;
        for (uint32_t j = 0; j <= N; j++)
            for (uint32_t i = 0; i <= N; i++) {
                uint32_t k[3];
                k[F->na] = F->ns > 0 ? N : 0;
                k[F->ua] = F->us > 0 ? i : N - i;
                k[F->va] = F->vs > 0 ? j : N - j;
                double p[3];
                for (int a = 0; a < 3; a++)
                    p[a] = grid_coord(k[a], N, size[a]);
                put_vertex(b, p, n, (double)i / N, (double)j / N, t);
            }
        put_grid(b, base, N, N);
    }
}

/* Torus: major circle in the xz plane, S segments along it (u), R rings around the tube (v),
 * both seams duplicated. */
static void build_torus(builder *b, double major, double minor, uint32_t S, uint32_t R)
{
    uint32_t base = b->nv;
    for (uint32_t j = 0; j <= R; j++) {
        double psi = SHAPE_TWO_PI * (j % R) / R;
        double sq = sin(psi), cq = cos(psi);
        for (uint32_t i = 0; i <= S; i++) {
            double phi = SHAPE_TWO_PI * (i % S) / S;
            double sp = sin(phi), cp = cos(phi);
            double ring = major + minor * cq;
            double p[3] = {ring * cp, minor * sq, -ring * sp};
            double n[3] = {cq * cp, sq, -cq * sp};
            double t[3] = {-sp, 0, -cp};
            put_vertex(b, p, n, (double)i / S, (double)j / R, t);
        }
    }
    put_grid(b, base, S, R);
}

nacre_result nacre_mesh_make_shape(nacre_context *ctx, const nacre_shape_desc *desc,
                                   nacre_mesh_data *out)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!desc || !out)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "shape: %s is NULL",
                       desc ? "output mesh" : "desc");
    memset(out, 0, sizeof(*out));
    nacre_result r = NACRE_OK;
    uint64_t nv = 0, nt = 0;
    const nacre_shape_desc *d = desc;
    switch (d->type) {
    case NACRE_SHAPE_SPHERE:
        if (!positive_finite(d->radius))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "shape: radius: must be positive");
        if ((r = check_count(ctx, "segments", d->segments, 3)) != NACRE_OK ||
            (r = check_count(ctx, "rings", d->rings, 2)) != NACRE_OK)
            return r;
        nv = 2ull * d->segments + (uint64_t)(d->rings - 1) * (d->segments + 1);
        nt = 2ull * d->segments * (d->rings - 1);
        break;
    case NACRE_SHAPE_BOX:
        for (int k = 0; k < 3; k++)
            if (!positive_finite(d->size[k]))
                return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                               "shape: size[%d]: must be positive", k);
        if ((r = check_count(ctx, "segments", d->segments, 1)) != NACRE_OK)
            return r;
        nv = 6ull * (d->segments + 1) * (d->segments + 1);
        nt = 12ull * d->segments * d->segments;
        break;
    case NACRE_SHAPE_PLANE:
        if (!positive_finite(d->size[0]) || !positive_finite(d->size[2]))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "shape: size[%d]: must be positive",
                           positive_finite(d->size[0]) ? 2 : 0);
        if ((r = check_count(ctx, "segments", d->segments, 1)) != NACRE_OK)
            return r;
        nv = (uint64_t)(d->segments + 1) * (d->segments + 1);
        nt = 2ull * d->segments * d->segments;
        break;
    case NACRE_SHAPE_TORUS:
        if (!positive_finite(d->radius))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "shape: radius: must be positive");
        if (!positive_finite(d->minor_radius))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                           "shape: minor_radius: must be positive");
        /* A tube as thick as the hole self-intersects: no longer a closed surface. */
        if (d->minor_radius >= d->radius)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                           "shape: minor_radius: must be smaller than radius (%g >= %g)",
                           (double)d->minor_radius, (double)d->radius);
        if ((r = check_count(ctx, "segments", d->segments, 3)) != NACRE_OK ||
            (r = check_count(ctx, "rings", d->rings, 3)) != NACRE_OK)
            return r;
        nv = (uint64_t)(d->segments + 1) * (d->rings + 1);
        nt = 2ull * d->segments * d->rings;
        break;
    default:
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "shape: type: unknown (%d)",
                       (int)d->type);
    }
    if (nv > UINT32_MAX || nt > NC_MESH_MAX_TRIANGLES)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "shape: segments, rings: too many triangles (%llu)",
                       (unsigned long long)nt);

    nacre_mesh_data m;
    memset(&m, 0, sizeof(m));
    m.vertex_count = (uint32_t)nv;
    m.triangle_count = (uint32_t)nt;
    m.positions = nc_alloc(ctx, (size_t)nv * 3 * sizeof(float));
    m.normals = nc_alloc(ctx, (size_t)nv * 3 * sizeof(float));
    m.uvs = nc_alloc(ctx, (size_t)nv * 2 * sizeof(float));
    m.tangents = nc_alloc(ctx, (size_t)nv * 4 * sizeof(float));
    m.indices = nc_alloc(ctx, (size_t)nt * 3 * sizeof(uint32_t));
    if (!m.positions || !m.normals || !m.uvs || !m.tangents || !m.indices) {
        nacre_mesh_data_free(ctx, &m);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }

    builder b = {&m, 0, 0};
    switch (d->type) {
    case NACRE_SHAPE_SPHERE:
        build_sphere(&b, d->radius, d->segments, d->rings);
        break;
    case NACRE_SHAPE_BOX: {
        static const box_face faces[6] = {
            {0, +1, 2, -1, 1, +1}, /* +x: u towards -z, v up */
            {0, -1, 2, +1, 1, +1}, /* -x: u towards +z */
            {1, +1, 0, +1, 2, -1}, /* +y: u towards +x, v towards -z */
            {1, -1, 0, +1, 2, +1}, /* -y: u towards +x, v towards +z */
            {2, +1, 0, +1, 1, +1}, /* +z: u towards +x, v up */
            {2, -1, 0, -1, 1, +1}, /* -z: u towards -x */
        };
        build_box_faces(&b, faces, 6, d->size, d->segments);
        break;
    }
    case NACRE_SHAPE_PLANE: {
        static const box_face top = {1, +1, 0, +1, 2, -1};
        const float size[3] = {d->size[0], 0.0f, d->size[2]};
        /* grid_coord(k, N, 0) is 0 for every k: the plane lies at y = 0. */
        build_box_faces(&b, &top, 1, size, d->segments);
        break;
    }
    case NACRE_SHAPE_TORUS:
        build_torus(&b, d->radius, d->minor_radius, d->segments, d->rings);
        break;
    }
    *out = m;
    return NACRE_OK;
}
