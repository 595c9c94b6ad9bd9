"""A second Ctrl-C as a render's partial video is removed left ``.NAME.partial.mp4`` behind (the removal
cut short); it is removed with stops held back now, as the other partial files are (test_stops_s25)."""

from __future__ import annotations

import signal
from pathlib import Path

import numpy as np
import pytest
from test_stops_s25 import _python_ctrl_c, _stop_in  # noqa: F401  (the fixture is used by name)

from viewer.render import write_mp4


def test_a_second_ctrl_c_as_a_partial_video_goes_leaves_no_partial_file(tmp_path, monkeypatch):
    def frames(k: int) -> np.ndarray:
        if k == 3:
            _stop_in(monkeypatch, Path, "unlink")
            signal.raise_signal(signal.SIGINT)
        return np.zeros((16, 16, 3), np.uint8)

    with pytest.raises(KeyboardInterrupt):
        write_mp4(tmp_path / "take.mp4", frames, 10, 30.0, None)
    assert sorted(p.name for p in tmp_path.iterdir()) == []
