"""Warnings about what tilerender ignores or approximates of a glTF file
(``tracer.scene.gltf_features``, ``tracer.scene.loader.load_warnings``): one per feature, about
materials only where the file's materials are used, shown by ``tilerender info``; loading is
the same with or without the features; every warning's feature is in docs/materials.md's
table."""

import json
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from cli import main as cli_main
from tests.helpers import tiny_scene, write_json
from tracer.scene import gltf_features
from tracer.scene.gltf_features import feature_warnings, used_features
from tracer.scene.loader import load_scene, load_warnings

DOCS = Path(__file__).resolve().parents[2] / "docs" / "materials.md"
NORMAL_TEXTURE = (
    "normalTexture approximated: a tangent frame per triangle from its UVs, not MikkTSpace"
)


def textured_box(path: Path, **material) -> Path:
    """A box with UVs and a PBR material (``material`` adds e.g. a normalTexture), as glTF."""
    box = trimesh.creation.box()
    mesh = trimesh.Trimesh(box.vertices, box.faces, process=False)
    image = Image.fromarray(np.full((4, 4, 3), 128, np.uint8))
    pbr = trimesh.visual.material.PBRMaterial(
        name="paint", baseColorTexture=image, metallicFactor=0.0, **material
    )
    mesh.visual = trimesh.visual.TextureVisuals(uv=box.vertices[:, :2] + 0.5, material=pbr)
    scene = trimesh.Scene()
    scene.add_geometry(mesh, node_name="box", geom_name="box")
    path.write_bytes(scene.export(file_type="glb"))
    return path


def test_normal_texture_becomes_a_normal_map_and_warns(tmp_path):
    image = Image.fromarray(np.full((4, 4, 3), 200, np.uint8))
    bumpy = textured_box(tmp_path / "bumpy.glb", normalTexture=image)
    plain = textured_box(tmp_path / "plain.glb")
    assert load_warnings(bumpy) == [f"bumpy.glb: {NORMAL_TEXTURE}"]
    assert load_warnings(plain) == []
    a, b = load_scene(bumpy), load_scene(plain)
    untextured = {"texture": None, "normal_map": None}
    assert a.materials["bumpy.glb#paint"].model_copy(update=untextured) == b.materials[
        "plain.glb#paint"
    ].model_copy(update=untextured)
    assert a.materials["bumpy.glb#paint"].texture is not None
    normal_map = a.materials["bumpy.glb#paint"].normal_map
    assert normal_map is not None and normal_map.strength == 1.0
    assert b.materials["plain.glb#paint"].normal_map is None
    np.testing.assert_array_equal(a.textures[normal_map.file], np.full((4, 4, 3), 200))
    (mesh_a,), (mesh_b,) = (
        [m for key, m in state.meshes.items() if key.endswith(":box")] for state in (a, b)
    )
    np.testing.assert_array_equal(mesh_a.vertices, mesh_b.vertices)
    np.testing.assert_array_equal(mesh_a.uvs, mesh_b.uvs)


def test_material_warnings_only_where_the_files_materials_are_used(tmp_path):
    image = Image.fromarray(np.full((4, 4, 3), 200, np.uint8))
    textured_box(tmp_path / "bumpy.glb", normalTexture=image)
    data = tiny_scene()
    data["objects"][1]["shape"] = "bumpy.glb"
    path = write_json(tmp_path / "scene.json", data)
    assert load_warnings(path) == []  # the scene's own material: the file's is not used
    data["objects"].append({"name": "own", "shape": "bumpy.glb"})
    write_json(path, data)
    assert load_warnings(path) == [f"bumpy.glb: {NORMAL_TEXTURE}"]  # once per file


def test_info_shows_the_warnings(tmp_path, capsys):
    image = Image.fromarray(np.full((4, 4, 3), 200, np.uint8))
    path = textured_box(tmp_path / "bumpy.glb", normalTexture=image)
    assert cli_main.main(["info", str(path)]) == 0
    assert json.loads(capsys.readouterr().out)["warnings"] == [f"bumpy.glb: {NORMAL_TEXTURE}"]


EVERYTHING = {
    "extensionsUsed": ["KHR_lights_punctual", "KHR_texture_transform", "KHR_materials_ior",
                       "EXT_mesh_gpu_instancing"],
    "skins": [{"joints": [0]}],
    "animations": [{"channels": [], "samplers": []}],
    "cameras": [{"type": "perspective", "perspective": {"yfov": 1.0, "znear": 0.1}},
                {"type": "orthographic"}],
    "extensions": {"KHR_lights_punctual": {"lights": [{"type": "point", "range": 5}]}},
    "accessors": [{"count": 3, "sparse": {"count": 1}}],
    "samplers": [{"wrapS": 33071, "magFilter": 9728}],
    "meshes": [{"primitives": [{
        "attributes": {"POSITION": 0, "NORMAL": 1, "TANGENT": 2, "TEXCOORD_0": 3, "COLOR_0": 4},
        "targets": [{"POSITION": 5}],
        "extensions": {"KHR_draco_mesh_compression": {}},
    }]}],
    "materials": [{
        "normalTexture": {"index": 0, "texCoord": 1}, "occlusionTexture": {"index": 0},
        "emissiveTexture": {"index": 0}, "alphaMode": "BLEND",
        "pbrMetallicRoughness": {"metallicFactor": 0.3, "metallicRoughnessTexture": {"index": 0},
                                 "baseColorTexture": {"index": 0, "extensions": {
                                     "KHR_texture_transform": {"scale": [2, 2]}}}},
        "extensions": {"KHR_materials_transmission": {"transmissionFactor": 0.7},
                       "KHR_materials_clearcoat": {}, "KHR_materials_sheen": {},
                       "KHR_materials_specular": {}, "KHR_materials_ior": {"ior": 1.4},
                       "KHR_materials_volume": {}, "KHR_materials_emissive_strength": {}},
    }],
}  # fmt: skip


def test_every_feature_warns_once_in_the_tables_order():
    warnings = feature_warnings(EVERYTHING)
    expected = [
        *gltf_features.GEOMETRY_WARNINGS.values(),
        *[text for key, text in gltf_features.MATERIAL_WARNINGS.items()
          if key != "KHR_materials_pbrSpecularGlossiness"],
        "EXT_mesh_gpu_instancing ignored",
        "KHR_materials_clearcoat ignored",
        "KHR_materials_sheen ignored",
        "KHR_materials_specular ignored",
    ]  # fmt: skip
    expected.remove(gltf_features.GEOMETRY_WARNINGS["EXT_meshopt_compression"])
    taken = [gltf_features.GEOMETRY_WARNINGS[key] for key in ("cameras", "KHR_lights_punctual")]
    assert warnings == [w for w in expected if w not in taken]  # the file's lights and camera
    geometry_only = feature_warnings(EVERYTHING, materials=False)
    assert geometry_only == [w for w in warnings if w in gltf_features.GEOMETRY_WARNINGS.values()]
    not_taken = [gltf_features.GEOMETRY_WARNINGS[key] for key in ("orthographic", "range")]
    assert feature_warnings(EVERYTHING, lights=False, cameras=False) == [
        w for w in expected if w not in not_taken
    ]
    assert not (used_features(EVERYTHING) - {"KHR_lights_punctual", "KHR_texture_transform"}) & (
        gltf_features.READ_EXTENSIONS
    )


def test_what_is_read_does_not_warn():
    """Factors of 0 or 1, glass at transmission 1, OPAQUE alpha, REPEAT wrapping, the
    extensions the mapping reads, lights without a range, perspective cameras and one texture
    transform per named material (with a texCoord override back to 0) give no warning (the
    normal map's own approximation aside)."""
    transform = {"KHR_texture_transform": {"offset": [0.5, 0], "texCoord": 0}}
    document = {
        "extensionsUsed": ["KHR_materials_ior", "KHR_materials_emissive_strength",
                           "KHR_lights_punctual", "KHR_texture_transform"],
        "extensions": {"KHR_lights_punctual": {"lights": [{"type": "spot"}]}},
        "cameras": [{"type": "perspective", "perspective": {"yfov": 1.0, "znear": 0.1}}],
        "samplers": [{"wrapS": 10497, "wrapT": 10497, "magFilter": 9729}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1,
                                                   "TEXCOORD_0": 2}}]}],
        "materials": [{"name": "paint", "alphaMode": "OPAQUE",
                       "normalTexture": {"index": 0, "texCoord": 1, "extensions": transform},
                       "pbrMetallicRoughness": {"metallicFactor": 0, "baseColorTexture": {
                           "index": 0, "extensions": transform}},
                       "extensions": {"KHR_materials_transmission": {"transmissionFactor": 1},
                                      "KHR_materials_volume": {"attenuationDistance": 1}}}],
    }  # fmt: skip
    assert feature_warnings(document) == [NORMAL_TEXTURE]  # MikkTSpace: not its transform


def test_the_feature_table_names_every_warned_feature():
    """docs/materials.md's glTF feature table has a row for every feature that warns."""
    text = DOCS.read_text(encoding="utf-8")
    table = text[text.index("### glTF features") :]
    for warning in [*gltf_features.GEOMETRY_WARNINGS.values(),
                    *gltf_features.MATERIAL_WARNINGS.values()]:  # fmt: skip
        feature = warning.split(" ignored")[0].split(" approximated")[0].split(" not decoded")[0]
        feature = feature.split(" between")[0].removeprefix("texture sampler ")
        assert feature.split()[0] in table, feature
