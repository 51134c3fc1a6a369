/*
 * post_particles.c: particles over a raster method's image and depth, as screen-space
 * volumetric billboards (Hubert 2020, seed 003 §3.1) or as sorted alpha-blended sprites
 * (§2.2.1, the baseline), by nacre_render_settings.particles. The path tracer renders the
 * particles' density grid instead (src/particles/scene_particles.c), and so does the fog pass
 * when the setting is "voxel".
 *
 * Every particle is a sphere of radius R seen along each pixel's ray (the ray through the pixel
 * centre, as the fog pass and the path tracer use): particles/billboard.h gives its column
 * density and the chord it covers. Billboards, two passes:
 *   1. per pixel, the sum of the particles' optical depths per channel (the seed's product of
 *      transmittances, in log form), of their scattering depths (for the albedo), and the
 *      nearest chord start and farthest chord end; a particle whose chord starts behind the
 *      scene's surface is not drawn (the depth test);
 *   2. per pixel, sigma_t = tau / (far - near) shaped by r(x) (figures 3.5-3.7), ray marched in
 *      16 steps from `near` to the nearer of `far` and the surface, so that a plume meeting the
 *      ground fades out instead of being cut; at each step the light of each directional light
 *      is attenuated by the optical depth towards it, marched in 8 steps through the same
 *      reconstruction read at the pixel each point projects to (the seed's "indirect samples by
 *      projection into the texture"), until the particles' bounds end; the environment adds
 *      isotropic light, attenuated by the mean transmittance towards the front and the back of
 *      the pixel's chord. The image becomes c T + L (single scattering).
 * Sprites: particles sorted far to near (ties by index), each a disc of transmittance
 * exp(-sigma_t D(rho)) blended over the image, with the colour albedo x (sum of E p(theta) +
 * environment) of its centre, unshadowed; its opacity fades where the surface is less than R
 * behind the sprite's centre (soft particles).
 * Not modelled: point and spot lights, the particles' shadows on the scene, multiple
 * scattering, particles closer to the camera plane than their radius (dropped).
 *
 * Resolution: both draw into buffers of transmittance and added light at 1/F of the image's
 * size, F = round(height / 180) (at least 1; 4 at 1280x720), as engines draw particles at
 * reduced resolution; each pixel of the image then takes c T + L bilinearly from them. The cost
 * of billboards grows with the pixels each particle covers, so this is what keeps a 720p frame
 * within milliseconds; the surface depth is read at each buffer pixel's centre.
 * Threads: both passes run over bands of 8 rows, each band adding its particles in a fixed order
 * (index order, or the sorted order), so the image does not depend on the thread count.
 * Units: view space in scene units, distances along unit rays, coefficients per scene unit.
 */
#include "core/core.h"
#include "core/optics.h"
#include "particles/billboard.h"
#include "particles/particles.h"
#include "render/method.h"
#include "core/simd.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif

#define BAND 8u
#define VIEW_STEPS 16
#define LIGHT_STEPS 8
#define MAX_SUNS 8
#define BUFFER_ROWS 180 /* rows of the particle buffers (see "Resolution") */
#define TILE 8          /* billboards: tiles of TILE x TILE buffer pixels, one 8-lane vector wide */
#define REC 16          /* floats per particle record of the billboard pass (one cache line) */
#define LOOK 8          /* floats per pixel of the light march's lookup */

typedef struct pp_system {
    float sigma_t[3], albedo[3], g;
} pp_system;

typedef struct pp_state {
    uint32_t cap, count;
    float *cx, *cy, *cz, *radius, *column, *dist; /* view space; column = d0 K R; dist to eye */
    uint16_t *sys;
    int32_t *rect;    /* x0, x1, y0, y1 (inclusive), x0 > x1: not drawn */
    uint32_t *order, *sort_tmp; /* sprites: far to near, and the merge sort's scratch */
    float *lit;       /* sprites: 3 per particle */
    float *rec;       /* billboards: REC per particle: centre, R^2, 4.5 / R^2, its column's tau_t[3],
                       * tau_s[3], the column d0 K R, |centre|^2 */
    size_t rec_cap;
    float *look;      /* billboards: LOOK per rect pixel (pack_lookup) */
    size_t look_cap;
    float *crow;      /* composite: per thread, 6 rows of rw + 2 */
    size_t crow_cap;
    uint32_t *bin_start, *bins;
    size_t bin_start_cap, bin_cap;
    float *acc;       /* 8 planes over the rect: tau_t[3], tau_s[3], near, far */
    size_t acc_cap;
    float *tl;        /* 6 planes over the rect: transmittance[3], added light[3] */
    size_t tl_cap;
    float *ray;       /* per rect pixel: origin x, y (ortho), unit direction, surface distance */
    size_t ray_cap;
    float *X, *Y;     /* per column and row: the ray's view-space x, y at z = -1 (ortho: origin) */
    int32_t xy_cap;
    pp_system sys_table[NACRE_MAX_FOGS];
} pp_state;

/* The frame's camera and lights in view space. */
typedef struct pp_frame {
    bool ortho;
    int32_t W, H;             /* the image */
    int32_t F, w, h;          /* buffer pixels are F x F image pixels; buffer size */
    int32_t rx0, ry0, rw, rh; /* the rect of the buffer all particles cover */
    float ax, bx, ay, by;     /* ray at image pixel coordinate (xf, yf): X = ax xf + bx, Y = ay yf + by */
    const float *depth;
    float bmin[3], bmax[3];   /* view-space bounds of the particles */
    uint32_t suns;
    float sun_dir[MAX_SUNS][3], sun_e[MAX_SUNS][3]; /* view space: the way the light travels */
    float env[3];
} pp_frame;

static bool pp_wanted(const nacre_scene *scene, const nacre_render_settings *settings)
{
    const nc_method *m = nc_method_get(settings->method);
    if (!m || m->renders_fog || settings->particles == NACRE_PARTICLES_DRAW_VOXEL)
        return false;
    for (uint32_t i = 0; i < scene->particles_count; i++) {
        const nc_particle_set *s = nc_scene_particle_set(scene, i, NULL);
        if (s && s->count)
            return true;
    }
    return false;
}

static void pp_destroy(nacre_context *ctx, void *state)
{
    pp_state *st = state;
    if (!st)
        return;
    void *arrays[] = {st->cx, st->cy, st->cz, st->radius, st->column, st->dist, st->sys, st->rect, st->order, st->sort_tmp,
                      st->lit, st->bin_start, st->bins, st->acc, st->tl, st->ray, st->X, st->Y,
                      st->rec, st->look, st->crow};
    for (size_t i = 0; i < sizeof(arrays) / sizeof(arrays[0]); i++)
        nc_free(ctx, arrays[i]);
    nc_free(ctx, st);
}

static nacre_result pp_create(nacre_context *ctx, void **state)
{
    pp_state *st = nc_calloc(ctx, 1, sizeof(*st));
    if (!st)
        return NACRE_ERROR_OUT_OF_MEMORY;
    *state = st;
    return NACRE_OK;
}

static nacre_result reserve_particles(nacre_context *ctx, pp_state *st, uint32_t n)
{
    if (n <= st->cap)
        return NACRE_OK;
    size_t c = 0;
    bool ok = true;
    float **f[] = {&st->cx, &st->cy, &st->cz, &st->radius, &st->column, &st->dist};
    for (size_t i = 0; i < 6; i++, c = 0)
        ok = ok && nc_reserve(ctx, f[i], &c, n, sizeof(float));
    ok = ok && nc_reserve(ctx, &st->sys, &c, n, sizeof(uint16_t));
    c = 0;
    ok = ok && nc_reserve(ctx, &st->rect, &c, 4 * (size_t)n, sizeof(int32_t));
    c = 0;
    ok = ok && nc_reserve(ctx, &st->order, &c, n, sizeof(uint32_t));
    c = 0;
    ok = ok && nc_reserve(ctx, &st->sort_tmp, &c, n, sizeof(uint32_t));
    c = 0;
    ok = ok && nc_reserve(ctx, &st->lit, &c, 3 * (size_t)n, sizeof(float));
    ok = ok && nc_reserve(ctx, &st->rec, &st->rec_cap, REC * (size_t)n, sizeof(float));
    st->cap = ok ? n : 0;
    return ok ? NACRE_OK : NACRE_ERROR_OUT_OF_MEMORY;
}

/* Buffer pixel coordinates (continuous, integer = centre) of a view-space point, false behind. */
static bool project(const nc_mat4 *P, const float p[3], const pp_frame *fr, float *px, float *py)
{
    float cx = P->m[0][0] * p[0] + P->m[0][1] * p[1] + P->m[0][2] * p[2] + P->m[0][3];
    float cy = P->m[1][0] * p[0] + P->m[1][1] * p[1] + P->m[1][2] * p[2] + P->m[1][3];
    float cw = P->m[3][0] * p[0] + P->m[3][1] * p[1] + P->m[3][2] * p[2] + P->m[3][3];
    if (!(cw > 1e-6f))
        return false;
    float F = (float)fr->F;
    *px = (cx / cw + 1.0f) * 0.5f * (float)fr->W / F - 0.5f;
    *py = (1.0f - cy / cw) * 0.5f * (float)fr->H / F - 0.5f;
    return true;
}

/* The particles of every system in view space, their screen rects and the frame's rect. */
static nacre_result gather(pp_state *st, const nc_post_input *in, pp_frame *fr)
{
    const nacre_scene *s = in->scene;
    uint32_t n = 0;
    for (uint32_t i = 0; i < s->particles_count; i++) {
        const nc_particle_set *set = nc_scene_particle_set(s, i, NULL);
        n += set ? set->count : 0;
    }
    nacre_result r = reserve_particles(in->ctx, st, n);
    if (r != NACRE_OK)
        return r;
    const nc_mat4 V = in->view->view, P = in->view->proj;
    const int32_t w = fr->w, h = fr->h;
    uint32_t base = 0;
    for (uint32_t i = 0; i < s->particles_count; i++) {
        const nacre_particles_desc *d;
        const nc_particle_set *set = nc_scene_particle_set(s, i, &d);
        if (!set)
            continue;
        pp_system *sy = &st->sys_table[i];
        for (int c = 0; c < 3; c++) {
            sy->sigma_t[c] = d->sigma_a[c] + d->sigma_s[c];
            sy->albedo[c] = sy->sigma_t[c] > 0 ? d->sigma_s[c] / sy->sigma_t[c] : 0.0f;
        }
        sy->g = d->g;
#pragma omp parallel for schedule(static) num_threads(in->ctx->threads)
        for (uint32_t k = 0; k < set->count; k++) {
            uint32_t j = base + k;
            nc_vec3 c = nc_mat4_point(&V, nc_v3(set->x[k], set->y[k], set->z[k]));
            float R = set->radius[k];
            st->cx[j] = c.x, st->cy[j] = c.y, st->cz[j] = c.z;
            st->radius[j] = R;
            st->column[j] = set->density[k] * NC_PARTICLE_KERNEL_K * R;
            st->dist[j] = fr->ortho ? -c.z : sqrtf(c.x * c.x + c.y * c.y + c.z * c.z);
            st->sys[j] = (uint16_t)i;
            float *q = st->rec + REC * (size_t)j;
            q[0] = c.x, q[1] = c.y, q[2] = c.z, q[3] = R * R, q[4] = NC_PARTICLE_KERNEL_A / (R * R);
            for (int ch = 0; ch < 3; ch++) {
                q[5 + ch] = sy->sigma_t[ch] * st->column[j];
                q[8 + ch] = sy->sigma_t[ch] * sy->albedo[ch] * st->column[j];
            }
            q[11] = st->column[j];
            q[12] = c.x * c.x + c.y * c.y + c.z * c.z;
            q[13] = q[14] = q[15] = 0.0f;
            int32_t *rc = st->rect + 4 * (size_t)j;
            rc[0] = 1, rc[1] = 0, rc[2] = 1, rc[3] = 0;
            if (!(st->column[j] > 0.0f) || (!fr->ortho && -c.z - R < 1e-4f * R))
                continue;
            float x0 = INFINITY, x1 = -INFINITY, y0 = INFINITY, y1 = -INFINITY;
            for (int q = 0; q < 8; q++) {
                float p[3] = {c.x + ((q & 1) ? R : -R), c.y + ((q & 2) ? R : -R), c.z + ((q & 4) ? R : -R)}, px, py;
                if (!project(&P, p, fr, &px, &py)) {
                    x0 = INFINITY;
                    break;
                }
                /* Comparisons, as fminf and fmaxf give (they skip a NaN too), without their libm calls. */
                x0 = px < x0 ? px : x0, x1 = px > x1 ? px : x1, y0 = py < y0 ? py : y0, y1 = py > y1 ? py : y1;
            }
            if (!(x0 <= x1) || x1 < 0 || y1 < 0 || x0 > (float)(w - 1) || y0 > (float)(h - 1))
                continue;
            const float cx0 = ceilf(x0), fx1 = floorf(x1), cy0 = ceilf(y0), fy1 = floorf(y1);
            rc[0] = (int32_t)(cx0 > 0.0f ? cx0 : 0.0f);
            rc[1] = (int32_t)(fx1 < (float)(w - 1) ? fx1 : (float)(w - 1));
            rc[2] = (int32_t)(cy0 > 0.0f ? cy0 : 0.0f);
            rc[3] = (int32_t)(fy1 < (float)(h - 1) ? fy1 : (float)(h - 1));
        }
        base += set->count;
    }
    st->count = n;
    int32_t x0 = w, x1 = -1, y0 = h, y1 = -1;
    float b0 = INFINITY, b1 = INFINITY, b2 = INFINITY, e0 = -INFINITY, e1 = -INFINITY, e2 = -INFINITY;
    for (uint32_t j = 0; j < n; j++) {
        const int32_t *rc = st->rect + 4 * (size_t)j;
        if (rc[0] > rc[1] || rc[2] > rc[3])
            continue;
        x0 = rc[0] < x0 ? rc[0] : x0, x1 = rc[1] > x1 ? rc[1] : x1;
        y0 = rc[2] < y0 ? rc[2] : y0, y1 = rc[3] > y1 ? rc[3] : y1;
        float R = st->radius[j];
        const float a0 = st->cx[j] - R, a1 = st->cy[j] - R, a2 = st->cz[j] - R;
        const float c0 = st->cx[j] + R, c1 = st->cy[j] + R, c2 = st->cz[j] + R;
        b0 = a0 < b0 ? a0 : b0, b1 = a1 < b1 ? a1 : b1, b2 = a2 < b2 ? a2 : b2;
        e0 = c0 > e0 ? c0 : e0, e1 = c1 > e1 ? c1 : e1, e2 = c2 > e2 ? c2 : e2;
    }
    /* The rect's width is a whole number of 8-pixel vectors; the columns past the buffer's
     * edge hold no particle (their rects are clipped) and composite never reads them. */
    fr->rx0 = x0, fr->ry0 = y0, fr->rw = (x1 - x0 + 1 + 7) / 8 * 8, fr->rh = y1 - y0 + 1;
    fr->bmin[0] = b0, fr->bmin[1] = b1, fr->bmin[2] = b2;
    fr->bmax[0] = e0, fr->bmax[1] = e1, fr->bmax[2] = e2;
    return NACRE_OK;
}

/* The camera's rays and the frame's directional lights in view space. */
static nacre_result frame_setup(pp_state *st, const nc_post_input *in, pp_frame *fr)
{
    const nc_raster_view *v = in->view;
    fr->ortho = v->orthographic;
    fr->W = v->width, fr->H = v->height;
    fr->F = (fr->H + BUFFER_ROWS / 2) / BUFFER_ROWS;
    if (fr->F < 1)
        fr->F = 1;
    fr->w = (fr->W + fr->F - 1) / fr->F, fr->h = (fr->H + fr->F - 1) / fr->F;
    fr->depth = in->depth;
    nc_mat4 ip;
    if (!nc_mat4_inverse(v->proj, &ip))
        return nc_fail(in->ctx, NACRE_ERROR_INVALID_ARGUMENT, "particles: camera projection is singular");
    /* X(xf), Y(yf): affine in the pixel for nacre's projections (no shear). */
    float Xv[2], Yv[2];
    for (int k = 0; k < 2; k++) {
        float nx = (k + 0.5f) * 2.0f / (float)fr->W - 1.0f, ny = 1.0f - (k + 0.5f) * 2.0f / (float)fr->H;
        float nz = fr->ortho ? 0.0f : 1.0f;
        float qx[4], qy[4];
        for (int r = 0; r < 4; r++) {
            qx[r] = ip.m[r][0] * nx + ip.m[r][2] * nz + ip.m[r][3];
            qy[r] = ip.m[r][1] * ny + ip.m[r][2] * nz + ip.m[r][3];
        }
        Xv[k] = fr->ortho ? qx[0] / qx[3] : qx[0] / -qx[2];
        Yv[k] = fr->ortho ? qy[1] / qy[3] : qy[1] / -qy[2];
    }
    fr->ax = Xv[1] - Xv[0], fr->bx = Xv[0];
    fr->ay = Yv[1] - Yv[0], fr->by = Yv[0];
    size_t cap = (size_t)(st->xy_cap > 0 ? st->xy_cap : 0), cap2 = cap;
    int32_t m = (fr->w > fr->h ? fr->w : fr->h) + 8; /* + 8: the rect's padding */
    if (!nc_reserve(in->ctx, &st->X, &cap, (size_t)m, sizeof(float)) ||
        !nc_reserve(in->ctx, &st->Y, &cap2, (size_t)m, sizeof(float)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    st->xy_cap = m;
    for (int32_t x = 0; x < fr->w + 8; x++)
        st->X[x] = fr->ax * ((x + 0.5f) * (float)fr->F - 0.5f) + fr->bx;
    for (int32_t y = 0; y < fr->h; y++)
        st->Y[y] = fr->ay * ((y + 0.5f) * (float)fr->F - 0.5f) + fr->by;
    const nacre_scene *s = in->scene;
    fr->suns = 0;
    for (uint32_t i = 0; i < s->light_count && fr->suns < MAX_SUNS; i++) {
        const nacre_light_desc *ld = &s->lights[i].desc;
        if (ld->type != NACRE_LIGHT_DIRECTIONAL)
            continue;
        nc_vec3 d = nc_mat4_dir(&v->view, nc_v3a(ld->direction));
        float len = sqrtf(d.x * d.x + d.y * d.y + d.z * d.z);
        fr->sun_dir[fr->suns][0] = d.x / len, fr->sun_dir[fr->suns][1] = d.y / len;
        fr->sun_dir[fr->suns][2] = d.z / len;
        memcpy(fr->sun_e[fr->suns], ld->strength, sizeof(fr->sun_e[0]));
        fr->suns++;
    }
    memcpy(fr->env, s->environment, sizeof(fr->env));
    return NACRE_OK;
}

/* Rays of the rect's buffer pixels, as 6 planes (so that 8 neighbours load as one vector):
 * origin x, y (z is 0), unit direction and the surface's distance (the depth buffer read at the
 * image pixel nearest the buffer pixel's centre). */
static nacre_result make_rays(nacre_context *ctx, pp_state *st, const pp_frame *fr)
{
    const size_t plane = (size_t)fr->rw * (size_t)fr->rh;
    if (!nc_reserve(ctx, &st->ray, &st->ray_cap, 6 * plane, sizeof(float)))
        return NACRE_ERROR_OUT_OF_MEMORY;
#pragma omp parallel for schedule(static) num_threads(ctx->threads)
    for (int32_t ry = 0; ry < fr->rh; ry++)
        for (int32_t rx = 0; rx < fr->rw; rx++) {
            int32_t x = rx + fr->rx0, y = ry + fr->ry0;
            int32_t xf = x * fr->F + fr->F / 2, yf = y * fr->F + fr->F / 2;
            xf = xf < fr->W ? xf : fr->W - 1, yf = yf < fr->H ? yf : fr->H - 1;
            float dep = fr->depth[(size_t)yf * (size_t)fr->W + (size_t)xf];
            float *r = st->ray + (size_t)ry * (size_t)fr->rw + (size_t)rx;
            if (fr->ortho) {
                r[0] = st->X[x], r[plane] = st->Y[y], r[2 * plane] = 0.0f, r[3 * plane] = 0.0f;
                r[4 * plane] = -1.0f, r[5 * plane] = dep;
                continue;
            }
            float X = st->X[x], Y = st->Y[y], len = sqrtf(X * X + Y * Y + 1.0f), inv = 1.0f / len;
            r[0] = r[plane] = 0.0f;
            r[2 * plane] = X * inv, r[3 * plane] = Y * inv, r[4 * plane] = -inv;
            r[5 * plane] = dep * len; /* INFINITY stays */
        }
    return NACRE_OK;
}

/* Ray of rect pixel (rx, ry): origin o, unit direction d; returns the surface's distance. */
static inline float pixel_ray(const pp_state *st, const pp_frame *fr, int32_t rx, int32_t ry, float o[3], float d[3])
{
    const size_t plane = (size_t)fr->rw * (size_t)fr->rh;
    const float *r = st->ray + (size_t)ry * (size_t)fr->rw + (size_t)rx;
    o[0] = r[0], o[1] = r[plane], o[2] = 0.0f;
    d[0] = r[2 * plane], d[1] = r[3 * plane], d[2] = r[4 * plane];
    return r[5 * plane];
}

/* Bin the particles (in the order of `order`, or index order) into bands of BAND rows. */
static nacre_result bin(nacre_context *ctx, pp_state *st, const pp_frame *fr, const uint32_t *order, uint32_t *bands)
{
    uint32_t nb = ((uint32_t)fr->rh + BAND - 1) / BAND;
    *bands = nb;
    if (!nc_reserve(ctx, &st->bin_start, &st->bin_start_cap, nb + 1, sizeof(uint32_t)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    memset(st->bin_start, 0, (nb + 1) * sizeof(uint32_t));
    for (uint32_t k = 0; k < st->count; k++) {
        const int32_t *rc = st->rect + 4 * (size_t)(order ? order[k] : k);
        if (rc[0] > rc[1] || rc[2] > rc[3])
            continue;
        for (uint32_t b = (uint32_t)(rc[2] - fr->ry0) / BAND; b <= (uint32_t)(rc[3] - fr->ry0) / BAND; b++)
            st->bin_start[b + 1]++;
    }
    for (uint32_t b = 0; b < nb; b++)
        st->bin_start[b + 1] += st->bin_start[b];
    if (!nc_reserve(ctx, &st->bins, &st->bin_cap, st->bin_start[nb] + 1, sizeof(uint32_t)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    for (uint32_t k = 0; k < st->count; k++) {
        uint32_t j = order ? order[k] : k;
        const int32_t *rc = st->rect + 4 * (size_t)j;
        if (rc[0] > rc[1] || rc[2] > rc[3])
            continue;
        for (uint32_t b = (uint32_t)(rc[2] - fr->ry0) / BAND; b <= (uint32_t)(rc[3] - fr->ry0) / BAND; b++)
            st->bins[st->bin_start[b]++] = j;
    }
    for (uint32_t b = nb; b > 0; b--)
        st->bin_start[b] = st->bin_start[b - 1];
    st->bin_start[0] = 0;
    return NACRE_OK;
}

/* Bin the particles, in index order, into tiles of TILE x TILE buffer pixels (rect coordinates,
 * tile t = ty * ntx + tx), so that each pixel visits only the particles whose rect overlaps its
 * tile. */
static nacre_result bin_tiles(nacre_context *ctx, pp_state *st, const pp_frame *fr, uint32_t *ntx, uint32_t *nty)
{
    const uint32_t nx = (uint32_t)fr->rw / TILE, ny = ((uint32_t)fr->rh + TILE - 1) / TILE, nt = nx * ny;
    *ntx = nx, *nty = ny;
    if (!nc_reserve(ctx, &st->bin_start, &st->bin_start_cap, nt + 1, sizeof(uint32_t)))
        return NACRE_ERROR_OUT_OF_MEMORY;
    memset(st->bin_start, 0, (nt + 1) * sizeof(uint32_t));
    for (int pass = 0; pass < 2; pass++) {
        for (uint32_t j = 0; j < st->count; j++) {
            const int32_t *rc = st->rect + 4 * (size_t)j;
            if (rc[0] > rc[1] || rc[2] > rc[3])
                continue;
            const uint32_t x0 = (uint32_t)(rc[0] - fr->rx0) / TILE, x1 = (uint32_t)(rc[1] - fr->rx0) / TILE;
            const uint32_t y0 = (uint32_t)(rc[2] - fr->ry0) / TILE, y1 = (uint32_t)(rc[3] - fr->ry0) / TILE;
            for (uint32_t ty = y0; ty <= y1; ty++)
                for (uint32_t tx = x0; tx <= x1; tx++) {
                    if (pass == 0)
                        st->bin_start[ty * nx + tx + 1]++;
                    else
                        st->bins[st->bin_start[ty * nx + tx]++] = j;
                }
        }
        if (pass == 0) {
            for (uint32_t t = 0; t < nt; t++)
                st->bin_start[t + 1] += st->bin_start[t];
            if (!nc_reserve(ctx, &st->bins, &st->bin_cap, st->bin_start[nt] + 1, sizeof(uint32_t)))
                return NACRE_ERROR_OUT_OF_MEMORY;
        }
    }
    for (uint32_t t = nt; t > 0; t--)
        st->bin_start[t] = st->bin_start[t - 1];
    st->bin_start[0] = 0;
    return NACRE_OK;
}

/* Rows y0..y1 (image rows) of band b, and those rows of `count` planes set to value[k]: both
 * passes start a band by clearing their own planes there. */
static void band_start(const pp_frame *fr, uint32_t b, float *planes, int count, const float *value, int32_t *y0,
                       int32_t *y1)
{
    const size_t plane = (size_t)fr->rw * (size_t)fr->rh;
    *y0 = fr->ry0 + (int32_t)(b * BAND);
    *y1 = *y0 + (int32_t)BAND - 1;
    if (*y1 > fr->ry0 + fr->rh - 1)
        *y1 = fr->ry0 + fr->rh - 1;
    for (int32_t y = *y0; y <= *y1; y++)
        for (int k = 0; k < count; k++) {
            float *row = planes + k * plane + (size_t)(y - fr->ry0) * (size_t)fr->rw;
            for (int32_t x = 0; x < fr->rw; x++)
                row[x] = value[k];
        }
}

static inline nc_v8f v8_min(nc_v8f a, nc_v8f b) { return nc_v8_sel(a < b, a, b); }
static inline nc_v8f v8_max(nc_v8f a, nc_v8f b) { return nc_v8_sel(a > b, a, b); }

/* sqrt(x) for x >= 0 from the approximate reciprocal square root and one Newton step (relative
 * error about 1e-6): a full-precision square root per lane cost as much as the exponential. */
static inline nc_v8f v8_sqrt_fast(nc_v8f x)
{
#ifdef __AVX__
    const nc_v8f y = (nc_v8f)_mm256_rsqrt_ps((__m256)x), xy = x * y;
    return nc_v8_sel(x > 0.0f, xy * (1.5f - 0.5f * xy * y), nc_v8_splat(0.0f));
#else
    return nc_v8_sqrt(x);
#endif
}

/* Particle q's chord along 8 rays with parameter t of the closest point and squared distance rho2
 * from its centre, on the lanes of m: false when no lane's chord is within the sphere and in front
 * of the surface at ts; otherwise the lanes that are (*m), the Gaussian column weight of each (*w,
 * 0 elsewhere) and the chord [*lo, *hi]. */
static inline __attribute__((always_inline)) bool chord(const float *q, nc_v8f t, nc_v8f rho2, nc_v8f ts,
                                                       nc_v8i *m, nc_v8f *w, nc_v8f *lo, nc_v8f *hi)
{
    const nc_v8f zero = nc_v8_splat(0.0f);
    *m &= rho2 < q[3];
    if (!nc_v8_bits(*m))
        return false;
    rho2 = v8_max(rho2, zero);
    const nc_v8f h = v8_sqrt_fast(q[3] - rho2);
    *lo = t - h;
    *m &= ~(*lo > ts);
    if (!nc_v8_bits(*m))
        return false;
    *w = nc_v8_sel(*m, nc_billboard_exp8(rho2 * -q[4]), zero);
    *hi = t + h;
    return true;
}

/* One row of 8 pixels of a tile against the tile's particles (index order). With one system
 * (`one`), the sums of tau_t and tau_s are its coefficients times the sum of the columns, so a
 * single sum is kept and scaled at the end. */
static inline __attribute__((always_inline)) void accumulate_row(const pp_state *st, const pp_frame *fr, bool one,
                                                                 bool persp, uint32_t e0, uint32_t e1, int32_t ry,
                                                                 int32_t tx)
{
    const size_t plane = (size_t)fr->rw * (size_t)fr->rh;
    const size_t i = (size_t)ry * (size_t)fr->rw + (size_t)tx;
    const int32_t y = ry + fr->ry0;
    const nc_v8i lane = (nc_v8i){0, 1, 2, 3, 4, 5, 6, 7} + (tx + fr->rx0);
    const nc_v8f ox = nc_v8_load(st->ray + i), oy = nc_v8_load(st->ray + plane + i);
    const nc_v8f dx = nc_v8_load(st->ray + 2 * plane + i), dy = nc_v8_load(st->ray + 3 * plane + i);
    const nc_v8f dz = nc_v8_load(st->ray + 4 * plane + i), ts = nc_v8_load(st->ray + 5 * plane + i);
    const nc_v8f zero = nc_v8_splat(0.0f);
    nc_v8f a0 = zero, a1 = zero, a2 = zero, s0 = zero, s1 = zero, s2 = zero;
    nc_v8f nr = nc_v8_splat(INFINITY), fa = nc_v8_splat(-INFINITY);
    for (uint32_t e = e0; e < e1; e++) {
        const uint32_t j = st->bins[e];
        const int32_t *rc = st->rect + 4 * (size_t)j;
        if (y < rc[2] || y > rc[3])
            continue;
        const float *q = st->rec + REC * (size_t)j;
        nc_v8f t, rho2;
        if (persp) { /* rays from the eye: v = c, |v|^2 per particle */
            t = q[0] * dx + q[1] * dy + q[2] * dz;
            rho2 = q[12] - t * t;
        } else {
            const nc_v8f vx = q[0] - ox, vy = q[1] - oy, vz = nc_v8_splat(q[2]);
            t = vx * dx + vy * dy + vz * dz;
            rho2 = vx * vx + vy * vy + vz * vz - t * t;
        }
        nc_v8i m = (lane >= rc[0]) & (lane <= rc[1]);
        nc_v8f w, lo, hi;
        if (!chord(q, t, rho2, ts, &m, &w, &lo, &hi))
            continue;
        if (one) {
            a0 += q[11] * w;
        } else {
            a0 += q[5] * w, a1 += q[6] * w, a2 += q[7] * w;
            s0 += q[8] * w, s1 += q[9] * w, s2 += q[10] * w;
        }
        nr = nc_v8_sel(m, v8_min(nr, lo), nr);
        fa = nc_v8_sel(m, v8_max(fa, hi), fa);
    }
    if (one) {
        const pp_system *sy = &st->sys_table[0];
        const nc_v8f col = a0;
        a0 = sy->sigma_t[0] * col, a1 = sy->sigma_t[1] * col, a2 = sy->sigma_t[2] * col;
        s0 = sy->sigma_t[0] * sy->albedo[0] * col, s1 = sy->sigma_t[1] * sy->albedo[1] * col;
        s2 = sy->sigma_t[2] * sy->albedo[2] * col;
    }
    float *acc = st->acc + i;
    nc_v8_store(acc, a0), nc_v8_store(acc + plane, a1), nc_v8_store(acc + 2 * plane, a2);
    nc_v8_store(acc + 3 * plane, s0), nc_v8_store(acc + 4 * plane, s1), nc_v8_store(acc + 5 * plane, s2);
    nc_v8_store(acc + 6 * plane, nr), nc_v8_store(acc + 7 * plane, fa);
}

/* accumulate_row's case of one system and rays from the eye, for ROWS_AT_ONCE rows of a tile together:
 * a particle's record, rect and broadcasts are read once for the rows instead of once per row,
 * and a particle outside the rows is skipped by one test. Each row's sums are those of
 * accumulate_row, bit for bit (the same operations, the particles in the same order). */
#define ROWS_AT_ONCE 8
static void accumulate_rows(const pp_state *st, const pp_frame *fr, uint32_t e0, uint32_t e1, int32_t ry, int32_t tx)
{
    const size_t plane = (size_t)fr->rw * (size_t)fr->rh;
    const int32_t y0 = ry + fr->ry0, y1 = y0 + ROWS_AT_ONCE - 1;
    const nc_v8i lane = (nc_v8i){0, 1, 2, 3, 4, 5, 6, 7} + (tx + fr->rx0);
    const nc_v8f zero = nc_v8_splat(0.0f);
    const float *ray = st->ray + (size_t)ry * (size_t)fr->rw + (size_t)tx;
    const size_t rw = (size_t)fr->rw;
    nc_v8f a[ROWS_AT_ONCE], nr[ROWS_AT_ONCE], fa[ROWS_AT_ONCE];
    for (int r = 0; r < ROWS_AT_ONCE; r++)
        a[r] = zero, nr[r] = nc_v8_splat(INFINITY), fa[r] = nc_v8_splat(-INFINITY);
    for (uint32_t e = e0; e < e1; e++) {
        const uint32_t j = st->bins[e];
        const int32_t *rc = st->rect + 4 * (size_t)j;
        if (y1 < rc[2] || y0 > rc[3])
            continue;
        const float *q = st->rec + REC * (size_t)j;
        const nc_v8i xm = (lane >= rc[0]) & (lane <= rc[1]);
        for (int r = 0; r < ROWS_AT_ONCE; r++) {
            if (y0 + r < rc[2] || y0 + r > rc[3])
                continue;
            const float *p = ray + (size_t)r * rw;
            const nc_v8f dx = nc_v8_load(p + 2 * plane), dy = nc_v8_load(p + 3 * plane);
            const nc_v8f dz = nc_v8_load(p + 4 * plane), ts = nc_v8_load(p + 5 * plane);
            const nc_v8f t = q[0] * dx + q[1] * dy + q[2] * dz;
            nc_v8i m = xm;
            nc_v8f w, lo, hi;
            if (!chord(q, t, q[12] - t * t, ts, &m, &w, &lo, &hi))
                continue;
            a[r] += q[11] * w;
            nr[r] = nc_v8_sel(m, v8_min(nr[r], lo), nr[r]);
            fa[r] = nc_v8_sel(m, v8_max(fa[r], hi), fa[r]);
        }
    }
    const pp_system *sy = &st->sys_table[0];
    for (int r = 0; r < ROWS_AT_ONCE; r++) {
        const nc_v8f col = a[r];
        float *acc = st->acc + (size_t)(ry + r) * rw + (size_t)tx;
        nc_v8_store(acc, sy->sigma_t[0] * col), nc_v8_store(acc + plane, sy->sigma_t[1] * col);
        nc_v8_store(acc + 2 * plane, sy->sigma_t[2] * col);
        nc_v8_store(acc + 3 * plane, sy->sigma_t[0] * sy->albedo[0] * col);
        nc_v8_store(acc + 4 * plane, sy->sigma_t[1] * sy->albedo[1] * col);
        nc_v8_store(acc + 5 * plane, sy->sigma_t[2] * sy->albedo[2] * col);
        nc_v8_store(acc + 6 * plane, nr[r]), nc_v8_store(acc + 7 * plane, fa[r]);
    }
}

/* Pass 1: per pixel of the rect, optical depths and the chord ends (planes of `acc`). A tile's
 * rows run as 8-lane vectors, the sums held in registers over the tile's particles, which each
 * pixel adds in index order (so the sums do not depend on the threads). The particle's rect
 * masks the lanes as the scalar loop over it did. */
static void accumulate(pp_state *st, const pp_frame *fr, uint32_t ntx, uint32_t nty, bool one, int threads)
{
    const int32_t tiles = (int32_t)(ntx * nty);
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads)
    for (int32_t tile = 0; tile < tiles; tile++) {
        const int32_t tx = (tile % (int32_t)ntx) * TILE, ty = (tile / (int32_t)ntx) * TILE;
        const int32_t ye = ty + TILE < fr->rh ? ty + TILE : fr->rh;
        const uint32_t e0 = st->bin_start[tile], e1 = st->bin_start[tile + 1];
        int32_t ry = ty;
        if (one && !fr->ortho)
            for (; ry + ROWS_AT_ONCE <= ye; ry += ROWS_AT_ONCE)
                accumulate_rows(st, fr, e0, e1, ry, tx);
        for (; ry < ye; ry++) {
            if (one && !fr->ortho)
                accumulate_row(st, fr, true, true, e0, e1, ry, tx);
            else if (one)
                accumulate_row(st, fr, true, false, e0, e1, ry, tx);
            else
                accumulate_row(st, fr, false, !fr->ortho, e0, e1, ry, tx);
        }
    }
}


/* Per rect pixel, what the light march reads, packed as one 32-byte record: near, 1 / (far -
 * near) (0 where nothing was drawn) and tau_t[3]. */
static void pack_lookup(pp_state *st, const pp_frame *fr, int threads)
{
    const size_t plane = (size_t)fr->rw * (size_t)fr->rh;
#pragma omp parallel for schedule(static) num_threads(threads)
    for (int32_t ry = 0; ry < fr->rh; ry++)
        for (int32_t rx = 0; rx < fr->rw; rx++) {
            const size_t i = (size_t)ry * (size_t)fr->rw + (size_t)rx;
            const float nr = st->acc[6 * plane + i], fa = st->acc[7 * plane + i];
            float *p = st->look + LOOK * i;
            p[0] = fa > nr ? nr : 0.0f;
            p[1] = fa > nr ? 1.0f / (fa - nr) : 0.0f;
            for (int c = 0; c < 3; c++)
                p[2 + c] = st->acc[c * plane + i];
            p[5] = p[6] = p[7] = 0.0f;
        }
}

/* Reconstructed sigma_t (3) at 8 view-space points q, read at the pixel each projects to; 0
 * outside the rect and the chords. */
static inline void sigma_at8(const pp_state *st, const pp_frame *fr, const nc_v8f q[3], nc_v8f sig[3])
{
    const nc_v8f zero = nc_v8_splat(0.0f);
    nc_v8f X, Y, t;
    nc_v8i ok;
    if (fr->ortho) {
        X = q[0], Y = q[1], t = -q[2];
        ok = q[2] == q[2];
    } else {
        ok = q[2] < 0.0f;
        const nc_v8f iz = -1.0f / nc_v8_sel(ok, q[2], nc_v8_splat(-1.0f));
        X = q[0] * iz, Y = q[1] * iz;
        t = nc_v8_sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
    }
    const float F = (float)fr->F, kx = 1.0f / (fr->ax * F), ky = 1.0f / (fr->ay * F);
    const float cx = (0.5f - fr->bx / fr->ax) / F - 0.5f, cy = (0.5f - fr->by / fr->ay) / F - 0.5f;
    /* Clamped before rounding so that far points cannot overflow the conversion. */
    const nc_v8f fx = v8_min(v8_max(X * kx + cx, nc_v8_splat(-1e6f)), nc_v8_splat(1e6f));
    const nc_v8f fy = v8_min(v8_max(Y * ky + cy, nc_v8_splat(-1e6f)), nc_v8_splat(1e6f));
    const nc_v8i x = nc_v8_rint(fx) - fr->rx0, y = nc_v8_rint(fy) - fr->ry0;
    ok &= (x >= 0) & (y >= 0) & (x < fr->rw) & (y < fr->rh);
    const nc_v8i idx = nc_v8i_sel(ok, (y * fr->rw + x) * LOOK, (nc_v8i){0});
    const nc_v8f nr = nc_v8_gather(st->look, idx), il = nc_v8_gather(st->look + 1, idx);
    const nc_v8f u = (t - nr) * il;
    /* r(x) of particles/billboard.h, lane by lane. */
    const nc_v8f yv = 1.0f - 2.0f * v8_max(u - 0.5f, 0.5f - u);
    const nc_v8f r = v8_min(yv * (1.0f / NC_BILLBOARD_REMAP_T), nc_v8_splat(1.0f)) *
                     (1.0f / (1.0f - 0.5f * NC_BILLBOARD_REMAP_T)) * il;
    ok &= (u > 0.0f) & (u < 1.0f) & (il > 0.0f);
    for (int c = 0; c < 3; c++)
        sig[c] = nc_v8_sel(ok, nc_v8_gather(st->look + 2 + c, idx) * r, zero);
}

/* Pass 2: ray march each pixel of the rect through its reconstruction, 8 pixels of a row at a
 * time (every lane takes the same steps; finished or empty lanes add nothing). */
static void march(pp_state *st, const pp_frame *fr, const float g, int threads)
{
    const size_t plane = (size_t)fr->rw * (size_t)fr->rh;
#pragma omp parallel for schedule(dynamic, 4) num_threads(threads)
    for (int32_t ry = 0; ry < fr->rh; ry++) {
        for (int32_t rx = 0; rx < fr->rw; rx += 8) {
            const size_t i = (size_t)ry * (size_t)fr->rw + (size_t)rx;
            const nc_v8f zero = nc_v8_splat(0.0f), one = nc_v8_splat(1.0f);
            const nc_v8f nr0 = nc_v8_load(st->acc + 6 * plane + i), fa = nc_v8_load(st->acc + 7 * plane + i);
            const nc_v8f ts = nc_v8_load(st->ray + 5 * plane + i);
            const nc_v8f t1_ = v8_min(fa, ts);
            const nc_v8i act = (fa > nr0) & (t1_ > nr0);
            nc_v8f T[3] = {one, one, one}, Ls[3] = {zero, zero, zero};
            if (nc_v8_bits(act)) {
                const nc_v8f nr = nc_v8_sel(act, nr0, zero), t1 = nc_v8_sel(act, t1_, zero);
                const nc_v8f L = nc_v8_sel(act, fa - nr0, one);
                const nc_v8f o[3] = {nc_v8_load(st->ray + i), nc_v8_load(st->ray + plane + i), zero};
                const nc_v8f d[3] = {nc_v8_load(st->ray + 2 * plane + i), nc_v8_load(st->ray + 3 * plane + i),
                                     nc_v8_load(st->ray + 4 * plane + i)};
                nc_v8f tau[3], alb[3], phase[MAX_SUNS];
                for (int c = 0; c < 3; c++) {
                    tau[c] = nc_v8_sel(act, nc_v8_load(st->acc + c * plane + i), zero);
                    const nc_v8f ts_c = nc_v8_load(st->acc + (3 + c) * plane + i);
                    alb[c] = nc_v8_sel(tau[c] > 0.0f, ts_c / nc_v8_sel(tau[c] > 0.0f, tau[c], one), zero);
                }
                for (uint32_t l = 0; l < fr->suns; l++)
                    for (int k = 0; k < 8; k++)
                        phase[l][k] = (float)nc_hg_phase(-(d[0][k] * fr->sun_dir[l][0] + d[1][k] * fr->sun_dir[l][1] +
                                                           d[2][k] * fr->sun_dir[l][2]), g);
                const nc_v8f dt = (t1 - nr) * (1.0f / VIEW_STEPS), iL = 1.0f / L;
                nc_v8f front[3] = {zero, zero, zero};
                for (int k = 0; k < VIEW_STEPS; k++) {
                    const nc_v8f t = nr + (k + 0.5f) * dt, u = (t - nr) * iL;
                    const nc_v8f yv = 1.0f - 2.0f * v8_max(u - 0.5f, 0.5f - u);
                    const nc_v8i live = act & (u > 0.0f) & (u < 1.0f);
                    const nc_v8f rr = nc_v8_sel(live, v8_min(yv * (1.0f / NC_BILLBOARD_REMAP_T), one) *
                                                          (1.0f / (1.0f - 0.5f * NC_BILLBOARD_REMAP_T)) * iL,
                                                zero);
                    if (!nc_v8_bits(rr > 0.0f))
                        continue;
                    const nc_v8f p[3] = {o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]};
                    nc_v8f S[3];
                    for (int c = 0; c < 3; c++) {
                        /* Environment: the mean transmittance to the chord's two ends. */
                        const nc_v8f tf = front[c] + 0.5f * tau[c] * rr * dt;
                        S[c] = fr->env[c] * 0.5f * (nc_billboard_exp8(-tf) + nc_billboard_exp8(-v8_max(tau[c] - tf, zero)));
                    }
                    for (uint32_t l = 0; l < fr->suns; l++) {
                        /* Length of p + s to (s >= 0) inside the particles' bounds. */
                        const float to[3] = {-fr->sun_dir[l][0], -fr->sun_dir[l][1], -fr->sun_dir[l][2]};
                        nc_v8f len = nc_v8_splat(INFINITY);
                        for (int a = 0; a < 3; a++) {
                            if (to[a] == 0.0f)
                                continue;
                            const float inv = 1.0f / to[a];
                            const nc_v8f ta = (fr->bmin[a] - p[a]) * inv, tb = (fr->bmax[a] - p[a]) * inv;
                            len = v8_min(len, v8_max(ta, tb));
                        }
                        len = nc_v8_sel((len > 0.0f) & (len < INFINITY), len, zero);
                        const nc_v8f ds = len * (1.0f / LIGHT_STEPS);
                        nc_v8f tl[3] = {zero, zero, zero};
                        for (int m = 0; m < LIGHT_STEPS; m++) {
                            const nc_v8f s = (m + 0.5f) * ds;
                            const nc_v8f qp[3] = {p[0] + s * to[0], p[1] + s * to[1], p[2] + s * to[2]};
                            nc_v8f sig[3];
                            sigma_at8(st, fr, qp, sig);
                            for (int c = 0; c < 3; c++)
                                tl[c] += sig[c] * ds;
                        }
                        for (int c = 0; c < 3; c++)
                            S[c] += fr->sun_e[l][c] * phase[l] * nc_billboard_exp8(-tl[c]);
                    }
                    for (int c = 0; c < 3; c++) {
                        const nc_v8f st_c = tau[c] * rr, a = nc_billboard_exp8(-st_c * dt);
                        Ls[c] += T[c] * (1.0f - a) * alb[c] * S[c];
                        T[c] *= a;
                        front[c] += st_c * dt;
                    }
                }
            }
            for (int c = 0; c < 3; c++) {
                nc_v8_store(st->tl + c * plane + i, T[c]);
                nc_v8_store(st->tl + (3 + c) * plane + i, Ls[c]);
            }
        }
    }
}

/* Sprites: sort far to near (ties by index) with a merge sort (qsort_r is not C11). */
static void sort_far_first(uint32_t *ord, uint32_t *tmp, uint32_t n, const float *dist)
{
    for (uint32_t width = 1; width < n; width *= 2) {
        for (uint32_t lo = 0; lo < n; lo += 2 * width) {
            uint32_t mid = lo + width < n ? lo + width : n, hi = lo + 2 * width < n ? lo + 2 * width : n;
            uint32_t a = lo, b = mid, k = lo;
            while (a < mid && b < hi) {
                uint32_t ia = ord[a], ib = ord[b];
                bool take_b = dist[ib] > dist[ia] || (dist[ib] == dist[ia] && ib < ia);
                tmp[k++] = take_b ? ord[b++] : ord[a++];
            }
            while (a < mid)
                tmp[k++] = ord[a++];
            while (b < hi)
                tmp[k++] = ord[b++];
        }
        memcpy(ord, tmp, n * sizeof(uint32_t));
    }
}

static void sprites(pp_state *st, const pp_frame *fr, uint32_t bands, int threads)
{
    const size_t plane = (size_t)fr->rw * (size_t)fr->rh;
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads)
    for (uint32_t b = 0; b < bands; b++) {
        static const float cleared[6] = {1, 1, 1, 0, 0, 0}; /* transmittance, radiance */
        int32_t y0, y1;
        band_start(fr, b, st->tl, 6, cleared, &y0, &y1);
        for (uint32_t e = st->bin_start[b]; e < st->bin_start[b + 1]; e++) {
            const uint32_t j = st->bins[e];
            const int32_t *rc = st->rect + 4 * (size_t)j;
            const pp_system *sy = &st->sys_table[st->sys[j]];
            const float R = st->radius[j], *lit = st->lit + 3 * (size_t)j;
            const bool grey = sy->sigma_t[0] == sy->sigma_t[1] && sy->sigma_t[1] == sy->sigma_t[2];
            const int32_t ya = rc[2] > y0 ? rc[2] : y0, yb = rc[3] < y1 ? rc[3] : y1;
            for (int32_t y = ya; y <= yb; y++) {
                const size_t ri = (size_t)(y - fr->ry0) * (size_t)fr->rw - (size_t)fr->rx0;
                for (int32_t x = rc[0]; x <= rc[1]; x++) {
                    float o[3], d[3], wgt, tm, hc;
                    float ts = pixel_ray(st, fr, x - fr->rx0, y - fr->ry0, o, d);
                    float v[3] = {st->cx[j] - o[0], st->cy[j] - o[1], st->cz[j] - o[2]};
                    if (!nc_billboard_hit(v, d, R, &wgt, &tm, &hc))
                        continue;
                    /* Soft particles; the clamp as fminf(fmaxf()) gives it, a NaN to 0. */
                    float fade = (ts - tm) / R;
                    fade = fade > 0.0f ? (fade < 1.0f ? fade : 1.0f) : 0.0f;
                    if (!(fade > 0.0f))
                        continue;
                    const size_t i = ri + (size_t)x;
                    float col = st->column[j] * wgt * fade, keep[3];
                    keep[0] = nc_fast_exp(-sy->sigma_t[0] * col);
                    keep[1] = grey ? keep[0] : nc_fast_exp(-sy->sigma_t[1] * col);
                    keep[2] = grey ? keep[0] : nc_fast_exp(-sy->sigma_t[2] * col);
                    for (int c = 0; c < 3; c++) {
                        st->tl[c * plane + i] *= keep[c];
                        st->tl[(3 + c) * plane + i] = st->tl[(3 + c) * plane + i] * keep[c] + (1.0f - keep[c]) * lit[c];
                    }
                }
            }
        }
    }
}

/* Each image pixel over the rect: c T + L, bilinear from the buffers (outside: T 1, L 0).
 * Separable: per image row, the 6 planes interpolated between their two buffer rows into a row
 * of scratch (with one cleared column each side), then each pixel between two of its columns. */
static void composite(pp_state *st, const pp_frame *fr, nacre_image *image, int threads)
{
    const size_t plane = (size_t)fr->rw * (size_t)fr->rh, cw = (size_t)fr->rw + 2;
    const int32_t F = fr->F;
    int32_t y0 = fr->ry0 * F - F, y1 = (fr->ry0 + fr->rh) * F + F, x0 = fr->rx0 * F - F, x1 = (fr->rx0 + fr->rw) * F + F;
    y0 = y0 > 0 ? y0 : 0, x0 = x0 > 0 ? x0 : 0;
    y1 = y1 < fr->H ? y1 : fr->H, x1 = x1 < fr->W ? x1 : fr->W;
#pragma omp parallel num_threads(threads)
    {
        int tid = 0;
#ifdef _OPENMP
        tid = omp_get_thread_num();
#endif
        float *V = st->crow + (size_t)tid * 6 * cw;
        for (int k = 0; k < 6; k++)
            V[k * cw] = V[k * cw + cw - 1] = k < 3 ? 1.0f : 0.0f;
#pragma omp for schedule(static)
        for (int32_t y = y0; y < y1; y++) {
            float *row = image->pixels + (size_t)y * image->stride;
            float v = (y + 0.5f) / (float)F - 0.5f - (float)fr->ry0;
            int32_t j0 = (int32_t)floorf(v);
            float fy = v - (float)j0;
            for (int k = 0; k < 6; k++) {
                const float clear = k < 3 ? 1.0f : 0.0f;
                const float *p0 = j0 >= 0 && j0 < fr->rh ? st->tl + k * plane + (size_t)j0 * (size_t)fr->rw : NULL;
                const float *p1 = j0 + 1 >= 0 && j0 + 1 < fr->rh ? st->tl + k * plane + (size_t)(j0 + 1) * (size_t)fr->rw
                                                                 : NULL;
                float *out = V + k * cw + 1;
                for (int32_t i = 0; i < fr->rw; i++)
                    out[i] = (1.0f - fy) * (p0 ? p0[i] : clear) + fy * (p1 ? p1[i] : clear);
            }
            for (int32_t x = x0; x < x1; x++) {
                float u = (x + 0.5f) / (float)F - 0.5f - (float)fr->rx0;
                int32_t i0 = (int32_t)floorf(u);
                float fx = u - (float)i0;
                if (i0 < -1 || i0 >= fr->rw)
                    continue; /* both taps outside: T 1, L 0 */
                /* Scratch column i0 + 1 is buffer column i0. */
                const float *c0 = V + (size_t)(i0 + 1);
                float *px = row + 3 * (size_t)x;
                for (int c = 0; c < 3; c++) {
                    float T = (1.0f - fx) * c0[c * cw] + fx * c0[c * cw + 1];
                    float L = (1.0f - fx) * c0[(3 + c) * cw] + fx * c0[(3 + c) * cw + 1];
                    px[c] = px[c] * T + L;
                }
            }
        }
    }
}

static nacre_result pp_apply(void *state, const nc_post_input *in, nacre_image *image, nacre_render_stats *stats)
{
    pp_state *st = state;
    uint64_t t_start = nc_now_us();
    pp_frame fr;
    memset(&fr, 0, sizeof(fr));
    nacre_result r = frame_setup(st, in, &fr);
    if (r == NACRE_OK)
        r = gather(st, in, &fr);
    if (r != NACRE_OK)
        return r;
    const int threads = in->ctx->threads;
    uint32_t bands = 0;
    if (fr.rw > 0 && fr.rh > 0) {
        size_t plane = (size_t)fr.rw * (size_t)fr.rh;
        if ((r = nc_memory_check(in->ctx, 28 * plane * sizeof(float), "particle billboard buffers")) != NACRE_OK)
            return r;
        if (!nc_reserve(in->ctx, &st->tl, &st->tl_cap, 6 * plane, sizeof(float)))
            return NACRE_ERROR_OUT_OF_MEMORY;
        if ((r = make_rays(in->ctx, st, &fr)) != NACRE_OK)
            return r;
        if (in->settings->particles == NACRE_PARTICLES_DRAW_SPRITES) {
            for (uint32_t j = 0; j < st->count; j++) {
                const pp_system *sy = &st->sys_table[st->sys[j]];
                float len = st->dist[j] > 0.0f ? st->dist[j] : 1.0f, *lit = st->lit + 3 * (size_t)j;
                float d[3] = {st->cx[j] / len, st->cy[j] / len, st->cz[j] / len};
                if (fr.ortho)
                    d[0] = d[1] = 0.0f, d[2] = -1.0f;
                for (int c = 0; c < 3; c++)
                    lit[c] = fr.env[c];
                for (uint32_t l = 0; l < fr.suns; l++) {
                    float p = (float)nc_hg_phase(-(d[0] * fr.sun_dir[l][0] + d[1] * fr.sun_dir[l][1] +
                                                   d[2] * fr.sun_dir[l][2]), sy->g);
                    for (int c = 0; c < 3; c++)
                        lit[c] += fr.sun_e[l][c] * p;
                }
                for (int c = 0; c < 3; c++)
                    lit[c] *= sy->albedo[c];
                st->order[j] = j;
            }
            sort_far_first(st->order, st->sort_tmp, st->count, st->dist);
            if ((r = bin(in->ctx, st, &fr, st->order, &bands)) != NACRE_OK)
                return r;
            sprites(st, &fr, bands, threads);
        } else {
            if (!nc_reserve(in->ctx, &st->acc, &st->acc_cap, 8 * plane, sizeof(float)) ||
                !nc_reserve(in->ctx, &st->look, &st->look_cap, LOOK * plane, sizeof(float)))
                return NACRE_ERROR_OUT_OF_MEMORY;
            uint32_t ntx, nty;
            if ((r = bin_tiles(in->ctx, st, &fr, &ntx, &nty)) != NACRE_OK)
                return r;
            accumulate(st, &fr, ntx, nty, in->scene->particles_count == 1, threads);
            pack_lookup(st, &fr, threads);
            /* One phase function: the scattering-weighted mean g of the systems. */
            double gs = 0.0, ws = 0.0;
            for (uint32_t i = 0; i < in->scene->particles_count; i++) {
                const nacre_particles_desc *d;
                const nc_particle_set *set = nc_scene_particle_set(in->scene, i, &d);
                double m = set ? nc_particles_mass(set) * (d->sigma_s[0] + d->sigma_s[1] + d->sigma_s[2]) : 0.0;
                gs += m * d->g;
                ws += m;
            }
            march(st, &fr, ws > 0 ? (float)(gs / ws) : 0.0f, threads);
        }
        if (!nc_reserve(in->ctx, &st->crow, &st->crow_cap, (size_t)(threads > 0 ? threads : 1) * 6 * ((size_t)fr.rw + 2),
                        sizeof(float)))
            return NACRE_ERROR_OUT_OF_MEMORY;
        composite(st, &fr, image, threads);
    }
    stats->stage_us[NACRE_STAGE_PARTICLES] += nc_now_us() - t_start;
    stats->stage_ran[NACRE_STAGE_PARTICLES] = true;
    stats->stage_runs[NACRE_STAGE_PARTICLES] = 1;
    return NACRE_OK;
}

const nc_post_pass nc_post_particles = {
    .name = "particles",
    .wanted = pp_wanted,
    .create = pp_create,
    .apply = pp_apply,
    .destroy = pp_destroy,
};
