"""When the denoiser's guides are prefiltered (``tracer.post.guides``): ``auto`` resolved from
the scene's materials and lens, explicit choices kept."""

from pathlib import Path

import pytest

from tracer.post.guides import noisy_guides, prefilter_argument, resolve_prefilter
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
    assert bool(noisy_guides(state.materials.values(), state.camera)) is noisy


def test_a_lens_aperture_makes_the_guides_noisy():
    state = scene_state("cornell-box")
    lens = fmt.override(state.camera, aperture_radius=0.01, focus_distance=3.0)
    assert noisy_guides(state.materials.values(), lens) == ("albedo", "normal")


def test_textures_alone_make_the_albedo_noisy_and_a_lens_both():
    textured = scene_state("textured")
    materials = list(textured.materials.values())
    assert noisy_guides(materials, textured.camera) == ("albedo",)
    lens = fmt.override(textured.camera, aperture_radius=0.05, focus_distance=3.5)
    assert noisy_guides(materials, lens) == ("albedo", "normal")
    box = scene_state("cornell-box")
    assert noisy_guides(box.materials.values(), box.camera) == ()


def test_a_normal_map_makes_both_guides_noisy():
    state = scene_state("textured")
    mapped = [
        material.model_copy(update={"normal_map": material.texture})
        for material in state.materials.values()
        if getattr(material, "texture", None) is not None
    ]
    assert mapped and noisy_guides(mapped, state.camera) == ("albedo", "normal")


def test_a_blended_surface_makes_both_guides_noisy_and_a_mask_does_not():
    state = scene_state("cornell-box")
    white = state.materials["white"]
    for mode, noisy in (("blend", ("albedo", "normal")), ("mask", ())):
        cut = white.model_copy(update={"alpha": fmt.Alpha(mode=mode, value=0.5)})
        assert noisy_guides([cut], state.camera) == noisy


@pytest.mark.parametrize(
    ("name", "lens", "resolved"),
    [("cornell-box", False, "off"), ("textured", False, "albedo"), ("textured", True, "on")],
)
def test_auto_is_resolved_and_explicit_choices_are_kept(name, lens, resolved):
    state = scene_state(name)
    materials, camera = state.materials.values(), state.camera
    if lens:
        camera = fmt.override(camera, aperture_radius=0.05, focus_distance=3.5)
    settings = fmt.override(state.render, denoise="fast")
    assert settings.denoise_prefilter == "auto"
    assert resolve_prefilter(settings, materials, camera).denoise_prefilter == resolved
    for choice in ("on", "off", "albedo"):
        explicit = fmt.override(settings, denoise_prefilter=choice)
        assert resolve_prefilter(explicit, materials, camera) is explicit


def test_each_choice_names_the_guides_to_prefilter():
    assert prefilter_argument("off") is False
    assert prefilter_argument("albedo") == ("albedo",)
    assert prefilter_argument("on") is True
    assert prefilter_argument("auto") is True  # left unresolved: as on
