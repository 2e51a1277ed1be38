"""One seeded generator per object class: ``GENERATORS[class](params=None, rng=None, name=...)``.

Each generator takes its class's parameter dataclass (``PARAMS[class]``: named sizes in m, masses in kg,
springs in N m/rad or N/m, damping, friction; every field with its documented range, ``.ranges()``), or
draws one around it when given ``rng`` (a seed or a numpy Generator; ``.sample(rng, scale)``), and returns an
:class:`~dexmots_rl.assets.objects.description.ObjectAsset` with watertight meshes and primitive collision.

Adding a class: a frozen ``Params`` subclass whose fields are declared with ``param(default, low, high,
unit, doc, kind)``, a generator building the parts (meshes with :mod:`..shapes`, collision from the geom
helpers in :mod:`.common`, masses shared with ``with_mass``), and one entry in each table below.
"""

from __future__ import annotations

from .bottles import JarParams, PumpDispenserParams, SprayBottleParams, jar, pump_dispenser, spray_bottle
from .common import Params
from .fixtures import DoorHandleParams, DrawerParams, ValveParams, door_handle, drawer, valve
from .hand_tools import PliersParams, ScissorsParams, StaplerParams, pliers, scissors, stapler

__all__ = ["GENERATORS", "PARAMS", "Params", "spray_bottle", "scissors", "stapler", "pump_dispenser", "jar",
           "valve", "drawer", "pliers", "door_handle", "SprayBottleParams", "ScissorsParams", "StaplerParams",
           "PumpDispenserParams", "JarParams", "ValveParams", "DrawerParams", "PliersParams", "DoorHandleParams"]

GENERATORS = {"spray_bottle": spray_bottle, "scissors": scissors, "stapler": stapler,
              "pump_dispenser": pump_dispenser, "jar": jar, "valve": valve, "drawer": drawer,
              "pliers": pliers, "door_handle": door_handle}
PARAMS = {"spray_bottle": SprayBottleParams, "scissors": ScissorsParams, "stapler": StaplerParams,
          "pump_dispenser": PumpDispenserParams, "jar": JarParams, "valve": ValveParams, "drawer": DrawerParams,
          "pliers": PliersParams, "door_handle": DoorHandleParams}
