"""The scene traversals of the kernels' material builds: ``scene_closest`` and
``scene_occluded`` whose mesh traversals skip the hits the alpha test hides
(``tracer.shading.alpha``). The same code as ``tracer.geometry.scene_intersect``'s, with the
test bound in; the lean builds keep those, which never compile it."""

from tracer.geometry.intersect import any_hit_traversal, closest_traversal
from tracer.geometry.scene_intersect import scene_closest, scene_occluded
from tracer.kernel.jit import jit_inline, with_globals
from tracer.shading.alpha import hidden

_blas_closest = jit_inline(with_globals(closest_traversal(True), hidden=hidden))
_blas_occluded = jit_inline(with_globals(any_hit_traversal(True), hidden=hidden))
alpha_closest = jit_inline(with_globals(scene_closest.py_func, blas_closest=_blas_closest))
"""``scene_closest`` with the alpha test."""
alpha_occluded = jit_inline(with_globals(scene_occluded.py_func, blas_occluded=_blas_occluded))
"""``scene_occluded`` with the alpha test."""


def traversals(materials: bool) -> dict:
    """The names a kernel build binds (``with_globals``) for its closest-hit and shadow
    traversals: with the alpha test in the material build, as they were in the lean one."""
    if materials:
        return {"scene_closest": alpha_closest, "scene_occluded": alpha_occluded}
    return {"scene_closest": scene_closest, "scene_occluded": scene_occluded}
