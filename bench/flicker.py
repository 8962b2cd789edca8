"""Temporal flicker of denoised animations against a reference (issue #24, item 4).

Each scene (``--scenes``) is rendered as ``--frames`` frames of ``--size`` at ``--spp`` with its
albedo and normal AOVs (the guides), along two camera paths:

- **still**: the scene's camera every frame; frame ``t`` takes samples
  ``[t * spp, (t + 1) * spp)``, so the running mean of frames 0..t is exactly a render at
  ``(t + 1) * spp`` (what a converging live session shows). Its reference is one render at
  ``--reference-spp``; a second, independent one measures the reference's own noise.
- **moving**: the camera orbits its ``look_at`` about its ``up`` by ``--degrees`` per frame;
  every frame has its own reference at ``--reference-spp``.

Sequences: the raw beauty; each frame denoised (``tracer.post.denoise.denoise``, guided by the
frame's own AOVs) at every quality of ``--qualities``, with and without prefiltered guides;
and, for the still camera, the running mean (``blend``), the running mean denoised (``blend,
denoise``: beauty and AOVs blended alike, then denoised) and the running mean of the denoised
frames (``denoise, blend``). Measures, per sequence, relative to the reference
(``d^2 / (R^2 + eps)`` per pixel and channel, eps = 1e-2 as ``rel_mse``), as RMS over
pixels, channels and frame pairs:

- ``change``: of ``F_t - F_{t-1}``; ``excess``: change minus the reference sequence's own
  (the true motion: its noise removed in quadrature; 0 for the still camera);
- ``error flicker``: of ``(F_t - R_t) - (F_{t-1} - R_{t-1})``, the change of the error alone;
  for the moving camera it holds the references' noise too, removed in quadrature in the
  ``noise removed`` column (the still camera's single reference cancels out of it);
- ``relMSE``: ``rel_mse(F_t, R_t)``, the mean over frames and the last frame's; the
  references' noise adds about ``var(R) / (R^2 + eps)`` to it, half the square of the
  ``reference noise`` change (that row's relMSE).

Writes ``bench/results/flicker.json``; figures and their reading in ``docs/denoising.md``.
"""

import argparse
import math
import statistics
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from common import (
    REPO_ROOT,
    console,
    machine_info,
    print_machine,
    print_table,
    usable_cores,
    write_results,
)

if TYPE_CHECKING:
    from tracer.scene.format import Camera

REFERENCE_SAMPLES = 1 << 24
"""First sample index of the references: far from the frames' samples, so the two are
independent."""

ROW_KEYS = (
    "scene",
    "camera",
    "sequence",
    "quality",
    "prefilter",
    "change",
    "error_flicker",
    "rel_mse",
    "rel_mse_frames",
    "reference_change",
    "excess",
    "error_flicker_noise_removed",
    "denoise_seconds",
)
"""The fields of a row (see :func:`measure_scene`)."""


class _Formatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    """Defaults shown, the description (the module docstring) kept as written."""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    from tracer.post.denoise import QUALITIES

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=_Formatter)
    parser.add_argument(
        "--scenes", nargs="+", default=["cornell-box", "textured"], help="folders of scenes/"
    )
    parser.add_argument("--size", default="320x180", help="WxH of the frames")
    parser.add_argument("--frames", type=int, default=12, help="frames per sequence")
    parser.add_argument("--spp", type=int, default=4, help="samples per pixel of each frame")
    parser.add_argument(
        "--reference-spp", type=int, default=256, help="samples per pixel of the references"
    )
    parser.add_argument(
        "--degrees", type=float, default=2.0, help="orbit of the moving camera per frame"
    )
    parser.add_argument(
        "--qualities", nargs="+", choices=QUALITIES, default=["fast", "high"], help="qualities"
    )
    parser.add_argument(
        "--prefilter",
        choices=("both", "on", "off"),
        default="both",
        help="prefilter the guides (on), take them as they are (off), or both",
    )
    parser.add_argument("--threads", type=int, default=usable_cores(), help="threads")
    args = parser.parse_args(argv)
    try:
        args.width, args.height = (int(side) for side in args.size.split("x"))
    except ValueError:
        parser.error(f"--size must be WxH, not {args.size!r}")
    args.prefilters = {"both": [False, True], "on": [True], "off": [False]}[args.prefilter]
    if min(args.spp, args.reference_spp, args.threads, args.width, args.height) < 1:
        parser.error("--size, --spp, --reference-spp and --threads must be at least 1")
    if args.frames < 2:
        parser.error("--frames must be at least 2 (flicker is a change between frames)")
    return args


def orbit(camera: "Camera", degrees: float) -> "Camera":
    """``camera`` turned by ``degrees`` about the axis through its ``look_at`` along its
    ``up``: its position moves on that circle, ``look_at`` and ``up`` stay."""
    from tracer.scene.format import override

    axis = np.asarray(camera.up, dtype=np.float64)
    axis /= np.linalg.norm(axis)
    angle = math.radians(degrees)

    def turn(v: np.ndarray) -> np.ndarray:  # Rodrigues' rotation
        return (
            v * math.cos(angle)
            + np.cross(axis, v) * math.sin(angle)
            + axis * np.dot(axis, v) * (1.0 - math.cos(angle))
        )

    offset = np.subtract(camera.position, camera.look_at)
    position = np.asarray(camera.look_at) + turn(offset)
    return override(camera, position=tuple(float(x) for x in position))


def scene_renderer(
    name: str, width: int, height: int, threads: int
) -> tuple["Camera", Callable[..., dict[str, np.ndarray]]]:
    """``(camera, render)``: scene ``name``'s camera at ``width`` x ``height`` and
    ``render(camera, spp, sample_start, aovs)``, a dict of (H, W, 3) float32 images: ``beauty``
    and, with ``aovs``, ``albedo`` and ``normal`` of the same paths."""
    from tracer.compiled.scene import compile_scene
    from tracer.integrators.aov import aov_layers
    from tracer.render import render_pixels
    from tracer.scene.format import override
    from tracer.scene.loader import load_scene

    scene = compile_scene(load_scene(REPO_ROOT / "scenes" / name / "scene.json"))

    def render(camera, spp: int, sample_start: int, aovs: bool) -> dict[str, np.ndarray]:
        settings = override(scene.render, spp=spp, aovs=aovs, denoise="off")
        out = render_pixels(
            scene, 0, width * height, camera, settings, sample_start=sample_start, threads=threads
        )
        images = {"beauty": out.rgb.reshape(height, width, 3)}
        if aovs:
            layers = aov_layers(out.aov.reshape(height, width, -1))
            images |= {"albedo": layers["albedo"], "normal": layers["normal"]}
        return images

    return override(scene.camera, width=width, height=height), render


def relative_ms(diff: np.ndarray, reference: np.ndarray) -> float:
    """Mean over pixels and channels of ``diff^2 / (reference^2 + eps)`` (``rel_mse``'s eps)."""
    from tracer.accuracy.error_estimate import REL_EPSILON

    d, r = np.asarray(diff, np.float64), np.asarray(reference, np.float64)
    return float(np.mean(d * d / (r * r + REL_EPSILON)))


def sequence_metrics(frames: list[np.ndarray], references: list[np.ndarray]) -> dict[str, Any]:
    """Relative RMS frame-to-frame ``change`` of ``frames`` and of their error against
    ``references`` (``error_flicker``), and each frame's ``rel_mse`` against its reference."""
    from tracer.accuracy.error_estimate import rel_mse

    change, error = [], []
    for t in range(1, len(frames)):
        scale = 0.5 * (references[t] + references[t - 1])
        change.append(relative_ms(frames[t] - frames[t - 1], scale))
        drift = (frames[t] - references[t]) - (frames[t - 1] - references[t - 1])
        error.append(relative_ms(drift, scale))
    errors = [rel_mse(f, r) for f, r in zip(frames, references, strict=True)]
    return {
        "change": math.sqrt(statistics.fmean(change)),
        "error_flicker": math.sqrt(statistics.fmean(error)),
        "rel_mse": statistics.fmean(errors),
        "rel_mse_frames": errors,
    }


def running_means(frames: list[dict[str, np.ndarray]]) -> list[dict[str, np.ndarray]]:
    """Frame t: the mean of frames 0..t, layer by layer (float32, as a render's)."""
    sums, out = {}, []
    for t, frame in enumerate(frames):
        for key, image in frame.items():
            sums[key] = sums.get(key, 0.0) + image.astype(np.float64)
        out.append({key: (s / (t + 1)).astype(np.float32) for key, s in sums.items()})
    return out


def denoised(
    frames: list[dict[str, np.ndarray]], quality: str, prefilter: bool, threads: int
) -> tuple[list[np.ndarray], float]:
    """Each frame's beauty denoised with its albedo and normal; and the median seconds."""
    from tracer.post.denoise import denoise

    results = [
        denoise(
            f["beauty"], f["albedo"], f["normal"], quality=quality, prefilter=prefilter,
            threads=threads,
        )
        for f in frames
    ]  # fmt: skip
    return [r.image for r in results], statistics.median(r.seconds for r in results)


def measure_scene(name: str, args: argparse.Namespace) -> list[dict[str, Any]]:
    """Every sequence of scene ``name``: one dict per table row."""
    camera, render = scene_renderer(name, args.width, args.height, args.threads)
    cameras = {
        "still": [camera] * args.frames,
        "moving": [orbit(camera, args.degrees * t) for t in range(args.frames)],
    }
    start = time.perf_counter()
    frames = {
        path: [render(c, args.spp, t * args.spp, True) for t, c in enumerate(cams)]
        for path, cams in cameras.items()
    }
    frame_seconds = time.perf_counter() - start
    start = time.perf_counter()
    ref_spp = args.reference_spp
    moving_refs = [
        render(c, ref_spp, REFERENCE_SAMPLES + t * ref_spp, False)["beauty"]
        for t, c in enumerate(cameras["moving"])
    ]  # frame 0 is the still camera: its reference is the still one
    second = render(camera, ref_spp, REFERENCE_SAMPLES + args.frames * ref_spp, False)["beauty"]
    references = {"still": [moving_refs[0]] * args.frames, "moving": moving_refs}
    console.print(
        f"[dim]{name}: {2 * args.frames} frames at {args.spp} spp in {frame_seconds:.1f} s, "
        f"{args.frames + 1} references at {ref_spp} spp in {time.perf_counter() - start:.1f} s[/]"
    )

    # The references' own noise: two independent renders of the still camera. Independent of
    # the frames' noise, it is removed in quadrature from the moving camera's measures.
    noise = sequence_metrics([moving_refs[0], second], [moving_refs[0], second])["change"]
    moving_change = sequence_metrics(moving_refs, moving_refs)["change"]
    motion = {"still": 0.0, "moving": math.sqrt(max(0.0, moving_change**2 - noise**2))}
    rows = []

    def add(path: str, sequence: str, images, quality="-", prefilter=None, seconds=None):
        metrics = sequence_metrics(images, references[path])
        flicker = metrics["error_flicker"]
        if path == "moving":
            flicker = math.sqrt(max(0.0, flicker**2 - noise**2))
        rows.append(
            {
                "scene": name,
                "camera": path,
                "sequence": sequence,
                "quality": quality,
                "prefilter": prefilter,
                **metrics,
                "reference_change": motion[path],
                "excess": metrics["change"] - motion[path],
                "error_flicker_noise_removed": flicker,
                "denoise_seconds": seconds,
            }
        )

    for path in ("still", "moving"):
        rows.append(
            {
                **dict.fromkeys(ROW_KEYS),
                "scene": name,
                "camera": path,
                "sequence": "reference noise" if path == "still" else "reference",
                "quality": "-",
                "change": noise if path == "still" else moving_change,
                # the references' noise in a relMSE against one: var(R) / (R^2 + eps)
                "rel_mse": noise**2 / 2 if path == "still" else None,
                "error_flicker_noise_removed": None if path == "still" else motion[path],
            }
        )
        add(path, "raw", [f["beauty"] for f in frames[path]])
        per_frame = {}
        for quality in args.qualities:
            for prefilter in args.prefilters:
                images, seconds = denoised(frames[path], quality, prefilter, args.threads)
                per_frame[quality, prefilter] = images
                add(path, "denoise", images, quality, prefilter, seconds)
        if path != "still":
            continue
        blends = running_means(frames[path])
        add(path, "blend", [b["beauty"] for b in blends])
        for quality in args.qualities:
            for prefilter in args.prefilters:
                images, seconds = denoised(blends, quality, prefilter, args.threads)
                add(path, "blend, denoise", images, quality, prefilter, seconds)
        for (quality, prefilter), images in per_frame.items():
            means = running_means([{"beauty": image} for image in images])
            add(path, "denoise, blend", [m["beauty"] for m in means], quality, prefilter)
    return rows


def measure(args: argparse.Namespace) -> list[dict[str, Any]]:
    """The rows of every scene (see the module docstring)."""
    return [row for name in args.scenes for row in measure_scene(name, args)]


def _cell(value: float | None, digits: int = 4) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    info = machine_info()
    print_machine(info)
    start = time.perf_counter()
    rows = measure(args)
    seconds = time.perf_counter() - start
    prefilter_text = {None: "-", True: "yes", False: "no"}
    print_table(
        f"Flicker, {args.width}x{args.height}, {args.frames} frames at {args.spp} spp, "
        f"references at {args.reference_spp} spp, moving camera {args.degrees:g} deg/frame",
        [
            "scene",
            "camera",
            "sequence",
            "quality",
            "prefilter",
            "change",
            "excess",
            "error flicker",
            "noise removed",
            "relMSE",
            "relMSE last",
            "denoise s",
        ],
        [
            (
                row["scene"],
                row["camera"],
                row["sequence"],
                row["quality"],
                prefilter_text[row["prefilter"]],
                _cell(row["change"]),
                _cell(row["excess"]),
                _cell(row["error_flicker"]),
                _cell(row["error_flicker_noise_removed"]),
                _cell(row["rel_mse"], 5),
                _cell(row["rel_mse_frames"] and row["rel_mse_frames"][-1], 5),
                _cell(row["denoise_seconds"], 3),
            )
            for row in rows
        ],
        caption="change: relative RMS (d^2 / (R^2 + 1e-2) per pixel channel, over frame pairs) "
        "of F_t - F_{t-1}; excess: change minus the reference's (its noise removed; 0 for the "
        "still camera's single reference); error flicker: of (F_t - R_t) - (F_{t-1} - R_{t-1}); "
        "'reference noise': the change between two independent references of the still camera; "
        "noise removed: the moving camera's error flicker (reference row: its change) with that "
        "noise removed in quadrature; relMSE against the reference (its noise included: the "
        "'reference noise' row's relMSE, to subtract), mean over frames and the last frame's; "
        "blend: running mean of frames 0..t; denoise s: median seconds per call. "
        f"{seconds:.0f} s in all.",
    )
    write_results(
        "flicker",
        {
            "options": {k: v for k, v in vars(args).items() if k != "prefilters"},
            "seconds": seconds,
            "results": rows,
        },
        info,
    )


if __name__ == "__main__":
    main()
