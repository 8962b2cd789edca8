"""The scene inspection (``GET /v1/scenes/{id}``) lists what loading ignored or approximated of
the scene's glTF files (``tracer.scene.loader.load_warnings``), also after a restart."""

import numpy as np
from PIL import Image

from tests.api.conftest import app_client
from tests.tracer.test_mesh_files_warnings import NORMAL_TEXTURE, textured_box


def test_inspect_lists_the_files_warnings(ray_session, tmp_path):
    image = Image.fromarray(np.full((4, 4, 3), 200, np.uint8))
    glb = textured_box(tmp_path / "bumpy.glb", normalTexture=image).read_bytes()
    data = tmp_path / "data"
    with app_client(data) as client:
        r = client.post("/v1/scenes", files={"mesh": ("bumpy.glb", glb)})
        assert r.status_code == 201, r.text
        scene = r.json()
        assert scene["warnings"] == [f"bumpy.glb: {NORMAL_TEXTURE}"]
        assert client.get(f"/v1/scenes/{scene['id']}").json()["warnings"] == scene["warnings"]
        plain = client.post("/v1/scenes", files={"mesh": ("plain.glb", glb)}).json()
        assert client.get(f"/v1/scenes/{plain['id']}").json()["warnings"] == [
            f"plain.glb: {NORMAL_TEXTURE}"
        ]
    with app_client(data) as client:  # restored from disk
        assert client.get(f"/v1/scenes/{scene['id']}").json()["warnings"] == scene["warnings"]
