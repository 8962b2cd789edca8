"""The scene summary of ``GET /v1/scenes/{id}`` for every kind of sky (no service needed): the
sky is reported as its radiance averaged over the sphere."""

import numpy as np
import pytest

from api.scenes import summary
from tests.helpers import tiny_scene, write_json
from tracer.scene.loader import load_scene


@pytest.mark.parametrize(
    "sky, mean",
    [
        ({"radiance": [0.1, 0.2, 0.3]}, [0.1, 0.2, 0.3]),
        ({"type": "gradient", "zenith": [1, 1, 1], "horizon": [0, 0, 0], "ground": [2, 0, 0]},
         [1.25, 0.25, 0.25]),
        ({"type": "environment", "file": "sky.npy", "scale": 2.0}, [1.0, 1.0, 1.0]),
        ({"type": "environment", "file": "black.npy"}, [0.0, 0.0, 0.0]),
    ],
)  # fmt: skip
def test_summary_reports_every_sky(tmp_path, sky, mean):
    np.save(tmp_path / "sky.npy", np.full((4, 8, 3), 0.5, np.float32))
    np.save(tmp_path / "black.npy", np.zeros((4, 8, 3), np.float32))
    state = load_scene(write_json(tmp_path / "scene.json", tiny_scene(sky=sky)))
    result = summary(state)
    np.testing.assert_allclose(result["sky"], mean, rtol=1e-12)
    assert ("sky" in result["effects"]["effects"]) == (max(mean) > 0.0)
