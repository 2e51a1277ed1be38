"""The fused kernels' types (sim/_kernels.py): the float and vector types, the scene's ``Model`` struct and the
``Saved`` struct a taped step keeps, with the scene structure they are built for, in one frozen spec.

The spec is what the fused kernels' function builders read (:func:`~._contact_kernels.build_contact`,
:func:`~._chain_kernels.build_chain`, :func:`~._palm_kernels.build_palm`); the functions one builder needs from
another are passed to it beside the spec.
"""

# no `from __future__ import annotations`: warp reads the closure-typed annotations at definition time

import dataclasses

import warp as wp

__all__ = ["FusedSpec", "fused_spec"]


@dataclasses.dataclass(frozen=True)
class FusedSpec:
    """The types and the scene structure of one build of the fused kernels (:func:`fused_spec`)."""

    dtype: type
    vec3: type
    vec4: type
    mat33: type
    quat: type
    vecJ: type
    matJ: type
    matJ3: type
    vec7: type  # a finger's saved result: force, torque on the object, normal force
    vecC: type  # a contact's saved result: force, point, normal force, joint forces
    mat43: type  # Jacobian of (signed distance, normal) w.r.t. the query point
    matJJ1: type  # a link's mass-matrix block and bias forces, side by side
    Model: type  # the scene's model struct (a wp.struct)
    Saved: type  # the per-call results a taped step keeps for the reverse pass (a wp.struct)
    J: int  # joints per finger
    K: int  # the convex object's planes
    palm: bool  # the palm's contact with a free object is built (the Model has its fields)
    NB: int  # palm boxes
    NS: int  # the object's surface samples against the palm
    shape: int  # the object's geometry kind
    hinges_only: bool  # every hand joint is revolute
    hinge_object: bool  # the object turns on a hinge (else it is a free body)
    box: bool  # the convex object is an axis-aligned box


def fused_spec(float_type, joints: int, planes: int, shape: int, hinges_only: bool, hinge_object: bool,
               object_limited: bool, box_object: bool, palm_boxes: int, palm_points: int) -> FusedSpec:
    """The spec of a scene of fingers with ``joints`` joints each (the arguments are
    :func:`~._kernels.build_kernels`'s)."""
    J = joints
    PALM = palm_boxes > 0 and palm_points > 0 and not hinge_object
    OBJ_LIMITED = bool(object_limited) and hinge_object
    BOX = bool(box_object)
    dtype = float_type
    vec3 = wp.types.vector(3, dtype)
    vec4 = wp.types.vector(4, dtype)
    mat33 = wp.types.matrix((3, 3), dtype)
    vecJ = wp.types.vector(J, dtype)
    matJ = wp.types.matrix((J, J), dtype)
    quat = wp.types.quaternion(dtype)
    matJ3 = wp.types.matrix((J, 3), dtype)
    vec7 = wp.types.vector(7, dtype)
    vecC = wp.types.vector(7 + J, dtype)
    mat43 = wp.types.matrix((4, 3), dtype)
    matJJ1 = wp.types.matrix((J, J + 1), dtype)

    @wp.struct
    class Model:
        base_pos: wp.array(dtype=vec3)
        base_rot: wp.array(dtype=mat33)
        off_pos: wp.array(dtype=vec3)
        off_rot: wp.array(dtype=mat33)
        axis: wp.array(dtype=vec3)
        jtype: wp.array(dtype=wp.int32)
        mass: wp.array(dtype=dtype)
        com: wp.array(dtype=vec3)
        inertia: wp.array(dtype=mat33)
        armature: wp.array(dtype=dtype)
        damping: wp.array(dtype=dtype)
        friction: wp.array(dtype=dtype)
        lower: wp.array(dtype=dtype)
        upper: wp.array(dtype=dtype)
        limit_ke: wp.array(dtype=dtype)
        effort: wp.array(dtype=dtype)  # PD drive saturation per dof (0: none)
        point_pos: wp.array(dtype=vec3)
        point_radius: wp.array(dtype=dtype)
        link_reach: wp.array(dtype=dtype)  # [F * J] m: max over a link's spheres of |centre| + radius (link frame)
        tip_pos: wp.array(dtype=vec3)
        obj_base_pos: vec3
        obj_base_rot: mat33
        obj_axis: vec3
        obj_mass: dtype
        obj_com: vec3
        obj_inertia: mat33
        obj_axial_inertia: dtype  # hinge: inertia about the axis (constant, the body turns about it) + armature
        obj_inv_inertia: mat33  # free: the inverse of obj_inertia (the contacts' implicit damping reads it)
        obj_bound: dtype  # radius of a sphere about the object origin that encloses its geometry
        if OBJ_LIMITED:  # the hinge object's range (rad) and its limit spring (N m/rad)
            obj_lower: dtype
            obj_upper: dtype
            obj_limit_ke: dtype
        planes: wp.array(dtype=vec4)
        if BOX:  # the convex object is an axis-aligned box: its centre and half extents (object frame, m)
            obj_box_center: vec3
            obj_box_half: vec3
        sdf: wp.array3d(dtype=dtype)  # signed distance grid for non-convex meshes
        sdf_origin: vec3
        sdf_cell: dtype
        shape_size: vec3
        gravity: vec3
        # contact: stiffness, damping, sharpness, friction, slip velocity, surface smoothing
        ke: dtype
        kd: dtype
        beta: dtype
        mu: dtype
        v_slip: dtype
        smooth: dtype
        if PALM:  # palm boxes (world frame) and the object's surface samples (object frame)
            palm_pos: wp.array(dtype=vec3)
            palm_rot: wp.array(dtype=mat33)
            palm_half: wp.array(dtype=vec3)
            obj_point_pos: wp.array(dtype=vec3)
            obj_point_radius: wp.array(dtype=dtype)
            palm_ke: dtype
            palm_beta: dtype
            palm_smooth: dtype

    @wp.struct
    class Saved:
        """Per-call results a taped step keeps for the reverse pass (rows: a substep's output rows;
        columns: finger, or sample sphere). Arrays with no rows when the step is not taped."""

        finger: wp.array2d(dtype=vec7)  # finger_step: force, torque on the object, normal force
        contact: wp.array2d(dtype=vecC)  # point_contact results (see its docstring)
        sdf: wp.array2d(dtype=vec4)  # object_sdf: distance, normal
        sdf_jac: wp.array2d(dtype=mat43)  # polytope_sdf: d(distance, normal)/d(point), for its adjoint
        law: wp.array2d(dtype=mat43)  # contact_force: n, cp, v_rel and (softplus, its slope, slip norm)
        inertia: wp.array2d(dtype=matJJ1)  # link_inertia: the link's [M | bias] contribution

    return FusedSpec(dtype=dtype, vec3=vec3, vec4=vec4, mat33=mat33, quat=quat, vecJ=vecJ, matJ=matJ, matJ3=matJ3,
                     vec7=vec7, vecC=vecC, mat43=mat43, matJJ1=matJJ1, Model=Model, Saved=Saved, J=J, K=planes,
                     palm=PALM, NB=palm_boxes, NS=palm_points, shape=shape, hinges_only=bool(hinges_only),
                     hinge_object=bool(hinge_object), box=BOX)
