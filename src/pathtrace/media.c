/*
 * media.c: participating media for the path tracer: coefficients at a point, majorants, free
 * flights and transmittance, in translucent objects and in fog.
 *
 * A translucent object's interior is a participating medium with sigma_a, sigma_s from
 * nc_medium_eval at the rest-pose point and Henyey-Greenstein phase with the material's g. A
 * layered material (layered/layers.h) puts its layers above that core: a point's layer comes from
 * its distance to the rest-pose mesh and the depth map at the nearest point's uv (an Embree point
 * query), each layer with its own coefficients and g. A layer grid over the object (built in
 * scene_setup.c) stores per cell the layers its depths can reach (depth is 1-Lipschitz), so
 * points in cells that only one layer (or the core) reaches skip the query, and the majorant
 * grid takes its bounds from it.
 *
 * Homogeneous free flights by spectral MIS over the RGB channels (flight_sample_homogeneous,
 * inline in pt_internal.h, and nc_pt_flight_resolve_homogeneous);
 * heterogeneous ones by spectral tracking (Kutz, Habel, Li, Novak 2017, "Spectral and
 * decomposition tracking", with history-aware probabilities): one scalar majorant bounds every
 * channel; at each tentative collision the event (absorb, scatter, null) is chosen with
 * probabilities proportional to sum_c beta_c sigma_x,c and each channel is weighted by
 * sigma_x,c / (majorant P_x). This is unbiased for RGB-different coefficients and reduces to
 * plain delta tracking (Woodcock 1965) for grey media. NEE transmittance: exact exp(-sigma_t d) in
 * homogeneous media, ratio tracking (Novak, Selle, Jarosz 2014) in heterogeneous ones. Heterogeneous
 * media get a coarse world-space majorant grid walked with a 3D DDA (Amanatides and Woo 1987);
 * its cells bound sigma_t by dense sampling (the medium interface gives point values only), so
 * a cell may rarely under-bound a feature smaller than the sampling step: null coefficients then
 * go negative and the signed weights of weighted tracking keep the estimate unbiased.
 *
 * Fog (nacre_fog_desc) fills the air: a path outside every object tracks the sum of the fogs'
 * coefficients by the same spectral tracking and ratio tracking, over majorant pieces cut where
 * a fog begins or ends and where height fog changes by a factor of 2 (see "fog" below); shadow
 * rays through air are attenuated by it, scattering vertices in it use NEE and phase sampling.
 * Translucent objects displace fog (inside one, only its medium counts). Fog emission (radiance
 * per unit length, seed 003 §1.2.11) is gathered by the collision estimator of the same walk: at
 * each tentative collision, before the event is chosen, beta x emission / majorant. With the
 * majorant form of the RTE, L = integral m e^(-m t) [eps / m + (sigma_a / m) 0 + (sigma_s / m) L_s
 * + (sigma_n / m) L] dt, this term is the deterministic part of each collision, so adding it and
 * then sampling the event as before stays unbiased (for each channel, with spectral tracking's
 * weights in beta).
 *
 * The closed forms (Beer-Lambert transmittance, the height factor and its caps) are the shared
 * ones of volume/volume.h, which the real-time fog pass uses too.
 *
 * Units: distances along a ray are ray parameters of unit directions (scene units),
 * coefficients are per scene unit, throughputs (beta) are RGB.
 */
#include "pathtrace/pt_internal.h"

#ifdef NACRE_HAVE_EMBREE

/* Rest-pose point of world point p: the inverse object transform, then, for deformed objects,
 * the rest point stored in the voxel of the deformed mesh that holds it (nearest voxel: pattern
 * edges move by up to half a voxel; NaN outside the voxelized mesh, i.e. medium 1). */
void nc_pt_rest_point(const pt_object *o, nc_vec3 p, float out[3])
{
    nc_vec3 q = nc_mat4_point(&o->world_to_rest, p);
    if (!o->rest) {
        out[0] = q.x, out[1] = q.y, out[2] = q.z;
        return;
    }
    float qv[3] = {q.x, q.y, q.z};
    size_t idx[3];
    for (int a = 0; a < 3; a++) {
        float f = floorf((qv[a] - o->rorigin[a]) / o->rvoxel);
        f = f < 0 ? 0 : f > (float)(o->rdims[a] - 1) ? (float)(o->rdims[a] - 1) : f;
        idx[a] = (size_t)f;
    }
    const float *r = o->rest + 3 * (idx[0] + o->rdims[0] * (idx[1] + o->rdims[1] * idx[2]));
    out[0] = r[0], out[1] = r[1], out[2] = r[2];
}

/* Coefficients and phase anisotropy of layer j of object o. */
static inline void layer_medium(const pt_object *o, uint32_t j, float sa[3], float ss[3], float *g)
{
    memcpy(sa, o->layer_sa[j], sizeof(o->layer_sa[j]));
    memcpy(ss, o->layer_ss[j], sizeof(o->layer_ss[j]));
    *g = o->layer_g[j];
}

/* Coefficients and phase anisotropy at world point p inside object o. In a layered material the
 * rest point's depth below the rest-pose surface picks the layer (a non-finite rest point, outside
 * a deformed object's voxels, is in the core). */
static void medium_at(const pt_scene *ps, const pt_object *o, nc_vec3 p, float sa[3], float ss[3], float *g)
{
    *g = o->g;
    if (!o->heterogeneous) {
        memcpy(sa, o->sigma_a, sizeof(o->sigma_a));
        memcpy(ss, o->sigma_s, sizeof(o->sigma_s));
        return;
    }
    uint32_t j = o->layers.count, hint = UINT32_MAX; /* layer (count: the core) */
    bool located = o->layers.count == 0;
    if (o->lbits) {
        /* A cell that only one layer can reach settles the point without a nearest-point query
         * (deep inside, usually the core); in the others the cell's triangle bounds the query. */
        float pv[3] = {p.x, p.y, p.z};
        size_t idx[3];
        bool inside = true;
        for (int a = 0; a < 3; a++) {
            float f = (pv[a] - o->lmin[a]) * o->linv[a];
            inside &= f >= 0.0f && f < (float)o->lres;
            idx[a] = inside ? (size_t)f : 0;
        }
        size_t cell = idx[0] + o->lres * (idx[1] + o->lres * idx[2]);
        uint32_t bits = inside ? o->lbits[cell] : 0u;
        hint = inside ? o->lhint[cell] : UINT32_MAX;
        if (bits && !(bits & (bits - 1))) {
            j = (uint32_t)__builtin_ctz(bits);
            located = true;
        }
    }
    if (located && j < o->layers.count) {
        layer_medium(o, j, sa, ss, g); /* no rest point needed */
        return;
    }
    float xyz[3];
    nc_pt_rest_point(o, p, xyz);
    if (!located && isfinite(xyz[0]) && isfinite(xyz[1]) && isfinite(xyz[2])) {
        float uv[2];
        /* Beyond the deepest bottom any uv allows, every point is in the core. */
        float depth = nc_locator_nearest(o->loc, xyz, o->layers.hi[o->layers.count - 1], &hint, uv);
        j = nc_layers_find(&o->layers, depth, uv[0], uv[1]);
        if (j < o->layers.count) {
            layer_medium(o, j, sa, ss, g);
            return;
        }
    }
    ps->eval(ps->scene, o->mat, xyz, 1, sa, ss);
}

/* Segments of a ray with their majorants: one segment for homogeneous media and the global
 * majorant, otherwise the grid cells the ray crosses (DDA) and global-majorant pieces outside. */
typedef struct maj_iter {
    const pt_object *o;
    int phase; /* 0: before the grid, 1: in it, 2: after it, 3: done */
    float t, tmax, tin, tout;
    int cell[3], step[3];
    float tnext[3], tdelta[3];
} maj_iter;

static void maj_init(maj_iter *it, const pt_object *o, nc_vec3 org, nc_vec3 dir, float tmax)
{
    memset(it, 0, sizeof(*it));
    it->o = o;
    it->tmax = tmax;
    it->tin = it->tout = tmax; /* no grid: everything is "before the grid" */
    if (!o->grid)
        return;
    float ov[3] = {org.x, org.y, org.z}, dv[3] = {dir.x, dir.y, dir.z};
    float t0 = 0.0f, t1 = tmax;
    for (int a = 0; a < 3; a++) {
        float lo = o->gmin[a], hi = o->gmin[a] + o->cell[a] * (float)o->res;
        if (dv[a] == 0.0f) {
            if (ov[a] < lo || ov[a] > hi)
                t1 = -1.0f;
            continue;
        }
        float ta = (lo - ov[a]) / dv[a], tb = (hi - ov[a]) / dv[a];
        if (ta > tb) {
            float s = ta;
            ta = tb;
            tb = s;
        }
        t0 = fmaxf(t0, ta);
        t1 = fminf(t1, tb);
    }
    if (!(t0 < t1))
        return;
    it->tin = t0;
    it->tout = t1;
    float tm = 0.5f * (t0 + fminf(t1, t0 + 1e-3f * (t1 - t0)));
    for (int a = 0; a < 3; a++) {
        float p = ov[a] + dv[a] * tm;
        int c = (int)floorf((p - o->gmin[a]) / o->cell[a]);
        c = c < 0 ? 0 : c >= (int)o->res ? (int)o->res - 1 : c;
        it->cell[a] = c;
        if (dv[a] > 0) {
            it->step[a] = 1;
            it->tnext[a] = (o->gmin[a] + (float)(c + 1) * o->cell[a] - ov[a]) / dv[a];
            it->tdelta[a] = o->cell[a] / dv[a];
        } else if (dv[a] < 0) {
            it->step[a] = -1;
            it->tnext[a] = (o->gmin[a] + (float)c * o->cell[a] - ov[a]) / dv[a];
            it->tdelta[a] = -o->cell[a] / dv[a];
        } else {
            it->step[a] = 0;
            it->tnext[a] = INFINITY;
            it->tdelta[a] = INFINITY;
        }
    }
}

static bool maj_next(maj_iter *it, float *s0, float *s1, float *maj)
{
    const pt_object *o = it->o;
    for (;;) {
        switch (it->phase) {
        case 0:
            it->phase = 1;
            if (it->tin > 0.0f) {
                *s0 = 0.0f;
                *s1 = it->tin;
                *maj = o->maj_global;
                it->t = it->tin;
                return true;
            }
            it->t = it->tin;
            break;
        case 1: {
            if (it->t >= it->tout || !o->grid) {
                it->phase = 2;
                break;
            }
            int a = it->tnext[0] < it->tnext[1] ? (it->tnext[0] < it->tnext[2] ? 0 : 2) : (it->tnext[1] < it->tnext[2] ? 1 : 2);
            float end = fminf(it->tnext[a], it->tout);
            *s0 = it->t;
            *s1 = end;
            *maj = o->grid[(size_t)it->cell[0] + o->res * ((size_t)it->cell[1] + o->res * (size_t)it->cell[2])];
            it->t = end;
            it->cell[a] += it->step[a];
            it->tnext[a] += it->tdelta[a];
            if (it->cell[a] < 0 || it->cell[a] >= (int)o->res)
                it->tout = fminf(it->tout, end); /* left the grid */
            return true;
        }
        case 2:
            it->phase = 3;
            if (it->tout < it->tmax) {
                *s0 = it->tout;
                *s1 = it->tmax;
                *maj = o->maj_global;
                return true;
            }
            break;
        default:
            return false;
        }
    }
}

/* ---- fog: participating media in open space ----------------------------------------------
 *
 * Fogs fill the air (the path is in no object). Along a ray each fog occupies one interval (a box
 * clipped by the slab test in its local frame, an ellipsoid's chord, or everything), and their coefficients add. The
 * majorant of a piece of the ray is the sum over the fogs present of their pattern bound times
 * the largest height() on the piece; height() = exp(-falloff (y - base)) is monotone in y, so its
 * largest value is at the lower end, and pieces are cut where height() changes by a factor of 2
 * (y steps of ln 2 / falloff) so that null collisions stay below half of the tentative ones. A
 * ray climbing out of height fog would produce ever thinner pieces forever: the walk stops when
 * no fog lies ahead and the optical depth that the majorants of every remaining piece could add
 * is below FOG_TAIL (a transmittance error below 1e-7, under float resolution). Where a piece's
 * majorant optical depth is below FOG_THIN (thin fog, or steep falloff: 1e4 per unit cut a ray
 * into 1e4 pieces per unit of height), the piece doubles in length while it stays below: it
 * then costs one tentative collision in a thousand, and thin stretches are crossed in a few
 * pieces. A fog's density (sigma_t times height()) is capped at NC_VOL_MAX_DENSITY per scene unit,
 * a free path far below float resolution at any scene scale, so that tracking weights (products
 * of two densities) stay finite. */
#define FOG_TAIL 1e-7f
#define FOG_THIN 1e-3f
#define FOG_LN2 0.69314718f

static float fog_height(const pt_fog *f, float y)
{
    return nc_vol_height_factor(f->height, f->falloff, f->base, f->hexp, y);
}

typedef struct fog_iter {
    const pt_scene *ps;
    nc_vec3 org, dir;
    float t, tmax;
    float a[NACRE_MAX_FOGS], b[NACRE_MAX_FOGS]; /* each fog's interval on the ray */
} fog_iter;

static void fog_init(fog_iter *it, const pt_scene *ps, nc_vec3 org, nc_vec3 dir, float tmax)
{
    const nc_pathtracer *pt = ps->pt;
    it->ps = ps;
    it->org = org;
    it->dir = dir;
    it->t = 0.0f;
    it->tmax = tmax;
    for (uint32_t i = 0; i < pt->fog_count; i++) {
        const pt_fog *f = &pt->fogs[i];
        float t0 = 0.0f, t1 = tmax;
        if (f->ellipsoid) {
            nc_vec3 q = nc_mat4_point(&f->rec->world_to_local, org), v = nc_mat4_dir(&f->rec->world_to_local, dir);
            double qv[3] = {q.x, q.y, q.z}, vv[3] = {v.x, v.y, v.z}, half[3] = {f->half[0], f->half[1], f->half[2]};
            double a = 0.0, b = tmax;
            if (nc_vol_shape_segment(true, half, qv, vv, &a, &b))
                t0 = (float)a, t1 = (float)b;
            else
                t1 = -1.0f;
        } else if (f->box) {
            /* The slab test in float, as the path tracer has always cut boxes. */
            nc_vec3 q = nc_mat4_point(&f->rec->world_to_local, org), v = nc_mat4_dir(&f->rec->world_to_local, dir);
            float qv[3] = {q.x, q.y, q.z}, vv[3] = {v.x, v.y, v.z};
            for (int a = 0; a < 3; a++) {
                if (vv[a] == 0.0f) {
                    if (fabsf(qv[a]) > f->half[a])
                        t1 = -1.0f;
                    continue;
                }
                float ta = (-f->half[a] - qv[a]) / vv[a], tb = (f->half[a] - qv[a]) / vv[a];
                t0 = fmaxf(t0, fminf(ta, tb));
                t1 = fminf(t1, fmaxf(ta, tb));
            }
        }
        if (!(t0 < t1))
            t0 = t1 = INFINITY; /* never present */
        it->a[i] = t0;
        it->b[i] = t1;
    }
}

static bool fog_next(fog_iter *it, float *s0, float *s1, float *maj)
{
    const nc_pathtracer *pt = it->ps->pt;
    while (it->t < it->tmax) {
        float t = it->t, next = it->tmax, m = 0.0f, rest = 0.0f;
        bool ahead = false;
        for (uint32_t i = 0; i < pt->fog_count; i++) {
            const pt_fog *f = &pt->fogs[i];
            if (!(it->b[i] > t))
                continue;
            if (it->a[i] > t) {
                next = fminf(next, it->a[i]);
                ahead = true;
                continue;
            }
            float end = it->b[i], mi = f->maj;
            float y0 = it->org.y + it->dir.y * t;
            if (f->height && fabsf(it->dir.y) > 1e-20f) { /* else: level, constant density */
                float len = FOG_LN2 / (f->falloff * fabsf(it->dir.y)), stop = fminf(end, it->tmax);
                if (f->maj * fog_height(f, fminf(y0, y0 + it->dir.y * len)) * len < FOG_THIN)
                    for (int k = 0; k < 128 && t + len < stop; k++) {
                        float l2 = 2.0f * len;
                        if (!(f->maj * fog_height(f, fminf(y0, y0 + it->dir.y * l2)) * l2 < FOG_THIN))
                            break;
                        len = l2;
                    }
                end = fminf(end, t + len);
                float y1 = it->org.y + it->dir.y * end;
                mi *= fog_height(f, fminf(y0, y1));
                /* Optical depth still ahead, bounded: rising, the integral of the height
                 * profile to infinity; falling, the densest point (the far end) times length. */
                if (it->dir.y > 0)
                    rest += f->maj * fog_height(f, y0) / (f->falloff * it->dir.y);
                else
                    rest += isfinite(it->b[i]) ? f->maj * fog_height(f, it->org.y + it->dir.y * it->b[i]) * (it->b[i] - t)
                                               : INFINITY;
            } else {
                mi *= fog_height(f, y0);
                rest += mi * (it->b[i] - t);
            }
            m += mi;
            next = fminf(next, end);
        }
        if (!ahead && rest < FOG_TAIL)
            return false;
        *s0 = t;
        *s1 = next;
        *maj = m;
        it->t = next;
        return true;
    }
    return false;
}

/* One fog's coefficients at the point of parameter t (inside its interval), or 0. */
static bool fog_one(const fog_iter *it, uint32_t i, float t, nc_vec3 p, float sa[3], float ss[3])
{
    const pt_fog *f = &it->ps->pt->fogs[i];
    if (!(it->a[i] <= t && t < it->b[i]))
        return false;
    if (f->patterned) {
        nc_vec3 q = nc_mat4_point(&f->rec->world_to_local, p);
        float qv[3] = {q.x, q.y, q.z};
        it->ps->eval(it->ps->scene, &f->rec->medium, qv, 1, sa, ss);
    } else {
        memcpy(sa, f->rec->desc.sigma_a, 3 * sizeof(float));
        memcpy(ss, f->rec->desc.sigma_s, 3 * sizeof(float));
    }
    float h = fog_height(f, p.y);
    for (int c = 0; c < 3; c++) {
        sa[c] *= h;
        ss[c] *= h;
    }
    return true;
}

/* The fogs' emission at the point of parameter t (summed; height factor and pattern as sigma). */
static void fog_emission_at(const fog_iter *it, float t, nc_vec3 p, float em[3])
{
    em[0] = em[1] = em[2] = 0.0f;
    for (uint32_t i = 0; i < it->ps->pt->fog_count; i++) {
        const pt_fog *f = &it->ps->pt->fogs[i];
        if (!f->emissive || !(it->a[i] <= t && t < it->b[i]))
            continue;
        float e[3], unused[3];
        if (f->emission_patterned) {
            nc_vec3 q = nc_mat4_point(&f->rec->world_to_local, p);
            float qv[3] = {q.x, q.y, q.z};
            it->ps->eval(it->ps->scene, &f->rec->emission, qv, 1, e, unused);
        } else {
            memcpy(e, f->rec->desc.emission, sizeof(e));
        }
        float h = fog_height(f, p.y);
        for (int c = 0; c < 3; c++)
            em[c] += e[c] * h;
    }
}

static void fog_at(const fog_iter *it, float t, nc_vec3 p, float sa[3], float ss[3])
{
    sa[0] = sa[1] = sa[2] = ss[0] = ss[1] = ss[2] = 0.0f;
    for (uint32_t i = 0; i < it->ps->pt->fog_count; i++) {
        float a[3], b[3];
        if (fog_one(it, i, t, p, a, b))
            for (int c = 0; c < 3; c++) {
                sa[c] += a[c];
                ss[c] += b[c];
            }
    }
}

/* Where fogs of different g overlap, the phase function is their mix weighted by each fog's
 * sigma_s, per channel. A scattering picks fog i with probability P_i proportional to
 * sum_c beta_c sigma_s,i,c and weights channel c by sigma_s,i,c / (sigma_s,c P_i): unbiased, and
 * NEE and phase sampling then use one HG lobe. */
static float fog_pick_phase(const fog_iter *it, float t, nc_vec3 p, nc_vec3 *beta, nc_rng *rng)
{
    const nc_pathtracer *pt = it->ps->pt;
    if (!pt->fog_mixed_g)
        return pt->fogs[0].g;
    float ss_i[NACRE_MAX_FOGS][3], ss[3] = {0, 0, 0}, w[NACRE_MAX_FOGS], wsum = 0.0f;
    float b[3] = {fabsf(beta->x), fabsf(beta->y), fabsf(beta->z)};
    for (uint32_t i = 0; i < pt->fog_count; i++) {
        float sa[3];
        if (!fog_one(it, i, t, p, sa, ss_i[i]))
            ss_i[i][0] = ss_i[i][1] = ss_i[i][2] = 0.0f;
        w[i] = b[0] * ss_i[i][0] + b[1] * ss_i[i][1] + b[2] * ss_i[i][2];
        wsum += w[i];
        for (int c = 0; c < 3; c++)
            ss[c] += ss_i[i][c];
    }
    if (!(wsum > 0.0f))
        return pt->fogs[0].g;
    float u = nc_rng_float(rng) * wsum, acc = 0.0f;
    uint32_t k = 0;
    for (uint32_t i = 0; i < pt->fog_count; i++) {
        if (!(w[i] > 0.0f))
            continue;
        k = i; /* the last positive one if rounding leaves u >= the sum */
        acc += w[i];
        if (u < acc)
            break;
    }
    float P = w[k] / wsum;
    float wc[3];
    for (int c = 0; c < 3; c++)
        wc[c] = ss[c] > 0.0f ? ss_i[k][c] / (ss[c] * P) : 0.0f;
    *beta = nc_v3(beta->x * wc[0], beta->y * wc[1], beta->z * wc[2]);
    return pt->fogs[k].g;
}

/* The part [*t0, *t1] of [0, tmax] where some fog is present (false: none), for equiangular
 * sampling (integrator.c), which should not spend samples where no fog can scatter. */
bool nc_pt_fog_span(const pt_scene *ps, nc_vec3 org, nc_vec3 dir, float tmax, float *t0, float *t1)
{
    fog_iter it;
    fog_init(&it, ps, org, dir, tmax);
    float a = INFINITY, b = -INFINITY;
    for (uint32_t i = 0; i < ps->pt->fog_count; i++)
        if (it.a[i] < it.b[i]) {
            a = fminf(a, it.a[i]);
            b = fmaxf(b, it.b[i]);
        }
    *t0 = a;
    *t1 = fminf(b, tmax);
    return a < *t1;
}

/* The fogs' coefficients at parameter t of the ray (summed) and, as at a scattering there, the
 * phase's g (fog_pick_phase: weights *beta where fogs of different g overlap; beta NULL: no g). */
float nc_pt_fog_point(const pt_scene *ps, nc_vec3 org, nc_vec3 dir, float tmax, float t, float sa[3], float ss[3],
                      nc_vec3 *beta, nc_rng *rng)
{
    fog_iter it;
    fog_init(&it, ps, org, dir, tmax);
    nc_vec3 p = ray_at(org, dir, t);
    fog_at(&it, t, p, sa, ss);
    return beta ? fog_pick_phase(&it, t, p, beta, rng) : 0.0f;
}

/* Tentative collisions along the ray: exponential steps at each piece's majorant (delta,
 * spectral and ratio tracking all walk this way; they differ in what they do at a collision).
 * In an object's medium (o) the pieces come from its majorant grid, in the air from the fogs. */
typedef struct collision_walk {
    const pt_object *o; /* NULL: fog */
    maj_iter it;
    fog_iter fog;
    float t, s1, m;
    bool in_piece;
    pt_budget *budget;
} collision_walk;

static void walk_init(collision_walk *w, const pt_scene *ps, const pt_object *o, nc_vec3 org, nc_vec3 dir, float tmax)
{
    w->o = o;
    w->budget = ps->budget;
    if (o)
        maj_init(&w->it, o, org, dir, tmax);
    else
        fog_init(&w->fog, ps, org, dir, tmax);
    w->in_piece = false;
}

/* The next tentative collision distance *t and the majorant *m there; false past tmax, or when
 * the path's budget runs out (the caller then checks budget->stop). */
static bool walk_next(collision_walk *w, nc_rng *rng, float *t, float *m)
{
    for (;;) {
        if (!budget_collision(w->budget))
            return false;
        if (!w->in_piece) {
            float s0;
            if (!(w->o ? maj_next(&w->it, &s0, &w->s1, &w->m) : fog_next(&w->fog, &s0, &w->s1, &w->m)))
                return false;
            if (!(w->m > 0.0f))
                continue;
            w->t = s0;
            w->in_piece = true;
        }
        w->t -= logf(1.0f - nc_rng_float(rng)) / w->m;
        if (w->t >= w->s1) {
            w->in_piece = false;
            continue;
        }
        *t = w->t;
        *m = w->m;
        return true;
    }
}

/* The coefficients at the walk's collision t, point p (and, in an object, the phase's g). */
static void walk_medium(const pt_scene *ps, const collision_walk *w, float t, nc_vec3 p, float sa[3], float ss[3],
                        float *g)
{
    if (w->o)
        medium_at(ps, w->o, p, sa, ss, g);
    else
        fog_at(&w->fog, t, p, sa, ss);
}

/* The weights of a flight of length t sampled by flight_sample_homogeneous, given the boundary
 * at tmax. Sampling (two random numbers) comes first so that the caller can decide from t
 * alone whether it needs the boundary (see nc_pt_clearance()). */
ff_event nc_pt_flight_resolve_homogeneous(const pt_object *o, float t, float tmax, nc_vec3 *beta, float *t_out)
{
    float b[3] = {fabsf(beta->x), fabsf(beta->y), fabsf(beta->z)}, st[3];
    float bsum = b[0] + b[1] + b[2];
    for (int c = 0; c < 3; c++)
        st[c] = o->sigma_a[c] + o->sigma_s[c];
    float tr[3], pdf = 0.0f;
    if (t >= tmax) {
        for (int c = 0; c < 3; c++) {
            tr[c] = nc_vol_transmittance(st[c], tmax);
            pdf += b[c] / bsum * tr[c];
        }
        if (!(pdf > 0.0f))
            return FF_ABSORB;
        *beta = nc_v3(beta->x * tr[0] / pdf, beta->y * tr[1] / pdf, beta->z * tr[2] / pdf);
        return FF_PASS;
    }
    for (int c = 0; c < 3; c++) {
        tr[c] = nc_vol_transmittance(st[c], t);
        pdf += b[c] / bsum * st[c] * tr[c];
    }
    if (!(pdf > 0.0f))
        return FF_ABSORB;
    *beta = nc_v3(beta->x * o->sigma_s[0] * tr[0] / pdf, beta->y * o->sigma_s[1] * tr[1] / pdf,
                  beta->z * o->sigma_s[2] * tr[2] / pdf);
    *t_out = t;
    return FF_SCATTER;
}

/* Spectral tracking from org along dir over [0, tmax] in a heterogeneous medium (o) or the fog
 * (o == NULL): FF_SCATTER with *t_out and the phase's *g_out, FF_PASS at tmax, or FF_ABSORB.
 * beta is updated by the per-channel weights. In fog, *emitted (if not NULL) gets the emission
 * gathered on the way, weighted by the throughput (the caller adds it to the path's radiance). */
ff_event nc_pt_free_flight(const pt_scene *ps, const pt_object *o, nc_vec3 org, nc_vec3 dir, float tmax,
                           nc_rng *rng, nc_vec3 *beta, float *t_out, float *g_out, nc_vec3 *emitted)
{
    collision_walk w;
    walk_init(&w, ps, o, org, dir, tmax);
    bool emission = !o && emitted && ps->pt->fog_emissive;
    float t, m;
    while (walk_next(&w, rng, &t, &m)) {
        float sa[3], ss[3], g = 0.0f;
        nc_vec3 p = ray_at(org, dir, t);
        walk_medium(ps, &w, t, p, sa, ss, &g);
        float b[3] = {beta->x, beta->y, beta->z};
        if (emission) {
            float em[3];
            fog_emission_at(&w.fog, t, p, em);
            *emitted = nc_add(*emitted, nc_v3(b[0] * em[0] / m, b[1] * em[1] / m, b[2] * em[2] / m));
        }
        float pa = 0, pss = 0, pn = 0;
        for (int c = 0; c < 3; c++) {
            pa += b[c] * sa[c];
            pss += b[c] * ss[c];
            pn += b[c] * fabsf(m - sa[c] - ss[c]);
        }
        float sum = pa + pss + pn;
        if (!(sum > 0.0f))
            return FF_ABSORB;
        float u = nc_rng_float(rng) * sum;
        if (u < pa)
            return FF_ABSORB;
        if (u < pa + pss) {
            float k = sum / (m * pss);
            *beta = nc_v3(b[0] * ss[0] * k, b[1] * ss[1] * k, b[2] * ss[2] * k);
            *t_out = t;
            *g_out = o ? g : fog_pick_phase(&w.fog, t, p, beta, rng);
            return FF_SCATTER;
        }
        float k = sum / (m * pn);
        *beta = nc_v3(b[0] * (m - sa[0] - ss[0]) * k, b[1] * (m - sa[1] - ss[1]) * k, b[2] * (m - sa[2] - ss[2]) * k);
    }
    return ps->budget->stop ? FF_ABSORB : FF_PASS;
}

/* Transmittance along [0, tmax]: exact for homogeneous media, ratio tracking otherwise (and in
 * fog, o == NULL). */
nc_vec3 nc_pt_transmittance(const pt_scene *ps, const pt_object *o, nc_vec3 org, nc_vec3 dir, float tmax, nc_rng *rng)
{
    if (o && !o->heterogeneous)
        return nc_v3(nc_vol_transmittance(o->sigma_a[0] + o->sigma_s[0], tmax),
                     nc_vol_transmittance(o->sigma_a[1] + o->sigma_s[1], tmax),
                     nc_vol_transmittance(o->sigma_a[2] + o->sigma_s[2], tmax));
    nc_vec3 tr = nc_v3(1, 1, 1);
    collision_walk w;
    walk_init(&w, ps, o, org, dir, tmax);
    float t, m;
    while (walk_next(&w, rng, &t, &m)) {
        float sa[3], ss[3], g;
        walk_medium(ps, &w, t, ray_at(org, dir, t), sa, ss, &g);
        tr = nc_v3(tr.x * (1.0f - (sa[0] + ss[0]) / m), tr.y * (1.0f - (sa[1] + ss[1]) / m),
                   tr.z * (1.0f - (sa[2] + ss[2]) / m));
        /* Russian roulette on small estimates keeps long ratio-tracking walks cheap. */
        float mx = fmaxf(fabsf(tr.x), fmaxf(fabsf(tr.y), fabsf(tr.z)));
        if (mx < 0.1f) {
            if (nc_rng_float(rng) >= 0.5f)
                return nc_v3(0, 0, 0);
            tr = nc_scale(tr, 2.0f);
        }
    }
    return ps->budget->stop ? nc_v3(0, 0, 0) : tr;
}

#endif /* NACRE_HAVE_EMBREE */
