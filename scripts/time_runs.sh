#!/usr/bin/env bash
# Time `bemlearn run` on two source trees, alternating, and print the medians.
#
#   scripts/time_runs.sh BASE_TREE NEW_TREE [RUNS] [OUT] [-- EXTRA RUN ARGUMENTS]
#
# For each of RUNS rounds (default 3) and each config (configs/furuta.yaml of BASE_TREE, and a
# config naming only `robot: tests/robots/cartpole.xml`), runs
#     PYTHONPATH=TREE python -m bemlearn run CONFIG --out OUT/<tree>-<config>-<round> --no-progress [EXTRA]
# for BASE_TREE then NEW_TREE (alternating, so that a change in the machine's load falls on both),
# and records the wall time, the CPU time (user + system, children included) and the 1-minute load
# average before and after each run in OUT/times.tsv (default OUT: a new folder under /tmp).
# Prints the medians per tree and config, their ratio (new / base), and checks with
# scripts/diff_metrics.py that the last round's metrics agree (the robot file's path, which names
# the tree, excepted).  Extra arguments (after --) go to both trees' runs, e.g. `-- --jobs 2`.
set -euo pipefail

if [[ $# -lt 2 ]]; then
    sed -n '2,14p' "$0" | sed 's/^# \{0,1\}//'
    exit 2
fi
BASE=$(cd "$1" && pwd)
NEW=$(cd "$2" && pwd)
shift 2
RUNS=3
OUT=""
if [[ $# -gt 0 && $1 != "--" ]]; then RUNS=$1; shift; fi
if [[ $# -gt 0 && $1 != "--" ]]; then OUT=$1; shift; fi
if [[ ${1:-} == "--" ]]; then shift; fi
EXTRA=("$@")
OUT=${OUT:-$(mktemp -d /tmp/time_runs.XXXXXX)}
HERE=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$OUT"
printf 'robot: %s\n' "$BASE/tests/robots/cartpole.xml" > "$OUT/cartpole.yaml"
declare -A CONFIG=([furuta]="$BASE/configs/furuta.yaml" [cartpole]="$OUT/cartpole.yaml")
TSV="$OUT/times.tsv"
printf 'round\ttree\tconfig\twall_s\tcpu_s\tload_before\tload_after\tstatus\n' > "$TSV"

load1() { cut -d' ' -f1 /proc/loadavg; }

for round in $(seq 1 "$RUNS"); do
    for name in furuta cartpole; do
        for tree in base new; do
            src=$BASE; [[ $tree == new ]] && src=$NEW
            run="$OUT/$tree-$name-$round"
            before=$(load1)
            status=0
            # resource: the wall and CPU time of the child (python -m bemlearn run …) as the kernel counts them
            PYTHONPATH="$src" python - "$src" "${CONFIG[$name]}" "$run" "$OUT/$tree-$name-$round.times" "${EXTRA[@]}" <<'EOF' \
                > "$run.log" 2>&1 || status=$?
import resource, subprocess, sys, time
src, config, run, times, *extra = sys.argv[1:]
t0 = time.perf_counter()
rc = subprocess.call([sys.executable, "-m", "bemlearn", "run", config, "--out", run, "--no-progress", *extra])
wall = time.perf_counter() - t0
ru = resource.getrusage(resource.RUSAGE_CHILDREN)
open(times, "w").write(f"{wall:.2f}\t{ru.ru_utime + ru.ru_stime:.2f}\n")
sys.exit(rc)
EOF
            after=$(load1)
            read -r wall cpu < "$OUT/$tree-$name-$round.times"
            printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$round" "$tree" "$name" "$wall" "$cpu" "$before" "$after" "$status" >> "$TSV"
            echo "round $round $name $tree: wall ${wall}s cpu ${cpu}s load ${before} -> ${after} (exit $status)"
        done
    done
done

python - "$TSV" <<'EOF'
import csv, statistics, sys
rows = list(csv.DictReader(open(sys.argv[1]), delimiter="\t"))
print(f"\nmedians over {len({r['round'] for r in rows})} round(s) ({sys.argv[1]}):")
for name in ("furuta", "cartpole"):
    med = {}
    for tree in ("base", "new"):
        sel = [r for r in rows if r["config"] == name and r["tree"] == tree]
        med[tree] = tuple(statistics.median(float(r[k]) for r in sel) for k in ("wall_s", "cpu_s", "load_before"))
        print(f"  {name:<9}{tree:<5} wall {med[tree][0]:7.1f} s  cpu {med[tree][1]:7.1f} s  load before {med[tree][2]:.2f}")
    print(f"  {name:<9}new/base: wall {med['new'][0] / med['base'][0]:.2f}x, cpu {med['new'][1] / med['base'][1]:.2f}x")
EOF

for name in furuta cartpole; do
    echo "metrics of the last round, $name:"
    python "$HERE/diff_metrics.py" --ignore '^robot\.mjcf$' "$OUT/base-$name-$RUNS/metrics.json" "$OUT/new-$name-$RUNS/metrics.json" || true
done
