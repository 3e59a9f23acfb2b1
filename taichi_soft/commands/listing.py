"""``list``: scenes, integrators and backends."""
from __future__ import annotations

from .common import EXIT_OK


def add_parser(sub):
    """The ``list`` command's arguments on the subparsers ``sub``."""
    p_list = sub.add_parser("list", help="list scenes, integrators and backends")
    p_list.add_argument("--options", action="store_true",
                        help="also each integrator's options (--set solver.NAME=VALUE or a scene's [solver] "
                             "table): default, what is allowed, meaning")
    p_list.set_defaults(func=cmd_list)


def cmd_list(args) -> int:
    from .. import runtime
    from ..sim.integrators import REGISTRY
    from ..sim.scene import SCENES_DIR, scene_names

    print(f"scenes (in {SCENES_DIR}):")
    for name in scene_names():
        print(f"  {name}")
    print("integrators:")
    for name, cls in REGISTRY.items():
        print(f"  {name:22s} order {cls.order}, {cls.description}")
        if args.options:
            for option, o in cls.Config.options().items():
                print(f"      {option} = {_toml(o.default)}  ({o.allowed}): {o.doc}")
    print("backends (--arch): " + ", ".join(runtime.ARCHS) + f"; available here: {', '.join(runtime.available_archs())}")
    print("precisions (--precision): " + ", ".join(runtime.PRECISIONS))
    return EXIT_OK


def _toml(value) -> str:
    """``value`` as a scene's TOML writes it."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return f'"{value}"' if isinstance(value, str) else repr(value)
