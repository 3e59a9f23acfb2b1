"""Modules that exist only to work around a behaviour of Taichi 1.7.4: each can go when Taichi
fixes what it works around (README.md here: every workaround of the project, where it lives, its
upstream issue and the test that shows when it can go).

* ``compile_speed``: Taichi's kernel front end without its per-node source excerpts and repeated
  source reads (a quarter off a compile);
* ``cpu_threads``: the CPU thread pool's workers placed one to a core while an explicit method
  launches parallel steps.
"""
