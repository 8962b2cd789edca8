"""Mesh files (OBJ, PLY, STL, glTF, GLB) through trimesh: triangles with their UVs (moved by a
glTF material's texture transform) and shading normals (the file's, or smoothed by angle as
the scene's ``MeshFile`` asks), and the file's own materials mapped onto ours (glTF
metallic-roughness, OBJ/MTL diffuse colours and ``map_Kd``), with their base-colour textures.
The mapping table is in docs/materials.md.

Every failure raises :class:`SceneError` with a one-line message.
"""

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pydantic
import trimesh

from tracer.errors import SceneError
from tracer.maths import portable
from tracer.scene import format as fmt
from tracer.scene import gltf_features, vertex_normals
from tracer.scene.gltf_alpha import alpha_mode, check_alpha, material_alpha
from tracer.scene.gltf_cameras import camera_nodes
from tracer.scene.gltf_texture_transform import material_uv_matrix, transformed_uvs
from tracer.scene.model import Mesh, frozen_array, make_mesh, placed
from tracer.shading.textures import (
    alpha_from_image,
    alpha_image_name,
    srgb_to_linear,
    texture_from_image,
)

METALLIC_THRESHOLD = 0.5
"""A glTF material at least this metallic becomes a conductor, below it a plastic."""
TRANSMISSION_THRESHOLD = 0.5
"""A glTF material at least this transmissive (KHR_materials_transmission) becomes a
dielectric."""
DEFAULT_IOR = 1.5
FILE_NORMALS = fmt.MeshFile(path="-")
"""The default shading: the file's normals where it has them, else flat."""
MIN_ATTENUATION = 1e-6
"""KHR_materials_volume attenuation colours are clamped above this before the logarithm."""


def load_trimesh(path: Path):
    """Whatever trimesh makes of ``path`` (a Trimesh or a Scene); SceneError if it cannot. A
    glTF file's cameras and materials' alpha are checked first: trimesh reads them too, and
    fails obscurely on a bad one."""
    document = gltf_features.gltf_json(path)
    if document is not None:
        camera_nodes(document, path.name)
        check_alpha(document, path.name)
    logging.getLogger("trimesh").setLevel(logging.ERROR)
    try:
        return trimesh.load(str(path), process=False)
    except Exception as exc:  # trimesh raises many kinds; all mean "cannot read this file"
        raise SceneError(f"{path.name}: cannot read mesh file ({exc})") from None


@dataclass
class Part:
    """One mesh node of a file: its name, transform in the file, geometry name and mesh."""

    node: str
    matrix: np.ndarray
    geometry: str
    mesh: trimesh.Trimesh


def file_parts(path: Path, loaded) -> list[Part]:
    """The triangle meshes of a loaded file, one per mesh node, in trimesh's node order."""
    if isinstance(loaded, trimesh.Trimesh):
        return [Part(path.stem, np.eye(4), path.stem, loaded)]
    parts = []
    if isinstance(loaded, trimesh.Scene):
        for node in loaded.graph.nodes_geometry:
            geometry_name = loaded.graph.transforms.node_data[node].get("geometry")
            geometry = loaded.geometry[geometry_name]
            if isinstance(geometry, trimesh.Trimesh):
                parts.append(
                    Part(str(node), _file_matrix(loaded.graph, node), geometry_name, geometry)
                )
    return parts


def _file_matrix(graph, node) -> np.ndarray:
    """The node's matrix in the file's base frame: the matrices on the path from the base frame,
    multiplied in order with ``tracer.maths.portable`` (trimesh's own product goes through BLAS)."""
    parents = graph.transforms.parents
    edges = graph.transforms.edge_data
    path = []
    while node != graph.base_frame and node in parents:
        parent = parents[node]
        path.append(edges[(parent, node)].get("matrix", np.eye(4)))
        node = parent
    return portable.chain(np.eye(4), *reversed(path))


def mesh_uvs(geometry: trimesh.Trimesh) -> np.ndarray | None:
    """The mesh's UVs per vertex (float64 (V, 2)), or None if it has none."""
    uv = getattr(geometry.visual, "uv", None)
    if uv is None or len(uv) != len(geometry.vertices) or np.ndim(uv) != 2:
        return None
    return np.asarray(uv, dtype=np.float64)[:, :2]


def file_normals(geometry: trimesh.Trimesh, in_file: bool) -> np.ndarray | None:
    """The normals per vertex the file gives a mesh (glTF NORMAL, OBJ vn, PLY nx ny nz), in
    trimesh's vertex order, or None. trimesh keeps the normals it reads in its cache and
    computes others only when asked, so an entry there before anyone asked is the file's;
    ``in_file`` is false when the file's JSON says it has none (glTF)."""
    cached = geometry._cache.cache.get("vertex_normals") if in_file else None
    if cached is None or np.shape(cached) != np.shape(geometry.vertices):
        return None
    return np.asarray(cached, dtype=np.float64)


def part_arrays(part: Part, label: str, in_file: bool, shape: fmt.MeshFile):
    """``(vertices, faces, uvs, normals)`` of a part in its own coordinates, the normals as
    ``shape`` asks: the file's (repaired where one has no length), smooth with creases at
    ``smooth_angle`` where the file has none, else None (flat). Checked (``make_mesh``) when
    normals are computed from the triangles."""
    vertices = np.asarray(part.mesh.vertices, dtype=np.float64)
    faces = np.asarray(part.mesh.faces, dtype=np.int64)
    uvs = mesh_uvs(part.mesh)
    normals = file_normals(part.mesh, in_file) if shape.normals == "file" else None
    if len(faces) == 0:
        return vertices, faces, uvs, None
    if normals is None and shape.smooth_angle is None:
        return vertices, faces, uvs, None
    make_mesh(vertices, faces, label, uvs)
    if normals is not None:
        return vertices, faces, uvs, vertex_normals.repaired(normals, vertices, faces)
    return _creased(vertices, faces, uvs, shape.smooth_angle)


def _creased(vertices, faces, uvs, angle: float):
    """``vertex_normals.creased`` at ``angle`` degrees, vertices and UVs split to follow."""
    source, faces, normals = vertex_normals.creased(vertices, faces, angle)
    return vertices[source], faces, None if uvs is None else uvs[source], normals


def shading_key(shape: fmt.MeshFile) -> str:
    """What tells a file's meshes with the normals ``shape`` asks for from the same file's
    meshes with the default normals, for their keys: empty for the default."""
    if shape.normals == "flat":
        return "?normals=flat"
    return "" if shape.smooth_angle is None else f"?smooth_angle={shape.smooth_angle!r}"


def load_mesh_file(path: Path, shape: fmt.MeshFile | None = None) -> Mesh:
    """All triangles of a mesh file in its own coordinates (glTF node transforms applied, as
    trimesh bakes them), with UVs if every part has them and normals (``part_arrays``) if
    any part has them (the others then get their flat normals, split per face)."""
    shape = shape or FILE_NORMALS
    loaded = load_trimesh(path)
    if isinstance(loaded, trimesh.Scene) and not loaded.geometry:
        raise SceneError(f"{path.name}: the file contains no meshes")
    parts = file_parts(path, loaded)
    if not parts:
        raise SceneError(f"{path.name}: the file holds no triangles (points or lines only?)")
    in_file = _normals_in_file(path)
    arrays = [part_arrays(part, path.name, in_file, shape) for part in parts]
    smooth = any(normals is not None for *_, normals in arrays)
    vertices, faces, uvs, normals = [], [], [], []
    count = 0
    for part, arrays_of_part in zip(parts, arrays, strict=True):
        part_vertices, part_faces, part_uvs, part_normals = arrays_of_part
        if smooth and part_normals is None:  # flat: a vertex per face corner, face normals
            if len(part_faces):
                make_mesh(part_vertices, part_faces, path.name, part_uvs)
            part_vertices, part_faces, part_uvs, part_normals = _creased(
                part_vertices, part_faces, part_uvs, 0.0
            )
        baked, part_faces = placed(part_vertices, part_faces, part.matrix)
        vertices.append(baked)
        faces.append(part_faces + count)
        uvs.append(part_uvs)
        if smooth:
            moved = vertex_normals.transformed(part_normals, part.matrix)
            normals.append(vertex_normals.repaired(moved, baked, part_faces))
        count += len(baked)
    uv = None if any(u is None for u in uvs) else np.concatenate(uvs)
    normal = np.concatenate(normals) if smooth else None
    return make_mesh(np.concatenate(vertices), np.concatenate(faces), path.name, uv, normal)


def _normals_in_file(path: Path) -> bool:
    """False when the file certainly has no normals (a glTF whose JSON has no NORMAL)."""
    document = gltf_features.gltf_json(path)
    return document is None or gltf_features.has_normals(document)


@dataclass
class FileModel:
    """A mesh file with its own materials: ``parts`` are ``(node name, matrix in the file,
    mesh key, material key)``; ``meshes``, ``materials`` and ``textures`` are keyed by those
    keys (and texture names)."""

    parts: list[tuple[str, np.ndarray, str, str]] = field(default_factory=list)
    meshes: dict[str, Mesh] = field(default_factory=dict)
    materials: dict[str, fmt.Material] = field(default_factory=dict)
    textures: dict[str, np.ndarray] = field(default_factory=dict)


def load_file_model(
    path: Path, reference: str, mesh_prefix: str, shape: fmt.MeshFile | None = None
) -> FileModel:
    """The file's meshes (one per geometry, keyed ``mesh_prefix + geometry``, with normals as
    ``shape`` asks: ``part_arrays``) and materials (keyed ``reference#name``), each node a
    part; textures are named ``reference#imageN``."""
    shape = shape or FILE_NORMALS
    loaded = load_trimesh(path)
    parts = file_parts(path, loaded)
    if not parts:
        raise SceneError(f"{path.name}: the file contains no triangle meshes")
    model = FileModel()
    mapper = _MaterialMapper(path, reference, model.textures)
    in_file = _normals_in_file(path)
    for part in parts:
        mesh_key = f"{mesh_prefix}{part.geometry}"
        material = getattr(part.mesh.visual, "material", None)
        if mesh_key not in model.meshes:
            label = f"{path.name}:{part.node}"
            vertices, faces, uvs, normals = part_arrays(part, label, in_file, shape)
            uv_matrix = mapper.uv_matrix(material)
            if uvs is not None and uv_matrix is not None:
                uvs = transformed_uvs(uvs, uv_matrix)
            model.meshes[mesh_key] = make_mesh(vertices, faces, label, uvs, normals)
        uvs_present = model.meshes[mesh_key].uvs is not None
        material_key = mapper.key(material, uvs_present, model.materials)
        try:
            matrix = fmt.Transform(matrix=tuple(map(tuple, part.matrix))).to_matrix()
        except pydantic.ValidationError as exc:
            problem = exc.errors()[0]["msg"].removeprefix("Value error, ")
            raise SceneError(f"{path.name}:{part.node}: transform: {problem}") from None
        model.parts.append((part.node, frozen_array(matrix, np.float64), mesh_key, material_key))
    return model


class _MaterialMapper:
    """Names and converts a file's materials, each trimesh material object once."""

    def __init__(self, path: Path, reference: str, textures: dict[str, np.ndarray]) -> None:
        self.path = path
        self.reference = reference
        self.textures = textures
        self.keys: dict[tuple[int, bool], str] = {}
        self.image_keys: dict[int, str] = {}
        self.gltf = gltf_materials(path)

    def key(self, material, uvs_present: bool, materials: dict[str, fmt.Material]) -> str:
        """The key of ``material`` (converted and stored in ``materials`` the first time); a
        texture is dropped for meshes without UVs (a material of its own)."""
        ident = (id(material), uvs_present)
        if ident in self.keys:
            return self.keys[ident]
        name = getattr(material, "name", None) or ("default" if material is None else "material")
        key = f"{self.reference}#{name}"
        converted = self.convert(material, key)
        if not uvs_present and getattr(converted, "texture", None) is not None:
            converted = converted.model_copy(update={"texture": None})
        alpha = getattr(converted, "alpha", None)
        if not uvs_present and alpha is not None and alpha.texture is not None:
            alpha = alpha.model_copy(update={"texture": None})
            converted = converted.model_copy(update={"alpha": alpha})
        if not uvs_present and getattr(converted, "normal_map", None) is not None:
            converted = converted.model_copy(update={"normal_map": None})
            key += " (no UVs)"
        base, n = key, 1
        while key in materials:
            n += 1
            key = f"{base}-{n}"
        materials[key] = converted
        self.keys[ident] = key
        return key

    def uv_matrix(self, material) -> np.ndarray | None:
        """The ``KHR_texture_transform`` of a glTF material (matched by name), or None."""
        name = getattr(material, "name", None)
        if not isinstance(material, trimesh.visual.material.PBRMaterial) or not name:
            return None
        where = f"{self.path.name}: material {name!r}"
        return material_uv_matrix(self.gltf.get(name, {}), where)

    def texture(self, image, wrap: str = "repeat") -> fmt.Texture:
        """A texture model for a PIL image of the file (stored once under its name)."""
        if id(image) not in self.image_keys:
            name = f"{self.reference}#image{len(self.image_keys)}"
            self.textures[name] = texture_from_image(image, f"{self.path.name}: {name}")
            self.image_keys[id(image)] = name
        return fmt.Texture(file=self.image_keys[id(image)], wrap=wrap)

    def alpha_texture(self, image) -> fmt.Texture | None:
        """A texture model of a PIL image's alpha channel (stored once, as the grey image
        ``alpha_image_name`` of the image's name), or None if it has none."""
        texture = self.texture(image)
        name = alpha_image_name(texture.file)
        if name not in self.textures:
            pixels = alpha_from_image(image, f"{self.path.name}: {texture.file}")
            if pixels is None:
                return None
            self.textures[name] = pixels
        return texture

    def normal_map(self, image, spec: dict) -> fmt.NormalMap | None:
        """A glTF ``normalTexture`` as a normal map (its ``scale`` the strength), or None."""
        if image is None:
            return None
        texture = self.texture(image)
        info = spec.get("normalTexture", {})
        strength = _factor(info.get("scale") if isinstance(info, dict) else None, 1.0)
        return fmt.NormalMap(file=texture.file, wrap=texture.wrap, strength=max(strength, 0.0))

    def convert(self, material, label: str) -> fmt.Material:
        if isinstance(material, trimesh.visual.material.PBRMaterial):
            spec = self.gltf.get(material.name, {}) if material.name else {}
            return self.pbr(material, spec, label)
        if isinstance(material, trimesh.visual.material.SimpleMaterial):
            texture = None if material.image is None else self.texture(material.image)
            return fmt.DiffuseMaterial(
                reflectance=_colour(np.asarray(material.diffuse[:3], np.float64) / 255.0),
                texture=texture,
            )
        return fmt.DiffuseMaterial(reflectance=(1.0, 1.0, 1.0))

    def pbr(self, material, spec: dict, label: str) -> fmt.Material:
        """A glTF metallic-roughness material as ours (docs/materials.md has the table);
        ``spec`` is the material's own JSON when it can be found (exact factors and the
        KHR extensions trimesh does not keep)."""
        pbr = spec.get("pbrMetallicRoughness", {})
        extensions = spec.get("extensions", {})
        base = np.ones(3)
        if "baseColorFactor" in pbr:
            base = np.asarray(pbr["baseColorFactor"][:3], dtype=np.float64)
        elif material.baseColorFactor is not None:
            base = np.asarray(material.baseColorFactor[:3], dtype=np.float64) / 255.0
        metallic = _factor(pbr.get("metallicFactor", material.metallicFactor), 1.0)
        roughness = _factor(pbr.get("roughnessFactor", material.roughnessFactor), 1.0)
        if material.metallicRoughnessTexture is not None:
            mr = np.asarray(material.metallicRoughnessTexture.convert("RGB"), np.float64) / 255.0
            roughness *= float(mr[..., 1].mean())
            metallic *= float(mr[..., 2].mean())
        emission = np.zeros(3)
        if material.emissiveFactor is not None:
            emission = np.asarray(spec.get("emissiveFactor", material.emissiveFactor)[:3], float)
        strength = extensions.get("KHR_materials_emissive_strength", {})
        emission = emission * _factor(strength.get("emissiveStrength"), 1.0)
        if material.emissiveTexture is not None and emission.max() > 0.0:
            pixels = texture_from_image(material.emissiveTexture, f"{self.path.name}: emission")
            emission = emission * srgb_to_linear(pixels).reshape(-1, 3).mean(axis=0)
        ior = _factor(extensions.get("KHR_materials_ior", {}).get("ior"), DEFAULT_IOR)
        transmission = extensions.get("KHR_materials_transmission", {})
        if _factor(transmission.get("transmissionFactor"), 0.0) >= TRANSMISSION_THRESHOLD:
            return fmt.DielectricMaterial(
                type="dielectric",
                ior=min(max(ior, 1.0), 10.0),
                absorption=_absorption(extensions.get("KHR_materials_volume", {})),
            )
        alpha = None
        where = f"{self.path.name}: material {material.name or label!r}"
        if emission.max() <= 0.0 and alpha_mode(spec, material, where) != "OPAQUE":
            image = material.baseColorTexture  # emitters stay opaque (gltf_features warns)
            texture = None if image is None else self.alpha_texture(image)
            alpha = material_alpha(spec, material, texture, where)
        common = {
            "reflectance": _colour(base),
            "roughness": min(max(roughness, 0.0), 1.0),
            "emission": tuple(float(max(e, 0.0)) for e in emission),
            "two_sided": bool(spec.get("doubleSided", material.doubleSided)),
            "texture": None
            if material.baseColorTexture is None
            else self.texture(material.baseColorTexture),
            "normal_map": self.normal_map(getattr(material, "normalTexture", None), spec),
            "alpha": alpha,
        }
        if metallic >= METALLIC_THRESHOLD:
            return fmt.ConductorMaterial(type="conductor", **common)
        coat = ior if 1.0 < ior <= 3.0 else DEFAULT_IOR
        return fmt.PlasticMaterial(type="plastic", ior=coat, **common)


def _factor(value, default: float) -> float:
    """A finite number from a file, else ``default``."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        return default
    return number if math.isfinite(number) else default


def _colour(values: np.ndarray) -> tuple[float, float, float]:
    return tuple(float(c) for c in np.clip(np.nan_to_num(values), 0.0, 1.0))


def _absorption(volume: dict) -> tuple[float, float, float]:
    """KHR_materials_volume's attenuation as a Beer-Lambert coefficient:
    ``-ln(attenuationColor) / attenuationDistance`` (none without a distance)."""
    distance = _factor(volume.get("attenuationDistance"), math.inf)
    if not 0.0 < distance < math.inf:
        return (0.0, 0.0, 0.0)
    colour = np.asarray(volume.get("attenuationColor", [1.0, 1.0, 1.0]), dtype=np.float64)[:3]
    colour = np.clip(np.nan_to_num(colour, nan=1.0), MIN_ATTENUATION, 1.0)
    return tuple(float(max(0.0, -math.log(c) / distance)) for c in colour)


def gltf_materials(path: Path) -> dict[str, dict]:
    """A glTF or GLB file's materials by name (names used once only), as its JSON gives them;
    empty for other files or when the JSON cannot be read (trimesh already read the file)."""
    document = gltf_features.gltf_json(path) or {}
    materials = document.get("materials", [])
    if not isinstance(materials, list):
        return {}
    names = [m.get("name") for m in materials if isinstance(m, dict)]
    return {
        m["name"]: m
        for m in materials
        if isinstance(m, dict) and isinstance(m.get("name"), str) and names.count(m["name"]) == 1
    }
