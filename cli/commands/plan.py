"""``tilerender plan``: print the effects a render of a scene runs and skips, and why."""

import argparse
import json
import sys

from cluster.jobs import with_overrides
from tracer.compiled.scene import compile_scene
from tracer.integrators.effects import effect_plan
from tracer.scene.loader import load_scene


def run(args: argparse.Namespace) -> int:
    state = load_scene(args.scene)
    scene = compile_scene(state)
    settings = with_overrides(state, integrator=args.integrator, max_depth=args.max_depth).render
    report = {
        "scene": args.scene,
        "integrator": settings.integrator,
        **effect_plan(scene, settings).to_json(),
    }
    json.dump(report, sys.stdout, indent=2)
    print()
    return 0
