"""`tilerender render --target-error / --time-budget`: renders in waves through the cluster
until the estimated error or the budget, writes the mean of every sample taken and says in the
image's metadata what it estimated and why it stopped; bad combinations are usage errors."""

import json

import numpy as np
import pytest
from PIL import Image

from cli import main as cli_main
from tests.helpers import tiny_scene, write_json
from tracer.compiled.scene import compile_scene
from tracer.io.images import read_image
from tracer.render import render_image
from tracer.scene.format import override
from tracer.scene.loader import load_scene

SIZE = ["--width", 16, "--height", 12, "--threads", 1]


def run(capsys, *argv):
    code = cli_main.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def png_metadata(path) -> dict:
    with Image.open(path) as image:
        return json.loads(image.text["tilerender"])


def test_target_error(capsys, tmp_path, tiny_scene_file):
    """The image is the library's render of the samples taken (the parts tile samples
    [0, spp)), and the estimate met the target."""
    png, npy = tmp_path / "out.png", tmp_path / "out.npy"
    for out in (png, npy):
        code, _, err = run(capsys, "render", tiny_scene_file, "-o", out, *SIZE,
                           "--target-error", 0.1, "-q")  # fmt: skip
        assert code == 0, err
    progressive = png_metadata(png)["progressive"]
    assert progressive["stopped"] == "target_error"
    assert progressive["error_estimate"] <= 0.1
    assert progressive["spot_checks"] == 0  # 192 pixels: too few to spot-check
    spp = progressive["spp"]
    assert png_metadata(png)["render"]["spp"] == spp
    scene = compile_scene(load_scene(tiny_scene_file))
    camera = override(scene.camera, width=16, height=12)
    expected = render_image(scene, camera, override(scene.render, spp=spp))[0]
    np.testing.assert_allclose(read_image(npy), expected, rtol=1e-5, atol=1e-6)


def test_larger_images_are_spot_checked(capsys, tmp_path, tiny_scene_file, spot_check_calls):
    """From 512 pixels on, waves spot-check pixels (here 32x24: one at a time) through the
    coordinator before their estimate; the metadata says how many the last estimate used."""
    out = tmp_path / "out.png"
    code, _, err = run(capsys, "render", tiny_scene_file, "-o", out, "--width", 32,
                       "--height", 24, "--target-error", 0.1, "-q")  # fmt: skip
    assert code == 0, err
    progressive = png_metadata(out)["progressive"]
    assert progressive["stopped"] == "target_error" and progressive["spot_checks"] <= 1
    assert spot_check_calls and set(spot_check_calls) == {1}


def test_time_budget_and_max_spp(capsys, tmp_path, tiny_scene_file):
    """A generous budget on a tiny image: the sample cap ends the render first; the message
    says how many samples were taken and why it stopped."""
    out = tmp_path / "out.png"
    code, _, err = run(capsys, "render", tiny_scene_file, "-o", out, *SIZE,
                       "--time-budget", 600, "--max-spp", 8)  # fmt: skip
    assert code == 0, err
    progressive = png_metadata(out)["progressive"]
    assert progressive["stopped"] == "max_spp" and progressive["spp"] == 8
    assert progressive["time_budget"] == 600
    assert "8 spp" in err and "--max-spp reached" in err


def test_animation_shares_the_budget(capsys, tmp_path):
    """An animation's budget is shared by its frames; each frame gets its own estimate."""
    scene = tiny_scene()
    scene["animation"] = {
        "fps": 4,
        "frames": 2,
        "camera": [{"time": 0}, {"time": 1, "position": [1.0, 2.0, 4.0]}],
    }
    path = write_json(tmp_path / "anim.json", scene)
    out = tmp_path / "f.png"
    code, _, err = run(capsys, "render", path, "-o", out, *SIZE, "--time-budget", 400,
                       "--max-spp", 4, "-q")  # fmt: skip
    assert code == 0, err
    for name in ("f_0000.png", "f_0001.png"):
        progressive = png_metadata(tmp_path / name)["progressive"]
        assert progressive["time_budget"] == 200 and progressive["spp"] == 4


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--target-error", "0"], ["--target-error", "positive"]),
        (["--target-error", "nan"], ["--target-error"]),
        (["--time-budget", "-1"], ["--time-budget", "positive"]),
        (["--time-budget", "inf"], ["--time-budget"]),
        (["--target-error", "0.1", "--spp", "4"], ["--spp", "--max-spp"]),
        (["--max-spp", "64"], ["--max-spp", "--target-error"]),
        (["--target-error", "0.1", "--max-spp", "3"], ["--max-spp", "at least 4"]),
    ],
)
def test_bad_quality_options(capsys, tmp_path, tiny_scene_file, argv, words):
    out = tmp_path / "out.png"
    code, _, err = run(capsys, "render", tiny_scene_file, "-o", out, *argv)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error:"), err
    assert all(w in lines[0] for w in words), lines[0]
    assert not out.exists()
