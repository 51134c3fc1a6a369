/*
 * surfaces.c: the path tracer's opaque BSDF: Lambert + normalized Blinn-Phong with the
 * conventions of shade/phong.c (f = kd / pi + ks (s + 8) / (8 pi) cos^s theta_h), sampled by
 * choosing a lobe with probability diffuse_prob (kd over kd + ks): cosine-weighted directions,
 * or a half vector h with density (s + 1) / (2 pi) cos^s theta_h reflected about (pdf divided by
 * 4 wo.h). Sampling (bsdf_sample, diffuse_prob) is inline in pt_internal.h; evaluation is here.
 * Directions are unit vectors pointing away from the surface; n is the shading normal on the
 * side of wo.
 *
 * A translucent object's surface is a smooth dielectric of the material's eta (Fresnel
 * reflection or refraction, chosen by the Fresnel probability), or, with eta == 1, index
 * matched: not a scattering vertex at all, the path just changes medium. Both are events of the
 * path loop (trace_path in integrator.c), not BSDFs here.
 */
#include "pathtrace/pt_internal.h"

#ifdef NACRE_HAVE_EMBREE

/* Direction at angle acos(cos_t) from axis `n`, azimuth 2 pi u (BSDF, light cone, phase and
 * guide sampling all use it). */
nc_vec3 nc_pt_around(nc_vec3 n, float cos_t, float u)
{
    nc_vec3 t, b;
    nc_basis(n, &t, &b);
    float sin_t = sqrtf(fmaxf(0.0f, 1.0f - cos_t * cos_t)), phi = 2.0f * PT_PI * u;
    return nc_normalize(nc_add(nc_scale(n, cos_t), nc_add(nc_scale(t, sin_t * cosf(phi)), nc_scale(b, sin_t * sinf(phi)))));
}

/* The BSDF f(wo, wi) (without the cosine), and in *pdf the solid-angle density of bsdf_sample. */
nc_vec3 nc_pt_bsdf_eval(const nacre_material_desc *m, nc_vec3 n, nc_vec3 wo, nc_vec3 wi, float *pdf)
{
    float ci = nc_dot(n, wi), co = nc_dot(n, wo);
    *pdf = 0;
    if (ci <= 0 || co <= 0)
        return nc_v3(0, 0, 0);
    nc_vec3 h = nc_normalize(nc_add(wi, wo));
    float nh = fmaxf(0.0f, nc_dot(n, h));
    float s = m->shininess;
    float spec = (s + 8.0f) / (8.0f * PT_PI) * (s > 0 ? powf(nh, s) : 1.0f);
    float pd = diffuse_prob(m);
    float ph = (s + 1.0f) / (2.0f * PT_PI) * (s > 0 ? powf(nh, s) : 1.0f);
    *pdf = pd * ci / PT_PI + (1.0f - pd) * ph / (4.0f * fmaxf(nc_dot(wo, h), 1e-6f));
    return nc_v3(m->diffuse[0] / PT_PI + m->specular[0] * spec, m->diffuse[1] / PT_PI + m->specular[1] * spec,
                 m->diffuse[2] / PT_PI + m->specular[2] * spec);
}

#endif /* NACRE_HAVE_EMBREE */
