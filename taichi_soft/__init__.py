"""taichi-soft: mass-spring soft bodies on Taichi.

Nothing here initialises Taichi: call ``taichi_soft.runtime.init(arch, precision)`` first.
Physics lives in ``sim``: ``model``, ``forces``, ``contact`` (terrains, body contact) and
``integrators``; ``simulation`` ties a scene to them; rendering and the command line sit on top
and are never imported by physics.
"""
import os

# Taichi reads these when it is first imported: set here, before any module of the package imports
# it (the one home of this environment; child processes inherit it).
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "False")
os.environ.setdefault("TI_LOG_LEVEL", "error")

__version__ = "0.1.0"
