"""Spot checks (``tracer.spot_check``): a few pixels rendered again with many more samples on
a sample stream of their own. Their parts are exactly the pixel's render on that stream, cut
into disjoint sample ranges; the stream is not the render's; threads change nothing; bad
pixels and sample counts are refused."""

import numpy as np
import pytest

from tracer.error_estimate import PARTS
from tracer.render import render_pixels
from tracer.scene_format import override
from tracer.spot_check import (
    SEED_BIT,
    render_spot_checks,
    spot_check_settings,
    spot_check_spp,
)

WIDTH, HEIGHT = 12, 9
PIXELS = np.array([[4, 6], [0, 0], [8, 11]])


@pytest.fixture(scope="module")
def view(cornell):
    camera = override(cornell.camera, width=WIDTH, height=HEIGHT)
    return cornell, camera, override(cornell.render, seed=5)


def test_parts_are_the_pixels_render_on_the_checks_stream(view):
    """Part k of pixel (y, x) is samples [k * spp / 4, (k + 1) * spp / 4) of that pixel with the
    checks' seed, bit for bit; their mean is the pixel's mean over all spp samples."""
    scene, camera, settings = view
    spp = 16
    parts = render_spot_checks(scene, PIXELS, spp, camera, settings, threads=1)
    assert parts.shape == (PARTS, len(PIXELS), 3)
    stream = spot_check_settings(settings)
    assert stream.seed == settings.seed ^ SEED_BIT
    for i, (y, x) in enumerate(PIXELS):
        p = y * WIDTH + x
        for k in range(PARTS):
            one = render_pixels(
                scene, p, p + 1, camera, override(stream, spp=spp // PARTS), 0, k * spp // PARTS
            )
            np.testing.assert_array_equal(parts[k, i], one.rgb[0])
        whole = render_pixels(scene, p, p + 1, camera, override(stream, spp=spp))
        np.testing.assert_allclose(parts[:, i].mean(axis=0), whole.rgb[0], rtol=1e-5, atol=1e-7)


def test_the_checks_stream_is_not_the_renders(view):
    """The render's own samples of the same lit pixels differ (an independent stream)."""
    scene, camera, settings = view
    lit = np.array([[y, x] for y in range(3, 6) for x in range(4, 8)])
    checked = render_spot_checks(scene, lit, 64, camera, settings).mean(axis=0)
    for i, (y, x) in enumerate(lit):
        p = y * WIDTH + x
        own = render_pixels(scene, p, p + 1, camera, override(settings, spp=64)).rgb[0]
        assert own.sum() > 0.0 and checked[i].sum() > 0.0
        assert np.abs(own - checked[i]).max() > 1e-4


def test_threads_change_nothing(view):
    scene, camera, settings = view
    one = render_spot_checks(scene, PIXELS, 8, camera, settings, threads=1)
    two = render_spot_checks(scene, PIXELS, 8, camera, settings, threads=2)
    np.testing.assert_array_equal(one, two)


def test_checks_take_64_times_the_renders_samples():
    assert spot_check_spp(4) == 256
    assert spot_check_spp(1024) == 65536
    assert spot_check_spp(1) % PARTS == 0


@pytest.mark.parametrize(
    ("pixels", "spp", "words"),
    [
        ([[HEIGHT, 0]], 8, "in the 12x9 frame"),
        ([[0, -1]], 8, "in the 12x9 frame"),
        ([[0, 0]], 6, "multiple of 4"),
        ([[0, 0]], 0, "multiple of 4"),
    ],
)
def test_bad_checks_are_refused(view, pixels, spp, words):
    scene, camera, settings = view
    with pytest.raises(ValueError, match=words):
        render_spot_checks(scene, np.array(pixels), spp, camera, settings)


def test_no_pixels_no_checks(view):
    scene, camera, settings = view
    assert render_spot_checks(scene, np.zeros((0, 2), int), 8, camera, settings).shape == (
        PARTS,
        0,
        3,
    )
