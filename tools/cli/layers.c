/*
 * layers.c: `nacre layers`, a procedural depth map for layered materials
 * (nacre_layer_map_generate) written as a data PNG (values * 255, no sRGB curve) or a linear
 * EXR, to use as a material's "depth_map" or to edit in a paint program.
 */
#include "cli.h"

#include <stdio.h>
#include <string.h>

static const char layers_help[] =
    "usage: nacre layers --kind veins|spots|constant [--size N] [--seed S] -o MAP.png\n"
    "Write a procedural depth map for layered materials (RGBA; channel j scales layer j's depth):\n"
    "  constant  every channel 1 (layers of constant thickness)\n"
    "  veins     R 1, G branching veins of tapering width, B and A 1\n"
    "  spots     R 1, G round spots of random size, B and A 1\n"
    "  --size N  pixels per side, 8..8192 (default 512)\n"
    "  --seed S  0..4294967295 (default 1): the same seed gives the same map\n"
    "  -o FILE   .png (8-bit data, read back as values / 255) or .exr (linear float)\n"
    "  --help, --version\n";

int nc_cli_layers(int argc, char **argv)
{
    int code;
    const char *out = NULL, *kind_name = NULL;
    long size = 512, seed = 1;
    nacre_layer_map_kind kind = NACRE_LAYER_MAP_VEINS;
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        if (nc_tool_common_flag("layers", a, layers_help, &code))
            return code;
        bool has_value = i + 1 < argc;
        if (strcmp(a, "--kind") == 0) {
            if (!has_value || !nacre_layer_map_kind_from_name(argv[i + 1], &kind))
                return nc_tool_usage("layers", "--kind needs veins, spots or constant");
            kind_name = argv[++i];
        } else if (strcmp(a, "--size") == 0) {
            if (!has_value || !nc_tool_parse_int(argv[++i], 8, 8192, &size))
                return nc_tool_usage("layers", "--size needs an integer in 8..8192");
        } else if (strcmp(a, "--seed") == 0) {
            if (!has_value || !nc_tool_parse_int(argv[++i], 0, 4294967295L, &seed))
                return nc_tool_usage("layers", "--seed needs an integer in 0..4294967295");
        } else if (strcmp(a, "-o") == 0 || strcmp(a, "--output") == 0) {
            if (!has_value)
                return nc_tool_usage("layers", "-o needs a file name");
            out = argv[++i];
        } else {
            return nc_tool_usage("layers", "unknown option '%s'", a);
        }
    }
    if (!kind_name)
        return nc_tool_usage("layers", "missing --kind");
    if (!out)
        return nc_tool_usage("layers", "missing -o FILE");
    nacre_context *ctx = nc_tool_context(0);
    if (!ctx)
        return 1;
    nacre_image img = {0};
    int rc = 0;
    if (nacre_layer_map_generate(ctx, kind, (int32_t)size, (uint32_t)seed, &img) != NACRE_OK ||
        nacre_image_write_data(ctx, &img, out) != NACRE_OK)
        rc = nc_tool_fail(ctx);
    nacre_image_free(ctx, &img);
    nacre_context_destroy(ctx);
    return rc;
}
