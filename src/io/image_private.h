/*
 * image_private.h: what the image files (image.c, image_png.c, image_exr.c) share: argument
 * checks, size limits for files, the sRGB transfer functions and the temporary-file writer that
 * guarantees no partial output. Private to the library.
 */
#ifndef NACRE_IMAGE_PRIVATE_H
#define NACRE_IMAGE_PRIVATE_H

#include "core/core.h"
#include "io/tmpfile.h"

#include <math.h>
#include <string.h>

#define NC_IMAGE_MAX_SIDE 65536
/* Files claiming more pixels than this are rejected before anything is allocated: 2^28 pixels
 * is 4 GiB of RGBA floats, far beyond any image this renderer makes. */
#define NC_IMAGE_MAX_PIXELS ((uint64_t)1 << 28)

/* Check that `image` is usable as input (sizes, channels, stride, pixels). `what` prefixes the
 * message, normally the path. */
nacre_result nc_image_check(nacre_context *ctx, const nacre_image *image, const char *what);
/* The writers behind nacre_image_write, which picks one by the path's extension. */
nacre_result nc_image_write_png(nacre_context *ctx, const nacre_image *image, const char *path, float exposure);
/* data: values * 255 without the sRGB curve or exposure (nacre_image_write_data). */
nacre_result nc_image_write_png_ex(nacre_context *ctx, const nacre_image *image, const char *path, float exposure,
                                   bool data);
nacre_result nc_image_write_exr(nacre_context *ctx, const nacre_image *image, const char *path, nacre_exr_pixel type);
/* Argument checks every writer starts with: context, path and image. */
nacre_result nc_image_write_check(nacre_context *ctx, const nacre_image *image, const char *path);


/* Check sizes read from a file header against the limits above and against the file's size:
 * width x height pixels of at least `min_bits` bits each cannot come from `file_size` bytes of a
 * format whose compression expands data by at most `max_ratio` (1 uncompressed, ~1032 for
 * deflate). Also checks the decoded image (4 floats per pixel at most) against the memory limit.
 * Runs before anything is allocated for the image; fails naming the path. */
nacre_result nc_image_check_file_size(nacre_context *ctx, const char *path, int64_t width, int64_t height,
                                      int64_t file_size, double min_bits, double max_ratio);

/* The piecewise sRGB transfer (IEC 61966-2-1), not a plain 2.2 gamma. */
static inline float nc_srgb_to_linear(float v)
{
    return v <= 0.04045f ? v / 12.92f : powf((v + 0.055f) / 1.055f, 2.4f);
}

static inline float nc_linear_to_srgb(float v)
{
    return v <= 0.0031308f ? v * 12.92f : 1.055f * powf(v, 1.0f / 2.4f) - 0.055f;
}

/* 8-bit sRGB encoding of a linear value: nc_linear_to_srgb in (0, 1), clamped to [0, 1] and
 * rounded to nearest (NaN gives 0). nc_srgb8_reference computes it with powf; the table gives
 * the same byte for every float without one: t[k] is the smallest float that encodes to k or
 * more (the encoding is monotonic), and start[b] the code of the smallest positive float whose
 * top 16 bits are b, from which at most a few comparisons with t reach the code. */
typedef struct nc_srgb8_table {
    float t[256];
    uint8_t start[0x3F80]; /* top 16 bits of the floats in (0, 1) */
} nc_srgb8_table;

uint8_t nc_srgb8_reference(float v);
void nc_srgb8_table_build(nc_srgb8_table *tb);

static inline uint8_t nc_srgb8_encode(const nc_srgb8_table *tb, float v)
{
    if (!(v > 0.0f && v < 1.0f))
        return nc_srgb8_reference(v);
    uint32_t bits;
    memcpy(&bits, &v, sizeof(bits));
    unsigned q = tb->start[bits >> 16];
    while (q < 255 && tb->t[q + 1] <= v)
        q++;
    return (uint8_t)q;
}


/* Format readers and writers; paths and images are already validated by the callers. */
/* srgb: decode 8/16-bit samples as sRGB to linear; else value / max (data images). */
nacre_result nc_image_read_png(nacre_context *ctx, const char *path, bool srgb, nacre_image *out);
/* The same from bytes in memory (a PNG embedded in a glTF); `name` names it in messages. */
nacre_result nc_image_read_png_memory(nacre_context *ctx, const char *name, const void *bytes, size_t size, bool srgb,
                                      nacre_image *out);
nacre_result nc_image_read_exr(nacre_context *ctx, const char *path, nacre_image *out);
/* JPEG (image_jpeg.c): 3 channels, srgb as for PNG; from a file or from bytes in memory. */
nacre_result nc_image_read_jpeg(nacre_context *ctx, const char *path, bool srgb, nacre_image *out);
nacre_result nc_image_read_jpeg_memory(nacre_context *ctx, const char *name, const void *bytes, size_t size,
                                       bool srgb, nacre_image *out);

#endif /* NACRE_IMAGE_PRIVATE_H */
