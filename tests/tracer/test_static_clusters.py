"""tracer/compiled/static_clusters.py: which static nodes share a baked mesh, and the errors that
name the mesh float32 cannot hold."""

import numpy as np
import pytest

from tracer.compiled.scene import compile_scene
from tracer.compiled.static_clusters import REACH, cluster_nodes, snapped_center
from tracer.errors import SceneError
from tracer.scene.format import Camera, DiffuseMaterial, RenderSettings
from tracer.scene.loader import MeshData, SceneData


def boxes(*placed: tuple[float, float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of cubes given as (x, y, z, size)."""
    lo = np.array([p[:3] for p in placed], dtype=np.float64)
    return lo, lo + np.array([[p[3]] * 3 for p in placed])


def test_near_nodes_share_a_cluster_and_far_ones_do_not():
    lo, hi = boxes((0, 0, 0, 1), (0.2, 0.1, 0.3, 0.3), (0.5, 0.5, 0.5, 0.01), (1e6, 1e6, 1e6, 1),
                   (1e6 + 2, 1e6, 1e6, 0.5))  # fmt: skip
    assert cluster_nodes(lo, hi) == [[0, 1, 2], [3, 4]]


def test_a_node_joins_when_it_loses_at_most_log2_reach_bits():
    size = 0.01
    limit = (REACH - 1.0) * size / 2  # farthest centre offset from the origin (0)
    inside = limit - size / 2 - 1e-9  # its centre, not its corner
    lo, hi = boxes((-0.5, -0.5, -0.5, 1), (inside, 0, 0, size), (inside + 2e-9, 0, 0, size))
    lo[1:, 1:] -= size / 2
    hi[1:, 1:] -= size / 2
    clusters = cluster_nodes(lo, hi)
    assert clusters[0][:2] == [0, 1] and [2] in clusters


def test_clusters_do_not_depend_on_the_order_nodes_come_in():
    rng = np.random.default_rng(5)
    centers = rng.uniform(-1e4, 1e4, (300, 3)) * (rng.random((300, 1)) < 0.5)
    sizes = 10.0 ** rng.uniform(-2, 2, (300, 1))
    lo, hi = centers - sizes, centers + sizes
    clusters = cluster_nodes(lo, hi)
    order = rng.permutation(300)
    again = cluster_nodes(lo[order], hi[order])
    as_sets = {frozenset(c) for c in clusters}
    assert {frozenset(int(order[i]) for i in c) for c in again} == as_sets
    assert sorted(i for c in clusters for i in c) == list(range(300))
    half = 0.5 * np.max(hi - lo, axis=1)
    for c in clusters:  # every member within REACH half sizes of its cluster's origin
        origin = snapped_center(
            lo[max(c, key=lambda i: (half[i], -i))], hi[max(c, key=lambda i: (half[i], -i))]
        )
        for i in c:
            far = np.max(np.maximum(np.abs(lo[i] - origin), np.abs(hi[i] - origin)))
            assert far <= REACH * half[i] * (1 + 1e-12)


def scene_of(vertices, faces) -> SceneData:
    return SceneData(
        camera=Camera(position=(0.0, 0.0, 5.0), look_at=(0.0, 0.0, 0.0), width=8, height=8),
        render=RenderSettings(spp=1),
        material_names=["white"],
        materials=[DiffuseMaterial(reflectance=(0.5, 0.5, 0.5))],
        meshes=[MeshData("thin", np.asarray(vertices, float), np.asarray(faces), 0)],
    )


def test_a_mesh_float32_cannot_hold_is_named_with_the_reason():
    tiny = np.array([[0.0, 0.0, 0.0], [1e-6, 0.0, 0.0], [0.0, 1e-6, 0.0]])
    vertices = np.concatenate([tiny, tiny + [1e9, 0.0, 0.0]])
    with pytest.raises(SceneError, match=r"thin: its triangles are too small for float32.*1e\+09"):
        compile_scene(scene_of(vertices, [[0, 1, 2], [3, 4, 5]]))


def test_a_mesh_of_zero_area_is_named_as_such():
    with pytest.raises(SceneError, match="thin: every triangle of the mesh has zero area"):
        compile_scene(scene_of([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]]))
