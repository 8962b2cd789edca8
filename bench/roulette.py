"""Russian roulette in glass: the variance of a sample at equal samples per pixel, with roulette
and without, against Mitsuba 3's on the same scene.

For every scene with glass and a stored Mitsuba reference (``bench/mitsuba_references.py``), we
render the reference's view at its size in ``--passes`` passes of ``--spp`` samples, once as the
scene says (roulette after ``rr_depth`` bounces) and once with roulette off. A sample's variance
is the variance of the pass means times the samples per pass, averaged over the image; Mitsuba's
is its stored variance of the mean times its samples. Time is ours per sample: what roulette
saves. Mitsuba is not needed to run this.
"""

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
from common import machine_info, print_machine, print_table, verdict, write_results

from tracer.compiled.scene import compile_scene
from tracer.render import render_image
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene

SCENES_DIR = Path(__file__).resolve().parents[1] / "scenes"
GLASS_SCENES = ("cornell-spheres", "mitsuba/sun", "mitsuba/outdoor")
TARGET = 1.1
"""Our variance at equal samples over Mitsuba's, at most (with roulette)."""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", nargs="+", default=list(GLASS_SCENES), metavar="NAME")
    parser.add_argument("--passes", type=int, default=8, help="passes per setting (default 8)")
    parser.add_argument("--spp", type=int, default=128, help="samples per pass (default 128)")
    return parser.parse_args(argv)


def sample_variance(scene, camera, settings, passes: int) -> tuple[float, float, float]:
    """(image-mean radiance, image-mean variance of one sample, seconds per pass)."""
    start = time.perf_counter()
    images = [
        render_image(scene, camera, settings, sample_start=k * settings.spp)[0]
        for k in range(passes)
    ]
    seconds = (time.perf_counter() - start) / passes
    stack = np.stack(images).astype(np.float64)
    variance = stack.var(axis=0, ddof=1) * settings.spp
    return float(stack.mean()), float(variance.mean()), seconds


def measure(name: str, passes: int, spp: int) -> dict:
    folder = SCENES_DIR / name
    record = json.loads((folder / "mitsuba.json").read_text())
    theirs = np.load(folder / "mitsuba_var_of_mean.npy").astype(np.float64)
    their_variance = float(theirs.mean()) * record["passes"] * record["spp_per_pass"]
    state = load_scene(SCENES_DIR / record["scene"])
    camera = fmt.override(state.camera, width=record["width"], height=record["height"])
    scene = compile_scene(dataclasses.replace(state, camera=camera))
    on = fmt.override(state.render, spp=spp)
    off = fmt.override(on, rr_depth=state.render.max_depth + 1)
    render_image(scene, camera, fmt.override(on, spp=1))  # compile or load the kernel first
    mean_on, var_on, time_on = sample_variance(scene, camera, on, passes)
    mean_off, var_off, time_off = sample_variance(scene, camera, off, passes)
    return {
        "scene": name,
        "size": [record["width"], record["height"]],
        "mitsuba_variance": their_variance,
        "roulette": {"mean": mean_on, "variance": var_on, "seconds_per_pass": time_on},
        "no_roulette": {"mean": mean_off, "variance": var_off, "seconds_per_pass": time_off},
        "roulette_over_mitsuba": var_on / their_variance,
        "no_roulette_over_mitsuba": var_off / their_variance,
        "roulette_efficiency_gain": (var_off * time_off) / (var_on * time_on),
    }


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    machine = machine_info()
    print_machine(machine)
    results = [measure(name, args.passes, args.spp) for name in args.scenes]
    rows = [
        [
            r["scene"],
            f"{r['roulette_over_mitsuba']:.3f}",
            f"{r['no_roulette_over_mitsuba']:.3f}",
            f"{r['roulette']['mean'] / r['no_roulette']['mean']:.4f}",
            f"{r['roulette']['seconds_per_pass'] / r['no_roulette']['seconds_per_pass']:.2f}",
            f"{r['roulette_efficiency_gain']:.2f}",
            verdict(r["roulette_over_mitsuba"], TARGET, at_most=True),
        ]
        for r in results
    ]
    print_table(
        f"Variance of a sample at equal spp ({args.passes} x {args.spp} spp) over Mitsuba's",
        ["scene", "roulette", "no roulette", "mean on/off", "time on/off", "efficiency gain",
         f"<= {TARGET}"],
        rows,
    )  # fmt: skip
    write_results("roulette", {"options": vars(args), "scenes": results}, machine)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
