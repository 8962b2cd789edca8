"""Shared test helpers: triangle soups, meshes, rays and tiny scenes."""

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import trimesh

from tracer.geometry import bvh

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"
CORNELL = SCENES / "cornell-box" / "scene.json"
GLTF_BOX = SCENES / "gltf-box" / "Box.gltf"


def tri_verts_of(vertices, faces) -> np.ndarray:
    """Triangles of an indexed mesh as float32 (T, 9) rows (v0, v1, v2)."""
    return (
        np.asarray(vertices, dtype=np.float64)[np.asarray(faces)].reshape(-1, 9).astype(np.float32)
    )


def icosphere(subdivisions: int = 2, radius: float = 1.0) -> np.ndarray:
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return tri_verts_of(mesh.vertices, mesh.faces)


def box(extents=(2.0, 2.0, 2.0)) -> np.ndarray:
    """Axis-aligned box centred at the origin (12 triangles, wound outward)."""
    mesh = trimesh.creation.box(extents=extents)
    return tri_verts_of(mesh.vertices, mesh.faces)


SOUP_KINDS = ("uniform", "clustered", "planar", "slivers", "mixed-sizes", "grid")


def soup(rng: np.random.Generator, n: int, kind: str = "uniform") -> np.ndarray:
    """A random triangle soup, float32 (n, 9), of one of ``SOUP_KINDS``."""
    if kind == "clustered":
        centres = rng.normal(size=(4, 3)) * 3.0
        base = centres[rng.integers(0, 4, n)] + rng.normal(scale=0.05, size=(n, 3))
        size = 0.05
    elif kind == "grid":
        # Centroids on a coarse lattice: many exactly equal bin keys and ties.
        base = rng.integers(-3, 4, size=(n, 3)).astype(np.float64)
        size = 0.3
    else:
        base = rng.uniform(-1.0, 1.0, size=(n, 3))
        size = 0.1
    if kind == "mixed-sizes":
        size = 10.0 ** rng.uniform(-3.0, 0.5, size=(n, 1, 1))
    offsets = rng.normal(scale=1.0, size=(n, 3, 3)) * size
    if kind == "slivers":
        offsets[:, 2] = offsets[:, 1] * rng.uniform(0.0, 1.0, size=(n, 1)) + 1e-4 * offsets[:, 2]
    tris = base[:, None, :] + offsets
    if kind == "planar":
        tris[:, :, 2] = 0.25
    return tris.reshape(n, 9).astype(np.float32)


def traversal(tri_verts: np.ndarray, prims=None) -> bvh.TraversalBVH:
    """Build and flatten a BVH over ``tri_verts``."""
    return bvh.to_traversal(bvh.build(tri_verts, prims), tri_verts)


def rays_at(rng: np.random.Generator, tri_verts: np.ndarray, n: int, spread: float = 3.0):
    """Rays from random origins around the triangles: half aimed at random points on random
    triangles (so most hit), half in uniformly random directions (many miss)."""
    v = tri_verts.astype(np.float64).reshape(-1, 3, 3)
    lo, hi = v.reshape(-1, 3).min(axis=0), v.reshape(-1, 3).max(axis=0)
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo) + 1e-3 * np.max(hi - lo)
    origins = centre + rng.uniform(-spread, spread, size=(n, 3)) * half
    b = rng.dirichlet(np.ones(3), n)
    targets = np.einsum("ij,ijk->ik", b, v[rng.integers(0, len(v), n)])
    aimed = targets - origins
    random = rng.normal(size=(n, 3))
    directions = np.where(np.arange(n)[:, None] % 2 == 0, aimed, random)
    # Lengths of 1/4 to 4 (``t`` is in units of the given direction), whatever the scene's scale.
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    directions *= rng.uniform(0.25, 4.0, size=(n, 1))
    return origins, directions


def tiny_scene(**changes) -> dict:
    """A tilerender/1 scene as a dict: a box on a floor, under a one-sided area light."""
    scene = {
        "format": "tilerender/1",
        "camera": {
            "position": [0.0, 1.5, 4.0],
            "look_at": [0.0, 0.5, 0.0],
            "up": [0.0, 1.0, 0.0],
            "vfov_deg": 45.0,
            "width": 12,
            "height": 8,
        },
        "render": {"spp": 2, "max_depth": 4, "rr_depth": 2, "seed": 1},
        "materials": {
            "grey": {"reflectance": [0.7, 0.7, 0.7]},
            "lamp": {"reflectance": [0, 0, 0], "emission": [8, 8, 8], "two_sided": False},
        },
        "objects": [
            {"name": "floor", "shape": {"type": "plane", "size": 10}, "material": "grey"},
            {
                "name": "cube",
                "shape": {"type": "box", "size": [1, 1, 1]},
                "material": "grey",
                "transform": {"translate": [0, 0.5, 0], "rotate": [0, 30, 0]},
            },
            {
                "name": "lamp",
                "shape": {"type": "rectangle", "size": [1, 1]},
                "material": "lamp",
                "transform": {"translate": [0, 3, 0], "rotate": [90, 0, 0]},
            },
        ],
    }
    scene.update(changes)
    return scene


def zip_bytes(entries: dict[str, bytes], links: dict[str, str] | None = None) -> bytes:
    """A zip of ``entries`` (name: bytes) and symbolic ``links`` (name: target)."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in entries.items():
            z.writestr(name, data)
        for name, target in (links or {}).items():
            info = zipfile.ZipInfo(name)
            info.external_attr = 0o120777 << 16
            z.writestr(info, target)
    return buffer.getvalue()


def write_json(path: Path, data) -> Path:
    path.write_text(json.dumps(data), encoding="utf-8")
    return path


def write_mesh(path: Path, vertices, faces) -> Path:
    """Write a mesh file (format from the suffix) through trimesh, without any processing."""
    trimesh.Trimesh(vertices=vertices, faces=faces, process=False).export(path)
    return path


def project(camera, points: np.ndarray) -> np.ndarray:
    """Film coordinates (x, y) in pixels of world ``points`` (N, 3), by the pinhole model of
    ``docs/scene-format.md`` (row 0 at the top, +x to the right of the view); NaN behind."""
    position = np.asarray(camera.position, dtype=np.float64)
    forward = np.asarray(camera.look_at, dtype=np.float64) - position
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, camera.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    rel = np.asarray(points, dtype=np.float64) - position
    depth = rel @ forward
    tan_half = np.tan(np.radians(camera.vfov_deg) / 2)
    aspect = camera.width / camera.height
    with np.errstate(divide="ignore", invalid="ignore"):
        sx = (rel @ right) / depth / (tan_half * aspect)
        sy = (rel @ up) / depth / tan_half
    x = (sx + 1.0) * 0.5 * camera.width
    y = (1.0 - sy) * 0.5 * camera.height
    xy = np.stack([x, y], axis=1)
    xy[depth <= 0.0] = np.nan
    return xy


def compile_dict(data: dict, directory: Path = SCENES):
    """Compile a scene given as a tilerender/1 dict (mesh paths relative to ``directory``)."""
    from tracer.compiled.scene import compile_scene
    from tracer.scene.format import SceneFile
    from tracer.scene.loader import scene_from_file_model

    return compile_scene(scene_from_file_model(SceneFile.model_validate(data), directory))


def render_passes(scene, passes: int, spp: int, camera=None, **changes) -> np.ndarray:
    """``passes`` independent renders over disjoint sample ranges, float64 (K, H, W, 3)."""
    from tracer.render import render_image
    from tracer.scene.format import override

    settings = override(scene.render, spp=spp, **changes)
    return np.stack(
        [
            render_image(scene, camera, settings=settings, sample_start=k * spp)[0]
            for k in range(passes)
        ]
    ).astype(np.float64)


def mean_and_error(passes: np.ndarray, axis=(1, 2)) -> tuple[np.ndarray, np.ndarray]:
    """Mean over passes of each pass's mean over ``axis``, and its standard error (from the
    spread of the passes), per channel."""
    per_pass = passes.mean(axis=axis)
    k = per_pass.shape[0]
    return per_pass.mean(axis=0), per_pass.std(axis=0, ddof=1) / np.sqrt(k)


def two_planes(ao_samples: int, ao_distance: float, pixels: int, spp: int | None = None):
    """A floor and a ceiling one unit above it, both 40 wide, seen from between them by a
    ``pixels`` x ``pixels`` camera looking at the floor; rendered with ambient occlusion."""
    plane = {"type": "plane", "size": 40.0}
    render = {"integrator": "ao", "ao_samples": ao_samples, "ao_distance": ao_distance}
    if spp is not None:
        render["spp"] = spp
    return compile_dict(
        {
            "camera": {
                "position": [0, 0.5, 0],
                "look_at": [0, 0, 0],
                "up": [0, 0, -1],
                "vfov_deg": 10,
                "width": pixels,
                "height": pixels,
            },
            "render": render,
            "materials": {"grey": {}},
            "objects": [
                {"shape": plane, "material": "grey"},
                {
                    "shape": plane,
                    "material": "grey",
                    "transform": {"translate": [0, 1, 0], "rotate": [180, 0, 0]},
                },
            ],
        }
    )
