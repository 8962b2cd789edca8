"""Fixtures shared by the test suite, and the kernel warmer of long runs."""

import os
import subprocess
import sys

import pytest
from hypothesis import HealthCheck, settings

from tests.helpers import CORNELL, ROOT, tiny_scene, write_json

WARM_FROM = 300
"""Runs of this many tests or more start ``tests/kernel_warmer.py`` beside them
(``TILERENDER_TEST_WARMER=off`` never does)."""
WARMER = pytest.StashKey[subprocess.Popen]()

# Kernels compile on first use (cached on disk afterwards): no per-example deadline, and the
# example counts are set per test, kept small so the suite stays fast on two cores.
settings.register_profile("tilerender", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("tilerender")


def pytest_collection_finish(session):
    """Start the kernel warmer for a long run."""
    if len(session.items) < WARM_FROM or os.environ.get("TILERENDER_TEST_WARMER") == "off":
        return
    import tracer  # noqa: F401 (sets NUMBA_CACHE_DIR, which the warmer inherits)

    session.config.stash[WARMER] = subprocess.Popen(
        [sys.executable, "-m", "tests.kernel_warmer"],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def pytest_sessionfinish(session):
    """Stop the kernel warmer if it is still compiling."""
    warmer = session.config.stash.get(WARMER, None)
    if warmer is not None:
        warmer.terminate()
        warmer.wait()


@pytest.fixture(scope="session")
def cornell():
    """The compiled Cornell box sample scene."""
    from tracer.compiled.scene import compile_scene
    from tracer.scene.loader import load_scene

    return compile_scene(load_scene(CORNELL))


@pytest.fixture
def tiny_scene_file(tmp_path):
    """A small valid JSON scene (built-in shapes only) in its own directory."""
    return write_json(tmp_path / "scene.json", tiny_scene())


@pytest.fixture(scope="module")
def ray_session():
    """One embedded Ray (2 CPUs) for the module, started only if this process has none (the
    API tests share one for the whole run: tests/api/conftest.py)."""
    from cluster.connect import connect, disconnect

    connection = connect(num_cpus=2)
    yield connection
    if connection.started:
        disconnect()


@pytest.fixture
def spot_check_calls(monkeypatch):
    """The pixel count of every ``Coordinator.render_spot_checks`` call of this process during
    the test (the coordinator of an in-process CLI render or service job), in order."""
    from cluster.coordinator import Coordinator

    calls = []
    check = Coordinator.render_spot_checks

    def counted(self, request, *args, **kwargs):
        calls.append(len(request.pixels))
        return check(self, request, *args, **kwargs)

    monkeypatch.setattr(Coordinator, "render_spot_checks", counted)
    return calls


@pytest.fixture(scope="session")
def numba_target_cache(tmp_path_factory):
    """A kernel cache base directory per numba CPU target (``NUMBA_CPU_NAME``), made once per
    session, so the tests that emulate the same CPU compile its kernels once."""
    caches = {}

    def get(target: str):
        if target not in caches:
            caches[target] = tmp_path_factory.mktemp(f"numba-{target}")
        return caches[target]

    return get
