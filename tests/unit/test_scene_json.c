/*
 * test_scene_json.c: the JSON scene loader. A scene using every feature loads into the right
 * scene contents; each kind of bad input fails with the expected code and a one-line message
 * naming the file and the field path, leaves the output NULL and frees everything (checked with
 * a counting allocator, and by ASan for cJSON's own allocations); allocation failures at every
 * step are survived; mesh paths are relative to the scene file; every example scene loads.
 */
#include "scene/scene.h"
#include "io/image_private.h"
#include "test_util.h"

#include <dirent.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define EXAMPLES NACRE_SOURCE_DIR "/examples"
#define TMP NACRE_TEST_TMP "/scene_json"

/* Counts live allocations made through the context, and can fail the n-th one. */
typedef struct counter {
    long live;
    long made;
    long fail_at; /* -1: never */
} counter;

static void *count_alloc(size_t size, void *user)
{
    counter *c = user;
    if (c->fail_at >= 0 && c->made >= c->fail_at)
        return NULL;
    c->made++;
    void *p = malloc(size);
    if (p)
        c->live++;
    return p;
}

static void count_free(void *ptr, void *user)
{
    if (!ptr)
        return;
    ((counter *)user)->live--;
    free(ptr);
}

static nacre_context *make_context(counter *c)
{
    c->live = c->made = 0;
    c->fail_at = -1;
    nacre_context_desc desc = {{count_alloc, count_free, c}, 1, NULL, NULL, 0};
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(&desc, &ctx) == NACRE_OK);
    return ctx;
}

static nacre_result load(nacre_context *ctx, const char *json, nacre_scene **scene,
                         nacre_scene_file_settings *rs)
{
    return nacre_scene_load_json(ctx, json, strlen(json), "t.json", EXAMPLES, scene, rs);
}

static void write_text(const char *path, const char *text)
{
    FILE *f = fopen(path, "wb");
    CHECK(f != NULL);
    if (!f)
        return;
    fputs(text, f);
    fclose(f);
}

/* ------------------------------------------------------------------------------------------ */

static const char full_scene[] =
    "{\n"
    "  \"_comment\": \"every feature\",\n"
    "  \"units\": \"cm\",\n"
    "  \"render\": {\"method\": \"phong\", \"width\": 64, \"height\": 48, \"exposure\": 0.5,\n"
    "             \"shadow_map_size\": 256, \"pcf_radius\": 2, \"shadow_bias\": 0.5, \"spp\": 16,\n"
    "             \"seed\": 7, \"time\": 1.5},\n"
    "  \"camera\": {\"type\": \"orthographic\", \"position\": [0, 5, 20], \"target\": [0, 1, 0],\n"
    "             \"up\": [0, 1, 0], \"fov\": 30, \"height\": 12, \"near\": 0.5, \"far\": 100},\n"
    "  \"environment\": [0.1, 0.2, 0.3],\n"
    "  \"materials\": {\n"
    "    \"ground\": {\"type\": \"opaque\", \"diffuse\": 0.5, \"specular\": [0.1, 0.2, 0.3], \"shininess\": 8},\n"
    "    \"wax\": {\"type\": \"translucent\", \"sigma_a\": [0.1, 0.2, 0.3], \"sigma_s\": 2, \"g\": 0.25, \"eta\": 1.4,\n"
    "             \"specular\": 0.05, \"shininess\": 32},\n"
    "    \"marble\": {\"preset\": \"marble\"},\n"
    "    \"milk\": {\"preset\": \"skimmilk\", \"type\": \"translucent\", \"g\": 0.5, \"sigma_s\": [1, 2, 3]}\n"
    "  },\n"
    "  \"lights\": [\n"
    "    {\"type\": \"directional\", \"direction\": [0, -2, 0], \"strength\": [1, 2, 3], \"angular_radius\": 0.5,\n"
    "     \"shadows\": false},\n"
    "    {\"type\": \"point\", \"position\": [1, 2, 3], \"intensity\": 100, \"radius\": 0.25},\n"
    "    {\"type\": \"spot\", \"position\": [0, 10, 0], \"direction\": [0, -1, 0], \"intensity\": [5, 6, 7],\n"
    "     \"inner_angle\": 10, \"outer_angle\": 40, \"falloff\": \"cycles\", \"_note\": \"skipped\"}\n"
    "  ],\n"
    "  \"objects\": [\n"
    "    {\"name\": \"monkey\", \"mesh\": \"meshes/suzanne.ply\", \"material\": \"marble\",\n"
    "     \"transform\": {\"translate\": [1, 2, 3], \"rotate\": [10, 20, 30], \"scale\": [1, 2, 3]}},\n"
    "    {\"name\": \"monkey 2\", \"mesh\": \"meshes/suzanne.ply\", \"material\": \"milk\", \"transform\": {\"scale\": 2}},\n"
    "    {\"shape\": {\"type\": \"sphere\", \"radius\": 2, \"segments\": 16, \"rings\": 8}, \"material\": \"wax\",\n"
    "     \"deformers\": [{\"type\": \"scale\", \"scale\": [1, 2, 3], \"center\": [0, 1, 0], \"scale_rate\": 0.5},\n"
    "                   {\"type\": \"twist\", \"axis\": \"x\", \"angle\": 90, \"angle_rate\": 10, \"length\": 4,\n"
    "                    \"center\": [0, -2, 0]},\n"
    "                   {\"type\": \"bend\", \"axis\": [0, 0, 2], \"direction\": \"y\", \"angle\": 45, \"length\": 3}]},\n"
    "    {\"shape\": {\"type\": \"sphere\", \"radius\": 2, \"segments\": 16, \"rings\": 8}, \"material\": \"wax\"},\n"
    "    {\"shape\": {\"type\": \"box\", \"size\": [1, 2, 3], \"segments\": 2}, \"material\": \"ground\",\n"
    "     \"shadows\": false, \"double_sided\": true},\n"
    "    {\"shape\": {\"type\": \"plane\", \"size\": [30, 0, 40]}, \"material\": \"ground\"},\n"
    "    {\"shape\": {\"type\": \"torus\", \"radius\": 3, \"minor_radius\": 1, \"segments\": 12, \"rings\": 6},\n"
    "     \"material\": \"wax\"}\n"
    "  ]\n"
    "}\n";

static void test_full_scene(void)
{
    counter c;
    nacre_context *ctx = make_context(&c);
    long baseline = c.live;
    nacre_scene *s = NULL;
    nacre_scene_file_settings rs;
    memset(&rs, 0xff, sizeof(rs));
    nacre_result r = load(ctx, full_scene, &s, &rs);
    CHECK(r == NACRE_OK);
    if (r != NACRE_OK) {
        printf("  full scene: %s\n", nacre_context_last_error(ctx));
        nacre_context_destroy(ctx);
        return;
    }
    CHECK(rs.render.method == NACRE_METHOD_PHONG);
    CHECK(rs.render.width == 64 && rs.render.height == 48);
    CHECK_NEAR(rs.exposure, 0.5, 0);
    CHECK(rs.render.shadow.map_size == 256);
    CHECK_NEAR(rs.render.shadow.pcf_radius, 2, 0);
    CHECK_NEAR(rs.render.shadow.bias, 0.5, 0);
    CHECK(rs.render.pathtrace.spp == 16 && rs.render.pathtrace.seed == 7);

    CHECK_NEAR(s->unit_mm, 10, 0);
    CHECK_NEAR(s->environment[0], 0.1, 1e-7);
    CHECK_NEAR(s->environment[2], 0.3, 1e-7);
    CHECK(s->has_camera);
    CHECK(s->camera.projection == NACRE_ORTHOGRAPHIC);
    CHECK_NEAR(s->camera.position[2], 20, 0);
    CHECK_NEAR(s->camera.target[1], 1, 0);
    CHECK_NEAR(s->camera.fov_y, 30, 0);
    CHECK_NEAR(s->camera.ortho_height, 12, 0);
    CHECK_NEAR(s->camera.near_clip, 0.5, 0);
    CHECK_NEAR(s->camera.far_clip, 100, 0);

    /* Materials in file order. */
    CHECK(s->material_count == 4);
    const nacre_material_desc *ground = &s->materials[0], *wax = &s->materials[1];
    const nacre_material_desc *marble = &s->materials[2], *milk = &s->materials[3];
    CHECK(ground->type == NACRE_MATERIAL_OPAQUE);
    CHECK_NEAR(ground->diffuse[1], 0.5, 0);
    CHECK_NEAR(ground->specular[2], 0.3, 1e-7);
    CHECK_NEAR(ground->shininess, 8, 0);
    CHECK(wax->type == NACRE_MATERIAL_TRANSLUCENT);
    CHECK_NEAR(wax->sigma_a[1], 0.2, 1e-7);
    CHECK_NEAR(wax->sigma_s[2], 2, 0); /* written in the file: per scene unit as is */
    CHECK_NEAR(wax->g, 0.25, 0);
    CHECK_NEAR(wax->eta, 1.4, 1e-6);
    CHECK_NEAR(wax->specular[0], 0.05, 1e-7);
    CHECK_NEAR(wax->shininess, 32, 0);
    /* Presets are per mm; this scene's unit is the centimetre. */
    nacre_material_desc ref;
    CHECK(nacre_material_preset("marble", &ref));
    CHECK(marble->type == NACRE_MATERIAL_TRANSLUCENT);
    for (int i = 0; i < 3; i++) {
        CHECK_NEAR(marble->sigma_a[i], ref.sigma_a[i] * 10, 1e-5);
        CHECK_NEAR(marble->sigma_s[i], ref.sigma_s[i] * 10, 1e-5);
    }
    CHECK_NEAR(marble->eta, ref.eta, 0);
    CHECK(nacre_material_preset("skimmilk", &ref));
    CHECK_NEAR(milk->sigma_a[2], ref.sigma_a[2] * 10, 1e-5);
    CHECK_NEAR(milk->sigma_s[0], 1, 0); /* override, not scaled */
    CHECK_NEAR(milk->sigma_s[2], 3, 0);
    CHECK_NEAR(milk->g, 0.5, 0);

    CHECK(nacre_scene_light_count(s) == 3);
    const nacre_light_desc *sun = &s->lights[0].desc, *point = &s->lights[1].desc;
    const nacre_light_desc *spot = &s->lights[2].desc;
    CHECK(sun->type == NACRE_LIGHT_DIRECTIONAL);
    CHECK_NEAR(sun->direction[1], -1, 1e-6);
    CHECK_NEAR(sun->strength[2], 3, 0);
    CHECK_NEAR(sun->angular_radius, 0.5, 0);
    CHECK(!sun->cast_shadows);
    CHECK(point->type == NACRE_LIGHT_POINT);
    CHECK_NEAR(point->position[2], 3, 0);
    CHECK_NEAR(point->strength[1], 100, 0);
    CHECK_NEAR(point->radius, 0.25, 0);
    CHECK(point->cast_shadows);
    CHECK(spot->type == NACRE_LIGHT_SPOT);
    CHECK_NEAR(spot->inner_angle, 10, 0);
    CHECK_NEAR(spot->outer_angle, 40, 0);
    CHECK(spot->falloff == NACRE_SPOT_FALLOFF_CYCLES);
    CHECK(point->falloff == NACRE_SPOT_FALLOFF_SMOOTH);
    CHECK_NEAR(spot->strength[0], 5, 0);

    /* Suzanne is loaded once for two objects, the identical spheres share one mesh. */
    CHECK(nacre_scene_object_count(s) == 7);
    CHECK(s->mesh_count == 5);
    const nc_object_rec *o = s->objects;
    CHECK(o[0].name && strcmp(o[0].name, "monkey") == 0);
    CHECK(o[1].name && strcmp(o[1].name, "monkey 2") == 0);
    CHECK(o[2].name == NULL);
    CHECK(o[0].desc.mesh.id == o[1].desc.mesh.id);
    CHECK(o[2].desc.mesh.id == o[3].desc.mesh.id);
    CHECK(o[2].desc.mesh.id != o[0].desc.mesh.id);
    CHECK(o[4].desc.mesh.id != o[2].desc.mesh.id);
    const nacre_mesh_data *monkey = nacre_scene_mesh_data(s, o[0].desc.mesh);
    CHECK(monkey && monkey->triangle_count == 968);
    CHECK(o[0].desc.material.id == 3 && o[1].desc.material.id == 4 && o[2].desc.material.id == 2);
    CHECK_NEAR(o[0].desc.transform.translate[1], 2, 0);
    CHECK_NEAR(o[0].desc.transform.rotate[2], 30, 0);
    CHECK_NEAR(o[0].desc.transform.scale[2], 3, 0);
    CHECK_NEAR(o[1].desc.transform.scale[0], 2, 0);
    CHECK_NEAR(o[1].desc.transform.scale[2], 2, 0);
    CHECK(o[2].desc.deformer_count == 3);
    const nacre_deformer *d = o[2].desc.deformers;
    CHECK(d[0].type == NACRE_DEFORM_SCALE);
    CHECK_NEAR(d[0].scale[1], 2, 0);
    CHECK_NEAR(d[0].center[1], 1, 0);
    CHECK_NEAR(d[0].scale_rate[2], 0.5, 0);
    CHECK(d[1].type == NACRE_DEFORM_TWIST);
    CHECK_NEAR(d[1].axis[0], 1, 0);
    CHECK_NEAR(d[1].axis[1], 0, 0);
    CHECK_NEAR(d[1].angle, 90, 0);
    CHECK_NEAR(d[1].angle_rate, 10, 0);
    CHECK_NEAR(d[1].length, 4, 0);
    CHECK_NEAR(d[1].center[1], -2, 0);
    CHECK(d[2].type == NACRE_DEFORM_BEND);
    CHECK_NEAR(d[2].axis[2], 2, 0);
    CHECK_NEAR(d[2].direction[1], 1, 0);
    CHECK_NEAR(d[2].angle, 45, 0);
    CHECK(o[3].desc.deformer_count == 0);
    CHECK(o[0].desc.cast_shadows && !o[0].desc.double_sided);
    CHECK(!o[4].desc.cast_shadows && o[4].desc.double_sided);
    const nacre_mesh_data *plane = nacre_scene_mesh_data(s, o[5].desc.mesh);
    CHECK(plane != NULL);
    if (plane) {
        float lo = 1e30f, hi = -1e30f;
        for (uint32_t i = 0; i < plane->vertex_count; i++) {
            lo = fminf(lo, plane->positions[3 * i + 2]);
            hi = fmaxf(hi, plane->positions[3 * i + 2]);
        }
        CHECK_NEAR(hi - lo, 40, 1e-4); /* [w, 0, d]: depth is the third entry */
    }

    CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
    nacre_scene_destroy(s);
    CHECK(c.live == baseline);

    /* settings may be NULL; a length shorter than the buffer is respected. */
    const char *text = "{\"units\": \"m\"} trailing text the length excludes";
    r = nacre_scene_load_json(ctx, text, 14, "t.json", NULL, &s, NULL);
    CHECK(r == NACRE_OK);
    CHECK(s && s->unit_mm == 1000.0f);
    nacre_scene_destroy(s);
    /* An empty object is an empty scene with default settings. */
    r = load(ctx, "{}", &s, &rs);
    CHECK(r == NACRE_OK && nacre_scene_object_count(s) == 0);
    nacre_render_settings def = nacre_render_settings_defaults();
    CHECK(rs.render.width == def.width && rs.render.height == def.height && rs.render.pathtrace.spp == def.pathtrace.spp);
    nacre_scene_destroy(s);
    CHECK(c.live == baseline);
    nacre_context_destroy(ctx);
    CHECK(c.live == 0);
}

/* ------------------------------------------------------------------------------------------ */

typedef struct bad_case {
    const char *json;
    nacre_result code;
    const char *needle;  /* must appear in the message (after "t.json") */
    const char *needle2; /* optional */
} bad_case;

#define OBJ(x) "{\"materials\": {\"m\": {\"type\": \"opaque\"}}, \"objects\": [" x "]}"
#define SPHERE "\"shape\": {\"type\": \"sphere\", \"segments\": 8, \"rings\": 4}"
#define MAT(x) "{\"materials\": {\"m\": " x "}}"
#define INVALID NACRE_ERROR_INVALID_ARGUMENT

static const bad_case bad_cases[] = {
    /* Malformed, structure. */
    {"{\"units\": \"mm\",}", NACRE_ERROR_PARSE, "t.json:1:", "malformed JSON"},
    {"", NACRE_ERROR_PARSE, "t.json:1:1: malformed JSON (unexpected end of input)", NULL},
    {"{\"units\": \"mm\"", NACRE_ERROR_PARSE, "unexpected end of input", NULL},
    {"{} {}", NACRE_ERROR_PARSE, "t.json:1:4: malformed JSON", NULL},
    {"[1, 2]", NACRE_ERROR_PARSE, "t.json: the top level must be an object, got an array", NULL},
    {"{\"unit\": \"mm\"}", INVALID, "t.json: unknown key \"unit\"", "valid keys: units, render, camera"},
    {"{\"units\": \"mm\", \"units\": \"cm\"}", NACRE_ERROR_PARSE, "t.json: duplicate key \"units\"", NULL},
    {OBJ("{\"material\": \"m\", " SPHERE ", \"transform\": {\"scale\": 1, \"scale\": 2}}"),
     NACRE_ERROR_PARSE, "t.json: objects[0].transform: duplicate key \"scale\"", NULL},
    {"{\"materials\": {\"a\": {\"type\": \"opaque\"}, \"b\": {\"type\": \"opaque\"}, \"a\": {\"type\": \"opaque\"}}}",
     NACRE_ERROR_PARSE, "materials: duplicate key \"a\"", NULL},
    /* Wrong types and lengths. */
    {"{\"render\": {\"width\": \"640\"}}", INVALID, "t.json: render.width: expected an integer, got a string", NULL},
    {"{\"camera\": {\"position\": [0, 1]}}", INVALID,
     "t.json: camera.position: expected an array of 3 numbers, got 2 elements", NULL},
    {"{\"camera\": {\"position\": [0, 1, \"2\"]}}", INVALID, "camera.position[2]: expected a number, got a string", NULL},
    {"{\"environment\": null}", INVALID, "environment: expected an array of 3 numbers or a number, got null", NULL},
    {"{\"render\": []}", INVALID, "t.json: render: expected an object, got an array", NULL},
    {"{\"lights\": {}}", INVALID, "t.json: lights: expected an array, got an object", NULL},
    {OBJ("{\"material\": \"m\", " SPHERE ", \"shadows\": 1}"), INVALID,
     "objects[0].shadows: expected true or false, got a number", NULL},
    {OBJ("{\"material\": \"m\", " SPHERE ", \"name\": \"\"}"), INVALID, "objects[0].name: must not be empty", NULL},
    /* Non-finite and out-of-range numbers. */
    {"{\"environment\": [1e999, 0, 0]}", INVALID, "t.json: environment[0]: must be non-negative and finite (got inf)", NULL},
    {"{\"environment\": [0, -1e999, 0]}", INVALID, "environment[1]: must be non-negative and finite", NULL},
    {"{\"environment\": -0.5}", INVALID, "environment: must be non-negative and finite (got -0.5)", NULL},
    {"{\"camera\": {\"position\": [1e39, 0, 0]}}", INVALID, "camera.position[0]: must be finite", NULL},
    {MAT("{\"type\": \"translucent\", \"sigma_a\": [1, -1, 1]}"), INVALID,
     "t.json: materials.m.sigma_a[1]: must be non-negative and finite (got -1)", NULL},
    {MAT("{\"type\": \"translucent\", \"sigma_s\": -2}"), INVALID, "materials.m.sigma_s: must be non-negative", NULL},
    {MAT("{\"type\": \"translucent\", \"eta\": 0}"), INVALID, "materials.m.eta: must be in [0.3, 3] (got 0)", NULL},
    /* Issue 29 item 6: eta far from any material's turned diffusion images to NaN. */
    {MAT("{\"type\": \"translucent\", \"eta\": 1e-6}"), INVALID, "materials.m.eta: must be in [0.3, 3] (got 1e-06)", NULL},
    {MAT("{\"type\": \"translucent\", \"eta\": 1e9}"), INVALID, "materials.m.eta: must be in [0.3, 3] (got 1e+09)", NULL},
    {MAT("{\"preset\": \"marble\", \"eta\": 3.5}"), INVALID, "materials.m.eta: must be in [0.3, 3] (got 3.5)", NULL},
    {MAT("{\"preset\": \"marble\", \"eta\": 0.29}"), INVALID, "materials.m.eta: must be in [0.3, 3] (got 0.29)", NULL},
    {MAT("{\"type\": \"translucent\", \"g\": 1}"), INVALID, "materials.m.g: must be in (-1, 1) (got 1)", NULL},
    {MAT("{\"type\": \"translucent\", \"g\": -1}"), INVALID, "materials.m.g: must be in (-1, 1) (got -1)", NULL},
    {MAT("{\"type\": \"opaque\", \"diffuse\": [0.5, 1.5, 0.5]}"), INVALID, "materials.m.diffuse[1]: must be in [0, 1]", NULL},
    {MAT("{\"type\": \"opaque\", \"shininess\": -1}"), INVALID, "materials.m.shininess: must be non-negative", NULL},
    {"{\"camera\": {\"fov\": 180}}", INVALID, "t.json: camera.fov: must be in (0, 180) (got 180)", NULL},
    {"{\"camera\": {\"fov\": 0}}", INVALID, "camera.fov: must be in (0, 180) (got 0)", NULL},
    {"{\"camera\": {\"height\": -2}}", INVALID, "camera.height: must be positive", NULL},
    {"{\"camera\": {\"near\": 10, \"far\": 5}}", INVALID, "camera.far: must be greater than near", NULL},
    {"{\"camera\": {\"position\": [1, 2, 3], \"target\": [1, 2, 3]}}", INVALID, "camera.target: must differ", NULL},
    {"{\"camera\": {\"position\": [0, 5, 0], \"target\": [0, 0, 0]}}", INVALID,
     "camera.up: must not be parallel to the view direction", NULL},
    {"{\"camera\": {\"up\": [0, 0, 0]}}", INVALID, "camera.up: must not be the zero vector", NULL},
    {"{\"render\": {\"width\": 0}}", INVALID, "t.json: render.width: must be an integer in 1..16384 (got 0)", NULL},
    {"{\"render\": {\"height\": 16385}}", INVALID, "render.height: must be an integer in 1..16384", NULL},
    {"{\"render\": {\"width\": 1.5}}", INVALID, "render.width: must be an integer", NULL},
    {"{\"render\": {\"width\": 1e999}}", INVALID, "render.width: must be an integer in 1..16384 (got inf)", NULL},
    {"{\"render\": {\"spp\": 0}}", INVALID, "render.spp: must be an integer", NULL},
    {"{\"render\": {\"seed\": -1}}", INVALID, "render.seed: must be an integer in 0..4294967295", NULL},
    {"{\"render\": {\"shadow_map_size\": -1}}", INVALID, "render.shadow_map_size", NULL},
    {"{\"render\": {\"pcf_radius\": -1}}", INVALID, "render.pcf_radius: must be non-negative", NULL},
    {"{\"render\": {\"time\": 1e999}}", INVALID, "render.time: must be finite", NULL},
    {"{\"units\": 0}", INVALID, "t.json: units: must be positive and finite", NULL},
    {"{\"units\": \"furlong\"}", INVALID, "units: unknown unit \"furlong\"", NULL},
    {"{\"units\": true}", INVALID, "units: expected \"mm\", \"cm\", \"m\" or a number", NULL},
    /* Unknown names. */
    {"{\"render\": {\"method\": \"raytrace\"}}", INVALID,
     "t.json: render.method: unknown render method \"raytrace\" (valid: phong, diffusion, layered, pathtrace)", NULL},
    {"{\"render\": {\"threads\": 4}}", INVALID, "t.json: render: unknown key \"threads\"", "valid keys: method, width"},
    {"{\"camera\": {\"type\": \"fisheye\"}}", INVALID, "camera.type: unknown camera type \"fisheye\"",
     "perspective, orthographic"},
    {MAT("{\"preset\": \"granite\"}"), INVALID, "t.json: materials.m.preset: unknown preset \"granite\"", "marble"},
    {MAT("{\"preset\": \"marble\", \"type\": \"opaque\"}"), INVALID, "materials.m.type: presets are translucent", NULL},
    {MAT("{\"type\": \"metal\"}"), INVALID, "materials.m.type: unknown material type \"metal\"", NULL},
    {MAT("{\"diffuse\": 0.5}"), INVALID, "materials.m: missing required key \"type\"", NULL},
    {MAT("{\"type\": \"opaque\", \"sigma_a\": 1}"), INVALID, "materials.m: unknown key \"sigma_a\"",
     "valid keys: type, diffuse, specular, shininess"},
    {MAT("{\"type\": \"translucent\", \"diffuse\": 1}"), INVALID, "materials.m: unknown key \"diffuse\"", NULL},
    {MAT("{\"type\": \"opaque\", \"colour\": 1}"), INVALID, "unknown key \"colour\"", NULL},
    {"{\"materials\": {\"\": {\"type\": \"opaque\"}}}", INVALID, "material names must not be empty", NULL},
    {"{\"lights\": [{\"type\": \"area\"}]}", INVALID, "t.json: lights[0].type: unknown light type \"area\"", NULL},
    {"{\"lights\": [{\"direction\": [0, -1, 0]}]}", INVALID, "lights[0]: missing required key \"type\"", NULL},
    {"{\"lights\": [{\"type\": \"directional\"}]}", INVALID, "lights[0]: missing required key \"direction\"", NULL},
    {"{\"lights\": [{\"type\": \"point\"}]}", INVALID, "lights[0]: missing required key \"position\"", NULL},
    {"{\"lights\": [{\"type\": \"point\", \"position\": [0, 1, 0], \"direction\": [0, -1, 0]}]}", INVALID,
     "lights[0]: unknown key \"direction\"", NULL},
    {"{\"lights\": [{\"type\": \"directional\", \"direction\": [0, -1, 0], \"irradiance\": 1, \"strength\": 1}]}",
     INVALID, "lights[0]: give \"irradiance\" or \"strength\", not both", NULL},
    {"{\"lights\": [{\"type\": \"point\", \"position\": [0, 1, 0], \"intensity\": [1, -1, 1]}]}", INVALID,
     "lights[0].intensity[1]: must be non-negative", NULL},
    {"{\"lights\": [{\"type\": \"directional\", \"direction\": [0, 0, 0]}]}", INVALID,
     "lights[0].direction: must not be the zero vector", NULL},
    {"{\"lights\": [{\"type\": \"spot\", \"position\": [0, 1, 0], \"direction\": [0, -1, 0], \"inner_angle\": 40,"
     " \"outer_angle\": 30}]}", INVALID, "lights[0]: inner_angle (40) must not exceed outer_angle (30)", NULL},
    {"{\"lights\": [{\"type\": \"spot\", \"position\": [0, 1, 0], \"direction\": [0, -1, 0], \"outer_angle\": 95}]}",
     INVALID, "lights[0].outer_angle: must be in (0, 90)", NULL},
    {"{\"lights\": [{\"type\": \"spot\", \"position\": [0, 1, 0], \"direction\": [0, -1, 0], \"falloff\": \"ies\"}]}",
     INVALID, "t.json: lights[0].falloff: unknown spot falloff \"ies\" (valid: smooth, cycles, gltf)", NULL},
    {"{\"lights\": [{\"type\": \"spot\", \"position\": [0, 1, 0], \"direction\": [0, -1, 0], \"falloff\": 1}]}",
     INVALID, "lights[0].falloff", NULL},
    {"{\"lights\": [{\"type\": \"point\", \"position\": [0, 1, 0], \"falloff\": \"gltf\"}]}", INVALID,
     "lights[0]: unknown key \"falloff\"", NULL},
    /* Objects. */
    {OBJ("{\"material\": \"nope\", " SPHERE "}"), INVALID, "t.json: objects[0].material: unknown material \"nope\"",
     "defined: m"},
    {OBJ("{\"material\": \"m\", \"shape\": {\"type\": \"cone\"}}"), INVALID,
     "t.json: objects[0].shape.type: unknown shape type \"cone\"", "sphere, box, plane, torus"},
    {OBJ("{\"material\": \"m\", \"shape\": {\"radius\": 1}}"), INVALID,
     "objects[0].shape: missing required key \"type\"", NULL},
    {OBJ("{\"material\": \"m\", " SPHERE ", \"mesh\": \"meshes/suzanne.ply\"}"), INVALID,
     "t.json: objects[0]: give \"mesh\" or \"shape\", not both", NULL},
    {OBJ("{\"material\": \"m\"}"), INVALID, "t.json: objects[0]: missing required key \"mesh\" or \"shape\"", NULL},
    {OBJ("{" SPHERE "}"), INVALID, "t.json: objects[0]: missing required key \"material\"", NULL},
    {OBJ("{\"material\": \"m\", \"mesh\": \"meshes/missing.ply\"}"), NACRE_ERROR_IO,
     "t.json: objects[0].mesh: cannot open mesh file \"meshes/missing.ply\"", "/examples/meshes/missing.ply"},
    {OBJ("{\"material\": \"m\", \"mesh\": 3}"), INVALID, "objects[0].mesh: expected a string, got a number", NULL},
    {OBJ("{\"material\": \"m\", " SPHERE "}, {\"material\": \"m\", " SPHERE "}, {\"material\": \"m\", " SPHERE
         ", \"transform\": {\"scale\": [1, -2, 1]}}"),
     INVALID, "t.json: objects[2].transform.scale[1]: must be positive and finite (got -2)", NULL},
    {OBJ("{\"material\": \"m\", " SPHERE ", \"transform\": {\"scale\": 0}}"), INVALID,
     "objects[0].transform.scale: must be positive and finite (got 0)", NULL},
    {OBJ("{\"material\": \"m\", " SPHERE ", \"transform\": {\"rotate\": [0, 1e999, 0]}}"), INVALID,
     "objects[0].transform.rotate[1]: must be finite", NULL},
    {OBJ("{\"material\": \"m\", " SPHERE ", \"transform\": {\"move\": [0, 1, 0]}}"), INVALID,
     "objects[0].transform: unknown key \"move\" (valid keys: translate, rotate, scale)", NULL},
    {OBJ("{\"material\": \"m\", " SPHERE ", \"colour\": 1}"), INVALID, "objects[0]: unknown key \"colour\"", NULL},
    {OBJ("{\"material\": \"m\", \"shape\": {\"type\": \"sphere\", \"radius\": -1}}"), INVALID,
     "objects[0].shape.radius: must be positive and finite (got -1)", NULL},
    {OBJ("{\"material\": \"m\", \"shape\": {\"type\": \"sphere\", \"segments\": 2}}"), INVALID,
     "objects[0].shape.segments: must be an integer in 3..4096 (got 2)", NULL},
    {OBJ("{\"material\": \"m\", \"shape\": {\"type\": \"sphere\", \"segments\": 8.5}}"), INVALID,
     "objects[0].shape.segments: must be an integer", NULL},
    {OBJ("{\"material\": \"m\", \"shape\": {\"type\": \"sphere\", \"segments\": 4096, \"rings\": 4096}}"), INVALID,
     "objects[0].shape: too finely subdivided", NULL},
    {OBJ("{\"material\": \"m\", \"shape\": {\"type\": \"sphere\", \"size\": 3}}"), INVALID,
     "objects[0].shape: unknown key \"size\" (valid keys: type, radius, segments, rings)", NULL},
    {OBJ("{\"material\": \"m\", \"shape\": {\"type\": \"box\", \"size\": [1, 0, 1]}}"), INVALID,
     "objects[0].shape.size[1]: must be positive and finite (got 0)", NULL},
    {OBJ("{\"material\": \"m\", \"shape\": {\"type\": \"plane\", \"size\": [10, 1, 10]}}"), INVALID,
     "objects[0].shape.size[1]: must be 0", NULL},
    {OBJ("{\"material\": \"m\", \"shape\": {\"type\": \"plane\", \"size\": [10, 10, 10, 10]}}"), INVALID,
     "objects[0].shape.size: expected [width, depth] or [width, 0, depth], got 4 elements", NULL},
    {OBJ("{\"material\": \"m\", \"shape\": {\"type\": \"torus\", \"radius\": 1, \"minor_radius\": 1}}"), INVALID,
     "objects[0].shape.minor_radius: must be smaller than radius", NULL},
    {OBJ("{\"material\": \"m\", " SPHERE ", \"deformers\": [{\"type\": \"melt\"}]}"), INVALID,
     "t.json: objects[0].deformers[0].type: unknown deformer type \"melt\"", "scale, twist, bend"},
    {OBJ("{\"material\": \"m\", " SPHERE ", \"deformers\": [{\"type\": \"twist\"}, {\"type\": \"twist\"},"
         " {\"type\": \"twist\"}, {\"type\": \"twist\"}, {\"type\": \"twist\"}]}"),
     INVALID, "t.json: objects[0].deformers: at most 4 deformers per object (got 5)", NULL},
    {OBJ("{\"material\": \"m\", " SPHERE ", \"deformers\": [{\"type\": \"twist\", \"axis\": \"w\"}]}"), INVALID,
     "objects[0].deformers[0].axis: unknown axis \"w\"", NULL},
    {OBJ("{\"material\": \"m\", " SPHERE ", \"deformers\": [{\"type\": \"twist\", \"length\": 0}]}"), INVALID,
     "objects[0].deformers[0].length: must be positive", NULL},
    {OBJ("{\"material\": \"m\", " SPHERE ", \"deformers\": [{\"type\": \"bend\", \"axis\": \"x\","
         " \"direction\": [2, 0, 0]}]}"),
     INVALID, "objects[0].deformers[0].direction: must not be parallel to axis", NULL},
    {OBJ("{\"material\": \"m\", " SPHERE ", \"deformers\": [{\"type\": \"scale\", \"angle\": 3}]}"), INVALID,
     "objects[0].deformers[0]: unknown key \"angle\" (valid keys: type, scale, scale_rate, center)", NULL},
    {OBJ("{\"material\": \"m\", " SPHERE ", \"deformers\": [{\"type\": \"scale\", \"scale\": [1, -1, 1]}]}"),
     INVALID, "objects[0].deformers[0].scale[1]: must be positive", NULL},
    /* A lower layer's message keeps its text, behind the field path. */
    {MAT("{\"type\": \"translucent\", \"sigma_a\": 0, \"sigma_s\": 0}"), INVALID,
     "t.json: materials.m: ", "sigma_a + sigma_s"},
    /* Diffusion and path-tracer render settings. */
    {"{\"render\": {\"voxel_resolution\": 0}}", INVALID, "t.json: render.voxel_resolution: must be an integer in 1..1024", NULL},
    {"{\"render\": {\"voxel_resolution\": 32.5}}", INVALID, "render.voxel_resolution: must be an integer", NULL},
    {"{\"render\": {\"tsm_size\": 0}}", INVALID, "render.tsm_size: must be an integer in 16..8192", NULL},
    {"{\"render\": {\"solver\": \"jacobi\"}}", INVALID, "render.solver: unknown solver \"jacobi\"", "multigrid, seed"},
    {"{\"render\": {\"solver\": 1}}", INVALID, "render.solver: expected a string, got a number", NULL},
    {"{\"render\": {\"source\": \"surface\"}}", INVALID, "render.source: unknown source \"surface\"", "volume, face"},
    {"{\"render\": {\"single_scattering\": \"sometimes\"}}", INVALID,
     "render.single_scattering: unknown single_scattering mode \"sometimes\"", "off, on, auto"},
    {"{\"render\": {\"single_scattering\": 1}}", INVALID, "render.single_scattering: expected a string, got a number", NULL},
    {"{\"render\": {\"tolerance\": 0}}", INVALID, "render.tolerance: must be in (0, 1) (got 0)", NULL},
    {"{\"render\": {\"tolerance\": 1}}", INVALID, "render.tolerance: must be in (0, 1)", NULL},
    {"{\"render\": {\"seed_iterations\": -1}}", INVALID, "render.seed_iterations: must be an integer in 0..1000000", NULL},
    {"{\"render\": {\"time_limit\": -1}}", INVALID, "render.time_limit: must be non-negative", NULL},
    {"{\"render\": {\"time_limit\": \"1h\"}}", INVALID, "render.time_limit: expected a number", NULL},
    {"{\"render\": {\"max_scatter\": 4294967296}}", INVALID, "render.max_scatter: must be an integer in 0..4294967295", NULL},
    /* Heterogeneous materials. */
    {MAT("{\"preset\": \"marble\", \"pattern\": 3}"), INVALID, "t.json: materials.m.pattern: expected an object, got a number", NULL},
    {MAT("{\"preset\": \"marble\", \"pattern\": {}}"), INVALID, "materials.m.pattern: missing required key \"type\"", NULL},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"stripes\"}}"), INVALID,
     "materials.m.pattern.type: unknown pattern type \"stripes\"", "random_mix, checker, noise, volume"},
    {MAT("{\"type\": \"opaque\", \"pattern\": {\"type\": \"checker\"}}"), INVALID, "materials.m: unknown key \"pattern\"", NULL},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"checker\", \"cell_size\": 1}}"), INVALID,
     "materials.m.pattern: medium 2 needs \"preset2\" or both \"sigma_a2\" and \"sigma_s2\"", NULL},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"checker\", \"sigma_a2\": 1, \"cell_size\": 1}}"), INVALID,
     "materials.m.pattern: medium 2 needs", NULL},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"checker\", \"preset2\": \"ketchup\"}}"), INVALID,
     "materials.m.pattern: missing required key \"cell_size\"", NULL},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"checker\", \"preset2\": \"ketchup\", \"cell_size\": 0}}"),
     INVALID, "materials.m.pattern.cell_size: must be positive and finite (got 0)", NULL},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"checker\", \"preset2\": \"mustard\", \"cell_size\": 1}}"),
     INVALID, "materials.m.pattern.preset2: unknown preset \"mustard\"", "ketchup"},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"checker\", \"preset2\": \"ketchup\", \"cell_size\": 1,"
         " \"fraction\": 0.5}}"),
     INVALID, "materials.m.pattern: unknown key \"fraction\" (valid keys: type, preset2, sigma_a2, sigma_s2, cell_size)", NULL},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"random_mix\", \"preset2\": \"ketchup\", \"cell_size\": 1,"
         " \"fraction\": 1.5}}"),
     INVALID, "materials.m.pattern.fraction: must be in [0, 1] (got 1.5)", NULL},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"random_mix\", \"preset2\": \"ketchup\", \"cell_size\": 1,"
         " \"seed\": -3}}"),
     INVALID, "materials.m.pattern.seed: must be an integer in 0..4294967295", NULL},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"noise\", \"preset2\": \"ketchup\", \"cell_size\": 1,"
         " \"octaves\": 13}}"),
     INVALID, "materials.m.pattern.octaves: must be an integer in 1..12 (got 13)", NULL},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"noise\", \"sigma_a2\": [1, -1, 1], \"sigma_s2\": 1,"
         " \"cell_size\": 1}}"),
     INVALID, "materials.m.pattern.sigma_a2[1]: must be non-negative", NULL},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"noise\", \"sigma_a2\": 0, \"sigma_s2\": 0,"
         " \"cell_size\": 1}}"),
     INVALID, "t.json: materials.m: ", "sigma_a2 + sigma_s2: must be positive"},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"volume\"}}"), INVALID,
     "materials.m.pattern: missing required key \"volume\"", NULL},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"volume\", \"volume\": \"x.nrrd\", \"cell_size\": 1}}"),
     INVALID, "materials.m.pattern: unknown key \"cell_size\" (valid keys: type, volume, channel, grid, density_scale, blackbody, kelvin_scale)", NULL},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"volume\", \"volume\": \"missing.nrrd\"}}"),
     NACRE_ERROR_IO, "t.json: materials.m.pattern.volume: ", "examples/missing.nrrd: cannot open"},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"volume\", \"volume\": \"hetero_density.nrrd\", \"channel\": 1}}"),
     INVALID, "materials.m.pattern.volume: ", "channel 1: the file has 1 channel(s)"},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"volume\", \"volume\": \"hetero_density.nrrd\","
         " \"density_scale\": -1}}"),
     INVALID, "materials.m.pattern.density_scale: must be non-negative", NULL},
    {MAT("{\"preset\": \"marble\", \"pattern\": {\"type\": \"volume\", \"volume\": \"hetero_cube.json\"}}"),
     NACRE_ERROR_PARSE, "materials.m.pattern.volume: ", "hetero_cube.json: line 1: magic: not a NRRD file"},
    /* Layers. */
    {MAT("{\"preset\": \"marble\", \"layers\": 3}"), INVALID, "t.json: materials.m.layers: expected an array, got a number", NULL},
    {MAT("{\"preset\": \"marble\", \"layers\": [{\"depth\": 1, \"preset\": \"skin1\"}, {\"depth\": 1, \"preset\": \"skin1\"},"
         " {\"depth\": 1, \"preset\": \"skin1\"}, {\"depth\": 1, \"preset\": \"skin1\"}, {\"depth\": 1, \"preset\": \"skin1\"}]}"),
     INVALID, "materials.m.layers: at most 4 layers (got 5)", NULL},
    {MAT("{\"preset\": \"marble\", \"layers\": [{\"preset\": \"skin1\"}]}"), INVALID,
     "materials.m.layers[0]: missing required key \"depth\"", NULL},
    {MAT("{\"preset\": \"marble\", \"layers\": [{\"depth\": 1, \"preset\": \"skin1\"}, {\"depth\": 2, \"sigma_a\": 1}]}"),
     INVALID, "materials.m.layers[1]: a layer needs \"preset\" or both \"sigma_a\" and \"sigma_s\"", NULL},
    {MAT("{\"preset\": \"marble\", \"layers\": [{\"depth\": -1, \"preset\": \"skin1\"}]}"), INVALID,
     "materials.m.layers[0].depth: must be non-negative", NULL},
    {MAT("{\"preset\": \"marble\", \"layers\": [{\"depth\": 1, \"preset\": \"skin1\", \"g\": 1}]}"), INVALID,
     "materials.m.layers[0].g: must be in (-1, 1)", NULL},
    {MAT("{\"preset\": \"marble\", \"layers\": [{\"depth\": 1, \"preset\": \"skin9\"}]}"), INVALID,
     "materials.m.layers[0].preset: unknown preset \"skin9\"", NULL},
    {MAT("{\"preset\": \"marble\", \"layers\": [{\"depth\": 1, \"preset\": \"skin1\", \"thickness\": 1}]}"), INVALID,
     "materials.m.layers[0]: unknown key \"thickness\" (valid keys: preset, sigma_a, sigma_s, g, depth)", NULL},
    {MAT("{\"preset\": \"marble\", \"layers\": [{\"depth\": 1, \"sigma_a\": 0, \"sigma_s\": 0}]}"), INVALID,
     "t.json: materials.m: ", "layers[0].sigma_a + sigma_s: must be positive"},
    {MAT("{\"preset\": \"marble\", \"depth_map\": \"layered_depth.png\"}"), INVALID,
     "materials.m.depth_map: a depth map needs \"layers\"", NULL},
    {MAT("{\"preset\": \"marble\", \"depth_map\": \"none.png\", \"layers\": [{\"depth\": 1, \"preset\": \"skin1\"}]}"),
     NACRE_ERROR_IO, "t.json: materials.m.depth_map: ", "examples/none.png: cannot open"},
    {MAT("{\"preset\": \"marble\", \"depth_map\": \"hetero_density.nrrd\", \"layers\": [{\"depth\": 1, \"preset\": \"skin1\"}]}"),
     INVALID, "materials.m.depth_map: ", "unknown image extension"},
    {MAT("{\"type\": \"opaque\", \"layers\": []}"), INVALID, "materials.m: unknown key \"layers\"", NULL},
};

static bool one_line(const char *s)
{
    return strchr(s, '\n') == NULL && strchr(s, '\r') == NULL;
}

static void expect_failure(nacre_context *ctx, counter *c, const char *json, size_t length,
                           nacre_result code, const char *needle, const char *needle2)
{
    long baseline = c->live;
    int sentinel = 0;
    nacre_scene *s = (nacre_scene *)(void *)&sentinel;
    nacre_scene_file_settings rs = {.render = nacre_render_settings_defaults()};
    rs.render.width = 12345;
    nacre_result r = nacre_scene_load_json(ctx, json, length, "t.json", EXAMPLES, &s, &rs);
    const char *msg = nacre_context_last_error(ctx);
    bool ok = r == code && s == NULL && strncmp(msg, "t.json", 6) == 0 && strstr(msg, needle) &&
              (!needle2 || strstr(msg, needle2)) && one_line(msg) && c->live == baseline &&
              rs.render.width == 12345;
    CHECK(ok);
    if (!ok)
        printf("  input: %s\n  got %d (%s), message: %s\n  expected %d with \"%s\"%s%s\n", json, (int)r,
               nacre_result_string(r), msg, (int)code, needle, needle2 ? " and " : "",
               needle2 ? needle2 : "");
    if (r == NACRE_OK && s)
        nacre_scene_destroy(s);
}

static void test_bad_inputs(void)
{
    counter c;
    nacre_context *ctx = make_context(&c);
    for (size_t i = 0; i < sizeof(bad_cases) / sizeof(bad_cases[0]); i++) {
        const bad_case *b = &bad_cases[i];
        expect_failure(ctx, &c, b->json, strlen(b->json), b->code, b->needle, b->needle2);
    }

    /* Line and column of a malformed file: the missing comma before "height" on line 3. */
    const char *text = "{\n  \"units\": \"mm\",\n  \"render\": {\"width\": 64 \"height\": 48}\n}\n";
    expect_failure(ctx, &c, text, strlen(text), NACRE_ERROR_PARSE, "t.json:3:26: malformed JSON", NULL);
    /* An unterminated string is reported at its opening quote. */
    text = "{\n  \"units\": \"mm}\n";
    expect_failure(ctx, &c, text, strlen(text), NACRE_ERROR_PARSE,
                   "t.json:2:12: malformed JSON (unterminated string)", NULL);
    /* A NUL byte inside the length would end cJSON's view of the text early. */
    static const char with_nul[] = "{\"units\": \"mm\"}\0{\"units\": 5}";
    expect_failure(ctx, &c, with_nul, sizeof(with_nul) - 1, NACRE_ERROR_PARSE, "t.json:1:16: malformed JSON (NUL byte)",
                   NULL);

    /* Keys and names from the file are cut and cleaned in messages: still one short line. */
    char big[2048];
    int n = snprintf(big, sizeof(big), "{\"");
    for (int i = 0; i < 1500; i++)
        big[n++] = (char)('a' + i % 26);
    snprintf(big + n, sizeof(big) - (size_t)n, "\\n\": 1}");
    expect_failure(ctx, &c, big, strlen(big), INVALID, "unknown key \"abcdefghij", "...\"");
    CHECK(strlen(nacre_context_last_error(ctx)) < 600);

    /* Arguments. */
    nacre_scene *s = NULL;
    CHECK(nacre_scene_load_json(ctx, NULL, 5, "t.json", NULL, &s, NULL) == INVALID);
    CHECK(nacre_scene_load_json(ctx, "{}", 2, "t.json", NULL, NULL, NULL) == INVALID);
    CHECK(nacre_scene_load_json(NULL, "{}", 2, "t.json", NULL, &s, NULL) == INVALID);
    CHECK(nacre_scene_load_file(ctx, NULL, &s, NULL) == INVALID);
    /* No name: messages still say where. */
    CHECK(nacre_scene_load_json(ctx, "{\"x\": 1}", 8, NULL, NULL, &s, NULL) == INVALID);
    CHECK(strstr(nacre_context_last_error(ctx), "<json>: unknown key \"x\"") != NULL);
    CHECK(s == NULL);
    nacre_context_destroy(ctx);
    CHECK(c.live == 0);
}

/* ------------------------------------------------------------------------------------------ */

static void test_files(void)
{
    counter c;
    nacre_context *ctx = make_context(&c);
    mkdir(TMP, 0755);
    mkdir(TMP "/sub", 0755);
    mkdir(TMP "/sub/m", 0755);
    write_text(TMP "/sub/m/tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    write_text(TMP "/bad.obj", "not a mesh at all\n");
    write_text(TMP "/sub/scene.json",
               "{\"materials\": {\"m\": {\"type\": \"opaque\"}},\n"
               " \"objects\": [{\"name\": \"tri\", \"mesh\": \"m/tri.obj\", \"material\": \"m\"},\n"
               "             {\"mesh\": \"" TMP "/sub/m/tri.obj\", \"material\": \"m\"}]}\n");
    write_text(TMP "/sub/missing.json",
               "{\"materials\": {\"m\": {\"type\": \"opaque\"}},\n"
               " \"objects\": [{\"mesh\": \"m/none.obj\", \"material\": \"m\"}]}\n");
    write_text(TMP "/sub/badmesh.json",
               "{\"materials\": {\"m\": {\"type\": \"opaque\"}},\n"
               " \"objects\": [{\"mesh\": \"../bad.obj\", \"material\": \"m\"}]}\n");
    write_text(TMP "/sub/malformed.json", "{\n  \"units\": \"mm\"\n  \"lights\": []\n}\n");

    /* Relative mesh paths start at the scene file's folder, not the working directory. */
    nacre_scene *s = NULL;
    nacre_scene_file_settings rs;
    nacre_result r = nacre_scene_load_file(ctx, TMP "/sub/scene.json", &s, &rs);
    CHECK(r == NACRE_OK);
    if (r != NACRE_OK)
        printf("  scene.json: %s\n", nacre_context_last_error(ctx));
    if (s) {
        CHECK(nacre_scene_object_count(s) == 2);
        CHECK(s->mesh_count == 1); /* relative and absolute spellings of one file: loaded once */
        const nacre_mesh_data *tri = nacre_scene_mesh_data(s, s->objects[0].desc.mesh);
        CHECK(tri && tri->triangle_count == 1);
        CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
        nacre_scene_destroy(s);
    }
    /* Same through a relative scene path. */
    char cwd[4096];
    CHECK(getcwd(cwd, sizeof(cwd)) != NULL);
    CHECK(chdir(TMP) == 0);
    s = NULL;
    r = nacre_scene_load_file(ctx, "sub/scene.json", &s, NULL);
    CHECK(r == NACRE_OK && s && nacre_scene_object_count(s) == 2);
    nacre_scene_destroy(s);
    r = nacre_scene_load_file(ctx, "sub/missing.json", &s, NULL);
    CHECK(r == NACRE_ERROR_IO && s == NULL);
    CHECK(strstr(nacre_context_last_error(ctx),
                 "sub/missing.json: objects[0].mesh: cannot open mesh file \"m/none.obj\" (sub/m/none.obj)") != NULL);
    CHECK(chdir(cwd) == 0);

    long baseline = c.live;
    s = NULL;
    r = nacre_scene_load_file(ctx, TMP "/sub/missing.json", &s, NULL);
    CHECK(r == NACRE_ERROR_IO && s == NULL);
    const char *msg = nacre_context_last_error(ctx);
    CHECK(strstr(msg, TMP "/sub/missing.json: objects[0].mesh: cannot open mesh file \"m/none.obj\"") != NULL);
    CHECK(strstr(msg, TMP "/sub/m/none.obj") != NULL);
    CHECK(c.live == baseline);

    /* The mesh loader's message, behind the scene's field path. */
    r = nacre_scene_load_file(ctx, TMP "/sub/badmesh.json", &s, NULL);
    CHECK(r != NACRE_OK && s == NULL);
    msg = nacre_context_last_error(ctx);
    CHECK(strstr(msg, TMP "/sub/badmesh.json: objects[0].mesh: ") == msg);
    CHECK(strstr(msg, "bad.obj") != NULL && one_line(msg));
    if (!(strstr(msg, TMP "/sub/badmesh.json: objects[0].mesh: ") == msg))
        printf("  badmesh: %s\n", msg);
    CHECK(c.live == baseline);

    r = nacre_scene_load_file(ctx, TMP "/sub/malformed.json", &s, NULL);
    CHECK(r == NACRE_ERROR_PARSE && s == NULL);
    CHECK(strstr(nacre_context_last_error(ctx), TMP "/sub/malformed.json:3:3: malformed JSON") != NULL);

    r = nacre_scene_load_file(ctx, TMP "/sub/no-such-scene.json", &s, NULL);
    CHECK(r == NACRE_ERROR_IO && s == NULL);
    CHECK(strstr(nacre_context_last_error(ctx), TMP "/sub/no-such-scene.json: cannot open") != NULL);
    r = nacre_scene_load_file(ctx, TMP "/sub", &s, NULL); /* a folder opens but does not read */
    CHECK(r == NACRE_ERROR_IO && s == NULL);
    CHECK(strstr(nacre_context_last_error(ctx), TMP "/sub: cannot read") != NULL);
    CHECK(c.live == baseline);
    nacre_context_destroy(ctx);
    CHECK(c.live == 0);
}

static int compare_strings(const void *a, const void *b)
{
    return strcmp(*(char *const *)a, *(char *const *)b);
}

/* ------------------------------------------------------------------------------------------ */

static const char pattern_scene[] =
    "{\"units\": \"cm\",\n"
    " \"render\": {\"voxel_resolution\": 48, \"tsm_size\": 1024, \"solver\": \"seed\", \"source\": \"face\",\n"
    "            \"tolerance\": 1e-5, \"seed_iterations\": 20, \"time_limit\": 2.5, \"max_scatter\": 100},\n"
    " \"materials\": {\n"
    "  \"mix\": {\"preset\": \"marble\", \"pattern\": {\"type\": \"random_mix\", \"preset2\": \"ketchup\",\n"
    "          \"sigma_s2\": [1, 2, 3], \"cell_size\": 2, \"fraction\": 0.3, \"seed\": 7}},\n"
    "  \"check\": {\"type\": \"translucent\", \"sigma_a\": 0.1, \"sigma_s\": 1,\n"
    "            \"pattern\": {\"type\": \"checker\", \"sigma_a2\": [0.2, 0.3, 0.4], \"sigma_s2\": 0.5, \"cell_size\": 5}},\n"
    "  \"noise\": {\"preset\": \"skin1\", \"pattern\": {\"type\": \"noise\", \"preset2\": \"skin2\", \"cell_size\": 3,\n"
    "            \"octaves\": 6, \"seed\": 11}},\n"
    "  \"noise default\": {\"preset\": \"skin1\", \"pattern\": {\"type\": \"noise\", \"preset2\": \"skin2\", \"cell_size\": 3}},\n"
    "  \"vol\": {\"preset\": \"wholemilk\", \"pattern\": {\"type\": \"volume\", \"volume\": \"dens.nrrd\", \"channel\": 1,\n"
    "          \"density_scale\": 0.5}}\n"
    " },\n"
    " \"lights\": [{\"type\": \"directional\", \"direction\": [0, -1, 0]}],\n"
    " \"objects\": [{\"shape\": {\"type\": \"box\"}, \"material\": \"mix\",\n"
    "              \"deformers\": [{\"type\": \"twist\", \"axis\": \"y\", \"angle\": 45}]},\n"
    "             {\"shape\": {\"type\": \"box\"}, \"material\": \"vol\"}]}\n";

/* A 2-channel big-endian uint16 volume, 3 x 2 x 1, channel c of sample i = 10 i + c. */
static void write_density(const char *path)
{
    static const char head[] = "NRRD0005\ntype: uint16\ndimension: 4\nsizes: 2 3 2 1\nencoding: raw\n"
                               "endian: big\nspace dimension: 3\nspace origin: (-1,-2,-3)\n"
                               "space directions: none (0.5,0,0) (0,4,0) (0,0,1)\n\n";
    uint8_t buf[sizeof(head) + 24];
    memcpy(buf, head, sizeof(head) - 1);
    size_t pos = sizeof(head) - 1;
    for (int i = 0; i < 6; i++)
        for (int c = 0; c < 2; c++) {
            buf[pos++] = 0;
            buf[pos++] = (uint8_t)(10 * i + c);
        }
    FILE *f = fopen(path, "wb");
    CHECK(f != NULL);
    if (!f)
        return;
    fwrite(buf, 1, pos, f);
    fclose(f);
}

static void test_patterns(void)
{
    counter c;
    nacre_context *ctx = make_context(&c);
    mkdir(TMP, 0755);
    write_density(TMP "/dens.nrrd");
    nacre_scene *s = NULL;
    nacre_scene_file_settings rs;
    nacre_result r = nacre_scene_load_json(ctx, pattern_scene, strlen(pattern_scene), "p.json", TMP, &s, &rs);
    CHECK(r == NACRE_OK);
    if (r != NACRE_OK) {
        printf("  pattern scene: %s\n", nacre_context_last_error(ctx));
        nacre_context_destroy(ctx);
        return;
    }
    CHECK(rs.render.diffusion.voxel_resolution == 48 && rs.render.diffusion.tsm_size == 1024);
    CHECK(rs.render.diffusion.solver == NACRE_SOLVER_SEED && rs.render.diffusion.source == NACRE_SOURCE_FACE);
    CHECK_NEAR(rs.render.diffusion.tolerance, 1e-5, 1e-12);
    CHECK(rs.render.diffusion.seed_iterations == 20 && rs.render.pathtrace.max_scatter == 100);
    CHECK_NEAR(rs.render.pathtrace.time_limit, 2.5, 0);

    CHECK(s->material_count == 5);
    nacre_material_desc marble, ketchup, skin2;
    CHECK(nacre_material_preset("marble", &marble) && nacre_material_preset("ketchup", &ketchup) &&
          nacre_material_preset("skin2", &skin2));
    const nacre_material_desc *mix = &s->materials[0], *check = &s->materials[1], *noise = &s->materials[2];
    const nacre_material_desc *noise_default = &s->materials[3], *vol = &s->materials[4];
    CHECK(mix->pattern.type == NACRE_PATTERN_RANDOM_MIX);
    for (int i = 0; i < 3; i++) {
        CHECK_NEAR(mix->sigma_s[i], marble.sigma_s[i] * 10, 1e-5);          /* medium 1: per cm */
        CHECK_NEAR(mix->pattern.sigma_a2[i], ketchup.sigma_a[i] * 10, 1e-5); /* preset2: per cm */
        CHECK_NEAR(mix->pattern.sigma_s2[i], i + 1, 0);                       /* override as written */
    }
    CHECK_NEAR(mix->pattern.cell_size, 2, 0);
    CHECK_NEAR(mix->pattern.fraction, 0.3, 1e-7);
    CHECK(mix->pattern.seed == 7);
    CHECK(check->pattern.type == NACRE_PATTERN_CHECKER);
    CHECK_NEAR(check->pattern.sigma_a2[2], 0.4, 1e-7);
    CHECK_NEAR(check->pattern.sigma_s2[1], 0.5, 0);
    CHECK_NEAR(check->pattern.cell_size, 5, 0);
    CHECK(noise->pattern.type == NACRE_PATTERN_NOISE);
    CHECK(noise->pattern.octaves == 6 && noise->pattern.seed == 11);
    CHECK_NEAR(noise->pattern.sigma_s2[1], skin2.sigma_s[1] * 10, 1e-5);
    CHECK(noise_default->pattern.octaves == 4 && noise_default->pattern.seed == 0);
    CHECK(vol->pattern.type == NACRE_PATTERN_VOLUME);
    const nc_volume_rec *v = nc_scene_volume(s, vol->pattern.volume);
    CHECK(v != NULL && s->volume_count == 1);
    if (v) {
        CHECK(v->dims[0] == 3 && v->dims[1] == 2 && v->dims[2] == 1);
        CHECK(v->origin[0] == -1 && v->origin[1] == -2 && v->origin[2] == -3);
        CHECK(v->spacing[0] == 0.5f && v->spacing[1] == 4 && v->spacing[2] == 1);
        bool same = true;
        for (int i = 0; i < 6; i++)
            same &= v->data[i] == 0.5f * (float)(10 * i + 1); /* channel 1, scaled */
        CHECK(same);
        CHECK(v->max_value == 25.5f && v->min_value == 0.5f);
    }
    CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
    nacre_scene_destroy(s);

    /* Every allocation failure while loading it is clean. */
    long baseline = c.live;
    bool succeeded = false;
    for (long n = 0; n < 100000 && !succeeded; n++) {
        c.made = 0;
        c.fail_at = n;
        s = NULL;
        r = nacre_scene_load_json(ctx, pattern_scene, strlen(pattern_scene), "p.json", TMP, &s, NULL);
        c.fail_at = -1;
        if (r == NACRE_OK) {
            succeeded = true;
            nacre_scene_destroy(s);
        } else {
            CHECK(s == NULL && c.live == baseline);
        }
    }
    CHECK(succeeded);

    /* A malformed volume file: the message names the scene field, the NRRD file and its line. */
    write_text(TMP "/bad.nrrd", "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 4 4 -4\nencoding: raw\n\n");
    static const char bad_volume[] =
        "{\"materials\": {\"v\": {\"preset\": \"marble\", \"pattern\": {\"type\": \"volume\", \"volume\": \"bad.nrrd\"}}}}";
    r = nacre_scene_load_json(ctx, bad_volume, strlen(bad_volume), "b.json", TMP, &s, NULL);
    CHECK(r == NACRE_ERROR_PARSE && s == NULL);
    CHECK(strstr(nacre_context_last_error(ctx), "b.json: materials.v.pattern.volume: ") != NULL);
    CHECK(strstr(nacre_context_last_error(ctx), "bad.nrrd: line 4: sizes:") != NULL);
    nacre_context_destroy(ctx);
    CHECK(c.live == 0);
}

/* Layers and a depth map read as data: a 2 x 1 PNG of 0/255 samples gives 0 and 1 exactly
 * (an sRGB decode would too; the 188 of the third channel tells them apart: 188 / 255 as data,
 * about 0.5 decoded), per-layer presets per scene unit, and a greyscale map's 3 channels are too
 * few for 4 layers. */
static void test_layers(void)
{
    counter c;
    nacre_context *ctx = make_context(&c);
    mkdir(TMP, 0755);
    float px[2 * 4] = {0.0f, 1.0f, 0.5f, 1.0f, 1.0f, 0.0f, 0.5f, 1.0f};
    nacre_image img = {2, 1, 4, 8, px};
    CHECK(nc_image_write_png(ctx, &img, TMP "/depth.png", 0.0f) == NACRE_OK);
    static const char scene[] =
        "{\"units\": \"cm\", \"materials\": {\"m\": {\"preset\": \"skin2\", \"depth_map\": \"depth.png\", \"layers\": ["
        "{\"sigma_a\": [1, 2, 3], \"sigma_s\": 4, \"g\": 0.5, \"depth\": 0.02},"
        "{\"preset\": \"skin1\", \"sigma_a\": 0.25, \"depth\": 0.3}]}}}";
    nacre_scene *s = NULL;
    nacre_result r = nacre_scene_load_json(ctx, scene, strlen(scene), "l.json", TMP, &s, NULL);
    CHECK(r == NACRE_OK);
    if (r != NACRE_OK) {
        printf("  layers: %s\n", nacre_context_last_error(ctx));
        nacre_context_destroy(ctx);
        return;
    }
    nacre_material_desc skin1;
    CHECK(nacre_material_preset("skin1", &skin1));
    const nacre_layering *l = &s->materials[0].layering;
    CHECK(l->count == 2);
    CHECK_NEAR(l->layers[0].sigma_a[2], 3, 0);
    CHECK_NEAR(l->layers[0].sigma_s[1], 4, 0);
    CHECK_NEAR(l->layers[0].g, 0.5, 0);
    CHECK_NEAR(l->layers[0].depth, 0.02, 1e-9);
    CHECK_NEAR(l->layers[1].sigma_a[0], 0.25, 0);                  /* override as written */
    CHECK_NEAR(l->layers[1].sigma_s[1], skin1.sigma_s[1] * 10, 1e-5); /* preset: per cm */
    CHECK_NEAR(l->layers[1].g, 0, 0);
    const nc_texture_rec *t = nc_scene_texture(s, l->depth_map);
    CHECK(t != NULL);
    if (t) {
        CHECK(t->width == 2 && t->height == 1 && t->channels == 4);
        CHECK(t->data[0] == 0.0f && t->data[1] == 1.0f && t->data[4] == 1.0f && t->data[5] == 0.0f);
        CHECK_NEAR(t->data[2], 188.0 / 255.0, 1e-6); /* data, not sRGB-decoded */
    }
    nacre_scene_destroy(s);

    /* Three channels (greyscale PNG) for four layers. */
    nacre_image grey = {2, 1, 3, 6, px};
    CHECK(nc_image_write_png(ctx, &grey, TMP "/grey.png", 0.0f) == NACRE_OK);
    static const char four[] =
        "{\"materials\": {\"m\": {\"preset\": \"skin2\", \"depth_map\": \"grey.png\", \"layers\": ["
        "{\"preset\": \"skin1\", \"depth\": 1}, {\"preset\": \"skin1\", \"depth\": 1},"
        "{\"preset\": \"skin1\", \"depth\": 1}, {\"preset\": \"skin1\", \"depth\": 1}]}}}";
    r = nacre_scene_load_json(ctx, four, strlen(four), "f.json", TMP, &s, NULL);
    CHECK(r == NACRE_ERROR_INVALID_ARGUMENT && s == NULL);
    CHECK(strstr(nacre_context_last_error(ctx), "f.json: materials.m: ") != NULL);
    CHECK(strstr(nacre_context_last_error(ctx), "depth_map: 3 channel(s) for 4 layers") != NULL);
    nacre_context_destroy(ctx);
    CHECK(c.live == 0);
}

/* Every example scene loads and commits; they are meant to be fast golden scenes. */
static void test_examples(void)
{
    counter c;
    nacre_context *ctx = make_context(&c);
    DIR *dir = opendir(EXAMPLES);
    CHECK(dir != NULL);
    if (!dir)
        return;
    char *names[64];
    int count = 0;
    struct dirent *e;
    while ((e = readdir(dir)) && count < 64) {
        size_t n = strlen(e->d_name);
        if (n > 5 && strcmp(e->d_name + n - 5, ".json") == 0)
            names[count++] = strdup(e->d_name);
    }
    closedir(dir);
    qsort(names, (size_t)count, sizeof(names[0]), compare_strings);
    CHECK(count >= 9);
    for (int i = 0; i < count; i++) {
        char path[1024];
        snprintf(path, sizeof(path), "%s/%s", EXAMPLES, names[i]);
        nacre_scene *s = NULL;
        nacre_scene_file_settings rs;
        nacre_result r = nacre_scene_load_file(ctx, path, &s, &rs);
        CHECK(r == NACRE_OK);
        if (r != NACRE_OK) {
            printf("  %s: %s\n", names[i], nacre_context_last_error(ctx));
        } else {
            CHECK(nacre_scene_object_count(s) > 0 && nacre_scene_light_count(s) > 0);
            CHECK(s->has_camera);
            /* Small enough to render quickly in tests (the demo is the showcase). */
            if (strcmp(names[i], "demo.json") != 0)
                CHECK((int64_t)rs.render.width * rs.render.height <= 480 * 360);
            CHECK(nacre_scene_commit(s, 0.0) == NACRE_OK);
        }
        nacre_scene_destroy(s);
        free(names[i]);
    }
    nacre_context_destroy(ctx);
    CHECK(c.live == 0);
}

/* Fail the n-th allocation for every n until the load succeeds: each failure must be clean. */
static void test_out_of_memory(void)
{
    counter c;
    nacre_context *ctx = make_context(&c);
    long baseline = c.live;
    int failures = 0;
    bool succeeded = false;
    for (long n = 0; n < 100000 && !succeeded; n++) {
        c.made = 0;
        c.fail_at = n;
        nacre_scene *s = NULL;
        nacre_result r = load(ctx, full_scene, &s, NULL);
        c.fail_at = -1;
        if (r == NACRE_OK) {
            succeeded = true;
            nacre_scene_destroy(s);
            break;
        }
        failures++;
        bool ok = s == NULL && c.live == baseline && nacre_context_last_error(ctx)[0] != '\0';
        CHECK(ok);
        if (!ok) {
            printf("  failing allocation %ld: %s (live %ld, baseline %ld)\n", n,
                   nacre_context_last_error(ctx), c.live, baseline);
            break;
        }
    }
    CHECK(succeeded);
    CHECK(failures > 10);
    CHECK(c.live == baseline);
    nacre_context_destroy(ctx);
    CHECK(c.live == 0);
}

/* Issue 29 items 6 and 12: the ends of the eta range load; nesting past cJSON's limit and
 * \u0000 inside a string are named as such. */
static void test_limits_and_nul(void)
{
    counter c;
    nacre_context *ctx = make_context(&c);
    nacre_scene *s = NULL;
    CHECK(load(ctx, MAT("{\"preset\": \"marble\", \"eta\": 0.3}"), &s, NULL) == NACRE_OK);
    nacre_scene_destroy(s);
    s = NULL;
    CHECK(load(ctx, MAT("{\"preset\": \"marble\", \"eta\": 3}"), &s, NULL) == NACRE_OK);
    nacre_scene_destroy(s);
    s = NULL;

    /* 1500 nested arrays: not "malformed JSON". */
    size_t n = 1500;
    char *deep = malloc(2 * n + 16);
    CHECK(deep != NULL);
    if (deep) {
        size_t k = 0;
        k += (size_t)sprintf(deep, "{\"a\": ");
        for (size_t i = 0; i < n; i++)
            deep[k++] = '[';
        for (size_t i = 0; i < n; i++)
            deep[k++] = ']';
        deep[k++] = '}';
        deep[k] = '\0';
        expect_failure(ctx, &c, deep, k, NACRE_ERROR_PARSE, "t.json:1:", "nested deeper than 1000 levels");
        CHECK(strstr(nacre_context_last_error(ctx), "malformed") == NULL);
        free(deep);
    }
    /* Brackets inside strings do not count; a shallow error stays "malformed JSON". */
    const char *text = "{\"a\": \"[[[[[[\", \"b\": [1,, 2]}";
    expect_failure(ctx, &c, text, strlen(text), NACRE_ERROR_PARSE, "t.json:1:", "malformed JSON");

    /* \u0000 used to end the path early and load "a.obj". */
    text = OBJ("{\"material\": \"m\", \"mesh\": \"meshes/suzanne.obj\\u0000.png\"}");
    expect_failure(ctx, &c, text, strlen(text), INVALID, "t.json: objects[0].mesh: contains \\u0000", NULL);
    text = OBJ("{\"material\": \"m\", " SPHERE ", \"name\": \"\\u0000\"}");
    expect_failure(ctx, &c, text, strlen(text), INVALID, "objects[0].name: contains \\u0000", NULL);
    text = MAT("{\"type\": \"translucent\", \"layers\": [{\"preset\": \"skin1\", \"depth\": 1}], \"depth_map\": \"layered_depth.png\\u0000\"}");
    expect_failure(ctx, &c, text, strlen(text), INVALID, "materials.m.depth_map: contains \\u0000", NULL);
    /* An escaped backslash followed by "u0000" is no NUL: the file name is looked for as written. */
    text = OBJ("{\"material\": \"m\", \"mesh\": \"a\\\\u0000.obj\"}");
    expect_failure(ctx, &c, text, strlen(text), NACRE_ERROR_IO, "cannot open mesh file \"a\\u0000.obj\"", NULL);
    nacre_context_destroy(ctx);
    CHECK(c.live == 0);
}

/* single_scattering: "auto" by default, the three names, and true / false (a bool before "auto"). */
static void test_single_scattering_values(void)
{
    counter c;
    nacre_context *ctx = make_context(&c);
    const struct {
        const char *json;
        nacre_single_scattering want;
    } cases[] = {{"{}", NACRE_SINGLE_SCATTERING_AUTO},
                 {"{\"render\": {\"single_scattering\": \"auto\"}}", NACRE_SINGLE_SCATTERING_AUTO},
                 {"{\"render\": {\"single_scattering\": \"on\"}}", NACRE_SINGLE_SCATTERING_ON},
                 {"{\"render\": {\"single_scattering\": \"off\"}}", NACRE_SINGLE_SCATTERING_OFF},
                 {"{\"render\": {\"single_scattering\": true}}", NACRE_SINGLE_SCATTERING_ON},
                 {"{\"render\": {\"single_scattering\": false}}", NACRE_SINGLE_SCATTERING_OFF}};
    for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
        nacre_scene *s = NULL;
        nacre_scene_file_settings fs;
        CHECK(load(ctx, cases[i].json, &s, &fs) == NACRE_OK);
        CHECK(fs.render.diffusion.single_scattering == cases[i].want);
        nacre_scene_destroy(s);
    }
    nacre_context_destroy(ctx);
}

int main(void)
{
    test_full_scene();
    test_single_scattering_values();
    test_bad_inputs();
    test_limits_and_nul();
    test_files();
    test_patterns();
    test_layers();
    test_examples();
    test_out_of_memory();
    return TEST_MAIN_END();
}
