"""Record per-line cost traces of an orbiting camera, for the balancer simulator.

The scene is built here (nothing is added to ``scenes/``): a 40 m ground plane and a ring of
five Nefertiti busts (70k triangles each, ``scenes/nefertiti/nefertiti-lowres.obj``) on
pedestals, lit by a constant sky and one area light. The camera circles the ring at bust
height looking level, so the top of every frame is empty sky (one bounding-box test per ray)
and the lines below the horizon cross the dense meshes and the ground: per-line costs differ by
orders of magnitude, and the busts drift through the frame as the camera moves.

For every frame, ``tracer.render.render_pixels`` renders the whole frame as one pixel run and
returns the cost of each pixel (BVH node visits plus triangle tests of all the pixel's rays,
bounces included); the script sums them per line and per span of a line (the cluster's work
units, ``worker.work_units``, at the finest spans they allow) and keeps the frame's wall-clock
seconds. The warm-up render of frame 0 goes through ``render_image`` and must give the same
line costs (the kernels are split-independent; the script stops if not). Each orbit is saved as
``bench/traces/<name>.npz``::

    cost       int64  (frames, height)         per-line cost
    span_cost  int32  (frames, height, spans)  per-span cost, ``spans`` equal spans per line
                                               (``WorkUnits.for_tracers(W, H, 10**6).spans``:
                                               64 at 640 px, 16 at 128 px); sums to ``cost``
    seconds    float64 (frames,)               wall-clock seconds of the frame's render call
    angle_deg  float64 (frames,)               camera azimuth of each frame
    spans, width, height, spp, max_depth, threads, frames, orbit_deg: int/float scalars
    description: str

Usage (from the repository root)::

    ./dev shell python bench/record_cost_traces.py                  # the four default traces
    ./dev shell python bench/record_cost_traces.py --only slow fast # just the small ones

The defaults record ``slow`` (45 degrees) and ``fast`` (360 degrees) at 128x96, and ``slow-hd``
and ``fast-hd``, the same orbits at 640x480 (480 lines, for simulations of up to 128 tracers),
all 128 frames at 1 spp. Each trace renders in under a minute on two cores once the kernels
are compiled (the first run compiles them: add a few seconds to a minute).
"""

import argparse
import json
import math
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
from common import REPO_ROOT, console, machine_info, usable_cores

from worker.work_units import WorkUnits

TRACE_DIR = REPO_ROOT / "bench" / "traces"
MESH = REPO_ROOT / "scenes" / "nefertiti" / "nefertiti-lowres.obj"

RING_RADIUS = 2.2
"""Busts stand on a circle of this radius (metres) around the origin."""
BUSTS = 5
ORBIT_RADIUS = 7.5
CAMERA_HEIGHT = 3.0
"""Eye height, above the busts' crowns (pedestal 0.6 m + bust about 1.5 m): with a level gaze
everything but the sky lies below the horizon, the middle line of the frame."""
VFOV_DEG = 40.0

ORBITS = {
    # name: (degrees covered over the frames, width, height)
    "slow": (45.0, 128, 96),
    "fast": (360.0, 128, 96),
    "slow-hd": (45.0, 640, 480),
    "fast-hd": (360.0, 640, 480),
}


def scene_document() -> dict:
    """The scene as a ``tilerender/1`` JSON document (the mesh is referenced by file name)."""
    objects: list[dict] = [
        {"name": "ground", "shape": {"type": "plane", "size": 40.0}, "material": "ground"},
        {
            "name": "sun",
            "shape": {"type": "rectangle", "size": [2.0, 2.0]},
            "material": "light",
            "transform": {"translate": [0.0, 8.0, 0.0], "rotate": [90.0, 0.0, 0.0]},
        },
    ]
    for k in range(BUSTS):
        phi = 2.0 * math.pi * k / BUSTS
        x, z = RING_RADIUS * math.cos(phi), RING_RADIUS * math.sin(phi)
        objects.append(
            {
                "name": f"pedestal-{k}",
                "shape": {"type": "box", "size": [0.9, 0.6, 0.9]},
                "material": "pedestal",
                "transform": {"translate": [x, 0.3, z]},
            }
        )
        objects.append(
            {
                "name": f"bust-{k}",
                "shape": "bust.obj",
                "material": "stone",
                "kind": "rigid",  # instanced: one 70k-triangle BVH shared by all five
                "transform": {
                    "translate": [x, 1.7, z],
                    "rotate": [0.0, -math.degrees(phi) + 90.0, 0.0],
                    "scale": 0.0044,
                },
            }
        )
    return {
        "format": "tilerender/1",
        "render": {"spp": 1, "max_depth": 3, "rr_depth": 2, "seed": 0},
        "sky": {"radiance": [0.6, 0.7, 0.9]},
        "materials": {
            "ground": {"reflectance": [0.5, 0.5, 0.5]},
            "pedestal": {"reflectance": [0.3, 0.3, 0.32]},
            "stone": {"reflectance": [0.78, 0.62, 0.45]},
            "light": {
                "reflectance": [0.0, 0.0, 0.0],
                "emission": [20.0, 19.0, 17.0],
                "two_sided": False,
            },
        },
        "objects": objects,
    }


def orbit_camera(angle_deg: float, width: int, height: int):
    """The camera at azimuth ``angle_deg``, level, looking at the ring's centre."""
    from tracer.scene import format as fmt

    a = math.radians(angle_deg)
    position = (ORBIT_RADIUS * math.sin(a), CAMERA_HEIGHT, ORBIT_RADIUS * math.cos(a))
    return fmt.Camera(
        position=position,
        look_at=(0.0, CAMERA_HEIGHT, 0.0),  # level gaze: the horizon is the middle line
        up=(0.0, 1.0, 0.0),
        vfov_deg=VFOV_DEG,
        width=width,
        height=height,
    )


def load_orbit_scene():
    """The scene, loaded and compiled through the normal loader (from a temporary folder)."""
    from tracer.compiled.scene import compile_scene
    from tracer.scene.loader import load_scene

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        shutil.copyfile(MESH, folder / "bust.obj")
        (folder / "scene.json").write_text(json.dumps(scene_document()))
        state = load_scene(folder / "scene.json")
    return state, compile_scene(state)


def record(name: str, frames: int, spp: int, threads: int, state, scene, out: Path) -> Path:
    """Render one orbit and save its trace; returns the file written."""
    from tracer.render import render_image, render_pixels
    from tracer.scene import format as fmt

    degrees, width, height = ORBITS[name]
    settings = fmt.override(state.render, spp=spp)
    units = WorkUnits(width, height, WorkUnits.for_tracers(width, height, 10**6).spans)
    angles = np.array([degrees * i / frames for i in range(frames)])
    cost = np.empty((frames, height), np.int64)
    span_cost = np.empty((frames, height, units.spans), np.int64)
    seconds = np.empty(frames)
    # One untimed frame first (frame 0, by whole lines): compiles (or loads) the kernels, warms
    # the caches and gives the line costs the pixel run of frame 0 must reproduce.
    first = orbit_camera(0.0, width, height)
    _, lines_cost = render_image(scene, first, settings, 0, threads=threads)
    start = time.perf_counter()
    for i, angle in enumerate(angles):
        camera = orbit_camera(float(angle), width, height)
        run = render_pixels(scene, 0, width * height, camera, settings, frame=i, threads=threads)
        seconds[i] = run.seconds
        span_cost[i] = units.per_unit(0, units.count, run.cost).reshape(height, units.spans)
        cost[i] = run.cost.reshape(height, width).sum(axis=1)
    total = time.perf_counter() - start
    if not np.array_equal(cost[0], lines_cost):
        raise SystemExit(f"{name}: frame 0's line costs differ between render_image and a run")
    if span_cost.max() > np.iinfo(np.int32).max:
        raise SystemExit(f"{name}: a span costs {span_cost.max()}, more than int32 holds")
    band_cost, band_seconds = calibrate(scene, first, settings, threads)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.npz"
    np.savez_compressed(
        path,
        cost=cost,
        span_cost=span_cost.astype(np.int32),
        spans=units.spans,
        seconds=seconds,
        angle_deg=angles,
        width=width,
        height=height,
        spp=spp,
        max_depth=settings.max_depth,
        threads=threads,
        frames=frames,
        orbit_deg=degrees,
        band_cost=band_cost,
        band_seconds=band_seconds,
        description=(
            f"{BUSTS} Nefertiti busts in a ring (r={RING_RADIUS} m) on a ground plane, camera "
            f"orbiting at r={ORBIT_RADIUS} m, eye height {CAMERA_HEIGHT} m, level gaze; "
            f"{degrees:g} degrees over {frames} frames; recorded with tilerender "
            f"{machine_info()['git']}"
        ),
    )
    sky = cost[:, : height // 3].sum() / max(1, cost.sum())
    slope, intercept = np.polyfit(band_cost, band_seconds, 1)
    fit = intercept + slope * band_cost
    console.print(
        f"{name}: {frames} frames {width}x{height} ({units.spans} spans a line) in {total:.1f} s "
        f"({seconds.mean() * 1e3:.1f} ms/frame, median {np.median(seconds) * 1e3:.1f}); the top "
        f"third of the frame holds {sky:.1%} of the cost, lines cost {cost.min()}..{cost.max()}; "
        f"bands: seconds = {intercept * 1e3:.2f} ms + cost / {1 / slope:.3g} per s, "
        f"r = {np.corrcoef(band_cost, band_seconds)[0, 1]:.3f}, worst band off the fit by "
        f"{np.max(np.abs(band_seconds - fit)) / band_seconds.mean():.0%} of a mean band; "
        f"wrote {_shown(path)} ({path.stat().st_size / 1024:.0f} KiB)"
    )
    return path


def calibrate(scene, camera, settings, threads: int, bands: int = 16, repeats: int = 3):
    """Does cost predict time? Render ``bands`` equal line bands of one frame separately (best
    of ``repeats`` each) and return each band's cost and seconds, for a straight-line fit."""
    from tracer.render import render_lines

    edges = [camera.height * k // bands for k in range(bands + 1)]
    band_cost = np.zeros(bands)
    band_seconds = np.full(bands, np.inf)
    for _ in range(repeats):
        for k in range(bands):
            part = render_lines(scene, edges[k], edges[k + 1], camera, settings, 0, 0, threads)
            band_cost[k] = part.cost.sum()
            band_seconds[k] = min(band_seconds[k], part.seconds)
    return band_cost, band_seconds


def _shown(path: Path) -> str:
    """``path`` relative to the repository when it lies inside it."""
    path = path.resolve()
    return str(path.relative_to(REPO_ROOT)) if path.is_relative_to(REPO_ROOT) else str(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0]
        + " Writes bench/traces/<name>.npz (cost per line and per span of a line per frame, "
        "seconds per frame).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument(
        "--only",
        nargs="+",
        choices=sorted(ORBITS),
        default=list(ORBITS),
        help="traces to record (slow/fast: 45/360 degrees at 128x96; *-hd: 640x480)",
    )
    parser.add_argument("--frames", type=int, default=128, help="frames per orbit")
    parser.add_argument("--spp", type=int, default=1, help="samples per pixel")
    parser.add_argument("--threads", type=int, default=usable_cores(), help="render threads")
    parser.add_argument("--out", type=Path, default=TRACE_DIR, help="folder for the .npz files")
    args = parser.parse_args(argv)
    if args.frames < 2 or args.spp < 1 or args.threads < 1:
        parser.error("--frames must be at least 2, --spp and --threads at least 1")
    console.print("[dim]loading and compiling the scene ...[/]")
    state, scene = load_orbit_scene()
    for name in args.only:
        record(name, args.frames, args.spp, args.threads, state, scene, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
