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
 *   message, "file:line:col: field: problem" where those are known, readable with
 *   nacre_context_last_error() until the next failure on that context. The library never prints;
 *   an optional log callback in the context desc receives the same messages.
 *
 * nacre DOES NOT (yet)
 *   - run on a GPU: everything is CPU code (OpenMP + AVX2 where the compiler targets it);
 *   - implement NACRE_METHOD_LAYERED (its issue is open): it returns NACRE_ERROR_UNSUPPORTED;
 *   - animate anything but deformers (time-dependent) and edits between commits.
 */
#ifndef NACRE_NACRE_H
#define NACRE_NACRE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#if defined(NACRE_BUILDING) && defined(__GNUC__)
#define NACRE_API __attribute__((visibility("default")))
#else
#define NACRE_API
#endif

/* ------------------------------------------------------------------------------------------ */
/* Version, results                                                                          */
/* ------------------------------------------------------------------------------------------ */

#define NACRE_VERSION_MAJOR 0
#define NACRE_VERSION_MINOR 1
#define NACRE_VERSION_PATCH 0

/* Result codes and their names come from this one list. */
#define NACRE_RESULT_LIST(X)                                                                   \
    X(NACRE_OK, 0, "ok")                                                                       \
    X(NACRE_ERROR_INVALID_ARGUMENT, 1, "invalid argument")                                     \
    X(NACRE_ERROR_IO, 2, "input/output error")                                                 \
    X(NACRE_ERROR_PARSE, 3, "parse error")                                                     \
    X(NACRE_ERROR_OUT_OF_MEMORY, 4, "out of memory")                                           \
    X(NACRE_ERROR_UNSUPPORTED, 5, "not supported")                                             \
    X(NACRE_ERROR_CANCELLED, 6, "cancelled")                                                   \
    X(NACRE_ERROR_INVALID_OPERATION, 7, "invalid operation")

typedef enum nacre_result {
#define NACRE_RESULT_ENUM_(name, value, text) name = value,
    NACRE_RESULT_LIST(NACRE_RESULT_ENUM_)
#undef NACRE_RESULT_ENUM_
} nacre_result;

/* Version string "MAJOR.MINOR.PATCH". */
NACRE_API const char *nacre_version(void);
/* Short English name of a result code ("parse error"). */
NACRE_API const char *nacre_result_string(nacre_result result);

/* ------------------------------------------------------------------------------------------ */
/* Context: allocator, threads, error messages                                               */
/* ------------------------------------------------------------------------------------------ */

typedef struct nacre_context nacre_context;

typedef enum nacre_log_level { NACRE_LOG_ERROR = 0, NACRE_LOG_WARNING, NACRE_LOG_INFO } nacre_log_level;

/* Reentrant: may be called from several threads at once. */
typedef void (*nacre_log_fn)(void *user, nacre_log_level level, const char *message);

typedef struct nacre_allocator {
    void *(*alloc_fn)(size_t size, void *user); /* NULL with free_fn NULL: malloc */
    void (*free_fn)(void *ptr, void *user);     /* must accept NULL */
    void *user;
} nacre_allocator;

typedef struct nacre_context_desc {
    nacre_allocator allocator; /* zero: malloc/free */
    int threads;               /* 0: all hardware threads; 1: serial (debugging) */
    nacre_log_fn log_fn;       /* optional */
    void *log_user;
    /* Bytes the library may hold at once through this context (images, meshes, voxel grids,
     * shadow maps, solver arrays, volumes). 0: half of physical memory, or less when the
     * process's address space is limited (RLIMIT_AS, `ulimit -v`). An allocation or an estimate
     * made before a large allocation that would go over it fails with NACRE_ERROR_OUT_OF_MEMORY
     * and a message naming the size needed and this limit. */
    uint64_t memory_limit;
} nacre_context_desc;

/* Create a context. desc may be NULL (defaults). */
NACRE_API nacre_result nacre_context_create(const nacre_context_desc *desc, nacre_context **out);
/* Destroy a context; every scene and renderer made from it must be destroyed first. */
NACRE_API void nacre_context_destroy(nacre_context *ctx);
/* Message of the latest failure on this context ("" if none). Valid until the next failure. */
NACRE_API const char *nacre_context_last_error(const nacre_context *ctx);
/* Result code of the latest failure on this context (NACRE_OK if none). */
NACRE_API nacre_result nacre_context_last_result(const nacre_context *ctx);
/* Forget the latest failure. */
NACRE_API void nacre_context_clear_error(nacre_context *ctx);
/* Number of threads renders use (resolved from the desc). */
NACRE_API int nacre_context_threads(const nacre_context *ctx);
/* Free one array the library allocated through this context (e.g. normals it computed into a
 * mesh the caller built). NULL does nothing. */
NACRE_API void nacre_free(nacre_context *ctx, void *ptr);
/* The memory limit in bytes (resolved from the desc), and a new one (0: the default again).
 * Lowering it below what is in use fails later allocations only; nothing is freed. */
NACRE_API uint64_t nacre_context_memory_limit(const nacre_context *ctx);
NACRE_API nacre_result nacre_context_set_memory_limit(nacre_context *ctx, uint64_t bytes);
/* Bytes held now through this context, and the most held at once since its creation. */
NACRE_API uint64_t nacre_context_memory_used(const nacre_context *ctx);
NACRE_API uint64_t nacre_context_memory_peak(const nacre_context *ctx);

/* ------------------------------------------------------------------------------------------ */
/* Images                                                                                     */
/* ------------------------------------------------------------------------------------------ */

/* A float image: `channels` floats per pixel, rows `stride` floats apart, top row first. */
typedef struct nacre_image {
    int32_t width, height, channels;
    size_t stride; /* floats from one row to the next, >= width * channels */
    float *pixels;
} nacre_image;

typedef enum nacre_exr_pixel { NACRE_EXR_HALF = 0, NACRE_EXR_FLOAT } nacre_exr_pixel;

typedef struct nacre_image_write_options {
    float exposure;           /* PNG: pixels are scaled by 2^exposure before sRGB encoding */
    nacre_exr_pixel exr_type; /* EXR: half (default) or float */
} nacre_image_write_options;

/* Image comparison metrics over all pixels and channels (see nacre_image_compare). */
typedef struct nacre_image_metrics {
    double rmse;          /* sqrt(mean((a-b)^2)) */
    double rel_mse;       /* mean((a-b)^2 / (b^2 + 1e-2)), b = reference */
    double psnr;          /* 10 log10(peak^2 / mse), peak = max reference value; inf if equal */
    double mean_rel_err;  /* mean(|a-b| / |b|) over values with b != 0 */
    double max_abs_err;   /* max |a-b| */
    uint64_t count;       /* values compared (pixels * channels, less those left out below) */
    uint64_t nonzero_ref; /* values with b != 0 */
    /* Pixels with a NaN or infinite channel in the test and in the reference image. Values that
     * are not finite in either image are left out of every metric above: check these first. */
    uint64_t nonfinite_test, nonfinite_ref;
} nacre_image_metrics;

/* Allocate a zeroed image (stride = width * channels). 1 <= width, height <= 65536. */
NACRE_API nacre_result nacre_image_alloc(nacre_context *ctx, int32_t width, int32_t height,
                                         int32_t channels, nacre_image *out);
/* Free pixels allocated by the library and zero the struct. */
NACRE_API void nacre_image_free(nacre_context *ctx, nacre_image *image);
/* Write by extension: .png (8-bit sRGB, exposure-scaled, RGB or RGBA) or .exr (linear).
 * Written to a temporary file in the same folder, then renamed: no partial file is left.
 * options may be NULL (exposure 0, half EXR). EXR refuses images holding NaN or infinities
 * (INVALID_ARGUMENT naming the first pixel). Half EXR holds magnitudes up to 65504: larger values
 * are written as +-65504 and a warning with their count goes to the context's log callback. */
NACRE_API nacre_result nacre_image_write(nacre_context *ctx, const nacre_image *image,
                                         const char *path, const nacre_image_write_options *options);
NACRE_API nacre_result nacre_image_write_png(nacre_context *ctx, const nacre_image *image,
                                             const char *path, float exposure);
NACRE_API nacre_result nacre_image_write_exr(nacre_context *ctx, const nacre_image *image,
                                             const char *path, nacre_exr_pixel type);
/* Read .png (sRGB decoded to linear, 8 or 16 bit) or .exr (R, G, B and A if present). The
 * result has 3 or 4 channels. */
/* Pixels with a NaN or infinite channel; the first one (row-major) in *x, *y and its channel in
 * *c when there is one (any pointer may be NULL). 0 for a NULL image. */
NACRE_API uint64_t nacre_image_count_nonfinite(const nacre_image *image, int32_t *x, int32_t *y, int32_t *c);
NACRE_API nacre_result nacre_image_read(nacre_context *ctx, const char *path, nacre_image *out);
/* As nacre_image_read, but PNG samples are read as data (value / 255 or / 65535, no sRGB
 * decoding): for depth maps and other non-colour images. */
NACRE_API nacre_result nacre_image_read_data(nacre_context *ctx, const char *path, nacre_image *out);
/* Compare `test` against `reference` (same size and channel count). */
NACRE_API nacre_result nacre_image_compare(nacre_context *ctx, const nacre_image *test,
                                           const nacre_image *reference, nacre_image_metrics *out);

/* ------------------------------------------------------------------------------------------ */
/* Mesh data: plain arrays, owned by whoever allocated them                                   */
/* ------------------------------------------------------------------------------------------ */

typedef struct nacre_mesh_data {
    uint32_t vertex_count;
    uint32_t triangle_count;
    float *positions; /* 3 floats per vertex */
    float *normals;   /* 3 per vertex, unit length, or NULL */
    float *uvs;       /* 2 per vertex, or NULL */
    float *tangents;  /* 4 per vertex: unit xyz + handedness w = +-1 (bitangent = w n x t), or NULL */
    uint32_t *indices; /* 3 per triangle, counter-clockwise seen from outside */
} nacre_mesh_data;

/* What mesh analysis reports. Edges are counted after welding exactly coincident positions. */
typedef struct nacre_mesh_info {
    uint32_t vertex_count, triangle_count;
    uint32_t welded_vertex_count;     /* distinct positions among referenced vertices */
    uint32_t unreferenced_vertices;   /* vertices no triangle uses */
    uint32_t degenerate_triangles;    /* zero area after welding (repeated vertex or collinear) */
    uint64_t edge_count;              /* undirected edges after welding */
    uint64_t boundary_edges;          /* used by one triangle */
    uint64_t nonmanifold_edges;       /* used by three or more triangles */
    bool closed;                      /* no boundary and no non-manifold edges */
    float bounds_min[3], bounds_max[3];
    double surface_area;
} nacre_mesh_info;

typedef enum nacre_shape_type {
    NACRE_SHAPE_SPHERE = 0, /* radius, segments (around) x rings */
    NACRE_SHAPE_BOX,        /* size[3], centred at the origin, per-face UVs */
    NACRE_SHAPE_PLANE,      /* size[0] x size[2] in the xz plane, normal +y */
    NACRE_SHAPE_TORUS       /* radius (major), minor_radius, in the xz plane */
} nacre_shape_type;

typedef struct nacre_shape_desc {
    nacre_shape_type type;
    float radius;        /* sphere radius; torus major radius */
    float minor_radius;  /* torus tube radius */
    float size[3];       /* box extents; plane uses size[0] and size[2] */
    uint32_t segments;   /* subdivisions around (sphere, torus) or per side (box, plane) */
    uint32_t rings;      /* subdivisions from pole to pole (sphere) or around the tube (torus) */
} nacre_shape_desc;

/* Defaults: sphere r=1 64x32, box 1x1x1, plane 10x10, torus 1/0.25 64x32. */
NACRE_API nacre_shape_desc nacre_shape_desc_defaults(nacre_shape_type type);
/* Build a shape with positions, normals, UVs and tangents. Closed shapes are watertight (shared
 * vertices along seams are exactly coincident). */
NACRE_API nacre_result nacre_mesh_make_shape(nacre_context *ctx, const nacre_shape_desc *desc,
                                             nacre_mesh_data *out);
/* Load OBJ, PLY (ASCII/binary) or glTF 2.0 (.gltf/.glb); all meshes in the file are merged,
 * with node transforms applied. Polygons are triangulated: by assimp when none has more than 64
 * corners, otherwise by nacre, in time linear in the corners for convex polygons (and those
 * star-shaped around their first corner, which become fans) and by ear clipping for others of
 * up to 512 corners; a longer polygon of that kind fails with UNSUPPORTED naming the face.
 * Normals and tangents are computed when missing (tangents need UVs; without UVs a tangent is
 * chosen perpendicular to the normal). Fails on empty meshes, non-finite positions and
 * out-of-range indices. */
NACRE_API nacre_result nacre_mesh_load(nacre_context *ctx, const char *path, nacre_mesh_data *out);
/* Free arrays allocated by the library and zero the struct. */
NACRE_API void nacre_mesh_data_free(nacre_context *ctx, nacre_mesh_data *mesh);
/* Check sizes, indices and finiteness; names the first problem. */
NACRE_API nacre_result nacre_mesh_validate(nacre_context *ctx, const nacre_mesh_data *mesh,
                                           const char *name);
/* (Re)compute area- and angle-weighted smooth normals across exactly coincident positions.
 * This and nacre_mesh_compute_tangents allocate a missing array through the context: free it
 * with nacre_mesh_data_free along with the rest, or alone with nacre_free. */
NACRE_API nacre_result nacre_mesh_compute_normals(nacre_context *ctx, nacre_mesh_data *mesh);
/* (Re)compute tangents from UVs (MikkTSpace-like per-vertex accumulation), orthogonalised
 * against the normals; needs normals. Without UVs, an arbitrary perpendicular frame. */
NACRE_API nacre_result nacre_mesh_compute_tangents(nacre_context *ctx, nacre_mesh_data *mesh);
/* Topology and size report. */
NACRE_API nacre_result nacre_mesh_analyze(nacre_context *ctx, const nacre_mesh_data *mesh,
                                          nacre_mesh_info *out);

/* ------------------------------------------------------------------------------------------ */
/* Scene description                                                                          */
/* ------------------------------------------------------------------------------------------ */

typedef struct nacre_scene nacre_scene;
typedef struct { uint32_t id; } nacre_mesh;
typedef struct { uint32_t id; } nacre_material;
typedef struct { uint32_t id; } nacre_object;
typedef struct { uint32_t id; } nacre_light;

/* Materials. Opaque: Lambert diffuse + normalized Blinn-Phong specular. Translucent: a
 * scattering medium bounded by the surface, homogeneous or patterned (sigma_a, sigma_s per
 * scene unit, Henyey-Greenstein g, relative index of refraction eta); the phong method shades it
 * as Lambert with the albedo of its diffuse reflectance (dipole Rd); later methods use the
 * medium. */
typedef enum nacre_material_type { NACRE_MATERIAL_OPAQUE = 0, NACRE_MATERIAL_TRANSLUCENT } nacre_material_type;

/* Heterogeneous media (diffusion, path tracer): the coefficients of a translucent material vary
 * over the object's rest-pose (undeformed mesh) coordinates, so patterns follow deformation.
 * The material's own sigma_a/sigma_s is medium 1; sigma_a2/sigma_s2 is medium 2. Cells are
 * aligned with the rest-pose origin. A point with a non-finite coordinate gets medium 1. The
 * phong method shades medium 1 only. Scene files: "pattern" (docs/scene-format.md). */
typedef enum nacre_pattern_type {
    NACRE_PATTERN_NONE = 0,   /* homogeneous */
    NACRE_PATTERN_RANDOM_MIX, /* cubic cells of `cell_size`, each medium 2 with probability `fraction` */
    NACRE_PATTERN_CHECKER,    /* 3D checker of `cell_size` alternating medium 1 and 2 */
    NACRE_PATTERN_NOISE,      /* fractal value noise (feature size `cell_size`, `octaves`) gives w in
                                 [0, 1]; sigma = (1 - w) * medium 1 + w * medium 2 */
    NACRE_PATTERN_VOLUME      /* a density d >= 0 from a volume (nacre_scene_add_volume, trilinear,
                                 clamped outside): sigma = d * medium 1; sigma_a2/sigma_s2 unused */
} nacre_pattern_type;

typedef struct { uint32_t id; } nacre_volume;

typedef struct nacre_medium_pattern {
    nacre_pattern_type type;
    float sigma_a2[3], sigma_s2[3]; /* medium 2, per scene unit */
    float cell_size;                /* rest-pose scene units, > 0 */
    float fraction;                 /* RANDOM_MIX: probability of medium 2, in [0, 1] */
    uint32_t seed;                  /* RANDOM_MIX, NOISE */
    uint32_t octaves;               /* NOISE: 1..12 */
    nacre_volume volume;            /* VOLUME */
} nacre_medium_pattern;

/* Layered materials (Francois, Pattanaik, Bouatouh, Breton 2006, "Subsurface texture mapping"):
 * up to NACRE_MAX_LAYERS media stacked under the surface, each with its own coefficients and
 * phase, above the material's own medium (the core, which keeps its pattern). The depth of a
 * point is its distance to the nearest point of the object's rest-pose mesh, and the depth map
 * is read at that nearest point's uv: for a surface that is flat over the depths involved this is
 * the seed's tangent-space lookup; on curved surfaces it is its exact 3D form. Layer j lies
 * between bottom(j - 1) (bottom(-1) = 0) and bottom(j), where bottom(j) is the largest of
 * depth(k) * map_k(u, v) for k <= j (a layer cannot end above the one before it: the running
 * maximum gives it zero thickness). Without a depth map map_k = 1 (layers of constant
 * thickness). Points deeper than the last bottom are in the core. The path tracer renders layered
 * media exactly; the diffusion method reports them as not implemented; the phong method shades the
 * core only. Scene files: "layers" and "depth_map" (docs/scene-format.md). */
#define NACRE_MAX_LAYERS 4
typedef struct { uint32_t id; } nacre_texture;

typedef struct nacre_layer {
    float sigma_a[3], sigma_s[3]; /* per scene unit; sigma_a + sigma_s > 0 in every channel */
    float g;                      /* Henyey-Greenstein anisotropy, in (-1, 1) */
    float depth;                  /* bottom below the surface, rest-pose scene units, >= 0; with a
                                     depth map, the scale of its channel (map value 1 = depth) */
} nacre_layer;

typedef struct nacre_layering {
    uint32_t count;                       /* 0 (not layered) .. NACRE_MAX_LAYERS */
    nacre_layer layers[NACRE_MAX_LAYERS]; /* from the surface inwards */
    nacre_texture depth_map;              /* optional (id 0: none): channel j scales layer j's depth,
                                             read bilinearly at the surface uv, repeating; needs
                                             at least `count` channels and a mesh with uvs */
} nacre_layering;

/* The range of a material's relative index of refraction eta (and of a slab's, for the diffusion
 * method). The diffusion boundary uses the polynomial fit of the diffuse Fresnel reflectance Fdr
 * (Egan and Hilgeman) in A = (1 + Fdr) / (1 - Fdr): Fdr reaches 1 near eta 3.85 and 0.26, where A
 * becomes infinite and the images NaN. [0.3, 3] keeps A within 1..30 and holds every real
 * material (water 1.33, glass 1.5, diamond 2.42) and its inverse down to 1 / 3. */
#define NACRE_ETA_MIN 0.3
#define NACRE_ETA_MAX 3.0

typedef struct nacre_material_desc {
    nacre_material_type type;
    float diffuse[3];  /* opaque: Lambert albedo in [0,1] */
    float specular[3]; /* Blinn-Phong specular albedo (both types) */
    float shininess;   /* Blinn-Phong exponent, >= 0 */
    float sigma_a[3];  /* translucent: absorption per scene unit, >= 0 */
    float sigma_s[3];  /* translucent: scattering per scene unit, >= 0 */
    float g;           /* Henyey-Greenstein anisotropy, in (-1, 1) */
    float eta;         /* relative index of refraction, in [NACRE_ETA_MIN, NACRE_ETA_MAX] */
    nacre_medium_pattern pattern; /* translucent: heterogeneity (default NONE); of the core when layered */
    nacre_layering layering;      /* translucent: layers above the core (default count 0) */
} nacre_material_desc;

/* Defaults: opaque grey 0.8, specular 0.04, shininess 64; translucent: the "jade" preset
 * (Blanchard 2012), g 0, eta 1.6, no pattern. Coefficients PER MILLIMETRE: in a scene whose unit
 * is not the millimetre, convert them with nacre_material_desc_per_unit. */
NACRE_API nacre_material_desc nacre_material_desc_defaults(nacre_material_type type);

/* Look up a named measured material (Jensen et al. 2001: "marble", "skimmilk", "wholemilk",
 * "cream", "ketchup", "apple", "potato", "chicken", "skin1", "skin2"; Blanchard 2012:
 * "jade", "aquamarine"), coefficients per millimetre, eta 1.3 for Jensen's. The
 * result is a translucent desc. Returns false if the name is unknown. */
NACRE_API bool nacre_material_preset(const char *name, nacre_material_desc *out);

/* Millimetres per unit of a named length unit: "mm" 1, "cm" 10, "m" 1000. False if unknown. */
NACRE_API bool nacre_units_mm(const char *name, float *mm_per_unit);
/* Turn a desc's coefficients (sigma_a, sigma_s of the core and of every layer) from per
 * millimetre into per scene unit, for a scene of `unit_mm` millimetres per unit (as given to
 * nacre_scene_set_unit_mm): presets and defaults are per millimetre, scenes are per unit.
 * Lengths (layer depths) are not touched. */
NACRE_API void nacre_material_desc_per_unit(nacre_material_desc *desc, float unit_mm);

/* Volumes for NACRE_PATTERN_VOLUME: a scalar density on a regular grid placed in the object's
 * rest-pose space. Sample (i, j, k) sits at origin + (i, j, k) * spacing (the NRRD convention:
 * "space origin" is the first sample's position). Between samples the density is trilinear;
 * outside the grid it is the value at the nearest boundary point (clamp). A material with
 * pattern VOLUME gets sigma_a = density * sigma_a and sigma_s = density * sigma_s (medium 1). */
typedef struct nacre_volume_data {
    uint32_t dims[3];  /* samples along x, y, z, each >= 1 */
    float origin[3];   /* rest-pose position of sample (0, 0, 0), scene units */
    float spacing[3];  /* distance between samples along x, y, z, scene units, > 0 */
    float *data;       /* dims[0] * dims[1] * dims[2] densities, x fastest, finite and >= 0 */
} nacre_volume_data;

/* Add a volume to a scene (data copied, validated; kept until the scene is destroyed). At most
 * 2^31 samples. A density of 0 makes sigma_t 0 there: fine for the path tracer, while the
 * diffusion approximation needs sigma_t > 0 where it solves. */
NACRE_API nacre_result nacre_scene_add_volume(nacre_scene *scene, const nacre_volume_data *data,
                                              nacre_volume *out);
/* Read a 3D NRRD file (raw encoding, little or big endian; int8/uint8/int16/uint16/int32/
 * uint32/float/double; optional leading channel axis, of which `channel` is read; placement from
 * "space origin" + axis-aligned "space directions", or "spacings"). Negative densities are
 * rejected. The library allocates `out->data`; free with nacre_volume_data_free. */
NACRE_API nacre_result nacre_volume_load_nrrd(nacre_context *ctx, const char *path, uint32_t channel,
                                              nacre_volume_data *out);
/* Free data allocated by the library and zero the struct. */
NACRE_API void nacre_volume_data_free(nacre_context *ctx, nacre_volume_data *volume);

/* Add a texture (pixels copied, 1 to 4 channels, every value finite and >= 0; kept until the
 * scene is destroyed). Row 0 is the top of the image and v = 0 its bottom row (v grows upwards,
 * the OBJ/glTF-flipped convention of most mesh exporters: texel (x, y) is centred at
 * u = (x + 0.5) / width, v = 1 - (y + 0.5) / height). Layer depth maps are data: read PNG depth
 * maps with nacre_image_read_data, not the sRGB-decoding nacre_image_read. */
NACRE_API nacre_result nacre_scene_add_texture(nacre_scene *scene, const nacre_image *image,
                                               nacre_texture *out);

typedef struct nacre_transform {
    float translate[3];
    float rotate[3]; /* Euler angles in degrees, applied about x, then y, then z */
    float scale[3];
} nacre_transform;

typedef enum nacre_deformer_type {
    NACRE_DEFORM_NONE = 0,
    NACRE_DEFORM_SCALE, /* non-uniform scale by `scale` about `center` */
    NACRE_DEFORM_TWIST, /* rotation about `axis` through `center` by angle * (s / length), s =
                           signed distance along the axis from the centre */
    NACRE_DEFORM_BEND   /* bends the `axis` direction into an arc of total `angle` over `length`,
                           towards `direction` (perpendicular to axis), starting at `center` */
} nacre_deformer_type;

/* A deformer acts on the mesh's own (rest-pose) coordinates before the object transform.
 * Time-dependent: the effective angle is angle + angle_rate * time, and the effective scale is
 * scale + scale_rate * time, so a scene can animate by committing at successive times. */
typedef struct nacre_deformer {
    nacre_deformer_type type;
    float center[3];
    float axis[3];      /* unit after normalisation; default +y */
    float direction[3]; /* bend: where the axis bends towards; default +x */
    float angle;        /* twist, bend: degrees */
    float angle_rate;   /* degrees per second */
    float length;       /* twist, bend: scene units over which `angle` accrues; default 1 */
    float scale[3];     /* scale deformer */
    float scale_rate[3];
} nacre_deformer;

#define NACRE_MAX_DEFORMERS 4

NACRE_API nacre_deformer nacre_deformer_defaults(nacre_deformer_type type);

typedef struct nacre_object_desc {
    const char *name;   /* copied; optional */
    nacre_mesh mesh;
    nacre_material material;
    nacre_transform transform;
    uint32_t deformer_count;
    nacre_deformer deformers[NACRE_MAX_DEFORMERS]; /* applied in order */
    bool cast_shadows;  /* default true */
    bool double_sided;  /* default false: back faces are culled */
} nacre_object_desc;

NACRE_API nacre_object_desc nacre_object_desc_defaults(void);

typedef enum nacre_light_type { NACRE_LIGHT_DIRECTIONAL = 0, NACRE_LIGHT_POINT, NACRE_LIGHT_SPOT } nacre_light_type;

typedef struct nacre_light_desc {
    nacre_light_type type;
    float direction[3];      /* directional, spot: the way the light travels (normalised) */
    float position[3];       /* point, spot */
    float strength[3];       /* directional: irradiance (W/m^2); point, spot: intensity (W/sr) */
    float inner_angle;       /* spot: full strength inside this half-angle (degrees) */
    float outer_angle;       /* spot: zero outside this half-angle (degrees) */
    float radius;            /* point, spot: emitter radius (path tracer), 0 = a point */
    float angular_radius;    /* directional: apparent radius in degrees (default the sun, 0.27) */
    bool cast_shadows;       /* default true */
} nacre_light_desc;

NACRE_API nacre_light_desc nacre_light_desc_defaults(nacre_light_type type);

typedef enum nacre_projection { NACRE_PERSPECTIVE = 0, NACRE_ORTHOGRAPHIC } nacre_projection;

typedef struct nacre_camera_desc {
    nacre_projection projection;
    float position[3];
    float target[3];
    float up[3];
    float fov_y;       /* perspective: vertical field of view, degrees */
    float ortho_height; /* orthographic: height of the view in scene units */
    float near_clip, far_clip; /* 0: chosen from the scene bounds */
} nacre_camera_desc;

NACRE_API nacre_camera_desc nacre_camera_desc_defaults(void);

/* Participating media in open space ("fog"; Hubert 2020: distance, height and local fog). A fog
 * fills the air around objects: a GLOBAL fog everywhere, a BOX fog inside a box. Translucent
 * objects displace it (inside them only their own medium counts); opaque objects sit in it.
 * Overlapping fogs add their coefficients (the phase function is their sigma_s-weighted mix).
 * Coefficients at a point p:
 *   sigma = height(p) * pattern(local(p)) with pattern() = sigma_a/sigma_s or the pattern's mix
 *   (as for materials: RANDOM_MIX, CHECKER, NOISE blend medium 1 and 2; VOLUME scales medium 1
 *   by the volume's density), local(p) = R^-1 (p - center) in scene units (R from `rotate`), and
 *   height(p) = exp(-height_falloff * (p.y - height_base)) (world y is up), its exponent capped
 *   at 60 so that the density stays finite far below.
 * Rendered by the path tracer; the real-time methods ignore fog so far. */
typedef enum nacre_fog_shape { NACRE_FOG_GLOBAL = 0, NACRE_FOG_BOX } nacre_fog_shape;

typedef struct { uint32_t id; } nacre_fog;

typedef struct nacre_fog_desc {
    nacre_fog_shape shape;
    float center[3];              /* origin of the local frame; BOX: the box's centre */
    float size[3];                /* BOX: edge lengths along the local axes, > 0 */
    float rotate[3];              /* Euler degrees, about x, then y, then z (as nacre_transform) */
    float sigma_a[3], sigma_s[3]; /* per scene unit, >= 0 */
    float g;                      /* Henyey-Greenstein anisotropy, in (-1, 1) */
    float height_falloff;         /* per scene unit, >= 0; 0: no height dependence */
    float height_base;            /* world y where height() = 1 */
    nacre_medium_pattern pattern; /* default NONE; medium 2 may be 0 (clear air) */
} nacre_fog_desc;

#define NACRE_MAX_FOGS 32

/* Defaults: GLOBAL, sigma_a 0, sigma_s 0.001 per unit, g 0, no height falloff, size 1. */
NACRE_API nacre_fog_desc nacre_fog_desc_defaults(nacre_fog_shape shape);
/* At most NACRE_MAX_FOGS per scene. */
NACRE_API nacre_result nacre_scene_add_fog(nacre_scene *scene, const nacre_fog_desc *desc, nacre_fog *out);
NACRE_API nacre_result nacre_scene_set_fog(nacre_scene *scene, nacre_fog fog, const nacre_fog_desc *desc);
NACRE_API uint32_t nacre_scene_fog_count(const nacre_scene *scene);
/* The files a scene loaded from a scene file was built from (meshes, depth maps, volumes), as
 * resolved against the scene file's folder; NULL past the count. A tool writing outputs can
 * check that it does not overwrite one of them. */
NACRE_API uint32_t nacre_scene_input_count(const nacre_scene *scene);
NACRE_API const char *nacre_scene_input_path(const nacre_scene *scene, uint32_t index);

/* Create an empty scene (units: millimetres). */
NACRE_API nacre_result nacre_scene_create(nacre_context *ctx, nacre_scene **out);
NACRE_API void nacre_scene_destroy(nacre_scene *scene);
NACRE_API nacre_context *nacre_scene_context(const nacre_scene *scene);

/* Add a mesh (arrays copied, validated; normals and tangents computed when missing). */
NACRE_API nacre_result nacre_scene_add_mesh(nacre_scene *scene, const nacre_mesh_data *data,
                                            nacre_mesh *out);
/* The mesh's rest-pose data as stored by the scene (borrowed until the scene is destroyed). */
NACRE_API const nacre_mesh_data *nacre_scene_mesh_data(const nacre_scene *scene, nacre_mesh mesh);
NACRE_API nacre_result nacre_scene_add_material(nacre_scene *scene, const nacre_material_desc *desc,
                                                nacre_material *out);
NACRE_API nacre_result nacre_scene_set_material(nacre_scene *scene, nacre_material material,
                                                const nacre_material_desc *desc);
NACRE_API nacre_result nacre_scene_add_object(nacre_scene *scene, const nacre_object_desc *desc,
                                              nacre_object *out);
/* Replace an object's transform, deformers and flags (mesh and material may change too). */
NACRE_API nacre_result nacre_scene_set_object(nacre_scene *scene, nacre_object object,
                                              const nacre_object_desc *desc);
NACRE_API nacre_result nacre_scene_add_light(nacre_scene *scene, const nacre_light_desc *desc,
                                             nacre_light *out);
NACRE_API nacre_result nacre_scene_set_light(nacre_scene *scene, nacre_light light,
                                             const nacre_light_desc *desc);
NACRE_API nacre_result nacre_scene_set_camera(nacre_scene *scene, const nacre_camera_desc *desc);
/* Uniform environment radiance: the ambient term of phong, the sky of the path tracer. */
NACRE_API nacre_result nacre_scene_set_environment(nacre_scene *scene, const float radiance[3]);
/* Scene length unit in millimetres (1 = mm, 1000 = m). Informational; coefficients are per unit. */
NACRE_API nacre_result nacre_scene_set_unit_mm(nacre_scene *scene, float unit_mm);

NACRE_API uint32_t nacre_scene_object_count(const nacre_scene *scene);
NACRE_API uint32_t nacre_scene_light_count(const nacre_scene *scene);

/* Evaluate deformers at `time` (seconds) and transforms: world-space geometry for rendering.
 * Needed after any edit and before rendering. */
NACRE_API nacre_result nacre_scene_commit(nacre_scene *scene, double time);
/* World-space bounds of the committed scene. */
NACRE_API nacre_result nacre_scene_bounds(const nacre_scene *scene, float min[3], float max[3]);

/* ------------------------------------------------------------------------------------------ */
/* Rendering                                                                                  */
/* ------------------------------------------------------------------------------------------ */

typedef enum nacre_method {
    NACRE_METHOD_PHONG = 0, /* ambient + Lambert + Blinn-Phong, shadow maps with PCF */
    NACRE_METHOD_DIFFUSION, /* Blanchard 2012 voxel diffusion */
    NACRE_METHOD_LAYERED,   /* Francois et al. 2006 subsurface texture mapping (not yet) */
    NACRE_METHOD_PATHTRACE, /* reference volumetric path tracer (Embree; see nacre render --help) */
    NACRE_METHOD_COUNT
} nacre_method;

/* "phong", "diffusion", "layered", "pathtrace". */
NACRE_API const char *nacre_method_name(nacre_method method);
/* Parse a method name; false if unknown. */
NACRE_API bool nacre_method_from_name(const char *name, nacre_method *out);
/* Whether this build implements the method. */
NACRE_API bool nacre_method_available(nacre_method method);

/* Diffusion solver (Blanchard 2012 section 4.5 and our default). */
typedef enum nacre_diffusion_solver {
    NACRE_SOLVER_MULTIGRID = 0, /* multigrid-preconditioned conjugate gradients to `tolerance` */
    NACRE_SOLVER_SEED           /* the seed: Jacobi sweeps over the resolution cascade, fixed counts */
} nacre_diffusion_solver;

/* Where the light transmitted through the surface enters the diffusion solve. */
typedef enum nacre_diffusion_source {
    NACRE_SOURCE_VOLUME = 0, /* reduced intensity deposited along the refracted ray, exp(-sigma_t' d) */
    NACRE_SOURCE_FACE        /* the seed: flux on the exposed voxel faces (Robin boundary source) */
} nacre_diffusion_source;

/* "multigrid", "seed"; "volume", "face". The from_name functions return false if unknown. */
NACRE_API const char *nacre_solver_name(nacre_diffusion_solver solver);
NACRE_API bool nacre_solver_from_name(const char *name, nacre_diffusion_solver *out);
NACRE_API const char *nacre_source_name(nacre_diffusion_source source);
NACRE_API bool nacre_source_from_name(const char *name, nacre_diffusion_source *out);

typedef struct nacre_render_settings {
    nacre_method method;
    int32_t width, height;    /* default 640 x 480; 1..16384 each, at most 2^26 pixels */
    float exposure;           /* EV stops applied when writing PNG (informational here) */
    int32_t shadow_map_size;  /* texels per side, default 2048; 0 disables shadows */
    float pcf_radius;         /* PCF kernel radius in shadow texels, default 1.5 */
    float shadow_bias;        /* depth bias in shadow texels, default 1.5 */
    uint32_t seed;            /* stochastic methods */
    uint32_t spp;             /* stochastic methods: samples per pixel */
    double time;              /* seconds: when the caller should commit the scene (deformers); the
                                 scene file's "render.time". The renderer itself does not read it. */
    /* diffusion */
    uint32_t voxel_resolution;       /* voxels along the longest axis of each translucent object, default 32 */
    int32_t tsm_size;                /* translucent shadow map: most texels per side, default 512; each map
                                        uses 4 texels per voxel side of the object's voxels (fewer on
                                        coarse grids), at most tsm_size */
    nacre_diffusion_solver solver;   /* default MULTIGRID */
    nacre_diffusion_source source;   /* default VOLUME */
    float tolerance;                 /* MULTIGRID: relative residual, default 1e-4 */
    uint32_t seed_iterations;        /* SEED: Jacobi sweeps per level, 0 = the seed's table 5.6 count */
    /* pathtrace */
    double time_limit;               /* seconds from the start of the render call; 0 = none.
                                        Stops within a pass, see nacre_render_stats */
    uint32_t max_scatter;            /* scattering events per path in media; 0 = unlimited */
    /* Raster methods (phong, diffusion): true promises that `out` holds, unchanged, the image this
     * renderer wrote in its previous frame (same pixels, size and stride), as in a viewer that
     * shows each frame and passes the buffer back. Pixels that were background then and still are
     * hold the environment already and are not rewritten (on a 1280x720 frame mostly background,
     * ~0.6 ms of memory writes); the image is identical to a full repaint. The renderer repaints
     * everything when the buffer, its size, the environment or the method differ from its last
     * frame. Default false. */
    bool reuse_output;
} nacre_render_settings;

NACRE_API nacre_render_settings nacre_render_settings_defaults(void);

/* Timed stages. A stage that did not run (cached or not used) reports 0 and ran = false. */
#define NACRE_STAGE_LIST(X)                                                                    \
    X(NACRE_STAGE_SETUP, "setup")                                                              \
    X(NACRE_STAGE_RASTER, "raster")                                                            \
    X(NACRE_STAGE_GBUFFER, "gbuffer")                                                          \
    X(NACRE_STAGE_SHADOW, "shadow")                                                            \
    X(NACRE_STAGE_VOXELIZE, "voxelize")                                                        \
    X(NACRE_STAGE_TSM, "tsm")                                                                  \
    X(NACRE_STAGE_INJECT, "inject")                                                            \
    X(NACRE_STAGE_PROPAGATE, "propagate")                                                      \
    X(NACRE_STAGE_SHADE, "shade")

typedef enum nacre_stage {
#define NACRE_STAGE_ENUM_(name, text) name,
    NACRE_STAGE_LIST(NACRE_STAGE_ENUM_)
#undef NACRE_STAGE_ENUM_
    NACRE_STAGE_COUNT
} nacre_stage;

NACRE_API const char *nacre_stage_name(nacre_stage stage);

typedef struct nacre_render_stats {
    uint64_t stage_us[NACRE_STAGE_COUNT];
    bool stage_ran[NACRE_STAGE_COUNT];
    uint64_t total_us;
    uint64_t triangles;          /* submitted to the camera rasterizer */
    uint64_t triangles_drawn;    /* after culling (back faces, off-screen, no pixel centre) */
    uint32_t shadow_maps;        /* rendered (not cached) this frame */
    int threads;
    /* diffusion (summed over translucent objects; dims of the largest grid) */
    uint32_t voxel_dims[3];
    nacre_diffusion_solver solver;
    uint32_t iterations;         /* MULTIGRID: PCG iterations (max over objects and channels); SEED: sweeps */
    double residual;             /* final relative residual (max over objects and channels) */
    /* pathtrace */
    uint32_t spp_done;           /* samples per pixel completed by every pixel (the minimum) */
    double samples_per_second;   /* camera paths per second */
    uint64_t samples_done;       /* camera paths completed, over all pixels (with a time limit,
                                    pixel counts may differ; each pixel is the mean of its own) */
    uint64_t paths_capped;       /* paths ended by the path-length or collision cap (README) */
    uint32_t pixels_unsampled;   /* time limit reached within the first pass: pixels without a
                                    sample, filled with their 8x8 block's mean (0 if none) */
} nacre_render_stats;

/* A renderer keeps the buffers and results of previous frames (G-buffer, shadow maps) and
 * recomputes only the stages whose inputs changed since its last render of the same scene:
 * changing only a material re-shades; moving only a light redraws its shadow map and re-shades;
 * moving the camera redraws the G-buffer. One renderer per thread. */
typedef struct nacre_renderer nacre_renderer;

NACRE_API nacre_result nacre_renderer_create(nacre_context *ctx, nacre_renderer **out);
NACRE_API void nacre_renderer_destroy(nacre_renderer *renderer);
/* Render a committed scene into `out` (3 channels, radiance). If out->pixels is NULL the image
 * is allocated (free with nacre_image_free); otherwise it must already be width x height x 3.
 * stats may be NULL. */
NACRE_API nacre_result nacre_renderer_render(nacre_renderer *renderer, const nacre_scene *scene,
                                             const nacre_render_settings *settings,
                                             nacre_image *out, nacre_render_stats *stats);
/* One-shot render with a temporary renderer. */
NACRE_API nacre_result nacre_render(const nacre_scene *scene, const nacre_render_settings *settings,
                                    nacre_image *out, nacre_render_stats *stats);

/* The per-pixel variance of the last path-traced image (variance of the pixel mean, 3 channels).
 * INVALID_OPERATION if the renderer's last frame was not path traced. Same allocation rule as
 * nacre_renderer_render. */
NACRE_API nacre_result nacre_renderer_variance(const nacre_renderer *renderer, nacre_image *out);

/* ------------------------------------------------------------------------------------------ */
/* Slab measurement (validation of diffusion and path tracing against exact results)          */
/* ------------------------------------------------------------------------------------------ */

/* A plane-parallel slab, infinite in x and y, of optical thickness tau (sigma_t * depth; INFINITY
 * for semi-infinite), single-scattering albedo a = sigma_s / sigma_t, Henyey-Greenstein g and
 * relative index eta with air (index 1) on both sides, lit by collimated light at normal
 * incidence with unit power per unit area. R: light leaving the top after scattering (the
 * specular reflection at the top excluded, reported as R_specular); T: all light leaving the
 * bottom (unscattered included). */
typedef struct nacre_slab_desc {
    nacre_method method;            /* DIFFUSION or PATHTRACE */
    double albedo, tau, g, eta;
    /* diffusion */
    uint32_t cells_per_mfp;         /* grid cells per reduced mean free path 1/sigma_t', default 8 */
    nacre_diffusion_solver solver;
    nacre_diffusion_source source;
    float tolerance;                /* default 1e-5 */
    /* pathtrace */
    uint64_t samples;               /* incident paths, default 1e6 */
    uint32_t max_scatter;           /* 0 = unlimited */
    uint64_t seed;
    double time_limit;              /* seconds, 0 = none: stop early, the result from the paths
                                       completed by then (samples_done) */
} nacre_slab_desc;

typedef struct nacre_slab_result {
    double R, T;
    double R_stderr, T_stderr;      /* pathtrace: standard errors of the means; diffusion: 0 */
    uint64_t samples_done;          /* pathtrace: paths completed (samples, or fewer at the time limit) */
    uint64_t paths_capped;          /* pathtrace: paths ended by the collision cap (README) */
    double R_specular;              /* Fresnel reflection at normal incidence, ((eta-1)/(eta+1))^2 */
    uint32_t iterations;            /* diffusion */
    double residual;                /* diffusion */
    double ms;
} nacre_slab_result;

NACRE_API nacre_slab_desc nacre_slab_desc_defaults(void);
NACRE_API nacre_result nacre_slab_measure(nacre_context *ctx, const nacre_slab_desc *desc,
                                          nacre_slab_result *out);

/* ------------------------------------------------------------------------------------------ */
/* Scene files (JSON; format in docs/scene-format.md)                                         */
/* ------------------------------------------------------------------------------------------ */

/* Load a scene file: builds the scene (not yet committed) and fills `settings` from its "render"
 * block (defaults otherwise); settings may be NULL. Paths inside are relative to the file.
 * Errors name the file and the field path, or line and column for malformed JSON. */
NACRE_API nacre_result nacre_scene_load_file(nacre_context *ctx, const char *path,
                                             nacre_scene **out, nacre_render_settings *settings);
/* Same, from a string; `name` is used in messages and `base_dir` resolves relative paths. */
NACRE_API nacre_result nacre_scene_load_json(nacre_context *ctx, const char *json, size_t length,
                                             const char *name, const char *base_dir,
                                             nacre_scene **out, nacre_render_settings *settings);

#ifdef __cplusplus
}
#endif

/* Voxelization (needs the declarations above). */
#include <nacre/voxel.h>

#endif /* NACRE_NACRE_H */
