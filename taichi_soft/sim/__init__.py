"""The engine: bodies and their springs (lattice, model, meshbody), forces, contact (``contact``:
terrains and body contact), integrators with their linear algebra, scenes and the running
simulation. It imports nothing of the application around it (command line, gallery, demo,
rendering, benchmarks, task runner: tests/test_imports.py); shared with it are only ``runtime``,
``errors``, ``paths``."""

from .bodies import BodySpec
from .scene import Scene, load_scene, scene_from_dict, scene_names
from .simulation import RunResult, Simulation
from .integrators import make_integrator
from .integrators import names as integrator_names

__all__ = ["BodySpec", "Scene", "load_scene", "scene_from_dict", "scene_names", "Simulation", "RunResult",
           "make_integrator", "integrator_names"]
