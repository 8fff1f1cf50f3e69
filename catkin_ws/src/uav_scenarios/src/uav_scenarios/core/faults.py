"""Scripted faults: a scenario's ``faults`` as the ``MAV_CMD_INJECT_FAILURE`` commands a test rig sends.

Pure: the schedule is a function of the scenario and of the run's elapsed simulation time, passed in. The
mission manager's MAVLink shell (:mod:`uav_scenarios.shell.fault_link`) sends what is due; the scorer records
each command and what followed (:mod:`uav_scenarios.core.scoring.faults`).

Each fault ``{at_s, unit, type, instance, duration_s}`` becomes an *inject* action at ``at_s`` (run time: simulated
seconds since the mission started) and, with ``duration_s``, a *clear* action (``FAILURE_TYPE_OK``) at
``at_s + duration_s``. Units and types are MAVLink's ``FAILURE_UNIT`` and ``FAILURE_TYPE`` numbers.

The camera units (:data:`CAMERA`: ``camera_nadir``, ``camera_forward``) are the range's own, as MAVLink has no
``FAILURE_UNIT`` for a payload camera: the mission manager asks the sim bridge to apply them
(``/sim_bridge/set_camera_fault``, :mod:`uav_scenarios.ros.camera_faults`) instead of the autopilot.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Protocol

__all__ = [
    "CAMERA",
    "FAILURE_TYPE_CODES",
    "FAILURE_UNIT_CODES",
    "SIMULATED",
    "FaultAction",
    "FaultSchedule",
    "camera_name",
    "fault_actions",
    "not_simulated",
]

#: MAVLink FAILURE_UNIT numbers of the scenario's unit names (the camera units have none: see :func:`not_simulated`).
FAILURE_UNIT_CODES: dict[str, int] = {
    "gyro": 0, "accel": 1, "mag": 2, "baro": 3, "gps": 4, "optical_flow": 5, "vio": 6, "distance_sensor": 7,
    "airspeed": 8, "battery": 100, "motor": 101, "servo": 102, "avoidance": 103, "rc_signal": 104,
    "mavlink_signal": 105,
}  # fmt: skip
#: MAVLink FAILURE_TYPE numbers.
FAILURE_TYPE_CODES: dict[str, int] = {
    "ok": 0, "off": 1, "stuck": 2, "garbage": 3, "wrong": 4, "slow": 5, "delayed": 6, "intermittent": 7,
}  # fmt: skip
#: What the SITL simulates (docs/sitl.md "Failure injection"); ``ok`` clears any of them.
SIMULATED: dict[str, frozenset[str]] = {
    "gps": frozenset({"off", "stuck", "garbage", "intermittent"}),
    "mag": frozenset({"off", "stuck", "garbage", "intermittent"}),
    "baro": frozenset({"off", "stuck", "garbage", "intermittent"}),
    "battery": frozenset({"off"}),
    "motor": frozenset({"off", "wrong"}),
}


#: The simulated cameras' faults, the sim bridge's (``camera_<name>``: its camera ``<name>``; docs/sim_bridge.md
#: "Camera faults"); ``ok`` clears any of them.
CAMERA: dict[str, frozenset[str]] = {
    "camera_nadir": frozenset({"off", "stuck", "garbage", "intermittent"}),
    "camera_forward": frozenset({"off", "stuck", "garbage", "intermittent"}),
}


def camera_name(unit: str) -> str:
    """The sim bridge's name of a camera unit (``camera_nadir`` -> ``nadir``); "" for an autopilot unit."""
    return unit.removeprefix("camera_") if unit in CAMERA else ""


def not_simulated(unit: str, failure_type: str) -> str:
    """Why the range cannot run this fault ("" when it can)."""
    if unit in CAMERA:
        if failure_type == "ok" or failure_type in CAMERA[unit]:
            return ""
        return f"{unit} {failure_type} is not simulated; a camera takes {'/'.join(sorted(CAMERA[unit]))}"
    if unit not in FAILURE_UNIT_CODES:
        return f"{unit} is not a MAVLink FAILURE_UNIT nor a camera of the range ({', '.join(CAMERA)})"
    if failure_type == "ok" and unit in SIMULATED:
        return ""
    if failure_type not in SIMULATED.get(unit, frozenset()):
        done = "; ".join(f"{u} {'/'.join(sorted(t))}" for u, t in SIMULATED.items())
        return (
            f"{unit} {failure_type} is not simulated by the SITL (it would answer UNSUPPORTED); "
            f"it simulates {done} (docs/sitl.md 'Failure injection')"
        )
    return ""


@dataclass(frozen=True)
class FaultAction:
    """One ``MAV_CMD_INJECT_FAILURE`` to send.

    Attributes:
        at_s: run time it is due (simulated seconds since the mission started).
        index: the fault's position in the scenario's ``faults`` list.
        unit, failure_type: the scenario's names (``failure_type`` is ``ok`` for a clear).
        instance: param3 (motor number, 1-based; 0 = all).
        clear: the end of a fault with ``duration_s`` (type OK).
    """

    at_s: float
    index: int
    unit: str
    failure_type: str
    instance: int
    clear: bool = False

    @property
    def camera(self) -> str:
        """The sim bridge's camera of a camera fault; "" for an autopilot fault (sent over MAVLink)."""
        return camera_name(self.unit)

    @property
    def unit_code(self) -> int:
        return FAILURE_UNIT_CODES[self.unit]

    @property
    def type_code(self) -> int:
        return FAILURE_TYPE_CODES[self.failure_type]

    @property
    def label(self) -> str:
        """E.g. ``gps off``, ``motor 1 wrong``, ``gps ok (end of fault 0)``."""
        inst = f" {self.instance}" if self.instance else ""
        end = f" (end of fault {self.index})" if self.clear else ""
        return f"{self.unit}{inst} {self.failure_type}{end}"


class _Fault(Protocol):
    """A scenario's fault (``uav_scenarios.core.config.FaultSpec``, which imports this module)."""

    @property
    def at_s(self) -> float: ...
    @property
    def unit(self) -> str: ...
    @property
    def type(self) -> str | bool: ...
    @property
    def instance(self) -> int: ...
    @property
    def duration_s(self) -> float | None: ...


def fault_actions(faults: Iterable[_Fault]) -> tuple[FaultAction, ...]:
    """The scenario's faults as actions in time order (ties: the file's order, an inject before a clear of the
    same time)."""
    actions: list[FaultAction] = []
    for i, f in enumerate(faults):
        actions.append(FaultAction(float(f.at_s), i, f.unit, str(f.type), int(f.instance)))
        if f.duration_s is not None:
            actions.append(FaultAction(float(f.at_s) + f.duration_s, i, f.unit, "ok", int(f.instance), clear=True))
    return tuple(sorted(actions, key=lambda a: (a.at_s, a.clear, a.index)))


class FaultSchedule:
    """Hands out each action once, when the run's elapsed time reaches it."""

    def __init__(self, actions: Iterable[FaultAction]) -> None:
        self._pending = sorted(actions, key=lambda a: (a.at_s, a.clear, a.index))

    @property
    def pending(self) -> tuple[FaultAction, ...]:
        return tuple(self._pending)

    @property
    def next_at_s(self) -> float | None:
        return self._pending[0].at_s if self._pending else None

    def due(self, elapsed_s: float) -> list[FaultAction]:
        """Actions due at ``elapsed_s`` (run time), oldest first; each is returned once."""
        n = 0
        while n < len(self._pending) and self._pending[n].at_s <= elapsed_s:
            n += 1
        out, self._pending = self._pending[:n], self._pending[n:]
        return out
