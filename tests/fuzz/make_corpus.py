#!/usr/bin/env python3
"""Write the generated part of the seed corpus of the fuzz targets (standard library only).

tests/fuzz/corpus/<target>/ holds small valid inputs libFuzzer starts from. Files copied from the
repository (examples/*.json, tests/data meshes, examples/hetero_density.nrrd) keep their names;
the files written here start with "gen-" and are tiny on purpose, so that mutations reach every
part of a file instead of spending themselves on pixel or vertex data:

  mesh       ASCII PLY with normals, uvs and a quad; binary PLY in both byte orders; a GLB
  image      PNG 8-bit RGBA, 16-bit RGB, grey+alpha, palette with tRNS; JPEG colour (4:4:4) and
             grey (libstb's encoder); EXR half RGBA and float
             RGB uncompressed, half RGB ZIP-compressed, luminance Y
  nrrd       uint8 with "spacings", 4D big-endian float with a channel axis, int16 with
             "byte skip", double with space origin and directions
  depth_map  RGBA 8-bit and RGB 16-bit PNG depth maps, a float RGBA EXR

Crash inputs added later are kept as they were found (named crash-<what>), not written here.
Run from anywhere: python3 tests/fuzz/make_corpus.py
"""
import json
import math
import os
import shutil
import struct
import zlib

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
CORPUS = os.path.join(HERE, "corpus")


def put(target, name, data):
    d = os.path.join(CORPUS, target)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def copy(target, src):
    d = os.path.join(CORPUS, target)
    os.makedirs(d, exist_ok=True)
    shutil.copyfile(os.path.join(ROOT, src), os.path.join(d, os.path.basename(src)))


# ---- meshes -------------------------------------------------------------------------------

# A tetrahedron with one face split in two by a quad's worth of corners (so polygons appear).
VERTS = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
UVS = [(0, 0), (1, 0), (0, 1), (0.5, 0.5)]
FACES = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]


def ply_ascii():
    lines = ["ply", "format ascii 1.0", "comment nacre fuzz seed", "element vertex 4",
             "property float x", "property float y", "property float z",
             "property float nx", "property float ny", "property float nz",
             "property float s", "property float t", "element face 5",
             "property list uchar int vertex_indices", "end_header"]
    for (x, y, z), (s, t) in zip(VERTS, UVS):
        n = math.sqrt(x * x + y * y + z * z) or 1.0
        lines.append(f"{x} {y} {z} {x / n:.4f} {y / n:.4f} {z / n:.4f} {s} {t}")
    for f in FACES:
        lines.append("3 " + " ".join(map(str, f)))
    lines.append("4 0 1 2 3")
    return ("\n".join(lines) + "\n").encode()


def ply_binary(big):
    order = ">" if big else "<"
    head = ["ply", f"format binary_{'big' if big else 'little'}_endian 1.0", "element vertex 4",
            "property float x", "property float y", "property float z", "property uchar red",
            "element face 4", "property list uchar uint vertex_indices", "end_header"]
    body = b"".join(struct.pack(order + "fffB", *v, 200) for v in VERTS)
    body += b"".join(struct.pack(order + "B3I", 3, *f) for f in FACES)
    return ("\n".join(head) + "\n").encode() + body


def glb():
    pos = b"".join(struct.pack("<3f", *v) for v in VERTS)
    uv = b"".join(struct.pack("<2f", *t) for t in UVS)
    idx = b"".join(struct.pack("<3H", *f) for f in FACES)
    binary = pos + uv + idx
    binary += b"\0" * (-len(binary) % 4)
    gltf = ('{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],'
            '"nodes":[{"mesh":0,"rotation":[0,0.7071068,0,0.7071068]}],'
            '"meshes":[{"primitives":[{"attributes":{"POSITION":0,"TEXCOORD_0":1},"indices":2}]}],'
            '"accessors":[{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3",'
            '"min":[0,0,0],"max":[1,1,1]},'
            '{"bufferView":1,"componentType":5126,"count":4,"type":"VEC2"},'
            '{"bufferView":2,"componentType":5123,"count":12,"type":"SCALAR"}],'
            '"bufferViews":[{"buffer":0,"byteOffset":0,"byteLength":48},'
            '{"buffer":0,"byteOffset":48,"byteLength":32},'
            '{"buffer":0,"byteOffset":80,"byteLength":24}],'
            f'"buffers":[{{"byteLength":{len(binary)}}}]}}').encode()
    gltf += b" " * (-len(gltf) % 4)
    chunks = struct.pack("<I4s", len(gltf), b"JSON") + gltf + struct.pack("<I4s", len(binary), b"BIN\0") + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


# ---- PNG ----------------------------------------------------------------------------------

def png(width, height, color_type, depth, rows, extra=b""):
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    raw = b"".join(b"\0" + r for r in rows)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, depth, color_type, 0, 0, 0))
            + extra + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


def png_rgba8(w, h, f):
    return png(w, h, 6, 8, [bytes(c for x in range(w) for c in f(x, y)) for y in range(h)])


def png_rgb16(w, h, f):
    return png(w, h, 2, 16, [b"".join(struct.pack(">3H", *f(x, y)) for x in range(w)) for y in range(h)])


def png_grey_alpha(w, h):
    return png(w, h, 4, 8, [bytes(v for x in range(w) for v in (x * 60 % 256, 255 - y * 40)) for y in range(h)])


def png_palette(w, h):
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    extra = chunk(b"PLTE", bytes([255, 0, 0, 0, 255, 0, 0, 0, 255])) + chunk(b"tRNS", bytes([255, 128]))
    return png(w, h, 3, 8, [bytes((x + y) % 3 for x in range(w)) for y in range(h)], extra)


# ---- EXR (scanline, single part) ------------------------------------------------------------

HALF, FLOAT = 1, 2
NO_COMPRESSION, ZIPS_COMPRESSION = 0, 2


def jpeg(w, h, comp, quality, f):
    """A JPEG by Debian libstb's stbi_write_jpg (libstb-dev is a build dependency of nacre)."""
    import ctypes
    import tempfile
    lib = ctypes.CDLL("libstb.so")
    data = bytes(c for y in range(h) for x in range(w) for c in f(x, y)[:comp])
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "t.jpg")
        if not lib.stbi_write_jpg(path.encode(), w, h, comp, data, quality):
            raise RuntimeError("stbi_write_jpg failed")
        return open(path, "rb").read()


def exr_attr(name, kind, value):
    return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value


def exr_zip(raw):
    # OpenEXR's ZIP: bytes split into even and odd halves, then a delta predictor, then zlib.
    t = bytearray(raw[0::2] + raw[1::2])
    prev = t[0] if t else 0
    for i in range(1, len(t)):
        cur = t[i]
        t[i] = (cur - prev + 128 + 256) & 0xFF
        prev = cur
    packed = zlib.compress(bytes(t), 9)
    return packed if len(packed) < len(raw) else raw


def exr(width, height, channels, ptype, compression, f):
    """channels: names (written sorted, as EXR requires); f(x, y, name) -> value."""
    names = sorted(channels)
    chlist = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", ptype, 0, 1, 1) for n in names) + b"\0"
    box = struct.pack("<4i", 0, 0, width - 1, height - 1)
    header = (exr_attr("channels", "chlist", chlist) + exr_attr("compression", "compression", bytes([compression]))
              + exr_attr("dataWindow", "box2i", box) + exr_attr("displayWindow", "box2i", box)
              + exr_attr("lineOrder", "lineOrder", b"\0") + exr_attr("pixelAspectRatio", "float", struct.pack("<f", 1))
              + exr_attr("screenWindowCenter", "v2f", struct.pack("<2f", 0, 0))
              + exr_attr("screenWindowWidth", "float", struct.pack("<f", 1)) + b"\0")
    fmt = "<e" if ptype == HALF else "<f"
    chunks = []
    for y in range(height):
        raw = b"".join(struct.pack(fmt, f(x, y, n)) for n in names for x in range(width))
        data = exr_zip(raw) if compression == ZIPS_COMPRESSION else raw
        chunks.append(struct.pack("<ii", y, len(data)) + data)
    start = 8 + len(header) + 8 * height
    offsets, at = [], start
    for c in chunks:
        offsets.append(at)
        at += len(c)
    return (b"\x76\x2f\x31\x01" + struct.pack("<I", 2) + header + b"".join(struct.pack("<Q", o) for o in offsets)
            + b"".join(chunks))


def colour(x, y, n):
    return {"R": 0.25 * x, "G": 0.5 + 0.1 * y, "B": 1.0 / (1 + x + y), "A": 1.0, "Y": 0.3 * (x + y)}[n]


# ---- NRRD ---------------------------------------------------------------------------------

def nrrd(header_lines, body):
    return ("NRRD0004\n" + "\n".join(header_lines) + "\n\n").encode() + body


# Examples whose commit is heavy: particles.json splats 10k large particles into 128^3 (100M
# additions, 70 ms in a release build), which under the fuzz build's sanitizers and coverage
# takes seconds, and its mutations reached the 10 s timeout. gen-particles.json stands in (for
# particles_iso.json too: 11M additions into 96^3 and a ray-marched isosurface).
HEAVY_EXAMPLES = {"particles.json", "particles_iso.json"}

PARTICLES_SEED = {
    "materials": {"m": {"type": "opaque"}},
    "objects": [{"shape": {"type": "plane", "size": [10, 10]}, "material": "m"}],
    "render": {"time": 1.0},
    "particles": [
        {"type": "emitter", "shape": "sphere", "center": [0, 1, 0], "emit_radius": 0.5, "rate": 40,
         "lifetime": 2, "velocity": [0, 2, 0], "spread": 15, "gravity": [0, -1, 0], "drag": 0.3,
         "radius": 0.3, "radius_rate": 0.1, "fade": 0.5, "seed": 3, "sigma_s": 0.5, "grid_resolution": 16},
        {"type": "list", "positions": [[0, 2, 0], [1, 2, 0.5]], "radii": [0.4, 0.6], "density": 2,
         "sigma_s": 0.5, "grid_resolution": 12, "isosurface": {"density": 1, "ior": 1.4, "roughness": 0.2}}]}


def main():
    for name in sorted(os.listdir(os.path.join(ROOT, "examples"))):
        if name.endswith(".json") and name not in HEAVY_EXAMPLES:
            copy("scene", os.path.join("examples", name))
    put("scene", "gen-particles.json", json.dumps(PARTICLES_SEED, indent=1).encode())

    copy("mesh", "tests/data/quad_cube.obj")
    copy("mesh", "tests/data/tetra_nodes.gltf")
    copy("mesh", "tests/data/gltf_pair.glb")
    copy("mesh", "tests/data/gltf_misc.gltf")
    put("mesh", "gen-tetra-ascii.ply", ply_ascii())
    put("mesh", "gen-tetra-le.ply", ply_binary(False))
    put("mesh", "gen-tetra-be.ply", ply_binary(True))
    put("mesh", "gen-tetra.glb", glb())

    put("image", "gen-rgba8.png", png_rgba8(4, 3, lambda x, y: (x * 60, y * 80, 128, 255 - x * 20)))
    put("image", "gen-rgb16.png", png_rgb16(3, 2, lambda x, y: (x * 20000, y * 30000, 65535)))
    put("image", "gen-grey-alpha.png", png_grey_alpha(3, 3))
    put("image", "gen-palette.png", png_palette(4, 2))
    put("image", "gen-rgb.jpg", jpeg(9, 8, 3, 100, lambda x, y: (x * 28, y * 30, 128)))
    put("image", "gen-grey.jpg", jpeg(16, 8, 1, 50, lambda x, y: ((x * 16 + y * 8) % 256,)))
    put("image", "gen-half-rgba.exr", exr(4, 3, "RGBA", HALF, NO_COMPRESSION, colour))
    put("image", "gen-float-rgb.exr", exr(3, 2, "RGB", FLOAT, NO_COMPRESSION, colour))
    put("image", "gen-half-rgb-zip.exr", exr(8, 2, "RGB", HALF, ZIPS_COMPRESSION, colour))
    put("image", "gen-half-y.exr", exr(3, 3, "Y", HALF, NO_COMPRESSION, colour))

    copy("nrrd", "examples/hetero_density.nrrd")
    put("nrrd", "gen-u8-spacings.nrrd",
        nrrd(["type: uint8", "dimension: 3", "sizes: 2 3 2", "encoding: raw", "spacings: 1 0.5 2"], bytes(range(0, 240, 20))))
    put("nrrd", "gen-f32-be-channels.nrrd",
        nrrd(["type: float", "dimension: 4", "sizes: 2 2 2 2", "endian: big", "encoding: raw",
              "space dimension: 3", "space origin: (1,2,3)",
              "space directions: none (0.5,0,0) (0,0.5,0) (0,0,0.5)", "kinds: vector space space space"],
             b"".join(struct.pack(">f", 0.125 * i) for i in range(16))))
    put("nrrd", "gen-i16-byteskip.nrrd",
        nrrd(["type: short", "dimension: 3", "sizes: 2 2 1", "endian: little", "encoding: raw", "byte skip: 4",
              "spacings: 1 1 1"], b"skip" + b"".join(struct.pack("<h", v) for v in (0, 100, 2000, 30000))))
    put("nrrd", "gen-f64-origin.nrrd",
        nrrd(["type: double", "dimension: 3", "sizes: 1 2 2", "endian: little", "encoding: raw",
              "space: right-anterior-superior", "space origin: (-1,-1,-1)",
              "space directions: (2,0,0) (0,2,0) (0,0,2)"],
             b"".join(struct.pack("<d", v) for v in (0.0, 0.5, 1.0, 4.0))))

    def depth(x, y):
        return (255, 255 if y == 1 else 0, 150 + 25 * x, 255)
    put("depth_map", "gen-rgba8.png", png_rgba8(4, 4, depth))
    put("depth_map", "gen-rgb16.png", png_rgb16(4, 2, lambda x, y: (65535, 30000 * (x % 2), 40000 + 5000 * y)))
    put("depth_map", "gen-float-rgba.exr",
        exr(4, 2, "RGBA", FLOAT, NO_COMPRESSION, lambda x, y, n: {"R": 1.0, "G": 0.5 * x, "B": 0.25 + y, "A": 2.0}[n]))


if __name__ == "__main__":
    main()
