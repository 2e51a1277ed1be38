"""Object variants: one scene of a hand and K objects of the same topology, each world simulating one of them.

:func:`load_variants` reads K MJCF files of the same hand with different objects (say the sizes of one class
drawn K times, or several library instances of a class) into one
:class:`~dexmots_rl.sim._articulated_scene.ArticulatedScene`. The variants must share the object's topology:
a fixed or free base, the number of bodies, each body's parent, the joints' names and kinds, and whether there
is a table; their geometry, joint axes, anchors and ranges, masses, inertias, table-contact samples, collision
geoms, table height and initial pose may differ. The hand (every field the hand's kernels read, and the palm's
boxes) must be the same in every file. A mismatch raises :class:`~dexmots_rl.sim.AssetError` naming the file
and the field.

The kernels' model structs hold every variant (a leading dimension V on the arrays that may differ:
sim/_object_kernels.py, sim/_hand_kernels.py, sim/_palm_object_kernels.py), and every launch reads ``variant[w]``
(int32 [N]). In :class:`~dexmots_rl.sim._articulated.ArticulatedSimulator` the variant of each world is the
per-world parameter ``"variant"`` (in ``scene.param_names`` when K > 1, a whole number in [0, K) carried as
a float like the other parameters, no gradient): it is set with the other parameters at reset (partial
resets included), and defaults to 0 (:meth:`~dexmots_rl.sim.ArticulatedScene.default_param_values`). With
K = 1 there is no such parameter and every world reads row 0: the step is the one of a single-object scene.

Example:
    >>> from dexmots_rl.sim._object_variants import load_variants
    >>> scene = load_variants(["bottle_a.xml", "bottle_b.xml"])  # doctest: +SKIP
    >>> scene.num_variants, scene.param_names[-1]  # doctest: +SKIP
    (2, 'variant')
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ._articulated_scene import ArticulatedScene, ObjectGeoms
from ._constants import GEOM_NONE
from ._mjcf_shapes import AssetError
from ._object_model import ObjectTree

__all__ = ["load_variants", "check_same_topology", "pad_geoms"]

# the object tree's fields that make its topology (the kernels are compiled for them)
TOPOLOGY_FIELDS = ("free", "num_bodies", "parent", "joint_names", "joint_kind", "has_table")


def _topology(tree: ObjectTree) -> dict:
    return {"free": tree.free, "num_bodies": tree.num_bodies, "parent": list(tree.parent),
            "joint_names": list(tree.joint_names), "joint_kind": [int(k) for k in tree.joint_kind],
            "has_table": tree.table_height is not None}


def check_same_topology(reference: ObjectTree, tree: ObjectTree, path, reference_path) -> None:
    """Raise :class:`AssetError` naming ``path`` and the first field of :data:`TOPOLOGY_FIELDS` where ``tree``
    differs from ``reference`` (read from ``reference_path``)."""
    ref, new = _topology(reference), _topology(tree)
    for field in TOPOLOGY_FIELDS:
        if ref[field] != new[field]:
            raise AssetError(f"object variant {str(path)!r}: its object's {field} ({new[field]}) differs from "
                             f"{str(reference_path)!r}'s ({ref[field]}); variants must share the object's topology")


def _check_same_hand(reference: ArticulatedScene, scene: ArticulatedScene, path) -> None:
    """Raise :class:`AssetError` naming ``path`` and the hand field (or the palm) that differs."""
    for name, value in reference.hand.items():
        other = scene.hand.get(name)
        same = (np.shape(value) == np.shape(other) and np.array_equal(np.asarray(value), np.asarray(other))
                if isinstance(value, (np.ndarray, list, tuple)) else value == other)
        if not same:
            raise AssetError(f"object variant {str(path)!r}: the hand's {name} differs from "
                             f"{reference.path!r}'s; variants must share the hand")
    for what, a, b in zip(("centres", "rotations", "half sizes"), reference.palm, scene.palm):
        if np.shape(a) != np.shape(b) or not np.array_equal(a, b):
            raise AssetError(f"object variant {str(path)!r}: the palm's box {what} differ from "
                             f"{reference.path!r}'s; variants must share the hand")


def pad_geoms(geoms: ObjectGeoms, width: int) -> ObjectGeoms:
    """``geoms`` padded with GEOM_NONE to ``width`` geoms per body."""
    extra = width - geoms.kind.shape[1]
    if extra == 0:
        return geoms
    num_bodies = geoms.kind.shape[0]
    return ObjectGeoms(
        kind=np.concatenate([geoms.kind, np.full((num_bodies, extra), GEOM_NONE, dtype=np.int32)], 1),
        pos=np.concatenate([geoms.pos, np.zeros((num_bodies, extra, 3))], 1),
        rot=np.concatenate([geoms.rot, np.tile(np.eye(3), (num_bodies, extra, 1, 1))], 1),
        size=np.concatenate([geoms.size, np.zeros((num_bodies, extra, 3))], 1),
        grid=np.concatenate([geoms.grid, np.zeros((num_bodies, extra, 4), dtype=np.int32)], 1),
        sdf_values=geoms.sdf_values)


def load_variants(paths, *, contact=None) -> ArticulatedScene:
    """One :class:`ArticulatedScene` of the K objects of ``paths`` (MJCF files of the same hand; see the module
    docstring); variant k is ``paths[k]``. One path gives the scene :func:`~dexmots_rl.sim.load_scene` does."""
    from ._model import load_scene

    paths = [Path(p) for p in paths]
    if not paths:
        raise ValueError("load_variants needs at least one MJCF file")
    scenes = []
    for path in paths:
        scene = load_scene(path, contact=contact)
        if not getattr(scene, "articulated", False):
            raise AssetError(f"object variant {str(path)!r}: body 'object' is not an articulated object tree")
        if scenes:
            check_same_topology(scenes[0].tree, scene.tree, path, paths[0])
            _check_same_hand(scenes[0], scene, path)
        scenes.append(scene)
    width = max(s.geoms.kind.shape[1] for s in scenes)
    geoms = [pad_geoms(s.geoms, width) for s in scenes]
    return dataclasses.replace(scenes[0], geoms=geoms[0], variant_trees=[s.tree for s in scenes],
                               variant_geoms=geoms, variant_paths=[str(p) for p in paths])
