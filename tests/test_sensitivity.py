"""Forward sensitivities of the plain kernel (rotorbayes.kernel.sensitivity, issue 33).

* the residuals written beside the Jacobian are the residual kernel's, bit for bit;
* on smooth stretches (no event) the Jacobian is the derivative of the computed
  residuals: central differences of the kernel itself agree to 1e-6 of each column;
* across stick/slip events (start, stop, reversal) it agrees with central differences
  of the independent reference integrator (tests/reference.py) to 1e-5 of each column;
* ``Problem.jacobian(method="sensitivity")`` gives it, and falls back to differences,
  with a warning that says why, where the kernel has no sensitivities;
* ``Problem.jacobian_rows`` hands least squares the same ``Jᵀ J`` and ``Jᵀ r`` in a few
  rows per step, and a fit on them ends where a fit on the whole Jacobian does.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from reference import reference_simulate

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.inference.problem import SensitivityFallback
from rotorbayes.kernel import layout, sensitivity

DT = 1e-3


def _brake():
    return dict(rb.parameters.thesis_set("4.3", "P_ref"))


def _problem(config, params, u):
    effects = ["initial_torsion"] if params.get("alpha0", 0.0) != 0.0 else []
    s = rb.simulate(params, u, dt=DT, config=config, effects=effects)
    ch = ("theta_u",) if config == "upper" else ("theta_u", "theta_l")
    prob = inference.Problem(
        config, [s.to_experiment("x")], base=params, channels=ch, effects=effects
    )
    return s, prob


def _kernel(prob, kp, names):
    """Residuals and Jacobian straight from the sensitivity kernel at kernel vector kp."""
    sim = prob.sims[0]
    (mu, wu, cu), (ml, wl, cl) = [
        c if c is not None else (np.empty(0), 1.0, -1)
        for c in prob._channel_columns(prob.experiments[0], 0)
    ]
    idx = np.array([layout.INDEX[n] for n in names], dtype=np.int64)
    r = np.empty((1, prob.n_residuals))
    J = np.zeros((len(names), prob.n_residuals)).T  # Fortran order, as Problem.jacobian's
    st = sensitivity.sensitivities_into(kp, sim.u, sim.dt, sim.cfg, sim.shape, sim.grid, sim.h0,
                                        idx,
                               not prob.model.stribeck, mu, ml, float(wu), float(wl), r, J,
                               np.arange(len(names), dtype=np.int64), cu, cl,
                               np.empty((len(names) + 1, 0)),
                               np.zeros(2, dtype=np.int64))  # fmt: skip
    assert st == layout.OK
    return r[0], J


def test_residuals_bit_for_bit():
    t = np.arange(0, 4.0 + DT / 2, DT)
    u = 1.3 * np.sin(2 * np.pi * 0.5 * t)
    p = _brake()
    s, prob = _problem("brake", p, u)
    assert len(s.events) >= 3
    x = prob.x_from(p)
    kp, _ = prob.sims[0].kernel_vector(prob.params_for(x, 0))
    r, _ = _kernel(prob, kp, prob.names)
    assert np.array_equal(r, prob.residuals(x))


@pytest.mark.parametrize("config", ["upper", "coupled", "brake"])
def test_smooth_stretch_against_central_differences(config):
    """Both discs slip throughout (no event): the Jacobian is the derivative of the
    computed residuals; central differences of the same kernel (relative step 1e-5; the
    same to 2 digits at 1e-4 and 1e-6) agree to 1e-6 of each column -- with the Stribeck
    curve to 1e-3 only: its substeps' lengths move with the state and the Stribeck
    parameters and are not differentiated (measured: 4e-4 for delta_l, 7e-5 for ws_l,
    below 2e-6 for the parameters outside the curve); there the reference decides
    (:func:`test_stribeck_stretch_against_the_reference`)."""
    t = np.arange(0, 3.0 + DT / 2, DT)
    u = 3.0 + 0.8 * np.sin(2 * np.pi * 0.7 * t) + 0.3 * np.sin(2 * np.pi * 2.3 * t)
    p = _brake()
    if config != "brake":
        p["Ts_l"] = p["Tc_l"]
    p["alpha0"] = 0.0
    if config != "upper":  # a pre-wound string: the lower disc slips from the start
        p["alpha0"] = -1.5 * (p["Ts_l"] + abs(p["dTc_l"])) / p["k_alpha"]
    s, prob = _problem(config, p, u)
    assert len(s.events) == 0 and s.mode_u[1] != 0
    names = [n for n in prob.names if n != "alpha0"] + ["u_offset"] + (
        ["alpha0", "c_alpha"] if config != "upper" else [])  # fmt: skip
    x = prob.x_from(p)
    kp, _ = prob.sims[0].kernel_vector(prob.params_for(x, 0))
    kp[layout.U_OFFSET] = 0.05  # a voltage offset and string damping, straight in the kernel
    if config != "upper":
        kp[layout.C_ALPHA] = 2e-3
    _, J = _kernel(prob, kp, names)
    for a, n in enumerate(names):
        i = layout.INDEX[n]
        h = 1e-5 * max(abs(kp[i]), 1e-2)
        rr = []
        for sg in (1.0, -1.0):
            k2 = kp.copy()
            k2[i] += sg * h
            if n == "Tc_l" and not prob.model.stribeck:
                k2[layout.TS_L] = k2[layout.TC_L]
            rr.append(_kernel(prob, k2, names)[0])
        d = (rr[0] - rr[1]) / (2 * h)
        err = np.abs(J[:, a] - d).max() / np.abs(d).max()
        assert err < (1e-3 if config == "brake" else 1e-6), (config, n, err)


@pytest.mark.slow
def test_stribeck_stretch_against_the_reference():
    """The brake's event-free stretch of the test above, every parameter of the Stribeck
    curve included: against central differences of the reference (relative step 1e-5),
    to 1e-5 of each column."""
    t = np.arange(0, 3.0 + DT / 2, DT)
    u = 3.0 + 0.8 * np.sin(2 * np.pi * 0.7 * t) + 0.3 * np.sin(2 * np.pi * 2.3 * t)
    p = _brake()
    p["alpha0"] = -1.5 * (p["Ts_l"] + abs(p["dTc_l"])) / p["k_alpha"]
    s, prob = _problem("brake", p, u)
    assert len(s.events) == 0
    x = prob.x_from(p)
    J, _ = prob.jacobian(x, method="sensitivity")
    base = prob.params_for(x, 0)
    for a, n in enumerate(prob.names):
        h = 1e-5 * max(abs(base[n]), 1e-2)
        rr = []
        for sg in (1.0, -1.0):
            r = reference_simulate({**base, n: base[n] + sg * h}, t, u, "brake")
            rr.append(np.concatenate([r["theta_u"], r["theta_l"]]))
        d = -(rr[0] - rr[1]) / (2 * h)
        err = np.abs(J[:, a] - d).max() / np.abs(d).max()
        assert err < 1e-5, (n, err)


@pytest.mark.slow
def test_across_events_against_the_reference():
    """A brake run with events of every kind (both discs break loose and reverse, the
    upper disc sticks): the Jacobian against central differences of the reference
    integrator (relative step 1e-5), to 1e-5 of each column."""
    t = np.arange(0, 4.5 + DT / 2, DT)
    u = np.where(t < 3.0, 4.0 * np.sin(2 * np.pi * 0.3 * t), 0.0)
    p = _brake()
    s, prob = _problem("brake", p, u)
    kinds = {(int(d), int(m)) for _, d, m in s.events}
    assert {(0, 0), (1, 1), (1, -1), (0, 1), (0, -1)} <= kinds, s.events
    x = prob.x_from(p)
    J, _ = prob.jacobian(x, method="sensitivity")
    base = prob.params_for(x, 0)

    def ref(pp):
        r = reference_simulate(pp, t, u, "brake")
        return np.concatenate([r["theta_u"], r["theta_l"]])

    for a, n in enumerate(prob.names):
        h = 1e-5 * max(abs(base[n]), 1e-2)
        pp = dict(base)
        pp[n] = base[n] + h
        rp = ref(pp)
        pp[n] = base[n] - h
        rm = ref(pp)
        d = -(rp - rm) / (2 * h)
        err = np.abs(J[:, a] - d).max() / np.abs(d).max()
        assert err < 1e-5, (n, err)


def test_problem_jacobian_option_and_fallback():
    t = np.arange(0, 2.0 + DT / 2, DT)
    u = 1.5 + 1.2 * np.sin(2 * np.pi * 0.8 * t)
    p = _brake()
    _, prob = _problem("brake", p, u)
    x = prob.x_from(p)
    Js, steps = prob.jacobian(x, method="sensitivity")
    Jd, _ = prob.jacobian(x, method="differences")
    assert Js.shape == Jd.shape and not steps.any()
    rel = np.abs(Js - Jd).max(axis=0) / np.abs(Jd).max(axis=0)
    assert rel.max() < 1e-2  # forward differences carry their own step error
    assert prob.sensitivity_support() is None
    with pytest.raises(ValueError, match="method"):
        prob.jacobian(x, method="adjoint")
    # A parameter the kernel cannot differentiate by (the input delay): differences, said so.
    dprob = inference.Problem(
        "brake",
        prob.experiments,
        base={**p, "t_delay": 0.01},
        effects=["input_delay"],
        channels=("theta_u", "theta_l"),
    )
    assert "t_delay" in (dprob.sensitivity_support() or "")
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        J2, _ = dprob.jacobian(dprob.x_from(dprob.base), method="sensitivity")
    assert any(issubclass(i.category, SensitivityFallback) for i in w)
    assert np.isfinite(J2).all()


def _two_pre_wound_runs(p, t):
    """Two brake runs at times ``t`` with their own string torsion (0.05 and -0.04 rad)."""
    exs = []
    for k, a0 in enumerate((0.05, -0.04)):
        u = 1.5 + 1.2 * np.sin(2 * np.pi * (0.6 + 0.3 * k) * t)
        exs.append(
            rb.simulate(
                {**p, "alpha0": a0}, u, dt=DT, config="brake", effects=["initial_torsion"]
            ).to_experiment(f"x{k}")
        )
    return exs


def test_multi_experiment_columns():
    """alpha0[i] moves only experiment i's rows; the other rows of its column are 0."""
    t = np.arange(0, 2.0 + DT / 2, DT)
    p = _brake()
    prob = inference.Problem("brake", _two_pre_wound_runs(p, t), base=p)
    x = prob.x_from({**p, "alpha0": 0.01})
    assert "alpha0[1]" in prob.names
    Js, _ = prob.jacobian(x, method="sensitivity")
    Jd, _ = prob.jacobian(x, method="differences")
    n = prob.n_residuals // 2
    j1 = prob.names.index("alpha0[1]")
    assert not Js[:n, j1].any()
    rel = np.abs(Js - Jd).max(axis=0) / np.abs(Jd).max(axis=0)
    assert rel.max() < 1e-2, dict(zip(prob.names, rel, strict=True))


def _gram_matches(prob, x):
    J, _ = prob.jacobian(x, method="sensitivity")
    r = prob.residuals(x)
    A, b, rk = prob.jacobian_rows(x)
    assert np.array_equal(rk, r)
    G, Ga = J.T @ J, A.T @ A
    assert np.abs(G - Ga).max() < 1e-12 * np.abs(G).max()
    assert np.abs(J.T @ r - A.T @ b).max() < 1e-12 * np.abs(J.T @ r).max() + 1e-300
    assert float(b @ b) <= float(r @ r) * (1 + 1e-12)
    return A


def test_reduced_rows_hold_the_gauss_newton_model():
    """The rows the kernel writes per step instead of every sample's (the samples' rows of
    a step lie in the span of six Hermite weights): the same JᵀJ and Jᵀr to 1e-12, in
    several times fewer rows, across events and Stribeck substeps."""
    t = np.arange(0, 4.0 + DT / 2, DT)
    u = 1.3 * np.sin(2 * np.pi * 0.5 * t)
    p = _brake()
    s, prob = _problem("brake", p, u)
    assert len(s.events) >= 3
    A = _gram_matches(prob, prob.x_from(p) * 1.03)
    assert A.shape[0] * 4 < prob.n_residuals
    # Two experiments, alpha0 of each its own column: zero in the other's rows.
    prob2 = inference.Problem("brake", _two_pre_wound_runs(p, t), base=p)
    _gram_matches(prob2, prob2.x_from({**p, "alpha0": 0.01}))
    # Upper disc alone (one channel).
    _, prob3 = _problem("upper", {**p, "Ts_l": p["Tc_l"]}, u)
    _gram_matches(prob3, prob3.x_from(prob3.base) * 0.97)
    # Where the kernel has no sensitivities: None (the caller differentiates otherwise).
    dprob = inference.Problem(
        "brake", prob.experiments, base={**p, "t_delay": 0.01}, effects=["input_delay"],
        channels=("theta_u", "theta_l"),
    )  # fmt: skip
    assert dprob.jacobian_rows(dprob.x_from(dprob.base)) is None


def test_fit_on_reduced_rows_ends_where_the_whole_jacobian_does(monkeypatch):
    from rotorbayes.inference import problem as problem_module
    from rotorbayes.inference.least_squares import fit

    t = np.arange(0, 6.0 + DT / 2, DT)
    u = 1.4 + 1.1 * np.sin(2 * np.pi * 0.4 * t) + 0.4 * np.sin(2 * np.pi * 1.3 * t)
    p = _brake()
    ex = rb.simulate(p, u, dt=DT, config="brake", quantize_angles=True).to_experiment("x")
    prob = inference.Problem("brake", [ex], base=p)
    x0 = prob.x_from(p) * 1.04
    monkeypatch.setattr(problem_module, "JACOBIAN_DEFAULT", "sensitivity")
    a = fit(prob, x0, uncertainty=False)
    b = fit(prob, x0, uncertainty=False, compressed=False)
    assert a.success and b.success
    assert abs(a.ssr - b.ssr) <= 1e-9 * b.ssr
    se = b.stderr
    moved = (a.x - b.x) / se
    assert np.all(np.abs(moved) <= 1e-3), dict(zip(prob.names, moved, strict=True))


def test_jacobian_option_of_fit(tmp_path, capsys):
    """``--jacobian sensitivity`` on the command line: the fit ends where the default's
    does (within a hundredth of a standard error) and fit.json says which was used; a
    model the kernel cannot differentiate falls back to differences and says so."""
    import json

    from rotorbayes.cli import main

    _, u = rb.signals.estimation_signal(10.0, seed=1)
    s = rb.simulate(_brake(), u, dt=DT, config="brake", quantize_angles=True)
    data = tmp_path / "d.csv"
    rb.save_experiment(s.to_experiment("d"), data)
    docs = {}
    for how in ("differences", "sensitivity"):
        out = tmp_path / how
        argv = ["fit", str(data), "--model", "brake", "--p0", "thesis:4.3:P_ref"]
        assert main([*argv, "--out", str(out), "--jacobian", how]) == 0
        docs[how] = json.loads((out / "fit.json").read_text())
        assert docs[how]["jacobian"] == how
    for n, e in docs["differences"]["estimates"].items():
        other = docs["sensitivity"]["estimates"][n]["value"]
        assert abs(other - e["value"]) <= 1e-2 * e["stderr"], n
    capsys.readouterr()
    with warnings.catch_warnings():  # the command prints the package's warnings, one line each
        warnings.simplefilter("default", SensitivityFallback)
        code = main(
            ["fit", str(data), "--model", "brake", "--p0", "thesis:4.3:P_ref", "--add",
             "input_delay", "--jacobian", "sensitivity", "--out", str(tmp_path / "delay")]
        )  # fmt: skip
    err = capsys.readouterr().err
    assert err.count("Jacobian by finite differences: no sensitivity by t_delay") == 1
    assert code in (0, 1)
    assert json.loads((tmp_path / "delay" / "fit.json").read_text())["jacobian"] == "differences"
