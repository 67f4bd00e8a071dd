"""Property tests (hypothesis) of the host's frame decoder (uwbcal.link.framing.FrameDecoder)
and of the recorder's record decoding: what any byte stream from a station, however damaged
or however split into reads, may and may not do. What these cannot see: the firmware's own
decoder (the libFuzzer harness, tests/fuzz/, covers that one)."""

from __future__ import annotations

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from uwbcal.errors import ProtocolError
from uwbcal.link import proto_gen as pg
from uwbcal.link.framing import Frame, FrameDecoder, FrameError, encode_frame

frames = st.builds(
    Frame,
    type=st.integers(0, 255),
    seq=st.integers(0, 0xFFFF),
    flags=st.integers(0, 255),
    payload=st.binary(max_size=pg.MAX_PAYLOAD),
    version=st.integers(0, 255),
)

SETTINGS = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _feed_split(data: bytes, cuts: list[int]) -> list[Frame | FrameError]:
    d = FrameDecoder()
    out: list[Frame | FrameError] = []
    pos = 0
    for c in sorted({min(c, len(data)) for c in cuts}) + [len(data)]:
        out += d.feed(data[pos:c])
        pos = c
    return out


@SETTINGS
@given(st.lists(frames, max_size=6), st.lists(st.integers(0, 4000), max_size=10))
def test_frames_survive_any_split_into_reads(fs: list[Frame], cuts: list[int]) -> None:
    wire = b"".join(encode_frame(f) for f in fs)
    assert _feed_split(wire, cuts) == fs


@SETTINGS
@given(st.binary(max_size=3000), st.lists(st.integers(0, 3000), max_size=10))
def test_any_bytes_give_only_frames_or_errors(data: bytes, cuts: list[int]) -> None:
    out = _feed_split(data, cuts)
    assert all(isinstance(x, Frame | FrameError) for x in out)
    # one result per non-empty delimited chunk, never more
    assert len(out) == sum(1 for chunk in data.split(b"\x00")[:-1] if chunk)
    for x in out:
        if isinstance(x, Frame):
            assert len(x.payload) <= pg.MAX_PAYLOAD


@SETTINGS
@given(st.binary(max_size=600), frames)
def test_a_frame_after_garbage_and_a_flush_is_recovered(garbage: bytes, f: Frame) -> None:
    out = FrameDecoder().feed(garbage + b"\x00" + encode_frame(f))
    assert out[-1] == f


@SETTINGS
@given(frames, st.integers(0, 10_000), st.integers(1, 255))
def test_one_corrupted_byte_is_never_a_different_valid_frame(f: Frame, at: int, xor: int) -> None:
    wire = bytearray(encode_frame(f)[:-1])
    wire[at % len(wire)] ^= xor
    out = FrameDecoder().feed(bytes(wire) + b"\x00")
    # the change may split the frame at a new 0x00; whatever decodes must not be a new frame
    assert all(isinstance(x, FrameError) or x == f for x in out)


@SETTINGS
@given(st.binary(max_size=2 * pg.TripletRecord.WIRE_SIZE + 5))
def test_record_tails_decode_or_refuse_cleanly(tail: bytes) -> None:
    try:
        recs = pg.records_array(pg.TripletRecord, tail)
    except ProtocolError:
        assert len(tail) % pg.TripletRecord.WIRE_SIZE != 0
        return
    assert len(recs) * pg.TripletRecord.WIRE_SIZE == len(tail)
