"""The job store's status transitions: a job the render thread starts after a cancel landed
stays cancelled (the race the load test found: a cancel between the thread's read of the job
and its status update used to be overwritten with "running")."""

from api.store import Store


def queued_job(tmp_path) -> tuple[Store, str]:
    store = Store(tmp_path / "jobs.db")
    store.add_scene("s1", "scene", "json", "scene.json", 12)
    store.add_job("j1", "s1", {"kind": "still"}, 1, 0, 8, 8)
    return store, "j1"


def test_starting_a_queued_job_marks_it_running_once(tmp_path):
    store, job = queued_job(tmp_path)
    assert store.start_job(job)
    first = store.job(job)
    assert first["status"] == "running" and first["started"] is not None
    assert store.start_job(job)  # resuming after a restart keeps the first start time
    assert store.job(job)["started"] == first["started"]


def test_a_cancel_before_the_start_wins(tmp_path):
    store, job = queued_job(tmp_path)
    assert store.finish_job(job, "cancelled", "cancelled by the user")
    assert not store.start_job(job)
    record = store.job(job)
    assert record["status"] == "cancelled" and record["error"] == "cancelled by the user"
