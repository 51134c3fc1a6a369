/*
 * test_voxel.c: voxelization (src/voxel/): solid counts against mesh volumes, exact
 * grid-aligned cubes, conservativeness against a brute-force separating-axis test (random
 * triangles, and random closed star-shaped meshes whose solid set is checked against an exact
 * inside test), shared edges (few vs many triangles), broken meshes, degenerate input, the level
 * pyramid, a 512^3 grid, thread independence (closed and open meshes, per-thread copies),
 * rest-pose coordinates and the `nacre voxelize` CLI.
 *
 * Volume bound: a voxel whose box does not touch the surface is entirely inside or entirely
 * outside, so its centre decides it exactly; only voxels touching the surface (the conservative
 * surface set, counted in the report) can be wrong, each by at most its volume h^3. Hence
 * |solid * h^3 - V| <= surface_voxels * h^3, with V the volume of the polyhedron (divergence
 * theorem), not of the smooth shape the mesh approximates.
 */
#include "test_util.h"

#include <nacre/nacre.h>

#include <sys/wait.h>

static nacre_context *ctx_threads(int threads)
{
    nacre_context_desc d = {0};
    d.threads = threads;
    nacre_context *ctx = NULL;
    nacre_context_create(&d, &ctx);
    return ctx;
}

static double mesh_volume(const nacre_mesh_data *m)
{
    double v = 0;
    for (uint32_t t = 0; t < m->triangle_count; t++) {
        const float *a = m->positions + 3 * m->indices[3 * t], *b = m->positions + 3 * m->indices[3 * t + 1],
                    *c = m->positions + 3 * m->indices[3 * t + 2];
        v += (double)a[0] * ((double)b[1] * c[2] - (double)b[2] * c[1]) -
             (double)a[1] * ((double)b[0] * c[2] - (double)b[2] * c[0]) +
             (double)a[2] * ((double)b[0] * c[1] - (double)b[1] * c[0]);
    }
    return v / 6.0;
}

static nacre_voxel_grid *vox(nacre_context *ctx, const nacre_mesh_data *m, uint32_t res, bool aniso,
                             nacre_voxel_solid_rule rule, nacre_voxel_report *rep)
{
    nacre_voxel_settings s = nacre_voxel_settings_defaults();
    s.resolution = res;
    s.anisotropic = aniso;
    s.solid_rule = rule;
    nacre_voxel_grid *g = NULL;
    nacre_result r = nacre_voxelize(ctx, m, &s, &g, rep);
    if (r != NACRE_OK)
        printf("voxelize failed: %s\n", nacre_context_last_error(ctx));
    CHECK(r == NACRE_OK);
    return g;
}

static bool same_set(const nacre_voxel_grid *a, const nacre_voxel_grid *b, nacre_voxel_set set, uint64_t *diff)
{
    uint32_t da[3], db[3];
    nacre_voxel_grid_dims(a, 0, da);
    nacre_voxel_grid_dims(b, 0, db);
    if (memcmp(da, db, sizeof(da)) != 0)
        return false;
    *diff = 0;
    for (uint32_t z = 0; z < da[2]; z++)
        for (uint32_t y = 0; y < da[1]; y++)
            for (uint32_t x = 0; x < da[0]; x++)
                *diff += nacre_voxel_grid_get(a, set, 0, x, y, z) != nacre_voxel_grid_get(b, set, 0, x, y, z);
    return *diff == 0;
}

static void check_volume(nacre_context *ctx, nacre_shape_desc sd, uint32_t res)
{
    nacre_mesh_data m = {0};
    CHECK(nacre_mesh_make_shape(ctx, &sd, &m) == NACRE_OK);
    nacre_voxel_report rep;
    nacre_voxel_grid *g = vox(ctx, &m, res, false, NACRE_VOXEL_SOLID_AUTO, &rep);
    double h3 = (double)rep.voxel_size * rep.voxel_size * rep.voxel_size;
    double v = mesh_volume(&m);
    CHECK(rep.closed);
    CHECK(rep.rule_used == NACRE_VOXEL_SOLID_PARITY);
    CHECK_NEAR((double)rep.solid_voxels * h3, v, (double)rep.surface_voxels * h3);
    CHECK(nacre_voxel_grid_count(g, NACRE_VOXEL_SOLID, 0) == rep.solid_voxels);
    /* The robust rule agrees with parity on a closed mesh, up to centres on the surface. */
    nacre_voxel_report rep2;
    nacre_voxel_grid *g2 = vox(ctx, &m, res, false, NACRE_VOXEL_SOLID_ROBUST, &rep2);
    uint64_t diff = 0;
    same_set(g, g2, NACRE_VOXEL_SOLID, &diff);
    CHECK(diff <= rep.solid_voxels / 1000);
    nacre_voxel_grid_destroy(g2);
    nacre_voxel_grid_destroy(g);
    nacre_mesh_data_free(ctx, &m);
}

/* Separating-axis triangle/box test (Akenine-Moeller 2001) for the unit box at (x, y, z); touching
 * counts as overlap. */
static bool tri_box(const double tv[3][3], int x, int y, int z)
{
    double c[3] = {x + 0.5, y + 0.5, z + 0.5}, v[3][3], e[3][3];
    for (int i = 0; i < 3; i++)
        for (int a = 0; a < 3; a++)
            v[i][a] = tv[i][a] - c[a];
    for (int i = 0; i < 3; i++)
        for (int a = 0; a < 3; a++)
            e[i][a] = v[(i + 1) % 3][a] - v[i][a];
    double axes[13][3];
    int n = 0;
    for (int a = 0; a < 3; a++) {
        axes[n][0] = axes[n][1] = axes[n][2] = 0;
        axes[n++][a] = 1;
    }
    axes[n][0] = e[0][1] * e[1][2] - e[0][2] * e[1][1];
    axes[n][1] = e[0][2] * e[1][0] - e[0][0] * e[1][2];
    axes[n][2] = e[0][0] * e[1][1] - e[0][1] * e[1][0];
    n++;
    for (int a = 0; a < 3; a++)
        for (int i = 0; i < 3; i++) {
            double u[3] = {0, 0, 0};
            u[a] = 1;
            axes[n][0] = u[1] * e[i][2] - u[2] * e[i][1];
            axes[n][1] = u[2] * e[i][0] - u[0] * e[i][2];
            axes[n][2] = u[0] * e[i][1] - u[1] * e[i][0];
            n++;
        }
    for (int k = 0; k < n; k++) {
        const double *ax = axes[k];
        double p0 = ax[0] * v[0][0] + ax[1] * v[0][1] + ax[2] * v[0][2];
        double p1 = ax[0] * v[1][0] + ax[1] * v[1][1] + ax[2] * v[1][2];
        double p2 = ax[0] * v[2][0] + ax[1] * v[2][1] + ax[2] * v[2][2];
        double mn = fmin(p0, fmin(p1, p2)), mx = fmax(p0, fmax(p1, p2));
        double r = 0.5 * (fabs(ax[0]) + fabs(ax[1]) + fabs(ax[2]));
        if (mn > r || mx < -r)
            return false;
    }
    return true;
}

static uint64_t rng_state = 0x9E3779B97F4A7C15ull;
static double rnd(void)
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return (double)(rng_state >> 11) / 9007199254740992.0;
}

static void test_conservative(nacre_context *ctx)
{
    enum { NT = 120 };
    for (int trial = 0; trial < 3; trial++) {
        float pos[NT * 9];
        uint32_t idx[NT * 3];
        for (int t = 0; t < NT; t++) {
            /* Sizes from a fraction of a voxel to a third of the grid (grid is ~16 voxels). */
            double size = t % 3 == 0 ? 0.03 : t % 3 == 1 ? 0.12 : 0.4;
            double c[3] = {rnd(), rnd(), rnd()};
            for (int k = 0; k < 3; k++) {
                for (int a = 0; a < 3; a++)
                    pos[9 * t + 3 * k + a] = (float)(c[a] + size * (rnd() - 0.5));
                idx[3 * t + k] = (uint32_t)(3 * t + k);
            }
        }
        nacre_mesh_data m = {0};
        m.vertex_count = NT * 3;
        m.triangle_count = NT;
        m.positions = pos;
        m.indices = idx;
        nacre_voxel_report rep;
        nacre_voxel_grid *g = vox(ctx, &m, 16 + 5 * (uint32_t)trial, trial == 1, NACRE_VOXEL_SOLID_ROBUST, &rep);
        if (!g)
            continue;
        const uint32_t *d = rep.dims;
        uint8_t *ref = calloc((size_t)d[0] * d[1] * d[2], 1);
        double inv_h = 1.0 / (double)rep.voxel_size;
        for (int t = 0; t < NT; t++) {
            double v[3][3];
            for (int k = 0; k < 3; k++)
                for (int a = 0; a < 3; a++)
                    v[k][a] = ((double)pos[9 * t + 3 * k + a] - (double)rep.origin[a]) * inv_h;
            for (uint32_t z = 0; z < d[2]; z++)
                for (uint32_t y = 0; y < d[1]; y++)
                    for (uint32_t x = 0; x < d[0]; x++)
                        if (tri_box((const double(*)[3])v, (int)x, (int)y, (int)z))
                            ref[x + d[0] * (y + (size_t)d[1] * z)] = 1;
        }
        uint64_t missed = 0, extra = 0, count = 0;
        for (uint32_t z = 0; z < d[2]; z++)
            for (uint32_t y = 0; y < d[1]; y++)
                for (uint32_t x = 0; x < d[0]; x++) {
                    bool got = nacre_voxel_grid_get(g, NACRE_VOXEL_SURFACE, 0, x, y, z);
                    bool want = ref[x + d[0] * (y + (size_t)d[1] * z)];
                    missed += want && !got;
                    extra += got && !want;
                    count += want;
                }
        CHECK(missed == 0);
        CHECK(extra == 0);
        CHECK(count == rep.surface_voxels);
        CHECK(count > 100);
        free(ref);
        nacre_voxel_grid_destroy(g);
    }
}

/* A random closed star-shaped mesh: an icosahedron subdivided `levels` times (shared vertices,
 * outward winding), each vertex pushed along its ray from the centre by a random factor in
 * [0.7, 1.3], then rotated at random and moved off the grid's symmetry. Every ray from the
 * centre crosses exactly one triangle (the one whose cone holds it), so the mesh is closed and
 * does not cross itself. pos/idx are malloc'ed; *centre is the transformed centre. */
static void star_mesh(int levels, nacre_mesh_data *m, double centre[3])
{
    static const double phi = 1.6180339887498949;
    double v0[12][3] = {{-1, phi, 0}, {1, phi, 0},  {-1, -phi, 0}, {1, -phi, 0}, {0, -1, phi}, {0, 1, phi},
                        {0, -1, -phi}, {0, 1, -phi}, {phi, 0, -1},  {phi, 0, 1},  {-phi, 0, -1}, {-phi, 0, 1}};
    static const uint32_t f0[20][3] = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                       {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                       {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                       {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
    uint32_t nv = 12, nt = 20, cap_v = 12, cap_t = 20;
    for (int l = 0; l < levels; l++)
        cap_v += cap_t * 3 / 2, cap_t *= 4;
    double(*v)[3] = malloc(sizeof(double[3]) * cap_v);
    uint32_t *t = malloc(sizeof(uint32_t) * 3 * cap_t), *t2 = malloc(sizeof(uint32_t) * 3 * cap_t);
    uint32_t(*edge)[3] = malloc(sizeof(uint32_t[3]) * cap_t * 3 / 2); /* hi, midpoint, next of the same lo */
    uint32_t *head = malloc(sizeof(uint32_t) * cap_v);                 /* first edge from each lo, or ~0 */
    memcpy(v, v0, sizeof(v0));
    memcpy(t, f0, sizeof(f0));
    for (uint32_t i = 0; i < nv; i++) {
        double r = sqrt(v[i][0] * v[i][0] + v[i][1] * v[i][1] + v[i][2] * v[i][2]);
        for (int a = 0; a < 3; a++)
            v[i][a] /= r;
    }
    for (int l = 0; l < levels; l++) {
        uint32_t ne = 0;
        memset(head, 0xFF, sizeof(uint32_t) * cap_v);
        for (uint32_t f = 0; f < nt; f++) {
            uint32_t mid[3];
            for (int k = 0; k < 3; k++) {
                uint32_t a = t[3 * f + k], b = t[3 * f + (k + 1) % 3], lo = a < b ? a : b, hi = a < b ? b : a, e;
                for (e = head[lo]; e != ~0u && edge[e][0] != hi; e = edge[e][2])
                    ;
                if (e == ~0u) {
                    double r = 0;
                    for (int c = 0; c < 3; c++) {
                        v[nv][c] = v[a][c] + v[b][c];
                        r += v[nv][c] * v[nv][c];
                    }
                    for (int c = 0; c < 3; c++)
                        v[nv][c] /= sqrt(r);
                    edge[ne][0] = hi, edge[ne][1] = nv++, edge[ne][2] = head[lo];
                    head[lo] = e = ne++;
                }
                mid[k] = edge[e][1];
            }
            const uint32_t *c = t + 3 * f;
            uint32_t q[4][3] = {{c[0], mid[0], mid[2]}, {mid[0], c[1], mid[1]}, {mid[2], mid[1], c[2]}, {mid[0], mid[1], mid[2]}};
            memcpy(t2 + 12 * f, q, sizeof(q));
        }
        uint32_t *sw = t;
        t = t2, t2 = sw;
        nt *= 4;
    }
    /* Random rotation (three angles), radius, displacement and offset. */
    double ang[3] = {6.2831853 * rnd(), 6.2831853 * rnd(), 6.2831853 * rnd()};
    double off[3] = {rnd() - 0.5, rnd() - 0.5, rnd() - 0.5}, scale = 0.5 + rnd();
    m->vertex_count = nv;
    m->triangle_count = nt;
    m->positions = malloc(sizeof(float) * 3 * nv);
    m->indices = t;
    for (uint32_t i = 0; i < nv; i++) {
        double f = scale * (0.7 + 0.6 * rnd()), p[3] = {v[i][0] * f, v[i][1] * f, v[i][2] * f};
        for (int k = 0; k < 3; k++) {
            int a = k, b = (k + 1) % 3;
            double ca = cos(ang[k]), sa = sin(ang[k]), pa = p[a], pb = p[b];
            p[a] = ca * pa - sa * pb;
            p[b] = sa * pa + ca * pb;
        }
        for (int a = 0; a < 3; a++)
            m->positions[3 * i + (uint32_t)a] = (float)(p[a] + off[a]);
    }
    for (int a = 0; a < 3; a++)
        centre[a] = off[a]; /* rotation keeps the origin, the float rounding moves it by 1e-7 */
    free(v);
    free(t2);
    free(edge);
    free(head);
}

/* Whether p is inside a star-shaped mesh around `centre`: the triangle whose cone (from the
 * centre) holds p writes p - centre = a v0 + b v1 + c v2 (vertices relative to the centre) with
 * a, b, c >= 0, and p is inside when a + b + c < 1. inv holds the inverse 3x3 matrix per triangle
 * (row-major). Independent of the voxelizer: no ray casting, no parity. The search starts at
 * *hint, the previous answer (neighbouring voxels mostly share a cone). */
static bool star_inside(const double *inv, uint32_t nt, const double centre[3], const double p[3], uint32_t *hint,
                        double *sum)
{
    double d[3] = {p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]};
    for (uint32_t i = 0; i < nt; i++) {
        uint32_t t = (*hint + i) % nt;
        const double *m = inv + 9 * t;
        double w[3];
        for (int k = 0; k < 3; k++)
            w[k] = m[3 * k] * d[0] + m[3 * k + 1] * d[1] + m[3 * k + 2] * d[2];
        if (w[0] >= -1e-12 && w[1] >= -1e-12 && w[2] >= -1e-12) {
            *hint = t;
            *sum = w[0] + w[1] + w[2];
            return *sum < 1;
        }
    }
    *sum = -1; /* no cone: cannot happen for a star-shaped mesh */
    return false;
}

/* Issue 3's conservativeness on random closed meshes: the surface set equals the brute-force
 * triangle/box set (no miss, no extra), at several resolutions, cubic and anisotropic, through
 * the vectorised paths (one-voxel, flat 2 x 2, 2 x 2 x 2 and general bounds) and, with 5120
 * triangles, the threaded pass with per-thread copies. The solid set is the same under PARITY
 * and ROBUST (the mesh is closed), and every voxel off the surface is solid exactly when its
 * centre is inside by star_inside. */
static void test_conservative_closed(nacre_context *ctx)
{
    static const struct {
        int levels;
        uint32_t res;
        bool aniso;
    } trials[] = {{2, 13, false}, {2, 24, true}, {3, 31, false}, {2, 40, true}, {4, 29, false}, {3, 9, true}};
    for (size_t k = 0; k < sizeof(trials) / sizeof(trials[0]); k++) {
        nacre_mesh_data m = {0};
        double centre[3];
        star_mesh(trials[k].levels, &m, centre);
        nacre_voxel_report rp, rr;
        nacre_voxel_grid *gp = vox(ctx, &m, trials[k].res, trials[k].aniso, NACRE_VOXEL_SOLID_PARITY, &rp);
        nacre_voxel_grid *gr = vox(ctx, &m, trials[k].res, trials[k].aniso, NACRE_VOXEL_SOLID_ROBUST, &rr);
        nacre_voxel_report ra;
        nacre_voxel_grid *ga = vox(ctx, &m, trials[k].res, trials[k].aniso, NACRE_VOXEL_SOLID_AUTO, &ra);
        CHECK(ra.closed); /* the mesh really is closed */
        nacre_voxel_grid_destroy(ga);
        if (!gp || !gr) {
            nacre_voxel_grid_destroy(gp);
            nacre_voxel_grid_destroy(gr);
            free(m.positions);
            free(m.indices);
            continue;
        }
        const uint32_t *d = rp.dims;
        const size_t n = (size_t)d[0] * d[1] * d[2];
        uint8_t *ref = calloc(n, 1);
        double inv_h = 1.0 / (double)rp.voxel_size, *inv = malloc(sizeof(double) * 9 * m.triangle_count);
        for (uint32_t t = 0; t < m.triangle_count; t++) {
            double v[3][3], lo[3], hi[3], q[3][3];
            for (int c = 0; c < 3; c++)
                for (int a = 0; a < 3; a++) {
                    double p = m.positions[3 * m.indices[3 * t + (uint32_t)c] + (uint32_t)a];
                    v[c][a] = (p - (double)rp.origin[a]) * inv_h;
                    q[a][c] = p - centre[a]; /* columns: corners relative to the centre */
                }
            /* Boxes [x, x + 1] that can touch [min, max]; the comparison below covers the whole
             * grid, so a voxel set outside these bounds still counts as extra. */
            for (int a = 0; a < 3; a++) {
                lo[a] = fmax(0, ceil(fmin(v[0][a], fmin(v[1][a], v[2][a]))) - 1);
                hi[a] = fmin(d[a] - 1.0, floor(fmax(v[0][a], fmax(v[1][a], v[2][a]))));
            }
            for (int z = (int)lo[2]; z <= (int)hi[2]; z++)
                for (int y = (int)lo[1]; y <= (int)hi[1]; y++)
                    for (int x = (int)lo[0]; x <= (int)hi[0]; x++)
                        if (tri_box((const double(*)[3])v, x, y, z))
                            ref[(size_t)x + d[0] * ((size_t)y + (size_t)d[1] * (size_t)z)] = 1;
            /* Inverse of q by cofactors. */
            double *o = inv + 9 * t;
            double det = q[0][0] * (q[1][1] * q[2][2] - q[1][2] * q[2][1]) -
                         q[0][1] * (q[1][0] * q[2][2] - q[1][2] * q[2][0]) +
                         q[0][2] * (q[1][0] * q[2][1] - q[1][1] * q[2][0]);
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) {
                    int i1 = (i + 1) % 3, i2 = (i + 2) % 3, j1 = (j + 1) % 3, j2 = (j + 2) % 3;
                    o[3 * i + j] = (q[j1][i1] * q[j2][i2] - q[j1][i2] * q[j2][i1]) / det;
                }
        }
        uint64_t missed = 0, extra = 0, count = 0, solid_diff = 0, wrong_inside = 0, checked = 0, inside = 0;
        uint32_t hint = 0;
        for (uint32_t z = 0; z < d[2]; z++)
            for (uint32_t y = 0; y < d[1]; y++)
                for (uint32_t x = 0; x < d[0]; x++) {
                    bool got = nacre_voxel_grid_get(gp, NACRE_VOXEL_SURFACE, 0, x, y, z);
                    bool want = ref[x + d[0] * (y + (size_t)d[1] * z)];
                    missed += want && !got;
                    extra += got && !want;
                    count += want;
                    bool sp = nacre_voxel_grid_get(gp, NACRE_VOXEL_SOLID, 0, x, y, z);
                    solid_diff += sp != nacre_voxel_grid_get(gr, NACRE_VOXEL_SOLID, 0, x, y, z);
                    solid_diff += got != nacre_voxel_grid_get(gr, NACRE_VOXEL_SURFACE, 0, x, y, z);
                    if (want)
                        continue; /* the centre may lie on the surface: either answer is right */
                    if (m.triangle_count > 400 && (x + y + z) % 4)
                        continue; /* star_inside scans the triangles: a quarter of the voxels will do */
                    double c[3] = {rp.origin[0] + (x + 0.5) * (double)rp.voxel_size,
                                   rp.origin[1] + (y + 0.5) * (double)rp.voxel_size,
                                   rp.origin[2] + (z + 0.5) * (double)rp.voxel_size},
                           sum;
                    bool in = star_inside(inv, m.triangle_count, centre, c, &hint, &sum);
                    wrong_inside += in != sp || sum < 0;
                    checked++;
                    inside += in;
                }
        if (missed || extra || solid_diff || wrong_inside)
            printf("closed trial %zu (%u tris, res %u%s): missed %llu extra %llu solid diff %llu wrong inside %llu\n", k,
                   m.triangle_count, trials[k].res, trials[k].aniso ? " aniso" : "", (unsigned long long)missed,
                   (unsigned long long)extra, (unsigned long long)solid_diff, (unsigned long long)wrong_inside);
        CHECK(missed == 0);
        CHECK(extra == 0);
        CHECK(count == rp.surface_voxels && count == rr.surface_voxels);
        CHECK(count > 50);
        CHECK(solid_diff == 0);
        CHECK(wrong_inside == 0);
        CHECK(inside > 0 && checked > inside); /* both sides of the surface were tested */
        free(ref);
        free(inv);
        nacre_voxel_grid_destroy(gp);
        nacre_voxel_grid_destroy(gr);
        free(m.positions);
        free(m.indices);
    }
}

/* Live bytes through the context's allocator (a size header in front of each block). */
static int64_t alloc_live, alloc_peak;
static void *count_alloc(size_t size, void *user)
{
    (void)user;
    uint64_t *p = malloc(size + 16);
    if (!p)
        return NULL;
    p[0] = size;
    int64_t live = __atomic_add_fetch(&alloc_live, (int64_t)size, __ATOMIC_RELAXED);
    if (live > alloc_peak)
        alloc_peak = live; /* allocations here are serial */
    return p + 2;
}
static void count_free(void *ptr, void *user)
{
    (void)user;
    if (!ptr)
        return;
    uint64_t *p = (uint64_t *)ptr - 2;
    __atomic_sub_fetch(&alloc_live, (int64_t)p[0], __ATOMIC_RELAXED);
    free(p);
}

/* The issue asks for any dimensions up to at least 512^3: a sphere at 512 has 512 voxels per side,
 * a solid count within the volume bound, levels 512, 256, ..., 4, coarse voxels set exactly
 * when a child is (spot checks, around the surface and at random), and all memory back after
 * destroy (about 37 MiB: two sets of 16 MiB at level 0 and the pyramid). */
static void test_512(void)
{
    nacre_context_desc cd = {0};
    cd.allocator.alloc_fn = count_alloc;
    cd.allocator.free_fn = count_free;
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(&cd, &ctx) == NACRE_OK);
    if (!ctx)
        return;
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
    sd.segments = 48;
    sd.rings = 24;
    nacre_mesh_data m = {0};
    CHECK(nacre_mesh_make_shape(ctx, &sd, &m) == NACRE_OK);
    int64_t before = alloc_live;
    alloc_peak = before;
    nacre_voxel_report rep;
    nacre_voxel_grid *g = vox(ctx, &m, 512, false, NACRE_VOXEL_SOLID_AUTO, &rep);
    if (g) {
        CHECK(rep.dims[0] == 512 && rep.dims[1] == 512 && rep.dims[2] == 512);
        CHECK(rep.closed);
        double h3 = (double)rep.voxel_size * rep.voxel_size * rep.voxel_size;
        CHECK_NEAR((double)rep.solid_voxels * h3, mesh_volume(&m), (double)rep.surface_voxels * h3);
        CHECK(rep.solid_voxels > 60000000); /* about pi / 6 of 512^3 */
        CHECK(nacre_voxel_grid_count(g, NACRE_VOXEL_SURFACE, 0) == rep.surface_voxels);
        CHECK(rep.levels == 8);
        CHECK(nacre_voxel_grid_levels(g) == 8);
        for (uint32_t l = 0; l < 8; l++) {
            uint32_t dl[3];
            CHECK(nacre_voxel_grid_dims(g, l, dl) && dl[0] == 512u >> l && dl[1] == 512u >> l && dl[2] == 512u >> l);
        }
        uint64_t bad = 0, active = 0, samples = 0;
        for (uint32_t l = 1; l < 8; l++) {
            uint32_t n = 512u >> l;
            for (int i = 0; i < 6000; i++) {
                uint32_t x, y, z;
                if (i % 2) { /* near the sphere (radius n / 2 around the centre) */
                    double u = 2 * rnd() - 1, phi = 6.2831853 * rnd(), r = 0.5 * n * (0.97 + 0.06 * rnd());
                    double s = sqrt(1 - u * u);
                    x = (uint32_t)fmin(n - 1, fmax(0, 0.5 * n + r * s * cos(phi)));
                    y = (uint32_t)fmin(n - 1, fmax(0, 0.5 * n + r * s * sin(phi)));
                    z = (uint32_t)fmin(n - 1, fmax(0, 0.5 * n + r * u));
                } else {
                    x = (uint32_t)(rnd() * n), y = (uint32_t)(rnd() * n), z = (uint32_t)(rnd() * n);
                }
                for (int set = 0; set < 2; set++) {
                    bool any = false;
                    for (uint32_t c = 0; c < 8; c++)
                        any = any || nacre_voxel_grid_get(g, (nacre_voxel_set)set, l - 1, 2 * x + (c & 1),
                                                          2 * y + ((c >> 1) & 1), 2 * z + (c >> 2));
                    bool got = nacre_voxel_grid_get(g, (nacre_voxel_set)set, l, x, y, z);
                    bad += any != got;
                    active += got;
                    samples++;
                }
            }
        }
        CHECK(bad == 0);
        CHECK(active > samples / 4 && active < samples); /* the samples saw both answers */
        /* The last corner voxel exists, one past it does not. */
        CHECK(!nacre_voxel_grid_get(g, NACRE_VOXEL_SOLID, 0, 511, 511, 511));
        CHECK(nacre_voxel_grid_get(g, NACRE_VOXEL_SOLID, 0, 256, 256, 256));
        CHECK(!nacre_voxel_grid_get(g, NACRE_VOXEL_SOLID, 0, 512, 256, 256));
        CHECK(alloc_peak - before < 96ll << 20);
    }
    nacre_voxel_grid_destroy(g);
    CHECK(alloc_live == before);
    nacre_mesh_data_free(ctx, &m);
    nacre_context_destroy(ctx);
}

static void test_aligned_cube(nacre_context *ctx)
{
    for (uint32_t seg = 1; seg <= 4; seg *= 4) {
        nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_BOX);
        sd.segments = seg;
        nacre_mesh_data m = {0};
        CHECK(nacre_mesh_make_shape(ctx, &sd, &m) == NACRE_OK);
        for (uint32_t n = 4; n <= 16; n += 12) {
            nacre_voxel_report rep;
            nacre_voxel_grid *g = vox(ctx, &m, n, false, NACRE_VOXEL_SOLID_AUTO, &rep);
            CHECK(rep.solid_voxels == (uint64_t)n * n * n);
            CHECK(rep.surface_voxels == (uint64_t)n * n * n - (uint64_t)(n - 2) * (n - 2) * (n - 2));
            CHECK_NEAR(rep.voxel_size, 1.0 / n, 1e-7);
            CHECK_NEAR(rep.origin[0], -0.5, 1e-7);
            nacre_voxel_grid_destroy(g);
        }
        nacre_mesh_data_free(ctx, &m);
    }
    /* Anisotropic: a 2 x 1 x 0.5 box at 8 gives 8 x 4 x 2, all solid. */
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_BOX);
    sd.size[0] = 2, sd.size[1] = 1, sd.size[2] = 0.5f;
    nacre_mesh_data m = {0};
    CHECK(nacre_mesh_make_shape(ctx, &sd, &m) == NACRE_OK);
    nacre_voxel_report rep;
    nacre_voxel_grid *g = vox(ctx, &m, 8, true, NACRE_VOXEL_SOLID_AUTO, &rep);
    CHECK(rep.dims[0] == 8 && rep.dims[1] == 4 && rep.dims[2] == 2);
    CHECK(rep.solid_voxels == 64);
    CHECK(rep.levels == 1);
    nacre_voxel_grid_destroy(g);
    /* Cubic grid: the box is centred, 8 x 4 x 2 solid inside 8^3. */
    g = vox(ctx, &m, 8, false, NACRE_VOXEL_SOLID_AUTO, &rep);
    CHECK(rep.solid_voxels == 64);
    CHECK(nacre_voxel_grid_get(g, NACRE_VOXEL_SOLID, 0, 0, 2, 3));
    CHECK(!nacre_voxel_grid_get(g, NACRE_VOXEL_SOLID, 0, 0, 1, 3));
    nacre_voxel_grid_destroy(g);
    nacre_mesh_data_free(ctx, &m);
}

/* Unpacking a whole set gives what voxel-by-voxel queries give, on a grid taller than 64 (more
 * than one word per column) and on a coarse level. */
static void test_unpack(nacre_context *ctx)
{
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_TORUS);
    nacre_mesh_data m = {0};
    CHECK(nacre_mesh_make_shape(ctx, &sd, &m) == NACRE_OK);
    nacre_voxel_report rep;
    nacre_voxel_grid *g = vox(ctx, &m, 70, false, NACRE_VOXEL_SOLID_AUTO, &rep);
    for (uint32_t level = 0; level < 2; level++)
        for (int set = 0; set < 2; set++) {
            uint32_t d[3];
            CHECK(nacre_voxel_grid_dims(g, level, d));
            uint8_t *out = malloc((size_t)d[0] * d[1] * d[2]);
            CHECK(nacre_voxel_grid_unpack(g, (nacre_voxel_set)set, level, out));
            size_t bad = 0, ones = 0;
            for (uint32_t z = 0; z < d[2]; z++)
                for (uint32_t y = 0; y < d[1]; y++)
                    for (uint32_t x = 0; x < d[0]; x++) {
                        uint8_t v = out[x + (size_t)d[0] * (y + (size_t)d[1] * z)];
                        bad += v != (uint8_t)nacre_voxel_grid_get(g, (nacre_voxel_set)set, level, x, y, z);
                        ones += v;
                    }
            CHECK(bad == 0);
            CHECK(ones == nacre_voxel_grid_count(g, (nacre_voxel_set)set, level));
            free(out);
        }
    uint8_t one;
    CHECK(!nacre_voxel_grid_unpack(g, NACRE_VOXEL_SOLID, 99, &one));
    nacre_voxel_grid_destroy(g);
    nacre_mesh_data_free(ctx, &m);
}

static void rotate(nacre_mesh_data *m)
{
    const double a = 0.37, b = 0.61;
    for (uint32_t i = 0; i < m->vertex_count; i++) {
        float *p = m->positions + 3 * i;
        double x = p[0], y = p[1], z = p[2];
        double x1 = cos(a) * x - sin(a) * y, y1 = sin(a) * x + cos(a) * y;
        double y2 = cos(b) * y1 - sin(b) * z, z2 = sin(b) * y1 + cos(b) * z;
        p[0] = (float)x1, p[1] = (float)y2, p[2] = (float)z2;
    }
}

static void test_shared_edges(nacre_context *ctx)
{
    for (int rot = 0; rot < 2; rot++) {
        nacre_mesh_data few = {0}, many = {0};
        nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_BOX);
        sd.size[0] = 1.0f, sd.size[1] = 0.73f, sd.size[2] = 0.41f;
        sd.segments = 1;
        CHECK(nacre_mesh_make_shape(ctx, &sd, &few) == NACRE_OK);
        sd.segments = 16;
        CHECK(nacre_mesh_make_shape(ctx, &sd, &many) == NACRE_OK);
        if (rot) {
            rotate(&few);
            rotate(&many);
        }
        nacre_voxel_report r1, r2;
        nacre_voxel_grid *g1 = vox(ctx, &few, 37, rot == 0, NACRE_VOXEL_SOLID_PARITY, &r1);
        nacre_voxel_grid *g2 = vox(ctx, &many, 37, rot == 0, NACRE_VOXEL_SOLID_PARITY, &r2);
        uint64_t diff = 1;
        CHECK(same_set(g1, g2, NACRE_VOXEL_SOLID, &diff));
        CHECK(diff == 0);
        CHECK(r1.solid_voxels > 1000);
        double h3 = (double)r1.voxel_size * r1.voxel_size * r1.voxel_size;
        CHECK_NEAR((double)r1.solid_voxels * h3, mesh_volume(&few), (double)r1.surface_voxels * h3);
        nacre_voxel_grid_destroy(g1);
        nacre_voxel_grid_destroy(g2);
        nacre_mesh_data_free(ctx, &few);
        nacre_mesh_data_free(ctx, &many);
    }
}

static void test_broken(nacre_context *ctx)
{
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
    nacre_mesh_data m = {0};
    CHECK(nacre_mesh_make_shape(ctx, &sd, &m) == NACRE_OK);
    nacre_voxel_report ref;
    nacre_voxel_grid *g = vox(ctx, &m, 48, false, NACRE_VOXEL_SOLID_AUTO, &ref);
    nacre_voxel_grid_destroy(g);
    CHECK(ref.closed);

    /* Hole: drop a patch of triangles near the equator on +x (and one near the top). */
    nacre_mesh_data holed = m;
    uint32_t *idx = malloc(sizeof(uint32_t) * 3 * m.triangle_count);
    uint32_t n = 0;
    for (uint32_t t = 0; t < m.triangle_count; t++) {
        const float *p = m.positions + 3 * m.indices[3 * t];
        bool drop = (p[0] > 0.9f && fabsf(p[1]) < 0.25f && fabsf(p[2]) < 0.3f) || (p[1] > 0.97f);
        if (!drop) {
            memcpy(idx + 3 * n, m.indices + 3 * t, 3 * sizeof(uint32_t));
            n++;
        }
    }
    CHECK(n < m.triangle_count - 20);
    holed.indices = idx;
    holed.triangle_count = n;
    nacre_voxel_report rep;
    g = vox(ctx, &holed, 48, false, NACRE_VOXEL_SOLID_AUTO, &rep);
    CHECK(!rep.closed);
    CHECK(rep.rule_used == NACRE_VOXEL_SOLID_ROBUST);
    CHECK_NEAR((double)rep.solid_voxels, (double)ref.solid_voxels, 0.01 * ref.solid_voxels);
    nacre_voxel_grid_destroy(g);
    free(idx);

    /* Duplicated flipped patch: 60 triangles repeated with reversed winding. */
    nacre_mesh_data dup = m;
    idx = malloc(sizeof(uint32_t) * 3 * (m.triangle_count + 60));
    memcpy(idx, m.indices, sizeof(uint32_t) * 3 * m.triangle_count);
    for (uint32_t k = 0; k < 60; k++) {
        const uint32_t *s = m.indices + 3 * (500 + k);
        uint32_t *o = idx + 3 * (m.triangle_count + k);
        o[0] = s[0], o[1] = s[2], o[2] = s[1];
    }
    dup.indices = idx;
    dup.triangle_count = m.triangle_count + 60;
    g = vox(ctx, &dup, 48, false, NACRE_VOXEL_SOLID_AUTO, &rep);
    CHECK(!rep.closed);
    CHECK_NEAR((double)rep.solid_voxels, (double)ref.solid_voxels, 0.01 * ref.solid_voxels);
    nacre_voxel_grid_destroy(g);
    free(idx);
    nacre_mesh_data_free(ctx, &m);
}

static void test_bad_input(nacre_context *ctx)
{
    nacre_voxel_grid *g = NULL;
    nacre_voxel_report rep;
    nacre_mesh_data empty = {0};
    CHECK(nacre_voxelize(ctx, &empty, NULL, &g, &rep) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(g == NULL);
    CHECK(nacre_voxelize(ctx, NULL, NULL, &g, &rep) == NACRE_ERROR_INVALID_ARGUMENT);

    /* A box plus a degenerate triangle and a triangle with a NaN vertex. */
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_BOX);
    nacre_mesh_data box = {0};
    CHECK(nacre_mesh_make_shape(ctx, &sd, &box) == NACRE_OK);
    uint32_t nv = box.vertex_count, nt = box.triangle_count;
    float *pos = malloc(sizeof(float) * 3 * (nv + 1));
    uint32_t *idx = malloc(sizeof(uint32_t) * 3 * (nt + 2));
    memcpy(pos, box.positions, sizeof(float) * 3 * nv);
    memcpy(idx, box.indices, sizeof(uint32_t) * 3 * nt);
    pos[3 * nv] = NAN, pos[3 * nv + 1] = 0, pos[3 * nv + 2] = 0;
    idx[3 * nt] = 0, idx[3 * nt + 1] = 1, idx[3 * nt + 2] = 1;
    idx[3 * nt + 3] = 0, idx[3 * nt + 4] = 1, idx[3 * nt + 5] = nv;
    nacre_mesh_data m = {0};
    m.vertex_count = nv + 1;
    m.triangle_count = nt + 2;
    m.positions = pos;
    m.indices = idx;
    g = vox(ctx, &m, 8, false, NACRE_VOXEL_SOLID_AUTO, &rep);
    CHECK(rep.skipped_degenerate == 1);
    CHECK(rep.skipped_nonfinite == 1);
    CHECK(rep.solid_voxels == 512);
    CHECK(!rep.closed); /* non-finite input: not analysed, robust rule */
    nacre_voxel_grid_destroy(g);

    /* Only bad triangles: clean error. */
    m.indices = idx + 3 * nt;
    m.triangle_count = 2;
    g = NULL;
    CHECK(nacre_voxelize(ctx, &m, NULL, &g, &rep) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(g == NULL);
    CHECK(strstr(nacre_context_last_error(ctx), "voxelize") != NULL);
    /* Out-of-range index. */
    idx[3 * nt + 5] = nv + 7;
    CHECK(nacre_voxelize(ctx, &m, NULL, &g, &rep) == NACRE_ERROR_INVALID_ARGUMENT);
    /* Bad resolution. */
    nacre_voxel_settings s = nacre_voxel_settings_defaults();
    s.resolution = 100000;
    CHECK(nacre_voxelize(ctx, &box, &s, &g, &rep) == NACRE_ERROR_INVALID_ARGUMENT);
    free(pos);
    free(idx);
    nacre_mesh_data_free(ctx, &box);
}

static void test_pyramid(nacre_context *ctx)
{
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_TORUS);
    nacre_mesh_data m = {0};
    CHECK(nacre_mesh_make_shape(ctx, &sd, &m) == NACRE_OK);
    nacre_voxel_report rep;
    nacre_voxel_grid *g = vox(ctx, &m, 70, true, NACRE_VOXEL_SOLID_AUTO, &rep);
    /* Torus 2.5 x 0.5 x 2.5: dims 70 x 14 x 70 -> 35 x 7 x 35 -> 18 x 4 x 18, then stop. */
    CHECK(rep.dims[1] == 14);
    CHECK(nacre_voxel_grid_levels(g) == 3);
    uint32_t d[3];
    CHECK(nacre_voxel_grid_dims(g, 2, d) && d[0] == 18 && d[1] == 4 && d[2] == 18);
    CHECK(!nacre_voxel_grid_dims(g, 3, d));
    uint64_t bad = 0;
    for (uint32_t l = 1; l < nacre_voxel_grid_levels(g); l++) {
        uint32_t dc[3];
        nacre_voxel_grid_dims(g, l, dc);
        for (int set = 0; set < 2; set++)
            for (uint32_t z = 0; z < dc[2]; z++)
                for (uint32_t y = 0; y < dc[1]; y++)
                    for (uint32_t x = 0; x < dc[0]; x++) {
                        bool any = false;
                        for (uint32_t c = 0; c < 8; c++)
                            any = any || nacre_voxel_grid_get(g, (nacre_voxel_set)set, l - 1, 2 * x + (c & 1),
                                                              2 * y + ((c >> 1) & 1), 2 * z + (c >> 2));
                        bad += any != nacre_voxel_grid_get(g, (nacre_voxel_set)set, l, x, y, z);
                    }
    }
    CHECK(bad == 0);
    CHECK(nacre_voxel_grid_count(g, NACRE_VOXEL_SOLID, 1) > 0);
    /* A 28^3 grid has 28, 14, 7, 4. */
    nacre_voxel_grid_destroy(g);
    g = vox(ctx, &m, 28, false, NACRE_VOXEL_SOLID_AUTO, &rep);
    CHECK(rep.levels == 4);
    nacre_voxel_grid_destroy(g);
    nacre_mesh_data_free(ctx, &m);
}

static void test_threads(void)
{
    nacre_context *c1 = ctx_threads(1), *c2 = ctx_threads(2);
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_TORUS);
    sd.segments = 128;
    sd.rings = 64; /* > the parallel threshold */
    nacre_mesh_data m = {0};
    CHECK(nacre_mesh_make_shape(c1, &sd, &m) == NACRE_OK);
    rotate(&m);
    nacre_voxel_report r1, r2;
    nacre_voxel_grid *g1 = vox(c1, &m, 64, true, NACRE_VOXEL_SOLID_ROBUST, &r1);
    nacre_voxel_grid *g2 = vox(c2, &m, 64, true, NACRE_VOXEL_SOLID_ROBUST, &r2);
    uint64_t diff = 1;
    CHECK(same_set(g1, g2, NACRE_VOXEL_SOLID, &diff));
    CHECK(same_set(g1, g2, NACRE_VOXEL_SURFACE, &diff));
    nacre_voxel_grid_destroy(g1);
    nacre_voxel_grid_destroy(g2);
    nacre_mesh_data_free(c1, &m);
    nacre_context_destroy(c1);
    nacre_context_destroy(c2);
}

static void test_rest(nacre_context *ctx)
{
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
    sd.segments = 24;
    sd.rings = 12;
    nacre_mesh_data rest = {0}, def = {0};
    CHECK(nacre_mesh_make_shape(ctx, &sd, &rest) == NACRE_OK);
    CHECK(nacre_mesh_make_shape(ctx, &sd, &def) == NACRE_OK);
    const float t[3] = {0.3f, -0.2f, 0.1f};
    for (uint32_t i = 0; i < def.vertex_count; i++)
        for (int a = 0; a < 3; a++)
            def.positions[3 * i + (uint32_t)a] += t[a];
    nacre_voxel_report rep;
    nacre_voxel_grid *g = vox(ctx, &def, 20, false, NACRE_VOXEL_SOLID_AUTO, &rep);
    size_t nvox = (size_t)rep.dims[0] * rep.dims[1] * rep.dims[2];
    float *out = malloc(sizeof(float) * 3 * nvox);
    CHECK(nacre_voxel_grid_rest_positions(g, &rest, &def, out) == NACRE_OK);
    double h = rep.voxel_size, worst = 0;
    uint64_t filled = 0, unset_ok = 0, unset = 0;
    for (uint32_t z = 0; z < rep.dims[2]; z++)
        for (uint32_t y = 0; y < rep.dims[1]; y++)
            for (uint32_t x = 0; x < rep.dims[0]; x++) {
                size_t i = x + rep.dims[0] * (y + (size_t)rep.dims[1] * z);
                bool in = nacre_voxel_grid_get(g, NACRE_VOXEL_SOLID, 0, x, y, z) ||
                          nacre_voxel_grid_get(g, NACRE_VOXEL_SURFACE, 0, x, y, z);
                if (!in) {
                    unset++;
                    unset_ok += isnan(out[3 * i]);
                    continue;
                }
                filled++;
                double c[3] = {rep.origin[0] + (x + 0.5) * h, rep.origin[1] + (y + 0.5) * h,
                               rep.origin[2] + (z + 0.5) * h};
                for (int a = 0; a < 3; a++)
                    worst = fmax(worst, fabs(out[3 * i + (size_t)a] - (c[a] - t[a])));
            }
    CHECK(filled > 1000);
    CHECK(unset_ok == unset);
    /* Translation: interior voxels exact; surface voxels hold the closest surface point, at most
     * half a voxel diagonal from the centre. */
    CHECK(worst <= 0.87 * h);
    free(out);
    nacre_voxel_grid_destroy(g);
    nacre_mesh_data_free(ctx, &rest);
    nacre_mesh_data_free(ctx, &def);
}

static int run(const char *cmd)
{
    int st = system(cmd);
    return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

static void test_cli(void)
{
    const char *obj = NACRE_TEST_TMP "/vox_cube.obj";
    FILE *f = fopen(obj, "w");
    CHECK(f != NULL);
    if (!f)
        return;
    fprintf(f, "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
               "f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n");
    fclose(f);
    const char *json = NACRE_TEST_TMP "/vox_cube.json", *nrrd = NACRE_TEST_TMP "/vox_cube.nrrd";
    char cmd[1024];
    remove(nrrd);
    snprintf(cmd, sizeof(cmd), "\"%s\" voxelize \"%s\" --res 8 --json -o \"%s\" > \"%s\"", NACRE_CLI, obj, nrrd, json);
    CHECK(run(cmd) == 0);
    char buf[2048] = {0};
    f = fopen(json, "r");
    if (f) {
        size_t n = fread(buf, 1, sizeof(buf) - 1, f);
        buf[n] = 0;
        fclose(f);
    }
    CHECK(strstr(buf, "\"dims\":[8,8,8]") != NULL);
    CHECK(strstr(buf, "\"solid_voxels\":512") != NULL);
    CHECK(strstr(buf, "\"surface_voxels\":296") != NULL);
    CHECK(strstr(buf, "\"closed\":true") != NULL);
    CHECK(strstr(buf, "\"voxel_size\":0.125") != NULL);
    CHECK(strstr(buf, "\"ms\":") != NULL);
    f = fopen(nrrd, "rb");
    CHECK(f != NULL);
    if (f) {
        char head[9] = {0};
        CHECK(fread(head, 1, 8, f) == 8);
        CHECK(strcmp(head, "NRRD0004") == 0);
        fseek(f, 0, SEEK_END);
        long size = ftell(f);
        fclose(f);
        CHECK(size > 2 * 512 && size < 2 * 512 + 1024);
    }
    snprintf(cmd, sizeof(cmd), "\"%s\" voxelize \"%s\" --res 0 2>/dev/null", NACRE_CLI, obj);
    CHECK(run(cmd) == 2);
    snprintf(cmd, sizeof(cmd), "\"%s\" voxelize \"%s/nope.obj\" --json 2>/dev/null", NACRE_CLI, NACRE_TEST_TMP);
    CHECK(run(cmd) == 2);
    snprintf(cmd, sizeof(cmd), "\"%s\" voxelize 2>/dev/null", NACRE_CLI);
    CHECK(run(cmd) == 2);
    snprintf(cmd, sizeof(cmd), "\"%s\" voxelize \"%s\" --bogus 2>/dev/null", NACRE_CLI, obj);
    CHECK(run(cmd) == 2);
}

/* The vectorised block path (all vertices finite) against the per-triangle path (forced by an
 * unreferenced NaN vertex, which changes neither the bounds nor any triangle): same bits and
 * the same degenerate count, with zero-area triangles and a triangle count that is not a
 * multiple of the block size, for both solid rules. */
static void test_block_path(nacre_context *ctx)
{
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
    sd.segments = 96;
    sd.rings = 61;
    nacre_mesh_data m = {0};
    CHECK(nacre_mesh_make_shape(ctx, &sd, &m) == NACRE_OK);
    uint32_t nt = m.triangle_count, extra = nt / 7 + 3;
    nacre_mesh_data a = {0};
    a.vertex_count = m.vertex_count;
    a.triangle_count = nt + extra;
    a.positions = malloc(sizeof(float) * 3 * (m.vertex_count + 1));
    a.indices = malloc(sizeof(uint32_t) * 3 * (nt + extra));
    memcpy(a.positions, m.positions, sizeof(float) * 3 * m.vertex_count);
    uint32_t k = 0, e = 0;
    for (uint32_t t = 0; t < nt; t++) {
        memcpy(a.indices + 3 * k++, m.indices + 3 * t, sizeof(uint32_t) * 3);
        if (t % 7 == 3 && e < extra) { /* zero area: repeated vertex */
            uint32_t i0 = m.indices[3 * t], i1 = m.indices[3 * t + 1];
            a.indices[3 * k] = i0, a.indices[3 * k + 1] = i1, a.indices[3 * k + 2] = i0;
            k++, e++;
        }
    }
    while (e < extra) {
        a.indices[3 * k] = a.indices[3 * k + 1] = a.indices[3 * k + 2] = 0;
        k++, e++;
    }
    CHECK(k == nt + extra);
    nacre_mesh_data b = a;
    b.vertex_count = m.vertex_count + 1;
    a.positions[3 * m.vertex_count] = NAN;
    a.positions[3 * m.vertex_count + 1] = 0;
    a.positions[3 * m.vertex_count + 2] = 0;
    /* ROBUST too: its x and y parities have their own vectorised path. */
    static const uint32_t resolutions[5] = {4, 9, 19, 39, 79};
    for (int i = 0; i < 10; i++) {
        uint32_t res = resolutions[i % 5];
        int rule = i < 5 ? NACRE_VOXEL_SOLID_PARITY : NACRE_VOXEL_SOLID_ROBUST;
        nacre_voxel_report ra, rb;
        nacre_voxel_grid *ga = vox(ctx, &a, res, false, (nacre_voxel_solid_rule)rule, &ra);
        nacre_voxel_grid *gb = vox(ctx, &b, res, false, (nacre_voxel_solid_rule)rule, &rb);
        if (ga && gb) {
            uint64_t diff = 0;
            CHECK(same_set(ga, gb, NACRE_VOXEL_SURFACE, &diff));
            CHECK(same_set(ga, gb, NACRE_VOXEL_SOLID, &diff));
            CHECK(ra.skipped_degenerate == extra);
            CHECK(rb.skipped_degenerate == extra);
            CHECK(ra.skipped_nonfinite == 0 && rb.skipped_nonfinite == 0);
            CHECK(ra.surface_voxels == rb.surface_voxels && ra.solid_voxels == rb.solid_voxels);
        }
        nacre_voxel_grid_destroy(ga);
        nacre_voxel_grid_destroy(gb);
    }
    free(a.positions);
    free(a.indices);
    nacre_mesh_data_free(ctx, &m);
}

/* nacre_voxelize_update on a reused grid equals a fresh nacre_voxelize bit for bit, on every
 * level and both sets: same dims again, larger and smaller dims (anisotropic too), another rule,
 * and a failure (bad index) followed by a successful update. */
static bool same_grid(const nacre_voxel_grid *a, const nacre_voxel_grid *b)
{
    uint32_t la = nacre_voxel_grid_levels(a);
    if (la != nacre_voxel_grid_levels(b))
        return false;
    for (uint32_t l = 0; l < la; l++) {
        uint32_t da[3], db[3];
        nacre_voxel_grid_dims(a, l, da);
        nacre_voxel_grid_dims(b, l, db);
        if (memcmp(da, db, sizeof(da)) != 0)
            return false;
        for (int set = 0; set < 2; set++) {
            if (nacre_voxel_grid_count(a, (nacre_voxel_set)set, l) != nacre_voxel_grid_count(b, (nacre_voxel_set)set, l))
                return false;
            for (uint32_t z = 0; z < da[2]; z++)
                for (uint32_t y = 0; y < da[1]; y++)
                    for (uint32_t x = 0; x < da[0]; x++)
                        if (nacre_voxel_grid_get(a, (nacre_voxel_set)set, l, x, y, z) !=
                            nacre_voxel_grid_get(b, (nacre_voxel_set)set, l, x, y, z))
                            return false;
        }
    }
    return true;
}

static void test_update(nacre_context *ctx)
{
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_TORUS);
    nacre_mesh_data m = {0};
    CHECK(nacre_mesh_make_shape(ctx, &sd, &m) == NACRE_OK);
    /* An open copy (a few triangles dropped) so ROBUST differs from PARITY. */
    nacre_mesh_data open = m;
    open.triangle_count = m.triangle_count - 5;
    struct {
        const nacre_mesh_data *mesh;
        uint32_t res;
        bool aniso;
        nacre_voxel_solid_rule rule;
    } steps[] = {
        {&m, 28, false, NACRE_VOXEL_SOLID_PARITY},   {&m, 28, false, NACRE_VOXEL_SOLID_PARITY},
        {&m, 64, false, NACRE_VOXEL_SOLID_PARITY},   {&m, 12, false, NACRE_VOXEL_SOLID_PARITY},
        {&open, 12, false, NACRE_VOXEL_SOLID_ROBUST}, {&open, 70, false, NACRE_VOXEL_SOLID_ROBUST},
        {&open, 33, true, NACRE_VOXEL_SOLID_ROBUST},  {&open, 33, true, NACRE_VOXEL_SOLID_AUTO},
        {&m, 40, true, NACRE_VOXEL_SOLID_AUTO},       {&open, 5, false, NACRE_VOXEL_SOLID_ROBUST},
        {&m, 130, false, NACRE_VOXEL_SOLID_PARITY},  {&open, 130, false, NACRE_VOXEL_SOLID_ROBUST},
    };
    nacre_voxel_report rep;
    nacre_voxel_grid *g = vox(ctx, &m, 20, false, NACRE_VOXEL_SOLID_ROBUST, &rep);
    CHECK(g != NULL);
    CHECK(nacre_voxelize_update(NULL, &m, NULL, &rep) == NACRE_ERROR_INVALID_ARGUMENT);
    for (size_t i = 0; g && i < sizeof(steps) / sizeof(steps[0]); i++) {
        nacre_voxel_report rf, ru;
        nacre_voxel_grid *f = vox(ctx, steps[i].mesh, steps[i].res, steps[i].aniso, steps[i].rule, &rf);
        nacre_voxel_settings s = nacre_voxel_settings_defaults();
        s.resolution = steps[i].res;
        s.anisotropic = steps[i].aniso;
        s.solid_rule = steps[i].rule;
        CHECK(nacre_voxelize_update(g, steps[i].mesh, &s, &ru) == NACRE_OK);
        CHECK(f && same_grid(f, g));
        CHECK(memcmp(rf.dims, ru.dims, sizeof(rf.dims)) == 0 && rf.voxel_size == ru.voxel_size);
        CHECK(memcmp(rf.origin, ru.origin, sizeof(rf.origin)) == 0);
        CHECK(rf.surface_voxels == ru.surface_voxels && rf.solid_voxels == ru.solid_voxels);
        CHECK(rf.rule_used == ru.rule_used && rf.closed == ru.closed && rf.levels == ru.levels);
        CHECK(rf.skipped_degenerate == ru.skipped_degenerate && rf.skipped_nonfinite == ru.skipped_nonfinite);
        nacre_voxel_grid_destroy(f);
    }
    /* A failing update (index out of range) empties the grid; the next one restores it. */
    nacre_mesh_data bad = m;
    bad.indices = malloc(sizeof(uint32_t) * 3 * m.triangle_count);
    memcpy(bad.indices, m.indices, sizeof(uint32_t) * 3 * m.triangle_count);
    bad.indices[4] = m.vertex_count + 7;
    nacre_voxel_settings s = nacre_voxel_settings_defaults();
    s.solid_rule = NACRE_VOXEL_SOLID_ROBUST;
    CHECK(nacre_voxelize_update(g, &bad, &s, &rep) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(nacre_voxel_grid_levels(g) == 0);
    CHECK(nacre_voxel_grid_count(g, NACRE_VOXEL_SURFACE, 0) == 0);
    CHECK(nacre_voxelize_update(g, &m, &s, &rep) == NACRE_OK);
    nacre_voxel_grid *f = vox(ctx, &m, 32, false, NACRE_VOXEL_SOLID_ROBUST, NULL);
    CHECK(f && same_grid(f, g));
    nacre_voxel_grid_destroy(f);
    free(bad.indices);
    nacre_voxel_grid_destroy(g);
    nacre_mesh_data_free(ctx, &m);
}

/* Thread independence where the ROBUST x and y parities matter: an open star mesh (a cap of
 * triangles removed, so the z parity is wrong through the hole and the vote leans on x and y)
 * with more triangles than the serial threshold, on grids small enough for per-thread copies
 * of the sets (whose merge must include px and py; merged by one thread, or by all when larger
 * than VOXEL_MERGE_PARALLEL: 91 and 101) and on one too large for them (104: 4 x 104^2 x 2 words,
 * over 4 per triangle): one thread and two give the same grid, every level and both sets, also
 * when updating a reused grid. */
static void test_threads_open(void)
{
    nacre_context *c1 = ctx_threads(1), *c2 = ctx_threads(2);
    nacre_mesh_data m = {0};
    double centre[3];
    star_mesh(5, &m, centre);
    uint32_t kept = 0;
    const float *p0 = m.positions + 3 * m.indices[0]; /* the cap around corner 0 of triangle 0 */
    for (uint32_t t = 0; t < m.triangle_count; t++) {
        const float *p = m.positions + 3 * m.indices[3 * t];
        double dd = 0;
        for (int a = 0; a < 3; a++)
            dd += ((double)p[a] - p0[a]) * ((double)p[a] - p0[a]);
        if (dd > 0.2 * 0.2) /* drop the triangles within 0.2 (radius 0.35 to 1.95) */
            memcpy(m.indices + 3 * kept++, m.indices + 3 * t, 3 * sizeof(uint32_t));
    }
    CHECK(kept < m.triangle_count - 10 && kept > 16384);
    m.triangle_count = kept;
    static const struct {
        uint32_t res;
        bool aniso;
        nacre_voxel_solid_rule rule;
    } cases[] = {{29, false, NACRE_VOXEL_SOLID_ROBUST}, {40, true, NACRE_VOXEL_SOLID_ROBUST},
                 {23, false, NACRE_VOXEL_SOLID_PARITY}, {91, false, NACRE_VOXEL_SOLID_ROBUST},
                 {101, false, NACRE_VOXEL_SOLID_PARITY}, {104, false, NACRE_VOXEL_SOLID_ROBUST}};
    nacre_voxel_grid *reused = NULL;
    for (size_t k = 0; k < sizeof(cases) / sizeof(cases[0]); k++) {
        nacre_voxel_report r1, r2;
        nacre_voxel_grid *g1 = vox(c1, &m, cases[k].res, cases[k].aniso, cases[k].rule, &r1);
        nacre_voxel_grid *g2 = vox(c2, &m, cases[k].res, cases[k].aniso, cases[k].rule, &r2);
        CHECK(g1 && g2 && same_grid(g1, g2));
        CHECK(r1.solid_voxels > 100 && r1.solid_voxels == r2.solid_voxels);
        if (!reused) {
            reused = g2;
            g2 = NULL;
        } else {
            nacre_voxel_settings s = nacre_voxel_settings_defaults();
            s.resolution = cases[k].res;
            s.anisotropic = cases[k].aniso;
            s.solid_rule = cases[k].rule;
            CHECK(nacre_voxelize_update(reused, &m, &s, NULL) == NACRE_OK);
            CHECK(same_grid(g1, reused));
        }
        nacre_voxel_grid_destroy(g1);
        nacre_voxel_grid_destroy(g2);
    }
    nacre_voxel_grid_destroy(reused);
    free(m.positions);
    free(m.indices);
    nacre_context_destroy(c1);
    nacre_context_destroy(c2);
}

/* A 100-sided polygon (issue: the prefilter queue lost the "last vertex" flag of a block when
 * four queued triangles were flushed, and a later group read past the vertex array). Loaded from
 * OBJ as a user would, and as fans from every pivot with the vertex array sized exactly, so that
 * ASan sees any read past its end. */
static void test_ngon(nacre_context *ctx)
{
    const char *path = NACRE_TEST_TMP "/vox_ngon100.obj";
    FILE *f = fopen(path, "w");
    CHECK(f != NULL);
    if (!f)
        return;
    for (int i = 0; i < 100; i++)
        fprintf(f, "v %.6f %.6f 0\n", cos(6.283185307179586 * i / 100), sin(6.283185307179586 * i / 100));
    fprintf(f, "f");
    for (int i = 1; i <= 100; i++)
        fprintf(f, " %d", i);
    fprintf(f, "\n");
    fclose(f);
    nacre_mesh_data m = {0};
    CHECK(nacre_mesh_load(ctx, path, &m) == NACRE_OK);
    for (uint32_t res = 4; res <= 64; res *= 2) {
        nacre_voxel_report rep;
        nacre_voxel_grid *g = vox(ctx, &m, res, false, NACRE_VOXEL_SOLID_ROBUST, &rep);
        CHECK(g && rep.surface_voxels > 0);
        nacre_voxel_grid_destroy(g);
    }
    nacre_mesh_data_free(ctx, &m);

    enum { N = 100 };
    for (uint32_t pivot = 0; pivot < N; pivot += 7) {
        float *pos = malloc(3 * N * sizeof(float));
        uint32_t *idx = malloc(3 * (N - 2) * sizeof(uint32_t));
        for (int i = 0; i < N; i++) {
            pos[3 * i] = (float)cos(6.283185307179586 * i / N);
            pos[3 * i + 1] = (float)sin(6.283185307179586 * i / N);
            pos[3 * i + 2] = 0.0f;
        }
        for (uint32_t t = 0; t < N - 2; t++) {
            idx[3 * t] = pivot;
            idx[3 * t + 1] = (pivot + 1 + t) % N;
            idx[3 * t + 2] = (pivot + 2 + t) % N;
        }
        nacre_mesh_data fan = {0};
        fan.positions = pos;
        fan.vertex_count = N;
        fan.indices = idx;
        fan.triangle_count = N - 2;
        nacre_voxel_report rep;
        nacre_voxel_grid *g = vox(ctx, &fan, 16, false, NACRE_VOXEL_SOLID_ROBUST, &rep);
        CHECK(g && rep.surface_voxels > 0);
        nacre_voxel_grid_destroy(g);
        free(pos);
        free(idx);
    }
}

int main(void)
{
    nacre_context *ctx = ctx_threads(0);
    nacre_shape_desc sphere = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
    nacre_shape_desc box = nacre_shape_desc_defaults(NACRE_SHAPE_BOX);
    box.size[0] = 1.3f, box.size[1] = 0.77f, box.size[2] = 0.5f;
    nacre_shape_desc torus = nacre_shape_desc_defaults(NACRE_SHAPE_TORUS);
    for (uint32_t res = 16; res <= 64; res += 24) {
        check_volume(ctx, sphere, res);
        check_volume(ctx, box, res + 3);
        check_volume(ctx, torus, res + 1);
    }
    test_aligned_cube(ctx);
    test_unpack(ctx);
    test_conservative(ctx);
    test_conservative_closed(ctx);
    test_512();
    test_shared_edges(ctx);
    test_broken(ctx);
    test_bad_input(ctx);
    test_pyramid(ctx);
    test_threads();
    test_block_path(ctx);
    test_update(ctx);
    test_threads_open();
    test_rest(ctx);
    test_cli();
    test_ngon(ctx);
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
