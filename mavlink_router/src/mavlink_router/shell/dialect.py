"""Build the router's message table from a pymavlink dialect (the only pymavlink use).

mavlink-router compiles the C library's ``mavlink_msg_entry_t`` table in; we
derive the same facts (``crc_extra`` and the payload offsets of
``target_system`` / ``target_component``) from pymavlink's generated classes.
"""

from __future__ import annotations

import importlib
import re
import struct
from collections.abc import Iterable, Mapping
from types import ModuleType

from mavlink_router.core.config import DIALECTS
from mavlink_router.core.frames import NO_TARGET, MessageSpec
from mavlink_router.errors import DialectError

__all__ = ["DIALECTS", "load_message_table", "message_ids"]


_TOKEN = re.compile(r"(\d*)([a-zA-Z?])")


def _field_offsets(fmt: str, names: list[str]) -> dict[str, int]:
    """Byte offset of every field of a little-endian struct format like ``<QfH16sB``."""
    body = fmt.lstrip("<>=!@")
    tokens = _TOKEN.findall(body)
    if len(tokens) != len(names):
        msg = f"format {fmt!r} has {len(tokens)} fields, the message has {len(names)}"
        raise DialectError(msg)
    offsets: dict[str, int] = {}
    offset = 0
    for (count, code), name in zip(tokens, names, strict=True):
        offsets[name] = offset
        offset += struct.calcsize(f"<{count}{code}")
    return offsets


def _module(dialect: str) -> ModuleType:
    key = dialect.lower()
    if key not in DIALECTS:
        msg = f"unknown MAVLink dialect {dialect!r}; use one of {', '.join(sorted(DIALECTS))}"
        raise DialectError(msg)
    try:
        return importlib.import_module(f"pymavlink.dialects.v20.{DIALECTS[key]}")
    except ImportError as err:
        msg = f"pymavlink has no dialect {DIALECTS[key]!r} ({err}); install pymavlink"
        raise DialectError(msg) from err


def load_message_table(dialect: str = "auto") -> dict[int, MessageSpec]:
    """``{msgid: MessageSpec}`` for every message of ``dialect``.

    Raises:
        DialectError: unknown dialect, or a message class that does not look like
            pymavlink's generated code.
    """
    module = _module(dialect)
    table: dict[int, MessageSpec] = {}
    for msgid, cls in module.mavlink_map.items():
        names = list(cls.ordered_fieldnames)
        offsets = _field_offsets(cls.unpacker.format, names)
        table[int(msgid)] = MessageSpec(
            name=str(cls.msgname),
            crc_extra=int(cls.crc_extra),
            target_system_ofs=offsets.get("target_system", NO_TARGET),
            target_component_ofs=offsets.get("target_component", NO_TARGET),
        )
    return table


def message_ids(table: Mapping[int, MessageSpec], names: Iterable[str]) -> frozenset[int]:
    """IDs of the named messages that exist in ``table`` (unknown names are skipped)."""
    by_name = {spec.name: msgid for msgid, spec in table.items()}
    return frozenset(by_name[name] for name in names if name in by_name)
