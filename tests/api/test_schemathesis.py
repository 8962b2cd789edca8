"""A bounded property-based run of the OpenAPI document against a real server: every
operation, at most ``EXAMPLES`` generated requests each, and no answer may be a 5xx (or
anything but JSON errors for 4xx)."""

import tempfile

import schemathesis
from hypothesis import HealthCheck, settings

from api.app import create_app
from tests.api.conftest import make_settings

EXAMPLES = 30

# The document the server serves (building it starts nothing); requests go to the live server.
schema = schemathesis.openapi.from_dict(create_app(make_settings(tempfile.gettempdir())).openapi())


@schema.parametrize()
@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck))
def test_no_server_errors(case, live_server):
    response = case.call(base_url=live_server.url, timeout=60)
    where = f"{case.method} {case.formatted_path} -> {response.status_code}: {response.text[:300]}"
    assert response.status_code < 500, where
    if 400 <= response.status_code < 500:
        body = response.json()
        assert body["error"]["message"] and body["error"]["status"] == response.status_code, where
