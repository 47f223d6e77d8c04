"""The documented Python API keeps working: the README's and the docs' Python examples run
as written, and every documented way of building a :class:`~rotorbayes.inference.Problem`
and a :class:`~rotorbayes.inference.likelihood.LogPosterior` is accepted (and every
documented refusal still names the bad argument)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

import rotorbayes as rb
from rotorbayes import inference as inf
from rotorbayes.inference.likelihood import LogPosterior, Prior
from rotorbayes.model.parameters import ParameterError, thesis_set

ROOT = Path(__file__).resolve().parents[1]


def python_blocks(md: str) -> list[str]:
    """The ```python blocks of a Markdown file, as written."""
    text = (ROOT / md).read_text(encoding="utf-8")
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def _data(config: str, seconds: float = 3.0, seed: int = 2, alpha0=None):
    t, u = rb.signals.estimation_signal(seconds, seed=seed)
    params = thesis_set({"upper": "4.1", "coupled": "4.2", "brake": "4.3"}[config], "P_ref")
    sim = rb.simulate(params, u, dt=t[1] - t[0], config=config, alpha0=alpha0, quantize_angles=True)
    return sim.to_experiment(f"{config}_{seed}")


@pytest.fixture(scope="module")
def brake():
    return [_data("brake", seed=2, alpha0=0.2), _data("brake", seed=5, alpha0=-0.1)]


def test_the_readme_and_docs_have_the_python_examples_this_file_runs():
    readme = python_blocks("README.md")
    assert len(readme) == 1 and 'inf.Problem("coupled", [ex])' in readme[0]
    assert any("LogPosterior(fit.problem, fit.x)" in b for b in python_blocks("docs/sampling.md"))
    assert any(
        "identify.fisher(fit.problem, fit.x)" in b for b in python_blocks("docs/identifiability.md")
    )


def test_problem_is_built_the_documented_ways(brake):
    ex = brake[0]
    p_ref = thesis_set("4.3", "P_ref")
    # A configuration name, a tuple or a single experiment, and a Model.
    a = inf.Problem("brake", [ex])
    assert inf.Problem("brake", (ex,)).names == a.names == inf.Problem("brake", ex).names
    b = inf.Problem(rb.Model("brake", ["lower_stribeck"]), [ex], base="thesis:4.3:P_ref")
    assert "Ts_l" in b.names and b.config == "brake"
    # The declared settings, by keyword, as the commands pass them.
    c = inf.Problem(
        "brake",
        [ex],
        free=["J_l", "Tc_l", "b_l"],
        base=p_ref,
        channels=["theta_u", "theta_l"],
        weights={"theta_u": 0.1},
        shape="exp",
        step=None,
        fixed=(),
        run_starts=None,
    )
    assert c.names == ["J_l", "Tc_l", "b_l"]
    assert c.channels == ("theta_u", "theta_l")
    assert c.weights == {"theta_u": 0.1, "theta_l": 1.0}
    assert isinstance(c.base, dict) and c.base["J_l"] == p_ref["J_l"]
    assert c.n_residuals == 2 * ex.n
    # Several experiments: alpha0 per experiment, each starting from its own estimate.
    d = inf.Problem("brake", brake, run_starts={"alpha0[1]": -0.1, "alpha0[7]": 3.0})
    assert d.names[-2:] == ["alpha0[0]", "alpha0[1]"]
    assert "initial_torsion" in d.effects
    assert d.run_starts == {"alpha0[1]": -0.1}
    x = d.start_vector(d.base)
    assert x[d.names.index("alpha0[1]")] == -0.1
    assert d.params_for(x, 1)["alpha0"] == -0.1
    assert d.values(x)["alpha0[0]"] == x[d.names.index("alpha0[0]")]
    np.testing.assert_array_equal(d.x_from(d.params_for(x, 0) | {"alpha0[1]": -0.1}), x)
    assert d.names_base()[-1] == "alpha0"
    assert np.all(d.lower <= x) and np.all(x <= d.upper)
    # Derived problems.
    e = d.like(free=["J_l", "alpha0"])
    assert e.names == ["J_l", "alpha0[0]", "alpha0[1]"] and e.experiments == d.experiments
    f = a.with_effects(["string_damping"])
    assert "c_alpha" in f.model.active and f.names == a.names
    # The problem's numbers.
    r = a.residuals(a.x_from(a.base))
    assert r.shape == (a.n_residuals,) and np.all(np.isfinite(r))
    assert a.evaluate(a.x_from(a.base)).ok
    assert a.residuals_batch(np.stack([a.x_from(a.base)] * 2)).shape == (2, a.n_residuals)
    sim = a.simulate(a.x_from(a.base))
    assert sim.theta_l.shape == (ex.n,)


def test_problem_refusals_name_the_bad_argument(brake, tmp_path):
    ex = brake[0]
    with pytest.raises(ValueError, match="load each file with rotorbayes.load_experiment"):
        inf.Problem("brake", None)
    with pytest.raises(ValueError, match="is the path"):
        inf.Problem("brake", [str(tmp_path / "a.csv")])
    with pytest.raises(ParameterError, match=r"free=\['J_l', 'Tc_l'\]"):
        inf.Problem("brake", [ex], free="J_l, Tc_l")
    with pytest.raises(ValueError, match="unknown channel"):
        inf.Problem("brake", [ex], channels=["theta_x"])
    with pytest.raises(ValueError, match="between"):
        inf.Problem("brake", [ex], weights={"theta_l": 1e6})
    with pytest.raises(ValueError, match="give the effects with the Model"):
        inf.Problem(rb.Model("brake"), [ex], effects=["string_damping"])
    with pytest.raises(ParameterError, match="both fixed and free"):
        inf.Problem("brake", [ex], free=["J_l"], fixed=["J_l"])
    with pytest.raises(ValueError, match="free parameter"):
        inf.Problem("brake", [ex]).residuals(np.zeros(2))
    with pytest.raises(TypeError, match="no setting"):
        inf.Problem("brake", [ex]).like(colour="red")


def test_log_posterior_is_built_the_documented_ways(brake):
    prob = inf.Problem("brake", brake)
    x = prob.start_vector(prob.base)
    kinds = {
        "robust": LogPosterior(prob, x),
        "floor": LogPosterior(prob, x, noise="floor"),
        "sampled": LogPosterior(prob, x, noise="sampled"),
        "ar1": LogPosterior(prob, x, ar1=True),
        "priors": LogPosterior(
            prob, x, noise="floor", priors={"J_l": Prior("normal", 0.01, 1.0, 0.04, 0.01)}
        ),
    }
    k = len(prob.names)
    for name, lp in kinds.items():
        assert lp.problem is prob
        z = lp.to_z(x)
        assert z.shape == (lp.ndim,) and len(lp.coord_names) == lp.ndim
        assert np.isfinite(lp(z[None, :])[0]), name
        X, S, P = lp.split(z[None, :])
        np.testing.assert_allclose(X[0], x, rtol=1e-12)
        assert S.shape == P.shape == (1, len(lp.channels))
        assert lp.row_chunk() >= 1
        assert lp.n_calls >= 1 and lp.n_failed == 0
    assert kinds["robust"].adjust.shape == (k, k)
    assert kinds["floor"].adjust is None
    assert kinds["ar1"].ar1 and kinds["ar1"].noise == "sampled"
    assert kinds["ar1"].coord_names[-1] == "phi_theta_l"
    assert kinds["sampled"].coord_names[-1] == "log_sigma_theta_l"
    assert kinds["priors"].priors["J_l"].kind == "normal"
    # The honest covariance given rather than computed: the same adjustment.
    given = LogPosterior(prob, x, uncertainty=kinds["robust"].uncertainty)
    np.testing.assert_array_equal(given.adjust, kinds["robust"].adjust)
    # An impossible point is -inf before any simulation.
    lp = kinds["floor"]
    bad = lp.to_z(x)
    bad[prob.names.index("Tc_l")] = math.log(prob.upper[prob.names.index("Tc_l")] * 2)
    calls = lp.n_calls
    assert lp(bad[None, :])[0] == -math.inf and lp.n_calls == calls
    with pytest.raises(ValueError, match="noise must be one of"):
        LogPosterior(prob, x, noise="gaussian")


@pytest.mark.slow
def test_the_readme_python_example_runs_as_written(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (block,) = python_blocks("README.md")
    exec(compile(block, "README.md", "exec"), {})
    out = capsys.readouterr().out
    assert out.strip(), "the example prints the verdict and the diagnosis"


@pytest.mark.slow
def test_the_sampling_and_identifiability_examples_run(tmp_path, monkeypatch, brake):
    """The docs' examples on a fit folder ``fit0/`` of short data; only the number of steps
    and profile points are made small (named below)."""
    from rotorbayes.commands.fit import fit

    monkeypatch.chdir(tmp_path)
    rb.save_experiment(brake[0], tmp_path / "est.csv")
    fit(["est.csv"], model="brake", out="fit0/")
    shorter = {"n_steps=2000": "n_steps=3", "n_points=11": "n_points=3"}
    for md in ("docs/identifiability.md", "docs/sampling.md"):
        for block in python_blocks(md):
            if "fit0/" not in block:
                continue
            for a, b in shorter.items():
                block = block.replace(a, b)
            exec(compile(block, md, "exec"), {})
    assert (tmp_path / "post").is_dir()


def test_every_field_of_a_problem_holds_its_declared_type(brake):
    """Loose inputs (a tuple of experiments, a list of channels, no weights, a named set)
    are normalised by the constructor: each field then holds the one type it declares."""
    import dataclasses
    import typing

    prob = inf.Problem(
        "brake",
        tuple(brake),
        channels=["theta_l"],
        base="thesis:4.3:P_ref",
        fixed=["dTc_u"],
        run_starts={"alpha0[1]": 0.1},
    )
    hints = typing.get_type_hints(inf.Problem)
    for f in dataclasses.fields(inf.Problem):
        want = hints[f.name]
        value = getattr(prob, f.name)
        origin = typing.get_origin(want)
        if origin is None:
            assert isinstance(value, want), (f.name, want, value)
        elif origin in (list, dict, tuple):
            assert isinstance(value, origin), (f.name, want, value)
            args = typing.get_args(want)
            items = value.items() if origin is dict else [(v,) for v in value]
            for item in items:
                for v, t in zip(item, args, strict=False):
                    if t is not Ellipsis:
                        assert isinstance(v, t), (f.name, want, v)
        else:  # an optional value (step): one of the two
            assert isinstance(value, tuple(a for a in typing.get_args(want))), (f.name, value)
    assert [f.name for f in dataclasses.fields(inf.Problem)][:2] == ["model", "experiments"]
    assert isinstance(prob.parameters, inf.ParameterMap)
