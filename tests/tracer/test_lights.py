"""Lights against analytic values: a Lambertian ground plane lit by a point, spot, sun or sky
light, seen by a camera looking straight down. Direct lighting only (``max_depth`` 2), so the
exact pixel value is the reflected radiance ``rho / pi * E`` averaged over the pixel's footprint,
which the tests integrate numerically; the tolerance comes from the spread of independent
passes."""

import math

import numpy as np
import pytest

from tests.helpers import compile_dict, mean_and_error, render_passes
from tracer.scene import format as fmt
from tracer.shading import lights

RHO = 0.6
SIZE = 16
CAMERA = {
    "position": [0.0, 6.0, 0.0],
    "look_at": [0.0, 0.0, 0.0],
    "up": [0.0, 0.0, -1.0],
    "vfov_deg": 30.0,
    "width": SIZE,
    "height": SIZE,
}


def ground_scene(lights_=(), sky=None, max_depth=2):
    data = {
        "camera": CAMERA,
        "render": {"spp": 16, "max_depth": max_depth, "rr_depth": 8},
        "materials": {"ground": {"reflectance": [RHO, RHO, RHO]}},
        "objects": [{"shape": {"type": "plane", "size": 8.0}, "material": "ground"}],
        "lights": list(lights_),
    }
    if sky is not None:
        data["sky"] = sky
    return compile_dict(data)


def footprint_points(sub: int = 12) -> np.ndarray:
    """Ground points (y = 0) under ``sub`` x ``sub`` film positions per pixel, (H, W, sub*sub,
    3), by the pinhole model of ``tracer.shading.camera``."""
    camera = fmt.Camera(**CAMERA)
    pos = np.array(camera.position)
    forward = np.array(camera.look_at) - pos
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, camera.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    tan_half = math.tan(math.radians(camera.vfov_deg) / 2)
    offsets = (np.arange(sub) + 0.5) / sub
    fx = np.arange(SIZE)[:, None] + offsets[None, :]
    sx = (2.0 * fx / SIZE - 1.0) * tan_half
    sy = (1.0 - 2.0 * fx / SIZE) * tan_half
    d = (
        forward[None, None, None, None, :]
        + sx[None, :, None, :, None] * right
        + sy[:, None, :, None, None] * up
    )
    t = -pos[1] / d[..., 1]
    points = pos + t[..., None] * d
    return points.reshape(SIZE, SIZE, sub * sub, 3)


def expected_image(irradiance) -> np.ndarray:
    """Mean over each pixel's footprint of rho / pi * E(point), (H, W, 3)."""
    points = footprint_points()
    e = irradiance(points)
    return RHO / math.pi * e.mean(axis=2)


def assert_matches(scene, expected, passes=8, spp=16):
    """Per pixel within 4 standard errors (plus 1e-4 relative, the footprint integration), and
    the image mean within 4 standard errors."""
    images = render_passes(scene, passes, spp)
    mean = images.mean(axis=0)
    se = images.std(axis=0, ddof=1) / math.sqrt(passes)
    slack = 4.0 * se + 1e-4 * np.abs(expected) + 1e-12
    bad = np.abs(mean - expected) > slack
    assert bad.mean() < 0.01, (mean[bad][:5], expected[bad][:5])
    image_mean, image_se = mean_and_error(images)
    target = expected.reshape(-1, 3).mean(axis=0)
    assert np.all(np.abs(image_mean - target) <= 4.0 * image_se + 1e-4 * target), (
        image_mean,
        target,
    )


def point_irradiance(position, intensity, spot=None):
    def irradiance(points):
        rel = np.asarray(position) - points
        dist2 = (rel**2).sum(axis=-1)
        cos = rel[..., 1] / np.sqrt(dist2)
        scale = cos / dist2
        if spot is not None:
            axis, cos_outer, cos_inner = spot
            cos_axis = -(rel @ axis) / np.sqrt(dist2)
            t = np.clip((cos_axis - cos_outer) / (cos_inner - cos_outer), 0.0, 1.0)
            scale = scale * t * t * (3.0 - 2.0 * t)
        return scale[..., None] * np.asarray(intensity)

    return irradiance


def test_point_light_irradiance():
    """E = I cos / r^2 on the plane: the inverse-square law and the cosine."""
    light = {"type": "point", "position": [0.7, 2.0, -0.4], "intensity": [10.0, 5.0, 2.0]}
    expected = expected_image(point_irradiance(light["position"], light["intensity"]))
    assert_matches(ground_scene([light]), expected)


def test_spot_light_cone_and_falloff():
    """A spot light: full intensity inside the inner cone, pbrt's smoothstep in the falloff,
    nothing outside; the footprint crosses all three."""
    light = {
        "type": "spot",
        "position": [0.0, 2.0, 0.0],
        "look_at": [0.3, 0.0, 0.0],
        "intensity": [20.0, 20.0, 20.0],
        "cone_angle_deg": 25.0,
        "falloff_deg": 10.0,
    }
    axis = np.array([0.3, -2.0, 0.0]) / np.linalg.norm([0.3, -2.0, 0.0])
    spot = (axis, math.cos(math.radians(25.0)), math.cos(math.radians(15.0)))
    expected = expected_image(point_irradiance(light["position"], light["intensity"], spot))
    assert (expected == 0.0).any() and (expected > 0.0).any()
    assert_matches(ground_scene([light]), expected)


def test_directional_sun_is_exact():
    """A sun of radius 0 is a delta light: every sample is exactly rho / pi * E cos(theta)."""
    to_sun = np.array([1.0, 2.0, 0.5]) / np.linalg.norm([1.0, 2.0, 0.5])
    light = {
        "type": "sun",
        "to_sun": list(to_sun),
        "irradiance": [3.0, 2.0, 1.0],
        "angular_radius_deg": 0.0,
    }
    image = render_passes(ground_scene([light]), 1, 4)[0]
    expected = RHO / math.pi * np.array([3.0, 2.0, 1.0]) * to_sun[1]
    np.testing.assert_allclose(image, np.broadcast_to(expected, image.shape), rtol=1e-6)


def test_sun_disc_irradiance():
    """A sun disc wholly above the horizon gives E cos(axis) exactly (the integral of cos over a
    cone of uniform radiance), sampled in its cone: statistically equal."""
    to_sun = np.array([0.5, 1.0, 0.2]) / np.linalg.norm([0.5, 1.0, 0.2])
    light = {
        "type": "sun",
        "to_sun": list(to_sun),
        "irradiance": [3.0, 3.0, 3.0],
        "angular_radius_deg": 8.0,
    }
    expected = np.broadcast_to(RHO / math.pi * 3.0 * to_sun[1], (SIZE, SIZE, 3))
    assert_matches(ground_scene([light]), expected)


def test_constant_sky_irradiance():
    """A plane under a constant sky L gets E = pi L: it shows rho L."""
    expected = np.broadcast_to(RHO * np.array([0.5, 1.0, 2.0]), (SIZE, SIZE, 3))
    assert_matches(ground_scene(sky={"radiance": [0.5, 1.0, 2.0]}), expected)


def test_gradient_sky_irradiance():
    """Radiance h + (z - h) cos(theta) above the horizon gives E = pi (h + 2/3 (z - h))."""
    zenith = np.array([0.2, 0.4, 1.0])
    horizon = np.array([1.0, 0.9, 0.8])
    sky = {
        "type": "gradient",
        "zenith": list(zenith),
        "horizon": list(horizon),
        "ground": [5.0, 0.0, 0.0],
    }
    e = math.pi * (horizon + 2.0 / 3.0 * (zenith - horizon))
    expected = np.broadcast_to(RHO / math.pi * e, (SIZE, SIZE, 3))
    assert_matches(ground_scene(sky=sky), expected)


def test_lights_add_up():
    """A point light, a sun and the sky together give the sum of their images, through one
    power-proportional light choice per vertex."""
    point = {"type": "point", "position": [0.0, 2.0, 0.0], "intensity": [6.0, 6.0, 6.0]}
    to_sun = np.array([0.0, 1.0, 1.0]) / math.sqrt(2.0)
    sun = {
        "type": "sun",
        "to_sun": list(to_sun),
        "irradiance": [2.0, 2.0, 2.0],
        "angular_radius_deg": 0.0,
    }
    e_point = point_irradiance(point["position"], point["intensity"])
    expected = expected_image(lambda p: e_point(p) + 2.0 * to_sun[1] + math.pi * 0.3)
    assert_matches(ground_scene([point, sun], sky={"radiance": [0.3, 0.3, 0.3]}), expected)


def test_a_wrong_intensity_is_caught():
    """Negative control: the point light's image against 2% more light fails."""
    light = {"type": "point", "position": [0.7, 2.0, -0.4], "intensity": [10.0, 5.0, 2.0]}
    expected = expected_image(point_irradiance(light["position"], light["intensity"]))
    with pytest.raises(AssertionError):
        assert_matches(ground_scene([light]), expected * 1.02)


def test_the_sun_disc_is_seen():
    """Looking straight at a sun of radius 5 degrees, the centre of the image shows the disc's
    radiance E / (pi sin^2(radius))."""
    scene = compile_dict(
        {
            "camera": {
                "position": [0, 0, 0],
                "look_at": [0, 1, 0],
                "up": [0, 0, 1],
                "vfov_deg": 2.0,
                "width": 4,
                "height": 4,
            },
            "render": {"spp": 4},
            "materials": {"ground": {}},
            "objects": [
                {
                    "shape": {"type": "plane", "size": 1.0},
                    "material": "ground",
                    "transform": {"translate": [0, -5, 0]},
                }
            ],
            "lights": [
                {
                    "type": "sun",
                    "to_sun": [0, 1, 0],
                    "irradiance": [1, 2, 3],
                    "angular_radius_deg": 5.0,
                }
            ],
        }
    )
    image = render_passes(scene, 1, 4)[0]
    radiance = np.array([1.0, 2.0, 3.0]) / (math.pi * math.sin(math.radians(5.0)) ** 2)
    np.testing.assert_allclose(image, np.broadcast_to(radiance, image.shape), rtol=1e-6)


def test_selection_weights():
    """Selection weights follow pbrt-v4's light powers over pi (docs in tracer.shading.lights)."""
    table = lights.build_light_table(
        [],
        np.zeros((0, 3), np.float32),
        (
            fmt.PointLight(type="point", position=(0, 0, 0), intensity=(3, 3, 3)),
            fmt.SunLight(type="sun", to_sun=(0, 1, 0), irradiance=(2, 2, 2)),
        ),
        fmt.ConstantSky(radiance=(1, 1, 1)),
        np.zeros(3),
        radius=2.0,
    )
    np.testing.assert_allclose(table.weight, [12.0, 8.0, 16.0 * math.pi])
    arrays = lights.light_arrays(table)
    assert arrays.cdf[-1] == 1.0
    np.testing.assert_allclose(arrays.data[:, lights.SELECT], table.weight[:2] / table.weight.sum())
