"""What every part of the Mitsuba export shares: the error for what Mitsuba cannot express,
the deviations the export lists, and helpers that write XML elements."""

import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Literal

import numpy as np

from tracer.errors import TilerenderError
from tracer.maths import portable

DeviationKind = Literal["proxy", "model"]


class UnsupportedFeature(TilerenderError, ValueError):
    """A scene feature Mitsuba cannot express (or the export does not handle yet)."""

    def __init__(self, feature: str, reason: str) -> None:
        super().__init__(f"{feature}: {reason}")
        self.feature = feature


@dataclass(frozen=True)
class Deviation:
    """Where the exported scene is not exactly ours.

    ``proxy``: the feature goes through a stand-in whose error is far below render noise (a
    tabulated bitmap, a far disc, a duplicated surface). ``model``: Mitsuba's model of the
    feature differs from ours (docs/mitsuba.md quantifies each).
    """

    feature: str
    kind: DeviationKind
    detail: str


def number(value: float) -> str:
    return repr(float(value))


def triple(values) -> str:
    return ", ".join(number(v) for v in values)


def child(parent: ET.Element, tag: str, **attrs) -> ET.Element:
    return ET.SubElement(parent, tag, {k: str(v) for k, v in attrs.items()})


def rgb(parent: ET.Element, name: str, values) -> None:
    child(parent, "rgb", name=name, value=triple(values))


def scalar(parent: ET.Element, name: str, value: float) -> None:
    child(parent, "float", name=name, value=number(value))


def to_world(parent: ET.Element, matrix: np.ndarray) -> None:
    """A ``to_world`` transform of the 4x4 ``matrix`` under ``parent``."""
    transform = child(parent, "transform", name="to_world")
    child(transform, "matrix", value=" ".join(number(v) for v in np.ravel(matrix)))


def look_at(parent: ET.Element, origin, target, up) -> None:
    """A ``to_world`` transform of ``parent`` that looks from ``origin`` at ``target``."""
    transform = child(parent, "transform", name="to_world")
    child(transform, "lookat", origin=triple(origin), target=triple(target), up=triple(up))


def slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", text).strip("-")[:40] or "mesh"


def frame(normal: np.ndarray) -> np.ndarray:
    """Two unit vectors completing ``normal`` to a right-handed frame, as columns x, y, z."""
    z = portable.normalized(normal)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = portable.normalized(portable.cross(helper, z))
    return np.column_stack([x, portable.cross(z, x), z])
