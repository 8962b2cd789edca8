"""The Mitsuba 3 export: each material, light, sky and camera maps to the plugin and parameters
docs/mitsuba.md gives; what Mitsuba cannot express raises naming the feature."""

import dataclasses
import json
import math
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from tracer.crosscheck import mitsuba_conversions as conversions
from tracer.crosscheck import mitsuba_export as mx
from tracer.crosscheck.mitsuba_base import UnsupportedFeature
from tracer.crosscheck.mitsuba_export import export_scene
from tracer.io.images import read_image, write_image
from tracer.scene import format as fmt
from tracer.scene.loader import SceneData, load_scene
from tracer.scene.shapes import box, rectangle, sphere
from tracer.shading.environment_light import environment_lookup, sampling_tables
from tracer.shading.materials import conductor_index_from_reflectance
from tracer.shading.textures import bilinear, srgb_to_linear, texture_table

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = [
    "cornell-box/scene.json",
    "cornell-spheres/scene.json",
    "veach-mis/scene.json",
    "many-lights/scene.json",
    "studio/scene.json",
    "nefertiti/scene.json",
    "outdoor/scene.json",
    "gltf-box/Box.gltf",
    "environment/scene.json",
    "textured/scene.json",
]


def state_of(materials, shapes=None, lights=(), sky=None, camera=None, render=None):
    """A scene of one shape per material (a unit rectangle unless ``shapes`` says otherwise)."""
    from tracer.scene.loader import MeshData

    names = list(materials)
    shapes = shapes or {}
    meshes = []
    for i, name in enumerate(names):
        vertices, faces = shapes.get(name, rectangle(1.0, 1.0))
        meshes.append(MeshData(name, vertices + [0.0, 0.0, -2.0 * i], faces, i))
    data = SceneData(
        camera=camera or fmt.Camera(),
        render=render or fmt.RenderSettings(),
        material_names=names,
        materials=list(materials.values()),
        meshes=meshes,
        sky=sky or fmt.ConstantSky(),
        lights=list(lights),
    )
    return data.to_state()


def export(tmp_path, state, **kwargs):
    result = export_scene(state, tmp_path, **kwargs)
    return result, ET.fromstring(result.xml)


def bsdf(root, material_index=0):
    """The BSDF element with id material-<index>, unwrapped from ``twosided``."""
    element = root.find(f"bsdf[@id='material-{material_index}']")
    return element, (element.find("bsdf") if element.get("type") == "twosided" else element)


def value(element, tag, name):
    found = element.find(f"{tag}[@name='{name}']")
    assert found is not None, f"no <{tag} name={name!r}>"
    return found.get("value")


def numbers(text):
    return np.array([float(v) for v in text.replace(",", " ").split()])


def test_xml_refers_only_to_written_files_and_defined_bsdfs(tmp_path):
    result, root = export(tmp_path, load_scene(ROOT / "scenes" / "outdoor" / "scene.json"))
    assert result.xml_path == tmp_path / "scene.xml"
    assert result.xml_path.read_text() == result.xml
    ids = {e.get("id") for e in root.iter() if e.get("id")}
    for ref in root.iter("ref"):
        assert ref.get("id") in ids
    for node in root.iter("string"):
        if node.get("name") == "filename":
            assert (tmp_path / node.get("value")).is_file(), node.get("value")


def test_meshes_are_world_space_triangles_without_normals(tmp_path):
    state = load_scene(ROOT / "scenes" / "veach-mis" / "scene.json")
    _, root = export(tmp_path, state)
    shapes = [s for s in root.findall("shape") if s.get("type") == "ply"]
    ours = state.world_meshes()
    files = [tmp_path / value(s, "string", "filename") for s in shapes]
    first = trimesh.load(files[0], process=False)
    np.testing.assert_allclose(first.vertices, ours[0].vertices)
    np.testing.assert_array_equal(first.faces, ours[0].faces)
    assert b"nx" not in files[0].read_bytes()[:400]  # no vertex normals in the header
    assert all(value(s, "boolean", "face_normals") == "true" for s in shapes)


def test_diffuse_two_sided_is_wrapped_one_sided_is_not(tmp_path):
    state = state_of(
        {
            "a": fmt.DiffuseMaterial(reflectance=(0.1, 0.2, 0.3)),
            "b": fmt.DiffuseMaterial(reflectance=(0.4, 0.5, 0.6), two_sided=False),
        }
    )
    _, root = export(tmp_path, state)
    outer, inner = bsdf(root, 0)
    assert outer.get("type") == "twosided" and inner.get("type") == "diffuse"
    np.testing.assert_allclose(numbers(value(inner, "rgb", "reflectance")), [0.1, 0.2, 0.3])
    outer, inner = bsdf(root, 1)
    assert outer is inner and outer.get("type") == "diffuse"


def test_mirror_is_a_perfect_conductor_with_its_reflectance(tmp_path):
    _, root = export(tmp_path, state_of({"m": fmt.MirrorMaterial(type="mirror")}))
    _, inner = bsdf(root)
    assert inner.get("type") == "conductor"
    assert value(inner, "string", "material") == "none"
    np.testing.assert_allclose(numbers(value(inner, "rgb", "specular_reflectance")), 1.0)


def test_dielectric_without_absorption_uses_the_path_tracer(tmp_path):
    glass = fmt.DielectricMaterial(type="dielectric", ior=1.33)
    result, root = export(tmp_path, state_of({"g": glass}, shapes={"g": sphere(1.0, 1)}))
    outer, inner = bsdf(root)
    assert outer is inner and inner.get("type") == "dielectric"
    assert float(value(inner, "float", "int_ior")) == 1.33
    assert float(value(inner, "float", "ext_ior")) == 1.0
    assert result.integrator == "path" and root.find("integrator").get("type") == "path"
    assert root.find(".//medium") is None


def test_absorbing_dielectric_gets_an_interior_medium_and_volpath(tmp_path):
    glass = fmt.DielectricMaterial(type="dielectric", absorption=(1.5, 0.4, 0.1))
    result, root = export(tmp_path, state_of({"g": glass}, shapes={"g": sphere(1.0, 1)}))
    assert result.integrator == "volpath"
    medium = root.find("shape/medium")
    assert medium.get("type") == "homogeneous" and medium.get("name") == "interior"
    sigma = numbers(value(medium, "rgb", "sigma_t")) * float(value(medium, "float", "scale"))
    np.testing.assert_allclose(sigma, [1.5, 0.4, 0.1])
    assert numbers(value(medium, "rgb", "sigma_t")).max() <= 1.0
    np.testing.assert_array_equal(numbers(value(medium, "rgb", "albedo")), 0.0)


def test_smooth_conductor_from_reflectance_uses_our_complex_index(tmp_path):
    gold = fmt.ConductorMaterial(type="conductor", reflectance=(0.95, 0.78, 0.34))
    result, root = export(tmp_path, state_of({"c": gold}))
    _, inner = bsdf(root)
    assert inner.get("type") == "conductor"
    eta, k = zip(*(conductor_index_from_reflectance(r) for r in (0.95, 0.78, 0.34)), strict=True)
    np.testing.assert_allclose(numbers(value(inner, "rgb", "eta")), eta)
    np.testing.assert_allclose(numbers(value(inner, "rgb", "k")), k)
    assert result.deviations == ()


def test_rough_conductor_is_ggx_with_alpha_roughness_squared(tmp_path):
    copper = fmt.ConductorMaterial(type="conductor", eta=(0.27, 0.68, 1.22), k=(3.6, 2.6, 2.3))
    copper = fmt.override(copper, roughness=0.3)
    result, root = export(tmp_path, state_of({"c": copper}))
    _, inner = bsdf(root)
    assert inner.get("type") == "roughconductor"
    assert value(inner, "string", "distribution") == "ggx"
    assert float(value(inner, "float", "alpha")) == pytest.approx(0.09)
    np.testing.assert_allclose(numbers(value(inner, "rgb", "eta")), [0.27, 0.68, 1.22])
    np.testing.assert_allclose(numbers(value(inner, "rgb", "k")), [3.6, 2.6, 2.3])
    assert [(d.kind, d.feature) for d in result.deviations] == [("model", "rough conductor 'c'")]
    with pytest.raises(UnsupportedFeature, match="rough conductor 'c'"):
        export_scene(state_of({"c": copper}), tmp_path / "strict", strict=True)


def test_smooth_plastic_is_mitsubas_plastic_with_the_linear_base(tmp_path):
    plastic = fmt.PlasticMaterial(type="plastic", reflectance=(0.7, 0.1, 0.1), ior=1.6)
    plastic = fmt.override(plastic, roughness=0.0)
    result, root = export(tmp_path, state_of({"p": plastic}))
    _, inner = bsdf(root)
    assert inner.get("type") == "plastic"
    assert float(value(inner, "float", "int_ior")) == 1.6
    assert float(value(inner, "float", "ext_ior")) == 1.0
    assert value(inner, "boolean", "nonlinear") == "false"
    np.testing.assert_allclose(numbers(value(inner, "rgb", "diffuse_reflectance")), [0.7, 0.1, 0.1])
    assert result.deviations == ()


def test_smooth_plastic_under_a_delta_light_is_a_model_difference(tmp_path):
    plastic = fmt.override(fmt.PlasticMaterial(type="plastic"), roughness=0.0)
    point = fmt.PointLight(type="point", position=(0, 1, 0), intensity=(1, 1, 1))
    result, _ = export(tmp_path, state_of({"p": plastic}, lights=[point]))
    assert [(d.kind, d.feature) for d in result.deviations] == [
        ("model", "smooth plastic 'p' under delta lights")
    ]


def test_rough_plastic_is_roughplastic_with_its_base_scaled_and_a_model_difference(tmp_path):
    plastic = fmt.PlasticMaterial(type="plastic", reflectance=(0.1, 0.45, 0.45), roughness=0.3)
    result, root = export(tmp_path, state_of({"p": plastic}))
    _, inner = bsdf(root)
    assert inner.get("type") == "roughplastic"
    assert value(inner, "string", "distribution") == "ggx"
    assert float(value(inner, "float", "alpha")) == pytest.approx(0.09)
    assert value(inner, "boolean", "nonlinear") == "false"
    scale = conversions.rough_plastic_base_scale(0.09, 1.5)
    np.testing.assert_allclose(
        numbers(value(inner, "rgb", "diffuse_reflectance")), np.array([0.1, 0.45, 0.45]) * scale
    )
    assert [d.kind for d in result.deviations] == ["model"]
    assert f"{scale:.5f}" in result.deviations[0].detail


def smooth_internal_fresnel(mu: float, ior: float) -> float:
    """Fresnel reflectance of a smooth interface met from inside (relative index 1 / ior)."""
    sin2_t = (1.0 - mu * mu) * ior * ior
    if sin2_t >= 1.0:
        return 1.0
    cos_t = math.sqrt(1.0 - sin2_t)
    r_s = (ior * mu - cos_t) / (ior * mu + cos_t)
    r_p = (mu - ior * cos_t) / (mu + ior * cos_t)
    return 0.5 * (r_s * r_s + r_p * r_p)


def test_base_scale_of_a_nearly_smooth_coat_is_mitsubas_sum_against_the_integral():
    """Near the smooth limit both internal reflectances are the smooth interface's: Mitsuba's
    as the mean of 2 F mu over 64 equally spaced cosines (0.5875 at ior 1.5), ours the
    integral (0.5963, by adaptive quadrature here): the scale undoes that sum's deficit. At
    alpha 1e-4 the rough interface still rounds the kink at the critical angle (3e-5 here)."""
    from scipy import integrate

    ior, alpha = 1.5, 1e-4
    mu = np.maximum(1e-6, np.linspace(0.0, 1.0, 64))
    summed = 2.0 * np.mean([smooth_internal_fresnel(m, ior) * m for m in mu])
    critical = math.sqrt(1.0 - 1.0 / ior**2)
    integral = sum(
        2.0 * integrate.quad(lambda m: smooth_internal_fresnel(m, ior) * m, lo, hi)[0]
        for lo, hi in ((0.0, critical), (critical, 1.0))
    )
    assert conversions.mitsuba_internal_reflectance(alpha, ior) == pytest.approx(summed, abs=5e-5)
    expected = (1.0 - summed) / (1.0 - integral)
    assert conversions.rough_plastic_base_scale(alpha, ior) == pytest.approx(expected, abs=2e-4)
    assert 1.015 < expected < 1.025


def test_base_scale_at_roughness_03_uses_the_separable_masking():
    """Separable masking never shadows less than height-correlated: Mitsuba's coat reflects
    less from inside than ours at every cosine, and its Fdr is below our Fdr summed its way."""
    from tracer.shading.materials import COAT_QUADRATURE, coat_tables, gauss_legendre
    from tracer.shading.microfacet import ggx_dielectric_albedo

    alpha, ior = 0.09, 1.5
    nodes, weights = gauss_legendre(COAT_QUADRATURE)
    mu = np.maximum(1e-6, np.linspace(0.0, 1.0, 64))
    ours = np.array([ggx_dielectric_albedo(m, alpha, 1.0 / ior, nodes, weights)[0] for m in mu])
    theirs = np.array(
        [conversions.separable_coat_reflectance(m, alpha, 1.0 / ior, nodes, weights) for m in mu]
    )
    assert np.all(theirs <= ours + 1e-12) and np.any(theirs < ours - 1e-4)
    fdr = conversions.mitsuba_internal_reflectance(alpha, ior)
    assert fdr == pytest.approx(2.0 * np.mean(theirs * mu), rel=1e-12)
    assert fdr < 2.0 * np.mean(ours * mu) - 1e-4
    expected = (1.0 - fdr) / (1.0 - coat_tables(alpha, ior)[1])
    assert conversions.rough_plastic_base_scale(alpha, ior) == pytest.approx(expected, rel=1e-12)
    assert 1.015 < expected < 1.025


def test_textured_rough_plastic_base_gets_the_same_scale(tmp_path):
    Image.fromarray(np.full((2, 3, 3), 128, np.uint8)).save(tmp_path / "grey.png")
    plastic = {"type": "plastic", "reflectance": [0.2, 0.4, 0.6], "roughness": 0.25,
               "texture": {"file": "grey.png"}}  # fmt: skip
    quad = {"name": "q", "shape": {"type": "rectangle"}, "material": "p"}
    scene = {"format": "tilerender/1", "materials": {"p": plastic}, "objects": [quad]}
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    _, root = export(tmp_path / "out", load_scene(tmp_path / "scene.json"))
    _, inner = bsdf(root)
    assert inner.get("type") == "roughplastic"
    _, image = bitmap_of(tmp_path / "out", inner)
    scale = conversions.rough_plastic_base_scale(0.25**2, 1.5)
    expected = srgb_to_linear(np.uint8(128)) * np.float32([0.2, 0.4, 0.6]) * scale
    np.testing.assert_allclose(image[0, 0], expected, rtol=1e-6)


def test_mitsubas_exported_rough_plastic_base_is_ours(tmp_path):
    """In Mitsuba itself (optional here): the internal reflectance its roughplastic computes
    (read off the base's linear / nonlinear ratio) is ours to the quadratures' 2e-4, and the
    exported material's base term equals ours up to the transmittance's masking (0.1% at
    roughness 0.3 up to 70 degrees; docs/mitsuba.md)."""
    mi = pytest.importorskip("mitsuba")
    from tracer.shading import bsdf as ours
    from tracer.shading.materials import material_row

    mi.set_variant("scalar_rgb")

    def base(material, wo, wi) -> np.ndarray:
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*wo)
        si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
        ctx = mi.BSDFContext()
        ctx.component = 1  # the diffuse base
        return np.array(material.eval(ctx, si, mi.Vector3f(*wi)))

    colour = (0.1, 0.45, 0.45)
    plastic = fmt.PlasticMaterial(type="plastic", reflectance=colour, roughness=0.3)
    _, root = export(tmp_path, state_of({"p": plastic}, camera=fmt.Camera(width=4, height=4)))
    inner = bsdf(root)[1]
    inner.set("version", "3.0.0")
    exported = mi.load_string(ET.tostring(inner, encoding="unicode"))
    spec = {key: inner.find(f"*[@name='{key}']").get("value") for key in ("alpha", "int_ior")}
    linear, nonlinear = (
        mi.load_dict({"type": "roughplastic", "distribution": "ggx", "nonlinear": flag,
                      "alpha": float(spec["alpha"]), "int_ior": float(spec["int_ior"]),
                      "ext_ior": 1.0, "diffuse_reflectance": {"type": "rgb", "value": 0.5}})
        for flag in (False, True)
    )  # fmt: skip
    wo, wi = (0.3, 0.0, math.sqrt(0.91)), (0.0, 0.2, math.sqrt(0.96))
    q = base(nonlinear, wo, wi)[0] / base(linear, wo, wi)[0]  # (1 - F) / (1 - F / 2)
    assert (1.0 - q) / (1.0 - 0.5 * q) == pytest.approx(
        conversions.mitsuba_internal_reflectance(0.09, 1.5), abs=2e-4
    )

    _, albedo, _, _, row = material_row(plastic)
    param = tuple(float(p) for p in row[: ours.PARAMS])
    for theta_o, theta_i in ((0.0, 30.0), (45.0, 10.0), (60.0, 70.0)):
        wo = (math.sin(math.radians(theta_o)), 0.0, math.cos(math.radians(theta_o)))
        wi = (0.0, math.sin(math.radians(theta_i)), math.cos(math.radians(theta_i)))
        t = ours.coat_transmittance(param, row, wi[2]) * ours.coat_transmittance(param, row, wo[2])
        mine = np.array(albedo) * t * wi[2] / (math.pi * 1.5**2 * (1.0 - param[ours.FDR_INT]))
        np.testing.assert_allclose(base(exported, wo, wi), mine, rtol=1e-3)


def emitter_shapes(root):
    return [s for s in root.findall("shape") if s.find("emitter") is not None]


def test_one_sided_emitter_is_one_area_light(tmp_path):
    lamp = fmt.DiffuseMaterial(reflectance=(0, 0, 0), emission=(5, 4, 3), two_sided=False)
    result, root = export(tmp_path, state_of({"lamp": lamp}))
    (shape,) = emitter_shapes(root)
    emitter = shape.find("emitter")
    assert emitter.get("type") == "area"
    np.testing.assert_allclose(numbers(value(emitter, "rgb", "radiance")), [5, 4, 3])
    assert result.deviations == ()


def test_two_sided_closed_emitter_emits_from_its_outside_only(tmp_path):
    lamp = fmt.DiffuseMaterial(reflectance=(0, 0, 0), emission=(5, 5, 5))
    state = state_of({"lamp": lamp}, shapes={"lamp": box((1.0, 1.0, 1.0))})
    result, root = export(tmp_path, state)
    assert len(emitter_shapes(root)) == 1
    assert result.deviations == ()


def test_two_sided_closed_emitter_around_the_camera_is_duplicated(tmp_path):
    lamp = fmt.DiffuseMaterial(reflectance=(0, 0, 0), emission=(5, 5, 5))
    camera = fmt.Camera(position=(0.0, 0.0, 0.0), look_at=(0.0, 0.0, -1.0))
    state = state_of({"lamp": lamp}, shapes={"lamp": sphere(3.0, 2)}, camera=camera)
    result, root = export(tmp_path, state)
    assert len(emitter_shapes(root)) == 2
    assert [d.kind for d in result.deviations] == ["proxy"]


def test_two_sided_open_emitter_gets_a_reversed_copy_just_behind(tmp_path):
    lamp = fmt.DiffuseMaterial(reflectance=(0, 0, 0), emission=(5, 5, 5))
    result, root = export(tmp_path, state_of({"lamp": lamp}))
    front, back = (
        trimesh.load(tmp_path / value(s, "string", "filename"), process=False)
        for s in emitter_shapes(root)
    )
    np.testing.assert_array_equal(back.faces, front.faces[:, ::-1])
    np.testing.assert_allclose(back.face_normals, -front.face_normals)
    gap = (front.vertices - back.vertices) @ front.face_normals[0]
    assert np.all(gap > 0.0) and np.all(gap < 1e-4)  # behind the front, by a hair
    assert [(d.kind, d.feature) for d in result.deviations] == [
        ("proxy", "two-sided emitter 'lamp'")
    ]


def test_point_light(tmp_path):
    point = fmt.PointLight(type="point", position=(1, 2, 3), intensity=(4, 5, 6))
    _, root = export(tmp_path, state_of({"a": fmt.DiffuseMaterial()}, lights=[point]))
    emitter = root.find("emitter[@type='point']")
    np.testing.assert_allclose(numbers(value(emitter, "point", "position")), [1, 2, 3])
    np.testing.assert_allclose(numbers(value(emitter, "rgb", "intensity")), [4, 5, 6])


def spot(falloff):
    return fmt.SpotLight(
        type="spot",
        position=(0, 3, 0),
        look_at=(1, 0, 0),
        intensity=(2, 2, 2),
        cone_angle_deg=30.0,
        falloff_deg=falloff,
    )


def test_hard_spot_is_a_cone_with_no_falloff(tmp_path):
    result, root = export(tmp_path, state_of({"a": fmt.DiffuseMaterial()}, lights=[spot(0.0)]))
    emitter = root.find("emitter[@type='spot']")
    assert float(value(emitter, "float", "cutoff_angle")) == 30.0
    assert float(value(emitter, "float", "beam_width")) == 30.0
    assert emitter.find("texture") is None
    lookat = emitter.find("transform/lookat")
    np.testing.assert_allclose(numbers(lookat.get("origin")), [0, 3, 0])
    np.testing.assert_allclose(numbers(lookat.get("target")), [1, 0, 0])
    up = numbers(lookat.get("up"))
    assert abs(up @ np.array([1.0, -3.0, 0.0])) < 1e-12  # perpendicular to the axis
    assert result.deviations == ()


def test_soft_spot_carries_our_falloff_in_a_projection_bitmap(tmp_path):
    result, root = export(tmp_path, state_of({"a": fmt.DiffuseMaterial()}, lights=[spot(10.0)]))
    texture = root.find("emitter[@type='spot']/texture")
    image = read_image(tmp_path / value(texture, "string", "filename"))
    n = conversions.SPOT_TEXTURE_SIZE
    assert image.shape == (n, n, 3)
    # Texel (i, j) centre looks along ((2u - 1) tan 30, (2v - 1) tan 30, 1).
    i, j = 3 * n // 8, n // 2
    s = (2.0 * (np.array([i, j]) + 0.5) / n - 1.0) * math.tan(math.radians(30.0))
    angle = math.degrees(math.atan(math.hypot(*s)))
    t = math.cos(math.radians(angle)) - math.cos(math.radians(30))
    t /= math.cos(math.radians(20)) - math.cos(math.radians(30))
    expected = t * t * (3 - 2 * t) if 0 < t < 1 else float(t >= 1)
    assert image[j, i, 0] == pytest.approx(expected, abs=1e-6)
    assert image[n // 2, n // 2, 0] == 1.0 and image[0, 0, 0] == 0.0
    assert [d.kind for d in result.deviations] == ["proxy"]


def test_sun_without_radius_is_directional(tmp_path):
    sun = fmt.SunLight(type="sun", to_sun=(0, 1, 1), irradiance=(3, 2, 1), angular_radius_deg=0.0)
    result, root = export(tmp_path, state_of({"a": fmt.DiffuseMaterial()}, lights=[sun]))
    emitter = root.find("emitter[@type='directional']")
    direction = numbers(value(emitter, "vector", "direction"))
    np.testing.assert_allclose(direction, -np.array([0, 1, 1]) / math.sqrt(2))
    np.testing.assert_allclose(numbers(value(emitter, "rgb", "irradiance")), [3, 2, 1])
    assert result.deviations == ()


def test_sun_with_radius_is_a_far_disc_of_the_same_solid_angle_and_irradiance(tmp_path):
    sun = fmt.SunLight(type="sun", to_sun=(0, 1, 0), irradiance=(3, 2, 1), angular_radius_deg=2.0)
    sky = fmt.ConstantSky(radiance=(0.1, 0.2, 0.3))
    state = state_of({"a": fmt.DiffuseMaterial()}, lights=[sun], sky=sky)
    result, root = export(tmp_path, state)
    disk = root.find("shape[@type='disk']")
    matrix = numbers(disk.find("transform/matrix").get("value")).reshape(4, 4)
    center = matrix[:3, 3]
    radius = np.linalg.norm(matrix[:3, 0])
    normal = matrix[:3, 2] / np.linalg.norm(matrix[:3, 2])
    scene_center = np.array([0.0, 0.0, 0.0])  # the unit rectangle at the origin
    to_disc = center - scene_center
    assert math.degrees(math.atan(radius / np.linalg.norm(to_disc))) == pytest.approx(2.0)
    np.testing.assert_allclose(normal, -to_disc / np.linalg.norm(to_disc), atol=1e-12)
    radiance = numbers(value(disk.find("emitter"), "rgb", "radiance"))
    solid_angle_cos = math.pi * math.sin(math.radians(2.0)) ** 2  # projected solid angle
    np.testing.assert_allclose((radiance - [0.1, 0.2, 0.3]) * solid_angle_cos, [3, 2, 1])
    np.testing.assert_array_equal(numbers(value(disk.find("bsdf"), "rgb", "reflectance")), 0.0)
    far = float(value(root.find("sensor"), "float", "far_clip"))
    assert far > np.linalg.norm(to_disc) + 10.0
    assert [d.kind for d in result.deviations] == ["proxy"]


def test_constant_sky_and_a_black_sky(tmp_path):
    sky = fmt.ConstantSky(radiance=(0.5, 0.6, 0.7))
    _, root = export(tmp_path / "a", state_of({"a": fmt.DiffuseMaterial()}, sky=sky))
    emitter = root.find("emitter[@type='constant']")
    np.testing.assert_allclose(numbers(value(emitter, "rgb", "radiance")), [0.5, 0.6, 0.7])
    _, root = export(tmp_path / "b", state_of({"a": fmt.DiffuseMaterial()}))
    assert root.find("emitter") is None


def test_gradient_sky_is_an_envmap_with_rows_at_mitsubas_polar_angles(tmp_path):
    sky = fmt.GradientSky(type="gradient", zenith=(0.2, 0.3, 0.8), horizon=(0.8, 0.8, 0.9),
                          ground=(0.3, 0.2, 0.1))  # fmt: skip
    result, root = export(tmp_path, state_of({"a": fmt.DiffuseMaterial()}, sky=sky))
    emitter = root.find("emitter[@type='envmap']")
    image = read_image(tmp_path / value(emitter, "string", "filename"))
    rows = conversions.SKY_ROWS
    assert image.shape == (rows, conversions.SKY_COLUMNS, 3)
    np.testing.assert_allclose(image[0, 0], [0.2, 0.3, 0.8])  # straight up
    np.testing.assert_allclose(image[-1, 0], [0.3, 0.2, 0.1])  # straight down
    i = rows // 3
    y = math.cos(i * math.pi / (rows - 1))
    expected = [0.8 - 0.6 * y, 0.8 - 0.5 * y, 0.9 - 0.1 * y]
    np.testing.assert_allclose(image[i, 5], expected, rtol=1e-6)
    # The horizon falls between two rows: above it the horizon colour, below it the ground.
    np.testing.assert_allclose(image[rows // 2 - 1, 0], [0.8, 0.8, 0.9], atol=1e-3)
    np.testing.assert_allclose(image[rows // 2, 0], [0.3, 0.2, 0.1])
    assert [d.kind for d in result.deviations] == ["proxy"]


def test_pinhole_camera_film_and_integrator(tmp_path):
    camera = fmt.Camera(position=(1, 2, 3), look_at=(0, 1, 0), vfov_deg=35.0, width=40, height=30)
    render = fmt.RenderSettings(spp=7, max_depth=5, rr_depth=3)
    _, root = export(tmp_path, state_of({"a": fmt.DiffuseMaterial()}, camera=camera, render=render))
    sensor = root.find("sensor")
    assert sensor.get("type") == "perspective"
    assert value(sensor, "string", "fov_axis") == "y"
    assert float(value(sensor, "float", "fov")) == 35.0
    lookat = sensor.find("transform/lookat")
    np.testing.assert_allclose(numbers(lookat.get("origin")), [1, 2, 3])
    np.testing.assert_allclose(numbers(lookat.get("target")), [0, 1, 0])
    np.testing.assert_allclose(numbers(lookat.get("up")), [0, 1, 0])
    assert value(sensor.find("sampler"), "integer", "sample_count") == "7"
    assert sensor.find("sampler").get("type") == "independent"
    film = sensor.find("film")
    assert (value(film, "integer", "width"), value(film, "integer", "height")) == ("40", "30")
    assert film.find("rfilter").get("type") == "box"
    integrator = root.find("integrator")
    assert value(integrator, "integer", "max_depth") == "5"
    assert value(integrator, "integer", "rr_depth") == "3"
    assert value(integrator, "boolean", "hide_emitters") == "false"


def test_thin_lens_camera_focuses_at_the_look_at_distance_by_default(tmp_path):
    camera = fmt.Camera(position=(0, 0, 5), look_at=(0, 0, 1), aperture_radius=0.1)
    _, root = export(tmp_path, state_of({"a": fmt.DiffuseMaterial()}, camera=camera))
    sensor = root.find("sensor")
    assert sensor.get("type") == "thinlens"
    assert float(value(sensor, "float", "aperture_radius")) == 0.1
    assert float(value(sensor, "float", "focus_distance")) == 4.0


def test_direct_integrator_is_a_path_of_two_vertices(tmp_path):
    render = fmt.RenderSettings(integrator="direct", max_depth=8)
    _, root = export(tmp_path, state_of({"a": fmt.DiffuseMaterial()}, render=render))
    assert value(root.find("integrator"), "integer", "max_depth") == "2"


@pytest.mark.parametrize(
    "render, feature",
    [
        (fmt.RenderSettings(integrator="ao"), "integrator 'ao'"),
        (fmt.RenderSettings(integrator="whitted"), "integrator 'whitted'"),
        (fmt.RenderSettings(effects={"shadows": False}), "effects switched off (shadows)"),
    ],
)
def test_settings_mitsuba_cannot_reproduce_raise_naming_them(tmp_path, render, feature):
    with pytest.raises(UnsupportedFeature) as error:
        export_scene(state_of({"a": fmt.DiffuseMaterial()}, render=render), tmp_path)
    assert error.value.feature == feature
    assert not (tmp_path / "scene.xml").exists()


def test_a_model_field_the_export_does_not_know_raises_naming_it(tmp_path, monkeypatch):
    """A field added to a model later (a texture, say) is refused when set, not dropped."""
    known = dict(mx.KNOWN_FIELDS)
    known[fmt.DiffuseMaterial] = {"type", "emission", "two_sided"}  # as if reflectance were new
    monkeypatch.setattr(mx, "KNOWN_FIELDS", known)
    with pytest.raises(UnsupportedFeature, match="material 'a': reflectance"):
        export_scene(state_of({"a": fmt.DiffuseMaterial(reflectance=(0.1, 0.1, 0.1))}), tmp_path)
    export_scene(state_of({"a": fmt.DiffuseMaterial()}), tmp_path)  # the default passes


def test_an_unknown_sky_kind_raises_naming_it(tmp_path):
    class EnvironmentSky(fmt.Strict):
        type: str = "envmap"
        path: str = "sky.exr"

    state = state_of({"a": fmt.DiffuseMaterial()}, sky=EnvironmentSky())
    with pytest.raises(UnsupportedFeature, match="sky of type 'envmap'"):
        export_scene(state, tmp_path)


def textured_scene(folder: Path, rotation: float = 30.0) -> Path:
    """A scene file with a random 12x6 environment map (scale 1.5, turned by ``rotation``) and a
    2 x 1 rectangle at z = 0 with a random 7x5 texture (tinted, repeated, UVs scaled), plus a
    textured conductor and mirror further back."""
    rng = np.random.default_rng(1)
    write_image(folder / "env.exr", rng.uniform(0.1, 2.0, (6, 12, 3)).astype(np.float32))
    Image.fromarray(rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)).save(folder / "tex.png")
    texture = {"file": "tex.png", "wrap": "repeat", "scale": [1.5, 2.0]}
    scene = {
        "format": "tilerender/1",
        "camera": {"position": [0, 0, 3], "look_at": [0, 0, 0], "width": 8, "height": 8},
        "sky": {"type": "environment", "file": "env.exr", "scale": 1.5, "rotation": rotation},
        "materials": {
            "t": {"reflectance": [0.9, 0.5, 0.7], "texture": texture},
            "metal": {"type": "conductor", "reflectance": [0.9, 0.8, 0.5], "texture": texture},
            "mirror": {"type": "mirror", "reflectance": [0.5, 0.5, 0.5], "texture": texture},
        },
        "objects": [
            {"name": "quad", "shape": {"type": "rectangle", "size": [2, 1]}, "material": "t"},
            {"name": "metal", "shape": {"type": "rectangle", "size": [1, 1]}, "material": "metal",
             "transform": {"translate": [0, 0, -2]}},
            {"name": "mirror", "shape": {"type": "rectangle", "size": [1, 1]},
             "material": "mirror", "transform": {"translate": [0, 0, -4]}},
        ],
    }  # fmt: skip
    path = folder / "scene.json"
    path.write_text(json.dumps(scene))
    return path


def bitmap_of(tmp_path, parent):
    texture = parent.find("texture")
    assert texture.get("type") == "bitmap"
    assert value(texture, "boolean", "raw") == "true"
    assert value(texture, "string", "filter_type") == "bilinear"
    return texture, read_image(tmp_path / value(texture, "string", "filename"))


def test_textures_are_bitmaps_of_linear_texels_times_the_base_colour(tmp_path):
    state = load_scene(textured_scene(tmp_path))
    result, root = export(tmp_path / "out", state)
    linear = srgb_to_linear(state.textures["tex.png"])
    names = sorted({m.material for m in state.world_meshes()})  # material-<i> in this order
    expected = {"t": ("reflectance", [0.9, 0.5, 0.7]), "metal": ("specular_reflectance", 1.0),
                "mirror": ("specular_reflectance", [0.5, 0.5, 0.5])}  # fmt: skip
    for name, (parameter, tint) in expected.items():
        _, inner = bsdf(root, names.index(name))
        texture, image = bitmap_of(tmp_path / "out", inner)
        assert texture.get("name") == parameter
        assert value(texture, "string", "wrap_mode") == "repeat"
        np.testing.assert_allclose(image, linear * np.float32(tint), rtol=1e-6)
    metal = bsdf(root, names.index("metal"))[1]
    assert metal.get("type") == "conductor" and metal.find("rgb[@name='eta']") is not None
    assert result.deviations[0].feature == "environment map"


def test_plastic_texture_tints_its_base_and_clamp_is_kept(tmp_path):
    Image.fromarray(np.full((2, 3, 3), 128, np.uint8)).save(tmp_path / "grey.png")
    plastic = {"type": "plastic", "reflectance": [0.2, 0.4, 0.6], "roughness": 0.0,
               "texture": {"file": "grey.png", "wrap": "clamp"}}  # fmt: skip
    quad = {"name": "q", "shape": {"type": "rectangle"}, "material": "p"}
    scene = {"format": "tilerender/1", "materials": {"p": plastic}, "objects": [quad]}
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    _, root = export(tmp_path / "out", load_scene(tmp_path / "scene.json"))
    _, inner = bsdf(root)
    assert inner.get("type") == "plastic" and inner.find("rgb[@name='diffuse_reflectance']") is None
    texture, image = bitmap_of(tmp_path / "out", inner)
    assert texture.get("name") == "diffuse_reflectance"
    assert value(texture, "string", "wrap_mode") == "clamp"
    expected = srgb_to_linear(np.uint8(128)) * np.float32([0.2, 0.4, 0.6])
    np.testing.assert_allclose(image[0, 0], expected, rtol=1e-6)


def test_textured_meshes_carry_scaled_uvs_with_v_from_the_top(tmp_path):
    state = load_scene(textured_scene(tmp_path))
    _, root = export(tmp_path / "out", state)
    shapes = [s for s in root.findall("shape") if s.get("type") == "ply"]
    for shape, mesh in zip(shapes, state.world_meshes(), strict=True):
        ply = trimesh.load(tmp_path / "out" / value(shape, "string", "filename"), process=False)
        uvs = state.meshes[state.nodes[mesh.node].mesh].uvs
        expected = np.column_stack([1.5 * uvs[:, 0], 1.0 - 2.0 * uvs[:, 1]])
        np.testing.assert_allclose(ply.visual.uv, expected, atol=1e-7)
    plain = load_scene(ROOT / "scenes" / "veach-mis" / "scene.json")
    _, root = export(tmp_path / "plain", plain)
    first = root.find("shape[@type='ply']")
    header = (tmp_path / "plain" / value(first, "string", "filename")).read_bytes()[:400]
    assert b"property float x" in header and b" s\n" not in header  # no UVs without a texture


def test_normal_map_is_mitsubas_normalmap_with_strength_baked_in_and_its_fixes_off(tmp_path):
    """The map's ``2 c - 1`` with its strength baked in, and Mitsuba's own fixes (flipping a
    normal the viewer is below, Estevez et al.'s shadowing; on by default since 3.7.1) off:
    left on, they made mitsuba/normal-map's wall 0.4% brighter than ours (docs/mitsuba.md)."""
    state = load_scene(ROOT / "scenes" / "mitsuba" / "normal-map" / "scene.json")
    result, root = export(tmp_path, state)
    assert not result.model_differences()
    names = sorted({m.material for m in state.world_meshes()})  # material-<i> in this order
    mapped = [n for n in names if state.materials[n].normal_map is not None]
    assert mapped == ["bumpy floor", "ridged wall"]
    for name in mapped:
        wrapper, _ = bsdf(root, names.index(name))
        normalmap = wrapper.find("bsdf[@type='normalmap']")
        assert value(normalmap, "boolean", "flip_invalid_normals") == "false"
        assert value(normalmap, "boolean", "use_shadowing_function") == "false"
        assert normalmap.find("bsdf").get("type") == "diffuse"
        texture, image = bitmap_of(tmp_path, normalmap)
        assert value(texture, "string", "wrap_mode") == "repeat"
        normal_map = state.materials[name].normal_map
        vector = 2.0 * state.textures[normal_map.file] / 255.0 - 1.0
        scale = [normal_map.strength, normal_map.strength, 1.0]
        np.testing.assert_allclose(2.0 * image - 1.0, vector * scale, atol=1e-6)


def test_environment_map_is_upsampled_keeping_its_pixels_and_integral(tmp_path):
    state = load_scene(textured_scene(tmp_path))
    sky = state.sky
    bitmap, k = conversions.environment_bitmap(sky)
    h, w = sky.image.shape[:2]
    scaled = (sky.image.astype(np.float64) * 1.5).astype(np.float32)
    assert k == conversions.ENVIRONMENT_MAX_FACTOR and bitmap.shape == (k * h + 1, k * w, 3)
    # Away from the edges, texel (i', j') holds the pixel it lies in; an edge row the mean.
    np.testing.assert_array_equal(bitmap[1:k, :k], np.broadcast_to(scaled[0, 0], (k - 1, k, 3)))
    np.testing.assert_array_equal(bitmap[0, ::k], scaled[0])
    np.testing.assert_allclose(bitmap[k, 5 * k], 0.5 * (scaled[0, 5] + scaled[1, 5]), rtol=1e-6)
    np.testing.assert_array_equal(bitmap[-1, ::k], scaled[-1])
    # Integrated over the sphere as Mitsuba interpolates it (rows at i' pi / (H' - 1),
    # linear in between), the mean radiance is ours (1.5 x the image's mean) to O(1/k^2).
    theta = np.linspace(0.0, math.pi, 20001)
    texel_theta = np.linspace(0.0, math.pi, k * h + 1)
    row_means = bitmap.mean(axis=1)
    rows = np.stack([np.interp(theta, texel_theta, row_means[:, c]) for c in range(3)], axis=1)
    weights = np.sin(theta)
    mitsuba_mean = (rows * weights[:, None]).sum(axis=0) / weights.sum()
    np.testing.assert_allclose(mitsuba_mean, sky.mean_radiance(), rtol=2e-3)


def test_environment_to_world_turns_our_centre_to_mitsubas(tmp_path):
    """Mitsuba looks up ``u = atan2(x, -z) / 2 pi`` of the local direction (its image centre
    along +z); ours has the centre along -z, turned by ``rotation`` about +y."""
    for rotation in (0.0, 30.0, -120.0):
        matrix = conversions.environment_to_world(rotation)[:3, :3]
        r = math.radians(rotation)
        # Our image centre looks along -z turned counter-clockwise (seen from above) by r.
        centre = np.array([-math.sin(r), 0.0, -math.cos(r)])
        local = np.linalg.solve(matrix, centre)
        u = math.atan2(local[0], -local[2]) / (2.0 * math.pi) % 1.0
        assert u == pytest.approx(0.5)
        np.testing.assert_allclose(matrix @ [0.0, 1.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)


def test_sun_disc_over_an_environment_map_adds_the_map_behind_it(tmp_path):
    state = load_scene(textured_scene(tmp_path))
    to_sun = np.array([0.3, 0.8, -0.5]) / np.linalg.norm([0.3, 0.8, -0.5])
    sun = fmt.SunLight(
        type="sun", to_sun=tuple(to_sun), irradiance=(3, 2, 1), angular_radius_deg=1.0
    )
    result, root = export(tmp_path / "out", dataclasses.replace(state, lights=(sun,)))
    radiance = numbers(value(root.find("shape[@type='disk']/emitter"), "rgb", "radiance"))
    t = sampling_tables(state.sky.image, 1.5)
    r = math.radians(30.0)
    behind, _ = environment_lookup(t.image, t.rows, t.cols, math.cos(r), math.sin(r), to_sun)
    own = np.array([3, 2, 1]) / (math.pi * math.sin(math.radians(1.0)) ** 2)
    np.testing.assert_allclose(radiance, own + behind, rtol=1e-9)
    assert any("environment map behind" in d.detail for d in result.deviations)


def test_mitsuba_sees_our_environment_orientation_and_texture_uvs(tmp_path):
    """In Mitsuba itself (optional here): its envmap at the centre of each of our pixels (any
    rotation) returns that pixel, and its bitmap at random points of the rectangle returns our
    bilinear lookup there, tint, UV scale and wrap included."""
    mi = pytest.importorskip("mitsuba")
    import drjit as dr

    mi.set_variant("scalar_rgb")
    state = load_scene(textured_scene(tmp_path))
    scene = mi.load_file(str(export_scene(state, tmp_path / "out").xml_path))
    sky = state.sky
    t = sampling_tables(sky.image, sky.model.scale)
    h, w = sky.image.shape[:2]
    r = math.radians(sky.model.rotation)
    c, s = math.cos(r), math.sin(r)
    for i in range(h):
        for j in range(w):
            theta, phi = math.pi * (i + 0.5) / h, 2.0 * math.pi * ((j + 0.5) / w - 0.5)
            m = np.array([math.sin(theta) * math.sin(phi), math.cos(theta),
                          -math.sin(theta) * math.cos(phi)])  # fmt: skip
            d = np.array([c * m[0] + s * m[2], m[1], c * m[2] - s * m[0]])  # map -> world
            ours, _ = environment_lookup(t.image, t.rows, t.cols, c, s, d)
            np.testing.assert_array_equal(ours, t.image[i, j])
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wi = mi.Vector3f(-d)
            np.testing.assert_allclose(np.array(scene.environment().eval(si)), ours, rtol=1e-6)

    quad = state.meshes[state.nodes[0].mesh]
    np.testing.assert_array_equal(quad.uvs, [[0, 0], [1, 0], [1, 1], [0, 1]])
    np.testing.assert_array_equal(
        quad.vertices[:, :2], [[-1, -0.5], [1, -0.5], [1, 0.5], [-1, 0.5]]
    )
    table = texture_table(state.textures, [state.materials["t"]])
    tint = np.array([0.9, 0.5, 0.7], np.float32)
    rng = np.random.default_rng(0)
    for x, y in rng.uniform((-1.0, -0.5), (1.0, 0.5), (200, 2)):
        si = scene.ray_intersect(mi.Ray3f(mi.Point3f(x, y, 1.0), mi.Vector3f(0, 0, -1)))
        theirs = np.array(si.bsdf().eval_diffuse_reflectance(si))
        u, v = (x + 1.0) / 2.0, y + 0.5  # the quad's UV at (x, y)
        ours = np.array(bilinear(table.pixels, table.info, table.scale, 0, u, v)) * tint
        np.testing.assert_allclose(theirs, ours, atol=2e-6)


def test_winding_numbers_tell_inside_from_outside():
    vertices, faces = sphere(1.0, 2)
    w = conversions.winding_numbers(
        np.array([[0, 0, 0], [0.5, 0.2, 0], [2, 0, 0]]), vertices, faces
    )
    np.testing.assert_allclose(w, [1, 1, 0], atol=1e-9)
    assert conversions.is_closed_outward(*box((1, 2, 3)))
    assert not conversions.is_closed_outward(vertices, faces[:, ::-1])
    assert not conversions.is_closed_outward(*rectangle(1, 1))


def test_the_export_does_not_import_mitsuba():
    code = "import sys, tracer.crosscheck.mitsuba_export; print('mitsuba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize("relative", SAMPLES)
def test_every_sample_scene_exports(tmp_path, relative):
    result = export_scene(load_scene(ROOT / "scenes" / relative), tmp_path)
    ET.fromstring(result.xml)
    assert result.integrator in ("path", "volpath")


def test_mitsuba_loads_and_renders_the_exports(tmp_path):
    """Mitsuba itself (optional here) parses every export and renders it without NaNs."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    for i, relative in enumerate(SAMPLES):
        state = load_scene(ROOT / "scenes" / relative)
        camera = fmt.override(state.camera, width=6, height=4)
        state = dataclasses.replace(state, camera=camera)
        result = export_scene(state, tmp_path / str(i))
        image = np.array(mi.render(mi.load_file(str(result.xml_path)), spp=1))
        assert image.shape == (4, 6, 3) and np.isfinite(image).all(), relative
