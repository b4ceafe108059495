#!/usr/bin/env bash
# Continue training recipes on a lent GPU machine, side by side, for a fixed wall time; each
# starts from runs/<recipe>/last.ckpt when there is one and falls back to the machine's CPUs
# if CUDA training fails at start. The recipes are the arguments after the budget (default:
# equivariant_hopper equivariant_drum); a recipe whose name holds "drum" reads .device/drum,
# any other .device/hopper.
# Needs, in the repository root (both ignored by git, both named in the device call's carry):
#   .whl/    wheels of what the machine's image lacks (hydra-core, omegaconf, antlr4, trimesh)
#   .device/ the thinned datasets of tools/device_copy.py (hoppers: --every 4; drum: --every 8)
# Writes to $OUT: <recipe>.log, <recipe>_train.log, <recipe>_last.ckpt.
#   bash tools/device_train.sh 00:00:07:00 [recipe ...]
set -u
budget=${1:-00:00:07:00}
shift $(( $# > 0 ? 1 : 0 ))
recipes=("${@:-}")
[ -z "${recipes[0]}" ] && recipes=(equivariant_hopper equivariant_drum)
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site \
    .whl/*.whl || exit 3
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
python3 -c "import torch, torch_geometric, lightning; print(torch.__version__, torch_geometric.__version__, lightning.__version__, torch.cuda.is_available())"
# the tests that need CUDA (skipped on the CPU machines)
timeout 120 python3 -m pytest -q -p no:cacheprovider -k cuda tests/transforms/test_radius_graph.py 2>&1 | tail -3
timeout 120 python3 tools/cuda_rollout_check.py 2>&1 | tail -5

train() {  # recipe accelerator threads max_time
    local data=.device/hopper init=()
    [[ $1 == *drum* ]] && data=.device/drum
    [ -f "runs/$1/last.ckpt" ] && init=("init=runs/$1/last.ckpt")
    python3 -m granular_pyg.train +experiment=$1 data.root=$data "${init[@]}" \
        hydra.run.dir=/tmp/run_$1_$2 \
        trainer.accelerator=$2 threads=$3 trainer.max_time=$4 \
        rollout_validation.every_n_epochs=null \
        data.train_samples_per_epoch=600 \
        trainer.enable_progress_bar=false >>"$OUT/$1.log" 2>&1
}

run() {  # recipe
    local start=$SECONDS
    if ! train "$1" gpu "$threads" "$budget"; then
        local used=$((SECONDS - start))
        local left=$(( $(echo "$budget" | awk -F: '{print $2*3600+$3*60+$4}') - used ))
        echo "== GPU training failed after ${used}s; CPU for ${left}s" >>"$OUT/$1.log"
        [ "$left" -gt 60 ] && train "$1" cpu "$threads" "$(printf '00:00:%02d:%02d' $((left / 60)) $((left % 60)))"
        cp /tmp/run_$1_cpu/checkpoints/last.ckpt "$OUT/$1_last.ckpt" 2>/dev/null
        cp /tmp/run_$1_cpu/train.log "$OUT/$1_train.log" 2>/dev/null
        return
    fi
    cp /tmp/run_$1_gpu/checkpoints/last.ckpt "$OUT/$1_last.ckpt"
    cp /tmp/run_$1_gpu/train.log "$OUT/$1_train.log"
}

threads=$(( 12 / ${#recipes[@]} > 0 ? 12 / ${#recipes[@]} : 1 ))
for r in "${recipes[@]}"; do run "$r" & done
wait
nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader
