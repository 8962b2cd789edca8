"""Lights: emissive triangles, point and spot lights, suns and the sky; one selection table.

Next-event estimation picks one light per path vertex with probability proportional to its
power (pbrt-v4's ``PowerLightSampler``), then a point or direction on it. Selection weights are
in the units of an emissive triangle's, mean emitted radiance times area (power / pi):

| kind | weight | sampled |
|---|---|---|
| triangle | mean(Le) * area | a point uniformly by area |
| point | 4 mean(I) | its position (a delta light) |
| spot | 2 mean(I) ((1 - cos_inner) + (cos_inner - cos_outer) / 2) | its position |
| sun | mean(E) R^2 | a direction uniformly in its cone (radius 0: the direction, a delta light) |
| sky | 4 pi R^2 mean(L) | a direction uniformly on the sphere (an environment map: by luminance) |

(R is the radius of the scene's bounding sphere; the infinite lights' weights are pbrt-v4's
``Phi`` over pi.) Emissive triangles come first, ordered by (instance, triangle index), never
by BVH leaf order, so refitted and rebuilt meshes sample the same lights with the same numbers;
then point, spot and sun lights in file order; the sky last.
"""

import math
import weakref
from typing import NamedTuple

import numpy as np

from tracer.compiled.arrays import pick
from tracer.errors import SceneError
from tracer.geometry.intersect import geometric_normal, hit_point
from tracer.geometry.scene_intersect import material_of
from tracer.geometry.transforms import apply_normal, apply_point
from tracer.kernel.jit import jit, jit_inline
from tracer.maths import portable
from tracer.scene import format as fmt
from tracer.scene.environment import EnvironmentMap
from tracer.shading.environment_light import (
    EnvironmentTables,
    empty_tables,
    environment_lookup,
    environment_sample,
    sampling_tables,
)
from tracer.shading.sampling import (
    INV_PI,
    power_heuristic,
    square_to_uniform_cone,
    square_to_uniform_sphere,
    square_to_uniform_triangle,
)

TRIANGLE = 0
POINT = 1
SPOT = 2
SUN = 3
SKY = 4

LIGHT_DATA = 16
"""Columns of ``light_data``, one row per point, spot or sun light:

``POS`` (3) render-space position (point, spot) or unit direction toward the sun; ``VALUE`` (3)
intensity (point, spot), the disc's radiance (sun with a radius) or irradiance (sun without);
``AXIS`` (3) a spot's unit axis; ``COS_OUTER`` a spot's cone / a sun's ``cos`` of its radius;
``COS_INNER`` where a spot's falloff starts; ``SELECT`` the selection probability;
``ONE_MINUS_COS`` a sun's ``1 - cos(radius)`` (computed without cancellation).
"""
POS = 0
VALUE = 3
AXIS = 6
COS_OUTER = 9
COS_INNER = 10
SELECT = 11
ONE_MINUS_COS = 12

SKY_SIZE = 14
"""``sky`` layout: ``SKY_TYPE`` (0 black, 1 constant, 2 gradient, 3 environment map), ``ZENITH``
(3; the constant sky's radiance), ``HORIZON`` (3), ``GROUND`` (3), ``SKY_SELECT`` (its selection
probability, 0 if light sampling never picks it), ``SKY_MEAN`` (mean radiance over the sphere),
``ENV_COS`` and ``ENV_SIN`` (cosine and sine of an environment map's rotation about +y; its
pixels and sampling tables are the ``sky_image``, ``sky_rows`` and ``sky_cols`` arrays)."""
SKY_TYPE = 0
ZENITH = 1
HORIZON = 4
GROUND = 7
SKY_SELECT = 10
SKY_MEAN = 11
ENV_COS = 12
ENV_SIN = 13
SKY_BLACK = 0
SKY_CONSTANT = 1
SKY_GRADIENT = 2
SKY_ENVIRONMENT = 3


class LightTable(NamedTuple):
    """Every light of a scene with its selection weight, before selection probabilities.

    ``kind``, ``inst`` and ``tri`` int32 (L,): the light kind, and for triangles the instance
    and row in that instance's pool (else ``tri`` is the row of ``data``, -1 for the sky);
    ``weight`` float64 (L,): selection weights; ``data`` float64 (P, ``LIGHT_DATA``); ``sky``
    float64 (``SKY_SIZE``,); ``sky_tables`` an environment map's pixels and sampling tables.
    """

    kind: np.ndarray
    inst: np.ndarray
    tri: np.ndarray
    weight: np.ndarray
    data: np.ndarray
    sky: np.ndarray
    sky_tables: EnvironmentTables


class LightArrays(NamedTuple):
    """What kernels read (``SceneArrays`` fields of the same names without ``light_``)."""

    kind: np.ndarray
    inst: np.ndarray
    tri: np.ndarray
    cdf: np.ndarray
    """float64 (L,): selection CDF, last entry exactly 1."""
    total: np.ndarray
    """float64 (1,): the sum of the selection weights."""
    data: np.ndarray
    env: np.ndarray
    """int32 (E,): rows of ``data`` for suns with a radius (rays that miss everything see
    them)."""
    sky: np.ndarray
    sky_image: np.ndarray
    sky_rows: np.ndarray
    sky_cols: np.ndarray
    """An environment map's ``EnvironmentTables`` (unread unless the sky is one)."""


def emission_means(emission: np.ndarray) -> np.ndarray:
    """Selection weight per unit area of each material: the mean of its emitted RGB radiance,
    summed in the same order as the kernels' ``emission_mean``."""
    e = emission.astype(np.float64)
    return (e[:, 0] + e[:, 1] + e[:, 2]) / 3.0


def world_areas(tri_verts: np.ndarray, rows: np.ndarray, xform: np.ndarray) -> np.ndarray:
    """World-space areas of triangles ``rows`` under the 12-value transform ``xform``."""
    v = tri_verts[rows].astype(np.float64).reshape(-1, 3, 3)
    linear = xform.reshape(3, 4)[:, :3]
    e1 = portable.transform_vectors(v[:, 1] - v[:, 0], linear)
    e2 = portable.transform_vectors(v[:, 2] - v[:, 0], linear)
    return 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)


def triangle_lights(
    instances: list[tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
    mat_emission: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(inst, tri, weight)`` of every emissive triangle of every instance.

    ``instances`` lists, in instance order, ``(k, tri_verts, rows, prims, materials, xform)``
    where ``rows``/``prims``/``materials`` describe the instance's triangles (its pool rows,
    their mesh-local indices and material indices).
    """
    weight_per_area = emission_means(mat_emission)
    inst_parts, tri_parts, weight_parts = [], [], []
    for k, tri_verts, rows, prims, materials, xform in instances:
        emits = weight_per_area[materials] > 0.0
        if not emits.any():
            continue
        order = np.argsort(prims[emits], kind="stable")
        chosen = rows[emits][order]
        weights = weight_per_area[materials[emits][order]] * world_areas(tri_verts, chosen, xform)
        inst_parts.append(np.full(chosen.shape[0], k, dtype=np.int32))
        tri_parts.append(chosen.astype(np.int32))
        weight_parts.append(weights)
    if not inst_parts:
        return np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros(0)
    return np.concatenate(inst_parts), np.concatenate(tri_parts), np.concatenate(weight_parts)


def _mean(rgb) -> float:
    return (float(rgb[0]) + float(rgb[1]) + float(rgb[2])) / 3.0


_TABLES: "weakref.WeakKeyDictionary[EnvironmentMap, EnvironmentTables]" = (
    weakref.WeakKeyDictionary()
)
"""Each environment map's tables, built once: states share the map, so recompiling a scene
after an edit does not pass over its pixels again."""


def environment_tables(sky: EnvironmentMap) -> EnvironmentTables:
    """The sampling tables of an environment map (cached for the map's lifetime)."""
    tables = _TABLES.get(sky)
    if tables is None:
        tables = sampling_tables(sky.image, sky.model.scale)
        _TABLES[sky] = tables
    return tables


def mean_sky_radiance(sky: fmt.Sky | EnvironmentMap) -> tuple[float, float, float]:
    """The sky's radiance averaged over the sphere, per channel (a constant sky's own)."""
    if isinstance(sky, EnvironmentMap):
        return sky.mean_radiance()
    if isinstance(sky, fmt.GradientSky):
        parts = zip(sky.horizon, sky.zenith, sky.ground, strict=True)
        return tuple(0.25 * (h + z) + 0.5 * g for h, z, g in parts)
    if isinstance(sky, fmt.EnvironmentSky):
        raise SceneError(
            f"{sky.file}: an environment sky needs its image (tracer.scene.environment)"
        )
    return tuple(float(c) for c in sky.radiance)


def sky_row(sky: fmt.Sky | EnvironmentMap) -> np.ndarray:
    """The ``sky`` array of a sky (selection probability still 0)."""
    row = np.zeros(SKY_SIZE)
    if isinstance(sky, EnvironmentMap):
        mean = _mean(sky.mean_radiance())
        if mean > 0.0:
            row[SKY_TYPE] = SKY_ENVIRONMENT
            row[SKY_MEAN] = mean
            row[ENV_COS] = math.cos(math.radians(sky.model.rotation))
            row[ENV_SIN] = math.sin(math.radians(sky.model.rotation))
    elif isinstance(sky, fmt.EnvironmentSky):
        raise SceneError(
            f"{sky.file}: an environment sky needs its image (tracer.scene.environment)"
        )
    elif isinstance(sky, fmt.GradientSky):
        row[SKY_TYPE] = SKY_GRADIENT
        row[ZENITH : ZENITH + 3] = sky.zenith
        row[HORIZON : HORIZON + 3] = sky.horizon
        row[GROUND : GROUND + 3] = sky.ground
        # Uniform directions have a uniform height y: the upper half averages the horizon and
        # zenith colours, the lower half is the ground.
        upper = [0.5 * (h + z) for h, z in zip(sky.horizon, sky.zenith, strict=True)]
        row[SKY_MEAN] = 0.5 * _mean(upper) + 0.5 * _mean(sky.ground)
    elif max(sky.radiance) > 0.0:
        row[SKY_TYPE] = SKY_CONSTANT
        row[ZENITH : ZENITH + 3] = sky.radiance
        row[SKY_MEAN] = _mean(sky.radiance)
    return row


def light_row(light: fmt.Light, origin: np.ndarray, radius: float) -> tuple[int, np.ndarray, float]:
    """``(kind, data row, selection weight)`` of a point, spot or sun light; positions are moved
    into render space (world minus ``origin``)."""
    row = np.zeros(LIGHT_DATA)
    if isinstance(light, fmt.SunLight):
        theta = math.radians(light.angular_radius_deg)
        row[POS : POS + 3] = light.to_sun
        one_minus_cos = 2.0 * math.sin(0.5 * theta) ** 2
        row[ONE_MINUS_COS] = one_minus_cos
        row[COS_OUTER] = 1.0 - one_minus_cos
        if theta > 0.0:
            sin2 = one_minus_cos * (2.0 - one_minus_cos)
            row[VALUE : VALUE + 3] = np.asarray(light.irradiance) / (math.pi * sin2)
        else:
            row[VALUE : VALUE + 3] = light.irradiance
        return SUN, row, _mean(light.irradiance) * radius * radius
    row[POS : POS + 3] = np.asarray(light.position, dtype=np.float64) - origin
    row[VALUE : VALUE + 3] = light.intensity
    if isinstance(light, fmt.PointLight):
        return POINT, row, 4.0 * _mean(light.intensity)
    axis = np.subtract(light.look_at, light.position).astype(np.float64)
    row[AXIS : AXIS + 3] = axis / portable.norm(axis)
    cos_outer = math.cos(math.radians(light.cone_angle_deg))
    cos_inner = math.cos(math.radians(light.cone_angle_deg - light.falloff_deg))
    row[COS_OUTER] = cos_outer
    row[COS_INNER] = cos_inner
    weight = 2.0 * _mean(light.intensity) * ((1.0 - cos_inner) + 0.5 * (cos_inner - cos_outer))
    return SPOT, row, weight


def build_light_table(
    instances: list[tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
    mat_emission: np.ndarray,
    lights: tuple = (),
    sky: fmt.Sky | EnvironmentMap | None = None,
    origin: np.ndarray | None = None,
    radius: float = 1.0,
) -> LightTable:
    """Every light of the scene with its selection weight (see the module docstring)."""
    inst, tri, weight = triangle_lights(instances, mat_emission)
    kinds = [np.full(inst.shape[0], TRIANGLE, np.int32)]
    insts, tris, weights = [inst], [tri], [weight]
    origin = np.zeros(3) if origin is None else origin
    rows = []
    for light in lights:
        kind, row, w = light_row(light, origin, radius)
        kinds.append(np.array([kind], np.int32))
        insts.append(np.array([-1], np.int32))
        tris.append(np.array([len(rows)], np.int32))
        weights.append(np.array([w]))
        rows.append(row)
    sky_array = sky_row(sky if sky is not None else fmt.ConstantSky())
    tables = empty_tables()
    if sky_array[SKY_TYPE] == SKY_ENVIRONMENT:
        tables = environment_tables(sky)
    if sky_array[SKY_TYPE] != SKY_BLACK:
        kinds.append(np.array([SKY], np.int32))
        insts.append(np.array([-1], np.int32))
        tris.append(np.array([-1], np.int32))
        weights.append(np.array([4.0 * math.pi * radius * radius * sky_array[SKY_MEAN]]))
    data = np.array(rows, dtype=np.float64).reshape(-1, LIGHT_DATA)
    return LightTable(
        np.concatenate(kinds),
        np.concatenate(insts),
        np.concatenate(tris),
        np.concatenate(weights),
        data,
        sky_array,
        tables,
    )


def scene_fields(light: LightArrays) -> dict[str, np.ndarray]:
    """``light`` as the ``SceneArrays`` fields it fills (``light_kind``, ..., ``sky``,
    ``sky_image``, ...)."""
    return {
        name if name.startswith("sky") else f"light_{name}": value
        for name, value in light._asdict().items()
    }


def light_arrays(table: LightTable, kinds: frozenset[int] | None = None) -> LightArrays:
    """The kernel arrays of ``table``, keeping only lights of ``kinds`` (all if None).

    Lights with zero weight are dropped from the selection table (light sampling cannot pick
    them); selection probabilities are written into ``data`` and ``sky``. A light kind left
    out is not seen by rays either: the sky turns black and suns disappear from ``env``.
    """
    keep = table.weight > 0.0
    if kinds is not None:
        keep &= np.isin(table.kind, np.array(sorted(kinds), dtype=np.int32))
    data = table.data.copy()
    sky = table.sky.copy()
    if kinds is not None and SKY not in kinds:
        sky[:] = 0.0
    if not keep.any():
        empty = np.zeros(0, np.int32)
        env = np.zeros(0, np.int32)
        return LightArrays(empty, empty.copy(), empty.copy(), np.zeros(0), np.zeros(1), data, env,
                           sky, *table.sky_tables)  # fmt: skip
    weights = table.weight[keep]
    total = float(weights.sum())
    cdf = np.cumsum(weights) / total
    cdf[-1] = 1.0
    kind = table.kind[keep]
    tri = table.tri[keep]
    for k, row, w in zip(kind, tri, weights, strict=True):
        if k == SKY:
            sky[SKY_SELECT] = w / total
        elif k != TRIANGLE:
            data[row, SELECT] = w / total
    env = np.array(
        [r for k, r in zip(kind, tri, strict=True) if k == SUN and data[r, ONE_MINUS_COS] > 0.0],
        dtype=np.int32,
    )
    return LightArrays(kind, table.inst[keep], tri, cdf, np.array([total]), data, env, sky,
                       *table.sky_tables)  # fmt: skip


@jit_inline
def emission_mean(mat_emission, mat):
    """Mean of a material's emitted RGB radiance: its selection weight per unit area."""
    return (
        np.float64(mat_emission[mat, 0])
        + np.float64(mat_emission[mat, 1])
        + np.float64(mat_emission[mat, 2])
    ) / 3.0


@jit_inline
def pick_light(s, u0):
    """The entry of the selection table that ``u0`` picks (by power)."""
    e = np.searchsorted(s.light_cdf, u0, side="right")
    if e >= s.light_cdf.shape[0]:
        e = s.light_cdf.shape[0] - 1
    return e


@jit_inline
def sample_triangle(s, e, u1, u2):
    """A point on the emissive triangle of entry ``e``, uniformly by area.

    Returns ``(k, mat, q_o, q_err, n_o, q_w, n_w)``: the instance and material, the point in
    object space with its error bound and the unit object normal (for spawning the shadow ray's
    end), and the world point and unit world normal.
    """
    k = s.light_inst[e]
    j = s.light_tri[e]
    tv = pick(s.tri_verts, s.inst_pool[k])
    b0, b1, b2 = square_to_uniform_triangle(u1, u2)
    q_o, q_err = hit_point(tv, j, b0, b1, b2)
    n_o, _ = geometric_normal(tv, j)
    if s.inst_identity[k]:
        return k, material_of(s, k, j), q_o, q_err, n_o, q_o, n_o
    n = apply_normal(s.inst_inv, k, n_o)
    inv_len = 1.0 / np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    n_w = (n[0] * inv_len, n[1] * inv_len, n[2] * inv_len)
    return k, material_of(s, k, j), q_o, q_err, n_o, apply_point(s.inst_xform, k, q_o), n_w


@jit
def sky_radiance(sky, d):
    """Radiance the sky sends along ``-d`` (seen looking along the unit direction ``d``)."""
    t = sky[SKY_TYPE]
    if t == SKY_CONSTANT:
        return (sky[ZENITH], sky[ZENITH + 1], sky[ZENITH + 2])
    if t == SKY_GRADIENT:
        y = d[1]
        if y < 0.0:
            return (sky[GROUND], sky[GROUND + 1], sky[GROUND + 2])
        return (
            sky[HORIZON] + (sky[ZENITH] - sky[HORIZON]) * y,
            sky[HORIZON + 1] + (sky[ZENITH + 1] - sky[HORIZON + 1]) * y,
            sky[HORIZON + 2] + (sky[ZENITH + 2] - sky[HORIZON + 2]) * y,
        )
    return (0.0, 0.0, 0.0)


@jit
def sun_pdf(data, row):
    """Solid-angle density of a sun's direction samples (uniform in its cone)."""
    return 1.0 / (2.0 * math.pi * data[row, ONE_MINUS_COS])


@jit
def smoothstep(a, b, x):
    if a == b:
        return 1.0 if x >= a else 0.0
    t = min(1.0, max(0.0, (x - a) / (b - a)))
    return t * t * (3.0 - 2.0 * t)


@jit
def sample_distant_or_point(data, sky, sky_image, sky_rows, sky_cols, kind, row, p, u1, u2):
    """Sample a point, spot, sun or sky light as seen from ``p`` (the ``sky_*`` arrays are an
    environment map's tables).

    Returns ``(wi, target, finite, Li, pdf, delta)``: the unit direction toward the light, the
    light's position (finite lights; else unused), whether it is at a finite distance, the
    incident radiance (for a delta light, the incident irradiance-like value ``I / d^2`` or
    ``E``), and the density of this sample *including its selection probability*: a solid-angle
    density, or for a delta light the selection probability alone. A zero pdf is a failure.
    """
    zero = (0.0, 0.0, 0.0)
    if kind == SKY:
        if sky[SKY_TYPE] == SKY_ENVIRONMENT:
            wi, L, pdf = environment_sample(sky_image, sky_rows, sky_cols, sky[ENV_COS],
                                            sky[ENV_SIN], u1, u2)  # fmt: skip
            return wi, p, False, L, sky[SKY_SELECT] * pdf, False
        wi = square_to_uniform_sphere(u1, u2)
        pdf = sky[SKY_SELECT] * 0.25 * INV_PI
        return wi, p, False, sky_radiance(sky, wi), pdf, False
    if kind == SUN:
        to_sun = (data[row, POS], data[row, POS + 1], data[row, POS + 2])
        value = (data[row, VALUE], data[row, VALUE + 1], data[row, VALUE + 2])
        if data[row, ONE_MINUS_COS] <= 0.0:
            return to_sun, p, False, value, data[row, SELECT], True
        wi = square_to_uniform_cone(u1, u2, data[row, ONE_MINUS_COS], to_sun)
        return wi, p, False, value, data[row, SELECT] * sun_pdf(data, row), False
    q = (data[row, POS], data[row, POS + 1], data[row, POS + 2])
    dx = q[0] - p[0]
    dy = q[1] - p[1]
    dz = q[2] - p[2]
    dist2 = dx * dx + dy * dy + dz * dz
    if not dist2 > 0.0:
        return zero, q, True, zero, 0.0, True
    inv = 1.0 / math.sqrt(dist2)
    wi = (dx * inv, dy * inv, dz * inv)
    scale = 1.0 / dist2
    if kind == SPOT:
        cos_axis = -(wi[0] * data[row, AXIS] + wi[1] * data[row, AXIS + 1]
                     + wi[2] * data[row, AXIS + 2])  # fmt: skip
        scale *= smoothstep(data[row, COS_OUTER], data[row, COS_INNER], cos_axis)
    li = (data[row, VALUE] * scale, data[row, VALUE + 1] * scale, data[row, VALUE + 2] * scale)
    return wi, q, True, li, data[row, SELECT], True


@jit
def environment_radiance(data, env, sky, sky_image, sky_rows, sky_cols, d, p_bsdf, mis):
    """Radiance arriving along ``-d`` from everything at infinity (sky and sun discs), each
    weighted against light sampling by the power heuristic when ``mis`` (``p_bsdf`` is the
    solid-angle density with which the BSDF chose ``d``)."""
    if sky[SKY_TYPE] == SKY_ENVIRONMENT:
        L, p_sky = environment_lookup(sky_image, sky_rows, sky_cols, sky[ENV_COS], sky[ENV_SIN],
                                      d)  # fmt: skip
    else:
        L = sky_radiance(sky, d)
        p_sky = 0.25 * INV_PI
    if mis and sky[SKY_SELECT] > 0.0:
        w = power_heuristic(p_bsdf, sky[SKY_SELECT] * p_sky)
        L = (L[0] * w, L[1] * w, L[2] * w)
    for i in range(env.shape[0]):
        row = env[i]
        cos = d[0] * data[row, POS] + d[1] * data[row, POS + 1] + d[2] * data[row, POS + 2]
        if cos < data[row, COS_OUTER]:
            continue
        w = 1.0
        if mis:
            p_light = data[row, SELECT] * sun_pdf(data, row)
            w = p_bsdf * p_bsdf / (p_bsdf * p_bsdf + p_light * p_light)
        L = (L[0] + data[row, VALUE] * w, L[1] + data[row, VALUE + 1] * w,
             L[2] + data[row, VALUE + 2] * w)  # fmt: skip
    return L
