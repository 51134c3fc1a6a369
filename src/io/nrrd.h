/*
 * nrrd.h: the NRRD volume reader (private). nacre_volume_load_nrrd reads a file and calls
 * nc_nrrd_parse, which works on memory so tests and the fuzzer can feed it bytes directly.
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

#endif /* NACRE_NRRD_H */
