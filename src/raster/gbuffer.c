/*
 * gbuffer.c: G-buffer storage and the resolve from a visibility buffer.
 *
 * For each pixel the camera ray through the pixel centre is intersected with the plane of the
 * visible triangle, in double. The resulting barycentrics are exact for the world-space triangle,
 * so they are perspective-correct and independent of how the rasterizer clipped or snapped it.
 * They are clamped to the triangle (a pixel centre on a silhouette edge may miss it by the
 * snapping error) and interpolate position, shading normal and UV. Rows run in
 * parallel; per-triangle terms are set up once per run of pixels on the same triangle, and with
 * AVX2 four pixels are evaluated at once. Empty pixels are written with streaming stores.
 *
 * Conventions: rays come from the inverse of proj * view (NDC z in [0, 1], y up; pixel centres at
 * +0.5, row 0 at the top). The geometric normal follows the winding (counter-clockwise = front);
 * seen from the back, both normals are flipped towards the camera. view_depth is -z_view.
 * Tangent frames are not stored: the layered method, their one user, builds them per pixel from
 * the triangle's UV gradients (render/method_layered.c).
 */
#include "raster/raster.h"

#include <string.h>
#ifdef __AVX__
#include <immintrin.h>
#endif

typedef struct dmat4 {
    double m[4][4];
} dmat4;

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
    gb->view_depth = nc_alloc(ctx, n * sizeof(float));
    gb->object = nc_alloc(ctx, n * sizeof(uint32_t));
    gb->material = nc_alloc(ctx, n * sizeof(uint32_t));
    gb->triangle = nc_alloc(ctx, n * sizeof(uint32_t));
    gb->row_span = nc_alloc(ctx, 2 * (size_t)height * sizeof(int32_t));
    if (!gb->position || !gb->normal || !gb->geo_normal || !gb->uv ||
        !gb->view_depth || !gb->object || !gb->material || !gb->triangle || !gb->row_span) {
        nc_gbuffer_free(ctx, gb);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    for (int32_t y = 0; y < height; y++) { /* new memory: every pixel needs writing */
        gb->row_span[2 * y] = 0;
        gb->row_span[2 * y + 1] = width;
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
    nc_free(ctx, gb->view_depth);
    nc_free(ctx, gb->object);
    nc_free(ctx, gb->material);
    nc_free(ctx, gb->triangle);
    nc_free(ctx, gb->row_span);
    memset(gb, 0, sizeof(*gb));
}

typedef struct ray_setup {
    dmat4 inv_vp;   /* clip -> world */
    double eye[3];  /* perspective: centre of projection */
    double zrow[4]; /* view row 2: view_depth = -(zrow . (p, 1)) */
    double sx, sy;  /* pixel -> NDC */
    bool ortho;
} ray_setup;

/* Small by-value vectors: kept in registers (arrays on the stack caused store-forwarding
 * stalls in this loop). */
typedef struct dv3 {
    double x, y, z;
} dv3;

static inline dv3 dv(double x, double y, double z)
{
    dv3 r = {x, y, z};
    return r;
}
static inline dv3 dsub(dv3 a, dv3 b) { return dv(a.x - b.x, a.y - b.y, a.z - b.z); }
static inline dv3 dscale(dv3 a, double s) { return dv(a.x * s, a.y * s, a.z * s); }
static inline double ddot(dv3 a, dv3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static inline dv3 dcross(dv3 a, dv3 b)
{
    return dv(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
static inline dv3 dload(const float *p) { return dv(p[0], p[1], p[2]); }
/* Unit vector, or `fallback` when a has no usable length. */
static inline dv3 dnormalize(dv3 a, dv3 fallback)
{
    double l2 = ddot(a, a);
    if (!(l2 > 1e-300) || !isfinite(l2))
        return fallback;
    return dscale(a, 1.0 / sqrt(l2));
}

static inline dv3 unproject_pt(const dmat4 *m, double x, double y, double z)
{
    double h0 = m->m[0][0] * x + m->m[0][1] * y + m->m[0][2] * z + m->m[0][3];
    double h1 = m->m[1][0] * x + m->m[1][1] * y + m->m[1][2] * z + m->m[1][3];
    double h2 = m->m[2][0] * x + m->m[2][1] * y + m->m[2][2] * z + m->m[2][3];
    double h3 = m->m[3][0] * x + m->m[3][1] * y + m->m[3][2] * z + m->m[3][3];
    double iw = 1.0 / h3;
    return dv(h0 * iw, h1 * iw, h2 * iw);
}

/* The camera ray through pixel (x, y). Perspective: o is the eye and d a positive multiple of
 * the direction (unprojected homogeneously, no division: only its direction matters). */
static inline void pixel_ray(const ray_setup *rs, int x, int y, dv3 *o, dv3 *d)
{
    double nx = (x + 0.5) * rs->sx - 1.0, ny = 1.0 - (y + 0.5) * rs->sy;
    if (rs->ortho) {
        dv3 pn = unproject_pt(&rs->inv_vp, nx, ny, 0.0);
        *o = pn;
        *d = dsub(unproject_pt(&rs->inv_vp, nx, ny, 1.0), pn);
        return;
    }
    const dmat4 *m = &rs->inv_vp;
    double h0 = m->m[0][0] * nx + m->m[0][1] * ny + m->m[0][3];
    double h1 = m->m[1][0] * nx + m->m[1][1] * ny + m->m[1][3];
    double h2 = m->m[2][0] * nx + m->m[2][1] * ny + m->m[2][3];
    double h3 = m->m[3][0] * nx + m->m[3][1] * ny + m->m[3][3];
    double sg = h3 < 0.0 ? -1.0 : 1.0;
    *o = dv(rs->eye[0], rs->eye[1], rs->eye[2]);
    *d = dv((h0 - rs->eye[0] * h3) * sg, (h1 - rs->eye[1] * h3) * sg, (h2 - rs->eye[2] * h3) * sg);
}

/* What a pixel needs from its triangle; neighbouring pixels often share it (large triangles),
 * so it is set up once per run of pixels on the same triangle. */
typedef struct tri_setup {
    uint32_t obj, tri;
    dv3 p0, e1, e2;
    dv3 nrm; /* e1 x e2 (unnormalised); plane: nrm . q = plane_d */
    double plane_d;
    dv3 m1, m2;        /* b1 = (q - p0) . m1, b2 = (q - p0) . m2 for q on the plane */
    double c0, a1, a2; /* perspective: q = eye + s d, s = c0 / (d . nrm), b = a + s (d . m) */
    dv3 ng;            /* unit geometric normal (winding side) */
    uint32_t material;
    bool degenerate;
    bool has_normals, has_uvs;
    dv3 n[3]; /* vertex normals */
    double uv[3][2];
} tri_setup;

static void setup_triangle(tri_setup *ts, const ray_setup *rs, const nc_gbuffer_source *src,
                           uint32_t obj, uint32_t tri)
{
    const uint32_t *ix = src->indices + 3 * (size_t)tri;
    size_t v[3] = {ix[0], ix[1], ix[2]};
    ts->obj = obj;
    ts->tri = tri;
    ts->material = src->material_index;
    ts->p0 = dload(src->positions + 3 * v[0]);
    ts->e1 = dsub(dload(src->positions + 3 * v[1]), ts->p0);
    ts->e2 = dsub(dload(src->positions + 3 * v[2]), ts->p0);
    ts->nrm = dcross(ts->e1, ts->e2);
    double nn = ddot(ts->nrm, ts->nrm);
    ts->degenerate = !(nn > 1e-300) || !isfinite(nn);
    if (!ts->degenerate) {
        double inv = 1.0 / nn;
        ts->m1 = dscale(dcross(ts->e2, ts->nrm), inv);
        ts->m2 = dscale(dcross(ts->nrm, ts->e1), inv);
        ts->ng = dscale(ts->nrm, 1.0 / sqrt(nn));
    }
    ts->plane_d = ddot(ts->nrm, ts->p0);
    dv3 eye = dv(rs->eye[0], rs->eye[1], rs->eye[2]), rel = dsub(eye, ts->p0);
    ts->c0 = ts->plane_d - ddot(ts->nrm, eye);
    ts->a1 = ts->degenerate ? 0.0 : ddot(rel, ts->m1);
    ts->a2 = ts->degenerate ? 0.0 : ddot(rel, ts->m2);
    ts->has_normals = src->normals != NULL;
    ts->has_uvs = src->uvs != NULL;
    for (int k = 0; k < 3; k++) {
        if (ts->has_normals)
            ts->n[k] = dload(src->normals + 3 * v[k]);
        if (ts->has_uvs) {
            ts->uv[k][0] = src->uvs[2 * v[k]];
            ts->uv[k][1] = src->uvs[2 * v[k] + 1];
        }
    }
    if (ts->degenerate)
        ts->ng = dv(0, 0, 1); /* unused: such pixels face the camera (resolve_pixel) */
    if (!ts->has_normals)
        ts->n[0] = ts->n[1] = ts->n[2] = ts->ng;
    if (!ts->has_uvs)
        memset(ts->uv, 0, sizeof(ts->uv));
}

/* One covered pixel of triangle ts. */
static void resolve_pixel(const ray_setup *rs, const tri_setup *ts, int x, int y, size_t p,
                          nc_gbuffer *out)
{
    dv3 o, d;
    pixel_ray(rs, x, y, &o, &d);
    double b0, b1, b2;
    dv3 ng;
    bool back;
    if (ts->degenerate) {
        b0 = b1 = b2 = 1.0 / 3.0;
        ng = dnormalize(dscale(d, -1.0), dv(0, 0, 1)); /* face the camera */
        back = false;
    } else {
        double den = ddot(d, ts->nrm);
        if (rs->ortho) {
            double t = (ts->plane_d - ddot(o, ts->nrm)) / den;
            dv3 r = dsub(dv(o.x + t * d.x, o.y + t * d.y, o.z + t * d.z), ts->p0);
            b1 = ddot(r, ts->m1);
            b2 = ddot(r, ts->m2);
        } else {
            double t = ts->c0 / den;
            b1 = ts->a1 + t * ddot(d, ts->m1);
            b2 = ts->a2 + t * ddot(d, ts->m2);
        }
        b0 = 1.0 - b1 - b2;
        if (!(isfinite(b1) && isfinite(b2))) { /* ray parallel to the plane */
            b0 = b1 = b2 = 1.0 / 3.0;
        } else if (b0 < 0.0 || b1 < 0.0 || b2 < 0.0) {
            /* Pixel centres on a silhouette may miss by the snapping error: clamp. */
            b0 = b0 > 0.0 ? b0 : 0.0;
            b1 = b1 > 0.0 ? b1 : 0.0;
            b2 = b2 > 0.0 ? b2 : 0.0;
            double inv = 1.0 / (b0 + b1 + b2);
            b0 *= inv;
            b1 *= inv;
            b2 *= inv;
        }
        ng = ts->ng;
        back = den > 0.0;
    }
    dv3 pos = dv(ts->p0.x + b1 * ts->e1.x + b2 * ts->e2.x, ts->p0.y + b1 * ts->e1.y + b2 * ts->e2.y,
                 ts->p0.z + b1 * ts->e1.z + b2 * ts->e2.z);
    dv3 n = ng;
    if (ts->has_normals) {
        const dv3 *vn = ts->n;
        n = dnormalize(dv(b0 * vn[0].x + b1 * vn[1].x + b2 * vn[2].x,
                          b0 * vn[0].y + b1 * vn[1].y + b2 * vn[2].y,
                          b0 * vn[0].z + b1 * vn[1].z + b2 * vn[2].z),
                       ng);
    }
    double u = 0.0, v = 0.0;
    if (ts->has_uvs) {
        u = b0 * ts->uv[0][0] + b1 * ts->uv[1][0] + b2 * ts->uv[2][0];
        v = b0 * ts->uv[0][1] + b1 * ts->uv[1][1] + b2 * ts->uv[2][1];
    }
    if (back) {
        n = dscale(n, -1.0);
        ng = dscale(ng, -1.0);
    }
    float *po = out->position + 3 * p, *no = out->normal + 3 * p, *go = out->geo_normal + 3 * p;
    po[0] = (float)pos.x;
    po[1] = (float)pos.y;
    po[2] = (float)pos.z;
    no[0] = (float)n.x;
    no[1] = (float)n.y;
    no[2] = (float)n.z;
    go[0] = (float)ng.x;
    go[1] = (float)ng.y;
    go[2] = (float)ng.z;
    out->uv[2 * p] = (float)u;
    out->uv[2 * p + 1] = (float)v;
    out->view_depth[p] =
        (float)-(rs->zrow[0] * pos.x + rs->zrow[1] * pos.y + rs->zrow[2] * pos.z + rs->zrow[3]);
    out->object[p] = ts->obj;
    out->material[p] = ts->material;
    out->triangle[p] = ts->tri;
}

#ifdef __AVX2__
/* Four pixels of one row at once (lanes may belong to different triangles): the scalar path is
 * a long chain of dependent divisions and square roots per pixel, which this overlaps. Same
 * formulas as resolve_pixel; lanes it cannot handle (degenerate triangle, ray parallel to the
 * plane) are redone by resolve_pixel. */
#define LANE(field)                                                                                \
    (uniform ? _mm256_set1_pd(L[0]->field)                                                         \
             : _mm256_setr_pd(L[0]->field, L[1]->field, L[2]->field, L[3]->field))

static inline __m256d dot4(__m256d ax, __m256d ay, __m256d az, __m256d bx, __m256d by, __m256d bz)
{
    return _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(ax, bx), _mm256_mul_pd(ay, by)),
                         _mm256_mul_pd(az, bz));
}

static void resolve4(const ray_setup *rs, const tri_setup *const L[4], const int xs[4], int y,
                     const size_t px[4], int count, nc_gbuffer *out)
{
    bool uniform = L[0] == L[1] && L[0] == L[2] && L[0] == L[3];
    const __m256d zero = _mm256_setzero_pd(), one = _mm256_set1_pd(1.0);
    const __m256d sign = _mm256_set1_pd(-0.0);
    __m256d nx =
        _mm256_sub_pd(_mm256_mul_pd(_mm256_add_pd(_mm256_setr_pd(xs[0], xs[1], xs[2], xs[3]),
                                                  _mm256_set1_pd(0.5)),
                                    _mm256_set1_pd(rs->sx)),
                      one);
    double ny = 1.0 - (y + 0.5) * rs->sy;
    const dmat4 *m = &rs->inv_vp;
    __m256d h[4];
    for (int i = 0; i < 4; i++)
        h[i] = _mm256_add_pd(_mm256_mul_pd(_mm256_set1_pd(m->m[i][0]), nx),
                             _mm256_set1_pd(m->m[i][1] * ny + m->m[i][3]));
    __m256d nrm_x = LANE(nrm.x), nrm_y = LANE(nrm.y), nrm_z = LANE(nrm.z);
    __m256d m1x = LANE(m1.x), m1y = LANE(m1.y), m1z = LANE(m1.z);
    __m256d m2x = LANE(m2.x), m2y = LANE(m2.y), m2z = LANE(m2.z);
    __m256d dx, dy, dz, b1, b2, den;
    if (rs->ortho) {
        /* Near point o (z = 0) and far point (z = 1); h holds the z = 0 homogeneous point. */
        __m256d iw0 = _mm256_div_pd(one, h[3]);
        __m256d ox = _mm256_mul_pd(h[0], iw0), oy = _mm256_mul_pd(h[1], iw0),
                oz = _mm256_mul_pd(h[2], iw0);
        __m256d f[4];
        for (int i = 0; i < 4; i++)
            f[i] = _mm256_add_pd(h[i], _mm256_set1_pd(m->m[i][2]));
        __m256d iw1 = _mm256_div_pd(one, f[3]);
        dx = _mm256_sub_pd(_mm256_mul_pd(f[0], iw1), ox);
        dy = _mm256_sub_pd(_mm256_mul_pd(f[1], iw1), oy);
        dz = _mm256_sub_pd(_mm256_mul_pd(f[2], iw1), oz);
        den = dot4(dx, dy, dz, nrm_x, nrm_y, nrm_z);
        __m256d t =
            _mm256_div_pd(_mm256_sub_pd(LANE(plane_d), dot4(ox, oy, oz, nrm_x, nrm_y, nrm_z)), den);
        __m256d rx = _mm256_sub_pd(_mm256_add_pd(ox, _mm256_mul_pd(t, dx)), LANE(p0.x));
        __m256d ry = _mm256_sub_pd(_mm256_add_pd(oy, _mm256_mul_pd(t, dy)), LANE(p0.y));
        __m256d rz = _mm256_sub_pd(_mm256_add_pd(oz, _mm256_mul_pd(t, dz)), LANE(p0.z));
        b1 = dot4(rx, ry, rz, m1x, m1y, m1z);
        b2 = dot4(rx, ry, rz, m2x, m2y, m2z);
    } else {
        __m256d sg = _mm256_and_pd(h[3], sign); /* positive multiple of the direction */
        dx =
            _mm256_xor_pd(_mm256_sub_pd(h[0], _mm256_mul_pd(_mm256_set1_pd(rs->eye[0]), h[3])), sg);
        dy =
            _mm256_xor_pd(_mm256_sub_pd(h[1], _mm256_mul_pd(_mm256_set1_pd(rs->eye[1]), h[3])), sg);
        dz =
            _mm256_xor_pd(_mm256_sub_pd(h[2], _mm256_mul_pd(_mm256_set1_pd(rs->eye[2]), h[3])), sg);
        den = dot4(dx, dy, dz, nrm_x, nrm_y, nrm_z);
        __m256d t = _mm256_div_pd(LANE(c0), den);
        b1 = _mm256_add_pd(LANE(a1), _mm256_mul_pd(t, dot4(dx, dy, dz, m1x, m1y, m1z)));
        b2 = _mm256_add_pd(LANE(a2), _mm256_mul_pd(t, dot4(dx, dy, dz, m2x, m2y, m2z)));
    }
    __m256d b0 = _mm256_sub_pd(_mm256_sub_pd(one, b1), b2);
    /* x - x == 0 exactly when x is finite. */
    __m256d ok = _mm256_and_pd(_mm256_cmp_pd(_mm256_sub_pd(b1, b1), zero, _CMP_EQ_OQ),
                               _mm256_cmp_pd(_mm256_sub_pd(b2, b2), zero, _CMP_EQ_OQ));
    __m256d neg = _mm256_or_pd(
        _mm256_or_pd(_mm256_cmp_pd(b0, zero, _CMP_LT_OQ), _mm256_cmp_pd(b1, zero, _CMP_LT_OQ)),
        _mm256_cmp_pd(b2, zero, _CMP_LT_OQ));
    if (_mm256_movemask_pd(neg)) {
        __m256d c0 = _mm256_max_pd(b0, zero), c1 = _mm256_max_pd(b1, zero),
                c2 = _mm256_max_pd(b2, zero);
        __m256d inv = _mm256_div_pd(one, _mm256_add_pd(_mm256_add_pd(c0, c1), c2));
        b0 = _mm256_blendv_pd(b0, _mm256_mul_pd(c0, inv), neg);
        b1 = _mm256_blendv_pd(b1, _mm256_mul_pd(c1, inv), neg);
        b2 = _mm256_blendv_pd(b2, _mm256_mul_pd(c2, inv), neg);
    }
#define INTERP(f0, f1, f2)                                                                         \
    _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(b0, LANE(f0)), _mm256_mul_pd(b1, LANE(f1))),         \
                  _mm256_mul_pd(b2, LANE(f2)))
    __m256d pos[3], n[3], ng[3], uv[2];
    pos[0] = _mm256_add_pd(
        LANE(p0.x), _mm256_add_pd(_mm256_mul_pd(b1, LANE(e1.x)), _mm256_mul_pd(b2, LANE(e2.x))));
    pos[1] = _mm256_add_pd(
        LANE(p0.y), _mm256_add_pd(_mm256_mul_pd(b1, LANE(e1.y)), _mm256_mul_pd(b2, LANE(e2.y))));
    pos[2] = _mm256_add_pd(
        LANE(p0.z), _mm256_add_pd(_mm256_mul_pd(b1, LANE(e1.z)), _mm256_mul_pd(b2, LANE(e2.z))));
    ng[0] = LANE(ng.x);
    ng[1] = LANE(ng.y);
    ng[2] = LANE(ng.z);
    n[0] = INTERP(n[0].x, n[1].x, n[2].x);
    n[1] = INTERP(n[0].y, n[1].y, n[2].y);
    n[2] = INTERP(n[0].z, n[1].z, n[2].z);
    __m256d l2 = dot4(n[0], n[1], n[2], n[0], n[1], n[2]);
    __m256d nok = _mm256_and_pd(_mm256_cmp_pd(l2, _mm256_set1_pd(1e-300), _CMP_GT_OQ),
                                _mm256_cmp_pd(l2, _mm256_set1_pd(INFINITY), _CMP_LT_OQ));
    __m256d il = _mm256_div_pd(one, _mm256_sqrt_pd(l2));
    for (int c = 0; c < 3; c++)
        n[c] = _mm256_blendv_pd(ng[c], _mm256_mul_pd(n[c], il), nok);
    uv[0] = INTERP(uv[0][0], uv[1][0], uv[2][0]);
    uv[1] = INTERP(uv[0][1], uv[1][1], uv[2][1]);
#undef INTERP
    __m256d flip = _mm256_and_pd(_mm256_cmp_pd(den, zero, _CMP_GT_OQ), sign);
    for (int c = 0; c < 3; c++) {
        n[c] = _mm256_xor_pd(n[c], flip);
        ng[c] = _mm256_xor_pd(ng[c], flip);
    }
    __m256d vd =
        _mm256_xor_pd(_mm256_add_pd(dot4(_mm256_set1_pd(rs->zrow[0]), _mm256_set1_pd(rs->zrow[1]),
                                         _mm256_set1_pd(rs->zrow[2]), pos[0], pos[1], pos[2]),
                                    _mm256_set1_pd(rs->zrow[3])),
                      sign);
    float fo[12][4];
    __m256d all[12] = {pos[0], pos[1], pos[2], n[0], n[1], n[2], ng[0], ng[1], ng[2], uv[0], uv[1], vd};
    for (int i = 0; i < 12; i++)
        _mm_storeu_ps(fo[i], _mm256_cvtpd_ps(all[i]));
    int okm = _mm256_movemask_pd(ok);
    for (int k = 0; k < count; k++) {
        const tri_setup *ts = L[k];
        size_t p = px[k];
        if (ts->degenerate || !(okm >> k & 1)) {
            resolve_pixel(rs, ts, xs[k], y, p, out);
            continue;
        }
        float *po = out->position + 3 * p, *no = out->normal + 3 * p, *go = out->geo_normal + 3 * p;
        po[0] = fo[0][k];
        po[1] = fo[1][k];
        po[2] = fo[2][k];
        no[0] = fo[3][k];
        no[1] = fo[4][k];
        no[2] = fo[5][k];
        go[0] = fo[6][k];
        go[1] = fo[7][k];
        go[2] = fo[8][k];
        out->uv[2 * p] = fo[9][k];
        out->uv[2 * p + 1] = fo[10][k];
        out->view_depth[p] = fo[11][k];
        out->object[p] = ts->obj;
        out->material[p] = ts->material;
        out->triangle[p] = ts->tri;
    }
}
#undef LANE
#endif

/* Fill n 32-bit words with `value`. Empty pixels are most of a frame and the G-buffer is
 * large (60 bytes per pixel), so long runs use streaming stores: they skip reading the old
 * contents into the cache first, which halves the memory traffic. The caller fences. */
static void fill32(void *dst, size_t n, uint32_t value)
{
    uint32_t *p = dst;
#ifdef __AVX__
    /* Whole cache lines only: a line shared with a resolved pixel takes normal stores
     * (partial streamed lines are slow). */
    if (n >= 64) {
        while ((uintptr_t)p & 63) {
            *p++ = value;
            n--;
        }
        __m256i v = _mm256_set1_epi32((int)value);
        for (; n >= 16; n -= 16, p += 16) {
            _mm256_stream_si256((__m256i *)p, v);
            _mm256_stream_si256((__m256i *)(p + 8), v);
        }
    }
#endif
    for (; n; n--)
        *p++ = value;
}

static inline uint32_t float_bits(float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof(u));
    return u;
}

/* Empty pixels [p, q). */
static void clear_run(nc_gbuffer *out, size_t p, size_t q)
{
    size_t n = q - p;
    fill32(out->position + 3 * p, 3 * n, 0);
    fill32(out->normal + 3 * p, 3 * n, 0);
    fill32(out->geo_normal + 3 * p, 3 * n, 0);
    fill32(out->uv + 2 * p, 2 * n, 0);
    fill32(out->material + p, n, 0);
    fill32(out->triangle + p, n, 0);
    fill32(out->view_depth + p, n, float_bits(INFINITY));
    fill32(out->object + p, n, NC_NO_OBJECT);
}

/* Neighbouring pixels mostly see different triangles of a dense mesh, whose vertices are far
 * apart in memory: fetch the indices INDEX_AHEAD pixels ahead and the vertex data VERTEX_AHEAD
 * pixels ahead, so the misses overlap instead of following one another. */
#define INDEX_AHEAD 24
#define VERTEX_AHEAD 4

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
    }
}

nacre_result nc_gbuffer_resolve(nacre_context *ctx, const nc_raster_view *view,
                                const nc_vis_buffer *vis, const nc_gbuffer_source *sources,
                                uint32_t source_count, nc_gbuffer *out)
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
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "G-buffer resolve: singular view or projection");
    for (int i = 0; i < 3; i++)
        rs.eye[i] = iv.m[i][3] / iv.m[3][3];
    for (int j = 0; j < 4; j++)
        rs.zrow[j] = v.m[2][j];
    rs.sx = 2.0 / view->width;
    rs.sy = 2.0 / view->height;
    rs.ortho = view->orthographic;

    int h = vis->height, w = vis->width;
    int threads = nc_threads(ctx);
    bool bad = false;
#pragma omp parallel num_threads(threads) reduction(|| : bad)
    {
#pragma omp for schedule(dynamic, 4)
        for (int y = 0; y < h; y++) {
            size_t row = (size_t)y * (size_t)w;
            /* Triangle setups, reused while pixels stay on the same triangle; a small ring so the
         * lanes of a batch and the previous pixel's setup are never overwritten. */
            tri_setup pool[8];
            int next = 0;
            const tri_setup *last = NULL;
            const tri_setup *lanes[4];
            int lane_x[4], n_lanes = 0;
            size_t lane_p[4];
            const uint32_t *objs = vis->object + row, *tris = vis->triangle + row;
            /* Empty pixels outside the span the previous resolve left are already empty. */
            int old_lo = out->row_span ? out->row_span[2 * y] : 0;
            int old_hi = out->row_span ? out->row_span[2 * y + 1] : w;
            int new_lo = w, new_hi = 0;
            int x = 0;
            while (x < w) {
                if (objs[x] == NC_NO_OBJECT) {
                    int e = x + 1;
                    while (e < w && objs[e] == NC_NO_OBJECT)
                        e++;
                    int lo = x > old_lo ? x : old_lo, hi = e < old_hi ? e : old_hi;
                    if (lo < hi)
                        clear_run(out, row + (size_t)lo, row + (size_t)hi);
                    x = e;
                    continue;
                }
                new_lo = x < new_lo ? x : new_lo;
                new_hi = x + 1;
                if (x + INDEX_AHEAD < w)
                    prefetch_indices(sources, source_count, objs[x + INDEX_AHEAD],
                                     tris[x + INDEX_AHEAD]);
                if (x + VERTEX_AHEAD < w)
                    prefetch_vertices(sources, source_count, objs[x + VERTEX_AHEAD],
                                      tris[x + VERTEX_AHEAD]);
                size_t px = row + (size_t)x;
                uint32_t obj = objs[x], tri = tris[x];
                if (obj >= source_count) {
                    bad = true;
                    clear_run(out, px, px + 1);
                    x++;
                    continue;
                }
                if (!last || last->obj != obj || last->tri != tri) {
                    tri_setup *ts = &pool[next];
                    next = (next + 1) & 7;
                    setup_triangle(ts, &rs, &sources[obj], obj, tri);
                    last = ts;
                }
#ifdef __AVX2__
                lanes[n_lanes] = last;
                lane_x[n_lanes] = x;
                lane_p[n_lanes] = px;
                if (++n_lanes == 4) {
                    resolve4(&rs, lanes, lane_x, y, lane_p, 4, out);
                    n_lanes = 0;
                }
#else
                resolve_pixel(&rs, last, x, y, px, out);
#endif
                x++;
            }
            for (int k = 0; k < n_lanes; k++) /* the row's last few pixels */
                resolve_pixel(&rs, lanes[k], lane_x[k], y, lane_p[k], out);
            if (out->row_span) {
                out->row_span[2 * y] = new_lo < new_hi ? new_lo : 0;
                out->row_span[2 * y + 1] = new_lo < new_hi ? new_hi : 0;
            }
            (void)lanes;
            (void)lane_x;
            (void)lane_p;
        }
#ifdef __AVX__
        _mm_sfence(); /* order this thread's streaming stores before the region ends */
#endif
    }
    if (bad)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "G-buffer resolve: visibility buffer names an object beyond the %u sources",
                       source_count);
    return NACRE_OK;
}
