"""Export a scene to Mitsuba 3: an XML scene, PLY meshes and EXR bitmaps, for cross-checks.

:func:`export_scene` turns a :class:`~tracer.scene.model.SceneState` (what the loader returns)
into files that Mitsuba 3 loads with ``mitsuba.load_file``. It never imports Mitsuba (an
optional development dependency). What Mitsuba cannot express raises
:class:`UnsupportedFeature`, naming the feature; what the export expresses through a proxy (a
bitmap, a far disc, a duplicated surface) or through a Mitsuba model that differs from ours is
listed in :attr:`MitsubaExport.deviations`. Every convention is in docs/mitsuba.md.
"""

import functools
import hashlib
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import trimesh

from tracer.errors import TilerenderError
from tracer.io.images import write_image
from tracer.kernel.jit import jit
from tracer.maths import portable
from tracer.scene import format as fmt
from tracer.scene.environment import EnvironmentMap
from tracer.scene.model import SceneState, WorldMesh
from tracer.shading.bsdf import ETA, SMOOTH_ALPHA, K
from tracer.shading.fresnel import fr_dielectric
from tracer.shading.materials import (
    COAT_QUADRATURE,
    PLASTIC_MIN_ALPHA,
    coat_tables,
    gauss_legendre,
    material_row,
    roughness_to_alpha,
)
from tracer.shading.microfacet import ggx_g1, ggx_sample_visible_normal, reflect_local
from tracer.shading.textures import srgb_to_linear

SKY_ROWS = 4096
"""Rows of the latitude-longitude bitmap of a gradient sky (Mitsuba puts row ``i`` at polar angle
``i * pi / (rows - 1)``; an even count puts the horizon between two rows)."""
SKY_COLUMNS = 8
"""Columns of that bitmap (the gradient does not depend on the azimuth)."""
SPOT_TEXTURE_SIZE = 512
"""Side of the projection bitmap that gives a spot light our smoothstep falloff."""
SUN_DISTANCE = 1e4
"""A sun with a radius becomes a disc this many scene radii away (parallax below 1e-4 rad)."""
EMITTER_OFFSET = 1e-5
"""Gap, in scene diagonals, behind the back copy of a two-sided emitter on an open mesh."""
ENVIRONMENT_TEXELS = 1 << 21
"""An environment map is resampled to about this many texels (see :func:`environment_bitmap`)."""
ENVIRONMENT_MAX_FACTOR = 32
"""At most this many bitmap texels per map pixel, along each axis."""
MITSUBA_COAT_COSINES = 64
"""Cosines ``max(1e-6, j / 63)`` over which Mitsuba's ``roughplastic`` averages its coat's
internal reflectance (``MI_ROUGH_TRANSMITTANCE_RES``)."""

DeviationKind = Literal["proxy", "model"]


class UnsupportedFeature(TilerenderError, ValueError):
    """A scene feature Mitsuba cannot express (or the export does not handle yet)."""

    def __init__(self, feature: str, reason: str) -> None:
        super().__init__(f"{feature}: {reason}")
        self.feature = feature


@dataclass(frozen=True)
class Deviation:
    """Where the exported scene is not exactly ours.

    ``proxy``: the feature goes through a stand-in whose error is far below render noise (a
    tabulated bitmap, a far disc, a duplicated surface). ``model``: Mitsuba's model of the
    feature differs from ours (docs/mitsuba.md quantifies each).
    """

    feature: str
    kind: DeviationKind
    detail: str


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


KNOWN_FIELDS = {
    fmt.DiffuseMaterial: {"type", "reflectance", "emission", "two_sided", "texture"},
    fmt.MirrorMaterial: {"type", "reflectance", "emission", "two_sided", "texture"},
    fmt.DielectricMaterial: {"type", "ior", "absorption"},
    fmt.ConductorMaterial: {
        "type",
        "reflectance",
        "eta",
        "k",
        "roughness",
        "emission",
        "two_sided",
        "texture",
    },
    fmt.PlasticMaterial: {
        "type",
        "reflectance",
        "ior",
        "roughness",
        "emission",
        "two_sided",
        "texture",
    },
    fmt.Texture: {"file", "wrap", "scale"},
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


SCENE_INPUT_SUFFIXES = {".json", ".obj", ".ply", ".stl", ".gltf", ".glb", ".bin"}
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


# --- XML helpers -----------------------------------------------------------------------------


def _number(value: float) -> str:
    return repr(float(value))


def _triple(values) -> str:
    return ", ".join(_number(v) for v in values)


def _child(parent: ET.Element, tag: str, **attrs) -> ET.Element:
    return ET.SubElement(parent, tag, {k: str(v) for k, v in attrs.items()})


def _rgb(parent: ET.Element, name: str, values) -> None:
    _child(parent, "rgb", name=name, value=_triple(values))


def _float(parent: ET.Element, name: str, value: float) -> None:
    _child(parent, "float", name=name, value=_number(value))


def _matrix(parent: ET.Element, matrix: np.ndarray) -> None:
    transform = _child(parent, "transform", name="to_world")
    _child(transform, "matrix", value=" ".join(_number(v) for v in np.ravel(matrix)))


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", text).strip("-")[:40] or "mesh"


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


def _frame(normal: np.ndarray) -> np.ndarray:
    """Two unit vectors completing ``normal`` to a right-handed frame, as columns x, y, z."""
    z = portable.normalized(normal)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = portable.normalized(portable.cross(helper, z))
    return np.column_stack([x, portable.cross(z, x), z])


def sky_radiance(sky: fmt.Sky | EnvironmentMap, direction) -> np.ndarray:
    """Radiance the sky sends from ``direction`` (unit, +y up), as ``tracer.shading.lights``
    defines it."""
    if isinstance(sky, EnvironmentMap):
        return environment_radiance(sky, direction)
    if isinstance(sky, fmt.GradientSky):
        y = float(direction[1])
        if y < 0.0:
            return np.asarray(sky.ground, dtype=np.float64)
        horizon = np.asarray(sky.horizon, dtype=np.float64)
        return horizon + (np.asarray(sky.zenith) - horizon) * y
    return np.asarray(sky.radiance, dtype=np.float64)


def gradient_sky_bitmap(sky: fmt.GradientSky) -> np.ndarray:
    """(SKY_ROWS, SKY_COLUMNS, 3) float32 latitude-longitude bitmap of the gradient: row ``i``
    holds the radiance at polar angle ``i * pi / (SKY_ROWS - 1)`` from +y (Mitsuba's
    ``envmap`` places rows at these angles and interpolates bilinearly between them)."""
    y = np.cos(np.arange(SKY_ROWS) * math.pi / (SKY_ROWS - 1))
    rows = np.stack([sky_radiance(sky, (0.0, yi, 0.0)) for yi in y])
    return np.repeat(rows[:, None, :], SKY_COLUMNS, axis=1).astype(np.float32)


def environment_scaled(sky: EnvironmentMap) -> np.ndarray:
    """The map's pixels times its ``scale``, float32, as ``tracer.shading.environment_light`` scales
    them for the kernels."""
    return (sky.image.astype(np.float64) * sky.model.scale).astype(np.float32)


def environment_radiance(sky: EnvironmentMap, direction) -> np.ndarray:
    """The map's radiance from unit ``direction``: the pixel ``tracer.shading.environment_light``
    looks up (nearest pixel, after turning the direction into the map's frame)."""
    h, w = sky.image.shape[:2]
    d = portable.transform_vectors(direction, _environment_frame(sky.model.rotation))
    v = math.atan2(math.hypot(d[0], d[2]), d[1]) / math.pi
    u = math.atan2(d[0], -d[2]) / (2.0 * math.pi) + 0.5
    i = min(max(int(v * h), 0), h - 1)
    j = min(max(int(u * w), 0), w - 1)
    return environment_scaled(sky)[i, j].astype(np.float64)


def _environment_frame(rotation_deg: float) -> np.ndarray:
    """World -> map directions: the inverse of the map's ``rotation`` about +y."""
    c, s = math.cos(math.radians(rotation_deg)), math.sin(math.radians(rotation_deg))
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def environment_to_world(rotation_deg: float) -> np.ndarray:
    """4x4 ``to_world`` of Mitsuba's ``envmap`` for our map turned by ``rotation_deg``.

    Mitsuba reads ``u = atan2(x, -z) / 2 pi`` (wrapped to [0, 1)) of the local direction: its
    image centre looks along +z, ours along -z, with ``u`` growing toward +x in both. So the
    local direction is ours in the map's frame turned by 180 degrees about +y (``F``), and
    ``to_world = (F R)^-1``, ``R`` the world -> map turn."""
    flip = np.diag([-1.0, 1.0, -1.0])
    matrix = np.eye(4)
    matrix[:3, :3] = portable.matmul(flip, _environment_frame(rotation_deg)).T  # a rotation
    return matrix


def environment_bitmap(sky: EnvironmentMap) -> tuple[np.ndarray, int]:
    """The map (scale applied) as Mitsuba's ``envmap`` bitmap, and the factor ``k`` it was
    upsampled by: ``(k H + 1, k W, 3)`` float32.

    Ours is constant over each pixel; Mitsuba interpolates bilinearly between texels placed at
    ``u = (j + 0.5) / W'`` (wrapping around) and at polar angles ``i pi / (H' - 1)`` (measured
    on 3.9.1). With ``W' = k W`` the edges of our columns fall midway between two texels; with
    ``H' = k H + 1`` the edges of our rows fall on a texel, which takes the mean of the two
    rows. Each edge becomes a linear ramp, symmetric about it, of one texel each side: the
    map's integral is kept and a lookup differs from ours only within ``1 / k`` of a pixel
    from its edges."""
    scaled = environment_scaled(sky)
    h, w = scaled.shape[:2]
    k = max(1, min(ENVIRONMENT_MAX_FACTOR, math.isqrt(ENVIRONMENT_TEXELS // (h * w))))
    columns = np.repeat(scaled, k, axis=1)
    fine = np.arange(k * h + 1)
    rows = columns[np.minimum(fine // k, h - 1)]
    edges = fine[(fine % k == 0) & (fine > 0) & (fine < k * h)]
    above = columns[edges // k - 1].astype(np.float64)
    rows[edges] = (0.5 * (above + columns[edges // k])).astype(np.float32)
    return rows, k


def spot_profile(cone_angle_deg: float, falloff_deg: float, cos_theta: np.ndarray) -> np.ndarray:
    """Our spot falloff: pbrt-v4's smoothstep between the cosines of the outer and inner cones."""
    cos_outer = math.cos(math.radians(cone_angle_deg))
    cos_inner = math.cos(math.radians(cone_angle_deg - falloff_deg))
    if cos_inner == cos_outer:
        return (cos_theta >= cos_outer).astype(np.float64)
    t = np.clip((cos_theta - cos_outer) / (cos_inner - cos_outer), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def spot_texture(cone_angle_deg: float, falloff_deg: float) -> np.ndarray:
    """(N, N, 3) float32 projection bitmap for Mitsuba's ``spot``: texel centres ``(u, v)`` map
    to the local direction ``((2u - 1) tan(cone), (2v - 1) tan(cone), 1)``, as the plugin's
    ``direction_to_uv`` does; each texel holds our falloff in that direction."""
    n = SPOT_TEXTURE_SIZE
    s = (2.0 * (np.arange(n) + 0.5) / n - 1.0) * math.tan(math.radians(cone_angle_deg))
    cos_theta = 1.0 / np.sqrt(1.0 + s[:, None] ** 2 + s[None, :] ** 2)
    profile = spot_profile(cone_angle_deg, falloff_deg, cos_theta)
    return np.repeat(profile[..., None], 3, axis=2).astype(np.float32)


@jit
def separable_coat_reflectance(cos_theta, alpha, eta, nodes, weights):
    """Directional reflectance of a GGX dielectric interface for light arriving at
    ``cos_theta`` from the side of relative index ``eta``, with separable masking, as Mitsuba's
    ``eval_reflectance`` integrates it: Fresnel times ``G1`` of the reflected direction over
    the visible normals (``tracer.shading.microfacet``'s sampler on the product rule ``nodes``,
    ``weights``). ``microfacet.ggx_dielectric_albedo`` is the height-correlated form."""
    wi = (math.sqrt(max(0.0, 1.0 - cos_theta * cos_theta)), 0.0, cos_theta)
    r = 0.0
    for a in range(nodes.shape[0]):
        for b in range(nodes.shape[0]):
            m = ggx_sample_visible_normal(wi, alpha, nodes[a], nodes[b])
            wr = reflect_local(wi, m)
            if wr[2] > 0.0:
                cos_im = wi[0] * m[0] + wi[1] * m[1] + wi[2] * m[2]
                r += weights[a] * weights[b] * fr_dielectric(cos_im, eta) * ggx_g1(wr, alpha)
    return r


@functools.lru_cache(maxsize=64)
def mitsuba_internal_reflectance(alpha: float, ior: float) -> float:
    """The internal diffuse reflectance Mitsuba's ``roughplastic`` computes for its coat: the
    mean of ``2 R(mu) mu`` over ``mu = max(1e-6, linspace(0, 1, 64))`` (both ends included, so
    not the integral ``2 int R mu dmu``), ``R`` the reflectance from inside with separable
    masking (:func:`separable_coat_reflectance`)."""
    nodes, weights = gauss_legendre(COAT_QUADRATURE)
    mu = np.maximum(1e-6, np.linspace(0.0, 1.0, MITSUBA_COAT_COSINES))
    r = np.array([separable_coat_reflectance(m, alpha, 1.0 / ior, nodes, weights) for m in mu])
    return float(2.0 * np.mean(r * mu))


def rough_plastic_base_scale(alpha: float, ior: float) -> float:
    """Factor on a rough plastic's ``diffuse_reflectance`` that makes the base term of
    Mitsuba's linear ``roughplastic`` ours: ``(1 - Fdr_mitsuba) / (1 - Fdr_ours)``, Mitsuba's
    internal reflectance (:func:`mitsuba_internal_reflectance`) over ours
    (``materials.coat_tables``, the kernels' own)."""
    ours = coat_tables(alpha, ior)[1]
    return (1.0 - mitsuba_internal_reflectance(alpha, ior)) / (1.0 - ours)


def winding_numbers(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Generalised winding number of a closed mesh at each point (1 inside an outward-wound
    mesh, 0 outside): the solid angles of its triangles (Van Oosterom and Strackee) over 4 pi."""
    tri = vertices[faces]  # (F, 3, 3)
    result = np.zeros(len(points))
    for i, p in enumerate(points):
        a, b, c = (tri[:, j] - p for j in range(3))
        la, lb, lc = (np.linalg.norm(v, axis=1) for v in (a, b, c))
        det = np.einsum("ij,ij->i", a, np.cross(b, c))
        den = (
            la * lb * lc
            + np.einsum("ij,ij->i", a, b) * lc
            + np.einsum("ij,ij->i", a, c) * lb
            + np.einsum("ij,ij->i", b, c) * la
        )
        result[i] = np.sum(2.0 * np.arctan2(det, den)) / (4.0 * math.pi)
    return result


def is_closed_outward(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Whether the triangles (with coincident vertices merged) bound a volume, wound outward."""
    mesh = trimesh.Trimesh(vertices, faces, process=True)
    return bool(mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0.0)


# --- the writer ------------------------------------------------------------------------------


@dataclass
class _Writer:
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
        bsdf_ids = self._materials(root)
        for index, mesh in enumerate(self.meshes):
            self._shape(root, index, mesh, bsdf_ids[mesh.material])
        self._sky(root)
        for i, light in enumerate(state.lights):
            self._light(root, i, light)
        self._sensor(root)
        return root

    def note(self, feature: str, kind: DeviationKind, detail: str) -> None:
        if not any(d.feature == feature for d in self.deviations):
            self.deviations.append(Deviation(feature, kind, detail))

    # -- integrator and camera

    def _integrator(self, root: ET.Element) -> None:
        render = self.state.render
        if render.effects:
            off = ", ".join(sorted(render.effects))
            raise UnsupportedFeature(f"effects switched off ({off})", "Mitsuba renders them all")
        if render.integrator not in ("path", "direct"):
            raise UnsupportedFeature(
                f"integrator {render.integrator!r}", "only 'path' and 'direct' have a Mitsuba twin"
            )
        absorbing = any(
            isinstance(self.state.materials[m.material], fmt.DielectricMaterial)
            and max(self.state.materials[m.material].absorption) > 0.0
            for m in self.meshes
        )
        self.integrator = "volpath" if absorbing else "path"
        max_depth = render.max_depth if render.integrator == "path" else min(render.max_depth, 2)
        element = _child(root, "integrator", type=self.integrator)
        _child(element, "integer", name="max_depth", value=max_depth)
        _child(element, "integer", name="rr_depth", value=render.rr_depth)
        _child(element, "boolean", name="hide_emitters", value="false")

    def _sensor(self, root: ET.Element) -> None:
        camera = self.state.camera
        lens = camera.aperture_radius > 0.0
        sensor = _child(root, "sensor", type="thinlens" if lens else "perspective")
        _child(sensor, "string", name="fov_axis", value="y")
        _float(sensor, "fov", camera.vfov_deg)
        _float(sensor, "near_clip", 1e-4 * self.radius)
        _float(sensor, "far_clip", self.far)
        if lens:
            forward = np.subtract(camera.look_at, camera.position)
            focus = camera.focus_distance or portable.norm(forward)
            _float(sensor, "aperture_radius", camera.aperture_radius)
            _float(sensor, "focus_distance", focus)
        transform = _child(sensor, "transform", name="to_world")
        _child(
            transform,
            "lookat",
            origin=_triple(camera.position),
            target=_triple(camera.look_at),
            up=_triple(camera.up),
        )
        sampler = _child(sensor, "sampler", type="independent")
        _child(sampler, "integer", name="sample_count", value=self.state.render.spp)
        film = _child(sensor, "film", type="hdrfilm")
        _child(film, "integer", name="width", value=camera.width)
        _child(film, "integer", name="height", value=camera.height)
        _child(film, "string", name="pixel_format", value="rgb")
        _child(film, "rfilter", type="box")

    # -- materials

    def _materials(self, root: ET.Element) -> dict[str, str]:
        ids = {}
        for i, name in enumerate(sorted({m.material for m in self.meshes})):
            ids[name] = f"material-{i}"
            material = self.state.materials[name]
            bsdf = self._bsdf(name, material)
            if getattr(material, "two_sided", False):
                wrapper = ET.Element("bsdf", type="twosided")
                wrapper.append(bsdf)
                bsdf = wrapper
            bsdf.set("id", ids[name])
            root.append(bsdf)
        return ids

    def _colour(
        self, parent: ET.Element, name: str, m: fmt.Material, colour, scale: float = 1.0
    ) -> None:
        """The base colour ``colour`` of ``m`` times ``scale`` as parameter ``name``: an RGB
        value, or with a texture a bitmap of the texture's linear texels times both."""
        texture = getattr(m, "texture", None)
        if texture is None:
            _rgb(parent, name, np.asarray(colour, dtype=np.float64) * scale)
            return
        # The kernels multiply the float32 colour by the float32 linear texel.
        linear = srgb_to_linear(self.state.textures[texture.file]).astype(np.float64)
        tint = np.asarray(colour, dtype=np.float32).astype(np.float64)
        texels = (linear * tint * scale).astype(np.float32)
        digest = hashlib.sha256(np.ascontiguousarray(texels).tobytes())
        digest.update(repr(texels.shape).encode())
        relative = f"textures/texture-{digest.hexdigest()[:16]}.exr"
        if not (self.out / relative).exists():
            write_image(self.out / relative, texels)
        element = _child(parent, "texture", type="bitmap", name=name)
        _child(element, "string", name="filename", value=relative)
        _child(element, "boolean", name="raw", value="true")
        _child(element, "string", name="filter_type", value="bilinear")
        _child(element, "string", name="wrap_mode", value=texture.wrap)

    def _bsdf(self, name: str, m: fmt.Material) -> ET.Element:
        if isinstance(m, fmt.DiffuseMaterial):
            bsdf = ET.Element("bsdf", type="diffuse")
            self._colour(bsdf, "reflectance", m, m.reflectance)
            return bsdf
        if isinstance(m, fmt.MirrorMaterial):
            bsdf = ET.Element("bsdf", type="conductor")
            _child(bsdf, "string", name="material", value="none")
            self._colour(bsdf, "specular_reflectance", m, m.reflectance)
            return bsdf
        if isinstance(m, fmt.DielectricMaterial):
            bsdf = ET.Element("bsdf", type="dielectric")
            _float(bsdf, "int_ior", m.ior)
            _float(bsdf, "ext_ior", 1.0)
            return bsdf
        if isinstance(m, fmt.ConductorMaterial):
            return self._conductor(name, m)
        if isinstance(m, fmt.PlasticMaterial):
            return self._plastic(name, m)
        raise UnsupportedFeature(f"material {name!r} of type {m.type!r}", "no Mitsuba twin")

    def _conductor(self, name: str, m: fmt.ConductorMaterial) -> ET.Element:
        param = material_row(m)[4]  # eta and k: given, or Gulbrandsen's from the colour
        alpha = roughness_to_alpha(m.roughness)
        if alpha < SMOOTH_ALPHA:
            bsdf = ET.Element("bsdf", type="conductor")
        else:
            bsdf = ET.Element("bsdf", type="roughconductor")
            _child(bsdf, "string", name="distribution", value="ggx")
            _float(bsdf, "alpha", alpha)
            self.note(
                f"rough conductor {name!r}",
                "model",
                "Mitsuba's Smith masking-shadowing is the separable G1(wo) G1(wi), ours the "
                "height-correlated form: within 0.03% below roughness 0.15; at 85 degrees from "
                "the normal Mitsuba's albedo is 0.8% lower at roughness 0.26, 4% at 0.45 "
                "(docs/mitsuba.md)",
            )
        _rgb(bsdf, "eta", param[ETA : ETA + 3])
        _rgb(bsdf, "k", param[K : K + 3])
        if m.texture is not None:  # a tint on the Fresnel term
            self._colour(bsdf, "specular_reflectance", m, (1.0, 1.0, 1.0))
        return bsdf

    def _plastic(self, name: str, m: fmt.PlasticMaterial) -> ET.Element:
        alpha = roughness_to_alpha(m.roughness)
        scale = 1.0
        if alpha <= PLASTIC_MIN_ALPHA:
            bsdf = ET.Element("bsdf", type="plastic")
            if self.delta_lights:
                self.note(
                    f"smooth plastic {name!r} under delta lights",
                    "model",
                    f"our coat keeps a GGX alpha of {PLASTIC_MIN_ALPHA:g}, Mitsuba's smooth "
                    "plastic is a perfect mirror: ours shows point, spot and radius-0 sun "
                    "lights as pinpoint highlights and their caustics off the coat, which "
                    "Mitsuba's path tracer cannot (under area lights, sun discs and skies "
                    "the two agree)",
                )
        else:
            bsdf = ET.Element("bsdf", type="roughplastic")
            _child(bsdf, "string", name="distribution", value="ggx")
            _float(bsdf, "alpha", alpha)
            scale = rough_plastic_base_scale(alpha, float(m.ior))
            self.note(
                f"rough plastic {name!r}",
                "model",
                "Mitsuba's roughplastic is our model with separable masking in its coat tables "
                "and its internal reflectance summed over 64 cosines (below the integral); "
                f"diffuse_reflectance is scaled by {scale:.5f} to undo the latter; the masking "
                "remains: up to roughness 0.3 the bases agree within 0.1% (0.3% at 85 degrees "
                "from the normal), from 0.5 Mitsuba's coat passes and reflects less light, "
                "several percent off the normal (docs/mitsuba.md)",
            )
        _float(bsdf, "int_ior", m.ior)
        _float(bsdf, "ext_ior", 1.0)
        self._colour(bsdf, "diffuse_reflectance", m, m.reflectance, scale)
        _child(bsdf, "boolean", name="nonlinear", value="false")
        return bsdf

    # -- geometry and area lights

    def _write_ply(
        self, index: int, name: str, vertices: np.ndarray, faces: np.ndarray, uvs=None
    ) -> str:
        relative = f"meshes/{index:04d}-{_slug(name)}.ply"
        path = self.out / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        visual = None if uvs is None else trimesh.visual.TextureVisuals(uv=uvs)
        mesh = trimesh.Trimesh(vertices, faces, visual=visual, process=False)
        path.write_bytes(mesh.export(file_type="ply", encoding="binary", vertex_normal=False))
        return relative

    def _mitsuba_uvs(self, mesh: WorldMesh) -> np.ndarray | None:
        """The UVs Mitsuba's ``bitmap`` needs for a textured mesh (None without a texture).

        Ours: ``v`` from the bottom of the image up, multiplied by the texture's ``scale``
        before the lookup; Mitsuba's ``v`` runs from the top row down (its PLY loader keeps
        the file's values). So the PLY holds ``(s_u u, 1 - s_v v)``, from the float32 UVs the
        kernels interpolate."""
        texture = getattr(self.state.materials[mesh.material], "texture", None)
        if texture is None:
            return None
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
        for part, (name, vertices, faces) in enumerate(copies):
            shape = _child(root, "shape", type="ply")
            filename = self._write_ply(2 * index + part, name, vertices, faces, uvs)
            _child(shape, "string", name="filename", value=filename)
            _child(shape, "boolean", name="face_normals", value="true")
            _child(shape, "ref", id=bsdf_id)
            if emits:
                emitter = _child(shape, "emitter", type="area")
                _rgb(emitter, "radiance", emission)
            if isinstance(material, fmt.DielectricMaterial) and max(material.absorption) > 0.0:
                # Mitsuba reads an RGB sigma_t as a reflectance (at most 1): pass it scaled.
                scale = max(material.absorption)
                medium = _child(shape, "medium", type="homogeneous", name="interior")
                _rgb(medium, "sigma_t", np.asarray(material.absorption) / scale)
                _float(medium, "scale", scale)
                _rgb(medium, "albedo", (0.0, 0.0, 0.0))

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

    # -- lights at infinity and delta lights

    def _sky(self, root: ET.Element) -> None:
        sky = self.state.sky
        if isinstance(sky, EnvironmentMap):
            self._environment(root, sky)
            return
        if isinstance(sky, fmt.ConstantSky):
            if max(sky.radiance) > 0.0:
                emitter = _child(root, "emitter", type="constant")
                _rgb(emitter, "radiance", sky.radiance)
            return
        if max(max(sky.zenith), max(sky.horizon), max(sky.ground)) <= 0.0:
            return
        write_image(self.out / "textures" / "sky.exr", gradient_sky_bitmap(sky))
        emitter = _child(root, "emitter", type="envmap")
        _child(emitter, "string", name="filename", value="textures/sky.exr")
        self.note(
            "gradient sky",
            "proxy",
            f"a {SKY_COLUMNS}x{SKY_ROWS} latitude-longitude bitmap, interpolated bilinearly: "
            "within 1e-5 of the gradient except a 0.02-degree band about the horizon",
        )

    def _environment(self, root: ET.Element, sky: EnvironmentMap) -> None:
        if max(sky.mean_radiance()) <= 0.0:
            return  # a black map: no light, as the kernels treat it
        bitmap, factor = environment_bitmap(sky)
        digest = hashlib.sha256(np.ascontiguousarray(bitmap).tobytes()).hexdigest()[:16]
        relative = f"textures/environment-{digest}.exr"
        write_image(self.out / relative, bitmap)
        emitter = _child(root, "emitter", type="envmap")
        _child(emitter, "string", name="filename", value=relative)
        _matrix(emitter, environment_to_world(sky.model.rotation))
        h, w = sky.image.shape[:2]
        self.note(
            "environment map",
            "proxy",
            f"our {w}x{h} map (nearest pixel) upsampled {factor} times to a "
            f"{bitmap.shape[1]}x{bitmap.shape[0]} bitmap that Mitsuba interpolates bilinearly: "
            f"its integral kept, lookups within 1/{factor} of a pixel from the map's pixel "
            "edges differ",
        )

    def _light(self, root: ET.Element, i: int, light: fmt.Light) -> None:
        if isinstance(light, fmt.PointLight):
            emitter = _child(root, "emitter", type="point")
            _child(emitter, "point", name="position", value=_triple(light.position))
            _rgb(emitter, "intensity", light.intensity)
        elif isinstance(light, fmt.SpotLight):
            self._spot(root, i, light)
        elif isinstance(light, fmt.SunLight):
            self._sun(root, i, light)
        else:
            raise UnsupportedFeature(f"lights[{i}] of type {light.type!r}", "no Mitsuba twin")

    def _spot(self, root: ET.Element, i: int, light: fmt.SpotLight) -> None:
        emitter = _child(root, "emitter", type="spot")
        _rgb(emitter, "intensity", light.intensity)
        # Mitsuba's own falloff is linear in angle; full intensity inside the cone, and ours
        # (a smoothstep in cos) from a projection bitmap, keeps our profile.
        _float(emitter, "cutoff_angle", light.cone_angle_deg)
        _float(emitter, "beam_width", light.cone_angle_deg)
        axis = np.subtract(light.look_at, light.position)
        up = _frame(axis)[:, 0]
        transform = _child(emitter, "transform", name="to_world")
        _child(
            transform,
            "lookat",
            origin=_triple(light.position),
            target=_triple(light.look_at),
            up=_triple(up),
        )
        if light.falloff_deg > 0.0:
            relative = f"textures/spot-{i}.exr"
            write_image(self.out / relative, spot_texture(light.cone_angle_deg, light.falloff_deg))
            texture = _child(emitter, "texture", type="bitmap", name="texture")
            _child(texture, "string", name="filename", value=relative)
            _child(texture, "boolean", name="raw", value="true")
            _child(texture, "string", name="wrap_mode", value="clamp")
            self.note(
                f"spot falloff of lights[{i}]",
                "proxy",
                f"our smoothstep falloff as a {SPOT_TEXTURE_SIZE}x{SPOT_TEXTURE_SIZE} projection "
                "bitmap (bilinear, within 1e-4); Mitsuba's own falloff is linear in angle",
            )

    def _sun(self, root: ET.Element, i: int, light: fmt.SunLight) -> None:
        to_sun = np.asarray(light.to_sun, dtype=np.float64)
        if light.angular_radius_deg == 0.0:
            emitter = _child(root, "emitter", type="directional")
            _child(emitter, "vector", name="direction", value=_triple(-to_sun))
            _rgb(emitter, "irradiance", light.irradiance)
            return
        theta = math.radians(light.angular_radius_deg)
        distance = SUN_DISTANCE * self.radius
        disc_radius = distance * math.tan(theta)
        # The disc hides the sky behind it: add the sky's radiance there to the disc's own.
        one_minus_cos = 2.0 * math.sin(0.5 * theta) ** 2
        sin2 = one_minus_cos * (2.0 - one_minus_cos)
        radiance = np.asarray(light.irradiance) / (math.pi * sin2)
        radiance = radiance + sky_radiance(self.state.sky, to_sun)
        matrix = np.eye(4)
        matrix[:3, :3] = _frame(-to_sun) * np.array([disc_radius, disc_radius, 1.0])
        matrix[:3, 3] = self.center + distance * to_sun
        shape = _child(root, "shape", type="disk")
        _matrix(shape, matrix)
        black = _child(shape, "bsdf", type="diffuse")
        _rgb(black, "reflectance", (0.0, 0.0, 0.0))
        emitter = _child(shape, "emitter", type="area")
        _rgb(emitter, "radiance", radiance)
        self.far = max(self.far, 4.0 * distance)
        detail = (
            f"a disc of radius D tan(theta) at D = {SUN_DISTANCE:g} scene radii (Mitsuba's "
            "directional light has no radius): parallax below 1e-4 rad"
        )
        if isinstance(self.state.sky, fmt.GradientSky):
            detail += "; the gradient sky behind the disc is replaced by its value at the centre"
        elif isinstance(self.state.sky, EnvironmentMap):
            detail += "; the environment map behind the disc is replaced by its value at the centre"
        self.note(f"sun lights[{i}] with a radius", "proxy", detail)
