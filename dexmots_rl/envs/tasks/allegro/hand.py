"""The Allegro hand v4's facts, stated once for every Allegro task (MuJoCo Playground keeps one such module per hand).

The hand (``assets/allegro_knob.xml``; ``allegro_cube.xml`` and the tool scenes carry the same one): four fingers
of four hinges, :data:`FINGERS` in the MJCF's order, joints ``j0``-``j15`` (:data:`JOINT_NAMES`) finger by finger.
On the index, middle and ring fingers the first joint abducts (about z) and the other three flex (about y); on the
thumb ``j12`` rotates it about -x (range 0.263-1.396 rad), ``j13`` about z, ``j14`` and ``j15`` flex (about y).

The contact law (:data:`CONTACT`) is sized for the hand's centimetre-scale objects and fingertips that give ~5 N:
stiffness 5e3 N/m, sharpness 1000 /m, surface smoothing 2 mm. The claw's defaults (1 cm smoothing, ~69 N at zero
gap) would make an object 7 mm too large and push 12 N against the fingertips; at the claw's sharpness of 200 /m
the proximal links push hard ~1 cm away (a cube centred on the palm, 9 mm from them, was knocked off).
"""

from __future__ import annotations

from ....assets.objects import FINGERS
from ....sim import ContactParams

__all__ = ["FINGERS", "JOINTS_PER_FINGER", "JOINT_NAMES", "THUMB_ROTATION_MIN", "CONTACT", "OPEN"]

JOINTS_PER_FINGER = 4
JOINT_NAMES = tuple(f"j{i}" for i in range(len(FINGERS) * JOINTS_PER_FINGER))  # index, middle, ring, thumb
THUMB_ROTATION_MIN = 0.263  # rad: j12's lower limit, the thumb turned out to the palm's side

CONTACT = ContactParams(stiffness=5.0e3, sharpness=1000.0, surface_smoothing=0.002, slip_velocity=0.1)

# rad: the flat hand, every joint at zero but the thumb's rotation, which cannot go below its limit
OPEN = (0.0,) * 12 + (THUMB_ROTATION_MIN, 0.0, 0.0, 0.0)
