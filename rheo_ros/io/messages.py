"""Conversion between the contract's messages and arrays, in one place.

The same functions build messages for rosbags (bags, no ROS install) and for rclpy
(the nodes): both expose the types by name with the same fields. ``MessageTypes``
hides the two differences: how a type is found and what an array field takes.
"""

from __future__ import annotations

import array
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from rheo_ros.experiment import check_object_hint

STAGE_TOPIC = "/stage/joint_states"
TACTILE_TOPIC = "/tactile/pressure"
MARKERS_TOPIC = "/markers/mesh"
TOPIC_TYPES = {
    STAGE_TOPIC: "sensor_msgs/msg/JointState",
    TACTILE_TOPIC: "sensor_msgs/msg/Image",
    MARKERS_TOPIC: "geometry_msgs/msg/PoseArray",
}
STAGE_JOINT = "stage"
TACTILE_FRAME = "tactile"
MARKERS_FRAME = "specimen"


@dataclass(frozen=True)
class MessageTypes:
    """Message classes by type name, and how array fields are given to them."""

    lookup: Callable[[str], type]
    float64s: Callable[[np.ndarray], Any]
    bytes_: Callable[[np.ndarray], Any]
    uint32s: Callable[[Any], Any]

    @classmethod
    def rosbags(cls, typestore: Any) -> MessageTypes:
        return cls(lambda name: typestore.types[name], lambda a: np.asarray(a, np.float64),
                   lambda a: np.frombuffer(np.ascontiguousarray(a).tobytes(), np.uint8),
                   lambda a: np.asarray(a, np.uint32))

    @classmethod
    def rclpy(cls) -> MessageTypes:
        import importlib

        def lookup(name: str) -> type:
            package, kind, msg = name.split("/")
            return getattr(importlib.import_module(f"{package}.{kind}"), msg)

        return cls(lookup, lambda a: array.array("d", np.asarray(a, np.float64).tobytes()),
                   lambda a: array.array("B", np.ascontiguousarray(a).tobytes()),
                   lambda a: array.array("I", [int(x) for x in a]))


def stamp_ns(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _header(types: MessageTypes, frame_id: str) -> Any:
    Time = types.lookup("builtin_interfaces/msg/Time")
    return types.lookup("std_msgs/msg/Header")(stamp=Time(sec=0, nanosec=0), frame_id=frame_id)


def _stamp(msg: Any, t_ns: int) -> None:
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(t_ns // 1_000_000_000), int(t_ns % 1_000_000_000)


# Encoders build their message once and refill it: a publisher or a bag writer
# serialises it at once, and at 100 Hz the construction would cost more than the rest.

class JointStateEncoder:
    """``/stage/joint_states``: joint ``stage``, position = depth (m), velocity (m/s)."""

    def __init__(self, types: MessageTypes) -> None:
        self.msg = types.lookup("sensor_msgs/msg/JointState")(
            header=_header(types, ""), name=[STAGE_JOINT], position=types.float64s([0.0]),
            velocity=types.float64s([0.0]), effort=types.float64s([]),
        )

    def __call__(self, t_ns: int, depth: float, velocity: float) -> Any:
        _stamp(self.msg, t_ns)
        self.msg.position[0], self.msg.velocity[0] = depth, velocity
        return self.msg


class PressureImageEncoder:
    """``/tactile/pressure``: 32FC1 image, rows x cols, little-endian float32 Pa."""

    def __init__(self, types: MessageTypes) -> None:
        self.types = types
        self.msg = types.lookup("sensor_msgs/msg/Image")(
            header=_header(types, TACTILE_FRAME), height=0, width=0, encoding="32FC1",
            is_bigendian=0, step=0, data=types.bytes_(np.zeros(0, np.uint8)),
        )

    def __call__(self, t_ns: int, pressure: np.ndarray) -> Any:
        p = np.ascontiguousarray(pressure, dtype="<f4")
        _stamp(self.msg, t_ns)
        self.msg.height, self.msg.width = p.shape
        self.msg.step = p.shape[1] * 4
        self.msg.data = self.types.bytes_(p)
        return self.msg


class MarkerArrayEncoder:
    """``/markers/mesh``: marker positions (N, 2) in m, frame ``specimen``, identity orientations."""

    def __init__(self, types: MessageTypes) -> None:
        self.types = types
        self.msg = types.lookup("geometry_msgs/msg/PoseArray")(header=_header(types, MARKERS_FRAME), poses=[])

    def __call__(self, t_ns: int, positions: np.ndarray) -> Any:
        xy = np.asarray(positions).tolist()
        if len(self.msg.poses) != len(xy):
            Pose = self.types.lookup("geometry_msgs/msg/Pose")
            Point = self.types.lookup("geometry_msgs/msg/Point")
            Quaternion = self.types.lookup("geometry_msgs/msg/Quaternion")
            self.msg.poses = [Pose(position=Point(x=0.0, y=0.0, z=0.0),
                                   orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)) for _ in xy]
        _stamp(self.msg, t_ns)
        for pose, (x, y) in zip(self.msg.poses, xy):
            pose.position.x, pose.position.y = x, y
        return self.msg


class MessageError(ValueError):
    """A message does not follow the contract; the text names the field."""


def read_joint_state(msg: Any) -> tuple[float, float]:
    """-> (depth m, velocity m/s) of joint ``stage``."""
    names = list(msg.name)
    if STAGE_JOINT not in names:
        raise MessageError(f"name: no joint {STAGE_JOINT!r} (has {names})")
    i = names.index(STAGE_JOINT)
    if len(msg.position) <= i:
        raise MessageError("position: missing")
    velocity = float(msg.velocity[i]) if len(msg.velocity) > i else float("nan")
    return float(msg.position[i]), velocity


def read_pressure_image(msg: Any) -> np.ndarray:
    """-> pressures (rows, cols) in Pa."""
    if msg.encoding != "32FC1":
        raise MessageError(f"encoding: {msg.encoding!r}, expected '32FC1'")
    raw = bytes(msg.data)
    if len(raw) % 4:   # np.frombuffer's own ValueError would not name the field
        raise MessageError(f"data: {len(raw)} bytes, not a whole number of 4-byte floats")
    data = np.frombuffer(raw, dtype=">f4" if msg.is_bigendian else "<f4")
    if data.size != msg.height * msg.width or msg.step != msg.width * 4:
        raise MessageError(f"data: {data.size} floats for {msg.height} x {msg.width} (step {msg.step})")
    with np.errstate(invalid="ignore"):   # a signalling NaN: the sample checks name it, no warning line
        return data.reshape(msg.height, msg.width).astype(float)


def read_marker_array(msg: Any) -> np.ndarray:
    """-> marker positions (N, 2) in m."""
    return np.array([[p.position.x, p.position.y] for p in msg.poses], dtype=float).reshape(-1, 2)


# -- the package's own messages (rheo_ros_interfaces) ----------------------------------

PHASE_TOPIC = "/rheo/phase"
ESTIMATE_TOPIC = "/rheo/estimate"
DIAGNOSIS_TOPIC = "/rheo/diagnosis"
PHASE_TYPE = "rheo_ros_interfaces/msg/Phase"
ESTIMATE_TYPE = "rheo_ros_interfaces/msg/Estimate"
DIAGNOSIS_TYPE = "rheo_ros_interfaces/msg/Diagnosis"
OBJECT_TOPIC = "/rheo/object"
OBJECT_TYPE = "rheo_ros_interfaces/msg/ObjectHint"
POOL_TOPIC = "/rheo/pool"
POOL_TYPE = "rheo_ros_interfaces/msg/Pool"


def _time(types: MessageTypes, t: float) -> Any:
    ns = int(round(t * 1e9))
    return types.lookup("builtin_interfaces/msg/Time")(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def phase_message(types: MessageTypes, event: Any, cut_short: str = "") -> Any:
    """``/rheo/phase`` from a ``PhaseEvent``: stamped with the sample that completed it;
    ``cut_short``: why a node closed this release before the mesh settled."""
    msg = types.lookup(PHASE_TYPE)(
        header=_header(types, ""), experiment=event.experiment, name=event.name,
        start=_time(types, event.t_start), end=_time(types, event.t_end), samples=event.samples,
        cut_short=cut_short,
    )
    _stamp(msg, int(round(event.t_found * 1e9)))
    return msg


def read_release_cut(msg: Any) -> tuple[float, float, str] | None:
    """``(found, end, why)`` of a Phase message saying a node closed a release before it
    settled (the data stopped): the latest sample stamp the node had then, the release's
    end (s) and why; None for any other phase. A recording made before Phase had
    ``cut_short`` has none."""
    why = getattr(msg, "cut_short", "")
    if msg.name != "release" or not why:
        return None
    end = int(msg.end.sec) * 1_000_000_000 + int(msg.end.nanosec)
    return stamp_ns(msg) * 1e-9, end * 1e-9, why


def estimate_message(types: MessageTypes, update: Any) -> Any:
    """``/rheo/estimate`` from an ``online.estimator.Update``."""
    cov = update.covariance
    msg = types.lookup(ESTIMATE_TYPE)(
        header=_header(types, ""), experiment=update.experiment, phase=update.phase, model=update.model,
        effects=list(update.effects), method=update.method, equations=list(update.equations),
        names=list(update.names), values=types.float64s(update.values),
        covariance=types.float64s(np.zeros(0) if cov is None else np.asarray(cov).ravel()),
        rmse_force=float(update.rmse_force), samples=int(update.samples),
        undetermined=list(update.undetermined), reasons=list(update.reasons), message=update.message,
        final=bool(update.final),
    )
    _stamp(msg, int(round(update.stamp * 1e9)))
    return msg


def read_estimate(msg: Any) -> dict[str, Any]:
    """An Estimate message as plain values: params, std (empty without covariance), the rest."""
    names = list(msg.names)
    values = np.asarray(msg.values, float)
    cov = np.asarray(msg.covariance, float)
    std = np.sqrt(np.diag(cov.reshape(len(names), len(names)))) if cov.size == len(names) ** 2 and names else None
    return {
        "stamp": stamp_ns(msg) * 1e-9, "experiment": int(msg.experiment), "phase": msg.phase, "model": msg.model,
        "method": msg.method, "equations": list(msg.equations), "params": dict(zip(names, values.tolist())),
        "std": {} if std is None else dict(zip(names, std.tolist())), "rmse_force": float(msg.rmse_force),
        "samples": int(msg.samples), "undetermined": dict(zip(msg.undetermined, msg.reasons)),
        "message": msg.message, "final": bool(msg.final),
    }


def diagnosis_message(types: MessageTypes, d: Any) -> Any:
    """``/rheo/diagnosis`` from an ``online.estimator.OnlineDiagnosis``."""
    msg = types.lookup(DIAGNOSIS_TYPE)(
        header=_header(types, ""), experiment=d.experiment, adequate=bool(d.adequate),
        missing_effects=list(d.missing_effects), forms=list(d.forms), undecided=list(d.undecided),
        verdict=d.verdict, undetermined=list(d.undetermined), models=list(d.models),
        rmse_force=types.float64s(d.rmse_force), bic=types.float64s(d.bic), candidates=list(d.candidates),
        delta_bic=types.float64s(d.delta_bic), model=d.models[-1] if d.models else "", names=list(d.names),
        values=types.float64s(d.values), std=types.float64s(d.std), evidence=d.evidence,
        at_bound=list(d.at_bound), leftover=list(d.leftover),
    )
    _stamp(msg, int(round(d.stamp * 1e9)))
    return msg


def read_diagnosis(msg: Any) -> dict[str, Any]:
    """A Diagnosis message as plain values."""
    names = list(msg.names)
    return {
        "stamp": stamp_ns(msg) * 1e-9, "experiment": int(msg.experiment), "adequate": bool(msg.adequate),
        "missing_effects": list(msg.missing_effects), "forms": dict(zip(msg.missing_effects, msg.forms)),
        "undecided": list(msg.undecided), "verdict": msg.verdict, "undetermined": list(msg.undetermined),
        "models": dict(zip(msg.models, zip(np.asarray(msg.rmse_force, float).tolist(),
                                           np.asarray(msg.bic, float).tolist()))),
        "candidates": dict(zip(msg.candidates, np.asarray(msg.delta_bic, float).tolist())),
        "model": msg.model, "params": dict(zip(names, np.asarray(msg.values, float).tolist())),
        "std": dict(zip(names, np.asarray(msg.std, float).tolist())), "evidence": msg.evidence,
        "at_bound": list(msg.at_bound), "leftover": list(msg.leftover),
    }


def object_hint_message(types: MessageTypes, t_ns: int, kind: str) -> Any:
    """``/rheo/object``: what the robot says about the object the next push meets."""
    msg = types.lookup(OBJECT_TYPE)(header=_header(types, ""), object=kind)
    _stamp(msg, t_ns)
    return msg


def read_object_hint(msg: Any) -> str:
    """The hint of an ObjectHint message (``new``, ``same`` or ``""``).

    Raises:
        MessageError: another word."""
    try:
        return check_object_hint(msg.object)
    except ValueError as exc:
        raise MessageError(str(exc)) from None


def pool_message(types: MessageTypes, update: Any) -> Any:
    """``/rheo/pool`` from an ``online.estimator.PoolUpdate``."""
    pool, change = update.pool, update.change
    msg = types.lookup(POOL_TYPE)(
        header=_header(types, ""), experiment=update.experiment, experiments=types.uint32s(pool.experiments),
        names=list(pool.names), values=types.float64s(pool.values),
        covariance=types.float64s(np.asarray(pool.covariance).ravel()), chi2=float(pool.chi2), dof=int(pool.dof),
        started=change is not None, stated=bool(change and change.stated),
        moved=list(change.moved) if change else [],
        shift=types.float64s(list(change.moved.values()) if change else []), message=update.message,
    )
    _stamp(msg, int(round(update.stamp * 1e9)))
    return msg


def read_pool(msg: Any) -> dict[str, Any]:
    """A Pool message as plain values: params, std, the members, whether it started a pool."""
    names = list(msg.names)
    cov = np.asarray(msg.covariance, float).reshape(len(names), len(names))
    return {
        "stamp": stamp_ns(msg) * 1e-9, "experiment": int(msg.experiment),
        "experiments": [int(k) for k in msg.experiments],
        "params": dict(zip(names, np.asarray(msg.values, float).tolist())),
        "std": dict(zip(names, np.sqrt(np.diag(cov)).tolist())), "chi2": float(msg.chi2), "dof": int(msg.dof),
        "started": bool(msg.started), "stated": bool(msg.stated),
        "moved": dict(zip(msg.moved, np.asarray(msg.shift, float).tolist())), "message": msg.message,
    }
