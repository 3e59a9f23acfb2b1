"""Scene validation: the defaults of every scene table and the checks that fill them in.

``validate(raw)`` checks every key and value of a scene dict (overrides applied), fills defaults
and returns the normalised dict ``Scene.data`` holds, raising ``UserError`` with one line that
names the key, the bad value and what is allowed. ``parse_resolution`` reads a WIDTHxHEIGHT given
in a scene or on the command line.
"""
from __future__ import annotations

import copy
import math

from .bodies import BodySpec
from ..errors import UserError
from .contact.terrain import CONTACT_DEFAULTS
from .contact.terrain import DEFAULTS as TERRAIN_DEFAULTS
from .contact.terrain import KINDS as TERRAIN_KINDS

SIM_DEFAULTS = {"integrator": "semi_implicit_euler", "dt": 0.001, "duration": 5.0, "gravity": [0.0, -9.8, 0.0]}
# Body defaults: the fields of bodies.BodySpec (their one home) in the scene's layout.
_SPEC = BodySpec()
SPRING_DEFAULT = {"k": _SPEC.stretch[0], "damping": _SPEC.stretch[1]}
BODY_DEFAULTS = {
    "shape": _SPEC.shape,
    "n": _SPEC.n,
    "size": _SPEC.size,
    "particle_mass": _SPEC.particle_mass,
    "center": list(_SPEC.center),
    "rotation": {"axis": list(_SPEC.rotation_axis), "degrees": _SPEC.rotation_degrees},
    "velocity": list(_SPEC.velocity),
    "angular_velocity": list(_SPEC.angular_velocity),
    "initial_stretch": list(_SPEC.initial_stretch),
    **{kind: {"k": getattr(_SPEC, kind)[0], "damping": getattr(_SPEC, kind)[1]} for kind in ("stretch", "shear", "bend")},
}
SHAPES = ("cube", "mesh")
# Keys of a mesh body only (no default: a mesh body names its file; scale replaces size).
MESH_BODY_KEYS = ("mesh", "scale")
RENDER_DEFAULTS = {"fps": 30, "resolution": [1280, 720], "camera": {}}
CAMERA_KEYS = {"position", "lookat", "up", "fov", "follow"}
TOP_KEYS = ("sim", "body", "terrain", "contact", "render", "solver")
MAX_N = 200  # particles per cube edge (8 million particles); whether a size fits is memory.check_fits's call


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _positive(key, x):
    if not _is_number(x) or x <= 0:
        raise UserError(f"{key} = {x!r}: must be a number > 0")
    return float(x)


def _nonneg(key, x):
    if not _is_number(x) or x < 0:
        raise UserError(f"{key} = {x!r}: must be a number >= 0")
    return float(x)


def _vec3(key, x, nonzero=False):
    if not (isinstance(x, list) and len(x) == 3 and all(_is_number(c) for c in x)):
        raise UserError(f"{key} = {x!r}: must be an array of 3 finite numbers, e.g. [0, 1, 0]")
    if nonzero and not any(c != 0 for c in x):
        raise UserError(f"{key} = {x!r}: must not be the zero vector")
    return [float(c) for c in x]


def _table(key, x):
    if not isinstance(x, dict):
        raise UserError(f"{key} = {x!r}: must be a table")
    return x


def _check_keys(key, table: dict, allowed):
    for k in table:
        if k not in allowed:
            raise UserError(f"unknown key {key}.{k}; allowed keys are {', '.join(sorted(allowed))}")


def _merge(defaults: dict, given: dict) -> dict:
    out = copy.deepcopy(defaults)
    for k, v in given.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = {**out[k], **v}
        else:
            out[k] = v
    return out


def validate(raw: dict, integrator_names=None) -> dict:
    """Check every key and value, fill defaults, return the normalised scene dict."""
    _check_keys("scene", raw, TOP_KEYS)
    sim = _merge(SIM_DEFAULTS, _table("sim", raw.get("sim", {})))
    _check_keys("sim", sim, SIM_DEFAULTS)
    if integrator_names is not None and sim["integrator"] not in integrator_names:
        raise UserError(f"sim.integrator = {sim['integrator']!r}: choose one of {', '.join(integrator_names)}")
    sim["dt"] = _positive("sim.dt", sim["dt"])
    sim["duration"] = _positive("sim.duration", sim["duration"])
    if sim["dt"] > sim["duration"]:
        raise UserError(f"sim.dt = {sim['dt']:g} s is longer than sim.duration = {sim['duration']:g} s: "
                        "a run takes whole steps; use a smaller dt or a longer duration")
    sim["gravity"] = _vec3("sim.gravity", sim["gravity"])

    bodies_raw = raw.get("body", [])
    if isinstance(bodies_raw, dict):
        bodies_raw = [bodies_raw]
    if not isinstance(bodies_raw, list) or not bodies_raw:
        raise UserError("the scene has no [[body]] table: it needs at least one body to simulate")
    bodies = []
    for b, given in enumerate(bodies_raw):
        key = f"body.{b}"
        body = _merge(BODY_DEFAULTS, _table(key, given))
        _check_keys(key, body, [*BODY_DEFAULTS, *MESH_BODY_KEYS])
        n = body["n"]
        if not isinstance(n, int) or isinstance(n, bool) or not 2 <= n <= MAX_N:
            raise UserError(f"{key}.n = {n!r}: must be an integer from 2 to {MAX_N}")
        body["size"] = _positive(f"{key}.size", body["size"])
        _validate_shape(key, body, given)
        body["particle_mass"] = _positive(f"{key}.particle_mass", body["particle_mass"])
        for vk in ("center", "velocity", "angular_velocity"):
            body[vk] = _vec3(f"{key}.{vk}", body[vk])
        body["initial_stretch"] = _vec3(f"{key}.initial_stretch", body["initial_stretch"])
        if min(body["initial_stretch"]) <= 0:
            raise UserError(f"{key}.initial_stretch = {body['initial_stretch']!r}: factors must be > 0")
        rot = _table(f"{key}.rotation", body["rotation"])
        _check_keys(f"{key}.rotation", rot, BODY_DEFAULTS["rotation"])
        rot["axis"] = _vec3(f"{key}.rotation.axis", rot["axis"], nonzero=True)
        if not _is_number(rot["degrees"]):
            raise UserError(f"{key}.rotation.degrees = {rot['degrees']!r}: must be a finite number")
        rot["degrees"] = float(rot["degrees"])
        for kind in ("stretch", "shear", "bend"):
            spring = _table(f"{key}.{kind}", body[kind])
            _check_keys(f"{key}.{kind}", spring, SPRING_DEFAULT)
            spring["k"] = _positive(f"{key}.{kind}.k", spring["k"])
            spring["damping"] = _nonneg(f"{key}.{kind}.damping", spring["damping"])
        bodies.append(body)

    terrain_raw = _table("terrain", raw.get("terrain", {"kind": "none"}))
    kind = terrain_raw.get("kind", "plane")
    if kind not in TERRAIN_KINDS:
        raise UserError(f"terrain.kind = {kind!r}: choose one of {', '.join(TERRAIN_KINDS)}")
    terrain = _merge({"kind": kind, **TERRAIN_DEFAULTS[kind]}, terrain_raw)
    for k in terrain:
        if k != "kind" and k not in TERRAIN_DEFAULTS[kind]:
            allowed = ", ".join(TERRAIN_DEFAULTS[kind]) or "none"
            raise UserError(f"unknown key terrain.{k} for terrain kind {kind!r}; its keys are kind, {allowed}")
    for k in ("point", "center"):
        if k in terrain:
            terrain[k] = _vec3(f"terrain.{k}", terrain[k])
    if "normal" in terrain:
        terrain["normal"] = _vec3("terrain.normal", terrain["normal"], nonzero=True)
    if "radius" in terrain:
        terrain["radius"] = _positive("terrain.radius", terrain["radius"])

    contact = _merge(CONTACT_DEFAULTS, _table("contact", raw.get("contact", {})))
    _check_keys("contact", contact, CONTACT_DEFAULTS)
    r = contact["restitution"]
    if not _is_number(r) or not 0 <= r <= 1:
        raise UserError(f"contact.restitution = {r!r}: must be a number in [0, 1]")
    contact["restitution"] = float(r)
    contact["friction"] = _nonneg("contact.friction", contact["friction"])
    contact["epsilon"] = _positive("contact.epsilon", contact["epsilon"])
    contact["bounce_threshold"] = _nonneg("contact.bounce_threshold", contact["bounce_threshold"])
    for key in ("impact_friction", "impact_at_crossing"):
        if not isinstance(contact[key], bool):
            raise UserError(f"contact.{key} = {contact[key]!r}: must be true or false")

    render = _merge(RENDER_DEFAULTS, _table("render", raw.get("render", {})))
    _check_keys("render", render, RENDER_DEFAULTS)
    fps = render["fps"]
    if not _is_number(fps) or fps <= 0 or fps > 1000:
        raise UserError(f"render.fps = {fps!r}: must be a number in (0, 1000]")
    render["fps"] = float(fps)
    render["resolution"] = parse_resolution(render["resolution"], "render.resolution")
    cam = _table("render.camera", render["camera"])
    _check_keys("render.camera", cam, CAMERA_KEYS)
    for k in ("position", "lookat"):
        if k in cam:
            cam[k] = _vec3(f"render.camera.{k}", cam[k])
    if "up" in cam:
        cam["up"] = _vec3("render.camera.up", cam["up"], nonzero=True)
    if "fov" in cam and (not _is_number(cam["fov"]) or not 1 <= cam["fov"] <= 170):
        raise UserError(f"render.camera.fov = {cam['fov']!r}: must be a number of degrees in [1, 170]")
    if "follow" in cam and not isinstance(cam["follow"], bool):
        raise UserError(f"render.camera.follow = {cam['follow']!r}: must be true or false")
    # [solver]: options of the chosen integrator; the integrator validates names and values.
    solver = dict(_table("solver", raw.get("solver", {})))
    return {"sim": sim, "body": bodies, "terrain": terrain, "contact": contact, "render": render, "solver": solver}


def _validate_shape(key: str, body: dict, given: dict):
    """``shape``, and for a mesh body its ``mesh`` file and ``scale``: the mesh is read and filled
    here (``meshbody``, cached), so a bad or too thin mesh fails before any work, and ``size``
    becomes the body's longest side [m] whichever of size and scale was given. A body that names
    a ``mesh`` and no ``shape`` is a mesh body."""
    if "mesh" in given and "shape" not in given:
        body["shape"] = "mesh"  # naming a mesh file makes a mesh body (--set body.0.mesh=... on a cube scene)
    shape = body["shape"]
    if shape not in SHAPES:
        raise UserError(f"{key}.shape = {shape!r}: choose one of {', '.join(SHAPES)}")
    if shape == "cube":
        for k in MESH_BODY_KEYS:
            if k in body:
                raise UserError(f"{key}.{k} is only for shape = \"mesh\" (this body is a cube)")
        return
    mesh = body.get("mesh")
    if not isinstance(mesh, str) or not mesh:
        raise UserError(f"{key}.mesh = {mesh!r}: a mesh body needs the path of an OBJ, STL or PLY file")
    scale = body.get("scale")
    if scale is not None:
        if "size" in given:
            raise UserError(f"{key}.scale and {key}.size are both given: give one (size: the longest side in m; "
                            "scale: metres per mesh unit)")
        scale = body["scale"] = _positive(f"{key}.scale", scale)
    from .meshbody import mesh_lattice

    filled = mesh_lattice(mesh, body["n"], size=None if scale else body["size"], scale=scale, key=f"{key}.mesh")
    body["size"] = float(filled.extent.max())



def parse_resolution(value, key="--resolution") -> list[int]:
    """``"1280x720"`` or ``[1280, 720]`` -> [width, height] in pixels (16..8192 each)."""
    if isinstance(value, str):
        parts = value.lower().split("x")
        try:
            value = [int(p) for p in parts]
        except ValueError:
            value = None
    if not (isinstance(value, list) and len(value) == 2 and all(isinstance(v, int) and not isinstance(v, bool) for v in value)
            and all(16 <= v <= 8192 for v in value)):
        raise UserError(f"{key} = {value!r}: must be WIDTHxHEIGHT with each from 16 to 8192, e.g. 1280x720")
    return list(value)
