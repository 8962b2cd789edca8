"""What bounded turns cost a big job: one frame rendered whole against the same frame in runs
of about ``--turn`` seconds (``cluster.turns``), interleaved, through one coordinator.

The service renders a job's frame run by run so that nothing waits for more than a turn
(``docs/api.md``); each run is a coordinator frame of its own, with its calls, its pool and its
assembly. This measures that overhead as a ratio of wall times, side by side in one process,
and checks that both give the same bits.

    python bench/turns.py [--width 640 --height 480 --spp 64 --turn 0.5 --rounds 3]
"""

import argparse
import statistics
import time

import numpy as np
from common import REPO_ROOT, fmt_float, machine_info, print_machine, print_table, write_results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--turn", type=float, default=0.5, help="seconds of one turn")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()

    from cluster.connect import connect
    from cluster.coordinator import Coordinator
    from cluster.scene_graph import SceneGraph
    from cluster.turns import TurnedFrame, TurnSizer
    from tracer.request import FrameRequest
    from tracer.scene import format as fmt
    from tracer.scene.loader import load_scene

    machine = machine_info()
    print_machine(machine)
    connect()
    state = load_scene(REPO_ROOT / "scenes" / "cornell-box" / "scene.json")
    camera = fmt.override(state.camera, width=args.width, height=args.height)
    settings = fmt.override(state.render, spp=args.spp)
    request = FrameRequest(0, camera, settings)
    whole_s, turned_s, runs = [], [], []
    with Coordinator(SceneGraph(state)) as coordinator:
        coordinator.render_frame(FrameRequest(0, fmt.override(camera, width=32, height=24)))
        for _ in range(args.rounds):
            start = time.perf_counter()
            whole = coordinator.render_frame(request).rgb
            whole_s.append(time.perf_counter() - start)
            part = TurnedFrame(request, TurnSizer(args.turn))
            frames: list = []
            start = time.perf_counter()
            for _ in part.turns(coordinator, None, frames.append):
                pass
            turned_s.append(time.perf_counter() - start)
            runs.append(len(frames))
            if not np.array_equal(part.image, whole):
                raise SystemExit("the frame in turns differs from the whole frame")
    ratio = statistics.median(w / t for w, t in zip(whole_s, turned_s, strict=True))
    print_table(
        f"{args.width}x{args.height} at {args.spp} spp: whole vs turns of {args.turn:g} s "
        f"({args.rounds} rounds, interleaved; bit-identical)",
        ["whole s (median)", "in turns s (median)", "runs", "whole/turns speed"],
        [[fmt_float(statistics.median(whole_s), 2), fmt_float(statistics.median(turned_s), 2),
          int(statistics.median(runs)), fmt_float(ratio, 3)]],
    )  # fmt: skip
    write_results(
        "turns",
        {"options": vars(args), "whole_s": whole_s, "turned_s": turned_s, "runs": runs},
        machine,
    )


if __name__ == "__main__":
    main()
