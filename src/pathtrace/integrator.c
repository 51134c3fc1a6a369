/*
 * integrator.c: the reference volumetric path tracer of `--method pathtrace`: unidirectional path
 * tracing (Kajiya 1986) with next-event estimation and multiple importance sampling (Veach and
 * Guibas 1995, power heuristic) over the committed scene, Embree 3 for ray-triangle queries.
 * This file holds the path loop (trace_path), the camera, the render passes with their time
 * limit and per-pixel accumulation, and the module's entry points (pathtrace.h). The rest of the
 * path tracer, one concept per file, shares the private types of pt_internal.h:
 * - media.c: free flights (spectral MIS, spectral tracking), ratio tracking, majorants, fog;
 * - surfaces.c: the opaque BSDF (the dielectric and index-matched boundaries are path events,
 *   handled in trace_path below);
 * - lights.c: light sampling, shadow rays, NEE and the MIS weights of lights hit by chance;
 * - sun_guide.c: sampling the sun through a dielectric boundary;
 * - scene_setup.c: the Embree scene and the per-object grids (majorant, layer, rest-pose,
 *   clearance, triangle adjacency).
 * Units: scene units for lengths, coefficients per scene unit; RGB radiometry as in phong.c.
 *
 * Non-symmetric transport: a camera path refracting from index n1 into n2 carries radiance that
 * was scaled by (n1 / n2)^2 when the light crossed the other way, so throughput gets (n1 / n2)^2
 * (Veach 1997, ch. 5); Russian roulette uses the throughput without that factor.
 *
 * Russian roulette (after RR_START vertices) survives with probability min(1, throughput), with
 * no cap below 1: in a nearly white medium (marble: albedo 0.998) a cap of 0.95 cut walks after
 * ~20 of their hundreds of vertices and the survivors' 1/0.95^k weights reached ~100, a heavy
 * tail that dominated the demo's error (2.5x the variance per sample, growing with spp).
 * Paths run longer instead, and the per-vertex cost is kept down by:
 * - clearance grids (see nc_pt_clearance() in scene_setup.c): a free flight shorter than a
 *   conservative bound on the distance to any surface skips the Embree query (same result bit
 *   for bit); the bound is extended by the clearance at the point it reaches, a few times,
 *   before asking;
 * - NEE (index-matched media) runs with a probability that falls with that bound
 *   (guide_probability), guided sun sampling (dielectric media) with one that falls with the
 *   optical depth of the way out along the guide axis (sun_guide_probability), each weighted by
 *   its inverse and MIS-combined with the expected density; the guide axis is found by a walk
 *   over the mesh from the previous vertex's facet, without a query in most cases (nc_pt_walk_guide,
 *   nc_pt_make_guide), and evaluated lazily for the MIS weight of phase-sampled paths (needed only when
 *   one refracts out into the sun).
 *
 * Determinism: each pixel of each pass has its own PCG32 stream (seed, pass, pixel); per-pixel
 * mean and M2 (Welford) are updated in pass order, so images do not depend on threads.
 * Time limit and caps (README, "Caps and the time limit"): the deadline is checked before each
 * sample and within paths (pt_budget); a sample in flight at the deadline is dropped, so each
 * pixel is the mean of the samples it completed - the pixel an unlimited render with that many
 * samples would give, bit for bit. Paths end at MAX_VERTICES vertices or MAX_PATH_COLLISIONS
 * units of tracking work, keeping what they gathered (counted in stats->paths_capped).
 *
 * Accumulation (progressive rendering for a viewer): the state keeps the per-pixel mean, M2 and
 * count between frames. An accumulating frame whose scene (uid), committed versions, size, seed
 * and max_scatter equal those of the state's last completed frame adds spp more samples to each
 * pixel instead of starting over; anything else (an edit of any kind, including the camera)
 * restarts from zero. A pixel's next sample is always pass count[pixel] of its stream, so the
 * random sequence continues rather than repeats and the update order is the one of a single
 * longer frame: frames of 4 + 4 spp give the image and variance of one frame of 8, bit for bit,
 * and pixels a time limit left behind catch up from their own count. What the scene setup builds
 * (Embree scene, grids) does not depend on the camera and is kept while only the camera changes
 * (nc_pt_prepare_scene), accumulating or not.
 *
 * Not handled: nested or overlapping translucent objects (a path is in air or in one object), the phong specular lobe on translucent
 * objects (their specular is the Fresnel reflection), double_sided (surfaces are shaded from the
 * side the path arrives on either way; there is no culling), cast_shadows = false on translucent
 * objects (their boundary still blocks NEE: letting shadow rays through would skip the light that
 * refracts through them) and on lights (a light's shadow rays cross media, whose attenuation is
 * not a shadow to be switched off; what a non-casting light should do there is undefined).
 *
 * cast_shadows = false on an opaque object makes it transparent to shadow rays (NEE, and the
 * guided sun's ray after leaving a dielectric). Paths still hit it, so NEE and BSDF/phase
 * sampling would see different worlds and their MIS combination would mix them; with any such
 * object in the scene, direct light comes from NEE alone (lights reached by a sampled direction
 * after a non-specular vertex score 0; guided sun samples take their whole cone). Exact for the
 * modified transport, but noisier on glossy highlights.
 */
#include "pathtrace/pt_internal.h"

#include <string.h>

nc_pathtrace_options nc_pathtrace_options_defaults(void)
{
    nc_pathtrace_options o;
    memset(&o, 0, sizeof(o));
    o.majorant_res = 16;
    return o;
}

#ifndef NACRE_HAVE_EMBREE

struct nc_pathtracer {
    int unused;
};

bool nc_pathtrace_available(void) { return false; }

nacre_result nc_pathtracer_create(nacre_context *ctx, const nc_pathtrace_options *options, nc_pathtracer **out)
{
    (void)options, (void)out;
    return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "pathtrace: built without Embree (install libembree-dev)");
}

nacre_result nc_pathtrace_render(nc_pathtracer **state, nacre_context *ctx, const nacre_scene *scene,
                                 const nacre_render_settings *settings, bool accumulate, nacre_image *out,
                                 nacre_render_stats *stats)
{
    (void)state, (void)scene, (void)settings, (void)accumulate, (void)out, (void)stats;
    return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "render: method 'pathtrace' needs Embree (libembree-dev)");
}

uint32_t nc_pathtrace_passes(const nc_pathtracer *state) { return (void)state, 0; }
uint64_t nc_pathtrace_samples(const nc_pathtracer *state) { return (void)state, 0; }
uint32_t nc_pathtrace_frames(const nc_pathtracer *state) { return (void)state, 0; }

nacre_result nc_pathtrace_variance(const nc_pathtracer *state, nacre_context *ctx, nacre_image *out)
{
    (void)state, (void)out;
    return nc_fail(ctx, NACRE_ERROR_INVALID_OPERATION, "variance: the last frame was not path traced");
}

void nc_pathtracer_destroy(nacre_context *ctx, nc_pathtracer *state) { (void)ctx, (void)state; }

#else /* NACRE_HAVE_EMBREE */

/* The equiangular technique on fog segment e (pt_internal.h, "Equiangular sampling"): for each
 * point or spot light, one distance t with density proportional to 1 / (D^2 + (t - delta)^2) on
 * [a, b] (the inverse of Kulla and Fajardo's eq. 6), the fog there, the transmittance from the
 * segment's origin by ratio tracking (the fog is heterogeneous in general), and NEE towards that
 * light; weighted by the balance heuristic against the distance technique's vertices, whose NEE
 * and phase-sampled hits of these lights carry the complementary weight (eq_weight_d). Single
 * scattering from a point light in fog is concentrated near the light, where distance sampling
 * rarely puts a vertex and NEE's 1 / d^2 then makes fireflies (issue 28). beta: the path's
 * throughput at the segment's origin. */
static nc_vec3 equiangular(const pt_scene *ps, const pt_eq *e, nc_vec3 beta, nc_rng *rng)
{
    const nc_pathtracer *pt = ps->pt;
    nc_vec3 L = nc_v3(0, 0, 0);
    for (uint32_t li = 0; li < pt->light_count; li++) {
        const pt_light *l = &pt->lights[li];
        float delta, D, ta, tb;
        if (l->type == NACRE_LIGHT_DIRECTIONAL || !eq_frame(l, e, &delta, &D, &ta, &tb))
            continue;
        float t = delta + D * tanf(ta + nc_rng_float(rng) * (tb - ta));
        t = fminf(fmaxf(t, e->a), e->b);
        float pe = eq_pdf(l, e, t);
        if (!(pe > 0.0f))
            continue;
        float sa[3], ss[3];
        nc_vec3 bw = beta;
        float g = nc_pt_fog_point(ps, e->o, e->d, e->tmax, t, sa, ss, &bw, rng);
        if (!(ss[0] > 0.0f || ss[1] > 0.0f || ss[2] > 0.0f))
            continue;
        nc_vec3 tr = nc_pt_transmittance(ps, NULL, e->o, e->d, t, rng);
        if (tr.x == 0 && tr.y == 0 && tr.z == 0)
            continue;
        nc_vec3 ld = nc_pt_direct_one(ps, li, ray_at(e->o, e->d, t), e->d, g, rng);
        float w = pe / (pe + eq_pd(sa, ss, t - e->a));
        L = nc_add(L, nc_scale(nc_mul(nc_mul(bw, tr), nc_mul(nc_v3(ss[0], ss[1], ss[2]), ld)), w / pe));
    }
    return L;
}

/* The radiance arriving at o from direction -d along one camera path. Longer than 150 lines on
 * purpose: the loop's events (free flight, medium vertex with NEE or the guided sun, light hit,
 * escape, index-matched and dielectric boundaries, opaque vertex, roulette) read and update about
 * twenty pieces of shared path state (throughput, MIS history, guide cache, medium, seed facet)
 * that a split would pass around in a struct; as one loop, the order of events and what each
 * changes read top to bottom. The pieces with no path state of their own are functions of
 * their concept's file (media.c, lights.c, sun_guide.c, surfaces.c). */
static nc_vec3 trace_path(const pt_scene *ps, nc_vec3 o, nc_vec3 d, nc_rng *rng)
{
    const nc_pathtracer *pt = ps->pt;
    nc_vec3 L = nc_v3(0, 0, 0), beta = nc_v3(1, 1, 1);
    float eta_scale = 1.0f; /* undoes the (n1/n2)^2 radiance factors for Russian roulette */
    int medium = -1;
    bool prev_delta = true;
    float prev_pdf = 0;
    float prev_q = 1.0f; /* probability that NEE ran at the previous vertex */
    nc_vec3 prev_p = o;
    uint32_t scatters = 0;
    /* Guided sun sampling (see guided_sun): the light, and the state of the phase-sampled
     * continuation: 0 none, 1 flying from a guided medium vertex, 2 refracted out since. */
    int sun = -1;
    for (uint32_t li = 0; li < pt->light_count && sun < 0; li++)
        if (pt->lights[li].type == NACRE_LIGHT_DIRECTIONAL && !pt->lights[li].delta)
            sun = (int)li;
    int direct = 0;
    guide guide_cached = {false, {0, 0, 0}, 1, 0, 1, 0};
    bool guide_known = false;
    nc_vec3 guide_vertex = o, guide_dir = d;
    uint32_t guide_obj = 0;
    float guide_q = 1.0f;
    uint32_t seed = UINT32_MAX, guide_seed = UINT32_MAX; /* see nc_pt_make_guide */
    int seed_obj = -1;
    float clear_here = -1.0f; /* clearance of o when o is a scattering vertex that looked it up */
    /* Equiangular sampling of fog segments (see equiangular()): this segment's, and the one of
     * the previous vertex when it was a fog vertex (for the MIS weight of a light it hits). */
    bool eq_lights = false;
    for (uint32_t li = 0; li < pt->light_count; li++)
        eq_lights |= pt->lights[li].type != NACRE_LIGHT_DIRECTIONAL;
    eq_lights &= pt->fog_count > 0;
    pt_eq eq, prev_eq;
    memset(&eq, 0, sizeof(eq));
    memset(&prev_eq, 0, sizeof(prev_eq));
    for (int vertex = 0, crossings = 0;;) {
        if (vertex >= MAX_VERTICES || crossings >= 4 * MAX_VERTICES) {
            ps->budget->capped = true;
            break;
        }
        if (!budget_tick(ps->budget))
            break;
        /* In a medium the flight is sampled first: when it ends short of the clearance bound no
         * surface can intervene and the boundary query is skipped. Heterogeneous media track up
         * to the bound, then (memoryless) on from there. */
        const pt_object *mo = medium >= 0 ? &pt->objects[medium] : NULL;
        ff_event ev = FF_PASS;
        float ts = 0, t_hom = 0, g = mo ? mo->g : 0.0f;
        bool query = true;
        if (mo) {
            /* A scattering vertex looked its clearance up already (for the guide). */
            float clear = clear_here >= 0.0f ? clear_here : nc_pt_clearance(mo, o);
            if (!mo->heterogeneous) {
                if (!flight_sample_homogeneous(mo, beta, rng, &t_hom))
                    break;
                /* Past the first bound, the clearance at the point reached extends it (sphere
                 * tracing along the flight): still a bound, so still bit for bit. */
                for (int k = 0; k < CLEAR_STEPS && clear > 0.0f && t_hom >= clear; k++) {
                    float more = nc_pt_clearance(mo, ray_at(o, d, clear));
                    if (!(more > 0.0f))
                        break;
                    clear += more;
                }
                if (t_hom < clear) {
                    ev = nc_pt_flight_resolve_homogeneous(mo, t_hom, INFINITY, &beta, &ts);
                    query = false;
                }
            } else if (clear > 0) {
                ev = nc_pt_free_flight(ps, mo, o, d, clear, rng, &beta, &ts, &g, NULL);
                if (ev == FF_PASS)
                    o = ray_at(o, d, clear);
                else
                    query = false;
            }
        }
        clear_here = -1.0f;
        eq.on = false;
        pt_hit h;
        memset(&h, 0, sizeof(h));
        float t_end = INFINITY;
        int light_hit = -1;
        if (query) {
                        h = intersect(ps, o, d, INFINITY);
            t_end = h.hit ? h.t : INFINITY;
            for (uint32_t li = 0; li < pt->light_count; li++) {
                const pt_light *l = &pt->lights[li];
                if (l->type == NACRE_LIGHT_DIRECTIONAL || l->delta)
                    continue;
                float tl = sphere_hit(l, o, d);
                if (tl < t_end) {
                    t_end = tl;
                    light_hit = (int)li;
                }
            }
            float tmax = isfinite(t_end) ? t_end : 1e30f;
            if (mo)
                ev = mo->heterogeneous ? nc_pt_free_flight(ps, mo, o, d, tmax, rng, &beta, &ts, &g, NULL)
                                       : nc_pt_flight_resolve_homogeneous(mo, t_hom, tmax, &beta, &ts);
            else if (pt->fog_count) {
                if (eq_lights && !(ps->max_scatter && scatters + 1 > ps->max_scatter) &&
                    nc_pt_fog_span(ps, o, d, tmax, &eq.a, &eq.b)) {
                    eq.on = true;
                    eq.o = o;
                    eq.d = d;
                    eq.tmax = tmax;
                    L = nc_add(L, equiangular(ps, &eq, beta, rng));
                }
                /* Fog emission along this flight: order `scatters` (seen directly: 0), kept
                 * under --max-scatter k for flights after at most k scatterings. */
                nc_vec3 emitted = nc_v3(0, 0, 0);
                ev = nc_pt_free_flight(ps, NULL, o, d, tmax, rng, &beta, &ts, &g, &emitted);
                L = nc_add(L, emitted);
            }
        }
        if (ev == FF_ABSORB)
            break;
        if (ev == FF_SCATTER) {
            nc_vec3 p = ray_at(o, d, ts);
            if (ps->max_scatter && ++scatters > ps->max_scatter)
                break;
            const pt_object *ob = mo; /* NULL: a fog vertex */
            nc_vec3 wo = nc_scale(d, -1.0f);
            /* Inside a closed dielectric every shadow ray ends on its boundary: no NEE, but the
             * sun can be sampled through the boundary. */
            guide gd = {false, {0, 0, 0}, 1, 0, 1, 0};
            float clear_p = -1.0f;
            bool guiding = false;
            float q = 1.0f;
            if (!ob) {
                /* Fog: plain NEE (no clearance grid in the open), MIS-weighted against the
                 * equiangular technique for point and spot lights. */
                if (eq.on) {
                    float sa[3], ss[3];
                    nc_pt_fog_point(ps, eq.o, eq.d, eq.tmax, ts, sa, ss, NULL, rng);
                    eq.t = ts;
                    eq.pd = eq_pd(sa, ss, ts - eq.a);
                }
                L = nc_add(L, nc_mul(beta, nc_pt_direct_light(ps, p, wo, false, NULL, wo, wo, g, -1, 1.0f, &eq, rng)));
            } else if (ob->kind == PT_MATCHED) {
                /* NEE attenuated by at least the clearance: run it less often deep inside, as
                 * the guided technique (guide_probability has the same argument). */
                clear_p = fmaxf(0.0f, nc_pt_clearance(ob, p));
                q = guide_probability(ob, clear_p);
                if (q >= 1.0f || nc_rng_float(rng) < q)
                    L = nc_add(L, nc_mul(beta, nc_pt_direct_light(ps, p, wo, false, NULL, wo, wo, g, medium, q, NULL, rng)));
            } else if (sun >= 0 && !pt->opt.no_sun_guiding) {
                guiding = true;
                clear_p = fmaxf(0.0f, nc_pt_clearance(ob, p));
                seed = seed_obj == medium ? seed : UINT32_MAX;
                guide_seed = seed;
                /* The walk is needed for q only where the clearance alone does not already put
                 * q at its floor (the walk can only lower it): deep vertices skip it unless the
                 * guide is made. */
                const pt_light *sl = &pt->lights[sun];
                float q_clear = pt->opt.guide_always ? 1.0f : sun_guide_probability(ob, clear_p, NULL);
                bool walked = q_clear > SUN_Q_MIN;
                guide_walk gw = {UINT32_MAX, sl->to_light, false, 0.0f};
                if (walked)
                    gw = nc_pt_walk_guide(ob, sl, p, seed);
                q = walked && !pt->opt.guide_always ? sun_guide_probability(ob, clear_p, &gw) : q_clear;
                if (q >= 1.0f || nc_rng_float(rng) < q) {
                    if (!walked)
                        gw = nc_pt_walk_guide(ob, sl, p, seed);
                    uint32_t last;
                    gd = nc_pt_make_guide(ps, (uint32_t)medium, sl, p, &gw, &last);
                    /* The next vertex's seed (a failed guide leaves the old one, usually near). */
                    if (last != UINT32_MAX) {
                        seed = last;
                        seed_obj = medium;
                    }
                    if (gd.valid)
                        L = nc_add(L, nc_mul(beta, guided_sun(ps, (uint32_t)medium, sl, &gd, q, p, d, g, rng)));
                    guide_known = true;
                } else {
                    guide_known = false;
                    /* The walk's facet seeds the next vertex's walk, which then stays short. */
                    if (gw.done) {
                        seed = gw.prim;
                        seed_obj = medium;
                    }
                }
            }
            float c = (float)nc_hg_sample_cos(g, nc_rng_float(rng));
            nc_vec3 wi = nc_pt_around(d, c, nc_rng_float(rng));
            prev_pdf = (float)nc_hg_phase(c, g);
            prev_q = ob && ob->kind == PT_MATCHED ? q : 1.0f;
            /* The MIS weight against the guided technique is needed only if this direction
             * refracts straight out into the sun (rare): the guide is then made if it was not. */
            direct = guiding ? 1 : 0;
            if (guiding) {
                guide_vertex = p;
                guide_dir = wi;
                guide_obj = (uint32_t)medium;
                guide_q = q;
                guide_cached = gd;
            }
            prev_delta = false;
            prev_p = p;
            prev_eq = eq;
            o = p;
            d = wi;
            clear_here = clear_p;
            vertex++;
            goto roulette;
        }
        if (light_hit >= 0) {
            const pt_light *l = &pt->lights[light_hit];
            nc_vec3 hp = ray_at(o, d, t_end);
            float fall = spot_falloff(l->desc, nc_normalize(nc_sub(hp, l->pos)));
            float w = 1.0f, cos_max;
            if (!prev_delta) {
                float lp = sphere_pdf(l, prev_p, &cos_max);
                w = pt->nee_only ? 0.0f : power_heuristic(prev_pdf, prev_q * lp) * eq_weight_d(l, &prev_eq);
            }
            L = nc_add(L, nc_mul(beta, nc_scale(l->value, fall * w)));
            break;
        }
        if (!h.hit) {
            if (medium < 0) {
                float gw = 1.0f;
                int gl = -1;
                if (direct == 2 && nc_dot(d, pt->lights[sun].to_light) >= pt->lights[sun].cos_max) {
                    uint32_t unused;
                    if (!guide_known) {
                        guide_walk gw = nc_pt_walk_guide(&pt->objects[guide_obj], &pt->lights[sun], guide_vertex, guide_seed);
                        guide_cached = nc_pt_make_guide(ps, guide_obj, &pt->lights[sun], guide_vertex, &gw, &unused);
                    }
                    float gp = guide_pdf(&guide_cached, guide_dir);
                    gw = !(gp > 0) ? 1.0f : pt->nee_only ? 0.0f : power_heuristic(prev_pdf, guide_q * gp);
                    gl = sun;
                }
                L = nc_add(L, nc_mul(beta, escaped(ps, d, prev_delta, prev_pdf, prev_q, gl, gw)));
            }
            break;
        }
        {
            const pt_object *ob = &pt->objects[h.obj];
            nc_vec3 p, ng, ns;
            nc_pt_surface_at(ob, &h, &p, &ng, &ns);
            bool entering = nc_dot(d, ng) < 0;
            if (ob->kind == PT_MATCHED) {
                /* Not a vertex: the path only changes medium. */
                medium = entering ? (int)h.obj : -1;
                o = offset_origin(ps, p, ng, d);
                crossings++;
                continue;
            }
            if (ob->kind == PT_DIELECTRIC) {
                nc_vec3 n = entering ? ng : nc_scale(ng, -1.0f); /* on the incident side */
                float eta = entering ? ob->eta : 1.0f / ob->eta;  /* n_transmitted / n_incident */
                float cos_i = -nc_dot(d, n);
                float F = (float)nc_fresnel_dielectric(cos_i, eta);
                float dv[3] = {d.x, d.y, d.z}, nv[3] = {n.x, n.y, n.z}, tv[3];
                if (nc_rng_float(rng) < F || !nc_refract(dv, nv, eta, tv)) {
                    d = nc_normalize(nc_add(d, nc_scale(n, 2.0f * cos_i)));
                    direct = 0;
                } else {
                    direct = direct == 1 && !entering && (int)h.obj == medium ? 2 : 0;
                    d = nc_normalize(nc_v3a(tv));
                    beta = nc_scale(beta, 1.0f / (eta * eta));
                    eta_scale *= eta * eta;
                    medium = entering ? (int)h.obj : -1;
                    /* The facet the path came in by seeds the first guide inside. */
                    if (entering) {
                        seed = h.prim;
                        seed_obj = medium;
                    }
                }
                o = offset_origin(ps, p, ng, d);
                prev_delta = true;
                prev_p = p;
                vertex++;
                goto roulette;
            }
            direct = 0;
            /* Opaque: shading frame on the side the path came from. */
            nc_vec3 wo = nc_scale(d, -1.0f);
            if (nc_dot(wo, ng) < 0)
                ng = nc_scale(ng, -1.0f);
            if (nc_dot(ns, ng) < 0)
                ns = nc_scale(ns, -1.0f);
            nacre_material_desc textured;
            const nacre_material_desc *m = nc_pt_material_at(ps, ob, &h, &textured);
            L = nc_add(L, nc_mul(beta, nc_pt_direct_light(ps, p, ng, true, m, ns, wo, 0, medium, 1.0f, NULL, rng)));
            nc_vec3 wi = bsdf_sample(m, ns, wo, rng);
            float pdf;
            nc_vec3 f = nc_pt_bsdf_eval(m, ns, wo, wi, &pdf);
            if (nc_dot(wi, ng) <= 0 || pdf <= 0 || max3(f) <= 0)
                break;
            beta = nc_mul(beta, nc_scale(f, nc_dot(ns, wi) / pdf));
            prev_pdf = pdf;
            prev_q = 1.0f;
            prev_delta = false;
            prev_eq.on = false;
            prev_p = p;
            o = offset_origin(ps, p, ng, wi);
            d = wi;
            vertex++;
        }
    roulette:
        if (vertex >= RR_START) {
            float q = fminf(1.0f, fmaxf(fabsf(beta.x), fmaxf(fabsf(beta.y), fabsf(beta.z))) * eta_scale);
            if (!(q > 0) || nc_rng_float(rng) >= q)
                break;
            beta = nc_scale(beta, 1.0f / q);
        }
    }
    return L;
}

/* ---- camera (identical to camera_view in render/render.c) ------------------------------ */

typedef struct pt_camera {
    nc_mat4 cam_to_world;
    bool ortho;
    float half_w, half_h; /* perspective: tan of half fov (x, y); ortho: half extents */
    float ortho_near;     /* ortho: view depth of the near plane */
} pt_camera;

static void make_camera(const nacre_scene *s, int32_t width, int32_t height, pt_camera *cam)
{
    const nacre_camera_desc *c = &s->camera;
    nc_mat4 view = nc_mat4_look_at(nc_v3a(c->position), nc_v3a(c->target), nc_v3a(c->up));
    nc_mat4_inverse(view, &cam->cam_to_world);
    cam->ortho = c->projection == NACRE_ORTHOGRAPHIC;
    float aspect = (float)width / (float)height;
    if (cam->ortho) {
        /* The raster pipeline's orthographic near plane sits before the nearest bound, possibly
         * behind the eye: rays start there so both see the same objects. */
        float dmin, dmax;
        nc_scene_view_depth_range(s, &view, &dmin, &dmax);
        float span = fmaxf(dmax - dmin, 1e-6f);
        cam->ortho_near = c->near_clip > 0 ? c->near_clip : dmin - 0.01f * span;
        cam->half_h = 0.5f * c->ortho_height;
        cam->half_w = cam->half_h * aspect;
    } else {
        cam->half_h = tanf(0.5f * c->fov_y * NC_DEG2RAD);
        cam->half_w = cam->half_h * aspect;
    }
}

static void camera_ray(const pt_camera *cam, float sx, float sy, int32_t w, int32_t h, nc_vec3 *o, nc_vec3 *d)
{
    /* Pixel (x, y) covers [x, x+1) x [y, y+1) with y down; NDC y is up. */
    float nx = 2.0f * sx / (float)w - 1.0f, ny = 1.0f - 2.0f * sy / (float)h;
    if (cam->ortho) {
        *o = nc_mat4_point(&cam->cam_to_world, nc_v3(nx * cam->half_w, ny * cam->half_h, -cam->ortho_near));
        *d = nc_normalize(nc_mat4_dir(&cam->cam_to_world, nc_v3(0, 0, -1)));
    } else {
        *o = nc_mat4_point(&cam->cam_to_world, nc_v3(0, 0, 0));
        *d = nc_normalize(nc_mat4_dir(&cam->cam_to_world, nc_v3(nx * cam->half_w, ny * cam->half_h, -1.0f)));
    }
}

/* ---- state ------------------------------------------------------------------------- */

bool nc_pathtrace_available(void) { return true; }

nacre_result nc_pathtracer_create(nacre_context *ctx, const nc_pathtrace_options *options, nc_pathtracer **out)
{
    nc_pathtracer *pt = nc_calloc(ctx, 1, sizeof(*pt));
    if (!pt)
        return NACRE_ERROR_OUT_OF_MEMORY;
    pt->ctx = ctx;
    pt->opt = options ? *options : nc_pathtrace_options_defaults();
    if (pt->opt.majorant_res > 256)
        pt->opt.majorant_res = 256;
    char config[64];
    snprintf(config, sizeof(config), "threads=%d", nc_threads(ctx) > 0 ? nc_threads(ctx) : 1);
    pt->device = rtcNewDevice(config);
    if (!pt->device) {
        nc_free(ctx, pt);
        return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "pathtrace: Embree device creation failed");
    }
    *out = pt;
    return NACRE_OK;
}

void nc_pathtracer_destroy(nacre_context *ctx, nc_pathtracer *pt)
{
    if (!pt)
        return;
    nc_pt_release_scene(pt);
    if (pt->device)
        rtcReleaseDevice(pt->device);
    nc_free(ctx, pt->mean);
    nc_free(ctx, pt->m2);
    nc_free(ctx, pt->count);
    nc_free(ctx, pt);
}

/* What the samples of a frame share. */
typedef struct pt_frame {
    const pt_scene *ps;
    nc_pathtracer *pt;
    pt_camera cam;
    int32_t w, h;
    uint32_t seed;
    uint64_t deadline_us; /* 0: none */
} pt_frame;

/* The next sample of pixel (x, y) into its mean and M2 (Welford). The pass of a sample is the
 * pixel's own count, not the frame's pass: a pixel continued over frames, or cut short by a
 * deadline, draws the samples one longer frame would. False when the deadline has passed: the
 * sample, if it was begun, is dropped. */
static bool sample_pixel(const pt_frame *fr, int32_t x, int32_t y, uint64_t *capped)
{
    if (fr->deadline_us && nc_now_us() >= fr->deadline_us)
        return false;
    pt_budget budget;
    budget_reset(&budget, fr->deadline_us);
    pt_scene ps = *fr->ps;
    ps.budget = &budget;
    size_t pi = (size_t)y * (size_t)fr->w + (size_t)x;
    nc_pathtracer *pt = fr->pt;
    uint32_t pp = pt->count[pi];
    nc_rng rng = nc_rng_make(((uint64_t)fr->seed << 32) | pp, pi);
    nc_vec3 o, d;
    camera_ray(&fr->cam, (float)x + nc_rng_float(&rng), (float)y + nc_rng_float(&rng), fr->w, fr->h, &o, &d);
    nc_vec3 L = trace_path(&ps, o, d, &rng);
    if (budget.expired)
        return false;
    *capped += budget.capped;
    double inv_n = 1.0 / (double)(++pt->count[pi]);
    for (int c = 0; c < 3; c++) {
        double v = comp(L, c);
        if (!isfinite(v))
            v = 0; /* a NaN or inf sample would poison the pixel forever */
        double *mu = &pt->mean[3 * pi + (size_t)c], *m2 = &pt->m2[3 * pi + (size_t)c];
        double delta = v - *mu;
        *mu += delta * inv_n;
        *m2 += delta * (v - *mu);
    }
    return true;
}

/* The 8x8 Bayer (ordered dither) matrix as a visiting order: rank r is cell (bx[r], by[r]). */
static void bayer_order(uint8_t bx[64], uint8_t by[64])
{
    for (uint32_t y = 0; y < 8; y++)
        for (uint32_t x = 0; x < 8; x++) {
            uint32_t v = 0, q = x ^ y;
            for (int k = 0; k < 3; k++)
                v |= (((q >> k) & 1u) << (5 - 2 * k)) | (((y >> k) & 1u) << (4 - 2 * k));
            bx[v] = (uint8_t)x;
            by[v] = (uint8_t)y;
        }
}

/* A time limit reached within the first pass leaves pixels without a sample (reported in
 * stats->pixels_unsampled): each gets the mean of the sampled pixels of its 8x8 block (the Bayer
 * order spreads them), or 0 if its block has none. */
static void fill_unsampled(const nc_pathtracer *pt, nacre_image *out)
{
    int32_t w = pt->width, h = pt->height;
    for (int32_t by = 0; by < h; by += 8)
        for (int32_t bx = 0; bx < w; bx += 8) {
            double sum[3] = {0, 0, 0};
            int n = 0;
            for (int32_t y = by; y < by + 8 && y < h; y++)
                for (int32_t x = bx; x < bx + 8 && x < w; x++) {
                    size_t pi = (size_t)y * (size_t)w + (size_t)x;
                    if (!pt->count[pi])
                        continue;
                    n++;
                    for (int c = 0; c < 3; c++)
                        sum[c] += pt->mean[3 * pi + (size_t)c];
                }
            for (int32_t y = by; y < by + 8 && y < h; y++)
                for (int32_t x = bx; x < bx + 8 && x < w; x++)
                    if (!pt->count[(size_t)y * (size_t)w + (size_t)x])
                        for (int c = 0; c < 3; c++)
                            out->pixels[(size_t)y * out->stride + 3 * (size_t)x + (size_t)c] = n ? (float)(sum[c] / n) : 0.0f;
        }
}

/* Whether a frame may add to the accumulators of the state's last frame (see "Accumulation"
 * above): the same scene (context and uid) with the same committed versions, the same size and
 * the same settings that decide the samples. spp and time_limit only say how many to add. */
static bool continues(const nc_pathtracer *pt, const nacre_scene *s, const nacre_render_settings *rs)
{
    return pt->valid && s->ctx == pt->ctx && s->uid == pt->acc_uid && nc_pt_scene_settled(s) &&
           memcmp(&s->committed, &pt->acc_versions, sizeof(s->committed)) == 0 && rs->width == pt->width &&
           rs->height == pt->height && rs->pathtrace.seed == pt->acc_seed && rs->pathtrace.max_scatter == pt->acc_max_scatter;
}

/* Empty accumulators for a w x h frame of scene s (grown if needed), labelled with what they
 * will hold so that the next frame can tell whether it continues them. */
static nacre_result restart_pixels(nc_pathtracer *pt, nacre_context *ctx, const nacre_scene *s,
                                   const nacre_render_settings *rs)
{
    size_t npix = (size_t)rs->width * (size_t)rs->height;
    if (npix * 3 > pt->pixel_capacity) {
        nc_free(ctx, pt->mean);
        nc_free(ctx, pt->m2);
        nc_free(ctx, pt->count);
        pt->mean = nc_alloc(ctx, npix * 3 * sizeof(double));
        pt->m2 = nc_alloc(ctx, npix * 3 * sizeof(double));
        pt->count = nc_alloc(ctx, npix * sizeof(uint32_t));
        pt->pixel_capacity = pt->mean && pt->m2 && pt->count ? npix * 3 : 0;
        if (!pt->pixel_capacity)
            return NACRE_ERROR_OUT_OF_MEMORY;
    }
    memset(pt->mean, 0, npix * 3 * sizeof(double));
    memset(pt->m2, 0, npix * 3 * sizeof(double));
    memset(pt->count, 0, npix * sizeof(uint32_t));
    pt->width = rs->width;
    pt->height = rs->height;
    pt->acc_uid = s->uid;
    pt->acc_versions = s->committed;
    pt->acc_seed = rs->pathtrace.seed;
    pt->acc_max_scatter = rs->pathtrace.max_scatter;
    pt->acc_frames = 0;
    pt->acc_samples = 0;
    return NACRE_OK;
}

/* Up to max_pass more samples for every pixel (fewer where the deadline cuts them); returns
 * the number of paths that hit a cap. */
static uint64_t run_passes(const pt_frame *fr, nacre_context *ctx, uint32_t max_pass)
{
    int32_t w = fr->w, h = fr->h;
    uint64_t capped = 0;
    enum { TILE = 16 };
    int32_t tiles_x = (w + TILE - 1) / TILE, tiles_y = (h + TILE - 1) / TILE;
    int64_t tiles = (int64_t)tiles_x * tiles_y;
    uint64_t t_trace = nc_now_us();
    uint32_t pass = 0;
    bool out_of_time = false;
    /* With a time limit the first pass visits the pixels in the order of an 8x8 Bayer matrix
     * over the image (every 64th pixel, then the ones halfway between, ...), so that a limit
     * reached within it leaves samples spread evenly (see fill_unsampled). */
    if (fr->deadline_us) {
        uint8_t bx[64], by[64];
        bayer_order(bx, by);
        int64_t blocks_y = (h + 7) / 8, items = 64 * blocks_y;
#pragma omp parallel for schedule(dynamic, 1) num_threads(nc_threads(ctx)) reduction(+ : capped)
        for (int64_t item = 0; item < items; item++) {
            int32_t r = (int32_t)(item / blocks_y), y = (int32_t)(item % blocks_y) * 8 + by[r];
            for (int32_t x = bx[r]; x < w && y < h; x += 8)
                if (!sample_pixel(fr, x, y, &capped))
                    break;
        }
        pass = 1;
        out_of_time = nc_now_us() >= fr->deadline_us;
    }
    /* Passes run in batches, each thread taking a tile through every pass of the batch: one
     * barrier per batch instead of per pass (long paths make tiles unequal, and threads would
     * idle at every pass end). Pixels still see their passes in order, so the result is the same
     * as pass by pass. With a time limit, a batch is sized from the measured time per pass to
     * take about half the time left, and the deadline is checked before every sample and within
     * paths: a sample still in flight at the deadline is dropped, and pixels keep the samples
     * they completed (their counts then differ by at most one batch, typically one pass). */
    while (pass < max_pass && !out_of_time) {
        uint32_t batch = max_pass - pass;
        if (fr->deadline_us) {
            uint64_t now = nc_now_us();
            if (now >= fr->deadline_us)
                break;
            double per_pass = (double)(now - t_trace) * 1e-6 / pass;
            double left = (double)(fr->deadline_us - now) * 1e-6;
            double fit = per_pass > 0 ? floor(0.5 * left / per_pass) : 1;
            batch = fit < 1 ? 1 : fit < (double)batch ? (uint32_t)fit : batch;
        }
#pragma omp parallel for schedule(dynamic, 1) num_threads(nc_threads(ctx)) reduction(+ : capped)
        for (int64_t tile = 0; tile < tiles; tile++) {
            int32_t x0 = (int32_t)(tile % tiles_x) * TILE, y0 = (int32_t)(tile / tiles_x) * TILE;
            bool go = true;
            for (uint32_t k = 0; k < batch && go; k++)
                for (int32_t y = y0; y < y0 + TILE && y < h && go; y++)
                    for (int32_t x = x0; x < x0 + TILE && x < w && go; x++)
                        go = sample_pixel(fr, x, y, &capped);
        }
        pass += batch;
        out_of_time = fr->deadline_us && nc_now_us() >= fr->deadline_us;
    }
    return capped;
}

/* The accumulated means into `out` and the frame's stats: spp_done is what every pixel holds
 * (accumulated), samples_done and samples_per_second count this frame's paths only. */
static void finish_frame(nc_pathtracer *pt, nacre_context *ctx, nacre_image *out, nacre_render_stats *stats,
                         uint64_t capped, double secs)
{
    int32_t w = pt->width, h = pt->height;
    size_t npix = (size_t)w * (size_t)h;
    uint32_t spp_min = UINT32_MAX;
    uint64_t total = 0, unsampled = 0;
    for (size_t i = 0; i < npix; i++) {
        spp_min = pt->count[i] < spp_min ? pt->count[i] : spp_min;
        total += pt->count[i];
        unsampled += pt->count[i] == 0;
    }
    uint64_t samples = total - pt->acc_samples;
    pt->acc_samples = total;
    pt->acc_frames++;
    for (int32_t y = 0; y < h; y++) {
        float *row = out->pixels + (size_t)y * out->stride;
        for (int32_t x = 0; x < w; x++)
            for (int c = 0; c < 3; c++)
                row[3 * x + c] = (float)pt->mean[3 * ((size_t)y * (size_t)w + (size_t)x) + (size_t)c];
    }
    if (unsampled)
        fill_unsampled(pt, out);
    pt->valid = true;
    if (stats) {
        stats->spp_done = npix ? spp_min : 0;
        stats->samples_done = samples;
        stats->paths_capped = capped;
        stats->pixels_unsampled = (uint32_t)unsampled;
        stats->samples_per_second = secs > 0 ? (double)samples / secs : 0;
        stats->threads = nc_threads(ctx);
    }
}

nacre_result nc_pathtrace_render(nc_pathtracer **state, nacre_context *ctx, const nacre_scene *scene,
                                 const nacre_render_settings *settings, bool accumulate, nacre_image *out,
                                 nacre_render_stats *stats)
{
    if (!state || !scene || !settings || !out || !out->pixels)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "pathtrace: missing argument");
    if (settings->pathtrace.spp == 0 && !(settings->pathtrace.time_limit > 0))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: spp: must be >= 1 (or set a time limit)");
    if (!(settings->pathtrace.time_limit >= 0) || !isfinite(settings->pathtrace.time_limit))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: time_limit: must be finite and >= 0");
    int32_t w = settings->width, h = settings->height;
    if (out->width != w || out->height != h || out->channels != 3)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "pathtrace: output image must be %dx%d with 3 channels", w, h);
    nacre_result res;
    if (!*state && (res = nc_pathtracer_create(ctx, NULL, state)) != NACRE_OK)
        return res;
    nc_pathtracer *pt = *state;
    const bool cont = accumulate && continues(pt, scene, settings);
    pt->valid = false; /* until this frame completes: a failed frame restarts the next */
    uint64_t t_start = nc_now_us();

    pt_scene ps;
    memset(&ps, 0, sizeof(ps));
    ps.scene = scene;
    ps.pt = pt;
    ps.eval = pt->opt.eval ? pt->opt.eval : nc_medium_eval;
    ps.env = nc_v3a(scene->environment);
    ps.env_on = max3(ps.env) > 0;
    ps.max_scatter = settings->pathtrace.max_scatter;
    float ext = 0;
    for (int a = 0; a < 3; a++)
        ext = fmaxf(ext, fmaxf(fabsf(scene->bounds_min[a]), fabsf(scene->bounds_max[a])));
    ps.eps = isfinite(ext) ? fmaxf(1e-5f * ext, 1e-7f) : 1e-5f; /* no objects: only fog */
    if ((res = nc_pt_prepare_scene(pt, scene, &ps)) != NACRE_OK)
        return res;
    if (!cont && (res = restart_pixels(pt, ctx, scene, settings)) != NACRE_OK)
        return res;

    pt_frame fr;
    fr.ps = &ps;
    fr.pt = pt;
    make_camera(scene, w, h, &fr.cam);
    fr.w = w;
    fr.h = h;
    fr.seed = settings->pathtrace.seed;
    fr.deadline_us = settings->pathtrace.time_limit > 0 ? t_start + (uint64_t)(settings->pathtrace.time_limit * 1e6) : 0;
    uint64_t t_trace = nc_now_us();
    uint64_t capped = run_passes(&fr, ctx, settings->pathtrace.spp ? settings->pathtrace.spp : UINT32_MAX);
    finish_frame(pt, ctx, out, stats, capped, (double)(nc_now_us() - t_trace) * 1e-6);
    return NACRE_OK;
}

uint32_t nc_pathtrace_passes(const nc_pathtracer *pt)
{
    if (!pt || !pt->valid)
        return 0;
    uint32_t n = UINT32_MAX;
    for (size_t i = 0, npix = (size_t)pt->width * (size_t)pt->height; i < npix; i++)
        n = pt->count[i] < n ? pt->count[i] : n;
    return n == UINT32_MAX ? 0 : n;
}

uint64_t nc_pathtrace_samples(const nc_pathtracer *pt) { return pt && pt->valid ? pt->acc_samples : 0; }

uint32_t nc_pathtrace_frames(const nc_pathtracer *pt) { return pt && pt->valid ? pt->acc_frames : 0; }

nacre_result nc_pathtrace_variance(const nc_pathtracer *pt, nacre_context *ctx, nacre_image *out)
{
    if (!pt || !pt->valid)
        return nc_fail(ctx, NACRE_ERROR_INVALID_OPERATION, "variance: the last frame was not path traced");
    int32_t w = pt->width, h = pt->height;
    if (out->pixels) {
        if (out->width != w || out->height != h || out->channels != 3 || out->stride < (size_t)w * 3)
            return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "variance: output image must be %dx%d with 3 channels", w, h);
    } else {
        nacre_result res = nacre_image_alloc(ctx, w, h, 3, out);
        if (res != NACRE_OK)
            return res;
    }
    for (int32_t y = 0; y < h; y++) {
        float *row = out->pixels + (size_t)y * out->stride;
        for (int32_t x = 0; x < w; x++)
            for (int c = 0; c < 3; c++) {
                double n = (double)pt->count[(size_t)y * (size_t)w + (size_t)x];
                double m2 = pt->m2[3 * ((size_t)y * (size_t)w + (size_t)x) + (size_t)c];
                /* Variance of the mean: sample variance / n; undefined with one sample (reported 0). */
                row[3 * x + c] = n > 1 ? (float)(m2 / ((n - 1) * n)) : 0.0f;
            }
    }
    return NACRE_OK;
}

#endif /* NACRE_HAVE_EMBREE */
