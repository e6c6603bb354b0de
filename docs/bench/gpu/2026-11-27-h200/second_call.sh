#!/usr/bin/env bash
# second GPU call of 2026-11-27 (not committed): the stages the first call's 512 threads broke
set -uo pipefail
O="$1"; mkdir -p "$O"; LOG="$O/log"
export PYTHONUNBUFFERED=1 SPRINGC_CACHE=/tmp/springc_kernels SPRINGC_SLOT_MAX=8
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl >/dev/null 2>&1
export PYTHONPATH="/tmp/site:$PWD"
st() { local n=$1 l=$2; shift 2; echo "=== $n" | tee -a "$LOG"; local s=$SECONDS
  timeout --kill-after=5 "$l" "$@" 2>&1 | grep -v "background-noise" | tee -a "$LOG"; echo "=== $n: exit ${PIPESTATUS[0]} after $((SECONDS-s)) s" | tee -a "$LOG"; }
st "compare" 105 python3 scripts/cuda_compare.py bench --seconds 0.02 --runs 64 --only "long delay line" "564-dof kws network" "pipeline classifier 8x3" --json "$O/compare.json"
st "throughput split" 65 python3 scripts/cpu_reference.py --device cuda --runs 10000 --seconds 0.02 --repeat 1 --only "564-dof kws network" "long delay line" --precision float64 float32 --threads 256 --slot-max 0 8 --json "$O/throughput_split.json"
st "throughput classifier" 50 python3 scripts/cpu_reference.py --device cuda --runs 10000 --seconds 0.02 --repeat 1 --only "pipeline classifier 8x3" --precision float64 --threads 256 --slot-max 8 --json "$O/throughput_classifier.json"
st "peers kws" 45 python3 scripts/gpu_peers.py --network "564-dof kws network" --runs 10000 --seconds 0.02 --threads 256 --json "$O/peers_kws.json"
