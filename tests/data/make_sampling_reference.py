"""Write ``sampling_reference.npz``: the chains the sampler gave for a small problem, kept so
that a change to the sampler's code can be checked to leave every chain bit for bit as it was.

Run from the repository root (once, with the code whose chains are the reference)::

    python tests/data/make_sampling_reference.py

``tests/test_sampling_reference.py`` runs the same cases and compares every array exactly.
The problem: the upper disc, 2 s at 200 Hz, quantised angles, sampled noise (6 coordinates);
12 walkers, 160 steps (the fit proposal is re-centred at step 150).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import h5py
import numpy as np

HERE = Path(__file__).resolve().parent
STEPS, WALKERS = 160, 12


def problem():
    """The log-posterior and its start point (the true parameters; no fit is needed)."""
    import rotorbayes as rb
    from rotorbayes import inference
    from rotorbayes.inference.likelihood import LogPosterior

    p = rb.parameters.resolve(
        dict(k_m=3.1, Tc_u=0.62, dTc_u=0.03, b_u=1.7, db_u=0.05), config="upper"
    )
    _, u = rb.signals.make_signal("est", 2.0, rate=200.0, seed=4)
    sim = rb.simulate(p, u, dt=1 / 200, config="upper", quantize_angles=True)
    prob = inference.Problem("upper", [sim.to_experiment("upper")], base=p)
    x = prob.x_from(p)
    return LogPosterior(prob, x, noise="sampled"), x


def h5_arrays(path: Path, tag: str) -> dict[str, np.ndarray]:
    """Every group's chain, log-probabilities, acceptances, random state and proposal."""
    out = {}
    with h5py.File(path, "r") as f:
        for name, g in sorted(f.items()):
            it = int(g.attrs["iteration"])
            out[f"{tag}/{name}/iteration"] = np.array(it)
            out[f"{tag}/{name}/chain"] = np.asarray(g["chain"][:it])
            out[f"{tag}/{name}/log_prob"] = np.asarray(g["log_prob"][:it])
            out[f"{tag}/{name}/accepted"] = np.asarray(g["accepted"][:])
            for a in sorted(g.attrs):
                if a.startswith(("random_state", "proposal")):
                    out[f"{tag}/{name}/{a}"] = np.asarray(g.attrs[a])
    return out


def run_arrays(runs, tag: str) -> dict[str, np.ndarray]:
    out = {}
    for r in runs:
        out[f"{tag}/{r.name}/chain"] = r.chain
        out[f"{tag}/{r.name}/log_prob"] = r.log_prob
        out[f"{tag}/{r.name}/acceptance"] = r.acceptance
    return out


class StopAfter:
    """``should_stop`` that says yes from its ``n``-th question on."""

    def __init__(self, n: int):
        self.n, self.asked = n, 0

    def __call__(self) -> bool:
        self.asked += 1
        return self.asked >= self.n


def cases(lp, x, tmp: Path) -> dict[str, np.ndarray]:
    """The chains of every case, by name."""
    from rotorbayes.inference import parallel, sampling

    kw = dict(n_walkers=WALKERS, n_ensembles=2, seed=3, progress=False)
    out: dict[str, np.ndarray] = {}
    # 1. The serial loop (the command's default), fit-de across its re-centring.
    sampling.sample(lp, x, tmp / "serial", n_steps=STEPS, **kw)
    out.update(h5_arrays(tmp / "serial" / "chain.h5", "serial"))
    # 2. The same on two threads.
    with parallel.open_executor(parallel.ExecutorSpec("threads", 2)) as ex:
        sampling.sample(lp, x, tmp / "threads", n_steps=STEPS, executor=ex, **kw)
    out.update(h5_arrays(tmp / "threads" / "chain.h5", "threads"))
    # 3. Stopped on request in the serial loop, then resumed to the end.
    try:
        sampling.sample(lp, x, tmp / "stopped", n_steps=STEPS, should_stop=StopAfter(40), **kw)
        raise AssertionError("the run was not stopped")
    except sampling.SamplingStopped:
        pass
    out.update(h5_arrays(tmp / "stopped" / "chain.h5", "stopped_part"))
    sampling.sample(lp, x, tmp / "stopped", n_steps=STEPS, **kw)
    out.update(h5_arrays(tmp / "stopped" / "chain.h5", "stopped"))
    # 4. A shorter run (as one killed after 70 steps) continued on threads to the end.
    sampling.sample(lp, x, tmp / "short", n_steps=70, **kw)
    with parallel.open_executor(parallel.ExecutorSpec("threads", 2)) as ex:
        sampling.sample(lp, x, tmp / "short", n_steps=STEPS, executor=ex, **kw)
    out.update(h5_arrays(tmp / "short" / "chain.h5", "short"))
    # 5. In memory, other moves and starts.
    out.update(
        run_arrays(
            sampling.sample(lp, x, None, n_steps=60, moves="de-mix", start="ball", **kw),
            "memory_demix",
        )
    )
    out.update(
        run_arrays(
            sampling.sample(
                lp,
                x,
                None,
                n_steps=40,
                moves="stretch",
                n_walkers=WALKERS,
                n_ensembles=1,
                seed=9,
                progress=False,
            ),
            "memory_stretch",
        )
    )
    return out


def main() -> int:
    lp, x = problem()
    with tempfile.TemporaryDirectory() as d:
        arrays = cases(lp, x, Path(d))
    np.savez_compressed(HERE / "sampling_reference.npz", **arrays)
    print(f"wrote {HERE / 'sampling_reference.npz'}: {len(arrays)} arrays")
    return 0


if __name__ == "__main__":
    sys.exit(main())
