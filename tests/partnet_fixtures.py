"""Folders in the PartNet-Mobility layout, written by the tests (the data set itself is not redistributable).

Like the real objects: an empty ``base`` link, a fixed joint turning the y-up mesh frame into z-up, links made
of several OBJ pieces (some open, not watertight) in ``textured_objs/``, roughly unit-normalised sizes, and
``semantics.txt`` / ``meta.json`` beside ``mobility.urdf``. Mesh pieces are given in the object's (y-up)
coordinates and every link's ``<visual>``/``<collision>`` origin undoes its pivot, as PartNet's files do.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import trimesh

Y_UP_TO_Z_UP = "1.5707963267948966 0 -1.5707963267948966"


def box(extents, centre) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(centre))


def open_box(extents, centre, drop=2) -> trimesh.Trimesh:
    """A box with ``drop`` triangles (one face) removed: an open surface, as scanned pieces are."""
    closed = box(extents, centre)
    return trimesh.Trimesh(closed.vertices, closed.faces[:-drop], process=False)


def quad(extents_xz, centre) -> trimesh.Trimesh:
    """A flat rectangle in the x-z plane (no volume at all)."""
    hx, hz = extents_xz[0] / 2, extents_xz[1] / 2
    vertices = np.array([[-hx, 0, -hz], [hx, 0, -hz], [hx, 0, hz], [-hx, 0, hz]]) + centre
    return trimesh.Trimesh(vertices, [[0, 1, 2], [0, 2, 3]], process=False)


class PartNetFolder:
    """Builds ``<root>/mobility.urdf`` and its files; links hold pieces in object coordinates."""

    def __init__(self, root: Path, category: str):
        self.root = Path(root)
        (self.root / "textured_objs").mkdir(parents=True, exist_ok=True)
        self.category = category
        self.links: dict[str, list[str]] = {"base": []}
        self.pivots: dict[str, np.ndarray] = {"base": np.zeros(3)}
        self.joints: list[str] = []
        self.semantics: list[str] = []
        self.pieces = 0

    def link(self, name: str, pieces, pivot=(0.0, 0.0, 0.0), label: str = "", kind: str = "static",
             scale: str | None = None, primitives=()):
        """A link made of ``pieces`` (object coordinates, or ``<mesh scale>``-scaled ones) and URDF
        ``primitives`` (``(origin xyz, geometry xml)``, link frame) whose frame sits at ``pivot``."""
        self.pivots[name] = np.asarray(pivot, dtype=float)
        elements = []
        undo = " ".join(f"{-x:.9g}" for x in pivot)
        scaled = f' scale="{scale}"' if scale else ""
        for mesh in pieces:
            self.pieces += 1
            file = f"textured_objs/original-{self.pieces}.obj"
            # as in the data set: a material library whose texture image is not there
            (self.root / file).with_suffix(".mtl").write_text(
                f"newmtl material_{self.pieces}\nKd 0.8 0.8 0.8\nmap_Kd ../images/texture_{self.pieces}.png\n")
            (self.root / file).write_text(f"mtllib original-{self.pieces}.mtl\nusemtl material_{self.pieces}\n"
                                          + trimesh.exchange.obj.export_obj(mesh, include_normals=False))
            for tag in ("visual", "collision"):
                named = f' name="{name}-{self.pieces}"' if tag == "visual" else ""
                elements.append(f'    <{tag}{named}><origin xyz="{undo}"/>'
                                f'<geometry><mesh filename="{file}"{scaled}/></geometry></{tag}>')
        for xyz, shape in primitives:
            for tag in ("visual", "collision"):
                elements.append(f'    <{tag}><origin xyz="{xyz}" rpy="0.3 0 0"/><geometry>{shape}</geometry></{tag}>')
        self.links[name] = elements
        self.semantics.append(f"{name} {kind} {label or name}")
        return self

    def joint(self, name: str, kind: str, parent: str, child: str, axis=(0, 0, 1), limit=None, extra: str = "",
              rpy: str = "0 0 0", xyz=None):
        """A joint at the child's pivot (relative to the parent's, unless ``xyz`` is given)."""
        if xyz is None:
            xyz = self.pivots[child] - (self.pivots[parent] if parent != "base" else 0.0)
        lines = [f'  <joint name="{name}" type="{kind}">',
                 f'    <origin xyz="{" ".join(f"{x:.9g}" for x in xyz)}" rpy="{rpy}"/>',
                 f'    <axis xyz="{" ".join(str(a) for a in axis)}"/>',
                 f'    <child link="{child}"/>', f'    <parent link="{parent}"/>']
        if limit is not None:
            lines.append(f'    <limit lower="{limit[0]}" upper="{limit[1]}"/>')
        self.joints.append("\n".join(lines + ([extra] if extra else []) + ["  </joint>"]))
        return self

    def write(self) -> Path:
        body = [f'<?xml version="1.0"?>\n<robot name="partnet_{self.root.name}">']
        for name, elements in self.links.items():
            body.append(f'  <link name="{name}">' + ("\n" + "\n".join(elements) + "\n  " if elements else "")
                        + "</link>")
        body += self.joints + ["</robot>\n"]
        path = self.root / "mobility.urdf"
        path.write_text("\n".join(body))
        (self.root / "semantics.txt").write_text("\n".join(self.semantics) + "\n")
        (self.root / "meta.json").write_text(json.dumps({"model_cat": self.category, "anno_id": "test"}))
        return path


def stapler(root: Path) -> Path:
    """A base slab with an open magazine, and an arm on a hinge at the back (0..0.45 rad)."""
    return (PartNetFolder(root, "Stapler")
            .link("link_1", [box((1.0, 0.08, 0.3), (0, 0.04, 0)), open_box((0.8, 0.1, 0.2), (0.05, 0.13, 0))])
            .link("link_0", [box((0.95, 0.06, 0.26), (0.0, 0.24, 0)), quad((0.6, 0.2), (0.05, 0.271, 0)),
                             box((0.1, 0.1, 0.2), (-0.42, 0.19, 0))], pivot=(-0.45, 0.2, 0), kind="hinge",
                  label="lid")
            .joint("joint_1", "fixed", "base", "link_1", rpy=Y_UP_TO_Z_UP)
            .joint("joint_0", "revolute", "link_1", "link_0", axis=(0, 0, -1), limit=(0, 0.45))
            .write())


def drawer(root: Path) -> Path:
    """A cabinet open at the front and a drawer (open box plus handle) sliding out 0..0.5 along x."""
    return (PartNetFolder(root, "StorageFurniture")
            .link("link_1", [open_box((1.0, 0.6, 0.8), (0, 0.3, 0)), box((1.0, 0.05, 0.8), (0, 0.625, 0))])
            .link("link_0", [open_box((0.9, 0.4, 0.7), (0.05, 0.3, 0)), box((0.04, 0.05, 0.3), (0.55, 0.3, 0))],
                  pivot=(0, 0, 0), kind="slider", label="drawer")
            .joint("joint_1", "fixed", "base", "link_1", rpy=Y_UP_TO_Z_UP)
            .joint("joint_0", "prismatic", "link_1", "link_0", axis=(1, 0, 0), limit=(0, 0.5),
                   extra='    <dynamics damping="2.5" friction="0.1"/>')
            .write())


def scissors(root: Path) -> Path:
    """Two blades on one pivot: blade A hinged on the empty base, blade B hinged on blade A."""
    return (PartNetFolder(root, "Scissors")
            .link("link_1", [box((1.0, 0.04, 0.1), (0.1, 0, 0)), open_box((0.2, 0.04, 0.2), (-0.5, 0, 0.1))],
                  kind="hinge", label="blade")
            .link("link_0", [box((1.0, 0.04, 0.1), (0.1, 0.05, 0)), open_box((0.2, 0.04, 0.2), (-0.5, 0.05, -0.1))],
                  pivot=(0.1, 0.05, 0), kind="hinge", label="blade")
            .joint("joint_1", "revolute", "base", "link_1", axis=(0, 1, 0), limit=(-0.3, 0.3), rpy=Y_UP_TO_Z_UP,
                   xyz=(0, 0, 0))
            .joint("joint_0", "revolute", "link_1", "link_0", axis=(0, 1, 0), limit=(0, 0.6))
            .write())


def lever_on_fixed_chain(root: Path) -> Path:
    """A body, a cap fixed on it at an angle, a lever hinged on the cap, a knob (a scaled mesh) fixed on the
    lever."""
    return (PartNetFolder(root, "Faucet")
            .link("link_1", [box((0.3, 0.6, 0.3), (0, 0.3, 0))])
            .link("link_2", [box((0.2, 0.1, 0.2), (0, 0.65, 0))], pivot=(0, 0.6, 0))
            .link("link_0", [box((0.6, 0.05, 0.08), (0.3, 0.72, 0))], pivot=(0, 0.7, 0), kind="hinge",
                  label="lever")
            .link("link_3", [box((0.1, 0.1, 0.1), (0.3, 0.75, 0))], pivot=(0.6, 0.7, 0), scale="2 1 1.5")
            .joint("joint_1", "fixed", "base", "link_1", rpy=Y_UP_TO_Z_UP)
            .joint("joint_2", "fixed", "link_1", "link_2", rpy="0 0.4 0")
            .joint("joint_0", "revolute", "link_2", "link_0", axis=(0, 0, 1), limit=(-0.2, 0.7),
                   xyz=(0, 0.1, 0))
            .joint("joint_3", "fixed", "link_0", "link_3")
            .write())


def knob(root: Path) -> Path:
    """A base block (with URDF primitives beside it) and a knob on a continuous joint about the up axis."""
    return (PartNetFolder(root, "Knob")
            .link("link_1", [box((0.6, 0.3, 0.6), (0, 0.15, 0))],
                  primitives=[("0.4 0.1 0", '<cylinder radius="0.1" length="0.3"/>'),
                              ("-0.4 0.1 0", '<sphere radius="0.08"/>'),
                              ("0 0.1 0.4", '<box size="0.1 0.2 0.05"/>')])
            .link("link_0", [box((0.3, 0.2, 0.1), (0, 0.4, 0)), open_box((0.1, 0.2, 0.3), (0, 0.4, 0))],
                  pivot=(0, 0.3, 0), kind="hinge", label="knob")
            .joint("joint_1", "fixed", "base", "link_1", rpy=Y_UP_TO_Z_UP)
            .joint("joint_0", "continuous", "link_1", "link_0", axis=(0, 1, 0))
            .write())


def keyboard(root: Path, keys: int = 5) -> Path:
    """A board with ``keys`` keys on prismatic joints (more than an object can move); the last key is stuck
    half-way down (lower == upper)."""
    folder = PartNetFolder(root, "Keyboard").link("link_0", [box((1.0, 0.1, 0.4), (0, 0.05, 0))])
    folder.joint("joint_0", "fixed", "base", "link_0", rpy=Y_UP_TO_Z_UP)
    for k in range(1, keys + 1):
        x = -0.45 + 0.18 * k
        folder.link(f"link_{k}", [box((0.12, 0.05, 0.12), (x, 0.125, 0))], pivot=(x, 0.1, 0), kind="slider")
        limit = (0.05, 0.05) if k == keys else (0, 0.02)
        folder.joint(f"joint_{k}", "prismatic", "link_0", f"link_{k}", axis=(0, -1, 0), limit=limit)
    return folder.write()


def disc(radius: float, centre, sides: int = 24) -> trimesh.Trimesh:
    """A flat disc in the x-y plane (a wall plate standing on its edge in the y-up frame; no volume)."""
    angles = 2 * np.pi * np.arange(sides) / sides
    rim = np.stack([radius * np.cos(angles), radius * np.sin(angles), np.zeros(sides)], 1)
    faces = [[sides, k, (k + 1) % sides] for k in range(sides)]
    return trimesh.Trimesh(np.vstack([rim, [[0.0, 0.0, 0.0]]]) + centre, faces, process=False)


def wall_switch(root: Path) -> Path:
    """A round wall plate standing on its edge in front of a back box, and a toggle on a hinge: the plate's
    smallest box may turn any way in its plane (a tilted one would reach through the table)."""
    return (PartNetFolder(root, "Switch")
            .link("link_1", [disc(0.5, (0, 0.5, 0)), box((0.8, 0.5, 0.4), (0, 0.25, -0.2))])
            .link("link_0", [box((0.1, 0.3, 0.15), (0, 0.5, 0.075))], pivot=(0, 0.5, 0), kind="hinge",
                  label="toggle")
            .joint("joint_1", "fixed", "base", "link_1", rpy=Y_UP_TO_Z_UP)
            .joint("joint_0", "revolute", "link_1", "link_0", axis=(1, 0, 0), limit=(-0.3, 0.3))
            .write())


def cabinet(root: Path) -> Path:
    """A cabinet of separate boards (sides, back, top, a thin bottom) with a door on a hinge at its side, open
    at rest: more board corners than the table samples a body keeps, and an unsprung door that gravity would
    swing."""
    boards = [box((0.04, 1.0, 0.6), (-0.48, 0.5, 0)), box((0.04, 1.0, 0.6), (0.48, 0.5, 0)),
              box((1.0, 1.0, 0.04), (0, 0.5, -0.28)), box((1.0, 0.04, 0.6), (0, 0.98, 0)), quad((1.0, 0.6), (0, 0, 0))]
    return (PartNetFolder(root, "StorageFurniture")
            .link("link_1", boards)
            .link("link_0", [box((0.9, 0.9, 0.03), (0.0, 0.5, 0.45))], pivot=(-0.45, 0.5, 0.3), kind="hinge",
                  label="door")
            .joint("joint_1", "fixed", "base", "link_1", rpy=Y_UP_TO_Z_UP)
            .joint("joint_0", "revolute", "link_1", "link_0", axis=(0, 1, 0), limit=(0, 1.6),
                   extra='    <!-- <origin xyz="9 9 9"/> a commented origin, as some files have -->')
            .write())


def screw_cap(root: Path) -> Path:
    """A bottle and its cap on stacked joints, as PartNet writes screw caps: the cap rises on a prismatic joint
    into an empty ``*_helper`` link and turns on a continuous joint below it."""
    return (PartNetFolder(root, "Bottle")
            .link("link_1", [box((0.5, 0.8, 0.5), (0, 0.4, 0)), open_box((0.25, 0.1, 0.25), (0, 0.85, 0))])
            .link("link_0_helper", [], pivot=(0, 0.9, 0))
            .link("link_0", [box((0.3, 0.15, 0.3), (0, 0.95, 0))], pivot=(0, 0.9, 0), kind="hinge", label="lid")
            .joint("joint_1", "fixed", "base", "link_1", rpy=Y_UP_TO_Z_UP)
            .joint("joint_2", "prismatic", "link_1", "link_0_helper", axis=(0, 1, 0), limit=(0, 0.1))
            .joint("joint_0", "continuous", "link_0_helper", "link_0", axis=(0, 1, 0))
            .write())


def strongbox(root: Path) -> Path:
    """A strongbox as PartNet's safes are cut: two side walls, a top plate and the block of the body (about 3 kg
    at the loader's default size and density), and a thin door on a hinge at the edge of its front. The door's
    centre, the grasp point, lies on the body's face: the open hand held over it sinks its fingers into the
    top plate and the body, far heavier than they are."""
    body = [box((1.0, 0.9, 0.14), (0, 0.45, -0.37)), box((1.0, 0.9, 0.14), (0, 0.45, 0.37)),
            box((1.0, 0.14, 0.9), (0, 0.83, 0)), box((0.95, 0.8, 0.85), (0, 0.4, 0))]
    return (PartNetFolder(root, "Safe")
            .link("link_1", body)
            .link("link_0", [box((0.9, 0.8, 0.02), (0.0, 0.45, 0.46))], pivot=(-0.45, 0.45, 0.46), kind="hinge",
                  label="door")
            .joint("joint_1", "fixed", "base", "link_1", rpy=Y_UP_TO_Z_UP)
            .joint("joint_0", "revolute", "link_1", "link_0", axis=(0, 1, 0), limit=(0, 2.9))
            .write())
