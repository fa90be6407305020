#!/bin/bash
# The heatmap-detector trial on a GPU machine that has only this repository (no simulated data):
# simulate training sequences on every core, load their pairs once into an .npz, then train the
# configurations side by side on the GPU, each for MINUTES minutes. Weights and logs go to OUT.
#   OUT=/tmp/out bash benchmarks/heatmap_detector_trial_gpu.sh
#   CONFIGS='"a:--position 1 --peak-score 1" "b:--position 1 --peak-score 1 --full 16 --half 32"' ...
# Environment: OUT (required), PER (sequences per process, 6), JOBS (processes, 16), SEED0 (1000),
# DEVICE (cuda), BATCH (16), MINUTES (5), CONFIGS (name:arguments, space-separated, quoted).
set -euo pipefail
export PYTHONUNBUFFERED=1
cd "$(dirname "$0")/.."
export PYTHONPATH=$PWD/src
: "${OUT:?set OUT to the folder for weights and logs}"
PER=${PER:-6}; JOBS=${JOBS:-16}; SEED0=${SEED0:-1000}
SIM=$(mktemp -d)
trap 'rm -rf "$SIM"' EXIT
mkdir -p "$OUT" "$SIM/all"
uptime; nvidia-smi --query-gpu=name --format=csv,noheader || true
T0=$(date +%s)
for i in $(seq 0 $((JOBS - 1))); do  # training seeds SEED0 .. SEED0 + PER * JOBS - 1 (not the test seeds 5000-5999)
  NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1 python3 -c "
import sys; sys.path.insert(0, 'benchmarks')
from pathlib import Path
from make_sim_datasets import make
make('train', $PER, Path('$SIM/p$i'), 8, $SEED0 + $PER * $i, None, ('paper', 'hard', 'mild'))
" > "$SIM/p$i.log" 2>&1 &
done
wait
for i in $(seq 0 $((JOBS - 1))); do for d in "$SIM/p$i"/train/*/; do ln -s "$d" "$SIM/all/p$i-$(basename "$d")"; done; done
echo "simulated $(ls "$SIM/all" | wc -l) sequences in $(( $(date +%s) - T0 )) s"
python3 -c "
import sys; sys.path.insert(0, 'benchmarks')
from pathlib import Path
from heatmap_detector_trial import cached_pairs
folders = sorted(p for p in Path('$SIM/all').iterdir() if p.is_dir())
print(len(cached_pairs(folders, '$SIM/pairs.npz', $JOBS)), 'pairs cached')
"
eval "set -- ${CONFIGS:-\"pos:--position 1 --peak-score 1\"}"
for cfg in "$@"; do
  name=${cfg%%:*}; args=${cfg#*:}
  # shellcheck disable=SC2086
  python3 benchmarks/heatmap_detector_trial.py train "$SIM/all" --whole-frames --device "${DEVICE:-cuda}" --batch "${BATCH:-16}" \
    --steps 100000 --minutes "${MINUTES:-5}" --cache "$SIM/pairs.npz" $args --out "$OUT/$name.pt" > "$OUT/$name.log" 2>&1 &
done
wait
tail -n 2 "$OUT"/*.log
