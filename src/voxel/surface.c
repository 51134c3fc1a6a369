/*
 * surface.c: the triangle pass of the voxelizer (seed 000, section 4.2: Schwarz and Seidel 2010,
 * "Fast parallel surface and solid voxelization on GPUs"): conservative surface voxelization of
 * every triangle into level 0, and in the same pass the parity toggles of the solid rules
 * (solid.c). Grid coordinates as in voxel_internal.h (one voxel = one unit).
 *
 * Surface: per triangle, the voxel bounding box; one voxel or one column (or one row along any
 * axis) is marked directly, since a triangle inside a 1 x 1 prism touches every voxel of the
 * prism its extent crosses. A triangle inside one layer along some axis (bounding box one voxel
 * thick) touches a voxel of the layer exactly when its projection along that axis touches the
 * voxel's square, so the three edge functions of that projection decide (SS10's 2D test).
 * Otherwise the full SS10 test: plane test with the critical-point offsets d1, d2, then the xy,
 * yz and zx edge functions offset to the box corner that maximises them. Touching counts
 * (<= / >=), so the set is conservative: with exact arithmetic it equals the set of closed boxes
 * the closed triangle meets. The per-voxel tests run on 2 x 2 tiles of voxels, four lanes at once.
 *
 * Triangle pass (AVX2): four triangles at a time, one per lane (load4, triangles4): grid
 * coordinates, normal, voxel bounds and column-centre ranges in doubles with the same operations
 * as the scalar path (triangle_one, used without AVX2, for meshes with a non-finite vertex and
 * for the last triangles), so both give the same bits. Bounds of one voxel or two in a line are
 * marked in the lanes; crossings that are the only column centre of their triangle are toggled in
 * the lanes (parity4: the lane form of solid.c's parity rule, kept here so that triangles4
 * inlines it), and so are the 2 x 2 footprints in one layer (flat4) and 2 x 2 x 2 bounds
 * (box4), which are most of the rest once voxels are a few triangles wide; what remains goes to
 * surface_bounded / nc_voxel_parity_triangle one triangle at a time.
 * On a coarse grid nearly every triangle lies strictly inside one voxel with no column line through
 * it, so all that work only sets one surface bit. A float prefilter (prefilter8) comes first, eight
 * triangles at a time: with a margin that covers the float error it proves that the double path
 * would do exactly that (one-voxel bounds, no parity work, not degenerate) and sets the bit; the
 * triangles it cannot clear are queued for load4 / triangles4, so the bits stay the same. At 4^3
 * (97% cleared) the triangle pass went from 112 to 78 instructions per triangle on Armadillo (400k
 * triangles) and an update (PARITY, 2 threads) about 30% faster (3.0 -> 2.1-2.3 ms; the Dragon's
 * 870k, 39%); at 28^3 (80% cleared) 5-15%. On finer grids most triangles fail it and it would cost
 * more than it saves: a range leaves it once its running pass rate drops below about 70%, which
 * keeps 64^3 and up at the exact path's instruction count (within 1%).
 *
 * Parallelism: chunks of triangles go to whichever thread is free. Bits are set with OR and
 * toggled with XOR, which commute, so the result does not depend on the thread count or the
 * schedule. On a small grid each thread but the first writes a private copy of the level-0 sets
 * with plain operations and the copies are merged after the pass; on a large one all threads
 * write the grid with atomic operations (a private copy would cost more to clear and merge).
 */
#include "voxel/voxel_internal.h"

#ifdef _OPENMP
#include <omp.h>
#endif

/* At least n words in *buf (contents undefined), reusing it when its capacity *cap suffices. */
static nacre_result words_reserve(nacre_context *ctx, uint64_t **buf, size_t *cap, size_t n)
{
    if (*buf && n <= *cap)
        return NACRE_OK;
    nc_free(ctx, *buf);
    *cap = 0;
    *buf = nc_alloc(ctx, (n ? n : 1) * 8);
    if (!*buf)
        return NACRE_ERROR_OUT_OF_MEMORY;
    *cap = n ? n : 1;
    return NACRE_OK;
}

/* Bits lo..hi (inclusive, 0 <= lo <= hi <= 63). */
static inline uint64_t bit_range(uint32_t lo, uint32_t hi)
{
    uint64_t top = hi == 63 ? ~0ull : ((1ull << (hi + 1)) - 1);
    return top & ~((1ull << lo) - 1);
}

/* Mark voxels z0..z1 of column (x, y). */
static inline void mark_run(uint64_t *set, const bitset *b, uint32_t x, uint32_t y, uint32_t z0,
                            uint32_t z1)
{
    uint64_t *col = set + ((size_t)y * b->dims[0] + x) * b->words;
    for (uint32_t w = z0 / 64; w <= z1 / 64; w++) {
        uint32_t lo = w == z0 / 64 ? z0 % 64 : 0, hi = w == z1 / 64 ? z1 % 64 : 63;
        bits_or(b->shared, col + w, bit_range(lo, hi));
    }
}

/* ------------------------------------------------------------------------------------------ */
/* Surface: Schwarz-Seidel triangle/box overlap                                              */
/* ------------------------------------------------------------------------------------------ */

typedef struct edge2 {
    double nx, ny, d;
} edge2;

/* The three edge functions of the projection onto axes (a, b), c the third axis of the
 * right-handed triple, offset so that "n . p + d >= 0 for all three" means the unit square at p
 * touches the projected triangle (SS10 eq. 4.3). */
static inline void setup_edges(const double v[3][3], const double n[3], int a, int b, int c, edge2 e[3])
{
    double s = n[c] >= 0 ? 1.0 : -1.0;
    for (int i = 0; i < 3; i++) {
        const double *p = v[i], *q = v[(i + 1) % 3];
        double ea = q[a] - p[a], eb = q[b] - p[b];
        double nx = -eb * s, ny = ea * s;
        e[i].nx = nx;
        e[i].ny = ny;
        e[i].d = -(nx * p[a] + ny * p[b]) + dmax(0.0, nx) + dmax(0.0, ny);
    }
}

/* Everything the per-voxel SS10 test needs, set up once per triangle. */
typedef struct ss10 {
    double n[3], d1, d2;
    edge2 exy[3], eyz[3], ezx[3];
} ss10;

static void ss10_setup(const double v[3][3], const double n[3], ss10 *s)
{
    double c[3];
    for (int a = 0; a < 3; a++) {
        s->n[a] = n[a];
        c[a] = n[a] > 0 ? 1.0 : 0.0;
    }
    s->d1 = n[0] * (c[0] - v[0][0]) + n[1] * (c[1] - v[0][1]) + n[2] * (c[2] - v[0][2]);
    s->d2 = n[0] * (1 - c[0] - v[0][0]) + n[1] * (1 - c[1] - v[0][1]) + n[2] * (1 - c[2] - v[0][2]);
    setup_edges(v, n, 0, 1, 2, s->exy);
    setup_edges(v, n, 1, 2, 0, s->eyz);
    setup_edges(v, n, 2, 0, 1, s->ezx);
}

/* The per-voxel tests work on 2 x 2 tiles of voxels, lane t at offset (t & 1, t >> 1) in the
 * two axes of the tile: four voxels per AVX2 instruction, and no branch per voxel. The scalar
 * version does the same double operations in the same order, so both give the same bits. */
#ifdef __AVX2__
typedef __m256d tile;
static inline tile tile_set(double base, int axis) /* axis 0: offsets 0 1 0 1, 1: 0 0 1 1 */
{
    __m256d off = axis ? _mm256_set_pd(1, 1, 0, 0) : _mm256_set_pd(1, 0, 1, 0);
    return _mm256_add_pd(_mm256_set1_pd(base), off);
}
static inline tile tile_one(double x) { return _mm256_set1_pd(x); }
static inline tile tile_lin(const edge2 *e, tile pa, tile pb) /* e.nx * pa + e.ny * pb + e.d */
{
    __m256d f = _mm256_add_pd(_mm256_mul_pd(_mm256_set1_pd(e->nx), pa), _mm256_mul_pd(_mm256_set1_pd(e->ny), pb));
    return _mm256_add_pd(f, _mm256_set1_pd(e->d));
}
static inline unsigned tile_ge0(tile f)
{
    return (unsigned)_mm256_movemask_pd(_mm256_cmp_pd(f, _mm256_setzero_pd(), _CMP_GE_OQ));
}
/* Plane test of SS10: (t + d1) (t + d2) <= 0, t = n . p, in the order of the scalar code. */
static inline unsigned tile_plane(const ss10 *s, tile x, tile y, tile z)
{
    tile np = _mm256_add_pd(_mm256_mul_pd(_mm256_set1_pd(s->n[0]), x),
                            _mm256_mul_pd(_mm256_set1_pd(s->n[1]), y));
    tile t = _mm256_add_pd(np, _mm256_mul_pd(_mm256_set1_pd(s->n[2]), z));
    tile p = _mm256_mul_pd(_mm256_add_pd(t, _mm256_set1_pd(s->d1)),
                           _mm256_add_pd(t, _mm256_set1_pd(s->d2)));
    return (unsigned)_mm256_movemask_pd(_mm256_cmp_pd(p, _mm256_setzero_pd(), _CMP_NGT_UQ));
}
#else
typedef struct tile {
    double l[4];
} tile;
static inline tile tile_set(double base, int axis)
{
    tile r;
    for (int t = 0; t < 4; t++)
        r.l[t] = base + (double)(axis ? t >> 1 : t & 1);
    return r;
}
static inline tile tile_one(double x)
{
    tile r = {{x, x, x, x}};
    return r;
}
static inline tile tile_lin(const edge2 *e, tile pa, tile pb)
{
    tile r;
    for (int t = 0; t < 4; t++)
        r.l[t] = e->nx * pa.l[t] + e->ny * pb.l[t] + e->d;
    return r;
}
static inline unsigned tile_ge0(tile f)
{
    unsigned m = 0;
    for (int t = 0; t < 4; t++)
        m |= (unsigned)(f.l[t] >= 0) << t;
    return m;
}
static inline unsigned tile_plane(const ss10 *s, tile x, tile y, tile z)
{
    unsigned m = 0;
    for (int t = 0; t < 4; t++) {
        double tt = s->n[0] * x.l[t] + s->n[1] * y.l[t] + s->n[2] * z.l[t];
        m |= (unsigned)!((tt + s->d1) * (tt + s->d2) > 0) << t;
    }
    return m;
}
#endif

/* Lanes of a tile that pass all three edge functions of one projection. */
static inline unsigned tile_edges(const edge2 e[3], tile pa, tile pb)
{
    return tile_ge0(tile_lin(&e[0], pa, pb)) & tile_ge0(tile_lin(&e[1], pa, pb)) & tile_ge0(tile_lin(&e[2], pa, pb));
}

/* Lanes of the tile starting at (i, j) that lie in the bounds (i <= hi_i, j <= hi_j). */
static inline unsigned tile_valid(int i, int hi_i, int j, int hi_j)
{
    return (i + 1 <= hi_i ? 0xFu : 0x5u) & (j + 1 <= hi_j ? 0xFu : 0x3u);
}

static inline void set_voxel(uint64_t *set, const bitset *b, uint32_t x, uint32_t y, uint32_t z)
{
    bits_or(b->shared, set + ((size_t)y * b->dims[0] + x) * b->words + z / 64, 1ull << (z % 64));
}

/* A triangle inside one closed layer along axis c touches a voxel of that layer exactly when its
 * projection along c touches the voxel's square (the layer holds the whole triangle), and every
 * square of the clamped bounds overlaps the projection's bounding box, so the three edge
 * functions of that projection decide alone (SS10's 2D test): the plane test and the two other
 * projections would only repeat it. */
static void surface_flat(const bitset *b, const double v[3][3], const double n[3], int c, const int lo[3],
                         const int hi[3])
{
    const int a = (c + 1) % 3, bb = (c + 2) % 3; /* (a, bb, c) right-handed, as setup_edges wants */
    edge2 e[3];
    setup_edges(v, n, a, bb, c, e);
    uint32_t p[3];
    p[c] = (uint32_t)lo[c];
    for (int j = lo[bb]; j <= hi[bb]; j += 2) {
        tile pb = tile_set(j, 1);
        for (int i = lo[a]; i <= hi[a]; i += 2) {
            unsigned m = tile_edges(e, tile_set(i, 0), pb) & tile_valid(i, hi[a], j, hi[bb]);
            for (; m; m &= m - 1) {
                unsigned t = (unsigned)__builtin_ctz(m);
                p[a] = (uint32_t)i + (t & 1u);
                p[bb] = (uint32_t)j + (t >> 1);
                set_voxel(b->surface, b, p[0], p[1], p[2]);
            }
        }
    }
}

/* The full SS10 test over the bounds: per 2 x 2 tile of columns the xy edge functions, then per
 * layer the plane test (critical-point offsets d1, d2) and the yz and zx edge functions offset to
 * the box corner that maximises them. Bits of a column are gathered per 64-bit word. */
static void surface_box(const bitset *b, const double v[3][3], const double n[3], const int lo[3], const int hi[3])
{
    ss10 s;
    ss10_setup(v, n, &s);
    for (int y = lo[1]; y <= hi[1]; y += 2) {
        tile ty = tile_set(y, 1);
        for (int x = lo[0]; x <= hi[0]; x += 2) {
            tile tx = tile_set(x, 0);
            unsigned mxy = tile_edges(s.exy, tx, ty) & tile_valid(x, hi[0], y, hi[1]);
            if (!mxy)
                continue;
            uint64_t *col[4], acc[4] = {0, 0, 0, 0};
            for (unsigned t = 0; t < 4; t++) {
                size_t cy = (size_t)y + (t >> 1), cx = (size_t)x + (t & 1);
                col[t] = b->surface + (cy * b->dims[0] + cx) * b->words;
            }
            int accw = lo[2] / 64;
            for (int z = lo[2]; z <= hi[2]; z++) {
                if (z / 64 != accw) {
                    for (unsigned t = 0; t < 4; t++)
                        if (acc[t])
                            bits_or(b->shared, col[t] + accw, acc[t]);
                    acc[0] = acc[1] = acc[2] = acc[3] = 0;
                    accw = z / 64;
                }
                tile tz = tile_one(z);
                unsigned m = mxy & tile_plane(&s, tx, ty, tz);
                m &= tile_edges(s.eyz, ty, tz) & tile_edges(s.ezx, tz, tx);
                for (unsigned t = 0; t < 4; t++)
                    acc[t] |= (uint64_t)((m >> t) & 1u) << (z % 64);
            }
            for (unsigned t = 0; t < 4; t++)
                if (acc[t])
                    bits_or(b->shared, col[t] + accw, acc[t]);
        }
    }
}

/* Surface voxels of a triangle with non-empty clamped voxel bounds lo..hi. Fast paths: a
 * triangle within a 1 x 1 prism along any axis touches every voxel of it that its extent
 * reaches (the prism cross-section contains its whole projection); one inside a single layer
 * needs only the 2D test of that layer (surface_flat). */
static void surface_bounded(const bitset *b, const double v[3][3], const double n[3], const int lo[3],
                            const int hi[3])
{
    if (lo[0] == hi[0] && lo[1] == hi[1]) {
        mark_run(b->surface, b, (uint32_t)lo[0], (uint32_t)lo[1], (uint32_t)lo[2], (uint32_t)hi[2]);
        return;
    }
    if ((lo[0] == hi[0] || lo[1] == hi[1]) && lo[2] == hi[2]) {
        for (int y = lo[1]; y <= hi[1]; y++)
            for (int x = lo[0]; x <= hi[0]; x++)
                mark_run(b->surface, b, (uint32_t)x, (uint32_t)y, (uint32_t)lo[2], (uint32_t)lo[2]);
        return;
    }
    for (int c = 0; c < 3; c++) {
        double l = lo[c], h = l + 1.0;
        if (lo[c] == hi[c] && v[0][c] >= l && v[1][c] >= l && v[2][c] >= l && v[0][c] <= h && v[1][c] <= h &&
            v[2][c] <= h) {
            surface_flat(b, v, n, c, lo, hi);
            return;
        }
    }
    surface_box(b, v, n, lo, hi);
}

/* Closed boxes: a coordinate exactly on a voxel face touches both voxels, hence ceil - 1. */
static void surface_triangle(const bitset *b, const double v[3][3], const double n[3])
{
    int lo[3], hi[3];
    for (int a = 0; a < 3; a++) {
        double mn = dmin(v[0][a], dmin(v[1][a], v[2][a]));
        double mx = dmax(v[0][a], dmax(v[1][a], v[2][a]));
        double l = dmax(ceil(mn) - 1.0, 0.0), h = dmin(floor(mx), (double)b->dims[a] - 1);
        if (l > h)
            return;
        lo[a] = (int)l;
        hi[a] = (int)h;
    }
    surface_bounded(b, v, n, lo, hi);
}

/* The reference path for one triangle: any vertex values, indices checked. */
static void triangle_one(const tri_out *o, const tri_source *src, uint32_t nv, size_t t, tri_counts *cnt)
{
    const uint32_t *ti = src->idx + 3 * t;
    if (ti[0] >= nv || ti[1] >= nv || ti[2] >= nv) {
        cnt->bad_index++;
        return;
    }
    double v[3][3], n[3];
    int st = load_triangle(src, t, v, n);
    cnt->degenerate += st == 2;
    cnt->nonfinite += st == 1;
    if (st != 0)
        return;
    surface_triangle(o->b, (const double(*)[3])v, n);
    nc_voxel_parity_triangle(o->b->solid, o->b, (const double(*)[3])v, n, 0, 1, 2);
    if (o->px) {
        nc_voxel_parity_triangle(o->px, o->b, (const double(*)[3])v, n, 1, 2, 0);
        nc_voxel_parity_triangle(o->py, o->b, (const double(*)[3])v, n, 2, 0, 1);
    }
}

#ifdef __AVX2__
typedef struct soa_consts {
    __m256d origin[3], inv_h, dimm1[3];
} soa_consts;

/* Corner ti of `pos` as four floats, the fourth being the next vertex's x (ignored) unless ti is
 * the last vertex, where a masked load keeps the read inside the array. */
static inline __m128 vertex_load(const float *pos, uint32_t ti, bool last)
{
    const float *p = pos + 3 * (size_t)ti;
    return last ? _mm_maskload_ps(p, _mm_set_epi32(0, -1, -1, -1)) : _mm_loadu_ps(p);
}

/* Four triangles (12 valid indices at ti, finite vertices) in grid coordinates, one triangle per
 * lane: v[corner][axis], with the same double operations as load_triangle. `last`: some index is
 * the last vertex's. */
static inline void load4(const float *pos, const uint32_t *ti, bool last, const soa_consts *k, __m256d v[3][3])
{
    for (int c = 0; c < 3; c++) {
        __m128 r0 = vertex_load(pos, ti[c], last), r1 = vertex_load(pos, ti[3 + c], last);
        __m128 r2 = vertex_load(pos, ti[6 + c], last), r3 = vertex_load(pos, ti[9 + c], last);
        _MM_TRANSPOSE4_PS(r0, r1, r2, r3);
        v[c][0] = _mm256_mul_pd(_mm256_sub_pd(_mm256_cvtps_pd(r0), k->origin[0]), k->inv_h);
        v[c][1] = _mm256_mul_pd(_mm256_sub_pd(_mm256_cvtps_pd(r1), k->origin[1]), k->inv_h);
        v[c][2] = _mm256_mul_pd(_mm256_sub_pd(_mm256_cvtps_pd(r2), k->origin[2]), k->inv_h);
    }
}

/* nc_voxel_parity_triangle for the lanes in `lanes`, each with exactly one column centre (pl[a] + 0.5,
 * pl[b] + 0.5) in its projected bounds: the same double operations lane by lane (orientation
 * swap, canonical edge order, top-left rule, crossing height). Returns the lanes done (all of
 * `lanes`, toggled or not). */
static unsigned parity4(uint64_t *flip, const bitset *bs, __m256d v[3][3], const __m256d n[3], const __m256d pl[3],
                        unsigned lanes, int a, int b, int c)
{
    const __m256d zero = _mm256_setzero_pd(), half = _mm256_set1_pd(0.5), sgn = _mm256_set1_pd(-0.0);
    /* n[c] == 0: edge-on, no crossing (as in nc_voxel_parity_triangle). */
    unsigned live = lanes & ~(unsigned)_mm256_movemask_pd(_mm256_cmp_pd(n[c], zero, _CMP_EQ_OQ));
    if (!live)
        return lanes;
    __m256d x = _mm256_add_pd(pl[a], half), y = _mm256_add_pd(pl[b], half);
    __m256d neg = _mm256_cmp_pd(n[c], zero, _CMP_LT_OQ); /* clockwise: swap corners 1 and 2 */
    __m256d pa[3], pb[3];
    pa[0] = v[0][a], pb[0] = v[0][b];
    pa[1] = _mm256_blendv_pd(v[1][a], v[2][a], neg), pb[1] = _mm256_blendv_pd(v[1][b], v[2][b], neg);
    pa[2] = _mm256_blendv_pd(v[2][a], v[1][a], neg), pb[2] = _mm256_blendv_pd(v[2][b], v[1][b], neg);
    __m256d inside = _mm256_castsi256_pd(_mm256_set1_epi64x(-1));
    for (int e = 0; e < 3; e++) {
        __m256d qa = pa[(e + 1) % 3], qb = pb[(e + 1) % 3];
        __m256d tie = _mm256_and_pd(_mm256_cmp_pd(pa[e], qa, _CMP_EQ_OQ), _mm256_cmp_pd(pb[e], qb, _CMP_GT_OQ));
        __m256d swap = _mm256_or_pd(_mm256_cmp_pd(pa[e], qa, _CMP_GT_OQ), tie);
        __m256d sa = _mm256_blendv_pd(pa[e], qa, swap), sb = _mm256_blendv_pd(pb[e], qb, swap);
        __m256d ta = _mm256_blendv_pd(qa, pa[e], swap), tb = _mm256_blendv_pd(qb, pb[e], swap);
        __m256d f = _mm256_sub_pd(_mm256_mul_pd(_mm256_sub_pd(ta, sa), _mm256_sub_pd(y, sb)),
                                  _mm256_mul_pd(_mm256_sub_pd(tb, sb), _mm256_sub_pd(x, sa)));
        f = _mm256_xor_pd(f, _mm256_and_pd(swap, sgn)); /* times -1 when swapped */
        __m256d flat = _mm256_and_pd(_mm256_cmp_pd(qb, pb[e], _CMP_EQ_OQ), _mm256_cmp_pd(qa, pa[e], _CMP_LT_OQ));
        __m256d tl = _mm256_or_pd(_mm256_cmp_pd(qb, pb[e], _CMP_LT_OQ), flat);
        __m256d on = _mm256_and_pd(_mm256_cmp_pd(f, zero, _CMP_EQ_OQ), tl);
        __m256d own = _mm256_or_pd(_mm256_cmp_pd(f, zero, _CMP_GT_OQ), on);
        inside = _mm256_and_pd(inside, own);
    }
    live &= (unsigned)_mm256_movemask_pd(inside);
    if (!live)
        return lanes;
    __m256d ga = _mm256_div_pd(_mm256_xor_pd(n[a], sgn), n[c]), gb = _mm256_div_pd(_mm256_xor_pd(n[b], sgn), n[c]);
    __m256d zc = _mm256_add_pd(_mm256_add_pd(v[0][c], _mm256_mul_pd(ga, _mm256_sub_pd(x, v[0][a]))),
                               _mm256_mul_pd(gb, _mm256_sub_pd(y, v[0][b])));
    __m256d k0 = _mm256_max_pd(_mm256_add_pd(_mm256_floor_pd(_mm256_sub_pd(zc, half)), _mm256_set1_pd(1.0)), zero);
    live &= (unsigned)_mm256_movemask_pd(_mm256_cmp_pd(k0, _mm256_set1_pd((double)bs->dims[c]), _CMP_LT_OQ));
    /* Voxel indices are below 4096: 32-bit integers, not a double-to-size_t conversion each. */
    int32_t ka[4], kb[4], kc[4];
    _mm_storeu_si128((__m128i *)ka, _mm256_cvttpd_epi32(pl[a]));
    _mm_storeu_si128((__m128i *)kb, _mm256_cvttpd_epi32(pl[b]));
    _mm_storeu_si128((__m128i *)kc, _mm256_cvttpd_epi32(k0));
    size_t stride[3] = {(size_t)64 * bs->words, (size_t)64 * bs->words * bs->dims[0], 1};
    for (; live; live &= live - 1) {
        int t = __builtin_ctz(live);
        size_t bit = (size_t)ka[t] * stride[a] + (size_t)kb[t] * stride[b] + (size_t)kc[t] * stride[c];
        bits_xor(bs->shared, flip + bit / 64, 1ull << (bit % 64));
    }
    return lanes;
}

/* setup_edges for four triangles, one per lane: the edge functions of the projection onto (a, b),
 * pa and pb the corners' a and b coordinates, nc the normal's third component; the same double
 * operations (s = -1 or 1 is a sign flip, exact either way). */
static inline void edges4(const __m256d pa[3], const __m256d pb[3], __m256d nc, __m256d nx[3], __m256d ny[3],
                          __m256d d[3])
{
    const __m256d zero = _mm256_setzero_pd(), sgn = _mm256_set1_pd(-0.0);
    __m256d sneg = _mm256_and_pd(_mm256_cmp_pd(nc, zero, _CMP_NGE_UQ), sgn), spos = _mm256_andnot_pd(sneg, sgn);
    for (int i = 0; i < 3; i++) {
        __m256d ea = _mm256_sub_pd(pa[(i + 1) % 3], pa[i]), eb = _mm256_sub_pd(pb[(i + 1) % 3], pb[i]);
        nx[i] = _mm256_xor_pd(eb, spos); /* -eb * s */
        ny[i] = _mm256_xor_pd(ea, sneg); /* ea * s */
        __m256d t = _mm256_xor_pd(_mm256_add_pd(_mm256_mul_pd(nx[i], pa[i]), _mm256_mul_pd(ny[i], pb[i])), sgn);
        d[i] = _mm256_add_pd(_mm256_add_pd(t, _mm256_max_pd(zero, nx[i])), _mm256_max_pd(zero, ny[i]));
    }
}

/* Lanes where all three edge functions are >= 0 at (x, y), as tile_edges / tile_lin compute it. */
static inline __m256d edges4_in(const __m256d nx[3], const __m256d ny[3], const __m256d d[3], __m256d x, __m256d y)
{
    const __m256d zero = _mm256_setzero_pd();
    __m256d in = _mm256_castsi256_pd(_mm256_set1_epi64x(-1));
    for (int i = 0; i < 3; i++) {
        __m256d f = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(nx[i], x), _mm256_mul_pd(ny[i], y)), d[i]);
        in = _mm256_and_pd(in, _mm256_cmp_pd(f, zero, _CMP_GE_OQ));
    }
    return in;
}

/* surface_flat for the lanes whose bounds are 2 x 2 voxels in one layer that holds the whole
 * triangle (on a grid with voxels a few triangles wide, most triangles that are not in a 1 x 1
 * prism), four at once: per lane the flat axis c and its (a, b) projection are picked with blends,
 * then the edge functions of setup_edges and tile_lin with the same double operations. Such
 * bounds have one axis of one voxel, so surface_bounded's run and row cases never apply and the
 * first flat axis it would find is the only one. Returns the lanes done. */
static __attribute__((noinline)) unsigned flat4(const bitset *bs, __m256d v[3][3], const __m256d n[3],
                                                 const __m128i li[3], const __m128i hi[3], const int32_t lo[3][4],
                                                 unsigned lanes)
{
    __m256d l[3], h[3]; /* the voxel bounds again as doubles (small integers: exact) */
    for (int a = 0; a < 3; a++) {
        l[a] = _mm256_cvtepi32_pd(li[a]);
        h[a] = _mm256_cvtepi32_pd(hi[a]);
    }
    const __m256d one = _mm256_set1_pd(1.0);
    __m256d eq[3], two[3];
    for (int a = 0; a < 3; a++) {
        __m256d top = _mm256_add_pd(l[a], one);
        __m256d in = _mm256_and_pd(_mm256_cmp_pd(v[0][a], l[a], _CMP_GE_OQ), _mm256_cmp_pd(v[0][a], top, _CMP_LE_OQ));
        in = _mm256_and_pd(in, _mm256_and_pd(_mm256_cmp_pd(v[1][a], l[a], _CMP_GE_OQ), _mm256_cmp_pd(v[1][a], top, _CMP_LE_OQ)));
        in = _mm256_and_pd(in, _mm256_and_pd(_mm256_cmp_pd(v[2][a], l[a], _CMP_GE_OQ), _mm256_cmp_pd(v[2][a], top, _CMP_LE_OQ)));
        eq[a] = _mm256_and_pd(_mm256_cmp_pd(l[a], h[a], _CMP_EQ_OQ), in);
        two[a] = _mm256_cmp_pd(_mm256_sub_pd(h[a], l[a]), one, _CMP_EQ_OQ);
    }
    __m256d c0 = _mm256_and_pd(eq[0], _mm256_and_pd(two[1], two[2]));
    __m256d c1 = _mm256_and_pd(eq[1], _mm256_and_pd(two[2], two[0]));
    __m256d c2 = _mm256_and_pd(eq[2], _mm256_and_pd(two[0], two[1]));
    unsigned m0 = (unsigned)_mm256_movemask_pd(c0), m1 = (unsigned)_mm256_movemask_pd(c1);
    lanes &= m0 | m1 | (unsigned)_mm256_movemask_pd(c2);
    if (!lanes)
        return 0;
    /* (a, b) = (1, 2) for c = 0, (2, 0) for c = 1, (0, 1) for c = 2. */
    __m256d pa[3], pb[3];
    for (int k = 0; k < 3; k++) {
        pa[k] = _mm256_blendv_pd(_mm256_blendv_pd(v[k][0], v[k][2], c1), v[k][1], c0);
        pb[k] = _mm256_blendv_pd(_mm256_blendv_pd(v[k][1], v[k][0], c1), v[k][2], c0);
    }
    __m256d la = _mm256_blendv_pd(_mm256_blendv_pd(l[0], l[2], c1), l[1], c0);
    __m256d lb = _mm256_blendv_pd(_mm256_blendv_pd(l[1], l[0], c1), l[2], c0);
    __m256d nc = _mm256_blendv_pd(_mm256_blendv_pd(n[2], n[1], c1), n[0], c0);
    __m256d ex[3], ey[3], ed[3];
    edges4(pa, pb, nc, ex, ey, ed);
    unsigned hit[4];
    for (int t = 0; t < 4; t++) /* tile_set's lane offsets (t & 1, t >> 1) */
        hit[t] = (unsigned)_mm256_movemask_pd(edges4_in(ex, ey, ed, _mm256_add_pd(la, _mm256_set1_pd((double)(t & 1))),
                                                        _mm256_add_pd(lb, _mm256_set1_pd((double)(t >> 1)))));
    for (unsigned m = lanes; m; m &= m - 1) {
        int k = __builtin_ctz(m);
        unsigned bit = 1u << k;
        int c = m0 & bit ? 0 : m1 & bit ? 1 : 2, a = (c + 1) % 3, b = (c + 2) % 3;
        uint32_t p[3];
        p[c] = (uint32_t)lo[c][k];
        for (int t = 0; t < 4; t++)
            if (hit[t] & bit) {
                p[a] = (uint32_t)lo[a][k] + (uint32_t)(t & 1);
                p[b] = (uint32_t)lo[b][k] + (uint32_t)(t >> 1);
                set_voxel(bs->surface, bs, p[0], p[1], p[2]);
            }
    }
    return lanes;
}

/* surface_box for the lanes whose bounds are 2 x 2 x 2 voxels (after flat4, most of the rest on a
 * grid with voxels a few triangles wide), four at once: ss10_setup and the per-voxel plane and
 * edge tests with the same double operations. Returns the lanes done. */
static __attribute__((noinline)) unsigned box4(const bitset *bs, __m256d v[3][3], const __m256d n[3],
                                                const __m128i li[3], const __m128i hi[3], const int32_t lo[3][4],
                                                unsigned lanes)
{
    __m256d l[3], h[3];
    for (int a = 0; a < 3; a++) {
        l[a] = _mm256_cvtepi32_pd(li[a]);
        h[a] = _mm256_cvtepi32_pd(hi[a]);
    }
    const __m256d zero = _mm256_setzero_pd(), one = _mm256_set1_pd(1.0);
    __m256d two = _mm256_and_pd(_mm256_cmp_pd(_mm256_sub_pd(h[0], l[0]), one, _CMP_EQ_OQ),
                                _mm256_cmp_pd(_mm256_sub_pd(h[1], l[1]), one, _CMP_EQ_OQ));
    two = _mm256_and_pd(two, _mm256_cmp_pd(_mm256_sub_pd(h[2], l[2]), one, _CMP_EQ_OQ));
    lanes &= (unsigned)_mm256_movemask_pd(two);
    if (!lanes)
        return 0;
    /* Plane offsets: c = 1 where n > 0, d1 = n . (c - v0), d2 = n . (1 - c - v0). */
    __m256d d1 = zero, d2 = zero;
    for (int a = 0; a < 3; a++) {
        __m256d c = _mm256_and_pd(_mm256_cmp_pd(n[a], zero, _CMP_GT_OQ), one);
        __m256d t1 = _mm256_mul_pd(n[a], _mm256_sub_pd(c, v[0][a]));
        __m256d t2 = _mm256_mul_pd(n[a], _mm256_sub_pd(_mm256_sub_pd(one, c), v[0][a]));
        d1 = a ? _mm256_add_pd(d1, t1) : t1;
        d2 = a ? _mm256_add_pd(d2, t2) : t2;
    }
    __m256d ex[3][3], ey[3][3], ed[3][3]; /* projections xy, yz, zx */
    for (int c = 0; c < 3; c++) {
        int a = (c + 1) % 3, b = (c + 2) % 3, slot = (c + 1) % 3; /* c = 2, 0, 1: xy, yz, zx */
        __m256d pa[3] = {v[0][a], v[1][a], v[2][a]}, pb[3] = {v[0][b], v[1][b], v[2][b]};
        edges4(pa, pb, n[c], ex[slot], ey[slot], ed[slot]);
    }
    __m256d p[3][2];
    for (int a = 0; a < 3; a++) {
        p[a][0] = l[a];
        p[a][1] = _mm256_add_pd(l[a], one);
    }
    __m256d xy[4], yz[4], zx[4];
    for (int i = 0; i < 2; i++)
        for (int j = 0; j < 2; j++) {
            xy[i + 2 * j] = edges4_in(ex[0], ey[0], ed[0], p[0][i], p[1][j]); /* (x, y) */
            yz[i + 2 * j] = edges4_in(ex[1], ey[1], ed[1], p[1][i], p[2][j]); /* (y, z) */
            zx[i + 2 * j] = edges4_in(ex[2], ey[2], ed[2], p[2][i], p[0][j]); /* (z, x) */
        }
    unsigned hit[8];
    for (int q = 0; q < 8; q++) {
        int dx = q & 1, dy = (q >> 1) & 1, dz = q >> 2;
        __m256d t = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(n[0], p[0][dx]), _mm256_mul_pd(n[1], p[1][dy])),
                                  _mm256_mul_pd(n[2], p[2][dz]));
        __m256d pr = _mm256_mul_pd(_mm256_add_pd(t, d1), _mm256_add_pd(t, d2));
        __m256d in = _mm256_and_pd(_mm256_cmp_pd(pr, zero, _CMP_NGT_UQ), xy[dx + 2 * dy]);
        in = _mm256_and_pd(in, _mm256_and_pd(yz[dy + 2 * dz], zx[dz + 2 * dx]));
        hit[q] = (unsigned)_mm256_movemask_pd(in);
    }
    for (unsigned m = lanes; m; m &= m - 1) {
        int k = __builtin_ctz(m);
        unsigned bit = 1u << k;
        for (int q = 0; q < 8; q++)
            if (hit[q] & bit)
                set_voxel(bs->surface, bs, (uint32_t)lo[0][k] + (uint32_t)(q & 1), (uint32_t)lo[1][k] + (uint32_t)((q >> 1) & 1),
                          (uint32_t)lo[2][k] + (uint32_t)(q >> 2));
    }
    return lanes;
}

/* OR the surface bits m0 (lane t: word w0[t]) and m1 (words w1[t]) in, after one look at the eight
 * words: on a coarse grid the bits are nearly always set already (a plain gather; a stale word only
 * sends us to bits_or, which reads again). Lanes with a zero mask change nothing. */
static inline void surface_or8(const bitset *b, __m128i w0, __m256i m0, __m128i w1, __m256i m1)
{
    __m256i g0 = _mm256_i32gather_epi64((const long long *)b->surface, w0, 8);
    __m256i g1 = _mm256_i32gather_epi64((const long long *)b->surface, w1, 8);
    __m256i miss = _mm256_or_si256(_mm256_andnot_si256(g0, m0), _mm256_andnot_si256(g1, m1));
    if (_mm256_testz_si256(miss, miss))
        return;
    uint32_t w[2][4];
    uint64_t m[2][4];
    _mm_storeu_si128((__m128i *)w[0], w0);
    _mm_storeu_si128((__m128i *)w[1], w1);
    _mm256_storeu_si256((__m256i *)m[0], m0);
    _mm256_storeu_si256((__m256i *)m[1], m1);
    for (int t = 0; t < 4; t++) {
        bits_or(b->shared, b->surface + w[0][t], m[0][t]);
        bits_or(b->shared, b->surface + w[1][t], m[1][t]);
    }
}

/* Four triangles at once, one per lane: the normal, the surface bounds of surface_triangle and
 * the column-centre ranges of nc_voxel_parity_triangle, all with the same double operations, so every
 * decision is bit-identical to triangle_one. A triangle inside one voxel with no column centre
 * in any projection (nearly all triangles of a large mesh on a coarse grid) ends here with one
 * bit set; the others go on to surface_bounded / nc_voxel_parity_triangle with the same arguments as in
 * triangle_one. Returns the number of zero-area triangles. */
static inline __attribute__((always_inline)) uint32_t triangles4(const tri_out *o, const soa_consts *k, __m256d v[3][3])
{
    const bitset *b = o->b;
    const __m256d zero = _mm256_setzero_pd(), one = _mm256_set1_pd(1.0), half = _mm256_set1_pd(0.5);
    __m256d e1[3], e2[3], n[3];
    for (int a = 0; a < 3; a++) {
        e1[a] = _mm256_sub_pd(v[1][a], v[0][a]);
        e2[a] = _mm256_sub_pd(v[2][a], v[0][a]);
    }
    n[0] = _mm256_sub_pd(_mm256_mul_pd(e1[1], e2[2]), _mm256_mul_pd(e1[2], e2[1]));
    n[1] = _mm256_sub_pd(_mm256_mul_pd(e1[2], e2[0]), _mm256_mul_pd(e1[0], e2[2]));
    n[2] = _mm256_sub_pd(_mm256_mul_pd(e1[0], e2[1]), _mm256_mul_pd(e1[1], e2[0]));
    unsigned deg = (unsigned)_mm256_movemask_pd(
        _mm256_and_pd(_mm256_cmp_pd(n[0], zero, _CMP_EQ_OQ),
                      _mm256_and_pd(_mm256_cmp_pd(n[1], zero, _CMP_EQ_OQ), _mm256_cmp_pd(n[2], zero, _CMP_EQ_OQ))));
    unsigned empty = 0, pok[3] = {0, 0, 0}, pone[3] = {0, 0, 0};
    __m256d ext = zero, pl[3] = {zero, zero, zero};
    __m128i li[3], hi4[3];
    const bool robust = o->px != NULL;
    for (int a = 0; a < 3; a++) {
        __m256d mn = _mm256_min_pd(v[0][a], _mm256_min_pd(v[1][a], v[2][a]));
        __m256d mx = _mm256_max_pd(v[0][a], _mm256_max_pd(v[1][a], v[2][a]));
        __m256d l = _mm256_max_pd(_mm256_sub_pd(_mm256_ceil_pd(mn), one), zero);
        __m256d h = _mm256_min_pd(_mm256_floor_pd(mx), k->dimm1[a]);
        empty |= (unsigned)_mm256_movemask_pd(_mm256_cmp_pd(l, h, _CMP_GT_OQ));
        ext = _mm256_add_pd(ext, _mm256_sub_pd(h, l));
        if (a < 2 || robust) { /* PARITY needs the column centres of the xy projection only */
            pl[a] = _mm256_max_pd(_mm256_ceil_pd(_mm256_sub_pd(mn, half)), zero);
            __m256d ph = _mm256_min_pd(_mm256_floor_pd(_mm256_sub_pd(mx, half)), k->dimm1[a]);
            pok[a] = (unsigned)_mm256_movemask_pd(_mm256_cmp_pd(pl[a], ph, _CMP_LE_OQ));
            pone[a] = (unsigned)_mm256_movemask_pd(_mm256_cmp_pd(pl[a], ph, _CMP_EQ_OQ));
        }
        li[a] = _mm256_cvttpd_epi32(l);
        hi4[a] = _mm256_cvttpd_epi32(h);
    }
    unsigned zpar = pok[0] & pok[1] & ~deg;
    unsigned xpar = robust ? pok[1] & pok[2] & ~deg : 0, ypar = robust ? pok[2] & pok[0] & ~deg : 0;
    unsigned surf = ~empty & ~deg & 0xF;
    /* Bounds of one voxel, or two in a line (a 1 x 1 prism): its lowest and highest voxels are
     * all the voxels it touches (surface_bounded's first fast paths). Marked without a branch per
     * lane: the other lanes get an empty mask on word 0. */
    unsigned line = surf & (unsigned)_mm256_movemask_pd(_mm256_cmp_pd(ext, one, _CMP_LE_OQ));
    if (line) {
        const __m128i nx = _mm_set1_epi32((int)b->dims[0]), nw = _mm_set1_epi32((int)b->words);
        const __m128i m63 = _mm_set1_epi32(63), lane32 = _mm_set_epi32(8, 4, 2, 1);
        const __m256i lane64 = _mm256_set_epi64x(8, 4, 2, 1), one64 = _mm256_set1_epi64x(1);
        __m128i on32 = _mm_cmpeq_epi32(_mm_and_si128(_mm_set1_epi32((int)line), lane32), lane32);
        __m256i on64 = _mm256_cmpeq_epi64(_mm256_and_si256(_mm256_set1_epi64x(line), lane64), lane64);
        /* Word indices fit in 32 bits (at most 4096^2 columns of 64 words); other lanes read word 0. */
        __m128i wl = _mm_add_epi32(_mm_mullo_epi32(_mm_add_epi32(_mm_mullo_epi32(li[1], nx), li[0]), nw),
                                   _mm_srli_epi32(li[2], 6));
        __m128i wh = _mm_add_epi32(_mm_mullo_epi32(_mm_add_epi32(_mm_mullo_epi32(hi4[1], nx), hi4[0]), nw),
                                   _mm_srli_epi32(hi4[2], 6));
        wl = _mm_and_si128(wl, on32);
        wh = _mm_and_si128(wh, on32);
        __m256i bl = _mm256_cvtepu32_epi64(_mm_and_si128(li[2], m63));
        __m256i bh = _mm256_cvtepu32_epi64(_mm_and_si128(hi4[2], m63));
        __m256i ml = _mm256_and_si256(_mm256_sllv_epi64(one64, bl), on64);
        __m256i mh = _mm256_and_si256(_mm256_sllv_epi64(one64, bh), on64);
        surface_or8(b, wl, ml, wh, mh);
    }
    /* Most crossings are the only column centre of their triangle: done here, four at a time. */
    if (zpar & pone[0] & pone[1])
        zpar &= ~parity4(b->solid, b, v, n, pl, zpar & pone[0] & pone[1], 0, 1, 2);
    if (xpar & pone[1] & pone[2])
        xpar &= ~parity4(o->px, b, v, n, pl, xpar & pone[1] & pone[2], 1, 2, 0);
    if (ypar & pone[2] & pone[0])
        ypar &= ~parity4(o->py, b, v, n, pl, ypar & pone[2] & pone[0], 2, 0, 1);
    unsigned box = surf & ~line;
    int32_t lo[3][4], hi[3][4];
    if (box) {
        for (int a = 0; a < 3; a++) {
            _mm_storeu_si128((__m128i *)lo[a], li[a]);
            _mm_storeu_si128((__m128i *)hi[a], hi4[a]);
        }
        box &= ~flat4(b, v, n, li, hi4, (const int32_t(*)[4])lo, box);
        if (box)
            box &= ~box4(b, v, n, li, hi4, (const int32_t(*)[4])lo, box);
    }
    unsigned slow = box | zpar | xpar | ypar;
    if (slow) {
        double vs[3][3][4], ns[3][4];
        for (int a = 0; a < 3; a++) {
            _mm_storeu_si128((__m128i *)lo[a], li[a]);
            _mm_storeu_si128((__m128i *)hi[a], hi4[a]);
        }
        for (int c = 0; c < 3; c++)
            for (int a = 0; a < 3; a++)
                _mm256_storeu_pd(vs[c][a], v[c][a]);
        for (int a = 0; a < 3; a++)
            _mm256_storeu_pd(ns[a], n[a]);
        for (; slow; slow &= slow - 1) {
            int t = __builtin_ctz(slow);
            unsigned bit = 1u << t;
            double vv[3][3], nn[3];
            for (int c = 0; c < 3; c++)
                for (int a = 0; a < 3; a++)
                    vv[c][a] = vs[c][a][t];
            for (int a = 0; a < 3; a++)
                nn[a] = ns[a][t];
            if (box & bit) {
                int l3[3] = {lo[0][t], lo[1][t], lo[2][t]}, h3[3] = {hi[0][t], hi[1][t], hi[2][t]};
                surface_bounded(b, (const double(*)[3])vv, nn, l3, h3);
            }
            if (zpar & bit)
                nc_voxel_parity_triangle(b->solid, b, (const double(*)[3])vv, nn, 0, 1, 2);
            if (xpar & bit)
                nc_voxel_parity_triangle(o->px, b, (const double(*)[3])vv, nn, 1, 2, 0);
            if (ypar & bit)
                nc_voxel_parity_triangle(o->py, b, (const double(*)[3])vv, nn, 2, 0, 1);
        }
    }
    return (uint32_t)__builtin_popcount(deg);
}

/* The 12 indices at ti: 0 if one is >= nv, 1 if all are valid and one is nv - 1, else 2. */
static inline int indices_check4(const uint32_t *ti, uint32_t nv)
{
    __m256i a = _mm256_loadu_si256((const __m256i *)ti);
    __m128i m = _mm_loadu_si128((const __m128i *)(ti + 8));
    m = _mm_max_epu32(m, _mm_max_epu32(_mm256_castsi256_si128(a), _mm256_extracti128_si256(a, 1)));
    m = _mm_max_epu32(m, _mm_shuffle_epi32(m, _MM_SHUFFLE(1, 0, 3, 2)));
    m = _mm_max_epu32(m, _mm_shuffle_epi32(m, _MM_SHUFFLE(2, 3, 0, 1)));
    uint32_t top = (uint32_t)_mm_cvtsi128_si32(m);
    return top >= nv ? 0 : top == nv - 1 ? 1 : 2;
}

typedef struct pre_consts {
    __m256 origin[3], inv_h, dimm1[3];
    __m256 m; /* margin */
    __m128i nx, words;
    bool robust;
} pre_consts;

/* The conservative float prefilter: the lanes of eight triangles (24 valid indices at ti, finite vertices)
 * for which triangles4 would certainly do nothing but mark one surface voxel, and that voxel marked. The
 * others are left for the exact path.
 *
 * Why it is safe (g the exact (p - origin) / h, m the margin of voxelize_impl, S = (|p|max + |origin|max) / h):
 * the float g differs from g by at most 3 roundings of 2^-24 relative (p - origin, the float 1/h, the
 * product), the double from triangles4 by 2 of 2^-53, so each corner, hence each min and max, is within
 * 4 * 2^-24 * S of the double one; m = 64 * 2^-24 * S + 1e-6 also covers the float roundings of mn - m and
 * the like (2^-24 of values below S + 1 each). So floor(mn - m) == floor(mx + m) == k puts the double min
 * and max strictly inside (k, k + 1): triangles4's voxel bounds are l = h = k (the clamps do nothing for
 * 0 <= k < dims), a one-voxel "line", and the same holds for the column-centre ranges, which are empty
 * (pl > ph) along every axis without `maybe`; PARITY walks the z lines only when both x and y ranges are
 * non-empty, ROBUST each axis pair, so the conditions below leave no parity work. Not degenerate: the edges
 * come from the float positions (p1 - p0, no cancellation against the origin), so they are within 3 * 2^-24
 * relative of the exact ones and the float normal within about 1e-6 |e1| |e2| of the exact normal; with
 * |n| > 1e-4 |e1| |e2| the exact normal is not small, and with |e1|, |e2| > 2^-20 voxel the double edges
 * (absolute error below 2^-51 * 4096 from coordinates under 4096) are within 4e-6 relative, so the double
 * normal is not zero either. A NaN or an infinity (overflow) fails every test. */
static __attribute__((noinline)) unsigned prefilter8(const tri_out *o, const float *pos, const uint32_t *ti, bool last,
                                  const pre_consts *q)
{
    __m256 p[3][3]; /* corner, axis; lane i = triangle i */
    for (int c = 0; c < 3; c++) {
        __m256 r[4];
        for (int i = 0; i < 4; i++)
            r[i] = _mm256_set_m128(vertex_load(pos, ti[3 * (i + 4) + c], last), vertex_load(pos, ti[3 * i + c], last));
        __m256 t0 = _mm256_unpacklo_ps(r[0], r[1]), t1 = _mm256_unpackhi_ps(r[0], r[1]);
        __m256 t2 = _mm256_unpacklo_ps(r[2], r[3]), t3 = _mm256_unpackhi_ps(r[2], r[3]);
        p[c][0] = _mm256_shuffle_ps(t0, t2, _MM_SHUFFLE(1, 0, 1, 0));
        p[c][1] = _mm256_shuffle_ps(t0, t2, _MM_SHUFFLE(3, 2, 3, 2));
        p[c][2] = _mm256_shuffle_ps(t1, t3, _MM_SHUFFLE(1, 0, 1, 0));
    }
    const __m256 one = _mm256_set1_ps(1.0f), half = _mm256_set1_ps(0.5f);
    __m256 e1[3], e2[3], k[3], maybe[3] = {_mm256_setzero_ps(), _mm256_setzero_ps(), _mm256_setzero_ps()};
    __m256 ok = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
    for (int a = 0; a < 3; a++) {
        e1[a] = _mm256_mul_ps(_mm256_sub_ps(p[1][a], p[0][a]), q->inv_h);
        e2[a] = _mm256_mul_ps(_mm256_sub_ps(p[2][a], p[0][a]), q->inv_h);
        __m256 g0 = _mm256_mul_ps(_mm256_sub_ps(p[0][a], q->origin[a]), q->inv_h);
        __m256 g1 = _mm256_mul_ps(_mm256_sub_ps(p[1][a], q->origin[a]), q->inv_h);
        __m256 g2 = _mm256_mul_ps(_mm256_sub_ps(p[2][a], q->origin[a]), q->inv_h);
        __m256 mn = _mm256_min_ps(g0, _mm256_min_ps(g1, g2)), mx = _mm256_max_ps(g0, _mm256_max_ps(g1, g2));
        /* [lo, hi] in [k, k + 1) (NaN fails the test), the centre k + 0.5 possibly in it or not. */
        __m256 lo = _mm256_sub_ps(mn, q->m), hi = _mm256_add_ps(mx, q->m);
        k[a] = _mm256_floor_ps(lo);
        ok = _mm256_and_ps(ok, _mm256_cmp_ps(hi, _mm256_add_ps(k[a], one), _CMP_LT_OQ));
        ok = _mm256_and_ps(ok, _mm256_cmp_ps(k[a], _mm256_setzero_ps(), _CMP_GE_OQ));
        ok = _mm256_and_ps(ok, _mm256_cmp_ps(k[a], q->dimm1[a], _CMP_LE_OQ));
        if (a < 2 || q->robust) {
            __m256 c = _mm256_add_ps(k[a], half);
            maybe[a] = _mm256_and_ps(_mm256_cmp_ps(lo, c, _CMP_LE_OQ), _mm256_cmp_ps(hi, c, _CMP_GE_OQ));
        }
    }
    __m256 busy = _mm256_and_ps(maybe[0], maybe[1]);
    if (q->robust)
        busy = _mm256_or_ps(busy, _mm256_and_ps(maybe[2], _mm256_or_ps(maybe[0], maybe[1])));
    ok = _mm256_andnot_ps(busy, ok);
    __m256 n0 = _mm256_sub_ps(_mm256_mul_ps(e1[1], e2[2]), _mm256_mul_ps(e1[2], e2[1]));
    __m256 n1 = _mm256_sub_ps(_mm256_mul_ps(e1[2], e2[0]), _mm256_mul_ps(e1[0], e2[2]));
    __m256 n2 = _mm256_sub_ps(_mm256_mul_ps(e1[0], e2[1]), _mm256_mul_ps(e1[1], e2[0]));
    __m256 nn = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(n0, n0), _mm256_mul_ps(n1, n1)), _mm256_mul_ps(n2, n2));
    __m256 l1 = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(e1[0], e1[0]), _mm256_mul_ps(e1[1], e1[1])),
                              _mm256_mul_ps(e1[2], e1[2]));
    __m256 l2 = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(e2[0], e2[0]), _mm256_mul_ps(e2[1], e2[1])),
                              _mm256_mul_ps(e2[2], e2[2]));
    const __m256 tiny = _mm256_set1_ps(0x1p-40f);
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(nn, _mm256_mul_ps(_mm256_mul_ps(_mm256_set1_ps(1e-8f), l1), l2), _CMP_GT_OQ));
    ok = _mm256_and_ps(ok, _mm256_and_ps(_mm256_cmp_ps(l1, tiny, _CMP_GT_OQ), _mm256_cmp_ps(l2, tiny, _CMP_GT_OQ)));
    unsigned pass = (unsigned)_mm256_movemask_ps(ok);
    if (!pass)
        return 0;
    /* triangles4's "line" marking of voxel k: word (ky nx + kx) words + kz / 64 (32 bits suffice, see there),
     * looked at first since on a coarse grid the bit is nearly always set; failed lanes read word 0. */
    const bitset *b = o->b;
    __m256i on = _mm256_castps_si256(ok);
    __m256i kx = _mm256_cvttps_epi32(k[0]), ky = _mm256_cvttps_epi32(k[1]), kz = _mm256_cvttps_epi32(k[2]);
    const __m256i column = _mm256_add_epi32(_mm256_mullo_epi32(ky, _mm256_set_m128i(q->nx, q->nx)), kx);
    __m256i w = _mm256_add_epi32(_mm256_mullo_epi32(column, _mm256_set_m128i(q->words, q->words)), _mm256_srli_epi32(kz, 6));
    w = _mm256_and_si256(w, on);
    __m256i bit = _mm256_and_si256(kz, _mm256_set1_epi32(63));
    const __m256i one64 = _mm256_set1_epi64x(1);
    __m128i wl = _mm256_castsi256_si128(w), wh = _mm256_extracti128_si256(w, 1);
    __m256i ml = _mm256_and_si256(_mm256_sllv_epi64(one64, _mm256_cvtepu32_epi64(_mm256_castsi256_si128(bit))),
                                  _mm256_cvtepi32_epi64(_mm256_castsi256_si128(on)));
    __m256i mh = _mm256_and_si256(_mm256_sllv_epi64(one64, _mm256_cvtepu32_epi64(_mm256_extracti128_si256(bit, 1))),
                                  _mm256_cvtepi32_epi64(_mm256_extracti128_si256(on, 1)));
    /* Consecutive triangles mostly share their voxel: then one word to look at, not a gather. */
    __m256i same = _mm256_and_si256(_mm256_cmpeq_epi32(w, _mm256_permutevar8x32_epi32(w, _mm256_setzero_si256())),
                                    _mm256_cmpeq_epi32(bit, _mm256_permutevar8x32_epi32(bit, _mm256_setzero_si256())));
    if (pass == 0xFFu && _mm256_movemask_ps(_mm256_castsi256_ps(same)) == 0xFF) {
        uint32_t w0 = (uint32_t)_mm256_cvtsi256_si32(w), b0 = (uint32_t)_mm256_cvtsi256_si32(bit);
        if (!((b->surface[w0] >> b0) & 1u))
            bits_or(b->shared, b->surface + w0, 1ull << b0);
        return pass;
    }
    surface_or8(b, wl, ml, wh, mh);
    return pass;
}

/* triangles4 for the prefilter's leftovers, out of line: the exact path's own loop in triangle_range keeps
 * its inlined copy (a call passes the lanes through memory, and the loop's state would crowd the registers). */
static __attribute__((noinline)) uint32_t triangles4_at(const tri_out *o, const float *pos, const uint32_t *ti,
                                                        bool last, const soa_consts *k)
{
    __m256d v[3][3];
    load4(pos, ti, last, k, v);
    return triangles4(o, k, v);
}
#endif

/* Triangles t0..t1 of the mesh. */
static void triangle_range(const tri_out *o, const tri_source *src, uint32_t nv, size_t nt, size_t t0,
                           size_t t1, tri_counts *cnt)
{
    size_t t = t0;
    (void)nt; /* only the look-ahead of the AVX2 path needs it */
#ifdef __AVX2__
    size_t queued[4]; /* triangles the prefilter left, for the exact path four at a time */
    unsigned nq = 0;
    if (src->all_finite) {
        soa_consts k;
        for (int a = 0; a < 3; a++) {
            k.origin[a] = _mm256_set1_pd(src->origin[a]);
            k.dimm1[a] = _mm256_set1_pd((double)o->b->dims[a] - 1);
        }
        k.inv_h = _mm256_set1_pd(src->inv_h);
        /* Vertex loads are random gathers and dominate on large meshes: fetch ahead, unless the
         * vertices fit in the L2 cache anyway (Suzanne's 96 KiB), where it is only overhead. */
        const size_t ahead = nv > VOXEL_PREFETCH_MIN ? nt : 0;
        if (src->margin > 0) {
            pre_consts q;
            for (int a = 0; a < 3; a++) {
                q.origin[a] = _mm256_set1_ps((float)src->origin[a]); /* exact: the grid's float origin */
                q.dimm1[a] = _mm256_set1_ps((float)o->b->dims[a] - 1);
            }
            q.inv_h = _mm256_set1_ps((float)src->inv_h);
            q.m = _mm256_set1_ps(src->margin);
            q.nx = _mm_set1_epi32((int)o->b->dims[0]);
            q.words = _mm_set1_epi32((int)o->b->words);
            q.robust = o->px != NULL;
            uint32_t qi[12];
            bool qlast = false;
            /* Triangles passed per block, times 8, a running mean. Below VOXEL_PRE_RATE_MIN the grid is
             * fine here and the prefilter would cost more than it saves: the rest of the range takes the
             * exact path. It starts just above, so one poor block is enough to leave. */
            unsigned rate = VOXEL_PRE_RATE_MIN + 2;
            for (; t + 8 <= t1 && rate >= VOXEL_PRE_RATE_MIN; t += 8) {
                /* Prefiltered blocks go through twice as fast: twice the exact path's distance. */
                for (size_t f = t + 64; f < t + 72 && f < ahead; f++)
                    for (int c = 0; c < 3; c++) { /* clamped: no out-of-range pointer is formed */
                        uint32_t i = src->idx[3 * f + (size_t)c];
                        __builtin_prefetch(src->pos + 3 * (size_t)(i < nv ? i : 0));
                    }
                const uint32_t *ti = src->idx + 3 * t;
                int ok0 = indices_check4(ti, nv), ok1 = indices_check4(ti + 12, nv);
                if (!ok0 || !ok1) { /* the exact path counts the bad indices */
                    for (int h = 0; h < 2; h++) {
                        int ok = h ? ok1 : ok0;
                        if (ok)
                            cnt->degenerate += triangles4_at(o, src->pos, ti + 12 * h, ok == 1, &k);
                        else
                            for (size_t u = t + 4 * (size_t)h; u < t + 4 * (size_t)h + 4; u++)
                                triangle_one(o, src, nv, u, cnt);
                    }
                    continue;
                }
                unsigned left = ~prefilter8(o, src->pos, ti, ok0 == 1 || ok1 == 1, &q) & 0xFFu;
                rate += 8u - (unsigned)__builtin_popcount(left) - (rate >> 3);
                const bool block_last = ok0 == 1 || ok1 == 1;
                for (; left; left &= left - 1) {
                    unsigned l = (unsigned)__builtin_ctz(left);
                    memcpy(qi + 3 * nq, ti + 3 * l, 3 * sizeof(uint32_t));
                    queued[nq] = t + l;
                    /* Per queued triangle: a flush below clears it while more of this block may
                     * follow into the next group of four. */
                    qlast |= block_last;
                    if (++nq == 4) {
                        cnt->degenerate += triangles4_at(o, src->pos, qi, qlast, &k);
                        nq = 0;
                        qlast = false;
                    }
                }
            }
        }
        for (; t + 4 <= t1; t += 4) {
            for (size_t f = t + 32; f < t + 36 && f < ahead; f++)
                for (int c = 0; c < 3; c++) { /* clamped: no out-of-range pointer is formed */
                    uint32_t i = src->idx[3 * f + (size_t)c];
                    __builtin_prefetch(src->pos + 3 * (size_t)(i < nv ? i : 0));
                }
            const uint32_t *ti = src->idx + 3 * t;
            int ok = indices_check4(ti, nv);
            if (!ok) {
                for (size_t u = t; u < t + 4; u++)
                    triangle_one(o, src, nv, u, cnt);
                continue;
            }
            __m256d v[3][3];
            load4(src->pos, ti, ok == 1, &k, v);
            cnt->degenerate += triangles4(o, &k, v);
        }
    }
    for (unsigned i = 0; i < nq; i++)
        triangle_one(o, src, nv, queued[i], cnt);
#endif
    for (; t < t1; t++)
        triangle_one(o, src, nv, t, cnt);
}

/* Words [i0, i1) of the per-thread copies of threads 1..team-1 (each nsets sets of w0 words:
 * surface, solid, then px and py for ROBUST) into the level-0 sets: OR for the surface, XOR for
 * the parity toggles. */
static void merge_copies(bitset *b, uint64_t *px, uint64_t *py, const uint64_t *priv, size_t nsets, size_t w0,
                         int team, size_t i0, size_t i1)
{
    for (int k = 1; k < team; k++) {
        const uint64_t *base = priv + (size_t)(k - 1) * nsets * w0;
        for (size_t i = i0; i < i1; i++) {
            b->surface[i] |= base[i];
            b->solid[i] ^= base[w0 + i];
        }
        if (px)
            for (size_t i = i0; i < i1; i++) {
                px[i] ^= base[2 * w0 + i];
                py[i] ^= base[3 * w0 + i];
            }
    }
}

/* The triangle pass of voxelize_impl (voxel.c) into level 0 of g and dst's toggle sets. */
nacre_result nc_voxel_triangle_pass(nacre_context *ctx, nacre_voxel_grid *g, const tri_out *dstp,
                                    const tri_source *srcp, size_t nt, uint32_t nv, int threads, tri_counts *total)
{
    const tri_out dst = *dstp;
    bitset *b = &g->level[0];
    nacre_result r;
    /* Surface and parities in one pass over the triangles; indices are checked here rather than
     * in a pass of their own (one less sweep over the index array), and a bad one fails the
     * whole call after the loop. Chunks are handed out on demand (dynamic), not in fixed
     * halves: the cost per triangle varies along a mesh (large triangles in one region), and on
     * a shared machine a thread that is descheduled for a while would otherwise hold up the
     * whole pass with its half; one atomic increment per 1024 triangles is all it costs. */
    uint32_t degenerate = 0, nonfinite = 0, bad_index = 0;
    size_t nchunks = (nt + VOXEL_CHUNK - 1) / VOXEL_CHUNK;
    const int team_max = nt > VOXEL_PARALLEL_MIN ? threads : 1;
    /* A small grid (its level-0 sets, px and py included, at most VOXEL_PRIVATE_WORDS words per
     * triangle) gets a private copy of them per thread after the first, merged after the pass:
     * plain writes instead of locked ones, and no cache line bouncing between cores on every
     * parity toggle (on Suzanne at 28^3 each set is a hundred cache lines that both threads
     * write; the copies took over a quarter off its time with two threads). On a large grid the
     * copies would cost about as much to clear and merge as they save (at 256^3 the parity
     * toggles are spread over megabytes that two threads rarely share). A single thread writes
     * the grid plainly. */
    const size_t w0 = bitset_words(b);
    const size_t nsets = dst.px ? 4 : 2;
    const bool priv = team_max > 1 && nsets * w0 <= VOXEL_PRIVATE_MAX && nsets * w0 <= nt * VOXEL_PRIVATE_WORDS;
    if (priv) {
        r = words_reserve(ctx, &g->priv, &g->cap_priv, (size_t)(team_max - 1) * nsets * w0);
        if (r != NACRE_OK)
            return r;
    }
    b->shared = team_max > 1 && !priv;
    int team = 1;
#pragma omp parallel num_threads(team_max) reduction(+ : degenerate, nonfinite, bad_index) if (team_max > 1)
    {
        int tid = 0;
#ifdef _OPENMP
        tid = omp_get_thread_num();
        if (tid == 0)
            team = omp_get_num_threads();
#endif
        tri_out mine = dst;
        bitset local;
        if (priv && tid > 0) {
            uint64_t *base = g->priv + (size_t)(tid - 1) * nsets * w0;
            memset(base, 0, nsets * w0 * 8);
            local = *b;
            local.shared = false;
            local.surface = base;
            local.solid = base + w0;
            mine.b = &local;
            if (dst.px) {
                mine.px = base + 2 * w0;
                mine.py = base + 3 * w0;
            }
        }
#pragma omp for schedule(dynamic, 1)
        for (size_t ch = 0; ch < nchunks; ch++) {
            size_t t0 = ch * VOXEL_CHUNK, t1 = t0 + VOXEL_CHUNK < nt ? t0 + VOXEL_CHUNK : nt;
            tri_counts cnt = {0, 0, 0};
            triangle_range(&mine, srcp, nv, nt, t0, t1, &cnt);
            degenerate += cnt.degenerate;
            nonfinite += cnt.nonfinite;
            bad_index += cnt.bad_index;
        }
        /* The loop's barrier has passed: every copy is complete. Large copies are merged by all
         * threads (a slice of the words each); small ones by one thread after the region, which
         * saves a barrier. */
        if (priv && nsets * w0 > VOXEL_MERGE_PARALLEL) {
            size_t nblk = (w0 + 4095) / 4096;
#pragma omp for schedule(static)
            for (size_t blk = 0; blk < nblk; blk++)
                merge_copies(b, dst.px, dst.py, g->priv, nsets, w0, team, blk * 4096,
                             blk * 4096 + 4096 < w0 ? blk * 4096 + 4096 : w0);
        }
    }
    if (priv && nsets * w0 <= VOXEL_MERGE_PARALLEL)
        merge_copies(b, dst.px, dst.py, g->priv, nsets, w0, team, 0, w0);
    total->degenerate = degenerate;
    total->nonfinite = nonfinite;
    total->bad_index = bad_index;
    return NACRE_OK;
}
