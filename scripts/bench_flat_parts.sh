#!/usr/bin/env bash
# Flat parts against T-LESS on the same simulator settings (docs/bench/flat-parts.md).
#   scripts/bench_flat_parts.sh OUT [FRAMES] [-- extra evaluate options]
# Writes OUT/models (the generated parts, unless present), OUT/sim_flat, OUT/sim_tless,
# OUT/eval_flat, OUT/eval_tless (report.json, report.md). The flat parts' classifier and templates are built
# by `tlessbot evaluate` with the defaults (cached in OUT/eval_flat).
set -euo pipefail
out=${1:?usage: $0 OUT [FRAMES] [-- evaluate options]}; frames=${2:-12}
shift $(( $# >= 2 ? 2 : 1 )); [ "${1:-}" = -- ] && shift
tb() { python -m tlessbot_ros.tools.cli "$@"; }
tless=${TLESS_MODELS:-../shared/data/tless_models_cad_stl}
# the parts made by code (tlessbot parts generate); or put your own CAD folder in OUT/models
[ -d "$out/models" ] || tb parts generate --out "$out/models"
sim=(--frames "$frames" --seed 41 --parts-min 3 --parts-max 8 --no-progress)
[ -d "$out/sim_flat" ] || tb simulate --models "$out/models" --out "$out/sim_flat" "${sim[@]}"
[ -d "$out/sim_tless" ] || tb simulate --models "$tless" --out "$out/sim_tless" "${sim[@]}"
tb evaluate --dataset "$out/sim_flat" --models "$out/models" --out "$out/eval_flat" "$@"
tb evaluate --dataset "$out/sim_tless" --models "$tless" --out "$out/eval_tless" \
    --classifier tlessbot_ros/data/classifier.npz --templates tlessbot_ros/data/templates.npz "$@"
