"""Record the numbers of a few estimation problems into ``problem_regression.npz``.

``tests/test_problem_regression.py`` rebuilds the same problems from the experiments
stored here and checks that every number is still the same, bit for bit: the free names
and bounds, start vectors, kernel vectors, residuals, a short least-squares fit, and the
log posterior (its prior, likelihood and coordinates) under every noise model — i.i.d. at
the floor, sampled sigma, AR(1), and the curvature-adjusted default — including log
coordinates and several experiments with an ``alpha0[i]`` each.

Run it from the repository root only to record new numbers on purpose (a change of the
integrator's arithmetic, say), and say so in the commit:

    python tests/data/make_problem_regression.py
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
FILE = HERE / "problem_regression.npz"
SECONDS = 1.5


def experiments() -> dict[str, object]:
    """The synthetic experiments (simulated once, with encoder rounding)."""
    import rotorbayes as rb
    from rotorbayes.model.parameters import thesis_set

    out = {}
    for name, config, thesis, seed, alpha0 in (
        ("brake_a", "brake", "4.3", 2, 0.4),
        ("brake_b", "brake", "4.3", 5, -0.3),
        ("coupled_a", "coupled", "4.2", 3, 0.0),
        ("coupled_b", "coupled", "4.2", 7, 0.2),
        ("upper_a", "upper", "4.1", 4, None),
    ):
        t, u = rb.signals.estimation_signal(SECONDS, seed=seed)
        sim = rb.simulate(
            thesis_set(thesis, "P_ref"),
            u,
            dt=t[1] - t[0],
            config=config,
            alpha0=alpha0,
            quantize_angles=True,
        )
        out[name] = sim.to_experiment(name)
    return out


def stored_experiments(data) -> dict[str, object]:
    """The experiments as the file stores them."""
    from rotorbayes import Experiment

    out = {}
    for name in json.loads(str(data["experiment_names"])):
        th_l = data[f"ex/{name}/theta_l"]
        out[name] = Experiment(
            t=data[f"ex/{name}/t"],
            u=data[f"ex/{name}/u"],
            theta_u=data[f"ex/{name}/theta_u"],
            theta_l=None if th_l.size == 0 else th_l,
            name=name,
        )
    return out


def problems(ex: dict) -> dict[str, object]:
    """The problems: built through the public constructor as users build them."""
    from rotorbayes import inference
    from rotorbayes.model.parameters import thesis_set

    brake = thesis_set("4.3", "P_ref")
    coupled = thesis_set("4.2", "P_ref")
    return {
        "brake": inference.Problem("brake", [ex["brake_a"]], base=brake),
        "brake_two": inference.Problem(
            "brake",
            [ex["brake_a"], ex["brake_b"]],
            base=brake,
            channels=("theta_u", "theta_l"),
            weights={"theta_u": 2.5, "theta_l": 0.7},
        ),
        "coupled_two": inference.Problem(
            "coupled",
            (ex["coupled_a"], ex["coupled_b"]),
            base=coupled,
            free=["J_l", "k_alpha", "Tc_l", "b_l", "alpha0"],
            run_starts={"alpha0[1]": 0.15, "alpha0[5]": 1.0},
        ),
        "coupled_asym": inference.Problem(
            "coupled", [ex["coupled_a"]], effects=["lower_asymmetric_coulomb"], fixed=["dTc_u"]
        ),
        "upper": inference.Problem("upper", [ex["upper_a"]], weights={"theta_u": 0.1}),
    }


#: Log posteriors recorded: (key, problem, keyword arguments of LogPosterior).
POSTERIORS = (
    ("brake/floor", "brake", {"noise": "floor"}),
    ("brake/sampled", "brake", {"noise": "sampled"}),
    ("brake/ar1", "brake", {"ar1": True}),
    ("brake/robust", "brake", {}),
    ("brake_two/floor", "brake_two", {"noise": "floor"}),
    ("brake_two/ar1", "brake_two", {"ar1": True}),
    ("brake_two/robust", "brake_two", {}),
    ("coupled_two/sampled", "coupled_two", {"noise": "sampled"}),
    ("upper/floor", "upper", {"noise": "floor"}),
)


def points(prob, n: int, seed: int) -> np.ndarray:
    """``n`` free vectors near the base values, inside the bounds."""
    rng = np.random.default_rng(seed)
    x0 = prob.start_vector(prob.base)
    X = x0 * (1.0 + 0.02 * rng.standard_normal((n, x0.size))) + 1e-4 * rng.standard_normal(
        (n, x0.size)
    )
    return np.clip(X, prob.lower, prob.upper)


def record(ex: dict) -> dict[str, np.ndarray]:
    """Every recorded number, by key."""
    from rotorbayes.inference import least_squares
    from rotorbayes.inference.likelihood import LogPosterior

    out: dict[str, np.ndarray] = {}
    probs = problems(ex)
    for key, prob in probs.items():
        x0 = prob.start_vector(prob.base)
        X = points(prob, 2, seed=11)
        out[f"{key}/names"] = np.array(json.dumps(prob.names))
        out[f"{key}/channels"] = np.array(json.dumps(list(prob.channels)))
        out[f"{key}/lower"] = prob.lower
        out[f"{key}/upper"] = prob.upper
        out[f"{key}/x0"] = x0
        out[f"{key}/X"] = X
        out[f"{key}/values"] = np.array(json.dumps(prob.values(X[0])))
        out[f"{key}/params"] = np.array(
            json.dumps([prob.params_for(X[0], i) for i in range(len(prob.experiments))])
        )
        for i in range(len(prob.experiments)):
            p, q = prob.kernel_vectors(X[0], i)
            out[f"{key}/kernel_p{i}"] = p
            out[f"{key}/kernel_q{i}"] = q
        out[f"{key}/r0"] = prob.residuals(x0)
        out[f"{key}/R"] = prob.residuals_batch(X)
        out[f"{key}/n_residuals"] = np.array(prob.n_residuals)
    # The optimiser handed the whole Jacobian, as when this was recorded (the compressed
    # default's steps agree only up to rounding; tests/test_triangle.py checks it).
    fit = least_squares.fit(
        probs["brake"],
        points(probs["brake"], 1, seed=3)[0],
        max_nfev=8,
        uncertainty=False,
        compressed=False,
    )
    out["fit/brake/x"] = fit.x
    out["fit/brake/ssr"] = np.array(fit.ssr)
    for key, pkey, kw in POSTERIORS:
        prob = probs[pkey]
        x_fit = prob.start_vector(prob.base)
        lp = LogPosterior(prob, x_fit, **kw)
        z0 = lp.to_z(x_fit)
        rng = np.random.default_rng(5)
        Z = z0 + 1e-5 * rng.standard_normal((4, z0.size)) * np.maximum(np.abs(z0), 1e-2)
        out[f"lp/{key}/coord_names"] = np.array(json.dumps(lp.coord_names))
        out[f"lp/{key}/log"] = lp.log
        out[f"lp/{key}/z0"] = z0
        out[f"lp/{key}/Z"] = Z
        out[f"lp/{key}/logpost"] = lp(Z)
        out[f"lp/{key}/log_prior"] = lp.log_prior(Z)
        X, S, P = lp.split(lp.evaluation_points(Z))
        out[f"lp/{key}/split"] = np.concatenate([X, S, P], axis=1)
        out[f"lp/{key}/loglik"] = lp.loglik(X, S, P)[0]
        L, _ = lp.pointwise(X[:2], S[:2], P[:2])
        out[f"lp/{key}/pointwise_sum"] = L.sum(axis=1)
        out[f"lp/{key}/sigma"] = np.array([lp.sigma[c] for c in lp.channels])
        if lp.adjust is not None:
            out[f"lp/{key}/adjust"] = lp.adjust
        out[f"lp/{key}/start"] = lp.start_ball(x_fit, 3, np.random.default_rng(9))
    return out


def main() -> None:
    ex = experiments()
    arrays = {"experiment_names": np.array(json.dumps(list(ex)))}
    for name, e in ex.items():
        arrays[f"ex/{name}/t"] = e.t
        arrays[f"ex/{name}/u"] = e.u
        arrays[f"ex/{name}/theta_u"] = e.theta_u
        arrays[f"ex/{name}/theta_l"] = e.theta_l if e.theta_l is not None else np.empty(0)
    # The numbers are computed from the experiments as stored, as the test reads them.
    arrays.update(record(stored_experiments(arrays)))
    np.savez_compressed(FILE, **arrays)
    print(f"wrote {FILE} ({FILE.stat().st_size} bytes, {len(arrays)} arrays)")


if __name__ == "__main__":
    main()
