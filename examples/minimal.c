/*
 * minimal.c: the smallest program that embeds nacre: a sphere on the default camera, lit by a
 * sun, rendered with the phong method and written as EXR. Built and run by the test suite.
 * usage: minimal [OUT.exr]
 */
#include <nacre/nacre.h>

#include <stdio.h>

int main(int argc, char **argv)
{
    const char *out_path = argc > 1 ? argv[1] : "minimal.exr";
    nacre_context *ctx = NULL;
    if (nacre_context_create(NULL, &ctx) != NACRE_OK)
        return 1;
    nacre_scene *scene = NULL;
    nacre_mesh_data sphere = {0};
    nacre_image img = {0};
    int rc = 1;
    if (nacre_scene_create(ctx, &scene) != NACRE_OK)
        goto out;

    nacre_shape_desc shape = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
    nacre_mesh mesh;
    if (nacre_mesh_make_shape(ctx, &shape, &sphere) != NACRE_OK ||
        nacre_scene_add_mesh(scene, &sphere, &mesh) != NACRE_OK) /* copied */
        goto out;

    nacre_material_desc md = nacre_material_desc_defaults(NACRE_MATERIAL_OPAQUE);
    nacre_material mat;
    nacre_object_desc od = nacre_object_desc_defaults();
    nacre_object obj;
    if (nacre_scene_add_material(scene, &md, &mat) != NACRE_OK)
        goto out;
    od.mesh = mesh;
    od.material = mat;
    if (nacre_scene_add_object(scene, &od, &obj) != NACRE_OK)
        goto out;

    nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
    nacre_light light;
    nacre_camera_desc cam = nacre_camera_desc_defaults();
    if (nacre_scene_add_light(scene, &ld, &light) != NACRE_OK || nacre_scene_set_camera(scene, &cam) != NACRE_OK)
        goto out;

    nacre_render_settings rs = nacre_render_settings_defaults();
    rs.width = 160;
    rs.height = 120;
    if (nacre_scene_commit(scene, 0.0) != NACRE_OK || nacre_render(scene, &rs, &img, NULL) != NACRE_OK ||
        nacre_image_write(ctx, &img, out_path, NULL) != NACRE_OK)
        goto out;
    /* The sphere fills the centre of the view: the middle pixel must be lit. */
    const float *centre = img.pixels + (size_t)(img.height / 2) * img.stride + 3 * (size_t)(img.width / 2);
    if (!(centre[0] > 0.0f))
        goto out;
    printf("wrote %s\n", out_path);
    rc = 0;
out:
    if (rc)
        fprintf(stderr, "minimal: %s\n", nacre_context_last_error(ctx));
    nacre_image_free(ctx, &img);
    nacre_mesh_data_free(ctx, &sphere);
    nacre_scene_destroy(scene);
    nacre_context_destroy(ctx);
    return rc;
}
