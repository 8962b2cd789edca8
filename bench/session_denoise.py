"""Frames per second of a denoised live session: what the viewer's denoise toggle costs.

Starts ``tilerender serve`` on 127.0.0.1 (a free port, a temporary data directory, its own
embedded Ray), uploads the Cornell box and opens one ``--size`` session, then, for
``--rounds`` rounds, switches its denoising (``PATCH /v1/sessions/{id}``) through off, fast,
balanced and high in turns. Each setting settles for ``--warm`` seconds and is then measured for
``--seconds``: the frames a client reading the MJPEG stream receives per second, with the camera
still and with it orbiting (a camera update every 0.1 s, so every frame starts its blend and
guides over). Reported per setting: the median over rounds of the client's fps, and the
session's own stats (spp per frame and the resolution scale the workload scaler chose, the
denoiser's milliseconds, frames the encoder dropped because a newer one was waiting).
Target (issue 24): >= 8 fps denoised at 320x180.

    python bench/session_denoise.py [--size 320x180] [--seconds 6] [--rounds 3]
"""

import argparse
import statistics
import tempfile
import threading
import time
from pathlib import Path

from api_latency import StreamReader, start_server, upload_cornell
from common import fmt_float, machine_info, print_machine, print_table, write_results

QUALITIES = ("off", "fast", "balanced", "high")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="Frames per second of a live session with each denoise setting, camera "
        "still and orbiting. Writes bench/results/session_denoise.json.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--size", default="320x180", help="WxH of the session")
    parser.add_argument("--seconds", type=float, default=6.0, help="measured seconds per turn")
    parser.add_argument("--warm", type=float, default=2.0, help="settling seconds per turn")
    parser.add_argument("--rounds", type=int, default=3, help="rounds of every setting")
    parser.add_argument("--target-fps", type=float, default=10.0, help="the session's target")
    args = parser.parse_args(argv)
    width, _, height = args.size.partition("x")
    args.width, args.height = int(width), int(height)
    if min(args.width, args.height, args.rounds) < 1 or min(args.seconds, args.warm) <= 0:
        parser.error("--size, --rounds, --seconds and --warm must be positive")
    return args


class Orbit(threading.Thread):
    """Moves the session's camera around the Cornell box every 0.1 s while ``moving``."""

    def __init__(self, http, session_id: str):
        super().__init__(daemon=True)
        self.http, self.session_id = http, session_id
        self.moving = threading.Event()
        self.stopped = False

    def run(self) -> None:
        angle = 0.0
        while not self.stopped:
            if self.moving.is_set():
                angle += 0.02
                camera = {"position": [0.5 * angle % 1.0 - 0.5, 0.0, 3.9], "look_at": [0, 0, 2.9]}
                self.http.put(f"/v1/sessions/{self.session_id}/camera", json=camera)
            time.sleep(0.1)


def measure(http, session_id: str, reader: StreamReader, seconds: float) -> dict:
    """The client's fps over ``seconds``, the frames the encoder dropped meanwhile and the
    session's stats at the end."""
    before = http.get(f"/v1/sessions/{session_id}").json()["stats"]
    start = time.perf_counter()
    time.sleep(seconds)
    end = time.perf_counter()
    stats = http.get(f"/v1/sessions/{session_id}").json()["stats"]
    return {
        "fps_client": sum(1 for a in reader.arrivals if start < a <= end) / (end - start),
        "spp": stats.get("spp"),
        "scale": stats.get("scale"),
        "render_ms": stats.get("render_ms"),
        "denoise_ms": stats.get("denoise_ms"),
        "dropped_per_second": (stats["frames_dropped"] - before["frames_dropped"]) / seconds,
    }


def _median(values: list) -> float | None:
    known = [v for v in values if v is not None]
    return statistics.median(known) if known else None


def main(argv: list[str] | None = None) -> None:
    import httpx

    args = parse_args(argv)
    info = machine_info()
    print_machine(info)
    samples: dict[tuple[str, str], list[dict]] = {}
    with tempfile.TemporaryDirectory() as data:
        process, url = start_server(Path(data), [])
        try:
            http = httpx.Client(base_url=url, timeout=60)
            scene = upload_cornell(http)
            body = {"scene_id": scene, "width": args.width, "height": args.height}
            session = http.post("/v1/sessions", json={**body, "target_fps": args.target_fps})
            session.raise_for_status()
            sid = session.json()["id"]
            reader = StreamReader(url + session.json()["stream_url"])
            reader.start()
            orbit = Orbit(http, sid)
            orbit.start()
            for _ in range(args.rounds):
                for motion in ("still", "orbiting"):
                    for quality in QUALITIES:
                        http.patch(f"/v1/sessions/{sid}", json={"denoise": quality})
                        if motion == "orbiting":
                            orbit.moving.set()
                        else:
                            orbit.moving.clear()
                        time.sleep(args.warm)
                        result = measure(http, sid, reader, args.seconds)
                        if quality == "off":  # the stats' mean still holds earlier turns'
                            result["denoise_ms"] = None
                        samples.setdefault((motion, quality), []).append(result)
            orbit.stopped = True
            reader.stopped = True
            http.delete(f"/v1/sessions/{sid}")
        finally:
            process.terminate()
            process.wait(30)
    rows, results = [], []
    for (motion, quality), runs in samples.items():
        median = {key: _median([run[key] for run in runs]) for key in runs[0]}
        results.append({"motion": motion, "denoise": quality, "median": median, "runs": runs})
        rows.append(
            (
                motion,
                quality,
                fmt_float(median["fps_client"], 1),
                fmt_float(median["spp"], 0),
                fmt_float(median["scale"], 2),
                fmt_float(median["render_ms"], 1),
                fmt_float(median["denoise_ms"], 1),
                fmt_float(median["dropped_per_second"], 1),
            )
        )
    print_table(
        f"a {args.size} session of the Cornell box (target {args.target_fps:g} fps), median of "
        f"{args.rounds} rounds of {args.seconds:g} s",
        ["camera", "denoise", "fps", "spp", "scale", "render ms", "denoise ms", "dropped/s"],
        rows,
    )
    write_results("session_denoise", {"options": vars(args), "results": results}, info)


if __name__ == "__main__":
    main()
