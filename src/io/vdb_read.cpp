/*
 * vdb_read.cpp: reads one scalar grid of an OpenVDB file (.vdb, the sparse volume format of
 * Blender, Houdini and EmberGen; OpenVDB 10, Debian's libopenvdb-dev) into a dense box, behind
 * the C function nc_vdb_read (io/vdb.h). The library's only C++ file: nothing of OpenVDB, and no
 * exception, crosses its boundary.
 *
 * The file is read whole through a stream that throws at its first short read (read_grid says
 * why), then the grid is picked by name and type, its transform checked, and only its active
 * bounding box copied out, after the caller has checked that dense copy against the memory
 * limit. Level sets (signed distances, not densities) are refused by their grid class. World
 * units are taken as nacre's scene units. OpenVDB trusts the block sizes stored in the file: a
 * corrupted size makes it ask for an impossible allocation, which ends as std::bad_alloc and a
 * clean error here.
 *
 * Copies run serially: OpenVDB would otherwise start TBB's worker threads next to nacre's
 * OpenMP threads on the same cores, and a one-off load of a few million voxels does not need
 * them.
 */
#include "io/vdb.h"

#include <openvdb/openvdb.h>
#include <openvdb/io/Stream.h>
#include <openvdb/tools/Dense.h>

#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <exception>
#include <fstream>
#include <ios>
#include <new>
#include <string>
#include <type_traits>
#include <vector>

namespace {

nacre_result set_message(char *message, size_t size, nacre_result code, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));

nacre_result set_message(char *message, size_t size, nacre_result code, const char *fmt, ...)
{
    if (message && size) {
        va_list ap;
        va_start(ap, fmt);
        std::vsnprintf(message, size, fmt, ap);
        va_end(ap);
    }
    return code;
}

bool is_scalar_real(const openvdb::GridBase &grid)
{
    return grid.isType<openvdb::FloatGrid>() || grid.isType<openvdb::DoubleGrid>();
}

/* The grid to read: `wanted` by name, or "density", or the first float grid. NULL with a
 * message when there is none. */
openvdb::GridBase::Ptr pick_grid(const openvdb::GridPtrVec &grids, const char *wanted, char *message,
                                 size_t size, nacre_result *code)
{
    std::string names;
    for (const auto &g : grids)
        names += (names.empty() ? "" : ", ") + ("'" + g->getName() + "' (" + g->valueType() + ")");
    if (names.empty())
        names = "none";
    if (wanted) {
        for (const auto &g : grids)
            if (g->getName() == wanted) {
                if (is_scalar_real(*g))
                    return g;
                *code = set_message(message, size, NACRE_ERROR_UNSUPPORTED,
                                    "grid '%s': holds %s values, not float (grids: %s)", wanted,
                                    g->valueType().c_str(), names.c_str());
                return nullptr;
            }
        *code = set_message(message, size, NACRE_ERROR_INVALID_ARGUMENT, "grid '%s': not in the file (grids: %s)",
                            wanted, names.c_str());
        return nullptr;
    }
    for (const auto &g : grids)
        if (g->getName() == "density" && is_scalar_real(*g))
            return g;
    for (const auto &g : grids)
        if (is_scalar_real(*g))
            return g;
    *code = set_message(message, size, NACRE_ERROR_UNSUPPORTED, "no float grid (grids: %s)", names.c_str());
    return nullptr;
}

/* Origin and spacing of index (0, 0, 0) from a linear, axis-aligned transform with positive
 * scales; false with a message otherwise. OpenVDB's matrices act on row vectors: the
 * translation is row 3 and the scale the diagonal. */
bool axis_aligned(const openvdb::math::Transform &xform, const std::string &name, double translation[3],
                  double scale[3], char *message, size_t size, nacre_result *code)
{
    if (!xform.isLinear()) {
        *code = set_message(message, size, NACRE_ERROR_UNSUPPORTED,
                            "grid '%s': transform %s is not linear (frustum transforms are not supported)",
                            name.c_str(), xform.mapType().c_str());
        return false;
    }
    const openvdb::math::Mat4d m = xform.baseMap()->getAffineMap()->getMat4();
    double largest = 0.0;
    for (int r = 0; r < 3; r++)
        largest = std::fmax(largest, std::fabs(m(r, r)));
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            if (r != c && !(std::fabs(m(r, c)) <= 1e-9 * largest)) {
                *code = set_message(message, size, NACRE_ERROR_UNSUPPORTED,
                                    "grid '%s': transform is rotated or sheared (only axis-aligned voxels "
                                    "are supported)", name.c_str());
                return false;
            }
    for (int a = 0; a < 3; a++) {
        scale[a] = m(a, a);
        translation[a] = m(3, a);
        if (!(scale[a] > 0.0 && std::isfinite(scale[a]) && std::isfinite(translation[a]))) {
            *code = set_message(message, size, NACRE_ERROR_UNSUPPORTED,
                                "grid '%s': voxel size %g along %c (must be finite and > 0; flipped "
                                "axes are not supported)", name.c_str(), scale[a], "xyz"[a]);
            return false;
        }
    }
    return true;
}

/* Fill `info` for the index box [lo, hi] (the active bounding box), padded by one voxel. */
bool fill_box(const openvdb::Coord &lo, const openvdb::Coord &hi, const double translation[3],
              const double scale[3], nc_vdb_grid_info *info, char *message, size_t size, nacre_result *code)
{
    uint64_t total = 1;
    for (int a = 0; a < 3; a++) {
        int64_t extent = (int64_t)hi[a] - (int64_t)lo[a] + 3;
        if (extent < 3 || extent > ((int64_t)1 << 30) || lo[a] <= INT32_MIN + 1) {
            *code = set_message(message, size, NACRE_ERROR_PARSE, "grid '%s': bounding box [%d, %d] along %c is "
                                "invalid", info->name, lo[a], hi[a], "xyz"[a]);
            return false;
        }
        info->dims[a] = (uint32_t)extent;
        info->index_min[a] = lo[a] - 1;
        info->spacing[a] = scale[a];
        info->origin[a] = translation[a] + scale[a] * (double)info->index_min[a];
        total *= (uint64_t)extent;
        if (total > ((uint64_t)1 << 40)) {
            *code = set_message(message, size, NACRE_ERROR_UNSUPPORTED, "grid '%s': bounding box too large",
                                info->name);
            return false;
        }
    }
    return true;
}

template <typename GridT>
nacre_result copy_dense(const GridT &grid, const nc_vdb_grid_info *info, float *out)
{
    using ValueT = typename GridT::ValueType;
    const openvdb::Coord lo(info->index_min[0], info->index_min[1], info->index_min[2]);
    const openvdb::Coord hi(lo[0] + (int32_t)info->dims[0] - 1, lo[1] + (int32_t)info->dims[1] - 1,
                            lo[2] + (int32_t)info->dims[2] - 1);
    const openvdb::CoordBBox box(lo, hi);
    if constexpr (std::is_same<ValueT, float>::value) {
        openvdb::tools::Dense<float, openvdb::tools::LayoutXYZ> dense(box, out);
        openvdb::tools::copyToDense(grid, dense, true);
    } else {
        /* Double grids: one z slice at a time through a double buffer, then narrowed. */
        const size_t slice = (size_t)info->dims[0] * info->dims[1];
        std::vector<ValueT> buffer(slice);
        for (int32_t z = lo[2]; z <= hi[2]; z++) {
            const openvdb::CoordBBox slab(openvdb::Coord(lo[0], lo[1], z), openvdb::Coord(hi[0], hi[1], z));
            openvdb::tools::Dense<ValueT, openvdb::tools::LayoutXYZ> dense(slab, buffer.data());
            openvdb::tools::copyToDense(grid, dense, true);
            float *dst = out + (size_t)(z - lo[2]) * slice;
            for (size_t i = 0; i < slice; i++)
                dst[i] = (float)buffer[i];
        }
    }
    return NACRE_OK;
}

nacre_result read_grid(const char *path, const char *grid_name, const nc_vdb_callbacks *cb, nc_vdb_grid_info *info,
                       char *message, size_t size)
{
    nacre_result code = NACRE_OK;
    openvdb::initialize();
    /* OpenVDB's readers do not check their stream after each read: on a cut file they go on
     * with sizes that were never read (a string "length" of garbage, then a loop filling it).
     * A stream that throws on the first short read stops them there; io::File opens its own
     * stream, so the grids come through io::Stream (which reads every grid of the file). */
    std::ifstream is;
    is.exceptions(std::ios::failbit | std::ios::badbit | std::ios::eofbit);
    is.open(path, std::ios::in | std::ios::binary);
    openvdb::io::Stream stream(is, false);
    openvdb::GridPtrVecPtr grids = stream.getGrids();
    if (!grids)
        return set_message(message, size, NACRE_ERROR_PARSE, "no grids");
    openvdb::GridBase::Ptr grid = pick_grid(*grids, grid_name, message, size, &code);
    if (!grid)
        return code;
    std::snprintf(info->name, sizeof(info->name), "%s", grid->getName().c_str());
    if (grid->getGridClass() == openvdb::GRID_LEVEL_SET)
        return set_message(message, size, NACRE_ERROR_UNSUPPORTED,
                           "grid '%s': is a level set (signed distances), not a density (fog volume)", info->name);
    double translation[3], scale[3];
    if (!axis_aligned(grid->transform(), grid->getName(), translation, scale, message, size, &code))
        return code;
    const openvdb::CoordBBox active = grid->evalActiveVoxelBoundingBox();
    if (active.empty())
        return set_message(message, size, NACRE_ERROR_INVALID_ARGUMENT, "grid '%s': has no active voxels",
                           info->name);
    if (!fill_box(active.min(), active.max(), translation, scale, info, message, size, &code))
        return code;
    /* The sparse tree is held already; the check is for the dense copy. */
    if ((code = cb->check(cb->user, info)) != NACRE_OK)
        return code;
    float *out = nullptr;
    if ((code = cb->alloc(cb->user, info, &out)) != NACRE_OK || !out)
        return code != NACRE_OK ? code : NACRE_ERROR_OUT_OF_MEMORY;
    if (grid->isType<openvdb::FloatGrid>())
        return copy_dense(*openvdb::gridConstPtrCast<openvdb::FloatGrid>(grid), info, out);
    return copy_dense(*openvdb::gridConstPtrCast<openvdb::DoubleGrid>(grid), info, out);
}

} // namespace

extern "C" int nc_vdb_available(void) { return 1; }

extern "C" nacre_result nc_vdb_read(const char *path, const char *grid_name, const nc_vdb_callbacks *cb,
                                    nc_vdb_grid_info *info, char *message, size_t message_size)
{
    if (message && message_size)
        message[0] = '\0';
    if (!path || !cb || !cb->check || !cb->alloc || !info)
        return NACRE_ERROR_INVALID_ARGUMENT;
    std::memset(info, 0, sizeof(*info));
    try {
        return read_grid(path, grid_name, cb, info, message, message_size);
    } catch (const std::ios_base::failure &) {
        return set_message(message, message_size, NACRE_ERROR_PARSE, "not a readable OpenVDB file (it ends early)");
    } catch (const std::bad_alloc &) {
        return set_message(message, message_size, NACRE_ERROR_OUT_OF_MEMORY, "out of memory while reading the grid");
    } catch (const openvdb::Exception &e) {
        /* OpenVDB's what() is "<Kind>: <detail>"; the detail may repeat the path. */
        return set_message(message, message_size, NACRE_ERROR_PARSE, "not a readable OpenVDB file (%s)", e.what());
    } catch (const std::exception &e) {
        return set_message(message, message_size, NACRE_ERROR_PARSE, "not a readable OpenVDB file (%s)", e.what());
    } catch (...) {
        return set_message(message, message_size, NACRE_ERROR_PARSE, "not a readable OpenVDB file");
    }
}
