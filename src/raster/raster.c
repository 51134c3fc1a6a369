/*
 * raster.c: the tiled software rasterizer behind nc_raster_visibility and nc_raster_depth.
 *
 * One frame runs four passes, each an OpenMP loop:
 *   1. vertices: world -> clip -> snapped screen position (8 sub-pixel bits, int32), NDC z and an
 *      outcode, for every vertex of every mesh (one global vertex numbering);
 *   2. setup, over contiguous chunks of the global triangle sequence: trivial frustum reject,
 *      homogeneous clipping (near plane and a guard band, in double) for the few triangles that
 *      need it, back-face culling on the exact integer area, rejection of triangles whose
 *      bounding box holds no pixel centre or, for boxes of up to 2 x 2 centres, that cover none
 *      (with AVX2, 8 triangles at a time before the exact scalar path), then one 48-byte record
 *      per surviving (sub-)triangle and a count per screen tile it touches;
 *   3. binning: a prefix sum over (tile, chunk) and a scatter of record references, so that
 *      each tile's list visits chunks 0..C-1 in order, i.e. triangles in submission order;
 *   4. tiles (64 x 64 pixels) in parallel: clear, then integer edge functions with the top-left
 *      rule and a depth test `z < depth`, so ties keep the earlier triangle. Narrow boxes take
 *      8-pixel rows at once (AVX2), wide ones solve each row's span per edge. Triangle ids are
 *      turned into (object, triangle) while the tile is in cache.
 * Scratch (vertices, records, bins) lives in the nc_rasterizer and only grows.
 * Nothing depends on which thread ran what, so the output is independent of the thread count.
 *
 * Conventions: pixel (x, y) has its centre at (x + 0.5, y + 0.5), row 0 at the top; snapped
 * coordinates are pixels * 256. Depth is NDC z, affine in screen space, interpolated from the
 * snapped vertices and evaluated per pixel from a fixed reference vertex (not incrementally), so
 * a pixel's depth does not depend on tiling. Front faces are counter-clockwise in NDC (y up).
 */
#include "raster/raster.h"
#include "core/simd.h"

#include <float.h>
#include <string.h>
#if defined(__SSE2__) || defined(__AVX__)
#include <immintrin.h>
#endif

#define SUB_BITS 8
#define SUB_ONE (1 << SUB_BITS)
#define SUB_HALF (SUB_ONE / 2)
#define TILE_SHIFT 6
#define TILE (1 << TILE_SHIFT)
/* Guard band beyond each side of the viewport, in pixels: vertices inside it are snapped
 * directly; |snapped coordinate| < 2^23 keeps every edge-function product within int64 and every
 * snapped value exact in a float. Larger triangles are clipped to it in homogeneous space. */
#define GUARD_PX 8192
#define MAX_SIZE 16384
/* Chunks per thread in the setup pass: cheap off-screen ranges are balanced dynamically. */
#define CHUNKS_PER_THREAD 4
/* Records wider than this (in pixel centres) are drawn span by span instead of pixel by pixel. */
#define SPAN_MIN_WIDTH 12
/* How far ahead the setup pass prefetches vertices (triangles). */
#define PREFETCH_TRIS 24
/* How far ahead the tile pass prefetches records. */
#define PREFETCH_RECS 8

/* Outcode bits: outside one frustum plane (for trivial rejection) or needing the slow path. */
enum {
    OUT_LEFT = 1,
    OUT_RIGHT = 2,
    OUT_BOTTOM = 4,
    OUT_TOP = 8,
    OUT_NEAR = 16,
    OUT_FAR = 32,
    OUT_FRUSTUM = 63,
    NEEDS_CLIP = 64
};

/* Pass 1 output. Triangles gather their vertices from all over the array, so the setup pass is
 * bound by cache misses; 8 bytes per vertex put 8 vertices in a cache line. z lives apart: only
 * the few triangles that survive culling read it. */
typedef struct svert {
    int32_t x;  /* snapped screen x (0 with NEEDS_CLIP) */
    int32_t yc; /* snapped screen y << CODE_BITS | outcode; |y| < 2^23 */
} svert;
#define CODE_BITS 7

static inline int32_t sv_y(svert v) { return v.yc >> CODE_BITS; }
static inline unsigned sv_code(svert v) { return (unsigned)v.yc & ((1u << CODE_BITS) - 1); }

/* A triangle ready for the tile pass, oriented so that its integer signed area is positive. */
typedef struct tri_rec {
    int32_t x[3], y[3];          /* snapped screen position */
    float z0, dzdx, dzdy;        /* depth at vertex 0 and its gradient per pixel */
    uint32_t id;                 /* global triangle id (submission order) */
    uint16_t px0, py0, px1, py1; /* inclusive range of pixel centres in the bounding box */
} tri_rec;

typedef struct chunk {
    tri_rec *recs;
    uint32_t rec_cap, rec_count; /* rec_count > rec_cap: grow and set the chunk up again */
    uint64_t drawn;
    uint64_t first, end; /* global triangle range */
    bool bad_index;
    bool redo; /* set up (again) in this frame's setup loop */
} chunk;

struct nc_rasterizer {
    nacre_context *ctx;
    /* Pass 1 output, per global vertex. */
    svert *verts;
    float *vz;
    size_t vert_cap, vz_cap;
    /* Per mesh: first global vertex and triangle. */
    uint64_t *vbase, *tbase;
    uint32_t mesh_cap;
    chunk *chunks;
    int chunk_count;
    /* Tile bins: counts[chunk][tile] (then write cursors), start[tile * C + chunk] (+1 total). */
    uint32_t *counts, *start;
    size_t tile_cap;
    uint32_t *refs;
    size_t ref_cap;
};

/* Everything the passes read about the current frame. */
typedef struct frame {
    float m[4][4];   /* world -> clip */
    double md[4][4]; /* the same in double, for clipping */
    int32_t width, height;
    float sx, sy; /* NDC -> snapped pixels scale (and offset) */
    float gx, gy; /* guard band in NDC units */
    int tiles_x, tiles_y;
    const nc_raster_mesh *meshes;
    uint32_t mesh_count;
    const uint64_t *vbase, *tbase;
    bool cull; /* cull back faces of meshes that are not double-sided */
    float *depth;
    uint32_t *ids;     /* global triangle id per pixel (then triangle in object), or NULL */
    uint32_t *objects; /* object per pixel, with ids */
    const svert *verts;
    const float *vz;
} frame;

nacre_result nc_rasterizer_create(nacre_context *ctx, nc_rasterizer **out)
{
    if (!ctx || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    *out = NULL;
    nc_rasterizer *r = nc_calloc(ctx, 1, sizeof(*r));
    if (!r)
        return NACRE_ERROR_OUT_OF_MEMORY;
    r->ctx = ctx;
    *out = r;
    return NACRE_OK;
}

static void free_chunks(nc_rasterizer *r)
{
    for (int c = 0; c < r->chunk_count; c++)
        nc_free(r->ctx, r->chunks[c].recs);
    nc_free(r->ctx, r->chunks);
    r->chunks = NULL;
    r->chunk_count = 0;
}

void nc_rasterizer_destroy(nc_rasterizer *r)
{
    if (!r)
        return;
    nacre_context *ctx = r->ctx;
    nc_free(ctx, r->verts);
    nc_free(ctx, r->vz);
    nc_free(ctx, r->vbase);
    nc_free(ctx, r->tbase);
    free_chunks(r);
    nc_free(ctx, r->counts);
    nc_free(ctx, r->start);
    nc_free(ctx, r->refs);
    nc_free(ctx, r);
}

nacre_result nc_vis_buffer_resize(nacre_context *ctx, nc_vis_buffer *vb, int32_t width,
                                  int32_t height)
{
    if (!vb || width < 1 || height < 1 || width > MAX_SIZE || height > MAX_SIZE)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "visibility buffer: invalid size %dx%d",
                       (int)width, (int)height);
    if (vb->depth && vb->width == width && vb->height == height)
        return NACRE_OK;
    nc_vis_buffer_free(ctx, vb);
    size_t n = (size_t)width * (size_t)height;
    vb->depth = nc_alloc(ctx, n * sizeof(float));
    vb->object = nc_alloc(ctx, n * sizeof(uint32_t));
    vb->triangle = nc_alloc(ctx, n * sizeof(uint32_t));
    if (!vb->depth || !vb->object || !vb->triangle) {
        nc_vis_buffer_free(ctx, vb);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    vb->width = width;
    vb->height = height;
    return NACRE_OK;
}

void nc_vis_buffer_free(nacre_context *ctx, nc_vis_buffer *vb)
{
    if (!vb)
        return;
    nc_free(ctx, vb->depth);
    nc_free(ctx, vb->object);
    nc_free(ctx, vb->triangle);
    memset(vb, 0, sizeof(*vb));
}

/* ---- helpers ---- */

static inline int32_t round_int(float v)
{
#if defined(__SSE2__)
    return _mm_cvtss_si32(_mm_set_ss(v)); /* round to nearest even, no libm call */
#else
    return (int32_t)lrintf(v);
#endif
}

static inline int64_t floor_div(int64_t a, int64_t b) /* b > 0 */
{
    int64_t q = a / b;
    return (a % b != 0 && a < 0) ? q - 1 : q;
}

/* Grow an array whose old contents are not needed (no copy). */
static bool grow(nacre_context *ctx, void **p, size_t *cap, size_t need, size_t elem)
{
    if (need <= *cap)
        return true;
    size_t n = need + need / 4 + 64, bytes;
    if (!nc_mul_size_ok(n, elem, &bytes)) {
        nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "rasterizer: allocation size overflows");
        return false;
    }
    nc_free(ctx, *p);
    *cap = 0;
    *p = nc_alloc(ctx, bytes);
    if (!*p)
        return false;
    *cap = n;
    return true;
}

static inline void clip_of(const frame *f, const float *p, float c[4])
{
    for (int i = 0; i < 4; i++)
        c[i] = f->m[i][0] * p[0] + f->m[i][1] * p[1] + f->m[i][2] * p[2] + f->m[i][3];
}

/* Inside the near plane and the guard band: safe to snap. Written so that NaN fails. */
static inline bool snappable(const frame *f, const float c[4])
{
    /* w in [FLT_MIN, FLT_MAX] and z <= FLT_MAX: 1/w and the projected x, y, z stay finite (an
     * infinite x or w from vertices near the float range gave inf/w or inf/inf, snapped to
     * INT32_MIN).
     * Anything else goes to the clipper, which works in double and rejects non-finite vertices. */
    float gw = f->gx * c[3], hw = f->gy * c[3];
    return c[2] >= 0.0f && c[2] <= FLT_MAX && c[3] >= FLT_MIN && gw <= FLT_MAX && hw <= FLT_MAX &&
           c[0] >= -gw && c[0] <= gw && c[1] >= -hw && c[1] <= hw;
}

static inline void snap(const frame *f, const float c[4], int32_t *x, int32_t *y, float *z)
{
    float iw = 1.0f / c[3];
    *x = round_int(c[0] * iw * f->sx + f->sx);
    *y = round_int(f->sy - c[1] * iw * f->sy);
    *z = c[2] * iw;
}

static inline uint8_t outcode(const frame *f, const float c[4])
{
    unsigned k = 0;
    if (!(c[0] >= -c[3]))
        k |= OUT_LEFT;
    if (!(c[0] <= c[3]))
        k |= OUT_RIGHT;
    if (!(c[1] >= -c[3]))
        k |= OUT_BOTTOM;
    if (!(c[1] <= c[3]))
        k |= OUT_TOP;
    if (!(c[2] >= 0.0f))
        k |= OUT_NEAR;
    if (!(c[2] <= c[3]))
        k |= OUT_FAR;
    if (!snappable(f, c))
        k |= NEEDS_CLIP;
    return (uint8_t)k;
}

/* ---- pass 1: vertices ---- */

static void transform_vertices(const frame *f, const float *restrict pos, size_t count,
                               svert *restrict out, float *restrict oz)
{
    size_t i = 0;
#ifdef __AVX2__
    /* The same operations in the same order as clip_of / outcode / snap (no FMA: C11 mode
     * does not contract), so a vertex gets the same bits on either path and the output does
     * not depend on which vertices fell in the scalar tail. */
    const __m256i off = _mm256_setr_epi32(0, 3, 6, 9, 12, 15, 18, 21);
    __m256 m[4][4];
    for (int r = 0; r < 4; r++)
        for (int c = 0; c < 4; c++)
            m[r][c] = _mm256_set1_ps(f->m[r][c]);
    const __m256 zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.0f), fmax = _mm256_set1_ps(FLT_MAX);
    const __m256 gx = _mm256_set1_ps(f->gx), gy = _mm256_set1_ps(f->gy);
    const __m256 sx = _mm256_set1_ps(f->sx), sy = _mm256_set1_ps(f->sy);
    const __m256 sign = _mm256_set1_ps(-0.0f);
    for (; i + 8 <= count; i += 8) {
        const float *p = pos + 3 * i;
        __m256 px = _mm256_i32gather_ps(p, off, 4);
        __m256 py = _mm256_i32gather_ps(p + 1, off, 4);
        __m256 pz = _mm256_i32gather_ps(p + 2, off, 4);
        __m256 c[4];
        for (int r = 0; r < 4; r++)
            c[r] = _mm256_add_ps(
                _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(m[r][0], px), _mm256_mul_ps(m[r][1], py)),
                              _mm256_mul_ps(m[r][2], pz)),
                m[r][3]);
        __m256 nw = _mm256_xor_ps(c[3], sign);
        __m256 gw = _mm256_mul_ps(gx, c[3]), hw = _mm256_mul_ps(gy, c[3]);
        __m256 ngw = _mm256_xor_ps(gw, sign), nhw = _mm256_xor_ps(hw, sign);
        __m256 ok = _mm256_and_ps(_mm256_cmp_ps(c[2], zero, _CMP_GE_OQ),
                                  _mm256_cmp_ps(c[3], _mm256_set1_ps(FLT_MIN), _CMP_GE_OQ));
        ok = _mm256_and_ps(ok, _mm256_and_ps(_mm256_cmp_ps(c[2], fmax, _CMP_LE_OQ),
                                             _mm256_and_ps(_mm256_cmp_ps(gw, fmax, _CMP_LE_OQ),
                                                           _mm256_cmp_ps(hw, fmax, _CMP_LE_OQ))));
        ok = _mm256_and_ps(ok, _mm256_and_ps(_mm256_cmp_ps(c[0], ngw, _CMP_GE_OQ),
                                             _mm256_cmp_ps(c[0], gw, _CMP_LE_OQ)));
        ok = _mm256_and_ps(ok, _mm256_and_ps(_mm256_cmp_ps(c[1], nhw, _CMP_GE_OQ),
                                             _mm256_cmp_ps(c[1], hw, _CMP_LE_OQ)));
#define BIT_IF(cmp, bit) _mm256_and_si256(_mm256_castps_si256(cmp), _mm256_set1_epi32(bit))
        __m256i code = BIT_IF(_mm256_cmp_ps(c[0], nw, _CMP_NGE_UQ), OUT_LEFT);
        code = _mm256_or_si256(code, BIT_IF(_mm256_cmp_ps(c[0], c[3], _CMP_NLE_UQ), OUT_RIGHT));
        code = _mm256_or_si256(code, BIT_IF(_mm256_cmp_ps(c[1], nw, _CMP_NGE_UQ), OUT_BOTTOM));
        code = _mm256_or_si256(code, BIT_IF(_mm256_cmp_ps(c[1], c[3], _CMP_NLE_UQ), OUT_TOP));
        code = _mm256_or_si256(code, BIT_IF(_mm256_cmp_ps(c[2], zero, _CMP_NGE_UQ), OUT_NEAR));
        code = _mm256_or_si256(code, BIT_IF(_mm256_cmp_ps(c[2], c[3], _CMP_NLE_UQ), OUT_FAR));
        code = _mm256_or_si256(
            code, _mm256_andnot_si256(_mm256_castps_si256(ok), _mm256_set1_epi32(NEEDS_CLIP)));
#undef BIT_IF
        __m256 iw = _mm256_div_ps(one, c[3]);
        __m256i x =
            _mm256_cvtps_epi32(_mm256_add_ps(_mm256_mul_ps(_mm256_mul_ps(c[0], iw), sx), sx));
        __m256i y =
            _mm256_cvtps_epi32(_mm256_sub_ps(sy, _mm256_mul_ps(_mm256_mul_ps(c[1], iw), sy)));
        __m256 z = _mm256_and_ps(_mm256_mul_ps(c[2], iw), ok);
        x = _mm256_and_si256(x, _mm256_castps_si256(ok));
        y = _mm256_and_si256(y, _mm256_castps_si256(ok));
        __m256i yc = _mm256_or_si256(_mm256_slli_epi32(y, CODE_BITS), code);
        __m256i lo = _mm256_unpacklo_epi32(x, yc), hi = _mm256_unpackhi_epi32(x, yc);
        _mm256_storeu_si256((__m256i *)(out + i), _mm256_permute2x128_si256(lo, hi, 0x20));
        _mm256_storeu_si256((__m256i *)(out + i + 4), _mm256_permute2x128_si256(lo, hi, 0x31));
        _mm256_storeu_ps(oz + i, z);
    }
#endif
    for (; i < count; i++) {
        float c[4];
        clip_of(f, pos + 3 * i, c);
        unsigned code = outcode(f, c);
        int32_t x = 0, y = 0;
        float z = 0.0f;
        if (!(code & NEEDS_CLIP))
            snap(f, c, &x, &y, &z);
        out[i].x = x;
        out[i].yc = (int32_t)(((uint32_t)y << CODE_BITS) | code);
        oz[i] = z;
    }
}

/* ---- pass 2: setup ---- */

typedef struct setup_out {
    tri_rec *recs;
    uint32_t cap, count;
    uint32_t *counts; /* this chunk's row of per-tile counts */
    int tiles_x;
} setup_out;

/* Edge function k (from vertex k to k+1) of a triangle with positive area at the sub-pixel
 * point (px, py): E = dx (Py - Ya) - dy (Px - Xa) > 0 inside. On the edge (E = 0) only top and
 * left edges own the point; with y down those have dy < 0, or dy == 0 and dx > 0. The result is
 * biased so that >= 0 means covered. */
static inline int64_t edge_at(const int32_t x[3], const int32_t y[3], int k, int64_t px, int64_t py)
{
    int k2 = k == 2 ? 0 : k + 1;
    int64_t dx = (int64_t)x[k2] - x[k], dy = (int64_t)y[k2] - y[k];
    bool top_left = dy < 0 || (dy == 0 && dx > 0);
    return dx * (py - y[k]) - dy * (px - x[k]) - (top_left ? 0 : 1);
}

/* Emit one snapped triangle; returns whether it produced a record. */
static inline bool emit(const frame *f, setup_out *o, int32_t x0, int32_t y0, float z0, int32_t x1,
                        int32_t y1, float z1, int32_t x2, int32_t y2, float z2, uint32_t id,
                        bool cull)
{
    int64_t area = ((int64_t)x1 - x0) * ((int64_t)y2 - y0) - ((int64_t)x2 - x0) * ((int64_t)y1 - y0);
    if (area == 0)
        return false;
    /* y points down on screen, so counter-clockwise in NDC (front) means negative area here. */
    if (area > 0) {
        if (cull)
            return false;
    } else {
        int32_t t;
        float tz;
        t = x1;
        x1 = x2;
        x2 = t;
        t = y1;
        y1 = y2;
        y2 = t;
        tz = z1;
        z1 = z2;
        z2 = tz;
        area = -area;
    }
    int32_t minx = x0 < x1 ? (x0 < x2 ? x0 : x2) : (x1 < x2 ? x1 : x2);
    int32_t maxx = x0 > x1 ? (x0 > x2 ? x0 : x2) : (x1 > x2 ? x1 : x2);
    int32_t miny = y0 < y1 ? (y0 < y2 ? y0 : y2) : (y1 < y2 ? y1 : y2);
    int32_t maxy = y0 > y1 ? (y0 > y2 ? y0 : y2) : (y1 > y2 ? y1 : y2);
    /* Pixel centres c = 256 i + 128 with minx <= c <= maxx (arithmetic shifts floor). */
    int32_t i0 = (minx - SUB_HALF + SUB_ONE - 1) >> SUB_BITS;
    int32_t i1 = (maxx - SUB_HALF) >> SUB_BITS;
    int32_t j0 = (miny - SUB_HALF + SUB_ONE - 1) >> SUB_BITS;
    int32_t j1 = (maxy - SUB_HALF) >> SUB_BITS;
    if (i0 < 0)
        i0 = 0;
    if (j0 < 0)
        j0 = 0;
    if (i1 > f->width - 1)
        i1 = f->width - 1;
    if (j1 > f->height - 1)
        j1 = f->height - 1;
    if (i0 > i1 || j0 > j1)
        return false;
    if (i1 - i0 <= 1 && j1 - j0 <= 1) {
        /* At most 4 pixel centres: most such triangles of a dense mesh cover none of them, and
         * testing here saves their record, binning and tile work. */
        const int32_t vx[3] = {x0, x1, x2}, vy[3] = {y0, y1, y2};
        bool any = false;
        for (int32_t j = j0; j <= j1; j++)
            for (int32_t i = i0; i <= i1; i++) {
                int64_t px = (int64_t)i * SUB_ONE + SUB_HALF, py = (int64_t)j * SUB_ONE + SUB_HALF;
                any |= (edge_at(vx, vy, 0, px, py) | edge_at(vx, vy, 1, px, py) |
                        edge_at(vx, vy, 2, px, py)) >= 0;
            }
        if (!any)
            return false;
    }
    uint32_t n = o->count++;
    if (n < o->cap) {
        tri_rec *r = &o->recs[n];
        r->x[0] = x0;
        r->x[1] = x1;
        r->x[2] = x2;
        r->y[0] = y0;
        r->y[1] = y1;
        r->y[2] = y2;
        /* Plane through the snapped vertices, in pixels (exact deltas, double for the solve). */
        double dx1 = (x1 - x0) * (1.0 / SUB_ONE), dy1 = (y1 - y0) * (1.0 / SUB_ONE);
        double dx2 = (x2 - x0) * (1.0 / SUB_ONE), dy2 = (y2 - y0) * (1.0 / SUB_ONE);
        double dz1 = (double)z1 - z0, dz2 = (double)z2 - z0;
        double inv = (double)(SUB_ONE * SUB_ONE) / (double)area;
        r->z0 = z0;
        r->dzdx = (float)((dz1 * dy2 - dz2 * dy1) * inv);
        r->dzdy = (float)((dz2 * dx1 - dz1 * dx2) * inv);
        r->id = id;
        r->px0 = (uint16_t)i0;
        r->px1 = (uint16_t)i1;
        r->py0 = (uint16_t)j0;
        r->py1 = (uint16_t)j1;
    }
    int tx0 = i0 >> TILE_SHIFT, tx1 = i1 >> TILE_SHIFT;
    int ty0 = j0 >> TILE_SHIFT, ty1 = j1 >> TILE_SHIFT;
    for (int ty = ty0; ty <= ty1; ty++)
        for (int tx = tx0; tx <= tx1; tx++)
            o->counts[ty * o->tiles_x + tx]++;
    return true;
}

typedef struct cvert {
    double c[4];
    int orig; /* 0..2: an unmodified input vertex, -1: made by clipping */
} cvert;

static inline double plane_dist(const frame *f, int plane, const double c[4])
{
    switch (plane) {
    case 0:
        return c[2];
    case 1:
        return f->gx * c[3] - c[0];
    case 2:
        return f->gx * c[3] + c[0];
    case 3:
        return f->gy * c[3] - c[1];
    default:
        return f->gy * c[3] + c[1];
    }
}

/* Slow path: clip against the near plane and the guard band in homogeneous space, then fan.
 * Double precision: a triangle kilometres long, cut a few centimetres in front of the camera,
 * would otherwise place the new vertices a pixel off. A new vertex is always interpolated from
 * the inside end of its edge, so two triangles sharing that edge make the same vertex and stay
 * watertight; input vertices the vertex pass found inside are kept as snapped there, exactly
 * as the fast path uses them. */
static bool setup_clipped(const frame *f, setup_out *o, const float *pos, const uint32_t vi[3],
                          const uint64_t gi[3], uint32_t id, bool cull)
{
    cvert buf[2][16];
    bool kept[3];
    int n = 3;
    for (int k = 0; k < 3; k++) {
        const float *p = pos + 3 * (size_t)vi[k];
        for (int q = 0; q < 4; q++) {
            buf[0][k].c[q] =
                f->md[q][0] * p[0] + f->md[q][1] * p[1] + f->md[q][2] * p[2] + f->md[q][3];
            if (!isfinite(buf[0][k].c[q]))
                return false;
        }
        buf[0][k].orig = k;
        kept[k] = !(sv_code(f->verts[gi[k]]) & NEEDS_CLIP);
    }
    int cur = 0;
    for (int plane = 0; plane < 5 && n > 0; plane++) {
        const cvert *in = buf[cur];
        cvert *out = buf[cur ^ 1];
        double d[16];
        bool any_out = false;
        for (int k = 0; k < n; k++) {
            d[k] = plane_dist(f, plane, in[k].c);
            if (in[k].orig >= 0 && kept[in[k].orig] && d[k] < 0.0)
                d[k] = 0.0; /* agree with the vertex pass */
            any_out |= !(d[k] >= 0.0);
        }
        if (!any_out)
            continue;
        int m = 0;
        for (int k = 0; k < n; k++) {
            int k2 = k + 1 == n ? 0 : k + 1;
            bool ia = d[k] >= 0.0, ib = d[k2] >= 0.0;
            if (ia)
                out[m++] = in[k];
            if (ia != ib) {
                const cvert *a = ia ? &in[k] : &in[k2], *b = ia ? &in[k2] : &in[k];
                double da = ia ? d[k] : d[k2], db = ia ? d[k2] : d[k];
                double t = da / (da - db);
                cvert v;
                for (int q = 0; q < 4; q++)
                    v.c[q] = a->c[q] + t * (b->c[q] - a->c[q]);
                v.orig = -1;
                out[m++] = v;
            }
        }
        n = m;
        cur ^= 1;
    }
    if (n < 3)
        return false;
    int32_t sx[16], sy[16];
    float sz[16];
    const cvert *poly = buf[cur];
    for (int k = 0; k < n; k++) {
        int ov = poly[k].orig;
        if (ov >= 0 && kept[ov]) {
            /* Exactly the neighbours' snapped vertex. */
            svert sv = f->verts[gi[ov]];
            sx[k] = sv.x;
            sy[k] = sv_y(sv);
            sz[k] = f->vz[gi[ov]];
        } else {
            const double *c = poly[k].c;
            if (!(c[3] > 0.0))
                return false;
            double iw = 1.0 / c[3];
            sx[k] = (int32_t)nearbyint(c[0] * iw * f->sx + f->sx);
            sy[k] = (int32_t)nearbyint(f->sy - c[1] * iw * f->sy);
            sz[k] = (float)(c[2] * iw);
        }
    }
    bool any = false;
    for (int k = 1; k + 1 < n; k++)
        any |= emit(f, o, sx[0], sy[0], sz[0], sx[k], sy[k], sz[k], sx[k + 1], sy[k + 1], sz[k + 1],
                    id, cull);
    return any;
}

/* One mesh's share of a chunk. */
typedef struct mesh_span {
    const uint32_t *idx;
    const svert *sv;
    const float *vz;
    const float *positions;
    uint64_t vb, tb; /* first global vertex and triangle of the mesh */
    uint32_t vc;
    bool cull;
} mesh_span;

/* The exact per-triangle path; returns 1 if the triangle made a record, -1 on a bad index. */
static inline int setup_tri(const frame *f, setup_out *o, const mesh_span *ms, uint64_t t)
{
    uint32_t a = ms->idx[3 * t], b = ms->idx[3 * t + 1], d = ms->idx[3 * t + 2];
    if (a >= ms->vc || b >= ms->vc || d >= ms->vc)
        return -1;
    svert va = ms->sv[a], vb = ms->sv[b], vd = ms->sv[d];
    unsigned ca = sv_code(va), cb = sv_code(vb), cd = sv_code(vd);
    if (ca & cb & cd & OUT_FRUSTUM)
        return 0;
    uint32_t id = (uint32_t)(ms->tb + t);
    if ((ca | cb | cd) & NEEDS_CLIP) {
        uint32_t vi[3] = {a, b, d};
        uint64_t gi[3] = {ms->vb + a, ms->vb + b, ms->vb + d};
        return setup_clipped(f, o, ms->positions, vi, gi, id, ms->cull);
    }
    return emit(f, o, va.x, sv_y(va), ms->vz[a], vb.x, sv_y(vb), ms->vz[b], vd.x, sv_y(vd),
                ms->vz[d], id, ms->cull);
}

static inline void prefetch_tri(const mesh_span *ms, uint64_t t)
{
    const uint32_t *q = ms->idx + 3 * t;
    for (int k = 0; k < 3; k++)
        __builtin_prefetch(&ms->sv[q[k] < ms->vc ? q[k] : 0]);
}

#ifdef __AVX2__
/* Eight triangles at a time, a conservative filter in front of setup_tri: a lane is dropped
 * only when setup_tri would drop it too (same outcode and bounding-box arithmetic; the area is
 * exact in int32 because lanes with a bounding box of 2^15 sub-pixels or more are passed on).
 * Most triangles of a dense mesh cover no pixel centre or face away, and rejecting them here
 * avoids a mispredicted branch or two each. Returns a mask of lanes to pass to setup_tri. */
static inline unsigned filter8(const frame *f, const mesh_span *ms, uint64_t t)
{
    /* 24 consecutive indices, de-interleaved into the first, second and third vertex of each
     * triangle (cheaper than three gathers). */
    const __m256i *ib = (const __m256i *)(ms->idx + 3 * t);
    __m256i v0 = _mm256_loadu_si256(ib), v1 = _mm256_loadu_si256(ib + 1),
            v2 = _mm256_loadu_si256(ib + 2);
    nc_v8i d[3];
    nc_v8_deinterleave3((nc_v8i)v0, (nc_v8i)v1, (nc_v8i)v2, &d[0], &d[1], &d[2]);
    const __m256i vi[3] = {(__m256i)d[0], (__m256i)d[1], (__m256i)d[2]};
    /* Bad indices: hand the lanes to setup_tri, which reports them. */
    const __m256i vmax = _mm256_set1_epi32((int)(ms->vc - 1));
    __m256i bad = _mm256_setzero_si256();
    for (int k = 0; k < 3; k++)
        bad = _mm256_or_si256(bad, _mm256_xor_si256(_mm256_max_epu32(vi[k], vmax), vmax));
    bad = _mm256_xor_si256(_mm256_cmpeq_epi32(bad, _mm256_setzero_si256()), _mm256_set1_epi32(-1));
    const int *base = (const int *)ms->sv;
    __m256i x[3], y[3], code_and = _mm256_set1_epi32(-1), code_or = _mm256_setzero_si256();
    const __m256i code_mask = _mm256_set1_epi32((1 << CODE_BITS) - 1);
    for (int k = 0; k < 3; k++) {
        __m256i off = _mm256_slli_epi32(_mm256_andnot_si256(bad, vi[k]), 1);
        x[k] = _mm256_i32gather_epi32(base + 0, off, 4);
        __m256i yc = _mm256_i32gather_epi32(base + 1, off, 4);
        __m256i code = _mm256_and_si256(yc, code_mask);
        y[k] = _mm256_srai_epi32(yc, CODE_BITS);
        code_and = _mm256_and_si256(code_and, code);
        code_or = _mm256_or_si256(code_or, code);
    }
    __m256i zero = _mm256_setzero_si256();
    __m256i out_frustum = _mm256_xor_si256(
        _mm256_cmpeq_epi32(_mm256_and_si256(code_and, _mm256_set1_epi32(OUT_FRUSTUM)), zero),
        _mm256_set1_epi32(-1));
    __m256i clip = _mm256_xor_si256(
        _mm256_cmpeq_epi32(_mm256_and_si256(code_or, _mm256_set1_epi32(NEEDS_CLIP)), zero),
        _mm256_set1_epi32(-1));
    __m256i minx = _mm256_min_epi32(x[0], _mm256_min_epi32(x[1], x[2]));
    __m256i maxx = _mm256_max_epi32(x[0], _mm256_max_epi32(x[1], x[2]));
    __m256i miny = _mm256_min_epi32(y[0], _mm256_min_epi32(y[1], y[2]));
    __m256i maxy = _mm256_max_epi32(y[0], _mm256_max_epi32(y[1], y[2]));
    __m256i i0 = _mm256_srai_epi32(
        _mm256_add_epi32(minx, _mm256_set1_epi32(SUB_ONE - 1 - SUB_HALF)), SUB_BITS);
    __m256i i1 = _mm256_srai_epi32(_mm256_sub_epi32(maxx, _mm256_set1_epi32(SUB_HALF)), SUB_BITS);
    __m256i j0 = _mm256_srai_epi32(
        _mm256_add_epi32(miny, _mm256_set1_epi32(SUB_ONE - 1 - SUB_HALF)), SUB_BITS);
    __m256i j1 = _mm256_srai_epi32(_mm256_sub_epi32(maxy, _mm256_set1_epi32(SUB_HALF)), SUB_BITS);
    i0 = _mm256_max_epi32(i0, zero);
    j0 = _mm256_max_epi32(j0, zero);
    i1 = _mm256_min_epi32(i1, _mm256_set1_epi32(f->width - 1));
    j1 = _mm256_min_epi32(j1, _mm256_set1_epi32(f->height - 1));
    __m256i empty = _mm256_or_si256(_mm256_cmpgt_epi32(i0, i1), _mm256_cmpgt_epi32(j0, j1));
    __m256i lim = _mm256_set1_epi32((1 << 15) - 1);
    __m256i large = _mm256_or_si256(_mm256_cmpgt_epi32(_mm256_sub_epi32(maxx, minx), lim),
                                    _mm256_cmpgt_epi32(_mm256_sub_epi32(maxy, miny), lim));
    __m256i area = _mm256_sub_epi32(
        _mm256_mullo_epi32(_mm256_sub_epi32(x[1], x[0]), _mm256_sub_epi32(y[2], y[0])),
        _mm256_mullo_epi32(_mm256_sub_epi32(x[2], x[0]), _mm256_sub_epi32(y[1], y[0])));
    __m256i no_area = _mm256_cmpeq_epi32(area, zero);
    if (ms->cull)
        no_area = _mm256_or_si256(no_area, _mm256_cmpgt_epi32(area, zero));
    /* Bounding boxes of at most 2 x 2 pixel centres: the exact coverage test of emit(), on the
     * oriented triangle (front faces are swapped there, which reverses every edge: E -> -E and
     * the top-left test mirrors). In int32: |dx|, |dy|, |P - A| < 2^15 here. */
    __m256i one = _mm256_set1_epi32(1);
    __m256i tiny =
        _mm256_and_si256(_mm256_cmpgt_epi32(_mm256_add_epi32(i0, _mm256_set1_epi32(2)), i1),
                         _mm256_cmpgt_epi32(_mm256_add_epi32(j0, _mm256_set1_epi32(2)), j1));
    tiny = _mm256_andnot_si256(
        _mm256_or_si256(_mm256_or_si256(clip, large), _mm256_or_si256(empty, no_area)), tiny);
    if (!_mm256_testz_si256(tiny, tiny)) {
        __m256i sdx[3], sdy[3], bias[3];
        for (int k = 0; k < 3; k++) {
            int k2 = k == 2 ? 0 : k + 1;
            /* sign_epi32(v, area): v * sign(area); oriented as emit() stores the triangle. */
            sdx[k] = _mm256_sign_epi32(_mm256_sub_epi32(x[k2], x[k]), area);
            sdy[k] = _mm256_sign_epi32(_mm256_sub_epi32(y[k2], y[k]), area);
            __m256i tl = _mm256_or_si256(_mm256_cmpgt_epi32(zero, sdy[k]),
                                         _mm256_and_si256(_mm256_cmpeq_epi32(sdy[k], zero),
                                                          _mm256_cmpgt_epi32(sdx[k], zero)));
            bias[k] = _mm256_andnot_si256(tl, one);
        }
        __m256i covered = zero;
        for (int c = 0; c < 4; c++) {
            __m256i ci = _mm256_add_epi32(i0, _mm256_set1_epi32(c & 1));
            __m256i cj = _mm256_add_epi32(j0, _mm256_set1_epi32(c >> 1));
            __m256i valid = _mm256_and_si256(_mm256_cmpgt_epi32(_mm256_add_epi32(i1, one), ci),
                                             _mm256_cmpgt_epi32(_mm256_add_epi32(j1, one), cj));
            __m256i pcx =
                _mm256_add_epi32(_mm256_slli_epi32(ci, SUB_BITS), _mm256_set1_epi32(SUB_HALF));
            __m256i pcy =
                _mm256_add_epi32(_mm256_slli_epi32(cj, SUB_BITS), _mm256_set1_epi32(SUB_HALF));
            __m256i in = valid;
            for (int k = 0; k < 3; k++) {
                __m256i e =
                    _mm256_sub_epi32(_mm256_mullo_epi32(sdx[k], _mm256_sub_epi32(pcy, y[k])),
                                     _mm256_mullo_epi32(sdy[k], _mm256_sub_epi32(pcx, x[k])));
                e = _mm256_sub_epi32(e, bias[k]);
                in = _mm256_and_si256(in, _mm256_cmpgt_epi32(e, _mm256_set1_epi32(-1)));
            }
            covered = _mm256_or_si256(covered, in);
        }
        empty = _mm256_or_si256(empty, _mm256_andnot_si256(covered, tiny));
    }
    /* Drop: outside the frustum, or (snappable, small and (no pixel centre or culled)). */
    __m256i drop =
        _mm256_andnot_si256(_mm256_or_si256(clip, large), _mm256_or_si256(empty, no_area));
    drop = _mm256_andnot_si256(bad, _mm256_or_si256(out_frustum, drop));
    return ~(unsigned)_mm256_movemask_ps(_mm256_castsi256_ps(drop)) & 0xffu;
}
#endif

/* Set up the global triangles [c->first, c->end). */
static void setup_chunk(const frame *f, chunk *c, uint32_t *counts)
{
    setup_out o = {c->recs, c->rec_cap, 0, counts, f->tiles_x};
    memset(counts, 0, (size_t)f->tiles_x * (size_t)f->tiles_y * sizeof(uint32_t));
    uint64_t drawn = 0;
    bool bad = false;
    uint64_t g = c->first;
    uint32_t m = 0;
    while (m + 1 < f->mesh_count && f->tbase[m + 1] <= g)
        m++;
    while (g < c->end) {
        const nc_raster_mesh *mesh = &f->meshes[m];
        mesh_span ms;
        ms.idx = mesh->indices;
        ms.sv = f->verts + f->vbase[m];
        ms.vz = f->vz + f->vbase[m];
        ms.positions = mesh->positions;
        ms.vb = f->vbase[m];
        ms.tb = f->tbase[m];
        ms.vc = mesh->vertex_count;
        ms.cull = f->cull && !mesh->double_sided;
        uint64_t stop = f->tbase[m + 1] < c->end ? f->tbase[m + 1] : c->end;
        uint64_t t = g - ms.tb, t_end = stop - ms.tb;
        /* Vertices are gathered from all over the array, so prefetch a few triangles ahead:
         * otherwise the loop waits on one cache miss at a time. */
#ifdef __AVX2__
        if (ms.vc < (1u << 30)) { /* gather offsets are vertex * 2 in int32 */
            /* Software pipeline: group t+8 is filtered (and its survivors' depths prefetched)
             * before the survivors of group t are set up. */
            unsigned next = t + 8 <= t_end ? filter8(f, &ms, t) : 0;
            for (; t + 8 <= t_end; t += 8) {
                if (t + PREFETCH_TRIS + 8 <= t_end)
                    for (int k = 0; k < 8; k++)
                        prefetch_tri(&ms, t + PREFETCH_TRIS + (uint64_t)k);
                unsigned keep = next;
                next = 0;
                if (t + 16 <= t_end) {
                    next = filter8(f, &ms, t + 8);
                    for (unsigned q = next; q; q &= q - 1) {
                        const uint32_t *ix = ms.idx + 3 * (t + 8 + (uint64_t)__builtin_ctz(q));
                        for (int k = 0; k < 3; k++)
                            __builtin_prefetch(&ms.vz[ix[k] < ms.vc ? ix[k] : 0]);
                    }
                }
                while (keep) {
                    int k = __builtin_ctz(keep);
                    keep &= keep - 1;
                    int res = setup_tri(f, &o, &ms, t + (uint64_t)k);
                    drawn += res > 0;
                    bad |= res < 0;
                }
            }
        }
#endif
        for (; t < t_end; t++) {
            if (t + PREFETCH_TRIS < t_end)
                prefetch_tri(&ms, t + PREFETCH_TRIS);
            int res = setup_tri(f, &o, &ms, t);
            drawn += res > 0;
            bad |= res < 0;
        }
        g = stop;
        m++;
    }
    c->rec_count = o.count;
    c->drawn = drawn;
    c->bad_index = bad;
}

/* ---- pass 4: tiles ---- */

static inline void put(const frame *f, size_t p, float z, uint32_t id)
{
    if (z < f->depth[p]) {
        f->depth[p] = z;
        if (f->ids)
            f->ids[p] = id;
    }
}

/* Depth along one span [lo, hi] of row j; the AVX2 path computes the same expression. */
static void fill_span(const frame *f, size_t row, int lo, int hi, float zrow, float dzdx,
                      int32_t cx, uint32_t id)
{
    float *restrict dr = f->depth + row;
    uint32_t *restrict ir = f->ids ? f->ids + row : NULL;
    const float inv = 1.0f / SUB_ONE;
    int i = lo;
#ifdef __AVX2__
    const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    const __m256 vinv = _mm256_set1_ps(inv), va = _mm256_set1_ps(dzdx), vzr = _mm256_set1_ps(zrow);
    const __m256i vid = _mm256_set1_epi32((int)id);
    /* Eight pixels a step; the last 1..7 masked, with the same expression. As a scalar loop they
     * cost a third of a shadow map's time: the next vector load of those pixels waited for their
     * one-float stores (no store forwarding). */
    for (; i <= hi; i += 8) {
        __m256i xi = _mm256_add_epi32(_mm256_set1_epi32(i), lane);
        __m256i xs = _mm256_add_epi32(_mm256_slli_epi32(xi, SUB_BITS), _mm256_set1_epi32(cx));
        __m256 fx = _mm256_mul_ps(_mm256_cvtepi32_ps(xs), vinv);
        __m256 z = _mm256_add_ps(vzr, _mm256_mul_ps(va, fx));
        if (i + 8 <= hi + 1) {
            __m256 old = _mm256_loadu_ps(dr + i);
            __m256 closer = _mm256_cmp_ps(z, old, _CMP_LT_OQ);
            _mm256_storeu_ps(dr + i, _mm256_blendv_ps(old, z, closer));
            if (ir) {
                __m256i oid = _mm256_loadu_si256((const __m256i *)(ir + i));
                __m256i nid = _mm256_castps_si256(
                    _mm256_blendv_ps(_mm256_castsi256_ps(oid), _mm256_castsi256_ps(vid), closer));
                _mm256_storeu_si256((__m256i *)(ir + i), nid);
            }
        } else {
            const __m256i m = _mm256_cmpgt_epi32(_mm256_set1_epi32(hi - i + 1), lane);
            __m256 old = _mm256_maskload_ps(dr + i, m);
            __m256i closer = _mm256_and_si256(_mm256_castps_si256(_mm256_cmp_ps(z, old, _CMP_LT_OQ)), m);
            _mm256_maskstore_ps(dr + i, closer, z);
            if (ir)
                _mm256_maskstore_epi32((int *)(ir + i), closer, vid);
        }
    }
#else
    for (; i <= hi; i++) {
        float fx = (float)(i * SUB_ONE + cx) * inv;
        float z = zrow + dzdx * fx;
        if (z < dr[i]) {
            dr[i] = z;
            if (ir)
                ir[i] = id;
        }
    }
#endif
}

static inline int32_t extent3(const int32_t v[3])
{
    int32_t lo = v[0] < v[1] ? v[0] : v[1], hi = v[0] < v[1] ? v[1] : v[0];
    lo = lo < v[2] ? lo : v[2];
    hi = hi > v[2] ? hi : v[2];
    return hi - lo;
}

/* Draw record r restricted to pixels [rx0, rx1] x [ry0, ry1]. */
static void draw(const frame *f, const tri_rec *r, int rx0, int ry0, int rx1, int ry1)
{
    int i0 = r->px0 > rx0 ? r->px0 : rx0, i1 = r->px1 < rx1 ? r->px1 : rx1;
    int j0 = r->py0 > ry0 ? r->py0 : ry0, j1 = r->py1 < ry1 ? r->py1 : ry1;
    if (i0 > i1 || j0 > j1)
        return;
    /* Edge values at the first pixel centre and their steps per pixel in x and y. */
    int64_t e[3], sx[3], sy[3];
    int64_t px = (int64_t)i0 * SUB_ONE + SUB_HALF, py = (int64_t)j0 * SUB_ONE + SUB_HALF;
    for (int k = 0; k < 3; k++) {
        int k2 = k == 2 ? 0 : k + 1;
        e[k] = edge_at(r->x, r->y, k, px, py);
        sx[k] = -((int64_t)r->y[k2] - r->y[k]) * SUB_ONE;
        sy[k] = ((int64_t)r->x[k2] - r->x[k]) * SUB_ONE;
    }
    const float inv = 1.0f / SUB_ONE;
    int32_t cx = SUB_HALF - r->x[0];
    size_t w = (size_t)f->width;
#ifdef __AVX2__
    /* Narrow boxes of small triangles, a row of up to 16 pixels (one or two vectors of 8) per
     * step without branches. Within a triangle's bounding box of under 64 px, and lanes up to 15
     * px past it, |E| < 2 x 2^14 x 2^15 = 2^30: int32 lanes suffice. */
    if (i1 - i0 < 16 && extent3(r->x) < 64 * SUB_ONE && extent3(r->y) < 64 * SUB_ONE) {
        const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        const int halves = i1 - i0 < 8 ? 1 : 2;
        __m256i ev[2][3], rowstep[3], valid[2];
        __m256 dzx[2];
        for (int h = 0; h < halves; h++) {
            const __m256i l = _mm256_add_epi32(lane, _mm256_set1_epi32(8 * h));
            for (int k = 0; k < 3; k++)
                ev[h][k] = _mm256_add_epi32(_mm256_set1_epi32((int32_t)e[k]),
                                            _mm256_mullo_epi32(l, _mm256_set1_epi32((int32_t)sx[k])));
            valid[h] = _mm256_cmpgt_epi32(_mm256_set1_epi32(i1 - i0 + 1), l);
            __m256i xs = _mm256_add_epi32(_mm256_slli_epi32(_mm256_add_epi32(_mm256_set1_epi32(i0), l), SUB_BITS),
                                          _mm256_set1_epi32(cx));
            __m256 fx = _mm256_mul_ps(_mm256_cvtepi32_ps(xs), _mm256_set1_ps(inv));
            dzx[h] = _mm256_mul_ps(_mm256_set1_ps(r->dzdx), fx);
        }
        for (int k = 0; k < 3; k++)
            rowstep[k] = _mm256_set1_epi32((int32_t)sy[k]);
        __m256i vid = _mm256_set1_epi32((int)r->id);
        for (int j = j0; j <= j1; j++) {
            float fy = (float)(j * SUB_ONE + SUB_HALF - r->y[0]) * inv;
            float zrow = r->z0 + r->dzdy * fy;
            for (int h = 0; h < halves; h++) {
                __m256i in = _mm256_or_si256(_mm256_or_si256(ev[h][0], ev[h][1]), ev[h][2]);
                in = _mm256_and_si256(_mm256_cmpgt_epi32(in, _mm256_set1_epi32(-1)), valid[h]);
                for (int k = 0; k < 3; k++)
                    ev[h][k] = _mm256_add_epi32(ev[h][k], rowstep[k]);
                if (_mm256_testz_si256(in, in))
                    continue;
                __m256 z = _mm256_add_ps(_mm256_set1_ps(zrow), dzx[h]);
                size_t at = (size_t)j * w + (size_t)i0 + (size_t)(8 * h);
                __m256 old = _mm256_maskload_ps(f->depth + at, in);
                __m256i closer =
                    _mm256_and_si256(_mm256_castps_si256(_mm256_cmp_ps(z, old, _CMP_LT_OQ)), in);
                _mm256_maskstore_ps(f->depth + at, closer, z);
                if (f->ids)
                    _mm256_maskstore_epi32((int *)(f->ids + at), closer, vid);
            }
        }
        return;
    }
#endif
    if (i1 - i0 + 1 < SPAN_MIN_WIDTH) {
        for (int j = j0; j <= j1; j++) {
            int64_t e0 = e[0], e1 = e[1], e2 = e[2];
            float fy = (float)(j * SUB_ONE + SUB_HALF - r->y[0]) * inv;
            float zrow = r->z0 + r->dzdy * fy;
            size_t row = (size_t)j * w;
            for (int i = i0; i <= i1; i++) {
                if ((e0 | e1 | e2) >= 0) {
                    float fx = (float)(i * SUB_ONE + cx) * inv;
                    put(f, row + (size_t)i, zrow + r->dzdx * fx, r->id);
                }
                e0 += sx[0];
                e1 += sx[1];
                e2 += sx[2];
            }
            e[0] += sy[0];
            e[1] += sy[1];
            e[2] += sy[2];
        }
        return;
    }
    /* Wide: solve each edge's inequality for the row's span. Edges that hold over the whole
     * region (affine, so checking the corners suffices) are dropped first. */
    int64_t nx = i1 - i0, ny = j1 - j0;
    int live[3], nlive = 0;
    for (int k = 0; k < 3; k++) {
        int64_t c00 = e[k], c10 = e[k] + sx[k] * nx, c01 = e[k] + sy[k] * ny;
        int64_t c11 = c10 + sy[k] * ny;
        if (c00 < 0 && c10 < 0 && c01 < 0 && c11 < 0)
            return;
        if (!(c00 >= 0 && c10 >= 0 && c01 >= 0 && c11 >= 0))
            live[nlive++] = k;
    }
    for (int j = j0; j <= j1; j++) {
        int64_t lo = 0, hi = nx;
        for (int q = 0; q < nlive; q++) {
            int k = live[q];
            int64_t ek = e[k] + sy[k] * (j - j0), s = sx[k];
            if (s > 0) { /* ek + s t >= 0  <=>  t >= ceil(-ek / s) */
                int64_t t = -floor_div(ek, s);
                if (t > lo)
                    lo = t;
            } else if (s < 0) { /* t <= floor(ek / -s) */
                int64_t t = floor_div(ek, -s);
                if (t < hi)
                    hi = t;
            } else if (ek < 0) {
                hi = -1;
            }
        }
        if (lo > hi)
            continue;
        float fy = (float)(j * SUB_ONE + SUB_HALF - r->y[0]) * inv;
        float zrow = r->z0 + r->dzdy * fy;
        fill_span(f, (size_t)j * w, i0 + (int)lo, i0 + (int)hi, zrow, r->dzdx, cx, r->id);
    }
}

/* Fill n 32-bit words with `value`; whole cache lines with streaming stores (the caller
 * fences). For tiles nothing touches: no read of the old contents, no cache pollution. */
static void fill32(void *dst, size_t n, uint32_t value, bool stream)
{
    uint32_t *p = dst;
#ifdef __AVX__
    if (stream && n >= 32) {
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
#else
    (void)stream;
#endif
    for (; n; n--)
        *p++ = value;
}

/* Global triangle ids of a tile -> (object, triangle within the object), while in cache. */
static void tile_ids(const frame *f, int x0, int y0, int x1, int y1)
{
    size_t w = (size_t)f->width;
    const uint64_t *tbase = f->tbase;
    uint32_t m = 0;
    for (int y = y0; y < y1; y++) {
        uint32_t *tri = f->ids + (size_t)y * w, *obj = f->objects + (size_t)y * w;
        for (int x = x0; x < x1; x++) {
            uint32_t g = tri[x];
            if (g == NC_NO_OBJECT) {
                obj[x] = NC_NO_OBJECT;
                continue;
            }
            if (g < tbase[m] || g >= tbase[m + 1]) { /* the mesh rarely changes */
                uint32_t lo = 0, hi = f->mesh_count - 1;
                while (lo < hi) {
                    uint32_t mid = (lo + hi + 1) / 2;
                    if (tbase[mid] <= g)
                        lo = mid;
                    else
                        hi = mid - 1;
                }
                m = lo;
            }
            obj[x] = f->meshes[m].object_index;
            tri[x] = (uint32_t)(g - tbase[m]);
        }
    }
}

static void draw_tile(const frame *f, const nc_rasterizer *rz, int tile)
{
    int tx = tile % f->tiles_x, ty = tile / f->tiles_x;
    int x0 = tx * TILE, y0 = ty * TILE;
    int x1 = x0 + TILE < f->width ? x0 + TILE : f->width;
    int y1 = y0 + TILE < f->height ? y0 + TILE : f->height;
    size_t w = (size_t)f->width, tw = (size_t)(x1 - x0);
    int cc = rz->chunk_count;
    const uint32_t *st = rz->start + (size_t)tile * (size_t)cc;
    bool empty = st[cc] == st[0];
    uint32_t one;
    float fone = 1.0f;
    memcpy(&one, &fone, sizeof(one));
    for (int y = y0; y < y1; y++) {
        size_t row = (size_t)y * w + (size_t)x0;
        fill32(f->depth + row, tw, one, empty);
        if (f->ids) {
            fill32(f->ids + row, tw, NC_NO_OBJECT, empty);
            if (empty)
                fill32(f->objects + row, tw, NC_NO_OBJECT, true);
        }
    }
    if (empty)
        return;
    for (int c = 0; c < cc; c++) {
        const tri_rec *recs = rz->chunks[c].recs;
        uint32_t end = st[c + 1];
        for (uint32_t q = st[c]; q < end; q++) {
            /* Records were written by the setup pass long ago (out of cache by now). */
            if (q + PREFETCH_RECS < end) {
                const char *ahead = (const char *)&recs[rz->refs[q + PREFETCH_RECS]];
                __builtin_prefetch(ahead);
                __builtin_prefetch(ahead + sizeof(tri_rec) - 1);
            }
            draw(f, &recs[rz->refs[q]], x0, y0, x1 - 1, y1 - 1);
        }
    }
    if (f->ids)
        tile_ids(f, x0, y0, x1, y1);
}

/* ---- the frame ---- */

static nacre_result check_args(nc_rasterizer *r, const nc_raster_view *view,
                               const nc_raster_mesh *meshes, uint32_t mesh_count)
{
    if (!view)
        return nc_fail(r->ctx, NACRE_ERROR_INVALID_ARGUMENT, "raster: view is NULL");
    if (view->width < 1 || view->height < 1 || view->width > MAX_SIZE || view->height > MAX_SIZE)
        return nc_fail(r->ctx, NACRE_ERROR_INVALID_ARGUMENT, "raster: invalid size %dx%d",
                       (int)view->width, (int)view->height);
    if (mesh_count && !meshes)
        return nc_fail(r->ctx, NACRE_ERROR_INVALID_ARGUMENT, "raster: meshes is NULL");
    uint64_t tris = 0;
    for (uint32_t m = 0; m < mesh_count; m++) {
        if (meshes[m].triangle_count && (!meshes[m].positions || !meshes[m].indices))
            return nc_fail(r->ctx, NACRE_ERROR_INVALID_ARGUMENT,
                           "raster: mesh %u: positions or indices are NULL", m);
        tris += meshes[m].triangle_count;
    }
    if (tris >= UINT32_MAX)
        return nc_fail(r->ctx, NACRE_ERROR_UNSUPPORTED, "raster: more than 2^32 - 2 triangles");
    return NACRE_OK;
}

/* Run passes 1-4 into f->depth / f->ids. */
static nacre_result run(nc_rasterizer *r, const nc_raster_view *view, const nc_raster_mesh *meshes,
                        uint32_t mesh_count, bool cull, float *depth, uint32_t *ids,
                        uint32_t *objects, nc_raster_counts *counts)
{
    nacre_context *ctx = r->ctx;
    nacre_result res = check_args(r, view, meshes, mesh_count);
    if (res != NACRE_OK)
        return res;
    int threads = nc_threads(ctx);
    frame f;
    memset(&f, 0, sizeof(f));
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++) {
            double acc = 0.0;
            for (int k = 0; k < 4; k++)
                acc += (double)view->proj.m[i][k] * view->view.m[k][j];
            f.md[i][j] = acc;
            f.m[i][j] = (float)acc;
        }
    f.width = view->width;
    f.height = view->height;
    f.sx = 0.5f * (float)view->width * SUB_ONE;
    f.sy = 0.5f * (float)view->height * SUB_ONE;
    f.gx = 1.0f + 2.0f * GUARD_PX / (float)view->width;
    f.gy = 1.0f + 2.0f * GUARD_PX / (float)view->height;
    f.tiles_x = (view->width + TILE - 1) / TILE;
    f.tiles_y = (view->height + TILE - 1) / TILE;
    f.meshes = meshes;
    f.mesh_count = mesh_count;
    f.cull = cull;
    f.depth = depth;
    f.ids = ids;
    f.objects = objects;

    /* Sizes and scratch. */
    if (mesh_count + 1 > r->mesh_cap) {
        nc_free(ctx, r->vbase);
        nc_free(ctx, r->tbase);
        r->mesh_cap = 0;
        r->vbase = nc_alloc(ctx, (mesh_count + 1) * sizeof(uint64_t));
        r->tbase = nc_alloc(ctx, (mesh_count + 1) * sizeof(uint64_t));
        if (!r->vbase || !r->tbase)
            return NACRE_ERROR_OUT_OF_MEMORY;
        r->mesh_cap = mesh_count + 1;
    }
    uint64_t nv = 0, nt = 0;
    for (uint32_t m = 0; m < mesh_count; m++) {
        r->vbase[m] = nv;
        r->tbase[m] = nt;
        nv += meshes[m].vertex_count;
        nt += meshes[m].triangle_count;
    }
    r->vbase[mesh_count] = nv;
    r->tbase[mesh_count] = nt;
    f.vbase = r->vbase;
    f.tbase = r->tbase;
    if (!grow(ctx, (void **)&r->verts, &r->vert_cap, nv, sizeof(svert)) ||
        !grow(ctx, (void **)&r->vz, &r->vz_cap, nv, sizeof(float)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    f.verts = r->verts;
    f.vz = r->vz;

    int cc = nt == 0 ? 1 : threads * CHUNKS_PER_THREAD;
    if (cc != r->chunk_count) {
        free_chunks(r);
        r->chunks = nc_calloc(ctx, (size_t)cc, sizeof(chunk));
        if (!r->chunks)
            return NACRE_ERROR_OUT_OF_MEMORY;
        r->chunk_count = cc;
    }
    size_t ntiles = (size_t)f.tiles_x * (size_t)f.tiles_y;
    size_t tcap = r->tile_cap, tcap2 = r->tile_cap;
    if (!grow(ctx, (void **)&r->counts, &tcap, ntiles * (size_t)cc, sizeof(uint32_t)) ||
        !grow(ctx, (void **)&r->start, &tcap2, ntiles * (size_t)cc + 1, sizeof(uint32_t))) {
        r->tile_cap = 0;
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    r->tile_cap = tcap < tcap2 ? tcap : tcap2;
    for (int c = 0; c < cc; c++) {
        chunk *ch = &r->chunks[c];
        ch->first = nt * (uint64_t)c / (uint64_t)cc;
        ch->end = nt * (uint64_t)(c + 1) / (uint64_t)cc;
        /* The fast path makes at most one record per triangle; clipping may need a redo. */
        size_t cap = ch->rec_cap;
        if (!grow(ctx, (void **)&ch->recs, &cap, (size_t)(ch->end - ch->first) + 16,
                  sizeof(tri_rec))) {
            ch->rec_cap = 0;
            return NACRE_ERROR_OUT_OF_MEMORY;
        }
        ch->rec_cap = (uint32_t)(cap > UINT32_MAX ? UINT32_MAX : cap);
    }

    /* Pass 1. */
    for (uint32_t m = 0; m < mesh_count; m++) {
        const nc_raster_mesh *mesh = &meshes[m];
        if (!mesh->vertex_count)
            continue;
        int64_t blocks = ((int64_t)mesh->vertex_count + 4095) / 4096;
        uint64_t vb = r->vbase[m];
#pragma omp parallel for num_threads(threads) schedule(static)
        for (int64_t b = 0; b < blocks; b++) {
            size_t lo = (size_t)b * 4096, hi = lo + 4096;
            if (hi > mesh->vertex_count)
                hi = mesh->vertex_count;
            transform_vertices(&f, mesh->positions + 3 * lo, hi - lo, r->verts + vb + lo,
                               r->vz + vb + lo);
        }
    }

    /* Pass 2, redone for chunks whose records overflowed (only when clipping made many). */
    for (int c = 0; c < cc; c++)
        r->chunks[c].redo = true;
    for (;;) {
#pragma omp parallel for num_threads(threads) schedule(dynamic, 1)
        for (int c = 0; c < cc; c++) {
            chunk *ch = &r->chunks[c];
            if (ch->redo)
                setup_chunk(&f, ch, r->counts + (size_t)c * ntiles);
        }
        bool again = false;
        for (int c = 0; c < cc; c++) {
            chunk *ch = &r->chunks[c];
            ch->redo = ch->rec_count > ch->rec_cap;
            if (ch->redo) {
                size_t cap = ch->rec_cap;
                if (!grow(ctx, (void **)&ch->recs, &cap, ch->rec_count, sizeof(tri_rec))) {
                    ch->rec_cap = 0;
                    return NACRE_ERROR_OUT_OF_MEMORY;
                }
                ch->rec_cap = (uint32_t)(cap > UINT32_MAX ? UINT32_MAX : cap);
                again = true;
            }
        }
        if (!again)
            break;
    }
    uint64_t drawn = 0;
    for (int c = 0; c < cc; c++) {
        if (r->chunks[c].bad_index)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "raster: index out of range");
        drawn += r->chunks[c].drawn;
    }

    /* Pass 3: offsets tile-major, chunk-minor; counts become per-chunk write cursors. */
    uint64_t total = 0;
    for (size_t t = 0; t < ntiles; t++) {
        for (int c = 0; c < cc; c++) {
            uint32_t *cnt = &r->counts[(size_t)c * ntiles + t];
            r->start[t * (size_t)cc + (size_t)c] = (uint32_t)total;
            total += *cnt;
            *cnt = (uint32_t)total - *cnt;
        }
        if (total > UINT32_MAX)
            return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "raster: too many tile references");
    }
    r->start[ntiles * (size_t)cc] = (uint32_t)total;
    if (!grow(ctx, (void **)&r->refs, &r->ref_cap, total, sizeof(uint32_t)))
        return NACRE_ERROR_OUT_OF_MEMORY;
#pragma omp parallel for num_threads(threads) schedule(dynamic, 1)
    for (int c = 0; c < cc; c++) {
        const chunk *ch = &r->chunks[c];
        uint32_t *cur = r->counts + (size_t)c * ntiles;
        for (uint32_t q = 0; q < ch->rec_count; q++) {
            const tri_rec *t = &ch->recs[q];
            int tx0 = t->px0 >> TILE_SHIFT, tx1 = t->px1 >> TILE_SHIFT;
            int ty0 = t->py0 >> TILE_SHIFT, ty1 = t->py1 >> TILE_SHIFT;
            for (int ty = ty0; ty <= ty1; ty++)
                for (int tx = tx0; tx <= tx1; tx++)
                    r->refs[cur[ty * f.tiles_x + tx]++] = q;
        }
    }

    /* Pass 4. */
    int ntiles_i = (int)ntiles;
#pragma omp parallel num_threads(threads)
    {
#pragma omp for schedule(dynamic, 1)
        for (int t = 0; t < ntiles_i; t++)
            draw_tile(&f, r, t);
#ifdef __AVX__
        _mm_sfence(); /* this thread's streaming stores, before the region ends */
#endif
    }

    if (counts) {
        counts->triangles = nt;
        counts->triangles_drawn = drawn;
    }
    return NACRE_OK;
}

nacre_result nc_raster_visibility(nc_rasterizer *r, const nc_raster_view *view,
                                  const nc_raster_mesh *meshes, uint32_t mesh_count,
                                  nc_vis_buffer *out, nc_raster_counts *counts)
{
    if (!r)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!out || !out->depth || !out->object || !out->triangle || !view ||
        out->width != view->width || out->height != view->height)
        return nc_fail(r->ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "raster: visibility buffer missing or not the view's size");
    return run(r, view, meshes, mesh_count, true, out->depth, out->triangle, out->object, counts);
}

nacre_result nc_raster_depth(nc_rasterizer *r, const nc_raster_view *view,
                             const nc_raster_mesh *meshes, uint32_t mesh_count,
                             bool cull_back_faces, float *depth)
{
    if (!r)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!depth)
        return nc_fail(r->ctx, NACRE_ERROR_INVALID_ARGUMENT, "raster: depth buffer is NULL");
    return run(r, view, meshes, mesh_count, cull_back_faces, depth, NULL, NULL, NULL);
}
