"""Per-pixel sample counts (adaptive sampling's kernel input): a pixel given ``n`` of a run's
``spp`` samples gets the bits of a render of ``n`` samples from the same first sample, in the
single-ray, stream and surface kernels, however the frame is split."""

from itertools import pairwise

import numpy as np
import pytest

from cli.commands.samples import REPO_SCENES
from tracer.compiled.scene import compile_scene
from tracer.render import render_pixels
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene

SPP = 4


@pytest.fixture(scope="module")
def spheres():
    """The Cornell box with a mirror and a glass sphere, small."""
    scene = compile_scene(load_scene(REPO_SCENES / "cornell-spheres" / "scene.json"))
    return scene, fmt.override(scene.camera, width=20, height=14)


def _counts(camera) -> np.ndarray:
    """Counts 1..SPP over the frame, in a pattern that no pixel block lines up with."""
    return (np.arange(camera.width * camera.height) * 7 % SPP + 1).astype(np.int32)


@pytest.mark.parametrize(
    ("integrator", "kernel"),
    [("path", "single"), ("path", "stream"), ("ao", "auto"), ("albedo", "auto")],
)
def test_a_pixel_with_n_samples_is_the_render_of_n_samples(spheres, integrator, kernel):
    scene, camera = spheres
    pixels = camera.width * camera.height
    settings = fmt.override(scene.render, spp=SPP, integrator=integrator, kernel=kernel)
    counts = _counts(camera)
    run = render_pixels(scene, 0, pixels, camera, settings, sample_start=5, counts=counts)
    assert run.rgb.max() > 0.0
    for n in range(1, SPP + 1):
        uniform = render_pixels(
            scene, 0, pixels, camera, fmt.override(settings, spp=n), sample_start=5
        )
        mine = counts == n
        assert run.rgb[mine].tobytes() == uniform.rgb[mine].tobytes()
        assert np.array_equal(run.rays[mine], uniform.rays[mine])


def test_counts_of_spp_everywhere_are_the_uniform_render(spheres):
    scene, camera = spheres
    pixels = camera.width * camera.height
    settings = fmt.override(scene.render, spp=SPP)
    full = np.full(pixels, SPP, np.int32)
    a = render_pixels(scene, 0, pixels, camera, settings, counts=full)
    b = render_pixels(scene, 0, pixels, camera, settings)
    assert a.rgb.tobytes() == b.rgb.tobytes()


def test_any_split_gives_the_same_bits(spheres):
    scene, camera = spheres
    pixels = camera.width * camera.height
    settings = fmt.override(scene.render, spp=SPP)
    counts = _counts(camera)
    whole = render_pixels(scene, 0, pixels, camera, settings, counts=counts, threads=2)
    cuts = [0, 13, 40, 41, 150, pixels]
    parts = [
        render_pixels(scene, a, b, camera, settings, counts=counts, threads=1).rgb
        for a, b in pairwise(cuts)
    ]
    assert np.concatenate(parts).tobytes() == whole.rgb.tobytes()


@pytest.mark.parametrize(
    ("counts", "message"),
    [(np.zeros(280, np.int32), "must lie in"), (np.full(280, SPP + 1), "must lie in"),
     (np.ones(10, np.int32), "for each of 280 pixels")],
)  # fmt: skip
def test_bad_counts_are_refused(spheres, counts, message):
    scene, camera = spheres
    settings = fmt.override(scene.render, spp=SPP)
    with pytest.raises(ValueError, match=message):
        render_pixels(scene, 0, 10, camera, settings, counts=counts)
