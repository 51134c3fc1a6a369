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
 * Layout: each row is cut into runs; empty pixels get the environment in bulk (streaming stores
 * with AVX; only inside the previous frame's object span when the image still holds that frame,
 * nacre_render_settings.reuse_output: the rest of the row is that environment already), and
 * object pixels are shaded in batches (up to NC_SHADE_BATCH pixels of one object
 * and material, SoA) whose per-light arithmetic runs 8 lanes at a time in vector registers
 * (core/simd.h), every value computed on every lane and conditions as selects. The lanes that
 * need a shadow lookup are collected over the batch and go to nc_shadow_lookup_n together (the
 * set-up of an orthographic map's lookups is vectorized there; each PCF window stays per pixel,
 * with the next windows' texels prefetched). The batches compute a per-pixel loop's formulas,
 * with two differences in the last bit: an integer shininess is raised by exact binary powering
 * in double rather than powf (pow8), and products and sums may be fused into FMAs (the build's
 * -ffp-contract=fast, CMakeLists.txt).
 *
 * The diffusion method reuses this pass through the subsurface hook of nc_shade_params: its
 * translucent objects keep ambient and specular and get the diffusion radiance in place of the
 * Lambert direct term (Blanchard 2012 section 4.6.2: the deferred passes are summed).
 */
#include "shade/shade.h"
#include "core/optics.h"
#include "core/simd.h"
#include "layered/layers.h"
#include "scene/lights.h"

#include <math.h>
#include <stdint.h>
#include <string.h>
#ifdef __AVX__
#include <immintrin.h>
#endif

/* Relative contribution below which a light's shadow lookup is skipped (see shade_light):
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

/* x^s on 8 lanes. An integer exponent (the usual shininess) is computed by binary powering in
 * double: a few multiplies per lane instead of a powf call, with an error far below a float ulp,
 * so the result is powf's (correctly rounded) value except in rare last-bit cases. Other
 * exponents take powf. Lanes with x = 1 are the callers' don't-care lanes (kept at 1 so that no
 * lane goes through slow denormal arithmetic). */
static nc_v8f pow8(nc_v8f x, float s)
{
    if (!(s >= 1.0f && s <= 65536.0f && s == (float)(int32_t)s)) {
        for (int l = 0; l < 8; l++)
            x[l] = powf(x[l], s);
        return x;
    }
    /* The two halves in double, 4 lanes per vector, in registers */
    typedef float v4f __attribute__((vector_size(16)));
    typedef double v4d __attribute__((vector_size(32)));
    v4d r0 = {1.0, 1.0, 1.0, 1.0}, r1 = r0;
    v4d b0 = __builtin_convertvector(__builtin_shufflevector(x, x, 0, 1, 2, 3), v4d);
    v4d b1 = __builtin_convertvector(__builtin_shufflevector(x, x, 4, 5, 6, 7), v4d);
    for (uint32_t e = (uint32_t)s;;) {
        if (e & 1u) {
            r0 *= b0;
            r1 *= b1;
        }
        e >>= 1;
        if (!e)
            break;
        b0 *= b0;
        b1 *= b1;
    }
    const v4f lo = __builtin_convertvector(r0, v4f), hi = __builtin_convertvector(r1, v4f);
    return __builtin_shufflevector(lo, hi, 0, 1, 2, 3, 4, 5, 6, 7);
}

/* |x| per lane (clears the sign bit, as fabsf) */
static inline nc_v8f abs8(nc_v8f x) { return (nc_v8f)((nc_v8i)x & 0x7fffffff); }

/* n (1..8) consecutive xyz triples at p as three 8-lane vectors, lanes n..7 zero: three loads
 * (masked when n < 8: nothing past the n-th triple is read) and nc_v8_deinterleave3. */
static inline void load_xyz8(const float *p, uint32_t n, nc_v8f *x, nc_v8f *y, nc_v8f *z)
{
    nc_v8i a, b, c, xi, yi, zi;
#ifdef __AVX2__
    if (n == 8) {
        a = nc_v8i_load((const int32_t *)(const void *)p);
        b = nc_v8i_load((const int32_t *)(const void *)(p + 8));
        c = nc_v8i_load((const int32_t *)(const void *)(p + 16));
    } else {
        const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7), m = _mm256_set1_epi32((int)(3 * n));
        a = (nc_v8i)_mm256_maskload_ps(p, _mm256_cmpgt_epi32(m, lane));
        b = (nc_v8i)_mm256_maskload_ps(p + 8, _mm256_cmpgt_epi32(m, _mm256_add_epi32(lane, _mm256_set1_epi32(8))));
        c = (nc_v8i)_mm256_maskload_ps(p + 16, _mm256_cmpgt_epi32(m, _mm256_add_epi32(lane, _mm256_set1_epi32(16))));
    }
#else
    float t[24] = {0};
    memcpy(t, p, 3 * n * sizeof(float));
    memcpy(&a, t, 32);
    memcpy(&b, t + 8, 32);
    memcpy(&c, t + 16, 32);
#endif
    nc_v8_deinterleave3(a, b, c, &xi, &yi, &zi);
    *x = (nc_v8f)xi;
    *y = (nc_v8f)yi;
    *z = (nc_v8f)zi;
}

/* Per-material constants of the pass. */
typedef struct mat_k {
    float kd[3], spec_norm, nh_cut;
} mat_k;

static void material_constants(const nacre_material_desc *m, mat_k *k)
{
    nc_material_albedo(m, k->kd);
    k->spec_norm = (m->shininess + 8.0f) / (8.0f * NC_PI);
    k->nh_cut = spec_cut(m->shininess);
}

/* Add light l to the batch's radiance acc. Every lane runs the same operations (the image does
 * not depend on how rows are cut into batches), 8 lanes at a time (core/simd.h): every value is
 * computed on every lane and conditions only select. A shadowed light's lanes that need a lookup
 * are collected over the batch and looked up together. */
static void shade_light(const nc_shade_light *sl, const nacre_material_desc *m, const mat_k *mk,
                        const float kl[3][NC_SHADE_BATCH], float lambert, const nc_shade_batch *b,
                        const nc_gbuffer *gb, size_t first, const nc_shade_params *params,
                        float acc[3][NC_SHADE_BATCH])
{
    const nacre_light_desc *l = sl->desc;
    const uint32_t count = b->count;
    const float lx = l->position[0], ly = l->position[1], lz = l->position[2];
    const float dx0 = l->direction[0], dy0 = l->direction[1], dz0 = l->direction[2];
    const bool directional = l->type == NACRE_LIGHT_DIRECTIONAL, spot = l->type == NACRE_LIGHT_SPOT;
    /* The spot cone's cosines once per batch, not per pixel */
    const float co = spot ? cosf(l->outer_angle * NC_DEG2RAD) : 0.0f, ci = spot ? cosf(l->inner_angle * NC_DEG2RAD) : 0.0f;
    const nc_v8i hard = (nc_v8i){0} - (int32_t)(ci <= co);
    const float nh_cut = mk->nh_cut, spec_norm = mk->spec_norm;
    const nc_v8i has_lambert = (nc_v8i){0} - (int32_t)(lambert != 0.0f);
    const float s0 = l->strength[0], s1 = l->strength[1], s2 = l->strength[2];
    const float ks0 = m->specular[0], ks1 = m->specular[1], ks2 = m->specular[2];
    const nc_v8f zero = {0}, one = nc_v8_splat(1.0f);
    /* A shadowed light's lanes to look up, and their scale, cos_i and spec */
    uint32_t lanes[NC_SHADE_BATCH], nl = 0;
    float S[NC_SHADE_BATCH], C[NC_SHADE_BATCH], P[NC_SHADE_BATCH];
    for (uint32_t g = 0; g < count; g += 8) {
        const uint32_t n = count - g < 8 ? count - g : 8;
        const nc_v8f nx = nc_v8_load(b->nx + g), ny = nc_v8_load(b->ny + g), nz = nc_v8_load(b->nz + g);
        const nc_v8f kl0 = nc_v8_load(kl[0] + g), kl1 = nc_v8_load(kl[1] + g), kl2 = nc_v8_load(kl[2] + g);
        /* Direction to the light and its strength factor (distance, spot cone) */
        nc_v8f wx, wy, wz, scale;
        nc_v8i ok = nc_v8_first(n);
        if (directional) {
            wx = nc_v8_splat(-dx0);
            wy = nc_v8_splat(-dy0);
            wz = nc_v8_splat(-dz0);
            scale = one;
        } else {
            const nc_v8f dx = lx - nc_v8_load(b->px + g), dy = ly - nc_v8_load(b->py + g),
                         dz = lz - nc_v8_load(b->pz + g);
            const nc_v8f d2 = dx * dx + dy * dy + dz * dz;
            const nc_v8f inv = 1.0f / nc_v8_sqrt(d2);
            wx = dx * inv;
            wy = dy * inv;
            wz = dz * inv;
            scale = 1.0f / d2;
            ok &= ~(d2 <= 0.0f);
            if (spot) {
                const nc_v8f c = dx0 * -wx + dy0 * -wy + dz0 * -wz;
                scale *= nc_spot_falloff8(l->falloff, c, co, ci, hard);
            }
        }
        const nc_v8f ct = nx * wx + ny * wy + nz * wz;
        nc_v8f hx = wx + nc_v8_load(b->vx + g), hy = wy + nc_v8_load(b->vy + g), hz = wz + nc_v8_load(b->vz + g);
        const nc_v8f len = nc_v8_sqrt(hx * hx + hy * hy + hz * hz);
        const nc_v8f inv_len = 1.0f / len;
        const nc_v8i pos = len > 0.0f;
        hx = nc_v8_sel(pos, hx * inv_len, hx);
        hy = nc_v8_sel(pos, hy * inv_len, hy);
        hz = nc_v8_sel(pos, hz * inv_len, hz);
        nc_v8f d = nx * hx + ny * hy + nz * hz;
        d = nc_v8_sel(d > 0.0f, d, zero);
        const nc_v8i up = (d > nh_cut) & ok;
        /* cos_i <= 0 or scale <= 0: unlit; no highlight and no Lambert term: nothing to add */
        ok &= ~(ct <= 0.0f) & ~(scale <= 0.0f) & (up | has_lambert);
        nc_v8f spec = zero;
        if (m->shininess > 0 && nc_v8_bits(up)) /* else no lane is in the lobe: no powers */
            spec = nc_v8_sel(up, spec_norm * pow8(nc_v8_sel(up, d, one), m->shininess), zero);
        else if (!(m->shininess > 0))
            spec = nc_v8_sel(up, nc_v8_splat(spec_norm), zero);
        const nc_v8f a0 = nc_v8_load(acc[0] + g), a1 = nc_v8_load(acc[1] + g), a2 = nc_v8_load(acc[2] + g);
        if (!sl->shadow) {
            const nc_v8f e = scale * ct;
            nc_v8_store(acc[0] + g, nc_v8_sel(ok, a0 + s0 * e * (kl0 + ks0 * spec), a0));
            nc_v8_store(acc[1] + g, nc_v8_sel(ok, a1 + s1 * e * (kl1 + ks1 * spec), a1));
            nc_v8_store(acc[2] + g, nc_v8_sel(ok, a2 + s2 * e * (kl2 + ks2 * spec), a2));
            continue;
        }
        /* The shadow lookup (PCF) is the most expensive part of a pixel. When this light's
         * unshadowed term is below NEGLIGIBLE of what the pixel already has (typically the
         * specular highlight of a subsurface pixel away from the highlight), it cannot change
         * the pixel beyond that bound: the light is skipped. */
        const nc_v8f u0 = abs8(s0 * scale * ct * (kl0 + ks0 * spec)), u1 = abs8(s1 * scale * ct * (kl1 + ks1 * spec)),
                     u2 = abs8(s2 * scale * ct * (kl2 + ks2 * spec));
        nc_v8f un = nc_v8_sel(u0 > 0.0f, u0, zero);
        un = nc_v8_sel(u1 > un, u1, un);
        un = nc_v8_sel(u2 > un, u2, un);
        nc_v8f have = nc_v8_sel(a0 > 0.0f, a0, zero);
        have = nc_v8_sel(a1 > have, a1, have);
        have = nc_v8_sel(a2 > have, a2, have);
        ok &= ~(un <= NEGLIGIBLE * have);
        uint32_t bits = nc_v8_bits(ok);
        if (!bits)
            continue;
        nc_v8_store(S + g, scale);
        nc_v8_store(C + g, ct);
        nc_v8_store(P + g, spec);
        for (; bits; bits &= bits - 1) {
            const uint32_t i = g + (uint32_t)__builtin_ctz(bits);
            lanes[nl++] = i;
            /* Its geometric normal, read after the loop: that array is not streamed otherwise */
            __builtin_prefetch(gb->geo_normal + 3 * (first + i));
        }
    }
    if (nl == 0)
        return;
    /* The collected lanes' lookups together (nc_shadow_lookup_n), at their positions with the
     * geometric normals; then their terms, scaled by the lit fraction */
    float qx[NC_SHADE_BATCH], qy[NC_SHADE_BATCH], qz[NC_SHADE_BATCH];
    float gx[NC_SHADE_BATCH], gy[NC_SHADE_BATCH], gz[NC_SHADE_BATCH], lit[NC_SHADE_BATCH];
    for (uint32_t t = 0; t < nl; t++) {
        const uint32_t i = lanes[t];
        const float *ng = gb->geo_normal + 3 * (first + i);
        qx[t] = b->px[i];
        qy[t] = b->py[i];
        qz[t] = b->pz[i];
        gx[t] = ng[0];
        gy[t] = ng[1];
        gz[t] = ng[2];
    }
    nc_shadow_lookup_n(sl->shadow, nl, qx, qy, qz, gx, gy, gz, params->pcf_radius, params->shadow_bias, lit);
    for (uint32_t t = 0; t < nl; t++) {
        const uint32_t i = lanes[t];
        const float scale = S[i] * lit[t];
        if (!(scale > 0))
            continue;
        const float e = scale * C[i];
        const float kl0 = kl[0][i], kl1 = kl[1][i], kl2 = kl[2][i];
        acc[0][i] += s0 * e * (kl0 + ks0 * P[i]);
        acc[1][i] += s1 * e * (kl1 + ks1 * P[i]);
        acc[2][i] += s2 * e * (kl2 + ks2 * P[i]);
    }
}

/* Environment radiance into n pixels: the background, most of a typical frame, in bulk. With
 * AVX the aligned middle of a long run is written with streaming stores: the image is far larger
 * than the caches, and plain stores would first read every line they fill (twice the memory
 * traffic). The caller fences (stream_fence) before the pass ends. */
static void fill_env(float *out, int32_t n, const float env[3])
{
    int32_t k = 0;
#ifdef __AVX__
    /* Pixels until the float after them is 32-byte aligned, then 8 pixels (3 vectors) a step */
    if (n >= 32) {
        while (k < n && ((uintptr_t)(out + 3 * (size_t)k) & 31u) != 0) {
            out[3 * k] = env[0];
            out[3 * k + 1] = env[1];
            out[3 * k + 2] = env[2];
            k++;
        }
        if (((uintptr_t)(out + 3 * (size_t)k) & 31u) == 0) {
            /* 24 floats = 8 pixels, starting at a pixel boundary */
            __m256 a = _mm256_setr_ps(env[0], env[1], env[2], env[0], env[1], env[2], env[0], env[1]);
            __m256 b = _mm256_setr_ps(env[2], env[0], env[1], env[2], env[0], env[1], env[2], env[0]);
            __m256 c = _mm256_setr_ps(env[1], env[2], env[0], env[1], env[2], env[0], env[1], env[2]);
            for (; k + 8 <= n; k += 8) {
                float *o = out + 3 * (size_t)k;
                _mm256_stream_ps(o, a);
                _mm256_stream_ps(o + 8, b);
                _mm256_stream_ps(o + 16, c);
            }
        }
    }
#endif
    for (; k < n; k++) {
        out[3 * k] = env[0];
        out[3 * k + 1] = env[1];
        out[3 * k + 2] = env[2];
    }
}

/* Orders fill_env's streaming stores before the pass returns (they are weakly ordered). */
static void stream_fence(void)
{
#ifdef __AVX__
    _mm_sfence();
#endif
}

/* Shade pixels [first, first + count) of the G-buffer, all of one object and material, into out. */
static void shade_run(const nacre_scene *scene, const nc_gbuffer *gb, const nc_shade_light *lights,
                      uint32_t light_count, const nc_shade_params *params, const mat_k *mk, size_t first,
                      uint32_t count, float *out)
{
    const float *env = scene->environment;
    const uint32_t object = gb->object[first];
    const nacre_material_desc *m = &scene->materials[gb->material[first]];
    nc_shade_batch b;
    float acc[3][NC_SHADE_BATCH];
    b.count = count;
    b.first = first;
    /* The batch's arrays are written 8 whole lanes at a time, the padding lanes included (see
     * nc_shade_batch): the kernels read them as vectors, and a vector load of lanes just written
     * one float at a time waits for those stores (no store forwarding), a stall per array and
     * batch that cost 2-3% of the pass. */
    const float *P = gb->position + 3 * first, *N = gb->normal + 3 * first;
    const uint32_t padded = (count + 7u) & ~7u;
    for (uint32_t g = 0; g < padded; g += 8) {
        const uint32_t n = count - g < 8 ? count - g : 8;
        nc_v8f x, y, z;
        load_xyz8(P + 3 * (size_t)g, n, &x, &y, &z);
        nc_v8_store(b.px + g, x);
        nc_v8_store(b.py + g, y);
        nc_v8_store(b.pz + g, z);
        load_xyz8(N + 3 * (size_t)g, n, &x, &y, &z);
        nc_v8_store(b.nx + g, x);
        nc_v8_store(b.ny + g, y);
        nc_v8_store(b.nz + g, z);
    }
    if (params->orthographic) {
        const nc_v8f vx = nc_v8_splat(-params->view_dir.x), vy = nc_v8_splat(-params->view_dir.y),
                     vz = nc_v8_splat(-params->view_dir.z);
        for (uint32_t g = 0; g < padded; g += 8) {
            nc_v8_store(b.vx + g, vx);
            nc_v8_store(b.vy + g, vy);
            nc_v8_store(b.vz + g, vz);
        }
    } else {
        const float ex = params->eye.x, ey = params->eye.y, ez = params->eye.z;
        for (uint32_t g = 0; g < padded; g += 8) {
            const nc_v8f x = ex - nc_v8_load(b.px + g), y = ey - nc_v8_load(b.py + g), z = ez - nc_v8_load(b.pz + g);
            const nc_v8f l = nc_v8_sqrt(x * x + y * y + z * z);
            const nc_v8f inv = 1.0f / l;
            const nc_v8i pos = l > 0.0f;
            nc_v8_store(b.vx + g, nc_v8_sel(pos, x * inv, x));
            nc_v8_store(b.vy + g, nc_v8_sel(pos, y * inv, y));
            nc_v8_store(b.vz + g, nc_v8_sel(pos, z * inv, z));
        }
    }
    /* Lambert albedo per lane: the material's, times its diffuse map at the pixel's uv */
    float kd[3][NC_SHADE_BATCH];
    for (int c = 0; c < 3; c++)
        for (uint32_t i = 0; i < padded; i++) /* the 8-lane groups read the padding */
            kd[c][i] = mk->kd[c];
    if (m->type == NACRE_MATERIAL_OPAQUE && m->diffuse_map.id != 0) {
        const nc_texture_rec *tex = nc_scene_texture(scene, m->diffuse_map);
        const float *uv = gb->uv + 2 * first;
        for (uint32_t i = 0; tex && i < count; i++) {
            float t[3];
            nc_texture_rgb(tex, uv[2 * i], uv[2 * i + 1], t);
            for (int c = 0; c < 3; c++)
                kd[c][i] *= t[c];
        }
    }
    for (int c = 0; c < 3; c++)
        for (uint32_t i = 0; i < padded; i++)
            acc[c][i] = kd[c][i] * env[c];
    /* Diffusion method: the light that enters and leaves the medium replaces Lambert. */
    float lambert = 1.0f / NC_PI;
    if (params->subsurface_object && params->subsurface_object[object]) {
        float sub[3][NC_SHADE_BATCH];
        params->subsurface(params->subsurface_user, object, &b, sub);
        for (int c = 0; c < 3; c++)
            for (uint32_t i = 0; i < padded; i++) /* whole groups, as the lights read them */
                acc[c][i] += sub[c][i];
        lambert = 0.0f;
    }
    /* The Lambert factor kd / pi per lane, computed here and read back from memory by the
     * lights: formed inside their arithmetic, the product would be fused into an FMA with the
     * specular term and round differently from an untextured material's constant. */
    float kl[3][NC_SHADE_BATCH];
    for (int c = 0; c < 3; c++)
        for (uint32_t i = 0; i < padded; i++)
            kl[c][i] = kd[c][i] * lambert;
    for (uint32_t li = 0; li < light_count; li++)
        shade_light(&lights[li], m, mk, (const float(*)[NC_SHADE_BATCH])kl, lambert, &b, gb, first, params, acc);
    for (uint32_t i = 0; i < count; i++) {
        out[3 * i] = acc[0][i];
        out[3 * i + 1] = acc[1][i];
        out[3 * i + 2] = acc[2][i];
    }
}

/* Row y: runs of empty pixels get the environment in bulk, and object pixels are shaded in
 * batches of one object and material (shade_run). */
static void shade_row(const nacre_scene *scene, const nc_gbuffer *gb, const nc_shade_light *lights,
                      uint32_t light_count, const nc_shade_params *params, const mat_k *mks, uint32_t cached,
                      const int32_t *prev_span, int32_t y, float *row)
{
    const int32_t w = gb->width;
    const size_t base = (size_t)y * (size_t)w;
    const uint32_t *obj = gb->object + base, *mat = gb->material + base;
    /* Outside the row's object span (nc_gbuffer) every pixel is empty: no ids to read there */
    int32_t x = 0, end = w;
    if (gb->row_span) {
        x = gb->row_span[2 * y];
        end = gb->row_span[2 * y + 1];
        x = x < 0 ? 0 : x > w ? w : x;
        end = end < x ? x : end > w ? w : end;
        /* The row outside its object span; outside the previous frame's span too, the pixels
         * hold the environment already */
        int32_t lo = 0, hi = w;
        if (prev_span) {
            lo = prev_span[2 * y] < 0 ? 0 : prev_span[2 * y];
            hi = prev_span[2 * y + 1] > w ? w : prev_span[2 * y + 1];
        }
        int64_t r[4];
        nc_range_minus(lo, hi, x, end, r);
        for (int k = 0; k < 4; k += 2)
            if (r[k + 1] > r[k])
                fill_env(row + 3 * (size_t)r[k], (int32_t)(r[k + 1] - r[k]), scene->environment);
    }
    while (x < end) {
        int32_t x0 = x;
#ifdef __AVX2__
        /* Sixteen ids at a time: one compare with NC_NO_OBJECT per eight */
        {
            const __m256i none = _mm256_set1_epi32((int)NC_NO_OBJECT);
            for (; x + 16 <= end; x += 16) {
                __m256i a = _mm256_cmpeq_epi32(_mm256_loadu_si256((const __m256i *)(obj + x)), none);
                __m256i b = _mm256_cmpeq_epi32(_mm256_loadu_si256((const __m256i *)(obj + x + 8)), none);
                if (_mm256_movemask_epi8(_mm256_and_si256(a, b)) != -1)
                    break;
            }
        }
#endif
        /* Eight ids at a time: their AND is NC_NO_OBJECT only if all are (one vector test) */
        for (; x + 8 <= end; x += 8) {
            uint32_t all = NC_NO_OBJECT;
            for (int k = 0; k < 8; k++)
                all &= obj[x + k];
            if (all != NC_NO_OBJECT)
                break;
        }
        while (x < end && obj[x] == NC_NO_OBJECT)
            x++;
        if (x > x0) {
            fill_env(row + 3 * (size_t)x0, x - x0, scene->environment);
            continue;
        }
        uint32_t o = obj[x0], mi = mat[x0];
        const int32_t batch_end = end - x0 < NC_SHADE_BATCH ? end : x0 + NC_SHADE_BATCH;
#ifdef __AVX2__
        /* The run's end eight ids at a time: where object or material first differ */
        {
            const __m256i vo = _mm256_set1_epi32((int)o), vm = _mm256_set1_epi32((int)mi);
            for (; x + 8 <= batch_end; x += 8) {
                __m256i same = _mm256_and_si256(
                    _mm256_cmpeq_epi32(_mm256_loadu_si256((const __m256i *)(obj + x)), vo),
                    _mm256_cmpeq_epi32(_mm256_loadu_si256((const __m256i *)(mat + x)), vm));
                uint32_t bits = (uint32_t)_mm256_movemask_ps(_mm256_castsi256_ps(same));
                if (bits != 0xffu) {
                    x += __builtin_ctz(~bits);
                    break;
                }
            }
        }
#endif
        while (x < batch_end && obj[x] == o && mat[x] == mi)
            x++;
        mat_k local;
        const mat_k *mk = mi < cached ? &mks[mi] : &local;
        if (mi >= cached)
            material_constants(&scene->materials[mi], &local);
        shade_run(scene, gb, lights, light_count, params, mk, base + (size_t)x0, (uint32_t)(x - x0),
                  row + 3 * (size_t)x0);
    }
}

void nc_shade_phong(const nacre_scene *scene, const nc_gbuffer *gb, const nc_shade_light *lights,
                    uint32_t light_count, const nc_shade_params *params, float *rgb, size_t stride,
                    const int32_t *prev_span, int threads)
{
    const int32_t h = gb->height;
    /* Per-material constants, looked up per run of pixels by index. Materials are few; a fixed
     * cap keeps this allocation-free, and larger scenes recompute them per run. */
    enum { CACHE = 256 };
    mat_k mks[CACHE];
    uint32_t cached = scene->material_count < CACHE ? scene->material_count : CACHE;
    for (uint32_t i = 0; i < cached; i++)
        material_constants(&scene->materials[i], &mks[i]);

    /* Rows in small dynamic chunks: objects cover the image unevenly, and static halves left one
     * thread idle for a large part of the pass. Pixels are independent, so the image does not
     * depend on the schedule. */
#pragma omp parallel num_threads(threads)
    {
#pragma omp for schedule(dynamic, 8)
        for (int32_t y = 0; y < h; y++)
            shade_row(scene, gb, lights, light_count, params, mks, cached, gb->row_span ? prev_span : NULL, y,
                      rgb + (size_t)y * stride);
        stream_fence(); /* this thread's streaming stores, before the region ends */
    }
}
