"""What the quality of the guides' prefilters buys: error and seconds of the OIDN denoiser
(``tracer.post.denoise``) for each quality of the beauty and of the prefilters.

Each scene (``--scenes``) is rendered at ``--size`` and ``--spp`` with its AOVs (the guides),
and at ``--reference-spp`` without; then every (quality, prefilter quality) pair denoises the
frame, in turns, for ``--repeats`` rounds. Reported: median seconds and the relative MSE
against the reference (whose own noise is in it, the same for every pair). This is the
measurement behind ``PREFILTER_QUALITY`` (``docs/denoising.md``, Guides and prefiltering).
Writes ``bench/results/denoise_prefilter.json``.
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
        "--scenes", nargs="+", default=["textured", "cornell-spheres"], help="folders of scenes/"
    )
    parser.add_argument("--size", default="320x180", help="WxH of the frames")
    parser.add_argument("--spp", type=int, default=4, help="samples per pixel of the frames")
    parser.add_argument("--reference-spp", type=int, default=256, help="spp of the references")
    parser.add_argument("--repeats", type=int, default=3, help="timed rounds")
    parser.add_argument("--threads", type=int, default=usable_cores(), help="threads")
    args = parser.parse_args(argv)
    width, _, height = args.size.partition("x")
    args.width, args.height = int(width), int(height)
    if min(args.spp, args.reference_spp, args.repeats, args.threads, args.width, args.height) < 1:
        parser.error("sizes, spp, --repeats and --threads must be at least 1")
    return args


def frames(name: str, args: argparse.Namespace) -> dict[str, np.ndarray]:
    """The beauty (``path``), its albedo and normal AOVs, and the reference of scene ``name``."""
    render, guides = frame_renderer(name, args.width, args.height, args.threads)
    reference = render(args.reference_spp, False).rgb.reshape(args.height, args.width, 3)
    return {**guides(render(args.spp, True)), "reference": reference}


def main(argv: list[str] | None = None) -> None:
    from tracer.accuracy.error_estimate import rel_mse
    from tracer.post.denoise import PREFILTER_QUALITY, QUALITIES, denoise

    args = parse_args(argv)
    info = machine_info()
    print_machine(info)
    results, rows = [], []
    for name in args.scenes:
        f = frames(name, args)
        contenders, outputs = {}, {}
        for quality, guide_quality in itertools.product(QUALITIES, QUALITIES):

            def run(_round, f=f, quality=quality, guide_quality=guide_quality):
                return denoise(
                    f["path"],
                    f["albedo"],
                    f["normal"],
                    quality=quality,
                    threads=args.threads,
                    prefilter_quality=guide_quality,
                )

            key = f"{quality}/{guide_quality}"
            contenders[key] = Contender(run)
            outputs[key] = run(-1).image  # a warm-up, and the image (the same every call)
        series = interleaved(contenders, dict.fromkeys(contenders, 1.0), args.repeats)
        noisy = rel_mse(f["path"], f["reference"])
        for key, measured in series.items():
            quality, guide_quality = key.split("/")
            error = rel_mse(outputs[key], f["reference"])
            default = PREFILTER_QUALITY[quality] == guide_quality
            results.append(
                {
                    "scene": name,
                    "quality": quality,
                    "prefilter_quality": guide_quality,
                    "default": default,
                    "median_seconds": measured.median_seconds,
                    "rel_mse": error,
                    "noisy_rel_mse": noisy,
                }
            )
            rows.append(
                (
                    name,
                    quality,
                    guide_quality + (" (default)" if default else ""),
                    f"{measured.median_seconds:.3f}",
                    f"{error:.5f}",
                )
            )
    print_table(
        f"OIDN guided by prefiltered AOVs, {args.size} at {args.spp} spp, {args.threads} threads, "
        f"{args.repeats} rounds; relMSE against {args.reference_spp} spp",
        ["scene", "quality", "prefilters", "median s", "relMSE"],
        rows,
    )
    write_results("denoise_prefilter", {"options": vars(args), "results": results}, info)


if __name__ == "__main__":
    main()
