/*
 * nacre.h: the public C API of nacre, a CPU renderer for translucent materials (jade, marble,
 * milk, skin, wax) and participating media, with a reference path tracer as ground truth.
 *
 * STEP BY STEP (this compiles; see examples/minimal.c)
 *
 *     nacre_context *ctx = NULL;
 *     nacre_context_create(NULL, &ctx);                 // NULL desc: malloc/free, all cores
 *     nacre_scene *scene = NULL;
 *     nacre_scene_create(ctx, &scene);
 *
 *     nacre_mesh_data sphere = {0};
 *     nacre_shape_desc shape = nacre_shape_desc_defaults(NACRE_SHAPE_SPHERE);
 *     nacre_mesh_make_shape(ctx, &shape, &sphere);     // library allocates, you free
 *     nacre_mesh mesh;
 *     nacre_scene_add_mesh(scene, &sphere, &mesh);     // copied: free yours now
 *     nacre_mesh_data_free(ctx, &sphere);
 *
 *     nacre_material_desc md = nacre_material_desc_defaults(NACRE_MATERIAL_OPAQUE);
 *     nacre_material mat;
 *     nacre_scene_add_material(scene, &md, &mat);
 *     nacre_object_desc od = nacre_object_desc_defaults();
 *     od.mesh = mesh; od.material = mat;
 *     nacre_object obj;
 *     nacre_scene_add_object(scene, &od, &obj);
 *
 *     nacre_light_desc ld = nacre_light_desc_defaults(NACRE_LIGHT_DIRECTIONAL);
 *     nacre_light light;
 *     nacre_scene_add_light(scene, &ld, &light);
 *     nacre_camera_desc cam = nacre_camera_desc_defaults();
 *     nacre_scene_set_camera(scene, &cam);
 *
 *     nacre_scene_commit(scene, 0.0);                   // evaluates deformers at time 0
 *     nacre_render_settings rs = nacre_render_settings_defaults();
 *     nacre_image img = {0};
 *     if (nacre_render(scene, &rs, &img, NULL) != NACRE_OK)
 *         fprintf(stderr, "%s\n", nacre_context_last_error(ctx));
 *     nacre_image_write(ctx, &img, "out.exr", NULL);
 *     nacre_image_free(ctx, &img);
 *     nacre_scene_destroy(scene);
 *     nacre_context_destroy(ctx);
 *
 * UNITS AND CONVENTIONS
 *   - Scene units are millimetres unless the scene says otherwise; absorption and scattering
 *     coefficients (sigma_a, sigma_s) are per scene unit.
 *   - Right-handed coordinates, y up by default (the camera's up vector decides). Triangles wind
 *     counter-clockwise seen from outside (the front face).
 *   - Colours are linear Rec.709 RGB. A directional light's strength is irradiance (W/m^2, per unit
 *     area perpendicular to the light); a point or spot light's strength is intensity (W/sr).
 *     The environment colour is a radiance. Rendered images hold radiance.
 *   - Angles in descs are degrees unless a field says otherwise.
 *   - Images are row-major, top row first, `channels` interleaved floats per pixel.
 *
 * OWNERSHIP
 *   - Objects made by nacre_X_create are freed by nacre_X_destroy; destroy(NULL) does nothing.
 *   - Plain data (nacre_image, nacre_mesh_data) filled by the library is allocated with the
 *     context's allocator and freed with nacre_image_free / nacre_mesh_data_free.
 *   - Descs and arrays passed in are copied unless a field says "borrowed".
 *   - Scene elements are typed index handles; id 0 is never valid, so a zeroed handle is invalid.
 *
 * MEMORY
 *   - Every allocation the library makes goes through the context and counts against its memory
 *     limit (nacre_context_desc.memory_limit; default half of physical memory). Large buffers
 *     (voxel grids, solver arrays, shadow maps, images, volumes) are also estimated before they
 *     are made, and file headers are checked against the file's size before anything is
 *     allocated for them, so a bad setting or a corrupt file fails with one message instead of
 *     being killed by the system. Memory held by the mesh importer and Embree is not counted.
 *
 * THREADING
 *   - Contexts are independent. The library has no global mutable state.
 *   - A scene has one writer at a time. Between nacre_scene_commit and the next edit, a scene may
 *     be rendered from several threads at once, each with its own nacre_renderer.
 *   - Each render uses OpenMP with the context's thread count; results do not depend on it.
 *
 * ERRORS
 *   Functions that act return nacre_result (NACRE_OK = 0). On failure the context keeps a one-line
 *   message, "file:line:col: field: problem" where those are known, for the thread that called:
 *   nacre_context_last_error() on that thread reads it until that thread's next failure on the
 *   context, whatever other threads do meanwhile. The library never prints; an optional log
 *   callback in the context desc receives the same messages (from any thread).
 *
 * nacre DOES NOT (yet)
 *   - run on a GPU: everything is CPU code (OpenMP + AVX2 where the compiler targets it);
 *   - implement NACRE_METHOD_LAYERED (its issue is open): it returns NACRE_ERROR_UNSUPPORTED;
 *   - light fog with point or spot lights, or shadow it, outside the path tracer: phong and
 *     diffusion draw fog by an analytic post pass (directional lights and the environment);
 *   - animate anything but deformers and particle systems (time-dependent) and edits between
 *     commits.
 *
 * HEADERS
 *   This header includes the whole API; each module header also compiles on its own:
 *     nacre/core.h    NACRE_API, version, result codes, context, allocator, log, memory limit
 *     nacre/image.h   nacre_image: alloc, free, read, write, compare, non-finite pixels
 *     nacre/mesh.h    nacre_mesh_data: shapes, loading, validation, normals, tangents, analysis
 *     nacre/scene.h   the scene: materials, media, layers, volumes, textures, deformers, objects,
 *                     lights, camera, fog, units and material presets
 *     nacre/render.h  methods, render settings, stats, the renderer; scene files (load, save)
 *     nacre/slab.h    slab measurement (validation against exact results)
 *     nacre/voxel.h   voxelization of triangle meshes
 *     nacre/particles.h  particle systems (emitters, lists) as media: simulation, density grid
 *   Their include guards are NACRE_PUBLIC_<NAME>_H: the library's private headers use
 *   NACRE_<NAME>_H (src/core/core.h, src/scene/scene.h).
 */
#ifndef NACRE_NACRE_H
#define NACRE_NACRE_H

#include <nacre/core.h>
#include <nacre/image.h>
#include <nacre/mesh.h>
#include <nacre/scene.h>
#include <nacre/render.h>
#include <nacre/slab.h>
#include <nacre/voxel.h>
#include <nacre/particles.h>

#endif /* NACRE_NACRE_H */
