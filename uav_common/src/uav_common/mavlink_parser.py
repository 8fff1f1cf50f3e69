"""Reset a pymavlink parser to its start-up state, in one place.

A datagram (UDP) or a resynchronised stream must never carry a fragment of an earlier
message into the next parse. pymavlink's ``MAVLink`` object keeps four pieces of parser
state (``buf``, ``buf_index``, ``expected_length``, ``have_prefix_error``, all set in its
``__init__``); forgetting one of them (``have_prefix_error`` was forgotten once) makes the
parser skip or reject the next good message.
"""

from __future__ import annotations

from typing import Any

__all__ = ["reset_parser"]

#: ``HEADER_LEN_V1 + 2``: what pymavlink's ``MAVLink.__init__`` expects first (header and checksum of a v1 frame).
_INITIAL_EXPECTED_LENGTH = 6 + 2


def reset_parser(parser: Any) -> None:
    """Drop any partial message held by ``parser`` (a pymavlink ``MAVLink`` instance)."""
    parser.buf = bytearray()
    parser.buf_index = 0
    parser.expected_length = _INITIAL_EXPECTED_LENGTH
    parser.have_prefix_error = False
