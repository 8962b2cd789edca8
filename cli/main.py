"""``tilerender``: render scenes from the command line.

The command line is parsed here; each command is a module of ``cli.commands`` (``COMMANDS``),
imported only once the line parses. How a command ends is decided here too (``failure``):
every failure a user can cause (a bad scene, a bad option, an unwritable output, a Ray address
that cannot be reached: a ``TilerenderError``) ends with one line on stderr and exit code 2;
nothing is written. A render the cluster cannot complete (every tracer lost: a ``ClusterError``,
or any ``TilerenderError`` that refines ``RuntimeError``) ends with one line and exit code 1.
Any other exception is a bug: one line saying so and exit code 1. Ctrl-C exits with 130,
writing nothing (an animation keeps the frames already written, and the message says how
many). ``serve`` runs until Ctrl-C (or SIGTERM), shuts down cleanly and exits 0.
"""

import argparse
import importlib
import sys
from collections.abc import Sequence

from cli.errors import UsageError
from tracer.errors import TilerenderError
from tracer.integrators.names import (
    DENOISE,
    DENOISE_PREFILTER,
    INTEGRATORS,
    KERNELS,
    LIGHT_SAMPLERS,
    OUTPUT_LAYERS,
)

EXIT_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130

DESCRIPTION = """\
tilerender: a Brigade-style path tracer.

Scenes are tilerender/1 JSON files (docs/scene-format.md) or single mesh files
(glTF, GLB, OBJ, PLY, STL), which get a framing camera and, if nothing emits,
a default area light. Images are linear radiance; .png is written in sRGB.
`render` renders through tracer actors on Ray (docs/cluster.md): an embedded
local Ray by default, or a cluster with --ray-address."""

EPILOG = """\
examples:
  tilerender render scenes/cornell-box/scene.json -o cornell.png
  tilerender render scenes/cornell-box/scene.json -o cornell.exr --spp 256 --seed 7
  tilerender render model.glb -o model.png --width 800 --height 600
  tilerender render scene.json -o frame.png --tracers 2 --balancer perfect-smooth
  tilerender render animated.json -o out.png --frames 0-23   (out_0000.png ...)
  tilerender render scene.json -o x.exr --ray-address 10.0.0.5:6379
  tilerender samples --out renders
  tilerender serve                       (the service and viewer on 127.0.0.1:8000)
  tilerender serve --port 9000 --ray-address 10.0.0.5:6379 --token SECRET
  tilerender info scenes/cornell-box/scene.json
  tilerender plan scenes/cornell-box/scene.json
  tilerender render scenes/cornell-box/scene.json -o ao.png --integrator ao
  tilerender render scenes/cornell-box/scene.json -o c.exr --target-error 0.02
  tilerender render scenes/studio/scene.json -o s.png --frames 0 --time-budget 10
  tilerender bench accuracy --scenes cornell-box --pixels 4096 --max-spp 256
  tilerender schema > scene-schema.json"""


COMMANDS = {
    name: f"cli.commands.{name}"
    for name in ("render", "samples", "serve", "info", "plan", "schema", "bench")
}
"""Each command's module; its ``run(args)`` returns the exit code."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, not a usage dump
        raise UsageError(f"{self.prog}: {message} (see --help)")


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must not be negative, got {value}")
    return value


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value > 0.0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive finite number, got {text}")
    return value


def power_of_two(text: str) -> int:
    value = positive_int(text)
    if value < 4 or value & (value - 1):
        raise argparse.ArgumentTypeError(
            f"must be a power of two, at least 4 (one wave of the error estimate), got {value}"
        )
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="tilerender",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    render = sub.add_parser(
        "render",
        help="render a scene to an image file",
        description="Render SCENE to OUT; the format follows OUT's extension "
        "(.png sRGB 8-bit, .exr float32 linear, .npy float32 linear (H, W, 3), row 0 at the top). "
        "Options override the scene file's camera and render settings.",
    )
    render.add_argument(
        "scene", metavar="SCENE", help="scene .json, or a .gltf/.glb/.obj/.ply/.stl"
    )
    render.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="OUT",
        help="image to write; for an animation each frame goes to OUT with _NNNN before the "
        "extension (out.png -> out_0000.png, out_0001.png, ...)",
    )
    add_render_options(render)
    add_quality_options(render)
    add_cluster_options(render)

    samples = sub.add_parser(
        "samples",
        help="render every sample scene into a directory",
        description="Render each scene under --scenes (a scene.json per folder, or a folder's "
        "single glTF/GLB file) to OUT/<folder>.png and .exr.",
    )
    samples.add_argument("--out", default="renders", metavar="DIR", help="(default: renders)")
    samples.add_argument("--scenes", default=None, metavar="DIR", help="(default: the repo's)")
    samples.add_argument("--spp", type=positive_int, help="samples per pixel for every scene")
    samples.add_argument("--threads", type=positive_int, help="render threads (default: all)")
    samples.add_argument("-q", "--quiet", action="store_true", help="no progress bars")

    add_serve_parser(sub)
    add_bench_parser(sub)

    info = sub.add_parser("info", help="describe a scene: geometry, materials, lights, camera")
    info.add_argument("scene", metavar="SCENE")

    plan = sub.add_parser(
        "plan",
        help="show the effects a scene needs (its effect plan) and why",
        description="Print, as JSON, the effects a render of SCENE runs and the ones it skips, "
        "each with the rule that decided it (docs/effects.md). Options override the scene's "
        "render settings, as for render.",
    )
    plan.add_argument("scene", metavar="SCENE")
    plan.add_argument("--integrator", choices=INTEGRATORS, help="integrator to plan for")
    plan.add_argument(
        "--max-depth", type=positive_int, help="path vertices after the camera (as for render)"
    )
    add_kernel_option(plan)
    add_light_sampler_option(plan)

    sub.add_parser(
        "schema",
        help="print the JSON Schema of scene files",
        description="Print the JSON Schema of tilerender/1 scene files (docs/scene-schema.json).",
    )
    return parser


def port_number(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a port number, got {text!r}") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"must be 0 to 65535, got {value}")
    return value


def add_serve_parser(sub) -> None:
    serve = sub.add_parser(
        "serve",
        help="run the HTTP service and its web viewer",
        description="Serve the REST API (/v1, OpenAPI at /docs), the web viewer (/) and "
        "/healthz, /readyz, /metrics, rendering on an embedded local Ray (or the cluster "
        "--ray-address names). Prints the viewer's URL. Settings not given here come from "
        "TILERENDER_* environment variables (docs/api.md).",
    )
    serve.add_argument(
        "--host", default="127.0.0.1", help="address to listen on (default: 127.0.0.1)"
    )
    serve.add_argument(
        "--port", type=port_number, default=8000, help="port (default: 8000; 0 = any free port)"
    )
    serve.add_argument(
        "--data-dir",
        metavar="DIR",
        help="scenes, jobs and results "
        "(default: $TILERENDER_DATA_DIR or ~/.local/share/tilerender)",
    )
    serve.add_argument("--db", metavar="FILE", help="SQLite database (default: DIR/tilerender.db)")
    serve.add_argument(
        "--token",
        help="require 'Authorization: Bearer TOKEN' on /v1 (default: $TILERENDER_TOKEN, or none)",
    )
    serve.add_argument(
        "--cors-origin", action="append", metavar="ORIGIN", help="allow this origin (repeatable)"
    )
    serve.add_argument(
        "--threads",
        type=positive_int,
        help="CPUs (render threads) per tracer (default: all of its node's)",
    )
    serve.add_argument(
        "--log-level", default="warning", choices=["critical", "error", "warning", "info", "debug"]
    )
    add_cluster_options(serve, frames=False)


def add_kernel_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--kernel",
        choices=KERNELS,
        help="how paths are traced: single (a path at a time), stream (a stream of paths a "
        "stage at a time) or auto (default: the measured rule, docs/performance.md); the "
        "same image bit for bit",
    )


def add_light_sampler_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--light-sampler",
        choices=LIGHT_SAMPLERS,
        help="how light samples pick emissive triangles: power, tree (a light tree) or auto "
        "(default: the tree where the scene has enough emissive triangles, docs/effects.md); "
        "the same image in expectation",
    )


def add_layer_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--aov",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="also render the AOV layers albedo, normal, depth, position, alpha, object_id and "
        "material_id from the same paths (path, direct, whitted, cost); a .exr then holds every "
        "layer as named channels, a .npz one array per layer (docs/outputs.md)",
    )
    parser.add_argument(
        "--denoise",
        nargs="?",
        const="high",
        choices=DENOISE,
        metavar="QUALITY",
        help="denoise the finished frame with Open Image Denoise: fast, balanced or high "
        "(the default when QUALITY is left out; off overrides a scene's render.denoise), "
        "guided by the albedo and normal AOVs; the "
        "image shows the denoised layer, a .exr or .npz keeps the beauty beside it "
        "(docs/denoising.md)",
    )
    parser.add_argument(
        "--denoise-prefilter",
        choices=DENOISE_PREFILTER,
        help="prefilter the denoiser's albedo and normal guides: auto (the default) where they "
        "are noisy (both with a lens aperture, a normal map or a blended surface, the albedo "
        "with textures only), on (both), off or albedo (docs/denoising.md)",
    )
    parser.add_argument(
        "--layer",
        choices=OUTPUT_LAYERS,
        help="write this layer alone (a .png, .npy or .exr; default: every layer to a .exr "
        "that has several, else denoised with --denoise, else beauty)",
    )


def add_render_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--spp", type=positive_int, help="samples per pixel")
    parser.add_argument("--width", type=positive_int, help="image width in pixels")
    parser.add_argument("--height", type=positive_int, help="image height in pixels")
    parser.add_argument("--seed", type=non_negative_int, help="random seed")
    parser.add_argument(
        "--integrator",
        choices=INTEGRATORS,
        help="path (default), direct, whitted, ao, or a debug output: albedo, normal, depth, cost",
    )
    parser.add_argument(
        "--max-depth",
        type=positive_int,
        help="path vertices after the camera: 1 = emitters only, 2 = direct light",
    )
    add_kernel_option(parser)
    add_light_sampler_option(parser)
    add_layer_options(parser)
    parser.add_argument(
        "--adaptive",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="adaptive sampling with --target-error or --time-budget: each wave gives pixels "
        "samples by their estimated share of the error (default: the scene's render.adaptive, "
        "auto: where it is predicted to win; docs/accuracy.md)",
    )
    parser.add_argument(
        "--threads",
        type=positive_int,
        help="render threads (CPUs) per tracer, or of this process when rendering in it "
        "(default: all of the node's CPUs)",
    )
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar")


def add_quality_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--target-error",
        type=positive_float,
        metavar="E",
        help="render in waves until the estimated relative error (RMS, e.g. 0.01 = 1%%; "
        "docs/accuracy.md) is at most E; instead of --spp",
    )
    parser.add_argument(
        "--time-budget",
        type=positive_float,
        metavar="S",
        help="render in waves for at most about S seconds (shared evenly by an animation's "
        "frames); with --target-error, whichever comes first",
    )
    parser.add_argument(
        "--max-spp",
        type=positive_int,
        metavar="N",
        help="with --target-error or --time-budget: stop at N samples per pixel (their mean with "
        "adaptive sampling; default 65536)",
    )


def add_bench_parser(sub) -> None:
    bench = sub.add_parser(
        "bench",
        help="run a study of the renderer (accuracy against time)",
        description="Studies that measure the renderer; see bench/README.md.",
    )
    studies = bench.add_subparsers(dest="study", metavar="STUDY", parser_class=_Parser)
    studies.required = True
    accuracy = studies.add_parser(
        "accuracy",
        help="error against a reference vs time: spp, depth, integrators, roulette, plan",
        description="For each sample scene (small images): sweep spp 1..MAX, max depth 1-16, "
        "the integrators, Russian roulette and the effect plan; measure the error against one "
        "reference per scene (relative MSE, RMSE, PSNR, SSIM, FLIP) and the time; the cost per "
        "effect (Reiter eq. 5.1); time to quality; the online error estimate's calibration. "
        "Writes accuracy.json, report.md and PNG plots into --out (docs/accuracy.md).",
    )
    accuracy.add_argument(
        "--scenes", nargs="+", metavar="NAME", help="scene folders under scenes/ (default: all)"
    )
    accuracy.add_argument(
        "--pixels", type=positive_int, help="about this many pixels per image (default 12288)"
    )
    accuracy.add_argument(
        "--max-spp", type=power_of_two, help="largest spp of the sweep (default 1024)"
    )
    accuracy.add_argument(
        "--reference-factor",
        type=positive_int,
        help="our own references take this many times --max-spp (default 16)",
    )
    accuracy.add_argument(
        "--repeats", type=positive_int, help="rounds of the effect-cost timings (default 7)"
    )
    accuracy.add_argument(
        "--effect-spp", type=positive_int, help="spp of one effect-cost render (default 32)"
    )
    accuracy.add_argument("--seed", type=non_negative_int, default=0, help="(default 0)")
    accuracy.add_argument("--threads", type=positive_int, help="render threads (default: all)")
    accuracy.add_argument(
        "--quick",
        action="store_true",
        help="a check that it works: 1024 pixels, 64 spp, references at 8x, 2 rounds "
        "(explicit options win)",
    )
    accuracy.add_argument(
        "--out",
        metavar="DIR",
        help="where the report goes (default: bench/results/accuracy)",
    )
    accuracy.add_argument(
        "--docs",
        action="store_true",
        help="also write docs/accuracy.md (between its report markers) and docs/accuracy/*.png",
    )
    accuracy.add_argument(
        "--cache", metavar="DIR", help="reference cache (default: bench/results/accuracy-cache)"
    )
    accuracy.add_argument(
        "--report-only",
        action="store_true",
        help="render nothing: rebuild the report from the results in --out",
    )
    accuracy.add_argument("-q", "--quiet", action="store_true", help="no progress bar")


def add_cluster_options(parser: argparse.ArgumentParser, frames: bool = True) -> None:
    from cluster.balancing import BALANCERS, DEFAULT_BALANCER  # light: numpy only

    parser.add_argument(
        "--tracers",
        type=positive_int,
        help="tracer actors to render with (default: one per Ray node, using its CPUs)",
    )
    parser.add_argument(
        "--balancer",
        metavar="NAME",
        help=f"how each frame's lines (or spans of them) are split among tracers: "
        f"{', '.join(sorted(BALANCERS))} (default: {DEFAULT_BALANCER}, which also balances "
        "within the frame when the tracers share this machine; cost-aware-tail does across "
        "machines too; for serve, TILERENDER_BALANCER if set)",
    )
    parser.add_argument(
        "--ray-address",
        metavar="ADDR",
        help="join a Ray cluster: host:port of its head, or 'auto' for the one `ray start` "
        "runs on this machine (default: start an embedded local Ray)",
    )
    if frames:
        parser.add_argument(
            "--in-process",
            action=argparse.BooleanOptionalAction,
            help="render in this process, without Ray (--no-in-process: always through Ray). "
            "Default: a still of at most 4.2 M pixel samples (width x height x spp) without "
            "--tracers, --balancer, --ray-address or a quality goal renders in this process, "
            "since starting and stopping the embedded Ray alone takes about 4.5 s; anything "
            "else goes through the coordinator",
        )
        parser.add_argument(
            "--frames",
            metavar="RANGE",
            help="animation frames to render: N or FIRST-LAST, inclusive (default: all)",
        )


def failure(exc: Exception) -> tuple[int, str]:
    """The exit code and the one line of stderr for an exception that ended a command."""
    message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    if isinstance(exc, TilerenderError):
        # The domain errors refine RuntimeError for a cluster that cannot finish (ClusterError,
        # PoolLost, CommandFailed), ValueError or ConnectionError for the user's input.
        return (EXIT_FAILED if isinstance(exc, RuntimeError) else EXIT_USAGE), f"error: {message}"
    return EXIT_FAILED, (
        f"internal error: {type(exc).__name__}: {message} (a bug; please report it)"
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``tilerender`` console script."""
    try:
        args = build_parser().parse_args(argv)
        args.argv = list(sys.argv[1:] if argv is None else argv)
        # heavy imports (numba, trimesh) only once the line parses
        return importlib.import_module(COMMANDS[args.command]).run(args)
    except KeyboardInterrupt as exc:
        message = exc.args[0] if exc.args else "interrupted; nothing written"
        print(message, file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # e.g. `tilerender info ... | head`
        sys.stderr.close()
        return 0
    except Exception as exc:
        code, message = failure(exc)
        print(message, file=sys.stderr)
        return code


if __name__ == "__main__":
    sys.exit(main())
