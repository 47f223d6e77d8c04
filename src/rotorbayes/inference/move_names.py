"""The names and words of the sampler's moves (``sample --moves``), apart from the moves
themselves (:mod:`rotorbayes.inference.sampling.moves`): the command line lists them
without importing emcee and scipy.stats, which every command would otherwise pay for."""

from __future__ import annotations

#: The sampler's moves (``sample --moves``): name -> (emcee moves with weights, words).
#: Every one is affine-invariant except the snooker move; all keep detailed balance, so
#: they differ only in how fast the walkers forget where they were.
MOVES = {
    "stretch": (
        (("stretch", 1.0),),
        "emcee's stretch move alone (a = 2; rotorbayes's default before the mixed moves)",
    ),
    "de": ((("de", 1.0),), "differential evolution alone (emcee's DEMove, γ = 2.38/√(2d))"),
    "de-mix": (
        (("de", 0.8), ("snooker", 0.2)),
        "differential evolution 80 % and DE snooker 20 % (emcee's DEMove, DESnookerMove)",
    ),
    "de-stretch": (
        (("de", 0.6), ("snooker", 0.2), ("stretch", 0.2)),
        "differential evolution 60 %, DE snooker 20 %, stretch 20 %",
    ),
    "fit-de": (
        (("fit", 0.5), ("de", 0.5)),
        "independence proposals from the fit's covariance (a Student t, 5 degrees "
        "of freedom, 1.2 x its width; re-centred once on the ensemble's draws after "
        "150 steps) 50 %, differential evolution 50 %",
    ),
}
#: Mean acceptance outside (low, high) is warned about, per moves (with the range expected).
#: Independence proposals are accepted less often than local moves without mixing worse:
#: each accepted one moves a walker across the posterior (measured on the 1 kHz brake
#: posterior: 0.19-0.24 with τ 19-32 steps, where de-mix had 0.39 and τ 42-49).
ACCEPTANCE = {
    "stretch": (0.15, 0.7, "0.2-0.5"),
    "de": (0.15, 0.7, "0.2-0.5"),
    "de-mix": (0.15, 0.7, "0.2-0.5"),
    "de-stretch": (0.15, 0.7, "0.2-0.5"),
    "fit-de": (0.05, 0.9, "0.1-0.6"),
}
#: The default, chosen by measured ESS per second (``benchmarks/bench_sampler_moves.py``).
DEFAULT_MOVES = "fit-de"
#: Moves of a run whose checkpoint does not name them (written before moves were stored).
LEGACY_MOVES = "stretch"
