"""Spot checks (``tracer.accuracy.spot_check``): a few pixels rendered again on sample streams of
their own, one per part. A part is exactly the pixel's render on its stream, over the sample range
asked for; the streams are not the render's nor each other's; threads change nothing; bad
pixels and sample counts are refused. The ledger plans checks within their share of the
render's samples, tops them up from wave to wave, and keeps only what was rendered."""

import numpy as np
import pytest

from tracer.accuracy.error_estimate import PARTS, SPOT_CHECK_FACTOR, SPOT_CHECK_SHARE
from tracer.accuracy.spot_check import (
    SEED_BIT,
    SpotCheckLedger,
    render_spot_checks,
    spot_check_settings,
)
from tracer.render import render_pixels
from tracer.scene.format import override

WIDTH, HEIGHT = 12, 9
PIXELS = np.array([[4, 6], [0, 0], [8, 11]])
LIT = np.array([[y, x] for y in range(3, 6) for x in range(4, 8)])
"""Pixels the Cornell box lights at this size."""


@pytest.fixture(scope="module")
def view(cornell):
    camera = override(cornell.camera, width=WIDTH, height=HEIGHT)
    return cornell, camera, override(cornell.render, seed=5)


def test_parts_are_the_pixels_render_on_their_streams(view):
    """Part k of pixel (y, x) is samples [start, start + spp) of that pixel with part k's
    seed, bit for bit, for one sample range per pixel; a pixel's work is its parts' work."""
    scene, camera, settings = view
    part_spp, part_start = np.array([4, 2, 3]), np.array([0, 5, 1])
    parts, work = render_spot_checks(
        scene, PIXELS, part_spp, part_start, camera, settings, threads=1
    )
    assert parts.shape == (PARTS, len(PIXELS), 3)
    expected_work = np.zeros(len(PIXELS), np.int64)
    for k in range(PARTS):
        stream = spot_check_settings(settings, k)
        assert stream.seed == settings.seed ^ SEED_BIT ^ (k << 58)
        for i, (y, x) in enumerate(PIXELS):
            p = y * WIDTH + x
            one = override(stream, spp=int(part_spp[i]))
            run = render_pixels(scene, p, p + 1, camera, one, 0, int(part_start[i]))
            np.testing.assert_array_equal(parts[k, i], run.rgb[0])
            expected_work[i] += run.cost[0]
    np.testing.assert_array_equal(work, expected_work)
    assert (work > 0).all()


def test_a_top_up_continues_the_samples(view):
    """Samples [0, 4) and [4, 8) of a part average to samples [0, 8) (float32 rounding)."""
    scene, camera, settings = view
    first = render_spot_checks(scene, LIT, 4, 0, camera, settings)[0]
    then = render_spot_checks(scene, LIT, 4, 4, camera, settings)[0]
    whole = render_spot_checks(scene, LIT, 8, 0, camera, settings)[0]
    np.testing.assert_allclose((first + then) / 2, whole, rtol=1e-5, atol=1e-7)


def test_the_streams_are_independent(view):
    """The render's own samples of lit pixels differ from every part's, and parts differ
    from each other."""
    scene, camera, settings = view
    checked = render_spot_checks(scene, LIT, 16, 0, camera, settings)[0]
    for i, (y, x) in enumerate(LIT):
        p = y * WIDTH + x
        own = render_pixels(scene, p, p + 1, camera, override(settings, spp=16)).rgb[0]
        assert own.sum() > 0.0 and (checked[:, i].sum(axis=1) > 0.0).all()
        for k in range(PARTS):
            assert np.abs(own - checked[k, i]).max() > 1e-4
            assert all(np.abs(checked[j, i] - checked[k, i]).max() > 1e-4 for j in range(k))


def test_threads_change_nothing(view):
    scene, camera, settings = view
    one = render_spot_checks(scene, PIXELS, 2, 0, camera, settings, threads=1)
    two = render_spot_checks(scene, PIXELS, 2, 0, camera, settings, threads=2)
    np.testing.assert_array_equal(one[0], two[0])
    np.testing.assert_array_equal(one[1], two[1])


@pytest.mark.parametrize(
    ("pixels", "spp", "start", "words"),
    [
        ([[HEIGHT, 0]], 2, 0, "in the 12x9 frame"),
        ([[0, -1]], 2, 0, "in the 12x9 frame"),
        ([[0, 0]], 0, 0, "at least one sample"),
        ([[0, 0]], 2, -1, "at least one sample"),
    ],
)
def test_bad_checks_are_refused(view, pixels, spp, start, words):
    scene, camera, settings = view
    with pytest.raises(ValueError, match=words):
        render_spot_checks(scene, np.array(pixels), spp, start, camera, settings)


def lit_parts(rng, height=32, width=32, spots=((5, 7), (20, 9), (11, 25))):
    """Four noisy part images in which part 2 alone saw each spot lit."""
    images = 0.5 + 0.01 * rng.normal(size=(PARTS, height, width, 3))
    for y, x in spots:
        images[:, y, x] = 0.0
        images[2, y, x] = 40.0
    return images


def test_the_ledger_keeps_checks_within_their_share():
    """A 32x32 frame at 4 spp may spend an eighth of 4 x 1024 samples: two pixels of 64 x 4
    samples; the most uncertain spots come first; nothing is spent before a check is added."""
    ledger = SpotCheckLedger(32 * 32)
    request = ledger.plan(lit_parts(np.random.default_rng(1)), 4)
    need = SPOT_CHECK_FACTOR * 4 // PARTS
    assert len(request.pixels) == 2 and request.samples == 2 * PARTS * need
    assert request.samples <= SPOT_CHECK_SHARE * 4 * 1024
    assert request.part_start.tolist() == [0, 0] and request.part_spp.tolist() == [need, need]
    assert ledger.spent == 0 and ledger.checks() is None  # planned, not yet rendered
    flat = np.full((PARTS, 32, 32, 3), 0.5)
    assert ledger.plan(flat, 4) is None and ledger.checks() is None


def test_the_ledger_tops_checks_up():
    """The next wave (8 spp) checks the same pixels again: only samples [64, 128) of each
    part are asked for, and the checks given to the estimate are the means of both."""
    rng = np.random.default_rng(2)
    ledger = SpotCheckLedger(32 * 32)
    images = lit_parts(rng)
    first = ledger.plan(images, 4)
    ledger.add(first, first.pixels, np.full((PARTS, 2, 3), 1.0))
    then = ledger.plan(images, 8)
    assert then.pixels.tolist() == first.pixels.tolist()
    assert then.part_start.tolist() == [64, 64] and then.part_spp.tolist() == [64, 64]
    ledger.add(then, then.pixels, np.full((PARTS, 2, 3), 3.0))
    checks = ledger.checks()
    assert checks.pixels.tolist() == first.pixels.tolist()
    np.testing.assert_allclose(checks.parts, 2.0)
    assert ledger.spent == first.samples + then.samples <= SPOT_CHECK_SHARE * 8 * 1024


def test_the_ledger_drops_what_was_not_rendered():
    """Checks that came back for one pixel only (a tracer failed): the estimate gets that one.
    Checks that do not continue a pixel's samples, or name a pixel twice, are refused and
    change nothing."""
    ledger = SpotCheckLedger(32 * 32)
    request = ledger.plan(lit_parts(np.random.default_rng(3)), 4)
    bad = type(request)(request.pixels, request.part_start + [0, 1], request.part_spp)
    with pytest.raises(ValueError, match="continue"):
        ledger.add(bad, request.pixels, np.ones((PARTS, 2, 3)))
    with pytest.raises(ValueError, match="distinct"):
        ledger.add(request, request.pixels[[0, 0]], np.ones((PARTS, 2, 3)))
    assert ledger.spent == 0 and not ledger.counts and ledger.checks() is None
    ledger.add(request, request.pixels[1:], np.ones((PARTS, 1, 3)))
    assert ledger.checks().pixels.tolist() == request.pixels[1:].tolist()


def test_the_ledger_prices_checks_by_work():
    """With the render's work given (10 per pixel sample), checks are priced at that mean
    until their own work is known: two spots at 4 spp. They turn out to cost three times the
    mean, so at 8 spp their top-ups do not fit what is left of the budget; they keep their
    older checks (the estimate still gets them). Counting samples instead, the same checks
    would be topped up."""
    images = lit_parts(np.random.default_rng(4))
    rate, pixels = 10.0, 32 * 32
    ledger = SpotCheckLedger(pixels)
    first = ledger.plan(images, 4, work=4 * pixels * rate)
    assert len(first.pixels) == 2
    costly = np.full(2, 3 * rate * first.samples / 2)
    ledger.add(first, first.pixels, np.ones((PARTS, 2, 3)), costly)
    assert ledger.spent == costly.sum()
    assert ledger.plan(images, 8, work=8 * pixels * rate) is None
    assert ledger.checks().pixels.tolist() == first.pixels.tolist()
    by_samples = SpotCheckLedger(pixels)
    request = by_samples.plan(images, 4)
    by_samples.add(request, request.pixels, np.ones((PARTS, 2, 3)))
    assert by_samples.plan(images, 8).pixels.tolist() == first.pixels.tolist()
