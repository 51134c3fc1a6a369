/*
 * face_stats.c: face_stats TEST REF sphere|checker [REF2]: docs/accuracy.md's per-region measures of a
 * diffusion image against the path tracer's on issue 28's scenes (the cameras of
 * examples/accuracy_sphere.json and examples/accuracy_checker.json, any square size).
 * checker: per visible face (+X, -Y, +Z; pixels within 0.03 of an edge left out) the mean ratio
 * per channel, the correlation of the G - B signal with the reference's and the ratio of their
 * standard deviations (the reference's noise is in its deviation: a lower bound). With a second
 * reference of another seed (REF2), also the noise-free forms: the truth's signal variance is the
 * covariance of the two references' signals (their noise is independent), so the contrast is
 * sqrt(var(test) / cov(ref, ref2)) and the correlation cov(test, ref) / sqrt(var(test) cov(ref, ref2)).
 * sphere: the mean ratio over lit pixels (n.l > 0) by the normal's angle to the nearest grid
 * axis, and over the shadowed crescent (n.l in (-0.3, 0)); pixels seen at more than 75 degrees
 * left out (anti-aliasing).
 *   cc -O2 scripts/face_stats.c -Iinclude -Lbuild/release -lnacre -lm -Wl,-rpath,build/release
 */
#include <nacre/nacre.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
typedef struct { double x, y, z; } v3;
static v3 sub(v3 a, v3 b) { return (v3){a.x - b.x, a.y - b.y, a.z - b.z}; }
static v3 cross(v3 a, v3 b) { return (v3){a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
static double dot(v3 a, v3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static v3 nrm(v3 a) { double l = sqrt(dot(a, a)); return (v3){a.x / l, a.y / l, a.z / l}; }
int main(int argc, char **argv)
{
    if (argc < 4)
        return 2;
    nacre_context *ctx; nacre_context_create(NULL, &ctx);
    nacre_image t = {0}, r = {0};
    nacre_image r2 = {0};
    if (nacre_image_read(ctx, argv[1], &t) || nacre_image_read(ctx, argv[2], &r)) { printf("read fail\n"); return 2; }
    if (argc > 4 && nacre_image_read(ctx, argv[4], &r2)) { printf("read fail\n"); return 2; }
    double gc[8] = {0}, gcc[8] = {0}, grc[8] = {0};
    int checker = strcmp(argv[3], "checker") == 0;
    v3 pos = checker ? (v3){2.4, -3.2, 2.0} : (v3){0, 0, 4.5}, up = checker ? (v3){0, 0, 1} : (v3){0, 1, 0};
    v3 f = nrm(sub((v3){0, 0, 0}, pos)), rt = nrm(cross(f, up)), u = cross(rt, f);
    double tf = tan(15.0 * M_PI / 180.0);
    int W = r.width, H = r.height;
    /* per class accumulators */
    double st[8][3] = {{0}}, sr[8][3] = {{0}}; double ga[8] = {0}, gb[8] = {0}, gaa[8] = {0}, gbb[8] = {0}, gab[8] = {0}; long n[8] = {0};
    for (int y = 0; y < H; y++) for (int x = 0; x < W; x++) {
        const float *pt = t.pixels + (size_t)y * t.stride + 3 * x, *pr = r.pixels + (size_t)y * r.stride + 3 * x;
        if (!(pr[0] + pr[1] + pr[2] > 0)) continue;
        double sx = (2 * (x + 0.5) / W - 1) * tf, sy = (1 - 2 * (y + 0.5) / H) * tf;
        v3 d = nrm((v3){f.x + sx * rt.x + sy * u.x, f.y + sx * rt.y + sy * u.y, f.z + sx * rt.z + sy * u.z});
        int cls = -1;
        if (checker) {
            double tmin = -1e9; int ax = -1;
            double o[3] = {pos.x, pos.y, pos.z}, dd[3] = {d.x, d.y, d.z}; double tmax = 1e9;
            for (int a = 0; a < 3; a++) { double t0 = (-0.5 - o[a]) / dd[a], t1 = (0.5 - o[a]) / dd[a]; if (t0 > t1) { double q = t0; t0 = t1; t1 = q; } if (t0 > tmin) { tmin = t0; ax = a; } if (t1 < tmax) tmax = t1; }
            if (tmin > tmax) continue;
            double pp[3] = {o[0] + tmin * dd[0], o[1] + tmin * dd[1], o[2] + tmin * dd[2]};
            /* skip pixels within 0.03 of an edge */
            int edge = 0; for (int a = 0; a < 3; a++) if (a != ax && fabs(pp[a]) > 0.47) edge = 1;
            if (edge) continue;
            cls = ax;
        } else {
            double b = dot(pos, d), c = dot(pos, pos) - 1, disc = b * b - c;
            if (disc < 0) continue;
            double tt = -b - sqrt(disc);
            v3 p = {pos.x + tt * d.x, pos.y + tt * d.y, pos.z + tt * d.z};
            if (-dot(p, d) < 0.25) continue;
            double m = fmax(fabs(p.x), fmax(fabs(p.y), fabs(p.z)));
            double ang = acos(fmin(m, 1.0)) * 180 / M_PI; /* angle to the nearest axis */
            v3 L = nrm((v3){0.55, 0.45, 0.7});
            double nl = dot(p, L);
            if (nl < 0) cls = 6 + (nl > -0.3 ? 0 : 1); /* 6: crescent, 7: deep dark */
            else cls = ang < 10 ? 0 : ang < 20 ? 1 : ang < 30 ? 2 : ang < 40 ? 3 : ang < 50 ? 4 : 5;
        }
        n[cls]++;
        for (int c = 0; c < 3; c++) { st[cls][c] += pt[c]; sr[cls][c] += pr[c]; }
        double a = pt[1] - pt[2], bb = pr[1] - pr[2];
        ga[cls] += a; gb[cls] += bb; gaa[cls] += a * a; gbb[cls] += bb * bb; gab[cls] += a * bb;
        if (r2.pixels) {
            const float *p2 = r2.pixels + (size_t)y * r2.stride + 3 * x;
            double cc = p2[1] - p2[2];
            gc[cls] += cc; gcc[cls] += cc * cc; grc[cls] += bb * cc;
        }
    }
    const char *names_c[3] = {"+X", "-Y", "+Z"};
    const char *names_s[8] = {"lit ax<10", "lit 10-20", "lit 20-30", "lit 30-40", "lit 40-50", "lit >50", "dark nl>-.3", "dark nl<-.3"};
    for (int k = 0; k < 8; k++) {
        if (!n[k]) continue;
        printf("%-12s n=%5ld ratio %.3f %.3f %.3f", checker ? names_c[k] : names_s[k], n[k], st[k][0] / sr[k][0], st[k][1] / sr[k][1], st[k][2] / sr[k][2]);
        if (checker) {
            double N = n[k], ma = ga[k] / N, mb = gb[k] / N, va = gaa[k] / N - ma * ma, vb = gbb[k] / N - mb * mb, cv = gab[k] / N - ma * mb;
            printf("  G-B corr %.3f std ratio %.3f", cv / sqrt(va * vb), sqrt(va / vb));
            if (r2.pixels) {
                double mc = gc[k] / N, vc = gcc[k] / N - mc * mc, c12 = grc[k] / N - mb * mc;
                printf("  | ref2 std ratio %.3f, refs' corr %.3f; noise-free: corr %.3f std ratio %.3f",
                       sqrt(va / vc), c12 / sqrt(vb * vc), cv / sqrt(va * c12), sqrt(va / c12));
            }
        }
        printf("\n");
    }
    return 0;
}
