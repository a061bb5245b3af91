#!/usr/bin/env bash
# The cost of the viewer's shadows per method and frame size (issue 40), as one prepared run:
# for each method and size, `penumbra-view --headless --json` renders the polar grazing frame of
# docs/viewer.md with and without shadows (the report's `shadow_overhead_ms`: median GPU time
# per frame with shadows minus without), and `--validate` checks it against its CPU twin; a
# markdown table on stdout, the JSON reports and frames under $OUT.
#
# Usage (from the repository root):
#   tools/viewer/measure.sh [TILESET] [FRAMES] [SIZES...]
# TILESET defaults to the embedded scene baked as docs/viewer.md's table bakes it (1024² px at
# 20 m, 64-px tiles, Fourier pyramids at level 9) under $OUT; FRAMES (5) frames are timed per
# run; SIZES default to 512x384 512x512 1920x1080. VIEW and PENUMBRA name the binaries (release
# builds by default; `cargo build --release -p penumbra-viewer -p penumbra-cli` first).
set -euo pipefail
out="${OUT:-target/viewer-measure}"
view="${VIEW:-target/release/penumbra-view}"
pen="${PENUMBRA:-target/release/penumbra}"
dir="${1:-$out/scene}"
frames="${2:-5}"
shift 2 2>/dev/null || shift $#
sizes=("$@")
[ ${#sizes[@]} -gt 0 ] || sizes=(512x384 512x512 1920x1080)
mkdir -p "$out"
if [ ! -e "$dir/tileset.json" ] && [ "$dir" = "$out/scene" ]; then
    "$pen" --quiet bake --out "$dir" --scene-size 1024 --tile-size 64 --levels 10 --horizon-levels 9
fi
camera=(--camera=-89.8,30,9000,210,-60,50 --sun-lat=-2.5 --sun-lon 75)
# METHODS="dp;uniform;uniform 400;fourier constant" picks some (dp and uniform, 100 steps, are
# needed for the ratios); a second word is fourier's model, uniform's steps or dp's levels.
IFS=';' read -r -a methods <<<"${METHODS:-dp;dp-jung;uniform;uniform 400;extrema;extrema-soft;fourier constant;fourier segment;fourier exact}"
# RUNS=3 renders every (size, method) that many times, interleaved (run 1 of every method,
# then run 2, ...): the table's cost is the median of the runs' medians, with their range.
runs="${RUNS:-1}"
for r in $(seq 1 "$runs"); do
for size in "${sizes[@]}"; do
    for m in "${methods[@]}"; do
        set -- $m
        args=(--method "$1")
        if [ $# -gt 1 ]; then
            case "$1" in
                fourier) args+=(--fourier-model "$2") ;;
                uniform) args+=(--steps "$2") ;;
                *) args+=(--dp-levels "$2") ;;
            esac
        fi
        tag="${m// /-}-$size"
        [ "$r" -gt 1 ] && tag="$tag-run$r"
        echo "+ $tag" >&2
        "$view" "$dir" --headless "${camera[@]}" "${args[@]}" --size "$size" --frames "$frames" \
            --validate --out "$out/$tag.png" --json >"$out/$tag.json"
    done
done
done
tags=$(printf '%s;' "${methods[@]}")
python3 - "$out" "$runs" "${tags// /-}" "${sizes[@]}" <<'PY'
import json, sys, os, statistics
out, runs, tags, sizes = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4:]
methods = [t for t in tags.split(";") if t]
adapter = None
print(f"| size | method | frame ms | without shadows ms | shadow cost ms (median of {runs} run(s); range) | ÷ dp's cost | ÷ uniform's cost | vs CPU twin: mean abs, PER | vs reference: mean abs | penumbra vs reference: mean abs (pixels) | vs exact disc model: mean abs |")
print("|---|---|---:|---:|---:|---:|---:|---|---:|---:|---:|")
for size in sizes:
    rep = {m: json.load(open(os.path.join(out, f"{m}-{size}.json"))) for m in methods}
    def load(m, r):
        return json.load(open(os.path.join(out, f"{m}-{size}" + (f"-run{r}" if r > 1 else "") + ".json")))
    all_costs = {m: [load(m, r)["timings"]["shadow_overhead_ms"] for r in range(1, runs + 1)] for m in methods}
    cost = {m: statistics.median(c) for m, c in all_costs.items()}
    for m in methods:
        r = rep[m]; t = r["timings"]; v = r["validation"]
        adapter = r["adapter"]
        frame = t["gpu_ms_median"] if t["gpu_ms_median"] is not None else t["wall_ms_median"]
        base = t["no_shadows"]["gpu_ms_median"] if t["no_shadows"]["gpu_ms_median"] is not None else t["no_shadows"]["wall_ms_median"]
        print(f"| {size} | {r['method']} | {frame:.2f} | {base:.2f} | {cost[m]:.2f} ({min(all_costs[m]):.1f}–{max(all_costs[m]):.1f}) | {cost[m]/cost['dp']:.2f} | {cost[m]/cost['uniform']:.2f} | "
              f"{v['same']['mean_abs']:.5f}, {v['same']['per_percent']:.3f} % | {v['reference']['mean_abs']:.4f} | "
              f"{v['penumbra']['reference']['mean_abs']:.4f} ({v['penumbra']['pixels']}) | "
              f"{'%.5f' % v['exact_model']['mean_abs'] if v.get('exact_model') else '–'} |")
print()
print(f"Adapter: {adapter['name']} ({adapter['backend']}, {adapter['device_type']}, driver {adapter['driver']}); "
      f"times from {'GPU timestamp queries' if adapter['timestamps'] else 'the wall clock'}.")
PY
