"""``semslam info MISSION --write-config F``: the binding the reader would use, as editable YAML.

Every sensor read is written out (its topic, kind and, when known, its extrinsic); every other
candidate topic (an alternative for a kind, an Odometry that is no ground truth, an Imu without
orientation) is written commented out, ready to be swapped in; the topics no sensor could read are
listed as comments. ``--config F`` reads it back: the same sensors, the same topics.
"""

from __future__ import annotations

import numpy as np
import yaml

from semslam.mission.binding import Binding, Unread


def _scalar(value) -> str:
    """``value`` as one YAML scalar (quoted when it must be)."""
    return yaml.safe_dump(value, default_flow_style=True, allow_unicode=True).splitlines()[0]


def _matrix(T: np.ndarray) -> str:
    return "[" + ", ".join("[" + ", ".join(f"{x:g}" for x in row) + "]" for row in np.asarray(T)) + "]"


def _sensor_block(name: str, topic: str, kind: str, comment: str, T_BS: np.ndarray | None, prefix: str) -> list[str]:
    lines = [f"{prefix}    {_scalar(name)}:  # {comment}", f"{prefix}      topic: {_scalar(topic)}"]
    lines.append(f"{prefix}      kind: {kind}")
    if T_BS is not None and not np.allclose(T_BS, np.eye(4)):
        lines.append(f"{prefix}      T_BS: {_matrix(T_BS)}")
    elif not prefix:
        lines.append(
            "      # T_BS: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]  # the sensor in the body frame"
        )
    return lines


def binding_yaml(mission) -> str:
    """The YAML of ``mission``'s (a ``BagMission``) binding."""
    plan = mission.plan
    meta = mission.metadata
    counts = mission.message_counts
    out = [
        f"# Sensor binding of {mission.path}, as `semslam info` chose it",
        "# (the rule: semslam.mission.binding). Edit it and pass it back with --config. A commented-out",
        "# sensor is a candidate left unread: uncomment it (and comment out the one it replaces) to use it.",
        "reader:",
        f"  stamp: {mission.config.stamp}",
        f"  atmospheric_pressure_pa: {_scalar(mission.config.atmospheric_pressure_pa)}"
        f"  # {plan.atmosphere.value:.0f} Pa ({plan.atmosphere.how})",
        "  sensors:",
    ]
    b: Binding
    for b in plan.binding.bindings:
        c = plan.stamps[b.sensor]
        stamp = "header stamps" if c.source == "header" else f"receive time ({c.reason})"
        comment = f"{b.msgtype.replace('/msg/', '/')}, {counts.get(b.topic, 0)} messages, {b.origin}; {stamp}"
        out += _sensor_block(b.sensor, b.topic, b.kind, comment, meta.sensors[b.sensor].T_BS, "")
    u: Unread
    taken = set(meta.sensors)
    for u in plan.binding.unread:
        if u.kind is None:
            continue
        name = u.topic.lstrip("/") or u.topic
        name = name if name not in taken else u.topic
        comment = f"{u.msgtype}, {u.count} messages: {u.reason}"
        out += _sensor_block(name, u.topic, u.kind, comment, None, "#")
    rest = [u for u in plan.binding.unread if u.kind is None]
    if rest:
        out.append("# Topics no sensor reads:")
        out += [f"#   {u.topic} ({u.msgtype or 'several types'}): {u.reason}" for u in rest]
    return "\n".join(out) + "\n"
