"""Memory model: how many bytes a run needs, from its particle and spring counts, before it starts.

``estimate(scene_data, integrator, precision, arch)`` splits a run's peak resident memory into

* a base: the Python process with numpy and the Taichi runtime, its kernels compiled (each
  integrator's ``BASE_BYTES``, measured: see below);
* fields: every Taichi field the model and the state allocate (``COMMON``) and what the
  integrator declares it allocates for the scene's counts (``Integrator.buffers``, with its options
  resolved by ``Integrator.resolve``, the same call its construction makes; ``tests/test_memory.py``
  checks the sum against the fields a real run allocates, so a new field that is not declared
  fails a test). An integrator that is not registered is an error;
* host arrays the model keeps (``x0_np``, ``v0_np``, ``mass_np``: 56 bytes per particle), the
  surface triangles (O(n^2)), copies made when a state is set in f32, and recorded states.

On the CPU backend fields live in host memory; on GPU backends they are device memory and the
host keeps only the base and the host arrays. ``check_fits`` compares the estimate with
``available_bytes`` and refuses, with one line, what cannot fit. The CLI calls it before
Taichi starts. Not modelled: rendering (GGUI buffers, a few bytes per surface vertex plus the
Vulkan driver; the Taichi renderer's image buffers, about 60 MB at 1280 x 720 and the default
quality, docs/rendering.md) and the demo window.

Measured on the 2-core, 24 GB CPU machine (``python main.py bench memory``, docs/benchmarks):
the estimate is within a few per cent of the peak resident memory for n >= 40.
"""
from __future__ import annotations

import math
import subprocess

from .contact import bodies as body_contact
from ..errors import UserError
from .footprint import MODEL, MODEL_SPRINGS, STATE, Buffers, Counts

_MB = 2**20
# The process base (the Python process with numpy and the Taichi runtime, its kernels compiled) is
# each integrator's ``BASE_BYTES``. Measured: the peak resident memory of a tiny run (n = 3, a few
# steps) on this machine's CPU backend, the midpoint of a run that compiles its kernels (empty
# offline cache) and one that loads them from the cache (MB, cold / warm): semi-implicit Euler
# 146 / 130, RK4 159 / 134, implicit Euler 206 / 144, fast mass-spring 182 / 146; explicit Euler
# and midpoint lie between semi-implicit and RK4.
# GPU backends: not measured here (no GPU on the machine this was written on). Assumed: the
# CUDA/Vulkan driver adds this much host memory, and the device holds this much besides the
# fields (context, Taichi's runtime pool).
GPU_HOST_EXTRA_BYTES = 512 * _MB
GPU_DEVICE_BASE_BYTES = 1536 * _MB

# Field entries every run has: the model's and the state's (footprint.MODEL, STATE). What each
# integrator adds, for the scene's counts and its resolved options, it declares itself
# (``Integrator.buffers``: the force strategy's buffers, its own fields, a factor, L-BFGS pairs):
# tests/test_memory.py checks the sum against the fields a real run allocates, so a new field that
# is not declared fails a test.
COMMON = MODEL + STATE
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


def counts(scene_data: dict, real_bytes: int = 8) -> Counts:
    """The scene's ``footprint.Counts`` for a run with reals of ``real_bytes``. The Cholesky
    envelope and the rows' width are the bodies' cubes' (a mesh body fills part of its n^3 cube,
    numbered in the same order: its envelope is smaller)."""
    from .lattice import envelope_size
    from .rows import lattice_width
    from .stencil import lattice_points as mask_points

    bodies = [int(b["n"]) for b in scene_data["body"]]
    lattice = all(b.get("shape", "cube") != "mesh" for b in scene_data["body"])
    return Counts(*scene_counts(scene_data), lattice=lattice, real_bytes=real_bytes, envelope=lambda: sum(envelope_size(n) for n in bodies),
                  row_width=lambda: max(lattice_width(n) for n in bodies),
                  lattice_points=lambda: mask_points(_mesh_lattice(b).grid.shape if b.get("shape", "cube") == "mesh"
                                                     else (int(b["n"]),) * 3 for b in scene_data["body"]))


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


def integrator_buffers(scene_data: dict, integrator: str, arch: str, real_bytes: int, fast_math: bool = True,
                       sizes: Counts | None = None) -> Buffers:
    """What the registered integrator ``integrator`` allocates for this scene, as it declares it:
    its options (the scene's ``[solver]`` table, those it has) resolved for ``arch`` and the
    counts, then its ``buffers``. An unregistered name is a ``UserError``."""
    cls, options, c = _resolved(scene_data, integrator, arch, fast_math, sizes)
    return cls.buffers(options, arch, c, real_bytes)


def _resolved(scene_data: dict, integrator: str, arch: str, fast_math: bool, sizes: Counts | None = None):
    """(class, resolved options, counts) of ``integrator`` on this scene."""
    # imports Taichi: only once the CLI has set it up quietly
    from .integrators import integrator_class, scene_options

    cls = integrator_class(integrator)
    c = sizes or counts(scene_data)
    return cls, cls.configure(scene_options(integrator, scene_data), arch, fast_math, c), c


def stores_springs(scene_data: dict, integrator: str, arch: str, fast_math: bool = True,
                   sizes: Counts | None = None) -> bool:
    """Whether the model of a run of ``integrator`` stores its springs (every pass but the stencil's)."""
    cls, options, _ = _resolved(scene_data, integrator, arch, fast_math, sizes)
    return cls.stores_springs(options)


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
    from .integrators import integrator_class  # imports Taichi: only once the CLI has set it up quietly

    classes = [integrator_class(name) for name in names]
    arch = resolve_arch(arch)
    real = 8 if precision == "f64" else 4
    c = counts(scene_data, real)
    n_p, n_s = c.particles, c.springs
    buffers = [integrator_buffers(scene_data, name, arch, real, fast_math, c) for name in names]
    fields = 0
    for name, b in zip(names, buffers):
        fields += COMMON.bytes(n_p, n_s, real) + b.bytes(n_p, n_s, real)
        if not stores_springs(scene_data, name, arch, fast_math, c):
            fields -= MODEL_SPRINGS.bytes(n_p, n_s, real)  # the stencil pass: the model stores none
        fields += n_p * (1 if scene_data["terrain"]["kind"] == "bowl" else 0)  # terrain.Bowl.inside (i8)
    if len(scene_data["body"]) > 1:  # body-body contact: one per simulation, and the implicit pair terms
        from .integrators.implicit import pairs

        fields += len(names) * body_contact.field_bytes(n_p, real)
        fields += sum(pairs.field_bytes(n_p, real) for cls in classes if cls.implicit)
    base = max(cls.BASE_BYTES for cls in classes)
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
        host += fields + max(b.transient for b in buffers)
    else:
        host += GPU_HOST_EXTRA_BYTES
        device = GPU_DEVICE_BASE_BYTES + fields
    return {"host": host, "device": device, "fields": fields, "particles": n_p, "springs": n_s, "arch": arch}


def estimate_bytes(scene_data: dict, integrator, precision: str, arch: str, fast_math: bool = True,
                   record_states: bool = False) -> int:
    """Peak resident host bytes of a run, plus device bytes on GPU backends (see ``estimate``)."""
    e = estimate(scene_data, integrator, precision, arch, record_states, fast_math)
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
            # f32 halves the state, but the gather's rows hold (k, kd) copies in f32 that f64 reads
            # through the groups (forces.rows_look_up_groups): suggest it only where it needs less.
            smaller = precision == "f64" and estimate_bytes(
                scene_data, integrator, "f32", arch, fast_math, record_states) < e["host"] + e["device"]
            hint = " or --precision f32" if smaller else ""
            raise UserError(f"the bodies need about {_gb(need)} of {where} memory ({what}) but {_gb(have)} is available; "
                            f"use smaller bodies (body.N.n){hint}")
