/*
 * math.h: small inline vector and matrix helpers for setup code (cameras, transforms, lights).
 * Hot loops work on flat float arrays instead.
 *
 * Conventions: column vectors, p' = M p; nc_mat4 is row-major storage m[row][col]. Right-handed
 * view space looking down -z. Projections map to clip space with w = -z_view (perspective) and
 * NDC x, y in [-1, 1] (y up), NDC z in [0, 1] from near to far.
 */
#ifndef NACRE_MATH_H
#define NACRE_MATH_H

#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <string.h>

#define NC_PI 3.14159265358979323846f
#define NC_DEG2RAD (NC_PI / 180.0f)

/* m ? a : b for a mask m of 0 or 1, as bit operations, for loops meant to vectorize: they
 * compute every value on every lane and pick with this. A ?: on floats lets GCC move the chosen
 * operation into a branch, and it does not if-convert a floating-point operation that could trap
 * (-ftrapping-math), so the loop would stay scalar. */
static inline float nc_sel(int32_t m, float a, float b)
{
    uint32_t ua, ub, mask = 0u - (uint32_t)m;
    memcpy(&ua, &a, sizeof(ua));
    memcpy(&ub, &b, sizeof(ub));
    uint32_t r = (ua & mask) | (ub & ~mask);
    float f;
    memcpy(&f, &r, sizeof(f));
    return f;
}

typedef struct nc_vec3 { float x, y, z; } nc_vec3;
typedef struct nc_vec4 { float x, y, z, w; } nc_vec4;
typedef struct nc_mat4 { float m[4][4]; } nc_mat4;

/* e^x for |x| < 87 (0 below -87, e^87 above): 2^(x log2 e) split into an integer power, built
 * in the exponent bits, and a degree-5 polynomial of the fraction; relative error under 4e-6.
 * Several times faster than expf where kernels take one per pixel and particle or per piece of
 * a march (billboards, the layered march); volume.h's nc_vol_exp_fast is the one to use where
 * expf's accuracy (1e-7) is needed. */
static inline float nc_fast_exp(float x)
{
    float y = x * 1.44269504f;
    if (!(y > -126.0f))
        return 0.0f;
    y = y < 126.0f ? y : 126.0f;
    float n = floorf(y), f = y - n;
    float p = 1.8775767e-3f;
    p = p * f + 8.9893397e-3f;
    p = p * f + 5.5826318e-2f;
    p = p * f + 2.4015361e-1f;
    p = p * f + 6.9315308e-1f;
    p = p * f + 9.9999994e-1f;
    int32_t bits = ((int32_t)n + 127) << 23;
    float scale;
    memcpy(&scale, &bits, sizeof(scale));
    return p * scale;
}

static inline nc_vec3 nc_v3(float x, float y, float z) { nc_vec3 r = {x, y, z}; return r; }
static inline nc_vec3 nc_v3a(const float *a) { nc_vec3 r = {a[0], a[1], a[2]}; return r; }
static inline void nc_v3store(nc_vec3 v, float *a) { a[0] = v.x; a[1] = v.y; a[2] = v.z; }
static inline nc_vec3 nc_add(nc_vec3 a, nc_vec3 b) { return nc_v3(a.x + b.x, a.y + b.y, a.z + b.z); }
static inline nc_vec3 nc_sub(nc_vec3 a, nc_vec3 b) { return nc_v3(a.x - b.x, a.y - b.y, a.z - b.z); }
static inline nc_vec3 nc_mul(nc_vec3 a, nc_vec3 b) { return nc_v3(a.x * b.x, a.y * b.y, a.z * b.z); }
static inline nc_vec3 nc_scale(nc_vec3 a, float s) { return nc_v3(a.x * s, a.y * s, a.z * s); }
static inline float nc_dot(nc_vec3 a, nc_vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static inline nc_vec3 nc_cross(nc_vec3 a, nc_vec3 b)
{
    return nc_v3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
static inline float nc_length(nc_vec3 a) { return sqrtf(nc_dot(a, a)); }
static inline nc_vec3 nc_normalize(nc_vec3 a)
{
    float l = nc_length(a);
    return l > 0.0f ? nc_scale(a, 1.0f / l) : a;
}
static inline nc_vec3 nc_vmin(nc_vec3 a, nc_vec3 b)
{
    return nc_v3(fminf(a.x, b.x), fminf(a.y, b.y), fminf(a.z, b.z));
}
static inline nc_vec3 nc_vmax(nc_vec3 a, nc_vec3 b)
{
    return nc_v3(fmaxf(a.x, b.x), fmaxf(a.y, b.y), fmaxf(a.z, b.z));
}
/* Slab test of the ray o + t d against the box [lo, hi], narrowing [*t0, *t1] (pass the range of
 * t to search, e.g. -inf..inf or 0..1 for a segment). *axis (when not NULL) gets the axis whose
 * plane the ray enters by, -1 if none narrowed *t0. False when the ray runs parallel to and
 * outside a slab; otherwise the caller tests the interval (empty when *t1 < *t0). */
static inline bool nc_ray_box(const float o[3], const float d[3], const float lo[3], const float hi[3], float *t0,
                              float *t1, int *axis)
{
    int ax = -1;
    for (int k = 0; k < 3; k++) {
        if (d[k] == 0.0f) {
            if (o[k] < lo[k] || o[k] > hi[k])
                return false;
            continue;
        }
        float inv = 1.0f / d[k];
        float a = (lo[k] - o[k]) * inv, b = (hi[k] - o[k]) * inv;
        if (a > b) {
            float tmp = a;
            a = b;
            b = tmp;
        }
        if (a > *t0) {
            *t0 = a;
            ax = k;
        }
        if (b < *t1)
            *t1 = b;
    }
    if (axis)
        *axis = ax;
    return true;
}

/* A unit vector perpendicular to unit n (Duff et al. 2017 branchless frame). */
static inline void nc_basis(nc_vec3 n, nc_vec3 *t, nc_vec3 *b)
{
    float s = copysignf(1.0f, n.z);
    float a = -1.0f / (s + n.z);
    float c = n.x * n.y * a;
    *t = nc_v3(1.0f + s * n.x * n.x * a, s * c, -s * n.x);
    *b = nc_v3(c, s + n.y * n.y * a, -n.y);
}

static inline nc_mat4 nc_mat4_identity(void)
{
    nc_mat4 r = {{{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}, {0, 0, 0, 1}}};
    return r;
}
static inline nc_mat4 nc_mat4_mul(nc_mat4 a, nc_mat4 b)
{
    nc_mat4 r;
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++)
            r.m[i][j] = a.m[i][0] * b.m[0][j] + a.m[i][1] * b.m[1][j] + a.m[i][2] * b.m[2][j] +
                        a.m[i][3] * b.m[3][j];
    return r;
}
static inline nc_mat4 nc_mat4_transpose(nc_mat4 a)
{
    nc_mat4 r;
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++)
            r.m[i][j] = a.m[j][i];
    return r;
}
static inline nc_vec3 nc_mat4_point(const nc_mat4 *a, nc_vec3 p)
{
    return nc_v3(a->m[0][0] * p.x + a->m[0][1] * p.y + a->m[0][2] * p.z + a->m[0][3],
                 a->m[1][0] * p.x + a->m[1][1] * p.y + a->m[1][2] * p.z + a->m[1][3],
                 a->m[2][0] * p.x + a->m[2][1] * p.y + a->m[2][2] * p.z + a->m[2][3]);
}
static inline nc_vec3 nc_mat4_dir(const nc_mat4 *a, nc_vec3 d)
{
    return nc_v3(a->m[0][0] * d.x + a->m[0][1] * d.y + a->m[0][2] * d.z,
                 a->m[1][0] * d.x + a->m[1][1] * d.y + a->m[1][2] * d.z,
                 a->m[2][0] * d.x + a->m[2][1] * d.y + a->m[2][2] * d.z);
}
static inline nc_vec4 nc_mat4_apply(const nc_mat4 *a, nc_vec4 p)
{
    nc_vec4 r;
    r.x = a->m[0][0] * p.x + a->m[0][1] * p.y + a->m[0][2] * p.z + a->m[0][3] * p.w;
    r.y = a->m[1][0] * p.x + a->m[1][1] * p.y + a->m[1][2] * p.z + a->m[1][3] * p.w;
    r.z = a->m[2][0] * p.x + a->m[2][1] * p.y + a->m[2][2] * p.z + a->m[2][3] * p.w;
    r.w = a->m[3][0] * p.x + a->m[3][1] * p.y + a->m[3][2] * p.z + a->m[3][3] * p.w;
    return r;
}
static inline nc_mat4 nc_mat4_translate(nc_vec3 t)
{
    nc_mat4 r = nc_mat4_identity();
    r.m[0][3] = t.x; r.m[1][3] = t.y; r.m[2][3] = t.z;
    return r;
}
static inline nc_mat4 nc_mat4_scale(nc_vec3 s)
{
    nc_mat4 r = nc_mat4_identity();
    r.m[0][0] = s.x; r.m[1][1] = s.y; r.m[2][2] = s.z;
    return r;
}
/* Rotation by `radians` about unit `axis` (right-hand rule). */
static inline nc_mat4 nc_mat4_rotate(nc_vec3 axis, float radians)
{
    nc_vec3 a = nc_normalize(axis);
    float c = cosf(radians), s = sinf(radians), t = 1.0f - c;
    nc_mat4 r = nc_mat4_identity();
    r.m[0][0] = t * a.x * a.x + c;       r.m[0][1] = t * a.x * a.y - s * a.z; r.m[0][2] = t * a.x * a.z + s * a.y;
    r.m[1][0] = t * a.x * a.y + s * a.z; r.m[1][1] = t * a.y * a.y + c;       r.m[1][2] = t * a.y * a.z - s * a.x;
    r.m[2][0] = t * a.x * a.z - s * a.y; r.m[2][1] = t * a.y * a.z + s * a.x; r.m[2][2] = t * a.z * a.z + c;
    return r;
}
/* General inverse by cofactors; returns false (and identity) if singular. */
bool nc_mat4_inverse(nc_mat4 a, nc_mat4 *out);
/* World-to-view for a camera at `eye` looking at `target`. */
nc_mat4 nc_mat4_look_at(nc_vec3 eye, nc_vec3 target, nc_vec3 up);
/* View-to-clip, vertical fov in radians, NDC z in [0, 1]. */
nc_mat4 nc_mat4_perspective(float fov_y, float aspect, float znear, float zfar);
/* View-to-clip for a box [l,r]x[b,t] and depths [znear, zfar] in front of the eye. */
nc_mat4 nc_mat4_ortho(float l, float r, float b, float t, float znear, float zfar);
/* Closest point of triangle abc to p (Ericson 2005, 5.1.5): its squared distance, and its
 * barycentric weights of b and c in *wb, *wc (a degenerate triangle gives vertex a). */
float nc_closest_on_triangle(const float p[3], const float a[3], const float b[3], const float c[3], float *wb,
                             float *wc);

#endif /* NACRE_MATH_H */
