"""Which sampler converges fastest: emcee's moves, starts and an affine reparametrisation,
side by side on one brake posterior at 1 kHz (issue 19, goal 3).

The posterior: the 30 s brake experiment at 1 kHz of ``bench_sampling.py`` (thesis table 4.3
``P_ref``, the held-out input ``estimation_signal(30.0, seed=1)``: smooth steps, quantised,
alpha0 = 0), least-squares fit of the brake's default free set (13 parameters) from the
truth, then ``LogPosterior(noise=...)``: by default ``sampled`` -- the free parameters plus
σ of both channels (15 coordinates), the goal's posterior; ``--noise robust`` samples the
command's default likelihood instead.

Every alternative gets the same posterior, the same number of log-posterior evaluations
(walkers x steps x ensembles) and the same seed policy (ensemble ``e`` seeded ``seed + 1000 e``,
as ``rotorbayes sample`` does). The alternatives run round-robin, one ensemble each in turn,
so a change of the machine's load hits them alike. Per alternative it prints:

* the slowest coordinate's **conservative ESS** -- the lower of arviz's bulk ESS over every
  thinned draw after burn-in and emcee's walkers x steps / τ summed over the ensembles, as
  the summary table does -- and that ESS per second, per minute, per 1000 evaluations and
  per CPU-second of the process;
* the largest τ (steps), the largest R-hat across the ensembles, the mean acceptance;
* arviz's bulk ESS with every walker as a chain (a cross-check of the conservative one);
* the wall time, the process's CPU time over the wall time (the cores it got) and the
  1-minute load average before and after its runs;

and the ratios of ESS/s and ESS per evaluation to the first alternative (the former default:
stretch move from a ball 0.1 of the fit's width).

Alternatives: ``MOVES`` of :mod:`rotorbayes.inference.sampling` (stretch, de, de-mix,
de-stretch, fit-de) from the former small ball or from the fit's covariance at full width;
de-mix in coordinates whitened by that covariance (``w = L⁻¹ (z − ẑ)``, sampled in ``w``,
mapped back to ``z`` for every figure); and a random-walk Metropolis move with the fit's
covariance as proposal (emcee ``GaussianMove``, scaled 2.38/√d).

Usage::

    python benchmarks/bench_sampler_moves.py [--steps 1500] [--walkers 32] [--ensembles 2]
        [--noise sampled|robust] [--only 'NAME|NAME'] [--first N] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import emcee  # noqa: E402
import numba  # noqa: E402
import numpy as np  # noqa: E402

import rotorbayes as rb  # noqa: E402
from rotorbayes import inference  # noqa: E402
from rotorbayes.inference import arviz_compat, posterior, sampling
from rotorbayes.inference.likelihood import LogPosterior  # noqa: E402


@dataclass
class Alt:
    name: str
    moves: str  # a name of S.MOVES, or "gauss"
    start: str = "fit"
    whiten: bool = False


ALTS = [
    Alt("stretch, ball (before)", "stretch", "ball"),
    Alt("stretch, fit start", "stretch", "fit"),
    Alt("de-mix, fit start", "de-mix", "fit"),
    Alt("de, fit start", "de", "fit"),
    Alt("de-mix, whitened", "de-mix", "fit", whiten=True),
    Alt("gauss MH, fit cov", "gauss", "fit"),
    Alt("fit-de, fit start", "fit-de", "fit"),
    Alt("de-mix, ball", "de-mix", "ball"),
    Alt("de-stretch, fit start", "de-stretch", "fit"),
]


class Whitened:
    """The log-posterior of ``w`` with ``z = z0 + L w`` (a constant Jacobian)."""

    def __init__(self, lp, z0, L):
        self.lp, self.z0, self.L = lp, z0, L
        self.ndim = lp.ndim

    def __call__(self, W):
        return self.lp(self.z0 + np.atleast_2d(W) @ self.L.T)


def run(lp, x, alt: Alt, seed: int, walkers: int, steps: int) -> sampling.EnsembleRun:
    name = f"ensemble{seed // 1000}"
    if alt.moves in sampling.MOVES and not alt.whiten:
        # The product's own code path (rotorbayes sample), in memory.
        return sampling.run_ensemble(
            lp,
            None,
            name,
            n_walkers=walkers,
            n_steps=steps,
            x_fit=x,
            seed=seed,
            progress=False,
            moves=alt.moves,
            start=alt.start,
        )
    rng = np.random.default_rng(seed)
    p0 = sampling.start_walkers(lp, x, walkers, rng, start=alt.start)
    z0, cov = sampling.fit_proposal(lp, x)
    target, L = lp, None
    if alt.whiten:
        L = np.linalg.cholesky(cov)
        target = Whitened(lp, z0, L)
        p0 = np.linalg.solve(L, (p0 - z0).T).T
    if alt.moves == "gauss":
        moves = [(emcee.moves.GaussianMove(cov * 2.38**2 / lp.ndim), 1.0)]
    else:
        moves = sampling.emcee_moves(alt.moves)
    sampler = emcee.EnsembleSampler(walkers, lp.ndim, target, vectorize=True, moves=moves)
    state = emcee.State(p0, random_state=np.random.RandomState(seed).get_state())
    t0, c0 = time.perf_counter(), time.process_time()
    sampler.run_mcmc(state, steps, progress=False)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    chain = sampler.get_chain()
    if L is not None:
        chain = z0 + chain @ L.T
    try:
        tau = emcee.autocorr.integrated_time(chain, tol=0)
    except Exception:  # noqa: BLE001
        tau = np.full(lp.ndim, np.nan)
    return sampling.EnsembleRun(
        name,
        chain,
        sampler.get_log_prob(),
        sampler.acceptance_fraction,
        np.asarray(tau, float),
        moves=alt.name,
        seconds=wall,
        cpu_seconds=cpu,
    )


def per_walker_ess(lp, runs) -> np.ndarray:
    """arviz bulk ESS with every walker of every ensemble as a chain, after burn-in."""
    burn, _ = sampling.burn_thin(runs)
    Z = np.concatenate([r.chain[burn:] for r in runs], axis=1)  # (steps, chains, ndim)
    post = {f"c{j}": Z[:, :, j].T for j in range(lp.ndim)}
    s = arviz_compat.summary(arviz_compat.from_groups({"posterior": post}))
    return np.array([float(s.loc[f"c{j}", "ess_bulk"]) for j in range(lp.ndim)])


def figures(lp, alt: Alt, runs, loads) -> dict:
    steps = [r.chain.shape[0] for r in runs]
    walkers = runs[0].chain.shape[1]
    ess_tau = np.zeros(lp.ndim)
    for r, st in zip(runs, steps, strict=True):
        ess_tau += np.where(np.isfinite(r.tau) & (r.tau > 0), st * walkers / r.tau, 0.0)
    ess_bulk, rhat = posterior.ess_all_draws(lp, runs)
    cons = np.minimum(ess_bulk, ess_tau)
    j = int(np.argmin(cons))
    wall = sum(r.seconds for r in runs)
    cpu = sum(r.cpu_seconds for r in runs)
    evals = sum(st * walkers for st in steps)
    pw = per_walker_ess(lp, runs)
    return {
        "name": alt.name,
        "slowest": lp.coord_names[j],
        "ess": float(cons[j]),
        "ess_bulk_all": float(ess_bulk[j]),
        "ess_tau": float(ess_tau[j]),
        "ess_per_walker_chains_min": float(pw.min()),
        "tau_max": float(max(np.nanmax(r.tau) for r in runs)),
        "rhat_max": float(np.nanmax(rhat)),
        "acceptance": float(np.mean([np.mean(r.acceptance) for r in runs])),
        "wall_s": wall,
        "cpu_s": cpu,
        "cores_busy": cpu / wall,
        "evaluations": evals,
        "ess_per_s": cons[j] / wall,
        "ess_per_min": 60 * cons[j] / wall,
        "ess_per_1000_evals": 1000 * cons[j] / evals,
        "ess_per_cpu_s": cons[j] / cpu,
        "load_before": loads[0],
        "load_after": loads[1],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=1500, help="steps per ensemble")
    ap.add_argument("--walkers", type=int, default=32)
    ap.add_argument("--ensembles", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--noise", choices=["sampled", "robust"], default="sampled")
    ap.add_argument(
        "--case",
        choices=["brake", "coupled"],
        default="brake",
        help="brake: the 30 s brake posterior above; coupled: a second posterior "
        "the moves were not chosen on -- the coupled rig (thesis table 4.2 P_ref), "
        "--seconds of held-out input at 1 kHz, quantised, its default free set "
        "(J_l, k_alpha and Tc_l nearly exchangeable: a sloppy posterior)",
    )
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument(
        "--only",
        help="alternative names separated by '|' (prefix match; the "
        "names hold commas), e.g. 'stretch, ball|fit-de'",
    )
    ap.add_argument(
        "--first", type=int, default=len(ALTS), help="run only the first N alternatives"
    )
    ap.add_argument("--json")
    a = ap.parse_args()
    alts = ALTS[: a.first]
    if a.only:
        want = [w.strip() for w in a.only.split("|") if w.strip()]
        alts = [x for x in ALTS if any(x.name.startswith(w) for w in want)]
    table = "4.3" if a.case == "brake" else "4.2"
    p = rb.parameters.thesis_set(table, "P_ref")
    t, u = rb.signals.estimation_signal(a.seconds, seed=1)
    sim = rb.simulate(p, u, dt=float(t[1] - t[0]), config=a.case, alpha0=0.0, quantize_angles=True)
    prob = inference.Problem(a.case, [sim.to_experiment(f"{a.case}_1khz_heldout")], base=p)
    t0 = time.perf_counter()
    res = inference.fit(prob, prob.x_from(p))
    lp = LogPosterior(prob, res.x, noise=a.noise)
    print(
        f"{a.case}, {a.seconds:g} s at 1 kHz (held-out smooth-steps input, quantised), "
        f"{prob.n_residuals} residuals; noise {a.noise}: {lp.ndim} coordinates "
        f"({', '.join(lp.coord_names)}); fit + posterior set-up "
        f"{time.perf_counter() - t0:.1f} s"
    )
    print(
        f"{len(alts)} alternatives x {a.ensembles} ensembles x {a.walkers} walkers x "
        f"{a.steps} steps = {a.ensembles * a.walkers * a.steps} log-posterior evaluations "
        f"each; {os.cpu_count()} cores, {numba.get_num_threads()} numba threads"
    )
    sampling.start_walkers(lp, res.x, 4, np.random.default_rng(12345))  # warm-up
    runs: dict[str, list] = {x.name: [] for x in alts}
    loads: dict[str, list] = {x.name: [] for x in alts}
    for e in range(a.ensembles):
        for alt in alts:
            l0 = os.getloadavg()[0]
            r = run(lp, res.x, alt, a.seed + 1000 * e, a.walkers, a.steps)
            l1 = os.getloadavg()[0]
            runs[alt.name].append(r)
            loads[alt.name] += [l0, l1]
            print(
                f"  ensemble {e} {alt.name}: {r.seconds:.1f} s, "
                f"{r.cpu_seconds / r.seconds:.2f} cores busy, load {l0:.1f} -> {l1:.1f}, "
                f"max τ {np.nanmax(r.tau):.1f}",
                flush=True,
            )
    out = []
    for alt in alts:
        ld = loads[alt.name]
        out.append(figures(lp, alt, runs[alt.name], (min(ld), max(ld))))
    base = out[0]
    print()
    print(
        "| alternative | slowest | ESS | ESS/s | ESS/min | ESS/1000 evals | ESS/CPU-s | "
        "max τ | max R-hat | accept. | ESS walkers-as-chains | wall s | cores busy | "
        "load avg | ESS/s ratio | ESS/eval ratio |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for f in out:
        print(
            f"| {f['name']} | {f['slowest']} | {f['ess']:.0f} | {f['ess_per_s']:.2f} | "
            f"{f['ess_per_min']:.0f} | {f['ess_per_1000_evals']:.2f} | "
            f"{f['ess_per_cpu_s']:.2f} | {f['tau_max']:.1f} | {f['rhat_max']:.3f} | "
            f"{f['acceptance']:.2f} | {f['ess_per_walker_chains_min']:.0f} | "
            f"{f['wall_s']:.0f} | {f['cores_busy']:.2f} | "
            f"{f['load_before']:.1f}-{f['load_after']:.1f} | "
            f"{f['ess_per_s'] / base['ess_per_s']:.2f} | "
            f"{f['ess_per_1000_evals'] / base['ess_per_1000_evals']:.2f} |"
        )
    best = max(out, key=lambda f: f["ess_per_s"])
    print(
        f"\nfastest by ESS/s: {best['name']}, {best['ess_per_min']:.0f} ESS/min for its "
        f"slowest coordinate {best['slowest']} (target >= 1000/min: "
        f"{'PASS' if best['ess_per_min'] >= 1000 else 'FAIL'}) with "
        f"{best['cores_busy']:.2f} cores busy at load {best['load_before']:.1f}-"
        f"{best['load_after']:.1f}"
    )
    if a.json:
        Path(a.json).write_text(
            json.dumps({"alternatives": out, "args": vars(a)}, indent=2, default=float)
        )


if __name__ == "__main__":
    main()
