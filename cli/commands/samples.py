"""``tilerender samples``: render every sample scene into a directory, in this process."""

import argparse
from pathlib import Path

from cli.errors import UsageError
from cli.in_process import render_to_file
from cli.output import stderr
from cluster.jobs import with_overrides
from tracer.compiled.scene import compile_scene
from tracer.scene.loader import load_scene

REPO_SCENES = Path(__file__).resolve().parents[2] / "scenes"


def sample_scene_files(root: Path) -> list[Path]:
    """Each sample scene under ``root``: a folder's scene.json, else its one glTF/GLB file."""
    found = []
    for folder in sorted(p for p in root.iterdir() if p.is_dir()):
        scene = folder / "scene.json"
        if scene.is_file():
            found.append(scene)
            continue
        gltf = sorted(folder.glob("*.gltf")) + sorted(folder.glob("*.glb"))
        if len(gltf) == 1:
            found.append(gltf[0])
    return found


def run(args: argparse.Namespace) -> int:
    root = Path(args.scenes) if args.scenes else REPO_SCENES
    if not root.is_dir():
        raise UsageError(f"{root}: no such scenes directory")
    scenes = sample_scene_files(root)
    if not scenes:
        raise UsageError(f"{root}: no sample scenes found")
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"--out: cannot make {out}: {exc.strerror or exc}") from None
    for path in scenes:
        state = with_overrides(load_scene(str(path)), spp=args.spp)
        name = path.parent.name
        render_to_file(
            compile_scene(state),
            state.camera,
            state.render,
            [out / f"{name}.png", out / f"{name}.exr"],
            args.threads,
            args.quiet,
            name,
        )
    if not args.quiet:
        stderr.print(f"{len(scenes)} sample scenes rendered into {out}/")
    return 0
