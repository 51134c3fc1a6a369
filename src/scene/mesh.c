/*
 * mesh.c: plain mesh data (nacre_mesh_data): freeing, validation, smooth normals, tangent frames
 * and a topology report.
 *
 * Normals: every triangle adds its unit normal, weighted by its corner angle (Thuermer and
 * Wuethrich 1998) times its area (as the public header documents), to all vertices at the same
 * position, so the seams of unshared vertices (OBJ files, per-face UVs) still shade smoothly.
 * Tangents: Lengyel 2001, "Computing tangent space basis vectors for an arbitrary mesh":
 * per-triangle dP/du and dP/dv, area weighted and summed over vertices that share position,
 * normal and UV, then Gram-Schmidt against the normal; the handedness w says whether the summed
 * dP/dv agrees with n x t. Analysis: exact-position welding, then every undirected edge becomes
 * one 64-bit key (welded ids a < b, key a * W + b), LSD radix sorted so that each run of equal
 * keys is one edge and its length the number of triangles using it.
 *
 * Determinism: scatter steps run serially in triangle order and sums are reduced in fixed-size
 * blocks, so results do not depend on the thread count. Lengths and areas are in the mesh's own
 * units.
 */
#include "scene/mesh_private.h"
#include "core/math.h"

#include <math.h>
#include <string.h>

/* ------------------------------------------------------------------------------------------ */
/* Welding                                                                                    */
/* ------------------------------------------------------------------------------------------ */

typedef struct weld_attr {
    const float *data[3];
    int dim[3];
    int count;
} weld_attr;

static inline uint32_t float_key(float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof(u));
    return u == 0x80000000u ? 0u : u; /* -0.0 and +0.0 are the same place */
}

static inline uint32_t weld_hash(const weld_attr *w, size_t i)
{
    uint64_t h = 0x243F6A8885A308D3ull;
    for (int a = 0; a < w->count; a++) {
        const float *p = w->data[a] + i * (size_t)w->dim[a];
        for (int k = 0; k < w->dim[a]; k++) {
            h ^= float_key(p[k]);
            h *= 0x9E3779B97F4A7C15ull;
            h ^= h >> 29;
        }
    }
    h *= 0xBF58476D1CE4E5B9ull;
    return (uint32_t)(h >> 32);
}

static inline bool weld_equal(const weld_attr *w, size_t i, size_t j)
{
    for (int a = 0; a < w->count; a++) {
        const float *p = w->data[a] + i * (size_t)w->dim[a];
        const float *q = w->data[a] + j * (size_t)w->dim[a];
        for (int k = 0; k < w->dim[a]; k++)
            if (float_key(p[k]) != float_key(q[k]))
                return false;
    }
    return true;
}

nacre_result nc_mesh_weld(nacre_context *ctx, uint32_t n, const float *positions,
                          const float *normals, const float *uvs, uint32_t *rep)
{
    weld_attr w = {{positions}, {3}, 1};
    if (normals) {
        w.data[w.count] = normals;
        w.dim[w.count++] = 3;
    }
    if (uvs) {
        w.data[w.count] = uvs;
        w.dim[w.count++] = 2;
    }
    /* Open addressing with linear probing, at most half full. Each slot keeps the hash next to
     * the vertex index so most mismatches are rejected without touching the vertex arrays. */
    size_t cap = 16;
    while (cap < (size_t)n * 2)
        cap *= 2;
    uint64_t *table = nc_alloc(ctx, cap * sizeof(uint64_t));
    uint32_t *hashes = nc_alloc(ctx, (size_t)n * sizeof(uint32_t));
    if (!table || !hashes) {
        nc_free(ctx, table);
        nc_free(ctx, hashes);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    memset(table, 0xff, cap * sizeof(uint64_t));
    const uint64_t empty = UINT64_MAX;
    const size_t mask = cap - 1;

#pragma omp parallel for num_threads(ctx->threads) if (n > NC_MESH_PARALLEL_MIN) schedule(static)
    for (size_t i = 0; i < n; i++)
        hashes[i] = weld_hash(&w, i);

    /* Serial insertion in index order makes the first vertex of each group its representative. */
    for (size_t i = 0; i < n; i++) {
        uint32_t h = hashes[i];
        size_t slot = h & mask;
        for (;;) {
            uint64_t e = table[slot];
            if (e == empty) {
                table[slot] = ((uint64_t)h << 32) | i;
                rep[i] = (uint32_t)i;
                break;
            }
            uint32_t j = (uint32_t)e;
            if ((uint32_t)(e >> 32) == h && weld_equal(&w, i, j)) {
                rep[i] = j;
                break;
            }
            slot = (slot + 1) & mask;
        }
    }
    nc_free(ctx, table);
    nc_free(ctx, hashes);
    return NACRE_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* Freeing and validation                                                                     */
/* ------------------------------------------------------------------------------------------ */

void nacre_mesh_data_free(nacre_context *ctx, nacre_mesh_data *mesh)
{
    if (!ctx || !mesh)
        return;
    nc_free(ctx, mesh->positions);
    nc_free(ctx, mesh->normals);
    nc_free(ctx, mesh->uvs);
    nc_free(ctx, mesh->tangents);
    nc_free(ctx, mesh->indices);
    memset(mesh, 0, sizeof(*mesh));
}

/* Index of the first vertex with a non-finite component among `dim` floats per vertex, or
 * UINT64_MAX. A min reduction keeps the answer independent of the thread count. */
static uint64_t first_nonfinite(const nacre_context *ctx, const float *a, size_t count, int dim)
{
    uint64_t first = UINT64_MAX;
    size_t n = count * (size_t)dim;
#pragma omp parallel for num_threads(ctx->threads) if (n > NC_MESH_PARALLEL_MIN) \
    schedule(static) reduction(min : first)
    for (size_t i = 0; i < n; i++)
        if (!isfinite(a[i]) && i / (size_t)dim < first)
            first = i / (size_t)dim;
    return first;
}

nacre_result nc_mesh_check_geometry(nacre_context *ctx, const nacre_mesh_data *mesh,
                                    const char *name, nacre_result code)
{
    if (!name)
        name = "mesh";
    if (!mesh)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: mesh is NULL", name);
    if (mesh->vertex_count == 0)
        return nc_fail(ctx, code, "%s: mesh has no vertices", name);
    if (mesh->triangle_count == 0)
        return nc_fail(ctx, code, "%s: mesh has no triangles", name);
    if (mesh->triangle_count > NC_MESH_MAX_TRIANGLES)
        return nc_fail(ctx, code, "%s: triangle_count: %u exceeds the limit %u", name,
                       (unsigned)mesh->triangle_count, (unsigned)NC_MESH_MAX_TRIANGLES);
    if (!mesh->positions)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: positions: NULL", name);
    if (!mesh->indices)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: indices: NULL", name);

    const uint32_t *idx = mesh->indices;
    const uint32_t nv = mesh->vertex_count;
    size_t nc = (size_t)mesh->triangle_count * 3;
    uint64_t bad = UINT64_MAX;
#pragma omp parallel for num_threads(ctx->threads) if (nc > NC_MESH_PARALLEL_MIN) \
    schedule(static) reduction(min : bad)
    for (size_t c = 0; c < nc; c++)
        if (idx[c] >= nv && c < bad)
            bad = c;
    if (bad != UINT64_MAX)
        return nc_fail(ctx, code, "%s: triangle %llu: index %u out of range (vertex_count %u)",
                       name, (unsigned long long)(bad / 3), (unsigned)idx[bad], (unsigned)nv);

    uint64_t v = first_nonfinite(ctx, mesh->positions, nv, 3);
    if (v != UINT64_MAX)
        return nc_fail(ctx, code, "%s: vertex %llu: non-finite position", name,
                       (unsigned long long)v);
    if (mesh->uvs && (v = first_nonfinite(ctx, mesh->uvs, nv, 2)) != UINT64_MAX)
        return nc_fail(ctx, code, "%s: vertex %llu: non-finite uv", name, (unsigned long long)v);
    return NACRE_OK;
}

nacre_result nacre_mesh_validate(nacre_context *ctx, const nacre_mesh_data *mesh, const char *name)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!name)
        name = "mesh";
    nacre_result r = nc_mesh_check_geometry(ctx, mesh, name, NACRE_ERROR_INVALID_ARGUMENT);
    if (r != NACRE_OK)
        return r;
    uint64_t v;
    if (mesh->normals &&
        (v = first_nonfinite(ctx, mesh->normals, mesh->vertex_count, 3)) != UINT64_MAX)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: vertex %llu: non-finite normal",
                       name, (unsigned long long)v);
    if (mesh->tangents &&
        (v = first_nonfinite(ctx, mesh->tangents, mesh->vertex_count, 4)) != UINT64_MAX)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: vertex %llu: non-finite tangent",
                       name, (unsigned long long)v);
    return NACRE_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* Normals                                                                                    */
/* ------------------------------------------------------------------------------------------ */

/* atan2(y, x) for y >= 0, in [0, pi], inline: libm's atan2f is an out-of-line call per corner
 * in the hottest loop of mesh loading. The octant is reduced to a ratio q in [0, 1], then to
 * |q| <= tan(pi/8), where Cephes' atanf polynomial (S. Moshier) is good to about 2e-7. */
static inline float angle_atan2(float y, float x)
{
    float ax = fabsf(x);
    float lo = y < ax ? y : ax, hi = y < ax ? ax : y;
    if (!(hi > 0.0f))
        return 0.0f;
    float q = lo / hi, base = 0.0f;
    if (q > 0.41421356f) {
        base = 0.25f * NC_PI;
        q = (q - 1.0f) / (q + 1.0f);
    }
    float z = q * q;
    float a = base + ((((8.05374449538e-2f * z - 1.38776856032e-1f) * z + 1.99777106478e-1f) * z -
                       3.33329491539e-1f) * z * q + q);
    if (y > ax)
        a = 0.5f * NC_PI - a;
    return x < 0.0f ? NC_PI - a : a;
}

nacre_result nacre_mesh_compute_normals(nacre_context *ctx, nacre_mesh_data *mesh)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_result r = nc_mesh_check_geometry(ctx, mesh, "mesh", NACRE_ERROR_INVALID_ARGUMENT);
    if (r != NACRE_OK)
        return r;
    const size_t nv = mesh->vertex_count, nt = mesh->triangle_count;
    const float *pos = mesh->positions;
    const uint32_t *idx = mesh->indices;

    uint32_t *rep = nc_alloc(ctx, nv * sizeof(uint32_t));
    float *face = nc_alloc(ctx, nt * 6 * sizeof(float)); /* normal * 2 area, 3 corner angles */
    float *acc = nc_calloc(ctx, nv * 3, sizeof(float));
    float *normals = mesh->normals ? mesh->normals : nc_alloc(ctx, nv * 3 * sizeof(float));
    if (!rep || !face || !acc || !normals) {
        r = NACRE_ERROR_OUT_OF_MEMORY;
        goto out;
    }
    r = nc_mesh_weld(ctx, (uint32_t)nv, pos, NULL, NULL, rep);
    if (r != NACRE_OK)
        goto out;

#pragma omp parallel for num_threads(ctx->threads) if (nt > NC_MESH_PARALLEL_MIN) schedule(static)
    for (size_t t = 0; t < nt; t++) {
        float *f = face + t * 6;
        uint32_t i0 = idx[t * 3], i1 = idx[t * 3 + 1], i2 = idx[t * 3 + 2];
        memset(f, 0, 6 * sizeof(float));
        if (rep[i0] == rep[i1] || rep[i1] == rep[i2] || rep[i0] == rep[i2])
            continue;
        nc_vec3 p0 = nc_v3a(pos + i0 * 3), p1 = nc_v3a(pos + i1 * 3), p2 = nc_v3a(pos + i2 * 3);
        nc_vec3 e1 = nc_sub(p1, p0), e2 = nc_sub(p2, p0);
        nc_vec3 n = nc_cross(e1, e2);
        float len = nc_length(n);
        if (!(len > 0.0f) || !isfinite(len))
            continue;
        /* atan2(|e1 x e2|, e1 . e2) stays accurate for the very thin and very flat corners that
         * acos loses. The three angles of a triangle sum to pi. */
        float a0 = angle_atan2(len, nc_dot(e1, e2));
        float a1 = angle_atan2(len, nc_dot(nc_sub(p2, p1), nc_sub(p0, p1)));
        float a2 = NC_PI - a0 - a1;
        a2 = a2 > 0.0f ? a2 : 0.0f;
        f[0] = n.x;
        f[1] = n.y;
        f[2] = n.z;
        f[3] = a0;
        f[4] = a1;
        f[5] = a2;
    }

    for (size_t t = 0; t < nt; t++) {
        const float *f = face + t * 6;
        for (int k = 0; k < 3; k++) {
            float *a = acc + (size_t)rep[idx[t * 3 + (size_t)k]] * 3;
            a[0] += f[0] * f[3 + k];
            a[1] += f[1] * f[3 + k];
            a[2] += f[2] * f[3 + k];
        }
    }

#pragma omp parallel for num_threads(ctx->threads) if (nv > NC_MESH_PARALLEL_MIN) schedule(static)
    for (size_t v = 0; v < nv; v++) {
        nc_vec3 s = nc_v3a(acc + (size_t)rep[v] * 3);
        float len = nc_length(s);
        /* Vertices that only touch degenerate triangles (or none) need some unit normal. */
        nc_vec3 n = (len > 0.0f && isfinite(len)) ? nc_scale(s, 1.0f / len) : nc_v3(0, 1, 0);
        nc_v3store(n, normals + v * 3);
    }
    mesh->normals = normals;

out:
    if (normals != mesh->normals)
        nc_free(ctx, normals);
    nc_free(ctx, rep);
    nc_free(ctx, face);
    nc_free(ctx, acc);
    return r;
}

/* ------------------------------------------------------------------------------------------ */
/* Tangents                                                                                   */
/* ------------------------------------------------------------------------------------------ */

/* A usable unit normal even when the caller's normal is zero or broken. */
static inline nc_vec3 safe_normal(const float *n)
{
    nc_vec3 v = nc_v3a(n);
    float len = nc_length(v);
    return (len > 0.0f && isfinite(len)) ? nc_scale(v, 1.0f / len) : nc_v3(0, 1, 0);
}

static inline void store_tangent(float *out, nc_vec3 t, float w)
{
    out[0] = t.x;
    out[1] = t.y;
    out[2] = t.z;
    out[3] = w;
}

nacre_result nacre_mesh_compute_tangents(nacre_context *ctx, nacre_mesh_data *mesh)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    nacre_result r = nc_mesh_check_geometry(ctx, mesh, "mesh", NACRE_ERROR_INVALID_ARGUMENT);
    if (r != NACRE_OK)
        return r;
    if (!mesh->normals && (r = nacre_mesh_compute_normals(ctx, mesh)) != NACRE_OK)
        return r;
    const size_t nv = mesh->vertex_count, nt = mesh->triangle_count;
    const float *pos = mesh->positions, *nrm = mesh->normals, *uv = mesh->uvs;
    const uint32_t *idx = mesh->indices;
    float *tangents = mesh->tangents ? mesh->tangents : nc_alloc(ctx, nv * 4 * sizeof(float));
    if (!tangents)
        return NACRE_ERROR_OUT_OF_MEMORY;

    if (!uv) {
#pragma omp parallel for num_threads(ctx->threads) if (nv > NC_MESH_PARALLEL_MIN) schedule(static)
        for (size_t v = 0; v < nv; v++) {
            nc_vec3 t, b;
            nc_basis(safe_normal(nrm + v * 3), &t, &b);
            store_tangent(tangents + v * 4, t, 1.0f);
        }
        mesh->tangents = tangents;
        return NACRE_OK;
    }

    uint32_t *rep = nc_alloc(ctx, nv * sizeof(uint32_t));
    float *face = nc_alloc(ctx, nt * 6 * sizeof(float)); /* area-weighted unit dP/du, dP/dv */
    float *acc = nc_calloc(ctx, nv * 6, sizeof(float));
    if (!rep || !face || !acc) {
        r = NACRE_ERROR_OUT_OF_MEMORY;
        goto out;
    }
    /* Corners that agree in position, normal and UV are one vertex of a smooth tangent field;
     * a UV seam or a crease keeps its sides apart. */
    r = nc_mesh_weld(ctx, (uint32_t)nv, pos, nrm, uv, rep);
    if (r != NACRE_OK)
        goto out;

#pragma omp parallel for num_threads(ctx->threads) if (nt > NC_MESH_PARALLEL_MIN) schedule(static)
    for (size_t t = 0; t < nt; t++) {
        float *f = face + t * 6;
        memset(f, 0, 6 * sizeof(float));
        uint32_t i0 = idx[t * 3], i1 = idx[t * 3 + 1], i2 = idx[t * 3 + 2];
        nc_vec3 p0 = nc_v3a(pos + i0 * 3);
        nc_vec3 e1 = nc_sub(nc_v3a(pos + i1 * 3), p0), e2 = nc_sub(nc_v3a(pos + i2 * 3), p0);
        float du1 = uv[i1 * 2] - uv[i0 * 2], dv1 = uv[i1 * 2 + 1] - uv[i0 * 2 + 1];
        float du2 = uv[i2 * 2] - uv[i0 * 2], dv2 = uv[i2 * 2 + 1] - uv[i0 * 2 + 1];
        float det = du1 * dv2 - du2 * dv1;
        float area = nc_length(nc_cross(e1, e2));
        if (det == 0.0f || !isfinite(det) || !(area > 0.0f) || !isfinite(area))
            continue; /* no UV parametrisation here: the vertex falls back to any frame */
        float inv = 1.0f / det;
        nc_vec3 s = nc_scale(nc_sub(nc_scale(e1, dv2), nc_scale(e2, dv1)), inv);
        nc_vec3 u = nc_scale(nc_sub(nc_scale(e2, du1), nc_scale(e1, du2)), inv);
        float ls = nc_length(s), lu = nc_length(u);
        if (!(ls > 0.0f) || !(lu > 0.0f) || !isfinite(ls) || !isfinite(lu))
            continue;
        /* Unit directions weighted by area: a sliver with a tiny UV footprint must not
         * outvote its neighbours through the 1/det factor. */
        s = nc_scale(s, area / ls);
        u = nc_scale(u, area / lu);
        f[0] = s.x;
        f[1] = s.y;
        f[2] = s.z;
        f[3] = u.x;
        f[4] = u.y;
        f[5] = u.z;
    }

    for (size_t t = 0; t < nt; t++) {
        const float *f = face + t * 6;
        for (int k = 0; k < 3; k++) {
            float *a = acc + (size_t)rep[idx[t * 3 + (size_t)k]] * 6;
            for (int j = 0; j < 6; j++)
                a[j] += f[j];
        }
    }

#pragma omp parallel for num_threads(ctx->threads) if (nv > NC_MESH_PARALLEL_MIN) schedule(static)
    for (size_t v = 0; v < nv; v++) {
        const float *a = acc + (size_t)rep[v] * 6;
        nc_vec3 n = safe_normal(nrm + v * 3);
        nc_vec3 s = nc_v3a(a), u = nc_v3a(a + 3);
        nc_vec3 t = nc_sub(s, nc_scale(n, nc_dot(n, s)));
        float lt = nc_length(t), ls = nc_length(s);
        if (lt > 1e-4f * ls && isfinite(lt)) {
            t = nc_scale(t, 1.0f / lt);
        } else {
            /* dP/du is missing or along the normal: take dP/dv's frame if there is one. */
            nc_vec3 alt = nc_cross(u, n);
            float la = nc_length(alt);
            if (la > 1e-4f * nc_length(u) && isfinite(la)) {
                t = nc_scale(alt, 1.0f / la);
            } else {
                nc_vec3 b;
                nc_basis(n, &t, &b);
            }
        }
        float w = nc_dot(nc_cross(n, t), u) < 0.0f ? -1.0f : 1.0f;
        store_tangent(tangents + v * 4, t, w);
    }
    mesh->tangents = tangents;

out:
    if (tangents != mesh->tangents)
        nc_free(ctx, tangents);
    nc_free(ctx, rep);
    nc_free(ctx, face);
    nc_free(ctx, acc);
    return r;
}

/* ------------------------------------------------------------------------------------------ */
/* Analysis                                                                                   */
/* ------------------------------------------------------------------------------------------ */

/* LSD radix sort of keys below 2^bits, 11-bit digits (a 2048-entry histogram stays in L1).
 * Digits where every key agrees are skipped. Returns whichever buffer holds the result. */
static uint64_t *radix_sort_u64(uint64_t *keys, uint64_t *tmp, size_t n, int bits)
{
    enum { DIGIT_BITS = 11, BUCKETS = 1 << DIGIT_BITS };
    size_t count[BUCKETS];
    uint64_t *src = keys, *dst = tmp;
    for (int shift = 0; shift < bits; shift += DIGIT_BITS) {
        memset(count, 0, sizeof(count));
        for (size_t i = 0; i < n; i++)
            count[(src[i] >> shift) & (BUCKETS - 1)]++;
        if (count[(src[0] >> shift) & (BUCKETS - 1)] == n)
            continue;
        size_t sum = 0;
        for (int b = 0; b < BUCKETS; b++) {
            size_t c = count[b];
            count[b] = sum;
            sum += c;
        }
        for (size_t i = 0; i < n; i++)
            dst[count[(src[i] >> shift) & (BUCKETS - 1)]++] = src[i];
        uint64_t *swap = src;
        src = dst;
        dst = swap;
    }
    return src;
}

#define ANALYZE_BLOCK 4096

nacre_result nacre_mesh_analyze(nacre_context *ctx, const nacre_mesh_data *mesh,
                                nacre_mesh_info *out)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!out)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "mesh: analysis output is NULL");
    memset(out, 0, sizeof(*out));
    nacre_result r = nc_mesh_check_geometry(ctx, mesh, "mesh", NACRE_ERROR_INVALID_ARGUMENT);
    if (r != NACRE_OK)
        return r;
    const size_t nv = mesh->vertex_count, nt = mesh->triangle_count;
    const float *pos = mesh->positions;
    const uint32_t *idx = mesh->indices;
    const size_t nblocks = (nt + ANALYZE_BLOCK - 1) / ANALYZE_BLOCK;

    uint32_t *rep = nc_alloc(ctx, nv * sizeof(uint32_t));
    uint32_t *id = nc_alloc(ctx, nv * sizeof(uint32_t)); /* dense welded id, indexed by rep */
    uint8_t *used = nc_calloc(ctx, nv, 1);
    uint64_t *keys = nc_alloc(ctx, nt * 3 * sizeof(uint64_t));
    uint64_t *tmp = nc_alloc(ctx, nt * 3 * sizeof(uint64_t));
    double *block_area = nc_alloc(ctx, nblocks * sizeof(double));
    uint32_t *block_degen = nc_alloc(ctx, nblocks * sizeof(uint32_t));
    if (!rep || !id || !used || !keys || !tmp || !block_area || !block_degen) {
        r = NACRE_ERROR_OUT_OF_MEMORY;
        goto out;
    }
    r = nc_mesh_weld(ctx, (uint32_t)nv, pos, NULL, NULL, rep);
    if (r != NACRE_OK)
        goto out;

    for (size_t c = 0; c < nt * 3; c++)
        used[idx[c]] = 1;
    uint32_t unreferenced = 0;
    for (size_t v = 0; v < nv; v++)
        id[v] = UINT32_MAX;
    for (size_t v = 0; v < nv; v++) {
        if (used[v])
            id[rep[v]] = 0;
        else
            unreferenced++;
    }
    uint32_t welded = 0;
    for (size_t v = 0; v < nv; v++)
        if (id[v] == 0)
            id[v] = welded++;

    /* welded <= 2^32 - 1, so a * W + b < W^2 fits in 64 bits, and W^2 itself marks the corner
     * keys of triangles that collapsed (they sort to the end). */
    const uint64_t W = welded;
    const uint64_t sentinel = W * W;

#pragma omp parallel for num_threads(ctx->threads) if (nblocks > 2) schedule(static)
    for (size_t b = 0; b < nblocks; b++) {
        size_t t_end = (b + 1) * ANALYZE_BLOCK < nt ? (b + 1) * ANALYZE_BLOCK : nt;
        double area = 0.0;
        uint32_t degen = 0;
        for (size_t t = b * ANALYZE_BLOCK; t < t_end; t++) {
            const uint32_t *tri = idx + t * 3;
            uint64_t w[3] = {id[rep[tri[0]]], id[rep[tri[1]]], id[rep[tri[2]]]};
            /* In double, differences of nearby floats are exact and the cross product far
             * finer than float spacing, so only truly collinear corners give zero area. */
            const float *p0 = pos + (size_t)tri[0] * 3, *p1 = pos + (size_t)tri[1] * 3,
                        *p2 = pos + (size_t)tri[2] * 3;
            double e1[3] = {(double)p1[0] - p0[0], (double)p1[1] - p0[1], (double)p1[2] - p0[2]};
            double e2[3] = {(double)p2[0] - p0[0], (double)p2[1] - p0[1], (double)p2[2] - p0[2]};
            double cx = e1[1] * e2[2] - e1[2] * e2[1];
            double cy = e1[2] * e2[0] - e1[0] * e2[2];
            double cz = e1[0] * e2[1] - e1[1] * e2[0];
            double a2 = cx * cx + cy * cy + cz * cz;
            area += 0.5 * sqrt(a2);
            bool collapsed = w[0] == w[1] || w[1] == w[2] || w[0] == w[2];
            if (collapsed || a2 == 0.0)
                degen++;
            for (int k = 0; k < 3; k++) {
                uint64_t a = w[k], c = w[(k + 1) % 3];
                keys[t * 3 + (size_t)k] = collapsed ? sentinel : (a < c ? a * W + c : c * W + a);
            }
        }
        block_area[b] = area;
        block_degen[b] = degen;
    }

    double area = 0.0;
    uint32_t degenerate = 0;
    for (size_t b = 0; b < nblocks; b++) {
        area += block_area[b];
        degenerate += block_degen[b];
    }

    int bits = 0;
    while (bits < 64 && (sentinel >> bits) != 0)
        bits++;
    const uint64_t *sorted = radix_sort_u64(keys, tmp, nt * 3, bits);
    uint64_t edges = 0, boundary = 0, nonmanifold = 0;
    for (size_t i = 0; i < nt * 3 && sorted[i] != sentinel;) {
        size_t j = i + 1;
        while (j < nt * 3 && sorted[j] == sorted[i])
            j++;
        edges++;
        if (j - i == 1)
            boundary++;
        else if (j - i >= 3)
            nonmanifold++;
        i = j;
    }

    float bmin[3] = {INFINITY, INFINITY, INFINITY}, bmax[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int k = 0; k < 3; k++) {
        float lo = INFINITY, hi = -INFINITY;
#pragma omp parallel for num_threads(ctx->threads) if (nv > NC_MESH_PARALLEL_MIN) \
    schedule(static) reduction(min : lo) reduction(max : hi)
        for (size_t v = 0; v < nv; v++) {
            float x = pos[v * 3 + (size_t)k];
            lo = x < lo ? x : lo;
            hi = x > hi ? x : hi;
        }
        bmin[k] = lo;
        bmax[k] = hi;
    }

    out->vertex_count = mesh->vertex_count;
    out->triangle_count = mesh->triangle_count;
    out->welded_vertex_count = welded;
    out->unreferenced_vertices = unreferenced;
    out->degenerate_triangles = degenerate;
    out->edge_count = edges;
    out->boundary_edges = boundary;
    out->nonmanifold_edges = nonmanifold;
    out->closed = boundary == 0 && nonmanifold == 0;
    memcpy(out->bounds_min, bmin, sizeof(bmin));
    memcpy(out->bounds_max, bmax, sizeof(bmax));
    out->surface_area = area;

out:
    nc_free(ctx, rep);
    nc_free(ctx, id);
    nc_free(ctx, used);
    nc_free(ctx, keys);
    nc_free(ctx, tmp);
    nc_free(ctx, block_area);
    nc_free(ctx, block_degen);
    return r;
}
