/*
 * pyramid.c: the voxel pyramid (seed 000, section 4.2.2): level l + 1 halves level l along every
 * axis (rounding up), a coarse voxel being in a set (surface, solid) when any of its 2 x 2 x 2
 * children is. Levels stop before a side would drop below 4 voxels. Sets laid out as in
 * voxel_internal.h; a coarse word gathers two fine words of a column (compress_pairs).
 */
#include "voxel/voxel_internal.h"

/* OR of bits 2i and 2i+1 of a word into bit i of the low half. */
static inline uint64_t compress_pairs(uint64_t w)
{
#ifdef __BMI2__
    return _pext_u64(w | (w >> 1), 0x5555555555555555ull); /* one instruction for the five steps */
#else
    uint64_t x = (w | (w >> 1)) & 0x5555555555555555ull;
    x = (x | (x >> 1)) & 0x3333333333333333ull;
    x = (x | (x >> 2)) & 0x0f0f0f0f0f0f0f0full;
    x = (x | (x >> 4)) & 0x00ff00ff00ff00ffull;
    x = (x | (x >> 8)) & 0x0000ffff0000ffffull;
    x = (x | (x >> 16)) & 0x00000000ffffffffull;
    return x;
#endif
}

static void downsample(const bitset *fine, const uint64_t *fs, const bitset *coarse, uint64_t *cs,
                       int threads)
{
    const uint32_t *cd = coarse->dims;
    size_t work = (size_t)fine->dims[0] * fine->dims[1] * fine->words;
    (void)work;
#pragma omp parallel for schedule(static) num_threads(threads) if (work > 16384)
    for (uint32_t y = 0; y < cd[1]; y++) {
        for (uint32_t x = 0; x < cd[0]; x++) {
            uint64_t *out = cs + ((size_t)y * cd[0] + x) * coarse->words;
            for (uint32_t dy = 0; dy < 2; dy++) {
                for (uint32_t dx = 0; dx < 2; dx++) {
                    uint32_t fx = 2 * x + dx, fy = 2 * y + dy;
                    if (fx >= fine->dims[0] || fy >= fine->dims[1])
                        continue;
                    const uint64_t *in = fs + ((size_t)fy * fine->dims[0] + fx) * fine->words;
                    for (uint32_t w = 0; w < fine->words; w++)
                        out[w / 2] |= compress_pairs(in[w]) << (32 * (w % 2));
                }
            }
        }
    }
}

/* Levels 1.. of g from level 0 (g->levels counts them; on a failure the caller resets it). */
nacre_result nc_voxel_pyramid(nacre_context *ctx, nacre_voxel_grid *g, int threads)
{
    nacre_result r;
    g->levels = 1;
    while (g->levels < VOXEL_MAX_LEVELS) {
        const bitset *f = &g->level[g->levels - 1];
        uint32_t cd[3];
        for (int a = 0; a < 3; a++)
            cd[a] = (f->dims[a] + 1) / 2;
        if (cd[0] < 4 || cd[1] < 4 || cd[2] < 4 || (f->dims[0] <= 4 || f->dims[1] <= 4 || f->dims[2] <= 4))
            break;
        bitset *c = &g->level[g->levels];
        r = nc_voxel_bitset_alloc(ctx, g, g->levels, cd);
        if (r != NACRE_OK)
            return r;
        downsample(f, f->surface, c, c->surface, threads);
        downsample(f, f->solid, c, c->solid, threads);
        g->levels++;
    }
    return NACRE_OK;
}
