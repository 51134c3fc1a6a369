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

#include <float.h>
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

/* e^x: core/math.h's nc_fast_exp (relative error under 4e-6), where expf is a library call per
 * channel and piece end. */
#define fast_exp nc_fast_exp

/* ln x for normal positive x: the exponent bits, and for the mantissa m in [sqrt(1/2), sqrt(2))
 * the series 2 atanh((m - 1) / (m + 1)) to the 9th power (truncation under 4e-10); absolute
 * error under 2e-7 after rounding. */
static inline float fast_log(float x)
{
    union {
        float f;
        int32_t i;
    } u = {.f = x};
    int32_t e = ((u.i >> 23) & 0xff) - 127;
    u.i = (u.i & 0x007fffff) | 0x3f800000; /* m in [1, 2) */
    if (u.f > 1.41421356f) {
        u.f *= 0.5f;
        e++;
    }
    const float t = (u.f - 1.0f) / (u.f + 1.0f), t2 = t * t;
    const float p = t * (2.0f + t2 * (0.66666667f + t2 * (0.4f + t2 * (0.28571429f + t2 * 0.22222222f))));
    return p + (float)e * 0.69314718f;
}

/* The depth map's layer bottoms at (u, v), as nc_layers_bottoms but in float and without integer
 * division: the march makes several per sample. Texel centres and wrapping as
 * nc_texture_sample_n; the bilinear weights differ from its double ones by float rounding (the
 * fraction of u * width keeps 24 - log2(width) bits). */
static inline void bottoms_at(const nc_layer_stack *s, float u, float v, float bottom[NACRE_MAX_LAYERS])
{
    float mapv[NACRE_MAX_LAYERS] = {1.0f, 1.0f, 1.0f, 1.0f};
    const nc_texture_rec *t = s->map;
    if (t && s->count) {
        float fu = u - floorf(u), fv = v - floorf(v);
        if (!(fu >= 0.0f && fu <= 1.0f))
            fu = 0.0f; /* NaN or infinite uv */
        if (!(fv >= 0.0f && fv <= 1.0f))
            fv = 0.0f;
        const float fx = fu * (float)t->width - 0.5f, fy = (1.0f - fv) * (float)t->height - 0.5f;
        const float x0 = floorf(fx), y0 = floorf(fy);
        const float ax = fx - x0, ay = fy - y0;
        /* x0 in [-1, width - 1]: one conditional wrap on each side */
        int32_t xa = (int32_t)x0, ya = (int32_t)y0;
        xa = xa < 0 ? xa + t->width : xa;
        ya = ya < 0 ? ya + t->height : ya;
        int32_t xb = xa + 1 < t->width ? xa + 1 : 0, yb = ya + 1 < t->height ? ya + 1 : 0;
        xa = xa < t->width ? xa : 0;
        ya = ya < t->height ? ya : 0;
        const size_t ch = (size_t)t->channels, w = (size_t)t->width;
        const float *p00 = t->data + ch * ((size_t)xa + w * (size_t)ya), *p10 = t->data + ch * ((size_t)xb + w * (size_t)ya);
        const float *p01 = t->data + ch * ((size_t)xa + w * (size_t)yb), *p11 = t->data + ch * ((size_t)xb + w * (size_t)yb);
        const float w00 = (1 - ay) * (1 - ax), w10 = (1 - ay) * ax, w01 = ay * (1 - ax), w11 = ay * ax;
        for (uint32_t k = 0; k < s->count; k++)
            mapv[k] = w00 * p00[k] + w10 * p10[k] + w01 * p01[k] + w11 * p11[k];
    }
    float run = 0;
    for (uint32_t j = 0; j < s->count; j++) {
        run = maxf(run, s->depth[j] * mapv[j]);
        bottom[j] = run;
    }
}

/* nc_layers_find with bottoms_at. */
static inline uint32_t find_at(const nc_layer_stack *s, float d, float u, float v)
{
    uint32_t j;
    if (nc_layers_settled(s, d, &j))
        return j;
    float bottom[NACRE_MAX_LAYERS];
    bottoms_at(s, u, v, bottom);
    return nc_layers_after(s, d, j, bottom);
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
    return r->m->count ? find_at(&r->m->stack, s * r->dz, r->pt->uv[0] + s * r->du, r->pt->uv[1] + s * r->dv)
                       : 0;
}

/* What one light gives at M(s), before the layer's sigma_s and phase: irradiance across the
 * refracted beam after the path K'M (rgb), and the cosine between the beam and the view ray. */
typedef struct light_at {
    bool lit;     /* false: no light reaches M this way (the rest is 0) */
    float w;      /* the scalar factor: Fresnel, beam compression, 1 / r^2, spot cone */
    float tau[3]; /* optical depth along K'M */
    float cos_s;
    float k[3];   /* K' */
} light_at;

/* bmc: the layer bottoms at M (stride floats apart) from nc_march_ray_make, or NULL: read here. */
static void eval_light(const ray_ctx *r, const nacre_light_desc *l, float co, float ci, float s, const float *bmc,
                       uint32_t stride, light_at *out)
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
        if (bmc)
            for (uint32_t j = 0; j < m->count; j++)
                bm[j] = bmc[(size_t)j * stride];
        else
            bottoms_at(&m->stack, pt->uv[0] + s * r->du, pt->uv[1] + s * r->dv, bm);
        bottoms_at(&m->stack, pt->uv[0] + dot3(pt->gu, dpk), pt->uv[1] + dot3(pt->gv, dpk), bk);
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
    out->w = scale;
    memcpy(out->tau, tau, sizeof(tau));
    out->cos_s = dot3(wt, r->d);
}

/* Light at a batch of points of the view ray: what eval_light gives, structure of arrays. */
#define NC_MARCH_BATCH 64
#define NC_MARCH_PAD 8 /* the closed forms read 8 lanes past any point */
typedef struct light_batch {
    float w[NC_MARCH_BATCH + NC_MARCH_PAD]; /* light_at.w, 0 where no light reaches (lit = w > 0) */
    float tau[3][NC_MARCH_BATCH + NC_MARCH_PAD];
    float cos_s[NC_MARCH_BATCH + NC_MARCH_PAD];
    float k[3][NC_MARCH_BATCH]; /* light_at.k, where lit: M_max's is the entry point of its shadow lookup */
} light_batch;

static void eval_scalar(const ray_ctx *r, const nacre_light_desc *l, float co, float ci, const float *s, uint32_t n,
                        const float *bm, uint32_t stride, light_batch *out)
{
    for (uint32_t i = 0; i < n; i++) {
        light_at la;
        eval_light(r, l, co, ci, s[i], bm ? bm + i : NULL, stride, &la);
        const bool lit = la.lit && la.w > 0;
        out->w[i] = lit ? la.w : 0.0f;
        for (int c = 0; c < 3; c++)
            out->tau[c][i] = lit ? la.tau[c] : 0.0f;
        out->cos_s[i] = lit ? la.cos_s : 0.0f;
        for (int c = 0; c < 3; c++)
            out->k[c][i] = la.k[c];
    }
}

#ifdef __AVX2__
#include <immintrin.h>

/* bottoms_at on 8 uvs: the same float arithmetic, the texels through gathers. */
static inline void bottoms8(const nc_layer_stack *s, __m256 u, __m256 v, __m256 bottom[NACRE_MAX_LAYERS])
{
    const __m256 one = _mm256_set1_ps(1.0f), zero = _mm256_setzero_ps();
    __m256 mapv[NACRE_MAX_LAYERS] = {one, one, one, one};
    const nc_texture_rec *t = s->map;
    if (t && s->count) {
        __m256 fu = _mm256_sub_ps(u, _mm256_floor_ps(u)), fv = _mm256_sub_ps(v, _mm256_floor_ps(v));
        /* NaN or infinite uv: 0 (ordered compares are false on NaN) */
        fu = _mm256_and_ps(fu, _mm256_and_ps(_mm256_cmp_ps(fu, zero, _CMP_GE_OQ), _mm256_cmp_ps(fu, one, _CMP_LE_OQ)));
        fv = _mm256_and_ps(fv, _mm256_and_ps(_mm256_cmp_ps(fv, zero, _CMP_GE_OQ), _mm256_cmp_ps(fv, one, _CMP_LE_OQ)));
        const __m256 half = _mm256_set1_ps(0.5f);
        const __m256 fx = _mm256_sub_ps(_mm256_mul_ps(fu, _mm256_set1_ps((float)t->width)), half);
        const __m256 fy = _mm256_sub_ps(_mm256_mul_ps(_mm256_sub_ps(one, fv), _mm256_set1_ps((float)t->height)), half);
        const __m256 x0 = _mm256_floor_ps(fx), y0 = _mm256_floor_ps(fy);
        const __m256 ax = _mm256_sub_ps(fx, x0), ay = _mm256_sub_ps(fy, y0);
        const __m256i W = _mm256_set1_epi32(t->width), H = _mm256_set1_epi32(t->height);
        const __m256i izero = _mm256_setzero_si256(), ione = _mm256_set1_epi32(1);
        __m256i xa = _mm256_cvttps_epi32(x0), ya = _mm256_cvttps_epi32(y0);
        xa = _mm256_add_epi32(xa, _mm256_and_si256(_mm256_cmpgt_epi32(izero, xa), W));
        ya = _mm256_add_epi32(ya, _mm256_and_si256(_mm256_cmpgt_epi32(izero, ya), H));
        __m256i xb = _mm256_add_epi32(xa, ione), yb = _mm256_add_epi32(ya, ione);
        xb = _mm256_and_si256(xb, _mm256_cmpgt_epi32(W, xb));
        yb = _mm256_and_si256(yb, _mm256_cmpgt_epi32(H, yb));
        xa = _mm256_and_si256(xa, _mm256_cmpgt_epi32(W, xa));
        ya = _mm256_and_si256(ya, _mm256_cmpgt_epi32(H, ya));
        const __m256i ch = _mm256_set1_epi32(t->channels);
        const __m256i rowa = _mm256_mullo_epi32(ya, W), rowb = _mm256_mullo_epi32(yb, W);
        const __m256i i00 = _mm256_mullo_epi32(_mm256_add_epi32(xa, rowa), ch);
        const __m256i i10 = _mm256_mullo_epi32(_mm256_add_epi32(xb, rowa), ch);
        const __m256i i01 = _mm256_mullo_epi32(_mm256_add_epi32(xa, rowb), ch);
        const __m256i i11 = _mm256_mullo_epi32(_mm256_add_epi32(xb, rowb), ch);
        const __m256 bx = _mm256_sub_ps(one, ax), by = _mm256_sub_ps(one, ay);
        const __m256 w00 = _mm256_mul_ps(by, bx), w10 = _mm256_mul_ps(by, ax);
        const __m256 w01 = _mm256_mul_ps(ay, bx), w11 = _mm256_mul_ps(ay, ax);
        if (t->channels == 4) {
            /* RGBA: a lane's four texels are four 16-byte loads; the same products and sums
             * per channel as the gathers below, then an 8 x 4 transpose. Gathers of 8 lanes are
             * slow on some CPUs (Zen 2/3: several times 8 loads). */
            int32_t o[4][8];
            float wt[4][8];
            _mm256_storeu_si256((__m256i *)o[0], i00);
            _mm256_storeu_si256((__m256i *)o[1], i10);
            _mm256_storeu_si256((__m256i *)o[2], i01);
            _mm256_storeu_si256((__m256i *)o[3], i11);
            _mm256_storeu_ps(wt[0], w00);
            _mm256_storeu_ps(wt[1], w10);
            _mm256_storeu_ps(wt[2], w01);
            _mm256_storeu_ps(wt[3], w11);
            __m128 lane[8];
            for (int q = 0; q < 8; q++) {
                __m128 acc = _mm_mul_ps(_mm_set1_ps(wt[0][q]), _mm_loadu_ps(t->data + o[0][q]));
                acc = _mm_fmadd_ps(_mm_set1_ps(wt[1][q]), _mm_loadu_ps(t->data + o[1][q]), acc);
                acc = _mm_fmadd_ps(_mm_set1_ps(wt[2][q]), _mm_loadu_ps(t->data + o[2][q]), acc);
                lane[q] = _mm_fmadd_ps(_mm_set1_ps(wt[3][q]), _mm_loadu_ps(t->data + o[3][q]), acc);
            }
            /* rows q | q + 4 in the two halves, then a 4 x 4 transpose in each half */
            const __m256 r0 = _mm256_set_m128(lane[4], lane[0]), r1 = _mm256_set_m128(lane[5], lane[1]);
            const __m256 r2 = _mm256_set_m128(lane[6], lane[2]), r3 = _mm256_set_m128(lane[7], lane[3]);
            const __m256 t0 = _mm256_unpacklo_ps(r0, r1), t1 = _mm256_unpackhi_ps(r0, r1);
            const __m256 t2 = _mm256_unpacklo_ps(r2, r3), t3 = _mm256_unpackhi_ps(r2, r3);
            const __m256 c[4] = {_mm256_castpd_ps(_mm256_unpacklo_pd(_mm256_castps_pd(t0), _mm256_castps_pd(t2))),
                                 _mm256_castpd_ps(_mm256_unpackhi_pd(_mm256_castps_pd(t0), _mm256_castps_pd(t2))),
                                 _mm256_castpd_ps(_mm256_unpacklo_pd(_mm256_castps_pd(t1), _mm256_castps_pd(t3))),
                                 _mm256_castpd_ps(_mm256_unpackhi_pd(_mm256_castps_pd(t1), _mm256_castps_pd(t3)))};
            for (uint32_t k = 0; k < s->count; k++)
                mapv[k] = c[k];
        } else {
            for (uint32_t k = 0; k < s->count; k++) {
                const float *d = t->data + k;
                __m256 acc = _mm256_mul_ps(w00, _mm256_i32gather_ps(d, i00, 4));
                acc = _mm256_fmadd_ps(w10, _mm256_i32gather_ps(d, i10, 4), acc);
                acc = _mm256_fmadd_ps(w01, _mm256_i32gather_ps(d, i01, 4), acc);
                mapv[k] = _mm256_fmadd_ps(w11, _mm256_i32gather_ps(d, i11, 4), acc);
            }
        }
    }
    __m256 run = _mm256_setzero_ps();
    for (uint32_t j = 0; j < s->count; j++) {
        run = _mm256_max_ps(run, _mm256_mul_ps(_mm256_set1_ps(s->depth[j]), mapv[j]));
        bottom[j] = run;
    }
}

static inline __m256 dot8(const __m256 a[3], const __m256 b[3])
{
    return _mm256_fmadd_ps(a[2], b[2], _mm256_fmadd_ps(a[1], b[1], _mm256_mul_ps(a[0], b[0])));
}

/* eval_light on 8 points of the ray (directional and point lights; spot lights take the scalar
 * path for their falloff). Lanes past n repeat the last point and are not stored. bmc: the
 * bottoms at the 8 points (8 readable lanes per layer, stride floats apart) or NULL. */
static void eval8(const ray_ctx *r, const nacre_light_desc *l, const float *sp, uint32_t n, const float *bmc,
                  uint32_t stride, light_batch *out, uint32_t at)
{
    const nc_march_point *pt = r->pt;
    const nc_layer_medium *m = r->m;
    float sl[8];
    for (uint32_t i = 0; i < 8; i++)
        sl[i] = sp[i < n ? i : n - 1];
    const __m256 s = _mm256_loadu_ps(sl), zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.0f);
    __m256 mpt[3], nm[3], pm[3], w[3], wt[3], k[3];
    const __m256 a = _mm256_max_ps(_mm256_sub_ps(_mm256_set1_ps(r->len), s), zero), b = s;
    const __m256 ab = _mm256_add_ps(a, b);
    const __m256 inv_ab = _mm256_div_ps(one, _mm256_blendv_ps(one, ab, _mm256_cmp_ps(ab, zero, _CMP_GT_OQ)));
    for (int c = 0; c < 3; c++) {
        mpt[c] = _mm256_fmadd_ps(s, _mm256_set1_ps(r->d[c]), _mm256_set1_ps(pt->p[c]));
        nm[c] = _mm256_fmadd_ps(a, _mm256_set1_ps(pt->n[c]), _mm256_mul_ps(b, _mm256_set1_ps(pt->ns[c])));
        pm[c] = _mm256_mul_ps(_mm256_fmadd_ps(a, _mm256_set1_ps(pt->p[c]), _mm256_mul_ps(b, _mm256_set1_ps(pt->ps[c]))),
                              inv_ab);
    }
    const __m256 nn = dot8(nm, nm);
    __m256 ok = _mm256_cmp_ps(nn, zero, _CMP_GT_OQ);
    const __m256 inv_nn = _mm256_div_ps(one, _mm256_sqrt_ps(_mm256_blendv_ps(one, nn, ok)));
    for (int c = 0; c < 3; c++)
        nm[c] = _mm256_mul_ps(nm[c], inv_nn);
    if (l->type == NACRE_LIGHT_DIRECTIONAL) {
        for (int c = 0; c < 3; c++)
            w[c] = _mm256_set1_ps(-l->direction[c]);
    } else {
        for (int c = 0; c < 3; c++)
            w[c] = _mm256_sub_ps(_mm256_set1_ps(l->position[c]), mpt[c]);
        const __m256 len2 = dot8(w, w);
        ok = _mm256_and_ps(ok, _mm256_cmp_ps(len2, zero, _CMP_GT_OQ));
        const __m256 inv = _mm256_div_ps(one, _mm256_sqrt_ps(_mm256_blendv_ps(one, len2, ok)));
        for (int c = 0; c < 3; c++)
            w[c] = _mm256_mul_ps(w[c], inv);
    }
    const __m256 cos_i = dot8(nm, w);
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(cos_i, zero, _CMP_GT_OQ));
    const float eta = m->eta;
    const __m256 veta = _mm256_set1_ps(eta), inv_eta2 = _mm256_set1_ps(1.0f / (eta * eta));
    const __m256 sin2_t = _mm256_mul_ps(_mm256_fnmadd_ps(cos_i, cos_i, one), inv_eta2);
    const __m256 cos_t = _mm256_sqrt_ps(_mm256_max_ps(_mm256_sub_ps(one, sin2_t), zero));
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(cos_t, _mm256_set1_ps(1e-4f), _CMP_GT_OQ));
    const __m256 cos_t_safe = _mm256_blendv_ps(one, cos_t, ok);
    const __m256 inv_eta = _mm256_set1_ps(1.0f / eta);
    for (int c = 0; c < 3; c++)
        wt[c] = _mm256_fmadd_ps(_mm256_fnmadd_ps(cos_i, nm[c], w[c]), inv_eta, _mm256_mul_ps(cos_t, nm[c]));
    __m256 h = zero;
    for (int c = 0; c < 3; c++)
        h = _mm256_fmadd_ps(_mm256_sub_ps(pm[c], mpt[c]), nm[c], h);
    h = _mm256_max_ps(h, zero);
    const __m256 km = _mm256_div_ps(h, cos_t_safe);
    for (int c = 0; c < 3; c++)
        k[c] = _mm256_fmadd_ps(km, wt[c], mpt[c]);
    /* Fresnel (nc_fresnel_dielectric_f): its cos_t is the refracted one above */
    const __m256 ec = _mm256_mul_ps(veta, cos_t), ei = _mm256_mul_ps(veta, cos_i);
    const __m256 rs = _mm256_div_ps(_mm256_sub_ps(cos_i, ec), _mm256_add_ps(cos_i, ec));
    const __m256 rp = _mm256_div_ps(_mm256_sub_ps(ei, cos_t), _mm256_add_ps(ei, cos_t));
    const __m256 fr = _mm256_mul_ps(_mm256_set1_ps(0.5f), _mm256_fmadd_ps(rs, rs, _mm256_mul_ps(rp, rp)));
    __m256 scale = _mm256_div_ps(_mm256_mul_ps(_mm256_sub_ps(one, fr), cos_i), cos_t_safe);
    if (l->type != NACRE_LIGHT_DIRECTIONAL) {
        __m256 dk[3];
        for (int c = 0; c < 3; c++)
            dk[c] = _mm256_sub_ps(k[c], _mm256_set1_ps(l->position[c]));
        const __m256 d2 = dot8(dk, dk);
        ok = _mm256_and_ps(ok, _mm256_cmp_ps(d2, zero, _CMP_GT_OQ));
        scale = _mm256_div_ps(scale, _mm256_blendv_ps(one, d2, ok));
    }
    __m256 tau[3] = {zero, zero, zero};
    if (m->count == 0) {
        for (int c = 0; c < 3; c++)
            tau[c] = _mm256_mul_ps(_mm256_set1_ps(m->st[0][c]), km);
    } else {
        __m256 bm[NACRE_MAX_LAYERS], bk[NACRE_MAX_LAYERS], dpk[3];
        if (bmc) {
            for (uint32_t j = 0; j < m->count; j++)
                bm[j] = _mm256_loadu_ps(bmc + (size_t)j * stride);
        } else {
            const __m256 u = _mm256_fmadd_ps(s, _mm256_set1_ps(r->du), _mm256_set1_ps(pt->uv[0]));
            const __m256 v = _mm256_fmadd_ps(s, _mm256_set1_ps(r->dv), _mm256_set1_ps(pt->uv[1]));
            bottoms8(&m->stack, u, v, bm);
        }
        for (int c = 0; c < 3; c++)
            dpk[c] = _mm256_sub_ps(k[c], _mm256_set1_ps(pt->p[c]));
        const __m256 gu[3] = {_mm256_set1_ps(pt->gu[0]), _mm256_set1_ps(pt->gu[1]), _mm256_set1_ps(pt->gu[2])};
        const __m256 gv[3] = {_mm256_set1_ps(pt->gv[0]), _mm256_set1_ps(pt->gv[1]), _mm256_set1_ps(pt->gv[2])};
        bottoms8(&m->stack, _mm256_add_ps(_mm256_set1_ps(pt->uv[0]), dot8(gu, dpk)),
                 _mm256_add_ps(_mm256_set1_ps(pt->uv[1]), dot8(gv, dpk)), bk);
        const __m256 inv_ct = _mm256_div_ps(one, cos_t_safe);
        __m256 above = zero, prev_m = zero, prev_k = zero;
        for (uint32_t j = 0; j < m->count; j++) {
            const __m256 dj =
                _mm256_mul_ps(_mm256_set1_ps(0.5f), _mm256_add_ps(_mm256_sub_ps(bm[j], prev_m), _mm256_sub_ps(bk[j], prev_k)));
            prev_m = bm[j];
            prev_k = bk[j];
            const __m256 len = _mm256_min_ps(_mm256_fnmadd_ps(above, inv_ct, km), _mm256_mul_ps(dj, inv_ct));
            const __m256 lp = _mm256_max_ps(len, zero);
            for (int c = 0; c < 3; c++)
                tau[c] = _mm256_fmadd_ps(_mm256_set1_ps(m->st[j][c]), lp, tau[c]);
            above = _mm256_add_ps(above, dj);
        }
        const __m256 rest = _mm256_max_ps(_mm256_fnmadd_ps(above, inv_ct, km), zero);
        for (int c = 0; c < 3; c++)
            tau[c] = _mm256_fmadd_ps(_mm256_set1_ps(m->st[m->count][c]), rest, tau[c]);
    }
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(scale, zero, _CMP_GT_OQ));
    float ow[8], ot[3][8], oc[8], ok3[3][8];
    _mm256_storeu_ps(ow, _mm256_and_ps(scale, ok));
    for (int c = 0; c < 3; c++) {
        _mm256_storeu_ps(ot[c], _mm256_and_ps(tau[c], ok));
        _mm256_storeu_ps(ok3[c], k[c]);
    }
    _mm256_storeu_ps(oc, _mm256_and_ps(dot8(wt, (const __m256[3]){_mm256_set1_ps(r->d[0]), _mm256_set1_ps(r->d[1]),
                                                                   _mm256_set1_ps(r->d[2])}),
                                       ok));
    for (uint32_t i = 0; i < n && i < 8; i++) {
        out->w[at + i] = ow[i];
        for (int c = 0; c < 3; c++) {
            out->tau[c][at + i] = ot[c][i];
            out->k[c][at + i] = ok3[c][i];
        }
        out->cos_s[at + i] = oc[i];
    }
}
#endif

#ifdef __AVX2__
/* fast_exp on 8 lanes. */
static inline __m256 fast_exp8(__m256 x)
{
    __m256 y = _mm256_mul_ps(x, _mm256_set1_ps(1.44269504f));
    const __m256 keep = _mm256_cmp_ps(y, _mm256_set1_ps(-126.0f), _CMP_GT_OQ);
    y = _mm256_max_ps(_mm256_min_ps(y, _mm256_set1_ps(126.0f)), _mm256_set1_ps(-126.0f));
    const __m256 n = _mm256_floor_ps(y), f = _mm256_sub_ps(y, n);
    __m256 p = _mm256_set1_ps(1.8775767e-3f);
    p = _mm256_fmadd_ps(p, f, _mm256_set1_ps(8.9893397e-3f));
    p = _mm256_fmadd_ps(p, f, _mm256_set1_ps(5.5826318e-2f));
    p = _mm256_fmadd_ps(p, f, _mm256_set1_ps(2.4015361e-1f));
    p = _mm256_fmadd_ps(p, f, _mm256_set1_ps(6.9315308e-1f));
    p = _mm256_fmadd_ps(p, f, _mm256_set1_ps(9.9999994e-1f));
    const __m256i e = _mm256_slli_epi32(_mm256_add_epi32(_mm256_cvtps_epi32(n), _mm256_set1_epi32(127)), 23);
    return _mm256_and_ps(keep, _mm256_mul_ps(p, _mm256_castsi256_ps(e)));
}
#endif

/* sum over e < n of k[e] e^a[e] */
static inline float sum_k_exp(const float *k, const float *a, uint32_t n)
{
    float acc = 0;
    uint32_t e = 0;
#ifdef __AVX2__
    __m256 v = _mm256_setzero_ps();
    for (; e + 8 <= n; e += 8)
        v = _mm256_fmadd_ps(_mm256_loadu_ps(k + e), fast_exp8(_mm256_loadu_ps(a + e)), v);
    float lanes[8];
    _mm256_storeu_ps(lanes, v);
    for (int q = 0; q < 8; q++)
        acc += lanes[q];
#endif
    for (; e < n; e++)
        acc += k[e] * fast_exp(a[e]);
    return acc;
}

/* The light at points s[0..n-1] (n <= NC_MARCH_BATCH) into out[0..n-1]; bm: the bottoms at
 * those points (nc_march_ray_make's, n rounded up to 8 readable per layer) or NULL. */
static void eval_batch(const ray_ctx *r, const nacre_light_desc *l, float co, float ci, const float *s, uint32_t n,
                       const float *bm, uint32_t stride, light_batch *out)
{
#ifdef __AVX2__
    if (l->type != NACRE_LIGHT_SPOT) {
        for (uint32_t i = 0; i < n; i += 8)
            eval8(r, l, s + i, n - i < 8 ? n - i : 8, bm ? bm + i : NULL, stride, out, i);
        return;
    }
    bm = NULL; /* the cached bottoms are bottoms8's; the scalar path reads its own */
#endif
    eval_scalar(r, l, co, ci, s, n, bm, stride, out);
}

#ifdef __AVX2__
/* fast_log on 8 lanes, the same operations. */
static inline __m256 fast_log8(__m256 x)
{
    const __m256i bits = _mm256_castps_si256(x);
    __m256i e = _mm256_sub_epi32(_mm256_and_si256(_mm256_srli_epi32(bits, 23), _mm256_set1_epi32(0xff)),
                                 _mm256_set1_epi32(127));
    __m256 mf = _mm256_castsi256_ps(_mm256_or_si256(_mm256_and_si256(bits, _mm256_set1_epi32(0x007fffff)),
                                                    _mm256_set1_epi32(0x3f800000)));
    const __m256 big = _mm256_cmp_ps(mf, _mm256_set1_ps(1.41421356f), _CMP_GT_OQ);
    mf = _mm256_blendv_ps(mf, _mm256_mul_ps(mf, _mm256_set1_ps(0.5f)), big);
    e = _mm256_add_epi32(e, _mm256_and_si256(_mm256_castps_si256(big), _mm256_set1_epi32(1)));
    const __m256 one = _mm256_set1_ps(1.0f);
    const __m256 t = _mm256_div_ps(_mm256_sub_ps(mf, one), _mm256_add_ps(mf, one)), t2 = _mm256_mul_ps(t, t);
    __m256 p = _mm256_fmadd_ps(t2, _mm256_set1_ps(0.22222222f), _mm256_set1_ps(0.28571429f));
    p = _mm256_fmadd_ps(t2, p, _mm256_set1_ps(0.4f));
    p = _mm256_fmadd_ps(t2, p, _mm256_set1_ps(0.66666667f));
    p = _mm256_fmadd_ps(t2, p, _mm256_set1_ps(2.0f));
    p = _mm256_mul_ps(t, p);
    return _mm256_fmadd_ps(_mm256_cvtepi32_ps(e), _mm256_set1_ps(0.69314718f), p);
}

/* hg on 8 lanes. */
static inline __m256 hg8(__m256 c, __m256 g)
{
    const __m256 one = _mm256_set1_ps(1.0f), g2 = _mm256_mul_ps(g, g);
    const __m256 d = _mm256_sub_ps(_mm256_add_ps(one, g2), _mm256_mul_ps(_mm256_add_ps(g, g), c));
    return _mm256_div_ps(_mm256_sub_ps(one, g2),
                         _mm256_mul_ps(_mm256_mul_ps(_mm256_set1_ps(4.0f * (float)NC_PI), d), _mm256_sqrt_ps(d)));
}

/* The ANALYTIC sum of nc_layered_radiance over pieces 0..np-1 (piece i: [pts[i], pts[i + 1]] in
 * layer layers[i]) with every piece end in lb (np <
 * NC_MARCH_BATCH), 8 pieces at a time: the same closed forms as its scalar loop, the integrand's
 * log and exponential at both ends of every piece at once. A piece's start takes the previous
 * piece's end values when the layer (so the phase) does not change, as the scalar loop does;
 * the lanes' sums are added at the end, so the result differs from that loop's by float
 * rounding only. */
static void closed_forms8(const nc_layer_medium *m, const float strength[3], const float *pts, const uint8_t *layers,
                          uint32_t np, const light_batch *lb, float vis0, float vis_rate, float sum[3])
{
    enum { N = NC_MARCH_BATCH + NC_MARCH_PAD };
    float ts[3][N], te[3][N], len[N], s0[N], s1[N], g[N], kc[3][N], change[N];
    float elf[3][N], ef[3][N], elit[N]; /* at point q: the end values of piece q - 1 */
    float tau[3] = {0, 0, 0};
    const uint32_t nr = (np + 7u) & ~7u;
    for (uint32_t i = 0; i < nr; i++) {
        const bool in = i < np;
        const uint32_t j = in ? layers[i] : 0;
        len[i] = in ? pts[i + 1] - pts[i] : 0.0f;
        s0[i] = in ? pts[i] : 0.0f;
        s1[i] = in ? pts[i + 1] : 0.0f;
        g[i] = m->g[j];
        change[i] = (i == 0 || !in || layers[i - 1] != j) ? -1.0f : 0.0f; /* sign bit: blend mask */
        for (int c = 0; c < 3; c++) {
            ts[c][i] = tau[c];
            if (in)
                tau[c] += m->st[j][c] * len[i];
            te[c][i] = tau[c];
            kc[c][i] = in ? m->ss[j][c] * strength[c] : 0.0f;
        }
    }
    const __m256 zero = _mm256_setzero_ps(), fmin = _mm256_set1_ps(FLT_MIN), half = _mm256_set1_ps(0.5f);
    const __m256 v0 = _mm256_set1_ps(vis0), vr = _mm256_set1_ps(vis_rate);
    elit[0] = 0;
    for (int c = 0; c < 3; c++)
        elf[c][0] = ef[c][0] = 0;
    /* The ends first: a chunk's starts read the previous piece's end, which may be in the chunk. */
    for (uint32_t i0 = 0; i0 < nr; i0 += 8) {
        const __m256 pb = _mm256_mul_ps(
            _mm256_mul_ps(hg8(_mm256_loadu_ps(lb->cos_s + i0 + 1), _mm256_loadu_ps(g + i0)),
                          _mm256_fmadd_ps(vr, _mm256_loadu_ps(s1 + i0), v0)),
            _mm256_loadu_ps(lb->w + i0 + 1));
        const __m256 b_lit = _mm256_cmp_ps(pb, fmin, _CMP_GT_OQ);
        const __m256 lpb = _mm256_and_ps(fast_log8(_mm256_blendv_ps(_mm256_set1_ps(1.0f), pb, b_lit)), b_lit);
        _mm256_storeu_ps(elit + i0 + 1, b_lit);
        for (int c = 0; c < 3; c++) {
            const __m256 lfb = _mm256_sub_ps(_mm256_sub_ps(lpb, _mm256_loadu_ps(lb->tau[c] + i0 + 1)),
                                             _mm256_loadu_ps(te[c] + i0));
            _mm256_storeu_ps(elf[c] + i0 + 1, lfb);
            _mm256_storeu_ps(ef[c] + i0 + 1, _mm256_and_ps(fast_exp8(lfb), b_lit));
        }
    }
    __m256 acc[3] = {zero, zero, zero};
    for (uint32_t i0 = 0; i0 < nr; i0 += 8) {
        const __m256 ch = _mm256_loadu_ps(change + i0);
        const __m256 pa = _mm256_mul_ps(
            _mm256_mul_ps(hg8(_mm256_loadu_ps(lb->cos_s + i0), _mm256_loadu_ps(g + i0)),
                          _mm256_fmadd_ps(vr, _mm256_loadu_ps(s0 + i0), v0)),
            _mm256_loadu_ps(lb->w + i0));
        const __m256 new_lit = _mm256_cmp_ps(pa, fmin, _CMP_GT_OQ);
        const __m256 lpa = fast_log8(_mm256_blendv_ps(_mm256_set1_ps(1.0f), pa, new_lit));
        const __m256 a_lit = _mm256_blendv_ps(_mm256_loadu_ps(elit + i0), new_lit, ch);
        const __m256 b_lit = _mm256_loadu_ps(elit + i0 + 1);
        const __m256 both = _mm256_and_ps(a_lit, b_lit);
        const __m256 l = _mm256_loadu_ps(len + i0);
        const __m256 in = _mm256_cmp_ps(_mm256_add_ps(_mm256_set1_ps((float)i0), _mm256_setr_ps(0, 1, 2, 3, 4, 5, 6, 7)),
                                        _mm256_set1_ps((float)np), _CMP_LT_OQ);
        for (int c = 0; c < 3; c++) {
            const __m256 lfa_new = _mm256_sub_ps(_mm256_sub_ps(lpa, _mm256_loadu_ps(lb->tau[c] + i0)),
                                                 _mm256_loadu_ps(ts[c] + i0));
            const __m256 lfa = _mm256_blendv_ps(_mm256_loadu_ps(elf[c] + i0), lfa_new, ch);
            const __m256 ea = _mm256_and_ps(_mm256_blendv_ps(_mm256_loadu_ps(ef[c] + i0), fast_exp8(lfa_new), ch), a_lit);
            const __m256 lfb = _mm256_loadu_ps(elf[c] + i0 + 1), fb = _mm256_loadu_ps(ef[c] + i0 + 1);
            const __m256 k = _mm256_loadu_ps(kc[c] + i0);
            const __m256 q = _mm256_sub_ps(lfa, lfb);
            const __m256 aq = _mm256_andnot_ps(_mm256_set1_ps(-0.0f), q);
            const __m256 exact = _mm256_div_ps(_mm256_mul_ps(l, _mm256_sub_ps(ea, fb)), q);
            const __m256 trap = _mm256_mul_ps(_mm256_mul_ps(l, half), _mm256_add_ps(ea, fb));
            const __m256 v = _mm256_and_ps(both, _mm256_cmp_ps(aq, _mm256_set1_ps(1e-4f), _CMP_GT_OQ));
            acc[c] = _mm256_add_ps(acc[c], _mm256_and_ps(_mm256_mul_ps(k, _mm256_blendv_ps(trap, exact, v)), in));
        }
    }
    for (int c = 0; c < 3; c++) {
        float lanes[8];
        _mm256_storeu_ps(lanes, acc[c]);
        sum[c] = 0;
        for (int q = 0; q < 8; q++)
            sum[c] += lanes[q];
    }
}
#endif


/* A point of the view ray with its layer, and the layer bottoms there once read: the boundary
 * search reuses them for its secant. */
typedef struct probe {
    float s;
    uint32_t layer;
    bool has_bot;
    float bot[NACRE_MAX_LAYERS];
} probe;

static inline void probe_at(const ray_ctx *r, float s, probe *p)
{
    const nc_layer_stack *st = &r->m->stack;
    p->s = s;
    p->has_bot = false;
    /* find_at, keeping the bottoms */
    const float d = s * r->dz;
    uint32_t j = 0;
    while (j < st->count && d >= st->hi[j])
        j++;
    if (j < st->count && d >= st->lo[j]) {
        bottoms_at(st, r->pt->uv[0] + s * r->du, r->pt->uv[1] + s * r->dv, p->bot);
        p->has_bot = true;
        while (j < st->count && d >= p->bot[j])
            j++;
    }
    p->layer = j;
}

static inline float probe_bottom(const ray_ctx *r, probe *p, uint32_t edge)
{
    if (!p->has_bot) {
        bottoms_at(&r->m->stack, r->pt->uv[0] + p->s * r->du, r->pt->uv[1] + p->s * r->dv, p->bot);
        p->has_bot = true;
    }
    return p->bot[edge];
}

/* The pieces of constant layer along [0, len] (ANALYTIC), or the N steps with the layer at their
 * midpoints (SAMPLES); stops early where the transmittance to P is negligible. Piece i is
 * [pts[i], pts[i + 1]] in layer layers[i] (pts[0] = 0); at most limit - 1 pieces (ANALYTIC; limit
 * <= NC_MARCH_MAX_PIECES): fewer than limit - 2 means none was cut off. */
static uint32_t make_pieces(const ray_ctx *r, const nc_march_params *prm, uint32_t limit, float *pts, uint8_t *layers)
{
    const nc_layer_medium *m = r->m;
    const uint32_t n = prm->samples;
    const float step = r->len / (float)n;
    const float tau_stop = -logf(NC_MARCH_T_MIN);
    float tau_min = 0; /* view optical depth in the least extinguishing channel */
    uint32_t count = 0;
    pts[0] = 0.0f;
/* the next piece, from the last one's end to b */
#define PIECE(b, j) (layers[count] = (uint8_t)(j), pts[++count] = (b))
    if (!prm->analytic) {
        for (uint32_t i = 0; i < n && tau_min < tau_stop; i++) {
            uint32_t j = layer_at(r, ((float)i + 0.5f) * step);
            PIECE((float)(i + 1) * step, j);
            tau_min += minf(m->st[j][0], minf(m->st[j][1], m->st[j][2])) * step;
        }
        return count;
    }
    /* Probes by pointer: the bisection keeps its brackets without copying the bottoms. */
    probe slot[2], mid[NC_MARCH_BISECT], after;
    probe *plo = &slot[0], *ps = &slot[1];
    probe_at(r, 0.0f, plo);
    float lo = 0;
    uint32_t jl = plo->layer;
    for (uint32_t i = 1; i <= n && tau_min < tau_stop; i++) {
        const float s = i == n ? r->len : (float)i * step;
        probe_at(r, s, ps);
        const uint32_t j = ps->layer;
        while (j != jl && count < limit - 2) {
            /* First change of layer after lo: layer_at(a) == jl, layer_at(b) != jl. */
            probe *pa = plo, *pb = ps;
            for (int it = 0; it < NC_MARCH_BISECT; it++) {
                probe_at(r, 0.5f * (pa->s + pb->s), &mid[it]);
                if (mid[it].layer == jl)
                    pa = &mid[it];
                else
                    pb = &mid[it];
            }
            /* The bracket's last step is a secant on depth - bottom: exact where the boundary
             * is flat, so a handful of halvings suffice. */
            const float a = pa->s, b = pb->s;
            const uint32_t jb = pb->layer;
            const uint32_t edge = jb > jl ? jl : jl - 1; /* the bottom crossed */
            const float fa = a * r->dz - probe_bottom(r, pa, edge);
            const float fb = b * r->dz - probe_bottom(r, pb, edge);
            float cut = fa != fb ? a + (b - a) * fa / (fa - fb) : b;
            cut = cut >= a && cut <= b ? cut : b;
            PIECE(cut, jl);
            tau_min += minf(m->st[jl][0], minf(m->st[jl][1], m->st[jl][2])) * (cut - lo);
            lo = cut;
            /* The layer just past the cut: a bracket that held two boundaries goes on with the
             * layer between them, not the one at its end. */
            probe_at(r, cut + 1e-3f * (b - cut), &after);
            jl = after.layer != jl ? after.layer : jb;
            plo->s = cut;
            plo->layer = jl;
            plo->has_bot = false;
        }
        PIECE(s, jl);
        tau_min += minf(m->st[jl][0], minf(m->st[jl][1], m->st[jl][2])) * (s - lo);
        lo = s;
        jl = j;
        probe *t = plo; /* the end probe starts the next step */
        plo = ps;
        ps = t;
        if (count >= limit - 2)
            break;
    }
#undef PIECE
    return count;
}

/* The refracted view ray of pt into r and the Fresnel transmittance out; false when no light
 * leaves P towards the eye. */
static bool view_ray(const nc_layer_medium *m, const nc_march_point *pt, ray_ctx *r, float *t_out)
{
    const float eta = m->eta;
    const float cos_o = dot3(pt->n, pt->v);
    if (!(cos_o > 0))
        return false;
    float sin2_t = (1.0f - cos_o * cos_o) / (eta * eta);
    if (sin2_t >= 1.0f)
        return false;
    float cos_t = sqrtf(1.0f - sin2_t);
    *r = (ray_ctx){.m = m, .pt = pt};
    for (int k = 0; k < 3; k++)
        r->d[k] = -pt->v[k] / eta + (cos_o / eta - cos_t) * pt->n[k];
    r->dz = -dot3(r->d, pt->n);
    r->du = dot3(pt->gu, r->d);
    r->dv = dot3(pt->gv, r->d);
    /* Eq. 15, with the refracted direction */
    r->len = m->depth_max / maxf(-dot3(pt->ns, r->d), 0.1f);
    *t_out = (1.0f - nc_fresnel_dielectric_f(cos_o, eta, 1.0f / (eta * eta))) / (eta * eta);
    return true;
}

/* The lights that can light a sample of pt's ray (bit li, the first 32): a directional light
 * behind both P's tangent plane and the fitted plane is behind every plane of eq. 9 (their
 * normals are positive blends of the two). */
static uint32_t lit_mask(const nc_march_point *pt, const nc_shade_light *lights, uint32_t light_count)
{
    uint32_t lit = 0;
    for (uint32_t li = 0; li < light_count && li < 32; li++) {
        const nacre_light_desc *l = lights[li].desc;
        if (l->type != NACRE_LIGHT_DIRECTIONAL || dot3(pt->n, l->direction) < 0 || dot3(pt->ns, l->direction) < 0)
            lit |= 1u << li;
    }
    return lit;
}

/* A view ray cut into pieces (make_pieces' pts[0..np] and layers, with pts[np + 1] = len for
 * ANALYTIC). bm: the layer bottoms at the points where the lights are evaluated (ANALYTIC:
 * pts[0..np + 1]; SAMPLES: the pieces' midpoints), stride floats per layer, from
 * nc_march_ray_make; NULL: read where needed. */
typedef struct cut_ray {
    ray_ctx r;
    float t_out;
    const float *pts;
    const uint8_t *layers;
    uint32_t np;
    const float *bm;
    uint32_t stride;
} cut_ray;

/* One light's evaluation along a cut ray: the batch of points base .. base + filled - 1 in lb. */
typedef struct light_eval {
    const nacre_light_desc *l;
    float co, ci; /* a spot light's cone cosines */
    light_batch lb;
    uint32_t base, filled;
} light_eval;

static void light_eval_init(light_eval *le, const nacre_light_desc *l)
{
    le->l = l;
    le->co = l->type == NACRE_LIGHT_SPOT ? cosf(l->outer_angle * NC_DEG2RAD) : 0.0f;
    le->ci = l->type == NACRE_LIGHT_SPOT ? cosf(l->inner_angle * NC_DEG2RAD) : 0.0f;
    le->base = le->filled = 0;
}

/* ANALYTIC rays of one batch (np + 1 < NC_MARCH_BATCH): the light at every piece end, and at M_max
 * when it is not the last end (the ray stopped early), for the shadow lookup at M_max's entry
 * point K': whether light reaches M_max and K'. */
static bool eval_ends_and_far(const cut_ray *cr, light_eval *le, float far_k[3])
{
    const uint32_t npts = cr->np + 1;
    float spts[NC_MARCH_BATCH];
    for (uint32_t e = 0; e < npts; e++)
        spts[e] = cr->pts[e];
    uint32_t fi = npts - 1;
    if (spts[fi] != cr->r.len)
        spts[++fi] = cr->r.len; /* pts[np + 1]: bm has it */
    eval_batch(&cr->r, le->l, le->co, le->ci, spts, fi + 1, cr->bm, cr->stride, &le->lb);
    le->base = 0;
    le->filled = npts;
    for (int c = 0; c < 3; c++)
        far_k[c] = le->lb.k[c][fi];
    return le->lb.w[fi] > 0;
}

/* The light of le along the cut ray with visibilities vis0 at P and vis1 at M_max's entry point,
 * added to rgb. */
static void light_sum(const cut_ray *cr, light_eval *le, float vis0, float vis1, const nc_march_params *prm,
                      float rgb[3])
{
    const ray_ctx *r = &cr->r;
    const nc_layer_medium *m = r->m;
    const nacre_light_desc *l = le->l;
    const float *pts = cr->pts;
    const uint8_t *layers = cr->layers;
    const uint32_t np = cr->np, npts = np + 1;
    light_batch *lb = &le->lb;
    float spts[NC_MARCH_BATCH];
    /* ANALYTIC evaluates the light at the pieces' ends in batches (FETCH): point q is pts[q].
     * bm is only given for rays of one batch (base 0). */
#define FETCH(q)                                                                                                       \
    do {                                                                                                               \
        if ((q) >= le->base + le->filled) {                                                                            \
            le->base = (q);                                                                                            \
            le->filled = npts - le->base < NC_MARCH_BATCH ? npts - le->base : NC_MARCH_BATCH;                          \
            for (uint32_t e = 0; e < le->filled; e++)                                                                  \
                spts[e] = pts[le->base + e];                                                                           \
            eval_batch(r, l, le->co, le->ci, spts, le->filled, cr->bm ? cr->bm + le->base : NULL, cr->stride, lb);    \
        }                                                                                                              \
    } while (0)
    /* Per channel, ln of the integrand without sigma_s * strength (kc): the pieces' ends
     * share it when the layer does not change, and its difference gives the exponential's
     * rate without a logarithm per channel. */
    float tau[3] = {0, 0, 0}, sum[3] = {0, 0, 0}, kc[3];
    float lfa[3] = {0, 0, 0}, ea[3] = {0, 0, 0}; /* ea = e^lfa: a piece's end starts the next */
    bool a_lit = false;
    uint32_t a_layer = UINT32_MAX, qa = 0;
    const float vis_rate = (vis1 - vis0) / r->len;
    if (!prm->analytic) {
        /* The seed's sums, a batch of samples at a time: the weights and exponents first
         * (the transmittance to P runs from sample to sample), then the exponentials 8 at a
         * time (sum_k_exp). */
        float ks[3][NC_MARCH_BATCH], arg[3][NC_MARCH_BATCH];
        for (uint32_t i0 = 0; i0 < np; i0 += NC_MARCH_BATCH) {
            const uint32_t nb = np - i0 < NC_MARCH_BATCH ? np - i0 : NC_MARCH_BATCH;
            for (uint32_t e = 0; e < nb; e++)
                spts[e] = 0.5f * (pts[i0 + e] + pts[i0 + e + 1]);
            eval_batch(r, l, le->co, le->ci, spts, nb, cr->bm ? cr->bm + i0 : NULL, cr->stride, lb);
            for (uint32_t e = 0; e < nb; e++) {
                const uint32_t j = layers[i0 + e];
                const float len = pts[i0 + e + 1] - pts[i0 + e];
                float w = nc_hg_phasef(lb->cos_s[e], m->g[j]) * (vis0 + vis_rate * spts[e]) * len * lb->w[e];
                w = w > 0 ? w : 0.0f;
                for (int c = 0; c < 3; c++) {
                    ks[c][e] = m->ss[j][c] * l->strength[c] * w;
                    arg[c][e] = -lb->tau[c][e] - tau[c] - 0.5f * m->st[j][c] * len;
                    tau[c] += m->st[j][c] * len;
                }
            }
            for (int c = 0; c < 3; c++)
                sum[c] += sum_k_exp(ks[c], arg[c], nb);
        }
        for (int c = 0; c < 3; c++)
            rgb[c] += sum[c] * cr->t_out;
        return;
    }
#ifdef __AVX2__
    if (npts <= NC_MARCH_BATCH) {
        FETCH(0);
        closed_forms8(m, l->strength, pts, layers, np, lb, vis0, vis_rate, sum);
        for (int c = 0; c < 3; c++)
            rgb[c] += sum[c] * cr->t_out;
        return;
    }
#endif
    for (uint32_t i = 0; i < np; i++) {
        const uint32_t j = layers[i];
        const float s0 = pts[i], s1 = pts[i + 1], len = s1 - s0;
        for (int c = 0; c < 3; c++)
            kc[c] = m->ss[j][c] * l->strength[c];
        if (a_layer != j) { /* the first piece, or a new layer: the start's phase changed */
            FETCH(i);
            qa = i - le->base;
            const float pa = nc_hg_phasef(lb->cos_s[qa], m->g[j]) * (vis0 + vis_rate * s0) * lb->w[qa];
            a_lit = pa > FLT_MIN; /* fast_log takes normal numbers */
            if (a_lit) {
                const float lp = fast_log(pa);
                for (int c = 0; c < 3; c++) {
                    lfa[c] = lp - lb->tau[c][qa] - tau[c];
                    ea[c] = fast_exp(lfa[c]);
                }
            }
        }
        FETCH(i + 1);
        const uint32_t qb = i + 1 - le->base;
        const float pb = nc_hg_phasef(lb->cos_s[qb], m->g[j]) * (vis0 + vis_rate * s1) * lb->w[qb];
        const bool b_lit = pb > FLT_MIN;
        const float lpb = b_lit ? fast_log(pb) : 0.0f;
        for (int c = 0; c < 3; c++) {
            const float tb = tau[c] + m->st[j][c] * len;
            const float lfb = lpb - lb->tau[c][qb] - tb;
            const float fb = b_lit ? fast_exp(lfb) : 0.0f;
            if (a_lit && b_lit) {
                const float q = lfa[c] - lfb, fa = ea[c];
                sum[c] += kc[c] * (q > 1e-4f || q < -1e-4f ? len * (fa - fb) / q : len * 0.5f * (fa + fb));
            } else { /* light on one end only: the trapezoid */
                sum[c] += kc[c] * len * 0.5f * ((a_lit ? ea[c] : 0.0f) + fb);
            }
            tau[c] = tb;
            lfa[c] = lfb;
            ea[c] = fb;
        }
        a_lit = b_lit;
        a_layer = j;
    }
#undef FETCH
    for (int c = 0; c < 3; c++)
        rgb[c] += sum[c] * cr->t_out;
}

/* The lights (those of mask lit among the first 32, and every later one) along a cut ray, added
 * to rgb. Visibility: the shadow maps at P and at the entry point K' of M_max's light; when all
 * the pieces' ends fit in one batch, M_max is its last point (or one more lane), so K' comes
 * with the batch instead of a scalar evaluation of its own. */
static void light_ray(const cut_ray *cr, const nc_shade_light *lights, uint32_t light_count, uint32_t lit,
                      const nc_march_params *prm, float rgb[3])
{
    const nc_march_point *pt = cr->r.pt;
    for (uint32_t li = 0; li < light_count; li++) {
        if (li < 32 && !(lit & (1u << li)))
            continue;
        light_eval le;
        light_eval_init(&le, lights[li].desc);
        float vis0 = 1, vis1 = 1;
        if (lights[li].shadow) {
            vis0 = nc_shadow_lookup(lights[li].shadow, nc_v3a(pt->p), nc_v3a(pt->n), prm->pcf_radius, prm->shadow_bias);
            bool far_lit;
            float far_k[3];
            if (prm->analytic && cr->np + 1 < NC_MARCH_BATCH) {
                far_lit = eval_ends_and_far(cr, &le, far_k);
            } else {
                light_at far;
                eval_light(&cr->r, le.l, le.co, le.ci, cr->r.len, NULL, 0, &far);
                far_lit = far.lit;
                memcpy(far_k, far.k, sizeof(far_k));
            }
            vis1 = far_lit ? nc_shadow_lookup(lights[li].shadow, nc_v3a(far_k), nc_v3a(pt->ns), prm->pcf_radius,
                                              prm->shadow_bias)
                           : vis0;
            if (vis0 <= 0 && vis1 <= 0)
                continue;
        }
        light_sum(cr, &le, vis0, vis1, prm, rgb);
    }
}

void nc_layered_radiance(const nc_layer_medium *m, const nc_march_point *pt, const nc_shade_light *lights,
                         uint32_t light_count, const nc_march_params *prm, float rgb[3])
{
    rgb[0] = rgb[1] = rgb[2] = 0;
    ray_ctx r;
    float t_out;
    if (light_count == 0 || !view_ray(m, pt, &r, &t_out))
        return;
    const uint32_t lit = lit_mask(pt, lights, light_count);
    if (!lit && light_count <= 32)
        return;
    float pts[NC_MARCH_MAX_PIECES + 2];
    uint8_t layers[NC_MARCH_MAX_PIECES];
    const uint32_t np = make_pieces(&r, prm, NC_MARCH_MAX_PIECES, pts, layers);
    pts[np + 1] = r.len;
    const cut_ray cr = {.r = r, .t_out = t_out, .pts = pts, .layers = layers, .np = np};
    light_ray(&cr, lights, light_count, lit, prm, rgb);
}

/* A slot: the header, then cap points, layers x cap bottoms, cap layer indices. */
#define NC_MARCH_RAY_HEAD ((sizeof(nc_march_ray) + 31) & ~(size_t)31)

uint32_t nc_march_ray_cap(const nc_march_params *prm)
{
    /* ANALYTIC: the steps' ends, 8 boundary crossings (beyond them a ray is LONG) and M_max;
     * SAMPLES: the steps' ends and M_max. One batch of NC_MARCH_BATCH points at most. */
    const uint64_t need = (uint64_t)prm->samples + (prm->analytic ? 11u : 2u);
    const uint64_t cap = (need + 7u) & ~(uint64_t)7u;
    return cap <= NC_MARCH_BATCH ? (uint32_t)cap : 0u;
}

size_t nc_march_ray_bytes(uint32_t cap, uint32_t layers)
{
    return (NC_MARCH_RAY_HEAD + (size_t)cap * ((1u + layers) * sizeof(float) + 1u) + 15u) & ~(size_t)15u;
}

uint32_t nc_march_ray_make(const nc_layer_medium *m, const nc_march_point *pt, const nc_march_params *prm,
                           uint32_t cap, uint32_t layers, void *slot)
{
    nc_march_ray *ray = slot;
    float *pts = (float *)((char *)slot + NC_MARCH_RAY_HEAD), *bm = pts + cap;
    uint8_t *lay = (uint8_t *)(bm + (size_t)layers * cap);
    ray->pt = *pt;
    ray->cap = cap;
    ray->layers = layers;
    ray->np = 0;
    ray->kind = NC_MARCH_RAY_DARK;
    if (m->count > layers || cap < 8 || cap > NC_MARCH_BATCH)
        return ray->kind = NC_MARCH_RAY_LONG;
    ray_ctx r;
    if (!view_ray(m, &ray->pt, &r, &ray->t_out))
        return ray->kind;
    memcpy(ray->d, r.d, sizeof(ray->d));
    ray->dz = r.dz;
    ray->du = r.du;
    ray->dv = r.dv;
    ray->len = r.len;
    const uint32_t np = make_pieces(&r, prm, cap - 1, pts, lay);
    if ((prm->analytic && np + 3 >= cap) || np + 2 > cap) /* possibly cut off by the limit */
        return ray->kind = NC_MARCH_RAY_LONG;
    pts[np + 1] = r.len;
    ray->np = np;
    /* The bottoms where light_ray evaluates the lights, 8 points at a time as eval8 reads them
     * (the last point repeated past the end). */
    const uint32_t ne = prm->analytic ? np + 2 : np;
    if (m->count && ne > 0) {
        const uint32_t ne8 = (ne + 7u) & ~7u; /* <= cap */
        float e[NC_MARCH_BATCH];
        for (uint32_t q = 0; q < ne8; q++) {
            const uint32_t qq = q < ne ? q : ne - 1;
            e[q] = prm->analytic ? pts[qq] : 0.5f * (pts[qq] + pts[qq + 1]);
        }
#ifdef __AVX2__
        for (uint32_t q = 0; q < ne8; q += 8) {
            const __m256 s = _mm256_loadu_ps(e + q);
            __m256 b[NACRE_MAX_LAYERS];
            bottoms8(&m->stack, _mm256_fmadd_ps(s, _mm256_set1_ps(r.du), _mm256_set1_ps(pt->uv[0])),
                     _mm256_fmadd_ps(s, _mm256_set1_ps(r.dv), _mm256_set1_ps(pt->uv[1])), b);
            for (uint32_t j = 0; j < m->count; j++)
                _mm256_storeu_ps(bm + (size_t)j * cap + q, b[j]);
        }
#else
        for (uint32_t q = 0; q < ne8; q++) {
            float b[NACRE_MAX_LAYERS];
            bottoms_at(&m->stack, pt->uv[0] + e[q] * r.du, pt->uv[1] + e[q] * r.dv, b);
            for (uint32_t j = 0; j < m->count; j++)
                bm[(size_t)j * cap + q] = b[j];
        }
#endif
    }
    return ray->kind = NC_MARCH_RAY_OK;
}

/* The cut ray of a made slot. */
static void ray_cut(const nc_layer_medium *m, const nc_march_ray *ray, cut_ray *cr)
{
    const float *pts = (const float *)((const char *)ray + NC_MARCH_RAY_HEAD), *bm = pts + ray->cap;
    *cr = (cut_ray){.r = {.m = m, .pt = &ray->pt, .dz = ray->dz, .du = ray->du, .dv = ray->dv, .len = ray->len},
                    .t_out = ray->t_out,
                    .pts = pts,
                    .layers = (const uint8_t *)(bm + (size_t)ray->layers * ray->cap),
                    .np = ray->np,
                    .bm = m->count ? bm : NULL,
                    .stride = ray->cap};
    memcpy(cr->r.d, ray->d, sizeof(cr->r.d));
}

void nc_march_ray_radiance(const nc_layer_medium *m, const void *slot, const nc_shade_light *lights,
                           uint32_t light_count, const nc_march_params *prm, float rgb[3])
{
    const nc_march_ray *ray = slot;
    rgb[0] = rgb[1] = rgb[2] = 0;
    if (ray->kind != NC_MARCH_RAY_OK || light_count == 0)
        return;
    const uint32_t lit = lit_mask(&ray->pt, lights, light_count);
    if (!lit && light_count <= 32)
        return;
    cut_ray cr;
    ray_cut(m, ray, &cr);
    light_ray(&cr, lights, light_count, lit, prm, rgb);
}

void nc_march_rays_radiance(const nc_layer_medium *const *media, const void *const *rays, uint32_t n,
                            const nc_shade_light *lights, uint32_t light_count, const nc_march_params *prm,
                            float *const *rgb)
{
    cut_ray cr[NC_MARCH_CHUNK];
    uint32_t lit[NC_MARCH_CHUNK];
    bool on[NC_MARCH_CHUNK];
    n = n < NC_MARCH_CHUNK ? n : NC_MARCH_CHUNK;
    for (uint32_t k = 0; k < n; k++) {
        const nc_march_ray *ray = rays[k];
        rgb[k][0] = rgb[k][1] = rgb[k][2] = 0;
        on[k] = ray->kind == NC_MARCH_RAY_OK && light_count > 0;
        lit[k] = on[k] ? lit_mask(&ray->pt, lights, light_count) : 0;
        on[k] = on[k] && (lit[k] || light_count > 32);
        if (on[k])
            ray_cut(media[k], ray, &cr[k]);
    }
    light_eval le[NC_MARCH_CHUNK];
    for (uint32_t li = 0; li < light_count; li++) {
        const nc_shade_light *sl = &lights[li];
        uint32_t act[NC_MARCH_CHUNK], na = 0;
        for (uint32_t k = 0; k < n; k++)
            if (on[k] && (li >= 32 || (lit[k] & (1u << li))))
                act[na++] = k;
        if (!sl->shadow || !prm->analytic) {
            for (uint32_t a = 0; a < na; a++)
                light_ray(&cr[act[a]], sl, 1, 1u, prm, rgb[act[a]]);
            continue;
        }
        /* Every ray's light first, then the lookups at the points P (normal n) and K' (normal
         * N_SP) of all of them in one call, then the sums. */
        float q[3][2 * NC_MARCH_CHUNK], qn[3][2 * NC_MARCH_CHUNK], vis[2 * NC_MARCH_CHUNK];
        bool far_lit[NC_MARCH_CHUNK];
        for (uint32_t a = 0; a < na; a++) {
            const cut_ray *c = &cr[act[a]];
            light_eval_init(&le[a], sl->desc);
            float far_k[3];
            far_lit[a] = eval_ends_and_far(c, &le[a], far_k);
            for (int k = 0; k < 3; k++) {
                q[k][a] = c->r.pt->p[k];
                qn[k][a] = c->r.pt->n[k];
                q[k][na + a] = far_lit[a] ? far_k[k] : c->r.pt->p[k];
                qn[k][na + a] = c->r.pt->ns[k];
            }
        }
        nc_shadow_lookup_n(sl->shadow, 2 * na, q[0], q[1], q[2], qn[0], qn[1], qn[2], prm->pcf_radius,
                           prm->shadow_bias, vis);
        for (uint32_t a = 0; a < na; a++) {
            const float vis0 = vis[a], vis1 = far_lit[a] ? vis[na + a] : vis0;
            if (vis0 <= 0 && vis1 <= 0)
                continue;
            light_sum(&cr[act[a]], &le[a], vis0, vis1, prm, rgb[act[a]]);
        }
    }
}
