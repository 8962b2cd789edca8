"""``tilerender render``: one scene to an image (or an animation to one image per frame), in
this process or through the coordinator."""

import argparse
from pathlib import Path

from cli.cluster_render import render_through_cluster
from cli.errors import CommandFailed, UsageError
from cli.in_process import render_to_file
from cli.output import check_layer_choice, output_path, stderr
from cluster.jobs import quality_goal, with_overrides
from cluster.progressive import DEFAULT_MAX_SPP, PARTS, Goal
from tracer.accuracy.denoised_error import MIN_PART_SPP
from tracer.compiled.scene import compile_scene
from tracer.post.denoise import DenoiserUnavailable, require_denoiser
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene
from tracer.scene.model import SceneState

IN_PROCESS_SAMPLES = 1 << 22
"""Most pixel samples (width x height x spp) of a still that ``render`` runs in its own process
unless told otherwise: about 1-3 s of rendering on 2 cores, while starting and stopping the
embedded Ray alone takes about 4.5 s (docs/performance.md, Start-up)."""


def run(args: argparse.Namespace) -> int:
    """Render through the coordinator: tracer actors on Ray (embedded unless --ray-address)."""
    output = output_path(args.output)
    from cluster.balancing import make_balancer

    if args.balancer is not None:  # a wrong name fails before Ray starts
        try:
            make_balancer(args.balancer)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    goal = goal_of(args)  # bad --target-error / --time-budget combinations fail early too
    state = with_overrides(
        load_scene(args.scene),
        width=args.width,
        height=args.height,
        spp=args.spp,
        seed=args.seed,
        max_depth=args.max_depth,
        integrator=args.integrator,
        kernel=args.kernel,
        light_sampler=args.light_sampler,
        aovs=args.aov,
        denoise=args.denoise,
        denoise_prefilter=args.denoise_prefilter,
        adaptive=args.adaptive,
    )
    camera, settings = state.camera, state.render
    check_layer_choice(args.layer, settings)
    if settings.denoise != "off":
        try:
            require_denoiser()
        except DenoiserUnavailable as exc:
            raise CommandFailed(str(exc)) from None
    if goal is not None and goal.target_error is not None and settings.denoise != "off":
        note(args.quiet, TARGET_WITH_DENOISE)
    frames = frame_selection(state, args.frames)
    if runs_in_process(args, camera, settings, still=frames is None, progressive=goal is not None):
        scene, label = compile_scene(state), Path(args.scene).name
        render_to_file(
            scene, camera, settings, [output], args.threads, args.quiet, label, args.layer
        )
        return 0
    if frames is None:
        outputs = [output]
    else:
        digits = max(4, len(str(frames[-1])))
        outputs = [output.with_name(f"{output.stem}_{f:0{digits}d}{output.suffix}") for f in frames]
        goal = goal_of(args, len(frames))
    render_through_cluster(state, frames, outputs, args, goal)
    return 0


TARGET_WITH_DENOISE = (
    f"note: with --denoise, --target-error is the denoised image's estimated error from "
    f"{PARTS * MIN_PART_SPP} spp on; before that, the beauty's estimate decides "
    "(docs/denoising.md)"
)


def note(quiet: bool, text: str) -> None:
    if not quiet:
        stderr.print(f"[yellow]{text}[/]")


def runs_in_process(
    args: argparse.Namespace,
    camera: fmt.Camera,
    settings: fmt.RenderSettings,
    still: bool,
    progressive: bool,
) -> bool:
    """Whether ``render`` renders here, without Ray: ``--in-process``, or by default a small
    still at a fixed spp with no cluster option given. ``--no-in-process`` never does."""
    cluster_options = [
        flag
        for flag, value in (
            ("--tracers", args.tracers),
            ("--balancer", args.balancer),
            ("--ray-address", args.ray_address),
        )
        if value is not None
    ]
    if args.in_process:
        if cluster_options:
            raise UsageError(f"--in-process renders without Ray: drop {', '.join(cluster_options)}")
        if not still or progressive:
            raise UsageError(
                "--in-process renders a still at a fixed --spp; animations, --target-error and "
                "--time-budget go through the coordinator"
            )
        return True
    if args.in_process is False or cluster_options or not still or progressive:
        return False
    return camera.width * camera.height * settings.spp <= IN_PROCESS_SAMPLES


def goal_of(args: argparse.Namespace, frames: int = 1) -> Goal | None:
    """The progressive goal of ``--target-error`` / ``--time-budget`` (None without them);
    the budget is shared evenly by ``frames``."""
    if args.target_error is None and args.time_budget is None:
        if args.max_spp is not None:
            raise UsageError("--max-spp applies with --target-error or --time-budget only")
        if args.adaptive is not None:
            raise UsageError(
                "--adaptive / --no-adaptive apply with --target-error or --time-budget only"
            )
        return None
    if args.spp is not None:
        raise UsageError(
            "--spp fixes the samples per pixel; with --target-error or --time-budget the waves "
            "choose them (cap them with --max-spp)"
        )
    max_spp = args.max_spp or DEFAULT_MAX_SPP
    if max_spp < PARTS:
        raise UsageError(
            f"--max-spp must be at least {PARTS} (a wave is {PARTS} independent parts of at "
            "least one sample each)"
        )
    return quality_goal(args.target_error, args.time_budget, max_spp, frames)


def frame_selection(state: SceneState, text: str | None) -> list[int] | None:
    """The animation frames ``--frames`` selects (all by default); None for a still scene."""
    animation = state.animation
    if animation is None:
        if text is not None:
            raise UsageError("--frames: the scene has no animation")
        return None
    count = animation.frames
    if text is None:
        return list(range(count))
    first, sep, last = text.strip().partition("-")
    try:
        a, b = int(first), int(last) if sep else int(first)
    except ValueError:
        raise UsageError(f"--frames: expected N or FIRST-LAST, got {text!r}") from None
    if not 0 <= a <= b < count:
        raise UsageError(f"--frames: {text!r} is not within the animation's frames 0-{count - 1}")
    return list(range(a, b + 1))
