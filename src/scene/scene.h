/*
 * scene.h: the scene's storage (private). Elements live in flat arrays indexed by handle id - 1.
 * Meshes keep their rest-pose data; nacre_scene_commit() evaluates each object's deformers and
 * transform into world-space arrays that the render stages read.
 *
 * Change tracking: every edit bumps one of the version counters below, so a renderer can tell
 * which of its cached stages are stale (see src/render/render.c).
 */
#ifndef NACRE_SCENE_H
#define NACRE_SCENE_H

#include "core/core.h"
#include "core/math.h"

/* Where an element came from, so that nacre_scene_save_file can refer to it instead of writing
 * its data again: set by the scene-file loader (nc_scene_set_*_source), absent (NULL path, no
 * shape) for elements made by the C API from raw arrays, which the writer writes out. */
typedef struct nc_mesh_rec {
    nacre_mesh_data data; /* rest pose, object space; owned */
    char *source_path;    /* owned, absolute: the mesh file it was loaded from, or NULL */
    bool from_shape;      /* made by nacre_mesh_make_shape(&shape) */
    nacre_shape_desc shape;
} nc_mesh_rec;

typedef struct nc_object_rec {
    nacre_object_desc desc; /* desc.name points at `name` */
    char *name;             /* owned, may be NULL */
    /* Committed world-space geometry (owned; vertex_count of the mesh each). UVs are the mesh's. */
    float *world_positions; /* 3 per vertex */
    float *world_normals;   /* 3 per vertex, unit */
    uint32_t world_capacity; /* vertices allocated */
    float bounds_min[3], bounds_max[3];
    nc_mat4 object_to_world;
} nc_object_rec;

/* A density volume (NACRE_PATTERN_VOLUME), see nacre_volume_data. */
typedef struct nc_volume_rec {
    uint32_t dims[3];
    float origin[3], spacing[3];
    float *data;          /* owned; dims[0] * dims[1] * dims[2] floats, x fastest */
    float min_value, max_value; /* over all samples: trilinear + clamp stays inside */
    /* Optional (NULL: none), borrowed: per block of 8^3 samples (block_res per axis, x
     * fastest) the largest sample of the block and of its neighbours, so that a lookup whose
     * lower corner lies in a block of 0 is 0 without reading the samples (particle grids). */
    const float *block_max;
    uint32_t block_res;
    char *source_path;    /* owned, absolute: the NRRD file it was read from, or NULL */
    uint32_t source_channel; /* the file's channel that was read */
    float source_scale;   /* density_scale the file's samples were multiplied by */
    char *source_grid;    /* owned: the OpenVDB grid named in the scene file, or NULL */
} nc_volume_rec;

/* A texture (nacre_scene_add_texture): tightly packed rows, top row first. */
typedef struct nc_texture_rec {
    int32_t width, height, channels;
    float *data;                        /* owned; width * height * channels floats */
    float min_value[4], max_value[4];   /* per channel: bilinear lookups stay inside */
    char *source_path;                  /* owned, absolute: the image it was read from, or NULL */
} nc_texture_rec;

/* A fog (nacre_fog_desc) with what the renderers derive from it once. */
typedef struct nc_fog_rec {
    nacre_fog_desc desc;
    nacre_material_desc medium; /* sigma_a, sigma_s, g, pattern as a translucent material, so that
                                   nc_medium_eval serves fogs and objects alike */
    nacre_material_desc emission; /* sigma_a: the emission, pattern as `medium` with a clear
                                     medium 2, so that nc_medium_eval gives emission at points */
    bool emissive;              /* some channel of desc.emission > 0 */
    bool emission_patterned;    /* `emission` varies in space (its pattern, or the emission_pattern) */
    nc_mat4 world_to_local;     /* p -> R^-1 (p - center) */
} nc_fog_rec;

typedef struct nc_light_rec {
    nacre_light_desc desc;  /* normalised direction */
    nacre_light_desc given; /* as passed: saving it reproduces `desc` bit for bit on reload,
                               where normalising the normalised direction again might not */
} nc_light_rec;

typedef struct nc_versions {
    uint64_t geometry;  /* meshes, objects, transforms, deformers, commit time */
    uint64_t materials;
    uint64_t lights;
    uint64_t camera;
    uint64_t environment; /* and fogs */
} nc_versions;

struct nc_particles_rec; /* src/particles/scene_particles.c */

/* Volume handles with this bit refer to the density grid of particle system (id & ~bit), made
 * at commit; they never reach scene files. */
#define NC_PARTICLE_VOLUME_BIT 0x80000000u

struct nacre_scene {
    nacre_context *ctx;
    uint64_t uid; /* distinguishes scenes for renderer caches (address reuse is possible) */
    nc_mesh_rec *meshes;
    uint32_t mesh_count, mesh_capacity;
    nacre_material_desc *materials;
    uint32_t material_count, material_capacity;
    char **material_names;      /* owned, NULL or one per material (names from a scene file) */
    uint32_t material_name_capacity;
    nc_object_rec *objects;
    uint32_t object_count, object_capacity;
    nc_light_rec *lights;
    uint32_t light_count, light_capacity;
    nc_volume_rec *volumes;
    uint32_t volume_count, volume_capacity;
    nc_texture_rec *textures;
    uint32_t texture_count, texture_capacity;
    nc_fog_rec fogs[NACRE_MAX_FOGS];
    uint32_t fog_count;         /* the scene's fogs, then particle_fog_count made at commit */
    uint32_t particle_fog_count; /* one per particle system with particles at the commit time */
    struct nc_particles_rec *particles;
    uint32_t particles_count, particles_capacity;
    uint64_t particles_version;  /* bumped by particle edits */
    uint64_t particles_built;    /* particles_version the fogs were made from, 0: none */
    double particles_time;       /* time they were made for */
    nacre_camera_desc camera;
    bool has_camera;
    float environment[3];
    float unit_mm;
    nc_versions versions;       /* bumped by every edit */
    nc_versions committed;      /* versions at the last commit */
    bool committed_valid;       /* commit done and nothing edited since */
    double time;                /* time of the last commit */
    float bounds_min[3], bounds_max[3]; /* world, committed */
    char **inputs;              /* files the scene was built from (nacre_scene_input_path) */
    uint32_t input_count, input_capacity;
};

/* Record a file the scene was built from (a scene file's meshes, depth maps, volumes); copied. */
nacre_result nc_scene_note_input(nacre_scene *scene, const char *path);

/* Sources of elements (see nc_mesh_rec), recorded by the scene-file loader; paths are stored
 * absolute (realpath) so that a later save finds them whatever the working directory. A mesh
 * gets a file path or a shape (the other NULL). */
nacre_result nc_scene_set_mesh_source(nacre_scene *scene, nacre_mesh mesh, const char *path,
                                      const nacre_shape_desc *shape);
nacre_result nc_scene_set_volume_source(nacre_scene *scene, nacre_volume volume, const char *path,
                                        uint32_t channel, float density_scale);
/* The grid a .vdb volume was read from when the scene file named it (copied). */
nacre_result nc_scene_set_volume_grid(nacre_scene *scene, nacre_volume volume, const char *grid);
nacre_result nc_scene_set_texture_source(nacre_scene *scene, nacre_texture texture, const char *path);
/* A material's name in its scene file (copied); nc_scene_material_name is NULL when unnamed. */
nacre_result nc_scene_set_material_name(nacre_scene *scene, nacre_material material, const char *name);
const char *nc_scene_material_name(const nacre_scene *scene, nacre_material material);

/* Lookup helpers: NULL when the handle is invalid. */
const nc_mesh_rec *nc_scene_mesh(const nacre_scene *scene, nacre_mesh mesh);
const nacre_material_desc *nc_scene_material(const nacre_scene *scene, nacre_material material);
/* Depth range along a view's -z axis of the committed bounds' corners, where both raster and
 * path-traced cameras fit their automatic near/far planes; (0.01, 100) for empty bounds. */
void nc_scene_view_depth_range(const nacre_scene *scene, const nc_mat4 *view, float *dmin, float *dmax);
const nc_volume_rec *nc_scene_volume(const nacre_scene *scene, nacre_volume volume);
const nc_texture_rec *nc_scene_texture(const nacre_scene *scene, nacre_texture texture);

/* Fill a fog record from a checked desc (scene.c; also used for the fogs of particles). */
void nc_scene_store_fog(nc_fog_rec *rec, const nacre_fog_desc *desc);
/* The user's fogs: fogs[0 .. nc_scene_user_fogs) (the rest are particle systems'). */
static inline uint32_t nc_scene_user_fogs(const nacre_scene *s) { return s->fog_count - s->particle_fog_count; }
/* Particle systems (src/particles/scene_particles.c): simulate and splat them at `time` into
 * their fogs when they or the time changed; drop those fogs; free them. */
nacre_result nc_scene_commit_particles(nacre_scene *scene, double time);
void nc_scene_drop_particle_fogs(nacre_scene *scene);
void nc_scene_free_particles(nacre_scene *scene);
const nc_volume_rec *nc_scene_particle_volume(const nacre_scene *scene, uint32_t index);

/* Evaluate the deformer chain at a rest-pose point (exposed for tests and the voxelizer). */
nc_vec3 nc_deform_point(const nacre_deformer *deformers, uint32_t count, double time, nc_vec3 p);
/* Object transform matrix from translate / rotate (degrees, x then y then z) / scale. */
nc_mat4 nc_transform_matrix(const nacre_transform *t);

#endif /* NACRE_SCENE_H */
