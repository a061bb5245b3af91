#!/usr/bin/env bash
# Scaling of a scene's bake under Slurm (docs/cluster.md, "Scaling measured"):
#   tools/slurm-scaling.sh PENUMBRA SCENE [N ...]      (default N: 1 2 4; repeats allowed)
# starts a single-node Slurm cluster in a temp folder (as tests/slurm.rs does: munged,
# slurmctld, slurmd, free ports, stopped by their pid files), bakes SCENE once in one process
# (`--threads 1`, GNU time: wall and peak RSS), then for each N writes `plan --slurm --shards N
# --cpus-per-task 1`, runs its submit.sh, waits for the chain, checks the tileset is the
# single bake's byte for byte, and prints one row: the chain's wall time (submission to the last
# job's end), the horizon array's (first task's start to last task's end), the finishes', and
# the horizon shards' measured slowest ÷ mean (their `wall_s`) against the plan's.
# The node is declared with twice this host's CPUs (config_overrides), so that N = 2 × cores
# tasks of one CPU run at once: they oversubscribe the cores, as the row says.
# Needs root, slurm-wlm and munge. Run it on a quiet host.
set -euo pipefail
pen=$(realpath "$1")
scene=$(realpath "$2")
shift 2
ns=("$@")
[ ${#ns[@]} -gt 0 ] || ns=(1 2 4)

D=$(mktemp -d /tmp/pscale.XXXXXX)
stop() {
  SLURM_CONF=$D/slurm.conf scancel --user=root 2>/dev/null || true
  for p in slurmd slurmctld munged; do
    [ -f "$D/$p.pid" ] && kill "$(cat "$D/$p.pid")" 2>/dev/null || true
  done
  sleep 1
  rm -rf "$D"
}
trap stop EXIT
head -c 1024 /dev/urandom >"$D/munge.key"
chmod 400 "$D/munge.key"
munged --key-file="$D/munge.key" --socket="$D/munge.sock" --pid-file="$D/munged.pid" \
  --log-file="$D/munged.log" --seed-file="$D/munged.seed" -f
port() { python3 -c 'import socket; s=socket.socket(); s.bind(("",0)); print(s.getsockname()[1])'; }
host=$(hostname -s)
mkdir "$D/state" "$D/spool"
cat >"$D/slurm.conf" <<EOF
ClusterName=penumbrascale
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$D/munge.sock,cred_expire=5
CredType=cred/munge
StateSaveLocation=$D/state
SlurmdSpoolDir=$D/spool
SlurmctldPidFile=$D/slurmctld.pid
SlurmdPidFile=$D/slurmd.pid
SlurmctldLogFile=$D/slurmctld.log
SlurmdLogFile=$D/slurmd.log
SlurmctldPort=$(port)
SlurmdPort=$(port)
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
MinJobAge=3600
SlurmdParameters=config_overrides
NodeName=$host CPUs=$((2 * $(nproc))) RealMemory=$(awk '/MemTotal/{print int($2/1024)}' /proc/meminfo) State=UNKNOWN
PartitionName=scale Nodes=ALL Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF=$D/slurm.conf
slurmctld -f "$SLURM_CONF"
slurmd -f "$SLURM_CONF"
until [ "$(sinfo -h -o %T 2>/dev/null)" = idle ]; do sleep 0.2; done

echo "== one process, --threads 1: $pen bake $scene"
/usr/bin/time -f 'single: wall %e s, user %U s, sys %S s, peak RSS %M KiB' \
  "$pen" --quiet --threads 1 bake "$scene" --out "$D/single" >/dev/null

echo "| N | chain wall s | horizon array wall s | horizon shards wall_s (each) | finishes s | finishes' share | measured slowest ÷ mean | plan's slowest ÷ mean |"
echo "|---:|---:|---:|---|---:|---:|---:|---:|"
k=0
for n in "${ns[@]}"; do
  k=$((k + 1))
  plan=$D/plan-$k
  "$pen" --quiet plan "$scene" --slurm "$plan" --out "$D/tiles-$k" --shards "$n" \
    --cpus-per-task 1 >/dev/null
  predicted=$("$pen" --quiet plan "$scene" --shards "$n" --json | python3 -c '
import json, sys
v = json.load(sys.stdin)
print("%.3f" % [s for s in v["shards"]["stages"] if s["stage"] == "horizon"][0]["slowest_over_mean"])')
  t0=$(date +%s.%N)
  bash "$plan/submit.sh" >"$plan/jobs.txt"
  ids=$(cut -d' ' -f2 "$plan/jobs.txt" | paste -sd,)
  while [ -n "$(squeue -h -j "$ids" 2>/dev/null)" ]; do sleep 0.5; done
  for id in ${ids//,/ }; do
    if scontrol show job "$id" | grep -o 'JobState=[A-Z]*' | grep -qv COMPLETED; then
      echo "job $id did not complete:"; tail -n 20 "$plan"/logs/*; exit 1
    fi
  done
  diff -r --exclude=.penumbra "$D/single" "$D/tiles-$k" >/dev/null ||
    { echo "N=$n: the tileset differs from the single bake's"; exit 1; }
  python3 - "$plan" "$t0" "$n" "$predicted" <<'PY'
import glob, json, os, re, sys
plan, t0, n, predicted = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
def spans(pattern):
    out = []
    for f in sorted(glob.glob(os.path.join(plan, "logs", pattern))):
        t = open(f).read()
        s = [float(x) for x in re.findall(r"== start .* at ([0-9.]+),", t)]
        e = [float(x) for x in re.findall(r"== end at ([0-9.]+)", t)]
        w = [float(x) for x in re.findall(r'"wall_s": ([0-9.eE+-]+)', t)]
        out.append((min(s), max(e), w[-1] if w else None))
    return out
everything = spans("*.out")
end = max(e for _, e, _ in everything)
h = spans("horizon-[0-9]*_*.out")
fin = spans("*-finish-*.out")
finishes = sum(e - s for s, e, _ in fin)
walls = [w for _, _, w in h]
mean = sum(walls) / len(walls)
# Where the chain's time went: each job's span (first start to last end) and the waits
# between one job's end and the next one's start (Slurm's scheduling of the dependency).
order = ["tile-*", "mip-[0-9]*_*", "mip-finish-*", "horizon-[0-9]*_*", "horizon-finish-*"]
parts, prev_end = [], t0
for pat in order:
    sp = spans(pat + ".out")
    if not sp:
        continue
    s0, e0 = min(s for s, _, _ in sp), max(e for _, e, _ in sp)
    parts.append("wait %.1f, %s %.1f" % (s0 - prev_end, pat.split("-")[0] + ("-finish" if "finish" in pat else ""), e0 - s0))
    prev_end = e0
print("| %d | %.1f | %.1f | %s | %.1f | %.1f %% | %.3f | %s |" % (
    n, end - t0, max(e for _, e, _ in h) - min(s for s, _, _ in h),
    " / ".join("%.1f" % w for w in walls), finishes, 100 * finishes / (end - t0),
    max(walls) / mean, predicted))
print("  N=%d: %s" % (n, "; ".join(parts)), file=sys.stderr)
PY
done
