"""What the viewer says before it does anything: a take align cut into segments is named by its
segments, and a stream whose speech cannot play stops before it is announced or a packet is sent."""

from __future__ import annotations

import shutil
import socket
from pathlib import Path

from conftest import run_cli


def test_a_take_align_cut_into_segments_is_named_by_its_segments(sim_take: Path, tmp_path: Path):
    aligned = tmp_path / "aligned"
    aligned.mkdir()
    for n in (1, 2):
        shutil.copytree(sim_take, aligned / f"{sim_take.name}.seg{n:02d}")
    proc = run_cli("viewer", "plot", aligned / sim_take.name, "-o", tmp_path / "x.png")
    assert proc.returncode == 1, proc.stderr
    assert f"{sim_take.name}.seg01, {sim_take.name}.seg02" in proc.stderr, proc.stderr
    assert "2 segment(s)" in proc.stderr
    other = run_cli("viewer", "plot", aligned / "nothing_here", "-o", tmp_path / "y.png")
    assert other.returncode == 1 and "no such take folder or CSV file" in other.stderr, other.stderr


def test_a_stream_whose_speech_cannot_play_is_not_announced_and_sends_nothing(sim_take: Path):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", 0))
        rx.settimeout(0.5)
        to = f"127.0.0.1:{rx.getsockname()[1]}"
        proc = run_cli("viewer", "stream", sim_take, "--to", to, "--audio", "--speed", "2")
        assert proc.returncode == 1, proc.stderr
        assert "use it with --speed 1" in proc.stderr, proc.stderr
        assert "streaming" not in proc.stderr, proc.stderr
        try:
            data = rx.recv(65536)
        except TimeoutError:
            data = None
        assert data is None
