#!/usr/bin/env bash
# phast-bench on a local multi-process Ray cluster: a head node and a second node (two raylets, 1 CPU each) on this
# machine; the same grid is run, its driver killed (SIGKILL, then Ctrl-C = SIGINT) and resumed, and the results are
# compared bit for bit with the same grid run by --backend local.  docs/ray.md shows the log of a real run:
#
#     bash benchmarks/ray_local_cluster.sh 2>&1 | tee docs/results/ray_local_cluster.log
#
# Needs the 'ray' extra (pip install -e '.[ray]').  Environment overrides: PY (python, default .venv/bin/python),
# OUT (absolute work directory, default /tmp/phast_ray_demo; emptied first), RAY_PORT (head port, default 6391).
# At the end 'ray stop' stops every Ray process of this user on this machine.
set -euo pipefail
set -m  # background jobs get their own process group, so SIGINT reaches the driver like a Ctrl-C

REPO=$(cd "$(dirname "$0")/.." && pwd)
cd "$REPO"
PY=${PY:-$REPO/.venv/bin/python}
RAY=$(dirname "$PY")/ray
OUT=${OUT:-/tmp/phast_ray_demo}
PORT=${RAY_PORT:-6391}
case "$OUT" in /*) ;; *) echo "OUT must be an absolute path, got $OUT" >&2; exit 2 ;; esac
[ -x "$RAY" ] || { echo "no ray CLI next to $PY: pip install -e '.[ray]'" >&2; exit 2; }
# workers are started by the raylets and inherit this environment: the same code (this checkout) and 1 thread
export PYTHONPATH=$REPO${PYTHONPATH:+:$PYTHONPATH} OMP_NUM_THREADS=1 RAY_USAGE_STATS_ENABLED=0
# Ray >= 2.5x: token authentication, explicitly on for head, second node and driver alike (with the mode unset,
# 'ray start --head' turns it on when ~/.ray/auth_token exists but 'ray start --address' does not, and the second
# node is refused); the token is generated once into ~/.ray/auth_token, never printed
export RAY_AUTH_MODE=${RAY_AUTH_MODE:-token}
[ "$RAY_AUTH_MODE" != token ] || "$RAY" get-auth-token --generate > /dev/null 2>&1
rm -rf "$OUT" && mkdir -p "$OUT"

GRID=(--envs WindyPendulum-v0,DampedOscillator-v0 --models gru,lstm --seeds 0-1
      --epochs 20 --n-train 256 --n-val 32 --n-test 32 --T 200 --no-progress)
RAY_ARGS=(--backend ray --address "127.0.0.1:$PORT")
BENCH=("$PY" -m phast_model.cli.bench "${GRID[@]}")  # a plain command, so that $! of 'BENCH &' is the driver itself
bench() { "${BENCH[@]}" "$@"; }
n_done() { find "$1/runs" -name '*.json' 2>/dev/null | wc -l; }
now() { date +%s.%N; }
secs() { "$PY" -c "import sys; print(f'{float(sys.argv[2]) - float(sys.argv[1]):.1f}')" "$1" "$2"; }
wait_for() {  # wait_for DIR N PID: until DIR holds N finished runs (or the driver PID ended)
  while [ "$(n_done "$1")" -lt "$2" ] && kill -0 "$3" 2>/dev/null; do sleep 0.5; done
}
section() { printf '\n=== %s  [%s]\n' "$1" "$(date -u +%H:%M:%S)"; }

section "setup"
echo "commit $(git rev-parse --short HEAD)$(git diff --quiet HEAD -- phast_model phast_gym || echo ' (+ uncommitted changes)')"
"$PY" -c "import ray, torch, sys; print('python', sys.version.split()[0], '| ray', ray.__version__, '| torch', torch.__version__)"
echo "grid: ${GRID[*]}  (2 envs x 2 models x 2 seeds = 8 runs)"
echo "out: $OUT"

section "start the cluster: head + a second node on this machine (1 CPU each)"
"$RAY" start --head --num-cpus=1 --port="$PORT" --include-dashboard=false --disable-usage-stats > "$OUT/ray_head.log" 2>&1
"$RAY" start --address="127.0.0.1:$PORT" --num-cpus=1 --disable-usage-stats > "$OUT/ray_worker.log" 2>&1
trap '"$RAY" stop > /dev/null 2>&1 || true' EXIT
for _ in $(seq 60); do  # until both raylets have registered with the head
  [ "$("$RAY" status --address="127.0.0.1:$PORT" 2>/dev/null | grep -c ' node_')" -ge 2 ] && break
  sleep 1
done
"$RAY" status --address="127.0.0.1:$PORT" | sed -n '/Node status/,/Pending/p'
echo "raylet processes: $(pgrep -u "$(id -u)" -f 'ray/core/src/ray/raylet/raylet' | wc -l)"

section "1. ray: run, then kill -9 the driver after 2 finished runs"
t0=$(now)
"${BENCH[@]}" "${RAY_ARGS[@]}" --out "$OUT/ray" > "$OUT/ray_1.log" 2>&1 &
pid=$!
wait_for "$OUT/ray" 1 "$pid"
echo "--- ray status while the grid runs (both nodes busy):"
"$RAY" status --address="127.0.0.1:$PORT" | grep -E 'CPU' | head -1
wait_for "$OUT/ray" 2 "$pid"
kill -9 "$pid" 2>/dev/null || true
wait "$pid" 2>/dev/null || true
echo "driver killed (SIGKILL) after $(secs "$t0" "$(now)") s; finished runs on disk: $(n_done "$OUT/ray")/8"
echo "--- ray status right after the kill (Ray stops the dead driver's tasks a moment later):"
"$RAY" status --address="127.0.0.1:$PORT" | grep -E 'CPU' | head -1

section "2. ray: same command at once; Ctrl-C (SIGINT) after 2 more runs"
before=$(n_done "$OUT/ray")
"${BENCH[@]}" "${RAY_ARGS[@]}" --out "$OUT/ray" > "$OUT/ray_2.log" 2>&1 &
pid=$!
wait_for "$OUT/ray" $((before + 2)) "$pid"
kill -INT "$pid" 2>/dev/null || true
rc=0; wait "$pid" || rc=$?
echo "driver interrupted (SIGINT): exit code $rc; finished runs on disk: $(n_done "$OUT/ray")/8"
grep -E 'phast-bench:|Traceback' "$OUT/ray_2.log" || true

section "3. ray: same command again; resumes and completes"
t1=$(now)
bench "${RAY_ARGS[@]}" --out "$OUT/ray" 2>&1 | grep -vE '^\s*"(summary_csv|tables_md)"' | tee "$OUT/ray_3.log"
echo "resume wall time: $(secs "$t1" "$(now)") s; finished runs on disk: $(n_done "$OUT/ray")/8"
echo "--- and once more: nothing left to run"
bench "${RAY_ARGS[@]}" --out "$OUT/ray" 2>&1 | grep -E '"(ran|cached|failed|missing)"' | tr -d '\n '; echo

section "4. ray, uninterrupted, into a fresh directory (wall time)"
t2=$(now)
bench "${RAY_ARGS[@]}" --out "$OUT/ray_clean" 2>&1 | grep -E '"(ran|cached|failed)"' | tr -d '\n '; echo
echo "ray (2 nodes x 1 CPU) wall time, 8 runs: $(secs "$t2" "$(now)") s"

section "4b. ray with a relative --out, driver started in another directory than the nodes"
(cd "$OUT" && bench "${RAY_ARGS[@]}" --envs WindyPendulum-v0 --models gru --seeds 0 --out rel_out 2>&1 \
   | grep -E '"(ran|failed)"' | tr -d '\n '; echo)
echo "results under the driver's $OUT/rel_out: $(n_done "$OUT/rel_out"); under the nodes' cwd $REPO/rel_out: $(n_done "$REPO/rel_out")"

section "5. the same grid with --backend local --workers 2"
t3=$(now)
bench --backend local --workers 2 --out "$OUT/local" 2>&1 | grep -E '"(ran|cached|failed)"' | tr -d '\n '; echo
echo "local (2 processes) wall time, 8 runs: $(secs "$t3" "$(now)") s"

section "6. compare: interrupted+resumed ray vs local, and uninterrupted ray vs local"
rc=0
"$PY" benchmarks/compare_runs.py "$OUT/ray" "$OUT/local" || rc=$?
"$PY" benchmarks/compare_runs.py "$OUT/ray_clean" "$OUT/local" | tail -1 || rc=$?
echo "compare exit code: $rc"

section "7. ray stop"
"$RAY" stop 2>&1 | tail -1
trap - EXIT
exit "$rc"
