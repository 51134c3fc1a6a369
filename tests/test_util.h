/*
 * test_util.h: the tiny assert helper every unit test shares. Header-only; each test executable
 * keeps its counters in one static struct.
 *
 *     CHECK(cond)            counts a pass, or prints "file:line: CHECK(cond) failed" and goes on
 *     CHECK_NEAR(a, b, tol)  |a - b| <= tol as doubles (NaN fails), printing both values
 *     return TEST_MAIN_END(); prints "N passed, M failed" on its own line; nonzero if any failed
 *     test_error_names(ctx, s) the context's last error is one line that contains s
 *
 * TEST_MAIN_END() also exits with status 1 itself when a check failed, so a bare
 * `TEST_MAIN_END();` at the end of main cannot turn a failure into exit status 0.
 */
#ifndef NACRE_TEST_UTIL_H
#define NACRE_TEST_UTIL_H

/* What almost every test needs, so a test can start with this header alone. */
#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <nacre/core.h>

static struct test_util_state {
    int passed;
    int failed;
} test_util_state_ __attribute__((unused));

static inline void test_util_check_(int ok, const char *file, int line, const char *expr)
{
    if (ok) {
        test_util_state_.passed++;
        return;
    }
    test_util_state_.failed++;
    printf("%s:%d: CHECK(%s) failed\n", file, line, expr);
    fflush(stdout);
}

static inline void test_util_check_near_(double a, double b, double tol, const char *file,
                                         int line, const char *ea, const char *eb)
{
    /* Written as !(x <= tol) so that a NaN anywhere fails. */
    if (!(fabs(a - b) <= tol)) {
        test_util_state_.failed++;
        printf("%s:%d: CHECK_NEAR(%s, %s) failed: %.9g vs %.9g (diff %.3g > tol %.3g)\n", file,
               line, ea, eb, a, b, fabs(a - b), tol);
        fflush(stdout);
        return;
    }
    test_util_state_.passed++;
}

/* Whether ctx's last error is one line naming `needle` (printed when it is not). */
static inline bool test_error_names(nacre_context *ctx, const char *needle)
{
    const char *msg = nacre_context_last_error(ctx);
    bool ok = msg && strstr(msg, needle) && !strchr(msg, '\n');
    if (!ok)
        printf("expected a one-line error naming %s, got: %s\n", needle, msg ? msg : "(none)");
    return ok;
}

static inline int test_util_end_(void)
{
    printf("%d passed, %d failed\n", test_util_state_.passed, test_util_state_.failed);
    fflush(stdout);
    if (test_util_state_.failed)
        exit(1);
    return 0;
}

#define CHECK(cond) test_util_check_((cond) ? 1 : 0, __FILE__, __LINE__, #cond)
#define CHECK_NEAR(a, b, tol)                                                                  \
    test_util_check_near_((double)(a), (double)(b), (double)(tol), __FILE__, __LINE__, #a, #b)
#define TEST_MAIN_END() test_util_end_()

#endif /* NACRE_TEST_UTIL_H */
