/*
 * scene.h: the scene description: nacre_scene and its element handles; materials with their
 * media patterns, layering, presets and units; volumes, textures, transforms, deformers, objects,
 * lights, the camera and fog; and the functions that build, edit and commit a scene. Loading a
 * scene file (nacre_scene_load_file, nacre_scene_load_json) also fills nacre_render_settings, so
 * it is declared in render.h. Part of nacre's public API; the conventions (units, ownership,
 * memory, threading, errors) are in the opening comment of nacre.h.
 */
#ifndef NACRE_PUBLIC_SCENE_H
#define NACRE_PUBLIC_SCENE_H

#include <nacre/core.h>
#include <nacre/image.h>
#include <nacre/mesh.h>

#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

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
    /* VOLUME as a fog's emission_pattern only: the volume holds temperatures, T = kelvin_scale d
     * kelvin, and the emission is emission x nacre_blackbody_rgb(T) per channel. */
    bool blackbody;
    float kelvin_scale;             /* > 0 when blackbody (1 for a grid in kelvin) */
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
 * media exactly; the diffusion method solves on each voxel's mean of its layers' and core's
 * coefficients (layers thinner than a voxel are averaged into it); the phong method shades the
 * core only. Scene files: "layers" and "depth_map" (docs/scene-format.md). */
#define NACRE_MAX_LAYERS 4
typedef struct { uint32_t id; } nacre_texture;

typedef struct nacre_layer {
    float sigma_a[3], sigma_s[3]; /* per scene unit; sigma_a + sigma_s > 0 in every channel */
    float g;                      /* Henyey-Greenstein anisotropy, in (-1, 1) */
    float depth;                  /* bottom below the surface, rest-pose scene units, >= 0; with a
                                     depth map, the scale of its channel (map value 1 = depth) */
} nacre_layer;

/* What the layered render method adds under its single scattering (seed 001 is single
 * scattering only): NONE, or DIFFUSION, the diffusion method's (seed 000) solution on the
 * object's voxels with each voxel's layer (or core) coefficients, for the multiply scattered
 * light. The other methods ignore it (the path tracer renders every order). */
typedef enum nacre_multiple_scattering {
    NACRE_MULTIPLE_SCATTERING_NONE = 0,
    NACRE_MULTIPLE_SCATTERING_DIFFUSION
} nacre_multiple_scattering;

/* "none", "diffusion"; false if unknown. */
NACRE_API bool nacre_multiple_scattering_from_name(const char *name, nacre_multiple_scattering *out);
NACRE_API const char *nacre_multiple_scattering_name(nacre_multiple_scattering ms);

typedef struct nacre_layering {
    uint32_t count;                       /* 0 (not layered) .. NACRE_MAX_LAYERS */
    nacre_layer layers[NACRE_MAX_LAYERS]; /* from the surface inwards */
    nacre_texture depth_map;              /* optional (id 0: none): channel j scales layer j's depth,
                                             read bilinearly at the surface uv, repeating; needs
                                             at least `count` channels and a mesh with uvs */
    nacre_multiple_scattering multiple_scattering; /* layered method only (default NONE); also for
                                                     count 0, where the core is the only medium */
} nacre_layering;

/* Procedural depth maps for layerings (what seed 001 paints by hand): RGBA, values in [0, 1].
 * CONSTANT: every channel 1. VEINS: R 1, G branching veins of tapering width (1 on a vein's axis,
 * a tube's profile to 0 at its edge, 0 elsewhere), B and A 1. SPOTS: as VEINS with round spots
 * of random size in G. The same seed gives the same map; maps tile (uv repeats). */
typedef enum nacre_layer_map_kind {
    NACRE_LAYER_MAP_CONSTANT = 0,
    NACRE_LAYER_MAP_VEINS,
    NACRE_LAYER_MAP_SPOTS
} nacre_layer_map_kind;

/* "constant", "veins", "spots"; false if unknown. */
NACRE_API bool nacre_layer_map_kind_from_name(const char *name, nacre_layer_map_kind *out);
/* Allocate *out (size x size x 4, free with nacre_image_free) and draw the map; size 8..8192.
 * Write it with nacre_image_write_data so that a PNG holds the values as they are. */
NACRE_API nacre_result nacre_layer_map_generate(nacre_context *ctx, nacre_layer_map_kind kind, int32_t size,
                                                uint32_t seed, nacre_image *out);

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
    nacre_texture diffuse_map;    /* opaque, optional (id 0: none): linear albedo texture multiplying
                                     `diffuse`, read bilinearly at the surface uv, repeating (RGB
                                     from channels 0-2; a 1- or 2-channel texture is grey from
                                     channel 0); objects using it need a mesh with uvs */
} nacre_material_desc;

/* Defaults: opaque grey 0.8, specular 0.04, shininess 64; translucent: the "jade" preset
 * (Blanchard 2012), g 0, eta 1.6, no pattern. Coefficients PER MILLIMETRE: in a scene whose unit
 * is not the millimetre, convert them with nacre_material_desc_per_unit. */
NACRE_API nacre_material_desc nacre_material_desc_defaults(nacre_material_type type);

/* Look up a named measured material (Jensen et al. 2001: "marble", "skimmilk", "wholemilk",
 * "cream", "ketchup", "apple", "potato", "chicken", "skin1", "skin2"; Blanchard 2012:
 * "jade", "aquamarine"; Francois et al. 2006 table 1: "fish", dermis and blood layers of 0.5 and
 * 1.5 mm depth over the organs, eta 1.33), coefficients per millimetre, eta 1.3 for Jensen's. The
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
/* Read one scalar grid of an OpenVDB file (.vdb; float or double values): `grid_name`, or
 * when NULL the grid "density", or else the file's first float grid. The result covers the
 * grid's active bounding box padded by one voxel on each side, so that outside it the clamped
 * density is the grid's background; voxel centres keep the file's placement (origin = world
 * position of the box's first voxel, spacing = voxel size). Transforms must be linear and
 * axis-aligned with positive scales (rotated, sheared, flipped and frustum grids are refused);
 * level sets, non-float grids and negative or non-finite values are refused. The dense copy is
 * checked against the context's memory limit before it is made. Built without OpenVDB, returns
 * NACRE_ERROR_UNSUPPORTED. The library allocates `out->data`; free with nacre_volume_data_free. */
NACRE_API nacre_result nacre_volume_load_vdb(nacre_context *ctx, const char *path, const char *grid_name,
                                             nacre_volume_data *out);
/* Free data allocated by the library and zero the struct. */
NACRE_API void nacre_volume_data_free(nacre_context *ctx, nacre_volume_data *volume);

/* Add a texture (pixels copied, 1 to 4 channels, every value finite and >= 0; kept until the
 * scene is destroyed). Row 0 is the top of the image and v = 0 its bottom row (v grows upwards,
 * the OBJ/glTF-flipped convention of most mesh exporters: texel (x, y) is centred at
 * u = (x + 0.5) / width, v = 1 - (y + 0.5) / height). Layer depth maps are data: read PNG depth
 * maps with nacre_image_read_data, not the sRGB-decoding nacre_image_read; diffuse maps are
 * colours: read them with nacre_image_read (sRGB PNG to linear). */
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

/* A spot light's intensity across its cone, as a factor of `strength` (c = cos of the angle from
 * the axis, co and ci = cos of outer_angle and inner_angle; docs/scene-format.md has the sources):
 *   SMOOTH (default): 0 outside, s = t^2 (3 - 2t) with t = (c - co) / (ci - co), 1 inside ci;
 *   CYCLES: c * s, as Blender Cycles 2.8-3.x (spot_size = 2 outer_angle, spot_blend =
 *           (ci - co) / (1 - co)); Cycles 4.x dropped the factor c and then equals SMOOTH;
 *   GLTF:   clamp(t, 0, 1)^2, as the sample code of glTF's KHR_lights_punctual.
 * inner_angle = outer_angle gives a hard cone for each (CYCLES: c inside). */
typedef enum nacre_spot_falloff {
    NACRE_SPOT_FALLOFF_SMOOTH = 0,
    NACRE_SPOT_FALLOFF_CYCLES,
    NACRE_SPOT_FALLOFF_GLTF
} nacre_spot_falloff;

typedef struct nacre_light_desc {
    nacre_light_type type;
    float direction[3];      /* directional, spot: the way the light travels (normalised) */
    float position[3];       /* point, spot */
    float strength[3];       /* directional: irradiance (W/m^2); point, spot: intensity (W/sr) */
    float inner_angle;       /* spot: full strength inside this half-angle (degrees) */
    float outer_angle;       /* spot: zero outside this half-angle (degrees) */
    nacre_spot_falloff falloff; /* spot: profile between the cones (default SMOOTH) */
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
 * The path tracer renders fog exactly. Phong and diffusion draw it by a post pass over their
 * image and depth (docs/scene-format.md "fog"): by default analytic transmittance and single
 * scattering of directional lights and the environment, without shadows in the fog or point and
 * spot lights (nacre_render_stats.fog_lights_ignored), patterns by their mean coefficients; with
 * nacre_render_settings.volumetrics FROXEL or RAYMARCH, single scattering of every light with
 * shadow maps and the fog's own shadow, patterns evaluated where they are. */
/* SPHERE: the ellipsoid inscribed in the box of `size` (a sphere of diameter size when the three
 * are equal), centred and rotated as a box. */
typedef enum nacre_fog_shape { NACRE_FOG_GLOBAL = 0, NACRE_FOG_BOX, NACRE_FOG_SPHERE } nacre_fog_shape;

typedef struct { uint32_t id; } nacre_fog;

typedef struct nacre_fog_desc {
    nacre_fog_shape shape;
    float center[3];              /* origin of the local frame; BOX, SPHERE: the centre */
    float size[3];                /* BOX: edge lengths along the local axes; SPHERE: diameters; > 0 */
    float rotate[3];              /* Euler degrees, about x, then y, then z (as nacre_transform) */
    float sigma_a[3], sigma_s[3]; /* per scene unit, >= 0 */
    float g;                      /* Henyey-Greenstein anisotropy, in (-1, 1) */
    float height_falloff;         /* per scene unit, >= 0; 0: no height dependence */
    float height_base;            /* world y where height() = 1 */
    nacre_medium_pattern pattern; /* default NONE; medium 2 may be 0 (clear air) */
    float emission[3];            /* radiance emitted per unit length (per scene unit, linear RGB),
                                     >= 0, default 0; scaled at p by height(p) and by the pattern
                                     as sigma is, medium 2 not emitting: x (1 - w) for RANDOM_MIX,
                                     CHECKER, NOISE, x d for VOLUME */
    nacre_medium_pattern emission_pattern; /* default NONE: emission follows `pattern`; else it
                                     follows this pattern instead (same rules: x d for VOLUME,
                                     x (1 - w) for the others), e.g. a .vdb file's "flame" or
                                     "heat" grid beside its "density"; height(p) still applies */
} nacre_fog_desc;

#define NACRE_MAX_FOGS 32

/* The radiance of a black body at `kelvin` in linear Rec.709 RGB, W / (m^2 sr) per channel:
 * Planck's law integrated from 360 to 830 nm against the CIE 1931 2-degree colour matching
 * functions (the analytic fit of Wyman, Sloan and Shirley 2013), Y = luminance / 683 lm/W;
 * channels outside the Rec.709 gamut (the deep reds of bodies below about 1900 K lack blue)
 * clipped to 0. 0 below 400 K and for NaN. For a fog whose emission_pattern is a temperature
 * grid, emission x this is the emission per unit length: emission = sigma_a is Kirchhoff's law
 * (a fog in thermal equilibrium), in a scene whose light strengths are in W/m^2. */
NACRE_API void nacre_blackbody_rgb(double kelvin, float rgb[3]);

/* Defaults: GLOBAL, sigma_a 0, sigma_s 0.001 per unit, g 0, no height falloff, size 1, no
 * emission. */
NACRE_API nacre_fog_desc nacre_fog_desc_defaults(nacre_fog_shape shape);
/* At most NACRE_MAX_FOGS per scene. */
NACRE_API nacre_result nacre_scene_add_fog(nacre_scene *scene, const nacre_fog_desc *desc, nacre_fog *out);
NACRE_API nacre_result nacre_scene_set_fog(nacre_scene *scene, nacre_fog fog, const nacre_fog_desc *desc);
/* The desc of a fog added by the user (particle systems' grids are not listed). */
NACRE_API nacre_result nacre_scene_get_fog(const nacre_scene *scene, nacre_fog fog, nacre_fog_desc *out);
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
NACRE_API uint32_t nacre_scene_material_count(const nacre_scene *scene);
/* Read back what the scene holds, for editors that change one field and set the desc again
 * (the viewer). Handles are ids 1..count. INVALID_ARGUMENT for an invalid handle. A light's
 * direction is the normalised one the scene keeps; an object's name is borrowed until the
 * object is set again or the scene destroyed. get_camera gives the defaults if none was set. */
NACRE_API nacre_result nacre_scene_get_camera(const nacre_scene *scene, nacre_camera_desc *out);
NACRE_API nacre_result nacre_scene_get_light(const nacre_scene *scene, nacre_light light,
                                             nacre_light_desc *out);
NACRE_API nacre_result nacre_scene_get_material(const nacre_scene *scene, nacre_material material,
                                                nacre_material_desc *out);
NACRE_API nacre_result nacre_scene_get_object(const nacre_scene *scene, nacre_object object,
                                              nacre_object_desc *out);
/* Millimetres per scene unit (nacre_scene_set_unit_mm; 1 by default). */
NACRE_API float nacre_scene_get_unit_mm(const nacre_scene *scene);

/* Evaluate deformers at `time` (seconds) and transforms: world-space geometry for rendering.
 * Needed after any edit and before rendering. */
NACRE_API nacre_result nacre_scene_commit(nacre_scene *scene, double time);
/* World-space bounds of the committed scene. */
NACRE_API nacre_result nacre_scene_bounds(const nacre_scene *scene, float min[3], float max[3]);

#ifdef __cplusplus
}
#endif

#endif /* NACRE_PUBLIC_SCENE_H */
