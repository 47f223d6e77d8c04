#!/usr/bin/env bash
# Issue 34's figures on a lent 16-core machine (no network there): the wheels that machine
# lacks travel in .whl/ (see benchmarks/README.md), the package runs from src/.
#   bash benchmarks/device_scale.sh OUT_DIR [bench_scale.py options...]
set -o pipefail
out=${1:?output folder}; shift
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD/src PYTHONUNBUFFERED=1 NUMBA_CACHE_DIR=/tmp/rotorbayes-numba
mkdir -p "$out"
{
  echo "== machine"; nproc; lscpu | grep -E 'Model name|^CPU\(s\)|Thread'; python3 --version
  python3 -c 'import numpy, scipy, numba; print("numpy", numpy.__version__, "scipy", scipy.__version__, "numba", numba.__version__)'
  echo "== first fit on a fresh numba cache (compile included)"
  /usr/bin/time -f "first fit: %e s wall, %U s user CPU" python3 - <<'PY'
import time
t = time.perf_counter()
import numpy as np
import rotorbayes as rb
from rotorbayes import inference
p = rb.parameters.thesis_set("4.3", "P_ref")
t_, u = rb.signals.estimation_signal(5.0, seed=1)
sim = rb.simulate(p, u, dt=float(t_[1] - t_[0]), config="brake", alpha0=0.0)
prob = inference.Problem("brake", [sim.to_experiment("b")], base=p)
r = inference.fit(prob, uncertainty=False, max_nfev=3)
print(f"import + simulate + 3-evaluation fit: {time.perf_counter() - t:.1f} s")
PY
  echo "== where one fit on all threads spends its time (cProfile, second of two fits)"
  python3 - <<'PY'
import cProfile, pstats, sys
import numpy as np
sys.path.insert(0, "benchmarks")
from threadpoolctl import threadpool_limits
from bench_scale import brake_problem
from rotorbayes import inference
from rotorbayes.inference.multistart import latin_hypercube
prob = brake_problem(30.0)
x0 = latin_hypercube(prob, 4, np.random.default_rng(0))[1]
with threadpool_limits(1):
    inference.fit(prob, x0, uncertainty=False)
    cProfile.run("inference.fit(prob, x0, uncertainty=False)", "/tmp/fit.prof")
pstats.Stats("/tmp/fit.prof").sort_stats("tottime").print_stats(22)
PY
  echo "== bench_scale"
  python3 benchmarks/bench_scale.py --json "$out/scale.json" "$@"
} 2>&1 | tee "$out/scale.log"
