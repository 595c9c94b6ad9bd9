"""benchmarks/paper.py (``make results``): the document is rendered from the results JSON alone and says
what the numbers say; a --quick run on tiny simulated data trains, evaluates and writes both files."""

from __future__ import annotations

import copy
import importlib
import json
import math
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # benchmarks/ is not an installed package: import it from the checkout
    sys.path.insert(0, str(ROOT))
paper = importlib.import_module("benchmarks.paper")


def _m(mean: float, std: float) -> dict[str, float]:
    return {"mean": mean, "std": std}


def _row(system: str, entire: float, crucial: float | None, rtf: float, content: str = "ppg") -> dict:
    floor = {"rmse_entire": _m(10.0, 1.0), "rmse_crucial": None if crucial is None else _m(20.0, 2.0)}
    return {
        "system": system,
        "steps": 0 if system == "ridge" else 100,
        "stopped": "closed_form" if system == "ridge" else "max_steps",
        "max_steps": 100,
        "content": content,
        "test": {
            "rmse_entire": _m(entire, 0.5),
            "rmse_crucial": None if crucial is None else _m(crucial, 0.25),
            "floor": floor,
            "utterances": 7,
            "rtf": rtf,
            "device": "cpu (test, 2 threads)",
        },
    }


def _results() -> dict:
    sim = [
        _row("s2a", 4.0, 8.0, 0.002),
        _row("s2a-mfcc", 4.5, 9.0, 0.002, "mfcc"),
        _row("blstm", 5.0, 10.0, 0.01),
        _row("ridge", 6.0, 11.0, 0.0005),
    ]
    fg = [_row("s2a", 7.0, None, 0.001, "fbank"), _row("blstm", 6.5, None, 0.004, "fbank")]

    def ev(entire: float) -> dict:
        return {
            "rmse_entire": _m(entire, 0.3),
            "rmse_crucial": _m(2 * entire, 0.3),
            "floor": {"rmse_entire": _m(9.0, 1.0), "rmse_crucial": _m(18.0, 1.0)},
            "utterances": 5,
        }

    cross = {
        "xspk/s2a": {"system": "s2a", "evals": {"en-unseen": ev(5.0), "es-unseen": ev(6.0)}},
        "xspk/s2a-mfcc": {"system": "s2a", "evals": {"en-unseen": ev(5.5), "es-unseen": ev(7.5)}},
        "es/s2a": {"system": "s2a", "evals": {"es-unseen": ev(4.8)}},
        "es/s2a-mfcc": {"system": "s2a", "evals": {"es-unseen": ev(4.9)}},
    }
    plan = dict(paper.FULL.__dict__)
    return {
        "quick": False,
        "generated": "2026-01-01 00:00 UTC",
        "machine": {"cpu": "Test CPU", "cores": 2, "python": "3.11", "torch": "2.13.0"},
        "settings": {
            "plan": plan,
            "jobs": 2,
            "threads_per_training": 1,
            "threads_for_rtf": 2,
            "seed": 1,
            "sim_config": "benchmarks/configs/simulated.toml",
            "sim_config_text": "lr = 1e-3",
            "fg_config": "benchmarks/configs/facegood.toml",
            "fg_config_text": "lr = 2e-3",
            "en_speakers": [f"spk{i:02d}" for i in range(1, 9)],
            "es_speakers": [f"spk{i:02d}" for i in range(9, 17)],
            "en_test": ["spk07", "spk08"],
            "es_test": ["spk15", "spk16"],
        },
        "wall_minutes": {"training_phase": 25.0, "total": 30.5},
        "data": {},
        "same_normalization_xspk_xlang": True,
        "table1": {"sim": sim, "facegood": fg},
        "paper_size_rtf": [{"system": "s2a", "rtf": 0.01}, {"system": "blstm", "rtf": 0.04}],
        "cross": cross,
        "paper": paper.PAPER,
    }


def _table_row(md: str, label: str, section: str) -> list[str]:
    """Cells of the first table row starting with ``label`` after the heading ``section``."""
    part = md.split(section, 1)[1]
    for line in part.splitlines():
        if line.startswith(f"| {label} |"):
            return [c.strip() for c in line.strip("|").split("|")]
    raise AssertionError(f"no row {label!r} after {section!r}")


def test_render_tables_come_from_the_json():
    md = paper.render(_results())
    s2a = _table_row(md, "Transformer-S2A (MoE) [PPG]", "(a) Simulated")
    assert s2a[2:5] == ["4.00 ± 0.50", "8.00 ± 0.25", "0.40"]
    floor = _table_row(md, "train-mean floor", "(a) Simulated")
    assert floor[2:4] == ["10.00 ± 1.00", "20.00 ± 2.00"]
    # FACEGOOD has no jawOpen/mouthClose: crucial is n/a, and the document says why
    fg = _table_row(md, "Transformer-S2A (MoE) [fbank]", "(b) FACEGOOD")
    assert fg[3] == "n/a"
    assert "no jawOpen or mouthClose" in md
    # Table 2: speed-up = RTF(BLSTM) / RTF(system), per column
    t2 = _table_row(md, "Transformer-S2A (MoE)", "## Table 2")
    assert t2[1:7] == ["0.0020", "5.00×", "0.0010", "4.00×", "0.0100", "4.00×"]
    assert "17×" in t2[7]
    assert _table_row(md, "ridge (±7 frames)", "## Table 2")[2] == "20.00×"
    # cross-speaker / cross-language rows
    es = _table_row(md, "English, 5 speakers", "## Cross-speaker")
    assert es[2:4] == ["5.00 ± 0.30", "5.50 ± 0.30"]
    assert "Spanish, unseen speakers spk15, spk16 | 6.00 ± 0.30 | 7.50 ± 0.30" in md
    assert "normalisation is identical (checked)" in md


def test_discussion_follows_the_numbers():
    res = _results()
    md = paper.render(res)
    assert "S2A is lower than BLSTM (4.00 vs 5.00)" in md
    assert "PPG is lower than MFCC" in md and "agrees with the paper's claim" in md
    assert "a 4.0× speed-up, against the paper's 17× speed-up" in md
    flipped = copy.deepcopy(res)
    flipped["table1"]["sim"][0]["test"]["rmse_entire"] = _m(5.5, 0.5)
    flipped["cross"]["xspk/s2a"]["evals"]["en-unseen"]["rmse_entire"] = _m(6.0, 0.3)
    md2 = paper.render(flipped)
    assert "S2A is higher than BLSTM (5.50 vs 5.00)" in md2
    assert "PPG is higher than MFCC" in md2 and "does not show here" in md2
    assert "--quick smoke run" not in md and "--quick smoke run" in paper.render({**res, "quick": True})


def test_quick_run_trains_evaluates_and_renders(tmp_path):
    out = tmp_path / "out"
    rc = paper.main(["--quick", "--only", "sim", "--systems", "ridge,nvp3", "--out", str(out)])
    assert rc == 0
    res = json.loads((out / "results.json").read_text())
    rows = {r["system"]: r for r in res["table1"]["sim"]}
    assert set(rows) == {"ridge", "nvp3"}
    for r in rows.values():
        t = r["test"]
        assert t["utterances"] >= 1 and t["frames"] > 0
        assert math.isfinite(t["rmse_entire"]["mean"]) and t["rmse_entire"]["mean"] > 0
        assert t["rmse_crucial"] is not None and t["rtf"] > 0
    assert rows["nvp3"]["steps"] == paper.QUICK.sim_steps and rows["nvp3"]["content"] == "ppg"
    # even on seconds of data the ridge regression beats predicting the mean
    assert (
        rows["ridge"]["test"]["rmse_entire"]["mean"] < rows["ridge"]["test"]["floor"]["rmse_entire"]["mean"]
    )
    assert res["data"]["ds-sim"]["splits"]["test"]["samples"] >= 1
    md = (out / "results.md").read_text()
    ridge = rows["ridge"]["test"]["rmse_entire"]
    assert f"| ridge (±7 frames) | closed form | {ridge['mean']:.2f} ± {ridge['std']:.2f} |" in md
    assert "--quick smoke run" in md
    # re-rendering needs only the JSON, and gives the same document
    (out / "results.md").unlink()
    assert paper.main(["--quick", "--out", str(out), "--render-only"]) == 0
    assert (out / "results.md").read_text() == md
    # a second run reuses every finished task (state records) and reproduces the numbers
    assert paper.main(["--quick", "--only", "sim", "--systems", "ridge,nvp3", "--out", str(out)]) == 0
    again = json.loads((out / "results.json").read_text())
    assert [r["test"]["rmse_entire"] for r in again["table1"]["sim"]] == [
        r["test"]["rmse_entire"] for r in res["table1"]["sim"]
    ]


def test_unknown_system_is_a_usage_error(tmp_path):
    with pytest.raises(SystemExit) as exc:
        paper.main(["--quick", "--systems", "s2a,gpt", "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert not re.search(r"results", " ".join(p.name for p in tmp_path.iterdir()))


def test_speed_set_takes_one_segment_per_recording(tmp_path):
    """The Table 2 dataset pins a val and a test take: they must come from different recordings, since
    the build keeps a recording's segments in one split (two segments of one would be refused)."""
    from dataset_helpers import make_aligned_take

    from capture import write_take

    for take_id, parent, subject in [
        ("a.seg01", "a", "spk01"),
        ("a.seg02", "a", "spk01"),
        ("b.seg01", "b", "spk01"),
        ("c", None, "spk01"),
        ("d", None, "spk02"),
    ]:
        take = make_aligned_take(take_id, 1.0, subject=subject)
        if parent:
            take.meta.extra["align"]["parent"] = {"id": parent, "source_kind": "livelinkface_csv"}
        write_take(take, tmp_path)
    picked = paper.takes_of_recordings(str(tmp_path), "spk01", 3)
    assert [take_id for _folder, take_id in picked] == ["a.seg01", "b.seg01", "c"]
    with pytest.raises(RuntimeError, match="spk01 has 3 recording"):
        paper.takes_of_recordings(str(tmp_path), "spk01", 4)
