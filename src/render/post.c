/*
 * post.c: the built-in post passes, applied in this order over every method's image with its
 * depth (method.h). Each pass decides from the scene and the settings whether it runs:
 *   fog   distance and exponential height fog (post_fog.c), for methods that do not render
 *         fog themselves (phong, diffusion), with volumetrics OFF
 *   froxel, raymarch   the volumetric fog of seed 003 §2.3 (post_volumetrics.c) in place of
 *         the fog pass, with volumetrics FROXEL or RAYMARCH
 *   particles  particles as screen-space volumetric billboards or sorted sprites
 *         (post_particles.c), before the fog passes so that fog in front of them covers them
 */
#include "render/method.h"

const nc_post_pass *const nc_post_passes[] = {&nc_post_particles, &nc_post_fog, &nc_post_froxel, &nc_post_raymarch};
const uint32_t nc_post_pass_count = sizeof(nc_post_passes) / sizeof(nc_post_passes[0]);
