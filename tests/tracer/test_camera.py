"""The thin-lens camera: aperture 0 is the pinhole ray for ray; lens rays of one film position
meet on the focus plane; objects on that plane stay sharp and others blur by the circle of
confusion."""

import math

import numpy as np

from tests.helpers import CORNELL, compile_dict, render_passes
from tracer.compiled.scene import compile_scene
from tracer.render import render_image
from tracer.scene.format import override
from tracer.scene.loader import load_scene
from tracer.shading.camera import (
    FOCUS_DISTANCE,
    LENS_RADIUS,
    camera_array,
    primary_ray,
    thin_lens_ray,
)


def test_zero_aperture_is_the_pinhole():
    cam = camera_array((0.1, 0.2, 3.0), (0.0, 0.0, 0.0), (0, 1, 0), 40.0, 64, 48)
    rng = np.random.default_rng(0)
    for fx, fy, u1, u2 in rng.uniform(0.0, 1.0, size=(200, 4)) * [64, 48, 1, 1]:
        assert thin_lens_ray(cam, 64, 48, fx, fy, u1, u2) == primary_ray(cam, 64, 48, fx, fy)


def test_lens_rays_meet_on_the_focus_plane():
    """For one film position, rays from anywhere on the lens pass through the pinhole ray's
    point on the plane at focus_distance along the view direction; they start on the lens
    disc, in the plane of the film's axes."""
    position = np.array([0.3, 1.0, 4.0])
    cam = camera_array(position, (0.0, 0.5, 0.0), (0, 1, 0), 35.0, 32, 32, 0.25, 3.0)
    assert cam[LENS_RADIUS] == 0.25 and cam[FOCUS_DISTANCE] == 3.0
    forward = cam[3:6]
    rng = np.random.default_rng(1)
    for fx, fy in rng.uniform(0.0, 32.0, size=(20, 2)):
        o0, d0 = primary_ray(cam, 32, 32, fx, fy)
        target = np.array(o0) + np.array(d0) * 3.0 / np.dot(d0, forward)
        for u1, u2 in rng.uniform(size=(10, 2)):
            o, d = thin_lens_ray(cam, 32, 32, fx, fy, u1, u2)
            offset = np.array(o) - position
            assert np.linalg.norm(offset) <= 0.25 + 1e-12
            assert abs(np.dot(offset, forward)) < 1e-12
            t = np.dot(target - np.array(o), d)
            np.testing.assert_allclose(np.array(o) + t * np.array(d), target, atol=1e-12)


def test_default_focus_is_the_look_at_distance():
    cam = camera_array((0.0, 0.0, 5.0), (0.0, 0.0, 1.0), (0, 1, 0), 40.0, 8, 8, 0.1)
    assert cam[FOCUS_DISTANCE] == 4.0


def test_explicit_zero_aperture_renders_the_same_image():
    scene = compile_scene(load_scene(CORNELL))
    camera = override(scene.camera, width=24, height=24)
    settings = override(scene.render, spp=2)
    a, _ = render_image(scene, camera, settings)
    b, _ = render_image(scene, override(camera, aperture_radius=0.0, focus_distance=2.0), settings)
    assert a.tobytes() == b.tobytes()


def edge_width(profile: np.ndarray) -> float:
    """Pixels between 10% and 90% of a rising edge's height."""
    lo, hi = profile.min(), profile.max()
    above10 = np.argmax(profile > lo + 0.1 * (hi - lo))
    above90 = np.argmax(profile > lo + 0.9 * (hi - lo))
    return float(above90 - above10)


def test_depth_of_field_blurs_by_the_circle_of_confusion():
    """Two emitting half-planes seen through a lens focused on the near one: the near edge stays
    sharp, the far edge spreads over about the circle of confusion 2 a |z - f| / z (on the focus
    plane), converted to pixels."""
    size, fov, aperture, focus, far = 64, 20.0, 0.15, 4.0, 12.0

    def half_plane(z, x0):
        # A rectangle facing the camera (+z) covering x > x0.
        return {
            "shape": {"type": "rectangle", "size": [20.0, 20.0]},
            "material": "lamp",
            "transform": {"translate": [x0 + 10.0, 0.0, -z]},
        }

    data = {
        "camera": {
            "position": [0, 0, 0],
            "look_at": [0, 0, -1],
            "vfov_deg": fov,
            "width": size,
            "height": size,
            "aperture_radius": aperture,
            "focus_distance": focus,
        },
        "render": {"spp": 64, "max_depth": 1},
        "materials": {"lamp": {"reflectance": [0, 0, 0], "emission": [1, 1, 1]}},
        "objects": [],
    }
    film_width = 2.0 * math.tan(math.radians(fov) / 2.0)  # per unit depth
    near = compile_dict({**data, "objects": [half_plane(focus, 0.0)]})
    far_scene = compile_dict({**data, "objects": [half_plane(far, 0.0)]})
    sharp = render_passes(near, 1, 64)[0][size // 2, :, 0]
    blurred = render_passes(far_scene, 1, 64)[0][size // 2, :, 0]
    coc = 2.0 * aperture * abs(far - focus) / far  # on the focus plane
    coc_pixels = coc / (focus * film_width) * size
    assert edge_width(sharp) <= 1.0
    # A disc blur's 10-90% width of a straight edge is about 0.7 of its diameter.
    assert 0.5 * coc_pixels < edge_width(blurred) < 1.0 * coc_pixels + 1.0
    pinhole = compile_dict(
        {
            **data,
            "camera": {**data["camera"], "aperture_radius": 0.0},
            "objects": [half_plane(far, 0.0)],
        }
    )
    assert edge_width(render_passes(pinhole, 1, 64)[0][size // 2, :, 0]) <= 1.0
