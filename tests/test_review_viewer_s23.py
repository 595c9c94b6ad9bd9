"""Review of the viewer's block-at-a-time speech and default frame/channel (e7407c8), and of
``dataset.build.mono_padded``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from dataset_helpers import make_aligned_take

from align.resample import mono_blocks
from capture import Audio, InputError
from dataset.build import mono_padded
from viewer.render import Animation, place_on_parent_clock


def test_mono_padded_takes_many_channels_whose_last_block_is_short():
    """Audio of more than 64 channels whose last block held fewer frames than channels was refused as
    (channels, samples) by the ``Audio`` made of each block; ``mono_blocks`` mixes each block without
    checking it again. The samples are those of ``mono_float`` on the whole, zero-padded."""
    block = next(mono_blocks(Audio(np.zeros(1 << 22, np.int16), 16000, "PCM_16"))).size  # frames a block
    pcm = np.zeros((block + 10, 70), np.int16)
    pcm[:, :3] = (np.arange(pcm.size // 70 * 3) % 4001 - 2000).reshape(-1, 3)  # sound on three of them
    audio = Audio(pcm, 48000, "PCM_16")
    padded = mono_padded(audio, audio.frames + 5)
    assert padded.dtype == np.float32 and padded.size == audio.frames + 5
    assert np.array_equal(padded[: audio.frames], audio.mono_float()) and not padded[audio.frames :].any()


TAKES = (
    "livelinkface/alexdjulin_S07/S07-001.csv",
    "livelinkface/alexdjulin_S88/S88-001.csv",
    "livelinkface/neurosync_MySlate_166/MySlate_166_iPhone_cal.csv",
    "paired/neurosync-trainer-lite-testset/testset.csv",
)


def test_without_jaw_open_the_mouth_shown_and_plotted_is_the_one_opening(samples):
    """Without jawOpen, the mouth channel that moved most was a smile (S07, S88, MySlate_166) or a pucker
    (testset): the frame shown had jawOpen at 0.203, 0.239, 0.000 and 0.066 (the takes' maxima 0.633,
    0.823, 0.101, 0.755), below their 90th percentile in all four, and the channel plotted followed the
    jaw with a correlation of 0.852, 0.363, 0.428 and -0.090. The lips parting, chosen first, opens the
    mouth with the jaw: 0.605, 0.336, 0.100, 0.742 at the frame shown, and 0.68..0.98."""
    from capture import ARKIT61
    from viewer.render import default_frame, load_animation, most_moving_mouth

    jaw_at = ARKIT61.index("jawOpen")
    for name in TAKES:
        anim = load_animation(samples / name)
        jaw = anim.weights[:, jaw_at].copy()
        anim.weights[:, jaw_at] = 0.0  # as an input without it
        k, note = default_frame(anim)
        mouth = most_moving_mouth([anim])
        assert note is not None and mouth in note
        assert jaw[k] > np.percentile(jaw, 90), (name, mouth, k)
        assert np.corrcoef(jaw, anim.weights[:, ARKIT61.index(mouth)])[0, 1] > 0.5, (name, mouth)


def test_resampled_speech_says_how_many_samples_its_blocks_give():
    """libsoxr gives round-half-up of frames * to / rate samples; ``round`` rounds a half to even: 787209
    samples at 192 kHz gave 393605 at 96 kHz where the ``Speech`` said 393604."""
    from viewer.render import Speech, resample_speech

    x = np.zeros(787209, np.float32)
    speech = resample_speech(Speech([x[: 1 << 18], x[1 << 18 :]], 192000, x.size), 96000)
    assert speech.frames == sum(block.size for block in speech.blocks) == 393605


def _shown(take) -> Animation:
    return Animation(take.meta.id, take.meta.fps, take.time, np.zeros((take.time.size, 61)), take=take)


def test_a_segments_parent_given_by_its_id_alone_places_it_and_a_malformed_report_is_one_line():
    """``render --compare`` (and ``plot``) of a take whose align report names its parent by the id alone
    (as the dataset stage reads it; ``dataset_helpers`` writes it so) stopped with a traceback
    (AttributeError: 'str' object has no attribute 'get'), and so did a report that is not an object."""
    raw = _shown(make_aligned_take("s1_raw", seconds=1.0))
    segment = make_aligned_take("s1", seconds=1.0)  # parent: "s1_raw"
    segment.meta.extra["align"]["segment_start_s"] = 0.75
    assert place_on_parent_clock(raw, _shown(segment)) == 0.75
    segment.meta.extra["align"]["parent"] = {"id": "s1_raw"}
    assert place_on_parent_clock(raw, _shown(segment)) == 0.75
    segment.meta.extra["align"]["segment_start_s"] = "soon"  # not a number: placed with the first
    assert place_on_parent_clock(raw, _shown(segment)) == 0.0
    segment.meta.extra["align"] = ["s1_raw"]
    with pytest.raises(InputError, match=r"^given/s1: malformed metadata: extra\.align must be an object"):
        place_on_parent_clock(raw, _shown(segment), Path("given/s1"))


@pytest.mark.parametrize("channel", ["jawOpen", "mouthLowerDownLeft", "eyeBlinkLeft"])
def test_the_frame_shown_by_default_holds_a_face(tmp_path, channel):
    """Frames whose face was lost are bridged from the frames around them, held at the ends: a take
    whose face was lost on its first 10 frames, widest open on its first frame with a face, showed frame
    0 (a frame without a face), by the jaw, by the mouth channel taken without it, and as the first
    frame when no mouth channel moves."""
    from capture import ARKIT52, Take, TakeMeta, write_take
    from viewer.render import default_frame, load_animation

    n, held = 30, [c for c in ARKIT52 if c == channel or c != "jawOpen"]
    values = np.zeros((n, len(held)), np.float32)
    values[:, held.index(channel)] = np.linspace(0.6, 0.1, n)
    status = np.zeros(n, np.uint8)
    status[:10], values[:10] = 1, np.nan  # face lost
    meta = TakeMeta(id="lost", source_kind="aligned", fps=30.0, channels=held)
    write_take(Take(meta, np.arange(n) / 30, values, status), tmp_path)
    k, note = default_frame(load_animation(tmp_path / "lost"))
    assert k == 10 and (note is None) == (channel == "jawOpen")
    assert channel != "eyeBlinkLeft" or "no mouth channel moves: frame 10 shown" in note
