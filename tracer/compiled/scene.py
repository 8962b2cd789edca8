"""Compile a scene state into the arrays kernels read (``tracer.compiled.arrays``).

Two levels (Reiter ch. 3): every mesh gets a BVH in its own object space, and a top-level BVH
is built over the instances that place meshes in the world. Static nodes are baked into
world-space meshes (static geometry never moves, so one tree serves it best), one per cluster of
nodes near enough to share an origin without losing float32 precision
(``tracer.compiled.static_clusters``); rigid, deformable and dynamic nodes are instances of their
meshes, which many nodes may share.

Compiling is incremental: given the previous compiled scene, every mesh BVH, pool and table
whose inputs are the very same objects is reused (states share unchanged objects), a mesh whose
vertices moved but whose faces did not is refitted instead of rebuilt, and only the top level
and the small tables are made anew. Moving one object therefore costs a top-level rebuild,
not a pass over the scene's triangles. The result is immutable, so a frame in flight keeps
rendering the version it started with while the next one compiles.

Every mesh is stored relative to its own centre (snapped to a power-of-two grid), so float32
vertices keep their precision wherever the mesh sits; transforms are float64. Triangles of
exactly zero area are dropped (decided with exact rational arithmetic); a mesh with nothing else
is an error.
"""

import dataclasses
from dataclasses import dataclass

import numpy as np

from tracer import config
from tracer.compiled.arrays import STABLE_POOL, VOLATILE_POOL, SceneArrays
from tracer.compiled.corners import NO_CORNERS, Corners, mesh_corners
from tracer.compiled.corners import joined as joined_corners
from tracer.compiled.light_tree import empty_tree
from tracer.compiled.static_clusters import cluster_nodes, snapped_center
from tracer.compiled.zero_area import all_zero_area, zero_area_mask
from tracer.errors import SceneError
from tracer.geometry import bvh as bvh_module
from tracer.geometry import bvh_update
from tracer.geometry.transforms import round_trip_bound, to_rows
from tracer.kernel.jit import jit
from tracer.maths import portable
from tracer.scene import format as fmt
from tracer.scene.checks import check_textures
from tracer.scene.model import Mesh, SceneState, placed
from tracer.shading.lights import LightTable, build_light_table, light_arrays, scene_fields
from tracer.shading.materials import MaterialTable, material_table
from tracer.shading.textures import TextureTable, texture_table

STATIC_KEY = "\0static"
"""Key of the baked static mesh among the compiled meshes (not a valid user mesh name)."""
FLOAT32_SAFE_EXTENT = 1e30
"""Largest mesh extent accepted: squares of object-space distances must stay finite."""


@dataclass(frozen=True, eq=False)
class MeshAccel:
    """One mesh's BVH in object space, relative to ``center``.

    ``source`` is what it was built from (compared by identity for reuse); ``tri_material``
    (int32, leaf order) is each triangle's material for the baked static mesh and -1 otherwise;
    ``lo``/``hi`` bound the stored vertices; ``zero_area`` marks the dropped triangles in the
    mesh's own order.
    """

    source: object
    bvh: bvh_module.TraversalBVH
    center: np.ndarray
    tri_material: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    zero_area: np.ndarray
    sah_reference: np.ndarray | None = None
    """float64 (N,): each BVH node's normalised SAH cost when it was last built (for selective
    rebuilds after refits, ``tracer.geometry.bvh_update``)."""
    owner: np.ndarray | None = None
    """For the baked static mesh, int32 (T, 2) per triangle (mesh order): the scene node it came
    from and its index in that node's mesh. ``None`` for user meshes."""
    node_runs: np.ndarray | None = None
    """For the baked static mesh, int32 (nodes, 2): each node's first triangle and its id."""
    corners: Corners = NO_CORNERS
    """Leaf order: each triangle's vertex UVs and shading normals (``tracer.compiled.corners``);
    ``None`` when the mesh has none (a baked static mesh has rows of zeros for the meshes
    without)."""

    @property
    def triangles(self) -> int:
        return int(self.zero_area.shape[0])


@dataclass(frozen=True, eq=False)
class Pool:
    """Mesh BVHs concatenated into one set of arrays; ``node_offset`` and ``tri_offset`` say
    where each mesh (by key) starts."""

    keys: tuple[str, ...]
    accels: tuple[MeshAccel, ...]
    node_offset: dict[str, int]
    tri_offset: dict[str, int]
    bounds: np.ndarray
    child: np.ndarray
    tri_verts: np.ndarray
    tri_prim: np.ndarray
    tri_material: np.ndarray
    tri_uv: np.ndarray
    """float32 (M, 6), or (0, 6) when no mesh of the pool has UVs."""
    tri_normal: np.ndarray
    """float32 (M, 9), or (0, 9) when no mesh of the pool has shading normals."""


@dataclass(frozen=True)
class SceneStats:
    triangles: int
    degenerate_triangles: int
    emissive_triangles: int
    instances: int
    bounds_min: tuple[float, float, float]
    bounds_max: tuple[float, float, float]


@dataclass(frozen=True, eq=False)
class CompiledScene:
    """Everything a render needs, for one version of a scene."""

    state: SceneState
    origin: np.ndarray
    """float64 (3,): world position of the render-space origin (positions in ``arrays`` are
    world minus origin)."""
    arrays: SceneArrays
    materials: MaterialTable
    textures: TextureTable
    lights: LightTable
    meshes: dict[str, MeshAccel]
    pools: tuple[Pool, Pool]
    static_signature: tuple
    static_clusters: int
    """How many baked static meshes there are (``static_key(k)`` for k below it)."""
    instance_nodes: np.ndarray
    """int32 (I,): the scene node of each instance (-1 - k for baked static cluster k)."""
    stats: SceneStats

    @property
    def camera(self) -> fmt.Camera:
        return self.state.camera

    @property
    def render(self) -> fmt.RenderSettings:
        return self.state.render

    @property
    def version(self) -> int:
        return self.state.version

    @property
    def material_names(self) -> tuple[str, ...]:
        return tuple(self.state.materials)

    @property
    def nbytes(self) -> int:
        """Bytes of every array the kernels read."""
        return self.arrays.nbytes


@jit
def _bounds(points):
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for i in range(points.shape[0]):
        for k in range(3):
            x = np.float64(points[i, k])
            if x < lo[k]:
                lo[k] = x
            if x > hi[k]:
                hi[k] = x
    return lo, hi


@jit
def _gather_centered(vertices, faces, center):
    """float32 (F, 9): each face's vertices minus ``center`` (computed in float64, rounded once)."""
    out = np.empty((faces.shape[0], 9), np.float32)
    for f in range(faces.shape[0]):
        for c in range(3):
            v = faces[f, c]
            for k in range(3):
                out[f, 3 * c + k] = np.float32(vertices[v, k] - center[k])
    return out


def _centered_triangles(vertices: np.ndarray, faces: np.ndarray, label: str):
    lo, hi = _bounds(vertices)
    if not (np.isfinite(hi - lo).all() and float(np.max(hi - lo)) < FLOAT32_SAFE_EXTENT):
        raise SceneError(f"{label}: the mesh is too large for float32 coordinates")
    center = snapped_center(lo, hi)
    return center, _gather_centered(vertices, faces, center)


def _accel(source, tri_verts, center, zero_area, tri_material, corners, label) -> MeshAccel:
    """A mesh's BVH; ``corners`` in the mesh's triangle order."""
    valid = np.flatnonzero(~zero_area).astype(np.int32)
    if valid.size == 0:
        given = source.vertices[source.faces] if isinstance(source, Mesh) else tri_verts
        raise SceneError(all_zero_area(label, np.asarray(given, np.float64).reshape(-1, 3, 3)))
    accel = bvh_module.to_traversal(bvh_module.build(tri_verts, valid), tri_verts)
    material = tri_material[accel.tri_prim].astype(np.int32)
    lo, hi = _bounds(accel.tri_verts.reshape(-1, 3))
    return MeshAccel(
        source,
        accel,
        center,
        material,
        lo,
        hi,
        zero_area,
        sah_reference=bvh_update.sah_costs(accel),
        corners=corners.ordered(accel.tri_prim),
    )


def mesh_accel(
    key: str,
    mesh: Mesh,
    previous: MeshAccel | None,
    rebuild_threshold: float = config.BVH_REBUILD_THRESHOLD,
) -> MeshAccel:
    """The BVH of a user mesh: reused if built from this very mesh; if only its vertices moved
    (same faces array, same zero-area triangles) refitted, with the subtrees that degraded past
    ``rebuild_threshold`` rebuilt (``tracer.geometry.bvh_update``); else built."""
    if previous is not None and previous.source is mesh:
        return previous
    center, tri_verts = _centered_triangles(mesh.vertices, mesh.faces, f"mesh {key!r}")
    zero_area = zero_area_mask(tri_verts)
    no_material = np.full(tri_verts.shape[0], -1, dtype=np.int32)
    if (
        previous is not None
        and isinstance(previous.source, Mesh)
        and previous.source.faces is mesh.faces
        and np.array_equal(previous.zero_area, zero_area)
    ):
        moved = bvh_update.update(
            previous.bvh,
            tri_verts[previous.bvh.tri_prim],
            previous.sah_reference,
            rebuild_threshold,
        )
        lo, hi = _bounds(moved.bvh.tri_verts.reshape(-1, 3))
        return MeshAccel(
            mesh,
            moved.bvh,
            center,
            previous.tri_material,
            lo,
            hi,
            zero_area,
            sah_reference=moved.reference,
            corners=mesh_corners(mesh).ordered(moved.bvh.tri_prim),
        )
    return _accel(
        mesh, tri_verts, center, zero_area, no_material, mesh_corners(mesh), f"mesh {key!r}"
    )


def static_signature(state: SceneState) -> tuple:
    """What the baked static mesh depends on: each static geometry node, its mesh and its world
    transform (a moving parent moves a static child too)."""
    return tuple(
        (node, state.meshes[node.mesh], state.world_transform(node.id).tobytes())
        for node in state.geometry_nodes()
        if node.kind == "static"
    )


def _same_signature(a: tuple, b: tuple) -> bool:
    return len(a) == len(b) and all(
        x[0] is y[0] and x[1] is y[1] and x[2] == y[2] for x, y in zip(a, b, strict=True)
    )


def static_key(cluster: int) -> str:
    """Key of baked static cluster ``cluster`` among the compiled meshes (0: ``STATIC_KEY``)."""
    return STATIC_KEY if cluster == 0 else f"{STATIC_KEY}:{cluster}"


def _world_triangles(node, mesh: Mesh, matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """float64 (F, 3, 3) world triangles of a static node, and its faces (mirrors reversed)."""
    world, faces = placed(mesh.vertices, mesh.faces, matrix)
    if not np.isfinite(world).all():
        raise SceneError(f"{node.name or node.id}: its transform moves vertices to infinity")
    return world[faces], faces


def static_accels(state: SceneState, signature: tuple, material_index: dict) -> list[MeshAccel]:
    """Static geometry baked into world-space meshes, one per cluster of nearby nodes
    (``tracer.compiled.static_clusters``), the cluster with the most triangles first; triangles in
    node order within each."""
    if not signature:
        return []
    triangles = [_world_triangles(node, mesh, state.world_transform(node.id))
                 for node, mesh, _ in signature]  # fmt: skip
    lo = np.array([t.reshape(-1, 3).min(axis=0) for t, _ in triangles])
    hi = np.array([t.reshape(-1, 3).max(axis=0) for t, _ in triangles])
    clusters = cluster_nodes(lo, hi)
    counts = [sum(triangles[i][1].shape[0] for i in c) for c in clusters]
    clusters = [clusters[k] for k in sorted(range(len(clusters)), key=lambda k: (-counts[k], k))]
    return [
        _bake([signature[i] for i in c], [triangles[i] for i in c], material_index, k)
        for k, c in enumerate(clusters)
    ]


def _bake(signature: tuple, triangles: list, material_index: dict, cluster: int) -> MeshAccel:
    """One cluster of static nodes baked into one mesh around its own origin."""
    parts, materials, owners, locals_, corners = [], [], [], [], []
    for (node, mesh, matrix), (world, faces) in zip(signature, triangles, strict=True):
        parts.append(world)
        corners.append(mesh_corners(mesh, faces, np.frombuffer(matrix).reshape(4, 4)))
        materials.append(np.full(faces.shape[0], material_index[node.material], np.int32))
        owners.append(np.full(faces.shape[0], node.id, np.int64))
        locals_.append(np.arange(faces.shape[0], dtype=np.int64))
    world = np.concatenate(parts)
    lo = world.reshape(-1, 3).min(axis=0)
    hi = world.reshape(-1, 3).max(axis=0)
    if not (np.isfinite(hi - lo).all() and float(np.max(hi - lo)) < FLOAT32_SAFE_EXTENT):
        names = ", ".join(str(node.name or node.id) for node, _, _ in signature[:3])
        raise SceneError(f"static objects ({names}...) span too much for float32 coordinates")
    center = snapped_center(lo, hi)
    tri_verts = (world - center).reshape(-1, 9).astype(np.float32)
    zero_area = zero_area_mask(tri_verts)
    counted = np.concatenate([[0], np.cumsum(zero_area)])
    ends = np.cumsum([p.shape[0] for p in parts])
    for (node, mesh, _), part, end in zip(signature, parts, ends, strict=True):
        if counted[end] - counted[end - part.shape[0]] == part.shape[0]:
            raise SceneError(
                all_zero_area(str(node.name or node.id), part, mesh.vertices[mesh.faces])
            )
    label = "scene" if cluster == 0 else f"static cluster {cluster}"
    corners = joined_corners(corners, [p.shape[0] for p in parts])
    accel = _accel(
        signature, tri_verts, center, zero_area, np.concatenate(materials), corners, label
    )
    owner = np.stack([np.concatenate(owners), np.concatenate(locals_)], axis=1)
    runs = np.stack([ends - [p.shape[0] for p in parts], [n.id for n, _, _ in signature]], axis=1)
    return dataclasses.replace(accel, owner=owner.astype(np.int32), node_runs=runs.astype(np.int32))


@jit
def _shift_children(child, node_offset, tri_offset):
    out = np.empty_like(child)
    for i in range(child.shape[0]):
        for side in range(child.shape[1]):
            c = child[i, side]
            if c >= 0:
                out[i, side] = c + node_offset
            else:
                v = -1 - c
                count = v & 7
                first = (v >> 3) + (tri_offset if count > 0 else 0)
                out[i, side] = -1 - ((first << 3) | count)
    return out


def make_pool(keys: tuple[str, ...], accels: tuple[MeshAccel, ...], previous: Pool | None) -> Pool:
    """Concatenate mesh BVHs; reuse ``previous`` if it holds exactly these."""
    if (
        previous is not None
        and previous.keys == keys
        and all(a is b for a, b in zip(previous.accels, accels, strict=True))
    ):
        return previous
    node_offset, tri_offset = {}, {}
    bounds, child, verts, prim, material, corners = [], [], [], [], [], []
    nodes = tris = 0
    for key, accel in zip(keys, accels, strict=True):
        node_offset[key] = nodes
        tri_offset[key] = tris
        bounds.append(accel.bvh.node_bounds)
        child.append(_shift_children(accel.bvh.node_child, nodes, tris))
        verts.append(accel.bvh.tri_verts)
        prim.append(accel.bvh.tri_prim)
        material.append(accel.tri_material)
        corners.append(accel.corners)
        nodes += accel.bvh.node_bounds.shape[0]
        tris += accel.bvh.tri_verts.shape[0]
    if tris > bvh_module.MAX_TRIANGLES:
        raise SceneError(f"at most {bvh_module.MAX_TRIANGLES} triangles per pool")

    def joined(parts, shape, dtype):
        return np.concatenate(parts) if parts else np.zeros(shape, dtype)

    # (0, width) when no mesh of the pool has the attribute: kernels never read it.
    uv, normal = joined_corners(corners, [v.shape[0] for v in verts])

    return Pool(
        keys,
        accels,
        node_offset,
        tri_offset,
        joined(bounds, (0, bvh_module.NODE_FLOATS), np.float32),
        joined(child, (0, bvh_module.WIDTH), np.int32),
        joined(verts, (0, 9), np.float32),
        joined(prim, (0,), np.int32),
        joined(material, (0,), np.int32),
        np.zeros((0, 6), np.float32) if uv is None else uv,
        np.zeros((0, 9), np.float32) if normal is None else normal,
    )


def object_tables(baked: list[MeshAccel], nodes: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """``SceneArrays.inst_object`` and ``static_runs``: what maps a hit to its scene node."""
    bases = np.cumsum([0] + [accel.triangles for accel in baked])
    runs = [a.node_runs + [b, 0] for a, b in zip(baked, bases, strict=False)] or [np.zeros((0, 2))]
    inst_object = [n if n >= 0 else -1 - bases[-1 - n] for n in nodes]
    return np.array(inst_object, np.int32), np.concatenate(runs).astype(np.int32)


def _world_box(accel: MeshAccel, xform: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    corners = np.array(
        [[x, y, z] for x in (accel.lo[0], accel.hi[0]) for y in (accel.lo[1], accel.hi[1])
         for z in (accel.lo[2], accel.hi[2])]
    )  # fmt: skip
    world = portable.transform_points(corners, xform.reshape(3, 4))
    return world.min(axis=0), world.max(axis=0)


def _outward_float32(lo: np.ndarray, hi: np.ndarray):
    lo32 = lo.astype(np.float32)
    hi32 = hi.astype(np.float32)
    lo32 = np.where(lo32 > lo, np.nextafter(lo32, np.float32(-np.inf)), lo32)
    hi32 = np.where(hi32 < hi, np.nextafter(hi32, np.float32(np.inf)), hi32)
    return lo32, hi32


def _pool_of(state: SceneState) -> dict[str, int]:
    """Pool of each mesh used by a non-static node: volatile if any user deforms it."""
    pools: dict[str, int] = {}
    for node in state.geometry_nodes():
        if node.kind == "static":
            continue
        moving = node.kind in ("deformable", "dynamic")
        if moving or node.mesh not in pools:
            pools[node.mesh] = VOLATILE_POOL if moving else STABLE_POOL
    return pools


def compile_scene(
    scene,
    previous: CompiledScene | None = None,
    rebuild_threshold: float = config.BVH_REBUILD_THRESHOLD,
) -> CompiledScene:
    """Compile a :class:`SceneState` (or a ``tracer.scene.loader.SceneData``), reusing what it can
    of ``previous`` (the compiled form of an earlier version of the same scene).

    ``rebuild_threshold`` decides what deformed meshes get (``tracer.geometry.bvh_update``): 0
    rebuilds them, ``math.inf`` only refits them, the default refits and rebuilds degraded
    subtrees."""
    state = scene.to_state() if hasattr(scene, "to_state") else scene
    if not state.geometry_nodes():
        raise SceneError("the scene has no objects")
    check_textures(state)
    material_index = {name: i for i, name in enumerate(state.materials)}
    materials = material_table(list(state.materials.values()))
    textures = texture_table(
        state.textures,
        list(state.materials.values()),
        previous.textures if previous is not None else None,
    )
    old_meshes = previous.meshes if previous is not None else {}

    # Mesh BVHs: the baked static clusters, then every mesh a non-static node uses.
    signature = static_signature(state)
    if previous is not None and _same_signature(previous.static_signature, signature):
        baked = [old_meshes[static_key(k)] for k in range(previous.static_clusters)]
    else:
        baked = static_accels(state, signature, material_index)
    meshes: dict[str, MeshAccel] = {static_key(k): accel for k, accel in enumerate(baked)}
    pool_of = _pool_of(state)
    for key in sorted(pool_of):
        meshes[key] = mesh_accel(key, state.meshes[key], old_meshes.get(key), rebuild_threshold)

    # Pools.
    stable_keys = [static_key(k) for k in range(len(baked))]
    stable_keys += sorted(k for k, p in pool_of.items() if p == STABLE_POOL)
    volatile_keys = sorted(k for k, p in pool_of.items() if p == VOLATILE_POOL)
    old_pools = previous.pools if previous is not None else (None, None)
    pools = (
        make_pool(tuple(stable_keys), tuple(meshes[k] for k in stable_keys), old_pools[0]),
        make_pool(tuple(volatile_keys), tuple(meshes[k] for k in volatile_keys), old_pools[1]),
    )

    # Render space is world space moved by ``origin``, the first static cluster's centre: that
    # cluster then needs no transform at all, and kernels skip it.
    origin = baked[0].center if baked else np.zeros(3)
    to_render = np.eye(4)
    to_render[:3, 3] = -origin

    # Instances: the static clusters first (node -1 - k), then non-static geometry nodes in id
    # order. A cluster's translation is exact: both centres lie on power-of-two grids.
    inst = []  # (node id, key, pool, object -> render 4x4, material index)
    for k, accel in enumerate(baked):
        shift = np.eye(4)
        shift[:3, 3] = accel.center - origin
        inst.append((-1 - k, static_key(k), STABLE_POOL, shift, -1))
    for node in state.geometry_nodes():
        if node.kind != "static":
            shift = np.eye(4)
            shift[:3, 3] = meshes[node.mesh].center
            matrix = portable.chain(to_render, state.world_transform(node.id), shift)
            inst.append(
                (node.id, node.mesh, pool_of[node.mesh], matrix, material_index[node.material])
            )
    xform = np.array([to_rows(m) for _, _, _, m, _ in inst])
    inv = np.array([to_rows(portable.affine_inverse(m)) for _, _, _, m, _ in inst])
    inst_pool = np.array([p for _, _, p, _, _ in inst], dtype=np.int32)
    inst_root = np.array([pools[p].node_offset[key] for _, key, p, _, _ in inst], np.int32)
    inst_material = np.array([m for *_, m in inst], dtype=np.int32)
    inst_rt = np.array([round_trip_bound(m) for _, _, _, m, _ in inst], dtype=np.float64)
    inst_identity = np.array([np.array_equal(m, np.eye(4)) for _, _, _, m, _ in inst], np.bool_)
    inst_object, static_runs = object_tables(baked, [n for n, *_ in inst])

    # The top level, over the instances' world boxes.
    boxes = [_world_box(meshes[key], xform[k]) for k, (_, key, _, _, _) in enumerate(inst)]
    lo, hi = _outward_float32(np.array([b[0] for b in boxes]), np.array([b[1] for b in boxes]))
    beyond = ~(
        np.all(np.abs(lo) < FLOAT32_SAFE_EXTENT, axis=1)
        & np.all(np.abs(hi) < FLOAT32_SAFE_EXTENT, axis=1)
    )
    if beyond.any():
        k = int(np.argmax(beyond))
        node = state.nodes.get(inst[k][0])
        label = "static objects" if node is None else str(node.name or node.id)
        raise SceneError(f"{label}: placed beyond the range of float32 bounds (|x| >= 1e30)")
    top = bvh_module.build_boxes(lo, hi, np.arange(len(inst), dtype=np.int32))
    tlas = bvh_module.to_traversal(top, np.zeros((len(inst), 9), np.float32))

    # Lights: every emissive triangle of every instance, in (instance, triangle) order.
    light_inputs = []
    for k, (_, key, p, _, m) in enumerate(inst):
        first = pools[p].tri_offset[key]
        rows = np.arange(first, first + meshes[key].bvh.tri_verts.shape[0])
        mats = pools[p].tri_material[rows] if m < 0 else np.full(rows.shape[0], m, np.int32)
        light_inputs.append((k, pools[p].tri_verts, rows, pools[p].tri_prim[rows], mats, xform[k]))
    radius = 0.5 * portable.norm(hi.max(axis=0).astype(np.float64) - lo.min(axis=0))
    lights = build_light_table(
        light_inputs, materials.emission, state.lights, state.sky, origin, max(radius, 1e-30)
    )
    light = light_arrays(lights)

    arrays = SceneArrays(
        blas_bounds=(pools[0].bounds, pools[1].bounds),
        blas_child=(pools[0].child, pools[1].child),
        tri_verts=(pools[0].tri_verts, pools[1].tri_verts),
        tri_prim=(pools[0].tri_prim, pools[1].tri_prim),
        tri_material=(pools[0].tri_material, pools[1].tri_material),
        inst_pool=inst_pool,
        inst_root=inst_root,
        inst_xform=xform,
        inst_inv=inv,
        inst_material=inst_material,
        inst_identity=inst_identity,
        inst_rt=inst_rt,
        inst_object=inst_object,
        static_runs=static_runs,
        tlas_bounds=tlas.node_bounds,
        tlas_child=tlas.node_child,
        tlas_inst=tlas.tri_prim,
        mat_albedo=materials.albedo,
        mat_emission=materials.emission,
        mat_two_sided=materials.two_sided,
        mat_kind=materials.kind,
        mat_param=materials.param,
        tri_uv=(pools[0].tri_uv, pools[1].tri_uv),
        tri_normal=(pools[0].tri_normal, pools[1].tri_normal),
        **textures.fields(),
        **scene_fields(light),
        **empty_tree()._asdict(),
    )
    stats = SceneStats(
        triangles=sum(meshes[key].triangles for key in set(k for _, k, _, _, _ in inst)),
        degenerate_triangles=sum(
            int(meshes[key].zero_area.sum()) for key in set(k for _, k, _, _, _ in inst)
        ),
        emissive_triangles=int(np.count_nonzero((lights.kind == 0) & (lights.weight > 0.0))),
        instances=len(inst),
        bounds_min=tuple(float(x) for x in lo.min(axis=0) + origin),
        bounds_max=tuple(float(x) for x in hi.max(axis=0) + origin),
    )
    return CompiledScene(
        state=state,
        origin=origin,
        arrays=arrays,
        materials=materials,
        textures=textures,
        lights=lights,
        meshes=meshes,
        pools=pools,
        static_signature=signature,
        static_clusters=len(baked),
        instance_nodes=np.array([n for n, *_ in inst], dtype=np.int32),
        stats=stats,
    )
