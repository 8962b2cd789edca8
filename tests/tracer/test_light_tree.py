"""The light tree (``tracer.shading.light_tree``): its probabilities are a distribution over the
emissive triangles, the sampler reports the probability the PMF function gives, every triangle
that can light a point can be picked, images agree with the power sampler's, and the plan
chooses it by its rule."""

from itertools import pairwise

import numpy as np
import pytest

from tests.helpers import SCENES, compile_dict, tiny_scene, write_mesh
from tests.stats import pass_statistics, welch_pixel_test
from tracer.compiled.light_tree import EMPTY, build_light_tree, light_tree_of
from tracer.compiled.scene import compile_scene
from tracer.integrators import flags
from tracer.integrators.effects import TREE_MIN_TRIANGLES, effect_plan
from tracer.render import render_image, render_pixels
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene
from tracer.shading import light_tree as lt

HALL = SCENES / "lamp-hall" / "scene.json"


@pytest.fixture(scope="module")
def hall():
    return compile_scene(load_scene(HALL))


@pytest.fixture(scope="module")
def many():
    return compile_scene(load_scene(SCENES / "many-lights" / "scene.json"))


def _points(scene, count: int, seed: int):
    """Fixed points inside the scene's box with unit normals (a seeded generator)."""
    rng = np.random.default_rng(seed)
    lo = np.array(scene.stats.bounds_min) - scene.origin
    hi = np.array(scene.stats.bounds_max) - scene.origin
    points = lo + (hi - lo) * rng.uniform(0.02, 0.98, (count, 3))
    normals = rng.normal(size=(count, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return [(tuple(p), tuple(n)) for p, n in zip(points, normals, strict=True)]


def _pmfs(tree, p, n) -> np.ndarray:
    args = (tree.light_tree_nodes, tree.light_tree_child, tree.light_tree_bits)
    return np.array([lt.tree_pmf(*args, i, p, n) for i in range(tree.light_tree_area.shape[0])])


def _dead_end_mass(tree, p, n) -> float:
    """The probability that the walk from the root meets a node whose slots all have zero
    importance (the sampler then picks nothing)."""
    nodes, child = tree.light_tree_nodes, tree.light_tree_child
    lost = 0.0
    stack = [(0, 1.0)]
    while stack:
        i, reach = stack.pop()
        c = lt.importances(nodes, i, p, n)
        total = sum(c)
        if not total > 0.0:
            lost += reach
            continue
        stack += [(int(child[i, k]), reach * c[k] / total) for k in range(lt.WIDTH)
                  if c[k] > 0.0 and child[i, k] >= 0]  # fmt: skip
    return lost


def _numpy_importances(nodes, p, n) -> np.ndarray:
    """``lt.importances`` of every node and slot, transcribed to numpy (the same IEEE
    operations in the same order): (N, WIDTH)."""
    w = lt.WIDTH

    def field(f):
        return nodes[:, f * w : (f + 1) * w]

    def positive_part(x):
        return np.where(x > 0.0, x, 0.0)

    with np.errstate(divide="ignore", invalid="ignore"):
        dx, dy, dz = (p[a] - field(lt.CENTRE + a) for a in range(3))
        d2 = (dx * dx + dy * dy) + dz * dz
        r2, phi = field(lt.RADIUS2), field(lt.PHI)
        inv = 1.0 / np.sqrt(d2)
        wx, wy, wz = dx * inv, dy * inv, dz * inv
        sin2_b = r2 / d2
        cos_b, sin_b = np.sqrt(1.0 - sin2_b), np.sqrt(sin2_b)
        cos_w = (field(lt.AXIS) * wx + field(lt.AXIS + 1) * wy) + field(lt.AXIS + 2) * wz
        cos_w = np.where(field(lt.TWO_SIDED) != 0.0, np.abs(cos_w), cos_w)
        cos_o, sin_o = field(lt.COS_O), field(lt.SIN_O)
        sin_w = np.sqrt(positive_part(1.0 - cos_w * cos_w))
        cos_x = cos_w * cos_o + sin_w * sin_o
        sin_x = sin_w * cos_o - cos_w * sin_o
        cos_e = np.where((cos_w > cos_o) | (cos_x > cos_b), 1.0, cos_x * cos_b + sin_x * sin_b)
        cos_a = -((n[0] * wx + n[1] * wy) + n[2] * wz)
        sin_a = np.sqrt(positive_part(1.0 - cos_a * cos_a))
        cos_r = np.where(cos_a > cos_b, 1.0, cos_a * cos_b + sin_a * sin_b)
        outside = np.where((cos_e > 0.0) & (cos_r > 0.0), phi * cos_e * cos_r / d2, 0.0)
        inside = phi / np.where(r2 > lt.TINY, r2, lt.TINY)
        return np.where(d2 <= r2, inside, outside)


@pytest.mark.parametrize("name", ["hall", "many"])
def test_vector_importances_are_their_numpy_transcription(name, request):
    """The four slots' importances, one LLVM vector computation, are the bits of the same
    operations in numpy, for every node of the tree from fixed points, inside spheres too."""
    scene = request.getfixturevalue(name)
    nodes = light_tree_of(scene).light_tree_nodes
    points = _points(scene, 10, seed=8)
    points += [(tuple(nodes[i, lt.CENTRE * lt.WIDTH :: lt.WIDTH][:3]), points[0][1])
               for i in range(0, nodes.shape[0], 97)]  # fmt: skip
    for p, n in points:
        expected = _numpy_importances(nodes, p, n)
        got = np.array([lt.importances(nodes, i, p, n) for i in range(nodes.shape[0])])
        assert got.tobytes() == expected.tobytes()
    assert (expected >= 0.0).all()


def test_the_wide_tree_holds_every_triangle_once(hall):
    """Every triangle is one slot's, every node but the root is one slot's, inner nodes have
    two to four slots, and empty slots weigh nothing."""
    tree = light_tree_of(hall)
    child, nodes = tree.light_tree_child, tree.light_tree_nodes
    leaves = -1 - child[(child < 0) & (child != EMPTY)]
    assert np.array_equal(np.sort(leaves), np.arange(hall.stats.emissive_triangles))
    assert np.array_equal(np.sort(child[child >= 0]), np.arange(1, child.shape[0]))
    assert ((child != EMPTY).sum(axis=1) >= 2).all()
    phi = nodes[:, lt.PHI * lt.WIDTH : (lt.PHI + 1) * lt.WIDTH]
    assert (phi[child == EMPTY] == 0.0).all() and (phi[child != EMPTY] > 0.0).all()


@pytest.mark.parametrize("name", ["hall", "many"])
def test_pmf_is_a_distribution_from_fixed_points(name, request):
    """From fixed points and normals the PMFs over all triangles sum to 1 less the mass of the
    walk's dead ends (exactly 1 where there are none), and never exceed 1."""
    scene = request.getfixturevalue(name)
    tree = light_tree_of(scene)
    assert tree.light_tree_area.shape[0] == scene.stats.emissive_triangles
    for p, n in _points(scene, 12, seed=5):
        pmf = _pmfs(tree, p, n)
        assert (pmf >= 0.0).all() and pmf.max() <= 1.0
        assert pmf.sum() + _dead_end_mass(tree, p, n) == pytest.approx(1.0, abs=1e-12)


def test_the_sampler_reports_the_pmf_of_what_it_picks(hall):
    """For many random numbers the sampled triangle's reported probability is the PMF
    function's, bit for bit, and each triangle is picked for a share of [0, 1) equal to its
    PMF (the walk maps [0, 1) onto intervals)."""
    tree = light_tree_of(hall)
    count = tree.light_tree_area.shape[0]
    u = (np.arange(20000) + 0.5) / 20000
    for p, n in _points(hall, 3, seed=11):
        pmf = _pmfs(tree, p, n)
        picks = np.zeros(count)
        for x in u:
            e, q = lt.tree_sample(tree.light_tree_nodes, tree.light_tree_child, p, n, x)
            if e >= 0:
                assert q == pmf[e]
                picks[e] += 1
        assert np.abs(picks / u.size - pmf).max() <= 2.0 / u.size


def test_every_triangle_that_can_light_a_point_can_be_picked(hall):
    """A triangle whose front faces the point and that rises above the point's surface has a
    positive probability (the bounds are conservative: else the estimator would be biased)."""
    tree = light_tree_of(hall)
    a = hall.arrays
    count = tree.light_tree_area.shape[0]
    verts = np.empty((count, 3, 3))
    for i in range(count):
        k, j = a.light_inst[i], a.light_tri[i]
        v = a.tri_verts[a.inst_pool[k]][j].astype(np.float64).reshape(3, 3)
        xform = a.inst_xform[k].reshape(3, 4)
        verts[i] = v @ xform[:, :3].T + xform[:, 3]
    normal = np.cross(verts[:, 1] - verts[:, 0], verts[:, 2] - verts[:, 0])
    for p, n in _points(hall, 8, seed=3):
        pmf = _pmfs(tree, p, n)
        front = np.einsum("ij,ij->i", normal, np.asarray(p) - verts[:, 0]) > 1e-9
        above = (np.einsum("ijk,k->ij", verts - np.asarray(p), np.asarray(n)) > 1e-9).any(axis=1)
        assert (pmf[front & above] > 0.0).all()
        assert (pmf[front & above]).size > 0


def test_the_build_is_deterministic(hall):
    """The same arrays, built twice; bit trails fit their depth (64 bits)."""
    again = build_light_tree(hall.arrays)
    for a, b in zip(light_tree_of(hall), again, strict=True):
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes()
    assert np.array_equal(np.sort(light_tree_of(hall).light_tree_key_light), np.arange(3904))


def test_the_plan_chooses_the_tree_by_its_rule(hall, cornell):
    """``auto``: the tree from ``TREE_MIN_TRIANGLES`` emissive triangles on; ``power`` and
    ``tree`` force it; no tree without light samples on emissive triangles; the report says
    which and why."""
    plan = effect_plan(hall, hall.render)
    assert plan.flags & flags.LIGHT_TREE and plan.to_json()["light_sampler"] == "tree"
    assert str(TREE_MIN_TRIANGLES) in plan.reasons["light_tree"]
    assert not effect_plan(cornell, cornell.render).flags & flags.LIGHT_TREE
    power = fmt.override(hall.render, light_sampler="power")
    assert not effect_plan(hall, power).flags & flags.LIGHT_TREE
    assert effect_plan(hall, power).reasons["light_tree"] == "set in render.light_sampler"
    tree = fmt.override(cornell.render, light_sampler="tree")
    assert effect_plan(cornell, tree).flags & flags.LIGHT_TREE
    dark = fmt.override(tree, effects={"area_lights": False})
    assert not effect_plan(cornell, dark).flags & flags.LIGHT_TREE
    ao = fmt.override(hall.render, integrator="ao")
    assert not effect_plan(hall, ao).flags & flags.LIGHT_TREE
    with pytest.raises(ValueError, match="light_sampler"):
        fmt.RenderSettings(light_sampler="bvh")


PASSES = 8
SIZE = (32, 20)


def _passes(scene, sampler: str, seed: int, spp: int, max_depth: int) -> np.ndarray:
    camera = fmt.override(scene.camera, width=SIZE[0], height=SIZE[1])
    settings = fmt.override(
        scene.render, spp=spp, seed=seed, light_sampler=sampler, max_depth=max_depth
    )
    return np.stack(
        [render_image(scene, camera, settings, sample_start=k * spp)[0] for k in range(PASSES)]
    ).astype(np.float64)


@pytest.mark.parametrize("max_depth", [2, 8])
def test_images_agree_with_the_power_sampler(hall, max_depth):
    """The tree and the power sampler at independent seeds: the image means agree by a Z-test
    (|z| < 4 per channel) and the pixels by the Sidak-corrected Welch test. At two vertices
    (direct light) every emitter a BSDF sample hits is weighted against the tree's probability
    as seen from the previous vertex: a wrong weight would show as a bias here."""
    tree = _passes(hall, "tree", 1, 16, max_depth)
    power = _passes(hall, "power", 2, 64, max_depth)  # noisier: more samples
    mean_a = tree.reshape(PASSES, -1, 3).mean(axis=1)
    mean_b = power.reshape(PASSES, -1, 3).mean(axis=1)
    se = np.sqrt(mean_a.var(axis=0, ddof=1) / PASSES + mean_b.var(axis=0, ddof=1) / PASSES)
    z = (mean_a.mean(axis=0) - mean_b.mean(axis=0)) / se
    assert np.all(np.abs(z) < 4.0), z
    result = welch_pixel_test(*pass_statistics(tree), *pass_statistics(power))
    assert result.accepted_fraction >= 0.99


def test_the_tree_is_less_noisy_than_power_at_the_same_samples(hall):
    """What it is for: on 3,904 lamp triangles, the pixel variance of the mean falls (median over
    pixels) by more than 4x at equal samples."""
    _, var_tree, _ = pass_statistics(_passes(hall, "tree", 3, 8, 8))
    _, var_power, _ = pass_statistics(_passes(hall, "power", 4, 8, 8))
    assert np.median(var_power.sum(axis=2)) > 4.0 * np.median(var_tree.sum(axis=2))


def test_tree_renders_are_the_same_bits_however_split(hall):
    """Pixel runs that start and end mid-line, on one and two threads, by the single-ray and
    the stream kernels: the whole frame's bits."""
    camera = fmt.override(hall.camera, width=23, height=11)
    settings = fmt.override(hall.render, spp=3, light_sampler="tree")
    n = camera.width * camera.height
    whole = render_pixels(hall, 0, n, camera, settings, threads=1)
    cuts = [0, 5, 6, 100, 177, n]
    for kernel in ("single", "stream"):
        split = fmt.override(settings, kernel=kernel)
        parts = [render_pixels(hall, a, b, camera, split, threads=2) for a, b in pairwise(cuts)]
        assert np.concatenate([p.rgb for p in parts]).tobytes() == whole.rgb.tobytes()
        assert np.array_equal(np.concatenate([p.rays for p in parts]), whole.rays)


@pytest.mark.parametrize("count", [1, 2, 3, 4, 5, 9])
def test_small_trees_are_distributions_the_sampler_follows(count, tmp_path):
    """Trees of one to nine triangles (a lone triangle is the root's only slot; others leave
    slots empty): every triangle is one slot's, the PMFs sum to one less the dead ends, and
    the sampler reports the PMF of what it picks."""
    rng = np.random.default_rng(count)
    corners = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.0, 0.0, 0.3]])
    vertices = np.concatenate([corners + (rng.uniform(-2, 2), 3.0, rng.uniform(-2, 2))
                               for _ in range(count)])  # fmt: skip
    faces = np.arange(3 * count).reshape(count, 3)[:, ::-1]  # facing down
    write_mesh(tmp_path / "lamps.obj", vertices, faces)
    data = tiny_scene()
    data["objects"][2]["shape"] = "lamps.obj"
    del data["objects"][2]["transform"]
    scene = compile_dict(data, tmp_path)
    tree = light_tree_of(scene)
    child = tree.light_tree_child
    assert np.array_equal(np.sort(-1 - child[(child < 0) & (child != EMPTY)]), np.arange(count))
    u = (np.arange(2000) + 0.5) / 2000
    for p, n in _points(scene, 4, seed=count) + [((0.0, 0.0, 0.0), (0.0, 1.0, 0.0))]:
        pmf = _pmfs(tree, p, n)
        assert pmf.sum() + _dead_end_mass(tree, p, n) == pytest.approx(1.0, abs=1e-12)
        for x in u[::7]:
            e, q = lt.tree_sample(tree.light_tree_nodes, child, p, n, x)
            assert (e < 0 and q == 0.0) or q == pmf[e]
