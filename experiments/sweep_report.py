"""Rebuild a push sweep's report (plots, tables) from its run directory.

jaxloco sweep-report outputs/2026-11-23/10-00-00
"""

import argparse
import sys

from jaxloco.runtime import configure
from jaxloco.sweep import write_report


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="jaxloco sweep-report", description=__doc__)
    parser.add_argument("run_dir", help="a push-sweep run directory (holds manifest.json)")
    parser.add_argument("--dpi", type=int, default=120)
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        summary = write_report(args.run_dir, dpi=args.dpi)
    except (FileNotFoundError, ValueError) as err:
        raise SystemExit(f"jaxloco sweep-report: {err}") from None
    for name, v in summary["variants"].items():
        print(f"{name}: recovered {v['recovered']}/{v['pushes']} ({v['success_rate']:.0%})")
    print(f"report written to {args.run_dir}/summary.md")


if __name__ == "__main__":
    configure()
    main()
