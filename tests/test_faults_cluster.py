"""Faults and hostile input, round two (issue 31): what a careless or hostile user met.

* a "scheduler" that is not one -- a web server, a program that accepts and never answers,
  a closed port, a peer that closes at once, a Dask peer that never takes the client: exit
  code 3 with the address within the documented wait, for every command that takes one,
  and nothing from Dask at exit (no "Unable to allocate ... EiB", no ``Client.__del__``);
* a disk that fills up while ``sample`` writes its summary: the reserve holds every file,
  and a write that fails anyway (beyond the reserve, a monkeypatched ENOSPC) ends with exit
  code 3 naming the folder and what was kept, never a traceback or a crash;
* a truncated, empty, overwritten or foreign posterior.nc given to ``identify --posterior``:
  a clear refusal (exit code 2) naming the file and what to do;
* a fit.json this user did not write (another owner, writable by others, unpacked from an
  archive) naming an effect file with its right SHA-256: not imported without
  ``--trust-effects``, and why is said.

The fake schedulers are tiny TCP servers in threads of the test; the time bounds are
generous for a loaded 2-core machine (the assertions are on exit codes and words).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import random
import shutil
import socket
import subprocess
import sys
import tarfile
import textwrap
import threading
import time
from pathlib import Path

import pytest

import rotorbayes as rb
from rotorbayes.cli import main
from rotorbayes.inference import parallel
from rotorbayes.util import exitcodes as EXIT

ENV = {**os.environ, "NUMBA_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1", parallel.TIMEOUT_ENV: "3"}
ENV.pop(parallel.SCHEDULER_ENV, None)
#: Seconds a refused scheduler may take, start-up of the interpreter and rotorbayes included
#: (the wait is 3 s; a loaded 2-core machine needs the rest).
BOUND = 60.0


# ------------------------------------------------------------------------- fake servers
class FakeServer:
    """A TCP server in a thread: ``kind`` 'http' answers what it reads with an HTTP error
    (as a web server, or the Dask dashboard, does); 'silent' accepts and never answers;
    'closer' accepts and closes at once; 'handshake' answers with a valid Dask handshake
    and then says nothing (a Dask peer that never takes the client)."""

    def __init__(self, kind: str):
        self.kind = kind
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.port = self.sock.getsockname()[1]
        self.address = f"tcp://127.0.0.1:{self.port}"
        self.conns: list[socket.socket] = []
        self.stop = threading.Event()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while not self.stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(conn)
            threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _serve(self, conn: socket.socket) -> None:
        with contextlib.suppress(OSError):
            if self.kind == "http":
                conn.recv(4096)
                conn.sendall(
                    b"HTTP/1.1 400 Bad Request\r\nContent-Type: text/plain\r\n"
                    b"Content-Length: 11\r\n\r\nBad Request"
                )
            elif self.kind == "closer":
                conn.close()
                return
            elif self.kind == "handshake":
                conn.sendall(parallel._handshake_bytes())
            self.stop.wait(120)

    def close(self) -> None:
        self.stop.set()
        for c in [self.sock, *self.conns]:
            with contextlib.suppress(OSError):
                c.close()


@pytest.fixture
def server(request):
    s = FakeServer(request.param)
    yield s
    s.close()


def closed_port() -> str:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return f"tcp://127.0.0.1:{port}"


def cli(args, cwd, env=None):
    return subprocess.Popen(
        [sys.executable, "-m", "rotorbayes.cli", *args],
        cwd=cwd,
        env={**ENV, **(env or {})},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def assert_clean_cluster_refusal(code: int, err: str, address: str) -> None:
    assert code == EXIT.ENVIRONMENT, err
    assert address in err, err
    for bad in (
        "Traceback",
        "EiB",
        "Unable to allocate",
        "Client.__del__",
        "Exception ignored",
        "MemoryError",
    ):
        assert bad not in err, (bad, err)


# --------------------------------------------------------------------------- projects
def _short_upper(folder: Path, seconds=4.0) -> Path:
    p = rb.parameters.resolve(
        dict(k_m=3.1, Tc_u=0.62, dTc_u=0.03, b_u=1.7, db_u=0.05), config="upper"
    )
    t, u = rb.signals.make_signal("est", seconds, rate=200.0, seed=4)
    sim = rb.simulate(p, u, dt=1 / 200, config="upper", quantize_angles=True)
    path = folder / "upper.csv"
    rb.save_experiment(sim.to_experiment("upper"), path)
    return path


@pytest.fixture(scope="module")
def proj(tmp_path_factory):
    """data/upper.csv (4 s at 200 Hz) and fit/ made from it."""
    d = tmp_path_factory.mktemp("proj")
    (d / "data").mkdir()
    data = _short_upper(d / "data")
    assert main(["fit", "--model", "upper", str(data), "--out", str(d / "fit")]) == 0
    return d


@pytest.fixture(scope="module")
def post(proj, tmp_path_factory):
    out = tmp_path_factory.mktemp("post") / "S"
    assert (
        main(
            [
                "sample",
                str(proj / "fit"),
                "--walkers",
                "10",
                "--steps",
                "20",
                "--ensembles",
                "1",
                "--max-draws",
                "5",
                "--quiet",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    return out


def listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


# ------------------------------------------------ 1. schedulers that are not schedulers
@pytest.mark.parametrize("server", ["http", "silent", "closer"], indirect=True)
def test_the_probe_refuses_what_does_not_speak_dask_within_the_wait(server):
    t0 = time.perf_counter()
    with pytest.raises(parallel.ClusterError) as e:
        parallel.probe_scheduler(server.address, "--scheduler", 2.0)
    took = time.perf_counter() - t0
    msg = str(e.value)
    assert server.address in msg and "(from --scheduler)" in msg
    assert took < 2.0 + 5.0, took
    said = {
        "http": ["not as a Dask scheduler", "HTTP/1.1 400 Bad Request", "dashboard"],
        "silent": ["did not answer as a Dask scheduler within 2 s"],
        "closer": ["closed it without answering"],
    }[server.kind]
    assert all(s in msg for s in said), msg


def test_the_probe_waits_for_a_closed_port_then_names_it():
    address = closed_port()
    t0 = time.perf_counter()
    with pytest.raises(parallel.ClusterError, match="no Dask scheduler answered at .* within 1 s"):
        parallel.probe_scheduler(address, parallel.SCHEDULER_ENV, 1.0)
    assert 0.9 < time.perf_counter() - t0 < 6.0


def test_the_probe_takes_a_peer_that_speaks_the_handshake():
    s = FakeServer("handshake")
    try:
        parallel.probe_scheduler(s.address, "--scheduler", 5.0)  # no error: it answered as Dask
    finally:
        s.close()


@pytest.mark.parametrize("kind", ["http", "silent", "closed"])
def test_multistart_on_a_scheduler_that_is_not_one_ends_with_exit_3(kind, tmp_path):
    s = None if kind == "closed" else FakeServer(kind)
    address = closed_port() if s is None else s.address
    try:
        t0 = time.perf_counter()
        p = cli(
            [
                "multistart",
                "--model",
                "upper",
                "example:upper_est",
                "--starts",
                "2",
                "--scheduler",
                address,
                "--out",
                "ms",
            ],
            tmp_path,
        )
        _, err = p.communicate(timeout=BOUND + 60)
        took = time.perf_counter() - t0
    finally:
        if s is not None:
            s.close()
    assert_clean_cluster_refusal(p.returncode, err, address)
    assert "(from --scheduler)" in err and took < BOUND, (took, err)
    assert listing(tmp_path) == []


@pytest.mark.parametrize("server", ["http", "silent"], indirect=True)
def test_sample_on_a_scheduler_from_the_environment_ends_with_exit_3(server, proj, tmp_path):
    t0 = time.perf_counter()
    p = cli(
        [
            "sample",
            str(proj / "fit"),
            "--walkers",
            "10",
            "--steps",
            "20",
            "--ensembles",
            "2",
            "--quiet",
            "--out",
            "S",
        ],
        tmp_path,
        env={parallel.SCHEDULER_ENV: server.address},
    )
    _, err = p.communicate(timeout=BOUND + 60)
    took = time.perf_counter() - t0
    assert_clean_cluster_refusal(p.returncode, err, server.address)
    assert f"(from {parallel.SCHEDULER_ENV})" in err and took < BOUND, (took, err)
    assert listing(tmp_path) == []  # the folder of a run that never began is not left


@pytest.mark.parametrize("server", ["http"], indirect=True)
def test_every_command_with_a_scheduler_option_refuses_a_web_server(server, proj, tmp_path, capsys):
    """identify --profiles, design and run (multistart and sample above): exit 3 at once,
    nothing written."""
    fit = str(proj / "fit")
    a = tmp_path / "a.toml"
    a.write_text(
        f'[analysis]\nout = "A"\nconfig = "upper"\ndata = ["{proj / "data" / "upper.csv"}"]\n'
    )
    for argv in (
        ["identify", fit, "--profiles", "k_m", "--points", "3", "--out", str(tmp_path / "i")],
        ["design", fit, "--out", str(tmp_path / "d"), "--no-check"],
        ["run", str(a)],
    ):
        t0 = time.perf_counter()
        code = main([*argv, "--scheduler", server.address])
        err = capsys.readouterr().err
        assert_clean_cluster_refusal(code, err, server.address)
        assert time.perf_counter() - t0 < BOUND, argv
    assert not any((tmp_path / n).exists() for n in ("i", "d", "A"))


def test_a_dask_peer_that_never_takes_the_client_is_exit_3_not_a_hang(tmp_path):
    """Past the handshake (a Dask process, but not a scheduler that answers): the client is
    given up after the wait and a grace, and the process ends without Dask's noise."""
    script = tmp_path / "drive.py"
    script.write_text(
        textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_faults_cluster import FakeServer
        from rotorbayes.inference import parallel
        parallel.CLIENT_GRACE = 2.0
        s = FakeServer("handshake")
        try:
            with parallel.open_executor(parallel.choose(scheduler=s.address)):
                print("opened")
        except parallel.ClusterError as exc:
            print(exc, file=sys.stderr)
            sys.exit(3)
    """)
    )
    t0 = time.perf_counter()
    p = subprocess.run(
        [sys.executable, str(script)],
        env={**ENV, parallel.TIMEOUT_ENV: "2"},
        capture_output=True,
        text=True,
        timeout=BOUND + 60,
    )
    assert p.returncode == 3, p.stderr
    assert "speaks Dask's protocol but did not take this client" in p.stderr
    assert "Traceback" not in p.stderr and "Exception ignored" not in p.stderr, p.stderr
    assert time.perf_counter() - t0 < BOUND


# --------------------------------------------------- 2. a disk that fills at the summary
@contextlib.contextmanager
def small_disk(path: Path, kib: int):
    """A real tmpfs of ``kib`` KiB (root and a kernel that allow it), else the test is
    skipped."""
    path.mkdir()
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={kib}k", "tmpfs", str(path)], capture_output=True
    )
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.decode().strip()})")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], capture_output=True)


def fill(disk: Path, leave_kib: int = 0) -> None:
    st = os.statvfs(disk)
    with contextlib.suppress(OSError), open(disk / "filler", "ab") as fh:
        fh.write(b"\0" * max(0, st.f_bavail * st.f_frsize - leave_kib * 1024))
        fh.flush()


SAMPLE = ["--walkers", "10", "--steps", "20", "--ensembles", "1", "--max-draws", "5", "--quiet"]


def test_the_reserve_holds_the_summary_when_the_disk_fills_at_that_moment(
    proj, tmp_path, monkeypatch, capsys
):
    """The red-team case: the disk fills to the last byte after the last step, as the
    summary begins: every file is still written (exit code 0), from the reserve."""
    from rotorbayes.inference import posterior

    made = posterior.inference_data

    def filling(*args, **kw):
        fill(disk)
        assert os.statvfs(disk).f_bavail == 0
        return made(*args, **kw)

    monkeypatch.setattr(posterior, "inference_data", filling)
    with small_disk(tmp_path / "disk", 16_000) as disk:
        out = disk / "S"
        code = main(["sample", str(proj / "fit"), *SAMPLE, "--out", str(out)])
        err = capsys.readouterr().err
        assert code == 0, err
        assert listing(out) == sorted(
            [
                "chain.h5",
                "settings.json",
                "log.txt",
                "posterior.nc",
                "summary.md",
                "summary.csv",
                "corner.png",
                "trace.png",
                "predictive.png",
                "correlation.png",
                "warnings.txt",
            ]
        )
        from rotorbayes.inference import arviz_compat

        arviz_compat.load(out / "posterior.nc")


def test_a_write_that_fails_with_enospc_says_what_was_kept_and_resume_writes_the_rest(
    proj, tmp_path, monkeypatch, capsys
):
    from rotorbayes.inference import sampling

    real = sampling.SummaryReserve.write

    def failing(self, name, data):
        if name == "corner.png":
            raise OSError(errno.ENOSPC, "No space left on device", str(self.folder / name))
        return real(self, name, data)

    monkeypatch.setattr(sampling.SummaryReserve, "write", failing)
    out = tmp_path / "S"
    assert main(["sample", str(proj / "fit"), *SAMPLE, "--out", str(out)]) == EXIT.ENVIRONMENT
    err = capsys.readouterr().err
    assert f"{out}/corner.png could not be written: the disk is full" in err
    assert "the chains are complete" in err and f"{out}/chain.h5" in err
    assert "written: posterior.nc, summary.md, summary.csv" in err
    assert "not written: corner.png, trace.png, predictive.png, correlation.png" in err
    assert f"rotorbayes sample {out} --resume" in err and "Traceback" not in err
    assert not [n for n in listing(out) if n.endswith(".reserve")]  # the room given back
    monkeypatch.undo()
    assert main(["sample", str(out), "--resume", "--quiet"]) == 0
    assert (out / "corner.png").exists() and (out / "warnings.txt").exists()


@pytest.mark.parametrize("leave_kib", [0, 40])
def test_a_real_enospc_beyond_the_reserve_is_exit_3_never_a_crash(proj, tmp_path, leave_kib):
    """No reserve at all (its estimates patched to nothing) and a disk filled as the summary
    begins, to the last byte or to 40 KiB (posterior.nc then began and failed inside HDF5:
    two h5py tracebacks and a segmentation fault, exit 139): the writes meet a real ENOSPC.
    The process ends with exit code 3 and words, in a process of its own."""
    with small_disk(tmp_path / "disk", 16_000) as disk:
        out = disk / "S"
        script = tmp_path / "drive.py"
        script.write_text(
            textwrap.dedent(f"""
            import os, sys
            from rotorbayes.cli import main
            from rotorbayes.commands import sample
            from rotorbayes.inference import posterior
            sample.summary_sizes = lambda *a, **k: {{n: 0 for n in sample.SAMPLE_OUTPUTS}}
            made = posterior.inference_data
            def filling(*a, **k):
                st = os.statvfs({str(disk)!r})
                try:
                    with open({str(disk / "filler")!r}, "ab") as fh:
                        fh.write(b"\\0" * max(0, st.f_bavail * st.f_frsize
                                             - {leave_kib} * 1024))
                except OSError:
                    pass
                return made(*a, **k)
            posterior.inference_data = filling
            sys.exit(main(["sample", {str(proj / "fit")!r}, *{SAMPLE!r}, "--out", {str(out)!r}]))
        """)
        )
        p = subprocess.run(
            [sys.executable, str(script)], env=ENV, capture_output=True, text=True, timeout=300
        )
        assert p.returncode == EXIT.ENVIRONMENT, (p.returncode, p.stderr)
        assert "the disk is full" in p.stderr and "the chains are complete" in p.stderr
        assert "Traceback" not in p.stderr and "HDF5-DIAG" not in p.stderr, p.stderr
        assert not [n for n in listing(out) if n.endswith((".reserve", ".tmp"))]


# -------------------------------------------------------- 3. a damaged posterior.nc
@pytest.mark.parametrize(
    "damage", ["truncated", "empty", "overwritten", "not netCDF", "a folder", "another fit's"]
)
def test_identify_refuses_a_damaged_posterior_with_its_name(proj, post, tmp_path, damage, capsys):
    s = tmp_path / "S"
    shutil.copytree(post, s)
    nc = s / "posterior.nc"
    raw = nc.read_bytes()
    if damage == "truncated":
        nc.write_bytes(raw[: len(raw) // 2])
    elif damage == "empty":
        nc.write_bytes(b"")
    elif damage == "overwritten":
        b = bytearray(raw)
        b[2000:6096] = random.Random(2).randbytes(4096)
        nc.write_bytes(bytes(b))
    elif damage == "not netCDF":
        nc.write_text("t,u,theta_u\n0,1,2\n")
    elif damage == "a folder":
        nc.unlink()
        nc.mkdir()
    else:
        from rotorbayes.inference import arviz_compat

        idata = arviz_compat.load(nc)
        renamed = arviz_compat.group(idata, "posterior").rename({"k_m": "k_x"})
        groups = {"posterior": {v: renamed[v].values for v in renamed}}
        arviz_compat.save(arviz_compat.from_groups(groups), nc)
    code = main(
        ["identify", str(proj / "fit"), "--posterior", str(s), "--out", str(tmp_path / "i")]
    )
    err = capsys.readouterr().err
    assert code == EXIT.REFUSED, err
    assert str(nc) in err and "Traceback" not in err and "Exception ignored" not in err, err
    if damage == "another fit's":
        assert "holds no draws of k_m" in err and "another fit" in err
    else:
        assert "cannot be read as a posterior" in err
        assert f"rotorbayes sample {s} --resume" in err  # what to do: write it again
    assert not (tmp_path / "i").exists()


def test_a_posterior_written_in_memory_reads_back_on_this_line(post):
    from rotorbayes.inference import arviz_compat

    idata = arviz_compat.load(post / "posterior.nc")
    assert {"posterior", "sample_stats", "log_likelihood", "observed_data", "constant_data"} <= set(
        arviz_compat.group_names(idata)
    )
    assert bytes(arviz_compat.to_bytes(idata))[:8] == b"\x89HDF\r\n\x1a\n"


# ------------------------------------------------------ 4. effect files of others' folders
EFFECT = """
import pathlib
from rotorbayes import Effect, Parameter
pathlib.Path(__file__).with_suffix(".ran").write_text("imported")

def shift(t, theta_u, omega_u, theta_l, omega_l, v, p, q):
    return q[0], 0.0

my_effect = Effect(name="my_effect", physics="a constant upper torque", parameters=(
    Parameter("c_test", "N m", -1.0, 1.0, 0.0, "test torque", start=0.0),),
    signature="none", configs=("upper",), friction_shift=shift)
"""


def forged(proj, folder: Path) -> tuple[Path, Path]:
    """A fit folder whose fit.json names an effect file beside it (by a relative path, as a
    folder sent to someone would) with its right SHA-256 -- what anyone can write."""
    shutil.copytree(proj / "fit", folder)
    eff = folder / "effects.py"
    eff.write_text(EFFECT)
    doc = json.loads((folder / "fit.json").read_text())
    doc["added_effects"] = ["effects.py:my_effect"]
    doc["effect_files"] = {"effects.py": hashlib.sha256(eff.read_bytes()).hexdigest()}
    (folder / "fit.json").write_text(json.dumps(doc))
    return folder, eff


def test_a_fit_json_of_another_user_does_not_run_its_effect_file(
    proj, tmp_path, monkeypatch, capsys
):
    from rotorbayes.inference.results import ResultError, check_effect_files

    fit, eff = forged(proj, tmp_path / "theirs")
    doc = json.loads((fit / "fit.json").read_text())
    assert check_effect_files(doc, fit / "fit.json")  # this user's own: as before
    other = os.geteuid() + 4242
    monkeypatch.setattr(os, "geteuid", lambda: other)  # the same files seen by another user
    for argv in (
        ["compare", str(fit)],
        ["diagnose", str(fit)],
        ["sample", str(fit), "--out", str(tmp_path / "s")],
        ["identify", str(fit), "--out", str(tmp_path / "i")],
        [
            "fit",
            "--model",
            "upper",
            str(proj / "data" / "upper.csv"),
            "--p0",
            str(fit),
            "--out",
            str(tmp_path / "f"),
        ],
    ):
        assert main(argv) == EXIT.REFUSED, argv
        err = capsys.readouterr().err
        assert "belongs to another user" in err and "--trust-effects" in err, err
        assert str(fit / "effects.py") in err and "Traceback" not in err
    assert not eff.with_suffix(".ran").exists()  # never imported
    assert listing(tmp_path) == ["theirs"]
    assert check_effect_files(doc, fit / "fit.json", trust=True)
    assert "importing its effect file" in capsys.readouterr().err
    with pytest.raises(ResultError, match="belongs to another user"):
        check_effect_files(doc, fit / "fit.json")


def test_a_folder_unpacked_from_an_archive_does_not_run_its_effect_file(proj, tmp_path, capsys):
    from rotorbayes.inference.results import check_effect_files

    fit, eff = forged(proj, tmp_path / "made")
    old = time.time() - 3 * 86400
    for p in (fit / "fit.json", eff):
        os.utime(p, (old, old))  # as written days ago on the sender's machine
    with tarfile.open(tmp_path / "results.tar", "w") as tar:
        tar.add(fit, arcname="fit")
    (tmp_path / "got").mkdir()
    with tarfile.open(tmp_path / "results.tar") as tar:
        tar.extractall(tmp_path / "got", filter="fully_trusted")  # times kept, as tar does
    got = tmp_path / "got" / "fit"
    doc = json.loads((got / "fit.json").read_text())
    assert main(["compare", str(got)]) == EXIT.REFUSED
    err = capsys.readouterr().err
    assert "unpacked from an archive" in err and f"touch {got / 'fit.json'}" in err, err
    assert not (got / "effects.ran").exists()
    os.utime(got / "fit.json")  # the user vouches for the folder: `touch fit.json`
    assert check_effect_files(doc, got / "fit.json")


def test_a_fit_json_others_may_change_does_not_run_its_effect_file(proj, tmp_path):
    from rotorbayes.inference.results import ResultError, check_effect_files

    fit, _ = forged(proj, tmp_path / "shared")
    doc = json.loads((fit / "fit.json").read_text())
    mode = (fit / "fit.json").stat().st_mode
    os.chmod(fit / "fit.json", mode | 0o002)
    with pytest.raises(ResultError, match="every user may change it.*chmod go-w"):
        check_effect_files(doc, fit / "fit.json")
    os.chmod(fit / "fit.json", mode & ~0o022)
    assert check_effect_files(doc, fit / "fit.json")
