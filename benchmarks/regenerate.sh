#!/usr/bin/env bash
# Regenerate benchmarks/RESULTS.md from runs of the code in this checkout: each section's run writes its
# folder under $OUT with a stamp (the commit, the exact command, the date, the wall time, the load), and
# riskfield/experiments/results.py assembles the whole document from those folders.
#
# Usage (repository root):
#   bash benchmarks/regenerate.sh                          # every section: hours of CPU on a 2-core machine
#   SECTIONS="filter link" bash benchmarks/regenerate.sh   # only these; the others keep their last stamped run
#   ARGS_teleop_gt="--runs 4" SECTIONS=teleop_gt ...       # extra bench arguments of one section (in its stamp)
#   BEFORE=<rev> SECTIONS="crowd_sim latency_camera" ...   # also each section's command at commit <rev>, in the
#                                                          # same invocation, shown beside it as "before"
#   OUT=dir (default bench_out/results), PY=python (default .venv/bin/python),
#   RESULTS=file (default benchmarks/RESULTS.md: read for the sections not re-run, then rewritten)
# The sections and their commands: .venv/bin/python -m riskfield.experiments.results --list
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
PY=${PY:-.venv/bin/python}
OUT=${OUT:-bench_out/results}
RESULTS=${RESULTS:-benchmarks/RESULTS.md}
mkdir -p "$OUT"
# Absolute: a "before" run works in another folder.
OUT=$(realpath -s "$OUT"); PY=$(realpath -s "$(command -v "$PY")")  # -s: a venv's python is a symlink

declare -A ARGS=()
ORDER=()
while IFS=$'\t' read -r name args; do ARGS[$name]=$args; ORDER+=("$name"); done \
  < <("$PY" -m riskfield.experiments.results --list)
read -r -a WANTED <<< "${SECTIONS:-${ORDER[*]}}"
for name in "${WANTED[@]}"; do
  [ -n "${ARGS[$name]+x}" ] || { echo "regenerate: no section '$name' (sections: ${ORDER[*]})" >&2; exit 2; }
done

# The commit measured; "+uncommitted" when tracked files differ from it (the stamp must not claim a commit
# the code is not). diff-index reads the index without writing it. The document this script writes is not
# code: a run after an earlier invocation rewrote it still measures the commit.
commit=$(git rev-parse --short HEAD)
git diff-index --quiet HEAD -- . ":(exclude)$RESULTS" 2>/dev/null || commit="$commit+uncommitted"

before_tree=""
if [ -n "${BEFORE:-}" ]; then
  before_commit=$(git rev-parse --short "${BEFORE}^{commit}")
  before_tree=$(mktemp -d)
  trap 'rm -rf "$before_tree"' EXIT
  # The other commit's files in a temp folder (the repository and its index are not touched), laid out as the
  # installed package (setup.py's package_dir): riskfield.{protocol,services,edge} are the top-level folders.
  git archive "$before_commit" | tar -x -C "$before_tree"
  for d in protocol services edge; do ln -s "../$d" "$before_tree/riskfield/$d"; done
fi

# run NAME DEST COMMIT [TREE]: one bench run into DEST, its stamp beside its output. With TREE (another
# commit's files) it runs there: Python puts the working folder first on sys.path, ahead of the editable
# install's finder, so `riskfield` and every service process the bench spawns import that commit's code.
run() {
  local name=$1 dest=$2 rev=$3 path=${4:-} extra_var="ARGS_$1"
  local -a argv
  read -r -a argv <<< "${ARGS[$name]} ${!extra_var:-}"
  rm -rf "$dest" && mkdir -p "$dest"
  local load0 t0 date rc
  load0=$(cut -d' ' -f1 /proc/loadavg); t0=$(date +%s); date=$(date -u '+%Y-%m-%d %H:%M UTC')
  echo "== $name ($rev): riskfield bench ${argv[*]} --out $dest" >&2
  set +e
  local pythonpath=${PYTHONPATH:-}
  [ -z "$path" ] || pythonpath="$path${pythonpath:+:$pythonpath}"
  (cd "${path:-.}" && PYTHONPATH="$pythonpath" "$PY" -m riskfield.cli bench "${argv[@]}" --out "$dest") \
    > >(tee "$dest/log.txt" >&2) 2>&1
  rc=$?
  set -e
  COMMAND="riskfield bench ${argv[*]} --out ${dest#"$ROOT"/}" REV=$rev DATE=$date RC=$rc LOAD0=$load0 \
    WALL=$(( $(date +%s) - t0 )) LOAD1=$(cut -d' ' -f1 /proc/loadavg) "$PY" - "$dest/stamp.json" <<'EOF'
import json, os, sys
e = os.environ
json.dump({"command": e["COMMAND"], "commit": e["REV"], "date": e["DATE"], "wall_s": int(e["WALL"]),
           "exit": int(e["RC"]), "load": f"{e['LOAD0']} → {e['LOAD1']}"}, open(sys.argv[1], "w"), indent=2)
EOF
  echo "   $name: exit $rc, $(( $(date +%s) - t0 )) s wall" >&2
}

for name in "${WANTED[@]}"; do
  run "$name" "$OUT/$name" "$commit"
  if [ -n "$before_tree" ]; then run "$name" "$OUT/$name/before" "$before_commit" "$before_tree"; fi
done

"$PY" -m riskfield.experiments.results "$OUT" --previous "$RESULTS" > "$OUT/RESULTS.md"
cp "$OUT/RESULTS.md" "$RESULTS"
echo "wrote $RESULTS (re-ran: ${WANTED[*]})" >&2
