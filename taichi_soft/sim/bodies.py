"""The bodies of a model as a scene describes them (``BodySpec``) and where a finalized body lives
in the model's arrays (``BodyInfo``). Plain dataclasses: no Taichi, nothing allocated."""

from dataclasses import dataclass

import numpy as np


@dataclass
class BodySpec:
    """One soft body, as a scene describes it. Lengths in m, masses in kg, angles in degrees.

    ``shape = "cube"``: an n^3 lattice of edge ``size``. ``shape = "mesh"``: the lattice clipped
    to the closed triangle mesh in the file ``mesh`` (``meshbody``), n points along its longest
    side, which is ``size`` long, or the mesh scaled by ``scale`` metres per unit when given.
    """

    n: int = 10
    size: float = 4.0
    shape: str = "cube"
    mesh: str | None = None
    scale: float | None = None
    particle_mass: float = 1.0
    center: tuple = (0.0, 9.0, 0.0)
    rotation_axis: tuple = (1.0, 0.0, 1.0)
    rotation_degrees: float = 0.0
    velocity: tuple = (0.0, 0.0, 0.0)
    angular_velocity: tuple = (0.0, 0.0, 0.0)
    # Initial deformation: the start shape is the rest shape scaled per body axis (1 = at rest).
    initial_stretch: tuple = (1.0, 1.0, 1.0)
    # (stiffness [N/m], damper coefficient [N s/m]) per spring kind
    stretch: tuple = (2000.0, 60.0)
    shear: tuple = (2000.0, 60.0)
    bend: tuple = (2000.0, 60.0)


@dataclass
class BodyInfo:
    """Where a finalized body's particles, springs and surface live in the model's arrays.

    A cube's ``surface`` is its lattice's boundary. A mesh body's ``mesh`` holds its
    ``meshbody.MeshLattice`` (the input surface embedded in the lattice: what is drawn), and its
    ``surface`` is that mesh in particle terms (``meshbody.particle_surface``: what the demo picks on).
    """

    particles: slice
    springs: slice
    surface: np.ndarray  # [n_tris, 3] global particle indices, outward winding
    spec: BodySpec
    mesh: object = None
