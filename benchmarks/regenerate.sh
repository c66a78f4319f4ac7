#!/usr/bin/env bash
# Regenerate benchmarks/RESULTS.md: the safety benchmark under both protocols (riskfield, authors) and both
# perception modes (gt, sim), then the document (paper tables beside, differences explained).
# ALL=1 also re-runs teleop (the product filter and, on gt, the paper preset) and navigation; otherwise their sections are kept from the current RESULTS.md.
# Usage (repository root): bash benchmarks/regenerate.sh      OUT=dir to change the output folder.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
OUT=${OUT:-bench_out/results}
mkdir -p "$OUT"
run() { local t0=$SECONDS; echo "== riskfield bench $*" >&2; "$PY" -m riskfield.cli bench "$@"; echo "   $((SECONDS - t0)) s wall" >&2; }
for p in gt sim; do
  run safety --protocol riskfield --perception "$p" --out "$OUT/safety_riskfield_$p"
  run safety --protocol authors --semantic both --perception "$p" --out "$OUT/safety_authors_$p"
done
if [ "${ALL:-0}" = 1 ]; then
  for p in gt sim; do
    run teleop --perception "$p" --out "$OUT/teleop_$p"
    if [ "$p" = gt ]; then run teleop --preset paper --perception gt --out "$OUT/teleop_gt_paper"; fi
    run navigation --perception "$p" --out "$OUT/navigation_$p"
  done
fi
"$PY" -m riskfield.experiments.results "$OUT" --previous benchmarks/RESULTS.md \
  --commit "$(git rev-parse --short HEAD)" > "$OUT/RESULTS.md"
cp "$OUT/RESULTS.md" benchmarks/RESULTS.md
echo "wrote benchmarks/RESULTS.md" >&2
