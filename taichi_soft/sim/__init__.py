"""The engine: bodies and their springs (lattice, model, meshbody), forces, terrains, body contact,
integrators with their linear algebra, scenes and the running simulation. It imports nothing of
the application around it (command line, gallery, demo, rendering, benchmarks, task runner:
tests/test_imports.py); shared with it are only ``runtime``, ``errors``, ``paths``."""
