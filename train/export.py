"""ONNX export of a trained run, checked against PyTorch with onnxruntime.

Graph inputs: ``content`` (1, frames, content_dim) float32, ``prosody`` (1, frames, prosody_dim) float32
(absent for the no-prosody ablation) and ``mask`` (1, frames) bool; output ``animation`` (1, frames,
channels), normalised. The file carries what a user of the graph needs and would otherwise have to fetch
from the dataset (``onnx_metadata``, as JSON strings in ``metadata_props``): the output's channel names,
the frame rate, the input features and their settings, and the normalisation statistics of the inputs
and of the output (``dataset.Normalizer.from_json(normalization["animation"]).inverse`` de-normalises).
The batch dimension is 1 everywhere. Frames are a dynamic axis, up to the model's ``max_frames``
(Transformer-S2A's positional table; longer inputs fail in onnxruntime, so run them in windows as
``predict`` does). The parity check runs both on random inputs of two lengths and reports the largest
difference; an output that is not finite (NaN or inf, from either) fails it. The graph is written beside
``out`` under a hidden name and renamed over ``out`` only once the parity check has passed. ``out`` may
not be the checkpoint exported, nor any other PyTorch checkpoint, nor a file of the run or of a dataset
folder other than an ONNX model.
"""

from __future__ import annotations

import copy
import json
import math
import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from capture.atomic import partial_path, put_in_place, written_into
from capture.command import progress, stops_deferred
from capture.errors import InputError, S2AError
from capture.take import make_out_dir
from dataset.bottleneck import ZIP_MAGIC

from .checkpoint import NOT_FINITE, checkpoint_path, disk_full, load_system, write_error
from .data import InputSpec
from .systems import max_frames


class ExportFailed(S2AError):
    """The exported graph does not reproduce the PyTorch model."""


class _WithProsody(nn.Module):
    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, content, prosody, mask):
        return self.model(content, prosody, mask)


class _NoProsody(nn.Module):
    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, content, mask):
        return self.model(content, None, mask)


class _TraceableAttention(nn.Module):
    """The same self-attention as an ``nn.MultiheadAttention`` (batch first, shared weights), written with
    shape-free reshapes: the legacy ONNX tracer freezes the frame count inside the built-in module."""

    def __init__(self, mha: nn.MultiheadAttention):
        super().__init__()
        self.mha = mha

    def forward(self, query, key, value, key_padding_mask=None, need_weights=False):
        m = self.mha
        b, d, h = query.shape[0], m.embed_dim, m.num_heads
        q, k, v = nn.functional.linear(query, m.in_proj_weight, m.in_proj_bias).chunk(3, dim=-1)
        q, k, v = (t.reshape(b, -1, h, d // h).transpose(1, 2) for t in (q, k, v))
        scores = q @ k.transpose(-1, -2) / (d // h) ** 0.5
        if key_padding_mask is not None:
            scores = scores.masked_fill(key_padding_mask[:, None, None, :], float("-inf"))
        y = (scores.softmax(-1) @ v).transpose(1, 2).reshape(b, -1, d)
        return m.out_proj(y), None


def _traceable(model: nn.Module) -> nn.Module:
    for name, child in list(model.named_children()):
        if isinstance(child, nn.MultiheadAttention):
            setattr(model, name, _TraceableAttention(child))
        else:
            _traceable(child)
    return model


def _inputs(spec: InputSpec, frames: int, seed: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    x = {"content": torch.randn(1, frames, spec.content_dim, generator=g)}
    if spec.prosody_dim:
        x["prosody"] = torch.randn(1, frames, spec.prosody_dim, generator=g)
    x["mask"] = torch.ones(1, frames, dtype=torch.bool)
    return x


def export_onnx(
    run: str | Path, out: str | Path, tolerance: float = 1e-4, say: Callable[[str], None] = progress
) -> dict[str, Any]:
    """Write ``out`` (.onnx) and check it with onnxruntime; raises ExportFailed beyond ``tolerance``
    (largest absolute difference, normalised units)."""
    import onnxruntime as ort

    out = Path(out)
    check_out(run, out)
    model, payload = load_system(run)
    spec = InputSpec.from_json(payload["inputs"])
    wrap = _WithProsody if spec.prosody_dim else _NoProsody
    reference = wrap(model)
    wrapper = wrap(_traceable(copy.deepcopy(model)))  # _traceable swaps modules in place
    limit = max_frames(payload.get("model_config"))
    lengths = _check_lengths(limit)
    example = _inputs(spec, lengths[0], 0)
    names = list(example)
    make_out_dir(out.parent)
    tmp = partial_path(out)  # renamed over out once the parity check passes; removed otherwise
    try:
        try:
            # written to and read from open files: torch's, onnx's and onnxruntime's C++ take a name as
            # UTF-8, and failed (TypeError) on a name that is not (Python holds it as surrogate escapes)
            with warnings.catch_warnings(), open(tmp, "wb") as f:
                warnings.simplefilter("ignore")
                torch.onnx.export(
                    wrapper,
                    tuple(example.values()),
                    f,
                    input_names=names,
                    output_names=["animation"],
                    dynamic_axes={**{n: {1: "frames"} for n in names}, "animation": {1: "frames"}},
                    opset_version=17,
                    dynamo=False,
                )
        except RuntimeError as exc:  # torch's writer: a full disk shows as a RuntimeError
            if disk_full(exc, out.parent):
                raise write_error(exc, out, "the ONNX file") from None
            raise
        annotate(tmp, payload, names, limit)
        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        session = ort.InferenceSession(tmp.read_bytes(), options, providers=["CPUExecutionProvider"])
        worst = 0.0
        for seed, frames in enumerate(lengths, 1):
            x = _inputs(spec, frames, seed)
            with torch.no_grad():
                ref = reference(*x.values()).numpy()
            if not np.all(np.isfinite(ref)):
                raise InputError(f"{NOT_FINITE} (nothing written)", checkpoint_path(run))
            got = session.run(None, {k: v.numpy() for k, v in x.items()})[0]
            worst = max(worst, largest_difference(got, ref))
        if not worst <= tolerance:
            raise ExportFailed(
                f"{out}: onnxruntime differs from PyTorch by {worst:.3g} (> {tolerance:g}); nothing written"
            )
        put_in_place(tmp, out)
    except OSError as exc:
        raise write_error(exc, out, "the ONNX file") from None
    finally:
        with stops_deferred():  # a second Ctrl-C cuts no removal short
            tmp.unlink(missing_ok=True)
    longest = f"; at most {limit} frames per call (max_frames)" if limit else ""
    say(f"{out}: exported {payload['system']}, onnxruntime matches PyTorch within {worst:.2e}{longest}")
    return {
        "run": str(run),
        "onnx": str(out),
        "model": payload["system"],
        "max_abs_diff": worst,
        "checked_frames": list(lengths),
        "inputs": names,
        # the longest input the graph takes (Transformer-S2A's positional table); null: no limit
        "max_frames": limit,
        # the last len(styles) prosody columns: a one-hot of one of these speakers, or 1/n each (mean style)
        "styles": list(spec.styles),
        "metadata": sorted(onnx_metadata(payload, limit)),  # keys of the graph's metadata_props
    }


def onnx_metadata(payload: dict[str, Any], limit: int | None) -> dict[str, str]:
    """What a user of the graph needs beside it, each as a JSON string (``metadata_props`` hold text):
    the output's channel names in order, the frame rate, the inputs (which features, in which order, feed
    ``content`` and ``prosody``), the features' settings (``dataset.FeatureSettings.from_manifest`` reads
    this entry), and the normalisation statistics (``train.normalize_features`` reads the dict these sit
    in; ``animation`` de-normalises the output). Together they stand in for the dataset's manifest."""
    info = payload["dataset"]
    fields = {
        "system": payload["system"],
        "channels": list(info["channels"]),
        "fps": info["fps"],
        "inputs": payload["inputs"],
        "features": info["features"],
        "normalization": info["normalization"],
        "max_frames": limit,
    }
    return {key: json.dumps(value) for key, value in fields.items()}


def annotate(path: Path, payload: dict[str, Any], names: list[str], limit: int | None) -> None:
    """Write ``onnx_metadata`` and a doc string into the graph at ``path``, and fix the output's batch
    dimension at 1 as the inputs' is (the tracer leaves it a symbol, ``Whereanimation_dim_0``)."""
    import onnx

    with open(path, "rb") as f:
        graph = onnx.load(f)
    for key, value in onnx_metadata(payload, limit).items():
        graph.metadata_props.add(key=key, value=value)
    channels = len(payload["dataset"]["channels"])
    features = " and ".join(f"{n} (1, frames, dim) float32" for n in names if n != "mask")
    graph.doc_string = (
        f"s2a-toolkit speech-to-animation model ({payload['system']}) at {payload['dataset']['fps']:g} "
        f"frames per second. Inputs: {features} (features as metadata 'inputs' and 'features' say, "
        "normalised with metadata 'normalization'), mask (1, frames) bool. Output: animation "
        f"(1, frames, {channels}) float32 of the channels in metadata 'channels', normalised: "
        "de-normalise with metadata 'normalization' -> 'animation'."
    )
    batch = graph.graph.output[0].type.tensor_type.shape.dim[0]
    batch.ClearField("dim_param")
    batch.dim_value = 1
    with open(path, "wb") as f:
        onnx.save(graph, f)


def largest_difference(got: np.ndarray, ref: np.ndarray) -> float:
    """The largest absolute difference of two outputs; inf when either is not finite or their shapes
    differ (NaN against NaN is no match)."""
    got, ref = np.asarray(got, np.float64), np.asarray(ref, np.float64)
    if got.shape != ref.shape or not (np.all(np.isfinite(got)) and np.all(np.isfinite(ref))):
        return math.inf
    return float(np.abs(got - ref).max(initial=0.0))


def check_out(run: str | Path, out: Path) -> None:
    """Refuse an ONNX path that is a folder, the checkpoint being exported (symbolic links resolved), any
    other PyTorch checkpoint (``torch.save`` writes zip archives; ONNX files are protobuf), or a file of
    the run or of a dataset that is not an ONNX model (``_toolkit_folder``)."""
    if out.is_dir():
        raise InputError("output path is a folder: give the ONNX file to write", out)
    if not out.exists() or written_into(out):  # a pipe opened to read its first bytes waits for a writer
        return
    source = checkpoint_path(run)
    try:
        same = source.is_file() and os.path.samefile(source, out)
        with open(out, "rb") as f:
            head = f.read(4)
    except OSError:
        return  # unreadable: writing it fails with its own error
    if same:
        raise InputError(
            "output path is the checkpoint being exported: give another -o (e.g. model.onnx)", out
        )
    if head == ZIP_MAGIC:
        raise InputError(
            "output path is a PyTorch checkpoint (or another zip archive), not an ONNX file: "
            "give another -o (e.g. model.onnx)",
            out,
        )
    owner = _toolkit_folder(run, out)
    if owner is not None and head and not _holds_onnx(out, head):
        raise InputError(
            f"output path is a file of {owner}, not an ONNX model: it is never replaced (give another -o, "
            "e.g. model.onnx)",
            out,
        )


def _toolkit_folder(run: str | Path, out: Path) -> str | None:
    """What keeps ``out``'s folder when the toolkit does: "the run exported" (its folder or one inside it,
    an ensemble's members) or "a dataset" (a folder holding manifest.json); None otherwise. Files there
    (``-o RUN/config.json``, tab-completed; ``RUN/ensemble.json``; ``DS/manifest.json``) were replaced
    by the graph."""
    run = Path(run)
    try:
        # a checkpoint file given as the run: its folder when that is a run folder (it holds config.json)
        folder = run if run.is_dir() else run.parent if (run.parent / "config.json").is_file() else None
        folder = None if folder is None else folder.resolve()
        parent = out.resolve().parent
    except (OSError, RuntimeError):  # a symbolic link loop: writing names it
        return None
    if folder is not None and (parent == folder or folder in parent.parents):
        return "the run exported"
    if (parent / "manifest.json").is_file():
        return "a dataset"
    return None


def _holds_onnx(path: Path, head: bytes) -> bool:
    """Whether ``path`` (starting with ``head``) holds an ONNX model: a ``ModelProto`` with an IR version
    and a graph. Its first field, the IR version, makes it start with byte 0x08, so other files are
    never read whole."""
    if head[:1] != b"\x08":
        return False
    from google.protobuf.message import DecodeError
    from onnx import ModelProto

    model = ModelProto()
    try:
        model.ParseFromString(path.read_bytes())
    except (OSError, DecodeError):
        return False
    return model.ir_version > 0 and model.HasField("graph")


def _check_lengths(limit: int | None) -> tuple[int, int]:
    """Frame counts the graph is traced with and checked on: 200 and 457, within ``max_frames``."""
    short, long = 200, 457
    if limit is not None and limit < long:
        long = limit
        short = min(short, max(1, limit // 2))
    return short, long
