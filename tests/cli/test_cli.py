"""The ``tilerender`` command line: renders what the library renders, describes scenes, and
turns every bad input into exit code 2 with one line on stderr and no output file."""

import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from cli import main as cli_main
from cluster.scene_graph import SceneGraph
from tests.helpers import GLTF_BOX, ROOT, tiny_scene, write_json
from tracer import config
from tracer.compiled.scene import compile_scene
from tracer.io.images import read_image
from tracer.render import render_image, render_lines
from tracer.scene.format import override
from tracer.scene.loader import load_scene

TILERENDER = Path(sys.executable).with_name("tilerender")


def run(capsys, *argv) -> tuple[int, str, str]:
    """Run ``tilerender argv`` in-process; returns (exit code, stdout, stderr)."""
    code = cli_main.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_usage_error(code: int, err: str, *words: str) -> None:
    """Exit code 2 and exactly one non-empty stderr line, starting "error:", no traceback."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, err
    assert len(lines) == 1, f"expected one line on stderr, got: {err!r}"
    assert lines[0].startswith("error:") and "Traceback" not in err
    for word in words:
        assert word in lines[0], f"{word!r} not in {lines[0]!r}"


# --- rendering ------------------------------------------------------------------------------


OVERRIDES = ["--width", 10, "--height", 6, "--spp", 3, "--seed", 5, "--max-depth", 3]


@pytest.mark.parametrize(
    ("threads", "executor"), [(1, "--in-process"), (2, "--in-process"), (2, "--no-in-process")]
)
def test_render_npy_equals_the_library(capsys, tmp_path, tiny_scene_file, threads, executor):
    """`render -o x.npy` with overrides writes exactly render_image of the scene with those
    overrides applied (every bit), on any number of threads, in process or through Ray."""
    out = tmp_path / "out.npy"
    code, _, err = run(
        capsys,
        "render",
        tiny_scene_file,
        "-o",
        out,
        *OVERRIDES,
        "--threads",
        threads,
        executor,
        "-q",
    )
    assert code == 0, err
    assert err == ""
    scene = compile_scene(load_scene(tiny_scene_file))
    camera = override(scene.camera, width=10, height=6)
    settings = override(scene.render, spp=3, seed=5, max_depth=3)
    expected, _ = render_image(scene, camera, settings)
    got = read_image(out)
    assert got.dtype == np.float32 and got.shape == (6, 10, 3)
    assert np.array_equal(got, expected)
    assert got.max() > 0


def png_metadata(path: Path) -> dict:
    with Image.open(path) as image:
        return json.loads(image.text["tilerender"])


@pytest.mark.parametrize(
    ("options", "executor"),
    [
        ([], "in-process"),  # a small still
        (["--no-in-process"], "ray"),
        (["--tracers", 1], "ray"),
        (["--balancer", "none"], "ray"),
        (["--target-error", 0.5, "--max-spp", 4], "ray"),
    ],
    ids=["small", "no-in-process", "tracers", "balancer", "target-error"],
)
def test_render_chooses_where_to_run(capsys, tmp_path, tiny_scene_file, options, executor):
    """A small still renders in this process; cluster options, a quality goal or
    --no-in-process go through the coordinator (the image's metadata says which ran)."""
    out = tmp_path / "out.png"
    size = ["--width", 8, "--height", 4]
    spp = [] if "--target-error" in options else ["--spp", 1]  # the waves choose the spp
    code, _, err = run(capsys, "render", tiny_scene_file, "-o", out, *size, *spp, *options, "-q")
    assert code == 0, err
    metadata = png_metadata(out)
    assert metadata["executor"] == executor
    if "--target-error" in options:  # waves count their rays one by one: none is claimed
        assert metadata["rays"] is None
    else:  # the rays traced, however the frame was rendered: the library's count
        scene = compile_scene(load_scene(tiny_scene_file))
        camera = override(scene.camera, width=8, height=4)
        lines = render_lines(scene, 0, 4, camera, override(scene.render, spp=1))
        assert metadata["rays"] == int(lines.rays.sum()) >= 32


def test_large_stills_go_through_the_coordinator(tiny_scene_file):
    """The default moves to Ray past IN_PROCESS_SAMPLES pixel samples, whatever their shape."""
    from cli.commands.render import IN_PROCESS_SAMPLES, runs_in_process

    args = cli_main.build_parser().parse_args(["render", "x.json", "-o", "x.png"])
    state = load_scene(tiny_scene_file)

    def in_process(width: int, height: int, spp: int) -> bool:
        camera = override(state.camera, width=width, height=height)
        settings = override(state.render, spp=spp)
        return runs_in_process(args, camera, settings, still=True, progressive=False)

    assert IN_PROCESS_SAMPLES == 256 * 256 * 64
    assert in_process(256, 256, 64) and in_process(2048, 2048, 1)
    assert not in_process(256, 256, 65) and not in_process(2049, 2048, 1)
    assert not in_process(64, 64, 1 << 11)
    assert not runs_in_process(
        args, state.camera, override(state.render, spp=1), still=False, progressive=False
    )


@pytest.mark.parametrize(
    ("options", "words"),
    [
        (["--tracers", 2], ["--in-process", "--tracers"]),
        (["--ray-address", "auto", "--balancer", "none"], ["--ray-address", "--balancer"]),
        (["--target-error", 0.1], ["--in-process", "--target-error"]),
    ],
)
def test_in_process_refuses_cluster_options(capsys, tmp_path, tiny_scene_file, options, words):
    """--in-process with a cluster option or a quality goal: one line, exit 2, no file."""
    out = tmp_path / "out.png"
    code, _, err = run(capsys, "render", tiny_scene_file, "-o", out, "--in-process", *options)
    assert_usage_error(code, err, *words)
    assert not out.exists()


def test_render_with_tracers_and_a_balancer(capsys, tmp_path, tiny_scene_file):
    """--tracers and --balancer change which tracer renders which lines, never the pixels."""
    out = tmp_path / "out.npy"
    options = ["--tracers", 3, "--balancer", "robin-hood", "-q"]
    code, _, err = run(capsys, "render", tiny_scene_file, "-o", out, *OVERRIDES, *options)
    assert code == 0, err
    assert err == ""
    scene = compile_scene(load_scene(tiny_scene_file))
    camera = override(scene.camera, width=10, height=6)
    settings = override(scene.render, spp=3, seed=5, max_depth=3)
    assert np.array_equal(read_image(out), render_image(scene, camera, settings)[0])


def animated_scene(frames: int = 4) -> dict:
    """tiny_scene with the cube (made rigid) sliding and turning, and the camera moving."""
    data = tiny_scene()
    data["objects"][1]["kind"] = "rigid"
    data["animation"] = {
        "fps": 4,
        "frames": frames,
        "objects": {
            "cube": [
                {"time": 0, "translate": [0, 0.5, 0]},
                {"time": 1, "translate": [0.8, 0.5, -0.5], "rotate": [0, 90, 0]},
            ]
        },
        "camera": [{"time": 0}, {"time": 1, "position": [1.0, 2.0, 4.0]}],
    }
    return data


def test_render_animation_writes_each_frame(capsys, tmp_path):
    """On an animated scene `render` writes OUT_NNNN per selected frame, each exactly the
    library's render of that frame's pose (frame number in the random keys), and prints a
    timing line with the idle percentage per frame."""
    scene = write_json(tmp_path / "anim.json", animated_scene(frames=4))
    out = tmp_path / "shot.npy"
    argv = ["--frames", "1-3", "--tracers", 2, "--width", 16, "--height", 12, "--spp", 2]
    code, stdout, err = run(capsys, "render", scene, "-o", out, *argv)
    assert code == 0, err
    assert stdout == ""
    names = sorted(p.name for p in tmp_path.glob("shot*"))
    assert names == ["shot_0001.npy", "shot_0002.npy", "shot_0003.npy"]
    state = load_scene(scene)
    state = dataclasses.replace(
        state,
        camera=override(state.camera, width=16, height=12),
        render=override(state.render, spp=2),
    )
    graph = SceneGraph(state)
    images = []
    for number in range(4):
        graph.frame_commit(number)
        if number == 0:
            continue
        expected = render_image(compile_scene(graph.state), frame=number)[0]
        images.append(read_image(tmp_path / f"shot_{number:04d}.npy"))
        assert np.array_equal(images[-1], expected), number
        assert f"frame {number}: shot_{number:04d}.npy" in err
    assert not np.array_equal(images[0], images[-1])
    assert err.count("idle") >= 3 and "wrote 3 frames" in err


def test_render_overrides_change_the_image(capsys, tmp_path, tiny_scene_file):
    """--seed and --max-depth reach the renderer: each changes the image."""
    images = {}
    for name, extra in [("base", []), ("seed", ["--seed", 99]), ("depth", ["--max-depth", 1])]:
        out = tmp_path / f"{name}.npy"
        code, _, err = run(capsys, "render", tiny_scene_file, "-o", out, "--spp", 2, "-q", *extra)
        assert code == 0, err
        images[name] = read_image(out)
    assert not np.array_equal(images["base"], images["seed"])
    # max_depth 1 shows only emitters seen directly: a darker image.
    assert images["depth"].sum() < images["base"].sum()


@pytest.mark.parametrize("suffix", [".png", ".exr"])
def test_render_png_and_exr(capsys, tmp_path, tiny_scene_file, suffix):
    """PNG and EXR outputs have the requested size and carry the settings as metadata; the
    progress summary goes to stderr unless -q."""
    out = tmp_path / f"out{suffix}"
    code, stdout, err = run(
        capsys, "render", tiny_scene_file, "-o", out, "--width", 9, "--height", 5, "--spp", 1
    )
    assert code == 0, err
    assert stdout == ""
    assert "wrote" in err and "9x5" in err
    assert read_image(out).shape == (5, 9, 3)
    if suffix == ".png":
        with Image.open(out) as image:
            metadata = json.loads(image.text["tilerender"])
        assert metadata["camera"]["width"] == 9 and metadata["render"]["spp"] == 1
        assert "area_lights" in metadata["effect_plan"]["effects"]
        assert "sky" in metadata["effect_plan"]["skipped"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out" + suffix, "scene.json"]


def test_render_mesh_file_alone(capsys, tmp_path):
    """A glTF file alone renders (framing camera, default light) to a non-black image."""
    out = tmp_path / "box.npy"
    code, _, err = run(
        capsys, "render", GLTF_BOX, "-o", out, "--width", 16, "--height", 12, "--spp", 2, "-q"
    )
    assert code == 0, err
    rgb = read_image(out)
    assert rgb.shape == (12, 16, 3) and rgb.mean() > 0.01


@pytest.mark.parametrize("executor", ["--in-process", "--no-in-process"])
def test_interrupted_render_writes_nothing(
    capsys, tmp_path, tiny_scene_file, monkeypatch, executor
):
    """Ctrl-C during a render exits with 130 and one line, and writes no file."""
    from cli import in_process
    from cluster.coordinator import Coordinator

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(Coordinator, "render_frame", interrupt)
    monkeypatch.setattr(in_process, "render_image", interrupt)
    out = tmp_path / "out.png"
    code, _, err = run(capsys, "render", tiny_scene_file, "-o", out, "--spp", 1, executor, "-q")
    assert code == 130
    assert err.strip().splitlines() == ["interrupted; nothing written"]
    assert not out.exists()


# --- info, help, schema ---------------------------------------------------------------------


def test_info_prints_json(capsys, tiny_scene_file):
    """`info` prints one JSON document describing the compiled scene."""
    code, out, err = run(capsys, "info", tiny_scene_file)
    assert code == 0, err
    report = json.loads(out)
    scene = compile_scene(load_scene(tiny_scene_file))
    assert report["triangles"] == scene.stats.triangles == 16
    assert report["emissive_triangles"] == 2
    assert report["zero_area_triangles_dropped"] == 0
    assert report["materials"] == ["grey", "lamp"]
    assert report["camera"]["width"] == 12 and report["render"]["spp"] == 2
    assert report["bvh_nodes"] == sum(pool.bounds.shape[0] for pool in scene.pools)
    assert report["nodes"] == 3 and report["instances"] == scene.stats.instances == 1
    assert report["bounds"]["min"] == list(scene.stats.bounds_min)


def test_plan_prints_the_effect_plan(capsys, tmp_path):
    """`plan` prints the effects a render runs and skips, each with its rule; options change
    the plan as they would change a render."""
    code, out, err = run(capsys, "plan", ROOT / "scenes" / "cornell-box" / "scene.json")
    assert code == 0, err
    report = json.loads(out)
    assert report["integrator"] == "path"
    assert {"area_lights", "light_samples", "shadows", "indirect"} <= set(report["effects"])
    assert {"sky", "sun", "refraction", "specular", "glossy"} <= set(report["skipped"])
    assert report["reasons"]["refraction"] == "no dielectric"
    code, out, err = run(
        capsys, "plan", ROOT / "scenes" / "cornell-box" / "scene.json", "--integrator", "ao"
    )
    assert code == 0, err
    assert "light_samples" in json.loads(out)["skipped"]
    switched = tmp_path / "scene.json"
    write_json(switched, tiny_scene(render={"effects": {"shadows": False}}))
    code, out, err = run(capsys, "plan", switched)
    assert json.loads(out)["reasons"]["shadows"] == "switched off in render.effects"


def test_kernel_option_on_plan_and_render(capsys, tmp_path, tiny_scene_file):
    """`--kernel` picks the kernel: `plan` reports it with its reason, `render` writes the same
    pixels with either, and an unknown kernel is a usage error (exit code 2)."""
    cornell = ROOT / "scenes" / "cornell-box" / "scene.json"
    code, out, err = run(capsys, "plan", cornell)
    assert code == 0, err
    assert json.loads(out)["kernel"] == "single"
    code, out, err = run(capsys, "plan", cornell, "--kernel", "stream")
    report = json.loads(out)
    assert report["kernel"] == "stream" and report["kernel_reason"] == "set in render.kernel"
    images = {}
    for kernel in ("single", "stream"):
        out_file = tmp_path / f"{kernel}.npy"
        args = ("-o", out_file, "--width", 8, "--height", 6, "--spp", 2, "-q", "--kernel", kernel)
        code, _, err = run(capsys, "render", tiny_scene_file, *args)
        assert code == 0, err
        images[kernel] = read_image(out_file)
    assert images["single"].tobytes() == images["stream"].tobytes()
    code, _, err = run(capsys, "plan", cornell, "--kernel", "gpu")
    assert_usage_error(code, err)
    assert "invalid choice: 'gpu'" in err


def test_light_sampler_option_on_plan_and_render(capsys, tmp_path):
    """`--light-sampler` picks how light samples pick emissive triangles: `plan` reports it and
    why (auto: by the scene's count), `render` writes an image with either, and an unknown
    sampler is a usage error (exit code 2)."""
    cornell = ROOT / "scenes" / "cornell-box" / "scene.json"
    code, out, err = run(capsys, "plan", cornell)
    assert code == 0, err
    report = json.loads(out)
    assert report["light_sampler"] == "power" and "2 emissive" in report["reasons"]["light_tree"]
    code, out, err = run(capsys, "plan", cornell, "--light-sampler", "tree")
    report = json.loads(out)
    assert report["light_sampler"] == "tree"
    assert report["reasons"]["light_tree"] == "set in render.light_sampler"
    for sampler in ("power", "tree"):
        out_file = tmp_path / f"{sampler}.npy"
        args = ("-o", out_file, "--width", 8, "--height", 6, "--spp", 2, "-q")
        code, _, err = run(capsys, "render", cornell, *args, "--light-sampler", sampler)
        assert code == 0, err
        assert read_image(out_file).max() > 0.0
    code, _, err = run(capsys, "plan", cornell, "--light-sampler", "bvh")
    assert_usage_error(code, err)


def test_plan_and_info_show_textures(capsys, tmp_path):
    """The textured sample scene's plan runs texture lookups and says why; `info` lists its
    images (width, height); a missing texture is a usage error (exit code 2), not a crash."""
    textured = ROOT / "scenes" / "textured" / "scene.json"
    code, out, err = run(capsys, "plan", textured)
    assert code == 0, err
    report = json.loads(out)
    assert "textures" in report["effects"]
    assert report["reasons"]["textures"] == "textured materials"
    code, out, err = run(capsys, "plan", ROOT / "scenes" / "cornell-box" / "scene.json")
    assert "textures" in json.loads(out)["skipped"]
    code, out, err = run(capsys, "info", textured)
    assert code == 0, err
    assert json.loads(out)["textures"]["tiles.png"] == [32, 32]
    data = tiny_scene()
    data["materials"]["grey"]["texture"] = {"file": "missing.png"}
    code, out, err = run(capsys, "info", write_json(tmp_path / "scene.json", data))
    assert code == 2 and "missing.png" in err


def test_render_integrator_option(capsys, tmp_path, tiny_scene_file):
    """--integrator reaches the renderer: the albedo output is the library's."""
    out = tmp_path / "albedo.npy"
    code, _, err = run(
        capsys, "render", tiny_scene_file, "-o", out, "--integrator", "albedo", "--spp", 1, "-q"
    )
    assert code == 0, err
    scene = compile_scene(load_scene(tiny_scene_file))
    expected, _ = render_image(scene, settings=override(scene.render, spp=1, integrator="albedo"))
    assert np.array_equal(read_image(out), expected)


def test_cli_integrators_are_the_registrys(capsys):
    """--integrator offers exactly the registry's integrators and refuses another name."""
    from tracer.integrators.registry import NAMES

    commands = cli_main.build_parser()._subparsers._group_actions[0].choices
    for command in ("render", "plan"):
        option = next(a for a in commands[command]._actions if a.dest == "integrator")
        assert tuple(option.choices) == NAMES, command
    code, _, err = run(capsys, "render", "scene.json", "--integrator", "no-such")
    assert code == 2 and "no-such" in err


def test_info_counts_dropped_triangles(capsys, tmp_path):
    """`info` reports zero-area triangles the compiler dropped."""
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n")
    code, out, err = run(capsys, "info", tmp_path / "m.obj")
    assert code == 0, err
    assert json.loads(out)["zero_area_triangles_dropped"] == 1


@pytest.mark.parametrize("argv", [["--help"], ["render", "--help"], ["samples", "--help"]])
def test_help(capsys, argv):
    """--help prints usage to stdout and exits 0."""
    with pytest.raises(SystemExit) as info:
        cli_main.main(argv)
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert "usage: tilerender" in out
    if argv == ["--help"]:
        assert all(word in out for word in ("render", "samples", "info", "plan", "schema"))
    if argv[0] == "render":
        assert all(f"--{o}" in out for o in ("spp", "width", "height", "seed", "max-depth"))
        assert all(f"--{o}" in out for o in ("tracers", "balancer", "ray-address", "frames"))


def test_schema_is_json(capsys):
    """`schema` prints the scene file's JSON Schema."""
    code, out, _ = run(capsys, "schema")
    assert code == 0
    schema = json.loads(out)
    assert "camera" in schema["properties"] and "objects" in schema["required"]


# --- bad input ------------------------------------------------------------------------------


BIG = config.MAX_IMAGE_SIDE + 1
OUT = "{tmp}/out.png"
BAD_INPUT = {
    # name: (argv with {tmp} and {scene} placeholders, words the error line must contain)
    "missing scene": (["render", "{tmp}/nope.json", "-o", OUT], ["nope.json"]),
    "bad json": (["render", "{tmp}/bad.json", "-o", OUT], ["not valid JSON"]),
    "unknown key": (["render", "{tmp}/unknown.json", "-o", OUT], ["lamps", "unknown key"]),
    "spp 0": (["render", "{scene}", "-o", OUT, "--spp", "0"], ["--spp", "at least 1"]),
    "spp abc": (["render", "{scene}", "-o", OUT, "--spp", "abc"], ["--spp", "'abc'"]),
    "spp negative": (["render", "{scene}", "-o", OUT, "--spp", "-3"], ["--spp"]),
    "spp too many": (["render", "{scene}", "-o", OUT, "--spp", str(config.MAX_SPP + 1)], ["spp"]),
    "width 0": (["render", "{scene}", "-o", OUT, "--width", "0"], ["--width"]),
    "width above max": (["render", "{scene}", "-o", OUT, "--width", str(BIG)], ["width", "16384"]),
    "height above max": (["render", "{scene}", "-o", OUT, "--height", str(BIG)], ["height"]),
    "too many pixels": (
        ["render", "{scene}", "-o", OUT, "--width", "16384", "--height", "16384"],
        ["pixels"],
    ),
    "seed negative": (["render", "{scene}", "-o", OUT, "--seed", "-1"], ["--seed"]),
    "seed too big": (["render", "{scene}", "-o", OUT, "--seed", str(2**63)], ["seed"]),
    "max-depth 0": (["render", "{scene}", "-o", OUT, "--max-depth", "0"], ["--max-depth"]),
    "threads 0": (["render", "{scene}", "-o", OUT, "--threads", "0"], ["--threads"]),
    "unknown extension": (["render", "{scene}", "-o", "{tmp}/out.jpg"], [".jpg", ".png"]),
    "no extension": (["render", "{scene}", "-o", "{tmp}/out"], ["unknown image format"]),
    "missing output dir": (
        ["render", "{scene}", "-o", "{tmp}/none/out.png"],
        ["does not exist"],
    ),
    "output is a directory": (["render", "{scene}", "-o", "{tmp}/dir.png"], ["directory"]),
    "output parent is a file": (["render", "{scene}", "-o", "{tmp}/bad.json/out.png", "-q"], []),
    "reference outside dir": (["render", "{tmp}/inner/escape.json", "-o", OUT], ["stolen.obj"]),
    "environment map missing": (
        ["render", "{tmp}/env-missing.json", "-o", OUT],
        ["sky", "nope.exr", "no such file"],
    ),
    "environment map outside dir": (
        ["render", "{tmp}/inner/env-escape.json", "-o", OUT],
        ["sky", "may not leave"],
    ),
    "environment map bad shape": (
        ["render", "{tmp}/env-shape.json", "-o", OUT],
        ["sky", "(H, W, 3)"],
    ),
    "no output option": (["render", "{scene}"], ["-o/--output"]),
    "unknown option": (["render", "{scene}", "-o", OUT, "--fast"], ["--fast"]),
    "unknown command": (["draw", "{scene}"], ["draw"]),
    "no command": ([], ["required"]),
    "info missing scene": (["info", "{tmp}/nope.json"], ["nope.json"]),
    "info bad json": (["info", "{tmp}/bad.json"], ["not valid JSON"]),
    "unknown balancer": (
        ["render", "{scene}", "-o", OUT, "--balancer", "fastest"],
        ["fastest", "cost-aware", "robin-hood"],
    ),
    "unreachable ray": (
        ["render", "{scene}", "-o", OUT, "--ray-address", "127.0.0.1:1"],
        ["127.0.0.1:1", "cannot reach"],
    ),
    "bad ray address": (["render", "{scene}", "-o", OUT, "--ray-address", "nowhere"], ["nowhere"]),
    "tracers 0": (["render", "{scene}", "-o", OUT, "--tracers", "0"], ["--tracers"]),
    "frames on a still scene": (
        ["render", "{scene}", "-o", OUT, "--frames", "0"],
        ["--frames", "no animation"],
    ),
    "frames past the end": (["render", "{anim}", "-o", OUT, "--frames", "2-9"], ["0-3"]),
    "frames not a range": (["render", "{anim}", "-o", OUT, "--frames", "two"], ["'two'"]),
    "samples no dir": (["samples", "--scenes", "{tmp}/none", "--out", "{tmp}"], ["none"]),
    "samples empty dir": (["samples", "--scenes", "{tmp}/inner", "--out", "{tmp}"], ["no sample"]),
}


@pytest.fixture
def bad_files(tmp_path):
    """The broken inputs BAD_INPUT refers to, in tmp_path."""
    (tmp_path / "bad.json").write_text('{"camera": ')
    write_json(tmp_path / "unknown.json", tiny_scene(lamps=[]))
    (tmp_path / "inner").mkdir()
    data = tiny_scene()
    data["objects"][1]["shape"] = "../stolen.obj"
    (tmp_path / "stolen.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    write_json(tmp_path / "inner" / "escape.json", data)
    (tmp_path / "dir.png").mkdir()
    write_json(tmp_path / "anim.json", animated_scene(frames=4))
    np.save(tmp_path / "sky.npy", np.ones((4, 8, 3), np.float32))
    np.save(tmp_path / "flat.npy", np.ones((4, 8), np.float32))
    for name, file in [("env-missing.json", "nope.exr"), ("inner/env-escape.json", "../sky.npy"),
                       ("env-shape.json", "flat.npy")]:  # fmt: skip
        write_json(tmp_path / name, tiny_scene(sky={"type": "environment", "file": file}))
    return tmp_path


@pytest.mark.parametrize("case", list(BAD_INPUT))
def test_bad_input(capsys, bad_files, tiny_scene_file, case):
    """Each bad input exits with 2 and one "error:" line on stderr, no traceback, and no
    output file."""
    template, words = BAD_INPUT[case]
    argv = [
        a.format(tmp=bad_files, scene=tiny_scene_file, anim=bad_files / "anim.json")
        for a in template
    ]
    before = sorted(bad_files.rglob("*"))
    code, out, err = run(capsys, *argv)
    assert_usage_error(code, err, *words)
    assert out == ""
    assert sorted(bad_files.rglob("*")) == before, "something was written"


def test_dot_reference_is_a_usage_error(capsys, tmp_path):
    """A scene whose mesh path is "." is bad input: exit code 2, one line."""
    data = tiny_scene()
    data["objects"][1]["shape"] = "."
    scene = write_json(tmp_path / "scene.json", data)
    code, _, err = run(capsys, "render", scene, "-o", tmp_path / "out.png")
    assert_usage_error(code, err)


def test_deeply_nested_json_is_a_usage_error(capsys, tmp_path):
    """A scene file of 100,000 nested brackets is bad input: exit code 2, one line."""
    scene = tmp_path / "scene.json"
    scene.write_text("[" * 100_000 + "]" * 100_000)
    code, _, err = run(capsys, "info", scene)
    assert_usage_error(code, err, "JSON")


@pytest.mark.slow  # numba spends ~20 s before it gives up typing the kernel
def test_huge_rr_depth_is_refused_or_rendered(capsys, tmp_path):
    """A scene with rr_depth = 2**64 either is refused as bad input or renders."""
    data = tiny_scene()
    data["render"]["rr_depth"] = 2**64
    scene = write_json(tmp_path / "scene.json", data)
    out = tmp_path / "out.npy"
    code, _, err = run(capsys, "render", scene, "-o", out, "-q")
    if code == 0:
        assert out.exists()
    else:
        assert_usage_error(code, err, "rr_depth")


# --- the real console script ----------------------------------------------------------------


def script(*argv, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(TILERENDER), *map(str, argv)], capture_output=True, text=True, cwd=cwd, timeout=300
    )


@pytest.mark.skipif(not TILERENDER.exists(), reason="console script not installed")
def test_console_script_exit_codes(tmp_path, tiny_scene_file):
    """The installed `tilerender` exits 2 with one line for bad input and 0 for a render."""
    result = script("render", tmp_path / "nope.json", "-o", tmp_path / "out.png")
    assert_usage_error(result.returncode, result.stderr, "nope.json")
    result = script(
        "render",
        tiny_scene_file,
        "-o",
        tmp_path / "out.png",
        "--spp",
        3,
        "--width",
        4,
        "--height",
        4,
    )
    assert result.returncode == 0, result.stderr
    assert read_image(tmp_path / "out.png").shape == (4, 4, 3)
    assert "Traceback" not in result.stderr


@pytest.mark.skipif(not TILERENDER.exists(), reason="console script not installed")
def test_console_script_overflowing_transform(tmp_path):
    """A transform whose determinant overflows is one line of error, even in a real process
    where Python prints warnings."""
    data = tiny_scene()
    data["objects"][1]["transform"] = {"scale": 1e300}
    scene = write_json(tmp_path / "scene.json", data)
    result = script("render", scene, "-o", tmp_path / "out.png")
    assert_usage_error(result.returncode, result.stderr, "singular")


# --- samples --------------------------------------------------------------------------------


def test_samples(capsys, tmp_path):
    """`samples` renders each folder's scene.json (or its one glTF) to <folder>.png and .exr,
    skipping folders without a scene."""
    scenes = tmp_path / "scenes"
    for name in ("alpha", "empty", "model"):
        (scenes / name).mkdir(parents=True)
    write_json(scenes / "alpha" / "scene.json", tiny_scene())
    shutil.copy(GLTF_BOX, scenes / "model" / "Box.gltf")
    out = tmp_path / "renders"
    code, _, err = run(capsys, "samples", "--scenes", scenes, "--out", out, "--spp", 1, "-q")
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == [
        "alpha.exr",
        "alpha.png",
        "model.exr",
        "model.png",
    ]
    assert read_image(out / "alpha.exr").shape == (8, 12, 3)
    assert read_image(out / "model.png").shape == (480, 640, 3)


def test_readme_sample_scenes_exist():
    """The scenes the README and `samples` rely on are in the repository."""
    from cli.commands.samples import REPO_SCENES, sample_scene_files

    assert REPO_SCENES == ROOT / "scenes"
    names = {p.parent.name for p in sample_scene_files(REPO_SCENES)}
    assert {"cornell-box", "gltf-box", "nefertiti", "studio"} <= names


# --- serve ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "argv,words",
    [
        (["--ray-address", "127.0.0.1:1"], ["cannot reach Ray"]),
        (["--ray-address", "no-port"], ["not a Ray address"]),
        (["--balancer", "fastest"], ["unknown balancer"]),
        (["--port", "70000"], ["65535"]),
        (["--token", "short"], ["token"]),
        (["--tracers", "0"], ["at least 1"]),
    ],
)
def test_serve_refuses_bad_options(capsys, tmp_path, argv, words):
    """`serve` checks its options (and that a cluster address answers) before starting
    anything: one line, exit code 2."""
    code, _, err = run(capsys, "serve", "--data-dir", tmp_path, *argv)
    assert_usage_error(code, err, *words)


def test_serve_port_in_use(capsys, tmp_path):
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code, _, err = run(capsys, "serve", "--data-dir", tmp_path, "--port", port)
    assert_usage_error(code, err, "cannot listen")


@pytest.mark.skipif(not TILERENDER.exists(), reason="console script not installed")
def test_serve_prints_the_viewer_url_and_stops_on_ctrl_c(tmp_path):
    """`serve --port 0` prints the viewer's URL, answers /readyz and the viewer page on it,
    and exits 0 on SIGINT."""
    import httpx

    from tests.api.conftest import start_server

    server = start_server(tmp_path / "data", "--tracers", "1", "--threads", "1")
    try:
        assert server.url.startswith("http://127.0.0.1:")
        assert httpx.get(server.url + "/readyz").json()["status"] == "ready"
        page = httpx.get(server.url + "/")
        assert page.status_code == 200 and "tilerender" in page.text
        assert (tmp_path / "data" / "tilerender.db").is_file()
    finally:
        assert server.stop() == 0


def test_serve_balancer_flag_overrides_the_environment_only_when_given(monkeypatch):
    """TILERENDER_BALANCER holds unless --balancer is given (the flag has no default of its
    own that would hide the variable)."""
    from cli.commands.serve import serve_settings

    monkeypatch.setenv("TILERENDER_BALANCER", "perfect")
    parser = cli_main.build_parser()
    assert serve_settings(parser.parse_args(["serve"])).balancer == "perfect"
    given = parser.parse_args(["serve", "--balancer", "none"])
    assert serve_settings(given).balancer == "none"


# --- exit codes -----------------------------------------------------------------------------


def _cluster_error():
    from cluster.errors import ClusterError

    return ClusterError("no tracer is left to render with")


def _scene_error():
    from tracer.errors import SceneError

    return SceneError("camera.width: too wide")


def _usage_error():
    from cli.errors import UsageError

    return UsageError("--frames: the scene has no animation")


def _command_failed():
    from cli.errors import CommandFailed

    return CommandFailed("Ray did not start")


@pytest.mark.parametrize(
    "make,code,words",
    [
        (_usage_error, 2, ["error: --frames"]),
        (_scene_error, 2, ["error: camera.width"]),
        (_cluster_error, 1, ["error: no tracer is left"]),
        (_command_failed, 1, ["error: Ray did not start"]),
        (lambda: KeyError("boom"), 1, ["internal error", "KeyError", "a bug"]),
        (lambda: ValueError("boom"), 1, ["internal error", "ValueError", "a bug"]),
        (lambda: OSError("boom"), 1, ["internal error", "OSError", "a bug"]),
    ],
)
def test_exceptions_map_to_exit_codes(capsys, monkeypatch, tiny_scene_file, make, code, words):
    """tilerender's own errors are the user's (2) or a render the cluster could not finish
    (1); any other exception is a bug: exit 1 and one line that says so, not a usage error."""
    from cli.commands import info

    def fail(args):
        raise make()

    monkeypatch.setattr(info, "run", fail)
    got, out, err = run(capsys, "info", tiny_scene_file)
    lines = [line for line in err.splitlines() if line.strip()]
    assert got == code, err
    assert len(lines) == 1 and "Traceback" not in err and out == ""
    assert all(word in lines[0] for word in words), lines[0]


def test_an_unwritable_output_is_a_user_error(capsys, monkeypatch, tmp_path, tiny_scene_file):
    """An OSError writing the image (here its directory vanished) is the user's to fix: exit
    2, one line naming the file."""
    from cli import output

    def vanished(path, rgb, metadata=None):
        raise FileNotFoundError(2, "No such file or directory", str(path))

    monkeypatch.setattr(output, "write_image", vanished)
    out = tmp_path / "out.npy"
    code, _, err = run(capsys, "render", tiny_scene_file, "-o", out, "--spp", 1, "-q")
    assert_usage_error(code, err, "cannot write", "out.npy", "No such file")
    assert not out.exists()


@pytest.mark.parametrize(("flag", "mode"), [("--adaptive", "on"), ("--no-adaptive", "off")])
def test_adaptive_sampling_switches(capsys, tmp_path, tiny_scene_file, flag, mode):
    """--adaptive / --no-adaptive choose the progressive frame's sampling; the metadata says
    which, with its mean samples per pixel, which --max-spp bounds (to within a wave's rounding
    up, under 4 samples) while the sample range may exceed it; with a fixed --spp they are a
    usage error."""
    out = tmp_path / "out.png"
    size = ["--width", 24, "--height", 16]
    goal = ["--target-error", 1e-4, "--max-spp", 64]
    code, _, err = run(capsys, "render", tiny_scene_file, "-o", out, *size, *goal, flag, "-q")
    assert code == 0, err
    progressive = png_metadata(out)["progressive"]
    assert progressive["adaptive"] == mode
    if mode == "off":
        assert progressive["adaptive_waves"] == 0
        assert progressive["spp"] == progressive["mean_spp"] == 64
    else:
        assert progressive["adaptive_waves"] >= 1 and abs(progressive["mean_spp"] - 64) < 4
        assert progressive["spp"] >= progressive["mean_spp"]
    code, _, err = run(capsys, "render", tiny_scene_file, "-o", out, "--spp", 2, flag)
    assert_usage_error(code, err, flag, "--target-error")
