"""Whole-image robustness: finite, non-negative radiance everywhere; no light leaks at contacts;
the same image at any scale and any distance from the origin."""

from pathlib import Path

import numpy as np
import pytest

from tests.stats import pass_statistics, welch_pixel_test
from tests.tracer.test_cornell_reference import image_mean_z
from tracer.compile import compile_scene
from tracer.loader import MeshData, SceneData, load_scene
from tracer.render import render_image
from tracer.scene_format import Camera, DiffuseMaterial, RenderSettings, override
from tracer.shapes import box, plane, rectangle

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
