#!/usr/bin/env python3
"""Writes the mesh files of scenes/mitsuba/scene.xml: the back wall as OBJ and a wedge
(a triangular prism) as binary PLY. The scene file itself is written by hand."""

import struct
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
