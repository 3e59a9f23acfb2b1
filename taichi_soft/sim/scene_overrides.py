"""``--set KEY=VALUE`` overrides: parsing an assignment and applying a set of them to a raw
scene dict (before validation)."""
from __future__ import annotations

import tomllib

from ..errors import UserError
from .scene_validation import TOP_KEYS


def parse_value(text: str):
    """A ``--set`` value: read as a TOML value (number, bool, array, inline table) or else a bare string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def parse_override(assignment: str) -> tuple[list[str], object]:
    """``"body.0.stretch.k=5000"`` -> (["body", "0", "stretch", "k"], 5000.0); bad syntax raises ``UserError``."""
    if "=" not in assignment:
        raise UserError(f"--set {assignment!r}: expected KEY=VALUE, e.g. sim.dt=0.002")
    key, text = assignment.split("=", 1)
    parts = key.strip().split(".")
    if not all(parts):
        raise UserError(f"--set {assignment!r}: empty part in key {key!r}")
    if parts[0] not in TOP_KEYS:
        raise UserError(f"--set {key}: unknown section {parts[0]!r}; sections are {', '.join(TOP_KEYS)}")
    return parts, parse_value(text.strip())


def _flatten(parts: list[str], value) -> list[tuple[list[str], object]]:
    """An inline-table value sets each of its keys: ``stretch={damping=5}`` is ``stretch.damping=5``
    (merged into the table, never replacing it, so an earlier ``stretch.k`` is kept)."""
    if isinstance(value, dict) and value:
        out = []
        for k, v in value.items():
            out += _flatten(parts + [k], v)
        return out
    return [(parts, value)]


def apply_overrides(data: dict, assignments) -> None:
    """Apply ``--set KEY=VALUE`` assignments to the raw scene dict as one set, in any order.

    ``terrain.kind`` is applied first (switching kind drops the old kind's geometry keys, so the
    new kind's keys given beside it are kept whatever their order); inline tables merge key by
    key; the same key given twice with different values is refused (``UserError``).
    """
    given: dict[tuple, tuple] = {}
    for assignment in assignments:
        parts, value = parse_override(assignment)
        for p, v in _flatten(parts, value):
            key = tuple(p)
            if key in given and given[key][1] != v:
                raise UserError(f"--set {'.'.join(p)} is given twice ({given[key][0]!r} and {assignment!r}); give it once")
            given[key] = (assignment, v)
    first = [k for k in given if k == ("terrain", "kind")]
    for key in first + [k for k in given if k != ("terrain", "kind")]:
        set_path(data, list(key), given[key][1])


def set_path(data: dict, parts: list[str], value) -> None:
    key = ".".join(parts)
    node = data
    for depth, part in enumerate(parts[:-1]):
        if isinstance(node, list):
            node = node[_list_index(node, part, parts[: depth + 1])]
        else:
            if parts[0] == "body" and depth == 0:
                node = node.setdefault(part, [{}])
                if not isinstance(node, list):
                    node = data[part] = [node]
                continue
            node = node.setdefault(part, {})
            if not isinstance(node, (dict, list)):
                raise UserError(f"--set {key}: {'.'.join(parts[: depth + 1])} is a value, not a table")
    last = parts[-1]
    if isinstance(node, list):
        node[_list_index(node, last, parts)] = value
    else:
        if parts == ["terrain", "kind"] and node.get("kind", "plane") != value:
            # Switching terrain kind: the old kind's geometry keys no longer apply.
            for k in list(node):
                if k != "kind":
                    del node[k]
        node[last] = value


def _list_index(lst: list, part: str, path: list) -> int:
    try:
        idx = int(part)
    except ValueError:
        raise UserError(f"--set {'.'.join(path)}: {part!r} is not a body index (0..{len(lst) - 1})") from None
    if not 0 <= idx < len(lst):
        raise UserError(f"--set {'.'.join(path)}: body index {idx} out of range (the scene has {len(lst)} bodies)")
    return idx
