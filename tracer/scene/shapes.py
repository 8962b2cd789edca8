"""Built-in shapes as (vertices float64 (V, 3), faces int64 (F, 3)), counter-clockwise outward,
the UVs of those that have them (rectangles and planes: the unit square across the shape), and
the shading normals of a smooth sphere."""

import numpy as np
import trimesh

from tracer.scene import format as fmt


def rectangle(width: float, height: float) -> tuple[np.ndarray, np.ndarray]:
    """Rectangle in the xy plane centred at the origin, facing +z."""
    hx, hy = 0.5 * width, 0.5 * height
    vertices = np.array([[-hx, -hy, 0.0], [hx, -hy, 0.0], [hx, hy, 0.0], [-hx, hy, 0.0]])
    return vertices, np.array([[0, 1, 2], [0, 2, 3]])


def box(size) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box centred at the origin with outward-facing triangles."""
    mesh = trimesh.creation.box(extents=size)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def sphere(radius: float, subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """Icosphere: 20 * 4**subdivisions triangles."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def plane(size: float) -> tuple[np.ndarray, np.ndarray]:
    """Square of side ``size`` in the xz plane through the origin, facing +y."""
    h = 0.5 * size
    vertices = np.array([[-h, 0.0, -h], [-h, 0.0, h], [h, 0.0, h], [h, 0.0, -h]])
    return vertices, np.array([[0, 1, 2], [0, 2, 3]])


def shape_mesh(shape) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of a built-in shape model from :mod:`tracer.scene.format`."""
    if isinstance(shape, fmt.Rectangle):
        return rectangle(*shape.size)
    if isinstance(shape, fmt.Box):
        return box(shape.size)
    if isinstance(shape, fmt.Sphere):
        return sphere(shape.radius, shape.subdivisions)
    if isinstance(shape, fmt.Plane):
        return plane(shape.size)
    raise TypeError(f"not a built-in shape: {shape!r}")


RECTANGLE_UVS = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
"""UVs of ``rectangle``'s vertices: ``u`` along +x, ``v`` along +y (an image seen from the
front stands upright)."""
PLANE_UVS = np.array([[0.0, 1.0], [0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])
"""UVs of ``plane``'s vertices: ``u`` along +x, ``v`` along -z (an image seen from above, with
-z up, is upright)."""


def shape_uvs(shape) -> np.ndarray | None:
    """UVs per vertex of a built-in shape (float64 (V, 2)), or None if it has none (box and
    sphere)."""
    if isinstance(shape, fmt.Rectangle):
        return RECTANGLE_UVS
    if isinstance(shape, fmt.Plane):
        return PLANE_UVS
    return None


def shape_normals(shape) -> np.ndarray | None:
    """Shading normals per vertex of a built-in shape (float64 (V, 3)), or None if it shades
    flat: a ``smooth`` sphere's are its vertices' directions from the centre."""
    if isinstance(shape, fmt.Sphere) and shape.smooth:
        vertices, _ = sphere(shape.radius, shape.subdivisions)
        return vertices / shape.radius  # make_mesh normalises them exactly
    return None
