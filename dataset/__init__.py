"""dataset: aligned takes → features, normalisation, splits, checksummed WebDataset-layout shards,
manifest, validation and statistics. ``ShardDataset`` (PyTorch) lives in ``dataset.torch_dataset``
so that importing this package does not import torch."""

# capture, imported first, guards the imports of a stage command against Ctrl-C (capture.import_guard); the
# guard ends once the command's own module (cli.py) has imported, after this package's imports.
import capture.import_guard  # noqa: F401  # isort: skip

from .build import BuildOptions, build_dataset, collect_takes, plan_shards, take_sha256
from .features import DEFAULT_FEATURES, FEATURES, FeatureSettings, compute_features, parse_features
from .manifest import MANIFEST_FILE, read_manifest, write_manifest
from .normalize import ChannelAccumulator, FeatureNormalizer, Normalizer, fit_normalizer
from .pitch import PitchSettings, track_pitch
from .ppg import BACKENDS, PPGResult, make_extractor
from .qa import CHECKS, VALIDATORS, Problem, Report, validate
from .shards import ShardInfo, ShardReader, ShardWriter
from .splits import SPLITS, SplitRule, assign_splits
from .stats import dataset_stats

__all__ = [
    "BACKENDS",
    "BuildOptions",
    "CHECKS",
    "ChannelAccumulator",
    "DEFAULT_FEATURES",
    "FEATURES",
    "FeatureNormalizer",
    "FeatureSettings",
    "MANIFEST_FILE",
    "Normalizer",
    "PPGResult",
    "PitchSettings",
    "Problem",
    "Report",
    "SPLITS",
    "ShardInfo",
    "ShardReader",
    "ShardWriter",
    "SplitRule",
    "VALIDATORS",
    "assign_splits",
    "build_dataset",
    "collect_takes",
    "compute_features",
    "dataset_stats",
    "fit_normalizer",
    "make_extractor",
    "parse_features",
    "plan_shards",
    "read_manifest",
    "take_sha256",
    "track_pitch",
    "validate",
    "write_manifest",
]
