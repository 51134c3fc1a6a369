/*
 * masked_compare.c: masked_compare TEST REF BG A B: the mean relative error of TEST against REF
 * over the pixels where image A or B differs from BG by more than 0.5% in some channel (for
 * particles: the pixels the billboards or the sprites cover, BG being the frame without them),
 * the mean ratio sum(TEST) / sum(REF) there, and the mean relative error over the whole image
 * (as `nacre compare`). Built and run by scripts/particles_accuracy.sh.
 */
#include <nacre/nacre.h>
#include <math.h>
#include <stdio.h>
int main(int argc, char **argv)
{
    if (argc < 6) return 2;
    nacre_context *ctx; nacre_context_create(NULL, &ctx);
    nacre_image t = {0}, r = {0}, bg = {0}, a = {0}, b = {0};
    if (nacre_image_read(ctx, argv[1], &t) || nacre_image_read(ctx, argv[2], &r) || nacre_image_read(ctx, argv[3], &bg) ||
        nacre_image_read(ctx, argv[4], &a) || nacre_image_read(ctx, argv[5], &b)) { printf("read fail %s\n", nacre_context_last_error(ctx)); return 2; }
    double sum = 0, full = 0, st = 0, sr = 0; long n = 0, nf = 0;
    for (int y = 0; y < r.height; y++) for (int x = 0; x < r.width; x++) {
        const float *pt = t.pixels + (size_t)y * t.stride + 3 * x, *pr = r.pixels + (size_t)y * r.stride + 3 * x;
        const float *pb = bg.pixels + (size_t)y * bg.stride + 3 * x, *pa = a.pixels + (size_t)y * a.stride + 3 * x, *pc = b.pixels + (size_t)y * b.stride + 3 * x;
        int m = 0;
        for (int c = 0; c < 3; c++) {
            if (fabsf(pa[c] - pb[c]) > 0.005f * fabsf(pb[c]) + 1e-6f || fabsf(pc[c] - pb[c]) > 0.005f * fabsf(pb[c]) + 1e-6f) m = 1;
            if (pr[c] != 0) { full += fabs(pt[c] - pr[c]) / fabs(pr[c]); nf++; }
        }
        if (!m) continue;
        for (int c = 0; c < 3; c++) if (pr[c] != 0) { sum += fabs(pt[c] - pr[c]) / fabs(pr[c]); st += pt[c]; sr += pr[c]; n++; }
    }
    printf("plume pixels %ld: mean rel err %.4f, mean ratio %.4f; whole image mean rel err %.4f\n", n / 3, sum / n, st / sr, full / nf);
    return 0;
}
