/*
 * common.c: what the `nacre` command and the benchmarks share: one-line errors on stderr (exit
 * status 2), argument parsing, the context every command makes (threads, --memory-limit, library
 * warnings printed), timing, medians and where the benchmark meshes are.
 */
#include "common.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

int nc_tool_error(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fputs("nacre: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
    va_end(ap);
    return NC_TOOL_EXIT_BAD;
}

int nc_tool_fail(nacre_context *ctx) { return nc_tool_error("%s", nacre_context_last_error(ctx)); }

int nc_tool_usage(const char *command, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "nacre %s: ", command);
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, " (see nacre %s --help)\n", command);
    va_end(ap);
    return NC_TOOL_EXIT_BAD;
}

bool nc_tool_parse_int(const char *s, long lo, long hi, long *out)
{
    char *end = NULL;
    errno = 0;
    long v = strtol(s, &end, 10);
    if (errno || end == s || *end != '\0' || v < lo || v > hi)
        return false;
    *out = v;
    return true;
}

bool nc_tool_parse_float(const char *s, double *out)
{
    char *end = NULL;
    errno = 0;
    double v = strtod(s, &end);
    if (errno || end == s || *end != '\0' || !isfinite(v))
        return false;
    *out = v;
    return true;
}

bool nc_tool_common_flag(const char *command, const char *arg, const char *help, int *exit_code)
{
    if (strcmp(arg, "--help") == 0 || strcmp(arg, "-h") == 0) {
        fputs(help, stdout);
        *exit_code = 0;
        return true;
    }
    if (strcmp(arg, "--version") == 0) {
        printf("nacre %s %s\n", command, nacre_version());
        *exit_code = 0;
        return true;
    }
    return false;
}


/* --memory-limit, set by main() before the command runs; 0 = the library's default. With the
 * warning hint below, the only state the commands share, set before any of them starts. */
static uint64_t cli_memory_limit;

/* "4G", "512M", "1.5g", "300k" or a plain byte count; false if malformed or 0. */
bool nc_tool_parse_bytes(const char *s, uint64_t *out)
{
    char *end = NULL;
    errno = 0;
    double v = strtod(s, &end);
    if (end == s || errno || !(v > 0))
        return false;
    double scale = 1;
    switch (*end) {
    case 'k': case 'K': scale = 1024.0; end++; break;
    case 'm': case 'M': scale = 1048576.0; end++; break;
    case 'g': case 'G': scale = 1073741824.0; end++; break;
    case 't': case 'T': scale = 1099511627776.0; end++; break;
    default: break;
    }
    if (*end == 'i' || *end == 'I')
        end++;
    if (*end == 'b' || *end == 'B')
        end++;
    if (*end != '\0' || !(v * scale >= 1) || !(v * scale < 1.8e19))
        return false;
    *out = (uint64_t)(v * scale);
    return true;
}

/* Library warnings (a half EXR's clamped values) are printed; errors are printed by the command
 * from nacre_context_last_error instead, once. */
static const char *cli_warning_hint = ""; /* what the command suggests after a warning */

void nc_tool_set_memory_limit(uint64_t bytes) { cli_memory_limit = bytes; }

void nc_tool_set_warning_hint(const char *hint) { cli_warning_hint = hint ? hint : ""; }

static void cli_log(void *user, nacre_log_level level, const char *message)
{
    (void)user;
    if (level == NACRE_LOG_WARNING)
        fprintf(stderr, "nacre: warning: %s%s\n", message, cli_warning_hint);
}

nacre_context *nc_tool_context(int threads)
{
    nacre_context_desc desc = {0};
    desc.threads = threads;
    desc.memory_limit = cli_memory_limit;
    desc.log_fn = cli_log;
    nacre_context *ctx = NULL;
    if (nacre_context_create(&desc, &ctx) != NACRE_OK) {
        nc_tool_error("cannot create a context (out of memory?)");
        return NULL;
    }
    return ctx;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

double nc_tool_median(double *v, int n)
{
    if (n <= 0)
        return 0;
    qsort(v, (size_t)n, sizeof(double), cmp_double);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

bool nc_tool_find_mesh(const char *file, char *path, size_t size)
{
    const char *dirs[3] = {getenv("NACRE_MESH_DIR"), "../shared/meshes", "/work/shared/meshes"};
    for (int d = 0; d < 3; d++) {
        if (!dirs[d] || !dirs[d][0])
            continue;
        snprintf(path, size, "%s/%s", dirs[d], file);
        FILE *f = fopen(path, "rb");
        if (f) {
            fclose(f);
            return true;
        }
    }
    return false;
}
