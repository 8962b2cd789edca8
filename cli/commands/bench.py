"""``tilerender bench accuracy``: the accuracy study (``cli.accuracy``), with a progress bar
per scene, and its report (``cli.accuracy_report``)."""

import argparse
import importlib.util
from pathlib import Path

from cli.accuracy import DEFAULT_CACHE, REPO_ROOT, StudyOptions, run_study
from cli.accuracy_metrics import refresh_time_to
from cli.accuracy_report import load_previous, write_report
from cli.commands.samples import REPO_SCENES, sample_scene_files
from cli.errors import CommandFailed, UsageError
from cli.output import note_compiling, progress_bar, stderr

STUDY_LIBRARIES = {"skimage": "scikit-image", "flip_evaluator": "flip-evaluator",
                   "matplotlib": "matplotlib"}  # fmt: skip
"""The ``study`` extra's modules (pyproject.toml) and their packages."""


def require_study_extra() -> None:
    """Refuse to start the study without its libraries, naming what to install."""
    missing = [
        pkg for module, pkg in STUDY_LIBRARIES.items() if not importlib.util.find_spec(module)
    ]
    if missing:
        raise CommandFailed(
            f"the accuracy study needs {', '.join(missing)}: install the 'study' extra "
            "(pip install 'tilerender[study]'; ./dev installs it)"
        )


def run(args: argparse.Namespace) -> int:
    """``bench accuracy``: the accuracy study (cli.accuracy), with a progress bar per scene."""
    require_study_extra()
    root = REPO_SCENES
    available = {path.parent.name: path for path in sample_scene_files(root)}
    names = args.scenes or sorted(available)
    unknown = [n for n in names if n not in available]
    if unknown:
        raise UsageError(
            f"--scenes: no sample scene {', '.join(unknown)} (have: {', '.join(sorted(available))})"
        )
    quick = args.quick

    def pick(value, default, quick_value):
        return value if value is not None else quick_value if quick else default

    try:
        options = StudyOptions(
            scenes=tuple(available[n] for n in names),
            pixels=pick(args.pixels, 128 * 96, 1024),
            max_spp=pick(args.max_spp, 1024, 64),
            reference_factor=pick(args.reference_factor, 16, 8),
            repeats=pick(args.repeats, 7, 2),
            effect_spp=pick(args.effect_spp, 32, 4),
            seed=args.seed,
            threads=args.threads,
            cache_dir=Path(args.cache) if args.cache else DEFAULT_CACHE,
        )
    except ValueError as exc:  # an option the study refuses
        raise UsageError(str(exc)) from None
    out = Path(args.out) if args.out else REPO_ROOT / "bench" / "results" / "accuracy"
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out: {out} is not a directory")
    command = " ".join(["tilerender", *getattr(args, "argv", ["bench", "accuracy"])])
    docs_page = REPO_ROOT / "docs" / "accuracy.md" if args.docs else None
    if args.report_only:
        try:
            results, images = load_previous(out)
        except (OSError, ValueError, KeyError) as exc:
            raise UsageError(f"--report-only: no readable results in {out} ({exc})") from None
        refresh_time_to(results)
        command = results.get("command", command)
        written = report(results, images, out, docs_page, command)
        if not args.quiet:
            stderr.print(f"rewrote the report from {out}: {len(written)} files")
        return 0
    note_compiling(args.quiet)
    with progress_bar(args.quiet, "{task.percentage:>3.0f}%", transient=False) as progress:
        current = {}

        def on_start(name: str, total: int) -> None:
            current["name"] = name
            current["task"] = progress.add_task(name, total=total)

        def on_phase(phase: str) -> None:
            progress.update(current["task"], description=f"{current['name']}: {phase}")

        def on_samples(n: int) -> None:
            progress.advance(current["task"], n)

        results, images = run_study(options, on_start, on_samples, on_phase)
        for task in progress.tasks:
            progress.update(task.id, completed=task.total)
    results["command"] = command
    written = report(results, images, out, docs_page, command)
    if not args.quiet:
        stderr.print(f"wrote {len(written)} files into {out}" + (" and docs/" if args.docs else ""))
    return 0


def report(results: dict, images: dict, out: Path, docs_page: Path | None, command: str) -> list:
    """Write the study's report (``cli.accuracy_report``); a place it cannot be written to is a
    UsageError."""
    try:
        return write_report(results, images, out, docs_page, command)
    except OSError as exc:
        raise UsageError(f"cannot write the report into {out}: {exc.strerror or exc}") from None
