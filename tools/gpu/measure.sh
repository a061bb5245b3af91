#!/usr/bin/env bash
# The GPU sweep's figures for docs/benchmarks.md (issue 39), as one prepared run on a machine
# with a GPU: the adapter, then beside the CPU sweep on the same machine's cores
#   1. the six real-DEM 256² blocks and the peers' 1024² DEM whole (360 azimuths, the whole map
#      as context): `penumbra-bench sweep --device gpu`;
#   2. the whole Moon at LDEM_4 (default tiles, every level, 360 azimuths, into Fourier
#      pyramids): `penumbra horizon --fourier --device gpu` against `--device cpu`, GNU time;
#   3. the Mars 800 m/px (and lunar south pole 5 m/px) extrapolation: a 512² tile with its
#      context and far rings, the sweep's own horizons on the GPU, the rings on the CPU
#      (`penumbra-bench far-field --extrapolate --device gpu`).
# Usage: tools/gpu/measure.sh [SHARED_DATA] [PEERS_WORK]  (run from the repository root).
set -euo pipefail
data="${1:-../shared/data}"
peers="${2:-../peers-work}"
out="${OUT:-target/gpu-measure}"
mkdir -p "$out"
cargo build --release --locked -p penumbra-cli --features penumbra-cli/gpu -p penumbra-bench
bin=target/release
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv | tee "$out/adapter.txt"
echo "== bench sweep (blocks, and the 1024² DEM whole when $peers/data/dem1024.npy is there)"
"$bin/penumbra-bench" sweep --data "$data" --peers "$peers" --skip-fast --device gpu \
    --whole-azimuths 360 | tee "$out/sweep.md"
echo "== whole Moon, LDEM_4"
rm -rf "$out/ldem4"
"$bin/penumbra" --quiet tile "$data/lola_ldem4/LDEM_4.LBL" --out "$out/ldem4" >/dev/null
for dev in gpu cpu; do
    rm -rf "$out/ldem4/fourier" "$out/ldem4/horizon"
    /usr/bin/time -f "$dev: %e s wall, %M KiB peak RSS" \
        "$bin/penumbra" --quiet horizon "$out/ldem4" --fourier --device "$dev" --json \
        > "$out/ldem4-$dev.json" 2> >(tee "$out/ldem4-$dev.time" >&2)
done
echo "== Mars 800 m/px and the lunar south pole, extrapolated"
"$bin/penumbra-bench" far-field --extrapolate --azimuths 36 --device gpu --markdown | tee "$out/extrapolate.md"
