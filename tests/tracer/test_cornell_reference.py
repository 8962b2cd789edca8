"""The Cornell box agrees with an independent renderer's reference (Mitsuba 3, 8192 spp).

Statistics in ``tests/stats.py`` and ``docs/tracer.md``. Our render: 16 independent passes of
16 spp (disjoint sample ranges), so our variance comes from the spread of the passes.
"""

from pathlib import Path

import numpy as np
import pytest

from tests.stats import pass_statistics, welch_pixel_test
from tracer.compiled.scene import compile_scene
from tracer.io.images import write_image
from tracer.render import render_image
from tracer.scene.format import override
from tracer.scene.loader import load_scene

SCENE_DIR = Path(__file__).resolve().parents[2] / "scenes" / "cornell-box"
REFERENCE_PASSES = 16
ALPHA = 0.01


@pytest.fixture(scope="module")
def cornell():
    return compile_scene(load_scene(SCENE_DIR / "scene.json"))


@pytest.fixture(scope="module")
def reference():
    mean = np.load(SCENE_DIR / "reference_mean.npy").astype(np.float64)
    var = np.load(SCENE_DIR / "reference_var_of_mean.npy").astype(np.float64)
    return mean, var


def render_passes(scene, passes: int, spp: int, **changes) -> np.ndarray:
    """``passes`` independent renders over disjoint sample ranges, shape (K, H, W, 3)."""
    settings = override(scene.render, spp=spp, **changes)
    return np.stack(
        [render_image(scene, settings=settings, sample_start=k * spp)[0] for k in range(passes)]
    )


def image_mean_z(passes: np.ndarray, reference) -> np.ndarray:
    """z-score per channel of the image-mean difference, using both images' standard errors."""
    ref_mean, ref_var = reference
    k = passes.shape[0]
    pass_means = passes.reshape(k, -1, 3).astype(np.float64).mean(axis=1)
    se_ours = pass_means.std(axis=0, ddof=1) / np.sqrt(k)
    se_ref = np.sqrt(ref_var.reshape(-1, 3).sum(axis=0)) / ref_var[..., 0].size
    diff = pass_means.mean(axis=0) - ref_mean.reshape(-1, 3).mean(axis=0)
    return diff / np.sqrt(se_ours**2 + se_ref**2)


@pytest.fixture(scope="module")
def ours(cornell):
    return render_passes(cornell, passes=16, spp=16)


def test_mean_radiance_within_one_percent(ours, reference):
    """Mean radiance per channel is within 1% of the reference's."""
    ratio = ours.reshape(-1, 3).mean(axis=0) / reference[0].reshape(-1, 3).mean(axis=0)
    assert np.all(np.abs(ratio - 1.0) < 0.01), ratio


def test_image_mean_is_unbiased(ours, reference):
    """The image means agree within their combined standard error (|z| < 4 per channel)."""
    z = image_mean_z(ours, reference)
    assert np.all(np.abs(z) < 4.0), z


def test_per_pixel_welch_test_accepts(ours, reference, tmp_path):
    """At least 99% of pixels pass the Sidak-corrected per-pixel test at alpha 0.01, and the
    uncorrected rejection rate stays near alpha (at most 2%)."""
    mean, var, dof = pass_statistics(ours)
    result = welch_pixel_test(mean, var, dof, *reference, REFERENCE_PASSES - 1, alpha=ALPHA)
    if result.accepted_fraction < 0.99:
        write_image(tmp_path / "ours.exr", mean.astype(np.float32))
        write_image(tmp_path / "p_values.exr", np.repeat(result.p_values[..., None], 3, axis=2))
    assert result.accepted_fraction >= 0.99, f"see {tmp_path}"
    assert result.uncorrected_rejected_fraction <= 0.02


def test_a_biased_render_is_caught(cornell, reference):
    """Negative control: one bounce fewer (max_depth 7) darkens the image by about 1%; the
    image-mean test must reject it, so the tests above can fail."""
    biased = render_passes(cornell, passes=8, spp=8, max_depth=7)
    z = image_mean_z(biased, reference)
    assert z[0] < -8.0, z
