/*
 * maps.c: procedural depth maps for layered materials (nacre_layer_map_generate), the kind of
 * "subsurface texture" seed 001 (Francois et al. 2006, section 2.1 and figures 4 and 12) paints
 * by hand: RGBA, channel j scaling the depth of layer j (nacre_layering), values in [0, 1].
 *
 *  - CONSTANT: every channel 1 (layers of constant thickness).
 *  - VEINS: R = 1 (a skin of constant thickness), G = branching veins (1 on a vein's axis,
 *    falling to 0 at its edge with the circular profile sqrt(1 - (d / w)^2) of a tube seen from
 *    above; widths taper from the trunks to the branches), B = 1 (the layer under the veins),
 *    A = 1.
 *  - SPOTS: R = 1, G = round spots of random radius with the same profile, B = A = 1.
 * The trees grow by random walks: each segment turns by a random angle, and splits with a fixed
 * probability into two thinner branches. Everything comes from a small counter-based generator
 * seeded with `seed`: the same seed gives the same map. Maps repeat (uv wraps), so shapes are
 * drawn with wrap-around.
 */
#include "core/core.h"

#include <math.h>
#include <string.h>

/* splitmix64: one independent 64-bit value per call */
static uint64_t next_u64(uint64_t *s)
{
    uint64_t z = (*s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

static float uniform(uint64_t *s) { return (float)(next_u64(s) >> 40) * (1.0f / 16777216.0f); }

/* max-blend a tube of radius w around segment (ax, ay)-(bx, by) into channel 1 (pixels). */
static void draw_segment(nacre_image *img, float ax, float ay, float bx, float by, float w)
{
    const int32_t n = img->width;
    int32_t x0 = (int32_t)floorf(fminf(ax, bx) - w), x1 = (int32_t)ceilf(fmaxf(ax, bx) + w);
    int32_t y0 = (int32_t)floorf(fminf(ay, by) - w), y1 = (int32_t)ceilf(fmaxf(ay, by) + w);
    const float dx = bx - ax, dy = by - ay, l2 = dx * dx + dy * dy;
    for (int32_t y = y0; y <= y1; y++)
        for (int32_t x = x0; x <= x1; x++) {
            float px = (float)x + 0.5f - ax, py = (float)y + 0.5f - ay;
            float t = l2 > 0 ? (px * dx + py * dy) / l2 : 0.0f;
            t = t < 0 ? 0 : t > 1 ? 1 : t;
            float qx = px - t * dx, qy = py - t * dy, d = sqrtf(qx * qx + qy * qy);
            if (d >= w)
                continue;
            float v = sqrtf(1.0f - (d / w) * (d / w));
            int32_t wx = ((x % n) + n) % n, wy = ((y % n) + n) % n;
            float *p = img->pixels + img->stride * (size_t)wy + 4 * (size_t)wx + 1;
            if (v > *p)
                *p = v;
        }
}

typedef struct branch {
    float x, y, angle, width;
    int depth;
} branch;

static void draw_veins(nacre_image *img, uint64_t *rng)
{
    const float n = (float)img->width;
    branch stack[256];
    int top = 0;
    const int trunks = 3;
    for (int t = 0; t < trunks; t++)
        stack[top++] = (branch){uniform(rng) * n, uniform(rng) * n, uniform(rng) * 6.2831853f, n * 0.012f, 0};
    while (top > 0) {
        branch b = stack[--top];
        const int segments = 24 + (int)(uniform(rng) * 16);
        const float step = n * 0.012f;
        for (int s = 0; s < segments && b.width > n * 0.0015f; s++) {
            b.angle += (uniform(rng) - 0.5f) * 0.7f;
            float nx = b.x + step * cosf(b.angle), ny = b.y + step * sinf(b.angle);
            draw_segment(img, b.x, b.y, nx, ny, b.width);
            b.x = nx, b.y = ny;
            b.width *= 0.985f;
            if (b.depth < 4 && top < 254 && uniform(rng) < 0.08f) {
                float turn = (0.4f + 0.5f * uniform(rng)) * (uniform(rng) < 0.5f ? -1.0f : 1.0f);
                stack[top++] = (branch){b.x, b.y, b.angle + turn, b.width * 0.7f, b.depth + 1};
                b.width *= 0.85f;
            }
        }
    }
}

static void draw_spots(nacre_image *img, uint64_t *rng)
{
    const float n = (float)img->width;
    for (int i = 0; i < 40; i++) {
        float x = uniform(rng) * n, y = uniform(rng) * n, r = n * (0.01f + 0.04f * uniform(rng));
        draw_segment(img, x, y, x, y, r);
    }
}

bool nacre_layer_map_kind_from_name(const char *name, nacre_layer_map_kind *out)
{
    static const char *const names[] = {"constant", "veins", "spots"};
    for (int i = 0; name && i < 3; i++)
        if (strcmp(name, names[i]) == 0) {
            *out = (nacre_layer_map_kind)i;
            return true;
        }
    return false;
}

nacre_result nacre_layer_map_generate(nacre_context *ctx, nacre_layer_map_kind kind, int32_t size, uint32_t seed,
                                      nacre_image *out)
{
    if (!ctx || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (size < 8 || size > 8192)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "layer map: size %d is not in 8..8192", (int)size);
    if (kind != NACRE_LAYER_MAP_CONSTANT && kind != NACRE_LAYER_MAP_VEINS && kind != NACRE_LAYER_MAP_SPOTS)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "layer map: unknown kind (%d)", (int)kind);
    nacre_result r = nacre_image_alloc(ctx, size, size, 4, out);
    if (r != NACRE_OK)
        return r;
    for (int32_t y = 0; y < size; y++)
        for (int32_t x = 0; x < size; x++) {
            float *p = out->pixels + out->stride * (size_t)y + 4 * (size_t)x;
            p[0] = p[2] = p[3] = 1.0f;
            p[1] = kind == NACRE_LAYER_MAP_CONSTANT ? 1.0f : 0.0f;
        }
    uint64_t rng = 0x6a09e667f3bcc909ull ^ ((uint64_t)seed << 17) ^ (uint64_t)kind;
    if (kind == NACRE_LAYER_MAP_VEINS)
        draw_veins(out, &rng);
    else if (kind == NACRE_LAYER_MAP_SPOTS)
        draw_spots(out, &rng);
    return NACRE_OK;
}
