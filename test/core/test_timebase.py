"""The one time base: ns <-> seconds, ns <-> stamps, a serialized message's stamp."""

from __future__ import annotations

import struct

import pytest

from tiltrov_ros.core.timebase import (
    NS_PER_S,
    cdr_stamp_ns,
    format_ns,
    ns_to_stamp,
    seconds,
    stamp_to_ns,
    to_ns,
)


@pytest.mark.parametrize('ns', [0, 1, 999_999_999, NS_PER_S, 12_345_678_901, 2**40 + 7])
def test_stamp_round_trip(ns: int) -> None:
    sec, nanosec = ns_to_stamp(ns)
    assert 0 <= nanosec < NS_PER_S
    assert stamp_to_ns(sec, nanosec) == ns


def test_seconds_and_to_ns() -> None:
    assert seconds(1_500_000_000) == 1.5
    assert to_ns(0.05) == 50_000_000 and to_ns(1e-9 * 0.6) == 1
    assert format_ns(12_345_678_901) == '12.346 s'


@pytest.mark.parametrize('order', ['<', '>'])
def test_cdr_stamp_in_either_byte_order(order: str) -> None:
    encapsulation = bytes([0, 1 if order == '<' else 0, 0, 0])
    data = encapsulation + struct.pack(f'{order}iI', 12, 345_678_901) + b'rest'
    assert cdr_stamp_ns(data) == 12_345_678_901
    assert cdr_stamp_ns(memoryview(data)) == 12_345_678_901


def test_cdr_stamp_of_bytes_too_short() -> None:
    with pytest.raises(ValueError, match='no stamp'):
        cdr_stamp_ns(b'\x00\x01\x00\x00\x0c\x00')
