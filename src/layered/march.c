/*
 * march.c: single scattering in layered materials along one view ray (Francois, Pattanaik,
 * Bouatouch, Breton 2006, "Subsurface texture mapping", seed 001: eqs. 1-5, 9-12, 15,
 * algorithms 1 and 2).
 *
 * The view ray refracts at P into the material and is followed to M_max (eq. 15), where the
 * depth reaches Depth_max: the depth at which the optical depth below the surface reaches
 * -log(eps) in every channel (eps = settings.layered.epsilon). A point M at distance s on it
 * lies in the layer that the depth map gives at M's depth (PM . -N_P) and at the texture
 * coordinates of M's projection into the tangent plane (uv_P + (grad u . PM, grad v . PM)),
 * as the seed's FindLayer. The light reaching M (algorithm 2) enters through the plane of eq. 9,
 * interpolated between P's tangent plane and the fitted plane N_SP with the weights |MM_max| and
 * |MP|; unlike the seed, the light direction is refracted there (Snell, the material's eta), so
 * that K'M of eq. 10 is the refracted path, and the entry point gets the Fresnel transmittance
 * and the cos_i / cos_t compression of the refracted beam. The path K'M is split among the
 * layers by eq. 12, with the thicknesses averaged between M and K'. The scattered light is
 * attenuated back to P, refracted out with Fresnel (1 - F) and the 1 / eta^2 of radiance leaving
 * a denser medium. Phase: Henyey-Greenstein with the layer's g (the seed's table 1 uses the
 * Schlick approximation of it).
 *
 * Shadows: the shadow maps are read at P and at the entry point K' of M_max's light; a sample's
 * visibility is interpolated between the two with the same weights as the planes (2 lookups per
 * light and pixel instead of one per sample).
 *
 * Integration along the ray, two ways (nacre_layered_integration):
 *  - SAMPLES, the seed's: N steps, one point sample at each step's midpoint, transmittance to P
 *    carried from step to step (eq. 13).
 *  - ANALYTIC: the N steps are cut at the layer boundaries they cross (found by bisection on the
 *    depth map), so that every piece has constant coefficients; over a piece the integrand
 *    (reduced intensity times the transmittance to P) is the product of exponentials of
 *    quantities linear in s when the surface is flat, and is integrated in closed form as the
 *    exponential through its two end values: len (f_a - f_b) / ln(f_a / f_b). For flat layers
 *    this is exact for any N; elsewhere a few steps reach the answer of hundreds of samples.
 * Both stop once the transmittance back to P is below NC_MARCH_T_MIN in every channel.
 *
 * Units: scene units for lengths, sigma per scene unit, irradiance and intensity as the lights
 * (render.h); the result is radiance.
 */
#include "layered/march.h"

#include "core/optics.h"
#include "scene/lights.h"

#include <math.h>
#include <string.h>

#define NC_MARCH_T_MIN 1e-4f
#define NC_MARCH_MAX_SAMPLES 4096
#define NC_MARCH_MAX_PIECES (NC_MARCH_MAX_SAMPLES + 64)
#define NC_MARCH_BISECT 2

/* Plain comparisons: fminf / fmaxf are library calls here (their NaN rules), and the march
 * makes hundreds per pixel. */
static inline float minf(float a, float b) { return a < b ? a : b; }
static inline float maxf(float a, float b) { return a > b ? a : b; }

static inline float dot3(const float a[3], const float b[3]) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

static inline float hg(float c, float g)
{
    float d = 1.0f + g * g - 2.0f * g * c;
    return (1.0f - g * g) / (4.0f * (float)NC_PI * d * sqrtf(d));
}

void nc_layer_medium_init(const nacre_scene *scene, const nacre_material_desc *m, float epsilon, nc_layer_medium *out)
{
    memset(out, 0, sizeof(*out));
    nc_layers_init(scene, &m->layering, &out->stack);
    out->count = out->stack.count;
    for (uint32_t j = 0; j <= out->count; j++) {
        const float *sa = j < out->count ? m->layering.layers[j].sigma_a : m->sigma_a;
        const float *ss = j < out->count ? m->layering.layers[j].sigma_s : m->sigma_s;
        for (int c = 0; c < 3; c++) {
            out->ss[j][c] = ss[c];
            out->st[j][c] = sa[c] + ss[c];
        }
        out->g[j] = j < out->count ? m->layering.layers[j].g : m->g;
    }
    out->eta = m->eta;
    /* Depth_max: down through the layers at their thinnest (lo), the depth where the optical
     * depth along the normal reaches -log(eps) in the least extinguishing channel. */
    const float target = -logf(epsilon);
    float tau = 0, z = 0, top = 0;
    out->depth_max = -1;
    for (uint32_t j = 0; j <= out->count; j++) {
        float st = fminf(out->st[j][0], fminf(out->st[j][1], out->st[j][2]));
        float thick = j < out->count ? fmaxf(out->stack.lo[j] - top, 0.0f) : INFINITY;
        if (st > 0 && tau + st * thick >= target) {
            out->depth_max = z + (target - tau) / st;
            break;
        }
        if (j < out->count) {
            tau += st * thick;
            z += thick;
            top = out->stack.lo[j];
        }
    }
    if (!(out->depth_max > 0)) { /* a core that does not attenuate: the extent of the scene */
        float ext = 0;
        for (int k = 0; k < 3; k++)
            ext = fmaxf(ext, scene->bounds_max[k] - scene->bounds_min[k]);
        out->depth_max = fmaxf(z, ext > 0 && isfinite(ext) ? ext : 1.0f);
    }
}

float nc_layer_medium_first_sigma_t(const nc_layer_medium *m)
{
    /* The first layer that has thickness somewhere (a zero-depth layer is not below anything). */
    uint32_t j = 0;
    while (j < m->count && !(m->stack.hi[j] > 0))
        j++;
    return fminf(m->st[j][0], fminf(m->st[j][1], m->st[j][2]));
}


/* The view ray inside: M(s) = P + s d; depth(s) = s dz; uv(s) = uv_P + s duv. */
typedef struct ray_ctx {
    const nc_layer_medium *m;
    const nc_march_point *pt;
    float d[3], dz, du, dv;
    float len; /* |P M_max| */
} ray_ctx;

static inline uint32_t layer_at(const ray_ctx *r, float s)
{
    return r->m->count ? nc_layers_find(&r->m->stack, s * r->dz, r->pt->uv[0] + s * r->du, r->pt->uv[1] + s * r->dv)
                       : 0;
}

/* What one light gives at M(s), before the layer's sigma_s and phase: irradiance across the
 * refracted beam after the path K'M (rgb), and the cosine between the beam and the view ray. */
typedef struct light_at {
    bool lit;     /* false: no light reaches M this way (the rest is 0) */
    float lw;     /* log of the scalar factor: Fresnel, beam compression, 1 / r^2, spot cone */
    float tau[3]; /* optical depth along K'M */
    float cos_s;
    float k[3];   /* K' */
} light_at;

static void eval_light(const ray_ctx *r, const nacre_light_desc *l, float co, float ci, float s, light_at *out)
{
    const nc_march_point *pt = r->pt;
    const nc_layer_medium *m = r->m;
    memset(out, 0, sizeof(*out));
    float mpt[3];
    for (int k = 0; k < 3; k++)
        mpt[k] = pt->p[k] + s * r->d[k];
    /* Eq. 9: the plane of M between the tangent plane (weight |MM_max|) and the fitted one (|MP|). */
    float a = maxf(r->len - s, 0.0f), b = s;
    float nm[3], pm[3], nn = 0;
    for (int k = 0; k < 3; k++) {
        nm[k] = a * pt->n[k] + b * pt->ns[k];
        pm[k] = (a * pt->p[k] + b * pt->ps[k]) / (a + b > 0 ? a + b : 1.0f);
        nn += nm[k] * nm[k];
    }
    if (!(nn > 0))
        return;
    nn = 1.0f / sqrtf(nn);
    for (int k = 0; k < 3; k++)
        nm[k] *= nn;
    /* Outside direction towards the light, from M (algorithm 2) */
    float w[3];
    if (l->type == NACRE_LIGHT_DIRECTIONAL) {
        for (int k = 0; k < 3; k++)
            w[k] = -l->direction[k];
    } else {
        float len2 = 0;
        for (int k = 0; k < 3; k++) {
            w[k] = l->position[k] - mpt[k];
            len2 += w[k] * w[k];
        }
        if (!(len2 > 0))
            return;
        float inv = 1.0f / sqrtf(len2);
        for (int k = 0; k < 3; k++)
            w[k] *= inv;
    }
    float cos_i = dot3(nm, w);
    if (!(cos_i > 0))
        return;
    const float eta = m->eta;
    float sin2_t = (1.0f - cos_i * cos_i) / (eta * eta);
    float cos_t = sqrtf(maxf(1.0f - sin2_t, 0.0f));
    if (!(cos_t > 1e-4f))
        return;
    float wt[3]; /* towards the light inside */
    for (int k = 0; k < 3; k++)
        wt[k] = (w[k] - cos_i * nm[k]) / eta + cos_t * nm[k];
    float h = 0;
    for (int k = 0; k < 3; k++)
        h += (pm[k] - mpt[k]) * nm[k];
    h = maxf(h, 0.0f);
    const float km = h / cos_t; /* eq. 10, along the refracted ray */
    for (int k = 0; k < 3; k++)
        out->k[k] = mpt[k] + km * wt[k];
    float scale = (1.0f - nc_fresnel_dielectric_f(cos_i, eta, 1.0f / (eta * eta))) * cos_i / cos_t;
    if (l->type != NACRE_LIGHT_DIRECTIONAL) {
        float dk[3], d2 = 0;
        for (int k = 0; k < 3; k++) {
            dk[k] = out->k[k] - l->position[k];
            d2 += dk[k] * dk[k];
        }
        if (!(d2 > 0))
            return;
        scale /= d2;
        if (l->type == NACRE_LIGHT_SPOT)
            scale *= nc_spot_falloff(l->falloff, dot3(dk, l->direction) / sqrtf(d2), co, ci);
    }
    /* Eq. 12: the refracted path's length in each layer, thicknesses averaged between M and K'. */
    float tau[3] = {0, 0, 0};
    if (m->count == 0) {
        for (int c = 0; c < 3; c++)
            tau[c] = m->st[0][c] * km;
    } else {
        float bm[NACRE_MAX_LAYERS], bk[NACRE_MAX_LAYERS];
        float dpk[3] = {out->k[0] - pt->p[0], out->k[1] - pt->p[1], out->k[2] - pt->p[2]};
        nc_layers_bottoms(&m->stack, pt->uv[0] + s * r->du, pt->uv[1] + s * r->dv, bm);
        nc_layers_bottoms(&m->stack, pt->uv[0] + dot3(pt->gu, dpk), pt->uv[1] + dot3(pt->gv, dpk), bk);
        float above = 0, prev_m = 0, prev_k = 0;
        for (uint32_t j = 0; j < m->count; j++) {
            float dj = 0.5f * ((bm[j] - prev_m) + (bk[j] - prev_k));
            prev_m = bm[j];
            prev_k = bk[j];
            float len = minf(km - above / cos_t, dj / cos_t);
            if (len > 0)
                for (int c = 0; c < 3; c++)
                    tau[c] += m->st[j][c] * len;
            above += dj;
        }
        float rest = km - above / cos_t;
        if (rest > 0)
            for (int c = 0; c < 3; c++)
                tau[c] += m->st[m->count][c] * rest;
    }
    if (!(scale > 0))
        return;
    out->lit = true;
    out->lw = logf(scale);
    memcpy(out->tau, tau, sizeof(tau));
    out->cos_s = dot3(wt, r->d);
}

/* A piece of the view ray [s0, s1] inside one layer. */
typedef struct piece {
    float s0, s1;
    uint8_t layer;
} piece;

/* The pieces of constant layer along [0, len] (ANALYTIC), or the N steps with the layer at their
 * midpoints (SAMPLES); stops early where the transmittance to P is negligible. */
static uint32_t make_pieces(const ray_ctx *r, const nc_march_params *prm, piece *out)
{
    const nc_layer_medium *m = r->m;
    const uint32_t n = prm->samples;
    const float step = r->len / (float)n;
    const float tau_stop = -logf(NC_MARCH_T_MIN);
    float tau_min = 0; /* view optical depth in the least extinguishing channel */
    uint32_t count = 0;
    if (!prm->analytic) {
        for (uint32_t i = 0; i < n && tau_min < tau_stop; i++) {
            uint32_t j = layer_at(r, ((float)i + 0.5f) * step);
            out[count++] = (piece){(float)i * step, (float)(i + 1) * step, (uint8_t)j};
            tau_min += minf(m->st[j][0], minf(m->st[j][1], m->st[j][2])) * step;
        }
        return count;
    }
    float lo = 0;
    uint32_t jl = layer_at(r, 0.0f);
    for (uint32_t i = 1; i <= n && tau_min < tau_stop; i++) {
        const float s = i == n ? r->len : (float)i * step;
        uint32_t j = layer_at(r, s);
        while (j != jl && count < NC_MARCH_MAX_PIECES - 2) {
            /* First change of layer after lo: layer_at(a) == jl, layer_at(b) != jl. */
            float a = lo, b = s;
            for (int it = 0; it < NC_MARCH_BISECT; it++) {
                float mid = 0.5f * (a + b);
                if (layer_at(r, mid) == jl)
                    a = mid;
                else
                    b = mid;
            }
            /* The bracket's last step is a secant on depth - bottom: exact where the boundary
             * is flat, so a handful of halvings suffice. */
            const uint32_t jb = layer_at(r, b);
            const uint32_t edge = jb > jl ? jl : jl - 1; /* the bottom crossed */
            float bot[NACRE_MAX_LAYERS] = {0, 0, 0, 0};
            nc_layers_bottoms(&m->stack, r->pt->uv[0] + a * r->du, r->pt->uv[1] + a * r->dv, bot);
            const float fa = a * r->dz - bot[edge];
            nc_layers_bottoms(&m->stack, r->pt->uv[0] + b * r->du, r->pt->uv[1] + b * r->dv, bot);
            const float fb = b * r->dz - bot[edge];
            float cut = fa != fb ? a + (b - a) * fa / (fa - fb) : b;
            cut = cut >= a && cut <= b ? cut : b;
            out[count++] = (piece){lo, cut, (uint8_t)jl};
            tau_min += minf(m->st[jl][0], minf(m->st[jl][1], m->st[jl][2])) * (cut - lo);
            lo = cut;
            /* The layer just past the cut: a bracket that held two boundaries goes on with the
             * layer between them, not the one at its end. */
            const uint32_t jn = layer_at(r, cut + 1e-3f * (b - cut));
            jl = jn != jl ? jn : jb;
        }
        out[count++] = (piece){lo, s, (uint8_t)jl};
        tau_min += minf(m->st[jl][0], minf(m->st[jl][1], m->st[jl][2])) * (s - lo);
        lo = s;
        jl = j;
        if (count >= NC_MARCH_MAX_PIECES - 2)
            break;
    }
    return count;
}

void nc_layered_radiance(const nc_layer_medium *m, const nc_march_point *pt, const nc_shade_light *lights,
                         uint32_t light_count, const nc_march_params *prm, float rgb[3])
{
    rgb[0] = rgb[1] = rgb[2] = 0;
    const float eta = m->eta;
    const float cos_o = dot3(pt->n, pt->v);
    if (!(cos_o > 0) || light_count == 0)
        return;
    /* The refracted view ray, pointing into the material. */
    float sin2_t = (1.0f - cos_o * cos_o) / (eta * eta);
    if (sin2_t >= 1.0f)
        return;
    float cos_t = sqrtf(1.0f - sin2_t);
    ray_ctx r = {.m = m, .pt = pt};
    for (int k = 0; k < 3; k++)
        r.d[k] = -pt->v[k] / eta + (cos_o / eta - cos_t) * pt->n[k];
    r.dz = -dot3(r.d, pt->n);
    r.du = dot3(pt->gu, r.d);
    r.dv = dot3(pt->gv, r.d);
    /* Eq. 15, with the refracted direction */
    r.len = m->depth_max / maxf(-dot3(pt->ns, r.d), 0.1f);
    const float t_out = (1.0f - nc_fresnel_dielectric_f(cos_o, eta, 1.0f / (eta * eta))) / (eta * eta);

    /* A directional light behind both P's tangent plane and the fitted plane is behind every
     * plane of eq. 9 (their normals are positive blends of the two): it lights no sample. */
    uint32_t lit = 0;
    for (uint32_t li = 0; li < light_count && li < 32; li++) {
        const nacre_light_desc *l = lights[li].desc;
        if (l->type != NACRE_LIGHT_DIRECTIONAL || dot3(pt->n, l->direction) < 0 || dot3(pt->ns, l->direction) < 0)
            lit |= 1u << li;
    }
    if (!lit && light_count <= 32)
        return;
    piece pieces[NC_MARCH_MAX_PIECES];
    const uint32_t np = make_pieces(&r, prm, pieces);
    for (uint32_t li = 0; li < light_count; li++) {
        const nacre_light_desc *l = lights[li].desc;
        if (li < 32 && !(lit & (1u << li)))
            continue;
        const float co = l->type == NACRE_LIGHT_SPOT ? cosf(l->outer_angle * NC_DEG2RAD) : 0.0f;
        const float ci = l->type == NACRE_LIGHT_SPOT ? cosf(l->inner_angle * NC_DEG2RAD) : 0.0f;
        /* Visibility at P and at the entry point of M_max's light. */
        float vis0 = 1, vis1 = 1;
        if (lights[li].shadow) {
            nc_vec3 n = nc_v3a(pt->n);
            vis0 = nc_shadow_lookup(lights[li].shadow, nc_v3a(pt->p), n, prm->pcf_radius, prm->shadow_bias);
            light_at far;
            eval_light(&r, l, co, ci, r.len, &far);
            vis1 = far.lit
                       ? nc_shadow_lookup(lights[li].shadow, nc_v3a(far.k), nc_v3a(pt->ns), prm->pcf_radius,
                                          prm->shadow_bias)
                       : vis0;
            if (vis0 <= 0 && vis1 <= 0)
                continue;
        }
        /* Per channel, ln of the integrand without sigma_s * strength (kc): the pieces' ends
         * share it when the layer does not change, and its difference gives the exponential's
         * rate without a logarithm per channel. */
        float tau[3] = {0, 0, 0}, sum[3] = {0, 0, 0}, kc[3];
        float lfa[3] = {0, 0, 0};
        bool a_lit = false;
        uint32_t a_layer = UINT32_MAX;
        light_at la, lb;
        for (uint32_t i = 0; i < np; i++) {
            const piece *pc = &pieces[i];
            const uint32_t j = pc->layer;
            const float len = pc->s1 - pc->s0;
            for (int c = 0; c < 3; c++)
                kc[c] = m->ss[j][c] * l->strength[c];
            if (!prm->analytic) {
                const float sm = 0.5f * (pc->s0 + pc->s1);
                eval_light(&r, l, co, ci, sm, &la);
                const float vis = vis0 + (vis1 - vis0) * (sm / r.len);
                const float w = hg(la.cos_s, m->g[j]) * vis * len;
                for (int c = 0; c < 3; c++) {
                    if (la.lit && w > 0)
                        sum[c] += kc[c] * w * expf(la.lw - la.tau[c] - tau[c] - 0.5f * m->st[j][c] * len);
                    tau[c] += m->st[j][c] * len;
                }
                continue;
            }
            if (a_layer != j) { /* the first piece, or a new layer: the start's phase changed */
                if (i == 0)
                    eval_light(&r, l, co, ci, pc->s0, &la);
                const float pa = hg(la.cos_s, m->g[j]) * (vis0 + (vis1 - vis0) * (pc->s0 / r.len));
                a_lit = la.lit && pa > 0;
                if (a_lit) {
                    const float lp = logf(pa) + la.lw;
                    for (int c = 0; c < 3; c++)
                        lfa[c] = lp - la.tau[c] - tau[c];
                }
            }
            eval_light(&r, l, co, ci, pc->s1, &lb);
            const float pb = hg(lb.cos_s, m->g[j]) * (vis0 + (vis1 - vis0) * (pc->s1 / r.len));
            const bool b_lit = lb.lit && pb > 0;
            const float lpb = b_lit ? logf(pb) + lb.lw : 0.0f;
            for (int c = 0; c < 3; c++) {
                const float tb = tau[c] + m->st[j][c] * len;
                const float lfb = lpb - lb.tau[c] - tb;
                if (a_lit && b_lit) {
                    const float q = lfa[c] - lfb, fa = expf(lfa[c]), fb = expf(lfb);
                    sum[c] += kc[c] * (q > 1e-4f || q < -1e-4f ? len * (fa - fb) / q : len * 0.5f * (fa + fb));
                } else { /* light on one end only: the trapezoid */
                    sum[c] += kc[c] * len * 0.5f * ((a_lit ? expf(lfa[c]) : 0.0f) + (b_lit ? expf(lfb) : 0.0f));
                }
                tau[c] = tb;
                lfa[c] = lfb;
            }
            a_lit = b_lit;
            a_layer = j;
            la = lb;
        }
        for (int c = 0; c < 3; c++)
            rgb[c] += sum[c] * t_out;
    }
}
