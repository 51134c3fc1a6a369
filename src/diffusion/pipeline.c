/*
 * pipeline.c: `--method diffusion` (Blanchard 2012 chapter 4): placeholder until the pipeline
 * lands.
 */
#include "diffusion/diffusion.h"

bool nc_diffusion_available(void) { return false; }
