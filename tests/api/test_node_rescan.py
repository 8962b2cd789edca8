"""The render thread's look for new Ray nodes: rate-limited, and a failing look does not stop
the service (the placement itself is tested in tests/cluster/test_coordinator.py)."""

import logging

from api import service as service_module
from api.events import EventHub
from api.scenes import SceneRepository
from api.service import NODE_RESCAN_SECONDS, RenderService
from api.settings import Settings
from api.store import Store


class CountingCoordinator:
    """Stands in for the coordinator: counts calls, optionally fails, reports no tracers."""

    def __init__(self, new_ids=(), fail=False):
        self.calls, self.new_ids, self.fail = 0, list(new_ids), fail
        self.stats = {}

    def place_new_nodes(self):
        self.calls += 1
        if self.fail:
            raise ConnectionError("GCS unreachable")
        return self.new_ids

    def tracers(self):
        return []

    balancer_name = "cost-aware"


def make_service(tmp_path):
    settings = Settings(data_dir=tmp_path)
    store = Store(settings.database)
    return RenderService(settings, store, SceneRepository(settings, store), EventHub())


def test_new_nodes_are_looked_for_at_most_every_interval(tmp_path, monkeypatch):
    clock = [1000.0]
    monkeypatch.setattr(service_module.time, "monotonic", lambda: clock[0])
    service = make_service(tmp_path)
    service.coordinator = CountingCoordinator(new_ids=["t7"])
    service._place_new_nodes()
    service._place_new_nodes()
    assert service.coordinator.calls == 1
    clock[0] += NODE_RESCAN_SECONDS - 0.1
    service._place_new_nodes()
    assert service.coordinator.calls == 1
    clock[0] += 0.2
    service._place_new_nodes()
    assert service.coordinator.calls == 2


def test_a_failing_look_is_logged_and_retried(tmp_path, monkeypatch, caplog):
    clock = [1000.0]
    monkeypatch.setattr(service_module.time, "monotonic", lambda: clock[0])
    service = make_service(tmp_path)
    service.coordinator = CountingCoordinator(fail=True)
    with caplog.at_level(logging.WARNING, logger="tilerender.api"):
        service._place_new_nodes()
    assert "looking for new Ray nodes failed: GCS unreachable" in caplog.text
    clock[0] += NODE_RESCAN_SECONDS
    service._place_new_nodes()
    assert service.coordinator.calls == 2
