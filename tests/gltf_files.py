"""Small glTF files for tests: a unit box exported by trimesh (one .gltf, buffers embedded),
its JSON edited before it is written (lights, cameras, extra nodes, materials)."""

import json
from collections.abc import Callable
from pathlib import Path

import trimesh
from trimesh.exchange.gltf import export_gltf


def write_gltf(path: Path, edit: Callable[[dict], None], mesh: trimesh.Trimesh | None = None):
    """Write ``mesh`` (default a unit box) as a .gltf whose JSON ``edit`` changes first."""
    scene = trimesh.Scene()
    scene.add_geometry(mesh or trimesh.creation.box(), node_name="box", geom_name="box")
    files = export_gltf(scene, embed_buffers=True, tree_postprocessor=edit)
    path.write_bytes(files["model.gltf"])
    return path


def read_gltf(path: Path) -> dict:
    return json.loads(path.read_text())


def add_node(tree: dict, node: dict, parent: int | None = None) -> int:
    """Append ``node`` to the tree, as a root of its scene or a child of ``parent``."""
    tree["nodes"].append(node)
    index = len(tree["nodes"]) - 1
    if parent is None:
        tree["scenes"][tree.get("scene", 0)]["nodes"].append(index)
    else:
        tree["nodes"][parent].setdefault("children", []).append(index)
    return index


def add_lights(tree: dict, lights: list[dict]) -> None:
    """The file-level KHR_lights_punctual list."""
    tree.setdefault("extensions", {})["KHR_lights_punctual"] = {"lights": lights}
    tree.setdefault("extensionsUsed", []).append("KHR_lights_punctual")


def light_node(index: int, **node) -> dict:
    return {**node, "extensions": {"KHR_lights_punctual": {"light": index}}}
