"""Seconds of the OIDN denoiser (``tracer.post.denoise``) on frames of the renderer's own.

A sample scene (``--scene``, the Cornell box by default) is rendered at each size in
``--sizes`` by the path tracer at ``--spp`` samples with its albedo and normal AOVs (the guides,
as noisy as a render's). With ``--render-spp``, a render of each frame at that spp is timed
with and without AOVs (what recording them costs), and timed again with AOVs in every round
of the contenders (the denoiser's share of a render, from runs adjacent in time). Then,
after one warm-up each, every contender (size x quality x
beauty only / both guides as they are / the albedo prefiltered / both prefiltered) denoises its
frame once per round, in turns, for
``--repeats`` rounds. Reported: median and best seconds, and frames per second at the smallest
size. The first call of the process is timed apart (it creates OIDN's device). With
``--reference-spp``, the smallest frame's relative MSE against a render at that spp says what
each quality buys. Writes ``bench/results/denoise.json``; figures in ``docs/denoising.md``.
"""

import argparse
import time

import numpy as np
from common import (
    REPO_ROOT,
    Contender,
    console,
    interleaved,
    machine_info,
    note,
    print_machine,
    print_table,
    usable_cores,
    write_results,
)

GUIDES = {
    "beauty": "none",
    "guided": "albedo+normal",
    "albedo prefiltered": "albedo+normal, albedo prefiltered",
    "prefiltered": "albedo+normal, prefiltered",
}
"""The contenders' guides: none, the AOVs as they are, the albedo alone prefiltered (``auto``
with textures only), both prefiltered (``auto`` with a lens or a normal map)."""

PREFILTER = {
    "beauty": False,
    "guided": False,
    "albedo prefiltered": ("albedo",),
    "prefiltered": True,
}
"""``denoise``'s ``prefilter`` for each contender."""


def size(text: str) -> tuple[int, int]:
    width, _, height = text.partition("x")
    return int(width), int(height)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    from tracer.post.denoise import QUALITIES

    parser = argparse.ArgumentParser(
        description="Seconds of the OIDN denoiser per frame size, quality and guides, on frames "
        "rendered by tilerender. Writes bench/results/denoise.json.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--scene", default="cornell-box", help="a folder of scenes/")
    parser.add_argument(
        "--sizes", nargs="+", type=size, default=[(640, 480), (320, 180)], help="WxH frames"
    )
    parser.add_argument("--spp", type=int, default=4, help="samples per pixel of the frames")
    parser.add_argument(
        "--qualities", nargs="+", choices=QUALITIES, default=list(QUALITIES), help="qualities"
    )
    parser.add_argument("--repeats", type=int, default=5, help="timed rounds")
    parser.add_argument("--threads", type=int, default=usable_cores(), help="threads")
    parser.add_argument(
        "--render-spp",
        type=int,
        default=64,
        help="also time a render of each frame at this spp, with and without AOVs, for the "
        "denoiser's share of a render (0: none)",
    )
    parser.add_argument(
        "--reference-spp",
        type=int,
        default=256,
        help="spp of a reference of the smallest frame for the error column (0: none)",
    )
    args = parser.parse_args(argv)
    if min(args.spp, args.repeats, args.threads) < 1 or min(min(s) for s in args.sizes) < 1:
        parser.error("--spp, --repeats, --threads and the sizes must be at least 1")
    return args


def frame_renderer(name: str, width: int, height: int, threads: int, **camera_fields):
    """``render(spp, aovs)``: scene ``name`` (a folder of ``scenes/``) rendered whole at
    ``width`` x ``height`` (``tracer.render.render_pixels``; ``camera_fields`` override the
    scene's camera's, e.g. a lens), and ``guides(out)``: the beauty, albedo and normal of a
    render with AOVs, (H, W, 3) each."""
    from tracer.compiled.scene import compile_scene
    from tracer.integrators.aov import aov_layers
    from tracer.render import render_pixels
    from tracer.scene.format import override
    from tracer.scene.loader import load_scene

    scene = compile_scene(load_scene(REPO_ROOT / "scenes" / name / "scene.json"))
    camera = override(scene.camera, width=width, height=height, **camera_fields)

    def render(spp: int, aovs: bool):
        settings = override(scene.render, spp=spp, aovs=aovs)
        return render_pixels(scene, 0, width * height, camera, settings, threads=threads)

    def guides(out) -> dict[str, np.ndarray]:
        layers = aov_layers(out.aov.reshape(height, width, -1))
        beauty = out.rgb.reshape(height, width, 3)
        return {"path": beauty, "albedo": layers["albedo"], "normal": layers["normal"]}

    return render, guides


def render_frames(args: argparse.Namespace, width: int, height: int) -> dict[str, np.ndarray]:
    """The beauty and its albedo and normal AOVs (one render, ``render.aovs``) of the scene at
    ``width`` x ``height``; with ``--render-spp``, also the seconds of a render at that spp with
    AOVs, and of the same render without them (in turns), for the denoiser's share."""
    render, guides = frame_renderer(args.scene, width, height, args.threads)
    start = time.perf_counter()
    frames = guides(render(args.spp, True))
    console.print(
        f"[dim]{width}x{height} at {args.spp} spp with AOVs rendered in "
        f"{time.perf_counter() - start:.2f} s (kernel compilation included where the cache "
        "was cold)[/]"
    )
    if args.render_spp:
        render(1, False)  # both kernels' flags warm
        times = {True: [], False: []}
        for _ in range(2):
            for aovs in (False, True):
                times[aovs].append(render(args.render_spp, aovs).seconds)
        frames["render"] = lambda _round: render(args.render_spp, True)
        frames["render_seconds"] = float(np.median(times[True]))
        frames["render_seconds_plain"] = float(np.median(times[False]))
        console.print(
            f"[dim]{width}x{height} at {args.render_spp} spp: {frames['render_seconds']:.2f} s "
            f"with AOVs, {frames['render_seconds_plain']:.2f} s without (median of 2 each, in "
            "turns)[/]"
        )
    if args.reference_spp and (width, height) == min(args.sizes, key=lambda s: s[0] * s[1]):
        start = time.perf_counter()
        frames["reference"] = render(args.reference_spp, False).rgb.reshape(height, width, 3)
        console.print(
            f"[dim]reference at {args.reference_spp} spp: {time.perf_counter() - start:.1f} s[/]"
        )
    return frames


def main(argv: list[str] | None = None) -> None:
    from tracer.accuracy.error_estimate import rel_mse
    from tracer.post.denoise import denoise

    args = parse_args(argv)
    info = machine_info()
    print_machine(info)
    frames = {s: render_frames(args, *s) for s in args.sizes}

    first = min(args.sizes, key=lambda s: s[0] * s[1])
    start = time.perf_counter()
    denoise(frames[first]["path"], quality=args.qualities[0], threads=args.threads)
    first_call = time.perf_counter() - start

    contenders, work, keys = {}, {}, {}
    for s in args.sizes:
        for quality in args.qualities:
            for guides in GUIDES:
                name = f"{s[0]}x{s[1]} {quality} {guides}"
                f = frames[s]
                extra = (f["albedo"], f["normal"]) if guides != "beauty" else ()
                prefilter = PREFILTER[guides]

                def run(_round, f=f, extra=extra, quality=quality, prefilter=prefilter):
                    return denoise(
                        f["path"],
                        *extra,
                        quality=quality,
                        threads=args.threads,
                        prefilter=prefilter,
                    )

                contenders[name] = Contender(run)
                work[name] = 1.0  # frames
                keys[name] = (s, quality, guides)
    warm = {name: c.run(-1) for name, c in contenders.items()}  # one warm-up each
    renders = {s: f"{s[0]}x{s[1]} render" for s in args.sizes if "render" in frames[s]}
    for s, name in renders.items():  # in the rounds too: shares of runs adjacent in time
        contenders[name], work[name] = Contender(frames[s]["render"]), 1.0
    series = interleaved(contenders, work, args.repeats)
    in_rounds = {s: series.pop(name) for s, name in renders.items()}

    results, rows = [], []
    for name, measured in series.items():
        s, quality, guides = keys[name]
        reference = frames[s].get("reference")
        error = None
        if reference is not None:
            error = rel_mse(warm[name].image, reference)
        render = in_rounds.get(s)
        share = None
        if render is not None:  # the median of the rounds' own shares
            paired = np.divide(measured.seconds, render.seconds)
            share = float(np.median(paired))
        entry = {
            "size": list(s),
            "quality": quality,
            "guides": list(warm[name].guides),
            "prefiltered": warm[name].prefiltered,
            "seconds": measured.seconds,
            "median_seconds": measured.median_seconds,
            "best_seconds": measured.best_seconds,
            "rel_mse": error,
            "share_of_render": share,
        }
        results.append(entry)
        rows.append(
            (
                f"{s[0]}x{s[1]}",
                quality,
                GUIDES[guides],
                f"{measured.median_seconds:.3f}",
                f"{measured.best_seconds:.3f}",
                f"{1.0 / measured.median_seconds:.1f}" if s == first else "",
                "" if error is None else f"{error:.4f}",
                f"{share:.1%}" if share is not None else "",
            )
        )
    noisy_error = None
    if "reference" in frames[first]:
        noisy_error = rel_mse(frames[first]["path"], frames[first]["reference"])
    print_table(
        f"OIDN denoiser, {args.scene} at {args.spp} spp, {args.threads} threads, "
        f"{args.repeats} rounds",
        [
            "frame",
            "quality",
            "guides",
            "median s",
            "best s",
            f"fps {first[0]}x{first[1]}",
            "relMSE",
            f"of a {args.render_spp}-spp render",
        ],
        rows,
        caption=f"first call of the process (device creation): {first_call:.3f} s; guides from "
        f"the albedo and normal AOVs at {args.spp} spp; relMSE against "
        f"{args.reference_spp} spp"
        + ("" if noisy_error is None else f" (the noisy frame: {noisy_error:.4f})")
        + "".join(
            f"; {args.render_spp}-spp render {w}x{h} in the rounds: {r.median_seconds:.2f} s"
            for (w, h), r in in_rounds.items()
        ),
    )
    if args.threads > usable_cores():
        note(f"{args.threads} threads on {usable_cores()} usable cores")
    write_results(
        "denoise",
        {
            "options": {**vars(args), "sizes": [list(s) for s in args.sizes]},
            "first_call_seconds": first_call,
            "noisy_rel_mse": noisy_error,
            "render_seconds_in_rounds": {
                f"{w}x{h}": in_rounds[(w, h)].median_seconds for w, h in in_rounds
            },
            "render_seconds": {
                f"{w}x{h}": [
                    frames[(w, h)].get("render_seconds_plain"),
                    frames[(w, h)].get("render_seconds"),
                ]
                for w, h in args.sizes
            },
            "results": results,
        },
        info,
    )


if __name__ == "__main__":
    main()
