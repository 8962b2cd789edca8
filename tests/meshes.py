"""Closed test meshes generated in code (nothing large is stored in the repo)."""

import numpy as np
import trimesh


def jittered_icosphere(
    subdivisions: int, jitter: float, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """A closed icosphere whose shared vertices are moved radially by up to ``jitter``."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions)
    rng = np.random.default_rng(seed)
    radius = 1.0 + rng.uniform(-jitter, jitter, size=(len(mesh.vertices), 1))
    return np.asarray(mesh.vertices) * radius, np.asarray(mesh.faces)


def menger_cells(level: int) -> np.ndarray:
    """Integer coordinates (n, 3) of the solid unit cells of a Menger sponge of side 3**level."""
    cells = np.zeros((1, 3), dtype=np.int64)
    for _ in range(level):
        offsets = np.array(
            [
                (x, y, z)
                for x in range(3)
                for y in range(3)
                for z in range(3)
                if (x == 1) + (y == 1) + (z == 1) < 2
            ]
        )
        cells = (cells[:, None, :] * 3 + offsets[None, :, :]).reshape(-1, 3)
    return cells


def menger_sponge(level: int) -> tuple[np.ndarray, np.ndarray]:
    """The closed surface of a Menger sponge of side 1: cell faces between a solid and an empty
    cell, two triangles each, wound counter-clockwise seen from outside. Adjacent faces share
    their edges exactly (no T-junctions), so the surface is closed."""
    cells = menger_cells(level)
    solid = {tuple(c) for c in cells}
    quads = []
    for c in cells:
        for axis in range(3):
            for sign in (-1, 1):
                neighbour = c.copy()
                neighbour[axis] += sign
                if tuple(neighbour) in solid:
                    continue
                u, v = [a for a in range(3) if a != axis]
                base = c.astype(np.float64)
                if sign > 0:
                    base[axis] += 1.0
                corners = []
                for du, dv in ((0, 0), (1, 0), (1, 1), (0, 1)):
                    p = base.copy()
                    p[u] += du
                    p[v] += dv
                    corners.append(p)
                # Orient counter-clockwise about the outward normal (sign * e_axis).
                normal = np.zeros(3)
                normal[axis] = sign
                if np.dot(np.cross(corners[1] - corners[0], corners[2] - corners[0]), normal) < 0:
                    corners = corners[::-1]
                quads.append(corners)
    quads = np.array(quads) / 3.0**level
    vertices, inverse = np.unique(quads.reshape(-1, 3), axis=0, return_inverse=True)
    quad_index = inverse.reshape(-1, 4)
    faces = np.concatenate([quad_index[:, [0, 1, 2]], quad_index[:, [0, 2, 3]]])
    return vertices, faces
