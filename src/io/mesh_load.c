/*
 * mesh_load.c: nacre_mesh_load: OBJ, PLY (ASCII and binary) and glTF 2.0 (.gltf, .glb) through
 * assimp's C API.
 *
 * Every mesh instance in the node tree is merged into one nacre_mesh_data with its node's global
 * transform applied: points by M, normals by the inverse transpose of M's 3x3 part, tangents and
 * bitangents by M (the handedness w is re-derived after the transform). A mirroring transform
 * (det < 0) reverses the corner order so triangles stay counter-clockwise seen from outside.
 * aiProcess_Triangulate fans polygons into triangles and aiProcess_SortByPType splits points and
 * lines off into meshes of their own, which are skipped. assimp's triangulation is an ear clipper
 * that takes time quadratic in a polygon's corners (a 200,000-corner face took 39 s) and loses
 * triangles on long polygons, so a file with a polygon of more than LOAD_ASSIMP_CORNERS_MAX corners
 * is triangulated here instead (triangulate_polygon): convex polygons (and those star-shaped
 * around their first corner) as fans, in linear time, others by ear clipping up to
 * LOAD_EAR_CORNERS_MAX corners; a longer one of those is an error that names the face. JoinIdenticalVertices is deliberately not
 * asked for: it costs seconds on million-triangle scans, and the normal and analysis code weld
 * exact duplicates themselves. So OBJ files come out with one vertex per face corner.
 *
 * Missing or unusable normals and tangents (zero length, non-finite, or absent in some of the
 * merged meshes) are computed by nacre_mesh_compute_normals / _tangents for those vertices only;
 * authored ones are kept. Bad positions, UVs or indices fail the load with NACRE_ERROR_PARSE.
 *
 * assimp 5.2 is not robust against broken files: it loops forever on a PLY header without
 * end_header, reads a truncated binary PLY's missing tail as garbage, allocates whatever an
 * ASCII PLY count says before reading the values, throws (and leaks) on a malformed ASCII
 * number or a late OBJ index out of range, and its triangulation indexes vertices through
 * unchecked faces. So the file is checked before assimp opens it (PLY header, ASCII PLY body,
 * OBJ indices) and the faces are checked before any post-processing; the error messages name the
 * file and, where known, the line. Files are imported with no post-processing first, then
 * triangulated with aiApplyPostProcessing.
 *
 * assimp keeps its last error in one process-wide string (aiGetErrorString), so two threads
 * loading broken files at the same time may read each other's message; nacre keeps no global
 * state of its own.
 */
#include "core/core.h"
#include "core/math.h"
#include "io/gltf.h"
#include "scene/mesh_private.h"

#include <assimp/cimport.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

/* assimp's own post-processing recurses over nodes too; a file nested deeper than this is not a
 * mesh anyone meant to write. */
#define LOAD_MAX_NODE_DEPTH 1024

/* Files whose polygons all have at most this many corners are triangulated by assimp (its
 * quadratic ear clipper is quick at this size); otherwise by triangulate_polygon. */
#define LOAD_ASSIMP_CORNERS_MAX 64
/* The largest polygon triangulate_polygon clips (quadratic time) when a fan does not fit it;
 * convex polygons may have any number of corners. */
#define LOAD_EAR_CORNERS_MAX 512

/* Bytes read ahead of assimp to check a PLY header (see check_ply_header). */
#define LOAD_HEAD_BYTES 65536

typedef struct load_instance {
    const struct aiMesh *mesh;
    nc_mat4 xf;             /* node's global transform */
    uint32_t first_vertex;  /* in the merged mesh */
    uint32_t first_triangle;
    uint32_t triangles;     /* faces with three corners */
    uint32_t node, slot;    /* preorder number of its node, its index in the node's mesh list */
} load_instance;

typedef struct load_state {
    nacre_context *ctx;
    const char *path;
    const struct aiScene *scene;
    load_instance *inst;
    uint32_t count, capacity;
    uint64_t vertices, triangles;
    double (*uv)[2]; /* triangulate_polygon's scratch for the longest polygon, or NULL */
    uint32_t *tri;
    uint32_t nodes;  /* nodes visited so far (preorder numbering) */
} load_state;

static nc_mat4 from_ai(const struct aiMatrix4x4 *a)
{
    nc_mat4 m = {{{(float)a->a1, (float)a->a2, (float)a->a3, (float)a->a4},
                  {(float)a->b1, (float)a->b2, (float)a->b3, (float)a->b4},
                  {(float)a->c1, (float)a->c2, (float)a->c3, (float)a->c4},
                  {(float)a->d1, (float)a->d2, (float)a->d3, (float)a->d4}}};
    return m;
}

static bool mesh_is_all_triangles(const struct aiMesh *mesh)
{
    return (mesh->mPrimitiveTypes & ~(unsigned)aiPrimitiveType_NGONEncodingFlag) ==
           aiPrimitiveType_TRIANGLE;
}

/* ------------------------------------------------------------------------------------------ */
/* Polygons with many corners                                                                 */
/* ------------------------------------------------------------------------------------------ */

/* The corners of a polygon projected onto the plane of its Newell normal, counter-clockwise
 * (positive area) in (u, v): the dominant axis of the normal is dropped, and u and v swapped when
 * that axis points backwards, so a left turn is convex. */
static void project_polygon(const struct aiVector3D *v, const unsigned *ix, unsigned n, double (*uv)[2])
{
    double nx = 0.0, ny = 0.0, nz = 0.0;
    for (unsigned i = 0; i < n; i++) {
        const struct aiVector3D *a = &v[ix[i]], *b = &v[ix[i + 1 == n ? 0 : i + 1]];
        nx += ((double)a->y - b->y) * ((double)a->z + b->z);
        ny += ((double)a->z - b->z) * ((double)a->x + b->x);
        nz += ((double)a->x - b->x) * ((double)a->y + b->y);
    }
    int axis = fabs(nx) > fabs(ny) ? (fabs(nx) > fabs(nz) ? 0 : 2) : (fabs(ny) > fabs(nz) ? 1 : 2);
    double sign = axis == 0 ? nx : axis == 1 ? ny : nz;
    for (unsigned i = 0; i < n; i++) {
        const struct aiVector3D *a = &v[ix[i]];
        double c[3] = {a->x, a->y, a->z};
        int u = (axis + 1) % 3, w = (axis + 2) % 3;
        if (sign < 0.0) {
            int t = u;
            u = w;
            w = t;
        }
        uv[i][0] = c[u];
        uv[i][1] = c[w];
    }
}

static inline double turn(const double *a, const double *b, const double *c)
{
    return (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0]);
}

/* Whether the fan from corner 0 triangulates the (projected) polygon: true for every convex
 * polygon and every one star-shaped around its first corner. Fan triangles that turn right
 * may hold at most a millionth of the area of those that turn left: a convex cap written with
 * rounded coordinates has slivers of either orientation next to corner 0. */
static bool fan_ok(const double (*uv)[2], unsigned n)
{
    double left = 0.0, right = 0.0;
    for (unsigned i = 1; i + 1 < n; i++) {
        double a = turn(uv[0], uv[i], uv[i + 1]);
        if (a >= 0.0)
            left += a;
        else
            right -= a;
    }
    return right <= 1e-6 * left;
}

static bool in_triangle(const double *p, const double *a, const double *b, const double *c)
{
    return turn(a, b, p) >= 0.0 && turn(b, c, p) >= 0.0 && turn(c, a, p) >= 0.0;
}

/* Triangulate one polygon of n >= 4 corners (face indices ix into v) into n - 2 triangles of
 * corner positions 0..n-1, written to tri. False if no fan fits it and it has more than
 * LOAD_EAR_CORNERS_MAX corners (then nothing is written). `uv` has room for n corners. */
static bool triangulate_polygon(const struct aiVector3D *v, const unsigned *ix, unsigned n, double (*uv)[2],
                                uint32_t *tri)
{
    project_polygon(v, ix, n, uv);
    if (fan_ok(uv, n)) {
        for (unsigned i = 1; i + 1 < n; i++) {
            tri[(i - 1) * 3] = 0;
            tri[(i - 1) * 3 + 1] = i;
            tri[(i - 1) * 3 + 2] = i + 1;
        }
        return true;
    }
    if (n > LOAD_EAR_CORNERS_MAX)
        return false;
    /* Ear clipping: a corner whose triangle with its neighbours turns left and holds no other
     * remaining reflex corner is cut off. A polygon that has no ear left (self-intersecting) has
     * its current corner cut anyway, so there are always n - 2 triangles. */
    uint16_t prev[LOAD_EAR_CORNERS_MAX], next[LOAD_EAR_CORNERS_MAX];
    for (unsigned i = 0; i < n; i++) {
        prev[i] = (uint16_t)(i == 0 ? n - 1 : i - 1);
        next[i] = (uint16_t)(i + 1 == n ? 0 : i + 1);
    }
    unsigned remaining = n, misses = 0, t = 0, i = 0;
    while (remaining > 3) {
        unsigned a = prev[i], c = next[i];
        bool ear = turn(uv[a], uv[i], uv[c]) > 0.0;
        for (unsigned j = next[c]; ear && j != a; j = next[j]) {
            if (turn(uv[prev[j]], uv[j], uv[next[j]]) > 0.0)
                continue; /* only reflex corners can lie inside an ear */
            const double *q = uv[j];
            bool shared = (q[0] == uv[a][0] && q[1] == uv[a][1]) || (q[0] == uv[i][0] && q[1] == uv[i][1]) ||
                          (q[0] == uv[c][0] && q[1] == uv[c][1]);
            if (!shared && in_triangle(q, uv[a], uv[i], uv[c]))
                ear = false;
        }
        if (!ear && ++misses <= remaining) {
            i = c;
            continue;
        }
        tri[t * 3] = a;
        tri[t * 3 + 1] = i;
        tri[t * 3 + 2] = c;
        t++;
        next[a] = (uint16_t)c;
        prev[c] = (uint16_t)a;
        remaining--;
        misses = 0;
        i = a;
    }
    tri[t * 3] = prev[i];
    tri[t * 3 + 1] = i;
    tri[t * 3 + 2] = next[i];
    return true;
}

/* Before post-processing: the most corners of any face, and (when that exceeds
 * LOAD_ASSIMP_CORNERS_MAX, so that triangulate_polygon will run) an error naming the first
 * non-convex face too long to clip. File face numbers, as in check_faces. */
static nacre_result check_polygons(nacre_context *ctx, const char *path, const struct aiScene *scene,
                                   unsigned *max_corners)
{
    *max_corners = 0;
    for (unsigned mi = 0; mi < scene->mNumMeshes; mi++) {
        const struct aiMesh *mesh = scene->mMeshes[mi];
        for (unsigned f = 0; mesh && f < mesh->mNumFaces; f++)
            if (mesh->mFaces[f].mNumIndices > *max_corners)
                *max_corners = mesh->mFaces[f].mNumIndices;
    }
    if (*max_corners <= LOAD_ASSIMP_CORNERS_MAX)
        return NACRE_OK;
    double(*uv)[2] = nc_alloc(ctx, (size_t)*max_corners * sizeof(*uv));
    if (!uv)
        return NACRE_ERROR_OUT_OF_MEMORY;
    nacre_result r = NACRE_OK;
    for (unsigned mi = 0; mi < scene->mNumMeshes && r == NACRE_OK; mi++) {
        const struct aiMesh *mesh = scene->mMeshes[mi];
        for (unsigned f = 0; mesh && f < mesh->mNumFaces && r == NACRE_OK; f++) {
            const struct aiFace *face = &mesh->mFaces[f];
            if (face->mNumIndices <= LOAD_EAR_CORNERS_MAX)
                continue;
            project_polygon(mesh->mVertices, face->mIndices, face->mNumIndices, uv);
            if (fan_ok(uv, face->mNumIndices))
                continue;
            char where[32] = "";
            if (scene->mNumMeshes > 1)
                snprintf(where, sizeof(where), "mesh %u: ", mi);
            r = nc_fail(ctx, NACRE_ERROR_UNSUPPORTED,
                        "%s: %sface %u: a non-convex polygon of %u corners (more than %d corners: it must be convex, "
                        "or star-shaped around its first corner; triangulate it before export)",
                        path, where, f, face->mNumIndices, LOAD_EAR_CORNERS_MAX);
        }
    }
    nc_free(ctx, uv);
    return r;
}

static nacre_result collect(load_state *s, const struct aiNode *node, nc_mat4 parent, int depth)
{
    if (depth > LOAD_MAX_NODE_DEPTH)
        return nc_fail(s->ctx, NACRE_ERROR_PARSE, "%s: node hierarchy deeper than %d", s->path,
                       LOAD_MAX_NODE_DEPTH);
    nc_mat4 local = from_ai(&node->mTransformation);
    nc_mat4 xf = nc_mat4_mul(parent, local);
    const uint32_t serial = s->nodes++;
    for (unsigned k = 0; k < node->mNumMeshes; k++) {
        unsigned mi = node->mMeshes[k];
        if (mi >= s->scene->mNumMeshes)
            return nc_fail(s->ctx, NACRE_ERROR_PARSE, "%s: node references mesh %u of %u",
                           s->path, mi, s->scene->mNumMeshes);
        const struct aiMesh *mesh = s->scene->mMeshes[mi];
        if (!mesh || !(mesh->mPrimitiveTypes & (aiPrimitiveType_TRIANGLE | aiPrimitiveType_POLYGON)) ||
            mesh->mNumVertices == 0 || !mesh->mVertices || !mesh->mFaces)
            continue;
        uint64_t tris = 0; /* polygons are left only when triangulate_polygon is to cut them */
        if (mesh_is_all_triangles(mesh)) {
            tris = mesh->mNumFaces;
        } else {
            for (unsigned f = 0; f < mesh->mNumFaces; f++)
                tris += mesh->mFaces[f].mNumIndices >= 3 ? mesh->mFaces[f].mNumIndices - 2 : 0;
        }
        if (tris == 0)
            continue;
        if (s->count == s->capacity) {
            uint32_t cap = s->capacity ? s->capacity * 2 : 16;
            load_instance *grown = nc_realloc(s->ctx, s->inst, s->capacity * sizeof(*grown),
                                              cap * sizeof(*grown));
            if (!grown)
                return NACRE_ERROR_OUT_OF_MEMORY;
            s->inst = grown;
            s->capacity = cap;
        }
        if (s->vertices + mesh->mNumVertices > UINT32_MAX)
            return nc_fail(s->ctx, NACRE_ERROR_UNSUPPORTED, "%s: more than %u vertices", s->path,
                           (unsigned)UINT32_MAX);
        if (s->triangles + tris > NC_MESH_MAX_TRIANGLES)
            return nc_fail(s->ctx, NACRE_ERROR_UNSUPPORTED, "%s: more than %u triangles", s->path,
                           (unsigned)NC_MESH_MAX_TRIANGLES);
        load_instance *in = &s->inst[s->count++];
        in->mesh = mesh;
        in->xf = xf;
        in->first_vertex = (uint32_t)s->vertices;
        in->first_triangle = (uint32_t)s->triangles;
        in->triangles = (uint32_t)tris;
        in->node = serial;
        in->slot = k;
        s->vertices += mesh->mNumVertices;
        s->triangles += tris;
    }
    for (unsigned c = 0; c < node->mNumChildren; c++) {
        if (!node->mChildren[c])
            continue;
        nacre_result r = collect(s, node->mChildren[c], xf, depth + 1);
        if (r != NACRE_OK)
            return r;
    }
    return NACRE_OK;
}

static bool is_identity(const nc_mat4 *m)
{
    nc_mat4 id = nc_mat4_identity();
    return memcmp(m, &id, sizeof(id)) == 0;
}

/* Inverse transpose of the 3x3 part (cofactor matrix; the 1/det scale is irrelevant because
 * normals are renormalised, but its sign matters, so it is kept). */
static nc_mat4 normal_matrix(const nc_mat4 *m, float *det_out)
{
    const float(*a)[4] = m->m;
    nc_mat4 c = nc_mat4_identity();
    c.m[0][0] = a[1][1] * a[2][2] - a[1][2] * a[2][1];
    c.m[0][1] = a[1][2] * a[2][0] - a[1][0] * a[2][2];
    c.m[0][2] = a[1][0] * a[2][1] - a[1][1] * a[2][0];
    c.m[1][0] = a[0][2] * a[2][1] - a[0][1] * a[2][2];
    c.m[1][1] = a[0][0] * a[2][2] - a[0][2] * a[2][0];
    c.m[1][2] = a[0][1] * a[2][0] - a[0][0] * a[2][1];
    c.m[2][0] = a[0][1] * a[1][2] - a[0][2] * a[1][1];
    c.m[2][1] = a[0][2] * a[1][0] - a[0][0] * a[1][2];
    c.m[2][2] = a[0][0] * a[1][1] - a[0][1] * a[1][0];
    float det = a[0][0] * c.m[0][0] + a[0][1] * c.m[0][1] + a[0][2] * c.m[0][2];
    *det_out = det;
    if (det < 0.0f)
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                c.m[i][j] = -c.m[i][j];
    return c;
}

/* Unit vector or NaN: NaN marks "compute this one" for the repair pass. A vector already of unit
 * length to within float rounding is kept bit for bit: dividing it by its computed length would
 * move it by an ulp, so a mesh that nacre wrote (nacre_scene_save_file writes meshes built from
 * raw arrays as PLY) would not reload identical. The tolerance is a few ulps of 1, far below
 * the precision of any authored normal that still needs normalising. */
static inline nc_vec3 unit_or_nan(nc_vec3 v)
{
    float len = nc_length(v);
    if (fabsf(len - 1.0f) <= 4.0f * FLT_EPSILON)
        return v;
    if (len > 0.0f && isfinite(len))
        return nc_scale(v, 1.0f / len);
    return nc_v3(NAN, NAN, NAN);
}

/* Copy one instance's vertices (transformed) into the merged arrays. */
static void fill_vertices(const load_state *s, const load_instance *in, nacre_mesh_data *m)
{
    const struct aiMesh *mesh = in->mesh;
    const size_t n = mesh->mNumVertices, v0 = in->first_vertex;
    const bool identity = is_identity(&in->xf);
    float det;
    const nc_mat4 nm = normal_matrix(&in->xf, &det);
    const nc_mat4 xf = in->xf;
    const struct aiVector3D *uv = mesh->mTextureCoords[0];
    const bool uv2 = mesh->mNumUVComponents[0] >= 2;
    const bool has_tangents = mesh->mTangents && mesh->mBitangents && mesh->mNormals;

#pragma omp parallel for num_threads(s->ctx->threads) if (n > NC_MESH_PARALLEL_MIN) \
    schedule(static)
    for (size_t i = 0; i < n; i++) {
        size_t v = v0 + i;
        nc_vec3 p = nc_v3((float)mesh->mVertices[i].x, (float)mesh->mVertices[i].y,
                          (float)mesh->mVertices[i].z);
        if (!identity)
            p = nc_mat4_point(&xf, p);
        nc_v3store(p, m->positions + v * 3);

        nc_vec3 n3 = nc_v3(NAN, NAN, NAN);
        if (m->normals) {
            if (mesh->mNormals) {
                n3 = nc_v3((float)mesh->mNormals[i].x, (float)mesh->mNormals[i].y,
                           (float)mesh->mNormals[i].z);
                n3 = unit_or_nan(identity ? n3 : nc_mat4_dir(&nm, n3));
            }
            nc_v3store(n3, m->normals + v * 3);
        }
        if (m->uvs) {
            m->uvs[v * 2] = uv ? (float)uv[i].x : 0.0f;
            m->uvs[v * 2 + 1] = uv && uv2 ? (float)uv[i].y : 0.0f;
        }
        if (m->tangents) {
            float *t4 = m->tangents + v * 4;
            nc_vec3 t = nc_v3(NAN, NAN, NAN);
            float w = 1.0f;
            if (has_tangents && isfinite(n3.x)) {
                nc_vec3 ta = nc_v3((float)mesh->mTangents[i].x, (float)mesh->mTangents[i].y,
                                   (float)mesh->mTangents[i].z);
                nc_vec3 bi = nc_v3((float)mesh->mBitangents[i].x, (float)mesh->mBitangents[i].y,
                                   (float)mesh->mBitangents[i].z);
                if (!identity) {
                    ta = nc_mat4_dir(&xf, ta);
                    bi = nc_mat4_dir(&xf, bi);
                }
                /* Authored tangents are not always perpendicular to the authored normal. */
                t = unit_or_nan(nc_sub(ta, nc_scale(n3, nc_dot(n3, ta))));
                w = nc_dot(nc_cross(n3, t), bi) < 0.0f ? -1.0f : 1.0f;
            }
            t4[0] = t.x;
            t4[1] = t.y;
            t4[2] = t.z;
            t4[3] = w;
        }
    }
}

/* Copy one instance's triangles. check_faces has vetted the file's faces, but triangulation
 * made new ones, and the merged arrays are indexed through these values: check again. */
static nacre_result fill_indices(const load_state *s, const load_instance *in, nacre_mesh_data *m)
{
    const struct aiMesh *mesh = in->mesh;
    const uint32_t nvm = mesh->mNumVertices, v0 = in->first_vertex;
    float det;
    normal_matrix(&in->xf, &det);
    /* A mirrored instance would turn inside out: swap two corners to keep outward winding. */
    const int c1 = det < 0.0f ? 2 : 1, c2 = det < 0.0f ? 1 : 2;
    uint32_t *out = m->indices + (size_t)in->first_triangle * 3;
    uint64_t bad = UINT64_MAX;

    if (mesh_is_all_triangles(mesh)) {
        const size_t nf = mesh->mNumFaces;
#pragma omp parallel for num_threads(s->ctx->threads) if (nf > NC_MESH_PARALLEL_MIN) \
    schedule(static) reduction(min : bad)
        for (size_t f = 0; f < nf; f++) {
            const struct aiFace *face = &mesh->mFaces[f];
            uint32_t *o = out + f * 3;
            if (face->mNumIndices != 3 || !face->mIndices) {
                o[0] = o[1] = o[2] = v0; /* cannot happen for a triangle-only mesh */
                continue;
            }
            const unsigned *ix = face->mIndices;
            if ((ix[0] >= nvm || ix[1] >= nvm || ix[2] >= nvm) && f < bad)
                bad = f;
            o[0] = v0 + ix[0];
            o[1] = v0 + ix[c1];
            o[2] = v0 + ix[c2];
        }
    } else {
        size_t t = 0;
        for (unsigned f = 0; f < mesh->mNumFaces; f++) {
            const struct aiFace *face = &mesh->mFaces[f];
            const unsigned n = face->mNumIndices;
            if (n < 3 || !face->mIndices)
                continue;
            const unsigned *ix = face->mIndices;
            if (n > 3) {
                /* Only when the file had a long polygon (check_polygons vetted it). */
                bool in_range = s->uv != NULL;
                for (unsigned k = 0; k < n && in_range; k++)
                    in_range = ix[k] < nvm;
                if (!in_range || !triangulate_polygon(mesh->mVertices, ix, n, s->uv, s->tri))
                    return nc_fail(s->ctx, NACRE_ERROR_PARSE, "%s: polygon of %u corners: cannot triangulate",
                                   s->path, n);
                for (unsigned k = 0; k + 2 < n; k++, t++) {
                    out[t * 3] = v0 + ix[s->tri[k * 3]];
                    out[t * 3 + 1] = v0 + ix[s->tri[k * 3 + (unsigned)c1]];
                    out[t * 3 + 2] = v0 + ix[s->tri[k * 3 + (unsigned)c2]];
                }
                continue;
            }
            if ((ix[0] >= nvm || ix[1] >= nvm || ix[2] >= nvm) && bad == UINT64_MAX)
                bad = t;
            out[t * 3] = v0 + ix[0];
            out[t * 3 + 1] = v0 + ix[c1];
            out[t * 3 + 2] = v0 + ix[c2];
            t++;
        }
    }
    if (bad == UINT64_MAX)
        return NACRE_OK;
    /* Report the file's own numbers: the triangle in the merged mesh, the raw index and the
     * vertex count of the mesh it belongs to. */
    const uint32_t *o = out + bad * 3;
    uint32_t raw = 0;
    for (int k = 2; k >= 0; k--)
        if (o[k] - v0 >= nvm)
            raw = o[k] - v0; /* unsigned wrap-around gives back the file's index */
    return nc_fail(s->ctx, NACRE_ERROR_PARSE,
                   "%s: triangle %llu: index %u out of range (vertex_count %u)", s->path,
                   (unsigned long long)(in->first_triangle + bad), (unsigned)raw, (unsigned)nvm);
}

/* Replace the NaN-marked entries of `dst` (dim floats per vertex) by those of `src`; true if
 * any entry is marked. With src NULL only reports. */
static bool repair(const nacre_context *ctx, float *dst, const float *src, size_t nv, int dim)
{
    int any = 0;
#pragma omp parallel for num_threads(ctx->threads) if (nv > NC_MESH_PARALLEL_MIN) \
    schedule(static) reduction(| : any)
    for (size_t v = 0; v < nv; v++) {
        float *d = dst + v * (size_t)dim;
        if (!isnan(d[0]))
            continue;
        any = 1;
        if (src)
            memcpy(d, src + v * (size_t)dim, (size_t)dim * sizeof(float));
    }
    return any != 0;
}

/* Compute normals (which = 0) or tangents (which = 1) into a scratch copy and patch the
 * vertices the file left without a usable one. */
static nacre_result complete_attribute(nacre_context *ctx, nacre_mesh_data *m, int which)
{
    float *dst = which == 0 ? m->normals : m->tangents;
    const int dim = which == 0 ? 3 : 4;
    if (!repair(ctx, dst, NULL, m->vertex_count, dim))
        return NACRE_OK;
    nacre_mesh_data tmp = *m;
    nacre_result r;
    if (which == 0) {
        tmp.normals = NULL;
        r = nacre_mesh_compute_normals(ctx, &tmp);
    } else {
        tmp.tangents = NULL;
        r = nacre_mesh_compute_tangents(ctx, &tmp);
    }
    if (r != NACRE_OK)
        return r;
    float *computed = which == 0 ? tmp.normals : tmp.tangents;
    repair(ctx, dst, computed, m->vertex_count, dim);
    nc_free(ctx, computed);
    return NACRE_OK;
}

/* Size in bytes of a PLY scalar type name, 0 if unknown. */
static unsigned ply_type_size(const char *t, size_t n)
{
    static const struct { const char *name; unsigned size; } types[] = {
        {"char", 1},   {"uchar", 1},  {"int8", 1},    {"uint8", 1},   {"short", 2},
        {"ushort", 2}, {"int16", 2},  {"uint16", 2},  {"int", 4},     {"uint", 4},
        {"int32", 4},  {"uint32", 4}, {"float", 4},   {"float32", 4}, {"double", 8},
        {"float64", 8},
    };
    for (size_t i = 0; i < sizeof(types) / sizeof(types[0]); i++)
        if (strlen(types[i].name) == n && memcmp(types[i].name, t, n) == 0)
            return types[i].size;
    return 0;
}

/* Split the next whitespace-separated word off [*p, end). */
static bool next_word(const char **p, const char *end, const char **w, size_t *n)
{
    const char *s = *p;
    while (s < end && (*s == ' ' || *s == '\t' || *s == '\r'))
        s++;
    const char *e = s;
    while (e < end && *e != ' ' && *e != '\t' && *e != '\r')
        e++;
    *w = s;
    *n = (size_t)(e - s);
    *p = e;
    return e > s;
}

static bool word_is(const char *w, size_t n, const char *lit)
{
    return strlen(lit) == n && memcmp(w, lit, n) == 0;
}

/* What check_ply_header learns for the ASCII body check: where the body starts and which
 * properties are lists, per element (up to the limits below; beyond them only the number syntax
 * is checked). */
#define PLY_MAX_ELEMENTS 16
#define PLY_MAX_PROPERTIES 32

typedef struct ply_layout {
    uint64_t body;     /* byte offset of an ASCII body; 0 if binary or not PLY */
    int header_lines;
    bool known;        /* the element table below is complete */
    int elements;
    uint64_t count[PLY_MAX_ELEMENTS];
    int properties[PLY_MAX_ELEMENTS];
    bool is_list[PLY_MAX_ELEMENTS][PLY_MAX_PROPERTIES];
    bool is_corners[PLY_MAX_ELEMENTS][PLY_MAX_PROPERTIES]; /* vertex_indices lists */
    uint64_t short_need; /* ASCII body shorter than its counts need (bytes needed); the body check
                            runs first, so a face with too few indices is named as such */
} ply_layout;

/* count <= 2^40 and record <= 4096 keep each term below 2^52; many elements could still add up
 * past 2^64, and any sum this large exceeds every file anyway. */
static inline uint64_t add_capped(uint64_t a, uint64_t b)
{
    return a + b < a || a + b > ((uint64_t)1 << 62) ? ((uint64_t)1 << 62) : a + b;
}

/* Checks on a PLY header before assimp sees the file (other files pass untouched):
 *  - assimp 5.2 loops forever on a header without "end_header", so one must be found within
 *    the bytes read (LOAD_HEAD_BYTES; real headers are a few hundred bytes);
 *  - binary PLY carries no end marker, and assimp reads a truncated file's missing tail as
 *    garbage (whose indices then crash its triangulation), so the size the header promises is
 *    checked. Vertex index lists count as at least 3 items (a face), which is exact for triangle
 *    meshes and a lower bound otherwise; other lists as at least 0;
 *  - assimp reserves memory for the element counts of an ASCII header before reading a value,
 *    so "element vertex 99999999999" in a small file would take gigabytes: every ASCII value
 *    needs at least a digit and a separator, which bounds the counts by the file size.
 * Header lines this does not understand are left to assimp. */
static nacre_result check_ply_header(nacre_context *ctx, const char *path, const char *head,
                                     size_t len, uint64_t file_size, ply_layout *layout)
{
    memset(layout, 0, sizeof(*layout));
    layout->known = true;
    /* assimp's own test: the first three letters are p, l, y in any case ("pLy=" passes too). */
    if (len < 3 || (head[0] | 0x20) != 'p' || (head[1] | 0x20) != 'l' || (head[2] | 0x20) != 'y')
        return NACRE_OK; /* not a PLY file */
    const char *p = head, *end = head + len;
    bool binary = false, sized = true; /* sized: every element's record size is known */
    uint64_t need = 0, count = 0, record = 0;     /* binary bytes */
    uint64_t need_text = 0, fields = 0;           /* ASCII values */
    int line = 0;
    while (p < end) {
        const char *eol = memchr(p, '\n', (size_t)(end - p));
        if (!eol)
            break;
        const char *q = p, *w;
        size_t n;
        line++;
        bool has = next_word(&q, eol, &w, &n);
        if (has && word_is(w, n, "format")) {
            binary = next_word(&q, eol, &w, &n) && (word_is(w, n, "binary_little_endian") ||
                                                     word_is(w, n, "binary_big_endian"));
        } else if (has && word_is(w, n, "element")) {
            need = add_capped(need, sized ? count * record : 0);
            need_text = add_capped(need_text, count * fields);
            char num[32];
            if (!next_word(&q, eol, &w, &n) || !next_word(&q, eol, &w, &n) || n >= sizeof(num)) {
                sized = layout->known = false;
                goto next_line;
            }
            memcpy(num, w, n);
            num[n] = '\0';
            char *stop;
            errno = 0;
            unsigned long long c = strtoull(num, &stop, 10);
            if (*stop != '\0' || errno) {
                sized = layout->known = false;
                goto next_line;
            }
            count = c;
            record = 0;
            fields = 0;
            if (layout->elements < PLY_MAX_ELEMENTS)
                layout->count[layout->elements++] = count;
            else
                layout->known = false;
            /* Any count beyond this cannot fit in a file, let alone in 32-bit indices. */
            if (count > ((uint64_t)1 << 40))
                return nc_fail(ctx, NACRE_ERROR_PARSE, "%s:%d: element count %llu too large",
                               path, line, (unsigned long long)count);
        } else if (has && word_is(w, n, "property")) {
            unsigned size = 0;
            fields++;
            bool list = next_word(&q, eol, &w, &n) && word_is(w, n, "list");
            int e = layout->elements - 1, pi = -1;
            if (e < 0 || layout->properties[e] >= PLY_MAX_PROPERTIES)
                layout->known = false;
            else
                layout->is_list[e][pi = layout->properties[e]++] = list;
            if (list) {
                const char *ct, *it, *name;
                size_t cn, in, nn;
                if (next_word(&q, eol, &ct, &cn) && next_word(&q, eol, &it, &in) &&
                    next_word(&q, eol, &name, &nn)) {
                    unsigned cs = ply_type_size(ct, cn), is = ply_type_size(it, in);
                    bool corners = word_is(name, nn, "vertex_indices") ||
                                   word_is(name, nn, "vertex_index");
                    /* An unknown type would leave the body's size unchecked, and assimp then
                     * sizes its arrays from the counts alone (tens of GB from a small file). */
                    if (!cs || !is)
                        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s:%d: unknown PLY list type '%.*s %.*s'",
                                       path, line, (int)(cn < 32 ? cn : 32), ct, (int)(in < 32 ? in : 32), it);
                    size = cs + (corners ? 3u * is : 0u);
                    fields += corners ? 3u : 0u;
                    if (corners && pi >= 0)
                        layout->is_corners[e][pi] = true;
                }
            } else {
                size = ply_type_size(w, n);
                if (size == 0)
                    return nc_fail(ctx, NACRE_ERROR_PARSE, "%s:%d: unknown PLY property type '%.*s'", path, line,
                                   (int)(n < 32 ? n : 32), w);
            }
            if (size == 0)
                sized = false;
            record += size;
            if (record > 4096)
                record = 4096; /* still a lower bound on the record's size */
            if (fields > 4096)
                fields = 4096; /* keeps count * fields below 2^52; still a valid lower bound */
        } else if (has && word_is(w, n, "end_header")) {
            uint64_t header = (uint64_t)(eol + 1 - head);
            if (!binary) {
                layout->body = header;
                layout->header_lines = line;
                /* "v v ... v\n" per record: two bytes per value, the last newline optional */
                need_text = add_capped(need_text, count * fields);
                need_text = need_text ? add_capped(header, 2 * need_text - 1) : header;
                if (file_size < need_text)
                    layout->short_need = need_text; /* reported after the body check */
                return NACRE_OK;
            }
            if (!sized)
                return NACRE_OK;
            need = add_capped(need, count * record + header);
            if (file_size < need)
                return nc_fail(ctx, NACRE_ERROR_PARSE,
                               "%s: truncated binary PLY: the header needs at least %llu bytes, "
                               "the file has %llu",
                               path, (unsigned long long)need, (unsigned long long)file_size);
            return NACRE_OK;
        }
    next_line:
        p = eol + 1;
    }
    if (len < file_size)
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: PLY header longer than %zu bytes", path, len);
    return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: PLY header has no end_header line", path);
}

/* Case-insensitive comparison of the first strlen(lit) chars of t with lowercase `lit`. */
static bool strncasecmp_ascii(const char *t, const char *lit)
{
    for (; *lit; t++, lit++)
        if ((*t | 0x20) != *lit)
            return false;
    return true;
}

/* Whether an ASCII PLY token is a number assimp's fast_atoreal_move reads whole without
 * throwing: [+-]? then nan / inf / infinity, or digits with an optional fraction ('.' or ','
 * before a digit) and an exponent that has digits. */
static bool ply_number_ok(const char *t, size_t n)
{
    size_t i = 0;
    if (i < n && (t[i] == '+' || t[i] == '-'))
        i++;
    if (n - i == 3 && (strncasecmp_ascii(t + i, "nan") || strncasecmp_ascii(t + i, "inf")))
        return true;
    if (n - i == 8 && strncasecmp_ascii(t + i, "infinity"))
        return true;
    size_t digits = 0;
    while (i < n && t[i] >= '0' && t[i] <= '9')
        i++, digits++;
    if (i < n && (t[i] == '.' || t[i] == ',')) {
        i++;
        size_t frac = 0;
        while (i < n && t[i] >= '0' && t[i] <= '9')
            i++, frac++;
        if (t[i - 1 - frac] == ',' && frac == 0)
            return false; /* a trailing comma is not eaten like a trailing dot */
        digits += frac;
    }
    if (digits == 0)
        return false;
    if (i < n && (t[i] == 'e' || t[i] == 'E')) {
        i++;
        if (i < n && (t[i] == '+' || t[i] == '-'))
            i++;
        size_t exp = 0;
        while (i < n && t[i] >= '0' && t[i] <= '9')
            i++, exp++;
        if (exp == 0)
            return false;
    }
    return i == n;
}

/* Where the body scan is in the PLY's element table: assimp reads one instance per non-blank
 * line and, for a list, resizes its value array to the count token before reading the items. */
typedef struct ply_cursor {
    const ply_layout *layout;
    int element, property;
    uint64_t instance;
    uint64_t items;    /* list items still to come on this line */
    bool line_used;
} ply_cursor;

static void ply_next_element(ply_cursor *c)
{
    while (c->element < c->layout->elements && c->instance >= c->layout->count[c->element]) {
        c->element++;
        c->instance = 0;
    }
}

/* The value assimp's strtoul10 gives a (syntax-checked) token, saturated. */
static uint64_t ply_leading_uint(const char *t, size_t n)
{
    uint64_t v = 0;
    size_t i = (n > 0 && t[0] == '+') ? 1 : 0;
    for (; i < n && t[i] >= '0' && t[i] <= '9'; i++)
        v = v > UINT64_MAX / 100 ? UINT64_MAX / 100 : v * 10 + (uint64_t)(t[i] - '0');
    return v;
}

/* assimp's ASCII PLY reader throws on a malformed number and leaks what it had built (5.2), and
 * it allocates a list's values before reading them, so a count like 4294967295 takes 32 GB.
 * Every token of the body is checked first: its number syntax, and for list counts (when the
 * header's layout is known) a size the file could hold, at least two bytes per item. One pass
 * over the file in `buf`-sized chunks. */
static nacre_result check_ply_ascii_body(nacre_context *ctx, const char *path, FILE *f,
                                         const ply_layout *layout, uint64_t file_size, char *buf,
                                         size_t cap)
{
    if (fseek(f, (long)layout->body, SEEK_SET) != 0)
        return NACRE_OK; /* let assimp report it */
    ply_cursor cur = {layout, 0, 0, 0, 0, false};
    ply_next_element(&cur);
    char tok[64];
    size_t n = 0;
    bool long_token = false;
    int line = layout->header_lines + 1; /* the body starts on the line after end_header */
    for (;;) {
        size_t got = fread(buf, 1, cap, f);
        bool eof = got == 0; /* one more pass with a newline ends the last token and line */
        for (size_t i = 0; i < got || (eof && i == 0); i++) {
            char c = eof ? '\n' : buf[i];
            bool space = c == ' ' || c == '\t' || c == '\r' || c == '\n';
            if (!space) {
                if ((unsigned char)c < 0x20 || c == 0x7f)
                    return nc_fail(ctx, NACRE_ERROR_PARSE,
                                   "%s:%d: control character 0x%02x in ASCII PLY data", path, line,
                                   (unsigned)(unsigned char)c);
                if (n < sizeof(tok))
                    tok[n++] = (unsigned char)c < 0x80 ? c : '?';
                else
                    long_token = true;
                continue;
            }
            if (n > 0) {
                if (long_token || !ply_number_ok(tok, n))
                    return nc_fail(ctx, NACRE_ERROR_PARSE, "%s:%d: not a number: \"%.*s%s\"",
                                   path, line, (int)(n < 32 ? n : 32), tok, n > 32 ? "..." : "");
                cur.line_used = true;
                if (cur.items > 0) {
                    cur.items--;
                } else if (layout->known && cur.element < layout->elements &&
                           cur.property < layout->properties[cur.element]) {
                    if (layout->is_list[cur.element][cur.property]) {
                        uint64_t items = ply_leading_uint(tok, n);
                        if (items < 3 && layout->is_corners[cur.element][cur.property])
                            return nc_fail(ctx, NACRE_ERROR_PARSE,
                                           "%s:%d: face %llu has %llu ind%s (need at least 3)", path, line,
                                           (unsigned long long)cur.instance, (unsigned long long)items,
                                           items == 1 ? "ex" : "ices");
                        if (items > file_size / 2)
                            return nc_fail(ctx, NACRE_ERROR_PARSE,
                                           "%s:%d: a list of %llu items cannot fit in the file",
                                           path, line, (unsigned long long)items);
                        cur.items = items;
                    }
                    cur.property++;
                }
            }
            n = 0;
            long_token = false;
            if (c == '\n') {
                line++;
                if (cur.line_used) {
                    cur.instance++;
                    ply_next_element(&cur);
                }
                cur.property = 0;
                cur.items = 0;
                cur.line_used = false;
            }
        }
        if (eof)
            return NACRE_OK;
    }
}

/* OBJ index check. assimp 5.2 resolves face indices only when it builds its meshes, after the
 * whole file is parsed, and an out-of-range index thrown there leaks every mesh built before it;
 * so indices are checked here first. Positive indices count from the start of the file and must
 * not exceed the file's total; negative ones count back from the current line and must not reach
 * before the first element. Lines other than v, vt, vn, f, l and p are skipped. */
typedef struct obj_scan {
    uint64_t count[3]; /* v, vt, vn seen so far */
    uint64_t max[3];   /* largest positive index used */
    int max_line[3];
    int line;
    int kind;          /* of the current line: 0..2 an element, 3 a face/line/point, -1 other */
    bool first;        /* next token is the line's keyword */
} obj_scan;

static const char *const obj_kind_name[3] = {"vertices", "texture coordinates", "normals"};

/* One token of an f/l/p line: "v", "v/vt", "v//vn" or "v/vt/vn". */
static nacre_result obj_face_token(nacre_context *ctx, const char *path, obj_scan *s,
                                   const char *t, size_t n)
{
    size_t i = 0;
    for (int k = 0; k < 3 && i <= n; k++) {
        bool neg = i < n && t[i] == '-';
        size_t j = i + (neg ? 1 : 0), digits = 0;
        uint64_t v = 0;
        while (j < n && t[j] >= '0' && t[j] <= '9' && digits < 19) {
            v = v * 10 + (uint64_t)(t[j] - '0');
            j++;
            digits++;
        }
        bool whole = digits > 0 && (j == n || t[j] == '/');
        if (whole && v > 0) {
            if (neg && v > s->count[k])
                return nc_fail(ctx, NACRE_ERROR_PARSE,
                               "%s:%d: index -%llu reaches before the first of %llu %s", path,
                               s->line, (unsigned long long)v, (unsigned long long)s->count[k],
                               obj_kind_name[k]);
            if (!neg && v > s->max[k]) {
                s->max[k] = v;
                s->max_line[k] = s->line;
            }
        }
        while (j < n && t[j] != '/')
            j++;
        i = j + 1;
    }
    return NACRE_OK;
}

static nacre_result obj_token(nacre_context *ctx, const char *path, obj_scan *s, const char *t,
                              size_t n)
{
    if (s->first) {
        s->first = false;
        s->kind = -1;
        if (n == 1 && t[0] == 'v')
            s->kind = 0;
        else if (n == 2 && t[0] == 'v' && t[1] == 't')
            s->kind = 1;
        else if (n == 2 && t[0] == 'v' && t[1] == 'n')
            s->kind = 2;
        else if (n == 1 && (t[0] == 'f' || t[0] == 'l' || t[0] == 'p'))
            s->kind = 3;
        if (s->kind >= 0 && s->kind < 3)
            s->count[s->kind]++;
        return NACRE_OK;
    }
    return s->kind == 3 ? obj_face_token(ctx, path, s, t, n) : NACRE_OK;
}

static nacre_result check_obj_indices(nacre_context *ctx, const char *path, FILE *f, char *buf,
                                      size_t cap)
{
    if (fseek(f, 0, SEEK_SET) != 0)
        return NACRE_OK;
    obj_scan s;
    memset(&s, 0, sizeof(s));
    s.line = 1;
    s.first = true;
    char tok[64];
    size_t n = 0;
    bool comment = false;
    nacre_result r = NACRE_OK;
    for (;;) {
        size_t got = fread(buf, 1, cap, f);
        bool eof = got == 0;
        for (size_t i = 0; i < got || (eof && i == 0); i++) {
            char c = eof ? '\n' : buf[i];
            bool space = c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == '\0';
            if (!space && !comment) {
                if (c == '#' && n == 0) {
                    comment = true;
                    continue;
                }
                if (n < sizeof(tok))
                    tok[n++] = c;
                continue;
            }
            if (n > 0 && !comment) {
                /* Tokens longer than tok are cut; no real index is that long. */
                if ((r = obj_token(ctx, path, &s, tok, n)) != NACRE_OK)
                    return r;
            }
            n = 0;
            if (c == '\n') {
                s.line++;
                s.first = true;
                comment = false;
            }
        }
        if (eof)
            break;
    }
    for (int k = 0; k < 3; k++)
        if (s.max[k] > s.count[k])
            return nc_fail(ctx, NACRE_ERROR_PARSE, "%s:%d: index %llu out of range (%llu %s)",
                           path, s.max_line[k], (unsigned long long)s.max[k],
                           (unsigned long long)s.count[k], obj_kind_name[k]);
    return NACRE_OK;
}

static bool has_extension(const char *path, const char *ext)
{
    size_t n = strlen(path), e = strlen(ext);
    if (n < e)
        return false;
    for (size_t i = 0; i < e; i++)
        if ((path[n - e + i] | 0x20) != ext[i])
            return false;
    return true;
}

/* Before any post-processing: assimp's triangulation indexes vertices through the faces without
 * checking, so a corrupt face must be caught here. Reports the file's own face numbers. */
static nacre_result check_faces(nacre_context *ctx, const char *path, const struct aiScene *scene)
{
    for (unsigned mi = 0; mi < scene->mNumMeshes; mi++) {
        const struct aiMesh *mesh = scene->mMeshes[mi];
        if (!mesh || mesh->mNumFaces == 0)
            continue;
        if (!mesh->mFaces || (mesh->mNumVertices > 0 && !mesh->mVertices))
            return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: mesh %u: missing vertex or face data",
                           path, mi);
        const uint32_t nvm = mesh->mNumVertices;
        const size_t nf = mesh->mNumFaces;
        uint64_t bad = UINT64_MAX;
#pragma omp parallel for num_threads(ctx->threads) if (nf > NC_MESH_PARALLEL_MIN) \
    schedule(static) reduction(min : bad)
        for (size_t f = 0; f < nf; f++) {
            const struct aiFace *face = &mesh->mFaces[f];
            bool ok = face->mNumIndices > 0 && face->mIndices;
            for (unsigned k = 0; ok && k < face->mNumIndices; k++)
                ok = face->mIndices[k] < nvm;
            if (!ok && f < bad)
                bad = f;
        }
        if (bad == UINT64_MAX)
            continue;
        const struct aiFace *face = &mesh->mFaces[bad];
        char where[32] = "";
        if (scene->mNumMeshes > 1)
            snprintf(where, sizeof(where), "mesh %u: ", mi);
        if (face->mNumIndices == 0 || !face->mIndices)
            return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: %sface %llu: no vertices", path, where,
                           (unsigned long long)bad);
        unsigned k = 0;
        while (face->mIndices[k] < nvm)
            k++;
        return nc_fail(ctx, NACRE_ERROR_PARSE,
                       "%s: %sface %llu: index %u out of range (vertex_count %u)", path, where,
                       (unsigned long long)bad, face->mIndices[k], (unsigned)nvm);
    }
    return NACRE_OK;
}

/* Read a mesh file through assimp: the checks before assimp opens it, the import, the face
 * checks, triangulation, and the list of mesh instances in the node tree (s->inst). On failure
 * nothing is left to free. */
static nacre_result open_scene(nacre_context *ctx, const char *path, load_state *s)
{
    /* assimp's own message for a missing file is vague; ask the OS first. */
    FILE *f = fopen(path, "rb");
    if (!f)
        return nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot open: %s", path, strerror(errno));
    struct stat st;
    if (fstat(fileno(f), &st) == 0 && S_ISDIR(st.st_mode)) {
        fclose(f); /* fopen opens a folder for reading; every read then fails */
        return nc_fail(ctx, NACRE_ERROR_IO, "%s: is a directory, not a mesh file", path);
    }
    char *head = nc_alloc(ctx, LOAD_HEAD_BYTES);
    if (!head) {
        fclose(f);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    size_t head_len = fread(head, 1, LOAD_HEAD_BYTES, f);
    uint64_t file_size = 0;
    if (fseek(f, 0, SEEK_END) == 0) {
        long end = ftell(f);
        file_size = end > 0 ? (uint64_t)end : 0;
    }
    ply_layout layout = {0};
    nacre_result r = head_len == 0 ? nc_fail(ctx, NACRE_ERROR_PARSE, "%s: empty file", path)
                                   : check_ply_header(ctx, path, head, head_len, file_size, &layout);
    if (r == NACRE_OK && layout.body)
        r = check_ply_ascii_body(ctx, path, f, &layout, file_size, head, LOAD_HEAD_BYTES);
    if (r == NACRE_OK && layout.short_need)
        r = nc_fail(ctx, NACRE_ERROR_PARSE,
                    "%s: truncated ASCII PLY: the header's element counts need at least %llu bytes, the file has %llu",
                    path, (unsigned long long)layout.short_need, (unsigned long long)file_size);
    if (r == NACRE_OK && has_extension(path, ".obj"))
        r = check_obj_indices(ctx, path, f, head, LOAD_HEAD_BYTES);
    fclose(f);
    nc_free(ctx, head);
    if (r != NACRE_OK)
        return r;

    /* A glTF's counts and offsets are checked against its buffers first (nc_gltf_check). */
    if (nc_gltf_is_path(path) && (r = nc_gltf_check(ctx, path)) != NACRE_OK)
        return r;
    /* Import without post-processing, check the faces, then triangulate (see check_faces). */
    const struct aiScene *scene = aiImportFile(path, 0);
    if (!scene) {
        const char *msg = aiGetErrorString();
        size_t len = msg ? strlen(msg) : 0;
        while (len > 0 && (msg[len - 1] == '\n' || msg[len - 1] == '\r' || msg[len - 1] == ' '))
            len--;
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: %.*s", path, (int)len,
                       len ? msg : "cannot parse");
    }
    unsigned max_corners = 0;
    if ((r = check_faces(ctx, path, scene)) != NACRE_OK ||
        (r = check_polygons(ctx, path, scene, &max_corners)) != NACRE_OK) {
        aiReleaseImport(scene);
        return r;
    }
    const bool own_triangulation = max_corners > LOAD_ASSIMP_CORNERS_MAX;
    scene = aiApplyPostProcessing(scene, own_triangulation ? aiProcess_SortByPType
                                                           : aiProcess_Triangulate | aiProcess_SortByPType);
    if (!scene)
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: triangulation failed", path);

    *s = (load_state){ctx, path, scene, NULL, 0, 0, 0, 0, NULL, NULL, 0};
    if (own_triangulation) {
        s->uv = nc_alloc(ctx, (size_t)max_corners * sizeof(*s->uv));
        s->tri = nc_calloc(ctx, (size_t)max_corners, 3 * sizeof(uint32_t));
        if (!s->uv || !s->tri) {
            r = NACRE_ERROR_OUT_OF_MEMORY;
            goto fail;
        }
    }
    if (scene->mRootNode)
        r = collect(s, scene->mRootNode, nc_mat4_identity(), 0);
    if (r != NACRE_OK)
        goto fail;
    if (s->count == 0 || s->triangles == 0) {
        r = nc_fail(ctx, NACRE_ERROR_PARSE, "%s: mesh has no triangles", path);
        goto fail;
    }
    return NACRE_OK;
fail:
    aiReleaseImport(scene);
    nc_free(ctx, s->inst);
    nc_free(ctx, s->uv);
    nc_free(ctx, s->tri);
    memset(s, 0, sizeof(*s));
    return r;
}

static void close_scene(load_state *s)
{
    if (s->scene)
        aiReleaseImport(s->scene);
    nc_free(s->ctx, s->inst);
    nc_free(s->ctx, s->uv);
    nc_free(s->ctx, s->tri);
    s->scene = NULL;
    s->inst = NULL;
    s->uv = NULL;
    s->tri = NULL;
}

/* Build one mesh from instances [begin, end) of s->inst, numbered from vertex and triangle 0,
 * and complete it (geometry check, missing normals and tangents). */
static nacre_result build_mesh(load_state *s, uint32_t begin, uint32_t end, nacre_mesh_data *out)
{
    nacre_context *ctx = s->ctx;
    nacre_mesh_data m;
    memset(&m, 0, sizeof(m));
    bool any_normals = false, any_uvs = false, any_tangents = false;
    uint64_t nv64 = 0, nt64 = 0;
    for (uint32_t i = begin; i < end; i++) {
        const struct aiMesh *mesh = s->inst[i].mesh;
        any_normals |= mesh->mNormals != NULL;
        any_uvs |= mesh->mTextureCoords[0] != NULL;
        any_tangents |= mesh->mTangents && mesh->mBitangents && mesh->mNormals;
        s->inst[i].first_vertex = (uint32_t)nv64;
        s->inst[i].first_triangle = (uint32_t)nt64;
        nv64 += mesh->mNumVertices;
        nt64 += s->inst[i].triangles;
    }
    const size_t nv = (size_t)nv64, nt = (size_t)nt64;
    nacre_result r = NACRE_OK;
    m.vertex_count = (uint32_t)nv;
    m.triangle_count = (uint32_t)nt;
    m.positions = nc_alloc(ctx, nv * 3 * sizeof(float));
    m.indices = nc_alloc(ctx, nt * 3 * sizeof(uint32_t));
    if (any_normals)
        m.normals = nc_alloc(ctx, nv * 3 * sizeof(float));
    if (any_uvs)
        m.uvs = nc_alloc(ctx, nv * 2 * sizeof(float));
    if (any_tangents)
        m.tangents = nc_alloc(ctx, nv * 4 * sizeof(float));
    if (!m.positions || !m.indices || (any_normals && !m.normals) || (any_uvs && !m.uvs) ||
        (any_tangents && !m.tangents)) {
        r = NACRE_ERROR_OUT_OF_MEMORY;
        goto fail;
    }
    for (uint32_t i = begin; i < end; i++) {
        fill_vertices(s, &s->inst[i], &m);
        if ((r = fill_indices(s, &s->inst[i], &m)) != NACRE_OK)
            goto fail;
    }
    /* Indices were checked per instance; this checks finite positions and UVs. */
    r = nc_mesh_check_geometry(ctx, &m, s->path, NACRE_ERROR_PARSE);
    if (r != NACRE_OK)
        goto fail;
    if (!m.normals)
        r = nacre_mesh_compute_normals(ctx, &m);
    else
        r = complete_attribute(ctx, &m, 0);
    if (r != NACRE_OK)
        goto fail;
    if (!m.tangents)
        r = nacre_mesh_compute_tangents(ctx, &m);
    else
        r = complete_attribute(ctx, &m, 1);
    if (r != NACRE_OK)
        goto fail;
    *out = m;
    return NACRE_OK;
fail:
    nacre_mesh_data_free(ctx, &m);
    return r;
}

nacre_result nacre_mesh_load(nacre_context *ctx, const char *path, nacre_mesh_data *out)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!path || !out)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "mesh load: %s is NULL",
                       path ? "output mesh" : "path");
    memset(out, 0, sizeof(*out));
    load_state s;
    nacre_result r = open_scene(ctx, path, &s);
    if (r != NACRE_OK)
        return r;
    r = build_mesh(&s, 0, s.count, out);
    close_scene(&s);
    return r;
}

void nc_mesh_parts_free(nacre_context *ctx, nc_mesh_part *parts, uint32_t count)
{
    for (uint32_t i = 0; parts && i < count; i++)
        nacre_mesh_data_free(ctx, &parts[i].data);
    nc_free(ctx, parts);
}

nacre_result nc_mesh_load_parts(nacre_context *ctx, const char *path, nc_mesh_part **parts_out,
                                uint32_t *count_out)
{
    *parts_out = NULL;
    *count_out = 0;
    load_state s;
    nacre_result r = open_scene(ctx, path, &s);
    if (r != NACRE_OK)
        return r;
    nc_mesh_part *parts = nc_calloc(ctx, s.count, sizeof(*parts));
    if (!parts) {
        close_scene(&s);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    for (uint32_t i = 0; i < s.count && r == NACRE_OK; i++) {
        const struct aiMesh *mesh = s.inst[i].mesh;
        parts[i].material = mesh->mMaterialIndex;
        parts[i].node = s.inst[i].node;
        parts[i].slot = s.inst[i].slot;
        parts[i].mesh = UINT32_MAX;
        for (unsigned k = 0; k < s.scene->mNumMeshes; k++)
            if (s.scene->mMeshes[k] == mesh)
                parts[i].mesh = k;
        r = build_mesh(&s, i, i + 1, &parts[i].data);
    }
    uint32_t count = s.count;
    close_scene(&s);
    if (r != NACRE_OK) {
        nc_mesh_parts_free(ctx, parts, count);
        return r;
    }
    *parts_out = parts;
    *count_out = count;
    return NACRE_OK;
}
