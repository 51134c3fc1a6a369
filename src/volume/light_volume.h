/*
 * light_volume.h: the optical depth from points to one light through one bounded patterned fog
 * (a box or an ellipsoid with a pattern), stored on a grid that does not depend on the camera
 * (Hubert 2020, seed 003 §2.2.3: "transmittance towards each light through a light-space
 * volume"; the froxels' lighting reads it, render/post_volumetrics.c).
 *   directional light: a grid aligned with the light, its columns parallel to the light's
 *             direction over the fog's box as the light sees it (the light-space bounds of the
 *             box's corners). Each column is marched once from where the light enters it, a step
 *             per node: each step's pattern at the midpoint of its part inside the fog times the
 *             height integral over that part (fog_field.h's march, the steps aligned to the
 *             nodes), and the running sum is the optical depth at each node (cumulative sums).
 *   point or spot light: nodes over the fog's box in its own frame, each marched towards the
 *             light by nc_fog_one_optical_depth (shadow_steps steps): a point light's rays fan
 *             out, so no column is shared by two nodes.
 * A lookup is trilinear in optical depth. Outside the grid: for a directional light, points
 * beside the columns get 0 (their ray misses the box) and points past a column's end its last
 * node (nothing lies beyond the box); for a point light, a point outside the box reads the grid
 * where its ray to the light enters the box (no fog of this one before that), 0 if it misses.
 * The grid is rebuilt only when its light or the fog change, never when the camera moves.
 *
 * A gray fog (nc_light_volume_fog_gray: the same sigma_t in every channel at every point, the
 * common white cloud) has one optical depth for all channels: its grid stores and interpolates
 * channel 0 alone, and the lookups copy it (the other channels' arithmetic was channel 0's, so
 * the results are those of the three-channel grid bit for bit, at a third of the gathers).
 *
 * Units: world scene units; optical depth per channel (dimensionless), capped at
 * NC_LIGHT_VOLUME_TAU_MAX so that the interpolation stays finite.
 */
#ifndef NACRE_VOLUME_LIGHT_VOLUME_H
#define NACRE_VOLUME_LIGHT_VOLUME_H

#include "volume/fog_field.h"

/* Optical depths beyond this are stored as this (e^-80: no light). */
#define NC_LIGHT_VOLUME_TAU_MAX 80.0f
/* Nodes per axis of a directional light's grid and of a point light's grid (the defaults). */
#define NC_LIGHT_VOLUME_DIR_RES 64u
#define NC_LIGHT_VOLUME_POINT_RES 24u
/* Largest node count per axis (stack scratch of a column's march). */
#define NC_LIGHT_VOLUME_MAX_RES 256u
/* Most planes bounding where a grid's lookups may be other than 0: a point light's cone over the
 * box (a plane through it and each of the box's 12 edges, at most 6 of which bound it) and the
 * box's 3 faces that it sees. */
#define NC_LIGHT_VOLUME_PLANES 15u

typedef struct nc_light_volume {
    bool directional;
    uint32_t n[3];     /* nodes per axis, >= 2 each */
    float axes[3][3];  /* world -> grid frame rows (directional: e1, e2, the light's direction) */
    float offset[3];   /* grid frame = axes x + offset */
    float lo[3];       /* grid frame coordinate of node 0 per axis */
    float step[3], inv_step[3];
    float light[3];    /* point: the light's position in the grid frame (the fog's) */
    float light_world[3];
    const nc_fog_one *fog;
    bool gray;         /* nc_light_volume_fog_gray(fog): tau holds channel 0 alone */
    /* Where the lookups may be other than 0 (nc_light_volume_reach8): n x + d >= 0 for the
     * planes (n, d) (world, unit n), up to a margin; the first reach_faces of them are a
     * directional grid's sides or a point light's faces of the box, the others pass through
     * the point light. reach_planes 0: anywhere. */
    uint32_t reach_planes, reach_faces;
    float reach[NC_LIGHT_VOLUME_PLANES][4];
    float reach_scale; /* 1 + the magnitudes of the grid's coordinates (the margins' scale) */
    float reach_inv_r; /* point light: 1 / its distance to the box */
    float *tau;        /* 3 per node (gray: 1), z fastest then y then x: a directional light's
                        * columns are contiguous (the caller's, nc_light_volume_floats of them) */
} nc_light_volume;

/* Whether fog o's sigma_t is the same in every channel at every point, so that one channel's
 * optical depth is every channel's bit for bit: the coefficients that its optical depth reads
 * (its own, and its medium's and medium 2's where its pattern picks or blends them) have equal
 * bits in all three channels, and its pattern scales them all alike (scene/medium.c). */
bool nc_light_volume_fog_gray(const nc_fog_one *o);

/* Frame and nodes of fog o's grid for a directional light travelling along `dir` (unit), or a
 * point light at `pos`, res nodes per axis (2 .. NC_LIGHT_VOLUME_MAX_RES), and whether it is
 * gray; tau is not set. */
void nc_light_volume_setup(nc_light_volume *v, const nc_fog_one *o, bool directional, const float dir[3],
                           const float pos[3], uint32_t res);

/* Nodes of v (3 floats of tau each, 1 if gray). */
static inline size_t nc_light_volume_nodes(const nc_light_volume *v) { return (size_t)v->n[0] * v->n[1] * v->n[2]; }
/* Floats of v->tau (at most 3 x nc_light_volume_nodes). */
static inline size_t nc_light_volume_floats(const nc_light_volume *v)
{
    return (v->gray ? 1u : 3u) * nc_light_volume_nodes(v);
}

/* Fill v->tau (threads: OpenMP threads; the result does not depend on them). */
void nc_light_volume_build(const nc_fog_field *f, nc_light_volume *v, int threads);

/* The optical depth per channel from world point x to the light through v's fog (see above). */
void nc_light_volume_lookup(const nc_light_volume *v, const float x[3], float tau[3]);

/* Which of the 8 points (px[l], py[l], pz[l]) lookups of v may give other than 0 (bit l): a clear
 * bit means that nc_light_volume_lookup and nc_light_volume_lookup8 give 0 in every channel
 * there. Outside one of v's planes by more than a margin of 1e-4 of the coordinates' magnitudes
 * (for a plane through a point light, 1e-4 of the angle, times the distance from the light over
 * that to the box: the lookups' rounding, which decides near the cone over the box, shifts it by
 * under 1e-6 of those); points with a coordinate infinite or NaN are never excluded. */
uint32_t nc_light_volume_reach8(const nc_light_volume *v, const float *px, const float *py, const float *pz);

/* nc_light_volume_lookup at 8 points (px[l], py[l], pz[l]), equal bit for bit: channel c of point
 * l in tau[8 c + l]. */
void nc_light_volume_lookup8(const nc_light_volume *v, const float *px, const float *py, const float *pz,
                             float *tau);

#endif /* NACRE_VOLUME_LIGHT_VOLUME_H */
