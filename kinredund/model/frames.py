"""End-effector frames by name: which frame is taken when a joint and a link share a name."""

from __future__ import annotations

import pinocchio as pin

from kinredund.errors import FrameNotFoundError, TaskError

#: frame types in the order an end-effector name is resolved when several frames share it: the link
#: (BODY) first, since a link is what carries a tool; then an operational frame; joints last
FRAME_PREFERENCE = (pin.FrameType.BODY, pin.FrameType.OP_FRAME, pin.FrameType.FIXED_JOINT,
                    pin.FrameType.JOINT, pin.FrameType.SENSOR)


#: the end of the name of the frame ``load_robot`` adds at the end-effector frame's origin, its z axis turned onto a
#: tool axis other than z (``<ee_frame>_tool_axis``)
TOOL_AXIS_FRAME = "_tool_axis"


def resolve_frame(model: pin.Model, name) -> tuple[int, str]:
    """(frame id, description) of the frame called ``name``, preferring a link when names are shared.

    A URDF may give a joint and a link the same name (the Unitree Z1's ``gripperStator``, the SO-100's
    ``gripper``); Pinocchio then has two frames of that name. The BODY (link) frame is taken, then an
    OP_FRAME, then a joint frame (:data:`FRAME_PREFERENCE`); the description says which.

    Raises:
        FrameNotFoundError: no frame has that name (lists the frames, links first).
        TaskError: the frame is fixed to the base (no joint of the model moves it).
    """
    frames = list(model.frames)
    if not isinstance(name, str) or not name:
        raise FrameNotFoundError(str(name) if isinstance(name, str) else repr(name), _frame_names(frames),
                                 "an end-effector frame is a non-empty name")
    ids = [i for i, f in enumerate(frames) if f.name == name]
    if not ids:
        raise FrameNotFoundError(name, _frame_names(frames), _SHARED_NOTE)
    rank = {t: k for k, t in enumerate(FRAME_PREFERENCE)}
    fid = min(ids, key=lambda i: (rank.get(frames[i].type, len(rank)), i))
    kind = str(frames[fid].type).rsplit(".", 1)[-1]
    info = f"frame {name!r} ({kind}, id {fid})"
    if len(ids) > 1:
        others = ", ".join(str(frames[i].type).rsplit(".", 1)[-1] for i in ids if i != fid)
        info += f"; the model also has a {others} frame of that name: the {kind} frame was taken"
    if frames[fid].parentJoint == 0:
        raise TaskError(f"the end-effector {info} is fixed to the base: no joint of the model moves it; "
                        "choose a frame on the kept chain")
    return fid, info


_SHARED_NOTE = "where a joint and a link share a name, the link (BODY) frame is taken"


def _frame_names(frames) -> list[str]:
    """Frame names without repeats, links and operational frames first."""
    first = [f.name for f in frames if f.type in (pin.FrameType.BODY, pin.FrameType.OP_FRAME)]
    rest = [f.name for f in frames if f.name not in set(first)]
    return list(dict.fromkeys(first + rest))
