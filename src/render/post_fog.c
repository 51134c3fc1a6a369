/*
 * post_fog.c: distance fog and exponential height fog as a post pass (Hubert 2020, seed 003
 * §2.1: analytic fog from the depth buffer; §2.1.2 height fog; §2.1.4 the fog's colour from a
 * light at infinity through the phase function plus an ambient term from the environment), over
 * the image of every method that does not render fog itself (phong, diffusion), background and
 * translucent objects included.
 *
 * Per pixel, the camera ray through the pixel centre (perspective: from the eye; orthographic:
 * from the near plane, as the path tracer's rays) runs to the depth buffer's surface or, over
 * the background, to infinity. Each fog i contributes the integral G_i of its height factor over
 * its part of the ray (global: all of it; box: the ray-box segment), in closed form
 * (nc_vol_height_integral), so its optical depth per channel is sigma_t,i G_i. The pixel's
 * colour c becomes c T + L, per channel, with
 *   T = e^(-tau),  tau = sum_i sigma_t,i G_i,
 *   L = (1 - T) / tau x sum_i (sigma_s,i S_i + eps_i) G_i,
 *   S_i = sum over directional lights l of E_l p_i(cos theta_l) + L_env,
 * E_l the light's irradiance, p_i fog i's Henyey-Greenstein phase at the angle between the
 * light's direction and the way to the eye, L_env the environment radiance taken as isotropic
 * ambient light (the phase integrates to 1 over directions), eps_i fog i's emission (radiance per
 * unit length where its height factor is 1, §1.2.11: a source like sigma_s S). For one fog of constant density
 * this is the exact single scattering of a medium lit without occlusion, sigma_s / sigma_t
 * (1 - T) S (the segment integral of §1.2.10); for height fog too, since S is constant along the
 * ray. Several fogs share the scattered light in proportion to their optical depths: exact when
 * their densities are proportional along the ray, energy-conserving always. Where the optical
 * depth diverges (the background through a global fog without falloff, or through height fog
 * along a level or descending ray) T = 0 and L is the diverging fogs' own colour,
 * sum (sigma_s,i S_i + eps_i) / sum sigma_t,i. A bounded fog that emits without extinction
 * adds eps G unattenuated by itself (the sigma_t -> 0 limit).
 *
 * Not modelled here (the froxel pass of issue 24 is where they belong): shadows in the fog and
 * the fog's attenuation of the light on its way in (every point is lit fully), point and spot
 * lights (they add no fog light; nacre render notes it), multiple scattering, the light that
 * emitting fog casts on surfaces and other fog. Patterned fogs use their mean coefficients and
 * mean emission over 16^3 points of the box (global fogs: of the scene's bounds), computed when
 * the fogs or the geometry change.
 *
 * The pixels are evaluated 8 at a time in float (8-lane vectors: rays, segments, the height
 * integral, the phase and the exponentials); test_fog_pass holds them within 1e-4 relative (in
 * practice 1e-6) of the same formula in double.
 *
 * Each pixel's T and L are kept between frames: a frame with the same committed scene, camera
 * and depth buffer (a viewer's still frames) only applies them.
 *
 * Units: scene units along unit directions; coefficients per scene unit; radiance per channel.
 */
#include "core/core.h"
#include "particles/particles.h"
#include "render/method.h"
#include "scene/medium.h"
#include "volume/volume.h"

#include <math.h>
#include <string.h>

enum { MEAN_RES = 16, MEAN_POINTS = MEAN_RES * MEAN_RES * MEAN_RES };

/* One fog as the pixels need it. */
typedef struct fog_const {
    bool box, ellipsoid; /* box: bounded (a box, or an ellipsoid if `ellipsoid`) */
    double w2l[3][4]; /* box: world -> local rows (rotation and translation) */
    double half[3];   /* box: half edge lengths (ellipsoid: semi-axes) */
    nc_vol_height h;
    /* The pixels' float forms of the above (fog_pixels8) */
    float w2lf[3][4], halff[3], inv_halff[3];
    nc_vol_height8 h8;
    double sigma_t[3], sigma_s[3]; /* where the height factor is 1 (patterns: their mean) */
    double emission[3];            /* likewise */
    double g;
} fog_const;

/* A directional light: the way its light travels, and its irradiance. */
typedef struct sun {
    double dir[3], e[3];
} sun;

/* The camera rays of the frame: pixel (x, y) -> view-space point through inv_proj. */
typedef struct camera_rays {
    double inv_proj[4][4];
    double cam_to_world[3][4];
    double sx, sy; /* pixel -> NDC */
    bool ortho;
} camera_rays;

/* What the pixels' transmittance and radiance depend on besides the depth buffer, compared whole
 * between frames (zeroed before being set, so padding compares). */
typedef struct fog_key {
    uint64_t uid, particles_built;
    nc_versions versions;
    uint32_t fog_count;
    nc_mat4 view, proj;
    int32_t width, height;
    bool ortho;
} fog_key;

typedef struct fog_state {
    fog_const fogs[NACRE_MAX_FOGS];
    uint32_t fog_count;
    sun *suns;
    uint32_t sun_capacity, sun_count;
    double env[3];
    /* Mean coefficients of the fogs, for the scene, fog and geometry versions they came from. */
    bool mean_valid;
    uint64_t mean_uid, mean_env, mean_geo;
    float mean_sa[NACRE_MAX_FOGS][3], mean_ss[NACRE_MAX_FOGS][3], mean_em[NACRE_MAX_FOGS][3];
    float *points, *eval_sa, *eval_ss; /* MEAN_POINTS x 3 each */
    /* Per pixel T and L (rgb each, 6 floats) of the frame of `key` and `depth`, kept while
     * `valid`: a frame with the same scene, camera and depths only applies them. */
    float *tl, *depth;
    size_t tl_capacity, depth_capacity;
    fog_key key;
    bool valid;
} fog_state;

/* The fogs this pass draws: the fogs of particle systems only when particles are drawn as
 * voxels (billboards and sprites have their own pass, post_particles.c); they come last. */

static bool fog_wanted(const nacre_scene *scene, const nacre_render_settings *settings)
{
    const nc_method *m = nc_method_get(settings->method);
    return nc_post_fogs_drawn(scene, settings) > 0 && m && !m->renders_fog && settings->volumetrics.mode == NACRE_VOLUMETRICS_OFF &&
           !nc_scene_particles_iso_drawn(scene, settings);
}

static void fog_destroy(nacre_context *ctx, void *state)
{
    fog_state *st = state;
    if (!st)
        return;
    nc_free(ctx, st->suns);
    nc_free(ctx, st->points);
    nc_free(ctx, st->eval_sa);
    nc_free(ctx, st->eval_ss);
    nc_free(ctx, st->tl);
    nc_free(ctx, st->depth);
    nc_free(ctx, st);
}

static nacre_result fog_create(nacre_context *ctx, void **state)
{
    fog_state *st = nc_calloc(ctx, 1, sizeof(*st));
    if (!st)
        return NACRE_ERROR_OUT_OF_MEMORY;
    size_t bytes = (size_t)MEAN_POINTS * 3 * sizeof(float);
    st->points = nc_alloc(ctx, bytes);
    st->eval_sa = nc_alloc(ctx, bytes);
    st->eval_ss = nc_alloc(ctx, bytes);
    if (!st->points || !st->eval_sa || !st->eval_ss) {
        fog_destroy(ctx, st);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    *state = st;
    return NACRE_OK;
}

/* Mean sigma_a, sigma_s of a patterned fog over a stratified grid of the region it is seen in:
 * its box (an ellipsoid: the grid's points inside it), or for a global fog the scene's bounds
 * (where the camera looks). */
static void pattern_mean(fog_state *st, const nacre_scene *s, const nc_fog_rec *rec, const nacre_material_desc *m,
                         float sa[3], float ss[3])
{
    bool box = rec->desc.shape != NACRE_FOG_GLOBAL, ellipsoid = rec->desc.shape == NACRE_FOG_SPHERE;
    for (int k = 0; k < MEAN_RES; k++)
        for (int j = 0; j < MEAN_RES; j++)
            for (int i = 0; i < MEAN_RES; i++) {
                float u[3] = {(i + 0.5f) / MEAN_RES, (j + 0.5f) / MEAN_RES, (k + 0.5f) / MEAN_RES};
                float *p = st->points + 3 * ((size_t)i + MEAN_RES * ((size_t)j + MEAN_RES * (size_t)k));
                nc_vec3 q;
                if (box)
                    q = nc_v3((u[0] - 0.5f) * rec->desc.size[0], (u[1] - 0.5f) * rec->desc.size[1],
                              (u[2] - 0.5f) * rec->desc.size[2]);
                else
                    q = nc_mat4_point(&rec->world_to_local,
                                      nc_v3(s->bounds_min[0] + u[0] * (s->bounds_max[0] - s->bounds_min[0]),
                                            s->bounds_min[1] + u[1] * (s->bounds_max[1] - s->bounds_min[1]),
                                            s->bounds_min[2] + u[2] * (s->bounds_max[2] - s->bounds_min[2])));
                p[0] = q.x, p[1] = q.y, p[2] = q.z;
            }
    nc_medium_eval(s, m, st->points, MEAN_POINTS, st->eval_sa, st->eval_ss);
    double a[3] = {0, 0, 0}, b[3] = {0, 0, 0};
    const float half[3] = {0.5f * rec->desc.size[0], 0.5f * rec->desc.size[1], 0.5f * rec->desc.size[2]};
    size_t counted = 0;
    for (size_t n = 0; n < MEAN_POINTS; n++) {
        if (ellipsoid && !nc_vol_shape_inside(true, half, st->points + 3 * n))
            continue;
        counted++;
        for (int c = 0; c < 3; c++) {
            a[c] += st->eval_sa[3 * n + c];
            b[c] += st->eval_ss[3 * n + c];
        }
    }
    const double count = counted ? (double)counted : 1.0;
    for (int c = 0; c < 3; c++) {
        sa[c] = (float)(a[c] / count);
        ss[c] = (float)(b[c] / count);
    }
}

/* The frame's fogs, directional lights and environment. */
static nacre_result fog_setup(fog_state *st, nacre_context *ctx, const nacre_scene *s)
{
    if (!st->mean_valid || st->mean_uid != s->uid || st->mean_env != s->committed.environment ||
        st->mean_geo != s->committed.geometry) {
        for (uint32_t i = 0; i < s->fog_count; i++) {
            const nc_fog_rec *rec = &s->fogs[i];
            if (nc_medium_heterogeneous(&rec->medium)) {
                pattern_mean(st, s, rec, &rec->medium, st->mean_sa[i], st->mean_ss[i]);
            } else {
                memcpy(st->mean_sa[i], rec->desc.sigma_a, sizeof(st->mean_sa[i]));
                memcpy(st->mean_ss[i], rec->desc.sigma_s, sizeof(st->mean_ss[i]));
            }
            float unused[3];
            if (rec->emissive && rec->emission_patterned)
                pattern_mean(st, s, rec, &rec->emission, st->mean_em[i], unused);
            else
                memcpy(st->mean_em[i], rec->desc.emission, sizeof(st->mean_em[i]));
        }
        st->mean_valid = true;
        st->mean_uid = s->uid;
        st->mean_env = s->committed.environment;
        st->mean_geo = s->committed.geometry;
    }
    st->fog_count = s->fog_count;
    for (uint32_t i = 0; i < s->fog_count; i++) {
        const nc_fog_rec *rec = &s->fogs[i];
        fog_const *f = &st->fogs[i];
        f->box = rec->desc.shape != NACRE_FOG_GLOBAL;
        f->ellipsoid = rec->desc.shape == NACRE_FOG_SPHERE;
        for (int r = 0; r < 3; r++) {
            for (int c = 0; c < 4; c++)
                f->w2l[r][c] = rec->world_to_local.m[r][c];
            f->half[r] = 0.5 * rec->desc.size[r];
        }
        /* The density cap exactly as the path tracer applies it (volume.h). */
        float mx[3];
        nc_medium_max_sigma_t(s, &rec->medium, mx);
        bool height = rec->desc.height_falloff > 0;
        f->h = (nc_vol_height){.falloff = height ? rec->desc.height_falloff : 0.0,
                               .base = rec->desc.height_base,
                               .cap = nc_vol_height_exp_cap(height, fmaxf(mx[0], fmaxf(mx[1], mx[2])))};
        f->h8 = nc_vol_height8_make(&f->h);
        for (int r = 0; r < 3; r++) {
            for (int c = 0; c < 4; c++)
                f->w2lf[r][c] = (float)f->w2l[r][c];
            f->halff[r] = (float)f->half[r];
            f->inv_halff[r] = (float)(1.0 / f->half[r]);
        }
        for (int c = 0; c < 3; c++) {
            f->sigma_s[c] = st->mean_ss[i][c];
            f->sigma_t[c] = (double)st->mean_sa[i][c] + st->mean_ss[i][c];
            f->emission[c] = st->mean_em[i][c];
        }
        f->g = rec->desc.g;
    }
    uint32_t suns = 0;
    for (uint32_t i = 0; i < s->light_count; i++)
        suns += s->lights[i].desc.type == NACRE_LIGHT_DIRECTIONAL;
    if (suns > st->sun_capacity) {
        sun *grown = nc_alloc(ctx, suns * sizeof(*grown));
        if (!grown)
            return NACRE_ERROR_OUT_OF_MEMORY;
        nc_free(ctx, st->suns);
        st->suns = grown;
        st->sun_capacity = suns;
    }
    st->sun_count = 0;
    for (uint32_t i = 0; i < s->light_count; i++) {
        const nacre_light_desc *ld = &s->lights[i].desc;
        if (ld->type != NACRE_LIGHT_DIRECTIONAL)
            continue;
        sun *l = &st->suns[st->sun_count++];
        for (int c = 0; c < 3; c++) {
            l->dir[c] = ld->direction[c];
            l->e[c] = ld->strength[c];
        }
    }
    for (int c = 0; c < 3; c++)
        st->env[c] = s->environment[c];
    return NACRE_OK;
}

static void camera_setup(const nc_raster_view *v, camera_rays *cr)
{
    nc_mat4 inv_proj, inv_view;
    nc_mat4_inverse(v->proj, &inv_proj);
    nc_mat4_inverse(v->view, &inv_view);
    for (int r = 0; r < 4; r++)
        for (int c = 0; c < 4; c++) {
            cr->inv_proj[r][c] = inv_proj.m[r][c];
            if (r < 3)
                cr->cam_to_world[r][c] = inv_view.m[r][c];
        }
    cr->sx = 2.0 / v->width;
    cr->sy = 2.0 / v->height;
    cr->ortho = v->orthographic;
}

/* The camera rays through the centres of pixels x0 .. x0 + 7 of row y (perspective: from the
 * eye; orthographic: from the near plane) in world space, in float: origins O and unit
 * directions D (3 planes of 8), and from the pixels' view-axis depths the distances along them
 * to the surfaces, into tmax (+inf stays +inf). */
static void camera_rays8(const camera_rays *cr, int32_t x0, int32_t y, const float *depth, float O[3][8],
                         float D[3][8], float *tmax)
{
    const nc_v8f zero = {0}, lane = {0, 1, 2, 3, 4, 5, 6, 7};
    nc_v8f nx = ((float)x0 + 0.5f + lane) * (float)cr->sx - 1.0f;
    float ny = (float)(1.0 - (y + 0.5) * cr->sy), nz = cr->ortho ? 0.0f : 1.0f;
    nc_v8f q[4];
    for (int r = 0; r < 4; r++)
        q[r] = (float)cr->inv_proj[r][0] * nx +
               (float)(cr->inv_proj[r][1] * ny + cr->inv_proj[r][2] * nz + cr->inv_proj[r][3]);
    nc_v8f ov[3] = {zero, zero, zero}, dv[3] = {zero, zero, zero - 1.0f}, t, z = nc_v8_load(depth);
    if (cr->ortho) {
        for (int k = 0; k < 3; k++)
            ov[k] = q[k] / q[3];
        t = z + ov[2];
    } else {
        nc_v8f len = nc_v8_sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
        nc_v8f inv = nc_v8_sel(q[3] < 0.0f, zero - 1.0f, zero + 1.0f) / len;
        for (int k = 0; k < 3; k++)
            dv[k] = q[k] * inv;
        t = z / -dv[2];
    }
    for (int r = 0; r < 3; r++) {
        const double *m = cr->cam_to_world[r];
        nc_v8_store(O[r], (float)m[0] * ov[0] + (float)m[1] * ov[1] + (float)m[2] * ov[2] + (float)m[3]);
        nc_v8_store(D[r], (float)m[0] * dv[0] + (float)m[1] * dv[1] + (float)m[2] * dv[2]);
    }
    nc_v8_store(tmax, nc_v8_sel(t > 0.0f, t, zero));
}

/* T and L along 8 rays (see the top of the file) at once, in float: every case of the closed forms
 * lane by lane (box, ellipsoid, level, capped, rising to infinity, diverging). Rays: origins O,
 * unit directions D (3 planes of 8), ends tmax (+inf over the background); tl: 6 floats per lane
 * (T rgb, L rgb). Float keeps the closed forms within a few 1e-7 relative of the double ones (the
 * height factor's exponential is nc_vol_exp_fast8's, the phase's power a refined reciprocal square
 * root). */
static void fog_pixels8(const fog_state *st, const float O[3][8], const float D[3][8], const float *tmax, float *tl)
{
    const nc_v8f zero = {0};
    nc_v8f o[3], d[3];
    for (int k = 0; k < 3; k++) {
        o[k] = nc_v8_load(O[k]);
        d[k] = nc_v8_load(D[k]);
    }
    nc_v8f tm = nc_v8_load(tmax);
    nc_v8f tau[3] = {zero, zero, zero}, acc[3] = {zero, zero, zero}, tau_inf[3] = {zero, zero, zero},
           acc_inf[3] = {zero, zero, zero};
    for (uint32_t i = 0; i < st->fog_count; i++) {
        const fog_const *f = &st->fogs[i];
        nc_v8f t0 = zero, t1 = tm;
        nc_v8i hit = zero == zero;
        if (f->box) {
            nc_v8f ol[3], dl[3];
            for (int k = 0; k < 3; k++) {
                const float *m = f->w2lf[k];
                ol[k] = m[0] * o[0] + m[1] * o[1] + m[2] * o[2] + m[3];
                dl[k] = m[0] * d[0] + m[1] * d[1] + m[2] * d[2];
            }
            if (f->ellipsoid) {
                nc_v8f A = zero, B = zero, C = zero - 1.0f;
                for (int k = 0; k < 3; k++) {
                    nc_v8f ok = ol[k] * f->inv_halff[k], dk = dl[k] * f->inv_halff[k];
                    A += dk * dk;
                    B += ok * dk;
                    C += ok * ok;
                }
                nc_v8f disc = B * B - A * C;
                hit = (A > 0.0f) & (disc > 0.0f);
                nc_v8f sq = nc_v8_sqrt(nc_v8_sel(hit, disc, zero));
                nc_v8f q = -(B + nc_v8_sel(B >= 0.0f, sq, -sq));
                nc_v8f Ah = nc_v8_sel(hit, A, zero + 1.0f), qh = nc_v8_sel(q != 0.0f, q, zero + 1.0f);
                nc_v8f r0 = q / Ah, r1 = nc_v8_sel(q != 0.0f, C / qh, -r0);
                nc_v8f lo = nc_v8_sel(r0 < r1, r0, r1), hi = nc_v8_sel(r0 < r1, r1, r0);
                t0 = nc_v8_sel(lo > t0, lo, t0);
                t1 = nc_v8_sel(hi < t1, hi, t1);
            } else {
                for (int k = 0; k < 3; k++) {
                    /* A direction of 0 along the axis: +-inf from outside the slab (a miss),
                     * -inf and +inf (or NaN, on its faces) from inside (no limit), as the
                     * scalar test answers. */
                    float h = f->halff[k];
                    nc_v8f ta = (-h - ol[k]) / dl[k], tb = (h - ol[k]) / dl[k];
                    nc_v8i swap = ta > tb;
                    nc_v8f lo = nc_v8_sel(swap, tb, ta), hi = nc_v8_sel(swap, ta, tb);
                    t0 = nc_v8_sel(lo > t0, lo, t0);
                    t1 = nc_v8_sel(hi < t1, hi, t1);
                }
            }
        }
        hit &= t1 > t0;
        if (!nc_v8_bits(hit))
            continue;
        nc_v8f G = nc_vol_height_integral8(&f->h8, o[1], d[1], t0, t1);
        hit &= G > 0.0f;
        if (!nc_v8_bits(hit))
            continue;
        G = nc_v8_sel(hit, G, zero);
        nc_v8f S[3] = {zero + (float)st->env[0], zero + (float)st->env[1], zero + (float)st->env[2]};
        float g = (float)f->g, pa = 1.0f + g * g, pb = -2.0f * g;
        float pc = (float)((1.0 - f->g * f->g) / (4.0 * 3.14159265358979323846));
        for (uint32_t l = 0; l < st->sun_count; l++) {
            const sun *sn = &st->suns[l];
            nc_v8f cs = -((float)sn->dir[0] * d[0] + (float)sn->dir[1] * d[1] + (float)sn->dir[2] * d[2]);
            nc_v8f p = nc_vol_hg_phase8(cs, zero + pa, zero + pb, zero + pc);
            for (int c = 0; c < 3; c++)
                S[c] += (float)sn->e[c] * p;
        }
        nc_v8i div = G == INFINITY, fin = hit & ~div;
        for (int c = 0; c < 3; c++) {
            float em = (float)f->emission[c], sg = (float)f->sigma_t[c], ss = (float)f->sigma_s[c];
            if (!(f->sigma_t[c] > 0.0)) {
                if (f->emission[c] > 0.0)
                    acc[c] += nc_v8_sel(fin, em * G, zero);
                continue;
            }
            nc_v8f src = ss * S[c] + em;
            tau_inf[c] += nc_v8_sel(div, zero + sg, zero);
            acc_inf[c] += nc_v8_sel(div, src, zero);
            tau[c] += nc_v8_sel(fin, sg * G, zero);
            acc[c] += nc_v8_sel(fin, src * G, zero);
        }
    }
    for (int c = 0; c < 3; c++) {
        nc_v8f T = nc_vol_transmittance8(tau[c]), ratio = nc_vol_exp_ratio8(tau[c], T);
        nc_v8i div = tau_inf[c] > 0.0f;
        nc_v8f Tc = nc_v8_sel(div, zero, T);
        nc_v8f Lc = nc_v8_sel(div, acc_inf[c] / nc_v8_sel(div, tau_inf[c], zero + 1.0f), acc[c] * ratio);
        for (int q = 0; q < 8; q++) {
            tl[6 * q + c] = Tc[q];
            tl[6 * q + 3 + c] = Lc[q];
        }
    }
}

static nacre_result fog_apply(void *state, const nc_post_input *in, nacre_image *image, nacre_render_stats *stats)
{
    fog_state *st = state;
    uint64_t t_start = nc_now_us();
    nacre_result res = fog_setup(st, in->ctx, in->scene);
    if (res != NACRE_OK)
        return res;
    st->fog_count = nc_post_fogs_drawn(in->scene, in->settings);
    int32_t w = image->width, h = image->height;
    const float *depth = in->depth;
    size_t n = (size_t)w * (size_t)h;
    fog_key key;
    memset(&key, 0, sizeof(key));
    key.uid = in->scene->uid;
    key.particles_built = in->scene->particles_built;
    key.versions = in->scene->committed;
    key.fog_count = st->fog_count;
    key.view = in->view->view;
    key.proj = in->view->proj;
    key.width = w;
    key.height = h;
    key.ortho = in->view->orthographic;
    bool same = st->valid && memcmp(&key, &st->key, sizeof(key)) == 0 && memcmp(depth, st->depth, n * sizeof(float)) == 0;
    if (!same) {
        st->valid = false;
        if (!nc_reserve(in->ctx, &st->tl, &st->tl_capacity, 6 * n, sizeof(float)) ||
            !nc_reserve(in->ctx, &st->depth, &st->depth_capacity, n, sizeof(float)))
            return NACRE_ERROR_OUT_OF_MEMORY;
        camera_rays cr;
        camera_setup(in->view, &cr);
        /* Rows in parallel; pixels are independent, so the image does not depend on the threads.
         * Applied as they are made (one pass over the image). */
#pragma omp parallel for schedule(static) num_threads(in->ctx->threads)
        for (int32_t y = 0; y < h; y++) {
            float *row = image->pixels + (size_t)y * image->stride;
            for (int32_t x0 = 0; x0 < w; x0 += 8) {
                /* 8 pixels (past the row's end, its last one again: computed, not stored) */
                float O[3][8], D[3][8], tmax[8], z[8], t8[48];
                int32_t n = w - x0 < 8 ? w - x0 : 8;
                for (int32_t q = 0; q < 8; q++)
                    z[q] = depth[(size_t)y * (size_t)w + (size_t)(x0 + (q < n ? q : n - 1))];
                camera_rays8(&cr, x0, y, z, O, D, tmax);
                fog_pixels8(st, O, D, tmax, t8);
                float *t = st->tl + 6 * ((size_t)y * (size_t)w + (size_t)x0);
                memcpy(t, t8, 6 * (size_t)n * sizeof(float));
                for (int32_t q = 0; q < n; q++)
                    for (int c = 0; c < 3; c++)
                        row[3 * (x0 + q) + c] = row[3 * (x0 + q) + c] * t[6 * q + c] + t[6 * q + 3 + c];
            }
        }
        memcpy(st->depth, depth, n * sizeof(float));
        st->key = key;
        st->valid = true;
    } else {
        const float *tl = st->tl;
#pragma omp parallel for schedule(static) num_threads(in->ctx->threads)
        for (int32_t y = 0; y < h; y++) {
            float *row = image->pixels + (size_t)y * image->stride;
            const float *t = tl + 6 * (size_t)y * (size_t)w;
            for (int32_t x = 0; x < w; x++)
                for (int c = 0; c < 3; c++)
                    row[3 * x + c] = row[3 * x + c] * t[6 * x + c] + t[6 * x + 3 + c];
        }
    }
    stats->fog_lights_ignored = in->scene->light_count - st->sun_count;
    stats->fog_patterns_averaged = 0;
    for (uint32_t i = 0; i < st->fog_count; i++)
        stats->fog_patterns_averaged += nc_medium_heterogeneous(&in->scene->fogs[i].medium);
    stats->stage_us[NACRE_STAGE_FOG] += nc_now_us() - t_start;
    stats->stage_ran[NACRE_STAGE_FOG] = true;
    stats->stage_runs[NACRE_STAGE_FOG] = 1;
    return NACRE_OK;
}

const nc_post_pass nc_post_fog = {
    .name = "fog",
    .wanted = fog_wanted,
    .create = fog_create,
    .apply = fog_apply,
    .destroy = fog_destroy,
};
