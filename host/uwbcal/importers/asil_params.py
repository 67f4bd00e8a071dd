"""The asil dataset's parameters.yaml: the YAML subset it uses, the keys the importer reads and
their checks, and the per-node and per-pair values (temperature in degC, distance in m)."""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Final

from uwbcal.errors import SessionError

_SCALAR_INT = re.compile(r"^[+-]?(0x[0-9a-fA-F]+|\d+)$")


def _scalar(text: str) -> Any:
    """A YAML scalar of the subset parameters.yaml uses: int (also 0x..), float, or string."""
    t = text.strip()
    if _SCALAR_INT.match(t):
        return int(t, 0) if not re.match(r"^[+-]?0\d", t) else int(t, 10)
    try:
        return float(t)
    except ValueError:
        return t.strip("'\"")


def parse_parameters(path: Path) -> dict[str, Any]:
    """Parse parameters.yaml (block mappings, block lists, scalars, ``#`` comments).

    Only the YAML subset the dataset uses; anything else is a SessionError naming the line.
    """
    if not path.is_file():
        raise SessionError(f"{path}: no such file")
    lines: list[tuple[int, int, str]] = []
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise SessionError(f"{path}: not text (byte {exc.start} is not UTF-8)") from None
    for no, line in enumerate(text.splitlines(), start=1):
        body = line.split("#", 1)[0].rstrip()
        if body.strip():
            lines.append((no, len(body) - len(body.lstrip(" ")), body.strip()))

    def block(i: int, indent: int) -> tuple[Any, int]:
        if i >= len(lines):
            return None, i
        if lines[i][2].startswith("- ") or lines[i][2] == "-":
            out_l: list[Any] = []
            while i < len(lines) and lines[i][1] == indent and lines[i][2].startswith("-"):
                no, _, text = lines[i]
                rest = text[1:].strip()
                if not rest:
                    val, i = block(i + 1, lines[i + 1][1] if i + 1 < len(lines) else indent + 2)
                    out_l.append(val)
                elif ":" in rest:  # "- key: ..." opens a mapping item
                    sub_indent = indent + (len(text) - len(rest))
                    lines[i] = (no, sub_indent, rest)
                    val, i = block(i, sub_indent)
                    out_l.append(val)
                else:
                    out_l.append(_scalar(rest))
                    i += 1
            return out_l, i
        out_d: dict[str, Any] = {}
        while i < len(lines) and lines[i][1] == indent:
            no, _, text = lines[i]
            if ":" not in text or text.startswith("-"):
                raise SessionError(f"{path}: line {no}: expected 'key: value'")
            key, _, value = text.partition(":")
            if value.strip():
                out_d[key.strip()] = _scalar(value)
                i += 1
            else:
                nxt = i + 1
                if nxt < len(lines) and (lines[nxt][1] > indent or lines[nxt][2].startswith("-")):
                    out_d[key.strip()], i = block(nxt, lines[nxt][1])
                else:
                    out_d[key.strip()] = None
                    i += 1
        if i < len(lines) and lines[i][1] > indent:
            raise SessionError(f"{path}: line {lines[i][0]}: unexpected indentation")
        return out_d, i

    value, end = block(0, lines[0][1] if lines else 0)
    if end != len(lines) or not isinstance(value, dict):
        no = lines[end][0] if end < len(lines) else len(lines)
        raise SessionError(f"{path}: line {no}: not the parameters.yaml layout")
    check_parameters(value, path)
    return value


#: Keys of parameters.yaml the importer reads, and the numbers they must hold.
_NUMBER_KEYS: Final = ("node_distance", "message_interval", "clock_offset")


def check_parameters(params: Mapping[str, Any], path: Path) -> None:
    """SessionError naming the first key of parameters.yaml the importer reads that is missing or
    of the wrong kind: ``nodes`` (a list of node ids), the numbers of _NUMBER_KEYS, ``temperature``
    (one number per node) and ``node_pairs`` (``nodes`` pairs with a ``distance``). Keys the
    importer does not read are kept as they are, unchecked."""
    def is_num(v: Any) -> bool:
        return isinstance(v, int | float) and not isinstance(v, bool)

    nodes = params.get("nodes")
    if not isinstance(nodes, list) or not nodes or not all(isinstance(n, int) for n in nodes):
        raise SessionError(f"{path}: 'nodes' must be a list of node ids (got {nodes!r:.40})")
    for key in _NUMBER_KEYS:
        if key in params and not is_num(params[key]):
            raise SessionError(f"{path}: '{key}' must be a number (got {params[key]!r:.40})")
    temp = params.get("temperature")
    if temp is not None and (not isinstance(temp, list) or not all(is_num(t) for t in temp)):
        raise SessionError(f"{path}: 'temperature' must be a list of numbers, one per node "
                           f"(got {temp!r:.40})")
    pairs = params.get("node_pairs")
    if pairs is not None:
        ok = isinstance(pairs, list) and all(
            isinstance(p, dict) and isinstance(p.get("nodes"), list) and len(p["nodes"]) == 2
            and is_num(p.get("distance")) for p in pairs)
        if not ok:
            raise SessionError(f"{path}: 'node_pairs' must list 'nodes: [a, b]' with a 'distance' in m")


def node_value(params: Mapping[str, Any], key: str, node_id: int) -> float | None:
    """Per-node list value of parameters.yaml (indexed like ``nodes``), or None."""
    values, nodes = params.get(key), params.get("nodes")
    if not isinstance(values, list) or not isinstance(nodes, list) or node_id not in nodes:
        return None
    idx = nodes.index(node_id)
    v = values[idx] if idx < len(values) else None
    return float(v) if isinstance(v, int | float) else None


def pair_distance(params: Mapping[str, Any], a: int, b: int) -> float | None:
    """Distance of the node pair (a, b), m, from node_pairs or node_distance."""
    pairs = params.get("node_pairs")
    if isinstance(pairs, list):
        for p in pairs:
            if isinstance(p, dict) and sorted(p.get("nodes") or []) == sorted([a, b]):
                d = p.get("distance")
                if isinstance(d, int | float):
                    return float(d)
    d = params.get("node_distance")
    return float(d) if isinstance(d, int | float) else None
