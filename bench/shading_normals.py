"""What shading normals and normal maps cost where a scene has them.

Sample scenes with spheres (``cornell-spheres``, ``environment``, ``many-lights``,
``outdoor``) are loaded with every sphere made ``smooth`` and rendered in this process two
ways, interleaved round by round after a warm-up each: ``smooth``, the scene's own plan (its
vertex normals interpolated at every hit on a sphere), and ``flat``, the same compiled scene
with the ``shading_normals`` effect switched off (``render.effects``), which is exactly the
flat scene's image. ``textured+map`` is the sample ``textured`` (copied to a temporary folder)
with a bumpy normal map on every material that has a texture and on the wall (a rectangle,
with UVs), timed with and without the ``normal_maps`` effect. Reported per scene: the share of
the image's camera hits on smooth or mapped surfaces, median and best seconds, and the
throughput with the effect over without (ratio of the medians and median of per-round
ratios). Targets (issue #25): shading normals cost at most 5% where a scene has them, normal
maps at most 10%. That flat scenes pay nothing is ``bench/compare_trees.py``'s job
(against a tree from before shading normals; their images are bit-identical).
"""

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
from common import (
    REPO_ROOT,
    Contender,
    console,
    fmt_float,
    interleaved,
    machine_info,
    print_machine,
    print_table,
    ratios,
    usable_cores,
    verdict,
    write_results,
)

SCENES = ("cornell-spheres", "environment", "many-lights", "outdoor", "textured+map")
TARGETS = {"shading_normals": 0.95, "normal_maps": 0.90}
"""Throughput with the effect over without, at least."""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="Time sample scenes with smooth spheres against the same scenes shading "
        "flat (the shading_normals effect off), interleaved. Writes "
        "bench/results/shading_normals.json.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--width", type=int, default=256)
    parser.add_argument("--height", type=int, default=192)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=9, help="timed rounds")
    parser.add_argument("--threads", type=int, default=usable_cores())
    parser.add_argument("--scenes", nargs="*", default=list(SCENES), help="scene folder names")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    return args


def mapped_scene(work: Path):
    """The sample ``textured`` copied into ``work`` with a bumpy normal map (``bumps.png``) on
    its textured materials and its wall."""
    import shutil

    from PIL import Image

    from tracer.compiled.scene import compile_scene
    from tracer.scene.loader import load_scene

    folder = work / "textured"
    shutil.copytree(REPO_ROOT / "scenes" / "textured", folder)
    y, x = np.mgrid[0:64, 0:64] / 64.0 * 2.0 * np.pi
    slope = np.stack([0.4 * np.cos(4 * x) * np.sin(4 * y), 0.4 * np.sin(4 * x) * np.cos(4 * y),
                      np.ones_like(x)], axis=-1)  # fmt: skip
    slope /= np.linalg.norm(slope, axis=-1, keepdims=True)
    Image.fromarray(np.rint((slope + 1.0) * 127.5).astype(np.uint8)).save(folder / "bumps.png")
    data = json.loads((folder / "scene.json").read_text(encoding="utf-8"))
    for name, material in data["materials"].items():
        if "texture" in material or name == "wall":
            material["normal_map"] = {"file": "bumps.png", "scale": [4, 4]}
    (folder / "scene.json").write_text(json.dumps(data), encoding="utf-8")
    return compile_scene(load_scene(folder / "scene.json"))


def smooth_scene(name: str):
    """Sample scene ``name`` compiled with every sphere ``smooth``."""
    from tracer.compiled.scene import compile_scene
    from tracer.scene.format import SceneFile
    from tracer.scene.loader import scene_from_file_model

    folder = REPO_ROOT / "scenes" / name
    data = json.loads((folder / "scene.json").read_text(encoding="utf-8"))
    spheres = 0
    for obj in data["objects"]:
        shape = obj.get("shape")
        if isinstance(shape, dict) and shape.get("type") == "sphere":
            shape["smooth"] = True
            spheres += 1
    if not spheres:
        raise SystemExit(f"{name}: the scene has no sphere to make smooth")
    return compile_scene(scene_from_file_model(SceneFile.model_validate(data), Path(folder)))


def smooth_hit_share(scene, camera) -> float:
    """The share of one-sample camera rays that hit a triangle with vertex normals or a
    material with a normal map."""
    from tracer.integrators import aov
    from tracer.render import render_pixels
    from tracer.scene.format import override

    settings = override(scene.render, spp=1, aovs=True)
    out = render_pixels(scene, 0, camera.width * camera.height, camera, settings).aov
    ids = out[:, aov.OBJECT_ID].astype(np.int64)
    state = scene.state
    smooth_nodes = [
        n.id
        for n in state.geometry_nodes()
        if state.meshes[n.mesh].normals is not None
        or getattr(state.materials[n.material], "normal_map", None) is not None
    ]
    return float(np.isin(ids, smooth_nodes).mean())


def measure(args: argparse.Namespace) -> dict:
    from tracer.render import render_image
    from tracer.scene.format import override

    out = {}
    work = Path(tempfile.mkdtemp(prefix="shading-normals-"))
    for name in args.scenes:
        effect = "normal_maps" if name.endswith("+map") else "shading_normals"
        scene = mapped_scene(work) if effect == "normal_maps" else smooth_scene(name)
        camera = override(scene.camera, width=args.width, height=args.height)
        smooth = override(scene.render, spp=args.spp)
        flat = override(smooth, effects={**smooth.effects, effect: False})
        images = {}

        def run(which, settings, job=(scene, camera, images)):
            def go(_round):
                scene_, camera_, images_ = job
                images_[which] = render_image(scene_, camera_, settings, threads=args.threads)[0]

            return go

        contenders = {"smooth": Contender(run("smooth", smooth)),
                      "flat": Contender(run("flat", flat))}  # fmt: skip
        with console.status(f"{name}: warming up"):
            for contender in contenders.values():
                contender.run(-1)
        samples = args.width * args.height * args.spp
        with console.status(f"{name}: {args.repeats} rounds"):
            series = interleaved(contenders, {k: samples for k in contenders}, args.repeats)
        out[name] = {
            "effect": effect,
            "smooth_hit_share": smooth_hit_share(scene, camera),
            "series": {k: s.summary(1e6) for k, s in series.items()},
            "smooth_vs_flat": ratios(series["smooth"], series["flat"]),
            "images_differ": images["smooth"].tobytes() != images["flat"].tobytes(),
        }
    return out


def report(results: dict, args: argparse.Namespace) -> None:
    rows = []
    for name, r in results.items():
        ratio = r["smooth_vs_flat"]
        rows.append((
            name,
            f"{100 * r['smooth_hit_share']:.0f}%",
            fmt_float(r["series"]["flat"]["median_seconds"], 3),
            fmt_float(r["series"]["smooth"]["median_seconds"], 3),
            fmt_float(ratio["median"], 3),
            fmt_float(ratio["paired_median"], 3),
            verdict(ratio["paired_median"], TARGETS[r["effect"]]),
        ))  # fmt: skip
    print_table(
        f"shading normals and normal maps, {args.width}x{args.height}, {args.spp} spp, "
        f"{args.threads} threads, "
        f"{args.repeats} rounds",
        ["scene", "hits smooth", "off s", "on s", "on/off", "paired", "target"],
        rows,
        caption="throughput with the effect over the same scene without it (targets: shading "
        "normals >= 0.95, normal maps >= 0.90)",
    )


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    machine = machine_info()
    print_machine(machine)
    results = measure(args)
    report(results, args)
    write_results("shading_normals", {"settings": vars(args), "scenes": results}, machine)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
