/*
 * fuzz_image.c: libFuzzer target for the image reader (nacre_image_read: PNG through libspng
 * and JPEG through stb_image with sRGB decoding, EXR through OpenEXRCore). The reader picks its
 * decoder by extension, so the input goes to a per-process temporary file named .png or .jpg
 * when it starts with that format's signature and .exr otherwise. An image that loads must have a sane shape and every pixel is read (ASan then
 * catches a buffer smaller than the shape says); a failure must leave the image empty with one
 * line of message.
 */
#include "fuzz_common.h"

/* Where the pixel sum goes, so that the loop reading every pixel is not dropped. */
volatile double fuzz_image_sink;

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char path[4096];
    fuzz_temp_path(path, sizeof(path), "image", fuzz_image_extension(data, size));
    fuzz_write_file(path, data, size);

    nacre_context *ctx = fuzz_context();
    nacre_image img;
    memset(&img, 0xA5, sizeof(img)); /* the reader must clear it, also on failure */
    nacre_result r = nacre_image_read(ctx, path, &img);
    if (r == NACRE_OK) {
        FUZZ_REQUIRE(img.width >= 1 && img.height >= 1 && (img.channels == 3 || img.channels == 4));
        FUZZ_REQUIRE(img.pixels && img.stride >= (size_t)img.width * (size_t)img.channels);
        /* Every value is read: ASan catches a buffer smaller than the shape says. */
        double sum = 0;
        for (int32_t y = 0; y < img.height; y++)
            for (size_t i = 0; i < (size_t)img.width * (size_t)img.channels; i++)
                sum += img.pixels[(size_t)y * img.stride + i];
        fuzz_image_sink = sum;
        nacre_image_free(ctx, &img);
    } else {
        FUZZ_REQUIRE(img.pixels == NULL && img.width == 0);
        fuzz_check_failure(ctx, r);
    }
    nacre_context_destroy(ctx);
    unlink(path);
    return 0;
}
