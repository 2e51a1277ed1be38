"""The Allegro hand v4 (16 DoF, right hand, Wonik frame) tasks; one module per task.

The hand (``assets/allegro_knob.xml``): four fingers of four hinges (index, middle, ring, thumb; joints
j0-j15 in that order), capsule links (radius 9.8 mm) and fingertip spheres (12 mm), motors of 0.5 N m
(IsaacGymEnvs' effort), joint damping 0.1, armature 0.001, mounted palm down with the fingers along +x.
"""

from __future__ import annotations

from . import rotate  # noqa: F401  (registers allegro_rotate)

__all__ = ["rotate"]
