"""A glTF file's JSON is parsed once per load (``gltf_features.gltf_json``), however many of the
loader's readers ask for it, and parsed again when the file changes."""

import os

from tests.tracer.test_mesh_files_warnings import textured_box
from tracer.scene import gltf_features
from tracer.scene.loader import load_scene, load_warnings


def counted_reads(monkeypatch) -> list:
    """Clears the cache and records each real parse of a file's JSON."""
    reads = []
    real = gltf_features._read_json

    def read(path, suffix):
        reads.append(path)
        return real(path, suffix)

    gltf_features._cached_json.cache_clear()
    monkeypatch.setattr(gltf_features, "_read_json", read)
    return reads


def test_one_load_parses_the_json_once(tmp_path, monkeypatch):
    path = textured_box(tmp_path / "box.glb")
    reads = counted_reads(monkeypatch)
    state = load_scene(path)
    load_warnings(path)
    assert reads == [path.resolve()]
    assert "box.glb#paint" in state.materials


def test_an_edited_file_is_read_again(tmp_path, monkeypatch):
    path = textured_box(tmp_path / "box.glb")
    reads = counted_reads(monkeypatch)
    before = gltf_features.gltf_json(path)
    stat = path.stat()
    textured_box(path, roughnessFactor=0.25)
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns))  # same time: the size tells
    after = gltf_features.gltf_json(path)
    assert len(reads) == 2
    assert "roughnessFactor" not in before["materials"][0]["pbrMetallicRoughness"]
    assert after["materials"][0]["pbrMetallicRoughness"]["roughnessFactor"] == 0.25
    same_size = path.read_bytes().replace(b'"roughnessFactor":0.25', b'"roughnessFactor":0.75')
    path.write_bytes(same_size)
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1))  # same size: the time tells
    assert (
        gltf_features.gltf_json(path)["materials"][0]["pbrMetallicRoughness"]["roughnessFactor"]
        == 0.75
    )
    assert len(reads) == 3
