"""``make bench``: run every benchmark module, print each figure beside its reference, and write
``benchmarks/results.json``. ``--quick`` uses smaller inputs; ``-k NAME`` runs matching modules only."""

from __future__ import annotations

import argparse
import importlib
import json
import pkgutil
import platform
import sys
import time
from pathlib import Path

import benchmarks


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks")
    parser.add_argument("--quick", action="store_true", help="smaller inputs, for a smoke run")
    parser.add_argument("-k", dest="only", default="", help="run modules whose name contains this")
    parser.add_argument("-o", "--out", type=Path, default=Path(__file__).with_name("results.json"))
    args = parser.parse_args()
    names = sorted(
        m.name
        for m in pkgutil.iter_modules(benchmarks.__path__)
        if m.name.startswith("bench_") and args.only in m.name
    )
    results = []
    failed = 0
    for name in names:
        module = importlib.import_module(f"benchmarks.{name}")
        print(f"== {name}: {(module.__doc__ or '').strip().splitlines()[0]}", flush=True)
        t0 = time.perf_counter()
        for fig in module.run(quick=args.quick):
            print("  " + fig.line(), flush=True)
            results.append(fig.to_json() | {"module": name})
            failed += fig.passed is False
        print(f"   ({time.perf_counter() - t0:.1f} s)", flush=True)
    report = {
        "machine": {"python": sys.version.split()[0], "platform": platform.platform()},
        "quick": args.quick,
        "figures": results,
    }
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"{len(results)} figures, {failed} below target; written to {args.out}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
