/*
 * pt_internal.h: private to src/pathtrace: the types and constants shared by the files of the
 * scene path tracer (integrator.c has the overview of the method and the list of files), the
 * functions one file calls in another (named nc_pt_*), and the small per-vertex helpers of every
 * concept, static inline (see "inline helpers" below for why they live here).
 *
 * Conventions: lengths in scene units, coefficients per scene unit, RGB throughputs and
 * radiances as nc_vec3; directions are unit vectors; pdfs are per unit solid angle.
 */
#ifndef NACRE_PT_INTERNAL_H
#define NACRE_PT_INTERNAL_H

#include "pathtrace/pathtrace.h"

#ifdef NACRE_HAVE_EMBREE

#include "core/optics.h"
#include "pathtrace/rng.h"
#include "layered/layers.h"
#include "scene/lights.h"
#include "scene/medium.h"
#include "scene/scene.h"
#include "volume/volume.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <embree3/rtcore.h>

#define PT_PI 3.14159265358979323846f
#define MAX_VERTICES 65536 /* real vertices per path; walks this long carry ~0 weight */
#define RR_START 8 /* vertices before Russian roulette (see integrator.c) */
#define MAX_CROSSINGS 256 /* index-matched boundaries a shadow ray may pass */
/* Caps that end pathological paths (see "Caps and the time limit" in README.md): tentative
 * collisions of every tracking walk of a path (free flights and shadow rays, majorant pieces
 * included), and the clock is read every DEADLINE_STRIDE units of work. */
#define MAX_PATH_COLLISIONS (1u << 20)
#define DEADLINE_STRIDE 1024u

enum { PT_OPAQUE = 0, PT_DIELECTRIC, PT_MATCHED };

typedef struct pt_object {
    int kind;
    bool casts;              /* blocks shadow rays (cast_shadows; always for non-opaque objects) */
    const nacre_material_desc *mat;
    const float *pos;       /* world positions */
    const float *nrm;       /* world normals */
    const uint32_t *idx;
    const float *uv;         /* the mesh's uvs, or NULL (read for an opaque diffuse_map) */
    bool heterogeneous;
    float sigma_a[3], sigma_s[3]; /* homogeneous media */
    float g, eta;
    float maj_global;        /* scalar majorant: max over channels of the sigma_t bound */
    nc_mat4 world_to_rest;
    float *rest;             /* deformed heterogeneous objects: rest-pose point per voxel of the
                                deformed object-space mesh (nacre_voxel_grid_rest_positions) */
    uint32_t rdims[3];
    float rorigin[3], rvoxel;
    nc_layer_stack layers;   /* count > 0: layers above the core (see layered/layers.h) */
    nc_surface_locator *loc; /* layered: nearest points of the rest-pose mesh */
    float layer_sa[NACRE_MAX_LAYERS][3], layer_ss[NACRE_MAX_LAYERS][3], layer_g[NACRE_MAX_LAYERS];
    uint8_t *lbits;          /* layered, not deformed: per cell of an lres^3 grid over the world
                                bounds, the layers (bit count: core) its points may be in */
    uint32_t *lhint;         /* per cell, the triangle nearest its centre (UINT32_MAX: none near):
                                it bounds the nearest-point search of points in the cell */
    uint32_t lres;
    float lmin[3], linv[3];
    float *grid;             /* majorant grid (heterogeneous, res^3) or NULL */
    uint32_t res;
    float gmin[3], cell[3];
    uint32_t tri_count;
    float *sun_dir;          /* dielectric objects with a guided sun: per triangle the sun refracted
                                through it, pointing back out (x = NaN: none; see refract_sun) */
    uint32_t *adj;           /* dielectric objects: per triangle and edge (v0v1, v1v2, v2v0) the
                                triangle across it, UINT32_MAX if none (see build_adjacency) */
    uint8_t *dist;           /* media: clearance grid (see build_clearance) or NULL */
    uint32_t ddims[3];
    float dorigin[3], dcell, dinv, dmargin;
} pt_object;

typedef struct pt_light {
    int type;
    bool delta;
    nc_vec3 to_light;       /* directional: unit direction towards the light */
    float cos_max;          /* directional: cos of the angular radius */
    float cone_pdf;         /* directional: 1 / solid angle */
    nc_vec3 pos;
    float radius;
    nc_vec3 value;          /* delta: E or I; area: radiance */
    const nacre_light_desc *desc;
} pt_light;

/* A fog of the scene (see "fog" in media.c). */
typedef struct pt_fog {
    const nc_fog_rec *rec;
    bool box, ellipsoid, patterned, height, emissive, emission_patterned;
    float half[3];        /* box: half edge lengths (ellipsoid: semi-axes) */
    float maj;            /* scalar bound of sigma_t where height() = 1 */
    float falloff, base, g;
    float hexp;           /* cap of height()'s exponent: at most 60, and maj e^hexp <= NC_VOL_MAX_DENSITY */
} pt_fog;

struct nc_pathtracer {
    nacre_context *ctx;
    nc_pathtrace_options opt;
    RTCDevice device;
    RTCScene rtc;
    pt_object *objects;
    uint32_t object_count;
    pt_light *lights;
    uint32_t light_count;
    pt_fog fogs[NACRE_MAX_FOGS];
    uint32_t fog_count;
    bool fog_mixed_g;      /* fogs differ in g: a scattering picks one fog's phase */
    bool fog_emissive;     /* some fog emits (nc_pt_free_flight gathers it) */
    bool any_matched;      /* some object is index matched (shadow rays may pass surfaces) */
    bool any_noncaster;    /* some opaque object has cast_shadows = false */
    bool nee_only;         /* shadow rays see another world than paths: no MIS (see integrator.c)  */
    /* What the fields above were built from (nc_pt_prepare_scene): a frame of the same scene
     * whose committed versions differ at most in the camera reuses them. */
    bool built_valid;
    uint64_t built_uid;
    nc_versions built_versions; /* camera not compared */
    int32_t width, height;
    double *mean, *m2;     /* per pixel and channel */
    uint32_t *count;       /* per pixel: samples in mean and m2 */
    size_t pixel_capacity;
    bool valid;            /* a frame was rendered into mean/m2 */
    /* What mean/m2/count accumulate (see "Accumulation" in integrator.c): an accumulating frame
     * with all of these unchanged adds to them, anything else restarts. */
    uint64_t acc_uid;
    nc_versions acc_versions;
    uint32_t acc_seed, acc_max_scatter;
    uint32_t acc_frames;   /* frames in the accumulators since the last restart */
    uint64_t acc_samples;  /* camera paths in the accumulators (sum of count) */
};

/* Per-path work (see MAX_PATH_COLLISIONS): a path stops when it reaches a cap (its estimate so
 * far is kept: later events contribute zero) or when the render's deadline passes (the caller
 * drops the sample). */
typedef struct pt_budget {
    uint64_t deadline_us; /* 0: none */
    uint32_t collisions;  /* tentative collisions and majorant pieces of the current path */
    uint32_t until_check; /* work units before the next clock read */
    bool stop, capped, expired;
} pt_budget;

static inline void budget_reset(pt_budget *b, uint64_t deadline_us)
{
    b->deadline_us = deadline_us;
    b->collisions = 0;
    b->until_check = DEADLINE_STRIDE;
    b->stop = b->capped = b->expired = false;
}

/* One unit of work that is not a collision (a path vertex); false: the path must stop. */
static inline bool budget_tick(pt_budget *b)
{
    if (b->stop)
        return false;
    if (b->deadline_us && --b->until_check == 0) {
        b->until_check = DEADLINE_STRIDE;
        if (nc_now_us() >= b->deadline_us) {
            b->stop = b->expired = true;
            return false;
        }
    }
    return true;
}

/* One tentative collision or majorant piece; false: the path must stop. */
static inline bool budget_collision(pt_budget *b)
{
    if (!budget_tick(b))
        return false;
    if (++b->collisions > MAX_PATH_COLLISIONS) {
        b->stop = b->capped = true;
        return false;
    }
    return true;
}

/* Everything a path needs, read-only during a pass (but for the budget of the path in flight). */
typedef struct pt_scene {
    const nacre_scene *scene;
    const nc_pathtracer *pt;
    nc_pt_medium_eval_fn eval;
    nc_vec3 env;
    bool env_on;
    float eps;
    uint32_t max_scatter;
    pt_budget *budget;     /* the current path's (each thread has its own) */
} pt_scene;

typedef struct pt_hit {
    bool hit;
    float t;
    uint32_t obj, prim;
    float u, v;
} pt_hit;

typedef enum { FF_PASS = 0, FF_SCATTER, FF_ABSORB } ff_event;

/* Clearance grids: see nc_pt_clearance() in scene_setup.c. */
#ifndef CLEAR_STEPS
#define CLEAR_STEPS 4        /* further bounds looked up along a flight before asking Embree */
#endif

/* The guided sun technique (sun_guide.c): refractions of the guide axis, and the guide cones. */
#define GUIDE_ITERATIONS 4
#define GUIDE_CONE_SCALE 1.05f /* guide cone half-angle over the sun's */
/* A fraction of the guided samples goes to a wider cone, so that where the axis is off (the
 * iteration stopped between two facets of a curved surface) phase-sampled paths into the sun
 * still meet a guided density far above theirs, rather than scoring the sun's full radiance
 * with MIS weight 1 (fireflies of ~4e4 seen on the demo's torus with the narrow cone alone). */
#define GUIDE_WIDE_FRACTION 0.1f
#define GUIDE_WIDE_ANGLE 0.05f /* radians, about 3 degrees */

/* The guide at a vertex: the axis that refracts out towards the sun and the cones around it. */
typedef struct guide {
    bool valid;
    nc_vec3 axis;
    float cos_a, pdf;     /* narrow cone: cos of its half-angle, its own uniform pdf */
    float cos_w, pdf_w;   /* wide cone, the same */
} guide;

/* Where the walk over the mesh from the seed facet ended (see nc_pt_walk_guide). */
typedef struct guide_walk {
    uint32_t prim;    /* the facet reached, UINT32_MAX if the seed gave nothing */
    nc_vec3 dir;      /* the sun refracted through it, pointing back out */
    bool done;        /* the ray p + t dir leaves through prim (or the walk went back and forth
                         between two facets: the axis is as good as it gets) ... */
    float t;          /* ... at this t */
} guide_walk;

/* ---- functions shared between the files (each defined in the file named) ------------------ */

/* media.c */
void nc_pt_rest_point(const pt_object *o, nc_vec3 p, float out[3]);
ff_event nc_pt_flight_resolve_homogeneous(const pt_object *o, float t, float tmax, nc_vec3 *beta, float *t_out);
ff_event nc_pt_free_flight(const pt_scene *ps, const pt_object *o, nc_vec3 org, nc_vec3 dir, float tmax,
                           nc_rng *rng, nc_vec3 *beta, float *t_out, float *g_out, nc_vec3 *emitted);
nc_vec3 nc_pt_transmittance(const pt_scene *ps, const pt_object *o, nc_vec3 org, nc_vec3 dir, float tmax, nc_rng *rng);
bool nc_pt_fog_span(const pt_scene *ps, nc_vec3 org, nc_vec3 dir, float tmax, float *t0, float *t1);
float nc_pt_fog_point(const pt_scene *ps, nc_vec3 org, nc_vec3 dir, float tmax, float t, float sa[3], float ss[3],
                      nc_vec3 *beta, nc_rng *rng);

/* lights.c */
nc_vec3 nc_pt_shadow(const pt_scene *ps, nc_vec3 p, nc_vec3 wi, float dist, int medium, nc_rng *rng);
typedef struct pt_eq pt_eq;
nc_vec3 nc_pt_direct_light(const pt_scene *ps, nc_vec3 p, nc_vec3 ng, bool surface, const nacre_material_desc *m,
                           nc_vec3 n, nc_vec3 wo, float g, int medium, float q, const pt_eq *eq, nc_rng *rng);
nc_vec3 nc_pt_direct_one(const pt_scene *ps, uint32_t li, nc_vec3 p, nc_vec3 d, float g, nc_rng *rng);

/* sun_guide.c */
bool nc_pt_refract_sun_facet(const pt_object *ob, const pt_light *l, uint32_t prim, nc_vec3 *dir);
guide_walk nc_pt_walk_guide(const pt_object *ob, const pt_light *l, nc_vec3 p, uint32_t seed);
guide nc_pt_make_guide(const pt_scene *ps, uint32_t obj, const pt_light *l, nc_vec3 p, const guide_walk *gw, uint32_t *last);

/* surfaces.c */
nc_vec3 nc_pt_around(nc_vec3 n, float cos_t, float u);
nc_vec3 nc_pt_bsdf_eval(const nacre_material_desc *m, nc_vec3 n, nc_vec3 wo, nc_vec3 wi, float *pdf);

/* scene_setup.c */
void nc_pt_surface_at(const pt_object *o, const pt_hit *h, nc_vec3 *p, nc_vec3 *ng, nc_vec3 *ns);
/* The opaque material of object o at hit h: o->mat, or with a diffuse_map a copy in *tmp whose
 * diffuse is multiplied by the texture at the hit's uv. */
const nacre_material_desc *nc_pt_material_at(const pt_scene *ps, const pt_object *o, const pt_hit *h,
                                             nacre_material_desc *tmp);
float nc_pt_clearance(const pt_object *o, nc_vec3 p);
void nc_pt_release_scene(nc_pathtracer *pt);
nacre_result nc_pt_build_scene(nc_pathtracer *pt, const nacre_scene *s, pt_scene *ps);
bool nc_pt_scene_settled(const nacre_scene *s);
nacre_result nc_pt_prepare_scene(nc_pathtracer *pt, const nacre_scene *s, pt_scene *ps);

/* ---- inline helpers ----------------------------------------------------------------------
 *
 * Small functions of every concept that the path loop calls per vertex. When the path tracer
 * was one file (pathtrace.c) the compiler inlined exactly these into trace_path,
 * nc_pt_direct_light and nc_pt_make_guide; they stay inline here so that it still does, for
 * speed and so that the images stay the same bit for bit: with -ffp-contract=fast, whether a
 * product meets a sum across a call decides where the compiler fuses them into an FMA. The
 * functions it kept out of line (nc_pt_around, nc_pt_surface_at, nc_pt_clearance,
 * nc_pt_bsdf_eval, the flights, ...) are defined in their files, and must stay out of line
 * (not static inline here) for the same reason. Moving a function between the two groups
 * changes images in the last bits. */

static inline float max3(nc_vec3 v) { return fmaxf(v.x, fmaxf(v.y, v.z)); }
static inline float comp(nc_vec3 v, int c) { return c == 0 ? v.x : c == 1 ? v.y : v.z; }
static inline nc_vec3 ray_at(nc_vec3 o, nc_vec3 d, float t) { return nc_add(o, nc_scale(d, t)); }
static inline float power_heuristic(float a, float b) { return a * a / (a * a + b * b); }

static inline pt_hit intersect(const pt_scene *ps, nc_vec3 o, nc_vec3 d, float tfar)
{
    struct RTCIntersectContext ictx;
    rtcInitIntersectContext(&ictx);
    struct RTCRayHit rh;
    rh.ray.org_x = o.x;
    rh.ray.org_y = o.y;
    rh.ray.org_z = o.z;
    rh.ray.dir_x = d.x;
    rh.ray.dir_y = d.y;
    rh.ray.dir_z = d.z;
    rh.ray.tnear = 0.0f;
    rh.ray.tfar = tfar;
    rh.ray.time = 0.0f;
    rh.ray.mask = 0xffffffffu;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(ps->pt->rtc, &ictx, &rh);
    pt_hit h;
    h.hit = rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
    h.t = rh.ray.tfar;
    h.obj = rh.hit.geomID;
    h.prim = rh.hit.primID;
    h.u = rh.hit.u;
    h.v = rh.hit.v;
    return h;
}

/* Start point for a ray leaving surface point p in direction d: pushed off the surface to the
 * side d goes, so the ray does not find its own triangle again. */
static inline nc_vec3 offset_origin(const pt_scene *ps, nc_vec3 p, nc_vec3 ng, nc_vec3 d)
{
    float s = nc_dot(d, ng) >= 0 ? ps->eps : -ps->eps;
    return nc_add(p, nc_scale(ng, s));
}

static inline void sample_uniform_sphere(float u1, float u2, nc_vec3 *w)
{
    float z = 1.0f - 2.0f * u1, r = sqrtf(fmaxf(0.0f, 1.0f - z * z)), phi = 2.0f * PT_PI * u2;
    *w = nc_v3(r * cosf(phi), r * sinf(phi), z);
}

/* -- media (media.c) */

/* Homogeneous media need no null collisions: the distance is sampled from the exponential of one
 * channel, chosen with probability proportional to the path throughput (hero channel, Wilkie et
 * al. 2014 spectral MIS with the history-aware choice of Kutz et al. 2017), and every channel is
 * weighted by its own density over the mixture density (one-sample balance heuristic). Grey media
 * reduce to weight = albedo per scattering. */
static inline bool flight_sample_homogeneous(const pt_object *o, nc_vec3 beta, nc_rng *rng, float *t)
{
    float b[3] = {fabsf(beta.x), fabsf(beta.y), fabsf(beta.z)};
    float bsum = b[0] + b[1] + b[2];
    if (!(bsum > 0.0f))
        return false;
    float u = nc_rng_float(rng) * bsum;
    int k = u < b[0] ? 0 : u < b[0] + b[1] ? 1 : 2;
    float st = o->sigma_a[k] + o->sigma_s[k];
    *t = st > 0.0f ? -logf(1.0f - nc_rng_float(rng)) / st : INFINITY;
    return true;
}

/* -- lights (lights.c) */

static inline float spot_falloff(const nacre_light_desc *l, nc_vec3 from_light)
{
    if (l->type != NACRE_LIGHT_SPOT)
        return 1.0f;
    float c = nc_dot(nc_v3a(l->direction), from_light);
    return nc_spot_falloff(l->falloff, c, cosf(l->outer_angle * NC_DEG2RAD), cosf(l->inner_angle * NC_DEG2RAD));
}

/* Equiangular sampling (Kulla and Fajardo 2012) of fog segments for point and spot lights,
 * combined with distance sampling by one-sample MIS per technique with the balance heuristic
 * (integrator.c). A fog segment: the ray o + t d, the part [a, b] of it where fog is, and for a
 * vertex of the distance technique its t and the density pd of that technique there. pd is a
 * deterministic stand-in (mean sigma_s at the vertex times exp(-mean sigma_t there x (t - a))):
 * any weights that sum to 1 at each point keep MIS unbiased, the true density of spectral
 * tracking in heterogeneous fog has no closed form, and this one follows it where the fog is
 * locally uniform. */
struct pt_eq {
    bool on;
    nc_vec3 o, d;
    float a, b, tmax; /* tmax: the segment's end (the fog lookups' ray) */
    float t, pd;
};

static inline float eq_pd(const float sa[3], const float ss[3], float s)
{
    float ms = (ss[0] + ss[1] + ss[2]) / 3.0f, mt = ms + (sa[0] + sa[1] + sa[2]) / 3.0f;
    return ms * expf(-mt * s);
}

/* The equiangular frame of light l on segment e: foot of the perpendicular (delta along the
 * ray), distance D and the angles of a and b seen from the light. False when degenerate. */
static inline bool eq_frame(const pt_light *l, const pt_eq *e, float *delta, float *D, float *ta, float *tb)
{
    *delta = nc_dot(nc_sub(l->pos, e->o), e->d);
    *D = nc_length(nc_sub(l->pos, ray_at(e->o, e->d, *delta)));
    if (!(*D > 0.0f))
        return false;
    *ta = atanf((e->a - *delta) / *D);
    *tb = atanf((e->b - *delta) / *D);
    return *tb > *ta;
}

/* Density in t of the equiangular technique for light l on segment e (0 outside [a, b]). */
static inline float eq_pdf(const pt_light *l, const pt_eq *e, float t)
{
    float delta, D, ta, tb;
    if (!(t >= e->a && t <= e->b) || !eq_frame(l, e, &delta, &D, &ta, &tb))
        return 0.0f;
    float x = t - delta;
    return D / ((tb - ta) * (D * D + x * x));
}

/* Balance-heuristic weight of the distance technique's vertex for light l (1 for suns, or
 * outside fog segments). */
static inline float eq_weight_d(const pt_light *l, const pt_eq *e)
{
    if (!e || !e->on || l->type == NACRE_LIGHT_DIRECTIONAL)
        return 1.0f;
    float pe = eq_pdf(l, e, e->t);
    return pe > 0.0f ? e->pd / (e->pd + pe) : 1.0f;
}

/* Solid-angle pdf of sampling the cone subtended by sphere light `l` from p; 0 when inside. */
static inline float sphere_pdf(const pt_light *l, nc_vec3 p, float *cos_max)
{
    nc_vec3 d = nc_sub(l->pos, p);
    float d2 = nc_dot(d, d), r2 = l->radius * l->radius;
    if (d2 <= r2)
        return 0.0f;
    float sin2 = r2 / d2;
    float cm = sqrtf(1.0f - sin2);
    *cos_max = cm;
    float one_minus = sin2 / (1.0f + cm);
    return 1.0f / (2.0f * PT_PI * one_minus);
}

/* Distance along d from o to sphere light l, or INFINITY. */
static inline float sphere_hit(const pt_light *l, nc_vec3 o, nc_vec3 d)
{
    nc_vec3 oc = nc_sub(o, l->pos);
    float b = nc_dot(oc, d), c = nc_dot(oc, oc) - l->radius * l->radius;
    float disc = b * b - c;
    if (disc < 0)
        return INFINITY;
    float s = sqrtf(disc), t = -b - s;
    if (t > 0)
        return t;
    t = -b + s;
    return c > 0 || t <= 0 ? INFINITY : t; /* only hits from outside count */
}

/* Radiance of lights seen along an escaping ray (environment and sun disks), MIS-weighted
 * against NEE when the previous vertex was not specular. */
static inline nc_vec3 escaped(const pt_scene *ps, nc_vec3 d, bool prev_delta, float prev_pdf, float prev_q,
                              int guided_light, float guided_weight)
{
    nc_vec3 L = nc_v3(0, 0, 0);
    if (ps->env_on)
        L = nc_scale(ps->env, prev_delta ? 1.0f : ps->pt->nee_only ? 0.0f : power_heuristic(prev_pdf, prev_q / (4.0f * PT_PI)));
    for (uint32_t li = 0; li < ps->pt->light_count; li++) {
        const pt_light *l = &ps->pt->lights[li];
        if (l->type != NACRE_LIGHT_DIRECTIONAL || l->delta || nc_dot(d, l->to_light) < l->cos_max)
            continue;
        float w = (int)li == guided_light ? guided_weight
                  : prev_delta          ? 1.0f
                  : ps->pt->nee_only    ? 0.0f
                                        : power_heuristic(prev_pdf, prev_q * l->cone_pdf);
        L = nc_add(L, nc_scale(l->value, w));
    }
    return L;
}

/* -- opaque BSDF (surfaces.c) */

static inline float diffuse_prob(const nacre_material_desc *m)
{
    float kd = (m->diffuse[0] + m->diffuse[1] + m->diffuse[2]), ks = (m->specular[0] + m->specular[1] + m->specular[2]);
    return kd + ks > 0 ? kd / (kd + ks) : 1.0f;
}

static inline nc_vec3 bsdf_sample(const nacre_material_desc *m, nc_vec3 n, nc_vec3 wo, nc_rng *rng)
{
    float u0 = nc_rng_float(rng), u1 = nc_rng_float(rng), u2 = nc_rng_float(rng);
    if (u0 < diffuse_prob(m))
        return nc_pt_around(n, sqrtf(1.0f - u1), u2); /* cosine-weighted */
    float ch = powf(1.0f - u1, 1.0f / (m->shininess + 1.0f));
    nc_vec3 h = nc_pt_around(n, ch, u2);
    return nc_sub(nc_scale(h, 2.0f * nc_dot(wo, h)), wo);
}

/* -- the sun through a dielectric boundary (sun_guide.c) */

/* Facet of object `obj` where the ray p + t dir leaves it (outward normal), or false. */
static inline bool exit_facet(const pt_scene *ps, uint32_t obj, nc_vec3 p, nc_vec3 dir, pt_hit *h, nc_vec3 *x, nc_vec3 *n)
{
    *h = intersect(ps, p, dir, INFINITY);
    if (!h->hit || h->obj != obj)
        return false;
    nc_vec3 ns;
    nc_pt_surface_at(&ps->pt->objects[obj], h, x, n, &ns);
    return nc_dot(dir, *n) > 0;
}

/* Probability q of running NEE at a vertex p of an index-matched homogeneous medium `o` that is
 * at least `clear` from any surface: whatever it finds is attenuated by at least
 * exp(-min_c sigma_t,c clear) on the way out, so deep vertices run it rarely (and weigh it by
 * 1 / q when they do; the MIS weights use the expected density q pdf). A function of p only,
 * as the MIS weight of the phase-sampled path needs it again. The floor GUIDE_Q_MIN keeps q pdf
 * far above any phase pdf (see sun_guide_probability). */
#define GUIDE_Q_SCALE 1.0f
#define GUIDE_Q_MIN 0.05f
static inline float guide_probability(const pt_object *o, float clear)
{
    if (o->heterogeneous || !(clear > 0.0f))
        return 1.0f;
    float st = fminf(o->sigma_a[0] + o->sigma_s[0], fminf(o->sigma_a[1] + o->sigma_s[1], o->sigma_a[2] + o->sigma_s[2]));
    return fmaxf(GUIDE_Q_MIN, fminf(1.0f, GUIDE_Q_SCALE * expf(-st * clear)));
}

/* Probability of running the guided sun technique at a vertex p of a dielectric homogeneous
 * medium, as guide_probability but from the optical depth of the way out along the guide axis
 * where the walk from the seed found it (nc_pt_walk_guide; NULL or unfinished: the clearance bound):
 * the guided estimate is worth at most exp(-min_c sigma_t,c d) of the sun, and most of a
 * vertex's cost (the guide's queries, the sample's exit query and shadow ray) is skipped when it
 * does not run. SUN_Q_SCALE keeps it certain up to an optical depth of ln(SUN_Q_SCALE), where
 * thinning would cost more variance than it saves time (demo, time x rel_mse: scale 1 worse
 * than 3 or 4; 6 and 10 about the same rel_mse as 4 but slower). A function of (p, seed), both known at the vertex. The floor SUN_Q_MIN keeps q pdf
 * far above any phase pdf: otherwise a phase-sampled path flying out of a deep vertex straight
 * into the sun (rare, but scoring the sun's full radiance, ~4e4) would get an MIS weight near 1
 * and a firefly with it. */
#ifndef SUN_Q_SCALE
#define SUN_Q_SCALE 4.0f
#endif
#ifndef SUN_Q_MIN
#define SUN_Q_MIN 0.05f
#endif
static inline float sun_guide_probability(const pt_object *o, float clear, const guide_walk *gw)
{
    if (o->heterogeneous)
        return 1.0f;
    float d = gw && gw->done ? fmaxf(clear, gw->t) : clear;
    if (!(d > 0.0f))
        return 1.0f;
    float s = fminf(o->sigma_a[0] + o->sigma_s[0], fminf(o->sigma_a[1] + o->sigma_s[1], o->sigma_a[2] + o->sigma_s[2]));
    return fmaxf(SUN_Q_MIN, fminf(1.0f, SUN_Q_SCALE * expf(-s * d)));
}

/* Density of the guided direction: the mixture of the narrow and the wide cone. */
static inline float guide_pdf(const guide *g, nc_vec3 w)
{
    if (!g->valid)
        return 0.0f;
    float c = nc_dot(w, g->axis);
    return (c >= g->cos_a ? (1.0f - GUIDE_WIDE_FRACTION) * g->pdf : 0.0f) + (c >= g->cos_w ? GUIDE_WIDE_FRACTION * g->pdf_w : 0.0f);
}

/* The guided estimate at medium vertex p (incoming direction d, HG g) for sun light l, run with
 * probability q. */
static inline nc_vec3 guided_sun(const pt_scene *ps, uint32_t obj, const pt_light *l, const guide *gd, float q, nc_vec3 p,
                                 nc_vec3 d, float g, nc_rng *rng)
{
    const pt_object *ob = &ps->pt->objects[obj];
    float cos_c = nc_rng_float(rng) < GUIDE_WIDE_FRACTION ? gd->cos_w : gd->cos_a;
    nc_vec3 w = nc_pt_around(gd->axis, 1.0f - nc_rng_float(rng) * (1.0f - cos_c), nc_rng_float(rng));
    pt_hit h;
    nc_vec3 x, n;
    if (!exit_facet(ps, obj, p, w, &h, &x, &n))
        return nc_v3(0, 0, 0);
    float cos_i = nc_dot(w, n);
    float wv[3] = {w.x, w.y, w.z}, nv[3] = {-n.x, -n.y, -n.z}, tv[3];
    if (!nc_refract(wv, nv, 1.0f / ob->eta, tv))
        return nc_v3(0, 0, 0); /* total internal reflection: phase sampling's path */
    nc_vec3 out = nc_normalize(nc_v3a(tv));
    if (nc_dot(out, l->to_light) < l->cos_max)
        return nc_v3(0, 0, 0);
    float phase = (float)nc_hg_phase(nc_dot(d, w), g);
    nc_vec3 tr = nc_pt_transmittance(ps, ob, p, w, h.t, rng);
    if (max3(tr) <= 0 && fminf(tr.x, fminf(tr.y, tr.z)) >= 0)
        return nc_v3(0, 0, 0);
    nc_vec3 vis = nc_pt_shadow(ps, offset_origin(ps, x, n, out), out, INFINITY, -1, rng);
    float F = (float)nc_fresnel_dielectric(cos_i, 1.0f / ob->eta);
    float qp = q * guide_pdf(gd, w);
    /* nee_only: the guided technique alone covers its cone (see trace_path). */
    float k = phase * (1.0f - F) * ob->eta * ob->eta * (ps->pt->nee_only ? 1.0f : power_heuristic(qp, phase)) / qp;
    return nc_scale(nc_mul(nc_mul(tr, vis), l->value), k);
}

#endif /* NACRE_HAVE_EMBREE */

#endif /* NACRE_PT_INTERNAL_H */
