"""What prefiltering the guides buys: error and seconds of the OIDN denoiser
(``tracer.post.denoise``) for each quality of the beauty, with the guides taken as they are
(``off``), the albedo alone prefiltered (``albedo``), or both prefiltered at each quality.

Each scene (``--scenes``) is rendered at ``--size`` and at each of ``--spp`` with its AOVs (the
guides), and at ``--reference-spp`` without; then every (quality, prefilter) pair denoises the
frame, in turns, for ``--repeats`` rounds. Reported: median seconds and the relative MSE
against the reference (whose own noise is in it, the same for every pair), and which prefilter
``render.denoise_prefilter`` ``auto`` picks for the scene (``tracer.post.guides``). This is the
measurement behind ``PREFILTER_QUALITY`` and the ``auto`` rule (``docs/denoising.md``, Guides
and prefiltering). Writes ``bench/results/denoise_prefilter.json``.
"""

import argparse
import itertools

import numpy as np
from common import (
    Contender,
    interleaved,
    machine_info,
    print_machine,
    print_table,
    usable_cores,
    write_results,
)
from denoise import frame_renderer


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="Error and seconds of the OIDN denoiser per quality of the beauty and of "
        "the guides' prefilters. Writes bench/results/denoise_prefilter.json.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument(
        "--scenes",
        nargs="+",
        default=["cornell-box", "cornell-spheres", "veach-mis", "textured"],
        help="folders of scenes/",
    )
    parser.add_argument("--size", default="320x180", help="WxH of the frames")
    parser.add_argument(
        "--spp", type=int, nargs="+", default=[1, 4, 16], help="samples per pixel of the frames"
    )
    parser.add_argument("--reference-spp", type=int, default=256, help="spp of the references")
    parser.add_argument("--repeats", type=int, default=3, help="timed rounds")
    parser.add_argument("--threads", type=int, default=usable_cores(), help="threads")
    parser.add_argument(
        "--lens",
        type=float,
        nargs=2,
        metavar=("RADIUS", "FOCUS"),
        help="give every scene's camera this aperture radius and focus distance (depth of field)",
    )
    args = parser.parse_args(argv)
    width, _, height = args.size.partition("x")
    args.width, args.height = int(width), int(height)
    if min(*args.spp, args.reference_spp, args.repeats, args.threads, args.width, args.height) < 1:
        parser.error("sizes, spp, --repeats and --threads must be at least 1")
    return args


PREFILTERS = ("off", "albedo", "fast", "balanced", "high")
"""The guides taken as they are, the albedo alone prefiltered (at ``PREFILTER_QUALITY``, the
normal counted clean), or both prefiltered at a quality."""


def frames(name: str, args: argparse.Namespace) -> tuple[np.ndarray, dict[int, dict]]:
    """The reference of scene ``name``, and for each of ``--spp`` the beauty (``path``) and its
    albedo and normal AOVs."""
    render, guides = frame_renderer(name, args.width, args.height, args.threads, **lens(args))
    reference = render(args.reference_spp, False).rgb.reshape(args.height, args.width, 3)
    return reference, {spp: guides(render(spp, True)) for spp in args.spp}


def lens(args: argparse.Namespace) -> dict:
    """The camera fields ``--lens`` sets (none without it)."""
    if args.lens is None:
        return {}
    return {"aperture_radius": args.lens[0], "focus_distance": args.lens[1]}


def auto_prefilters(name: str, args: argparse.Namespace) -> str:
    """What ``render.denoise_prefilter`` ``auto`` makes of scene ``name`` (with ``--lens``):
    on, albedo or off."""
    from denoise import REPO_ROOT

    from tracer.post.guides import resolve_prefilter
    from tracer.scene.format import override
    from tracer.scene.loader import load_scene

    state = load_scene(str(REPO_ROOT / "scenes" / name / "scene.json"))
    camera = override(state.camera, **lens(args))
    return resolve_prefilter(state.render, state.materials.values(), camera).denoise_prefilter


def main(argv: list[str] | None = None) -> None:
    from tracer.accuracy.error_estimate import rel_mse
    from tracer.post.denoise import PREFILTER_QUALITY, QUALITIES, denoise

    args = parse_args(argv)
    info = machine_info()
    print_machine(info)
    results, rows = [], []
    for name in args.scenes:
        reference, by_spp = frames(name, args)
        auto = auto_prefilters(name, args)
        for spp, f in by_spp.items():
            contenders, outputs = {}, {}
            for quality, prefilter in itertools.product(QUALITIES, PREFILTERS):

                def run(_round, f=f, quality=quality, prefilter=prefilter):
                    return denoise(
                        f["path"],
                        f["albedo"],
                        f["normal"],
                        quality=quality,
                        threads=args.threads,
                        prefilter={"off": False, "albedo": ("albedo",)}.get(prefilter, True),
                        prefilter_quality=None if prefilter in ("off", "albedo") else prefilter,
                    )

                key = f"{quality}/{prefilter}"
                contenders[key] = Contender(run)
                outputs[key] = run(-1).image  # a warm-up, and the image (the same every call)
            series = interleaved(contenders, dict.fromkeys(contenders, 1.0), args.repeats)
            noisy = rel_mse(f["path"], reference)
            for key, measured in series.items():
                quality, prefilter = key.split("/")
                error = rel_mse(outputs[key], reference)
                chosen = prefilter == (PREFILTER_QUALITY[quality] if auto == "on" else auto)
                results.append(
                    {
                        "scene": name,
                        "spp": spp,
                        "quality": quality,
                        "prefilter": prefilter,
                        "auto": chosen,
                        "median_seconds": measured.median_seconds,
                        "rel_mse": error,
                        "noisy_rel_mse": noisy,
                    }
                )
                rows.append(
                    (
                        name,
                        str(spp),
                        quality,
                        prefilter + (" (auto)" if chosen else ""),
                        f"{measured.median_seconds:.3f}",
                        f"{error:.5f}",
                        f"{noisy:.4f}",
                    )
                )
    print_table(
        f"OIDN guided by the AOVs, as they are or prefiltered, {args.size}, {args.threads} "
        f"threads, {args.repeats} rounds; relMSE against {args.reference_spp} spp"
        + (f"; lens {args.lens[0]:g} focused at {args.lens[1]:g}" if args.lens else ""),
        ["scene", "spp", "quality", "prefilter", "median s", "relMSE", "raw relMSE"],
        rows,
    )
    write_results("denoise_prefilter", {"options": vars(args), "results": results}, info)


if __name__ == "__main__":
    main()
