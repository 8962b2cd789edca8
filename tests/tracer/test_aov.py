"""AOVs from the path tracer's own paths (tracer.integrators.aov): the beauty is unchanged by
them, they are split-independent, and they are what they say (against the first-hit debug
integrators, the scene's materials and geometry, and a mirror in front of a coloured wall)."""

import itertools

import numpy as np
import pytest
from numba import njit

from tests.helpers import SCENES, compile_dict, tiny_scene
from tracer.compiled.scene import compile_scene
from tracer.geometry.query import scene_hits
from tracer.integrators import aov
from tracer.integrators.pixels import pixel_run
from tracer.maths.rng import pixel_key, sample_key
from tracer.render import render_pixels
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene
from tracer.shading.camera import camera_sample_ray

SAMPLE_SCENES = sorted(p.parent.name for p in SCENES.glob("*/scene.json"))


def small(state, width=24, height=18):
    return compile_scene(state), fmt.override(state.camera, width=width, height=height)


@pytest.fixture(scope="module")
def scenes():
    """Each sample scene compiled, with a small camera."""
    return {name: small(load_scene(SCENES / name / "scene.json")) for name in SAMPLE_SCENES}


def render(scene, camera, p0=0, p1=None, threads=None, sample_start=0, **changes):
    settings = fmt.override(scene.render, **{"spp": 4, **changes})
    p1 = camera.width * camera.height if p1 is None else p1
    return render_pixels(
        scene, p0, p1, camera, settings, threads=threads, sample_start=sample_start
    )


@pytest.mark.parametrize("name", SAMPLE_SCENES)
def test_beauty_is_the_same_with_aovs_and_aovs_do_not_depend_on_the_split(scenes, name):
    """On every sample scene: the beauty, work and rays are bit for bit those of a render
    without AOVs; the AOVs of a run split mid-line on one thread are the whole frame's."""
    scene, camera = scenes[name]
    plain = render(scene, camera)
    full = render(scene, camera, aovs=True)
    assert plain.aov is None and full.aov.shape == (camera.width * camera.height, aov.CHANNELS)
    assert np.array_equal(plain.rgb, full.rgb)
    assert np.array_equal(plain.cost, full.cost) and np.array_equal(plain.rays, full.rays)
    cut = camera.width * 7 + 5
    parts = [
        render(scene, camera, 0, cut, 1, aovs=True),
        render(scene, camera, cut, threads=1, aovs=True),
    ]
    assert np.array_equal(np.concatenate([p.aov for p in parts]), full.aov)
    assert np.isfinite(full.aov).all()
    alpha = full.aov[:, aov.ALPHA]
    assert ((alpha >= 0) & (alpha <= 1)).all()


@pytest.mark.parametrize("name", SAMPLE_SCENES)
def test_depth_and_first_hit_albedo_match_the_debug_integrators(scenes, name):
    """The depth AOV is the depth integrator's image (the same camera samples, the same sums);
    where no delta material is in view the albedo AOV is the albedo integrator's, and the
    normal AOV the normal integrator's (which maps n to 0.5 n + 0.5)."""
    scene, camera = scenes[name]
    out = render(scene, camera, aovs=True).aov
    depth = render(scene, camera, integrator="depth").rgb
    assert np.array_equal(out[:, aov.DEPTH], depth[:, 0])
    albedo = render(scene, camera, integrator="albedo").rgb
    normal = render(scene, camera, integrator="normal").rgb
    kinds = {m.type for m in load_scene(SCENES / name / "scene.json").materials.values()}
    if kinds <= {"diffuse", "plastic"}:
        assert np.allclose(out[:, aov.ALBEDO : aov.ALBEDO + 3], albedo, atol=1e-6)
        # The debug output maps the mean normal; a missing sample counts 0 there, 0.5 here.
        hits = out[:, aov.ALPHA][:, None]
        mapped = 0.5 * out[:, aov.NORMAL : aov.NORMAL + 3] + 0.5 * hits
        assert np.allclose(mapped, normal, atol=1e-6)


def test_position_alpha_and_normal_of_the_first_hit():
    """With one sample per pixel: the world position lies at the depth along the camera ray
    (its distance from the camera is the depth), alpha is 1 where the ray hits and 0 where it
    misses, the normal is a unit vector facing the camera, and misses leave every AOV 0 but
    the ids, which are -1."""
    data = tiny_scene()
    data["camera"].update(width=32, height=24)
    data["camera"]["position"] = [0.0, 1.5, 4.0]
    scene = compile_dict(data)
    camera = scene.camera
    out = render(scene, camera, spp=1, aovs=True).aov
    alpha = out[:, aov.ALPHA]
    assert set(np.unique(alpha)) <= {0.0, 1.0} and 0 < alpha.sum() < alpha.size
    hit = alpha == 1.0
    position = out[hit, aov.POSITION : aov.POSITION + 3].astype(np.float64)
    distance = np.linalg.norm(position - np.asarray(camera.position), axis=1)
    assert np.allclose(distance, out[hit, aov.DEPTH], rtol=1e-5)
    normal = out[hit, aov.NORMAL : aov.NORMAL + 3].astype(np.float64)
    assert np.allclose(np.linalg.norm(normal, axis=1), 1.0, atol=1e-5)
    towards = np.asarray(camera.position) - position
    assert (np.einsum("ij,ij->i", normal, towards) > 0).all()
    assert not out[~hit, : aov.OBJECT_ID].any() and (out[~hit, aov.IDS] == -1).all()


def mirror_scene(reflectance):
    """A mirror filling the view, facing the camera at 45 degrees, and a red diffuse wall it
    shows (the wall itself out of view)."""
    data = tiny_scene()
    data["camera"].update(position=[0.0, 0.0, 0.0], look_at=[0.0, 0.0, -1.0], vfov_deg=20.0)
    data["camera"].update(width=16, height=12)
    data["materials"] = {
        "mirror": {"type": "mirror", "reflectance": reflectance},
        "red": {"reflectance": [0.8, 0.1, 0.1]},
        "lamp": {"reflectance": [0, 0, 0], "emission": [4, 4, 4]},
    }
    data["objects"] = [
        {
            "name": "mirror",
            "shape": {"type": "rectangle", "size": [20, 20]},
            "material": "mirror",
            "transform": {"translate": [0, 0, -5], "rotate": [0, 45, 0]},
        },
        {
            "name": "wall",
            "shape": {"type": "rectangle", "size": [50, 50]},
            "material": "red",
            "transform": {"translate": [10, 0, -5], "rotate": [0, -90, 0]},
        },
        {
            "name": "lamp",
            "shape": {"type": "rectangle", "size": [1, 1]},
            "material": "lamp",
            "transform": {"translate": [0, 8, -5], "rotate": [90, 0, 0]},
        },
    ]
    return compile_dict(data)


def test_albedo_and_normal_follow_a_mirror_to_the_surface_it_shows():
    """Through a tinted mirror the albedo is the tint times the wall's colour and the normal
    the wall's (facing the mirror); depth and position stay the mirror's."""
    tint = [0.5, 1.0, 0.25]
    scene = mirror_scene(tint)
    camera = scene.camera
    out = render(scene, camera, spp=2, aovs=True).aov
    assert (out[:, aov.ALPHA] == 1.0).all()
    expected = np.array(tint) * np.array([0.8, 0.1, 0.1])
    assert np.allclose(out[:, aov.ALBEDO : aov.ALBEDO + 3], expected, atol=1e-6)
    assert np.allclose(out[:, aov.NORMAL : aov.NORMAL + 3], [-1.0, 0.0, 0.0], atol=1e-5)
    position = out[:, aov.POSITION : aov.POSITION + 3]
    # On the mirror's plane x + z = -5 (rotated 45 degrees about y through (0, 0, -5)).
    assert np.allclose(position[:, 0] + position[:, 2], -5.0, atol=1e-4)


def test_the_back_of_a_one_sided_card_is_black_but_has_its_aovs():
    """A one-sided card seen from behind sends no light, yet its AOVs are its own: its albedo,
    alpha 1 and the normal facing the camera (the vertex shader records before it gives up)."""
    colour = [0.2, 0.5, 0.8]
    data = tiny_scene()
    data["camera"].update(position=[0.0, 0.0, 0.0], look_at=[0.0, 0.0, -1.0], vfov_deg=20.0)
    data["camera"].update(width=8, height=6)
    data["materials"]["card"] = {"reflectance": colour, "two_sided": False}
    data["objects"] = [
        {
            "name": "card",
            "shape": {"type": "rectangle", "size": [20, 20]},
            "material": "card",
            "transform": {"translate": [0, 0, -5], "rotate": [0, 180, 0]},
        },
        {
            "name": "lamp",
            "shape": {"type": "rectangle", "size": [1, 1]},
            "material": "lamp",
            "transform": {"translate": [0, 5, -8], "rotate": [0, 180, 0]},
        },
    ]
    scene = compile_dict(data)
    rendered = render(scene, scene.camera, spp=2, aovs=True)
    assert (rendered.aov[:, aov.ALPHA] == 1.0).all()
    assert not rendered.rgb.any()
    assert np.allclose(rendered.aov[:, aov.ALBEDO : aov.ALBEDO + 3], colour, atol=1e-6)
    assert np.allclose(rendered.aov[:, aov.NORMAL : aov.NORMAL + 3], [0.0, 0.0, 1.0], atol=1e-5)


def test_a_path_that_ends_at_its_first_vertex_still_records_it():
    """With ``max_depth`` 1 the first vertex scatters nothing, and its albedo and normal are
    bit for bit those of a longer path's first vertex (every surface here is diffuse)."""
    scene = compile_dict(tiny_scene())
    camera = scene.camera
    short = render(scene, camera, max_depth=1, aovs=True).aov
    long = render(scene, camera, max_depth=4, aovs=True).aov
    assert short[:, aov.ALPHA].any()
    assert np.array_equal(short[:, : aov.DEPTH], long[:, : aov.DEPTH])


def test_aovs_refused_where_no_paths_give_them():
    """AOVs with a first-hit integrator, or with the stream kernel, are refused with a reason."""
    with pytest.raises(ValueError, match="ao integrator gives no AOVs"):
        fmt.RenderSettings(integrator="ao", aovs=True)
    with pytest.raises(ValueError, match="stream kernel does not record AOVs"):
        fmt.RenderSettings(kernel="stream", denoise="fast")
    assert not fmt.RenderSettings(integrator="ao", denoise="fast").renders_aovs
    assert fmt.RenderSettings(denoise="fast").renders_aovs


@njit
def camera_rays(camera, width, height, seed, sample_start):
    """Render-space (origin, direction) of every pixel's camera ray of sample ``sample_start``
    of frame 0, as the kernels make them; float64 (W * H, 2, 3), row-major."""
    rays = np.empty((width * height, 2, 3))
    for i in range(width * height):
        y = i // width
        key = sample_key(pixel_key(seed, 0, i), sample_start)
        o, d = camera_sample_ray(camera, width, height, i - y * width, y, key)
        for c in range(3):
            rays[i, 0, c] = o[c]
            rays[i, 1, c] = d[c]
    return rays


def first_sample_rays(scene, camera, settings, sample_start=0):
    """World-space origins and directions of every pixel's camera ray of sample
    ``sample_start``."""
    run = pixel_run(scene, camera, settings, 0, 1, 0, sample_start, 0)
    rays = camera_rays(run.camera, camera.width, camera.height, settings.seed, sample_start)
    origins = rays[:, 0] + scene.origin
    assert np.array_equal(origins - scene.origin, rays[:, 0])  # scene_hits sees these rays
    return origins, rays[:, 1]


def id_scene():
    """Objects of every kind of storage: static ones baked into two clusters (a backdrop far
    from the floor's), two rigid instances of one mesh, each object its own material except
    two sharing one, and sky around them."""
    data = tiny_scene()
    data["camera"].update(width=40, height=30)
    data["materials"] = {
        "floor": {"reflectance": [0.7, 0.7, 0.7]},
        "red": {"reflectance": [0.8, 0.1, 0.1]},
        "green": {"type": "plastic", "reflectance": [0.1, 0.8, 0.1]},
        "lamp": {"reflectance": [0, 0, 0], "emission": [8, 8, 8], "two_sided": False},
        "unused": {"reflectance": [0.5, 0.5, 0.5]},
        "far": {"reflectance": [0.2, 0.2, 0.9]},
    }
    box = {"type": "box", "size": [0.6, 0.6, 0.6]}
    data["objects"] = [
        {"name": "floor", "shape": {"type": "rectangle", "size": [3, 3]}, "material": "floor",
         "transform": {"rotate": [-90, 0, 0]}},
        {"name": "left", "shape": box, "material": "red", "kind": "rigid",
         "transform": {"translate": [-0.8, 0.3, 0]}},
        {"name": "right", "shape": box, "material": "green", "kind": "rigid",
         "transform": {"translate": [0.8, 0.3, 0], "rotate": [0, 30, 0]}},
        {"name": "post", "shape": {"type": "box", "size": [0.1, 0.3, 0.1]}, "material": "red",
         "transform": {"translate": [0, 0.6, 2.5]}},
        {"name": "lamp", "shape": {"type": "rectangle", "size": [1, 1]}, "material": "lamp",
         "transform": {"translate": [0, 3, 0], "rotate": [90, 0, 0]}},
        {"name": "backdrop", "shape": {"type": "rectangle", "size": [3000, 3000]},
         "material": "far", "transform": {"translate": [0, 0, -5000]}},
    ]  # fmt: skip
    return compile_dict(data)


def hit_ids(scene, camera, settings, sample_start=0):
    """Object and material ids of a direct closest-hit query of each pixel's first-sample
    camera ray (``tracer.geometry.query``)."""
    hits = scene_hits(scene, *first_sample_rays(scene, camera, settings, sample_start))
    names = scene.material_names
    material = [-1 if m is None else names.index(m) for m in hits.material]
    return hits.node, np.array(material)


@pytest.mark.parametrize("name", [*SAMPLE_SCENES, "ids"])
def test_ids_are_what_the_first_sample_camera_ray_hits(scenes, name):
    """On every sample scene and on one of static clusters and instances: the object and
    material ids are those of a direct query of the camera ray of each pixel's first sample
    (-1 where it misses, exactly where alpha is 0 at one sample), also for a render whose first
    sample is not sample 0."""
    scene, camera = (id_scene(), None) if name == "ids" else scenes[name]
    camera = camera or scene.camera
    if name == "ids":
        assert scene.static_clusters == 2 and scene.stats.instances == 4
    for sample_start, spp in ((0, 1), (0, 3), (5, 2)):
        out = render(scene, camera, spp=spp, sample_start=sample_start, aovs=True).aov
        settings = fmt.override(scene.render, spp=spp)
        node, material = hit_ids(scene, camera, settings, sample_start)
        assert np.array_equal(out[:, aov.OBJECT_ID], node)
        assert np.array_equal(out[:, aov.MATERIAL_ID], material)
        if spp == 1:
            assert np.array_equal(out[:, aov.ALPHA] == 0, node == -1)
    nodes = scene.state.nodes
    for n, m in zip(node[node >= 0], material[node >= 0], strict=True):  # each its material
        assert scene.material_names[m] == nodes[n].material
    if name == "ids":
        assert set(node) == {-1, 0, 1, 2, 3, 5}  # sky, both clusters, both instances


def test_ids_do_not_depend_on_the_split():
    """Ids of runs cut mid-line, on one thread or two, are the whole frame's."""
    scene = id_scene()
    camera = scene.camera
    whole = render(scene, camera, spp=2, aovs=True).aov
    cuts = [0, 37, camera.width * 11 + 3, camera.width * 20, camera.width * camera.height]
    parts = [render(scene, camera, a, b, 1 + k % 2, spp=2, aovs=True).aov
             for k, (a, b) in enumerate(itertools.pairwise(cuts))]  # fmt: skip
    assert np.array_equal(np.concatenate(parts)[:, aov.IDS], whole[:, aov.IDS])
