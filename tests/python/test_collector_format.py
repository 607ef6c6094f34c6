"""The record format's Python side: exact depth conversion, layout offsets, header round trip."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from quad_il.data import decode_depth_codes, encode_depth_m
from quad_il.data.format import (
    HEADER_SIZE,
    CorruptDataError,
    FormatVersionError,
    NotADatasetError,
    ShardHeader,
    layout_json,
    parse_shard_header,
    record_dtype,
    serialize_shard_header,
)


def test_depth_special_values_follow_rep118() -> None:
    d = np.array([np.nan, -np.inf, np.inf, 0.0, -0.0, -2.5], dtype=np.float32)
    np.testing.assert_array_equal(encode_depth_m(d), [0, 1, 65535, 0, 0, 0])
    m = decode_depth_codes(np.array([0, 1, 65535, 2, 1000], dtype=np.uint16))
    assert np.isnan(m[0]) and m[1] == -np.inf and m[2] == np.inf and m[3] == np.float32(0.002) and m[4] == 1.0


def test_depth_rounds_the_exact_float_value_half_up() -> None:
    # The same hand-checked values as the C++ test (test_record_format.cpp).
    values = np.array(
        [1.0, 3.25, 0.0004, 0.0015, 2.0005, 65.534, 65.5345, 1000.0, 0.0025, 1.2345], np.float32
    )
    np.testing.assert_array_equal(
        encode_depth_m(values), [1000, 3250, 2, 2, 2000, 65534, 65535, 65535, 2, 1235]
    )


def test_every_valid_code_round_trips_through_metres() -> None:
    codes = np.arange(2, 65535, dtype=np.uint16)
    np.testing.assert_array_equal(encode_depth_m(decode_depth_codes(codes)), codes)


@settings(max_examples=300, deadline=None)
@given(st.floats(min_value=0.0020000000949949026, max_value=65.5, width=32))
def test_decoded_depth_is_within_half_a_millimetre(d: float) -> None:
    back = decode_depth_codes(encode_depth_m(np.array([d], np.float32)))[0]
    assert abs(float(back) - d) <= 0.0005 + 1e-6


def test_float16_depth_is_the_nearest_half_of_the_millimetre_value() -> None:
    codes = np.array([2, 999, 10000, 20001, 65534], dtype=np.uint16)
    np.testing.assert_array_equal(decode_depth_codes(codes, "float16"), (codes / 1000.0).astype(np.float16))


def test_record_layout_has_the_documented_offsets() -> None:
    dt = record_dtype(320, 240, 136, 128, 128)
    assert dt.itemsize == 159104
    assert (
        dt.fields["seq"][1] == 8
        and dt.fields["p_world_body"][1] == 56
        and dt.fields["q_world_body"][1] == 104
    )
    assert dt.fields["plan_status_text"][1] == 264 and dt.fields["knots"][1] == 312
    assert dt.fields["ctrl_pts_world"][1] == 1400 and dt.fields["yaw_pts"][1] == 4472
    assert dt.fields["depth_code"][1] == 5496 and dt.fields["crc32"][1] == 159100
    assert dt.fields["depth_code"][0].shape == (240, 320)
    assert '["depth_code","<u2",[240,320],5496]' in layout_json(320, 240, 136, 128, 128)


def make_header(**changes: object) -> ShardHeader:
    h = ShardHeader(
        format_version=1,
        header_size=HEADER_SIZE,
        record_size=record_dtype(8, 6, 12, 4, 0).itemsize,
        image_width=8,
        image_height=6,
        depth_encoding=1,
        max_knots=12,
        max_ctrl_pts=4,
        max_yaw_pts=0,
        shard_index=3,
        camera_fx_px=4.84,
        camera_fy_px=4.84,
        camera_cx_px=4.0,
        camera_cy_px=3.0,
        layout_json=layout_json(8, 6, 12, 4, 0),
    )
    return dataclasses.replace(h, **changes)


def test_header_round_trips_and_rejects_foreign_other_version_and_corrupt_bytes() -> None:
    h = make_header()
    assert parse_shard_header(serialize_shard_header(h), "s") == h
    with pytest.raises(NotADatasetError, match="s: not a quad_il record shard"):
        parse_shard_header(b"GIF89a" + bytes(5000), "s")
    with pytest.raises(FormatVersionError, match="version 3 is not supported"):
        parse_shard_header(serialize_shard_header(make_header(format_version=3)), "s")
    flipped = bytearray(serialize_shard_header(h))
    flipped[50] ^= 1
    with pytest.raises(CorruptDataError, match="header CRC mismatch"):
        parse_shard_header(bytes(flipped), "s")
    with pytest.raises(CorruptDataError, match="differs from format version 1's layout"):
        parse_shard_header(serialize_shard_header(make_header(max_knots=13)), "s")
    with pytest.raises(CorruptDataError, match="truncated header"):
        parse_shard_header(serialize_shard_header(h)[:1000], "s")
