"""Memory model: how many bytes a run needs, from its particle and spring counts, before it starts.

``estimate(scene_data, integrator, precision, arch)`` splits a run's peak resident memory into

* a base: the Python process with numpy and the Taichi runtime, its kernels compiled
  (``BASE_BYTES``, measured: see below);
* fields: every Taichi field the model, the state and the integrator allocate, counted per
  particle and per spring in ``FIELDS`` (``tests/test_memory.py`` checks the table against the
  fields a real run allocates, so a new field that is not counted here fails a test);
* host arrays the model keeps (``x0_np``, ``v0_np``, ``mass_np``: 56 bytes per particle), the
  surface triangles (O(n^2)), copies made when a state is set in f32, and recorded states.

On the CPU backend fields live in host memory; on GPU backends they are device memory and the
host keeps only the base and the host arrays. ``check_fits`` compares the estimate with
``available_bytes`` and refuses, with one line, what cannot fit. The CLI calls it before
Taichi starts. Not modelled: rendering (GGUI buffers, a few bytes per surface vertex plus the
Vulkan driver) and the demo window.

Measured on the 2-core, 24 GB CPU machine (``python main.py bench memory``, docs/benchmarks):
the estimate is within a few per cent of the peak resident memory for n >= 40.
"""
from __future__ import annotations

import math
import subprocess
from dataclasses import dataclass

from . import collision
from .errors import UserError

# Peak resident memory [bytes] of a tiny run (n = 3, a few steps) per integrator on this machine's
# CPU backend: the process, numpy, the Taichi runtime and the compiled kernels. The midpoint of a
# run that compiles its kernels (empty offline cache) and one that loads them from the cache
# (MB, cold / warm): semi-implicit Euler 146 / 130, RK4 159 / 134, implicit Euler 206 / 144,
# fast mass-spring 182 / 146; explicit Euler and midpoint lie between semi-implicit and RK4.
_MB = 2**20
BASE_BYTES = {
    "semi_implicit_euler": 138 * _MB,
    "explicit_euler": 138 * _MB,
    "midpoint": 142 * _MB,
    "rk4": 147 * _MB,
    "implicit_euler": 175 * _MB,
    "fast_mass_spring": 164 * _MB,
}
BASE_BYTES_OTHER = 175 * _MB  # an integrator not in the table: the largest base above
# GPU backends: not measured here (no GPU on the machine this was written on). Assumed: the
# CUDA/Vulkan driver adds this much host memory, and the device holds this much besides the
# fields (context, Taichi's runtime pool).
GPU_HOST_EXTRA_BYTES = 512 * _MB
GPU_DEVICE_BASE_BYTES = 1536 * _MB


@dataclass(frozen=True)
class FieldCounts:
    """Field entries of one run: reals (f32 or f64) and 4-byte ints, per particle and per spring."""

    particle_reals: int = 0
    particle_ints: int = 0
    spring_reals: int = 0
    spring_ints: int = 0

    def __add__(self, other: "FieldCounts") -> "FieldCounts":
        return FieldCounts(*(a + b for a, b in zip(self.astuple(), other.astuple())))

    def __sub__(self, other: "FieldCounts") -> "FieldCounts":
        return FieldCounts(*(a - b for a, b in zip(self.astuple(), other.astuple())))

    def astuple(self):
        return (self.particle_reals, self.particle_ints, self.spring_reals, self.spring_ints)

    def bytes(self, n_particles: int, n_springs: int, real_bytes: int) -> int:
        return (n_particles * (self.particle_reals * real_bytes + self.particle_ints * 4)
                + n_springs * (self.spring_reals * real_bytes + self.spring_ints * 4))


# Field entries of the model, the state and each integrator together, per force-strategy family
# (forces.py: "scatter", the CPU default without fast math, reads the model's own springs
# through slab ranges and needs no adjacency; "gather", the default with fast math and on GPUs,
# keeps padded spring rows, ``rows_bytes``, and no adjacency). Implicit solvers build the adjacency and no force-pass
# buffers, whatever the family. Measured from the fields the code allocates at two sizes in f32
# and f64 (tests/test_memory.py checks the table against the allocation); the source files are
# the truth. fast_mass_spring's Cholesky factor ("cholesky", _cholesky_values) and its L-BFGS
# pairs (_lbfgs_reals, as many as its ``history`` option keeps) are counted separately.
_MODEL = FieldCounts(2, 0, 1, 3)  # mass, inv_mass | rest, ends x2, group
_ADJACENCY = FieldCounts(0, 2, 2, 6)  # adj_offset, adj_split | per spring end: rest, other, group, code
_STATE = FieldCounts(6, 0, 0, 0)  # x, v
_SCATTER = _MODEL + _STATE + FieldCounts(3, 0, 2, 0)  # force sums | (k, kd)
_GATHER = _MODEL + _STATE  # + the padded rows (rows.py), counted by rows_bytes
_PING_PONG = FieldCounts(6, 0, 0, 0)  # one-stage methods with gathered forces: second x, v
_RK_STAGES = FieldCounts(18, 0, 0, 0)  # two stage states, the running sums (midpoint, rk4)
# Implicit solvers (no force-pass buffers), per particle: the objective's 9 vectors (with the
# displacements u, u_trial the solve iterates on) and friction block, contact normals, multiplier
# and its end-of-step value (the next step's warm start), end-of-step velocities (50 reals), the PCG's 4 vectors (12), restitution's prescribed change,
# right-hand side and response (9), the scheme's base displacement and the last step's end state
# (9), the active-set flags (3 ints); per spring: damper direction and gradient (6 reals).
_IMPLICIT = _MODEL + _ADJACENCY + _STATE + FieldCounts(80, 3, 6, 0)
_IMPLICIT_EULER = _IMPLICIT + FieldCounts(9, 0, 9, 0)  # block-Jacobi inverses | Hessian blocks
_FAST_MASS_SPRING = _IMPLICIT + FieldCounts(1, 0, 0, 0)  # diagonal of M + L (L-BFGS pairs: _lbfgs_reals)
FIELDS = {
    ("semi_implicit_euler", "scatter"): _SCATTER,
    ("explicit_euler", "scatter"): _SCATTER,
    ("midpoint", "scatter"): _SCATTER + _RK_STAGES,
    ("rk4", "scatter"): _SCATTER + _RK_STAGES,
    ("implicit_euler", "scatter"): _IMPLICIT_EULER,
    ("fast_mass_spring", "scatter"): _FAST_MASS_SPRING,
    ("semi_implicit_euler", "gather"): _GATHER + _PING_PONG,
    ("explicit_euler", "gather"): _GATHER + _PING_PONG,
    ("midpoint", "gather"): _GATHER + _RK_STAGES,
    ("rk4", "gather"): _GATHER + _RK_STAGES,
    ("implicit_euler", "gather"): _IMPLICIT_EULER,
    ("fast_mass_spring", "gather"): _FAST_MASS_SPRING,
    "cholesky": FieldCounts(3, 2, 0, 0),  # linalg.SkylineCholesky: tmp, start, offset (+ the envelope)
    "state": _STATE,  # x, v (included in the totals above)
}
EXPLICIT = ("semi_implicit_euler", "explicit_euler", "midpoint", "rk4")
IMPLICIT = ("implicit_euler", "fast_mass_spring")
HOST_PARTICLE_BYTES = 56  # model.x0_np, v0_np (float64 vec3) and mass_np (float64)


def _mesh_lattice(body: dict):
    """The (cached) ``meshbody.MeshLattice`` of a validated mesh body, None for a cube."""
    if body.get("shape", "cube") != "mesh":
        return None
    from .meshbody import mesh_lattice

    scale = body.get("scale")
    return mesh_lattice(body["mesh"], int(body["n"]), size=None if scale else body["size"], scale=scale)


def scene_counts(scene_data: dict) -> tuple[int, int]:
    """(particles, springs) of a validated scene: from the body sizes for cubes, the filled
    lattice (read once, cached) for mesh bodies."""
    from .lattice import spring_count  # imports Taichi: only once the CLI has set it up quietly

    n_p = n_s = 0
    for b in scene_data["body"]:
        m = _mesh_lattice(b)
        n = int(b["n"])
        n_p += m.n_particles if m else n**3
        n_s += m.n_springs if m else spring_count(n)
    return n_p, n_s


def _surface_host_bytes(scene_data: dict) -> int:
    """Host bytes of the bodies' surfaces: a cube's 12 (n-1)^2 triangles as int64 triples; a mesh
    body's triangles (int64, twice: the mesh's and ``BodyInfo.surface``), vertices (float64) and
    each vertex's embedding (index and float64 weight per followed particle)."""
    total = 0
    for b in scene_data["body"]:
        m = _mesh_lattice(b)
        if m is None:
            total += 12 * (int(b["n"]) - 1) ** 2 * 3 * 8
        else:
            # + its particle-index stand-in (meshbody.particle_surface), at most one triple per triangle
            total += 2 * m.triangles.nbytes + m.vertices.nbytes + m.embed_index.nbytes + m.embed_weight.nbytes
    return total


def _cholesky_values(scene_data: dict, integrator: str, arch: str) -> int:
    """Values of fast_mass_spring's skyline Cholesky factor, 0 when it solves with PCG only."""
    if integrator != "fast_mass_spring":
        return 0
    from .integrators.implicit import CHOLESKY_AUTO_MAX
    from .lattice import envelope_size

    solver = scene_data.get("solver", {}).get("global_solver", "auto")
    if solver == "pcg" or (solver == "auto" and arch != "cpu"):
        return 0
    # A mesh body fills part of its n^3 cube, numbered in the same order: its envelope is smaller.
    nnz = sum(envelope_size(int(b["n"])) for b in scene_data["body"])
    return nnz if solver == "cholesky" or nnz <= CHOLESKY_AUTO_MAX else 0


def _lbfgs_reals(scene_data: dict, integrator: str) -> int:
    """Per-particle reals of fast_mass_spring's L-BFGS pairs: 6 per pair kept (s, y), 6 for the
    iterate and rhs it saves; 0 with ``history = 0``."""
    if integrator != "fast_mass_spring":
        return 0
    from .integrators.implicit.options import LOCAL_GLOBAL

    history = scene_data.get("solver", {}).get("history", LOCAL_GLOBAL["history"].default)
    return 6 * history + 6 if history else 0


def _envelope_transient(scene_data: dict, integrator: str, n_p: int, n_s: int, real: int) -> int:
    """Host bytes above the fields while fast_mass_spring sizes its Cholesky envelope (CPU backend).

    It downloads the spring ends (8 bytes per spring) and takes their min and max (4 + 4), with
    per-particle starts (16 bytes), after the implicit base fields are allocated and before its
    own buffers and the state are: the peak is the larger of the two moments.
    """
    if integrator != "fast_mass_spring" or scene_data.get("solver", {}).get("global_solver", "auto") == "pcg":
        return 0
    later = (FIELDS[("fast_mass_spring", "scatter")] - _MODEL).bytes(n_p, n_s, real)
    return max(0, 16 * n_s + 16 * n_p - later)


def force_family(scene_data: dict, arch: str, fast_math: bool = True) -> str:
    """"scatter" or "gather": which force strategy (forces.py) a run's ``[solver] forces``,
    backend and fast-math setting pick (``per_spring`` is counted as scatter, its close upper bound)."""
    from .forces import auto_strategy  # imports Taichi: only once the CLI has set it up quietly

    forces = scene_data.get("solver", {}).get("forces", "auto")
    if forces == "auto":
        forces = auto_strategy("cpu" if arch == "cpu" else "gpu", fast_math)
    return "gather" if forces == "gather" else "scatter"


def rows_bytes(scene_data: dict, n_p: int, real: int) -> int:
    """The gather strategy's padded spring rows (rows.py): width x (2 ints + 3 reals) per particle."""
    from .rows import lattice_width

    width = max(lattice_width(int(b["n"])) for b in scene_data["body"])
    return n_p * width * (2 * 4 + 3 * real)


def field_counts(integrator: str, family: str = "scatter", cholesky: bool = False) -> FieldCounts:
    """Per-particle and per-spring field entries of the model, state and ``integrator`` with the
    force strategy ``family``; ``cholesky``: with the factor's index fields (its values are counted
    by ``_cholesky_values``). A registered subclass of a method in ``FIELDS`` (one that changes its
    steps, not its fields) counts as that method; any other integrator is an error: its memory is
    not known, and another method's numbers would pass a run the machine cannot hold."""
    from .integrators import REGISTRY

    cls = REGISTRY.get(integrator)
    for name in [integrator] + ([c.name for c in cls.__mro__ if hasattr(c, "name")] if cls else []):
        if (name, family) in FIELDS:
            break
    else:
        raise KeyError(f"memory.FIELDS has no entry for integrator {integrator!r} ({family} forces): add its "
                       "field counts (tests/test_memory.py measures them)")
    counts = FIELDS[(name, family)]
    if cholesky:
        counts = counts + FIELDS["cholesky"]
    return counts


def resolve_arch(arch: str) -> str:
    """The backend ``arch`` will run on, as far as can be told before Taichi starts."""
    if arch == "auto":
        return "cuda" if _nvidia_free_bytes() is not None else "cpu"
    return arch


def estimate(scene_data: dict, integrator, precision: str, arch: str, record_states: bool = False,
             fast_math: bool = True) -> dict:
    """Peak memory [bytes] of a run: {"host", "device", "fields", "particles", "springs"}.

    ``integrator``: a name, a list of names (``compare`` runs one simulation per name in one
    process), or None for the scene's. ``device`` is 0 on the CPU backend (fields count as host).
    ``record_states``: ``run --states`` keeps every output frame's x and v, then stacks them.
    ``fast_math``: the run's setting (the command line's default is on), which picks the force
    strategy on the CPU.
    """
    names = [scene_data["sim"]["integrator"]] if integrator is None else (
        [integrator] if isinstance(integrator, str) else list(integrator))
    arch = resolve_arch(arch)
    real = 8 if precision == "f64" else 4
    n_p, n_s = scene_counts(scene_data)
    family = force_family(scene_data, arch, fast_math)
    fields = 0
    for name in names:
        nnz = _cholesky_values(scene_data, name, arch)
        fields += field_counts(name, family, nnz > 0).bytes(n_p, n_s, real) + nnz * real
        if family == "gather" and name not in IMPLICIT:
            fields += rows_bytes(scene_data, n_p, real)
        fields += _lbfgs_reals(scene_data, name) * n_p * real
        fields += n_p * (1 if scene_data["terrain"]["kind"] == "bowl" else 0)  # terrain.Bowl.inside (i8)
    if len(scene_data["body"]) > 1:  # body-body contact: one per simulation, and the implicit pair terms
        from .integrators.implicit import pairs

        fields += len(names) * collision.field_bytes(n_p, real)
        fields += sum(pairs.field_bytes(n_p, real) for name in names if name in IMPLICIT)
    base = max(BASE_BYTES.get(name, BASE_BYTES_OTHER) for name in names)
    host = base + len(names) * (HOST_PARTICLE_BYTES * n_p + _surface_host_bytes(scene_data))
    if real == 4:
        host += n_p * 2 * 3 * real  # State.set converts the float64 x0_np, v0_np to f32 copies
    host += len(names) * n_p * 16  # simulation.check_start: signed distances and contact radii (float64)
    if record_states:
        sim = scene_data["sim"]
        frames = math.floor(sim["duration"] * scene_data["render"]["fps"]) + 2
        host += 2 * frames * n_p * 2 * 3 * real  # the frames kept, and their stacked copy when written
    device = 0
    if arch == "cpu":
        host += fields + max(_envelope_transient(scene_data, name, n_p, n_s, real) for name in names)
    else:
        host += GPU_HOST_EXTRA_BYTES
        device = GPU_DEVICE_BASE_BYTES + fields
    return {"host": host, "device": device, "fields": fields, "particles": n_p, "springs": n_s, "arch": arch}


def estimate_bytes(scene_data: dict, integrator, precision: str, arch: str, fast_math: bool = True) -> int:
    """Peak resident host bytes of a run, plus device bytes on GPU backends (see ``estimate``)."""
    e = estimate(scene_data, integrator, precision, arch, fast_math=fast_math)
    return e["host"] + e["device"]


def _host_available_bytes() -> int | None:
    """MemAvailable [bytes] from /proc/meminfo, lowered to the cgroup's headroom if it has a limit."""
    try:
        with open("/proc/meminfo") as f:
            info = {line.split(":")[0]: line.split()[1] for line in f}
        avail = int(info["MemAvailable"]) * 1024
    except (OSError, KeyError, ValueError, IndexError):
        return None
    try:
        with open("/sys/fs/cgroup/memory.max") as f:
            limit = f.read().strip()
        if limit != "max":
            with open("/sys/fs/cgroup/memory.current") as f:
                avail = min(avail, int(limit) - int(f.read().strip()))
    except (OSError, ValueError):
        pass
    return avail


def _nvidia_free_bytes() -> int | None:
    """Free memory [bytes] of the first CUDA device as nvidia-smi reports it, None without one."""
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=memory.free", "--format=csv,noheader,nounits", "-i", "0"],
                             capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.SubprocessError):
        return None
    try:
        return int(float(out.stdout.split()[0])) * _MB if out.returncode == 0 else None
    except (ValueError, IndexError):
        return None


def available_bytes(arch: str) -> int | None:
    """Memory [bytes] a run on ``arch`` may use: host MemAvailable for cpu; free device memory for
    cuda (nvidia-smi); None where it cannot be told (vulkan, metal, no nvidia-smi)."""
    arch = resolve_arch(arch)
    if arch == "cpu":
        return _host_available_bytes()
    if arch == "cuda":
        return _nvidia_free_bytes()
    return None


def _gb(b: int) -> str:
    return f"{b / 1e9:.2f} GB" if b < 10e9 else f"{b / 1e9:.1f} GB"


def check_fits(scene_data: dict, integrator, precision: str, arch: str, record_states: bool = False,
               fast_math: bool = True):
    """Raise ``UserError`` (one line: the estimate and what is available) if the run cannot fit.

    Host memory is always checked (where /proc/meminfo tells it); device memory on GPU backends
    where ``available_bytes`` can tell it. Does not start Taichi.
    """
    e = estimate(scene_data, integrator, precision, arch, record_states, fast_math)
    what = f"{e['particles']:,} particles, {e['springs']:,} springs, {precision}"
    checks = [("host", e["host"], _host_available_bytes())]
    if e["device"]:
        checks.append((f"{e['arch']} device", e["device"], available_bytes(e["arch"])))
    for where, need, have in checks:
        if have is not None and need > have:
            hint = " or --precision f32" if precision == "f64" else ""
            raise UserError(f"the bodies need about {_gb(need)} of {where} memory ({what}) but {_gb(have)} is available; "
                            f"use smaller bodies (body.N.n){hint}")
