"""Dynamic scenes: what a commit costs a replica, and refit vs rebuild vs selective rebuild.

Three measurements, all on scenes built here (nothing to download):

1. **Move one object in a 1M-triangle scene**: a static 1.3M-triangle sphere field plus a rigid
   box; each commit moves the box (``set_transform``). Timed: ``SceneReplica.apply`` of one
   commit (validation, state update, incremental compile: the top level is rebuilt, mesh BVHs
   are reused). Target <= 10 ms.
2. **Deform a 20k-triangle mesh**: ``update_vertices`` on a 20,480-triangle sphere. Timed: the
   BVH refit alone (``tracer.geometry.bvh_update.update`` with an infinite threshold) and the whole
   replica apply. Target: refit <= 10 ms.
3. **Museum** (after Reiter's workload; BART's museum): a static room and N separate triangles
   that fly apart from a sphere, tumbling, and come back together. Every frame is an
   ``update_vertices`` commit, applied by three replicas in lockstep, one per strategy (refit
   only, selective rebuild at 1.3x, full rebuild), each followed by a render of the frame.
   Reported per strategy: update time, render time and their sum over the animation. The three
   renders of every frame must be bit-identical (the BVH changes speed, never pixels).

Commit and snapshot sizes (the binary codec, ``tracer.scene.codec``) are reported for each.
"""

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # for `common`

import numpy as np
import trimesh
from common import (
    fmt_float,
    machine_info,
    note,
    print_machine,
    print_table,
    styled_verdict,
    verdict,
    write_results,
)

from tracer.geometry import bvh_update
from tracer.render import render_image
from tracer.scene import format as fmt
from tracer.scene.codec import encode_commit, encode_state
from tracer.scene.model import Node, SceneState, Sky, frozen_array, make_mesh
from tracer.scene.ops import Commit, parse_ops
from worker.replica import SceneReplica

STRATEGIES = {"refit": math.inf, "selective": 1.3, "rebuild": 0.0}
WHITE = fmt.DiffuseMaterial()
LAMP = fmt.DiffuseMaterial(reflectance=(0, 0, 0), emission=(12, 11, 10), two_sided=False)


def matrix(translate=(0.0, 0.0, 0.0), scale: float = 1.0) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] *= scale
    m[:3, 3] = translate
    return frozen_array(m, np.float64)


def node(i, name, mesh, material, kind="static", transform=None) -> Node:
    return Node(i, name, None, matrix() if transform is None else transform, kind, mesh, material)


def sphere(subdivisions: int, radius: float = 1.0):
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def room_meshes() -> dict:
    """An open box room 12 x 6 x 12 (floor, ceiling, walls) and a ceiling lamp."""
    box = trimesh.creation.box(extents=(12, 6, 12))
    lamp = [[-1, 2.99, -1], [1, 2.99, -1], [1, 2.99, 1], [-1, 2.99, 1]]
    return {
        "room": make_mesh(box.vertices, box.faces[:, ::-1]),  # facing inwards
        "lamp": make_mesh(lamp, [[0, 2, 1], [0, 3, 2]]),
    }


def state(meshes, nodes, camera, settings) -> SceneState:
    return SceneState(
        version=0,
        meshes=meshes,
        materials={"white": WHITE, "lamp": LAMP},
        nodes={n.id: n for n in nodes},
        camera=camera,
        render=settings,
        sky=Sky((0.0, 0.0, 0.0)),
    )


def commit_of(version: int, ops: list[dict]) -> Commit:
    return Commit(version, parse_ops(ops))


def percentile(values, q: float) -> float:
    return float(np.percentile(np.asarray(values), q))


# --- 1. moving one object in a 1M-triangle scene ----------------------------------------------


def move_one_object(commits: int, subdivisions: int) -> dict:
    big = make_mesh(*sphere(subdivisions, 2.0))
    box = trimesh.creation.box(extents=(0.5, 0.5, 0.5))
    meshes = {**room_meshes(), "field": big, "box": make_mesh(box.vertices, box.faces)}
    nodes = [
        node(0, "room", "room", "white"),
        node(1, "lamp", "lamp", "lamp"),
        node(2, "field", "field", "white"),
        node(3, "box", "box", "white", "rigid", matrix((3.0, -2.0, 0.0))),
    ]
    camera = fmt.Camera(position=(0, 0, 5.5), look_at=(0, 0, 0), width=64, height=48)
    scene = state(meshes, nodes, camera, fmt.RenderSettings(spp=1, max_depth=3))
    start = time.perf_counter()
    replica = SceneReplica(scene)
    first_compile = time.perf_counter() - start
    seconds, sizes = [], []
    for k in range(1, commits + 2):  # the first commit warms up (compiles) and is not counted
        angle = 2 * math.pi * k / commits
        t = [3.0 * math.cos(angle), -2.0, 3.0 * math.sin(angle)]
        commit = commit_of(k, [{"op": "set_transform", "node": 3, "transform": {"translate": t}}])
        sizes.append(len(encode_commit(commit)))
        start = time.perf_counter()
        replica.apply([commit])
        if k > 1:
            seconds.append(time.perf_counter() - start)
    start = time.perf_counter()
    snapshot = encode_state(replica.state)
    encode_seconds = time.perf_counter() - start
    return {
        "triangles": int(big.triangles + 14),
        "first_compile_seconds": first_compile,
        "apply_ms": [1e3 * s for s in seconds],
        "apply_ms_median": 1e3 * statistics.median(seconds),
        "apply_ms_p95": 1e3 * percentile(seconds, 95),
        "commit_bytes": max(sizes),
        "snapshot_bytes": len(snapshot),
        "snapshot_encode_seconds": encode_seconds,
    }


# --- 2. deforming a 20k-triangle mesh ---------------------------------------------------------


def deform_mesh(steps: int, subdivisions: int) -> dict:
    vertices, faces = sphere(subdivisions)
    meshes = {**room_meshes(), "blob": make_mesh(vertices, faces)}
    nodes = [
        node(0, "room", "room", "white"),
        node(1, "lamp", "lamp", "lamp"),
        node(2, "blob", "blob", "white", "deformable"),
    ]
    camera = fmt.Camera(position=(0, 0, 5.5), look_at=(0, 0, 0), width=64, height=48)
    replica = SceneReplica(state(meshes, nodes, camera, fmt.RenderSettings(spp=1, max_depth=3)))
    refit_seconds, apply_seconds, sizes = [], [], []
    for k in range(1, steps + 2):  # the first step warms up (compiles) and is not counted
        wobble = 1.0 + 0.15 * np.sin(4 * vertices[:, [1]] + 0.7 * k) * np.cos(3 * vertices[:, [0]])
        moved = vertices * wobble
        commit = commit_of(k, [{"op": "update_vertices", "mesh": "blob", "vertices": moved}])
        sizes.append(len(encode_commit(commit)))
        accel = replica.current.meshes["blob"]
        leaf_order = (moved[faces] - accel.center).reshape(-1, 9).astype(np.float32)
        leaf_order = leaf_order[accel.bvh.tri_prim]
        start = time.perf_counter()
        bvh_update.update(accel.bvh, leaf_order, accel.sah_reference, math.inf)
        refit = time.perf_counter() - start
        start = time.perf_counter()
        replica.apply([commit])
        if k > 1:
            refit_seconds.append(refit)
            apply_seconds.append(time.perf_counter() - start)
    return {
        "triangles": int(faces.shape[0]),
        "refit_ms_median": 1e3 * statistics.median(refit_seconds),
        "refit_ms_p95": 1e3 * percentile(refit_seconds, 95),
        "apply_ms_median": 1e3 * statistics.median(apply_seconds),
        "apply_ms_p95": 1e3 * percentile(apply_seconds, 95),
        "commit_bytes": max(sizes),
        "snapshot_bytes": len(encode_state(replica.state)),
    }


# --- 3. the museum ----------------------------------------------------------------------------


MOTIONS = ("explode", "local", "wave")


def museum_pose(
    n: int, frame: int, frames: int, motion: str, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """N separate small triangles on a sphere at frame 0 and the last frame, each tumbling about
    its centre. ``explode``: all fly through the room at mid-animation (a refitted tree decays);
    ``local``: one in eight flies, the rest stay; ``wave``: all stay, rippling along the sphere
    (the tree's shape stays good)."""
    rng = np.random.default_rng(seed)
    golden = math.pi * (3.0 - math.sqrt(5.0))
    i = np.arange(n) + 0.5
    y = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - y * y)
    home = 1.2 * np.stack([r * np.cos(golden * i), y, r * np.sin(golden * i)], axis=1)
    away = rng.uniform([-5.0, -2.5, -5.0], [5.0, 2.5, 5.0], (n, 3))
    size = 2.4 / math.sqrt(n)
    corners = rng.normal(size=(n, 3, 3))
    corners *= size / np.linalg.norm(corners, axis=2, keepdims=True)
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    s = 0.5 - 0.5 * math.cos(2 * math.pi * frame / max(1, frames - 1))  # 0 -> 1 -> 0
    if motion == "explode":
        flight = np.full((n, 1), s)
    elif motion == "local":
        flight = np.where(np.arange(n)[:, None] % 8 == 0, s, 0.0)
    elif motion == "wave":
        flight = np.zeros((n, 1))
        home = home * (1.0 + 0.08 * s * np.sin(6.0 * home[:, [1]] + 4.0 * s))
    else:
        raise ValueError(f"unknown motion {motion!r}")
    angle = 2 * math.pi * s
    # Rodrigues rotation of each triangle's corners about its own axis.
    cos, sin = math.cos(angle), math.sin(angle)
    dot = np.einsum("nk,nck->nc", axis, corners)[..., None]
    rotated = (
        corners * cos
        + np.cross(axis[:, None, :], corners) * sin
        + axis[:, None, :] * dot * (1 - cos)
    )
    centre = (1 - flight) * home + flight * away
    vertices = (centre[:, None, :] + rotated).reshape(-1, 3)
    return vertices, np.arange(3 * n).reshape(n, 3)


def museum(sizes: list[int], frames: int, width: int, spp: int, motion: str) -> list[dict]:
    rows = []
    camera = fmt.Camera(
        position=(0, 0.5, 5.8), look_at=(0, 0, 0), width=width, height=width * 3 // 4
    )
    settings = fmt.RenderSettings(spp=spp, max_depth=3, seed=1)
    for n in sizes:
        vertices, faces = museum_pose(n, 0, frames, motion)
        meshes = {**room_meshes(), "cloud": make_mesh(vertices, faces)}
        nodes = [
            node(0, "room", "room", "white"),
            node(1, "lamp", "lamp", "lamp"),
            node(2, "cloud", "cloud", "white", "dynamic"),
        ]
        scene = state(meshes, nodes, camera, settings)
        replicas = {
            name: SceneReplica(scene, rebuild_threshold=t) for name, t in STRATEGIES.items()
        }
        update = dict.fromkeys(STRATEGIES, 0.0)
        render = dict.fromkeys(STRATEGIES, 0.0)
        commit_bytes = 0
        for replica in replicas.values():  # warm-up: compile kernels, fill caches
            render_image(replica.current, frame=0)
        for frame in range(1, frames):
            moved, _ = museum_pose(n, frame, frames, motion)
            commit = commit_of(
                frame, [{"op": "update_vertices", "mesh": "cloud", "vertices": moved}]
            )
            commit_bytes = max(commit_bytes, len(encode_commit(commit)))
            images = []
            for name, replica in replicas.items():
                start = time.perf_counter()
                replica.apply([commit])
                update[name] += time.perf_counter() - start
                start = time.perf_counter()
                images.append(render_image(replica.current, frame=frame)[0])
                render[name] += time.perf_counter() - start
            if not all(np.array_equal(images[0], other) for other in images[1:]):
                raise AssertionError(
                    f"museum {motion} N={n} frame {frame}: strategies render differently"
                )
        rows.append(
            {
                "motion": motion,
                "moving_triangles": n,
                "frames": frames - 1,
                "update_seconds": update,
                "render_seconds": render,
                "total_seconds": {k: update[k] + render[k] for k in STRATEGIES},
                "commit_bytes": commit_bytes,
                "snapshot_bytes": len(encode_state(replicas["refit"].state)),
            }
        )
    return rows


# --- main ---------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog="Quick check: --quick (small sizes, few frames).",
    )
    parser.add_argument("--commits", type=int, default=40, help="moves of the box (default 40)")
    parser.add_argument(
        "--big-subdivisions",
        type=int,
        default=8,
        help="icosphere level of the 1M-triangle scene (8 = 1.31M triangles)",
    )
    parser.add_argument("--deform-steps", type=int, default=40, help="deformations (default 40)")
    parser.add_argument(
        "--museum",
        type=int,
        nargs="+",
        default=[64, 256, 1024, 4096, 16384, 65536],
        help="moving-triangle counts of the museum workload",
    )
    parser.add_argument(
        "--motions", nargs="+", choices=MOTIONS, default=list(MOTIONS), help="museum animations"
    )
    parser.add_argument("--frames", type=int, default=25, help="museum animation frames")
    parser.add_argument("--width", type=int, default=160, help="museum render width (4:3)")
    parser.add_argument("--spp", type=int, default=1, help="museum samples per pixel")
    parser.add_argument("--quick", action="store_true", help="small sizes, for a smoke test")
    args = parser.parse_args(argv)
    if args.quick:
        args.commits, args.big_subdivisions, args.deform_steps = 5, 5, 5
        args.museum, args.frames, args.width = [64, 1024], 5, 48

    info = machine_info()
    print_machine(info)
    move = move_one_object(args.commits, args.big_subdivisions)
    deform = deform_mesh(args.deform_steps, 5)
    rows = [
        row
        for motion in args.motions
        for row in museum(args.museum, args.frames, args.width, args.spp, motion)
    ]

    print_table(
        "Commit applied on a replica",
        ["workload", "triangles", "median ms", "p95 ms", "target", "verdict", "commit B",
         "snapshot B"],
        [
            ["move one object (set_transform)", move["triangles"],
             fmt_float(move["apply_ms_median"]),
             fmt_float(move["apply_ms_p95"]), "<= 10 ms",
             styled_verdict(verdict(move["apply_ms_median"], 10.0, at_most=True)),
             move["commit_bytes"], move["snapshot_bytes"]],
            ["deform (refit only)", deform["triangles"], fmt_float(deform["refit_ms_median"]),
             fmt_float(deform["refit_ms_p95"]), "<= 10 ms",
             styled_verdict(verdict(deform["refit_ms_median"], 10.0, at_most=True)), "", ""],
            ["deform (update_vertices apply)", deform["triangles"],
             fmt_float(deform["apply_ms_median"]), fmt_float(deform["apply_ms_p95"]), "", "",
             deform["commit_bytes"], deform["snapshot_bytes"]],
        ],
    )  # fmt: skip
    print_table(
        f"Museum: update + render seconds over {args.frames - 1} frames "
        f"({args.width}x{args.width * 3 // 4}, {args.spp} spp)",
        [
            "motion",
            "moving tris",
            *[f"{k} upd/render/total" for k in STRATEGIES],
            "best",
            "commit B",
        ],
        [
            [r["motion"], r["moving_triangles"]]
            + [
                f"{r['update_seconds'][k]:.3f}/{r['render_seconds'][k]:.3f}/"
                f"{r['total_seconds'][k]:.3f}"
                for k in STRATEGIES
            ]
            + [min(STRATEGIES, key=lambda k, r=r: r["total_seconds"][k]), r["commit_bytes"]]
            for r in rows
        ],
    )
    note(
        f"first compile of the {move['triangles']}-triangle scene: "
        f"{move['first_compile_seconds']:.2f} s; "
        f"snapshot encode {move['snapshot_encode_seconds']:.2f} s"
    )
    write_results(
        "dynamic_scenes",
        {"options": vars(args), "move_one_object": move, "deform": deform, "museum": rows},
        info,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
