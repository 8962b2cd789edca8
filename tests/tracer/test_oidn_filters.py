"""Reusing OIDN filters across calls (``tracer.post.oidn_filters``): the cache's bookkeeping on a
stand-in for pyoidn, and, on the real one, that a reused filter gives a new filter's bits."""

from types import SimpleNamespace

import numpy as np

from tracer.post.oidn_filters import MAX_PIXELS, FilterCache


class FakeFilter:
    def __init__(self, log: list, device: "FakeDevice", _type: str) -> None:
        self.log, self.device, self.images, self.options = log, device, {}, {}
        log.append(("new", self))

    def set_image(self, name, image, _format):
        self.images[name] = image

    def set_quality(self, value):
        self.options["quality"] = value

    def set_bool(self, name, value):
        self.options[name] = value

    def commit(self):
        pass

    def execute(self):
        self.log.append(("execute", self))
        if self.device.fail:
            self.device.error = "boom"

    def release(self):
        self.log.append(("release", self))


class FakeDevice:
    fail = False
    error = None

    def get_error(self):
        error, self.error = self.error, None
        return error


def fake_cache(size: int) -> tuple[FilterCache, list, FakeDevice]:
    log: list = []
    device = FakeDevice()
    pyoidn = SimpleNamespace(
        Filter=lambda dev, kind: FakeFilter(log, dev, kind),
        OIDN_FILTER_TYPE_RT="RT",
        OIDN_FORMAT_FLOAT3=3,
    )
    return FilterCache(pyoidn, device, size), log, device


def image(height: int = 4, width: int = 6) -> np.ndarray:
    return np.zeros((height, width, 3), np.float32)


def created(log: list) -> list:
    return [f for event, f in log if event == "new"]


def test_a_filter_is_reused_for_the_same_images_size_and_options():
    cache, log, _ = fake_cache(4)
    options = {"hdr": True, "cleanAux": False, "quality": 4}
    for _ in range(3):
        assert cache.run({"color": image(), "output": image()}, options) is None
    assert len(created(log)) == 1 and len(cache) == 1
    (filter_,) = created(log)
    assert filter_.options == options


def test_other_names_sizes_or_options_get_their_own_filter():
    cache, log, _ = fake_cache(8)
    cache.run({"color": image(), "output": image()}, {"quality": 4})
    cache.run({"color": image(5), "output": image(5)}, {"quality": 4})
    cache.run({"color": image(), "output": image()}, {"quality": 6})
    cache.run({"albedo": image(), "output": image()}, {"quality": 4})
    assert len(created(log)) == 4 and len(cache) == 4


def test_the_least_recently_used_filter_is_released_first():
    cache, log, _ = fake_cache(2)
    sizes = [4, 5, 4, 6]  # 4 used again before 6 arrives: 5 is the one dropped
    for height in sizes:
        cache.run({"color": image(height), "output": image(height)}, {"quality": 4})
    first, second, _ = created(log)
    assert ("release", second) in log and ("release", first) not in log
    assert len(cache) == 2


def test_the_kept_filters_cover_at_most_max_pixels():
    """Filters of large images push out older ones, and one beyond the budget alone is released
    after its call: the cache never pins more scratch memory than ``MAX_PIXELS`` asks for."""
    cache, log, _ = fake_cache(8)
    side = int((MAX_PIXELS / 2) ** 0.5)  # two of these fit, a third does not
    for name in ("albedo", "normal", "color"):
        cache.run({name: image(side, side), "output": image(side, side)}, {"quality": 4})
    albedo, normal, color = created(log)
    assert ("release", albedo) in log and len(cache) == 2
    huge = int(MAX_PIXELS**0.5) + 1
    cache.run({"color": image(huge, huge), "output": image(huge, huge)}, {"quality": 4})
    assert len(cache) == 0 and all(("release", f) in log for f in (normal, color))


def test_a_filter_that_failed_is_released_and_not_kept():
    cache, log, device = fake_cache(4)
    device.fail = True
    assert cache.run({"color": image(), "output": image()}, {"quality": 4}) == "boom"
    assert len(cache) == 0 and ("release", created(log)[0]) in log
    device.fail = False
    assert cache.run({"color": image(), "output": image()}, {"quality": 4}) is None
    assert len(created(log)) == 2


def test_a_reused_filter_gives_a_new_filters_bits():
    import pyoidn

    from tracer.post.denoise import _OIDN_QUALITY

    device = pyoidn.Device(pyoidn.OIDN_DEVICE_TYPE_CPU)
    device.commit()
    rng = np.random.default_rng(1)
    frames = [rng.random((24, 40, 3), dtype=np.float32) for _ in range(2)]
    options = {"hdr": True, "quality": _OIDN_QUALITY["fast"]}

    def denoised(cache: FilterCache, color: np.ndarray) -> np.ndarray:
        output = np.empty_like(color)
        assert cache.run({"color": color, "output": output}, options) is None
        return output

    reused = FilterCache(pyoidn, device)
    outputs = [denoised(reused, frame) for frame in frames]  # the second on a reused filter
    fresh = denoised(FilterCache(pyoidn, device), frames[1])
    assert len(reused) == 1
    assert np.array_equal(outputs[1], fresh) and not np.array_equal(outputs[0], outputs[1])
