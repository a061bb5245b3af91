#!/usr/bin/env bash
# Render a Celestia addon with an installed, stock Celestia under Xvfb + Mesa and save a
# screenshot of its window as a PNG. Builds nothing.
#
#   CELESTIA=/path/to/bin/celestia tools/celestia/render.sh ADDON|- OUT.png [options]
#
# ADDON is a folder `penumbra package` / `package::celestia::write_addon` wrote ("-": none, the
# stock body). Options (defaults in brackets):
#   --body PATH        the body Celestia selects             ["Sol/Earth/Moon"]
#   --lon DEG --lat DEG  the point the camera is above        [0 0]
#   --distance RADII   camera distance from the body's centre, in body radii (CEL gotolonglat) [3]
#   --jd JD            the simulation time, Julian date TDB (sets the Sun) [2460332.0]
#   --surface NAME     show alternate surface NAME (CEL setsurface), e.g. Penumbra
#   --fov DEG          vertical field of view                [30]
#   --size WxH         window and screenshot size           [800x600]
#   --ambient X        ambient light level 0..1              [0]
#   --settle S         seconds the script waits for the window's size before it moves [4]
#   --timeout S        seconds to wait for the frames to stop changing [120]
#   --cel 'COMMANDS'   extra CEL commands run after the move (e.g. 'orbit { ... }')
#
# Written for Celestia 1.6's GLUT front end, which reads the celestia.cfg of the data folder it
# was built with (it changes into it at start): the addon is linked into that folder's
# extras/ for the run and unlinked after. CELESTIA_DATA names that folder
# [$(dirname $CELESTIA)/../share/celestia]. Needs Xvfb, xdotool and ImageMagick; Mesa's software
# renderer is forced (LIBGL_ALWAYS_SOFTWARE=1).
#
# Timing: a CEL `wait` is counted in frame time, and one slow frame (virtual-texture tiles load
# inside a frame, on a software renderer) runs through several commands at once. So the script
# (view.cel.in) only sets the view and drops a marker capture; this script then grabs the window
# once a second and keeps the first frame that equals the one before it (all tiles loaded).
set -euo pipefail

die() { echo "render.sh: $*" >&2; exit 2; }
[ $# -ge 2 ] || die "usage: CELESTIA=/path/to/celestia $0 ADDON|- OUT.png [--lon DEG --lat DEG --distance RADII --jd JD --surface NAME --fov DEG --size WxH --ambient X --settle S --timeout S --cel CMDS]"
addon=$1 out=$2; shift 2
body="Sol/Earth/Moon" lon=0 lat=0 distance=3 jd=2460332.0 surface="" fov=30 size=800x600
ambient=0 settle=4 timeout=120 extra=""
while [ $# -gt 0 ]; do
  [ $# -ge 2 ] || die "option $1 needs a value"
  case $1 in
    --body) body=$2 ;; --lon) lon=$2 ;; --lat) lat=$2 ;; --distance) distance=$2 ;;
    --jd) jd=$2 ;; --surface) surface=$2 ;; --fov) fov=$2 ;; --size) size=$2 ;;
    --ambient) ambient=$2 ;; --settle) settle=$2 ;; --timeout) timeout=$2 ;; --cel) extra=$2 ;;
    *) die "unknown option '$1'" ;;
  esac
  shift 2
done
for v in lon lat distance jd fov ambient settle timeout; do
  [[ ${!v} =~ ^-?[0-9]+(\.[0-9]+)?$ ]] || die "--$v '${!v}' is not a number"
done
[[ $size =~ ^([0-9]+)x([0-9]+)$ ]] || die "--size '$size' is not WxH (such as 800x600)"
width=${BASH_REMATCH[1]} height=${BASH_REMATCH[2]}
[[ $surface =~ ^[A-Za-z0-9_\ -]*$ ]] || die "--surface '$surface': letters, digits, ' ', '_', '-' only"

[ -n "${CELESTIA:-}" ] || die "set CELESTIA to an installed celestia binary (this script builds nothing)"
[ -x "$CELESTIA" ] || die "CELESTIA='$CELESTIA' is not an executable file"
data=${CELESTIA_DATA:-$(dirname "$CELESTIA")/../share/celestia}
[ -f "$data/celestia.cfg" ] || die "no celestia.cfg in '$data': set CELESTIA_DATA to the data folder Celestia was built with"
[ -d "$data/extras" ] || die "'$data/extras' is not a folder (celestia.cfg's ExtrasDirectories)"
command -v Xvfb >/dev/null || die "Xvfb is not installed (Debian: apt-get install xvfb)"
command -v xdotool >/dev/null || die "xdotool is not installed (Debian: apt-get install xdotool)"

here=$(cd "$(dirname "$0")" && pwd)
out_abs=$(cd "$(dirname "$out")" && pwd)/$(basename "$out")
[[ $out_abs == *.png ]] || die "OUT '$out' must end in .png"
rm -f "$out_abs"

work=$(mktemp -d)
link=""
xvfb_pid="" cel_pid=""
cleanup() {
  [ -n "$cel_pid" ] && kill "$cel_pid" 2>/dev/null || true
  [ -n "$xvfb_pid" ] && kill "$xvfb_pid" 2>/dev/null || true
  [ -n "$link" ] && rm -f "$link"
  rm -rf "$work"
}
trap cleanup EXIT

if [ "$addon" != "-" ]; then
  [ -d "$addon" ] || die "ADDON '$addon' is not a folder"
  ls "$addon"/*.ssc >/dev/null 2>&1 || die "ADDON '$addon' holds no .ssc catalog"
  link="$data/extras/penumbra-render-$$"
  ln -s "$(cd "$addon" && pwd)" "$link"
fi

surface_cmd=""
[ -n "$surface" ] && surface_cmd="setsurface { name \"$surface\" }"
sed -e "s|@SETTLE@|$settle|; s|@AMBIENT@|$ambient|; s|@JD@|$jd|; s|@BODY@|$body|" \
    -e "s|@SURFACE_CMD@|$surface_cmd|; s|@DISTANCE@|$distance|; s|@LON@|$lon|; s|@LAT@|$lat|" \
    -e "s|@FOV@|$fov|; s|@MARKER@|$work/marker.png|" \
    "$here/view.cel.in" > "$work/view.cel"
printf '%s\n' "$extra" > "$work/extra.cel"
sed -i -e "/@EXTRA@/{r $work/extra.cel" -e 'd}' "$work/view.cel"

Xvfb -displayfd 3 -screen 0 "${width}x${height}x24" -nolisten tcp 3>"$work/display" 2>"$work/xvfb.log" &
xvfb_pid=$!
for _ in $(seq 100); do [ -s "$work/display" ] && break; sleep 0.1; done
[ -s "$work/display" ] || die "Xvfb did not start: $(cat "$work/xvfb.log")"
export DISPLAY=:$(cat "$work/display")
export LIBGL_ALWAYS_SOFTWARE=1

"$CELESTIA" -f "$work/view.cel" >"$work/celestia.log" 2>&1 &
cel_pid=$!
win=$(timeout 60 xdotool search --sync --name '^Celestia$' | head -n1) || die "no Celestia window appeared: $(tail -5 "$work/celestia.log")"
xdotool windowmove "$win" 0 0 windowsize "$win" "$width" "$height"
alive() { kill -0 "$cel_pid" 2>/dev/null || die "Celestia exited early: $(tail -5 "$work/celestia.log")"; }
got=""
for _ in $(seq $((timeout * 10))); do
  # The marker is complete once it parses (Celestia may still be writing it).
  got=$(identify -format '%wx%h' "$work/marker.png" 2>/dev/null) && break
  alive; sleep 0.1
done
[ -n "$got" ] || die "the start script did not reach its view within $timeout s"
[ "$got" = "${width}x${height}" ] || die "the window was ${got}, not ${width}x${height}, when the view was set: give a longer --settle"
prev="" frame=0 start=$SECONDS
while :; do
  sleep 1; alive
  frame=$((frame + 1))
  import -window "$win" "$work/frame$frame.png"
  sum=$(convert "$work/frame$frame.png" rgb:- | md5sum)
  [ "$sum" = "$prev" ] && [ $frame -ge 3 ] && break
  prev=$sum
  [ $((SECONDS - start)) -lt "$timeout" ] || die "frames still change after $timeout s"
done
cp "$work/frame$frame.png" "$out_abs"
kill "$cel_pid" 2>/dev/null || true
cel_pid=""
grep -i -E 'error|cannot|failed' "$work/celestia.log" >&2 || true
echo "$out_abs"
