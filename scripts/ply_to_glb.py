#!/usr/bin/env python3
"""Convert a binary little-endian triangle PLY (float x y z [more float properties ignored],
faces as "list uchar int|uint") into a .glb with the same vertices and triangles, for comparing
load times: python3 scripts/ply_to_glb.py IN.ply OUT.glb (plain Python, no numpy)."""
import json
import struct
import sys


def main(src, dst):
    data = open(src, "rb").read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in header:
        sys.exit("%s: only binary little-endian PLY" % src)
    nv = nf = 0
    vprops, element = [], None
    for line in header:
        w = line.split()
        if w[:2] == ["element", "vertex"]:
            nv, element = int(w[2]), "vertex"
        elif w[:2] == ["element", "face"]:
            nf, element = int(w[2]), "face"
        elif w[0] == "property" and element == "vertex":
            if w[1] not in ("float", "float32"):
                sys.exit("%s: vertex property %s is not float" % (src, w[2]))
            vprops.append(w[2])
        elif w[0] == "property" and element == "face":
            if w[1:4] not in (["list", "uchar", "int"], ["list", "uchar", "uint"]):
                sys.exit("%s: faces must be list uchar int" % src)
    if vprops[:3] != ["x", "y", "z"]:
        sys.exit("%s: the first vertex properties must be x y z" % src)
    stride = 4 * len(vprops)
    verts = data[end:end + nv * stride]
    if stride != 12:
        verts = b"".join(verts[i:i + 12] for i in range(0, len(verts), stride))
    fbytes = data[end + nv * stride:end + nv * stride + nf * 13]
    idx = bytearray()
    for n, a, b, c in struct.iter_unpack("<Biii", fbytes):
        if n != 3:
            sys.exit("%s: not a triangle mesh" % src)
        idx += struct.pack("<3I", a, b, c)
    xs = [v for v in struct.iter_unpack("<3f", verts)]
    mn = [min(p[k] for p in xs) for k in range(3)]
    mx = [max(p[k] for p in xs) for k in range(3)]
    binary = bytes(verts) + bytes(idx)
    doc = {"asset": {"version": "2.0", "generator": "nacre scripts/ply_to_glb.py"},
           "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": nv, "type": "VEC3", "min": mn, "max": mx},
                         {"bufferView": 1, "componentType": 5125, "count": nf * 3, "type": "SCALAR"}],
           "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(verts)},
                           {"buffer": 0, "byteOffset": len(verts), "byteLength": len(idx)}],
           "buffers": [{"byteLength": len(binary)}]}
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    binary += b"\0" * (-len(binary) % 4)
    total = 12 + 8 + len(js) + 8 + len(binary)
    with open(dst, "wb") as f:
        f.write(struct.pack("<III", 0x46546C67, 2, total))
        f.write(struct.pack("<II", len(js), 0x4E4F534A) + js)
        f.write(struct.pack("<II", len(binary), 0x004E4942) + binary)


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
