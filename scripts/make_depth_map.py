#!/usr/bin/env python3
"""Write examples/layered_depth.png, the depth map of examples/layered.json (standard library only).

Channels (data, value / 255; each scales its layer's "depth", see docs/scene-format.md):
  R  epidermis: constant 1 (a layer of constant thickness)
  G  veins: 1 on a few wavy lines across the map, 0 elsewhere (the vein layer exists only there)
  B  dermis: 1 with a slow ripple down to 0.6 (thickness varies smoothly)
  A  unused by the example's three layers: 1
"""
import math
import os
import struct
import sys
import zlib

W, H = 256, 128


def texel(x, y):
    u, v = (x + 0.5) / W, 1.0 - (y + 0.5) / H
    r = 1.0
    g = 0.0
    for k, (phase, amp, freq) in enumerate(((0.1, 0.08, 2), (0.45, 0.05, 3), (0.8, 0.07, 1))):
        centre = phase + amp * math.sin(2 * math.pi * freq * u + k)
        d = abs(v - centre)
        g = max(g, max(0.0, 1.0 - d / 0.025))  # ~6 texels wide, soft edges
    b = 0.8 + 0.2 * math.cos(2 * math.pi * 2 * u) * math.cos(2 * math.pi * 3 * v)
    return [round(255 * min(1.0, max(0.0, c))) for c in (r, g, b, 1.0)]


def png(path):
    raw = b"".join(b"\x00" + bytes(c for x in range(W) for c in texel(x, y)) for y in range(H))

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    out = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", W, H, 8, 6, 0, 0, 0))
    out += chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(out)
    os.replace(tmp, path)


if __name__ == "__main__":
    here = os.path.dirname(os.path.abspath(__file__))
    png(sys.argv[1] if len(sys.argv) > 1 else os.path.join(here, "..", "examples", "layered_depth.png"))
