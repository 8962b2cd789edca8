"""Numbers the Mitsuba export computes for Mitsuba's models: sky and environment bitmaps, the spot
light's falloff texture, the rough plastic's base scale, and whether a mesh is closed."""

import functools
import math

import numpy as np
import trimesh

from tracer.kernel.jit import jit
from tracer.maths import portable
from tracer.scene import format as fmt
from tracer.scene.environment import EnvironmentMap
from tracer.shading.fresnel import fr_dielectric
from tracer.shading.materials import (
    COAT_QUADRATURE,
    coat_tables,
    gauss_legendre,
)
from tracer.shading.microfacet import ggx_g1, ggx_sample_visible_normal, reflect_local

SKY_ROWS = 4096
"""Rows of the latitude-longitude bitmap of a gradient sky (Mitsuba puts row ``i`` at polar angle
``i * pi / (rows - 1)``; an even count puts the horizon between two rows)."""
SKY_COLUMNS = 8
"""Columns of that bitmap (the gradient does not depend on the azimuth)."""
SPOT_TEXTURE_SIZE = 512
"""Side of the projection bitmap that gives a spot light our smoothstep falloff."""
ENVIRONMENT_TEXELS = 1 << 21
"""An environment map is resampled to about this many texels (see :func:`environment_bitmap`)."""
ENVIRONMENT_MAX_FACTOR = 32
"""At most this many bitmap texels per map pixel, along each axis."""
MITSUBA_COAT_COSINES = 64
"""Cosines ``max(1e-6, j / 63)`` over which Mitsuba's ``roughplastic`` averages its coat's
internal reflectance (``MI_ROUGH_TRANSMITTANCE_RES``)."""


def sky_radiance(sky: fmt.Sky | EnvironmentMap, direction) -> np.ndarray:
    """Radiance the sky sends from ``direction`` (unit, +y up), as ``tracer.shading.lights``
    defines it."""
    if isinstance(sky, EnvironmentMap):
        return environment_radiance(sky, direction)
    if isinstance(sky, fmt.GradientSky):
        y = float(direction[1])
        if y < 0.0:
            return np.asarray(sky.ground, dtype=np.float64)
        horizon = np.asarray(sky.horizon, dtype=np.float64)
        return horizon + (np.asarray(sky.zenith) - horizon) * y
    return np.asarray(sky.radiance, dtype=np.float64)


def gradient_sky_bitmap(sky: fmt.GradientSky) -> np.ndarray:
    """(SKY_ROWS, SKY_COLUMNS, 3) float32 latitude-longitude bitmap of the gradient: row ``i``
    holds the radiance at polar angle ``i * pi / (SKY_ROWS - 1)`` from +y (Mitsuba's
    ``envmap`` places rows at these angles and interpolates bilinearly between them)."""
    y = np.cos(np.arange(SKY_ROWS) * math.pi / (SKY_ROWS - 1))
    rows = np.stack([sky_radiance(sky, (0.0, yi, 0.0)) for yi in y])
    return np.repeat(rows[:, None, :], SKY_COLUMNS, axis=1).astype(np.float32)


def environment_scaled(sky: EnvironmentMap) -> np.ndarray:
    """The map's pixels times its ``scale``, float32, as ``tracer.shading.environment_light`` scales
    them for the kernels."""
    return (sky.image.astype(np.float64) * sky.model.scale).astype(np.float32)


def environment_radiance(sky: EnvironmentMap, direction) -> np.ndarray:
    """The map's radiance from unit ``direction``: the pixel ``tracer.shading.environment_light``
    looks up (nearest pixel, after turning the direction into the map's frame)."""
    h, w = sky.image.shape[:2]
    d = portable.transform_vectors(direction, _environment_frame(sky.model.rotation))
    v = math.atan2(math.hypot(d[0], d[2]), d[1]) / math.pi
    u = math.atan2(d[0], -d[2]) / (2.0 * math.pi) + 0.5
    i = min(max(int(v * h), 0), h - 1)
    j = min(max(int(u * w), 0), w - 1)
    return environment_scaled(sky)[i, j].astype(np.float64)


def _environment_frame(rotation_deg: float) -> np.ndarray:
    """World -> map directions: the inverse of the map's ``rotation`` about +y."""
    c, s = math.cos(math.radians(rotation_deg)), math.sin(math.radians(rotation_deg))
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def environment_to_world(rotation_deg: float) -> np.ndarray:
    """4x4 ``to_world`` of Mitsuba's ``envmap`` for our map turned by ``rotation_deg``.

    Mitsuba reads ``u = atan2(x, -z) / 2 pi`` (wrapped to [0, 1)) of the local direction: its
    image centre looks along +z, ours along -z, with ``u`` growing toward +x in both. So the
    local direction is ours in the map's frame turned by 180 degrees about +y (``F``), and
    ``to_world = (F R)^-1``, ``R`` the world -> map turn."""
    flip = np.diag([-1.0, 1.0, -1.0])
    matrix = np.eye(4)
    matrix[:3, :3] = portable.matmul(flip, _environment_frame(rotation_deg)).T  # a rotation
    return matrix


def environment_bitmap(sky: EnvironmentMap) -> tuple[np.ndarray, int]:
    """The map (scale applied) as Mitsuba's ``envmap`` bitmap, and the factor ``k`` it was
    upsampled by: ``(k H + 1, k W, 3)`` float32.

    Ours is constant over each pixel; Mitsuba interpolates bilinearly between texels placed at
    ``u = (j + 0.5) / W'`` (wrapping around) and at polar angles ``i pi / (H' - 1)`` (measured
    on 3.9.1). With ``W' = k W`` the edges of our columns fall midway between two texels; with
    ``H' = k H + 1`` the edges of our rows fall on a texel, which takes the mean of the two
    rows. Each edge becomes a linear ramp, symmetric about it, of one texel each side: the
    map's integral is kept and a lookup differs from ours only within ``1 / k`` of a pixel
    from its edges."""
    scaled = environment_scaled(sky)
    h, w = scaled.shape[:2]
    k = max(1, min(ENVIRONMENT_MAX_FACTOR, math.isqrt(ENVIRONMENT_TEXELS // (h * w))))
    columns = np.repeat(scaled, k, axis=1)
    fine = np.arange(k * h + 1)
    rows = columns[np.minimum(fine // k, h - 1)]
    edges = fine[(fine % k == 0) & (fine > 0) & (fine < k * h)]
    above = columns[edges // k - 1].astype(np.float64)
    rows[edges] = (0.5 * (above + columns[edges // k])).astype(np.float32)
    return rows, k


def spot_profile(cone_angle_deg: float, falloff_deg: float, cos_theta: np.ndarray) -> np.ndarray:
    """Our spot falloff: pbrt-v4's smoothstep between the cosines of the outer and inner cones."""
    cos_outer = math.cos(math.radians(cone_angle_deg))
    cos_inner = math.cos(math.radians(cone_angle_deg - falloff_deg))
    if cos_inner == cos_outer:
        return (cos_theta >= cos_outer).astype(np.float64)
    t = np.clip((cos_theta - cos_outer) / (cos_inner - cos_outer), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def spot_texture(cone_angle_deg: float, falloff_deg: float) -> np.ndarray:
    """(N, N, 3) float32 projection bitmap for Mitsuba's ``spot``: texel centres ``(u, v)`` map
    to the local direction ``((2u - 1) tan(cone), (2v - 1) tan(cone), 1)``, as the plugin's
    ``direction_to_uv`` does; each texel holds our falloff in that direction."""
    n = SPOT_TEXTURE_SIZE
    s = (2.0 * (np.arange(n) + 0.5) / n - 1.0) * math.tan(math.radians(cone_angle_deg))
    cos_theta = 1.0 / np.sqrt(1.0 + s[:, None] ** 2 + s[None, :] ** 2)
    profile = spot_profile(cone_angle_deg, falloff_deg, cos_theta)
    return np.repeat(profile[..., None], 3, axis=2).astype(np.float32)


@jit
def separable_coat_reflectance(cos_theta, alpha, eta, nodes, weights):
    """Directional reflectance of a GGX dielectric interface for light arriving at
    ``cos_theta`` from the side of relative index ``eta``, with separable masking, as Mitsuba's
    ``eval_reflectance`` integrates it: Fresnel times ``G1`` of the reflected direction over
    the visible normals (``tracer.shading.microfacet``'s sampler on the product rule ``nodes``,
    ``weights``). ``microfacet.ggx_dielectric_albedo`` is the height-correlated form."""
    wi = (math.sqrt(max(0.0, 1.0 - cos_theta * cos_theta)), 0.0, cos_theta)
    r = 0.0
    for a in range(nodes.shape[0]):
        for b in range(nodes.shape[0]):
            m = ggx_sample_visible_normal(wi, alpha, nodes[a], nodes[b])
            wr = reflect_local(wi, m)
            if wr[2] > 0.0:
                cos_im = wi[0] * m[0] + wi[1] * m[1] + wi[2] * m[2]
                r += weights[a] * weights[b] * fr_dielectric(cos_im, eta) * ggx_g1(wr, alpha)
    return r


@functools.lru_cache(maxsize=64)
def mitsuba_internal_reflectance(alpha: float, ior: float) -> float:
    """The internal diffuse reflectance Mitsuba's ``roughplastic`` computes for its coat: the
    mean of ``2 R(mu) mu`` over ``mu = max(1e-6, linspace(0, 1, 64))`` (both ends included, so
    not the integral ``2 int R mu dmu``), ``R`` the reflectance from inside with separable
    masking (:func:`separable_coat_reflectance`)."""
    nodes, weights = gauss_legendre(COAT_QUADRATURE)
    mu = np.maximum(1e-6, np.linspace(0.0, 1.0, MITSUBA_COAT_COSINES))
    r = np.array([separable_coat_reflectance(m, alpha, 1.0 / ior, nodes, weights) for m in mu])
    return float(2.0 * np.mean(r * mu))


def rough_plastic_base_scale(alpha: float, ior: float) -> float:
    """Factor on a rough plastic's ``diffuse_reflectance`` that makes the base term of
    Mitsuba's linear ``roughplastic`` ours: ``(1 - Fdr_mitsuba) / (1 - Fdr_ours)``, Mitsuba's
    internal reflectance (:func:`mitsuba_internal_reflectance`) over ours
    (``materials.coat_tables``, the kernels' own)."""
    ours = coat_tables(alpha, ior)[1]
    return (1.0 - mitsuba_internal_reflectance(alpha, ior)) / (1.0 - ours)


def winding_numbers(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Generalised winding number of a closed mesh at each point (1 inside an outward-wound
    mesh, 0 outside): the solid angles of its triangles (Van Oosterom and Strackee) over 4 pi."""
    tri = vertices[faces]  # (F, 3, 3)
    result = np.zeros(len(points))
    for i, p in enumerate(points):
        a, b, c = (tri[:, j] - p for j in range(3))
        la, lb, lc = (np.linalg.norm(v, axis=1) for v in (a, b, c))
        det = np.einsum("ij,ij->i", a, np.cross(b, c))
        den = (
            la * lb * lc
            + np.einsum("ij,ij->i", a, b) * lc
            + np.einsum("ij,ij->i", a, c) * lb
            + np.einsum("ij,ij->i", b, c) * la
        )
        result[i] = np.sum(2.0 * np.arctan2(det, den)) / (4.0 * math.pi)
    return result


def is_closed_outward(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Whether the triangles (with coincident vertices merged) bound a volume, wound outward."""
    mesh = trimesh.Trimesh(vertices, faces, process=True)
    return bool(mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0.0)


MASK_GRID = 8
"""Points per texel side at which ``mask_opacity`` thresholds an alpha texture."""
MASK_SIDE = 4096
"""The largest side of a thresholded mask (fewer points per texel for large textures)."""


def mask_opacity(alpha: np.ndarray, wrap: str, cutoff: float) -> tuple[np.ndarray, int]:
    """A mask's opacity for Mitsuba: ``alpha`` (H, W) looked up bilinearly as the kernels do
    (``tracer.shading.textures.bilinear``, ``wrap`` at the edges) at the centres of a grid
    ``k`` times finer than the texels, 1 where it reaches ``cutoff`` and 0 elsewhere; returns
    the grid (H k, W k) and ``k``."""
    height, width = alpha.shape
    k = max(1, min(MASK_GRID, MASK_SIDE // max(height, width)))

    def neighbours(size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x = (np.arange(size * k) + 0.5) / k - 0.5  # texel space, centres at integers
        i0 = np.floor(x).astype(np.int64)
        if wrap == "repeat":
            return i0 % size, (i0 + 1) % size, x - i0
        return np.clip(i0, 0, size - 1), np.clip(i0 + 1, 0, size - 1), x - i0

    x0, x1, fx = neighbours(width)
    y0, y1, fy = neighbours(height)
    fx, fy = fx[None, :], fy[:, None]
    value = ((1 - fx) * (1 - fy) * alpha[np.ix_(y0, x0)] + fx * (1 - fy) * alpha[np.ix_(y0, x1)]
             + (1 - fx) * fy * alpha[np.ix_(y1, x0)] + fx * fy * alpha[np.ix_(y1, x1)])  # fmt: skip
    return (value >= cutoff).astype(np.float64), k
