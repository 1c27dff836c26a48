"""Editing a URDF as text, so that a calibrated URDF is a minimal diff of its input.

A parser and serialiser (ElementTree) would rewrite the whole file: quotes, spacing,
self-closing tags, attribute order, entities.  Here the file stays text: the
``<joint name="...">`` elements are found (outside comments and CDATA), and inside each
only the ``xyz`` / ``rpy`` attribute values of its ``<origin>`` are replaced, number by
number, keeping every number whose value did not change as it was written.  So a
version-control diff of a calibrated URDF shows exactly the changed ``<origin>``
attributes.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from kincal.errors import RobotFileError

__all__ = ["element_span", "format_floats", "mask_comments", "set_origin"]

_ATTR = r"""\b{name}\s*=\s*(["'])(.*?)\1"""


def mask_comments(text: str) -> str:
    """``text`` with the inside of ``<!-- -->`` comments and ``<![CDATA[ ]]>`` blanked."""
    out = list(text)
    for pat in (r"<!--.*?-->", r"<!\[CDATA\[.*?\]\]>"):
        for m in re.finditer(pat, text, re.S):
            for i in range(m.start(), m.end()):
                if out[i] not in "\r\n":
                    out[i] = " "
    return "".join(out)


def element_span(masked: str, tag: str, name: str) -> tuple[int, int, int]:
    """``(start, end_of_start_tag, end)`` of the element ``<tag name="name" ...>`` in the
    masked text (``end`` after its closing tag, or after ``/>``)."""
    for m in re.finditer(rf"<{tag}\b[^>]*>", masked):
        attr = re.search(_ATTR.format(name="name"), m.group(0))
        if attr is None or attr.group(2) != name:
            continue
        if m.group(0).endswith("/>"):
            return m.start(), m.end(), m.end()
        close = masked.find(f"</{tag}>", m.end())
        if close < 0:
            raise RobotFileError(f"<{tag} name={name!r}> is not closed")
        return m.start(), m.end(), close + len(f"</{tag}>")
    raise RobotFileError(f"no <{tag} name={name!r}> in the file")


def format_floats(old: str | None, values: Sequence[float] | NDArray[np.float64],
                  shortest: str) -> str:
    """The attribute value for ``values``: numbers equal to the old ones keep their text."""
    parts = old.split() if old is not None else []
    if len(parts) != len(values):
        return shortest
    out = []
    new_parts = shortest.split()
    for p, v, n in zip(parts, values, new_parts, strict=True):
        try:
            same = float(p) == float(v)
        except ValueError:
            same = False
        out.append(p if same else n)
    if out == parts:
        return old  # type: ignore[return-value]
    sep = re.findall(r"\s+", old.strip()) if old is not None else []
    text = out[0]
    for k, part in enumerate(out[1:]):
        text += (sep[k] if k < len(sep) else " ") + part
    lead = old[: len(old) - len(old.lstrip())] if old else ""
    trail = old[len(old.rstrip()):] if old else ""
    return lead + text + trail


def set_origin(text: str, joint: str, xyz: Sequence[float] | NDArray[np.float64],
               rpy: Sequence[float] | NDArray[np.float64],
               fmt: Callable[[Sequence[float] | NDArray[np.float64]], str]) -> str:
    """``text`` with the ``<origin>`` of ``<joint name=joint>`` set to xyz / rpy.

    ``fmt(values) -> str`` writes numbers (shortest round-trip form).  Unchanged numbers
    keep their text; a missing attribute is added (``rpy`` only when not all zero); a
    missing ``<origin>`` is added as the joint's first child, on a line of its own with
    the file's line ending (CRLF stays CRLF).
    """
    masked = mask_comments(text)
    start, head_end, end = element_span(masked, "joint", joint)
    m = re.search(r"<origin\b[^>]*?/?>", masked[head_end:end])
    if m is None:
        indent = re.search(r"(\r?\n)([ \t]*)<", masked[head_end:end])
        newline, pad = (indent.group(1), indent.group(2)) if indent else (
            "\r\n" if "\r\n" in text else "\n", "  ")
        attrs = f'xyz="{fmt(xyz)}"' + (f' rpy="{fmt(rpy)}"' if any(rpy) else "")
        return text[:head_end] + f"{newline}{pad}<origin {attrs}/>" + text[head_end:]
    o0, o1 = head_end + m.start(), head_end + m.end()
    tag = text[o0:o1]
    for name, values in (("xyz", xyz), ("rpy", rpy)):
        a = re.search(_ATTR.format(name=name), tag)
        if a is None:
            if name == "rpy" and not any(values):
                continue
            if name == "xyz" and not any(values):
                continue
            insert = len(tag) - (2 if tag.endswith("/>") else 1)
            while insert > 0 and tag[insert - 1] in " \t":
                insert -= 1
            tag = tag[:insert] + f' {name}="{fmt(values)}"' + tag[insert:]
            continue
        new = format_floats(a.group(2), values, fmt(values))
        tag = tag[:a.start(2)] + new + tag[a.end(2):]
    return text[:o0] + tag + text[o1:]
