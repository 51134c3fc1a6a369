/*
 * sun_guide.c: sampling the sun through a dielectric boundary, for vertices inside a dielectric
 * object (the path tracer's second technique for directional lights of non-zero radius).
 *
 * Inside a dielectric object NEE is impossible (every shadow ray ends on the boundary) and a
 * sun of 0.27 degrees is found by phase sampling with probability ~1e-4. A second technique
 * samples, at each medium vertex p, a direction in a small cone around the direction that
 * refracts out towards the sun: the "guide axis", a function of p only (refract the sun
 * direction through the facet that the ray towards the sun meets, and repeat with the facet the
 * refracted ray meets, up to GUIDE_ITERATIONS times). The guided direction is traced to the
 * boundary (transmittance as for NEE), refracted out with weight (1 - F) eta^2 and, if it lands in
 * the sun's cone and nothing occludes it, scores the sun's radiance. Phase sampling covers the
 * same paths (free flight, one refraction, sun) and both are weighted by the power heuristic on
 * the direction chosen at p; paths that reflect or scatter again are phase sampling's alone. Any
 * axis gives an unbiased result; a good one makes it converge. Only the first non-delta
 * directional light is guided.
 *
 * The guide cone's density is per unit solid angle; the facet walk and Moller-Trumbore test
 * (Moller and Trumbore 1997) work on the world-space triangles of the committed mesh.
 */
#include "pathtrace/pt_internal.h"

#ifdef NACRE_HAVE_EMBREE

/* Where the ray p + t dir meets the plane of triangle `prim` of `o` (Moller and Trumbore 1997):
 * true if it crosses the triangle at *t > 0; otherwise *edge is the edge (0: v0v1, 1: v1v2,
 * 2: v2v0) beyond which the plane point lies farthest, or -1 when the plane is not ahead. Lets
 * nc_pt_make_guide find the facet its refracted direction leaves through without asking Embree: the
 * guide axis need not be exact, only a function of p. */
static bool crosses_triangle(const pt_object *o, uint32_t prim, nc_vec3 p, nc_vec3 dir, float *t, int *edge)
{
    const uint32_t *tri = o->idx + 3 * (size_t)prim;
    nc_vec3 a = nc_v3a(o->pos + 3 * (size_t)tri[0]), b = nc_v3a(o->pos + 3 * (size_t)tri[1]),
            c = nc_v3a(o->pos + 3 * (size_t)tri[2]);
    nc_vec3 e1 = nc_sub(b, a), e2 = nc_sub(c, a), pv = nc_cross(dir, e2);
    float det = nc_dot(e1, pv);
    *edge = -1;
    if (fabsf(det) < 1e-20f)
        return false;
    float inv = 1.0f / det;
    nc_vec3 tv = nc_sub(p, a), qv = nc_cross(tv, e1);
    float u = nc_dot(tv, pv) * inv, v = nc_dot(dir, qv) * inv, w = 1.0f - u - v;
    *t = nc_dot(e2, qv) * inv;
    if (!(*t > 0.0f))
        return false;
    if (u >= 0.0f && v >= 0.0f && w >= 0.0f)
        return true;
    /* u, v, w: weights of v1, v2, v0; a negative one lies across the opposite edge. */
    *edge = v <= u && v <= w ? 0 : w <= u ? 1 : 2;
    return false;
}

/* Outward geometric normal of triangle `prim` (counter-clockwise winding, as nc_pt_surface_at). */
static nc_vec3 facet_normal(const pt_object *o, uint32_t prim)
{
    const uint32_t *tri = o->idx + 3 * (size_t)prim;
    nc_vec3 a = nc_v3a(o->pos + 3 * (size_t)tri[0]), b = nc_v3a(o->pos + 3 * (size_t)tri[1]),
            c = nc_v3a(o->pos + 3 * (size_t)tri[2]);
    return nc_normalize(nc_cross(nc_sub(b, a), nc_sub(c, a)));
}

/* The sun direction refracted into object `ob` through facet `prim` (light travels along
 * -to_light and enters there), pointing back out; false if the facet faces away or the light
 * cannot enter (it always can from air). */
bool nc_pt_refract_sun_facet(const pt_object *ob, const pt_light *l, uint32_t prim, nc_vec3 *dir)
{
    nc_vec3 n = facet_normal(ob, prim);
    float lv[3] = {-l->to_light.x, -l->to_light.y, -l->to_light.z}, nv[3] = {n.x, n.y, n.z}, tv[3];
    if (!(nc_dot(l->to_light, n) > 0) || !nc_refract(lv, nv, ob->eta, tv))
        return false;
    *dir = nc_normalize(nc_scale(nc_v3a(tv), -1.0f));
    return true;
}

/* The same from the table made at scene build (the walk below visits many facets per vertex). */
static bool refract_sun(const pt_object *ob, const pt_light *l, uint32_t prim, nc_vec3 *dir)
{
    if (!ob->sun_dir)
        return nc_pt_refract_sun_facet(ob, l, prim, dir);
    const float *v = ob->sun_dir + 3 * (size_t)prim;
    if (isnan(v[0]))
        return false;
    *dir = nc_v3a(v);
    return true;
}

/* The query-free start of nc_pt_make_guide: from the seed facet, refract the sun and, while the ray
 * from p along the refracted direction misses the facet, step to the neighbour across the edge
 * it passes (a point location walk over the mesh). A function of (p, seed), so the probability
 * of guiding may use the distance it finds (see sun_guide_probability). */
#define GUIDE_WALK_STEPS 24
guide_walk nc_pt_walk_guide(const pt_object *ob, const pt_light *l, nc_vec3 p, uint32_t seed)
{
    guide_walk gw = {UINT32_MAX, l->to_light, false, 0.0f};
    if (seed == UINT32_MAX || !refract_sun(ob, l, seed, &gw.dir))
        return gw;
    gw.prim = seed;
    uint32_t prev = UINT32_MAX;
    for (int step = 0; step <= GUIDE_WALK_STEPS; step++) {
        int edge;
        if (crosses_triangle(ob, gw.prim, p, gw.dir, &gw.t, &edge)) {
            gw.done = true;
            return gw;
        }
        uint32_t next = edge >= 0 && ob->adj ? ob->adj[3 * (size_t)gw.prim + (size_t)edge] : UINT32_MAX;
        if (next == prev && next != UINT32_MAX) {
            /* Refracted through either facet the ray leaves through the other: the guide's wide
             * cone covers the difference. */
            gw.done = true;
            return gw;
        }
        nc_vec3 nd;
        if (step == GUIDE_WALK_STEPS || next == UINT32_MAX || !refract_sun(ob, l, next, &nd))
            return gw; /* nc_pt_make_guide asks Embree from here */
        prev = gw.prim;
        gw.prim = next;
        gw.dir = nd;
    }
    return gw;
}

/* The guide at p, from the walk from the seed (see nc_pt_walk_guide; the seed is the last facet of the
 * previous guide on the path: vertices a mean free path apart refract the sun through the same
 * facet or a near one, and then no query is needed at all); where the walk does not end, Embree
 * finds the facets. The axis depends on (p, seed), both known at the vertex, so the MIS weights
 * stay consistent (the lazy re-evaluation in trace_path passes the same seed). *last receives
 * the facet the axis was refracted through. */
guide nc_pt_make_guide(const pt_scene *ps, uint32_t obj, const pt_light *l, nc_vec3 p, const guide_walk *gw, uint32_t *last)
{
    guide g = {false, {0, 0, 0}, 1, 0, 1, 0};
    const pt_object *ob = &ps->pt->objects[obj];
    nc_vec3 dir = gw->dir, x, n = {0, 0, 0};
    pt_hit h;
    uint32_t prim = gw->prim;
    float lv[3] = {-l->to_light.x, -l->to_light.y, -l->to_light.z}, tv[3];
    *last = UINT32_MAX;
    for (int it = 0; it < GUIDE_ITERATIONS && !gw->done; it++) {
        /* Converged once the refracted direction leaves through the facet it was refracted by
         * (checked without a query: nearly always so on flat or finely tessellated parts). */
        float tc;
        int edge;
        if (it > 0 && crosses_triangle(ob, prim, p, dir, &tc, &edge))
            break;
        if (!exit_facet(ps, obj, p, dir, &h, &x, &n))
            return g;
        prim = h.prim;
        /* Light travels along -to_light, enters through the facet (normal n, eta = ob->eta). */
        float nv[3] = {n.x, n.y, n.z};
        if (nc_dot(l->to_light, n) <= 0 || !nc_refract(lv, nv, ob->eta, tv))
            return g;
        dir = nc_normalize(nc_scale(nc_v3a(tv), -1.0f));
    }
    *last = prim;
    float a = fminf(GUIDE_CONE_SCALE * acosf(fminf(1.0f, l->cos_max)), 0.5f);
    g.valid = true;
    g.axis = dir;
    g.cos_a = cosf(a);
    float s = sinf(a);
    g.pdf = 1.0f / (2.0f * PT_PI * (s * s / (1.0f + g.cos_a)));
    float aw = fmaxf(a, GUIDE_WIDE_ANGLE), sw = sinf(aw);
    g.cos_w = cosf(aw);
    g.pdf_w = 1.0f / (2.0f * PT_PI * (sw * sw / (1.0f + g.cos_w)));
    return g;
}

#endif /* NACRE_HAVE_EMBREE */
