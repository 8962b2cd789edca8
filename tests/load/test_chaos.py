"""Chaos under load (slow): during a locust run, SIGKILL a tracer process; in another run, kill
every process of a Ray worker node (``ray start`` topology). No request fails, no job fails or
is lost, and every result equals its reference bit for bit. ``bench/load/run.py --chaos ...``
runs the same with the long profile."""

import httpx
import pytest

from bench.load import harness

PROFILE = harness.Profile(users=10, seconds=30, spawn_rate=10, stop_timeout=10)


def run_with_chaos(tmp_path, nodes: str, make_action) -> harness.LoadRun:
    with harness.service(tmp_path, nodes, 2) as (api, topology):
        http = httpx.Client(base_url=api.url, timeout=60)
        harness.warm_up(http)
        chaos = harness.Chaos(nodes, 10.0, make_action(api, topology))
        run = harness.run_profile(api.url, PROFILE, tmp_path / "locust", chaos)
        run.jobs = harness.settle(http)
        run.results = harness.check_results(http, run.jobs, run.locust_jobs, harness.References())
        run.tracers = http.get("/v1/cluster").json()["tracers"]
        log = api.log_tail()
    print(harness.format_run(run))
    assert run.chaos.fired_at is not None, "the chaos action did not run"
    assert run.failures == 0, (tmp_path / "locust" / "locust_failures.csv").read_text() + log
    jobs = run.job_counts()
    assert jobs["submitted"] == jobs["completed"] > 0, jobs
    assert run.results["mismatched"] == [] and run.results["unverified"] == [], run.results
    assert sum(t["failures"] for t in run.tracers) >= 1, run.tracers  # the chaos hit a tracer
    return run


@pytest.mark.slow
def test_a_tracer_killed_under_load_loses_nothing(tmp_path):
    def kill(api, _topology):
        return lambda: harness.kill_a_tracer(api.url)

    run = run_with_chaos(tmp_path, "embedded", kill)
    assert "SIGKILL to tracer" in run.chaos.note


@pytest.mark.slow
def test_a_ray_node_removed_under_load_loses_nothing(tmp_path):
    def remove(api, topology):
        def action() -> str:
            topology.workers[-1].kill()
            return "worker node killed"

        return action

    run = run_with_chaos(tmp_path, "ray-start", remove)
    states = {t["id"]: t["state"] for t in run.tracers}
    assert "ready" in states.values(), states  # the other node's tracer carried on
