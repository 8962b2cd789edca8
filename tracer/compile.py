"""Compile loaded scene data into the flat arrays kernels read.

Steps: concatenate every mesh's triangles; move the scene next to the origin (render space, so
float32 vertices keep their precision however far from the world origin the scene sits); drop
triangles of exactly zero area (they can never be hit; checked with exact rational arithmetic);
build the BVH; lay materials and emitters out as tables.
"""

import math
from dataclasses import dataclass
from fractions import Fraction
from typing import NamedTuple

import numpy as np

from tracer import bvh as bvh_module
from tracer import scene_format as fmt
from tracer.bsdf import MATERIAL_KINDS
from tracer.errors import SceneError
from tracer.lights import LightTable, build_light_table
from tracer.loader import SceneData

FLOAT32_SAFE_EXTENT = 1e30
"""Largest scene extent accepted: squares of render-space distances must stay finite."""


class MaterialTable(NamedTuple):
    """Per material: ``kind`` int32 (K,), ``albedo`` and ``emission`` float32 (K, 3),
    ``two_sided`` bool (K,)."""

    kind: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray
    two_sided: np.ndarray


@dataclass(frozen=True)
class SceneStats:
    triangles: int
    degenerate_triangles: int
    emissive_triangles: int
    bounds_min: tuple[float, float, float]
    bounds_max: tuple[float, float, float]


@dataclass(frozen=True)
class CompiledScene:
    """Everything a render needs. Positions are in render space: world minus ``origin``."""

    bvh: bvh_module.TraversalBVH
    tri_material: np.ndarray
    materials: MaterialTable
    material_names: tuple[str, ...]
    lights: LightTable
    origin: np.ndarray
    camera: fmt.Camera
    render: fmt.RenderSettings
    stats: SceneStats

    @property
    def nbytes(self) -> int:
        """Bytes of per-triangle data and BVH nodes (what tracing and shading read)."""
        return self.bvh.nbytes + self.tri_material.nbytes


def render_space_origin(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The centre of the bounds, snapped to a power-of-two grid as coarse as the scene's extent.

    Snapping leaves a scene that already sits around the origin exactly where it is, and moves a
    distant one by an amount that float64 represents exactly at its scale.
    """
    center = 0.5 * (lo + hi)
    extent = float(np.max(hi - lo))
    if not extent > 0.0:
        return np.zeros(3)
    grid = 2.0 ** math.floor(math.log2(extent))
    return np.round(center / grid) * grid


def zero_area_mask(tri_verts: np.ndarray) -> np.ndarray:
    """Triangles whose float32 vertices are exactly collinear (or repeated).

    Triangles with a repeated vertex are degenerate outright. For the rest, float64 screens out
    the clearly non-degenerate (a cross product far from zero), and every remaining candidate is
    decided exactly, with rational arithmetic on the float32 values: float64 alone is not exact
    when one triangle mixes tiny and ordinary coordinates.
    """
    v = tri_verts.astype(np.float64).reshape(-1, 3, 3)
    repeated = (
        np.all(v[:, 0] == v[:, 1], axis=1)
        | np.all(v[:, 1] == v[:, 2], axis=1)
        | np.all(v[:, 2] == v[:, 0], axis=1)
    )
    e1 = v[:, 1] - v[:, 0]
    e2 = v[:, 2] - v[:, 0]
    size = np.abs(np.cross(e1, e2)).max(axis=1)
    scale = np.abs(e1).max(axis=1) * np.abs(e2).max(axis=1)
    mask = repeated.copy()
    for i in np.flatnonzero((size <= 1e-9 * scale) & ~repeated):
        p = [[Fraction(float(x)) for x in vertex] for vertex in tri_verts[i].reshape(3, 3)]
        a = [p[1][k] - p[0][k] for k in range(3)]
        b = [p[2][k] - p[0][k] for k in range(3)]
        mask[i] = (
            a[1] * b[2] == a[2] * b[1] and a[2] * b[0] == a[0] * b[2] and a[0] * b[1] == a[1] * b[0]
        )
    return mask


def compile_scene(data: SceneData) -> CompiledScene:
    """Flatten, validate and accelerate a loaded scene."""
    if not data.meshes:
        raise SceneError("the scene has no objects")
    lo = np.min([m.vertices.min(axis=0) for m in data.meshes], axis=0)
    hi = np.max([m.vertices.max(axis=0) for m in data.meshes], axis=0)
    origin = render_space_origin(lo, hi)
    if (
        not np.isfinite(hi - lo).all()
        or np.abs(np.concatenate([lo, hi]) - np.tile(origin, 2)).max() > 3e38
    ):
        raise SceneError("the scene is too large for float32 coordinates")

    parts = []
    materials = []
    degenerate = 0
    for mesh in data.meshes:
        tris = (mesh.vertices[mesh.faces] - origin).reshape(-1, 9).astype(np.float32)
        bad = zero_area_mask(tris)
        if bad.all():
            raise SceneError(f"{mesh.name}: every triangle of the mesh has zero area")
        degenerate += int(bad.sum())
        parts.append((tris, bad))
        materials.append(np.full(tris.shape[0], mesh.material, dtype=np.int32))
    tri_verts = np.concatenate([p[0] for p in parts])
    valid = np.flatnonzero(~np.concatenate([p[1] for p in parts])).astype(np.int32)
    tri_material_all = np.concatenate(materials)

    accel = bvh_module.to_traversal(bvh_module.build(tri_verts, valid), tri_verts)
    tri_material = tri_material_all[accel.tri_prim]
    table = material_table(data.materials)
    lights = build_light_table(accel.tri_verts, tri_material, table.emission)
    stats = SceneStats(
        triangles=int(tri_verts.shape[0]),
        degenerate_triangles=degenerate,
        emissive_triangles=int(lights.tri.shape[0]),
        bounds_min=tuple(float(x) for x in lo),
        bounds_max=tuple(float(x) for x in hi),
    )
    return CompiledScene(
        bvh=accel,
        tri_material=tri_material,
        materials=table,
        material_names=tuple(data.material_names),
        lights=lights,
        origin=origin,
        camera=data.camera,
        render=data.render,
        stats=stats,
    )


def material_table(materials: list[fmt.DiffuseMaterial]) -> MaterialTable:
    """Columns of the material models, in their order."""
    return MaterialTable(
        kind=np.array([MATERIAL_KINDS[m.type] for m in materials], dtype=np.int32),
        albedo=np.array([m.reflectance for m in materials], dtype=np.float32).reshape(-1, 3),
        emission=np.array([m.emission for m in materials], dtype=np.float32).reshape(-1, 3),
        two_sided=np.array([m.two_sided for m in materials], dtype=np.bool_),
    )
