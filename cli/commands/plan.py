"""``tilerender plan``: print the effects a render of a scene runs and skips, and why."""

import argparse
import json
import sys

from cluster.jobs import with_overrides
from tracer.compiled.scene import compile_scene
from tracer.integrators.effects import effect_plan
from tracer.integrators.kernel_choice import plan_report
from tracer.scene.loader import load_scene


def run(args: argparse.Namespace) -> int:
    state = load_scene(args.scene)
    scene = compile_scene(state)
    settings = with_overrides(
        state,
        integrator=args.integrator,
        max_depth=args.max_depth,
        kernel=args.kernel,
        light_sampler=args.light_sampler,
    ).render
    report = {
        "scene": args.scene,
        "integrator": settings.integrator,
        **plan_report(effect_plan(scene, settings), settings),
    }
    json.dump(report, sys.stdout, indent=2)
    print()
    return 0
