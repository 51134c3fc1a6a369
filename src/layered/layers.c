/*
 * layers.c: point location in layered materials (Francois, Pattanaik, Bouatouh, Breton 2006,
 * "Subsurface texture mapping", seed 001 section 2.1: FindLayer and LayerThickness).
 *
 * The seed stores, per texel of an RGBA "subsurface texture", the depth of the bottom of each of
 * four layers below the surface along the normal, and locates a point M by projecting PM (P the
 * surface point) into tangent space to get M's texture coordinates and comparing M's depth with
 * the depths there. Its 3D form, used here: the depth of M is its distance to the nearest point
 * of the mesh, and the texture coordinates are that nearest point's. Where the surface is flat
 * over the depths involved the two agree (the projection of PM onto the tangent plane is the
 * nearest point); on curved surfaces this one is still a function of M alone, which a path tracer
 * needs (the seed's depends on the ray it marches along).
 *
 * Units: depths and distances in rest-pose scene units; uv as the mesh gives them; texture
 * values are dimensionless scales of each layer's depth (nacre_layering).
 */
#include "layered/layers.h"

#include "core/math.h"

#include <math.h>
#include <string.h>

/* ---- depth maps ---------------------------------------------------------------------------- */

static inline int32_t wrap(int32_t i, int32_t n)
{
    i %= n;
    return i < 0 ? i + n : i;
}

float nc_texture_sample(const nc_texture_rec *tex, int c, float u, float v)
{
    float out[4];
    nc_texture_sample_n(tex, c, 1, u, v, out);
    return out[0];
}

void nc_texture_sample_n(const nc_texture_rec *tex, int c, int n, float u, float v, float *out)
{
    /* Texel (x, y) is centred at u = (x + 0.5) / w, v = 1 - (y + 0.5) / h (row 0 on top). The
     * coordinates are reduced to one period first so that huge uvs cannot overflow the floor. */
    double fu = (double)u - floor((double)u), fv = (double)v - floor((double)v);
    if (!(fu >= 0.0 && fu <= 1.0))
        fu = 0.0; /* NaN or infinite uv */
    if (!(fv >= 0.0 && fv <= 1.0))
        fv = 0.0;
    double fx = fu * tex->width - 0.5, fy = (1.0 - fv) * tex->height - 0.5;
    double x0 = floor(fx), y0 = floor(fy);
    float ax = (float)(fx - x0), ay = (float)(fy - y0);
    int32_t xa = wrap((int32_t)x0, tex->width), xb = wrap((int32_t)x0 + 1, tex->width);
    int32_t ya = wrap((int32_t)y0, tex->height), yb = wrap((int32_t)y0 + 1, tex->height);
    size_t ch = (size_t)tex->channels, w = (size_t)tex->width;
    const float *d = tex->data + c;
    const float *p00 = d + ch * (xa + w * (size_t)ya), *p10 = d + ch * (xb + w * (size_t)ya);
    const float *p01 = d + ch * (xa + w * (size_t)yb), *p11 = d + ch * (xb + w * (size_t)yb);
    for (int k = 0; k < n; k++)
        out[k] = (1 - ay) * ((1 - ax) * p00[k] + ax * p10[k]) + ay * ((1 - ax) * p01[k] + ax * p11[k]);
}

void nc_texture_rgb(const nc_texture_rec *tex, float u, float v, float out[3])
{
    if (tex->channels < 3) {
        out[0] = out[1] = out[2] = nc_texture_sample(tex, 0, u, v);
        return;
    }
    nc_texture_sample_n(tex, 0, 3, u, v, out);
}

/* ---- layer stacks ---------------------------------------------------------------------------- */

void nc_layers_init(const nacre_scene *scene, const nacre_layering *l, nc_layer_stack *out)
{
    memset(out, 0, sizeof(*out));
    out->count = l->count < NACRE_MAX_LAYERS ? l->count : NACRE_MAX_LAYERS;
    out->map = l->depth_map.id ? nc_scene_texture(scene, l->depth_map) : NULL;
    /* max_k depth_k min_k bounds every uv's running maximum from below (each term does), and
     * max_k depth_k max_k from above. */
    float lo = 0, hi = 0;
    for (uint32_t j = 0; j < out->count; j++) {
        out->depth[j] = l->layers[j].depth;
        float mn = out->map ? out->map->min_value[j] : 1.0f, mx = out->map ? out->map->max_value[j] : 1.0f;
        lo = fmaxf(lo, out->depth[j] * mn);
        hi = fmaxf(hi, out->depth[j] * mx);
        out->lo[j] = lo;
        out->hi[j] = hi;
    }
}

void nc_layers_bottoms(const nc_layer_stack *s, float u, float v, float bottom[NACRE_MAX_LAYERS])
{
    /* One bilinear footprint for every layer's channel (the march calls this per sample). */
    float mapv[NACRE_MAX_LAYERS] = {1.0f, 1.0f, 1.0f, 1.0f};
    if (s->map && s->count)
        nc_texture_sample_n(s->map, 0, (int)s->count, u, v, mapv);
    float run = 0;
    for (uint32_t j = 0; j < s->count; j++) {
        run = fmaxf(run, s->depth[j] * mapv[j]);
        bottom[j] = run;
    }
}

uint32_t nc_layers_find(const nc_layer_stack *s, float d, float u, float v)
{
    /* Constant layers need no lookup; with a map, the depths of layers that every uv puts
     * above (or below) d settle most points without sampling. */
    uint32_t j;
    if (nc_layers_settled(s, d, &j))
        return j;
    float bottom[NACRE_MAX_LAYERS];
    nc_layers_bottoms(s, u, v, bottom);
    return nc_layers_after(s, d, j, bottom);
}

uint32_t nc_layers_touching(const nc_layer_stack *s, float d0, float d1)
{
    uint32_t bits = 0;
    for (uint32_t j = 0; j <= s->count; j++) {
        float top = j == 0 ? 0.0f : s->lo[j - 1];
        float bot = j == s->count ? INFINITY : s->hi[j];
        if (d1 >= top && d0 <= bot)
            bits |= 1u << j;
    }
    return bits;
}

/* ---- nearest surface points -------------------------------------------------------------- */

#ifdef NACRE_HAVE_EMBREE

struct nc_surface_locator {
    RTCScene scene;
    const nacre_mesh_data *mesh;
};

nacre_result nc_locator_create(nacre_context *ctx, RTCDevice device, const nacre_mesh_data *mesh,
                               nc_surface_locator **out)
{
    *out = NULL;
    nc_surface_locator *loc = nc_calloc(ctx, 1, sizeof(*loc));
    if (!loc)
        return NACRE_ERROR_OUT_OF_MEMORY;
    loc->mesh = mesh;
    loc->scene = rtcNewScene(device);
    rtcSetSceneBuildQuality(loc->scene, RTC_BUILD_QUALITY_HIGH);
    RTCGeometry g = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    /* Embree's own buffers, not shared ones: a shared vertex buffer must have 16 bytes of slack
     * past its last vertex, which the scene's arrays do not promise. */
    float *vb = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float),
                                        mesh->vertex_count);
    unsigned *ib = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned),
                                           mesh->triangle_count);
    if (vb && ib) {
        memcpy(vb, mesh->positions, (size_t)mesh->vertex_count * 3 * sizeof(float));
        memcpy(ib, mesh->indices, (size_t)mesh->triangle_count * 3 * sizeof(unsigned));
    }
    rtcCommitGeometry(g);
    rtcAttachGeometry(loc->scene, g);
    rtcReleaseGeometry(g);
    rtcCommitScene(loc->scene);
    if (!vb || !ib || rtcGetDeviceError(device) != RTC_ERROR_NONE) {
        nc_locator_destroy(ctx, loc);
        return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "layers: building the nearest-point structure failed");
    }
    *out = loc;
    return NACRE_OK;
}

void nc_locator_destroy(nacre_context *ctx, nc_surface_locator *loc)
{
    if (!loc)
        return;
    if (loc->scene)
        rtcReleaseScene(loc->scene);
    nc_free(ctx, loc);
}

typedef struct nearest_query {
    const nacre_mesh_data *mesh;
    float p[3];
    float best2;
    uint32_t prim;
    float wb, wc;
} nearest_query;

static bool nearest_cb(struct RTCPointQueryFunctionArguments *args)
{
    nearest_query *q = args->userPtr;
    const nacre_mesh_data *m = q->mesh;
    const uint32_t *t = m->indices + 3 * (size_t)args->primID;
    const float *a = m->positions + 3 * (size_t)t[0], *b = m->positions + 3 * (size_t)t[1];
    const float *c = m->positions + 3 * (size_t)t[2];
    /* The distance to the triangle's plane bounds the distance to the triangle from below: most
     * candidates are rejected on it (on a smooth surface every neighbour of the nearest triangle
     * has a plane farther away than the nearest point) before the full region walk. */
    float ab[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, ac[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    float n[3] = {ab[1] * ac[2] - ab[2] * ac[1], ab[2] * ac[0] - ab[0] * ac[2], ab[0] * ac[1] - ab[1] * ac[0]};
    float h = n[0] * (q->p[0] - a[0]) + n[1] * (q->p[1] - a[1]) + n[2] * (q->p[2] - a[2]);
    float nn = n[0] * n[0] + n[1] * n[1] + n[2] * n[2];
    if (h * h >= q->best2 * nn && nn > 0)
        return false;
    float wb, wc;
    float d2 = nc_closest_on_triangle(q->p, a, b, c, &wb, &wc);
    if (d2 < q->best2) {
        q->best2 = d2;
        q->prim = args->primID;
        q->wb = wb;
        q->wc = wc;
        args->query->radius = sqrtf(d2);
        return true;
    }
    return false;
}

float nc_locator_nearest(const nc_surface_locator *loc, const float p[3], float max_dist, uint32_t *hint,
                         float uv[2])
{
    /* Candidates must beat max_dist^2: the search only visits the mesh within that sphere, which
     * the hint's own distance (an upper bound on the nearest) may shrink before it starts. */
    const nacre_mesh_data *m = loc->mesh;
    float r2 = max_dist * max_dist;
    nearest_query q = {m, {p[0], p[1], p[2]}, isfinite(r2) ? r2 : INFINITY, UINT32_MAX, 0, 0};
    if (hint && *hint < m->triangle_count) {
        const uint32_t *t = m->indices + 3 * (size_t)*hint;
        float wb, wc;
        float d2 = nc_closest_on_triangle(q.p, m->positions + 3 * (size_t)t[0], m->positions + 3 * (size_t)t[1],
                                       m->positions + 3 * (size_t)t[2], &wb, &wc);
        if (d2 < q.best2) {
            q.best2 = d2;
            q.prim = *hint;
            q.wb = wb;
            q.wc = wc;
        }
    }
    struct RTCPointQuery pq;
    pq.x = p[0], pq.y = p[1], pq.z = p[2];
    pq.radius = q.best2 < INFINITY ? sqrtf(q.best2) : (max_dist >= 0 ? max_dist : 0.0f);
    pq.time = 0;
    struct RTCPointQueryContext qc;
    rtcInitPointQueryContext(&qc);
    rtcPointQuery(loc->scene, &pq, &qc, nearest_cb, &q);
    uv[0] = uv[1] = 0;
    if (hint)
        *hint = q.prim;
    if (q.prim == UINT32_MAX)
        return INFINITY;
    const float *tuv = m->uvs;
    if (tuv) {
        const uint32_t *t = m->indices + 3 * (size_t)q.prim;
        float wa = 1 - q.wb - q.wc;
        for (int k = 0; k < 2; k++)
            uv[k] = wa * tuv[2 * (size_t)t[0] + k] + q.wb * tuv[2 * (size_t)t[1] + k] + q.wc * tuv[2 * (size_t)t[2] + k];
    }
    return sqrtf(q.best2);
}

#endif /* NACRE_HAVE_EMBREE */

static const char *const ms_names[] = {"none", "diffusion"};

bool nacre_multiple_scattering_from_name(const char *name, nacre_multiple_scattering *out)
{
    for (int i = 0; name && i < 2; i++)
        if (strcmp(name, ms_names[i]) == 0) {
            *out = (nacre_multiple_scattering)i;
            return true;
        }
    return false;
}

const char *nacre_multiple_scattering_name(nacre_multiple_scattering ms)
{
    return (unsigned)ms < 2 ? ms_names[ms] : "unknown";
}
