"""Pixels do not depend on the CPU that renders them.

Each render here runs in a subprocess whose CPU-dependent code paths are switched to what
another machine would run: numba's code generation target (``NUMBA_CPU_NAME`` with the CPU's
own features, each target in a kernel cache of its own), OpenBLAS's kernels
(``OPENBLAS_CORETYPE``) and numpy's SIMD dispatch (``NPY_DISABLE_CPU_FEATURES``). The frame
must be bit-identical to the one this process renders with the host's own settings, and so
must everything behind it: every array the kernels read, float64 ray queries against the
compiled scene and the render's work per line. (float32 pixels alone hide most last-bit
differences of the float64 arithmetic behind them: scene compilation that differed in its
instance inverses, light and sky tables still gave identical pixels at 160x120, 16 spp.)
Every subprocess reports what it really ran with, and the test checks that each knob took
effect, so an ignored variable cannot pass for agreement.

Not covered, on purpose: glibc's libm picks other, not bit-identical variants of ``exp``,
``sin``, ``pow``, ... on CPUs without FMA and AVX2 (``GLIBC_TUNABLES=glibc.cpu.hwcaps=
-FMA,-AVX2``); the emulations below leave libm alone.

Two scenes: ``scenes/outdoor`` (every effect but textures) and a harsher one built here (every
effect, odd rotations, non-uniform and mirroring scales, a shearing matrix, static, rigid and
deformable nodes, a parent chain, an environment map, a camera looking along no axis). The
default suite compares one emulated other CPU; ``-m slow`` runs the wide matrix.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from tests.cpu_variants import (
    Variant,
    matrix,
    numpy_dispatch,
    openblas_corename,
    other_cpu,
)
from tests.harsh_scene import harsh_scene
from tests.helpers import ROOT, SCENES, write_json

OUTDOOR = SCENES / "outdoor" / "scene.json"
WIDTH, HEIGHT, SPP = 48, 32, 2
KNOBS = (
    "NUMBA_CPU_NAME",
    "NUMBA_CPU_FEATURES",
    "OPENBLAS_CORETYPE",
    "NPY_DISABLE_CPU_FEATURES",
    "NPY_ENABLE_CPU_FEATURES",
    "GLIBC_TUNABLES",
    "TILERENDER_NUMBA_CACHE",
)
"""Environment variables a variant sets; inherited values are dropped first."""
CHILD_TIMEOUT = 1200.0
"""Seconds a subprocess may take (a cold kernel compile is a minute on a busy 2-core box)."""

pytestmark = pytest.mark.skipif(
    sys.platform != "linux" or platform.machine() != "x86_64",
    reason="the CPU emulation knobs are x86-64 Linux ones",
)


def process_config() -> dict:
    """What this process's CPU-dependent code paths are: numba's target, OpenBLAS's kernels,
    numpy's dispatch, the tracer sources and the kernel cache."""
    from numba.core.registry import cpu_target

    from tracer.kernel import numba_cache

    _, cpu, features = cpu_target.target_context.codegen().magic_tuple()
    return {
        "numba_cpu": cpu,
        "numba_avx512": "+avx512f" in features,
        "numba_host_features": features != "",
        "openblas": openblas_corename(),
        "numpy_dispatch": numpy_dispatch(),
        "glibc_tunables": os.environ.get("GLIBC_TUNABLES", ""),
        "sources": numba_cache.source_digest(),
        "cache_dir": os.environ.get("NUMBA_CACHE_DIR", ""),
    }


# --- rendering ----------------------------------------------------------------------------------


def digest(value: np.ndarray) -> str:
    import hashlib

    return hashlib.sha256(np.ascontiguousarray(value).tobytes()).hexdigest()[:16]


HIT_FIELDS = ("node", "triangle", "t", "point", "normal")


def query_rays(camera) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(label, origins, directions): rays from the eye and from an odd point at a grid round
    the camera's target, made with exact arithmetic (the same bits on every CPU)."""
    u, v = np.meshgrid(np.arange(-32, 32) * 0.0731, np.arange(-24, 24) * 0.0617)
    grid = np.stack([u.ravel(), v.ravel(), (u * v).ravel() * 0.37], axis=1)
    rays = []
    for label, origin in (("eye", camera.position), ("odd", (-2.71, 3.13, 2.29))):
        origin = np.asarray(origin, np.float64)
        directions = np.asarray(camera.look_at, np.float64) + grid - origin
        rays.append((label, np.broadcast_to(origin, directions.shape).copy(), directions))
    return rays


def array_digests(scene, camera) -> dict[str, str]:
    """Hashes of every array the kernels read (the scene's arrays and the camera constants)
    and of float64 ray queries against the scene (distance, point, normal): a last-bit
    difference in compilation or in the intersection code shows here even where float32
    pixels round it away."""
    from tracer.geometry.query import scene_hits
    from tracer.integrators.pixels import pixel_run

    run = pixel_run(scene, camera, scene.render, 0, 1, frame=0, sample_start=0, flags=0)
    named = {"camera": run.camera}
    for name, value in scene.arrays._asdict().items():
        if isinstance(value, tuple):
            named.update({f"{name}[{k}]": part for k, part in enumerate(value)})
        else:
            named[name] = value
    for label, origins, directions in query_rays(camera):
        hits = scene_hits(scene, origins, directions)
        named.update({f"query-{label}.{key}": getattr(hits, key) for key in HIT_FIELDS})
    return {name: digest(value) for name, value in named.items() if isinstance(value, np.ndarray)}


def render_jobs(jobs: list[dict]) -> tuple[list[np.ndarray], list[dict], dict]:
    """Render each job (scene file, width, height, spp) with the public API; returns the
    float32 images, each scene's digests (its arrays, queries and the render's work per line)
    and the path kernel's cache hits and misses in this process."""
    from tracer.compiled.light_tree import light_tree_of
    from tracer.compiled.scene import compile_scene
    from tracer.integrators.path import kernel_for
    from tracer.render import effect_plan, render_image
    from tracer.scene.format import override
    from tracer.scene.loader import load_scene

    images, digests, flags = [], [], set()
    for job in jobs:
        scene = compile_scene(load_scene(job["scene"]))
        camera = override(scene.camera, width=job["width"], height=job["height"])
        sampler = job.get("light_sampler", "auto")
        settings = override(scene.render, spp=job["spp"], light_sampler=sampler)
        image, cost = render_image(scene, camera, settings)
        images.append(image)
        tree = {f"light_tree.{k}": digest(v) for k, v in light_tree_of(scene)._asdict().items()}
        digests.append({**array_digests(scene, camera), **tree, "render.cost": digest(cost)})
        flags.add(effect_plan(scene, settings).flags)
    stats = [k.stats for k in {id(k): k for k in map(kernel_for, flags)}.values()]
    kernel = {
        "hits": sum(sum(s.cache_hits.values()) for s in stats),
        "misses": sum(sum(s.cache_misses.values()) for s in stats),
    }
    return images, digests, kernel


def child_main() -> None:
    """Subprocess entry point: ``argv[1]`` is a request (jobs, outputs, report path)."""
    request = json.loads(Path(sys.argv[1]).read_text())
    start = time.perf_counter()
    images, digests, kernel = render_jobs(request["jobs"])
    for image, out in zip(images, request["outputs"], strict=True):
        np.save(out, image)
    report = {
        **process_config(),
        "arrays": digests,
        "kernel": kernel,
        "seconds": time.perf_counter() - start,
    }
    Path(request["report"]).write_text(json.dumps(report))


@dataclass
class Run:
    """A variant's images (one per job) and the configuration its process reported."""

    variant: Variant
    images: list[np.ndarray]
    config: dict
    cache: Path | None = None
    """The kernel cache base it was given (None: the parent's)."""


def render_in_subprocess(
    variant: Variant, jobs: list[dict], workdir: Path, cache: Path | None
) -> Run:
    """Render ``jobs`` in a fresh interpreter under ``variant``'s environment (kernels from
    ``cache``, or this process's cache if None); float32 pixels come back through .npy files."""
    workdir.mkdir(parents=True, exist_ok=True)
    outputs = [str(workdir / f"{variant.name}-{k}.npy") for k in range(len(jobs))]
    report = workdir / f"{variant.name}.json"
    request = workdir / f"{variant.name}-request.json"
    write_json(request, {"jobs": jobs, "outputs": outputs, "report": str(report)})
    env = {k: v for k, v in os.environ.items() if k not in KNOBS}
    env.update(variant.env)
    if cache is not None:
        env["TILERENDER_NUMBA_CACHE"] = str(cache)
    code = "from tests.tracer.test_cross_cpu import child_main; child_main()"
    done = subprocess.run(
        [sys.executable, "-c", code, str(request)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=CHILD_TIMEOUT,
        check=False,
    )
    assert done.returncode == 0, f"{variant.name}: {done.stderr[-3000:]}"
    config = json.loads(report.read_text())
    return Run(variant, [np.load(out) for out in outputs], config, cache)


def render_here(jobs: list[dict]) -> Run:
    """The reference: ``jobs`` rendered in this process, with the host's own settings."""
    images, digests, kernel = render_jobs(jobs)
    config = {**process_config(), "arrays": digests, "kernel": kernel}
    return Run(Variant("this-process"), images, config)


def cached_cpu_names(cache: Path) -> set[str]:
    """The CPU names numba compiled the kernels under ``cache`` for (from its index files)."""
    import pickle

    import numba  # noqa: F401 - the index keys hold numba types

    names = set()
    for index in cache.rglob("*.nbi"):
        with index.open("rb") as f:
            pickle.load(f)  # numba's version
            _, overloads = pickle.loads(f.read())
        names |= {key[1][1] for key in overloads}  # (signature, (triple, cpu, features), ...)
    return names


def check_config(run: Run, reference: Run) -> None:
    """The subprocess ran the same tracer sources with every knob of its variant in effect."""
    config, host, env = run.config, reference.config, run.variant.env
    assert config["sources"] == host["sources"], "tracer sources changed during the test"
    if run.variant.numba is not None:
        assert config["numba_cpu"] == run.variant.numba
        assert config["numba_host_features"] == run.variant.host_features
    if "OPENBLAS_CORETYPE" in env:
        assert config["openblas"], "cannot ask OpenBLAS which kernels it uses"
    if "NPY_DISABLE_CPU_FEATURES" in env:
        disabled = set(env["NPY_DISABLE_CPU_FEATURES"].split())
        assert config["numpy_dispatch"] == [t for t in host["numpy_dispatch"] if t not in disabled]
    if run.cache is not None:
        assert Path(config["cache_dir"]).parent == run.cache


def differing(a: np.ndarray, b: np.ndarray) -> int:
    """Pixels whose bits differ anywhere in their three channels."""
    return int(np.any(a.view(np.uint32) != b.view(np.uint32), axis=-1).sum())


def differences(run: Run, reference: Run, names: list[str]) -> list[str]:
    """What differs from the reference, per scene: the digests that differ (arrays, queries,
    work per line) and the number of pixels whose bits differ (empty when all agree)."""
    found = []
    images = zip(names, run.images, reference.images, strict=True)
    arrays = zip(run.config["arrays"], reference.config["arrays"], strict=True)
    for (name, image, expected), (digests, expected_digests) in zip(images, arrays, strict=True):
        assert image.dtype == np.float32 and image.shape == expected.shape
        arrays_differ = sorted(k for k in expected_digests if digests.get(k) != expected_digests[k])
        pixels = differing(image, expected)
        if pixels or image.tobytes() != expected.tobytes() or arrays_differ:
            found.append(
                f"{run.variant.name} {run.variant.env} on {name}: {pixels} of "
                f"{image.shape[0] * image.shape[1]} pixels differ; arrays differ: {arrays_differ}"
            )
    return found


# --- the scenes ---------------------------------------------------------------------------------


def jobs_for(scenes: dict[str, Path]) -> list[dict]:
    """One small render job per scene, and the harsh scene again with its light samples picked
    by the light tree (built over mirrored, sheared and scaled emitters)."""
    jobs = [
        {"scene": str(path), "width": WIDTH, "height": HEIGHT, "spp": SPP}
        for path in scenes.values()
    ]
    return [*jobs, {**jobs[-1], "light_sampler": "tree"}]


def job_names(scenes: dict[str, Path]) -> list[str]:
    """The jobs' names, in ``jobs_for``'s order."""
    return [*scenes, "harsh, light tree"]


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> dict[str, Path]:
    """Scene files by name: the sample outdoor scene and the harsh one."""
    return {"outdoor": OUTDOOR, "harsh": harsh_scene(tmp_path_factory.mktemp("harsh"))}


@pytest.fixture(scope="module")
def reference(scenes) -> Run:
    """Both scenes rendered in this process with the host's settings."""
    return render_here(jobs_for(scenes))


# --- tests ----------------------------------------------------------------------------------------


def test_scenes_use_every_effect(scenes):
    """The harsh scene runs every effect of the path tracer; outdoor all but textures, shading
    normals, normal maps and the terminator falloff and bending that come with them, and the
    alpha test."""
    from tracer.compiled.scene import compile_scene
    from tracer.integrators.flags import (
        ALL,
        ALPHA_TEST,
        NORMAL_BENDING,
        NORMAL_MAPS,
        SHADING_NORMALS,
        SHADOW_TERMINATOR,
        TEXTURES,
    )
    from tracer.render import effect_plan
    from tracer.scene.loader import load_scene

    plans = {}
    for name, path in scenes.items():
        scene = compile_scene(load_scene(path))
        plans[name] = effect_plan(scene, scene.render).flags
    assert plans["harsh"] == ALL
    shading = SHADING_NORMALS | NORMAL_MAPS | SHADOW_TERMINATOR | NORMAL_BENDING
    assert plans["outdoor"] == ALL & ~(TEXTURES | shading | ALPHA_TEST)


def test_reference_is_a_real_image(reference):
    """Finite, non-negative, varied images: equality below is not that of two black frames."""
    for image in reference.images:
        assert image.shape == (HEIGHT, WIDTH, 3) and image.dtype == np.float32
        assert np.isfinite(image).all() and (image >= 0).all()
        assert image.std() > 0.02 and len(np.unique(image)) > WIDTH * HEIGHT


def test_another_cpu_renders_the_same_bits(reference, scenes, tmp_path, numba_target_cache):
    """Another CPU (an emulated AMD EPYC on an AVX-512 host: numba for Zen 2 in its own kernel
    cache, OpenBLAS's Zen kernels, numpy without AVX-512; elsewhere the old x86-64 baseline)
    renders both scenes bit for bit as this process does: the pixels, the arrays the kernels
    read, float64 ray queries and the work per line."""
    variant = other_cpu()
    if all(os.environ.get(k) == v for k, v in variant.env.items()):
        pytest.skip(f"this process already runs as the emulated {variant.name}")
    cache = numba_target_cache(variant.cache_key)
    run = render_in_subprocess(variant, jobs_for(scenes), tmp_path, cache)
    check_config(run, reference)
    assert run.config["numba_cpu"] != reference.config["numba_cpu"]
    assert run.config["openblas"] != reference.config["openblas"]
    assert run.config["numpy_dispatch"] != reference.config["numpy_dispatch"]
    assert cached_cpu_names(cache) == {variant.numba}
    found = differences(run, reference, job_names(scenes))
    assert not found, "\n".join(found)
    for image, expected in zip(run.images, reference.images, strict=True):
        assert np.array_equal(image, expected) and image.tobytes() == expected.tobytes()


@pytest.mark.slow
def test_cpu_matrix_renders_the_same_bits(reference, scenes, tmp_path, numba_target_cache):
    """Every variant of the wide matrix renders both scenes bit for bit as this process does
    (pixels, arrays, queries, work per line); all differences are reported together: which
    variant, which scene, how many pixels, which arrays."""
    failures = []
    for variant in matrix():
        cache = None if variant.cache_key is None else numba_target_cache(variant.cache_key)
        run = render_in_subprocess(variant, jobs_for(scenes), tmp_path, cache)
        check_config(run, reference)
        failures += differences(run, reference, job_names(scenes))
        config = run.config
        print(  # shown with -s or -rA: what each variant ran and how long it took
            f"{variant.name}: numba {config['numba_cpu']}, OpenBLAS {config['openblas']}, "
            f"numpy {' '.join(config['numpy_dispatch']) or 'baseline'}, kernel {config['kernel']},"
            f" {config['seconds']:.1f} s"
        )
    assert not failures, "\n".join(failures)
