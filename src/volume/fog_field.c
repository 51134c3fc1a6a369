/*
 * fog_field.c: point evaluation and light-ray optical depth of the scene's fogs (fog_field.h;
 * seed 003 §1.2.7.1 products of homogeneous steps, §2.1.2 height fog, §2.2.3 volumetric shadow).
 */
#include "volume/fog_field.h"

#include "scene/medium.h"

#include <math.h>
#include <string.h>

void nc_fog_field_init(nc_fog_field *f, const nacre_scene *s, uint32_t count, uint32_t shadow_steps)
{
    memset(f, 0, sizeof(*f));
    f->scene = s;
    f->count = count < s->fog_count ? count : s->fog_count;
    f->shadow_steps = shadow_steps ? shadow_steps : 1;
    memcpy(f->bounds_min, s->bounds_min, sizeof(f->bounds_min));
    memcpy(f->bounds_max, s->bounds_max, sizeof(f->bounds_max));
    for (uint32_t i = 0; i < f->count; i++) {
        const nc_fog_rec *rec = &s->fogs[i];
        nc_fog_one *o = &f->fogs[i];
        o->box = rec->desc.shape != NACRE_FOG_GLOBAL;
        o->ellipsoid = rec->desc.shape == NACRE_FOG_SPHERE;
        o->patterned = nc_medium_heterogeneous(&rec->medium);
        for (int r = 0; r < 3; r++) {
            for (int c = 0; c < 4; c++)
                o->w2l[r][c] = rec->world_to_local.m[r][c];
            o->half[r] = 0.5f * rec->desc.size[r];
            o->sigma_a[r] = rec->desc.sigma_a[r];
            o->sigma_s[r] = rec->desc.sigma_s[r];
        }
        /* The density cap exactly as the path tracer and the fog pass apply it. */
        float mx[3];
        nc_medium_max_sigma_t(s, &rec->medium, mx);
        o->height = rec->desc.height_falloff > 0;
        o->hf_falloff = o->height ? rec->desc.height_falloff : 0.0f;
        o->hf_base = rec->desc.height_base;
        o->hf_cap = nc_vol_height_exp_cap(o->height, fmaxf(mx[0], fmaxf(mx[1], mx[2])));
        o->h = (nc_vol_height){.falloff = o->hf_falloff, .base = o->hf_base, .cap = o->hf_cap};
        o->g = rec->desc.g;
        o->medium = &rec->medium;
        o->emissive = rec->emissive;
        o->emission_patterned = rec->emission_patterned;
        memcpy(o->emission, rec->desc.emission, sizeof(o->emission));
        o->emission_medium = &rec->emission;
        f->emissive |= o->emissive;
    }
}

static inline void to_local(const nc_fog_one *o, const float p[3], float q[3])
{
    for (int r = 0; r < 3; r++)
        q[r] = o->w2l[r][0] * p[0] + o->w2l[r][1] * p[1] + o->w2l[r][2] * p[2] + o->w2l[r][3];
}

static inline bool inside(const nc_fog_one *o, const float q[3])
{
    return nc_vol_shape_inside(o->ellipsoid, o->half, q);
}

/* 8 points at a time (core/simd.h), in structure of arrays inside (points, sums and local
 * points one array per coordinate or channel, n rounded up to 8): every step over the points is
 * a few vector operations. The pattern is evaluated only at the points inside a bounded fog
 * (most froxels miss a small cloud), packed in front. The lane-wise operations are the scalar
 * ones (nc_vol_exp_fast8, the same products and sums in fog order): results do not depend on
 * how points are grouped. */
/* 8 points' 3 channels from planes nn apart (planes[c nn + l]) to xyz order (out[3 l + c]). */
static inline void interleave8(const float *planes, size_t nn, float *out)
{
    nc_v8i a, b, c;
    nc_v8_interleave3(nc_v8i_load((const int32_t *)(const void *)planes),
                      nc_v8i_load((const int32_t *)(const void *)(planes + nn)),
                      nc_v8i_load((const int32_t *)(const void *)(planes + 2 * nn)), &a, &b, &c);
    nc_v8i_store((int32_t *)(void *)out, a);
    nc_v8i_store((int32_t *)(void *)(out + 8), b);
    nc_v8i_store((int32_t *)(void *)(out + 16), c);
}

void nc_fog_field_eval(const nc_fog_field *f, uint32_t n, const float *p, float *sigma_t, float *sigma_s, float *g,
                       float *scratch)
{
    size_t nn = ((size_t)n + 7) & ~(size_t)7;
    float *px = scratch, *py = px + nn, *pz = py + nn;
    float *at = pz + nn, *as = at + 3 * nn, *ag = as + 3 * nn; /* sigma_t, sigma_s (channel c at c nn), g */
    uint8_t *in = (uint8_t *)(ag + nn);                        /* per block of 8: the lanes inside */
    float *local = ag + 2 * nn, *sa = local + 3 * nn, *ss = sa + 3 * nn; /* packed for nc_medium_eval */
    size_t full = (size_t)n & ~(size_t)7;
    for (size_t k = 0; k < full; k += 8) {
        nc_v8i x, y, z;
        nc_v8_deinterleave3(nc_v8i_load((const int32_t *)(const void *)(p + 3 * k)),
                            nc_v8i_load((const int32_t *)(const void *)(p + 3 * k + 8)),
                            nc_v8i_load((const int32_t *)(const void *)(p + 3 * k + 16)), &x, &y, &z);
        nc_v8_store(px + k, (nc_v8f)x);
        nc_v8_store(py + k, (nc_v8f)y);
        nc_v8_store(pz + k, (nc_v8f)z);
    }
    for (size_t k = full; k < nn; k++) {
        px[k] = k < n ? p[3 * k] : 0.0f;
        py[k] = k < n ? p[3 * k + 1] : 0.0f;
        pz[k] = k < n ? p[3 * k + 2] : 0.0f;
    }
    memset(at, 0, 7 * nn * sizeof(float));
    /* g accumulates sigma_s x g (channel mean) first, then is divided by the channel-mean sigma_s. */
    for (uint32_t i = 0; i < f->count; i++) {
        const nc_fog_one *o = &f->fogs[i];
        if (!o->box && !o->patterned) {
            /* A global fog without pattern: its coefficients times the height factor, which
             * nc_vol_exp_fast (relative error 1e-7) gives 8 lanes at a time. */
            float flat = nc_vol_height_factor(false, 0.0f, 0.0f, o->hf_cap, 0.0f);
            float ms = o->sigma_s[0] + o->sigma_s[1] + o->sigma_s[2], ts[3];
            for (int c = 0; c < 3; c++)
                ts[c] = o->sigma_a[c] + o->sigma_s[c];
            for (size_t k = 0; k < nn; k += 8) {
                nc_v8f hf = nc_v8_splat(flat);
                if (o->height) {
                    nc_v8f e = -o->hf_falloff * (nc_v8_load(py + k) - o->hf_base);
                    hf = nc_vol_exp_fast8(nc_v8_sel(e < o->hf_cap, e, nc_v8_splat(o->hf_cap))); /* fminf */
                }
                for (int c = 0; c < 3; c++) {
                    nc_v8_store(at + c * nn + k, nc_v8_load(at + c * nn + k) + ts[c] * hf);
                    nc_v8_store(as + c * nn + k, nc_v8_load(as + c * nn + k) + o->sigma_s[c] * hf);
                }
                nc_v8_store(ag + k, nc_v8_load(ag + k) + ms * hf * o->g);
            }
            continue;
        }
        /* The local point (to_local) and, for bounded fogs, which lanes are inside
         * (nc_vol_shape_inside), 8 points at a time; then the rest point by point. */
        const float(*w)[4] = o->w2l;
        const float *h = o->half;
        uint32_t m = 0;
        for (size_t k = 0; k < nn; k += 8) {
            nc_v8f x = nc_v8_load(px + k), y = nc_v8_load(py + k), z = nc_v8_load(pz + k);
            nc_v8f lx = w[0][0] * x + w[0][1] * y + w[0][2] * z + w[0][3];
            nc_v8f ly = w[1][0] * x + w[1][1] * y + w[1][2] * z + w[1][3];
            nc_v8f lz = w[2][0] * x + w[2][1] * y + w[2][2] * z + w[2][3];
            nc_v8i inside = nc_v8_first((uint32_t)(n - k < 8 ? n - k : 8));
            if (o->box && o->ellipsoid) {
                nc_v8f ex = lx / h[0], ey = ly / h[1], ez = lz / h[2];
                inside &= ex * ex + ey * ey + ez * ez <= 1.0f;
            } else if (o->box) {
                const nc_v8i abs_mask = (nc_v8i){0} + 0x7fffffff; /* fabsf: the sign bit cleared */
                inside &= ((nc_v8f)((nc_v8i)lx & abs_mask) <= h[0]) & ((nc_v8f)((nc_v8i)ly & abs_mask) <= h[1]) &
                          ((nc_v8f)((nc_v8i)lz & abs_mask) <= h[2]);
            }
            uint32_t bits = nc_v8_bits(inside);
            in[k / 8] = (uint8_t)bits;
            for (uint32_t b = bits; b; b &= b - 1) {
                int l = __builtin_ctz(b);
                local[3 * m] = lx[l];
                local[3 * m + 1] = ly[l];
                local[3 * m + 2] = lz[l];
                m++;
            }
        }
        if (m == 0)
            continue;
        if (o->patterned)
            nc_medium_eval(f->scene, o->medium, local, m, sa, ss);
        /* Without falloff the height factor is one constant. */
        float flat = o->height ? 0.0f : nc_vol_height_factor(false, o->hf_falloff, o->hf_base, o->hf_cap, 0.0f);
        uint32_t j = 0;
        for (size_t k = 0; k < nn; k += 8)
            for (uint32_t b = in[k / 8]; b; b &= b - 1, j++) {
                size_t q = k + (size_t)__builtin_ctz(b);
                float hf = o->height ? nc_vol_height_factor(true, o->hf_falloff, o->hf_base, o->hf_cap, py[q]) : flat;
                const float *a = o->patterned ? sa + 3 * (size_t)j : o->sigma_a;
                const float *s = o->patterned ? ss + 3 * (size_t)j : o->sigma_s;
                float msum = 0.0f;
                for (int c = 0; c < 3; c++) {
                    float av = a[c] * hf, sv = s[c] * hf;
                    at[c * nn + q] += av + sv;
                    as[c * nn + q] += sv;
                    msum += sv;
                }
                ag[q] += msum * o->g;
            }
    }
    for (size_t k = 0; k < nn; k += 8) {
        nc_v8f m = nc_v8_load(as + k) + nc_v8_load(as + nn + k) + nc_v8_load(as + 2 * nn + k);
        nc_v8f gk = nc_v8_sel(m > 0.0f, nc_v8_load(ag + k) / m, (nc_v8f){0});
        if (k + 8 <= n) {
            nc_v8_store(g + k, gk);
            interleave8(at + k, nn, sigma_t + 3 * k);
            interleave8(as + k, nn, sigma_s + 3 * k);
            continue;
        }
        for (size_t q = k; q < n; q++) {
            g[q] = gk[q - k];
            for (int c = 0; c < 3; c++) {
                sigma_t[3 * q + c] = at[c * nn + q];
                sigma_s[3 * q + c] = as[c * nn + q];
            }
        }
    }
}

void nc_fog_field_emission(const nc_fog_field *f, uint32_t n, const float *p, float *emission, float *scratch)
{
    float *local = scratch, *em = scratch + 3 * (size_t)n, *unused = scratch + 6 * (size_t)n;
    memset(emission, 0, 3 * (size_t)n * sizeof(float));
    for (uint32_t i = 0; i < f->count; i++) {
        const nc_fog_one *o = &f->fogs[i];
        if (!o->emissive)
            continue;
        for (uint32_t k = 0; k < n; k++)
            to_local(o, p + 3 * (size_t)k, local + 3 * (size_t)k);
        if (o->emission_patterned) {
            nc_medium_eval(f->scene, o->emission_medium, local, n, em, unused);
        } else {
            for (uint32_t k = 0; k < n; k++)
                memcpy(em + 3 * (size_t)k, o->emission, sizeof(o->emission));
        }
        for (uint32_t k = 0; k < n; k++) {
            if (o->box && !inside(o, local + 3 * (size_t)k))
                continue;
            float hf = nc_vol_height_factor(o->height, o->hf_falloff, o->hf_base, o->hf_cap, p[3 * (size_t)k + 1]);
            for (int c = 0; c < 3; c++)
                emission[3 * k + c] += em[3 * k + c] * hf;
        }
    }
}

void nc_fog_one_emission(const nc_fog_field *f, const nc_fog_one *o, const float p[3], float emission[3])
{
    emission[0] = emission[1] = emission[2] = 0.0f;
    if (!o->emissive)
        return;
    float q[3];
    to_local(o, p, q);
    if (o->emission_patterned) {
        float unused[3];
        nc_medium_eval(f->scene, o->emission_medium, q, 1, emission, unused);
    } else {
        memcpy(emission, o->emission, sizeof(o->emission));
    }
}

bool nc_fog_field_segment(const nc_fog_one *o, const float p[3], const float w[3], double *t0, double *t1)
{
    if (!o->box)
        return *t1 > *t0;
    double ol[3], dl[3], half[3];
    for (int k = 0; k < 3; k++) {
        const float *m = o->w2l[k];
        ol[k] = (double)m[0] * p[0] + (double)m[1] * p[1] + (double)m[2] * p[2] + m[3];
        dl[k] = (double)m[0] * w[0] + (double)m[1] * w[1] + (double)m[2] * w[2];
        half[k] = o->half[k];
    }
    return nc_vol_shape_segment(o->ellipsoid, half, ol, dl, t0, t1);
}

/* Where the ray p + t w leaves the scene bounds (0 if it starts outside and never enters). */
static double bounds_exit(const nc_fog_field *f, const float p[3], const float w[3])
{
    double a = 0.0, b = INFINITY;
    for (int k = 0; k < 3; k++) {
        if (w[k] == 0.0f) {
            if (p[k] < f->bounds_min[k] || p[k] > f->bounds_max[k])
                return 0.0;
            continue;
        }
        double ta = (f->bounds_min[k] - p[k]) / w[k], tb = (f->bounds_max[k] - p[k]) / w[k];
        if (ta > tb) {
            double u = ta;
            ta = tb;
            tb = u;
        }
        a = ta > a ? ta : a;
        b = tb < b ? tb : b;
    }
    return b > a ? b : 0.0;
}

bool nc_fog_field_patterned(const nc_fog_field *f)
{
    for (uint32_t i = 0; i < f->count; i++)
        if (f->fogs[i].patterned)
            return true;
    return false;
}

void nc_fog_one_optical_depth(const nc_fog_field *f, const nc_fog_one *o, const float p[3], const float w[3],
                              float tmax, double tau[3], float *scratch)
{
    double a = 0.0, b = tmax;
    if (!nc_fog_field_segment(o, p, w, &a, &b))
        return;
    if (!o->patterned) {
        double G = nc_vol_height_integral(&o->h, p[1], w[1], a, b);
        if (!(G > 0.0))
            return;
        for (int c = 0; c < 3; c++) {
            double st = (double)o->sigma_a[c] + o->sigma_s[c];
            if (st > 0.0)
                tau[c] += st * G; /* inf stays inf */
        }
        return;
    }
    /* Patterned: march [a, bm] (a global fog within the scene bounds), each step's pattern at
     * its midpoint times the step's height integral; what lies beyond bm gets the mean of the
     * marched pattern. */
    double bm = b;
    if (!o->box) {
        double e = bounds_exit(f, p, w);
        bm = e < b ? e : b;
    }
    uint32_t n = f->shadow_steps;
    double len = bm > a ? bm - a : 0.0, dt = len / n;
    float *local = scratch, *sa = scratch + 3 * (size_t)n, *ss = scratch + 6 * (size_t)n;
    for (uint32_t k = 0; k < n; k++) {
        float t = (float)(a + (k + 0.5) * dt);
        float q[3] = {p[0] + t * w[0], p[1] + t * w[1], p[2] + t * w[2]};
        to_local(o, q, local + 3 * (size_t)k);
    }
    nc_medium_eval(f->scene, o->medium, local, n, sa, ss);
    double mean[3] = {0, 0, 0};
    /* Without falloff every step has the same height integral. */
    double G_flat = o->height ? 0.0 : nc_vol_height_integral(&o->h, p[1], w[1], 0.0, dt);
    for (uint32_t k = 0; k < n; k++) {
        double G = G_flat;
        if (!(len > 0.0))
            G = 0.0;
        else if (o->height)
            G = nc_vol_height_integral(&o->h, p[1], w[1], a + k * dt, a + (k + 1) * dt);
        for (int c = 0; c < 3; c++) {
            double st = (double)sa[3 * k + c] + ss[3 * k + c];
            mean[c] += st / n;
            if (st > 0.0)
                tau[c] += st * G;
        }
    }
    if (b > bm) {
        double G = nc_vol_height_integral(&o->h, p[1], w[1], bm, b);
        for (int c = 0; c < 3; c++)
            if (mean[c] > 0.0 && G > 0.0)
                tau[c] += mean[c] * G;
    }
}

void nc_fog_field_optical_depth(const nc_fog_field *f, const float p[3], const float w[3], float tmax, unsigned which,
                                double tau[3], float *scratch)
{
    tau[0] = tau[1] = tau[2] = 0.0;
    for (uint32_t i = 0; i < f->count; i++) {
        const nc_fog_one *o = &f->fogs[i];
        if (!(which & (o->patterned ? NC_FOG_PATTERNED : NC_FOG_ANALYTIC)) || ((which & NC_FOG_BOXES) && !o->box))
            continue;
        nc_fog_one_optical_depth(f, o, p, w, tmax, tau, scratch);
    }
}
