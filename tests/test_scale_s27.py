"""Costs that grow past a machine. The ridge holds an input-by-input float64 matrix per set of sums: one,
plus one per channel glitched in some frames (solved alone), and agreement a set per take; at
ridge_context 60 with PPG (8,107 inputs, 0.53 GB each) 61 glitched channels need ~32 GB. Past the memory
given (``Memory``: by default a share of the machine's available memory) the sums refuse with an
``InputError`` naming the size, the memory there is and what to do, before allocating the matrix. And an
import of a folder of loose CSVs listed the folder several times per CSV (O(N²): 1,500 CSVs 108-210 s):
within ``listed_once`` each folder is listed, and what is found in it found, once."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import torch
from test_loosecal_s27 import loose_copy
from test_ridgevalues_s27 import glitched  # noqa: F401 (fixture)
from test_take_folder import make_take_folder

from capture.errors import InputError
from capture.importer import audio_beside, find_sources, import_source
from capture.take_folder import listed_once
from dataset.manifest import read_manifest
from train.agreement import take_agreement
from train.config import resolve_config
from train.data import resolve_inputs
from train.ridge import SOLVING, Memory, NormalEquations

N_IN = 30
MATRIX = 8 * N_IN * N_IN  # bytes of one input-by-input float64 matrix


def test_a_glitched_channel_past_the_memory_is_refused_before_its_sums():
    """Room for the sums and one glitched channel's (and a solution's): a second glitched channel is
    refused, its matrix not made; the message names the size, the memory and what to do."""
    memory = Memory(budget=(2 + SOLVING) * MATRIX)
    eq = NormalEquations(N_IN, 3, memory)
    gen = torch.Generator().manual_seed(0)
    x, y = torch.randn(50, N_IN, generator=gen), torch.randn(50, 3, generator=gen)
    usable = torch.ones(50, 3, dtype=torch.bool)
    usable[:5, 0] = False
    eq.add(x, y, usable)  # one glitched channel: fits
    usable[5:9, 2] = False
    with pytest.raises(InputError) as err:
        eq.add(x, y, usable)
    message = str(err.value)
    assert message.startswith("config:ridge_context: ") and "\n" not in message
    assert "2 channels glitched" in message and f"{(3 + SOLVING) * MATRIX / 1e9:.2f} GB" in message
    assert f"{(2 + SOLVING) * MATRIX / 1e9:.2f} GB is there" in message
    assert "smaller ridge_context" in message and "--channels" in message
    assert list(eq.gaps) == [0] and memory.held == 2


def test_the_default_memory_is_a_share_of_the_machines():
    """No budget given: a share of the memory available, at most the machine's physical memory."""
    physical = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    assert 0 < Memory().budget <= physical
    eq = NormalEquations(N_IN, 2)
    assert eq.memory.held == 1


def test_agreement_past_the_memory_is_refused_before_reading(glitched):  # noqa: F811
    """Agreement holds a set of sums per take (its train and val takes: four here, each with headYaw
    glitched: two matrices), then their total and a take left out (two each): without room for the
    takes' sets it refuses before reading one; with room for them but not for the total, before it."""
    cfg = resolve_config(sets=["ridge_alpha=0.1"])
    spec = resolve_inputs(read_manifest(glitched), cfg)
    n_in = (2 * cfg["ridge_context"] + 1) * (spec.content_dim + spec.prosody_dim)
    matrix = 8 * n_in * n_in
    said = []
    with pytest.raises(InputError) as err:
        take_agreement(glitched, cfg, say=said.append, memory=Memory(budget=(4 + 1 + SOLVING) * matrix))
    assert "agreement's sums of 4 takes" in str(err.value)
    assert f"need {(4 + 2 + SOLVING) * matrix / 1e9:.2f} GB" in str(err.value)
    assert not said  # no take read
    with pytest.raises(InputError, match="sums of 4 takes .1 channels glitched"):
        take_agreement(glitched, cfg, say=said.append, memory=Memory(budget=(4 * 2 + 3 + SOLVING) * matrix))
    enough = Memory(budget=(4 * 2 + 4 + SOLVING) * matrix)
    assert take_agreement(glitched, cfg, say=said.append, memory=enough) == take_agreement(glitched, cfg)


def _imported(folder: Path) -> list[tuple]:
    """(source, take id, values, neutral pose, audio beside) of each source found in ``folder``."""
    found = []
    for source in find_sources([folder], skipped=lambda path, why: None):
        take = import_source(source)
        found.append((source, take.meta.id, take.values, take.neutral, audio_beside(source)))
    return found


def test_an_import_lists_a_folder_of_loose_csvs_once(tmp_path, samples):
    """Each CSV of a folder of loose ones looked at the whole folder (its ``.mov`` files, the take's
    ``_neutral.csv``, placeholders, audio beside it) several times: 1,500 CSVs took 210 s. Within
    ``listed_once`` (one import) the folder is listed once, with the same takes; a later import sees the
    files changed since."""
    phone = make_take_folder(tmp_path / "phone", samples)
    loose = tmp_path / "loose"
    for n in range(3):
        loose_copy(phone, loose, f"MySlate_{170 + n}_iPhone")
    sf.write(loose / "MySlate_171_iPhone_cal.wav", np.zeros(1600, np.float32), 16000)
    alone = _imported(loose)
    with listed_once() as listing:
        shared = _imported(loose)
    assert listing.folders == [loose]
    assert len(shared) == len(alone) == 3
    for a, b in zip(alone, shared, strict=True):
        assert a[:2] == b[:2] and a[4] == b[4]
        np.testing.assert_array_equal(a[2], b[2])
        np.testing.assert_array_equal(a[3], b[3])
    assert shared[1][4][0] == loose / "MySlate_171_iPhone_cal.wav"
    (loose / "MySlate_170_iPhone_neutral.csv").unlink()
    with listed_once():
        assert _imported(loose)[0][3] is None
