"""When the denoiser's guides are prefiltered (``tracer.post.guides``): ``auto`` resolved from
the scene's materials and lens, explicit choices kept."""

from pathlib import Path

import pytest

from tracer.post.guides import guides_are_noisy, resolve_prefilter
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene

SCENES = Path(__file__).resolve().parents[2] / "scenes"


def scene_state(name: str):
    return load_scene(str(SCENES / name / "scene.json"))


@pytest.mark.parametrize(
    ("name", "noisy"), [("cornell-box", False), ("veach-mis", False), ("textured", True)]
)
def test_textures_make_the_guides_noisy(name, noisy):
    state = scene_state(name)
    assert guides_are_noisy(state.materials.values(), state.camera) is noisy


def test_a_lens_aperture_makes_the_guides_noisy():
    state = scene_state("cornell-box")
    lens = fmt.override(state.camera, aperture_radius=0.01, focus_distance=3.0)
    assert guides_are_noisy(state.materials.values(), lens)


@pytest.mark.parametrize(("name", "resolved"), [("cornell-box", "off"), ("textured", "on")])
def test_auto_is_resolved_and_explicit_choices_are_kept(name, resolved):
    state = scene_state(name)
    materials, camera = state.materials.values(), state.camera
    settings = fmt.override(state.render, denoise="fast")
    assert settings.denoise_prefilter == "auto"
    assert resolve_prefilter(settings, materials, camera).denoise_prefilter == resolved
    for choice in ("on", "off"):
        explicit = fmt.override(settings, denoise_prefilter=choice)
        assert resolve_prefilter(explicit, materials, camera) is explicit
