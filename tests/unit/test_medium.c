/*
 * test_medium.c: heterogeneous media (src/scene/medium.c) and density volumes (scene storage,
 * src/io/nrrd.c). Pattern statistics (random-mix fraction within binomial bounds, checker parity,
 * noise range, continuity), determinism across batch sizes and threads, trilinear volumes exact
 * on a linear field, majorants above every sample, validation, NRRD round trips (voxelizer
 * exports and files written here in several types and byte orders) and malformed NRRD headers.
 */
#include "io/nrrd.h"
#include "scene/medium.h"
#include "test_util.h"

#include <sys/stat.h>

#define TMP NACRE_TEST_TMP "/medium"

static nacre_material_desc two_media(nacre_pattern_type type)
{
    nacre_material_desc m;
    nacre_material_preset("marble", &m);
    nacre_material_desc k;
    nacre_material_preset("ketchup", &k);
    m.pattern.type = type;
    memcpy(m.pattern.sigma_a2, k.sigma_a, sizeof(k.sigma_a));
    memcpy(m.pattern.sigma_s2, k.sigma_s, sizeof(k.sigma_s));
    m.pattern.cell_size = 0.75f;
    m.pattern.fraction = 0.3f;
    m.pattern.seed = 7;
    m.pattern.octaves = 4;
    return m;
}

static bool is_medium(const float *sa, const float *ss, const float *a, const float *s)
{
    return memcmp(sa, a, 3 * sizeof(float)) == 0 && memcmp(ss, s, 3 * sizeof(float)) == 0;
}

/* Small deterministic generator for test points. */
static uint64_t rng_state = 0x9e3779b97f4a7c15ull;
static double urand(void)
{
    rng_state = rng_state * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(rng_state >> 11) * (1.0 / 9007199254740992.0);
}

/* ------------------------------------------------------------------------------------------ */

static void test_random_mix(nacre_scene *scene)
{
    nacre_material_desc m = two_media(NACRE_PATTERN_RANDOM_MIX);
    const int side = 60; /* 216000 cells, one point at each centre */
    size_t n = (size_t)side * side * side;
    float *p = malloc(n * 3 * sizeof(float)), *sa = malloc(n * 3 * sizeof(float)), *ss = malloc(n * 3 * sizeof(float));
    size_t i = 0;
    for (int z = 0; z < side; z++)
        for (int y = 0; y < side; y++)
            for (int x = 0; x < side; x++, i++) {
                p[3 * i] = (float)((x - side / 2 + 0.5) * m.pattern.cell_size);
                p[3 * i + 1] = (float)((y - side / 2 + 0.5) * m.pattern.cell_size);
                p[3 * i + 2] = (float)((z - side / 2 + 0.5) * m.pattern.cell_size);
            }
    nc_medium_eval(scene, &m, p, n, sa, ss);
    size_t two = 0, other = 0, pairs = 0, both = 0;
    for (i = 0; i < n; i++) {
        bool is2 = is_medium(sa + 3 * i, ss + 3 * i, m.pattern.sigma_a2, m.pattern.sigma_s2);
        bool is1 = is_medium(sa + 3 * i, ss + 3 * i, m.sigma_a, m.sigma_s);
        two += is2;
        other += !is1 && !is2;
        /* Neighbours along x must be independent: P(both) = p^2. */
        if (i % (size_t)side != (size_t)side - 1) {
            bool next2 = is_medium(sa + 3 * (i + 1), ss + 3 * (i + 1), m.pattern.sigma_a2, m.pattern.sigma_s2);
            pairs++;
            both += is2 && next2;
        }
    }
    double f = (double)m.pattern.fraction;
    double sigma = sqrt(f * (1 - f) / (double)n);
    double got = (double)two / (double)n;
    printf("random_mix: %zu cells, fraction %.5f (expected %.2f, 5 sigma = %.5f)\n", n, got, f, 5 * sigma);
    CHECK(other == 0);
    CHECK(fabs(got - f) < 5 * sigma);
    double pb = f * f, sb = sqrt(pb * (1 - pb) / (double)pairs);
    CHECK(fabs((double)both / (double)pairs - pb) < 5 * sb);

    /* Every point of a cell gets the cell's medium. */
    for (int t = 0; t < 2000; t++) {
        size_t c = (size_t)(urand() * (double)n) % n;
        float q[3];
        for (int k = 0; k < 3; k++)
            q[k] = p[3 * c + k] + (float)((urand() - 0.5) * 0.98) * m.pattern.cell_size;
        float qa[3], qs[3];
        nc_medium_eval(scene, &m, q, 1, qa, qs);
        CHECK(memcmp(qa, sa + 3 * c, sizeof(qa)) == 0 && memcmp(qs, ss + 3 * c, sizeof(qs)) == 0);
    }
    /* A different seed gives a different pattern; fraction 0 and 1 are pure media. */
    nacre_material_desc m2 = m;
    m2.pattern.seed = 8;
    float *sa2 = malloc(n * 3 * sizeof(float)), *ss2 = malloc(n * 3 * sizeof(float));
    nc_medium_eval(scene, &m2, p, n, sa2, ss2);
    size_t differ = 0;
    for (i = 0; i < n; i++)
        differ += sa2[3 * i] != sa[3 * i];
    CHECK(differ > n / 4);
    m2.pattern.fraction = 0.0f;
    nc_medium_eval(scene, &m2, p, n, sa2, ss2);
    bool all1 = true;
    for (i = 0; i < n; i++)
        all1 &= is_medium(sa2 + 3 * i, ss2 + 3 * i, m.sigma_a, m.sigma_s);
    CHECK(all1);
    m2.pattern.fraction = 1.0f;
    nc_medium_eval(scene, &m2, p, n, sa2, ss2);
    bool all2 = true;
    for (i = 0; i < n; i++)
        all2 &= is_medium(sa2 + 3 * i, ss2 + 3 * i, m.pattern.sigma_a2, m.pattern.sigma_s2);
    CHECK(all2);
    free(sa2);
    free(ss2);
    free(p);
    free(sa);
    free(ss);
}

static void test_checker(nacre_scene *scene)
{
    nacre_material_desc m = two_media(NACRE_PATTERN_CHECKER);
    m.pattern.cell_size = 1.5f;
    int bad = 0, count = 0;
    for (int z = -6; z < 6; z++)
        for (int y = -6; y < 6; y++)
            for (int x = -6; x < 6; x++)
                for (int t = 0; t < 3; t++) {
                    /* Random points strictly inside the cell (away from its faces). */
                    float q[3] = {(float)((x + 0.01 + 0.98 * urand()) * 1.5), (float)((y + 0.01 + 0.98 * urand()) * 1.5),
                                  (float)((z + 0.01 + 0.98 * urand()) * 1.5)};
                    float sa[3], ss[3];
                    nc_medium_eval(scene, &m, q, 1, sa, ss);
                    bool odd = ((x + y + z) & 1) != 0;
                    bool ok = odd ? is_medium(sa, ss, m.pattern.sigma_a2, m.pattern.sigma_s2)
                                  : is_medium(sa, ss, m.sigma_a, m.sigma_s);
                    bad += !ok;
                    count++;
                }
    printf("checker: %d of %d points with the wrong parity\n", bad, count);
    CHECK(bad == 0);
}

static void test_noise(nacre_scene *scene)
{
    nacre_material_desc m = two_media(NACRE_PATTERN_NOISE);
    m.pattern.cell_size = 2.0f;
    const size_t n = 100000;
    double sum = 0, sum2 = 0, lo = 1, hi = 0, max_jump = 0;
    bool blend_ok = true;
    for (size_t i = 0; i < n; i++) {
        float q[3] = {(float)(urand() * 40 - 20), (float)(urand() * 40 - 20), (float)(urand() * 40 - 20)};
        float w = nc_medium_pattern_weight(&m.pattern, q);
        lo = fmin(lo, w);
        hi = fmax(hi, w);
        sum += w;
        sum2 += (double)w * w;
        /* Continuity: a step of 1e-4 cells moves w by at most Lipschitz * step. */
        float r[3] = {q[0] + 2e-4f, q[1] - 2e-4f, q[2] + 2e-4f};
        max_jump = fmax(max_jump, fabs((double)nc_medium_pattern_weight(&m.pattern, r) - w));
        float sa[3], ss[3];
        nc_medium_eval(scene, &m, q, 1, sa, ss);
        for (int c = 0; c < 3; c++) {
            double ea = m.sigma_a[c] + w * ((double)m.pattern.sigma_a2[c] - m.sigma_a[c]);
            double es = m.sigma_s[c] + w * ((double)m.pattern.sigma_s2[c] - m.sigma_s[c]);
            blend_ok &= fabs(sa[c] - ea) <= 1e-6 * (1 + fabs(ea)) && fabs(ss[c] - es) <= 1e-6 * (1 + fabs(es));
        }
    }
    double mean = sum / (double)n, sd = sqrt(fmax(0, sum2 / (double)n - mean * mean));
    printf("noise: w in [%.4f, %.4f], mean %.4f, sd %.4f, max change over 3.5e-4 units %.2e\n", lo, hi, mean, sd,
           max_jump);
    CHECK(lo >= 0 && hi <= 1);
    CHECK(hi - lo > 0.5);
    CHECK(fabs(mean - 0.5) < 0.05);
    CHECK(sd > 0.05);
    /* Lipschitz bound: each octave <= 1.875 * sqrt(3) * 2^o / cell * 2^-o over the amplitude
     * sum, i.e. under 3.25 * octaves / (cell * 1.875) per unit: ~3.5 per unit here. */
    CHECK(max_jump < 3.5 * 3.5e-4 * 1.5);
    CHECK(blend_ok);

    /* Octaves: 1 is smooth value noise; 12 still in range. */
    m.pattern.octaves = 12;
    bool in = true;
    for (int i = 0; i < 10000; i++) {
        float q[3] = {(float)(urand() * 1e4), (float)(urand() * 1e4), (float)(urand() * -1e4)};
        float w = nc_medium_pattern_weight(&m.pattern, q);
        in &= w >= 0 && w <= 1;
    }
    CHECK(in);

    /* Absurd cells (coordinates far beyond the integer clamp) still give finite media. */
    float tiny[] = {1e-30f, 1e-45f};
    nacre_pattern_type all[] = {NACRE_PATTERN_RANDOM_MIX, NACRE_PATTERN_CHECKER, NACRE_PATTERN_NOISE};
    bool finite = true;
    for (int t = 0; t < 3; t++)
        for (int k = 0; k < 2; k++) {
            nacre_material_desc b = two_media(all[t]);
            b.pattern.cell_size = tiny[k];
            b.pattern.octaves = 12;
            float q[6] = {3e38f, -3e38f, 1.0f, 0.5f, -1e-3f, 7.0f}, sa[6], ss[6];
            nc_medium_eval(scene, &b, q, 2, sa, ss);
            for (int i = 0; i < 6; i++)
                finite &= isfinite(sa[i]) && isfinite(ss[i]) && sa[i] >= 0 && ss[i] >= 0;
        }
    CHECK(finite);
}

/* Serial and threaded batches, single points and repeated calls all agree bit for bit. */
static void test_determinism(nacre_scene *scene)
{
    nacre_pattern_type types[] = {NACRE_PATTERN_RANDOM_MIX, NACRE_PATTERN_CHECKER, NACRE_PATTERN_NOISE};
    const size_t n = 70000;
    float *p = malloc(n * 3 * sizeof(float));
    float *a1 = malloc(n * 3 * sizeof(float)), *s1 = malloc(n * 3 * sizeof(float));
    float *a2 = malloc(n * 3 * sizeof(float)), *s2 = malloc(n * 3 * sizeof(float));
    for (size_t i = 0; i < 3 * n; i++)
        p[i] = (float)(urand() * 30 - 15);
    for (size_t t = 0; t < 3; t++) {
        nacre_material_desc m = two_media(types[t]);
        nc_medium_eval(scene, &m, p, n, a1, s1);
        nc_medium_eval(scene, &m, p, n, a2, s2);
        CHECK(memcmp(a1, a2, n * 3 * sizeof(float)) == 0 && memcmp(s1, s2, n * 3 * sizeof(float)) == 0);
        bool same = true;
        for (size_t i = 0; i < n; i += 97) {
            float a[3], s[3];
            nc_medium_eval(scene, &m, p + 3 * i, 1, a, s);
            same &= memcmp(a, a1 + 3 * i, sizeof(a)) == 0 && memcmp(s, s1 + 3 * i, sizeof(s)) == 0;
        }
        CHECK(same);
        /* Without a scene (serial path) too. */
        nc_medium_eval(NULL, &m, p, n, a2, s2);
        CHECK(memcmp(a1, a2, n * 3 * sizeof(float)) == 0 && memcmp(s1, s2, n * 3 * sizeof(float)) == 0);
    }
    free(p);
    free(a1);
    free(s1);
    free(a2);
    free(s2);
}

static float linear_field(const float q[3]) { return 1.0f + 0.5f * q[0] + 0.25f * q[1] + 2.0f * q[2]; }

/* Adds a volume sampling the linear field on a 5 x 4 x 6 grid. */
static nacre_volume add_linear_volume(nacre_scene *scene, nacre_volume_data *v)
{
    static float data[5 * 4 * 6];
    v->dims[0] = 5, v->dims[1] = 4, v->dims[2] = 6;
    v->origin[0] = 1.0f, v->origin[1] = 0.5f, v->origin[2] = 2.0f;
    v->spacing[0] = 0.5f, v->spacing[1] = 0.25f, v->spacing[2] = 1.0f;
    for (uint32_t z = 0; z < 6; z++)
        for (uint32_t y = 0; y < 4; y++)
            for (uint32_t x = 0; x < 5; x++) {
                float q[3] = {v->origin[0] + x * v->spacing[0], v->origin[1] + y * v->spacing[1],
                              v->origin[2] + z * v->spacing[2]};
                data[x + 5 * (y + 4 * z)] = linear_field(q);
            }
    v->data = data;
    nacre_volume h = {0};
    CHECK(nacre_scene_add_volume(scene, v, &h) == NACRE_OK);
    return h;
}

static void test_volume(nacre_scene *scene)
{
    nacre_volume_data v;
    memset(&v, 0, sizeof(v));
    uint64_t before = scene->versions.materials;
    nacre_volume h = add_linear_volume(scene, &v);
    CHECK(h.id >= 1);
    CHECK(scene->versions.materials > before);
    nacre_material_desc m;
    nacre_material_preset("skin1", &m);
    m.pattern.type = NACRE_PATTERN_VOLUME;
    m.pattern.volume = h;
    nacre_material mh;
    CHECK(nacre_scene_add_material(scene, &m, &mh) == NACRE_OK);
    float hi[3] = {v.origin[0] + 4 * v.spacing[0], v.origin[1] + 3 * v.spacing[1], v.origin[2] + 5 * v.spacing[2]};
    double worst = 0, worst_out = 0;
    for (int i = 0; i < 20000; i++) {
        float q[3], c[3];
        for (int k = 0; k < 3; k++) {
            /* Half the points inside, half up to one grid length outside (clamped). */
            double span = hi[k] - v.origin[k];
            q[k] = (float)(v.origin[k] + (i & 1 ? urand() : urand() * 3 - 1) * span);
            c[k] = fminf(fmaxf(q[k], v.origin[k]), hi[k]);
        }
        float d = nc_volume_density(nc_scene_volume(scene, h), q);
        double err = fabs(d - linear_field(c)) / linear_field(c);
        if (i & 1)
            worst = fmax(worst, err);
        else
            worst_out = fmax(worst_out, err);
        float sa[3], ss[3];
        nc_medium_eval(scene, &m, q, 1, sa, ss);
        for (int k = 0; k < 3; k++) {
            CHECK_NEAR(sa[k], d * m.sigma_a[k], 1e-6 * d * m.sigma_a[k]);
            CHECK_NEAR(ss[k], d * m.sigma_s[k], 1e-6 * d * m.sigma_s[k]);
        }
    }
    printf("volume: trilinear relative error on a linear field %.2e inside, %.2e clamped outside\n", worst,
           worst_out);
    /* A batch (8 points per vector step) equals the point-by-point lookup bit for bit, with
     * non-finite points (density 1) among finite ones. */
    enum { NB = 1003 };
    static float bp[3 * NB], ba[3 * NB], bs[3 * NB];
    for (int i = 0; i < NB; i++)
        for (int k = 0; k < 3; k++)
            bp[3 * i + k] = (float)(v.origin[k] + (urand() * 3 - 1) * (hi[k] - v.origin[k]));
    bp[3 * 5] = NAN, bp[3 * 17 + 1] = INFINITY, bp[3 * 900 + 2] = -INFINITY;
    nc_medium_eval(scene, &m, bp, NB, ba, bs);
    int same = 0;
    for (int i = 0; i < NB; i++) {
        const float *q = bp + 3 * i;
        float d = isfinite(q[0]) && isfinite(q[1]) && isfinite(q[2]) ? nc_volume_density(nc_scene_volume(scene, h), q)
                                                                      : 1.0f;
        bool ok = true;
        for (int k = 0; k < 3; k++)
            ok = ok && ba[3 * i + k] == d * m.sigma_a[k] && bs[3 * i + k] == d * m.sigma_s[k];
        same += ok;
    }
    printf("volume: batch of %d points equal to single lookups: %d\n", NB, same);
    CHECK(same == NB);
    CHECK(worst < 2e-6);
    CHECK(worst_out < 2e-6);
    /* Samples themselves are exact. */
    float q[3] = {v.origin[0] + 2 * v.spacing[0], v.origin[1] + v.spacing[1], v.origin[2] + 3 * v.spacing[2]};
    CHECK(nc_volume_density(nc_scene_volume(scene, h), q) == v.data[2 + 5 * (1 + 4 * 3)]);

    /* A 1 x 1 x 1 volume is a constant; a 2-sample axis interpolates linearly. */
    float one = 0.25f;
    nacre_volume_data c = {{1, 1, 1}, {0, 0, 0}, {1, 1, 1}, &one};
    nacre_volume hc;
    CHECK(nacre_scene_add_volume(scene, &c, &hc) == NACRE_OK);
    float far[3] = {100, -5, 3};
    CHECK(nc_volume_density(nc_scene_volume(scene, hc), far) == 0.25f);
    float two[2] = {0.0f, 2.0f};
    nacre_volume_data l = {{2, 1, 1}, {0, 0, 0}, {4, 1, 1}, two};
    nacre_volume hl;
    CHECK(nacre_scene_add_volume(scene, &l, &hl) == NACRE_OK);
    float mid[3] = {1.0f, 7, -7};
    CHECK_NEAR(nc_volume_density(nc_scene_volume(scene, hl), mid), 0.5, 1e-7);

    /* Validation. */
    nacre_volume bad;
    float neg[1] = {-1.0f};
    nacre_volume_data vn = {{1, 1, 1}, {0, 0, 0}, {1, 1, 1}, neg};
    CHECK(nacre_scene_add_volume(scene, &vn, &bad) == NACRE_ERROR_INVALID_ARGUMENT && bad.id == 0);
    CHECK(strstr(nacre_context_last_error(scene->ctx), "data[0]") != NULL);
    float nan1[1] = {NAN};
    vn.data = nan1;
    CHECK(nacre_scene_add_volume(scene, &vn, &bad) == NACRE_ERROR_INVALID_ARGUMENT);
    vn.data = &one;
    vn.spacing[1] = 0;
    CHECK(nacre_scene_add_volume(scene, &vn, &bad) == NACRE_ERROR_INVALID_ARGUMENT);
    vn.spacing[1] = 1;
    vn.dims[2] = 0;
    CHECK(nacre_scene_add_volume(scene, &vn, &bad) == NACRE_ERROR_INVALID_ARGUMENT);
    vn.dims[0] = vn.dims[1] = vn.dims[2] = 1u << 20; /* 2^60 samples: overflow guarded */
    CHECK(nacre_scene_add_volume(scene, &vn, &bad) == NACRE_ERROR_INVALID_ARGUMENT);
    vn.dims[0] = vn.dims[1] = vn.dims[2] = 1;
    vn.data = NULL;
    CHECK(nacre_scene_add_volume(scene, &vn, &bad) == NACRE_ERROR_INVALID_ARGUMENT);
}

/* The majorant bounds sigma_a + sigma_s (as a caller computes it, in float) at every point. */
static void test_majorants(nacre_scene *scene)
{
    nacre_volume_data v;
    memset(&v, 0, sizeof(v));
    nacre_volume h = add_linear_volume(scene, &v);
    nacre_pattern_type types[] = {NACRE_PATTERN_NONE, NACRE_PATTERN_RANDOM_MIX, NACRE_PATTERN_CHECKER,
                                  NACRE_PATTERN_NOISE, NACRE_PATTERN_VOLUME};
    const size_t n = 50000;
    float *p = malloc(n * 3 * sizeof(float)), *sa = malloc(n * 3 * sizeof(float)), *ss = malloc(n * 3 * sizeof(float));
    for (size_t i = 0; i < 3 * n; i++)
        p[i] = (float)(urand() * 12 - 3);
    p[0] = NAN;
    p[4] = INFINITY;
    for (int variant = 0; variant < 2; variant++)
        for (size_t t = 0; t < 5; t++) {
            nacre_material_desc m = two_media(types[t]);
            if (variant) {
                /* Medium 2 denser in some channels, lighter in others. */
                m.pattern.sigma_s2[0] = 9.0f;
                m.pattern.sigma_a2[2] = 1e-4f;
            }
            m.pattern.volume = h;
            float maj[3];
            nc_medium_max_sigma_t(scene, &m, maj);
            nc_medium_eval(scene, &m, p, n, sa, ss);
            bool ok = true;
            float top[3] = {0, 0, 0};
            for (size_t i = 0; i < n; i++)
                for (int c = 0; c < 3; c++) {
                    float st = sa[3 * i + c] + ss[3 * i + c];
                    ok &= st <= maj[c];
                    top[c] = fmaxf(top[c], st);
                }
            CHECK(ok);
            /* ... and is not loose for the discrete patterns (some sample reaches it). */
            if (types[t] == NACRE_PATTERN_RANDOM_MIX || types[t] == NACRE_PATTERN_CHECKER ||
                types[t] == NACRE_PATTERN_NONE)
                for (int c = 0; c < 3; c++)
                    CHECK(top[c] == maj[c]);
        }
    free(p);
    free(sa);
    free(ss);
}

/* Non-finite points get medium 1 in every pattern. */
static void test_nan_points(nacre_scene *scene)
{
    nacre_volume_data v;
    memset(&v, 0, sizeof(v));
    nacre_volume h = add_linear_volume(scene, &v);
    nacre_pattern_type types[] = {NACRE_PATTERN_RANDOM_MIX, NACRE_PATTERN_CHECKER, NACRE_PATTERN_NOISE,
                                  NACRE_PATTERN_VOLUME};
    float pts[4][3] = {{NAN, 0, 0}, {0, NAN, 1}, {1, 2, NAN}, {INFINITY, 0, -INFINITY}};
    for (size_t t = 0; t < 4; t++) {
        nacre_material_desc m = two_media(types[t]);
        m.pattern.fraction = 1.0f; /* random mix would otherwise be medium 2 everywhere */
        m.pattern.volume = h;
        float sa[12], ss[12];
        nc_medium_eval(scene, &m, &pts[0][0], 4, sa, ss);
        for (int i = 0; i < 4; i++)
            CHECK(is_medium(sa + 3 * i, ss + 3 * i, m.sigma_a, m.sigma_s));
    }
    nacre_material_desc m = two_media(NACRE_PATTERN_NONE);
    CHECK(!nc_medium_heterogeneous(&m));
    m.pattern.type = NACRE_PATTERN_CHECKER;
    CHECK(nc_medium_heterogeneous(&m));
}

static void test_validation(nacre_scene *scene)
{
    nacre_material h;
    nacre_material_desc m = two_media(NACRE_PATTERN_RANDOM_MIX);
    CHECK(nacre_scene_add_material(scene, &m, &h) == NACRE_OK);
    static const char *const fields[] = {"cell_size", "fraction", "octaves", "sigma_a2",
                                         "sigma_s2", "volume", "pattern.type"};
    for (size_t i = 0; i < sizeof(fields) / sizeof(fields[0]); i++) {
        nacre_material_desc b = two_media(NACRE_PATTERN_RANDOM_MIX);
        switch (i) {
        case 0: b.pattern.cell_size = 0; break;
        case 1: b.pattern.fraction = 1.5f; break;
        case 2: b.pattern.type = NACRE_PATTERN_NOISE; b.pattern.octaves = 13; break;
        case 3: b.pattern.sigma_a2[1] = NAN; break;
        case 4: b.pattern.sigma_s2[2] = -1; break;
        case 5: b.pattern.type = NACRE_PATTERN_VOLUME; b.pattern.volume.id = 999; break;
        case 6: b.pattern.type = (nacre_pattern_type)77; break;
        }
        CHECK(nacre_scene_add_material(scene, &b, &h) == NACRE_ERROR_INVALID_ARGUMENT);
        CHECK(strstr(nacre_context_last_error(scene->ctx), fields[i]) != NULL);
        CHECK(nacre_scene_set_material(scene, (nacre_material){1}, &b) == NACRE_ERROR_INVALID_ARGUMENT);
    }
    nacre_material_desc b = two_media(NACRE_PATTERN_CHECKER);
    b.pattern.cell_size = INFINITY;
    CHECK(nacre_scene_add_material(scene, &b, &h) == NACRE_ERROR_INVALID_ARGUMENT);
    b = two_media(NACRE_PATTERN_NOISE);
    b.pattern.octaves = 0;
    CHECK(nacre_scene_add_material(scene, &b, &h) == NACRE_ERROR_INVALID_ARGUMENT);
    b.pattern.octaves = 12;
    CHECK(nacre_scene_add_material(scene, &b, &h) == NACRE_OK);
    /* Opaque materials ignore the pattern. */
    b = nacre_material_desc_defaults(NACRE_MATERIAL_OPAQUE);
    b.pattern.type = NACRE_PATTERN_CHECKER;
    CHECK(nacre_scene_add_material(scene, &b, &h) == NACRE_OK);
}

/* About 2M points, as a 128^3 diffusion grid asks for (64^3 under the sanitizers, whose
 * instrumented stack arrays make the timing meaningless anyway). */
static void test_speed(nacre_scene *scene)
{
#if defined(__SANITIZE_ADDRESS__)
    const size_t n = (size_t)64 * 64 * 64;
#else
    const size_t n = (size_t)128 * 128 * 128;
#endif
    float *p = malloc(n * 3 * sizeof(float)), *sa = malloc(n * 3 * sizeof(float)), *ss = malloc(n * 3 * sizeof(float));
    for (size_t i = 0; i < 3 * n; i++)
        p[i] = (float)(urand() * 64);
    nacre_volume_data v;
    memset(&v, 0, sizeof(v));
    nacre_volume h = add_linear_volume(scene, &v);
    const char *names[] = {"random_mix", "checker", "noise(4)", "volume"};
    nacre_pattern_type types[] = {NACRE_PATTERN_RANDOM_MIX, NACRE_PATTERN_CHECKER, NACRE_PATTERN_NOISE,
                                  NACRE_PATTERN_VOLUME};
    for (int t = 0; t < 4; t++) {
        nacre_material_desc m = two_media(types[t]);
        m.pattern.volume = h;
        /* Best of 3: the machine is shared, and the first run also faults the pages in. */
        uint64_t us = UINT64_MAX;
        for (int rep = 0; rep < 3; rep++) {
            uint64_t t0 = nc_now_us();
            nc_medium_eval(scene, &m, p, n, sa, ss);
            uint64_t dt = nc_now_us() - t0;
            us = dt < us ? dt : us;
        }
        printf("speed: %-10s %zu points in %.2f ms (%d threads)\n", names[t], n, (double)us / 1000.0,
               nc_threads(scene->ctx));
        CHECK(us < 5000000); /* loose: sanitizer builds are several times slower */
    }
    free(p);
    free(sa);
    free(ss);
}

/* ------------------------------------------------------------------------------------------ */
/* NRRD                                                                                       */
/* ------------------------------------------------------------------------------------------ */

static void write_bytes(const char *path, const void *data, size_t size)
{
    FILE *f = fopen(path, "wb");
    CHECK(f != NULL);
    if (!f)
        return;
    CHECK(fwrite(data, 1, size, f) == size);
    fclose(f);
}

/* The voxelizer's export reads back: channel 0 = solid, 1 = surface, placement from the file. */
static void test_nrrd_voxel_roundtrip(nacre_context *ctx)
{
    nacre_shape_desc sd = nacre_shape_desc_defaults(NACRE_SHAPE_TORUS);
    nacre_mesh_data mesh = {0};
    CHECK(nacre_mesh_make_shape(ctx, &sd, &mesh) == NACRE_OK);
    nacre_voxel_settings vs = nacre_voxel_settings_defaults();
    vs.resolution = 20;
    vs.anisotropic = true;
    nacre_voxel_grid *grid = NULL;
    nacre_voxel_report rep;
    CHECK(nacre_voxelize(ctx, &mesh, &vs, &grid, &rep) == NACRE_OK);
    const char *path = TMP "/voxels.nrrd";
    CHECK(nacre_voxel_grid_write_nrrd(grid, 0, path) == NACRE_OK);
    for (uint32_t ch = 0; ch < 2; ch++) {
        nacre_volume_data v;
        CHECK(nacre_volume_load_nrrd(ctx, path, ch, &v) == NACRE_OK);
        CHECK(v.dims[0] == rep.dims[0] && v.dims[1] == rep.dims[1] && v.dims[2] == rep.dims[2]);
        for (int k = 0; k < 3; k++) {
            CHECK_NEAR(v.spacing[k], rep.voxel_size, 1e-6 * rep.voxel_size);
            CHECK_NEAR(v.origin[k], rep.origin[k] + 0.5f * rep.voxel_size, 1e-6); /* sample = voxel centre */
        }
        size_t mismatches = 0, ones = 0;
        for (uint32_t z = 0; z < v.dims[2]; z++)
            for (uint32_t y = 0; y < v.dims[1]; y++)
                for (uint32_t x = 0; x < v.dims[0]; x++) {
                    float d = v.data ? v.data[x + (size_t)v.dims[0] * (y + (size_t)v.dims[1] * z)] : -1;
                    bool set = nacre_voxel_grid_get(grid, ch == 0 ? NACRE_VOXEL_SOLID : NACRE_VOXEL_SURFACE, 0, x, y, z);
                    mismatches += d != (set ? 1.0f : 0.0f);
                    ones += d == 1.0f;
                }
        CHECK(mismatches == 0);
        CHECK(ones == nacre_voxel_grid_count(grid, ch == 0 ? NACRE_VOXEL_SOLID : NACRE_VOXEL_SURFACE, 0));
        nacre_volume_data_free(ctx, &v);
        CHECK(v.data == NULL);
    }
    nacre_volume_data v;
    CHECK(nacre_volume_load_nrrd(ctx, path, 2, &v) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "channel 2") != NULL);
    CHECK(v.data == NULL);
    nacre_voxel_grid_destroy(grid);
    nacre_mesh_data_free(ctx, &mesh);
}

/* Our own writer: every supported type, both byte orders, 3D and 4D, directions or spacings. */
static size_t put_sample(uint8_t *dst, const char *type, bool big, double v)
{
    uint8_t b[8];
    size_t n;
    if (strcmp(type, "uint8") == 0) { uint8_t x = (uint8_t)v; memcpy(b, &x, n = 1); }
    else if (strcmp(type, "int8") == 0) { int8_t x = (int8_t)v; memcpy(b, &x, n = 1); }
    else if (strcmp(type, "uint16") == 0) { uint16_t x = (uint16_t)v; memcpy(b, &x, n = 2); }
    else if (strcmp(type, "short") == 0) { int16_t x = (int16_t)v; memcpy(b, &x, n = 2); }
    else if (strcmp(type, "uint32") == 0) { uint32_t x = (uint32_t)v; memcpy(b, &x, n = 4); }
    else if (strcmp(type, "int") == 0) { int32_t x = (int32_t)v; memcpy(b, &x, n = 4); }
    else if (strcmp(type, "float") == 0) { float x = (float)v; memcpy(b, &x, n = 4); }
    else { memcpy(b, &v, n = 8); }
    for (size_t i = 0; i < n; i++)
        dst[i] = big ? b[n - 1 - i] : b[i]; /* the test host is little endian (x86-64) */
    return n;
}

static void test_nrrd_writer_roundtrip(nacre_context *ctx)
{
    const char *types[] = {"uint8", "int8", "uint16", "short", "uint32", "int", "float", "double"};
    const uint32_t nx = 7, ny = 3, nz = 5;
    int cases = 0;
    for (size_t t = 0; t < 8; t++)
        for (int big = 0; big < 2; big++)
            for (int four = 0; four < 2; four++) {
                uint32_t channels = four ? 3 : 1, pick = four ? 1 : 0;
                char head[512];
                int hl;
                if (four)
                    hl = snprintf(head, sizeof(head),
                                  "NRRD0005\n# written by test_medium\ntype: %s\ndimension: 4\nsizes: %u %u %u %u\n"
                                  "encoding: raw\nendian: %s\nspace: right-anterior-superior\n"
                                  "space directions: none (0.5,0,0) (0,2,0) (0,0,0.25)\n"
                                  "space origin: (-1.5,2,3.25)\nkinds: vector domain domain domain\n"
                                  "labels: \"c\" \"x\" \"y\" \"z\"\nkey:=value\n\n",
                                  types[t], channels, nx, ny, nz, big ? "big" : "little");
                else
                    hl = snprintf(head, sizeof(head),
                                  "NRRD0004\r\ntype: %s\r\ndimension: 3\r\nsizes: %u %u %u\r\n"
                                  "encoding: raw\r\nendian: %s\r\nspacings: 0.5 2 0.25\r\n\r\n",
                                  types[t], nx, ny, nz, big ? "big" : "little");
                size_t n = (size_t)nx * ny * nz;
                uint8_t *buf = malloc((size_t)hl + n * channels * 8);
                memcpy(buf, head, (size_t)hl);
                size_t pos = (size_t)hl;
                for (size_t i = 0; i < n; i++)
                    for (uint32_t c = 0; c < channels; c++)
                        pos += put_sample(buf + pos, types[t], big, (double)((i * 7 + c * 3) % 100));
                char path[256];
                snprintf(path, sizeof(path), TMP "/rt_%s_%d_%d.nrrd", types[t], big, four);
                write_bytes(path, buf, pos);
                free(buf);
                nacre_volume_data v;
                nacre_result r = nacre_volume_load_nrrd(ctx, path, pick, &v);
                CHECK(r == NACRE_OK);
                if (r != NACRE_OK) {
                    printf("  %s: %s\n", path, nacre_context_last_error(ctx));
                    continue;
                }
                CHECK(v.dims[0] == nx && v.dims[1] == ny && v.dims[2] == nz);
                CHECK(v.spacing[0] == 0.5f && v.spacing[1] == 2.0f && v.spacing[2] == 0.25f);
                if (four)
                    CHECK(v.origin[0] == -1.5f && v.origin[1] == 2.0f && v.origin[2] == 3.25f);
                else
                    CHECK(v.origin[0] == 0 && v.origin[1] == 0 && v.origin[2] == 0);
                bool same = true;
                for (size_t i = 0; i < n; i++)
                    same &= v.data[i] == (float)((i * 7 + pick * 3) % 100);
                CHECK(same);
                nacre_volume_data_free(ctx, &v);
                cases++;
            }
    printf("nrrd: %d written files read back exactly\n", cases);

    /* byte skip -1 (data at the end) and line skip. */
    const char *skip = "NRRD0001\ntype: uchar\ndimension: 3\nsizes: 2 1 1\nencoding: raw\nline skip: 1\n"
                       "byte skip: 2\n\nignored line\nxx\x03\x04";
    nacre_volume_data v;
    CHECK(nc_nrrd_parse(ctx, "skip", (const uint8_t *)skip, strlen(skip), 0, &v) == NACRE_OK);
    CHECK(v.data && v.data[0] == 3.0f && v.data[1] == 4.0f);
    nacre_volume_data_free(ctx, &v);
    const char *tail = "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 2\nencoding: raw\nbyte skip: -1\n\nabc\x05\x06";
    CHECK(nc_nrrd_parse(ctx, "tail", (const uint8_t *)tail, strlen(tail), 0, &v) == NACRE_OK);
    CHECK(v.data && v.data[0] == 5.0f && v.data[1] == 6.0f);
    nacre_volume_data_free(ctx, &v);
}

static void test_nrrd_malformed(nacre_context *ctx)
{
    /* Literal with its exact length: some hold NUL bytes in their data. */
#define LIT(s) s, sizeof(s) - 1
    static const struct {
        const char *text;
        size_t len;
        const char *expect; /* substring of the message */
    } cases[] = {
        {LIT(""), "empty"},
        {LIT("PNG\n"), "magic"},
        {LIT("NRRD0009\n\n"), "magic"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n"), "no blank line"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\n\x01\x02"), "truncated"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: -2 2 2\nencoding: raw\n\n"), "line 4: sizes"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 0 2 2\nencoding: raw\n\n"), "line 4: sizes"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 99999999999999999999 2 2\nencoding: raw\n\n"), "sizes"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2147483648 2147483648 2\nencoding: raw\n\n"), "2^31"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 2\nencoding: raw\n\n"), "line 4: sizes"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 2 2 2\nencoding: raw\n\n"), "line 4: sizes"},
        {LIT("NRRD0004\ntype: uint8\nsizes: 2 2 2\ndimension: 3\nencoding: raw\n\n"), "after 'dimension'"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 2\n"), "line 3: dimension"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: gzip\n\n"), "line 5: encoding"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: ascii\n\n1"), "encoding"},
        {LIT("NRRD0004\ntype: int64\ndimension: 3\n"), "line 2: type"},
        {LIT("NRRD0004\ntype: block\n"), "type"},
        {LIT("NRRD0004\ntype: float\ndimension: 3\nsizes: 1 1 1\nencoding: raw\n\n\0\0\0\0"), "endian"},
        {LIT("NRRD0004\ntype: float\ndimension: 3\nsizes: 1 1 1\nencoding: raw\nendian: middle\n"), "line 6: endian"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: raw\ndata file: x.raw\n\n"), "detached"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: raw\nfrobnicate: 3\n\n\x01"), "unknown field"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: raw\nspace directions: (1,0,0) (0,1,0) (0,0,1)\n\n\x01"),
         "space dimension"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: raw\nspace dimension: 3\n"
         "space directions: (1,0,0) (0,1,0)\n\n\x01"), "line 7: space directions"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: raw\nspace dimension: 3\n"
         "space directions: (1,1,0) (0,1,0) (0,0,1)\n\n\x01"), "not aligned"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: raw\nspace dimension: 3\n"
         "space directions: (-1,0,0) (0,1,0) (0,0,1)\n\n\x01"), "spacing must be"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: raw\nspace dimension: 3\n"
         "space directions: (1,0,0) (0,nan,0) (0,0,1)\n\n\x01"), "line 7: space directions"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: raw\nspace dimension: 3\n"
         "space origin: (1,2)\n\n\x01"), "line 7: space origin"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: raw\nspacings: 1 0 1\n\n\x01"), "spacings"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: raw\nspacings: 1 nan 1\n\n\x01"), "spacings"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 4\nsizes: 2 1 1 1\nencoding: raw\nspace dimension: 3\n"
         "space directions: (1,0,0) (1,0,0) (0,1,0) (0,0,1)\n\n\x01\x01"), "channel axis"},
        {LIT("NRRD0004\ntype: int8\ndimension: 3\nsizes: 1 1 1\nencoding: raw\n\n\xff"), "sample 0"},
        {LIT("NRRD0004\ntype: float\ndimension: 3\nsizes: 1 1 1\nencoding: raw\nendian: little\n\n\x00\x00\xc0\x7f"),
         "sample 0"},
        {LIT("NRRD0004\ntype: uint8\ntype: uint8\n"), "line 3: type: given twice"},
        {LIT("NRRD0004\ntype\n"), "line 2"},
        {LIT("NRRD0004\ntype:\n"), "line 2"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: raw\nbyte skip: 100\n\n\x01"), "byte skip"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: raw\nbyte skip: -2\n\n\x01"), "byte skip"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: raw\nline skip: 5\n\n\x01"), "line skip"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 1 1 1\nencoding: raw\nspace dimension: 2\n\n\x01"), "line 6"},
        {LIT("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 2 2\n\n"), "encoding: missing"},
        {LIT("NRRD0004\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\n"), "type: missing"},
    };
    int passed = 0;
    for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
        size_t len = cases[i].len;
        nacre_volume_data v;
        memset(&v, 0xab, sizeof(v));
        nacre_result r = nc_nrrd_parse(ctx, "case.nrrd", (const uint8_t *)cases[i].text, len, 0, &v);
        const char *msg = nacre_context_last_error(ctx);
        bool ok = r != NACRE_OK && v.data == NULL && strncmp(msg, "case.nrrd: ", 11) == 0 &&
                  strstr(msg, cases[i].expect) != NULL && !strchr(msg, '\n');
        if (!ok)
            printf("  malformed case %zu: result %d, message \"%s\" (expected \"%s\")\n", i, (int)r, msg,
                   cases[i].expect);
        CHECK(ok);
        passed += ok;
    }
    printf("nrrd: %d of %zu malformed headers rejected with the expected message\n", passed,
           sizeof(cases) / sizeof(cases[0]));

    /* NUL bytes inside the header, and a missing file. */
    const char nul[] = "NRRD0004\ntype: ui\0nt8\n\n";
    nacre_volume_data v;
    CHECK(nc_nrrd_parse(ctx, "nul", (const uint8_t *)nul, sizeof(nul) - 1, 0, &v) == NACRE_ERROR_PARSE);
    CHECK(strstr(nacre_context_last_error(ctx), "NUL") != NULL);
    CHECK(nacre_volume_load_nrrd(ctx, TMP "/missing.nrrd", 0, &v) == NACRE_ERROR_IO);
    CHECK(strstr(nacre_context_last_error(ctx), "missing.nrrd") != NULL);
    /* Every truncation of a valid file fails cleanly or (past the header) succeeds. */
    const char good[] = "NRRD0004\ntype: uint16\ndimension: 3\nsizes: 2 1 1\nencoding: raw\nendian: big\n"
                        "space dimension: 3\nspace origin: (1,2,3)\nspace directions: (1,0,0) (0,1,0) (0,0,1)\n\n"
                        "\x01\x02\x03\x04";
    size_t full = sizeof(good) - 1;
    int ok_count = 0;
    for (size_t cut = 0; cut <= full; cut++) {
        nacre_result r = nc_nrrd_parse(ctx, "cut", (const uint8_t *)good, cut, 0, &v);
        if (r == NACRE_OK) {
            ok_count++;
            CHECK(v.data[0] == 258.0f && v.data[1] == 772.0f);
            nacre_volume_data_free(ctx, &v);
        }
    }
    CHECK(ok_count == 1);
}

/* The Jensen et al. 2001 presets carry that paper's figure 5 values (sigma_s' and sigma_a in
 * mm^-1, R G B) and eta 1.3; with g = 0 the preset's sigma_s is sigma_s'. */
static void test_presets(void)
{
    static const struct {
        const char *name;
        float sps[3], sa[3];
    } jensen[] = {
        {"apple", {2.29f, 2.39f, 1.97f}, {0.0030f, 0.0034f, 0.046f}},
        {"chicken1", {0.15f, 0.21f, 0.38f}, {0.015f, 0.077f, 0.19f}},
        {"chicken2", {0.19f, 0.25f, 0.32f}, {0.018f, 0.088f, 0.20f}},
        {"cream", {7.38f, 5.47f, 3.15f}, {0.0002f, 0.0028f, 0.0163f}},
        {"ketchup", {0.18f, 0.07f, 0.03f}, {0.061f, 0.97f, 1.45f}},
        {"marble", {2.19f, 2.62f, 3.00f}, {0.0021f, 0.0041f, 0.0071f}},
        {"potato", {0.68f, 0.70f, 0.55f}, {0.0024f, 0.0090f, 0.12f}},
        {"skimmilk", {0.70f, 1.22f, 1.90f}, {0.0014f, 0.0025f, 0.0142f}},
        {"skin1", {0.74f, 0.88f, 1.01f}, {0.032f, 0.17f, 0.48f}},
        {"skin2", {1.09f, 1.59f, 1.79f}, {0.013f, 0.070f, 0.145f}},
        {"wholemilk", {2.55f, 3.21f, 3.77f}, {0.0011f, 0.0024f, 0.014f}},
        {"chicken", {0.15f, 0.21f, 0.38f}, {0.015f, 0.077f, 0.19f}},
    };
    for (size_t i = 0; i < sizeof(jensen) / sizeof(jensen[0]); i++) {
        nacre_material_desc m;
        CHECK(nacre_material_preset(jensen[i].name, &m));
        CHECK(m.type == NACRE_MATERIAL_TRANSLUCENT && m.g == 0.0f && m.eta == 1.3f);
        CHECK(m.pattern.type == NACRE_PATTERN_NONE);
        for (int c = 0; c < 3; c++)
            CHECK(m.sigma_s[c] == jensen[i].sps[c] && m.sigma_a[c] == jensen[i].sa[c]);
    }
}

int main(void)
{
    mkdir(NACRE_TEST_TMP, 0777);
    mkdir(TMP, 0777);
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(NULL, &ctx) == NACRE_OK);
    nacre_scene *scene = NULL;
    CHECK(nacre_scene_create(ctx, &scene) == NACRE_OK);

    test_presets();
    test_random_mix(scene);
    test_checker(scene);
    test_noise(scene);
    test_determinism(scene);
    test_volume(scene);
    test_majorants(scene);
    test_nan_points(scene);
    test_validation(scene);
    test_speed(scene);
    test_nrrd_voxel_roundtrip(ctx);
    test_nrrd_writer_roundtrip(ctx);
    test_nrrd_malformed(ctx);

    nacre_scene_destroy(scene);
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
