"""What tilerender ignores or approximates of a glTF 2.0 file: one short warning per feature the
file uses, read from its JSON (the feature table is in docs/materials.md, "Materials from mesh
files"). Loading itself does not depend on these; they are for the user (``tilerender info``,
the API's scene inspection).
"""

import functools
import json
import struct
from pathlib import Path

from tracer.scene import gltf_texture_transform as texture_transform

REPEAT = 10497
"""glTF's sampler wrap mode REPEAT, the only one textures use."""
NEAREST = 9728

READ_EXTENSIONS = {
    "KHR_lights_punctual",
    "KHR_materials_emissive_strength",
    "KHR_materials_ior",
    "KHR_materials_transmission",
    "KHR_materials_volume",
    "KHR_texture_transform",
}
"""Extensions the loader reads (docs/materials.md): only what it approximates of them warns."""

GEOMETRY_WARNINGS = {
    "skins": "skins ignored: skinned meshes render as stored, not posed by their joints",
    "targets": "morph targets ignored: meshes render in their base shape",
    "animations": "animations ignored: the file renders at rest (a scene's animation section "
    "moves objects)",
    "cameras": "cameras not used: the scene's own camera is (camera.from_object takes the file's)",
    "orthographic": "orthographic cameras ignored: only perspective cameras are supported",
    "sparse": "sparse accessors ignored: their substituted values are not applied",
    "KHR_lights_punctual": "KHR_lights_punctual not used: the object does not ask for the "
    'file\'s lights ("lights": true)',
    "range": "light range ignored: lights fall off with the inverse square of the distance",
    "KHR_draco_mesh_compression": "KHR_draco_mesh_compression not decoded (no DracoPy): its "
    "meshes load as zeros",
    "EXT_meshopt_compression": "EXT_meshopt_compression not decoded: its meshes do not load "
    "correctly",
}
MATERIAL_WARNINGS = {
    "TANGENT": "TANGENT ignored: normal maps use each triangle's own tangent frame from its UVs",
    "TEXCOORD_1": "UV sets after TEXCOORD_0 ignored: every texture uses TEXCOORD_0, whatever "
    "its texCoord",
    "COLOR_0": "vertex colours ignored: surfaces use their material's base colour",
    "normalTexture": "normalTexture approximated: a tangent frame per triangle from its UVs, "
    "not MikkTSpace",
    "occlusionTexture": "occlusionTexture ignored: the path tracer finds occlusion itself",
    "metallicFactor": "metallicFactor between 0 and 1 approximated: below 0.5 a plastic, "
    "else a metal",
    "metallicRoughnessTexture": "metallicRoughnessTexture approximated: its mean metallic and "
    "roughness, one value per material",
    "emissiveTexture": "emissiveTexture approximated: its mean colour, uniform over the material",
    "alphaMode": "alphaMode MASK/BLEND ignored on glass (KHR_materials_transmission) and "
    "emissive materials: they are opaque",
    "transmission": "KHR_materials_transmission approximated: glass at a "
    "transmissionFactor of 0.5 or more (no transmissionTexture), else opaque",
    "KHR_materials_pbrSpecularGlossiness": "KHR_materials_pbrSpecularGlossiness approximated: "
    "converted to metallic-roughness by trimesh",
    "KHR_texture_transform": "KHR_texture_transform approximated: where a material's "
    "baseColorTexture and normalTexture transforms differ, both take the baseColorTexture's",
    "unnamed transform": "KHR_texture_transform ignored on materials without a name of their "
    "own (materials are matched to the file's JSON by name)",
    "wrap": "texture sampler wrap modes ignored: every texture repeats",
    "filter": "texture sampler NEAREST filter ignored: textures are bilinear",
}


JSON_CACHE_SIZE = 8
"""Parsed glTF documents kept (one load reads its file's JSON several times: ``gltf_json``)."""


def gltf_json(path: Path) -> dict | None:
    """The JSON of a .gltf or .glb file, or None for other files or JSON that cannot be read
    (trimesh reads the file itself; this is for what trimesh does not keep). Parsed once per
    version of the file (its resolved path, size and modification time), so the loader's
    several readers of one file share a parse; callers must not modify the document."""
    try:
        resolved = path.resolve()
        stat = resolved.stat()
    except (OSError, RuntimeError):
        return None
    return _cached_json(resolved, path.suffix.lower(), stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=JSON_CACHE_SIZE)
def _cached_json(path: Path, suffix: str, mtime_ns: int, size: int) -> dict | None:
    """``_read_json`` of one version of a file (``mtime_ns`` and ``size`` are only its key)."""
    return _read_json(path, suffix)


def _read_json(path: Path, suffix: str) -> dict | None:
    """The JSON of a file read as ``suffix`` says (``.gltf`` or ``.glb``), or None."""
    try:
        if suffix == ".gltf":
            document = json.loads(path.read_text(encoding="utf-8"))
        elif suffix == ".glb":
            with path.open("rb") as handle:
                magic, _, _, length, kind = struct.unpack("<4sIII4s", handle.read(20))
                if magic != b"glTF" or kind != b"JSON":
                    return None
                document = json.loads(handle.read(length))
        else:
            return None
    except (OSError, ValueError, struct.error):
        return None
    return document if isinstance(document, dict) else None


def _dicts(value) -> list[dict]:
    return [item for item in value if isinstance(item, dict)] if isinstance(value, list) else []


def has_normals(document: dict) -> bool:
    """Whether any primitive of the file has a NORMAL attribute."""
    return any("NORMAL" in p.get("attributes", {}) for p in _primitives(document))


def _primitives(document: dict) -> list[dict]:
    return [p for m in _dicts(document.get("meshes")) for p in _dicts(m.get("primitives"))]


def used_features(document: dict) -> set[str]:
    """The keys of ``GEOMETRY_WARNINGS`` and ``MATERIAL_WARNINGS`` the document uses, and the
    names of other extensions it uses."""
    used = {key for key in ("skins", "animations", "cameras") if _dicts(document.get(key))}
    used |= {"orthographic" for c in _dicts(document.get("cameras"))
             if c.get("type") == "orthographic"}  # fmt: skip
    used |= {"sparse" for a in _dicts(document.get("accessors")) if "sparse" in a}
    named: set[str] = set()  # extensions by name
    extensions = document.get("extensions", {}) or {}
    lights = extensions.get("KHR_lights_punctual", {}) if isinstance(extensions, dict) else {}
    if isinstance(lights, dict) and _dicts(lights.get("lights")):
        used.add("KHR_lights_punctual")
        used |= {"range" for light in _dicts(lights.get("lights")) if "range" in light}
    for primitive in _primitives(document):
        attributes = primitive.get("attributes", {})
        if isinstance(attributes, dict):
            used |= {"TANGENT"} & set(attributes)
            used |= {"COLOR_0" for name in attributes if name.startswith("COLOR_")}
        if primitive.get("targets"):
            used.add("targets")
        named |= set(primitive.get("extensions", {}) or {})
    names = [m.get("name") for m in _dicts(document.get("materials"))]
    for material in _dicts(document.get("materials")):
        used |= {key for key in ("normalTexture", "occlusionTexture", "emissiveTexture")
                 if key in material}  # fmt: skip
        pbr = material.get("pbrMetallicRoughness", {}) or {}
        if "metallicRoughnessTexture" in pbr:
            used.add("metallicRoughnessTexture")
        metallic = pbr.get("metallicFactor", 1.0)
        if isinstance(metallic, int | float) and 0.0 < metallic < 1.0:
            used.add("metallicFactor")
        extensions = material.get("extensions", {}) or {}
        if material.get("alphaMode", "OPAQUE") in ("MASK", "BLEND") and _opaque_kind(material):
            used.add("alphaMode")
        named |= set(extensions)
        transmission = extensions.get("KHR_materials_transmission", {}) or {}
        factor = transmission.get("transmissionFactor", 0.0)
        if "transmissionTexture" in transmission or factor not in (0, 0.0, 1, 1.0):
            used.add("transmission")
        if texture_transform.transforms_differ(material):
            used.add("KHR_texture_transform")
        name = material.get("name")
        unique = isinstance(name, str) and name != "" and names.count(name) == 1
        if not unique and texture_transform.has_transform(material):
            used.add("unnamed transform")
        sampled = texture_transform.sampled_infos(material).values()
        if any(texture_transform.tex_coord(info) != 0 for info in sampled):
            used.add("TEXCOORD_1")
    for sampler in _dicts(document.get("samplers")):
        if sampler.get("wrapS", REPEAT) != REPEAT or sampler.get("wrapT", REPEAT) != REPEAT:
            used.add("wrap")
        if sampler.get("magFilter") == NEAREST:
            used.add("filter")
    listed = document.get("extensionsUsed", [])
    if isinstance(listed, list):
        named |= {name for name in listed if isinstance(name, str)}
    return used | (named - READ_EXTENSIONS)


def _opaque_kind(material: dict) -> bool:
    """Whether a material becomes glass or an emitter, which take no alpha (by its JSON)."""
    extensions = material.get("extensions", {}) or {}
    transmission = extensions.get("KHR_materials_transmission", {}) or {}
    factor = transmission.get("transmissionFactor", 0.0)
    glass = isinstance(factor, int | float) and factor >= 0.5
    emissive = material.get("emissiveFactor", [0.0, 0.0, 0.0])
    lit = isinstance(emissive, list) and any(isinstance(e, int | float) and e > 0 for e in emissive)
    return glass or lit


def feature_warnings(
    document: dict, materials: bool = True, lights: bool = True, cameras: bool = True
) -> list[str]:
    """One warning per feature of the file that is ignored or approximated, in the table's
    order, then other extensions by name; with ``materials`` false (the scene gives the
    object its own material) only those about geometry and the file's scene. ``lights`` and
    ``cameras`` say whether the file's lights and cameras are taken (a file alone: yes)."""
    used = used_features(document)
    used -= {"KHR_lights_punctual"} if lights else {"range"}
    used -= {"cameras"} if cameras else {"orthographic"}
    warnings = [text for key, text in GEOMETRY_WARNINGS.items() if key in used]
    if materials:
        warnings += [text for key, text in MATERIAL_WARNINGS.items() if key in used]
        known = set(GEOMETRY_WARNINGS) | set(MATERIAL_WARNINGS)
        warnings += [f"{name} ignored" for name in sorted(used - known)]
    return warnings
