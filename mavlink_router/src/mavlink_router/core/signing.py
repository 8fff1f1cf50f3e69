"""MAVLink 2 message signing: verify inbound state-changing messages (pure).

Specification: https://mavlink.io/en/guide/message_signing.html. A signed frame
ends with a 13-byte block ``link_id(1) timestamp(6, LE, 10 µs units since
2015-01-01 UTC) signature(6)``, where ``signature`` is the first 6 bytes of
``SHA-256(secret_key + frame[:-6])`` (the frame from its start marker through
the timestamp).

Replay protection follows the specification: per ``(sysid, compid, link_id)``
stream the timestamp must increase; a new stream is accepted only if its
timestamp is no more than one minute older than the verifier's own timestamp,
which follows both the wall clock and the newest timestamp it has accepted.

Which messages are "state-changing" is a policy given as message *names*
(:data:`STATE_CHANGING_MESSAGES`), resolved to IDs against the dialect by the
caller. Time is passed in.
"""

from __future__ import annotations

import enum
import hashlib
import hmac

from mavlink_router.core.frames import IFLAG_SIGNED, SIGNATURE_LEN, STX_V2
from mavlink_router.errors import ConfigError

__all__ = [
    "SIGNING_EPOCH_UNIX_S",
    "STATE_CHANGING_MESSAGES",
    "SignatureCheck",
    "SignatureVerifier",
    "parse_key_text",
    "signing_timestamp",
]

SIGNING_EPOCH_UNIX_S = 1_420_070_400
"""1 January 2015 00:00:00 UTC, the origin of MAVLink signing timestamps."""

REPLAY_WINDOW_TICKS = 60 * 100_000
"""A new stream may start up to one minute (in 10 µs ticks) behind our clock."""

MAVLINK2_MIN_SIGNED = 12 + SIGNATURE_LEN

STATE_CHANGING_MESSAGES: tuple[str, ...] = (
    # commands (arm, takeoff, mode changes via DO_SET_MODE, reposition, ...)
    "COMMAND_LONG",
    "COMMAND_INT",
    # legacy mode change
    "SET_MODE",
    # mission upload / edit / clear / select
    "MISSION_COUNT",
    "MISSION_ITEM",
    "MISSION_ITEM_INT",
    "MISSION_WRITE_PARTIAL_LIST",
    "MISSION_CLEAR_ALL",
    "MISSION_SET_CURRENT",
    # parameters
    "PARAM_SET",
    "PARAM_EXT_SET",
    "PARAM_MAP_RC",
    # setpoints and direct control
    "SET_POSITION_TARGET_LOCAL_NED",
    "SET_POSITION_TARGET_GLOBAL_INT",
    "SET_ATTITUDE_TARGET",
    "SET_ACTUATOR_CONTROL_TARGET",
    "MANUAL_CONTROL",
    "RC_CHANNELS_OVERRIDE",
    "MANUAL_SETPOINT",
    # home, origin, fence, rally, signing setup itself
    "SET_HOME_POSITION",
    "SET_GPS_GLOBAL_ORIGIN",
    "FENCE_POINT",
    "RALLY_POINT",
    "SETUP_SIGNING",
)


def signing_timestamp(now_unix_s: float) -> int:
    """The MAVLink signing timestamp (10 µs ticks since 2015-01-01) of a UNIX time."""
    return int((now_unix_s - SIGNING_EPOCH_UNIX_S) * 100_000)


def _digest(key: bytes, signed_part: bytes) -> bytes:
    return hashlib.sha256(key + signed_part).digest()[:6]


def raise_if_bad_key(key: bytes) -> None:
    """Raise :class:`ConfigError` unless ``key`` is a 32-byte MAVLink signing key."""
    if len(key) != 32:
        msg = f"a MAVLink signing key is 32 bytes, got {len(key)}"
        raise ConfigError(msg)


def parse_key_text(text: str, *, source: str) -> bytes:
    """The 32-byte secret key from a key file's text.

    Accepted forms: 64 hexadecimal digits (the key itself), or any other
    non-empty single line, taken as a passphrase and hashed with SHA-256 (what
    MAVProxy's ``signing setup <passphrase>`` and QGroundControl do).

    Raises:
        ConfigError: the file is empty or has more than one non-empty line.
    """
    lines = [line.strip() for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    if len(lines) != 1:
        msg = (
            f"{source}: a signing key file holds exactly one line (64 hex digits, or a passphrase); "
            f"found {len(lines)} non-comment lines"
        )
        raise ConfigError(msg)
    line = lines[0]
    if len(line) == 64:
        try:
            return bytes.fromhex(line)
        except ValueError:
            pass
    return hashlib.sha256(line.encode("utf-8")).digest()


class SignatureCheck(enum.Enum):
    """Outcome of :meth:`SignatureVerifier.check`."""

    OK = "ok"
    UNSIGNED = "unsigned"
    BAD_SIGNATURE = "bad_signature"
    REPLAY = "replay"


class SignatureVerifier:
    """Checks signatures of frames from one endpoint against one secret key."""

    __slots__ = ("_key", "_local_ts", "_streams")

    def __init__(self, key: bytes) -> None:
        raise_if_bad_key(key)
        self._key = key
        self._streams: dict[tuple[int, int, int], int] = {}
        self._local_ts = 0

    def check(self, raw: bytes, now_unix_s: float) -> SignatureCheck:
        """Verify one complete frame; on success the stream's timestamp advances."""
        if raw[0] != STX_V2 or not raw[2] & IFLAG_SIGNED or len(raw) < MAVLINK2_MIN_SIGNED:
            return SignatureCheck.UNSIGNED
        tail = raw[-SIGNATURE_LEN:]
        link_id = tail[0]
        timestamp = int.from_bytes(tail[1:7], "little")
        if not hmac.compare_digest(_digest(self._key, raw[:-6]), tail[7:]):
            return SignatureCheck.BAD_SIGNATURE
        self._local_ts = max(self._local_ts, signing_timestamp(now_unix_s))
        stream = (raw[5], raw[6], link_id)
        last = self._streams.get(stream)
        if last is None:
            if timestamp + REPLAY_WINDOW_TICKS < self._local_ts:
                return SignatureCheck.REPLAY
        elif timestamp <= last:
            return SignatureCheck.REPLAY
        self._streams[stream] = timestamp
        self._local_ts = max(self._local_ts, timestamp)
        return SignatureCheck.OK
