/*
 * math.c: the non-trivial matrix helpers of math.h (inverse, camera and projection matrices).
 */
#include "core/math.h"

bool nc_mat4_inverse(nc_mat4 a, nc_mat4 *out)
{
    const float *m = &a.m[0][0];
    float inv[16];
    inv[0] = m[5] * m[10] * m[15] - m[5] * m[11] * m[14] - m[9] * m[6] * m[15] + m[9] * m[7] * m[14] + m[13] * m[6] * m[11] - m[13] * m[7] * m[10];
    inv[4] = -m[4] * m[10] * m[15] + m[4] * m[11] * m[14] + m[8] * m[6] * m[15] - m[8] * m[7] * m[14] - m[12] * m[6] * m[11] + m[12] * m[7] * m[10];
    inv[8] = m[4] * m[9] * m[15] - m[4] * m[11] * m[13] - m[8] * m[5] * m[15] + m[8] * m[7] * m[13] + m[12] * m[5] * m[11] - m[12] * m[7] * m[9];
    inv[12] = -m[4] * m[9] * m[14] + m[4] * m[10] * m[13] + m[8] * m[5] * m[14] - m[8] * m[6] * m[13] - m[12] * m[5] * m[10] + m[12] * m[6] * m[9];
    inv[1] = -m[1] * m[10] * m[15] + m[1] * m[11] * m[14] + m[9] * m[2] * m[15] - m[9] * m[3] * m[14] - m[13] * m[2] * m[11] + m[13] * m[3] * m[10];
    inv[5] = m[0] * m[10] * m[15] - m[0] * m[11] * m[14] - m[8] * m[2] * m[15] + m[8] * m[3] * m[14] + m[12] * m[2] * m[11] - m[12] * m[3] * m[10];
    inv[9] = -m[0] * m[9] * m[15] + m[0] * m[11] * m[13] + m[8] * m[1] * m[15] - m[8] * m[3] * m[13] - m[12] * m[1] * m[11] + m[12] * m[3] * m[9];
    inv[13] = m[0] * m[9] * m[14] - m[0] * m[10] * m[13] - m[8] * m[1] * m[14] + m[8] * m[2] * m[13] + m[12] * m[1] * m[10] - m[12] * m[2] * m[9];
    inv[2] = m[1] * m[6] * m[15] - m[1] * m[7] * m[14] - m[5] * m[2] * m[15] + m[5] * m[3] * m[14] + m[13] * m[2] * m[7] - m[13] * m[3] * m[6];
    inv[6] = -m[0] * m[6] * m[15] + m[0] * m[7] * m[14] + m[4] * m[2] * m[15] - m[4] * m[3] * m[14] - m[12] * m[2] * m[7] + m[12] * m[3] * m[6];
    inv[10] = m[0] * m[5] * m[15] - m[0] * m[7] * m[13] - m[4] * m[1] * m[15] + m[4] * m[3] * m[13] + m[12] * m[1] * m[7] - m[12] * m[3] * m[5];
    inv[14] = -m[0] * m[5] * m[14] + m[0] * m[6] * m[13] + m[4] * m[1] * m[14] - m[4] * m[2] * m[13] - m[12] * m[1] * m[6] + m[12] * m[2] * m[5];
    inv[3] = -m[1] * m[6] * m[11] + m[1] * m[7] * m[10] + m[5] * m[2] * m[11] - m[5] * m[3] * m[10] - m[9] * m[2] * m[7] + m[9] * m[3] * m[6];
    inv[7] = m[0] * m[6] * m[11] - m[0] * m[7] * m[10] - m[4] * m[2] * m[11] + m[4] * m[3] * m[10] + m[8] * m[2] * m[7] - m[8] * m[3] * m[6];
    inv[11] = -m[0] * m[5] * m[11] + m[0] * m[7] * m[9] + m[4] * m[1] * m[11] - m[4] * m[3] * m[9] - m[8] * m[1] * m[7] + m[8] * m[3] * m[5];
    inv[15] = m[0] * m[5] * m[10] - m[0] * m[6] * m[9] - m[4] * m[1] * m[10] + m[4] * m[2] * m[9] + m[8] * m[1] * m[6] - m[8] * m[2] * m[5];
    double det = (double)m[0] * inv[0] + (double)m[1] * inv[4] + (double)m[2] * inv[8] + (double)m[3] * inv[12];
    if (det == 0.0 || !isfinite(det)) {
        *out = nc_mat4_identity();
        return false;
    }
    float s = (float)(1.0 / det);
    for (int i = 0; i < 16; i++)
        (&out->m[0][0])[i] = inv[i] * s;
    return true;
}

nc_mat4 nc_mat4_look_at(nc_vec3 eye, nc_vec3 target, nc_vec3 up)
{
    nc_vec3 f = nc_normalize(nc_sub(target, eye));
    nc_vec3 s = nc_cross(f, up);
    if (nc_length(s) < 1e-6f) { /* up parallel to the view direction: pick any side vector */
        nc_vec3 t, b;
        nc_basis(f, &t, &b);
        s = t;
    }
    s = nc_normalize(s);
    nc_vec3 u = nc_cross(s, f);
    nc_mat4 r = nc_mat4_identity();
    r.m[0][0] = s.x;  r.m[0][1] = s.y;  r.m[0][2] = s.z;  r.m[0][3] = -nc_dot(s, eye);
    r.m[1][0] = u.x;  r.m[1][1] = u.y;  r.m[1][2] = u.z;  r.m[1][3] = -nc_dot(u, eye);
    r.m[2][0] = -f.x; r.m[2][1] = -f.y; r.m[2][2] = -f.z; r.m[2][3] = nc_dot(f, eye);
    return r;
}

nc_mat4 nc_mat4_perspective(float fov_y, float aspect, float znear, float zfar)
{
    float f = 1.0f / tanf(0.5f * fov_y);
    nc_mat4 r = {{{0}}};
    r.m[0][0] = f / aspect;
    r.m[1][1] = f;
    /* z_ndc = (A z + B) / -z maps -znear -> 0 and -zfar -> 1 */
    r.m[2][2] = zfar / (znear - zfar);
    r.m[2][3] = znear * zfar / (znear - zfar);
    r.m[3][2] = -1.0f;
    return r;
}

nc_mat4 nc_mat4_ortho(float l, float r_, float b, float t, float znear, float zfar)
{
    nc_mat4 r = nc_mat4_identity();
    r.m[0][0] = 2.0f / (r_ - l);
    r.m[0][3] = -(r_ + l) / (r_ - l);
    r.m[1][1] = 2.0f / (t - b);
    r.m[1][3] = -(t + b) / (t - b);
    r.m[2][2] = -1.0f / (zfar - znear);
    r.m[2][3] = -znear / (zfar - znear);
    return r;
}

/* Closest point of triangle abc to p, as barycentric weights (of b and c) and squared distance:
 * the Voronoi-region walk of Ericson, "Real-Time Collision Detection" (2005), section 5.1.5. */
float nc_closest_on_triangle(const float p[3], const float a[3], const float b[3], const float c[3],
                                 float *wb, float *wc)
{
    float ab[3], ac[3], ap[3];
    for (int k = 0; k < 3; k++)
        ab[k] = b[k] - a[k], ac[k] = c[k] - a[k], ap[k] = p[k] - a[k];
#define DOT(x, y) ((x)[0] * (y)[0] + (x)[1] * (y)[1] + (x)[2] * (y)[2])
    float d1 = DOT(ab, ap), d2 = DOT(ac, ap);
    float v, w;
    if (d1 <= 0 && d2 <= 0) {
        v = 0, w = 0; /* vertex a */
    } else {
        float bp[3], cp[3];
        for (int k = 0; k < 3; k++)
            bp[k] = p[k] - b[k], cp[k] = p[k] - c[k];
        float d3 = DOT(ab, bp), d4 = DOT(ac, bp), d5 = DOT(ab, cp), d6 = DOT(ac, cp);
        float vc = d1 * d4 - d3 * d2, vb = d5 * d2 - d1 * d6, va = d3 * d6 - d5 * d4;
        if (d3 >= 0 && d4 <= d3) {
            v = 1, w = 0; /* vertex b */
        } else if (d6 >= 0 && d5 <= d6) {
            v = 0, w = 1; /* vertex c */
        } else if (vc <= 0 && d1 >= 0 && d3 <= 0) {
            v = d1 / (d1 - d3), w = 0; /* edge ab */
        } else if (vb <= 0 && d2 >= 0 && d6 <= 0) {
            v = 0, w = d2 / (d2 - d6); /* edge ac */
        } else if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
            w = (d4 - d3) / ((d4 - d3) + (d5 - d6)); /* edge bc */
            v = 1 - w;
        } else {
            float den = va + vb + vc;
            if (!(den > 0)) { /* degenerate triangle: fall back to vertex a */
                v = 0, w = 0;
            } else {
                v = vb / den;
                w = vc / den;
            }
        }
    }
#undef DOT
    float q2 = 0;
    for (int k = 0; k < 3; k++) {
        float q = a[k] + v * ab[k] + w * ac[k] - p[k];
        q2 += q * q;
    }
    *wb = v;
    *wc = w;
    return q2;
}
