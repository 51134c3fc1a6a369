#!/usr/bin/env python3
"""Write the small glTF test files of tests/data (plain json + struct; no Blender needed).

gltf_pair.glb      a ground quad (with UVs), an opaque cube and a KHR_materials_volume sphere,
                   a sun (KHR_lights_punctual, lux), a point light (candela) and a camera, in metres
gltf_pair.json     the same scene as a nacre scene file: the same triangles as PLY files
                   (gltf_pair_*.ply), the materials and lights converted as docs/scene-format.md
                   says ("glTF 2.0 scenes"), so that both render the same image
gltf_import.json   a nacre scene that imports gltf_pair.glb and overrides a material and the lights
gltf_split.gltf    the pair as .gltf + gltf_split.bin, with an ignored extension (clearcoat)
bad_*.gl*          malformed files: truncated GLB, a missing buffer, an out-of-range accessor,
                   an unknown required extension

Run from the repository root: python3 scripts/make_gltf_tests.py
"""
import json
import math
import os
import struct

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "data")
LUMENS_PER_WATT = 683.0
f32 = lambda x: struct.unpack("<f", struct.pack("<f", x))[0]


def sphere(radius, segments, rings):
    """UV sphere with single pole vertices and a shared seam (closed, watertight)."""
    pos, nrm = [], []
    pos.append((0.0, radius, 0.0)); nrm.append((0.0, 1.0, 0.0))
    for j in range(1, rings):
        th = math.pi * j / rings
        for i in range(segments):
            ph = 2.0 * math.pi * i / segments
            n = (math.sin(th) * math.cos(ph), math.cos(th), -math.sin(th) * math.sin(ph))
            pos.append(tuple(radius * c for c in n)); nrm.append(n)
    pos.append((0.0, -radius, 0.0)); nrm.append((0.0, -1.0, 0.0))
    last = len(pos) - 1
    ring = lambda j, i: 1 + (j - 1) * segments + (i % segments)
    tri = []
    for i in range(segments):
        tri.append((0, ring(1, i), ring(1, i + 1)))
    for j in range(1, rings - 1):
        for i in range(segments):
            a, b, c, d = ring(j, i), ring(j + 1, i), ring(j + 1, i + 1), ring(j, i + 1)
            tri += [(a, b, c), (a, c, d)]
    for i in range(segments):
        tri.append((last, ring(rings - 1, i + 1), ring(rings - 1, i)))
    return pos, nrm, None, tri


def cube(h):
    faces = [((1, 0, 0), (0, 0, -1), (0, 1, 0)), ((-1, 0, 0), (0, 0, 1), (0, 1, 0)),
             ((0, 1, 0), (1, 0, 0), (0, 0, -1)), ((0, -1, 0), (1, 0, 0), (0, 0, 1)),
             ((0, 0, 1), (1, 0, 0), (0, 1, 0)), ((0, 0, -1), (-1, 0, 0), (0, 1, 0))]
    pos, nrm, tri = [], [], []
    for n, u, v in faces:
        base = len(pos)
        for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            pos.append(tuple(h * (n[k] + su * u[k] + sv * v[k]) for k in range(3))); nrm.append(n)
        tri += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return pos, nrm, None, tri


def quad(size):
    s = size / 2
    pos = [(-s, 0, s), (s, 0, s), (s, 0, -s), (-s, 0, -s)]
    nrm = [(0, 1, 0)] * 4
    uv = [(0, 1), (1, 1), (1, 0), (0, 0)]  # glTF: v down from the top
    return pos, nrm, uv, [(0, 1, 2), (0, 2, 3)]


class Builder:
    def __init__(self):
        self.bin = bytearray()
        self.views, self.accessors = [], []

    def add(self, data, fmt, count, comp, typ, target, minmax=None):
        while len(self.bin) % 4:
            self.bin.append(0)
        off = len(self.bin)
        self.bin += struct.pack("<%d%s" % (len(data), fmt), *data)
        self.views.append({"buffer": 0, "byteOffset": off, "byteLength": len(self.bin) - off, "target": target})
        acc = {"bufferView": len(self.views) - 1, "componentType": comp, "count": count, "type": typ}
        if minmax:
            acc["min"], acc["max"] = minmax
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def mesh(self, geo, material, name):
        pos, nrm, uv, tri = geo
        flat = [c for p in pos for c in p]
        mn = [min(p[k] for p in pos) for k in range(3)]
        mx = [max(p[k] for p in pos) for k in range(3)]
        attrs = {"POSITION": self.add(flat, "f", len(pos), 5126, "VEC3", 34962, (mn, mx)),
                 "NORMAL": self.add([c for n in nrm for c in n], "f", len(nrm), 5126, "VEC3", 34962)}
        if uv:
            attrs["TEXCOORD_0"] = self.add([c for t in uv for c in t], "f", len(uv), 5126, "VEC2", 34962)
        idx = self.add([i for t in tri for i in t], "H", len(tri) * 3, 5123, "SCALAR", 34963)
        return {"name": name, "primitives": [{"attributes": attrs, "indices": idx, "material": material}]}


def quat_look(fwd, up):
    """Quaternion (x, y, z, w) of the rotation taking -z to fwd and +y towards up."""
    f = [c / math.sqrt(sum(x * x for x in fwd)) for c in fwd]
    z = [-c for c in f]
    x = [up[1] * z[2] - up[2] * z[1], up[2] * z[0] - up[0] * z[2], up[0] * z[1] - up[1] * z[0]]
    ln = math.sqrt(sum(c * c for c in x)); x = [c / ln for c in x]
    y = [z[1] * x[2] - z[2] * x[1], z[2] * x[0] - z[0] * x[2], z[0] * x[1] - z[1] * x[0]]
    m = [[x[0], y[0], z[0]], [x[1], y[1], z[1]], [x[2], y[2], z[2]]]
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        return [(m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s, 0.25 * s]
    s = math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2]) * 2
    return [0.25 * s, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s, (m[2][1] - m[1][2]) / s]


# The scene, in metres.
GROUND = quad(1.2)
CUBE = cube(0.08)
BALL = sphere(0.1, 32, 16)
CUBE_AT = [-0.18, 0.08, 0.0]
BALL_AT = [0.14, 0.1, 0.05]
SUN_DIR = [-0.4, -1.0, -0.5]
SUN_LUX = 2.5 * LUMENS_PER_WATT
SUN_COLOR = [1.0, 0.95, 0.9]
POINT_AT = [0.0, 0.5, 0.4]
POINT_CD = 0.02 * LUMENS_PER_WATT
CAM_AT = [0.0, 0.35, 0.75]
CAM_TARGET = [0.0, 0.06, 0.0]
ATT_COLOR = [0.5, 0.8, 0.6]
ATT_DIST = 0.01  # metres
IOR = 1.45


def materials(extra_ext=None):
    ground = {"name": "ground", "pbrMetallicRoughness": {"baseColorFactor": [0.55, 0.5, 0.45, 1],
                                                         "metallicFactor": 0, "roughnessFactor": 0.6},
              "extensions": {"KHR_materials_specular": {"specularFactor": 0.5}}}
    cube_m = {"name": "paint", "pbrMetallicRoughness": {"baseColorFactor": [0.7, 0.15, 0.1, 1],
                                                        "metallicFactor": 0, "roughnessFactor": 0.4}}
    ball = {"name": "ball", "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0,
                                                     "roughnessFactor": 0.3},
            "extensions": {"KHR_materials_volume": {"thicknessFactor": 0.2, "attenuationColor": ATT_COLOR,
                                                    "attenuationDistance": ATT_DIST},
                           "KHR_materials_diffuse_transmission": {"diffuseTransmissionFactor": 1.0},
                           "KHR_materials_ior": {"ior": IOR}}}
    if extra_ext:
        cube_m["extensions"] = {extra_ext: {}}
    return [ground, cube_m, ball]


def gltf_doc(b, extra_ext=None):
    meshes = [b.mesh(GROUND, 0, "ground"), b.mesh(CUBE, 1, "cube"), b.mesh(BALL, 2, "ball")]
    fwd = [CAM_TARGET[k] - CAM_AT[k] for k in range(3)]
    used = ["KHR_lights_punctual", "KHR_materials_volume", "KHR_materials_diffuse_transmission",
            "KHR_materials_ior", "KHR_materials_specular"] + ([extra_ext] if extra_ext else [])
    doc = {
        "asset": {"version": "2.0", "generator": "nacre scripts/make_gltf_tests.py"},
        "extensionsUsed": used,
        "scene": 0,
        "scenes": [{"nodes": [0, 1, 2, 3, 4, 5, 6]}],
        "nodes": [
            {"name": "ground", "mesh": 0},
            {"name": "cube", "mesh": 1, "translation": CUBE_AT},
            {"name": "ballholder", "translation": BALL_AT, "children": [7]},
            {"name": "sun", "rotation": quat_look(SUN_DIR, [0, 0, 1] if abs(SUN_DIR[1]) > 0.9 else [0, 1, 0]),
             "extensions": {"KHR_lights_punctual": {"light": 0}}},
            {"name": "lamp", "translation": POINT_AT, "extensions": {"KHR_lights_punctual": {"light": 1}}},
            {"name": "cam", "camera": 0, "translation": CAM_AT, "rotation": quat_look(fwd, [0, 1, 0])},
            {"name": "side", "camera": 1, "translation": [0.9, 0.2, 0.0], "rotation": quat_look([-1, -0.1, 0], [0, 1, 0])},
            {"name": "ball", "mesh": 2},
        ],
        "cameras": [{"name": "main", "type": "perspective", "perspective": {"yfov": math.radians(35), "znear": 0.01}},
                    {"name": "sidecam", "type": "perspective", "perspective": {"yfov": math.radians(30), "znear": 0.01}}],
        "extensions": {"KHR_lights_punctual": {"lights": [
            {"type": "directional", "color": SUN_COLOR, "intensity": SUN_LUX},
            {"type": "point", "color": [1, 1, 1], "intensity": POINT_CD}]}},
        "materials": materials(extra_ext),
        "meshes": meshes,
        "accessors": b.accessors,
        "bufferViews": b.views,
        "buffers": [{"byteLength": len(b.bin)}],
    }
    return doc


def glb(doc, binary):
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    binary = bytes(binary) + b"\0" * (-len(binary) % 4)
    total = 12 + 8 + len(js) + 8 + len(binary)
    return (struct.pack("<III", 0x46546C67, 2, total) + struct.pack("<II", len(js), 0x4E4F534A) + js +
            struct.pack("<II", len(binary), 0x004E4942) + binary)


def write_ply(path, geo):
    """ASCII PLY of the same float32 values (a binary body starting with byte 0x0a is misread by
    assimp 5.2, which skips whitespace after end_header)."""
    pos, nrm, uv, tri = geo
    head = ["ply", "format ascii 1.0", "element vertex %d" % len(pos),
            "property float x", "property float y", "property float z",
            "property float nx", "property float ny", "property float nz"]
    if uv:
        head += ["property float s", "property float t"]
    head += ["element face %d" % len(tri), "property list uchar int vertex_indices", "end_header"]
    lines = head[:]
    for i, p in enumerate(pos):
        vals = list(p) + list(nrm[i]) + ([uv[i][0], 1.0 - uv[i][1]] if uv else [])  # PLY: v up
        lines.append(" ".join(repr(f32(v)) for v in vals))
    for t in tri:
        lines.append("3 %d %d %d" % t)
    open(path, "w").write("\n".join(lines) + "\n")


def main():
    os.makedirs(OUT, exist_ok=True)
    b = Builder()
    doc = gltf_doc(b)
    open(os.path.join(OUT, "gltf_pair.glb"), "wb").write(glb(doc, b.bin))
    for name, geo in (("ground", GROUND), ("cube", CUBE), ("ball", BALL)):
        write_ply(os.path.join(OUT, "gltf_pair_%s.ply" % name), geo)

    # The equivalent nacre scene, converted as docs/scene-format.md "glTF 2.0 scenes" says.
    def phong(base, rough, spec):
        a = rough * rough
        return {"type": "opaque", "diffuse": base, "specular": [spec] * 3, "shininess": 2 / (a * a) - 2}
    f0 = ((IOR - 1) / (IOR + 1)) ** 2
    a = 0.3 * 0.3
    ball = {"type": "translucent", "sigma_a": [-math.log(c) / ATT_DIST for c in ATT_COLOR],
            "sigma_s": [1000.0] * 3, "g": 0, "eta": IOR, "specular": [f0] * 3, "shininess": 2 / (a * a) - 2}
    fwd = [CAM_TARGET[k] - CAM_AT[k] for k in range(3)]
    pair = {
        "units": "m",
        "render": {"method": "phong", "width": 160, "height": 120},
        "environment": [0.05, 0.05, 0.05],
        "camera": {"type": "perspective", "position": CAM_AT, "target": CAM_TARGET, "up": [0, 1, 0], "fov": 35,
                   "near": 0.01},
        "materials": {"ground": phong([0.55, 0.5, 0.45], 0.6, 0.04 * 0.5), "paint": phong([0.7, 0.15, 0.1], 0.4, 0.04),
                      "ball": ball},
        "lights": [{"type": "directional", "direction": SUN_DIR,
                    "irradiance": [c * SUN_LUX / LUMENS_PER_WATT for c in SUN_COLOR]},
                   {"type": "point", "position": POINT_AT, "intensity": POINT_CD / LUMENS_PER_WATT}],
        "objects": [{"name": "ground", "mesh": "gltf_pair_ground.ply", "material": "ground"},
                    {"name": "cube", "mesh": "gltf_pair_cube.ply", "material": "paint",
                     "transform": {"translate": CUBE_AT}},
                    {"name": "ball", "mesh": "gltf_pair_ball.ply", "material": "ball",
                     "transform": {"translate": BALL_AT}}],
    }
    open(os.path.join(OUT, "gltf_pair.json"), "w").write(json.dumps(pair, indent=1) + "\n")

    imp = {"import": "gltf_pair.glb", "render": {"method": "phong", "width": 160, "height": 120},
           "environment": [0.05, 0.05, 0.05],
           "materials": {"ball": {"preset": "marble"}},
           "lights": [{"type": "directional", "direction": [0, -1, 0], "irradiance": 1.0}]}
    open(os.path.join(OUT, "gltf_import.json"), "w").write(json.dumps(imp, indent=1) + "\n")

    # .gltf + .bin, with an extension nacre ignores.
    b2 = Builder()
    doc2 = gltf_doc(b2, "KHR_materials_clearcoat")
    doc2["buffers"] = [{"uri": "gltf_split.bin", "byteLength": len(b2.bin)}]
    open(os.path.join(OUT, "gltf_split.bin"), "wb").write(bytes(b2.bin))
    open(os.path.join(OUT, "gltf_split.gltf"), "w").write(json.dumps(doc2, separators=(",", ":")))

    # Malformed files.
    whole = glb(doc, b.bin)
    open(os.path.join(OUT, "bad_truncated.glb"), "wb").write(whole[: len(whole) * 2 // 3])
    bad = json.loads(json.dumps(doc2))
    bad["buffers"] = [{"uri": "no_such_buffer.bin", "byteLength": len(b2.bin)}]
    open(os.path.join(OUT, "bad_missing_buffer.gltf"), "w").write(json.dumps(bad, separators=(",", ":")))
    bad = json.loads(json.dumps(doc2))
    bad["accessors"][0]["count"] += 1000
    open(os.path.join(OUT, "bad_accessor.gltf"), "w").write(json.dumps(bad, separators=(",", ":")))
    bad = json.loads(json.dumps(doc2))
    bad["extensionsUsed"].append("KHR_draco_mesh_compression")
    bad["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    open(os.path.join(OUT, "bad_required.gltf"), "w").write(json.dumps(bad, separators=(",", ":")))


if __name__ == "__main__":
    main()
