"""The accuracy study's plots (``cli.accuracy_report``'s PNGs): error against time and an
image strip per scene, the calibration of the raw and the denoised error estimates, and the
cost per effect."""

import math
from pathlib import Path

import numpy as np

from cli.accuracy_metrics import TARGETS
from cli.accuracy_sweep import DEFAULT_CONFIG, DENOISED_STRIP
from tracer.accuracy.error_estimate import PARTS, to_display

CALIBRATION_BAND = 0.3
"""The calibration goal: estimated within +-30% of the true relative error."""
DENOISED_BAND = 0.5
"""Issue 24's goal for the denoised image's estimate: within +-50% of its true error..."""


def write_plots(results: dict, images: dict, folder: Path) -> list[Path]:
    """Every PNG: error against time and an image strip per scene, the calibration and the
    effect costs."""
    import matplotlib

    matplotlib.use("Agg")
    written = []
    for name, scene in results["scenes"].items():
        written.append(error_vs_time_plot(name, scene, folder / f"error-vs-time-{name}.png"))
        written.append(strip_plot(name, scene, images[name], folder / f"strip-{name}.png"))
    written.append(calibration_plot(results, folder / "calibration.png"))
    if any(calibration_records(s, True) for s in results["scenes"].values()):
        path = folder / "calibration-denoised.png"
        written.append(calibration_plot(results, path, denoised=True))
    written.append(effect_costs_plot(results, folder / "effect-costs.png"))
    return written


def relative_error(rel_mse: float) -> float:
    """The relative RMS error of a relative MSE (clipped just above zero for log plots)."""
    return math.sqrt(max(rel_mse, 1e-12))


def error_vs_time_plot(name: str, scene: dict, path: Path) -> Path:
    """Log-log relative error against seconds, one line per configuration, with a 1/sqrt(t)
    guide through the default configuration's middle and the targets as dotted lines."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8.5, 5.0))
    ax.set_prop_cycle(color=plt.get_cmap("tab20").colors)
    for config, data in scene["configs"].items():
        t = [lv["seconds"] for lv in data["levels"]]
        e = [relative_error(lv["rel_mse"]) for lv in data["levels"]]
        style = {"linewidth": 2.5, "color": "black"} if config == DEFAULT_CONFIG else {}
        if "denoise" in data:
            style = {"linewidth": 2.0, "linestyle": "--"}
        ax.plot(t, e, marker="o", markersize=3, label=config, **style)
    default = scene["configs"][DEFAULT_CONFIG]["levels"]
    middle = default[len(default) // 2]
    t0, e0 = middle["seconds"], relative_error(middle["rel_mse"])
    guide_t = np.geomspace(default[0]["seconds"], default[-1]["seconds"], 20)
    ax.plot(guide_t, e0 * np.sqrt(t0 / guide_t), "k--", linewidth=1, label="1/sqrt(t)")
    for target in TARGETS:
        ax.axhline(math.sqrt(target), color="grey", linestyle=":", linewidth=1)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("render seconds (CPU seconds / threads, cumulative)")
    ax.set_ylabel("relative error (sqrt of relative MSE)")
    width, height = scene["size"]
    ax.set_title(f"{name} ({width}x{height}): error against time, 1 to "
                 f"{default[-1]['spp']} spp")  # fmt: skip
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def strip_plot(name: str, scene: dict, scene_images: dict, path: Path) -> Path:
    """Crops of the default configuration at each strip spp beside the reference's, and under
    them those of ``DENOISED_STRIP`` where the study has them."""
    import matplotlib.pyplot as plt

    reference = scene_images["reference"]
    crop = crop_box(reference)
    rows = [(DEFAULT_CONFIG, scene_images["strips"])]
    if scene_images.get("denoised_strips") and DENOISED_STRIP in scene["configs"]:
        rows.append((DENOISED_STRIP, scene_images["denoised_strips"]))
    columns = len(rows[0][1]) + 1
    fig, axes = plt.subplots(
        len(rows), columns, figsize=(2.0 * columns, 2.4 * len(rows)), squeeze=False
    )
    for row, (config, strips) in zip(axes, rows, strict=True):
        levels = {lv["spp"]: lv for lv in scene["configs"][config]["levels"]}
        panels = [(f"{config} {spp} spp\nimage error "
                   f"{relative_error(levels[spp]['rel_mse']):.1%}", img)
                  for spp, img in sorted(strips.items())]  # fmt: skip
        panels.append(("reference", reference))
        for ax, (title, image) in zip(row, panels, strict=False):
            y0, y1, x0, x1 = crop
            ax.imshow(to_display(image[y0:y1, x0:x1]), interpolation="nearest")
            ax.set_title(title, fontsize=8)
        for ax in row:
            ax.axis("off")
    labels = "; ".join(f"{c}: {scene['configs'][c]['label']}" for c, _ in rows)
    fig.suptitle(f"{name}: {labels}", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def crop_box(reference: np.ndarray) -> tuple[int, int, int, int]:
    """A square crop of half the shorter side around the most detailed part of the reference
    (the largest sum of display gradients), so that noise and edges both show."""
    shown = to_display(reference).mean(axis=2)
    h, w = shown.shape
    side = max(8, min(h, w) // 2)
    detail = np.abs(np.diff(shown, axis=0))[:, :-1] + np.abs(np.diff(shown, axis=1))[:-1]
    integral = np.pad(detail, ((1, 0), (1, 0))).cumsum(0).cumsum(1)
    best, box = -1.0, (0, min(h, side), 0, min(w, side))
    step = max(1, side // 4)
    for y in range(0, max(1, h - side), step):
        for x in range(0, max(1, w - side), step):
            y1, x1 = min(y + side, h - 1), min(x + side, w - 1)
            total = integral[y1, x1] - integral[y, x1] - integral[y1, x] + integral[y, x]
            if total > best:
                best, box = total, (y, min(y + side, h), x, min(x + side, w))
    return box


def calibration_records(scene: dict, denoised: bool) -> list[dict]:
    """A scene's calibration records (spp, estimated, true) of the raw estimate, or of the
    denoised image's (records from before it have none)."""
    if not denoised:
        return scene["calibration"]
    return [{"spp": r["spp"], **r["denoised"]} for r in scene["calibration"] if "denoised" in r]


def calibration_plot(results: dict, path: Path, denoised: bool = False) -> Path:
    """Estimated against true relative error for every scene and spp, with y = x and the
    band (+-30%, +-50% for the denoised image); where the estimate said "not estimable yet", a
    cross on the bottom edge at the true error."""
    import matplotlib.pyplot as plt

    band = DENOISED_BAND if denoised else CALIBRATION_BAND
    fig, ax = plt.subplots(figsize=(6.5, 5.5))
    values = [
        v
        for scene in results["scenes"].values()
        for r in calibration_records(scene, denoised)
        for v in (r["true"], r["estimated"])
        if v
    ]
    lo, hi = min(values) / 1.5, max(values) * 1.5
    for name, scene in results["scenes"].items():
        records = calibration_records(scene, denoised)
        given = [r for r in records if r["estimated"] is not None]
        (line,) = ax.plot([r["true"] for r in given], [r["estimated"] for r in given],
                          marker="o", markersize=4, linestyle="-", linewidth=0.8,
                          label=name)  # fmt: skip
        missing = [r["true"] for r in records if r["estimated"] is None]
        ax.plot(missing, [lo * 1.15] * len(missing), marker="x", linestyle="none",
                color=line.get_color(), clip_on=False)  # fmt: skip
    line = np.geomspace(lo, hi, 10)
    ax.plot(line, line, "k-", linewidth=1, label="estimate = true")
    ax.fill_between(line, line * (1 - band), line * (1 + band),
                    color="grey", alpha=0.2, label=f"+-{band:.0%}")  # fmt: skip
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlim(lo, hi)
    ax.set_ylim(lo, hi)
    ax.set_xlabel("true relative error (against the reference)")
    ax.set_ylabel("estimated relative error (x: not estimable yet)")
    what = "the denoised image's error estimate (SURE)" if denoised else "the online error estimate"
    ax.set_title(f"Calibration of {what} ({PARTS} parts, 4 to max spp)", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def effect_costs_plot(results: dict, path: Path) -> Path:
    """Stacked bars of Reiter's parts per scene beside the measured all-effects time."""
    import matplotlib.pyplot as plt

    names = list(results["scenes"])
    fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(names) + 2), 4.5))
    x = np.arange(len(names))
    parts = list(next(iter(results["scenes"].values()))["effects"]["parts"])
    bottom = np.zeros(len(names))
    for part in parts:
        values = np.array([results["scenes"][n]["effects"]["parts"][part] for n in names]) * 1e3
        ax.bar(x - 0.2, values, 0.4, bottom=bottom, label=part)
        bottom += values
    totals = np.array([results["scenes"][n]["effects"]["total"] for n in names]) * 1e3
    ax.bar(x + 0.2, totals, 0.4, color="black", alpha=0.6, label="all effects (measured)")
    ax.set_xticks(x, names, rotation=30, ha="right")
    ax.set_ylabel("milliseconds per render")
    spp = next(iter(results["scenes"].values()))["effects"]["spp"]
    ax.set_title(f"Cost per effect after Reiter eq. 5.1 ({spp} spp)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
