"""Hostile and careless input, round two (issue 31): every case a red team tried ends in one
clear message with the documented exit code (``rotorbayes.util.exitcodes``: 2 = refused input),
never a traceback, a Python warning or a silently wrong result.

Covered: recursion bombs (TOML and JSON nested 100 000 deep) wherever a file is read; the
numeric options' ranges (``--step``, ``--weights``, the tolerances); ``--fixed`` of every
free parameter; a file too short to fit; fit.json values that are NaN, negative or absurd;
user effects carried by ``simulate --params FIT/``, ``multistart --around FIT/`` and
``params FIT/fit.json`` (with the trust rules of ``fit --p0 FIT/``); and the Python API's
argument checks (``Problem``, ``Problem.residuals``, ``rotorbayes.simulate``).
The misuse of the command line in general is in ``test_cli_misuse.py``, faults of the
environment in ``test_faults.py``.
"""

from __future__ import annotations

import json
import shutil
import time
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import rotorbayes as rb
from rotorbayes import inference
from rotorbayes.cli import main
from rotorbayes.io.tomlfile import MAX_NESTING, nesting_depth
from rotorbayes.model.parameters import thesis_set
from rotorbayes.util import exitcodes as EXIT

ROOT = Path(__file__).resolve().parents[1]
DEEP = 100_000  # the red team's nesting depth
USER_FILE = ROOT / "examples" / "angle_friction.py"


def refused(capsys, argv, *needles, code=EXIT.REFUSED) -> str:
    """Run ``argv`` in-process: exit ``code``, one line ``rotorbayes CMD: error: ...``
    holding every needle, no traceback and no Python warning."""
    got = main(argv)
    cap = capsys.readouterr()
    err = cap.err.strip()
    assert got == code, (got, err)
    assert "Traceback" not in cap.err and "Warning" not in cap.err, err
    assert len(err.splitlines()) == 1, err
    assert err.startswith(f"rotorbayes {argv[0]}: error: "), err
    for n in needles:
        assert n in err, (n, err)
    return err


def listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def _upper_data(path: Path, seconds: float = 4.0) -> Path:
    p = rb.parameters.resolve(
        dict(k_m=3.1, Tc_u=0.62, dTc_u=0.03, b_u=1.7, db_u=0.05), config="upper"
    )
    t, u = rb.signals.make_signal("est", seconds, rate=200.0, seed=4)
    sim = rb.simulate(p, u, dt=1 / 200, config="upper", quantize_angles=True)
    rb.save_experiment(sim.to_experiment("upper"), path)
    return path


@pytest.fixture(scope="module")
def proj(tmp_path_factory):
    """data/upper.csv (4 s at 200 Hz) and fit/, an upper-configuration fit of it."""
    d = tmp_path_factory.mktemp("proj")
    (d / "data").mkdir()
    data = _upper_data(d / "data" / "upper.csv")
    assert main(["fit", "--model", "upper", str(data), "--out", str(d / "fit")]) == 0
    return d


@pytest.fixture(scope="module")
def user_fit(tmp_path_factory):
    """A coupled fit with a user effect (a copy of examples/angle_friction.py): its folder,
    the effect file and the data file."""
    d = tmp_path_factory.mktemp("user")
    eff = d / "angle_friction.py"
    shutil.copy(USER_FILE, eff)
    spec = f"{eff}:angle_friction"
    t, u = rb.signals.estimation_signal(4.0, seed=11, rate=200.0)
    truth = dict(thesis_set("4.2", "P_ref"), a_fric=0.2, phi_fric=-1.1)
    sim = rb.simulate(
        truth, u, dt=t[1] - t[0], config="coupled", effects=[spec], quantize_angles=True
    )
    data = d / "est.csv"
    rb.save_experiment(sim.to_experiment(), data)
    fit = d / "fitE"
    assert main(
        [
            "fit",
            "--model",
            "coupled",
            str(data),
            "--p0",
            "thesis:4.2:P_ref",
            "--add",
            spec,
            "--max-nfev",
            "3",
            "--no-search",
            "--out",
            str(fit),
        ]
    ) in (0, 1)
    return SimpleNamespace(folder=fit, effect=eff, data=data)


@pytest.fixture
def here(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return tmp_path


# ---------------------------------------------------------------- 1. recursion bombs
def _toml_bomb(path: Path, line: int = 1) -> Path:
    path.write_text("# a parameter file\n" * (line - 1) + "J_l = " + "[" * DEEP + "]" * DEEP + "\n")
    return path


@pytest.mark.parametrize("role", ["analysis", "p0", "base", "params", "priors", "around", "show"])
def test_a_toml_file_nested_100000_deep_is_refused_with_its_file_and_line(proj, here, capsys, role):
    """Was: RecursionError inside tomllib, exit 1 ("not converged")."""
    bomb = _toml_bomb(here / "bomb.toml", line=3)
    data = str(proj / "data" / "upper.csv")
    argv = {
        "analysis": ["run", "bomb.toml"],
        "p0": ["fit", "--model", "upper", data, "--p0", "bomb.toml", "--out", "o"],
        "base": ["fit", "--model", "upper", data, "--base", "bomb.toml", "--out", "o"],
        "params": ["simulate", "--model", "upper", "--params", "bomb.toml", "--out", "s.csv"],
        "priors": ["sample", str(proj / "fit"), "--priors", "bomb.toml", "--out", "o"],
        "around": ["multistart", "--model", "upper", data, "--around", "bomb.toml", "--out", "o"],
        "show": ["params", "bomb.toml"],
    }[role]
    refused(capsys, argv, "bomb.toml, line 3", f"nested more than {MAX_NESTING} levels deep")
    assert listing(here) == [bomb.name]


@pytest.mark.parametrize("cmd", ["compare", "diagnose", "params", "p0", "simulate", "sample"])
def test_a_fit_json_nested_100000_deep_is_refused(proj, here, capsys, cmd):
    """Was: RecursionError inside json, exit 1."""
    bad = here / "bad"
    shutil.copytree(proj / "fit", bad)
    text = (bad / "fit.json").read_text().rstrip()
    assert text.endswith("}")
    (bad / "fit.json").write_text(text[:-1] + ', "x": ' + "[" * DEEP + "]" * DEEP + "}\n")
    argv = {
        "compare": ["compare", "bad"],
        "diagnose": ["diagnose", "bad"],
        "params": ["params", "bad/fit.json"],
        "p0": [
            "fit",
            "--model",
            "upper",
            str(proj / "data" / "upper.csv"),
            "--p0",
            "bad",
            "--out",
            "o",
        ],
        "simulate": ["simulate", "--model", "upper", "--params", "bad", "--out", "s.csv"],
        "sample": ["sample", "bad", "--out", "o"],
    }[cmd]
    refused(capsys, argv, "fit.json, line", f"nested more than {MAX_NESTING} levels deep")
    assert listing(here) == ["bad"]


def test_a_multistart_json_nested_too_deep_is_refused_as_a_start(proj, here, capsys):
    (here / "ms").mkdir()
    (here / "ms" / "multistart.json").write_text('{"names": ' + "[" * DEEP + "]" * DEEP + "}")
    refused(
        capsys,
        ["fit", "--model", "upper", str(proj / "data" / "upper.csv"), "--p0", "ms", "--out", "o"],
        "multistart.json, line 1",
        "nested more than",
    )


def test_the_nesting_scan_skips_strings_and_comments_and_is_cheap():
    deep = "[" * 300
    assert nesting_depth(
        f'a = "{deep}"\n# {deep}\nb = \'{deep}\'\nc = [[1], [2]]\nd = """\n{deep}\n"""\n', limit=64
    ) == (2, None)
    assert nesting_depth('{"a": "\\"' + deep + '", "b": [[{}]]}', kind="json") == (4, None)
    depth, where = nesting_depth("x = 1\n" + "[" * 65 + "]" * 65, limit=64)
    assert depth == 65 and where == 6 + 64
    # The scan stops at the limit: a bomb of 10 million brackets costs nothing.
    t0 = time.perf_counter()
    assert nesting_depth("[" * 10_000_000)[1] == MAX_NESTING
    assert time.perf_counter() - t0 < 0.5


# ------------------------------------------------------------- 2. numeric options
@pytest.mark.parametrize(
    "step,needles",
    [
        (
            "1e-12",
            [
                "--step 1e-12 s",
                "shorter than a hundredth of the sample interval",
                "give a step between 5e-05 s and 4 s",
                "upper.csv",
            ],
        ),
        ("1e9", ["--step 1e+09 s", "longer than the record", "upper.csv (4 s)"]),
    ],
)
def test_step_has_a_range_from_the_data(proj, here, capsys, step, needles):
    """Was: 1e-12 "Unable to allocate 29.1 TiB ... check the disk" (exit 3); 1e9 accepted."""
    for cmd in ("fit", "multistart"):
        refused(
            capsys,
            [
                cmd,
                "--model",
                "upper",
                str(proj / "data" / "upper.csv"),
                "--step",
                step,
                "--out",
                "o",
            ],
            *needles,
        )
    assert listing(here) == []


def test_step_is_checked_against_the_validation_files_too(proj, here, capsys):
    short = _upper_data(here / "short.csv", seconds=2.0)
    refused(
        capsys,
        [
            "fit",
            "--model",
            "upper",
            str(proj / "data" / "upper.csv"),
            "--validate",
            str(short),
            "--step",
            "3",
            "--out",
            "o",
        ],
        "--step 3 s is longer than the record of",
        "short.csv",
    )
    assert listing(here) == ["short.csv"]


@pytest.mark.parametrize("w", ["1e308", "1e-308", "1e5", "1e-5"])
def test_extreme_weights_are_refused_without_warnings(proj, here, capsys, w):
    """Was: RuntimeWarnings with source paths and scipy's "array must not contain infs"
    (1e308); standard errors divided by zero (1e-308)."""
    refused(
        capsys,
        [
            "fit",
            "--model",
            "upper",
            str(proj / "data" / "upper.csv"),
            "--weights",
            f"theta_u={w}",
            "--out",
            "o",
        ],
        "--weights: the weight of theta_u",
        "between 0.0001 and 10000",
        "--channels",
    )


@pytest.mark.parametrize("tol", ["1e-300", "0.5"])
def test_tolerances_outside_the_machines_precision_are_refused(proj, here, capsys, tol):
    """Was: scipy's UserWarning with its source path, and with all three below the machine
    epsilon scipy's own message."""
    argv = ["fit", "--model", "upper", str(proj / "data" / "upper.csv"), "--out", "o"]
    for flag in ("--ftol", "--xtol", "--gtol"):
        refused(capsys, [*argv, flag, tol], f"argument {flag}: got {tol}", ">= 1e-15 and <= 0.1")


def test_fixing_every_free_parameter_is_refused(proj, here, capsys):
    """Was: "zero-size array to reduction operation maximum which has no identity"."""
    refused(
        capsys,
        [
            "fit",
            "--model",
            "upper",
            str(proj / "data" / "upper.csv"),
            "--fixed",
            "k_m,Tc_u,b_u,dTc_u,db_u",
            "--out",
            "o",
        ],
        "--fixed k_m,Tc_u,b_u,dTc_u,db_u",
        "nothing is left to fit",
        "free at least one",
    )
    assert listing(here) == []


def test_a_file_too_short_to_fit_is_refused(proj, here, capsys):
    """Was: a RuntimeWarning, "nan %" and an "at the encoder floor" verdict."""
    lines = (proj / "data" / "upper.csv").read_text().splitlines(keepends=True)
    head = [ln for ln in lines if ln.startswith("#")]
    body = [ln for ln in lines if not ln.startswith("#")]
    (here / "ten.csv").write_text("".join(head + body[:11]))  # the header and 10 rows
    for cmd in ("fit", "multistart"):
        refused(
            capsys,
            [cmd, "--model", "upper", "ten.csv", "--out", "o"],
            "ten.csv: only 10 samples",
            "at least 100",
        )
    assert listing(here) == ["ten.csv"]


def test_undetermined_standard_errors_are_words_not_nan_percent():
    from rotorbayes.commands.fit import _uncertainty_words

    nan = float("nan")
    u = SimpleNamespace(
        inflation=lambda: np.array([nan, nan]),
        warning=lambda: "",
        shares=lambda: {
            "a": dict(noise=nan, model_error=nan, input_hold=nan),
            "b": dict(noise=nan, model_error=nan, input_hold=nan),
        },
        names=["a", "b"],
        n_eff=nan,
        n_samples=10,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "Mean of empty slice"
        text = _uncertainty_words(SimpleNamespace(uncertainty=u))
    assert "nan" not in text and "no parameter has a finite standard error" in text


# ------------------------------------------------------------ 3. fit.json values
@pytest.mark.parametrize("where", ["estimates", "params"])
@pytest.mark.parametrize(
    "value,shown", [(float("nan"), "NaN"), (None, "null"), (-5.0, "-5"), (1e300, "1e+300")]
)
def test_a_hand_edited_fit_json_value_names_file_parameter_and_value(
    proj, here, capsys, where, value, shown
):
    """Was: "the model cannot be simulated at this fit" (diagnose), or a silent run on a
    motor constant of -5 or NaN (compare, simulate --params)."""
    bad = here / "bad"
    shutil.copytree(proj / "fit", bad)
    doc = json.loads((bad / "fit.json").read_text())
    if where == "estimates":
        doc["estimates"]["k_m"]["value"] = value
    else:
        doc["params"]["k_m"] = value
    (bad / "fit.json").write_text(json.dumps(doc))  # json writes NaN as NaN
    needles = ["bad/fit.json", f"k_m = {shown}", "fit again", "correct the value"]
    for argv in (
        ["compare", "bad", "--out", "c"],
        ["diagnose", "bad"],
        ["identify", "bad", "--out", "i"],
    ):
        refused(capsys, argv, *needles)
    if where == "params":  # commands that read the values alone
        for argv in (
            ["params", "bad/fit.json"],
            ["simulate", "--model", "upper", "--params", "bad", "--out", "s.csv"],
            [
                "multistart",
                "--model",
                "upper",
                str(proj / "data" / "upper.csv"),
                "--around",
                "bad",
                "--out",
                "m",
            ],
        ):
            refused(capsys, argv, *needles)
    assert listing(here) == ["bad"]


# ---------------------------------------------------------------- 4. user effects
def test_simulate_params_of_a_fit_carries_its_user_effect(user_fit, here, capsys):
    """Was: the effect dropped silently (its parameters ignored)."""
    assert (
        main(
            [
                "simulate",
                "--model",
                "coupled",
                "--params",
                str(user_fit.folder),
                "--duration",
                "2",
                "--rate",
                "200",
                "--out",
                "s.csv",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "effects carried over from" in out and "angle_friction" in out
    ex = rb.load_experiment(here / "s.csv")
    assert "angle_friction" in ex.meta["effects"] and "param.a_fric" in ex.meta
    # It is the fit's simulation: the same as the Python API with the effect on.
    doc = json.loads((user_fit.folder / "fit.json").read_text())
    vals = {k: v for k, v in doc["params"].items() if v is not None}
    sim = rb.simulate(
        vals, ex.u, dt=ex.dt, config="coupled", effects=[f"{user_fit.effect}:angle_friction"]
    )
    assert np.array_equal(sim.theta_l, ex.theta_l)


def test_params_and_multistart_around_a_fit_with_a_user_effect(user_fit, here, capsys):
    """Was: "unknown parameter 'a_fric'" without what to do."""
    assert main(["params", str(user_fit.folder / "fit.json")]) == 0
    out = capsys.readouterr().out
    assert "a_fric" in out and "(user effect angle_friction)" in out
    assert (
        main(
            [
                "multistart",
                "--model",
                "coupled",
                str(user_fit.data),
                "--around",
                str(user_fit.folder),
                "--starts",
                "2",
                "--max-nfev",
                "2",
                "--out",
                "ms",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "effects carried over from" in out
    doc = json.loads((here / "ms" / "multistart.json").read_text())
    assert "a_fric" in doc["names"] and "phi_fric" in doc["names"]


def test_a_changed_user_effect_file_needs_trust_for_simulate_and_multistart(user_fit, here, capsys):
    changed = here / "fitC"
    shutil.copytree(user_fit.folder, changed)
    eff = here / "angle_friction.py"
    eff.write_text(user_fit.effect.read_text() + "\n# edited\n")
    doc = json.loads((changed / "fit.json").read_text())
    old = doc["added_effects"][0]
    doc["added_effects"] = [f"{eff}:angle_friction"]
    doc["effect_files"] = {str(eff): doc["effect_files"][old.rpartition(":")[0]]}
    (changed / "fit.json").write_text(json.dumps(doc))
    # Showing the values imports nothing: no trust needed, and the changed file never ran.
    eff.write_text(eff.read_text() + "raise SystemExit('imported')\n")
    assert main(["params", "fitC/fit.json"]) == 0
    assert "a_fric" in capsys.readouterr().out
    eff.write_text(user_fit.effect.read_text() + "\n# edited\n")
    for argv in (
        ["simulate", "--model", "coupled", "--params", "fitC", "--duration", "2", "--out", "s.csv"],
        [
            "multistart",
            "--model",
            "coupled",
            str(user_fit.data),
            "--around",
            "fitC",
            "--starts",
            "2",
            "--out",
            "ms",
        ],
    ):
        refused(capsys, argv, "changed since the fit", "--trust-effects")
        assert (
            main(
                [
                    *argv,
                    "--trust-effects",
                    *(["--max-nfev", "2"] if argv[0] == "multistart" else []),
                ]
            )
            == 0
        ), argv
        assert "importing it because of --trust-effects" in capsys.readouterr().err


# --------------------------------------------------------------------- 5. Python API
def test_problem_names_its_bad_arguments(proj):
    ex = rb.load_experiment(proj / "data" / "upper.csv")
    with pytest.raises(ValueError, match="experiments is None.*load_experiment"):
        inference.Problem("coupled", None)
    with pytest.raises(
        ValueError,
        match=r"experiments\[0\] is the path 'a.csv'.*"
        r"rotorbayes.load_experiment\('a.csv'\)",
    ):
        inference.Problem("coupled", ["a.csv"])
    with pytest.raises(ValueError, match="experiments is the path"):
        inference.Problem("upper", str(proj / "data" / "upper.csv"))
    with pytest.raises(
        ValueError,
        match=r"free = 'k_m': give a list of names, e.g. "
        r"free=\['k_m'\]",
    ):
        inference.Problem("upper", [ex], free="k_m")
    with pytest.raises(ValueError, match="base: k_m = 'big' is not a number"):
        inference.Problem("upper", [ex], base={"k_m": "big"})
    with pytest.raises(ValueError, match="weight of channel theta_u is 1e\\+308"):
        inference.Problem("upper", [ex], weights={"theta_u": 1e308})
    with pytest.raises(ValueError, match="step 1e-12 s is shorter"):
        inference.Problem("upper", [ex], step=1e-12)
    prob = inference.Problem("upper", [ex])
    x = prob.x_from(prob.base)
    for bad in (x[:2], np.r_[x, 1.0], x[:, None]):
        for call in (prob.residuals, prob.evaluate, prob.simulate):
            with pytest.raises(ValueError, match="5 free parameter"):
                call(bad)
    with pytest.raises(ValueError, match="one number per free parameter"):
        prob.residuals(["a"] * 5)
    with pytest.raises(ValueError, match="nothing left to fit"):
        inference.fit(inference.Problem("upper", [ex], free=[]))


def test_simulate_names_its_bad_arguments_and_accepts_read_only_arrays(tmp_path):
    t, u = rb.signals.make_signal("est", 2.0, rate=200.0, seed=1)
    ref = rb.simulate(None, u, dt=0.005, config="brake")
    np.save(tmp_path / "u.npy", u)
    mm = np.load(tmp_path / "u.npy", mmap_mode="r")  # read-only, as pandas' columns can be
    ro = u.copy()
    ro.flags.writeable = False
    for v in (mm, ro):
        assert np.array_equal(rb.simulate(None, v, dt=0.005, config="brake").theta_l, ref.theta_l)
    # A prescribed upper angle that is read-only, too.
    thu = ref.theta_u.copy()
    thu.flags.writeable = False
    rb.simulate(None, None, theta_u=thu, dt=0.005, config="coupled")
    with pytest.raises(ValueError, match="u is the text 'abc'"):
        rb.simulate(None, "abc", dt=0.005)
    with pytest.raises(ValueError, match="u must hold the input voltage"):
        rb.simulate(None, ["1", "x", "2"], dt=0.005)
    with pytest.raises(ValueError, match=r"params\['k_m'\] = 'big' is not a number"):
        rb.simulate({"k_m": "big"}, u, dt=0.005)
    with pytest.raises(ValueError, match="dt = '0.005'"):
        rb.simulate(None, u, dt="0.005")
    with pytest.raises(ValueError, match="alpha0 = 'x' is not a number"):
        rb.simulate(None, u, dt=0.005, alpha0="x")
