"""Tunables and limits, in one place.

numba freezes module globals into compiled code as constants, so kernels take these values as
arguments (or are compiled against them once, as for array sizes); change them here only.
"""

# --- BVH build -------------------------------------------------------------------------------
BVH_BINS = 16
"""Bins per axis in the binned-SAH builder."""
BVH_MAX_LEAF = 4
"""Most triangles in one leaf. Leaves are never larger: the builder forces a split instead."""
BVH_TRAVERSAL_COST = 1.0
BVH_INTERSECT_COST = 1.0
BVH_REBUILD_THRESHOLD = 1.3
"""After a refit, subtrees whose normalised SAH cost grew past this factor of its value when
they were built are rebuilt (Reiter's 1.3; see tracer.geometry.bvh_update). 0 = always rebuild the
whole tree, ``math.inf`` = only refit."""
BVH_MAX_BUILD_DEPTH = 48
"""Below this depth the builder stops trusting SAH and splits at the index median, which bounds
the tree depth (and the traversal stack) for adversarial inputs such as collinear centroids."""
BVH_MAX_TREE_DEPTH = 80
"""Deepest tree allowed. The builder keeps the depth at most ``BVH_MAX_BUILD_DEPTH`` + 28
(index-median splits below that depth, at most 2**28 primitives): 76. ``bvh.build`` checks it."""
TRAVERSAL_STACK_SIZE = 3 * BVH_MAX_TREE_DEPTH
"""Entries on a traversal stack. A scene traversal stacks a mesh's traversal on top of the top
level's; a 4-wide tree whose traversal could need more than its half (``bvh.MAX_STACK_NEED``)
stays 2-wide, which needs at most one entry per level plus one."""

# --- Rays ------------------------------------------------------------------------------------
SHADOW_EPSILON = 1e-9
"""Shadow rays stop this fraction of their length short of the (already offset) light sample.
A relative length, independent of the scene's scale; see docs/robustness.md."""

# --- Limits on user input --------------------------------------------------------------------
MAX_IMAGE_SIDE = 16384
MAX_PIXELS = 64 * 1024 * 1024
MAX_SPP = 1 << 20
MAX_DEPTH = 1024
MAX_SPHERE_SUBDIVISIONS = 8
MAX_ENVIRONMENT_PIXELS = 16 * 1024 * 1024
"""Largest environment map (pixels): its image and sampling tables then take about 320 MB."""

# --- Debug outputs ---------------------------------------------------------------------------
COST_HEATMAP_MAX = 65536
"""Work per sample (node visits plus triangle tests) shown as the hottest colour of the cost
heat map (tracer.io.heatmap); the scale is logarithmic from 0."""

# --- Textures --------------------------------------------------------------------------------
MAX_TEXTURE_SIDE = 16384
MAX_TEXTURE_PIXELS = 16 * 1024 * 1024
"""Most pixels in one texture (64 MB of uint8 in a scene, 192 MB of float32 texels compiled)."""
