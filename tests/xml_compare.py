"""Structural comparison of two XML documents whose numbers may differ in their last digits.

A number derived in float64 (a norm, a product of matrices) can differ in its last bits from one
CPU to another; its text then differs although the document means the same. Elements, their
order, attribute names and non-numeric values must match exactly; attribute values that are
lists of numbers must match within a tolerance relative to the largest number of the list.
"""

import math
import re
import xml.etree.ElementTree as ET

NUMBERS = re.compile(r"[\s,]+")


def _numbers(text: str) -> list[float] | None:
    tokens = [t for t in NUMBERS.split(text.strip()) if t]
    try:
        return [float(t) for t in tokens] if tokens else None
    except ValueError:
        return None


def _value_difference(a: str, b: str, rtol: float) -> str | None:
    if a == b:
        return None
    x, y = _numbers(a), _numbers(b)
    if x is None or y is None or len(x) != len(y):
        return f"{a!r} != {b!r}"
    scale = max([0.0, *(abs(v) for v in x + y if math.isfinite(v))])
    for u, v in zip(x, y, strict=True):
        if not (u == v or abs(u - v) <= rtol * scale):
            return f"{a!r} != {b!r} (beyond a relative {rtol:g})"
    return None


def xml_differences(a: str, b: str, rtol: float = 1e-9) -> list[str]:
    """Where documents ``a`` and ``b`` differ, as 'path: what' lines (empty when they agree)."""
    found: list[str] = []

    def walk(x: ET.Element, y: ET.Element, path: str) -> None:
        if x.tag != y.tag:
            found.append(f"{path}: <{x.tag}> != <{y.tag}>")
            return
        if sorted(x.attrib) != sorted(y.attrib):
            found.append(f"{path}: attributes {sorted(x.attrib)} != {sorted(y.attrib)}")
            return
        for key in x.attrib:
            problem = _value_difference(x.attrib[key], y.attrib[key], rtol)
            if problem:
                found.append(f"{path}@{key}: {problem}")
        if (x.text or "").strip() != (y.text or "").strip():
            found.append(f"{path}: text {x.text!r} != {y.text!r}")
        if len(x) != len(y):
            found.append(f"{path}: {len(x)} children != {len(y)}")
            return
        for i, (cx, cy) in enumerate(zip(x, y, strict=True)):
            walk(cx, cy, f"{path}/{cx.tag}[{i}]")

    walk(ET.fromstring(a), ET.fromstring(b), ET.fromstring(a).tag)
    return found
