#!/usr/bin/env python3
"""Writes the small scenes under tests/data/ that the import tests read (run from
anywhere; the files are committed, this script documents and regenerates them).

box/: one scene in every format: a floor, a back wall and an area light (OBJ files),
three principled materials, a point light and a camera. scene.toml (OBJ), box.gltf
(data-URI buffer), box.glb (binary chunk), box.xml (Mitsuba 3), and import-*.toml, which
import each and add the TOML's own camera and film.

textured/: a quad with a base-colour texture (external PNG) and a metallic-roughness
texture (PNG embedded in the GLB's binary chunk), for the texture import test.

errors/: one file per unsupported glTF feature or Mitsuba element.
"""

import base64
import json
import math
import struct
import zlib
from pathlib import Path

HERE = Path(__file__).resolve().parent

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


def write(path, data):
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(data, str):
        data = data.encode()
    path.write_bytes(data)


# Texture coordinates of the corners (OBJ convention: v up).
UVS = [(0, 0), (1, 0), (1, 1), (0, 1)]


def obj(corners):
    v = "".join(f"v {x} {y} {z}\n" for x, y, z in corners)
    return v + "".join(f"vt {u} {t}\n" for u, t in UVS) + "f 1/1 2/2 3/3 4/4\n"


def png(width, height, rows):
    """An 8-bit RGB PNG from rows of (r, g, b) byte triples."""
    raw = b"".join(b"\0" + bytes(c for px in row for c in px) for row in rows)

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


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
        for u, t in UVS:
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
        "asset": {"version": "2.0", "generator": "vkinverse tests/data/make_data.py"},
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


def box():
    d = HERE / "box"
    for name, corners in QUADS.items():
        write(d / f"{name}.obj", obj(corners))
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


def textured():
    d = HERE / "textured"
    # 2 x 2 base colour: row 0 red, green; row 1 blue, white (sRGB bytes).
    base = png(2, 2, [[(255, 0, 0), (0, 255, 0)], [(0, 0, 255), (255, 255, 255)]])
    write(d / "checker.png", base)
    # Metallic-roughness: G = roughness, B = metallic; a 2 x 1 image.
    mr = png(2, 1, [[(0, 51, 255), (0, 204, 0)]])
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


def normal_mapped():
    """A quad facing +y with a 2 x 2 normal map (scale 0.5) and its buffer in a data URI."""
    d = HERE / "textured"
    # Tangent-space normals as bytes (n + 1) / 2 * 255: tilted along +u, along +v, along
    # -u and untilted.
    write(d / "bumps.png", png(2, 2, [[(200, 128, 230), (128, 200, 230)], [(55, 128, 230), (128, 128, 255)]]))
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


def errors():
    d = HERE / "errors"
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

    base = (HERE / "box" / "box.xml").read_text()
    xml = {
        "dielectric": base.replace('<bsdf type="principled">', '<bsdf type="dielectric">', 1),
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
    for obj_name in QUADS:
        write(d / f"{obj_name}.obj", obj(QUADS[obj_name]))


if __name__ == "__main__":
    box()
    textured()
    normal_mapped()
    errors()
