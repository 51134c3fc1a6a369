/*
 * voxel.c: conservative surface and solid voxelization of triangle meshes into bit-packed
 * columns, a level pyramid, NRRD export and rest-pose coordinates (seed 000, section 4.2:
 * Schwarz and Seidel 2010, "Fast parallel surface and solid voxelization on GPUs").
 *
 * Layout: a set is nx * ny columns along z, each `words` 64-bit words; bit k of word w of
 * column (x, y) is voxel z = 64 w + k; column index x + nx * y. Everything is computed in grid
 * coordinates g = (p - origin) / voxel_size (doubles, so voxel (i, j, k) is the unit box at
 * (i, j, k)); a vertex shared by two triangles maps to the same doubles in both.
 *
 * Surface: per triangle, the voxel bounding box; one voxel or one column (or one row along any
 * axis) is marked directly, since a triangle inside a 1 x 1 prism touches every voxel of the
 * prism its extent crosses; otherwise the SS10 test: plane test with the critical-point offsets
 * d1, d2, then the xy, yz and zx edge functions offset to the box corner that maximises them.
 * Touching counts (<= / >=), so the set is conservative: with exact arithmetic it equals the set
 * of closed boxes the closed triangle meets.
 *
 * Solid (parity): a column line through voxel centres (i + 0.5, j + 0.5) crosses a triangle
 * when the point is inside its xy projection; the crossing toggles one bit (the first voxel
 * whose centre lies above the crossing) in a flip set, and a prefix XOR along each column then
 * turns the toggles into "inside" bits (the seed's XOR of a prefix mask, done once per column
 * instead of once per crossing). Points on an edge are decided by the top-left rule on the
 * projection turned counter-clockwise, and every edge function is evaluated with its endpoints
 * in one canonical order (lexicographic by position), so two triangles sharing an edge get
 * exactly opposite values and a line through a shared edge or vertex is counted once (or an even
 * number of times at a silhouette fold, which leaves parity right).
 * Robust (meshes not closed): the same parity along x, y and z, and a voxel is solid when at least
 * two agree. A hole or flipped patch spoils the lines through it along one axis; the other two
 * usually miss it. A duplicated patch adds two crossings at the same place and cancels itself.
 *
 * Parallelism: triangles are split statically over threads and bits are set with atomic OR/XOR,
 * which commute, so the result does not depend on the thread count or the schedule.
 */
#include "core/core.h"

#include <errno.h>
#include <math.h>
#ifdef __AVX2__
#include <immintrin.h>
#endif
#include <stdio.h>
#include <string.h>

#define VOXEL_MAX_RES 4096u
#define VOXEL_MAX_LEVELS 16
#define VOXEL_PARALLEL_MIN 4096

/* Branch-free min/max without libm's NaN rules (inputs are finite here): the libm calls cost
 * more than the rest of the per-triangle work. */
static inline double dmin(double a, double b) { return a < b ? a : b; }
static inline double dmax(double a, double b) { return a > b ? a : b; }
static inline float fmn(float a, float b) { return a < b ? a : b; }
static inline float fmx(float a, float b) { return a > b ? a : b; }

typedef struct bitset {
    uint32_t dims[3];
    uint32_t words; /* per column */
    uint64_t *surface, *solid;
} bitset;

struct nacre_voxel_grid {
    nacre_context *ctx;
    float origin[3];
    float voxel_size;
    uint32_t levels;
    bitset level[VOXEL_MAX_LEVELS];
    size_t cap[VOXEL_MAX_LEVELS]; /* words allocated for each of surface and solid, per level */
    uint64_t *px, *py;            /* ROBUST scratch: x and y parities, kept for nacre_voxelize_update */
    size_t cap_px, cap_py;        /* words allocated in px, py */
};

nacre_voxel_settings nacre_voxel_settings_defaults(void)
{
    nacre_voxel_settings s;
    memset(&s, 0, sizeof(s));
    s.resolution = 32;
    s.solid_rule = NACRE_VOXEL_SOLID_AUTO;
    return s;
}

/* Zeroed buffer of n words in *buf, reusing it when its capacity *cap suffices (only the n words
 * used are cleared). */
static nacre_result words_prepare(nacre_context *ctx, uint64_t **buf, size_t *cap, size_t n)
{
    if (*buf && n <= *cap) {
        memset(*buf, 0, n * 8);
        return NACRE_OK;
    }
    nc_free(ctx, *buf);
    *cap = 0;
    *buf = nc_calloc(ctx, n ? n : 1, 8);
    if (!*buf)
        return NACRE_ERROR_OUT_OF_MEMORY;
    *cap = n ? n : 1;
    return NACRE_OK;
}

/* Level `l` of g with `dims`, both sets zeroed; allocations are reused when they fit. */
static nacre_result bitset_alloc(nacre_context *ctx, nacre_voxel_grid *g, uint32_t l, const uint32_t dims[3])
{
    bitset *b = &g->level[l];
    size_t cols, n, bytes;
    memcpy(b->dims, dims, sizeof(b->dims));
    b->words = (dims[2] + 63u) / 64u;
    if (!nc_mul_size_ok((size_t)dims[0], (size_t)dims[1], &cols) ||
        !nc_mul_size_ok(cols, (size_t)b->words, &n) || !nc_mul_size_ok(n, 8, &bytes))
        return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "voxel: grid too large");
    if (b->surface && b->solid && n <= g->cap[l]) {
        memset(b->surface, 0, bytes);
        memset(b->solid, 0, bytes);
        return NACRE_OK;
    }
    nc_free(ctx, b->surface);
    nc_free(ctx, b->solid);
    g->cap[l] = 0;
    b->surface = nc_calloc(ctx, n ? n : 1, 8);
    b->solid = nc_calloc(ctx, n ? n : 1, 8);
    if (!b->surface || !b->solid)
        return NACRE_ERROR_OUT_OF_MEMORY;
    g->cap[l] = n ? n : 1;
    return NACRE_OK;
}

static size_t bitset_words(const bitset *b)
{
    return (size_t)b->dims[0] * b->dims[1] * b->words;
}

void nacre_voxel_grid_destroy(nacre_voxel_grid *grid)
{
    if (!grid)
        return;
    for (uint32_t l = 0; l < VOXEL_MAX_LEVELS; l++) {
        nc_free(grid->ctx, grid->level[l].surface);
        nc_free(grid->ctx, grid->level[l].solid);
    }
    nc_free(grid->ctx, grid->px);
    nc_free(grid->ctx, grid->py);
    nc_free(grid->ctx, grid);
}

/* Bits lo..hi (inclusive, 0 <= lo <= hi <= 63). */
static inline uint64_t bit_range(uint32_t lo, uint32_t hi)
{
    uint64_t top = hi == 63 ? ~0ull : ((1ull << (hi + 1)) - 1);
    return top & ~((1ull << lo) - 1);
}

static inline void atomic_or(uint64_t *w, uint64_t m)
{
    /* Reading first skips the locked RMW when the bits are already there (common on dense meshes). */
    if ((__atomic_load_n(w, __ATOMIC_RELAXED) & m) != m)
        __atomic_fetch_or(w, m, __ATOMIC_RELAXED);
}

/* Mark voxels z0..z1 of column (x, y). */
static inline void mark_run(uint64_t *set, const bitset *b, uint32_t x, uint32_t y, uint32_t z0,
                            uint32_t z1)
{
    uint64_t *col = set + ((size_t)y * b->dims[0] + x) * b->words;
    for (uint32_t w = z0 / 64; w <= z1 / 64; w++) {
        uint32_t lo = w == z0 / 64 ? z0 % 64 : 0, hi = w == z1 / 64 ? z1 % 64 : 63;
        atomic_or(col + w, bit_range(lo, hi));
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
static void setup_edges(const double v[3][3], const double n[3], int a, int b, int c, edge2 e[3])
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

static inline bool edges_pass(const edge2 e[3], double pa, double pb)
{
    return e[0].nx * pa + e[0].ny * pb + e[0].d >= 0 && e[1].nx * pa + e[1].ny * pb + e[1].d >= 0 &&
           e[2].nx * pa + e[2].ny * pb + e[2].d >= 0;
}

static void surface_triangle(const bitset *b, const double v[3][3])
{
    int lo[3], hi[3];
    for (int a = 0; a < 3; a++) {
        double mn = dmin(v[0][a], dmin(v[1][a], v[2][a]));
        double mx = dmax(v[0][a], dmax(v[1][a], v[2][a]));
        /* Closed boxes: a coordinate exactly on a voxel face touches both voxels. */
        double l = ceil(mn) - 1.0, h = floor(mx);
        if (l < 0)
            l = 0;
        if (h > (double)b->dims[a] - 1)
            h = (double)b->dims[a] - 1;
        if (l > h)
            return;
        lo[a] = (int)l;
        hi[a] = (int)h;
    }
    /* Fast paths: a triangle within a 1 x 1 prism along any axis touches every voxel of it that
     * its extent reaches (the prism cross-section contains its whole projection). */
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
    double e1[3], e2[3], n[3];
    for (int a = 0; a < 3; a++) {
        e1[a] = v[1][a] - v[0][a];
        e2[a] = v[2][a] - v[0][a];
    }
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
    double c[3];
    for (int a = 0; a < 3; a++)
        c[a] = n[a] > 0 ? 1.0 : 0.0;
    double d1 = n[0] * (c[0] - v[0][0]) + n[1] * (c[1] - v[0][1]) + n[2] * (c[2] - v[0][2]);
    double d2 = n[0] * (1 - c[0] - v[0][0]) + n[1] * (1 - c[1] - v[0][1]) + n[2] * (1 - c[2] - v[0][2]);
    edge2 exy[3], eyz[3], ezx[3];
    setup_edges(v, n, 0, 1, 2, exy);
    setup_edges(v, n, 1, 2, 0, eyz);
    setup_edges(v, n, 2, 0, 1, ezx);
    for (int y = lo[1]; y <= hi[1]; y++) {
        for (int x = lo[0]; x <= hi[0]; x++) {
            if (!edges_pass(exy, x, y))
                continue;
            double np = n[0] * x + n[1] * y;
            uint64_t *col = b->surface + ((size_t)y * b->dims[0] + (size_t)x) * b->words;
            uint64_t acc = 0;
            int accw = lo[2] / 64;
            for (int z = lo[2]; z <= hi[2]; z++) {
                double t = np + n[2] * z;
                if ((t + d1) * (t + d2) > 0 || !edges_pass(eyz, y, z) || !edges_pass(ezx, z, x))
                    continue;
                if (z / 64 != accw) {
                    if (acc)
                        atomic_or(col + accw, acc);
                    acc = 0;
                    accw = z / 64;
                }
                acc |= 1ull << (z % 64);
            }
            if (acc)
                atomic_or(col + accw, acc);
        }
    }
}

/* ------------------------------------------------------------------------------------------ */
/* Solid: column parity                                                                       */
/* ------------------------------------------------------------------------------------------ */

/* Edge function of (p -> q) at (x, y) in the (a, b) plane, evaluated with the endpoints in
 * canonical (lexicographic) order so that the reversed edge gives exactly the negated value. */
static inline double edge_fn(const double *p, const double *q, int a, int b, double x, double y)
{
    bool swap = p[a] > q[a] || (p[a] == q[a] && p[b] > q[b]);
    const double *s = swap ? q : p, *t = swap ? p : q;
    double f = (t[a] - s[a]) * (y - s[b]) - (t[b] - s[b]) * (x - s[a]);
    return swap ? -f : f;
}

/* Top-left rule for edge p -> q of a counter-clockwise triangle in the (a, b) plane (b up):
 * left edges go down, top edges are horizontal and go left. */
static inline bool top_left(const double *p, const double *q, int a, int b)
{
    return q[b] < p[b] || (q[b] == p[b] && q[a] < p[a]);
}

/* Toggle, in `flip` (column axis c, columns over (a, b) with dims da x db, nc voxels per column,
 * `words` per column), the first voxel above each crossing of the column centre lines. */
static void parity_triangle(uint64_t *flip, uint32_t da, uint32_t db, uint32_t nc, uint32_t words,
                            const double v[3][3], int a, int b, int c)
{
    const double *p0 = v[0], *p1 = v[1], *p2 = v[2];
    /* Column centres in the projected bounding box: i + 0.5 in [min, max]. Most triangles of a
     * fine mesh contain none, so this comes first. */
    double mna = dmin(p0[a], dmin(p1[a], p2[a])), mxa = dmax(p0[a], dmax(p1[a], p2[a]));
    double ia0 = dmax(0.0, ceil(mna - 0.5)), ia1 = dmin((double)da - 1, floor(mxa - 0.5));
    if (ia0 > ia1)
        return;
    double mnb = dmin(p0[b], dmin(p1[b], p2[b])), mxb = dmax(p0[b], dmax(p1[b], p2[b]));
    double ib0 = dmax(0.0, ceil(mnb - 0.5)), ib1 = dmin((double)db - 1, floor(mxb - 0.5));
    if (ib0 > ib1)
        return;
    double area = (p1[a] - p0[a]) * (p2[b] - p0[b]) - (p1[b] - p0[b]) * (p2[a] - p0[a]);
    if (area == 0)
        return; /* edge-on: the neighbours' top-left rule owns the lines through it */
    if (area < 0) {
        const double *t = p1;
        p1 = p2;
        p2 = t;
    }
    bool tl0 = top_left(p0, p1, a, b), tl1 = top_left(p1, p2, a, b), tl2 = top_left(p2, p0, a, b);
    /* Plane: c = p0[c] + ga * (x - p0[a]) + gb * (y - p0[b]). */
    double n[3], e1[3], e2[3];
    for (int k = 0; k < 3; k++) {
        e1[k] = v[1][k] - v[0][k];
        e2[k] = v[2][k] - v[0][k];
    }
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
    double ga = -n[a] / n[c], gb = -n[b] / n[c];
    for (int j = (int)ib0; j <= (int)ib1; j++) {
        double y = j + 0.5;
        for (int i = (int)ia0; i <= (int)ia1; i++) {
            double x = i + 0.5;
            double w0 = edge_fn(p0, p1, a, b, x, y), w1 = edge_fn(p1, p2, a, b, x, y),
                   w2 = edge_fn(p2, p0, a, b, x, y);
            if (!(w0 > 0 || (w0 == 0 && tl0)) || !(w1 > 0 || (w1 == 0 && tl1)) ||
                !(w2 > 0 || (w2 == 0 && tl2)))
                continue;
            double zc = v[0][c] + ga * (x - v[0][a]) + gb * (y - v[0][b]);
            /* First voxel whose centre k + 0.5 lies strictly above the crossing. */
            double k0 = floor(zc - 0.5) + 1.0;
            if (k0 < 0)
                k0 = 0;
            if (k0 >= (double)nc)
                continue;
            uint32_t k = (uint32_t)k0;
            uint64_t *col = flip + ((size_t)j * da + (size_t)i) * words;
            __atomic_fetch_xor(col + k / 64, 1ull << (k % 64), __ATOMIC_RELAXED);
        }
    }
}

/* Turn toggles into inside bits: prefix XOR along every column, masked to nc voxels. */
static void prefix_xor(uint64_t *flip, size_t columns, uint32_t nc, uint32_t words, int threads)
{
    uint64_t last = nc % 64 ? (1ull << (nc % 64)) - 1 : ~0ull;
#pragma omp parallel for schedule(static) num_threads(threads) if (columns > 4096)
    for (size_t col = 0; col < columns; col++) {
        uint64_t carry = 0;
        uint64_t *w = flip + col * words;
        for (uint32_t i = 0; i < words; i++) {
            uint64_t x = w[i];
            x ^= x << 1;
            x ^= x << 2;
            x ^= x << 4;
            x ^= x << 8;
            x ^= x << 16;
            x ^= x << 32;
            x ^= carry;
            carry = (x >> 63) ? ~0ull : 0;
            w[i] = x;
        }
        w[words - 1] &= last;
    }
}

/* ------------------------------------------------------------------------------------------ */
/* Driver                                                                                     */
/* ------------------------------------------------------------------------------------------ */

typedef struct tri_source {
    const float *pos;
    const uint32_t *idx;
    double origin[3], inv_h;
    bool all_finite; /* no vertex is NaN or infinite: skip the per-corner checks */
} tri_source;

/* Grid coordinates of triangle t; false if a vertex is not finite or the area is zero. */
static inline int load_triangle(const tri_source *s, size_t t, double v[3][3])
{
    for (int k = 0; k < 3; k++) {
        const float *p = s->pos + 3 * (size_t)s->idx[3 * t + (size_t)k];
        if (!s->all_finite && (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2])))
            return 1;
        for (int a = 0; a < 3; a++)
            v[k][a] = ((double)p[a] - s->origin[a]) * s->inv_h;
    }
    double e1[3], e2[3];
    for (int a = 0; a < 3; a++) {
        e1[a] = v[1][a] - v[0][a];
        e2[a] = v[2][a] - v[0][a];
    }
    if (e1[1] * e2[2] - e1[2] * e2[1] == 0 && e1[2] * e2[0] - e1[0] * e2[2] == 0 &&
        e1[0] * e2[1] - e1[1] * e2[0] == 0)
        return 2;
    return 0;
}

/* ROBUST: the x and y flip sets, filled in the same triangle pass as the surface and z parity
 * (parity_triangle is the same function with the same coordinates as in a pass of its own, and
 * the XOR toggles commute, so the result is the same). x columns over (y, z), y over (z, x). */
typedef struct robust_sets {
    uint64_t *px, *py;
    uint32_t wx, wy; /* words per column */
} robust_sets;

static inline void parity_xy(const bitset *b, const robust_sets *rs, const double v[3][3], bool px, bool py)
{
    if (px)
        parity_triangle(rs->px, b->dims[1], b->dims[2], b->dims[0], rs->wx, v, 1, 2, 0);
    if (py)
        parity_triangle(rs->py, b->dims[2], b->dims[0], b->dims[1], rs->wy, v, 2, 0, 1);
}

#ifdef __AVX2__
typedef struct fast_consts {
    __m256d origin, inv_h, dimm1; /* lane 3 zero */
} fast_consts;

/* One finite triangle (all_finite sources only): the same double operations as load_triangle,
 * surface_triangle's bounds and parity_triangle's column-centre test, with the three axes in
 * lanes 0..2 of a vector, so every decision is bit-identical to the scalar path. The common
 * cases (no surface voxel or one 1 x 1 column run, no column centre) finish here; the rest go
 * to surface_triangle / parity_triangle. Returns 2 for a zero-area triangle, else 0. */
static inline void triangle_avx_load(const float *pos, const uint32_t *ti, const fast_consts *fc, __m256d v[3])
{
    const __m128i m3 = _mm_set_epi32(0, -1, -1, -1);
    for (int k = 0; k < 3; k++) {
        __m128 f = _mm_maskload_ps(pos + 3 * (size_t)ti[k], m3);
        v[k] = _mm256_mul_pd(_mm256_sub_pd(_mm256_cvtps_pd(f), fc->origin), fc->inv_h);
    }
}

static inline int triangle_avx(const bitset *b, const __m256d v[3], const fast_consts *fc, const robust_sets *rs)
{
    __m256d e1 = _mm256_sub_pd(v[1], v[0]), e2 = _mm256_sub_pd(v[2], v[0]);
    /* n = e1.yzx * e2.zxy - e1.zxy * e2.yzx, lane 3 is 0 - 0. */
    __m256d n = _mm256_sub_pd(
        _mm256_mul_pd(_mm256_permute4x64_pd(e1, _MM_SHUFFLE(3, 0, 2, 1)),
                      _mm256_permute4x64_pd(e2, _MM_SHUFFLE(3, 1, 0, 2))),
        _mm256_mul_pd(_mm256_permute4x64_pd(e1, _MM_SHUFFLE(3, 1, 0, 2)),
                      _mm256_permute4x64_pd(e2, _MM_SHUFFLE(3, 0, 2, 1))));
    if (_mm256_movemask_pd(_mm256_cmp_pd(n, _mm256_setzero_pd(), _CMP_EQ_OQ)) == 0xF)
        return 2;
    __m256d mn = _mm256_min_pd(v[0], _mm256_min_pd(v[1], v[2]));
    __m256d mx = _mm256_max_pd(v[0], _mm256_max_pd(v[1], v[2]));
    /* Surface bounds as in surface_triangle. */
    __m256d l = _mm256_max_pd(_mm256_sub_pd(_mm256_ceil_pd(mn), _mm256_set1_pd(1.0)), _mm256_setzero_pd());
    __m256d h = _mm256_min_pd(_mm256_floor_pd(mx), fc->dimm1);
    /* Column centres i + 0.5 in the xy bounds as in parity_triangle (c = z). */
    __m256d half = _mm256_set1_pd(0.5);
    __m256d pl = _mm256_max_pd(_mm256_ceil_pd(_mm256_sub_pd(mn, half)), _mm256_setzero_pd());
    __m256d ph = _mm256_min_pd(_mm256_floor_pd(_mm256_sub_pd(mx, half)), fc->dimm1);
    int pmask = _mm256_movemask_pd(_mm256_cmp_pd(pl, ph, _CMP_GT_OQ));
    bool parity = (pmask & 3) == 0;
    /* x parity: column centres over (y, z), lanes 1 and 2; y parity: over (z, x), lanes 2 and 0. */
    bool parx = rs && (pmask & 6) == 0, pary = rs && (pmask & 5) == 0;
    bool none = (_mm256_movemask_pd(_mm256_cmp_pd(l, h, _CMP_GT_OQ)) & 7) != 0;
    bool run = (_mm256_movemask_pd(_mm256_cmp_pd(l, h, _CMP_EQ_OQ)) & 3) == 3;
    if (!none && run) {
        double lo[4], hi[4];
        _mm256_storeu_pd(lo, l);
        _mm256_storeu_pd(hi, h);
        mark_run(b->surface, b, (uint32_t)lo[0], (uint32_t)lo[1], (uint32_t)lo[2], (uint32_t)hi[2]);
    }
    if ((!none && !run) || parity || parx || pary) {
        double w[3][4], vv[3][3];
        for (int k = 0; k < 3; k++) {
            _mm256_storeu_pd(w[k], v[k]);
            for (int a = 0; a < 3; a++)
                vv[k][a] = w[k][a];
        }
        if (!none && !run)
            surface_triangle(b, (const double(*)[3])vv);
        if (parity)
            parity_triangle(b->solid, b->dims[0], b->dims[1], b->dims[2], b->words, (const double(*)[3])vv, 0,
                            1, 2);
        if (parx || pary)
            parity_xy(b, rs, (const double(*)[3])vv, parx, pary);
    }
    return 0;
}
#endif

static inline bool get_bit(const uint64_t *set, size_t col, uint32_t words, uint32_t k)
{
    return (set[col * words + k / 64] >> (k % 64)) & 1u;
}

/* Majority of the x, y and z parities into b->solid (which holds the z parity on entry); rs holds
 * the x and y toggles from the triangle pass. */
static void robust_solid(const robust_sets *rs, bitset *b, int threads)
{
    const uint64_t *px = rs->px, *py = rs->py;
    const uint32_t *d = b->dims;
    prefix_xor(rs->px, (size_t)d[1] * d[2], d[0], rs->wx, threads);
    prefix_xor(rs->py, (size_t)d[2] * d[0], d[1], rs->wy, threads);
    {
        uint32_t wx = rs->wx, wy = rs->wy;
        size_t work = (size_t)d[0] * d[1] * d[2];
        (void)work;
#pragma omp parallel for schedule(static) num_threads(threads) if (work > 65536)
        for (uint32_t y = 0; y < d[1]; y++) {
            for (uint32_t x = 0; x < d[0]; x++) {
                uint64_t *col = b->solid + ((size_t)y * d[0] + x) * b->words;
                for (uint32_t z = 0; z < d[2]; z++) {
                    int votes = (int)((col[z / 64] >> (z % 64)) & 1u);
                    votes += get_bit(px, (size_t)z * d[1] + y, wx, x);
                    votes += get_bit(py, (size_t)x * d[2] + z, wy, y);
                    uint64_t m = 1ull << (z % 64);
                    col[z / 64] = votes >= 2 ? col[z / 64] | m : col[z / 64] & ~m;
                }
            }
        }
    }
}

/* OR of bits 2i and 2i+1 of a 128-bit pair (lo, hi) into bit i of one word. */
static inline uint64_t compress_pairs(uint64_t w)
{
    uint64_t x = (w | (w >> 1)) & 0x5555555555555555ull;
    x = (x | (x >> 1)) & 0x3333333333333333ull;
    x = (x | (x >> 2)) & 0x0f0f0f0f0f0f0f0full;
    x = (x | (x >> 4)) & 0x00ff00ff00ff00ffull;
    x = (x | (x >> 8)) & 0x0000ffff0000ffffull;
    x = (x | (x >> 16)) & 0x00000000ffffffffull;
    return x;
}

static void downsample(const bitset *fine, const uint64_t *fs, const bitset *coarse, uint64_t *cs,
                       int threads)
{
    const uint32_t *cd = coarse->dims;
    size_t work = (size_t)fine->dims[0] * fine->dims[1] * fine->words;
    (void)work;
#pragma omp parallel for schedule(static) num_threads(threads) if (work > 16384)
    for (uint32_t y = 0; y < cd[1]; y++) {
        for (uint32_t x = 0; x < cd[0]; x++) {
            uint64_t *out = cs + ((size_t)y * cd[0] + x) * coarse->words;
            for (uint32_t dy = 0; dy < 2; dy++) {
                for (uint32_t dx = 0; dx < 2; dx++) {
                    uint32_t fx = 2 * x + dx, fy = 2 * y + dy;
                    if (fx >= fine->dims[0] || fy >= fine->dims[1])
                        continue;
                    const uint64_t *in = fs + ((size_t)fy * fine->dims[0] + fx) * fine->words;
                    for (uint32_t w = 0; w < fine->words; w++)
                        out[w / 2] |= compress_pairs(in[w]) << (32 * (w % 2));
                }
            }
        }
    }
}

static uint64_t popcount_set(const uint64_t *s, size_t n)
{
    uint64_t c = 0;
    for (size_t i = 0; i < n; i++)
        c += (uint64_t)__builtin_popcountll(s[i]);
    return c;
}

/* Voxelize into *out: a fresh grid when *out is NULL (destroyed on failure), else the grid
 * given, whose allocations are reused when they fit (levels set to 0 on a failure after it was
 * touched). */
static nacre_result voxelize_impl(nacre_context *ctx, const nacre_mesh_data *mesh,
                                  const nacre_voxel_settings *settings, nacre_voxel_grid **out,
                                  nacre_voxel_report *report)
{
    uint64_t t_start = nc_now_us();
    if (report)
        memset(report, 0, sizeof(*report));
    nacre_voxel_settings s = settings ? *settings : nacre_voxel_settings_defaults();
    if (s.resolution == 0)
        s.resolution = 32;
    if (s.resolution > VOXEL_MAX_RES)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "voxelize: resolution %u above %u",
                       s.resolution, VOXEL_MAX_RES);
    if ((unsigned)s.solid_rule > NACRE_VOXEL_SOLID_ROBUST)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "voxelize: unknown solid rule %d",
                       (int)s.solid_rule);
    if (!mesh || mesh->triangle_count == 0 || mesh->vertex_count == 0)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "voxelize: mesh is empty");
    if (!mesh->positions || !mesh->indices)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "voxelize: mesh has no positions or indices");
    const size_t nt = mesh->triangle_count;
    const uint32_t nv = mesh->vertex_count;
    const float *pos = mesh->positions;
    const uint32_t *idx = mesh->indices;

    /* Bounds over the finite vertices, streamed (a pass over triangles gathers vertices at
     * random and costs several times more on large meshes); unreferenced vertices count too. */
    float bmin[3] = {INFINITY, INFINITY, INFINITY}, bmax[3] = {-INFINITY, -INFINITY, -INFINITY};
    int threads = nc_threads(ctx);
    uint32_t nonfinite_vertices = 0;
#pragma omp parallel num_threads(threads) if (nv > VOXEL_PARALLEL_MIN)
    {
        float lmin[3] = {INFINITY, INFINITY, INFINITY}, lmax[3] = {-INFINITY, -INFINITY, -INFINITY};
        uint32_t lnf = 0;
#pragma omp for schedule(static)
        for (size_t i = 0; i < nv; i++) {
            const float *p = pos + 3 * i;
            if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2])) {
                lnf++;
                continue;
            }
            for (int a = 0; a < 3; a++) {
                lmin[a] = fmn(lmin[a], p[a]);
                lmax[a] = fmx(lmax[a], p[a]);
            }
        }
#pragma omp critical(nacre_voxel_bounds)
        {
            for (int a = 0; a < 3; a++) {
                bmin[a] = fmn(bmin[a], lmin[a]);
                bmax[a] = fmx(bmax[a], lmax[a]);
            }
            nonfinite_vertices += lnf;
        }
    }
    if (!(bmin[0] <= bmax[0]))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "voxelize: no finite vertex");

    /* Fit: longest axis = resolution voxels. A flat or point mesh still gets a positive size. */
    double ext[3], longest = 0;
    for (int a = 0; a < 3; a++) {
        ext[a] = (double)bmax[a] - (double)bmin[a];
        longest = dmax(longest, ext[a]);
    }
    if (!(longest > 0))
        longest = dmax(1e-6, fabs((double)bmax[0]) * 1e-6);
    double h = longest / s.resolution;
    uint32_t dims[3];
    double origin[3];
    for (int a = 0; a < 3; a++) {
        if (s.anisotropic) {
            double n = ceil(ext[a] / h);
            dims[a] = n < 1 ? 1u : n > s.resolution ? s.resolution : (uint32_t)n;
        } else {
            dims[a] = s.resolution;
        }
        origin[a] = 0.5 * ((double)bmin[a] + (double)bmax[a]) - 0.5 * dims[a] * h;
    }

    bool fresh = *out == NULL;
    nacre_voxel_grid *g = fresh ? nc_calloc(ctx, 1, sizeof(*g)) : *out;
    if (!g)
        return NACRE_ERROR_OUT_OF_MEMORY;
    g->ctx = ctx;
    g->levels = 0;
    g->voxel_size = (float)h;
    for (int a = 0; a < 3; a++)
        g->origin[a] = (float)origin[a];
    nacre_result r = bitset_alloc(ctx, g, 0, dims);
    if (r != NACRE_OK)
        goto fail;
    /* Use the float-rounded origin and size so queries and exports describe exactly this grid. */
    tri_source src = {pos, idx, {g->origin[0], g->origin[1], g->origin[2]}, 1.0 / (double)g->voxel_size,
                      nonfinite_vertices == 0};

    nacre_voxel_solid_rule rule = s.solid_rule;
    bool closed = rule == NACRE_VOXEL_SOLID_PARITY;
    if (rule == NACRE_VOXEL_SOLID_AUTO) {
        closed = false;
        if (nonfinite_vertices == 0) {
            nacre_mesh_info info;
            r = nacre_mesh_analyze(ctx, mesh, &info);
            if (r != NACRE_OK)
                goto fail;
            closed = info.closed;
        }
        rule = closed ? NACRE_VOXEL_SOLID_PARITY : NACRE_VOXEL_SOLID_ROBUST;
    }

    bitset *b = &g->level[0];
    uint32_t degenerate = 0, nonfinite = 0, bad_index = 0;
    robust_sets rsets, *rs = NULL;
    if (rule == NACRE_VOXEL_SOLID_ROBUST) {
        rsets.wx = (dims[0] + 63u) / 64u;
        rsets.wy = (dims[1] + 63u) / 64u;
        /* Sizes cannot overflow: each is at most the level-0 size times 64 words per 4096 voxels. */
        r = words_prepare(ctx, &g->px, &g->cap_px, (size_t)dims[1] * dims[2] * rsets.wx);
        if (r == NACRE_OK)
            r = words_prepare(ctx, &g->py, &g->cap_py, (size_t)dims[2] * dims[0] * rsets.wy);
        if (r != NACRE_OK)
            goto fail;
        rsets.px = g->px;
        rsets.py = g->py;
        rs = &rsets;
    }
#ifdef __AVX2__
    fast_consts fc;
    fc.origin = _mm256_set_pd(0.0, src.origin[2], src.origin[1], src.origin[0]);
    fc.inv_h = _mm256_set1_pd(src.inv_h);
    fc.dimm1 = _mm256_set_pd(0.0, (double)dims[2] - 1, (double)dims[1] - 1, (double)dims[0] - 1);
#endif
    /* Surface and z parity in one pass over the triangles; indices are checked here rather than
     * in a pass of their own (one less sweep over the index array), and a bad one fails the
     * whole call after the loop. */
#define VOXEL_BLOCK 8
    size_t nblocks = (nt + VOXEL_BLOCK - 1) / VOXEL_BLOCK;
#pragma omp parallel for schedule(static) num_threads(threads) reduction(+ : degenerate, nonfinite, bad_index) if (nt > VOXEL_PARALLEL_MIN)
    for (size_t blk = 0; blk < nblocks; blk++) {
        size_t t0 = blk * VOXEL_BLOCK, t1 = t0 + VOXEL_BLOCK < nt ? t0 + VOXEL_BLOCK : nt;
        /* Vertex loads are random gathers and dominate on large meshes: fetch ahead. */
        for (size_t t = t0 + 32; t < t1 + 32 && t < nt; t++) {
            const uint32_t *ahead = idx + 3 * t;
            for (int k = 0; k < 3; k++) /* clamped: no out-of-range pointer is formed */
                __builtin_prefetch(pos + 3 * (size_t)(ahead[k] < nv ? ahead[k] : 0));
        }
#ifdef __AVX2__
        /* Whole blocks of valid indices: all loads first, then the branchy part, so the
         * gathers of a block overlap. */
        bool valid = src.all_finite && t1 - t0 == VOXEL_BLOCK;
        for (size_t t = t0; valid && t < t1; t++)
            valid = idx[3 * t] < nv && idx[3 * t + 1] < nv && idx[3 * t + 2] < nv;
        if (valid) {
            __m256d vb[VOXEL_BLOCK][3];
            for (size_t i = 0; i < VOXEL_BLOCK; i++)
                triangle_avx_load(pos, idx + 3 * (t0 + i), &fc, vb[i]);
            for (size_t i = 0; i < VOXEL_BLOCK; i++)
                degenerate += triangle_avx(b, vb[i], &fc, rs) == 2;
            continue;
        }
#endif
        for (size_t t = t0; t < t1; t++) {
            const uint32_t *ti = idx + 3 * t;
            if (ti[0] >= nv || ti[1] >= nv || ti[2] >= nv) {
                bad_index++;
                continue;
            }
            double v[3][3];
            int st = load_triangle(&src, t, v);
            degenerate += st == 2;
            nonfinite += st == 1;
            if (st != 0)
                continue;
            surface_triangle(b, (const double(*)[3])v);
            parity_triangle(b->solid, dims[0], dims[1], dims[2], b->words, (const double(*)[3])v, 0, 1, 2);
            if (rs)
                parity_xy(b, rs, (const double(*)[3])v, true, true);
        }
    }
    if (bad_index) {
        r = nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                    "voxelize: %u triangles have a vertex index >= vertex count %u", bad_index, nv);
        goto fail;
    }
    if (degenerate + nonfinite == nt) {
        r = nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "voxelize: no triangle with a finite, non-zero area");
        goto fail;
    }
    prefix_xor(b->solid, (size_t)dims[0] * dims[1], dims[2], b->words, threads);
    if (rs)
        robust_solid(rs, b, threads);

    /* Pyramid. */
    g->levels = 1;
    while (g->levels < VOXEL_MAX_LEVELS) {
        const bitset *f = &g->level[g->levels - 1];
        uint32_t cd[3];
        for (int a = 0; a < 3; a++)
            cd[a] = (f->dims[a] + 1) / 2;
        if (cd[0] < 4 || cd[1] < 4 || cd[2] < 4 || (f->dims[0] <= 4 || f->dims[1] <= 4 || f->dims[2] <= 4))
            break;
        bitset *c = &g->level[g->levels];
        r = bitset_alloc(ctx, g, g->levels, cd);
        if (r != NACRE_OK)
            goto fail;
        downsample(f, f->surface, c, c->surface, threads);
        downsample(f, f->solid, c, c->solid, threads);
        g->levels++;
    }

    if (report) {
        memcpy(report->dims, dims, sizeof(dims));
        report->voxel_size = g->voxel_size;
        memcpy(report->origin, g->origin, sizeof(g->origin));
        report->surface_voxels = popcount_set(b->surface, bitset_words(b));
        report->solid_voxels = popcount_set(b->solid, bitset_words(b));
        report->closed = closed;
        report->rule_used = rule;
        report->levels = g->levels;
        report->skipped_degenerate = degenerate;
        report->skipped_nonfinite = nonfinite;
        report->ms = (double)(nc_now_us() - t_start) / 1000.0;
    }
    *out = g;
    return NACRE_OK;
fail:
    if (fresh) {
        nacre_voxel_grid_destroy(g);
    } else {
        g->levels = 0;
        memset(g->level[0].dims, 0, sizeof(g->level[0].dims));
    }
    return r;
}

nacre_result nacre_voxelize(nacre_context *ctx, const nacre_mesh_data *mesh,
                            const nacre_voxel_settings *settings, nacre_voxel_grid **out,
                            nacre_voxel_report *report)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (report)
        memset(report, 0, sizeof(*report));
    if (!out)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "voxelize: output is NULL");
    *out = NULL;
    return voxelize_impl(ctx, mesh, settings, out, report);
}

nacre_result nacre_voxelize_update(nacre_voxel_grid *grid, const nacre_mesh_data *mesh,
                                   const nacre_voxel_settings *settings, nacre_voxel_report *report)
{
    if (report)
        memset(report, 0, sizeof(*report));
    if (!grid)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_voxel_grid *g = grid;
    return voxelize_impl(grid->ctx, mesh, settings, &g, report);
}

/* ------------------------------------------------------------------------------------------ */
/* Queries and export                                                                         */
/* ------------------------------------------------------------------------------------------ */

uint32_t nacre_voxel_grid_levels(const nacre_voxel_grid *grid)
{
    return grid ? grid->levels : 0;
}

bool nacre_voxel_grid_dims(const nacre_voxel_grid *grid, uint32_t level, uint32_t dims[3])
{
    if (!dims)
        return false;
    if (!grid || level >= grid->levels) {
        dims[0] = dims[1] = dims[2] = 0;
        return false;
    }
    memcpy(dims, grid->level[level].dims, 3 * sizeof(uint32_t));
    return true;
}

bool nacre_voxel_grid_get(const nacre_voxel_grid *grid, nacre_voxel_set set, uint32_t level,
                          uint32_t x, uint32_t y, uint32_t z)
{
    if (!grid || level >= grid->levels)
        return false;
    const bitset *b = &grid->level[level];
    if (x >= b->dims[0] || y >= b->dims[1] || z >= b->dims[2])
        return false;
    const uint64_t *s = set == NACRE_VOXEL_SOLID ? b->solid : b->surface;
    return get_bit(s, (size_t)y * b->dims[0] + x, b->words, z);
}

bool nacre_voxel_grid_unpack(const nacre_voxel_grid *grid, nacre_voxel_set set, uint32_t level, uint8_t *out)
{
    if (!grid || !out || level >= grid->levels)
        return false;
    const bitset *b = &grid->level[level];
    const uint64_t *s = set == NACRE_VOXEL_SOLID ? b->solid : b->surface;
    const size_t nx = b->dims[0], slab = nx * b->dims[1];
    /* Column by column: each 64-bit word holds 64 consecutive z of one (x, y). */
    for (size_t col = 0; col < slab; col++) {
        const uint64_t *w = s + col * b->words;
        for (uint32_t z = 0; z < b->dims[2]; z++)
            out[col + slab * z] = (uint8_t)((w[z / 64] >> (z % 64)) & 1u);
    }
    return true;
}

uint64_t nacre_voxel_grid_count(const nacre_voxel_grid *grid, nacre_voxel_set set, uint32_t level)
{
    if (!grid || level >= grid->levels)
        return 0;
    const bitset *b = &grid->level[level];
    return popcount_set(set == NACRE_VOXEL_SOLID ? b->solid : b->surface, bitset_words(b));
}

nacre_result nacre_voxel_grid_write_nrrd(const nacre_voxel_grid *grid, uint32_t level,
                                         const char *path)
{
    if (!grid)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_context *ctx = grid->ctx;
    if (!path || level >= grid->levels)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "voxel nrrd: no path or level %u missing", level);
    const bitset *b = &grid->level[level];
    size_t plen = strlen(path);
    char *tmp = nc_alloc(ctx, plen + 8);
    uint8_t *row = nc_alloc(ctx, 2 * (size_t)b->dims[0]);
    nacre_result r = NACRE_OK;
    FILE *f = NULL;
    if (!tmp || !row) {
        r = NACRE_ERROR_OUT_OF_MEMORY;
        goto out;
    }
    memcpy(tmp, path, plen);
    memcpy(tmp + plen, ".tmp", 5);
    f = fopen(tmp, "wb");
    if (!f) {
        r = nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot write: %s", path, strerror(errno));
        goto out;
    }
    double h = (double)grid->voxel_size * (double)(1u << level);
    /* NRRD places samples at their centres: "space origin" is the centre of voxel (0, 0, 0). */
    fprintf(f,
            "NRRD0004\n# nacre voxelization level %u: channel 0 solid, channel 1 surface\n"
            "type: uint8\ndimension: 4\nsizes: 2 %u %u %u\nkinds: vector domain domain domain\n"
            "encoding: raw\nspace dimension: 3\n"
            "space directions: none (%.9g,0,0) (0,%.9g,0) (0,0,%.9g)\n"
            "space origin: (%.9g,%.9g,%.9g)\n\n",
            level, b->dims[0], b->dims[1], b->dims[2], h, h, h, grid->origin[0] + 0.5 * h,
            grid->origin[1] + 0.5 * h, grid->origin[2] + 0.5 * h);
    for (uint32_t z = 0; z < b->dims[2]; z++)
        for (uint32_t y = 0; y < b->dims[1]; y++) {
            for (uint32_t x = 0; x < b->dims[0]; x++) {
                size_t col = (size_t)y * b->dims[0] + x;
                row[2 * x] = get_bit(b->solid, col, b->words, z);
                row[2 * x + 1] = get_bit(b->surface, col, b->words, z);
            }
            fwrite(row, 2, b->dims[0], f);
        }
    if (ferror(f) | (fclose(f) != 0)) {
        f = NULL;
        remove(tmp);
        r = nc_fail(ctx, NACRE_ERROR_IO, "%s: write failed", path);
        goto out;
    }
    f = NULL;
    if (rename(tmp, path) != 0) {
        remove(tmp);
        r = nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot rename: %s", path, strerror(errno));
    }
out:
    if (f) {
        fclose(f);
        remove(tmp);
    }
    nc_free(ctx, tmp);
    nc_free(ctx, row);
    return r;
}

/* ------------------------------------------------------------------------------------------ */
/* Rest-pose coordinates                                                                      */
/* ------------------------------------------------------------------------------------------ */

/* Closest point of triangle (a, b, c) to p as barycentric weights (Ericson 2005, 5.1.5). */
static void closest_bary(const double p[3], const double a[3], const double b[3], const double c[3],
                         double w[3])
{
    double ab[3], ac[3], ap[3], bp[3], cp[3];
    for (int k = 0; k < 3; k++) {
        ab[k] = b[k] - a[k];
        ac[k] = c[k] - a[k];
        ap[k] = p[k] - a[k];
        bp[k] = p[k] - b[k];
        cp[k] = p[k] - c[k];
    }
#define DOT(u, v) (u[0] * v[0] + u[1] * v[1] + u[2] * v[2])
    double d1 = DOT(ab, ap), d2 = DOT(ac, ap), d3 = DOT(ab, bp), d4 = DOT(ac, bp), d5 = DOT(ab, cp),
           d6 = DOT(ac, cp);
#undef DOT
    double va = d3 * d6 - d5 * d4, vb = d5 * d2 - d1 * d6, vc = d1 * d4 - d3 * d2;
    if (d1 <= 0 && d2 <= 0) {
        w[0] = 1, w[1] = 0, w[2] = 0;
    } else if (d3 >= 0 && d4 <= d3) {
        w[0] = 0, w[1] = 1, w[2] = 0;
    } else if (vc <= 0 && d1 >= 0 && d3 <= 0) {
        double t = d1 / (d1 - d3);
        w[0] = 1 - t, w[1] = t, w[2] = 0;
    } else if (d6 >= 0 && d5 <= d6) {
        w[0] = 0, w[1] = 0, w[2] = 1;
    } else if (vb <= 0 && d2 >= 0 && d6 <= 0) {
        double t = d2 / (d2 - d6);
        w[0] = 1 - t, w[1] = 0, w[2] = t;
    } else if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
        double t = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        w[0] = 0, w[1] = 1 - t, w[2] = t;
    } else {
        double den = 1.0 / (va + vb + vc);
        w[1] = vb * den;
        w[2] = vc * den;
        w[0] = 1 - w[1] - w[2];
    }
}

nacre_result nacre_voxel_grid_rest_positions(const nacre_voxel_grid *grid,
                                             const nacre_mesh_data *rest,
                                             const nacre_mesh_data *deformed, float *out)
{
    if (!grid)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_context *ctx = grid->ctx;
    if (!rest || !deformed || !out || !rest->positions || !deformed->positions ||
        !deformed->indices || rest->vertex_count != deformed->vertex_count)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "voxel rest positions: need rest and deformed meshes with the same vertices");
    const bitset *b = &grid->level[0];
    const uint32_t *d = b->dims;
    const size_t nvox = (size_t)d[0] * d[1] * d[2];
    if (nvox > UINT32_MAX) /* the breadth-first queue holds 32-bit voxel ids */
        return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "voxel rest positions: more than 2^32 voxels");
    float *best = nc_alloc(ctx, nvox * sizeof(float));
    uint32_t *queue = nc_alloc(ctx, nvox * sizeof(uint32_t));
    if (!best || !queue) {
        nc_free(ctx, best);
        nc_free(ctx, queue);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    for (size_t i = 0; i < nvox; i++) {
        best[i] = INFINITY;
        out[3 * i] = out[3 * i + 1] = out[3 * i + 2] = NAN;
    }
    tri_source src = {deformed->positions, deformed->indices,
                      {grid->origin[0], grid->origin[1], grid->origin[2]}, 1.0 / (double)grid->voxel_size, false};
    const double h = grid->voxel_size;
    /* Surface voxels: closest deformed triangle among those touching the voxel (bounding box). */
    for (size_t t = 0; t < deformed->triangle_count; t++) {
        const uint32_t *ti = deformed->indices + 3 * t;
        if (ti[0] >= deformed->vertex_count || ti[1] >= deformed->vertex_count ||
            ti[2] >= deformed->vertex_count)
            continue;
        double v[3][3];
        if (load_triangle(&src, t, v) != 0)
            continue;
        int lo[3], hi[3];
        bool empty = false;
        for (int a = 0; a < 3; a++) {
            double mn = dmin(v[0][a], dmin(v[1][a], v[2][a])), mx = dmax(v[0][a], dmax(v[1][a], v[2][a]));
            lo[a] = (int)dmax(0.0, ceil(mn) - 1.0);
            hi[a] = (int)dmin((double)d[a] - 1, floor(mx));
            empty = empty || lo[a] > hi[a];
        }
        if (empty)
            continue;
        for (int z = lo[2]; z <= hi[2]; z++)
            for (int y = lo[1]; y <= hi[1]; y++)
                for (int x = lo[0]; x <= hi[0]; x++) {
                    size_t col = (size_t)y * d[0] + (size_t)x;
                    if (!get_bit(b->surface, col, b->words, (uint32_t)z))
                        continue;
                    double p[3] = {x + 0.5, y + 0.5, z + 0.5}, w[3];
                    closest_bary(p, v[0], v[1], v[2], w);
                    double dist = 0;
                    for (int a = 0; a < 3; a++) {
                        double q = w[0] * v[0][a] + w[1] * v[1][a] + w[2] * v[2][a] - p[a];
                        dist += q * q;
                    }
                    size_t vi = col + (size_t)z * d[0] * d[1];
                    if (dist < best[vi]) {
                        best[vi] = (float)dist;
                        for (int a = 0; a < 3; a++)
                            out[3 * vi + (size_t)a] =
                                (float)(w[0] * rest->positions[3 * (size_t)ti[0] + (size_t)a] +
                                        w[1] * rest->positions[3 * (size_t)ti[1] + (size_t)a] +
                                        w[2] * rest->positions[3 * (size_t)ti[2] + (size_t)a]);
                    }
                }
    }
    /* Store displacements (rest - deformed centre) on surface voxels, then spread them
     * breadth-first through the solid voxels. */
    size_t head = 0, tail = 0;
    for (size_t vi = 0; vi < nvox; vi++) {
        if (!isfinite(out[3 * vi]))
            continue;
        size_t x = vi % d[0], y = (vi / d[0]) % d[1], z = vi / ((size_t)d[0] * d[1]);
        double c[3] = {grid->origin[0] + (x + 0.5) * h, grid->origin[1] + (y + 0.5) * h,
                       grid->origin[2] + (z + 0.5) * h};
        for (int a = 0; a < 3; a++)
            out[3 * vi + (size_t)a] -= (float)c[a];
        queue[tail++] = (uint32_t)vi;
    }
    while (head < tail) {
        size_t vi = queue[head++];
        long x = (long)(vi % d[0]), y = (long)((vi / d[0]) % d[1]), z = (long)(vi / ((size_t)d[0] * d[1]));
        static const int off[6][3] = {{-1, 0, 0}, {1, 0, 0}, {0, -1, 0}, {0, 1, 0}, {0, 0, -1}, {0, 0, 1}};
        for (int k = 0; k < 6; k++) {
            long nx = x + off[k][0], ny = y + off[k][1], nz = z + off[k][2];
            if (nx < 0 || ny < 0 || nz < 0 || nx >= (long)d[0] || ny >= (long)d[1] || nz >= (long)d[2])
                continue;
            size_t col = (size_t)ny * d[0] + (size_t)nx, ni = col + (size_t)nz * d[0] * d[1];
            if (isfinite(out[3 * ni]) || !get_bit(b->solid, col, b->words, (uint32_t)nz))
                continue;
            for (int a = 0; a < 3; a++)
                out[3 * ni + (size_t)a] = out[3 * vi + (size_t)a];
            queue[tail++] = (uint32_t)ni;
        }
    }
    /* Displacement back to positions. */
    for (size_t vi = 0; vi < nvox; vi++) {
        if (!isfinite(out[3 * vi]))
            continue;
        size_t x = vi % d[0], y = (vi / d[0]) % d[1], z = vi / ((size_t)d[0] * d[1]);
        out[3 * vi] += (float)(grid->origin[0] + (x + 0.5) * h);
        out[3 * vi + 1] += (float)(grid->origin[1] + (y + 0.5) * h);
        out[3 * vi + 2] += (float)(grid->origin[2] + (z + 0.5) * h);
    }
    nc_free(ctx, best);
    nc_free(ctx, queue);
    return NACRE_OK;
}
