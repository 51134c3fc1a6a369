/*
 * cli.h: helpers shared by the `nacre` subcommands and benchmarks (argument parsing, error
 * printing, timing). Exit status 2 for every error.
 */
#ifndef NACRE_CLI_H
#define NACRE_CLI_H

#include <nacre/nacre.h>

#include <stdarg.h>
#include <stdbool.h>
#include <stdint.h>
#include <time.h>

/* Print "nacre: <last error of ctx>" and return 2. */
int nc_cli_fail(nacre_context *ctx);
/* Print "nacre CMD: <message> (see nacre CMD --help)" and return 2. */
int nc_cli_usage(const char *command, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
bool nc_cli_parse_int(const char *s, long lo, long hi, long *out);
bool nc_cli_parse_float(const char *s, double *out);
/* Handles --help / --version for a subcommand; true if handled (exit with *exit_code). */
bool nc_cli_common_flag(const char *command, const char *arg, const char *help, int *exit_code);
/* A context with `threads` threads (0 = all); prints an error and returns NULL on failure. */
nacre_context *nc_cli_context(int threads);

static inline uint64_t nc_cli_now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000u + (uint64_t)ts.tv_nsec / 1000u;
}

/* Path of a benchmark mesh: the first of $NACRE_MESH_DIR, ../shared/meshes and
 * /work/shared/meshes that holds `file`, written to path; false if none does. */
bool nc_cli_find_mesh(const char *file, char *path, size_t size);
/* Median of n values (sorts in place). */
double nc_cli_median(double *values, int n);

/* `nacre slab ...` (tools/cli/slab.c). */
int nc_cli_slab(int argc, char **argv);
/* `nacre bench ...` (tools/cli/bench.c). */
int nc_cli_bench(int argc, char **argv);
/* `nacre bench diffusion`, solver part (bench/bench_diffusion_solver.c). */
int nc_bench_diffusion_solver(bool json, int runs);
/* Optional row filter of `nacre bench voxelize|diffusion`: mesh file names containing `only`
 * (NULL: all) and one resolution (0: all). */
typedef struct nc_bench_filter {
    const char *only;
    uint32_t res;
} nc_bench_filter;
bool nc_bench_filter_mesh(const nc_bench_filter *f, const char *file);
/* `nacre bench diffusion`, pipeline part (bench/bench_diffusion.c); repaint: every frame
 * writes every pixel (no reuse_output). */
int nc_bench_diffusion_pipeline(bool json, int runs, const nc_bench_filter *filter, bool repaint);
/* `nacre bench raster` part for lucy_1600k (bench/bench_raster.c). */
int nc_bench_raster(int argc, char **argv);

#endif /* NACRE_CLI_H */
