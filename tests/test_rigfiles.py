"""A real rig's files in (issue 36, point 1): MATLAB .mat v5 and v7.3, the CSV layouts
spreadsheets and loggers write, a mapping from the file's names to the model's and declared
units (s or ms; rad, deg or encoder counts), read the same by every command.

The files are made here as MATLAB and Simulink make them: v5 through ``scipy.io.savemat``;
v7.3 as an HDF5 file behind MATLAB's 512-byte header, arrays stored transposed (HDF5 holds
MATLAB's column-major arrays with their axes reversed), ``MATLAB_class`` attributes, a
struct as a group and a struct array as datasets of references into ``#refs#``.
"""

from __future__ import annotations

import json
import math

import h5py
import numpy as np
import pytest
import scipy.io

from rotorbayes.cli import main
from rotorbayes.io.examples import example_path
from rotorbayes.io.measurements import DataFileError, load_experiment, quantize
from rotorbayes.io.rigfiles import DEFAULT_COUNTS_PER_REV, ReadSpec
from rotorbayes.util import exitcodes as EXIT

SIGNALS = ("t", "u", "theta_u", "theta_l")


@pytest.fixture(scope="module")
def brake():
    """The bundled brake record (encoder-quantised angles, 200 Hz, 30 s)."""
    return load_experiment(example_path("example:brake_est"))


def _same(a, b, keys=SIGNALS) -> None:
    for k in keys:
        x, y = getattr(a, k), getattr(b, k)
        assert x.dtype == y.dtype == np.float64
        assert np.array_equal(x, y), (k, np.max(np.abs(x - y)))


def _csv(path, cols: dict, sep=",", comma=False, extra=None) -> None:
    """A CSV of ``cols`` (file name -> values) written with shortest round-trip numbers."""
    names = list(cols) + list(extra or {})
    rows = zip(*[np.asarray(v).tolist() for v in cols.values()], strict=True)
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(sep.join(names) + "\n")
        for row in rows:
            text = [repr(float(v)) for v in row] + list((extra or {}).values())
            line = sep.join(text)
            fh.write((line.replace(".", ",") if comma else line) + "\n")


# ------------------------------------------------------------------------------------------
# MATLAB v7.3, written as MATLAB writes it

_HEADER = (
    b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Thu Nov 26 12:00:00 2026 "
    b"HDF5 schema 1.00 ."
)


def _mat73(path, variables: dict) -> None:
    """Write ``variables`` (2-D arrays in MATLAB's orientation, dicts for structs, lists of
    dicts for struct arrays) the way MATLAB's ``save -v7.3`` does."""
    with h5py.File(path, "w", userblock_size=512) as f:
        refs = f.create_group("#refs#")
        counter = [0]

        def put(parent, name, value):
            if isinstance(value, dict):
                g = parent.create_group(name)
                g.attrs["MATLAB_class"] = np.bytes_("struct")
                for k, v in value.items():
                    put(g, k, v)
            elif isinstance(value, list):  # a 1xN struct array: fields of references
                g = parent.create_group(name)
                g.attrs["MATLAB_class"] = np.bytes_("struct")
                for field in value[0]:
                    targets = []
                    for elem in value:
                        counter[0] += 1
                        key = f"r{counter[0]}"
                        put(refs, key, elem[field])
                        targets.append(refs[key].ref)
                    d = g.create_dataset(
                        field, data=np.array(targets, dtype=h5py.ref_dtype).reshape(len(value), 1)
                    )
                    d.attrs["MATLAB_class"] = np.bytes_("cell")
            elif isinstance(value, str):
                d = parent.create_dataset(
                    name, data=np.array([ord(c) for c in value], np.uint16)[:, None]
                )
                d.attrs["MATLAB_class"] = np.bytes_("char")
            else:
                a = np.atleast_2d(np.asarray(value))
                d = parent.create_dataset(name, data=a.T)  # MATLAB's layout, axes reversed
                d.attrs["MATLAB_class"] = np.bytes_(
                    {
                        "f": "double" if a.dtype == np.float64 else "single",
                        "i": "int32",
                        "u": "uint32",
                    }[a.dtype.kind]
                )

        for k, v in variables.items():
            put(f, k, v)
    with open(path, "r+b") as fh:
        fh.write(_HEADER.ljust(116, b" ") + b"\0" * 8 + b"\x00\x02IM")


def _scope(ex, *, counts=False) -> dict:
    """Simulink's "Structure With Time": the voltage one signal, both encoders another."""
    th = np.column_stack([ex.theta_u, ex.theta_l])
    if counts:
        th = np.column_stack(
            [
                np.round(ex.theta_u / (2 * math.pi / DEFAULT_COUNTS_PER_REV["theta_u"])),
                np.round(ex.theta_l / (2 * math.pi / 40000.0)),
            ]
        ).astype(np.int32)
    return {
        "time": ex.t[:, None],
        "signals": [
            {"values": ex.u[:, None], "label": "Volt", "dimensions": np.array([[1.0]])},
            {"values": th, "label": "Encoders", "dimensions": np.array([[2.0]])},
        ],
        "blockName": "rig/Scope",
    }


SCOPE = (
    "t=ScopeData.time,u=ScopeData.signals(1).values,"
    "theta_u=ScopeData.signals(2).values(:,1),theta_l=ScopeData.signals(2).values(:,2)"
)


def _scope_v5(path, ex, counts=False) -> None:
    s = _scope(ex, counts=counts)
    sig = np.empty((1, 2), dtype=[("values", object), ("label", object), ("dimensions", object)])
    for j, e in enumerate(s["signals"]):
        sig[0, j] = (e["values"], e["label"], e["dimensions"])
    scipy.io.savemat(
        path, {"ScopeData": {"time": s["time"], "signals": sig, "blockName": s["blockName"]}}
    )


def test_mat_v5_structure_with_time_equals_csv(tmp_path, brake):
    _scope_v5(tmp_path / "run.mat", brake)
    got = load_experiment(tmp_path / "run.mat", read=ReadSpec.from_options(SCOPE))
    _same(got, brake)
    # The hash is that of the file's bytes.
    import hashlib

    assert got.sha256 == hashlib.sha256((tmp_path / "run.mat").read_bytes()).hexdigest()


def test_mat_v73_struct_array_and_counts_equal_csv(tmp_path, brake):
    # The bundled angles are whole counts, so counts * 2 pi / cpr gives them back exactly.
    for k in ("theta_u", "theta_l"):
        assert np.array_equal(
            quantize(getattr(brake, k), DEFAULT_COUNTS_PER_REV[k]), getattr(brake, k)
        )
    _mat73(tmp_path / "run73.mat", {"ScopeData": _scope(brake, counts=True)})
    with open(tmp_path / "run73.mat", "rb") as fh:
        assert fh.read(19) == b"MATLAB 7.3 MAT-file"
    got = load_experiment(
        tmp_path / "run73.mat", read=ReadSpec.from_options(SCOPE, angle_unit="counts")
    )
    _same(got, brake)


def test_mat_plain_variables_rows_or_columns_and_array_format(tmp_path, brake):
    # Variables named as the model names them need no mapping; row vectors are fine.
    scipy.io.savemat(
        tmp_path / "plain.mat",
        {
            "t": brake.t[None, :],
            "u": brake.u[:, None],
            "theta_u": brake.theta_u,
            "theta_l": brake.theta_l[:, None],
        },
    )
    _same(load_experiment(tmp_path / "plain.mat"), brake)
    # Simulink's "Array" format: one matrix, a column per signal; and its transpose.
    m = np.column_stack([brake.t, brake.u, brake.theta_u, brake.theta_l])
    _mat73(tmp_path / "array.mat", {"data": m, "dataT": m.T})
    cols = "t=data(:,1),u=data(:,2),theta_u=data(:,3),theta_l=data(:,4)"
    _same(load_experiment(tmp_path / "array.mat", read=ReadSpec.from_options(cols)), brake)
    rows = "t=dataT(1,:),u=dataT(2,:),theta_u=dataT(3,:),theta_l=dataT(4,:)"
    _same(load_experiment(tmp_path / "array.mat", read=ReadSpec.from_options(rows)), brake)


def test_mat_without_mapping_lists_what_it_holds(tmp_path, brake):
    _scope_v5(tmp_path / "run.mat", brake)
    with pytest.raises(DataFileError) as e:
        load_experiment(tmp_path / "run.mat")
    msg = str(e.value)
    assert "run.mat" in msg and "--columns" in msg
    assert "ScopeData.signals(2).values (6001x2)" in msg
    with pytest.raises(DataFileError, match=r"6001x2 matrix, not one signal.*\(:,K\)"):
        load_experiment(
            tmp_path / "run.mat", read=ReadSpec.from_options(SCOPE.replace("values(:,1)", "values"))
        )
    # A MATLAB object (a timeseries) holds no data outside MATLAB: named as such.
    _mat73(tmp_path / "obj.mat", {"t": brake.t[:, None]})
    with h5py.File(tmp_path / "obj.mat", "r+") as f:
        d = f.create_dataset("ts", data=np.array([[3707764736, 2, 1, 1, 1, 1]], np.uint32).T)
        d.attrs["MATLAB_class"] = np.bytes_("timeseries")
        d.attrs["MATLAB_object_decode"] = 3
    with pytest.raises(DataFileError, match=r"ts \(a MATLAB timeseries object: save its "):
        load_experiment(tmp_path / "obj.mat")
    with pytest.raises(
        DataFileError,
        match=r"ts is a MATLAB object of class timeseries.*"
        r"t = ts.Time, u = ts.Data",
    ):
        load_experiment(tmp_path / "obj.mat", read=ReadSpec.from_options("u=ts"))
    (tmp_path / "bad.mat").write_bytes(b"MATLAB 5.0 MAT-file" + b"\0" * 200)
    with pytest.raises(DataFileError, match="bad.mat: not a readable MATLAB file"):
        load_experiment(tmp_path / "bad.mat")


@pytest.mark.parametrize("sep,comma", [(";", True), ("\t", True), ("\t", False), (",", False)])
def test_spreadsheet_and_logger_csv_with_mapping(tmp_path, brake, sep, comma):
    cols = {"Time": brake.t, "Volt": brake.u, "Enc up": brake.theta_u, "Enc low": brake.theta_l}
    _csv(tmp_path / "log.csv", cols, sep=sep, comma=comma, extra={"Status": "ok"})
    spec = ReadSpec.from_options("t=Time,u=Volt,theta_u=Enc up,theta_l=Enc low")
    _same(load_experiment(tmp_path / "log.csv", read=spec), brake)


def test_units_ms_deg_counts_are_exactly_the_documented_conversions(tmp_path, brake):
    """A file in ms / deg / counts fits like the CSV its documented conversion makes."""
    t_ms = brake.t * 1000.0
    deg_u, deg_l = np.rad2deg(brake.theta_u), np.rad2deg(brake.theta_l)
    _csv(tmp_path / "raw.csv", {"t": t_ms, "u": brake.u, "theta_u": deg_u, "theta_l": deg_l})
    got = load_experiment(
        tmp_path / "raw.csv", read=ReadSpec.from_options(time_unit="ms", angle_unit="deg")
    )
    _csv(
        tmp_path / "si.csv",
        {
            "t": t_ms / 1000,
            "u": brake.u,
            "theta_u": deg_u * (math.pi / 180),
            "theta_l": deg_l * (math.pi / 180),
        },
    )
    _same(got, load_experiment(tmp_path / "si.csv"))
    # Counts with the encoders' own counts per revolution.
    cu = np.round(brake.theta_u / (2 * math.pi / 1000.0))
    _csv(
        tmp_path / "c.csv",
        {
            "t": brake.t,
            "u": brake.u,
            "theta_u": cu,
            "theta_l": np.round(brake.theta_l / (2 * math.pi / 40000.0)),
        },
    )
    got = load_experiment(
        tmp_path / "c.csv",
        read=ReadSpec.from_options(angle_unit="counts", counts_per_rev="theta_u=1000"),
    )
    assert np.array_equal(got.theta_u, cu * (2 * math.pi / 1000.0))
    assert np.array_equal(got.theta_l, brake.theta_l)


def test_guards_name_the_options(tmp_path, brake):
    _csv(
        tmp_path / "deg.csv",
        {
            "t": brake.t,
            "u": brake.u,
            "theta_u": np.rad2deg(brake.theta_u),
            "theta_l": np.rad2deg(brake.theta_l),
        },
    )
    with pytest.raises(
        DataFileError,
        match=r"deg.csv, line \d+: .*looks like degrees; "
        r"declare them with --angle-unit deg \(analysis file: angle_unit",
    ):
        load_experiment(tmp_path / "deg.csv")
    _csv(
        tmp_path / "cnt.csv",
        {
            "t": brake.t,
            "u": brake.u,
            "theta_u": np.round(brake.theta_u * 54934.256 / 2 / math.pi),
            "theta_l": np.round(brake.theta_l * 40000 / 2 / math.pi),
        },
    )
    with pytest.raises(
        DataFileError,
        match=r"encoder counts; declare them with --angle-unit "
        r"counts .*--counts-per-rev",
    ):
        load_experiment(tmp_path / "cnt.csv")
    _csv(
        tmp_path / "ms.csv",
        {"t": brake.t * 1000, "u": brake.u, "theta_u": brake.theta_u, "theta_l": brake.theta_l},
    )
    with pytest.raises(DataFileError, match=r"--time-unit ms \(analysis file: time_unit"):
        load_experiment(tmp_path / "ms.csv")
    # A declared unit that is wrong: the message says what was declared.
    with pytest.raises(DataFileError, match="read with --angle-unit deg; check the declared"):
        load_experiment(tmp_path / "cnt.csv", read=ReadSpec.from_options(angle_unit="deg"))
    # A mapping naming a column the file lacks.
    with pytest.raises(
        DataFileError,
        match=r"no column for u = 'Volt'.*the file's columns "
        r"are 't', 'u'",
    ):
        load_experiment(tmp_path / "ms.csv", read=ReadSpec.from_options("u=Volt"))


def test_cli_fit_of_mat_equals_csv_bit_for_bit_and_is_read_again(tmp_path, brake, capsys):
    """A new user's first command on a Simulink record, and its fit against the CSV's."""
    _mat73(tmp_path / "run.mat", {"ScopeData": _scope(brake, counts=True)})
    common = [
        "--model",
        "brake",
        "--p0",
        "thesis:4.3:P_ref",
        "--max-nfev",
        "4",
        "--free",
        "Tc_l,b_l",
    ]
    assert main(
        [
            "fit",
            str(tmp_path / "run.mat"),
            "--columns",
            SCOPE,
            "--angle-unit",
            "counts",
            "--out",
            str(tmp_path / "fm"),
            *common,
        ]
    ) in (0, 1)
    assert main(
        ["fit", str(example_path("example:brake_est")), "--out", str(tmp_path / "fc"), *common]
    ) in (0, 1)
    capsys.readouterr()
    dm = json.loads((tmp_path / "fm" / "fit.json").read_text())
    dc = json.loads((tmp_path / "fc" / "fit.json").read_text())
    assert dm["estimates"] == dc["estimates"] and dm["ssr"] == dc["ssr"]
    assert dm["data_files"][0]["read"] == {
        "columns": dict(ReadSpec.from_options(SCOPE).columns),
        "time_unit": "s",
        "angle_unit": "counts",
        "counts_per_rev": {},
    }
    assert "read" not in dc["data_files"][0]
    # Later commands read the file the same way: the same residuals at the estimates.
    from rotorbayes.inference.results import load_fit

    fm, fc = load_fit(tmp_path / "fm"), load_fit(tmp_path / "fc")
    assert np.array_equal(fm.problem.residuals(fm.x), fc.problem.residuals(fc.x))


def test_cli_refuses_bad_mapping_and_simulate_reads_mat_input(tmp_path, brake, capsys):
    scipy.io.savemat(
        tmp_path / "in.mat", {"Zeit": brake.t[:, None] * 1000, "Spannung": brake.u[:, None]}
    )
    assert (
        main(
            [
                "fit",
                "--model",
                "brake",
                str(tmp_path / "in.mat"),
                "--columns",
                "t",
                "--out",
                str(tmp_path / "x"),
            ]
        )
        == EXIT.REFUSED
    )
    err = capsys.readouterr().err
    assert "--columns: columns: 't' is not SIGNAL=NAME" in err and "Traceback" not in err
    assert (
        main(
            [
                "simulate",
                "--model",
                "upper",
                "--input-file",
                str(tmp_path / "in.mat"),
                "--columns",
                "t=Zeit,u=Spannung",
                "--time-unit",
                "ms",
                "--out",
                str(tmp_path / "sim.csv"),
            ]
        )
        == 0
    )
    sim = load_experiment(tmp_path / "sim.csv")
    assert np.array_equal(sim.u, brake.u) and sim.n == brake.n
    assert (
        main(
            [
                "simulate",
                "--model",
                "upper",
                "--columns",
                "t=Zeit",
                "--out",
                str(tmp_path / "sim2.csv"),
            ]
        )
        == EXIT.REFUSED
    )
    assert "--input-file" in capsys.readouterr().err


def test_analysis_file_reads_a_mat_file(tmp_path, brake):
    from rotorbayes.commands.study.analysis import AnalysisError, load_analysis, read_spec

    _scope_v5(tmp_path / "run.mat", brake)
    cols = ", ".join(f'{k} = "{v}"' for k, v in ReadSpec.from_options(SCOPE).columns.items())
    (tmp_path / "a.toml").write_text(
        f'[analysis]\nout = "o"\nconfig = "brake"\ndata = ["run.mat"]\n'
        f'columns = {{{cols}}}\nangle_unit = "rad"\n'
    )
    spec = read_spec(load_analysis(tmp_path / "a.toml"))
    _same(load_experiment(tmp_path / "run.mat", read=spec), brake)
    (tmp_path / "b.toml").write_text(
        '[analysis]\nout = "o"\nconfig = "brake"\ndata = ["run.mat"]\nangle_unit = "grad"\n'
    )
    with pytest.raises(
        AnalysisError,
        match=r"b.toml: \[analysis\] angle unit 'grad': choose "
        "rad, deg or counts",
    ):
        load_analysis(tmp_path / "b.toml")


def test_run_fits_a_mat_file_as_its_analysis_file_says(tmp_path, brake, capsys):
    from rotorbayes.commands.study.analysis import _command_line

    _scope_v5(tmp_path / "run.mat", brake)
    cols = ", ".join(f'{k} = "{v}"' for k, v in ReadSpec.from_options(SCOPE).columns.items())
    (tmp_path / "a.toml").write_text(
        f'[analysis]\nout = "o"\nconfig = "brake"\ndata = ["run.mat"]\ncolumns = {{{cols}}}\n'
        '[fit]\np0 = "thesis:4.3:P_ref"\nfree = ["Tc_l", "b_l"]\nmax_nfev = 3\n'
    )
    assert main(["run", str(tmp_path / "a.toml")]) in (0, 1)
    log = (tmp_path / "o" / "log.txt").read_text()
    # The stage's command line is one to type: the MATLAB names quoted for the shell.
    assert "--columns 't=ScopeData.time,u=ScopeData.signals(1).values," in log
    doc = json.loads((tmp_path / "o" / "fit0" / "fit.json").read_text())
    assert doc["data_files"][0]["read"]["columns"]["t"] == "ScopeData.time"
    assert (
        _command_line("fit", {"data": ["my data.csv"], "columns": "t=d(:,1)"})
        == "fit 'my data.csv' --columns 't=d(:,1)'"
    )


def test_a_loggers_units_row_is_read_and_checked(tmp_path, brake):
    deg = {
        "Time": brake.t * 1000,
        "Volt": brake.u,
        "A1": np.rad2deg(brake.theta_u),
        "A2": np.rad2deg(brake.theta_l),
    }
    _csv(tmp_path / "log.csv", deg, sep=";", comma=True)
    lines = (tmp_path / "log.csv").read_text().splitlines(keepends=True)
    lines.insert(1, "[ms];[V];[deg];[deg]\n")
    (tmp_path / "log.csv").write_text("".join(lines))
    cols = "t=Time,u=Volt,theta_u=A1,theta_l=A2"
    got = load_experiment(
        tmp_path / "log.csv", read=ReadSpec.from_options(cols, time_unit="ms", angle_unit="deg")
    )
    assert got.n == brake.n
    with pytest.raises(
        DataFileError,
        match=r"log.csv, line 2: the units row gives theta_u in "
        r"deg, but it is read in rad: declare the unit with --angle-unit deg",
    ):
        load_experiment(tmp_path / "log.csv", read=ReadSpec.from_options(cols, time_unit="ms"))
    # Bad data on the first line after the units row still names its line.
    lines[2] = "0;x;0;0\n"
    (tmp_path / "log.csv").write_text("".join(lines))
    with pytest.raises(DataFileError, match=r"line 3: value 'x' in column Volt"):
        load_experiment(
            tmp_path / "log.csv", read=ReadSpec.from_options(cols, time_unit="ms", angle_unit="deg")
        )


def test_every_form_gives_the_csvs_residuals_bit_for_bit(tmp_path, brake):
    """The same record as .mat v5, v7.3 (counts), a spreadsheet's semicolon CSV and a
    logger's tab CSV in ms: the residual vector at one parameter set equals the plain
    CSV's bit for bit."""
    from rotorbayes.inference import Problem
    from rotorbayes.model import Model, parameters

    _scope_v5(tmp_path / "v5.mat", brake)
    _mat73(tmp_path / "v73.mat", {"ScopeData": _scope(brake, counts=True)})
    names = {"Time": brake.t, "Volt": brake.u, "Up": brake.theta_u, "Low": brake.theta_l}
    _csv(tmp_path / "sheet.csv", names, sep=";", comma=True)
    t_ms = brake.t * 1000.0
    _csv(
        tmp_path / "log.txt",
        {"ms": t_ms, "V": brake.u, "a": brake.theta_u, "b": brake.theta_l},
        sep="\t",
    )
    _csv(
        tmp_path / "log_si.csv",
        {"t": t_ms / 1000, "u": brake.u, "theta_u": brake.theta_u, "theta_l": brake.theta_l},
    )
    named = "t=Time,u=Volt,theta_u=Up,theta_l=Low"
    forms = [
        (tmp_path / "v5.mat", ReadSpec.from_options(SCOPE), brake),
        (tmp_path / "v73.mat", ReadSpec.from_options(SCOPE, angle_unit="counts"), brake),
        (tmp_path / "sheet.csv", ReadSpec.from_options(named), brake),
        (
            tmp_path / "log.txt",
            ReadSpec.from_options("t=ms,u=V,theta_u=a,theta_l=b", "ms"),
            load_experiment(tmp_path / "log_si.csv"),
        ),
    ]
    base = parameters.resolve(None, config="brake")

    def residuals(ex):
        prob = Problem(Model("brake"), [ex], free=["Tc_l", "b_l"], base=base)
        return prob.residuals(prob.start_vector(base))

    for path, spec, csv in forms:
        got = load_experiment(path, read=spec)
        _same(got, csv)
        assert np.array_equal(residuals(got), residuals(csv)), path.name


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (
            ["--counts-per-rev", "1000"],
            "--counts-per-rev: counts per revolution given, but the "
            "angles are read in rad; they are for --angle-unit counts",
        ),
        (
            ["--angle-unit", "counts", "--counts-per-rev", "theta_x=5"],
            "--counts-per-rev: counts per revolution: 'theta_x' is not an angle",
        ),
        (
            ["--angle-unit", "counts", "--counts-per-rev", "0"],
            "--counts-per-rev: counts per revolution of theta_u: 0.0",
        ),
        (["--columns", "t=a,t=b"], "--columns: columns: t is mapped twice"),
        (["--columns", "x=a"], "--columns: columns: 'x' is not a signal of the model"),
    ],
)
def test_bad_read_options_are_refused_naming_the_option(tmp_path, capsys, argv, needle):
    assert (
        main(["fit", "--model", "brake", "example:brake_est", *argv, "--out", str(tmp_path / "f")])
        == EXIT.REFUSED
    )
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "f").exists()
