"""The effect plan: what it saves per sample scene, and runtime flags against specialised kernels.

For every sample scene (``scenes/*``), three contenders render the same frame in this process,
interleaved round by round after a warm-up each:

- ``all``: every effect on (``render.effect_plan: false``): the full build of the path kernel
  (material dispatch and every light kind compiled in), every flag set;
- ``plan``: the scene's effect plan (the default renderer): the build the plan needs
  (``tracer.integrators.path.kernel_for``: without the material dispatch and the non-triangle
  lights when the plan has neither) with the plan's runtime flags;
- ``specialised``: the plan, with the full build compiled for that one plan
  (``numba.literally``: every flag a constant, LLVM removes the branches they switch off;
  ``specialised_kernel`` here, run by ``render_specialised`` through the renderer's pixel loop).

Reported per scene: the effects the plan skips, median and best seconds, the speed-up of the
plan over all effects (ratio of the medians, and the median of the per-round ratios) and of
the specialised kernel over the flags, and whether the images are bit-identical (they should
be: every rule skips only work that adds zeros). Separately, in subprocesses with empty kernel
caches, the cold compile time of the flags kernel and of one specialised kernel, since a
specialised kernel is compiled (and cached) once per distinct plan.
"""

import argparse
import functools
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import (
    REPO_ROOT,
    Contender,
    Series,
    console,
    fmt_float,
    machine_info,
    print_machine,
    print_table,
    ratios,
    time_call,
    usable_cores,
    write_results,
)

COLD_SCENE = REPO_ROOT / "scenes" / "cornell-box" / "scene.json"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="Time every sample scene with all effects, with its effect plan (runtime "
        "flags) and with a kernel specialised for its plan; cold compile times of both kernels. "
        "Writes bench/results/effects.json.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--width", type=int, default=256)
    parser.add_argument("--height", type=int, default=192)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=9, help="timed rounds")
    parser.add_argument("--threads", type=int, default=usable_cores())
    parser.add_argument("--scenes", nargs="*", help="scene folder names (default: all)")
    parser.add_argument(
        "--no-specialised", action="store_true", help="skip the specialised kernels"
    )
    parser.add_argument("--no-cold", action="store_true", help="skip the cold compile timings")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    machine = machine_info()
    print_machine(machine)
    results = {"scenes": measure_scenes(args)}
    report_scenes(results["scenes"], not args.no_specialised)
    if not args.no_cold:
        results["cold"] = measure_cold(not args.no_specialised)
        report_cold(results["cold"])
    write_results("effects", {"settings": vars(args), **results}, machine)
    return 0


@functools.cache
def specialised_kernel():
    """The path kernel compiled for one plan and mode: ``numba.literally`` makes both constants,
    so numba compiles (and caches) one kernel per value and LLVM removes every branch the plan
    switches off. Kept to measure against the runtime flags (``docs/effects.md``)."""
    from numba import literally

    from tracer.integrators.path import KERNELS
    from tracer.kernel.jit import jit

    full = KERNELS[(True, True)]

    def trace_pixels_specialised(scene, camera, width, height, p0, p1, sample_start, spp,
                                 max_depth, rr_depth, seed, frame, shadow_t_max, mode, plan,
                                 first, stride, stack_node, stack_t, out_rgb, out_cost,
                                 out_rays, out_aov):  # fmt: skip
        literally(mode)
        literally(plan)
        full(scene, camera, width, height, p0, p1, sample_start, spp, max_depth, rr_depth, seed,
             frame, shadow_t_max, mode, plan, first, stride, stack_node, stack_t, out_rgb,
             out_cost, out_rays, out_aov)  # fmt: skip

    return jit(trace_pixels_specialised)


def render_specialised(scene, camera, settings, plan, threads):
    """``tracer.render.render_image`` (same line chunks, same pixel loop) with the specialised
    kernel; returns ``(rgb (H, W, 3), cost (H,))``."""
    from tracer.integrators.pixels import pixel_run, trace_run
    from tracer.integrators.registry import REGISTRY
    from tracer.render import chunk_lines

    integrator = REGISTRY[settings.integrator]
    kernel = specialised_kernel()
    width, height = camera.width, camera.height
    image = np.empty((height, width, 3), np.float32)
    cost = np.empty(height, np.int64)
    chunk = chunk_lines(camera, settings)
    for y0 in range(0, height, chunk):
        y1 = min(height, y0 + chunk)
        run = pixel_run(scene, camera, settings, y0 * width, y1 * width, 0, 0, plan.flags)
        rgb, pixel_cost, _, _ = trace_run(kernel, integrator.arguments(scene, run), run, threads)
        image[y0:y1] = rgb.reshape(y1 - y0, width, 3)
        cost[y0:y1] = pixel_cost.reshape(y1 - y0, width).sum(axis=1)
    return image, cost


def spot_lit_studio():
    """The studio scene lit by three spot lights instead of its area lights: nothing a ray can
    hit emits, so the plan drops the last vertex's continuation ray (the one rule that saves
    rays in a scene whose sample scenes all have area lights or a sky)."""
    import dataclasses

    from tracer.scene import format as fmt
    from tracer.scene.loader import load_scene

    state = load_scene(REPO_ROOT / "scenes" / "studio" / "scene.json")
    materials = {
        name: m.model_copy(update={"emission": (0.0, 0.0, 0.0)}) if hasattr(m, "emission") else m
        for name, m in state.materials.items()
    }
    spots = tuple(
        fmt.SpotLight(type="spot", position=p, look_at=(0.0, 0.5, 0.0), intensity=i,
                      cone_angle_deg=35.0, falloff_deg=10.0)
        for p, i in (((-2.0, 3.5, 2.5), (40.0, 36.0, 30.0)), ((3.0, 2.0, 2.0), (8.0, 10.0, 14.0)),
                     ((0.0, 4.0, -1.5), (15.0, 15.0, 15.0)))
    )  # fmt: skip
    return dataclasses.replace(state, materials=materials, lights=spots)


def scene_states(args: argparse.Namespace):
    """(name, state) of every sample scene, then the spot-lit studio."""
    from cli.commands.samples import sample_scene_files
    from tracer.scene.loader import load_scene

    for path in sample_scene_files(REPO_ROOT / "scenes"):
        yield path.parent.name, lambda path=path: load_scene(path)
    yield "studio-spots (bench only)", spot_lit_studio


def measure_scenes(args: argparse.Namespace) -> dict:
    from tracer.compiled.scene import compile_scene
    from tracer.integrators.effects import EffectPlan, effect_plan
    from tracer.integrators.flags import ALL, EFFECTS
    from tracer.render import render_image
    from tracer.scene.format import override

    out = {}
    for name, make in scene_states(args):
        if args.scenes and name.split()[0] not in args.scenes:
            continue
        scene = compile_scene(make())
        camera = override(scene.camera, width=args.width, height=args.height)
        settings = override(scene.render, spp=args.spp)
        plan = effect_plan(scene, settings)
        everything = EffectPlan(ALL, {})
        images = {}

        def render_image_with(scene_, camera_, settings_, plan_, threads):
            return render_image(scene_, camera_, settings_, threads=threads, plan=plan_)

        def run(which, plan_, specialised, job=(scene, camera, settings, images)):
            def go(_round):
                scene_, camera_, settings_, images_ = job
                render = render_specialised if specialised else render_image_with
                image, cost = render(scene_, camera_, settings_, plan_, args.threads)
                images_[which] = (image, int(cost.sum()))

            return go

        contenders = {
            "all": Contender(run("all", everything, False)),
            "plan": Contender(run("plan", plan, False)),
        }
        if not args.no_specialised:
            contenders["specialised"] = Contender(run("specialised", plan, True))
        warm = {}
        with console.status(f"{name}: warming up (compiles the specialised kernel if new)"):
            for key, contender in contenders.items():
                start = time.perf_counter()
                contender.run(-1)
                warm[key] = time.perf_counter() - start
        samples = args.width * args.height * args.spp
        with console.status(f"{name}: {args.repeats} rounds"):
            series = rotated(contenders, samples, args.repeats)
        entry = {
            "skipped": [e for e in EFFECTS if e not in plan.names()],
            "warm_up_seconds": warm,
            "series": {k: s.summary(1e6) for k, s in series.items()},
            "plan_vs_all": ratios(series["plan"], series["all"]),
            "identical": images["plan"][0].tobytes() == images["all"][0].tobytes(),
            "cost": {k: v[1] for k, v in images.items()},
        }
        if "specialised" in series:
            entry["specialised_vs_plan"] = ratios(series["specialised"], series["plan"])
            entry["identical_specialised"] = (
                images["specialised"][0].tobytes() == images["plan"][0].tobytes()
            )
        out[name] = entry
    return out


def rotated(contenders: dict, samples: float, repeats: int) -> dict:
    """Like ``common.interleaved``, with the contenders' order rotated every round, so none
    always runs first (or right after the same other one) on a machine whose speed drifts."""
    names = list(contenders)
    series = {name: Series(name, samples) for name in names}
    for r in range(repeats):
        for name in names[r % len(names) :] + names[: r % len(names)]:
            seconds, _ = time_call(lambda n=name, r=r: contenders[n].run(r))
            series[name].seconds.append(seconds)
    return series


def report_scenes(scenes: dict, specialised: bool) -> None:
    rows = []
    for name, e in scenes.items():
        s = e["series"]
        row = [
            name,
            str(len(e["skipped"])),
            fmt_float(e["cost"]["plan"] / e["cost"]["all"], 3),
            fmt_float(s["all"]["median_seconds"], 3),
            fmt_float(s["plan"]["median_seconds"], 3),
            fmt_float(e["plan_vs_all"]["median"], 3),
            fmt_float(e["plan_vs_all"]["paired_median"], 3),
        ]
        if specialised:
            row += [
                fmt_float(s["specialised"]["median_seconds"], 3),
                fmt_float(e["specialised_vs_plan"]["paired_median"], 3),
            ]
        row.append("yes" if e["identical"] else "NO")
        rows.append(row)
    columns = ["scene", "skipped", "work", "all s", "plan s", "speed-up", "paired"]
    if specialised:
        columns += ["specialised s", "spec./flags"]
    columns.append("same image")
    print_table(
        "Effect plan: all effects vs the plan (runtime flags) vs a specialised kernel",
        columns,
        rows,
        caption="skipped = effects the plan leaves out (listed in the JSON); work = BVH node "
        "visits and triangle tests of the plan / all effects; median seconds per render; "
        "speed-up = throughput ratio of the medians, paired = median of per-round ratios "
        "(> 1: faster); same image = plan and all effects bit-identical",
    )


COLD_SCRIPT = """
import sys, time
start = time.perf_counter()
sys.path.insert(0, "bench")
from effects import render_specialised
from tracer.compiled.scene import compile_scene
from tracer.integrators.effects import effect_plan
from tracer.scene.loader import load_scene
from tracer.render import render_image
from tracer.scene.format import override
scene = compile_scene(load_scene(sys.argv[1]))
loaded = time.perf_counter()
tiny = override(scene.camera, width=1, height=1)
settings = override(scene.render, spp=1)
if sys.argv[2] == "1":
    render_specialised(scene, tiny, settings, effect_plan(scene, settings), 1)
else:
    render_image(scene, tiny, settings, threads=1)
print(loaded - start, time.perf_counter() - loaded)
"""


def measure_cold(specialised: bool) -> dict:
    """Seconds to the first pixel with an empty kernel cache (import and compile of the scene,
    then the kernel), for the flags kernel and for one specialised kernel."""
    out = {}
    kinds = ["flags", "specialised"] if specialised else ["flags"]
    for kind in kinds:
        with tempfile.TemporaryDirectory(prefix="tilerender-effects-") as cache:
            env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
            env["TILERENDER_NUMBA_CACHE"] = cache
            flag = "1" if kind == "specialised" else "0"
            with console.status(f"cold start of the {kind} kernel"):
                result = subprocess.run(
                    [sys.executable, "-c", COLD_SCRIPT, str(COLD_SCENE), flag],
                    cwd=REPO_ROOT, env=env, capture_output=True, text=True, check=True,
                )  # fmt: skip
            load, kernel = (float(x) for x in result.stdout.split())
            out[kind] = {"load_seconds": load, "kernel_seconds": kernel}
    return out


def report_cold(cold: dict) -> None:
    rows = [
        [kind, fmt_float(v["load_seconds"]), fmt_float(v["kernel_seconds"])]
        for kind, v in cold.items()
    ]
    print_table(
        "Cold compile, empty kernel cache (Cornell box, one pixel)",
        ["kernel", "import + scene s", "first pixel s"],
        rows,
        caption="a specialised kernel compiles once per distinct plan (then it is cached)",
    )


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    np.seterr(all="ignore")
    sys.exit(main())
