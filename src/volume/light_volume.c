/*
 * light_volume.c: optical-depth grids towards one light through one bounded patterned fog
 * (light_volume.h; seed 003 §2.2.3, the fog's shadow on itself).
 */
#include "volume/light_volume.h"
#include "core/math.h"
#include "core/simd.h"

#include "scene/medium.h"

#include <float.h>
#include <math.h>
#include <string.h>

/* World point of fog-local q (w2l is a rotation and a translation: its inverse is the transpose). */
static void local_to_world(const nc_fog_one *o, const float q[3], float x[3])
{
    float d[3] = {q[0] - o->w2l[0][3], q[1] - o->w2l[1][3], q[2] - o->w2l[2][3]};
    for (int c = 0; c < 3; c++)
        x[c] = o->w2l[0][c] * d[0] + o->w2l[1][c] * d[1] + o->w2l[2][c] * d[2];
}

static bool same3(const float a[3])
{
    return memcmp(a, a + 1, sizeof(float)) == 0 && memcmp(a, a + 2, sizeof(float)) == 0;
}

bool nc_light_volume_fog_gray(const nc_fog_one *o)
{
    /* Equal bits, not equal values: 0 and -0 (or two NaNs) could round apart further on. An
     * emission grid's blackbody scales the channels apart (fogs' absorption never has it). */
    const nacre_material_desc *m = o->medium;
    if (!same3(o->sigma_a) || !same3(o->sigma_s) || !m || m->pattern.blackbody || !same3(m->sigma_a) ||
        !same3(m->sigma_s))
        return false;
    /* A volume scales medium 1 (medium 2 unused); the other patterns pick or blend medium 2. */
    if (m->pattern.type == NACRE_PATTERN_NONE || m->pattern.type == NACRE_PATTERN_VOLUME)
        return true;
    return same3(m->pattern.sigma_a2) && same3(m->pattern.sigma_s2);
}

/* Plane (n, d) of the grid frame, n x + d >= 0 inside, as a plane of the world (the frame is
 * axes x + offset, axes a rotation: n (axes x + offset) + d = (axes^T n) x + n offset + d). */
static void add_plane(nc_light_volume *v, const double n[3], double d)
{
    float *r = v->reach[v->reach_planes++];
    for (int c = 0; c < 3; c++)
        r[c] = (float)(n[0] * v->axes[0][c] + n[1] * v->axes[1][c] + n[2] * v->axes[2][c]);
    r[3] = (float)(d + n[0] * v->offset[0] + n[1] * v->offset[1] + n[2] * v->offset[2]);
}

/* The planes of nc_light_volume_reach8. A directional grid's lookups are 0 beside its columns
 * and before they start (node 0 of every column is 0): its 4 sides and its near end. A point
 * light outside the box reaches the box's fog only along rays through the box: its points lie
 * in the cone from the light over the box (bounded by the planes through the light and the
 * box's silhouette edges: those of the 12 edges whose plane has the whole box on one side) and
 * behind the faces that the light sees (x = L + s (b - L) for b in the box and s >= 1). A light
 * inside the box, or nearly, reaches everywhere. */
static void reach_setup(nc_light_volume *v, const nc_fog_one *o, const float hi[3])
{
    v->reach_planes = v->reach_faces = 0;
    double scale = 0.0;
    if (v->directional) {
        for (int k = 0; k < 3; k++) {
            double top = (double)v->lo[k] + (double)v->step[k] * (v->n[k] - 1);
            scale = fmax(scale, fmax(fabs(v->lo[k]), fmax(fabs(hi[k]), fabs(top))));
            double n[3] = {0, 0, 0};
            n[k] = 1.0;
            add_plane(v, n, -v->lo[k]);
            if (k < 2) {
                n[k] = -1.0;
                add_plane(v, n, top);
            }
        }
        v->reach_faces = v->reach_planes;
        v->reach_scale = (float)(1.0 + scale);
        v->reach_inv_r = 0.0f;
        return;
    }
    const double L[3] = {v->light[0], v->light[1], v->light[2]}, h[3] = {o->half[0], o->half[1], o->half[2]};
    double r2 = 0.0;
    for (int k = 0; k < 3; k++) {
        double out = fabs(L[k]) - h[k];
        r2 += out > 0.0 ? out * out : 0.0;
        scale = fmax(scale, fmax(fabs(v->light_world[k]), fmax(fabs(v->offset[k]), h[k])));
    }
    scale += 1.0;
    v->reach_scale = (float)scale;
    double r = sqrt(r2);
    if (!(r > 1e-3 * scale)) /* inside or nearly (or not finite) */
        return;
    v->reach_inv_r = (float)(1.0 / r);
    for (int k = 0; k < 3; k++) {
        double n[3] = {0, 0, 0};
        if (L[k] > h[k])
            n[k] = -1.0;
        else if (L[k] < -h[k])
            n[k] = 1.0;
        else
            continue;
        add_plane(v, n, h[k]);
    }
    v->reach_faces = v->reach_planes;
    for (int j = 0; j < 3; j++)
        for (int e = 0; e < 4; e++) {
            /* The edge along axis j at the signs e of the other two axes. */
            int k = (j + 1) % 3, m = (j + 2) % 3;
            double p0[3], a[3] = {0, 0, 0}, b[3], n[3];
            p0[j] = -h[j];
            p0[k] = e & 1 ? h[k] : -h[k];
            p0[m] = e & 2 ? h[m] : -h[m];
            a[j] = 2.0 * h[j];
            for (int c = 0; c < 3; c++)
                b[c] = p0[c] - L[c];
            n[0] = a[1] * b[2] - a[2] * b[1];
            n[1] = a[2] * b[0] - a[0] * b[2];
            n[2] = a[0] * b[1] - a[1] * b[0];
            double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
            if (!(len > 1e-12 * (2.0 * h[j]) * sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2])))
                continue;
            for (int c = 0; c < 3; c++)
                n[c] /= len;
            /* The box on one side (its edge's corners on the plane, to rounding). */
            double smin = INFINITY, smax = -INFINITY, tol = 1e-9 * scale;
            for (int q = 0; q < 8; q++) {
                double sq = 0.0;
                for (int c = 0; c < 3; c++)
                    sq += n[c] * ((q >> c & 1 ? h[c] : -h[c]) - L[c]);
                smin = fmin(smin, sq);
                smax = fmax(smax, sq);
            }
            if (!(smin >= -tol) && !(smax <= tol))
                continue;
            if (!(smin >= -tol))
                for (int c = 0; c < 3; c++)
                    n[c] = -n[c];
            add_plane(v, n, -(n[0] * L[0] + n[1] * L[1] + n[2] * L[2]));
        }
}

void nc_light_volume_setup(nc_light_volume *v, const nc_fog_one *o, bool directional, const float dir[3],
                           const float pos[3], uint32_t res)
{
    memset(v, 0, sizeof(*v));
    res = res < 2 ? 2 : res > NC_LIGHT_VOLUME_MAX_RES ? NC_LIGHT_VOLUME_MAX_RES : res;
    v->directional = directional;
    v->fog = o;
    v->gray = nc_light_volume_fog_gray(o);
    v->n[0] = v->n[1] = v->n[2] = res;
    float hi[3];
    if (directional) {
        const nc_vec3 d = nc_normalize(nc_v3a(dir));
        const nc_vec3 helper = fabsf(d.y) < 0.9f ? nc_v3(0.0f, 1.0f, 0.0f) : nc_v3(1.0f, 0.0f, 0.0f);
        const nc_vec3 e1 = nc_normalize(nc_cross(helper, d));
        nc_v3store(e1, v->axes[0]);
        nc_v3store(nc_cross(d, e1), v->axes[1]);
        nc_v3store(d, v->axes[2]);
        /* The light-space bounds of the box's corners. */
        for (int k = 0; k < 3; k++) {
            v->lo[k] = INFINITY;
            hi[k] = -INFINITY;
        }
        for (int c = 0; c < 8; c++) {
            float q[3] = {c & 1 ? o->half[0] : -o->half[0], c & 2 ? o->half[1] : -o->half[1],
                          c & 4 ? o->half[2] : -o->half[2]},
                  x[3];
            local_to_world(o, q, x);
            for (int k = 0; k < 3; k++) {
                float g = v->axes[k][0] * x[0] + v->axes[k][1] * x[1] + v->axes[k][2] * x[2];
                v->lo[k] = g < v->lo[k] ? g : v->lo[k];
                hi[k] = g > hi[k] ? g : hi[k];
            }
        }
    } else {
        for (int k = 0; k < 3; k++) {
            for (int c = 0; c < 3; c++)
                v->axes[k][c] = o->w2l[k][c];
            v->offset[k] = o->w2l[k][3];
            v->lo[k] = -o->half[k];
            hi[k] = o->half[k];
        }
        memcpy(v->light_world, pos, sizeof(v->light_world));
        for (int k = 0; k < 3; k++)
            v->light[k] = v->axes[k][0] * pos[0] + v->axes[k][1] * pos[1] + v->axes[k][2] * pos[2] + v->offset[k];
    }
    for (int k = 0; k < 3; k++) {
        float span = hi[k] - v->lo[k];
        v->step[k] = (span > 0.0f ? span : 1e-6f) / (float)(v->n[k] - 1);
        v->inv_step[k] = 1.0f / v->step[k];
    }
    reach_setup(v, o, hi);
}

static inline float cap_tau(double t) { return t < NC_LIGHT_VOLUME_TAU_MAX ? (float)t : NC_LIGHT_VOLUME_TAU_MAX; }

/* Directional: column (i, j) from where the light enters it, one step per node (its nodes are
 * contiguous in tau: a column is written in one pass, not a cache line per node). */
static void build_column(const nc_fog_field *f, nc_light_volume *v, uint32_t i, uint32_t j)
{
    const nc_fog_one *o = v->fog;
    uint32_t ns = v->n[2];
    float u = v->lo[0] + (float)i * v->step[0], w = v->lo[1] + (float)j * v->step[1];
    const float *d = v->axes[2];
    float p0[3];
    for (int c = 0; c < 3; c++)
        p0[c] = u * v->axes[0][c] + w * v->axes[1][c] + v->lo[2] * d[c];
    float local[3 * NC_LIGHT_VOLUME_MAX_RES], sa[3 * NC_LIGHT_VOLUME_MAX_RES], ss[3 * NC_LIGHT_VOLUME_MAX_RES];
    double G[NC_LIGHT_VOLUME_MAX_RES];
    uint32_t step_of[NC_LIGHT_VOLUME_MAX_RES];
    const size_t stride = v->gray ? 1 : 3;
    const int channels = (int)stride;
    float *out = v->tau + stride * ((size_t)i * v->n[1] + j) * ns;
    double a = 0.0, b = (double)v->step[2] * (ns - 1);
    uint32_t m = 0;
    if (nc_fog_field_segment(o, p0, d, &a, &b)) {
        for (uint32_t k = 0; k + 1 < ns; k++) {
            double t0 = (double)k * v->step[2], t1 = t0 + v->step[2];
            t0 = t0 > a ? t0 : a;
            t1 = t1 < b ? t1 : b;
            if (!(t1 > t0))
                continue;
            float t = (float)(0.5 * (t0 + t1)), x[3] = {p0[0] + t * d[0], p0[1] + t * d[1], p0[2] + t * d[2]};
            for (int r = 0; r < 3; r++)
                local[3 * m + r] = o->w2l[r][0] * x[0] + o->w2l[r][1] * x[1] + o->w2l[r][2] * x[2] + o->w2l[r][3];
            G[m] = nc_vol_height_integral(&o->h, p0[1], d[1], t0, t1);
            step_of[m++] = k;
        }
    }
    if (m > 0)
        nc_medium_eval(f->scene, o->medium, local, m, sa, ss);
    double tau[3] = {0, 0, 0};
    uint32_t q = 0;
    for (uint32_t k = 0; k < ns; k++) {
        for (int c = 0; c < channels; c++)
            out[k * stride + c] = cap_tau(tau[c]);
        if (q < m && step_of[q] == k) {
            for (int c = 0; c < channels; c++) {
                double st = (double)sa[3 * q + c] + ss[3 * q + c];
                if (st > 0.0 && G[q] > 0.0)
                    tau[c] += st * G[q];
            }
            q++;
        }
    }
}

/* Point: node (i, j, k) marched towards the light. */
static void build_node(const nc_fog_field *f, nc_light_volume *v, uint32_t i, uint32_t j, uint32_t k, float *scratch)
{
    float q[3] = {v->lo[0] + (float)i * v->step[0], v->lo[1] + (float)j * v->step[1], v->lo[2] + (float)k * v->step[2]};
    float x[3];
    local_to_world(v->fog, q, x);
    const float *lw = v->light_world;
    float w[3] = {lw[0] - x[0], lw[1] - x[1], lw[2] - x[2]};
    float dist = sqrtf(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    double tau[3] = {0, 0, 0};
    if (dist > 0.0f) {
        for (int c = 0; c < 3; c++)
            w[c] /= dist;
        nc_fog_one_optical_depth(f, v->fog, x, w, dist, tau, scratch);
    }
    const size_t stride = v->gray ? 1 : 3;
    float *out = v->tau + stride * (((size_t)i * v->n[1] + j) * v->n[2] + k);
    for (size_t c = 0; c < stride; c++)
        out[c] = cap_tau(tau[c]);
}

void nc_light_volume_build(const nc_fog_field *f, nc_light_volume *v, int threads)
{
    (void)threads;
    if (v->directional) {
        int64_t cols = (int64_t)v->n[0] * v->n[1];
#pragma omp parallel for schedule(dynamic, 8) num_threads(threads)
        for (int64_t c = 0; c < cols; c++)
            build_column(f, v, (uint32_t)(c % v->n[0]), (uint32_t)(c / v->n[0]));
        return;
    }
    /* Rows along z, whose nodes are contiguous. */
    int64_t rows = (int64_t)v->n[0] * v->n[1];
#pragma omp parallel for schedule(dynamic, 4) num_threads(threads)
    for (int64_t r = 0; r < rows; r++) {
        float scratch[NC_FOG_TAU_SCRATCH(256)];
        for (uint32_t k = 0; k < v->n[2]; k++)
            build_node(f, v, (uint32_t)(r / v->n[1]), (uint32_t)(r % v->n[1]), k, scratch);
    }
}

/* Trilinear at grid coordinates g (node units, inside [0, n - 1] per axis). */
static void trilinear(const nc_light_volume *v, const float g[3], float tau[3])
{
    uint32_t i0[3];
    float t[3];
    for (int k = 0; k < 3; k++) {
        uint32_t i = (uint32_t)g[k];
        i0[k] = i + 1 < v->n[k] ? i : v->n[k] - 2;
        t[k] = g[k] - (float)i0[k];
    }
    const size_t sz = v->gray ? 1 : 3, sy = sz * v->n[2], sx = sy * v->n[1];
    const int channels = (int)sz;
    const float *p = v->tau + i0[0] * sx + i0[1] * sy + i0[2] * sz;
    for (int c = 0; c < channels; c++) {
        const float *q = p + c;
        float a = q[0] + t[0] * (q[sx] - q[0]), b = q[sy] + t[0] * (q[sy + sx] - q[sy]);
        float e = q[sz] + t[0] * (q[sz + sx] - q[sz]), h = q[sz + sy] + t[0] * (q[sz + sy + sx] - q[sz + sy]);
        float ab = a + t[1] * (b - a), eh = e + t[1] * (h - e);
        tau[c] = ab + t[2] * (eh - ab);
    }
    if (v->gray)
        tau[1] = tau[2] = tau[0];
}

void nc_light_volume_lookup(const nc_light_volume *v, const float x[3], float tau[3])
{
    tau[0] = tau[1] = tau[2] = 0.0f;
    float g[3];
    bool inside = true;
    for (int k = 0; k < 3; k++) {
        float c = v->axes[k][0] * x[0] + v->axes[k][1] * x[1] + v->axes[k][2] * x[2] + v->offset[k];
        g[k] = (c - v->lo[k]) * v->inv_step[k];
        float top = (float)(v->n[k] - 1);
        inside = inside && g[k] >= 0.0f && g[k] <= top;
    }
    if (v->directional) {
        /* Beside the columns: the ray misses the box; before or past a column: its ends. */
        if (!(g[0] >= 0.0f && g[0] <= (float)(v->n[0] - 1) && g[1] >= 0.0f && g[1] <= (float)(v->n[1] - 1)))
            return;
        float top = (float)(v->n[2] - 1);
        g[2] = g[2] > 0.0f ? (g[2] < top ? g[2] : top) : 0.0f;
        trilinear(v, g, tau);
        return;
    }
    if (!inside) {
        /* Outside the box: where the segment to the light enters it (a slab test in the grid's
         * frame; for a sphere too: no fog of this one lies between the box and the sphere). */
        float a = 0.0f, b = 1.0f, c[3], d[3], top[3];
        for (int k = 0; k < 3; k++) {
            c[k] = g[k] * v->step[k] + v->lo[k];
            d[k] = v->light[k] - c[k];
            top[k] = v->lo[k] + v->step[k] * (float)(v->n[k] - 1);
        }
        if (!nc_ray_box(c, d, v->lo, top, &a, &b, NULL) || !(a < b))
            return;
        for (int k = 0; k < 3; k++) {
            float top = (float)(v->n[k] - 1), gk = (c[k] + a * d[k] - v->lo[k]) * v->inv_step[k];
            g[k] = gk > 0.0f ? (gk < top ? gk : top) : 0.0f;
        }
    }
    trilinear(v, g, tau);
}

uint32_t nc_light_volume_reach8(const nc_light_volume *v, const float *px, const float *py, const float *pz)
{
    if (v->reach_planes == 0)
        return 0xffu;
    const nc_v8f x = nc_v8_load(px), y = nc_v8_load(py), z = nc_v8_load(pz);
    const nc_v8i abs_mask = (nc_v8i){0} + 0x7fffffff; /* fabsf: the sign bit cleared */
    nc_v8f ax = (nc_v8f)((nc_v8i)x & abs_mask), ay = (nc_v8f)((nc_v8i)y & abs_mask), az = (nc_v8f)((nc_v8i)z & abs_mask);
    nc_v8i finite = (ax <= FLT_MAX) & (ay <= FLT_MAX) & (az <= FLT_MAX);
    nc_v8f big = nc_v8_sel(ax > ay, ax, ay);
    nc_v8f s = v->reach_scale + nc_v8_sel(big > az, big, az);
    nc_v8f m = 1e-4f * s;
    nc_v8i in = ~finite;
    nc_v8i ok = (nc_v8i){0} == 0;
    uint32_t k = 0;
    for (; k < v->reach_faces; k++) {
        const float *r = v->reach[k];
        ok &= r[0] * x + r[1] * y + r[2] * z + r[3] + m >= 0.0f;
    }
    if (k < v->reach_planes) {
        const float *L = v->light_world;
        nc_v8f lx = x - L[0], ly = y - L[1], lz = z - L[2];
        nc_v8f rho = nc_v8_sqrt(lx * lx + ly * ly + lz * lz);
        nc_v8f mc = 1e-4f * (s + rho * (s + rho) * v->reach_inv_r);
        for (; k < v->reach_planes; k++) {
            const float *r = v->reach[k];
            ok &= r[0] * x + r[1] * y + r[2] * z + r[3] + mc >= 0.0f;
        }
    }
    return nc_v8_bits(in | ok);
}

/* nc_light_volume_lookup lane by lane, the same arithmetic (the results are equal bit for bit):
 * the grid coordinates, a point light's slab test for the lanes outside the box, then trilinear
 * over gathers of the 8 corners. */
void nc_light_volume_lookup8(const nc_light_volume *v, const float *px, const float *py, const float *pz,
                             float *tau)
{
    const nc_v8f x = nc_v8_load(px), y = nc_v8_load(py), z = nc_v8_load(pz), zero = {0};
    nc_v8f g[3];
    nc_v8i inside = (nc_v8i){0} == 0;
    for (int k = 0; k < 3; k++) {
        nc_v8f c = v->axes[k][0] * x + v->axes[k][1] * y + v->axes[k][2] * z + v->offset[k];
        g[k] = (c - v->lo[k]) * v->inv_step[k];
        float top = (float)(v->n[k] - 1);
        inside &= (g[k] >= 0.0f) & (g[k] <= top);
    }
    nc_v8i live;
    if (v->directional) {
        live = (g[0] >= 0.0f) & (g[0] <= (float)(v->n[0] - 1)) & (g[1] >= 0.0f) & (g[1] <= (float)(v->n[1] - 1));
        float top = (float)(v->n[2] - 1);
        g[2] = nc_v8_sel(g[2] > 0.0f, nc_v8_sel(g[2] < top, g[2], nc_v8_splat(top)), zero);
    } else {
        live = inside;
        if (nc_v8_bits(inside) != 0xffu) {
            /* nc_ray_box from c along d over [0, 1], per lane */
            nc_v8f c[3], d[3], a = zero, b = nc_v8_splat(1.0f);
            nc_v8i ok = (nc_v8i){0} == 0;
            for (int k = 0; k < 3; k++) {
                c[k] = g[k] * v->step[k] + v->lo[k];
                d[k] = v->light[k] - c[k];
                float top = v->lo[k] + v->step[k] * (float)(v->n[k] - 1);
                nc_v8i flat = d[k] == 0.0f;
                ok &= ~(flat & ((c[k] < v->lo[k]) | (c[k] > top)));
                nc_v8f inv = 1.0f / d[k];
                nc_v8f ea = (v->lo[k] - c[k]) * inv, eb = (top - c[k]) * inv;
                nc_v8i swap = ea > eb;
                nc_v8f lo = nc_v8_sel(swap, eb, ea), hi = nc_v8_sel(swap, ea, eb);
                a = nc_v8_sel(~flat & (lo > a), lo, a);
                b = nc_v8_sel(~flat & (hi < b), hi, b);
            }
            nc_v8i enter = ~inside & ok & (a < b);
            for (int k = 0; k < 3; k++) {
                float top = (float)(v->n[k] - 1);
                nc_v8f gk = (c[k] + a * d[k] - v->lo[k]) * v->inv_step[k];
                gk = nc_v8_sel(gk > 0.0f, nc_v8_sel(gk < top, gk, nc_v8_splat(top)), zero);
                g[k] = nc_v8_sel(enter, gk, g[k]);
            }
            live |= enter;
        }
    }
    if (!nc_v8_bits(live)) {
        memset(tau, 0, 24 * sizeof(float));
        return;
    }
    /* trilinear; dead lanes read node 0 and give 0 */
    nc_v8i i0[3];
    nc_v8f t[3];
    for (int k = 0; k < 3; k++) {
        nc_v8i i = nc_v8i_sel(live, __builtin_convertvector(nc_v8_sel(live, g[k], zero), nc_v8i), (nc_v8i){0});
        i0[k] = nc_v8i_sel(i + 1 < (int32_t)v->n[k], i, (nc_v8i){0} + (int32_t)(v->n[k] - 2));
        t[k] = g[k] - __builtin_convertvector(i0[k], nc_v8f);
    }
    const int32_t sz = v->gray ? 1 : 3, sy = sz * (int32_t)v->n[2], sx = sy * (int32_t)v->n[1];
    const nc_v8i base = i0[0] * sx + i0[1] * sy + i0[2] * sz;
    for (int ch = 0; ch < sz; ch++) {
        const float *q = v->tau + ch;
        nc_v8f q000 = nc_v8_gather(q, base), q100 = nc_v8_gather(q, base + sx);
        nc_v8f q010 = nc_v8_gather(q, base + sy), q110 = nc_v8_gather(q, base + (sy + sx));
        nc_v8f q001 = nc_v8_gather(q, base + sz), q101 = nc_v8_gather(q, base + (sz + sx));
        nc_v8f q011 = nc_v8_gather(q, base + (sz + sy)), q111 = nc_v8_gather(q, base + (sz + sy + sx));
        nc_v8f a = q000 + t[0] * (q100 - q000), b = q010 + t[0] * (q110 - q010);
        nc_v8f e = q001 + t[0] * (q101 - q001), h = q011 + t[0] * (q111 - q011);
        nc_v8f ab = a + t[1] * (b - a), eh = e + t[1] * (h - e);
        nc_v8_store(tau + 8 * ch, nc_v8_sel(live, ab + t[2] * (eh - ab), zero));
    }
    if (v->gray) {
        memcpy(tau + 8, tau, 8 * sizeof(float));
        memcpy(tau + 16, tau, 8 * sizeof(float));
    }
}
