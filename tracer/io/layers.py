"""A frame's layers (beauty, denoised, AOVs) in one file: a multilayer OpenEXR or a NumPy bundle.

A frame's layers are a ``dict`` from the names in :data:`LAYERS` to float32 arrays, (H, W, 3),
or (H, W) for ``depth``, ``alpha`` and the ids; ``beauty`` is required and every layer has the
same H and W. The EXR names its channels as compositors (Nuke, Blender, OpenImageIO) read layers
(:data:`EXR_CHANNELS`): the beauty is the default layer ``R``, ``G``, ``B``; depth is OpenEXR's
standard ``Z``; alpha is a layer of its own (``alpha.A``), since the beauty (sky included) is
not premultiplied by it; an id is a one-value layer (``object_id.X``, as Blender names its
``IndexOB.X``). What the ids name is the writer's to put in the metadata
(``tracer.io.metadata.id_names``).
The ``.npz`` holds one array per layer and the metadata JSON as a 0-d string array
``metadata``. Writes are atomic (``tracer.io.files``), like ``tracer.io.images``.
"""

import json
from pathlib import Path

import numpy as np

from tracer.io.files import atomic_path, output_file

LAYERS: dict[str, int] = {
    "beauty": 3,
    "denoised": 3,
    "albedo": 3,
    "normal": 3,
    "depth": 1,
    "position": 3,
    "alpha": 1,
    "object_id": 1,
    "material_id": 1,
}
"""The known layers, in file order, with their channel counts."""
ID_LAYERS = ("object_id", "material_id")
"""The layers of ids (exact integers, -1 where the camera ray misses), not colours."""

EXR_CHANNELS: dict[str, tuple[str, ...]] = {
    "beauty": ("R", "G", "B"),
    "denoised": ("denoised.R", "denoised.G", "denoised.B"),
    "albedo": ("albedo.R", "albedo.G", "albedo.B"),
    "normal": ("normal.X", "normal.Y", "normal.Z"),
    "depth": ("Z",),
    "position": ("position.X", "position.Y", "position.Z"),
    "alpha": ("alpha.A",),  # not the default layer's A: the beauty is not premultiplied
    "object_id": ("object_id.X",),
    "material_id": ("material_id.X",),
}
"""Each layer's EXR channel names, in the order of the array's last axis."""

LAYER_FORMATS = (".exr", ".npz")


def check_layers_path(path: str | Path) -> Path:
    """The output path, if its extension names a layers format; ValueError otherwise."""
    return output_file(path, LAYER_FORMATS, "layers")


def _check_layer(name: str, array: np.ndarray) -> np.ndarray:
    """One layer as a C-contiguous float32 array of its shape; ValueError otherwise."""
    array = np.ascontiguousarray(array, dtype=np.float32)
    n = LAYERS[name]
    if array.ndim != (2 if n == 1 else 3) or (n > 1 and array.shape[2] != n):
        want = "(H, W)" if n == 1 else f"(H, W, {n})"
        raise ValueError(f"layer {name!r}: expected shape {want}, got {array.shape}")
    if array.shape[0] < 1 or array.shape[1] < 1:
        raise ValueError(f"layer {name!r}: empty image, shape {array.shape}")
    return array


def check_layers(layers: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The layers as C-contiguous float32 arrays in :data:`LAYERS` order, after checking names,
    shapes and sizes; ValueError naming the first problem."""
    unknown = sorted(set(layers) - set(LAYERS))
    if unknown:
        raise ValueError(
            f"unknown layer {', '.join(map(repr, unknown))}; the layers are " + ", ".join(LAYERS)
        )
    if "beauty" not in layers:
        raise ValueError(f"no 'beauty' layer (got {', '.join(layers) or 'none'})")
    checked = {name: _check_layer(name, layers[name]) for name in LAYERS if name in layers}
    size = checked["beauty"].shape[:2]
    for name, array in checked.items():
        if array.shape[:2] != size:
            raise ValueError(
                f"layer {name!r} is {array.shape[0]}x{array.shape[1]} (H x W), "
                f"beauty is {size[0]}x{size[1]}"
            )
    return checked


def write_layers(
    path: str | Path, layers: dict[str, np.ndarray], metadata: dict | None = None
) -> Path:
    """Write a frame's layers to ``path``, a multilayer ``.exr`` (float32, ZIP, scanline) or a
    ``.npz`` bundle, with ``metadata`` (JSON-serialisable) in the EXR header attribute
    ``tilerender`` or the bundle's ``metadata`` member. Arrays are converted to float32."""
    path = check_layers_path(path)
    layers = check_layers(layers)
    text = json.dumps(metadata or {}, sort_keys=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".npz":
            with open(tmp, "wb") as f:  # a file object: np.savez would add ".npz" to a name
                np.savez(f, **layers, metadata=np.array(text))
        else:
            _write_exr(tmp, layers, text)
    return path


def _write_exr(path: Path, layers: dict[str, np.ndarray], text: str) -> None:
    import OpenEXR

    channels = {}
    for name, array in layers.items():
        planes = [array] if array.ndim == 2 else [array[..., i] for i in range(array.shape[2])]
        for channel, plane in zip(EXR_CHANNELS[name], planes, strict=True):
            # OpenEXR.File writes a strided view wrongly: each channel must be contiguous
            channels[channel] = np.ascontiguousarray(plane)
    header = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        "tilerender": text,
    }
    OpenEXR.File(header, channels).write(str(path))


def read_layers(path: str | Path) -> tuple[dict[str, np.ndarray], dict]:
    """The layers and metadata of a file written by :func:`write_layers`; a plain RGB EXR (as
    ``tracer.io.images.write_image`` writes) reads as its beauty. EXR channels that name no
    layer are ignored; a layer with only some of its channels is a ValueError."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npz":
        with np.load(path, allow_pickle=False) as bundle:
            members = {name: bundle[name] for name in bundle.files}
        text = members.pop("metadata", None)
        return _checked(path, members), json.loads(text.item()) if text is not None else {}
    if suffix != ".exr":
        raise ValueError(
            f"{path}: unknown layers format {suffix or '(none)'!r}; use one of "
            + ", ".join(LAYER_FORMATS)
        )
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:  # closing empties header()
        text = f.header().get("tilerender")
        channels = {name: c.pixels for name, c in f.channels().items()}
    layers = {}
    for name, names in EXR_CHANNELS.items():
        present = [c for c in names if c in channels]
        if not present:
            continue
        if len(present) != len(names):
            missing = [c for c in names if c not in channels]
            raise ValueError(f"{path}: layer {name!r} has no {', '.join(missing)} channel")
        planes = [np.asarray(channels[c], np.float32) for c in names]
        layers[name] = planes[0] if len(planes) == 1 else np.stack(planes, axis=-1)
    return _checked(path, layers), json.loads(text) if text else {}


def _checked(path: Path, layers: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """:func:`check_layers` of what a file holds, its errors naming the file."""
    try:
        return check_layers(layers)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def layer_as_rgb(layers: dict[str, np.ndarray], name: str, view: bool = True) -> np.ndarray:
    """Layer ``name`` as a float32 (H, W, 3) image for ``tracer.io.images.write_image``. Colour
    layers and ``position`` are as they are; ``normal`` is mapped from [-1, 1] to [0, 1]
    (``(n + 1) / 2``, for viewing only); ``depth`` is divided by its largest finite value (by 1
    if none is positive), clamped to [0, 1] (+inf is 1, NaN 0) and repeated in 3 channels;
    ``alpha`` is repeated in 3 channels; an id layer is false colour (:func:`id_colours`). With
    ``view=False`` (float formats) every layer keeps its values: only one-channel layers are
    repeated in 3 channels."""
    if name not in LAYERS or name not in layers:
        raise ValueError(
            f"no layer {name!r}; the layers present are " + (", ".join(layers) or "none")
        )
    array = _check_layer(name, layers[name])
    if not view:
        return np.repeat(array[..., None], 3, axis=2) if array.ndim == 2 else array.copy()
    if name == "normal":
        return (array + np.float32(1.0)) * np.float32(0.5)
    if name == "alpha":
        return np.repeat(array[..., None], 3, axis=2)
    if name in ID_LAYERS:
        return id_colours(array)
    if name != "depth":
        return array.copy()
    finite = array[np.isfinite(array)]
    top = finite.max() if finite.size else 0.0
    scaled = array / np.float32(top if top > 0 else 1.0)
    scaled = np.clip(np.nan_to_num(scaled, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    return np.repeat(scaled[..., None], 3, axis=2)


def id_colours(ids: np.ndarray) -> np.ndarray:
    """Float32 (H, W, 3) false colours of an id layer (H, W): each id its own colour, a hash
    of it (the same in every file), in [0.2, 1] per channel; black where the id is negative
    (nothing hit)."""
    h = (ids.astype(np.int64) + 1).astype(np.uint32)
    for shift, factor in ((16, 0x7FEB352D), (15, 0x846CA68B)):  # lowbias32 (C. Wellons)
        h ^= h >> np.uint32(shift)
        h *= np.uint32(factor)
    h ^= h >> np.uint32(16)
    channels = np.stack([(h >> np.uint32(8 * c)) & np.uint32(255) for c in range(3)], axis=-1)
    colours = np.float32(0.2) + np.float32(0.8 / 255) * channels.astype(np.float32)
    colours[ids < 0] = 0.0
    return colours
