"""Make the textured sample scene's assets: procedural images, a GLB crate and an OBJ poster.

Run from the repository root (it rewrites the files beside this script)::

    python scenes/textured/make_textured.py

- ``crate.glb``: a unit box with its own UVs per face and a glTF metallic-roughness material
  (metallic 0, roughness 0.6) whose ``baseColorTexture`` is ``crate.png`` (embedded);
- ``poster.obj`` + ``poster.mtl`` + ``poster.png``: a 1.6 x 1.2 quad whose MTL ``map_Kd``
  shows four coloured quadrants and a gradient (its orientation is plain to see);
- ``tiles.png``: a checker tile for the floor (``scene.json`` repeats it through its UV scale).

Every image is computed here; the output is the same on every run.
"""

from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

HERE = Path(__file__).resolve().parent


def crate_image(size: int = 64) -> np.ndarray:
    """Planks of wood with a dark frame and a diagonal brace, uint8 (size, size, 3)."""
    y, x = np.mgrid[0:size, 0:size] / (size - 1)
    grain = 0.5 + 0.5 * np.sin(40.0 * x + 6.0 * np.sin(7.0 * y))
    plank = (np.floor(y * 4) % 2) * 0.12
    wood = np.stack(
        [0.55 + 0.25 * grain - plank, 0.35 + 0.15 * grain - plank, 0.15 + 0.05 * grain], -1
    )
    frame = (np.minimum(np.minimum(x, 1 - x), np.minimum(y, 1 - y)) < 0.1) | (np.abs(x - y) < 0.07)
    wood[frame] *= 0.45
    return np.clip(np.rint(wood * 255), 0, 255).astype(np.uint8)


def poster_image(width: int = 64, height: int = 48) -> np.ndarray:
    """Quadrants red (top left), green (top right), blue (bottom left), yellow (bottom right),
    brightening from left to right, uint8 (height, width, 3)."""
    y, x = np.mgrid[0:height, 0:width]
    top, left = y < height // 2, x < width // 2
    image = np.empty((height, width, 3), np.float64)
    image[top & left] = (220, 40, 30)
    image[top & ~left] = (40, 180, 60)
    image[~top & left] = (40, 70, 220)
    image[~top & ~left] = (230, 200, 40)
    image *= (0.55 + 0.45 * x / (width - 1))[..., None]
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def tiles_image(size: int = 32) -> np.ndarray:
    """A 2x2 checker of light and dark stone with grout lines, uint8 (size, size, 3)."""
    y, x = np.mgrid[0:size, 0:size]
    half = size // 2
    dark = (x < half) != (y < half)
    image = np.where(dark[..., None], [[[90, 88, 84]]], [[[200, 196, 186]]]).astype(np.float64)
    grout = (x % half == 0) | (y % half == 0)
    image[grout] = (60, 58, 55)
    return image.astype(np.uint8)


def crate_mesh() -> trimesh.Trimesh:
    """A unit box centred at the origin, 24 vertices so every face has the whole image."""
    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    vertices, faces, uvs = [], [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            normal = np.zeros(3)
            normal[axis] = sign
            u_axis = np.roll(np.eye(3)[axis], 1) * sign  # right-handed (u, v, normal)
            v_axis = np.cross(normal, u_axis)
            base = len(vertices)
            for cu, cv in corners:
                vertices.append(0.5 * normal + (cu - 0.5) * u_axis + (cv - 0.5) * v_axis)
                uvs.append((cu, cv))
            faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    mesh = trimesh.Trimesh(np.array(vertices), np.array(faces), process=False)
    material = trimesh.visual.material.PBRMaterial(
        name="crate",
        baseColorFactor=[255, 255, 255, 255],
        metallicFactor=0.0,
        roughnessFactor=0.6,
        baseColorTexture=Image.fromarray(crate_image()),
    )
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.array(uvs), material=material)
    return mesh


POSTER_OBJ = """\
# A 1.6 x 1.2 poster in the xy plane facing +z (made by make_textured.py)
mtllib poster.mtl
v -0.8 -0.6 0
v 0.8 -0.6 0
v 0.8 0.6 0
v -0.8 0.6 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
usemtl poster
f 1/1 2/2 3/3
f 1/1 3/3 4/4
"""
POSTER_MTL = """\
newmtl poster
Kd 1 1 1
map_Kd poster.png
"""


def main() -> None:
    Image.fromarray(poster_image()).save(HERE / "poster.png")
    Image.fromarray(tiles_image()).save(HERE / "tiles.png")
    (HERE / "poster.obj").write_text(POSTER_OBJ)
    (HERE / "poster.mtl").write_text(POSTER_MTL)
    (HERE / "crate.glb").write_bytes(crate_mesh().export(file_type="glb"))


if __name__ == "__main__":
    main()
