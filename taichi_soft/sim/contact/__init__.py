"""Contact, the one home of what keeps bodies out of the terrain and out of each other.

* ``terrain``: the terrains (plane, tilted plane, sphere, bowl, none), their distance queries and
  the contact model every explicit method applies after its step (``Terrain.impact``: restitution
  above a bounce threshold, Coulomb friction), with the coefficients as fields a run may change.
* ``bodies``: contact between bodies (``BodyContacts``): a uniform grid of the particles
  (``BodyGrid``), face frames that turn with each body, the explicit methods' impulses.

The implicit solvers treat contact as constraints inside their step and keep those parts beside
the step they belong to (``integrators/implicit/``: ``contact`` for the terrain, ``pairs`` and
``pair_list`` for bodies, ``restitution``): they read and write the step's own scalars, and moving
them here would make contact import the implicit solver.
"""
