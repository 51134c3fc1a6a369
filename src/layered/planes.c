/*
 * planes.c: the planar approximations of seed 001 (Francois, Pattanaik, Bouatouch, Breton 2006,
 * "Subsurface texture mapping", section 2.2, eqs. 7-8 and 14) and the uv gradients of each
 * triangle.
 *
 * Light that scatters deep below a visible point P entered the surface away from P, where the
 * tangent plane at P is a poor stand-in for the surface. The seed fits, per vertex V, a plane by
 * least squares to the vertices within r = -log(eps) / sigma_t of V (farther ones attenuate the
 * light below eps), and the renderer interpolates between P's tangent plane and that plane with
 * the depth of the point being lit. The fit here is the total least-squares plane: through the
 * neighbours' centroid, normal to the direction of least spread (the smallest eigenvector of
 * their covariance, by cyclic Jacobi rotations). It is oriented like the vertex normal. As eq. 14
 * the plane is stored by its normal and its point on the vertex's normal line, so that
 * interpolating the points over a triangle gives points of the interpolated plane.
 *
 * Neighbours come from a uniform hash grid of cell r (counting sort of the vertices by cell
 * hash): each query visits the 27 cells around V. Units: world scene units.
 */
#include "layered/planes.h"

#include <math.h>
#include <string.h>

void nc_layer_planes_free(nacre_context *ctx, nc_layer_planes *p)
{
    nc_free(ctx, p->plane_n);
    nc_free(ctx, p->plane_p);
    nc_free(ctx, p->grad_uv);
    memset(p, 0, sizeof(*p));
}

static inline uint32_t cell_hash(int32_t x, int32_t y, int32_t z, uint32_t mask)
{
    uint32_t h = (uint32_t)x * 73856093u ^ (uint32_t)y * 19349663u ^ (uint32_t)z * 83492791u;
    h ^= h >> 15;
    h *= 0x2c1b3c6du;
    h ^= h >> 12;
    return h & mask;
}

/* Eigenvector of the smallest eigenvalue of the symmetric 3x3 matrix a (cyclic Jacobi). */
static void smallest_eigenvector(double a[3][3], double out[3])
{
    double v[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    for (int sweep = 0; sweep < 16; sweep++) {
        double off = fabs(a[0][1]) + fabs(a[0][2]) + fabs(a[1][2]);
        if (off < 1e-30 * (fabs(a[0][0]) + fabs(a[1][1]) + fabs(a[2][2]) + 1e-300))
            break;
        for (int p = 0; p < 2; p++)
            for (int q = p + 1; q < 3; q++) {
                if (a[p][q] == 0.0)
                    continue;
                double theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                double t = (theta >= 0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));
                double c = 1.0 / sqrt(t * t + 1.0), s = t * c;
                for (int k = 0; k < 3; k++) { /* a = J^T a J */
                    double akp = a[k][p], akq = a[k][q];
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for (int k = 0; k < 3; k++) {
                    double apk = a[p][k], aqk = a[q][k];
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for (int k = 0; k < 3; k++) {
                    double vkp = v[k][p], vkq = v[k][q];
                    v[k][p] = c * vkp - s * vkq;
                    v[k][q] = s * vkp + c * vkq;
                }
            }
    }
    int m = 0;
    for (int k = 1; k < 3; k++)
        if (a[k][k] < a[m][m])
            m = k;
    for (int k = 0; k < 3; k++)
        out[k] = v[k][m];
}

/* Per triangle, grad u and grad v in its plane: g = a e1 + b e2 with g.e1 = du1, g.e2 = du2. */
static void uv_gradients(const float *pos, const float *uvs, const uint32_t *idx, uint32_t nt, float *grad)
{
    for (uint32_t t = 0; t < nt; t++) {
        const uint32_t *tri = idx + 3 * (size_t)t;
        const float *p0 = pos + 3 * (size_t)tri[0], *p1 = pos + 3 * (size_t)tri[1], *p2 = pos + 3 * (size_t)tri[2];
        const float *t0 = uvs + 2 * (size_t)tri[0], *t1 = uvs + 2 * (size_t)tri[1], *t2 = uvs + 2 * (size_t)tri[2];
        double e1[3], e2[3];
        for (int k = 0; k < 3; k++)
            e1[k] = (double)p1[k] - p0[k], e2[k] = (double)p2[k] - p0[k];
        double g11 = e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2];
        double g22 = e2[0] * e2[0] + e2[1] * e2[1] + e2[2] * e2[2];
        double g12 = e1[0] * e2[0] + e1[1] * e2[1] + e1[2] * e2[2];
        double det = g11 * g22 - g12 * g12;
        float *g = grad + 6 * (size_t)t;
        if (!(det > 1e-30 * g11 * g22) || !isfinite(det)) {
            memset(g, 0, 6 * sizeof(float));
            continue;
        }
        for (int c = 0; c < 2; c++) {
            double d1 = (double)t1[c] - t0[c], d2 = (double)t2[c] - t0[c];
            double a = (g22 * d1 - g12 * d2) / det, b = (g11 * d2 - g12 * d1) / det;
            for (int k = 0; k < 3; k++)
                g[3 * c + k] = (float)(a * e1[k] + b * e2[k]);
        }
    }
}

nacre_result nc_layer_planes_build(nacre_context *ctx, const float *pos, const float *nrm, const float *uvs,
                                   const uint32_t *idx, uint32_t nv, uint32_t nt, float radius, nc_layer_planes *out)
{
    if (out->vertex_count != nv || out->triangle_count != nt || (uvs != NULL) != (out->grad_uv != NULL))
        nc_layer_planes_free(ctx, out);
    if (!out->plane_n) {
        out->plane_n = nc_alloc(ctx, 3 * (size_t)nv * sizeof(float) + 1);
        out->plane_p = nc_alloc(ctx, 3 * (size_t)nv * sizeof(float) + 1);
        out->grad_uv = uvs ? nc_alloc(ctx, 6 * (size_t)nt * sizeof(float) + 1) : NULL;
        if (!out->plane_n || !out->plane_p || (uvs && !out->grad_uv)) {
            nc_layer_planes_free(ctx, out);
            return NACRE_ERROR_OUT_OF_MEMORY;
        }
        out->vertex_count = nv;
        out->triangle_count = nt;
    }
    if (uvs)
        uv_gradients(pos, uvs, idx, nt, out->grad_uv);

    /* Hash grid: table of 2^k >= 2 nv buckets, vertices sorted by bucket. */
    uint32_t buckets = 1;
    while (buckets < 2 * nv && buckets < (1u << 30))
        buckets <<= 1;
    uint32_t *start = nc_calloc(ctx, (size_t)buckets + 1, sizeof(uint32_t));
    uint32_t *order = nc_alloc(ctx, (size_t)nv * sizeof(uint32_t) + 1);
    uint32_t *vb = nc_alloc(ctx, (size_t)nv * sizeof(uint32_t) + 1);
    if (!start || !order || !vb) {
        nc_free(ctx, start);
        nc_free(ctx, order);
        nc_free(ctx, vb);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    const float inv_cell = 1.0f / radius, r2 = radius * radius;
    const uint32_t mask = buckets - 1;
    for (uint32_t i = 0; i < nv; i++) {
        const float *p = pos + 3 * (size_t)i;
        vb[i] = cell_hash((int32_t)floorf(p[0] * inv_cell), (int32_t)floorf(p[1] * inv_cell),
                          (int32_t)floorf(p[2] * inv_cell), mask);
        start[vb[i] + 1]++;
    }
    for (uint32_t b = 0; b < buckets; b++)
        start[b + 1] += start[b];
    {
        uint32_t *fill = nc_alloc(ctx, (size_t)buckets * sizeof(uint32_t));
        if (!fill) {
            nc_free(ctx, start);
            nc_free(ctx, order);
            nc_free(ctx, vb);
            return NACRE_ERROR_OUT_OF_MEMORY;
        }
        memcpy(fill, start, (size_t)buckets * sizeof(uint32_t));
        for (uint32_t i = 0; i < nv; i++) /* increasing i per bucket: the sums below are in a fixed order */
            order[fill[vb[i]]++] = i;
        nc_free(ctx, fill);
    }

#pragma omp parallel for schedule(dynamic, 256) num_threads(nc_threads(ctx))
    for (int64_t vi = 0; vi < (int64_t)nv; vi++) {
        const float *v = pos + 3 * (size_t)vi, *nv3 = nrm + 3 * (size_t)vi;
        const int32_t cx = (int32_t)floorf(v[0] * inv_cell), cy = (int32_t)floorf(v[1] * inv_cell),
                      cz = (int32_t)floorf(v[2] * inv_cell);
        uint32_t seen[27];
        int nseen = 0;
        double sum[3] = {0, 0, 0}, cov[3][3] = {{0}};
        uint32_t count = 0;
        for (int dz = -1; dz <= 1; dz++)
            for (int dy = -1; dy <= 1; dy++)
                for (int dx = -1; dx <= 1; dx++) {
                    uint32_t b = cell_hash(cx + dx, cy + dy, cz + dz, mask);
                    bool dup = false; /* two cells of the 27 may share a bucket */
                    for (int k = 0; k < nseen; k++)
                        dup |= seen[k] == b;
                    if (dup)
                        continue;
                    seen[nseen++] = b;
                    for (uint32_t k = start[b]; k < start[b + 1]; k++) {
                        const float *q = pos + 3 * (size_t)order[k];
                        /* relative to V: the sums stay well conditioned far from the origin */
                        double d[3] = {(double)q[0] - v[0], (double)q[1] - v[1], (double)q[2] - v[2]};
                        if (d[0] * d[0] + d[1] * d[1] + d[2] * d[2] > (double)r2)
                            continue;
                        count++;
                        for (int a = 0; a < 3; a++) {
                            sum[a] += d[a];
                            for (int c = 0; c < 3; c++)
                                cov[a][c] += d[a] * d[c];
                        }
                    }
                }
        float *pn = out->plane_n + 3 * (size_t)vi, *pp = out->plane_p + 3 * (size_t)vi;
        memcpy(pn, nv3, 3 * sizeof(float));
        memcpy(pp, v, 3 * sizeof(float));
        if (count < 3)
            continue; /* the tangent plane */
        double mean[3], n[3];
        for (int a = 0; a < 3; a++)
            mean[a] = sum[a] / count;
        for (int a = 0; a < 3; a++)
            for (int c = 0; c < 3; c++)
                cov[a][c] = cov[a][c] / count - mean[a] * mean[c];
        smallest_eigenvector(cov, n);
        double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        double along = (n[0] * nv3[0] + n[1] * nv3[1] + n[2] * nv3[2]) / len;
        if (!(len > 0) || fabs(along) < 0.2)
            continue; /* a fold or a thin sheet: the fitted plane says nothing about this side */
        double sgn = along > 0 ? 1.0 / len : -1.0 / len;
        for (int a = 0; a < 3; a++)
            n[a] *= sgn;
        /* The plane's point on V's normal line: V + t N_V with (V + t N_V - C) . n = 0. */
        double t = (mean[0] * n[0] + mean[1] * n[1] + mean[2] * n[2]) / fabs(along);
        for (int a = 0; a < 3; a++) {
            pn[a] = (float)n[a];
            pp[a] = (float)(v[a] + t * nv3[a]);
        }
    }
    nc_free(ctx, start);
    nc_free(ctx, order);
    nc_free(ctx, vb);
    return NACRE_OK;
}
