"""The two encodings every spring kernel relies on (their one home):

* spring group ``g = body * 3 + kind`` (kind: stretch 0, shear 1, bend 2), the index into
  ``group_k`` / ``group_kd``: ``spring_group``, ``group_body``, ``group_kind``;
* the signed spring id in ``adj_spring``: ``s`` where the particle is end a of spring s, ``-s - 1``
  where it is end b: ``end_a_code``, ``end_b_code``, ``is_end_a``, ``code_spring`` and (for
  entries known to be end b, branch-free) ``end_b_spring``.

They are ``ti.pyfunc``: callable from Python and from kernels alike.
"""

import taichi as ti

from .lattice import SPRING_KINDS

N_KINDS = len(SPRING_KINDS)  # spring groups per body


@ti.pyfunc
def spring_group(body, kind):
    """Group index of spring ``kind`` (0 stretch, 1 shear, 2 bend) of body ``body``."""
    return body * N_KINDS + kind


@ti.pyfunc
def group_body(group):
    """Body index of a spring group (works elementwise on numpy integer arrays)."""
    return group // N_KINDS


@ti.pyfunc
def group_kind(group):
    """Spring kind (0 stretch, 1 shear, 2 bend) of a group (works elementwise on numpy arrays)."""
    return group % N_KINDS


@ti.pyfunc
def end_a_code(s):
    """``adj_spring`` entry of spring s seen from its end a."""
    return s


@ti.pyfunc
def end_b_code(s):
    """``adj_spring`` entry of spring s seen from its end b (negative)."""
    return -s - 1


@ti.pyfunc
def is_end_a(code):
    """True where an ``adj_spring`` entry belongs to the spring's end a."""
    return code >= 0


@ti.pyfunc
def end_b_spring(code):
    """Spring id of an ``adj_spring`` entry known to be an end-b one (no branch)."""
    return -code - 1


@ti.pyfunc
def code_spring(code):
    """Spring id of any ``adj_spring`` entry (scalars; numpy: ``np.maximum(c, -c - 1)``)."""
    return max(code, -code - 1)
