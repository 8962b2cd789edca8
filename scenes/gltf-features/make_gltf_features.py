"""Make the glTF features sample: one ``gltf-features.gltf`` (buffers and images embedded) that
renders on its own with what an exporter writes besides triangles.

Run from the repository root (it rewrites the file beside this script)::

    python scenes/gltf-features/make_gltf_features.py

- a smooth sphere: vertex normals (``NORMAL``) on a coarse icosphere, a red plastic;
- a tiled floor: a base-colour checker and a normal map of bevelled tiles, both repeated 4x4
  by the same ``KHR_texture_transform`` (scale [4, 4], rotation 0.3 rad);
- a glowing block: ``emissiveFactor`` times ``KHR_materials_emissive_strength``;
- ``KHR_lights_punctual``: a spot above the sphere, a warm point light at the side, a dim
  directional light (intensities in candela and lux: 683 per W/sr or W/m^2);
- a perspective camera (``yfov``, ``aspectRatio`` 4:3) on a node looking at the sphere.

trimesh writes the meshes, materials and images; the extensions, lights and camera are added
to its JSON before it is written. Every image is computed here; the output is the same on
every run.
"""

import math
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image
from trimesh.exchange.gltf import export_gltf

HERE = Path(__file__).resolve().parent
LUMENS_PER_WATT = 683.0


def checker(size: int = 64) -> np.ndarray:
    """A 2x2 checker of warm light and slate grey, uint8 (size, size, 3)."""
    y, x = np.mgrid[0:size, 0:size]
    dark = (x < size // 2) != (y < size // 2)
    return np.where(dark[..., None], [[[70, 76, 86]]], [[[214, 200, 176]]]).astype(np.uint8)


def tile_normals(size: int = 64, bevel: float = 0.12) -> np.ndarray:
    """A tangent-space normal map of two by two tiles with bevelled edges (+x right, +y up in
    the image, as glTF's OpenGL convention), uint8 (size, size, 3)."""
    y, x = np.mgrid[0:size, 0:size] / size * 2.0 % 1.0  # position inside a tile, [0, 1)
    y = 1.0 - y  # image rows run down, the map's +y up
    nx = np.where(x < bevel, -1.0, np.where(x > 1 - bevel, 1.0, 0.0)) * 0.6
    ny = np.where(y < bevel, -1.0, np.where(y > 1 - bevel, 1.0, 0.0)) * 0.6
    normal = np.stack([nx, ny, np.ones_like(nx)], axis=-1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    return np.rint((normal * 0.5 + 0.5) * 255).astype(np.uint8)


def floor() -> trimesh.Trimesh:
    """A 6 x 6 square in the xz plane facing +y, UVs over [0, 1]."""
    vertices = [[-3, 0, 3], [3, 0, 3], [3, 0, -3], [-3, 0, -3]]
    mesh = trimesh.Trimesh(vertices, [[0, 1, 2], [0, 2, 3]], process=False)
    material = trimesh.visual.material.PBRMaterial(
        name="tiles", metallicFactor=0.0, roughnessFactor=0.5,
        baseColorTexture=Image.fromarray(checker()),
        normalTexture=Image.fromarray(tile_normals()),
    )  # fmt: skip
    mesh.visual = trimesh.visual.TextureVisuals(uv=[[0, 0], [1, 0], [1, 1], [0, 1]],
                                                material=material)  # fmt: skip
    return mesh


def sphere() -> trimesh.Trimesh:
    """A coarse icosphere (320 faces) with its vertices' directions as normals."""
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.7)
    mesh.vertex_normals = mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)
    mesh.visual = trimesh.visual.TextureVisuals(
        material=trimesh.visual.material.PBRMaterial(
            name="red plastic",
            baseColorFactor=[200, 30, 25, 255],
            metallicFactor=0.0,
            roughnessFactor=0.3,
        )
    )
    return mesh


def block() -> trimesh.Trimesh:
    mesh = trimesh.creation.box(extents=[0.5, 0.5, 0.5])
    mesh.visual = trimesh.visual.TextureVisuals(
        material=trimesh.visual.material.PBRMaterial(
            name="glow",
            baseColorFactor=[20, 20, 20, 255],
            metallicFactor=0.0,
            emissiveFactor=[1.0, 0.6, 0.2],
        )
    )
    return mesh


def look_rotation(forward, up=(0.0, 1.0, 0.0)) -> list[float]:
    """glTF's (x, y, z, w) turning a node's -Z onto ``forward`` with its +Y toward ``up``."""
    back = -np.asarray(forward, float) / np.linalg.norm(forward)
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    matrix = np.eye(4)
    matrix[:3, :3] = np.column_stack([right, np.cross(back, right), back])
    w, x, y, z = trimesh.transformations.quaternion_from_matrix(matrix)
    return [x, y, z, w]


def add_features(tree: dict) -> None:
    """Texture transforms, emissive strength, lights and a camera in trimesh's JSON."""
    transform = {"KHR_texture_transform": {"scale": [4, 4], "rotation": 0.3}}
    for material in tree["materials"]:
        if material.get("name") == "tiles":
            material["pbrMetallicRoughness"]["baseColorTexture"]["extensions"] = transform
            material["normalTexture"]["extensions"] = transform
        if material.get("name") == "glow":
            material["extensions"] = {"KHR_materials_emissive_strength": {"emissiveStrength": 4}}
    tree["extensions"] = {"KHR_lights_punctual": {"lights": [
        {"name": "spot", "type": "spot", "color": [1.0, 0.95, 0.85],
         "intensity": 12 * LUMENS_PER_WATT,
         "spot": {"innerConeAngle": math.radians(15), "outerConeAngle": math.radians(30)}},
        {"name": "warm", "type": "point", "color": [1.0, 0.7, 0.45],
         "intensity": 3 * LUMENS_PER_WATT},
        {"name": "sky", "type": "directional", "color": [0.7, 0.8, 1.0],
         "intensity": 0.4 * LUMENS_PER_WATT},
    ]}}  # fmt: skip
    tree["cameras"] = [{"name": "view", "type": "perspective",
                        "perspective": {"yfov": math.radians(40), "aspectRatio": 4 / 3,
                                        "znear": 0.05}}]  # fmt: skip
    position = np.array([0.0, 2.2, 5.2])
    nodes = [
        {"name": "spot", "translation": [0.3, 4.0, 0.8], "rotation":
         look_rotation([-0.3, -3.3, -0.8], up=(0.0, 0.0, -1.0)),
         "extensions": {"KHR_lights_punctual": {"light": 0}}},
        {"name": "warm", "translation": [-2.2, 1.4, 1.2],
         "extensions": {"KHR_lights_punctual": {"light": 1}}},
        {"name": "sky", "rotation": look_rotation([0.4, -1.0, -0.5]),
         "extensions": {"KHR_lights_punctual": {"light": 2}}},
        {"name": "camera", "camera": 0, "translation": position.tolist(),
         "rotation": look_rotation(np.array([0.2, 0.5, 0.0]) - position)},
    ]  # fmt: skip
    for node in nodes:
        tree["nodes"].append(node)
        tree["scenes"][0]["nodes"].append(len(tree["nodes"]) - 1)
    tree["extensionsUsed"] = sorted(
        set(tree.get("extensionsUsed", []))
        | {"KHR_texture_transform", "KHR_materials_emissive_strength", "KHR_lights_punctual"}
    )


def main() -> None:
    scene = trimesh.Scene()
    scene.add_geometry(floor(), node_name="floor", geom_name="floor")
    ball = trimesh.transformations.translation_matrix([0.2, 0.7, 0.0])
    scene.add_geometry(sphere(), node_name="sphere", geom_name="sphere", transform=ball)
    glow = trimesh.transformations.translation_matrix([-1.3, 0.25, -0.8])
    scene.add_geometry(block(), node_name="block", geom_name="block", transform=glow)
    files = export_gltf(scene, include_normals=True, embed_buffers=True,
                        tree_postprocessor=add_features)  # fmt: skip
    (HERE / "gltf-features.gltf").write_bytes(files["model.gltf"])


if __name__ == "__main__":
    main()
