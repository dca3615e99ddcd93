"""Compare limit searches per direction (e.g. the same search at two torque bounds).

jaxloco limits-compare outputs/bound_500 outputs/model_limits --labels "500 N m" "model" \
    --out outputs/limits_compared

Each run directory holds a limit search's ``summary.json`` (``jaxloco push-sweep``); writes
``comparison.md``, ``comparison.json`` and ``comparison_polar.png`` into ``--out``.
"""

import argparse
import json
import sys
from pathlib import Path

from jaxloco.sweep.limits_report import write_limits_comparison


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="jaxloco limits-compare", description=__doc__)
    parser.add_argument("run_dirs", nargs="+", help="limit-search run directories (2 or more)")
    parser.add_argument("--labels", nargs="+", help="one label per run (default: folder names)")
    parser.add_argument("--out", required=True, help="folder for the comparison")
    parser.add_argument("--dpi", type=int, default=120)
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    labels = args.labels or [Path(d).name for d in args.run_dirs]
    if len(labels) != len(args.run_dirs) or len(set(labels)) != len(labels):
        raise SystemExit("jaxloco limits-compare: --labels needs one distinct label per run")
    summaries = {}
    for label, run_dir in zip(labels, args.run_dirs, strict=True):
        path = Path(run_dir) / "summary.json"
        if not path.is_file():
            raise SystemExit(f"jaxloco limits-compare: no limit search summary at {path}")
        summaries[label] = json.loads(path.read_text())
    try:
        cmp = write_limits_comparison(summaries, args.out, dpi=args.dpi)
    except ValueError as err:
        raise SystemExit(f"jaxloco limits-compare: {err}") from None
    for name, v in cmp["variants"].items():
        medians = ", ".join(f"{lb}: {m:g}" for lb, m in v["median_limit_Ns"].items())
        print(f"{name}: median limit (N s) {medians}")
    print(f"comparison written to {Path(args.out) / 'comparison.md'}")


if __name__ == "__main__":
    main()
