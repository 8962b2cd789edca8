"""Small scene states built directly from ``tracer.scene.model``, and a deep comparison."""

import numpy as np

from tracer.scene import format as fmt
from tracer.scene.model import (
    Animation,
    CameraKey,
    Mesh,
    Node,
    NodeKey,
    SceneState,
    Sky,
    frozen_array,
    make_mesh,
)

TRIANGLE = ([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [[0, 1, 2]])
QUAD = (
    [[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]],
    [[0, 1, 2], [0, 2, 3]],
)


def translation(x: float, y: float, z: float) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, 3] = (x, y, z)
    return frozen_array(matrix, np.float64)


def node(node_id, name, parent=None, transform=None, kind="static", mesh=None, material=None):
    transform = frozen_array(np.eye(4), np.float64) if transform is None else transform
    return Node(node_id, name, parent, transform, kind, mesh, material)


def small_state(version: int = 0, animation: Animation | None = None) -> SceneState:
    """A group "room" holding a floor and a cube (the cube holds a "handle"), plus a lamp:

    ids 0 room (group), 1 floor (quad, white), 2 cube (tri, red, rigid, at x=2),
    3 handle (tri, red, child of cube, at y=1), 4 lamp (quad, light, at y=5).
    """
    meshes = {"quad": make_mesh(*QUAD, "quad"), "tri": make_mesh(*TRIANGLE, "tri")}
    materials = {
        "white": fmt.DiffuseMaterial(),
        "red": fmt.DiffuseMaterial(reflectance=(0.8, 0.1, 0.1)),
        "light": fmt.DiffuseMaterial(reflectance=(0.0, 0.0, 0.0), emission=(10.0, 10.0, 10.0)),
    }
    nodes = [
        node(0, "room"),
        node(1, "floor", 0, mesh="quad", material="white"),
        node(2, "cube", 0, translation(2, 0, 0), "rigid", "tri", "red"),
        node(3, "handle", 2, translation(0, 1, 0), "rigid", "tri", "red"),
        node(4, "lamp", None, translation(0, 5, 0), mesh="quad", material="light"),
    ]
    return SceneState(
        version=version,
        meshes=meshes,
        materials=materials,
        nodes={n.id: n for n in nodes},
        camera=fmt.Camera(position=(0.0, 2.0, 8.0), width=64, height=48),
        render=fmt.RenderSettings(spp=4),
        sky=Sky((0.1, 0.2, 0.3)),
        animation=animation,
    )


def spinning_animation() -> Animation:
    """The cube turns a half circle about y and moves along x over 1 s; the camera dollies in."""
    half_turn = (0.0, 0.0, 1.0, 0.0)
    return Animation(
        fps=4.0,
        frames=5,
        nodes={
            2: (
                NodeKey(0.0, (2.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (1.0, 1.0, 1.0)),
                NodeKey(1.0, (4.0, 0.0, 0.0), half_turn, (2.0, 2.0, 2.0)),
            )
        },
        camera=(
            CameraKey(0.0, (0.0, 2.0, 8.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0),
            CameraKey(1.0, (0.0, 2.0, 4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 60.0),
        ),
    )


def same_array(a: np.ndarray, b: np.ndarray) -> bool:
    """Bit-identical: same dtype, shape and bytes."""
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def assert_same_mesh(a: Mesh, b: Mesh) -> None:
    assert same_array(a.vertices, b.vertices) and same_array(a.faces, b.faces)
    for name in ("uvs", "normals"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None) and (x is None or same_array(x, y)), name


def assert_states_equal(a: SceneState, b: SceneState) -> None:
    """Every field equal; arrays bit for bit; table order preserved."""
    assert a.version == b.version
    assert list(a.meshes) == list(b.meshes)
    for name in a.meshes:
        assert_same_mesh(a.meshes[name], b.meshes[name])
    assert list(a.materials.items()) == list(b.materials.items())
    assert list(a.nodes) == list(b.nodes)
    for node_id, x in a.nodes.items():
        y = b.nodes[node_id]
        assert (x.id, x.name, x.parent, x.kind, x.mesh, x.material) == (
            y.id,
            y.name,
            y.parent,
            y.kind,
            y.mesh,
            y.material,
        )
        assert same_array(x.transform, y.transform)
    assert (a.camera, a.render, a.sky, a.animation) == (b.camera, b.render, b.sky, b.animation)
