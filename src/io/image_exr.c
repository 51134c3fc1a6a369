/*
 * image_exr.c: OpenEXR through the OpenEXR 3.1 C API (OpenEXRCore). Values are linear and stored
 * unchanged (HALF rounds to nearest; magnitudes above 65504, the largest half, are clamped to it
 * and counted in a warning through the log callback). NaN and infinities are refused. Writing: one scanline part, ZIP compression, channels
 * R, G, B (+ A) for 3 (4) channels, Y (+ A) for 1 (2). Reading: part 0, scanline or tiled
 * (level 0 of a mip/rip-mapped file), HALF, FLOAT or UINT channels converted to float; R, G, B
 * and A are taken by name (a missing colour channel reads as 0), a Y-only file is copied to
 * R, G and B, other channels are ignored. The data window becomes the image; the display window
 * is ignored.
 *
 * All file access goes through our own read/write callbacks on a file descriptor, so open errors
 * are ours to report (with errno) and the writer can target the temporary file. OpenEXR's
 * messages are caught by an error handler instead of going to stderr. OpenEXR allocates its
 * internal buffers with malloc: its allocator hooks take no user pointer, so the context
 * allocator cannot reach them without global state.
 *
 * Three OpenEXR 3.1.5 bugs are worked around: a write context's error callback deadlocks on
 * exr_get_user_data (write_error_cb), ZIP chunks that do not shrink are stored corrupt
 * (compress_or_store), and some unpackers ignore or dereference NULL destination pointers
 * (decode_chunk).
 */
#include "io/image_private.h"

#include <OpenEXR/openexr.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

typedef struct exr_stream {
    int fd;
    int io_errno;      /* errno of the first failed read or write; 0 if none */
    char message[256]; /* first message OpenEXR reported (read contexts only) */
} exr_stream;

/* pread or pwrite all of [offset, offset + size), retrying interrupted calls; returns the count
 * done (short at end of file, or when a write makes no progress) or -1 with io_errno set. */
static int64_t stream_io(exr_stream *s, uint8_t *rbuf, const uint8_t *wbuf, uint64_t size, uint64_t offset)
{
    uint64_t done = 0;
    if (offset > (uint64_t)INT64_MAX - size)
        return -1;
    while (done < size) {
        uint64_t want = size - done;
        if (want > (uint64_t)SSIZE_MAX)
            want = (uint64_t)SSIZE_MAX;
        ssize_t k = rbuf ? pread(s->fd, rbuf + done, (size_t)want, (off_t)(offset + done))
                         : pwrite(s->fd, wbuf + done, (size_t)want, (off_t)(offset + done));
        if (k < 0) {
            if (errno == EINTR)
                continue;
            if (!s->io_errno)
                s->io_errno = errno;
            return -1;
        }
        if (k == 0)
            break; /* end of file: the short count tells OpenEXR the file is truncated */
        done += (uint64_t)k;
    }
    return (int64_t)done;
}

static int64_t stream_read(exr_const_context_t exr, void *user, void *buffer, uint64_t size,
                           uint64_t offset, exr_stream_error_func_ptr_t error_cb)
{
    (void)exr;
    (void)error_cb;
    return stream_io(user, buffer, NULL, size, offset);
}

static int64_t stream_size(exr_const_context_t exr, void *user)
{
    (void)exr;
    exr_stream *s = user;
    struct stat st;
    if (fstat(s->fd, &st) != 0)
        return -1;
    return (int64_t)st.st_size;
}

static int64_t stream_write(exr_const_context_t exr, void *user, const void *buffer,
                            uint64_t size, uint64_t offset, exr_stream_error_func_ptr_t error_cb)
{
    (void)exr;
    (void)error_cb;
    return stream_io(user, NULL, buffer, size, offset);
}

static void read_error_cb(exr_const_context_t exr, exr_result_t code, const char *msg)
{
    void *user = NULL;
    if (!exr || exr_get_user_data(exr, &user) != EXR_ERR_SUCCESS || !user)
        return;
    exr_stream *s = user;
    /* The first message is the most specific: later ones are callers reporting the same
     * failure in more general terms. */
    if (s->message[0])
        return;
    if (!msg)
        msg = exr_get_default_error_message(code);
    /* Messages can quote bytes of a corrupt file (a bad attribute name): keep the one-line
     * message printable and short. */
    size_t n = 0, limit = 160;
    for (; msg[n] && n < limit; n++) {
        unsigned char c = (unsigned char)msg[n];
        s->message[n] = (c >= 0x20 && c < 0x7f) ? (char)c : '?';
    }
    if (msg[n])
        memcpy(s->message + n, "...", 4);
    else
        s->message[n] = '\0';
}

/* Swallows OpenEXR's messages when writing. It cannot store them: in OpenEXR 3.1 a write context
 * reports errors while holding its (non-recursive) lock, and exr_get_user_data() takes that lock
 * again, which deadlocks. Our arguments are valid by construction, so what can fail is I/O
 * (caught in stream_write with errno) or memory, both known from the result code. */
static void write_error_cb(exr_const_context_t exr, exr_result_t code, const char *msg)
{
    (void)exr;
    (void)code;
    (void)msg;
}

static nacre_result exr_fail(nacre_context *ctx, const char *path, const exr_stream *s,
                             exr_result_t rv, const char *doing)
{
    if (rv == EXR_ERR_OUT_OF_MEMORY)
        return nc_fail(ctx, NACRE_ERROR_OUT_OF_MEMORY, "%s: out of memory %s EXR", path, doing);
    if (s->io_errno)
        return nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot %s file: %s", path,
                       strcmp(doing, "reading") == 0 ? "read" : "write", strerror(s->io_errno));
    const char *msg = s->message[0] ? s->message : exr_get_default_error_message(rv);
    if (strcmp(doing, "reading") == 0)
        return nc_fail(ctx, NACRE_ERROR_PARSE, "%s: invalid EXR: %s", path, msg);
    return nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot write EXR: %s", path, msg);
}

/* ------------------------------------------------------------------------------------------ */
/* Writing                                                                                    */
/* ------------------------------------------------------------------------------------------ */

#define NC_HALF_MAX 65504.0f /* the largest finite half */

static const char *const channel_names[4][4] = {
    {"Y"}, {"Y", "A"}, {"R", "G", "B"}, {"R", "G", "B", "A"}};

/* Slot of a channel name within a pixel of `channels` values, or -1. */
static int write_slot(const char *name, int32_t channels)
{
    for (int32_t c = 0; c < channels; c++)
        if (strcmp(name, channel_names[channels - 1][c]) == 0)
            return (int)c;
    return -1;
}

/* The library's compressor, called by compress_or_store through encoding_user_data. */
typedef struct compress_hook {
    exr_result_t (*compress)(exr_encode_pipeline_t *enc);
} compress_hook;

/* OpenEXR 3.1.5's ZIP compressor writes wrong bytes when compression does not shrink a chunk
 * (small or noisy chunks): it stores compressed_bytes == packed_bytes but not the packed data,
 * and every reader then gets garbage. The format says such a chunk is stored raw, so store the
 * packed bytes ourselves. */
static exr_result_t compress_or_store(exr_encode_pipeline_t *enc)
{
    const compress_hook *hook = enc->encoding_user_data;
    exr_result_t rv = hook->compress(enc);
    if (rv != EXR_ERR_SUCCESS || enc->compressed_bytes < enc->packed_bytes)
        return rv;
    if (enc->compressed_buffer != enc->packed_buffer) {
        if (enc->compressed_alloc_size < enc->packed_bytes)
            return EXR_ERR_OUT_OF_MEMORY;
        memcpy(enc->compressed_buffer, enc->packed_buffer, enc->packed_bytes);
    }
    enc->compressed_bytes = enc->packed_bytes;
    return EXR_ERR_SUCCESS;
}

static exr_result_t write_pixels(exr_context_t exr, const nacre_image *image)
{
    compress_hook hook = {NULL};
    int32_t lines;
    exr_result_t rv = exr_get_scanlines_per_chunk(exr, 0, &lines);
    if (rv != EXR_ERR_SUCCESS)
        return rv;
    exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
    bool first = true;
    for (int32_t y = 0; y < image->height && rv == EXR_ERR_SUCCESS; y += lines) {
        exr_chunk_info_t ci;
        rv = exr_write_scanline_chunk_info(exr, 0, y, &ci);
        if (rv != EXR_ERR_SUCCESS)
            break;
        rv = first ? exr_encoding_initialize(exr, 0, &ci, &enc)
                   : exr_encoding_update(exr, 0, &ci, &enc);
        if (rv != EXR_ERR_SUCCESS)
            break;
        first = false;
        const float *row = image->pixels + (size_t)ci.start_y * image->stride;
        for (int16_t c = 0; c < enc.channel_count; c++) {
            exr_coding_channel_info_t *ch = &enc.channels[c];
            int slot = write_slot(ch->channel_name, image->channels);
            ch->encode_from_ptr = (const uint8_t *)(row + (slot < 0 ? 0 : slot));
            ch->user_pixel_stride = image->channels * (int32_t)sizeof(float);
            ch->user_line_stride = (int32_t)(image->stride * sizeof(float));
            ch->user_bytes_per_element = (int16_t)sizeof(float);
            ch->user_data_type = EXR_PIXEL_FLOAT;
        }
        rv = exr_encoding_choose_default_routines(exr, 0, &enc);
        if (rv == EXR_ERR_SUCCESS && enc.compress_fn) {
            hook.compress = enc.compress_fn;
            enc.encoding_user_data = &hook;
            enc.compress_fn = compress_or_store;
        }
        if (rv == EXR_ERR_SUCCESS)
            rv = exr_encoding_run(exr, 0, &enc);
    }
    if (!first)
        exr_encoding_destroy(exr, &enc);
    return rv;
}

nacre_result nc_image_write_exr(nacre_context *ctx, const nacre_image *image,
                                   const char *path, nacre_exr_pixel type)
{
    nacre_result r = nc_image_write_check(ctx, image, path);
    if (r != NACRE_OK)
        return r;
    if (type != NACRE_EXR_HALF && type != NACRE_EXR_FLOAT)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: unknown EXR pixel type %d",
                       path, (int)type);
    /* OpenEXR takes the row pitch in bytes as an int32. */
    if (image->stride > (size_t)INT32_MAX / sizeof(float))
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "%s: image stride %zu is too large for the EXR writer", path,
                       image->stride);

    /* No file ever holds NaN or infinity: they are a renderer's failure, not an image. */
    int32_t bx = 0, by = 0, bc = 0;
    uint64_t nonfinite = nacre_image_count_nonfinite(image, &bx, &by, &bc);
    if (nonfinite > 0) {
        float v = image->pixels[(size_t)by * image->stride + (size_t)bx * (size_t)image->channels + (size_t)bc];
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT,
                       "%s: pixel (%d, %d) channel %s is %s (%llu pixel%s not finite): not written", path, (int)bx,
                       (int)by, channel_names[image->channels - 1][bc], isnan(v) ? "NaN" : v > 0 ? "+Inf" : "-Inf",
                       (unsigned long long)nonfinite, nonfinite == 1 ? "" : "s");
    }
    /* Half holds magnitudes up to 65504; OpenEXR would turn larger ones into infinities. They
     * are clamped to +-65504 in a copy instead, and the count goes to the log as a warning. */
    nacre_image src = *image;
    float *clamped = NULL;
    uint64_t over = 0;
    if (type == NACRE_EXR_HALF) {
        const size_t row_values = (size_t)image->width * (size_t)image->channels;
        for (int32_t y = 0; y < image->height; y++) {
            const float *row = image->pixels + (size_t)y * image->stride;
            for (size_t i = 0; i < row_values; i++)
                over += fabsf(row[i]) > NC_HALF_MAX;
        }
        if (over > 0) {
            clamped = nc_calloc(ctx, row_values, (size_t)image->height * sizeof(float));
            if (!clamped)
                return NACRE_ERROR_OUT_OF_MEMORY;
            for (int32_t y = 0; y < image->height; y++) {
                const float *row = image->pixels + (size_t)y * image->stride;
                float *out = clamped + (size_t)y * row_values;
                for (size_t i = 0; i < row_values; i++)
                    out[i] = fminf(fmaxf(row[i], -NC_HALF_MAX), NC_HALF_MAX);
            }
            src.pixels = clamped;
            src.stride = row_values;
        }
    }
    image = &src;

    nc_tmpfile tmp;
    r = nc_tmpfile_open(ctx, path, &tmp);
    if (r != NACRE_OK) {
        nc_free(ctx, clamped);
        return r;
    }
    exr_stream s = {tmp.fd, 0, ""};
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    init.error_handler_fn = write_error_cb;
    init.user_data = &s;
    init.write_fn = stream_write;
    exr_context_t exr = NULL;
    exr_result_t rv = exr_start_write(&exr, tmp.tmp_path, EXR_WRITE_FILE_DIRECTLY, &init);
    int part = 0;
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_add_part(exr, NULL, EXR_STORAGE_SCANLINE, &part);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_initialize_required_attr_simple(exr, part, image->width, image->height,
                                                 EXR_COMPRESSION_ZIP);
    exr_pixel_type_t ptype = type == NACRE_EXR_HALF ? EXR_PIXEL_HALF : EXR_PIXEL_FLOAT;
    for (int32_t c = 0; c < image->channels && rv == EXR_ERR_SUCCESS; c++)
        rv = exr_add_channel(exr, part, channel_names[image->channels - 1][c], ptype,
                             EXR_PERCEPTUALLY_LOGARITHMIC, 1, 1);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_write_header(exr);
    if (rv == EXR_ERR_SUCCESS)
        rv = write_pixels(exr, image);
    /* exr_finish writes the chunk offset table, so its result matters too. */
    if (exr) {
        exr_result_t frv = exr_finish(&exr);
        if (rv == EXR_ERR_SUCCESS)
            rv = frv;
    }
    nc_free(ctx, clamped);
    if (rv != EXR_ERR_SUCCESS) {
        r = exr_fail(ctx, path, &s, rv, "writing");
        nc_tmpfile_abort(ctx, &tmp);
        return r;
    }
    r = nc_tmpfile_commit(ctx, &tmp);
    if (r == NACRE_OK && over > 0)
        nc_warn(ctx, "%s: %llu value%s beyond the half range clamped to +-65504; a float EXR keeps them",
                path, (unsigned long long)over, over == 1 ? "" : "s");
    return r;
}

/* ------------------------------------------------------------------------------------------ */
/* Reading                                                                                    */
/* ------------------------------------------------------------------------------------------ */

enum { SLOT_R, SLOT_G, SLOT_B, SLOT_A, SLOT_Y, SLOT_COUNT };
static const char *const slot_names[SLOT_COUNT] = {"R", "G", "B", "A", "Y"};

typedef struct exr_layout {
    int file_channel[SLOT_COUNT]; /* index in the channel list, or -1 */
    bool luminance;               /* Y only: decode Y into R, then copy */
    int32_t min_x, min_y;         /* data window origin */
} exr_layout;

/* Where a decoded channel goes within an output pixel, or -1 to skip it. */
static int read_slot(const exr_layout *lay, const char *name)
{
    for (int s = 0; s < SLOT_COUNT; s++) {
        if (lay->file_channel[s] < 0 || strcmp(name, slot_names[s]) != 0)
            continue;
        if (s == SLOT_Y)
            return lay->luminance ? SLOT_R : -1;
        return s;
    }
    return -1;
}

/* One decoding pass over the chunks of part 0. */
typedef struct exr_decoder {
    nacre_context *ctx;
    exr_context_t exr;
    const exr_layout *lay;
    nacre_image *out;
    exr_decode_pipeline_t pipe;
    bool started;  /* pipe initialized (needs exr_decoding_destroy) */
    float *planes; /* the current chunk as float planes (see decode_chunk) */
    size_t planes_count;
} exr_decoder;

/* Decode one chunk whose top-left pixel is (x0, y0) in the output image.
 *
 * Each channel we keep is decoded into its own plane and then interleaved into the image; the
 * channels we drop all share one more plane. Decoding straight into the interleaved image would
 * save a copy, but OpenEXR 3.1.5's specialised unpackers get that layout wrong: with 4 HALF
 * channels they write them in file order (A, B, G, R) whatever the destination pointers say,
 * and with 3 or 4 HALF channels they write through the NULL pointer of a skipped channel.
 * Separate planes for every channel is the layout its own tests use. */
static exr_result_t decode_chunk(exr_decoder *d, const exr_chunk_info_t *ci, int64_t x0,
                                 int64_t y0)
{
    nacre_image *out = d->out;
    /* A corrupt file must not make us write outside the image. */
    if (x0 < 0 || y0 < 0 || ci->width < 1 || ci->height < 1 || x0 + ci->width > out->width ||
        y0 + ci->height > out->height)
        return EXR_ERR_CORRUPT_CHUNK;
    exr_result_t rv = d->started ? exr_decoding_update(d->exr, 0, ci, &d->pipe)
                                 : exr_decoding_initialize(d->exr, 0, ci, &d->pipe);
    if (rv != EXR_ERR_SUCCESS)
        return rv;
    d->started = true;

    /* Planes 0..3 for R, G, B, A (the slots), plane 4 for everything dropped. */
    enum { DROP = 4, PLANES = 5 };
    size_t plane = (size_t)ci->width * (size_t)ci->height;
    if (plane * PLANES > d->planes_count) {
        nc_free(d->ctx, d->planes);
        d->planes_count = 0;
        d->planes = nc_calloc(d->ctx, plane, PLANES * sizeof(float));
        if (!d->planes)
            return EXR_ERR_OUT_OF_MEMORY;
        d->planes_count = plane * PLANES;
    }
    for (int16_t c = 0; c < d->pipe.channel_count; c++) {
        exr_coding_channel_info_t *ch = &d->pipe.channels[c];
        int slot = read_slot(d->lay, ch->channel_name);
        /* Subsampled channels (always dropped) have fewer pixels than a plane holds. */
        ch->decode_to_ptr = (uint8_t *)(d->planes + (size_t)(slot < 0 ? DROP : slot) * plane);
        ch->user_pixel_stride = (int32_t)sizeof(float);
        ch->user_line_stride = ch->width * (int32_t)sizeof(float);
        ch->user_bytes_per_element = (int16_t)sizeof(float);
        ch->user_data_type = EXR_PIXEL_FLOAT;
    }
    rv = exr_decoding_choose_default_routines(d->exr, 0, &d->pipe);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_decoding_run(d->exr, 0, &d->pipe);
    if (rv != EXR_ERR_SUCCESS)
        return rv;

    for (int16_t c = 0; c < d->pipe.channel_count; c++) {
        int slot = read_slot(d->lay, d->pipe.channels[c].channel_name);
        if (slot < 0)
            continue;
        const float *src = d->planes + (size_t)slot * plane;
        for (int32_t y = 0; y < ci->height; y++) {
            float *dst = out->pixels + (size_t)(y0 + y) * out->stride +
                         (size_t)x0 * (size_t)out->channels + (size_t)slot;
            for (int32_t x = 0; x < ci->width; x++, dst += out->channels)
                *dst = *src++;
        }
    }
    return EXR_ERR_SUCCESS;
}

static exr_result_t read_scanlines(exr_decoder *d)
{
    int32_t lines;
    exr_result_t rv = exr_get_scanlines_per_chunk(d->exr, 0, &lines);
    if (rv != EXR_ERR_SUCCESS)
        return rv;
    if (lines < 1)
        return EXR_ERR_INVALID_ATTR;
    for (int64_t y = 0; y < d->out->height && rv == EXR_ERR_SUCCESS; y += lines) {
        exr_chunk_info_t ci;
        rv = exr_read_scanline_chunk_info(d->exr, 0, (int)(d->lay->min_y + y), &ci);
        if (rv == EXR_ERR_SUCCESS)
            rv = decode_chunk(d, &ci, (int64_t)ci.start_x - d->lay->min_x,
                              (int64_t)ci.start_y - d->lay->min_y);
    }
    return rv;
}

static exr_result_t read_tiles(exr_decoder *d)
{
    int32_t tw, th;
    exr_result_t rv = exr_get_tile_sizes(d->exr, 0, 0, 0, &tw, &th);
    if (rv != EXR_ERR_SUCCESS)
        return rv;
    if (tw < 1 || th < 1)
        return EXR_ERR_INVALID_ATTR;
    int64_t nx = ((int64_t)d->out->width + tw - 1) / tw;
    int64_t ny = ((int64_t)d->out->height + th - 1) / th;
    for (int64_t ty = 0; ty < ny && rv == EXR_ERR_SUCCESS; ty++) {
        for (int64_t tx = 0; tx < nx && rv == EXR_ERR_SUCCESS; tx++) {
            exr_chunk_info_t ci;
            rv = exr_read_tile_chunk_info(d->exr, 0, (int)tx, (int)ty, 0, 0, &ci);
            if (rv == EXR_ERR_SUCCESS)
                rv = decode_chunk(d, &ci, tx * tw, ty * th);
        }
    }
    return rv;
}

/* Find the channels we read and check they are full resolution. */
static nacre_result read_layout(nacre_context *ctx, const char *path, exr_context_t exr,
                                exr_stream *s, exr_layout *lay)
{
    const exr_attr_chlist_t *chlist = NULL;
    exr_result_t rv = exr_get_channels(exr, 0, &chlist);
    if (rv != EXR_ERR_SUCCESS || !chlist)
        return exr_fail(ctx, path, s, rv != EXR_ERR_SUCCESS ? rv : EXR_ERR_MISSING_REQ_ATTR,
                        "reading");
    for (int k = 0; k < SLOT_COUNT; k++)
        lay->file_channel[k] = -1;
    for (int i = 0; i < chlist->num_channels; i++) {
        const char *name = chlist->entries[i].name.str;
        for (int k = 0; name && k < SLOT_COUNT; k++)
            if (strcmp(name, slot_names[k]) == 0)
                lay->file_channel[k] = i;
    }
    bool colour = lay->file_channel[SLOT_R] >= 0 || lay->file_channel[SLOT_G] >= 0 ||
                  lay->file_channel[SLOT_B] >= 0;
    lay->luminance = !colour && lay->file_channel[SLOT_Y] >= 0;
    if (!colour && !lay->luminance)
        return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED,
                       "%s: EXR has no R, G, B or Y channel in its first part", path);
    if (!lay->luminance)
        lay->file_channel[SLOT_Y] = -1; /* Y beside colour is ignored */
    for (int k = 0; k < SLOT_COUNT; k++) {
        if (lay->file_channel[k] < 0)
            continue;
        const exr_attr_chlist_entry_t *e = &chlist->entries[lay->file_channel[k]];
        if (e->x_sampling != 1 || e->y_sampling != 1)
            return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED,
                           "%s: EXR channel %s is subsampled (%dx%d); not supported", path,
                           slot_names[k], (int)e->x_sampling, (int)e->y_sampling);
    }
    return NACRE_OK;
}

nacre_result nc_image_read_exr(nacre_context *ctx, const char *path, nacre_image *out)
{
    exr_stream s = {-1, 0, ""};
    s.fd = open(path, O_RDONLY | O_CLOEXEC);
    if (s.fd < 0)
        return nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot open: %s", path, strerror(errno));
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    init.error_handler_fn = read_error_cb;
    init.user_data = &s;
    init.read_fn = stream_read;
    init.size_fn = stream_size;
    init.max_image_width = NC_IMAGE_MAX_SIDE;
    init.max_image_height = NC_IMAGE_MAX_SIDE;

    nacre_result r = NACRE_OK;
    exr_context_t exr = NULL;
    exr_result_t rv = exr_start_read(&exr, path, &init);
    exr_storage_t storage = EXR_STORAGE_SCANLINE;
    exr_attr_box2i_t dw;
    memset(&dw, 0, sizeof(dw));
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_get_storage(exr, 0, &storage);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_get_data_window(exr, 0, &dw);
    if (rv != EXR_ERR_SUCCESS) {
        r = exr_fail(ctx, path, &s, rv, "reading");
        goto out_finish;
    }
    if (storage != EXR_STORAGE_SCANLINE && storage != EXR_STORAGE_TILED) {
        r = nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "%s: deep EXR images are not supported",
                    path);
        goto out_finish;
    }
    {
        /* A pixel holds at least one half channel. Uncompressed data is stored as is; RLE
         * (count + byte) expands at most 64:1; every other codec is bounded here by 4096:1
         * (deflate's own limit is ~1032:1, and the lossy ones are coarser). */
        exr_compression_t comp = EXR_COMPRESSION_ZIP;
        (void)exr_get_compression(exr, 0, &comp);
        double ratio = comp == EXR_COMPRESSION_NONE ? 1.0 : comp == EXR_COMPRESSION_RLE ? 64.0 : 4096.0;
        r = nc_image_check_file_size(ctx, path, (int64_t)dw.max.x - dw.min.x + 1, (int64_t)dw.max.y - dw.min.y + 1,
                                     stream_size(exr, &s), 16.0, ratio);
    }
    if (r != NACRE_OK)
        goto out_finish;
    exr_layout lay;
    r = read_layout(ctx, path, exr, &s, &lay);
    if (r != NACRE_OK)
        goto out_finish;
    lay.min_x = dw.min.x;
    lay.min_y = dw.min.y;

    int32_t channels = lay.file_channel[SLOT_A] >= 0 ? 4 : 3;
    r = nacre_image_alloc(ctx, dw.max.x - dw.min.x + 1, dw.max.y - dw.min.y + 1, channels,
                          out);
    if (r != NACRE_OK)
        goto out_finish;
    exr_decoder d;
    memset(&d, 0, sizeof(d));
    d.ctx = ctx;
    d.exr = exr;
    d.lay = &lay;
    d.out = out;
    rv = storage == EXR_STORAGE_TILED ? read_tiles(&d) : read_scanlines(&d);
    if (d.started)
        exr_decoding_destroy(exr, &d.pipe);
    nc_free(ctx, d.planes);
    if (rv != EXR_ERR_SUCCESS) {
        r = exr_fail(ctx, path, &s, rv, "reading");
        nacre_image_free(ctx, out);
        goto out_finish;
    }
    if (lay.luminance) {
        for (int32_t y = 0; y < out->height; y++) {
            float *p = out->pixels + (size_t)y * out->stride;
            for (int32_t x = 0; x < out->width; x++, p += channels)
                p[1] = p[2] = p[0];
        }
    }

out_finish:
    if (exr)
        exr_finish(&exr);
    close(s.fd);
    return r;
}
