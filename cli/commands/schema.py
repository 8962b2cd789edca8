"""``tilerender schema``: print the JSON Schema of scene files."""

import argparse
import json

from tracer.scene import format as fmt


def scene_schema_json() -> str:
    """The JSON Schema of scene files, as committed in docs/scene-schema.json."""
    return json.dumps(fmt.SceneFile.model_json_schema(), indent=2, sort_keys=True)


def run(args: argparse.Namespace) -> int:
    print(scene_schema_json())
    return 0
