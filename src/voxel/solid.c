/*
 * solid.c: the voxelizer's solid rules (seed 000, section 4.2; Schwarz and Seidel 2010): the
 * parity toggles of one triangle, the prefix XOR that turns them into inside bits, and the
 * ROBUST majority vote. Grid coordinates as in voxel_internal.h (one voxel = one unit).
 *
 * Solid (parity): a column line through voxel centres (i + 0.5, j + 0.5) crosses a triangle
 * when the point is inside its xy projection; the crossing toggles one bit (the first voxel
 * whose centre lies above the crossing) in a flip set, and a prefix XOR along each column then
 * turns the toggles into "inside" bits (the seed's XOR of a prefix mask, done once per column
 * instead of once per crossing). Points on an edge are decided by the top-left rule on the
 * projection turned counter-clockwise, and every edge function is evaluated with its endpoints
 * in one canonical order (lexicographic by position), so two triangles sharing an edge get
 * exactly opposite values and a line through a shared edge or vertex is counted once (or an even
 * number of times at a silhouette fold, which leaves parity right). The four-lane form of the
 * toggles of the triangle pass (parity4) lives in surface.c.
 * Robust (meshes not closed): the same parity along x, y and z, and a voxel is solid when at least
 * two agree. A hole or flipped patch spoils the lines through it along one axis; the other two
 * usually miss it. A duplicated patch adds two crossings at the same place and cancels itself.
 * The x and y toggles are stored in the layout of the solid set (bit z of column x + nx * y), so
 * the running XOR along x or y and the vote are word operations on 64 voxels at a time.
 */
#include "voxel/voxel_internal.h"

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
 * nc_voxel_robust_solid). */
void nc_voxel_parity_triangle(uint64_t *flip, const bitset *bs, const double v[3][3], const double n[3], int a,
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
            if (!((int)edge_owns(&e0, a, b, x, y) & (int)edge_owns(&e1, a, b, x, y) & (int)edge_owns(&e2, a, b, x, y)))
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
void nc_voxel_prefix_xor(uint64_t *flip, size_t columns, uint32_t nc, uint32_t words, int threads)
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

/* ROBUST: px and py hold the x and y toggles in the layout of the solid set, where a running XOR
 * along x or y is word-wise (64 voxels of a column at a time) instead of bit by bit; the solid set
 * (z parity, already prefix-XORed) then becomes the bitwise majority of the three parities. */
void nc_voxel_robust_solid(uint64_t *px, uint64_t *py, bitset *b, int threads)
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
