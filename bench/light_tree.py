"""Many-light sampling (issue #26 item 2): render seconds to a relative MSE of 1e-2 in
progressive frames with light samples picked by power and by the light tree, side by side,
against each scene's shared reference (``cli/accuracy_reference.py``).

Frames run as ``bench/adaptive.py`` runs them (its ``frame_run``, adaptive sampling off, so only
the light sampler differs), at the accuracy study's size (about ``--pixels`` pixels). A scene
without an independent reference gets our own (``--reference-spp`` samples per pixel in 16
passes, cached). The two samplers run interleaved, the first alternating, for ``--repeats``
rounds, each round on a seed of its own; the table gives medians, the median of the per-round
ratios power / tree, and what ``render.light_sampler`` ``auto`` picks for the scene.
"""

import argparse
import statistics

from adaptive import TARGET, frame_run, setup, study_arguments, time_to
from common import (
    machine_info,
    print_machine,
    print_table,
    styled_verdict,
    verdict,
    write_results,
)

from tracer.integrators.effects import effect_plan
from tracer.scene import format as fmt

SCENES = ("lamp-hall", "many-lights", "veach-mis", "cornell-box")
SAMPLERS = ("power", "tree")
SPEEDUP = 5.0
"""Target on the scene with thousands of lights: time by power over time with the tree."""
SLOWDOWN = 1.05
"""No scene slower than this with the sampler ``auto`` picks."""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = study_arguments(__doc__.split("\n\n")[0], SCENES, 3)
    parser.add_argument(
        "--reference-spp", type=int, default=4096, help="own references' spp (default 4096)"
    )
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    info = machine_info()
    print_machine(info)
    results = {}
    for name in args.scenes:
        scene, camera, settings, ref, floor = setup(
            name, args.pixels, args.threads, args.reference_spp
        )
        auto = effect_plan(scene, fmt.override(settings, light_sampler="auto")).to_json()
        runs = {sampler: [] for sampler in SAMPLERS}
        for sampler in SAMPLERS:  # warm: kernels and the tree
            warm = fmt.override(settings, spp=1, light_sampler=sampler)
            frame_run(scene, camera, warm, ref, floor, "off", 8, 1)
        for round_index in range(args.repeats):
            seeded = fmt.override(settings, seed=settings.seed + 7919 * round_index)
            order = SAMPLERS if round_index % 2 == 0 else SAMPLERS[::-1]
            for sampler in order:
                chosen = fmt.override(seeded, light_sampler=sampler)
                runs[sampler].append(
                    frame_run(scene, camera, chosen, ref, floor, "off", args.max_spp, args.threads)
                )
        results[name] = summarise(runs, camera, floor, auto)
    report(results)
    write_results("light_tree", {"options": vars(args), "scenes": results}, info)
    return 0


def summarise(runs: dict[str, list], camera, floor: float, auto: dict) -> dict:
    """Per sampler: seconds and spp to the target per round and their medians; the paired
    ratio power / tree; the sampler ``auto`` picks and why."""
    out = {
        "size": [camera.width, camera.height],
        "noise_floor": floor,
        "auto": auto["light_sampler"],
        "auto_reason": auto["reasons"]["light_tree"],
        "samplers": {},
    }
    for sampler, frames in runs.items():
        seconds = [time_to(r, TARGET) for r in frames]
        spp = [time_to(r, TARGET, "mean_spp") for r in frames]
        out["samplers"][sampler] = {
            "seconds": seconds,
            "spp": spp,
            "median_seconds": _median(seconds),
            "median_spp": _median(spp),
            "records": frames,
        }
    power, tree = (out["samplers"][s]["seconds"] for s in SAMPLERS)
    out["speedup_paired_median"] = _median(
        [a / b for a, b in zip(power, tree, strict=True) if a and b]
    )
    return out


def _median(values: list) -> float | None:
    known = [v for v in values if v is not None]
    return statistics.median(known) if known else None


def report(results: dict) -> None:
    rows = []
    for name, result in results.items():
        samplers = result["samplers"]
        speedup = result["speedup_paired_median"] or 0.0
        auto_speedup = speedup if result["auto"] == "tree" else 1.0
        rows.append(
            [
                name,
                "x".join(map(str, result["size"])),
                *(_fmt(samplers[s]["median_seconds"], 2) for s in SAMPLERS),
                *(_fmt(samplers[s]["median_spp"], 0) for s in SAMPLERS),
                _fmt(speedup, 2),
                result["auto"],
                styled_verdict(verdict(auto_speedup, 1 / SLOWDOWN)),
            ]
        )
    print_table(
        f"Render seconds to relMSE {TARGET:g}, progressive frames, adaptive sampling off",
        [
            "scene", "size", "s power", "s tree", "spp power", "spp tree", "power/tree",
            "auto picks", f"auto >= 1/{SLOWDOWN:g}",
        ],
        rows,
        caption=f"medians over the rounds; power/tree: median of the per-round ratios (target "
        f">= {SPEEDUP:g} on lamp-hall)",
    )  # fmt: skip


def _fmt(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


if __name__ == "__main__":
    raise SystemExit(main())
