/*
 * main.c: the `nacre` command-line tool. Subcommands: render, info, compare, voxelize, bench,
 * and view (the interactive viewer, tools/view/).
 *
 * Exit status: 0 on success, 2 on any error (bad arguments, bad input files, failed writes).
 * Errors are one line on stderr: "nacre: <message>". The library returns errors; the tools
 * print them (tools/common/common.c).
 */
#define _XOPEN_SOURCE 700 /* realpath (XSI); the build asks for POSIX 2008 only */
#include "cli.h"

#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "demo_scene.h"

#define EXIT_BAD NC_TOOL_EXIT_BAD

static void print_main_help(FILE *f)
{
    fprintf(f,
            "usage: nacre <command> [options]\n"
            "\n"
            "commands:\n"
            "  render [SCENE.json]   render a scene (no scene: the built-in demo) to PNG or EXR\n"
            "  info FILE             mesh counts, bounds, open and non-manifold edges; a glTF's\n"
            "                        meshes, materials and extensions (--json)\n"
            "  compare A B           error metrics of image A against reference B\n"
            "  voxelize MESH         surface and solid voxelization, NRRD export\n"
            "  slab                  reflectance and transmittance of a slab (diffusion, pathtrace)\n"
            "  bench NAME            benchmarks (medians): raster, voxelize, diffusion, pathtrace, load,\n"
            "                        layered, particles, volumetrics\n"
            "  view [SCENE.json]     interactive viewer: edit lights, materials, method; headless runs\n"
            "  layers --kind K -o F  procedural depth map for layered materials (veins, spots, constant)\n"
            "\n"
            "  nacre <command> --help   options of a command\n"
            "  nacre --version          version\n"
            "\n"
            "every command:\n"
            "  --memory-limit SIZE      most memory nacre may hold (4G, 512M, bytes; default half of\n"
            "                           physical memory, less under ulimit -v); over it: exit 2\n");
}


/* `path` made absolute without resolving its last component (which may not exist yet): the
 * real path of its folder, then the name. Lexical (as given) when the folder does not resolve. */
static void normalized_path(const char *path, char *out, size_t size)
{
    const char *slash = strrchr(path, '/');
    const char *base = slash ? slash + 1 : path;
    char dir[PATH_MAX], real[PATH_MAX];
    size_t n = slash ? (size_t)(slash - path) : 0;
    if (slash && n == 0)
        n = 1; /* "/name": the root */
    if (n >= sizeof(dir))
        n = sizeof(dir) - 1;
    memcpy(dir, slash ? path : ".", slash ? n : 1);
    dir[slash ? n : 1] = '\0';
    if (strcmp(base, ".") != 0 && strcmp(base, "..") != 0 && base[0] && realpath(dir, real))
        snprintf(out, size, "%s%s%s", real, strcmp(real, "/") == 0 ? "" : "/", base);
    else
        snprintf(out, size, "%s", path);
}

/* Whether two paths name the same file: device and inode when both exist, the normalized paths
 * when neither does (an output that does not exist yet cannot be an existing input). */
static bool same_file(const char *a, const char *b)
{
    struct stat sa, sb;
    bool ea = stat(a, &sa) == 0, eb = stat(b, &sb) == 0;
    if (ea && eb)
        return sa.st_dev == sb.st_dev && sa.st_ino == sb.st_ino;
    if (ea != eb)
        return false;
    char na[PATH_MAX + 256], nb[PATH_MAX + 256];
    normalized_path(a, na, sizeof(na));
    normalized_path(b, nb, sizeof(nb));
    return strcmp(na, nb) == 0;
}

/* Refuse to write an output over one of the run's inputs or over another of its outputs: false
 * (after one line on stderr) if `out` names the same file as `other`. */
static bool output_distinct(const char *command, const char *out, const char *out_what, const char *other,
                            const char *other_what)
{
    if (!out || !other || !same_file(out, other))
        return true;
    fprintf(stderr, "nacre %s: %s '%s' is the same file as the %s '%s': refusing to overwrite it\n", command, out_what,
            out, other_what, other);
    return false;
}

/* ---------------------------------------------------------------------------------------- */
/* render                                                                                   */
/* ---------------------------------------------------------------------------------------- */

static const char render_help[] =
    "usage: nacre render [SCENE.json | MODEL.gltf | MODEL.glb] [options]\n"
    "Render a scene file or a glTF 2.0 scene (default: the built-in demo scene) to an image.\n"
    "\n"
    "  -o, --output FILE   output .png (sRGB, exposure-scaled) or .exr (linear); default nacre.png\n"
    "  --method M          phong | diffusion | layered | pathtrace (default: the scene's, else phong)\n"
    "  --size WxH          image size (default: the scene's)\n"
    "  --exposure EV       PNG exposure in stops (default: the scene's, else 0)\n"
    "  --time T            time in seconds at which deformers and particles are evaluated (default:\n"
    "                      the scene's, else 0)\n"
    "  --threads N         worker threads (default: all cores)\n"
    "  --memory-limit SIZE most memory nacre may hold (4G, 512M; default half of RAM)\n"
    "  --exr-float         write 32-bit float EXR instead of half (half holds up to 65504: larger\n"
    "                      values are written as 65504, with a warning giving their count)\n"
    "  --stats             print one JSON object with per-stage timings in microseconds\n"
    "  --camera NAME       glTF: render from the camera of this name (camera or node; default:\n"
    "                      the first); glTF is in metres, lights in lux and candela (683 lm/W)\n"
    "  --thickness-layer   glTF: a translucent material's thickness texture becomes a one-layer\n"
    "                      depth map (docs/scene-format.md; default: the medium fills the mesh)\n"
    "  --save-scene FILE   also write the scene as a .json scene file, with this run's settings\n"
    "                      (size, method, time, ...) in its render block, before rendering;\n"
    "                      `nacre render FILE` then renders the same image\n"
    "  --particles P       phong, diffusion: billboards (default: volumetric billboards) | sprites\n"
    "                      (sorted alpha-blended) | voxel (the density grid, through the fog pass);\n"
    "                      the path tracer always renders the density grid\n"
    "diffusion:\n"
    "  --voxel-res N       voxels along each translucent object's longest axis (default 32)\n"
    "  --tsm-size N        translucent shadow map texels per side (default 512)\n"
    "  --solver S          multigrid (default: PCG to --tolerance) | seed (Jacobi cascade)\n"
    "  --source S          volume (default) | face (the seed's face injection)\n"
    "  --single-scattering on|off|auto  diffusion: march light scattered once per pixel, diffuse the\n"
    "                      rest (auto, the default: on for patterned media)\n"
    "  --tolerance T       relative residual for multigrid (default 1e-4)\n"
    "  --seed-iterations N Jacobi sweeps for the seed solver (default: the seed's table 5.6)\n"
    "pathtrace:\n"
    "  --spp N             samples per pixel (default: the scene's, else 64)\n"
    "  --seed N            random seed (same seed, same image)\n"
    "  --time-limit S      end the command after about S seconds (loading included): passes stop\n"
    "                      mid-way, each pixel keeps the samples it completed (see README);\n"
    "                      paths end at 65536 vertices or 2^20 collisions (paths_capped in --stats)\n"
    "  --max-scatter K     scattering events per path in media (K = 1: single scattering)\n"
    "  --variance FILE     also write the per-pixel variance of the estimate (.exr)\n"
    "layered (seed 001, single scattering in layered materials):\n"
    "  --samples N         steps along each refracted view ray, 1..4096 (default 16)\n"
    "  --integration I     analytic (default: steps cut at layer boundaries, each piece in\n"
    "                      closed form) | samples (the seed: one point sample per step)\n"
    "  --epsilon E         negligible attenuation in (0, 1) (default 0.01): radius of the fitted\n"
    "                      planes, -log(E) / sigma_t, and the depth where marching stops\n"
    "  --half-res T        march every other pixel in x and y, and interpolate the others where\n"
    "                      their marched neighbours agree within relative tolerance T in (0, 1)\n"
    "                      (default 0.05; 0 marches every pixel; docs/performance.md: the error)\n"
    "fog over phong and diffusion (docs/scene-format.md, \"Volumetrics\"):\n"
    "  --volumetrics V     off (default: analytic fog, directional lights and ambient, unshadowed)\n"
    "                      | froxel (frustum grid: every fog and light, shadow maps, the fog's own\n"
    "                      shadows) | raymarch (the same lighting marched per pixel; slow, a check)\n"
    "  --froxel-grid WxHxD froxel columns, rows and depth slices (default 160x90x64, each 1..1024)\n"
    "  --raymarch-steps N  steps per pixel ray for raymarch (default 64)\n"
    "  --shadow-steps N    steps towards each light through patterned fog (default 8)\n"
    "  --help, --version\n";

static void print_stats(const char *scene_name, const nacre_render_settings *rs, const nacre_render_stats *st,
                        uint64_t load_us, uint64_t commit_us, uint64_t write_us, uint64_t total_us,
                        uint64_t memory_peak)
{
    printf("{\"scene\":\"");
    for (const char *c = scene_name; *c; c++) {
        if (*c == '"' || *c == '\\')
            putchar('\\');
        if ((unsigned char)*c >= 0x20)
            putchar(*c);
    }
    printf("\",\"method\":\"%s\",\"width\":%d,\"height\":%d,\"threads\":%d,\"load_us\":%llu,\"commit_us\":%llu",
           nacre_method_name(rs->method), rs->width, rs->height, st->threads, (unsigned long long)load_us,
           (unsigned long long)commit_us);
    nacre_method_info info;
    nacre_method_info_get(rs->method, &info);
    for (int i = 0; i < NACRE_STAGE_COUNT; i++)
        printf(",\"%s_us\":%llu", nacre_stage_name((nacre_stage)i), (unsigned long long)st->stage_us[i]);
    /* Which stages ran, and how often (maps drawn, objects voxelized): the rest were cached. */
    printf(",\"stage_runs\":{");
    for (int i = 0, n = 0; i < NACRE_STAGE_COUNT; i++)
        if (st->stage_runs[i])
            printf("%s\"%s\":%u", n++ ? "," : "", nacre_stage_name((nacre_stage)i), st->stage_runs[i]);
    printf("}");
    printf(",\"render_us\":%llu,\"write_us\":%llu,\"total_us\":%llu,\"triangles\":%llu,\"triangles_drawn\":%llu,"
           "\"shadow_maps\":%u",
           (unsigned long long)st->total_us, (unsigned long long)write_us, (unsigned long long)total_us,
           (unsigned long long)st->triangles, (unsigned long long)st->triangles_drawn, st->shadow_maps);
    if (info.stages & (1u << NACRE_STAGE_PROPAGATE))
        printf(",\"solver\":\"%s\",\"iterations\":%u,\"residual\":%.3g,\"voxel_dims\":[%u,%u,%u]",
               nacre_solver_name(st->solver), st->iterations, st->residual,
               st->voxel_dims[0], st->voxel_dims[1], st->voxel_dims[2]);
    if (info.stochastic)
        printf(",\"spp\":%u,\"samples\":%llu,\"samples_per_second\":%.6g,\"paths_capped\":%llu,"
               "\"pixels_unsampled\":%u",
               st->spp_done, (unsigned long long)st->samples_done, st->samples_per_second,
               (unsigned long long)st->paths_capped, st->pixels_unsampled);
    printf(",\"memory_peak_bytes\":%llu}\n", (unsigned long long)memory_peak);
}

static bool has_suffix(const char *s, const char *suffix)
{
    size_t n = strlen(s), m = strlen(suffix);
    if (n < m)
        return false;
    for (size_t i = 0; i < m; i++)
        if ((s[n - m + i] | 0x20) != (suffix[i] | 0x20))
            return false;
    return true;
}

/* A rendered image with NaN or infinite values is the method's failure: say so (one line naming
 * the method and the first pixel) instead of writing it. */
static bool image_finite(const nacre_image *img, const nacre_render_settings *rs, const char *what)
{
    int32_t fx = 0, fy = 0;
    unsigned long long bad = nacre_image_count_nonfinite(img, &fx, &fy, NULL);
    if (bad == 0)
        return true;
    nc_tool_error("render: method '%s' produced %llu pixel%s with NaN or infinite values in its %s (first at x %d, y %d); "
                  "nothing written",
                  nacre_method_name(rs->method), bad, bad == 1 ? "" : "s", what, (int)fx, (int)fy);
    return false;
}

static int cmd_render(int argc, char **argv)
{
    const char *scene_path = NULL, *out_path = "nacre.png", *method_name = NULL, *variance_path = NULL,
               *save_path = NULL;
    const char *solver_name = NULL, *source_name = NULL, *camera_name = NULL, *particles_name = NULL;
    bool thickness_layer = false;
    nacre_particles_draw particles_draw = NACRE_PARTICLES_DRAW_BILLBOARDS;
    nacre_diffusion_solver solver = NACRE_SOLVER_MULTIGRID;
    nacre_diffusion_source source = NACRE_SOURCE_VOLUME;
    long width = 0, height = 0, threads = 0, voxel_res = -1, tsm_size = -1, seed_iters = -1, spp = -1, seed = -1,
         max_scatter = -1, layered_samples = -1, froxel[3] = {-1, -1, -1}, raymarch_steps = -1, shadow_steps = -1;
    double exposure = NAN, time = NAN, tolerance = NAN, time_limit = NAN, layered_epsilon = NAN, layered_half_res = NAN;
    const char *integration_name = NULL, *volumetrics_name = NULL;
    nacre_layered_integration integration = NACRE_LAYERED_ANALYTIC;
    nacre_volumetrics_mode volumetrics = NACRE_VOLUMETRICS_OFF;
    bool stats = false, exr_float = false;
    int single_scattering = -1;
    int code;
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        if (nc_tool_common_flag("render", a, render_help, &code))
            return code;
        bool has_value = i + 1 < argc;
        if ((strcmp(a, "-o") == 0 || strcmp(a, "--output") == 0)) {
            if (!has_value)
                return nc_tool_usage("render", "%s needs a file name", a);
            out_path = argv[++i];
        } else if (strcmp(a, "--method") == 0) {
            if (!has_value)
                return nc_tool_usage("render", "--method needs a name");
            method_name = argv[++i];
        } else if (strcmp(a, "--size") == 0) {
            if (!has_value)
                return nc_tool_usage("render", "--size needs WxH");
            const char *v = argv[++i];
            char wbuf[32];
            const char *x = strchr(v, 'x');
            if (!x || (size_t)(x - v) >= sizeof(wbuf))
                return nc_tool_usage("render", "--size '%s': expected WxH, e.g. 640x480", v);
            memcpy(wbuf, v, (size_t)(x - v));
            wbuf[x - v] = '\0';
            if (!nc_tool_parse_int(wbuf, 1, 16384, &width) || !nc_tool_parse_int(x + 1, 1, 16384, &height))
                return nc_tool_usage("render", "--size '%s': width and height must be integers in 1..16384", v);
        } else if (strcmp(a, "--exposure") == 0) {
            if (!has_value || !nc_tool_parse_float(argv[++i], &exposure))
                return nc_tool_usage("render", "--exposure needs a finite number");
        } else if (strcmp(a, "--time") == 0) {
            if (!has_value || !nc_tool_parse_float(argv[++i], &time))
                return nc_tool_usage("render", "--time needs a finite number of seconds");
        } else if (strcmp(a, "--threads") == 0) {
            if (!has_value || !nc_tool_parse_int(argv[++i], 1, 1024, &threads))
                return nc_tool_usage("render", "--threads needs an integer in 1..1024");
        } else if (strcmp(a, "--voxel-res") == 0) {
            if (!has_value || !nc_tool_parse_int(argv[++i], 1, 1024, &voxel_res))
                return nc_tool_usage("render", "--voxel-res needs an integer in 1..1024");
        } else if (strcmp(a, "--tsm-size") == 0) {
            if (!has_value || !nc_tool_parse_int(argv[++i], 16, 8192, &tsm_size))
                return nc_tool_usage("render", "--tsm-size needs an integer in 16..8192");
        } else if (strcmp(a, "--solver") == 0) {
            if (!has_value)
                return nc_tool_usage("render", "--solver needs multigrid or seed");
            solver_name = argv[++i];
            if (!nacre_solver_from_name(solver_name, &solver))
                return nc_tool_usage("render", "--solver '%s': expected multigrid or seed", solver_name);
        } else if (strcmp(a, "--particles") == 0) {
            if (!has_value)
                return nc_tool_usage("render", "--particles needs billboards, sprites or voxel");
            particles_name = argv[++i];
            if (!nacre_particles_draw_from_name(particles_name, &particles_draw))
                return nc_tool_usage("render", "--particles '%s': expected billboards, sprites or voxel", particles_name);
        } else if (strcmp(a, "--single-scattering") == 0) {
            nacre_single_scattering mode;
            if (!has_value || !nacre_single_scattering_from_name(argv[i + 1], &mode))
                return nc_tool_usage("render", "--single-scattering needs on, off or auto");
            single_scattering = (int)mode;
            i++;
        } else if (strcmp(a, "--source") == 0) {
            if (!has_value)
                return nc_tool_usage("render", "--source needs volume or face");
            source_name = argv[++i];
            if (!nacre_source_from_name(source_name, &source))
                return nc_tool_usage("render", "--source '%s': expected volume or face", source_name);
        } else if (strcmp(a, "--tolerance") == 0) {
            if (!has_value || !nc_tool_parse_float(argv[++i], &tolerance) || !(tolerance > 0 && tolerance < 1))
                return nc_tool_usage("render", "--tolerance needs a number in (0, 1)");
        } else if (strcmp(a, "--seed-iterations") == 0) {
            if (!has_value || !nc_tool_parse_int(argv[++i], 1, 100000, &seed_iters))
                return nc_tool_usage("render", "--seed-iterations needs an integer in 1..100000");
        } else if (strcmp(a, "--spp") == 0) {
            if (!has_value || !nc_tool_parse_int(argv[++i], 1, 1 << 24, &spp))
                return nc_tool_usage("render", "--spp needs an integer in 1..16777216");
        } else if (strcmp(a, "--seed") == 0) {
            if (!has_value || !nc_tool_parse_int(argv[++i], 0, 4294967295L, &seed))
                return nc_tool_usage("render", "--seed needs an integer in 0..4294967295");
        } else if (strcmp(a, "--time-limit") == 0) {
            if (!has_value || !nc_tool_parse_float(argv[++i], &time_limit) || !(time_limit > 0))
                return nc_tool_usage("render", "--time-limit needs a positive number of seconds");
        } else if (strcmp(a, "--max-scatter") == 0) {
            if (!has_value || !nc_tool_parse_int(argv[++i], 1, 1000000, &max_scatter))
                return nc_tool_usage("render", "--max-scatter needs an integer in 1..1000000");
        } else if (strcmp(a, "--samples") == 0) {
            if (!has_value || !nc_tool_parse_int(argv[++i], 1, 4096, &layered_samples))
                return nc_tool_usage("render", "--samples needs an integer in 1..4096");
        } else if (strcmp(a, "--epsilon") == 0) {
            if (!has_value || !nc_tool_parse_float(argv[++i], &layered_epsilon) ||
                !(layered_epsilon > 0 && layered_epsilon < 1))
                return nc_tool_usage("render", "--epsilon needs a number in (0, 1)");
        } else if (strcmp(a, "--half-res") == 0) {
            if (!has_value || !nc_tool_parse_float(argv[++i], &layered_half_res) ||
                !(layered_half_res >= 0 && layered_half_res < 1))
                return nc_tool_usage("render", "--half-res needs a number in [0, 1)");
        } else if (strcmp(a, "--integration") == 0) {
            if (!has_value || !nacre_layered_integration_from_name(argv[i + 1], &integration))
                return nc_tool_usage("render", "--integration needs analytic or samples");
            integration_name = argv[++i];
        } else if (strcmp(a, "--volumetrics") == 0) {
            if (!has_value)
                return nc_tool_usage("render", "--volumetrics needs off, froxel or raymarch");
            volumetrics_name = argv[++i];
            if (!nacre_volumetrics_from_name(volumetrics_name, &volumetrics))
                return nc_tool_usage("render", "--volumetrics '%s': expected off, froxel or raymarch", volumetrics_name);
        } else if (strcmp(a, "--froxel-grid") == 0) {
            if (!has_value)
                return nc_tool_usage("render", "--froxel-grid needs WxHxD");
            const char *v = argv[++i];
            char buf[3][32];
            const char *p = v;
            for (int k = 0; k < 3; k++) {
                const char *x = k < 2 ? strchr(p, 'x') : p + strlen(p);
                if (!x || (size_t)(x - p) >= sizeof(buf[k]))
                    return nc_tool_usage("render", "--froxel-grid '%s': expected WxHxD, e.g. 160x90x64", v);
                memcpy(buf[k], p, (size_t)(x - p));
                buf[k][x - p] = '\0';
                if (!nc_tool_parse_int(buf[k], 1, 1024, &froxel[k]))
                    return nc_tool_usage("render", "--froxel-grid '%s': each of W, H, D must be an integer in 1..1024", v);
                p = x + 1;
            }
        } else if (strcmp(a, "--raymarch-steps") == 0) {
            if (!has_value || !nc_tool_parse_int(argv[++i], 1, 4096, &raymarch_steps))
                return nc_tool_usage("render", "--raymarch-steps needs an integer in 1..4096");
        } else if (strcmp(a, "--shadow-steps") == 0) {
            if (!has_value || !nc_tool_parse_int(argv[++i], 1, 256, &shadow_steps))
                return nc_tool_usage("render", "--shadow-steps needs an integer in 1..256");
        } else if (strcmp(a, "--variance") == 0) {
            if (!has_value)
                return nc_tool_usage("render", "--variance needs a file name");
            variance_path = argv[++i];
            if (!has_suffix(variance_path, ".exr"))
                return nc_tool_usage("render", "--variance '%s': use a .exr file name", variance_path);
        } else if (strcmp(a, "--save-scene") == 0) {
            if (!has_value)
                return nc_tool_usage("render", "--save-scene needs a file name");
            save_path = argv[++i];
            if (!has_suffix(save_path, ".json"))
                return nc_tool_usage("render", "--save-scene '%s': use a .json file name", save_path);
        } else if (strcmp(a, "--stats") == 0) {
            stats = true;
        } else if (strcmp(a, "--camera") == 0) {
            if (!has_value)
                return nc_tool_usage("render", "--camera needs a camera name");
            camera_name = argv[++i];
        } else if (strcmp(a, "--thickness-layer") == 0) {
            thickness_layer = true;
        } else if (strcmp(a, "--exr-float") == 0) {
            exr_float = true;
        } else if (a[0] == '-' && a[1] != '\0') {
            return nc_tool_usage("render", "unknown option '%s'", a);
        } else if (!scene_path) {
            scene_path = a;
        } else {
            return nc_tool_usage("render", "unexpected argument '%s'", a);
        }
    }
    if (!has_suffix(out_path, ".png") && !has_suffix(out_path, ".exr"))
        return nc_tool_usage("render", "output '%s': use a .png or .exr file name", out_path);
    if (!output_distinct("render", out_path, "output", scene_path, "scene") ||
        !output_distinct("render", variance_path, "variance output", scene_path, "scene") ||
        !output_distinct("render", variance_path, "variance output", out_path, "output") ||
        !output_distinct("render", save_path, "saved scene", scene_path, "scene") ||
        !output_distinct("render", save_path, "saved scene", out_path, "output") ||
        !output_distinct("render", save_path, "saved scene", variance_path, "variance output"))
        return EXIT_BAD;
    nacre_method method = NACRE_METHOD_PHONG;
    if (method_name && !nacre_method_from_name(method_name, &method))
        return nc_tool_usage("render", "unknown method '%s' (phong, diffusion, layered, pathtrace)", method_name);
    const bool gltf = scene_path && (has_suffix(scene_path, ".gltf") || has_suffix(scene_path, ".glb"));
    if (camera_name && !gltf)
        return nc_tool_usage("render", "--camera needs a .gltf or .glb scene");
    if (thickness_layer && !gltf)
        return nc_tool_usage("render", "--thickness-layer needs a .gltf or .glb scene (a scene file says "
                                       "\"import\": {\"file\": ..., \"thickness\": \"layer\"})");

    nacre_context *ctx = nc_tool_context((int)threads);
    if (!ctx)
        return EXIT_BAD;
    int rc = EXIT_BAD;
    nacre_scene *scene = NULL;
    nacre_renderer *renderer = NULL;
    nacre_image img = {0};
    nacre_scene_file_settings fs = {.render = nacre_render_settings_defaults()};
    nacre_render_settings rs;
    nacre_method_info info;
    uint64_t t_start = nc_tool_now_us();
    nacre_result res;
    if (gltf)
        res = nacre_scene_load_gltf(ctx, scene_path, &(nacre_gltf_options){.camera = camera_name, .thickness_layer = thickness_layer}, &scene, &fs,
                                    NULL);
    else if (scene_path)
        res = nacre_scene_load_file(ctx, scene_path, &scene, &fs);
    else
        res = nacre_scene_load_json(ctx, (const char *)nacre_demo_scene_json, strlen((const char *)nacre_demo_scene_json),
                                    "<built-in demo>", ".", &scene, &fs);
    if (res != NACRE_OK) {
        nc_tool_fail(ctx);
        goto out;
    }
    rs = fs.render;
    /* The files the scene was built from are inputs too (its meshes, depth maps, volumes). */
    for (uint32_t i = 0; i < nacre_scene_input_count(scene); i++) {
        const char *input = nacre_scene_input_path(scene, i);
        if (!output_distinct("render", out_path, "output", input, "scene's input") ||
            !output_distinct("render", variance_path, "variance output", input, "scene's input"))
            goto out;
    }
    uint64_t load_us = nc_tool_now_us() - t_start;
    if (method_name)
        rs.method = method;
    if (!method_name && scene_path == NULL) {
        /* The demo shows the best method this build has (not layered: its single scattering is
         * for layered materials, and the demo has none). */
        for (int m = NACRE_METHOD_COUNT - 1; m >= 0; m--)
            if (m != NACRE_METHOD_LAYERED && nacre_method_info_get((nacre_method)m, &info) && info.available &&
                !info.stochastic) {
                rs.method = (nacre_method)m;
                break;
            }
    }
    if (width) {
        rs.width = (int32_t)width;
        rs.height = (int32_t)height;
    }
    if (!isnan(exposure))
        fs.exposure = (float)exposure;
    if (!isnan(time))
        fs.time = time;
    if (voxel_res > 0)
        rs.diffusion.voxel_resolution = (uint32_t)voxel_res;
    if (tsm_size > 0)
        rs.diffusion.tsm_size = (int32_t)tsm_size;
    if (solver_name)
        rs.diffusion.solver = solver;
    if (source_name)
        rs.diffusion.source = source;
    if (single_scattering >= 0)
        rs.diffusion.single_scattering = (nacre_single_scattering)single_scattering;
    if (particles_name)
        rs.particles = particles_draw;
    if (!isnan(tolerance))
        rs.diffusion.tolerance = (float)tolerance;
    if (seed_iters > 0)
        rs.diffusion.seed_iterations = (uint32_t)seed_iters;
    if (spp > 0)
        rs.pathtrace.spp = (uint32_t)spp;
    if (seed >= 0)
        rs.pathtrace.seed = (uint32_t)seed;
    if (!isnan(time_limit))
        rs.pathtrace.time_limit = time_limit;
    if (max_scatter > 0)
        rs.pathtrace.max_scatter = (uint32_t)max_scatter;
    if (layered_samples > 0)
        rs.layered.samples = (uint32_t)layered_samples;
    if (!isnan(layered_epsilon))
        rs.layered.epsilon = (float)layered_epsilon;
    if (!isnan(layered_half_res))
        rs.layered.half_res = (float)layered_half_res;
    if (integration_name)
        rs.layered.integration = integration;
    if (volumetrics_name)
        rs.volumetrics.mode = volumetrics;
    if (froxel[0] > 0) {
        rs.volumetrics.froxel_width = (uint32_t)froxel[0];
        rs.volumetrics.froxel_height = (uint32_t)froxel[1];
        rs.volumetrics.froxel_slices = (uint32_t)froxel[2];
    }
    if (raymarch_steps > 0)
        rs.volumetrics.raymarch_steps = (uint32_t)raymarch_steps;
    if (shadow_steps > 0)
        rs.volumetrics.shadow_steps = (uint32_t)shadow_steps;
    nacre_method_info_get(rs.method, &info);
    if (variance_path && !info.stochastic) {
        nc_tool_error("--variance needs --method pathtrace");
        goto out;
    }
    if (!nacre_method_available(rs.method)) {
        nc_tool_error("method '%s' is not implemented yet", nacre_method_name(rs.method));
        goto out;
    }
    /* The renderer's own message cannot name the file. */
    if (nacre_scene_object_count(scene) == 0 && (info.needs_objects || nacre_scene_fog_count(scene) == 0)) {
        nc_tool_error("%s: scene has no objects (nothing to render with method '%s')",
                  scene_path ? scene_path : "<built-in demo>", nacre_method_name(rs.method));
        goto out;
    }
    if (save_path) {
        /* The scene as this run renders it: the command line's settings in its render block. The
         * library refuses to write over the scene's inputs. */
        nacre_scene_file_settings saved = fs;
        saved.render = rs;
        if (nacre_scene_save_file(scene, &saved, save_path) != NACRE_OK) {
            nc_tool_fail(ctx);
            goto out;
        }
    }
    uint64_t t0 = nc_tool_now_us();
    if (nacre_scene_commit(scene, fs.time) != NACRE_OK) {
        nc_tool_fail(ctx);
        goto out;
    }
    uint64_t commit_us = nc_tool_now_us() - t0;
    if (rs.pathtrace.time_limit > 0) /* the limit is the whole command's: loading and commit count */
        rs.pathtrace.time_limit = fmax(rs.pathtrace.time_limit - (double)(nc_tool_now_us() - t_start) * 1e-6, 1e-3);
    nacre_render_stats st;
    if (nacre_renderer_create(ctx, &renderer) != NACRE_OK || nacre_renderer_render(renderer, scene, &rs, &img, &st) != NACRE_OK) {
        nc_tool_fail(ctx);
        goto out;
    }
    if (st.pixels_unsampled > 0)
        fprintf(stderr, "nacre: warning: the time limit ended the first pass: %u of %d pixels have no sample "
                        "(each shows the mean of its 8x8 block, black if the block has none)\n",
                st.pixels_unsampled, rs.width * rs.height);
    if (st.paths_capped > 0)
        fprintf(stderr, "nacre: note: %llu paths reached the path-length or collision cap and were ended there "
                        "(see README: the path tracer's caps)\n",
                (unsigned long long)st.paths_capped);
    /* Raster methods draw fog by the fog post pass; say what it leaves out (with volumetrics
     * froxel or raymarch both counts are 0). */
    if (st.fog_lights_ignored > 0)
        fprintf(stderr, "nacre: note: method '%s' lights fog with directional lights and the environment only; "
                        "%u point or spot light%s add%s no light to the fog (--method pathtrace and --volumetrics froxel do)\n",
                nacre_method_name(rs.method), st.fog_lights_ignored, st.fog_lights_ignored == 1 ? "" : "s",
                st.fog_lights_ignored == 1 ? "s" : "");
    if (st.fog_patterns_averaged > 0)
        fprintf(stderr, "nacre: note: method '%s' draws %u patterned fog%s with %s mean coefficients "
                        "(--method pathtrace and --volumetrics froxel render the pattern)\n",
                nacre_method_name(rs.method), st.fog_patterns_averaged, st.fog_patterns_averaged == 1 ? "" : "s",
                st.fog_patterns_averaged == 1 ? "its" : "their");
    if (!image_finite(&img, &rs, "image")) /* nothing is written */
        goto out;
    if (variance_path) {
        nacre_image var = {0};
        nacre_image_write_options vo = {.exr_type = NACRE_EXR_FLOAT};
        bool got = nacre_renderer_variance(renderer, &var) == NACRE_OK, finite = got && image_finite(&var, &rs, "variance");
        bool ok = finite && nacre_image_write(ctx, &var, variance_path, &vo) == NACRE_OK;
        nacre_image_free(ctx, &var);
        if (!ok) {
            if (!got || finite)
                nc_tool_fail(ctx);
            goto out;
        }
    }
    t0 = nc_tool_now_us();
    nacre_image_write_options wo = {.exposure = fs.exposure, .exr_type = exr_float ? NACRE_EXR_FLOAT : NACRE_EXR_HALF};
    nc_tool_set_warning_hint(" (--exr-float)"); /* the one warning an image write gives: half range */
    nacre_result wr = nacre_image_write(ctx, &img, out_path, &wo);
    nc_tool_set_warning_hint(NULL);
    if (wr != NACRE_OK) {
        nc_tool_fail(ctx);
        goto out;
    }
    uint64_t write_us = nc_tool_now_us() - t0;
    if (stats)
        print_stats(scene_path ? scene_path : "<built-in demo>", &rs, &st, load_us, commit_us, write_us,
                    nc_tool_now_us() - t_start, nacre_context_memory_peak(ctx));
    rc = 0;
out:
    nacre_image_free(ctx, &img);
    nacre_renderer_destroy(renderer);
    nacre_scene_destroy(scene);
    nacre_context_destroy(ctx);
    return rc;
}

/* ---------------------------------------------------------------------------------------- */
/* info                                                                                     */
/* ---------------------------------------------------------------------------------------- */

static const char info_help[] =
    "usage: nacre info MESH [--json] [--thickness-layer]\n"
    "Load a mesh (OBJ, PLY, glTF) and report vertex and triangle counts, bounds, surface area,\n"
    "and its topology after welding exactly coincident vertices: boundary (open) edges,\n"
    "non-manifold edges, degenerate triangles, closedness. For a glTF (.gltf, .glb) also its\n"
    "scene: meshes, materials (opaque or translucent), lights, cameras, and which extensions\n"
    "were mapped and which ignored (each ignored one also warns on stderr).\n"
    "\n"
    "  --json              one JSON object\n"
    "  --thickness-layer   glTF: map thickness textures to one-layer depth maps (as render does)\n"
    "  --help, --version\n";

static void print_json_string(const char *str)
{
    putchar('"');
    for (const char *c = str; *c; c++) {
        if (*c == '"' || *c == '\\')
            putchar('\\');
        if ((unsigned char)*c >= 0x20)
            putchar(*c);
    }
    putchar('"');
}

static void print_json_names(const char *key, const char (*names)[NACRE_GLTF_NAME_MAX], uint32_t count)
{
    printf(",\"%s\":[", key);
    for (uint32_t i = 0; i < count && i < NACRE_GLTF_REPORT_MAX; i++) {
        if (i)
            putchar(',');
        print_json_string(names[i]);
    }
    putchar(']');
}

/* The "gltf" member of info --json: what the scene import mapped. */
static void print_gltf_json(const nacre_gltf_report *r, uint64_t scene_us)
{
    printf(",\"gltf\":{\"meshes\":%u,\"primitives\":%u,\"objects\":%u,\"lights\":%u,\"cameras\":%u,"
           "\"scene_load_ms\":%.3f,\"materials\":[",
           r->meshes, r->primitives, r->objects, r->lights, r->cameras, scene_us / 1000.0);
    for (uint32_t i = 0; i < r->material_count && i < NACRE_GLTF_REPORT_MAX; i++) {
        printf("%s{\"name\":", i ? "," : "");
        print_json_string(r->materials[i]);
        printf(",\"type\":\"%s\"}", r->translucent[i] ? "translucent" : "opaque");
    }
    printf("]");
    print_json_names("extensions_mapped", r->mapped, r->mapped_count);
    print_json_names("extensions_ignored", r->ignored, r->ignored_count);
    printf("}");
}

static void print_gltf_text(const nacre_gltf_report *r, uint64_t scene_us)
{
    printf("  glTF                  %u meshes, %u primitives -> %u objects, %u lights, %u cameras\n", r->meshes,
           r->primitives, r->objects, r->lights, r->cameras);
    for (uint32_t i = 0; i < r->material_count && i < NACRE_GLTF_REPORT_MAX; i++)
        printf("  material              %s (%s)\n", r->materials[i], r->translucent[i] ? "translucent" : "opaque");
    for (uint32_t i = 0; i < r->mapped_count && i < NACRE_GLTF_REPORT_MAX; i++)
        printf("  extension mapped      %s\n", r->mapped[i]);
    for (uint32_t i = 0; i < r->ignored_count && i < NACRE_GLTF_REPORT_MAX; i++)
        printf("  extension ignored     %s\n", r->ignored[i]);
    printf("  scene load            %.1f ms\n", scene_us / 1000.0);
}

static int cmd_info(int argc, char **argv)
{
    nacre_gltf_report gltf_report;
    memset(&gltf_report, 0, sizeof(gltf_report));
    const char *path = NULL;
    bool json = false, thickness_layer = false;
    int code;
    for (int i = 0; i < argc; i++) {
        if (nc_tool_common_flag("info", argv[i], info_help, &code))
            return code;
        if (strcmp(argv[i], "--json") == 0)
            json = true;
        else if (strcmp(argv[i], "--thickness-layer") == 0)
            thickness_layer = true;
        else if (argv[i][0] == '-')
            return nc_tool_usage("info", "unknown option '%s'", argv[i]);
        else if (!path)
            path = argv[i];
        else
            return nc_tool_usage("info", "unexpected argument '%s'", argv[i]);
    }
    if (!path)
        return nc_tool_usage("info", "missing MESH");
    nacre_context *ctx = nc_tool_context(0);
    if (!ctx)
        return EXIT_BAD;
    nacre_mesh_data mesh = {0};
    nacre_mesh_info info;
    int rc = EXIT_BAD;
    uint64_t t0 = nc_tool_now_us();
    if (nacre_mesh_load(ctx, path, &mesh) != NACRE_OK) {
        nc_tool_fail(ctx);
        goto out;
    }
    uint64_t load_us = nc_tool_now_us() - t0;
    if (nacre_mesh_analyze(ctx, &mesh, &info) != NACRE_OK) {
        nc_tool_fail(ctx);
        goto out;
    }
    const bool gltf = has_suffix(path, ".gltf") || has_suffix(path, ".glb");
    uint64_t scene_us = 0;
    if (gltf) {
        t0 = nc_tool_now_us();
        nacre_scene *scene = NULL;
        if (nacre_scene_load_gltf(ctx, path, &(nacre_gltf_options){.thickness_layer = thickness_layer}, &scene, NULL,
                                  &gltf_report) != NACRE_OK) {
            nc_tool_fail(ctx);
            goto out;
        }
        scene_us = nc_tool_now_us() - t0;
        nacre_scene_destroy(scene);
    }
    if (json) {
        printf("{\"file\":\"");
        for (const char *c = path; *c; c++) {
            if (*c == '"' || *c == '\\')
                putchar('\\');
            putchar(*c);
        }
        printf("\",\"vertices\":%u,\"triangles\":%u,\"welded_vertices\":%u,\"unreferenced_vertices\":%u,"
               "\"degenerate_triangles\":%u,\"edges\":%llu,\"boundary_edges\":%llu,\"nonmanifold_edges\":%llu,"
               "\"closed\":%s,\"bounds\":{\"min\":[%.9g,%.9g,%.9g],\"max\":[%.9g,%.9g,%.9g]},\"surface_area\":%.9g,"
               "\"has_normals\":%s,\"has_uvs\":%s,\"load_ms\":%.3f",
               info.vertex_count, info.triangle_count, info.welded_vertex_count, info.unreferenced_vertices,
               info.degenerate_triangles, (unsigned long long)info.edge_count, (unsigned long long)info.boundary_edges,
               (unsigned long long)info.nonmanifold_edges, info.closed ? "true" : "false", info.bounds_min[0],
               info.bounds_min[1], info.bounds_min[2], info.bounds_max[0], info.bounds_max[1], info.bounds_max[2],
               info.surface_area, mesh.normals ? "true" : "false", mesh.uvs ? "true" : "false", load_us / 1000.0);
        if (gltf)
            print_gltf_json(&gltf_report, scene_us);
        printf("}\n");
    } else {
        printf("%s\n", path);
        printf("  vertices              %u (%u after welding, %u unreferenced)\n", info.vertex_count,
               info.welded_vertex_count, info.unreferenced_vertices);
        printf("  triangles             %u (%u degenerate)\n", info.triangle_count, info.degenerate_triangles);
        printf("  edges                 %llu (%llu boundary, %llu non-manifold)\n", (unsigned long long)info.edge_count,
               (unsigned long long)info.boundary_edges, (unsigned long long)info.nonmanifold_edges);
        printf("  closed                %s\n", info.closed ? "yes" : "no");
        printf("  bounds                (%g, %g, %g) .. (%g, %g, %g)\n", info.bounds_min[0], info.bounds_min[1],
               info.bounds_min[2], info.bounds_max[0], info.bounds_max[1], info.bounds_max[2]);
        printf("  surface area          %g\n", info.surface_area);
        printf("  load                  %.1f ms\n", load_us / 1000.0);
        if (gltf)
            print_gltf_text(&gltf_report, scene_us);
    }
    rc = 0;
out:
    nacre_mesh_data_free(ctx, &mesh);
    nacre_context_destroy(ctx);
    return rc;
}

/* ---------------------------------------------------------------------------------------- */
/* compare                                                                                  */
/* ---------------------------------------------------------------------------------------- */

static const char compare_help[] =
    "usage: nacre compare TEST REFERENCE [--json]\n"
    "Compare two images (.exr or .png, same size) over all pixels and channels:\n"
    "  rmse           sqrt(mean((t - r)^2))\n"
    "  rel_mse        mean((t - r)^2 / (r^2 + 0.01))\n"
    "  psnr           10 log10(peak^2 / mse), peak = max reference value (dB)\n"
    "  mean_rel_err   mean(|t - r| / |r|) over values where the reference is non-zero\n"
    "  max_abs_err    max |t - r|\n"
    "Over the reference's lit pixels (R + G + B > 0; the object on a black background):\n"
    "  lit_ratio      sum(t) / sum(r) per channel\n"
    "  dark_ratio     the same over the darkest quarter of those pixels\n"
    "  lit_rel_err_median, lit_rel_err_p90   of |T - R| / R per pixel, T, R = R + G + B\n"
    "Pixels holding NaN or infinite values are counted (nonfinite_test, nonfinite_reference) and\n"
    "left out of the metrics; if either image has any, compare prints the metrics and an error\n"
    "and exits with status 2.\n"
    "\n"
    "  --json              one JSON object\n"
    "  --thickness-layer   glTF: map thickness textures to one-layer depth maps (as render does)\n"
    "  --help, --version\n";

static void print_number(double v)
{
    if (isfinite(v))
        printf("%.9g", v);
    else
        printf("null"); /* JSON has no infinity: identical images have psnr null */
}

static int cmd_compare(int argc, char **argv)
{
    const char *paths[2] = {NULL, NULL};
    int npaths = 0, code;
    bool json = false;
    for (int i = 0; i < argc; i++) {
        if (nc_tool_common_flag("compare", argv[i], compare_help, &code))
            return code;
        if (strcmp(argv[i], "--json") == 0)
            json = true;
        else if (argv[i][0] == '-')
            return nc_tool_usage("compare", "unknown option '%s'", argv[i]);
        else if (npaths < 2)
            paths[npaths++] = argv[i];
        else
            return nc_tool_usage("compare", "unexpected argument '%s'", argv[i]);
    }
    if (npaths != 2)
        return nc_tool_usage("compare", "needs two images");
    nacre_context *ctx = nc_tool_context(0);
    if (!ctx)
        return EXIT_BAD;
    nacre_image a = {0}, b = {0};
    nacre_image_metrics m;
    int rc = EXIT_BAD;
    if (nacre_image_read(ctx, paths[0], &a) != NACRE_OK || nacre_image_read(ctx, paths[1], &b) != NACRE_OK ||
        nacre_image_compare(ctx, &a, &b, &m) != NACRE_OK) {
        nc_tool_fail(ctx);
        goto out;
    }
    if (json) {
        printf("{\"rmse\":");
        print_number(m.rmse);
        printf(",\"rel_mse\":");
        print_number(m.rel_mse);
        printf(",\"psnr\":");
        print_number(m.psnr);
        printf(",\"mean_rel_err\":");
        print_number(m.mean_rel_err);
        printf(",\"max_abs_err\":");
        print_number(m.max_abs_err);
        printf(",\"values\":%llu,\"nonzero_reference_values\":%llu,\"nonfinite_test\":%llu,"
               "\"nonfinite_reference\":%llu",
               (unsigned long long)m.count, (unsigned long long)m.nonzero_ref, (unsigned long long)m.nonfinite_test,
               (unsigned long long)m.nonfinite_ref);
        printf(",\"lit_pixels\":%llu,\"lit_ratio\":[%.6g,%.6g,%.6g],\"dark_ratio\":[%.6g,%.6g,%.6g]"
               ",\"lit_rel_err_median\":%.6g,\"lit_rel_err_p90\":%.6g}\n",
               (unsigned long long)m.lit_pixels, m.lit_ratio[0], m.lit_ratio[1], m.lit_ratio[2], m.dark_ratio[0],
               m.dark_ratio[1], m.dark_ratio[2], m.lit_rel_err_median, m.lit_rel_err_p90);
    } else {
        printf("rmse          %.6g\nrel_mse       %.6g\npsnr          %.3f dB\nmean_rel_err  %.6g\nmax_abs_err   %.6g\n",
               m.rmse, m.rel_mse, m.psnr, m.mean_rel_err, m.max_abs_err);
        if (m.lit_pixels)
            printf("lit pixels    %llu: ratio R G B %.4f %.4f %.4f, darkest quarter %.4f %.4f %.4f,\n"
                   "              relative error of R+G+B median %.4f, p90 %.4f\n",
                   (unsigned long long)m.lit_pixels, m.lit_ratio[0], m.lit_ratio[1], m.lit_ratio[2], m.dark_ratio[0],
                   m.dark_ratio[1], m.dark_ratio[2], m.lit_rel_err_median, m.lit_rel_err_p90);
        if (m.nonfinite_test || m.nonfinite_ref)
            printf("nonfinite     %llu test, %llu reference pixels (left out)\n", (unsigned long long)m.nonfinite_test,
                   (unsigned long long)m.nonfinite_ref);
    }
    if (m.nonfinite_test || m.nonfinite_ref) {
        fflush(stdout);
        nc_tool_error("compare: %s has %llu and %s has %llu pixels with NaN or infinite values; the metrics leave them out",
                  paths[0], (unsigned long long)m.nonfinite_test, paths[1], (unsigned long long)m.nonfinite_ref);
        goto out;
    }
    rc = 0;
out:
    nacre_image_free(ctx, &a);
    nacre_image_free(ctx, &b);
    nacre_context_destroy(ctx);
    return rc;
}

/* ---------------------------------------------------------------------------------------- */
/* voxelize                                                                                 */
/* ---------------------------------------------------------------------------------------- */

static const char voxelize_help[] =
    "usage: nacre voxelize MESH --res N [--aniso] [--json] [-o OUT.nrrd]\n"
    "Voxelize a mesh: conservative surface set and solid set (voxel centres inside the mesh;\n"
    "column parity for closed meshes, a vote of x/y/z parities otherwise).\n"
    "\n"
    "  --res N       voxels along the longest axis, 1..4096 (default 32)\n"
    "  --aniso       fit the other axes to the bounds instead of an N^3 grid\n"
    "  -o FILE       write NRRD (uint8, sizes 2 x y z: channel 0 solid, channel 1 surface)\n"
    "  --json        one JSON object: dims, voxel_size, origin, counts, closed, ms\n"
    "  --memory-limit SIZE  most memory nacre may hold (4G, 512M; default half of RAM)\n"
    "  --help, --version\n";

static int cmd_voxelize(int argc, char **argv)
{
    const char *path = NULL, *out_path = NULL;
    bool json = false;
    long res = 32;
    int code;
    nacre_voxel_settings vs = nacre_voxel_settings_defaults();
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        if (nc_tool_common_flag("voxelize", a, voxelize_help, &code))
            return code;
        if (strcmp(a, "--json") == 0) {
            json = true;
        } else if (strcmp(a, "--aniso") == 0) {
            vs.anisotropic = true;
        } else if (strcmp(a, "--res") == 0) {
            if (i + 1 >= argc || !nc_tool_parse_int(argv[++i], 1, 4096, &res))
                return nc_tool_usage("voxelize", "--res needs an integer in 1..4096");
        } else if (strcmp(a, "-o") == 0 || strcmp(a, "--output") == 0) {
            if (i + 1 >= argc)
                return nc_tool_usage("voxelize", "%s needs a file name", a);
            out_path = argv[++i];
        } else if (a[0] == '-') {
            return nc_tool_usage("voxelize", "unknown option '%s'", a);
        } else if (!path) {
            path = a;
        } else {
            return nc_tool_usage("voxelize", "unexpected argument '%s'", a);
        }
    }
    if (!path)
        return nc_tool_usage("voxelize", "missing MESH");
    if (!output_distinct("voxelize", out_path, "output", path, "mesh"))
        return EXIT_BAD;
    vs.resolution = (uint32_t)res;
    nacre_context *ctx = nc_tool_context(0);
    if (!ctx)
        return EXIT_BAD;
    nacre_mesh_data mesh = {0};
    nacre_voxel_grid *grid = NULL;
    nacre_voxel_report rep;
    int rc = EXIT_BAD;
    if (nacre_mesh_load(ctx, path, &mesh) != NACRE_OK || nacre_voxelize(ctx, &mesh, &vs, &grid, &rep) != NACRE_OK ||
        (out_path && nacre_voxel_grid_write_nrrd(grid, 0, out_path) != NACRE_OK)) {
        nc_tool_fail(ctx);
        goto out;
    }
    if (json) {
        printf("{\"dims\":[%u,%u,%u],\"voxel_size\":%.9g,\"origin\":[%.9g,%.9g,%.9g],\"surface_voxels\":%llu,"
               "\"solid_voxels\":%llu,\"closed\":%s,\"rule\":\"%s\",\"levels\":%u,\"skipped_degenerate\":%u,"
               "\"skipped_nonfinite\":%u,\"ms\":%.3f}\n",
               rep.dims[0], rep.dims[1], rep.dims[2], rep.voxel_size, rep.origin[0], rep.origin[1], rep.origin[2],
               (unsigned long long)rep.surface_voxels, (unsigned long long)rep.solid_voxels,
               rep.closed ? "true" : "false", rep.rule_used == NACRE_VOXEL_SOLID_PARITY ? "parity" : "robust",
               rep.levels, rep.skipped_degenerate, rep.skipped_nonfinite, rep.ms);
    } else {
        printf("%s\n  grid      %u x %u x %u, voxel %g, origin (%g, %g, %g), %u levels\n", path, rep.dims[0],
               rep.dims[1], rep.dims[2], rep.voxel_size, rep.origin[0], rep.origin[1], rep.origin[2], rep.levels);
        printf("  surface   %llu voxels\n  solid     %llu voxels (%s, mesh %s)\n", (unsigned long long)rep.surface_voxels,
               (unsigned long long)rep.solid_voxels, rep.rule_used == NACRE_VOXEL_SOLID_PARITY ? "parity" : "robust vote",
               rep.closed ? "closed" : "not closed");
        printf("  skipped   %u degenerate, %u non-finite triangles\n  time      %.3f ms\n", rep.skipped_degenerate,
               rep.skipped_nonfinite, rep.ms);
    }
    rc = 0;
out:
    nacre_voxel_grid_destroy(grid);
    nacre_mesh_data_free(ctx, &mesh);
    nacre_context_destroy(ctx);
    return rc;
}

/* ---------------------------------------------------------------------------------------- */

int main(int argc, char **argv)
{
    if (argc < 2) {
        print_main_help(stderr);
        return EXIT_BAD;
    }
    const char *cmd = argv[1];
    if (strcmp(cmd, "--help") == 0 || strcmp(cmd, "-h") == 0 || strcmp(cmd, "help") == 0) {
        print_main_help(stdout);
        return 0;
    }
    if (strcmp(cmd, "--version") == 0) {
        printf("nacre %s\n", nacre_version());
        return 0;
    }
    /* The viewer's OpenMP threads should sleep, not spin, between the many short parallel
     * regions of a frame: spinning workers take the cores from the GL driver's threads that
     * present the frame (camera-only frames 15-20% faster). libgomp reads the policy when it
     * loads, so the viewer re-executes itself once with it set, unless the user chose one. */
    if (strcmp(cmd, "view") == 0 && !getenv("OMP_WAIT_POLICY") && !getenv("GOMP_SPINCOUNT")) {
        setenv("OMP_WAIT_POLICY", "passive", 1);
        execv("/proc/self/exe", argv);
        unsetenv("OMP_WAIT_POLICY"); /* no re-exec (no /proc): run as we are */
    }
    /* --memory-limit applies to every command: taken out of argv here, wherever it stands. */
    int kept = 2;
    for (int i = 2; i < argc; i++) {
        if (strcmp(argv[i], "--memory-limit") == 0) {
            uint64_t limit = 0;
            if (i + 1 >= argc || !nc_tool_parse_bytes(argv[i + 1], &limit))
                return nc_tool_usage(cmd, "--memory-limit needs a size such as 4G, 512M or a byte count");
            nc_tool_set_memory_limit(limit);
            i++;
            continue;
        }
        argv[kept++] = argv[i];
    }
    argc = kept;
    argv[argc] = NULL;
    if (strcmp(cmd, "render") == 0)
        return cmd_render(argc - 2, argv + 2);
    if (strcmp(cmd, "info") == 0)
        return cmd_info(argc - 2, argv + 2);
    if (strcmp(cmd, "compare") == 0)
        return cmd_compare(argc - 2, argv + 2);
    if (strcmp(cmd, "voxelize") == 0)
        return cmd_voxelize(argc - 2, argv + 2);
    if (strcmp(cmd, "slab") == 0)
        return nc_cli_slab(argc - 2, argv + 2);
    if (strcmp(cmd, "bench") == 0)
        return nc_cli_bench(argc - 2, argv + 2);
    if (strcmp(cmd, "view") == 0)
        return nc_cli_view(argc - 2, argv + 2);
    if (strcmp(cmd, "layers") == 0)
        return nc_cli_layers(argc - 2, argv + 2);
    fprintf(stderr, "nacre: unknown command '%s'\n", cmd);
    print_main_help(stderr);
    return EXIT_BAD;
}
