"""Signing: key files and signature checks against frames signed by pymavlink (independent code)."""

from __future__ import annotations

import hashlib

import pytest
from mr_build import KEY, TABLE, command_long, pack

from mavlink_router.core.signing import (
    SIGNING_EPOCH_UNIX_S,
    STATE_CHANGING_MESSAGES,
    SignatureCheck,
    SignatureVerifier,
    parse_key_text,
    signing_timestamp,
)
from mavlink_router.errors import ConfigError
from mavlink_router.shell.dialect import message_ids

NOW = 1_800_000_000.0
TS = signing_timestamp(NOW)


def test_key_file_forms() -> None:
    assert parse_key_text(KEY.hex() + "\n", source="k") == KEY
    assert (
        parse_key_text("# comment\n  correct horse battery staple \n", source="k")
        == hashlib.sha256(b"correct horse battery staple").digest()
    )


@pytest.mark.parametrize("text", ["", "\n# only a comment\n", "one\ntwo\n"])
def test_bad_key_files(text: str) -> None:
    with pytest.raises(ConfigError, match=r"k: a signing key file holds exactly one line"):
        parse_key_text(text, source="k")


def test_short_key_rejected() -> None:
    with pytest.raises(ConfigError, match="32 bytes"):
        SignatureVerifier(b"short")


def test_timestamp_epoch() -> None:
    assert signing_timestamp(SIGNING_EPOCH_UNIX_S + 1.5) == 150_000


def test_verifier_accepts_pymavlink_signatures_and_rejects_tampering() -> None:
    verifier = SignatureVerifier(KEY)
    raw = pack(command_long(1, 1), 255, 190, key=KEY, timestamp=TS)
    assert verifier.check(raw, NOW) is SignatureCheck.OK
    tampered = bytearray(pack(command_long(1, 1), 255, 190, key=KEY, timestamp=TS + 5))
    tampered[14] ^= 0x01  # a payload byte (the CRC no longer matters to the signature check)
    assert verifier.check(bytes(tampered), NOW) is SignatureCheck.BAD_SIGNATURE
    assert verifier.check(pack(command_long(1, 1), 255, 190), NOW) is SignatureCheck.UNSIGNED


def test_replay_rules() -> None:
    verifier = SignatureVerifier(KEY)
    first = pack(command_long(1, 1), 255, 190, key=KEY, timestamp=TS)
    assert verifier.check(first, NOW) is SignatureCheck.OK
    assert verifier.check(first, NOW) is SignatureCheck.REPLAY  # same timestamp on the same stream
    newer = pack(command_long(1, 1), 255, 190, key=KEY, timestamp=TS + 1)
    assert verifier.check(newer, NOW) is SignatureCheck.OK
    stale_new_stream = pack(command_long(1, 1), 255, 1, key=KEY, timestamp=TS - 61 * 100_000)
    assert verifier.check(stale_new_stream, NOW) is SignatureCheck.REPLAY
    recent_new_stream = pack(command_long(1, 1), 255, 2, key=KEY, timestamp=TS - 30 * 100_000)
    assert verifier.check(recent_new_stream, NOW) is SignatureCheck.OK


def test_protected_messages_resolve_against_the_dialect() -> None:
    ids = message_ids(TABLE, STATE_CHANGING_MESSAGES)
    names = {TABLE[i].name for i in ids}
    assert {"COMMAND_LONG", "COMMAND_INT", "SET_MODE", "PARAM_SET", "MISSION_ITEM_INT"} <= names
    assert {"SET_POSITION_TARGET_LOCAL_NED", "SETUP_SIGNING"} <= names
    assert "HEARTBEAT" not in names
