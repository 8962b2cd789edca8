"""Base-colour textures (``tracer.shading.textures``, ``tracer.scene.mesh_files``): the bilinear
lookup against a naive oracle, UVs at hits, textured renders of the albedo and path integrators,
glTF and OBJ/MTL materials, the effect plan's texture rule, snapshots and edits, and bad inputs."""

import base64
import io
import json
import math
import struct

import numpy as np
import pytest
from numba import njit
from PIL import Image

from tests.helpers import SCENES, write_json
from tracer.compiled.scene import compile_scene
from tracer.errors import SceneError
from tracer.geometry.scene_intersect import scene_closest
from tracer.integrators.effects import EffectPlan, effect_plan
from tracer.integrators.flags import ALL, TEXTURES
from tracer.render import render_image, render_lines
from tracer.scene import format as fmt
from tracer.scene.codec import decode_state, encode_state
from tracer.scene.loader import load_scene
from tracer.scene.ops import apply_ops, parse_ops
from tracer.shading.textures import bilinear, hit_uv, srgb_to_linear, texture_table

TEXTURED = SCENES / "textured" / "scene.json"

# --- the lookup ------------------------------------------------------------------------------

TINY = np.array(
    [[[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 255]],
     [[10, 20, 30], [128, 64, 32], [0, 0, 0], [200, 100, 50]]],
    dtype=np.uint8,
)  # fmt: skip
"""4 texels wide, 2 high (powers of two: texel centres and midpoints are exact in binary)."""


@njit
def lookup(pixels, info, scale, t, u, v):
    return bilinear(pixels, info, scale, t, u, v)


def tiny_table(wrap: str, scale=(1.0, 1.0)):
    texture = fmt.Texture(file="tiny.png", wrap=wrap, scale=scale)
    return texture_table({"tiny.png": TINY}, [fmt.DiffuseMaterial(texture=texture)])


def at(table, u: float, v: float) -> np.ndarray:
    return np.array(lookup(table.pixels, table.info, table.scale, 0, u, v))


def naive_bilinear(linear: np.ndarray, u: float, v: float, wrap: str) -> np.ndarray:
    """The lookup as docs/materials.md states it, in plain Python (row 0 is the image's top)."""
    height, width = linear.shape[:2]
    if wrap == "repeat":
        u, v = u % 1.0, v % 1.0
    else:
        u, v = min(max(u, 0.0), 1.0), min(max(v, 0.0), 1.0)
    x = u * width - 0.5
    y = (1.0 - v) * height - 0.5
    x0, y0 = math.floor(x), math.floor(y)
    fx, fy = x - x0, y - y0

    def texel(i, j):
        if wrap == "repeat":
            i, j = i % width, j % height
        else:
            i, j = min(max(i, 0), width - 1), min(max(j, 0), height - 1)
        return linear[j, i].astype(np.float64)

    return ((1 - fx) * (1 - fy) * texel(x0, y0) + fx * (1 - fy) * texel(x0 + 1, y0)
            + (1 - fx) * fy * texel(x0, y0 + 1) + fx * fy * texel(x0 + 1, y0 + 1))  # fmt: skip


def test_srgb_decoding():
    """8-bit sRGB to linear: the IEC 61966-2-1 curve (0, 1 and a mid grey)."""
    linear = srgb_to_linear(np.array([0, 255, 128, 10], np.uint8))
    assert linear[0] == 0.0 and linear[1] == 1.0
    assert linear[2] == pytest.approx(0.2158605, rel=1e-6)
    assert linear[3] == pytest.approx(10 / 255 / 12.92, rel=1e-6)


@pytest.mark.parametrize("wrap", ["repeat", "clamp"])
def test_texel_centres_are_exact(wrap):
    """At each texel's centre the lookup is that texel, exactly (u right, v up, row 0 on top)."""
    table = tiny_table(wrap)
    linear = srgb_to_linear(TINY)
    for row in range(2):
        for col in range(4):
            value = at(table, (col + 0.5) / 4, 1.0 - (row + 0.5) / 2)
            assert value.tolist() == linear[row, col].astype(np.float64).tolist()


def test_corners_and_edges():
    """Clamp: the corners are the corner texels and far outside is the edge; repeat: a corner
    mixes the four corner texels equally, and UVs repeat with period 1 in both directions."""
    linear = srgb_to_linear(TINY).astype(np.float64)
    clamp = tiny_table("clamp")
    assert at(clamp, 0.0, 0.0).tolist() == linear[1, 0].tolist()  # bottom left
    assert at(clamp, 1.0, 1.0).tolist() == linear[0, 3].tolist()  # top right
    assert at(clamp, -7.0, 0.75).tolist() == linear[0, 0].tolist()
    assert at(clamp, 3.0, 0.25).tolist() == linear[1, 3].tolist()
    repeat = tiny_table("repeat")
    corner = 0.25 * (linear[0, 0] + linear[0, 3] + linear[1, 0] + linear[1, 3])
    np.testing.assert_allclose(at(repeat, 0.0, 0.0), corner, rtol=1e-15)
    np.testing.assert_allclose(at(repeat, 1.0, 1.0), corner, rtol=1e-15)
    assert at(repeat, 1.125, -0.75).tolist() == at(repeat, 0.125, 0.25).tolist()
    assert at(repeat, -0.875, 2.25).tolist() == at(repeat, 0.125, 0.25).tolist()
    # Half-way between two texel centres: their mean.
    np.testing.assert_allclose(at(repeat, 0.25, 0.75), 0.5 * (linear[0, 0] + linear[0, 1]))


def test_scale_multiplies_uvs():
    """``scale`` multiplies UVs before wrapping: (u, v) with scale (2, 4) is (2u, 4v)."""
    scaled = tiny_table("repeat", (2.0, 4.0))
    plain = tiny_table("repeat")
    for u, v in [(0.1, 0.2), (0.37, -0.61), (2.3, 5.9)]:
        np.testing.assert_allclose(at(scaled, u, v), at(plain, 2 * u, 4 * v), rtol=1e-12)


@pytest.mark.parametrize("wrap", ["repeat", "clamp"])
def test_lookup_matches_the_naive_oracle(wrap):
    """Anywhere in [-3, 3]^2 the kernel agrees with the naive bilinear lookup."""
    table = tiny_table(wrap)
    linear = srgb_to_linear(TINY)
    rng = np.random.default_rng(4)
    for u, v in rng.uniform(-3.0, 3.0, size=(500, 2)):
        np.testing.assert_allclose(
            at(table, u, v), naive_bilinear(linear, u, v, wrap), rtol=1e-12, atol=1e-15
        )


def test_absurd_uvs_stay_inside_the_image():
    """UVs too large to have a fraction are looked up at 0 (never outside the texel array)."""
    table = tiny_table("repeat", (1e300, 1e300))
    assert np.isfinite(at(table, 1e300, -1e300)).all()
    assert at(table, 1e300, 1e300).tolist() == at(tiny_table("repeat"), 0.0, 0.0).tolist()


# --- UVs at hits -----------------------------------------------------------------------------


@njit
def uv_of_ray(scene, o, d):
    stack_node = np.empty(256, np.int32)
    stack_t = np.empty(256, np.float64)
    ray_o = (o[0], o[1], o[2])
    ray_d = (d[0], d[1], d[2])
    k, j, _, b0, b1, b2, _ = scene_closest(scene, ray_o, ray_d, np.inf, stack_node, stack_t)
    if k < 0:
        return -1.0, -1.0
    return hit_uv(scene, k, j, b0, b1, b2)


QUADS = {
    "static": ({"translate": [-2.5, 0, 0]}, "static"),
    "rigid": ({"translate": [0, 0, 0], "rotate": [0, 0, 30]}, "rigid"),
    "mirrored": ({"translate": [2.5, 0, 0], "scale": [-1, 1, 1]}, "static"),
}


def uv_scene(tmp_path, image: np.ndarray | None = None, **changes) -> dict:
    """Three textured 2x2 rectangles facing +z (static, rigid and rotated, mirrored)."""
    Image.fromarray(quadrant_image() if image is None else image).save(tmp_path / "q.png")
    scene = {
        "camera": {"position": [0, 0, 4], "look_at": [0, 0, 0], "width": 16, "height": 16,
                   "vfov_deg": 20},
        "render": {"spp": 4, "integrator": "albedo"},
        "materials": {
            "pic": {"reflectance": [1, 1, 1], "texture": {"file": "q.png", "wrap": "clamp"}},
            "lamp": {"emission": [1, 1, 1]},
        },
        "objects": [
            {"name": name, "shape": {"type": "rectangle", "size": [2, 2]}, "material": "pic",
             "transform": transform, "kind": kind}
            for name, (transform, kind) in QUADS.items()
        ],
    }  # fmt: skip
    scene.update(changes)
    return scene


def test_uv_interpolation_at_hits(tmp_path):
    """A ray's hit reports the UV interpolated from the triangle's vertices: on a 2x2
    rectangle, (u, v) = ((x + 1) / 2, (y + 1) / 2) in its own coordinates, for the baked
    static mesh, a rotated rigid instance, and a mirrored one (whose winding is reversed)."""
    path = write_json(tmp_path / "scene.json", uv_scene(tmp_path))
    scene = compile_scene(load_scene(path))
    rng = np.random.default_rng(0)
    for name, (transform, _) in QUADS.items():
        matrix = fmt.Transform(**transform).to_matrix()
        for x, y in rng.uniform(-0.95, 0.95, size=(20, 2)):
            world = matrix @ [x, y, 0.0, 1.0]
            origin = world[:3] + [0.0, 0.0, 3.0]
            u, v = uv_of_ray(scene.arrays, origin - scene.origin, np.array([0.0, 0.0, -1.0]))
            assert (u, v) == pytest.approx(((x + 1) / 2, (y + 1) / 2), abs=1e-6), name


# --- textured renders ------------------------------------------------------------------------

QUADRANTS = {"top-left": (220, 40, 30), "top-right": (40, 180, 60),
             "bottom-left": (40, 70, 220), "bottom-right": (230, 200, 40)}  # fmt: skip


def quadrant_image(size: int = 8) -> np.ndarray:
    """Four flat quadrants of ``QUADRANTS``' colours, uint8 (size, size, 3), row 0 on top."""
    image = np.empty((size, size, 3), np.uint8)
    h = size // 2
    image[:h, :h] = QUADRANTS["top-left"]
    image[:h, h:] = QUADRANTS["top-right"]
    image[h:, :h] = QUADRANTS["bottom-left"]
    image[h:, h:] = QUADRANTS["bottom-right"]
    return image


def facing_quad_scene(tmp_path, material: dict, shape="rectangle") -> dict:
    """A camera looking down -z at a 2x2 quad filling its inner view (albedo output)."""
    obj = {"name": "quad", "shape": {"type": shape, "size": [2, 2]} if shape == "rectangle"
           else shape}  # fmt: skip
    if material is not None:
        obj["material"] = "pic"
    return {
        "camera": {"position": [0, 0, 3], "look_at": [0, 0, 0], "width": 16, "height": 16,
                   "vfov_deg": 30},
        "render": {"spp": 4, "integrator": "albedo"},
        "materials": {"pic": material or {"reflectance": [1, 1, 1]}},
        "objects": [obj],
    }  # fmt: skip


def assert_quadrants(image: np.ndarray, factor=(1.0, 1.0, 1.0)) -> None:
    """Each quarter of the picture (away from the middle lines) shows its quadrant's colour,
    linear, times ``factor``: the image is upright and unmirrored."""
    n = image.shape[0]
    inner = {"top-left": image[1:5, 1:5], "top-right": image[1:5, n - 5 : n - 1],
             "bottom-left": image[n - 5 : n - 1, 1:5],
             "bottom-right": image[n - 5 : n - 1, n - 5 : n - 1]}  # fmt: skip
    for name, pixels in inner.items():
        expected = srgb_to_linear(np.array(QUADRANTS[name], np.uint8)) * np.array(factor)
        np.testing.assert_allclose(
            pixels.reshape(-1, 3), np.broadcast_to(expected, (16, 3)), rtol=1e-6, err_msg=name
        )


def render_file(path, **changes) -> np.ndarray:
    scene = compile_scene(load_scene(path))
    return render_image(scene, settings=fmt.override(scene.render, **changes))[0]


def test_textured_rectangle_shows_its_image(tmp_path):
    """The albedo output of a textured rectangle seen from the front is the image, upright,
    its quadrants in their places, in linear colour times the reflectance."""
    Image.fromarray(quadrant_image()).save(tmp_path / "q.png")
    material = {"reflectance": [0.5, 1.0, 0.25], "texture": {"file": "q.png", "wrap": "clamp"}}
    path = write_json(tmp_path / "scene.json", facing_quad_scene(tmp_path, material))
    assert_quadrants(render_file(path), (0.5, 1.0, 0.25))


def test_textures_switched_off_show_the_flat_colour(tmp_path):
    """``render.effects.textures: false`` renders the base colour alone."""
    Image.fromarray(quadrant_image()).save(tmp_path / "q.png")
    material = {"reflectance": [0.5, 1.0, 0.25], "texture": {"file": "q.png"}}
    path = write_json(tmp_path / "scene.json", facing_quad_scene(tmp_path, material))
    image = render_file(path, effects={"textures": False})
    np.testing.assert_array_equal(image[image.sum(axis=2) > 0], [[0.5, 1.0, 0.25]] * 256)


def test_textured_plane_needs_textures_and_shows_them(tmp_path):
    """A path-traced checker floor under a white sky: the plan keeps ``textures`` and its image
    equals the all-effects image bit for bit; without textures (the same random numbers) every
    pixel is the flat floor's, and the texture scales it by exactly its texel's value: the
    checker shows, upright."""
    Image.fromarray(checker_image()).save(tmp_path / "checker.png")
    data = {
        "camera": {"position": [0, 3, 0.001], "look_at": [0, 0, 0], "width": 16, "height": 16,
                   "vfov_deg": 30},
        "render": {"spp": 4, "max_depth": 2},
        "sky": {"radiance": [1, 1, 1]},
        "materials": {"floor": {"reflectance": [0.8, 0.8, 0.8],
                                "texture": {"file": "checker.png", "wrap": "repeat"}}},
        "objects": [{"shape": {"type": "plane", "size": 2}, "material": "floor"}],
    }  # fmt: skip
    scene = compile_scene(load_scene(write_json(tmp_path / "scene.json", data)))
    plan = effect_plan(scene, scene.render)
    assert "textures" in plan.names()
    image = render_image(scene, plan=plan)[0]
    assert image.tobytes() == render_image(scene, plan=EffectPlan(ALL, {}))[0].tobytes()
    flat = render_image(scene, plan=EffectPlan(plan.flags & ~TEXTURES, {}))[0]
    assert flat.min() > 0.0
    # Looking straight down with -z up in the picture, the plane's UVs put the image upright:
    # its top-left block (bright) at the picture's top left.
    bright, dark = srgb_to_linear(np.array([255, 64], np.uint8))
    ratio = image / flat
    for rows, cols, value in [
        ((1, 6), (1, 6), bright),
        ((1, 6), (10, 15), dark),
        ((10, 15), (1, 6), dark),
        ((10, 15), (10, 15), bright),
    ]:
        block = ratio[rows[0] : rows[1], cols[0] : cols[1]]
        np.testing.assert_allclose(block, value, rtol=1e-5)  # fmt: skip


def checker_image() -> np.ndarray:
    """8x8: 4x4 blocks, bright (255) top left and bottom right, dark (64) elsewhere."""
    image = np.full((8, 8, 3), 64, np.uint8)
    image[:4, :4] = image[4:, 4:] = 255
    return image


def test_splits_are_bit_identical_on_the_textured_scene():
    """The textured sample scene rendered whole and split into line ranges on 1 or 2 threads:
    the same bits."""
    scene = compile_scene(load_scene(TEXTURED))
    camera = fmt.override(scene.camera, width=40, height=30)
    settings = fmt.override(scene.render, spp=2)
    whole = render_lines(scene, 0, 30, camera, settings, threads=2).rgb
    parts = [render_lines(scene, a, b, camera, settings, threads=1).rgb
             for a, b in [(0, 7), (7, 8), (8, 30)]]  # fmt: skip
    assert np.concatenate(parts).tobytes() == whole.tobytes()


# --- glTF and OBJ/MTL ------------------------------------------------------------------------


def png_uri(image: np.ndarray) -> str:
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG")
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode()


QUAD_POSITIONS = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
GLTF_UVS = [(0, 1), (1, 1), (1, 0), (0, 0)]
"""glTF's texture coordinates put (0, 0) at the image's top-left corner."""


def gltf_document(materials: list[dict], image: np.ndarray | None = None) -> dict:
    """A glTF with one 2x2 quad facing +z per material (side by side along x, 3 apart), UVs
    in glTF's convention, and ``image`` as texture 0."""
    blob = b"".join(struct.pack("<3f", *p) for p in QUAD_POSITIONS)
    blob += b"".join(struct.pack("<2f", *uv) for uv in GLTF_UVS)
    blob += struct.pack("<6H", 0, 1, 2, 0, 2, 3)
    document = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": list(range(len(materials)))}],
        "nodes": [{"mesh": i, "translation": [3.0 * i, 0, 0]} for i in range(len(materials))],
        "meshes": [
            {"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2,
                             "material": i}]}
            for i in range(len(materials))
        ],
        "materials": materials,
        "buffers": [{"byteLength": len(blob),
                     "uri": "data:application/octet-stream;base64,"
                     + base64.b64encode(blob).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48},
                        {"buffer": 0, "byteOffset": 48, "byteLength": 32},
                        {"buffer": 0, "byteOffset": 80, "byteLength": 12}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": [-1, -1, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"},
        ],
    }  # fmt: skip
    if image is not None:
        document["images"] = [{"uri": png_uri(image)}]
        document["textures"] = [{"source": 0}]
    return document


def test_gltf_base_colour_texture(tmp_path):
    """A glTF's baseColorTexture times baseColorFactor is the base colour, oriented by glTF's
    convention (texture coordinate (0, 0) at the image's top left), when the file is placed
    in a JSON scene with its own materials."""
    material = {"name": "pic", "pbrMetallicRoughness": {
        "baseColorFactor": [0.5, 1.0, 0.25, 1.0], "baseColorTexture": {"index": 0},
        "metallicFactor": 0.0, "roughnessFactor": 1.0}}  # fmt: skip
    write_json(tmp_path / "quad.gltf", gltf_document([material], quadrant_image()))
    path = write_json(tmp_path / "scene.json", facing_quad_scene(tmp_path, None, "quad.gltf"))
    state = load_scene(path)
    loaded = state.materials["quad.gltf#pic"]
    assert loaded.type == "plastic" and loaded.texture is not None
    assert state.textures[loaded.texture.file].tolist() == quadrant_image().tolist()
    assert_quadrants(render_file(path), (0.5, 1.0, 0.25))


def test_gltf_material_mapping(tmp_path):
    """The table of docs/materials.md: metallic >= 0.5 a conductor, below a plastic, missing
    factors glTF's defaults (metallic 1, roughness 1), transmission a dielectric with
    KHR_materials_ior and KHR_materials_volume, emission times KHR_materials_emissive_strength,
    doubleSided the sidedness."""
    materials = [
        {"name": "gold", "pbrMetallicRoughness": {"baseColorFactor": [1.0, 0.8, 0.3, 1],
                                                  "metallicFactor": 0.9, "roughnessFactor": 0.3}},
        {"name": "paint", "doubleSided": True,
         "pbrMetallicRoughness": {"baseColorFactor": [0.2, 0.4, 0.6, 1], "metallicFactor": 0.1,
                                  "roughnessFactor": 0.5}},
        {"name": "default"},
        {"name": "glass", "extensions": {
            "KHR_materials_transmission": {"transmissionFactor": 1.0},
            "KHR_materials_ior": {"ior": 1.33},
            "KHR_materials_volume": {"attenuationColor": [0.5, 1.0, 1.0],
                                     "attenuationDistance": 2.0}}},
        {"name": "lamp", "emissiveFactor": [1.0, 0.5, 0.0],
         "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 4.0}},
         "pbrMetallicRoughness": {"metallicFactor": 0.0}},
    ]  # fmt: skip
    path = write_json(tmp_path / "model.gltf", gltf_document(materials))
    m = load_scene(path).materials
    gold = m["model.gltf#gold"]
    assert gold.type == "conductor" and gold.roughness == 0.3
    assert gold.reflectance == (1.0, 0.8, 0.3) and gold.two_sided is False
    paint = m["model.gltf#paint"]
    assert paint.type == "plastic" and paint.reflectance == (0.2, 0.4, 0.6)
    assert paint.roughness == 0.5 and paint.ior == 1.5 and paint.two_sided is True
    default = m["model.gltf#default"]
    assert default.type == "conductor" and default.roughness == 1.0
    assert default.reflectance == (1.0, 1.0, 1.0)
    glass = m["model.gltf#glass"]
    assert glass.type == "dielectric" and glass.ior == 1.33
    assert glass.absorption == pytest.approx((math.log(2.0) / 2.0, 0.0, 0.0))
    lamp = m["model.gltf#lamp"]
    assert lamp.type == "plastic" and lamp.emission == (4.0, 2.0, 0.0)
    assert "default-light" not in load_scene(path).nodes[len(materials) - 1].name


def test_glb_sample_crate_loads_its_texture():
    """The sample crate (written by trimesh, texture embedded in the GLB) is a plastic with its
    texture, and its 24 vertices carry UVs."""
    state = load_scene(SCENES / "textured" / "crate.glb")
    crate = state.materials["crate.glb#crate"]
    assert crate.type == "plastic" and crate.roughness == pytest.approx(0.6)
    assert state.textures[crate.texture.file].shape == (64, 64, 3)
    (mesh,) = [m for key, m in state.meshes.items() if key.startswith("crate.glb:")]
    assert mesh.uvs is not None and mesh.uvs.shape == (24, 2)


OBJ_QUAD = """mtllib quad.mtl
v -1 -1 0
v 1 -1 0
v 1 1 0
v -1 1 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
usemtl pic
f 1/1 2/2 3/3
f 1/1 3/3 4/4
"""


def test_obj_mtl_map_kd(tmp_path):
    """An OBJ whose MTL has ``map_Kd``: the image times Kd is the base colour (OBJ's texture
    coordinates put (0, 0) at the image's bottom left), placed in a JSON scene and alone."""
    Image.fromarray(quadrant_image()).save(tmp_path / "q.png")
    (tmp_path / "quad.mtl").write_text("newmtl pic\nKd 0.2 1 0.6\nmap_Kd q.png\n")
    (tmp_path / "quad.obj").write_text(OBJ_QUAD)
    path = write_json(tmp_path / "scene.json", facing_quad_scene(tmp_path, None, "quad.obj"))
    material = load_scene(path).materials["quad.obj#pic"]
    assert material.type == "diffuse" and material.texture is not None
    assert_quadrants(render_file(path), (0.2, 1.0, 0.6))  # trimesh keeps Kd to 8 bits
    alone = load_scene(tmp_path / "quad.obj")
    assert alone.materials["quad.obj#pic"].texture is not None
    assert len(alone.textures) == 1


def test_snapshot_round_trip_keeps_textures_and_uvs():
    """encode_state / decode_state keep every image and UV bit for bit; the decoded scene
    renders the same pixels."""
    state = load_scene(TEXTURED)
    decoded = decode_state(encode_state(state))
    assert decoded.textures.keys() == state.textures.keys()
    for name, pixels in state.textures.items():
        assert decoded.textures[name].dtype == np.uint8
        assert decoded.textures[name].tobytes() == pixels.tobytes()
    for name, mesh in state.meshes.items():
        if mesh.uvs is None:
            assert decoded.meshes[name].uvs is None
        else:
            assert decoded.meshes[name].uvs.tobytes() == mesh.uvs.tobytes()
    camera = fmt.override(state.camera, width=24, height=18)
    settings = fmt.override(state.render, spp=1, integrator="albedo")
    a = render_image(compile_scene(state), camera, settings)[0]
    b = render_image(compile_scene(decoded), camera, settings)[0]
    assert a.tobytes() == b.tobytes()


def test_moving_an_object_reuses_the_texels():
    """A commit that moves a rigid textured object keeps the packed texels (no re-decoding)."""
    state = load_scene(TEXTURED)
    scene = compile_scene(state)
    crate = next(n.id for n in state.nodes.values() if n.name == "crate")
    ops = parse_ops([{"op": "set_kind", "node": crate, "kind": "rigid"},
                     {"op": "set_transform", "node": crate,
                      "transform": {"translate": [-0.5, 0.5, 0]}}])  # fmt: skip
    moved = compile_scene(apply_ops(state, ops), previous=scene)
    assert moved.textures.pixels is scene.textures.pixels


def test_edits_keep_textures_consistent(tmp_path):
    """Edits: a texture must be one of the scene's images, a textured material needs a mesh
    with UVs, update_vertices keeps the UVs, and add_mesh can give them."""
    path = write_json(tmp_path / "scene.json", uv_scene(tmp_path))
    state = load_scene(path)
    unknown = {"op": "set_material", "name": "other",
               "material": {"texture": {"file": "elsewhere.png"}}}  # fmt: skip
    with pytest.raises(SceneError, match="not one of the scene's images"):
        apply_ops(state, parse_ops([unknown]))
    box = {"op": "add_mesh", "mesh": "tri", "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
           "faces": [[0, 1, 2]]}  # fmt: skip
    node = {"op": "add_node", "name": "t", "kind": "rigid", "mesh": "tri", "material": "pic"}
    with pytest.raises(SceneError, match="has no UVs"):
        apply_ops(state, parse_ops([box, node]))
    with_uvs = apply_ops(state, parse_ops([{**box, "uvs": [[0, 0], [1, 0], [0, 1]]}, node]))
    mesh = with_uvs.meshes["tri"]
    moved = apply_ops(
        with_uvs,
        parse_ops(
            [
                {
                    "op": "update_vertices",
                    "mesh": "tri",
                    "vertices": [[0, 0, 1], [1, 0, 1], [0, 1, 1]],
                }
            ]
        ),
    )
    assert moved.meshes["tri"].uvs is mesh.uvs  # fmt: skip
    compile_scene(moved)


# --- the effect plan -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "integrator, textured, needed",
    [("path", True, True), ("albedo", True, True), ("ao", True, False),
     ("normal", True, False), ("path", False, False)],
)  # fmt: skip
def test_texture_rule(tmp_path, integrator, textured, needed):
    """Textures are needed iff a visible object's material has one and the output reads base
    colours; a textured material no object uses needs none."""
    data = uv_scene(tmp_path, render={"integrator": integrator})
    if not textured:
        data["materials"]["unused"] = data["materials"]["pic"]
        data["materials"]["pic"] = {"reflectance": [1, 1, 1]}
    scene = compile_scene(load_scene(write_json(tmp_path / "scene.json", data)))
    assert ("textures" in effect_plan(scene, scene.render).names()) == needed


# --- bad inputs ------------------------------------------------------------------------------


def load_error(path) -> str:
    with pytest.raises(SceneError) as info:
        compile_scene(load_scene(path))
    message = str(info.value)
    assert message and "\n" not in message
    return message


def textured_scene_file(tmp_path, texture: dict, shape=None) -> object:
    data = facing_quad_scene(tmp_path, {"reflectance": [1, 1, 1], "texture": texture})
    if shape is not None:
        data["objects"][0]["shape"] = shape
    return write_json(tmp_path / "scene.json", data)


def test_missing_texture_file(tmp_path):
    message = load_error(textured_scene_file(tmp_path, {"file": "nope.png"}))
    assert "nope.png" in message and "no such file" in message


@pytest.mark.parametrize("reference", ["../outside.png", "sub/../../outside.png"])
def test_texture_path_leaving_the_scene_directory(tmp_path, reference):
    scene_dir = tmp_path / "scene"
    (scene_dir / "sub").mkdir(parents=True)
    Image.fromarray(quadrant_image()).save(tmp_path / "outside.png")
    message = load_error(textured_scene_file(scene_dir, {"file": reference}))
    assert "may not leave" in message


def test_absolute_texture_path(tmp_path):
    Image.fromarray(quadrant_image()).save(tmp_path / "q.png")
    message = load_error(textured_scene_file(tmp_path, {"file": str(tmp_path / "q.png")}))
    assert "relative" in message


@pytest.mark.parametrize(
    "content, words",
    [(b"just some text", "not an image"), (b"\x89PNG\r\n\x1a\n" + b"\0" * 40, "q.png")],
)
def test_texture_that_is_not_an_image(tmp_path, content, words):
    (tmp_path / "q.png").write_bytes(content)
    message = load_error(textured_scene_file(tmp_path, {"file": "q.png"}))
    assert words in message and "texture" in message


def test_textured_mesh_without_uvs(tmp_path):
    """A textured material on a box (no UVs) or an OBJ without ``vt`` lines: a clear error."""
    Image.fromarray(quadrant_image()).save(tmp_path / "q.png")
    message = load_error(textured_scene_file(tmp_path, {"file": "q.png"}, {"type": "box"}))
    assert "quad" in message and "no UVs" in message
    (tmp_path / "plain.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    message = load_error(textured_scene_file(tmp_path, {"file": "q.png"}, "plain.obj"))
    assert "no UVs" in message


def test_builtin_shape_needs_a_material(tmp_path):
    data = facing_quad_scene(tmp_path, {"reflectance": [1, 1, 1]})
    del data["objects"][0]["material"]
    message = load_error(write_json(tmp_path / "scene.json", data))
    assert "needs a material" in message


def test_file_material_name_clash(tmp_path):
    """A file's material may not take the name of a material of the scene."""
    Image.fromarray(quadrant_image()).save(tmp_path / "q.png")
    (tmp_path / "quad.mtl").write_text("newmtl pic\nKd 1 1 1\nmap_Kd q.png\n")
    (tmp_path / "quad.obj").write_text(OBJ_QUAD)
    data = facing_quad_scene(tmp_path, None, "quad.obj")
    data["materials"]["quad.obj#pic"] = {"reflectance": [1, 1, 1]}
    assert "rename" in load_error(write_json(tmp_path / "scene.json", data))


def test_gltf_image_files_may_not_leave_the_directory(tmp_path):
    """A glTF's external image resolves inside the scene's directory only."""
    scene_dir = tmp_path / "scene"
    scene_dir.mkdir()
    Image.fromarray(quadrant_image()).save(tmp_path / "outside.png")
    document = gltf_document([{"name": "pic", "pbrMetallicRoughness": {
        "baseColorTexture": {"index": 0}}}], quadrant_image())  # fmt: skip
    document["images"] = [{"uri": "../outside.png"}]
    write_json(scene_dir / "quad.gltf", document)
    path = write_json(scene_dir / "scene.json", facing_quad_scene(scene_dir, None, "quad.gltf"))
    state = load_scene(path)  # loads: the texture is left out, never read from outside
    assert not state.textures
    assert json.loads((scene_dir / "quad.gltf").read_text())["images"]
