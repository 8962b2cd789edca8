"""Base-colour alpha in renders (``tracer.shading.alpha``, ``tracer.geometry.alpha_traversal``):
a transparent card is no card, bit for bit; a mask cuts a card as geometry would, for camera
and shadow rays; blend transmits ``1 - alpha`` of the light behind it; splits, threads and the
stream kernel give the same bits; lean plans never compile the test; no NaN or negative value."""

import numpy as np
import pytest
from PIL import Image

from tests.helpers import write_json
from tests.stats import pass_statistics, welch_pixel_test
from tracer.compiled.scene import compile_scene
from tracer.geometry import alpha_traversal, scene_intersect
from tracer.integrators import path, stream
from tracer.integrators.effects import effect_plan
from tracer.integrators.flags import ALPHA_TEST
from tracer.render import render_image, render_lines
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene

FLOOR = {"name": "floor", "shape": {"type": "plane", "size": 4}, "material": "floor"}
LAMP = {"name": "lamp", "shape": {"type": "rectangle", "size": [1, 1]}, "material": "lamp",
        "transform": {"translate": [0, 2, 0], "rotate": [90, 0, 0]}}  # fmt: skip
ABOVE = {"position": [0.3, 3.0, 2.4], "look_at": [0, 0.4, 0], "width": 24, "height": 20,
         "vfov_deg": 50}  # fmt: skip
BELOW = {"position": [0, 0.6, 0], "look_at": [0, 0, 0], "up": [0, 0, -1], "width": 16,
         "height": 16, "vfov_deg": 50}  # fmt: skip
"""Views of the card and its shadow from above, and of the floor alone from under the card."""


def card(size=(2.0, 2.0), x: float = 0.0) -> dict:
    """A horizontal card at height 1 (between the lamp and the floor), ``u`` along +x."""
    place = {"translate": [x, 1, 0], "rotate": [-90, 0, 0]}
    shape = {"type": "rectangle", "size": list(size)}
    return {"name": "card", "shape": shape, "material": "card", "transform": place}


def card_scene(
    tmp_path, card_material: dict | None, objects=None, camera=ABOVE, materials=None, **render
):
    """The lamp over a floor with ``objects`` (default: a card of ``card_material``) and
    ``materials`` besides the card's, loaded and compiled."""
    if objects is None:
        objects = [] if card_material is None else [card()]
    scene = {
        "camera": camera,
        "render": {"spp": 4, "max_depth": 3, "seed": 7, **render},
        "materials": {
            "floor": {"reflectance": [0.8, 0.8, 0.8]},
            "lamp": {"reflectance": [0, 0, 0], "emission": [12, 12, 12], "two_sided": False},
            "card": card_material or {"reflectance": [0.5, 0.3, 0.2]},
            **(materials or {}),
        },
        "objects": [FLOOR, LAMP, *objects],
    }
    return compile_scene(load_scene(write_json(tmp_path / "scene.json", scene)))


def render(scene, **changes) -> np.ndarray:
    return render_image(scene, settings=fmt.override(scene.render, **changes))[0]


def stripe_image(tmp_path) -> str:
    """A 2x1 RGBA image: the left texel transparent, the right opaque (clamped, a mask at 0.5
    cuts at u = 0.5 exactly)."""
    image = np.array([[[90, 90, 90, 0], [90, 90, 90, 255]]], np.uint8)
    Image.fromarray(image, "RGBA").save(tmp_path / "stripe.png")
    return "stripe.png"


@pytest.mark.parametrize(
    "alpha",
    [{"mode": "mask", "value": 0.0}, {"mode": "blend", "value": 0.0},
     {"mode": "mask", "value": 0.9, "cutoff": 0.95}],
)  # fmt: skip
def test_a_transparent_card_is_no_card(tmp_path, alpha):
    """A card no ray can meet renders the very bits of the scene without it: camera rays,
    continuation rays and shadow rays pass it alike (the plan of both runs the material
    build: alpha, and every effect for the card-less scene)."""
    empty = render(card_scene(tmp_path, None), effect_plan=False)
    scene = card_scene(tmp_path, {"reflectance": [0.5, 0.3, 0.2], "alpha": alpha})
    assert effect_plan(scene, scene.render).flags & ALPHA_TEST
    assert render(scene).tobytes() == empty.tobytes()
    assert render(scene, effect_plan=False).tobytes() == empty.tobytes()


def test_alpha_switched_off_is_an_opaque_card(tmp_path):
    """``render.effects.alpha_test: false`` renders the card as if it had no alpha."""
    opaque = render(card_scene(tmp_path, {"reflectance": [0.5, 0.3, 0.2]}))
    clear = {"mode": "mask", "value": 0.0}
    scene = card_scene(tmp_path, {"reflectance": [0.5, 0.3, 0.2], "alpha": clear})
    assert render(scene, effects={"alpha_test": False}).tobytes() == opaque.tobytes()


def test_a_mask_cuts_the_card_as_geometry_would(tmp_path):
    """A 2x2 card whose mask keeps its right half (u >= 0.5) and a 1x2 card of geometry in its
    place: the same image (the card seen and its shadow on the floor) by a per-pixel Welch
    test over independent passes, and different from the whole card."""
    file = stripe_image(tmp_path)
    material = {"reflectance": [0.5, 0.3, 0.2],
                "alpha": {"mode": "mask", "texture": {"file": file, "wrap": "clamp"}}}  # fmt: skip
    masked = card_scene(tmp_path, material)
    half = card_scene(tmp_path, None, objects=[card((1.0, 2.0), x=0.5)])
    whole = card_scene(tmp_path, None, objects=[card()])

    def passes(scene, start):
        return np.stack([render(scene, spp=8, seed=start + k) for k in range(12)])

    a = pass_statistics(passes(masked, 100))
    b = pass_statistics(passes(half, 200))
    c = pass_statistics(passes(whole, 300))
    assert welch_pixel_test(*a, *b).accepted_fraction == 1.0
    assert welch_pixel_test(*a, *c).accepted_fraction < 0.9


@pytest.mark.parametrize(
    ("values", "expected", "wrong"), [([0.3], 0.7, 0.3), ([0.7], 0.3, 0.7), ([0.5, 0.5], 0.25, 0.5)]
)
def test_blend_transmits_one_minus_alpha(tmp_path, values, expected, wrong):
    """Under black blend cards of alphas ``values`` covering the lamp, the floor gets the
    product of their ``1 - alpha`` of its light (direct light, the camera under the cards):
    the per-pixel difference ``covered - expected bare`` at the same random numbers averages
    to 0 within 5 standard errors (of its spread over the pixels), and not with ``wrong`` (for
    two cards: what one decision for both would give)."""
    cards = [{**card((3.0, 3.0)), "name": f"card-{i}", "material": f"card-{i}",
              "transform": {"translate": [0, 1 + 0.2 * i, 0], "rotate": [-90, 0, 0]}}
             for i in range(len(values))]  # fmt: skip
    settings = {"camera": BELOW, "integrator": "direct", "spp": 16}
    bare = render(card_scene(tmp_path, None, **settings)).astype(np.float64)
    blends = {f"card-{i}": {"reflectance": [0, 0, 0], "alpha": {"mode": "blend", "value": v}}
              for i, v in enumerate(values)}  # fmt: skip
    scene = card_scene(tmp_path, None, objects=cards, materials=blends, **settings)
    covered = render(scene).astype(np.float64)
    assert bare.min() > 0.0
    for factor, near in ((expected, True), (wrong, False)):
        difference = (covered - factor * bare).reshape(-1, 3)
        error = difference.std(axis=0, ddof=1) / np.sqrt(difference.shape[0])
        assert (np.abs(difference.mean(axis=0)) < 5.0 * error).all() == near


def test_splits_threads_and_the_stream_kernel_agree(tmp_path):
    """A scene of a masked and a blended card: rendered whole on two threads, in line ranges
    on one, and by the stream kernel, the same bits."""
    file = stripe_image(tmp_path)
    objects = [card((1.5, 1.5), x=-0.8), {**card((1.5, 1.5), x=0.8), "material": "glass"}]
    scene = {
        "camera": {**ABOVE, "width": 20, "height": 16},
        "render": {"spp": 3, "max_depth": 4, "seed": 3},
        "materials": {
            "floor": {"reflectance": [0.8, 0.8, 0.8]},
            "lamp": {"reflectance": [0, 0, 0], "emission": [12, 12, 12], "two_sided": False},
            "card": {"reflectance": [0.5, 0.3, 0.2], "alpha": {"mode": "mask", "texture": {
                "file": file, "wrap": "repeat", "scale": [3, 1]}}},
            "glass": {"type": "plastic", "alpha": {"mode": "blend", "value": 0.4}},
        },
        "objects": [FLOOR, LAMP, *objects],
    }  # fmt: skip
    compiled = compile_scene(load_scene(write_json(tmp_path / "scene.json", scene)))
    camera, settings = compiled.camera, compiled.render
    whole = render_lines(compiled, 0, 16, camera, settings, threads=2).rgb
    parts = [render_lines(compiled, a, b, camera, settings, threads=1).rgb
             for a, b in [(0, 5), (5, 6), (6, 16)]]  # fmt: skip
    assert np.concatenate(parts).tobytes() == whole.tobytes()
    streamed = render_lines(compiled, 0, 16, camera, fmt.override(settings, kernel="stream"))
    assert streamed.rgb.tobytes() == whole.tobytes()
    assert np.isfinite(whole).all() and whole.min() >= 0.0


@pytest.mark.parametrize(
    "alpha",
    [{"mode": "mask", "cutoff": 0.0}, {"mode": "mask", "cutoff": 1.0},
     {"mode": "blend", "value": 1.0}, {"mode": "blend", "value": 1e-9},
     {"mode": "mask", "cutoff": 1e9}],
)  # fmt: skip
def test_extreme_alphas_stay_finite_and_positive(tmp_path, alpha):
    """Cut-offs at 0, 1 and beyond, blends at 1 and near 0: no NaN, infinity or negative
    value; a cutoff of 0 and a blend of 1 are the opaque card, bit for bit."""
    image = render(card_scene(tmp_path, {"reflectance": [0.5, 0.3, 0.2], "alpha": alpha}))
    assert np.isfinite(image).all() and image.min() >= 0.0
    if alpha.get("cutoff") == 0.0 or alpha.get("value") == 1.0:
        opaque = card_scene(tmp_path, {"reflectance": [0.5, 0.3, 0.2]})
        assert image.tobytes() == render(opaque, effect_plan=False).tobytes()


def test_lean_plans_never_compile_the_alpha_test(tmp_path):
    """A scene without alpha plans no alpha test and runs the lean build, whose kernels bind
    the traversals without it; a scene with alpha plans it (not for the surface outputs, which
    see every surface opaque) and runs the material build, whose kernels bind the others."""
    plain = card_scene(tmp_path, {"reflectance": [0.5, 0.3, 0.2]})
    flags = effect_plan(plain, plain.render).flags
    assert not flags & ALPHA_TEST and path.build_for(flags) == (False, False)
    cut = card_scene(tmp_path, {"reflectance": [0.5, 0.3, 0.2], "alpha": {"mode": "mask"}})
    flags = effect_plan(cut, cut.render).flags
    assert flags & ALPHA_TEST and path.build_for(flags) == (True, False)
    ao = effect_plan(cut, fmt.override(cut.render, integrator="ao"))
    assert not ao.flags & ALPHA_TEST and "opaque" in ao.reasons["alpha_test"]
    for kernels in (path.KERNELS, stream.KERNELS):
        for (materials, _), kernel in kernels.items():
            names = kernel.py_func.__globals__
            expected = alpha_traversal.traversals(materials)
            assert names["scene_closest"] is expected["scene_closest"]
            assert names["scene_occluded"] is expected["scene_occluded"]
            lean = names["scene_closest"] is scene_intersect.scene_closest
            assert lean == (not materials)
