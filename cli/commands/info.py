"""``tilerender info``: describe a scene (geometry, materials, lights, camera, what it ignores
of its glTF files) as JSON."""

import argparse
import json
import sys

from tracer.compiled.scene import compile_scene
from tracer.scene.loader import load_scene, load_warnings


def run(args: argparse.Namespace) -> int:
    scene = compile_scene(load_scene(args.scene))
    stats = scene.stats
    report = {
        "scene": args.scene,
        "triangles": stats.triangles,
        "zero_area_triangles_dropped": stats.degenerate_triangles,
        "emissive_triangles": stats.emissive_triangles,
        "bounds": {"min": stats.bounds_min, "max": stats.bounds_max},
        "materials": list(scene.material_names),
        "textures": {
            name: [int(image.shape[1]), int(image.shape[0])]
            for name, _, image in scene.textures.sources
        },
        "instances": scene.stats.instances,
        "nodes": len(scene.state.nodes),
        "bvh_nodes": sum(int(pool.bounds.shape[0]) for pool in scene.pools),
        "bytes_per_triangle": round(scene.nbytes / max(1, stats.triangles), 1),
        "camera": scene.camera.model_dump(),
        "render": scene.render.model_dump(),
        "warnings": load_warnings(args.scene),
    }
    json.dump(report, sys.stdout, indent=2)
    print()
    return 0
