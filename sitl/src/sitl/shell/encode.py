"""Vehicle state -> pymavlink message objects (the telemetry the autopilot reports).

Every number here is what PX4 puts in the same field: simulation-time stamps
(``time_boot_ms``, ``time_usec``), 1e-7 degree positions, millimetre altitudes,
centi-units for speeds and currents, the estimate (not the truth) for
everything a client sees on the vehicle links.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from sitl.core.control import Setpoint
from sitl.core.estimator import field_in_body
from sitl.core.failsafe import FailsafeKind
from sitl.core.modes import FlightMode
from sitl.core.params import ParamTable, encode_wire_value
from sitl.core.personality import PX4
from sitl.core.protocol import MissionState, MsgId
from sitl.shell.links import mavlink
from sitl.shell.wire import WirePackers
from sitl.vehicle import Vehicle

__all__ = ["AUTOPILOT_CAPABILITIES", "FLIGHT_SW_VERSION", "Encoder", "statustext_chunks"]

#: What AUTOPILOT_VERSION advertises for the default (PX4) personality: exactly what is implemented
#: (missions INT and float, COMMAND_INT, bytewise parameters, position and attitude targets, fences, MAVLink 2;
#: no rally points, FTP, terrain or flight termination). The ArduPilot personality's are in its Personality.
AUTOPILOT_CAPABILITIES = PX4.capabilities
# PX4 version encoding: major << 24 | minor << 16 | patch << 8 | type (255 = release). We claim 1.14.0.
FLIGHT_SW_VERSION = PX4.flight_sw_version

# Sensors we simulate; PREARM_CHECK in health means "armable" (MAVSDK health.is_armable).
_S = mavlink
SENSORS = (
    _S.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | _S.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | _S.MAV_SYS_STATUS_SENSOR_3D_MAG
    | _S.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | _S.MAV_SYS_STATUS_SENSOR_GPS
    | _S.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | _S.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | _S.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | _S.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | _S.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | _S.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | _S.MAV_SYS_STATUS_AHRS
    | _S.MAV_SYS_STATUS_SENSOR_BATTERY
    | _S.MAV_SYS_STATUS_PREARM_CHECK
)
# HIGHRES_IMU fields_updated: every field, and the magnetometer's (bits 6-8) and the barometer's
# (abs pressure, pressure altitude, temperature: bits 9, 11, 12).
_HIGHRES_ALL = 0x1FFF
_HIGHRES_MAG = 0x1C0
_HIGHRES_BARO = 0x1A00
INT16_MAX = 32767
UINT16_MAX = 65535


def statustext_chunks(text: str, chunk_id: int) -> list[tuple[bytes, int, int]]:
    """``(text, id, chunk_seq)`` pieces of at most 50 bytes (MAVLink 2 STATUSTEXT chunking).

    A text that fits is sent with id 0; a longer one in 50-byte chunks sharing
    ``chunk_id`` (1..65535), the last one shorter than 50 bytes (NUL-terminated).
    """
    raw = text.encode("utf-8", "replace")
    if len(raw) <= 50:
        return [(raw, 0, 0)]
    pieces = [raw[i : i + 50] for i in range(0, len(raw), 50)]
    if len(pieces[-1]) == 50:
        pieces.append(b"")
    return [(piece, chunk_id, i) for i, piece in enumerate(pieces)]


def sim_time_us(t_s: float) -> int:
    """Simulation time in whole microseconds, rounded: ``steps * dt * 1e6`` in floating point can land a
    hair below the instant (2050 * 0.004 * 1e6 = 8199999.999999999), and truncating it would stamp the state
    1 us early (a 10 Hz camera on the grid k / 10 then skipped a frame now and then)."""
    return round(t_s * 1e6)


def _isa_pressure_hpa(alt_amsl_m: float) -> float:
    return float(1013.25 * max(0.0, 1.0 - 2.25577e-5 * alt_amsl_m) ** 5.25588)


def _cdeg(rad: float) -> int:
    return round(math.degrees(rad) % 360.0 * 100.0) % 36000


def _clamp_int(value: float, low: int, high: int) -> int:
    if not math.isfinite(value):
        return low
    return int(max(low, min(high, round(value))))


class Encoder:
    """Builds messages from one :class:`Vehicle`; ``build(msg_id)`` or the named helpers."""

    def __init__(self, vehicle: Vehicle, *, unix_epoch_s: float, system_id: int) -> None:
        self.v = vehicle
        self.unix_epoch_s = unix_epoch_s
        self.system_id = system_id
        self.load_permille = 0
        self.errors_comm = 0
        self.factory = mavlink.MAVLink(None)
        self.fast = WirePackers()
        self.personality = vehicle.autopilot.personality
        self._chunk_id = 0
        # the last magnetometer and barometer readings (what HIGHRES_IMU repeats while a sensor is silent)
        self._last_mag = (0.0, 0.0, 0.0)
        self._last_baro = (0.0, 0.0, 0.0)
        #: message id -> builder (what :meth:`build` dispatches through; the gateway's stream loop calls it directly)
        self.builders = self._table()

    @property
    def time_boot_ms(self) -> int:
        return (sim_time_us(self.v.t_s) // 1000) & 0xFFFFFFFF

    @property
    def time_usec(self) -> int:
        return sim_time_us(self.v.t_s)

    def build(self, msg_id: int) -> Any | None:
        """The message for a stream or a REQUEST_MESSAGE; ``None`` if it cannot be produced."""
        builder = self.builders.get(msg_id)
        return None if builder is None else builder()

    def _table(self) -> dict[int, Callable[[], Any]]:
        return {
            MsgId.HEARTBEAT: self.heartbeat,
            MsgId.SYS_STATUS: self.sys_status,
            MsgId.BATTERY_STATUS: self.battery_status,
            MsgId.EXTENDED_SYS_STATE: self.extended_sys_state,
            MsgId.ATTITUDE: self.attitude,
            MsgId.ATTITUDE_QUATERNION: self.attitude_quaternion,
            MsgId.LOCAL_POSITION_NED: self.local_position_ned,
            MsgId.GLOBAL_POSITION_INT: self.global_position_int,
            MsgId.GPS_RAW_INT: self.gps_raw_int,
            MsgId.HOME_POSITION: self.home_position,
            MsgId.ALTITUDE: self.altitude,
            MsgId.VFR_HUD: self.vfr_hud,
            MsgId.HIGHRES_IMU: self.highres_imu,
            MsgId.SYSTEM_TIME: self.system_time,
            MsgId.ODOMETRY: lambda: self.odometry(truth=False),
            MsgId.POSITION_TARGET_LOCAL_NED: self.position_target,
            MsgId.MISSION_CURRENT: self.mission_current,
            MsgId.AUTOPILOT_VERSION: self.autopilot_version,
            MsgId.GPS_GLOBAL_ORIGIN: self.gps_global_origin,
        }

    def extended_sys_state(self) -> Any:
        ap = self.v.autopilot
        return self.fast.extended_sys_state(mavlink.MAV_VTOL_STATE_UNDEFINED, int(ap.landed_state))

    def attitude(self) -> Any:
        s = self.v.est.full
        r, p, y = s.euler_rad
        return self.fast.attitude(self.time_boot_ms, r, p, y, *s.rates_frd_radps)

    def attitude_quaternion(self) -> Any:
        s = self.v.est.full
        return self.fast.attitude_quaternion(self.time_boot_ms, *s.q_wxyz, *s.rates_frd_radps)

    def local_position_ned(self) -> Any:
        e = self.v.est
        if not e.pos_valid:
            return None  # PX4 sends LOCAL_POSITION_NED only while the position is valid
        return self.fast.local_position_ned(self.time_boot_ms, *e.pos_ned_m, *e.vel_ned_mps)

    def altitude(self) -> Any:
        e = self.v.est
        amsl = e.full.alt_amsl_m
        rel = -e.pos_ned_m[2]
        agl = e.full.height_above_ground_m
        return self.fast.altitude(self.time_usec, amsl, amsl, rel, rel, agl, agl)

    def vfr_hud(self) -> Any:
        e = self.v.est
        vn, ve, vd = e.vel_ned_mps
        speed = math.hypot(vn, ve)
        heading = int(math.degrees(e.yaw_rad) % 360.0) % 360
        throttle = _clamp_int(100.0 * self.v.autopilot.thrust, 0, 100)
        return self.fast.vfr_hud(speed, speed, heading, throttle, e.full.alt_amsl_m, -vd)

    def system_time(self) -> Any:
        unix_us = round(self.unix_epoch_s * 1e6) + sim_time_us(self.v.t_s)
        return self.fast.system_time(unix_us, self.time_boot_ms)

    def gps_global_origin(self) -> Any:
        h = self.v.home
        return self.factory.gps_global_origin_encode(
            round(h.lat_deg * 1e7), round(h.lon_deg * 1e7), round(h.alt_amsl_m * 1000), self.time_usec
        )

    # ------------------------------------------------------------------ messages
    def heartbeat(self) -> Any:
        ap = self.v.autopilot
        p = self.personality
        return self.fast.heartbeat(
            mavlink.MAV_TYPE_QUADROTOR,
            p.mav_autopilot,
            p.base_mode(ap.mode, armed=ap.armed),
            p.custom_mode(ap.mode),
            int(ap.system_status),
        )

    def sys_status(self) -> Any:
        ap = self.v.autopilot
        b = self.v.battery_reading
        health = SENSORS
        estimator = self.v.estimator
        if not self.v.est.gps_ok:
            health &= ~mavlink.MAV_SYS_STATUS_SENSOR_GPS
        if not estimator.mag_healthy:
            health &= ~mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
        if not estimator.baro_healthy:
            health &= ~mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
        if ap.prearm_failure() is not None:
            health &= ~mavlink.MAV_SYS_STATUS_PREARM_CHECK
        if ap.crashed:
            health &= ~(mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | mavlink.MAV_SYS_STATUS_PREARM_CHECK)
        present = SENSORS
        settings = ap.settings
        fence_on = settings.fence_action is not None and (
            settings.fence_radius_m > 0 or settings.fence_max_alt_m > 0 or not ap.fence_store.fence.empty
        )
        if fence_on:
            present |= mavlink.MAV_SYS_STATUS_GEOFENCE
            if FailsafeKind.GEOFENCE not in ap.failsafe.active:
                health |= mavlink.MAV_SYS_STATUS_GEOFENCE
        return self.fast.sys_status(
            present,
            present,
            health,
            _clamp_int(self.load_permille, 0, 1000),
            _clamp_int(b.voltage_v * 1000.0, 0, UINT16_MAX - 1),
            _clamp_int(b.current_a * 100.0, -1, INT16_MAX),
            _clamp_int(100.0 * b.remaining, 0, 100),
            0,
            _clamp_int(self.errors_comm, 0, UINT16_MAX),
            0,
            0,
            0,
            0,
        )

    def battery_status(self) -> Any:
        b = self.v.battery_reading
        cells = self.v.cfg.battery.cells
        cell_mv = _clamp_int(b.cell_voltage_v * 1000.0, 0, UINT16_MAX - 1)
        voltages = [cell_mv if i < cells else UINT16_MAX for i in range(10)]
        ext = [cell_mv if 10 + i < cells else 0 for i in range(4)]
        settings = self.v.autopilot.settings
        if b.remaining <= settings.battery_critical_remaining:
            state = mavlink.MAV_BATTERY_CHARGE_STATE_CRITICAL
        elif b.remaining <= settings.battery_low_remaining:
            state = mavlink.MAV_BATTERY_CHARGE_STATE_LOW
        else:
            state = mavlink.MAV_BATTERY_CHARGE_STATE_OK
        remaining_mah = b.remaining * self.v.cfg.battery.capacity_mah
        time_remaining = int(remaining_mah * 3.6 / b.current_a) if b.current_a > 0.5 else 0
        return self.fast.battery_status(
            0,
            mavlink.MAV_BATTERY_FUNCTION_ALL,
            mavlink.MAV_BATTERY_TYPE_LIPO,
            INT16_MAX,
            voltages,
            _clamp_int(b.current_a * 100.0, -1, INT16_MAX),
            _clamp_int(b.consumed_mah, 0, 2**31 - 1),
            _clamp_int(b.energy_consumed_j / 100.0, 0, 2**31 - 1),
            _clamp_int(100.0 * b.remaining, 0, 100),
            time_remaining,
            state,
            ext,
        )

    def global_position_int(self) -> Any:
        e = self.v.est
        if not e.pos_valid:
            return None
        s = e.full
        vn, ve, vd = e.vel_ned_mps
        return self.fast.global_position_int(
            self.time_boot_ms,
            round(s.lat_deg * 1e7),
            round(s.lon_deg * 1e7),
            round(s.alt_amsl_m * 1000.0),
            round(-e.pos_ned_m[2] * 1000.0),
            _clamp_int(vn * 100.0, -INT16_MAX, INT16_MAX),
            _clamp_int(ve * 100.0, -INT16_MAX, INT16_MAX),
            _clamp_int(vd * 100.0, -INT16_MAX, INT16_MAX),
            _cdeg(e.yaw_rad),
        )

    def gps_raw_int(self) -> Any:
        e = self.v.est
        est = self.v.estimator
        r = est.gps_report  # the receiver's own (wrong) fix under a STUCK or GARBAGE failure
        if r is not None:
            lat, lon, alt = r.lat_deg, r.lon_deg, r.alt_amsl_m
            vn, ve = r.vel_n_mps, r.vel_e_mps
            ok = True
        else:
            s = e.full
            lat, lon, alt = s.lat_deg, s.lon_deg, s.alt_amsl_m
            vn, ve, _ = e.vel_ned_mps
            ok = e.gps_ok
        speed = math.hypot(vn, ve)
        cog = _cdeg(math.atan2(ve, vn)) if speed > 0.2 else UINT16_MAX
        return self.fast.gps_raw_int(
            self.time_usec,
            est.fix_type if ok else mavlink.GPS_FIX_TYPE_NO_FIX,
            round(lat * 1e7),
            round(lon * 1e7),
            round(alt * 1000.0),
            80 if ok else UINT16_MAX,
            120 if ok else UINT16_MAX,
            _clamp_int(speed * 100.0, 0, UINT16_MAX - 1),
            cog,
            12 if ok else 0,
            round(alt * 1000.0),
            _clamp_int(est.h_acc_m * 1000.0, 0, 2**31 - 1) if ok else 0,
            _clamp_int(est.v_acc_m * 1000.0, 0, 2**31 - 1) if ok else 0,
            100 if ok else 0,
            0,
            0,
        )

    def home_position(self) -> Any:
        h = self.v.home
        return self.fast.home_position(
            round(h.lat_deg * 1e7),
            round(h.lon_deg * 1e7),
            round(h.alt_amsl_m * 1000.0),
            0.0,
            0.0,
            0.0,
            [1.0, 0.0, 0.0, 0.0],
            0.0,
            0.0,
            0.0,
            self.time_usec,
        )

    def highres_imu(self) -> Any:
        s = self.v.est.full
        est = self.v.estimator
        ax, ay, az = s.specific_force_frd_mps2
        updated = _HIGHRES_ALL
        # the magnetometer: the field at the estimate's attitude, or what a failed one reports
        if not est.mag_reporting:
            mx, my, mz = self._last_mag  # silent: the last reading, not flagged as updated (PX4)
            updated &= ~_HIGHRES_MAG
        else:
            mx, my, mz = est.mag_report_body if est.mag_report_body is not None else field_in_body(s.q_wxyz)
            self._last_mag = (mx, my, mz)
        if not est.baro_reporting:
            pressure, alt, temperature = self._last_baro
            updated &= ~_HIGHRES_BARO
        else:
            alt = est.baro_report_alt_m if est.baro_report_alt_m is not None else s.alt_amsl_m
            pressure = _isa_pressure_hpa(alt)
            temperature = 15.0 - 0.0065 * alt
            self._last_baro = (pressure, alt, temperature)
        return self.fast.highres_imu(
            self.time_usec, ax, ay, az, *s.rates_frd_radps, mx, my, mz, pressure, 0.0, alt, temperature, updated
        )

    def odometry(self, *, truth: bool) -> Any:
        v = self.v
        if truth:
            s = v.truth()
            pos = v.pos_ned_truth_m
        else:
            if not v.est.pos_valid:
                return None  # PX4 publishes no odometry without a local position
            s = v.est.full
            pos = v.est.pos_ned_m
        w, x, y, z = s.q_wxyz
        vn, ve, vd = s.vel_ned_mps
        # NED -> body FRD: R^T v
        bx = (1 - 2 * (y * y + z * z)) * vn + 2 * (x * y + w * z) * ve + 2 * (x * z - w * y) * vd
        by = 2 * (x * y - w * z) * vn + (1 - 2 * (x * x + z * z)) * ve + 2 * (y * z + w * x) * vd
        bz = 2 * (x * z + w * y) * vn + 2 * (y * z - w * x) * ve + (1 - 2 * (x * x + y * y)) * vd
        return self.fast.odometry_unknown_covariance(
            sim_time_us(s.t_s),
            mavlink.MAV_FRAME_LOCAL_NED,
            mavlink.MAV_FRAME_BODY_FRD,
            *pos,
            [w, x, y, z],
            bx,
            by,
            bz,
            *s.rates_frd_radps,
            mavlink.MAV_ESTIMATOR_TYPE_NAIVE if truth else mavlink.MAV_ESTIMATOR_TYPE_UNKNOWN,
            100,
        )

    def position_target(self) -> Any:
        ap = self.v.autopilot
        nav = ap.last_nav
        sp = nav.setpoint if nav is not None else Setpoint()
        vsp = ap.velocity_setpoint
        mask = 0
        pos = list(sp.pos)
        for i, bit in enumerate((1, 2, 4)):
            if not math.isfinite(pos[i]):
                mask |= bit
                pos[i] = 0.0
        yaw = sp.yaw_rad if math.isfinite(sp.yaw_rad) else 0.0
        if not math.isfinite(sp.yaw_rad):
            mask |= 1024
        mask |= 64 | 128 | 256 | 2048
        return self.fast.position_target_local_ned(
            self.time_boot_ms, mavlink.MAV_FRAME_LOCAL_NED, mask, *pos, *vsp, 0.0, 0.0, 0.0, yaw, 0.0
        )

    def mission_current(self) -> Any:
        ap = self.v.autopilot
        count = len(ap.mission_store)
        state = ap.mission_state
        if self.personality.mission_home_item:
            # ArduPilot: seq counts from 1 (item 0 is home); total excludes home; mission_mode 1 in AUTO else 0
            total = max(count - 1, 0)
            seq = min(ap.mission_current_seq, max(count - 1, 0))
            mode = 1 if ap.mode is FlightMode.AUTO_MISSION else 0
            return self.fast.mission_current(seq, total, int(state), mode)
        total = count
        seq = (
            min(ap.mission_current_seq, max(total - 1, 0)) if state is not MissionState.COMPLETE else max(total - 1, 0)
        )
        mode = 1 if ap.mode is FlightMode.AUTO_MISSION else 2
        return self.fast.mission_current(seq, total, int(state), mode)

    def autopilot_version(self) -> Any:
        uid = (0x5549_4C53 << 32) | self.system_id  # "UILS" + sysid: stable per instance
        return self.factory.autopilot_version_encode(
            self.personality.capabilities,
            self.personality.flight_sw_version,
            0,
            0,
            0,
            b"uavsitl\0",
            b"\0" * 8,
            b"\0" * 8,
            0,
            0,
            uid,
        )

    def param_value(self, params: ParamTable, name: str) -> Any:
        spec = params.spec(name)
        return self.factory.param_value_encode(
            name.encode("ascii"),
            encode_wire_value(params[name], spec.type, bytewise=self.personality.int_params_bytewise),
            int(spec.type),
            len(params),
            params.index_of(name),
        )

    def statustexts(self, severity: int, text: str) -> list[Any]:
        self._chunk_id = self._chunk_id % 65535 + 1
        return [
            self.factory.statustext_encode(severity, piece, sid, seq)
            for piece, sid, seq in statustext_chunks(text, self._chunk_id)
        ]
