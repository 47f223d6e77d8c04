"""``rotorbayes sample``: posterior sampling with emcee from a fit, checkpointed."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import sys
from pathlib import Path

import numpy as np

from ..io.outputs import InterruptGuard
from ..util import exitcodes as EXIT
from ..util.exitcodes import Interrupted, Refused
from .common import Outcome
from .config import ExecutorOptions, FitFolderOptions, SampleOptions
from .options import (
    MAX_STEPS,
    MAX_WALKERS,
    add_changed_data_option,
    add_parallel_options,
    add_trust_option,
    ranged,
)

HELP = "posterior sampling with emcee from a fit (checkpointed; --resume continues)"


#: Steps per ensemble of a new run (``--steps``; ``[sample] steps`` of an analysis file).
DEFAULT_STEPS = 2000


def add_arguments(sp) -> None:
    sp.add_argument("source", help="a fit folder, or with --resume a sample folder")
    sp.add_argument("--out", help="output folder (new runs)")
    sp.add_argument(
        "--resume",
        action="store_true",
        help="continue the chains in SOURCE (a folder written by sample)",
    )
    sp.add_argument(
        "--walkers",
        type=ranged(int, ge=4, le=MAX_WALKERS, why=" (walkers per ensemble)"),
        default=32,
        help="walkers per ensemble",
    )
    sp.add_argument(
        "--steps",
        type=ranged(int, ge=10, le=MAX_STEPS, why=" (steps per ensemble)"),
        default=None,
        help=f"total steps per ensemble (default {DEFAULT_STEPS}; with --resume the new total)",
    )
    sp.add_argument(
        "--ensembles",
        type=ranged(int, ge=1, le=64, why=" (independent ensembles)"),
        default=2,
        help="independent ensembles (>= 2 for R-hat)",
    )
    sp.add_argument("--seed", type=ranged(int, ge=0, le=2**31 - 1), default=0)
    sp.add_argument(
        "--noise",
        choices=["robust", "floor", "sampled"],
        default="robust",
        help="robust: floor noise widened to the fit's honest covariance "
        "(correlated rounding while a disc sticks, model error, the input "
        "between samples); floor: i.i.d. at the encoder floor (too narrow on "
        "stick-slip data; to compare); sampled: σ sampled (prior 1/σ)",
    )
    sp.add_argument("--ar1", action="store_true", help="AR(1) errors per channel")
    from ..inference.move_names import DEFAULT_MOVES, MOVES

    sp.add_argument(
        "--moves",
        choices=list(MOVES),
        default=None,
        help="emcee's proposals "
        f"(default {DEFAULT_MOVES}; --resume keeps the run's own): "
        # argparse formats help with %: a percentage in the text is written %%
        + "; ".join(f"{k}: {v[1]}" for k, v in MOVES.items()).replace("%", "%%"),
    )
    sp.add_argument(
        "--priors", help="TOML with a [priors] table (default: uniform within the physical bounds)"
    )
    sp.add_argument(
        "--max-draws",
        type=ranged(int, ge=1, le=100_000, why=" (draws kept per ensemble)"),
        default=100,
        help="draws per ensemble kept in posterior.nc (with the pointwise "
        "log-likelihood of every sample: about 2 x draws x samples x channels x "
        "4 bytes)",
    )
    sp.add_argument("--quiet", action="store_true", help="no progress bar")
    sp.add_argument("--force", action="store_true", help="overwrite results in --out")
    add_trust_option(sp)
    add_changed_data_option(sp)
    add_parallel_options(
        sp,
        "ensembles",
        backend_help=(
            "where the independent ensembles run, concurrently, in segments of "
            "steps: serial, local threads, local processes, or dask (a local Dask "
            "cluster of --workers processes, or the scheduler of --scheduler or "
            "DASK_SCHEDULER_ADDRESS). Default, without any of these options: one "
            "ensemble after the other in this process, its walkers in the "
            "kernel's threads (as fast on one machine)"
        ),
    )


#: Files ``sample`` derives from chain.h5 (rewritten by every run, --resume included).
SAMPLE_OUTPUTS = (
    "posterior.nc",
    "summary.md",
    "summary.csv",
    "corner.png",
    "trace.png",
    "predictive.png",
    "correlation.png",
    "warnings.txt",
)


def _read_settings(src: Path) -> dict:
    """settings.json of a sample folder, checked; refused (Refused) when absent or damaged."""
    path = src / "settings.json"
    if not src.is_dir():
        raise Refused(
            f"{src}: no such folder; --resume needs a folder written by `rotorbayes sample`"
        )
    if not path.exists():
        raise Refused(
            f"{src}: no settings.json; --resume needs a folder written by `rotorbayes sample`"
        )
    try:
        settings = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise Refused(
            f"{path}: cannot be read ({exc}): damaged; --resume cannot continue "
            "this run. Start again with `rotorbayes sample FIT --out "
            f"{src} --force`"
        ) from None
    need = {
        "fit": str,
        "walkers": int,
        "steps": int,
        "ensembles": int,
        "seed": int,
        "noise": str,
        "ar1": bool,
    }
    bad = [
        k
        for k, t in need.items()
        if not isinstance(settings.get(k) if isinstance(settings, dict) else None, t)
    ]
    if bad:
        raise Refused(
            f"{path}: {', '.join(bad)} missing or of the wrong type: damaged or "
            "not written by `rotorbayes sample`; start again with `rotorbayes "
            f"sample FIT --out {src} --force`"
        )
    return settings


def sample(
    source: str,
    *,
    out: str | None = None,
    resume: bool = False,
    walkers: int = 32,
    steps: int | None = None,
    ensembles: int = 2,
    seed: int = 0,
    noise: str = "robust",
    ar1: bool = False,
    moves: str | None = None,
    priors: str | None = None,
    max_draws: int = 100,
    quiet: bool = False,
    force: bool = False,
    trust_effects: bool = False,
    backend: str | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    accept_changed_data: bool = False,
) -> Outcome:
    """emcee from the fit folder ``source`` into the folder ``out``, checkpointed at every
    step (chain.h5); with ``resume`` (``source`` then a sample folder) the same chains go on
    to ``steps`` in total.

    ``walkers`` per ensemble, ``steps`` (default 2000), ``ensembles`` independent
    ensembles, ``seed``; ``noise`` "robust", "floor" or "sampled", ``ar1`` errors, ``moves``
    emcee's proposals (a resumed run keeps its own), ``priors`` a TOML file; ``max_draws``
    per ensemble kept in posterior.nc.  Writes the summary tables and figures from the
    chains.

    ``backend``, ``workers``, ``scheduler`` (or ``DASK_SCHEDULER_ADDRESS``, or a study on a
    Dask cluster) run the ensembles concurrently on the executor
    (:mod:`rotorbayes.inference.parallel`), in segments of steps, with the same chains bit
    for bit; without them they run one after the other in this process, as before.
    """
    return execute(
        SampleOptions(
            source=source,
            out=out,
            resume=resume,
            walkers=walkers,
            steps=steps,
            ensembles=ensembles,
            seed=seed,
            noise=noise,
            ar1=ar1,
            moves=moves,
            priors=priors,
            max_draws=max_draws,
            quiet=quiet,
            force=force,
            fit_folder=FitFolderOptions(
                trust_effects=trust_effects, accept_changed_data=accept_changed_data
            ),
            executor=ExecutorOptions(backend=backend, workers=workers, scheduler=scheduler),
        )
    )


def execute(options: SampleOptions) -> Outcome:
    """:func:`sample` with its options as one
    :class:`~rotorbayes.commands.config.SampleOptions` (the form the study builds)."""
    from ..io.outputs import clean_stale, folder_lock, follow_link

    a = options
    src = Path(a.source)
    if a.resume:
        if a.out and Path(a.out).absolute() != src.absolute():
            raise Refused(f"--resume continues {src}/ in place; leave out --out {a.out}")
        out = src
    else:
        if a.steps is None:
            a = dataclasses.replace(a, steps=DEFAULT_STEPS)
        if not a.out:
            raise Refused("give --out FOLDER for the posterior (or --resume FOLDER)")
        out = follow_link(Path(a.out), "--out")  # a link is followed, never replaced
        if out.exists() and not out.is_dir():
            raise Refused(f"--out {out}: is a file, not a folder; give a new folder name")
        if not out.parent.is_dir():
            raise Refused(
                f"--out {out}: the folder {out.parent}/ does not exist; create it "
                "first or choose another --out"
            )
    _check_sample_target(a, out)
    with folder_lock(out):
        _check_sample_target(a, out)  # again, under the lock
        clean_stale(out)
        code = _sample_locked(a, src, out)
    return Outcome(code, out)


def _check_sample_target(a: SampleOptions, out: Path) -> None:
    if a.resume:
        return
    from ..io.outputs import check_replaceable

    # Never the working folder, a folder of the user's own files or one holding an input,
    # --force or not (without --force, a result folder is refused below, with its hint).
    check_replaceable(out, True, inputs=[a.source, a.priors])
    if out.is_dir() and any(out.iterdir()) and not a.force:
        raise Refused(
            f"{out}/ already holds results; continue them with "
            f"`rotorbayes sample {out} --resume --steps N`, choose another "
            "--out or pass --force"
        )


def _sample_locked(a: SampleOptions, src: Path, out: Path) -> int:
    import shutil

    from ..inference import sampling
    from ..inference.likelihood import LogPosterior, load_priors
    from ..io.outputs import check_free_space

    if a.resume:
        settings = _read_settings(src)
        if a.steps is not None:
            settings["steps"] = a.steps  # checked against the steps held, below
    else:
        settings = {
            "fit": str(Path(a.source).resolve()),
            "walkers": a.walkers,
            "steps": a.steps,
            "ensembles": a.ensembles,
            "seed": a.seed,
            "noise": a.noise,
            "ar1": a.ar1,
            "moves": a.moves or sampling.DEFAULT_MOVES,
            "priors": str(Path(a.priors).resolve()) if a.priors else None,
        }
    fit = a.fit_folder.load(settings["fit"])
    priors = load_priors(settings["priors"], fit.problem) if settings.get("priors") else None
    lp = LogPosterior(
        fit.problem, fit.x, priors=priors, noise=settings["noise"], ar1=settings["ar1"]
    )
    if settings["walkers"] < 2 * lp.ndim:
        raise Refused(
            f"--walkers {settings['walkers']}: emcee needs at least twice the "
            f"{lp.ndim} sampled coordinates; give --walkers {2 * lp.ndim} or more"
        )
    if not a.resume:
        # The walkers start around the fit: a prior that excludes it cannot be sampled.
        z0 = np.asarray(lp.to_z(fit.x), float)[None, :]
        if not np.isfinite(lp.log_prior(z0)[0]):
            where = f"--priors {a.priors}" if a.priors else "the priors"
            raise Refused(
                f"{where} give zero probability to the fit's point in "
                f"{fit.folder}/ (a value outside a prior's lower..upper); widen "
                "that prior or fit again (nothing was written)"
            )
    # Room for posterior.nc, the tables and the figures, file by file (held from before
    # the first step until each is written: S.SummaryReserve).
    sizes = summary_sizes(
        lp, settings["walkers"], settings["steps"], settings["ensembles"], a.max_draws
    )
    outputs = sum(sizes.values())
    need = (
        sampling.chain_bytes(settings["walkers"], lp.ndim, settings["steps"], settings["ensembles"])
        + outputs
    )
    chain = out / "chain.h5"
    # Reserve files left by a killed run are free space, not results.
    sampling.SummaryReserve.clear(out)
    if a.resume:
        held, restored = sampling.recover_checkpoint(
            chain, n_walkers=settings["walkers"], ndim=lp.ndim, n_ensembles=settings["ensembles"]
        )
        if restored:
            print(f"warning: {restored}", file=sys.stderr, flush=True)
        most = max(held.values(), default=0)
        if settings["steps"] < most:
            raise Refused(
                f"--steps {settings['steps']} is below the {most} steps {chain} "
                "already holds; give the new total (at least that many)"
            )
        have = chain.stat().st_size if chain.exists() else 0
        check_free_space(out, max(need - have, 2_000_000), what=f"sample {out}")
        if not held and not chain.exists():
            print(
                f"{out}/ holds no finished step yet (the run was stopped before its first "
                "step): sampling starts at step 0"
            )
        elif held:
            print(
                f"resuming {chain}: "
                + ", ".join(f"{n} at step {k}" for n, k in sorted(held.items()))
                + f" of {settings['steps']} (each continues from its stored state)"
            )
    else:
        check_free_space(out.parent, need, what=f"--out {out}")
    created = not out.exists()
    if not a.resume and not created:
        # --force: the new run's checkpoint must live in OUT to be resumable, so the old
        # results go now (after every check has passed).
        for p in out.iterdir():
            if p.name == "log.txt":
                continue
            shutil.rmtree(p) if p.is_dir() else p.unlink()
    out.mkdir(exist_ok=True)
    sampling.save_settings(out, settings)
    print(
        f"sampling {lp.ndim} coordinates ({', '.join(lp.coord_names)}) of {fit.folder}/ "
        f"with {settings['walkers']} walkers x {settings['steps']} steps x "
        f"{settings['ensembles']} independent ensembles; noise: "
        f"{'AR(1), sampled' if lp.ar1 else settings['noise']}; checkpoint {out}/chain.h5 "
        "(every step: a kill loses nothing, --resume continues)",
        flush=True,
    )
    stale = [n for n in SAMPLE_OUTPUTS if (out / n).exists()]
    reserve = None
    guard = InterruptGuard().start()  # Ctrl-C: stop between two steps, never inside one
    try:
        reserve = sampling.SummaryReserve(out, sizes)
        try:
            with _ensemble_executor(a.executor, int(settings["ensembles"])) as ex:
                runs = sampling.sample(
                    lp,
                    fit.x,
                    out,
                    n_walkers=settings["walkers"],
                    n_steps=settings["steps"],
                    n_ensembles=settings["ensembles"],
                    seed=settings["seed"],
                    progress=not a.quiet and sys.stderr.isatty(),
                    should_stop=lambda: guard.hit > 0,
                    moves=a.moves or settings.get("moves"),
                    executor=ex,
                )
        except RuntimeError as exc:
            if "cannot place the walkers" not in str(exc):
                raise
            raise Refused(f"{fit.folder}/: {exc}") from None
        except sampling.CheckpointBusy as exc:
            raise EXIT.Busy(f"{exc.strerror} `rotorbayes sample {out} --resume`") from None
        except sampling.SamplingStopped as exc:
            earlier = (
                (f" ({', '.join(stale)} still describe the earlier, shorter run until then)")
                if stale
                else ""
            )
            raise Interrupted(
                f"interrupted (Ctrl-C): {exc}; every finished step is kept in {out}/chain.h5 "
                "(settings in "
                f"settings.json). Continue with `rotorbayes sample {out} --resume`{earlier}"
            ) from None
        except BaseException as exc:
            if created and not sampling.steps_held(chain):
                shutil.rmtree(out, ignore_errors=True)  # nothing done: leave no folder
            if EXIT.is_disk_full(exc) and not isinstance(exc, EXIT.EnvironmentFailure):
                _die_disk_full(out, exc)
            raise
        written = _write_sample_outputs(a, out, lp, fit, runs, guard, reserve)
    finally:
        guard.stop()
        if reserve is not None:
            reserve.close()
    return written


def summary_sizes(lp, walkers: int, steps: int, ensembles: int, max_draws: int) -> dict[str, int]:
    """Generous bounds on the size of every file written after the chains [bytes], known
    before the first step: posterior.nc from the kept draws and the data
    (:func:`~rotorbayes.inference.posterior.file_bytes`), each figure one byte per pixel of
    its canvas at 100 dpi (a PNG of these plots takes 0.1-0.2), the tables and warnings 64
    KiB plus a line per coordinate."""
    from ..inference.posterior import file_bytes

    k, chans = lp.ndim, len(lp.channels)
    rows = ensembles * min(max_draws, walkers * steps)
    corner = 2.1 * k + 1.3  # corner.py: 2 in per panel, 5 % gaps, margins [in]
    inches = {
        "corner.png": corner * corner,
        "trace.png": 10 * (1.5 * k + 0.8),
        "predictive.png": 10 * (5.7 * chans + 0.8),
        "correlation.png": (1.0 + 0.6 * k) * (0.8 + 0.6 * k),
    }
    text = 65_536 + 1_024 * k
    sizes = {
        "posterior.nc": file_bytes(lp, rows),
        "summary.md": text,
        "summary.csv": text,
        "warnings.txt": text + 256 * k * ensembles,
    }
    sizes.update({n: int(v * 100 * 100) + 65_536 for n, v in inches.items()})
    return {n: sizes[n] for n in SAMPLE_OUTPUTS}


@contextlib.contextmanager
def _ensemble_executor(options: ExecutorOptions, n_ensembles: int = 1):
    """The executor the ensembles run on, or None (one after the other in this process, as
    before the executor layer): an executor when ``--backend``, ``--workers`` or
    ``--scheduler`` is given, ``DASK_SCHEDULER_ADDRESS`` is set, or a study runs on a Dask
    cluster; with none of these, the default pool where it pays: several ensembles on a
    machine of :data:`~rotorbayes.inference.parallel.PROCESSES_FROM_CORES` cores or more
    (16 cores, 4 ensembles of 32 walkers on 30 s at 1 kHz: processes 1.54 s, the serial
    loop on 16 numba threads 2.33 s; benchmarks/README.md).  On a smaller machine the
    serial loop (the walkers of an ensemble are one parallel kernel batch) was as fast as
    any pool (2 cores: serial 1.48 s, threads 1.37 s, processes 1.96 s), so it stays."""
    from ..inference import parallel

    if (
        not options.given
        and not os.environ.get(parallel.SCHEDULER_ENV)
        and not parallel.is_dask(parallel.current_executor())
    ):
        cores = os.cpu_count() or 1
        if not (
            n_ensembles >= 2
            and cores >= parallel.PROCESSES_FROM_CORES
            and parallel.default_backend(cores) == "processes"
        ):
            yield None
            return
    with options.open() as ex:
        yield ex


def _die_disk_full(out: Path, exc: BaseException) -> None:
    """The disk filled up in the middle of an HDF5 write. h5py's objects are then in a state
    in which tearing them down can crash the interpreter, so say what happened and leave at
    once (the lock goes with the process)."""
    print(
        f"rotorbayes sample: error: {out}/chain.h5: the disk is full (no space left on the "
        "device) while a step was being written; the steps finished before it are in the "
        f"checkpoint. Free some space and continue with `rotorbayes sample {out} "
        "--resume` (if the checkpoint is refused as damaged, start again with --force)",
        file=sys.__stderr__,
        flush=True,
    )
    with contextlib.suppress(Exception):
        sys.__stdout__.flush()
    os._exit(EXIT.ENVIRONMENT)


def _write_sample_outputs(a: SampleOptions, out: Path, lp, fit, runs, guard, reserve=None) -> int:
    """The summary, InferenceData and figures from finished chains, each made in memory
    and then written into the room reserved for it (``reserve``, a
    :class:`~rotorbayes.inference.sampling.SummaryReserve`); Ctrl-C between two files
    stops with a true account of what is on disk, and so does a write that fails (exit
    code 3: the chains are complete, ``--resume`` writes the rest)."""
    from ..figures import posterior as posterior_figures
    from ..inference import arviz_compat, posterior, sampling

    if reserve is None:
        reserve = sampling.SummaryReserve(out, {})
    names = lp.coord_names
    done: list[str] = []

    def written_so_far() -> str:
        left = [n for n in SAMPLE_OUTPUTS if n not in done]
        return (
            f"; written: {', '.join(done)}" if done else "; none of the summary files was written"
        ) + (f"; not written: {', '.join(left)}" if left else "")

    def checkpoint() -> None:
        if guard.hit:
            raise Interrupted(
                f"interrupted (Ctrl-C) after the sampling had finished; the chains are "
                f"complete in {out}/chain.h5"
                + written_so_far().replace("not written", "not yet rewritten")
                + f". `rotorbayes sample {out} "
                "--resume` writes them from the chains (no new steps)"
            )

    warnings = sampling.convergence(runs, names)
    if lp.n_failed:
        warnings.append(
            f"{lp.n_failed} proposals could not be simulated (counted in "
            "sample_stats.failed_simulations; they got -inf)"
        )
    idata = posterior.inference_data(lp, runs, max_draws=a.max_draws)
    rows = posterior.summary_table(idata, lp, runs)
    if len(runs) >= 2:
        bad = [r["parameter"] for r in rows if not r["r_hat"] < 1.01]
        if bad:
            warnings.append(
                f"R-hat across the {len(runs)} ensembles is >= 1.01 for "
                f"{', '.join(bad)}: they have not converged to one distribution"
            )
    else:
        warnings.append(
            "one ensemble: no R-hat (the walkers of an ensemble are not "
            "independent chains); use --ensembles 2 or more"
        )
    unc = lp.uncertainty
    if unc is not None and unc.warning():
        warnings.append(unc.warning())
    if lp.noise == "floor":
        warnings.append(
            "--noise floor counts every sample as independent: on data where a "
            "disc sticks or turns slowly the intervals are too narrow (the "
            "default, --noise robust, widens them to what the errors support)"
        )
    md = posterior.table_markdown(rows, assumptions=unc.assumptions() if unc is not None else None)
    print("\n" + md)
    for name, make in (
        ("posterior.nc", lambda: arviz_compat.to_bytes(idata)),
        ("summary.md", lambda: (md + "\n").encode()),
        ("summary.csv", lambda: posterior.table_csv(rows).encode()),
        ("corner.png", lambda: _png(posterior_figures.plot_corner(idata, fit.problem))),
        ("trace.png", lambda: _png(posterior_figures.plot_trace(runs, names)[0])),
        ("predictive.png", lambda: _png(posterior_figures.plot_predictive(idata, fit.problem)[0])),
        (
            "correlation.png",
            lambda: _png(posterior_figures.plot_correlation(idata, fit.problem)[0]),
        ),
        ("warnings.txt", lambda: ("\n".join(warnings) + "\n").encode()),
    ):
        checkpoint()
        data = make()
        try:
            reserve.write(name, data)
        except OSError as exc:
            kept = (
                f"{out}/{name} could not be written: "
                + (
                    "the disk is full (no space left on the device)"
                    if EXIT.is_disk_full(exc)
                    else EXIT.describe_environment(exc, "")
                )
                + f"; the chains are complete in {out}/chain.h5"
                + written_so_far()
            )
            raise EXIT.EnvironmentFailure(
                f"{kept}. Free some space (or fix the folder) and run `rotorbayes sample "
                f"{out} --resume` to write them (no new steps)"
            ) from None
        done.append(name)
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    print(
        f"\nwrote posterior.nc, summary.md/.csv, corner.png, trace.png, predictive.png, "
        f"correlation.png in {out}/ ({lp.n_calls} log-posterior evaluations in all, the "
        "walkers' starting points included)"
    )
    if guard.hit:
        raise Interrupted(
            f"interrupted (Ctrl-C) as the last file was written; the results "
            f"were kept, complete, in {out}/"
        )
    return EXIT.DONE


def _png(fig) -> memoryview:
    """``fig`` as PNG bytes at 100 dpi (the figures of every command), the figure closed."""
    import io

    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    try:
        fig.savefig(buf, dpi=100, format="png")
    finally:
        plt.close(fig)
    return buf.getbuffer()
