/*
 * gltf.h: the glTF 2.0 importer's entry for the scene-file loader (a scene file's "import"):
 * nc_gltf_import adds a glTF's meshes, materials, lights and camera to an existing scene.
 * Private to the library; the mapping is in docs/scene-format.md, "glTF 2.0 scenes".
 */
#ifndef NACRE_IO_GLTF_H
#define NACRE_IO_GLTF_H

#include "core/core.h"

/* Add the file's contents to `scene` (options as nacre_scene_load_gltf; NULL for defaults).
 * `report` must not be NULL. On failure the scene may hold part of the file. */
nacre_result nc_gltf_import(nacre_scene *scene, const char *path, const nacre_gltf_options *options,
                            nacre_gltf_report *report);

/* Whether a path names a glTF file (.gltf or .glb, any case). */
bool nc_gltf_is_path(const char *path);
/* The structure checks the importer runs before assimp sees a glTF (GLB chunks, buffers, views,
 * accessors against their views, the node tree), for any other reader of the file:
 * nacre_mesh_load runs them too, since assimp trusts a file's counts (a mutated accessor count
 * made it ask for 4 GB). */
nacre_result nc_gltf_check(nacre_context *ctx, const char *path);

#endif
