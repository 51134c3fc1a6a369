/*
 * test_image.c: the image module: allocation, EXR and PNG round trips (HALF/FLOAT, strides, RGBA,
 * grey, exposure), files made directly with libspng and OpenEXR (16-bit PNG, tiled EXR with an
 * offset data window and mixed channel types), damaged and missing files, write failures that
 * must leave nothing behind, allocation failures, and comparison metrics on hand-computed cases.
 * Files go to NACRE_TEST_TMP/image.
 */
#include <nacre/nacre.h>

#include "io/image_private.h"
#include "test_util.h"

#include <OpenEXR/openexr.h>
#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <signal.h>
#include <spng.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#define DIR_ NACRE_TEST_TMP "/image"

static char *tpath(char *buf, const char *name)
{
    snprintf(buf, 512, "%s/%s", DIR_, name);
    return buf;
}

static bool file_exists(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0;
}

/* Entries of the test folder whose name starts with `prefix` and contains ".tmp". */
static int count_temp_files(const char *prefix)
{
    DIR *d = opendir(DIR_);
    if (!d)
        return -1;
    int n = 0;
    struct dirent *e;
    size_t len = strlen(prefix);
    while ((e = readdir(d)) != NULL)
        if (strncmp(e->d_name, prefix, len) == 0 && strstr(e->d_name + len, ".tmp"))
            n++;
    closedir(d);
    return n;
}

static bool error_names(const nacre_context *ctx, const char *path)
{
    const char *msg = nacre_context_last_error(ctx);
    bool ok = strstr(msg, path) != NULL;
    if (!ok)
        printf("  message without path %s: %s\n", path, msg);
    return ok;
}

static uint32_t rng_next(uint32_t *s)
{
    *s = *s * 1664525u + 1013904223u;
    return *s >> 8;
}

static float rng_float(uint32_t *s) { return (float)rng_next(s) / 16777216.0f; }

static double srgb_encode(double v)
{
    if (!(v > 0.0))
        return 0.0;
    if (v >= 1.0)
        return 1.0;
    return v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1.0 / 2.4) - 0.055;
}

static nacre_image make_image(nacre_context *ctx, int32_t w, int32_t h, int32_t c, size_t pad)
{
    /* A padded layout, built by hand: the library must honour stride. */
    nacre_image img = {w, h, c, (size_t)w * (size_t)c + pad, NULL};
    img.pixels = calloc(img.stride * (size_t)h, sizeof(float));
    for (size_t i = 0; i < img.stride * (size_t)h; i++)
        img.pixels[i] = NAN; /* padding poison: must never be read into a file */
    (void)ctx;
    return img;
}

static float *px(const nacre_image *img, int32_t x, int32_t y)
{
    return img->pixels + (size_t)y * img->stride + (size_t)x * (size_t)img->channels;
}

static void expect_read_error(nacre_context *ctx, const char *path, nacre_result code);

/* ------------------------------------------------------------------------------------------ */

static void test_alloc(nacre_context *ctx)
{
    nacre_image img;
    CHECK(nacre_image_alloc(ctx, 3, 2, 4, &img) == NACRE_OK);
    CHECK(img.width == 3 && img.height == 2 && img.channels == 4 && img.stride == 12);
    CHECK(img.pixels && img.pixels[0] == 0.0f && img.pixels[23] == 0.0f);
    nacre_image_free(ctx, &img);
    CHECK(img.pixels == NULL && img.width == 0);
    nacre_image_free(ctx, &img); /* twice is harmless */

    CHECK(nacre_image_alloc(ctx, 0, 2, 3, &img) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(img.pixels == NULL);
    CHECK(nacre_image_alloc(ctx, 65537, 2, 3, &img) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(nacre_image_alloc(ctx, 2, -1, 3, &img) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(nacre_image_alloc(ctx, 2, 2, 0, &img) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(nacre_image_alloc(ctx, 2, 2, 5, &img) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "channels") != NULL);
    CHECK(nacre_image_alloc(ctx, 2, 2, 3, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(nacre_image_alloc(ctx, 65536, 1, 1, &img) == NACRE_OK);
    nacre_image_free(ctx, &img);
}

static void test_exr_float_roundtrip(nacre_context *ctx)
{
    char path[512];
    /* 37 x 19 spans two 16-line ZIP chunks; 5 floats of padding per row. */
    nacre_image img = make_image(ctx, 37, 19, 3, 5);
    uint32_t s = 1;
    for (int32_t y = 0; y < img.height; y++)
        for (int32_t x = 0; x < img.width; x++)
            for (int c = 0; c < 3; c++) {
                float v = (rng_float(&s) - 0.25f) * powf(10.0f, (float)((x + c) % 12) - 6.0f);
                px(&img, x, y)[c] = v;
            }
    px(&img, 0, 0)[0] = 1e30f;
    px(&img, 1, 0)[0] = -0.0f;
    px(&img, 2, 0)[0] = 1e-40f; /* a float denormal */
    nacre_image_write_options opt = {0.0f, NACRE_EXR_FLOAT};
    CHECK(nacre_image_write(ctx, &img, tpath(path, "float.exr"), &opt) == NACRE_OK);
    nacre_image back = {0};
    CHECK(nacre_image_read(ctx, path, &back) == NACRE_OK);
    CHECK(back.width == 37 && back.height == 19 && back.channels == 3);
    CHECK(back.stride == 37 * 3);
    int mismatches = 0;
    if (back.pixels)
        for (int32_t y = 0; y < img.height; y++)
            for (int32_t x = 0; x < img.width; x++)
                if (memcmp(px(&img, x, y), px(&back, x, y), 3 * sizeof(float)) != 0)
                    mismatches++;
    CHECK(mismatches == 0);
    nacre_image_free(ctx, &back);
    CHECK(count_temp_files("float.exr") == 0);
    free(img.pixels);
}

static void test_exr_half_roundtrip(nacre_context *ctx)
{
    char path[512];
    nacre_image img = make_image(ctx, 23, 17, 3, 2);
    uint32_t s = 7;
    for (int32_t y = 0; y < img.height; y++)
        for (int32_t x = 0; x < img.width; x++)
            for (int c = 0; c < 3; c++) {
                /* (1024 + m) / 1024 * 2^e with e in [-14, 15]: every normal half value. */
                int m = (int)(rng_next(&s) % 1024);
                int e = (int)(rng_next(&s) % 30) - 14;
                float v = ldexpf((float)(1024 + m) / 1024.0f, e);
                px(&img, x, y)[c] = (rng_next(&s) & 1) ? -v : v;
            }
    px(&img, 0, 0)[0] = 0.0f;
    px(&img, 1, 0)[0] = 65504.0f; /* largest half */
    px(&img, 2, 0)[0] = ldexpf(1.0f, -24); /* smallest half denormal */
    /* Not representable: must round to the nearest half. */
    px(&img, 3, 0)[0] = 0.1f;
    CHECK(nc_image_write_exr(ctx, &img, tpath(path, "half.exr"), NACRE_EXR_HALF) == NACRE_OK);
    nacre_image back = {0};
    CHECK(nacre_image_read(ctx, path, &back) == NACRE_OK);
    CHECK(back.width == 23 && back.height == 17 && back.channels == 3);
    int mismatches = 0;
    if (back.pixels) {
        for (int32_t y = 0; y < img.height; y++)
            for (int32_t x = 0; x < img.width; x++)
                for (int c = 0; c < 3; c++)
                    if (!(x == 3 && y == 0 && c == 0) && px(&img, x, y)[c] != px(&back, x, y)[c])
                        mismatches++;
        /* The half nearest 0.1 is 1638/16384 = 0.0999755859375. */
        CHECK(px(&back, 3, 0)[0] == 0.0999755859375f);
    }
    CHECK(mismatches == 0);
    nacre_image_free(ctx, &back);

    /* Default options (NULL) write half too. */
    CHECK(nacre_image_write(ctx, &img, tpath(path, "half_default.EXR"), NULL) == NACRE_OK);
    CHECK(nacre_image_read(ctx, path, &back) == NACRE_OK);
    CHECK(back.pixels && back.pixels[1] == px(&img, 0, 0)[1]);
    nacre_image_free(ctx, &back);
    free(img.pixels);
}

/* Every channel count and pixel type over small sizes: single-pixel rows, chunks that ZIP cannot
 * shrink (stored raw), partial last chunks. Values are exact in half. */
static void test_exr_small_sizes(nacre_context *ctx)
{
    char path[512];
    static const int32_t sizes[5] = {1, 2, 3, 5, 17};
    int bad = 0, failed = 0;
    for (int a = 0; a < 5; a++)
        for (int b = 0; b < 5; b++)
            for (int32_t ch = 1; ch <= 4; ch++)
                for (int t = 0; t < 2; t++) {
                    int32_t w = sizes[a], h = sizes[b];
                    nacre_image img = make_image(ctx, w, h, ch, 1);
                    for (int32_t y = 0; y < h; y++)
                        for (int32_t x = 0; x < w; x++)
                            for (int32_t c = 0; c < ch; c++)
                                px(&img, x, y)[c] = (float)((x * 7 + y * 13 + c * 3) % 64) * 0.25f;
                    nacre_image back = {0};
                    if (nc_image_write_exr(ctx, &img, tpath(path, "small.exr"),
                                              t ? NACRE_EXR_FLOAT : NACRE_EXR_HALF) != NACRE_OK ||
                        nacre_image_read(ctx, path, &back) != NACRE_OK) {
                        failed++;
                        free(img.pixels);
                        continue;
                    }
                    /* 1 and 2 channels come back as grey RGB (+ alpha). */
                    for (int32_t y = 0; y < h; y++)
                        for (int32_t x = 0; x < w; x++) {
                            const float *p = px(&img, x, y), *q = px(&back, x, y);
                            if (ch >= 3) {
                                for (int32_t c = 0; c < ch; c++)
                                    bad += p[c] != q[c];
                            } else {
                                bad += q[0] != p[0] || q[1] != p[0] || q[2] != p[0];
                                if (ch == 2)
                                    bad += q[3] != p[1];
                            }
                        }
                    nacre_image_free(ctx, &back);
                    free(img.pixels);
                }
    CHECK(failed == 0);
    CHECK(bad == 0);
}

static void test_exr_channels(nacre_context *ctx)
{
    char path[512];
    /* RGBA float. */
    nacre_image img = make_image(ctx, 5, 4, 4, 3);
    for (int32_t y = 0; y < 4; y++)
        for (int32_t x = 0; x < 5; x++)
            for (int c = 0; c < 4; c++)
                px(&img, x, y)[c] = (float)(x + 10 * y) + 0.25f * (float)c;
    CHECK(nc_image_write_exr(ctx, &img, tpath(path, "rgba.exr"), NACRE_EXR_FLOAT) == NACRE_OK);
    nacre_image back = {0};
    CHECK(nacre_image_read(ctx, path, &back) == NACRE_OK);
    CHECK(back.channels == 4);
    int bad = 0;
    for (int32_t y = 0; back.pixels && y < 4; y++)
        for (int32_t x = 0; x < 5; x++)
            bad += memcmp(px(&img, x, y), px(&back, x, y), 4 * sizeof(float)) != 0;
    CHECK(bad == 0);
    nacre_image_free(ctx, &back);
    free(img.pixels);

    /* One channel is written as Y and read back as grey RGB. */
    img = make_image(ctx, 3, 2, 1, 1);
    for (int32_t y = 0; y < 2; y++)
        for (int32_t x = 0; x < 3; x++)
            px(&img, x, y)[0] = (float)(x + 3 * y) * 0.5f;
    CHECK(nc_image_write_exr(ctx, &img, tpath(path, "grey.exr"), NACRE_EXR_HALF) == NACRE_OK);
    CHECK(nacre_image_read(ctx, path, &back) == NACRE_OK);
    CHECK(back.channels == 3);
    bad = 0;
    for (int32_t y = 0; back.pixels && y < 2; y++)
        for (int32_t x = 0; x < 3; x++)
            for (int c = 0; c < 3; c++)
                bad += px(&back, x, y)[c] != px(&img, x, y)[0];
    CHECK(bad == 0);
    nacre_image_free(ctx, &back);
    free(img.pixels);

    /* Grey + alpha: Y and A, read back as RGBA. */
    img = make_image(ctx, 2, 2, 2, 0);
    for (int i = 0; i < 8; i++)
        img.pixels[i] = (float)i * 0.125f;
    CHECK(nc_image_write_exr(ctx, &img, tpath(path, "ya.exr"), NACRE_EXR_FLOAT) == NACRE_OK);
    CHECK(nacre_image_read(ctx, path, &back) == NACRE_OK);
    CHECK(back.channels == 4);
    if (back.pixels) {
        CHECK(back.pixels[4] == 0.25f && back.pixels[5] == 0.25f && back.pixels[6] == 0.25f);
        CHECK(back.pixels[7] == 0.375f);
    }
    nacre_image_free(ctx, &back);
    free(img.pixels);
}

/* Test EXRs made directly with OpenEXR: data window (5,-3)-(17,5) (13 x 9 pixels), scanline
 * (ZIP, 16 lines per chunk) or 4x4 tiles (uncompressed), with the given channels. Values by
 * channel name: R = x / 2, G = y + 1/4, B = 100 x + y, A = 3/4, anything else -1 (x, y from the
 * window's corner). */
enum { TW = 13, TH = 9 };

static float exr_value(const char *name, int x, int y)
{
    switch (name[0] == '\0' || name[1] != '\0' ? '?' : name[0]) {
    case 'R': return (float)x * 0.5f;
    case 'G': return (float)y + 0.25f;
    case 'B': return (float)(x * 100 + y);
    case 'A': return 0.75f;
    default: return -1.0f;
    }
}

static bool write_test_exr(const char *path, bool tiled, int n, const char *const *names,
                           const exr_pixel_type_t *types)
{
    static float fbuf[8][TH][TW];
    static uint32_t ubuf[8][TH][TW];
    for (int c = 0; c < n; c++)
        for (int y = 0; y < TH; y++)
            for (int x = 0; x < TW; x++) {
                fbuf[c][y][x] = exr_value(names[c], x, y);
                ubuf[c][y][x] = (uint32_t)fbuf[c][y][x];
            }
    /* OpenEXR 3.1.5 corrupts ZIP chunks that do not shrink (the library works around it for
     * its own files), so the small tiles here are stored uncompressed. */
    exr_compression_t compression = tiled ? EXR_COMPRESSION_NONE : EXR_COMPRESSION_ZIP;
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    exr_context_t exr = NULL;
    int part = 0;
    exr_attr_box2i_t dw;
    dw.min.x = 5;
    dw.min.y = -3;
    dw.max.x = 5 + TW - 1;
    dw.max.y = -3 + TH - 1;
    exr_attr_v2f_t centre;
    centre.x = 0.0f;
    centre.y = 0.0f;
    exr_result_t rv = exr_start_write(&exr, path, EXR_WRITE_FILE_DIRECTLY, &init);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_add_part(exr, NULL, tiled ? EXR_STORAGE_TILED : EXR_STORAGE_SCANLINE, &part);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_initialize_required_attr(exr, part, &dw, &dw, 1.0f, &centre, 1.0f,
                                          EXR_LINEORDER_INCREASING_Y, compression);
    if (rv == EXR_ERR_SUCCESS && tiled)
        rv = exr_set_tile_descriptor(exr, part, 4, 4, EXR_TILE_ONE_LEVEL, EXR_TILE_ROUND_DOWN);
    for (int c = 0; c < n && rv == EXR_ERR_SUCCESS; c++)
        rv = exr_add_channel(exr, part, names[c], types[c], EXR_PERCEPTUALLY_LOGARITHMIC, 1, 1);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_write_header(exr);
    int32_t lines = 16;
    if (rv == EXR_ERR_SUCCESS && !tiled)
        rv = exr_get_scanlines_per_chunk(exr, part, &lines);
    exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
    bool first = true;
    int nx = tiled ? (TW + 3) / 4 : 1, ny = tiled ? (TH + 3) / 4 : (TH + lines - 1) / lines;
    for (int ty = 0; ty < ny && rv == EXR_ERR_SUCCESS; ty++) {
        for (int tx = 0; tx < nx && rv == EXR_ERR_SUCCESS; tx++) {
            exr_chunk_info_t ci;
            int x0 = tiled ? tx * 4 : 0, y0 = tiled ? ty * 4 : ty * lines;
            rv = tiled ? exr_write_tile_chunk_info(exr, part, tx, ty, 0, 0, &ci)
                       : exr_write_scanline_chunk_info(exr, part, dw.min.y + y0, &ci);
            if (rv == EXR_ERR_SUCCESS)
                rv = first ? exr_encoding_initialize(exr, part, &ci, &enc)
                           : exr_encoding_update(exr, part, &ci, &enc);
            if (rv != EXR_ERR_SUCCESS)
                break;
            first = false;
            for (int c = 0; c < enc.channel_count; c++) {
                exr_coding_channel_info_t *ch = &enc.channels[c];
                int k = 0;
                while (k < n - 1 && strcmp(names[k], ch->channel_name) != 0)
                    k++;
                bool uint = types[k] == EXR_PIXEL_UINT;
                ch->encode_from_ptr = uint ? (const uint8_t *)&ubuf[k][y0][x0]
                                           : (const uint8_t *)&fbuf[k][y0][x0];
                ch->user_pixel_stride = 4;
                ch->user_line_stride = TW * 4;
                ch->user_bytes_per_element = 4;
                ch->user_data_type = uint ? EXR_PIXEL_UINT : EXR_PIXEL_FLOAT;
            }
            rv = exr_encoding_choose_default_routines(exr, part, &enc);
            if (rv == EXR_ERR_SUCCESS)
                rv = exr_encoding_run(exr, part, &enc);
        }
    }
    if (!first)
        exr_encoding_destroy(exr, &enc);
    if (exr) {
        exr_result_t frv = exr_finish(&exr);
        if (rv == EXR_ERR_SUCCESS)
            rv = frv;
    }
    if (rv != EXR_ERR_SUCCESS)
        printf("  writing test EXR %s failed: %s\n", path, exr_get_default_error_message(rv));
    return rv == EXR_ERR_SUCCESS;
}

/* Read a file from write_test_exr and check every pixel; `present` lists which of R, G, B, A
 * the file has (missing colour channels read as 0). */
static void check_test_exr(nacre_context *ctx, const char *path, const bool present[4])
{
    nacre_image img = {0};
    CHECK(nacre_image_read(ctx, path, &img) == NACRE_OK);
    CHECK(img.width == TW && img.height == TH && img.channels == (present[3] ? 4 : 3));
    static const char *const rgba[4] = {"R", "G", "B", "A"};
    int bad = 0;
    for (int y = 0; img.pixels && y < TH; y++)
        for (int x = 0; x < TW; x++)
            for (int c = 0; c < img.channels; c++)
                bad += px(&img, x, y)[c] != (present[c] ? exr_value(rgba[c], x, y) : 0.0f);
    CHECK(bad == 0);
    if (bad)
        printf("  %s: %d wrong values\n", path, bad);
    nacre_image_free(ctx, &img);
}

static void test_exr_foreign(nacre_context *ctx)
{
    char path[512];
    /* Tiled, mixed types, an extra channel. */
    const char *n1[5] = {"R", "G", "B", "A", "Z"};
    exr_pixel_type_t t1[5] = {EXR_PIXEL_HALF, EXR_PIXEL_FLOAT, EXR_PIXEL_UINT, EXR_PIXEL_HALF,
                              EXR_PIXEL_FLOAT};
    bool p1[4] = {true, true, true, true};
    if (write_test_exr(tpath(path, "tiled.exr"), true, 5, n1, t1))
        check_test_exr(ctx, path, p1);
    else
        CHECK(!"tiled EXR written");
    /* Scanline, all HALF, one of three channels not read (OpenEXR 3.1 crashed on a NULL
     * destination here), no B. */
    const char *n2[3] = {"G", "R", "Z"};
    exr_pixel_type_t t2[3] = {EXR_PIXEL_HALF, EXR_PIXEL_HALF, EXR_PIXEL_HALF};
    bool p2[4] = {true, true, false, false};
    if (write_test_exr(tpath(path, "scan_grz.exr"), false, 3, n2, t2))
        check_test_exr(ctx, path, p2);
    else
        CHECK(!"scanline GRZ EXR written");
    /* The same with four channels and alpha. */
    const char *n3[4] = {"A", "B", "R", "Z"};
    exr_pixel_type_t t3[4] = {EXR_PIXEL_HALF, EXR_PIXEL_HALF, EXR_PIXEL_HALF, EXR_PIXEL_HALF};
    bool p3[4] = {true, false, true, true};
    if (write_test_exr(tpath(path, "tiled_abrz.exr"), true, 4, n3, t3))
        check_test_exr(ctx, path, p3);
    else
        CHECK(!"tiled ABRZ EXR written");
    /* No colour at all. */
    const char *n4[1] = {"Z"};
    exr_pixel_type_t t4[1] = {EXR_PIXEL_FLOAT};
    CHECK(write_test_exr(tpath(path, "only_z.exr"), false, 1, n4, t4));
    expect_read_error(ctx, path, NACRE_ERROR_UNSUPPORTED);
}

/* The PNG writer's table-driven sRGB encoding gives the byte of the powf formula for every
 * float: checked on a stride through all floats in (0, 1), around every code's threshold, and
 * on the special values. */
static void test_srgb8_table(void)
{
    nc_srgb8_table *tb = malloc(sizeof(*tb));
    CHECK(tb != NULL);
    if (!tb)
        return;
    nc_srgb8_table_build(tb);
    uint64_t checked = 0, wrong = 0;
    for (uint32_t bits = 1; bits < 0x3F800000u; bits += 997) {
        float v;
        memcpy(&v, &bits, sizeof(v));
        wrong += nc_srgb8_encode(tb, v) != nc_srgb8_reference(v);
        checked++;
    }
    for (int k = 1; k < 256; k++) {
        uint32_t b0;
        memcpy(&b0, &tb->t[k], sizeof(b0));
        for (uint32_t bits = b0 > 2048 ? b0 - 2048 : 1; bits < b0 + 2048 && bits < 0x3F800000u; bits++) {
            float v;
            memcpy(&v, &bits, sizeof(v));
            wrong += nc_srgb8_encode(tb, v) != nc_srgb8_reference(v);
            checked++;
        }
    }
    const float special[] = {0.0f, -0.0f, -1.0f, 1.0f, 2.0f, 1e-40f, 0.0031308f, 0.5f, 0.99999994f, INFINITY, -INFINITY, NAN};
    for (size_t i = 0; i < sizeof(special) / sizeof(special[0]); i++) {
        wrong += nc_srgb8_encode(tb, special[i]) != nc_srgb8_reference(special[i]);
        checked++;
    }
    printf("sRGB 8-bit table: %llu floats checked, %llu differ from powf\n", (unsigned long long)checked,
           (unsigned long long)wrong);
    CHECK(wrong == 0);
    CHECK(nc_srgb8_encode(tb, 0.5f) == 188 && nc_srgb8_encode(tb, 0.0031308f) == 10);
    free(tb);
}

static void test_png_roundtrip(nacre_context *ctx)
{
    char path[512];
    nacre_image img = make_image(ctx, 31, 7, 3, 4);
    uint32_t s = 3;
    for (int32_t y = 0; y < img.height; y++)
        for (int32_t x = 0; x < img.width; x++)
            for (int c = 0; c < 3; c++)
                px(&img, x, y)[c] = rng_float(&s) * 1.3f - 0.1f; /* some clamp at each end */
    px(&img, 0, 0)[0] = 0.002f; /* the linear segment of the sRGB curve */
    px(&img, 1, 0)[0] = 1.0f;
    px(&img, 2, 0)[0] = 0.0f;
    CHECK(nc_image_write_png(ctx, &img, tpath(path, "rgb.png"), 0.0f) == NACRE_OK);
    nacre_image back = {0};
    CHECK(nacre_image_read(ctx, path, &back) == NACRE_OK);
    CHECK(back.width == 31 && back.height == 7 && back.channels == 3);
    /* Rounding to 8 bits moves a value by at most half a code in sRGB space. */
    double worst = 0.0;
    for (int32_t y = 0; back.pixels && y < img.height; y++)
        for (int32_t x = 0; x < img.width; x++)
            for (int c = 0; c < 3; c++) {
                double d = fabs(srgb_encode(px(&back, x, y)[c]) -
                                srgb_encode(px(&img, x, y)[c]));
                if (d > worst)
                    worst = d;
            }
    CHECK(worst <= 0.5 / 255.0 + 1e-5);
    if (back.pixels) {
        CHECK(px(&back, 1, 0)[0] == 1.0f);
        CHECK(px(&back, 2, 0)[0] == 0.0f);
        /* 0.002 is on the linear segment: 0.02584 -> code 7 (a 2.2 gamma would give 15). */
        CHECK_NEAR(px(&back, 0, 0)[0], 7.0 / 255.0 / 12.92, 1e-7);
    }
    nacre_image_free(ctx, &back);
    free(img.pixels);
}

static void test_png_exposure(nacre_context *ctx)
{
    char path[512];
    nacre_image img = make_image(ctx, 2, 1, 3, 0);
    for (int i = 0; i < 6; i++)
        img.pixels[i] = 0.5f;
    img.pixels[3] = 0.6f;
    nacre_image_write_options opt = {-1.0f, NACRE_EXR_HALF};
    CHECK(nacre_image_write(ctx, &img, tpath(path, "exposure_minus1.png"), &opt) == NACRE_OK);
    nacre_image back = {0};
    CHECK(nacre_image_read(ctx, path, &back) == NACRE_OK);
    if (back.pixels) {
        /* 0.5 * 2^-1 = 0.25 linear: sRGB 0.5371 -> code 137. */
        CHECK(fabs(srgb_encode(back.pixels[0]) - srgb_encode(0.25)) <= 0.5 / 255.0 + 1e-6);
        CHECK_NEAR(srgb_encode(back.pixels[0]) * 255.0, 137.0, 1e-3);
    }
    nacre_image_free(ctx, &back);

    /* +1 EV: 0.6 -> 1.2 clamps to white, 0.5 -> exactly 1.0. */
    CHECK(nc_image_write_png(ctx, &img, tpath(path, "exposure_plus1.png"), 1.0f) == NACRE_OK);
    CHECK(nacre_image_read(ctx, path, &back) == NACRE_OK);
    if (back.pixels) {
        CHECK(back.pixels[0] == 1.0f);
        CHECK(back.pixels[3] == 1.0f);
    }
    nacre_image_free(ctx, &back);

    CHECK(nc_image_write_png(ctx, &img, tpath(path, "exposure_nan.png"), NAN) ==
          NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(!file_exists(path));
    free(img.pixels);
}

static void test_png_alpha_and_grey(nacre_context *ctx)
{
    char path[512];
    nacre_image img = make_image(ctx, 3, 2, 4, 1);
    for (int32_t y = 0; y < 2; y++)
        for (int32_t x = 0; x < 3; x++) {
            float *p = px(&img, x, y);
            p[0] = 0.25f;
            p[1] = 0.5f;
            p[2] = 1.0f;
            p[3] = (float)(x + 3 * y) / 5.0f;
        }
    /* Exposure scales colour but never alpha. */
    CHECK(nc_image_write_png(ctx, &img, tpath(path, "rgba.png"), 2.0f) == NACRE_OK);
    nacre_image back = {0};
    CHECK(nacre_image_read(ctx, path, &back) == NACRE_OK);
    CHECK(back.channels == 4);
    int bad = 0;
    for (int32_t y = 0; back.pixels && y < 2; y++)
        for (int32_t x = 0; x < 3; x++) {
            float a = px(&img, x, y)[3];
            float expect = (float)(int)(a * 255.0f + 0.5f) / 255.0f;
            bad += px(&back, x, y)[3] != expect;
            bad += px(&back, x, y)[0] != 1.0f; /* 0.25 * 4 */
        }
    CHECK(bad == 0);
    nacre_image_free(ctx, &back);
    free(img.pixels);

    /* One channel: grey PNG, read back as RGB. */
    img = make_image(ctx, 4, 1, 1, 2);
    for (int x = 0; x < 4; x++)
        img.pixels[x] = (float)x / 3.0f;
    CHECK(nacre_image_write(ctx, &img, tpath(path, "grey.PNG"), NULL) == NACRE_OK);
    CHECK(nacre_image_read(ctx, path, &back) == NACRE_OK);
    CHECK(back.channels == 3);
    bad = 0;
    for (int x = 0; back.pixels && x < 4; x++) {
        const float *p = px(&back, x, 0);
        bad += p[0] != p[1] || p[1] != p[2];
        bad += fabs(srgb_encode(p[0]) - srgb_encode(img.pixels[x])) > 0.5 / 255.0 + 1e-6;
    }
    CHECK(bad == 0);
    nacre_image_free(ctx, &back);
    free(img.pixels);
}

/* A 16-bit RGB PNG written with libspng directly. */
static void test_png_16bit(nacre_context *ctx)
{
    char path[512];
    uint16_t data[2 * 2 * 3] = {0, 65535, 32768, 1000, 20000, 65534,
                                12, 40000, 50000, 65535, 0, 1};
    FILE *fp = fopen(tpath(path, "rgb16.png"), "wb");
    CHECK(fp != NULL);
    if (!fp)
        return;
    spng_ctx *enc = spng_ctx_new(SPNG_CTX_ENCODER);
    struct spng_ihdr ihdr = {2, 2, 16, SPNG_COLOR_TYPE_TRUECOLOR, 0, 0, 0};
    int e = spng_set_png_file(enc, fp);
    if (!e)
        e = spng_set_ihdr(enc, &ihdr);
    if (!e)
        e = spng_encode_image(enc, data, sizeof(data), SPNG_FMT_PNG, SPNG_ENCODE_FINALIZE);
    spng_ctx_free(enc);
    fclose(fp);
    CHECK(e == 0);
    nacre_image img = {0};
    CHECK(nacre_image_read(ctx, path, &img) == NACRE_OK);
    CHECK(img.channels == 3 && img.width == 2 && img.height == 2);
    int bad = 0;
    for (int i = 0; img.pixels && i < 12; i++) {
        double v = data[i] / 65535.0;
        double lin = v <= 0.04045 ? v / 12.92 : pow((v + 0.055) / 1.055, 2.4);
        bad += fabs(img.pixels[i] - lin) > 1e-6;
    }
    CHECK(bad == 0);
    nacre_image_free(ctx, &img);
}

/* Copy the first `keep` bytes of a file, or its first half if keep < 0. */
static bool copy_prefix(const char *from, const char *to, long keep)
{
    FILE *in = fopen(from, "rb");
    if (!in)
        return false;
    fseek(in, 0, SEEK_END);
    long size = ftell(in);
    fseek(in, 0, SEEK_SET);
    if (keep < 0 || keep > size)
        keep = size / 2;
    unsigned char *buf = malloc((size_t)size + 1);
    bool ok = buf && fread(buf, 1, (size_t)size, in) == (size_t)size;
    fclose(in);
    FILE *out = ok ? fopen(to, "wb") : NULL;
    ok = out && fwrite(buf, 1, (size_t)keep, out) == (size_t)keep;
    if (out)
        fclose(out);
    free(buf);
    return ok;
}

static void write_bytes(const char *path, const void *data, size_t size)
{
    FILE *fp = fopen(path, "wb");
    if (fp) {
        fwrite(data, 1, size, fp);
        fclose(fp);
    }
}

static uint32_t crc32_of(const unsigned char *p, size_t n)
{
    uint32_t c = 0xffffffffu;
    for (size_t i = 0; i < n; i++) {
        c ^= p[i];
        for (int k = 0; k < 8; k++)
            c = (c >> 1) ^ (0xedb88320u & (0u - (c & 1u)));
    }
    return c ^ 0xffffffffu;
}

static void put_be32(unsigned char *p, uint32_t v)
{
    p[0] = (unsigned char)(v >> 24);
    p[1] = (unsigned char)(v >> 16);
    p[2] = (unsigned char)(v >> 8);
    p[3] = (unsigned char)v;
}

static void expect_read_error(nacre_context *ctx, const char *path, nacre_result code)
{
    nacre_image img = {0};
    nacre_context_clear_error(ctx);
    nacre_result r = nacre_image_read(ctx, path, &img);
    CHECK(r == code);
    if (r != code)
        printf("  %s: got %d (%s)\n", path, (int)r, nacre_context_last_error(ctx));
    CHECK(img.pixels == NULL);
    CHECK(error_names(ctx, path));
    nacre_image_free(ctx, &img);
}

static void test_bad_files(nacre_context *ctx)
{
    char src[512], path[512];
    /* Noise, so that the compressed data is large enough to cut in the middle. */
    nacre_image img = make_image(ctx, 64, 64, 3, 0);
    uint32_t s = 11;
    for (size_t i = 0; i < 64 * 64 * 3; i++)
        img.pixels[i] = rng_float(&s);
    CHECK(nc_image_write_png(ctx, &img, tpath(src, "noise.png"), 0.0f) == NACRE_OK);
    CHECK(nc_image_write_exr(ctx, &img, tpath(path, "noise.exr"), NACRE_EXR_HALF) == NACRE_OK);
    free(img.pixels);

    CHECK(copy_prefix(src, tpath(path, "truncated.png"), -1));
    expect_read_error(ctx, path, NACRE_ERROR_PARSE);
    CHECK(copy_prefix(src, tpath(path, "truncated_header.png"), 20));
    expect_read_error(ctx, path, NACRE_ERROR_PARSE);
    char exr_src[512];
    tpath(exr_src, "noise.exr");
    CHECK(copy_prefix(exr_src, tpath(path, "truncated.exr"), -1));
    expect_read_error(ctx, path, NACRE_ERROR_PARSE);
    CHECK(copy_prefix(exr_src, tpath(path, "truncated_header.exr"), 30));
    expect_read_error(ctx, path, NACRE_ERROR_PARSE);

    unsigned char garbage[4096];
    for (size_t i = 0; i < sizeof(garbage); i++)
        garbage[i] = (unsigned char)(rng_next(&s) & 0xff);
    write_bytes(tpath(path, "garbage.png"), garbage, sizeof(garbage));
    expect_read_error(ctx, path, NACRE_ERROR_PARSE);
    write_bytes(tpath(path, "garbage.exr"), garbage, sizeof(garbage));
    expect_read_error(ctx, path, NACRE_ERROR_PARSE);
    /* The EXR magic number followed by garbage reaches the header parser. */
    garbage[0] = 0x76;
    garbage[1] = 0x2f;
    garbage[2] = 0x31;
    garbage[3] = 0x01;
    garbage[4] = 2;
    garbage[5] = garbage[6] = garbage[7] = 0;
    write_bytes(tpath(path, "garbage_magic.exr"), garbage, sizeof(garbage));
    expect_read_error(ctx, path, NACRE_ERROR_PARSE);
    write_bytes(tpath(path, "empty.png"), "", 0);
    expect_read_error(ctx, path, NACRE_ERROR_PARSE);
    write_bytes(tpath(path, "empty.exr"), "", 0);
    expect_read_error(ctx, path, NACRE_ERROR_PARSE);

    expect_read_error(ctx, tpath(path, "missing.png"), NACRE_ERROR_IO);
    CHECK(strstr(nacre_context_last_error(ctx), "No such file") != NULL);
    expect_read_error(ctx, tpath(path, "missing.exr"), NACRE_ERROR_IO);
    expect_read_error(ctx, tpath(path, "noise.tiff"), NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "unknown image extension") != NULL);

    /* A PNG header claiming 60000 x 60000 pixels (within the per-side limit, far over the
     * pixel limit) is refused before any allocation. */
    unsigned char png[8 + 25] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n', 0, 0, 0, 13,
                                 'I', 'H', 'D', 'R'};
    put_be32(png + 16, 60000);
    put_be32(png + 20, 60000);
    png[24] = 8; /* bit depth */
    png[25] = 2; /* RGB */
    put_be32(png + 29, crc32_of(png + 12, 17));
    write_bytes(tpath(path, "huge.png"), png, sizeof(png));
    expect_read_error(ctx, path, NACRE_ERROR_PARSE);
    CHECK(strstr(nacre_context_last_error(ctx), "out of range") != NULL);
}

/* JPEG: tests/data/gltf_textured.jpg holds the texels of gltf_textured.png (scripts/
 * make_gltf_tests.py, quality 100, no chroma subsampling), so the lossless PNG is the reference;
 * as data the samples are code / 255; broken files fail with one line naming the path. */
static void test_jpeg(nacre_context *ctx)
{
    const char *jpg_path = NACRE_SOURCE_DIR "/tests/data/gltf_textured.jpg";
    nacre_image jpg = {0}, png = {0}, data = {0};
    CHECK(nacre_image_read(ctx, jpg_path, &jpg) == NACRE_OK);
    CHECK(nacre_image_read(ctx, NACRE_SOURCE_DIR "/tests/data/gltf_textured.png", &png) == NACRE_OK);
    CHECK(nacre_image_read_data(ctx, jpg_path, &data) == NACRE_OK);
    CHECK(jpg.width == 8 && jpg.height == 8 && jpg.channels == 3 && jpg.stride == 24);
    if (jpg.pixels && png.pixels && data.pixels && png.width == 8 && png.height == 8 && png.channels == 3) {
        double worst = 0, worst_data = 0;
        for (size_t i = 0; i < 8 * 8 * 3; i++) {
            worst = fmax(worst, fabs(nc_linear_to_srgb(jpg.pixels[i]) - nc_linear_to_srgb(png.pixels[i])));
            worst_data = fmax(worst_data, fabs(nc_linear_to_srgb(jpg.pixels[i]) - data.pixels[i]));
        }
        printf("JPEG: largest difference to the PNG %.4f, sRGB read against data read %.2g\n", worst, worst_data);
        CHECK(worst < 4.0 / 255.0);
        CHECK(worst_data < 1e-5);
    }
    nacre_image_free(ctx, &jpg);
    nacre_image_free(ctx, &png);
    nacre_image_free(ctx, &data);

    char path[512];
    CHECK(copy_prefix(jpg_path, tpath(path, "truncated_header.jpg"), 100));
    expect_read_error(ctx, path, NACRE_ERROR_PARSE);
    CHECK(copy_prefix(jpg_path, tpath(path, "three_bytes.jpeg"), 3));
    expect_read_error(ctx, path, NACRE_ERROR_PARSE);
    unsigned char garbage[512];
    uint32_t s = 5;
    for (size_t i = 0; i < sizeof(garbage); i++)
        garbage[i] = (unsigned char)(rng_next(&s) & 0xff);
    write_bytes(tpath(path, "garbage.jpg"), garbage, sizeof(garbage));
    expect_read_error(ctx, path, NACRE_ERROR_PARSE);
    CHECK(strstr(nacre_context_last_error(ctx), "not a JPEG") != NULL);
    write_bytes(tpath(path, "empty.JPG"), "", 0);
    expect_read_error(ctx, path, NACRE_ERROR_PARSE);
    /* The frame header claiming 16000 x 16000 pixels in a file of under 1 KB is refused before
     * anything is decoded. */
    FILE *fp = fopen(jpg_path, "rb");
    unsigned char buf[4096];
    size_t n = fp ? fread(buf, 1, sizeof(buf), fp) : 0;
    if (fp)
        fclose(fp);
    size_t sof = 0;
    for (size_t i = 2; i + 9 < n && !sof; i++)
        if (buf[i] == 0xFF && buf[i + 1] == 0xC0)
            sof = i;
    CHECK(sof != 0);
    if (sof) {
        buf[sof + 5] = buf[sof + 7] = 16000 >> 8;
        buf[sof + 6] = buf[sof + 8] = 16000 & 0xff;
        write_bytes(tpath(path, "huge.jpg"), buf, n);
        expect_read_error(ctx, path, NACRE_ERROR_PARSE);
        printf("huge JPEG: %s\n", nacre_context_last_error(ctx));
        CHECK(strstr(nacre_context_last_error(ctx), "more than its") != NULL);
    }
    /* nacre reads JPEG, it does not write it */
    nacre_image img = make_image(ctx, 4, 4, 3, 0);
    CHECK(nacre_image_write(ctx, &img, tpath(path, "out.jpg"), NULL) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "writes PNG or EXR") != NULL);
    struct stat st;
    CHECK(stat(path, &st) != 0);
    free(img.pixels);
}

static int64_t write_at(exr_const_context_t exr, void *user, const void *buffer, uint64_t size,
                        uint64_t offset, exr_stream_error_func_ptr_t error_cb)
{
    (void)exr;
    (void)error_cb;
    FILE *fp = user;
    if (fseek(fp, (long)offset, SEEK_SET) != 0 || fwrite(buffer, 1, size, fp) != size)
        return -1;
    return (int64_t)size;
}

/* An EXR holding only a header that claims w x h pixels (one half channel, ZIP); no pixel data.
 * Written through our own stream: OpenEXR's file writer deletes a file whose chunks are missing.
 * `pad` zero bytes follow the header. */
static bool write_header_only_exr(const char *path, int w, int h, size_t pad)
{
    FILE *fp = fopen(path, "wb");
    CHECK(fp != NULL);
    if (!fp)
        return false;
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    init.user_data = fp;
    init.write_fn = write_at;
    exr_context_t exr = NULL;
    int part = 0;
    exr_result_t rv = exr_start_write(&exr, path, EXR_WRITE_FILE_DIRECTLY, &init);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_add_part(exr, NULL, EXR_STORAGE_SCANLINE, &part);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_initialize_required_attr_simple(exr, part, w, h, EXR_COMPRESSION_ZIP);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_add_channel(exr, part, "R", EXR_PIXEL_HALF, EXR_PERCEPTUALLY_LOGARITHMIC, 1, 1);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_write_header(exr);
    if (exr)
        exr_finish(&exr);
    fseek(fp, 0, SEEK_END);
    for (size_t i = 0; i < pad; i++)
        fputc(0, fp);
    fclose(fp);
    CHECK(rv == EXR_ERR_SUCCESS);
    return rv == EXR_ERR_SUCCESS;
}

static void test_exr_huge_header(nacre_context *ctx)
{
    char path[512];
    if (!write_header_only_exr(tpath(path, "huge.exr"), 60000, 60000, 0))
        return;
    expect_read_error(ctx, path, NACRE_ERROR_PARSE);
    CHECK(strstr(nacre_context_last_error(ctx), "out of range") != NULL);
}

static void test_header_vs_file_size(nacre_context *ctx)
{
    char path[512];
    if (!write_header_only_exr(tpath(path, "big_window.exr"), 16384, 16384, 17 * 1024))
        return;
    nacre_context *fresh = NULL;
    CHECK(nacre_context_create(NULL, &fresh) == NACRE_OK);
    expect_read_error(fresh, path, NACRE_ERROR_PARSE);
    CHECK(strstr(nacre_context_last_error(fresh), "can hold") != NULL);
    CHECK(nacre_context_memory_peak(fresh) < ((uint64_t)64 << 20));
    nacre_context_destroy(fresh);

    unsigned char png[8 + 25] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n', 0, 0, 0, 13,
                                 'I', 'H', 'D', 'R'};
    put_be32(png + 16, 16384);
    put_be32(png + 20, 16384);
    png[24] = 8; /* bit depth */
    png[25] = 2; /* RGB */
    put_be32(png + 29, crc32_of(png + 12, 17));
    write_bytes(tpath(path, "big_ihdr.png"), png, sizeof(png));
    expect_read_error(ctx, path, NACRE_ERROR_PARSE);
    CHECK(strstr(nacre_context_last_error(ctx), "can hold") != NULL);

    nacre_context *small = NULL;
    nacre_context_desc d = {0};
    d.memory_limit = 2u << 20;
    CHECK(nacre_context_create(&d, &small) == NACRE_OK);
    CHECK(nacre_context_memory_limit(small) == (2u << 20));
    nacre_image img = make_image(ctx, 512, 512, 3, 0);
    for (size_t i = 0; i < 512 * 512 * 3; i++)
        img.pixels[i] = 0.5f;
    CHECK(nc_image_write_png(ctx, &img, tpath(path, "big_for_limit.png"), 0.0f) == NACRE_OK);
    free(img.pixels);
    expect_read_error(small, path, NACRE_ERROR_OUT_OF_MEMORY);
    CHECK(strstr(nacre_context_last_error(small), "memory limit of 2.00 MiB") != NULL);
    CHECK(nacre_context_memory_used(small) == 0);
    nacre_image big = {0};
    CHECK(nacre_image_alloc(small, 1024, 1024, 3, &big) == NACRE_ERROR_OUT_OF_MEMORY);
    CHECK(strstr(nacre_context_last_error(small), "memory limit") != NULL);
    CHECK(nacre_context_set_memory_limit(small, 64u << 20) == NACRE_OK);
    CHECK(nacre_image_alloc(small, 1024, 1024, 3, &big) == NACRE_OK);
    CHECK(nacre_context_memory_used(small) >= 1024u * 1024u * 12u);
    nacre_image_free(small, &big);
    CHECK(nacre_context_memory_used(small) == 0);
    nacre_context_destroy(small);
}

static void test_write_failures(nacre_context *ctx)
{
    char path[512];
    nacre_image img = make_image(ctx, 8, 8, 3, 0);
    for (size_t i = 0; i < 8 * 8 * 3; i++)
        img.pixels[i] = 0.5f;

    /* A folder that does not exist. */
    const char *names[2] = {"no_such_dir/x.png", "no_such_dir/x.exr"};
    for (int k = 0; k < 2; k++) {
        nacre_context_clear_error(ctx);
        CHECK(nacre_image_write(ctx, &img, tpath(path, names[k]), NULL) == NACRE_ERROR_IO);
        CHECK(error_names(ctx, path));
        CHECK(strstr(nacre_context_last_error(ctx), "cannot create file: No such file") !=
              NULL);
        CHECK(!file_exists(path));
    }

    /* The target is a folder: the temporary file is written, the rename fails, and the
     * temporary file must be gone. */
    const char *dirs[2] = {"target_dir.png", "target_dir.exr"};
    for (int k = 0; k < 2; k++) {
        mkdir(tpath(path, dirs[k]), 0755);
        nacre_context_clear_error(ctx);
        CHECK(nacre_image_write(ctx, &img, path, NULL) == NACRE_ERROR_IO);
        CHECK(error_names(ctx, path));
        CHECK(count_temp_files(dirs[k]) == 0);
        /* Reading a folder fails cleanly too. */
        expect_read_error(ctx, path, NACRE_ERROR_IO);
    }

    /* Writing fails halfway (file size limit): nothing may be left behind. */
    nacre_image big = make_image(ctx, 256, 256, 3, 0);
    uint32_t s = 5;
    for (size_t i = 0; i < 256 * 256 * 3; i++)
        big.pixels[i] = rng_float(&s);
    struct rlimit old;
    getrlimit(RLIMIT_FSIZE, &old);
    struct rlimit lim = old;
    lim.rlim_cur = 4096;
    void (*old_handler)(int) = signal(SIGXFSZ, SIG_IGN);
    const char *partial[2] = {"partial.png", "partial.exr"};
    if (setrlimit(RLIMIT_FSIZE, &lim) == 0) {
        for (int k = 0; k < 2; k++) {
            nacre_context_clear_error(ctx);
            nacre_image_write_options opt = {0.0f, NACRE_EXR_FLOAT};
            nacre_result r = nacre_image_write(ctx, &big, tpath(path, partial[k]), &opt);
            CHECK(r == NACRE_ERROR_IO);
            CHECK(error_names(ctx, path));
            CHECK(strstr(nacre_context_last_error(ctx), "File too large") != NULL);
            CHECK(!file_exists(path));
            CHECK(count_temp_files(partial[k]) == 0);
        }
        setrlimit(RLIMIT_FSIZE, &old);
    }
    signal(SIGXFSZ, old_handler);
    free(big.pixels);

    /* A failed write keeps the previous file intact. */
    CHECK(nacre_image_write(ctx, &img, tpath(path, "keep.png"), NULL) == NACRE_OK);
    nacre_image bad = img;
    bad.stride = 1; /* less than width * channels */
    CHECK(nacre_image_write(ctx, &bad, path, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(error_names(ctx, path));
    nacre_image back = {0};
    CHECK(nacre_image_read(ctx, path, &back) == NACRE_OK);
    nacre_image_free(ctx, &back);

    /* Argument errors. */
    CHECK(nacre_image_write(ctx, &img, tpath(path, "x.bmp"), NULL) ==
          NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "x.bmp: unknown image extension") != NULL);
    CHECK(nacre_image_write(ctx, &img, tpath(path, "noext"), NULL) ==
          NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(nacre_image_write(ctx, NULL, tpath(path, "null.png"), NULL) ==
          NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(nc_image_write_exr(ctx, &img, tpath(path, "badtype.exr"), (nacre_exr_pixel)7) ==
          NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(!file_exists(path));
    CHECK(count_temp_files("") == 0);
    free(img.pixels);
}

static void test_compare(nacre_context *ctx)
{
    float ta[2] = {1.0f, 3.0f}, ra[2] = {2.0f, 0.0f};
    nacre_image t = {2, 1, 1, 2, ta}, r = {2, 1, 1, 2, ra};
    nacre_image_metrics m;
    CHECK(nacre_image_compare(ctx, &t, &r, &m) == NACRE_OK);
    /* diffs -1, 3: mse 5; peak 2; rel over b != 0: 1/2. */
    CHECK_NEAR(m.rmse, sqrt(5.0), 1e-12);
    CHECK_NEAR(m.rel_mse, (1.0 / 4.01 + 9.0 / 0.01) / 2.0, 1e-9);
    CHECK_NEAR(m.psnr, 10.0 * log10(4.0 / 5.0), 1e-12);
    CHECK_NEAR(m.mean_rel_err, 0.5, 1e-12);
    CHECK_NEAR(m.max_abs_err, 3.0, 0.0);
    CHECK(m.count == 2 && m.nonzero_ref == 1);

    /* Equal images: psnr is infinite. */
    CHECK(nacre_image_compare(ctx, &r, &r, &m) == NACRE_OK);
    CHECK(m.rmse == 0.0 && isinf(m.psnr) && m.psnr > 0 && m.max_abs_err == 0.0);

    /* Reference never positive: peak falls back to 1. */
    float tb[2] = {0.5f, -1.0f}, rb[2] = {0.0f, -1.0f};
    nacre_image t2 = {2, 1, 1, 2, tb}, r2 = {2, 1, 1, 2, rb};
    CHECK(nacre_image_compare(ctx, &t2, &r2, &m) == NACRE_OK);
    CHECK_NEAR(m.psnr, 10.0 * log10(1.0 / 0.125), 1e-12);
    CHECK_NEAR(m.mean_rel_err, 0.0, 0.0);
    CHECK(m.nonzero_ref == 1);

    /* Stride: 2x2 RGB with 2 floats of padding holding junk that must be ignored. */
    float tc[2 * 8], rc[2 * 8];
    for (int i = 0; i < 16; i++) {
        tc[i] = 1000.0f + (float)i;
        rc[i] = -1000.0f;
    }
    for (int y = 0; y < 2; y++)
        for (int i = 0; i < 6; i++) {
            rc[y * 8 + i] = 1.0f;
            tc[y * 8 + i] = 1.0f;
        }
    tc[8 + 5] = 1.5f;
    nacre_image t3 = {2, 2, 3, 8, tc}, r3 = {2, 2, 3, 8, rc};
    CHECK(nacre_image_compare(ctx, &t3, &r3, &m) == NACRE_OK);
    CHECK(m.count == 12 && m.nonzero_ref == 12);
    CHECK_NEAR(m.max_abs_err, 0.5, 0.0);
    CHECK_NEAR(m.rmse, sqrt(0.25 / 12.0), 1e-12);
    CHECK_NEAR(m.mean_rel_err, 0.5 / 12.0, 1e-12);
    CHECK_NEAR(m.rel_mse, 0.25 / 1.01 / 12.0, 1e-12);
    CHECK_NEAR(m.psnr, 10.0 * log10(1.0 / (0.25 / 12.0)), 1e-9);

    /* Different sizes. */
    nacre_image t4 = {1, 2, 1, 1, ta};
    nacre_context_clear_error(ctx);
    CHECK(nacre_image_compare(ctx, &t4, &r, &m) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(strstr(nacre_context_last_error(ctx), "1x2") != NULL);
    CHECK(strstr(nacre_context_last_error(ctx), "2x1") != NULL);
    nacre_image t5 = {2, 1, 3, 6, tc};
    CHECK(nacre_image_compare(ctx, &t5, &r, &m) == NACRE_ERROR_INVALID_ARGUMENT);
    CHECK(nacre_image_compare(ctx, &t, &r, NULL) == NACRE_ERROR_INVALID_ARGUMENT);
}

/* An allocator that fails after `budget` allocations and counts what is outstanding. */
typedef struct limit_state {
    int budget;
    long outstanding;
} limit_state;

static void *limited_alloc(size_t size, void *user)
{
    limit_state *a = user;
    if (a->budget == 0)
        return NULL;
    if (a->budget > 0)
        a->budget--;
    void *p = malloc(size);
    if (p)
        a->outstanding++;
    return p;
}

static void limited_free(void *ptr, void *user)
{
    limit_state *a = user;
    if (ptr)
        a->outstanding--;
    free(ptr);
}

static void test_allocation_failures(void)
{
    char png[512], exr[512], out[512];
    tpath(png, "noise.png");
    tpath(exr, "noise.exr");
    tpath(out, "oom_out.exr");
    int failures = 0, successes = 0;
    for (int budget = 0; budget < 12; budget++) {
        limit_state a = {-1, 0};
        nacre_context_desc desc = {{limited_alloc, limited_free, &a}, 1, NULL, NULL, 0};
        nacre_context *ctx = NULL;
        if (nacre_context_create(&desc, &ctx) != NACRE_OK)
            continue;
        const char *paths[2] = {png, exr};
        for (int k = 0; k < 2; k++) {
            a.budget = budget;
            nacre_image img = {0};
            nacre_result r = nacre_image_read(ctx, paths[k], &img);
            if (r == NACRE_OK) {
                successes++;
                a.budget = budget;
                r = nacre_image_write(ctx, &img, out, NULL);
                CHECK(r == NACRE_OK || r == NACRE_ERROR_OUT_OF_MEMORY);
                nacre_image_free(ctx, &img);
            } else {
                CHECK(r == NACRE_ERROR_OUT_OF_MEMORY);
                CHECK(img.pixels == NULL);
                failures++;
            }
        }
        a.budget = -1;
        nacre_context_destroy(ctx);
        CHECK(a.outstanding == 0);
    }
    CHECK(failures > 0 && successes > 0);
    CHECK(count_temp_files("oom_out") == 0);
}

/* Issue 29 items 6, 9 and 10: no EXR holds NaN or infinity; a half EXR clamps what it cannot hold
 * to 65504 and says so through the log callback; compare counts non-finite pixels instead of
 * letting NaN vanish from its maxima. */
typedef struct log_capture {
    int warnings;
    char last[1024];
} log_capture;

static void capture_log(void *user, nacre_log_level level, const char *message)
{
    log_capture *lc = user;
    if (level == NACRE_LOG_WARNING) {
        lc->warnings++;
        snprintf(lc->last, sizeof(lc->last), "%s", message);
    }
}

static void test_nonfinite_and_half_range(void)
{
    log_capture lc = {0, ""};
    nacre_context_desc desc = {0};
    desc.log_fn = capture_log;
    desc.log_user = &lc;
    nacre_context *ctx = NULL;
    CHECK(nacre_context_create(&desc, &ctx) == NACRE_OK);
    if (!ctx)
        return;
    char path[512];
    nacre_image img = make_image(ctx, 5, 4, 3, 1);
    for (int32_t y = 0; y < 4; y++)
        for (int32_t x = 0; x < 5; x++)
            for (int c = 0; c < 3; c++)
                px(&img, x, y)[c] = 0.25f * (float)(x + y + c);

    /* NaN and +-Inf are refused, naming the file and the pixel; nothing is left behind. */
    const float bad[3] = {NAN, INFINITY, -INFINITY};
    const char *bad_name[3] = {"NaN", "+Inf", "-Inf"};
    for (int i = 0; i < 3; i++) {
        px(&img, 3, 2)[1] = bad[i];
        for (int t = 0; t < 2; t++) {
            remove(tpath(path, "nonfinite.exr"));
            CHECK(nc_image_write_exr(ctx, &img, path, t ? NACRE_EXR_FLOAT : NACRE_EXR_HALF) ==
                  NACRE_ERROR_INVALID_ARGUMENT);
            CHECK(error_names(ctx, path));
            CHECK(strstr(nacre_context_last_error(ctx), "pixel (3, 2) channel G") != NULL);
            CHECK(strstr(nacre_context_last_error(ctx), bad_name[i]) != NULL);
            CHECK(!file_exists(path));
            CHECK(count_temp_files("nonfinite.exr") == 0);
        }
    }

    /* Compare: NaN in the test image is counted and left out of the metrics. */
    px(&img, 3, 2)[1] = NAN;
    nacre_image ref = make_image(ctx, 5, 4, 3, 0);
    for (int32_t y = 0; y < 4; y++)
        for (int32_t x = 0; x < 5; x++)
            for (int c = 0; c < 3; c++)
                px(&ref, x, y)[c] = 0.25f * (float)(x + y + c);
    px(&ref, 0, 0)[0] = 1.0f; /* one finite difference of 1 */
    nacre_image_metrics m;
    CHECK(nacre_image_compare(ctx, &img, &ref, &m) == NACRE_OK);
    CHECK(m.nonfinite_test == 1 && m.nonfinite_ref == 0);
    CHECK(m.count == 5 * 4 * 3 - 1);
    CHECK_NEAR(m.max_abs_err, 1.0, 0.0);
    CHECK(isfinite(m.rmse) && isfinite(m.rel_mse) && isfinite(m.mean_rel_err) && m.rmse > 0);
    px(&ref, 1, 1)[2] = -INFINITY;
    CHECK(nacre_image_compare(ctx, &img, &ref, &m) == NACRE_OK);
    CHECK(m.nonfinite_test == 1 && m.nonfinite_ref == 1 && m.count == 5 * 4 * 3 - 2);
    free(ref.pixels);

    /* Half range: values beyond 65504 are written as +-65504 with one warning giving the count;
     * float keeps them and does not warn. */
    px(&img, 3, 2)[1] = 1.0f;
    px(&img, 0, 0)[0] = 1e6f;
    px(&img, 1, 0)[2] = -70000.0f;
    px(&img, 2, 0)[1] = 65504.0f; /* the largest half: no clamping */
    lc.warnings = 0;
    CHECK(nc_image_write_exr(ctx, &img, tpath(path, "over.exr"), NACRE_EXR_HALF) == NACRE_OK);
    CHECK(lc.warnings == 1);
    CHECK(strstr(lc.last, "over.exr") != NULL && strstr(lc.last, "2 values") != NULL &&
          strstr(lc.last, "65504") != NULL);
    nacre_image back = {0};
    CHECK(nacre_image_read(ctx, path, &back) == NACRE_OK);
    if (back.pixels) {
        CHECK(px(&back, 0, 0)[0] == 65504.0f);
        CHECK(px(&back, 1, 0)[2] == -65504.0f);
        CHECK(px(&back, 2, 0)[1] == 65504.0f);
        CHECK(px(&back, 4, 3)[2] == px(&img, 4, 3)[2]);
        int32_t x, y, c;
        CHECK(nacre_image_count_nonfinite(&back, &x, &y, &c) == 0);
    }
    nacre_image_free(ctx, &back);
    lc.warnings = 0;
    CHECK(nc_image_write_exr(ctx, &img, tpath(path, "over_float.exr"), NACRE_EXR_FLOAT) == NACRE_OK);
    CHECK(lc.warnings == 0);
    CHECK(nacre_image_read(ctx, path, &back) == NACRE_OK);
    CHECK(back.pixels && px(&back, 0, 0)[0] == 1e6f);
    nacre_image_free(ctx, &back);
    free(img.pixels);
    nacre_context_destroy(ctx);
}

int main(void)
{
    if (mkdir(DIR_, 0755) != 0 && errno != EEXIST) {
        printf("cannot create %s: %s\n", DIR_, strerror(errno));
        return 1;
    }
    nacre_context *ctx = NULL;
    if (nacre_context_create(NULL, &ctx) != NACRE_OK)
        return 1;
    test_alloc(ctx);
    test_exr_float_roundtrip(ctx);
    test_exr_half_roundtrip(ctx);
    test_exr_small_sizes(ctx);
    test_exr_channels(ctx);
    test_exr_foreign(ctx);
    test_srgb8_table();
    test_png_roundtrip(ctx);
    test_png_exposure(ctx);
    test_png_alpha_and_grey(ctx);
    test_png_16bit(ctx);
    test_bad_files(ctx);
    test_jpeg(ctx);
    test_exr_huge_header(ctx);
    test_header_vs_file_size(ctx);
    test_write_failures(ctx);
    test_compare(ctx);
    test_nonfinite_and_half_range();
    test_allocation_failures();
    nacre_context_destroy(ctx);
    return TEST_MAIN_END();
}
