import numpy as np
import pytest

from capture import channels as ch
from capture import read_livelink_csv
from capture.errors import InputError


def test_sixty_one_channels_in_engine_order():
    assert len(ch.LIVELINK_ORDER) == 61 == len(set(ch.LIVELINK_ORDER))
    assert ch.LIVELINK_ORDER[15:17] == ("JawLeft", "JawRight")
    assert ch.LIVELINK_ORDER[21:23] == ("MouthLeft", "MouthRight")
    assert ch.LIVELINK_ORDER[17] == "JawOpen" and ch.LIVELINK_ORDER[51] == "TongueOut"
    assert ch.LIVELINK_ORDER[52:] == (
        "HeadYaw",
        "HeadPitch",
        "HeadRoll",
        "LeftEyeYaw",
        "LeftEyePitch",
        "LeftEyeRoll",
        "RightEyeYaw",
        "RightEyePitch",
        "RightEyeRoll",
    )


def test_csv_order_differs_only_at_the_two_pairs():
    diff = [i for i, (a, b) in enumerate(zip(ch.LIVELINK_ORDER, ch.CSV_ORDER)) if a != b]
    assert diff == [15, 16, 21, 22]
    assert ch.CSV_ORDER[15:17] == ("JawRight", "JawLeft")
    assert ch.CSV_ORDER[21:23] == ("MouthRight", "MouthLeft")


def test_csv_header_of_the_real_samples_is_csv_order(samples):
    header = (samples / "paired/neurosync-trainer-lite-testset/testset.csv").open().readline()
    assert tuple(header.strip().split(",")[2:]) == ch.CSV_ORDER


def test_names_and_sets():
    assert ch.arkit_name("JawOpen") == "jawOpen"
    assert ch.canonical("JAWOPEN") == ch.canonical("jawopen") == "jawOpen"
    assert ch.livelink_name("mouthClose") == "MouthClose"
    assert ch.udp_index("jawLeft") == 15 and ch.udp_index("JawLeft") == 15
    assert ch.canonical("HeadYaw") == "headYaw"
    assert len(ch.ARKIT52) == 52 and len(ch.ARKIT61) == 61
    p = ch.PRONUNCIATION32
    assert len(p) == 32
    groups = {k: sum(n.startswith(k) for n in p) for k in ("jaw", "mouth", "cheek", "nose")}
    assert groups == {"jaw": 4, "mouth": 23, "cheek": 3, "nose": 2}
    assert not any(n.startswith(("eye", "brow", "tongue")) for n in p)
    assert ch.channel_set("Pronunciation32") == p
    assert ch.channel_set("JawOpen, mouthclose") == ("jawOpen", "mouthClose")
    with pytest.raises(InputError, match="unknown channel"):
        ch.channel_set("jawOpen,notAChannel")
    with pytest.raises(InputError):
        ch.udp_index("nope")


def test_jaw_left_from_csv_is_the_channel_of_udp_index_15(tmp_path, samples):
    """The CSV's JawLeft column (18th value column) and UDP value 15 name the same channel."""
    src = samples / "livelinkface/neurosync_MySlate_166/MySlate_166_iPhone_cal.csv"
    lines = src.read_text().splitlines()
    header = lines[0].split(",")
    jl, jr = header.index("JawLeft"), header.index("JawRight")
    assert (jl, jr) == (18, 17)  # CSV: JawRight before JawLeft
    rows = []
    for line in lines[1:4]:
        f = line.split(",")
        f[jl], f[jr] = "0.7000000000", "0.1000000000"
        rows.append(",".join(f))
    path = tmp_path / "t.csv"
    path.write_text("\n".join([lines[0], *rows]) + "\n")
    take = read_livelink_csv(path)
    assert np.allclose(take.channel("jawLeft"), 0.7) and np.allclose(take.channel("jawRight"), 0.1)
    # The take's channels are in UDP/engine order, so column 15 is JawLeft as in a packet.
    assert take.meta.channels[15] == ch.canonical(ch.LIVELINK_ORDER[15]) == "jawLeft"
    assert np.allclose(take.values[:, 15], 0.7)


def test_optional_left_right_swap(tmp_path, samples):
    src = samples / "livelinkface/neurosync_MySlate_166/MySlate_166_iPhone_cal.csv"
    plain = read_livelink_csv(src)
    swapped = read_livelink_csv(src, swap_lr=True)
    assert np.array_equal(swapped.channel("jawLeft"), plain.channel("jawRight"))
    assert np.array_equal(swapped.channel("mouthRight"), plain.channel("mouthLeft"))
    assert np.array_equal(swapped.channel("jawOpen"), plain.channel("jawOpen"))
