"""dataset: aligned takes → features, normalisation, splits, checksummed WebDataset-layout shards,
manifest, validation and statistics. ``ShardDataset`` (PyTorch) lives in ``dataset.torch_dataset``
so that importing this package does not import torch."""

# capture, imported first, guards the imports of a stage command against Ctrl-C (capture.import_guard); the
# guard ends once the command's own module (cli.py) has imported, after the modules it imports.
import capture.import_guard  # noqa: F401  # isort: skip

from capture.lazy_package import lazy_package

# The names below are imported on first use (PEP 562): a DataLoader worker started by "spawn" or
# "forkserver" imports dataset.torch_dataset, and with an eager package it paid for the build, its
# features, PPG and pitch tracking and the validator too. s2a-dataset's cli.py imports what it needs
# itself, under the guard.
__all__ = lazy_package(
    __name__,
    {
        "BuildOptions": "build",
        "build_dataset": "build",
        "collect_takes": "build",
        "plan_shards": "build",
        "take_sha256": "build",
        "DEFAULT_FEATURES": "features",
        "FEATURES": "features",
        "FeatureSettings": "features",
        "compute_features": "features",
        "parse_features": "features",
        "MANIFEST_FILE": "manifest",
        "read_manifest": "manifest",
        "write_manifest": "manifest",
        "ChannelAccumulator": "normalize",
        "FeatureNormalizer": "normalize",
        "Normalizer": "normalize",
        "fit_normalizer": "normalize",
        "PitchSettings": "pitch",
        "track_pitch": "pitch",
        "BACKENDS": "ppg",
        "PPGResult": "ppg",
        "make_extractor": "ppg",
        "CHECKS": "qa",
        "VALIDATORS": "qa",
        "Problem": "qa",
        "Report": "qa",
        "validate": "qa",
        "ShardInfo": "shards",
        "ShardReader": "shards",
        "ShardWriter": "shards",
        "SPLITS": "splits",
        "SplitRule": "splits",
        "assign_splits": "splits",
        "dataset_stats": "stats",
    },
)
