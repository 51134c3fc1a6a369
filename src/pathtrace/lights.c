/*
 * lights.c: the path tracer's lights: sampling them from a point, shadow rays (through media
 * and index-matched boundaries), next-event estimation, and the MIS weights (power heuristic,
 * Veach and Guibas 1995) of lights reached by a sampled direction.
 *
 * Radiometry as in phong.c: the environment is a uniform radiance (sampled uniformly over
 * the sphere); a directional light of irradiance E and angular radius r is a distant disk of
 * radiance E / (pi sin^2 r), sampled uniformly in its cone (r = 0: a delta light, NEE only); a
 * point or spot light of intensity I and radius r is a sphere of radiance I / (pi r^2) times the
 * spot falloff of the direction from its centre (r = 0: delta). Through index-matched boundaries
 * NEE works. Inside a dielectric object NEE cannot work (shadow rays end on the boundary): a sun
 * of non-zero radius is sampled through the boundary by a second technique, MIS-combined with
 * phase sampling (guided_sun in sun_guide.c); every other light, and a delta sun, is reached
 * only by paths that refract out and hit it by chance (point lights, delta suns: never; exact
 * but slow for small sphere lights).
 *
 * pdfs of directions are per unit solid angle; 0 marks a delta light.
 */
#include "pathtrace/pt_internal.h"

#ifdef NACRE_HAVE_EMBREE

/* Transmittance from p (in medium `medium`, -1 = air) to distance `dist` along wi: blocked by
 * opaque and dielectric surfaces, through media and index-matched boundaries. */
static bool occluded(const pt_scene *ps, nc_vec3 o, nc_vec3 d, float tfar)
{
    struct RTCIntersectContext ictx;
    rtcInitIntersectContext(&ictx);
    struct RTCRay ray;
    ray.org_x = o.x;
    ray.org_y = o.y;
    ray.org_z = o.z;
    ray.dir_x = d.x;
    ray.dir_y = d.y;
    ray.dir_z = d.z;
    ray.tnear = 0.0f;
    ray.tfar = tfar;
    ray.time = 0.0f;
    ray.mask = 0xffffffffu;
    ray.id = 0;
    ray.flags = 0;
    rtcOccluded1(ps->pt->rtc, &ictx, &ray);
    return ray.tfar < 0.0f; /* Embree marks an occluded ray with tfar = -inf */
}

nc_vec3 nc_pt_shadow(const pt_scene *ps, nc_vec3 p, nc_vec3 wi, float dist, int medium, nc_rng *rng)
{
    /* Without index-matched objects, a shadow ray from air is blocked by any hit: the cheaper
     * any-hit query answers it. */
    const bool fog = ps->pt->fog_count > 0;
    if (medium < 0 && !ps->pt->any_matched && !ps->pt->any_noncaster && !fog)
        return occluded(ps, p, wi, dist) ? nc_v3(0, 0, 0) : nc_v3(1, 1, 1);
    nc_vec3 tr = nc_v3(1, 1, 1);
    nc_vec3 o = p;
    float remaining = dist;
    for (int k = 0; k < MAX_CROSSINGS; k++) {
        pt_hit h = intersect(ps, o, wi, remaining);
        float seg = h.hit ? h.t : remaining;
        if (medium >= 0) {
            tr = nc_mul(tr, nc_pt_transmittance(ps, &ps->pt->objects[medium], o, wi, seg, rng));
            if (tr.x == 0 && tr.y == 0 && tr.z == 0)
                return tr;
        }
        const pt_object *ob = h.hit ? &ps->pt->objects[h.obj] : NULL;
        if (ob && ob->kind != PT_MATCHED && ob->casts)
            return nc_v3(0, 0, 0);
        /* Fog after the occlusion test: a blocked ray needs no tracking. */
        if (medium < 0 && fog) {
            tr = nc_mul(tr, nc_pt_transmittance(ps, NULL, o, wi, seg, rng));
            if (tr.x == 0 && tr.y == 0 && tr.z == 0)
                return tr;
        }
        if (!ob)
            return tr;
        nc_vec3 hp, ng, ns;
        nc_pt_surface_at(ob, &h, &hp, &ng, &ns);
        if (ob->kind == PT_MATCHED)
            medium = nc_dot(wi, ng) < 0 ? (int)h.obj : -1;
        nc_vec3 no = offset_origin(ps, hp, ng, wi);
        remaining -= nc_length(nc_sub(no, o));
        o = no;
        if (remaining <= 0)
            return tr;
    }
    return nc_v3(0, 0, 0);
}

/* One light sample from p: direction, distance, radiance (or delta value) and pdf (0: delta). */
typedef struct light_sample {
    nc_vec3 wi;
    float dist;
    nc_vec3 value;
    float pdf;
} light_sample;

static bool sample_light(const pt_light *l, nc_vec3 p, nc_rng *rng, light_sample *s)
{
    float u1 = nc_rng_float(rng), u2 = nc_rng_float(rng);
    if (l->type == NACRE_LIGHT_DIRECTIONAL) {
        s->dist = INFINITY;
        s->value = l->value;
        if (l->delta) {
            s->wi = l->to_light;
            s->pdf = 0;
        } else {
            s->wi = nc_pt_around(l->to_light, 1.0f - u1 * (1.0f - l->cos_max), u2);
            s->pdf = l->cone_pdf;
        }
        return true;
    }
    nc_vec3 d = nc_sub(l->pos, p);
    float d2 = nc_dot(d, d);
    if (d2 <= 0)
        return false;
    float dl = sqrtf(d2);
    nc_vec3 axis = nc_scale(d, 1.0f / dl);
    float fall = spot_falloff(l->desc, nc_scale(axis, -1.0f));
    if (fall <= 0)
        return false;
    if (l->delta) {
        s->wi = axis;
        s->dist = dl;
        s->value = nc_scale(l->value, fall / d2);
        s->pdf = 0;
        return true;
    }
    float cos_max;
    float pdf = sphere_pdf(l, p, &cos_max);
    if (pdf <= 0)
        return false;
    s->wi = nc_pt_around(axis, 1.0f - u1 * (1.0f - cos_max), u2);
    float t = sphere_hit(l, p, s->wi);
    if (!isfinite(t))
        t = dl; /* grazing the silhouette: rounding */
    s->dist = t;
    s->value = nc_scale(l->value, fall);
    s->pdf = pdf;
    return true;
}

/* NEE from a fog point p towards light li alone, by light sampling only (weight 1: the
 * equiangular vertices of integrator.c have no phase-sampled continuation to share it with);
 * d is the direction the path travels, g the phase's anisotropy. */
nc_vec3 nc_pt_direct_one(const pt_scene *ps, uint32_t li, nc_vec3 p, nc_vec3 d, float g, nc_rng *rng)
{
    const nc_pathtracer *pt = ps->pt;
    light_sample s;
    if (!sample_light(&pt->lights[li], p, rng, &s))
        return nc_v3(0, 0, 0);
    float f = (float)nc_hg_phase(nc_dot(d, s.wi), g);
    if (!(f > 0))
        return nc_v3(0, 0, 0);
    float dist = s.dist * (1.0f - 1e-4f);
    for (uint32_t k = 0; k < pt->light_count; k++) {
        const pt_light *b = &pt->lights[k];
        if (k != li && b->type != NACRE_LIGHT_DIRECTIONAL && !b->delta && sphere_hit(b, p, s.wi) < dist)
            return nc_v3(0, 0, 0);
    }
    nc_vec3 tr = nc_pt_shadow(ps, p, s.wi, dist, -1, rng);
    return nc_scale(nc_mul(tr, s.value), f / (s.pdf > 0 ? s.pdf : 1.0f));
}

/* NEE from p over every light and the environment. `surface`: opaque vertex with shading
 * normal n and outgoing wo (else a medium vertex with HG g, incoming direction d = -wo). Run
 * with probability q (see nee_probability): weighted by 1 / q, MIS with the density q pdf. At a
 * fog vertex eq (else NULL) gives each point or spot light's weight against equiangular sampling. */
nc_vec3 nc_pt_direct_light(const pt_scene *ps, nc_vec3 p, nc_vec3 ng, bool surface, const nacre_material_desc *m,
                           nc_vec3 n, nc_vec3 wo, float g, int medium, float q, const pt_eq *eq, nc_rng *rng)
{
    const nc_pathtracer *pt = ps->pt;
    nc_vec3 sum = nc_v3(0, 0, 0);
    for (uint32_t li = 0; li <= pt->light_count; li++) {
        light_sample s;
        if (li == pt->light_count) {
            if (!ps->env_on)
                break;
            sample_uniform_sphere(nc_rng_float(rng), nc_rng_float(rng), &s.wi);
            s.dist = INFINITY;
            s.value = ps->env;
            s.pdf = 1.0f / (4.0f * PT_PI);
        } else if (!sample_light(&pt->lights[li], p, rng, &s)) {
            continue;
        }
        nc_vec3 f;
        float fpdf;
        if (surface) {
            if (nc_dot(s.wi, ng) <= 0)
                continue;
            f = nc_scale(nc_pt_bsdf_eval(m, n, wo, s.wi, &fpdf), fmaxf(0.0f, nc_dot(n, s.wi)));
        } else {
            fpdf = (float)nc_hg_phase(nc_dot(nc_scale(wo, -1.0f), s.wi), g);
            f = nc_v3(fpdf, fpdf, fpdf);
        }
        if (max3(f) <= 0)
            continue;
        nc_vec3 o = surface ? offset_origin(ps, p, ng, s.wi) : p;
        float dist = isfinite(s.dist) ? s.dist * (1.0f - 1e-4f) : INFINITY;
        /* Sphere lights are opaque to each other and to the sky, as they are to BSDF-sampled
         * rays (which end on them); otherwise the two MIS strategies would see different worlds. */
        bool hidden = false;
        for (uint32_t k = 0; k < pt->light_count && !hidden; k++) {
            const pt_light *b = &pt->lights[k];
            hidden = k != li && b->type != NACRE_LIGHT_DIRECTIONAL && !b->delta && sphere_hit(b, o, s.wi) < dist;
        }
        if (hidden)
            continue;
        nc_vec3 tr = nc_pt_shadow(ps, o, s.wi, dist, medium, rng);
        if (tr.x == 0 && tr.y == 0 && tr.z == 0)
            continue;
        nc_vec3 c = nc_scale(nc_mul(nc_mul(f, tr), s.value), li < pt->light_count ? eq_weight_d(&pt->lights[li], eq) : 1.0f);
        if (s.pdf > 0)
            c = nc_scale(c, (pt->nee_only ? 1.0f : power_heuristic(q * s.pdf, fpdf)) / (q * s.pdf));
        else
            c = nc_scale(c, 1.0f / q);
        sum = nc_add(sum, c);
    }
    return sum;
}

#endif /* NACRE_HAVE_EMBREE */
