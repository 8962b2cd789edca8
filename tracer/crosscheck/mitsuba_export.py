"""Export a scene to Mitsuba 3: an XML scene, PLY meshes and EXR bitmaps, for cross-checks.

:func:`export_scene` turns a :class:`~tracer.scene.model.SceneState` (what the loader returns)
into files that Mitsuba 3 loads with ``mitsuba.load_file``. It never imports Mitsuba (an
optional development dependency). What Mitsuba cannot express raises
:class:`UnsupportedFeature`, naming the feature; what the export expresses through a proxy (a
bitmap, a far disc, a duplicated surface) or through a Mitsuba model that differs from ours is
listed in :attr:`MitsubaExport.deviations`. Every convention is in docs/mitsuba.md.

This module writes the scene (integrator, camera, meshes and area lights) and the files; the
materials are ``mitsuba_materials``', the sky and the lights ``mitsuba_emitters``', the numbers
both need ``mitsuba_conversions``'.
"""

import hashlib
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from tracer.compiled.corners import moved_normals
from tracer.crosscheck.mitsuba_base import (
    Deviation,
    DeviationKind,
    UnsupportedFeature,
    child,
    look_at,
    rgb,
    scalar,
    slug,
)
from tracer.crosscheck.mitsuba_conversions import is_closed_outward, winding_numbers
from tracer.crosscheck.mitsuba_emitters import EmittersWriter
from tracer.crosscheck.mitsuba_materials import MaterialsWriter
from tracer.maths import portable
from tracer.scene import format as fmt
from tracer.scene.environment import EnvironmentMap
from tracer.scene.loader import MESH_SUFFIXES
from tracer.scene.model import SceneState, WorldMesh

EMITTER_OFFSET = 1e-5
"""Gap, in scene diagonals, behind the back copy of a two-sided emitter on an open mesh."""


@dataclass(frozen=True)
class MitsubaExport:
    """What :func:`export_scene` wrote: ``xml_path`` (``scene.xml``), its text, the integrator
    plugin it chose (``path``, or ``volpath`` for absorbing glass) and the deviations."""

    xml_path: Path
    xml: str
    integrator: str
    deviations: tuple[Deviation, ...]

    def model_differences(self) -> tuple[Deviation, ...]:
        return tuple(d for d in self.deviations if d.kind == "model")


_OPAQUE_FIELDS = {"type", "reflectance", "emission", "two_sided", "texture", "normal_map", "alpha"}
"""The fields every opaque material has (``tracer.scene.format_materials._Opaque``)."""

KNOWN_FIELDS = {
    fmt.DiffuseMaterial: _OPAQUE_FIELDS,
    fmt.MirrorMaterial: _OPAQUE_FIELDS,
    fmt.DielectricMaterial: {"type", "ior", "absorption"},
    fmt.ConductorMaterial: _OPAQUE_FIELDS | {"eta", "k", "roughness"},
    fmt.PlasticMaterial: _OPAQUE_FIELDS | {"ior", "roughness"},
    fmt.Texture: {"file", "wrap", "scale"},
    fmt.Alpha: {"mode", "cutoff", "value", "texture"},
    fmt.NormalMap: {"file", "wrap", "scale", "strength"},
    fmt.ConstantSky: {"type", "radiance"},
    fmt.GradientSky: {"type", "zenith", "horizon", "ground"},
    fmt.EnvironmentSky: {"type", "file", "scale", "rotation"},
    fmt.PointLight: {"type", "position", "intensity"},
    fmt.SpotLight: {"type", "position", "look_at", "intensity", "cone_angle_deg", "falloff_deg"},
    fmt.SunLight: {"type", "to_sun", "irradiance", "angular_radius_deg"},
    fmt.Camera: {
        "position",
        "look_at",
        "up",
        "vfov_deg",
        "width",
        "height",
        "aperture_radius",
        "focus_distance",
    },
    fmt.RenderSettings: {
        "spp",
        "max_depth",
        "rr_depth",
        "seed",
        "integrator",
        "effects",
        "effect_plan",
        "ao_samples",
        "ao_distance",
    },
}
"""Fields the export understands, per model. A field added to a model later (a texture, say)
is refused when it is set, rather than silently dropped."""


SCENE_INPUT_SUFFIXES = {".json", ".bin", *MESH_SUFFIXES}
"""Files a scene is read from (the scene file, meshes, glTF buffers)."""
REFERENCE_RECORD = "mitsuba.json"
"""The record kept next to a scene's stored Mitsuba reference (``bench/mitsuba_references.py``)."""


def scene_inputs_digest(scene_file: str | Path) -> str:
    """sha256 over the scene file's folder: the names and bytes of its scene and mesh files
    (sorted; a reference's own record excluded), to tell when a stored reference is stale."""
    folder = Path(scene_file).parent
    digest = hashlib.sha256()
    for path in sorted(p for p in folder.iterdir() if p.is_file()):
        if path.suffix in SCENE_INPUT_SUFFIXES and path.name != REFERENCE_RECORD:
            digest.update(path.name.encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()


def export_scene(state: SceneState, out_dir: str | Path, strict: bool = False) -> MitsubaExport:
    """Write ``scene.xml`` and its meshes (``meshes/``) and bitmaps (``textures/``) to
    ``out_dir``.

    The scene is exported as it is (an animated scene at the pose of ``state``). Raises
    :class:`UnsupportedFeature` for anything Mitsuba cannot express, and, when ``strict``, for
    features whose Mitsuba model differs from ours (deviations of kind ``model``).
    """
    out = Path(out_dir)
    writer = _Writer(state, out)
    root = writer.build()
    if strict and (differences := [d for d in writer.deviations if d.kind == "model"]):
        first = differences[0]
        raise UnsupportedFeature(first.feature, f"Mitsuba's model differs: {first.detail}")
    ET.indent(root)
    xml = ET.tostring(root, encoding="unicode") + "\n"
    out.mkdir(parents=True, exist_ok=True)
    path = out / "scene.xml"
    path.write_text(xml, encoding="utf-8")
    return MitsubaExport(path, xml, writer.integrator, tuple(writer.deviations))


def _check_fields(model, label: str) -> None:
    """Refuse a set field the export does not know (see ``KNOWN_FIELDS``)."""
    known = KNOWN_FIELDS.get(type(model))
    if known is None:
        kind = getattr(model, "type", type(model).__name__)
        raise UnsupportedFeature(f"{label} of type {kind!r}", "not supported by the export yet")
    for name, info in type(model).model_fields.items():
        default = info.get_default(call_default_factory=True)
        if name not in known and getattr(model, name) != default:
            raise UnsupportedFeature(f"{label}: {name}", "not supported by the export yet")


# --- the writer ------------------------------------------------------------------------------


MITSUBA_TWINS: dict[str, int | None] = {"path": None, "direct": 2}
"""Our integrators that Mitsuba's path integrator renders, and the path depth each caps at."""


@dataclass
class _Writer(MaterialsWriter, EmittersWriter):
    state: SceneState
    out: Path
    deviations: list[Deviation] = field(default_factory=list)
    integrator: str = "path"

    def build(self) -> ET.Element:
        state = self.state
        _check_fields(state.camera, "camera")
        _check_fields(state.render, "render settings")
        self.meshes = state.world_meshes()
        if not self.meshes:
            raise UnsupportedFeature("scene without geometry", "nothing to export")
        corners = np.concatenate([m.vertices for m in self.meshes])
        self.lo, self.hi = corners.min(axis=0), corners.max(axis=0)
        self.center = 0.5 * (self.lo + self.hi)
        self.radius = max(0.5 * portable.norm(self.hi - self.lo), 1e-6)
        for name in sorted({m.material for m in self.meshes}):
            material = state.materials[name]
            _check_fields(material, f"material {name!r}")
            if getattr(material, "texture", None) is not None:
                _check_fields(material.texture, f"material {name!r}: texture")
            if getattr(material, "alpha", None) is not None:
                _check_fields(material.alpha, f"material {name!r}: alpha")
        sky = state.sky
        _check_fields(sky.model if isinstance(sky, EnvironmentMap) else sky, "sky")
        for i, light in enumerate(state.lights):
            _check_fields(light, f"lights[{i}]")
        self.delta_lights = any(
            not isinstance(light, fmt.SunLight) or light.angular_radius_deg == 0.0
            for light in state.lights
        )

        root = ET.Element("scene", version="3.0.0")
        self.root = root
        reach = portable.norm(np.subtract(state.camera.position, self.center))
        self.far = 10.0 * (self.radius + reach)
        self._integrator(root)
        bsdf_ids = self.write_materials(root)
        for index, mesh in enumerate(self.meshes):
            self._shape(root, index, mesh, bsdf_ids[mesh.material])
        self.write_sky(root)
        for i, light in enumerate(state.lights):
            self.write_light(root, i, light)
        self._sensor(root)
        return root

    def note(self, feature: str, kind: DeviationKind, detail: str) -> None:
        if not any(d.feature == feature for d in self.deviations):
            self.deviations.append(Deviation(feature, kind, detail))

    # -- integrator and camera

    def _integrator(self, root: ET.Element) -> None:
        render = self.state.render
        # Mitsuba shades with vertex normals and normal maps (its normalmap's own fixes
        # switched off) without the terminator's falloff and without bending them: both off
        # is its twin.
        if off := sorted(set(render.effects) - {"shadow_terminator", "normal_bending"}):
            raise UnsupportedFeature(
                f"effects switched off ({', '.join(off)})", "Mitsuba renders them all"
            )
        if render.integrator not in MITSUBA_TWINS:
            twins = " and ".join(repr(name) for name in MITSUBA_TWINS)
            raise UnsupportedFeature(
                f"integrator {render.integrator!r}", f"only {twins} have a Mitsuba twin"
            )
        absorbing = any(
            isinstance(self.state.materials[m.material], fmt.DielectricMaterial)
            and max(self.state.materials[m.material].absorption) > 0.0
            for m in self.meshes
        )
        # Mitsuba's path tracer sends shadow rays into a mask as into an opaque surface and
        # counts a pass through it as a bounce; its volpath, as ours, does neither.
        cut_out = any(
            getattr(self.state.materials[m.material], "alpha", None) is not None
            for m in self.meshes
        )
        self.integrator = "volpath" if absorbing or cut_out else "path"
        cap = MITSUBA_TWINS[render.integrator]
        max_depth = render.max_depth if cap is None else min(render.max_depth, cap)
        element = child(root, "integrator", type=self.integrator)
        child(element, "integer", name="max_depth", value=max_depth)
        child(element, "integer", name="rr_depth", value=render.rr_depth)
        child(element, "boolean", name="hide_emitters", value="false")

    def _sensor(self, root: ET.Element) -> None:
        camera = self.state.camera
        lens = camera.aperture_radius > 0.0
        sensor = child(root, "sensor", type="thinlens" if lens else "perspective")
        child(sensor, "string", name="fov_axis", value="y")
        scalar(sensor, "fov", camera.vfov_deg)
        scalar(sensor, "near_clip", 1e-4 * self.radius)
        scalar(sensor, "far_clip", self.far)
        if lens:
            forward = np.subtract(camera.look_at, camera.position)
            focus = camera.focus_distance or portable.norm(forward)
            scalar(sensor, "aperture_radius", camera.aperture_radius)
            scalar(sensor, "focus_distance", focus)
        look_at(sensor, camera.position, camera.look_at, camera.up)
        sampler = child(sensor, "sampler", type="independent")
        child(sampler, "integer", name="sample_count", value=self.state.render.spp)
        film = child(sensor, "film", type="hdrfilm")
        child(film, "integer", name="width", value=camera.width)
        child(film, "integer", name="height", value=camera.height)
        child(film, "string", name="pixel_format", value="rgb")
        child(film, "rfilter", type="box")

    # -- geometry and area lights

    def _write_ply(
        self, index: int, name: str, vertices: np.ndarray, faces: np.ndarray, uvs=None,
        normals=None,
    ) -> str:  # fmt: skip
        relative = f"meshes/{index:04d}-{slug(name)}.ply"
        path = self.out / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        visual = None if uvs is None else trimesh.visual.TextureVisuals(uv=uvs)
        mesh = trimesh.Trimesh(
            vertices, faces, visual=visual, vertex_normals=normals, process=False
        )
        data = mesh.export(file_type="ply", encoding="binary", vertex_normal=normals is not None)
        path.write_bytes(data)
        return relative

    def _world_normals(self, mesh: WorldMesh) -> np.ndarray | None:
        """The mesh's shading normals in world space, pointing to the side its (world) faces
        face, or None for a flat mesh."""
        normals = self.state.meshes[self.state.nodes[mesh.node].mesh].normals
        if normals is None:
            return None
        return moved_normals(normals, self.state.world_transform(mesh.node))

    def _mitsuba_uvs(self, mesh: WorldMesh) -> np.ndarray | None:
        """The UVs Mitsuba's ``bitmap`` needs for a textured mesh (None without a texture).

        Ours: ``v`` from the bottom of the image up, multiplied by the texture's ``scale``
        before the lookup; Mitsuba's ``v`` runs from the top row down (its PLY loader keeps
        the file's values). So the PLY holds ``(s_u u, 1 - s_v v)``, from the float32 UVs the
        kernels interpolate."""
        material = self.state.materials[mesh.material]
        alpha = getattr(material, "alpha", None)
        maps = [t for t in (getattr(material, "texture", None),
                            getattr(material, "normal_map", None),
                            None if alpha is None else alpha.texture) if t is not None]  # fmt: skip
        if not maps:
            return None
        texture = maps[0]
        if any(tuple(t.scale) != tuple(texture.scale) for t in maps):
            raise UnsupportedFeature(
                f"material {mesh.material!r}", "textures and maps of different scales"
            )
        uvs = self.state.meshes[self.state.nodes[mesh.node].mesh].uvs
        if uvs is None:
            raise UnsupportedFeature(f"mesh {mesh.name!r}", "a texture on a mesh without UVs")
        uv = uvs.astype(np.float32).astype(np.float64) * np.asarray(texture.scale)
        return np.column_stack([uv[:, 0], 1.0 - uv[:, 1]])

    def _shape(self, root: ET.Element, index: int, mesh: WorldMesh, bsdf_id: str) -> None:
        material = self.state.materials[mesh.material]
        emission = tuple(getattr(material, "emission", (0.0, 0.0, 0.0)))
        emits = max(emission) > 0.0
        uvs = self._mitsuba_uvs(mesh)
        copies = [(mesh.name, mesh.vertices, mesh.faces)]
        if emits and material.two_sided and not self._emits_outside_only(mesh):
            copies.append((f"{mesh.name}-back", *self._back_copy(mesh)))
            self.note(
                f"two-sided emitter {mesh.name!r}",
                "proxy",
                "Mitsuba's area lights emit from the front only: the open mesh is duplicated, "
                f"wound the other way, {EMITTER_OFFSET:g} scene diagonals behind",
            )
        normals = self._world_normals(mesh)
        material = self.state.materials[mesh.material]
        tilted = normals is not None or getattr(material, "normal_map", None) is not None
        if tilted and "shadow_terminator" not in self.state.render.effects:
            self.note(
                "shadow terminator",
                "model",
                "Mitsuba has no terminator falloff (Chiang et al. 2019): with it, light on "
                "coarse smooth meshes is darker here near where it grazes the facets",
            )
        if tilted and "normal_bending" not in self.state.render.effects:
            self.note(
                "normal bending",
                "model",
                "Mitsuba leaves points black where the viewer is below the shading normal; "
                "here the normal is turned toward the viewer",
            )
        for part, (name, vertices, faces) in enumerate(copies):
            shape = child(root, "shape", type="ply")
            smooth = normals if part == 0 else None  # the back copy of an emitter shades flat
            filename = self._write_ply(2 * index + part, name, vertices, faces, uvs, smooth)
            child(shape, "string", name="filename", value=filename)
            if smooth is None:
                child(shape, "boolean", name="face_normals", value="true")
            child(shape, "ref", id=bsdf_id)
            if emits:
                emitter = child(shape, "emitter", type="area")
                rgb(emitter, "radiance", emission)
            if isinstance(material, fmt.DielectricMaterial) and max(material.absorption) > 0.0:
                # Mitsuba reads an RGB sigma_t as a reflectance (at most 1): pass it scaled.
                scale = max(material.absorption)
                medium = child(shape, "medium", type="homogeneous", name="interior")
                rgb(medium, "sigma_t", np.asarray(material.absorption) / scale)
                scalar(medium, "scale", scale)
                rgb(medium, "albedo", (0.0, 0.0, 0.0))

    def _emits_outside_only(self, mesh: WorldMesh) -> bool:
        """Whether a two-sided emitter's back faces are unreachable: a closed, outward-wound
        mesh with no camera, point or spot light, or vertex of another mesh inside it."""
        if not is_closed_outward(mesh.vertices, mesh.faces):
            return False
        points = [np.asarray(self.state.camera.position, dtype=np.float64)[None]]
        lights = [lt for lt in self.state.lights if hasattr(lt, "position")]
        points += [np.asarray(lt.position, dtype=np.float64)[None] for lt in lights]
        points += [other.vertices for other in self.meshes if other.node != mesh.node]
        candidates = np.concatenate(points)
        lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
        inside_box = candidates[np.all((candidates >= lo) & (candidates <= hi), axis=1)]
        if not len(inside_box):
            return True
        return bool(np.all(winding_numbers(inside_box, mesh.vertices, mesh.faces) < 0.5))

    def _back_copy(self, mesh: WorldMesh) -> tuple[np.ndarray, np.ndarray]:
        normals = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).vertex_normals
        gap = EMITTER_OFFSET * 2.0 * self.radius
        return mesh.vertices - gap * normals, mesh.faces[:, ::-1].copy()
