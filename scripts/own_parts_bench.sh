#!/bin/bash
# The own-parts bench of issue 41 from nothing: parts folders, scenes, end-to-end scores.
#
#   scripts/own_parts_bench.sh BENCH make            # once: parts folders and scenes (~40 min)
#   scripts/own_parts_bench.sh BENCH eval OUT SEED SET...   # SEED 4100 | 4242 | 4343
#   scripts/own_parts_bench.sh BENCH smoothed DIR SEED SET...   # the same scenes with smoothed,
#                                  stereo-like depth (simulate --depth-model smoothed) in
#                                  DIR/SEED-SET; score them with SCENES=DIR ... eval OUT SEED SET
#   scripts/own_parts_bench.sh BENCH pile DIR SEED SET...   # crowded scenes: 8-12 parts a frame,
#                                  dropped into piles, smoothed depth, in DIR/SEED-SET (SCENES=DIR)
#   scripts/own_parts_bench.sh BENCH why OUT SEED SET       # each part's outcome by cause
#   scripts/own_parts_bench.sh BENCH none OUT SEED SET      # each "none" part by cause (rerun)
#   scripts/own_parts_bench.sh BENCH resolvable OUT SEED SET...  # 5 cm / 5° over the parts the
#                                  rig can resolve at their true pose (scripts/resolvable_parts.py)
#
# SETs: T (T-LESS, packaged classifier and templates), g (the 8 parts of `tlessbot parts
# generate`), s (the SyGrid CAD models), h7 / h8 (families drawn with `parts generate --seed 7 /
# 8 --count 8`). Scenes: 20 frames of `tlessbot bench own-parts --seed SEED` (T, g, s; the held-
# out families at 4100 and 4242). Templates are rebuilt by the code being scored (`make` builds
# them; rebuild with `tlessbot templates` after changing what templates hold). Needs ../shared.
# SCENES=DIR: eval, why, none and resolvable read the scenes from DIR/SEED-SET instead.
set -eu
BENCH=$1; what=$2; shift 2
SHARED=${SHARED:-$(cd "$(dirname "$0")/../.." && pwd)/shared}
PY=${PYTHON:-python}
# the tree this script is in, not the package an editable install points at (a worktree)
export PYTHONPATH="$(cd "$(dirname "$0")/.." && pwd)${PYTHONPATH:+:$PYTHONPATH}"
cli() { nice -n 10 "$PY" -m tlessbot_ros.tools.cli "$@"; }
SCENES=${SCENES:-$BENCH/scenes}
case $what in
make)
  mkdir -p "$BENCH/parts" "$BENCH/scenes"
  cli parts generate --out "$BENCH/cad/g"
  cli parts generate --out "$BENCH/cad/h7" --seed 7 --count 8
  cli parts generate --out "$BENCH/cad/h8" --seed 8 --count 8
  for k in g h7 h8; do cli parts build --models "$BENCH/cad/$k" --out "$BENCH/parts/$k"; done
  cli parts build --models "$SHARED/data/sygrid_real_d435i/models" --out "$BENCH/parts/s"
  for seed in 4100 4242 4343; do
    cli bench own-parts --set g="$BENCH/parts/g" --set s="$BENCH/parts/s" \
      --reference "$SHARED/data/tless_models_cad_stl" --frames 20 --seed $seed \
      --out "$BENCH/run/$seed"
    for k in T-LESS_packaged g s; do
      ln -sfn "$BENCH/run/$seed/$k/scenes" "$BENCH/scenes/$seed-${k%%-*}"
    done
  done
  for seed in 4100 4242; do for k in h7 h8; do
    cli bench own-parts --set $k="$BENCH/parts/$k" --frames 20 --seed $seed --out "$BENCH/run/$seed-$k"
    ln -sfn "$BENCH/run/$seed-$k/$k/scenes" "$BENCH/scenes/$seed-$k"
  done; done
  ;;
smoothed|pile)
  # as `bench own-parts` simulates a set (its --parts-min/max and T-LESS ids), smoothed depth;
  # pile: more parts a frame, dropped onto each other
  DIR=$1; SEED=$2; shift 2
  crowd=(--parts-min 3 --parts-max 8)
  [ "$what" = pile ] && crowd=(--parts-min 8 --parts-max 12 --pile)
  for k in "$@"; do
    if [ "$k" = T ]; then models=(--models "$SHARED/data/tless_models_cad_stl" --ids 2 5 8 11 14 19 25 30)
    else models=(--models "$BENCH/parts/$k/models"); fi
    cli simulate "${models[@]}" --out "$DIR/$SEED-$k" --frames 20 --seed "$SEED" \
      "${crowd[@]}" --depth-model smoothed --no-progress
  done
  ;;
eval)
  OUT=$1; SEED=$2; shift 2
  for k in "$@"; do
    if [ "$k" = T ]; then
      more=(--models "$SHARED/data/tless_models_cad_stl" --classifier tlessbot_ros/data/classifier.npz
            --templates tlessbot_ros/data/templates.npz)
    else
      more=(--models "$BENCH/parts/$k/models" --classifier "$BENCH/parts/$k/classifier.npz"
            --templates "$BENCH/parts/$k/templates.npz")
    fi
    cli evaluate --dataset "$SCENES/$SEED-$k" "${more[@]}" --out "$OUT/$SEED/$k"
  done
  ;;
why)
  OUT=$1; SEED=$2; k=$3
  # T has no parts folder: its scenes folder holds models_info.json
  models=$BENCH/parts/$k/models; [ "$k" = T ] && models=$SCENES/$SEED-$k
  "$PY" scripts/own_parts_why.py "$SCENES/$SEED-$k" "$models" "$OUT/$SEED/$k/estimates.csv"
  ;;
none)
  OUT=$1; SEED=$2; k=$3
  if [ "$k" = T ]; then   # the packaged classifier and templates; T-LESS lists no manifest
    more=("$SCENES/$SEED-$k" --templates tlessbot_ros/data/templates.npz
          --classifier tlessbot_ros/data/classifier.npz)
  else
    more=("$BENCH/parts/$k/models" --manifest "$BENCH/parts/$k/manifest.json"
          --templates "$BENCH/parts/$k/templates.npz" --classifier "$BENCH/parts/$k/classifier.npz")
  fi
  "$PY" scripts/own_parts_none.py "$SCENES/$SEED-$k" "${more[0]}" \
    "$OUT/$SEED/$k/estimates.csv" "${more[@]:1}" --rerun
  ;;
resolvable)
  OUT=$1; SEED=$2; shift 2
  header=()
  for k in "$@"; do
    if [ "$k" = T ]; then models=$SHARED/data/tless_models_cad_stl; twins=()
    else models=$BENCH/parts/$k/models; twins=(--manifest "$BENCH/parts/$k/manifest.json"); fi
    nice -n 10 "$PY" scripts/resolvable_parts.py \
      "$SCENES/$SEED-$k" "$models" "$OUT/$SEED/$k/estimates.csv" "${twins[@]}" \
      --label "$SEED $k" "${header[@]}"
    header=(--no-header)
  done
  ;;
*) echo "usage: $0 BENCH make | eval OUT SEED SET... | smoothed DIR SEED SET..." \
     "| why|none OUT SEED SET" \
     "| resolvable OUT SEED SET..." >&2; exit 2;;
esac
