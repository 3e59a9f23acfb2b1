"""Scene files: TOML with [sim], [[body]], [terrain], [contact] and [render] tables.

``load_scene(name_or_path, overrides)`` reads a scene, applies ``--set KEY=VALUE`` overrides,
fills defaults and validates every value, raising ``UserError`` with one line that names the
key, the bad value and what is allowed. The result is a plain nested dict (``Scene.data``)
that ``Scene.build`` turns into runtime objects.

This module finds and reads scene files and holds ``Scene``; the overrides are applied by
``scene_overrides``, the defaults and the checks live in ``scene_validation``.
"""
from __future__ import annotations

import copy
import tomllib
from dataclasses import dataclass
from pathlib import Path

from ..errors import UserError
from ..paths import PACKAGE_DIR, ROOT
from .scene_overrides import apply_overrides, set_path
from .scene_validation import validate


def _scenes_dir() -> Path:
    """The scene folder: the checkout's top-level scenes/, or the installed package data
    taichi_soft/scenes (``pip install .`` maps the one onto the other, see pyproject.toml)."""
    checkout = ROOT / "scenes"
    return checkout if (checkout / "plane.toml").is_file() else PACKAGE_DIR / "scenes"


SCENES_DIR = _scenes_dir()


def scene_names() -> list[str]:
    """Names of the scenes shipped in ``scenes/`` (file stems)."""
    return sorted(p.stem for p in SCENES_DIR.glob("*.toml"))


def resolve_scene_path(name_or_path: str) -> Path:
    """A shipped scene name (``plane``) or a path to a ``.toml`` file."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists() or "/" in name_or_path:
        if not p.is_file():
            raise UserError(f"scene file {name_or_path!r} {_what_it_is(p)}; expected a .toml file or a scene name "
                            f"({', '.join(scene_names())})")
        return p
    candidate = SCENES_DIR / f"{name_or_path}.toml"
    if not candidate.is_file():
        raise UserError(f"unknown scene {name_or_path!r}; choose one of: {', '.join(scene_names())} or a path to a .toml file")
    return candidate


def _what_it_is(p: Path) -> str:
    """What a path that is not a regular file is, for an error message."""
    if p.is_dir():
        return "is a directory"
    if p.is_char_device():
        return "is a character device, not a file"
    if p.is_block_device():
        return "is a block device, not a file"
    if p.is_fifo():
        return "is a named pipe, not a file"
    if p.is_socket():
        return "is a socket, not a file"
    if p.is_symlink():
        return "is a broken symbolic link"
    return "does not exist"


def resolve_mesh_paths(raw: dict, base: Path, from_cli: set):
    """Make each body's relative ``mesh`` path absolute: relative to ``base`` (the scene file's
    folder), or to the current directory for a path given on the command line (``from_cli``: the
    dotted keys that came from --set or flags)."""
    bodies = raw.get("body", [])
    for b, body in enumerate(bodies if isinstance(bodies, list) else [bodies]):
        mesh = body.get("mesh") if isinstance(body, dict) else None
        if isinstance(mesh, str) and mesh and not Path(mesh).is_absolute():
            cli = f"body.{b}.mesh" in from_cli or (b == 0 and "body.mesh" in from_cli)
            body["mesh"] = str((Path.cwd() if cli else base) / mesh)



@dataclass
class Scene:
    """A validated scene: ``name`` (file stem), ``path``, the normalised ``data`` dict and the
    terrain kind the file itself gives (``file_kind``; overrides may change it)."""

    name: str
    path: Path | None
    data: dict
    file_kind: str | None = None

    @property
    def sim(self) -> dict:
        return self.data["sim"]

    @property
    def label(self) -> str:
        """What runs, for overlays and messages: the scene name, plus the terrain if an override
        switched it (``plane, terrain sphere``)."""
        kind = self.data["terrain"]["kind"]
        return self.name if kind == self.file_kind else f"{self.name}, terrain {kind}"


def load_scene(name_or_path: str, overrides=(), integrator_names=None, flags=None) -> Scene:
    """Read, override and validate a scene. Raises ``UserError`` on any problem.

    ``overrides``: ``--set KEY=VALUE`` strings; ``flags``: {dotted key: (value, "--flag text")}
    from dedicated command-line flags, applied after (and winning over) the overrides.
    """
    path = resolve_scene_path(name_or_path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as e:
        raise UserError(f"scene {path}: malformed TOML: {e}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise UserError(f"scene {path}: cannot read: {e}") from None
    return scene_from_dict(raw, path.stem, path, overrides, integrator_names, flags)


def scene_from_dict(raw: dict, name="custom", path=None, overrides=(), integrator_names=None, flags=None) -> Scene:
    """Validate a scene given as a dict (as parsed from TOML), after applying overrides and flags
    (see ``load_scene``). An error caused by an override or flag names it; any other the scene.
    """
    raw = copy.deepcopy(raw)
    terrain = raw.get("terrain", {"kind": "none"})
    file_kind = terrain.get("kind", "plane") if isinstance(terrain, dict) else None
    sources = {a.split("=", 1)[0].strip(): f"--set {a}" for a in overrides}
    apply_overrides(raw, overrides)
    for key, (value, text) in (flags or {}).items():
        set_path(raw, key.split("."), value)
        sources[key] = text
    resolve_mesh_paths(raw, Path(path).parent if path else Path.cwd(), set(sources))
    try:
        data = validate(raw, integrator_names)
    except UserError as e:
        raise UserError(f"{_blame(str(e), sources, path or name)}: {e}") from None
    return Scene(name, path, data, file_kind)


def _blame(message: str, sources: dict, where) -> str:
    """Which input an error message is about: the override or flag whose key it names first, else the scene."""
    hits = []
    for key, text in sources.items():
        for pattern in (f"{key} ", f"{key}.", f"{key}:", f"key {key}"):
            at = message.find(pattern)
            if at >= 0 and (at == 0 or not message[at - 1].isalnum() and message[at - 1] not in "._"):
                hits.append((at, text))
    return min(hits)[1] if hits else f"scene {where}"
