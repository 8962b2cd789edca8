"""Committed OIDN filters kept for reuse across denoising calls, per device.

OIDN's documentation asks to reuse a filter for every image of the same size, format and
features rather than create one per image: a new filter's first execution sets up its network
(``docs/denoising.md``). :class:`FilterCache` keeps the most recently used filters of one device
by what they were set up for (image names, size, options); a call sets its images on the cached
filter, which OIDN commits without rebuilding the network, and executes it. A kept filter holds
OIDN's scratch memory for its image size, so the cache keeps filters for a bounded number of
pixels in all. A kept filter still points at the last call's arrays, which may be freed: the
key names every image, so each is set again before the next commit. The cache is not locked:
its device's lock (``tracer.post.denoise``) guards it.
"""

from __future__ import annotations

from collections import OrderedDict
from types import ModuleType

import numpy as np

MAX_FILTERS = 8
"""Filters kept per device: the three a prefiltered call uses (albedo, normal, beauty) for two
frame sizes and qualities at once (a job's frame and a live session's), with room to spare."""

MAX_PIXELS = 3 * 2048 * 2048
"""Pixels of the images the kept filters were set up for, in all: the three filters of a
prefiltered call of up to about 4 megapixels. A larger call's filters are released after it."""

FilterKey = tuple[tuple[str, ...], tuple[int, int], tuple[tuple[str, object], ...]]
"""What a filter was set up for: its images' names, the images' (height, width), its options."""


class FilterCache:
    """The ``RT`` filters of one committed OIDN device, least recently used dropped first."""

    def __init__(self, pyoidn: ModuleType, device: object, size: int = MAX_FILTERS) -> None:
        self._pyoidn = pyoidn
        self._device = device
        self._size = size
        self._filters: OrderedDict[FilterKey, object] = OrderedDict()

    def __len__(self) -> int:
        return len(self._filters)

    def _pixels(self) -> int:
        return sum(height * width for _, (height, width), _ in self._filters)

    def _filter(self, key: FilterKey, options: dict) -> object:
        """The cached filter for ``key``, or a new one with ``options`` set."""
        filter_ = self._filters.pop(key, None)
        height, width = key[1]
        while self._filters and self._pixels() + height * width > MAX_PIXELS:
            self._filters.popitem(last=False)[1].release()
        if filter_ is None:
            filter_ = self._pyoidn.Filter(self._device, self._pyoidn.OIDN_FILTER_TYPE_RT)
            for name, value in options.items():
                if name == "quality":
                    filter_.set_quality(value)
                else:
                    filter_.set_bool(name, value)
            while len(self._filters) >= self._size:
                self._filters.popitem(last=False)[1].release()
        self._filters[key] = filter_
        return filter_

    def run(self, images: dict[str, np.ndarray], options: dict) -> str | None:
        """Run an ``RT`` filter over ``images`` (name -> C-contiguous float32 (H, W, 3)) with
        ``options`` (``quality`` an OIDN quality, others bool); OIDN's error message or None.
        A filter that reported an error is released, not kept."""
        shape = next(iter(images.values())).shape[:2]
        key = (tuple(images), shape, tuple(sorted(options.items())))
        filter_ = self._filter(key, options)
        for name, image in images.items():
            filter_.set_image(name, image, self._pyoidn.OIDN_FORMAT_FLOAT3)
        filter_.commit()
        error = self._device.get_error()
        if error is None:
            filter_.execute()
            error = self._device.get_error()
        if error is not None or self._pixels() > MAX_PIXELS:
            del self._filters[key]
            filter_.release()
        return error
