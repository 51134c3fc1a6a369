/*
 * phong.c: the baseline shading of `--method phong`: ambient + Lambert + normalized
 * Blinn-Phong, shadowed by shadow maps with PCF. It is the left image of Blanchard 2012's
 * figure 5.4, against which the translucent methods are compared.
 *
 * Radiometry: a directional light gives irradiance E (W/m^2) on a surface facing it; a point or
 * spot light of intensity I (W/sr) gives E = I / d^2. Outgoing radiance is
 *   L = E cos(theta) * (kd / pi + ks (s + 8) / (8 pi) cos^s(theta_h)) + kd * L_env,
 * the last term being a white uniform environment of radiance L_env seen by a Lambert surface
 * (unshadowed: no ambient occlusion). (s + 8) / (8 pi) normalizes Blinn-Phong so that ks is
 * close to the fraction of energy reflected specularly.
 *
 * A light's shadow lookup is skipped when its unshadowed term is below 2^-16 of what the pixel
 * already holds (NEGLIGIBLE), which for the translucent objects of the diffusion method (no
 * Lambert term, a narrow highlight) removes most lookups; pixels change by less than that bound.
 * The Blinn-Phong lobe is 0 below 2^-64 of its peak (SPEC_FLOOR): this skips powf, and the
 * slow denormal arithmetic, over most of a glossy object.
 *
 * The diffusion method reuses this pass through the subsurface hook of nc_shade_params: its
 * translucent objects keep ambient and specular and get the diffusion radiance in place of the
 * Lambert direct term (Blanchard 2012 section 4.6.2: the deferred passes are summed).
 */
#include "shade/shade.h"
#include "core/optics.h"

#include <math.h>

/* Relative contribution below which a light's shadow lookup is skipped (see nc_shade_phong):
 * 2^-16, 32 times below the resolution of a half-float EXR. */
#define NEGLIGIBLE (1.0f / 65536.0f)
/* Blinn-Phong lobe values below this are 0 (see spec_cut): 2^-64 times the lobe's peak, far
 * below anything a pixel can show next to the ambient term. */
#define SPEC_FLOOR 5.421011e-20f

void nc_material_albedo(const nacre_material_desc *m, float out[3])
{
    for (int c = 0; c < 3; c++) {
        if (m->type == NACRE_MATERIAL_OPAQUE) {
            out[c] = m->diffuse[c];
            continue;
        }
        double sp = (double)m->sigma_s[c] * (1.0 - (double)m->g);
        double st = sp + (double)m->sigma_a[c];
        out[c] = st > 0 ? (float)nc_dipole_rd(sp / st, m->eta) : 0.0f;
    }
}

/* cos theta_h below which cos^s theta_h < SPEC_FLOOR: there the specular lobe is taken as 0,
 * which saves powf and keeps its denormal results (slow to multiply) out of the pixel's
 * arithmetic. -1 (never) for s = 0. */
static float spec_cut(float shininess)
{
    return shininess > 0.0f ? powf(SPEC_FLOOR, 1.0f / shininess) : -1.0f;
}

/* Smooth spot falloff between the inner and outer cone (Hermite in cos angle). */
static float spot_falloff(const nacre_light_desc *l, nc_vec3 to_point)
{
    float c = nc_dot(nc_v3a(l->direction), to_point);
    float co = cosf(l->outer_angle * NC_DEG2RAD), ci = cosf(l->inner_angle * NC_DEG2RAD);
    if (c <= co)
        return 0.0f;
    if (c >= ci || ci <= co)
        return 1.0f;
    float t = (c - co) / (ci - co);
    return t * t * (3.0f - 2.0f * t);
}

void nc_shade_phong(const nacre_scene *scene, const nc_gbuffer *gb, const nc_shade_light *lights,
                    uint32_t light_count, const nc_shade_params *params, float *rgb, size_t stride,
                    int threads)
{
    const int32_t w = gb->width, h = gb->height;
    const float *env = scene->environment;
    /* Per-material constants, looked up per pixel by index. Materials are few; a fixed cap keeps
     * this allocation-free, and larger scenes fall back to recomputing. */
    enum { CACHE = 256 };
    float albedo[CACHE][3], spec_norms[CACHE], nh_cuts[CACHE];
    uint32_t cached = scene->material_count < CACHE ? scene->material_count : CACHE;
    for (uint32_t i = 0; i < cached; i++) {
        nc_material_albedo(&scene->materials[i], albedo[i]);
        spec_norms[i] = (scene->materials[i].shininess + 8.0f) / (8.0f * NC_PI);
        nh_cuts[i] = spec_cut(scene->materials[i].shininess);
    }

    /* Rows in small dynamic chunks: objects cover the image unevenly, and static halves left one
     * thread idle for a large part of the pass. Pixels are independent, so the image does not
     * depend on the schedule. */
#pragma omp parallel for schedule(dynamic, 8) num_threads(threads)
    for (int32_t y = 0; y < h; y++) {
        float *row = rgb + (size_t)y * stride;
        for (int32_t x = 0; x < w; x++) {
            size_t i = (size_t)y * (size_t)w + (size_t)x;
            float *out = row + 3 * (size_t)x;
            if (gb->object[i] == NC_NO_OBJECT) {
                out[0] = env[0];
                out[1] = env[1];
                out[2] = env[2];
                continue;
            }
            uint32_t mi = gb->material[i];
            const nacre_material_desc *m = &scene->materials[mi];
            float kd[3];
            if (mi < cached) {
                kd[0] = albedo[mi][0]; kd[1] = albedo[mi][1]; kd[2] = albedo[mi][2];
            } else {
                nc_material_albedo(m, kd);
            }
            nc_vec3 p = nc_v3a(gb->position + 3 * i);
            nc_vec3 n = nc_v3a(gb->normal + 3 * i);
            nc_vec3 ng = nc_v3a(gb->geo_normal + 3 * i);
            nc_vec3 v = params->orthographic ? nc_scale(params->view_dir, -1.0f)
                                             : nc_normalize(nc_sub(params->eye, p));
            float acc[3] = {kd[0] * env[0], kd[1] * env[1], kd[2] * env[2]};
            /* Diffusion method: the light that enters and leaves the medium replaces Lambert. */
            float lambert = 1.0f / NC_PI;
            if (params->subsurface_object && params->subsurface_object[gb->object[i]]) {
                float sub[3];
                params->subsurface(params->subsurface_user, gb->object[i], p, n, v, sub);
                acc[0] += sub[0];
                acc[1] += sub[1];
                acc[2] += sub[2];
                lambert = 0.0f;
            }
            float spec_norm = mi < cached ? spec_norms[mi] : (m->shininess + 8.0f) / (8.0f * NC_PI);
            for (uint32_t li = 0; li < light_count; li++) {
                const nacre_light_desc *l = lights[li].desc;
                nc_vec3 wi;
                float scale = 1.0f;
                if (l->type == NACRE_LIGHT_DIRECTIONAL) {
                    wi = nc_scale(nc_v3a(l->direction), -1.0f);
                } else {
                    nc_vec3 d = nc_sub(nc_v3a(l->position), p);
                    float d2 = nc_dot(d, d);
                    if (d2 <= 0)
                        continue;
                    wi = nc_scale(d, 1.0f / sqrtf(d2));
                    scale = 1.0f / d2;
                    if (l->type == NACRE_LIGHT_SPOT)
                        scale *= spot_falloff(l, nc_scale(wi, -1.0f));
                }
                float cos_i = nc_dot(n, wi);
                if (cos_i <= 0 || scale <= 0)
                    continue;
                nc_vec3 hv = nc_normalize(nc_add(wi, v));
                float nh = nc_dot(n, hv);
                nh = nh > 0.0f ? nh : 0.0f;
                float nh_cut = mi < cached ? nh_cuts[mi] : spec_cut(m->shininess);
                float spec = 0.0f;
                if (nh > nh_cut)
                    spec = m->shininess > 0 ? spec_norm * powf(nh, m->shininess) : spec_norm;
                else if (lambert == 0.0f)
                    continue; /* no Lambert term and no highlight: nothing to add */
                if (lights[li].shadow) {
                    /* The shadow lookup (PCF) is the most expensive part of a pixel. When this
                     * light's unshadowed term is below NEGLIGIBLE of what the pixel already has
                     * (typically the specular highlight of a subsurface pixel away from the
                     * highlight), it cannot change the pixel beyond that bound: skip the light. */
                    float unshadowed = 0.0f, have = 0.0f;
                    /* Plain comparisons: fmaxf is a library call here (NaN rules). */
                    for (int c = 0; c < 3; c++) {
                        float u = fabsf(l->strength[c] * scale * cos_i * (kd[c] * lambert + m->specular[c] * spec));
                        unshadowed = u > unshadowed ? u : unshadowed;
                        have = acc[c] > have ? acc[c] : have;
                    }
                    if (unshadowed <= NEGLIGIBLE * have)
                        continue;
                    scale *= nc_shadow_lookup(lights[li].shadow, p, ng, params->pcf_radius, params->shadow_bias);
                    if (scale <= 0)
                        continue;
                }
                float e = scale * cos_i;
                for (int c = 0; c < 3; c++)
                    acc[c] += l->strength[c] * e * (kd[c] * lambert + m->specular[c] * spec);
            }
            out[0] = acc[0];
            out[1] = acc[1];
            out[2] = acc[2];
        }
    }
}
