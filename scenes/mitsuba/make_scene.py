#!/usr/bin/env python3
"""Writes the mesh files of scenes/mitsuba/scene.xml, the back wall as OBJ and a wedge
(a triangular prism) as binary PLY, the normal map of normalmap.xml and
textured_shapes.xml, the emission texture of textured_light.xml's globe and the lattice
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
