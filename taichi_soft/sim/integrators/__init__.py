"""Integrator registry: the CLI, tests and benchmarks all read ``REGISTRY``."""
from __future__ import annotations

from ...errors import UserError
from ..allocation import check_tree_room
from . import explicit  # noqa: F401  registers the explicit family
from . import implicit  # noqa: F401  registers implicit_euler, fast_mass_spring
from .base import REGISTRY, Integrator, register

__all__ = ["REGISTRY", "Integrator", "register", "make_integrator", "integrator_class", "names", "scene_options"]


def names() -> list[str]:
    """Registered integrator names, in registration order."""
    return list(REGISTRY)


def integrator_class(name: str) -> type:
    """The registered integrator class called ``name``; unknown names raise ``UserError`` listing
    the valid ones."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise UserError(f"unknown integrator {name!r}; choose one of: {', '.join(REGISTRY)}") from None


def scene_options(name: str, scene_data: dict) -> dict:
    """The entries of a scene's ``[solver]`` table that integrator ``name`` has (a scene may carry
    options of other integrators, for ``compare``); unknown names raise ``UserError``."""
    return integrator_class(name).Config.accepted(scene_data.get("solver", {}))


def make_integrator(name: str, model, terrain, options: dict | None = None, contacts=None) -> Integrator:
    """Instantiate the integrator called ``name`` (``contacts``: the simulation's
    ``contact.bodies.BodyContacts``, or None for one body); unknown names raise ``UserError``, and so
    does a runtime about to run out of field trees (``allocation.check_tree_room``)."""
    cls = integrator_class(name)
    check_tree_room()
    return cls(model, terrain, options, contacts)
