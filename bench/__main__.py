"""python -m bench [--out DIR] [--only NAME] [--quick]"""

from __future__ import annotations

import argparse
import importlib
import json
import pkgutil
import platform
import time
from pathlib import Path

import pandas as pd

import bench


def machine() -> dict[str, object]:
    import os

    import numpy
    import pyarrow

    return {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "cpus": os.cpu_count(),
        "numpy": numpy.__version__,
        "pyarrow": pyarrow.__version__,
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, default=Path("out/bench"))
    parser.add_argument("--only", action="append", default=[])
    parser.add_argument("--quick", action="store_true", help="smaller inputs, for a smoke run")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    results: dict[str, object] = {"machine": machine()}
    modules = [m.name for m in pkgutil.iter_modules(bench.__path__) if m.name.startswith("bench_")]
    for name in sorted(modules):
        if args.only and not any(o in name for o in args.only):
            continue
        module = importlib.import_module(f"bench.{name}")
        print(f"== {name}: {(module.__doc__ or '').strip().splitlines()[0]}", flush=True)
        rows = module.run(args.out, args.quick)
        frame = pd.DataFrame(rows)
        frame.to_csv(args.out / f"{name}.csv", index=False)
        print(frame.to_string(index=False), flush=True)
        results[name] = rows
    (args.out / "results.json").write_text(json.dumps(results, indent=2, default=str))
    print(f"results in {args.out}/")


if __name__ == "__main__":
    main()
