"""The choices ``s2a-train`` offers that need no PyTorch to name: its command line imports this, not the
modules that use them, so that ``--help`` and usage errors answer at once."""

PRECISIONS = ("fp32", "bf16")  # inference arithmetic (train.precision)
