/*
 * script.c: reading and replaying `nacre view --script FILE`.
 *
 * Grammar, one event per line (blank lines and lines starting with '#' are ignored; tokens are
 * separated by spaces or tabs):
 *
 *   FRAME orbit DYAW DPITCH        turn the camera about its target (degrees)
 *   FRAME pan DX DY                move camera and target by DX, DY pixels of the image
 *   FRAME zoom FACTOR              distance to the target times FACTOR (> 0)
 *   FRAME light I direction X Y Z  light I (0-based): direction the light travels
 *   FRAME light I position X Y Z   light I: position (point and spot lights)
 *   FRAME light I strength R G B   light I: irradiance or intensity
 *   FRAME material M preset NAME   material M (0-based): a measured preset (jade, marble, ...)
 *   FRAME material M FIELD VALUE   FIELD: sigma_a_scale, sigma_s_scale, g, eta, layerK_depth (layer
 *                                  K from the surface, 0-based, scene units), multiple_scattering
 *                                  0|1 (layered materials: the diffusion under the march)
 *   FRAME method NAME              phong, diffusion, layered, pathtrace
 *   FRAME voxel_res N              diffusion voxel resolution (2..512)
 *   FRAME solver NAME              multigrid, seed
 *   FRAME set NAME VALUE           a render setting by its scene-file name (nc_view_render_setting):
 *                                  layered_samples N, layered_epsilon E, layered_half_res T,
 *                                  layered_integration
 *                                  analytic|samples, volumetrics off|froxel|raymarch,
 *                                  froxel_width|froxel_height|froxel_slices N, raymarch_steps N,
 *                                  shadow_steps N, froxel_temporal A, particles billboards|sprites|voxel,
 *                                  single_scattering auto|on|off
 *   FRAME exposure EV              display and PNG exposure (stops)
 *   FRAME time T                   timeline time (seconds, deformers)
 *   FRAME play | pause             timeline playback (1/30 s per frame in headless runs)
 *   FRAME view normal|wipe|error   what the window shows (wipe and error: against the path tracer)
 *   FRAME wipe X                   wipe line at fraction X of the width (0..1)
 *   FRAME pick X Y                 select the light whose handle is at pixel (X, Y), else the object
 *                                  under it in the last frame
 *   FRAME drag X0 Y0 X1 Y1         a left drag in the frame: from a light's handle it moves the
 *                                  light, elsewhere it orbits (pixels)
 *   FRAME key K                    a key as in the window (see nacre view --help)
 *   FRAME resize W H               new image (and window) size
 *
 * FRAME is an integer >= 0: the event applies before that frame renders. Events of the same
 * frame apply in file order.
 */
#include "script.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static bool fail(char *err, size_t size, const nc_script *s, int line, const char *fmt, ...)
{
    int n = snprintf(err, size, "%s:%d: ", s->path, line);
    if (n < 0 || (size_t)n >= size)
        return false;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err + n, size - (size_t)n, fmt, ap);
    va_end(ap);
    return false;
}

static bool parse_long(const char *t, long *out)
{
    char *end = NULL;
    errno = 0;
    long x = strtol(t, &end, 10);
    if (errno || end == t || *end)
        return false;
    *out = x;
    return true;
}

static bool parse_float(const char *t, float *out)
{
    char *end = NULL;
    errno = 0;
    float x = strtof(t, &end);
    if (errno || end == t || *end || !isfinite(x))
        return false;
    *out = x;
    return true;
}

static char *read_all(const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    size_t cap = 4096, n = 0;
    char *buf = malloc(cap);
    while (buf) {
        n += fread(buf + n, 1, cap - n - 1, f);
        if (n < cap - 1)
            break;
        char *grown = realloc(buf, cap * 2);
        if (!grown) {
            free(buf);
            buf = NULL;
            break;
        }
        buf = grown;
        cap *= 2;
    }
    bool bad = ferror(f);
    fclose(f);
    if (buf && bad) {
        free(buf);
        return NULL;
    }
    if (buf)
        buf[n] = '\0';
    return buf;
}

static int by_frame(const void *a, const void *b)
{
    const nc_script_event *x = a, *y = b;
    if (x->frame != y->frame)
        return x->frame < y->frame ? -1 : 1;
    return (x->line > y->line) - (x->line < y->line); /* file order within a frame */
}

bool nc_script_load(const char *path, nc_script *s, char *err, size_t size)
{
    memset(s, 0, sizeof(*s));
    s->path = strdup(path);
    s->text = read_all(path);
    if (!s->path || !s->text) {
        snprintf(err, size, "%s: cannot read the script (%s)", path, strerror(errno ? errno : EIO));
        return false;
    }
    size_t cap = 0;
    int line = 0;
    for (char *p = s->text; *p;) {
        char *eol = strchr(p, '\n');
        if (eol)
            *eol = '\0';
        line++;
        nc_script_event ev = {.line = line};
        char *save = NULL;
        for (char *tok = strtok_r(p, " \t\r", &save); tok; tok = strtok_r(NULL, " \t\r", &save)) {
            if (ev.argc == 0 && tok[0] == '#')
                break;
            if (ev.argc == NC_SCRIPT_MAX_ARGS + 1)
                return fail(err, size, s, line, "too many words (at most a frame, a command and %d arguments)",
                            NC_SCRIPT_MAX_ARGS - 1);
            if (ev.argc == 0) {
                if (!parse_long(tok, &ev.frame) || ev.frame < 0)
                    return fail(err, size, s, line, "'%s': expected a frame number >= 0 first", tok);
            } else {
                ev.argv[ev.argc - 1] = tok;
            }
            ev.argc++;
        }
        if (ev.argc == 1)
            return fail(err, size, s, line, "frame %ld: missing the command", ev.frame);
        if (ev.argc > 1) {
            ev.argc--; /* count the command and its arguments */
            if (s->count == cap) {
                cap = cap ? cap * 2 : 16;
                nc_script_event *grown = realloc(s->events, cap * sizeof(*grown));
                if (!grown)
                    return fail(err, size, s, line, "out of memory");
                s->events = grown;
            }
            s->events[s->count++] = ev;
        }
        if (!eol)
            break;
        p = eol + 1;
    }
    if (s->count)
        qsort(s->events, s->count, sizeof(*s->events), by_frame);
    return true;
}

/* The arguments as numbers: argv[first..first+n) into x; false names the offender in err. */
static bool numbers(const nc_script *s, const nc_script_event *ev, int first, int n, float *x, char *err,
                    size_t size)
{
    if (ev->argc != first + n)
        return fail(err, size, s, ev->line, "%s: expected %d number%s after '%s'", ev->argv[0], n, n == 1 ? "" : "s",
                    ev->argv[first - 1]);
    for (int i = 0; i < n; i++)
        if (!parse_float(ev->argv[first + i], &x[i]))
            return fail(err, size, s, ev->line, "%s: '%s' is not a finite number", ev->argv[0], ev->argv[first + i]);
    return true;
}

static bool index_arg(const nc_script *s, const nc_script_event *ev, uint32_t *out, char *err, size_t size)
{
    long i;
    if (ev->argc < 2 || !parse_long(ev->argv[1], &i) || i < 0 || i > 1000000)
        return fail(err, size, s, ev->line, "%s: expected an index (0-based) after '%s'", ev->argv[0], ev->argv[0]);
    *out = (uint32_t)i;
    return true;
}

/* light I direction|position|strength X Y Z; material M preset NAME | material M FIELD VALUE */
static bool run_element(const nc_script *s, const nc_script_event *ev, nc_view *v, bool check, char *err,
                        size_t size)
{
    uint32_t i = 0;
    float x[3];
    if (!index_arg(s, ev, &i, err, size))
        return false;
    if (ev->argc < 3)
        return fail(err, size, s, ev->line, "%s %u: missing what to change", ev->argv[0], i);
    const char *what = ev->argv[2];
    bool ok;
    if (strcmp(ev->argv[0], "light") == 0) {
        if (strcmp(what, "direction") && strcmp(what, "position") && strcmp(what, "strength"))
            return fail(err, size, s, ev->line, "light: '%s': expected direction, position or strength", what);
        if (!numbers(s, ev, 3, 3, x, err, size))
            return false;
        ok = what[0] == 'd'   ? nc_view_light_direction(v, i, x, check)
             : what[0] == 'p' ? nc_view_light_position(v, i, x, check)
                              : nc_view_light_strength(v, i, x, check);
    } else if (strcmp(what, "preset") == 0) {
        if (ev->argc != 4)
            return fail(err, size, s, ev->line, "material %u preset: expected one preset name", i);
        ok = nc_view_material_preset(v, i, ev->argv[3], check);
    } else {
        if (!numbers(s, ev, 3, 1, x, err, size))
            return false;
        ok = nc_view_material_field(v, i, what, x[0], check);
    }
    return ok ? true : fail(err, size, s, ev->line, "%s", v->message);
}

/* One event: validated (check) or applied. */
static bool run_event(const nc_script *s, const nc_script_event *ev, nc_view *v, bool check, char *err,
                      size_t size)
{
    const char *cmd = ev->argv[0];
    float x[3];
    if (strcmp(cmd, "orbit") == 0 || strcmp(cmd, "pan") == 0) {
        if (!numbers(s, ev, 1, 2, x, err, size))
            return false;
        if (!check)
            (cmd[0] == 'o' ? nc_view_orbit : nc_view_pan)(v, x[0], x[1]);
        return true;
    }
    if (strcmp(cmd, "zoom") == 0 || strcmp(cmd, "exposure") == 0 || strcmp(cmd, "time") == 0 ||
        strcmp(cmd, "wipe") == 0) {
        if (!numbers(s, ev, 1, 1, x, err, size))
            return false;
        if (cmd[0] == 'z' && !(x[0] > 0.0f))
            return fail(err, size, s, ev->line, "zoom: the factor must be > 0");
        if (cmd[0] == 'w' && !(x[0] >= 0.0f && x[0] <= 1.0f))
            return fail(err, size, s, ev->line, "wipe: the position must be in 0..1");
        if (check)
            return true;
        if (cmd[0] == 'z')
            nc_view_zoom(v, x[0]);
        else if (cmd[0] == 'e')
            v->fs.exposure = x[0], v->need_render = true;
        else if (cmd[0] == 't')
            nc_view_set_time(v, x[0]);
        else
            v->wipe = x[0], v->need_render = true;
        return true;
    }
    if (strcmp(cmd, "light") == 0 || strcmp(cmd, "material") == 0)
        return run_element(s, ev, v, check, err, size);
    if (strcmp(cmd, "drag") == 0) {
        float p[4];
        if (!numbers(s, ev, 1, 4, p, err, size))
            return false;
        if (!check)
            nc_view_drag(v, p[0], p[1], p[2], p[3]);
        return true;
    }
    if (strcmp(cmd, "play") == 0 || strcmp(cmd, "pause") == 0) {
        if (ev->argc != 1)
            return fail(err, size, s, ev->line, "%s: takes no arguments", cmd);
        if (!check)
            v->playing = cmd[1] == 'l';
        return true;
    }
    if (strcmp(cmd, "set") == 0) {
        if (ev->argc != 3)
            return fail(err, size, s, ev->line, "set: expected a setting and its value (set volumetrics froxel)");
        return nc_view_render_setting(v, ev->argv[1], ev->argv[2], check) ? true
                                                                          : fail(err, size, s, ev->line, "%s", v->message);
    }
    static const char *const one_arg[] = {"method", "solver", "voxel_res", "view", "key", "pick", "resize", NULL};
    bool known = false;
    for (int i = 0; one_arg[i]; i++)
        known = known || strcmp(cmd, one_arg[i]) == 0;
    if (!known)
        return fail(err, size, s, ev->line,
                    "unknown command '%s' (orbit, pan, zoom, light, material, method, voxel_res, solver, set, "
                    "exposure, time, play, pause, view, wipe, pick, drag, key, resize)",
                    cmd);
    if (ev->argc != 2 && strcmp(cmd, "pick") && strcmp(cmd, "resize"))
        return fail(err, size, s, ev->line, "%s: expected one argument", cmd);
    bool ok = true;
    if (strcmp(cmd, "method") == 0) {
        nacre_method m;
        if (!nacre_method_from_name(ev->argv[1], &m))
            return fail(err, size, s, ev->line, "method '%s': expected phong, diffusion, layered or pathtrace",
                        ev->argv[1]);
        ok = nc_view_set_method(v, m, check);
    } else if (strcmp(cmd, "solver") == 0) {
        nacre_diffusion_solver sv;
        if (!nacre_solver_from_name(ev->argv[1], &sv))
            return fail(err, size, s, ev->line, "solver '%s': expected multigrid or seed", ev->argv[1]);
        ok = check || nc_view_solver(v, sv);
    } else if (strcmp(cmd, "voxel_res") == 0) {
        long n;
        if (!parse_long(ev->argv[1], &n) || n < 0 || n > 100000)
            return fail(err, size, s, ev->line, "voxel_res: '%s' is not a resolution", ev->argv[1]);
        ok = nc_view_voxel_resolution(v, (uint32_t)n, check);
    } else if (strcmp(cmd, "view") == 0) {
        static const char *const modes[] = {"normal", "wipe", "error"};
        int m = -1;
        for (int i = 0; i < 3; i++)
            if (strcmp(ev->argv[1], modes[i]) == 0)
                m = i;
        if (m < 0)
            return fail(err, size, s, ev->line, "view '%s': expected normal, wipe or error", ev->argv[1]);
        if (!check)
            nc_view_set_mode(v, (nc_view_mode)m);
    } else if (strcmp(cmd, "key") == 0) {
        ok = nc_view_key(v, ev->argv[1], check);
    } else if (strcmp(cmd, "pick") == 0 || strcmp(cmd, "resize") == 0) {
        long a, b;
        if (ev->argc != 3 || !parse_long(ev->argv[1], &a) || !parse_long(ev->argv[2], &b) || a < 0 || b < 0 ||
            a > 16384 || b > 16384)
            return fail(err, size, s, ev->line, "%s: expected two integers (pixels) in 0..16384", cmd);
        if (cmd[0] == 'r')
            ok = nc_view_resize(v, (int32_t)a, (int32_t)b, check);
        else if (!check)
            ok = nc_view_pick(v, (int32_t)a, (int32_t)b);
    }
    return ok ? true : fail(err, size, s, ev->line, "%s", v->message);
}

bool nc_script_check(nc_script *s, nc_view *v, long frames, char *err, size_t size)
{
    for (size_t i = 0; i < s->count; i++) {
        const nc_script_event *ev = &s->events[i];
        if (frames > 0 && ev->frame >= frames)
            return fail(err, size, s, ev->line, "frame %ld is past the run's last frame (%ld with --frames %ld)",
                        ev->frame, frames - 1, frames);
        if (!run_event(s, ev, v, true, err, size))
            return false;
    }
    return true;
}

bool nc_script_run(nc_script *s, nc_view *v, long frame, char *err, size_t size)
{
    while (s->next < s->count && s->events[s->next].frame <= frame) {
        const nc_script_event *ev = &s->events[s->next++];
        if (ev->frame == frame && !run_event(s, ev, v, false, err, size))
            return false;
    }
    return true;
}

void nc_script_free(nc_script *s)
{
    free(s->path);
    free(s->text);
    free(s->events);
    memset(s, 0, sizeof(*s));
}
