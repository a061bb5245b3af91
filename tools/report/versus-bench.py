#!/usr/bin/env python3
"""A `penumbra report` of a shared DEM against the benchmarks' figures for it (docs/report.md,
"Against the benchmarks").

usage: versus-bench.py REPORT.json CASE   (CASE as the benches name it, e.g. "LDEM_4 (Moon)")

The benchmarks measure one block of the DEM; the report, many blocks over the tileset. The
report's figure is a mean over blocks with standard error SE (the spread between blocks over
√blocks); one block's figure scatters about the DEM's mean by the spread between blocks,
sd = SE·√blocks, which is the benchmark's sampling error as an estimate of that mean. The two
agree when |report − bench| ≤ 2·√(SE² + sd²); where the report saw no event at all (a PER of
0 in n answers, whose SE is 0), the rule of three bounds it instead: 300/n %. Prints a Markdown
table."""
import json
import math
import re
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parents[2] / "docs"


def bench_rows(md, case, ncol_name):
    """Rows of a docs table whose first cell is `case`, keyed by the second cell."""
    rows = {}
    for line in (DOCS / md).read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) > ncol_name and cells[0] == case:
            rows.setdefault(cells[1].strip("*"), cells)
    return rows


def num(cell):
    return float(re.sub(r"[^0-9.eE+-]", "", cell))


def main():
    report = json.loads(Path(sys.argv[1]).read_text())
    case = sys.argv[2]
    nb = len(report["blocks"])
    out = ["| product | row | quantity | benchmark (one block) | report (± SE, "
           f"{nb} blocks) | sd between blocks | agree |", "|---|---|---|---:|---:|---:|---|"]
    fb = bench_rows("fourier-bench.md", case, 12)
    # docs/fourier-bench.md columns: case, variant, bytes, µs, share, RMS, p99, max, PER 1°,
    # 5°, 15°, PER all, lit MAE, lit MAE constant.
    for f in report["fourier"]:
        b = fb.get(f["variant"])
        if not b:
            continue
        for q, bi, v, se in [("PER %", 11, f["per_pct"], f["se_per_pct"]),
                             ("lit MAE", 12, f["lit_mae"], f["se_lit_mae"])]:
            out.append(row("storage", f["variant"], q, num(b[bi]), v, se, nb, None))
    sb = bench_rows("shadows.md", case, 5)
    # docs/shadows.md columns: case, method, lit MAE, PER, max, ms/Mpx.
    for s in report["shadows"][1:]:
        b = sb.get(s["method"])
        if not b:
            continue
        for q, bi, v, se in [("lit MAE", 2, s["lit_mae"], s["se_lit_mae"]),
                             ("PER %", 3, s["per_pct"], s["se_per_pct"])]:
            n = s["samples"] if q == "PER %" else None
            out.append(row("shadow", s["method"], q, num(b[bi]), v, se, nb, n))
    print("\n".join(out))


def row(product, name, q, bench, v, se, nb, n):
    se = se or 0.0
    sd = se * math.sqrt(nb)
    tol = 2 * math.sqrt(se * se + sd * sd)
    if n and v == 0.0:
        tol = max(tol, 300.0 / n)
    ok = abs(v - bench) <= tol
    return (f"| {product} | {name} | {q} | {bench:.4g} | {v:.4g} ± {se:.2g} | {sd:.2g} | "
            f"{'yes' if ok else '**no**'} |")


if __name__ == "__main__":
    main()
