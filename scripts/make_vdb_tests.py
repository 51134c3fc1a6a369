#!/usr/bin/python3
"""Writes the small OpenVDB files of tests/data (and the NRRD twin of the cloud) that
tests/unit/test_vdb.c reads. Needs Debian's python3-openvdb, which is built for the system
interpreter: run it as /usr/bin/python3 scripts/make_vdb_tests.py (from the repository root).
The outputs are committed, so the tests do not need python3-openvdb.

vdb_field.vdb   grids "temperature" (float, 7 everywhere active), "density" (float, the linear
                field FIELD below on a non-uniform axis-aligned transform) and "velocity" (vec3)
vdb_cloud.vdb   grid "density": a soft ball of 8^3 voxels, voxel size 0.1, offset; vdb_cloud.nrrd holds the
                same samples over the same padded box, for the VDB-vs-NRRD comparison
vdb_rotated.vdb a float grid with a rotated transform (refused)
vdb_levelset.vdb a level-set sphere (refused: not a density)
vdb_vector.vdb  only a vec3 grid (refused: no float grid)
vdb_negative.vdb a float grid with one negative voxel (refused)
"""
import math
import struct
import sys

import pyopenvdb as vdb

OUT = "tests/data/"

# The density field's index box and transform (row-vector matrix: scale, then translation).
FIELD_MIN, FIELD_MAX = (2, 1, 0), (6, 4, 2)
FIELD_SCALE, FIELD_TRANSLATE = (0.25, 0.5, 0.125), (1.0, -2.0, 0.5)


def field(i, j, k):
    return 0.5 + 0.1 * i - 0.05 * j + 0.02 * k


def linear(scale, translate):
    return vdb.createLinearTransform(matrix=[[scale[0], 0, 0, 0], [0, scale[1], 0, 0],
                                             [0, 0, scale[2], 0], [translate[0], translate[1], translate[2], 1]])


def float_grid(name, values, transform):
    g = vdb.FloatGrid(0.0)
    g.name = name
    acc = g.getAccessor()
    for ijk, v in values.items():
        acc.setValueOn(ijk, v)
    g.transform = transform
    return g


def box(lo, hi):
    return [(i, j, k) for k in range(lo[2], hi[2] + 1) for j in range(lo[1], hi[1] + 1)
            for i in range(lo[0], hi[0] + 1)]


def cloud(i, j, k):
    r = math.sqrt((i - 3.5) ** 2 + (j - 4.0) ** 2 + (k - 3.25) ** 2)
    return max(0.0, 2.0 * (1.0 - r / 4.5)) * (1.0 + 0.3 * math.sin(0.9 * i + 0.4 * k))


def write_nrrd(path, values, scale, translate):
    """The padded box nacre_volume_load_vdb makes: active bounding box + 1 voxel, background 0."""
    lo = [min(p[a] for p in values) - 1 for a in range(3)]
    hi = [max(p[a] for p in values) + 1 for a in range(3)]
    dims = [hi[a] - lo[a] + 1 for a in range(3)]
    origin = [translate[a] + scale[a] * lo[a] for a in range(3)]
    data = bytearray()
    for ijk in box(lo, hi):
        data += struct.pack("<f", values.get(ijk, 0.0))
    header = ("NRRD0004\n# the samples of vdb_cloud.vdb (scripts/make_vdb_tests.py)\ntype: float\n"
              "dimension: 3\nsizes: %d %d %d\nencoding: raw\nendian: little\nspace dimension: 3\n"
              "space directions: (%.9g,0,0) (0,%.9g,0) (0,0,%.9g)\nspace origin: (%.9g,%.9g,%.9g)\n\n"
              % (dims[0], dims[1], dims[2], scale[0], scale[1], scale[2], origin[0], origin[1], origin[2]))
    with open(path, "wb") as f:
        f.write(header.encode() + bytes(data))


def main():
    t = linear(FIELD_SCALE, FIELD_TRANSLATE)
    dens = float_grid("density", {p: field(*p) for p in box(FIELD_MIN, FIELD_MAX)}, t)
    temp = float_grid("temperature", {p: 7.0 for p in box((0, 0, 0), (1, 1, 1))}, t)
    vel = vdb.Vec3SGrid()
    vel.name = "velocity"
    vel.getAccessor().setValueOn((0, 0, 0), (1.0, 2.0, 3.0))
    vdb.write(OUT + "vdb_field.vdb", grids=[temp, dens, vel])

    scale, translate = (0.1, 0.1, 0.1), (-0.35, 0.1, -0.35)
    values = {}
    for p in box((0, 0, 0), (7, 7, 7)):  # one leaf node: a small file
        v = cloud(*p)
        if v > 0.0:
            values[p] = v
    vdb.write(OUT + "vdb_cloud.vdb", grids=[float_grid("density", values, linear(scale, translate))])
    write_nrrd(OUT + "vdb_cloud.nrrd", values, scale, translate)

    c, s = math.cos(0.3), math.sin(0.3)
    rot = vdb.createLinearTransform(matrix=[[c, s, 0, 0], [-s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    vdb.write(OUT + "vdb_rotated.vdb", grids=[float_grid("density", {(0, 0, 0): 1.0}, rot)])

    ls = vdb.createLevelSetSphere(radius=1.5, center=(3.5, 3.5, 3.5), voxelSize=1.0, halfWidth=1.5)
    ls.name = "surface"
    vdb.write(OUT + "vdb_levelset.vdb", grids=[ls])

    vdb.write(OUT + "vdb_vector.vdb", grids=[vel])

    neg = {p: 1.0 for p in box((0, 0, 0), (2, 2, 2))}
    neg[(1, 2, 0)] = -0.5
    vdb.write(OUT + "vdb_negative.vdb", grids=[float_grid("density", neg, linear((1, 1, 1), (0, 0, 0)))])


if __name__ == "__main__":
    main()
