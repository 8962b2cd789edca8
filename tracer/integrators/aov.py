"""Arbitrary output variables (AOVs) from the path tracer's own paths: what the denoiser's guides
and compositors read, gathered while the beauty is traced (no second camera pass).

Per camera sample the path kernel (``tracer.integrators.path``) records, with the plan's
``flags.AOVS`` bit, what ``tracer.integrators.vertex.shade`` gives it from the surface evaluation
it shades with:

- ``albedo`` and ``normal`` at the path's first non-delta vertex, following mirrors, smooth
  conductors and glass as Cycles and Open Image Denoise recommend: the albedo is the colour
  ``bsdf.bsdf_albedo`` gives that vertex (textured), times the colours of the delta vertices
  before it; the normal is its shading normal facing the ray (the geometric one where the plan
  has no shading normals or normal maps), unbent. Glass picks reflection or
  refraction per sample, so the mean over samples is their Fresnel blend. A path that escapes,
  or ends, before such a vertex adds zero to both.
- ``depth`` (the distance along the camera ray), ``position`` (the world-space point) and
  ``alpha`` (1 where the camera ray hits something) at the camera ray's hit; 0 where it misses.
- ``object_id`` and ``material_id``: the scene node (a scene file's objects by their index) and
  the material (its index in the scene's ``materials``) the camera ray of the pixel's first
  sample in the render call hits; -1 where it misses.

Each but the ids is the mean over the pixel's samples, like the beauty (a mean of ids means
nothing): all are as independent of the frame's split and threads as the beauty. Whoever
combines renders of several sample ranges takes the ids from the one with the frame's first
sample (:data:`IDS`). The kernel accumulates positions in render space; ``world_positions``
adds the scene's origin where the camera rays hit.
"""

import numpy as np

ALBEDO = 0
NORMAL = 3
DEPTH = 6
POSITION = 7
ALPHA = 10
OBJECT_ID = 11
MATERIAL_ID = 12
CHANNELS = 13
"""Columns of the kernels' AOV output: albedo (3), normal (3), depth, position (3), alpha,
object id, material id."""
IDS = slice(OBJECT_ID, MATERIAL_ID + 1)
"""The id columns: a pixel's first sample's, not a mean (ids are exact in float32 below 2**24)."""

LAYERS = {
    "albedo": slice(ALBEDO, ALBEDO + 3),
    "normal": slice(NORMAL, NORMAL + 3),
    "depth": DEPTH,
    "position": slice(POSITION, POSITION + 3),
    "alpha": ALPHA,
    "object_id": OBJECT_ID,
    "material_id": MATERIAL_ID,
}
"""Each AOV layer's columns."""


def world_positions(aov: np.ndarray, origin: np.ndarray) -> None:
    """Move the kernels' render-space positions (``aov``, (n, CHANNELS)) to world space in
    place: the origin, weighted by the share of samples that hit (``alpha``)."""
    aov[:, POSITION : POSITION + 3] += (
        aov[:, ALPHA : ALPHA + 1].astype(np.float64) * np.asarray(origin, np.float64)
    ).astype(np.float32)


def aov_layers(aov: np.ndarray) -> dict[str, np.ndarray]:
    """The AOV channels (H, W, CHANNELS) as named layers: (H, W, 3) for albedo, normal and
    position, (H, W) for depth, alpha and the ids."""
    return {name: np.ascontiguousarray(aov[..., columns]) for name, columns in LAYERS.items()}
