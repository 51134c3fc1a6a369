/*
 * post.c: the built-in post passes, applied in this order over every method's image with its
 * depth (method.h). The fog and froxel volumetrics of seed 003 go here as they land; until then
 * the list is empty and a frame ends with its method.
 */
#include "render/method.h"

const nc_post_pass *const nc_post_passes[] = {NULL};
const uint32_t nc_post_pass_count = 0;
