"""Single-ray and batched queries against a compiled scene (Bikker 7.3.6): picking, line of
sight. World-space rays in, and for each: the scene node hit, the triangle of that node's mesh,
the distance, the world-space point and unit geometric normal, and the material.
"""

from dataclasses import dataclass

import numpy as np

from tracer import config
from tracer.compiled.arrays import borrow_scene
from tracer.compiled.scene import CompiledScene, static_key
from tracer.geometry.raycast import check_rays
from tracer.geometry.scene_intersect import material_of, scene_closest, surface
from tracer.kernel.borrow import borrowed
from tracer.kernel.jit import jit
from tracer.kernel.threads import run_parts

RAY_BLOCK = 256


@jit
def _scene_rays(
    scene, origins, directions, t_max, first, stride, stack_node, stack_t, inst, row, t, point,
    normal, material,
):  # fmt: skip
    s = borrow_scene(scene)
    stack_node = borrowed(stack_node)
    stack_t = borrowed(stack_t)
    n = origins.shape[0]
    for block in range(first, (n + RAY_BLOCK - 1) // RAY_BLOCK, stride):
        for i in range(block * RAY_BLOCK, min(n, (block + 1) * RAY_BLOCK)):
            o = (origins[i, 0], origins[i, 1], origins[i, 2])
            d = (directions[i, 0], directions[i, 1], directions[i, 2])
            k, j, t_hit, b0, b1, b2, _ = scene_closest(s, o, d, t_max[i], stack_node, stack_t)
            if k < 0:
                continue
            _, _, _, p, ng = surface(s, k, j, b0, b1, b2)
            inst[i] = k
            row[i] = j
            t[i] = t_hit
            material[i] = material_of(s, k, j)
            for c in range(3):
                point[i, c] = p[c]
                normal[i, c] = ng[c]


@dataclass
class SceneHits:
    """Per ray: ``node`` scene node id (-1 for a miss), ``triangle`` index in that node's mesh,
    ``t`` distance in units of the direction (inf for a miss), world ``point`` and unit
    geometric ``normal`` (counter-clockwise front; NaN rows for misses), ``material`` name (None
    for a miss)."""

    node: np.ndarray
    triangle: np.ndarray
    t: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    material: list


def scene_hits(
    scene: CompiledScene,
    origins: np.ndarray,
    directions: np.ndarray,
    t_max: np.ndarray | float | None = None,
    threads: int | None = None,
) -> SceneHits:
    """Closest hits of world-space rays ``origins[i] + t * directions[i]``, ``t`` in (0, t_max)."""
    origins, directions, t_max = check_rays(origins, directions, t_max)
    n = origins.shape[0]
    render_origins = origins - scene.origin
    inst = np.full(n, -1, np.int32)
    row = np.full(n, -1, np.int32)
    t = np.full(n, np.inf)
    point = np.full((n, 3), np.nan)
    normal = np.full((n, 3), np.nan)
    material = np.full(n, -1, np.int32)

    def work(part: int, parts: int) -> None:
        stack_node = np.empty(config.TRAVERSAL_STACK_SIZE, np.int32)
        stack_t = np.empty(config.TRAVERSAL_STACK_SIZE, np.float64)
        _scene_rays(
            scene.arrays, render_origins, directions, t_max, part, parts, stack_node, stack_t,
            inst, row, t, point, normal, material,
        )  # fmt: skip

    run_parts(work, threads)
    hit = inst >= 0
    node = np.full(n, -1, np.int32)
    triangle = np.full(n, -1, np.int32)
    node[hit] = scene.instance_nodes[inst[hit]]
    for pool_index, pool in enumerate(scene.pools):
        mine = hit & (scene.arrays.inst_pool[np.maximum(inst, 0)] == pool_index)
        triangle[mine] = pool.tri_prim[row[mine]]
    for k in range(scene.static_clusters):
        static = hit & (node == -1 - k)
        if static.any():
            owner = scene.meshes[static_key(k)].owner
            node[static] = owner[triangle[static], 0]
            triangle[static] = owner[triangle[static], 1]
    point[hit] += scene.origin
    names = scene.material_names
    return SceneHits(
        node, triangle, t, point, normal, [names[m] if m >= 0 else None for m in material]
    )
