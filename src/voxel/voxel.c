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
 * prism its extent crosses. A triangle inside one layer along some axis (bounding box one voxel
 * thick) touches a voxel of the layer exactly when its projection along that axis touches the
 * voxel's square, so the three edge functions of that projection decide (SS10's 2D test).
 * Otherwise the full SS10 test: plane test with the critical-point offsets d1, d2, then the xy,
 * yz and zx edge functions offset to the box corner that maximises them. Touching counts
 * (<= / >=), so the set is conservative: with exact arithmetic it equals the set of closed boxes
 * the closed triangle meets. The per-voxel tests run on 2 x 2 tiles of voxels, four lanes at once.
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
 * The x and y toggles are stored in the layout of the solid set (bit z of column x + nx * y), so
 * the running XOR along x or y and the vote are word operations on 64 voxels at a time.
 *
 * Triangle pass (AVX2): four triangles at a time, one per lane (load4, triangles4): grid
 * coordinates, normal, voxel bounds and column-centre ranges in doubles with the same operations
 * as the scalar path (triangle_one, used without AVX2, for meshes with a non-finite vertex and
 * for the last triangles), so both give the same bits. Bounds of one voxel or two in a line are
 * marked in the lanes; crossings that are the only column centre of their triangle are toggled in
 * the lanes (parity4), and so are the 2 x 2 footprints in one layer (flat4) and 2 x 2 x 2 bounds
 * (box4), which are most of the rest once voxels are a few triangles wide; what remains goes to
 * surface_bounded / parity_triangle one triangle at a time.
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
#include "core/core.h"
#include "io/nrrd.h"

#include <errno.h>
#include <math.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#if defined(__AVX2__) || defined(__BMI2__)
#include <immintrin.h>
#endif
#include <stdio.h>
#include <string.h>

#define VOXEL_MAX_RES 4096u
#define VOXEL_MAX_LEVELS 16
#define VOXEL_PARALLEL_MIN 4096
#define VOXEL_CHUNK 1024 /* triangles (vertices) per scheduling unit of the triangle (bounds) pass */
#define VOXEL_BOUNDS_PARALLEL 65536
#define VOXEL_PRIVATE_WORDS 4        /* per-thread copies of the level-0 sets: at most this many words per triangle */
#define VOXEL_PRIVATE_MAX (1u << 18) /* and at most this many words (2 MiB) per thread */
#define VOXEL_PREFETCH_MIN 16384 /* vertices (192 KiB) below which the triangle pass does not prefetch */
#define VOXEL_PRE_RATE_MIN 46 /* of 64: the prefilter pays when about 70% of the triangles pass it */
#define VOXEL_MERGE_PARALLEL 32768 /* words of copies merged by all threads rather than one */

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
    bool shared; /* other threads write the same words: atomic read-modify-writes */
} bitset;

struct nacre_voxel_grid {
    nacre_context *ctx;
    float origin[3];
    float voxel_size;
    uint32_t levels;
    bitset level[VOXEL_MAX_LEVELS];
    size_t cap[VOXEL_MAX_LEVELS]; /* words allocated for each of surface and solid, per level */
    uint64_t *px, *py;            /* ROBUST scratch: x and y parities (level-0 layout), kept across updates */
    size_t cap_px, cap_py;        /* words allocated in px, py */
    uint64_t *priv;               /* per-thread level-0 sets of a small grid (see voxelize_impl), kept */
    size_t cap_priv;
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
    nc_free(grid->ctx, grid->priv);
    nc_free(grid->ctx, grid);
}

/* Bits lo..hi (inclusive, 0 <= lo <= hi <= 63). */
static inline uint64_t bit_range(uint32_t lo, uint32_t hi)
{
    uint64_t top = hi == 63 ? ~0ull : ((1ull << (hi + 1)) - 1);
    return top & ~((1ull << lo) - 1);
}

/* Set bits m of *w; a locked RMW only when other threads write the same set. */
static inline void bits_or(bool shared, uint64_t *w, uint64_t m)
{
    if (!shared) {
        *w |= m;
        return;
    }
    /* Reading first skips the locked RMW when the bits are already there (common on dense meshes). */
    if ((__atomic_load_n(w, __ATOMIC_RELAXED) & m) != m)
        __atomic_fetch_or(w, m, __ATOMIC_RELAXED);
}

static inline void bits_xor(bool shared, uint64_t *w, uint64_t m)
{
    if (shared)
        __atomic_fetch_xor(w, m, __ATOMIC_RELAXED);
    else
        *w ^= m;
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

/* ------------------------------------------------------------------------------------------ */
/* Solid: column parity                                                                       */
/* ------------------------------------------------------------------------------------------ */

/* Top-left rule for edge p -> q of a counter-clockwise triangle in the (a, b) plane (b up):
 * left edges go down, top edges are horizontal and go left. */
static inline bool top_left(const double *p, const double *q, int a, int b)
{
    return (q[b] < p[b]) | ((q[b] == p[b]) & (q[a] < p[a]));
}

/* Edge function of (p -> q) in the (a, b) plane, set up with the endpoints in canonical
 * (lexicographic) order so that the reversed edge gives exactly the negated value. */
typedef struct edge_canon {
    const double *s;
    double ea, eb, sign;
    bool tl; /* top-left (owns points on it) */
} edge_canon;

static inline void edge_canon_setup(const double *p, const double *q, int a, int b, edge_canon *e)
{
    /* Bitwise, not short-circuit: the order of two vertices is a coin toss, and branches on it
     * cost more than the arithmetic (most triangles reaching here cover one column centre). */
    bool swap = (p[a] > q[a]) | ((p[a] == q[a]) & (p[b] > q[b]));
    const double *s = swap ? q : p, *t = swap ? p : q;
    e->s = s;
    e->ea = t[a] - s[a];
    e->eb = t[b] - s[b];
    e->sign = swap ? -1.0 : 1.0;
    e->tl = top_left(p, q, a, b);
}

static inline bool edge_owns(const edge_canon *e, int a, int b, double x, double y)
{
    double f = e->sign * (e->ea * (y - e->s[b]) - e->eb * (x - e->s[a]));
    return (f > 0) | ((f == 0) & e->tl);
}

/* Toggle, in `flip` (laid out like the level-0 sets of b: bit z of column x + nx * y), the first
 * voxel above each crossing of the lines along axis c through the voxel centres of the (a, b)
 * plane. Every flip set shares that layout so that the ROBUST vote is word-wise (see
 * robust_solid). */
static void parity_triangle(uint64_t *flip, const bitset *bs, const double v[3][3], const double n[3], int a,
                            int b, int c)
{
    const uint32_t da = bs->dims[a], db = bs->dims[b], nc = bs->dims[c];
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
    /* n[c] is the doubled projected area, with the same operations as the 2D cross product. */
    if (n[c] == 0)
        return; /* edge-on: the neighbours' top-left rule owns the lines through it */
    if (n[c] < 0) {
        const double *t = p1;
        p1 = p2;
        p2 = t;
    }
    edge_canon e0, e1, e2;
    edge_canon_setup(p0, p1, a, b, &e0);
    edge_canon_setup(p1, p2, a, b, &e1);
    edge_canon_setup(p2, p0, a, b, &e2);
    /* Plane: c = v0[c] + ga * (x - v0[a]) + gb * (y - v0[b]). */
    double ga = -n[a] / n[c], gb = -n[b] / n[c];
    /* Bit address of voxel (x, y, z) is 64 * words * (x + nx * y) + z. */
    size_t stride[3] = {(size_t)64 * bs->words, (size_t)64 * bs->words * bs->dims[0], 1};
    for (int j = (int)ib0; j <= (int)ib1; j++) {
        double y = j + 0.5;
        for (int i = (int)ia0; i <= (int)ia1; i++) {
            double x = i + 0.5;
            if (!(edge_owns(&e0, a, b, x, y) & edge_owns(&e1, a, b, x, y) & edge_owns(&e2, a, b, x, y)))
                continue;
            double zc = v[0][c] + ga * (x - v[0][a]) + gb * (y - v[0][b]);
            /* First voxel whose centre k + 0.5 lies strictly above the crossing. */
            double k0 = floor(zc - 0.5) + 1.0;
            if (k0 < 0)
                k0 = 0;
            if (k0 >= (double)nc)
                continue;
            size_t bit = (size_t)i * stride[a] + (size_t)j * stride[b] + (size_t)k0 * stride[c];
            bits_xor(bs->shared, flip + bit / 64, 1ull << (bit % 64));
        }
    }
}

/* Turn toggles into inside bits: prefix XOR along every column, masked to nc voxels. */
static void prefix_xor(uint64_t *flip, size_t columns, uint32_t nc, uint32_t words, int threads)
{
    uint64_t last = nc % 64 ? (1ull << (nc % 64)) - 1 : ~0ull;
#pragma omp parallel for schedule(static) num_threads(threads) if (columns * words > 16384)
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
    float margin;    /* of the float prefilter (prefilter8), grid units; 0: no prefilter */
} tri_source;

/* Grid coordinates of triangle t and its normal (e1 x e2); 1 if a vertex is not finite, 2 if
 * the area is zero, else 0. */
static inline int load_triangle(const tri_source *s, size_t t, double v[3][3], double n[3])
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
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
    return n[0] == 0 && n[1] == 0 && n[2] == 0 ? 2 : 0;
}

/* Where a triangle's bits go: level 0 and, for ROBUST, the x and y toggle sets (NULL otherwise),
 * laid out like the solid set; filled in the same triangle pass as the surface and z parity (the
 * XOR toggles commute, so the result is the same as in passes of their own). */
typedef struct tri_out {
    const bitset *b;
    uint64_t *px, *py;
} tri_out;

typedef struct tri_counts {
    uint32_t degenerate, nonfinite, bad_index;
} tri_counts;

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
    parity_triangle(o->b->solid, o->b, (const double(*)[3])v, n, 0, 1, 2);
    if (o->px) {
        parity_triangle(o->px, o->b, (const double(*)[3])v, n, 1, 2, 0);
        parity_triangle(o->py, o->b, (const double(*)[3])v, n, 2, 0, 1);
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

/* parity_triangle for the lanes in `lanes`, each with exactly one column centre (pl[a] + 0.5,
 * pl[b] + 0.5) in its projected bounds: the same double operations lane by lane (orientation
 * swap, canonical edge order, top-left rule, crossing height). Returns the lanes done (all of
 * `lanes`, toggled or not). */
static unsigned parity4(uint64_t *flip, const bitset *bs, __m256d v[3][3], const __m256d n[3], const __m256d pl[3],
                        unsigned lanes, int a, int b, int c)
{
    const __m256d zero = _mm256_setzero_pd(), half = _mm256_set1_pd(0.5), sgn = _mm256_set1_pd(-0.0);
    /* n[c] == 0: edge-on, no crossing (as in parity_triangle). */
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
 * the column-centre ranges of parity_triangle, all with the same double operations, so every
 * decision is bit-identical to triangle_one. A triangle inside one voxel with no column centre
 * in any projection (nearly all triangles of a large mesh on a coarse grid) ends here with one
 * bit set; the others go on to surface_bounded / parity_triangle with the same arguments as in
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
                parity_triangle(b->solid, b, (const double(*)[3])vv, nn, 0, 1, 2);
            if (xpar & bit)
                parity_triangle(o->px, b, (const double(*)[3])vv, nn, 1, 2, 0);
            if (ypar & bit)
                parity_triangle(o->py, b, (const double(*)[3])vv, nn, 2, 0, 1);
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

static inline bool get_bit(const uint64_t *set, size_t col, uint32_t words, uint32_t k)
{
    return (set[col * words + k / 64] >> (k % 64)) & 1u;
}

/* ROBUST: px and py hold the x and y toggles in the layout of the solid set, where a running XOR
 * along x or y is word-wise (64 voxels of a column at a time) instead of bit by bit; the solid set
 * (z parity, already prefix-XORed) then becomes the bitwise majority of the three parities. */
static void robust_solid(uint64_t *px, uint64_t *py, bitset *b, int threads)
{
    const size_t w = b->words, row = (size_t)b->dims[0] * w, ny = b->dims[1];
    uint64_t *solid = b->solid;
#pragma omp parallel num_threads(threads) if (row * ny > 16384)
    {
        /* Along y, over the words of a row: each thread keeps a contiguous strip of columns. */
#pragma omp for schedule(static)
        for (size_t i = 0; i < row; i++) {
            uint64_t acc = 0;
            for (size_t y = 0; y < ny; y++) {
                acc ^= py[y * row + i];
                py[y * row + i] = acc;
            }
        }
#pragma omp for schedule(static)
        for (size_t y = 0; y < ny; y++) {
            uint64_t *rx = px + y * row, *ry = py + y * row, *rs = solid + y * row;
            for (size_t i = w; i < row; i++)
                rx[i] ^= rx[i - w];
            for (size_t i = 0; i < row; i++)
                rs[i] = (rs[i] & (rx[i] | ry[i])) | (rx[i] & ry[i]);
        }
    }
}

/* OR of bits 2i and 2i+1 of a word into bit i of the low half. */
static inline uint64_t compress_pairs(uint64_t w)
{
#ifdef __BMI2__
    return _pext_u64(w | (w >> 1), 0x5555555555555555ull); /* one instruction for the five steps */
#else
    uint64_t x = (w | (w >> 1)) & 0x5555555555555555ull;
    x = (x | (x >> 1)) & 0x3333333333333333ull;
    x = (x | (x >> 2)) & 0x0f0f0f0f0f0f0f0full;
    x = (x | (x >> 4)) & 0x00ff00ff00ff00ffull;
    x = (x | (x >> 8)) & 0x0000ffff0000ffffull;
    x = (x | (x >> 16)) & 0x00000000ffffffffull;
    return x;
#endif
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

/* Extend mn, mx by the finite vertices i0..i1 and count the others. */
static void vertex_bounds(const float *pos, size_t i0, size_t i1, float mn[3], float mx[3], uint32_t *nonfinite)
{
    size_t i = i0;
#ifdef __AVX2__
    /* Eight vertices are three registers of floats whose lanes keep their axis (float j of the
     * group is axis j % 3) from group to group; a group with a NaN or infinity (x - x != 0)
     * goes to the scalar loop below. */
    __m256 lo[3], hi[3];
    for (int r = 0; r < 3; r++) {
        lo[r] = _mm256_set1_ps(INFINITY);
        hi[r] = _mm256_set1_ps(-INFINITY);
    }
    for (; i + 8 <= i1; i += 8) {
        const float *p = pos + 3 * i;
        __m256 r0 = _mm256_loadu_ps(p), r1 = _mm256_loadu_ps(p + 8), r2 = _mm256_loadu_ps(p + 16);
        __m256 z = _mm256_setzero_ps();
        __m256 fin = _mm256_and_ps(_mm256_cmp_ps(_mm256_sub_ps(r0, r0), z, _CMP_EQ_OQ),
                                   _mm256_and_ps(_mm256_cmp_ps(_mm256_sub_ps(r1, r1), z, _CMP_EQ_OQ),
                                                 _mm256_cmp_ps(_mm256_sub_ps(r2, r2), z, _CMP_EQ_OQ)));
        if (_mm256_movemask_ps(fin) != 0xFF)
            break;
        lo[0] = _mm256_min_ps(lo[0], r0), hi[0] = _mm256_max_ps(hi[0], r0);
        lo[1] = _mm256_min_ps(lo[1], r1), hi[1] = _mm256_max_ps(hi[1], r1);
        lo[2] = _mm256_min_ps(lo[2], r2), hi[2] = _mm256_max_ps(hi[2], r2);
    }
    float l[24], h[24];
    for (int r = 0; r < 3; r++) {
        _mm256_storeu_ps(l + 8 * r, lo[r]);
        _mm256_storeu_ps(h + 8 * r, hi[r]);
    }
    for (int j = 0; j < 24; j++) {
        mn[j % 3] = fmn(mn[j % 3], l[j]);
        mx[j % 3] = fmx(mx[j % 3], h[j]);
    }
#endif
    for (; i < i1; i++) {
        const float *p = pos + 3 * i;
        if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2])) {
            (*nonfinite)++;
            continue;
        }
        for (int a = 0; a < 3; a++) {
            mn[a] = fmn(mn[a], p[a]);
            mx[a] = fmx(mx[a], p[a]);
        }
    }
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
    /* Serial below VOXEL_BOUNDS_PARALLEL: a fork and join would cost more than the pass. */
#pragma omp parallel num_threads(threads) if (nv > VOXEL_BOUNDS_PARALLEL)
    {
        float lmin[3] = {INFINITY, INFINITY, INFINITY}, lmax[3] = {-INFINITY, -INFINITY, -INFINITY};
        uint32_t lnf = 0;
        size_t nblk = ((size_t)nv + VOXEL_CHUNK - 1) / VOXEL_CHUNK;
#pragma omp for schedule(static)
        for (size_t blk = 0; blk < nblk; blk++) {
            size_t i0 = blk * VOXEL_CHUNK, i1 = i0 + VOXEL_CHUNK < nv ? i0 + VOXEL_CHUNK : nv;
            vertex_bounds(pos, i0, i1, lmin, lmax, &lnf);
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
    {
        /* The estimate before anything is made: level 0's two sets, two more parity sets under
         * the robust rule, and the pyramid (under a seventh of level 0). Only what a reused grid
         * does not hold yet counts. */
        uint64_t words = (uint64_t)dims[0] * dims[1] * ((dims[2] + 63u) / 64u);
        uint64_t sets = s.solid_rule == NACRE_VOXEL_SOLID_PARITY ? 2 : 4;
        uint64_t need = words * 8 * sets + words * 8 * 2 / 7;
        if (fresh || words > (*out)->cap[0]) {
            char what[96];
            snprintf(what, sizeof(what), "voxel grid %ux%ux%u (voxel resolution %u)", dims[0], dims[1], dims[2],
                     s.resolution);
            nacre_result mr = nc_memory_check(ctx, need, what);
            if (mr != NACRE_OK)
                return mr;
        }
    }
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
                      nonfinite_vertices == 0, 0.0f};
    {
        /* Float grid coordinates differ from the doubles by at most 4 * 2^-24 * (|p| + |origin|) / h (see
         * prefilter8); the margin is 16 times that, plus an absolute term for the roundings of small values. A
         * margin of an eighth of a voxel or more would pass almost nothing: no prefilter then. */
        double amax = 0, omax = 0;
        for (int a = 0; a < 3; a++) {
            amax = dmax(amax, dmax(fabs((double)bmin[a]), fabs((double)bmax[a])));
            omax = dmax(omax, fabs((double)g->origin[a]));
        }
        double m = 64.0 * 0x1p-24 * (amax + omax) * src.inv_h + 1e-6;
        if (m < 0.125 && isfinite((float)src.inv_h))
            src.margin = (float)m;
    }

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
    tri_out dst = {b, NULL, NULL};
    if (rule == NACRE_VOXEL_SOLID_ROBUST) {
        /* Same size as a level-0 set, which bitset_alloc has checked for overflow. */
        r = words_prepare(ctx, &g->px, &g->cap_px, bitset_words(b));
        if (r == NACRE_OK)
            r = words_prepare(ctx, &g->py, &g->cap_py, bitset_words(b));
        if (r != NACRE_OK)
            goto fail;
        dst.px = g->px;
        dst.py = g->py;
    }
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
            goto fail;
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
            triangle_range(&mine, &src, nv, nt, t0, t1, &cnt);
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
    if (dst.px)
        robust_solid(dst.px, dst.py, b, threads);

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

typedef struct nrrd_rows {
    const bitset *b;
} nrrd_rows;

/* Channel 0 solid, channel 1 surface. */
static void nrrd_row(void *user, uint32_t y, uint32_t z, uint8_t *row)
{
    const bitset *b = ((const nrrd_rows *)user)->b;
    for (uint32_t x = 0; x < b->dims[0]; x++) {
        size_t col = (size_t)y * b->dims[0] + x;
        row[2 * x] = get_bit(b->solid, col, b->words, z);
        row[2 * x + 1] = get_bit(b->surface, col, b->words, z);
    }
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
    double h = (double)grid->voxel_size * (double)(1u << level);
    /* NRRD places samples at their centres: "space origin" is the centre of voxel (0, 0, 0). */
    const double origin[3] = {grid->origin[0] + 0.5 * h, grid->origin[1] + 0.5 * h, grid->origin[2] + 0.5 * h};
    char comment[96];
    snprintf(comment, sizeof(comment), "nacre voxelization level %u: channel 0 solid, channel 1 surface", level);
    nrrd_rows rows = {b};
    return nc_nrrd_write_u8(ctx, path, comment, 2, b->dims, h, origin, nrrd_row, &rows);
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
                      {grid->origin[0], grid->origin[1], grid->origin[2]}, 1.0 / (double)grid->voxel_size, false,
                      0.0f};
    const double h = grid->voxel_size;
    /* Surface voxels: closest deformed triangle among those touching the voxel (bounding box). */
    for (size_t t = 0; t < deformed->triangle_count; t++) {
        const uint32_t *ti = deformed->indices + 3 * t;
        if (ti[0] >= deformed->vertex_count || ti[1] >= deformed->vertex_count ||
            ti[2] >= deformed->vertex_count)
            continue;
        double v[3][3], nrm[3];
        if (load_triangle(&src, t, v, nrm) != 0)
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
