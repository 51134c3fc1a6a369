/*
 * shadow.c: shadow maps (depth from the light, rendered with nc_raster_depth) and their
 * percentage-closer lookup.
 *
 * Directional lights get one orthographic map fitted to the scene bounds projected into light
 * space (a tight box, 2 texels of margin). Spot lights get one perspective map with fov =
 * 2 * outer angle plus a small margin. Point lights get six 90-degree faces (widened by 4 texels
 * so that PCF kernels near a face border stay on that face). Perspective near/far come from the
 * bounds, with near >= far / 1000 so float NDC depth stays well resolved. Back faces are not
 * culled: open meshes and single planes cast shadows from either side.
 *
 * Lookup: a box filter of half-width pcf_radius texels centred on the projected point; each texel
 * it overlaps contributes its comparison result weighted by the overlap area. The receiver is
 * treated as the plane through p with normal n, so each texel compares the stored depth against
 * that plane's depth at the texel centre (receiver-plane depth bias): planar receivers need only a
 * small constant bias, given in texels and scaled with the slope of n against the light. Depths
 * are compared linearly (distance along the map's view axis), in scene units.
 *
 * Cost: most lookups of the shading pass are on lit surfaces, whose window's depth range
 * straddles the receiver (the map holds that very surface), so the depth-range shortcut rarely
 * decides and the taps run. For an orthographic map and a receiver no steeper than MAX_SLOPE
 * (nearly all), pcf_window4x4_affine does the 4x4 taps as one compare each against the plane's
 * depth, affine in the texel indices: Suzanne's 4^3 pass went from 432 to 197 instructions per
 * lookup (callgrind), the shading pass of the bench's Armadillo from 3.08 to 2.76 ms (medians of
 * 5 alternating runs). Prefetching every window of a batch at once, or each window when its pixel
 * is found (lookups deferred to the end of the row), did not measurably help.
 *
 * Fog lookups (nc_shadow_lookup_volume_n, the froxels'): far more points than pixels, spread
 * through the volume, and their 2 x 2 texels are scattered over a map larger than the caches, so
 * gathering them was most of the cost. Nearly all points are far from a shadow's edge: a table of
 * each 8 x 8 block's least and greatest depth (nc_shadow_minmax, made once per map) decides them
 * exactly (lit or shadowed for every texel of the block), and only the rest (~3% of the bench's
 * groups of 8) read texels, fetched a column at a time. A pyramid deciding a group of 8 at once
 * decided fewer (a column's points span hundreds of texels), and gathers of single floats, or
 * loads lane by lane, were slower than two gathers of (min, max) pairs.
 */
#include "raster/raster.h"
#include "core/simd.h"

#include <string.h>

/* Extra texels around a cube face (see the file comment). */
#define CUBE_MARGIN_TEXELS 4.0f
/* Perspective maps keep far / near <= this. */
#define MAX_DEPTH_RATIO 1000.0f
/* Largest slope (tangent of the angle between n and the light) the bias and plane follow. */
#define MAX_SLOPE 10.0f

static void corners(const float lo[3], const float hi[3], nc_vec3 out[8])
{
    for (int i = 0; i < 8; i++)
        out[i] = nc_v3((i & 1) ? hi[0] : lo[0], (i & 2) ? hi[1] : lo[1], (i & 4) ? hi[2] : lo[2]);
}

static nc_vec3 up_for(nc_vec3 f) { return fabsf(f.y) < 0.99f ? nc_v3(0, 1, 0) : nc_v3(1, 0, 0); }

/* Near and far view depths (along f from eye) covering the bounds, or false if all behind. */
static bool depth_range(const nc_vec3 c[8], nc_vec3 eye, nc_vec3 f, float *near_out, float *far_out)
{
    float dmin = INFINITY, dmax = -INFINITY;
    for (int i = 0; i < 8; i++) {
        float d = nc_dot(nc_sub(c[i], eye), f);
        dmin = fminf(dmin, d);
        dmax = fmaxf(dmax, d);
    }
    if (!(dmax > 0.0f))
        return false;
    float far_d = dmax * 1.01f;
    float near_d = fmaxf(dmin * 0.99f, far_d / MAX_DEPTH_RATIO);
    *near_out = near_d;
    *far_out = far_d;
    return true;
}

static void set_face(nc_shadow_map *sm, int face, nc_mat4 view, nc_mat4 proj, bool ortho,
                     float texel)
{
    nc_raster_view *v = &sm->views[face];
    v->view = view;
    v->proj = proj;
    v->width = v->height = sm->size;
    v->orthographic = ortho;
    sm->world_to_clip[face] = nc_mat4_mul(proj, view);
    sm->texel_world[face] = texel;
}

nacre_result nc_shadow_render(nc_rasterizer *r, nacre_context *ctx, const nacre_light_desc *light,
                              const float bounds_min[3], const float bounds_max[3], int32_t size,
                              const nc_raster_mesh *casters, uint32_t caster_count,
                              nc_shadow_map *sm)
{
    if (!r || !light || !bounds_min || !bounds_max || !sm)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "shadow map: missing argument");
    if (size < 1 || size > 16384)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "shadow map: size %d out of range",
                       (int)size);
    for (int i = 0; i < 3; i++)
        if (!isfinite(bounds_min[i]) || !isfinite(bounds_max[i]) || bounds_min[i] > bounds_max[i])
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "shadow map: invalid scene bounds");
    nc_shadow_kind kind;
    switch (light->type) {
    case NACRE_LIGHT_DIRECTIONAL:
        kind = NC_SHADOW_ORTHO;
        break;
    case NACRE_LIGHT_SPOT:
        kind = NC_SHADOW_PERSPECTIVE;
        break;
    case NACRE_LIGHT_POINT:
        kind = NC_SHADOW_CUBE;
        break;
    default:
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "shadow map: unknown light type %d",
                       (int)light->type);
    }
    nc_vec3 dir = nc_v3a(light->direction), pos = nc_v3a(light->position);
    if (kind != NC_SHADOW_CUBE) {
        float len = nc_length(dir);
        if (!(len > 0.0f) || !isfinite(len))
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                           "shadow map: light direction is zero");
        dir = nc_scale(dir, 1.0f / len);
    }
    int faces = nc_shadow_face_count(light->type);
    size_t texels = (size_t)size * (size_t)size * (size_t)faces;
    if (!sm->depth || sm->size != size || sm->face_count != faces) {
        nc_free(ctx, sm->depth);
        sm->depth = nc_alloc(ctx, texels * sizeof(float));
        if (!sm->depth) {
            memset(sm, 0, sizeof(*sm));
            return NACRE_ERROR_OUT_OF_MEMORY;
        }
    }
    sm->kind = kind;
    sm->size = size;
    sm->face_count = faces;
    nc_v3store(pos, sm->light_pos);
    nc_v3store(dir, sm->light_dir);

    nc_vec3 c[8];
    corners(bounds_min, bounds_max, c);
    nc_vec3 lo = nc_v3a(bounds_min), hi = nc_v3a(bounds_max);
    float scale = fmaxf(nc_length(nc_sub(hi, lo)), 1e-6f * (1.0f + nc_length(lo) + nc_length(hi)));
    if (kind == NC_SHADOW_ORTHO) {
        nc_vec3 centre = nc_scale(nc_add(lo, hi), 0.5f);
        nc_vec3 eye = nc_sub(centre, nc_scale(dir, scale));
        nc_mat4 view = nc_mat4_look_at(eye, nc_add(eye, dir), up_for(dir));
        float l = INFINITY, rr = -INFINITY, b = INFINITY, t = -INFINITY, dn = INFINITY,
              df = -INFINITY;
        for (int i = 0; i < 8; i++) {
            nc_vec3 q = nc_mat4_point(&view, c[i]);
            l = fminf(l, q.x);
            rr = fmaxf(rr, q.x);
            b = fminf(b, q.y);
            t = fmaxf(t, q.y);
            dn = fminf(dn, -q.z);
            df = fmaxf(df, -q.z);
        }
        /* Non-zero extents and 2 texels of margin, so PCF at the border sees the casters. */
        float ex = fmaxf(rr - l, 1e-4f * scale), ey = fmaxf(t - b, 1e-4f * scale);
        float mx = 2.0f * ex / (float)size, my = 2.0f * ey / (float)size;
        float cx = 0.5f * (l + rr), cy = 0.5f * (b + t);
        l = cx - 0.5f * ex - mx;
        rr = cx + 0.5f * ex + mx;
        b = cy - 0.5f * ey - my;
        t = cy + 0.5f * ey + my;
        float mz = 0.01f * (df - dn) + 1e-4f * scale;
        nc_mat4 proj = nc_mat4_ortho(l, rr, b, t, dn - mz, df + mz);
        set_face(sm, 0, view, proj, true, fmaxf(rr - l, t - b) / (float)size);
    } else if (kind == NC_SHADOW_PERSPECTIVE) {
        float outer = fminf(fmaxf(light->outer_angle, 0.0f), 85.0f);
        /* One degree plus two texels of margin around the cone. */
        float half = (outer + 1.0f) * NC_DEG2RAD;
        half = atanf(tanf(half) * (1.0f + 4.0f / (float)size));
        float near_d = 1.0f, far_d = 2.0f;
        if (!depth_range(c, pos, dir, &near_d, &far_d)) {
            near_d = 1e-3f * scale;
            far_d = scale;
        }
        nc_mat4 view = nc_mat4_look_at(pos, nc_add(pos, dir), up_for(dir));
        nc_mat4 proj = nc_mat4_perspective(2.0f * half, 1.0f, near_d, far_d);
        set_face(sm, 0, view, proj, false, 2.0f * tanf(half) / (float)size);
    } else {
        static const float axes[6][3] = {{1, 0, 0},  {-1, 0, 0}, {0, 1, 0},
                                         {0, -1, 0}, {0, 0, 1},  {0, 0, -1}};
        static const float ups[6][3] = {{0, 1, 0}, {0, 1, 0}, {0, 0, 1},
                                        {0, 0, 1}, {0, 1, 0}, {0, 1, 0}};
        float tan_half = (float)size / ((float)size - 2.0f * CUBE_MARGIN_TEXELS);
        if (!(tan_half > 0.0f) || tan_half > 2.0f)
            tan_half = 2.0f; /* tiny maps */
        for (int f = 0; f < 6; f++) {
            nc_vec3 fa = nc_v3a(axes[f]);
            float near_d = 1.0f, far_d = 2.0f;
            if (!depth_range(c, pos, fa, &near_d, &far_d)) {
                near_d = 1e-3f * scale;
                far_d = scale;
            }
            nc_mat4 view = nc_mat4_look_at(pos, nc_add(pos, fa), nc_v3a(ups[f]));
            nc_mat4 proj = nc_mat4_perspective(2.0f * atanf(tan_half), 1.0f, near_d, far_d);
            set_face(sm, f, view, proj, false, 2.0f * tan_half / (float)size);
        }
    }
    /* New depths from here on: what was derived from the old ones (nc_shadow_minmax) is stale. */
    sm->generation = atomic_fetch_add_explicit(&ctx->shadow_serial, 1, memory_order_relaxed) + 1;
    size_t face_texels = (size_t)size * (size_t)size;
    for (int f = 0; f < faces; f++) {
        nacre_result res = nc_raster_depth(r, &sm->views[f], casters, caster_count, false,
                                           sm->depth + (size_t)f * face_texels);
        if (res != NACRE_OK)
            return res;
    }
    return NACRE_OK;
}

void nc_shadow_free(nacre_context *ctx, nc_shadow_map *sm)
{
    if (!sm)
        return;
    nc_free(ctx, sm->depth);
    memset(sm, 0, sizeof(*sm));
}

/* Stored NDC depth -> distance along the view axis. */
/* Branch-free min/max: libm's fminf/fmaxf are not inlined (NaN rules) and dominated the taps. */
static inline float fmin_fast(float a, float b) { return a < b ? a : b; }
static inline float fmax_fast(float a, float b) { return a > b ? a : b; }

static inline float linear_depth(const nc_raster_view *v, float ndc)
{
    const nc_mat4 *p = &v->proj;
    if (v->orthographic)
        return (p->m[2][3] - ndc) / p->m[2][2];
    return p->m[2][3] / (ndc + p->m[2][2]);
}

/* What the PCF taps of one lookup share: the window (centre u, vv and half-width rad, in
 * texels), the receiver (depth d along the view axis, view-space point pv and normal nv, the
 * plane's offset plane_d) and the map's projection terms, with the divisions done once. */
typedef struct pcf_frame {
    const float *map;
    int size;
    bool ortho, clamp;
    float u, vv, rad, d, plane_d, inv_nz, inv_size, inv_m00, inv_m11, m03, m13, m22, m23, inv_m22, max_dev, bias_world;
    nc_vec3 pv, nv;
} pcf_frame;

/* The per-column parts of the taps (columns i0 .. i0 + nw - 1): overlap with the window, the
 * receiver plane's x term, and the squared x distance from the window's centre. */
static inline void pcf_columns(const pcf_frame *f, int i0, int nw, float *col_o, float *col_r, float *col_d2)
{
    for (int k = 0; k < nw; k++) {
        int i = i0 + k;
        col_o[k] = fmin_fast((float)i + 1.0f, f->u + f->rad) - fmax_fast((float)i, f->u - f->rad);
        float tx = ((float)i + 0.5f) * f->inv_size - 1.0f;
        col_r[k] = f->ortho ? f->nv.x * ((tx - f->m03) * f->inv_m00 - f->pv.x) : f->nv.x * (tx * f->inv_m00);
        float du = (float)i + 0.5f - f->u;
        col_d2[k] = du * du;
    }
}

/* The per-row parts of row j: its overlap with the window (returned), the plane's y term and the
 * squared y distance. */
static inline float pcf_row(const pcf_frame *f, int j, float *row_r, float *dv2)
{
    float ty = 1.0f - ((float)j + 0.5f) * f->inv_size;
    *row_r = f->ortho ? f->nv.y * ((ty - f->m13) * f->inv_m11 - f->pv.y) : f->nv.y * (ty * f->inv_m11);
    float dv = (float)j + 0.5f - f->vv;
    *dv2 = dv * dv;
    return fmin_fast((float)j + 1.0f, f->vv + f->rad) - fmax_fast((float)j, f->vv - f->rad);
}

/* One tap: is the stored depth (NDC) at or behind the receiver plane's depth at this texel?
 * The plane's depth is kept within lim = max_dev x (distance in texels) of d (NaN, behind the
 * light and parallel planes included). */
static inline bool pcf_tap_lit(const pcf_frame *f, float stored, float col_r, float row_r, float col_d2, float dv2)
{
    if (!(stored < 1.0f))
        return true;
    float recv = f->ortho ? f->d + (col_r + row_r) * f->inv_nz : f->plane_d / (col_r + row_r + f->nv.z * -1.0f);
    float lim = f->max_dev * sqrtf(col_d2 + dv2);
    if (!(recv >= f->d - lim))
        recv = recv > f->d ? f->d + lim : f->d - lim;
    else if (recv > f->d + lim)
        recv = f->d + lim;
    float occluder = f->ortho ? (f->m23 - stored) * f->inv_m22 : f->m23 / (stored + f->m22);
    return occluder >= recv - f->bias_world;
}

static inline nc_v8f min8(nc_v8f a, nc_v8f b) { return nc_v8_sel(a < b, a, b); }
static inline nc_v8f max8(nc_v8f a, nc_v8f b) { return nc_v8_sel(a > b, a, b); }

/* Overlap of texel columns (or rows) c .. c + 1 with the box filter [centre - rad, centre + rad],
 * 0 outside it */
static inline nc_v8f overlap8(nc_v8f c, float centre, float rad)
{
    const nc_v8f o = min8(c + 1.0f, nc_v8_splat(centre + rad)) - max8(c, nc_v8_splat(centre - rad));
    return nc_v8_sel(o > 0.0f, o, (nc_v8f){0});
}

/* The usual window (pcf_radius 1.5): columns i0 .. i0 + 3 and rows j0 .. j0 + 3, wholly inside
 * the map, whose texels T hold two rows each (T[0]: rows j0 and j0 + 1 in lanes 0-3 and 4-7;
 * T[1]: rows j0 + 2 and j0 + 3). pcf_window's weights and pcf_tap_lit's comparisons, 8 taps per
 * vector, with the branches as selects. The sums differ from pcf_window's only in their
 * rounding: the total weight is the product of the column and row overlaps' sums, and the lit
 * weight is summed per lane over the two vectors, then across the lanes. */
static float pcf_window4x4(const pcf_frame *f, int i0, int j0, const nc_v8f T[2])
{
    const nc_v8f zero = {0};
    const nc_v8f ci = (float)i0 + (nc_v8f){0.0f, 1.0f, 2.0f, 3.0f, 0.0f, 1.0f, 2.0f, 3.0f};
    const nc_v8f col_o = overlap8(ci, f->u, f->rad);
    const nc_v8f tx = (ci + 0.5f) * f->inv_size - 1.0f;
    const nc_v8f col_r = f->ortho ? f->nv.x * ((tx - f->m03) * f->inv_m00 - f->pv.x) : f->nv.x * (tx * f->inv_m00);
    const nc_v8f du = ci + 0.5f - f->u;
    const nc_v8f col_d2 = du * du;
    const float d = f->d;
    nc_v8f lit = zero, oy_sum = zero;
    for (int h = 0; h < 2; h++) {
        const nc_v8f rj = (float)(j0 + 2 * h) + (nc_v8f){0.0f, 0.0f, 0.0f, 0.0f, 1.0f, 1.0f, 1.0f, 1.0f};
        const nc_v8f ty = 1.0f - (rj + 0.5f) * f->inv_size;
        const nc_v8f row_r = f->ortho ? f->nv.y * ((ty - f->m13) * f->inv_m11 - f->pv.y) : f->nv.y * (ty * f->inv_m11);
        const nc_v8f dv = rj + 0.5f - f->vv;
        const nc_v8f oy = overlap8(rj, f->vv, f->rad); /* rows outside the window weigh 0 */
        oy_sum += oy;
        const nc_v8f stored = T[h];
        nc_v8f recv = f->ortho ? d + (col_r + row_r) * f->inv_nz : f->plane_d / (col_r + row_r + f->nv.z * -1.0f);
        const nc_v8f lim = f->max_dev * nc_v8_sqrt(col_d2 + dv * dv);
        const nc_v8f lo = d - lim, hi = d + lim;
        recv = nc_v8_sel(recv >= lo, nc_v8_sel(recv > hi, hi, recv), lo);
        const nc_v8f occluder = f->ortho ? (f->m23 - stored) * f->inv_m22 : f->m23 / (stored + f->m22);
        const nc_v8i is_lit = ~(stored < 1.0f) | (occluder >= recv - f->bias_world);
        lit += nc_v8_sel(is_lit, col_o, zero) * oy;
    }
    /* oy_sum: rows j0 + j0 + 2 in lanes 0-3, j0 + 1 + j0 + 3 in lanes 4-7 */
    const float rows = oy_sum[0] + oy_sum[4];
    const float total = (col_o[0] + col_o[1] + col_o[2] + col_o[3]) * rows;
    const float sum = nc_v8_sum(lit);
    return total > 0.0f ? sum / total : 1.0f;
}

/* The taps of the window [i0, i1] x [j0, j1], each weighted by its overlap with the box filter.
 * Texels beyond the map are lit (one map) or clamped to its edge (cube faces, whose margin
 * covers the kernel). The parts that depend only on the column or only on the row are computed
 * once per column and once per row. */
static float pcf_window(const pcf_frame *f, int i0, int i1, int j0, int j1)
{
    enum { MAXW = 18 }; /* columns of a window of half-width <= 8 */
    float col_o[MAXW], col_r[MAXW], col_d2[MAXW];
    const int nw = i1 - i0 + 1, size = f->size;
    pcf_columns(f, i0, nw, col_o, col_r, col_d2);
    float lit = 0.0f, total = 0.0f;
    for (int j = j0; j <= j1; j++) {
        float row_r, dv2;
        float oy = pcf_row(f, j, &row_r, &dv2);
        if (oy <= 0.0f)
            continue;
        for (int k = 0; k < nw; k++) {
            float ox = col_o[k];
            if (ox <= 0.0f)
                continue;
            float wgt = ox * oy;
            total += wgt;
            int ti = i0 + k, tj = j;
            if (f->clamp) {
                ti = ti < 0 ? 0 : (ti >= size ? size - 1 : ti);
                tj = tj < 0 ? 0 : (tj >= size ? size - 1 : tj);
            } else if (ti < 0 || tj < 0 || ti >= size || tj >= size) {
                lit += wgt; /* beyond the map: nothing recorded, lit */
                continue;
            }
            if (pcf_tap_lit(f, f->map[(size_t)tj * (size_t)size + (size_t)ti], col_r[k], row_r, col_d2[k], dv2))
                lit += wgt;
        }
    }
    return total > 0.0f ? lit / total : 1.0f;
}

/* An orthographic map's 4x4 window when the receiver plane is no steeper than the depth limit
 * (slope < MAX_SLOPE, so pcf_tap_lit never clamps the plane's depth: |recv - d| <= slope x
 * distance < lim): the plane's depth at the texel centres is then affine in the texel indices,
 * recv(i0 + a, j0 + b) = r0 + a ci + b cj, and each tap is one compare against it. The same
 * taps and weights as pcf_window4x4, without its per-tap clamp, square root and plane terms;
 * the depths differ from the per-tap ones only in rounding, far below the bias. Wholly lit and
 * wholly shadowed windows return exactly 1 and 0 (as the depth-range test does). */
static inline float pcf_window4x4_affine(const float *map, int size, int i0, int j0, float u, float vv, float rad,
                                         float r0, float ci, float cj, float m23, float inv_m22)
{
    const nc_v8f zero = {0};
    const nc_v8f col = {0.0f, 1.0f, 2.0f, 3.0f, 0.0f, 1.0f, 2.0f, 3.0f};
    const nc_v8f row = {0.0f, 0.0f, 0.0f, 0.0f, 1.0f, 1.0f, 1.0f, 1.0f};
    const float *p = map + (size_t)j0 * (size_t)size + (size_t)i0;
    const nc_v8f t0 = nc_v8_load2(p, p + size), t1 = nc_v8_load2(p + 2 * (size_t)size, p + 3 * (size_t)size);
    /* Receiver depth minus the bias at each tap, and the stored depths as distances */
    const nc_v8f r_0 = r0 + ci * col + cj * row, r_1 = r_0 + 2.0f * cj;
    const nc_v8i lit0 = ~(t0 < 1.0f) | ((m23 - t0) * inv_m22 >= r_0);
    const nc_v8i lit1 = ~(t1 < 1.0f) | ((m23 - t1) * inv_m22 >= r_1);
    const uint32_t bits = nc_v8_bits(lit0) | nc_v8_bits(lit1) << 8;
    if (bits == 0xffffu)
        return 1.0f;
    if (bits == 0)
        return 0.0f;
    /* Box-filter overlaps of the columns and of the two row pairs */
    const nc_v8f ci_ = (float)i0 + col, rj0 = (float)j0 + row, rj1 = rj0 + 2.0f;
    const nc_v8f wx = overlap8(ci_, u, rad);
    const nc_v8f w0 = wx * overlap8(rj0, vv, rad), w1 = wx * overlap8(rj1, vv, rad);
    const float sum = nc_v8_sum(nc_v8_sel(lit0, w0, zero) + nc_v8_sel(lit1, w1, zero)), total = nc_v8_sum(w0 + w1);
    return total > 0.0f ? sum / total : 1.0f;
}

/* The window part of a lookup (f: the receiver and the map, f->map the face's texels): the lit
 * fraction, from the window's depth range when that decides it, else from the PCF taps. */
static inline float lookup_window(const nc_raster_view *v, const pcf_frame *f)
{
    const int size = f->size;
    const float rad = f->rad, u = f->u, vv = f->vv, d = f->d, bias_world = f->bias_world;
    int i0 = (int)floorf(u - rad), i1 = (int)floorf(u + rad);
    int j0 = (int)floorf(vv - rad), j1 = (int)floorf(vv + rad);
    if (i1 < 0 || j1 < 0 || i0 >= size || j0 >= size)
        return 1.0f;
    const float *map = f->map;
    /* Most receivers are wholly lit or wholly shadowed: decide from the window's depth range
     * against the widest receiver deviation before doing per-tap plane intersections. */
    if (i0 >= 0 && j0 >= 0 && i1 < size && j1 < size) {
        const float reach = f->max_dev * (rad + 1.0f) * 1.4142136f;
        /* The usual 4x4 window (pcf_radius 1.5): its 16 texels in two vectors, for the depth
         * range and the taps */
        const bool four = i1 - i0 == 3 && j1 - j0 == 3;
        nc_v8f T[2];
        float smin = INFINITY, smax = -INFINITY;
        if (four) {
            for (int h = 0; h < 2; h++) {
                const float *row = map + (size_t)(j0 + 2 * h) * (size_t)size + (size_t)i0;
                T[h] = nc_v8_load2(row, row + size);
            }
            const nc_v8f lo = min8(T[0], T[1]), hi = max8(T[0], T[1]);
            smin = fmin_fast(fmin_fast(fmin_fast(lo[0], lo[1]), fmin_fast(lo[2], lo[3])),
                             fmin_fast(fmin_fast(lo[4], lo[5]), fmin_fast(lo[6], lo[7])));
            smax = fmax_fast(fmax_fast(fmax_fast(hi[0], hi[1]), fmax_fast(hi[2], hi[3])),
                             fmax_fast(fmax_fast(hi[4], hi[5]), fmax_fast(hi[6], hi[7])));
        } else {
            for (int j = j0; j <= j1; j++) {
                const float *row = map + (size_t)j * (size_t)size;
                for (int i = i0; i <= i1; i++) {
                    smin = fmin_fast(smin, row[i]);
                    smax = fmax_fast(smax, row[i]);
                }
            }
        }
        if (!(smin < 1.0f) || linear_depth(v, smin) >= d + reach - bias_world)
            return 1.0f;
        if (smax < 1.0f && linear_depth(v, smax) < d - reach - bias_world)
            return 0.0f;
        if (four)
            return pcf_window4x4(f, i0, j0, T);
    }
    return pcf_window(f, i0, i1, j0, j1);
}

float nc_shadow_lookup(const nc_shadow_map *sm, nc_vec3 p, nc_vec3 n, float pcf_radius, float bias)
{
    if (!sm || !sm->depth || sm->size < 1)
        return 1.0f;
    int face = 0;
    if (sm->kind == NC_SHADOW_CUBE) {
        nc_vec3 d = nc_sub(p, nc_v3a(sm->light_pos));
        float ax = fabsf(d.x), ay = fabsf(d.y), az = fabsf(d.z);
        if (ax >= ay && ax >= az)
            face = d.x >= 0.0f ? 0 : 1;
        else if (ay >= az)
            face = d.y >= 0.0f ? 2 : 3;
        else
            face = d.z >= 0.0f ? 4 : 5;
    }
    const nc_raster_view *v = &sm->views[face];
    const nc_mat4 *vm = &v->view, *pm = &v->proj;
    bool ortho = v->orthographic;
    nc_vec3 pv = nc_mat4_point(vm, p);
    float d = -pv.z; /* receiver depth along the view axis */
    float near_d = linear_depth(v, 0.0f), far_d = linear_depth(v, 1.0f);
    if (!(d >= near_d) || !(d <= far_d))
        return 1.0f; /* nothing in the map can be in front of it */
    float w = ortho ? 1.0f : d;
    nc_vec4 clip = nc_mat4_apply(pm, (nc_vec4){pv.x, pv.y, pv.z, 1.0f});
    float ndc_x = clip.x / clip.w, ndc_y = clip.y / clip.w;
    int size = sm->size;
    float u = (ndc_x * 0.5f + 0.5f) * (float)size, vv = (0.5f - ndc_y * 0.5f) * (float)size;
    if (!isfinite(u) || !isfinite(vv))
        return 1.0f;

    /* World size of a texel at p. */
    float m00 = pm->m[0][0], m11 = pm->m[1][1], m03 = pm->m[0][3], m13 = pm->m[1][3];
    float texel = fmax_fast(2.0f * w / (m00 * (float)size), 2.0f * w / (m11 * (float)size));
    /* The receiver is the plane through p with normal n. Each texel compares against the depth
     * where its own ray meets that plane: exact for planar receivers, also when the plane nearly
     * contains a perspective map's axis (the ground seen by a point light's side faces). The
     * change is limited to MAX_SLOPE texel sizes per texel of distance. */
    nc_vec3 nv = nc_normalize(nc_mat4_dir(vm, n));
    nc_vec3 ray = ortho ? nc_v3(0, 0, -1) : nc_normalize(pv);
    float cos_t = fabsf(nc_dot(nv, ray));
    float sin_t = sqrtf(fmax_fast(0.0f, 1.0f - cos_t * cos_t));
    float slope = sin_t < MAX_SLOPE * cos_t ? sin_t / cos_t : MAX_SLOPE;
    float bias_world = fmax_fast(bias, 0.0f) * texel * 0.5f * (1.0f + slope);
    pcf_frame f = {
        .map = sm->depth + (size_t)face * (size_t)size * (size_t)size,
        .size = size,
        .ortho = ortho,
        .clamp = sm->kind == NC_SHADOW_CUBE,
        .u = u,
        .vv = vv,
        .rad = fmin_fast(fmax_fast(pcf_radius, 0.5f), 8.0f),
        .d = d,
        .plane_d = nc_dot(nv, pv),
        .inv_nz = 1.0f / nv.z,
        .inv_size = 2.0f / (float)size,
        .inv_m00 = 1.0f / m00,
        .inv_m11 = 1.0f / m11,
        .m03 = m03,
        .m13 = m13,
        .m22 = pm->m[2][2],
        .m23 = pm->m[2][3],
        .inv_m22 = 1.0f / pm->m[2][2],
        .max_dev = MAX_SLOPE * texel,
        .bias_world = bias_world,
        .pv = pv,
        .nv = nv,
    };
    return lookup_window(v, &f);
}

/* Cache hint for the rows of the PCF window around (u, vv) in a face of `size` texels (kernels
 * wider than 2 texels are left alone). Only a hint: it reads nothing. */
static inline void prefetch_window(const float *map, int size, float rad, float u, float vv)
{
#if defined(__GNUC__)
    if (rad > 2.0f || !(u > -rad && vv > -rad && u < (float)size + rad && vv < (float)size + rad))
        return; /* also NaN */
    int i0 = (int)floorf(u - rad), i1 = (int)floorf(u + rad);
    int j0 = (int)floorf(vv - rad), j1 = (int)floorf(vv + rad);
    i0 = i0 < 0 ? 0 : i0;
    i1 = i1 >= size ? size - 1 : i1;
    j0 = j0 < 0 ? 0 : j0;
    j1 = j1 >= size ? size - 1 : j1;
    for (int j = j0; j <= j1; j++) {
        const float *row = map + (size_t)j * (size_t)size;
        __builtin_prefetch(row + i0);
        __builtin_prefetch(row + i1);
    }
#else
    (void)map, (void)size, (void)rad, (void)u, (void)vv;
#endif
}

/* Lookups prefetched ahead of the one being done: their first reads miss the cache (the map is
 * larger than it, and shading visits its texels in screen order). */
#define PREFETCH_AHEAD 4u

/* Per-point set-up of an orthographic map's lookups, CHUNK points at a time in SoA loops that
 * vectorize (nc_shadow_lookup's operations, with its early returns as a mask). */
#define CHUNK 64u

void nc_shadow_lookup_n(const nc_shadow_map *sm, uint32_t n, const float *px, const float *py, const float *pz,
                        const float *nx, const float *ny, const float *nz, float pcf_radius, float bias, float *out)
{
    if (!sm || !sm->depth || sm->size < 1) {
        for (uint32_t i = 0; i < n; i++)
            out[i] = 1.0f;
        return;
    }
    const float rad = fmin_fast(fmax_fast(pcf_radius, 0.5f), 8.0f);
    if (sm->kind != NC_SHADOW_ORTHO || !sm->views[0].orthographic) {
        /* Perspective and cube maps: one lookup at a time, single-face maps prefetched */
        const nc_mat4 *m = &sm->world_to_clip[0];
        const bool hint = sm->kind != NC_SHADOW_CUBE;
        for (uint32_t i = 0; i < n; i++) {
            if (hint && i + PREFETCH_AHEAD < n) {
                uint32_t a = i + PREFETCH_AHEAD;
                nc_vec4 c = nc_mat4_apply(m, (nc_vec4){px[a], py[a], pz[a], 1.0f});
                prefetch_window(sm->depth, sm->size, rad, (c.x / c.w * 0.5f + 0.5f) * (float)sm->size,
                                (0.5f - c.y / c.w * 0.5f) * (float)sm->size);
            }
            out[i] = nc_shadow_lookup(sm, nc_v3(px[i], py[i], pz[i]), nc_v3(nx[i], ny[i], nz[i]), pcf_radius, bias);
        }
        return;
    }
    const nc_raster_view *v = &sm->views[0];
    const nc_mat4 *vm = &v->view, *pm = &v->proj;
    const int size = sm->size;
    const float fsize = (float)size;
    const float near_d = linear_depth(v, 0.0f), far_d = linear_depth(v, 1.0f);
    const float m00 = pm->m[0][0], m11 = pm->m[1][1];
    const float texel = fmax_fast(2.0f / (m00 * fsize), 2.0f / (m11 * fsize));
    const float bias_texel = fmax_fast(bias, 0.0f) * texel * 0.5f;
    const pcf_frame base = {
        .map = sm->depth,
        .size = size,
        .ortho = true,
        .clamp = false,
        .rad = rad,
        .inv_size = 2.0f / fsize,
        .inv_m00 = 1.0f / m00,
        .inv_m11 = 1.0f / m11,
        .m03 = pm->m[0][3],
        .m13 = pm->m[1][3],
        .m22 = pm->m[2][2],
        .m23 = pm->m[2][3],
        .inv_m22 = 1.0f / pm->m[2][2],
        .max_dev = MAX_SLOPE * texel,
    };
    /* The matrices' entries as scalars: the loops must not reload them through pointers that
     * could alias the outputs */
    float V[3][4], P[4][4];
    memcpy(V, vm->m, sizeof(V));
    memcpy(P, pm->m, sizeof(P));
    /* Squared plane slope (depth per texel) below which the taps never clamp: the limit is
     * max_dev per texel of distance; the margin keeps rounding away from it */
    const float affine_lim2 = (0.999f * base.max_dev) * (0.999f * base.max_dev);
    pcf_frame f = base; /* the map's part, once; each lookup sets the point's part */
    for (uint32_t c0 = 0; c0 < n; c0 += CHUNK) {
        const uint32_t cn = n - c0 < CHUNK ? n - c0 : CHUNK;
        float U[CHUNK], VV[CHUNK], D[CHUNK], PD[CHUNK], INZ[CHUNK], BW[CHUNK];
        float PVX[CHUNK], PVY[CHUNK], PVZ[CHUNK], NVX[CHUNK], NVY[CHUNK], NVZ[CHUNK];
        float CI[CHUNK], CJ[CHUNK];
        int32_t ok[CHUNK], fast[CHUNK], I0[CHUNK], J0[CHUNK];
        float R0[CHUNK];
        for (uint32_t k = 0; k < cn; k++) {
            const uint32_t i = c0 + k;
            const float x = px[i], y = py[i], z = pz[i];
            float pvx = V[0][0] * x + V[0][1] * y + V[0][2] * z + V[0][3];
            float pvy = V[1][0] * x + V[1][1] * y + V[1][2] * z + V[1][3];
            float pvz = V[2][0] * x + V[2][1] * y + V[2][2] * z + V[2][3];
            float d = -pvz;
            float cx = P[0][0] * pvx + P[0][1] * pvy + P[0][2] * pvz + P[0][3] * 1.0f;
            float cy = P[1][0] * pvx + P[1][1] * pvy + P[1][2] * pvz + P[1][3] * 1.0f;
            float cw = P[3][0] * pvx + P[3][1] * pvy + P[3][2] * pvz + P[3][3] * 1.0f;
            float u = (cx / cw * 0.5f + 0.5f) * fsize, vv = (0.5f - cy / cw * 0.5f) * fsize;
            float ax = nx[i], ay = ny[i], az = nz[i];
            float dx = V[0][0] * ax + V[0][1] * ay + V[0][2] * az;
            float dy = V[1][0] * ax + V[1][1] * ay + V[1][2] * az;
            float dz = V[2][0] * ax + V[2][1] * ay + V[2][2] * az;
            float l = sqrtf(dx * dx + dy * dy + dz * dz);
            float inv_l = 1.0f / l;
            int32_t pos = l > 0.0f;
            dx = nc_sel(pos, dx * inv_l, dx);
            dy = nc_sel(pos, dy * inv_l, dy);
            dz = nc_sel(pos, dz * inv_l, dz);
            float cos_t = fabsf(dz);
            float sin_t = sqrtf(fmax_fast(0.0f, 1.0f - cos_t * cos_t));
            float slope = nc_sel(sin_t < MAX_SLOPE * cos_t, sin_t / cos_t, MAX_SLOPE);
            ok[k] = (d >= near_d) & (d <= far_d) & (fabsf(u) <= 3.4028235e38f) & (fabsf(vv) <= 3.4028235e38f);
            /* The receiver plane's depth per texel along i and j (pcf_window4x4_affine), and
             * whether its 4x4 window applies: a slope below the limit, the window in the map */
            const float inz = 1.0f / dz;
            const float ci = dx * inz * base.inv_size * base.inv_m00, cj = -(dy * inz * base.inv_size * base.inv_m11);
            CI[k] = ci;
            CJ[k] = cj;
            fast[k] = ok[k] & (ci * ci + cj * cj < affine_lim2) & (u - rad >= 0.0f) & (vv - rad >= 0.0f) &
                      (u + rad < fsize) & (vv + rad < fsize);
            U[k] = u;
            VV[k] = vv;
            D[k] = d;
            BW[k] = bias_texel * (1.0f + slope);
            PD[k] = dx * pvx + dy * pvy + dz * pvz;
            INZ[k] = inz;
            PVX[k] = pvx;
            PVY[k] = pvy;
            PVZ[k] = pvz;
            NVX[k] = dx;
            NVY[k] = dy;
            NVZ[k] = dz;
        }
        /* The fast points' 4x4 window (pcf_window4x4_affine): its first texel (i0, j0) and the
         * receiver's depth there as pcf_tap_lit computes it, less the bias; fast[k] is cleared
         * where the window is not 4x4. Eight points at a time: fast points have u, vv >= rad, so
         * truncation is floor, and the other lanes compute on zeros (no garbage, no denormals). */
        for (uint32_t k = 0; k < cn; k += 8) {
            const nc_v8f zero = {0};
            const nc_v8i m = nc_v8_first(cn - k) & (nc_v8i_load(fast + k) != 0);
            const nc_v8f u = nc_v8_sel(m, nc_v8_load(U + k), zero), vv = nc_v8_sel(m, nc_v8_load(VV + k), zero);
            const nc_v8i i0 = __builtin_convertvector(nc_v8_sel(m, u - rad, zero), nc_v8i),
                         j0 = __builtin_convertvector(nc_v8_sel(m, vv - rad, zero), nc_v8i),
                         i1 = __builtin_convertvector(nc_v8_sel(m, u + rad, zero), nc_v8i),
                         j1 = __builtin_convertvector(nc_v8_sel(m, vv + rad, zero), nc_v8i);
            nc_v8i_store(fast + k, m & (i1 - i0 == 3) & (j1 - j0 == 3));
            nc_v8i_store(I0 + k, i0);
            nc_v8i_store(J0 + k, j0);
            const nc_v8f tx = (__builtin_convertvector(i0, nc_v8f) + 0.5f) * base.inv_size - 1.0f;
            const nc_v8f ty = 1.0f - (__builtin_convertvector(j0, nc_v8f) + 0.5f) * base.inv_size;
            const nc_v8f col_r = nc_v8_sel(m, nc_v8_load(NVX + k), zero) *
                                 ((tx - base.m03) * base.inv_m00 - nc_v8_sel(m, nc_v8_load(PVX + k), zero));
            const nc_v8f row_r = nc_v8_sel(m, nc_v8_load(NVY + k), zero) *
                                 ((ty - base.m13) * base.inv_m11 - nc_v8_sel(m, nc_v8_load(PVY + k), zero));
            nc_v8_store(R0 + k, nc_v8_sel(m, nc_v8_load(D + k), zero) +
                                    (col_r + row_r) * nc_v8_sel(m, nc_v8_load(INZ + k), zero) -
                                    nc_v8_sel(m, nc_v8_load(BW + k), zero));
        }
        for (uint32_t k = 0; k < cn && k < PREFETCH_AHEAD; k++)
            prefetch_window(base.map, size, rad, U[k], VV[k]);
        for (uint32_t k = 0; k < cn; k++) {
            if (k + PREFETCH_AHEAD < cn)
                prefetch_window(base.map, size, rad, U[k + PREFETCH_AHEAD], VV[k + PREFETCH_AHEAD]);
            if (!ok[k]) {
                out[c0 + k] = 1.0f;
                continue;
            }
            if (fast[k]) {
                out[c0 + k] = pcf_window4x4_affine(base.map, size, I0[k], J0[k], U[k], VV[k], rad, R0[k], CI[k], CJ[k],
                                                   base.m23, base.inv_m22);
                continue;
            }
            f.u = U[k];
            f.vv = VV[k];
            f.d = D[k];
            f.plane_d = PD[k];
            f.inv_nz = INZ[k];
            f.bias_world = BW[k];
            f.pv = nc_v3(PVX[k], PVY[k], PVZ[k]);
            f.nv = nc_v3(NVX[k], NVY[k], NVZ[k]);
            out[c0 + k] = lookup_window(v, &f);
        }
    }
}

float nc_shadow_lookup_volume(const nc_shadow_map *sm, nc_vec3 p, float pcf_radius, float bias)
{
    (void)pcf_radius;
    if (!sm || !sm->depth || sm->size < 1)
        return 1.0f;
    int face = 0;
    if (sm->kind == NC_SHADOW_CUBE) {
        nc_vec3 d = nc_sub(p, nc_v3a(sm->light_pos));
        float ax = fabsf(d.x), ay = fabsf(d.y), az = fabsf(d.z);
        face = ax >= ay && ax >= az ? (d.x >= 0.0f ? 0 : 1) : ay >= az ? (d.y >= 0.0f ? 2 : 3) : (d.z >= 0.0f ? 4 : 5);
    }
    const nc_raster_view *v = &sm->views[face];
    nc_vec3 pv = nc_mat4_point(&v->view, p);
    float d = -pv.z, near_d = linear_depth(v, 0.0f);
    if (!(d >= near_d))
        return 1.0f; /* nothing in the map can be in front of it */
    /* Beyond the far plane the point is behind every caster: its texels decide alone (the
     * comparison below against a depth past the far plane). */
    float w = v->orthographic ? 1.0f : d;
    const nc_mat4 *pm = &v->proj;
    float ndc_x = (pm->m[0][0] * pv.x + pm->m[0][2] * pv.z + pm->m[0][3]) / w;
    float ndc_y = (pm->m[1][1] * pv.y + pm->m[1][2] * pv.z + pm->m[1][3]) / w;
    int size = sm->size;
    float u = (ndc_x * 0.5f + 0.5f) * (float)size - 0.5f, vv = (0.5f - ndc_y * 0.5f) * (float)size - 0.5f;
    if (!(u > -1.0f && u < (float)size && vv > -1.0f && vv < (float)size))
        return 1.0f;
    /* Bias: `bias` texels of world size at the point. */
    float texel = 2.0f * w / (pm->m[0][0] * (float)size);
    float limit = d - fmax_fast(bias, 0.0f) * texel;
    int x0 = (int)floorf(u), y0 = (int)floorf(vv);
    float fx = u - (float)x0, fy = vv - (float)y0;
    const float *map = sm->depth + (size_t)face * (size_t)size * (size_t)size;
    float lit = 0.0f;
    /* 2 x 2 bilinear comparison: shafts with smooth edges at one texel's scale. */
    for (int k = 0; k < 4; k++) {
        int x = x0 + (k & 1), y = y0 + (k >> 1);
        float wt = ((k & 1) ? fx : 1.0f - fx) * ((k >> 1) ? fy : 1.0f - fy);
        bool in = x >= 0 && y >= 0 && x < size && y < size;
        float z = in ? map[(size_t)y * (size_t)size + (size_t)x] : 1.0f;
        if (z >= 1.0f || linear_depth(v, z) >= limit) /* 1: cleared, no caster */
            lit += wt;
    }
    return lit;
}

/* ---- min-max table (nc_shadow_minmax) ----------------------------------------------------- */

void nc_shadow_minmax_free(nacre_context *ctx, nc_shadow_minmax *mm)
{
    if (!mm)
        return;
    nc_free(ctx, mm->data);
    memset(mm, 0, sizeof(*mm));
}

/* Texels folded at once into a block row's blocks (a multiple of every block width). */
#define MM_STRIP 256

/* Block row by of the table: its texel rows by B - 1 .. (by + 1) B - 1 folded column by column
 * (a NaN as -inf for the min, +inf for the max), a strip at a time, then each block's columns
 * bx B - 1 .. (bx + 1) B - 1. The pair stored is NaN (no comparison passes) where an end is
 * infinite, and the max +inf on the table's border, whose lanes may have taps outside the map
 * (lit): so the lookups need no test but the block's. */
static void mm_block_row(const float *map, int32_t n, int32_t shift, int32_t dim, int32_t by, float *row)
{
    const int32_t B = 1 << shift, per = MM_STRIP >> shift;
    const int32_t y0 = by * B - 1 > 0 ? by * B - 1 : 0, y1 = (by + 1) * B - 1 < n - 1 ? (by + 1) * B - 1 : n - 1;
    for (int32_t bx0 = 0; bx0 < dim; bx0 += per) {
        const int32_t bx1 = bx0 + per < dim ? bx0 + per : dim;
        const int32_t x0 = bx0 * B - 1 > 0 ? bx0 * B - 1 : 0, x1 = bx1 * B - 1 < n - 1 ? bx1 * B - 1 : n - 1;
        const int32_t w = x1 - x0 + 1; /* at most MM_STRIP + 1 */
        float lo[MM_STRIP + 1], hi[MM_STRIP + 1];
        for (int32_t i = 0; i < w; i++) {
            lo[i] = INFINITY;
            hi[i] = -INFINITY;
        }
        for (int32_t y = y0; y <= y1; y++) {
            const float *r = map + (size_t)y * (size_t)n + x0;
            int32_t i = 0;
            for (; i + 8 <= w; i += 8) {
                const nc_v8f t = nc_v8_load(r + i);
                const nc_v8i num = t == t;
                nc_v8_store(lo + i, min8(nc_v8_load(lo + i), nc_v8_sel(num, t, nc_v8_splat(-INFINITY))));
                nc_v8_store(hi + i, max8(nc_v8_load(hi + i), nc_v8_sel(num, t, nc_v8_splat(INFINITY))));
            }
            for (; i < w; i++) {
                const float t = r[i];
                lo[i] = fmin_fast(lo[i], t == t ? t : -INFINITY);
                hi[i] = fmax_fast(hi[i], t == t ? t : INFINITY);
            }
        }
        for (int32_t bx = bx0; bx < bx1; bx++) {
            const int32_t a = (bx * B - 1 > 0 ? bx * B - 1 : 0) - x0;
            const int32_t b = (bx * B + B - 1 < n - 1 ? bx * B + B - 1 : n - 1) - x0;
            float l = INFINITY, h = -INFINITY;
            for (int32_t i = a; i <= b; i++) {
                l = fmin_fast(l, lo[i]);
                h = fmax_fast(h, hi[i]);
            }
            if (!(l > -INFINITY && h < INFINITY))
                l = h = NAN; /* a NaN texel (or an infinite depth): no comparison decides */
            else if (bx == 0 || by == 0 || bx == dim - 1 || by == dim - 1)
                h = INFINITY; /* the taps of its lanes may be outside the map: never all shadowed */
            row[2 * bx] = l;
            row[2 * bx + 1] = h;
        }
    }
}

nacre_result nc_shadow_minmax_update(nacre_context *ctx, const nc_shadow_map *sm, nc_shadow_minmax *mm, int threads)
{
    if (!mm)
        return NACRE_OK;
    if (!sm || !sm->depth || sm->size < 1 || sm->kind == NC_SHADOW_CUBE || sm->generation == 0) {
        mm->generation = 0;
        return NACRE_OK;
    }
    if (mm->generation == sm->generation && mm->size == sm->size)
        return NACRE_OK;
    mm->generation = 0;
    const int32_t n = sm->size;
    int32_t shift = 0;
    while ((n >> shift) + 1 > NC_SHADOW_MM_DIM)
        shift++;
    if (shift > 8)
        return NACRE_OK; /* blocks wider than a strip (maps of 2^16 texels a side): none */
    const int32_t dim = (n >> shift) + 1;
    if (!nc_reserve(ctx, &mm->data, &mm->capacity, 2 * (size_t)dim * (size_t)dim, sizeof(float)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    mm->size = n;
    mm->shift = shift;
    mm->dim = dim;
    if (threads < 1)
        threads = 1;
#pragma omp parallel for schedule(static) num_threads(threads)
    for (int32_t by = 0; by < dim; by++)
        mm_block_row(sm->depth, n, shift, dim, by, mm->data + 2 * (size_t)by * (size_t)dim);
    mm->generation = sm->generation;
    return NACRE_OK;
}

/* One group of 8 lookups between vol8_setup and vol8_finish: per lane whether it is live, its
 * first texel (x0, y0), bilinear fractions, comparison depths, and whether the table decided it
 * (lit: all 4 taps lit; the other live lanes not in todo: all shadowed). */
typedef struct vol8 {
    nc_v8f fx, fy, tl, limit;
    nc_v8i live, lit, todo, x0, y0;
} vol8;

static inline bool mm_valid(const nc_shadow_map *sm, const nc_shadow_minmax *mm)
{
    return mm && mm->generation != 0 && mm->generation == sm->generation && mm->size == sm->size;
}

/* The set-up of 8 lookups in a single-face map, and the table's decisions (mm: valid or NULL). */
static inline void vol8_setup(const nc_shadow_map *sm, const nc_shadow_minmax *mm, const float *px, const float *py,
                              const float *pz, float bias, vol8 *g)
{
    const nc_raster_view *v = &sm->views[0];
    const nc_mat4 *m = &v->view, *pm = &v->proj;
    const nc_v8f x = nc_v8_load(px), y = nc_v8_load(py), z = nc_v8_load(pz), zero = {0};
    nc_v8f vx = m->m[0][0] * x + m->m[0][1] * y + m->m[0][2] * z + m->m[0][3];
    nc_v8f vy = m->m[1][0] * x + m->m[1][1] * y + m->m[1][2] * z + m->m[1][3];
    nc_v8f vz = m->m[2][0] * x + m->m[2][1] * y + m->m[2][2] * z + m->m[2][3];
    nc_v8f d = -vz;
    nc_v8f ndc_x = pm->m[0][0] * vx + pm->m[0][2] * vz + pm->m[0][3];
    nc_v8f ndc_y = pm->m[1][1] * vy + pm->m[1][2] * vz + pm->m[1][3];
    float size = (float)sm->size;
    /* An orthographic map's w is 1: no division (a sun's map, the froxels' most lookups). */
    nc_v8f texel = nc_v8_splat(2.0f / (pm->m[0][0] * size));
    if (!v->orthographic) {
        ndc_x /= d;
        ndc_y /= d;
        texel = 2.0f * d / (pm->m[0][0] * size);
    }
    nc_v8f u = (ndc_x * 0.5f + 0.5f) * size - 0.5f, vv = (0.5f - ndc_y * 0.5f) * size - 0.5f;
    const nc_v8i live = (d >= linear_depth(v, 0.0f)) & (u > -1.0f) & (u < size) & (vv > -1.0f) & (vv < size);
    g->live = live;
    g->lit = (nc_v8i){0};
    g->todo = live;
    g->limit = d - fmax_fast(bias, 0.0f) * texel;
    /* An orthographic map's linear depth (m23 - t) / m22 is monotonic in t: the test moves to
     * the stored depths, one multiply-add per lane instead of a division per texel (the texels
     * within a rounding of the limit may flip). */
    const float m22 = pm->m[2][2], m23 = pm->m[2][3];
    g->tl = m23 - m22 * g->limit;
    /* The live lanes' first texels and bilinear fractions (dead lanes: texel 0, never read). */
    const nc_v8f fu = nc_v8_sel(live, nc_v8_floor(u), zero), fv = nc_v8_sel(live, nc_v8_floor(vv), zero);
    g->fx = nc_v8_sel(live, u - fu, zero);
    g->fy = nc_v8_sel(live, vv - fv, zero);
    g->x0 = __builtin_convertvector(fu, nc_v8i);
    g->y0 = __builtin_convertvector(fv, nc_v8i);
    if (!mm)
        return;
    /* The table's block [lo, hi] holds every texel of a lane's taps that is in the map (those
     * outside are lit). An orthographic map's test is t >= 1 or a comparison of t with tl, which
     * the block's ends decide for all its texels; a perspective map's linear depth
     * m23 / (t + m22) is monotonic in t over [lo, hi] when t + m22 keeps its sign there (float
     * addition and division round monotonically), so its ends bound it. A NaN pair decides
     * nothing, an infinite max no shadow (nc_shadow_minmax); NaN and infinite limits compare as
     * the taps would. */
    const nc_v8i idx = ((g->y0 + 1) >> mm->shift) * mm->dim + ((g->x0 + 1) >> mm->shift);
    nc_v8f lo, hi;
#ifdef __AVX2__
    {
        /* (min, max) pairs as doubles' bits: 4 lanes a gather */
        const __m256 p0 = _mm256_castpd_ps(_mm256_i32gather_pd((const double *)mm->data, _mm256_castsi256_si128((__m256i)idx), 8));
        const __m256 p1 = _mm256_castpd_ps(_mm256_i32gather_pd((const double *)mm->data, _mm256_extracti128_si256((__m256i)idx, 1), 8));
        lo = (nc_v8f)_mm256_castpd_ps(_mm256_permute4x64_pd(_mm256_castps_pd(_mm256_shuffle_ps(p0, p1, 0x88)), 0xd8));
        hi = (nc_v8f)_mm256_castpd_ps(_mm256_permute4x64_pd(_mm256_castps_pd(_mm256_shuffle_ps(p0, p1, 0xdd)), 0xd8));
    }
#else
    for (int l = 0; l < 8; l++) {
        lo[l] = mm->data[2 * (size_t)idx[l]];
        hi[l] = mm->data[2 * (size_t)idx[l] + 1];
    }
#endif
    const nc_v8f cmp = v->orthographic ? g->tl : g->limit;
    nc_v8i all_lit, all_dark;
    if (v->orthographic) {
        if (m22 < 0.0f) {
            all_lit = (lo >= 1.0f) | (lo >= cmp);
            all_dark = (hi < 1.0f) & (hi < cmp);
        } else {
            all_lit = (lo >= 1.0f) | (hi <= cmp);
            all_dark = (hi < 1.0f) & (lo > cmp);
        }
    } else {
        const nc_v8f den_lo = lo + m22, den_hi = hi + m22;
        const nc_v8i mono = ((den_lo > 0.0f) & (den_hi > 0.0f)) | ((den_lo < 0.0f) & (den_hi < 0.0f));
        const nc_v8f a = m23 / den_lo, b = m23 / den_hi;
        all_lit = (lo >= 1.0f) | (mono & (min8(a, b) >= cmp));
        all_dark = (hi < 1.0f) & mono & (max8(a, b) < cmp);
    }
    g->lit = live & all_lit;
    g->todo = live & ~(all_lit | all_dark);
}

/* The texels of the lanes the table left (todo), their comparisons and the bilinear sums. */
static inline void vol8_finish(const nc_shadow_map *sm, const vol8 *g, float *out)
{
    const nc_raster_view *v = &sm->views[0];
    const float m22 = v->proj.m[2][2], m23 = v->proj.m[2][3];
    const nc_v8f zero = {0}, one = nc_v8_splat(1.0f);
    /* Per tap, the lanes it lights: the decided lit ones, and the others' comparisons of their
     * texels (1, no caster, outside the map). */
    nc_v8i lit_k[4] = {g->lit, g->lit, g->lit, g->lit};
    const uint32_t todo_bits = nc_v8_bits(g->todo);
    if (todo_bits) {
        const float *map = sm->depth;
        const int n = sm->size;
        for (int k = 0; k < 4; k++) {
            nc_v8f t;
#ifdef __AVX2__
            nc_v8i tx = g->x0 + (k & 1), ty = g->y0 + (k >> 1);
            nc_v8i in = g->todo & (tx >= 0) & (ty >= 0) & (tx < n) & (ty < n);
            t = (nc_v8f)_mm256_mask_i32gather_ps((__m256)one, map, (__m256i)(ty * n + tx), (__m256)in, 4);
#else
            float ts[8];
            for (int l = 0; l < 8; l++) {
                int tx = g->x0[l] + (k & 1), ty = g->y0[l] + (k >> 1);
                bool in = (todo_bits >> l & 1u) && tx >= 0 && ty >= 0 && tx < n && ty < n;
                ts[l] = in ? map[(size_t)ty * (size_t)n + (size_t)tx] : 1.0f;
            }
            t = nc_v8_load(ts);
#endif
            nc_v8i behind;
            if (v->orthographic)
                behind = m22 < 0.0f ? t >= g->tl : t <= g->tl;
            else
                behind = m23 / (t + m22) >= g->limit;
            lit_k[k] = g->lit | (g->todo & ((t >= 1.0f) | behind));
        }
    }
    /* The weights as the taps sum them, whoever decided (a lit lane's sum need not be 1). */
    nc_v8f sum = zero;
    for (int k = 0; k < 4; k++) {
        nc_v8f wt = ((k & 1) ? g->fx : 1.0f - g->fx) * ((k >> 1) ? g->fy : 1.0f - g->fy);
        sum += nc_v8_sel(lit_k[k], wt, zero);
    }
    nc_v8_store(out, nc_v8_sel(g->live, sum, one));
}

/* Fetch the rows of the texels that the undecided lanes will read. */
static inline void vol8_prefetch(const nc_shadow_map *sm, const vol8 *g)
{
    const int n = sm->size;
    for (uint32_t bits = nc_v8_bits(g->todo); bits; bits &= bits - 1) {
        const int l = __builtin_ctz(bits), x = g->x0[l] > 0 ? g->x0[l] : 0, y = g->y0[l];
        if (y >= 0)
            __builtin_prefetch(sm->depth + (size_t)y * (size_t)n + (size_t)x);
        if (y + 1 < n)
            __builtin_prefetch(sm->depth + (size_t)(y + 1) * (size_t)n + (size_t)x);
    }
}

void nc_shadow_lookup_volume8(const nc_shadow_map *sm, const float *px, const float *py, const float *pz, float bias,
                              float *out)
{
    if (!sm || !sm->depth || sm->size < 1 || sm->kind == NC_SHADOW_CUBE) {
        for (int l = 0; l < 8; l++)
            out[l] = nc_shadow_lookup_volume(sm, nc_v3(px[l], py[l], pz[l]), 0.5f, bias);
        return;
    }
    vol8 g;
    vol8_setup(sm, NULL, px, py, pz, bias, &g);
    vol8_finish(sm, &g, out);
}

/* Groups set up (and their texels fetched) before the first is finished: a column's worth. */
#define VOL_CHUNK 8

uint32_t nc_shadow_lookup_volume_n(const nc_shadow_map *sm, const nc_shadow_minmax *mm, uint32_t n, const float *px,
                                   const float *py, const float *pz, float bias, float *out)
{
    uint32_t read = 0;
    if (!sm || !sm->depth || sm->size < 1 || sm->kind == NC_SHADOW_CUBE) {
        for (uint32_t i = 0; i < n; i += 8)
            nc_shadow_lookup_volume8(sm, px + i, py + i, pz + i, bias, out + i);
        return n;
    }
    if (!mm_valid(sm, mm))
        mm = NULL;
    vol8 g[VOL_CHUNK];
    for (uint32_t c0 = 0; c0 < n; c0 += 8 * VOL_CHUNK) {
        const uint32_t cn = (n - c0) / 8 < VOL_CHUNK ? (n - c0) / 8 : VOL_CHUNK;
        for (uint32_t q = 0; q < cn; q++) {
            const uint32_t i = c0 + 8 * q;
            vol8_setup(sm, mm, px + i, py + i, pz + i, bias, &g[q]);
            vol8_prefetch(sm, &g[q]);
        }
        for (uint32_t q = 0; q < cn; q++) {
            read += (uint32_t)__builtin_popcount(nc_v8_bits(g[q].todo));
            vol8_finish(sm, &g[q], out + c0 + 8 * q);
        }
    }
    return read;
}
