"""The stream kernel traces the single-ray kernel's paths a stage at a time: on every sample
scene its pixels, work and ray counts are the single-ray kernel's bit for bit, however the
frame is split and however many threads render it."""

import json
import subprocess
import sys
from itertools import pairwise

import numpy as np
import pytest

from cli.commands.samples import REPO_SCENES, sample_scene_files
from tracer.compiled.scene import compile_scene
from tracer.integrators import flags, stream
from tracer.integrators.effects import effect_plan
from tracer.integrators.kernel_choice import choose_kernel, plan_report
from tracer.render import render_image, render_pixels
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene

SCENES = sample_scene_files(REPO_SCENES)


@pytest.fixture(scope="module")
def spheres():
    """The Cornell box with a mirror and a glass sphere."""
    return compile_scene(load_scene(REPO_SCENES / "cornell-spheres" / "scene.json"))


def _kernel(render: fmt.RenderSettings, name: str) -> fmt.RenderSettings:
    return fmt.override(render, kernel=name)


def _both(scene, camera, render, threads=1):
    """The frame by the single-ray kernel and by the stream kernel: (rgb, cost, rays) each."""
    out = []
    for name in ("single", "stream"):
        run = render_pixels(
            scene, 0, camera.width * camera.height, camera, _kernel(render, name), threads=threads
        )
        out.append(run)
    return out


def _assert_same(a, b):
    assert a.rgb.tobytes() == b.rgb.tobytes()
    assert np.array_equal(a.cost, b.cost) and np.array_equal(a.rays, b.rays)


@pytest.mark.parametrize("path", SCENES, ids=[p.parent.name for p in SCENES])
def test_stream_matches_single_ray_on_every_sample_scene(path):
    """Every sample scene, small and at few samples: the same bits, work and rays, and a
    frame that is not black (so equality means something)."""
    scene = compile_scene(load_scene(path))
    camera = fmt.override(scene.camera, width=24, height=18)
    render = fmt.override(scene.render, spp=2)
    single, streamed = _both(scene, camera, render)
    assert single.rgb.max() > 0.0 and (single.rays >= 2).all()
    _assert_same(single, streamed)


def test_stream_refills_and_batches_match_single_ray(cornell):
    """More samples than the stream holds and more pixels than a batch: paths finish and are
    replaced mid-batch, and pixels wait for the batch's last path; on two threads too."""
    camera = fmt.override(cornell.camera, width=40, height=20)
    render = fmt.override(cornell.render, spp=64)
    samples = camera.width * camera.height * render.spp
    assert samples > 2 * stream.BATCH_SAMPLES and stream.BATCH_SAMPLES > stream.STREAM_SIZE
    for threads in (1, 2):
        single, streamed = _both(cornell, camera, render, threads)
        _assert_same(single, streamed)


def test_stream_split_anywhere_matches_whole_frame(cornell):
    """Pixel runs that start and end mid-line, rendered by the stream kernel, put together are
    the whole frame."""
    camera = fmt.override(cornell.camera, width=29, height=13)
    render = fmt.override(cornell.render, spp=3, kernel="stream")
    n = camera.width * camera.height
    whole = render_pixels(cornell, 0, n, camera, render, threads=1)
    cuts = [0, 7, 8, 100, 231, n]
    parts = [render_pixels(cornell, a, b, camera, render, threads=2) for a, b in pairwise(cuts)]
    assert np.concatenate([p.rgb for p in parts]).tobytes() == whole.rgb.tobytes()
    assert np.array_equal(np.concatenate([p.cost for p in parts]), whole.cost)


def test_whitted_and_direct_stream_match_single_ray(spheres):
    """The other modes of the path kernel: Whitted (paths through delta lobes only) and direct
    light, over mirrors and glass."""
    camera = fmt.override(spheres.camera, width=20, height=15)
    for integrator in ("whitted", "direct"):
        render = fmt.override(spheres.render, spp=4, integrator=integrator)
        _assert_same(*_both(spheres, camera, render))


def test_kernel_choice_follows_settings_and_rule(cornell, spheres):
    """``render.kernel`` names the kernel; ``auto`` takes the measured rule (the single-ray
    kernel, with or without material effects); the surface integrators have one kernel whatever
    is asked; the plan report says which and why."""
    for name in ("single", "stream"):
        render = fmt.override(cornell.render, kernel=name)
        assert choose_kernel(render).name == name
    lambertian = effect_plan(cornell, cornell.render).flags
    glossy = effect_plan(spheres, spheres.render).flags
    assert glossy & flags.MATERIAL_EFFECTS and not lambertian & flags.MATERIAL_EFFECTS
    assert cornell.render.kernel == spheres.render.kernel == "auto"
    assert choose_kernel(cornell.render) == choose_kernel(spheres.render)
    assert choose_kernel(spheres.render).name == "single"
    ao = fmt.override(cornell.render, integrator="ao", kernel="stream")
    assert choose_kernel(ao).name == "single"
    report = plan_report(effect_plan(spheres, spheres.render), spheres.render)
    assert report["kernel"] == "single" and "renderer_mrays" in report["kernel_reason"]
    forced = fmt.override(spheres.render, kernel="stream")
    assert plan_report(effect_plan(spheres, forced), forced)["kernel_reason"] == (
        "set in render.kernel"
    )


def test_unknown_kernel_is_refused():
    with pytest.raises(ValueError, match="kernel"):
        fmt.RenderSettings(kernel="gpu")


def test_render_image_uses_the_chosen_kernel(cornell):
    """A whole image through ``render_image`` is the same under either choice."""
    camera = fmt.override(cornell.camera, width=16, height=12)
    images = [
        render_image(cornell, camera, fmt.override(cornell.render, spp=2, kernel=k))[0]
        for k in ("single", "stream", "auto")
    ]
    assert images[0].tobytes() == images[1].tobytes() == images[2].tobytes()


WARM_CHILD = """
import json
from tracer.compiled.scene import compile_scene
from tracer.integrators.effects import effect_plan
from tracer.integrators.kernel_choice import chosen_kernel
from tracer.render import render_image
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene
scene = compile_scene(load_scene({path!r}))
camera = fmt.override(scene.camera, width=2, height=2)
out = {{}}
for kernel in ("single", "stream"):
    settings = fmt.override(scene.render, spp=1, kernel=kernel)
    render_image(scene, camera, settings)
    stats = chosen_kernel(settings, effect_plan(scene, settings).flags).stats
    out[kernel] = [sum(stats.cache_hits.values()), sum(stats.cache_misses.values())]
print(json.dumps(out))
"""


def test_both_kernels_load_from_the_disk_cache_in_a_new_process():
    """A second process finds both kernels in numba's on-disk cache: no recompiling at warm
    start (a kernel closing over a jitted helper would miss every time: the cache key pickles
    closure cells)."""
    code = WARM_CHILD.format(path=str(REPO_SCENES / "cornell-box" / "scene.json"))
    counts = []
    for _ in range(2):  # the first may compile what this process has not
        done = subprocess.run(
            [sys.executable, "-c", code],
            cwd=REPO_SCENES.parent,
            capture_output=True,
            text=True,
            timeout=600,
            check=False,
        )
        assert done.returncode == 0, done.stderr[-3000:]
        counts.append(json.loads(done.stdout.splitlines()[-1]))
    assert counts[1] == {"single": [1, 0], "stream": [1, 0]}
