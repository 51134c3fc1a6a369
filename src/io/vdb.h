/*
 * vdb.h: OpenVDB volumes (private). nacre_volume_load_vdb (vdb.c, C) owns the context, the
 * memory limit and the messages; nc_vdb_read (vdb_read.cpp, the library's one C++ file) is the
 * only code that touches OpenVDB. This header is C and C++: it uses no nacre internals, so the
 * C++ side never sees core/core.h (C11 atomics), and allocation goes through callbacks that the
 * C side implements with the context's allocator.
 *
 * Placement: OpenVDB puts voxel (i, j, k) at world position M (i, j, k) (the grid's linear
 * transform, voxel centres at integer index coordinates), which is nacre_volume_data's sample
 * convention once origin = M (bbox min) and spacing = M's diagonal: so only axis-aligned
 * transforms with positive scales map onto nacre_volume_data, and others are refused.
 */
#ifndef NACRE_VDB_H
#define NACRE_VDB_H

#include <nacre/core.h>

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define NC_VDB_NAME_MAX 256
/* Room for nc_vdb_read's message (without the file name, which the caller prefixes). */
#define NC_VDB_MESSAGE_MAX 512

/* The grid nc_vdb_read picked and the dense box it copies out. */
typedef struct nc_vdb_grid_info {
    char name[NC_VDB_NAME_MAX]; /* the grid's name in the file (possibly "") */
    int32_t index_min[3];       /* index coordinates of dense sample (0, 0, 0) */
    uint32_t dims[3];           /* dense samples along x, y, z: active bounding box + 1 each side */
    double origin[3];           /* world position of sample (0, 0, 0) */
    double spacing[3];          /* voxel size along x, y, z, > 0 */
} nc_vdb_grid_info;

typedef struct nc_vdb_callbacks {
    void *user;
    /* Before the dense copy is made (the sparse grid is read by then): may refuse with a
     * result (the callee recorded the error), which stops the read. */
    nacre_result (*check)(void *user, const nc_vdb_grid_info *info);
    /* Storage for info->dims[0] * dims[1] * dims[2] floats, x fastest; NULL and a result
     * other than NACRE_OK stop the read. The caller owns the storage whatever happens. */
    nacre_result (*alloc)(void *user, const nc_vdb_grid_info *info, float **out);
} nc_vdb_callbacks;

/* vdb_read.cpp is built with default visibility (CMakeLists.txt says why): these stay internal. */
#define NC_VDB_HIDDEN __attribute__((visibility("hidden")))

/* 1 when the library was built with OpenVDB. */
NC_VDB_HIDDEN int nc_vdb_available(void);

/* Read the float (or double) grid `grid_name` of the .vdb file `path` (NULL: "density", or the
 * first float grid when there is none by that name) densely over its active bounding box padded
 * by one voxel, so that sampling outside it (clamped to the boundary) gives the background.
 * Values are copied as stored (inactive voxels inside the box hold their tile or background
 * value); the caller checks them. On failure returns the code and, unless a callback stopped
 * the read, a one-line message naming the field or grid in `message`. Exceptions never leave
 * this function. */
NC_VDB_HIDDEN nacre_result nc_vdb_read(const char *path, const char *grid_name, const nc_vdb_callbacks *cb,
                                       nc_vdb_grid_info *info, char *message, size_t message_size);

#ifdef __cplusplus
}
#endif

#endif /* NACRE_VDB_H */
