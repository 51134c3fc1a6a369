#!/usr/bin/env python3
"""Write the small glTF test files of tests/data (plain json + struct; no Blender needed).

gltf_pair.glb      a ground quad (with UVs), an opaque cube and a KHR_materials_volume sphere,
                   a sun (KHR_lights_punctual, lux), a point light (candela) and a camera, in metres
gltf_pair.json     the same scene as a nacre scene file: the same triangles as PLY files
                   (gltf_pair_*.ply), the materials and lights converted as docs/scene-format.md
                   says ("glTF 2.0 scenes"), so that both render the same image
gltf_import.json   a nacre scene that imports gltf_pair.glb and overrides a material and the lights
gltf_split.gltf    the pair as .gltf + gltf_split.bin, with an ignored extension (clearcoat)
gltf_demo.glb      examples/demo.json as glTF: the same shapes (nacre's generators, rewritten
                   below), the torus's transform as its node's matrix, the column's twist baked
                   into its vertices, in metres; gltf_demo.json imports it in millimetres and
                   overrides jade and marble with the presets (glTF has no scattering)
gltf_textured.glb  two quads under an orthographic camera and a sun: one with a base colour
                   texture (an 8x8 sRGB PNG in the GLB's BIN chunk) times baseColorFactor, one
                   whose texture is the same texels as a JPEG (written by Debian libstb's
                   stbi_write_jpg at quality 100, no chroma subsampling)
gltf_textured.gltf the textured quad alone, its image a file beside it (gltf_textured.png) and its
                   buffer a data: URI
gltf_textured.json both as a nacre scene file: PLY quads with uvs, "diffuse_map" on the PNG
gltf_misc.gltf     one root node over a two-primitive mesh (a metal, and no material: the default),
                   a spot light and an orthographic camera; its buffer is a base64 data: URI
gltf_thickness.glb a UV-mapped KHR_materials_volume sphere whose thicknessTexture (an 8x8 PNG in
                   the BIN chunk) holds latitude bands in G and other values in R and B, a sun and
                   a camera; gltf_thickness.json is the same as a nacre scene with the layer that
                   the "thickness": "layer" import makes (docs/scene-format.md): the sphere as PLY
                   with uvs, the depth map gltf_thickness_depth.png (G copied into R)
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


# ---- the demo scene (examples/demo.json), shapes as src/scene/shapes.c builds them ----------

def grid(base, cols, rows):
    tri = []
    for j in range(rows):
        for i in range(cols):
            v00 = base + j * (cols + 1) + i
            v10, v01 = v00 + 1, v00 + cols + 1
            tri += [(v00, v10, v01 + 1), (v00, v01 + 1, v01)]
    return tri


def box_faces(faces, size, N):
    pos, nrm, tri = [], [], []
    for na, ns, ua, us, va, vs in faces:
        n = [0.0, 0.0, 0.0]
        n[na] = float(ns)
        base = len(pos)
        for j in range(N + 1):
            for i in range(N + 1):
                k = [0, 0, 0]
                k[na] = N if ns > 0 else 0
                k[ua] = i if us > 0 else N - i
                k[va] = j if vs > 0 else N - j
                pos.append(tuple(f32((k[a] / N - 0.5) * f32(size[a])) for a in range(3)))
                nrm.append(tuple(n))
        tri += grid(base, N, N)
    return pos, nrm, None, tri


BOX_FACES = [(0, 1, 2, -1, 1, 1), (0, -1, 2, 1, 1, 1), (1, 1, 0, 1, 2, -1), (1, -1, 0, 1, 2, 1),
             (2, 1, 0, 1, 1, 1), (2, -1, 0, -1, 1, 1)]


def torus(major, minor, S, R):
    two_pi = 6.283185307179586476925
    pos, nrm = [], []
    for j in range(R + 1):
        psi = two_pi * (j % R) / R
        sq, cq = math.sin(psi), math.cos(psi)
        for i in range(S + 1):
            phi = two_pi * (i % S) / S
            sp, cp = math.sin(phi), math.cos(phi)
            ring = major + minor * cq
            pos.append((f32(ring * cp), f32(minor * sq), f32(-ring * sp)))
            nrm.append((cq * cp, sq, -cq * sp))
    return pos, nrm, None, grid(0, S, R)


def rot_matrix(axis, deg):
    a = math.radians(deg)
    c, s, t = math.cos(a), math.sin(a), 1 - math.cos(a)
    x, y, z = axis
    return [[t * x * x + c, t * x * y - s * z, t * x * z + s * y],
            [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
            [t * x * z - s * y, t * y * z + s * x, t * z * z + c]]


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def twist_y(geo, angle_deg, length, center_y):
    """The demo column's twist deformer (about +y through (0, center_y, 0)), baked; normals by the
    deformation's Jacobian (inverse transpose), as nacre's commit maps them."""
    pos, nrm, uv, tri = geo
    k = math.radians(angle_deg) / length
    out_p, out_n = [], []
    for p, n in zip(pos, nrm):
        s = p[1] - center_y
        a = k * s
        c, si = math.cos(a), math.sin(a)
        # Rotation about +y by a: x' = c x + s z, z' = -s x + c z (right-handed).
        out_p.append((c * p[0] + si * p[2], p[1], -si * p[0] + c * p[2]))
        # Jacobian J = R(a) + dR/da * k (x, z) e_y^T; normal -> cofactor(J) n.
        J = [[c, k * (-si * p[0] + c * p[2]), si], [0, 1, 0], [-si, k * (-c * p[0] - si * p[2]), c]]
        cof = [[J[1][1] * J[2][2] - J[1][2] * J[2][1], J[1][2] * J[2][0] - J[1][0] * J[2][2], J[1][0] * J[2][1] - J[1][1] * J[2][0]],
               [J[0][2] * J[2][1] - J[0][1] * J[2][2], J[0][0] * J[2][2] - J[0][2] * J[2][0], J[0][1] * J[2][0] - J[0][0] * J[2][1]],
               [J[0][1] * J[1][2] - J[0][2] * J[1][1], J[0][2] * J[1][0] - J[0][0] * J[1][2], J[0][0] * J[1][1] - J[0][1] * J[1][0]]]
        m = [sum(cof[i][j] * n[j] for j in range(3)) for i in range(3)]
        ln = math.sqrt(sum(v * v for v in m))
        out_n.append(tuple(v / ln for v in m))
    return out_p, out_n, uv, tri


def scaled(geo, f, offset=(0, 0, 0)):
    pos, nrm, uv, tri = geo
    return [tuple((p[k] + offset[k]) * f for k in range(3)) for p in pos], nrm, uv, tri


def write_demo():
    mm = 0.001
    plane = box_faces([(1, 1, 0, 1, 2, -1)], [600, 0, 600], 1)
    tor = torus(28.0, 11.0, 96, 48)
    column = twist_y(box_faces(BOX_FACES, [26, 60, 26], 24), 60.0, 60.0, -30.0)
    # The torus's transform, translate [-22, 39, 0] and rotate [90, 20, 0] (x, then y), in metres.
    r = matmul(rot_matrix((0, 1, 0), 20.0), rot_matrix((1, 0, 0), 90.0))
    t = [-22 * mm, 39 * mm, 0.0]
    torus_matrix = [r[0][0], r[1][0], r[2][0], 0, r[0][1], r[1][1], r[2][1], 0,
                    r[0][2], r[1][2], r[2][2], 0, t[0], t[1], t[2], 1]
    b = Builder()
    jade = {"name": "jade", "pbrMetallicRoughness": {"baseColorFactor": [0.4, 0.7, 0.45, 1], "metallicFactor": 0,
                                                     "roughnessFactor": 0.35},
            "extensions": {"KHR_materials_volume": {"thicknessFactor": 0.02, "attenuationColor": [0.3, 0.75, 0.4],
                                                    "attenuationDistance": 0.01},
                           "KHR_materials_diffuse_transmission": {"diffuseTransmissionFactor": 1.0},
                           "KHR_materials_ior": {"ior": 1.6}}}
    marble = {"name": "marble", "pbrMetallicRoughness": {"baseColorFactor": [0.9, 0.88, 0.85, 1], "metallicFactor": 0,
                                                         "roughnessFactor": 0.35},
              "extensions": {"KHR_materials_volume": {"thicknessFactor": 0.02, "attenuationColor": [0.95, 0.9, 0.85],
                                                      "attenuationDistance": 0.02},
                             "KHR_materials_diffuse_transmission": {"diffuseTransmissionFactor": 1.0}}}
    # Opaque ground: diffuse [0.55, 0.5, 0.45]; specular 0.02 = F0 0.04 x specularFactor 0.5;
    # shininess 16 = 2 / alpha^2 - 2 with alpha = roughness^2, so roughness = (1/9)^(1/4).
    ground = {"name": "ground", "pbrMetallicRoughness": {"baseColorFactor": [0.55, 0.5, 0.45, 1],
                                                         "metallicFactor": 0, "roughnessFactor": (1 / 9) ** 0.25},
              "extensions": {"KHR_materials_specular": {"specularFactor": 0.5}}}
    meshes = [b.mesh(scaled(plane, mm), 2, "ground"), b.mesh(scaled(tor, mm), 0, "jade torus"),
              b.mesh(scaled(column, mm, (48, 30, -10)), 1, "marble column")]
    cam_at, cam_target = [0, 70 * mm, 190 * mm], [0, 25 * mm, 0]
    fwd = [cam_target[k] - cam_at[k] for k in range(3)]
    sun = [-0.5, -1.0, -0.6]
    irr = [3.0, 2.9, 2.7]
    doc = {
        "asset": {"version": "2.0", "generator": "nacre scripts/make_gltf_tests.py (examples/demo.json)"},
        "extensionsUsed": ["KHR_lights_punctual", "KHR_materials_volume", "KHR_materials_diffuse_transmission",
                           "KHR_materials_ior", "KHR_materials_specular"],
        "scene": 0, "scenes": [{"nodes": [0, 1, 2, 3, 4]}],
        "nodes": [{"name": "ground", "mesh": 0}, {"name": "jade torus", "mesh": 1, "matrix": torus_matrix},
                  {"name": "marble column", "mesh": 2},
                  {"name": "sun", "rotation": quat_look(sun, [0, 1, 0]),
                   "extensions": {"KHR_lights_punctual": {"light": 0}}},
                  {"name": "camera", "camera": 0, "translation": cam_at, "rotation": quat_look(fwd, [0, 1, 0])}],
        "cameras": [{"name": "camera", "type": "perspective", "perspective": {"yfov": math.radians(35), "znear": 0.001}}],
        "extensions": {"KHR_lights_punctual": {"lights": [
            {"type": "directional", "color": [1.0, irr[1] / irr[0], irr[2] / irr[0]],
             "intensity": irr[0] * LUMENS_PER_WATT}]}},
        "materials": [jade, marble, ground],
        "meshes": meshes, "accessors": b.accessors, "bufferViews": b.views,
        "buffers": [{"byteLength": len(b.bin)}],
    }
    open(os.path.join(OUT, "gltf_demo.glb"), "wb").write(glb(doc, b.bin))
    demo = {"import": "gltf_demo.glb", "units": "mm",
            "render": {"method": "phong", "width": 960, "height": 540, "exposure": 0, "shadow_map_size": 2048},
            "environment": [0.25, 0.3, 0.4],
            "materials": {"jade": {"preset": "jade"}, "marble": {"preset": "marble"}}}
    open(os.path.join(OUT, "gltf_demo.json"), "w").write(json.dumps(demo, indent=1) + "\n")


def write_misc():
    import base64
    b = Builder()
    tri = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
    m = b.mesh((tri, [(0, 0, 1)] * 3, None, [(0, 1, 2)]), 0, "tri")
    quad2 = [(0, 0, -1), (1, 0, -1), (0, 1, -1)]
    m2 = b.mesh((quad2, [(0, 0, 1)] * 3, None, [(0, 1, 2)]), 0, "tri2")
    prim2 = m2["primitives"][0]
    del prim2["material"]
    m["primitives"].append(prim2)
    doc = {
        "asset": {"version": "2.0"},
        "extensionsUsed": ["KHR_lights_punctual"],
        "scenes": [{"nodes": [0]}],
        "nodes": [{"children": [1, 2, 3], "translation": [0, 0, -2]},
                  {"mesh": 0, "scale": [2, 2, 2]},
                  {"translation": [0, 3, 0], "rotation": [-math.sqrt(0.5), 0, 0, math.sqrt(0.5)],  # -z to -y
                   "extensions": {"KHR_lights_punctual": {"light": 0}}},
                  {"camera": 0, "translation": [0.5, 0.5, 4]}],
        "cameras": [{"type": "orthographic", "orthographic": {"xmag": 2, "ymag": 1.5, "znear": 0.1, "zfar": 10}}],
        "extensions": {"KHR_lights_punctual": {"lights": [
            {"type": "spot", "color": [1, 0.5, 0.25], "intensity": 683, "spot": {"innerConeAngle": 0.2,
                                                                                  "outerConeAngle": 0.6}}]}},
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.6, 0.2, 1], "metallicFactor": 1,
                                                "roughnessFactor": 0.5}, "doubleSided": True}],
        "meshes": [m], "accessors": b.accessors, "bufferViews": b.views,
        "buffers": [{"byteLength": len(b.bin),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(bytes(b.bin)).decode()}],
    }
    open(os.path.join(OUT, "gltf_misc.gltf"), "w").write(json.dumps(doc, separators=(",", ":")))


# ---- base colour textures ----------------------------------------------------------------

def png_rgb(w, h, rows):
    """A minimal 8-bit RGB PNG (no filtering) of rows of (r, g, b) bytes."""
    import zlib
    raw = b"".join(b"\0" + bytes(c for px in row for c in px) for row in rows)
    chunk = lambda t, d: struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xffffffff)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)) +
            chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


TEX_N = 8
TEX_FACTOR = [0.9, 0.8, 0.7]
JPEG_FACTOR = [0.3, 0.6, 0.9]
TEX_QUAD = quad(1.0)
JPEG_QUAD = ([(x + 1.1, y, z) for x, y, z in TEX_QUAD[0]], TEX_QUAD[1], TEX_QUAD[2], TEX_QUAD[3])


def texture_rows():
    """8x8 texels of distinct colours: red across, green down, blue a checker."""
    return [[(32 * i + 16, 255 - 30 * j, 200 if (i + j) % 2 else 40) for i in range(TEX_N)] for j in range(TEX_N)]


def jpeg_rgb(w, h, rows):
    """A JPEG of rows of (r, g, b) bytes, by libstb (libstb-dev, a build dependency of nacre)."""
    import ctypes
    import tempfile
    lib = ctypes.CDLL("libstb.so")
    data = bytes(c for row in rows for px in row for c in px)
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "t.jpg")
        if not lib.stbi_write_jpg(path.encode(), w, h, 3, data, 100):
            raise RuntimeError("stbi_write_jpg failed")
        return open(path, "rb").read()


def write_textured():
    png = png_rgb(TEX_N, TEX_N, texture_rows())
    jpeg = jpeg_rgb(TEX_N, TEX_N, texture_rows())
    cam = {"name": "top", "camera": 0, "translation": [0.55, 2.0, 0.0],
           "rotation": quat_look([0, -1, 0], [0, 0, -1])}
    sun = {"name": "sun", "rotation": quat_look([-0.3, -1.0, -0.2], [0, 1, 0]),
           "extensions": {"KHR_lights_punctual": {"light": 0}}}

    def doc_for(b, meshes, images, textures, mats, nodes):
        return {"asset": {"version": "2.0", "generator": "nacre scripts/make_gltf_tests.py"},
                "extensionsUsed": ["KHR_lights_punctual"], "scenes": [{"nodes": list(range(len(nodes)))}],
                "nodes": nodes,
                "cameras": [{"type": "orthographic", "orthographic": {"xmag": 1.1, "ymag": 0.55, "znear": 0.1,
                                                                      "zfar": 10}}],
                "extensions": {"KHR_lights_punctual": {"lights": [
                    {"type": "directional", "color": [1, 1, 1], "intensity": 2.0 * LUMENS_PER_WATT}]}},
                "materials": mats, "meshes": meshes, "textures": textures, "images": images,
                "samplers": [{"wrapS": 10497, "wrapT": 10497}],
                "accessors": b.accessors, "bufferViews": b.views}

    def material(name, factor, tex):
        return {"name": name, "pbrMetallicRoughness": {"baseColorFactor": factor + [1], "metallicFactor": 0,
                                                       "roughnessFactor": 0.5, "baseColorTexture": {"index": tex}}}

    # The GLB: both quads, both images in the BIN chunk
    b = Builder()
    meshes = [b.mesh(TEX_QUAD, 0, "textured"), b.mesh(JPEG_QUAD, 1, "jpeg")]
    views = []
    for data in (png, jpeg):
        while len(b.bin) % 4:
            b.bin.append(0)
        b.views.append({"buffer": 0, "byteOffset": len(b.bin), "byteLength": len(data)})
        views.append(len(b.views) - 1)
        b.bin += data
    doc = doc_for(b, meshes, [{"bufferView": views[0], "mimeType": "image/png"},
                              {"bufferView": views[1], "mimeType": "image/jpeg"}],
                  [{"source": 0, "sampler": 0}, {"source": 1, "sampler": 0}],
                  [material("textured", TEX_FACTOR, 0), material("jpeg", JPEG_FACTOR, 1)],
                  [{"mesh": 0}, {"mesh": 1}, cam, sun])
    doc["buffers"] = [{"byteLength": len(b.bin)}]
    open(os.path.join(OUT, "gltf_textured.glb"), "wb").write(glb(doc, b.bin))

    # The .gltf: the textured quad, its image a file
    import base64
    b2 = Builder()
    doc2 = doc_for(b2, [b2.mesh(TEX_QUAD, 0, "textured")], [{"uri": "gltf_textured.png"}],
                   [{"source": 0, "sampler": 0}], [material("textured", TEX_FACTOR, 0)], [{"mesh": 0}, cam, sun])
    doc2["buffers"] = [{"byteLength": len(b2.bin),
                        "uri": "data:application/octet-stream;base64," + base64.b64encode(bytes(b2.bin)).decode()}]
    open(os.path.join(OUT, "gltf_textured.png"), "wb").write(png)
    open(os.path.join(OUT, "gltf_textured.jpg"), "wb").write(jpeg)
    open(os.path.join(OUT, "gltf_textured.gltf"), "w").write(json.dumps(doc2, separators=(",", ":")))

    # The same as a nacre scene: roughness 0.5 -> shininess 2 / 0.25^2 - 2 = 30, F0 0.04
    write_ply(os.path.join(OUT, "gltf_textured_quad.ply"), TEX_QUAD)
    write_ply(os.path.join(OUT, "gltf_textured_jpeg.ply"), JPEG_QUAD)
    sun_dir = [-0.3, -1.0, -0.2]
    scene = {
        "units": "m",
        "render": {"method": "phong", "width": 128, "height": 64},
        "environment": [0.1, 0.1, 0.1],
        "camera": {"type": "orthographic", "position": cam["translation"], "target": [0.55, 0.0, 0.0],
                   "up": [0, 0, -1], "height": 1.1, "near": 0.1, "far": 10},
        "materials": {"textured": {"type": "opaque", "diffuse": TEX_FACTOR, "specular": 0.04, "shininess": 30,
                                   "diffuse_map": "gltf_textured.png"},
                      "jpeg": {"type": "opaque", "diffuse": JPEG_FACTOR, "specular": 0.04, "shininess": 30,
                               "diffuse_map": "gltf_textured.jpg"}},
        "lights": [{"type": "directional", "direction": sun_dir, "irradiance": 2.0}],
        "objects": [{"name": "textured", "mesh": "gltf_textured_quad.ply", "material": "textured"},
                    {"name": "jpeg", "mesh": "gltf_textured_jpeg.ply", "material": "jpeg"}],
    }
    open(os.path.join(OUT, "gltf_textured.json"), "w").write(json.dumps(scene, indent=1) + "\n")


# ---- thickness texture as a one-layer depth map ---------------------------------------------

TH_FACTOR = 0.03  # metres: the layer's depth where G is 1
TH_N = 8


def uv_sphere(radius, segments, rings):
    """A UV sphere with uvs (u around, v from the north pole down, glTF's convention); the seam
    shares vertices (u jumps back to 0), harmless for maps that vary with latitude only."""
    pos, nrm, _, tri = sphere(radius, segments, rings)
    uv = [(0.5, 0.0)]
    for j in range(1, rings):
        uv += [(i / segments, j / rings) for i in range(segments)]
    uv.append((0.5, 1.0))
    return pos, nrm, uv, tri


def thickness_rows(copy_g_to_r):
    """Latitude bands in G (thickness), a ramp in R and a constant in B that the import ignores."""
    rows = []
    for j in range(TH_N):
        g = [230, 40, 160, 90, 250, 20, 130, 200][j]
        rows.append([((g if copy_g_to_r else 17 * i + 5), g, 99) for i in range(TH_N)])
    return rows


def write_thickness():
    geo = uv_sphere(0.1, 48, 24)
    png = png_rgb(TH_N, TH_N, thickness_rows(False))
    b = Builder()
    mesh = b.mesh(geo, 0, "ball")
    while len(b.bin) % 4:
        b.bin.append(0)
    b.views.append({"buffer": 0, "byteOffset": len(b.bin), "byteLength": len(png)})
    b.bin += png
    cam_at, target = [0.0, 0.12, 0.45], [0.0, 0.0, 0.0]
    fwd = [target[k] - cam_at[k] for k in range(3)]
    sun_dir = [-0.5, -0.6, -0.62]
    doc = {"asset": {"version": "2.0", "generator": "nacre scripts/make_gltf_tests.py"},
           "extensionsUsed": ["KHR_lights_punctual", "KHR_materials_volume", "KHR_materials_transmission"],
           "scenes": [{"nodes": [0, 1, 2]}],
           "nodes": [{"name": "ball", "mesh": 0},
                     {"name": "cam", "camera": 0, "translation": cam_at, "rotation": quat_look(fwd, [0, 1, 0])},
                     {"name": "sun", "rotation": quat_look(sun_dir, [0, 1, 0]),
                      "extensions": {"KHR_lights_punctual": {"light": 0}}}],
           "cameras": [{"type": "perspective", "perspective": {"yfov": math.radians(30), "znear": 0.01}}],
           "extensions": {"KHR_lights_punctual": {"lights": [
               {"type": "directional", "color": [1, 1, 1], "intensity": 3.0 * LUMENS_PER_WATT}]}},
           "materials": [{"name": "wax", "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1],
                                                                 "metallicFactor": 0, "roughnessFactor": 0.3},
                          "extensions": {"KHR_materials_volume": {
                              "thicknessFactor": TH_FACTOR, "thicknessTexture": {"index": 0},
                              "attenuationColor": ATT_COLOR, "attenuationDistance": 0.05},
                              "KHR_materials_transmission": {"transmissionFactor": 1.0}}}],
           "textures": [{"source": 0}], "images": [{"bufferView": len(b.views) - 1, "mimeType": "image/png"}],
           "meshes": [mesh], "accessors": b.accessors, "bufferViews": b.views,
           "buffers": [{"byteLength": len(b.bin)}]}
    open(os.path.join(OUT, "gltf_thickness.glb"), "wb").write(glb(doc, b.bin))
    write_ply(os.path.join(OUT, "gltf_thickness_ball.ply"), geo)
    open(os.path.join(OUT, "gltf_thickness_depth.png"), "wb").write(png_rgb(TH_N, TH_N, thickness_rows(True)))
    # The mapping of docs/scene-format.md: roughness 0.3 -> shininess 2 / 0.09^2 - 2, F0 0.04
    sigma_a = [-math.log(c) / 0.05 for c in ATT_COLOR]
    a = 0.3 * 0.3
    scene = {
        "units": "m",
        "render": {"method": "phong", "width": 64, "height": 48},
        "camera": {"type": "perspective", "position": cam_at, "target": target, "up": [0, 1, 0], "fov": 30,
                   "near": 0.01},
        "materials": {"wax": {"type": "translucent", "sigma_a": sigma_a, "sigma_s": [10.0] * 3, "g": 0,
                              "eta": 1.5, "specular": [0.04] * 3, "shininess": 2 / (a * a) - 2,
                              "depth_map": "gltf_thickness_depth.png",
                              "layers": [{"sigma_a": sigma_a, "sigma_s": [1000.0] * 3, "g": 0,
                                          "depth": TH_FACTOR}]}},
        "lights": [{"type": "directional", "direction": sun_dir, "irradiance": 3.0}],
        "objects": [{"name": "ball", "mesh": "gltf_thickness_ball.ply", "material": "wax"}],
    }
    open(os.path.join(OUT, "gltf_thickness.json"), "w").write(json.dumps(scene, indent=1) + "\n")


def main():
    os.makedirs(OUT, exist_ok=True)
    write_thickness()
    write_demo()
    write_misc()
    write_textured()
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
