"""The short load profile: locust, headless, against ``tilerender serve`` on 127.0.0.1 (its own
embedded Ray, two tracers of one CPU), 20 users for 20 s with the realistic mix of
``bench/load/locustfile.py``; then a deliberately full queue.

Asserted: no failed request; every job submitted completes (polled to the end) and its NPY
result equals a local render of the same scene and settings bit for bit; frames streamed,
events received and camera updates happened; no job was refused (the profile keeps fewer jobs
in flight than ``MAX_QUEUE``); status p99 within ``STATUS_P99_MS``; a full queue answers 429
with Retry-After within a second, every time.

``STATUS_P99_MS`` is looser than the 50 ms target: the test shares two cores with locust, the
tracers and whatever else runs; the target is measured by ``bench/load/run.py`` (20 users,
60 s) and reported in ``docs/load.md``.
"""

import time

import httpx
import pytest

from bench.load import harness
from bench.load.topology import serve_embedded

PROFILE = harness.Profile(users=20, seconds=20, spawn_rate=20, stop_timeout=10)
STATUS_P99_MS = 250.0
MAX_QUEUE = 16


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    work = tmp_path_factory.mktemp("load")
    api = serve_embedded(work, work / "data", "--tracers", "2", "--threads", "1")
    yield api
    api.stop()


@pytest.fixture(scope="module")
def http(server):
    with httpx.Client(base_url=server.url, timeout=60) as client:
        harness.warm_up(client)  # kernels a cold cache compiles, before any timing
        yield client


def test_short_profile_loses_nothing_and_results_equal_references(server, http, tmp_path):
    run = harness.run_profile(server.url, PROFILE, tmp_path)
    run.jobs = harness.settle(http)
    run.results = harness.check_results(http, run.jobs, run.locust_jobs, harness.References())
    print(harness.format_run(run))

    failures = (tmp_path / "locust_failures.csv").read_text()
    assert run.failures == 0, failures + server.log_tail()
    jobs = run.job_counts()
    assert jobs["submitted"] == jobs["completed"] > 10, jobs
    assert jobs["submitted (seen by locust)"] + 2 == jobs["submitted"]  # + the warm-up's two
    assert run.results["mismatched"] == [] and run.results["unverified"] == [], run.results
    assert run.results["checked"] == jobs["completed"]
    counts = run.counts
    assert counts.get("frames streamed", 0) > 0 and counts.get("camera updates", 0) > 0
    assert counts.get("events received", 0) > 0 and counts.get("sessions opened", 0) > 0
    assert not any(name.startswith("rejected") for name in counts), counts
    assert run.endpoint("/v1/jobs/[id]")["p99"] <= STATUS_P99_MS


@pytest.fixture(scope="module")
def full_queue(http):
    """The queue filled with long jobs, probed with more submissions, then cancelled."""
    scene_id = harness.upload(http, "cornell")
    probe = harness.probe_full_queue(http, scene_id, MAX_QUEUE)
    print(probe)
    return probe


def test_a_full_queue_answers_429_promptly(full_queue):
    assert full_queue["all_429"] and full_queue["retry_after"] == ["10"], full_queue
    assert 1 <= full_queue["queued_before_429"] <= MAX_QUEUE
    assert full_queue["max_ms"] < 1000.0, full_queue


def test_jobs_cancelled_in_the_queue_end_cancelled(http, full_queue):
    """Cancelling the queue's jobs one after another while the render thread starts each next
    one: every job ends cancelled (the running one may finish its frame first)."""
    deadline = time.monotonic() + 15
    while True:
        statuses = {job["id"]: job["status"] for job in harness.list_jobs(http)}
        left = [j for j in full_queue["cancelled"] if statuses[j] not in harness.TERMINAL]
        if not left or time.monotonic() > deadline:
            break
        time.sleep(0.2)
    assert not left, f"{len(left)} cancelled jobs are still {[statuses[j] for j in left]}"
