/*
 * pathtrace.c: the reference volumetric path tracer of `--method pathtrace`: unidirectional path
 * tracing (Kajiya 1986) with next-event estimation and multiple importance sampling (Veach and
 * Guibas 1995, power heuristic) over the committed scene, Embree 3 for ray-triangle queries.
 *
 * Surfaces: opaque materials are Lambert + normalized Blinn-Phong with the conventions of
 * shade/phong.c (f = kd / pi + ks (s + 8) / (8 pi) cos^s theta_h). A translucent object's surface
 * is a smooth dielectric of the material's eta (Fresnel reflection or refraction, chosen by the
 * Fresnel probability), or, with eta == 1, index matched: not a scattering vertex at all, the
 * path just changes medium. Its interior is a participating medium with sigma_a, sigma_s from
 * nc_medium_eval at the rest-pose point and Henyey-Greenstein phase with the material's g. A
 * layered material (layered/layers.h) puts its layers above that core: a point's layer comes from
 * its distance to the rest-pose mesh and the depth map at the nearest point's uv (an Embree point
 * query), each layer with its own coefficients and g. A layer grid over the object stores per
 * cell the layers its depths can reach (depth is 1-Lipschitz), so points in cells that only one
 * layer (or the core) reaches skip the query, and the majorant grid takes its bounds from it.
 *
 * Media: homogeneous free flights by spectral MIS over the RGB channels (free_flight_homogeneous);
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
 * Rest pose: an object's rest-pose point is the inverse object transform of the world point,
 * exact for objects without deformers. A deformed heterogeneous object gets a 64-voxel (longest
 * axis) grid of its deformed mesh holding each voxel's rest point (nacre_voxel_grid_rest_positions:
 * exact on the surface, first order inside), looked up by nearest voxel: the pattern follows the
 * deformation to within about a voxel.
 *
 * Lights (radiometry as in phong.c): the environment is a uniform radiance (sampled uniformly over
 * the sphere); a directional light of irradiance E and angular radius r is a distant disk of
 * radiance E / (pi sin^2 r), sampled uniformly in its cone (r = 0: a delta light, NEE only); a
 * point or spot light of intensity I and radius r is a sphere of radiance I / (pi r^2) times the
 * spot falloff of the direction from its centre (r = 0: delta). Through index-matched boundaries
 * NEE works. Inside a dielectric object NEE cannot work (shadow rays end on the boundary): a sun
 * of non-zero radius is sampled through the boundary by a second technique, MIS-combined with
 * phase sampling (guided_sun); every other light, and a delta sun, is reached only by paths
 * that refract out and hit it by chance (point lights, delta suns: never; exact but slow for
 * small sphere lights).
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
 * - clearance grids (see clearance()): a free flight shorter than a conservative bound on the
 *   distance to any surface skips the Embree query (same result bit for bit); the bound is
 *   extended by the clearance at the point it reaches, a few times, before asking;
 * - NEE (index-matched media) runs with a probability that falls with that bound
 *   (guide_probability), guided sun sampling (dielectric media) with one that falls with the
 *   optical depth of the way out along the guide axis (sun_guide_probability), each weighted by
 *   its inverse and MIS-combined with the expected density; the guide axis is found by a walk
 *   over the mesh from the previous vertex's facet, without a query in most cases (walk_guide,
 *   make_guide), and evaluated lazily for the MIS weight of phase-sampled paths (needed only when
 *   one refracts out into the sun).
 *
 * Determinism: each pixel of each pass has its own PCG32 stream (seed, pass, pixel); per-pixel
 * mean and M2 (Welford) are updated in pass order, so images do not depend on threads.
 * Time limit and caps (README, "Caps and the time limit"): the deadline is checked before each
 * sample and within paths (pt_budget); a sample in flight at the deadline is dropped, so each
 * pixel is the mean of the samples it completed - the pixel an unlimited render with that many
 * samples would give, bit for bit. Paths end at MAX_VERTICES vertices or MAX_PATH_COLLISIONS
 * units of tracking work, keeping what they gathered (counted in stats->paths_capped).
 * Fog (nacre_fog_desc) fills the air: a path outside every object tracks the sum of the fogs'
 * coefficients by the same spectral tracking and ratio tracking, over majorant pieces cut where
 * a fog begins or ends and where height fog changes by a factor of 2 (see "fog" below); shadow
 * rays through air are attenuated by it, scattering vertices in it use NEE and phase sampling.
 * Translucent objects displace fog (inside one, only its medium counts).
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
#include "pathtrace/pathtrace.h"

#include "core/optics.h"
#include "pathtrace/rng.h"
#include "layered/layers.h"
#include "scene/medium.h"
#include "scene/scene.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
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
                                 const nacre_render_settings *settings, nacre_image *out,
                                 nacre_render_stats *stats)
{
    (void)state, (void)scene, (void)settings, (void)out, (void)stats;
    return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "render: method 'pathtrace' needs Embree (libembree-dev)");
}

nacre_result nc_pathtrace_variance(const nc_pathtracer *state, nacre_context *ctx, nacre_image *out)
{
    (void)state, (void)out;
    return nc_fail(ctx, NACRE_ERROR_INVALID_OPERATION, "variance: the last frame was not path traced");
}

void nc_pathtracer_destroy(nacre_context *ctx, nc_pathtracer *state) { (void)ctx, (void)state; }

#else /* NACRE_HAVE_EMBREE */

#include <embree3/rtcore.h>

#define PT_PI 3.14159265358979323846f
#define MAX_VERTICES 65536 /* real vertices per path; walks this long carry ~0 weight */
#define RR_START 8 /* vertices before Russian roulette (see the top of the file) */
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

/* A fog of the scene (see "fog" below). */
typedef struct pt_fog {
    const nc_fog_rec *rec;
    bool box, patterned, height;
    float half[3];        /* box: half edge lengths */
    float maj;            /* scalar bound of sigma_t where height() = 1 */
    float falloff, base, g;
    float hexp;           /* cap of height()'s exponent: at most 60, and maj e^hexp <= FOG_MAX_DENSITY */
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
    bool any_matched;      /* some object is index matched (shadow rays may pass surfaces) */
    bool any_noncaster;    /* some opaque object has cast_shadows = false */
    bool nee_only;         /* shadow rays see another world than paths: no MIS (see top) */
    int32_t width, height;
    double *mean, *m2;     /* per pixel and channel */
    uint32_t *count;       /* per pixel: samples in mean and m2 */
    size_t pixel_capacity;
    bool valid;            /* a frame was rendered into mean/m2 */
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

static void budget_reset(pt_budget *b, uint64_t deadline_us)
{
    b->deadline_us = deadline_us;
    b->collisions = 0;
    b->until_check = DEADLINE_STRIDE;
    b->stop = b->capped = b->expired = false;
}

/* One unit of work that is not a collision (a path vertex); false: the path must stop. */
static bool budget_tick(pt_budget *b)
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
static bool budget_collision(pt_budget *b)
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

static float max3(nc_vec3 v) { return fmaxf(v.x, fmaxf(v.y, v.z)); }
static float comp(nc_vec3 v, int c) { return c == 0 ? v.x : c == 1 ? v.y : v.z; }
static nc_vec3 ray_at(nc_vec3 o, nc_vec3 d, float t) { return nc_add(o, nc_scale(d, t)); }
static float power_heuristic(float a, float b) { return a * a / (a * a + b * b); }

static pt_hit intersect(const pt_scene *ps, nc_vec3 o, nc_vec3 d, float tfar)
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

/* World position (barycentric, more precise than o + t d), outward geometric normal from the
 * counter-clockwise winding, and interpolated shading normal. */
static void surface_at(const pt_object *o, const pt_hit *h, nc_vec3 *p, nc_vec3 *ng, nc_vec3 *ns)
{
    const uint32_t *tri = o->idx + 3 * (size_t)h->prim;
    nc_vec3 a = nc_v3a(o->pos + 3 * (size_t)tri[0]), b = nc_v3a(o->pos + 3 * (size_t)tri[1]),
            c = nc_v3a(o->pos + 3 * (size_t)tri[2]);
    float w = 1.0f - h->u - h->v;
    *p = nc_add(nc_add(nc_scale(a, w), nc_scale(b, h->u)), nc_scale(c, h->v));
    *ng = nc_normalize(nc_cross(nc_sub(b, a), nc_sub(c, a)));
    nc_vec3 na = nc_v3a(o->nrm + 3 * (size_t)tri[0]), nb = nc_v3a(o->nrm + 3 * (size_t)tri[1]),
            nc = nc_v3a(o->nrm + 3 * (size_t)tri[2]);
    *ns = nc_normalize(nc_add(nc_add(nc_scale(na, w), nc_scale(nb, h->u)), nc_scale(nc, h->v)));
}

/* Start point for a ray leaving surface point p in direction d: pushed off the surface to the
 * side d goes, so the ray does not find its own triangle again. */
static nc_vec3 offset_origin(const pt_scene *ps, nc_vec3 p, nc_vec3 ng, nc_vec3 d)
{
    float s = nc_dot(d, ng) >= 0 ? ps->eps : -ps->eps;
    return nc_add(p, nc_scale(ng, s));
}

static void sample_uniform_sphere(float u1, float u2, nc_vec3 *w)
{
    float z = 1.0f - 2.0f * u1, r = sqrtf(fmaxf(0.0f, 1.0f - z * z)), phi = 2.0f * PT_PI * u2;
    *w = nc_v3(r * cosf(phi), r * sinf(phi), z);
}

/* Direction at angle acos(cos_t) from axis `n`, azimuth 2 pi u. */
static nc_vec3 around(nc_vec3 n, float cos_t, float u)
{
    nc_vec3 t, b;
    nc_basis(n, &t, &b);
    float sin_t = sqrtf(fmaxf(0.0f, 1.0f - cos_t * cos_t)), phi = 2.0f * PT_PI * u;
    return nc_normalize(nc_add(nc_scale(n, cos_t), nc_add(nc_scale(t, sin_t * cosf(phi)), nc_scale(b, sin_t * sinf(phi)))));
}

/* ---- media ---------------------------------------------------------------------------- */

/* Rest-pose point of world point p: the inverse object transform, then, for deformed objects,
 * the rest point stored in the voxel of the deformed mesh that holds it (nearest voxel: pattern
 * edges move by up to half a voxel; NaN outside the voxelized mesh, i.e. medium 1). */
static void rest_point(const pt_object *o, nc_vec3 p, float out[3])
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
    rest_point(o, p, xyz);
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
 * clipped by the slab test in its local frame, or everything), and their coefficients add. The
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
 * pieces. A fog's density (sigma_t times height()) is capped at FOG_MAX_DENSITY per scene unit,
 * a free path far below float resolution at any scene scale, so that tracking weights (products
 * of two densities) stay finite. */
#define FOG_TAIL 1e-7f
#define FOG_THIN 1e-3f
#define FOG_MAX_DENSITY 1e12f
#define FOG_LN2 0.69314718f

static float fog_height(const pt_fog *f, float y)
{
    return expf(f->height ? fminf(f->hexp, -f->falloff * (y - f->base)) : f->hexp);
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
        if (f->box) {
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

/* ---- clearance grids ---------------------------------------------------------------------
 *
 * In a dense medium (marble: a mean free path of 0.4 mm in a 60 mm block) a path scatters
 * thousands of times, and each free flight would ask Embree where the boundary is. A clearance
 * grid over each medium object stores per cell the chessboard distance, in cells, to the nearest
 * cell touched by any surface of the scene, by a sphere light or by the outside of the grid
 * (build_clearance). A surface point in a cell k cells away from point p's cell differs from p
 * by at least k - 1 cells along one axis, so (k - 1) cells is a lower bound on the distance from
 * p to any surface: a flight shorter than that needs no query, since the query could not change
 * it. The flight is sampled before the query either way, so the image is the same bit for bit. */
#define CLEARANCE_RES 192    /* at most this many cells along the object's longest axis */
#define CLEARANCE_MIN_RES 32 /* and at least this many */
#ifndef CLEAR_STEPS
#define CLEAR_STEPS 4        /* further bounds looked up along a flight before asking Embree */
#endif

/* Lower bound on the distance from p to any surface (<= 0: unknown, ask Embree). */
static float clearance(const pt_object *o, nc_vec3 p)
{
    if (!o->dist)
        return 0.0f;
    float pv[3] = {p.x, p.y, p.z};
    size_t idx[3];
    for (int a = 0; a < 3; a++) {
        float f = (pv[a] - o->dorigin[a]) * o->dinv;
        if (!(f >= 0.0f) || f >= (float)o->ddims[a])
            return 0.0f;
        idx[a] = (size_t)f;
    }
    uint8_t k = o->dist[idx[0] + o->ddims[0] * (idx[1] + o->ddims[1] * idx[2])];
    return ((float)k - 1.0f) * o->dcell - o->dmargin;
}

typedef enum { FF_PASS = 0, FF_SCATTER, FF_ABSORB } ff_event;

/* Homogeneous media need no null collisions: the distance is sampled from the exponential of one
 * channel, chosen with probability proportional to the path throughput (hero channel, Wilkie et
 * al. 2014 spectral MIS with the history-aware choice of Kutz et al. 2017), and every channel is
 * weighted by its own density over the mixture density (one-sample balance heuristic). Grey media
 * reduce to weight = albedo per scattering. */
static bool flight_sample_homogeneous(const pt_object *o, nc_vec3 beta, nc_rng *rng, float *t)
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

/* The weights of a flight of length t sampled by flight_sample_homogeneous, given the boundary
 * at tmax. Sampling (two random numbers) comes first so that the caller can decide from t
 * alone whether it needs the boundary (see clearance()). */
static ff_event flight_resolve_homogeneous(const pt_object *o, float t, float tmax, nc_vec3 *beta, float *t_out)
{
    float b[3] = {fabsf(beta->x), fabsf(beta->y), fabsf(beta->z)}, st[3];
    float bsum = b[0] + b[1] + b[2];
    for (int c = 0; c < 3; c++)
        st[c] = o->sigma_a[c] + o->sigma_s[c];
    float tr[3], pdf = 0.0f;
    if (t >= tmax) {
        for (int c = 0; c < 3; c++) {
            tr[c] = expf(-st[c] * tmax);
            pdf += b[c] / bsum * tr[c];
        }
        if (!(pdf > 0.0f))
            return FF_ABSORB;
        *beta = nc_v3(beta->x * tr[0] / pdf, beta->y * tr[1] / pdf, beta->z * tr[2] / pdf);
        return FF_PASS;
    }
    for (int c = 0; c < 3; c++) {
        tr[c] = expf(-st[c] * t);
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
 * beta is updated by the per-channel weights. */
static ff_event free_flight(const pt_scene *ps, const pt_object *o, nc_vec3 org, nc_vec3 dir, float tmax,
                            nc_rng *rng, nc_vec3 *beta, float *t_out, float *g_out)
{
    collision_walk w;
    walk_init(&w, ps, o, org, dir, tmax);
    float t, m;
    while (walk_next(&w, rng, &t, &m)) {
        float sa[3], ss[3], g = 0.0f;
        nc_vec3 p = ray_at(org, dir, t);
        walk_medium(ps, &w, t, p, sa, ss, &g);
        float b[3] = {beta->x, beta->y, beta->z};
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
static nc_vec3 transmittance(const pt_scene *ps, const pt_object *o, nc_vec3 org, nc_vec3 dir, float tmax, nc_rng *rng)
{
    if (o && !o->heterogeneous)
        return nc_v3(expf(-(o->sigma_a[0] + o->sigma_s[0]) * tmax), expf(-(o->sigma_a[1] + o->sigma_s[1]) * tmax),
                     expf(-(o->sigma_a[2] + o->sigma_s[2]) * tmax));
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

static nc_vec3 shadow(const pt_scene *ps, nc_vec3 p, nc_vec3 wi, float dist, int medium, nc_rng *rng)
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
            tr = nc_mul(tr, transmittance(ps, &ps->pt->objects[medium], o, wi, seg, rng));
            if (tr.x == 0 && tr.y == 0 && tr.z == 0)
                return tr;
        }
        const pt_object *ob = h.hit ? &ps->pt->objects[h.obj] : NULL;
        if (ob && ob->kind != PT_MATCHED && ob->casts)
            return nc_v3(0, 0, 0);
        /* Fog after the occlusion test: a blocked ray needs no tracking. */
        if (medium < 0 && fog) {
            tr = nc_mul(tr, transmittance(ps, NULL, o, wi, seg, rng));
            if (tr.x == 0 && tr.y == 0 && tr.z == 0)
                return tr;
        }
        if (!ob)
            return tr;
        nc_vec3 hp, ng, ns;
        surface_at(ob, &h, &hp, &ng, &ns);
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

/* ---- lights ----------------------------------------------------------------------------- */

static float spot_falloff(const nacre_light_desc *l, nc_vec3 from_light)
{
    if (l->type != NACRE_LIGHT_SPOT)
        return 1.0f;
    float c = nc_dot(nc_v3a(l->direction), from_light);
    float co = cosf(l->outer_angle * NC_DEG2RAD), ci = cosf(l->inner_angle * NC_DEG2RAD);
    if (c <= co)
        return 0.0f;
    if (c >= ci || ci <= co)
        return 1.0f;
    float t = (c - co) / (ci - co);
    return t * t * (3.0f - 2.0f * t);
}

/* Solid-angle pdf of sampling the cone subtended by sphere light `l` from p; 0 when inside. */
static float sphere_pdf(const pt_light *l, nc_vec3 p, float *cos_max)
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
static float sphere_hit(const pt_light *l, nc_vec3 o, nc_vec3 d)
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
            s->wi = around(l->to_light, 1.0f - u1 * (1.0f - l->cos_max), u2);
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
    s->wi = around(axis, 1.0f - u1 * (1.0f - cos_max), u2);
    float t = sphere_hit(l, p, s->wi);
    if (!isfinite(t))
        t = dl; /* grazing the silhouette: rounding */
    s->dist = t;
    s->value = nc_scale(l->value, fall);
    s->pdf = pdf;
    return true;
}

/* ---- opaque BSDF (phong.c conventions) ------------------------------------------------ */

static float diffuse_prob(const nacre_material_desc *m)
{
    float kd = (m->diffuse[0] + m->diffuse[1] + m->diffuse[2]), ks = (m->specular[0] + m->specular[1] + m->specular[2]);
    return kd + ks > 0 ? kd / (kd + ks) : 1.0f;
}

static nc_vec3 bsdf_eval(const nacre_material_desc *m, nc_vec3 n, nc_vec3 wo, nc_vec3 wi, float *pdf)
{
    float ci = nc_dot(n, wi), co = nc_dot(n, wo);
    *pdf = 0;
    if (ci <= 0 || co <= 0)
        return nc_v3(0, 0, 0);
    nc_vec3 h = nc_normalize(nc_add(wi, wo));
    float nh = fmaxf(0.0f, nc_dot(n, h));
    float s = m->shininess;
    float spec = (s + 8.0f) / (8.0f * PT_PI) * (s > 0 ? powf(nh, s) : 1.0f);
    float pd = diffuse_prob(m);
    float ph = (s + 1.0f) / (2.0f * PT_PI) * (s > 0 ? powf(nh, s) : 1.0f);
    *pdf = pd * ci / PT_PI + (1.0f - pd) * ph / (4.0f * fmaxf(nc_dot(wo, h), 1e-6f));
    return nc_v3(m->diffuse[0] / PT_PI + m->specular[0] * spec, m->diffuse[1] / PT_PI + m->specular[1] * spec,
                 m->diffuse[2] / PT_PI + m->specular[2] * spec);
}

static nc_vec3 bsdf_sample(const nacre_material_desc *m, nc_vec3 n, nc_vec3 wo, nc_rng *rng)
{
    float u0 = nc_rng_float(rng), u1 = nc_rng_float(rng), u2 = nc_rng_float(rng);
    if (u0 < diffuse_prob(m))
        return around(n, sqrtf(1.0f - u1), u2); /* cosine-weighted */
    float ch = powf(1.0f - u1, 1.0f / (m->shininess + 1.0f));
    nc_vec3 h = around(n, ch, u2);
    return nc_sub(nc_scale(h, 2.0f * nc_dot(wo, h)), wo);
}

/* ---- the path ------------------------------------------------------------------------ */

/* NEE from p over every light and the environment. `surface`: opaque vertex with shading
 * normal n and outgoing wo (else a medium vertex with HG g, incoming direction d = -wo). Run
 * with probability q (see nee_probability): weighted by 1 / q, MIS with the density q pdf. */
static nc_vec3 direct_light(const pt_scene *ps, nc_vec3 p, nc_vec3 ng, bool surface, const nacre_material_desc *m,
                            nc_vec3 n, nc_vec3 wo, float g, int medium, float q, nc_rng *rng)
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
            f = nc_scale(bsdf_eval(m, n, wo, s.wi, &fpdf), fmaxf(0.0f, nc_dot(n, s.wi)));
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
        nc_vec3 tr = shadow(ps, o, s.wi, dist, medium, rng);
        if (tr.x == 0 && tr.y == 0 && tr.z == 0)
            continue;
        nc_vec3 c = nc_mul(nc_mul(f, tr), s.value);
        if (s.pdf > 0)
            c = nc_scale(c, (pt->nee_only ? 1.0f : power_heuristic(q * s.pdf, fpdf)) / (q * s.pdf));
        else
            c = nc_scale(c, 1.0f / q);
        sum = nc_add(sum, c);
    }
    return sum;
}

/* Radiance of lights seen along an escaping ray (environment and sun disks), MIS-weighted
 * against NEE when the previous vertex was not specular. */
static nc_vec3 escaped(const pt_scene *ps, nc_vec3 d, bool prev_delta, float prev_pdf, float prev_q,
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

/* ---- sun through a dielectric boundary ---------------------------------------------------
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
 * directional light is guided. */
#define GUIDE_ITERATIONS 4
#define GUIDE_CONE_SCALE 1.05f /* guide cone half-angle over the sun's */
/* A fraction of the guided samples goes to a wider cone, so that where the axis is off (the
 * iteration stopped between two facets of a curved surface) phase-sampled paths into the sun
 * still meet a guided density far above theirs, rather than scoring the sun's full radiance
 * with MIS weight 1 (fireflies of ~4e4 seen on the demo's torus with the narrow cone alone). */
#define GUIDE_WIDE_FRACTION 0.1f
#define GUIDE_WIDE_ANGLE 0.05f /* radians, about 3 degrees */

typedef struct guide {
    bool valid;
    nc_vec3 axis;
    float cos_a, pdf;     /* narrow cone: cos of its half-angle, its own uniform pdf */
    float cos_w, pdf_w;   /* wide cone, the same */
} guide;

/* Facet of object `obj` where the ray p + t dir leaves it (outward normal), or false. */
static bool exit_facet(const pt_scene *ps, uint32_t obj, nc_vec3 p, nc_vec3 dir, pt_hit *h, nc_vec3 *x, nc_vec3 *n)
{
    *h = intersect(ps, p, dir, INFINITY);
    if (!h->hit || h->obj != obj)
        return false;
    nc_vec3 ns;
    surface_at(&ps->pt->objects[obj], h, x, n, &ns);
    return nc_dot(dir, *n) > 0;
}

/* Where the ray p + t dir meets the plane of triangle `prim` of `o` (Moller and Trumbore 1997):
 * true if it crosses the triangle at *t > 0; otherwise *edge is the edge (0: v0v1, 1: v1v2,
 * 2: v2v0) beyond which the plane point lies farthest, or -1 when the plane is not ahead. Lets
 * make_guide find the facet its refracted direction leaves through without asking Embree: the
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

/* Outward geometric normal of triangle `prim` (counter-clockwise winding, as surface_at). */
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
static bool refract_sun_facet(const pt_object *ob, const pt_light *l, uint32_t prim, nc_vec3 *dir)
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
        return refract_sun_facet(ob, l, prim, dir);
    const float *v = ob->sun_dir + 3 * (size_t)prim;
    if (isnan(v[0]))
        return false;
    *dir = nc_v3a(v);
    return true;
}

/* The query-free start of make_guide: from the seed facet, refract the sun and, while the ray
 * from p along the refracted direction misses the facet, step to the neighbour across the edge
 * it passes (a point location walk over the mesh). A function of (p, seed), so the probability
 * of guiding may use the distance it finds (see sun_guide_probability). */
#define GUIDE_WALK_STEPS 24
typedef struct guide_walk {
    uint32_t prim;    /* the facet reached, UINT32_MAX if the seed gave nothing */
    nc_vec3 dir;      /* the sun refracted through it, pointing back out */
    bool done;        /* the ray p + t dir leaves through prim (or the walk went back and forth
                         between two facets: the axis is as good as it gets) ... */
    float t;          /* ... at this t */
} guide_walk;

static guide_walk walk_guide(const pt_object *ob, const pt_light *l, nc_vec3 p, uint32_t seed)
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
            return gw; /* make_guide asks Embree from here */
        prev = gw.prim;
        gw.prim = next;
        gw.dir = nd;
    }
    return gw;
}

/* The guide at p, from the walk from the seed (see walk_guide; the seed is the last facet of the
 * previous guide on the path: vertices a mean free path apart refract the sun through the same
 * facet or a near one, and then no query is needed at all); where the walk does not end, Embree
 * finds the facets. The axis depends on (p, seed), both known at the vertex, so the MIS weights
 * stay consistent (the lazy re-evaluation in trace_path passes the same seed). *last receives
 * the facet the axis was refracted through. */
static guide make_guide(const pt_scene *ps, uint32_t obj, const pt_light *l, nc_vec3 p, const guide_walk *gw, uint32_t *last)
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

/* Probability q of running NEE at a vertex p of an index-matched homogeneous medium `o` that is
 * at least `clear` from any surface: whatever it finds is attenuated by at least
 * exp(-min_c sigma_t,c clear) on the way out, so deep vertices run it rarely (and weigh it by
 * 1 / q when they do; the MIS weights use the expected density q pdf). A function of p only,
 * as the MIS weight of the phase-sampled path needs it again. The floor GUIDE_Q_MIN keeps q pdf
 * far above any phase pdf (see sun_guide_probability). */
#define GUIDE_Q_SCALE 1.0f
#define GUIDE_Q_MIN 0.05f
static float guide_probability(const pt_object *o, float clear)
{
    if (o->heterogeneous || !(clear > 0.0f))
        return 1.0f;
    float st = fminf(o->sigma_a[0] + o->sigma_s[0], fminf(o->sigma_a[1] + o->sigma_s[1], o->sigma_a[2] + o->sigma_s[2]));
    return fmaxf(GUIDE_Q_MIN, fminf(1.0f, GUIDE_Q_SCALE * expf(-st * clear)));
}

/* Probability of running the guided sun technique at a vertex p of a dielectric homogeneous
 * medium, as guide_probability but from the optical depth of the way out along the guide axis
 * where the walk from the seed found it (walk_guide; NULL or unfinished: the clearance bound):
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
static float sun_guide_probability(const pt_object *o, float clear, const guide_walk *gw)
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
static float guide_pdf(const guide *g, nc_vec3 w)
{
    if (!g->valid)
        return 0.0f;
    float c = nc_dot(w, g->axis);
    return (c >= g->cos_a ? (1.0f - GUIDE_WIDE_FRACTION) * g->pdf : 0.0f) + (c >= g->cos_w ? GUIDE_WIDE_FRACTION * g->pdf_w : 0.0f);
}

/* The guided estimate at medium vertex p (incoming direction d, HG g) for sun light l, run with
 * probability q. */
static nc_vec3 guided_sun(const pt_scene *ps, uint32_t obj, const pt_light *l, const guide *gd, float q, nc_vec3 p,
                          nc_vec3 d, float g, nc_rng *rng)
{
    const pt_object *ob = &ps->pt->objects[obj];
    float cos_c = nc_rng_float(rng) < GUIDE_WIDE_FRACTION ? gd->cos_w : gd->cos_a;
    nc_vec3 w = around(gd->axis, 1.0f - nc_rng_float(rng) * (1.0f - cos_c), nc_rng_float(rng));
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
    nc_vec3 tr = transmittance(ps, ob, p, w, h.t, rng);
    if (max3(tr) <= 0 && fminf(tr.x, fminf(tr.y, tr.z)) >= 0)
        return nc_v3(0, 0, 0);
    nc_vec3 vis = shadow(ps, offset_origin(ps, x, n, out), out, INFINITY, -1, rng);
    float F = (float)nc_fresnel_dielectric(cos_i, 1.0f / ob->eta);
    float qp = q * guide_pdf(gd, w);
    /* nee_only: the guided technique alone covers its cone (see trace_path). */
    float k = phase * (1.0f - F) * ob->eta * ob->eta * (ps->pt->nee_only ? 1.0f : power_heuristic(qp, phase)) / qp;
    return nc_scale(nc_mul(nc_mul(tr, vis), l->value), k);
}

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
    uint32_t seed = UINT32_MAX, guide_seed = UINT32_MAX; /* see make_guide */
    int seed_obj = -1;
    float clear_here = -1.0f; /* clearance of o when o is a scattering vertex that looked it up */
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
            float clear = clear_here >= 0.0f ? clear_here : clearance(mo, o);
            if (!mo->heterogeneous) {
                if (!flight_sample_homogeneous(mo, beta, rng, &t_hom))
                    break;
                /* Past the first bound, the clearance at the point reached extends it (sphere
                 * tracing along the flight): still a bound, so still bit for bit. */
                for (int k = 0; k < CLEAR_STEPS && clear > 0.0f && t_hom >= clear; k++) {
                    float more = clearance(mo, ray_at(o, d, clear));
                    if (!(more > 0.0f))
                        break;
                    clear += more;
                }
                if (t_hom < clear) {
                    ev = flight_resolve_homogeneous(mo, t_hom, INFINITY, &beta, &ts);
                    query = false;
                }
            } else if (clear > 0) {
                ev = free_flight(ps, mo, o, d, clear, rng, &beta, &ts, &g);
                if (ev == FF_PASS)
                    o = ray_at(o, d, clear);
                else
                    query = false;
            }
        }
        clear_here = -1.0f;
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
                ev = mo->heterogeneous ? free_flight(ps, mo, o, d, tmax, rng, &beta, &ts, &g)
                                       : flight_resolve_homogeneous(mo, t_hom, tmax, &beta, &ts);
            else if (pt->fog_count)
                ev = free_flight(ps, NULL, o, d, tmax, rng, &beta, &ts, &g);
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
                /* Fog: plain NEE (no clearance grid in the open). */
                L = nc_add(L, nc_mul(beta, direct_light(ps, p, wo, false, NULL, wo, wo, g, -1, 1.0f, rng)));
            } else if (ob->kind == PT_MATCHED) {
                /* NEE attenuated by at least the clearance: run it less often deep inside, as
                 * the guided technique (guide_probability has the same argument). */
                clear_p = fmaxf(0.0f, clearance(ob, p));
                q = guide_probability(ob, clear_p);
                if (q >= 1.0f || nc_rng_float(rng) < q)
                    L = nc_add(L, nc_mul(beta, direct_light(ps, p, wo, false, NULL, wo, wo, g, medium, q, rng)));
            } else if (sun >= 0 && !pt->opt.no_sun_guiding) {
                guiding = true;
                clear_p = fmaxf(0.0f, clearance(ob, p));
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
                    gw = walk_guide(ob, sl, p, seed);
                q = walked && !pt->opt.guide_always ? sun_guide_probability(ob, clear_p, &gw) : q_clear;
                if (q >= 1.0f || nc_rng_float(rng) < q) {
                    if (!walked)
                        gw = walk_guide(ob, sl, p, seed);
                    uint32_t last;
                    gd = make_guide(ps, (uint32_t)medium, sl, p, &gw, &last);
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
            nc_vec3 wi = around(d, c, nc_rng_float(rng));
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
                w = pt->nee_only ? 0.0f : power_heuristic(prev_pdf, prev_q * lp);
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
                        guide_walk gw = walk_guide(&pt->objects[guide_obj], &pt->lights[sun], guide_vertex, guide_seed);
                        guide_cached = make_guide(ps, guide_obj, &pt->lights[sun], guide_vertex, &gw, &unused);
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
            surface_at(ob, &h, &p, &ng, &ns);
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
            const nacre_material_desc *m = ob->mat;
            L = nc_add(L, nc_mul(beta, direct_light(ps, p, ng, true, m, ns, wo, 0, medium, 1.0f, rng)));
            nc_vec3 wi = bsdf_sample(m, ns, wo, rng);
            float pdf;
            nc_vec3 f = bsdf_eval(m, ns, wo, wi, &pdf);
            if (nc_dot(wi, ng) <= 0 || pdf <= 0 || max3(f) <= 0)
                break;
            beta = nc_mul(beta, nc_scale(f, nc_dot(ns, wi) / pdf));
            prev_pdf = pdf;
            prev_q = 1.0f;
            prev_delta = false;
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
        float dmin = INFINITY, dmax = -INFINITY;
        for (int k = 0; k < 8; k++) {
            nc_vec3 p = nc_v3((k & 1) ? s->bounds_max[0] : s->bounds_min[0], (k & 2) ? s->bounds_max[1] : s->bounds_min[1],
                              (k & 4) ? s->bounds_max[2] : s->bounds_min[2]);
            float d = -nc_mat4_point(&view, p).z;
            dmin = fminf(dmin, d);
            dmax = fmaxf(dmax, d);
        }
        if (!isfinite(dmin) || !isfinite(dmax)) {
            dmin = 0.01f;
            dmax = 100.0f;
        }
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

static void release_scene(nc_pathtracer *pt)
{
    nacre_context *ctx = pt->ctx;
    if (pt->rtc)
        rtcReleaseScene(pt->rtc);
    pt->rtc = NULL;
    for (uint32_t i = 0; i < pt->object_count; i++) {
        nc_free(ctx, pt->objects[i].grid);
        nc_locator_destroy(ctx, pt->objects[i].loc);
        nc_free(ctx, pt->objects[i].lbits);
        nc_free(ctx, pt->objects[i].lhint);
        nc_free(ctx, pt->objects[i].rest);
        nc_free(ctx, pt->objects[i].dist);
        nc_free(ctx, pt->objects[i].adj);
        nc_free(ctx, pt->objects[i].sun_dir);
    }
    nc_free(ctx, pt->objects);
    nc_free(ctx, pt->lights);
    pt->objects = NULL;
    pt->lights = NULL;
    pt->object_count = pt->light_count = 0;
}

void nc_pathtracer_destroy(nacre_context *ctx, nc_pathtracer *pt)
{
    if (!pt)
        return;
    release_scene(pt);
    if (pt->device)
        rtcReleaseDevice(pt->device);
    nc_free(ctx, pt->mean);
    nc_free(ctx, pt->m2);
    nc_free(ctx, pt->count);
    nc_free(ctx, pt);
}

/* Deformed heterogeneous objects: voxelize the deformed mesh in object space (the committed world
 * positions through the inverse object transform) and record each voxel's rest-pose point. */
#define REST_RES 64
static nacre_result build_rest_grid(nc_pathtracer *pt, pt_object *o, const nc_object_rec *rec,
                                    const nacre_mesh_data *md)
{
    nacre_context *ctx = pt->ctx;
    float *def = nc_alloc(ctx, (size_t)md->vertex_count * 3 * sizeof(float));
    if (!def)
        return NACRE_ERROR_OUT_OF_MEMORY;
    for (uint32_t v = 0; v < md->vertex_count; v++)
        nc_v3store(nc_mat4_point(&o->world_to_rest, nc_v3a(rec->world_positions + 3 * (size_t)v)), def + 3 * (size_t)v);
    nacre_mesh_data dm = *md;
    dm.positions = def;
    nacre_voxel_settings vs = nacre_voxel_settings_defaults();
    vs.resolution = REST_RES;
    vs.anisotropic = true;
    nacre_voxel_grid *grid = NULL;
    nacre_voxel_report rep;
    nacre_result res = nacre_voxelize(ctx, &dm, &vs, &grid, &rep);
    if (res == NACRE_OK) {
        size_t n = (size_t)rep.dims[0] * rep.dims[1] * rep.dims[2];
        o->rest = nc_alloc(ctx, n * 3 * sizeof(float));
        if (!o->rest)
            res = NACRE_ERROR_OUT_OF_MEMORY;
        else
            res = nacre_voxel_grid_rest_positions(grid, md, &dm, o->rest);
        memcpy(o->rdims, rep.dims, sizeof(o->rdims));
        memcpy(o->rorigin, rep.origin, sizeof(o->rorigin));
        o->rvoxel = rep.voxel_size;
    }
    nacre_voxel_grid_destroy(grid);
    nc_free(ctx, def);
    return res;
}

/* Layers of object o's material: coefficients, the stack's depth ranges and a nearest-point
 * structure over the rest-pose mesh; the global majorant grows to cover every layer. */
static nacre_result setup_layers(nc_pathtracer *pt, const pt_scene *ps, pt_object *o, const nc_object_rec *rec, const nacre_mesh_data *md)
{
    const nacre_layering *l = &o->mat->layering;
    if (l->depth_map.id && !md->uvs)
        return nc_fail(pt->ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "pathtrace: object '%s': its layered material has a depth_map but its mesh has no uvs",
                       rec->name ? rec->name : "(unnamed)");
    nc_layers_init(ps->scene, l, &o->layers);
    for (uint32_t j = 0; j < o->layers.count; j++) {
        for (int c = 0; c < 3; c++) {
            o->layer_sa[j][c] = l->layers[j].sigma_a[c];
            o->layer_ss[j][c] = l->layers[j].sigma_s[c];
            o->maj_global = fmaxf(o->maj_global, o->layer_sa[j][c] + o->layer_ss[j][c]);
        }
        o->layer_g[j] = l->layers[j].g;
    }
    return nc_locator_create(pt->ctx, pt->device, md, &o->loc);
}

/* The world bounds of an object, padded a little, cut into res^3 cells: origin and cell size. */
static void grid_box(const nc_object_rec *rec, float eps, uint32_t res, float origin[3], float cell[3])
{
    for (int a = 0; a < 3; a++) {
        float lo = rec->bounds_min[a], hi = rec->bounds_max[a];
        float pad = 1e-3f * (hi - lo) + eps;
        origin[a] = lo - pad;
        cell[a] = (hi - lo + 2 * pad) / (float)res;
    }
}

/* Layer grid and majorant grid of a layered object. Depth below the rest-pose surface is
 * 1-Lipschitz, so over a cell whose centre maps to rest point q every depth lies within
 * d(q) +- r, r the cell's half diagonal times the largest stretch of the world-to-rest map
 * (bounded by the Frobenius norm of its linear part). The layers such depths can reach at any uv
 * (nc_layers_touching) are the cell's layer bits: a cell with one bit needs no nearest-point
 * query at all (medium_at). The layer grid has LAYER_RES cells a side (rounded to a multiple of
 * the majorant grid's), and a majorant cell bounds sigma_t by the layers of its layer cells, the
 * core counting with its global bound. Deformed objects map to rest space through a voxel lookup
 * without such a bound: no layer grid, and majorant cells keep the global majorant. */
#define LAYER_RES 64
static nacre_result build_grid_layered(nc_pathtracer *pt, const pt_scene *ps, pt_object *o, const nc_object_rec *rec)
{
    uint32_t res = pt->opt.majorant_res;
    size_t n = (size_t)res * res * res;
    if (res) {
        if (!(o->grid = nc_alloc(pt->ctx, n * sizeof(float))))
            return NACRE_ERROR_OUT_OF_MEMORY;
        o->res = res;
    }
    if (o->rest) {
        for (size_t i = 0; i < n; i++)
            o->grid[i] = o->maj_global;
        if (res)
            grid_box(rec, ps->eps, res, o->gmin, o->cell);
        return NACRE_OK;
    }
    uint32_t k = res ? (LAYER_RES / res > 1 ? LAYER_RES / res : 1) : 1;
    uint32_t lres = res ? res * k : LAYER_RES;
    size_t nl = (size_t)lres * lres * lres;
    o->lbits = nc_alloc(pt->ctx, nl);
    o->lhint = nc_alloc(pt->ctx, nl * sizeof(uint32_t));
    if (!o->lbits || !o->lhint)
        return NACRE_ERROR_OUT_OF_MEMORY;
    o->lres = lres;
    float half2 = 0, lcell[3];
    grid_box(rec, ps->eps, lres, o->lmin, lcell);
    for (int a = 0; a < 3; a++) {
        o->linv[a] = 1.0f / lcell[a];
        half2 += 0.25f * lcell[a] * lcell[a];
        if (res) {
            o->gmin[a] = o->lmin[a];
            o->cell[a] = lcell[a] * (float)k;
        }
    }
    float stretch2 = 0;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            stretch2 += o->world_to_rest.m[i][j] * o->world_to_rest.m[i][j];
    /* A little slack for the rounding of the distance query and of the map. */
    float r = sqrtf(half2 * stretch2) * 1.001f + 1e-6f;
#pragma omp parallel for schedule(dynamic, 64) num_threads(nc_threads(pt->ctx))
    for (int64_t ci = 0; ci < (int64_t)nl; ci++) {
        uint32_t cx = (uint32_t)ci % lres, cy = ((uint32_t)ci / lres) % lres, cz = (uint32_t)(ci / ((int64_t)lres * lres));
        nc_vec3 c = nc_v3(o->lmin[0] + lcell[0] * ((float)cx + 0.5f), o->lmin[1] + lcell[1] * ((float)cy + 0.5f),
                          o->lmin[2] + lcell[2] * ((float)cz + 0.5f));
        nc_vec3 q = nc_mat4_point(&o->world_to_rest, c);
        float qv[3] = {q.x, q.y, q.z}, uv[2];
        /* Past the deepest bottom by more than r the cell is core only (d = INFINITY says so). */
        uint32_t near = UINT32_MAX;
        float d = nc_locator_nearest(o->loc, qv, o->layers.hi[o->layers.count - 1] + r, &near, uv);
        o->lbits[ci] = (uint8_t)nc_layers_touching(&o->layers, d - r, d + r);
        o->lhint[ci] = near;
    }
    if (res == 0)
        return NACRE_OK;
    float bound[NACRE_MAX_LAYERS + 1];
    uint32_t count = o->layers.count;
    for (uint32_t j = 0; j < count; j++)
        bound[j] = fmaxf(o->layer_sa[j][0] + o->layer_ss[j][0],
                         fmaxf(o->layer_sa[j][1] + o->layer_ss[j][1], o->layer_sa[j][2] + o->layer_ss[j][2]));
    float core[3];
    nc_pt_medium_max_fn max_fn = pt->opt.max_sigma_t ? pt->opt.max_sigma_t : nc_medium_max_sigma_t;
    max_fn(ps->scene, o->mat, core);
    bound[count] = fmaxf(core[0], fmaxf(core[1], core[2]));
    for (size_t ci = 0; ci < n; ci++) {
        uint32_t cx = (uint32_t)ci % res, cy = ((uint32_t)ci / res) % res, cz = (uint32_t)(ci / ((size_t)res * res));
        uint32_t bits = 0;
        for (uint32_t z = cz * k; z < (cz + 1) * k; z++)
            for (uint32_t y = cy * k; y < (cy + 1) * k; y++)
                for (uint32_t x = cx * k; x < (cx + 1) * k; x++)
                    bits |= o->lbits[x + (size_t)lres * (y + (size_t)lres * z)];
        float m = 0;
        for (uint32_t j = 0; j <= count; j++)
            if (bits & (1u << j))
                m = fmaxf(m, bound[j]);
        o->grid[ci] = fminf(m, o->maj_global);
    }
    return NACRE_OK;
}

/* Majorant grid of a heterogeneous object: world bounds cut into res^3 cells, each bounding
 * sigma_t (max over channels) by the maximum over a 5^3 lattice of samples (cell faces included),
 * capped by the material's global bound. */
static nacre_result build_grid(nc_pathtracer *pt, const pt_scene *ps, pt_object *o, const nc_object_rec *rec)
{
    uint32_t res = pt->opt.majorant_res;
    if (res == 0)
        return NACRE_OK;
    size_t n = (size_t)res * res * res;
    o->grid = nc_alloc(pt->ctx, n * sizeof(float));
    if (!o->grid)
        return NACRE_ERROR_OUT_OF_MEMORY;
    o->res = res;
    grid_box(rec, ps->eps, res, o->gmin, o->cell);
    enum { S = 5 };
#pragma omp parallel for schedule(static) num_threads(nc_threads(pt->ctx))
    for (int64_t ci = 0; ci < (int64_t)n; ci++) {
        uint32_t cx = (uint32_t)ci % res, cy = ((uint32_t)ci / res) % res, cz = (uint32_t)ci / (res * res);
        float xyz[S * S * S * 3], sa[S * S * S * 3], ss[S * S * S * 3];
        int k = 0;
        for (int i = 0; i < S; i++)
            for (int j = 0; j < S; j++)
                for (int l = 0; l < S; l++) {
                    nc_vec3 w = nc_v3(o->gmin[0] + o->cell[0] * ((float)cx + (float)i / (S - 1)),
                                      o->gmin[1] + o->cell[1] * ((float)cy + (float)j / (S - 1)),
                                      o->gmin[2] + o->cell[2] * ((float)cz + (float)l / (S - 1)));
                    rest_point(o, w, xyz + 3 * k);
                    k++;
                }
        ps->eval(ps->scene, o->mat, xyz, (size_t)k, sa, ss);
        float m = 0;
        for (int q = 0; q < 3 * k; q++)
            m = fmaxf(m, sa[q] + ss[q]);
        o->grid[ci] = fminf(m, o->maj_global);
    }
    return NACRE_OK;
}

/* Mark cells overlapped by the box [lo, hi] (world) as surface cells. */
static void mark_box(pt_object *o, const float lo[3], const float hi[3])
{
    uint32_t i0[3], i1[3];
    for (int a = 0; a < 3; a++) {
        float f0 = floorf((lo[a] - o->dmargin - o->dorigin[a]) / o->dcell);
        float f1 = floorf((hi[a] + o->dmargin - o->dorigin[a]) / o->dcell);
        float top = (float)(o->ddims[a] - 1);
        if (!(f1 >= 0.0f) || !(f0 <= top))
            return; /* outside (or NaN): the grid's border already bounds it */
        i0[a] = f0 < 0.0f ? 0u : (uint32_t)f0;
        i1[a] = f1 > top ? o->ddims[a] - 1 : (uint32_t)f1;
    }
    for (uint32_t z = i0[2]; z <= i1[2]; z++)
        for (uint32_t y = i0[1]; y <= i1[1]; y++)
            memset(o->dist + i0[0] + (size_t)o->ddims[0] * (y + (size_t)o->ddims[1] * z), 0, i1[0] - i0[0] + 1);
}

/* One raster pass of the chessboard distance transform: each cell takes the minimum over its
 * 13 neighbours already visited in scan order (dir = +1 forward, -1 backward) plus one. Two
 * passes give the exact chessboard distance (Rosenfeld and Pfaltz 1966). */
static void chamfer_pass(uint8_t *d, const uint32_t dims[3], int dir)
{
    int64_t nx = dims[0], ny = dims[1], nz = dims[2];
    for (int64_t zz = 0; zz < nz; zz++)
        for (int64_t yy = 0; yy < ny; yy++)
            for (int64_t xx = 0; xx < nx; xx++) {
                int64_t x = dir > 0 ? xx : nx - 1 - xx, y = dir > 0 ? yy : ny - 1 - yy, z = dir > 0 ? zz : nz - 1 - zz;
                uint8_t *c = d + x + nx * (y + ny * z);
                int best = *c;
                if (best == 0)
                    continue;
                for (int dz = -1; dz <= 0; dz++)
                    for (int dy = -1; dy <= 1; dy++)
                        for (int dx = -1; dx <= 1; dx++) {
                            if (dz == 0 && (dy > 0 || (dy == 0 && dx >= 0)))
                                continue; /* not yet visited in this scan order */
                            int64_t qx = x + dir * dx, qy = y + dir * dy, qz = z + dir * dz;
                            if (qx < 0 || qy < 0 || qz < 0 || qx >= nx || qy >= ny || qz >= nz)
                                continue;
                            int v = d[qx + nx * (qy + ny * qz)] + 1;
                            best = v < best ? v : best;
                        }
                *c = (uint8_t)best;
            }
}

/* Clearance grid of medium object `o` (see clearance()): cubic cells over its bounds plus one
 * cell of border; cells touched by the bounding box of any triangle of any object, or of any
 * sphere light, are surface cells; cells are also at most their chessboard distance from the
 * outside of the grid, which stands for everything beyond it. The margin absorbs rounding in
 * cell lookups and Embree's hits reported a little before the surface. */
static nacre_result build_clearance(nc_pathtracer *pt, const pt_scene *ps, pt_object *o, const nc_object_rec *rec)
{
    if (pt->opt.no_clearance)
        return NACRE_OK;
    float ext = 0;
    for (int a = 0; a < 3; a++)
        ext = fmaxf(ext, rec->bounds_max[a] - rec->bounds_min[a]);
    if (!(ext > 0) || !isfinite(ext))
        return NACRE_OK;
    /* Cells of about half a mean free path of the densest channel make most flights provably
     * short; at most CLEARANCE_RES cells along the longest axis bound memory and build time. */
    float st = o->heterogeneous ? o->maj_global
                                : fminf(o->sigma_a[0] + o->sigma_s[0],
                                        fminf(o->sigma_a[1] + o->sigma_s[1], o->sigma_a[2] + o->sigma_s[2]));
    o->dcell = ext / (float)CLEARANCE_RES;
    if (st > 0.0f && 0.5f / st > o->dcell)
        o->dcell = fminf(0.5f / st, ext / (float)CLEARANCE_MIN_RES);
    /* Cells below the scene's float resolution (a tiny or degenerate object) would bound
     * nothing, and a zero cell size has no grid at all: no clearance then (Embree is asked). */
    if (!(o->dcell >= ps->eps) || !isfinite(o->dcell))
        return NACRE_OK;
    o->dinv = 1.0f / o->dcell;
    o->dmargin = 0.01f * o->dcell + 4.0f * ps->eps;
    size_t n = 1;
    for (int a = 0; a < 3; a++) {
        o->dorigin[a] = rec->bounds_min[a] - o->dcell;
        float cells = ceilf((rec->bounds_max[a] - rec->bounds_min[a]) / o->dcell) + 2.0f;
        o->ddims[a] = !(cells >= 1.0f) ? 1u : cells > (float)(CLEARANCE_RES + 4) ? CLEARANCE_RES + 4 : (uint32_t)cells;
        n *= o->ddims[a];
    }
    o->dist = nc_alloc(pt->ctx, n);
    if (!o->dist)
        return NACRE_ERROR_OUT_OF_MEMORY;
    for (uint32_t z = 0; z < o->ddims[2]; z++)
        for (uint32_t y = 0; y < o->ddims[1]; y++)
            for (uint32_t x = 0; x < o->ddims[0]; x++) {
                uint32_t c[3] = {x, y, z}, k = 255;
                for (int a = 0; a < 3; a++) {
                    uint32_t e = c[a] + 1 < o->ddims[a] - c[a] ? c[a] + 1 : o->ddims[a] - c[a];
                    k = e < k ? e : k;
                }
                o->dist[x + (size_t)o->ddims[0] * (y + (size_t)o->ddims[1] * z)] = (uint8_t)k;
            }
    for (uint32_t j = 0; j < pt->object_count; j++) {
        const pt_object *q = &pt->objects[j];
        for (uint32_t t = 0; t < q->tri_count; t++) {
            const uint32_t *tri = q->idx + 3 * (size_t)t;
            float lo[3], hi[3];
            for (int a = 0; a < 3; a++) {
                float v0 = q->pos[3 * (size_t)tri[0] + (size_t)a], v1 = q->pos[3 * (size_t)tri[1] + (size_t)a],
                      v2 = q->pos[3 * (size_t)tri[2] + (size_t)a];
                lo[a] = fminf(v0, fminf(v1, v2));
                hi[a] = fmaxf(v0, fmaxf(v1, v2));
            }
            mark_box(o, lo, hi);
        }
    }
    for (uint32_t li = 0; li < pt->light_count; li++) {
        const pt_light *l = &pt->lights[li];
        if (l->type == NACRE_LIGHT_DIRECTIONAL || l->delta)
            continue;
        float lo[3] = {l->pos.x - l->radius, l->pos.y - l->radius, l->pos.z - l->radius};
        float hi[3] = {l->pos.x + l->radius, l->pos.y + l->radius, l->pos.z + l->radius};
        mark_box(o, lo, hi);
    }
    chamfer_pass(o->dist, o->ddims, 1);
    chamfer_pass(o->dist, o->ddims, -1);
    return NACRE_OK;
}

/* Triangle adjacency of a dielectric object for make_guide's walk. Edges are matched by vertex
 * position, not index, so that seams (split normals or texture coordinates) do not stop the walk;
 * an edge shared by more than two triangles links none of them. */
typedef struct adj_edge {
    float a[3], b[3]; /* endpoints, lexicographically ordered */
    uint32_t slot;    /* 3 * triangle + edge */
} adj_edge;

static int cmp_point(const float *p, const float *q)
{
    for (int k = 0; k < 3; k++)
        if (p[k] != q[k])
            return p[k] < q[k] ? -1 : 1;
    return 0;
}

static int cmp_edge(const void *x, const void *y)
{
    const adj_edge *e = x, *f = y;
    int c = cmp_point(e->a, f->a);
    return c ? c : cmp_point(e->b, f->b);
}

static nacre_result build_adjacency(nc_pathtracer *pt, pt_object *o)
{
    size_t n = 3 * (size_t)o->tri_count;
    adj_edge *edges = nc_alloc(pt->ctx, n * sizeof(*edges));
    o->adj = nc_alloc(pt->ctx, n * sizeof(uint32_t));
    if (!edges || !o->adj) {
        nc_free(pt->ctx, edges);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    for (size_t i = 0; i < n; i++) {
        const float *p = o->pos + 3 * (size_t)o->idx[i], *q = o->pos + 3 * (size_t)o->idx[i % 3 == 2 ? i - 2 : i + 1];
        if (cmp_point(p, q) > 0) {
            const float *t = p;
            p = q;
            q = t;
        }
        memcpy(edges[i].a, p, sizeof(edges[i].a));
        memcpy(edges[i].b, q, sizeof(edges[i].b));
        edges[i].slot = (uint32_t)i;
        o->adj[i] = UINT32_MAX;
    }
    qsort(edges, n, sizeof(*edges), cmp_edge);
    for (size_t i = 0; i < n;) {
        size_t j = i + 1;
        while (j < n && cmp_edge(&edges[i], &edges[j]) == 0)
            j++;
        if (j == i + 2) {
            o->adj[edges[i].slot] = edges[i + 1].slot / 3;
            o->adj[edges[i + 1].slot] = edges[i].slot / 3;
        }
        i = j;
    }
    nc_free(pt->ctx, edges);
    return NACRE_OK;
}

static nacre_result build_scene(nc_pathtracer *pt, const nacre_scene *s, pt_scene *ps)
{
    nacre_context *ctx = pt->ctx;
    release_scene(pt);
    pt->objects = nc_calloc(ctx, s->object_count, sizeof(*pt->objects));
    pt->lights = nc_calloc(ctx, s->light_count + 1, sizeof(*pt->lights));
    if (!pt->objects || !pt->lights)
        return NACRE_ERROR_OUT_OF_MEMORY;
    pt->object_count = s->object_count;
    pt->any_matched = false;
    pt->any_noncaster = false;
    pt->nee_only = false;
    pt->rtc = rtcNewScene(pt->device);
    rtcSetSceneFlags(pt->rtc, RTC_SCENE_FLAG_ROBUST);
    rtcSetSceneBuildQuality(pt->rtc, RTC_BUILD_QUALITY_HIGH);
    nc_pt_medium_max_fn max_fn = pt->opt.max_sigma_t ? pt->opt.max_sigma_t : nc_medium_max_sigma_t;
    for (uint32_t i = 0; i < s->object_count; i++) {
        const nc_object_rec *rec = &s->objects[i];
        const nacre_mesh_data *md = &s->meshes[rec->desc.mesh.id - 1].data;
        const nacre_material_desc *m = &s->materials[rec->desc.material.id - 1];
        pt_object *o = &pt->objects[i];
        o->mat = m;
        o->pos = rec->world_positions;
        o->nrm = rec->world_normals;
        o->idx = md->indices;
        o->tri_count = md->triangle_count;
        o->g = m->g;
        o->eta = m->eta;
        if (m->type == NACRE_MATERIAL_OPAQUE) {
            o->kind = PT_OPAQUE;
            o->casts = rec->desc.cast_shadows;
            pt->any_noncaster |= !o->casts;
        } else {
            o->kind = m->eta == 1.0f ? PT_MATCHED : PT_DIELECTRIC;
            o->casts = true;
            pt->any_matched |= o->kind == PT_MATCHED;
            const bool layered = m->layering.count > 0;
            o->heterogeneous = nc_medium_heterogeneous(m) || layered || pt->opt.force_heterogeneous;
            float mx[3];
            max_fn(s, m, mx);
            o->maj_global = fmaxf(mx[0], fmaxf(mx[1], mx[2]));
            if (layered) {
                nacre_result res = setup_layers(pt, ps, o, rec, md);
                if (res != NACRE_OK)
                    return res;
            }
            for (int c = 0; c < 3; c++) {
                o->sigma_a[c] = m->sigma_a[c];
                o->sigma_s[c] = m->sigma_s[c];
            }
            nc_mat4_inverse(rec->object_to_world, &o->world_to_rest);
            if (o->kind == PT_DIELECTRIC) {
                nacre_result res = build_adjacency(pt, o);
                if (res != NACRE_OK)
                    return res;
            }
            if (o->heterogeneous) {
                nacre_result res = rec->desc.deformer_count > 0 ? build_rest_grid(pt, o, rec, md) : NACRE_OK;
                if (res != NACRE_OK)
                    return res;
                res = layered ? build_grid_layered(pt, ps, o, rec) : build_grid(pt, ps, o, rec);
                if (res != NACRE_OK)
                    return res;
            }
        }
        RTCGeometry g = rtcNewGeometry(pt->device, RTC_GEOMETRY_TYPE_TRIANGLE);
        /* Embree reads vertex buffers 16 bytes at a time: its own buffers are padded for that. */
        float *vb = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float),
                                            md->vertex_count);
        unsigned *ib = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned),
                                               md->triangle_count);
        if (!vb || !ib) {
            rtcReleaseGeometry(g);
            return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "pathtrace: Embree buffer allocation failed");
        }
        memcpy(vb, rec->world_positions, (size_t)md->vertex_count * 3 * sizeof(float));
        memcpy(ib, md->indices, (size_t)md->triangle_count * 3 * sizeof(unsigned));
        rtcCommitGeometry(g);
        rtcAttachGeometryByID(pt->rtc, g, i);
        rtcReleaseGeometry(g);
    }
    rtcCommitScene(pt->rtc);
    if (rtcGetDeviceError(pt->device) != RTC_ERROR_NONE)
        return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "pathtrace: Embree scene build failed");

    for (uint32_t i = 0; i < s->light_count; i++) {
        const nacre_light_desc *ld = &s->lights[i].desc;
        pt_light *l = &pt->lights[pt->light_count];
        nc_vec3 strength = nc_v3a(ld->strength);
        if (max3(strength) <= 0)
            continue;
        l->type = ld->type;
        l->desc = ld;
        if (ld->type == NACRE_LIGHT_DIRECTIONAL) {
            l->to_light = nc_normalize(nc_scale(nc_v3a(ld->direction), -1.0f));
            float r = ld->angular_radius * NC_DEG2RAD;
            l->delta = !(r > 0);
            if (l->delta) {
                l->value = strength;
            } else {
                float sr = sinf(r);
                l->cos_max = cosf(r);
                float one_minus = sr * sr / (1.0f + l->cos_max);
                l->cone_pdf = 1.0f / (2.0f * PT_PI * one_minus);
                l->value = nc_scale(strength, 1.0f / (PT_PI * sr * sr));
            }
        } else {
            l->pos = nc_v3a(ld->position);
            l->radius = ld->radius;
            l->delta = !(ld->radius > 0);
            l->value = l->delta ? strength : nc_scale(strength, 1.0f / (PT_PI * ld->radius * ld->radius));
        }
        pt->light_count++;
    }
    pt->fog_count = s->fog_count;
    pt->fog_mixed_g = false;
    for (uint32_t i = 0; i < s->fog_count; i++) {
        const nc_fog_rec *rec = &s->fogs[i];
        pt_fog *f = &pt->fogs[i];
        f->rec = rec;
        f->box = rec->desc.shape == NACRE_FOG_BOX;
        for (int a = 0; a < 3; a++)
            f->half[a] = 0.5f * rec->desc.size[a];
        f->patterned = nc_medium_heterogeneous(&rec->medium);
        float mx[3];
        max_fn(s, &rec->medium, mx);
        f->maj = fmaxf(mx[0], fmaxf(mx[1], mx[2]));
        f->height = rec->desc.height_falloff > 0;
        f->hexp = f->height ? 60.0f : 0.0f;
        if (f->maj > 0)
            f->hexp = fminf(f->hexp, logf(FOG_MAX_DENSITY / f->maj));
        f->falloff = rec->desc.height_falloff;
        f->base = rec->desc.height_base;
        f->g = rec->desc.g;
        pt->fog_mixed_g |= f->g != pt->fogs[0].g;
    }
    pt->nee_only = pt->any_noncaster;
    for (uint32_t li = 0; li < pt->light_count && !pt->opt.no_sun_guiding; li++) {
        const pt_light *l = &pt->lights[li];
        if (l->type != NACRE_LIGHT_DIRECTIONAL || l->delta)
            continue;
        /* The guided sun (the first one, as trace_path picks it). */
        for (uint32_t i = 0; i < pt->object_count; i++) {
            pt_object *o = &pt->objects[i];
            if (o->kind != PT_DIELECTRIC)
                continue;
            if (!(o->sun_dir = nc_alloc(ctx, 3 * (size_t)o->tri_count * sizeof(float))))
                return NACRE_ERROR_OUT_OF_MEMORY;
            for (uint32_t t = 0; t < o->tri_count; t++) {
                nc_vec3 dir = {NAN, 0, 0};
                refract_sun_facet(o, l, t, &dir);
                memcpy(o->sun_dir + 3 * (size_t)t, &dir, 3 * sizeof(float));
            }
        }
        break;
    }
    /* After every object and light is known: the grids record all of them. */
    for (uint32_t i = 0; i < pt->object_count; i++) {
        if (pt->objects[i].kind == PT_OPAQUE)
            continue;
        nacre_result res = build_clearance(pt, ps, &pt->objects[i], &s->objects[i]);
        if (res != NACRE_OK)
            return res;
    }
    return NACRE_OK;
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

/* Sample pp of pixel (x, y), which must be its next one (pixels see their passes in order), into
 * the pixel's mean and M2 (Welford). False when the deadline has passed: the sample, if it was
 * begun, is dropped. */
static bool sample_pixel(const pt_frame *fr, int32_t x, int32_t y, uint32_t pp, uint64_t *capped)
{
    if (fr->deadline_us && nc_now_us() >= fr->deadline_us)
        return false;
    pt_budget budget;
    budget_reset(&budget, fr->deadline_us);
    pt_scene ps = *fr->ps;
    ps.budget = &budget;
    size_t pi = (size_t)y * (size_t)fr->w + (size_t)x;
    nc_rng rng = nc_rng_make(((uint64_t)fr->seed << 32) | pp, pi);
    nc_vec3 o, d;
    camera_ray(&fr->cam, (float)x + nc_rng_float(&rng), (float)y + nc_rng_float(&rng), fr->w, fr->h, &o, &d);
    nc_vec3 L = trace_path(&ps, o, d, &rng);
    if (budget.expired)
        return false;
    *capped += budget.capped;
    nc_pathtracer *pt = fr->pt;
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

nacre_result nc_pathtrace_render(nc_pathtracer **state, nacre_context *ctx, const nacre_scene *scene,
                                 const nacre_render_settings *settings, nacre_image *out,
                                 nacre_render_stats *stats)
{
    if (!state || !scene || !settings || !out || !out->pixels)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "pathtrace: missing argument");
    if (settings->spp == 0 && !(settings->time_limit > 0))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: spp: must be >= 1 (or set a time limit)");
    if (!(settings->time_limit >= 0) || !isfinite(settings->time_limit))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "render: time_limit: must be finite and >= 0");
    int32_t w = settings->width, h = settings->height;
    if (out->width != w || out->height != h || out->channels != 3)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "pathtrace: output image must be %dx%d with 3 channels", w, h);
    nacre_result res;
    if (!*state && (res = nc_pathtracer_create(ctx, NULL, state)) != NACRE_OK)
        return res;
    nc_pathtracer *pt = *state;
    pt->valid = false;
    uint64_t t_start = nc_now_us();

    pt_scene ps;
    memset(&ps, 0, sizeof(ps));
    ps.scene = scene;
    ps.pt = pt;
    ps.eval = pt->opt.eval ? pt->opt.eval : nc_medium_eval;
    ps.env = nc_v3a(scene->environment);
    ps.env_on = max3(ps.env) > 0;
    ps.max_scatter = settings->max_scatter;
    float ext = 0;
    for (int a = 0; a < 3; a++)
        ext = fmaxf(ext, fmaxf(fabsf(scene->bounds_min[a]), fabsf(scene->bounds_max[a])));
    ps.eps = isfinite(ext) ? fmaxf(1e-5f * ext, 1e-7f) : 1e-5f; /* no objects: only fog */
    if ((res = build_scene(pt, scene, &ps)) != NACRE_OK)
        return res;

    size_t npix = (size_t)w * (size_t)h;
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
    pt->width = w;
    pt->height = h;

    pt_frame fr;
    fr.ps = &ps;
    fr.pt = pt;
    make_camera(scene, w, h, &fr.cam);
    fr.w = w;
    fr.h = h;
    fr.seed = settings->seed;
    fr.deadline_us = settings->time_limit > 0 ? t_start + (uint64_t)(settings->time_limit * 1e6) : 0;
    uint64_t capped = 0;
    enum { TILE = 16 };
    int32_t tiles_x = (w + TILE - 1) / TILE, tiles_y = (h + TILE - 1) / TILE;
    int64_t tiles = (int64_t)tiles_x * tiles_y;
    uint64_t t_trace = nc_now_us();
    uint32_t pass = 0;
    uint32_t max_pass = settings->spp ? settings->spp : UINT32_MAX;
    bool out_of_time = false;
    /* With a time limit the first pass visits the pixels in the order of an 8x8 Bayer matrix
     * over the image (every 64th pixel, then the ones halfway between, ...), so that a limit
     * reached within it leaves samples spread evenly (see fill_unsampled). */
    if (fr.deadline_us) {
        uint8_t bx[64], by[64];
        bayer_order(bx, by);
        int64_t blocks_y = (h + 7) / 8, items = 64 * blocks_y;
#pragma omp parallel for schedule(dynamic, 1) num_threads(nc_threads(ctx)) reduction(+ : capped)
        for (int64_t item = 0; item < items; item++) {
            int32_t r = (int32_t)(item / blocks_y), y = (int32_t)(item % blocks_y) * 8 + by[r];
            for (int32_t x = bx[r]; x < w && y < h; x += 8)
                if (!sample_pixel(&fr, x, y, 0, &capped))
                    break;
        }
        pass = 1;
        out_of_time = nc_now_us() >= fr.deadline_us;
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
        if (fr.deadline_us) {
            uint64_t now = nc_now_us();
            if (now >= fr.deadline_us)
                break;
            double per_pass = (double)(now - t_trace) * 1e-6 / pass;
            double left = (double)(fr.deadline_us - now) * 1e-6;
            double fit = per_pass > 0 ? floor(0.5 * left / per_pass) : 1;
            batch = fit < 1 ? 1 : fit < (double)batch ? (uint32_t)fit : batch;
        }
        uint32_t first = pass, last = pass + batch;
#pragma omp parallel for schedule(dynamic, 1) num_threads(nc_threads(ctx)) reduction(+ : capped)
        for (int64_t tile = 0; tile < tiles; tile++) {
            int32_t x0 = (int32_t)(tile % tiles_x) * TILE, y0 = (int32_t)(tile / tiles_x) * TILE;
            bool go = true;
            for (uint32_t pp = first; pp < last && go; pp++)
                for (int32_t y = y0; y < y0 + TILE && y < h && go; y++)
                    for (int32_t x = x0; x < x0 + TILE && x < w && go; x++)
                        go = sample_pixel(&fr, x, y, pp, &capped);
        }
        pass = last;
        out_of_time = fr.deadline_us && nc_now_us() >= fr.deadline_us;
    }
    double secs = (double)(nc_now_us() - t_trace) * 1e-6;
    uint32_t spp_min = UINT32_MAX;
    uint64_t samples = 0, unsampled = 0;
    for (size_t i = 0; i < npix; i++) {
        spp_min = pt->count[i] < spp_min ? pt->count[i] : spp_min;
        samples += pt->count[i];
        unsampled += pt->count[i] == 0;
    }
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
    return NACRE_OK;
}

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
