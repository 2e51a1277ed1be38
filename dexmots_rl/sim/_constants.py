"""The simulator's physical constants and its one geometry enumeration, read by every kernel module.

Plain Python numbers: a kernel turns each into its float type where it uses it (``dtype(CONTACT_CUTOFF)``), so
float32 and float64 builds read the same value.
"""

from __future__ import annotations

__all__ = ["CONTACT_CUTOFF", "LSE_CUTOFF", "LIMIT_WIDTH", "OBJECT_STOP_FREQUENCY", "FRICTION_VELOCITY", "SDF_PAD",
           "GEOM_NONE", "GEOM_BOX", "GEOM_SPHERE", "GEOM_CAPSULE", "GEOM_CYLINDER", "GEOM_SDF", "GEOM_CONVEX",
           "HAND_FRICTION", "TABLE_FRICTION"]

# A contact (finger sphere, palm or table sample) at a gap wider than this many 1/sharpness feels nothing: its
# softplus penalty is below e^-12 of the force at touching, and skipping it saves the law's work.
CONTACT_CUTOFF = 12.0
# A smooth max (log-sum-exp of face distances) drops the terms this many smoothing lengths below the largest.
LSE_CUTOFF = 12.0
LIMIT_WIDTH = 0.02  # rad (or m): a range stop stiffens smoothly (C1) over this depth, then is linear
# rad/s: an object joint's range stop (implicit, stable at any stiffness) is as stiff as an oscillator of this
# frequency on the joint's inertia; the stapler's arm (3.6e-4 kg m^2) gets 360 N m/rad and goes ~0.01 rad past its
# stop under 1 N m
OBJECT_STOP_FREQUENCY = 1000.0
FRICTION_VELOCITY = 0.05  # rad/s (or m/s): a joint's Coulomb friction is f tanh(qd / FRICTION_VELOCITY)
# m: a mesh's signed-distance grid reaches this far beyond it, more than a finger sphere's radius (the Allegro's
# largest is 14 mm), so the centre of a sphere that touches the mesh is inside the grid, where the distance is
# interpolated
SDF_PAD = 0.02
# Coulomb coefficients by default: the fingers' on the object (ContactParams) and the table's (TableContact); in an
# articulated scene each is also the per-world parameter "hand/friction" / "table/friction"
HAND_FRICTION = 1.0
TABLE_FRICTION = 0.8

# Collision geometry. A tool scene's object bodies carry a list of geoms (GEOM_NONE pads it); the knob and cube
# scenes' one object is a single shape, a convex polytope (GEOM_CONVEX), a sphere, a cylinder or a mesh's
# signed-distance grid (GEOM_SDF).
GEOM_NONE, GEOM_BOX, GEOM_SPHERE, GEOM_CAPSULE, GEOM_CYLINDER, GEOM_SDF, GEOM_CONVEX = -1, 0, 1, 2, 3, 4, 5
