"""Make the lamp hall's lamps: thousands of small emissive triangles in three colours.

Run from the repository root (it rewrites the files beside this script)::

    python scenes/lamp-hall/make_lamp_hall.py

- ``lamps-warm.ply``, ``lamps-cool.ply``, ``lamps-red.ply``: per colour, square ceiling lamps
  (two triangles each, facing down) on a jittered 48 x 24 grid under the hall's 60 x 30 m
  ceiling, 3 m above the floor, and octahedral bulbs (eight triangles each, facing out)
  hanging at random heights; 3,904 emissive triangles in all.

The random numbers come from a fixed seed: the output is the same on every run.
"""

from pathlib import Path

import numpy as np
import trimesh

HERE = Path(__file__).resolve().parent
SEED = 26
HALL = (60.0, 3.0, 30.0)
"""The hall's size (x, y, z), its floor centred on the origin (``scene.json``'s room box)."""
GRID = (48, 24)
CEILING_LAMP = 0.1
"""A ceiling lamp's side (m)."""
BULBS = 200
BULB_RADIUS = 0.05
COLOURS = ("warm", "cool", "red")
WEIGHTS = (0.6, 0.3, 0.1)
"""How often each colour is drawn."""

OCTAHEDRON = np.array(
    [[0, 4, 2], [2, 4, 1], [1, 4, 3], [3, 4, 0], [2, 5, 0], [1, 5, 2], [3, 5, 1], [0, 5, 3]]
)
"""The faces of the unit octahedron's vertices +x, -x, +z, -z, +y, -y, counter-clockwise seen
from outside."""


def ceiling_lamps(rng: np.random.Generator) -> list[np.ndarray]:
    """One (4, 3) quad per grid cell, jittered, its vertices ordered to face down (-y)."""
    nx, nz = GRID
    half = 0.5 * CEILING_LAMP
    quads = []
    for i in range(nx):
        for k in range(nz):
            x = (i + 0.5 + rng.uniform(-0.3, 0.3)) * HALL[0] / nx - 0.5 * HALL[0]
            z = (k + 0.5 + rng.uniform(-0.3, 0.3)) * HALL[2] / nz - 0.5 * HALL[2]
            y = HALL[1] - 0.005
            corners = [(-half, -half), (half, -half), (half, half), (-half, half)]
            quads.append(np.array([[x + dx, y, z + dz] for dx, dz in corners]))
    return quads


def bulb(centre: np.ndarray) -> np.ndarray:
    """The six vertices of an octahedral bulb."""
    axes = np.array([[1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, 0, -1], [0, 1, 0], [0, -1, 0]])
    return centre + BULB_RADIUS * axes


def lamp_meshes() -> dict[str, trimesh.Trimesh]:
    """Each colour's lamps as one mesh."""
    rng = np.random.default_rng(SEED)
    parts = {c: ([], []) for c in COLOURS}

    def add(colour: str, vertices: np.ndarray, faces: np.ndarray) -> None:
        verts, tris = parts[colour]
        offset = sum(v.shape[0] for v in verts)
        verts.append(vertices)
        tris.append(faces + offset)

    for quad in ceiling_lamps(rng):
        colour = COLOURS[rng.choice(len(COLOURS), p=WEIGHTS)]
        # (0, 1, 2) and (0, 2, 3): counter-clockwise seen from below.
        add(colour, quad, np.array([[0, 1, 2], [0, 2, 3]]))
    for _ in range(BULBS):
        centre = np.array(
            [rng.uniform(-0.48, 0.48) * HALL[0], rng.uniform(1.2, 2.6),
             rng.uniform(-0.48, 0.48) * HALL[2]]
        )  # fmt: skip
        colour = COLOURS[rng.choice(len(COLOURS), p=WEIGHTS)]
        add(colour, bulb(centre), OCTAHEDRON)
    return {
        c: trimesh.Trimesh(np.concatenate(v), np.concatenate(f), process=False)
        for c, (v, f) in parts.items()
    }


def main() -> None:
    for colour, mesh in lamp_meshes().items():
        mesh.export(HERE / f"lamps-{colour}.ply", file_type="ply", encoding="ascii")


if __name__ == "__main__":
    main()
