"""What robustness costs: primary rays through tilerender's intersector against the same
traversal with the intersector of before the fixes, side by side in one run.

"Before the fixes" (``naive_closest``, below): a Moller-Trumbore triangle test with a constant
epsilon on ``t``, and a slab test with min/max swaps and no widening; same BVH, same traversal
order, same float32 data, float64 arithmetic. "After" is ``tracer.geometry.raycast.closest_hits``:
watertight test, the ``deltaT`` rejection near ``t = 0``, the NaN-safe sign-selected slab test.

Workloads: camera rays on the ~1.31M-triangle smooth and bumpy icospheres of
``bench/raycast.py`` and on the Cornell box. Single thread, interleaved rounds. The closed
spheres also show what the fixes buy: how many camera rays the naive test lets slip through.
"""

import argparse
import sys
from pathlib import Path

import numpy as np
from common import (
    Contender,
    interleaved,
    machine_info,
    note,
    print_machine,
    print_table,
    ratios,
    styled_verdict,
    verdict,
    write_results,
)
from numba import njit
from raycast import camera_rays, icospheres

from tracer import config
from tracer.compiled.scene import STATIC_KEY, compile_scene
from tracer.geometry import bvh
from tracer.geometry.intersect import nearest_first4, push_far
from tracer.geometry.raycast import Hits, _closest
from tracer.kernel.borrow import borrowed
from tracer.scene.loader import load_scene

ROOT = Path(__file__).resolve().parents[1]
TARGET_COST = 0.10
"""Robustness may cost at most 10% of primary-ray throughput."""
NAIVE_EPSILON = 1e-7


@njit(cache=True, error_model="numpy", inline="always")
def _naive_slab(b, node, s, ox, oy, oz, ix, iy, iz, t_max):
    """Entry distance into the box of slot ``s`` of a wide node (tracer.geometry.bvh layout), or
    inf."""
    t0 = (b[node, s] - ox) * ix
    t1 = (b[node, 12 + s] - ox) * ix
    near = min(t0, t1)
    far = max(t0, t1)
    t0 = (b[node, 4 + s] - oy) * iy
    t1 = (b[node, 16 + s] - oy) * iy
    near = max(near, min(t0, t1))
    far = min(far, max(t0, t1))
    t0 = (b[node, 8 + s] - oz) * iz
    t1 = (b[node, 20 + s] - oz) * iz
    near = max(near, min(t0, t1))
    far = min(far, max(t0, t1))
    near = max(near, 0.0)
    far = min(far, t_max)
    return near if near <= far and near < t_max else np.inf


@njit(cache=True, error_model="numpy", inline="always")
def _moller_trumbore(tv, j, o, d, t_max):
    e1x = tv[j, 3] - np.float64(tv[j, 0])
    e1y = tv[j, 4] - np.float64(tv[j, 1])
    e1z = tv[j, 5] - np.float64(tv[j, 2])
    e2x = tv[j, 6] - np.float64(tv[j, 0])
    e2y = tv[j, 7] - np.float64(tv[j, 1])
    e2z = tv[j, 8] - np.float64(tv[j, 2])
    px = d[1] * e2z - d[2] * e2y
    py = d[2] * e2x - d[0] * e2z
    pz = d[0] * e2y - d[1] * e2x
    det = e1x * px + e1y * py + e1z * pz
    if det == 0.0:
        return np.inf
    inv = 1.0 / det
    sx = o[0] - tv[j, 0]
    sy = o[1] - tv[j, 1]
    sz = o[2] - tv[j, 2]
    u = (sx * px + sy * py + sz * pz) * inv
    if u < 0.0 or u > 1.0:
        return np.inf
    qx = sy * e1z - sz * e1y
    qy = sz * e1x - sx * e1z
    qz = sx * e1y - sy * e1x
    v = (d[0] * qx + d[1] * qy + d[2] * qz) * inv
    if v < 0.0 or u + v > 1.0:
        return np.inf
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    return t if NAIVE_EPSILON < t < t_max else np.inf


@njit(cache=True, error_model="numpy", nogil=True)
def naive_closest(
    node_bounds, node_child, tri_verts, tri_prim, origins, directions, stack_node, stack_t, prim
):
    """Closest hits with the pre-fix intersector; same traversal as tracer.geometry.intersect."""
    node_bounds = borrowed(node_bounds)
    node_child = borrowed(node_child)
    tri_verts = borrowed(tri_verts)
    stack_node = borrowed(stack_node)
    stack_t = borrowed(stack_t)
    for i in range(origins.shape[0]):
        o = (origins[i, 0], origins[i, 1], origins[i, 2])
        d = (directions[i, 0], directions[i, 1], directions[i, 2])
        ix = 1.0 / d[0]
        iy = 1.0 / d[1]
        iz = 1.0 / d[2]
        t_hit = np.inf
        hit = -1
        sp = 0
        entry = 0
        while True:
            if entry >= 0:
                t0 = _naive_slab(node_bounds, entry, 0, o[0], o[1], o[2], ix, iy, iz, t_hit)
                t1 = _naive_slab(node_bounds, entry, 1, o[0], o[1], o[2], ix, iy, iz, t_hit)
                t2 = _naive_slab(node_bounds, entry, 2, o[0], o[1], o[2], ix, iy, iz, t_hit)
                t3 = _naive_slab(node_bounds, entry, 3, o[0], o[1], o[2], ix, iy, iz, t_hit)
                t0, c0, t1, c1, t2, c2, t3, c3 = nearest_first4(
                    t0, node_child[entry, 0], t1, node_child[entry, 1],
                    t2, node_child[entry, 2], t3, node_child[entry, 3],
                )  # fmt: skip
                sp = push_far(stack_node, stack_t, sp, t1, c1, t2, c2, t3, c3)
                if t0 < np.inf:
                    entry = c0
                    continue
            else:
                v = -1 - entry
                for j in range(v >> 3, (v >> 3) + (v & 7)):
                    t = _moller_trumbore(tri_verts, j, o, d, t_hit)
                    if t < t_hit:
                        t_hit = t
                        hit = j
            found = False
            while sp > 0:
                sp -= 1
                if stack_t[sp] < t_hit:
                    entry = stack_node[sp]
                    found = True
                    break
            if not found:
                break
        prim[i] = tri_prim[hit] if hit >= 0 else -1


def cornell_camera_rays(count: int, rng: np.random.Generator):
    """Jittered primary rays of the Cornell box's own camera, in its static mesh's space."""
    scene = compile_scene(load_scene(ROOT / "scenes" / "cornell-box" / "scene.json"))
    cam = scene.camera
    side = int(np.ceil(np.sqrt(count)))
    idx = np.arange(side * side)[:count]
    jitter = rng.random((count, 2))
    tan_half = np.tan(np.radians(cam.vfov_deg) / 2.0)
    x = ((idx % side + jitter[:, 0]) / side * 2.0 - 1.0) * tan_half
    y = (1.0 - (idx // side + jitter[:, 1]) / side * 2.0) * tan_half
    static = scene.meshes[STATIC_KEY]
    position = np.asarray(cam.position) - static.center
    forward = np.asarray(cam.look_at) - np.asarray(cam.position)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, cam.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    d = forward + x[:, None] * right + y[:, None] * up
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return static.bvh, np.ascontiguousarray(np.broadcast_to(position, (count, 3))), d


def measure(name, accel, origins, directions, repeats):
    """Time both intersectors on one workload, each as a bare kernel call on one thread with
    preallocated outputs (no input checks); returns a table row and a JSON record."""
    n = len(origins)
    tables = (accel.node_bounds, accel.node_child, accel.tri_verts, accel.tri_prim)
    stacks = (
        np.empty(config.TRAVERSAL_STACK_SIZE, np.int32),
        np.empty(config.TRAVERSAL_STACK_SIZE, np.float64),
    )
    t_max = np.full(n, np.inf)
    robust_out = Hits(
        np.full(n, -1, np.int32),
        np.full(n, np.inf),
        np.zeros((n, 3)),
        np.zeros(n, np.int64),
        np.full(n, -1, np.int32),
    )
    naive_prim = np.full(n, -1, np.int32)

    def robust(_round):
        _closest(*tables, origins, directions, t_max, 0, 1, *stacks, *robust_out)
        return robust_out.prim.copy()

    def naive(_round):
        naive_closest(*tables, origins, directions, *stacks, naive_prim)
        return naive_prim.copy()

    robust(0)  # compile or load from the cache
    naive(0)
    answers = {}
    series = interleaved(
        {"robust": Contender(robust), "naive": Contender(naive)},
        {"robust": n, "naive": n},
        repeats,
        on_result=lambda who, _r, value: answers.__setitem__(who, value),
    )
    ratio = ratios(series["robust"], series["naive"])
    cost = 1.0 - ratio["paired_median"]
    slipped = int(((answers["naive"] < 0) & (answers["robust"] >= 0)).sum())
    row = [
        name,
        f"{series['robust'].median_rate / 1e6:.2f}",
        f"{series['naive'].median_rate / 1e6:.2f}",
        f"{100 * cost:+.1f}%",
        styled_verdict(verdict(cost, TARGET_COST, at_most=True)),
        str(slipped),
    ]
    result = {
        "workload": name,
        "robust": series["robust"].summary(1e6),
        "naive": series["naive"].summary(1e6),
        "ratio": ratio,
        "cost": cost,
        "naive_misses_where_robust_hits": slipped,
    }
    return row, result


def parse_args(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rays", type=int, default=1_000_000, help="camera rays per workload")
    parser.add_argument("--repeats", type=int, default=5, help="interleaved rounds")
    parser.add_argument("--subdivisions", type=int, default=8, help="icosphere subdivisions")
    return parser.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    machine = machine_info()
    print_machine(machine)
    rng = np.random.default_rng(5)
    workloads = []
    for mesh in icospheres(args.subdivisions, 0.02, 7):
        accel = bvh.to_traversal(bvh.build(mesh.tri_verts), mesh.tri_verts)
        rays = camera_rays(args.rays, rng)
        workloads.append((f"{mesh.name} sphere", accel, rays.origins, rays.directions))
    workloads.append(("Cornell box", *cornell_camera_rays(args.rays, rng)))

    measured = [measure(*workload, args.repeats) for workload in workloads]
    rows = [row for row, _ in measured]
    results = [result for _, result in measured]
    print_table(
        "Primary rays, one thread: robust vs pre-fix intersector (Mrays/s, median)",
        ["workload", "robust", "naive", "cost", "<= 10%", "rays naive lets slip"],
        rows,
    )
    note("cost = 1 - median over rounds of (robust rate / naive rate), each round side by side")
    write_results("robustness_cost", {"args": vars(args), "workloads": results}, machine)
    return 0


if __name__ == "__main__":
    sys.exit(main())
