#!/usr/bin/env bash
# The GPU check, as run on a lent GPU machine (docs/results.md, "On a GPU"): the stage benchmark
# (bench_gpu.py); `pcpg run experiments/quick.yaml` with the paper's lstm_dec on the CPU and with
# clustering and BC on cuda through Ray, metrics compared; then experiments/gridworld_paper.yaml
# the same way, on cuda with runner.gpus_per_task 0.25 and 1.
#
#   bash benchmarks/gpu_check.sh OUT_DIR
#
# Where pcpg's locked environment is not installed (a bare GPU image with torch), the wheels in
# .whl/ are installed into a private folder first. Each part has its own time limit.
set -uo pipefail
cd "$(dirname "$0")/.."
out=${1:-gpu_check_out}
mkdir -p "$out"
export PYTHONUNBUFFERED=1 RAY_ENABLE_UV_RUN_RUNTIME_ENV=0 RAY_AUTH_MODE=disabled
PY=${PY:-python3}
if [ -d .whl ] && ! $PY -c "import pydantic, ray, gymnasium" 2>/dev/null; then
  $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/pcpg-site .whl/*.whl || exit 1
  export PYTHONPATH=/tmp/pcpg-site:$PWD
fi
nvidia-smi -L 2>/dev/null || echo "no nvidia-smi"
$PY -c "import torch, ray; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), 'ray', ray.__version__)"

timeout 330 $PY benchmarks/bench_gpu.py --cache .bench_cache --json "$out/bench_gpu.json" 2>&1 | tee "$out/bench_gpu.log"

# whether a Ray task that asks for no GPU sees one (Ray 2.60 on an H100 machine: it does)
$PY -c "
import ray
ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
seen = ray.remote(lambda: __import__('torch').cuda.is_available())
print('a Ray task sees the GPU: asking for none', ray.get(seen.remote()),
      '/ asking for 0.25', ray.get(seen.options(num_gpus=0.25).remote()))
" 2>&1 | grep "Ray task"

PCPG=($PY -c "import sys; from pcpg_dist.cli import main; sys.exit(main())")
for side in cpu gpu; do
  extra=(); [ $side = gpu ] && extra=(clustering.device=cuda bc.device=cuda)
  start=$EPOCHREALTIME
  timeout 150 "${PCPG[@]}" run experiments/quick.yaml --no-tracking --quiet --workdir /tmp/pcpg-e2e-$side \
    clustering.method=lstm_dec "${extra[@]}" > "$out/e2e_$side.log" 2>&1
  echo "e2e $side: exit $? in $(awk "BEGIN {print $EPOCHREALTIME - $start}") s"
  grep -E "time per stage|error" "$out/e2e_$side.log"
done
$PY - <<'EOF'
import json
from pathlib import Path
m = {s: json.loads(Path(f"/tmp/pcpg-e2e-{s}/quick/summary/metrics.json").read_text()) for s in ("cpu", "gpu")}
keys = [k for k in m["cpu"] if "seconds" not in k and k in m["gpu"]]
diff = [k for k in keys if abs(m["cpu"][k] - m["gpu"][k]) > 1e-9]
print(f"e2e metrics: {len(keys)} compared, {len(diff)} differ")
for k in diff:
    print(f"  differs: {k} cpu {m['cpu'][k]:.5f} gpu {m['gpu'][k]:.5f}")
import re
for k in keys:
    if re.fullmatch(r"(E\d/)?clustering/accuracy|pcpg/accuracy/p[\d.]+|cross/diagonal_mean", k):
        print(f"  {k:24s} cpu {m['cpu'][k]:.4f}  gpu {m['gpu'][k]:.4f}")
EOF

# the paper protocol with the paper's clusterer: CPU, and cuda with a quarter or a whole GPU per task
for v in "cpu" "cuda runner.gpus_per_task=0.25" "cuda runner.gpus_per_task=1"; do
  set -- $v; tag=$1_${2##*=}; start=$EPOCHREALTIME
  timeout 170 "${PCPG[@]}" run experiments/gridworld_paper.yaml --no-tracking --quiet --workdir /tmp/pcpg-gp-$tag \
    clustering.method=lstm_dec clustering.device=$1 bc.device=$1 ${2:-} > "$out/gp_$tag.log" 2>&1
  echo "paper lstm_dec $v: exit $? wall $(awk "BEGIN {print $EPOCHREALTIME - $start}") s"
  grep -E "time per stage|error" "$out/gp_$tag.log"; grep -A9 "Clustering" "$out/gp_$tag.log" | grep -E "E[1-5]"
done
