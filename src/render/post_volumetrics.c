/*
 * post_volumetrics.c: volumetric fog over the image and depth of a rasterizing method (Hubert
 * 2020, seed 003 §2.3), by two post passes that share one lighting of fog points:
 *   froxel    (§2.3.2; Wronski 2014, Hillaire 2015) a frustum-aligned grid of W x H columns and
 *             D depth slices. fill: every fog's sigma_t, sigma_s and phase g at each froxel's
 *             centre (fog_field.h: global and box fogs, height falloff, the pattern at the point);
 *             light: the in-scattered source per froxel; integrate: front to back along each
 *             column with the segment integral of §1.2.10 (exact for a homogeneous slice with a
 *             constant source); apply: c Tr + L (figure 2.18) with Tr and L read trilinearly at
 *             the pixel's depth, for opaque and translucent surfaces and the background alike.
 *   raymarch  (§2.3.1) the same lighting at the midpoints of raymarch_steps equal steps along
 *             each pixel's ray, integrated with the same segment integral: the froxels' check
 *             and the choice for close-ups (no grid to resolve). It also draws the isosurfaces
 *             of particle systems drawn as voxels (§3.2.2, figure 3.15; iso_shade below): the
 *             march stops at the surface, which reflects and refracts into the medium behind it.
 * Lighting of a point (§1.2.8 - 1.2.9): the source is sigma_s (sum over lights of E p(cos) V Tr
 * + L_env) + eps, eps the fogs' emission there (§1.2.11; it lights nothing else here), E the light's irradiance there (directional: its strength; point and spot:
 * intensity / distance^2 with the spot's falloff of scene/lights.h), p the Henyey-Greenstein
 * phase with the froxel's sigma_s-weighted g, V the opaque shadow from the light's shadow map
 * (the phong pass's maps; none when shadows are off), Tr the transmittance from the point
 * towards the light through every fog (§2.2.3, the fog's own shadow: closed form for fogs
 * without pattern, a march of shadow_steps through patterned ones, fog_field.h), and L_env the
 * environment taken as unshadowed isotropic ambient light, as in the analytic fog pass. The march
 * evaluates this per point in double; the froxels in float, 8 froxels of a column at a time
 * (froxel_light_column: global fogs without pattern in closed form, patterned ones from a coarse
 * grid, boxes without pattern exactly, a fast exponential), which the tests hold to the march.
 * Froxels whose sigma_s is 0 in every channel get no source (their emission aside) without
 * being lit: most of a particle system's grid.
 * The coarse grid reads each patterned box or sphere's optical depth towards each light from a
 * grid of its own that does not move with the camera (volume/light_volume.h: light-aligned
 * columns for directional lights, nodes over the box for point and spot lights).
 *
 * Depth slices: with a perspective camera slice 0 runs from the eye to z0 and slices 1 .. D-1
 * are spaced exponentially from z0 to zf (boundaries z0 (zf / z0)^(k / (D - 1))), zf the
 * farther of the camera's far plane and the farthest corner of a box fog, z0 = max(near / 2,
 * zf / 1000): fine slices where the scene begins, as many as possible over it. Orthographic
 * cameras get D equal slices from the near plane to zf. Beyond zf (the background, at
 * infinite depth), the remaining fog of each column ray that such a pixel reads is added in closed
 * form as in the analytic pass: the optical depth of every fog to infinity (height integral;
 * patterns at the segment's start), lit by the directional lights with the fog's transmittance
 * towards them at that start and by the environment, plus its emission (the pattern at that
 * start); point and spot lights add nothing there.
 *
 * Frames keep what did not change (froxel_apply; a viewer's frames): the filled grid while the
 * fogs, camera and grid settings are the same, the lit and integrated grid while the lights,
 * shadow settings and the depths that pixels read are too, each light's coarse optical depths
 * while that light did not move, each light's grids through the patterned boxes while that light
 * and the fogs did not change (a camera that moves keeps them), and a still frame's per-pixel L
 * and T. A kept frame equals a new one bit for bit (test_volumetrics); froxel_temporal keeps
 * nothing of the froxel grid (it moves).
 *
 * Results do not depend on the thread count: every column and pixel is computed alone.
 * Units: scene units along unit directions; coefficients per scene unit; radiance per channel.
 */
#include "core/core.h"
#include "core/optics.h"
#include "core/simd.h"
#include "particles/particles.h"
#include "render/method.h"
#include "scene/lights.h"
#include "scene/medium.h"
#include "volume/fog_field.h"
#include "volume/light_volume.h"

#include <math.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif

/* A light as the fog points need it. */
typedef struct vlight {
    nacre_light_type type;
    float pos[3], dir[3], e[3];
    float co, ci; /* spot: cos of the outer and inner half-angles */
    nacre_spot_falloff falloff;
    const nc_shadow_map *shadow;
} vlight;

/* The camera rays of the frame (as the analytic fog pass and the path tracer shoot them). */
typedef struct camera_rays {
    double inv_proj[4][4];
    double cam_to_world[3][4];
    bool ortho;
    double near, far; /* view-axis depths of the near and far planes */
} camera_rays;

/* A global fog without pattern, whose optical depth towards the lights the froxels take in closed
 * form (float; nc_vol_height_integral's cases). */
typedef struct vfog {
    const nc_fog_one *o;
    float sig_t[3]; /* where the height factor is 1 */
    float flat;     /* without falloff: the constant factor e^min(cap, 0) */
    float yc, fcap; /* with falloff: the height below which the factor is the constant fcap = e^cap */
} vfog;

/* What the froxel fill reads (fogs, camera, grid), then what the lighting reads besides (lights,
 * shadow maps), compared whole between frames: zeroed before being set, so padding compares. */
typedef struct fill_key {
    uint64_t uid, geometry, materials, environment, particles_built;
    nacre_volumetrics_settings vs;
    nacre_particles_draw particles;
    nc_mat4 view, proj;
    int32_t width, height;
    bool ortho;
} fill_key;

typedef struct light_key {
    uint64_t lights;
    nacre_shadow_settings shadow;
    nacre_method method;
    bool shadow_maps;
} light_key;

/* What one light's part of the coarse optical-depth grid depends on besides the fill and the
 * depths: where the light is (zeroed before being set). */
typedef struct tau_key {
    nacre_light_type type;
    float pos[3], dir[3];
} tau_key;

/* What a light's optical-depth grid through a bounded patterned fog depends on (light_volume.h):
 * the fogs (not the camera) and where the light is (zeroed before being set). */
typedef struct lvol_key {
    uint64_t uid, geometry, materials, environment, particles_built;
    nacre_particles_draw particles;
    uint32_t fog_count, fog, shadow_steps, res;
    nacre_light_type type;
    float pos[3], dir[3];
} lvol_key;

/* One light's grid through one fog, owned by vol_state (tau). */
typedef struct lvol {
    nc_light_volume v;
    float *tau;
    size_t capacity;
    lvol_key key;
    bool valid;
} lvol;

enum { SLICE_SHIFT = 18, SLICE_TABLE = 512 };

static inline uint32_t float_bits(float x)
{
    uint32_t u;
    memcpy(&u, &x, sizeof(u));
    return u;
}

typedef struct vol_state {
    nc_fog_field field;
    vfog gfog[NACRE_MAX_FOGS];
    uint32_t gfog_count;
    bool analytic_boxes; /* any box fog without pattern (exact per froxel, nc_fog_field_optical_depth) */
    bool tau_gray;       /* tau_grid's channels are equal: its first plane is all of them */
    vlight *lights;
    uint32_t light_capacity, light_count;
    /* Per light, the min-max table of its shadow map, which decides most of froxel_light's
     * lookups without their texels (made again when the map is re-rendered) */
    nc_shadow_minmax *shadow_mm;
    size_t shadow_mm_count;
    float env[3];
    float pcf, bias;
    camera_rays cam;
    /* froxel grid: W x H columns of D froxels, column-major in depth (index col * D + k) */
    uint32_t W, H, D;
    float *st, *ss, *src, *g; /* 3N each (sigma_t, sigma_s, the source after light), N */
    float *em;           /* 3N: emission (fill), added to the source by light; only if some fog emits */
    size_t em_capacity;
    /* Radiance and transmittance from the eye to boundaries 0 (the eye) .. D and infinity of
     * every column, column-major, 8 floats each (L rgb, -, T rgb, - at [col (D + 2) + b] x 8):
     * a pixel's lookup reads one vector per column and boundary, b and b + 1 side by side, and
     * froxel_integrate writes each column as one stream. */
    float *acc;
    /* froxel_apply_pixels' bilinear weights: per image column and per row (pixel_columns) */
    int32_t *px_i;
    float *px_w;
    size_t px_capacity, px_wcapacity;
    float *col_depth;     /* per column: the farthest depth of the pixels that read it */
    /* froxel_light's per column: the lit slices n, then [first, end) the lit ones that scatter
     * (end 0: none) */
    uint32_t *col_span;
    size_t col_span_capacity;
    /* Per column: col_empty, no medium in any froxel (sigma_t and emission 0: froxel_fill,
     * kept with the fill); col_clear, L 0 and T 1 at every boundary, the tail's included
     * (froxel_integrate; never with the temporal blend, which brings in the history's medium).
     * Pixels that read only clear columns are left as they are, and a clear column's boundaries
     * are written only where a pixel also reads a column that is not clear: a fog that fills a
     * part of the view (a box, a particle system) costs the columns it covers. */
    uint8_t *col_empty, *col_clear;
    size_t col_empty_capacity, col_clear_capacity;
    float *prev_col_depth; /* col_depth of the frame the lit grid was made for */
    float *row_depth;      /* column_depths' scratch: per image row and column */
    float *prev_depth;     /* the depth buffer of that frame */
    size_t col_capacity, prev_col_capacity, row_capacity, prev_depth_capacity;
    /* Frame-to-frame reuse (froxel_apply): the grid's fill, and its lighting and integration,
     * hold for these keys while the flags are set. */
    fill_key fkey;
    light_key lkey;
    bool fill_valid, light_valid;
    /* Per pixel L and T (rgb each) of the kept grid over prev_depth, made by the second frame
     * that keeps both (a still camera and scene): later ones only apply them. */
    float *px_tl;
    size_t px_tl_capacity;
    bool px_tl_valid;
    double *bound;        /* D + 1 view-axis depths of the slice boundaries */
    float slice_inv_b1, slice_scale; /* perspective: slice 1 + log(z / bound[1]) x slice_scale */
    /* Perspective: the slice at the start of each range of 2^SLICE_SHIFT float bit patterns from
     * boundf[1] (32 ranges an octave: the slices' own spacing is ~6 in the default grid), so
     * that depth_slot finds a pixel's slice without a logarithm; slice_table_n 0: not made. */
    uint16_t slice_table[SLICE_TABLE];
    uint32_t slice_table_n;
    bool slice_one_step; /* no range holds two boundaries: one compare finds the slice */
    float *boundf;                   /* bound in float (D + 1), then 1 / each slice's depth (D) */
    size_t boundf_capacity;
    size_t grid_capacity;
    /* Optical depth towards each light at the froxels of even indices (Wc x Hc x Dc nodes), per
     * light and node column 3 planes of Dc (one per channel: froxel_light_column interpolates a
     * plane 8 nodes at a time; with tau_gray only the first is written and read); tau_range: per light and node column, the nodes [lo, hi) outside
     * which all 3 planes are 0 (the froxels' rays that miss the fog's shadow skip it) */
    uint32_t Wc, Hc, Dc;
    float *tau_grid;
    uint32_t *tau_range;
    size_t tau_capacity, tau_range_capacity;
    /* The lights each part of tau_grid was made for (tau_count of them), kept while the fill and
     * the depths are; redo: per light, whether this frame remakes it */
    tau_key *tau_keys;
    bool *tau_redo;
    size_t tau_key_capacity, tau_redo_capacity;
    uint32_t tau_count;
    /* Per light and fog (index light x fog count + fog): the optical-depth grids of the bounded
     * patterned fogs that tau_grid reads (light_volume.h), kept while their keys hold. */
    lvol *lvols;
    size_t lvol_count;
    /* per-thread scratch */
    float *scratch;
    size_t scratch_per_thread, scratch_capacity;
    /* Temporal reprojection (volumetrics.temporal > 0): where in its slice each froxel samples
     * this frame (0.5 without), and the previous frame's blended sigma_t and source with what
     * locates them: its camera (world -> view, view -> clip), slice boundaries and jitter. */
    float jitter;
    uint32_t frame;       /* frames since the history began: picks the jitter */
    bool hist_valid;
    uint64_t hist_uid;
    uint32_t hW, hH, hD;
    float *hist_st, *hist_src; /* 3N each */
    size_t hist_capacity, hist_src_capacity;
    uint32_t *hist_lit;   /* per column: the slices that were lit (the others hold no source) */
    size_t hist_lit_capacity;
    double *hist_bound;   /* D + 1 */
    size_t hist_bound_capacity;
    double hist_view[3][4], hist_proj[4][4];
    float hist_jitter;
} vol_state;

/* ---- set-up ------------------------------------------------------------------------------ */

static void vol_destroy(nacre_context *ctx, void *state)
{
    vol_state *st = state;
    if (!st)
        return;
    nc_free(ctx, st->lights);
    for (size_t i = 0; i < st->shadow_mm_count; i++)
        nc_shadow_minmax_free(ctx, &st->shadow_mm[i]);
    nc_free(ctx, st->shadow_mm);
    nc_free(ctx, st->st);
    nc_free(ctx, st->ss);
    nc_free(ctx, st->src);
    nc_free(ctx, st->em);
    nc_free(ctx, st->prev_col_depth);
    nc_free(ctx, st->row_depth);
    nc_free(ctx, st->prev_depth);
    nc_free(ctx, st->px_tl);
    nc_free(ctx, st->g);
    nc_free(ctx, st->acc);
    nc_free(ctx, st->px_i);
    nc_free(ctx, st->px_w);
    nc_free(ctx, st->bound);
    nc_free(ctx, st->boundf);
    nc_free(ctx, st->tau_grid);
    nc_free(ctx, st->tau_range);
    nc_free(ctx, st->tau_keys);
    nc_free(ctx, st->tau_redo);
    for (size_t i = 0; i < st->lvol_count; i++)
        nc_free(ctx, st->lvols[i].tau);
    nc_free(ctx, st->lvols);
    nc_free(ctx, st->col_depth);
    nc_free(ctx, st->col_span);
    nc_free(ctx, st->col_empty);
    nc_free(ctx, st->col_clear);
    nc_free(ctx, st->scratch);
    nc_free(ctx, st->hist_st);
    nc_free(ctx, st->hist_src);
    nc_free(ctx, st->hist_bound);
    nc_free(ctx, st->hist_lit);
    nc_free(ctx, st);
}

static nacre_result vol_create(nacre_context *ctx, void **state)
{
    vol_state *st = nc_calloc(ctx, 1, sizeof(*st));
    if (!st)
        return NACRE_ERROR_OUT_OF_MEMORY;
    *state = st;
    return NACRE_OK;
}

static bool froxel_wanted(const nacre_scene *scene, const nacre_render_settings *settings)
{
    const nc_method *m = nc_method_get(settings->method);
    return nc_post_fogs_drawn(scene, settings) > 0 && m && !m->renders_fog &&
           settings->volumetrics.mode == NACRE_VOLUMETRICS_FROXEL && !nc_scene_particles_iso_drawn(scene, settings);
}

static bool raymarch_wanted(const nacre_scene *scene, const nacre_render_settings *settings)
{
    const nc_method *m = nc_method_get(settings->method);
    /* An isosurface needs a ray per pixel: froxels cannot hold a surface. */
    return nc_post_fogs_drawn(scene, settings) > 0 && m && !m->renders_fog &&
           (settings->volumetrics.mode == NACRE_VOLUMETRICS_RAYMARCH || nc_scene_particles_iso_drawn(scene, settings));
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
    cr->ortho = v->orthographic;
    /* The planes' depths from NDC z = 0 and 1 on the axis. */
    for (int k = 0; k < 2; k++) {
        double z = -(cr->inv_proj[2][2] * k + cr->inv_proj[2][3]) / (cr->inv_proj[3][2] * k + cr->inv_proj[3][3]);
        if (k == 0)
            cr->near = z;
        else
            cr->far = z;
    }
}

/* The camera ray through NDC (nx, ny): world origin o and unit direction d, and (scale, offset)
 * such that a view-axis depth z lies at ray distance z scale + offset. */
static void camera_ray(const camera_rays *cr, double nx, double ny, float o[3], float d[3], double *scale,
                       double *offset)
{
    double ov[3] = {0, 0, 0}, dv[3] = {0, 0, -1}, q[4];
    double nz = cr->ortho ? 0.0 : 1.0;
    for (int r = 0; r < 4; r++)
        q[r] = cr->inv_proj[r][0] * nx + cr->inv_proj[r][1] * ny + cr->inv_proj[r][2] * nz + cr->inv_proj[r][3];
    if (cr->ortho) {
        for (int k = 0; k < 3; k++)
            ov[k] = q[k] / q[3];
        *scale = 1.0;
        *offset = ov[2]; /* the ray starts on the near plane, at view z = ov[2] */
    } else {
        double sg = q[3] < 0 ? -1.0 : 1.0, len = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
        for (int k = 0; k < 3; k++)
            dv[k] = q[k] * sg / len;
        *scale = 1.0 / -dv[2];
        *offset = 0.0;
    }
    for (int r = 0; r < 3; r++) {
        const double *m = cr->cam_to_world[r];
        o[r] = (float)(m[0] * ov[0] + m[1] * ov[1] + m[2] * ov[2] + m[3]);
        d[r] = (float)(m[0] * dv[0] + m[1] * dv[1] + m[2] * dv[2]);
    }
}

static inline double ray_t(double z, double scale, double offset)
{
    double t = z * scale + offset;
    return t > 0.0 ? t : 0.0;
}

/* Floats of froxel_light_column's scratch for columns of up to d froxels. */
#define LIGHT_SCRATCH(d) ((17u + NACRE_MAX_FOGS) * (((size_t)(d) + 7) & ~(size_t)7))

/* Lights, fogs, environment and camera of the frame; per-thread scratch for batches of up to
 * `batch` points. */
static nacre_result vol_setup(vol_state *st, const nc_post_input *in, uint32_t batch)
{
    nacre_context *ctx = in->ctx;
    const nacre_scene *s = in->scene;
    const nacre_volumetrics_settings *vs = &in->settings->volumetrics;
    nc_fog_field_init(&st->field, s, nc_post_fogs_drawn(s, in->settings), vs->shadow_steps);
    if (s->light_count > st->light_capacity) {
        vlight *grown = nc_alloc(ctx, s->light_count * sizeof(*grown));
        if (!grown)
            return NACRE_ERROR_OUT_OF_MEMORY;
        nc_free(ctx, st->lights);
        st->lights = grown;
        st->light_capacity = s->light_count;
    }
    st->light_count = 0;
    for (uint32_t i = 0; i < s->light_count; i++) {
        const nacre_light_desc *ld = &s->lights[i].desc;
        vlight *l = &st->lights[st->light_count++];
        l->type = ld->type;
        memcpy(l->pos, ld->position, sizeof(l->pos));
        memcpy(l->dir, ld->direction, sizeof(l->dir));
        memcpy(l->e, ld->strength, sizeof(l->e));
        l->co = cosf(ld->outer_angle * (float)NC_DEG2RAD);
        l->ci = cosf(ld->inner_angle * (float)NC_DEG2RAD);
        l->falloff = ld->falloff;
        l->shadow = in->lights && i < in->light_count ? in->lights[i].shadow : NULL;
    }
    memcpy(st->env, s->environment, sizeof(st->env));
    /* A point in the air has no surface to soften: the smallest window (shafts stay sharp at
     * the map's resolution, and a lookup costs a quarter). */
    st->pcf = 0.5f;
    st->bias = in->settings->shadow.bias;
    camera_setup(in->view, &st->cam);
    /* The grid reaches past the camera's far plane (fitted to the objects) to the far corners
     * of the box fogs, so that lights shine on all of them; only global fog beyond that is left
     * to the closed-form tail. */
    const nc_mat4 *vm = &in->view->view;
    for (uint32_t i = 0; i < st->field.count; i++) {
        const nc_fog_rec *rec = &s->fogs[i];
        if (rec->desc.shape == NACRE_FOG_GLOBAL) /* a sphere's box bounds it: its corners serve */
            continue;
        nc_mat4 l2w;
        if (!nc_mat4_inverse(rec->world_to_local, &l2w))
            continue;
        for (int c = 0; c < 8; c++) {
            nc_vec3 q = nc_v3((c & 1 ? 0.5f : -0.5f) * rec->desc.size[0], (c & 2 ? 0.5f : -0.5f) * rec->desc.size[1],
                              (c & 4 ? 0.5f : -0.5f) * rec->desc.size[2]);
            double z = -nc_mat4_point(vm, nc_mat4_point(&l2w, q)).z;
            if (isfinite(z) && z > st->cam.far)
                st->cam.far = z;
        }
    }
    st->gfog_count = 0;
    st->analytic_boxes = false;
    for (uint32_t i = 0; i < st->field.count; i++) {
        const nc_fog_one *o = &st->field.fogs[i];
        if (o->patterned)
            continue;
        if (o->box) {
            st->analytic_boxes = true;
            continue;
        }
        vfog *v = &st->gfog[st->gfog_count++];
        v->o = o;
        for (int c = 0; c < 3; c++)
            v->sig_t[c] = o->sigma_a[c] + o->sigma_s[c];
        v->flat = o->hf_cap >= 0.0f ? 1.0f : expf(o->hf_cap);
        v->yc = o->hf_falloff > 0.0f ? o->hf_base - o->hf_cap / o->hf_falloff : -INFINITY;
        v->fcap = expf(o->hf_cap);
    }
    size_t per = 13u * batch + NC_FOG_EVAL_SCRATCH(batch) + NC_FOG_TAU_SCRATCH(vs->shadow_steps) +
                 LIGHT_SCRATCH(batch);
    size_t total = per * (size_t)(ctx->threads > 0 ? ctx->threads : 1);
    if (!nc_reserve(ctx, &st->scratch, &st->scratch_capacity, total, sizeof(float)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    st->scratch_per_thread = per;
    return NACRE_OK;
}

static float *thread_scratch(const vol_state *st)
{
    int tid = 0;
#ifdef _OPENMP
    tid = omp_get_thread_num();
#endif
    return st->scratch + (size_t)tid * st->scratch_per_thread;
}

/* ---- lighting of fog points ---------------------------------------------------------------- */

/* Where light l reaches point x: the way it travels (wi), the distance (INFINITY for
 * directional lights) and the factor of its strength there (1 / d^2, spot falloff); false if
 * it does not. */
static inline bool light_at(const vlight *li, const float x[3], float wi[3], float *dist, float *scale)
{
    *dist = INFINITY;
    *scale = 1.0f;
    if (li->type == NACRE_LIGHT_DIRECTIONAL) {
        memcpy(wi, li->dir, 3 * sizeof(float));
        return true;
    }
    float v[3] = {x[0] - li->pos[0], x[1] - li->pos[1], x[2] - li->pos[2]};
    float d2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    if (!(d2 > 0.0f))
        return false;
    *dist = sqrtf(d2);
    for (int c = 0; c < 3; c++)
        wi[c] = v[c] / *dist;
    *scale = 1.0f / d2;
    if (li->type == NACRE_LIGHT_SPOT) {
        float cs = wi[0] * li->dir[0] + wi[1] * li->dir[1] + wi[2] * li->dir[2];
        *scale *= nc_spot_falloff(li->falloff, cs, li->co, li->ci);
    }
    return *scale > 0.0f;
}

/* Optical depths beyond this are stored as this (e^-80: no light), so that infinite ones
 * interpolate. */
#define TAU_MAX 80.0f

/* The source (sigma_s x in-scattered radiance) at n points p seen along direction d (eye to
 * point): src[3k + c] from ss[3k + c] and g[k]. src may alias ss. The march's lighting: every
 * optical depth integrated here (froxel_light_column is the froxels' faster form). */
static void light_points(const vol_state *st, uint32_t n, const float *p, const float d[3], const float *ss,
                         const float *g, float *src, float *tau_scratch)
{
    for (uint32_t k = 0; k < n; k++) {
        const float *x = p + 3 * (size_t)k;
        float s[3] = {ss[3 * k], ss[3 * k + 1], ss[3 * k + 2]};
        if (!(s[0] > 0.0f || s[1] > 0.0f || s[2] > 0.0f)) {
            src[3 * k] = src[3 * k + 1] = src[3 * k + 2] = 0.0f;
            continue;
        }
        double acc[3] = {st->env[0], st->env[1], st->env[2]};
        for (uint32_t l = 0; l < st->light_count; l++) {
            const vlight *li = &st->lights[l];
            float wi[3], dist, scale;
            if (!light_at(li, x, wi, &dist, &scale))
                continue;
            float vis = 1.0f;
            if (li->shadow) {
                vis = nc_shadow_lookup_volume(li->shadow, nc_v3a(x), st->pcf, st->bias);
                if (!(vis > 0.0f))
                    continue;
            }
            float tau[3], w[3] = {-wi[0], -wi[1], -wi[2]};
            double td[3];
            nc_fog_field_optical_depth(&st->field, x, w, dist, NC_FOG_ALL, td, tau_scratch);
            for (int c = 0; c < 3; c++)
                tau[c] = td[c] < TAU_MAX ? (float)td[c] : TAU_MAX;
            float ph = nc_hg_phasef(-(d[0] * wi[0] + d[1] * wi[1] + d[2] * wi[2]), g[k]) * vis * scale;
            for (int c = 0; c < 3; c++)
                acc[c] += li->e[c] * ph * expf(-tau[c]);
        }
        for (int c = 0; c < 3; c++)
            src[3 * k + c] = (float)(s[c] * acc[c]);
    }
}

/* The fog beyond ray distance t0 along (o, d) to infinity, in closed form (see the top of the
 * file): radiance L and transmittance T per channel. */
static void tail(const vol_state *st, const float o[3], const float d[3], double t0, double L[3], double T[3],
                 float *tau_scratch)
{
    const nc_fog_field *f = &st->field;
    double tau[3] = {0, 0, 0}, acc[3] = {0, 0, 0}, tau_inf[3] = {0, 0, 0}, acc_inf[3] = {0, 0, 0};
    for (uint32_t i = 0; i < f->count; i++) {
        const nc_fog_one *fo = &f->fogs[i];
        double a = t0, b = INFINITY;
        if (!nc_fog_field_segment(fo, o, d, &a, &b))
            continue;
        double G = nc_vol_height_integral(&fo->h, o[1], d[1], a, b);
        if (!(G > 0.0))
            continue;
        float x[3] = {o[0] + (float)a * d[0], o[1] + (float)a * d[1], o[2] + (float)a * d[2]};
        float sa[3], ss[3];
        if (fo->patterned) {
            float q[3];
            for (int r = 0; r < 3; r++)
                q[r] = fo->w2l[r][0] * x[0] + fo->w2l[r][1] * x[1] + fo->w2l[r][2] * x[2] + fo->w2l[r][3];
            nc_medium_eval(f->scene, fo->medium, q, 1, sa, ss);
        } else {
            memcpy(sa, fo->sigma_a, sizeof(sa));
            memcpy(ss, fo->sigma_s, sizeof(ss));
        }
        float em[3];
        nc_fog_one_emission(f, fo, x, em);
        double S[3] = {st->env[0], st->env[1], st->env[2]};
        for (uint32_t l = 0; l < st->light_count; l++) {
            const vlight *li = &st->lights[l];
            if (li->type != NACRE_LIGHT_DIRECTIONAL)
                continue;
            float w[3] = {-li->dir[0], -li->dir[1], -li->dir[2]};
            double tl[3];
            nc_fog_field_optical_depth(f, x, w, INFINITY, NC_FOG_ALL, tl, tau_scratch);
            double ph = nc_hg_phase(-(d[0] * li->dir[0] + d[1] * li->dir[1] + d[2] * li->dir[2]), fo->g);
            for (int c = 0; c < 3; c++)
                if (isfinite(tl[c]))
                    S[c] += li->e[c] * ph * exp(-tl[c]);
        }
        bool diverges = isinf(G);
        for (int c = 0; c < 3; c++) {
            double sig_t = (double)sa[c] + ss[c];
            if (!(sig_t > 0.0)) {
                /* Emission in clear air: its integral, unattenuated (infinite: no limit). */
                if (em[c] > 0.0f)
                    acc[c] += diverges ? INFINITY : em[c] * G;
                continue;
            }
            if (diverges) {
                tau_inf[c] += sig_t;
                acc_inf[c] += ss[c] * S[c] + em[c];
            } else {
                tau[c] += sig_t * G;
                acc[c] += (ss[c] * S[c] + em[c]) * G;
            }
        }
    }
    for (int c = 0; c < 3; c++) {
        if (tau_inf[c] > 0.0) {
            L[c] = acc_inf[c] / tau_inf[c];
            T[c] = 0.0;
            continue;
        }
        T[c] = exp(-tau[c]);
        L[c] = acc[c] * nc_vol_exp_ratio_t(tau[c], T[c]);
    }
}

/* ---- froxels ----------------------------------------------------------------------------- */

static nacre_result grid_setup(vol_state *st, nacre_context *ctx, const nacre_volumetrics_settings *vs)
{
    st->W = vs->froxel_width;
    st->H = vs->froxel_height;
    st->D = vs->froxel_slices;
    size_t cols = (size_t)st->W * st->H, n = cols * st->D;
    /* Columns never outnumber froxels: the accumulated boundaries (n + 2 cols) fit in 3n. */
    if (n > st->grid_capacity) {
        nc_free(ctx, st->st);
        nc_free(ctx, st->ss);
        nc_free(ctx, st->src);
        nc_free(ctx, st->g);
        nc_free(ctx, st->acc);
        nc_free(ctx, st->bound);
        st->st = nc_alloc(ctx, 3 * n * sizeof(float));
        st->ss = nc_alloc(ctx, 3 * n * sizeof(float));
        st->src = nc_alloc(ctx, 3 * n * sizeof(float));
        st->g = nc_alloc(ctx, n * sizeof(float));
        st->acc = nc_alloc(ctx, 24 * n * sizeof(float));
        st->bound = nc_alloc(ctx, (n + 1) * sizeof(double));
        st->grid_capacity = 0;
        st->fill_valid = st->light_valid = false;
        if (!st->st || !st->ss || !st->src || !st->g || !st->acc || !st->bound)
            return NACRE_ERROR_OUT_OF_MEMORY;
        st->grid_capacity = n;
    }
    if (st->field.emissive && !nc_reserve(ctx, &st->em, &st->em_capacity, 3 * n, sizeof(float)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    const camera_rays *cr = &st->cam;
    uint32_t D = st->D;
    if (!nc_reserve(ctx, &st->boundf, &st->boundf_capacity, 2 * (size_t)D + 1, sizeof(float)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    if (cr->ortho) {
        for (uint32_t k = 0; k <= D; k++)
            st->bound[k] = cr->near + (cr->far - cr->near) * k / D;
    } else {
        double zf = cr->far, z0 = fmax(0.5 * cr->near, 1e-3 * zf);
        st->bound[0] = 0.0;
        if (D == 1) {
            st->bound[1] = zf;
        } else {
            for (uint32_t k = 1; k <= D; k++)
                st->bound[k] = z0 * pow(zf / z0, (double)(k - 1) / (D - 1));
            st->slice_inv_b1 = (float)(1.0 / st->bound[1]);
            st->slice_scale = (float)((D - 1) / log(st->bound[D] / st->bound[1]));
        }
    }
    for (uint32_t k = 0; k <= D; k++)
        st->boundf[k] = (float)st->bound[k];
    for (uint32_t k = 0; k < D; k++)
        st->boundf[D + 1 + k] = (float)(1.0 / (st->bound[k + 1] - st->bound[k]));
    st->slice_table_n = 0;
    st->slice_one_step = false;
    if (!cr->ortho && D > 1 && st->boundf[1] > 0.0f && st->boundf[D] > st->boundf[1]) {
        uint32_t b1 = float_bits(st->boundf[1]), n = ((float_bits(st->boundf[D]) - b1) >> SLICE_SHIFT) + 1;
        if (n <= SLICE_TABLE) {
            uint32_t k = 1;
            for (uint32_t i = 0; i < n; i++) {
                uint32_t at = b1 + (i << SLICE_SHIFT);
                float z;
                memcpy(&z, &at, sizeof(z));
                while (k + 1 < D && z >= st->boundf[k + 1])
                    k++;
                st->slice_table[i] = (uint16_t)k;
            }
            st->slice_table_n = n;
            /* Boundaries between two ranges' starts (and after the last start, below bf[D]). */
            st->slice_one_step = D - 1 - st->slice_table[n - 1] <= 1;
            for (uint32_t i = 0; i + 1 < n; i++)
                st->slice_one_step = st->slice_one_step && st->slice_table[i + 1] - st->slice_table[i] <= 1;
        }
    }
    return NACRE_OK;
}

/* Column (i, j)'s ray through its centre. */
static void column_ray(const vol_state *st, uint32_t i, uint32_t j, float o[3], float d[3], double *scale,
                       double *offset)
{
    double nx = (i + 0.5) / st->W * 2.0 - 1.0, ny = 1.0 - (j + 0.5) / st->H * 2.0;
    camera_ray(&st->cam, nx, ny, o, d, scale, offset);
}

/* 4 doubles and 4 floats, for the depths of column_points and froxel_integrate's running sums
 * (GCC and Clang vector extensions, as core/simd.h) */
typedef double v4d __attribute__((vector_size(32)));
typedef int64_t v4l __attribute__((vector_size(32)));
typedef float v4f __attribute__((vector_size(16)));

/* lo and hi as one vector, in registers (two halves stored and read back as one vector would
 * stall on the stores) */
static inline nc_v8f v8_halves(v4f lo, v4f hi)
{
#ifdef __AVX__
    return (nc_v8f)_mm256_set_m128((__m128)hi, (__m128)lo);
#else
    nc_v8f v;
    memcpy(&v, &lo, sizeof(lo));
    memcpy((float *)&v + 4, &hi, sizeof(hi));
    return v;
#endif
}

/* The D froxel centres of a column ray, 8 at a time: each slice's depth in double as the ray
 * distance was always taken, then the 8 points in float, stored as triples in p, or with p NULL
 * in the planes xyz[0..2] (the lighting's layout; each padded to a multiple of 8 with the last
 * point). */
static void column_points(const vol_state *st, const float o[3], const float d[3], double scale, double offset,
                          float *p, float *const xyz[3])
{
    const double *b = st->bound;
    double jit = st->jitter;
    bool mid = st->jitter == 0.5f;
    uint32_t D = st->D, k0 = 0;
    for (; k0 + 8 <= D; k0 += 8) {
        /* ray_t in double, 4 slices a half; clamped after rounding to float, which gives the
         * same floats */
        v4f t[2];
        for (int h = 0; h < 2; h++) {
            v4d b0, b1, z;
            memcpy(&b0, b + k0 + 4 * h, sizeof(b0));
            memcpy(&b1, b + k0 + 4 * h + 1, sizeof(b1));
            if (mid)
                z = 0.5 * (b0 + b1);
            else
                z = b0 + jit * (b1 - b0);
            t[h] = __builtin_convertvector(z * scale + offset, v4f);
        }
        nc_v8f tv = v8_halves(t[0], t[1]);
        tv = nc_v8_sel(tv > 0.0f, tv, (nc_v8f){0});
        nc_v8f x = o[0] + tv * d[0], y = o[1] + tv * d[1], z = o[2] + tv * d[2];
        if (!p) {
            nc_v8_store(xyz[0] + k0, x);
            nc_v8_store(xyz[1] + k0, y);
            nc_v8_store(xyz[2] + k0, z);
            continue;
        }
        nc_v8i a, bb, c;
        nc_v8_interleave3((nc_v8i)x, (nc_v8i)y, (nc_v8i)z, &a, &bb, &c);
        nc_v8i_store((int32_t *)(void *)(p + 3 * k0), a);
        nc_v8i_store((int32_t *)(void *)(p + 3 * k0 + 8), bb);
        nc_v8i_store((int32_t *)(void *)(p + 3 * k0 + 16), c);
    }
    for (uint32_t k = k0; k < D; k++) {
        double z = mid ? 0.5 * (b[k] + b[k + 1]) : b[k] + jit * (b[k + 1] - b[k]);
        float t = (float)ray_t(z, scale, offset);
        for (int c = 0; c < 3; c++) {
            if (p)
                p[3 * k + c] = o[c] + t * d[c];
            else
                xyz[c][k] = o[c] + t * d[c];
        }
    }
    for (uint32_t k = D; !p && k % 8 != 0; k++)
        for (int c = 0; c < 3; c++)
            xyz[c][k] = xyz[c][D - 1];
}

static void froxel_fill(vol_state *st, int threads)
{
    int64_t cols = (int64_t)st->W * st->H;
    /* Without a global fog, a column whose ray misses every fog holds no medium, and its
     * froxels are 0 (as nc_fog_field_eval gives them outside the fogs) without being evaluated.
     * The shapes are tested a little larger (1e-4 of their size, and 1e-4 units), so that no
     * point that rounding puts inside a fog is missed. */
    nc_fog_one padded[NACRE_MAX_FOGS];
    bool bounded = st->field.count > 0;
    for (uint32_t f = 0; f < st->field.count && bounded; f++) {
        padded[f] = st->field.fogs[f];
        bounded = padded[f].box;
        for (int k = 0; k < 3; k++)
            padded[f].half[k] = padded[f].half[k] * (1.0f + 1e-4f) + 1e-4f;
    }
#pragma omp parallel for schedule(static) num_threads(threads)
    for (int64_t col = 0; col < cols; col++) {
        float *sc = thread_scratch(st), *p = sc, *ev = sc + 13u * st->D;
        float o[3], d[3];
        double scale, offset;
        column_ray(st, (uint32_t)(col % st->W), (uint32_t)(col / st->W), o, d, &scale, &offset);
        size_t base = (size_t)col * st->D;
        bool hit = !bounded;
        for (uint32_t f = 0; f < st->field.count && !hit; f++) {
            double a = 0.0, b = ray_t(st->bound[st->D], scale, offset) * (1.0 + 1e-4) + 1e-4;
            hit = nc_fog_field_segment(&padded[f], o, d, &a, &b);
        }
        if (!hit) {
            memset(st->st + 3 * base, 0, 3 * (size_t)st->D * sizeof(float));
            memset(st->ss + 3 * base, 0, 3 * (size_t)st->D * sizeof(float));
            memset(st->g + base, 0, (size_t)st->D * sizeof(float));
            if (st->field.emissive)
                memset(st->em + 3 * base, 0, 3 * (size_t)st->D * sizeof(float));
            st->col_empty[col] = 1;
            continue;
        }
        column_points(st, o, d, scale, offset, p, NULL);
        nc_fog_field_eval(&st->field, st->D, p, st->st + 3 * base, st->ss + 3 * base, st->g + base, ev);
        if (st->field.emissive)
            nc_fog_field_emission(&st->field, st->D, p, st->em + 3 * base, ev);
        /* A NaN counts as medium: only a column surely empty is empty. */
        int any = 0;
        const float *sg = st->st + 3 * base, *em = st->field.emissive ? st->em + 3 * base : NULL;
        for (size_t k = 0; k < 3 * (size_t)st->D; k++)
            any |= sg[k] != 0.0f;
        for (size_t k = 0; st->field.emissive && k < 3 * (size_t)st->D; k++)
            any |= em[k] != 0.0f;
        st->col_empty[col] = !any;
    }
}

/* Froxels that a pixel reads in a column whose pixels reach view depth z: the slices that begin
 * at or before it. */
static uint32_t lit_slices(const vol_state *st, float z)
{
    /* bound rises: the count of bound[0 .. D - 1] <= z, by bisection */
    uint32_t lo = 0, hi = st->D;
    while (lo < hi) {
        uint32_t mid = (lo + hi) / 2;
        if (st->bound[mid] <= z)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

/* The optical-depth grid of every light through every bounded patterned fog (light_volume.h),
 * each rebuilt only when its light or the fogs changed: a camera that moves keeps them all. */
static nacre_result light_volumes_update(vol_state *st, const nc_post_input *in, int threads)
{
    nacre_context *ctx = in->ctx;
    const nacre_scene *s = in->scene;
    uint32_t count = st->field.count;
    size_t need = (size_t)st->light_count * count;
    if (need > st->lvol_count) {
        lvol *grown = nc_calloc(ctx, need, sizeof(*grown));
        if (!grown)
            return NACRE_ERROR_OUT_OF_MEMORY;
        if (st->lvol_count)
            memcpy(grown, st->lvols, st->lvol_count * sizeof(*grown));
        nc_free(ctx, st->lvols);
        st->lvols = grown;
        st->lvol_count = need;
    }
    for (uint32_t l = 0; l < st->light_count; l++) {
        const vlight *li = &st->lights[l];
        bool directional = li->type == NACRE_LIGHT_DIRECTIONAL;
        for (uint32_t i = 0; i < count; i++) {
            const nc_fog_one *o = &st->field.fogs[i];
            if (!o->patterned || !o->box)
                continue;
            lvol *e = &st->lvols[(size_t)l * count + i];
            lvol_key k;
            memset(&k, 0, sizeof(k));
            k.uid = s->uid;
            k.geometry = s->committed.geometry;
            k.materials = s->committed.materials;
            k.environment = s->committed.environment;
            k.particles_built = s->particles_built;
            k.particles = in->settings->particles;
            k.fog_count = count;
            k.fog = i;
            k.shadow_steps = st->field.shadow_steps;
            k.res = directional ? NC_LIGHT_VOLUME_DIR_RES : NC_LIGHT_VOLUME_POINT_RES;
            k.type = li->type;
            if (directional)
                memcpy(k.dir, li->dir, sizeof(k.dir));
            else
                memcpy(k.pos, li->pos, sizeof(k.pos));
            /* The fog record's address moves with the field; the grid's data does not. */
            nc_light_volume_setup(&e->v, o, directional, li->dir, li->pos, k.res);
            if (e->valid && memcmp(&k, &e->key, sizeof(k)) == 0) {
                e->v.tau = e->tau;
                continue;
            }
            e->valid = false;
            if (!nc_reserve(ctx, &e->tau, &e->capacity, 3 * nc_light_volume_nodes(&e->v), sizeof(float)))
                return NACRE_ERROR_OUT_OF_MEMORY;
            e->v.tau = e->tau;
            nc_light_volume_build(&st->field, &e->v, threads);
            e->key = k;
            e->valid = true;
        }
    }
    return NACRE_OK;
}

/* Optical depth towards light l through the patterned fogs at the 8 points X, Y, Z (lanes q <
 * count, the others 0; tau[8c + q], capped at TAU_MAX; 0 where light_at finds no light): the
 * bounded fogs from their grids (light_volumes_update, 8 lookups at a time), the global ones
 * marched (box_tau8 is the form without global ones). */
static void patterned_tau8(const vol_state *st, uint32_t l, const float *X, const float *Y, const float *Z,
                           uint32_t count, float *tau, float *scratch)
{
    float w[8][3], dist[8];
    bool lit[8];
    double td[8][3];
    for (uint32_t q = 0; q < count; q++) {
        const float x[3] = {X[q], Y[q], Z[q]};
        float wi[3] = {0, 0, 0}, sf;
        lit[q] = light_at(&st->lights[l], x, wi, &dist[q], &sf);
        for (int c = 0; c < 3; c++) {
            w[q][c] = -wi[c];
            td[q][c] = 0.0;
        }
    }
    for (uint32_t i = 0; i < st->field.count; i++) {
        const nc_fog_one *o = &st->field.fogs[i];
        if (!o->patterned)
            continue;
        if (!o->box) {
            for (uint32_t q = 0; q < count; q++) {
                const float x[3] = {X[q], Y[q], Z[q]};
                if (lit[q])
                    nc_fog_one_optical_depth(&st->field, o, x, w[q], dist[q], td[q], scratch);
            }
            continue;
        }
        float t[24];
        nc_light_volume_lookup8(&st->lvols[(size_t)l * st->field.count + i].v, X, Y, Z, t);
        for (uint32_t q = 0; q < count; q++)
            for (int c = 0; c < 3 && lit[q]; c++)
                td[q][c] += t[8 * c + q];
    }
    for (uint32_t q = 0; q < 8; q++)
        for (int c = 0; c < 3; c++)
            tau[8 * c + q] = q >= count ? 0.0f : td[q][c] < TAU_MAX ? (float)td[q][c] : TAU_MAX;
}

/* Which of the 8 points X, Y, Z light l reaches, as light_at answers lane by lane: a directional
 * light every point; a point light those at a distance d with 0 < d^2 < inf (1 / d^2 > 0); a
 * spot those with the cosine c to its axis inside its outer cone (nc_spot_falloff > 0) besides.
 * The arithmetic here is not light_at's (another order, other fused products), so the lanes
 * where that could decide take light_at itself: d^2 beyond 1e30 (near overflow, or 1 / d^2 x a
 * small falloff near underflow), and for a spot d^2 below 1e-30 (subnormal squares) or c within
 * 1e-4 of the cone's cosine or, for the Cycles falloff (c x a step), of 0. Elsewhere the falloff
 * is above 1e-12 or 0 and both cosines are within a few ulps of each other. */
static nc_v8i lit8(const vlight *li, const float *X, const float *Y, const float *Z)
{
    if (li->type == NACRE_LIGHT_DIRECTIONAL)
        return (nc_v8i){0} == 0;
    nc_v8f vx = nc_v8_load(X) - li->pos[0], vy = nc_v8_load(Y) - li->pos[1], vz = nc_v8_load(Z) - li->pos[2];
    nc_v8f d2 = vx * vx + vy * vy + vz * vz;
    /* Fused or not, a sum of squares is 0 only if each square rounds to 0: d2 > 0 as light_at's. */
    nc_v8i positive = d2 > 0.0f, unsure = positive & ~(d2 < 1e30f), lit = positive & ~unsure;
    if (li->type == NACRE_LIGHT_SPOT && nc_v8_bits(lit)) {
        const nc_v8i abs_mask = (nc_v8i){0} + 0x7fffffff; /* fabsf: the sign bit cleared */
        nc_v8f c = (vx * li->dir[0] + vy * li->dir[1] + vz * li->dir[2]) / nc_v8_sqrt(nc_v8_sel(lit, d2, nc_v8_splat(1.0f)));
        nc_v8i odd = ~(d2 >= 1e-30f) | ~((nc_v8f)((nc_v8i)(c - li->co) & abs_mask) > 1e-4f);
        nc_v8i inside = c > li->co;
        if (li->falloff == NACRE_SPOT_FALLOFF_CYCLES) {
            odd |= ~((nc_v8f)((nc_v8i)c & abs_mask) > 1e-4f);
            inside &= c > 0.0f;
        }
        unsure |= lit & odd;
        lit &= ~odd & inside;
    }
    for (uint32_t b = nc_v8_bits(unsure); b; b &= b - 1) {
        int q = __builtin_ctz(b);
        const float x[3] = {X[q], Y[q], Z[q]};
        float wi[3], dist, scale;
        lit[q] = light_at(li, x, wi, &dist, &scale) ? -1 : 0;
    }
    return lit;
}

/* patterned_tau8 when every patterned fog is bounded (their optical depths all come from their
 * light grids), 8 lanes at once: tau[8c + q] (channel planes). The same sums in the same order
 * as patterned_tau8's (in double, fog after fog, then rounded to float and capped, 0 where the
 * light does not reach), so the results are equal bit for bit; gray: every such fog is gray
 * (light_volume.h), and channel 0 is every channel. False, with tau not written, where every
 * lane is 0: outside every grid's reach (most of the frame, for a small cloud), or unlit. */
static bool box_tau8(const vol_state *st, uint32_t l, const float *X, const float *Y, const float *Z, bool gray,
                     float *tau)
{
    typedef double v8d __attribute__((vector_size(64)));
    const nc_v8f zero = {0};
    const lvol *grids = st->lvols + (size_t)l * st->field.count;
    uint32_t reached = 0, fog_reach[NACRE_MAX_FOGS];
    for (uint32_t i = 0; i < st->field.count; i++) {
        fog_reach[i] = st->field.fogs[i].patterned ? nc_light_volume_reach8(&grids[i].v, X, Y, Z) : 0;
        reached |= fog_reach[i];
    }
    if (!reached)
        return false;
    const nc_v8i lit = lit8(&st->lights[l], X, Y, Z);
    if (!nc_v8_bits(lit))
        return false;
    const int channels = gray ? 1 : 3;
    v8d acc[3] = {{0}, {0}, {0}};
    for (uint32_t i = 0; i < st->field.count; i++) {
        /* A grid that reaches none of the lanes adds +0 (its lookups are >= +0), as before. */
        if (!fog_reach[i])
            continue;
        float t[24];
        nc_light_volume_lookup8(&grids[i].v, X, Y, Z, t);
        for (int c = 0; c < channels; c++)
            acc[c] += __builtin_convertvector(nc_v8_load(t + 8 * c), v8d);
    }
    for (int c = 0; c < channels; c++) {
        /* Capped after the rounding: a sum below TAU_MAX that rounds to it is TAU_MAX either way. */
        nc_v8f r = __builtin_convertvector(acc[c], nc_v8f);
        nc_v8_store(tau + 8 * c, nc_v8_sel(lit, nc_v8_sel(r < TAU_MAX, r, nc_v8_splat(TAU_MAX)), zero));
    }
    if (gray) {
        memcpy(tau + 8, tau, 8 * sizeof(float));
        memcpy(tau + 16, tau, 8 * sizeof(float));
    }
    return true;
}

/* A froxel that scatters nothing (sigma_s 0 in every channel) has no source whatever its light:
 * the lighting skips it (in a particle system's grid most froxels are empty). */
static inline bool scatters(const float *ss)
{
    /* On the bits (NaN counts as not 0): a branch-free test that the compaction loops can take
     * per froxel. */
    uint32_t b = float_bits(ss[0]) | float_bits(ss[1]) | float_bits(ss[2]);
    return (b & 0x7fffffffu) != 0;
}

/* Bit k set where froxel k of the 8 at ss (3 words each) scatters: scatters() 8 at a time. */
static inline uint32_t scatter_bits8(const float *ss)
{
    nc_v8i x, y, z;
    nc_v8_deinterleave3(nc_v8i_load((const int32_t *)(const void *)ss),
                        nc_v8i_load((const int32_t *)(const void *)(ss + 8)),
                        nc_v8i_load((const int32_t *)(const void *)(ss + 16)), &x, &y, &z);
    return nc_v8_bits(((x | y | z) & 0x7fffffff) != 0);
}

/* Whether every one of the n froxels at ss scatters. */
static bool span_scatters(const float *ss, uint32_t n)
{
    uint32_t k = 0;
    for (; k + 8 <= n; k += 8)
        if (scatter_bits8(ss + 3 * (size_t)k) != 0xffu)
            return false;
    for (; k < n; k++)
        if (!scatters(ss + 3 * (size_t)k))
            return false;
    return true;
}

/* The first froxel of the n at ss that scatters (*a) and one past the last (*b); a = b = 0 if
 * none does. */
static void scatter_span(const float *ss, uint32_t n, uint32_t *a, uint32_t *b)
{
    uint32_t lo = n, hi = 0, k = 0;
    for (; k + 8 <= n; k += 8) {
        uint32_t bits = scatter_bits8(ss + 3 * (size_t)k);
        if (!bits)
            continue;
        lo = lo < n ? lo : k + (uint32_t)__builtin_ctz(bits);
        hi = k + 32u - (uint32_t)__builtin_clz(bits);
    }
    for (; k < n; k++)
        if (scatters(ss + 3 * (size_t)k)) {
            lo = lo < n ? lo : k;
            hi = k + 1;
        }
    *a = lo < hi ? lo : 0;
    *b = lo < hi ? hi : 0;
}

/* Most depth slices a column can have (renderer.c's check of froxel_slices). */
#define MAX_SLICES 1024u

/* The coarse grid of the patterned fogs' optical depths towards the lights (nodes at the
 * froxels of even indices): their shadow on themselves varies slowly next to the opaque
 * shadows, so it is looked up (bounded fogs: their light grids) or marched (global ones) at 1/8
 * of the froxels and interpolated in optical depth. Fogs without pattern stay exact per
 * froxel (closed form, and a box's walls are sharp). Only nodes that a lit froxel which scatters
 * reads are made (the others hold 0). With `keep` (the fill and the depths are the previous
 * frame's), the part of each light that did not move is kept. */
static nacre_result tau_grid_fill(vol_state *st, nacre_context *ctx, int threads, uint32_t batch, bool keep)
{
    st->Wc = (st->W + 1) / 2;
    st->Hc = (st->H + 1) / 2;
    st->Dc = (st->D + 1) / 2;
    size_t cols_c = (size_t)st->Wc * st->Hc, nodes = cols_c * st->Dc, need = nodes * 3 * st->light_count;
    size_t caps[3] = {st->tau_capacity, st->tau_range_capacity, st->tau_key_capacity};
    if (!nc_reserve(ctx, &st->tau_grid, &st->tau_capacity, need, sizeof(float)) ||
        !nc_reserve(ctx, &st->tau_range, &st->tau_range_capacity, 2 * cols_c * st->light_count, sizeof(uint32_t)) ||
        !nc_reserve(ctx, &st->tau_keys, &st->tau_key_capacity, st->light_count, sizeof(tau_key)) ||
        !nc_reserve(ctx, &st->tau_redo, &st->tau_redo_capacity, st->light_count, sizeof(bool))) {
        st->tau_count = 0;
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    /* A grown array holds nothing of the previous frame. */
    if (!keep || caps[0] != st->tau_capacity || caps[1] != st->tau_range_capacity || caps[2] != st->tau_key_capacity)
        st->tau_count = 0;
    bool any = false;
    for (uint32_t l = 0; l < st->light_count; l++) {
        tau_key k;
        memset(&k, 0, sizeof(k));
        k.type = st->lights[l].type;
        if (k.type == NACRE_LIGHT_DIRECTIONAL)
            memcpy(k.dir, st->lights[l].dir, sizeof(k.dir));
        else
            memcpy(k.pos, st->lights[l].pos, sizeof(k.pos));
        st->tau_redo[l] = !(l < st->tau_count && memcmp(&k, &st->tau_keys[l], sizeof(k)) == 0);
        st->tau_keys[l] = k;
        any = any || st->tau_redo[l];
    }
    /* Every patterned fog bounded: box_tau8 (gray: and all of them gray, so that the grid's
     * three channels are equal). */
    bool boxes = true, gray = true;
    for (uint32_t i = 0; i < st->field.count; i++) {
        const nc_fog_one *o = &st->field.fogs[i];
        if (o->patterned) {
            boxes = boxes && o->box;
            gray = gray && nc_light_volume_fog_gray(o);
        }
    }
    st->tau_gray = boxes && gray;
    /* Valid once the loop below has run (it cannot fail). */
    st->tau_count = st->light_count;
    if (!any)
        return NACRE_OK;
    int64_t cols = (int64_t)cols_c;
    uint32_t Dc = st->Dc;
    const int planes = st->tau_gray ? 1 : 3; /* the ones froxel_light_column reads */
#pragma omp parallel for schedule(dynamic, 4) num_threads(threads)
    for (int64_t cc = 0; cc < cols; cc++) {
        float *sc = thread_scratch(st), *p = sc, *tau = sc + 13u * batch + NC_FOG_EVAL_SCRATCH(batch);
        /* The nodes' points, one array per coordinate, the last used one repeated to a multiple
         * of 8: each light reads them 8 at a time. */
        float NX[MAX_SLICES / 2 + 8], NY[MAX_SLICES / 2 + 8], NZ[MAX_SLICES / 2 + 8];
        float o[3], d[3];
        double scale, offset;
        uint32_t gi = (uint32_t)(cc % st->Wc), gj = (uint32_t)(cc / st->Wc);
        /* Nodes that a lit froxel which scatters reads (froxel_light: froxels k of the columns
         * 2g - 1 .. 2g + 1 read nodes k / 2 and (k + 1) / 2, within the columns' spans); the
         * others are never read, and set to 0. */
        uint32_t first = Dc, used = 0;
        for (uint32_t j = gj > 0 ? 2 * gj - 1 : 0; j <= 2 * gj + 1 && j < st->H; j++)
            for (uint32_t i = gi > 0 ? 2 * gi - 1 : 0; i <= 2 * gi + 1 && i < st->W; i++) {
                const uint32_t *span = st->col_span + 3 * ((size_t)j * st->W + i);
                if (span[2] == 0)
                    continue;
                uint32_t c0 = span[1] / 2, c1 = span[2] / 2 < Dc ? span[2] / 2 : Dc - 1;
                first = c0 < first ? c0 : first;
                used = c1 + 1 > used ? c1 + 1 : used;
            }
        if (used > 0) {
            column_ray(st, 2 * gi, 2 * gj, o, d, &scale, &offset);
            column_points(st, o, d, scale, offset, p, NULL);
            for (uint32_t c = first, end = first + ((used - first + 7) & ~7u); c < end; c++) {
                const float *x = p + 6 * (size_t)(c < used ? c : used - 1);
                NX[c] = x[0], NY[c] = x[1], NZ[c] = x[2];
            }
        }
        for (uint32_t l = 0; l < st->light_count; l++) {
            if (!st->tau_redo[l])
                continue;
            float *out = st->tau_grid + 3 * ((size_t)l * nodes + (size_t)cc * Dc);
            uint32_t *range = st->tau_range + 2 * ((size_t)l * cols_c + (size_t)cc), lo = Dc, hi = 0;
            memset(out, 0, (size_t)planes * Dc * sizeof(float));
            for (uint32_t c0 = first; c0 < used; c0 += 8) {
                /* 8 nodes at a time (the last repeated past used) */
                uint32_t count = used - c0 < 8 ? used - c0 : 8;
                float t[24];
                if (boxes) {
                    if (!box_tau8(st, l, NX + c0, NY + c0, NZ + c0, gray, t))
                        continue; /* 0, as written */
                } else {
                    patterned_tau8(st, l, NX + c0, NY + c0, NZ + c0, count, t, tau);
                }
                for (int ch = 0; ch < planes; ch++)
                    memcpy(out + (size_t)ch * Dc + c0, t + 8 * ch, count * sizeof(float));
                nc_v8i nonzero = (nc_v8_load(t) != 0.0f) | (nc_v8_load(t + 8) != 0.0f) | (nc_v8_load(t + 16) != 0.0f);
                uint32_t bits = nc_v8_bits(nonzero & nc_v8_first(count));
                if (bits) {
                    uint32_t a = c0 + (uint32_t)__builtin_ctz(bits);
                    lo = a < lo ? a : lo;
                    hi = c0 + 32 - (uint32_t)__builtin_clz(bits);
                }
            }
            range[0] = lo;
            range[1] = hi;
        }
    }
    return NACRE_OK;
}

/* Froxel index i on the coarse grid of n nodes: nodes a0, a1 and the weight of a1. */
static inline void coarse(uint32_t i, uint32_t n, uint32_t *a0, uint32_t *a1, float *w)
{
    *a0 = i / 2;
    *a1 = *a0 + 1 < n ? *a0 + 1 : *a0;
    *w = (i & 1) && *a1 != *a0 ? 0.5f : 0.0f;
}

/* Pixel coordinate x of an image n wide on a grid of m columns: the two columns its bilinear
 * lookup reads (froxel_apply_pixels) and the weight of the second. */
static inline void pixel_columns(int32_t x, int32_t n, uint32_t m, int32_t *i0, int32_t *i1, float *w)
{
    float f = (x + 0.5f) * (float)m / (float)n - 0.5f;
    *i0 = (int32_t)floorf(f);
    *w = f - (float)*i0;
    if (*i0 < 0)
        *i0 = 0, *w = 0.0f;
    *i1 = *i0 + 1 < (int32_t)m ? *i0 + 1 : *i0;
    if (*i1 == *i0)
        *w = 0.0f;
}

/* The columns and rows that each image column and row reads (pixel_columns), for column_depths
 * and froxel_apply_pixels. */
static nacre_result pixel_tables(vol_state *st, nacre_context *ctx, int32_t w, int32_t h)
{
    if (!nc_reserve(ctx, &st->px_i, &st->px_capacity, 2 * ((size_t)w + (size_t)h), sizeof(int32_t)) ||
        !nc_reserve(ctx, &st->px_w, &st->px_wcapacity, (size_t)w + (size_t)h, sizeof(float)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    int32_t *xi = st->px_i, *yi = st->px_i + 2 * (size_t)w;
    float *xw = st->px_w, *yw = st->px_w + w;
    for (int32_t x = 0; x < w; x++)
        pixel_columns(x, w, st->W, &xi[2 * x], &xi[2 * x + 1], &xw[x]);
    for (int32_t y = 0; y < h; y++)
        pixel_columns(y, h, st->H, &yi[2 * y], &yi[2 * y + 1], &yw[y]);
    return NACRE_OK;
}

/* The farthest depth that any pixel reads from each column: froxels behind it are never seen
 * (a column behind a wall is integrated, but no pixel looks past the wall), so they are not lit.
 * First per image row and column of froxels, then per row of froxels over the image rows that
 * read it (a maximum does not depend on the order). */
static nacre_result column_depths(vol_state *st, nacre_context *ctx, const float *depth, int32_t w, int32_t h,
                                  int threads)
{
    size_t cols = (size_t)st->W * st->H, rows = (size_t)h * st->W;
    if (!nc_reserve(ctx, &st->col_depth, &st->col_capacity, cols, sizeof(float)) ||
        !nc_reserve(ctx, &st->row_depth, &st->row_capacity, rows, sizeof(float)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    const int32_t *xi = st->px_i, *yi = st->px_i + 2 * (size_t)w;
#pragma omp parallel for schedule(static) num_threads(threads)
    for (int32_t y = 0; y < h; y++) {
        float *row = st->row_depth + (size_t)y * st->W;
        for (uint32_t i = 0; i < st->W; i++)
            row[i] = 0.0f;
        const float *dr = depth + (size_t)y * (size_t)w;
        for (int32_t x = 0; x < w; x++) {
            float z = dr[x];
            int32_t i0 = xi[2 * x], i1 = xi[2 * x + 1];
            if (!(z <= row[i0]))
                row[i0] = z;
            if (!(z <= row[i1]))
                row[i1] = z;
        }
    }
#pragma omp parallel for schedule(static) num_threads(threads)
    for (int32_t j = 0; j < (int32_t)st->H; j++) {
        float *row = st->col_depth + (size_t)j * st->W;
        for (uint32_t i = 0; i < st->W; i++)
            row[i] = 0.0f;
        for (int32_t y = 0; y < h; y++) {
            if (yi[2 * y] != j && yi[2 * y + 1] != j)
                continue;
            const float *r = st->row_depth + (size_t)y * st->W;
            for (uint32_t i = 0; i < st->W; i++)
                if (!(r[i] <= row[i]))
                    row[i] = r[i];
        }
    }
    return NACRE_OK;
}

/* ---- the froxels' lighting, 8 froxels of a column at a time (core/simd.h) ------------------- */

/* nc_vol_height_integral of global fog v (with a falloff) in float along rays from heights y
 * with direction y components wy over [0, len] (finite; a point light at height y_end, where the
 * height factor is f_end), given the factors f_y at y. Where the segment rises by h (after its
 * capped stretch below yc), the integral of e^(-k y) is (f_lo - f_hi) / (k s): the factors at
 * both ends are known, so no exponential is taken; below k s rest = 0.1 the difference cancels,
 * and the series of rest f_lo (1 - e^-x) / x is used. The case of a directional light (len
 * infinite) is froxel_light_column's. */
static inline nc_v8f v8_height_integral(const vfog *v, nc_v8f y, nc_v8f wy, nc_v8f len, nc_v8f f_y, float y_end,
                                        float f_end)
{
    float k = v->o->hf_falloff;
    nc_v8f s = nc_v8_sel(wy >= 0.0f, wy, -wy);
    nc_v8i here = wy >= 0.0f; /* the point is the lower end */
    nc_v8f y_lo = nc_v8_sel(here, y, nc_v8_splat(y_end)), f_lo = nc_v8_sel(here, f_y, nc_v8_splat(f_end));
    nc_v8f f_hi = nc_v8_sel(here, nc_v8_splat(f_end), f_y);
    nc_v8i below = y_lo < v->yc;
    nc_v8f ks = k * s, inv_ks = nc_v8_rcp(ks); /* s = 0: level, taken at the end */
    nc_v8f to_cap = (v->yc - y_lo) * (k * inv_ks);
    nc_v8f capped = nc_v8_sel(below, nc_v8_sel(to_cap < len, to_cap, len), (nc_v8f){0});
    f_lo = nc_v8_sel(below, nc_v8_splat(v->fcap), f_lo);
    nc_v8f rest = len - capped, x = ks * rest;
    nc_v8f series = rest * f_lo * nc_vol_exp_ratio_series8(x);
    nc_v8f total = capped * f_lo + nc_v8_sel(x < 0.1f, series, (f_lo - f_hi) * inv_ks);
    return nc_v8_sel(s == 0.0f, len * f_lo, total); /* level: constant density */
}

/* The froxels' lighting of one column (light_points' sum, by light over groups of 8 froxels in
 * SoA arrays): n froxels, whose centres column_points put in the first 3 planes of ls, seen along d, src[3k + c] from ss[3k + c] and g[k]; src
 * may alias ss. Only the froxels in span[1] .. span[2] - 1 that scatter are lit, packed (the
 * others' source is 0). The optical depth towards a light is the sum of the patterned fogs'
 * coarse grid (interpolated; cn, cw: the grid's 4 columns around this one and their weights, cn
 * NULL without patterned fogs; once for all channels where st->tau_gray), the global fogs
 * without pattern in closed form and the boxes without pattern exactly
 * (nc_fog_field_optical_depth, sharp walls); its exponential is nc_vol_transmittance8's. The
 * opaque shadow is looked up per froxel. Square roots and divisions are nc_v8_rsqrt's and
 * nc_v8_rcp's (relative 2^-22), which keep them off the divider. */
static void froxel_light_column(const vol_state *st, uint32_t n, const uint32_t span[3], const float d[3], const float *ss, const float *g, float *src, const size_t cn[4],
                                const float cw[4], float *ls, float *tau_scratch)
{
    /* The froxels that scatter, in order (span_bits: all of them, the common case, when the
     * span is the whole column). */
    int32_t idx[MAX_SLICES];
    uint32_t m = 0;
    bool all = span[1] == 0 && span[2] == n && span_scatters(ss, n);
    if (all) {
        m = n;
    } else {
        for (uint32_t k = span[1]; k < span[2]; k++) {
            idx[m] = (int32_t)k;
            m += scatters(ss + 3 * (size_t)k);
        }
    }
    if (m == 0) {
        memset(src, 0, 3 * (size_t)n * sizeof(float));
        return;
    }
    bool packed = !all; /* else idx is 0 .. n - 1 */
    const size_t S = ((size_t)st->D + 7) & ~(size_t)7;
    const uint32_t m8 = (m + 7) & ~7u;
    /* X, Y, Z: the froxel centres (column_points' planes, padded to 8 with the last one) */
    float *X = ls, *Y = ls + S, *Z = ls + 2 * S, *PA = ls + 3 * S, *F = ls + 4 * S;
    float *A[3] = {ls + 5 * S, ls + 6 * S, ls + 7 * S}, *T[3] = {ls + 8 * S, ls + 9 * S, ls + 10 * S};
    float *CG = ls + 11 * S, *HF = ls + 14 * S; /* CG: 3 x S, a node per 2 froxels plus padding */
    float *PB = HF + NACRE_MAX_FOGS * S, *PC = PB + S; /* PA, PB, PC: the phase's constants */
    if (packed) {
        /* Lanes past m repeat the last froxel (their results are not used); idx[k] >= k, so the
         * planes compact in place. */
        for (uint32_t k = m; k < m8; k++)
            idx[k] = idx[m - 1];
        for (uint32_t k = 0; k < m8; k++) {
            uint32_t q = (uint32_t)idx[k];
            X[k] = X[q];
            Y[k] = Y[q];
            Z[k] = Z[q];
            F[k] = g[q];
        }
    } else {
        memcpy(F, g, n * sizeof(float));
        for (uint32_t k = n; k < m8; k++)
            F[k] = g[n - 1];
    }
    for (uint32_t k = 0; k < m8; k += 8) {
        nc_v8f gk = nc_v8_load(F + k), g2 = gk * gk;
        nc_v8_store(PA + k, 1.0f + g2);
        nc_v8_store(PB + k, -2.0f * gk);
        nc_v8_store(PC + k, (1.0f - g2) * (float)(1.0 / (4.0 * NC_PI)));
        for (int c = 0; c < 3; c++)
            nc_v8_store(A[c] + k, nc_v8_splat(st->env[c]));
    }
    /* Each global fog's height factor at the froxels, shared by all lights. */
    for (uint32_t f = 0; f < st->gfog_count; f++) {
        const nc_fog_one *o = st->gfog[f].o;
        for (uint32_t k = 0; k < m8; k += 8) {
            nc_v8f e = -o->hf_falloff * (nc_v8_load(Y + k) - o->hf_base);
            nc_v8f hf = o->height ? nc_vol_exp_fast8(nc_v8_sel(e < o->hf_cap, e, nc_v8_splat(o->hf_cap)))
                                  : nc_v8_splat(st->gfog[f].flat);
            nc_v8_store(HF + f * S + k, hf);
        }
    }
    const size_t cols_c = (size_t)st->Wc * st->Hc, nodes = cols_c * st->Dc;
    const int channels = st->tau_gray ? 1 : 3; /* of the coarse grid that differ */
    for (uint32_t l = 0; l < st->light_count; l++) {
        const vlight *li = &st->lights[l];
        if (!(li->e[0] != 0.0f || li->e[1] != 0.0f || li->e[2] != 0.0f))
            continue; /* it would add e F Tr = 0 */
        bool directional = li->type == NACRE_LIGHT_DIRECTIONAL;
        /* The coarse grid's nodes where any of the 4 columns around this one is not 0. */
        uint32_t used = n / 2 + 1 < st->Dc ? n / 2 + 1 : st->Dc, lo = used, hi = 0;
        for (int q = 0; cn && q < 4; q++) {
            const uint32_t *r = st->tau_range + 2 * ((size_t)l * cols_c + cn[q]);
            lo = r[0] < lo ? r[0] : lo;
            hi = r[1] > hi ? r[1] : hi;
        }
        hi = hi < used ? hi : used;
        if (lo < hi) {
            /* The 4 grid columns around this one (per channel; 0 outside [lo, hi), the last node
             * repeated past the used ones), then linear in depth: even froxels on the nodes, odd
             * ones halfway (x = 0.5 (x + x) exactly). */
            const float *grid = st->tau_grid + 3 * (size_t)l * nodes;
            uint32_t half = (n + 1) / 2;
            for (int c = 0; c < channels; c++) {
                const float *g0 = grid + (3 * cn[0] + (size_t)c) * st->Dc, *g1 = grid + (3 * cn[1] + (size_t)c) * st->Dc,
                            *g2 = grid + (3 * cn[2] + (size_t)c) * st->Dc, *g3 = grid + (3 * cn[3] + (size_t)c) * st->Dc;
                float *cg = CG + c * S, *t = T[c];
                for (uint32_t kc = 0; kc < lo; kc++)
                    cg[kc] = 0.0f;
                for (uint32_t kc = lo; kc < hi; kc++)
                    cg[kc] = cw[0] * g0[kc] + cw[1] * g1[kc] + cw[2] * g2[kc] + cw[3] * g3[kc];
                for (uint32_t kc = hi; kc < used; kc++)
                    cg[kc] = 0.0f;
                for (uint32_t kc = used; kc <= half; kc++)
                    cg[kc] = cg[used - 1];
                if (packed) {
                    for (uint32_t q = 0; q < m8; q++)
                        t[q] = 0.5f * (cg[idx[q] >> 1] + cg[(idx[q] + 1) >> 1]);
                    continue;
                }
                for (uint32_t h = 0; h < half; h++) {
                    t[2 * h] = cg[h];
                    t[2 * h + 1] = 0.5f * (cg[h] + cg[h + 1]);
                }
                for (uint32_t k = 2 * half; k < m8; k++)
                    t[k] = t[n - 1];
            }
            for (int c = channels; c < 3; c++)
                memcpy(T[c], T[0], m8 * sizeof(float));
        } else {
            for (int c = 0; c < 3; c++)
                memset(T[c], 0, m8 * sizeof(float));
        }
        if (directional) {
            nc_v8f cs = nc_v8_splat(-(d[0] * li->dir[0] + d[1] * li->dir[1] + d[2] * li->dir[2]));
            float wy = -li->dir[1], inv_wy = 1.0f / wy;
            for (uint32_t k = 0; k < m8; k += 8)
                nc_v8_store(F + k, nc_vol_hg_phase8(cs, nc_v8_load(PA + k), nc_v8_load(PB + k), nc_v8_load(PC + k)));
            for (uint32_t f = 0; f < st->gfog_count; f++) {
                const vfog *v = &st->gfog[f];
                float kf = v->o->hf_falloff, tail = 1.0f / (kf * wy);
                for (uint32_t k = 0; k < m8; k += 8) {
                    nc_v8f hf = nc_v8_load(HF + f * S + k), y = nc_v8_load(Y + k), G;
                    if (!(kf > 0.0f) || wy < 0.0f) {
                        G = nc_v8_splat(INFINITY); /* constant or denser fog forever */
                    } else if (wy == 0.0f) {
                        G = nc_v8_sel(hf > 0.0f, nc_v8_splat(INFINITY), (nc_v8f){0});
                    } else {
                        /* Rising forever: the capped stretch below yc, then the integral of e^(-k wy t). */
                        nc_v8i below = y < v->yc;
                        nc_v8f f_lo = nc_v8_sel(below, nc_v8_splat(v->fcap), hf);
                        nc_v8f capped = nc_v8_sel(below, (v->yc - y) * inv_wy, (nc_v8f){0});
                        G = capped * f_lo + f_lo * tail;
                    }
                    for (int c = 0; c < 3; c++)
                        if (v->sig_t[c] > 0.0f)
                            nc_v8_store(T[c] + k, nc_v8_load(T[c] + k) + v->sig_t[c] * G);
                }
            }
        } else {
            float hl[NACRE_MAX_FOGS];
            for (uint32_t f = 0; f < st->gfog_count; f++) {
                const nc_fog_one *o = st->gfog[f].o;
                hl[f] = o->height ? nc_vol_exp_fast(fminf(o->hf_cap, -o->hf_falloff * (li->pos[1] - o->hf_base)))
                                  : st->gfog[f].flat;
            }
            const nc_v8f zero = {0};
            const nc_v8i hard = (nc_v8i){0} - (int32_t)(li->ci <= li->co); /* nc_spot_falloff8's */
            for (uint32_t k = 0; k < m8; k += 8) {
                nc_v8f vx = nc_v8_load(X + k) - li->pos[0], vy = nc_v8_load(Y + k) - li->pos[1],
                       vz = nc_v8_load(Z + k) - li->pos[2];
                nc_v8f d2 = vx * vx + vy * vy + vz * vz;
                nc_v8i valid = d2 > 0.0f;
                nc_v8f inv = nc_v8_rsqrt(d2), dist = d2 * inv;
                nc_v8f wx = vx * inv, wyv = vy * inv, wz = vz * inv;
                nc_v8f scale = inv * inv;
                if (li->type == NACRE_LIGHT_SPOT)
                    scale *= nc_spot_falloff8(li->falloff, wx * li->dir[0] + wyv * li->dir[1] + wz * li->dir[2],
                                              li->co, li->ci, hard);
                nc_v8f cs = -(d[0] * wx + d[1] * wyv + d[2] * wz);
                nc_v8f ph = nc_vol_hg_phase8(cs, nc_v8_load(PA + k), nc_v8_load(PB + k), nc_v8_load(PC + k));
                nc_v8_store(F + k, nc_v8_sel(valid, ph * scale, zero));
                for (uint32_t f = 0; f < st->gfog_count; f++) {
                    const vfog *v = &st->gfog[f];
                    nc_v8f G = v->o->hf_falloff > 0.0f
                                   ? v8_height_integral(v, nc_v8_load(Y + k), -wyv, dist, nc_v8_load(HF + f * S + k),
                                                        li->pos[1], hl[f])
                                   : dist * v->flat;
                    G = nc_v8_sel(valid, G, zero);
                    for (int c = 0; c < 3; c++)
                        if (v->sig_t[c] > 0.0f)
                            nc_v8_store(T[c] + k, nc_v8_load(T[c] + k) + v->sig_t[c] * G);
                }
            }
        }
        /* The opaque shadow, then the boxes without pattern per froxel where light arrives. */
        if (li->shadow) {
            float vis[MAX_SLICES];
            nc_shadow_lookup_volume_n(li->shadow, &st->shadow_mm[l], m8, X, Y, Z, st->bias, vis);
            for (uint32_t k = 0; k < m8; k += 8)
                nc_v8_store(F + k, nc_v8_load(F + k) * nc_v8_load(vis + k));
        }
        for (uint32_t k = 0; st->analytic_boxes && k < m; k++) {
            if (!(F[k] > 0.0f))
                continue;
            const float x[3] = {X[k], Y[k], Z[k]};
            float w[3], dist = INFINITY;
            if (directional) {
                w[0] = -li->dir[0], w[1] = -li->dir[1], w[2] = -li->dir[2];
            } else {
                float v[3] = {li->pos[0] - x[0], li->pos[1] - x[1], li->pos[2] - x[2]};
                dist = sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
                w[0] = v[0] / dist, w[1] = v[1] / dist, w[2] = v[2] / dist;
            }
            double td[3];
            nc_fog_field_optical_depth(&st->field, x, w, dist, NC_FOG_ANALYTIC | NC_FOG_BOXES, td, tau_scratch);
            for (int c = 0; c < 3; c++)
                T[c][k] += td[c] < TAU_MAX ? (float)td[c] : TAU_MAX;
        }
        for (uint32_t k = 0; k < m8; k += 8) {
            nc_v8f fk = nc_v8_load(F + k);
            if (!nc_v8_bits(fk != 0.0f))
                continue; /* in the shadow: e F Tr adds 0 */
            for (int c = 0; c < 3; c++)
                nc_v8_store(A[c] + k, nc_v8_load(A[c] + k) + li->e[c] * fk * nc_vol_transmittance8(nc_v8_load(T[c] + k)));
        }
    }
    if (!packed) {
        uint32_t k = 0;
        for (; k + 8 <= n; k += 8) {
            nc_v8i a, b, c;
            nc_v8_interleave3((nc_v8i)nc_v8_load(A[0] + k), (nc_v8i)nc_v8_load(A[1] + k), (nc_v8i)nc_v8_load(A[2] + k),
                              &a, &b, &c);
            const float *s3 = ss + 3 * (size_t)k;
            nc_v8_store(src + 3 * (size_t)k, nc_v8_load(s3) * (nc_v8f)a);
            nc_v8_store(src + 3 * (size_t)k + 8, nc_v8_load(s3 + 8) * (nc_v8f)b);
            nc_v8_store(src + 3 * (size_t)k + 16, nc_v8_load(s3 + 16) * (nc_v8f)c);
        }
        for (; k < n; k++)
            for (int c = 0; c < 3; c++)
                src[3 * k + c] = ss[3 * k + c] * A[c][k];
        return;
    }
    uint32_t q = 0;
    for (uint32_t k = 0; k < n; k++) {
        bool lit = q < m && (uint32_t)idx[q] == k;
        for (int c = 0; c < 3; c++)
            src[3 * k + c] = lit ? ss[3 * k + c] * A[c][q] : 0.0f;
        q += lit;
    }
}

static nacre_result froxel_light(vol_state *st, nacre_context *ctx, int threads, uint32_t batch, bool keep)
{
    int64_t cols = (int64_t)st->W * st->H;
    if (!nc_reserve(ctx, &st->col_span, &st->col_span_capacity, 3 * (size_t)cols, sizeof(uint32_t)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    if (st->light_count > st->shadow_mm_count) {
        nc_shadow_minmax *grown = nc_realloc(ctx, st->shadow_mm, st->shadow_mm_count * sizeof(*grown),
                                             st->light_count * sizeof(*grown));
        if (!grown)
            return NACRE_ERROR_OUT_OF_MEMORY;
        memset(grown + st->shadow_mm_count, 0, (st->light_count - st->shadow_mm_count) * sizeof(*grown));
        st->shadow_mm = grown;
        st->shadow_mm_count = st->light_count;
    }
    for (uint32_t l = 0; l < st->light_count; l++) {
        nacre_result r = nc_shadow_minmax_update(ctx, st->lights[l].shadow, &st->shadow_mm[l], threads);
        if (r != NACRE_OK)
            return r;
    }
#pragma omp parallel for schedule(static) num_threads(threads)
    for (int64_t col = 0; col < cols; col++) {
        uint32_t *span = st->col_span + 3 * col, n = lit_slices(st, st->col_depth[col]);
        span[0] = n;
        scatter_span(st->ss + 3 * (size_t)col * st->D, n, &span[1], &span[2]);
    }
    bool patterned = nc_fog_field_patterned(&st->field);
    nacre_result res = patterned ? tau_grid_fill(st, ctx, threads, batch, keep) : NACRE_OK;
    if (res != NACRE_OK)
        return res;
#pragma omp parallel for schedule(dynamic, 16) num_threads(threads)
    for (int64_t col = 0; col < cols; col++) {
        float *sc = thread_scratch(st), *tau = sc + 13u * batch + NC_FOG_EVAL_SCRATCH(batch);
        float *ls = tau + NC_FOG_TAU_SCRATCH(st->field.shadow_steps);
        const size_t S = ((size_t)st->D + 7) & ~(size_t)7;
        uint32_t i = (uint32_t)(col % st->W), j = (uint32_t)(col / st->W);
        uint32_t a0 = 0, a1 = 0, b0 = 0, b1 = 0;
        float wa = 0.0f, wb = 0.0f;
        if (patterned) {
            coarse(i, st->Wc, &a0, &a1, &wa);
            coarse(j, st->Hc, &b0, &b1, &wb);
        }
        const size_t cn[4] = {(size_t)b0 * st->Wc + a0, (size_t)b0 * st->Wc + a1, (size_t)b1 * st->Wc + a0,
                              (size_t)b1 * st->Wc + a1};
        const float cw[4] = {(1 - wa) * (1 - wb), wa * (1 - wb), (1 - wa) * wb, wa * wb};
        const uint32_t *span = st->col_span + 3 * col, n = span[0];
        size_t base = (size_t)col * st->D;
        if (span[2] > 0) {
            float o[3], d[3];
            double scale, offset;
            column_ray(st, i, j, o, d, &scale, &offset);
            float *const xyz[3] = {ls, ls + S, ls + 2 * S};
            column_points(st, o, d, scale, offset, NULL, xyz);
            froxel_light_column(st, n, span, d, st->ss + 3 * base, st->g + base, st->src + 3 * base,
                                patterned ? cn : NULL, cw, ls, tau);
        } else {
            memset(st->src + 3 * base, 0, 3 * (size_t)n * sizeof(float));
        }
        if (st->field.emissive) /* emission: a source term beside sigma_s L (§1.2.11) */
            for (size_t k = 3 * base; k < 3 * (base + n); k++)
                st->src[k] += st->em[k];
        memset(st->src + 3 * (base + n), 0, 3 * (size_t)(st->D - n) * sizeof(float));
    }
    return NACRE_OK;
}

/* ---- temporal reprojection ------------------------------------------------------------------
 *
 * With volumetrics.temporal = a > 0 (Wronski 2014, Hillaire 2015: the froxel grid is too coarse in
 * depth to sample thin features, so successive frames sample different depths and are blended):
 * frame f samples every froxel at the fraction j_f = frac(0.5 + f phi^-1) of its slice (the R1
 * sequence: 0.5 first, then evenly spread), and after the lighting each froxel's sigma_t and
 * source become (1 - a) x this frame's + a x the previous frame's blended grid at the same world
 * point, found through the previous camera and slices (trilinear between the previous samples;
 * taps outside the previous grid or in slices it did not light are left out, and a froxel with
 * less than half of its weight in valid taps keeps this frame's values). The history restarts
 * when the scene object or the grid's size changes, or the setting is 0. What moved since (the
 * camera is followed, lights and fogs are not) lags by about 1 / (1 - a) frames: ghosting,
 * measured in docs/accuracy.md. */

static void temporal_begin(vol_state *st, const nc_post_input *in)
{
    float a = in->settings->volumetrics.temporal;
    bool same = st->hist_valid && st->hist_uid == in->scene->uid && st->hW == st->W && st->hH == st->H &&
                st->hD == st->D;
    if (!(a > 0.0f) || !same) {
        st->hist_valid = false;
        st->frame = 0;
    }
    if (!(a > 0.0f)) {
        st->jitter = 0.5f;
        return;
    }
    double j = 0.5 + st->frame * 0.61803398874989485;
    st->jitter = (float)(j - floor(j));
}

/* The previous frame's slice coordinate of view-axis depth z (samples at integers), or -1
 * outside its slices. */
static double hist_slice(const vol_state *st, double z)
{
    const double *b = st->hist_bound;
    uint32_t D = st->hD;
    if (!(z >= b[0] && z < b[D]))
        return -1.0;
    uint32_t lo = 0, hi = D; /* b[lo] <= z < b[hi] */
    while (hi - lo > 1) {
        uint32_t mid = (lo + hi) / 2;
        if (z >= b[mid])
            lo = mid;
        else
            hi = mid;
    }
    return lo + (z - b[lo]) / (b[lo + 1] - b[lo]) - st->hist_jitter;
}

static void temporal_blend_column(const vol_state *st, float a, size_t col, const float *p)
{
    uint32_t W = st->W, H = st->H, D = st->D;
    for (uint32_t k = 0; k < D; k++) {
        const float *x = p + 3 * (size_t)k;
        double v[3], c[4];
        for (int r = 0; r < 3; r++)
            v[r] = st->hist_view[r][0] * x[0] + st->hist_view[r][1] * x[1] + st->hist_view[r][2] * x[2] +
                   st->hist_view[r][3];
        for (int r = 0; r < 4; r++)
            c[r] = st->hist_proj[r][0] * v[0] + st->hist_proj[r][1] * v[1] + st->hist_proj[r][2] * v[2] +
                   st->hist_proj[r][3];
        if (!(c[3] > 0.0))
            continue;
        double u = (c[0] / c[3] + 1.0) * 0.5 * W - 0.5, w = (1.0 - c[1] / c[3]) * 0.5 * H - 0.5;
        double sl = hist_slice(st, -v[2]);
        if (!(u >= -0.5 && u <= W - 0.5 && w >= -0.5 && w <= H - 0.5 && sl >= -0.5 && sl <= D - 0.5))
            continue;
        double f[3] = {u, w, sl}, lim[3] = {W - 1.0, H - 1.0, D - 1.0};
        int32_t i0[3];
        double t[3];
        for (int q = 0; q < 3; q++) {
            double g = f[q] < 0.0 ? 0.0 : f[q] > lim[q] ? lim[q] : f[q];
            i0[q] = (int32_t)floor(g);
            if (i0[q] > (int32_t)lim[q] - 1)
                i0[q] = lim[q] >= 1.0 ? (int32_t)lim[q] - 1 : 0;
            t[q] = g - i0[q];
            if (t[q] > 1.0)
                t[q] = 1.0;
        }
        double hs[3] = {0, 0, 0}, hr[3] = {0, 0, 0}, wsum = 0.0;
        for (int corner = 0; corner < 8; corner++) {
            int32_t ci = i0[0] + (corner & 1), cj = i0[1] + ((corner >> 1) & 1), ck = i0[2] + ((corner >> 2) & 1);
            double wt = ((corner & 1) ? t[0] : 1.0 - t[0]) * (((corner >> 1) & 1) ? t[1] : 1.0 - t[1]) *
                        (((corner >> 2) & 1) ? t[2] : 1.0 - t[2]);
            if (wt == 0.0 || ci >= (int32_t)W || cj >= (int32_t)H || ck >= (int32_t)D)
                continue;
            size_t hc = (size_t)cj * W + (size_t)ci;
            if ((uint32_t)ck >= st->hist_lit[hc])
                continue;
            size_t at = 3 * (hc * D + (size_t)ck);
            for (int ch = 0; ch < 3; ch++) {
                hs[ch] += wt * st->hist_st[at + ch];
                hr[ch] += wt * st->hist_src[at + ch];
            }
            wsum += wt;
        }
        if (!(wsum >= 0.5))
            continue;
        size_t at = 3 * (col * D + k);
        for (int ch = 0; ch < 3; ch++) {
            st->st[at + ch] = (1.0f - a) * st->st[at + ch] + a * (float)(hs[ch] / wsum);
            st->src[at + ch] = (1.0f - a) * st->src[at + ch] + a * (float)(hr[ch] / wsum);
        }
    }
}

/* Blend the lit grid with the history (if any), then keep the result as the next history. */
static nacre_result temporal_end(vol_state *st, const nc_post_input *in, int threads)
{
    float a = in->settings->volumetrics.temporal;
    if (!(a > 0.0f))
        return NACRE_OK;
    nacre_context *ctx = in->ctx;
    size_t cols = (size_t)st->W * st->H, n = cols * st->D;
    if (st->hist_valid) {
#pragma omp parallel for schedule(static) num_threads(threads)
        for (int64_t col = 0; col < (int64_t)cols; col++) {
            float *p = thread_scratch(st), o[3], d[3];
            double scale, offset;
            column_ray(st, (uint32_t)(col % st->W), (uint32_t)(col / st->W), o, d, &scale, &offset);
            column_points(st, o, d, scale, offset, p, NULL);
            temporal_blend_column(st, a, (size_t)col, p);
        }
    }
    if (!nc_reserve(ctx, &st->hist_st, &st->hist_capacity, 3 * n, sizeof(float)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    if (!nc_reserve(ctx, &st->hist_src, &st->hist_src_capacity, 3 * n, sizeof(float)) ||
        !nc_reserve(ctx, &st->hist_lit, &st->hist_lit_capacity, cols, sizeof(uint32_t)) ||
        !nc_reserve(ctx, &st->hist_bound, &st->hist_bound_capacity, (size_t)st->D + 1, sizeof(double))) {
        st->hist_valid = false;
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    memcpy(st->hist_st, st->st, 3 * n * sizeof(float));
    memcpy(st->hist_src, st->src, 3 * n * sizeof(float));
    for (size_t c = 0; c < cols; c++)
        st->hist_lit[c] = lit_slices(st, st->col_depth[c]);
    memcpy(st->hist_bound, st->bound, ((size_t)st->D + 1) * sizeof(double));
    const nc_raster_view *view = in->view;
    for (int r = 0; r < 4; r++)
        for (int c = 0; c < 4; c++) {
            st->hist_proj[r][c] = view->proj.m[r][c];
            if (r < 3)
                st->hist_view[r][c] = view->view.m[r][c];
        }
    st->hist_jitter = st->jitter;
    st->hist_uid = in->scene->uid;
    st->hW = st->W;
    st->hH = st->H;
    st->hD = st->D;
    st->hist_valid = true;
    st->frame++;
    return NACRE_OK;
}

/* Front to back along each column: the running sums L += T_before S, T *= T_slice of the three
 * channels are two 4-lane steps per slice (one multiply-add, one multiply: the chain of dependent
 * steps stays one operation long), stored side by side as the boundary's acc vector (lanes 3 and
 * 7 carry the next slice's first channel along: never read). The closed-form tail only where a
 * pixel reads it: a column whose pixels all have finite depths never reads boundary D + 1
 * (depth_slot), which then holds boundary D's values. */
static void froxel_integrate(vol_state *st, int threads, uint32_t batch, bool use_empty)
{
    int64_t cols = (int64_t)st->W * st->H;
    uint32_t D = st->D, D3 = 3 * D;
    /* Clear columns (vol_state.col_clear): empty, and where a pixel sees past the grid, a tail
     * that adds nothing. */
#pragma omp parallel for schedule(static) num_threads(threads)
    for (int64_t col = 0; col < cols; col++) {
        bool clear = use_empty && st->col_empty[col];
        if (clear && !isfinite(st->col_depth[col])) {
            float *sc = thread_scratch(st), *tau = sc + 13u * batch + NC_FOG_EVAL_SCRATCH(batch);
            float o[3], d[3];
            double scale, offset, L[3], T[3];
            column_ray(st, (uint32_t)(col % st->W), (uint32_t)(col / st->W), o, d, &scale, &offset);
            tail(st, o, d, ray_t(st->bound[D], scale, offset), L, T, tau);
            for (int c = 0; c < 3; c++)
                clear = clear && L[c] == 0.0 && T[c] == 1.0;
        }
        st->col_clear[col] = clear;
    }
#pragma omp parallel for schedule(static) num_threads(threads)
    for (int64_t col = 0; col < cols; col++) {
        if (st->col_clear[col]) {
            /* Written only for the pixels that also read a column that is not clear. */
            int64_t i = col % st->W, j = col / st->W;
            bool read = false;
            for (int64_t jj = j > 0 ? j - 1 : 0; jj <= j + 1 && jj < (int64_t)st->H && !read; jj++)
                for (int64_t ii = i > 0 ? i - 1 : 0; ii <= i + 1 && ii < (int64_t)st->W; ii++)
                    read = read || !st->col_clear[jj * st->W + ii];
            if (read) {
                const nc_v8f none = {0, 0, 0, 0, 1, 1, 1, 1};
                float *pa = st->acc + 8 * (size_t)col * (D + 2);
                for (uint32_t b = 0; b < D + 2; b++)
                    nc_v8_store(pa + 8 * b, none);
            }
            continue;
        }
        float *sc = thread_scratch(st), *tau = sc + 13u * batch + NC_FOG_EVAL_SCRATCH(batch);
        /* T3 and S3 one word longer: the last slice's vectors read one word past them */
        float *len3 = sc, *T3 = sc + D3 + 1, *S3 = sc + 2 * (size_t)D3 + 2;
        float o[3], d[3];
        double scale, offset;
        column_ray(st, (uint32_t)(col % st->W), (uint32_t)(col / st->W), o, d, &scale, &offset);
        size_t base = (size_t)col * D;
        /* each slice's length along the ray, once per channel: 8 slices at a time as in
         * column_points (the same double differences as one at a time) */
        uint32_t k0 = 0;
        for (; k0 + 8 <= D; k0 += 8) {
            v4f h[2];
            for (int q = 0; q < 2; q++) {
                v4d b0, b1, t0, t1;
                memcpy(&b0, st->bound + k0 + 4 * q, sizeof(b0));
                memcpy(&b1, st->bound + k0 + 4 * q + 1, sizeof(b1));
                t0 = b0 * scale + offset;
                t1 = b1 * scale + offset;
                t0 = (v4d)((v4l)(t0 > 0.0) & (v4l)t0); /* ray_t's clamp at 0 */
                t1 = (v4d)((v4l)(t1 > 0.0) & (v4l)t1);
                h[q] = __builtin_convertvector(t1 - t0, v4f);
            }
            nc_v8i l8 = (nc_v8i)v8_halves(h[0], h[1]), a, b, c;
            nc_v8_interleave3(l8, l8, l8, &a, &b, &c);
            nc_v8i_store((int32_t *)(void *)(len3 + 3 * k0), a);
            nc_v8i_store((int32_t *)(void *)(len3 + 3 * k0 + 8), b);
            nc_v8i_store((int32_t *)(void *)(len3 + 3 * k0 + 16), c);
        }
        for (uint32_t k = k0; k < D; k++) {
            float len = (float)(ray_t(st->bound[k + 1], scale, offset) - ray_t(st->bound[k], scale, offset));
            len3[3 * k] = len3[3 * k + 1] = len3[3 * k + 2] = len;
        }
        /* nc_vol_march_step's segment integral in float, (1 - T) / sigma_t, each slice's
         * transmittance and source first (8 words at a time), then the running sums. */
        const float *sig = st->st + 3 * base, *src = st->src + 3 * base;
        uint32_t i = 0;
        for (; i + 8 <= D3; i += 8) {
            nc_v8f sg = nc_v8_load(sig + i), len = nc_v8_load(len3 + i), x = sg * len, T = nc_vol_transmittance8(x);
            nc_v8f w = nc_v8_sel(x < 1e-3f, len * (1.0f - 0.5f * x), (1.0f - T) * nc_v8_rcp(sg));
            nc_v8_store(T3 + i, T);
            nc_v8_store(S3 + i, nc_v8_load(src + i) * w);
        }
        for (; i < D3; i++) {
            float x = sig[i] * len3[i], T = nc_vol_exp_fast(-x);
            T3[i] = T;
            S3[i] = src[i] * (x < 1e-3f ? len3[i] * (1.0f - 0.5f * x) : (1.0f - T) / sig[i]);
        }
        T3[D3] = S3[D3] = 0.0f;
        float *pa = st->acc + 8 * (size_t)col * (D + 2);
        v4f ml = {0, 0, 0, 0}, mt = {1, 1, 1, 1};
        memcpy(pa, &ml, sizeof(ml));
        memcpy(pa + 4, &mt, sizeof(mt));
        for (uint32_t k = 0; k < D; k++) {
            v4f s4, t4;
            memcpy(&s4, S3 + 3 * k, sizeof(s4));
            memcpy(&t4, T3 + 3 * k, sizeof(t4));
            ml += mt * s4;
            mt *= t4;
            memcpy(pa + 8 * (k + 1), &ml, sizeof(ml));
            memcpy(pa + 8 * (k + 1) + 4, &mt, sizeof(mt));
        }
        if (!isfinite(st->col_depth[col])) {
            double L[3], T[3];
            tail(st, o, d, ray_t(st->bound[D], scale, offset), L, T, tau);
            for (int c = 0; c < 3; c++) {
                ml[c] = (float)(ml[c] + mt[c] * L[c]);
                mt[c] = (float)(mt[c] * T[c]);
            }
        }
        memcpy(pa + 8 * (D + 1), &ml, sizeof(ml));
        memcpy(pa + 8 * (D + 1) + 4, &mt, sizeof(mt));
    }
}

/* The slice boundaries around depth z: b0 and the weight of b0 + 1. */
static inline void depth_slot(const vol_state *st, float z, uint32_t *b0, float *frac)
{
    uint32_t D = st->D;
    const float *bf = st->boundf, *inv_w = st->boundf + D + 1;
    if (!(z < bf[D]) || isinf(z)) {
        *b0 = isinf(z) ? D + 1 : D;
        *frac = 0.0f;
        return;
    }
    uint32_t k;
    if (st->cam.ortho) {
        float u = (z - bf[0]) * inv_w[0];
        k = u > 0.0f ? (uint32_t)u : 0;
    } else if (D == 1 || z < bf[1]) {
        k = 0;
    } else if (st->slice_table_n) {
        /* z >= bf[1] > 0 here: its bits grow with it, and the table's slice begins at or before
         * the start of z's range (the steps below move up from there). */
        uint32_t i = (float_bits(z) - float_bits(bf[1])) >> SLICE_SHIFT;
        k = st->slice_table[i < st->slice_table_n ? i : st->slice_table_n - 1];
        if (st->slice_one_step) {
            /* At most one boundary ahead (bf[k + 1] <= bf[D] > z stops at the last slice):
             * a compare, not a loop whose trip count the branch predictor cannot guess. */
            k += z >= bf[k + 1];
            float f = (z - bf[k]) * inv_w[k];
            *b0 = k;
            *frac = f < 0.0f ? 0.0f : f > 1.0f ? 1.0f : f;
            return;
        }
    } else {
        /* The steps below correct the rounding. */
        float u = 1.0f + logf(z * st->slice_inv_b1) * st->slice_scale;
        k = u > 1.0f ? (uint32_t)u : 1;
    }
    if (k >= D)
        k = D - 1;
    while (k > 0 && z < bf[k])
        k--;
    while (k + 1 < D && z >= bf[k + 1])
        k++;
    float f = (z - bf[k]) * inv_w[k];
    *b0 = k;
    *frac = f < 0.0f ? 0.0f : f > 1.0f ? 1.0f : f;
}

/* A pixel's L and T from the 4 columns around it (weights wc) at boundaries b0 and b0 + 1
 * (weight fz), each weight applied only where it is not 0 (0 x an infinite tail is not 0). */
static inline nc_v8f apply_exact(const float *const a[4], const float wc[4], uint32_t b, float fz)
{
    nc_v8f v = {0};
    for (int q = 0; q < 4; q++) {
        if (wc[q] == 0.0f)
            continue;
        v += wc[q] * (1.0f - fz) * nc_v8_load(a[q] + 8 * (size_t)b);
        if (fz > 0.0f)
            v += wc[q] * fz * nc_v8_load(a[q] + 8 * (size_t)b + 8);
    }
    return v;
}

/* Each pixel reads boundaries b0 and b0 + 1 (depth_slot) of the 4 columns around it: trilinear
 * in (x, y, slice). Neighbouring pixels of a row mostly read the same columns at the same
 * boundaries (8 pixels a column in the default grid, a slice over several pixels of a
 * surface): along such a run the rows' blend by wy is done once, and the blend in x and depth of
 * the four results is A + wx Bx + fz (Bz + wx C) per pixel; 8 pixels of a run at one slot (most
 * of a surface) are blended together, a channel per vector over the 8. A run whose values are
 * not all finite (an infinite tail) takes apply_exact. tl (if not NULL) keeps L and T (6 floats a
 * pixel); keep_depth (if not NULL) a copy of the depths, each row while it is in the cache. */
static void froxel_apply_pixels(const vol_state *st, const float *depth, nacre_image *image, float *tl,
                                float *keep_depth, int threads)
{
    int32_t w = image->width, h = image->height;
    uint32_t D = st->D, W = st->W;
    size_t stride = 8 * ((size_t)D + 2);
    const int32_t *xi = st->px_i, *yi = st->px_i + 2 * (size_t)w;
    const float *xw = st->px_w, *yw = st->px_w + w;
    const float *acc = st->acc;
#pragma omp parallel for schedule(static) num_threads(threads)
    for (int32_t y = 0; y < h; y++) {
        int32_t j0 = yi[2 * y], j1 = yi[2 * y + 1];
        float wy = yw[y];
        float *row = image->pixels + (size_t)y * image->stride;
        const float *dr = depth + (size_t)y * (size_t)w;
        const float *r0 = acc + (size_t)j0 * W * stride, *r1 = acc + (size_t)j1 * W * stride;
        int32_t run_i = -1;
        uint32_t run_b = 0;
        bool finite = false;
        nc_v8f A = {0}, Bx = {0}, Bz = {0}, C = {0};
        const uint8_t *k0 = st->col_clear + (size_t)j0 * W, *k1 = st->col_clear + (size_t)j1 * W;
        for (int32_t x = 0; x < w;) {
            /* A run of pixels between the same columns (i1 follows from i0: pixel_columns) */
            int32_t i0 = xi[2 * x], i1 = xi[2 * x + 1], xe = x + 1;
            while (xe < w && xi[2 * xe] == i0)
                xe++;
            if (k0[i0] & k0[i1] & k1[i0] & k1[i1]) { /* L 0, T 1: the pixels stay */
                for (; tl && x < xe; x++) {
                    float *t = tl + 6 * ((size_t)y * (size_t)w + (size_t)x);
                    t[0] = t[1] = t[2] = 0.0f;
                    t[3] = t[4] = t[5] = 1.0f;
                }
                x = xe;
                continue;
            }
            const float *c00 = r0 + (size_t)i0 * stride, *c10 = r0 + (size_t)i1 * stride;
            const float *c01 = r1 + (size_t)i0 * stride, *c11 = r1 + (size_t)i1 * stride;
            while (x < xe) {
                int32_t cnt = xe - x < 8 ? xe - x : 8;
                uint32_t bs[8];
                float fs[8];
                /* The frame that keeps L and T takes the per-pixel form (the 8-pixel one is
                 * checked against it: test_volumetrics' frame reuse). */
                bool same = cnt == 8 && !tl;
                for (int32_t q = 0; q < cnt; q++) {
                    depth_slot(st, dr[x + q], &bs[q], &fs[q]);
                    same = same && bs[q] == bs[0];
                }
                for (int32_t q = 0; q < cnt; q++) {
                    uint32_t b = bs[q];
                    if (i0 != run_i || b != run_b) {
                        run_i = i0;
                        run_b = b;
                        size_t o0 = 8 * (size_t)b, o1 = b < D ? o0 + 8 : o0; /* boundaries D, D + 1: fz = 0 */
                        nc_v8f V00 = (1.0f - wy) * nc_v8_load(c00 + o0) + wy * nc_v8_load(c01 + o0);
                        nc_v8f V10 = (1.0f - wy) * nc_v8_load(c10 + o0) + wy * nc_v8_load(c11 + o0);
                        nc_v8f V01 = (1.0f - wy) * nc_v8_load(c00 + o1) + wy * nc_v8_load(c01 + o1);
                        nc_v8f V11 = (1.0f - wy) * nc_v8_load(c10 + o1) + wy * nc_v8_load(c11 + o1);
                        A = V00;
                        Bx = V10 - V00;
                        Bz = V01 - V00;
                        C = (V11 - V10) - Bz;
                        /* lanes 0-2 and 4-6: x times 0 is 0 only for finite x */
                        finite = (nc_v8_bits((V00 + V10 + V01 + V11) * 0.0f == 0.0f) & 0x77) == 0x77;
                    }
                    if (same && finite) {
                        /* 8 pixels of one slot: the same blend per channel, the pixels in the
                         * lanes (rgb deinterleaved), as A + wx Bx + fz (Bz + wx C) lane by lane */
                        nc_v8f wx = nc_v8_load(xw + x), fz = nc_v8_load(fs), ch[6];
                        for (int c = 0; c < 6; c++) {
                            int l = c < 3 ? c : c + 1;
                            ch[c] = A[l] + wx * Bx[l] + fz * (Bz[l] + wx * C[l]);
                        }
                        float *px = row + 3 * (size_t)x;
                        nc_v8i pr, pg, pb, oa, ob, oc;
                        nc_v8_deinterleave3(nc_v8i_load((const int32_t *)(const void *)px),
                                            nc_v8i_load((const int32_t *)(const void *)(px + 8)),
                                            nc_v8i_load((const int32_t *)(const void *)(px + 16)), &pr, &pg, &pb);
                        nc_v8_interleave3((nc_v8i)((nc_v8f)pr * ch[3] + ch[0]), (nc_v8i)((nc_v8f)pg * ch[4] + ch[1]),
                                          (nc_v8i)((nc_v8f)pb * ch[5] + ch[2]), &oa, &ob, &oc);
                        nc_v8i_store((int32_t *)(void *)px, oa);
                        nc_v8i_store((int32_t *)(void *)(px + 8), ob);
                        nc_v8i_store((int32_t *)(void *)(px + 16), oc);
                        break;
                    }
                    float wx = xw[x + q], fz = fs[q];
                    nc_v8f v;
                    if (finite) {
                        v = A + wx * Bx + fz * (Bz + wx * C);
                    } else {
                        const float *a[4] = {c00, c10, c01, c11};
                        float wc[4] = {(1 - wx) * (1 - wy), wx * (1 - wy), (1 - wx) * wy, wx * wy};
                        v = apply_exact(a, wc, b, fz);
                    }
                    float *px = row + 3 * (size_t)(x + q);
                    for (int c = 0; c < 3; c++)
                        px[c] = px[c] * v[4 + c] + v[c];
                    if (tl) {
                        float *t = tl + 6 * ((size_t)y * (size_t)w + (size_t)(x + q));
                        for (int c = 0; c < 3; c++) {
                            t[c] = v[c];
                            t[3 + c] = v[4 + c];
                        }
                    }
                }
                x += cnt;
            }
        }
        if (keep_depth)
            memcpy(keep_depth + (size_t)y * (size_t)w, dr, (size_t)w * sizeof(float));
    }
}

/* froxel_apply_pixels from the kept L and T. */
static void froxel_apply_kept(const vol_state *st, nacre_image *image, int threads)
{
    int32_t w = image->width, h = image->height;
#pragma omp parallel for schedule(static) num_threads(threads)
    for (int32_t y = 0; y < h; y++) {
        float *row = image->pixels + (size_t)y * image->stride;
        const float *t = st->px_tl + 6 * (size_t)y * (size_t)w;
        for (int32_t x = 0; x < w; x++)
            for (int c = 0; c < 3; c++)
                row[3 * x + c] = row[3 * x + c] * t[6 * x + 3 + c] + t[6 * x + c];
    }
}

static void volumetric_stats(const nacre_scene *s, nacre_render_stats *stats)
{
    (void)s;
    stats->fog_lights_ignored = 0;
    stats->fog_patterns_averaged = 0;
}

static void stage_done(nacre_render_stats *stats, nacre_stage stage, uint64_t t0)
{
    stats->stage_us[stage] += nc_now_us() - t0;
    stats->stage_ran[stage] = true;
    stats->stage_runs[stage] = 1;
}

/* The keys of this frame's grid (see fill_key). */
static void frame_keys(const nc_post_input *in, fill_key *fk, light_key *lk)
{
    const nacre_scene *s = in->scene;
    memset(fk, 0, sizeof(*fk));
    memset(lk, 0, sizeof(*lk));
    fk->uid = s->uid;
    fk->geometry = s->committed.geometry;
    fk->materials = s->committed.materials;
    fk->environment = s->committed.environment;
    fk->particles_built = s->particles_built;
    fk->vs = in->settings->volumetrics;
    fk->particles = in->settings->particles;
    fk->view = in->view->view;
    fk->proj = in->view->proj;
    fk->width = in->view->width;
    fk->height = in->view->height;
    fk->ortho = in->view->orthographic;
    lk->lights = s->committed.lights;
    lk->shadow = in->settings->shadow;
    lk->method = in->settings->method;
    lk->shadow_maps = in->lights != NULL;
}

static nacre_result froxel_apply(void *state, const nc_post_input *in, nacre_image *image, nacre_render_stats *stats)
{
    vol_state *st = state;
    const nacre_volumetrics_settings *vs = &in->settings->volumetrics;
    uint64_t t0 = nc_now_us();
    uint32_t batch = vs->froxel_slices;
    nacre_result res = vol_setup(st, in, batch);
    if (res == NACRE_OK)
        res = grid_setup(st, in->ctx, vs);
    size_t ncols = (size_t)vs->froxel_width * vs->froxel_height;
    if (res == NACRE_OK && (!nc_reserve(in->ctx, &st->col_empty, &st->col_empty_capacity, ncols, 1) ||
                            !nc_reserve(in->ctx, &st->col_clear, &st->col_clear_capacity, ncols, 1)))
        res = NACRE_ERROR_OUT_OF_MEMORY;
    if (res != NACRE_OK)
        return res;
    int threads = in->ctx->threads;
    /* A frame whose fogs, camera and grid did not change keeps the filled grid; if its lights,
     * shadow maps and visible depths did not change either, the lit and integrated grid. The
     * temporal blend changes the grid every frame: nothing is kept. */
    fill_key fk;
    light_key lk;
    frame_keys(in, &fk, &lk);
    bool temporal = vs->temporal > 0.0f;
    bool same_fill = !temporal && st->fill_valid && memcmp(&fk, &st->fkey, sizeof(fk)) == 0;
    bool same_light = same_fill && st->light_valid && memcmp(&lk, &st->lkey, sizeof(lk)) == 0;
    st->fill_valid = st->light_valid = false;
    bool kept_tl = st->px_tl_valid;
    st->px_tl_valid = false;
    temporal_begin(st, in);
    if (!same_fill) {
        froxel_fill(st, threads);
        stage_done(stats, NACRE_STAGE_FROXEL_FILL, t0);
    }
    t0 = nc_now_us();
    size_t cols = (size_t)st->W * st->H, pixels = (size_t)image->width * (size_t)image->height;
    /* The same depth buffer (and grid: same_fill) gives the same column depths. */
    bool same_buffer = same_fill && memcmp(in->depth, st->prev_depth, pixels * sizeof(float)) == 0;
    if ((res = pixel_tables(st, in->ctx, image->width, image->height)) != NACRE_OK ||
        (!same_buffer && (res = column_depths(st, in->ctx, in->depth, image->width, image->height, threads)) != NACRE_OK))
        return res;
    bool same_depths = same_buffer || (same_fill && memcmp(st->col_depth, st->prev_col_depth, cols * sizeof(float)) == 0);
    same_light = same_light && same_depths;
    if (!same_light) {
        if ((nc_fog_field_patterned(&st->field) && (res = light_volumes_update(st, in, threads)) != NACRE_OK) ||
            (res = froxel_light(st, in->ctx, threads, batch, same_depths)) != NACRE_OK ||
            (res = temporal_end(st, in, threads)) != NACRE_OK)
            return res;
        stage_done(stats, NACRE_STAGE_FROXEL_LIGHT, t0);
        t0 = nc_now_us();
        froxel_integrate(st, threads, batch, !temporal);
        stage_done(stats, NACRE_STAGE_FROXEL_INTEGRATE, t0);
        t0 = nc_now_us();
    }
    /* Kept for the next frame only once the grid is complete (an error above leaves it stale). */
    float *keep_depth = NULL;
    if (!temporal) {
        if (!nc_reserve(in->ctx, &st->prev_col_depth, &st->prev_col_capacity, cols, sizeof(float)) ||
            !nc_reserve(in->ctx, &st->prev_depth, &st->prev_depth_capacity, pixels, sizeof(float)))
            return NACRE_ERROR_OUT_OF_MEMORY;
        memcpy(st->prev_col_depth, st->col_depth, cols * sizeof(float));
        if (!same_buffer)
            keep_depth = st->prev_depth; /* by froxel_apply_pixels, row by row as it reads them */
        st->fkey = fk;
        st->lkey = lk;
        st->fill_valid = st->light_valid = true;
    }
    /* The depths' check counts as apply's when the lit grid is kept. */
    bool still = same_light && same_buffer;
    if (still && kept_tl) {
        froxel_apply_kept(st, image, threads);
        st->px_tl_valid = true; /* still over the grid and depths they were made for */
    } else {
        float *tl = NULL;
        if (still && !temporal && nc_reserve(in->ctx, &st->px_tl, &st->px_tl_capacity, 6 * pixels, sizeof(float)))
            tl = st->px_tl;
        froxel_apply_pixels(st, in->depth, image, tl, keep_depth, threads);
        st->px_tl_valid = tl != NULL;
    }
    stage_done(stats, NACRE_STAGE_FROXEL_APPLY, t0);
    volumetric_stats(in->scene, stats);
    return NACRE_OK;
}

/* ---- ray marching ------------------------------------------------------------------------ */

/* A particle system's isosurface as the march needs it. */
typedef struct viso {
    const nc_particle_grid *grid;
    float level, eta, alpha;
} viso;

/* March the fogs along o + t d, t in [t0, t1], at the midpoints of n equal steps (sc: the
 * thread's scratch). */
static void march_segment(const vol_state *st, const float o[3], const float d[3], double t0, double t1, uint32_t n,
                          float *sc, nc_vol_march m[3])
{
    float *p = sc, *sig_t = sc + 3u * n, *src = sc + 6u * n, *g = sc + 9u * n, *em = sc + 10u * n;
    float *ev = sc + 13u * n;
    float *tau = ev + NC_FOG_EVAL_SCRATCH(n);
    double dt = (t1 - t0) / n;
    for (uint32_t k = 0; k < n; k++) {
        float t = (float)(t0 + (k + 0.5) * dt);
        for (int c = 0; c < 3; c++)
            p[3 * k + c] = o[c] + t * d[c];
    }
    nc_fog_field_eval(&st->field, n, p, sig_t, src, g, ev);
    light_points(st, n, p, d, src, g, src, tau);
    if (st->field.emissive) { /* emission: a source term beside sigma_s L (§1.2.11) */
        nc_fog_field_emission(&st->field, n, p, em, ev);
        for (size_t k = 0; k < 3 * (size_t)n; k++)
            src[k] += em[k];
    }
    for (int c = 0; c < 3; c++)
        m[c] = nc_vol_march_begin();
    for (uint32_t k = 0; k < n; k++)
        for (int c = 0; c < 3; c++)
            nc_vol_march_step(&m[c], sig_t[3 * k + c], src[3 * k + c], dt);
}

/* GGX (Trowbridge-Reitz) reflection with Smith's separable masking, times cos_l: the highlight
 * of a light of unit irradiance on a rough dielectric, Fresnel weighted. */
static double ggx_highlight(const float n[3], const float v[3], const float l[3], double alpha, double eta)
{
    double nl = n[0] * l[0] + n[1] * l[1] + n[2] * l[2], nv = n[0] * v[0] + n[1] * v[1] + n[2] * v[2];
    if (!(nl > 0.0 && nv > 0.0 && alpha > 0.0))
        return 0.0;
    double h[3] = {v[0] + l[0], v[1] + l[1], v[2] + l[2]};
    double hl = sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2]);
    if (!(hl > 0.0))
        return 0.0;
    double nh = (n[0] * h[0] + n[1] * h[1] + n[2] * h[2]) / hl, lh = (l[0] * h[0] + l[1] * h[1] + l[2] * h[2]) / hl;
    double a2 = alpha * alpha, q = nh * nh * (a2 - 1.0) + 1.0, D = a2 / (NC_PI * q * q);
    double g1l = 2.0 * nl / (nl + sqrt(a2 + (1.0 - a2) * nl * nl));
    double g1v = 2.0 * nv / (nv + sqrt(a2 + (1.0 - a2) * nv * nv));
    return D * g1l * g1v * nc_fresnel_dielectric(lh > 0.0 ? lh : 0.0, eta) / (4.0 * nv);
}

/* The radiance leaving the isosurface of `iso` at ray distance th towards the eye: reflection
 * (the environment, Fresnel weighted; the lights' GGX highlights, shadow-mapped and attenuated by
 * the fogs towards them) plus the refracted part, marched through the fogs from the surface
 * along the refracted ray to where it leaves the grid, then the scene behind (`behind`, the
 * pixel's colour: the screen does not know what lies along the bent ray). */
static void iso_shade(const vol_state *st, const viso *iso, const float o[3], const float d[3], double th,
                      double inside_max, uint32_t n, float *sc, const double behind[3], double out[3])
{
    float p[3], nrm[3], v[3] = {-d[0], -d[1], -d[2]};
    for (int c = 0; c < 3; c++)
        p[c] = (float)(o[c] + th * d[c]);
    if (!nc_particle_iso_normal(iso->grid, p, nrm))
        memcpy(nrm, v, sizeof(nrm));
    double cos_i = v[0] * nrm[0] + v[1] * nrm[1] + v[2] * nrm[2];
    if (cos_i < 0.0) { /* a grazing crossing whose difference normal tips away: face the eye */
        for (int c = 0; c < 3; c++)
            nrm[c] -= (float)(2.0 * cos_i) * v[c];
        cos_i = -cos_i;
    }
    double F = nc_fresnel_dielectric(cos_i > 1.0 ? 1.0 : cos_i, iso->eta);
    for (int c = 0; c < 3; c++)
        out[c] = F * st->env[c];
    float *tau_scratch = sc + 13u * n + NC_FOG_EVAL_SCRATCH(n);
    for (uint32_t l = 0; l < st->light_count && iso->alpha > 0.0f; l++) {
        const vlight *li = &st->lights[l];
        float wi[3], dist, scale;
        if (!light_at(li, p, wi, &dist, &scale))
            continue;
        float w[3] = {-wi[0], -wi[1], -wi[2]};
        double f = ggx_highlight(nrm, v, w, iso->alpha, iso->eta) * scale;
        if (!(f > 0.0))
            continue;
        if (li->shadow) {
            f *= nc_shadow_lookup_volume(li->shadow, nc_v3a(p), st->pcf, st->bias);
            if (!(f > 0.0))
                continue;
        }
        double td[3];
        nc_fog_field_optical_depth(&st->field, p, w, dist, NC_FOG_ALL, td, tau_scratch);
        for (int c = 0; c < 3; c++)
            out[c] += f * li->e[c] * exp(-(td[c] < TAU_MAX ? td[c] : TAU_MAX));
    }
    float dr[3];
    if (!nc_refract(d, nrm, iso->eta, dr))
        return;
    double len = nc_particle_grid_exit(iso->grid, p, dr);
    len = len < inside_max ? len : inside_max;
    nc_vol_march m[3];
    if (len > 0.0) {
        march_segment(st, p, dr, 0.0, len, n, sc, m);
    } else {
        for (int c = 0; c < 3; c++)
            m[c] = nc_vol_march_begin();
    }
    for (int c = 0; c < 3; c++)
        out[c] += (1.0 - F) * (m[c].radiance + m[c].transmittance * behind[c]);
}

static nacre_result raymarch_apply(void *state, const nc_post_input *in, nacre_image *image,
                                   nacre_render_stats *stats)
{
    vol_state *st = state;
    const nacre_volumetrics_settings *vs = &in->settings->volumetrics;
    uint64_t t0 = nc_now_us();
    uint32_t n = vs->raymarch_steps;
    nacre_result res = vol_setup(st, in, n);
    if (res != NACRE_OK)
        return res;
    viso isos[NACRE_MAX_FOGS];
    uint32_t iso_count = 0;
    for (uint32_t i = 0; i < in->scene->particles_count && in->settings->particles == NACRE_PARTICLES_DRAW_VOXEL; i++) {
        const nacre_particles_desc *pd;
        const nc_particle_grid *g = nc_scene_particle_grid(in->scene, i, &pd);
        if (g && pd->isosurface.density > 0.0f && g->max_value >= pd->isosurface.density && iso_count < NACRE_MAX_FOGS)
            isos[iso_count++] = (viso){g, pd->isosurface.density, pd->isosurface.ior, pd->isosurface.roughness};
    }
    /* The far plane as the froxels see it: the march stops there, the tail goes on. */
    double far = st->cam.far;
    int32_t w = image->width, h = image->height;
    const float *depth = in->depth;
#pragma omp parallel for schedule(dynamic, 1) num_threads(in->ctx->threads)
    for (int32_t y = 0; y < h; y++) {
        float *sc = thread_scratch(st);
        float *tau = sc + 13u * n + NC_FOG_EVAL_SCRATCH(n);
        float *row = image->pixels + (size_t)y * image->stride;
        for (int32_t x = 0; x < w; x++) {
            float o[3], d[3];
            double scale, offset;
            camera_ray(&st->cam, (x + 0.5) * 2.0 / w - 1.0, 1.0 - (y + 0.5) * 2.0 / h, o, d, &scale, &offset);
            float z = depth[(size_t)y * (size_t)w + (size_t)x];
            bool background = isinf(z);
            double tend = ray_t(z < far ? z : far, scale, offset);
            double th = INFINITY;
            const viso *hit = NULL;
            for (uint32_t s = 0; s < iso_count; s++) {
                double t;
                if (nc_particle_iso_hit(isos[s].grid, isos[s].level, o, d, 0.0, tend, &t) && t < th)
                    th = t, hit = &isos[s];
            }
            nc_vol_march m[3];
            march_segment(st, o, d, 0.0, hit ? th : tend, n, sc, m);
            double L[3] = {0, 0, 0}, T[3] = {1, 1, 1};
            if (background)
                tail(st, o, d, tend, L, T, tau);
            float *px = row + 3 * (size_t)x;
            if (hit) {
                double behind[3], surf[3];
                for (int c = 0; c < 3; c++)
                    behind[c] = px[c] * T[c] + L[c];
                iso_shade(st, hit, o, d, th, background ? INFINITY : tend - th, n, sc, behind, surf);
                for (int c = 0; c < 3; c++)
                    px[c] = (float)(m[c].radiance + m[c].transmittance * surf[c]);
                continue;
            }
            for (int c = 0; c < 3; c++)
                px[c] = (float)(px[c] * m[c].transmittance * T[c] + m[c].radiance + m[c].transmittance * L[c]);
        }
    }
    stage_done(stats, NACRE_STAGE_RAYMARCH, t0);
    volumetric_stats(in->scene, stats);
    return NACRE_OK;
}

const nc_post_pass nc_post_froxel = {
    .name = "froxel",
    .wanted = froxel_wanted,
    .create = vol_create,
    .apply = froxel_apply,
    .destroy = vol_destroy,
};

const nc_post_pass nc_post_raymarch = {
    .name = "raymarch",
    .wanted = raymarch_wanted,
    .create = vol_create,
    .apply = raymarch_apply,
    .destroy = vol_destroy,
};
