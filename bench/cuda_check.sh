#!/bin/bash
# CUDA check: train the default scene on the GPU (auto for 150 s, paper for 60 s), evaluate the auto run.
# Run from the repository root on a machine with a CUDA build of torch and srvol installed:
#   bash bench/cuda_check.sh [SCENE]   (SCENE default: bench/work/suite/scenes/bumpy; `srvol synth bumpy --out ...`)
# Writes bench/work/cuda/{auto,paper}; the figures go into bench/results/cuda_table.md by hand.
set -e
S=${1:-bench/work/suite/scenes/bumpy}
W=bench/work/cuda
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv
python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())"
srvol train "$S" --out $W/auto --device cuda --time-budget 150 --force
cat $W/auto/train_summary.json
srvol eval $W/auto
srvol train "$S" --out $W/paper --preset paper --device cuda --time-budget 60 --force
cat $W/paper/train_summary.json
