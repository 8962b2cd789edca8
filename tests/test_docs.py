"""The committed documentation artefacts match the code."""

import json
from pathlib import Path

from cli.commands.schema import scene_schema_json

ROOT = Path(__file__).resolve().parents[1]


def test_scene_schema_is_current():
    """docs/scene-schema.json is what `tilerender schema` prints (regenerate it if not)."""
    committed = (ROOT / "docs" / "scene-schema.json").read_text()
    assert json.loads(committed) == json.loads(scene_schema_json()), (
        "run: tilerender schema > docs/scene-schema.json"
    )


def test_sample_scenes_follow_the_schema():
    """Every sample scene.json validates against the exported schema's model."""
    from tracer.scene.format import SceneFile

    scenes = sorted((ROOT / "scenes").glob("*/scene.json"))
    assert len(scenes) >= 3
    for path in scenes:
        SceneFile.model_validate_json(path.read_text())


def test_architecture_names_every_module():
    """docs/architecture.md stays true to the code: it names each module of every package by
    its path, and every module path it names exists."""
    import re

    text = (ROOT / "docs" / "architecture.md").read_text()
    packages = ("tracer", "worker", "cluster", "api", "cli")
    missing = [
        path.relative_to(ROOT).as_posix()
        for package in packages
        for path in sorted((ROOT / package).rglob("*.py"))
        if path.name != "__init__.py" and path.relative_to(ROOT).as_posix() not in text
    ]
    assert not missing, f"docs/architecture.md does not mention {missing}"
    named = set(re.findall(rf"`((?:{'|'.join(packages)})/[\w/]+\.py)`", text))
    gone = sorted(path for path in named if not (ROOT / path).is_file())
    assert not gone, f"docs/architecture.md names modules that do not exist: {gone}"


def test_scene_format_fragments_validate():
    """Every JSON fragment in docs/scene-format.md, added to the first example, is a valid
    scene (the animation fragment is checked in tests/tracer/test_scene_animation.py)."""
    import re

    from tracer.scene.format import SceneFile

    text = (ROOT / "docs" / "scene-format.md").read_text(encoding="utf-8")
    blocks = [json.loads(b) for b in re.findall(r"```json\n(.*?)```", text, re.S)]
    first = blocks[0]
    SceneFile.model_validate(first)
    fragments = [b for b in blocks[1:] if "animation" not in b]
    assert any("lights" in b for b in fragments)
    for fragment in fragments:
        SceneFile.model_validate({**first, **fragment})
