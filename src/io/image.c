/*
 * image.c: float images: allocation, the read/write entry points that dispatch on the file
 * extension, the temporary-file writer shared by the PNG and EXR writers, and image comparison.
 *
 * Conventions: pixels are linear floats, `channels` interleaved, rows `stride` floats apart, top
 * row first. Writers never leave a partial file: they write "<path>.tmpXXXXXX" in the same
 * folder and rename() it over <path> only once everything succeeded (rename within one folder is
 * atomic on POSIX file systems).
 */
#include "io/image_private.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

nacre_result nacre_image_alloc(nacre_context *ctx, int32_t width, int32_t height,
                               int32_t channels, nacre_image *out)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!out)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "image: output image is NULL");
    memset(out, 0, sizeof(*out));
    if (width < 1 || width > NC_IMAGE_MAX_SIDE || height < 1 || height > NC_IMAGE_MAX_SIDE)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "image: size %dx%d out of range (1..%d per side)", (int)width,
                       (int)height, NC_IMAGE_MAX_SIDE);
    if (channels < 1 || channels > 4)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "image: %d channels out of range (1..4)", (int)channels);
    size_t stride, count;
    if (!nc_mul_size_ok((size_t)width, (size_t)channels, &stride) ||
        !nc_mul_size_ok(stride, (size_t)height, &count))
        return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "image: %dx%dx%d overflows size_t",
                       (int)width, (int)height, (int)channels);
    float *pixels = nc_calloc(ctx, count, sizeof(float));
    if (!pixels)
        return NACRE_ERROR_OUT_OF_MEMORY;
    out->width = width;
    out->height = height;
    out->channels = channels;
    out->stride = stride;
    out->pixels = pixels;
    return NACRE_OK;
}

void nacre_image_free(nacre_context *ctx, nacre_image *image)
{
    if (!ctx || !image)
        return;
    nc_free(ctx, image->pixels);
    memset(image, 0, sizeof(*image));
}

nacre_result nc_image_write_check(nacre_context *ctx, const nacre_image *image, const char *path)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!path)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "image write: path is NULL");
    return nc_image_check(ctx, image, path);
}

nacre_result nc_image_check(nacre_context *ctx, const nacre_image *image, const char *what)
{
    if (!image)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: image is NULL", what);
    if (image->width < 1 || image->width > NC_IMAGE_MAX_SIDE || image->height < 1 ||
        image->height > NC_IMAGE_MAX_SIDE)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "%s: image size %dx%d out of range (1..%d per side)", what,
                       (int)image->width, (int)image->height, NC_IMAGE_MAX_SIDE);
    if (image->channels < 1 || image->channels > 4)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "%s: image has %d channels (1..4 supported)", what, (int)image->channels);
    if (image->stride < (size_t)image->width * (size_t)image->channels)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "%s: image stride %zu is less than width x channels (%d x %d)", what,
                       image->stride, (int)image->width, (int)image->channels);
    size_t last_row;
    if (!nc_mul_size_ok(image->stride, (size_t)image->height - 1, &last_row) ||
        last_row > SIZE_MAX / sizeof(float) - (size_t)image->width * (size_t)image->channels)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: image stride %zu is too large",
                       what, image->stride);
    if (!image->pixels)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: image pixels are NULL", what);
    return NACRE_OK;
}

uint64_t nacre_image_count_nonfinite(const nacre_image *image, int32_t *x, int32_t *y, int32_t *c)
{
    if (!image || !image->pixels)
        return 0;
    uint64_t count = 0;
    const int32_t nc = image->channels;
    for (int32_t j = 0; j < image->height; j++) {
        const float *row = image->pixels + (size_t)j * image->stride;
        for (int32_t i = 0; i < image->width; i++) {
            int32_t bad = -1;
            for (int32_t k = nc - 1; k >= 0; k--)
                if (!isfinite(row[(size_t)i * (size_t)nc + (size_t)k]))
                    bad = k;
            if (bad < 0)
                continue;
            if (count++ == 0) {
                if (x)
                    *x = i;
                if (y)
                    *y = j;
                if (c)
                    *c = bad;
            }
        }
    }
    return count;
}

nacre_result nc_image_check_file_size(nacre_context *ctx, const char *path, int64_t width, int64_t height,
                                      int64_t file_size, double min_bits, double max_ratio)
{
    if (width < 1 || height < 1 || width > NC_IMAGE_MAX_SIDE || height > NC_IMAGE_MAX_SIDE ||
        (uint64_t)width * (uint64_t)height > NC_IMAGE_MAX_PIXELS)
        return nc_fail(ctx, NACRE_ERROR_PARSE,
                       "%s: image size %lldx%lld out of range (1..%d per side, at most %llu "
                       "pixels)",
                       path, (long long)width, (long long)height, NC_IMAGE_MAX_SIDE,
                       (unsigned long long)NC_IMAGE_MAX_PIXELS);
    double least = (double)width * (double)height * min_bits / 8.0;
    if (file_size >= 0 && least > (double)file_size * max_ratio + 4096.0)
        return nc_fail(ctx, NACRE_ERROR_PARSE,
                       "%s: header says %lldx%lld pixels, more than its %lld bytes can hold (truncated or "
                       "corrupt file)",
                       path, (long long)width, (long long)height, (long long)file_size);
    char what[1100];
    snprintf(what, sizeof(what), "%s: image %lldx%lld", path, (long long)width, (long long)height);
    return nc_memory_check(ctx, (uint64_t)width * (uint64_t)height * 4 * sizeof(float), what);
}

/* ------------------------------------------------------------------------------------------ */
/* Dispatch by extension                                                                      */
/* ------------------------------------------------------------------------------------------ */

typedef enum image_format { FORMAT_UNKNOWN, FORMAT_PNG, FORMAT_EXR, FORMAT_JPEG } image_format;

/* ASCII-only, so the locale cannot change what counts as ".PNG". */
static bool ext_equal(const char *ext, const char *lower)
{
    for (; *ext && *lower; ext++, lower++) {
        char c = *ext;
        if (c >= 'A' && c <= 'Z')
            c = (char)(c - 'A' + 'a');
        if (c != *lower)
            return false;
    }
    return *ext == '\0' && *lower == '\0';
}

static image_format format_of(const char *path)
{
    const char *slash = strrchr(path, '/');
    const char *base = slash ? slash + 1 : path;
    const char *dot = strrchr(base, '.');
    if (!dot)
        return FORMAT_UNKNOWN;
    if (ext_equal(dot + 1, "png"))
        return FORMAT_PNG;
    if (ext_equal(dot + 1, "exr"))
        return FORMAT_EXR;
    if (ext_equal(dot + 1, "jpg") || ext_equal(dot + 1, "jpeg"))
        return FORMAT_JPEG;
    return FORMAT_UNKNOWN;
}

nacre_result nacre_image_write(nacre_context *ctx, const nacre_image *image, const char *path,
                               const nacre_image_write_options *options)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!path)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "image write: path is NULL");
    nacre_image_write_options opt = {0.0f, NACRE_EXR_HALF};
    if (options)
        opt = *options;
    switch (format_of(path)) {
    case FORMAT_PNG:
        return nc_image_write_png(ctx, image, path, opt.exposure);
    case FORMAT_EXR:
        return nc_image_write_exr(ctx, image, path, opt.exr_type);
    case FORMAT_JPEG:
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: nacre reads JPEG but writes PNG or EXR", path);
    case FORMAT_UNKNOWN:
        break;
    }
    return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                   "%s: unknown image extension (use .png or .exr)", path);
}

static nacre_result image_read(nacre_context *ctx, const char *path, bool srgb, nacre_image *out)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!out)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "image read: output image is NULL");
    memset(out, 0, sizeof(*out));
    if (!path)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "image read: path is NULL");
    switch (format_of(path)) {
    case FORMAT_PNG:
        return nc_image_read_png(ctx, path, srgb, out);
    case FORMAT_EXR:
        return nc_image_read_exr(ctx, path, out);
    case FORMAT_JPEG:
        return nc_image_read_jpeg(ctx, path, srgb, out);
    case FORMAT_UNKNOWN:
        break;
    }
    return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                   "%s: unknown image extension (use .png, .exr, .jpg or .jpeg)", path);
}

nacre_result nacre_image_read(nacre_context *ctx, const char *path, nacre_image *out)
{
    return image_read(ctx, path, true, out);
}

nacre_result nacre_image_read_data(nacre_context *ctx, const char *path, nacre_image *out)
{
    return image_read(ctx, path, false, out);
}

/* ------------------------------------------------------------------------------------------ */
/* Comparison                                                                                 */
/* ------------------------------------------------------------------------------------------ */

static int cmp_float(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

/* The lit-pixel measures of nacre_image_metrics (3-channel images). Percentiles by sorting: the
 * nearest rank, so that the result is exact and independent of anything but the pixels. */
static nacre_result lit_metrics(nacre_context *ctx, const nacre_image *test, const nacre_image *reference,
                                nacre_image_metrics *out)
{
    if (test->channels != 3)
        return NACRE_OK;
    const int32_t w = test->width, h = test->height;
    size_t n = 0;
    for (int32_t y = 0; y < h; y++)
        for (int32_t x = 0; x < w; x++) {
            const float *a = test->pixels + (size_t)y * test->stride + 3 * (size_t)x;
            const float *b = reference->pixels + (size_t)y * reference->stride + 3 * (size_t)x;
            float sb = b[0] + b[1] + b[2], sa = a[0] + a[1] + a[2];
            n += isfinite(sa) && isfinite(sb) && sb > 0.0f;
        }
    if (n == 0)
        return NACRE_OK;
    /* lum: per lit pixel, the reference's R + G + B averaged over its lit 3x3 neighbours. The
     * darkest quarter is chosen by it, not by the pixel's own value: a noisy (path-traced)
     * reference would otherwise select the pixels its noise made dark, which biases the ratio
     * there upwards (by 10-15% at ~500 samples per pixel). */
    float *lum = nc_alloc(ctx, (2 * n + (size_t)w * (size_t)h) * sizeof(float));
    if (!lum)
        return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "image compare: out of memory");
    float *err = lum + n, *smooth = err + n;
    for (int32_t y = 0; y < h; y++)
        for (int32_t x = 0; x < w; x++) {
            double sum = 0.0;
            int cnt = 0;
            for (int32_t dy = -1; dy <= 1; dy++)
                for (int32_t dx = -1; dx <= 1; dx++) {
                    int32_t xx = x + dx, yy = y + dy;
                    if (xx < 0 || yy < 0 || xx >= w || yy >= h)
                        continue;
                    const float *b = reference->pixels + (size_t)yy * reference->stride + 3 * (size_t)xx;
                    float sb = b[0] + b[1] + b[2];
                    if (isfinite(sb) && sb > 0.0f) {
                        sum += sb;
                        cnt++;
                    }
                }
            smooth[(size_t)y * (size_t)w + (size_t)x] = cnt ? (float)(sum / cnt) : 0.0f;
        }
    size_t k = 0;
    for (int32_t y = 0; y < h; y++)
        for (int32_t x = 0; x < w; x++) {
            const float *a = test->pixels + (size_t)y * test->stride + 3 * (size_t)x;
            const float *b = reference->pixels + (size_t)y * reference->stride + 3 * (size_t)x;
            float sb = b[0] + b[1] + b[2], sa = a[0] + a[1] + a[2];
            if (!(isfinite(sa) && isfinite(sb) && sb > 0.0f))
                continue;
            lum[k] = smooth[(size_t)y * (size_t)w + (size_t)x];
            err[k++] = fabsf(sa - sb) / sb;
        }
    qsort(err, n, sizeof(float), cmp_float);
    out->lit_rel_err_median = err[(n - 1) / 2];
    out->lit_rel_err_p90 = err[(size_t)(0.9 * (double)(n - 1) + 0.5)];
    qsort(lum, n, sizeof(float), cmp_float);
    const float quarter = lum[n / 4];
    double sa[3] = {0, 0, 0}, sb[3] = {0, 0, 0}, da[3] = {0, 0, 0}, db[3] = {0, 0, 0};
    for (int32_t y = 0; y < h; y++)
        for (int32_t x = 0; x < w; x++) {
            const float *a = test->pixels + (size_t)y * test->stride + 3 * (size_t)x;
            const float *b = reference->pixels + (size_t)y * reference->stride + 3 * (size_t)x;
            float lb = b[0] + b[1] + b[2], la = a[0] + a[1] + a[2];
            if (!(isfinite(la) && isfinite(lb) && lb > 0.0f))
                continue;
            const bool dark = smooth[(size_t)y * (size_t)w + (size_t)x] <= quarter;
            for (int c = 0; c < 3; c++) {
                sa[c] += a[c];
                sb[c] += b[c];
                if (dark) {
                    da[c] += a[c];
                    db[c] += b[c];
                }
            }
        }
    nc_free(ctx, lum);
    out->lit_pixels = n;
    for (int c = 0; c < 3; c++) {
        out->lit_ratio[c] = sb[c] > 0.0 ? sa[c] / sb[c] : 0.0;
        out->dark_ratio[c] = db[c] > 0.0 ? da[c] / db[c] : 0.0;
    }
    return NACRE_OK;
}

nacre_result nacre_image_compare(nacre_context *ctx, const nacre_image *test,
                                 const nacre_image *reference, nacre_image_metrics *out)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!out)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "image compare: metrics are NULL");
    memset(out, 0, sizeof(*out));
    nacre_result r = nc_image_check(ctx, test, "image compare: test");
    if (r != NACRE_OK)
        return r;
    r = nc_image_check(ctx, reference, "image compare: reference");
    if (r != NACRE_OK)
        return r;
    if (test->width != reference->width || test->height != reference->height ||
        test->channels != reference->channels)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "image compare: size mismatch: test is %dx%d with %d channels, "
                       "reference is %dx%d with %d channels",
                       (int)test->width, (int)test->height, (int)test->channels,
                       (int)reference->width, (int)reference->height,
                       (int)reference->channels);

    /* Serial on purpose: a fixed summation order makes the metrics reproducible bit for bit,
     * whatever the thread count. Double accumulators keep 2^28-term sums accurate enough. */
    size_t row_values = (size_t)test->width * (size_t)test->channels;
    double sum_sq = 0.0, sum_rel_sq = 0.0, sum_rel = 0.0, max_abs = 0.0;
    double peak = -INFINITY;
    uint64_t nonzero = 0, skipped = 0;
    int32_t fx, fy, fc;
    out->nonfinite_test = nacre_image_count_nonfinite(test, &fx, &fy, &fc);
    out->nonfinite_ref = nacre_image_count_nonfinite(reference, &fx, &fy, &fc);
    for (int32_t y = 0; y < test->height; y++) {
        const float *a = test->pixels + (size_t)y * test->stride;
        const float *b = reference->pixels + (size_t)y * reference->stride;
        for (size_t i = 0; i < row_values; i++) {
            /* A NaN would poison every sum and drop out of the maxima unseen. */
            if (!isfinite(a[i]) || !isfinite(b[i])) {
                skipped++;
                continue;
            }
            double bv = b[i];
            double d = (double)a[i] - bv;
            double ad = fabs(d);
            sum_sq += d * d;
            sum_rel_sq += d * d / (bv * bv + 1e-2);
            if (bv != 0.0) {
                sum_rel += ad / fabs(bv);
                nonzero++;
            }
            if (ad > max_abs)
                max_abs = ad;
            if (bv > peak)
                peak = bv;
        }
    }
    uint64_t count = (uint64_t)row_values * (uint64_t)test->height - skipped;
    double mse = count ? sum_sq / (double)count : 0.0;
    if (!(peak > 0.0))
        peak = 1.0;
    out->rmse = sqrt(mse);
    out->rel_mse = count ? sum_rel_sq / (double)count : 0.0;
    out->psnr = mse == 0.0 ? INFINITY : 10.0 * log10(peak * peak / mse);
    out->mean_rel_err = nonzero ? sum_rel / (double)nonzero : 0.0;
    out->max_abs_err = max_abs;
    out->count = count;
    out->nonzero_ref = nonzero;
    return lit_metrics(ctx, test, reference, out);
}

nacre_result nacre_image_write_data(nacre_context *ctx, const nacre_image *image, const char *path)
{
    if (!ctx)
        return NACRE_ERROR_INVALID_ARGUMENT;
    if (!path)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "image write: path is NULL");
    if (format_of(path) == FORMAT_PNG)
        return nc_image_write_png_ex(ctx, image, path, 0.0f, true);
    const nacre_image_write_options opt = {0.0f, NACRE_EXR_FLOAT};
    return nacre_image_write(ctx, image, path, &opt);
}
