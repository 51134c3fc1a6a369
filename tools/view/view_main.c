/*
 * view_main.c: `nacre view [SCENE.json]`, the interactive viewer: options, the SDL2 window with
 * an OpenGL context, mouse and keys, the frame loop, and the headless mode of tests and scripts
 * (--frames N, --script, --screenshot, one JSON line of timings). The edits themselves are in
 * view_state.c, the panel in panel.cpp, the script grammar in script.c.
 */
#include "cli.h"
#include "panel.h"
#include "script.h"
#include "view.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "demo_scene.h"

static const char view_help[] =
    "usage: nacre view [SCENE.json | MODEL.gltf | MODEL.glb] [options]\n"
    "Open a window on a scene (default: the built-in demo) and edit it while it renders.\n"
    "\n"
    "  --size WxH          image and window size (default 640x480)\n"
    "  --method M          phong | diffusion | layered | pathtrace (default: the scene's; the demo:\n"
    "                      diffusion)\n"
    "  --voxel-res N       diffusion voxel resolution (default: the scene's, else 32)\n"
    "  --spp N             samples per pixel each path-traced frame adds (default 1)\n"
    "  --threads N         worker threads (default: all cores)\n"
    "  --camera NAME       glTF: view from the camera of this name (default: the first)\n"
    "  --thickness-layer   glTF: thickness textures become one-layer depth maps (see nacre render)\n"
    "  --exact             solve every frame to the scene's tolerance (default: a frame in which a\n"
    "                      light moved solves the diffusion to 1e-3, and the frame is rendered\n"
    "                      again at the scene's tolerance once the light rests for 2 frames)\n"
    "headless (tests, scripts):\n"
    "  --frames N          render N frames, then exit (the timeline steps 1/30 s per frame)\n"
    "  --script FILE       timed events, one per line: FRAME COMMAND ARGS (README, `nacre view`)\n"
    "  --screenshot FILE   write the last frame's image (not the panel): .png (exposure) or .exr\n"
    "  --window-shot FILE  write the last frame's window as drawn (frame, light handles, panel): .png\n"
    "  --save-scene FILE   write the final state as a scene file (`nacre render FILE` reproduces it)\n"
    "  With --frames, one JSON line: frames, fps, per-stage microseconds and stage_runs summed\n"
    "  over the frames, the final camera and time.\n"
    "mouse: left drag orbits, middle or shift+left drag pans, wheel zooms, left click picks a light's\n"
    "       handle (circle) or an object, left drag on a handle moves that light\n"
    "keys:  1 phong, 2 diffusion, 3 layered, 4 pathtrace; p/space play; t wipe; e error view;\n"
    "       n frame; arrows turn the light; [ ] select light; r camera home; h panel; q quit\n"
    "  --help, --version\n";

typedef struct view_options {
    const char *scene, *method, *script, *screenshot, *window_shot, *save_scene, *camera;
    long width, height, frames, voxel_res, spp, threads;
    bool thickness_layer, exact;
} view_options;

/* Case-insensitive suffix test (file extensions). */
static bool ends_with(const char *s, const char *suffix)
{
    size_t n = strlen(s), m = strlen(suffix);
    for (size_t i = 0; n >= m && i < m; i++)
        if ((s[n - m + i] | 0x20) != (suffix[i] | 0x20))
            return false;
    return n >= m;
}

static int parse_options(int argc, char **argv, view_options *o, bool *done)
{
    int code = 0;
    *done = false;
    *o = (view_options){.width = 640, .height = 480};
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        if (nc_tool_common_flag("view", a, view_help, &code)) {
            *done = true;
            return code;
        }
        bool v = i + 1 < argc;
        if (strcmp(a, "--size") == 0) {
            const char *s = v ? argv[++i] : "";
            char *x = strchr(s, 'x');
            char w[32];
            if (!x || (size_t)(x - s) >= sizeof(w))
                return nc_tool_usage("view", "--size needs WxH, e.g. 640x480");
            memcpy(w, s, (size_t)(x - s));
            w[x - s] = '\0';
            if (!nc_tool_parse_int(w, 1, 16384, &o->width) || !nc_tool_parse_int(x + 1, 1, 16384, &o->height))
                return nc_tool_usage("view", "--size '%s': width and height must be integers in 1..16384", s);
        } else if (strcmp(a, "--method") == 0 && v) {
            o->method = argv[++i];
        } else if (strcmp(a, "--camera") == 0 && v) {
            o->camera = argv[++i];
        } else if (strcmp(a, "--thickness-layer") == 0) {
            o->thickness_layer = true;
        } else if (strcmp(a, "--exact") == 0) {
            o->exact = true;
        } else if (strcmp(a, "--script") == 0 && v) {
            o->script = argv[++i];
        } else if (strcmp(a, "--screenshot") == 0 && v) {
            o->screenshot = argv[++i];
        } else if (strcmp(a, "--window-shot") == 0 && v) {
            o->window_shot = argv[++i];
        } else if (strcmp(a, "--save-scene") == 0 && v) {
            o->save_scene = argv[++i];
        } else if (strcmp(a, "--frames") == 0) {
            if (!v || !nc_tool_parse_int(argv[++i], 1, 100000000, &o->frames))
                return nc_tool_usage("view", "--frames needs an integer >= 1");
        } else if (strcmp(a, "--voxel-res") == 0) {
            if (!v || !nc_tool_parse_int(argv[++i], 2, 512, &o->voxel_res))
                return nc_tool_usage("view", "--voxel-res needs an integer in 2..512");
        } else if (strcmp(a, "--spp") == 0) {
            if (!v || !nc_tool_parse_int(argv[++i], 1, 65536, &o->spp))
                return nc_tool_usage("view", "--spp needs an integer in 1..65536");
        } else if (strcmp(a, "--threads") == 0) {
            if (!v || !nc_tool_parse_int(argv[++i], 1, 1024, &o->threads))
                return nc_tool_usage("view", "--threads needs an integer in 1..1024");
        } else if (a[0] == '-' && a[1]) {
            return nc_tool_usage("view", v ? "unknown option '%s'" : "unknown option or missing value '%s'", a);
        } else if (!o->scene) {
            o->scene = a;
        } else {
            return nc_tool_usage("view", "unexpected argument '%s'", a);
        }
    }
    if ((o->screenshot || o->window_shot || o->save_scene) && !o->frames)
        return nc_tool_usage("view", "--screenshot, --window-shot and --save-scene need --frames N (headless run)");
    const bool gltf = o->scene && (ends_with(o->scene, ".glb") || ends_with(o->scene, ".gltf"));
    if (o->camera && !gltf)
        return nc_tool_usage("view", "--camera needs a .gltf or .glb scene");
    if (o->thickness_layer && !gltf)
        return nc_tool_usage("view", "--thickness-layer needs a .gltf or .glb scene");
    return 0;
}

/* Load the scene and set up the view with the options; the message is printed on failure. */
static bool open_view(nc_view *v, nacre_context *ctx, const view_options *o)
{
    nacre_scene *scene = NULL;
    nacre_scene_file_settings fs = {.render = nacre_render_settings_defaults()};
    nacre_result res;
    if (o->camera || o->thickness_layer)
        res = nacre_scene_load_gltf(ctx, o->scene,
                                    &(nacre_gltf_options){.camera = o->camera, .thickness_layer = o->thickness_layer},
                                    &scene, &fs, NULL);
    else if (o->scene)
        res = nacre_scene_load_file(ctx, o->scene, &scene, &fs);
    else
        res = nacre_scene_load_json(ctx, (const char *)nacre_demo_scene_json,
                                    strlen((const char *)nacre_demo_scene_json), "<built-in demo>", ".", &scene, &fs);
    if (res != NACRE_OK) {
        nc_tool_fail(ctx);
        return false;
    }
    if (nacre_scene_object_count(scene) == 0) {
        nc_tool_error("%s: scene has no objects (nothing to view)", o->scene ? o->scene : "<built-in demo>");
        nacre_scene_destroy(scene);
        return false;
    }
    if (!o->scene) /* the demo shows diffusion, as `nacre render` does */
        fs.render.method = nacre_method_available(NACRE_METHOD_DIFFUSION) ? NACRE_METHOD_DIFFUSION : NACRE_METHOD_PHONG;
    fs.render.width = (int32_t)o->width;
    fs.render.height = (int32_t)o->height;
    if (o->voxel_res)
        fs.render.diffusion.voxel_resolution = (uint32_t)o->voxel_res;
    if (!nc_view_init(v, ctx, scene, &fs)) {
        nc_tool_error("view: %s", v->message); /* the caller frees the view */
        return false;
    }
    v->interactive = !o->exact;
    if (o->spp)
        v->pathtrace_spp = (uint32_t)o->spp;
    if (o->method) {
        nacre_method m;
        if (!nacre_method_from_name(o->method, &m)) {
            nc_tool_usage("view", "unknown method '%s' (phong, diffusion, layered, pathtrace)", o->method);
            return false;
        }
        if (!nc_view_set_method(v, m, false)) {
            nc_tool_error("%s", v->message);
            return false;
        }
    }
    if (o->frames)
        v->fixed_step = 1.0 / 30.0;
    return true;
}

/* Mouse state between events: a left press that does not move is a click (pick); one that
 * starts on a light's handle drags that light. */
typedef struct drag_state {
    bool left, middle, moved, shift;
    int x0, y0;
    uint32_t light; /* the light being dragged, UINT32_MAX: none */
} drag_state;

/* Window pixel to frame pixel (the frame is stretched over the window when they differ). */
static void to_frame(SDL_Window *w, const nc_view *v, int x, int y, int32_t *fx, int32_t *fy)
{
    int ww = 1, wh = 1;
    SDL_GetWindowSize(w, &ww, &wh);
    *fx = (int32_t)((int64_t)x * v->fs.render.width / (ww > 0 ? ww : 1));
    *fy = (int32_t)((int64_t)y * v->fs.render.height / (wh > 0 ? wh : 1));
}

static const char *key_name(SDL_Keycode k)
{
    switch (k) {
    case SDLK_1: return "1";
    case SDLK_2: return "2";
    case SDLK_3: return "3";
    case SDLK_4: return "4";
    case SDLK_p: return "p";
    case SDLK_SPACE: return "space";
    case SDLK_t: return "t";
    case SDLK_e: return "e";
    case SDLK_n: return "n";
    case SDLK_LEFT: return "left";
    case SDLK_RIGHT: return "right";
    case SDLK_UP: return "up";
    case SDLK_DOWN: return "down";
    case SDLK_LEFTBRACKET: return "[";
    case SDLK_RIGHTBRACKET: return "]";
    case SDLK_r: return "r";
    default: return NULL;
    }
}

/* One event for the viewer (after the panel declined it); false on quit. */
static bool handle_event(nc_view *v, SDL_Window *w, const SDL_Event *e, drag_state *d, bool *show_panel,
                         bool *minimized)
{
    switch (e->type) {
    case SDL_QUIT:
        return false;
    case SDL_WINDOWEVENT:
        if (e->window.event == SDL_WINDOWEVENT_SIZE_CHANGED) {
            int dw = 0, dh = 0;
            SDL_GL_GetDrawableSize(w, &dw, &dh);
            if (dw > 0 && dh > 0)
                nc_view_resize(v, dw, dh, false);
        } else if (e->window.event == SDL_WINDOWEVENT_MINIMIZED) {
            *minimized = true;
        } else if (e->window.event == SDL_WINDOWEVENT_RESTORED || e->window.event == SDL_WINDOWEVENT_SHOWN) {
            *minimized = false;
        }
        return true;
    case SDL_MOUSEBUTTONDOWN:
        d->shift = (SDL_GetModState() & KMOD_SHIFT) != 0;
        d->left = e->button.button == SDL_BUTTON_LEFT;
        d->middle = e->button.button == SDL_BUTTON_MIDDLE;
        d->moved = false;
        d->x0 = e->button.x;
        d->y0 = e->button.y;
        d->light = UINT32_MAX;
        if (d->left && !d->shift) {
            int32_t fx, fy;
            to_frame(w, v, e->button.x, e->button.y, &fx, &fy);
            d->light = nc_view_light_at(v, (float)fx + 0.5f, (float)fy + 0.5f);
        }
        return true;
    case SDL_MOUSEBUTTONUP:
        if (d->left && !d->moved) {
            int32_t fx, fy;
            to_frame(w, v, e->button.x, e->button.y, &fx, &fy);
            nc_view_pick(v, fx, fy);
        }
        d->left = d->middle = false;
        return true;
    case SDL_MOUSEMOTION:
        if (!d->left && !d->middle)
            return true;
        if (abs(e->motion.x - d->x0) + abs(e->motion.y - d->y0) > 2)
            d->moved = true;
        if (!d->moved)
            return true;
        if (d->left && d->light != UINT32_MAX) {
            int32_t fx, fy;
            to_frame(w, v, e->motion.x, e->motion.y, &fx, &fy);
            nc_view_light_drag(v, d->light, (float)fx + 0.5f, (float)fy + 0.5f);
        } else if (d->middle || d->shift)
            nc_view_pan(v, (float)e->motion.xrel, (float)e->motion.yrel);
        else
            nc_view_orbit(v, -0.3f * (float)e->motion.xrel, 0.3f * (float)e->motion.yrel);
        return true;
    case SDL_MOUSEWHEEL:
        nc_view_zoom(v, powf(0.9f, (float)e->wheel.y));
        return true;
    case SDL_KEYDOWN:
        if (e->key.keysym.sym == SDLK_q || e->key.keysym.sym == SDLK_ESCAPE)
            return false;
        if (e->key.keysym.sym == SDLK_h)
            *show_panel = !*show_panel;
        else if (key_name(e->key.keysym.sym))
            nc_view_key(v, key_name(e->key.keysym.sym), false);
        return true;
    default:
        return true;
    }
}

static void print_json(const nc_view *v, double seconds)
{
    printf("{\"frames\":%llu,\"rendered\":%llu,\"seconds\":%.6g,\"fps\":%.4g,\"method\":\"%s\",\"width\":%d,"
           "\"height\":%d,\"time\":%.9g",
           (unsigned long long)v->frames, (unsigned long long)v->rendered, seconds,
           seconds > 0 ? (double)v->frames / seconds : 0.0, nacre_method_name(v->fs.render.method),
           v->fs.render.width, v->fs.render.height, v->fs.time);
    for (int i = 0; i < NACRE_STAGE_COUNT; i++)
        printf(",\"%s_us\":%llu", nacre_stage_name((nacre_stage)i), (unsigned long long)v->stage_us[i]);
    printf(",\"stage_runs\":{");
    for (int i = 0, n = 0; i < NACRE_STAGE_COUNT; i++)
        if (v->stage_runs[i])
            printf("%s\"%s\":%llu", n++ ? "," : "", nacre_stage_name((nacre_stage)i),
                   (unsigned long long)v->stage_runs[i]);
    const float *p = v->camera.position, *t = v->camera.target;
    printf("},\"camera\":{\"position\":[%.9g,%.9g,%.9g],\"target\":[%.9g,%.9g,%.9g]}", p[0], p[1], p[2], t[0], t[1],
           t[2]);
    if (v->object != UINT32_MAX)
        printf(",\"selected_object\":%u", v->object);
    float hx, hy;
    if (nc_view_light_handle_pixel(v, v->light, &hx, &hy))
        printf(",\"selected_light\":%u,\"light_handle\":[%.1f,%.1f]", v->light, hx, hy);
    if (v->mean_rel_err >= 0)
        printf(",\"mean_rel_err\":%.6g,\"truth_spp\":%u", v->mean_rel_err, v->truth_stats.spp_done);
    printf("}\n");
}

/* The frame loop: events, script, render, display. Returns the exit status. */
static int run(nc_view *v, nc_script *script, const view_options *o, SDL_Window *w)
{
    uint8_t *rgba = NULL;
    size_t rgba_size = 0;
    drag_state drag = {0};
    drag.light = UINT32_MAX;
    bool show_panel = true, minimized = false, running = true;
    char err[512];
    uint64_t start = nc_tool_now_us(), last = start;
    for (long frame = 0; running && (!o->frames || frame < o->frames); frame++) {
        SDL_Event e;
        bool idle = !o->frames && !v->need_render && !v->playing && v->mode == NC_VIEW_NORMAL &&
                    v->fs.render.method != NACRE_METHOD_PATHTRACE;
        /* Idle or minimized: sleep until an event instead of spinning. */
        if ((idle || minimized) && !o->frames && SDL_WaitEventTimeout(&e, 250)) {
            if (!nc_panel_event(&e))
                running = handle_event(v, w, &e, &drag, &show_panel, &minimized);
        }
        while (running && SDL_PollEvent(&e))
            if (!nc_panel_event(&e))
                running = handle_event(v, w, &e, &drag, &show_panel, &minimized);
        if (script && !nc_script_run(script, v, frame, err, sizeof(err)))
            return nc_tool_error("%s", err);
        if (minimized && !o->frames)
            continue;
        uint64_t now = nc_tool_now_us();
        uint64_t rendered = v->rendered;
        if (!nc_view_frame(v, (double)(now - last) * 1e-6) && o->frames)
            return nc_tool_error("%s", v->message);
        if (v->rendered != rendered) {
            uint64_t t = nc_tool_now_us();
            double inst = 1e6 / (double)(t - last > 0 ? t - last : 1);
            v->fps = v->fps > 0 ? 0.9 * v->fps + 0.1 * inst : inst;
        }
        last = now;
        size_t need = (size_t)v->fs.render.width * (size_t)v->fs.render.height * 4;
        if (need > rgba_size) {
            uint8_t *grown = realloc(rgba, need);
            if (!grown) {
                free(rgba);
                return nc_tool_error("view: out of memory for the %dx%d display", v->fs.render.width,
                                     v->fs.render.height);
            }
            rgba = grown;
            rgba_size = need;
        }
        nc_view_display(v, rgba);
        if (o->window_shot && o->frames && frame == o->frames - 1)
            nc_panel_capture(o->window_shot);
        nc_panel_draw(v, rgba, v->fs.render.width, v->fs.render.height, show_panel);
    }
    free(rgba);
    double seconds = (double)(nc_tool_now_us() - start) * 1e-6;
    if (o->screenshot && !nc_view_save_image(v, o->screenshot))
        return nc_tool_error("view: --screenshot: %s", v->message);
    if (o->save_scene && !nc_view_save_scene(v, o->save_scene))
        return nc_tool_error("view: --save-scene: %s", v->message);
    if (o->frames)
        print_json(v, seconds);
    return 0;
}

/* SDL, the window and its GL context around run(). */
static int with_window(nc_view *v, nc_script *script, const view_options *o)
{
    if (SDL_Init(SDL_INIT_VIDEO) != 0)
        return nc_tool_error("view: cannot open a window: %s (no display? run under xvfb-run)", SDL_GetError());
    SDL_GL_SetAttribute(SDL_GL_DOUBLEBUFFER, 1);
    Uint32 flags = SDL_WINDOW_OPENGL | SDL_WINDOW_ALLOW_HIGHDPI | (o->frames ? 0 : SDL_WINDOW_RESIZABLE);
    char title[300];
    snprintf(title, sizeof(title), "nacre view - %s", o->scene ? o->scene : "demo");
    SDL_Window *w = SDL_CreateWindow(title, SDL_WINDOWPOS_CENTERED, SDL_WINDOWPOS_CENTERED, (int)o->width,
                                     (int)o->height, flags);
    SDL_GLContext gl = w ? SDL_GL_CreateContext(w) : NULL;
    int rc;
    char err[256];
    if (!w || !gl) {
        rc = nc_tool_error("view: cannot open an OpenGL window: %s", SDL_GetError());
    } else if (!nc_panel_init(w, gl, err, sizeof(err))) {
        rc = nc_tool_error("view: %s", err);
    } else {
        /* Headless runs measure the renderer, not the display's refresh. */
        SDL_GL_SetSwapInterval(o->frames ? 0 : 1);
        rc = run(v, script, o, w);
        nc_panel_shutdown();
    }
    if (gl)
        SDL_GL_DeleteContext(gl);
    if (w)
        SDL_DestroyWindow(w);
    SDL_Quit();
    return rc;
}

int nc_cli_view(int argc, char **argv)
{
    view_options o;
    bool done;
    int code = parse_options(argc, argv, &o, &done);
    if (done || code)
        return code;
    nacre_context *ctx = nc_tool_context((int)o.threads);
    if (!ctx)
        return NC_TOOL_EXIT_BAD;
    nc_view v;
    memset(&v, 0, sizeof(v));
    nc_script script = {0};
    char err[512];
    int rc = NC_TOOL_EXIT_BAD;
    if (!open_view(&v, ctx, &o))
        goto out;
    if (o.script && (!nc_script_load(o.script, &script, err, sizeof(err)) ||
                     !nc_script_check(&script, &v, o.frames, err, sizeof(err)))) {
        nc_tool_error("%s", err);
        goto out;
    }
    rc = with_window(&v, o.script ? &script : NULL, &o);
out:
    nc_script_free(&script);
    nc_view_free(&v);
    nacre_context_destroy(ctx);
    return rc;
}
