"""The effect plan (``tracer.integrators.effects``): its rules on small scenes, the user's
switches, and the proof that it is free of error: for every sample scene the plan's image agrees
with the all-effects image (bit for bit at the same seed, and by a Z-test at independent seeds),
and in a scene that needs an effect, dropping it changes the image (so the plan must keep it)."""

import numpy as np
import pytest

from cli.commands.samples import REPO_SCENES, sample_scene_files
from tests.helpers import compile_dict, tiny_scene
from tests.stats import pass_statistics, welch_pixel_test
from tracer.compiled.scene import compile_scene
from tracer.integrators.effects import EffectPlan, effect_plan, needed_effects
from tracer.integrators.flags import ALL, EFFECTS, LIGHT_TREE, MATERIAL_EFFECTS, SUN
from tracer.render import render_image
from tracer.scene.format import override
from tracer.scene.loader import load_scene

SAMPLE_SCENES = sample_scene_files(REPO_SCENES)
SIZE = (48, 32)
PASSES = 8
SPP = 4


def names(plan: EffectPlan) -> set[str]:
    return set(plan.names())


def test_rules_on_the_tiny_scene():
    """A diffuse box under an area light: area lights, light samples, shadows, indirect light
    and emitter hits; nothing else."""
    scene = compile_dict(tiny_scene(render={"max_depth": 4}))
    plan = needed_effects(scene, scene.render)
    assert names(plan) == {"area_lights", "light_samples", "shadows", "indirect", "emitter_hits"}
    assert plan.reasons["sky"] == "the sky is black"


@pytest.mark.parametrize(
    "change, effect, needed",
    [
        ({"sky": {"radiance": [0.2, 0.2, 0.2]}}, "sky", True),
        ({"sky": {"type": "gradient", "zenith": [0, 0, 0], "horizon": [0, 0, 0]}}, "sky", False),
        ({"lights": [{"type": "point", "position": [0, 2, 0], "intensity": [1, 1, 1]}]},
         "point_lights", True),
        ({"lights": [{"type": "point", "position": [0, 2, 0], "intensity": [0, 0, 0]}]},
         "point_lights", False),
        ({"lights": [{"type": "sun", "to_sun": [0, 1, 0], "irradiance": [1, 1, 1]}]}, "sun", True),
        ({"materials": {"grey": {"type": "dielectric"}, "lamp": {"emission": [1, 1, 1]}}},
         "refraction", True),
        ({"materials": {"grey": {"type": "dielectric", "absorption": [1, 0, 0]},
                        "lamp": {"emission": [1, 1, 1]}}}, "absorption", True),
        ({"materials": {"grey": {"type": "dielectric"}, "lamp": {"emission": [1, 1, 1]}}},
         "absorption", False),
        ({"materials": {"grey": {"type": "mirror"}, "lamp": {"emission": [1, 1, 1]}}},
         "specular", True),
        ({"materials": {"grey": {"type": "conductor"}, "lamp": {"emission": [1, 1, 1]}}},
         "specular", True),
        ({"materials": {"grey": {"type": "conductor", "roughness": 0.5},
                        "lamp": {"emission": [1, 1, 1]}}}, "glossy", True),
        ({"materials": {"grey": {"type": "plastic"}, "lamp": {"emission": [1, 1, 1]}}},
         "glossy", True),
        ({"render": {"max_depth": 2}}, "indirect", False),
        ({"render": {"integrator": "direct"}}, "indirect", False),
        ({"render": {"integrator": "ao"}}, "light_samples", False),
        ({"materials": {"grey": {"reflectance": [0, 0, 0]},
                        "lamp": {"reflectance": [0, 0, 0], "emission": [1, 1, 1]}}},
         "indirect", False),
        ({"materials": {"grey": {}, "lamp": {"emission": [0, 0, 0]}}}, "light_samples", False),
    ],
)  # fmt: skip
def test_each_rule(change, effect, needed):
    """Each rule decides its effect from what the scene contains."""
    scene = compile_dict(tiny_scene(**change))
    settings = scene.render
    assert (effect in names(needed_effects(scene, settings))) == needed


def test_only_point_lights_skip_the_last_ray():
    """With only point lights nothing a ray can hit emits: the plan drops emitter hits (the
    last vertex's continuation ray), and the image stays bit-identical."""
    data = tiny_scene(
        materials={"grey": {"reflectance": [0.7, 0.7, 0.7]}, "lamp": {"emission": [0, 0, 0]}},
        lights=[{"type": "point", "position": [0.5, 2.5, 0.5], "intensity": [5, 5, 5]}],
        render={"spp": 4, "max_depth": 3, "rr_depth": 8},
    )
    scene = compile_dict(data)
    plan = effect_plan(scene, scene.render)
    assert "emitter_hits" not in names(plan)
    planned, cost_plan = render_image(scene)
    full, cost_full = render_image(scene, plan=EffectPlan(ALL, {}))
    assert planned.tobytes() == full.tobytes()
    assert cost_plan.sum() < cost_full.sum()


def test_user_switches():
    """render.effects switches effects off on purpose, whatever the scene needs; effect_plan
    false runs every effect except those."""
    data = tiny_scene(render={"effects": {"shadows": False, "indirect": False}})
    scene = compile_dict(data)
    plan = effect_plan(scene, scene.render)
    assert not {"shadows", "indirect"} & names(plan)
    assert plan.reasons["shadows"] == "switched off in render.effects"
    every = effect_plan(scene, override(scene.render, effect_plan=False))
    assert names(every) == set(EFFECTS) - {"shadows", "indirect"}
    with pytest.raises(ValueError, match="only be switched off"):
        override(scene.render, effects={"sky": True})
    with pytest.raises(ValueError):
        override(scene.render, effects={"specular": False})  # not a switchable effect


def test_switched_off_effects_change_the_image():
    """Shadows off brightens the floor under the box; area lights off leaves only black."""
    scene = compile_dict(tiny_scene(render={"spp": 4, "max_depth": 3}))
    base, _ = render_image(scene)
    no_shadows, _ = render_image(scene, settings=override(scene.render, effects={"shadows": False}))
    assert no_shadows.mean() > 1.02 * base.mean()
    dark, _ = render_image(scene, settings=override(scene.render, effects={"area_lights": False}))
    assert dark.max() == 0.0


def test_a_switched_off_sky_is_black_and_unsampled():
    """The sky switched off: rays that escape see nothing and light samples never pick it."""
    data = tiny_scene(
        sky={"radiance": [1.0, 1.0, 1.0]},
        materials={"grey": {"reflectance": [0.5, 0.5, 0.5]}, "lamp": {"emission": [0, 0, 0]}},
    )
    scene = compile_dict(data)
    image, _ = render_image(scene, settings=override(scene.render, effects={"sky": False}))
    assert image.max() == 0.0


def plan_and_all(scene, seed_all: int):
    """Passes of the plan's image and of the all-effects image (same sample ranges)."""
    camera = override(scene.camera, width=SIZE[0], height=SIZE[1])
    settings = override(scene.render, spp=SPP)
    plan = effect_plan(scene, settings)
    everything = EffectPlan(ALL | (plan.flags & LIGHT_TREE), {})  # the same light sampler
    planned = [
        render_image(scene, camera, settings, sample_start=k * SPP, plan=plan)[0]
        for k in range(PASSES)
    ]
    full = [
        render_image(scene, camera, override(settings, seed=seed_all), sample_start=k * SPP,
                     plan=everything)[0]
        for k in range(PASSES)
    ]  # fmt: skip
    return np.stack(planned).astype(np.float64), np.stack(full).astype(np.float64), plan


@pytest.mark.parametrize("path", SAMPLE_SCENES, ids=[p.parent.name for p in SAMPLE_SCENES])
def test_plan_image_is_the_all_effects_image(path):
    """Every sample scene: at the same seed the plan's image is the all-effects image bit for
    bit (each rule only skips work that adds zeros, and random numbers are drawn at fixed
    dimensions per vertex); at independent seeds the two agree by the image-mean Z-test and
    the Sidak-corrected per-pixel Welch test."""
    scene = compile_scene(load_scene(path))
    planned, full, plan = plan_and_all(scene, scene.render.seed)
    assert planned.tobytes() == full.tobytes(), plan.names()
    _, independent, _ = plan_and_all(scene, scene.render.seed + 1)
    k = PASSES
    mean_a = planned.reshape(k, -1, 3).mean(axis=1)
    mean_b = independent.reshape(k, -1, 3).mean(axis=1)
    se = np.sqrt(mean_a.var(axis=0, ddof=1) / k + mean_b.var(axis=0, ddof=1) / k)
    z = (mean_a.mean(axis=0) - mean_b.mean(axis=0)) / np.where(se > 0, se, 1.0)
    assert np.all(np.abs(z) < 4.0), z
    result = welch_pixel_test(*pass_statistics(planned), *pass_statistics(independent))
    assert result.accepted_fraction >= 0.99


EFFECT_SCENES = [
    ("cornell-spheres", "refraction", ["glass"]),
    ("cornell-spheres", "specular", ["mirror"]),
    ("outdoor", "sun", None),
    ("outdoor", "sky", None),
    ("outdoor", "glossy", ["gold"]),
    ("outdoor", "specular", ["chrome"]),
    ("outdoor", "refraction", ["glass"]),
    ("outdoor", "absorption", ["glass"]),
    ("outdoor", "point_lights", ["ground", "chrome", "red-plastic"]),
    ("outdoor", "area_lights", ["lantern", "stone"]),
    ("many-lights", "area_lights", None),
    ("many-lights", "glossy", ["steel", "teal-plastic"]),
    ("veach-mis", "glossy", ["plate-0", "plate-1", "plate-2", "plate-3"]),
    ("textured", "textures", ["floor-tiles", "poster.obj#poster", "crate.glb#crate"]),
    ("environment", "sky", None),
]
"""Scene, effect, and the materials whose pixels show it (None: the whole image)."""
EFFECT_SIZE = (96, 64)


def material_mask(scene, camera, materials) -> np.ndarray:
    """Pixels whose centre sees one of ``materials`` (bool (H, W))."""
    from tracer.geometry.query import scene_hits
    from tracer.shading.camera import camera_array, primary_ray

    cam = camera_array(camera.position, camera.look_at, camera.up, camera.vfov_deg,
                       camera.width, camera.height)  # fmt: skip
    rays = [
        primary_ray(cam, camera.width, camera.height, x + 0.5, y + 0.5)
        for y in range(camera.height)
        for x in range(camera.width)
    ]
    origins = np.array([o for o, _ in rays])
    directions = np.array([d for _, d in rays])
    hits = scene_hits(scene, origins, directions)
    mask = np.array([m in materials for m in hits.material])
    return mask.reshape(camera.height, camera.width)


BLOCKS = 4
"""The image is cut into BLOCKS x BLOCKS regions for the paired test."""


def paired_t(scene, camera, settings, plan_a, plan_b, mask, passes: int = 24) -> float:
    """The largest |t| over image blocks and colour channels of the mean difference (over
    ``mask``'s pixels in the block) between two plans' images, paired: each pass renders both
    plans with the same random numbers, so what the plans share cancels and only the effect's
    contribution remains. Blocks and channels catch an effect that moves light within an
    object (a mirror against a white diffuse ball has about the same mean)."""
    h, w = camera.height, camera.width
    rows = np.minimum(np.arange(h) * BLOCKS // h, BLOCKS - 1)
    cols = np.minimum(np.arange(w) * BLOCKS // w, BLOCKS - 1)
    block = rows[:, None] * BLOCKS + cols[None, :]
    n = BLOCKS * BLOCKS
    diffs = np.zeros((passes, 3 * n))
    counts = np.tile(np.bincount(block[mask], minlength=n), 3)
    for k in range(passes):
        start = k * settings.spp
        a = render_image(scene, camera, settings, sample_start=start, plan=EffectPlan(plan_a, {}))
        b = render_image(scene, camera, settings, sample_start=start, plan=EffectPlan(plan_b, {}))
        d = a[0].astype(np.float64) - b[0].astype(np.float64)
        diffs[k] = np.concatenate(
            [np.bincount(block[mask], weights=d[..., c][mask], minlength=n) for c in range(3)]
        )
    used = counts >= 4
    mean = diffs[:, used].mean(axis=0)
    se = diffs[:, used].std(axis=0, ddof=1) / np.sqrt(passes)
    t = np.where(se > 0, np.abs(mean) / np.where(se > 0, se, 1.0), np.where(mean != 0, np.inf, 0))
    return float(t.max())


@pytest.mark.parametrize("name, effect, materials", EFFECT_SCENES)
def test_a_needed_effect_is_kept_and_shows(name, effect, materials):
    """A scene that needs an effect keeps it, and the effect shows: without it (the plan minus
    that flag) the expected image changes where the effect's objects are: a paired t-test on
    24 passes finds |t| > 6 in some block and channel (p < 1e-5 at 23 degrees of freedom; the
    48 tests together stay below 1e-3). Without 'specular' or 'glossy' the material dispatch
    goes too: every surface renders as Lambertian."""
    scene = compile_scene(load_scene(REPO_SCENES / name / "scene.json"))
    camera = override(scene.camera, width=EFFECT_SIZE[0], height=EFFECT_SIZE[1])
    settings = override(scene.render, spp=8)
    plan = effect_plan(scene, settings)
    assert effect in names(plan)
    dropped = plan.flags & ~EFFECTS[effect]
    if effect in ("specular", "glossy"):
        dropped &= ~MATERIAL_EFFECTS
    if materials is None:
        mask = np.ones((camera.height, camera.width), bool)
    else:
        mask = material_mask(scene, camera, materials)
        assert mask.sum() >= 4
    t = paired_t(scene, camera, settings, plan.flags, dropped, mask)
    assert t > 6.0, t


def test_an_unneeded_effect_changes_nothing():
    """Control: dropping an effect the scene does not need leaves every pass bit-identical, so
    the paired test above measures the effect alone."""
    scene = compile_scene(load_scene(REPO_SCENES / "cornell-spheres" / "scene.json"))
    camera = override(scene.camera, width=SIZE[0], height=SIZE[1])
    settings = override(scene.render, spp=4)
    plan = effect_plan(scene, settings)
    assert "sun" not in names(plan)
    a = render_image(scene, camera, settings, plan=EffectPlan(ALL, {}))[0]
    b = render_image(scene, camera, settings, plan=EffectPlan(ALL & ~SUN, {}))[0]
    assert a.tobytes() == b.tobytes()
