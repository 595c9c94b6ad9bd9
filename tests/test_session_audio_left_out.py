"""A live session whose audio log holds samples a take cannot hold (NaN in a float device's stream): the
face take is still written, without the audio and with a repair saying why (the whole stream was lost)."""

from __future__ import annotations

import numpy as np
from live_helpers import Listener, synthetic_take

from capture import read_take
from capture.audio_capture import AudioLog
from capture.replay import replay_take
from capture.session_takes import AUDIO_LOG, SessionLog, build_takes


def test_audio_a_take_cannot_hold_leaves_the_face_take_without_it(tmp_path):
    listener = Listener(tmp_path / "out")
    replay_take(synthetic_take(120, seed=2), "127.0.0.1", listener.port)
    _lines, err, code = listener.stop()
    assert code == 0, err
    session = listener.session_dir
    log = SessionLog(session)
    first_ns = int(log.stream_rows(next(iter(log.streams)))["arrival_ns"][0])
    log.close()
    audio = AudioLog(session / AUDIO_LOG, fsync=False)
    audio.start(16000, 1, "FLOAT", "test")
    chunk = np.full((16000, 1), 0.1, np.float32)
    chunk[100:110] = np.nan
    audio.add_chunk(0, first_ns, chunk)
    audio.close()
    (summary,) = build_takes(session, tmp_path / "rebuilt")
    assert summary.get("error") is None and summary["frames"] == 120, summary
    take = read_take(summary["path"])
    assert take.audio is None
    (note,) = [r for r in take.meta.repairs if r["kind"] == "audio_left_out"]
    assert "10 NaN or infinite sample(s)" in note["message"]
