/*
 * slab.c: Monte Carlo measurement of light transport through an analytic plane-parallel slab
 * (nacre_slab_measure with NACRE_METHOD_PATHTRACE), the ground truth the diffusion solver and
 * the scene path tracer are checked against. The method is the classical photon random walk of
 * Prahl et al. 1989 / Wang, Jacques, Zheng 1995 (MCML) reduced to one dimension: in a
 * plane-parallel slab only the depth z and the direction cosine mu to the inward normal matter.
 *
 * Units: optical depth (sigma_t = 1), so free paths are Exp(1) and the slab is [0, tau]. Light
 * arrives at z = 0 with unit power, refracted to the direction cosine mu_t (1 at normal
 * incidence). Boundaries are smooth dielectrics of
 * relative index eta against air on both sides; a path meeting one reflects with the Fresnel
 * probability, otherwise leaves (no radiance scaling is needed: we count power, not radiance).
 *
 * Variance reduction, all unbiased:
 *   - the specular reflection at the top is removed analytically (R_specular);
 *   - the unscattered light, including its bounces between the two faces (at mu_t),
 *     is scored analytically, and the first collision is forced inside the slab (on a leg of the
 *     ballistic zig-zag chosen by its share of the collision probability), so a pure absorber
 *     has T = exp(-tau) exactly and zero variance;
 *   - absorption by weight (w *= albedo per scattering) with Russian roulette below 5% of the
 *     entering weight.
 * A path scores its final weight once, to R or to T, so the standard error of each is that of
 * an i.i.d. mean over the paths.
 *
 * Determinism: paths are cut into fixed chunks of CHUNK; chunk c uses PCG32 stream c of the
 * seed, and the chunk sums are added in chunk order, so results do not depend on threads.
 * max_scatter K > 0 drops a path at its (K+1)-th collision (K = 1: single scattering only).
 * Semi-infinite, non-absorbing slabs make walks with an infinite mean length; a walk is cut at
 * MAX_COLLISIONS collisions and scores nothing, which biases R down
 * by about 1/sqrt(MAX_COLLISIONS) (1e-3) only there (such paths are counted in paths_capped).
 * A thin slab of high index traps light by total internal reflection: a flight of optical length
 * s crosses it s |mu| / tau times. After FOLD_AFTER reflections in one flight the rest of it is
 * folded in closed form: the number of faces it reaches, the first one it leaves by (geometric in
 * the Fresnel reflectance, which is the same at every face) or its end point reflected back into
 * the slab; same distribution, constant cost.
 *
 * Time limit: the clock is read before each chunk and every DEADLINE_STRIDE collisions; a path in
 * flight at the deadline is dropped and R, T are means over the completed paths (samples_done).
 */
#include "core/optics.h"
#include "pathtrace/pathtrace.h"
#include "pathtrace/rng.h"

#include <math.h>
#include <string.h>

enum { CHUNK = 1024 };
#define MAX_COLLISIONS (1u << 20)
#define FOLD_AFTER 1
#define DEADLINE_STRIDE 4096u
#define RR_THRESHOLD 0.05
#define RR_SURVIVE 0.2
#define TWO_PI 6.283185307179586

typedef struct slab_sums {
    double r, r2, t, t2;
    uint64_t done, capped;
} slab_sums;

typedef struct slab_setup {
    double albedo, tau, g, eta_out; /* eta_out: relative index seen from inside, 1 / eta */
    double ext;                     /* exp(-tau / mu_t): one ballistic crossing */
    double mu_t;                    /* direction cosine of the refracted incident light */
    double f0;                      /* Fresnel of the incident light, outside at the incidence
                                       angle or inside at mu_t (the same by reciprocity) */
    double w_collide;               /* weight of the forced first collision */
    uint32_t max_scatter;
    bool index_matched;
    uint64_t deadline_us;           /* 0: none */
} slab_setup;

/* Fresnel reflection probability for a path meeting a face at direction cosine |mu|. */
static double face_reflectance(const slab_setup *s, double mu)
{
    return s->index_matched ? 0.0 : nc_fresnel_dielectric(fabs(mu), s->eta_out);
}

/* Scores weight w leaving by the bottom (T) or the top (R). */
static void score(slab_sums *sum, bool bottom, double w)
{
    if (bottom) {
        sum->t += w;
        sum->t2 += w * w;
    } else {
        sum->r += w;
        sum->r2 += w * w;
    }
}

/* The rest of a free flight of optical length `len` from depth *z with direction cosine *mu
 * (not 0) in a finite slab, faces reflecting with probability F at every hit (see the top):
 * true if the path leaves (scored), else *z and *mu at its end. */
static bool fold_flight(const slab_setup *s, nc_rng *rng, double len, double *z, double *mu, double w, slab_sums *sum)
{
    double m = fabs(*mu), travel = len * m;
    double first = *mu > 0 ? s->tau - *z : *z; /* distance to the face ahead */
    if (travel < first) {
        *z += len * *mu;
        return false;
    }
    double hits = 1.0 + floor((travel - first) / s->tau); /* faces reached */
    double F = face_reflectance(s, m), u = nc_rng_double(rng);
    double leave = F >= 1.0 ? INFINITY : F <= 0.0 ? 1.0 : 1.0 + floor(log(1.0 - u) / log(F));
    bool first_bottom = *mu > 0;
    if (leave <= hits) {
        bool odd = fmod(leave, 2.0) == 1.0;
        score(sum, odd ? first_bottom : !first_bottom, w);
        return true;
    }
    double rest = fmod(travel - first, s->tau);
    bool bottom = fmod(hits, 2.0) == 1.0 ? first_bottom : !first_bottom;
    *z = bottom ? s->tau - rest : rest;
    *mu = bottom ? -m : m;
    return false;
}

enum { PATH_DONE = 0, PATH_CAPPED, PATH_EXPIRED };

/* One path from its forced first collision to its exit; adds its score to `sum`. *until_check
 * counts collisions down to the next clock read (shared by the paths of a chunk). */
static int trace_path(const slab_setup *s, nc_rng *rng, slab_sums *sum, uint32_t *until_check)
{
    double q = s->f0 * s->ext; /* ratio of collision weight between successive ballistic legs */
    unsigned leg = 0;
    while (q > 0 && nc_rng_double(rng) < q && leg < 4096)
        leg++;
    double mu = (leg & 1) ? -s->mu_t : s->mu_t;
    double d = -log(1.0 - nc_rng_double(rng) * (1.0 - s->ext)) * s->mu_t; /* depth travelled */
    double z = (leg & 1) ? s->tau - d : d;
    double w = s->w_collide;
    uint32_t scatters = 0, events = 0;
    for (;;) {
        /* At a collision. */
        if (++events > MAX_COLLISIONS)
            return PATH_CAPPED;
        if (s->deadline_us && --*until_check == 0) {
            *until_check = DEADLINE_STRIDE;
            if (nc_now_us() >= s->deadline_us)
                return PATH_EXPIRED;
        }
        if (s->max_scatter && ++scatters > s->max_scatter)
            return PATH_DONE;
        w *= s->albedo;
        if (w <= 0)
            return PATH_DONE;
        if (w < RR_THRESHOLD * s->w_collide) {
            if (nc_rng_double(rng) >= RR_SURVIVE)
                return PATH_DONE;
            w /= RR_SURVIVE;
        }
        double c = nc_hg_sample_cos(s->g, nc_rng_double(rng));
        double sin_t = sqrt(fmax(0.0, 1.0 - c * c));
        double sin_mu = sqrt(fmax(0.0, 1.0 - mu * mu));
        mu = mu * c + sin_mu * sin_t * cos(TWO_PI * nc_rng_double(rng));
        mu = fmin(1.0, fmax(-1.0, mu));
        /* Free flight, with any number of Fresnel reflections at the faces. */
        for (uint32_t hits = 0;; hits++) {
            double len = -log(1.0 - nc_rng_double(rng));
            if (hits >= FOLD_AFTER && mu != 0 && isfinite(s->tau)) {
                if (fold_flight(s, rng, len, &z, &mu, w, sum))
                    return PATH_DONE;
                break;
            }
            double znew = z + len * mu;
            if (mu > 0 && znew > s->tau) {
                if (nc_rng_double(rng) < face_reflectance(s, mu)) {
                    /* The rest of the exponential flight continues after the mirror (memoryless). */
                    z = s->tau;
                    mu = -mu;
                    continue;
                }
                score(sum, true, w);
                return PATH_DONE;
            }
            if (mu < 0 && znew < 0) {
                if (nc_rng_double(rng) < face_reflectance(s, mu)) {
                    z = 0;
                    mu = -mu;
                    continue;
                }
                score(sum, false, w);
                return PATH_DONE;
            }
            z = znew;
            break;
        }
    }
}

nacre_result nc_slab_pathtrace(nacre_context *ctx, const nacre_slab_desc *desc, nacre_slab_result *out)
{
    if (!ctx || !desc || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!(desc->albedo >= 0 && desc->albedo <= 1))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "slab: albedo: must be in [0, 1]");
    if (!(desc->tau >= 0)) /* INFINITY passes: semi-infinite */
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "slab: tau: must be >= 0 (INFINITY: semi-infinite)");
    if (!(desc->g > -1 && desc->g < 1))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "slab: g: must be in (-1, 1)");
    if (!(desc->eta > 0 && isfinite(desc->eta)))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "slab: eta: must be finite and > 0");
    if (desc->samples < 2)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "slab: samples: need at least 2 paths");
    if (!(desc->time_limit >= 0) || !isfinite(desc->time_limit))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "slab: time_limit: must be finite and >= 0");
    uint64_t t0 = nc_now_us();

    slab_setup s;
    memset(&s, 0, sizeof(s));
    s.albedo = desc->albedo;
    s.tau = desc->tau;
    s.g = desc->g;
    s.eta_out = 1.0 / desc->eta;
    s.index_matched = desc->eta == 1.0;
    s.max_scatter = desc->max_scatter;
    s.deadline_us = desc->time_limit > 0 ? t0 + (uint64_t)(desc->time_limit * 1e6) : 0;
    double cos_i = cos(desc->incidence * 0.017453292519943295), sin_i = sqrt(fmax(0.0, 1.0 - cos_i * cos_i));
    s.mu_t = sqrt(fmax(0.0, 1.0 - sin_i * sin_i / (desc->eta * desc->eta)));
    s.ext = exp(-desc->tau / s.mu_t);
    s.f0 = s.index_matched ? 0.0 : nc_fresnel_dielectric(cos_i, desc->eta);
    /* Ballistic light: enters with 1 - F0, then zig-zags at mu_t, each leg losing exp(-tau / mu_t)
     * to collisions and each face letting 1 - F0 out. */
    double w0 = 1.0 - s.f0, e = s.ext, f = s.f0;
    double zigzag = 1.0 - f * f * e * e;
    double t_ball = w0 * e * (1.0 - f) / zigzag;
    double r_ball = w0 * e * e * f * (1.0 - f) / zigzag;
    s.w_collide = w0 * (1.0 - e) / (1.0 - f * e);

    uint64_t n = desc->samples;
    uint64_t chunks = (n + CHUNK - 1) / CHUNK;
    slab_sums *sums = nc_calloc(ctx, (size_t)chunks, sizeof(*sums));
    if (!sums)
        return NACRE_ERROR_OUT_OF_MEMORY;
    if (s.w_collide > 0 && s.albedo > 0) {
#pragma omp parallel for schedule(dynamic, 1) num_threads(nc_threads(ctx))
        for (int64_t c = 0; c < (int64_t)chunks; c++) {
            nc_rng rng = nc_rng_make(desc->seed, (uint64_t)c);
            uint64_t begin = (uint64_t)c * CHUNK, end = begin + CHUNK < n ? begin + CHUNK : n;
            slab_sums acc = {0, 0, 0, 0, 0, 0};
            uint32_t until_check = DEADLINE_STRIDE;
            bool late = s.deadline_us && nc_now_us() >= s.deadline_us;
            for (uint64_t i = begin; i < end && !late; i++) {
                slab_sums one = {0, 0, 0, 0, 0, 0};
                int st = trace_path(&s, &rng, &one, &until_check);
                if (st == PATH_EXPIRED)
                    break; /* dropped: it did not finish */
                acc.r += one.r;
                acc.r2 += one.r2;
                acc.t += one.t;
                acc.t2 += one.t2;
                acc.done++;
                acc.capped += st == PATH_CAPPED;
            }
            sums[c] = acc;
        }
    } else {
        sums[0].done = n; /* nothing to trace: all light is ballistic */
    }
    slab_sums tot = {0, 0, 0, 0, 0, 0};
    for (uint64_t c = 0; c < chunks; c++) {
        tot.r += sums[c].r;
        tot.r2 += sums[c].r2;
        tot.t += sums[c].t;
        tot.t2 += sums[c].t2;
        tot.done += sums[c].done;
        tot.capped += sums[c].capped;
    }
    nc_free(ctx, sums);
    if (tot.done < 2)
        return nc_fail(ctx, NACRE_ERROR_INVALID_OPERATION,
                       "slab: the time limit ended the run before 2 paths were complete");

    double dn = (double)tot.done;
    double mr = tot.r / dn, mt = tot.t / dn;
    memset(out, 0, sizeof(*out));
    out->R = r_ball + mr;
    out->T = t_ball + mt;
    out->R_stderr = sqrt(fmax(0.0, tot.r2 / dn - mr * mr) / (dn - 1.0));
    out->T_stderr = sqrt(fmax(0.0, tot.t2 / dn - mt * mt) / (dn - 1.0));
    out->R_specular = s.f0;
    out->samples_done = tot.done;
    out->paths_capped = tot.capped;
    out->ms = (double)(nc_now_us() - t0) * 1e-3;
    return NACRE_OK;
}
