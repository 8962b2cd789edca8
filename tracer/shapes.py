"""Built-in shapes as (vertices float64 (V, 3), faces int64 (F, 3)), counter-clockwise outward."""

import numpy as np
import trimesh

from tracer import scene_format as fmt


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
    """Triangles of a built-in shape model from :mod:`tracer.scene_format`."""
    if isinstance(shape, fmt.Rectangle):
        return rectangle(*shape.size)
    if isinstance(shape, fmt.Box):
        return box(shape.size)
    if isinstance(shape, fmt.Sphere):
        return sphere(shape.radius, shape.subdivisions)
    if isinstance(shape, fmt.Plane):
        return plane(shape.size)
    raise TypeError(f"not a built-in shape: {shape!r}")
