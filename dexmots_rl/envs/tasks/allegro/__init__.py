"""The Allegro hand v4 (16 DoF, right hand, Wonik frame) tasks; one module per task.

The hand (``assets/allegro_knob.xml``; its joint order, contact law and open pose: :mod:`.hand`): four fingers of
four hinges, capsule links (radius 9.8 mm) and fingertip spheres (12 mm), motors of 0.5 N m
(IsaacGymEnvs' effort), joint damping 0.1, armature 0.001. ``allegro_rotate`` mounts it palm down over a
knob (``assets/allegro_knob.xml``), ``repose_cube`` palm up with a cube on its colliding palm box
(``assets/allegro_cube.xml``); ``operate`` palm down over any articulated object of the library or a URDF
standing on a table (:mod:`.operate_object`), and one task per library class on it (:mod:`.tools`:
``spray_bottle``, ``scissors``, ``stapler``, ``pump_dispenser``, ``jar``, ``valve``, ``drawer``, ``pliers``,
``door_handle``).
"""

from __future__ import annotations

from . import hand, operate_object, repose, rotate, tools  # noqa: F401  (register the tasks)

__all__ = ["hand", "operate_object", "repose", "rotate", "tools"]
