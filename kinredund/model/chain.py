"""Keeping a chain of a robot's joints and locking the others: ``load_robot(joints=, locked=)``.

:func:`reduce_model` checks the names and values and calls ``pin.buildReducedModel``; a locked joint sits at the
value given, at its mimic's law of its master, or at the middle of its limits.
"""

from __future__ import annotations

from collections.abc import Mapping
from numbers import Real

import numpy as np
import pinocchio as pin

from kinredund.errors import ChoiceError, JointVectorError, URDFError, check_choice
from kinredund.model.robot import NO_LIMIT


def finite_mid(lo: float, hi: float) -> float:
    """The middle of a joint's limits [rad or m]; where one is absent (beyond ``NO_LIMIT``), 0 clipped into them."""
    if abs(lo) < NO_LIMIT and abs(hi) < NO_LIMIT:
        return 0.5 * (lo + hi)
    return float(np.clip(0.0, lo, hi))


def reduce_model(model: pin.Model, joints, locked, mimic: dict, frame_id: int, source: str
                 ) -> tuple[pin.Model, dict[str, float]]:
    """Keep ``joints`` (names, or None for every joint that can move), lock the others; return (model,
    locked values).

    A locked joint sits at ``locked[name]`` if given, else at a mimic's law of its (locked) master,
    else at the middle of its limits (0 where they are absent). A joint whose limits leave it no range
    (lower = upper) cannot move: by default it is locked at that value, and naming it in ``joints`` is
    refused (a coordinate that cannot move leaves the tracker and the IK no room).

    Raises:
        ChoiceError: a kept or locked name is not a joint of the model.
        JointVectorError: a locked value is not a finite number inside the joint's limits.
        URDFError: a kept joint is a mimic joint or has no range, or a locked mimic joint on the
            end-effector's chain follows a kept joint (its motion would be lost).
    """
    names = list(model.names)[1:]
    stuck = [n for n in names if model.joints[model.getJointId(n)].nq == 1
             and model.lowerPositionLimit[model.idx_qs[model.getJointId(n)]]
             == model.upperPositionLimit[model.idx_qs[model.getJointId(n)]]]
    keep = [n for n in names if n not in stuck] if joints is None else _joint_list(joints, names)
    if set(stuck) & set(keep):
        raise URDFError(source, f"joint(s) {', '.join(n for n in keep if n in stuck)} have lower = upper limit: they "
                                "cannot move; leave them out of joints= (they are then locked at that value)")
    if locked is not None and not isinstance(locked, Mapping):
        raise ChoiceError("locked (a dict joint name -> value)", locked, [n for n in names if n not in keep])
    locked = {} if locked is None else dict(locked)
    for key in locked:
        check_choice("locked joint", key, [n for n in names if n not in keep])
    mimics = [n for n in keep if n in mimic]
    if mimics:
        chain = [names[j - 1] for j in model.supports[model.frames[frame_id].parentJoint][1:]]
        raise URDFError(source, (
            f"joint(s) {', '.join(mimics)} mimic another joint: every kept joint needs its own coordinate. "
            f"Keep a chain without them, e.g. joints={[n for n in chain if n not in mimic]}"
        ))
    on_chain = set(model.supports[model.frames[frame_id].parentJoint])
    values, q = {}, pin.neutral(model)
    order = sorted((n for n in names if n not in keep), key=lambda n: n in mimic)  # masters first
    for n in order:
        jid = model.getJointId(n)
        lo, hi = float(model.lowerPositionLimit[model.idx_qs[jid]]), float(model.upperPositionLimit[model.idx_qs[jid]])
        if model.joints[jid].nq != 1:  # a floating or planar joint: at its neutral configuration
            if n in locked:
                raise JointVectorError(f"joint {n!r} has {model.joints[jid].nq} coordinates: it locks at its neutral")
            continue
        if n in locked:
            v = locked[n]
            if isinstance(v, bool) or not isinstance(v, Real) or not np.isfinite(v) or not lo <= v <= hi:
                raise JointVectorError(f"locked value of {n!r} must be a finite number in [{lo:g}, {hi:g}], got {v!r}")
        elif n in mimic and mimic[n].master in values:
            v = mimic[n].multiplier * values[mimic[n].master] + mimic[n].offset
        else:
            if n in mimic and jid in on_chain:
                raise URDFError(source, (
                    f"joint {n!r} mimics the kept joint {mimic[n].master!r} and moves the end-effector frame: "
                    "locking it would lose that motion; lock its master too"
                ))
            v = finite_mid(lo, hi)
        values[n] = float(v)
        q[model.idx_qs[jid]] = v
    lock_ids = [model.getJointId(n) for n in order]
    if not lock_ids:
        return model, values
    # buildReducedModel looks joint frames up by name and fails where a link shares the name (the
    # SO-100's ``gripper``): rename such joints for the call, and back in the reduced model
    shared = {f.name for f in model.frames if f.type != pin.FrameType.JOINT} & set(names)
    model = pin.Model(model)
    _rename_joints(model, {n: n + _TEMP for n in shared})
    reduced = pin.buildReducedModel(model, lock_ids, q)
    _rename_joints(reduced, {n + _TEMP: n for n in shared})
    return reduced, values


_TEMP = "#joint"


def _rename_joints(model: pin.Model, mapping: dict[str, str]) -> None:
    """Rename joints and their (joint or fixed-joint) frames in place: old name -> new name."""
    for j in range(model.njoints):
        if model.names[j] in mapping:
            model.names[j] = mapping[model.names[j]]
    for i, f in enumerate(model.frames):
        if f.name in mapping and f.type in (pin.FrameType.JOINT, pin.FrameType.FIXED_JOINT):
            renamed = pin.Frame(f)
            renamed.name = mapping[f.name]
            model.frames[i] = renamed


def _joint_list(joints, names: list[str]) -> list[str]:
    if not isinstance(joints, (list, tuple)) or not all(isinstance(j, str) for j in joints):
        raise ChoiceError("joints (a list of joint names)", joints, names)
    keep = [check_choice("joint", j, names) for j in joints]
    if not keep:
        raise ChoiceError("joints (an empty list keeps nothing)", joints, names)
    if len(set(keep)) != len(keep):
        raise ChoiceError("joints (a name repeated)", joints, names)
    return [n for n in names if n in keep]  # q follows the model's order
