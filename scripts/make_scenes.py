#!/usr/bin/env python3
"""Writes the meshes and reference textures of the bundled scenes `ajar` and `glossy`
(standard library only; run from the repository root: python3 scripts/make_scenes.py).

  ajar:   a closed room lit by an area light outside it through a door left ajar, so that
          the textured back wall receives almost only indirect light (the situation of the
          "Veach Ajar" texture experiment of Bálint et al. 2023);
  glossy: a metal sphere whose roughness varies over its surface, a roughness texture to
          recover (the case where roughness gradients are hard to estimate);
  gap:    a closed box whose only light is a small one-sided area light 2 cm under the
          ceiling, facing the ceiling: light reaches the room only off the ceiling through
          that gap, so the image is carried by rare bright paths (a gradient check where
          variance is large and any correlation between the residual image and the
          adjoint's paths shows as bias).

The outputs are committed; the script documents how they were made and regenerates them
bit for bit.
"""

import math
import struct
from pathlib import Path


def write_exr(path, width, height, pixel):
    """Uncompressed scanline OpenEXR with float R, G, B channels; pixel(x, y) -> (r, g, b),
    y = 0 is the top row."""

    def attr(name, kind, data):
        return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(data)) + data

    chlist = b"".join(c.encode() + b"\0" + struct.pack("<iBBBBii", 2, 0, 0, 0, 0, 1, 1) for c in "BGR") + b"\0"
    box = struct.pack("<iiii", 0, 0, width - 1, height - 1)
    header = (
        struct.pack("<ii", 20000630, 2)
        + attr("channels", "chlist", chlist)
        + attr("compression", "compression", b"\0")
        + attr("dataWindow", "box2i", box)
        + attr("displayWindow", "box2i", box)
        + attr("lineOrder", "lineOrder", b"\0")
        + attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
        + attr("screenWindowCenter", "v2f", struct.pack("<ff", 0.0, 0.0))
        + attr("screenWindowWidth", "float", struct.pack("<f", 1.0))
        + b"\0"
    )
    line_bytes = 3 * 4 * width
    first = len(header) + 8 * height
    offsets = b"".join(struct.pack("<Q", first + y * (8 + line_bytes)) for y in range(height))
    lines = []
    for y in range(height):
        px = [pixel(x, y) for x in range(width)]
        data = b"".join(struct.pack(f"<{width}f", *[p[c] for p in px]) for c in (2, 1, 0))
        lines.append(struct.pack("<ii", y, len(data)) + data)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(header + offsets + b"".join(lines))


def write_obj(path, comment, positions, faces, uvs=None, normals=None):
    """faces: lists of 1-based vertex indices (counter-clockwise seen from the front); uvs
    and normals, when given, are indexed like the positions."""
    out = [f"# {comment}"]
    out += [f"v {x:.6g} {y:.6g} {z:.6g}" for x, y, z in positions]
    if uvs:
        out += [f"vt {u:.6g} {v:.6g}" for u, v in uvs]
    if normals:
        out += [f"vn {x:.6g} {y:.6g} {z:.6g}" for x, y, z in normals]
    for f in faces:
        if uvs and normals:
            out.append("f " + " ".join(f"{i}/{i}/{i}" for i in f))
        elif uvs:
            out.append("f " + " ".join(f"{i}/{i}" for i in f))
        else:
            out.append("f " + " ".join(str(i) for i in f))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(out) + "\n")


def quad(path, comment, a, b, c, d, uv=False):
    """One quad a, b, c, d, counter-clockwise seen from the side it faces (`comment` names
    that side as "facing +x" and so on, which is checked)."""
    e1 = [q - p for p, q in zip(a, b)]
    e2 = [q - p for p, q in zip(a, c)]
    n = (e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0])
    axis = max(range(3), key=lambda k: abs(n[k]))
    facing = ("+" if n[axis] > 0 else "-") + "xyz"[axis]
    assert f"facing {facing}" in comment, f"{path}: the quad faces {facing}, not as its comment says"
    uvs = [(0, 0), (1, 0), (1, 1), (0, 1)] if uv else None
    write_obj(path, comment, [a, b, c, d], [[1, 2, 3, 4]], uvs=uvs)


def ajar(root):
    m = root / "meshes"
    # The room spans x, z in [-1, 1], y in [0, 2]; every wall faces inwards.
    quad(m / "floor.obj", "floor, y = 0, facing +y", (-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1))
    quad(m / "ceiling.obj", "ceiling, y = 2, facing -y", (-1, 2, -1), (1, 2, -1), (1, 2, 1), (-1, 2, 1))
    quad(m / "back.obj", "textured back wall, z = -1, facing +z; u along +x, v along +y", (-1, 0, -1), (1, 0, -1), (1, 2, -1), (-1, 2, -1), uv=True)
    quad(m / "front.obj", "front wall behind the camera, z = 1, facing -z", (1, 0, 1), (-1, 0, 1), (-1, 2, 1), (1, 2, 1))
    quad(m / "right.obj", "right wall, x = 1, facing -x", (1, 0, -1), (1, 0, 1), (1, 2, 1), (1, 2, -1))
    # Left wall, x = -1, facing +x, with a door gap z in [DOOR0, DOOR1], y in [0, DOOR_TOP].
    door0, door1, top = -0.2, -0.05, 1.6
    pieces = [
        ((-1, 0, -1), (-1, 0, door0), (-1, 2, door0), (-1, 2, -1)),
        ((-1, 0, door1), (-1, 0, 1), (-1, 2, 1), (-1, 2, door1)),
        ((-1, top, door0), (-1, top, door1), (-1, 2, door1), (-1, 2, door0)),
    ]
    positions = [p for piece in pieces for p in piece]
    faces = [[4 * k + 1, 4 * k + 2, 4 * k + 3, 4 * k + 4] for k in range(len(pieces))]
    write_obj(m / "left.obj", f"left wall, x = -1, facing +x, door gap z in [{door0}, {door1}], y < {top}", positions, faces)
    # The light: outside, beyond the door, facing the room (+x), tilted towards the back.
    quad(m / "light.obj", "area light outside the door, x = -1.6, facing +x", (-1.6, 0.2, 0.7), (-1.6, 0.2, -0.9), (-1.6, 1.8, -0.9), (-1.6, 1.8, 0.7))
    # Reference albedo: tiles of four colours with a darker grout, 32 x 32 texels.
    colours = [(0.75, 0.3, 0.15), (0.2, 0.45, 0.7), (0.8, 0.75, 0.35), (0.3, 0.6, 0.3)]

    def albedo(x, y):
        if x % 8 == 0 or y % 8 == 0:
            return (0.1, 0.1, 0.1)
        return colours[((x // 8) + 2 * (y // 8)) % 4]

    write_exr(root / "textures" / "albedo.exr", 32, 32, albedo)


def sphere(path, comment, centre, radius, seg_u, seg_v):
    """UV sphere with normals; u around the y axis, v from the bottom (0) to the top (1)."""
    positions, uvs, normals, faces = [], [], [], []
    for j in range(seg_v + 1):
        v = j / seg_v
        theta = math.pi * (1.0 - v)
        for i in range(seg_u + 1):
            u = i / seg_u
            phi = 2.0 * math.pi * u
            n = (math.sin(theta) * math.cos(phi), math.cos(theta), -math.sin(theta) * math.sin(phi))
            positions.append(tuple(c + radius * x for c, x in zip(centre, n)))
            normals.append(n)
            uvs.append((u, v))
    row = seg_u + 1
    for j in range(seg_v):
        for i in range(seg_u):
            a = j * row + i + 1
            b, c, d = a + 1, a + row + 1, a + row
            if j > 0:
                faces.append([a, b, c])
            if j < seg_v - 1:
                faces.append([a, c, d])
    write_obj(path, comment, positions, faces, uvs=uvs, normals=normals)


def glossy(root):
    m = root / "meshes"
    sphere(m / "sphere.obj", "UV sphere, radius 0.6 at (0, 0.6, 0), 32 x 16 segments", (0.0, 0.6, 0.0), 0.6, 32, 16)
    quad(m / "floor.obj", "floor, y = 0, facing +y; tiled by its texture", (-3, 0, 3), (3, 0, 3), (3, 0, -3), (-3, 0, -3), uv=True)
    quad(m / "light.obj", "area light above and in front of the sphere, facing -y", (-0.6, 2.2, 0.2), (0.6, 2.2, 0.2), (0.6, 2.2, 1.4), (-0.6, 2.2, 1.4))

    def floor(x, y):
        v = 0.7 if (x // 4 + y // 4) % 2 == 0 else 0.1
        return (v, v, v)

    write_exr(root / "textures" / "checker.exr", 32, 32, floor)

    def roughness(x, y):
        # Bands around the sphere (u) from polished to rough, and a smoother cap.
        r = 0.1 + 0.5 * (0.5 - 0.5 * math.cos(2.0 * math.pi * (x + 0.5) / 8.0))
        if y < 2:
            r = 0.15
        return (r, r, r)

    write_exr(root / "textures" / "roughness.exr", 8, 8, roughness)


def box(path, comment, lo, hi):
    """An axis-aligned box standing on the floor, its five visible faces facing outwards
    (no bottom face)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    positions = [(x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1), (x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1)]
    faces = [
        [5, 8, 7, 6],  # top, facing +y
        [4, 3, 7, 8],  # front, facing +z
        [2, 1, 5, 6],  # back, facing -z
        [3, 2, 6, 7],  # right, facing +x
        [1, 4, 8, 5],  # left, facing -x
    ]
    write_obj(path, comment, positions, faces)


def gap(root):
    m = root / "meshes"
    # The room spans x, z in [-1, 1], y in [0, 2]; every wall faces inwards; the camera
    # stands inside, in front of the front wall.
    quad(m / "floor.obj", "floor, y = 0, facing +y", (-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1))
    quad(m / "ceiling.obj", "ceiling, y = 2, facing -y", (-1, 2, -1), (1, 2, -1), (1, 2, 1), (-1, 2, 1))
    quad(m / "back.obj", "back wall, z = -1, facing +z", (-1, 0, -1), (1, 0, -1), (1, 2, -1), (-1, 2, -1))
    quad(m / "front.obj", "front wall behind the camera, z = 1, facing -z", (1, 0, 1), (-1, 0, 1), (-1, 2, 1), (1, 2, 1))
    quad(m / "left.obj", "left wall, x = -1, facing +x", (-1, 0, 1), (-1, 0, -1), (-1, 2, -1), (-1, 2, 1))
    quad(m / "right.obj", "right wall, x = 1, facing -x", (1, 0, -1), (1, 0, 1), (1, 2, 1), (1, 2, -1))
    box(m / "block.obj", "grey block on the floor, x in [0.15, 0.65], z in [-0.7, -0.2], 0.6 high", (0.15, 0, -0.7), (0.65, 0.6, -0.2))
    # The light: 0.3 x 0.3, 2 cm under the ceiling, emitting upwards only.
    quad(m / "light.obj", "area light 2 cm under the ceiling, y = 1.98, facing +y", (-0.15, 1.98, 0.15), (0.15, 1.98, 0.15), (0.15, 1.98, -0.15), (-0.15, 1.98, -0.15))


if __name__ == "__main__":
    ajar(Path("scenes/ajar"))
    glossy(Path("scenes/glossy"))
    gap(Path("scenes/gap"))
