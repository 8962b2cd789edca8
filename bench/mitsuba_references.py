"""Mitsuba 3 reference images of the sample scenes and of the cross-check scenes (scenes/mitsuba/).

For each scene: export it with ``tracer.crosscheck.mitsuba_export`` at the reference size (the
scene's own size divided by a whole factor, about 12,000 pixels), render ``--passes`` independent
passes of
``--spp`` samples with Mitsuba (seeds 0, 1, ...), and store next to the scene file:

- ``mitsuba_mean.npy``: float32 (H, W, 3) linear RGB, row 0 at the top: the mean of the passes;
- ``mitsuba_var_of_mean.npy``: float32 (H, W, 3): the variance of that mean (the spread of the
  passes divided by their number);
- ``mitsuba.json``: how they were made (size, passes, spp, seeds, variant, Mitsuba version, the
  export's deviations, hashes of the scene's files and of the exported XML, seconds).

``tests/tracer/test_mitsuba_agreement.py`` compares tilerender with these files; Mitsuba is not
needed to run the tests. The script also writes ``bench/results/mitsuba_references.json``.
Mitsuba is optional (``pip install mitsuba``); its LLVM variant needs a libLLVM that can select
``fminimum`` (``bench/get_libllvm.sh``), else use ``--variant scalar_rgb`` (about 3x slower).
"""

import argparse
import dataclasses
import hashlib
import importlib.util
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import (
    REPO_ROOT,
    console,
    machine_info,
    note,
    package_version,
    print_machine,
    print_table,
    usable_cores,
    write_results,
)

SCENES_DIR = REPO_ROOT / "scenes"
SCENES = {
    "cornell-box": ("cornell-box/scene.json", 2),
    "cornell-spheres": ("cornell-spheres/scene.json", 2),
    "veach-mis": ("veach-mis/scene.json", 4),
    "many-lights": ("many-lights/scene.json", 4),
    "studio": ("studio/scene.json", 4),
    "nefertiti": ("nefertiti/scene.json", 4),
    "outdoor": ("outdoor/scene.json", 4),
    "gltf-box": ("gltf-box/Box.gltf", 5),
    "environment": ("environment/scene.json", 4),
    "textured": ("textured/scene.json", 2),
    "mitsuba/outdoor": ("mitsuba/outdoor/scene.json", 4),
    "mitsuba/many-lights": ("mitsuba/many-lights/scene.json", 4),
    "mitsuba/lamps": ("mitsuba/lamps/scene.json", 4),
    "mitsuba/sun": ("mitsuba/sun/scene.json", 4),
    "mitsuba/textured": ("mitsuba/textured/scene.json", 2),
    "mitsuba/environment": ("mitsuba/environment/scene.json", 2),
    "mitsuba/smooth": ("mitsuba/smooth/scene.json", 3),
    "mitsuba/normal-map": ("mitsuba/normal-map/scene.json", 3),
    "mitsuba/alpha-card": ("mitsuba/alpha-card/scene.json", 2),
}
"""Name -> (scene file under scenes/, factor the reference's size is divided by)."""
MEAN_FILE = "mitsuba_mean.npy"
VAR_FILE = "mitsuba_var_of_mean.npy"
RECORD_FILE = "mitsuba.json"
EXPORT_FILE = "mitsuba_export.xml"
"""The exported XML the reference was rendered from (the agreement test compares the current
export with it, numbers within a relative 1e-9: their last digits depend on the CPU)."""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="Render Mitsuba 3 references (mean and variance of the mean) of the sample "
        "and cross-check scenes and store them next to each scene file.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument(
        "--scenes",
        default=",".join(SCENES),
        help=f"comma-separated scene names, from: {', '.join(SCENES)}",
    )
    parser.add_argument("--passes", type=int, default=16, help="independent passes per scene")
    parser.add_argument("--spp", type=int, default=1024, help="samples per pixel per pass")
    parser.add_argument(
        "--variant", default="llvm_ad_rgb", help="Mitsuba variant (llvm_ad_rgb or scalar_rgb)"
    )
    parser.add_argument("--threads", type=int, default=usable_cores(), help="Mitsuba threads")
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="write the files under this directory (OUT/NAME/) instead of next to the scenes",
    )
    parser.add_argument(
        "--keep-export",
        type=Path,
        default=None,
        help="keep the exported Mitsuba scenes under this directory (KEEP/NAME/scene.xml)",
    )
    args = parser.parse_args(argv)
    for name in ("passes", "spp", "threads"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be at least 1")
    if args.passes < 2:
        parser.error("--passes must be at least 2 (the variance comes from their spread)")
    args.scenes = [s for s in args.scenes.split(",") if s]
    unknown = [s for s in args.scenes if s not in SCENES]
    if unknown:
        parser.error(f"unknown scene(s) {', '.join(unknown)}; known: {', '.join(SCENES)}")
    return args


def reference_state(scene_file: Path, factor: int):
    """The loaded scene with its camera at the reference size (its size divided by ``factor``)."""
    from tracer.scene import format as fmt
    from tracer.scene.loader import load_scene

    state = load_scene(scene_file)
    camera = state.camera
    if camera.width % factor or camera.height % factor:
        size = f"{camera.width}x{camera.height}"
        raise SystemExit(f"{scene_file}: {size} is not divisible by {factor}")
    size = {"width": camera.width // factor, "height": camera.height // factor}
    return dataclasses.replace(state, camera=fmt.override(camera, **size))


def render_passes(mi, xml_path: Path, passes: int, spp: int) -> tuple[np.ndarray, float]:
    """``passes`` renders (seeds 0..passes-1) as float64 (P, H, W, 3), and their seconds."""
    scene = mi.load_file(str(xml_path))
    images = []
    start = time.perf_counter()
    for seed in range(passes):
        images.append(np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float64))
    return np.stack(images), time.perf_counter() - start


def make_reference(mi, name: str, args: argparse.Namespace, export_root: Path) -> dict:
    """Export, render and store one scene's reference; its record."""
    from tracer.crosscheck.mitsuba_export import export_scene, scene_inputs_digest

    relative, factor = SCENES[name]
    scene_file = SCENES_DIR / relative
    state = reference_state(scene_file, factor)
    exported = export_scene(state, export_root / name)
    with console.status(f"{name}: {args.passes} passes of {args.spp} spp"):
        images, seconds = render_passes(mi, exported.xml_path, args.passes, args.spp)
    if not np.isfinite(images).all():
        raise SystemExit(f"{name}: Mitsuba returned non-finite pixels")
    mean = images.mean(axis=0)
    var_of_mean = images.var(axis=0, ddof=1) / args.passes
    out = scene_file.parent if args.out is None else args.out / name
    out.mkdir(parents=True, exist_ok=True)
    np.save(out / MEAN_FILE, mean.astype(np.float32))
    np.save(out / VAR_FILE, var_of_mean.astype(np.float32))
    (out / EXPORT_FILE).write_text(exported.xml)
    height, width = mean.shape[:2]
    record = {
        "scene": relative,
        "renderer": f"Mitsuba {package_version('mitsuba')}",
        "variant": args.variant,
        "integrator": exported.integrator,
        "width": width,
        "height": height,
        "downscale": factor,
        "passes": args.passes,
        "spp_per_pass": args.spp,
        "seeds": list(range(args.passes)),
        "max_depth": state.render.max_depth,
        "rr_depth": state.render.rr_depth,
        "deviations": [dataclasses.asdict(d) for d in exported.deviations],
        "scene_inputs_sha256": scene_inputs_digest(scene_file),
        "export_xml_sha256": hashlib.sha256(exported.xml.encode()).hexdigest(),
        "render_seconds": round(seconds, 2),
        "threads": args.threads,
    }
    (out / RECORD_FILE).write_text(json.dumps(record, indent=2) + "\n")
    return record


def import_mitsuba(variant: str, threads: int):
    """Mitsuba with ``variant`` set (before any numba import: Dr.Jit must load its libLLVM
    first), or exit with the reason it cannot run."""
    if importlib.util.find_spec("mitsuba") is None:
        raise SystemExit("Mitsuba 3 is not installed (pip install mitsuba)")
    if variant.startswith("llvm_"):
        from cornell import llvm_ready

        if not llvm_ready(variant):
            raise SystemExit(f"{variant} cannot run here (see the note); try --variant scalar_rgb")
    import drjit as dr
    import mitsuba as mi

    if variant not in mi.variants():
        raise SystemExit(f"Mitsuba has no variant {variant!r} (it has {', '.join(mi.variants())})")
    mi.set_variant(variant)
    dr.set_thread_count(threads)
    return mi


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    machine = machine_info()
    print_machine(machine)
    mi = import_mitsuba(args.variant, args.threads)
    records = {}
    with tempfile.TemporaryDirectory(prefix="mitsuba-export-") as tmp:
        export_root = args.keep_export or Path(tmp)
        for name in args.scenes:
            records[name] = make_reference(mi, name, args, export_root)
            r = records[name]
            samples = r["width"] * r["height"] * r["passes"] * r["spp_per_pass"]
            console.print(
                f"{name}: {r['width']}x{r['height']}, {r['render_seconds']:.1f} s, "
                f"{samples / r['render_seconds'] / 1e6:.2f} Msamples/s"
            )
    rows = []
    for name, r in records.items():
        samples = r["width"] * r["height"] * r["passes"] * r["spp_per_pass"]
        kinds = [d["kind"] for d in r["deviations"]]
        deviations = f"{kinds.count('model')} / {kinds.count('proxy')}"
        rows.append(
            [
                name,
                f"{r['width']}x{r['height']}",
                r["integrator"],
                f"{r['render_seconds']:.1f}",
                f"{samples / r['render_seconds'] / 1e6:.2f}",
                deviations,
            ]
        )
    print_table(
        f"Mitsuba references: {args.passes} passes x {args.spp} spp, {args.variant}, "
        f"{args.threads} threads",
        ["scene", "size", "integrator", "seconds", "Msamples/s", "model / proxy deviations"],
        rows,
        caption="deviations: where the export is not exactly our scene (listed in each "
        "mitsuba.json; docs/mitsuba.md). The machine may be shared: seconds are for the "
        "record, not a speed comparison",
    )
    if args.out is not None:
        note(f"references written under {args.out}, not next to the scenes")
    machine["mitsuba"] = package_version("mitsuba")
    options = {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()}
    write_results("mitsuba_references", {"options": options, "scenes": records}, machine)
    return 0


if __name__ == "__main__":
    sys.exit(main())
