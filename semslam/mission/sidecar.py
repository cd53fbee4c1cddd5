"""The mission sidecar: what a bag cannot say (extrinsics, ground truth, simulator extras) as JSON.

Convention (where the sidecar lives):

* a bag that is one file — ROS 1 ``tank.bag``, ROS 2 ``tank.mcap`` — has it next to it, named after
  the whole file name: ``tank.bag.semslam.json``, ``tank.mcap.semslam.json``;
* a ROS 2 bag directory (sqlite3 or mcap storage) has it inside: ``tank/semslam.json``
  (``ros2 bag`` ignores files it does not list in ``metadata.yaml``).

Content (version 1)::

    {"format": "semslam-mission", "version": 1, "name": "tank",
     "sensors": {"<name>": {"kind": "dvl", "topic": "/dvl", "msgtype": "cola2_msgs/msg/DVL",
                            "T_BS": [[...4 rows...]]}},
     "ground_truth": {...GroundTruthMap.to_dict()...} | null,
     "extras": {...},
     "datum": {"latitude_deg": ..., "longitude_deg": ..., "altitude_m": ...} | null,
     "pressure": {"atmospheric_pa": 101325.0}}

``datum`` is the origin of the GPS fixes' local NED frame; ``pressure.atmospheric_pa`` the surface
pressure the writer converted depth with (``reader.atmospheric_pressure_pa: auto`` reads it back).
Both are optional (sidecars written before them have neither).

A bag without a sidecar is fine: sensors then have identity extrinsics and no ground truth.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semslam.errors import MissionError
from semslam.mission.geodesy import Geodetic
from semslam.mission.ground_truth import GroundTruthMap
from semslam.mission.mission import SENSOR_KINDS, MissionMetadata, SensorInfo

FORMAT = "semslam-mission"
VERSION = 1
DIR_SIDECAR = "semslam.json"
FILE_SUFFIX = ".semslam.json"


def sidecar_path(bag: Path) -> Path:
    """Where the sidecar of ``bag`` lives (see the module docstring)."""
    bag = Path(bag)
    return bag / DIR_SIDECAR if bag.is_dir() else bag.with_name(bag.name + FILE_SUFFIX)


def _jsonable(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (set, frozenset)):
        return sorted(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


@dataclass
class Sidecar:
    metadata: MissionMetadata
    atmospheric_pressure_pa: float | None = None  # what the writer converted depth with


def dumps(meta: MissionMetadata, atmospheric_pressure_pa: float | None = None) -> str:
    doc = {
        "format": FORMAT,
        "version": VERSION,
        "name": meta.name,
        "sensors": {
            name: {"kind": s.kind, "topic": s.topic, "msgtype": s.msgtype, "T_BS": np.asarray(s.T_BS).tolist()}
            for name, s in meta.sensors.items()
        },
        "ground_truth": None if meta.ground_truth is None else meta.ground_truth.to_dict(),
        "extras": meta.extras,
        "datum": None if meta.datum is None else meta.datum.to_dict(),
    }
    if atmospheric_pressure_pa is not None:
        doc["pressure"] = {"atmospheric_pa": float(atmospheric_pressure_pa)}
    try:
        return json.dumps(doc, indent=1, default=_jsonable, allow_nan=True)
    except TypeError as exc:
        raise MissionError(f"mission {meta.name!r}: metadata cannot be written as JSON ({exc})") from None


def load(path: Path) -> Sidecar | None:
    """The sidecar at ``path``, None if there is none; MissionError naming the key if invalid."""
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MissionError(f"{path}: not a readable semslam sidecar ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise MissionError(f'{path}: not a semslam sidecar (expected "format": "{FORMAT}")')
    if doc.get("version") != VERSION:
        raise MissionError(f"{path}: sidecar version {doc.get('version')!r} not supported (expected {VERSION})")
    sensors = {}
    for name, s in (doc.get("sensors") or {}).items():
        where = f"{path}: sensors.{name}"
        if not isinstance(s, dict) or s.get("kind") not in SENSOR_KINDS:
            raise MissionError(f"{where}.kind: expected one of {', '.join(SENSOR_KINDS)}")
        T = np.asarray(s.get("T_BS", np.eye(4).tolist()), dtype=float)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise MissionError(f"{where}.T_BS: expected a finite 4×4 matrix")
        sensors[name] = SensorInfo(name=name, kind=s["kind"], topic=s.get("topic"), msgtype=s.get("msgtype"), T_BS=T)
    gt = doc.get("ground_truth")
    try:
        ground_truth = None if gt is None else GroundTruthMap.from_dict(gt)
    except (KeyError, TypeError, ValueError) as exc:
        raise MissionError(f"{path}: ground_truth: malformed ({exc!r})") from None
    extras = doc.get("extras") or {}
    if not isinstance(extras, dict):
        raise MissionError(f"{path}: extras: expected an object")
    name = str(doc.get("name") or "mission")
    try:
        datum = None if doc.get("datum") is None else Geodetic.from_dict(doc["datum"])
    except (KeyError, TypeError, ValueError) as exc:
        raise MissionError(f"{path}: datum: malformed ({exc!r})") from None
    pressure = doc.get("pressure") or {}
    p_atm = pressure.get("atmospheric_pa") if isinstance(pressure, dict) else None
    if p_atm is not None and not (isinstance(p_atm, (int, float)) and p_atm > 0):
        raise MissionError(f"{path}: pressure.atmospheric_pa: expected a positive number")
    meta = MissionMetadata(name=name, sensors=sensors, ground_truth=ground_truth, extras=extras, datum=datum)
    return Sidecar(meta, None if p_atm is None else float(p_atm))
