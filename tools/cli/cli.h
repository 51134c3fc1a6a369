/*
 * cli.h: the `nacre` command's subcommands that live outside main.c. Shared helpers are in
 * tools/common/common.h, the benchmarks' entry points in bench/bench.h.
 */
#ifndef NACRE_CLI_H
#define NACRE_CLI_H

#include "common.h"

/* `nacre slab ...` (tools/cli/slab.c). */
int nc_cli_slab(int argc, char **argv);
/* `nacre bench ...` (tools/cli/bench.c): argument parsing, then bench/. */
int nc_cli_bench(int argc, char **argv);
/* `nacre view ...` (tools/view/view_main.c; tools/view/view_stub.c in a build without SDL2). */
int nc_cli_view(int argc, char **argv);
/* `nacre layers ...` (tools/cli/layers.c): procedural depth maps. */
int nc_cli_layers(int argc, char **argv);

#endif /* NACRE_CLI_H */
