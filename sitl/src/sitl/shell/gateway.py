"""MAVLink microservices of the vehicle links: messages in -> autopilot calls; telemetry out.

The gateway is the only place where pymavlink messages meet the autopilot core.
Inbound messages are checked (target system/component, finite values) and
translated into core requests; replies go back on the link and to the address
they came from; periodic telemetry follows each link's
:class:`~sitl.core.telemetry.StreamScheduler`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Hashable
from typing import Any

from sitl.config import StreamProfile
from sitl.core.autopilot import ManualInput
from sitl.core.commands import CommandRequest, handle_command
from sitl.core.mission import MissionItem
from sitl.core.mission_transfer import (
    MissionAckOut,
    MissionCountOut,
    MissionOut,
    MissionRequestOut,
    Peer,
)
from sitl.core.modes import BASE_MODE_CUSTOM_MODE_ENABLED
from sitl.core.navigator import FollowTarget
from sitl.core.offboard import (
    OffboardRejection,
    attitude_setpoint,
    setpoint_from_global_int,
    setpoint_from_local_ned,
)
from sitl.core.params import decode_wire_value
from sitl.core.protocol import MavCmd, MavMissionResult, MavResult, MavSeverity, MsgId
from sitl.core.telemetry import NORMAL_RATES_HZ, ONBOARD_RATES_HZ, StreamScheduler
from sitl.shell.encode import Encoder, sim_time_us
from sitl.shell.links import MavLink, Received, mavlink
from sitl.vehicle import Vehicle
from uav_common.geo import GeoPoint

__all__ = ["Gateway"]

log = logging.getLogger(__name__)

# FTP (MAVLink FTP) opcodes we answer: everything gets a NAK, so clients fall back quickly.
_FTP_NAK = 129
_FTP_ERR_FILE_NOT_FOUND = 10
_FTP_ERR_UNKNOWN_COMMAND = 9
_FTP_OPEN_FILE_RO = 4
_DATALINK_TYPES = frozenset({mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER})


def _text(value: Any) -> str:
    if isinstance(value, bytes):
        value = value.decode("ascii", "replace")
    return str(value).split("\0", 1)[0]


class Gateway:
    """Microservices (command, param, mission, offboard, manual control, telemetry) over the vehicle links."""

    def __init__(
        self,
        vehicle: Vehicle,
        links: dict[str, tuple[MavLink, StreamProfile]],
        *,
        system_id: int,
        component_id: int,
        unix_epoch_s: float,
        persist_params: Callable[[dict[str, float]], None] | None = None,
    ) -> None:
        self.v = vehicle
        self.ap = vehicle.autopilot
        self.personality = vehicle.autopilot.personality
        self.links = {name: link for name, (link, _) in links.items()}
        max_rate = 1.0 / vehicle.dt_s
        # links of the same profile share one scheduler (their streams are due at the same instants) until a
        # SET_MESSAGE_INTERVAL on one of them gives that link its own copy (see _own_scheduler)
        by_profile = {
            profile: StreamScheduler(
                ONBOARD_RATES_HZ if profile is StreamProfile.ONBOARD else NORMAL_RATES_HZ, max_rate
            )
            for _, profile in links.values()
        }
        self.streams = {name: by_profile[profile] for name, (_, profile) in links.items()}
        self.system_id = system_id
        self.component_id = component_id
        self.encoder = Encoder(vehicle, unix_epoch_s=unix_epoch_s, system_id=system_id)
        self.persist_params = persist_params
        self._handlers: dict[str, Callable[[Any, Hashable, float], None]] = {
            "HEARTBEAT": self._on_heartbeat,
            "COMMAND_LONG": self._on_command_long,
            "COMMAND_INT": self._on_command_int,
            "SET_MODE": self._on_set_mode,
            "PARAM_REQUEST_LIST": self._on_param_request_list,
            "PARAM_REQUEST_READ": self._on_param_request_read,
            "PARAM_SET": self._on_param_set,
            "MISSION_COUNT": self._on_mission_count,
            "MISSION_ITEM_INT": self._on_mission_item_int,
            "MISSION_ITEM": self._on_mission_item,
            "MISSION_REQUEST_LIST": self._on_mission_request_list,
            "MISSION_REQUEST_INT": self._on_mission_request_int,
            "MISSION_REQUEST": self._on_mission_request,
            "MISSION_CLEAR_ALL": self._on_mission_clear_all,
            "MISSION_SET_CURRENT": self._on_mission_set_current,
            "SET_POSITION_TARGET_LOCAL_NED": self._on_set_position_target_local_ned,
            "SET_POSITION_TARGET_GLOBAL_INT": self._on_set_position_target_global_int,
            "SET_ATTITUDE_TARGET": self._on_set_attitude_target,
            "FOLLOW_TARGET": self._on_follow_target,
            "MANUAL_CONTROL": self._on_manual_control,
            "TIMESYNC": self._on_timesync,
            "PING": self._on_ping,
            "FILE_TRANSFER_PROTOCOL": self._on_ftp,
        }
        self._next_due_s = 0.0
        self._stream_links: list[tuple[StreamScheduler, list[MavLink]]] = []
        self._group_streams()

    def _group_streams(self) -> None:
        groups: dict[int, tuple[StreamScheduler, list[MavLink]]] = {}
        for name, sched in self.streams.items():
            groups.setdefault(id(sched), (sched, []))[1].append(self.links[name])
        self._stream_links = list(groups.values())

    def _own_scheduler(self, link_name: str) -> StreamScheduler:
        """The link's scheduler, first copied if other links share it (SET_MESSAGE_INTERVAL is per link)."""
        sched = self.streams[link_name]
        if sum(1 for other in self.streams.values() if other is sched) > 1:
            sched = sched.copy()
            self.streams[link_name] = sched
            self._group_streams()
        return sched

    # ================================================================== inbound
    def handle(self, rx: Received, wall_s: float) -> None:
        msg = rx.msg
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if src == (self.system_id, self.component_id) or src[0] == 0:
            return  # our own traffic echoed back, or an invalid source
        handler = self._handlers.get(msg.get_type())
        if handler is None:
            return
        try:
            handler(msg, rx.route, wall_s)
        except (ValueError, TypeError, OverflowError, KeyError) as err:
            # bad content that slipped past the checks: count it, never die
            self._stats(rx.route).rx_invalid_values += 1
            log.debug("dropped %s from %s: %s", msg.get_type(), rx.route, err)

    def _stats(self, route: Hashable) -> Any:
        return self._link(route).stats

    def _link(self, route: Hashable) -> MavLink:
        assert isinstance(route, tuple)
        return self.links[route[0]]

    def _for_us(self, msg: Any, route: Hashable, *, component: bool = True) -> bool:
        ts = getattr(msg, "target_system", 0)
        tc = getattr(msg, "target_component", 0)
        ok = ts in (0, self.system_id) and (not component or tc in (0, self.component_id))
        if not ok:
            self._stats(route).rx_other_target += 1
        return ok

    def _peer(self, msg: Any, route: Hashable) -> Peer:
        return Peer(route, msg.get_srcSystem(), msg.get_srcComponent())

    def send_to(self, route: Hashable, msg: Any) -> None:
        self._link(route).send(msg, route)

    def broadcast(self, msg: Any) -> None:
        for link in self.links.values():
            link.send(msg)

    def _on_heartbeat(self, msg: Any, route: Hashable, wall_s: float) -> None:
        gcs_sysid = self.ap.settings.datalink_sysid
        if gcs_sysid:
            # ArduCopter: only the heartbeat of system SYSID_MYGCS is the ground station's
            if msg.get_srcSystem() == gcs_sysid and msg.type != mavlink.MAV_TYPE_QUADROTOR:
                self.ap.datalink_heard(self.v.t_s, wall_s)
        elif msg.type in _DATALINK_TYPES:
            self.ap.datalink_heard(self.v.t_s, wall_s)

    # ------------------------------------------------------------------ commands
    def _on_command_long(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if not self._for_us(msg, route):
            return
        params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        self._command(CommandRequest(msg.command, params), msg, route)

    def _on_command_int(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if not self._for_us(msg, route):
            return
        lat = msg.x * 1e-7 if msg.x != 0 or msg.y != 0 else math.nan
        lon = msg.y * 1e-7 if msg.x != 0 or msg.y != 0 else math.nan
        if msg.x == 0x7FFFFFFF or msg.y == 0x7FFFFFFF:
            lat = lon = math.nan
        params = (msg.param1, msg.param2, msg.param3, msg.param4, lat, lon, msg.z)
        self._command(CommandRequest(msg.command, params, frame=msg.frame), msg, route)

    def _command(self, req: CommandRequest, msg: Any, route: Hashable) -> None:
        assert isinstance(route, tuple)
        streams = (
            self._own_scheduler(route[0]) if req.command == MavCmd.SET_MESSAGE_INTERVAL else self.streams[route[0]]
        )
        if any(math.isinf(p) for p in req.params):
            self._stats(route).rx_invalid_values += 1
        outcome = handle_command(req, self.ap, streams, self.v.t_s)
        self._next_due_s = min(self._next_due_s, streams.next_due_s)
        ack = self.encoder.factory.command_ack_encode(
            req.command, int(outcome.result), 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
        )
        self.send_to(route, ack)
        for msg_id in outcome.send:
            if msg_id == MsgId.MESSAGE_INTERVAL and outcome.interval_of is not None:
                reply = self.encoder.factory.message_interval_encode(
                    outcome.interval_of, streams.interval_us(outcome.interval_of)
                )
            else:
                reply = self.encoder.build(msg_id)
            if reply is not None:
                self.send_to(route, reply)
        self.flush_events()

    def _on_set_mode(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if not self._for_us(msg, route, component=False):
            return
        if not msg.base_mode & BASE_MODE_CUSTOM_MODE_ENABLED:
            self.ap.say(MavSeverity.CRITICAL, "SET_MODE without custom mode is not supported")
            return
        mode = self.personality.mode_from_custom_mode(msg.custom_mode)
        if mode is None:
            self.ap.say(MavSeverity.CRITICAL, f"Mode change denied: unsupported custom_mode {msg.custom_mode}")
            return
        self.ap.set_mode(mode)
        self.flush_events()

    # ------------------------------------------------------------------ parameters
    def _on_param_request_list(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if not self._for_us(msg, route):
            return
        params = self.v.params
        for name in params.names:
            self.send_to(route, self.encoder.param_value(params, name))

    def _on_param_request_read(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if not self._for_us(msg, route):
            return
        params = self.v.params
        if msg.param_index >= 0:
            if msg.param_index >= len(params):
                self._stats(route).rx_invalid_values += 1
                return
            name = params.names[msg.param_index]
        else:
            name = _text(msg.param_id)
            if name not in params:
                self._stats(route).rx_invalid_values += 1
                hint = self.personality.unknown_param_hint(name)
                if hint:  # a script written for the other autopilot: say so (real autopilots stay silent)
                    self.ap.say(MavSeverity.WARNING, hint)
                    self.flush_events()
                return
        self.send_to(route, self.encoder.param_value(params, name))

    def _on_param_set(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if not self._for_us(msg, route):
            return
        params = self.v.params
        name = _text(msg.param_id)
        if name not in params:
            self._stats(route).rx_invalid_values += 1
            hint = self.personality.unknown_param_hint(name)
            self.ap.say(MavSeverity.WARNING, hint or f"Parameter {name[:16]!r} does not exist")
            self.flush_events()
            return
        bytewise = self.personality.int_params_bytewise
        value = decode_wire_value(msg.param_value, msg.param_type, params.spec(name), bytewise=bytewise)
        if value is None:
            outcome_ok, reason = False, f"{name}: cannot decode value of type {msg.param_type}"
        else:
            before = params.version
            outcome = params.set(name, value)
            outcome_ok, reason = outcome.accepted, outcome.reason
            if outcome.accepted:
                self.ap.refresh_settings()  # a takeoff sent right after MIS_TAKEOFF_ALT must not use the old one
            if outcome.accepted and params.version != before and self.persist_params is not None:
                self.persist_params(params.changed_from_default())
        if outcome_ok:
            self.broadcast(self.encoder.param_value(params, name))
        else:
            self._stats(route).rx_invalid_values += 1
            self.ap.say(MavSeverity.WARNING, reason)
            self.send_to(route, self.encoder.param_value(params, name))
        self.flush_events()

    # ------------------------------------------------------------------ missions
    def _send_mission(self, outs: list[MissionOut]) -> None:
        m = self.encoder.factory
        for out in outs:
            peer = out.peer
            tgt = (peer.system_id, peer.component_id)
            if isinstance(out, MissionRequestOut):
                reply = m.mission_request_int_encode(*tgt, out.seq, out.mission_type)
            elif isinstance(out, MissionAckOut):
                reply = m.mission_ack_encode(*tgt, int(out.result), out.mission_type)
                if out.result is MavMissionResult.ACCEPTED and out.mission_type in (0, 255):
                    self.ap.mission_uploaded()
            elif isinstance(out, MissionCountOut):
                reply = m.mission_count_encode(*tgt, out.count, out.mission_type)
            else:
                it = out.item
                if out.as_int:
                    reply = m.mission_item_int_encode(
                        *tgt, it.seq, it.frame, it.command, it.current, it.autocontinue,
                        it.param1, it.param2, it.param3, it.param4, it.x, it.y, it.z, it.mission_type,
                    )  # fmt: skip
                else:
                    reply = m.mission_item_encode(
                        *tgt, it.seq, it.frame, it.command, it.current, it.autocontinue,
                        it.param1, it.param2, it.param3, it.param4, it.x * 1e-7, it.y * 1e-7, it.z, it.mission_type,
                    )  # fmt: skip
            self.send_to(peer.route, reply)
        self.flush_events()

    def _on_mission_count(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if self._for_us(msg, route):
            self._send_mission(
                self.ap.mission_server.on_count(self._peer(msg, route), msg.count, msg.mission_type, wall_s)
            )

    def _on_mission_item_int(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if not self._for_us(msg, route):
            return
        item = MissionItem(
            msg.seq, msg.frame, msg.command, msg.current, msg.autocontinue,
            msg.param1, msg.param2, msg.param3, msg.param4, msg.x, msg.y, msg.z, msg.mission_type,
        )  # fmt: skip
        self._send_mission(self.ap.mission_server.on_item(self._peer(msg, route), item, wall_s))

    def _on_mission_item(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if not self._for_us(msg, route):
            return
        if not (math.isfinite(msg.x) and math.isfinite(msg.y)):
            self._stats(route).rx_invalid_values += 1
            self._send_mission([MissionAckOut(self._peer(msg, route), MavMissionResult.INVALID_PARAM5_X, 0)])
            return
        item = MissionItem(
            msg.seq, msg.frame, msg.command, msg.current, msg.autocontinue,
            msg.param1, msg.param2, msg.param3, msg.param4,
            round(msg.x * 1e7), round(msg.y * 1e7), msg.z, msg.mission_type,
        )  # fmt: skip
        self._send_mission(self.ap.mission_server.on_item(self._peer(msg, route), item, wall_s))

    def _on_mission_request_list(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if self._for_us(msg, route):
            self._send_mission(self.ap.mission_server.on_request_list(self._peer(msg, route), msg.mission_type))

    def _on_mission_request_int(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if self._for_us(msg, route):
            outs = self.ap.mission_server.on_request(self._peer(msg, route), msg.seq, msg.mission_type, as_int=True)
            self._send_mission(outs)

    def _on_mission_request(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if self._for_us(msg, route):
            outs = self.ap.mission_server.on_request(self._peer(msg, route), msg.seq, msg.mission_type, as_int=False)
            self._send_mission(outs)

    def _on_mission_clear_all(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if self._for_us(msg, route):
            self._send_mission(self.ap.mission_server.on_clear_all(self._peer(msg, route), msg.mission_type))

    def _on_mission_set_current(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if not self._for_us(msg, route):
            return
        if self.ap.set_mission_current(msg.seq) is not MavResult.ACCEPTED:
            self.ap.say(MavSeverity.WARNING, f"Mission item {msg.seq} does not exist")
        self.broadcast(self.encoder.mission_current())
        self.flush_events()

    # ------------------------------------------------------------------ offboard, sticks
    def _on_set_position_target_local_ned(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if not self._for_us(msg, route):
            return
        est = self.v.est
        sp = setpoint_from_local_ned(
            msg.coordinate_frame,
            msg.type_mask,
            (msg.x, msg.y, msg.z),
            (msg.vx, msg.vy, msg.vz),
            (msg.afx, msg.afy, msg.afz),
            msg.yaw,
            msg.yaw_rate,
            vehicle_pos=est.pos_ned_m,
            vehicle_yaw_rad=est.yaw_rad,
        )
        self._offboard(sp, route, wall_s)

    def _on_set_position_target_global_int(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if not self._for_us(msg, route):
            return
        sp = setpoint_from_global_int(
            msg.coordinate_frame,
            msg.type_mask,
            msg.lat_int,
            msg.lon_int,
            msg.alt,
            (msg.vx, msg.vy, msg.vz),
            (msg.afx, msg.afy, msg.afz),
            msg.yaw,
            msg.yaw_rate,
            projection=self.v.projection,
        )
        self._offboard(sp, route, wall_s)

    def _on_set_attitude_target(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if not self._for_us(msg, route):
            return
        q = (msg.q[0], msg.q[1], msg.q[2], msg.q[3])
        rates = (msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate)
        self._offboard(attitude_setpoint(msg.type_mask, q, rates, msg.thrust), route, wall_s)

    def _on_follow_target(self, msg: Any, route: Hashable, wall_s: float) -> None:
        """FOLLOW_TARGET (MAVSDK FollowMe, QGC): the target's position (and velocity, when estimated)."""
        if not msg.est_capabilities & 1 or not (msg.lat or msg.lon):
            return
        if abs(msg.lat) > 900_000_000 or abs(msg.lon) > 1_800_000_000 or not math.isfinite(msg.alt):
            self._stats(route).rx_invalid_values += 1
            return
        n, e, d = self.v.projection.to_ned(GeoPoint(msg.lat * 1e-7, msg.lon * 1e-7, msg.alt))
        vel = tuple(float(v) for v in msg.vel)
        if not all(math.isfinite(v) for v in vel):  # PX4 uses the velocity whenever it is given
            vel = (0.0, 0.0, 0.0)
        self.ap.follow_target_update(FollowTarget(self.v.t_s, (n, e, d), (vel[0], vel[1], vel[2])))

    def _offboard(self, sp: Any, route: Hashable, wall_s: float) -> None:
        if isinstance(sp, OffboardRejection):
            self._stats(route).rx_invalid_values += 1
            return
        self.ap.offboard_setpoint(sp, self.v.t_s, wall_s)

    def _on_manual_control(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if msg.target != self.system_id:
            self._stats(route).rx_other_target += 1
            return
        values = (msg.x, msg.y, msg.z, msg.r)
        if any(abs(v) > 1000 for v in values) or msg.z < 0:
            self._stats(route).rx_invalid_values += 1
            return
        sticks = ManualInput(pitch=msg.x / 1000.0, roll=msg.y / 1000.0, throttle=msg.z / 1000.0, yaw=msg.r / 1000.0)
        self.ap.manual_control(sticks, self.v.t_s, wall_s)

    # ------------------------------------------------------------------ small services
    def _on_timesync(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if msg.tc1 == 0:
            now_ns = sim_time_us(self.v.t_s) * 1000
            self.send_to(route, self.encoder.factory.timesync_encode(now_ns, msg.ts1))

    def _on_ping(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if msg.target_system == 0 and msg.target_component == 0:
            reply = self.encoder.factory.ping_encode(
                msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()
            )
            self.send_to(route, reply)

    def _on_ftp(self, msg: Any, route: Hashable, wall_s: float) -> None:
        if not self._for_us(msg, route) or msg.target_network != 0:
            return
        payload = list(msg.payload)
        seq = payload[0] | (payload[1] << 8)
        opcode = payload[3]
        error = _FTP_ERR_FILE_NOT_FOUND if opcode == _FTP_OPEN_FILE_RO else _FTP_ERR_UNKNOWN_COMMAND
        reply = [0] * 251
        reply[0], reply[1] = (seq + 1) & 0xFF, ((seq + 1) >> 8) & 0xFF
        reply[2] = payload[2]
        reply[3] = _FTP_NAK
        reply[4] = 1
        reply[5] = opcode
        reply[12] = error
        out = self.encoder.factory.file_transfer_protocol_encode(0, msg.get_srcSystem(), msg.get_srcComponent(), reply)
        self.send_to(route, out)

    # ================================================================== outbound
    def after_step(self, wall_s: float) -> None:
        """Send whatever is due after a physics step: streams, then events."""
        t = self.v.t_s
        if t >= self._next_due_s:
            cache: dict[int, Any] = {}
            next_due = math.inf
            builders = self.encoder.builders
            for sched, links in self._stream_links:
                if t >= sched.next_due_s:
                    for msg_id in sched.due(t):
                        m = cache.get(msg_id)
                        if m is None:
                            builder = builders.get(msg_id)
                            m = None if builder is None else builder()
                            cache[msg_id] = m
                        if m is not None:
                            for link in links:
                                link.send(m)
                due = sched.next_due_s
                next_due = due if due < next_due else next_due
            self._next_due_s = next_due
        ap = self.ap
        if ap.heartbeat_due or ap.statustexts or ap.mission_progress.reached or ap.mission_current_changed:
            self.flush_events()
        if ap.mission_server.upload_in_progress:
            for out in ap.mission_server.tick(wall_s):
                self._send_mission([out])

    def flush_events(self) -> None:
        ap = self.ap
        if ap.heartbeat_due:
            ap.heartbeat_due = False
            self.broadcast(self.encoder.heartbeat())
        if ap.statustexts:
            texts, ap.statustexts = ap.statustexts, []
            for severity, text in texts:
                log.info("STATUSTEXT[%s] %s", MavSeverity(severity).name, text)
                for m in self.encoder.statustexts(int(severity), text):
                    self.broadcast(m)
        reached = ap.drain_reached()
        for seq in reached:
            self.broadcast(self.encoder.factory.mission_item_reached_encode(seq))
        if reached or ap.mission_current_changed:
            ap.mission_current_changed = False
            self.broadcast(self.encoder.mission_current())

    def send_heartbeat(self, skip: frozenset[Hashable] = frozenset()) -> None:
        """A heartbeat to every peer of every link but the routes in ``skip`` (lockstep peers: a heartbeat sent
        on wall time while the simulation is paused must not reach them, docs/lockstep.md)."""
        msg = self.encoder.heartbeat()
        if not skip:
            self.broadcast(msg)
        else:
            for link in self.links.values():
                for route in link.routes():
                    if route not in skip:
                        link.send(msg, route)
        self.flush()

    def flush(self) -> None:
        """Put every link's batched frames on the wire (after each step and each burst of input)."""
        for link in self.links.values():
            link.flush()
