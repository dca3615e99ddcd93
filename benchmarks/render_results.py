"""Render RESULTS.md from the benchmarks' latest JSON.

    python benchmarks/render_results.py [--results DIR] [--out RESULTS.md]

Reads every ``bench_*.json`` in ``DIR`` (``make bench`` writes them to
``benchmarks/results/``) and writes, per benchmark, its machine, date and commit, its
targets (measured value, target, met or not) and the tables it printed. A benchmark written
before it recorded tables is rendered from its lists of rows.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _cell(value) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value).replace("|", "\\|")


def _markdown_table(headers: list[str], rows: list[list]) -> list[str]:
    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return lines


def render_benchmark(result: dict) -> list[str]:
    """One benchmark's section of RESULTS.md."""
    m = result.get("machine", {})
    lines = [
        f"## {result.get('benchmark', '?')}",
        "",
        f"{m.get('cpu', '?')}, {m.get('cores', '?')} cores, {m.get('backend', '?')}; "
        f"jax {m.get('jax', '?')}, mujoco {m.get('mujoco', '?')}; "
        f"{result.get('date') or 'date not recorded'}; "
        f"commit {result.get('commit') or 'not recorded'}"
        + ("; `--quick`" if result.get("quick") else ""),
        "",
    ]
    targets = result.get("targets") or []
    if isinstance(targets, list) and targets:
        lines += _markdown_table(
            ["target", "measured", "required", "met"],
            [
                [
                    t["name"],
                    "-" if t["measured"] is None else t["measured"],
                    t["target"].strip(),
                    "yes" if t["met"] else "**no**",
                ]
                for t in targets
            ],
        )
        lines.append("")
    tables = result.get("tables") or []
    if tables:
        for table in tables:
            lines += [f"**{table['title']}**", ""]
            lines += _markdown_table(table["headers"], table["rows"])
            lines.append("")
    else:
        for key, value in result.items():
            if isinstance(value, list) and value and all(isinstance(r, dict) for r in value):
                headers = list(dict.fromkeys(k for r in value for k in r))
                lines += [f"**{key}**", ""]
                lines += _markdown_table(headers, [[r.get(h, "") for h in headers] for r in value])
                lines.append("")
    return lines


def render(results_dir: Path) -> str:
    files = sorted(results_dir.glob("bench_*.json"))
    if not files:
        raise SystemExit(f"render_results: no bench_*.json in {results_dir}")
    lines = [
        "# Benchmark results",
        "",
        "Rendered by `benchmarks/render_results.py` from the JSON in "
        f"`{results_dir.relative_to(ROOT) if results_dir.is_relative_to(ROOT) else results_dir}`"
        " (`make bench` writes it); do not edit by hand. Times are medians unless a table "
        "says otherwise.",
        "",
    ]
    for f in files:
        lines += render_benchmark(json.loads(f.read_text()))
    return "\n".join(lines).rstrip() + "\n"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results")
    parser.add_argument("--out", type=Path, default=ROOT / "RESULTS.md")
    args = parser.parse_args()
    args.out.write_text(render(args.results.resolve()))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
