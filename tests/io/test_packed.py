"""Arrays packed for the browser: float32 and uint32, one after another, laid out by name."""

import numpy as np
import pytest

from tryon.io.packed import packed_layout, write_packed


def test_arrays_are_packed_in_order_with_their_offsets_and_types(tmp_path):
    arrays = [("positions", np.arange(6, dtype=np.float64).reshape(2, 3)), ("faces", np.array([[0, 1, 2]], np.uint32))]
    layout = packed_layout(arrays)
    assert layout == {"positions": {"offset": 0, "count": 6, "type": "float32"},
                      "faces": {"offset": 24, "count": 3, "type": "uint32"}}
    write_packed(tmp_path / "s.bin", arrays)
    raw = (tmp_path / "s.bin").read_bytes()
    assert len(raw) == 36
    assert np.array_equal(np.frombuffer(raw[:24], "<f4"), np.arange(6, dtype=np.float32))
    assert np.array_equal(np.frombuffer(raw[24:], "<u4"), [0, 1, 2])


def test_signed_integers_are_refused_not_written_as_floats():
    with pytest.raises(ValueError, match="faces"):
        packed_layout([("faces", np.array([0, 1, 2], np.int64))])
