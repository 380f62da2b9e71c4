#!/usr/bin/env python3
"""Writes the mesh files of scenes/mitsuba/scene.xml, the back wall as OBJ and a wedge
(a triangular prism) as binary PLY, the normal map of normalmap.xml and
textured_shapes.xml, the height field of bumpmap.xml, the emission texture of textured_light.xml's globe and the lattice
opacity of masked.xml. The scene files themselves are written by hand."""

import math
import struct
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
(HERE / "meshes").mkdir(exist_ok=True)
(HERE / "meshes" / "wall.obj").write_text(
    "# the back wall, facing +z\nv -2 0 -1.5\nv 2 0 -1.5\nv 2 3 -1.5\nv -2 3 -1.5\nf 1 2 3 4\n"
)
# A wedge: triangle ends at z = ±0.35, faces counter-clockwise seen from outside.
v = [(-0.4, 0, 0.35), (0.4, 0, 0.35), (-0.4, 0.6, 0.35), (-0.4, 0, -0.35), (0.4, 0, -0.35), (-0.4, 0.6, -0.35)]
faces = [(0, 1, 2), (3, 5, 4), (0, 3, 4, 1), (1, 4, 5, 2), (0, 2, 5, 3)]
# Mitsuba reads triangles only: quads become fans.
faces = [(f[0], f[k], f[k + 1]) for f in faces for k in range(1, len(f) - 1)]
header = (
    "ply\nformat binary_little_endian 1.0\ncomment a wedge for scenes/mitsuba\n"
    f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
    f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
)
body = b"".join(struct.pack("<3f", *p) for p in v)
body += b"".join(struct.pack("<B", len(f)) + struct.pack(f"<{len(f)}i", *f) for f in faces)
(HERE / "meshes" / "wedge.ply").write_bytes(header.encode() + body)

# The normal map of normalmap.xml: 8 x 8 texels, 8-bit RGB encoding (n + 1) / 2 of
# tangent-space normals. Columns tilt along u (left: -30°, right: +30°, the middle two
# columns flat), rows along v (top rows +20°, bottom rows -20°).
sys.path.insert(0, str(HERE.parents[1] / "tests" / "data"))
from make_data import png  # noqa: E402  (8-bit RGB PNG writer)


def texel(ax, ay):
    n = (math.tan(math.radians(ax)), math.tan(math.radians(ay)), 1.0)
    length = math.sqrt(sum(c * c for c in n))
    return tuple(round((c / length + 1) / 2 * 255) for c in n)


rows = []
for y in range(8):
    ay = 20 if y < 3 else (-20 if y > 4 else 0)
    rows.append([texel(-30 if x < 3 else (30 if x > 4 else 0), ay) for x in range(8)])
(HERE / "meshes" / "bumps.png").write_bytes(png(8, 8, rows))

# The height field of bumpmap.xml: 16 x 16 texels, grey, 8-bit, two periods of a wave
# along u times one along v, (1 + sin(4 pi x / 16) cos(2 pi y / 16)) / 2.
heights = []
for y in range(16):
    row = []
    for x in range(16):
        h = round((1 + math.sin(4 * math.pi * (x + 0.5) / 16) * math.cos(2 * math.pi * (y + 0.5) / 16)) / 2 * 255)
        row.append((h, h, h))
    heights.append(row)
(HERE / "meshes" / "heights.png").write_bytes(png(16, 16, heights))

# The glowing band of textured_light.xml's globe: 32 x 16 texels, black but for three rows
# (warm on one half of the circumference, cool on the other).
band = [[(0, 0, 0)] * 32 for _ in range(16)]
for y in range(7, 10):
    band[y] = [(255, 180, 90)] * 16 + [(90, 160, 255)] * 16
(HERE / "meshes" / "band.png").write_bytes(png(32, 16, band))

# The lattice of masked.xml's card: 16 x 16 texels, opaque (white) bars two texels wide
# (rows and columns 1-2, 5-6, ...) and holes (black) of 2 x 2 texels between them and
# along the border; the bars of the bottom quarter are grey (opacity 0.5). Large texels:
# the bilinear lookup ramps across a bar's edge over a whole texel, which Mitsuba's mask
# and a blend treat alike, a ray passing through with probability 1 - opacity.
def lattice_texel(x, y):
    if x % 4 not in (1, 2) and y % 4 not in (1, 2):
        return (0,) * 3
    return (188,) * 3 if y >= 12 else (255,) * 3  # sRGB 188: linear 0.5


lattice = [[lattice_texel(x, y) for x in range(16)] for y in range(16)]
(HERE / "meshes" / "lattice.png").write_bytes(png(16, 16, lattice))


def radiance_hdr(width, height, rows):
    """A Radiance HDR (RGBE) file from rows of linear (r, g, b) floats, scanlines stored
    flat (not run-length encoded), as Walter's rgbe.c writes and reads them: the largest
    component's binary exponent shared, each mantissa truncated to 8 bits."""
    body = bytearray()
    for row in rows:
        for px in row:
            v = max(px)
            if v < 1e-32:
                body += bytes(4)
                continue
            m, e = math.frexp(v)
            scale = m * 256 / v
            body += bytes(int(c * scale) for c in px) + bytes([e + 128])
    header = f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {height} +X {width}\n".encode()
    return header + bytes(body)


# The sky of envmap.xml: 64 x 32 texels in Mitsuba's layout (column 0 towards -z, rows
# from the zenith to the nadir), a blue sky brightening to a white horizon over a brown
# ground, a sun of 2 x 2 texels and a red band on the horizon a quarter-turn from it, so
# that a wrong rotation, mirror or half-texel shift moves light, shadows and colour.
def sky_texel(x, y):
    t = y / 31  # 0 at the zenith, 1 at the nadir
    if t > 0.5:
        return (0.12, 0.1, 0.08)
    k = t / 0.5
    px = (0.25 + 0.75 * k, 0.4 + 0.55 * k, 0.9 + 0.1 * k)
    if y in (8, 9) and x in (20, 21):
        px = (60.0, 52.0, 40.0)
    if 12 <= y <= 15 and 36 <= x <= 43:
        px = (2.0, 0.25, 0.1)
    return px


sky = [[sky_texel(x, y) for x in range(64)] for y in range(32)]
(HERE / "meshes" / "sky.hdr").write_bytes(radiance_hdr(64, 32, sky))
