/*
 * vdb.c: nacre_volume_load_vdb, the C side of OpenVDB volumes (io/vdb.h). OpenVDB itself is
 * reached only through nc_vdb_read (vdb_read.cpp); this file gives it the context's allocator,
 * checks the memory limit before the dense copy is made, checks
 * the values (densities finite and >= 0, as NRRD volumes) and words the errors
 * ("file: grid 'name': problem"). Built without OpenVDB (NACRE_HAVE_OPENVDB unset), loading a
 * .vdb file fails with NACRE_ERROR_UNSUPPORTED and says so.
 *
 * Placement is the file's: sample (i, j, k) of the result is voxel index_min + (i, j, k) at
 * world position origin + (i, j, k) * spacing, in the file's world units taken as scene units.
 */
#include "io/vdb.h"
#include "core/core.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

typedef struct load_state {
    nacre_context *ctx;
    const char *path;
    float *data; /* owned until handed to the caller */
    size_t count;
} load_state;

static nacre_result check_memory(void *user, const nc_vdb_grid_info *info)
{
    load_state *st = user;
    /* The dense floats. The sparse tree OpenVDB read is held outside the context's allocator
     * and freed when the load returns. */
    uint64_t samples = (uint64_t)info->dims[0] * info->dims[1] * info->dims[2];
    if (samples > ((uint64_t)1 << 31))
        return nc_fail(st->ctx, NACRE_ERROR_UNSUPPORTED,
                       "%s: grid '%s': %ux%ux%u samples (active bounding box + 1 voxel), over 2^31", st->path,
                       info->name, info->dims[0], info->dims[1], info->dims[2]);
    char what[NC_VDB_NAME_MAX + 256];
    snprintf(what, sizeof(what), "%s: grid '%s' densified to %ux%ux%u", st->path, info->name, info->dims[0],
             info->dims[1], info->dims[2]);
    return nc_memory_check(st->ctx, samples * sizeof(float), what);
}

static nacre_result alloc_dense(void *user, const nc_vdb_grid_info *info, float **out)
{
    load_state *st = user;
    st->count = (size_t)info->dims[0] * info->dims[1] * info->dims[2];
    st->data = nc_alloc(st->ctx, st->count * sizeof(float));
    *out = st->data;
    return st->data ? NACRE_OK : NACRE_ERROR_OUT_OF_MEMORY;
}

#ifdef NACRE_HAVE_OPENVDB
static bool built_with_openvdb(void) { return nc_vdb_available() != 0; }
#else
static bool built_with_openvdb(void) { return false; }

/* Never called: nacre_volume_load_vdb stops first. Keeps the call below linkable. */
nacre_result nc_vdb_read(const char *path, const char *grid_name, const nc_vdb_callbacks *cb, nc_vdb_grid_info *info,
                         char *message, size_t message_size)
{
    (void)path, (void)grid_name, (void)cb, (void)info;
    if (message && message_size)
        snprintf(message, message_size, "built without OpenVDB");
    return NACRE_ERROR_UNSUPPORTED;
}

int nc_vdb_available(void) { return 0; }
#endif /* NACRE_HAVE_OPENVDB */

nacre_result nacre_volume_load_vdb(nacre_context *ctx, const char *path, const char *grid_name, nacre_volume_data *out)
{
    if (!ctx || !out)
        return NACRE_ERROR_INVALID_ARGUMENT;
    memset(out, 0, sizeof(*out));
    if (!path)
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "volume: no path");
    if (grid_name && !grid_name[0])
        return nc_fail(ctx, NACRE_ERROR_INVALID_ARGUMENT, "%s: grid: empty name", path);
    if (!built_with_openvdb())
        return nc_fail(ctx, NACRE_ERROR_UNSUPPORTED,
                       "%s: cannot read OpenVDB volumes: nacre was built without OpenVDB (apt-get install "
                       "libopenvdb-dev libboost-dev, then reconfigure)", path);
    /* OpenVDB's own message for a missing file is vaguer than errno's. */
    FILE *f = fopen(path, "rb");
    if (!f)
        return nc_fail(ctx, NACRE_ERROR_IO, "%s: cannot open: %s", path, strerror(errno));
    fclose(f);

    load_state st = {ctx, path, NULL, 0};
    nc_vdb_callbacks cb = {&st, check_memory, alloc_dense};
    nc_vdb_grid_info info;
    char message[NC_VDB_MESSAGE_MAX];
    nacre_result r = nc_vdb_read(path, grid_name, &cb, &info, message, sizeof(message));
    if (r != NACRE_OK) {
        if (message[0])
            nc_fail(ctx, r, "%s: %s", path, message);
        goto fail;
    }
    for (size_t i = 0; i < st.count; i++) {
        float v = st.data[i];
        if (!(isfinite(v) && v >= 0.0f)) {
            size_t x = i % info.dims[0], y = i / info.dims[0] % info.dims[1], z = i / info.dims[0] / info.dims[1];
            r = nc_fail(ctx, NACRE_ERROR_PARSE,
                        "%s: grid '%s': voxel (%lld, %lld, %lld) is %g (densities must be finite and >= 0)", path,
                        info.name, (long long)info.index_min[0] + (long long)x,
                        (long long)info.index_min[1] + (long long)y, (long long)info.index_min[2] + (long long)z,
                        (double)v);
            goto fail;
        }
    }
    for (int a = 0; a < 3; a++) {
        out->dims[a] = info.dims[a];
        out->origin[a] = (float)info.origin[a];
        out->spacing[a] = (float)info.spacing[a];
        if (!(isfinite(out->origin[a]) && out->spacing[a] > 0.0f && isfinite(out->spacing[a]))) {
            r = nc_fail(ctx, NACRE_ERROR_UNSUPPORTED, "%s: grid '%s': placement out of float range", path,
                        info.name);
            memset(out, 0, sizeof(*out));
            goto fail;
        }
    }
    out->data = st.data;
    return NACRE_OK;
fail:
    nc_free(ctx, st.data);
    return r;
}
