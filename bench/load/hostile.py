"""The hostile corpus against a real server: every case answered as it must be, no 5xx, the
server healthy and its memory back to its baseline after each.

    python bench/load/hostile.py                  # every case (two servers: without a token, with)
    python bench/load/hostile.py --quick          # the fast subset
    python bench/load/hostile.py --markdown out.md  # also the summary for docs/load.md

Starts ``tilerender serve --tracers 1 --threads 1`` on 127.0.0.1 (its own embedded Ray),
makes the fixtures (``hostile_cases.py``), sends each case of ``hostile_cases.py`` and
``hostile_uploads.py`` in turn and checks after it:

- the status is the expected one; a 4xx carries the JSON error body (``{"error": {"status",
  "code", "message"}}``, the message containing the case's word), never a stack trace or the
  server's data directory; a 405 lists the route's methods in ``Allow``, a 401 sends
  ``WWW-Authenticate``;
- no 5xx was counted by the server itself (its ``/metrics``), answered to us or not;
- ``/healthz`` answers (and, during a heavy case, answered within ``HEALTH_LIMIT`` all along);
- the API process's RSS is back within ``--rss-tolerance-mib`` of the baseline (measured
  once the fixtures exist), waiting up to ``RSS_SETTLE`` seconds for it;
- a case that must not change a scene left its version as it was.

Then the auth cases run against a second server with a token. Prints one row per case
(expected, got, ms, RSS delta, problems) and the totals; exit code 1 if any case failed.
"""

import argparse
import contextlib
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parents[1])]

import httpx  # noqa: E402
import psutil  # noqa: E402

from bench.load.hostile_cases import API_CASES, JSON, Answer, Case, Target  # noqa: E402
from bench.load.hostile_uploads import (  # noqa: E402
    AUTH_CASES,
    TOKEN,
    UPLOAD_CASES,
    animated_scene,
    scene_bytes,
)
from bench.load.topology import serve_embedded  # noqa: E402

CASES: list[Case] = UPLOAD_CASES + API_CASES + AUTH_CASES
HEALTH_LIMIT = 1.0
"""Seconds /healthz may take while a heavy case runs."""
RSS_SETTLE = 5.0
DEFAULT_RSS_TOLERANCE_MIB = 64.0
FIXTURE_TIMEOUT = 900.0
"""A cold kernel cache compiles the fixture job's kernels first (minutes)."""


@dataclass
class Outcome:
    case: Case
    answer: Answer
    rss_delta_mib: float
    problems: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return not self.problems


def judge(case: Case, answer: Answer, data_dir: Path | None = None) -> list[str]:
    """What is wrong with ``answer`` to ``case`` (empty: nothing)."""
    if answer.status is None:
        return [] if case.expect is None else [f"no answer ({answer.note})"]
    problems = []
    if answer.status != case.expect:
        problems.append(f"status {answer.status}, expected {case.expect or 'no answer'}")
    if "Traceback" in answer.text or 'File "' in answer.text:
        problems.append("a stack trace in the answer")
    if data_dir is not None and str(data_dir) in answer.text:
        problems.append("the server's data directory in the answer")
    if 400 <= answer.status < 500 and case.json_error:
        problems += _error_body(answer, case.word)
    if case.allow is not None and answer.status == 405:
        allow = {m.strip().upper() for m in answer.headers.get("allow", "").split(",")}
        allow -= {"", "HEAD", "OPTIONS"}
        if allow != set(case.allow):
            problems.append(
                f"Allow: {answer.headers.get('allow')!r}, expected {', '.join(sorted(case.allow))}"
            )
    if answer.status == 401 and answer.headers.get("www-authenticate", "") != "Bearer":
        problems.append("a 401 without WWW-Authenticate: Bearer")
    return problems


def _error_body(answer: Answer, word: str) -> list[str]:
    try:
        body = answer.json()
    except ValueError:
        ctype = answer.headers.get("content-type", "?")
        return [f"not a JSON error body ({ctype}: {answer.text[:60]!r})"]
    error = body.get("error") if isinstance(body, dict) else None
    if not isinstance(error, dict) or set(body) != {"error"}:
        return [f"not the error shape: {answer.text[:80]!r}"]
    problems = []
    if error.get("status") != answer.status or not error.get("code"):
        problems.append(f"error status/code {error.get('status')}/{error.get('code')}")
    message = str(error.get("message") or "")
    if not message:
        problems.append("an empty error message")
    elif word.lower() not in message.lower():
        problems.append(f"message without {word!r}: {message[:100]!r}")
    return problems


# --- The server ---------------------------------------------------------------------------


@contextlib.contextmanager
def server(workdir: Path, *extra: str):
    """``tilerender serve --tracers 1 --threads 1`` (plus ``extra``) on 127.0.0.1."""
    api = serve_embedded(workdir, workdir / "data", "--tracers", "1", "--threads", "1", *extra)
    try:
        yield api
    finally:
        api.stop()


QUAD = [[-0.5, 2.0, -1.0], [0.5, 2.0, -1.0], [0.5, 2.5, -1.0], [-0.5, 2.5, -1.0]]
QUAD_OPS = [
    {"op": "add_mesh", "mesh": "quad", "vertices": QUAD, "faces": [[0, 1, 2], [0, 2, 3]]},
    {"op": "add_node", "name": "quad", "kind": "deformable", "mesh": "quad", "material": "grey"},
]


def make_fixture(target: Target, name: str) -> str:
    """The fixture ``name`` (``hostile_cases.py``), made through the API; returns its id."""
    http = target.client
    headers = {"Authorization": f"Bearer {target.token}"} if target.token else {}

    def post(path: str, **kwargs) -> dict:
        kwargs["headers"] = {**headers, **kwargs.get("headers", {})}
        r = http.post(path, timeout=120, **kwargs)
        assert r.status_code in (200, 201, 202), f"{path}: {r.status_code} {r.text[:300]}"
        return r.json()

    if name in ("scene", "scratch", "meshy"):
        scene_id = post("/v1/scenes", content=scene_bytes(), headers=JSON)["id"]
        if name == "meshy":
            post(f"/v1/scenes/{scene_id}/commits", json={"ops": QUAD_OPS})
        return scene_id
    if name == "animated":
        return post("/v1/scenes", json=animated_scene())["id"]
    assert name == "done_job", name
    job = post("/v1/jobs", json={"scene_id": target.fixtures["scene"], "spp": 1})["id"]
    deadline = time.monotonic() + FIXTURE_TIMEOUT
    while (status := http.get(f"/v1/jobs/{job}", headers=headers).json()["status"]) != "done":
        assert status in ("queued", "running"), f"the fixture job ended {status}"
        assert time.monotonic() < deadline, "the fixture job did not finish"
        time.sleep(0.2)
    return job


FIXTURES = ("scene", "scratch", "animated", "meshy", "done_job")


def prepare(target: Target) -> None:
    """Make every fixture (``done_job`` renders: the first run compiles the kernels)."""
    for name in FIXTURES:
        target.fixtures[name] = make_fixture(target, name)


def rss_mib(pid: int) -> float:
    return psutil.Process(pid).memory_info().rss / (1 << 20)


def server_5xx(http: httpx.Client) -> float:
    """5xx answers the server counted (``tilerender_http_requests`` by status)."""
    from prometheus_client.parser import text_string_to_metric_families

    total = 0.0
    for family in text_string_to_metric_families(http.get("/metrics", timeout=30).text):
        if family.name == "tilerender_http_requests":
            total += sum(
                s.value
                for s in family.samples
                if s.name.endswith("_total") and s.labels.get("status", "").startswith("5")
            )
    return total


class HealthProbe:
    """Times /healthz every 50 ms in a thread while a heavy case runs."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.worst = 0.0
        self.failures = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        with httpx.Client(base_url=self.url) as http:
            while not self._stop.is_set():
                start = time.perf_counter()
                try:
                    ok = http.get("/healthz", timeout=10).status_code == 200
                except httpx.HTTPError:
                    ok = False
                self.worst = max(self.worst, time.perf_counter() - start)
                self.failures += not ok
                self._stop.wait(0.05)

    def __enter__(self) -> "HealthProbe":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(15)


def run_case(
    case: Case, target: Target, pid: int, baseline_mib: float, tolerance_mib: float,
    data_dir: Path | None = None,
) -> Outcome:  # fmt: skip
    """Send ``case`` and check the answer and the server afterwards (module docstring)."""
    http = target.client
    auth = {"Authorization": f"Bearer {target.token}"} if target.token else {}
    errors_before = server_5xx(http)
    version = None
    if case.keeps:
        version = http.get(f"/v1/scenes/{target.fixtures[case.keeps]}", headers=auth).json()
    if case.heavy:
        with HealthProbe(target.url) as probe:
            answer = case.send(target)
    else:
        probe, answer = None, case.send(target)
    problems = judge(case, answer, data_dir)
    _clean_up(answer, http, auth)
    if probe is not None and (probe.worst > HEALTH_LIMIT or probe.failures):
        problems.append(f"/healthz took up to {probe.worst:.1f} s meanwhile")
    try:
        healthy = http.get("/healthz", timeout=5).status_code == 200
    except httpx.HTTPError:
        healthy = False
    if not healthy:
        problems.append("/healthz does not answer afterwards")
    errors = server_5xx(http) - errors_before
    if errors:
        problems.append(f"the server counted {errors:.0f} 5xx")
    if version is not None:
        after = http.get(f"/v1/scenes/{target.fixtures[case.keeps]}", headers=auth).json()
        if after.get("version") != version.get("version"):
            problems.append(f"scene version {version.get('version')} -> {after.get('version')}")
            target.fixtures[case.keeps] = make_fixture(target, case.keeps)  # for the next cases
    deadline = time.monotonic() + RSS_SETTLE
    while (delta := rss_mib(pid) - baseline_mib) > tolerance_mib and time.monotonic() < deadline:
        time.sleep(0.1)
    if delta > tolerance_mib:
        problems.append(f"RSS {delta:+.0f} MiB over the baseline after {RSS_SETTLE:g} s")
    return Outcome(case, answer, delta, problems)


def _clean_up(answer: Answer, http: httpx.Client, auth: dict) -> None:
    """Remove what a case that was (wrongly or rightly) accepted made."""
    location = answer.headers.get("location", "")
    if answer.status == 201 and location.startswith("/v1/sessions/"):
        # as a viewer would: its first frame (and the memory that takes), then close
        http.get(location + "/frame.jpg", headers=auth, timeout=60)
    if answer.status == 201 and location.startswith(("/v1/scenes/", "/v1/sessions/")):
        http.delete(location, headers=auth, timeout=60)
    elif answer.status == 202 and location.startswith("/v1/jobs/"):
        http.post(location + "/cancel", headers=auth, timeout=60)


def run_server(
    cases: list[Case], workdir: Path, tolerance_mib: float, token: str | None = None,
    log=lambda line: print(line, flush=True),
) -> list[Outcome]:  # fmt: skip
    """Start a server (with ``token``, if given), make the fixtures, run ``cases``."""
    extra = ("--token", token) if token else ()
    with server(workdir, *extra) as api, httpx.Client(base_url=api.url, timeout=60) as http:
        target = Target(api.url, http, token=token)
        prepare(target)
        if token:
            target.token = None  # the auth cases set their own headers
        baseline = rss_mib(api.process.pid)
        log(f"server {api.url} (pid {api.process.pid}), baseline RSS {baseline:.0f} MiB")
        outcomes = []
        for case in cases:
            outcome = run_case(case, target, api.process.pid, baseline, tolerance_mib, api.data_dir)
            log(format_row(outcome))
            outcomes.append(outcome)
            if outcome.rss_delta_mib > tolerance_mib:  # charge the growth to this case only
                baseline += outcome.rss_delta_mib
        return outcomes


# --- Reports ----------------------------------------------------------------------------------


def format_row(o: Outcome) -> str:
    got = "-" if o.answer.status is None else str(o.answer.status)
    expected = "-" if o.case.expect is None else str(o.case.expect)
    verdict = "ok" if o.passed else "FAIL: " + "; ".join(o.problems)
    return (
        f"{o.case.name[:52]:52} {expected:>4} {got:>4} {1000 * o.answer.seconds:7.0f} ms"
        f" {o.rss_delta_mib:+6.1f} MiB  {verdict}"
    )


def totals(outcomes: list[Outcome]) -> dict:
    answered = [o.answer.status for o in outcomes if o.answer.status is not None]
    return {
        "cases": len(outcomes),
        "passed": sum(o.passed for o in outcomes),
        "failed": sum(not o.passed for o in outcomes),
        "5xx answered": sum(s >= 500 for s in answered),
        "unanswered": len(outcomes) - len(answered),
        "max RSS delta MiB": round(max((o.rss_delta_mib for o in outcomes), default=0.0), 1),
        "slowest ms": round(1000 * max((o.answer.seconds for o in outcomes), default=0.0)),
    }


def markdown(outcomes: list[Outcome]) -> str:
    """The summary for docs/load.md: totals, then one row per route, then the failures."""
    t = totals(outcomes)
    lines = [
        f"{t['cases']} cases, **{t['passed']} passed, {t['failed']} failed**; "
        f"5xx answered {t['5xx answered']}, unanswered {t['unanswered']}, largest RSS delta "
        f"{t['max RSS delta MiB']} MiB, slowest answer {t['slowest ms']} ms.",
        "",
        "| route | cases | passed | expected statuses | slowest ms |",
        "|---|---:|---:|---|---:|",
    ]
    routes: dict[str, list[Outcome]] = {}
    for o in outcomes:
        routes.setdefault(o.case.route, []).append(o)
    for route, group in routes.items():
        statuses = ", ".join(sorted({str(o.case.expect or "none") for o in group}))
        slowest = round(1000 * max(o.answer.seconds for o in group))
        passed = sum(o.passed for o in group)
        lines.append(f"| `{route}` | {len(group)} | {passed} | {statuses} | {slowest} |")
    failed = [o for o in outcomes if not o.passed]
    if failed:
        lines += ["", "Failed:", ""]
        lines += [f"- {o.case.name}: {'; '.join(o.problems)}" for o in failed]
    return "\n".join(lines) + "\n"


def select(quick: bool, only: str | None = None) -> list[Case]:
    chosen = [c for c in CASES if c.quick or not quick]
    return [c for c in chosen if only is None or only.lower() in c.name.lower()]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="only the fast cases")
    parser.add_argument("--only", help="only cases whose name contains this")
    parser.add_argument("--rss-tolerance-mib", type=float, default=DEFAULT_RSS_TOLERANCE_MIB)
    parser.add_argument("--markdown", type=Path, help="write the summary here")
    args = parser.parse_args(argv)
    cases = select(args.quick, args.only)
    work = Path(tempfile.mkdtemp(prefix="tilerender-hostile-"))
    outcomes = []
    plain = [c for c in cases if not c.auth]
    if plain:
        outcomes += run_server(plain, work / "plain", args.rss_tolerance_mib)
    guarded = [c for c in cases if c.auth]
    if guarded:
        outcomes += run_server(guarded, work / "token", args.rss_tolerance_mib, token=TOKEN)
    summary = totals(outcomes)
    print(", ".join(f"{k} {v}" for k, v in summary.items()))
    if args.markdown is not None:
        args.markdown.write_text(markdown(outcomes))
    return 0 if summary["failed"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
