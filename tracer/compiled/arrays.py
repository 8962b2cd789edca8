"""Every array a render kernel reads, in one named tuple.

Two-level acceleration (Bikker ch. 3, Reiter ch. 3-4): each mesh has a BVH in its own object
space; instances place meshes in the world with affine transforms; a top-level BVH (TLAS) is
built over the instances' world boxes. Mesh BVHs live in two *pools*, concatenated arrays in
the traversal layout of ``tracer.geometry.bvh``: pool 0 holds static and rigid geometry (rarely
rebuilt, shared between scene versions), pool 1 deformable and dynamic meshes (small, rebuilt or
refitted per version). A field that differs per pool is a pair ``(pool0, pool1)`` indexed by the
instance's pool.
"""

from typing import NamedTuple

import numpy as np

from tracer.kernel.borrow import borrowed
from tracer.kernel.jit import jit_inline

STABLE_POOL = 0
VOLATILE_POOL = 1


class SceneArrays(NamedTuple):
    blas_bounds: tuple[np.ndarray, np.ndarray]
    """float32 (N, 24) per pool: interior nodes, their four child boxes (tracer.geometry.bvh
    layout)."""
    blas_child: tuple[np.ndarray, np.ndarray]
    """int32 (N, 4) per pool: child references, pool-global node and triangle indices."""
    tri_verts: tuple[np.ndarray, np.ndarray]
    """float32 (M, 9) per pool: object-space triangles in leaf order."""
    tri_prim: tuple[np.ndarray, np.ndarray]
    """int32 (M,) per pool: each row's triangle index within its mesh."""
    tri_material: tuple[np.ndarray, np.ndarray]
    """int32 (M,) per pool: material of each row (used when the instance has none of its own)."""
    inst_pool: np.ndarray
    """int32 (I,): pool of each instance's mesh."""
    inst_root: np.ndarray
    """int32 (I,): root node of the instance's mesh in its pool."""
    inst_xform: np.ndarray
    """float64 (I, 12): object -> world (tracer.geometry.transforms layout)."""
    inst_inv: np.ndarray
    """float64 (I, 12): world -> object."""
    inst_material: np.ndarray
    """int32 (I,): the instance's material, or -1 to use the triangles' own."""
    inst_identity: np.ndarray
    """bool (I,): the instance's transform is exactly the identity (kernels skip it)."""
    inst_rt: np.ndarray
    """float64 (I, 2): ``(c1, c0)`` of ``transforms.round_trip_bound`` per instance."""
    inst_object: np.ndarray
    """int32 (I,): the scene node (object id) of the instance; for a baked static mesh -1 - its
    first key in ``static_runs``."""
    static_runs: np.ndarray
    """int32 (R, 2): the baked static meshes' triangles as runs of one node each, ascending:
    ``(first key, node)``, a triangle's key being its instance's base plus its index in the
    mesh (``tri_prim``)."""
    tlas_bounds: np.ndarray
    """float32 (K, 24): the top-level 4-wide BVH over instance world boxes."""
    tlas_child: np.ndarray
    """int32 (K, 4): its child references; leaves index ``tlas_inst``."""
    tlas_inst: np.ndarray
    """int32 (I,): instance indices in top-level leaf order."""
    mat_albedo: np.ndarray
    """float32 (Q, 3)."""
    mat_emission: np.ndarray
    """float32 (Q, 3)."""
    mat_two_sided: np.ndarray
    """bool (Q,)."""
    mat_kind: np.ndarray
    """int32 (Q,): BSDF kind (``tracer.shading.bsdf`` constants)."""
    mat_param: np.ndarray
    """float64 (Q, ``bsdf.PARAM_COLUMNS``): BSDF parameters (``tracer.shading.materials``)."""
    mat_texture: np.ndarray
    """int32 (Q,): the material's base-colour texture (a row of ``tex_info``), or -1."""
    mat_normal_map: np.ndarray
    """int32 (Q,): the material's normal map (a row of ``tex_info``, linear texels), or -1."""
    mat_normal_strength: np.ndarray
    """float64 (Q,): the strength of the material's normal map."""
    tri_uv: tuple[np.ndarray, np.ndarray]
    """float32 (M, 6) per pool: each row's vertex UVs (zeros for a mesh without UVs); (0, 6)
    when no mesh of the pool has UVs."""
    tri_normal: tuple[np.ndarray, np.ndarray]
    """float32 (M, 9) per pool: each row's vertex shading normals (zeros for a flat mesh);
    (0, 9) when no mesh of the pool has any."""
    tex_pixels: np.ndarray
    """float32 (N, 3): linear RGB texels of every texture (``tracer.shading.textures``)."""
    tex_info: np.ndarray
    """int64 (T, 4): per texture its first texel, width, height and wrap mode."""
    tex_scale: np.ndarray
    """float64 (T, 2): per texture the scale applied to UVs."""
    mat_alpha: np.ndarray
    """float64 (Q, 4): each material's alpha (``tracer.shading.textures.TextureTable.alpha``);
    (0, 4) unless the plan tests alpha (``flags.ALPHA_TEST``)."""
    light_kind: np.ndarray
    """int32 (L,): kind of each light (``tracer.shading.lights`` constants)."""
    light_inst: np.ndarray
    """int32 (L,): for an emissive triangle, its instance (else -1)."""
    light_tri: np.ndarray
    """int32 (L,): for an emissive triangle, its row in the instance's pool; for a point, spot
    or sun light, its row of ``light_data``; -1 for the sky."""
    light_cdf: np.ndarray
    """float64 (L,): selection CDF (by power), last entry exactly 1."""
    light_total: np.ndarray
    """float64 (1,): sum of the selection weights."""
    light_data: np.ndarray
    """float64 (P, ``lights.LIGHT_DATA``): point, spot and sun lights."""
    light_env: np.ndarray
    """int32 (E,): rows of ``light_data`` of suns that rays can see (a radius > 0)."""
    sky: np.ndarray
    """float64 (``lights.SKY_SIZE``,): the sky (``tracer.shading.lights``)."""
    sky_image: np.ndarray
    """float32 (H, W, 3): an environment map's radiance, scale applied
    (``tracer.shading.environment_light``; a placeholder unless the sky is one)."""
    sky_rows: np.ndarray
    """float64 (H + 1,): the map's marginal CDF over rows."""
    sky_cols: np.ndarray
    """float64 (H, W + 1): the map's conditional CDFs over each row's columns."""
    light_tree_nodes: np.ndarray
    """float64 (N, ``light_tree.NODE * light_tree.WIDTH``): the 4-wide light tree over the
    emissive triangles (``tracer.compiled.light_tree``; empty unless the plan samples lights
    with it)."""
    light_tree_child: np.ndarray
    """int32 (N, ``light_tree.WIDTH``): each slot's node, or ``-1 - light`` for a triangle."""
    light_tree_bits: np.ndarray
    """uint64 (T,): each emissive triangle's path from the root."""
    light_tree_area: np.ndarray
    """float64 (T,): each emissive triangle's area."""
    light_tree_keys: np.ndarray
    """int64 (T,): ``instance << 32 | pool row`` of the emissive triangles, ascending."""
    light_tree_key_light: np.ndarray
    """int32 (T,): the emissive triangle of each key."""

    @property
    def nbytes(self) -> int:
        """Bytes of every array (both pools)."""
        total = 0
        for value in self:
            for array in value if isinstance(value, tuple) else (value,):
                total += array.nbytes
        return total


@jit_inline
def pick(pair, pool):
    """``pair[pool]`` for a pool index known only at run time, as a select rather than numba's
    tuple indexing (which goes through a zero-filled stack copy of the tuple on every use)."""
    return pair[0] if pool == 0 else pair[1]


@jit_inline
def _pair(pair):
    return (borrowed(pair[0]), borrowed(pair[1]))


@jit_inline
def borrow_scene(s):
    """The same arrays as borrowed views (tracer.kernel.borrow): call once at a kernel's entry."""
    return SceneArrays(
        _pair(s.blas_bounds),
        _pair(s.blas_child),
        _pair(s.tri_verts),
        _pair(s.tri_prim),
        _pair(s.tri_material),
        borrowed(s.inst_pool),
        borrowed(s.inst_root),
        borrowed(s.inst_xform),
        borrowed(s.inst_inv),
        borrowed(s.inst_material),
        borrowed(s.inst_identity),
        borrowed(s.inst_rt),
        borrowed(s.inst_object),
        borrowed(s.static_runs),
        borrowed(s.tlas_bounds),
        borrowed(s.tlas_child),
        borrowed(s.tlas_inst),
        borrowed(s.mat_albedo),
        borrowed(s.mat_emission),
        borrowed(s.mat_two_sided),
        borrowed(s.mat_kind),
        borrowed(s.mat_param),
        borrowed(s.mat_texture),
        borrowed(s.mat_normal_map),
        borrowed(s.mat_normal_strength),
        _pair(s.tri_uv),
        _pair(s.tri_normal),
        borrowed(s.tex_pixels),
        borrowed(s.tex_info),
        borrowed(s.tex_scale),
        borrowed(s.mat_alpha),
        borrowed(s.light_kind),
        borrowed(s.light_inst),
        borrowed(s.light_tri),
        borrowed(s.light_cdf),
        borrowed(s.light_total),
        borrowed(s.light_data),
        borrowed(s.light_env),
        borrowed(s.sky),
        borrowed(s.sky_image),
        borrowed(s.sky_rows),
        borrowed(s.sky_cols),
        borrowed(s.light_tree_nodes),
        borrowed(s.light_tree_child),
        borrowed(s.light_tree_bits),
        borrowed(s.light_tree_area),
        borrowed(s.light_tree_keys),
        borrowed(s.light_tree_key_light),
    )
