"""LiPo battery model: open-circuit voltage curve, internal resistance, coulomb counting.

The load is the electrical power the motors (through their ESCs) and the avionics
draw; the current follows from ``P = V_terminal * I`` with
``V_terminal = OCV(soc) - I * R``, i.e. ``I = (OCV - sqrt(OCV^2 - 4 R P)) / (2 R)``.
When the pack cannot deliver the power (negative discriminant) it delivers its
maximum, ``OCV / (2 R)`` at ``OCV / 2``.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

__all__ = ["BatteryModel", "BatteryReading", "BatterySpec"]


@dataclass(frozen=True)
class BatterySpec:
    """Physical pack: ``ocv_curve`` is ``((soc, cell_volts), ...)`` from soc 0 to 1."""

    cells: int
    capacity_mah: float
    internal_resistance_ohm: float
    ocv_curve: tuple[tuple[float, float], ...]

    def cell_ocv_v(self, soc: float) -> float:
        """Open-circuit cell voltage at state of charge ``soc`` (linear interpolation, clamped)."""
        socs = [p[0] for p in self.ocv_curve]
        soc = 0.0 if math.isnan(soc) else min(1.0, max(0.0, soc))
        i = bisect.bisect_right(socs, soc)
        if i >= len(socs):
            return self.ocv_curve[-1][1]
        if i == 0:
            return self.ocv_curve[0][1]
        (s0, v0), (s1, v1) = self.ocv_curve[i - 1], self.ocv_curve[i]
        return v0 + (v1 - v0) * (soc - s0) / (s1 - s0)

    def pack_ocv_v(self, soc: float) -> float:
        return self.cells * self.cell_ocv_v(soc)


@dataclass(frozen=True)
class BatteryReading:
    """What the battery reports (and what SYS_STATUS / BATTERY_STATUS carry)."""

    voltage_v: float
    current_a: float
    consumed_mah: float
    energy_consumed_j: float
    remaining: float
    cell_voltage_v: float
    power_w: float

    @property
    def remaining_pct(self) -> int:
        return round(100.0 * self.remaining)


class BatteryModel:
    """Stateful pack; :meth:`step` integrates one time step of a given electrical load."""

    def __init__(self, spec: BatterySpec, initial_soc: float = 1.0) -> None:
        if not 0.0 <= initial_soc <= 1.0:
            msg = f"initial_soc must be in [0, 1], got {initial_soc}"
            raise ValueError(msg)
        self.spec = spec
        self._capacity_c = spec.capacity_mah * 3.6
        self._charge_used_c = (1.0 - initial_soc) * self._capacity_c
        self._initial_used_c = self._charge_used_c
        self._energy_j = 0.0
        ocv = spec.pack_ocv_v(initial_soc)
        self._ocv_soc = initial_soc
        self._ocv_v = ocv
        self._voltage_v = ocv
        self._current_a = 0.0
        self._reading: BatteryReading | None = None

    @property
    def soc(self) -> float:
        return max(0.0, 1.0 - self._charge_used_c / self._capacity_c)

    @property
    def reading(self) -> BatteryReading:
        """The state after the last :meth:`step`."""
        if self._reading is None:
            consumed_mah = (self._charge_used_c - self._initial_used_c) / 3.6
            self._reading = BatteryReading(
                voltage_v=self._voltage_v,
                current_a=self._current_a,
                consumed_mah=consumed_mah,
                energy_consumed_j=self._energy_j,
                remaining=self.soc,
                cell_voltage_v=self._voltage_v / self.spec.cells,
                power_w=self._current_a * self._voltage_v,
            )
        return self._reading

    @property
    def terminal_voltage_v(self) -> float:
        return self._voltage_v

    def _ocv(self) -> float:
        soc = self.soc
        if abs(soc - self._ocv_soc) > 1e-5:
            self._ocv_soc = soc
            self._ocv_v = self.spec.pack_ocv_v(soc)
        return self._ocv_v

    def current_for_power(self, power_w: float) -> tuple[float, float]:
        """``(current_a, terminal_voltage_v)`` that delivers ``power_w`` at the present charge."""
        ocv = self._ocv()
        r = self.spec.internal_resistance_ohm
        power_w = max(0.0, power_w)
        if r <= 0.0:
            return power_w / ocv, ocv
        disc = ocv * ocv - 4.0 * r * power_w
        current = ocv / (2.0 * r) if disc <= 0.0 else (ocv - math.sqrt(disc)) / (2.0 * r)
        return current, ocv - current * r

    def step(self, power_w: float, dt_s: float) -> None:
        """Draw ``power_w`` (electrical, at the terminals) for ``dt_s`` seconds."""
        current, voltage = self.current_for_power(power_w)
        self._charge_used_c += current * dt_s
        self._energy_j += current * voltage * dt_s
        self._current_a = current
        self._voltage_v = voltage
        self._reading = None
