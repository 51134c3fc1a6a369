/*
 * nrrd.h: NRRD volumes (private). The reader: nacre_volume_load_nrrd reads a file and calls
 * nc_nrrd_parse, which works on memory so tests and the fuzzer can feed it bytes directly. The
 * writers: nc_nrrd_write_u8, used by the voxelizer's export, and nc_nrrd_write_f32, used by the
 * scene writer for volumes that have no file.
 */
#ifndef NACRE_NRRD_H
#define NACRE_NRRD_H

#include "core/core.h"

/* Largest file nacre_volume_load_nrrd reads (header + raw data). */
#define NC_NRRD_FILE_MAX ((size_t)1 << 33)
/* Largest number of samples (all channels) a volume may hold. */
#define NC_NRRD_SAMPLES_MAX ((uint64_t)1 << 31)

/* Parse an attached-data NRRD held in `bytes` (not NUL terminated). `name` is used in messages
 * ("name: line N: field: problem"). On success out->data is allocated with the context's
 * allocator (nacre_volume_data_free). On failure *out is zeroed and one error is recorded. */
nacre_result nc_nrrd_parse(nacre_context *ctx, const char *name, const uint8_t *bytes, size_t length,
                           uint32_t channel, nacre_volume_data *out);

/* Fills `row` with the `channels` x dims[0] interleaved bytes of row (y, z) of the volume. */
typedef void (*nc_nrrd_row_fn)(void *user, uint32_t y, uint32_t z, uint8_t *row);

/* Write a raw uint8 NRRD of `channels` interleaved channels (a 4-D file with a vector axis first
 * when channels > 1) on a dims grid of cubic cells of side `spacing`, the first sample centred at
 * `origin`. `comment` goes in a "#" line. Written under a temporary name and renamed into place:
 * a failure leaves nothing at `path`. */
nacre_result nc_nrrd_write_u8(nacre_context *ctx, const char *path, const char *comment, uint32_t channels,
                              const uint32_t dims[3], double spacing, const double origin[3], nc_nrrd_row_fn row_fn,
                              void *user);

/* Write a raw little-endian float NRRD of one channel: sample (i, j, k) at origin + (i, j, k) *
 * spacing (nacre_volume_data's placement), values printed so that reading the file back gives
 * the same floats bit for bit. Temporary name and rename, as nc_nrrd_write_u8. */
nacre_result nc_nrrd_write_f32(nacre_context *ctx, const char *path, const char *comment, const uint32_t dims[3],
                               const float spacing[3], const float origin[3], const float *data);

#endif /* NACRE_NRRD_H */
