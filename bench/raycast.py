"""Ray casting on a ~1.31M-triangle mesh: BVH build, memory, and rays/s against Embree.

Meshes: ``trimesh.creation.icosphere(subdivisions=8)`` ("smooth") and the same sphere with every
vertex moved radially by up to +-2% ("bumpy", seeded). For each: the BVH build time and bytes
per triangle; then closest-hit rays per second for two ray sets, tilerender on one thread and
on all threads against Embree (embreex, one thread), interleaved and repeated:

camera
    a pinhole camera outside the sphere framing it, one ray through each cell of a jittered
    pixel grid (coherent);
diffuse
    from every camera ray's hit, a ray leaving the surface (offset off it along the geometric
    normal that faces the camera ray) in a cosine-distributed direction (incoherent).

The two engines' answers are compared (same triangle hit, same distance), and any-hit
(occlusion) queries are timed on the diffuse set with ``t_max`` half the closest hit's distance
(so nothing should be occluded).
"""

import argparse
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from common import (
    Contender,
    Series,
    console,
    fmt_float,
    interleaved,
    machine_info,
    note,
    package_version,
    print_machine,
    print_table,
    styled_verdict,
    time_call,
    usable_cores,
    verdict,
    write_results,
)

from tracer.geometry import bvh
from tracer.geometry.raycast import Hits, any_hits, closest_hits

BUILD_TARGET = 2.0
"""Most BVH build seconds per million triangles."""
MEMORY_TARGET = 80.0
"""Most bytes per triangle (BVH, triangles and the renderer's 4-byte material id)."""
MATERIAL_ID_BYTES = 4
PER_CORE_TARGET = 0.4
PER_CORE_STRETCH = 0.8
"""Least throughput ratio tilerender (one thread) / Embree (one thread), and the stretch goal."""
RELATIVE_OFFSET = 1e-5
"""Secondary-ray origins sit this far off the surface, relative to the hit point's magnitude."""
EDGE_BARYCENTRIC = 1e-4
"""A hit whose smallest barycentric is below this counts as on a triangle edge."""
CAMERA_DISTANCE = 3.0
CAMERA_VFOV_DEG = 42.0
EMBREE_NO_HIT = 1e37
"""What embreex leaves in ``tfar`` when a ray misses."""


@dataclass
class Mesh:
    name: str
    tri_verts: np.ndarray
    """float32 (T, 9): v0, v1, v2 of every triangle."""

    @property
    def triangles(self) -> int:
        return self.tri_verts.shape[0]


@dataclass
class RaySet:
    name: str
    origins: np.ndarray
    directions: np.ndarray
    """float64 (N, 3) each, contiguous; float32 copies are made for Embree."""

    @property
    def count(self) -> int:
        return self.origins.shape[0]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="Ray casting: BVH build time and memory, closest-hit and any-hit rays/s of "
        "tilerender (1 and all threads) vs Embree (1 thread) on icospheres. "
        "Writes bench/results/raycast.json.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument(
        "--subdivisions", type=int, default=8, help="icosphere subdivisions (8: 1.31M triangles)"
    )
    parser.add_argument("--rays", type=int, default=1_000_000, help="camera rays per mesh")
    parser.add_argument("--repeats", type=int, default=5, help="timed rounds of every contender")
    parser.add_argument("--build-repeats", type=int, default=3, help="BVH builds (best counts)")
    parser.add_argument(
        "--threads", type=int, default=usable_cores(), help="threads for 'all threads'"
    )
    parser.add_argument("--noise", type=float, default=0.02, help="radial noise of 'bumpy'")
    parser.add_argument("--seed", type=int, default=1, help="seed of the noise and the rays")
    parser.add_argument("--no-embree", action="store_true", help="time tilerender alone")
    args = parser.parse_args(argv)
    for name in ("subdivisions", "rays", "repeats", "build_repeats", "threads"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1")
    return args


# --- scenes and rays -------------------------------------------------------------------------


def icospheres(subdivisions: int, noise: float, seed: int) -> list[Mesh]:
    """The smooth unit icosphere and a bumpy copy (radii scaled by 1 + U(-noise, noise))."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    vertices = np.asarray(sphere.vertices, np.float64)
    faces = np.asarray(sphere.faces)
    rng = np.random.default_rng(seed)
    bumpy = vertices * (1.0 + rng.uniform(-noise, noise, (vertices.shape[0], 1)))
    return [
        Mesh("smooth", vertices[faces].reshape(-1, 9).astype(np.float32)),
        Mesh("bumpy", bumpy[faces].reshape(-1, 9).astype(np.float32)),
    ]


def camera_rays(count: int, rng: np.random.Generator) -> RaySet:
    """Rays from a pinhole camera outside the unit sphere, through a jittered pixel grid in
    scanline order (the grid is as square as ``count`` allows)."""
    columns = int(np.ceil(np.sqrt(count)))
    rows = -(-count // columns)
    index = np.arange(count)
    jitter = rng.random((count, 2))
    tan_half = np.tan(np.radians(CAMERA_VFOV_DEG) / 2.0)
    x = ((index % columns + jitter[:, 0]) / columns * 2.0 - 1.0) * tan_half * columns / rows
    y = (1.0 - (index // columns + jitter[:, 1]) / rows * 2.0) * tan_half

    position = CAMERA_DISTANCE * unit(np.array([0.36, 0.48, 0.8]))
    forward = unit(-position)
    right = unit(np.cross(forward, [0.0, 1.0, 0.0]))
    up = np.cross(right, forward)
    directions = unit(forward + x[:, None] * right + y[:, None] * up)
    origins = np.broadcast_to(position, (count, 3))
    return RaySet("camera", np.ascontiguousarray(origins), np.ascontiguousarray(directions))


def unit(v: np.ndarray) -> np.ndarray:
    """``v`` (a vector or rows of vectors) scaled to unit length."""
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def facing_normals(tri_verts: np.ndarray, prim: np.ndarray, incoming: np.ndarray) -> np.ndarray:
    """Unit geometric normals of triangles ``prim``, flipped to face against ``incoming``."""
    v = tri_verts[prim].astype(np.float64).reshape(-1, 3, 3)
    normals = unit(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]))
    flip = np.einsum("ij,ij->i", normals, incoming) > 0.0
    normals[flip] *= -1.0
    return normals


def cosine_directions(normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Cosine-distributed unit directions about each unit normal (Duff et al.'s basis)."""
    nx, ny, nz = normals.T
    sign = np.where(nz >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    tangent = np.stack([1.0 + sign * nx * nx * a, sign * b, -sign * nx], axis=1)
    bitangent = np.stack([b, sign + ny * ny * a, -ny], axis=1)
    u1, u2 = rng.random((2, normals.shape[0]))
    r, phi = np.sqrt(u1)[:, None], 2.0 * np.pi * u2[:, None]
    z = np.sqrt(np.maximum(0.0, 1.0 - u1))[:, None]
    return unit(r * np.cos(phi) * tangent + r * np.sin(phi) * bitangent + z * normals)


def diffuse_rays(mesh: Mesh, camera: RaySet, hits: Hits, rng: np.random.Generator) -> RaySet:
    """One diffuse bounce from every camera ray that hit (in the camera rays' order)."""
    hit = hits.prim >= 0
    incoming = camera.directions[hit]
    points = camera.origins[hit] + hits.t[hit, None] * incoming
    normals = facing_normals(mesh.tri_verts, hits.prim[hit], incoming)
    offset = RELATIVE_OFFSET * np.abs(points).max(axis=1, keepdims=True)
    origins = points + offset * normals
    return RaySet("diffuse", origins, cosine_directions(normals, rng))


# --- engines ---------------------------------------------------------------------------------


def build_bvh(mesh: Mesh, repeats: int) -> tuple[float, bvh.TraversalBVH]:
    """Best seconds of ``repeats`` builds (canonical build plus traversal layout) and the BVH."""
    best, trav = np.inf, None
    for _ in range(repeats):
        seconds, trav = time_call(
            lambda: bvh.to_traversal(bvh.build(mesh.tri_verts), mesh.tri_verts)
        )
        best = min(best, seconds)
    return best, trav


def warm_up_kernels() -> float:
    """Compile (or load from the cache) every kernel timed here, on a tiny mesh; seconds taken."""
    tiny = icospheres(1, 0.0, 0)[0]
    start = np.zeros((4, 3)) + [0.0, 0.0, 3.0]
    toward = np.tile([0.0, 0.0, -1.0], (4, 1))

    def compile_all() -> None:
        trav = bvh.to_traversal(bvh.build(tiny.tri_verts), tiny.tri_verts)
        closest_hits(trav, start, toward, threads=1)
        any_hits(trav, start, toward, 1.0, threads=1)

    seconds, _ = time_call(compile_all)
    return seconds


class Embree:
    """An embreex scene over a mesh (one thread: embreex loops over rays in C)."""

    def __init__(self, mesh: Mesh):
        from embreex import rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh

        def build() -> Any:
            scene = rtcs.EmbreeScene()
            TriangleMesh(scene, mesh.tri_verts.reshape(-1, 3, 3))
            scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))  # commits
            return scene

        self.build_seconds, self.scene = time_call(build)

    def closest(self, origins: np.ndarray, directions: np.ndarray) -> dict[str, np.ndarray]:
        return self.scene.run(origins, directions, output=1)

    def occluded(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray) -> Any:
        return self.scene.run(origins, directions, dists=t_max.copy(), query="OCCLUDED") != -1


def embree_available() -> bool:
    try:
        import embreex  # noqa: F401
    except ImportError:
        note("embreex is not installed (pip install embreex); timing tilerender alone")
        return False
    return True


def closest_contenders(
    trav: bvh.TraversalBVH, embree: Embree | None, rays: RaySet, threads: int
) -> dict[str, Contender]:
    """Closest-hit queries of ``rays`` by tilerender (1 and ``threads`` threads) and Embree."""
    o, d = rays.origins, rays.directions
    contenders = {
        "tilerender 1T": Contender(lambda _: closest_hits(trav, o, d, threads=1)),
        f"tilerender {threads}T": Contender(lambda _: closest_hits(trav, o, d, threads=threads)),
    }
    if embree is not None:
        o32, d32 = o.astype(np.float32), d.astype(np.float32)
        contenders["embree 1T"] = Contender(lambda _: embree.closest(o32, d32))
    return contenders


def any_contenders(
    trav: bvh.TraversalBVH, embree: Embree | None, rays: RaySet, t_max: np.ndarray, threads: int
) -> dict[str, Contender]:
    """Any-hit queries of ``rays`` up to ``t_max`` by tilerender and Embree."""
    o, d = rays.origins, rays.directions
    contenders = {
        "tilerender 1T": Contender(lambda _: any_hits(trav, o, d, t_max, threads=1)),
        f"tilerender {threads}T": Contender(lambda _: any_hits(trav, o, d, t_max, threads=threads)),
    }
    if embree is not None:
        o32, d32, t32 = o.astype(np.float32), d.astype(np.float32), t_max.astype(np.float32)
        contenders["embree 1T"] = Contender(lambda _: embree.occluded(o32, d32, t32))
    return contenders


def first_results() -> tuple[dict[str, Any], Callable[[str, int, Any], None]]:
    """A dict and an ``on_result`` hook that keeps each contender's round-0 answer."""
    kept: dict[str, Any] = {}

    def keep(name: str, round_index: int, value: Any) -> None:
        if round_index == 0:
            kept[name] = value

    return kept, keep


def compare_closest(ours: Hits, embree: dict[str, np.ndarray]) -> dict[str, Any]:
    """How far tilerender's closest hits and Embree's agree."""
    prim_e = embree["primID"]
    agree = ours.prim == prim_e
    both = (ours.prim >= 0) & (prim_e >= 0)
    one = (ours.prim >= 0) != (prim_e >= 0)
    different = both & ~agree
    u, v = embree["u"].astype(np.float64), embree["v"].astype(np.float64)
    embree_min_b = np.minimum(np.minimum(u, v), 1.0 - u - v)
    on_edge = different & (np.minimum(ours.b.min(axis=1), embree_min_b) < EDGE_BARYCENTRIC)
    dt = np.abs(ours.t - embree["tfar"].astype(np.float64))
    rel_t = dt / np.where(both, ours.t, 1.0)
    same = both & agree
    return {
        "rays": int(agree.size),
        "hit_fraction": float((ours.prim >= 0).mean()),
        "prim_agreement": float(agree.mean()),
        "hit_miss_mismatches": int(one.sum()),
        "different_prims": int(different.sum()),
        "different_prims_on_edge": int(on_edge.sum()),
        "max_relative_t_difference": float(rel_t[both].max(initial=0.0)),
        "max_relative_t_difference_same_prim": float(rel_t[same].max(initial=0.0)),
        "max_abs_t_difference_same_prim": float(dt[same].max(initial=0.0)),
        "disagreements": disagreement_samples(ours, embree, embree_min_b, np.flatnonzero(~agree)),
    }


def disagreement_samples(
    ours: Hits,
    embree: dict[str, np.ndarray],
    embree_min_b: np.ndarray,
    rays: np.ndarray,
    limit: int = 20,
) -> list[dict[str, Any]]:
    """The first ``limit`` rays the engines disagree on, for the JSON file."""
    return [
        {
            "ray": int(i),
            "prim": int(ours.prim[i]),
            "t": float(ours.t[i]),
            "min_barycentric": float(ours.b[i].min()) if ours.prim[i] >= 0 else None,
            "embree_prim": int(embree["primID"][i]),
            "embree_t": float(embree["tfar"][i]) if embree["primID"][i] >= 0 else None,
            "embree_min_barycentric": float(embree_min_b[i]) if embree["primID"][i] >= 0 else None,
        }
        for i in rays[:limit]
    ]


# --- reporting -------------------------------------------------------------------------------


def rate_cells(series: Series | None) -> list[str]:
    """Median and best Mrays/s of a contender (dashes if it did not run)."""
    if series is None:
        return ["-", "-"]
    return [fmt_float(series.median_rate / 1e6), fmt_float(series.best_rate / 1e6)]


def per_core(series: dict[str, Series]) -> dict[str, float] | None:
    """Throughput ratios tilerender 1T / Embree 1T (None without Embree)."""
    if "embree 1T" not in series:
        return None
    ours, theirs = series["tilerender 1T"], series["embree 1T"]
    return {
        "median": ours.median_rate / theirs.median_rate,
        "best": ours.best_rate / theirs.best_rate,
    }


def per_core_verdict(ratio: float) -> str:
    """PASS, PASS (stretch) or MISS for a per-core throughput ratio."""
    if ratio >= PER_CORE_STRETCH:
        return "PASS (stretch)"
    return verdict(ratio, PER_CORE_TARGET)


def print_build_table(rows: list[dict[str, Any]]) -> None:
    """Build seconds and bytes per triangle of every mesh, with their verdicts."""
    print_table(
        "BVH build and memory",
        [
            "mesh",
            "triangles",
            "build s (best)",
            "s / M tris",
            f"<= {BUILD_TARGET}",
            "B/tri BVH",
            "B/tri + mat id",
            f"<= {MEMORY_TARGET:g}",
            "embree build s",
        ],
        [
            [
                r["mesh"],
                f"{r['triangles']:,}",
                fmt_float(r["build_seconds"], 3),
                fmt_float(r["build_seconds_per_million"], 3),
                styled_verdict(r["build_verdict"]),
                fmt_float(r["bytes_per_triangle_bvh"], 1),
                fmt_float(r["bytes_per_triangle"], 1),
                styled_verdict(r["memory_verdict"]),
                fmt_float(r.get("embree_build_seconds"), 3),
            ]
            for r in rows
        ],
        caption="build: bvh.build + bvh.to_traversal; memory: trav.nbytes / triangles "
        f"(+ {MATERIAL_ID_BYTES} B material id the renderer keeps per triangle)",
    )


def print_speed_table(
    title: str, rows: list[dict[str, Any]], threads: int, targeted: bool = True
) -> None:
    """Mrays/s of every contender and the per-core ratio (with verdicts if ``targeted``)."""
    columns = ["mesh / rays", "rays", "ours 1T", "best", f"ours {threads}T", "best"]
    columns += ["embree 1T", "best", "1T/embree", "best", "verdict"]
    table = []
    for r in rows:
        s = r["series"]
        ratio = r.get("per_core")
        table.append(
            [
                r["label"],
                f"{r['rays']:,}",
                *rate_cells(s["tilerender 1T"]),
                *rate_cells(s[f"tilerender {threads}T"]),
                *rate_cells(s.get("embree 1T")),
                fmt_float(ratio and ratio["median"]),
                fmt_float(ratio and ratio["best"]),
                styled_verdict(r.get("verdict", "-")),
            ]
        )
    print_table(
        title,
        columns,
        table,
        caption="Mrays/s, median and best of the rounds"
        + (
            f"; verdict on the 1T/embree ratio of medians (target >= {PER_CORE_TARGET}, "
            f"stretch >= {PER_CORE_STRETCH})"
            if targeted
            else ""
        ),
    )


def print_validation_table(rows: list[dict[str, Any]]) -> None:
    """How well tilerender's closest hits match Embree's."""
    print_table(
        "Agreement with Embree (closest hits)",
        [
            "mesh / rays",
            "hit",
            "same prim",
            "hit vs miss",
            "other prim",
            "on edge",
            "max rel dt",
            "same prim",
            "max abs dt",
        ],
        [
            [
                r["label"],
                f"{100 * v['hit_fraction']:.2f}%",
                f"{100 * v['prim_agreement']:.4f}%",
                v["hit_miss_mismatches"],
                v["different_prims"],
                v["different_prims_on_edge"],
                f"{v['max_relative_t_difference']:.1e}",
                f"{v['max_relative_t_difference_same_prim']:.1e}",
                f"{v['max_abs_t_difference_same_prim']:.1e}",
            ]
            for r in rows
            if (v := r.get("validation"))
        ],
        caption=f"on edge: different triangles hit, one of the hits within barycentric "
        f"{EDGE_BARYCENTRIC:g} of an edge (a shared or silhouette edge). dt: difference of the "
        "distances where both hit (all, then same triangle only; abs in sphere radii); "
        "Embree's float32 ray origins limit the relative agreement of short diffuse rays",
    )


# --- the benchmark ---------------------------------------------------------------------------


def run_rays(
    label: str,
    contenders: dict[str, Contender],
    count: int,
    repeats: int,
) -> tuple[dict[str, Series], dict[str, Any]]:
    """Interleave ``contenders`` for ``repeats`` rounds; their series and round-0 answers."""
    kept, keep = first_results()
    with console.status(f"{label}: {repeats} rounds of {', '.join(contenders)}"):
        series = interleaved(contenders, dict.fromkeys(contenders, count), repeats, keep)
    return series, kept


def speed_row(
    label: str, rays: int, series: dict[str, Series], targeted: bool = True
) -> dict[str, Any]:
    """A table row (and JSON entry) of one ray set's timings; ``targeted`` rows get a verdict
    on the per-core ratio."""
    row = {"label": label, "rays": rays, "series": series}
    ratio = per_core(series)
    if ratio is not None:
        row["per_core"] = ratio
        if targeted:
            row["verdict"] = per_core_verdict(ratio["median"])
    return row


def bench_mesh(mesh: Mesh, args: argparse.Namespace, use_embree: bool) -> dict[str, Any]:
    """Build, closest-hit and any-hit measurements of one mesh."""
    rng = np.random.default_rng(args.seed)
    with console.status(f"{mesh.name}: {args.build_repeats} BVH builds"):
        build_seconds, trav = build_bvh(mesh, args.build_repeats)
    bvh_bytes = trav.nbytes / mesh.triangles
    build = {
        "mesh": mesh.name,
        "triangles": mesh.triangles,
        "build_seconds": build_seconds,
        "build_seconds_per_million": build_seconds / (mesh.triangles / 1e6),
        "bytes_per_triangle_bvh": bvh_bytes,
        "bytes_per_triangle": bvh_bytes + MATERIAL_ID_BYTES,
        "bvh_nbytes": trav.nbytes,
    }
    build["build_verdict"] = verdict(build["build_seconds_per_million"], BUILD_TARGET, True)
    build["memory_verdict"] = verdict(build["bytes_per_triangle"], MEMORY_TARGET, True)
    embree = None
    if use_embree:
        with console.status(f"{mesh.name}: Embree build"):
            embree = Embree(mesh)
        build["embree_build_seconds"] = embree.build_seconds

    closest_rows, validation_rows = [], []
    camera = camera_rays(args.rays, rng)
    hits_for_bounce = closest_hits(trav, camera.origins, camera.directions, threads=args.threads)
    diffuse = diffuse_rays(mesh, camera, hits_for_bounce, rng)
    diffuse_hits = None
    for rays in (camera, diffuse):
        label = f"{mesh.name} / {rays.name}"
        contenders = closest_contenders(trav, embree, rays, args.threads)
        series, answers = run_rays(label, contenders, rays.count, args.repeats)
        row = speed_row(label, rays.count, series)
        ours = answers["tilerender 1T"]
        row["threads_agree"] = bool(
            np.array_equal(ours.prim, answers[f"tilerender {args.threads}T"].prim)
        )
        if embree is not None:
            row["validation"] = compare_closest(ours, answers["embree 1T"])
            validation_rows.append(row)
        closest_rows.append(row)
        diffuse_hits = ours

    t_max = 0.5 * diffuse_hits.t
    label = f"{mesh.name} / {diffuse.name}"
    contenders = any_contenders(trav, embree, diffuse, t_max, args.threads)
    series, answers = run_rays(f"{label} (any hit)", contenders, diffuse.count, args.repeats)
    any_row = speed_row(label, diffuse.count, series, targeted=False)
    any_row["occluded"] = {name: int(np.count_nonzero(a)) for name, a in answers.items()}
    return {
        "build": build,
        "closest": closest_rows,
        "validation": validation_rows,
        "any": [any_row],
    }


def json_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Rows with their timing series summarised (Mrays/s) for the JSON file."""
    return [
        {**r, "series": {name: s.summary(scale=1e6) for name, s in r["series"].items()}}
        for r in rows
    ]


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    machine = machine_info()
    machine["embreex"] = package_version("embreex")
    print_machine(machine)
    use_embree = not args.no_embree and embree_available()
    with console.status("compiling or loading the kernels"):
        note(f"kernel warm-up took {warm_up_kernels():.1f} s")

    results = [
        bench_mesh(mesh, args, use_embree)
        for mesh in icospheres(args.subdivisions, args.noise, args.seed)
    ]

    print_build_table([r["build"] for r in results])
    print_speed_table(
        "Closest hit, Mrays/s", [row for r in results for row in r["closest"]], args.threads
    )
    if use_embree:
        print_validation_table([row for r in results for row in r["validation"]])
    any_rows = [row for r in results for row in r["any"]]
    print_speed_table(
        "Any hit (t_max = half the closest hit), Mrays/s", any_rows, args.threads, targeted=False
    )
    for row in any_rows:
        occluded = ", ".join(f"{name}: {n}" for name, n in row["occluded"].items())
        console.print(f"any hit, {row['label']}: occluded rays (expected 0): {occluded}")
    for row in (row for r in results for row in r["closest"]):
        if not row["threads_agree"]:
            note(f"{row['label']}: 1-thread and multi-thread answers differ")

    write_results(
        "raycast",
        {
            "settings": vars(args),
            "targets": {
                "build_seconds_per_million_at_most": BUILD_TARGET,
                "bytes_per_triangle_at_most": MEMORY_TARGET,
                "per_core_ratio_at_least": PER_CORE_TARGET,
                "per_core_ratio_stretch": PER_CORE_STRETCH,
            },
            "meshes": [
                {
                    "build": r["build"],
                    "closest": json_rows(r["closest"]),
                    "any": json_rows(r["any"]),
                }
                for r in results
            ],
        },
        machine,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
