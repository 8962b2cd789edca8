"""The hostile corpus (``bench/load/hostile_cases.py``, ``hostile_uploads.py``) against a real
``tilerender serve`` on 127.0.0.1 (one tracer of one CPU, its own embedded Ray): every case
answered with its status and the JSON error body, no 5xx counted by the server, ``/healthz``
answering and the API's RSS back within ``TOLERANCE_MIB`` of its baseline after each case.

One server here, with a token: the corpus's cases send it, the auth cases their own headers
(``python bench/load/hostile.py`` runs them on a second server, and also the heavy cases left
out of the quick subset: 400k-entry lists, 64 MiB bodies, a stalled body).
"""

import dataclasses

import httpx
import pytest

from bench.load import hostile
from bench.load.hostile_cases import Answer, Case, Target, call
from bench.load.hostile_uploads import TOKEN

TOLERANCE_MIB = hostile.DEFAULT_RSS_TOLERANCE_MIB


SAMPLE_EVERY = 3
"""The default suite sends every third case of the quick subset and every auth case (about a
third of the time); ``-m slow`` sends the rest."""


def params(cases: list[Case]) -> list:
    return [
        pytest.param(
            case,
            id=case.name,
            marks=[] if k % SAMPLE_EVERY == 0 or case.auth else [pytest.mark.slow],
        )
        for k, case in enumerate(cases)
    ]


@dataclasses.dataclass
class Live:
    target: Target
    pid: int
    data_dir: object
    baseline_mib: float


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    work = tmp_path_factory.mktemp("hostile")
    with (
        hostile.server(work, "--token", TOKEN) as api,
        httpx.Client(base_url=api.url, timeout=60) as http,
    ):
        target = Target(api.url, http, token=TOKEN)
        hostile.prepare(target)
        yield Live(target, api.process.pid, api.data_dir, hostile.rss_mib(api.process.pid))


@pytest.mark.parametrize("case", params(hostile.select(quick=True)))
def test_hostile_case(live, case):
    target = dataclasses.replace(live.target, token=None) if case.auth else live.target
    outcome = hostile.run_case(
        case, target, live.pid, live.baseline_mib, TOLERANCE_MIB, live.data_dir
    )
    if outcome.rss_delta_mib > TOLERANCE_MIB:  # charge the growth to this case only
        live.baseline_mib += outcome.rss_delta_mib
    assert outcome.passed, hostile.format_row(outcome)


def test_the_corpus_covers_every_route():
    names = [c.name for c in hostile.CASES]
    assert len(names) == len(set(names)) and len(names) >= 70
    routes = " ".join(c.route for c in hostile.CASES)
    for route in (
        "POST /v1/scenes", "/commits", "PATCH /v1/scenes", "POST /v1/jobs", "GET /v1/jobs",
        "/cancel", "/frames/", "/result", "/events", "/query", "POST /v1/sessions",
        "/camera", "/frame.jpg", "/stream", "/v1/cluster/balancer", "/healthz",
    ):  # fmt: skip
        assert route in routes, route
    statuses = {c.expect for c in hostile.CASES}
    assert {200, 201, 400, 401, 403, 404, 405, 408, 409, 413, 415, 422} <= statuses
    assert len(hostile.select(quick=True)) >= 70


ERROR = '{"error": {"status": 422, "code": "invalid", "message": "spp: too large"}}'
CASE = Case("example", "POST /v1/jobs", 422, call("POST", "/v1/jobs"), word="spp")


def test_judge_wants_the_json_error_body():
    assert hostile.judge(CASE, Answer(422, {}, ERROR)) == []
    plain = Answer(422, {"content-type": "text/plain"}, "Bad Request")
    assert "not a JSON error body" in hostile.judge(CASE, plain)[0]
    assert "without 'spp'" in hostile.judge(CASE, Answer(422, {}, ERROR.replace("spp", "x")))[0]
    assert hostile.judge(CASE, Answer(500, {}, ERROR)) == ["status 500, expected 422"]


def test_judge_finds_server_paths_missing_headers_and_silence(tmp_path):
    leak = Answer(422, {}, ERROR.replace("too large", f"{tmp_path}/uploads/x"))
    assert hostile.judge(CASE, leak, tmp_path) == ["the server's data directory in the answer"]
    wrong = dataclasses.replace(CASE, expect=405, allow=frozenset({"GET", "POST"}))
    answer = Answer(405, {"allow": "POST"}, ERROR.replace("422", "405"))
    assert "Allow: 'POST'" in hostile.judge(dataclasses.replace(wrong, word=""), answer)[0]
    unauthorized = dataclasses.replace(CASE, expect=401, word="")
    assert "WWW-Authenticate" in hostile.judge(unauthorized, Answer(401, {}, ERROR.replace(
        "422", "401")))[0]  # fmt: skip
    assert hostile.judge(CASE, Answer(None, note="timed out")) == ["no answer (timed out)"]
    gone = dataclasses.replace(CASE, expect=None)
    assert hostile.judge(gone, Answer(None)) == []
