#!/usr/bin/env bash
# Byte-identity check for refactors: runs the main job on the embedded scene and tile + mip +
# horizon (one level, 36 azimuths) on LDEM_4 and the Gale DEM, and hashes every output file.
#
#   tools/golden/run.sh record   # write tools/golden/hashes.txt (before a refactor)
#   tools/golden/run.sh check    # compare against it (after); exit 1 on any difference
#
# Uses target/release/penumbra (built here), or the binary named by PENUMBRA_BIN (CI passes the
# debug build its tests made: the outputs are the same bytes whatever the optimisation level,
# and that saves CI a release build of every crate), and ../shared/data. A tileset's manifest
# records the source paths it was given, so the script always runs from the repository root
# with the same relative paths. The bookkeeping folder .penumbra/ (locks, indexes) is not output
# and is left out.
set -euo pipefail
cd "$(dirname "$0")/../.."
mode=${1:-check}
data=../shared/data
bin=${PENUMBRA_BIN:-target/release/penumbra}
if [ -z "${PENUMBRA_BIN:-}" ]; then
  cargo build --release --locked --quiet -p penumbra-cli
elif [ ! -x "$bin" ]; then
  echo "golden: PENUMBRA_BIN=$bin is not an executable; build it first (cargo build -p penumbra-cli)" >&2
  exit 2
fi
work=target/golden
rm -rf "$work"
mkdir -p "$work"
run() { echo "+ $*" >&2; "$bin" --quiet "$@" >/dev/null; }

run bake --out "$work/scene"
run tile "$data/lola_ldem4/LDEM_4.LBL" --out "$work/ldem4" --tile-size 128
run mip "$work/ldem4"
run horizon "$work/ldem4" --levels 1 --azimuths 36
run tile "$data/mola_gale_128ppd_crop/gale-mola.bin" --body mars --out "$work/gale" --tile-size 256
run mip "$work/gale"
run horizon "$work/gale" --levels 3 --azimuths 36

hashes=$(cd "$work" && find . -type f -not -path '*/.penumbra/*' | LC_ALL=C sort | xargs sha256sum)
case "$mode" in
  record) echo "$hashes" >tools/golden/hashes.txt; echo "recorded $(echo "$hashes" | wc -l) files" ;;
  check)
    if diff <(echo "$hashes") tools/golden/hashes.txt >"$work/diff.txt"; then
      echo "golden: $(echo "$hashes" | wc -l) files byte-identical"
    else
      echo "golden: outputs differ from tools/golden/hashes.txt:"; cat "$work/diff.txt"; exit 1
    fi ;;
  *) echo "usage: $0 record|check" >&2; exit 2 ;;
esac
