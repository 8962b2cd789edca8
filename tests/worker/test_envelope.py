"""``worker.envelope.SceneEnvelope``: plain values pass through ``fetched`` unchanged; object
references are replaced by their values."""

from worker.envelope import DEFAULT_SCENE, SceneEnvelope


def test_an_envelope_of_plain_values_is_its_own_fetch():
    envelope = SceneEnvelope("s", 3, [b"c1", b"c2"], b"snap")
    assert envelope.fetched() is envelope
    assert SceneEnvelope() == SceneEnvelope(DEFAULT_SCENE, None, (), None)


def test_references_in_an_envelope_are_fetched(ray_session):
    import ray

    commits, snapshot = ray.put([b"c1"]), ray.put(b"snap")
    fetched = SceneEnvelope("s", 1, commits, snapshot).fetched()
    assert fetched == SceneEnvelope("s", 1, [b"c1"], b"snap")
