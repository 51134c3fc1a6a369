/*
 * test_pathtrace_slab.c: the Monte Carlo slab (nacre_slab_measure, method PATHTRACE) against
 * exact results: adding-doubling values for semi-infinite slabs (van de Hulst 1980 tables, as
 * quoted in issue 5), the single-scattering integral evaluated by quadrature here, Beer-Lambert
 * for a pure absorber, and energy conservation without absorption. Tolerance: 3 standard errors
 * plus 0.5% relative, as the issue asks.
 */
#include "test_util.h"

#include <nacre/nacre.h>

static nacre_context *ctx;

static nacre_slab_result measure(double albedo, double tau, double g, double eta, uint64_t samples,
                                 uint32_t max_scatter)
{
    nacre_slab_desc d = nacre_slab_desc_defaults();
    d.method = NACRE_METHOD_PATHTRACE;
    d.albedo = albedo;
    d.tau = tau;
    d.g = g;
    d.eta = eta;
    d.samples = samples;
    d.max_scatter = max_scatter;
    d.seed = 7;
    nacre_slab_result r;
    memset(&r, 0, sizeof(r));
    nacre_result res = nacre_slab_measure(ctx, &d, &r);
    CHECK(res == NACRE_OK);
    if (res != NACRE_OK)
        printf("  %s\n", nacre_context_last_error(ctx));
    printf("  a=%.3g tau=%.3g g=%.2g eta=%.3g K=%u: R=%.5f +- %.5f  T=%.5f +- %.5f  (%.0f ms)\n", albedo, tau,
           g, eta, max_scatter, r.R, r.R_stderr, r.T, r.T_stderr, r.ms);
    return r;
}

#define CHECK_STAT(value, stderr_, expected)                                                   \
    CHECK_NEAR(value, expected, 3.0 * (stderr_) + 0.005 * fabs(expected))

/* Exact single scattering for an index-matched slab lit at normal incidence, by Simpson's rule
 * over the exit cosine m (the depth integral is done in closed form):
 *   R1 = a int_0^1 2 pi p(-m) m / (1 + m) (1 - exp(-tau (1 + m) / m)) dm
 *   T1 = a int_0^1 2 pi p(m) m (exp(-tau) - exp(-tau / m)) / (1 - m) dm    (tau e^-tau at m = 1)
 * where p is Henyey-Greenstein of the angle to the incident direction. */
static void single_scatter(double a, double tau, double g, double *r1, double *t1)
{
    const int n = 20000;
    double sr = 0, st = 0;
    for (int i = 0; i <= n; i++) {
        double m = (double)i / n;
        double w = (i == 0 || i == n) ? 1.0 : (i & 1) ? 4.0 : 2.0;
        double pr = 0, pt = 0;
        if (m > 0) {
            double two_pi = 6.283185307179586;
            double hg_back = two_pi * (1 - g * g) / (4 * 3.141592653589793 * pow(1 + g * g + 2 * g * m, 1.5));
            double hg_fwd = two_pi * (1 - g * g) / (4 * 3.141592653589793 * pow(1 + g * g - 2 * g * m, 1.5));
            pr = hg_back * m / (1 + m) * (isinf(tau) ? 1.0 : 1 - exp(-tau * (1 + m) / m));
            double k = fabs(1 - m) < 1e-9 ? tau * exp(-tau) : m * (exp(-tau) - exp(-tau / m)) / (1 - m);
            pt = isinf(tau) ? 0.0 : hg_fwd * k;
        }
        sr += w * pr;
        st += w * pt;
    }
    *r1 = a * sr / (3.0 * n);
    *t1 = a * st / (3.0 * n);
}

int main(void)
{
    nacre_context_desc cd = {0};
    cd.threads = 2;
    CHECK(nacre_context_create(&cd, &ctx) == NACRE_OK);
    CHECK(nacre_method_available(NACRE_METHOD_PATHTRACE) || true);

    /* Adding-doubling, semi-infinite, g = 0, R without the specular reflection. */
    nacre_slab_result r = measure(0.99, INFINITY, 0.0, 1.0, 60000, 0);
    CHECK_STAT(r.R, r.R_stderr, 0.7527);
    CHECK_NEAR(r.T, 0.0, 0.0);
    r = measure(0.9, INFINITY, 0.0, 1.0, 100000, 0);
    CHECK_STAT(r.R, r.R_stderr, 0.4149);
    r = measure(0.9, INFINITY, 0.0, 1.33, 100000, 0);
    CHECK_STAT(r.R, r.R_stderr, 0.2747);
    CHECK_NEAR(r.R_specular, 0.0201, 5e-5);

    /* Single scattering, index matched: isotropic and forward-peaked, thin and thick. */
    const double cases[][3] = {{0.8, 1.0, 0.0}, {0.9, 0.3, 0.7}, {0.95, 2.5, -0.4}, {0.9, INFINITY, 0.0}};
    for (int i = 0; i < 4; i++) {
        double a = cases[i][0], tau = cases[i][1], g = cases[i][2], r1, t1;
        single_scatter(a, tau, g, &r1, &t1);
        r = measure(a, tau, g, 1.0, 100000, 1);
        printf("    exact: R1=%.5f T=%.5f\n", r1, exp(-tau) + t1);
        CHECK_STAT(r.R, r.R_stderr, r1);
        CHECK_STAT(r.T, r.T_stderr, exp(-tau) + t1);
    }

    /* Pure absorber: Beer-Lambert, exactly (the ballistic part is analytic). */
    r = measure(0.0, 1.7, 0.0, 1.0, 1000, 0);
    CHECK_NEAR(r.T, exp(-1.7), 1e-12);
    CHECK_NEAR(r.R, 0.0, 0.0);
    CHECK_NEAR(r.T_stderr, 0.0, 0.0);
    /* With a boundary, the ballistic zig-zag between the faces is still closed form. */
    r = measure(0.0, 0.5, 0.0, 1.5, 1000, 0);
    {
        double f = 0.04, e = exp(-0.5);
        CHECK_NEAR(r.T, (1 - f) * (1 - f) * e / (1 - f * f * e * e), 1e-12);
    }

    /* Oblique incidence. Semi-infinite, isotropic, single scattering, index matched, light at mu0
     * to the normal (unit power per unit area of the face): collisions at depth z have density
     * e^(-z/mu0)/mu0 and escape upwards at cosine m with e^(-z/m), so
     *   R1 = (a/2) int_0^1 m / (m + mu0) dm = (a/2) (1 - mu0 ln((1 + mu0) / mu0)). */
    for (int i = 0; i < 2; i++) {
        double deg = i ? 75.0 : 50.0, mu0 = cos(deg * 3.141592653589793 / 180.0), a = 0.9;
        nacre_slab_desc d = nacre_slab_desc_defaults();
        d.method = NACRE_METHOD_PATHTRACE;
        d.albedo = a;
        d.incidence = deg;
        d.samples = 100000;
        d.max_scatter = 1;
        d.seed = 3;
        nacre_slab_result o;
        CHECK(nacre_slab_measure(ctx, &d, &o) == NACRE_OK);
        double r1 = 0.5 * a * (1.0 - mu0 * log((1.0 + mu0) / mu0));
        printf("  oblique %.0f deg, single scattering: R=%.5f +- %.5f, exact %.5f\n", deg, o.R, o.R_stderr, r1);
        CHECK_STAT(o.R, o.R_stderr, r1);
        /* Diffusion (volume source along the refracted ray) within 3% of the full transport there
         * (measured at albedo 0.9: +2.1% at 50 degrees, +0.3% at 75). */
        d.max_scatter = 0;
        nacre_slab_result pt, df;
        CHECK(nacre_slab_measure(ctx, &d, &pt) == NACRE_OK);
        d.method = NACRE_METHOD_DIFFUSION;
        CHECK(nacre_slab_measure(ctx, &d, &df) == NACRE_OK);
        printf("  oblique %.0f deg: path tracer R=%.5f +- %.5f, diffusion R=%.5f\n", deg, pt.R, pt.R_stderr, df.R);
        CHECK_NEAR(df.R, pt.R, 0.03 * pt.R);
    }
    /* A pure absorber with boundaries lit at 50 degrees: the ballistic zig-zag at the refracted
     * cosine, Fresnel at the incidence angle, in closed form. */
    {
        nacre_slab_desc d = nacre_slab_desc_defaults();
        d.method = NACRE_METHOD_PATHTRACE;
        d.albedo = 0.0;
        d.tau = 0.5;
        d.eta = 1.5;
        d.incidence = 50.0;
        d.samples = 1000;
        nacre_slab_result o;
        CHECK(nacre_slab_measure(ctx, &d, &o) == NACRE_OK);
        double ci = cos(50.0 * 3.141592653589793 / 180.0), si = sqrt(1 - ci * ci);
        double ct = sqrt(1 - si * si / 2.25);
        double rs = (ci - 1.5 * ct) / (ci + 1.5 * ct), rp = (1.5 * ci - ct) / (1.5 * ci + ct);
        double f = 0.5 * (rs * rs + rp * rp), e = exp(-0.5 / ct);
        CHECK_NEAR(o.R_specular, f, 1e-12);
        CHECK_NEAR(o.T, (1 - f) * (1 - f) * e / (1 - f * f * e * e), 1e-12);
        d.incidence = 90.0;
        CHECK(nacre_slab_measure(ctx, &d, &o) == NACRE_ERROR_INVALID_ARGUMENT);
    }

    /* No absorption: everything entering leaves (R + T = 1 - R_specular). */
    r = measure(1.0, 2.0, 0.0, 1.0, 40000, 0);
    CHECK_NEAR(r.R + r.T, 1.0, 1e-9);
    r = measure(1.0, 1.0, 0.6, 1.4, 40000, 0);
    CHECK_NEAR(r.R + r.T + r.R_specular, 1.0, 1e-9);

    /* Same seed, same numbers, whatever the thread count. */
    {
        nacre_context *c1 = NULL;
        nacre_context_desc d1 = {0};
        d1.threads = 1;
        CHECK(nacre_context_create(&d1, &c1) == NACRE_OK);
        nacre_slab_desc d = nacre_slab_desc_defaults();
        d.method = NACRE_METHOD_PATHTRACE;
        d.albedo = 0.95;
        d.samples = 20000;
        nacre_slab_result a, b;
        CHECK(nacre_slab_measure(c1, &d, &a) == NACRE_OK);
        CHECK(nacre_slab_measure(ctx, &d, &b) == NACRE_OK);
        CHECK(a.R == b.R && a.T == b.T && a.R_stderr == b.R_stderr);
        nacre_context_destroy(c1);
    }

    /* Bad descs fail cleanly. */
    {
        nacre_slab_desc d = nacre_slab_desc_defaults();
        d.method = NACRE_METHOD_PATHTRACE;
        nacre_slab_result o;
        d.albedo = 1.5;
        CHECK(nacre_slab_measure(ctx, &d, &o) == NACRE_ERROR_INVALID_ARGUMENT);
        d.albedo = 0.5;
        d.g = 1.0;
        CHECK(nacre_slab_measure(ctx, &d, &o) == NACRE_ERROR_INVALID_ARGUMENT);
        d.g = 0;
        d.eta = NAN;
        CHECK(nacre_slab_measure(ctx, &d, &o) == NACRE_ERROR_INVALID_ARGUMENT);
        d.eta = 1;
        d.tau = -1;
        CHECK(nacre_slab_measure(ctx, &d, &o) == NACRE_ERROR_INVALID_ARGUMENT);
        d.tau = 1;
        d.samples = 0;
        CHECK(nacre_slab_measure(ctx, &d, &o) == NACRE_ERROR_INVALID_ARGUMENT);
        /* eta beyond [NACRE_ETA_MIN, NACRE_ETA_MAX]: exact Fresnel, so the path tracer takes it;
         * the diffusion boundary's fit breaks there (issue 29 item 6) and refuses it. */
        d.samples = 2000;
        d.eta = 5;
        CHECK(nacre_slab_measure(ctx, &d, &o) == NACRE_OK && isfinite(o.R) && isfinite(o.T));
        d.method = NACRE_METHOD_DIFFUSION;
        CHECK(nacre_slab_measure(ctx, &d, &o) == NACRE_ERROR_INVALID_ARGUMENT);
        CHECK(strstr(nacre_context_last_error(ctx), "eta must be in [0.3, 3] for diffusion (got 5)") != NULL);
        d.eta = 3;
        CHECK(nacre_slab_measure(ctx, &d, &o) == NACRE_OK && isfinite(o.R) && isfinite(o.T));
    }

    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
