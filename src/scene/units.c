/*
 * units.c: scene length units and the conversion of per-millimetre coefficients into them.
 *
 * Scene files and descs give lengths in scene units (millimetres unless the scene says "cm",
 * "m" or a number of millimetres per unit) and coefficients (sigma_a, sigma_s) per scene unit.
 * The measured presets and the translucent default are tabulated per millimetre, so they are
 * multiplied by the millimetres per unit before they enter a scene: this is the one place that
 * does it, for the scene-file loader and the C API alike.
 */
#include "core/core.h"

#include <math.h>
#include <string.h>

bool nacre_units_mm(const char *name, float *mm_per_unit)
{
    static const struct {
        const char *name;
        float mm;
    } units[] = {{"mm", 1.0f}, {"cm", 10.0f}, {"m", 1000.0f}};
    if (!name)
        return false;
    for (size_t i = 0; i < sizeof(units) / sizeof(units[0]); i++)
        if (strcmp(name, units[i].name) == 0) {
            if (mm_per_unit)
                *mm_per_unit = units[i].mm;
            return true;
        }
    return false;
}

void nacre_material_desc_per_unit(nacre_material_desc *desc, float unit_mm)
{
    if (!desc || !(unit_mm > 0) || !isfinite(unit_mm))
        return;
    for (int c = 0; c < 3; c++) {
        desc->sigma_a[c] *= unit_mm;
        desc->sigma_s[c] *= unit_mm;
    }
    for (uint32_t k = 0; k < desc->layering.count && k < NACRE_MAX_LAYERS; k++)
        for (int c = 0; c < 3; c++) {
            desc->layering.layers[k].sigma_a[c] *= unit_mm;
            desc->layering.layers[k].sigma_s[c] *= unit_mm;
        }
}
