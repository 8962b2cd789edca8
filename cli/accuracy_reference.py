"""The one reference image per scene that the accuracy study measures every render against.

An independent renderer's reference is preferred: ``mitsuba_mean.npy`` with
``mitsuba_var_of_mean.npy`` and ``mitsuba.json`` (or the Cornell box's ``reference_mean.npy``
and ``reference_var_of_mean.npy``) in the scene's folder, when its resolution is the study's or
an integer multiple of it (``k x k`` blocks of a box-filtered image average to the box-filtered
image of the larger pixel), and when Mitsuba's material models are ours for that scene. It was
rendered with the scene's own render settings.

Otherwise the reference is our own path tracer with every effect, ``max_depth``
``REFERENCE_DEPTH`` and a seed no sweep uses, in ``passes`` independent passes over disjoint
sample ranges: their mean is the reference and their spread gives its variance. It is cached
under a key that hashes the scene's files, the camera, the settings and the tracer's code (the
hash ``tracer.kernel.numba_cache`` keys compiled kernels by), so a changed renderer never meets a
reference it made before the change.
"""

import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tracer.compiled.scene import CompiledScene
from tracer.io.files import atomic_path
from tracer.kernel.numba_cache import source_digest
from tracer.render import render_image
from tracer.scene import format as fmt

REFERENCE_DEPTH = 64
"""Path vertices of our own references: deeper than any configuration of the sweep, so that a
capped depth shows as error (Russian roulette keeps long paths cheap)."""
REFERENCE_SEED_OFFSET = 1_000_003
"""Added to the study's seed for our own references: no configuration shares their samples."""
INDEPENDENT_FILES = (
    ("mitsuba_mean.npy", "mitsuba_var_of_mean.npy"),
    ("reference_mean.npy", "reference_var_of_mean.npy"),
)
CACHE_VERSION = 1


@dataclass(frozen=True)
class Reference:
    """A scene's reference: ``mean`` and ``var_of_mean`` float64 (H, W, 3)."""

    mean: np.ndarray
    var_of_mean: np.ndarray
    source: str
    """``mitsuba`` (an independent renderer's file) or ``tilerender``."""
    settings: fmt.RenderSettings
    """The settings a render must use to be unbiased against this reference."""
    spp: int
    seconds: float
    """Seconds rendering it took (0 when read from a file or the cache)."""
    detail: str
    """Where it came from, in words."""


def independent_reference(
    folder: Path, width: int, height: int, settings: fmt.RenderSettings
) -> tuple[Reference | None, str]:
    """An independent renderer's reference in ``folder`` at (a multiple of) ``width x height``,
    the least noisy one when there are several; ``(None, why)`` when there is none to use.

    A Mitsuba reference whose ``mitsuba.json`` lists a ``model`` deviation (a material model
    that differs from ours, docs/mitsuba.md) is not used: every configuration would show that
    difference as error. Its ``max_depth`` and ``rr_depth`` are the settings it was made with.
    """
    found, notes = [], []
    for mean_name, var_name in INDEPENDENT_FILES:
        mean_path, var_path = folder / mean_name, folder / var_name
        if not (mean_path.is_file() and var_path.is_file()):
            continue
        record = _mitsuba_record(folder) if mean_name.startswith("mitsuba") else {}
        models = [d["feature"] for d in record.get("deviations", []) if d.get("kind") == "model"]
        if models:
            notes.append(f"{mean_name} not used: its material models differ ({', '.join(models)})")
            continue
        mean = np.load(mean_path).astype(np.float64)
        var = np.load(var_path).astype(np.float64)
        if mean.ndim != 3 or mean.shape != var.shape or mean.shape[2] != 3:
            notes.append(f"{mean_name} not used: shape {mean.shape}")
            continue
        k = mean.shape[1] // width
        if k < 1 or mean.shape[0] != k * height or mean.shape[1] != k * width:
            notes.append(f"{mean_name} not used: {mean.shape[1]}x{mean.shape[0]} pixels")
            continue
        used = fmt.override(
            settings, max_depth=record.get("max_depth"), rr_depth=record.get("rr_depth")
        )
        spp = record.get("passes", 0) * record.get("spp_per_pass", 0) or None
        detail = (
            f"{mean_name} ({record.get('renderer', 'Mitsuba 3')}, {mean.shape[1]}x{mean.shape[0]}"
            + (f", {spp} spp" if spp else "")
            + (f", {k}x{k} blocks averaged" if k > 1 else "")
            + ")"
        )
        var = block_mean(var, k) / (k * k)
        found.append(Reference(block_mean(mean, k), var, "mitsuba", used, spp or 0, 0.0, detail))
    if not found:
        return None, "; ".join(notes)
    return min(found, key=lambda ref: float(ref.var_of_mean.mean())), "; ".join(notes)


def _mitsuba_record(folder: Path) -> dict:
    """``mitsuba.json`` beside a Mitsuba reference (how it was made), or {}."""
    path = folder / "mitsuba.json"
    try:
        return json.loads(path.read_text()) if path.is_file() else {}
    except (OSError, ValueError):
        return {}


def block_mean(image: np.ndarray, k: int) -> np.ndarray:
    """The mean of each ``k x k`` block of an (H, W, C) image."""
    if k == 1:
        return image
    h, w, c = image.shape
    return image.reshape(h // k, k, w // k, k, c).mean(axis=(1, 3))


def reference_settings(settings: fmt.RenderSettings, seed: int) -> fmt.RenderSettings:
    """Our own reference's settings: the path tracer, every effect the scene needs, deep."""
    return fmt.override(
        settings,
        integrator="path",
        max_depth=REFERENCE_DEPTH,
        seed=seed + REFERENCE_SEED_OFFSET,
        effects={},
        effect_plan=True,
    )


def cache_key(
    folder: Path, camera: fmt.Camera, settings: fmt.RenderSettings, spp: int, passes: int
) -> str:
    """A hash of everything our reference depends on: every file of the scene's folder, the
    camera, the settings, the sample counts and the tracer's code (``tracer/*.py``)."""
    digest = hashlib.sha256()
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        if path.suffix == ".npy":  # references themselves
            continue
        digest.update(str(path.relative_to(folder)).encode())
        digest.update(path.read_bytes())
    record = {
        "camera": camera.model_dump(mode="json"),
        "settings": settings.model_dump(mode="json"),
        "spp": spp,
        "passes": passes,
        "version": CACHE_VERSION,
        "tracer": source_digest(),
    }
    digest.update(json.dumps(record, sort_keys=True).encode())
    return digest.hexdigest()[:16]


def own_reference(
    scene: CompiledScene,
    folder: Path,
    camera: fmt.Camera,
    settings: fmt.RenderSettings,
    spp: int,
    passes: int,
    cache_dir: Path,
    threads: int | None = None,
    on_samples: Callable[[int], None] | None = None,
) -> Reference:
    """Our own reference of ``spp`` samples per pixel in ``passes`` passes, from the cache
    when it is there (``on_samples(n)`` is told of every pass rendered)."""
    per_pass = max(1, spp // passes)
    key = cache_key(folder, camera, settings, per_pass, passes)
    path = cache_dir / f"{folder.name}-{camera.width}x{camera.height}-{key}.npz"
    detail = f"tilerender, path, max_depth {settings.max_depth}, {per_pass * passes} spp"
    if path.is_file():
        with np.load(path) as cached:
            mean, var = cached["mean"], cached["var_of_mean"]
        if on_samples is not None:
            on_samples(per_pass * passes)
        return Reference(
            mean, var, "tilerender", settings, per_pass * passes, 0.0, detail + " (cached)"
        )
    start = time.perf_counter()
    images = []
    for k in range(passes):
        rgb, _ = render_image(
            scene,
            camera,
            fmt.override(settings, spp=per_pass),
            sample_start=k * per_pass,
            threads=threads,
        )
        images.append(rgb.astype(np.float64))
        if on_samples is not None:
            on_samples(per_pass)
    seconds = time.perf_counter() - start
    stack = np.stack(images)
    mean = stack.mean(axis=0)
    var = stack.var(axis=0, ddof=1) / passes
    cache_dir.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, mean=mean, var_of_mean=var)
    return Reference(mean, var, "tilerender", settings, per_pass * passes, seconds, detail)
