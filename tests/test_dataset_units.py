"""Units of the dataset stage: exact normalisation round trips, split rules, the preprocessor's
frame grid and pitch, and deterministic shard bytes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from capture.errors import InputError
from dataset import (
    ChannelAccumulator,
    Normalizer,
    ShardReader,
    ShardWriter,
    SplitRule,
    assign_splits,
    fit_normalizer,
)
from dataset.features import FeatureSettings, compute_features, to_animation_rate

# float32 blendshape-like values: zero, or magnitudes the device produces (about 1e-6 .. 10)
values32 = st.one_of(
    st.just(0.0),
    st.floats(2**-20, 10.0, width=32),
    st.floats(-10.0, -(2**-20), width=32),
)


@settings(max_examples=200, deadline=None)
@given(
    x=arrays(np.float32, (7, 3), elements=values32),
    offset=arrays(np.float32, 3, elements=st.floats(-1.0, 1.0, width=32)),
    scale=arrays(np.float32, 3, elements=st.integers(-12, 6).map(lambda e: 2.0**e)),
    kind=st.sampled_from(["zscore", "neutral"]),
)
def test_normalization_round_trips_exactly(x, offset, scale, kind):
    norm = Normalizer(kind, ["a", "b", "c"], offset, scale)
    back = norm.inverse(norm.forward(x))
    assert back.dtype == np.float32
    np.testing.assert_array_equal(back, x)
    # via JSON (as stored in the manifest) and with a sample's own neutral
    again = Normalizer.from_json(norm.to_json())
    neutral = offset[::-1].copy()
    np.testing.assert_array_equal(again.inverse(again.forward(x, neutral), neutral), x)


def test_fitted_normalizers_from_statistics():
    rng = np.random.default_rng(0)
    x = rng.normal([0.1, 0.5, 0.0], [0.05, 0.2, 0.0], (2000, 3)).astype(np.float32)
    acc = ChannelAccumulator(3)
    acc.add(x[:1000])
    other = ChannelAccumulator(3)
    other.add(x[1000:])
    acc.merge(other)
    z = fit_normalizer("zscore", ["a", "b", "c"], acc)
    y = z.forward(x)
    np.testing.assert_allclose(y[:, :2].mean(0), 0, atol=1e-3)
    assert np.all((y[:, :2].std(0) > 2**-0.5) & (y[:, :2].std(0) < 2**0.5))
    assert np.all(np.frexp(z.scale)[0] == 0.5)  # powers of two: exact inverse
    assert z.scale[2] == 1.0  # a channel that never moves is not blown up
    n = fit_normalizer("neutral", ["a", "b", "c"], acc)
    np.testing.assert_allclose(n.offset[:2], np.percentile(x[:, :2], 5, axis=0), atol=2e-3)
    with pytest.raises(InputError):
        Normalizer("minmax", ["a"], [0.0], [1.0])


def test_percentiles_of_channels_beyond_blendshape_range():
    # controls beyond ±2 (up to the build's limit, ±10: angles in radians, a rig's wider controls) and
    # blendshape weights: every percentile within the histogram's resolution (0.5 % beyond ±2, 5e-4 inside)
    rng = np.random.default_rng(1)
    x = np.stack(
        [rng.uniform(0, 9.5, 5000), np.clip(rng.normal(0, 3, 5000), -9.9, 9.9), rng.beta(2, 5, 5000)], 1
    )
    acc = ChannelAccumulator(3)
    acc.add(x[:2000])
    rest = ChannelAccumulator(3)
    rest.add(x[2000:])
    acc.merge(rest)
    for q in (5, 50, 95):
        got, want = acc.percentile(q), np.percentile(x, q, axis=0)
        np.testing.assert_allclose(got[:2], want[:2], rtol=0.01, atol=2e-3)
        np.testing.assert_allclose(got[2], want[2], atol=1e-3)
    n = fit_normalizer("neutral", ["a", "b", "c"], acc)
    np.testing.assert_allclose(n.offset, np.percentile(x, 5, axis=0), rtol=0.01, atol=2e-3)


def test_a_pinned_split_topped_up_by_its_fraction_is_warned_about():
    from dataset.build import split_share_warnings

    takes = {f"t{i}": (f"s{i % 4}", 10.0) for i in range(20)}
    rule = SplitRule("take", 0.1, 0.2, seed=3, test=("t1",))
    split_of = assign_splits(takes, rule)
    (warning,) = split_share_warnings(takes, split_of, rule)
    added = sorted(t for t, s in split_of.items() if s == "test" and t != "t1")
    assert (
        len(added) == 3
        and f"the test split holds 3 take(s) besides those pinned with --test ({', '.join(added)})" in warning
    )
    assert "give --test-fraction 0 to keep only the pinned ones" in warning
    exact = SplitRule("take", 0.1, 0.0, seed=3, test=("t1",))
    assert [t for t, s in assign_splits(takes, exact).items() if s == "test"] == ["t1"]
    assert not split_share_warnings(takes, assign_splits(takes, exact), exact)
    # a pinned take's whole group goes with it (its speaker's takes, its recording's segments): not added
    by_speaker = SplitRule("speaker", 0.0, 0.25, seed=3, test=("t1",))
    split_of = assign_splits(takes, by_speaker)
    assert {s for t, s in split_of.items() if takes[t][0] == "s1"} == {"test"}
    assert not split_share_warnings(takes, split_of, by_speaker)
    segments = SplitRule("take", 0.0, 0.0, seed=3, test=("t1",))
    recordings = {"t1": "rec", "t2": "rec"}
    split_of = assign_splits(takes, segments, recordings)
    assert split_of["t2"] == "test" and not split_share_warnings(takes, split_of, segments, recordings)


def test_splits_by_take_and_speaker():
    takes = {f"t{i}": (f"s{i % 4}", 10.0) for i in range(20)}
    by_take = assign_splits(takes, SplitRule("take", 0.1, 0.2, seed=3))
    counts = {s: sum(v == s for v in by_take.values()) for s in ("train", "val", "test")}
    assert counts == {"train": 14, "val": 2, "test": 4}
    assert assign_splits(takes, SplitRule("take", 0.1, 0.2, seed=3)) == by_take  # deterministic
    by_spk = assign_splits(takes, SplitRule("speaker", 0.25, 0.25, test=("s1",)))
    for spk in ("s0", "s1", "s2", "s3"):
        assert len({by_spk[t] for t, (s, _) in takes.items() if s == spk}) == 1
    assert all(by_spk[t] == "test" for t, (s, _) in takes.items() if s == "s1")
    assert set(by_spk.values()) == {"train", "val", "test"}
    pinned = assign_splits(takes, SplitRule("take", 0.0, 0.0, val=("t5",)))
    assert pinned["t5"] == "val" and sum(v == "train" for v in pinned.values()) == 19
    with pytest.raises(InputError, match="not among the inputs"):
        assign_splits(takes, SplitRule(test=("nobody",)))
    with pytest.raises(InputError):
        SplitRule("window")
    # one take: it stays in train whatever the fractions
    assert assign_splits({"only": ("s", 5.0)}, SplitRule()) == {"only": "train"}


def test_interpolation_to_the_animation_grid():
    hop = 0.02
    grid = np.arange(51, dtype=np.float32)  # value = analysis frame index, centres at k * 20 ms
    at60 = to_animation_rate(grid, hop, 60, 60.0)
    np.testing.assert_allclose(at60, np.arange(60) / 60.0 / hop, atol=1e-5)
    at30 = to_animation_rate(np.stack([grid, -grid], 1), hop, 30, 30.0)
    np.testing.assert_allclose(at30[:, 1], -np.arange(30) / 30.0 / hop, atol=1e-5)


def test_pitch_energy_fbank_of_a_tone():
    sr, f0 = 16000, 180.0
    t = np.arange(2 * sr) / sr
    x = (0.3 * np.sin(2 * np.pi * f0 * t) * (t < 1.0)).astype(np.float32)  # 1 s tone, 1 s silence
    feats, phones = compute_features(x, 120, 60.0, ("pitch", "energy", "fbank", "mfcc"), FeatureSettings())
    assert phones is None
    assert {k: v.shape for k, v in feats.items()} == {
        "pitch": (120, 2),
        "energy": (120, 1),
        "fbank": (120, 40),
        "mfcc": (120, 13),
    }
    voiced = feats["pitch"][:, 1]
    assert voiced[5:55].all() and not voiced[65:].any()
    np.testing.assert_allclose(np.exp(feats["pitch"][10:50, 0]), f0, rtol=0.01)
    assert feats["energy"][10:50].min() > feats["energy"][70:].max() + 5
    assert int(np.argmax(feats["fbank"][30])) <= 4  # 180 Hz lies in the lowest mel bands


def test_shard_writer_is_deterministic_and_rejects_bad_keys(tmp_path):
    members = {"json": b'{"a":1}\n', "anim.npy": b"x" * 1000, "flac": b"y" * 10}
    infos = []
    for name in ("a.tar", "b.tar"):
        w = ShardWriter(tmp_path / name)
        w.add("k1", members)
        w.add("k2", members)
        infos.append(w.close())
    assert (tmp_path / "a.tar").read_bytes() == (tmp_path / "b.tar").read_bytes()
    assert infos[0].sha256 == infos[1].sha256 and infos[0].keys == ["k1", "k2"]
    assert [k for k, _ in ShardReader(tmp_path / "a.tar")] == ["k1", "k2"]
    w = ShardWriter(tmp_path / "c.tar")
    with pytest.raises(InputError):
        w.add("has.dot", members)
    w.add("k2", members)
    with pytest.raises(InputError, match="increasing order"):
        w.add("k1", members)
    w.abort()
    assert not list(tmp_path.glob(".c.tar*")) and not (tmp_path / "c.tar").exists()
