"""What a scene file takes of its objects' glTF files besides meshes and materials: the lights
of objects with ``"lights": true`` and the camera ``camera.from_object`` names, each placed by
its object's transform (and its parents'). The scene holds them once, in world space, so the
object and its parents must be static."""

from pathlib import Path

import numpy as np

from tracer.errors import SceneError
from tracer.maths import portable
from tracer.scene import format as fmt
from tracer.scene import gltf_cameras
from tracer.scene.gltf_features import gltf_json
from tracer.scene.gltf_lights import file_lights


def _placement(scene: fmt.SceneFile, index: int, what: str) -> np.ndarray:
    """The world matrix of ``scene.objects[index]``, which with its parents must be static."""
    names = {obj.name: i for i, obj in enumerate(scene.objects) if obj.name}
    label = scene.objects[index].name or f"objects[{index}]"
    matrices = []
    i = index
    while i is not None:
        obj = scene.objects[i]
        if obj.kind != "static":
            raise SceneError(
                f"{label}: {what} are placed once, so the object and its parents must be "
                f"static ({obj.name or f'objects[{i}]'} is {obj.kind})"
            )
        matrices.append(obj.transform.to_matrix())
        parent = None if obj.parent is None else names.get(obj.parent)
        if obj.parent is not None and (parent is None or parent >= i):
            raise SceneError(f"{label}: parent {obj.parent!r} is not an earlier object")
        i = parent
    return portable.chain(np.eye(4), *reversed(matrices))


def _document(scene_dir: Path, obj: fmt.SceneObject, label: str, resolve) -> dict:
    document = gltf_json(resolve(scene_dir, obj.shape.path))
    if document is None:
        raise SceneError(f"{label}: {obj.shape.path} is not a glTF file (no lights or cameras)")
    return document


def object_lights(scene: fmt.SceneFile, scene_dir: Path, resolve) -> list:
    """The lights of the glTF files of objects with ``lights`` true, in object order, placed;
    ``resolve(scene_dir, reference)`` finds a file (``loader.resolve_reference``)."""
    lights = []
    for i, obj in enumerate(scene.objects):
        if isinstance(obj.shape, fmt.MeshFile) and obj.shape.lights:
            label = obj.name or f"objects[{i}]"
            document = _document(scene_dir, obj, label, resolve)
            placement = _placement(scene, i, "a file's lights")
            lights += file_lights(document, obj.shape.path, placement)
    return lights


def object_camera(scene: fmt.SceneFile, scene_dir: Path, resolve) -> fmt.Camera:
    """The scene's camera: its own, or the one ``camera.from_object`` names, placed."""
    camera = scene.camera
    if not isinstance(camera, fmt.FileCamera):
        return camera
    index = max(i for i, obj in enumerate(scene.objects) if obj.name == camera.from_object)
    obj = scene.objects[index]
    where = f"camera.from_object {camera.from_object!r}"
    document = _document(scene_dir, obj, where, resolve)
    placement = _placement(scene, index, "a file's cameras")
    entry = gltf_cameras.chosen(document, obj.shape.path, camera.name)
    if entry is None:
        raise SceneError(f"{where}: {obj.shape.path} has no perspective camera")
    image = camera.model_dump(exclude={"from_object", "name"})
    return gltf_cameras.view(entry, placement, f"{where}: {obj.shape.path}", **image)
