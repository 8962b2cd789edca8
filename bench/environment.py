"""Environment maps: what an environment-lit render costs, and what importance sampling saves.

Cost: ``scenes/environment`` rendered three ways in this process, interleaved round by round
after a warm-up each, at equal samples: under its HDR map (``map``), under a map of the same
size holding the map's mean radiance everywhere (``flat map``: the lookup and sampling code
with the paths of a constant sky), and under a ``constant`` sky of that mean radiance (the
sky's original code). Reported: samples/s, and the cost of the two maps relative to the
constant sky (ratio of median seconds; > 1 is slower).

Variance: the map's light samples drawn from its importance tables (luminance * sin(theta))
against near-uniform tables (sin(theta) only: every direction about equally likely), at equal
samples per pixel; the per-pixel variance of independent passes, averaged over the image, for
direct light (``max_depth`` 2) and full paths, over the image and by the material each pixel's
centre sees. Both estimate the same image (checked by the image means). The ratio uniform /
importance is the factor of samples importance sampling saves at equal noise (both use the same
code, so about the same time per sample).
"""

import argparse
import dataclasses

import numpy as np
from common import (
    REPO_ROOT,
    Contender,
    fmt_float,
    interleaved,
    machine_info,
    print_machine,
    print_table,
    usable_cores,
    write_results,
)

from tracer.compiled.scene import compile_scene
from tracer.render import render_image
from tracer.scene import format as fmt
from tracer.scene.environment import EnvironmentMap
from tracer.scene.format import override
from tracer.scene.loader import load_scene
from tracer.shading import lights
from tracer.shading.environment_light import sampling_tables

SCENE = REPO_ROOT / "scenes" / "environment" / "scene.json"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="Cost of an environment-lit render against a constant sky of the same mean, "
        "and the variance importance sampling saves against near-uniform sampling. Writes "
        "bench/results/environment.json.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--width", type=int, default=240)
    parser.add_argument("--height", type=int, default=160)
    parser.add_argument("--spp", type=int, default=16, help="samples per timed render")
    parser.add_argument("--repeats", type=int, default=7, help="timed rounds")
    parser.add_argument("--passes", type=int, default=16, help="passes for the variance")
    parser.add_argument("--pass-spp", type=int, default=4, help="samples per variance pass")
    parser.add_argument("--threads", type=int, default=usable_cores())
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    machine = machine_info()
    print_machine(machine)
    state = load_scene(SCENE)
    camera = override(state.camera, width=args.width, height=args.height)
    scenes = sky_variants(state)
    cost = measure_cost(scenes, camera, args)
    variance = measure_variance(scenes["map"], camera, args)
    write_results("environment", {"options": vars(args), "cost": cost, "variance": variance},
                  machine)  # fmt: skip


def sky_variants(state) -> dict:
    """The sample scene compiled under its map, a flat map of its mean and a constant sky."""
    sky = state.sky
    mean = lights.mean_sky_radiance(sky)
    flat = EnvironmentMap(sky.model, np.broadcast_to(np.float32(mean) / np.float32(
        sky.model.scale), sky.image.shape).copy())  # fmt: skip
    flat.image.setflags(write=False)
    constant = fmt.ConstantSky(radiance=mean)
    return {
        "map": compile_scene(state),
        "flat map": compile_scene(dataclasses.replace(state, sky=flat)),
        "constant": compile_scene(dataclasses.replace(state, sky=constant)),
    }


def measure_cost(scenes: dict, camera, args) -> dict:
    settings = override(scenes["map"].render, spp=args.spp)
    samples = args.width * args.height * args.spp
    contenders = {
        name: Contender(
            lambda r, s=scene: render_image(
                s, camera, override(settings, seed=r + 1), threads=args.threads
            )
        )
        for name, scene in scenes.items()
    }
    for contender in contenders.values():
        contender.run(0)  # warm-up: kernels compiled or loaded
    means = {}

    def record(name, _round, value):
        means.setdefault(name, []).append(float(value[0].mean()))

    series = interleaved(contenders, dict.fromkeys(scenes, samples), args.repeats, record)
    base = series["constant"]
    paired = {
        name: float(np.median(np.divide(s.seconds, base.seconds))) for name, s in series.items()
    }
    rows = [
        (name, fmt_float(s.median_rate / 1e6, 3), fmt_float(s.best_rate / 1e6, 3),
         fmt_float(s.median_seconds, 3), fmt_float(s.median_seconds / base.median_seconds, 3),
         fmt_float(paired[name], 3), fmt_float(float(np.mean(means[name])), 4))
        for name, s in series.items()
    ]  # fmt: skip
    print_table(
        f"Cost: scenes/environment, {args.width}x{args.height}, {args.spp} spp, "
        f"{args.threads} threads, {args.repeats} rounds",
        ["sky", "Msamples/s median", "best", "median s", "s / constant", "paired", "image mean"],
        rows,
        caption="flat map: the map's code with the map's mean radiance everywhere; s / constant: "
        "ratio of median seconds, paired: median of the per-round ratios (> 1: slower)",
    )
    return {
        name: {**s.summary(1e6), "cost_vs_constant": s.median_seconds / base.median_seconds,
               "paired_cost_vs_constant": paired[name],
               "image_mean": float(np.mean(means[name]))}
        for name, s in series.items()
    }  # fmt: skip


def uniform_tables(scene):
    """The compiled scene with near-uniform sampling tables for its map."""
    sky = scene.state.sky
    table = scene.lights._replace(
        sky_tables=sampling_tables(sky.image, sky.model.scale, by_luminance=False)
    )
    arrays = scene.arrays._replace(**lights.scene_fields(lights.light_arrays(table)))
    return dataclasses.replace(scene, lights=table, arrays=arrays)


def passes(scene, camera, settings, count: int, threads: int) -> np.ndarray:
    return np.stack(
        [
            render_image(scene, camera, settings, sample_start=k * settings.spp, threads=threads)[0]
            for k in range(count)
        ]
    ).astype(np.float64)


def pixel_materials(scene, camera) -> np.ndarray:
    """The material each pixel's centre sees ("sky" where the ray escapes), (H, W)."""
    from tracer.geometry.query import scene_hits
    from tracer.shading.camera import camera_array, primary_ray

    w, h = camera.width, camera.height
    cam = camera_array(camera.position, camera.look_at, camera.up, camera.vfov_deg, w, h)
    rays = [primary_ray(cam, w, h, x + 0.5, y + 0.5) for y in range(h) for x in range(w)]
    hits = scene_hits(scene, np.array([o for o, _ in rays]), np.array([d for _, d in rays]))
    return np.array([m or "sky" for m in hits.material], dtype=object).reshape(h, w)


def measure_variance(scene, camera, args) -> dict:
    uniform = uniform_tables(scene)
    materials = pixel_materials(scene, camera)
    results = {}
    rows = []
    by_material = []
    for label, depth in (("direct (max_depth 2)", 2), ("path (max_depth 8)", 8)):
        settings = override(scene.render, spp=args.pass_spp, max_depth=depth)
        a = passes(scene, camera, settings, args.passes, args.threads)
        b = passes(uniform, camera, override(settings, seed=1), args.passes, args.threads)
        # The mean over pixels, not a median: near-uniform samples find the sun so rarely that
        # most pixels' sample variance misses it, and a few pixels carry all of it.
        pixel_a = a.var(axis=0, ddof=1).mean(axis=2)
        pixel_b = b.var(axis=0, ddof=1).mean(axis=2)
        var_a, var_b = pixel_a.mean(), pixel_b.mean()
        split = {}
        for name in sorted(set(materials.ravel())):
            mask = materials == name
            split[name] = {"pixels": int(mask.sum()), "variance_importance": pixel_a[mask].mean(),
                           "variance_uniform": pixel_b[mask].mean()}  # fmt: skip
            va, vb = pixel_a[mask].mean(), pixel_b[mask].mean()
            by_material.append(
                (label, name, int(mask.sum()), f"{va:.3e}", f"{vb:.3e}", fmt_float(vb / va, 1))
            )
        mean_a, mean_b = a.mean(), b.mean()
        se = np.sqrt(a.mean(axis=(1, 2, 3)).var(ddof=1) / args.passes
                     + b.mean(axis=(1, 2, 3)).var(ddof=1) / args.passes)  # fmt: skip
        results[label] = {
            "variance_importance": var_a,
            "variance_uniform": var_b,
            "ratio": var_b / var_a,
            "mean_importance": mean_a,
            "mean_uniform": mean_b,
            "mean_z": (mean_a - mean_b) / se,
            "by_material": split,
        }
        rows.append((label, f"{var_a:.3e}", f"{var_b:.3e}", fmt_float(var_b / var_a, 1),
                     fmt_float(mean_a, 4), fmt_float(mean_b, 4),
                     fmt_float((mean_a - mean_b) / se, 2)))  # fmt: skip
    print_table(
        f"Variance at equal samples: {args.passes} passes of {args.pass_spp} spp, "
        f"{args.width}x{args.height}",
        ["render", "var importance", "var uniform", "uniform / importance", "mean imp.",
         "mean unif.", "z"],
        rows,
        caption="var: per-pixel variance of a pass, averaged over the image and channels; z: "
        "difference of the image means in standard errors",
    )  # fmt: skip
    print_table(
        "Variance by what the pixel centre sees",
        ["render", "material", "pixels", "var importance", "var uniform", "uniform / importance"],
        by_material,
        caption="the chrome ball mirrors the sun: its noise comes from the camera ray's jitter "
        "across the sun's reflection, which no light sampling changes",
    )
    return results


if __name__ == "__main__":
    main()
