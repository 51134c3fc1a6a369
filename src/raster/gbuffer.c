/*
 * gbuffer.c: G-buffer storage and the resolve from a visibility buffer.
 *
 * For each pixel the camera ray through the pixel centre is intersected with the plane of the
 * visible triangle (Moller-Trumbore, in double). The resulting barycentrics are exact for the
 * world-space triangle, so they are perspective-correct and independent of how the rasterizer
 * clipped or snapped it. They are clamped to the triangle (a pixel centre on a silhouette edge
 * may miss it by the snapping error) and interpolate position, shading normal, UV and tangent.
 *
 * Conventions: rays come from the inverse of proj * view (NDC z in [0, 1], y up; pixel centres at
 * +0.5, row 0 at the top). The geometric normal follows the winding (counter-clockwise = front);
 * seen from the back, both normals are flipped towards the camera and the tangent's handedness
 * is negated so that the bitangent w * (n x t) keeps pointing along +v. view_depth is -z_view.
 */
#include "raster/raster.h"

#include <string.h>

typedef struct dmat4 { double m[4][4]; } dmat4;

/* Gauss-Jordan with partial pivoting; false if singular. */
static bool dmat4_inverse(const dmat4 *a, dmat4 *out)
{
    double m[4][8];
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++) {
            m[i][j] = a->m[i][j];
            m[i][j + 4] = i == j ? 1.0 : 0.0;
        }
    for (int c = 0; c < 4; c++) {
        int p = c;
        for (int i = c + 1; i < 4; i++)
            if (fabs(m[i][c]) > fabs(m[p][c]))
                p = i;
        if (!(fabs(m[p][c]) > 0.0))
            return false;
        if (p != c)
            for (int j = 0; j < 8; j++) {
                double t = m[c][j];
                m[c][j] = m[p][j];
                m[p][j] = t;
            }
        double inv = 1.0 / m[c][c];
        for (int j = 0; j < 8; j++)
            m[c][j] *= inv;
        for (int i = 0; i < 4; i++) {
            if (i == c || m[i][c] == 0.0)
                continue;
            double s = m[i][c];
            for (int j = 0; j < 8; j++)
                m[i][j] -= s * m[c][j];
        }
    }
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++)
            out->m[i][j] = m[i][j + 4];
    return true;
}

static void unproject(const dmat4 *inv, double x, double y, double z, double out[3])
{
    double h[4];
    for (int i = 0; i < 4; i++)
        h[i] = inv->m[i][0] * x + inv->m[i][1] * y + inv->m[i][2] * z + inv->m[i][3];
    for (int i = 0; i < 3; i++)
        out[i] = h[i] / h[3];
}

nacre_result nc_gbuffer_resize(nacre_context *ctx, nc_gbuffer *gb, int32_t width, int32_t height)
{
    if (!gb || width < 1 || height < 1 || width > 16384 || height > 16384)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "G-buffer: invalid size %dx%d",
                       (int)width, (int)height);
    if (gb->position && gb->width == width && gb->height == height)
        return NACRE_OK;
    nc_gbuffer_free(ctx, gb);
    size_t n = (size_t)width * (size_t)height;
    gb->position = nc_alloc(ctx, n * 3 * sizeof(float));
    gb->normal = nc_alloc(ctx, n * 3 * sizeof(float));
    gb->geo_normal = nc_alloc(ctx, n * 3 * sizeof(float));
    gb->uv = nc_alloc(ctx, n * 2 * sizeof(float));
    gb->tangent = nc_alloc(ctx, n * 4 * sizeof(float));
    gb->view_depth = nc_alloc(ctx, n * sizeof(float));
    gb->object = nc_alloc(ctx, n * sizeof(uint32_t));
    gb->material = nc_alloc(ctx, n * sizeof(uint32_t));
    gb->triangle = nc_alloc(ctx, n * sizeof(uint32_t));
    if (!gb->position || !gb->normal || !gb->geo_normal || !gb->uv || !gb->tangent ||
        !gb->view_depth || !gb->object || !gb->material || !gb->triangle) {
        nc_gbuffer_free(ctx, gb);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    gb->width = width;
    gb->height = height;
    return NACRE_OK;
}

void nc_gbuffer_free(nacre_context *ctx, nc_gbuffer *gb)
{
    if (!gb)
        return;
    nc_free(ctx, gb->position);
    nc_free(ctx, gb->normal);
    nc_free(ctx, gb->geo_normal);
    nc_free(ctx, gb->uv);
    nc_free(ctx, gb->tangent);
    nc_free(ctx, gb->view_depth);
    nc_free(ctx, gb->object);
    nc_free(ctx, gb->material);
    nc_free(ctx, gb->triangle);
    memset(gb, 0, sizeof(*gb));
}

typedef struct ray_setup {
    dmat4 inv_vp;      /* clip -> world */
    double eye[3];     /* perspective: centre of projection */
    double zrow[4];    /* view row 2: view_depth = -(zrow . (p, 1)) */
    double sx, sy;     /* pixel -> NDC */
    bool ortho;
    int32_t width;
} ray_setup;

static inline void pixel_ray(const ray_setup *rs, int x, int y, double o[3], double d[3])
{
    double nx = (x + 0.5) * rs->sx - 1.0, ny = 1.0 - (y + 0.5) * rs->sy;
    double pn[3];
    unproject(&rs->inv_vp, nx, ny, 0.0, pn);
    if (rs->ortho) {
        double pf[3];
        unproject(&rs->inv_vp, nx, ny, 1.0, pf);
        for (int i = 0; i < 3; i++) {
            o[i] = pn[i];
            d[i] = pf[i] - pn[i];
        }
    } else {
        for (int i = 0; i < 3; i++) {
            o[i] = rs->eye[i];
            d[i] = pn[i] - rs->eye[i];
        }
    }
}

static inline void sub3(const double a[3], const double b[3], double r[3])
{
    r[0] = a[0] - b[0]; r[1] = a[1] - b[1]; r[2] = a[2] - b[2];
}
static inline void cross3(const double a[3], const double b[3], double r[3])
{
    r[0] = a[1] * b[2] - a[2] * b[1];
    r[1] = a[2] * b[0] - a[0] * b[2];
    r[2] = a[0] * b[1] - a[1] * b[0];
}
static inline double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* One covered pixel. */
static void resolve_pixel(const ray_setup *rs, const nc_gbuffer_source *src, uint32_t tri, int x,
                          int y, size_t p, nc_gbuffer *out)
{
    const uint32_t *ix = src->indices + 3 * (size_t)tri;
    uint32_t v[3] = {ix[0], ix[1], ix[2]};
    double P[3][3];
    for (int k = 0; k < 3; k++)
        for (int c = 0; c < 3; c++)
            P[k][c] = src->positions[3 * (size_t)v[k] + c];
    double o[3], d[3], e1[3], e2[3], s[3], pv[3], qv[3];
    pixel_ray(rs, x, y, o, d);
    sub3(P[1], P[0], e1);
    sub3(P[2], P[0], e2);
    sub3(o, P[0], s);
    cross3(d, e2, pv);
    double det = dot3(e1, pv);
    cross3(s, e1, qv);
    double b1 = dot3(s, pv) / det, b2 = dot3(d, qv) / det;
    double b0 = 1.0 - b1 - b2;
    if (!(isfinite(b1) && isfinite(b2))) {
        b0 = b1 = b2 = 1.0 / 3.0;
    } else if (b0 < 0.0 || b1 < 0.0 || b2 < 0.0) {
        b0 = b0 > 0.0 ? b0 : 0.0;
        b1 = b1 > 0.0 ? b1 : 0.0;
        b2 = b2 > 0.0 ? b2 : 0.0;
        double sum = b0 + b1 + b2;
        b0 /= sum; b1 /= sum; b2 /= sum;
    }
    const double b[3] = {b0, b1, b2};

    double pos[3];
    for (int c = 0; c < 3; c++)
        pos[c] = b0 * P[0][c] + b1 * P[1][c] + b2 * P[2][c];
    double ng[3];
    cross3(e1, e2, ng);
    double lg = sqrt(dot3(ng, ng));
    if (lg > 0.0) {
        ng[0] /= lg; ng[1] /= lg; ng[2] /= lg;
    } else { /* degenerate: face the camera */
        double ld = sqrt(dot3(d, d));
        ng[0] = -d[0] / ld; ng[1] = -d[1] / ld; ng[2] = -d[2] / ld;
    }
    bool back = dot3(ng, d) > 0.0;
    double n[3] = {ng[0], ng[1], ng[2]};
    if (src->normals) {
        double a[3] = {0, 0, 0};
        for (int k = 0; k < 3; k++)
            for (int c = 0; c < 3; c++)
                a[c] += b[k] * src->normals[3 * (size_t)v[k] + c];
        double la = sqrt(dot3(a, a));
        if (la > 0.0 && isfinite(la)) {
            n[0] = a[0] / la; n[1] = a[1] / la; n[2] = a[2] / la;
        }
    }
    double uv[2] = {0, 0};
    if (src->uvs)
        for (int k = 0; k < 3; k++) {
            uv[0] += b[k] * src->uvs[2 * (size_t)v[k]];
            uv[1] += b[k] * src->uvs[2 * (size_t)v[k] + 1];
        }
    double t[3] = {0, 0, 0}, hand = 1.0;
    if (src->tangents) {
        double w = 0.0;
        for (int k = 0; k < 3; k++) {
            const float *tk = src->tangents + 4 * (size_t)v[k];
            for (int c = 0; c < 3; c++)
                t[c] += b[k] * tk[c];
            w += b[k] * tk[3];
        }
        hand = w < 0.0 ? -1.0 : 1.0;
    } else if (src->uvs) {
        /* dp/du of the triangle: solves e1 = dp/du du1 + dp/dv dv1 (and e2 likewise). */
        const float *u0 = src->uvs + 2 * (size_t)v[0], *u1 = src->uvs + 2 * (size_t)v[1],
                    *u2 = src->uvs + 2 * (size_t)v[2];
        double du1 = u1[0] - u0[0], dv1 = u1[1] - u0[1], du2 = u2[0] - u0[0], dv2 = u2[1] - u0[1];
        double den = du1 * dv2 - du2 * dv1;
        if (den != 0.0) {
            for (int c = 0; c < 3; c++)
                t[c] = (e1[c] * dv2 - e2[c] * dv1) / den;
            /* Handedness: whether dp/dv agrees with ng x t. */
            double bt[3], nt[3];
            for (int c = 0; c < 3; c++)
                bt[c] = (e2[c] * du1 - e1[c] * du2) / den;
            cross3(ng, t, nt);
            hand = dot3(nt, bt) < 0.0 ? -1.0 : 1.0;
        }
    }
    /* Gram-Schmidt against the shading normal. */
    double tn = dot3(t, n);
    for (int c = 0; c < 3; c++)
        t[c] -= tn * n[c];
    double lt = sqrt(dot3(t, t));
    if (lt > 1e-12 && isfinite(lt)) {
        t[0] /= lt; t[1] /= lt; t[2] /= lt;
    } else {
        nc_vec3 tt, bb;
        nc_basis(nc_v3((float)n[0], (float)n[1], (float)n[2]), &tt, &bb);
        t[0] = tt.x; t[1] = tt.y; t[2] = tt.z;
        hand = 1.0;
    }
    if (back) {
        for (int c = 0; c < 3; c++) {
            n[c] = -n[c];
            ng[c] = -ng[c];
        }
        hand = -hand;
    }
    for (int c = 0; c < 3; c++) {
        out->position[3 * p + c] = (float)pos[c];
        out->normal[3 * p + c] = (float)n[c];
        out->geo_normal[3 * p + c] = (float)ng[c];
        out->tangent[4 * p + c] = (float)t[c];
    }
    out->tangent[4 * p + 3] = (float)hand;
    out->uv[2 * p] = (float)uv[0];
    out->uv[2 * p + 1] = (float)uv[1];
    out->view_depth[p] = (float)-(rs->zrow[0] * pos[0] + rs->zrow[1] * pos[1] +
                                  rs->zrow[2] * pos[2] + rs->zrow[3]);
}

/* Empty pixels [p, q): one memset per array rather than nine small stores per pixel. */
static void clear_run(nc_gbuffer *out, size_t p, size_t q)
{
    size_t n = q - p;
    memset(out->position + 3 * p, 0, 3 * n * sizeof(float));
    memset(out->normal + 3 * p, 0, 3 * n * sizeof(float));
    memset(out->geo_normal + 3 * p, 0, 3 * n * sizeof(float));
    memset(out->uv + 2 * p, 0, 2 * n * sizeof(float));
    memset(out->tangent + 4 * p, 0, 4 * n * sizeof(float));
    memset(out->material + p, 0, n * sizeof(uint32_t));
    memset(out->triangle + p, 0, n * sizeof(uint32_t));
    for (size_t i = p; i < q; i++) {
        out->view_depth[i] = INFINITY;
        out->object[i] = NC_NO_OBJECT;
    }
}

/* Neighbouring pixels mostly see different triangles of a dense mesh, whose vertices are far
 * apart in memory: fetch the indices INDEX_AHEAD pixels ahead and the vertex data VERTEX_AHEAD
 * pixels ahead, so the misses overlap instead of following one another. */
#define INDEX_AHEAD 16
#define VERTEX_AHEAD 6

static inline void prefetch_indices(const nc_gbuffer_source *sources, uint32_t source_count,
                                    uint32_t obj, uint32_t tri)
{
    if (obj < source_count)
        __builtin_prefetch(sources[obj].indices + 3 * (size_t)tri);
}

static inline void prefetch_vertices(const nc_gbuffer_source *sources, uint32_t source_count,
                                     uint32_t obj, uint32_t tri)
{
    if (obj >= source_count)
        return;
    const nc_gbuffer_source *s = &sources[obj];
    const uint32_t *ix = s->indices + 3 * (size_t)tri;
    for (int k = 0; k < 3; k++) {
        size_t v = ix[k];
        __builtin_prefetch(s->positions + 3 * v);
        if (s->normals)
            __builtin_prefetch(s->normals + 3 * v);
        if (s->uvs)
            __builtin_prefetch(s->uvs + 2 * v);
        if (s->tangents)
            __builtin_prefetch(s->tangents + 4 * v);
    }
}

nacre_result nc_gbuffer_resolve(nacre_context *ctx, const nc_raster_view *view, const nc_vis_buffer *vis,
                                const nc_gbuffer_source *sources, uint32_t source_count,
                                nc_gbuffer *out)
{
    if (!view || !vis || !out || !vis->object || !out->position)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "G-buffer resolve: missing argument");
    if (vis->width != view->width || vis->height != view->height || out->width != vis->width ||
        out->height != vis->height)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "G-buffer resolve: view %dx%d, visibility %dx%d, G-buffer %dx%d differ",
                       (int)view->width, (int)view->height, (int)vis->width, (int)vis->height,
                       (int)out->width, (int)out->height);
    if (source_count && !sources)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "G-buffer resolve: sources is NULL");
    for (uint32_t s = 0; s < source_count; s++)
        if (!sources[s].positions || !sources[s].indices)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                           "G-buffer resolve: source %u: positions or indices are NULL", s);

    ray_setup rs;
    memset(&rs, 0, sizeof(rs));
    dmat4 v, p, vp, iv;
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++) {
            v.m[i][j] = view->view.m[i][j];
            p.m[i][j] = view->proj.m[i][j];
        }
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++) {
            double s = 0.0;
            for (int k = 0; k < 4; k++)
                s += p.m[i][k] * v.m[k][j];
            vp.m[i][j] = s;
        }
    if (!dmat4_inverse(&vp, &rs.inv_vp) || !dmat4_inverse(&v, &iv))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "G-buffer resolve: singular view or projection");
    for (int i = 0; i < 3; i++)
        rs.eye[i] = iv.m[i][3] / iv.m[3][3];
    for (int j = 0; j < 4; j++)
        rs.zrow[j] = v.m[2][j];
    rs.sx = 2.0 / view->width;
    rs.sy = 2.0 / view->height;
    rs.ortho = view->orthographic;
    rs.width = view->width;

    int h = vis->height, w = vis->width;
    int threads = nc_threads(ctx);
    bool bad = false;
    #pragma omp parallel for num_threads(threads) schedule(dynamic, 4) reduction(|| : bad)
    for (int y = 0; y < h; y++) {
        size_t row = (size_t)y * (size_t)w;
        const uint32_t *objs = vis->object + row, *tris = vis->triangle + row;
        int x = 0;
        while (x < w) {
            if (objs[x] == NC_NO_OBJECT) {
                int e = x + 1;
                while (e < w && objs[e] == NC_NO_OBJECT)
                    e++;
                clear_run(out, row + (size_t)x, row + (size_t)e);
                x = e;
                continue;
            }
            if (x + INDEX_AHEAD < w)
                prefetch_indices(sources, source_count, objs[x + INDEX_AHEAD], tris[x + INDEX_AHEAD]);
            if (x + VERTEX_AHEAD < w)
                prefetch_vertices(sources, source_count, objs[x + VERTEX_AHEAD], tris[x + VERTEX_AHEAD]);
            size_t px = row + (size_t)x;
            uint32_t obj = objs[x];
            if (obj >= source_count) {
                bad = true;
                clear_run(out, px, px + 1);
                x++;
                continue;
            }
            const nc_gbuffer_source *src = &sources[obj];
            uint32_t tri = tris[x];
            resolve_pixel(&rs, src, tri, x, y, px, out);
            out->object[px] = obj;
            out->material[px] = src->material_index;
            out->triangle[px] = tri;
            x++;
        }
    }
    if (bad)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "G-buffer resolve: visibility buffer names an object beyond the %u sources",
                       source_count);
    return NACRE_OK;
}
