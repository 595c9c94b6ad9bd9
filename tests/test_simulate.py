"""The simulated speaker (capture.simulate, ``s2a-capture simulate``): files, import, ground truth."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import run_here
from live_helpers import run_cli

from capture import ARKIT61, PRONUNCIATION32, FrameStatus, read_audio, read_take, read_take_folder
from capture.errors import InputError
from capture.simulate import Artifacts, TakeSpec, inventory, simulate_take, viseme_matrix, write_take_folder
from capture.textgrid import read_textgrid

BILABIALS = {"p", "b", "m"}


def folder_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> tuple[Path, list[dict]]:
    """Three 6 s takes of two speakers with a .mov, written by the CLI."""
    out = tmp_path_factory.mktemp("sim") / "takes"
    r = run_cli(
        "simulate",
        "-o",
        str(out),
        "--speakers",
        "2",
        "--takes",
        "3",
        "--seconds",
        "6",
        "--seed",
        "11",
        "--mov",
        "--json",
    )
    assert r.returncode == 0, r.stderr
    return out, [json.loads(line) for line in r.stdout.splitlines()]


def test_cli_writes_live_link_face_take_folders(session):
    out, summaries = session
    assert [s["speaker"] for s in summaries] == ["spk01", "spk02", "spk01"]
    assert [s["take"] for s in summaries] == [1, 1, 2]
    for s in summaries:
        folder = Path(s["path"])
        prefix = folder.name.split("_", 1)[1].rsplit("_", 1)
        stem = f"{prefix[0]}_{prefix[1]}_{s['speaker']}"
        names = {p.name for p in folder.iterdir()}
        assert names == {
            f"{stem}.csv",
            f"{stem}.wav",
            f"{stem}.mov",
            f"{stem}.TextGrid",
            "frame_log.csv",
            "take.json",
            "video_metadata.json",
            "audio_metadata.json",
            "simulation.json",
        }
        header = (folder / f"{stem}.csv").read_text().splitlines()[0]
        assert header.startswith("Timecode,BlendshapeCount,EyeBlinkLeft,") and header.count(",") == 62
        app_take = json.loads((folder / "take.json").read_text())
        assert app_take["identifier"] == folder.name and app_take["take"] == s["take"]
        assert 5.0 < s["duration_s"] < 7.5


def test_same_seed_gives_byte_identical_output(tmp_path, session):
    out, _ = session
    again = tmp_path / "again"
    r = run_cli(
        "simulate",
        "-o",
        str(again),
        "--speakers",
        "2",
        "--takes",
        "3",
        "--seconds",
        "6",
        "--seed",
        "11",
        "--mov",
    )
    assert r.returncode == 0, r.stderr
    assert folder_bytes(again) == folder_bytes(out)
    other = tmp_path / "other"
    r = run_cli("simulate", "-o", str(other), "--takes", "1", "--seconds", "6", "--seed", "12")
    assert r.returncode == 0, r.stderr
    first = next(other.rglob("*.wav")).read_bytes()
    assert first != next(out.rglob("*.wav")).read_bytes()


def test_written_takes_import_unchanged(tmp_path, session):
    out, summaries = session
    imported = tmp_path / "imported"
    r = run_cli("import", str(out), "-o", str(imported), "--json")
    assert r.returncode == 0, r.stderr
    lines = [json.loads(line) for line in r.stdout.splitlines()]
    assert sorted(x["id"] for x in lines) == sorted(s["id"] for s in summaries)
    for s in summaries:
        take = read_take(imported / s["id"])
        truth = take.meta.extra["simulation"]
        assert truth == json.loads((Path(s["path"]) / "simulation.json").read_text())
        sim = simulate_take(TakeSpec(11, int(truth["speaker_index"]), s["take"], 6.0, mov=True))
        # Every frame slot is back, with the declared drops and face-lost frames in place.
        assert take.time.size == truth["frames"] == sim.take.time.size
        np.testing.assert_array_equal(take.frame_status, sim.take.frame_status)
        assert (
            np.flatnonzero(take.frame_status == FrameStatus.DROPPED).tolist()
            == truth["dropped_frame_indices"]
        )
        assert take.count(FrameStatus.FACE_LOST) == truth["face_lost_frames"]
        assert take.meta.extra["frame_log"]["dropped_video_frames"] == truth["dropped_frames"]
        np.testing.assert_allclose(take.time, sim.take.time, atol=2e-5)
        ok = take.valid
        cols = [take.meta.channels.index(c) for c in ARKIT61]
        np.testing.assert_allclose(take.values[ok][:, cols], sim.take.values[ok], atol=1e-6)
        # Audio: the WAV and the .mov hold the same samples; its start is the declared one.
        np.testing.assert_array_equal(take.audio.samples, sim.audio.samples)
        wav = read_audio(Path(s["path"]) / truth["audio_file"])
        np.testing.assert_array_equal(wav.samples, sim.audio.samples)
        assert take.meta.audio.start_source == "frame_log_audio"
        assert take.meta.audio.start_s == pytest.approx(truth["audio_start_s"], abs=2e-5)
        assert take.meta.start_timecode == truth["start_timecode"]


def _estimate_capture_offset(take, sim) -> float:
    """Lag (s) that best matches the imported jawOpen to the simulator's clean articulation."""
    jaw = take.channel("jawOpen")
    ok = np.isfinite(jaw)
    tau = take.time[ok] - take.meta.audio.start_s
    j = PRONUNCIATION32.index("jawOpen")
    lags = np.arange(-0.2, 0.2, 0.0005)
    err = [np.mean((sim.articulation.face_at(tau - lag)[:, j] - jaw[ok]) ** 2) for lag in lags]
    return float(lags[int(np.argmin(err))])


def _estimate_apparent_offset(take) -> float:
    """Lag (s) at which jawOpen best follows the log energy of the audio: what an aligner sees."""
    jaw = take.channel("jawOpen")
    ok = np.isfinite(jaw)
    audio = take.audio.mono_float()
    hop = take.audio.sample_rate // 100
    env = np.log(np.sqrt(np.convolve(audio**2, np.ones(3 * hop) / (3 * hop), "same")[::hop]) + 1e-4)
    te = np.arange(env.size) / 100.0
    tau = take.time[ok] - take.meta.audio.start_s
    lags = np.arange(-0.2, 0.2, 0.005)
    corr = [np.corrcoef(np.interp(te, tau - lag, jaw[ok]), env)[0, 1] for lag in lags]
    return float(lags[int(np.argmax(corr))])


@pytest.mark.parametrize("mov", [False, True])
def test_declared_offset_and_drops_are_recovered_from_the_files(tmp_path, mov):
    sim = simulate_take(TakeSpec(5, 1, 1, 12.0, mov=mov))
    truth = sim.truth
    assert truth["capture_offset_s"] != 0.0 and truth["dropped_frames"] > 0
    take = read_take_folder(write_take_folder(sim, tmp_path))
    assert take.meta.audio.start_s == pytest.approx(truth["audio_start_s"], abs=2e-5)
    assert take.meta.audio.start_source == ("frame_log_audio" if mov else "assumed_first_csv_row")
    assert np.flatnonzero(take.frame_status == FrameStatus.DROPPED).tolist() == truth["dropped_frame_indices"]
    assert _estimate_capture_offset(take, sim) == pytest.approx(truth["capture_offset_s"], abs=0.002)
    assert truth["apparent_offset_s"] == pytest.approx(truth["capture_offset_s"] - truth["face_lead_s"])
    assert _estimate_apparent_offset(take) == pytest.approx(truth["apparent_offset_s"], abs=0.025)


def test_face_leads_the_audio_when_no_offset_is_injected():
    leads = []
    for speaker in (0, 1, 2):
        sim = simulate_take(TakeSpec(21, speaker, 1, 12.0, artifacts=Artifacts.without(["offset"])))
        assert sim.truth["capture_offset_s"] == 0.0
        assert 0.01 <= sim.truth["face_lead_s"] <= 0.04
        take = sim.take
        take.attach_audio(sim.audio, 0.0)
        leads.append(-_estimate_apparent_offset(take))
    # The face moves before the sound: the best jaw/energy lag is negative (a lead), tens of ms.
    assert np.mean(leads) > 0.0


def test_mouth_close_peaks_inside_bilabial_phones(tmp_path):
    from scipy.signal import find_peaks

    sim = simulate_take(TakeSpec(2, 0, 1, 15.0, artifacts=Artifacts.without(["all"])))
    folder = write_take_folder(sim, tmp_path)
    take = read_take_folder(folder)
    tg = read_textgrid(folder / sim.truth["textgrid"])
    lead = sim.truth["face_lead_s"]
    frame = 1.0 / take.meta.fps
    bilabials = [iv for iv in tg.tier("phones").intervals if iv.text in BILABIALS]
    assert len(bilabials) >= 5
    close = take.channel("mouthClose")
    peaks, _ = find_peaks(close, prominence=0.05)
    tau = take.time[peaks] - take.meta.audio.start_s
    # A peak belongs to a bilabial if it falls inside one (shifted by the face's lead, +-1 frame).
    inside = [any(iv.xmin - lead - frame <= t <= iv.xmax + frame for iv in bilabials) for t in tau]
    assert len(peaks) >= 0.8 * len(bilabials)
    assert np.mean(inside) >= 0.9
    # And the lips close far more during bilabials than elsewhere.
    t_all = take.time - take.meta.audio.start_s + lead
    in_bilabial = np.zeros(t_all.size, bool)
    for iv in bilabials:
        in_bilabial |= (t_all >= iv.xmin) & (t_all < iv.xmax)
    assert np.mean(close[in_bilabial]) > 4 * np.mean(close[~in_bilabial])


def test_jaw_open_grows_with_energy_within_a_vowel_class():
    rows = []
    for speaker in (0, 1):
        sim = simulate_take(
            TakeSpec(4, speaker, 1, 25.0, artifacts=Artifacts.without(["drops", "face-lost"]))
        )
        utt, audio = sim.utterance, sim.audio.mono_float()
        ratio = sim.audio.sample_rate / utt.sample_rate
        jaw = sim.take.channel("jawOpen")
        tau = sim.take.time - sim.truth["audio_start_s"] - sim.truth["capture_offset_s"]
        for i in range(utt.phone.size):
            ph = utt.inventory.phones[utt.phone[i]]
            if not ph.is_vowel or utt.part[i] == 1:
                continue
            a, b = int(utt.start[i] * ratio), int(utt.end[i] * ratio)
            energy_db = 10 * np.log10(np.mean(audio[a:b] ** 2) + 1e-12)
            k = int(np.argmin(np.abs(tau + sim.truth["face_lead_s"] - (a + b) / 2 / sim.audio.sample_rate)))
            rows.append((speaker * 1000 + utt.phone[i], jaw[k], energy_db))
    data = np.array(rows)
    z = []
    for cls in np.unique(data[:, 0]):
        r = data[data[:, 0] == cls]
        if len(r) >= 4:
            z.append((r[:, 1:] - r[:, 1:].mean(axis=0)) / r[:, 1:].std(axis=0))
    pooled = np.concatenate(z)
    assert len(pooled) >= 40
    assert np.corrcoef(pooled[:, 0], pooled[:, 1])[0, 1] > 0.3


def test_speech_pitch_is_trackable_by_praat():
    parselmouth = pytest.importorskip("parselmouth")
    for speaker in (0, 1):
        sim = simulate_take(TakeSpec(6, speaker, 1, 8.0))
        snd = parselmouth.Sound(sim.audio.mono_float().astype(np.float64), sim.audio.sample_rate)
        pitch = snd.to_pitch(time_step=0.01, pitch_floor=60.0, pitch_ceiling=500.0)
        f0, t = pitch.selected_array["frequency"], pitch.xs()
        utt = sim.utterance
        seg = np.clip(np.searchsorted(utt.end / utt.sample_rate, t, side="right"), 0, utt.phone.size - 1)
        vowel = np.array([utt.inventory.phones[p].is_vowel for p in utt.phone])[seg]
        expected = sim.speaker.f0_hz * 2.0 ** (utt.f0_st(t) / 12.0)
        assert np.mean(f0[vowel] > 0) > 0.9
        tracked = vowel & (f0 > 0)
        err_st = np.abs(12 * np.log2(f0[tracked] / expected[tracked]))
        assert np.median(err_st) < 0.5
        # Silence between phrases is unvoiced.
        silent = np.array([utt.inventory.phones[p].kind == "silence" for p in utt.phone])[seg]
        assert np.mean(f0[silent] > 0) < 0.2


def test_thirty_fps_second_language_and_44k_audio(tmp_path):
    out = tmp_path / "es"
    r = run_cli(
        "simulate",
        "-o",
        str(out),
        "--seconds",
        "4",
        "--fps",
        "30",
        "--language",
        "es",
        "--sample-rate",
        "44100",
        "--seed",
        "3",
        "--json",
    )
    assert r.returncode == 0, r.stderr
    (summary,) = [json.loads(line) for line in r.stdout.splitlines()]
    take = read_take_folder(summary["path"])
    assert take.meta.fps == 30.0 and take.audio.sample_rate == 44100
    assert take.meta.audio.start_source == "assumed_first_csv_row" and take.meta.audio.start_s == 0.0
    tg = read_textgrid(next(Path(summary["path"]).glob("*.TextGrid")))
    labels = {iv.text for iv in tg.tier("phones").intervals} - {""}
    assert labels <= {p.symbol for p in inventory("es").phones}
    assert tg.xmax == pytest.approx(take.audio.duration_s)


def test_artifacts_switch_off(tmp_path):
    sim = simulate_take(TakeSpec(8, 0, 1, 10.0, artifacts=Artifacts.without(["all"])))
    t = sim.truth
    assert t["dropped_frames"] == 0 and t["face_lost_frames"] == 0 and t["capture_offset_s"] == 0.0
    assert t["leading_silence_s"] < 0.2
    assert np.all(sim.take.channel("eyeBlinkLeft") == 0.0)
    assert np.ptp(sim.take.channel("headYaw")) == 0.0
    noisy = simulate_take(TakeSpec(8, 0, 1, 10.0))
    assert np.nanmax(noisy.take.channel("eyeBlinkLeft")) > 0.4
    assert noisy.truth["leading_silence_s"] >= 0.4


def test_speakers_differ_and_visemes_follow_phonetics():
    a = simulate_take(TakeSpec(1, 0, 1, 3.0)).speaker
    b = simulate_take(TakeSpec(1, 1, 1, 3.0)).speaker
    assert a.f0_hz != b.f0_hz and a.vtl_scale != b.vtl_scale and a.rate != b.rate
    en = inventory("en")
    assert 38 <= sum(p.kind != "silence" for p in en.phones) <= 42
    targets, _ = viseme_matrix(en)

    def v(sym, ch):
        return targets[en.index(sym), PRONUNCIATION32.index(ch)]

    assert v("p", "mouthClose") > 3 * v("aa", "mouthClose")
    assert v("m", "mouthPressLeft") > v("iy", "mouthPressLeft")
    assert v("f", "mouthRollLower") > v("s", "mouthRollLower")
    assert v("uw", "mouthPucker") > v("iy", "mouthPucker") and v("uw", "mouthFunnel") > v("aa", "mouthFunnel")
    assert v("aa", "jawOpen") > v("ih", "jawOpen") > v("iy", "jawOpen") * 0.9
    assert v("iy", "mouthSmileLeft") > v("uw", "mouthSmileLeft")
    assert v("iy", "mouthStretchRight") > v("ow", "mouthStretchRight")


@pytest.mark.parametrize(
    "args, message",
    [
        (["--language", "klingon"], "unknown language"),
        (["--fps", "25"], "--fps"),
        (["--takes", "0"], "--takes"),
        (["--takes", "100000000"], "between 1 and 10,000"),  # not minutes of silence
        (["--speakers", "3", "--takes", "2"], "--speakers"),
        (["--seconds", "0.5"], "--seconds"),
        (["--sample-rate", "8000"], "--sample-rate"),
        (["--without", "noise,sparkles"], "unknown artifact"),
    ],
)
def test_bad_arguments_are_one_line_errors(tmp_path, args, message):
    r = run_cli("simulate", "-o", str(tmp_path / "x"), *args)
    assert r.returncode == 1
    assert message in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize(
    "out, message", [("afile", "not a folder"), ("afile/sub", "cannot create"), ("/proc/x", "cannot create")]
)
def test_unusable_output_folder_is_a_one_line_error(tmp_path, out, message):
    (tmp_path / "afile").write_text("")
    r = run_cli("simulate", "-o", str(tmp_path / out), "--seconds", "2")
    assert r.returncode == 1
    assert message in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_api_rejects_unknown_language():
    with pytest.raises(InputError, match="unknown language"):
        simulate_take(TakeSpec(0, 0, 1, 3.0, language="xx"))


def test_a_folder_with_older_takes_keeps_them(tmp_path):
    """A run repeated with the same arguments writes the same bytes again (and may add speakers); a take
    folder of the same name holding another take (other settings, or a recording) is never replaced. (In
    this process: the command line runs as a subprocess in the other tests here.)"""
    out = tmp_path / "takes"
    args = ["simulate", "-o", str(out), "--takes", "2", "--seconds", "2", "--seed", "3"]
    assert run_here("capture", *args).returncode == 0
    before = folder_bytes(out)
    again = run_here("capture", *args)
    assert again.returncode == 0, again.stderr
    assert folder_bytes(out) == before
    more = run_here(
        "capture", *args[:3], "--speakers", "2", "--takes", "3", *args[5:]
    )  # spk01's two takes, and spk02's
    assert more.returncode == 0, more.stderr
    added = folder_bytes(out)
    assert {k: v for k, v in added.items() if k in before} == before and len(added) > len(before)
    longer = run_here("capture", *args[:6], "3", *args[7:])  # --seconds 3: other takes of the same names
    assert longer.returncode == 1 and "Traceback" not in longer.stderr
    (line,) = longer.stderr.strip().splitlines()
    assert "2 take folders this simulation writes are there already, holding other takes" in line, line
    assert "20250109_SimSpk01_1, 20250109_SimSpk01_2" in line, line
    assert folder_bytes(out) == added  # nothing written, nothing replaced
    (out / "20250109_SimSpk01_1" / "simulation.json").unlink()  # as a recording's folder of that name
    kept = folder_bytes(out)
    r = run_here("capture", *args)
    assert r.returncode == 1 and "1 take folder this simulation writes is there already" in r.stderr
    assert folder_bytes(out) == kept
