"""The accuracy study's report: JSON, a markdown page, PNG plots and image strips.

``write_report`` writes ``accuracy.json``, ``report.md`` and the PNGs into one folder; with
``docs`` it also puts the PNGs in ``docs/accuracy/`` and the markdown into ``docs/accuracy.md``
between the ``REPORT_START`` and ``REPORT_END`` markers (the hand-written guide around them is
kept).
"""

import datetime as dt
import json
from pathlib import Path

import numpy as np

from cli.accuracy_plots import (
    CALIBRATION_BAND,
    DENOISED_BAND,
    calibration_records,
    write_plots,
)
from cli.accuracy_sweep import DEFAULT_CONFIG
from tracer.accuracy.denoised_error import MIN_PART_SPP
from tracer.accuracy.error_estimate import PARTS, SPOT_CHECK_FACTOR, SPOT_CHECKS

REPORT_START = "<!-- accuracy-report:start -->"
REPORT_END = "<!-- accuracy-report:end -->"
DENOISED_SHARE = 0.8
"""Issue 24's goal: the denoised image's estimate within ``DENOISED_BAND`` of its true error at
this share of the study's levels or more."""


def write_report(
    results: dict, images: dict, out_dir: Path, docs_page: Path | None = None, command: str = ""
) -> list[Path]:
    """Write everything into ``out_dir`` (and into ``docs_page`` and the folder beside it named
    after it, when given); returns the files written."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written = [out_dir / "accuracy.json", out_dir / "images.npz"]
    written[0].write_text(json.dumps(results, indent=2, default=_json_default) + "\n")
    save_images(images, written[1])
    image_dirs = [out_dir]
    if docs_page is not None:
        image_dirs.append(docs_page.with_suffix(""))
    for folder in image_dirs:
        folder.mkdir(parents=True, exist_ok=True)
        written += write_plots(results, images, folder)
    (out_dir / "report.md").write_text(markdown(results, ".", command))
    written.append(out_dir / "report.md")
    if docs_page is not None:
        relative = docs_page.with_suffix("").name
        splice(docs_page, markdown(results, relative, command))
        written.append(docs_page)
    return written


def save_images(images: dict, path: Path) -> None:
    """The report's images (reference and strip crops per scene) in one ``.npz``."""
    arrays = {f"{name}/reference": scene["reference"] for name, scene in images.items()}
    for name, scene in images.items():
        arrays.update({f"{name}/strip/{spp}": img for spp, img in scene["strips"].items()})
        denoised = scene.get("denoised_strips", {})
        arrays.update({f"{name}/denoised/{spp}": img for spp, img in denoised.items()})
    np.savez_compressed(path, **arrays)


def load_previous(folder: Path) -> tuple[dict, dict]:
    """The results and images a previous run wrote into ``folder`` (to rebuild its report)."""
    results = json.loads((folder / "accuracy.json").read_text())
    images: dict = {name: {"strips": {}, "denoised_strips": {}} for name in results["scenes"]}
    with np.load(folder / "images.npz") as arrays:
        for key in arrays.files:
            name, kind, *rest = key.split("/")
            if kind == "reference":
                images[name]["reference"] = arrays[key]
            else:
                strips = "strips" if kind == "strip" else "denoised_strips"
                images[name][strips][int(rest[0])] = arrays[key]
    return results, images


def _json_default(value):
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"cannot write {type(value).__name__} to JSON")


def splice(page: Path, report: str) -> None:
    """Replace what lies between the report markers of ``page`` (append them if missing)."""
    text = page.read_text() if page.is_file() else ""
    block = f"{REPORT_START}\n{report.rstrip()}\n{REPORT_END}"
    if REPORT_START in text and REPORT_END in text:
        head, rest = text.split(REPORT_START, 1)
        _, tail = rest.split(REPORT_END, 1)
        text = head + block + tail
    else:
        text = text.rstrip() + ("\n\n" if text else "") + block + "\n"
    page.write_text(text)


# --- plots -------------------------------------------------------------------------------------


# --- markdown ----------------------------------------------------------------------------------


def seconds_text(value: float | None) -> str:
    if value is None:
        return "-"
    if value < 1.0:
        return f"{value * 1e3:.0f} ms"
    return f"{value:.1f} s" if value < 100 else f"{value:.0f} s"


def time_to_text(entry: dict) -> str:
    """A time-to-quality entry: ``0.42 s (37 spp)``, ``~12 s (extrapolated)`` or ``-``."""
    if entry["seconds"] is None:
        floor = entry.get("floor")
        return "not reached" + (f" (bias {floor:.1e})" if floor else "")
    text = f"{seconds_text(entry['seconds'])} ({entry['spp']:.0f} spp)"
    return text if entry["how"] == "measured" else f"~{text}, extrapolated"


def cheapest(scene: dict, target: str) -> tuple[str, dict] | None:
    """The configuration reaching relative MSE ``target`` in the least time."""
    reached = [
        (name, data["time_to"][target])
        for name, data in scene["configs"].items()
        if data["time_to"][target]["seconds"] is not None
    ]
    return min(reached, key=lambda item: item[1]["seconds"]) if reached else None


def markdown(results: dict, image_dir: str, command: str) -> str:
    """The generated report (markdown), with images under ``image_dir``."""
    options = results["options"]
    machine = results["machine"]
    when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d")
    lines = [
        f"Generated on {when} by `{command or 'tilerender bench accuracy'}` in "
        f"{results['seconds'] / 60:.0f} minutes: about {options['pixels']} pixels per image, "
        f"1 to {options['max_spp']} spp, seed {options['seed']}. Machine: {machine['cpus']} "
        f"CPUs, load average {machine['load_average'][0]:.1f} at the start and "
        f"{machine['load_average_end'][0]:.1f} at the end. Seconds are render seconds: the "
        "process's CPU seconds over its render threads, the wall-clock time of the render on "
        "an idle machine (on this shared one, wall-clock time measured the neighbours too; "
        "it is kept in the JSON as `wall_seconds`). Configurations took turns wave by wave.",
        "",
        "### Time to quality, every scene",
        "",
        "Render seconds for the default configuration (`path`, the scene's own "
        "settings) to reach a relative MSE of 1e-2, 1e-3 and 1e-4 (relative errors of 10%, "
        "3.2% and 1%), and the configuration that reaches 1% error soonest. *Extrapolated*: "
        "past the sweep's last level, along relMSE = bias + c / N fitted to its last four "
        "levels; *not reached (bias b)*: the fitted bias lies above the target.",
        "",
        "| scene | size | reference | relMSE 1e-2 | relMSE 1e-3 | 1% error (1e-4) "
        "| cheapest to 1% |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, scene in results["scenes"].items():
        times = scene["configs"][DEFAULT_CONFIG]["time_to"]
        best = cheapest(scene, "0.0001")
        best_text = f"`{best[0]}`: {time_to_text(best[1])}" if best else "none"
        width, height = scene["size"]
        lines.append(
            f"| {name} | {width}x{height} | {scene['reference']['source']} | "
            f"{time_to_text(times['0.01'])} | {time_to_text(times['0.001'])} | "
            f"{time_to_text(times['0.0001'])} | {best_text} |"
        )
    lines += ["", *denoiser_section(results), ""]
    lines += ["", *calibration_section(results, image_dir), ""]
    lines += ["", *denoised_calibration_section(results, image_dir), ""]
    lines += [
        "### Cost per effect (Reiter eq. 5.1)",
        "",
        f"![cost per effect]({image_dir}/effect-costs.png)",
        "",
        *effect_summary(results),
        "",
    ]
    for name, scene in results["scenes"].items():
        lines += scene_section(name, scene, image_dir)
    return "\n".join(lines) + "\n"


DENOISE_TARGET = 1 / 8
"""Issue 24's target: time to relative MSE 1e-2 with the denoiser at most 1/8 of without."""


def denoised_configs(scene: dict) -> list[str]:
    return [name for name, data in scene["configs"].items() if "denoise" in data]


def denoiser_section(results: dict) -> list[str]:
    """Time to quality with and without the denoiser, per scene, and its bias floor: what is
    left at the sweep's last level, raw against denoised."""
    scenes = {n: s for n, s in results["scenes"].items() if denoised_configs(s)}
    if not scenes:
        return []
    lines = [
        "### Time to quality with the denoiser",
        "",
        "Render seconds to a relative MSE of 1e-2 and 1e-3 for `path` and for `path` denoised "
        "by Open Image Denoise (the denoised configurations denoise the mean of `path-aov`, "
        "`path` recording its albedo and normal AOVs, once per level; their seconds are that "
        "render's plus one denoising). *Ratio*: the quicker denoised time to 1e-2 over `path`'s "
        f"(target <= 1/{round(1 / DENOISE_TARGET)}). *At the last level*: relative MSE at the "
        "sweep's highest spp, raw and denoised: a denoised error above the raw one is the "
        "denoiser's bias (it blurs what the samples have resolved).",
        "",
    ]
    names = denoised_configs(next(iter(scenes.values())))
    lines += [
        "| scene | `path`: 1e-2 / 1e-3 | "
        + " | ".join(f"`{n}`: 1e-2 / 1e-3" for n in names)
        + f" | ratio at 1e-2 | at the last level: {' / '.join(['path', *names])} |",
        "|---" * (len(names) + 4) + "|",
    ]
    for name, scene in scenes.items():
        configs = scene["configs"]
        raw = configs[DEFAULT_CONFIG]
        cells = [
            f"{time_to_text(raw['time_to']['0.01'])} / {time_to_text(raw['time_to']['0.001'])}"
        ]
        denoised = [configs[c] for c in names]
        for data in denoised:
            times = data["time_to"]
            cells.append(f"{time_to_text(times['0.01'])} / {time_to_text(times['0.001'])}")
        quickest = [d["time_to"]["0.01"]["seconds"] for d in denoised]
        quickest = min((t for t in quickest if t is not None), default=None)
        base = raw["time_to"]["0.01"]["seconds"]
        if quickest is None or base is None:
            ratio = "-"
        else:
            r = quickest / base
            ratio = f"{r:.3f} ({'met' if r <= DENOISE_TARGET else 'missed'})"
        last = " / ".join(f"{d['levels'][-1]['rel_mse']:.1e}" for d in [raw, *denoised])
        lines.append(f"| {name} | {' | '.join(cells)} | {ratio} | {last} |")
    return lines


def within_band(record: dict) -> bool:
    """Whether a calibration record's estimate is within the band of its true error."""
    return record["true"] > 0 and abs(record["estimated"] / record["true"] - 1) <= CALIBRATION_BAND


def calibration_section(results: dict, image_dir: str) -> list[str]:
    rows = []
    records = []
    for name, scene in results["scenes"].items():
        given = [r for r in scene["calibration"] if r["estimated"] is not None and r["true"] > 0]
        missing = [r["spp"] for r in scene["calibration"] if r["estimated"] is None]
        records += scene["calibration"]
        ratios = [r["estimated"] / r["true"] for r in given]
        spp = [r["spp"] for r in scene["calibration"]]
        cells = (
            f"{min(ratios):.2f} | {np.median(ratios):.2f} | {max(ratios):.2f}"
            if ratios
            else "- | - | -"
        )
        levels = f"{spp[0]}-{spp[-1]}" if spp else "-"
        rows.append(
            f"| {name} | {levels} | {cells} | "
            f"{sum(map(within_band, given))}/{len(given)} | {spp_ranges(missing)} | "
            f"{check_share_text(scene['calibration'])} |"
        )
    given = [r for r in records if r["estimated"] is not None and r["true"] > 0]
    missing = [r for r in records if r["estimated"] is None]
    low = [r for r in given if r["true"] <= 0.1]
    ratios = [r["estimated"] / r["true"] for r in given]
    missing_true = [r["true"] for r in missing]
    missing_text = (
        f"For the other {len(missing)} it said *not estimable yet* (true error "
        f"{min(missing_true):.0%} to {max(missing_true):.0%})."
        if missing
        else "It gave an estimate at every level."
    )
    spread = f"ratios {min(ratios):.2f} to {max(ratios):.2f}" if ratios else "no ratios"
    return [
        "### Calibration of the online error estimate",
        "",
        f"![calibration]({image_dir}/calibration.png)",
        "",
        f"Estimated relative error (from {PARTS} independent parts, no reference) over the "
        "true one (against the reference, its noise floor removed), for renders with the "
        f"reference's own settings at every spp from {PARTS} up, {len(records)} levels in all. "
        f"Where it gave an estimate ({len(given)} levels): {sum(map(within_band, given))} of "
        f"{len(given)} within +-30%, {sum(map(within_band, low))} of {len(low)} where the true "
        f"error is at most 10%; {spread}. {missing_text} *Spot checks*: the pixels checked "
        f"at each level (at most {SPOT_CHECKS}, {SPOT_CHECK_FACTOR} times the level's samples "
        "each), and what the checks of every level up to the last cost, as a share of the "
        "render time of the parts (what a progressive render that doubles its samples pays).",
        "",
        "| scene | spp | est/true min | median | max | within +-30% | not estimable at spp "
        "| spot checks: pixels, time |",
        "|---|---|---|---|---|---|---|---|",
        *rows,
    ]


def denoised_calibration_section(results: dict, image_dir: str) -> list[str]:
    """The denoised image's error estimate against its true error, per scene: where it is
    given, how close; where not, the levels it left to the beauty's estimate."""
    scenes = {n: calibration_records(s, True) for n, s in results["scenes"].items()}
    scenes = {n: r for n, r in scenes.items() if r}
    if not scenes:
        return []
    rows, within_all, total, eligible_all = [], 0, 0, 0
    deep = PARTS * MIN_PART_SPP
    for name, records in scenes.items():
        given = [r for r in records if r["estimated"] is not None and r["true"] > 0]
        ratios = [r["estimated"] / r["true"] for r in given]
        within = sum(abs(q - 1) <= DENOISED_BAND for q in ratios)
        eligible = sum(r["spp"] >= deep for r in records)
        within_all += within
        total += len(records)
        eligible_all += eligible
        cells = (
            f"{min(ratios):.2f} | {np.median(ratios):.2f} | {max(ratios):.2f}"
            if ratios
            else "- | - | -"
        )
        missing = [r["spp"] for r in records if r["estimated"] is None]
        share = records[-1]["seconds"] / max(1e-12, scenes_seconds(results, name))
        rows.append(
            f"| {name} | {cells} | {within}/{eligible} | {spp_ranges(missing)} | {share:.1%} |"
        )
    met = "met" if within_all >= DENOISED_SHARE * eligible_all else "missed"
    return [
        "### Calibration of the denoised image's error estimate",
        "",
        f"![calibration of the denoised estimate]({image_dir}/calibration-denoised.png)",
        "",
        "The same renders as above, their mean denoised (`high`, guided by the AOVs): the error "
        "of the denoised image estimated by SURE (`tracer.accuracy.denoised_error`: the "
        "residual against the raw mean, the raw variance and the denoiser's response to a "
        "probe of noise; one extra denoising) over its true error against the reference. It "
        f"is given from {MIN_PART_SPP} samples per part ({deep} spp) on; below, a render to a "
        "target error says so and falls back to the beauty's estimate. Within "
        f"+-{DENOISED_BAND:.0%} at {within_all} of the {eligible_all} levels from {deep} spp "
        "on, counting a level there without an estimate as a miss (target: "
        f"{DENOISED_SHARE:.0%}; {met}); of all {total} levels, {within_all}. *Time*: the two "
        "denoisings of the last level over the render time of its parts.",
        "",
        f"| scene | est/true min | median | max | within +-{DENOISED_BAND:.0%}, levels from "
        f"{deep} spp | not given at spp | time |",
        "|---|---|---|---|---|---|---|",
        *rows,
    ]


def scenes_seconds(results: dict, name: str) -> float:
    """Render seconds of a scene's calibration parts at its last level."""
    return results["scenes"][name]["calibration"][-1]["seconds"]


def check_share_text(records: list[dict]) -> str:
    """Pixels spot-checked per level (range) and the checks' seconds over the parts'."""
    if not records or "check_seconds" not in records[-1]:
        return "-"
    counts = sorted({r["checked"] for r in records})
    pixels = f"{counts[0]}" if len(counts) == 1 else f"{counts[0]}-{counts[-1]}"
    seconds = records[-1]["seconds"]
    share = sum(r["check_seconds"] for r in records) / seconds if seconds > 0 else 0.0
    return f"{pixels}, {share:.1%}"


def spp_ranges(levels: list[int]) -> str:
    """Doubling spp levels as runs: ``4-32, 256``; ``-`` for none."""
    runs: list[list[int]] = []
    for level in levels:
        if runs and level == 2 * runs[-1][-1]:
            runs[-1].append(level)
        else:
            runs.append([level])
    return ", ".join(f"{r[0]}-{r[-1]}" if len(r) > 1 else f"{r[0]}" for r in runs) or "-"


def effect_summary(results: dict) -> list[str]:
    parts = list(next(iter(results["scenes"].values()))["effects"]["parts"])
    lines = [
        f"| scene | {' | '.join(parts)} | sum of parts | all effects (measured) | sum / measured |",
        "|---|" + "---|" * (len(parts) + 3),
    ]
    for name, scene in results["scenes"].items():
        costs = scene["effects"]
        total = costs["total"]
        cells = [f"{seconds_text(v)} ({v / total:.0%})" for v in costs["parts"].values()]
        lines.append(
            f"| {name} | {' | '.join(cells)} | {seconds_text(costs['sum_of_parts'])} | "
            f"{seconds_text(total)} | {costs['ratio']:.3f} |"
        )
    return lines


def number_text(value: float | None, scale: float, digits: int) -> str:
    """``value * scale`` with ``digits`` decimals, or "-" when there is none (results from
    before the ray counter, or a level of zero seconds)."""
    return "-" if value is None else f"{value * scale:.{digits}f}"


def scene_section(name: str, scene: dict, image_dir: str) -> list[str]:
    ref = scene["reference"]
    width, height = scene["size"]
    max_spp = scene["configs"][DEFAULT_CONFIG]["levels"][-1]["spp"]
    lines = [
        f"### {name}",
        "",
        f"{width}x{height} pixels, {scene['triangles']} triangles. Reference: {ref['detail']}, "
        f"max_depth {ref['max_depth']}; its noise floor (relative MSE it adds, subtracted "
        f"from every relative MSE below) is {ref['noise_floor']:.2e}."
        + (f" ({ref['note']}.)" if ref.get("note") else ""),
        "",
        f"![{name}: error against time]({image_dir}/error-vs-time-{name}.png)",
        "",
        f"![{name}: image strip]({image_dir}/strip-{name}.png)",
        "",
        f"At {max_spp} spp (relative MSE, RMSE in linear radiance, PSNR/SSIM/FLIP of the sRGB "
        "display images), millions of rays traced (camera, continuation, shadow and occlusion "
        "rays) and their rate, work in millions of BVH node visits and triangle tests, and the "
        "time to reach a relative MSE of 1e-2 and 1e-3:",
        "",
        "| configuration | seconds | rays (M) | Mrays/s | work (M) | relMSE | RMSE | PSNR "
        "| SSIM | FLIP | to 1e-2 | to 1e-3 |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for config, data in scene["configs"].items():
        last = data["levels"][-1]
        flip = "-" if last["flip"] is None else f"{last['flip']:.3f}"
        lines.append(
            f"| `{config}`: {data['label']} | {seconds_text(last['seconds'])} | "
            f"{number_text(last.get('rays'), 1e-6, 1)} | "
            f"{number_text(last.get('mrays_per_second'), 1.0, 2)} | "
            f"{last['work'] / 1e6:.0f} | {last['rel_mse']:.2e} | {last['rmse']:.4f} | "
            f"{last['psnr']:.1f} | {last['ssim']:.3f} | {flip} | "
            f"{time_to_text(data['time_to']['0.01'])} | {time_to_text(data['time_to']['0.001'])} |"
        )
    costs = scene["effects"]
    lines += [
        "",
        f"Effect costs ({costs['spp']} spp, median of {costs['repeats']} interleaved rounds; "
        "rays and work per round in millions (rays traced; BVH node visits and triangle tests); "
        "relative MSE of each stage's image over all rounds):",
        "",
        "| stage | integrator | seconds | rays (M) | work (M) | relMSE |",
        "|---|---|---|---|---|---|",
    ]
    for stage in costs["stages"]:
        lines.append(
            f"| {stage['name']} | {stage['integrator']} | {seconds_text(stage['median_seconds'])} "
            f"| {number_text(stage.get('rays'), 1e-6, 2)} | {stage['work'] / 1e6:.1f} "
            f"| {stage['rel_mse']:.2e} |"
        )
    lines.append("")
    return lines
