"""The shading normal at a hit, as the effect plan asks for it: interpolated vertex normals
(``SHADING_NORMALS``), then the material's normal map (``NORMAL_MAPS``); shared by the path
vertex, the AOVs and the debug outputs so they all see the same normal."""

from tracer.geometry.scene_intersect import shading_normal
from tracer.integrators import flags
from tracer.kernel.jit import jit_inline
from tracer.shading.normal_maps import mapped_normal


@jit_inline
def surface_normal(s, mat, k, j, b0, b1, b2, ng, plan):
    """``(smooth, ns)``: the world shading normal on the side of the geometric ``ng``, and
    whether it differs from ``ng`` by construction (vertex normals or a normal map)."""
    smooth = False
    ns = ng
    if plan & flags.SHADING_NORMALS:
        smooth, ns = shading_normal(s, k, j, b0, b1, b2, ng)
    if plan & flags.NORMAL_MAPS:
        mapped, ns = mapped_normal(s, mat, k, j, b0, b1, b2, ns, ng)
        smooth = smooth or mapped
    return smooth, ns
