"""Whole-image robustness: finite, non-negative radiance everywhere; no light leaks at contacts;
the same image at any scale and any distance from the origin."""

from pathlib import Path

import numpy as np
import pytest

from tests.stats import pass_statistics, welch_pixel_test
from tests.tracer.test_cornell_reference import image_mean_z
from tracer.compiled.scene import compile_scene
from tracer.render import render_image
from tracer.scene.format import Camera, DiffuseMaterial, RenderSettings, override
from tracer.scene.loader import MeshData, SceneData, load_scene
from tracer.scene.shapes import box, plane, rectangle

ROOT = Path(__file__).resolve().parents[2]
SAMPLE_SCENES = sorted(ROOT.glob("scenes/*/scene.json")) + sorted(ROOT.glob("scenes/*/*.gltf"))


@pytest.mark.parametrize("path", SAMPLE_SCENES, ids=lambda p: p.parent.name)
def test_sample_scene_images_are_finite_and_non_negative(path):
    scene = compile_scene(load_scene(path))
    camera = override(scene.camera, width=48, height=32)
    rgb, cost = render_image(scene, camera, override(scene.render, spp=8))
    assert np.isfinite(rgb).all()
    assert (rgb >= 0.0).all()
    assert rgb.max() > 0.0  # something is lit
    assert (cost > 0).all()


def test_no_light_leaks_where_a_box_rests_on_a_floor():
    """A closed box resting on a floor (its bottom coplanar with the floor), the camera inside,
    the only light outside above it: every pixel must be exactly black."""
    floor_v, floor_f = plane(20.0)
    box_v, box_f = box((2.0, 2.0, 2.0))
    box_v = box_v + [0.0, 1.0, 0.0]  # bottom face at y = 0, on the floor
    light_v, light_f = rectangle(4.0, 4.0)
    light_v = light_v @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]]).T + [0.0, 5.0, 0.0]
    data = SceneData(
        camera=Camera(position=(0.6, 0.3, 0.6), look_at=(-1.0, 0.0, -1.0), width=64, height=64),
        render=RenderSettings(spp=16, max_depth=12),
        material_names=["white", "light"],
        materials=[
            DiffuseMaterial(reflectance=(0.95, 0.95, 0.95)),
            DiffuseMaterial(reflectance=(0.0, 0.0, 0.0), emission=(50.0, 50.0, 50.0)),
        ],
        meshes=[
            MeshData("floor", floor_v, floor_f, 0),
            MeshData("box", box_v, box_f, 0),
            MeshData("light", light_v, light_f, 1),
        ],
    )
    scene = compile_scene(data)
    rgb, _ = render_image(scene)
    assert rgb.max() == 0.0, f"{int((rgb.max(axis=2) > 0).sum())} pixels see leaked light"
    # The same camera outside the box sees light: the scene is lit, the box is what blocks it.
    outside = override(scene.camera, position=(4.0, 2.0, 4.0), look_at=(0.0, 0.5, 0.0))
    assert render_image(scene, outside)[0].max() > 0.0


def transformed(state, scale: float, offset: float) -> SceneData:
    """The scene and its camera scaled about the origin, then moved by ``offset`` along (1,1,1)."""
    shift = np.full(3, offset)
    names = list(state.materials)
    meshes = [
        MeshData(m.name, m.vertices * scale + shift, m.faces, names.index(m.material))
        for m in state.world_meshes()
    ]
    camera = override(
        state.camera,
        position=tuple(np.asarray(state.camera.position) * scale + shift),
        look_at=tuple(np.asarray(state.camera.look_at) * scale + shift),
    )
    return SceneData(camera, state.render, names, list(state.materials.values()), meshes)


@pytest.mark.parametrize(("scale", "offset"), [(1e-3, 0.0), (1e4, 0.0), (1.0, 1e5)])
def test_cornell_box_is_scale_and_translation_invariant(scale, offset):
    """The Cornell box scaled by 1e-3 or 1e4, or moved 1e5 away, still matches the reference
    (the same statistics as tests/tracer/test_cornell_reference.py, with 8 passes of 16 spp)."""
    data = transformed(load_scene(ROOT / "scenes" / "cornell-box" / "scene.json"), scale, offset)
    scene = compile_scene(data)
    settings = override(scene.render, spp=16)
    passes = np.stack(
        [render_image(scene, settings=settings, sample_start=16 * k)[0] for k in range(8)]
    )
    ref_dir = ROOT / "scenes" / "cornell-box"
    reference = (
        np.load(ref_dir / "reference_mean.npy").astype(np.float64),
        np.load(ref_dir / "reference_var_of_mean.npy").astype(np.float64),
    )
    assert np.isfinite(passes).all() and (passes >= 0).all()
    z = image_mean_z(passes, reference)
    assert np.all(np.abs(z) < 4.0), z
    mean, var, dof = pass_statistics(passes)
    result = welch_pixel_test(mean, var, dof, *reference, 15)
    assert result.accepted_fraction >= 0.99


def cornell_and_far_speck(distance: float | None, copy_at: float | None = None) -> SceneData:
    """The Cornell box with a black 1x1 static triangle at (d, d, d) (none for None), and a
    second Cornell box moved by ``copy_at`` along x."""
    data = transformed(load_scene(ROOT / "scenes" / "cornell-box" / "scene.json"), 1.0, 0.0)
    data.material_names.append("black")
    data.materials.append(DiffuseMaterial(reflectance=(0.0, 0.0, 0.0)))
    if distance is not None:
        speck = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]) + distance
        data.meshes.append(MeshData("speck", speck, np.array([[0, 1, 2]]), len(data.materials) - 1))
    if copy_at is not None:
        shift = np.array([copy_at, 0.0, 0.0])
        data.meshes += [
            MeshData(f"{m.name}-copy", m.vertices + shift, m.faces, m.material)
            for m in list(data.meshes)
            if m.name != "speck"
        ]
    return data


FAR = [1e3, 1e4, 1e5, 1e6, 1e7, 1e8]


@pytest.mark.parametrize("distance", FAR)
def test_a_far_object_leaves_the_rest_of_the_scene_exactly_as_it_was(distance):
    """Precision of static geometry is local: the Cornell box with a far speck is baked apart
    from it, and renders bit for bit as without it (so it matches the reference as well as the
    plain box does, tests/tracer/test_cornell_reference.py)."""
    alone = compile_scene(cornell_and_far_speck(None))
    with_speck = compile_scene(cornell_and_far_speck(distance))
    assert with_speck.static_clusters == 2
    settings = override(alone.render, spp=4)
    camera = override(alone.camera, width=64, height=64)
    expected = render_image(alone, camera, settings)[0]
    assert np.array_equal(render_image(with_speck, camera, settings)[0], expected)


def render_against_reference(scene, camera=None) -> tuple[np.ndarray, float]:
    """Image-mean z per channel and the per-pixel acceptance against the Cornell reference, from
    8 passes of 16 spp."""
    settings = override(scene.render, spp=16)
    passes = np.stack(
        [render_image(scene, camera, settings, sample_start=16 * k)[0] for k in range(8)]
    )
    ref_dir = ROOT / "scenes" / "cornell-box"
    reference = (
        np.load(ref_dir / "reference_mean.npy").astype(np.float64),
        np.load(ref_dir / "reference_var_of_mean.npy").astype(np.float64),
    )
    mean, var, dof = pass_statistics(passes)
    accepted = welch_pixel_test(mean, var, dof, *reference, 15).accepted_fraction
    return image_mean_z(passes, reference), accepted


@pytest.mark.slow
@pytest.mark.parametrize("distance", FAR)
def test_far_speck_sweep_against_the_reference(distance):
    """The issue's sweep, measured as it was reported: against the Cornell reference."""
    z, accepted = render_against_reference(compile_scene(cornell_and_far_speck(distance)))
    assert np.all(np.abs(z) < 4.0), z
    assert accepted >= 0.99


def test_two_detailed_clusters_a_million_apart_both_render_right():
    """Two Cornell boxes 1e6 apart, all static: each is its own cluster, and the far one seen
    by the camera moved with it matches the reference as the near one does."""
    scene = compile_scene(cornell_and_far_speck(None, copy_at=1e6))
    assert scene.static_clusters == 2
    for shift in (0.0, 1e6):
        camera = override(
            scene.camera,
            position=tuple(np.add(scene.camera.position, (shift, 0.0, 0.0))),
            look_at=tuple(np.add(scene.camera.look_at, (shift, 0.0, 0.0))),
        )
        z, accepted = render_against_reference(scene, camera)
        assert np.all(np.abs(z) < 4.0), (shift, z)
        assert accepted >= 0.99, shift
