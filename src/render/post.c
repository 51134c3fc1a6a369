/*
 * post.c: the built-in post passes, applied in this order over every method's image with its
 * depth (method.h). Each pass decides from the scene and the settings whether it runs:
 *   fog   distance and exponential height fog (post_fog.c), for methods that do not render
 *         fog themselves (phong, diffusion)
 *   particles  particles as screen-space volumetric billboards or sorted sprites
 *         (post_particles.c), before the fog so that fog in front of them covers them
 * The froxel volumetrics of seed 003 (issue 24) will replace the fog pass where they apply.
 */
#include "render/method.h"

const nc_post_pass *const nc_post_passes[] = {&nc_post_particles, &nc_post_fog};
const uint32_t nc_post_pass_count = sizeof(nc_post_passes) / sizeof(nc_post_passes[0]);
