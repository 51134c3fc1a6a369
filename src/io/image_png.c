/*
 * image_png.c: PNG through libspng. Writing: 8 bits per channel, sRGB-encoded with the piecewise
 * sRGB curve after scaling by 2^exposure, clamped to [0, 1] and rounded to nearest; 1 channel is
 * written as grey, 2 as grey + alpha, 3 as RGB, 4 as RGBA. Alpha is coverage, so it is stored
 * linearly and not exposure-scaled. An sRGB chunk marks the encoding. Data images (depth maps,
 * nacre_image_write_data) are written as value * 255 in every channel, without the curve,
 * the exposure or the chunk.
 *
 * Reading: any PNG colour type at 1..16 bits is expanded by libspng to RGBA (8 or 16 bits; palette
 * and tRNS transparency applied), colour channels are decoded from sRGB to linear floats and alpha
 * is divided by the maximum code value. The result has 4 channels if the file has alpha (an alpha
 * colour type or a tRNS chunk), else 3. gAMA, cHRM and iCCP chunks are ignored: the data is taken
 * as sRGB, which is what every PNG this project writes or compares against is.
 *
 * libspng allocates its internal state with malloc: its allocator hooks take no user pointer, so
 * the context allocator cannot reach them without global state. Every buffer of ours goes through
 * the context allocator.
 */
#include "io/image_private.h"

#include <errno.h>
#include <spng.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>

/* Ancillary chunks are not used; the cap keeps a hostile file from making libspng buffer
 * gigabytes of metadata. */
#define PNG_CHUNK_LIMIT ((size_t)64 << 20)

typedef struct png_sink {
    nacre_context *ctx;
    nc_tmpfile *tmp;
    bool failed; /* the message is already recorded */
} png_sink;

static int png_write_cb(spng_ctx *enc, void *user, void *data, size_t length)
{
    (void)enc;
    png_sink *sink = user;
    if (nc_tmpfile_write(sink->ctx, sink->tmp, data, length) != NACRE_OK) {
        sink->failed = true;
        return SPNG_IO_ERROR;
    }
    return 0;
}

static inline uint8_t quantize(float v)
{
    /* !(v > 0) also sends NaN to 0. */
    if (!(v > 0.0f))
        return 0;
    if (v >= 1.0f)
        return 255;
    return (uint8_t)(v * 255.0f + 0.5f);
}

uint8_t nc_srgb8_reference(float v)
{
    return quantize(v > 0.0f && v < 1.0f ? nc_linear_to_srgb(v) : v);
}

static inline float float_of(uint32_t bits)
{
    float v;
    memcpy(&v, &bits, sizeof(v));
    return v;
}

/* A powf per sample was half the time of writing a rendered PNG; the table costs ~4000 powf. */
void nc_srgb8_table_build(nc_srgb8_table *tb)
{
    const uint32_t one = 0x3F800000u; /* the bits of 1.0f */
    tb->t[0] = 0.0f;
    for (unsigned k = 1; k < 256; k++) {
        /* first positive float below 1 that encodes to k or more (1.0f if none) */
        uint32_t lo = 1, hi = one;
        while (lo < hi) {
            uint32_t mid = lo + (hi - lo) / 2;
            if (nc_srgb8_reference(float_of(mid)) >= k)
                hi = mid;
            else
                lo = mid + 1;
        }
        tb->t[k] = float_of(lo);
    }
    unsigned q = 0; /* the buckets ascend, and so do their codes */
    for (uint32_t b = 0; b < sizeof(tb->start); b++) {
        float v = float_of(b ? b << 16 : 1u);
        while (q < 255 && tb->t[q + 1] <= v)
            q++;
        tb->start[b] = (uint8_t)q;
    }
}

static void encode_row(const nc_srgb8_table *tb, const float *src, int32_t width, int32_t channels, float scale,
                       bool data, uint8_t *dst)
{
    /* Channels 1 and 3 are all colour; with 2 and 4 the last one is alpha. */
    int32_t colour = data ? 0 : (channels == 2 || channels == 4) ? channels - 1 : channels;
    if (data) {
        for (int32_t i = 0; i < width * channels; i++)
            dst[i] = quantize(src[i]);
        return;
    }
    for (int32_t x = 0; x < width; x++) {
        for (int32_t c = 0; c < colour; c++)
            dst[c] = nc_srgb8_encode(tb, src[c] * scale);
        if (colour < channels)
            dst[colour] = quantize(src[colour]);
        src += channels;
        dst += channels;
    }
}

nacre_result nc_image_write_png(nacre_context *ctx, const nacre_image *image,
                                   const char *path, float exposure)
{
    return nc_image_write_png_ex(ctx, image, path, exposure, false);
}

nacre_result nc_image_write_png_ex(nacre_context *ctx, const nacre_image *image, const char *path, float exposure,
                                   bool data)
{
    nacre_result r = nc_image_write_check(ctx, image, path);
    if (r != NACRE_OK)
        return r;
    if (!isfinite(exposure))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: exposure %g is not finite",
                       path, (double)exposure);

    static const uint8_t colour_types[4] = {
        SPNG_COLOR_TYPE_GRAYSCALE, SPNG_COLOR_TYPE_GRAYSCALE_ALPHA, SPNG_COLOR_TYPE_TRUECOLOR,
        SPNG_COLOR_TYPE_TRUECOLOR_ALPHA};
    size_t row_bytes = (size_t)image->width * (size_t)image->channels;
    float scale = exp2f(exposure);
    uint8_t *row = nc_alloc(ctx, row_bytes);
    nc_srgb8_table *table = nc_alloc(ctx, sizeof(*table));
    if (!row || !table) {
        nc_free(ctx, row);
        nc_free(ctx, table);
        return NACRE_ERROR_OUT_OF_MEMORY;
    }
    nc_srgb8_table_build(table);
    nc_tmpfile tmp;
    r = nc_tmpfile_open(ctx, path, &tmp);
    if (r != NACRE_OK)
        goto out_free_row;
    spng_ctx *enc = spng_ctx_new(SPNG_CTX_ENCODER);
    if (!enc) {
        r = nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "%s: out of memory creating PNG encoder",
                    path);
        goto out_abort;
    }
    png_sink sink = {ctx, &tmp, false};
    struct spng_ihdr ihdr = {0};
    ihdr.width = (uint32_t)image->width;
    ihdr.height = (uint32_t)image->height;
    ihdr.bit_depth = 8;
    ihdr.color_type = colour_types[image->channels - 1];
    int e = spng_set_png_stream(enc, png_write_cb, &sink);
    if (!e)
        e = spng_set_ihdr(enc, &ihdr);
    if (!e)
        e = data ? 0 : spng_set_srgb(enc, 0); /* rendering intent: perceptual */
    /* zlib level 6 with every filter tried cost ~150 ms at 1280x720; level 3 with the
     * Paeth/Up filters writes files a few percent larger several times faster. */
    if (!e)
        e = spng_set_option(enc, SPNG_IMG_COMPRESSION_LEVEL, 3);
    if (!e)
        e = spng_set_option(enc, SPNG_FILTER_CHOICE, SPNG_FILTER_CHOICE_UP | SPNG_FILTER_CHOICE_PAETH);
    if (!e)
        e = spng_encode_image(enc, NULL, 0, SPNG_FMT_PNG,
                              SPNG_ENCODE_PROGRESSIVE | SPNG_ENCODE_FINALIZE);
    for (int32_t y = 0; !e && y < image->height; y++) {
        encode_row(table, image->pixels + (size_t)y * image->stride, image->width, image->channels, scale, data, row);
        e = spng_encode_row(enc, row, row_bytes);
        /* The last row reports end of image, with the file finalized. */
        if (e == SPNG_EOI && y == image->height - 1)
            e = 0;
    }
    spng_ctx_free(enc);
    if (e) {
        r = sink.failed ? NACRE_ERROR_IO
                        : nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot encode PNG: %s", path,
                                  spng_strerror(e));
        goto out_abort;
    }
    r = nc_tmpfile_commit(ctx, &tmp);
    goto out_free_row;

out_abort:
    nc_tmpfile_abort(ctx, &tmp);
out_free_row:
    nc_free(ctx, row);
    nc_free(ctx, table);
    return r;
}

static nacre_result png_read_error(nacre_context *ctx, const char *path, FILE *fp, int e)
{
    if (ferror(fp))
        return nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot read file: %s", path, strerror(errno));
    if (feof(fp))
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: invalid PNG: file is truncated", path);
    return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: invalid PNG: %s", path, spng_strerror(e));
}

/* Decode the PNG of stream fp (closed here); `path` names it in messages. */
static nacre_result read_png_stream(nacre_context *ctx, const char *path, FILE *fp, int64_t file_size, bool srgb,
                                    nacre_image *out);

nacre_result nc_image_read_png(nacre_context *ctx, const char *path, bool srgb, nacre_image *out)
{
    FILE *fp = fopen(path, "rb");
    if (!fp)
        return nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot open: %s", path, strerror(errno));
    struct stat st;
    return read_png_stream(ctx, path, fp, fstat(fileno(fp), &st) == 0 ? (int64_t)st.st_size : -1, srgb, out);
}

nacre_result nc_image_read_png_memory(nacre_context *ctx, const char *name, const void *bytes, size_t size, bool srgb,
                                      nacre_image *out)
{
    if (size == 0)
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: invalid PNG: no bytes", name);
    FILE *fp = fmemopen((void *)(uintptr_t)bytes, size, "rb");
    if (!fp)
        return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "%s: cannot open the PNG's bytes: %s", name, strerror(errno));
    return read_png_stream(ctx, name, fp, (int64_t)size, srgb, out);
}

static nacre_result read_png_stream(nacre_context *ctx, const char *path, FILE *fp, int64_t file_size, bool srgb,
                                    nacre_image *out)
{
    nacre_result r = NACRE_OK;
    uint8_t *data = NULL;
    float *table16 = NULL;
    spng_ctx *dec = spng_ctx_new(0);
    if (!dec) {
        r = nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "%s: out of memory creating PNG decoder",
                    path);
        goto out_close;
    }
    spng_set_image_limits(dec, NC_IMAGE_MAX_SIDE, NC_IMAGE_MAX_SIDE);
    spng_set_chunk_limits(dec, PNG_CHUNK_LIMIT, PNG_CHUNK_LIMIT);
    int e = spng_set_png_file(dec, fp);
    struct spng_ihdr ihdr;
    if (!e)
        e = spng_get_ihdr(dec, &ihdr);
    if (e) {
        r = png_read_error(ctx, path, fp, e);
        goto out_free_dec;
    }
    /* Deflate expands at most ~1032:1; a pixel holds at least bit_depth bits (1 for the
     * smallest grey or palette images). */
    r = nc_image_check_file_size(ctx, path, ihdr.width, ihdr.height, file_size, ihdr.bit_depth, 1032.0);
    if (r != NACRE_OK)
        goto out_free_dec;

    bool wide = ihdr.bit_depth == 16;
    int fmt = wide ? SPNG_FMT_RGBA16 : SPNG_FMT_RGBA8;
    size_t size;
    e = spng_decoded_image_size(dec, fmt, &size);
    if (e) {
        r = png_read_error(ctx, path, fp, e);
        goto out_free_dec;
    }
    data = nc_alloc(ctx, size);
    if (!data) {
        r = NACRE_ERROR_OUT_OF_MEMORY;
        goto out_free_dec;
    }
    e = spng_decode_image(dec, data, size, fmt, SPNG_DECODE_TRNS);
    if (e) {
        r = png_read_error(ctx, path, fp, e);
        goto out_free_dec;
    }
    struct spng_trns trns;
    bool alpha = ihdr.color_type == SPNG_COLOR_TYPE_GRAYSCALE_ALPHA ||
                 ihdr.color_type == SPNG_COLOR_TYPE_TRUECOLOR_ALPHA ||
                 spng_get_trns(dec, &trns) == 0;
    int32_t channels = alpha ? 4 : 3;
    r = nacre_image_alloc(ctx, (int32_t)ihdr.width, (int32_t)ihdr.height, channels, out);
    if (r != NACRE_OK)
        goto out_free_dec;

    size_t pixels = (size_t)ihdr.width * (size_t)ihdr.height;
    float *dst = out->pixels; /* freshly allocated: stride == width * channels */
    if (wide) {
        /* 64 Ki entries (256 KiB) beat a powf per sample for any image over ~100x100. */
        table16 = nc_alloc(ctx, 65536 * sizeof(float));
        if (!table16) {
            nacre_image_free(ctx, out);
            r = NACRE_ERROR_OUT_OF_MEMORY;
            goto out_free_dec;
        }
        for (int i = 0; i < 65536; i++)
            table16[i] = srgb ? nc_srgb_to_linear((float)i / 65535.0f) : (float)i / 65535.0f;
        const uint16_t *src = (const uint16_t *)data;
        for (size_t i = 0; i < pixels; i++, src += 4, dst += channels) {
            dst[0] = table16[src[0]];
            dst[1] = table16[src[1]];
            dst[2] = table16[src[2]];
            if (alpha)
                dst[3] = (float)src[3] / 65535.0f;
        }
    } else {
        float table8[256];
        for (int i = 0; i < 256; i++)
            table8[i] = srgb ? nc_srgb_to_linear((float)i / 255.0f) : (float)i / 255.0f;
        const uint8_t *src = data;
        for (size_t i = 0; i < pixels; i++, src += 4, dst += channels) {
            dst[0] = table8[src[0]];
            dst[1] = table8[src[1]];
            dst[2] = table8[src[2]];
            if (alpha)
                dst[3] = (float)src[3] / 255.0f;
        }
    }

out_free_dec:
    spng_ctx_free(dec);
out_close:
    fclose(fp);
    nc_free(ctx, table16);
    nc_free(ctx, data);
    return r;
}
