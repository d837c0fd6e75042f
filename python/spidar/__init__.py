"""spidar for Python: a world (an experiment) behind a SPIDAR-H rig, in a few lines.

Why it exists: a lab builds its own experiments. A class with a ``step`` method is a world;
``spidar run --world ADDR`` feels it through the rig's 1 kHz loop, with the same safety rules,
clamps and counters as the built-in worlds (``docs/python.md``)::

    import spidar

    class Wall(spidar.World):
        def step(self, t_s, samples):
            return [spidar.Proxy(spidar.Plane(point_m=(0, 1.1, -0.3), normal=(0, 0, 1)), k_n_per_m=2000)]

    spidar.main(Wall())

Frames and units are the link's: world frame (metres, y up, floor at y = 0, the user at the
origin facing -z), seconds on the rig's clock, newtons. Standard library only; numpy is not
needed (numbers travel as plain floats and tuples).

What it must never do: bypass the rig's safety. Everything a world sends goes through the rig's
guards; this package only speaks the link (:mod:`spidar.wire`) and keeps its rules
(:mod:`spidar.world`).
"""

from typing import List, Sequence

from .wire import (
    BOTH_HANDS,
    HANDS,
    MAX_PROXIES,
    PROTOCOL_VERSION,
    Blow,
    Capsule,
    ContactModel,
    HandContact,
    HandSample,
    HandState,
    Plane,
    Proxy,
    RigInfo,
    RigStatus,
    Sphere,
    Vec3,
    WireError,
)
from .world import Link, LinkAddressError, ServeReport, Stats, World, default_address, main, serve

__all__ = [
    "BOTH_HANDS",
    "HANDS",
    "MAX_PROXIES",
    "PROTOCOL_VERSION",
    "Blow",
    "Capsule",
    "ContactModel",
    "HandContact",
    "HandSample",
    "HandState",
    "Link",
    "LinkAddressError",
    "Plane",
    "Proxy",
    "RigInfo",
    "RigStatus",
    "ServeReport",
    "Sphere",
    "Stats",
    "Vec3",
    "WireError",
    "World",
    "default_address",
    "impulse_on",
    "main",
    "serve",
]

__version__ = "0.1.0"


def impulse_on(samples: Sequence[HandSample], index: int) -> Vec3:
    """The impulse (N s, world frame) the hands put into proxy ``index`` over ``samples``: the
    reaction of what the rig really applied, to be applied to the body the proxy stands for.
    Only samples computed against a model (``model_seq`` > 0) count."""
    x = y = z = 0.0
    for s in samples:
        if s.model_seq:
            ix, iy, iz = s.proxy_impulse_n_s[index]
            x, y, z = x + ix, y + iy, z + iz
    return (x, y, z)


def newest_hands(samples: Sequence[HandSample]) -> List[HandState]:
    """The hands of the newest sample (an empty list when there is none)."""
    return list(samples[-1].hands) if samples else []
