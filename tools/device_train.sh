#!/usr/bin/env bash
# Continue the equivariant hopper and drum models on a lent GPU machine, side by side, for a
# fixed wall time; each falls back to the machine's CPUs if CUDA training fails at start.
# Needs, in the repository root (both ignored by git, both named in the device call's carry):
#   .whl/    wheels of what the machine's image lacks (hydra-core, omegaconf, antlr4, trimesh)
#   .device/ the thinned datasets of tools/device_copy.py (hoppers: --every 4; drum: --every 8)
# Writes to $OUT: <model>.log, <model>_train.log, <model>_last.ckpt.
#   bash tools/device_train.sh 00:00:07:00
set -u
budget=${1:-00:00:07:00}
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site \
    .whl/*.whl || exit 3
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
python3 -c "import torch, torch_geometric, lightning; print(torch.__version__, torch_geometric.__version__, lightning.__version__, torch.cuda.is_available())"
# the tests that need CUDA (skipped on the CPU machines)
timeout 120 python3 -m pytest -q -p no:cacheprovider -k cuda tests/transforms/test_radius_graph.py 2>&1 | tail -3
timeout 120 python3 tools/cuda_rollout_check.py 2>&1 | tail -5

train() {  # model accelerator threads max_time
    python3 -m granular_pyg.train +experiment=equivariant_$1 data.root=.device/$1 \
        init=runs/equivariant_$1/last.ckpt hydra.run.dir=/tmp/run_$1_$2 \
        trainer.accelerator=$2 threads=$3 trainer.max_time=$4 \
        rollout_validation.every_n_epochs=null \
        data.train_samples_per_epoch=600 \
        trainer.enable_progress_bar=false >>"$OUT/$1.log" 2>&1
}

run() {  # model
    local start=$SECONDS
    if ! train "$1" gpu 6 "$budget"; then
        local used=$((SECONDS - start))
        local left=$(( $(echo "$budget" | awk -F: '{print $2*3600+$3*60+$4}') - used ))
        echo "== GPU training failed after ${used}s; CPU for ${left}s" >>"$OUT/$1.log"
        [ "$left" -gt 60 ] && train "$1" cpu 7 "$(printf '00:00:%02d:%02d' $((left / 60)) $((left % 60)))"
        cp /tmp/run_$1_cpu/checkpoints/last.ckpt "$OUT/$1_last.ckpt" 2>/dev/null
        cp /tmp/run_$1_cpu/train.log "$OUT/$1_train.log" 2>/dev/null
        return
    fi
    cp /tmp/run_$1_gpu/checkpoints/last.ckpt "$OUT/$1_last.ckpt"
    cp /tmp/run_$1_gpu/train.log "$OUT/$1_train.log"
}

run hopper &
run drum &
wait
nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader
