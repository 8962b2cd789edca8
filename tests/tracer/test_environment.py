"""Environment-map skies: the sampling distribution against its definition and its density
(chi-square, integral over the sphere, sampled and looked-up densities equal), the image
convention, a furnace against the constant sky, NEE / BSDF / MIS agreement under a peaky map,
the variance importance sampling saves, and every bad input refused with a clear error."""

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from numba import njit
from scipy import stats

from tests.chi2 import chi2_test, integrate_pdf, level
from tests.helpers import compile_dict, mean_and_error, render_passes, tiny_scene
from tests.tracer.test_integrators import agree, passes_with_plan
from tracer.errors import SceneError
from tracer.integrators.effects import EffectPlan, effect_plan, needed_effects
from tracer.integrators.flags import LIGHT_SAMPLES, SHADOWS
from tracer.scene import format as fmt
from tracer.scene.checks import check_state
from tracer.scene.codec import decode_state, encode_state
from tracer.scene.environment import EnvironmentMap
from tracer.scene.format import override
from tracer.scene.loader import load_scene
from tracer.scene.ops import Commit, apply_commit, parse_ops
from tracer.shading import lights
from tracer.shading.environment_light import (
    environment_lookup,
    environment_sample,
    sampling_tables,
)

ROTATION = 40.0
COS_R = math.cos(math.radians(ROTATION))
SIN_R = math.sin(math.radians(ROTATION))


@njit
def sample_many(image, rows, cols, cos_r, sin_r, u):
    n = u.shape[0]
    wi = np.empty((n, 3))
    radiance = np.empty((n, 3))
    pdf = np.empty(n)
    for k in range(n):
        d, L, p = environment_sample(image, rows, cols, cos_r, sin_r, u[k, 0], u[k, 1])
        for c in range(3):
            wi[k, c] = d[c]
            radiance[k, c] = L[c]
        pdf[k] = p
    return wi, radiance, pdf


@njit
def lookup_many(image, rows, cols, cos_r, sin_r, d):
    n = d.shape[0]
    radiance = np.empty((n, 3))
    pdf = np.empty(n)
    for k in range(n):
        L, p = environment_lookup(image, rows, cols, cos_r, sin_r, (d[k, 0], d[k, 1], d[k, 2]))
        for c in range(3):
            radiance[k, c] = L[c]
        pdf[k] = p
    return radiance, pdf


def moderate_map(h=8, w=16, seed=1) -> np.ndarray:
    """Pixels between 0.2 and 1.2 (no sharp peaks: the chi-square harness's cell integrals
    are exact enough)."""
    return (0.2 + np.random.default_rng(seed).random((h, w, 3))).astype(np.float32)


def peaky_map(h=32, w=64) -> np.ndarray:
    """A dim sky with a 4 x 4 pixel "sun" above the horizon carrying most of the power."""
    rng = np.random.default_rng(7)
    image = 0.05 + 0.1 * rng.random((h, w, 3))
    image[9:13, 40:44] = [400.0, 360.0, 300.0]
    return image.astype(np.float32)


def map_pixels(d: np.ndarray, h: int, w: int, rotation_deg: float) -> tuple[np.ndarray, ...]:
    """Pixel (row, column) of world directions, by the convention of docs/scene-format.md
    (written out independently of the kernels)."""
    a = math.radians(rotation_deg)
    # World = R_y(a) map, so map = R_y(-a) world.
    mx = math.cos(a) * d[:, 0] - math.sin(a) * d[:, 2]
    mz = math.sin(a) * d[:, 0] + math.cos(a) * d[:, 2]
    theta = np.arccos(np.clip(d[:, 1], -1.0, 1.0))
    phi = np.arctan2(mx, -mz)
    v = theta / math.pi
    u = phi / (2.0 * math.pi) + 0.5
    return np.minimum((v * h).astype(int), h - 1), np.minimum((u * w).astype(int), w - 1)


def pixel_probabilities(image: np.ndarray) -> np.ndarray:
    """P(pixel) by definition: luminance times sin(theta) at the row's centre, normalised."""
    h = image.shape[0]
    lum = image.astype(np.float64) @ np.array([0.2126, 0.7152, 0.0722])
    weight = lum * np.sin(math.pi * (np.arange(h) + 0.5) / h)[:, None]
    return weight / weight.sum()


# --- the distribution -----------------------------------------------------------------------


def test_sampled_directions_follow_the_pdf():
    """Chi-square (Mitsuba's harness: equal-solid-angle cells about z, the claimed density
    integrated per cell) of importance-sampled directions of a rotated map; the density
    integrates to 1 over the sphere."""
    t = sampling_tables(moderate_map())
    n = 200_000
    u = np.random.default_rng(11).random((n, 2))
    wi, _, pdf = sample_many(t.image, t.rows, t.cols, COS_R, SIN_R, u)
    assert (pdf > 0.0).all()

    def density(d):
        return lookup_many(t.image, t.rows, t.cols, COS_R, SIN_R, np.ascontiguousarray(d))[1]

    result = chi2_test(wi, density, n)
    assert result.p_value > level(0.01, 1), result.table()
    assert abs(result.pdf_integral - 1.0) < 2e-3


def test_a_wrong_pdf_is_caught():
    """Negative control: the same samples against a density 10% too large in the upper
    hemisphere (renormalised) fail the chi-square test."""
    t = sampling_tables(moderate_map())
    n = 200_000
    u = np.random.default_rng(11).random((n, 2))
    wi, _, _ = sample_many(t.image, t.rows, t.cols, COS_R, SIN_R, u)

    def wrong(d):
        p = lookup_many(t.image, t.rows, t.cols, COS_R, SIN_R, np.ascontiguousarray(d))[1]
        return p * np.where(d[:, 1] > 0.0, 1.1, 0.9)

    assert chi2_test(wi, wrong, n).p_value < level(0.01, 1)


def test_pixels_are_chosen_by_luminance_times_sin_theta():
    """Under a peaky map the sampled directions fall in each pixel as often as its luminance
    times sin(theta) says (chi-square over pixels, small cells pooled); pixel positions come
    from the documented convention, computed independently of the kernels."""
    image = peaky_map()
    h, w, _ = image.shape
    t = sampling_tables(image)
    n = 400_000
    u = np.random.default_rng(5).random((n, 2))
    wi, _, _ = sample_many(t.image, t.rows, t.cols, COS_R, SIN_R, u)
    rows, cols = map_pixels(wi, h, w, ROTATION)
    observed = np.bincount(rows * w + cols, minlength=h * w).astype(float)
    expected = n * pixel_probabilities(image).ravel()
    small = expected < 5.0
    obs = np.append(observed[~small], observed[small].sum())
    exp = np.append(expected[~small], expected[small].sum())
    p = stats.chisquare(obs, exp).pvalue
    assert p > 0.01, p
    assert observed.reshape(h, w)[9:13, 40:44].sum() > n / 2  # the sun takes most samples


def test_the_density_integrates_to_one_under_a_peaky_map():
    """Cell integrals of the looked-up density over the whole sphere sum to 1 (midpoint rule on
    a fine grid about z, not aligned with the pixels; the peak's edges cost some accuracy)."""
    t = sampling_tables(peaky_map())

    def density(d):
        return lookup_many(t.image, t.rows, t.cols, COS_R, SIN_R, np.ascontiguousarray(d))[1]

    total = integrate_pdf(density, 64, 128, sub=16).sum()
    assert abs(total - 1.0) < 5e-3, total


def test_sampled_density_is_the_looked_up_density():
    """For every sampled direction, the escape lookup finds the same radiance and the same
    density as the sample reported (what MIS needs), and a unit direction."""
    t = sampling_tables(peaky_map())
    u = np.random.default_rng(3).random((50_000, 2))
    wi, radiance, pdf = sample_many(t.image, t.rows, t.cols, COS_R, SIN_R, u)
    np.testing.assert_allclose(np.linalg.norm(wi, axis=1), 1.0, rtol=1e-12)
    looked_up, pdf_lookup = lookup_many(t.image, t.rows, t.cols, COS_R, SIN_R, wi)
    same = np.isclose(pdf, pdf_lookup, rtol=1e-9, atol=0.0)
    # Only a direction on a pixel's edge may round into its neighbour.
    assert same.mean() > 0.9999, np.flatnonzero(~same)[:5]
    np.testing.assert_array_equal(radiance[same], looked_up[same])


def test_uniform_tables_are_close_to_uniform_on_the_sphere():
    """``by_luminance=False`` weights pixels by sin(theta) at their row's centre only: the
    density is ``H sin(theta_row) / (sum of sin(theta_row)) / (2 pi^2 sin(theta))``, within 5%
    of uniform (1 / (4 pi)) in the band |y| < 0.6 of a 32-row map."""
    h = 32
    t = sampling_tables(peaky_map(h, 64), by_luminance=False)
    rng = np.random.default_rng(2)
    d = rng.normal(size=(2000, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    _, pdf = lookup_many(t.image, t.rows, t.cols, 1.0, 0.0, d)
    theta = np.arccos(d[:, 1])
    sin_rows = np.sin(math.pi * (np.arange(h) + 0.5) / h)
    row = np.minimum((theta / math.pi * h).astype(int), h - 1)
    expected = h * sin_rows[row] / sin_rows.sum() / (2.0 * math.pi**2 * np.sin(theta))
    np.testing.assert_allclose(pdf, expected, rtol=1e-9)
    band = np.abs(d[:, 1]) < 0.6
    np.testing.assert_allclose(pdf[band], 1.0 / (4.0 * math.pi), rtol=0.05)


def test_image_convention():
    """The image centre looks along -z, u = 3/4 along +x, u = 1/4 along -x; the top row looks up
    and the bottom row down; rotation turns the map counter-clockwise seen from above."""
    image = np.arange(9 * 3, dtype=np.float32).reshape(3, 3, 3)  # each pixel its own colour
    t = sampling_tables(image)

    def pixel_seen(d, rotation=0.0):
        a = math.radians(rotation)
        L, _ = environment_lookup(t.image, t.rows, t.cols, math.cos(a), math.sin(a), d)
        flat = np.flatnonzero((image == np.array(L, np.float32)).all(axis=2))
        return divmod(int(flat[0]), 3)

    assert pixel_seen((0.0, 0.0, -1.0)) == (1, 1)
    assert pixel_seen((1.0, 0.0, 0.0)) == (1, 2)
    assert pixel_seen((-1.0, 0.0, 0.0)) == (1, 0)
    assert pixel_seen((0.0, 1.0, 0.0))[0] == 0
    assert pixel_seen((0.0, -1.0, 0.0))[0] == 2
    # Turned 90 degrees counter-clockwise (from above): the centre moves from -z to -x, and
    # what was seen along +x (u = 3/4) is now seen along -z.
    assert pixel_seen((-1.0, 0.0, 0.0), rotation=90.0) == (1, 1)
    assert pixel_seen((0.0, 0.0, -1.0), rotation=90.0) == (1, 2)
    assert pixel_seen((0.0, 0.0, 1.0), rotation=90.0) == (1, 0)


def test_selection_weight_and_mean():
    """The sky's selection weight is 4 pi R^2 times its mean radiance over the sphere: for a
    constant map, the constant times the scale."""
    image = np.full((6, 12, 3), [0.5, 1.0, 1.5], np.float32)
    sky = EnvironmentMap(fmt.EnvironmentSky(type="environment", file="x.npy", scale=2.0), image)
    np.testing.assert_allclose(sky.mean_radiance(), [1.0, 2.0, 3.0], rtol=1e-12)
    table = lights.build_light_table([], np.zeros((0, 3), np.float32), (), sky, np.zeros(3), 2.0)
    np.testing.assert_allclose(table.weight, [4.0 * math.pi * 4.0 * 2.0])
    assert table.sky[lights.SKY_TYPE] == lights.SKY_ENVIRONMENT
    np.testing.assert_array_equal(table.sky_tables.image, image * 2.0)


# --- rendering ------------------------------------------------------------------------------


def write_map(directory, image, name="sky.npy"):
    np.save(directory / name, image)
    return name


def sphere_scene(directory, sky, ground=False, material=None, size=16, **render):
    """A unit ball (albedo 0.5 unless ``material``) alone, seen against the sky; or on a ground
    plane, seen from above so that every pixel shows the ball or the ground (the sky seen
    directly is the same number for every estimator, and only blurs the tests' statistics)."""
    objects = [{"shape": {"type": "sphere", "subdivisions": 3}, "material": "ball"}]
    position, look_at = [0.0, 1.5, 4.5], [0.0, 0.0, 0.0]
    if ground:
        objects[0]["transform"] = {"translate": [0.0, 1.0, 0.0]}
        objects.append({"shape": {"type": "plane", "size": 20.0}, "material": "ground"})
        position, look_at = [0.0, 3.5, 3.5], [0.0, 0.6, 0.0]
    data = {
        "camera": {"position": position, "look_at": look_at, "vfov_deg": 45.0,
                   "width": size, "height": size},
        "render": {"spp": 8, "max_depth": 8, "seed": 3, **render},
        "sky": sky,
        "materials": {"ball": material or {"reflectance": [0.5, 0.5, 0.5]},
                      "ground": {"reflectance": [0.6, 0.6, 0.6]}},
        "objects": objects,
    }  # fmt: skip
    return compile_dict(data, directory)


def test_furnace_constant_map_equals_constant_sky(tmp_path):
    """A diffuse sphere (albedo 0.5) under a map of constant radiance (rotated, importance
    sampled: its density is not uniform) renders like it does under a constant sky: the two
    agree statistically, and on the sphere both show albedo times radiance."""
    radiance = 0.7
    name = write_map(tmp_path, np.full((8, 16, 3), radiance, np.float32))
    env = sphere_scene(tmp_path, {"type": "environment", "file": name, "rotation": 30.0})
    const = sphere_scene(tmp_path, {"radiance": [radiance] * 3}, seed=4)
    a = render_passes(env, 12, 8)
    b = render_passes(const, 12, 8)
    agree(a, b)
    centre = a[:, 6:10, 6:10].reshape(12, -1, 3).mean(axis=1)  # pixels on the sphere
    mean = centre.mean(axis=0)
    se = centre.std(axis=0, ddof=1) / math.sqrt(12)
    assert np.all(np.abs(mean - 0.5 * radiance) < 4.0 * se + 1e-6), (mean, se)


def test_furnace_is_sensitive(tmp_path):
    """Negative control: the map at 3% more radiance is told apart from the constant sky."""
    name = write_map(tmp_path, np.full((8, 16, 3), 0.7 * 1.03, np.float32))
    env = sphere_scene(tmp_path, {"type": "environment", "file": name})
    const = sphere_scene(tmp_path, {"radiance": [0.7] * 3}, seed=4)
    with pytest.raises(AssertionError):
        agree(render_passes(env, 12, 8), render_passes(const, 12, 8))


@pytest.fixture(scope="module")
def peaky_scene(tmp_path_factory):
    """A diffuse ball on a diffuse ground under the rotated peaky map, direct light only."""
    directory = tmp_path_factory.mktemp("peaky")
    name = write_map(directory, peaky_map())
    sky = {"type": "environment", "file": name, "rotation": ROTATION}
    return sphere_scene(directory, sky, ground=True, max_depth=2)


@pytest.mark.parametrize("material", [None, {"type": "plastic", "roughness": 0.3}])
def test_nee_bsdf_and_mis_agree_under_a_peaky_map(tmp_path, material):
    """Direct light from a peaky map three ways: light samples only (Whitted on non-delta
    surfaces), BSDF samples only (no light samples) and both with MIS; for a Lambertian and
    a glossy (plastic) ball on a Lambertian ground."""
    name = write_map(tmp_path, peaky_map())
    sky = {"type": "environment", "file": name, "rotation": ROTATION}
    scene = sphere_scene(tmp_path, sky, ground=True, material=material, max_depth=2)
    settings = override(scene.render, max_depth=2)
    mis = render_passes(scene, 12, 16, max_depth=2)
    # Light samples only: most go to the sun, and are wasted where it is below a surface's
    # horizon (the back of the ball), so they take more samples per pass.
    nee = render_passes(scene, 12, 256, integrator="whitted", seed=5)
    plan = effect_plan(scene, settings)
    bsdf_only = EffectPlan(plan.flags & ~(LIGHT_SAMPLES | SHADOWS), {})
    bsdf = passes_with_plan(scene, scene.camera, override(settings, seed=6), bsdf_only, 12, 1024)
    agree(mis, nee)
    agree(mis, bsdf)


def uniform_tables_scene(scene):
    """The compiled scene with its map's sampling tables weighting pixels by sin(theta) only
    (near-uniform sampling of the sphere), everything else the same."""
    sky = scene.state.sky
    table = scene.lights._replace(
        sky_tables=sampling_tables(sky.image, sky.model.scale, by_luminance=False)
    )
    arrays = scene.arrays._replace(**lights.scene_fields(lights.light_arrays(table)))
    return dataclasses.replace(scene, lights=table, arrays=arrays)


def test_importance_sampling_reduces_variance(peaky_scene):
    """At equal samples, importance-sampled light samples of the peaky map give a per-pixel
    variance several times smaller than near-uniform ones (measured over independent passes),
    and both estimate the same image (image means within 4 standard errors: the near-uniform
    passes are too skewed, rarely finding the sun, for a per-pixel test)."""
    uniform = uniform_tables_scene(peaky_scene)
    a = render_passes(peaky_scene, 16, 16)
    b = render_passes(uniform, 16, 16, seed=9)
    mean_a, se_a = mean_and_error(a)
    mean_b, se_b = mean_and_error(b)
    assert np.all(np.abs(mean_a - mean_b) < 4.0 * np.sqrt(se_a**2 + se_b**2)), (mean_a, mean_b)
    ratio = b.var(axis=0, ddof=1).mean() / a.var(axis=0, ddof=1).mean()
    assert ratio > 20.0, ratio


# --- the effect plan ------------------------------------------------------------------------


def test_the_plan_needs_the_sky_only_when_the_map_emits(tmp_path):
    """An environment map is the sky effect; an all-black map or scale 0 is a black sky."""
    name = write_map(tmp_path, peaky_map())
    black = write_map(tmp_path, np.zeros((4, 8, 3), np.float32), "black.npy")
    for sky, needed in [
        ({"type": "environment", "file": name}, True),
        ({"type": "environment", "file": black}, False),
        ({"type": "environment", "file": name, "scale": 0.0}, False),
    ]:
        scene = compile_dict(tiny_scene(sky=sky), tmp_path)
        plan = needed_effects(scene, scene.render)
        assert ("sky" in plan.names()) == needed, sky


# --- files, states and bad input ------------------------------------------------------------


def scene_file(directory: Path, sky: dict) -> Path:
    path = directory / "scene.json"
    path.write_text(json.dumps(tiny_scene(sky=sky)), encoding="utf-8")
    return path


@pytest.mark.parametrize("channels", ["RGB", "RGBA-half"])
def test_exr_maps_are_read(tmp_path, channels):
    """An OpenEXR map (float or half, with or without alpha) loads with its R, G, B values."""
    image = peaky_map(4, 8)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if channels == "RGB":
        pixels = {"RGB": image}
        expected = image
    else:
        half = image.astype(np.float16)
        pixels = {c: np.ascontiguousarray(half[..., i]) for i, c in enumerate("RGB")}
        pixels["A"] = np.ones(half.shape[:2], np.float16)
        expected = half.astype(np.float32)
    OpenEXR.File(header, pixels).write(str(tmp_path / "sky.exr"))
    state = load_scene(scene_file(tmp_path, {"type": "environment", "file": "sky.exr"}))
    assert isinstance(state.sky, EnvironmentMap)
    np.testing.assert_array_equal(state.sky.image, expected)
    assert state.sky.image.dtype == np.float32 and not state.sky.image.flags.writeable


def test_snapshots_carry_the_image(tmp_path):
    """A state with a map survives the snapshot codec exactly; a snapshot whose map lost its
    image is refused."""
    write_map(tmp_path, peaky_map(4, 8))
    sky = {"type": "environment", "file": "sky.npy", "scale": 2.5, "rotation": 10.0}
    state = load_scene(scene_file(tmp_path, sky))
    back = decode_state(encode_state(state))
    assert back.sky.model == state.sky.model
    assert back.sky.image.tobytes() == state.sky.image.tobytes()
    check_state(back)
    bare = dataclasses.replace(state, sky=state.sky.model)
    with pytest.raises(SceneError, match="environment"):
        check_state(bare)


def test_set_sky_refuses_an_environment_map():
    with pytest.raises(SceneError, match="scene file"):
        parse_ops([{"op": "set_sky", "sky": {"type": "environment", "file": "sky.exr"}}])


def test_set_sky_replaces_a_map(tmp_path):
    write_map(tmp_path, peaky_map(4, 8))
    state = load_scene(scene_file(tmp_path, {"type": "environment", "file": "sky.npy"}))
    new = apply_commit(state, Commit(1, parse_ops([{"op": "set_sky", "radiance": [1, 1, 1]}])))
    assert new.sky == fmt.ConstantSky(radiance=(1.0, 1.0, 1.0))


BAD_MAPS = {
    "missing file": ("nope.npy", None, "no such file"),
    "escapes the directory": ("../outside.npy", None, "may not leave"),
    "absolute path": ("/etc/passwd", None, "relative to the scene file"),
    "unknown type": ("sky.png", b"\x89PNG", "unknown environment map type '.png'"),
    "wrong channels": ("sky.npy", np.zeros((4, 8, 4), np.float32), "(H, W, 3)"),
    "two dimensions": ("sky.npy", np.zeros((4, 8), np.float32), "(H, W, 3)"),
    "empty": ("sky.npy", np.zeros((0, 8, 3), np.float32), "(H, W, 3)"),
    "integers": ("sky.npy", np.zeros((4, 8, 3), np.int32), "floats"),
    "negative": ("sky.npy", -np.ones((4, 8, 3), np.float32), "negative"),
    "nan": ("sky.npy", np.full((4, 8, 3), np.nan, np.float32), "NaN"),
    "overflows float32": ("sky.npy", np.full((4, 8, 3), 1e39), "infinite"),
    "not npy": ("sky.npy", b"not an array", "not a NumPy array file"),
    "not exr": ("sky.exr", b"garbage", "cannot read OpenEXR"),
    "exr without RGB": ("sky.exr", "Y", "no R, G, B channel"),
}


@pytest.mark.parametrize("case", list(BAD_MAPS))
def test_bad_maps_are_refused(tmp_path, case):
    """Every bad map is a SceneError naming the sky and the problem."""
    name, content, words = BAD_MAPS[case]
    inner = tmp_path / "inner"
    inner.mkdir()
    np.save(tmp_path / "outside.npy", np.ones((2, 4, 3), np.float32))
    if isinstance(content, np.ndarray):
        np.save(inner / name, content)
    elif isinstance(content, bytes):
        (inner / name).write_bytes(content)
    elif content == "Y":
        header = {"type": OpenEXR.scanlineimage}
        OpenEXR.File(header, {"Y": np.ones((4, 8), np.float32)}).write(str(inner / name))
    with pytest.raises(SceneError) as error:
        load_scene(scene_file(inner, {"type": "environment", "file": name}))
    message = str(error.value)
    assert "sky" in message and words in message, message


def test_a_too_large_map_is_refused_before_reading(tmp_path, monkeypatch):
    from tracer import config

    monkeypatch.setattr(config, "MAX_ENVIRONMENT_PIXELS", 16)
    write_map(tmp_path, np.ones((4, 8, 3), np.float32))
    with pytest.raises(SceneError, match="too large"):
        load_scene(scene_file(tmp_path, {"type": "environment", "file": "sky.npy"}))


@pytest.mark.parametrize(
    "sky, words",
    [
        ({"type": "environment"}, "file"),
        ({"type": "environment", "file": "sky.npy", "scale": -1.0}, "scale"),
        ({"type": "environment", "file": "sky.npy", "gain": 1.0}, "unknown key"),
        ({"type": "panorama", "file": "sky.npy"}, "environment"),
    ],
)
def test_bad_environment_models_are_refused(tmp_path, sky, words):
    with pytest.raises(SceneError, match=words):
        load_scene(scene_file(tmp_path, sky))


@pytest.mark.parametrize("rotation", [0.0, 70.0])
def test_the_map_is_seen_where_rays_escape(tmp_path, rotation):
    """A camera with a 2-degree view toward the centre of map pixel (1, 6), turned with the
    map, sees exactly that pixel's radiance times the scale."""
    image = np.arange(4 * 8 * 3, dtype=np.float32).reshape(4, 8, 3) + 1.0
    name = write_map(tmp_path, image)
    theta, phi = math.pi * 1.5 / 4, 2.0 * math.pi * (6.5 / 8 - 0.5)
    d = np.array([math.sin(theta) * math.sin(phi), math.cos(theta),
                  -math.sin(theta) * math.cos(phi)])  # fmt: skip
    a = math.radians(rotation)
    d = np.array([math.cos(a) * d[0] + math.sin(a) * d[2], d[1],
                  -math.sin(a) * d[0] + math.cos(a) * d[2]])  # fmt: skip
    scene = compile_dict(
        {
            "camera": {"position": [0, 0, 0], "look_at": list(d), "vfov_deg": 2.0,
                       "width": 4, "height": 4},
            "render": {"spp": 4},
            "sky": {"type": "environment", "file": name, "rotation": rotation, "scale": 0.5},
            "materials": {"ground": {}},
            "objects": [{"shape": {"type": "plane", "size": 1.0}, "material": "ground",
                         "transform": {"translate": [0, -50, 0]}}],
        },
        tmp_path,
    )  # fmt: skip
    seen = render_passes(scene, 1, 4)[0]
    np.testing.assert_array_equal(seen, np.broadcast_to(0.5 * image[1, 6], seen.shape))
