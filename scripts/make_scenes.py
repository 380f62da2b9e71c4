#!/usr/bin/env python3
"""Writes the generated files of the repository's scenes: meshes, textures and the small
test scenes. The outputs are committed; this script documents how they were made and
regenerates them bit for bit. Standard library only, run from anywhere:

  python3 scripts/make_scenes.py              every group
  python3 scripts/make_scenes.py GROUP...     the named groups (--help lists them)
"""

import argparse
import base64
import json
import math
import struct
import sys
import textwrap
import zlib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------------------------------
# Writers shared by every group.


def write(path, data):
    """Writes bytes or text (UTF-8) to path, creating its folder."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data.encode() if isinstance(data, str) else data)


def grid(width, height, texel):
    """Rows of an image, top row first, from texel(x, y)."""
    return [[texel(x, y) for x in range(width)] for y in range(height)]


def png(rows):
    """An 8-bit RGB PNG from rows of (r, g, b) byte triples."""
    raw = b"".join(b"\0" + bytes(c for px in row for c in px) for row in rows)

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    header = struct.pack(">IIBBBBB", len(rows[0]), len(rows), 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


def exr(rows):
    """An uncompressed scanline OpenEXR with float R, G, B channels from rows of linear
    (r, g, b) floats."""

    def attr(name, kind, data):
        return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(data)) + data

    width, height = len(rows[0]), len(rows)
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
    for y, row in enumerate(rows):
        data = b"".join(struct.pack(f"<{width}f", *[p[c] for p in row]) for c in (2, 1, 0))
        lines.append(struct.pack("<ii", y, len(data)) + data)
    return header + offsets + b"".join(lines)


def rgbe(rows):
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
    header = f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {len(rows)} +X {len(rows[0])}\n".encode()
    return header + bytes(body)


def npy(shape, values):
    """A little-endian float32 NumPy array file (format 1.0, C order) of `shape` from a flat
    list of values."""
    header = "{'descr': '<f4', 'fortran_order': False, 'shape': (%s), }" % (", ".join(str(n) for n in shape) + ("," if len(shape) == 1 else ""))
    header += " " * (-(10 + len(header) + 1) % 64) + "\n"
    assert len(values) == math.prod(shape)
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode("latin1") + struct.pack(f"<{len(values)}f", *values)


def write_obj(path, comment, positions, faces, uvs=None, normals=None):
    """faces: lists of 1-based vertex indices (counter-clockwise seen from the front); uvs
    and normals, when given, are indexed like the positions; no comment line when comment
    is None."""
    out = [] if comment is None else [f"# {comment}"]
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
    write(path, "\n".join(out) + "\n")


def write_ply(path, comment, positions, faces):
    """A binary little-endian PLY; faces: lists of 0-based vertex indices, written as
    triangle fans (Mitsuba reads triangles only)."""
    faces = [(f[0], f[k], f[k + 1]) for f in faces for k in range(1, len(f) - 1)]
    header = (
        f"ply\nformat binary_little_endian 1.0\ncomment {comment}\n"
        f"element vertex {len(positions)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    body = b"".join(struct.pack("<3f", *p) for p in positions)
    body += b"".join(struct.pack("<B", len(f)) + struct.pack(f"<{len(f)}i", *f) for f in faces)
    write(path, header.encode() + body)


# Texture coordinates of a quad's corners (OBJ convention: v up).
QUAD_UVS = [(0, 0), (1, 0), (1, 1), (0, 1)]


def quad(path, comment, a, b, c, d, uv=False):
    """One quad a, b, c, d, counter-clockwise seen from the side it faces (`comment` names
    that side as "facing +x" and so on, which is checked; no check without a comment)."""
    if comment is not None:
        e1 = [q - p for p, q in zip(a, b)]
        e2 = [q - p for p, q in zip(a, c)]
        n = (e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0])
        axis = max(range(3), key=lambda k: abs(n[k]))
        facing = ("+" if n[axis] > 0 else "-") + "xyz"[axis]
        assert f"facing {facing}" in comment, f"{path}: the quad faces {facing}, not as its comment says"
    write_obj(path, comment, [a, b, c, d], [[1, 2, 3, 4]], uvs=QUAD_UVS if uv else None)


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


def room(m, back_comment="back wall, z = -1, facing +z", back_uv=False, left=True):
    """The walls of a room spanning x, z in [-1, 1], y in [0, 2], every wall facing
    inwards, into folder m (the left wall only when `left`)."""
    quad(m / "floor.obj", "floor, y = 0, facing +y", (-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1))
    quad(m / "ceiling.obj", "ceiling, y = 2, facing -y", (-1, 2, -1), (1, 2, -1), (1, 2, 1), (-1, 2, 1))
    quad(m / "back.obj", back_comment, (-1, 0, -1), (1, 0, -1), (1, 2, -1), (-1, 2, -1), uv=back_uv)
    quad(m / "front.obj", "front wall behind the camera, z = 1, facing -z", (1, 0, 1), (-1, 0, 1), (-1, 2, 1), (1, 2, 1))
    if left:
        quad(m / "left.obj", "left wall, x = -1, facing +x", (-1, 0, 1), (-1, 0, -1), (-1, 2, -1), (-1, 2, 1))
    quad(m / "right.obj", "right wall, x = 1, facing -x", (1, 0, -1), (1, 0, 1), (1, 2, 1), (1, 2, -1))


# ---------------------------------------------------------------------------------------
# bundled: scenes/ajar, scenes/glossy, scenes/gap, scenes/smoke.


def ajar(root):
    """A closed room lit by an area light outside it through a door left ajar, so that the
    textured back wall receives almost only indirect light (the situation of the "Veach
    Ajar" texture experiment of Bálint et al. 2023)."""
    m = root / "meshes"
    room(m, back_comment="textured back wall, z = -1, facing +z; u along +x, v along +y", back_uv=True, left=False)
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

    write(root / "textures" / "albedo.exr", exr(grid(32, 32, albedo)))


def glossy(root):
    """A metal sphere whose roughness varies over its surface, a roughness texture to
    recover (the case where roughness gradients are hard to estimate)."""
    m = root / "meshes"
    sphere(m / "sphere.obj", "UV sphere, radius 0.6 at (0, 0.6, 0), 32 x 16 segments", (0.0, 0.6, 0.0), 0.6, 32, 16)
    quad(m / "floor.obj", "floor, y = 0, facing +y; tiled by its texture", (-3, 0, 3), (3, 0, 3), (3, 0, -3), (-3, 0, -3), uv=True)
    quad(m / "light.obj", "area light above and in front of the sphere, facing -y", (-0.6, 2.2, 0.2), (0.6, 2.2, 0.2), (0.6, 2.2, 1.4), (-0.6, 2.2, 1.4))

    def floor(x, y):
        v = 0.7 if (x // 4 + y // 4) % 2 == 0 else 0.1
        return (v, v, v)

    write(root / "textures" / "checker.exr", exr(grid(32, 32, floor)))

    def roughness(x, y):
        # Bands around the sphere (u) from polished to rough, and a smoother cap.
        r = 0.1 + 0.5 * (0.5 - 0.5 * math.cos(2.0 * math.pi * (x + 0.5) / 8.0))
        if y < 2:
            r = 0.15
        return (r, r, r)

    write(root / "textures" / "roughness.exr", exr(grid(8, 8, roughness)))


def gap(root):
    """A closed box whose only light is a small one-sided area light 2 cm under the
    ceiling, facing the ceiling: light reaches the room only off the ceiling through that
    gap, so the image is carried by rare bright paths (a gradient check where variance is
    large and any correlation between the residual image and the adjoint's paths shows as
    bias)."""
    m = root / "meshes"
    room(m)  # the camera stands inside, in front of the front wall
    box(m / "block.obj", "grey block on the floor, x in [0.15, 0.65], z in [-0.7, -0.2], 0.6 high", (0.15, 0, -0.7), (0.65, 0.6, -0.2))
    # The light: 0.3 x 0.3, 2 cm under the ceiling, emitting upwards only.
    quad(m / "light.obj", "area light 2 cm under the ceiling, y = 1.98, facing +y", (-0.15, 1.98, 0.15), (0.15, 1.98, 0.15), (0.15, 1.98, -0.15), (-0.15, 1.98, -0.15))


def smoothstep(a, b, t):
    t = min(max((t - a) / (b - a), 0.0), 1.0)
    return t * t * (3.0 - 2.0 * t)


LATTICE = {}


def lattice_value(i, j, k, seed):
    """A value in [0, 1) at integer lattice point (i, j, k): an integer hash of the point
    and the seed (remembered in LATTICE)."""
    key = (i, j, k, seed)
    if key not in LATTICE:
        h = (i * 73856093 ^ j * 19349663 ^ k * 83492791 ^ seed * 2654435761) & 0xFFFFFFFF
        h ^= h >> 13
        h = (h * 0x5BD1E995) & 0xFFFFFFFF
        h ^= h >> 15
        LATTICE[key] = (h & 0xFFFFFF) / 16777216.0
    return LATTICE[key]


def value_noise(u, v, w, cells, seed):
    """Value noise in [0, 1) at (u, v, w) in the unit cube: lattice values `cells` apart per
    side, interpolated with smoothstep weights."""
    x, y, z = u * cells, v * cells, w * cells
    i, j, k = math.floor(x), math.floor(y), math.floor(z)
    fx, fy, fz = x - i, y - j, z - k
    sx, sy, sz = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy), fz * fz * (3 - 2 * fz)
    total = 0.0
    for a, wa in ((0, 1 - sx), (1, sx)):
        for b, wb in ((0, 1 - sy), (1, sy)):
            for c, wc in ((0, 1 - sz), (1, sz)):
                total += wa * wb * wc * lattice_value(i + a, j + b, k + c, seed)
    return total


# The smoke's puffs: centre (in the box's [-1, 1] coordinates), standard deviation, weight.
SMOKE_PUFFS = [((0.0, 0.35, 0.0), 0.2, 1.0), ((-0.32, 0.48, 0.12), 0.13, 0.8), ((0.3, 0.42, -0.12), 0.12, 0.7), ((0.05, -0.5, 0.05), 0.14, 0.9)]


def smoke_density(x, y, z):
    """The smoke's density at (x, y, z) in the box's [-1, 1] coordinates: a rising, winding
    plume under a cap of puffs and over a puff at its foot, broken up by three octaves of
    value noise; 0 to 4, and 0 at the box's faces."""
    cx = 0.14 * math.sin(3.0 * y + 0.5)
    cz = 0.10 * math.cos(2.5 * y)
    r = 0.07 + 0.07 * (y + 0.7)
    plume = math.exp(-((x - cx) ** 2 + (z - cz) ** 2) / (2 * r * r)) * smoothstep(-0.75, -0.5, y) * (1 - smoothstep(0.25, 0.55, y))
    puffs = sum(wt * math.exp(-((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2) / (2 * s * s)) for c, s, wt in SMOKE_PUFFS)
    u, v, w = (x + 1) / 2, (y + 1) / 2, (z + 1) / 2
    n = 0.5 * value_noise(u, v, w, 5, 1) + 0.3 * value_noise(u, v, w, 11, 2) + 0.2 * value_noise(u, v, w, 23, 3)
    raw = (plume + puffs) * (2.2 * n - 0.35)
    return 4.0 * (1.0 - math.exp(-1.6 * max(raw - 0.05, 0.0)))


def smoke_emission(d):
    """A temperature-like colour for density d: dim red where the smoke is thin, through
    orange to a pale yellow in the dense core."""
    t = d / 4.0
    return (0.08 + 1.5 * smoothstep(0.0, 0.45, t), 0.04 + 1.0 * smoothstep(0.15, 0.75, t), 0.03 + 0.6 * smoothstep(0.45, 1.0, t))


def smoke(root):
    """An emitting and absorbing medium, 64^3 voxels of smoke-like density and a coloured
    emission that follows it (the volume experiment of Bálint et al. 2023)."""
    n = 64
    centres = [2 * (i + 0.5) / n - 1 for i in range(n)]
    density = [smoke_density(x, y, z) for z in centres for y in centres for x in centres]
    emission = [c for d in density for c in smoke_emission(d)]
    write(root / "grids" / "density.npy", npy((n, n, n), density))
    write(root / "grids" / "emission.npy", npy((n, n, n, 3), emission))


def bundled():
    """scenes/ajar, scenes/glossy and scenes/gap: meshes and reference textures; scenes/smoke:
    its density and emission grids."""
    for scene in [ajar, glossy, gap, smoke]:
        scene(ROOT / "scenes" / scene.__name__)


# ---------------------------------------------------------------------------------------
# mitsuba: the meshes and textures of scenes/mitsuba/ (its XML files are written by hand).


def mitsuba():
    """scenes/mitsuba/meshes: scene.xml's wall (OBJ) and wedge (PLY), the normal map of
    normalmap.xml and textured_shapes.xml, the height field of bumpmap.xml, the emission
    texture of textured_light.xml's globe, the lattice opacity of masked.xml and the sky of
    envmap.xml."""
    m = ROOT / "scenes" / "mitsuba" / "meshes"
    quad(m / "wall.obj", "the back wall, facing +z", (-2, 0, -1.5), (2, 0, -1.5), (2, 3, -1.5), (-2, 3, -1.5))
    # A wedge (a triangular prism): triangle ends at z = ±0.35, faces counter-clockwise
    # seen from outside.
    wedge = [(-0.4, 0, 0.35), (0.4, 0, 0.35), (-0.4, 0.6, 0.35), (-0.4, 0, -0.35), (0.4, 0, -0.35), (-0.4, 0.6, -0.35)]
    write_ply(m / "wedge.ply", "a wedge for scenes/mitsuba", wedge, [(0, 1, 2), (3, 5, 4), (0, 3, 4, 1), (1, 4, 5, 2), (0, 2, 5, 3)])

    # The normal map of normalmap.xml: 8 x 8 texels, 8-bit RGB encoding (n + 1) / 2 of
    # tangent-space normals. Columns tilt along u (left: -30°, right: +30°, the middle two
    # columns flat), rows along v (top rows +20°, bottom rows -20°).
    def normal(x, y):
        ax = -30 if x < 3 else (30 if x > 4 else 0)
        ay = 20 if y < 3 else (-20 if y > 4 else 0)
        n = (math.tan(math.radians(ax)), math.tan(math.radians(ay)), 1.0)
        length = math.sqrt(sum(c * c for c in n))
        return tuple(round((c / length + 1) / 2 * 255) for c in n)

    write(m / "bumps.png", png(grid(8, 8, normal)))

    # The height field of bumpmap.xml: 16 x 16 texels, grey, 8-bit, two periods of a wave
    # along u times one along v, (1 + sin(4 pi x / 16) cos(2 pi y / 16)) / 2.
    def height(x, y):
        h = round((1 + math.sin(4 * math.pi * (x + 0.5) / 16) * math.cos(2 * math.pi * (y + 0.5) / 16)) / 2 * 255)
        return (h, h, h)

    write(m / "heights.png", png(grid(16, 16, height)))

    # The glowing band of textured_light.xml's globe: 32 x 16 texels, black but for three
    # rows (warm on one half of the circumference, cool on the other).
    def band(x, y):
        if not 7 <= y < 10:
            return (0, 0, 0)
        return (255, 180, 90) if x < 16 else (90, 160, 255)

    write(m / "band.png", png(grid(32, 16, band)))

    # The lattice of masked.xml's card: 16 x 16 texels, opaque (white) bars two texels wide
    # (rows and columns 1-2, 5-6, ...) and holes (black) of 2 x 2 texels between them and
    # along the border; the bars of the bottom quarter are grey (opacity 0.5). Large texels:
    # the bilinear lookup ramps across a bar's edge over a whole texel, which Mitsuba's mask
    # and a blend treat alike, a ray passing through with probability 1 - opacity.
    def lattice(x, y):
        if x % 4 not in (1, 2) and y % 4 not in (1, 2):
            return (0,) * 3
        return (188,) * 3 if y >= 12 else (255,) * 3  # sRGB 188: linear 0.5

    write(m / "lattice.png", png(grid(16, 16, lattice)))

    # The sky of envmap.xml: 64 x 32 texels in Mitsuba's layout (column 0 towards -z, rows
    # from the zenith to the nadir), a blue sky brightening to a white horizon over a brown
    # ground, a sun of 2 x 2 texels and a red band on the horizon a quarter-turn from it, so
    # that a wrong rotation, mirror or half-texel shift moves light, shadows and colour.
    def sky(x, y):
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

    write(m / "sky.hdr", rgbe(grid(64, 32, sky)))


# ---------------------------------------------------------------------------------------
# tests: the small scenes under tests/data/ that the import tests read.
#
# box/: one scene in every format: a floor, a back wall and an area light (OBJ files),
# three principled materials, a point light and a camera. scene.toml (OBJ), box.gltf
# (data-URI buffer), box.glb (binary chunk), box.xml (Mitsuba 3), and import-*.toml, which
# import each and add the TOML's own camera and film; bare.glb, the box without camera or
# light.
#
# textured/: a quad with a base-colour texture (external PNG) and a metallic-roughness
# texture (PNG embedded in the GLB's binary chunk), for the texture import test; a quad
# with a normal map.
#
# errors/: one file per unsupported glTF feature or Mitsuba element.

TEST_DATA = ROOT / "tests" / "data"
# The glTF files' asset.generator: the name of the script that first wrote them, kept so
# that regenerating leaves the committed files unchanged.
GLTF_GENERATOR = "vkinverse tests/data/make_data.py"

# Geometry: each quad as four corners (counter-clockwise seen from its front) split into
# triangles (0, 1, 2) and (0, 2, 3), the order tobj gives an OBJ `f 1 2 3 4`.
QUADS = {
    "floor": [(-1, 0, -1), (-1, 0, 1), (1, 0, 1), (1, 0, -1)],
    "wall": [(-1, 0, -1), (1, 0, -1), (1, 2, -1), (-1, 2, -1)],
    "light": [(-0.3, 1.9, -0.3), (0.3, 1.9, -0.3), (0.3, 1.9, 0.3), (-0.3, 1.9, 0.3)],
}
MATERIALS = {  # name: (base colour, roughness, metallic, emission)
    "white": ((0.7, 0.7, 0.7), 1.0, 0.0, 0.0),
    "red": ((0.6, 0.2, 0.1), 0.6, 0.0, 0.0),
    "lamp": ((0.0, 0.0, 0.0), 1.0, 0.0, 10.0),
}
MESH_MATERIAL = {"floor": "white", "wall": "red", "light": "lamp"}
CAMERA = {"origin": (0.0, 1.0, 3.0), "target": (0.0, 0.9, 0.0), "fov_y": 45.0}
BULB = {"position": (0.5, 1.5, 0.5), "intensity": 2.0}


def test_quads(d):
    """The box's quads as OBJ files (no comment, texture coordinates) in folder d."""
    for name, corners in QUADS.items():
        quad(d / f"{name}.obj", None, *corners, uv=True)


def camera_matrix():
    """Column-major node matrix of the camera: glTF cameras look down their local −Z."""
    o, t = CAMERA["origin"], CAMERA["target"]
    f = [t[i] - o[i] for i in range(3)]
    n = math.sqrt(sum(c * c for c in f))
    f = [c / n for c in f]
    up = (0.0, 1.0, 0.0)
    r = [f[1] * up[2] - f[2] * up[1], f[2] * up[0] - f[0] * up[2], f[0] * up[1] - f[1] * up[0]]
    n = math.sqrt(sum(c * c for c in r))
    r = [c / n for c in r]
    u = [r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0]]
    return [*r, 0, *u, 0, *(-c for c in f), 0, *o, 1]


def box_gltf(binary):
    """The box as a glTF document and its buffer bytes."""
    blob = bytearray()
    accessors, views, meshes, nodes = [], [], [], []
    for name, corners in QUADS.items():
        pos_offset = len(blob)
        for c in corners:
            blob += struct.pack("<3f", *c)
        uv_offset = len(blob)
        for u, t in QUAD_UVS:
            blob += struct.pack("<2f", u, 1 - t)  # glTF's v runs down the image
        idx_offset = len(blob)
        blob += struct.pack("<6H", 0, 1, 2, 0, 2, 3)
        blob += b"\0" * (-len(blob) % 4)
        views.append({"buffer": 0, "byteOffset": pos_offset, "byteLength": 48})
        views.append({"buffer": 0, "byteOffset": uv_offset, "byteLength": 32})
        views.append({"buffer": 0, "byteOffset": idx_offset, "byteLength": 12})
        lo = [min(c[i] for c in corners) for i in range(3)]
        hi = [max(c[i] for c in corners) for i in range(3)]
        accessors.append({"bufferView": len(views) - 3, "componentType": 5126, "count": 4, "type": "VEC3", "min": lo, "max": hi})
        accessors.append({"bufferView": len(views) - 2, "componentType": 5126, "count": 4, "type": "VEC2"})
        accessors.append({"bufferView": len(views) - 1, "componentType": 5123, "count": 6, "type": "SCALAR"})
        material = list(MATERIALS).index(MESH_MATERIAL[name])
        attributes = {"POSITION": len(accessors) - 3, "TEXCOORD_0": len(accessors) - 2}
        meshes.append({"name": name + "-mesh", "primitives": [{"attributes": attributes, "indices": len(accessors) - 1, "material": material}]})
        nodes.append({"name": name, "mesh": len(meshes) - 1})
    materials = []
    for name, (base, rough, metal, emission) in MATERIALS.items():
        m = {"name": name, "pbrMetallicRoughness": {"baseColorFactor": [*base, 1.0], "roughnessFactor": rough, "metallicFactor": metal}}
        if emission > 0:
            m["emissiveFactor"] = [1.0, 1.0, 1.0]
            m["extensions"] = {"KHR_materials_emissive_strength": {"emissiveStrength": emission}}
        materials.append(m)
    nodes.append({"name": "camera", "camera": 0, "matrix": camera_matrix()})
    nodes.append({"name": "bulb-node", "translation": list(BULB["position"]), "extensions": {"KHR_lights_punctual": {"light": 0}}})
    doc = {
        "asset": {"version": "2.0", "generator": GLTF_GENERATOR},
        "extensionsUsed": ["KHR_lights_punctual", "KHR_materials_emissive_strength"],
        "scene": 0,
        "scenes": [{"nodes": list(range(len(nodes)))}],
        "nodes": nodes,
        "meshes": meshes,
        "materials": materials,
        "cameras": [{"type": "perspective", "perspective": {"yfov": math.radians(CAMERA["fov_y"]), "aspectRatio": 1.0, "znear": 0.01}}],
        "extensions": {"KHR_lights_punctual": {"lights": [{"name": "bulb", "type": "point", "color": [1.0, 1.0, 1.0], "intensity": BULB["intensity"]}]}},
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": len(blob)}],
    }
    if not binary:
        doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(bytes(blob)).decode()
    return doc, bytes(blob)


def bare_glb():
    """The box as a GLB without camera or light (its lamp does not emit): what a model from
    a sample collection often is."""
    doc, blob = box_gltf(binary=True)
    doc["nodes"] = [n for n in doc["nodes"] if "mesh" in n]
    doc["scenes"] = [{"nodes": list(range(len(doc["nodes"])))}]
    for key in ["cameras", "extensions", "extensionsUsed"]:
        del doc[key]
    for m in doc["materials"]:
        m.pop("emissiveFactor", None)
        m.pop("extensions", None)
    return glb(doc, blob)


def glb(doc, blob):
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    blob += b"\0" * (-len(blob) % 4)
    body = struct.pack("<I4s", len(js), b"JSON") + js + struct.pack("<I4s", len(blob), b"BIN\0") + blob
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def test_box():
    d = TEST_DATA / "box"
    test_quads(d)
    o, t = CAMERA["origin"], CAMERA["target"]
    materials = "".join(
        f'[[materials]]\nname = "{n}"\ntype = "principled"\nbase_color = {list(b)}\nroughness = {r}\nmetallic = {m}\n\n'
        for n, (b, r, m, _) in MATERIALS.items()
    )
    meshes = "".join(
        f'[[meshes]]\nfile = "{n}.obj"\nmaterial = "{MESH_MATERIAL[n]}"\n'
        + (f"emission = [{MATERIALS[MESH_MATERIAL[n]][3]}, {MATERIALS[MESH_MATERIAL[n]][3]}, {MATERIALS[MESH_MATERIAL[n]][3]}]\n" if MATERIALS[MESH_MATERIAL[n]][3] else "")
        + "\n"
        for n in QUADS
    )
    sensor = f"[[sensors]]\norigin = {list(o)}\ntarget = {list(t)}\nup = [0.0, 1.0, 0.0]\nfov_y = {CAMERA['fov_y']}\n"
    light = f'[[lights]]\nname = "bulb"\ntype = "point"\nposition = {list(BULB["position"])}\nintensity = {BULB["intensity"]}\n'
    head = "[film]\nwidth = 24\nheight = 24\n[integrator]\nmax_depth = 4\nrr_depth = 5\n\n"
    write(d / "scene.toml", "# The box in the project's format; box.gltf, box.glb and box.xml hold the same scene.\n" + head + sensor + "\n" + materials + meshes + light)
    doc, blob = box_gltf(binary=False)
    write(d / "box.gltf", json.dumps(doc, indent=1))
    write(d / "box.glb", glb(*box_gltf(binary=True)))
    write(d / "bare.glb", bare_glb())
    shapes = "    <!-- Flat faces, as in scene.toml, whose OBJs carry no normals: without face_normals\n         the import, like Mitsuba, smooths each mesh with computed vertex normals. -->\n" + "".join(
        f'    <shape type="obj" id="{n}">\n        <string name="filename" value="{n}.obj"/>\n        <boolean name="face_normals" value="true"/>\n        <ref id="{MESH_MATERIAL[n]}"/>\n'
        + (f'        <emitter type="area"><rgb name="radiance" value="{MATERIALS[MESH_MATERIAL[n]][3]}"/></emitter>\n' if MATERIALS[MESH_MATERIAL[n]][3] else "")
        + "    </shape>\n"
        for n in QUADS
    )
    bsdfs = "".join(
        f'    <bsdf type="twosided" id="{n}">\n        <bsdf type="principled">\n            <rgb name="base_color" value="{b[0]}, {b[1]}, {b[2]}"/>\n'
        f'            <float name="roughness" value="{r}"/>\n            <float name="metallic" value="{m}"/>\n        </bsdf>\n    </bsdf>\n'
        for n, (b, r, m, _) in MATERIALS.items()
    )
    xml = f"""<scene version="3.0.0">
    <default name="res" value="24"/>
    <integrator type="path">
        <integer name="max_depth" value="4"/>
        <integer name="rr_depth" value="5"/>
    </integrator>
    <sensor type="perspective">
        <float name="fov" value="{CAMERA['fov_y']}"/>
        <string name="fov_axis" value="y"/>
        <transform name="to_world">
            <lookat origin="{o[0]}, {o[1]}, {o[2]}" target="{t[0]}, {t[1]}, {t[2]}" up="0, 1, 0"/>
        </transform>
        <sampler type="independent"><integer name="sample_count" value="64"/></sampler>
        <film type="hdrfilm">
            <integer name="width" value="$res"/>
            <integer name="height" value="$res"/>
            <rfilter type="box"/>
        </film>
    </sensor>
{bsdfs}{shapes}    <emitter type="point" id="bulb">
        <point name="position" x="{BULB['position'][0]}" y="{BULB['position'][1]}" z="{BULB['position'][2]}"/>
        <rgb name="intensity" value="{BULB['intensity']}"/>
    </emitter>
</scene>
"""
    write(d / "box.xml", xml)
    for name, file in [("gltf", "box.gltf"), ("glb", "box.glb"), ("xml", "box.xml")]:
        write(d / f"import-{name}.toml", f'# {file} with the camera and film of scene.toml.\nimport = "{file}"\n\n' + head + sensor)


# The accessors and buffer views of quad_blob().
QUAD_ACCESSORS = [
    {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-1, 0, -1], "max": [1, 0, 1]},
    {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
    {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"},
]
QUAD_VIEWS = [
    {"buffer": 0, "byteOffset": 0, "byteLength": 48},
    {"buffer": 0, "byteOffset": 48, "byteLength": 32},
    {"buffer": 0, "byteOffset": 80, "byteLength": 12},
]


def quad_blob():
    """The buffer of a quad in the y = 0 plane facing +y: 4 positions (VEC3 floats, 48
    bytes), 4 glTF texture coordinates (VEC2 floats, 32 bytes), 6 u16 indices (12 bytes)."""
    blob = bytearray()
    for c in [(-1, 0, -1), (-1, 0, 1), (1, 0, 1), (1, 0, -1)]:
        blob += struct.pack("<3f", *c)
    for uv in [(0, 0), (0, 1), (1, 1), (1, 0)]:
        blob += struct.pack("<2f", *uv)
    return blob + struct.pack("<6H", 0, 1, 2, 0, 2, 3)


def test_textured():
    d = TEST_DATA / "textured"
    # 2 x 2 base colour: row 0 red, green; row 1 blue, white (sRGB bytes).
    write(d / "checker.png", png([[(255, 0, 0), (0, 255, 0)], [(0, 0, 255), (255, 255, 255)]]))
    # Metallic-roughness: G = roughness, B = metallic; a 2 x 1 image.
    mr = png([[(0, 51, 255), (0, 204, 0)]])
    blob = quad_blob() + b"\0\0"
    png_offset = len(blob)
    blob += mr + b"\0" * (-len(mr) % 4)
    doc = {
        "asset": {"version": "2.0"},
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [
            {"name": "quad", "mesh": 0, "rotation": [0, 0.7071068, 0, 0.7071068], "scale": [2, 1, 1]},
            {"name": "eye", "camera": 0, "translation": [0, 3, 0], "rotation": [-0.7071068, 0, 0, 0.7071068]},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]}],
        "materials": [
            {
                "name": "painted",
                "pbrMetallicRoughness": {
                    "baseColorFactor": [0.5, 1.0, 1.0, 1.0],
                    "baseColorTexture": {"index": 0},
                    "metallicRoughnessTexture": {"index": 1},
                    "roughnessFactor": 0.5,
                },
            }
        ],
        "textures": [{"source": 0}, {"source": 1}],
        "images": [{"uri": "checker.png"}, {"bufferView": 3, "mimeType": "image/png"}],
        "cameras": [{"type": "perspective", "perspective": {"yfov": 0.8, "aspectRatio": 2.0, "znear": 0.01}}],
        "accessors": QUAD_ACCESSORS,
        "bufferViews": QUAD_VIEWS + [
            {"buffer": 0, "byteOffset": png_offset, "byteLength": len(mr)},
        ],
        "buffers": [{"byteLength": len(blob)}],
    }
    write(d / "textured.glb", glb(doc, bytes(blob)))


def test_normal_mapped():
    """A quad facing +y with a 2 x 2 normal map (scale 0.5) and its buffer in a data URI."""
    d = TEST_DATA / "textured"
    # Tangent-space normals as bytes (n + 1) / 2 * 255: tilted along +u, along +v, along
    # -u and untilted.
    write(d / "bumps.png", png([[(200, 128, 230), (128, 200, 230)], [(55, 128, 230), (128, 128, 255)]]))
    blob = quad_blob()
    doc = {
        "asset": {"version": "2.0"},
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [
            {"name": "quad", "mesh": 0},
            {"name": "eye", "camera": 0, "translation": [0, 3, 0], "rotation": [-0.7071068, 0, 0, 0.7071068]},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]}],
        "materials": [
            {
                "name": "bumpy",
                "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.8, 0.8, 1.0], "roughnessFactor": 0.4, "metallicFactor": 0.0},
                "normalTexture": {"index": 0, "scale": 0.5},
            }
        ],
        "textures": [{"source": 0}],
        "images": [{"uri": "bumps.png"}],
        "cameras": [{"type": "perspective", "perspective": {"yfov": 0.8, "aspectRatio": 1.0, "znear": 0.01}}],
        "accessors": QUAD_ACCESSORS,
        "bufferViews": QUAD_VIEWS,
        "buffers": [{"byteLength": len(blob), "uri": "data:application/octet-stream;base64," + base64.b64encode(bytes(blob)).decode()}],
    }
    write(d / "normal-mapped.gltf", json.dumps(doc, indent=1))


def test_errors():
    """One file per unsupported feature: variants of box.gltf and of box.xml (which
    test_box writes first)."""
    d = TEST_DATA / "errors"
    doc, _ = box_gltf(binary=False)

    def variant(name, edit):
        v = json.loads(json.dumps(doc))
        edit(v)
        write(d / f"{name}.gltf", json.dumps(v))

    variant("required-extension", lambda v: (v.setdefault("extensionsRequired", []).append("KHR_draco_mesh_compression"), v["extensionsUsed"].append("KHR_draco_mesh_compression")))
    variant("optional-extension", lambda v: (v["materials"][1].setdefault("extensions", {}).update({"KHR_materials_clearcoat": {"clearcoatFactor": 1}}), v["extensionsUsed"].append("KHR_materials_clearcoat")))
    variant("required-on-material", lambda v: (v["materials"][0].setdefault("extensions", {}).update({"KHR_materials_clearcoat": {"clearcoatFactor": 1}}), v.setdefault("extensionsRequired", []).append("KHR_materials_clearcoat")))
    variant("lines", lambda v: v["meshes"][1]["primitives"][0].update({"mode": 1}))
    variant("normal-map-texcoord1", lambda v: (v["materials"][0].update({"normalTexture": {"index": 0, "texCoord": 1}}), v.update({"textures": [{"source": 0}], "images": [{"uri": "none.png"}]})))
    variant("texcoord1", lambda v: (v["materials"][0]["pbrMetallicRoughness"].update({"baseColorTexture": {"index": 0, "texCoord": 1}}), v.update({"textures": [{"source": 0}], "images": [{"uri": "none.png"}]})))
    variant("orthographic-flat", lambda v: v["cameras"].__setitem__(0, {"type": "orthographic", "orthographic": {"xmag": 1, "ymag": 0, "znear": 0.01, "zfar": 10}}))
    variant("missing-emissive-image", lambda v: (v["materials"][2].update({"emissiveTexture": {"index": 0}}), v.update({"textures": [{"source": 0}], "images": [{"uri": "none.png"}]})))
    variant("missing-buffer", lambda v: v["buffers"][0].update({"uri": "nowhere.bin"}))

    base = (TEST_DATA / "box" / "box.xml").read_text()
    xml = {
        "blendbsdf": base.replace('<bsdf type="principled">', '<bsdf type="blendbsdf">', 1),
        "bsplinecurve": base.replace('<shape type="obj" id="floor">', '<shape type="bsplinecurve" id="floor">', 1),
        "unknown-parameter": base.replace('<float name="fov"', '<float name="lens_tilt" value="2"/>\n        <float name="fov"', 1),
        "aov": base.replace('<integrator type="path">', '<integrator type="aov">', 1),
        "medium": base.replace("</scene>", '    <medium type="homogeneous" id="fog"/>\n</scene>', 1),
        "undefined-default": base.replace('value="$res"', 'value="$resolution"', 1),
        "clearcoat": base.replace('<float name="metallic" value="0.0"/>', '<float name="metallic" value="0.0"/>\n            <float name="clearcoat" value="0.5"/>', 1),
        "radiancemeter": base.replace('<sensor type="perspective">', '<sensor type="radiancemeter">', 1),
        "missing-radiance-bitmap": base.replace('<rgb name="radiance" value="10.0"/>', '<texture type="bitmap" name="radiance"><string name="filename" value="x.exr"/></texture>', 1),
    }
    for name, text in xml.items():
        assert text != base, name
        write(d / f"{name}.xml", text)
    test_quads(d)


def tests():
    """tests/data/box, textured and errors: the small scenes the import tests read."""
    test_box()  # first: test_errors edits its box.xml
    test_textured()
    test_normal_mapped()
    test_errors()


# ---------------------------------------------------------------------------------------

GROUPS = {"bundled": bundled, "mitsuba": mitsuba, "tests": tests}


def main():
    listing = "\n".join(textwrap.fill(" ".join(f.__doc__.split()), 88, initial_indent=f"  {name:9}", subsequent_indent=" " * 11) for name, f in GROUPS.items())
    parser = argparse.ArgumentParser(
        description="Regenerates the generated scene files (all groups when none is named).",
        epilog="groups:\n" + listing,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("groups", nargs="*", metavar="GROUP", help="one of: " + ", ".join(GROUPS))
    args = parser.parse_args()
    unknown = [g for g in args.groups if g not in GROUPS]
    if unknown:
        parser.error(f"unknown group {', '.join(unknown)} (groups: {', '.join(GROUPS)})")
    for name in args.groups or GROUPS:
        GROUPS[name]()


if __name__ == "__main__":
    sys.exit(main())
