"""What each ``rotorbayes`` command does, as functions a Python user can call too.

One module per command, named after it, each with

* ``HELP`` — the command's one-line description;
* ``add_arguments(parser)`` — its command-line options (argparse); the option
  ``--max-nfev`` arrives as the keyword ``max_nfev``;
* a public function of the command's name (``fit.fit``, ``sample.sample``, ...) that takes
  plain arguments, prints what the command prints, writes what it writes and returns an
  :class:`~rotorbayes.commands.common.Outcome` (exit code, the folder written, its main
  document).  Bad input raises :class:`~rotorbayes.util.exitcodes.Refused` or a ``ValueError``
  naming the file or value (a measurement file, a parameter set, an output folder that
  holds results: ``rotorbayes.cli.REFUSED`` lists them), Ctrl-C
  :class:`~rotorbayes.util.exitcodes.Interrupted`.

For example::

    from rotorbayes.commands.fit import fit
    from rotorbayes.commands.diagnose import diagnose

    outcome = fit(["example:upper_est"], model="upper", out="f0")
    diagnose("f0")

Shared pieces: :mod:`.common` (loading data and parameter sets, the executor, strict JSON),
:mod:`.options` (the option types and option groups of several commands' command lines)
and :mod:`.config` (the same options as typed objects: the problem, the solver, the
executor; ``fit``, ``multistart``, ``sample`` and ``identify`` build one from their
keywords and ``execute`` it).
:mod:`rotorbayes.cli` is only the table of these commands and the exit codes.

The package imports none of its modules here: :mod:`rotorbayes.commands.study.analysis`
calls the fit, diagnose, compare, sample and identify functions, and the ``run`` and
``demo`` commands call the study.
"""
