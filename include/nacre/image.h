/*
 * image.h: float images (nacre_image), their write options and comparison metrics, and the
 * functions that allocate, free, write (PNG, EXR), read, compare and check them for non-finite
 * pixels. Part of nacre's public API; the conventions (units, ownership, memory, threading,
 * errors) are in the opening comment of nacre.h.
 */
#ifndef NACRE_PUBLIC_IMAGE_H
#define NACRE_PUBLIC_IMAGE_H

#include <nacre/core.h>

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

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
    /* Over the reference's lit pixels (3 channels: R + G + B > 0, finite in both images), the
     * measures of docs/accuracy.md's tables: the ratio of the test's sum to the reference's per
     * channel, the same over the darkest quarter of those pixels (by the reference's R + G + B
     * averaged over the lit pixels of its 3x3 neighbourhood, at or below the 25th percentile: a noisy
     * reference's darkest pixels are biased dark), and the median and 90th percentile of the per-pixel relative error of
     * R + G + B. All 0 when there is no such pixel or the images have another channel count. */
    uint64_t lit_pixels;
    double lit_ratio[3], dark_ratio[3];
    double lit_rel_err_median, lit_rel_err_p90;
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
/* Write a data image (depth maps and other non-colour images) by extension: .png as value * 255
 * in every channel (8 bits, clamped to [0, 1], no sRGB curve or exposure; nacre_image_read_data
 * reads it back), .exr as linear float. As nacre_image_write otherwise. */
NACRE_API nacre_result nacre_image_write_data(nacre_context *ctx, const nacre_image *image, const char *path);
/* Pixels with a NaN or infinite channel; the first one (row-major) in *x, *y and its channel in
 * *c when there is one (any pointer may be NULL). 0 for a NULL image. */
NACRE_API uint64_t nacre_image_count_nonfinite(const nacre_image *image, int32_t *x, int32_t *y, int32_t *c);
/* Read .png (sRGB decoded to linear, 8 or 16 bit), .jpg/.jpeg (sRGB decoded, 3 channels) or
 * .exr (R, G, B and A if present). The result has 3 or 4 channels. */
NACRE_API nacre_result nacre_image_read(nacre_context *ctx, const char *path, nacre_image *out);
/* As nacre_image_read, but PNG and JPEG samples are read as data (value / 255 or / 65535, no sRGB
 * decoding): for depth maps and other non-colour images. */
NACRE_API nacre_result nacre_image_read_data(nacre_context *ctx, const char *path, nacre_image *out);
/* Compare `test` against `reference` (same size and channel count). */
NACRE_API nacre_result nacre_image_compare(nacre_context *ctx, const nacre_image *test,
                                           const nacre_image *reference, nacre_image_metrics *out);

#ifdef __cplusplus
}
#endif

#endif /* NACRE_PUBLIC_IMAGE_H */
