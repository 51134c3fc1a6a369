/*
 * common.h: helpers shared by the `nacre` command (tools/cli) and the benchmarks (bench/):
 * errors, argument parsing, the context, timing, medians, benchmark meshes. Neither of those two
 * calls into the other except through bench/bench.h, the benchmarks' entry points.
 */
#ifndef NACRE_TOOL_COMMON_H
#define NACRE_TOOL_COMMON_H

#include <nacre/nacre.h>

#include <stdarg.h>
#include <stdbool.h>
#include <stdint.h>
#include <time.h>

#define NC_TOOL_EXIT_BAD 2

/* Print "nacre: <message>" and return 2. */
int nc_tool_error(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
/* Print "nacre: <last error of ctx>" and return 2. */
int nc_tool_fail(nacre_context *ctx);
/* Print "nacre CMD: <message> (see nacre CMD --help)" and return 2. */
int nc_tool_usage(const char *command, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
bool nc_tool_parse_int(const char *s, long lo, long hi, long *out);
bool nc_tool_parse_float(const char *s, double *out);
/* "4G", "512M", "1.5g", "300k" or a plain byte count; false if malformed or 0. */
bool nc_tool_parse_bytes(const char *s, uint64_t *out);
/* Handles --help / --version for a subcommand; true if handled (exit with *exit_code). */
bool nc_tool_common_flag(const char *command, const char *arg, const char *help, int *exit_code);
/* The memory limit of the contexts made from now on (0: the library's default). */
void nc_tool_set_memory_limit(uint64_t bytes);
/* Text printed after each library warning (e.g. " (--exr-float)"); NULL or "" for none. */
void nc_tool_set_warning_hint(const char *hint);
/* A context with `threads` threads (0 = all) that prints library warnings; prints an error and
 * returns NULL on failure. */
nacre_context *nc_tool_context(int threads);

static inline uint64_t nc_tool_now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000u + (uint64_t)ts.tv_nsec / 1000u;
}

/* Path of a benchmark mesh: the first of $NACRE_MESH_DIR, ../shared/meshes and
 * /work/shared/meshes that holds `file`, written to path; false if none does. */
bool nc_tool_find_mesh(const char *file, char *path, size_t size);
/* Median of n values (sorts in place). */
double nc_tool_median(double *values, int n);

#endif /* NACRE_TOOL_COMMON_H */
