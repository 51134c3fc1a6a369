/*
 * image_jpeg.c: JPEG reading (baseline and progressive, grey or colour) for textures: a scene's
 * diffuse maps and the base colour images that glTF files carry, which are JPEG as often as PNG.
 * Decoding is stb_image's (Debian's libstb); nacre only checks sizes before anything is
 * decoded and converts the 8-bit samples to linear floats (sRGB decoded unless read as data).
 * JPEG has no alpha, so the image has 3 channels. nacre writes no JPEG: renders go to PNG/EXR.
 */
#include "io/image_private.h"

#include <stb_image.h>
#include <stdio.h>
#include <stdlib.h>

/* Entropy-coded JPEG can describe a flat 8x8 block in a few bits, and a progressive file's
 * end-of-band runs span thousands of blocks, so the header's size is only bounded loosely by
 * the file's: this ratio rejects absurd headers, the memory limit does the rest. */
#define JPEG_MAX_RATIO 20000.0
/* Compressed bytes are a fraction of the pixels, which nc_image_check_file_size bounds. */
#define JPEG_FILE_MAX ((size_t)1 << 30)

static nacre_result decode(nacre_context *ctx, const char *name, const unsigned char *bytes, size_t size, bool srgb,
                           nacre_image *out)
{
    if (size < 3 || bytes[0] != 0xFF || bytes[1] != 0xD8 || bytes[2] != 0xFF)
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: not a JPEG file (no start-of-image marker)", name);
    if (size > (size_t)INT32_MAX)
        return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "%s: JPEG of %zu bytes is too large", name, size);
    int w = 0, h = 0, comp = 0;
    if (!stbi_info_from_memory(bytes, (int)size, &w, &h, &comp))
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: invalid JPEG: %s", name, stbi_failure_reason());
    nacre_result r = nc_image_check_file_size(ctx, name, w, h, (int64_t)size, 8.0, JPEG_MAX_RATIO);
    if (r != NACRE_OK)
        return r;
    /* stb_image allocates its own 3 bytes per pixel with malloc; the check above bounds it. */
    int dw = 0, dh = 0, dc = 0;
    unsigned char *rgb = stbi_load_from_memory(bytes, (int)size, &dw, &dh, &dc, 3);
    if (!rgb)
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: invalid JPEG: %s", name, stbi_failure_reason());
    if (dw != w || dh != h) {
        stbi_image_free(rgb);
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: invalid JPEG: decoded %dx%d, the header says %dx%d", name, dw,
                       dh, w, h);
    }
    r = nacre_image_alloc(ctx, w, h, 3, out);
    if (r == NACRE_OK) {
        float table[256];
        for (int i = 0; i < 256; i++)
            table[i] = srgb ? nc_srgb_to_linear((float)i / 255.0f) : (float)i / 255.0f;
        size_t n = (size_t)w * (size_t)h * 3;
        for (size_t i = 0; i < n; i++)
            out->pixels[i] = table[rgb[i]];
    }
    stbi_image_free(rgb);
    return r;
}

nacre_result nc_image_read_jpeg_memory(nacre_context *ctx, const char *name, const void *bytes, size_t size,
                                       bool srgb, nacre_image *out)
{
    return decode(ctx, name, bytes, size, srgb, out);
}

nacre_result nc_image_read_jpeg(nacre_context *ctx, const char *path, bool srgb, nacre_image *out)
{
    char *bytes = NULL;
    size_t size = 0;
    nacre_result r = nc_read_file(ctx, path, JPEG_FILE_MAX, "not a JPEG nacre reads", &bytes, &size);
    if (r == NACRE_OK)
        r = decode(ctx, path, (const unsigned char *)bytes, size, srgb, out);
    nc_free(ctx, bytes);
    return r;
}
